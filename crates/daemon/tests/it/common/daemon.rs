//! A daemon on 127.0.0.1:0 with the demo puppet, and a WebSocket client's
//! view of it: the helpers every end-to-end test drives it with.

use std::path::{Path, PathBuf};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use glam::DVec2;
use puppetry_daemon::config::ShowConfig;
use puppetry_daemon::protocol::{FrameKind, decode_frame};
use puppetry_daemon::serve::{Running, start};
use puppetry_mesh::Mesh;
use puppetry_testkit::stage_text::Gingerbread;
use serde_json::Value;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

pub type Client = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// How long a test waits for the next message it is owed. Generous: the
/// daemon's promises, not the machine's load, decide pass or fail.
pub const WAIT: Duration = Duration::from_secs(20);

/// How long a test lets a looping replay play until it has seen every state
/// it waits for.
pub const PLAYS: Duration = Duration::from_secs(120);

pub fn root() -> PathBuf {
    puppetry_testkit::root()
}

/// A stage with the demo puppet, its feet pinned, on a free port.
pub fn stage_config(extra: &str) -> ShowConfig {
    ShowConfig::parse("test.toml", &stage_text(extra), Path::new("/")).unwrap()
}

/// The stage file text of [`stage_config`] (for tests that run the binary
/// on a file).
pub fn stage_text(extra: &str) -> String {
    format!(
        r#"
[stage]
width = 1280
height = 720
listen = "127.0.0.1:0"
client_timeout_s = 10

[access]
performer_tokens = ["secret"]
[[access.person]]
name = "Director"
role = "director"
token = "boss"

{puppet}{extra}
"#,
        puppet = Gingerbread::new("gingerbread").hand_pins(),
    )
}

/// An `[[input]]` replaying a real capture (a WeTab's touch screen) in a
/// loop, calibrated onto the puppet's middle.
pub fn looping_capture() -> String {
    let evemu = root().join("../shared/fixtures/evemu");
    format!(
        r#"
[[input]]
kind = "replay"
name = "wetab"
file = "{wetab}"
repeat = true
calibration = {{ kind = "range", x = [0, 32760], y = [0, 32760], flip_y = true, stage_min = [590, 320], stage_max = [690, 400] }}
"#,
        wetab = evemu.join("wetab.event").display(),
    )
}

pub async fn daemon(extra: &str) -> Running {
    start(
        &stage_config(extra),
        puppetry_daemon::stream::WebFiles::Embedded,
        None,
    )
    .await
    .unwrap()
}

pub async fn connect(running: &Running, hello: Value) -> (Client, Value) {
    connect_url(&format!("ws://{}/ws", running.address), hello).await
}

/// A TCP connection to `to` from the local address `from` (any of
/// 127.0.0.0/8 on Linux): a second or third "machine" for per-address caps.
pub async fn connect_from(from: [u8; 4], to: std::net::SocketAddr) -> TcpStream {
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.bind(std::net::SocketAddr::from((from, 0))).unwrap();
    socket.connect(to).await.unwrap()
}

/// A client of the WebSocket at `url` that said `hello`, and the stage
/// message it was answered with.
pub async fn connect_url(url: &str, hello: Value) -> (Client, Value) {
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    ws.send(Message::text(hello.to_string())).await.unwrap();
    let stage = next_text(&mut ws).await;
    (ws, stage)
}

pub async fn next_message(ws: &mut Client) -> Message {
    tokio::time::timeout(WAIT, ws.next())
        .await
        .expect("a message in time")
        .expect("connection open")
        .expect("no error")
}

pub async fn next_text(ws: &mut Client) -> Value {
    loop {
        if let Message::Text(text) = next_message(ws).await {
            return serde_json::from_str(&text).unwrap();
        }
    }
}

/// A decoded vertex frame.
pub struct Frame {
    pub puppet: u32,
    pub sequence: u64,
    pub vertices: Vec<DVec2>,
}

pub fn decode(bytes: &[u8]) -> Frame {
    let frame = decode_frame(bytes).expect("a well-formed frame");
    assert_eq!(frame.header.kind, FrameKind::Vertices, "vertex frame kind");
    Frame {
        puppet: frame.header.puppet,
        sequence: frame.header.sequence,
        vertices: frame.points,
    }
}

