//! The web renderer in headless Chromium against the real daemon: the page
//! loads, draws the puppet, and a synthetic drag deforms it (pixels change).
//! Also the record button and the keyframing pad (a director's), two named
//! performers and a viewer who see each other's hands, a refused token,
//! and the show view and the performer view's chrome. Runs only with
//! Chromium (off only with `PUPPETRY_BROWSER_TESTS=0`) (see `tests/it/common/browser.rs`).

use crate::common::browser::{self, DIRECTOR, PERFORMER};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_browser_drag_deforms_the_puppet() {
    if !browser::enabled("a_browser_drag_deforms_the_puppet") {
        return;
    }
    // The demo puppet's belly: on the puppet, between its pinned feet.
    let summary = browser::run_page_script("demo", "drag.mjs", "640,360").await;
    assert!(
        summary["changedPixels"].as_u64().unwrap() > 500,
        "{summary}"
    );
    // Let go, the page says the puppet springs back and how to keep a
    // pose: a newcomer took the snap back (undo grey) for a lost pose.
    let said = summary["letGo"].as_str().unwrap_or_default();
    assert!(
        said.contains("springs back") && said.contains("Shift+click pins"),
        "{summary}"
    );
}

/// The stage does not move under a performer's finger: while a contact
/// holds the puppet, the toolbar growing a line (as when a name joins the
/// people list) leaves the stage where it is; after the lift the stage
/// moves below the taller bar, and with nothing held it moves at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stage_holds_still_under_a_held_contact_while_the_toolbar_grows() {
    if !browser::enabled("the_stage_holds_still_under_a_held_contact_while_the_toolbar_grows") {
        return;
    }
    let summary = browser::run_page_script("demo", "hold.mjs", "640,360").await;
    let shift = |name: &str| summary[name].as_f64().unwrap();
    assert!(shift("heldShift") < 0.5, "{summary}");
    assert!(shift("liftShift") > 5.0, "{summary}");
    assert!(shift("freeShift") > 5.0, "{summary}");
}

/// As above for a director's brush stroke half painted: it holds the stage
/// as a contact does, so the stage waits for its lift too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stage_holds_still_under_a_directors_stroke_while_the_toolbar_grows() {
    if !browser::enabled("the_stage_holds_still_under_a_directors_stroke_while_the_toolbar_grows") {
        return;
    }
    let summary = browser::run_page_as(
        "demo",
        DIRECTOR,
        "hold.mjs",
        "640,360",
        &[("PUPPETRY_HOLD_WITH", "stroke")],
    )
    .await
    .summary;
    let shift = |name: &str| summary[name].as_f64().unwrap();
    assert_eq!(summary["heldWith"], "stroke", "{summary}");
    assert!(shift("heldShift") < 0.5, "{summary}");
    assert!(shift("liftShift") > 5.0, "{summary}");
    assert!(shift("freeShift") > 5.0, "{summary}");
}

/// The page's soundtrack (issue 35): picked on a director's page, it
/// plays while a take records, in time with the take's clock, on that
/// page and on one joining halfway (from halfway); it stops with the take
/// and plays again from the start when the take is played back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_soundtrack_plays_in_time_with_takes_on_every_page() {
    if !browser::enabled("a_soundtrack_plays_in_time_with_takes_on_every_page") {
        return;
    }
    let run = browser::run_page_as("demo", DIRECTOR, "soundtrack.mjs", "640,360", &[]).await;
    let summary = &run.summary;
    eprintln!("{summary}");
    assert!(
        summary["late"]["truth"].as_f64().unwrap() >= 1.5,
        "{summary}"
    );
}

