//! Depth over the wire: when a performer folds the demo figure's arm over
//! its body, every client gets a depth frame (kind 4: one depth per
//! triangle, the part folded over nearer), a newcomer gets the newest one
//! at once, and letting go sends the mesh's own order back.

use futures_util::SinkExt;
use puppetry_daemon::protocol::{FrameKind, decode_frame};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::*;

/// Reads until a depth frame of puppet 0 satisfies `done`; its depths.
async fn depth_until(ws: &mut Client, done: impl Fn(&[u16]) -> bool) -> Vec<u16> {
    loop {
        if let Message::Binary(bytes) = next_message(ws).await {
            let frame = decode_frame(&bytes).expect("a well-formed frame");
            if frame.header.kind == FrameKind::Depth && done(&frame.depths) {
                return frame.depths;
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fold_sends_depth_frames_to_every_client() {
    let running = daemon("").await;
    let (mut performer, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let mesh = placed_mesh(&stage);
    let triangles = mesh.triangles().len();
    let hand = hand(&mesh);
    let contacts = |phase: &str, at: glam::DVec2| {
        json!({"type": "contacts", "contacts": [
            {"id": 1, "phase": if phase == "down" { "down" } else { "move" }, "x": 640.0, "y": 364.0},
            {"id": 2, "phase": phase, "x": at.x, "y": at.y}]})
    };
    // One finger holds the chest, the other drags the hand across it.
    let send = |m: serde_json::Value| Message::text(m.to_string());
    performer.send(send(contacts("down", hand))).await.unwrap();
    let to = glam::DVec2::new(610.0, 350.0);
    for step in 1..=12 {
        let at = hand.lerp(to, step as f64 / 12.0);
        performer.send(send(contacts("move", at))).await.unwrap();
    }
    let folded = depth_until(&mut viewer, |d| d.iter().any(|&v| v > 1)).await;
    assert_eq!(folded.len(), triangles);

    // A newcomer gets the newest depth at once.
    let (mut newcomer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let got = depth_until(&mut newcomer, |_| true).await;
    assert_eq!(got.len(), triangles);

    // Let go: the arm springs back and the depth is the mesh's order again
    // (one piece: every triangle at the same depth).
    performer
        .send(send(json!({"type": "contacts", "contacts": [
            {"id": 1, "phase": "up"}, {"id": 2, "phase": "up"}]})))
        .await
        .unwrap();
    let rest = depth_until(&mut viewer, |d| d.iter().all(|&v| v == d[0])).await;
    assert_eq!(rest.len(), triangles);
    running.shutdown().await;
}

/// The depth-layer brush over the wire: a performer may not paint depth, a
/// director's dab sends every client a depth frame with the layer under
/// the brush, and a bad layer is refused naming the field.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_director_paints_depth_layers_and_every_client_sees_them() {
    let running = daemon("").await;
    let (mut director, _) = connect(
        &running,
        json!({"type": "hello", "role": "director", "token": "boss"}),
    )
    .await;
    let (mut performer, _) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let dab = |layer: u32| {
        Message::text(
            json!({"type": "paint_depth", "puppet": 0, "x": 640.0, "y": 350.0,
                   "radius": 60.0, "layer": layer, "stroke": 1})
            .to_string(),
        )
    };
    performer.send(dab(3)).await.unwrap();
    loop {
        let m = next_text(&mut performer).await;
        if m["type"] == "error" {
            assert_eq!(m["code"], "forbidden", "{m}");
            break;
        }
    }
    director.send(dab(3)).await.unwrap();
    let painted = depth_until(&mut viewer, |d| d.contains(&3)).await;
    let threes = painted.iter().filter(|&&d| d == 3).count();
    assert!(threes > 10 && threes < painted.len() / 2, "{threes}");
    director.send(dab(40000)).await.unwrap();
    loop {
        let m = next_text(&mut director).await;
        if m["type"] == "error" {
            assert!(m["message"].as_str().unwrap().contains("layer"), "{m}");
            break;
        }
    }
    running.shutdown().await;
}
