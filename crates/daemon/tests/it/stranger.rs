//! A stranger on the show network, over loopback (issue 32): a performer
//! flooding contacts is refused with a typed error while another performer
//! keeps playing; connections that trickle their headers, sit silent or
//! stop reading their WebSocket are closed; one address cannot take every
//! place; a rebound name's page is not the daemon's own; and the small
//! protocol holes (a second hello, an unpin of no puppet, a fragmented
//! message past 64 KiB, an input named like a client) are closed.

use crate::common::daemon::*;

use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use glam::DVec2;
use puppetry_daemon::serve::{Options, Running, start_with};
use puppetry_daemon::stream::{EdgeTimes, WebFiles};
use serde_json::{Value, json};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

const PERFORMER: &str = r#"{"type": "hello", "role": "performer", "token": "secret"}"#;

fn performer() -> Value {
    serde_json::from_str(PERFORMER).unwrap()
}

/// The daemon of [`stage_config`], its edge waiting as `times` says.
async fn daemon_with(
    extra: &str,
    times: EdgeTimes,
    adjust: impl FnOnce(&mut puppetry_daemon::config::ShowConfig),
) -> Running {
    let mut config = stage_config(extra);
    adjust(&mut config);
    let mut options = Options::new(WebFiles::Embedded);
    options.edge = times;
    start_with(&config, options).await.unwrap()
}

/// Reads until the next `error` message.
async fn next_error(ws: &mut Client) -> Value {
    loop {
        let m = next_text(ws).await;
        if m["type"] == "error" {
            return m;
        }
    }
}

/// A `contacts` message of `ids`, each `phase` at `at`.
fn contacts(ids: impl Iterator<Item = u32>, phase: &str, at: DVec2) -> String {
    let contacts: Vec<Value> = ids
        .map(|id| json!({"id": id, "phase": phase, "x": at.x, "y": at.y}))
        .collect();
    json!({"type": "contacts", "contacts": contacts}).to_string()
}

