//! Headless-Chromium page tests against the real daemon: start it on a stage
//! file from `config/`, run a script of `tests/web` against the page as a
//! performer, and read the script's one-line JSON summary. They run only
//! with `PUPPETRY_BROWSER_TESTS=1` (set by `.ci/run`, which installs
//! Chromium and the Node packages), so `cargo test` works on a bare machine.

use std::process::Command;

use puppetry_daemon::serve::start;
use puppetry_stage::config::StageConfig;

/// Whether browser tests are on. When they are not, says so where it is
/// seen: libtest hides a passing test's `eprintln!`, so this writes to the
/// process's stderr directly.
pub fn enabled(test: &str) -> bool {
    use std::io::Write;
    let on = std::env::var_os("PUPPETRY_BROWSER_TESTS").is_some();
    if !on {
        let _ = writeln!(
            std::io::stderr(),
            "browser test {test}: NOT RUN (set PUPPETRY_BROWSER_TESTS=1 with Chromium, Node and tests/web's packages installed; .ci/run does)"
        );
    }
    on
}

/// Serves `config/<stage>.toml` on a free port, runs `tests/web/<script>`
/// against it with the pointer at the stage point `point` ("x,y"), and
/// returns the script's summary once it has succeeded.
pub async fn run_page_script(stage: &str, script: &str, point: &str) -> serde_json::Value {
    let root = puppetry_testkit::root();
    let mut config = StageConfig::load(&root.join(format!("config/{stage}.toml"))).unwrap();
    config.stage.listen = "127.0.0.1:0".parse().unwrap();
    let running = start(&config, puppetry_daemon::stream::WebFiles::Embedded, None)
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
