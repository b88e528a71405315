//! Issue 12's stage side end to end, over WebSocket on 127.0.0.1:0: handle
//! dots that follow the puppet (handles frames), safe edits (brush bounds,
//! versioned weight files, undo, redo, reset, and takes with them that
//! replay exactly), the whole live state for newcomers, replays paused and
//! played from the page, and skeletons grabbed anywhere on their shape.

use std::collections::HashMap;
use std::path::Path;

use futures_util::SinkExt;
use glam::DVec2;
use puppetry_daemon::config::ShowConfig;
use puppetry_daemon::protocol::{FrameKind, decode_frame};
use puppetry_daemon::serve::{Options, Running, start_with};
use puppetry_daemon::stream::WebFiles;
use puppetry_stage::Stage;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::{
    Client, connect, daemon, follow, hand, next_message, placed_mesh, root, stage_text,
};

const PERFORMER: &str = "secret";
/// The test stage's director: painting, saving and undo are theirs.
const DIRECTOR: &str = "boss";

/// A text message's type and a test it must pass.
type Wanted<'a> = (&'a str, &'a dyn Fn(&Value) -> bool);

/// A connection that keeps what it has read: the newest text message of
/// each type (and per puppet) and recent frames by kind and sequence.
struct Conn {
    ws: Client,
    texts: Vec<Value>,
    /// (kind, sequence) → (header generation, points).
    frames: HashMap<(u32, u64), (u32, Vec<DVec2>)>,
}

impl Conn {
    async fn open(running: &Running, hello: Value) -> (Conn, Value) {
        let (ws, stage) = connect(running, hello).await;
        let conn = Conn {
            ws,
            texts: Vec::new(),
            frames: HashMap::new(),
        };
        (conn, stage)
    }

    async fn performer(running: &Running, token: &str) -> (Conn, Value) {
        Conn::open(
            running,
            json!({"type": "hello", "role": "performer", "token": token}),
        )
        .await
    }

    async fn viewer(running: &Running) -> (Conn, Value) {
        Conn::open(running, json!({"type": "hello", "role": "viewer"})).await
    }

    /// Reads one message; returns the text one, if it was text.
    async fn read(&mut self) -> Option<Value> {
        match next_message(&mut self.ws).await {
            Message::Binary(bytes) => {
                let frame = decode_frame(&bytes).expect("a well-formed frame");
                let h = frame.header;
                self.frames
                    .insert((h.kind.code(), h.sequence), (h.generation, frame.points));
                None
            }
            Message::Text(text) => {
                let m: Value = serde_json::from_str(&text).unwrap();
                self.texts.push(m.clone());
                Some(m)
            }
            _ => None,
        }
    }

    /// Reads until a text message of type `kind` satisfies `done`.
    async fn text_until(&mut self, kind: &str, done: impl Fn(&Value) -> bool) -> Value {
        loop {
            if let Some(m) = self.read().await
                && m["type"] == kind
                && done(&m)
            {
                return m;
            }
        }
    }

    /// Reads until the newest text message of type `kind` read so far
    /// satisfies `done`: for a state that may have arrived before the
    /// message waited on just before it (a client is sent the newest of
    /// each kind, in no promised order between kinds).
    async fn newest_until(&mut self, kind: &str, done: impl Fn(&Value) -> bool) -> Value {
        loop {
            if let Some(m) = self.texts.iter().rev().find(|m| m["type"] == kind)
                && done(m)
            {
                return m.clone();
            }
            self.read().await;
        }
    }

