//! The web renderer draws both rigs (headless Chromium against the real
//! daemon on `config/grid.toml` and `config/skeleton.toml`, whose replays
//! play the rigs) and curve puppets (`config/curve.toml`), and takes a director's paint strokes; pages opened later
//! show the skeleton's live key pose; roles, undo/redo/reset and the
//! replay toggle from the page. Like `tests/web.rs` it runs only with
//! Chromium (off only with `PUPPETRY_BROWSER_TESTS=0`) (see `tests/common/browser.rs`).

use crate::common::browser::{self, DIRECTOR, PERFORMER};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_browser_draws_grids_and_skeletons() {
    if !browser::enabled("the_browser_draws_grids_and_skeletons") {
        return;
    }
    for stage in ["grid", "skeleton"] {
        let summary = browser::run_page_as(stage, DIRECTOR, "rigs.mjs", "640,360", &[])
            .await
            .summary;
        assert_eq!(summary["kind"], stage, "{summary}");
    }
}

/// Issue 13: the curve stage's rope and ribbon are drawn as strokes of
/// their colours, and a mouse drag near the ribbon's end moves the stroke
/// under the pointer while its far end stays (`tests/web/curve.mjs`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_browser_draws_curve_puppets_and_a_drag_peels_one() {
    if !browser::enabled("the_browser_draws_curve_puppets_and_a_drag_peels_one") {
        return;
    }
    let summary = browser::run_page_as("curve", PERFORMER, "curve.mjs", "1110,300", &[])
        .await
        .summary;
    assert!(summary["farEndMoved"].as_f64().unwrap() <= 0.5, "{summary}");
}

/// Issue 12, observation 8 (page side): a performer sets the skeleton's
/// key pose slider to rest → crouch at 0.5; a viewer and a performer
/// opening the page afterwards show exactly that (before: rest → cheer at
/// 0), and follow the next move.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_opened_later_shows_the_live_key_pose() {
    if !browser::enabled("a_page_opened_later_shows_the_live_key_pose") {
        return;
    }
    let env = [("PUPPETRY_TOKEN", "ana")];
    let summary = browser::run_page_as("skeleton", PERFORMER, "pose.mjs", "640,360", &env)
        .await
        .summary;
    assert_eq!(summary["newcomers"]["viewer"]["to"], "crouch", "{summary}");
    assert_eq!(summary["newcomers"]["late"]["t"], 0.5, "{summary}");
}

/// Roles and safe edits from the page, on the skeleton stage: the director
/// has the director's tools, a performer only the performer's, a viewer
/// none; the director's paint stroke is one undo step on every page; the
/// performer undoes, redoes and resets it; the director pauses and plays
/// the stage's replay (issue 12, observation 9's replay that fought the
/// performer).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn roles_undo_and_the_replay_toggle_work_from_the_page() {
    if !browser::enabled("roles_undo_and_the_replay_toggle_work_from_the_page") {
        return;
    }
    let env = [("PUPPETRY_TOKEN", "ana"), ("PUPPETRY_DIRECTOR", "director")];
    let summary = browser::run_page_as("skeleton", "", "edits.mjs", "640,360", &env)
        .await
        .summary;
    assert_eq!(summary["replay"]["name"], "skeleton-play", "{summary}");
}
