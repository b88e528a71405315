//! From a recorded take: the animation holds the take's own frames, and
//! Spine's runtime applied at t gives the take's vertices at t; the glb of
//! a take passes the Khronos validator.

use std::path::Path;

use glam::DVec2;
use puppetry_export::spine::{SpineOptions, export_spine};
use puppetry_export::take::animation_of_take;
use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;
use puppetry_take::{Frame, Header, Record, TakeWriter};

use crate::common::{arg, node_script};
use puppetry_testkit::stage_text::{Gingerbread, STAGE};

const FPS: f64 = 30.0;
const STEPS: usize = 24;

fn config() -> StageConfig {
    let text = format!("{STAGE}{}", Gingerbread::new("gingerbread").hand_pins());
    StageConfig::parse("take-test.toml", &text, Path::new("/")).unwrap()
}

/// A take of a hand dragging the head, one step per 1/30 s (written with
/// exact times, as a recorder would at that pace); returns its frames.
fn record(path: &Path, config: &StageConfig) -> Vec<Vec<[f32; 2]>> {
    let mut stage = Stage::from_config(config).unwrap();
    let points: Vec<DVec2> = (0..STEPS)
        .map(|k| {
            let a = k as f64 / STEPS as f64 * std::f64::consts::TAU;
            DVec2::new(640.0, 470.0) + DVec2::new(a.sin(), 1.0 - a.cos()) * 50.0
        })
        .collect();
    crate::fixture::record_drag(path, &mut stage, "t", FPS, &points)
}

#[test]
fn a_take_exports_its_own_frames_and_spine_plays_them() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("t.take");
    let config = config();
    let recorded = record(&take, &config);
    let animation = animation_of_take(&take, &config, FPS, None, None).unwrap();
    assert!(animation.frame_count >= STEPS);
    // Frame k of the export is the take's frame k, bit for bit.
    for (k, frame) in recorded.iter().enumerate() {
        assert!(animation.puppets[0].frames[k] == *frame, "frame {k}");
    }

    let path = dir.path().join("take.json");
    let layout = export_spine(&animation, &SpineOptions::default(), &mut (), &path).unwrap();
    let ks = [0usize, 5, 11, 23];
    let times: Vec<String> = ks.iter().map(|&k| (k as f64 / FPS).to_string()).collect();
    let result = node_script(
        "export-spine.mjs",
        &["@esotericsoftware/spine-core"],
        &[arg(&path), "take", &times.join(",")],
    );
    let samples = result["samples"].as_array().unwrap();
    let placed = &layout.puppets[0];
    for (sample, &k) in samples.iter().zip(&ks) {
        let world = sample["slots"][&placed.slot].as_array().unwrap();
        for (i, &v) in placed.order.iter().enumerate() {
            let e = recorded[k][v as usize];
            for c in 0..2 {
                let got = world[i * 2 + c].as_f64().unwrap();
                assert!(
                    (got - e[c] as f64).abs() <= 1e-4,
                    "t = {k}/30, vertex {v}: {got} vs {}",
                    e[c]
                );
            }
        }
    }

    let glb = dir.path().join("take.glb");
    puppetry_export::gltf::export_glb(&animation, &Default::default(), &mut (), &glb).unwrap();
    let report = node_script("export-validate.mjs", &["gltf-validator"], &[arg(&glb)]);
    assert_eq!(report["issues"]["numErrors"], 0, "{report}");
    assert_eq!(report["issues"]["numWarnings"], 0, "{report}");
}

/// A take recorded after a director removed one puppet and put another
/// on top draws what the stage drew: the removed one not at all (its
/// stage-file pins, let go when it went, do not make the take mismatch),
/// the others bottom to top in the new order.
#[test]
fn a_take_draws_the_lineup_it_was_recorded_with() {
    let text = format!(
        "{STAGE}{}{}{}",
        Gingerbread::new("a").at(300.0, 360.0),
        Gingerbread::new("b").hand_pins(),
        Gingerbread::new("c").at(980.0, 360.0),
    );
    let config = StageConfig::parse("lineup-take.toml", &text, Path::new("/")).unwrap();
    let mut stage = Stage::from_config(&config).unwrap();
    stage.remove_puppet(1).unwrap();
    stage.set_order(&[2, 0]).unwrap();
    stage.solve();
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("lineup.take");
    let header = Header::of_stage("lineup", "lineup-take.toml", &stage, false);
    assert_eq!(header.on_stage, Some(vec![2, 0]));
    let mut writer = TakeWriter::create(&take, &header).unwrap();
    for k in 0..3 {
        let t = k as f64 / FPS;
        for p in [2u32, 0] {
            let frame = Frame::of_pose(p, t, stage.puppets()[p as usize].pose());
            writer.write(&Record::Frame(frame)).unwrap();
        }
    }
    writer.flush().unwrap();
    let animation = animation_of_take(&take, &config, FPS, None, None).unwrap();
    let names: Vec<&str> = animation.puppets.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["c", "a"]);
    // A take of the stage file's own lineup names none and draws them all.
    let fresh = Stage::from_config(&config).unwrap();
    let header = Header::of_stage("all", "lineup-take.toml", &fresh, true);
    assert_eq!(header.on_stage, None);
    assert_eq!(header.drawn(), [0, 1, 2]);
}

