//! The stranger's table (issue 32), as a run anyone can repeat: the real
//! `puppetry serve` binary with a performer dragging and a viewer watching,
//! attacked row by row over loopback, and the command line fed crafted
//! take and stage files. Each row prints what it tried and counts panics,
//! crashes, wrong-permission successes, the longest gap the watching
//! viewer saw between frames, and the peak resident memory; the test fails
//! on any panic, crash, wrong-permission success or peak over 500 MB.
//! Gaps are printed, not asserted (timing is the machine's).
//!
//!     cargo test --release -p puppetry --test it hostile -- --nocapture
//!     PUPPETRY_HOSTILE_SCALE=10 cargo test --release -p puppetry --test it hostile -- --nocapture
//!
//! The default scale runs in seconds in the suite; a larger one tries more
//! random values, tokens, datagrams and files. Slow and silent HTTP
//! connections, SIGXFSZ, symlinked temp files and NATS strangers have tests
//! of their own (`stranger`, `files`, `guarded`, `relay::secure`).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_tungstenite::MaybeTlsStream;
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::{
    Client, WAIT, connect_from, connect_url, get_request, hand, http_status, placed_mesh,
    stage_text,
};
use crate::common::served::{Served, serve, serve_command};
use crate::guarded::write_take;

/// The peak resident memory every row must stay under.
const RSS_LIMIT_MIB: f64 = 500.0;

const DIRECTOR: &str = "boss";
const PERFORMER: &str = "secret";

fn scale() -> usize {
    std::env::var("PUPPETRY_HOSTILE_SCALE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
        .max(1)
}

/// A seeded generator (splitmix64): the same run every time.
struct Dice(u64);

impl Dice {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A number in `low..high`.
    fn within(&mut self, low: usize, high: usize) -> usize {
        low + (self.next() % (high - low) as u64) as usize
    }

    fn byte(&mut self) -> u8 {
        self.next() as u8
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.byte()).collect()
    }
}

/// One row of the table.
#[derive(Default)]
struct Row {
    name: &'static str,
    tries: usize,
    refused: usize,
    wrong_permission: usize,
    panics: usize,
    crashes: usize,
    stalls: usize,
    longest_gap_ms: f64,
    peak_rss_mib: f64,
    notes: Vec<String>,
}

impl Row {
    fn new(name: &'static str) -> Row {
        Row {
            name,
            ..Row::default()
        }
    }

    fn print(&self) {
        println!(
            "| {:<26} | {:>6} | {:>7} | {:>5} | {:>6} | {:>7} | {:>6} | {:>8.0} | {:>8.1} |{}",
            self.name,
            self.tries,
            self.refused,
            self.wrong_permission,
            self.panics,
            self.crashes,
            self.stalls,
            self.longest_gap_ms,
            self.peak_rss_mib,
            if self.notes.is_empty() {
                String::new()
            } else {
                format!(" {}", self.notes.join("; "))
            }
        );
    }

    fn failed(&self) -> bool {
        self.panics > 0
            || self.crashes > 0
            || self.wrong_permission > 0
            || self.stalls > 0
            || self.peak_rss_mib >= RSS_LIMIT_MIB
    }
}