/// Takes from the page: the record button turns red with "REC take-001"
/// and a running time on a performer's page and a viewer's, a drag is
/// recorded, and after stopping the take list holds take-001, which is in
/// the daemon's (temporary) takes folder.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_record_button_records_a_take_every_page_sees() {
    if !browser::enabled("the_record_button_records_a_take_every_page_sees") {
        return;
    }
    let run = browser::run_page_as("demo", DIRECTOR, "record.mjs", "640,360", &[]).await;
    let summary = &run.summary;
    assert!(
        summary["changedPixels"].as_u64().unwrap() > 500,
        "{summary}"
    );
    let takes: Vec<_> = puppetry_take::list(run.takes.path())
        .unwrap()
        .into_iter()
        .map(|t| t.unwrap())
        .collect();
    assert_eq!(takes.len(), 2, "{takes:?}");
    let take = &takes[0];
    assert_eq!(take.name, "take-001");
    assert_eq!(take.ending, "stopped", "{take:?}");
    // The drag is in it: contact steps and the frames they caused.
    assert!(take.steps > 0 && take.frames > 0, "{take:?}");
    // The overdub layered over take-001 and left out its hand, whose grab
    // was inside the replaced disc.
    let overdub = &takes[1];
    assert_eq!(overdub.layers, ["take-001"], "{overdub:?}");
    assert_eq!(summary["replace"].as_array().unwrap().len(), 1, "{summary}");
    let played_contacts = puppetry_take::TakeReader::open(&overdub.file)
        .unwrap()
        .filter_map(|r| match r.unwrap() {
            puppetry_take::Record::Step(s) => Some(s),
            _ => None,
        })
        .flat_map(|s| s.changes)
        .filter(|c| {
            matches!(c, puppetry_stage::Change::Contacts { frame }
                if frame.source.as_str().starts_with("take-001/"))
        })
        .count();
    assert_eq!(played_contacts, 0, "the replaced hand was played");
}

/// The keyframing pad: two key poses made from the page (the puppet's head
/// held by a finger, then by the mouse), then a drag on the pad from one
/// key to the other moves the puppet; the cursor every page sees follows,
/// key handles appear, keys move and go, and a viewer sees the pad
/// read-only.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_key_pad_blends_key_poses_made_on_the_page() {
    if !browser::enabled("the_key_pad_blends_key_poses_made_on_the_page") {
        return;
    }
    // The demo puppet's head; key poses are the director's.
    let summary = browser::run_page_as("demo", DIRECTOR, "keypad.mjs", "640,540", &[])
        .await
        .summary;
    assert!(
        summary["changedPixels"].as_u64().unwrap() > 500,
        "{summary}"
    );
    assert!(summary["keyHandles"].as_u64().unwrap() > 0, "{summary}");
}

/// Issue 31: the keyframe stage's `[[pad]]` area is drawn on the page (a
/// finger there moves the key cursor, so it must not look like bare
/// stage), and the key pad's names overlap neither each other nor a dot.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stage_pad_area_is_drawn_and_key_names_do_not_overlap() {
    if !browser::enabled("the_stage_pad_area_is_drawn_and_key_names_do_not_overlap") {
        return;
    }
    let summary = browser::run_page_as("keyframe", DIRECTOR, "padarea.mjs", "110,110", &[])
        .await
        .summary;
    let area: Vec<f64> = summary["drawn"][0]["area"]
        .as_array()
        .map(|a| a.iter().filter_map(|v| v.as_f64()).collect())
        .unwrap_or_default();
    assert_eq!(area, [20.0, 20.0, 200.0, 200.0], "{summary}");
    assert_eq!(summary["labels"].as_array().unwrap().len(), 6, "{summary}");
}

/// Issue 12, observations 1 and 2: performers Ana and Ben (the demo stage's
/// people) and a viewer, with a transparent show page to tell the puppet
/// from the background. Every page's legend shows both in the colours the
/// server gave them, far apart; while Ana holds the puppet's belly and Ben
/// drags its head, every page draws each dot under its finger (within a
/// few pixels), in its owner's colour, on the puppet. Before: the viewer's
/// dots stayed where the fingers landed, and both hashed to nearly the
/// same yellow-green.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_performers_and_a_viewer_see_every_hand_under_its_finger_in_its_colour() {
    if !browser::enabled(
        "two_performers_and_a_viewer_see_every_hand_under_its_finger_in_its_colour",
    ) {
        return;
    }
    let env = [
        ("PUPPETRY_TOKENS", "ana,ben"),
        ("PUPPETRY_HOLD", "640,360"),
        ("PUPPETRY_DRAG", "40,0"),
    ];
    let summary = browser::run_page_as("demo", "", "people.mjs", "640,540", &env)
        .await
        .summary;
    assert!(
        summary["colourDistance"].as_u64().unwrap() >= 80,
        "{summary}"
    );
    // Four pages, two fingers each, halfway and at the end.
    assert_eq!(summary["end"].as_object().unwrap().len(), 8, "{summary}");
}