/// A skeleton puppet exports to Spine as a rig: its 15 bones with
/// rotation and translation timelines and weighted vertices, no deform
/// keys; spine-core poses it within the fit's reported skinning error of
/// the take's vertices at every sampled frame.
#[test]
fn a_skeleton_take_exports_as_bones_that_follow_the_take() {
    let dir = tempfile::tempdir().unwrap();
    let animation = skeleton_take(dir.path());
    let puppet = &animation.puppets[0];
    assert!(
        puppet.skeleton.is_some(),
        "the take's puppet has its skeleton"
    );
    let moved = puppet.frames.iter().any(|f| f != &puppet.frames[0]);
    assert!(moved, "the hand moved nothing");

    let path = dir.path().join("wave.json");
    let layout = export_spine(&animation, &SpineOptions::default(), &mut (), &path).unwrap();
    let placed = &layout.puppets[0];
    let (bones, error, mean) = placed.bones.expect("exported as bones");
    assert_eq!(bones, 15);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let take_anim = &json["animations"]["take"];
    assert_eq!(take_anim["bones"].as_object().unwrap().len(), 15);
    assert!(
        take_anim["attachments"]["default"]
            .get(&placed.slot)
            .is_none(),
        "no deform keys for a rigged puppet"
    );
    let ks: Vec<usize> = (0..animation.frame_count).step_by(4).collect();
    let times: Vec<String> = ks.iter().map(|&k| (k as f64 / FPS).to_string()).collect();
    let result = node_script(
        "export-spine.mjs",
        &["@esotericsoftware/spine-core"],
        &[arg(&path), "take", &times.join(",")],
    );
    let mut worst = 0.0f64;
    for (sample, &k) in result["samples"].as_array().unwrap().iter().zip(&ks) {
        let world = sample["slots"][&placed.slot].as_array().unwrap();
        for (i, &v) in placed.order.iter().enumerate() {
            let e = puppet.frames[k][v as usize];
            let g = |c: usize| world[i * 2 + c].as_f64().unwrap();
            let d = ((g(0) - e[0] as f64).powi(2) + (g(1) - e[1] as f64).powi(2)).sqrt();
            worst = worst.max(d);
        }
    }
    // The bound: an elbow bent 69° on a 543-unit figure costs 13 units
    // at the joint; everywhere else the rig follows within a unit.
    let height = {
        let ys = puppet.frames[0].iter().map(|q| q[1]);
        f64::from(ys.clone().fold(f32::MIN, f32::max) - ys.fold(f32::MAX, f32::min))
    };
    assert!(
        error < 0.04 * height && mean < 1.0,
        "max {error}, mean {mean}"
    );
    assert!(
        worst <= error + 1e-3,
        "spine-core is {worst} stage units from the take, the fit said {error}"
    );
    // What the rig saves: the same frames as deform keys, for the record.
    let mut keyed = animation.clone();
    keyed.puppets[0].skeleton = None;
    let keyed_path = dir.path().join("keyed.json");
    export_spine(&keyed, &SpineOptions::default(), &mut (), &keyed_path).unwrap();
    let size = |p: &Path| std::fs::metadata(p).unwrap().len() as f64 / animation.duration();
    crate::common::note(&format!(
        "Spine per second of take: {:.0} kB as bones, {:.0} kB as deform keys",
        size(&path) / 1e3,
        size(&keyed_path) / 1e3
    ));
    crate::common::note(&format!(
        "skeleton to Spine bones: spine-core within {worst:.3} stage units of the take \
         (fit's bound {error:.3}, mean {mean:.3}; the puppet is {height:.0} units tall)"
    ));
}

