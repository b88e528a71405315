//! The web renderer in headless Chromium against the real daemon: the page
//! loads, draws the puppet, and a synthetic drag deforms it (pixels change).
//! Also the record button and the keyframing pad. Runs only with
//! `PUPPETRY_BROWSER_TESTS=1` (see `tests/it/common/browser.rs`).

use crate::common::browser;

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
    let run = browser::run_page("demo", "record.mjs", "640,360", &[]).await;
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
    // The demo puppet's head.
    let summary = browser::run_page_script("demo", "keypad.mjs", "640,540").await;
    assert!(
        summary["changedPixels"].as_u64().unwrap() > 500,
        "{summary}"
    );
    assert!(summary["keyHandles"].as_u64().unwrap() > 0, "{summary}");
}
