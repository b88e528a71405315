//! The daemon end to end on 127.0.0.1:0: performers drag the puppet over
//! WebSocket and every client sees the same frames as a direct solve; two
//! performers stay apart; bad clients are refused without harm; a stalled
//! client slows nobody; replays drive it; shutdown is clean.

use crate::common::daemon::*;

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use glam::DVec2;
use puppetry_deform::{Anchor, Arap, Steps};
use puppetry_input::replay::{Pacing, ReplaySource};
use puppetry_input::{Calibration, CalibrationSpec, SourceId};
use puppetry_mesh::{Locator, Mesh};
use serde_json::{Value, json};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

/// What `puppetry solve` gives for these rest points held at these targets.
fn direct_solve(mesh: &Mesh, holds: &[(DVec2, DVec2)]) -> Vec<DVec2> {
    let locator = Locator::new(mesh);
    let anchors: Vec<Anchor> = holds
        .iter()
        .map(|(p, _)| {
            let l = locator.locate(mesh, *p).expect("on the puppet");
            Anchor::Point {
                triangle: l.triangle,
                bary: l.bary,
            }
        })
        .collect();
    let targets: Vec<DVec2> = holds.iter().map(|h| h.1).collect();
    let mut arap = Arap::register(mesh).unwrap();
    arap.compile(&anchors).unwrap();
    arap.update(&targets, Steps::Both).unwrap().to_vec()
}