/// A take of the demo skeleton (config/skeleton.toml) whose right hand
/// swings up and back about its elbow, read into an animation.
fn skeleton_take(dir: &Path) -> puppetry_export::Animation {
    let root = crate::fixture::root();
    let config = StageConfig::load(&root.join("config/skeleton.toml")).unwrap();
    let take = dir.join("wave.take");
    let mut stage = Stage::from_config(&config).unwrap();
    stage.solve();
    let joints = stage.puppets()[0].rig().points().unwrap().to_vec();
    let (elbow, hand) = (joints[8], joints[9]);
    let frames = 45;
    // The right hand swung up and back about its elbow.
    let points: Vec<DVec2> = (0..frames)
        .map(|k| {
            let a = (k as f64 / frames as f64 * std::f64::consts::TAU).sin() * 1.2;
            elbow + DVec2::from_angle(a).rotate(hand - elbow)
        })
        .collect();
    crate::fixture::record_drag(&take, &mut stage, "wave", FPS, &points);
    animation_of_take(&take, &config, FPS, None, None).unwrap()
}

/// The same rig as a glTF skin: valid (Khronos validator), and three.js
/// skins it to the take within the fit's bound.
#[test]
fn a_skeleton_take_exports_as_a_gltf_skin() {
    let dir = tempfile::tempdir().unwrap();
    let animation = skeleton_take(dir.path());
    let puppet = &animation.puppets[0];
    let skin = puppetry_export::skin::fit(puppet, puppet.skeleton.as_ref().unwrap());
    let error = skin.max_error;
    let ks: Vec<usize> = (0..animation.frame_count).step_by(4).collect();
    let times: Vec<String> = ks.iter().map(|&k| (k as f64 / FPS).to_string()).collect();
    let glb = dir.path().join("wave.glb");
    puppetry_export::gltf::export_glb(&animation, &Default::default(), &mut (), &glb).unwrap();
    let report = node_script("export-validate.mjs", &["gltf-validator"], &[arg(&glb)]);
    assert_eq!(report["issues"]["numErrors"], 0, "{report}");
    assert_eq!(report["issues"]["numWarnings"], 0, "{report}");
    let three = node_script(
        "export-three.mjs",
        &["three", "playwright-core"],
        &[arg(&glb), &times.join(",")],
    );
    let mut worst_gltf = 0.0f64;
    for (sample, &k) in three["samples"].as_array().unwrap().iter().zip(&ks) {
        // three.js names the mesh "gingerbread_skinned" (spaces become _).
        let meshes = sample["skinned"].as_object().unwrap();
        assert_eq!(meshes.len(), 1, "one skinned mesh: {:?}", meshes.keys());
        let skinned = meshes.values().next().unwrap().as_array().unwrap();
        assert_eq!(skinned.len(), puppet.frames[k].len() * 3);
        for (v, e) in puppet.frames[k].iter().enumerate() {
            let g = |c: usize| skinned[v * 3 + c].as_f64().unwrap();
            let d = ((g(0) - e[0] as f64).powi(2) + (g(1) - e[1] as f64).powi(2)).sqrt();
            worst_gltf = worst_gltf.max(d);
            assert!(g(2).abs() < 1e-3, "z of vertex {v}: {}", g(2));
        }
    }
    assert!(
        worst_gltf <= error + 1e-3,
        "three.js skins it {worst_gltf} stage units from the take, the fit said {error}"
    );
    crate::common::note(&format!(
        "skeleton to glTF skin: three.js within {worst_gltf:.3} stage units of the take"
    ));
}

