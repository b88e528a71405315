//! Both rigs live in the daemon on 127.0.0.1:0, driven by replays: an
//! lp-FFD puppet with a grid handle and a vertex handle dragged, skeleton
//! puppets with a joint dragged (free mode) and turned (FK mode) — every
//! frame compared with a direct solve of the same handles. Also grid
//! export, key poses, rigidity painting (live and saved) and bad requests.

use crate::common::daemon::{Client, connect, next_message, root};

use std::path::{Path, PathBuf};

use futures_util::SinkExt;
use glam::DVec2;
use puppetry_daemon::config::ShowConfig;
use puppetry_daemon::serve::{Running, start};
use puppetry_deform::ffd::{GridSpec, LpFfd, LpParams};
use puppetry_deform::skeleton::{ShapeAware, Skeleton, SkeletonParams};
use puppetry_deform::{Anchor, Arap, Steps};
use puppetry_mesh::{Locator, Mesh};
use puppetry_stage::{Rig, Stage};
use puppetry_testkit::stage_text::Gingerbread;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

/// A frame of any kind: 1 = vertices, 2 = rig points, 3 = handle points,
/// 4 = depth (no points).
struct Frame {
    kind: u32,
    puppet: u32,
    points: Vec<DVec2>,
}

fn decode(bytes: &[u8]) -> Frame {
    let frame = puppetry_daemon::protocol::decode_frame(bytes).expect("a well-formed frame");
    Frame {
        kind: frame.header.kind.code(),
        puppet: frame.header.puppet,
        points: frame.points,
    }
}

/// A client connection that remembers the newest frame of each kind it
/// has read past, so a frame that arrived while waiting for a text message
/// is not lost.
struct Conn {
    ws: Client,
    newest: std::collections::HashMap<u32, Vec<DVec2>>,
}

impl Conn {
    async fn next(&mut self) -> Message {
        let m = next_message(&mut self.ws).await;
        if let Message::Binary(bytes) = &m {
            let frame = decode(bytes);
            assert_eq!(frame.puppet, 0);
            // 1 vertices, 2 rig points, 3 handle points, 4 depth.
            assert!((1..=4).contains(&frame.kind), "known frame kinds");
            self.newest.insert(frame.kind, frame.points);
        }
        m
    }

    /// The newest frame of `kind` once it satisfies `done`.
    async fn frame_until(&mut self, kind: u32, done: impl Fn(&[DVec2]) -> bool) -> Vec<DVec2> {
        loop {
            if let Some(points) = self.newest.get(&kind)
                && done(points)
            {
                return points.clone();
            }
            self.next().await;
        }
    }

    /// Reads until a text message of `kind`.
    async fn text_of(&mut self, kind: &str) -> Value {
        loop {
            if let Message::Text(text) = self.next().await {
                let m: Value = serde_json::from_str(&text).unwrap();
                if m["type"] == kind {
                    return m;
                }
            }
        }
    }

