//! Show control over OSC end to end (`docs/osc.md`): the real `puppetry
//! serve` binary on a stage file with an `[osc]` section, a UDP socket on
//! 127.0.0.1:0 standing in for the desk that receives the state, another
//! sending triggers, and a WebSocket viewer checking that the triggers did
//! what they say. Also: a flood of malformed datagrams panics nothing and
//! logs a bounded number of lines, and bad `[osc]` sections are refused
//! naming the field.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use futures_util::SinkExt;
use glam::DVec2;
use puppetry_daemon::protocol::{FrameKind, decode_frame};
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};
use serde_json::{Value, json};
use tokio::net::UdpSocket;
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::{
    Client, WAIT, hand, next_message, next_text, placed_mesh, root, stage_text,
};
use crate::common::served::serve;
use puppetry_testkit::stage_text::Gingerbread;

async fn connect(http: &str, hello: Value) -> (Client, Value) {
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{http}/ws"))
        .await
        .unwrap();
    ws.send(Message::text(hello.to_string())).await.unwrap();
    let stage = next_text(&mut ws).await;
    assert_eq!(stage["type"], "stage", "{stage}");
    (ws, stage)
}

/// Reads text messages until one satisfies `done`.
async fn text_until(ws: &mut Client, done: impl Fn(&Value) -> bool) -> Value {
    loop {
        let m = next_text(ws).await;
        if done(&m) {
            return m;
        }
    }
}

/// The desk's end: receives the state the daemon sends.
struct Desk {
    socket: UdpSocket,
}

impl Desk {
    async fn new() -> Desk {
        Desk {
            socket: UdpSocket::bind("127.0.0.1:0").await.unwrap(),
        }
    }

    fn address(&self) -> SocketAddr {
        self.socket.local_addr().unwrap()
    }

    /// Reads datagrams until a message satisfies `done` (in time).
    async fn until(&self, what: &str, mut done: impl FnMut(&OscMessage) -> bool) -> OscMessage {
        let read = async {
            let mut buffer = vec![0u8; 65_536];
            loop {
                let (n, _) = self.socket.recv_from(&mut buffer).await.unwrap();
                let (_, packet) = rosc::decoder::decode_udp(&buffer[..n]).unwrap();
                let OscPacket::Bundle(bundle) = packet else {
                    panic!("the state comes in bundles: {packet:?}");
                };
                for packet in bundle.content {
                    let OscPacket::Message(m) = packet else {
                        panic!("bundles of messages: {packet:?}");
                    };
                    if done(&m) {
                        return m;
                    }
                }
            }
        };
        tokio::time::timeout(WAIT, read)
            .await
            .unwrap_or_else(|_| panic!("no OSC message: {what}"))
    }
}

/// Sends one trigger to the daemon.
async fn trigger(osc: SocketAddr, address: &str, args: Vec<OscType>) {
    let packet = OscPacket::Message(OscMessage {
        addr: address.into(),
        args,
    });
    send_raw(osc, &rosc::encoder::encode(&packet).unwrap()).await;
}

async fn send_raw(osc: SocketAddr, datagram: &[u8]) {
    let socket = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    socket.send_to(datagram, osc).await.unwrap();
}

fn s(v: &str) -> OscType {
    OscType::String(v.into())
}

fn int(m: &OscMessage, i: usize) -> i32 {
    match m.args[i] {
        OscType::Int(v) => v,
        ref other => panic!("{}: argument {i} is {other:?}", m.addr),
    }
}

fn float(m: &OscMessage, i: usize) -> f64 {
    match m.args[i] {
        OscType::Float(v) => f64::from(v),
        ref other => panic!("{}: argument {i} is {other:?}", m.addr),
    }
}

fn string(m: &OscMessage, i: usize) -> &str {
    match &m.args[i] {
        OscType::String(v) => v,
        other => panic!("{}: argument {i} is {other:?}", m.addr),
    }
}

/// An `[osc]` section listening on a free port, sending to `send`.
fn osc_section(send: &[String]) -> String {
    format!("\n[osc]\nlisten = \"127.0.0.1:0\"\nsend = {send:?}\nrate = 60\n")
}

/// A host every send to fails (a broadcast address, which the daemon's
/// socket may not send to).
const REFUSED: &str = "255.255.255.255:9";

