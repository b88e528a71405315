//! The relay tier end to end: a real `nats-server` on a free loopback
//! port, a daemon publishing a looping real capture, and two relays in
//! this process. Relay viewers get the direct client's very bytes, a late
//! joiner gets the state at once, a remote performer is checked by the
//! daemon as a direct one is, killing one relay leaves the other (and lets
//! go of its performers' handles), and a NATS restart is told and
//! recovered from.

mod secure;

use std::collections::BTreeMap;

use futures_util::SinkExt;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use crate::common::daemon::*;
use crate::common::nats::NatsServer;
use puppetry_daemon::protocol::{FrameKind, decode_frame};
use puppetry_daemon::relay::{RelayOptions, RelayRunning, serve};

/// The daemon's stage: a looping real capture, published on `nats`.
fn stage(nats: &str) -> String {
    let relay = format!("\n[relay]\nnats = \"{nats}\"\nstage = \"t\"\n");
    stage_text(&(looping_capture() + &relay))
}

async fn relay(nats: &str, name: &str) -> RelayRunning {
    serve::start(RelayOptions {
        nats: nats.to_string(),
        stage: "t".into(),
        name: name.into(),
        listen: "127.0.0.1:0".parse().unwrap(),
        web_files: puppetry_daemon::stream::WebFiles::Embedded,
        max_connections: 64,
        client_timeout: std::time::Duration::from_secs(10),
    })
    .await
    .unwrap()
}

/// Connects to `address`, says `hello`, and reads until a `stage`
/// message with puppets (a relay that has not heard the daemon yet sends
/// an empty stage first, and says it is not live), or an error.
async fn join(address: std::net::SocketAddr, hello: Value) -> (Client, Value) {
    let url = format!("ws://{address}/ws");
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    ws.send(Message::text(hello.to_string())).await.unwrap();
    loop {
        let m = next_text(&mut ws).await;
        let staged = m["type"] == "stage" && m["puppets"].as_array().is_some_and(|p| !p.is_empty());
        if staged || m["type"] == "error" {
            return (ws, m);
        }
    }
}

/// A stage message's puppets without their handles (which move with the
/// replay's contacts between two clients' joining).
fn puppets(stage: &Value) -> Value {
    let mut puppets = stage["puppets"].clone();
    for p in puppets.as_array_mut().expect("puppets") {
        p.as_object_mut().unwrap().remove("handles");
    }
    puppets
}

fn viewer() -> Value {
    json!({"type": "hello", "role": "viewer"})
}

/// The next `count` vertex frames of puppet 0, by sequence.
async fn frames(ws: &mut Client, count: usize) -> BTreeMap<u64, Vec<u8>> {
    let mut seen = BTreeMap::new();
    while seen.len() < count {
        if let Message::Binary(bytes) = next_message(ws).await
            && let Ok(frame) = decode_frame(&bytes)
            && frame.header.kind == FrameKind::Vertices
        {
            seen.insert(frame.header.sequence, bytes.to_vec());
        }
    }
    seen
}

/// Reads until a text message of `kind` satisfying `done` (other messages
/// keep coming while the replay plays: the wait is bounded as a whole).
async fn until(ws: &mut Client, kind: &str, done: impl Fn(&Value) -> bool) -> Value {
    let waiting = async {
        loop {
            let m = next_text(ws).await;
            if m["type"] == kind && done(&m) {
                return m;
            }
        }
    };
    tokio::time::timeout(PLAYS, waiting)
        .await
        .unwrap_or_else(|_| panic!("no {kind} message as awaited in {PLAYS:?}"))
}

/// Reads until a `handles` message whose contact owners satisfy `done`,
/// within [`PLAYS`].
async fn until_owners(ws: &mut Client, done: impl Fn(&[String]) -> bool) {
    let waiting = until_contact_owners(ws, done);
    tokio::time::timeout(PLAYS, waiting)
        .await
        .unwrap_or_else(|_| panic!("the handles' owners never became as awaited in {PLAYS:?}"));
}

