//! The network edge under strangers' requests: malformed request lines, a
//! huge header, paths that try to climb out of the web client, and ten
//! times the connection cap at once. Each gets a clear answer, nothing in
//! the daemon panics, and frames keep coming.

use crate::common::daemon::*;

use std::sync::atomic::{AtomicUsize, Ordering};

use futures_util::SinkExt;
use glam::DVec2;
use serde_json::json;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

/// Panics on the daemon's runtime threads since this binary started.
static DAEMON_PANICS: AtomicUsize = AtomicUsize::new(0);

/// Counts panics on tokio's worker threads (where the daemon's tasks run;
/// test bodies run on their own threads), then reports them as usual.
fn count_daemon_panics() {
    static INSTALLED: std::sync::Once = std::sync::Once::new();
    INSTALLED.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if std::thread::current()
                .name()
                .is_some_and(|n| n.starts_with("tokio-runtime-worker"))
            {
                DAEMON_PANICS.fetch_add(1, Ordering::SeqCst);
            }
            previous(info);
        }));
    });
}

/// The whole answer to `request`, as text.
async fn raw(address: std::net::SocketAddr, request: &[u8]) -> String {
    String::from_utf8_lossy(&http_raw(address, request).await).into_owned()
}

fn status(answer: &str) -> u16 {
    http_status(answer.as_bytes())
}

