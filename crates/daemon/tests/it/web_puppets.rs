//! Puppets added, reordered and removed at runtime from the director's page
//! (headless Chromium against the real daemon on `config/demo.toml`): the
//! Puppets panel uploads a PNG that every page then shows, warns about a
//! fully opaque picture, says why a file that is not a PNG was refused,
//! and moves and removes puppets for every page. Like `web.rs` it runs
//! only with Chromium (off only with `PUPPETRY_BROWSER_TESTS=0`) (see `common/browser.rs`).

use crate::common::browser::{self, DIRECTOR};

/// The director adds a cut-out figure at 300 vertices (every page gets
/// it, drawn where the stage message puts it), then a fully opaque picture
/// (added, with the warning shown on the page) and a text file named .png
/// (refused, `bad_image`, shown on the page); moves the figure down and
/// removes both, after a dismissed confirm removed nothing. A performer
/// has no panel and its upload is forbidden.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_director_adds_reorders_and_removes_puppets_from_the_page() {
    if !browser::enabled("a_director_adds_reorders_and_removes_puppets_from_the_page") {
        return;
    }
    let env = [("PUPPETRY_TOKEN", "ana")];
    let summary = browser::run_page_as("demo", DIRECTOR, "puppets.mjs", "640,360", &env)
        .await
        .summary;
    let vertices = summary["added"]["vertices"].as_u64().unwrap();
    assert!((255..=345).contains(&vertices), "{summary}");
    assert_eq!(summary["added"]["name"], "figure", "{summary}");
    assert_eq!(summary["badImage"]["code"], "bad_image", "{summary}");
    assert_eq!(summary["performerUpload"]["code"], "forbidden", "{summary}");
    assert_eq!(summary["after"], summary["before"], "{summary}");
    // Issue 45: a picture in two pieces said so, and joined into one.
    assert_eq!(summary["split"]["pieces"], 2, "{summary}");
    assert_eq!(summary["joined"]["pieces"], 1, "{summary}");
}