/// The warnings of a log, and how many it may have: five lines and one
/// "held back" line per ten-second window of the daemon's life.
fn warnings(log: &[String], began: Instant) -> (Vec<&String>, usize) {
    let windows = began.elapsed().as_secs() as usize / 10 + 1;
    (
        log.iter().filter(|l| l.contains("WARN")).collect(),
        6 * windows,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn osc_sends_the_handles_of_a_drag_and_triggers_start_and_stop_a_take() {
    let dir = tempfile::tempdir().unwrap();
    let desk = Desk::new().await;
    let began = Instant::now();
    // A host that refuses every datagram comes first: the desk after it
    // still gets everything.
    let send = [REFUSED.to_string(), desk.address().to_string()];
    let served = serve(dir.path(), &stage_text(&osc_section(&send)));
    let osc = served
        .osc
        .expect("the daemon printed where OSC triggers go");

    // Before anything: the puppet list and its two stage-file pins.
    let puppets = desk
        .until("the puppet list", |m| m.addr == "/puppetry/puppets")
        .await;
    assert_eq!(puppets.args, [s("gingerbread")]);
    desk.until("two pins", |m| {
        m.addr == "/puppetry/puppet/gingerbread/handles" && int(m, 0) == 2
    })
    .await;

    // A performer grabs the hand: the desk gets the contact's handle.
    let (mut performer, stage) = connect(
        &served.http,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    let owner = format!("client:{}", stage["client"]);
    let grab = hand(&placed_mesh(&stage));
    let contact = |phase: &str, at: DVec2| {
        let c = json!([{"id": 1, "phase": phase, "x": at.x, "y": at.y}]);
        Message::text(json!({"type": "contacts", "contacts": c}).to_string())
    };
    performer.send(contact("down", grab)).await.unwrap();
    for k in 1..=10 {
        let at = grab + DVec2::new(6.0, 4.0) * f64::from(k);
        performer.send(contact("move", at)).await.unwrap();
    }
    let held = desk
        .until("the performer's handle", |m| {
            m.addr.starts_with("/puppetry/puppet/gingerbread/handle/") && string(m, 1) == owner
        })
        .await;
    assert!(int(&held, 0) > 0, "a handle id: {held:?}");
    assert_eq!(string(&held, 2), "contact");
    // The handle's point follows the finger (handle frames), not where
    // it landed: it ends where the drag ends.
    let end = grab + DVec2::new(60.0, 40.0);
    desk.until("the handle at the end of the drag", |m| {
        m.addr == held.addr
            && string(m, 1) == owner
            && DVec2::new(float(m, 3), float(m, 4)).distance(end) < 0.5
    })
    .await;
    desk.until("three handles", |m| {
        m.addr == "/puppetry/puppet/gingerbread/handles" && int(m, 0) == 3
    })
    .await;
    // Let go: the slot says it is empty, the count drops back.
    performer
        .send(contact("up", grab + DVec2::new(60.0, 40.0)))
        .await
        .unwrap();
    let emptied = desk
        .until("the slot emptied", |m| {
            m.addr == held.addr && int(m, 0) == 0
        })
        .await;
    assert_eq!(string(&emptied, 1), "");
    desk.until("two handles again", |m| {
        m.addr == "/puppetry/puppet/gingerbread/handles" && int(m, 0) == 2
    })
    .await;

    // A trigger starts a take: every page and the desk see it recording.
    let (mut viewer, _) = connect(&served.http, json!({"type": "hello", "role": "viewer"})).await;
    trigger(osc, "/puppetry/take/start", vec![s("osc-take")]).await;
    text_until(&mut viewer, |m| {
        m["type"] == "take" && m["recording"] == "osc-take"
    })
    .await;
    desk.until("recording", |m| {
        m.addr == "/puppetry/take/recording" && m.args == [OscType::Int(1), s("osc-take")]
    })
    .await;
    desk.until("the take's clock running", |m| {
        m.addr == "/puppetry/take/elapsed" && float(m, 0) > 0.0
    })
    .await;
    // And another stops it: the take is on disk, ended by the stop.
    trigger(osc, "/puppetry/take/stop", vec![]).await;
    text_until(&mut viewer, |m| {
        m["type"] == "take" && m["recording"].is_null()
    })
    .await;
    desk.until("not recording", |m| {
        m.addr == "/puppetry/take/recording" && m.args == [OscType::Int(0), s("")]
    })
    .await;
    let take = dir.path().join("takes/osc-take.take");
    assert_eq!(puppetry_take::summarize(&take).unwrap().ending, "stopped");
    // The refused host is logged, a few lines a window, and nothing else.
    let log = served.stop();
    let (warned, bound) = warnings(&log, began);
    assert!(!warned.is_empty(), "the refused host is logged");
    assert!(warned.len() <= bound, "{}", log.join("\n"));
    assert!(
        warned.iter().all(|l| l.contains(REFUSED)),
        "{}",
        log.join("\n")
    );
}

/// The demo puppet keyframed (its key file) and a skeleton beside it.
fn keys_and_skeleton(send: SocketAddr) -> String {
    let assets = root().join("assets/gingerbread");
    let skeleton = std::fs::read_to_string(root().join("config/skeleton.toml")).unwrap();
    // The skeleton stage's rig, its replay left out (it would fight the
    // triggers).
    let rig =
        &skeleton[skeleton.find("[puppet.skeleton]").unwrap()..skeleton.find("[[input]]").unwrap()];
    format!(
        r#"
[stage]
width = 1280
height = 720
listen = "127.0.0.1:0"

{keyed}
{dancer}
{osc}"#,
        keyed = Gingerbread::new("gingerbread").hand_pins().with(&format!(
            "keys = \"{}\"",
            assets.join("gingerbread.keys.json").display()
        )),
        dancer = Gingerbread::new("dancer").with(rig),
        osc = osc_section(&[send.to_string()]),
    )
}

/// Reads until a rig frame of `puppet` satisfies `done`; returns its points.
async fn rig_until(ws: &mut Client, puppet: u32, done: impl Fn(&[DVec2]) -> bool) -> Vec<DVec2> {
    loop {
        if let Message::Binary(bytes) = next_message(ws).await {
            let frame = decode_frame(&bytes).unwrap();
            if frame.header.kind == FrameKind::Rig
                && frame.header.puppet == puppet
                && done(&frame.points)
            {
                return frame.points;
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn osc_triggers_move_the_keyframing_cursor_pose_a_skeleton_and_reset_puppets() {
    let dir = tempfile::tempdir().unwrap();
    let desk = Desk::new().await;
    let served = serve(dir.path(), &keys_and_skeleton(desk.address()));
    let osc = served.osc.unwrap();
    let (mut viewer, stage) =
        connect(&served.http, json!({"type": "hello", "role": "viewer"})).await;
    let rest: Vec<DVec2> =
        serde_json::from_value::<Vec<[f64; 2]>>(stage["puppets"][1]["rig"]["rest"].clone())
            .unwrap()
            .into_iter()
            .map(DVec2::from)
            .collect();

    // The pad cursor, by name and by index.
    trigger(
        osc,
        "/puppetry/puppet/gingerbread/cursor",
        vec![OscType::Float(0.25), OscType::Float(0.75)],
    )
    .await;
    text_until(&mut viewer, |m| {
        m["type"] == "keys" && m["puppet"] == 0 && m["cursor"] == json!([0.25, 0.75])
    })
    .await;
    desk.until("the cursor", |m| {
        m.addr == "/puppetry/puppet/gingerbread/cursor"
            && m.args == [OscType::Int(1), OscType::Float(0.25), OscType::Float(0.75)]
    })
    .await;
    // A keyframing key by name: the cursor glides onto its pad point.
    trigger(
        osc,
        "/puppetry/puppet/0/key",
        vec![s("wave right"), OscType::Float(0.2)],
    )
    .await;
    text_until(&mut viewer, |m| {
        m["type"] == "keys" && m["cursor"] == json!([0.85, 0.85])
    })
    .await;
    trigger(osc, "/puppetry/puppet/0/cursor/off", vec![]).await;
    text_until(&mut viewer, |m| {
        m["type"] == "keys" && m["cursor"].is_null()
    })
    .await;
    desk.until("the cursor let go", |m| {
        m.addr == "/puppetry/puppet/gingerbread/cursor" && int(m, 0) == 0
    })
    .await;

    // A pose between two of the skeleton's key poses: its joints move
    // (the left hand, joint 6, turns with "cheer") and the desk hears it.
    trigger(
        osc,
        "/puppetry/puppet/dancer/pose",
        vec![s("rest"), s("cheer"), OscType::Float(0.5)],
    )
    .await;
    let posed = rig_until(&mut viewer, 1, |joints| joints[6].distance(rest[6]) > 10.0).await;
    assert!(posed[0].distance(rest[0]) < 1e-3, "the root stays");
    desk.until("the pose", |m| {
        m.addr == "/puppetry/puppet/dancer/pose"
            && m.args == [s("rest"), s("cheer"), OscType::Float(0.5)]
    })
    .await;
    // Blend to a named pose: from the nearer of the two (cheer), ending
    // on the named one.
    trigger(
        osc,
        "/puppetry/puppet/dancer/key",
        vec![s("crouch"), OscType::Float(0.2)],
    )
    .await;
    desk.until("the blend's end", |m| {
        m.addr == "/puppetry/puppet/dancer/pose"
            && m.args == [s("cheer"), s("crouch"), OscType::Float(1.0)]
    })
    .await;
    // A key pose nobody has is refused by name (in the log).
    trigger(osc, "/puppetry/puppet/dancer/key", vec![s("moonwalk")]).await;
    trigger(
        osc,
        "/puppetry/puppet/dancer/pose",
        vec![s("rest"), s("moonwalk"), OscType::Int(1)],
    )
    .await;
    // Triggers are handled in order: once this one shows, both were seen.
    trigger(
        osc,
        "/puppetry/puppet/gingerbread/cursor",
        vec![OscType::Int(0), OscType::Int(1)],
    )
    .await;
    text_until(&mut viewer, |m| {
        m["type"] == "keys" && m["cursor"] == json!([0.0, 1.0])
    })
    .await;
    // Reset every puppet (a pattern): the skeleton back at rest, the
    // cursor let go, for every page and the desk.
    trigger(osc, "/puppetry/puppet/*/reset", vec![]).await;
    // (The page gets the frame and the pose message in either order.)
    let (mut pose_at_rest, mut frame_at_rest) = (false, false);
    while !(pose_at_rest && frame_at_rest) {
        match next_message(&mut viewer).await {
            Message::Text(text) => {
                let m: Value = serde_json::from_str(&text).unwrap();
                pose_at_rest |= m["type"] == "pose" && m["puppet"] == 1 && m["from"].is_null();
            }
            Message::Binary(bytes) => {
                let frame = decode_frame(&bytes).unwrap();
                frame_at_rest |= frame.header.kind == FrameKind::Rig
                    && frame.header.puppet == 1
                    && frame.points[6].distance(rest[6]) < 1e-3;
            }
            _ => {}
        }
    }
    desk.until("the pose at rest", |m| {
        m.addr == "/puppetry/puppet/dancer/pose" && m.args == [s(""), s(""), OscType::Float(0.0)]
    })
    .await;
    desk.until("the cursor let go by the reset", |m| {
        m.addr == "/puppetry/puppet/gingerbread/cursor" && int(m, 0) == 0
    })
    .await;
    let log = served.stop().join("\n");
    assert!(
        log.contains("/puppetry/puppet/dancer/key: name: no key pose \"moonwalk\""),
        "{log}"
    );
    assert!(
        log.contains("/puppetry/puppet/dancer/pose") && log.contains("moonwalk"),
        "{log}"
    );
}

/// Malformed datagrams of every kind a stranger could send.
fn malformed() -> Vec<Vec<u8>> {
    let message = |addr: &str, args: Vec<OscType>| {
        rosc::encoder::encode(&OscPacket::Message(OscMessage {
            addr: addr.into(),
            args,
        }))
        .unwrap()
    };
    let mut deep = OscPacket::Message(OscMessage {
        addr: "/puppetry/take/stop".into(),
        args: vec![],
    });
    for _ in 0..40 {
        deep = OscPacket::Bundle(OscBundle {
            timetag: OscTime::from((0, 1)),
            content: vec![deep],
        });
    }
    let valid = message("/puppetry/take/start", vec![s("x")]);
    vec![
        b"not osc at all".to_vec(),
        Vec::new(),
        vec![0xff; 3000],
        valid[..valid.len() - 3].to_vec(),
        message("/puppetry/take/rewind", vec![]),
        message(&format!("/puppetry/{}", "z".repeat(4000)), vec![]),
        message("/puppetry/puppet/nobody/reset", vec![]),
        message(
            "/puppetry/puppet/gingerbread/pose",
            vec![OscType::Blob(vec![0; 2000])],
        ),
        message(
            "/puppetry/puppet/gingerbread/cursor",
            vec![OscType::Double(f64::NAN), OscType::Float(1.0)],
        ),
        message("/puppetry/puppet/*/[", vec![]),
        rosc::encoder::encode(&deep).unwrap(),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_osc_panics_nothing_and_logs_a_bounded_number_of_lines() {
    let dir = tempfile::tempdir().unwrap();
    let began = Instant::now();
    let served = serve(dir.path(), &stage_text(&osc_section(&[])));
    let osc = served.osc.unwrap();
    let kinds = malformed();
    let socket = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    for k in 0..3000 {
        socket.send_to(&kinds[k % kinds.len()], osc).await.unwrap();
    }
    // Still listening: a good trigger after the flood starts a take (sent
    // until it shows: the flood may have filled the socket's buffer).
    let take = dir.path().join("takes/after-the-flood.take");
    let deadline = Instant::now() + WAIT;
    while !take.exists() {
        assert!(
            Instant::now() < deadline,
            "the trigger after the flood did nothing"
        );
        trigger(osc, "/puppetry/take/start", vec![s("after-the-flood")]).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let log = served.stop();
    let (warned, bound) = warnings(&log, began);
    assert!(!warned.is_empty(), "the bad packets are logged");
    assert!(
        warned.len() <= bound,
        "{} warnings:\n{}",
        warned.len(),
        log.join("\n")
    );
    assert!(
        log.iter().all(|l| l.len() < 600),
        "echoed input is cut short"
    );
    assert!(
        !log.iter().any(|l| l.contains("panicked")),
        "{}",
        log.join("\n")
    );
}

fn parse(text: &str) -> Result<puppetry_daemon::config::ShowConfig, String> {
    puppetry_daemon::config::ShowConfig::parse("osc.toml", text, Path::new("/"))
        .map_err(|e| e.to_string())
}

#[test]
fn bad_osc_sections_are_named_and_explained() {
    let base = "[stage]\nwidth = 100\nheight = 100\n[osc]\n";
    let good = parse(&format!(
        "{base}listen = \"127.0.0.1:9000\"\nsend = [\"localhost:9001\", \"[::1]:9002\"]\n"
    ))
    .unwrap();
    let osc = good.osc.unwrap();
    assert_eq!((osc.rate, osc.prefix.as_str()), (30.0, "/puppetry"));
    for (section, says) in [
        ("", "osc.toml: osc: give `listen`"),
        (
            "send = [\"a:1\"]\nrate = 0\n",
            "osc.rate: must be between 1 and 120",
        ),
        ("send = [\"a:1\"]\nrate = 1000\n", "osc.rate"),
        ("send = [\"a:1\"]\nprefix = \"puppetry\"\n", "osc.prefix"),
        ("send = [\"a:1\"]\nprefix = \"/pup pets\"\n", "osc.prefix"),
        ("send = [\"a:1\"]\nprefix = \"/p/\"\n", "osc.prefix"),
        (
            "send = [\"a:1\", \"nowhere\"]\n",
            "osc.send[1]: \"nowhere\": expected host:port",
        ),
        (
            "send = [\"a:0\"]\n",
            "osc.send[0]: \"a:0\": the port must be 1 to 65535",
        ),
        ("send = [\"::1:9000\"]\n", "osc.send[0]"),
        ("listen = \"here\"\n", "listen"),
        ("send = [\"a:1\"]\nport = 9000\n", "port"),
    ] {
        let message = parse(&format!("{base}{section}")).unwrap_err();
        assert!(message.contains(says), "{says}: {message}");
    }
}

/// The `[osc]` example commented out in `config/demo.toml`, uncommented.
fn demo_example() -> (PathBuf, String) {
    let path = root().join("config/demo.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let example: Vec<&str> = text
        .lines()
        .skip_while(|l| !l.starts_with("# [osc]"))
        .take_while(|l| l.starts_with('#'))
        .filter_map(|l| l.strip_prefix("# "))
        .filter(|l| !l.starts_with(' ') && !l.is_empty())
        .collect();
    (path, example.join("\n"))
}

#[test]
fn the_demo_stages_osc_example_parses() {
    let (path, example) = demo_example();
    assert!(
        example.starts_with("[osc]"),
        "{}: no [osc] example",
        path.display()
    );
    let text = format!("{}\n{example}\n", std::fs::read_to_string(&path).unwrap());
    let config = parse(&text).unwrap();
    let osc = config.osc.expect("the example has an [osc] section");
    assert!(
        osc.listen.is_some_and(|a| a.ip().is_loopback()),
        "loopback only"
    );
    assert!(!osc.send.is_empty());
}