/// A performer dragging the puppet's hand at about 100 Hz and a viewer
/// timing the frames it is sent: the show that must go on.
struct Watch {
    longest_gap_us: Arc<AtomicU64>,
    last_frame: Arc<Mutex<Instant>>,
    running: Arc<AtomicBool>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl Watch {
    async fn start(url: &str) -> Watch {
        let (mut performer, stage) = connect_url(
            url,
            json!({"type": "hello", "role": "performer", "token": PERFORMER}),
        )
        .await;
        let (mut viewer, _) = connect_url(url, json!({"type": "hello", "role": "viewer"})).await;
        let grab = hand(&placed_mesh(&stage));
        let running = Arc::new(AtomicBool::new(true));
        let longest_gap_us = Arc::new(AtomicU64::new(0));
        let last_frame = Arc::new(Mutex::new(Instant::now()));
        let drag = tokio::spawn({
            let running = running.clone();
            async move {
                let mut k = 0u64;
                while running.load(Ordering::Relaxed) {
                    let phase = if k == 0 { "down" } else { "move" };
                    let y = grab.y + (k % 60) as f64;
                    let m = json!({"type": "contacts", "contacts": [{"id": 1, "phase": phase, "x": grab.x, "y": y}]});
                    if performer.send(Message::text(m.to_string())).await.is_err() {
                        return;
                    }
                    // Answers (errors, pongs) are read and dropped.
                    while let Ok(Some(_)) =
                        tokio::time::timeout(Duration::ZERO, performer.next()).await
                    {
                    }
                    tokio::time::sleep(Duration::from_millis(10)).await;
                    k += 1;
                }
            }
        });
        let watch = tokio::spawn({
            let (running, longest, last) =
                (running.clone(), longest_gap_us.clone(), last_frame.clone());
            async move {
                while running.load(Ordering::Relaxed) {
                    match tokio::time::timeout(Duration::from_millis(200), viewer.next()).await {
                        Ok(Some(Ok(Message::Binary(_)))) => {
                            let mut last = last.lock().unwrap();
                            let gap = last.elapsed().as_micros() as u64;
                            longest.fetch_max(gap, Ordering::Relaxed);
                            *last = Instant::now();
                        }
                        Ok(Some(Ok(_))) | Err(_) => {}
                        Ok(None | Some(Err(_))) => return,
                    }
                }
            }
        });
        Watch {
            longest_gap_us,
            last_frame,
            running,
            tasks: vec![drag, watch],
        }
    }

    /// The longest gap between frames since the last call (counting the
    /// one still open), in ms.
    fn take_gap_ms(&self) -> f64 {
        let open = self.last_frame.lock().unwrap().elapsed().as_micros() as u64;
        self.longest_gap_us.fetch_max(open, Ordering::Relaxed);
        self.longest_gap_us.swap(0, Ordering::Relaxed) as f64 / 1000.0
    }

    async fn stop(self) {
        self.running.store(false, Ordering::Relaxed);
        for task in self.tasks {
            let _ = task.await;
        }
    }
}

/// What came back for one message: the errors before the matching pong,
/// or the close code if the daemon hung up.
enum Answer {
    Errors(Vec<Value>),
    Closed(u16),
    /// Nothing within [`WAIT`].
    Silent,
}

/// Sends `text`, then a ping, and reads until its pong.
async fn exchange(ws: &mut Client, text: &str, mark: f64) -> Answer {
    let ping = json!({"type": "ping", "t": mark}).to_string();
    if ws.send(Message::text(text)).await.is_err() || ws.send(Message::text(ping)).await.is_err() {
        return Answer::Closed(0);
    }
    let mut errors = Vec::new();
    loop {
        match tokio::time::timeout(WAIT, ws.next()).await {
            Err(_) => return Answer::Silent,
            Ok(None | Some(Err(_))) => return Answer::Closed(0),
            Ok(Some(Ok(Message::Close(frame)))) => {
                return Answer::Closed(frame.map_or(0, |f| u16::from(f.code)));
            }
            Ok(Some(Ok(Message::Text(t)))) => {
                let m: Value = serde_json::from_str(&t).unwrap();
                if m["type"] == "error" {
                    errors.push(m);
                } else if m["type"] == "pong" && m["t"].as_f64() == Some(mark) {
                    return Answer::Errors(errors);
                }
            }
            Ok(Some(Ok(_))) => {}
        }
    }
}

fn hello(role: &str, token: &str) -> Value {
    json!({"type": "hello", "role": role, "token": token})
}

/// One valid message of every type that carries a number, as a director
/// would send it on the test stage. Those that write files in the
/// repository (`save_weights`, `save_keys`) or take the only puppet off
/// (`remove_puppet`) are left out: their numbers are the same `puppet`.
fn numeric_messages() -> Vec<Value> {
    vec![
        json!({"type": "contacts", "contacts": [{"id": 7, "phase": "down", "x": 600.0, "y": 300.0}]}),
        json!({"type": "pin", "x": 640.5, "y": 360.5}),
        json!({"type": "depth_flip", "x": 640.5, "y": 360.5}),
        json!({"type": "unpin", "puppet": 0, "handle": 99}),
        json!({"type": "paint", "puppet": 0, "x": 640.5, "y": 360.5, "radius": 20.5, "strength": 0.5, "stroke": 1}),
        json!({"type": "paint_depth", "puppet": 0, "x": 640.5, "y": 360.5, "radius": 20.5, "layer": 1, "stroke": 2}),
        json!({"type": "add_curve", "name": "rope", "points": [[100.5, 100.5], [300.5, 120.5]], "width": 12.5, "colour": "#aa3300"}),
        json!({"type": "undo", "puppet": 0}),
        json!({"type": "redo", "puppet": 0}),
        json!({"type": "reset", "puppet": 0}),
        json!({"type": "export_grid", "puppet": 0}),
        json!({"type": "pose", "puppet": 0, "from": "rest", "to": "cheer", "t": 0.5}),
        json!({"type": "play", "take": "none", "replace": [{"puppet": 0, "at": [640.5, 360.5], "radius": 30.5}]}),
        json!({"type": "order_puppets", "order": [0]}),
        json!({"type": "cursor", "puppet": 0, "at": [0.5, 0.5]}),
        json!({"type": "key_add", "puppet": 0, "at": [0.5, 0.5]}),
        json!({"type": "key_move", "puppet": 0, "key": 0, "at": [0.25, 0.75]}),
        json!({"type": "key_delete", "puppet": 0, "key": 3}),
        json!({"type": "ping", "t": 1.5}),
    ]
}

/// Every number in `value`, as paths of keys and indices.
fn number_paths(value: &Value, path: &mut Vec<Value>, out: &mut Vec<Vec<Value>>) {
    match value {
        Value::Number(_) => out.push(path.clone()),
        Value::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                path.push(json!(i));
                number_paths(item, path, out);
                path.pop();
            }
        }
        Value::Object(fields) => {
            for (k, item) in fields {
                path.push(json!(k));
                number_paths(item, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

/// `message` as text with the number at `path` replaced by `raw` (any
/// JSON text, or text that is not JSON at all, like `NaN`).
fn with_raw(message: &Value, path: &[Value], raw: &str) -> String {
    const MARK: &str = "hostile-mark-7f3a";
    let mut m = message.clone();
    let mut at = &mut m;
    for step in path {
        at = match step {
            Value::String(k) => &mut at[k.as_str()],
            Value::Number(i) => &mut at[i.as_u64().unwrap() as usize],
            _ => unreachable!(),
        };
    }
    *at = json!(MARK);
    m.to_string().replace(&format!("\"{MARK}\""), raw)
}

/// The bad values every number is replaced with, and `extra` random ones.
fn bad_values(rng: &mut Dice, extra: usize) -> Vec<String> {
    let mut values: Vec<String> = [
        "1e308",
        "-1e308",
        "1e20",
        "-1e20",
        "-1",
        "0",
        "-0.0",
        "1e-300",
        "4294967296",
        "18446744073709551616",
        "1e999",
        "NaN",
        "null",
        "\"7\"",
        "[]",
        "{}",
        "true",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for _ in 0..extra {
        let v = f64::from_bits(rng.next());
        if v.is_finite() {
            values.push(format!("{v:e}"));
        }
        values.push((rng.next() as i64 >> 20).to_string());
    }
    values
}

async fn director(url: &str) -> Client {
    connect_url(url, hello("director", DIRECTOR)).await.0
}

/// Row: every number of every message type replaced by bad values.
async fn bad_numbers(url: &str, rng: &mut Dice) -> Row {
    let mut row = Row::new("bad numbers");
    let messages = numeric_messages();
    let values = bad_values(rng, 4 * (scale() - 1));
    let mut ws = director(url).await;
    let mut mark = 0.0;
    for message in &messages {
        let mut paths = Vec::new();
        number_paths(message, &mut Vec::new(), &mut paths);
        for path in &paths {
            for raw in &values {
                let text = with_raw(message, path, raw);
                row.tries += 1;
                mark += 1.0;
                match exchange(&mut ws, &text, mark).await {
                    Answer::Errors(errors) => row.refused += usize::from(!errors.is_empty()),
                    Answer::Closed(_) => {
                        // Twenty bad messages in a row close the
                        // connection: the stranger comes back.
                        row.refused += 1;
                        ws = director(url).await;
                    }
                    Answer::Silent => row.stalls += 1,
                }
                // Whatever a mutated `down` held is let go.
                if message["type"] == "contacts" {
                    let up = text.replace("\"down\"", "\"up\"");
                    mark += 1.0;
                    if let Answer::Closed(_) = exchange(&mut ws, &up, mark).await {
                        ws = director(url).await;
                    }
                }
            }
        }
    }
    let _ = exchange(
        &mut ws,
        &json!({"type": "reset", "puppet": 0}).to_string(),
        -1.0,
    )
    .await;
    row.notes.push(format!(
        "{} message types, {} values",
        messages.len(),
        values.len()
    ));
    row
}

/// The messages `docs/protocol.md` ("Roles") gives directors only, in a
/// valid form; and those performers may send too.
fn director_only() -> Vec<Value> {
    vec![
        json!({"type": "record", "name": "stolen"}),
        json!({"type": "stop_recording"}),
        json!({"type": "play", "take": "take-001"}),
        json!({"type": "stop_playing"}),
        json!({"type": "paint", "puppet": 0, "x": 640.0, "y": 360.0, "radius": 20.0, "strength": 0.5}),
        json!({"type": "paint_depth", "puppet": 0, "x": 640.0, "y": 360.0, "radius": 20.0, "layer": 2}),
        json!({"type": "save_weights", "puppet": 0}),
        json!({"type": "key_add", "puppet": 0, "at": [0.5, 0.5]}),
        json!({"type": "key_move", "puppet": 0, "key": 0, "at": [0.5, 0.5]}),
        json!({"type": "key_delete", "puppet": 0, "key": 0}),
        json!({"type": "save_keys", "puppet": 0}),
        json!({"type": "replay", "source": "wetab", "playing": false}),
        json!({"type": "remove_puppet", "puppet": 0}),
        json!({"type": "order_puppets", "order": [0]}),
        json!({"type": "add_curve", "name": "rope", "points": [[100.0, 100.0], [300.0, 120.0]], "width": 12.0, "colour": "#aa3300"}),
    ]
}

fn performer_may() -> Vec<Value> {
    vec![
        json!({"type": "pin", "x": 640.0, "y": 360.0}),
        json!({"type": "depth_flip", "x": 640.0, "y": 360.0}),
        json!({"type": "unpin", "puppet": 0, "handle": 99}),
        json!({"type": "pose", "puppet": 0, "from": "a", "to": "b", "t": 0.5}),
        json!({"type": "cursor", "puppet": 0, "at": [0.5, 0.5]}),
        json!({"type": "undo", "puppet": 0}),
        json!({"type": "redo", "puppet": 0}),
        json!({"type": "reset", "puppet": 0}),
        json!({"type": "contacts", "contacts": [{"id": 3, "phase": "down", "x": 10.0, "y": 10.0}]}),
    ]
}

/// Row: viewers and performers sending what only those above them may,
/// over WebSocket and HTTP.
async fn escalations(served: &Served, url: &str) -> Row {
    let mut row = Row::new("role escalations");
    let mut mark = 0.0;
    let mut attempt = async |hello: Value, message: &Value, row: &mut Row| {
        let (mut ws, _) = connect_url(url, hello).await;
        mark += 1.0;
        row.tries += 1;
        match exchange(&mut ws, &message.to_string(), mark).await {
            Answer::Errors(errors) if errors.iter().any(|e| e["code"] == "forbidden") => {
                row.refused += 1
            }
            Answer::Errors(errors) => {
                row.wrong_permission += 1;
                row.notes.push(format!("{message} answered {errors:?}"));
            }
            Answer::Closed(code) => row.notes.push(format!("{message}: closed {code}")),
            Answer::Silent => row.stalls += 1,
        }
    };
    for _ in 0..scale() {
        for message in director_only() {
            for hello in [
                json!({"type": "hello", "role": "viewer"}),
                hello("viewer", DIRECTOR),
                hello("performer", PERFORMER),
            ] {
                attempt(hello, &message, &mut row).await;
            }
        }
        for message in performer_may() {
            for hello in [
                json!({"type": "hello", "role": "viewer"}),
                hello("viewer", PERFORMER),
            ] {
                attempt(hello, &message, &mut row).await;
            }
        }
    }
    // HTTP: takes and puppets with no token or a lesser one.
    let address = served.http.as_str();
    for path in [
        "/takes/take-001.take",
        "/takes/take-001/export?format=glb&fps=10",
        "/takes/take-001/export?format=spine&fps=10",
    ] {
        for token in [None, Some(PERFORMER), Some("wrong"), Some("")] {
            let mut request = format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n");
            if let Some(token) = token {
                request += &format!("Authorization: Bearer {token}\r\n");
            }
            request += "\r\n";
            let status =
                http_status(&crate::common::daemon::http_raw(address, request.as_bytes()).await);
            row.tries += 1;
            if (200..300).contains(&status) {
                row.wrong_permission += 1;
                row.notes
                    .push(format!("GET {path} with {token:?}: {status}"));
            } else {
                row.refused += 1;
            }
        }
    }
    for token in [None, Some(PERFORMER), Some("wrong")] {
        let body = b"\x89PNG\r\n\x1a\n";
        let mut request = format!(
            "POST /puppets?name=stolen HTTP/1.1\r\nHost: {address}\r\nOrigin: http://{address}\r\nConnection: close\r\nContent-Type: image/png\r\nContent-Length: {}\r\n",
            body.len()
        );
        if let Some(token) = token {
            request += &format!("Authorization: Bearer {token}\r\n");
        }
        let mut request = (request + "\r\n").into_bytes();
        request.extend_from_slice(body);
        let status = http_status(&crate::common::daemon::http_raw(address, &request).await);
        row.tries += 1;
        if (200..300).contains(&status) {
            row.wrong_permission += 1;
            row.notes
                .push(format!("POST /puppets with {token:?}: {status}"));
        } else {
            row.refused += 1;
        }
    }
    row
}

/// Row: hellos with tokens near the real ones, and random ones.
async fn token_probes(url: &str, rng: &mut Dice) -> Row {
    let mut row = Row::new("token probes");
    let mut tokens: Vec<String> = [
        "bos",
        "boss ",
        " boss",
        "BOSS",
        "boss\u{0}",
        "bosss",
        "",
        "secret ",
        "SECRET",
        "b",
        "null",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for _ in 0..40 * scale() {
        let n = rng.within(0, 80);
        tokens.push(
            (0..n)
                .map(|_| char::from(b' ' + rng.within(0, 95) as u8))
                .collect(),
        );
    }
    for token in &tokens {
        for role in ["director", "performer"] {
            row.tries += 1;
            let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
            ws.send(Message::text(hello(role, token).to_string()))
                .await
                .unwrap();
            let mut answered = false;
            while let Ok(Some(Ok(m))) = tokio::time::timeout(WAIT, ws.next()).await {
                match m {
                    Message::Text(t) => {
                        let m: Value = serde_json::from_str(&t).unwrap();
                        if m["type"] == "stage" {
                            row.wrong_permission += 1;
                            row.notes.push(format!("{role} with {token:?} admitted"));
                            answered = true;
                            break;
                        }
                        if m["type"] == "error" && m["code"] == "bad_token" {
                            row.refused += 1;
                            answered = true;
                        }
                    }
                    Message::Close(_) => break,
                    _ => {}
                }
            }
            if !answered {
                row.stalls += 1;
            }
        }
    }
    row
}

/// Row: more WebSockets from one address than its places, while another
/// address's viewer still gets in.
async fn connections(served: &Served) -> Row {
    let mut row = Row::new("websockets from one host");
    let to: std::net::SocketAddr = served.http.parse().unwrap();
    let url = format!("ws://{to}/ws");
    let cap = 64;
    let mut held = Vec::new();
    for _ in 0..(cap + 40 * scale()) {
        row.tries += 1;
        let stream = connect_from([127, 0, 0, 5], to).await;
        match tokio_tungstenite::client_async(url.as_str(), MaybeTlsStream::Plain(stream)).await {
            // Past the cap the upgrade is answered with a close frame
            // (1013, try again later) instead of the stage.
            Ok((mut ws, _)) => {
                let hello = json!({"type": "hello", "role": "viewer"}).to_string();
                let _ = ws.send(Message::text(hello)).await;
                match tokio::time::timeout(WAIT, ws.next()).await {
                    Ok(Some(Ok(Message::Text(t)))) if t.contains("\"stage\"") => held.push(ws),
                    Err(_) => row.stalls += 1,
                    _ => row.refused += 1,
                }
            }
            Err(_) => row.refused += 1,
        }
    }
    if held.len() > cap {
        row.wrong_permission += held.len() - cap;
    }
    row.notes
        .push(format!("{} held from 127.0.0.5", held.len()));
    // Another machine is served.
    let stream = connect_from([127, 0, 0, 6], to).await;
    let other = tokio_tungstenite::client_async(url.as_str(), MaybeTlsStream::Plain(stream)).await;
    if other.is_err() {
        row.stalls += 1;
        row.notes
            .push("a viewer from 127.0.0.6 was turned away".into());
    }
    // And a page from it too.
    let mut page = connect_from([127, 0, 0, 6], to).await;
    page.write_all(&get_request("/")).await.unwrap();
    let mut answer = Vec::new();
    let _ = tokio::time::timeout(WAIT, page.read_to_end(&mut answer)).await;
    if http_status(&answer) != 200 {
        row.stalls += 1;
    }
    row
}

/// Row: a performer within every budget (40 contacts a message, the
/// most allowed) sending as fast as the socket takes it, moving them all
/// each time: the stage must keep up or drop moves, never fall behind.
async fn valid_flood(url: &str) -> Row {
    let mut row = Row::new("contact flood in budget");
    let (mut ws, stage) = connect_url(url, hello("performer", PERFORMER)).await;
    let grab = hand(&placed_mesh(&stage));
    let n = puppetry_limits::contacts::MAX_CONTACTS_PER_MESSAGE as u32;
    let message = |phase: &str, k: usize| {
        let contacts: Vec<Value> = (0..n)
            .map(|id| {
                let x = grab.x - 40.0 + f64::from(id) * 2.0;
                json!({"id": 100 + id, "phase": phase, "x": x, "y": grab.y + (k % 30) as f64})
            })
            .collect();
        json!({"type": "contacts", "contacts": contacts}).to_string()
    };
    let until = Instant::now() + Duration::from_secs(2 * scale() as u64);
    let mut k = 0;
    while Instant::now() < until {
        let phase = if k == 0 { "down" } else { "move" };
        if ws.send(Message::text(message(phase, k))).await.is_err() {
            row.notes.push("the performer was closed".into());
            break;
        }
        // What the daemon says back is read and dropped.
        while let Ok(Some(Ok(m))) = tokio::time::timeout(Duration::ZERO, ws.next()).await {
            if let Message::Text(t) = m
                && t.contains("\"error\"")
            {
                row.refused += 1;
            }
        }
        k += 1;
        row.tries += 1;
    }
    let _ = exchange(&mut ws, &message("up", k), -2.0).await;
    row
}

/// Row: ten performers, each at its limit of 40 fingers, all on the one
/// puppet, moving every finger at 100 Hz (issue 45's memory row: 707 MB
/// reported). The puppet takes `MAX_HANDLES_PER_PUPPET` of them; the rest
/// hold nothing. Its peak memory is the row's.
async fn ten_full_hands(url: &str) -> Row {
    let mut row = Row::new("10 × 40 fingers at 100 Hz");
    let mut clients = Vec::new();
    let mut mesh = None;
    for _ in 0..10 {
        let (ws, stage) = connect_url(url, hello("performer", PERFORMER)).await;
        mesh.get_or_insert_with(|| placed_mesh(&stage));
        clients.push(ws);
    }
    let mesh = mesh.expect("ten performers");
    let vertices = mesh.vertices();
    let n = puppetry_limits::contacts::MAX_HELD_PER_CLIENT;
    let message = |client: usize, phase: &str, k: usize| {
        let contacts: Vec<Value> = (0..n)
            .map(|id| {
                // Spread over the puppet, a little circle each.
                let v = vertices[(client * n + id) * 7 % vertices.len()];
                let a = k as f64 * 0.2;
                json!({"id": id, "phase": phase, "x": v.x + 3.0 * a.cos(), "y": v.y + 3.0 * a.sin()})
            })
            .collect();
        json!({"type": "contacts", "contacts": contacts}).to_string()
    };
    let until = Instant::now() + Duration::from_secs(3 * scale() as u64);
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    let mut k = 0;
    while Instant::now() < until {
        tick.tick().await;
        let phase = if k == 0 { "down" } else { "move" };
        for (c, ws) in clients.iter_mut().enumerate() {
            if ws.send(Message::text(message(c, phase, k))).await.is_err() {
                row.notes.push(format!("performer {c} was closed"));
                return row;
            }
            // What the daemon says back is read and dropped.
            while let Ok(Some(Ok(m))) = tokio::time::timeout(Duration::ZERO, ws.next()).await {
                if let Message::Text(t) = m
                    && t.contains("\"error\"")
                {
                    row.refused += 1;
                }
            }
            row.tries += 1;
        }
        k += 1;
    }
    for (c, ws) in clients.iter_mut().enumerate() {
        let _ = exchange(ws, &message(c, "up", k), -2.0).await;
    }
    row
}

/// Row: pictures at the size limit (`MAX_PICTURE_PIXELS`, a figure on a
/// transparent background) sent by a director three at a time, three
/// times (issue 45's memory row: several at once summed 994 MB). One is
/// meshed at a time; the others are answered 429 busy.
async fn big_pictures(served: &Served) -> Row {
    let mut row = Row::new("pictures at the limit ×3");
    let side = (puppetry_limits::files::MAX_PICTURE_PIXELS as f64).sqrt() as u32;
    let mut body = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut body, side, side);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        let centre = f64::from(side) / 2.0;
        let pixels: Vec<u8> = (0..side)
            .flat_map(|y| (0..side).map(move |x| (x, y)))
            .flat_map(|(x, y)| {
                let (dx, dy) = (f64::from(x) - centre, f64::from(y) - centre);
                // A wavy disc: an outline with some length to it.
                let r = centre * (0.8 + 0.1 * (8.0 * dy.atan2(dx)).sin());
                if dx * dx + dy * dy < r * r {
                    [180, 90, 40, 255]
                } else {
                    [0, 0, 0, 0]
                }
            })
            .collect();
        writer.write_image_data(&pixels).unwrap();
    }
    let request = |n: usize| {
        let mut r = format!(
            "POST /puppets?name=big{n}&vertices=2000 HTTP/1.1\r\nHost: {}\r\nContent-Type: image/png\r\n\
             Content-Length: {}\r\nAuthorization: Bearer {DIRECTOR}\r\nConnection: close\r\n\r\n",
            served.http,
            body.len()
        )
        .into_bytes();
        r.extend_from_slice(&body);
        r
    };
    for round in 0..3 {
        let sent = (0..3).map(|k| {
            let request = request(round * 3 + k);
            let address = served.http.clone();
            tokio::spawn(async move {
                crate::common::daemon::http_raw(address.as_str(), &request).await
            })
        });
        for answer in futures_util::future::join_all(sent).await {
            let status = http_status(&answer.unwrap());
            row.tries += 1;
            match status {
                200 => {}
                429 => row.refused += 1,
                other => row.notes.push(format!("answered {other}")),
            }
        }
    }
    row
}

/// Row: random and malformed OSC datagrams at the trigger port.
async fn osc_packets(served: &Served, rng: &mut Dice) -> Row {
    let mut row = Row::new("OSC datagrams");
    let to = served.osc.expect("the stage has [osc]");
    let socket = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let addresses = [
        "/puppetry/take/record",
        "/puppetry/cursor",
        "/puppetry/pose",
        "/#bundle",
        "/",
    ];
    for k in 0..2000 * scale() {
        let mut packet = Vec::new();
        match k % 4 {
            // Random bytes.
            0 => {
                let n = rng.within(0, 600);
                packet = rng.bytes(n);
            }
            // A real address with random type tags and arguments.
            1 | 2 => {
                let address = addresses[rng.within(0, addresses.len())];
                packet.extend_from_slice(address.as_bytes());
                pad(&mut packet);
                packet.push(b',');
                for _ in 0..rng.within(0, 12) {
                    packet.push(b"ifsbhtdTFNI[]x"[rng.within(0, 14)]);
                }
                pad(&mut packet);
                let n = rng.within(0, 64);
                packet.extend(rng.bytes(n));
            }
            // Nested bundles claiming more than they hold.
            _ => {
                packet.extend_from_slice(b"#bundle\0");
                packet.extend_from_slice(&[0; 8]);
                for _ in 0..rng.within(1, 40) {
                    packet.extend_from_slice(&(rng.next() as u32).to_be_bytes());
                    packet.extend_from_slice(b"#bundle\0");
                }
            }
        }
        row.tries += 1;
        let _ = socket.send_to(&packet, to).await;
        if k % 64 == 0 {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }
    row
}

/// Zeros up to the next multiple of four bytes, at least one (an OSC
/// string's end).
fn pad(packet: &mut Vec<u8>) {
    packet.push(0);
    while !packet.len().is_multiple_of(4) {
        packet.push(0);
    }
}

/// Row: an export of a 90 s take at 1000 fps in each of glb and Spine,
/// with the director's token: refused before memory grows.
async fn export_bombs(served: &Served) -> Row {
    let mut row = Row::new("export bombs");
    for format in ["glb", "spine", "png"] {
        let request = format!(
            "GET /takes/long/export?format={format}&fps=1000 HTTP/1.1\r\nHost: x\r\nConnection: close\r\nAuthorization: Bearer {DIRECTOR}\r\n\r\n"
        );
        let answer =
            crate::common::daemon::http_raw(served.http.as_str(), request.as_bytes()).await;
        row.tries += 1;
        // 413 (past the export budget); 400 for a format the route does
        // not serve.
        match http_status(&answer) {
            status @ 400.. => {
                row.refused += 1;
                if status != 413 {
                    row.notes.push(format!("{format}: {status}"));
                }
            }
            status => {
                row.wrong_permission += 1;
                row.notes.push(format!("{format}: {status}"));
            }
        }
    }
    row
}

/// How a child process ended, and its peak memory.
struct Ran {
    code: Option<i32>,
    signal: Option<i32>,
    output: String,
    peak_rss_kib: u64,
    /// Still running when given up on (killed).
    stuck: bool,
}

impl Ran {
    fn panicked(&self) -> bool {
        self.code == Some(101) || self.output.contains("panicked")
    }
}

/// Runs `command` to its end (or `limit`, then kills it), its peak memory
/// from `wait4`. `serving` ends it early, by SIGTERM, once its output says
/// it serves: a stage file that starts is an answer too.
fn run(mut command: Command, limit: Duration, serving: bool) -> Ran {
    let mut child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    let output = Arc::new(Mutex::new(String::new()));
    let readers: Vec<_> = [
        Box::new(child.stdout.take().unwrap()) as Box<dyn Read + Send>,
        Box::new(child.stderr.take().unwrap()),
    ]
    .into_iter()
    .map(|mut stream| {
        let output = output.clone();
        std::thread::spawn(move || {
            let mut buffer = [0u8; 4096];
            while let Ok(n) = stream.read(&mut buffer) {
                if n == 0 {
                    break;
                }
                let mut o = output.lock().unwrap();
                if o.len() < 1 << 20 {
                    o.push_str(&String::from_utf8_lossy(&buffer[..n]));
                }
            }
        })
    })
    .collect();
    let started = Instant::now();
    let (mut status, mut usage) = (0, unsafe { std::mem::zeroed::<libc::rusage>() });
    let mut stuck = false;
    let mut signalled = false;
    loop {
        let done = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if done == pid {
            break;
        }
        if serving && !signalled && output.lock().unwrap().contains("stop with Ctrl-C") {
            unsafe { libc::kill(pid, libc::SIGTERM) };
            signalled = true;
        }
        if started.elapsed() > limit {
            stuck = true;
            unsafe { libc::kill(pid, libc::SIGKILL) };
            unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    for r in readers {
        let _ = r.join();
    }
    std::mem::forget(child);
    let output = std::mem::take(&mut *output.lock().unwrap());
    Ran {
        code: libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status)),
        signal: (libc::WIFSIGNALED(status) && !stuck).then(|| libc::WTERMSIG(status)),
        output,
        peak_rss_kib: usage.ru_maxrss as u64,
        stuck,
    }
}

fn tally(row: &mut Row, ran: &Ran, what: &str) {
    row.tries += 1;
    if ran.panicked() {
        row.panics += 1;
        row.notes.push(format!("{what}: panicked"));
    }
    if let Some(signal) = ran.signal {
        row.crashes += 1;
        row.notes.push(format!("{what}: signal {signal}"));
    }
    if ran.stuck {
        row.stalls += 1;
        row.notes.push(format!("{what}: still running"));
    }
    if ran.code.is_some_and(|c| c != 0) {
        row.refused += 1;
    }
    row.peak_rss_mib = row.peak_rss_mib.max(ran.peak_rss_kib as f64 / 1024.0);
}

/// Row: a take damaged in every way, read by `takes --verify` and exported.
fn take_files(dir: &Path, stage: &Path, rng: &mut Dice) -> Row {
    let mut row = Row::new("crafted take files");
    let takes = dir.join("crafted");
    let good = std::fs::read(record_take(&takes)).unwrap();
    for k in 0..30 * scale() {
        let mut bytes = good.clone();
        match k % 5 {
            0 => {
                for _ in 0..rng.within(1, 8) {
                    let i = rng.within(0, bytes.len());
                    bytes[i] ^= 1 << rng.within(0, 8);
                }
            }
            1 => bytes.truncate(rng.within(0, bytes.len())),
            2 => {
                let i = rng.within(0, bytes.len());
                let n = rng.within(1, 300);
                bytes.splice(i..i, rng.bytes(n));
            }
            // Numbers in the text made huge, negative or not numbers.
            3 => {
                let text = String::from_utf8_lossy(&bytes).into_owned();
                let bad = ["1e20", "-1", "1e308", "NaN", "4294967296", "0"];
                let value = bad[rng.within(0, bad.len())];
                bytes = text.replacen("0.", value, rng.within(1, 4)).into_bytes();
            }
            _ => {
                let i = rng.within(0, bytes.len());
                bytes.truncate(i);
                bytes.extend(std::iter::repeat_n(b'9', rng.within(1, 10_000)));
            }
        }
        // `takes` reads a folder: one take in each.
        let folder = takes.join(format!("{k}"));
        std::fs::create_dir_all(&folder).unwrap();
        let file = folder.join(format!("crafted-{k}.take"));
        std::fs::write(&file, &bytes).unwrap();
        let mut verify = Command::new(env!("CARGO_BIN_EXE_puppetry"));
        verify
            .arg("takes")
            .arg("--verify")
            .arg(&folder)
            .arg("--config")
            .arg(stage);
        tally(
            &mut row,
            &run(verify, WAIT, false),
            &format!("takes --verify crafted-{k}"),
        );
        let mut export = Command::new(env!("CARGO_BIN_EXE_puppetry"));
        export
            .arg("export")
            .arg(&file)
            .arg("--config")
            .arg(stage)
            .args(["--format", "glb", "--fps", "30", "-o"])
            .arg(dir.join(format!("crafted-{k}.glb")));
        tally(
            &mut row,
            &run(export, WAIT, false),
            &format!("export crafted-{k}"),
        );
    }
    row
}

/// A short real take of the test stage, recorded by the binary from a
/// replay of a touch screen capture.
fn record_take(takes: &Path) -> PathBuf {
    std::fs::create_dir_all(takes).unwrap();
    let stage = takes.join("recording.toml");
    std::fs::write(
        &stage,
        stage_text(&crate::common::daemon::looping_capture()),
    )
    .unwrap();
    let mut command = serve_command(&stage);
    command.arg("--record").arg(takes);
    let served = Served::start(command);
    std::thread::sleep(Duration::from_millis(1500));
    served.stop();
    std::fs::read_dir(takes)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "take"))
        .expect("a take recorded")
}

/// Row: stage files with every number made bad in turn, and named files
/// that never end or are picture bombs.
fn stage_files(dir: &Path) -> Row {
    let mut row = Row::new("crafted stage files");
    let text = stage_text("");
    let numbers = number_spans(&text);
    let bad = [
        "nan",
        "inf",
        "-inf",
        "1e20",
        "0",
        "-1",
        "1e-300",
        "4294967296",
    ];
    let mut files = Vec::new();
    for &(start, end) in &numbers {
        for value in bad {
            files.push(format!("{}{value}{}", &text[..start], &text[end..]));
        }
    }
    let mesh = crate::common::daemon::root().join("assets/gingerbread/gingerbread.mesh.json");
    let image = crate::common::daemon::root().join("assets/gingerbread/gingerbread.png");
    let bomb = dir.join("bomb.png");
    write_picture_bomb(&bomb);
    for (what, instead) in [
        (&mesh, "/dev/zero"),
        (&image, "/dev/zero"),
        (&image, "/dev/urandom"),
        (&mesh, "/"),
        (&image, bomb.to_str().unwrap()),
    ] {
        files.push(text.replace(&what.display().to_string(), instead));
    }
    for extra in [
        "[[input]]\nkind = \"replay\"\nname = \"zero\"\nfile = \"/dev/zero\"\n",
        "[[input]]\nkind = \"replay\"\nname = \"client:1\"\nfile = \"/dev/null\"\n",
        "[stage]\nwidth = 1\n",
    ] {
        files.push(stage_text(extra));
    }
    for (k, file) in files.iter().enumerate() {
        let path = dir.join(format!("stage-{k}.toml"));
        std::fs::write(&path, file).unwrap();
        tally(
            &mut row,
            &run(serve_command(&path), WAIT, true),
            &format!("stage-{k}.toml"),
        );
    }
    row.notes.push(format!(
        "{} numbers × {} values, 8 named files",
        numbers.len(),
        bad.len()
    ));
    row
}

/// Where the numbers of a stage file's values are (after `= ` or inside
/// an array), as byte ranges.
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let bytes = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    let mut in_string = false;
    while i < bytes.len() {
        let c = bytes[i];
        if c == b'"' {
            in_string = !in_string;
        }
        let starts = !in_string
            && (c.is_ascii_digit() || c == b'-')
            && i > 0
            && matches!(bytes[i - 1], b' ' | b'[' | b',');
        if starts {
            let end = (i + 1..bytes.len())
                .find(|&j| !(bytes[j].is_ascii_digit() || bytes[j] == b'.'))
                .unwrap_or(bytes.len());
            spans.push((i, end));
            i = end;
        } else {
            i += 1;
        }
    }
    spans
}

/// A small PNG that claims 16384 × 16384 pixels (a 1 GB RGBA picture).
fn write_picture_bomb(path: &Path) {
    let file = std::fs::File::create(path).unwrap();
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), 16384, 16384);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::One);
    let mut writer = encoder.write_header().unwrap();
    let row = vec![0u8; 16384 / 8];
    let mut stream = writer.stream_writer().unwrap();
    for _ in 0..16384 {
        std::io::Write::write_all(&mut stream, &row).unwrap();
    }
    stream.finish().unwrap();
}

