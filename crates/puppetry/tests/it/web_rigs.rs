//! The web renderer draws both rigs (headless Chromium against the real
//! daemon on `config/grid.toml` and `config/skeleton.toml`, whose replays
//! play the rigs) and takes paint strokes. Like `tests/web.rs` it runs only
//! with `PUPPETRY_BROWSER_TESTS=1` (see `tests/common/browser.rs`).

use crate::common::browser;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_browser_draws_grids_and_skeletons() {
    if !browser::enabled("the_browser_draws_grids_and_skeletons") {
        return;
    }
    for stage in ["grid", "skeleton"] {
        let summary = browser::run_page_script(stage, "rigs.mjs", "640,360").await;
        assert_eq!(summary["kind"], stage, "{summary}");
    }
}
