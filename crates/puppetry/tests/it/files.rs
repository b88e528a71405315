//! Files the daemon and the command line write and read, when they go
//! wrong: a file-size limit (`ulimit -f`) stops the take with its error
//! instead of killing the daemon with SIGXFSZ, and `takes --verify` fails,
//! saying where, on a take damaged mid-file instead of answering "replays
//! exactly" for the part before the damage.

use std::path::Path;

use futures_util::SinkExt;
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::{PLAYS, WAIT, looping_capture, next_text, stage_text};
use crate::common::served::Served;

/// Serves a looping replay recording into `takes` under `ulimit -f KB`
/// set by `sh`, which leaves SIGXFSZ at its default (terminate): only the
/// daemon itself can ignore it.
fn serve_under_file_limit(dir: &Path, kb: u32) -> Served {
    let stage = dir.join("stage.toml");
    std::fs::write(&stage, stage_text(&looping_capture())).unwrap();
    let script = format!(
        "ulimit -f {kb}; exec '{bin}' serve --config '{stage}' --record '{takes}'",
        bin = env!("CARGO_BIN_EXE_puppetry"),
        stage = stage.display(),
        takes = dir.join("takes").display(),
    );
    let mut sh = std::process::Command::new("sh");
    sh.arg("-c").arg(script);
    Served::start(sh)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_file_size_limit_stops_the_take_and_the_daemon_lives() {
    let dir = tempfile::tempdir().unwrap();
    let mut daemon = serve_under_file_limit(dir.path(), 64);
    let (mut ws, _) = tokio_tungstenite::connect_async(daemon.ws_url())
        .await
        .unwrap();
    ws.send(Message::text(
        json!({"type": "hello", "role": "viewer"}).to_string(),
    ))
    .await
    .unwrap();
    // Before the fix the daemon died of SIGXFSZ (exit 153) at the limit
    // and this never came.
    let error = tokio::time::timeout(PLAYS, async {
        loop {
            let m = next_text(&mut ws).await;
            if m["type"] == "take"
                && let Some(error) = m["error"].as_str()
            {
                return error.to_string();
            }
        }
    })
    .await
    .expect("the take's error reached the page");
    assert!(error.to_lowercase().contains("file too large"), "{error}");
    // Still serving, still alive.
    tokio::time::timeout(WAIT, async {
        let mut frames = 0;
        while frames < 5 {
            if let Message::Binary(_) = crate::common::daemon::next_message(&mut ws).await {
                frames += 1;
            }
        }
    })
    .await
    .expect("frames after the take stopped");
    assert!(daemon.alive(), "the daemon exited");
}
