//! The web renderer in headless Chromium against the real daemon: the page
//! loads, draws the puppet, and a synthetic drag deforms it (pixels change).
//! Needs Chromium and the Node packages of `tests/web`; `.ci/run` installs
//! them and sets `PUPPETRY_BROWSER_TESTS=1`. Without that variable the test
//! says so and does nothing, so `cargo test` works on a bare machine.

use std::path::PathBuf;
use std::process::Command;

use puppetry::serve::start;
use puppetry::stage::config::StageConfig;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_browser_drag_deforms_the_puppet() {
    if std::env::var_os("PUPPETRY_BROWSER_TESTS").is_none() {
        eprintln!(
            "skipped: set PUPPETRY_BROWSER_TESTS=1 (see .ci/run) to run the headless-browser test"
        );
        return;
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut config = StageConfig::load(&root.join("config/demo.toml")).unwrap();
    config.stage.listen = "127.0.0.1:0".parse().unwrap();
    let running = start(&config, root.join("clients/web"), None)
        .await
        .unwrap();
    let url = format!("http://{}/?role=performer&token=demo", running.address);
    let script = root.join("tests/web/drag.mjs");
    // The demo puppet's belly: on the puppet, between its pinned feet.
    let output = tokio::task::spawn_blocking(move || {
        Command::new("node")
            .arg(script)
            .env("PUPPETRY_URL", url)
            .env("PUPPETRY_POINT", "640,360")
            .output()
            .expect("node runs (install nodejs)")
    })
    .await
    .unwrap();
    running.shutdown().await;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        output.status.success(),
        "drag test failed:\n{stdout}\n{stderr}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(stdout.lines().last().unwrap_or("{}")).unwrap();
    assert_eq!(summary["ok"], true, "{stdout}");
    assert!(summary["changedPixels"].as_u64().unwrap() > 500, "{stdout}");
}
