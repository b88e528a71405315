//! The daemon's memory per viewer (issue 12, observation 7): the binary
//! serving the demo puppet, 200 viewers connected and reading while a
//! performer drags, the daemon's resident set read from `/proc` before and
//! after. Not part of the suite (it measures, and 200 sockets are a load):
//!
//!     cargo test --release -p puppetry --test it memory -- --ignored --nocapture
//!
//! `PUPPETRY_MEMORY_BIN=/path/to/puppetry` measures another build (one from
//! before `access.max_per_address` existed, say).

use crate::common::daemon::*;
use crate::common::served::Served;

use futures_util::{SinkExt, StreamExt};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

const VIEWERS: usize = 200;

/// The director of the test stage, which older builds do not read.
const PEOPLE: &str =
    "[[access.person]]\nname = \"Director\"\nrole = \"director\"\ntoken = \"boss\"\n";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement: run it with --ignored --nocapture"]
async fn memory_per_viewer_at_200_viewers() {
    let other = std::env::var("PUPPETRY_MEMORY_BIN").ok();
    let idle = std::env::var("PUPPETRY_MEMORY_IDLE").is_ok();
    let bin = other
        .clone()
        .unwrap_or_else(|| env!("CARGO_BIN_EXE_puppetry").to_string());
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("stage.toml");
    let mut text = stage_text("");
    match other {
        // All the viewers come from 127.0.0.1.
        None => text = text.replace("[access]\n", "[access]\nmax_per_address = 1000\n"),
        // A build from before named people.
        Some(_) => text = text.replace(PEOPLE, ""),
    }
    std::fs::write(&stage, text).unwrap();
    let mut command = std::process::Command::new(&bin);
    command.args(["serve", "--config"]).arg(&stage);
    let daemon = Served::start(command);
    let url = daemon.ws_url();
    let hello = |role: &str| json!({"type": "hello", "role": role, "token": "secret"}).to_string();

    // Each viewer reads everything it is sent until told to stop.
    let stop = std::sync::Arc::new(tokio::sync::Notify::new());
    let mut readers = Vec::new();
    let mut connect_viewer = async || {
        let (mut ws, _) = tokio_tungstenite::connect_async(url.as_str())
            .await
            .unwrap();
        ws.send(Message::text(hello("viewer"))).await.unwrap();
        let Some(Ok(Message::Text(_))) = ws.next().await else {
            panic!("no stage message");
        };
        let stop = stop.clone();
        readers.push(tokio::spawn(async move {
            if idle {
                // Reads nothing more: what a stalled page costs.
                stop.notified().await;
                return;
            }
            let stopped = stop.notified();
            tokio::pin!(stopped);
            loop {
                tokio::select! {
                    _ = &mut stopped => return,
                    m = ws.next() => if !matches!(m, Some(Ok(_))) { return },
                }
            }
        }));
    };
    let (mut performer, stage) =
        connect_url(&url, serde_json::from_str(&hello("performer")).unwrap()).await;
    let grab = hand(&placed_mesh(&stage));
    println!(
        "stage message: {} bytes, {} vertices",
        stage.to_string().len(),
        placed_mesh(&stage).vertices().len()
    );
    let drag = async |ws: &mut Client, steps: usize| {
        for k in 0..steps {
            let phase = if k == 0 { "down" } else { "move" };
            let at = grab + glam::DVec2::new(0.0, (k % 40) as f64);
            let m = json!({"type": "contacts", "contacts": [{"id": 1, "phase": phase, "x": at.x, "y": at.y}]});
            ws.send(Message::text(m.to_string())).await.unwrap();
            tokio::time::sleep(std::time::Duration::from_millis(2)).await;
        }
        let up = json!({"type": "contacts", "contacts": [{"id": 1, "phase": "up"}]});
        ws.send(Message::text(up.to_string())).await.unwrap();
    };
    connect_viewer().await;
    drag(&mut performer, 200).await;
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let before = daemon.rss_kib();
    for _ in 1..VIEWERS {
        connect_viewer().await;
    }
    drag(&mut performer, 500).await;
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let after = daemon.rss_kib();
    let per_viewer = (after.saturating_sub(before)) as f64 / (VIEWERS - 1) as f64;
    println!(
        "daemon RSS: {before} KiB with 1 viewer, {after} KiB with {VIEWERS}: {:.3} MB per viewer",
        per_viewer / 1024.0
    );
    stop.notify_waiters();
    for r in readers {
        let _ = r.await;
    }
}