/// This process's resident memory, in MiB (the daemon runs in it).
fn rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_contacts_flood_is_refused_while_another_performer_plays() {
    let running = daemon("").await;
    let (mut player, stage) = connect(&running, performer()).await;
    let mesh = placed_mesh(&stage);
    let grab = hand(&mesh);
    let held = follow(&mesh, grab);
    player
        .send(Message::text(contacts([1].into_iter(), "down", grab)))
        .await
        .unwrap();
    frame_until(&mut player, |f| held(f).distance(grab) < 1e-2).await;
    let rss_before = rss_mib();

    // The flood: 1,400 contacts on the puppet in one message (about as
    // many as fit in 64 KiB), again and again, reconnecting whenever the
    // daemon closes the connection for too many bad messages.
    let address = running.address;
    let flooding = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let flood = tokio::spawn({
        let flooding = flooding.clone();
        async move {
            let url = format!("ws://{address}/ws");
            let spot = grab.round();
            let message = contacts(0..1400, "down", spot)
                .replace(".0,", ",")
                .replace(".0}", "}");
            assert!(message.len() < 64 * 1024, "{}", message.len());
            let (mut refusals, mut closes) = (Vec::new(), Vec::new());
            while flooding.load(std::sync::atomic::Ordering::Relaxed) {
                let (mut ws, _) = tokio_tungstenite::connect_async(url.as_str())
                    .await
                    .unwrap();
                ws.send(Message::text(PERFORMER)).await.unwrap();
                let mut sent = 0;
                while flooding.load(std::sync::atomic::Ordering::Relaxed) {
                    if sent < puppetry_daemon::stream::MAX_BAD_MESSAGES {
                        ws.send(Message::text(message.clone())).await.unwrap();
                        sent += 1;
                    }
                    let read = tokio::time::timeout(Duration::from_secs(1), ws.next());
                    match read.await {
                        Ok(Some(Ok(Message::Text(text)))) => {
                            let m: Value = serde_json::from_str(&text).unwrap();
                            if m["type"] == "error" {
                                refusals.push(m);
                            }
                        }
                        Ok(Some(Ok(Message::Close(frame)))) => {
                            let frame = frame.expect("a close frame with a code");
                            closes.push((u16::from(frame.code), frame.reason.to_string()));
                            break;
                        }
                        Ok(Some(Ok(_))) | Err(_) => {}
                        Ok(None | Some(Err(_))) => {
                            panic!("the flooding connection ended without a close frame")
                        }
                    }
                }
            }
            (refusals, closes)
        }
    });

    // The other performer's round trips: a move sent, until a frame shows
    // the hand there (printed, not asserted: timing is the machine's).
    let mut round_trips = Vec::new();
    // Each target differs from the last fifty, so a frame still queued
    // from an earlier move cannot pass for this one.
    for i in 0..300 {
        let to = grab + DVec2::new(0.0, 1.0 + (i % 50) as f64);
        let sent = Instant::now();
        player
            .send(Message::text(contacts([1].into_iter(), "move", to)))
            .await
            .unwrap();
        frame_until(&mut player, |f| held(f).distance(to) < 1e-2).await;
        round_trips.push(sent.elapsed().as_secs_f64() * 1000.0);
    }
    let rss_during = rss_mib();
    flooding.store(false, std::sync::atomic::Ordering::Relaxed);
    let (refusals, closes) = flood.await.unwrap();
    round_trips.sort_by(f64::total_cmp);
    println!(
        "second performer's round trip during the flood: median {:.1} ms, max {:.1} ms over {} moves; \
         {} floods refused, {} connections closed; RSS {rss_before:.0} MiB before, {rss_during:.0} MiB during",
        round_trips[round_trips.len() / 2],
        round_trips[round_trips.len() - 1],
        round_trips.len(),
        refusals.len(),
        closes.len(),
    );
    // Every flood was refused whole with the typed error, and counted:
    // twenty in a row closed the connection.
    assert!(!refusals.is_empty());
    for m in &refusals {
        assert_eq!(m["code"], "too_many", "{m}");
        assert_eq!(m["field"], "contacts", "{m}");
    }
    assert!(!closes.is_empty());
    for close in &closes {
        assert_eq!(close, &(1008, "too many bad messages".to_string()));
    }
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn contacts_held_past_the_budget_or_named_twice_are_refused_whole() {
    use puppetry_limits::contacts::MAX_HELD_PER_CLIENT;
    let running = daemon("").await;
    let (mut ws, stage) = connect(&running, performer()).await;
    let at = hand(&placed_mesh(&stage));
    let held = MAX_HELD_PER_CLIENT as u32;
    // The budget, a few at a time.
    for first in (0..held).step_by(10) {
        ws.send(Message::text(contacts(first..first + 10, "down", at)))
            .await
            .unwrap();
    }
    // One more is refused, naming the budget.
    ws.send(Message::text(contacts([held].into_iter(), "down", at)))
        .await
        .unwrap();
    let error = next_error(&mut ws).await;
    assert_eq!(error["code"], "too_many", "{error}");
    // A lift makes room, in the same message.
    let lift_and_land = json!({"type": "contacts", "contacts": [
        {"id": 0, "phase": "up"},
        {"id": held, "phase": "down", "x": at.x, "y": at.y},
    ]});
    ws.send(Message::text(lift_and_land.to_string()))
        .await
        .unwrap();
    // One id twice in one message.
    let twice = json!({"type": "contacts", "contacts": [
        {"id": 1, "phase": "move", "x": at.x, "y": at.y},
        {"id": 1, "phase": "up"},
    ]});
    ws.send(Message::text(twice.to_string())).await.unwrap();
    let error = next_error(&mut ws).await;
    assert_eq!(error["code"], "bad_message", "{error}");
    assert_eq!(error["field"], "contacts[1].id", "{error}");
    // The lift-and-land went through (no error before the duplicate's):
    // a ping answers next.
    ws.send(Message::text(r#"{"type": "ping", "t": 1}"#))
        .await
        .unwrap();
    loop {
        let m = next_text(&mut ws).await;
        assert_ne!(m["type"], "error", "{m}");
        if m["type"] == "pong" {
            break;
        }
    }
    running.shutdown().await;
}

/// Reads until the server closes `stream` (or resets it). Whatever the
/// server sent is dropped.
async fn until_closed(stream: &mut TcpStream) {
    let mut buffer = [0u8; 4096];
    loop {
        match tokio::time::timeout(WAIT, stream.read(&mut buffer)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return,
            Ok(Ok(_)) => {}
            Err(_) => panic!("the connection was not closed within {WAIT:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trickling_and_silent_connections_are_closed_while_viewers_connect() {
    let times = EdgeTimes {
        header_read: Duration::from_secs(1),
        ..EdgeTimes::default()
    };
    let running = daemon_with("", times, |_| {}).await;
    let address = running.address;
    // Slowloris: a header line every 300 ms, never the blank line.
    let slowloris = tokio::spawn(async move {
        let mut stream = TcpStream::connect(address).await.unwrap();
        let start = Instant::now();
        stream.write_all(b"GET / HTTP/1.1\r\n").await.unwrap();
        for i in 0.. {
            tokio::time::sleep(Duration::from_millis(300)).await;
            let line = format!("X-Trickle-{i}: a\r\n");
            if stream.write_all(line.as_bytes()).await.is_err() || i > 100 {
                break;
            }
            // Closed by the server? A read returns at once then.
            let mut byte = [0u8; 1];
            if let Ok(Ok(0) | Err(_)) =
                tokio::time::timeout(Duration::from_millis(1), stream.read(&mut byte)).await
            {
                break;
            }
        }
        start.elapsed()
    });
    // A silent connection, and one idle after an answer.
    let opened = Instant::now();
    let mut silent = TcpStream::connect(address).await.unwrap();
    let mut idle = TcpStream::connect(address).await.unwrap();
    idle.write_all(b"GET /app.js HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    // Meanwhile a viewer connects and is served.
    let (_viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    assert_eq!(stage["type"], "stage");
    until_closed(&mut silent).await;
    let silent_for = opened.elapsed();
    until_closed(&mut idle).await;
    let idle_for = opened.elapsed();
    let trickled_for = slowloris.await.unwrap();
    println!(
        "header-read timeout {:?}: slowloris lasted {trickled_for:.2?}, silent {silent_for:.2?}, idle after an answer {idle_for:.2?}",
        times.header_read
    );
    // Cut (well before the 100 lines it would have trickled).
    assert!(trickled_for < Duration::from_secs(30), "{trickled_for:?}");
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_address_cannot_take_every_place() {
    let running = daemon_with("", EdgeTimes::default(), |config| {
        config.access.max_per_address = 2;
    })
    .await;
    let address = running.address;
    let cap = 2 + puppetry_limits::net::HTTP_PER_ADDRESS;
    // The address's places, taken by connections that say nothing.
    let mut held = Vec::new();
    for _ in 0..cap {
        held.push(connect_from([127, 0, 0, 1], address).await);
    }
    // One more from it is refused; another address is served.
    let mut refused = connect_from([127, 0, 0, 1], address).await;
    let mut answer = Vec::new();
    tokio::time::timeout(WAIT, refused.read_to_end(&mut answer))
        .await
        .unwrap()
        .unwrap();
    let answer = String::from_utf8_lossy(&answer);
    assert_eq!(http_status(answer.as_bytes()), 503, "{answer}");
    assert!(
        answer.contains("too many connections from this address"),
        "{answer}"
    );
    let mut other = connect_from([127, 0, 0, 2], address).await;
    other.write_all(&get_request("/")).await.unwrap();
    let mut answer = Vec::new();
    tokio::time::timeout(WAIT, other.read_to_end(&mut answer))
        .await
        .unwrap()
        .unwrap();
    assert_eq!(http_status(&answer), 200);
    // A place given back is taken again.
    drop(held.pop());
    let mut served = false;
    for _ in 0..200 {
        let mut again = connect_from([127, 0, 0, 1], address).await;
        again.write_all(&get_request("/")).await.unwrap();
        let mut answer = Vec::new();
        let _ = tokio::time::timeout(WAIT, again.read_to_end(&mut answer)).await;
        if http_status(&answer) == 200 {
            served = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(served, "a freed place is served");
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_that_stops_reading_is_closed() {
    let times = EdgeTimes {
        ping_every: Duration::from_millis(300),
        ..EdgeTimes::default()
    };
    let running = daemon_with("", times, |_| {}).await;
    let viewer = json!({"type": "hello", "role": "viewer"});
    let (mut reader, _) = connect(&running, viewer.clone()).await;
    let (mut deaf, _) = connect(&running, viewer).await;
    // The reader reads (and so answers pings) for ten pings' time; the
    // deaf one reads nothing.
    let until = Instant::now() + 10 * times.ping_every;
    let mut pings = 0;
    while Instant::now() < until {
        if let Ok(message) = tokio::time::timeout(times.ping_every, reader.next()).await {
            if let Some(Ok(Message::Ping(_))) = message {
                pings += 1;
            }
            assert!(
                !matches!(message, Some(Ok(Message::Close(_))) | None),
                "the reader was closed: {message:?}"
            );
        }
    }
    assert!(pings >= 2, "{pings} pings");
    assert_eq!(
        crate::roles::until_close(&mut deaf).await,
        (1008, "no answer to ping (not reading)".to_string())
    );
    // The reader is still served.
    reader
        .send(Message::text(r#"{"type": "ping", "t": 2}"#))
        .await
        .unwrap();
    while next_text(&mut reader).await["type"] != "pong" {}
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rebound_name_is_refused_though_its_host_header_agrees() {
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    let running = daemon("").await;
    let port = running.address.port();
    let open = |origin: String, host: String| {
        let mut request = format!("ws://{}/ws", running.address)
            .into_client_request()
            .unwrap();
        request
            .headers_mut()
            .insert("Origin", origin.parse().unwrap());
        request.headers_mut().insert("Host", host.parse().unwrap());
        tokio_tungstenite::connect_async(request)
    };
    let refused = open(
        format!("http://evil.example:{port}"),
        format!("evil.example:{port}"),
    )
    .await;
    match refused {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), 403);
        }
        other => panic!("a rebound page was let in: {:?}", other.map(|(_, r)| r)),
    }
    // The daemon's own page, by address or by localhost, is let in.
    for origin in [
        format!("http://127.0.0.1:{port}"),
        format!("http://localhost:{port}"),
    ] {
        let host = origin.trim_start_matches("http://").to_string();
        let (mut ws, _) = open(origin, host).await.unwrap();
        ws.send(Message::text(r#"{"type": "hello", "role": "viewer"}"#))
            .await
            .unwrap();
        assert_eq!(next_text(&mut ws).await["type"], "stage");
    }
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_hello_counts_as_a_bad_message() {
    let running = daemon("").await;
    let (mut ws, _) = connect(&running, performer()).await;
    for _ in 0..puppetry_daemon::stream::MAX_BAD_MESSAGES {
        ws.send(Message::text(PERFORMER)).await.unwrap();
    }
    let error = next_error(&mut ws).await;
    assert_eq!(error["code"], "bad_message", "{error}");
    assert_eq!(
        crate::roles::until_close(&mut ws).await,
        (1008, "too many bad messages".to_string())
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unpin_of_a_puppet_not_on_stage_is_refused() {
    let running = daemon("").await;
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    ws.send(Message::text(
        json!({"type": "unpin", "puppet": 99, "handle": 0}).to_string(),
    ))
    .await
    .unwrap();
    ws.send(Message::text(r#"{"type": "ping", "t": 3}"#))
        .await
        .unwrap();
    // The refusal comes before the ping's answer.
    let answer = loop {
        let m = next_text(&mut ws).await;
        if m["type"] == "error" || m["type"] == "pong" {
            break m;
        }
    };
    assert_eq!(answer["code"], "not_found", "{answer}");
    assert_eq!(answer["field"], "puppet", "{answer}");
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fragmented_message_past_64_kib_closes_with_1009() {
    use tokio_tungstenite::tungstenite::protocol::frame::Frame;
    use tokio_tungstenite::tungstenite::protocol::frame::coding::{Data, OpCode};
    let running = daemon("").await;
    let (mut ws, _) = connect(&running, performer()).await;
    // 100 KiB of text in 1 KiB fragments: each frame is small, the
    // message is not; the client goes on sending after the limit (as one
    // does that does not read while it sends).
    let part = vec![b'x'; 1024];
    let fragments = 100;
    for i in 0..fragments {
        let code = if i == 0 { Data::Text } else { Data::Continue };
        let frame = Frame::message(part.clone(), OpCode::Data(code), i == fragments - 1);
        if ws.send(Message::Frame(frame)).await.is_err() {
            break;
        }
    }
    assert_eq!(next_error(&mut ws).await["code"], "too_large");
    assert_eq!(
        crate::roles::until_close(&mut ws).await,
        (1009, "message too large".to_string())
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_input_named_like_a_client_is_refused_at_start() {
    let capture = looping_capture().replace("name = \"wetab\"", "name = \"client:1\"");
    let config = stage_config(&capture);
    let error = match start_with(&config, Options::new(WebFiles::Embedded)).await {
        Ok(running) => {
            running.shutdown().await;
            panic!("an input named client:1 was taken");
        }
        Err(e) => e.to_string(),
    };
    assert!(error.contains("input[0].name"), "{error}");
    assert!(error.contains("client:"), "{error}");
}
