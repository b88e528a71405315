//! The web renderer in headless Chromium against the real daemon: the page
//! loads, draws the puppet, and a synthetic drag deforms it (pixels change).
//! Runs only with `PUPPETRY_BROWSER_TESTS=1` (see `tests/common/browser.rs`).

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