/// A newer vertex frame than `after`; its sequence.
async fn newer_frame(ws: &mut Client, after: u64) -> u64 {
    let waiting = frame_until(ws, |f| f.sequence > after);
    tokio::time::timeout(PLAYS, waiting)
        .await
        .unwrap_or_else(|_| panic!("no frame after {after} in {PLAYS:?}"))
        .sequence
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relays_serve_the_daemons_bytes_and_outlive_each_other_and_nats() {
    let mut nats = NatsServer::start();
    let config = puppetry_daemon::config::ShowConfig::parse(
        "relay.toml",
        &stage(&nats.url()),
        std::path::Path::new("/"),
    )
    .unwrap();
    let running =
        puppetry_daemon::serve::start(&config, puppetry_daemon::stream::WebFiles::Embedded, None)
            .await
            .unwrap();
    let relay_a = relay(&nats.url(), "a").await;
    let relay_b = relay(&nats.url(), "b").await;

    // A viewer of relay b who never reads: it slows no one (it gets
    // newest-only and is dropped after the client timeout).
    let (_stalled, _) = join(relay_b.address, viewer()).await;
    // The same stage everywhere: relays rebuild the daemon's message.
    let (mut direct, direct_stage) = join(running.address, viewer()).await;
    let (mut on_a, a_stage) = join(relay_a.address, viewer()).await;
    let (mut on_b, b_stage) = join(relay_b.address, viewer()).await;
    for (name, got) in [("a", &a_stage), ("b", &b_stage)] {
        assert_eq!(got["type"], "stage", "relay {name}: {got}");
        assert!(
            puppets(got) == puppets(&direct_stage),
            "relay {name}: its stage's puppets differ from the daemon's"
        );
        assert_eq!(got["stage"], direct_stage["stage"], "relay {name}");
        assert!(
            got["you"]["owner"]
                .as_str()
                .unwrap()
                .starts_with(&format!("relay:{name}:")),
            "{}",
            got["you"]
        );
    }

    // Every frame a relay viewer gets is byte for byte the direct one of
    // the same sequence (newest-only may skip some, never change one).
    let (direct_frames, a_frames, b_frames) = tokio::join!(
        frames(&mut direct, 80),
        frames(&mut on_a, 60),
        frames(&mut on_b, 60)
    );
    for (name, relayed) in [("a", &a_frames), ("b", &b_frames)] {
        let common: Vec<u64> = relayed
            .keys()
            .filter(|s| direct_frames.contains_key(s))
            .copied()
            .collect();
        assert!(
            common.len() >= 30,
            "relay {name}: only {} of its {} frames were among the direct viewer's",
            common.len(),
            relayed.len()
        );
        for s in common {
            assert!(
                relayed[&s] == direct_frames[&s],
                "relay {name}: frame {s} differs from the direct one"
            );
        }
    }
    drop((direct, on_a, on_b));

    // Pictures come through the relay, the same bytes, fetched from the
    // daemon once however many viewers ask at the same moment.
    let picture = "/puppets/0/texture.png";
    let from_daemon = http_get(running.address, picture).await;
    let at_once =
        futures_util::future::join_all((0..12).map(|_| http_get(relay_b.address, picture))).await;
    assert_eq!(
        relay_b.picture_fetches(),
        1,
        "twelve viewers asking at once make one fetch"
    );
    let from_relay = http_get(relay_b.address, picture).await;
    assert_eq!(relay_b.picture_fetches(), 1, "the fetched picture is kept");
    assert_eq!(http_status(&from_relay), 200);
    let body = |answer: &[u8]| {
        let at = answer.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        answer[at + 4..].to_vec()
    };
    assert!(
        at_once
            .iter()
            .all(|answer| body(answer) == body(&from_relay)),
        "every viewer who asked at once got the picture"
    );
    assert!(
        body(&from_relay) == body(&from_daemon),
        "the relayed picture differs"
    );

    // A page of a foreign origin is refused at the relay.
    let mut request = format!("ws://{}/ws", relay_b.address)
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("Origin", "http://elsewhere.example".parse().unwrap());
    match tokio_tungstenite::connect_async(request).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(answer)) => {
            assert_eq!(answer.status(), 403)
        }
        other => panic!("a foreign origin was let in: {:?}", other.map(|_| ())),
    }

    // A late joiner gets the whole state at once: the stage, the handles,
    // the newest frame.
    let (mut late, late_stage) = join(relay_b.address, viewer()).await;
    assert!(puppets(&late_stage) == puppets(&direct_stage));
    until(&mut late, "handles", |_| true).await;
    frame_until(&mut late, |_| true).await;
    drop(late);

    // A remote performer on relay a: let in by the daemon, named for the
    // relay, checked like a direct one.
    let performer_hello = json!({"type": "hello", "role": "performer", "token": "secret"});
    let (mut performer, seated) = join(relay_a.address, performer_hello).await;
    assert_eq!(seated["role"], "performer", "{seated}");
    let owner = seated["you"]["owner"].as_str().unwrap().to_string();
    assert!(owner.starts_with("relay:a:"), "{owner}");
    let grab = hand(&placed_mesh(&seated));
    performer
        .send(Message::text(
            json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": grab.x, "y": grab.y}]})
                .to_string(),
        ))
        .await
        .unwrap();
    let (mut watcher, _) = join(running.address, viewer()).await;
    until_owners(&mut watcher, |owners| owners.contains(&owner)).await;
    let paint = json!({"type": "paint", "puppet": 0, "x": 640.0, "y": 400.0, "radius": 40.0, "strength": 2.0});
    performer
        .send(Message::text(paint.to_string()))
        .await
        .unwrap();
    let refused = until(&mut performer, "error", |_| true).await;
    assert_eq!(refused["code"], "forbidden", "{refused}");
    let (mut wrong, refused) = join(
        relay_a.address,
        json!({"type": "hello", "role": "performer", "token": "nope"}),
    )
    .await;
    assert_eq!(refused["code"], "bad_token", "{refused}");
    let closed = loop {
        if let Message::Close(frame) = next_message(&mut wrong).await {
            break frame.map(|f| u16::from(f.code));
        }
    };
    assert_eq!(closed, Some(4001));

    // Relay a goes: relay b's viewers go on, and the performer's handle is
    // let go on stage.
    let (mut on_b, _) = join(relay_b.address, viewer()).await;
    let before = newer_frame(&mut on_b, 0).await;
    relay_a.shutdown().await;
    drop(performer);
    newer_frame(&mut on_b, before + 10).await;
    until_owners(&mut watcher, |owners| !owners.contains(&owner)).await;
    drop(watcher);

    // NATS goes: direct clients go on; relay viewers are told, then told
    // again when it is back, and frames flow again.
    let (mut direct, _) = join(running.address, viewer()).await;
    let before = newer_frame(&mut direct, 0).await;
    nats.stop();
    newer_frame(&mut direct, before + 10).await;
    let lost = until(&mut on_b, "live", |m| m["live"] == false).await;
    assert!(lost["reason"].is_string(), "{lost}");
    // Meanwhile the relay answers pings itself, on the daemon's clock, and
    // refuses what needs the stage without holding it against the client.
    on_b.send(Message::text(json!({"type": "ping", "t": 7.5}).to_string()))
        .await
        .unwrap();
    let pong = until(&mut on_b, "pong", |_| true).await;
    assert_eq!(pong["t"], 7.5);
    assert!(pong["clock"].as_f64().unwrap() > 0.0, "{pong}");
    for _ in 0..30 {
        on_b.send(Message::text(json!({"type": "list_takes"}).to_string()))
            .await
            .unwrap();
        let refused = until(&mut on_b, "error", |_| true).await;
        assert_eq!(refused["code"], "failed", "{refused}");
    }
    drop(direct);
    nats.restart();
    until(&mut on_b, "live", |m| m["live"] == true).await;
    let after = newer_frame(&mut on_b, 0).await;
    newer_frame(&mut on_b, after).await;
    let (_, b_again) = join(relay_b.address, viewer()).await;
    assert!(puppets(&b_again) == puppets(&direct_stage));

    relay_b.shutdown().await;
    running.shutdown().await;
}