fn pins_on_stage(stage: &Value) -> Vec<DVec2> {
    stage["puppets"][0]["handles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| DVec2::new(h["at"][0].as_f64().unwrap(), h["at"][1].as_f64().unwrap()))
        .collect()
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

fn contacts(list: Value) -> Message {
    Message::text(json!({"type": "contacts", "contacts": list}).to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_performer_drag_equals_the_direct_solve() {
    let running = daemon("").await;
    let (mut performer, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    assert_eq!(stage["type"], "stage");
    assert_eq!(stage["role"], "performer");
    let mesh = placed_mesh(&stage);
    let pins = pins_on_stage(&stage);
    assert_eq!(pins.len(), 2, "the two feet are pinned from the start");
    let grab = hand(&mesh);
    let to = grab + DVec2::new(-20.0, 90.0);
    performer
        .send(contacts(
            json!([{"id": 7, "phase": "down", "x": grab.x, "y": grab.y}]),
        ))
        .await
        .unwrap();
    for k in 1..=10 {
        let p = grab + (to - grab) * (k as f64 / 10.0);
        performer
            .send(contacts(
                json!([{"id": 7, "phase": "move", "x": p.x, "y": p.y}]),
            ))
            .await
            .unwrap();
    }
    let expected = direct_solve(&mesh, &[(pins[0], pins[0]), (pins[1], pins[1]), (grab, to)]);
    let frame = frame_until(&mut performer, |f| {
        max_distance(&f.vertices, &expected) < 1e-2
    })
    .await;
    assert_eq!(frame.puppet, 0);
    assert!(
        max_distance(&frame.vertices, mesh.vertices()) > 50.0,
        "the hand moved"
    );
    // A viewer connecting now gets the same newest frame.
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let seen = frame_until(&mut viewer, |_| true).await;
    assert!(max_distance(&seen.vertices, &expected) < 1e-2);
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_performers_hold_two_handles_apart() {
    let running = daemon("").await;
    let hello = json!({"type": "hello", "role": "performer", "token": "secret"});
    let (mut a, stage) = connect(&running, hello.clone()).await;
    let (mut b, _) = connect(&running, hello).await;
    let mesh = placed_mesh(&stage);
    let pins = pins_on_stage(&stage);
    let grab_a = hand(&mesh);
    let head = mesh
        .vertices()
        .iter()
        .copied()
        .fold(DVec2::splat(f64::NEG_INFINITY), |a, b| {
            if b.y > a.y { b } else { a }
        });
    let grab_b = head - DVec2::new(0.0, 15.0);
    // Both use contact id 1: the daemon must keep them apart.
    a.send(contacts(
        json!([{"id": 1, "phase": "down", "x": grab_a.x, "y": grab_a.y}]),
    ))
    .await
    .unwrap();
    b.send(contacts(
        json!([{"id": 1, "phase": "down", "x": grab_b.x, "y": grab_b.y}]),
    ))
    .await
    .unwrap();
    // Nothing orders messages across two connections: B's grab may be
    // applied after A's move, and would then hold the already-moved mesh at
    // another rest point. The daemon promises only that both grabs show in
    // a handles message; wait for that before moving.
    until_contact_owners(&mut a, |owners| owners.len() == 2).await;
    let to_a = grab_a + DVec2::new(0.0, 60.0);
    let to_b = grab_b + DVec2::new(-40.0, 0.0);
    a.send(contacts(
        json!([{"id": 1, "phase": "move", "x": to_a.x, "y": to_a.y}]),
    ))
    .await
    .unwrap();
    b.send(contacts(
        json!([{"id": 1, "phase": "move", "x": to_b.x, "y": to_b.y}]),
    ))
    .await
    .unwrap();
    let expected = direct_solve(
        &mesh,
        &[
            (pins[0], pins[0]),
            (pins[1], pins[1]),
            (grab_a, to_a),
            (grab_b, to_b),
        ],
    );
    frame_until(&mut a, |f| max_distance(&f.vertices, &expected) < 1e-2).await;
    // The handles message names two different owners for the contacts.
    let owners = loop {
        let m = next_text(&mut b).await;
        if m["type"] == "handles" {
            let owners = contact_owners(&m);
            if owners.len() == 2 {
                break owners;
            }
        }
    };
    assert_ne!(owners[0], owners[1]);
    // When one performer leaves, its contact is let go; the other stays.
    drop(a);
    let expected = direct_solve(
        &mesh,
        &[(pins[0], pins[0]), (pins[1], pins[1]), (grab_b, to_b)],
    );
    frame_until(&mut b, |f| max_distance(&f.vertices, &expected) < 1e-2).await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_clients_are_refused_and_the_server_keeps_running() {
    let running = daemon("").await;
    // Wrong token: an error, then the connection closes.
    let (_, refused) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "nope"}),
    )
    .await;
    assert_eq!(refused["type"], "error");
    // No hello first: refused too.
    let (_, refused) = connect(&running, json!({"type": "contacts", "contacts": []})).await;
    assert_eq!(refused["type"], "error");
    // A viewer may not send input.
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    viewer
        .send(contacts(
            json!([{"id": 1, "phase": "down", "x": 640, "y": 360}]),
        ))
        .await
        .unwrap();
    let reply = loop {
        let m = next_text(&mut viewer).await;
        if m["type"] == "error" {
            break m;
        }
    };
    assert!(reply["message"].as_str().unwrap().contains("viewer"));
    // Malformed messages get errors; after enough of them, a close.
    let hello = json!({"type": "hello", "role": "performer", "token": "secret"});
    let (mut abuser, _) = connect(&running, hello.clone()).await;
    let mut errors = 0;
    for _ in 0..puppetry_daemon::stream::MAX_BAD_MESSAGES {
        abuser.send(Message::text("{not json")).await.unwrap();
    }
    let closed = loop {
        match tokio::time::timeout(WAIT, abuser.next())
            .await
            .expect("in time")
        {
            Some(Ok(Message::Text(t))) if t.contains("error") => errors += 1,
            Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break true,
            Some(Ok(_)) => {}
        }
    };
    assert!(closed && errors >= 1);
    // An oversized message ends that connection only.
    let (mut big, _) = connect(&running, hello.clone()).await;
    let _ = big
        .send(Message::text(
            "x".repeat(puppetry_daemon::stream::MAX_CLIENT_MESSAGE + 10),
        ))
        .await;
    // The server still serves a good client.
    let (mut good, stage) = connect(&running, hello).await;
    assert_eq!(stage["type"], "stage");
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    good.send(contacts(
        json!([{"id": 3, "phase": "down", "x": grab.x, "y": grab.y}]),
    ))
    .await
    .unwrap();
    good.send(contacts(
        json!([{"id": 3, "phase": "move", "x": grab.x, "y": grab.y + 30.0}]),
    ))
    .await
    .unwrap();
    frame_until(&mut good, |f| f.sequence >= 2).await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_client_slows_no_one() {
    let running = daemon("").await;
    let hello = json!({"type": "hello", "role": "performer", "token": "secret"});
    // This client says hello and then never reads again.
    let url = format!("ws://{}/ws", running.address);
    let (mut stalled, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    stalled
        .send(Message::text(
            json!({"type": "hello", "role": "viewer"}).to_string(),
        ))
        .await
        .unwrap();
    let (mut performer, stage) = connect(&running, hello).await;
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    performer
        .send(contacts(
            json!([{"id": 1, "phase": "down", "x": grab.x, "y": grab.y}]),
        ))
        .await
        .unwrap();
    // Far more frame bytes than the stalled socket can buffer.
    let moves = 400;
    let mut last = grab;
    for k in 0..moves {
        last = grab + DVec2::new((k as f64 * 0.1).sin() * 30.0, (k % 50) as f64);
        performer
            .send(contacts(
                json!([{"id": 1, "phase": "move", "x": last.x, "y": last.y}]),
            ))
            .await
            .unwrap();
        // Keep reading, as a live renderer does.
        while let Ok(Some(_)) =
            tokio::time::timeout(Duration::from_millis(1), performer.next()).await
        {}
    }
    // One last move, whose frame the fast client must still get.
    last += DVec2::new(0.0, 7.0);
    performer
        .send(contacts(
            json!([{"id": 1, "phase": "move", "x": last.x, "y": last.y}]),
        ))
        .await
        .unwrap();
    let pins = pins_on_stage(&stage);
    let expected = direct_solve(
        &mesh,
        &[(pins[0], pins[0]), (pins[1], pins[1]), (grab, last)],
    );
    frame_until(&mut performer, |f| {
        max_distance(&f.vertices, &expected) < 1e-2
    })
    .await;
    drop(stalled);
    running.shutdown().await;
}

/// A connection with nothing new to send sleeps: it wakes for changes,
/// not for a feed that can never change (a daemon's relay notices).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_connection_does_not_wake() {
    let running = daemon("").await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    // The newcomer's state, then quiet: no input runs on this stage.
    frame_until(&mut viewer, |_| true).await;
    let sends = || {
        running
            .timings()
            .sends
            .load(std::sync::atomic::Ordering::Relaxed)
    };
    let before = sends();
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let after = sends();
    assert!(
        after - before <= 2,
        "an idle connection woke {} times in half a second",
        after - before
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_is_clean_and_frees_the_port() {
    let running = daemon("").await;
    let address = running.address;
    let (_viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    tokio::time::timeout(WAIT, running.shutdown())
        .await
        .expect("shutdown in time");
    assert!(
        TcpStream::connect(address).await.is_err(),
        "nothing listens after shutdown"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_serves_the_page_and_the_picture() {
    let running = daemon("").await;
    let get = |path: &'static str| http_get(running.address, path);
    let page = get("/").await;
    assert!(
        page.starts_with(b"HTTP/1.1 200"),
        "{}",
        String::from_utf8_lossy(&page[..40.min(page.len())])
    );
    let picture = get("/puppets/0/texture.png").await;
    assert!(picture.starts_with(b"HTTP/1.1 200") && picture.windows(4).any(|w| w == b"\x89PNG"));
    assert!(get("/../Cargo.toml").await.starts_with(b"HTTP/1.1 404"));
    assert!(
        get("/puppets/9/texture.png")
            .await
            .starts_with(b"HTTP/1.1 404")
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replay_drives_the_puppet_to_the_direct_solve() {
    // Learn where the puppet is, then record a drag on it.
    let probe = daemon("").await;
    let (_, stage) = connect(&probe, json!({"type": "hello", "role": "viewer"})).await;
    probe.shutdown().await;
    let mesh = placed_mesh(&stage);
    let pins = pins_on_stage(&stage);
    let grab = hand(&mesh);
    let to = grab + DVec2::new(10.0, 80.0);
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("drag.jsonl");
    let mut lines = vec![
        json!({"t": 0.0, "source": "table", "contacts": [{"id": 4, "phase": "down", "x": grab.x, "y": grab.y}]}),
    ];
    for k in 1..=30 {
        let p = grab + (to - grab) * (k as f64 / 30.0);
        lines.push(json!({"t": k as f64 * 0.001, "source": "table", "contacts": [{"id": 4, "phase": "move", "x": p.x, "y": p.y}]}));
    }
    // The finger stays there (a replay that ends lets go of what it held).
    lines.push(json!({"t": 600.0, "source": "table", "contacts": [{"id": 4, "phase": "up", "x": to.x, "y": to.y}]}));
    let text: String = lines.iter().map(|l| format!("{l}\n")).collect();
    std::fs::write(&recording, text).unwrap();
    let extra = format!(
        "[[input]]\nkind = \"replay\"\nfile = \"{}\"\n",
        recording.display()
    );
    let running = daemon(&extra).await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let expected = direct_solve(&mesh, &[(pins[0], pins[0]), (pins[1], pins[1]), (grab, to)]);
    frame_until(&mut viewer, |f| max_distance(&f.vertices, &expected) < 1e-2).await;
    running.shutdown().await;
}

/// Issue 45: a recording that ends with a finger down (a capture cut
/// short, a FIFO whose writer went away) left the puppet held for ever:
/// its frames name their own source, not the replay input's. Whatever a
/// replay left down lifts when it ends.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replay_that_ends_mid_touch_lets_go() {
    let probe = daemon("").await;
    let (_, stage) = connect(&probe, json!({"type": "hello", "role": "viewer"})).await;
    probe.shutdown().await;
    let grab = hand(&placed_mesh(&stage));
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("cut.jsonl");
    // Nothing for two seconds (the viewer connects), a finger held for
    // one, and the file ends.
    let lines = [
        json!({"t": 0.0, "source": "table", "contacts": []}),
        json!({"t": 2.0, "source": "table", "contacts": [{"id": 4, "phase": "down", "x": grab.x, "y": grab.y}]}),
        json!({"t": 3.0, "source": "table", "contacts": [{"id": 4, "phase": "move", "x": grab.x, "y": grab.y + 20.0}]}),
    ];
    let text: String = lines.iter().map(|l| format!("{l}\n")).collect();
    std::fs::write(&recording, text).unwrap();
    let extra = format!(
        "[[input]]\nkind = \"replay\"\nfile = \"{}\"\nname = \"cut\"\n",
        recording.display()
    );
    let running = daemon(&extra).await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    until_contact_owners(&mut viewer, |o| o == ["table"]).await;
    until_contact_owners(&mut viewer, |o| o.is_empty()).await;
    running.shutdown().await;
}

/// Plays a capture into the demo daemon, calibrated onto the puppet's
/// belly (device range `0..=range` on both axes), through the same decoder
/// a live device uses, until a viewer has seen its touches grab the puppet
/// and then only the stage file's two pins hold it: no contact is left
/// stuck. Returns whether frames were solved for the touches.
///
/// The capture plays at its own pace, over and over with a rest between,
/// once the viewer is connected: every state the viewer must see lasts long
/// enough to be published on a loaded machine, and a play it missed is
/// followed by another.
async fn a_capture_grabs_and_lets_go(capture: &std::path::Path, range: f64) -> bool {
    let running = daemon("").await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let calibration = Calibration::new(CalibrationSpec::Range {
        x: [0.0, range],
        y: [0.0, range],
        flip_y: true,
        stage_min: [590.0, 320.0],
        stage_max: [690.0, 400.0],
    })
    .unwrap();
    let performance = async {
        loop {
            let source = ReplaySource::open_with(
                capture,
                SourceId::from("table"),
                DVec2::new(1280.0, 720.0),
                Some(calibration.clone()),
            )
            .unwrap();
            running.play(source, Pacing::RealTime).await;
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
    };
    let watch = async {
        let mut solved_for_touches = false;
        let mut table_handles_seen = false;
        loop {
            match next_message(&mut viewer).await {
                Message::Binary(bytes) => {
                    // Sequence 1 is the pins' solve at start.
                    // (Any kind: rig and handles frames share the solve's.)
                    let header = puppetry_daemon::protocol::decode_frame(&bytes)
                        .unwrap()
                        .header;
                    solved_for_touches |= header.sequence > 1;
                }
                Message::Text(text) => {
                    let m: Value = serde_json::from_str(&text).unwrap();
                    if m["type"] != "handles" {
                        continue;
                    }
                    let handles = m["handles"].as_array().unwrap();
                    table_handles_seen |= handles.iter().any(|h| h["owner"] == "table");
                    if table_handles_seen
                        && handles.len() == 2
                        && handles.iter().all(|h| h["kind"] == "pin")
                    {
                        return solved_for_touches;
                    }
                }
                _ => {}
            }
        }
    };
    let solved = tokio::time::timeout(PLAYS, async {
        tokio::select! {
            () = performance => unreachable!("plays until the viewer has seen it all"),
            solved = watch => solved,
        }
    })
    .await
    .expect("touches seen down and lifted within the plays' time");
    running.shutdown().await;
    solved
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_real_touch_capture_drives_the_puppet_and_leaves_no_stuck_contact() {
    // The eGalax capture (multi-touch protocol B).
    let capture = root().join("../shared/fixtures/evemu/wetab.event");
    assert!(
        a_capture_grabs_and_lets_go(&capture, 32760.0).await,
        "the capture's touches were solved"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn performers_pin_and_unpin() {
    let running = daemon("").await;
    let (mut performer, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    let handles_where = |m: &Value, kind: &str| -> Vec<Value> {
        m["handles"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|h| h["kind"] == kind)
            .cloned()
            .collect()
    };
    // A pin on the hand, owned by this client.
    performer
        .send(Message::text(
            json!({"type": "pin", "x": grab.x, "y": grab.y}).to_string(),
        ))
        .await
        .unwrap();
    let pin = loop {
        let m = next_text(&mut performer).await;
        if m["type"] == "handles" && handles_where(&m, "pin").len() == 3 {
            break handles_where(&m, "pin")
                .into_iter()
                .find(|h| h["owner"] != "config")
                .unwrap();
        }
    };
    assert!(pin["owner"].as_str().unwrap().starts_with("client:"));
    // A pin off every puppet is ignored; a drag then pulls against three pins.
    performer
        .send(Message::text(
            json!({"type": "pin", "x": 5.0, "y": 5.0}).to_string(),
        ))
        .await
        .unwrap();
    // Unpinning removes it again.
    let id = pin["id"].as_u64().unwrap();
    performer
        .send(Message::text(
            json!({"type": "unpin", "puppet": 0, "handle": id}).to_string(),
        ))
        .await
        .unwrap();
    loop {
        let m = next_text(&mut performer).await;
        if m["type"] != "handles" {
            // (`history` counts the pin and the unpin.)
            continue;
        }
        if handles_where(&m, "pin").len() == 2 {
            assert!(
                handles_where(&m, "pin")
                    .iter()
                    .all(|h| h["owner"] == "config")
            );
            break;
        }
        assert!(
            handles_where(&m, "pin").len() <= 3,
            "the pin off the puppet was not made"
        );
    }
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tuio_table_over_udp_grabs_and_lets_go() {
    let running = daemon("[[input]]\nkind = \"tuio\"\nlisten = \"127.0.0.1:0\"\n").await;
    let table = running.tuio_addresses[0];
    let (mut viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    // TUIO is normalised, y down; the default calibration fits the stage.
    let (x, y) = ((grab.x / 1280.0) as f32, (1.0 - grab.y / 720.0) as f32);
    let udp = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    udp.send_to(&crate::common::tuio::v1(None, &[5], &[(5, x, y)], 1), table)
        .await
        .unwrap();
    udp.send_to(
        &crate::common::tuio::v1(None, &[5], &[(5, x, y - 0.05)], 2),
        table,
    )
    .await
    .unwrap();
    until_contact_owners(&mut viewer, |o| o.iter().any(|o| o.starts_with("tuio"))).await;
    // The cursor leaves the alive list: its handle goes.
    udp.send_to(&crate::common::tuio::v1(None, &[], &[], 3), table)
        .await
        .unwrap();
    until_contact_owners(&mut viewer, |o| o.is_empty()).await;
    running.shutdown().await;
}

/// Issue 45: a TUIO sender that died mid-touch (no empty alive set, no
/// more datagrams) held the puppet for ever; past its `release_after_s`
/// it is let go.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tuio_sender_that_dies_mid_touch_is_let_go() {
    let running =
        daemon("[[input]]\nkind = \"tuio\"\nlisten = \"127.0.0.1:0\"\nrelease_after_s = 0.3\n")
            .await;
    let table = running.tuio_addresses[0];
    let (mut viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let grab = hand(&placed_mesh(&stage));
    let (x, y) = ((grab.x / 1280.0) as f32, (1.0 - grab.y / 720.0) as f32);
    let udp = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let down = crate::common::tuio::v1(Some("table"), &[5], &[(5, x, y)], 1);
    udp.send_to(&down, table).await.unwrap();
    until_contact_owners(&mut viewer, |o| o == ["tuio:table"]).await;
    drop(udp);
    until_contact_owners(&mut viewer, |o| o.is_empty()).await;
    running.shutdown().await;
}

/// Issue 45: a pad whose firmware hangs with the port open let go only
/// when the port closed; silent past its `release_after_s` while holding,
/// it lets go.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_serial_pad_that_hangs_holding_a_contact_is_let_go() {
    use std::io::Write;
    let mut pad = crate::common::pty::open_pty();
    let extra = format!(
        "[[input]]\nkind = \"serial\"\npath = \"{}\"\nformat = \"csv\"\nname = \"pad\"\nrelease_after_s = 0.3\n",
        pad.path
    );
    let running = daemon(&extra).await;
    let (mut viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let grab = hand(&placed_mesh(&stage));
    write!(pad.master, "1,d,{},{}\nf\n", grab.x, grab.y).unwrap();
    until_contact_owners(&mut viewer, |o| o == ["pad"]).await;
    // The port stays open (the pty is kept), and nothing more comes.
    until_contact_owners(&mut viewer, |o| o.is_empty()).await;
    drop(pad);
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_serial_pad_grabs_and_a_hang_up_lets_go() {
    use std::io::Write;
    let mut pad = crate::common::pty::open_pty();
    let extra = format!(
        "[[input]]\nkind = \"serial\"\npath = \"{}\"\nformat = \"csv\"\nname = \"pad\"\n",
        pad.path
    );
    let running = daemon(&extra).await;
    let (mut viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    // Pad units are stage units by default.
    write!(
        pad.master,
        "1,d,{},{}\nf\n1,m,{},{}\nf\n",
        grab.x,
        grab.y,
        grab.x,
        grab.y + 40.0
    )
    .unwrap();
    until_contact_owners(&mut viewer, |o| o == ["pad"]).await;
    // The pad goes away: its contact is lifted.
    drop(pad);
    until_contact_owners(&mut viewer, |o| o.is_empty()).await;
    running.shutdown().await;
}

/// The HID hybrid capture (hid-recorder format) through the same path.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hid_capture_drives_the_daemon_and_leaves_no_stuck_contact() {
    let capture = root().join("tests/fixtures/touch-hybrid.hid");
    assert!(
        a_capture_grabs_and_lets_go(&capture, 4095.0).await,
        "the capture's touches were solved"
    );
}
