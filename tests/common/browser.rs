//! Headless-Chromium page tests against the real daemon: start it on a stage
//! file from `config/`, run a script of `tests/web` against the page as a
//! performer, and read the script's one-line JSON summary. They run only
//! with `PUPPETRY_BROWSER_TESTS=1` (set by `.ci/run`, which installs
//! Chromium and the Node packages), so `cargo test` works on a bare machine.

use std::path::PathBuf;
use std::process::Command;

use puppetry::serve::start;
use puppetry::stage::config::StageConfig;

/// Whether browser tests are on; says how to turn them on when they are not.
pub fn enabled() -> bool {
    let on = std::env::var_os("PUPPETRY_BROWSER_TESTS").is_some();
    if !on {
        eprintln!(
            "skipped: set PUPPETRY_BROWSER_TESTS=1 (see .ci/run) to run the headless-browser test"
        );
    }
    on
}

/// Serves `config/<stage>.toml` on a free port, runs `tests/web/<script>`
/// against it with the pointer at the stage point `point` ("x,y"), and
/// returns the script's summary once it has succeeded.
pub async fn run_page_script(stage: &str, script: &str, point: &str) -> serde_json::Value {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut config = StageConfig::load(&root.join(format!("config/{stage}.toml"))).unwrap();
    config.stage.listen = "127.0.0.1:0".parse().unwrap();
    let running = start(&config, root.join("clients/web"), None)
        .await
        .unwrap();
    let url = format!("http://{}/?role=performer&token=demo", running.address);
    let script = root.join("tests/web").join(script);
    let point = point.to_string();
    let output = tokio::task::spawn_blocking(move || {
        Command::new("node")
            .arg(script)
            .env("PUPPETRY_URL", url)
            .env("PUPPETRY_POINT", point)
            .output()
            .expect("node runs (install nodejs)")
    })
    .await
    .unwrap();
    running.shutdown().await;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stage}: {stdout}\n{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(stdout.lines().last().unwrap_or("{}")).unwrap();
    assert_eq!(summary["ok"], true, "{stdout}");
    summary
}