/// Issue 12, observation 3 (and 5, page side): a wrong token gets the
/// banner "token refused — viewing only" and a viewer's page at once, and
/// the token is never sent again (a dropped connection comes back as a
/// viewer); a good token leaves the address bar and survives a reload.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_token_falls_back_to_viewing_without_retrying() {
    if !browser::enabled("a_refused_token_falls_back_to_viewing_without_retrying") {
        return;
    }
    let env = [("PUPPETRY_TOKEN", "ana")];
    let summary = browser::run_page_as("demo", "", "token.mjs", "640,360", &env)
        .await
        .summary;
    assert_eq!(summary["wrong"]["role"], "viewer", "{summary}");
    assert_eq!(
        summary["wrongAfterDrop"].as_array().unwrap().len(),
        3,
        "{summary}"
    );
}

/// Issue 12, observation 9 (page side): `/?view=show` has no UI at all, no
/// dots unless asked, a transparent background and a fixed drawing size
/// when asked; the performer's toolbar sits above the stage, hides with
/// `h` (the stage then fills the window), and the page has fullscreen, a
/// loud connection indicator and a latency readout.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_show_view_is_only_the_puppets_and_the_toolbar_hides() {
    if !browser::enabled("the_show_view_is_only_the_puppets_and_the_toolbar_hides") {
        return;
    }
    let env = [("PUPPETRY_TOKEN", "ana")];
    let summary = browser::run_page_as("demo", PERFORMER, "show.mjs", "640,360", &env)
        .await
        .summary;
    assert_eq!(
        summary["show"]["ui"].as_array().unwrap().len(),
        0,
        "{summary}"
    );
    assert_eq!(summary["transparent"]["alpha"]["corner"], 0, "{summary}");
}

/// Issue 13: the demo figure's arm dragged across its pinned chest is
/// drawn wholly over the body: where the two overlap and their pictures
/// differ, the pixel is the arm's (`tests/web/depth.mjs`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_arm_folded_over_the_body_is_drawn_over_it() {
    if !browser::enabled("an_arm_folded_over_the_body_is_drawn_over_it") {
        return;
    }
    let summary = browser::run_page_as("demo", PERFORMER, "depth.mjs", "640,364", &[])
        .await
        .summary;
    let pixels = &summary["pixels"];
    let telling = pixels["telling"].as_u64().unwrap();
    let near = pixels["near"].as_u64().unwrap();
    assert!(telling >= 30 && near * 10 >= telling * 9, "{summary}");
}

/// Issue 45: a TUIO sender that died mid-touch held the puppet, and no one
/// could see it (it is no person) or let it go. Every page's people list
/// shows it holding one contact; the director's "×" lets it go and its
/// handle leaves every page.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_director_sees_a_silent_sender_holding_the_puppet_and_lets_it_go() {
    if !browser::enabled("a_director_sees_a_silent_sender_holding_the_puppet_and_lets_it_go") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("tuio.toml");
    // It would let go by itself only after an hour.
    let extra = "[[input]]\nkind = \"tuio\"\nlisten = \"127.0.0.1:0\"\nrelease_after_s = 3600\n";
    std::fs::write(&stage, crate::common::daemon::stage_text(extra)).unwrap();
    let sender = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let env = [("PUPPETRY_HOLDER", "tuio:table")];
    let prepare = async |running: &puppetry_daemon::serve::Running| {
        // On the puppet's belly (TUIO is 0..1, y down, over the stage).
        let down = crate::common::tuio::v1(Some("table"), &[5], &[(5, 0.5, 0.5)], 1);
        sender
            .send_to(&down, running.tuio_addresses[0])
            .await
            .unwrap();
    };
    let run = browser::run_page_prepared(
        &stage,
        "?role=director&token=boss",
        "release.mjs",
        "640,360",
        &env,
        prepare,
    )
    .await;
    assert_eq!(run.summary["after"], 0, "{}", run.summary);
}