/// Reads until a frame satisfies `done`; returns it.
pub async fn frame_until(ws: &mut Client, mut done: impl FnMut(&Frame) -> bool) -> Frame {
    loop {
        if let Message::Binary(bytes) = next_message(ws).await {
            // Rig and handles frames share the socket: only vertex frames.
            if decode_frame(&bytes).is_ok_and(|f| f.header.kind != FrameKind::Vertices) {
                continue;
            }
            let frame = decode(&bytes);
            if done(&frame) {
                return frame;
            }
        }
    }
}

/// The puppet's rest mesh as placed on the stage, from the stage message.
pub fn placed_mesh(stage: &Value) -> Mesh {
    puppet_mesh(stage, 0)
}

/// The rest mesh of the stage message's `index`-th puppet, as placed.
pub fn puppet_mesh(stage: &Value, index: usize) -> Mesh {
    let p = &stage["puppets"][index];
    let rest: Vec<f64> = serde_json::from_value(p["rest"].clone()).unwrap();
    let triangles: Vec<u32> = serde_json::from_value(p["triangles"].clone()).unwrap();
    let vertices = rest.chunks(2).map(|c| DVec2::new(c[0], c[1])).collect();
    let triangles = triangles.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    Mesh::new("stage", vertices, triangles, None, None).unwrap()
}

/// A point on the puppet's raised hand, in stage coordinates.
pub fn hand(mesh: &Mesh) -> DVec2 {
    // The right-most vertex is on the right hand; step inwards a little.
    let v = mesh
        .vertices()
        .iter()
        .copied()
        .fold(DVec2::splat(f64::NEG_INFINITY), |a, b| {
            if b.x > a.x { b } else { a }
        });
    v - DVec2::new(15.0, 0.0)
}

/// The owners of a "handles" message's contact handles.
pub fn contact_owners(m: &Value) -> Vec<String> {
    m["handles"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|h| h["kind"] == "contact")
        .map(|h| h["owner"].as_str().unwrap().to_string())
        .collect()
}

/// Reads until a "handles" message whose contact owners satisfy `done`.
pub async fn until_contact_owners(ws: &mut Client, done: impl Fn(&[String]) -> bool) {
    let waited = tokio::time::timeout(PLAYS, async {
        loop {
            let m = next_text(ws).await;
            if m["type"] == "handles" && done(&contact_owners(&m)) {
                return;
            }
        }
    });
    waited
        .await
        .expect("the contact handles waited for, within the wait");
}

/// Where the material point that lay at `rest_point` is in a frame. Handles
/// are hard constraints, so a grabbed point is exactly at its target.
pub fn follow(mesh: &Mesh, rest_point: DVec2) -> impl Fn(&Frame) -> DVec2 + use<> {
    let hit = puppetry_mesh::Locator::new(mesh)
        .locate(mesh, rest_point)
        .expect("on the puppet");
    let corners = mesh.triangles()[hit.triangle as usize];
    move |frame: &Frame| {
        corners
            .iter()
            .zip(hit.bary)
            .map(|(&v, w)| frame.vertices[v as usize] * w)
            .sum()
    }
}

/// Sends `request` as it is over a new connection and returns the whole
/// answer (the server closes the connection after it, or [`WAIT`] runs
/// out). A write the server cut short is not an error: it may answer and
/// close before a huge request is all sent.
pub async fn http_raw(address: impl tokio::net::ToSocketAddrs, request: &[u8]) -> Vec<u8> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = TcpStream::connect(address).await.unwrap();
    let _ = stream.write_all(request).await;
    let mut answer = Vec::new();
    let _ = tokio::time::timeout(WAIT, stream.read_to_end(&mut answer)).await;
    answer
}

/// A GET request for `path` that asks the server to close after answering.
pub fn get_request(path: &str) -> Vec<u8> {
    format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").into_bytes()
}

/// The whole answer to a GET of `path`.
pub async fn http_get(address: impl tokio::net::ToSocketAddrs, path: &str) -> Vec<u8> {
    http_raw(address, &get_request(path)).await
}

/// An HTTP answer's status code.
pub fn http_status(answer: &[u8]) -> u16 {
    answer
        .strip_prefix(b"HTTP/1.1 ")
        .and_then(|rest| rest.get(..3))
        .and_then(|code| std::str::from_utf8(code).ok()?.parse().ok())
        .unwrap_or_else(|| panic!("not an HTTP answer: {:?}", String::from_utf8_lossy(answer)))
}