    async fn send(&mut self, message: Value) {
        self.ws
            .send(Message::text(message.to_string()))
            .await
            .unwrap();
    }
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

/// A stage file with the demo puppet (mesh `mesh`) and `rig` appended to
/// its table, plus a replay input if given.
fn config(mesh: &Path, pins: bool, rig: &str, replay: Option<&Path>) -> ShowConfig {
    let mut puppet = Gingerbread::new("gingerbread").mesh(mesh).scale(1.2);
    if pins {
        puppet = puppet.hand_pins();
    }
    let mut text = format!(
        r#"
[stage]
width = 1280
height = 720
listen = "127.0.0.1:0"
client_timeout_s = 5

[access]
performer_tokens = ["secret"]
[[access.person]]
name = "Director"
role = "director"
token = "boss"

{puppet}{rig}
"#,
        puppet = puppet.with(""),
    );
    if let Some(file) = replay {
        text += &format!(
            "\n[[input]]\nkind = \"replay\"\nname = \"take\"\nfile = \"{}\"\n",
            file.display()
        );
    }
    ShowConfig::parse("rigs.toml", &text, Path::new("/")).unwrap()
}

fn demo_mesh() -> PathBuf {
    root().join("assets/gingerbread/gingerbread.mesh.json")
}

/// A recording of one source: per frame, the contacts (id, phase, point).
fn write_replay(dir: &Path, frames: &[Vec<(u32, &str, DVec2)>]) -> PathBuf {
    let mut text = String::new();
    for (k, contacts) in frames.iter().enumerate() {
        let list: Vec<Value> = contacts
            .iter()
            .map(|(id, phase, p)| json!({"id": id, "phase": phase, "x": p.x, "y": p.y}))
            .collect();
        text += &json!({"t": k as f64 * 0.01, "source": "take", "contacts": list}).to_string();
        text.push('\n');
    }
    // The fingers stay down until the test ends: a replay that ends lets
    // go of what it held.
    let held: std::collections::BTreeSet<u32> = frames.iter().flatten().map(|c| c.0).collect();
    let ups: Vec<Value> = held
        .iter()
        .map(|id| json!({"id": id, "phase": "up", "x": 0.0, "y": 0.0}))
        .collect();
    text += &json!({"t": 600.0, "source": "take", "contacts": ups}).to_string();
    text.push('\n');
    let path = dir.join("take.jsonl");
    std::fs::write(&path, text).unwrap();
    path
}

/// A contact landing at `from` and moving to `to` in `steps` frames,
/// never lifted.
fn drag(id: u32, from: DVec2, to: DVec2, steps: usize) -> Vec<(u32, &'static str, DVec2)> {
    (0..=steps)
        .map(|k| {
            let phase = if k == 0 { "down" } else { "move" };
            (id, phase, from + (to - from) * (k as f64 / steps as f64))
        })
        .collect()
}

async fn run(config: &ShowConfig) -> Running {
    start(config, puppetry_daemon::stream::WebFiles::Embedded, None)
        .await
        .unwrap()
}

/// A director's connection (directors paint and save as well as perform).
async fn director(running: &Running) -> (Conn, Value) {
    let (ws, stage) = connect(
        running,
        json!({"type": "hello", "role": "director", "token": "boss"}),
    )
    .await;
    let conn = Conn {
        ws,
        newest: Default::default(),
    };
    (conn, stage)
}

fn anchor_at(mesh: &Mesh, p: DVec2) -> Anchor {
    let l = Locator::new(mesh).locate(mesh, p).expect("on the puppet");
    Anchor::Point {
        triangle: l.triangle,
        bary: l.bary,
    }
}

/// The stage's own view of the config, for rest positions to aim at.
fn staged(config: &ShowConfig) -> Stage {
    Stage::from_config(config).unwrap()
}

fn pins_on_stage(stage: &Stage) -> Vec<DVec2> {
    stage.puppets()[0]
        .handles()
        .iter()
        .map(|h| h.target)
        .collect()
}

const GRID: &str = "[puppet.grid]\ncolumns = 10\nrows = 10\niterations = 200\n";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replay_drags_a_grid_handle_and_a_vertex_handle_like_a_direct_lp_ffd_solve() {
    let dir = tempfile::tempdir().unwrap();
    let plain = config(&demo_mesh(), true, GRID, None);
    let stage = staged(&plain);
    let puppet = &stage.puppets()[0];
    let Rig::Grid(grid) = puppet.rig() else {
        panic!("a grid puppet")
    };
    let spec: GridSpec = *grid.ffd().spec();
    // A top-row handle above the head, and the right hand (far from any
    // grid handle).
    let index = 9 * 10 + 5;
    let handle = grid.ffd().rest_grid()[index];
    let handle_to = handle + DVec2::new(80.0, -20.0);
    let mesh = puppet.mesh.clone();
    let hand = mesh
        .vertices()
        .iter()
        .copied()
        .fold(DVec2::splat(f64::NEG_INFINITY), |a, b| {
            if b.x > a.x { b } else { a }
        })
        - DVec2::new(15.0, 0.0);
    assert!(
        grid.ffd()
            .rest_grid()
            .iter()
            .all(|g| g.distance(hand) > stage.grab_radius()),
        "the hand is a direct grab"
    );
    let hand_to = hand + DVec2::new(-10.0, 60.0);
    let a = drag(1, handle, handle_to, 10);
    let b = drag(2, hand, hand_to, 10);
    let frames: Vec<_> = a.iter().zip(&b).map(|(x, y)| vec![*x, *y]).collect();
    let replay = write_replay(dir.path(), &frames);
    let pins = pins_on_stage(&stage);

    let mut direct = LpFfd::register(
        &mesh,
        spec,
        LpParams {
            iterations: 200,
            ..LpParams::default()
        },
    )
    .unwrap();
    let anchors: Vec<Anchor> = [pins[0], pins[1], hand]
        .iter()
        .map(|&p| anchor_at(&mesh, p))
        .collect();
    direct.compile(&anchors, &[index]).unwrap();
    for _ in 0..5 {
        direct
            .update(&[pins[0], pins[1], hand_to], &[handle_to])
            .unwrap();
    }
    let expected = direct.pose().to_vec();
    let expected_grid = direct.grid().to_vec();
    assert!(max_distance(&expected, mesh.vertices()) > 20.0, "it moved");

    let running = run(&config(&demo_mesh(), true, GRID, Some(&replay))).await;
    let (mut ws, stage_message) = director(&running).await;
    let rig = &stage_message["puppets"][0]["rig"];
    assert_eq!(rig["kind"], "grid");
    assert_eq!(
        (rig["columns"].as_u64(), rig["rows"].as_u64()),
        (Some(10), Some(10))
    );
    let seen = ws
        .frame_until(1, |v| max_distance(v, &expected) < 0.05)
        .await;
    assert!(max_distance(&seen, &expected) < 0.05);
    let grid_seen = ws
        .frame_until(2, |g| max_distance(g, &expected_grid) < 0.05)
        .await;
    assert!(
        grid_seen[index].distance(handle_to) < 1.0,
        "the dragged grid handle is near where it was pulled"
    );
    // The grid, exported.
    ws.send(json!({"type": "export_grid", "puppet": 0})).await;
    let export = ws.text_of("grid").await;
    assert_eq!(export["columns"], 10);
    assert_eq!(export["rows"], 10);
    let points = |v: &Value| -> Vec<DVec2> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|p| DVec2::new(p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
            .collect()
    };
    assert!(max_distance(&points(&export["rest"]), grid.ffd().rest_grid()) < 1e-9);
    assert!(max_distance(&points(&export["grid"]), &expected_grid) < 0.05);
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn contacts_grab_grid_handles_and_points_and_say_which() {
    let running = run(&config(&demo_mesh(), true, GRID, None)).await;
    let (mut ws, stage_message) = director(&running).await;
    let rest = &stage_message["puppets"][0]["rig"]["rest"][95];
    let (x, y) = (rest[0].as_f64().unwrap() + 3.0, rest[1].as_f64().unwrap());
    ws.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": x, "y": y}]}))
        .await;
    let handles = loop {
        let m = ws.text_of("handles").await;
        if m["handles"].as_array().unwrap().len() == 3 {
            break m;
        }
    };
    let grips: Vec<&str> = handles["handles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| h["grip"].as_str().unwrap())
        .collect();
    assert_eq!(grips, ["point", "point", "grid"]);
    assert_eq!(handles["handles"][2]["index"], 95);
    running.shutdown().await;
}

/// The demo skeleton placed on the stage, from the stage's own rig.
fn placed_skeleton(stage: &Stage) -> Skeleton {
    match stage.puppets()[0].rig() {
        Rig::Skeleton(r) => r.deformer().skeleton().clone(),
        _ => panic!("a skeleton puppet"),
    }
}

fn skeleton_rig(mode: &str, poses: &str) -> String {
    let text = std::fs::read_to_string(root().join("config/skeleton.toml")).unwrap();
    let joints = text
        .split("joints = [")
        .nth(1)
        .unwrap()
        .split("]\n#")
        .next()
        .unwrap();
    let bones = text
        .split("bones = [")
        .nth(1)
        .unwrap()
        .split("]\n\n")
        .next()
        .unwrap();
    format!("[puppet.skeleton]\nmode = \"{mode}\"\njoints = [{joints}]\nbones = [{bones}]\n{poses}")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replay_drags_a_joint_in_free_mode_like_a_direct_solve() {
    let dir = tempfile::tempdir().unwrap();
    let rig = skeleton_rig("free", "");
    let stage = staged(&config(&demo_mesh(), false, &rig, None));
    let skeleton = placed_skeleton(&stage);
    let mesh = stage.puppets()[0].mesh.clone();
    // The right hand (joint 9) moved up; the others stay.
    let from = skeleton.joints()[9];
    let to = from + DVec2::new(-20.0, 70.0);
    let replay = write_replay(
        dir.path(),
        &drag(1, from, to, 8)
            .into_iter()
            .map(|c| vec![c])
            .collect::<Vec<_>>(),
    );
    let mut joints = skeleton.joints().to_vec();
    joints[9] = to;
    let mut direct = ShapeAware::register(&mesh, skeleton, SkeletonParams::default()).unwrap();
    let expected = direct.update(&joints).unwrap().to_vec();

    let running = run(&config(&demo_mesh(), false, &rig, Some(&replay))).await;
    let (mut ws, stage_message) = director(&running).await;
    assert_eq!(stage_message["puppets"][0]["rig"]["kind"], "skeleton");
    assert_eq!(stage_message["puppets"][0]["rig"]["mode"], "free");
    let seen = ws
        .frame_until(1, |v| max_distance(v, &expected) < 1e-2)
        .await;
    assert!(max_distance(&seen, mesh.vertices()) > 30.0, "the arm moved");
    let seen_joints = ws.frame_until(2, |j| max_distance(j, &joints) < 1e-3).await;
    assert_eq!(seen_joints.len(), 16);
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replay_turns_a_bone_in_fk_mode_like_a_direct_solve() {
    let dir = tempfile::tempdir().unwrap();
    let rig = skeleton_rig("fk", "");
    let stage = staged(&config(&demo_mesh(), false, &rig, None));
    let skeleton = placed_skeleton(&stage);
    let mesh = stage.puppets()[0].mesh.clone();
    // Grab the right elbow (joint 8) and swing it: bone 7 (shoulder to
    // elbow) turns about the shoulder and the forearm follows.
    let from = skeleton.joints()[8];
    let to = skeleton.joints()[7] + DVec2::new(30.0, 60.0);
    let replay = write_replay(
        dir.path(),
        &drag(1, from, to, 8)
            .into_iter()
            .map(|c| vec![c])
            .collect::<Vec<_>>(),
    );
    let mut pose = skeleton.rest_pose();
    skeleton.aim(&mut pose, 7, to).unwrap();
    let joints = skeleton.joints_of(&pose).unwrap();
    let mut direct =
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    let expected = direct.update_pose(&pose).unwrap().to_vec();
    assert!(
        joints[9].distance(skeleton.joints()[9]) > 50.0,
        "the hand follows the elbow"
    );

    let running = run(&config(&demo_mesh(), false, &rig, Some(&replay))).await;
    let (mut ws, _) = director(&running).await;
    ws.frame_until(1, |v| max_distance(v, &expected) < 1e-2)
        .await;
    ws.frame_until(2, |j| max_distance(j, &joints) < 1e-3).await;
    // A contact off the joints grabs the nearest bone at that point.
    let belly = skeleton.joints()[0] + DVec2::new(0.0, 40.0);
    ws.send(json!({"type": "contacts", "contacts": [{"id": 3, "phase": "down", "x": belly.x, "y": belly.y}]}),
    )
    .await;
    loop {
        let m = ws.text_of("handles").await;
        let bones: Vec<&Value> = m["handles"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|h| h["owner"] != "take")
            .collect();
        if let [bone] = bones.as_slice() {
            assert_eq!(
                (bone["grip"].as_str(), bone["index"].as_u64()),
                (Some("bone"), Some(0))
            );
            break;
        }
    }
    ws.send(json!({"type": "contacts", "contacts": [{"id": 3, "phase": "up"}]}))
        .await;
    ws.send(json!({"type": "pin", "x": 5.0, "y": 5.0})).await;
    ws.send(json!({"type": "export_grid", "puppet": 0})).await;
    let error = ws.text_of("error").await;
    assert!(
        error["message"].as_str().unwrap().contains("no grid"),
        "{error}"
    );
    // The root joint is grabbed: the handle set is that one alone.
    let root = skeleton.joints()[0];
    ws.send(json!({"type": "contacts", "contacts": [{"id": 4, "phase": "down", "x": root.x, "y": root.y}]}),
    )
    .await;
    let handles = loop {
        let m = ws.text_of("handles").await;
        if m["handles"]
            .as_array()
            .unwrap()
            .iter()
            .any(|h| h["owner"] != "take" && h["grip"] == "joint")
        {
            break m;
        }
    };
    let mine: Vec<&Value> = handles["handles"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|h| h["owner"] != "take")
        .collect();
    assert_eq!(
        mine.len(),
        1,
        "the belly let go and empty stage grabbed nothing: {handles}"
    );
    assert_eq!(
        (mine[0]["grip"].as_str(), mine[0]["index"].as_u64()),
        (Some("joint"), Some(0))
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pose_message_sets_the_interpolated_key_pose() {
    let poses = "[[puppet.skeleton.poses]]\nname = \"rest\"\n\n[[puppet.skeleton.poses]]\nname = \"cheer\"\nturn = [[4, -60], [7, 60]]\n";
    let rig = skeleton_rig("fk", poses);
    let config = config(&demo_mesh(), false, &rig, None);
    let stage = staged(&config);
    let skeleton = placed_skeleton(&stage);
    let mesh = stage.puppets()[0].mesh.clone();
    let rest = skeleton.rest_pose();
    let mut cheer = rest.clone();
    cheer.rotate_joint(4, (-60f64).to_radians()).unwrap();
    cheer.rotate_joint(7, 60f64.to_radians()).unwrap();
    let half = puppetry_deform::skeleton::Pose::interpolate(&rest, &cheer, 0.5).unwrap();
    let joints = skeleton.joints_of(&half).unwrap();
    let mut direct =
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    let expected = direct.update_pose(&half).unwrap().to_vec();

    let running = run(&config).await;
    let (mut ws, stage_message) = director(&running).await;
    assert_eq!(
        stage_message["puppets"][0]["rig"]["poses"],
        json!(["rest", "cheer"])
    );
    ws.send(json!({"type": "pose", "puppet": 0, "from": "rest", "to": "cheer", "t": 0.5}))
        .await;
    ws.frame_until(2, |j| max_distance(j, &joints) < 1e-3).await;
    ws.frame_until(1, |v| max_distance(v, &expected) < 1e-2)
        .await;
    // Bad requests are refused, and the connection stays.
    for (bad, says) in [
        (
            json!({"type": "pose", "puppet": 0, "from": "rest", "to": "moon", "t": 0.5}),
            "moon",
        ),
        (
            json!({"type": "pose", "puppet": 3, "from": "rest", "to": "cheer", "t": 0.5}),
            "puppet 3",
        ),
        (
            json!({"type": "pose", "puppet": 0, "from": "rest", "to": "cheer"}),
            "missing field",
        ),
        (
            json!({"type": "paint", "puppet": 0, "x": 1.0, "y": 1.0, "radius": -1.0, "strength": 2.0}),
            "radius",
        ),
        (
            json!({"type": "paint", "puppet": 0, "x": 1.0, "y": 1.0, "radius": 1.0, "strength": 2.0, "colour": 1}),
            "colour",
        ),
        (json!({"type": "save_weights", "puppet": 7}), "puppet 7"),
    ] {
        ws.send(bad).await;
        let error = ws.text_of("error").await;
        assert!(error["message"].as_str().unwrap().contains(says), "{error}");
    }
    // Viewers may export but not pose.
    let (viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let mut viewer = Conn {
        ws: viewer,
        newest: Default::default(),
    };
    viewer
        .send(json!({"type": "pose", "puppet": 0, "from": "rest", "to": "cheer", "t": 1.0}))
        .await;
    let error = viewer.text_of("error").await;
    assert!(
        error["message"].as_str().unwrap().contains("viewers"),
        "{error}"
    );
    running.shutdown().await;
}

/// A direct ARAP solve of `mesh` with these rest points held at targets.
fn direct_arap(mesh: &Mesh, holds: &[(DVec2, DVec2)]) -> Vec<DVec2> {
    let anchors: Vec<Anchor> = holds.iter().map(|(p, _)| anchor_at(mesh, *p)).collect();
    let targets: Vec<DVec2> = holds.iter().map(|h| h.1).collect();
    let mut arap = Arap::register(mesh).unwrap();
    arap.compile(&anchors).unwrap();
    arap.update(&targets, Steps::Both).unwrap().to_vec()
}

fn with_weights(mesh: &Mesh, weights: &[f64]) -> Mesh {
    Mesh::new(
        "painted",
        mesh.vertices().to_vec(),
        mesh.triangles().to_vec(),
        None,
        Some(weights.to_vec()),
    )
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn painting_stiffens_a_free_form_puppet_and_saves_to_its_mesh_file() {
    let dir = tempfile::tempdir().unwrap();
    let mesh_file = dir.path().join("gingerbread.mesh.json");
    std::fs::copy(demo_mesh(), &mesh_file).unwrap();
    let config = config(&mesh_file, true, "", None);
    let stage = staged(&config);
    let mesh = stage.puppets()[0].mesh.clone();
    let pins = pins_on_stage(&stage);
    let hand = mesh
        .vertices()
        .iter()
        .copied()
        .fold(DVec2::splat(f64::NEG_INFINITY), |a, b| {
            if b.x > a.x { b } else { a }
        })
        - DVec2::new(15.0, 0.0);
    let hand_to = hand + DVec2::new(-30.0, 100.0);
    let holds = [(pins[0], pins[0]), (pins[1], pins[1]), (hand, hand_to)];
    let unpainted = direct_arap(&mesh, &holds);

    let running = run(&config).await;
    let (mut ws, _) = director(&running).await;
    ws.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": hand.x, "y": hand.y}]}),
    )
    .await;
    ws.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "move", "x": hand_to.x, "y": hand_to.y}]}),
    )
    .await;
    ws.frame_until(1, |v| max_distance(v, &unpainted) < 1e-2)
        .await;
    // Stiffen the arm's middle: the deformed arm is where the brush lands.
    let brush = hand + (hand_to - hand) * 0.3 - DVec2::new(60.0, 0.0);
    ws.send(json!({"type": "paint", "puppet": 0, "x": brush.x, "y": brush.y, "radius": 70.0, "strength": 1000.0}))
        .await;
    // A second dab, most likely while the first rebuild is under way: the
    // solver that ends up in use has both.
    let elbow = brush + DVec2::new(50.0, 20.0);
    ws.send(json!({"type": "paint", "puppet": 0, "x": elbow.x, "y": elbow.y, "radius": 40.0, "strength": 1000.0}))
        .await;
    ws.send(json!({"type": "save_weights", "puppet": 0})).await;
    let saved = ws.text_of("weights_saved").await;
    // A new version beside the mesh file; the mesh file stays as it was.
    let version = mesh_file.with_file_name("gingerbread.v1.mesh.json");
    assert_eq!(saved["file"], version.display().to_string());
    assert_eq!(
        Mesh::load(&mesh_file).unwrap().weights(),
        Mesh::load(&demo_mesh()).unwrap().weights()
    );
    let reloaded = Mesh::load(&version).unwrap();
    let original = Mesh::load(&demo_mesh()).unwrap();
    assert_eq!(reloaded.vertices(), original.vertices());
    assert_eq!(reloaded.triangles(), original.triangles());
    assert_eq!(reloaded.uv(), original.uv());
    let weights = reloaded.weights();
    let stiffened = weights.iter().filter(|&&w| w > 10.0).count();
    assert!(stiffened > 5, "{stiffened} triangles stiffened");
    assert!(
        weights.iter().filter(|&&w| w == 1.0).count() > weights.len() / 2,
        "triangles away from the brush keep their weight"
    );
    let painted = direct_arap(&with_weights(&mesh, weights), &holds);
    assert!(
        max_distance(&painted, &unpainted) > 1.0,
        "painting matters for this drag"
    );
    // The rebuilt solver is swapped in and the next frames use it.
    ws.frame_until(1, |v| max_distance(v, &painted) < 1e-2)
        .await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn painting_a_skeleton_puppet_refactors_it() {
    let dir = tempfile::tempdir().unwrap();
    let mesh_file = dir.path().join("gingerbread.mesh.json");
    std::fs::copy(demo_mesh(), &mesh_file).unwrap();
    let rig = skeleton_rig(
        "fk",
        "[[puppet.skeleton.poses]]\nname = \"up\"\nturn = [[7, 50]]\n",
    );
    let config = config(&mesh_file, false, &rig, None);
    let stage = staged(&config);
    let skeleton = placed_skeleton(&stage);
    let mesh = stage.puppets()[0].mesh.clone();
    let mut up = skeleton.rest_pose();
    up.rotate_joint(7, 50f64.to_radians()).unwrap();

    let running = run(&config).await;
    let (mut ws, _) = director(&running).await;
    ws.send(json!({"type": "pose", "puppet": 0, "from": "up", "to": "up", "t": 0.0}))
        .await;
    let shoulder = skeleton.joints()[7];
    ws.send(json!({"type": "paint", "puppet": 0, "x": shoulder.x, "y": shoulder.y - 30.0, "radius": 60.0, "strength": 0.01}),
    )
    .await;
    ws.send(json!({"type": "save_weights", "puppet": 0})).await;
    let saved = ws.text_of("weights_saved").await;
    let saved = Path::new(saved["file"].as_str().unwrap());
    assert_ne!(saved, mesh_file, "a new version beside the mesh file");
    let weights = Mesh::load(saved).unwrap().weights().to_vec();
    assert!(weights.iter().any(|&w| w < 0.5), "softened");
    let mut direct = ShapeAware::register(
        &with_weights(&mesh, &weights),
        skeleton.clone(),
        SkeletonParams::default(),
    )
    .unwrap();
    let expected = direct.update_pose(&up).unwrap().to_vec();
    let mut unpainted = ShapeAware::register(&mesh, skeleton, SkeletonParams::default()).unwrap();
    let before = unpainted.update_pose(&up).unwrap().to_vec();
    assert!(
        max_distance(&expected, &before) > 0.1,
        "painting matters here"
    );
    ws.frame_until(1, |v| max_distance(v, &expected) < 1e-2)
        .await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn painting_a_grid_puppet_refactors_it() {
    let dir = tempfile::tempdir().unwrap();
    let mesh_file = dir.path().join("gingerbread.mesh.json");
    std::fs::copy(demo_mesh(), &mesh_file).unwrap();
    let config = config(&mesh_file, true, GRID, None);
    let stage = staged(&config);
    let mesh = stage.puppets()[0].mesh.clone();
    let Rig::Grid(grid) = stage.puppets()[0].rig() else {
        panic!("a grid puppet")
    };
    let spec = *grid.ffd().spec();
    let pins = pins_on_stage(&stage);
    let hand = mesh
        .vertices()
        .iter()
        .copied()
        .fold(DVec2::splat(f64::NEG_INFINITY), |a, b| {
            if b.x > a.x { b } else { a }
        })
        - DVec2::new(15.0, 0.0);
    let hand_to = hand + DVec2::new(-30.0, 100.0);
    let anchors: Vec<Anchor> = [pins[0], pins[1], hand]
        .iter()
        .map(|&p| anchor_at(&mesh, p))
        .collect();
    let targets = [pins[0], pins[1], hand_to];
    let solve = |mesh: &Mesh| {
        let params = LpParams {
            iterations: 200,
            ..LpParams::default()
        };
        let mut ffd = LpFfd::register(mesh, spec, params).unwrap();
        ffd.compile(&anchors, &[]).unwrap();
        for _ in 0..5 {
            ffd.update(&targets, &[]).unwrap();
        }
        ffd.pose().to_vec()
    };
    let unpainted = solve(&mesh);

    let running = run(&config).await;
    let (mut ws, _) = director(&running).await;
    ws.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": hand.x, "y": hand.y}]}))
        .await;
    ws.send(json!({"type": "contacts", "contacts": [{"id": 1, "phase": "move", "x": hand_to.x, "y": hand_to.y}]}))
        .await;
    ws.frame_until(1, |v| max_distance(v, &unpainted) < 0.05)
        .await;
    // Soften the shoulder, where the arm bends.
    let shoulder = hand - DVec2::new(150.0, 0.0);
    ws.send(json!({"type": "paint", "puppet": 0, "x": shoulder.x, "y": shoulder.y, "radius": 60.0, "strength": 0.01}))
        .await;
    // Every client hears of the new weights.
    let broadcast = ws.text_of("weights").await;
    ws.send(json!({"type": "save_weights", "puppet": 0})).await;
    let saved = ws.text_of("weights_saved").await;
    let saved = Path::new(saved["file"].as_str().unwrap());
    assert_ne!(saved, mesh_file, "a new version beside the mesh file");
    let weights = Mesh::load(saved).unwrap().weights().to_vec();
    let heard: Vec<f64> = serde_json::from_value(broadcast["weights"].clone()).unwrap();
    assert_eq!(heard.len(), weights.len());
    assert!(
        heard
            .iter()
            .zip(&weights)
            .all(|(a, b)| (a - b).abs() <= 1e-12 * b.abs())
    );
    assert!(weights.iter().any(|&w| w < 0.1), "softened");
    let painted = solve(&with_weights(&mesh, &weights));
    assert!(
        max_distance(&painted, &unpainted) > 0.5,
        "painting matters for this drag"
    );
    ws.frame_until(1, |v| max_distance(v, &painted) < 0.05)
        .await;
    running.shutdown().await;
}

/// The rebuild bookkeeping without threads: one rebuild at a time, and a
/// finished one that is already stale starts the next with the newest
/// weights.
#[test]
fn dabs_during_a_rebuild_go_into_the_next_one() {
    let config = config(&demo_mesh(), true, "", None);
    let mut stage = staged(&config);
    let centre = DVec2::new(640.0, 360.0);
    let first = stage
        .paint(0, centre, 50.0, 10.0)
        .unwrap()
        .expect("a free-form puppet rebuilds off the stage thread");
    assert_eq!(first.mesh.weights(), stage.puppets()[0].weights());
    assert!(
        stage.paint(0, centre, 50.0, 10.0).unwrap().is_none(),
        "no second rebuild while one is under way"
    );
    let newest = stage.puppets()[0].weights().to_vec();
    assert_ne!(first.mesh.weights(), newest.as_slice());
    let arap = Arap::register(&first.mesh).unwrap();
    let second = stage
        .install(0, first.generation, arap)
        .expect("the weights moved on: another rebuild");
    assert_eq!(second.mesh.weights(), newest.as_slice());
    assert!(second.generation > first.generation);
    let arap = Arap::register(&second.mesh).unwrap();
    assert!(
        stage.install(0, second.generation, arap).is_none(),
        "up to date"
    );
    // Solving compiles the new solver with the pins: the rest pose holds.
    stage.solve();
    assert!(
        max_distance(
            stage.puppets()[0].pose(),
            stage.puppets()[0].mesh.vertices()
        ) < 1e-6
    );
    // Painting off the puppet changes nothing and rebuilds nothing.
    assert!(
        stage
            .paint(0, DVec2::new(5.0, 5.0), 10.0, 10.0)
            .unwrap()
            .is_none()
    );
    assert!(stage.paint(0, centre, 0.0, 10.0).is_err());
    assert!(stage.paint(1, centre, 10.0, 10.0).is_err());
}
