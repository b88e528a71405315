//! The web renderer draws both rigs (headless Chromium against the real
//! daemon on `config/grid.toml` and `config/skeleton.toml`, whose replays
//! play the rigs) and takes paint strokes. Like `tests/web.rs` it runs only
//! with `PUPPETRY_BROWSER_TESTS=1` and the Node packages of `tests/web`.

use std::path::PathBuf;
use std::process::Command;

use puppetry::serve::start;
use puppetry::stage::config::StageConfig;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_browser_draws_grids_and_skeletons() {
    if std::env::var_os("PUPPETRY_BROWSER_TESTS").is_none() {
        eprintln!(
            "skipped: set PUPPETRY_BROWSER_TESTS=1 (see .ci/run) to run the headless-browser test"
        );
        return;
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    for stage in ["grid", "skeleton"] {
        let mut config = StageConfig::load(&root.join(format!("config/{stage}.toml"))).unwrap();
        config.stage.listen = "127.0.0.1:0".parse().unwrap();
        let running = start(&config, root.join("clients/web"), None)
            .await
            .unwrap();
        let url = format!("http://{}/?role=performer&token=demo", running.address);
        let script = root.join("tests/web/rigs.mjs");
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
        assert!(output.status.success(), "{stage}: {stdout}\n{stderr}");
        let summary: serde_json::Value =
            serde_json::from_str(stdout.lines().last().unwrap_or("{}")).unwrap();
        assert_eq!(summary["ok"], true, "{stdout}");
        assert_eq!(summary["kind"], stage, "{stdout}");
    }
}
