//! Headless-Chromium page tests against the real daemon: start it on a stage
//! file from `config/`, run a script of `tests/web` against the page as a
//! performer, a director or a viewer, and read the script's one-line JSON
//! summary. They need Debian's Chromium, Node and `tests/web`'s packages
//! (`.ci/run` installs them) and fail saying what to install when one is
//! missing; `PUPPETRY_BROWSER_TESTS=0` turns them off on purpose.

use std::path::{Path, PathBuf};
use std::process::Command;

use puppetry_daemon::config::ShowConfig;
use puppetry_daemon::serve::{Options, start_with};
use puppetry_daemon::stream::WebFiles;

/// Whether browser tests are on (always, unless `PUPPETRY_BROWSER_TESTS=0`).
/// When they are not, says so where it is seen: libtest hides a passing
/// test's `eprintln!`, so this writes to the process's stderr directly.
pub fn enabled(test: &str) -> bool {
    use std::io::Write;
    // On unless turned off on purpose: a machine without Chromium or Node
    // fails these tests saying what to install, it does not pass them.
    let off = std::env::var_os("PUPPETRY_BROWSER_TESTS").is_some_and(|v| v == "0");
    if off {
        let _ = writeln!(
            std::io::stderr(),
            "browser test {test}: NOT RUN (PUPPETRY_BROWSER_TESTS=0 turns the headless-Chromium tests off)"
        );
    }
    !off
}

/// What a page script ran against, kept for the test to look at.
pub struct PageRun {
    /// The script's summary (it succeeded).
    pub summary: serde_json::Value,
    /// The daemon's takes folder: a fresh temporary one, so takes recorded
    /// from the page never land in the source tree; removed when dropped.
    pub takes: tempfile::TempDir,
}

/// The page's address (after the server's) for an anonymous performer of
/// the bundled stages.
pub const PERFORMER: &str = "?role=performer&token=demo";

/// The page's address for the bundled stages' director (who records,
/// paints, saves and edits key poses).
pub const DIRECTOR: &str = "?role=director&token=director";

/// Serves `config/<stage>.toml` on a free port, runs `tests/web/<script>`
/// against it as a performer with the pointer at the stage point `point`
/// ("x,y"), and returns the script's summary once it has succeeded.
pub async fn run_page_script(stage: &str, script: &str, point: &str) -> serde_json::Value {
    run_page(stage, script, point, &[]).await.summary
}

/// As [`run_page_script`], with extra environment variables for the script,
/// and the takes folder kept for the caller.
pub async fn run_page(stage: &str, script: &str, point: &str, env: &[(&str, &str)]) -> PageRun {
    run_page_as(stage, PERFORMER, script, point, env).await
}

/// As [`run_page`], with the page's address `query` (`PERFORMER`,
/// `DIRECTOR`, `""` for a viewer) in the script's `PUPPETRY_URL`.
pub async fn run_page_as(
    stage: &str,
    query: &str,
    script: &str,
    point: &str,
    env: &[(&str, &str)],
) -> PageRun {
    let root = puppetry_testkit::root();
    run_page_on(
        &root.join(format!("config/{stage}.toml")),
        query,
        script,
        point,
        env,
    )
    .await
}

/// As [`run_page_as`], on the stage file at `stage` (anywhere).
pub async fn run_page_on(
    stage: &Path,
    query: &str,
    script: &str,
    point: &str,
    env: &[(&str, &str)],
) -> PageRun {
    run_page_prepared(stage, query, script, point, env, async |_| {}).await
}

/// As [`run_page_on`], with `prepare` done to the running daemon before
/// the script starts (a device's datagram sent, say).
pub async fn run_page_prepared(
    stage: &Path,
    query: &str,
    script: &str,
    point: &str,
    env: &[(&str, &str)],
    prepare: impl AsyncFnOnce(&puppetry_daemon::serve::Running),
) -> PageRun {
    let root = puppetry_testkit::root();
    let node_modules = root.join("tests/web/node_modules");
    check_tools(&node_modules);
    let mut config = ShowConfig::load(stage).unwrap();
    config.stage.listen = "127.0.0.1:0".parse().unwrap();
    let takes = tempfile::tempdir().unwrap();
    let mut options = Options::new(WebFiles::Embedded);
    options.takes_dir = takes.path().to_path_buf();
    options.puppets_dir = takes.path().join("puppets");
    let running = start_with(&config, options).await.unwrap();
    prepare(&running).await;
    let url = format!("http://{}/{query}", running.address);
    let script = root.join("tests/web").join(script);
    let point = point.to_string();
    let env: Vec<(String, String)> = env
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let output = tokio::task::spawn_blocking(move || {
        Command::new("node")
            .arg(script)
            .env("PUPPETRY_URL", url)
            .env("PUPPETRY_POINT", point)
            .envs(env)
            .output()
            .expect("node runs (install Node.js: apt-get install nodejs)")
    })
    .await
    .unwrap();
    running.shutdown().await;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        output.status.success(),
        "{}: {stdout}\n{stderr}",
        stage.display()
    );
    let summary: serde_json::Value =
        serde_json::from_str(stdout.lines().last().unwrap_or("{}")).unwrap();
    assert_eq!(summary["ok"], true, "{stdout}");
    PageRun { summary, takes }
}

/// What browser tests need, missing, is a failure that says
/// what to install (rather than a launch error deep in a script).
fn check_tools(node_modules: &Path) {
    let node = Command::new("node").arg("--version").output();
    assert!(
        node.as_ref().is_ok_and(|o| o.status.success()),
        "browser tests need Node.js, which does not run ({node:?}): install it (apt-get install nodejs npm)"
    );
    let chromium = std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    assert!(
        chromium.is_file(),
        "browser tests need Chromium, and there is none at {}: install it (apt-get install chromium), set CHROMIUM to its path, or turn them off with PUPPETRY_BROWSER_TESTS=0",
        chromium.display()
    );
    assert!(
        node_modules.join("playwright-core").is_dir(),
        "browser tests need playwright-core, and {} has none: run `npm install` in tests/web",
        node_modules.display()
    );
}