fn get(path: &str) -> Vec<u8> {
    get_request(path)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn strangers_requests_get_clear_answers_and_no_panic() {
    count_daemon_panics();
    let panics_before = DAEMON_PANICS.load(Ordering::SeqCst);
    let running = daemon("").await;
    let address = running.address;

    // A request line with no path, and one with an empty path segment.
    assert_eq!(status(&raw(address, b"GET\r\nHost: x\r\n\r\n").await), 400);
    assert_eq!(
        status(&raw(address, b"GET  HTTP/1.1\r\nHost: x\r\n\r\n").await),
        400
    );
    assert_eq!(status(&raw(address, &get("//")).await), 404);
    // A 1 MB header.
    let mut huge = b"GET / HTTP/1.1\r\nHost: x\r\nX-Filler: ".to_vec();
    huge.extend(std::iter::repeat_n(b'a', 1 << 20));
    huge.extend_from_slice(b"\r\n\r\n");
    let answer = raw(address, &huge).await;
    assert!(
        answer.is_empty() || (400..500).contains(&status(&answer)),
        "{answer:?}"
    );
    // Paths that try to climb out of the web client, plain and encoded.
    for path in [
        "/../Cargo.toml",
        "/%2e%2e/Cargo.toml",
        "/%2E%2E%2FCargo.toml",
        "/..%2f..%2fCargo.toml",
        "/puppets/0/../../Cargo.toml",
        "/puppets/%2e%2e/texture.png",
    ] {
        assert_eq!(status(&raw(address, &get(path)).await), 404, "{path}");
    }
    // The page and a module are still served, with their types.
    let page = raw(address, &get("/")).await;
    assert_eq!(status(&page), 200);
    assert!(
        page.to_ascii_lowercase()
            .contains("content-type: text/html"),
        "{page:.200}"
    );
    let script = raw(address, &get("/app.js")).await;
    assert_eq!(status(&script), 200);
    assert!(
        script
            .to_ascii_lowercase()
            .contains("content-type: text/javascript"),
        "{script:.200}"
    );
    assert_eq!(status(&raw(address, &get("/no-such-file.js")).await), 404);
    assert_eq!(
        status(
            &raw(
                address,
                b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
            )
            .await
        ),
        405
    );
    running.shutdown().await;
    assert_eq!(
        DAEMON_PANICS.load(Ordering::SeqCst),
        panics_before,
        "the daemon panicked"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ten_times_the_connection_cap_is_refused_and_frames_keep_coming() {
    count_daemon_panics();
    let panics_before = DAEMON_PANICS.load(Ordering::SeqCst);
    let cap = 8;
    let mut config = stage_config("");
    config.stage.max_connections = cap;
    let running =
        puppetry_daemon::serve::start(&config, puppetry_daemon::stream::WebFiles::Embedded, None)
            .await
            .unwrap();
    let address = running.address;
    let hello = json!({"type": "hello", "role": "performer", "token": "secret"});
    let (mut performer, stage) = connect(&running, hello).await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    // The rest of the places taken by connections that say nothing.
    let mut idle = Vec::new();
    for _ in 0..cap - 2 {
        idle.push(TcpStream::connect(address).await.unwrap());
    }
    // Ten times the cap at once: each is told, none is served.
    let flood: Vec<_> = (0..10 * cap)
        .map(|_| tokio::spawn(async move { raw(address, &get("/")).await }))
        .collect();
    for answer in flood {
        let answer = answer.await.unwrap();
        assert_eq!(status(&answer), 503, "{answer:?}");
        assert!(answer.contains("too many open connections"), "{answer:?}");
    }
    // The connected clients were not disturbed: a drag still reaches the
    // viewer as frames.
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    let to = grab + DVec2::new(0.0, 50.0);
    for (phase, at) in [("down", grab), ("move", to)] {
        let contacts = json!({"type": "contacts", "contacts": [{"id": 1, "phase": phase, "x": at.x, "y": at.y}]});
        performer
            .send(Message::text(contacts.to_string()))
            .await
            .unwrap();
    }
    let held = follow(&mesh, grab);
    frame_until(&mut viewer, |f| held(f).distance(to) < 1e-2).await;
    // Places freed are taken again.
    drop(idle);
    let mut served = false;
    for _ in 0..200 {
        if status(&raw(address, &get("/")).await) == 200 {
            served = true;
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert!(served, "a connection is served once places are free");
    running.shutdown().await;
    assert_eq!(
        DAEMON_PANICS.load(Ordering::SeqCst),
        panics_before,
        "the daemon panicked"
    );
}

/// Reads until the next `error` message.
async fn next_error(ws: &mut Client) -> serde_json::Value {
    loop {
        let m = next_text(ws).await;
        if m["type"] == "error" {
            return m;
        }
    }
}

/// Opens a WebSocket and sends `first` before any hello.
async fn open(running: &puppetry_daemon::serve::Running, first: Message) -> Client {
    let url = format!("ws://{}/ws", running.address);
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    ws.send(first).await.unwrap();
    ws
}

/// `[[[…]]]` nested `depth` deep, as a message's field.
fn nested(depth: usize) -> String {
    format!(
        r#"{{"type": "contacts", "contacts": {}{}}}"#,
        "[".repeat(depth),
        "]".repeat(depth)
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_messages_get_typed_errors_and_closes_say_why() {
    count_daemon_panics();
    let panics_before = DAEMON_PANICS.load(Ordering::SeqCst);
    let running = daemon("").await;
    let performer = json!({"type": "hello", "role": "performer", "token": "secret"});

    // Before the hello: a binary message, and a deeply nested text.
    let mut ws = open(&running, Message::binary(vec![0u8; 64])).await;
    let error = next_error(&mut ws).await;
    assert_eq!(error["code"], "binary", "{error}");
    assert_eq!(
        crate::roles::until_close(&mut ws).await,
        (1008, "the first message must be a hello".to_string())
    );
    let mut ws = open(&running, Message::text(nested(10_000))).await;
    assert_eq!(next_error(&mut ws).await["code"], "hello");
    assert_eq!(crate::roles::until_close(&mut ws).await.0, 1008);

    // After it: deeply nested JSON is a bad message and the client goes on.
    let (mut ws, _) = connect(&running, performer.clone()).await;
    ws.send(Message::text(nested(10_000))).await.unwrap();
    let error = next_error(&mut ws).await;
    assert_eq!(error["code"], "bad_message", "{error}");
    ws.send(Message::text(r#"{"type": "ping", "t": 7.5}"#))
        .await
        .unwrap();
    loop {
        let m = next_text(&mut ws).await;
        if m["type"] == "pong" {
            assert_eq!(m["t"], 7.5);
            // The daemon's clock, running since it started.
            assert!(m["clock"].as_f64().is_some_and(|c| c > 0.0), "{m}");
            break;
        }
    }
    // Coordinates out of range name their field (1e12 was silently
    // ignored, 1e9 taken).
    for (message, field) in [
        (
            json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": 1e12, "y": 300.0}]}),
            "contacts[0].x",
        ),
        (
            json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": 10.0, "y": 10.0},
                                                    {"id": 2, "phase": "down", "x": 10.0, "y": -1e9}]}),
            "contacts[1].y",
        ),
        (json!({"type": "pin", "x": 1e12, "y": 300.0}), "x"),
        (
            json!({"type": "cursor", "puppet": 0, "at": [0.5, 1e300]}),
            "at[1]",
        ),
    ] {
        ws.send(Message::text(message.to_string())).await.unwrap();
        let error = next_error(&mut ws).await;
        assert_eq!(error["code"], "out_of_range", "{error}");
        assert_eq!(error["field"], field, "{error}");
    }
    // Over 64 KiB: too large, then a close frame saying so.
    let big = format!(
        r#"{{"type": "pin", "x": 1, "y": 1, "pad": "{}"}}"#,
        "x".repeat(70 * 1024)
    );
    ws.send(Message::text(big)).await.unwrap();
    assert_eq!(next_error(&mut ws).await["code"], "too_large");
    assert_eq!(
        crate::roles::until_close(&mut ws).await,
        (1009, "message too large".to_string())
    );

    // Too many bad messages in a row: closed, saying why.
    let (mut ws, _) = connect(&running, performer.clone()).await;
    for _ in 0..puppetry_daemon::stream::MAX_BAD_MESSAGES {
        ws.send(Message::binary(vec![1u8])).await.unwrap();
    }
    assert_eq!(
        crate::roles::until_close(&mut ws).await,
        (1008, "too many bad messages".to_string())
    );

    // The daemon is still serving.
    let (_, stage) = connect(&running, performer).await;
    assert_eq!(stage["type"], "stage");
    running.shutdown().await;
    assert_eq!(
        DAEMON_PANICS.load(Ordering::SeqCst),
        panics_before,
        "the daemon panicked"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn errors_echo_at_most_200_characters_of_input() {
    let running = daemon("").await;
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    let long = "q".repeat(3000);
    for message in [
        json!({"type": long}).to_string(),
        json!({"type": "pin", "x": 1.0, "y": 1.0, long.clone(): 1}).to_string(),
        json!({"type": "play", "take": long}).to_string(),
        json!({"type": "record", "name": long}).to_string(),
    ] {
        ws.send(Message::text(message.clone())).await.unwrap();
        let error = next_error(&mut ws).await;
        let text = error["message"].as_str().unwrap();
        assert!(
            !text.contains(&"q".repeat(201)),
            "{} characters echoed: {text:.300}",
            text.matches('q').count()
        );
        assert!(text.chars().count() <= 620, "{text}");
    }
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_past_the_per_address_cap_are_closed_saying_why() {
    let mut config = stage_config("");
    config.access.max_per_address = 3;
    let running =
        puppetry_daemon::serve::start(&config, puppetry_daemon::stream::WebFiles::Embedded, None)
            .await
            .unwrap();
    let viewer = json!({"type": "hello", "role": "viewer"});
    let mut open_ones = Vec::new();
    for _ in 0..3 {
        let (ws, stage) = connect(&running, viewer.clone()).await;
        assert_eq!(stage["type"], "stage");
        open_ones.push(ws);
    }
    // The fourth from this address is opened only to be closed.
    let url = format!("ws://{}/ws", running.address);
    for _ in 0..3 {
        let (mut ws, _) = tokio_tungstenite::connect_async(url.as_str())
            .await
            .unwrap();
        assert_eq!(
            crate::roles::until_close(&mut ws).await,
            (1013, "too many connections from this address".to_string())
        );
    }
    // A place given back is taken again (the server notices the close
    // asynchronously: a bounded number of tries).
    drop(open_ones.pop());
    let mut served = false;
    for _ in 0..200 {
        let (mut ws, _) = tokio_tungstenite::connect_async(url.as_str())
            .await
            .unwrap();
        ws.send(Message::text(viewer.to_string())).await.unwrap();
        match next_message(&mut ws).await {
            Message::Text(_) => {
                served = true;
                break;
            }
            _ => tokio::time::sleep(std::time::Duration::from_millis(50)).await,
        }
    }
    assert!(served, "a freed place is served");
    running.shutdown().await;
}