    /// Reads until each `(kind, done)` pair has been met by a text message,
    /// in whatever order they come (weights and history travel separately),
    /// and returns the messages that met them, in the pairs' order.
    async fn texts_until(&mut self, wanted: &[Wanted<'_>]) -> Vec<Value> {
        let mut found: Vec<Option<Value>> = vec![None; wanted.len()];
        while found.iter().any(Option::is_none) {
            let Some(m) = self.read().await else { continue };
            for ((kind, done), slot) in wanted.iter().zip(&mut found) {
                if slot.is_none() && m["type"] == *kind && done(&m) {
                    *slot = Some(m.clone());
                }
            }
        }
        found.into_iter().flatten().collect()
    }

    async fn send(&mut self, message: Value) {
        self.ws
            .send(Message::text(message.to_string()))
            .await
            .unwrap();
    }

    /// The newest `handles` message read so far.
    fn handles(&self) -> Option<&Value> {
        self.texts.iter().rev().find(|m| m["type"] == "handles")
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn handle_dots_follow_the_finger_on_the_puppet_during_a_drag() {
    // Observation 1: a viewer's dot stayed where the finger landed.
    let running = daemon("").await;
    let (mut performer, stage) = Conn::performer(&running, PERFORMER).await;
    let (mut viewer, _) = Conn::viewer(&running).await;
    let mesh = placed_mesh(&stage);
    let landing = hand(&mesh);
    let on_puppet = follow(&mesh, landing);
    performer
        .send(json!({"type": "contacts", "contacts": [
            {"id": 1, "phase": "down", "x": landing.x, "y": landing.y}]}))
        .await;
    let mut finger = landing;
    for step in 1..=5 {
        finger = landing + DVec2::new(8.0, 6.0) * step as f64;
        performer
            .send(json!({"type": "contacts", "contacts": [
                {"id": 1, "phase": "move", "x": finger.x, "y": finger.y}]}))
            .await;
    }
    // The viewer's handles frame of the newest handle set puts the held
    // point under the finger, on the solved puppet (the barycentric point
    // of the vertex frame of the same solve), not where it landed.
    loop {
        viewer.read().await;
        let Some(handles) = viewer.handles() else {
            continue;
        };
        let generation = handles["generation"].as_u64().unwrap() as u32;
        let Some(index) = handles["handles"]
            .as_array()
            .unwrap()
            .iter()
            .position(|h| h["kind"] == "contact")
        else {
            continue;
        };
        let found = viewer
            .frames
            .iter()
            .find_map(|(&(kind, sequence), (g, points))| {
                (kind == FrameKind::Handles.code()
                    && *g == generation
                    && points[index].distance(finger) < 1e-3)
                    .then(|| (sequence, points[index]))
            });
        let Some((sequence, dot)) = found else {
            continue;
        };
        let Some((_, vertices)) = viewer.frames.get(&(FrameKind::Vertices.code(), sequence)) else {
            continue;
        };
        let under = on_puppet(&crate::common::daemon::Frame {
            puppet: 0,
            sequence,
            vertices: vertices.clone(),
        });
        assert!(dot.distance(under) < 1e-3, "dot {dot} vs puppet {under}");
        assert!(dot.distance(landing) > 30.0, "not the landing point");
        break;
    }
    running.shutdown().await;
}

/// The test stage with the demo mesh copied into `dir` (so saving cannot
/// touch the shared asset).
fn stage_in(dir: &Path, extra: &str) -> ShowConfig {
    let assets = root().join("assets/gingerbread");
    let mesh = dir.join("gingerbread.mesh.json");
    std::fs::copy(assets.join("gingerbread.mesh.json"), &mesh).unwrap();
    let text = stage_text(extra).replace(
        &assets.join("gingerbread.mesh.json").display().to_string(),
        &mesh.display().to_string(),
    );
    ShowConfig::parse("edits.toml", &text, Path::new("/")).unwrap()
}

fn weights(m: &Value) -> Vec<u64> {
    m["weights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_f64().unwrap().to_bits())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn edits_are_bounded_saved_beside_the_mesh_and_undone_exactly() {
    // Observation 4: a huge dab was clamped into every weight and
    // save_weights overwrote the shared mesh file, with no undo.
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let config = stage_in(dir.path(), "");
    let mut options = Options::new(WebFiles::Embedded);
    options.takes_dir = takes.clone();
    let running = start_with(&config, options).await.unwrap();
    let (mut p, stage) = Conn::performer(&running, DIRECTOR).await;
    let loaded = weights(&stage["puppets"][0]);
    let original = std::fs::read(dir.path().join("gingerbread.mesh.json")).unwrap();

    for (radius, strength, field) in [(1e308, 1e308, "radius"), (40.0, 1e308, "strength")] {
        p.send(json!({"type": "paint", "puppet": 0, "x": 640.0, "y": 420.0,
                      "radius": radius, "strength": strength}))
            .await;
        let error = p.text_until("error", |_| true).await;
        let message = error["message"].as_str().unwrap();
        assert!(message.contains(field), "{message}");
    }

    p.send(json!({"type": "record", "name": "edits"})).await;
    p.text_until("take", |m| m["recording"] == "edits").await;
    // A drag while painting, so the take has frames to compare.
    p.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": 640.0, "y": 470.0}]}))
        .await;
    for (i, x) in [600.0, 620.0, 640.0].into_iter().enumerate() {
        p.send(json!({"type": "paint", "puppet": 0, "x": x, "y": 420.0,
                      "radius": 60.0, "strength": 3.0, "stroke": 1}))
            .await;
        p.send(json!({"type": "contacts", "contacts": [
            {"id": 1, "phase": "move", "x": 650.0 + 5.0 * i as f64, "y": 480.0}]}))
            .await;
    }
    let [history, painted] = p
        .texts_until(&[
            ("history", &|m| m["undo"] == 1 && m["redo"] == 0),
            ("weights", &|m| weights(m) != loaded),
        ])
        .await
        .try_into()
        .unwrap();
    assert_eq!(history["puppet"], 0);
    let painted = weights(&painted);
    // Every dab arrived before the history said 1: wait for the last one.
    p.send(json!({"type": "save_weights", "puppet": 0})).await;
    let v1 = p.text_until("weights_saved", |_| true).await;
    let painted = {
        // The file holds the weights as painted by all three dabs.
        let saved = puppetry_mesh::Mesh::load(Path::new(v1["file"].as_str().unwrap())).unwrap();
        let saved: Vec<u64> = saved.weights().iter().map(|w| w.to_bits()).collect();
        assert!(saved.len() == painted.len());
        saved
    };
    assert_eq!(
        Path::new(v1["file"].as_str().unwrap()),
        dir.path().join("gingerbread.v1.mesh.json")
    );
    p.send(json!({"type": "save_weights", "puppet": 0})).await;
    let v2 = p.text_until("weights_saved", |_| true).await;
    assert_eq!(
        Path::new(v2["file"].as_str().unwrap()),
        dir.path().join("gingerbread.v2.mesh.json")
    );
    assert_eq!(
        std::fs::read(dir.path().join("gingerbread.mesh.json")).unwrap(),
        original,
        "the mesh file is untouched"
    );

    p.send(json!({"type": "undo", "puppet": 0})).await;
    p.texts_until(&[
        ("weights", &|m| weights(m) == loaded),
        ("history", &|m| m["undo"] == 0 && m["redo"] == 1),
    ])
    .await;
    p.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "move", "x": 670.0, "y": 490.0}]}))
        .await;
    p.send(json!({"type": "redo", "puppet": 0})).await;
    p.text_until("weights", |m| weights(m) == painted).await;
    p.send(json!({"type": "reset", "puppet": 0})).await;
    p.texts_until(&[
        ("weights", &|m| weights(m) == loaded),
        ("history", &|m| m["undo"] == 2 && m["redo"] == 0),
    ])
    .await;
    p.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "up"}]}))
        .await;
    p.send(json!({"type": "stop_recording"})).await;
    p.text_until("take", |m| m.get("recording").is_none()).await;
    running.shutdown().await;

    // The take, undo and all, replays bit for bit into a fresh stage.
    let take = takes.join(format!("edits.{}", puppetry_take::EXTENSION));
    let steps: Vec<puppetry_take::Step> = puppetry_take::TakeReader::open(&take)
        .unwrap()
        .filter_map(|r| match r.unwrap() {
            puppetry_take::Record::Step(s) => Some(s),
            _ => None,
        })
        .collect();
    let restores = steps
        .iter()
        .flat_map(|s| &s.changes)
        .filter(|c| matches!(c, puppetry_stage::Change::Restore { .. }))
        .count();
    assert_eq!(restores, 3, "undo, redo and reset are recorded");
    let verified =
        puppetry_take::replay::verify(&take, Stage::from_config(&config).unwrap()).unwrap();
    assert!(verified.frames > 3, "{verified:?}");
    assert_eq!(verified.first_mismatch, None);
}