/// Counts the daemon's panics since its log's line `from`.
fn daemon_panics(served: &Served, from: usize) -> usize {
    served.log()[from.min(served.log().len())..]
        .iter()
        .filter(|l| l.contains("panicked"))
        .count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_strangers_table() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    write_take(&takes, "take-001", 2.0);
    write_take(&takes, "long", 90.0);
    let osc = "\n[osc]\nlisten = \"127.0.0.1:0\"\nsend = []\nrate = 60\n";
    let mut served = serve(dir.path(), &stage_text(osc));
    let url = served.ws_url();
    let watch = Watch::start(&url).await;
    let mut rng = Dice(32);
    println!(
        "| {:<26} | {:>6} | {:>7} | {:>5} | {:>6} | {:>7} | {:>6} | {:>8} | {:>8} |",
        "row", "tries", "refused", "wrong", "panics", "crashes", "stalls", "gap ms", "RSS MiB"
    );
    println!("|{}|", ["---"; 9].join("|"));
    let mut rows = Vec::new();
    watch.take_gap_ms();
    for k in 0..9 {
        let from = served.log().len();
        let mut row = match k {
            0 => bad_numbers(&url, &mut rng).await,
            1 => escalations(&served, &url).await,
            2 => token_probes(&url, &mut rng).await,
            3 => connections(&served).await,
            4 => osc_packets(&served, &mut rng).await,
            5 => valid_flood(&url).await,
            6 => ten_full_hands(&url).await,
            7 => big_pictures(&served).await,
            _ => export_bombs(&served).await,
        };
        // Let the last of it land before reading the daemon.
        tokio::time::sleep(Duration::from_millis(300)).await;
        row.panics += daemon_panics(&served, from);
        row.crashes += usize::from(!served.alive());
        row.longest_gap_ms = watch.take_gap_ms();
        row.peak_rss_mib = served.peak_rss_kib() as f64 / 1024.0;
        row.print();
        rows.push(row);
    }
    watch.stop().await;
    let stage = dir.path().join("stage.toml");
    for row in [
        take_files(dir.path(), &stage, &mut rng),
        stage_files(dir.path()),
    ] {
        row.print();
        rows.push(row);
    }
    assert!(served.alive());
    served.stop();
    let failed: Vec<&str> = rows.iter().filter(|r| r.failed()).map(|r| r.name).collect();
    assert!(failed.is_empty(), "rows failed: {failed:?}");
}