/// Let go, a puppet springs back in one solve: the take steps there, and
/// the keyed exports hold the frame before until the snap instead of
/// blending into it (Spine's `stepped` curve; glb a key just before), while
/// the rest of the motion still blends between frames as before.
#[test]
fn a_let_go_is_a_step_in_spine_and_glb_not_a_blend() {
    if !crate::common::browser_enabled("a_let_go_is_a_step_in_spine_and_glb_not_a_blend") {
        return;
    }
    const FPS: f64 = 30.0;
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("snap.take");
    const LET_GO: usize = 9;
    let config = record_let_go(&take, FPS, LET_GO);
    let animation =
        puppetry_export::take::animation_of_take(&take, &config, FPS, None, None).unwrap();
    let p = &animation.puppets[0];
    assert_eq!(p.snaps, [LET_GO], "the take stepped where the hand let go");
    let between = |k: usize| ((k as f64 - 0.5) / FPS).to_string();
    let far = |a: &[[f32; 2]], b: &[[f32; 2]]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2)).sqrt())
            .fold(0.0f32, f32::max)
    };
    assert!(
        far(&p.frames[LET_GO - 1], &p.frames[LET_GO]) > 20.0,
        "no snap to check"
    );

    // Spine: half a frame before the snap, still the held frame; half a
    // frame before an ordinary frame, between its neighbours.
    let json = dir.path().join("snap.json");
    let layout = export_spine(&animation, &SpineOptions::default(), &mut (), &json).unwrap();
    let result = node_script(
        "export-spine.mjs",
        &["@esotericsoftware/spine-core"],
        &[
            arg(&json),
            "take",
            &format!("{},{}", between(LET_GO), between(5)),
        ],
    );
    let placed = &layout.puppets[0];
    let spine_pose = |sample: &serde_json::Value| -> Vec<[f32; 2]> {
        let world = sample["slots"][&placed.slot].as_array().unwrap();
        let mut pose = vec![[0.0f32; 2]; p.vertex_count()];
        for (i, &v) in placed.order.iter().enumerate() {
            pose[v as usize] = [
                world[2 * i].as_f64().unwrap() as f32,
                world[2 * i + 1].as_f64().unwrap() as f32,
            ];
        }
        pose
    };
    let samples = result["samples"].as_array().unwrap();
    let held = spine_pose(&samples[0]);
    assert!(
        far(&held, &p.frames[LET_GO - 1]) < 1e-3,
        "Spine blends into the snap: {}",
        far(&held, &p.frames[LET_GO - 1])
    );
    let blended = spine_pose(&samples[1]);
    assert!(
        far(&blended, &p.frames[4]) > 1.0 && far(&blended, &p.frames[5]) > 1.0,
        "Spine no longer blends between frames"
    );

    // glb in three.js: the same.
    let glb = dir.path().join("snap.glb");
    puppetry_export::gltf::export_glb(
        &animation,
        &puppetry_export::gltf::GltfOptions::default(),
        &mut (),
        &glb,
    )
    .unwrap();
    let report = node_script("export-validate.mjs", &["gltf-validator"], &[arg(&glb)]);
    assert_eq!(report["issues"]["numErrors"], 0, "{report}");
    let result = node_script(
        "export-three.mjs",
        &["three", "playwright-core"],
        &[arg(&glb), &format!("{},{}", between(LET_GO), between(5))],
    );
    let three_pose = |sample: &serde_json::Value| -> Vec<[f32; 2]> {
        let xyz = sample["puppets"][0]["positions"].as_array().unwrap();
        xyz.chunks(3)
            .map(|c| [c[0].as_f64().unwrap() as f32, c[1].as_f64().unwrap() as f32])
            .collect()
    };
    let samples = result["samples"].as_array().unwrap();
    let held = three_pose(&samples[0]);
    assert!(
        far(&held, &p.frames[LET_GO - 1]) < 1e-3,
        "glb blends into the snap: {}",
        far(&held, &p.frames[LET_GO - 1])
    );
    let blended = three_pose(&samples[1]);
    assert!(
        far(&blended, &p.frames[4]) > 1.0 && far(&blended, &p.frames[5]) > 1.0,
        "glb no longer blends between frames"
    );
}

/// A take of the head dragged sideways (feet pinned), held still, and let
/// go at step `let_go`; returns its stage file.
fn record_let_go(take: &Path, fps: f64, let_go: usize) -> StageConfig {
    use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
    let text = format!(
        "{}{}",
        puppetry_testkit::stage_text::STAGE,
        puppetry_testkit::stage_text::Gingerbread::new("gingerbread")
            .pins("[[168, 58], [344, 58]]")
    );
    let config =
        puppetry_stage::config::StageConfig::parse("snap.toml", &text, std::path::Path::new("/"))
            .unwrap();
    let mut stage = puppetry_stage::Stage::from_config(&config).unwrap();
    stage.solve();
    let head = stage.puppets()[0].mesh.vertices().iter().copied().fold(
        glam::DVec2::splat(f64::NEG_INFINITY),
        |a, b| {
            if b.y > a.y { b } else { a }
        },
    ) - glam::DVec2::new(0.0, 10.0);
    let points: Vec<glam::DVec2> = (0..12)
        .map(|k| head + glam::DVec2::new(12.0 * k.min(8) as f64, 0.0))
        .collect();
    crate::fixture::record_drag_with(take, &mut stage, "snap", fps, &points, |k, _| {
        if k != let_go {
            return Vec::new();
        }
        vec![puppetry_stage::Change::Contacts {
            frame: ContactFrame {
                source: SourceId::new("hand"),
                time: k as f64,
                contacts: vec![Contact::new(1, Phase::Up, points[k])],
            },
        }]
    });
    config
}