/// `config/skeleton.toml` on a free port, its skeleton in `mode`.
fn skeleton(mode: &str) -> ShowConfig {
    let dir = root().join("config");
    let text = std::fs::read_to_string(dir.join("skeleton.toml"))
        .unwrap()
        .replace("127.0.0.1:8080", "127.0.0.1:0")
        .replace("mode = \"fk\"", &format!("mode = \"{mode}\""));
    ShowConfig::parse("skeleton.toml", &text, &dir).unwrap()
}

async fn paused(config: &ShowConfig) -> Running {
    let mut options = Options::new(WebFiles::Embedded);
    options.paused_replays = true;
    start_with(config, options).await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_newcomer_gets_the_pose_history_weights_and_inputs_at_connect() {
    // Observation 8: a new page showed rest→cheer 0 while the puppet was at
    // rest→crouch 0.5.
    let running = paused(&skeleton("fk")).await;
    let (mut p, _) = Conn::performer(&running, "demo").await;
    p.send(json!({"type": "pose", "puppet": 0, "from": "rest", "to": "crouch", "t": 0.5}))
        .await;
    p.text_until("pose", |m| m["to"] == "crouch").await;
    let (mut newcomer, _) = Conn::viewer(&running).await;
    // Everything comes at connect, in no promised order.
    let kinds = [
        "pose", "history", "weights", "handles", "inputs", "keys", "take",
    ];
    while !kinds
        .iter()
        .all(|k| newcomer.texts.iter().any(|m| m["type"] == *k))
    {
        newcomer.read().await;
    }
    let of = |kind: &str| {
        newcomer
            .texts
            .iter()
            .find(|m| m["type"] == kind)
            .unwrap()
            .clone()
    };
    assert_eq!(
        of("pose"),
        json!({"type": "pose", "puppet": 0, "from": "rest", "to": "crouch", "t": 0.5})
    );
    assert_eq!(
        of("history"),
        json!({"type": "history", "puppet": 0, "undo": 1, "redo": 0})
    );
    assert!(of("handles")["generation"].is_u64());
    assert_eq!(
        of("inputs"),
        json!({"type": "inputs", "replays": [{"name": "skeleton-play", "playing": false}]})
    );
    running.shutdown().await;
}

fn replay_contacts(m: &Value) -> usize {
    m["handles"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|h| h["owner"] == "skeleton-play")
        .count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_paused_replay_leaves_the_puppet_until_it_is_played() {
    // Observation 9: the rig demos' replays looped forever and fought the
    // performer.
    let running = paused(&skeleton("fk")).await;
    assert!(running.inputs_done(), "a paused replay feeds nothing");
    let (mut viewer, stage) = Conn::viewer(&running).await;
    assert!(
        stage["puppets"][0]["handles"]
            .as_array()
            .unwrap()
            .is_empty()
    );
    // Nothing has moved the puppet: no frame was ever solved. (A client
    // gets every frame published before it connected before the answer to
    // its first request.)
    viewer.send(json!({"type": "list_takes"})).await;
    viewer.text_until("takes", |_| true).await;
    assert!(viewer.frames.is_empty(), "{:?}", viewer.frames.keys());

    let (mut director, _) = Conn::performer(&running, "director").await;
    director
        .send(json!({"type": "replay", "source": "nothing", "playing": true}))
        .await;
    let error = director.text_until("error", |_| true).await;
    assert!(error["message"].as_str().unwrap().contains("nothing"));
    director
        .send(json!({"type": "replay", "source": "skeleton-play", "playing": true}))
        .await;
    viewer
        .text_until("inputs", |m| m["replays"][0]["playing"] == true)
        .await;
    viewer
        .newest_until("handles", |m| replay_contacts(m) > 0)
        .await;
    director
        .send(json!({"type": "replay", "source": "skeleton-play", "playing": false}))
        .await;
    viewer
        .text_until("inputs", |m| m["replays"][0]["playing"] == false)
        .await;
    // Paused, it lets go of what it held (the newest handles, which may
    // have come before the pause if the replay was between strokes).
    viewer
        .newest_until("handles", |m| replay_contacts(m) == 0)
        .await;
    running.shutdown().await;
}

/// The posed joints of the newest rig frame.
async fn joints_until(conn: &mut Conn, done: impl Fn(&[DVec2]) -> bool) -> Vec<DVec2> {
    loop {
        let newest = conn
            .frames
            .iter()
            .filter(|((kind, _), _)| *kind == FrameKind::Rig.code())
            .max_by_key(|((_, sequence), _)| *sequence)
            .map(|(_, (_, points))| points.clone());
        if let Some(points) = newest
            && done(&points)
        {
            return points;
        }
        conn.read().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_skeleton_grabbed_mid_bone_turns_it_in_fk_and_drags_it_in_free_mode() {
    // Observation 9: only a 12 px joint could be grabbed; a drag anywhere
    // else did nothing and showed nothing.
    for mode in ["fk", "free"] {
        let running = paused(&skeleton(mode)).await;
        let (mut p, stage) = Conn::performer(&running, "demo").await;
        let rest: Vec<DVec2> =
            serde_json::from_value::<Vec<[f64; 2]>>(stage["puppets"][0]["rig"]["rest"].clone())
                .unwrap()
                .into_iter()
                .map(DVec2::from)
                .collect();
        // Mid forearm (bone 5: elbow 5 → hand 6), off both joints.
        let at = rest[5].lerp(rest[6], 0.5) + DVec2::new(0.0, 3.0);
        let (elbow, hand) = (rest[5], rest[6]);
        let finger = match mode {
            "fk" => elbow + (at - elbow).rotate(DVec2::from_angle(0.5)),
            _ => at + DVec2::new(20.0, -12.0),
        };
        p.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": at.x, "y": at.y}]}))
            .await;
        let handles = p
            .text_until("handles", |m| !m["handles"].as_array().unwrap().is_empty())
            .await;
        assert_eq!(handles["handles"][0]["grip"], "bone", "{handles}");
        assert_eq!(handles["handles"][0]["index"], 5);
        p.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "move", "x": finger.x, "y": finger.y}]}))
            .await;
        let moved = |j: &[DVec2]| j[6].distance(hand) > 5.0;
        let joints = joints_until(&mut p, moved).await;
        if mode == "fk" {
            assert!(joints[5].distance(elbow) < 1e-3, "the elbow stays");
            let turned = (joints[6] - joints[5]).angle_to(hand - elbow).abs();
            assert!((turned - 0.5).abs() < 1e-3, "turned {turned}");
        } else {
            let shift = finger - at;
            assert!(joints[5].distance(elbow + shift) < 1e-3, "{}", joints[5]);
            assert!(joints[6].distance(hand + shift) < 1e-3, "{}", joints[6]);
        }
        assert!(joints[4].distance(rest[4]) < 1e-3, "the upper arm stays");
        running.shutdown().await;
    }
}
