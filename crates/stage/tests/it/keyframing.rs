//! Spatial keyframing on the stage (the 2005 paper's §5.3): key poses set
//! from held handles, the cursor blending them through the solver, a finger
//! overriding a keyed grip, pads on input sources, key files in the stage
//! file, and exact replay of keyframing changes.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, HandleKind, Stage};
use puppetry_testkit::stage_text::{Gingerbread, STAGE};

fn config(extra_puppet: &str, extra: &str) -> StageConfig {
    let text = format!(
        "{STAGE}{}{extra}\n",
        Gingerbread::new("gingerbread")
            .hand_pins()
            .with(extra_puppet)
    );
    StageConfig::parse("keys-test.toml", &text, Path::new("/")).unwrap()
}

fn contacts(source: &str, list: &[(u32, Phase, DVec2)]) -> Change {
    Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new(source),
            time: 0.0,
            contacts: list
                .iter()
                .map(|&(id, phase, at)| Contact::new(id, phase, at))
                .collect(),
        },
    }
}

/// Head, left hand and right hand of the demo puppet (stage points).
const GRABS: [[f64; 2]; 3] = [[640.0, 470.0], [560.0, 380.0], [720.0, 380.0]];

fn apply(stage: &mut Stage, change: &Change) {
    stage.apply_change(change).unwrap();
    stage.solve();
}

fn pose(stage: &Stage) -> Vec<DVec2> {
    stage.puppets()[0].pose().to_vec()
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

/// Holds the three points, moves them by `offsets`, adds a key at `at`,
/// lifts them; returns the pose the key was made from.
fn key_from_hands(
    stage: &mut Stage,
    name: &str,
    at: [f64; 2],
    offsets: [[f64; 2]; 3],
) -> Vec<DVec2> {
    let downs: Vec<_> = GRABS
        .iter()
        .enumerate()
        .map(|(i, g)| (i as u32, Phase::Down, DVec2::from(*g)))
        .collect();
    apply(stage, &contacts("hands", &downs));
    let moves: Vec<_> = GRABS
        .iter()
        .zip(offsets)
        .enumerate()
        .map(|(i, (g, o))| (i as u32, Phase::Move, DVec2::from(*g) + DVec2::from(o)))
        .collect();
    apply(stage, &contacts("hands", &moves));
    let seen = pose(stage);
    apply(
        stage,
        &Change::KeyAdd {
            puppet: 0,
            name: name.into(),
            at: DVec2::from(at),
        },
    );
    let ups: Vec<_> = (0..3).map(|i| (i, Phase::Up, DVec2::ZERO)).collect();
    apply(stage, &contacts("hands", &ups));
    seen
}

fn three_keys(stage: &mut Stage) -> Vec<(DVec2, Vec<DVec2>)> {
    vec![
        (
            DVec2::new(0.2, 0.2),
            key_from_hands(
                stage,
                "up",
                [0.2, 0.2],
                [[0.0, 60.0], [-40.0, 40.0], [40.0, 40.0]],
            ),
        ),
        (
            DVec2::new(0.8, 0.2),
            key_from_hands(
                stage,
                "lean",
                [0.8, 0.2],
                [[80.0, -20.0], [0.0, -50.0], [30.0, 60.0]],
            ),
        ),
        (
            DVec2::new(0.5, 0.9),
            key_from_hands(
                stage,
                "wave",
                [0.5, 0.9],
                [[-30.0, 0.0], [-90.0, 20.0], [0.0, 0.0]],
            ),
        ),
    ]
}

fn cursor(stage: &mut Stage, at: DVec2) {
    apply(
        stage,
        &Change::Cursor {
            puppet: 0,
            at: Some(at),
        },
    );
}

#[test]
fn the_cursor_on_each_key_point_gives_its_pose() {
    let mut stage = Stage::from_config(&config("", "")).unwrap();
    let keys = three_keys(&mut stage);
    let entries = stage.puppets()[0].keying().keys().to_vec();
    assert_eq!(entries.len(), 3);
    for (k, (at, seen)) in keys.iter().enumerate() {
        cursor(&mut stage, *at);
        // The keyed handles are exactly where the key put them…
        let targets: Vec<f64> = stage.puppets()[0]
            .handles()
            .iter()
            .filter(|h| h.kind == HandleKind::Key)
            .flat_map(|h| [h.target.x, h.target.y])
            .collect();
        assert_eq!(targets.len(), 6, "the cursor holds the three keyed points");
        for (t, v) in targets.iter().zip(&entries[k].values) {
            assert!(
                (t - v).abs() < 1e-9,
                "key {k}: handle at {t}, key value {v}"
            );
        }
        // …so the pose is the key's pose. The first key holds the very
        // points the hands held (to 1e-9); later ones were made by hands
        // that landed on the puppet a hair (<1e-9 of rest) away from the
        // keyed points, so they match to the solver's sensitivity to that.
        let d = max_distance(&pose(&stage), seen);
        let tolerance = if k == 0 { 1e-9 } else { 1e-6 };
        assert!(d < tolerance, "key at {at}: {d} off its pose");
    }
    // Letting the cursor go lets the puppet go.
    apply(
        &mut stage,
        &Change::Cursor {
            puppet: 0,
            at: None,
        },
    );
    assert!(
        stage.puppets()[0]
            .handles()
            .iter()
            .all(|h| h.kind != HandleKind::Key)
    );
}

#[test]
fn one_key_gives_a_constant_pose() {
    let mut stage = Stage::from_config(&config("", "")).unwrap();
    let seen = key_from_hands(
        &mut stage,
        "only",
        [0.5, 0.5],
        [[10.0, 30.0], [-20.0, 10.0], [20.0, -10.0]],
    );
    for at in [[0.0, 0.0], [1.0, 1.0], [0.3, 0.9], [0.5, 0.5]] {
        cursor(&mut stage, DVec2::from(at));
        assert!(max_distance(&pose(&stage), &seen) < 1e-9, "at {at:?}");
    }
}

/// The largest vertex jump between neighbouring cursor positions along a
/// sweep of `steps` steps through all three keys.
fn largest_jump(steps: usize) -> f64 {
    let mut stage = Stage::from_config(&config("", "")).unwrap();
    three_keys(&mut stage);
    let mut last: Option<Vec<DVec2>> = None;
    let mut largest = 0.0f64;
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        // Corner to corner, passing between the keys.
        cursor(&mut stage, DVec2::new(t, 0.1 + 0.8 * t));
        let now = pose(&stage);
        if let Some(before) = &last {
            largest = largest.max(max_distance(before, &now));
        }
        last = Some(now);
    }
    largest
}

#[test]
fn blending_is_continuous_across_a_dense_sweep() {
    let coarse = largest_jump(200);
    let fine = largest_jump(400);
    // Continuous: halving the step (about) halves the largest jump, and no
    // jump is larger than a few stage units at this density.
    assert!(
        fine < 0.75 * coarse,
        "jumps {coarse} then {fine}: not shrinking with the step"
    );
    assert!(fine < 5.0, "a jump of {fine} stage units");
}

#[test]
fn a_finger_on_a_keyed_point_takes_it_over_until_it_lets_go() {
    let mut stage = Stage::from_config(&config("", "")).unwrap();
    three_keys(&mut stage);
    cursor(&mut stage, DVec2::new(0.5, 0.5));
    let head = stage.puppets()[0]
        .handles()
        .iter()
        .filter(|h| h.kind == HandleKind::Key)
        .map(|h| h.target)
        .next()
        .unwrap();
    apply(&mut stage, &contacts("finger", &[(9, Phase::Down, head)]));
    apply(
        &mut stage,
        &contacts("finger", &[(9, Phase::Move, head + DVec2::new(0.0, 80.0))]),
    );
    let handles = stage.puppets()[0].handles();
    assert_eq!(
        handles.iter().filter(|h| h.kind == HandleKind::Key).count(),
        2
    );
    let finger = handles
        .iter()
        .find(|h| h.kind == HandleKind::Contact)
        .unwrap();
    assert_eq!(
        finger.target,
        head + DVec2::new(0.0, 80.0),
        "the finger, not the cursor, holds it"
    );
    apply(&mut stage, &contacts("finger", &[(9, Phase::Up, head)]));
    assert_eq!(
        stage.puppets()[0]
            .handles()
            .iter()
            .filter(|h| h.kind == HandleKind::Key)
            .count(),
        3,
        "the cursor holds it again"
    );
}

#[test]
fn a_pad_on_an_input_source_moves_the_cursor_instead_of_grabbing() {
    let pad =
        "[[pad]]\npuppet = \"gingerbread\"\nsource = \"table\"\narea = [1000, 500, 1200, 700]\n";
    let mut stage = Stage::from_config(&config("", pad)).unwrap();
    three_keys(&mut stage);
    let (at, seen) = &three_keys_points()[1];
    let stage_point = DVec2::new(1000.0, 500.0) + *at * 200.0;
    apply(
        &mut stage,
        &contacts("table", &[(1, Phase::Down, stage_point)]),
    );
    assert_eq!(stage.puppets()[0].keying().cursor(), Some(*at));
    let _ = seen;
    // Another source's contact there is no pad contact.
    apply(
        &mut stage,
        &contacts("other", &[(1, Phase::Down, stage_point)]),
    );
    assert_eq!(stage.puppets()[0].keying().cursor(), Some(*at));
    apply(
        &mut stage,
        &contacts("table", &[(1, Phase::Move, DVec2::new(1100.0, 600.0))]),
    );
    assert_eq!(
        stage.puppets()[0].keying().cursor(),
        Some(DVec2::new(0.5, 0.5))
    );
}

fn three_keys_points() -> Vec<(DVec2, ())> {
    vec![
        (DVec2::new(0.2, 0.2), ()),
        (DVec2::new(0.8, 0.2), ()),
        (DVec2::new(0.5, 0.9), ()),
    ]
}

#[test]
fn key_files_save_and_load_with_the_stage() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("g.keys.json");
    let keys_line = format!("keys = \"{}\"", file.display());
    let mut stage = Stage::from_config(&config(&keys_line, "")).unwrap();
    let keys = three_keys(&mut stage);
    let (path, key_file) = stage.key_file(0).unwrap();
    assert_eq!(path, file);
    key_file.save(&path).unwrap();
    // A stage loaded from the file has the same keys, and they drive the
    // puppet the same way.
    let mut again = Stage::from_config(&config(&keys_line, "")).unwrap();
    again.solve();
    assert_eq!(again.puppets()[0].keying().keys().len(), 3);
    for (at, seen) in &keys {
        cursor(&mut again, *at);
        let d = max_distance(&pose(&again), seen);
        assert!(d < 1e-6, "key at {at}: {d} off after saving and loading");
    }
}

#[test]
fn bad_key_files_and_pads_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.keys.json");
    let keys_line = format!("keys = \"{}\"", file.display());
    let good = r#"{"puppet": "gingerbread", "grips": [{"kind": "point", "at": [256, 300]}],
        "keys": [{"name": "a", "at": [0.5, 0.5], "values": [256, 320]}]}"#;
    std::fs::write(&file, good).unwrap();
    Stage::from_config(&config(&keys_line, "")).unwrap();
    let cases = [
        (good.replace("320]", "NaN]"), "NaN"),
        (good.replace("\"gingerbread\"", "\"someone\""), "puppet"),
        (good.replace("[256, 300]", "[-900, 300]"), "grips[0].at"),
        (good.replace("[256, 320]", "[256]"), "values"),
    ];
    for (text, needle) in cases {
        std::fs::write(&file, &text).unwrap();
        let err = Stage::from_config(&config(&keys_line, ""))
            .err()
            .unwrap_or_else(|| panic!("{text} was accepted"))
            .to_string();
        assert!(
            err.contains("bad.keys.json") && err.contains(needle),
            "{err}"
        );
    }
    let pad = "[[pad]]\npuppet = \"nobody\"\narea = [0, 0, 10, 10]\n";
    let text = format!("{STAGE}{}{pad}", Gingerbread::new("g"));
    let err = StageConfig::parse("pads.toml", &text, Path::new("/"))
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("pads.toml") && err.contains("pad[0].puppet"),
        "{err}"
    );
}

#[test]
fn keyframing_changes_replay_exactly() {
    // The same changes into two fresh stages give the same bits: a take
    // records these changes and replays them.
    let run = || {
        let mut stage = Stage::from_config(&config("", "")).unwrap();
        stage.solve();
        three_keys(&mut stage);
        let mut poses = Vec::new();
        for i in 0..50 {
            let t = i as f64 / 49.0;
            cursor(&mut stage, DVec2::new(t, 1.0 - t));
            poses.push(pose(&stage));
        }
        poses
    };
    let (a, b) = (run(), run());
    let bits = |v: &[Vec<DVec2>]| -> Vec<u64> {
        v.iter()
            .flatten()
            .flat_map(|p| [p.x.to_bits(), p.y.to_bits()])
            .collect()
    };
    assert!(bits(&a) == bits(&b));
}

#[test]
fn a_skeleton_keys_its_joint_angles() {
    let root = puppetry_testkit::root();
    let config = StageConfig::load(&root.join("config/skeleton.toml")).unwrap();
    let mut stage = Stage::from_config(&config).unwrap();
    stage.solve();
    let names: Vec<String> = match stage.puppets()[0].rig() {
        puppetry_stage::Rig::Skeleton(r) => r.pose_names().iter().map(|s| s.to_string()).collect(),
        _ => panic!("config/skeleton.toml has a skeleton"),
    };
    let mut seen = Vec::new();
    for (i, name) in names.iter().take(2).enumerate() {
        stage.set_key_pose(0, name, name, 0.0).unwrap();
        stage.solve();
        seen.push(pose(&stage));
        let at = DVec2::new(0.2 + 0.6 * i as f64, 0.5);
        apply(
            &mut stage,
            &Change::KeyAdd {
                puppet: 0,
                name: name.clone(),
                at,
            },
        );
    }
    for (i, seen) in seen.iter().enumerate() {
        cursor(&mut stage, DVec2::new(0.2 + 0.6 * i as f64, 0.5));
        let d = max_distance(&pose(&stage), seen);
        assert!(d < 1e-9, "key {i}: {d} off");
    }
}

#[test]
fn a_grid_puppet_keys_its_grid_handles() {
    // Enough iterations for lp-FFD to converge from wherever it starts.
    let grid = "[puppet.grid]\ncolumns = 6\nrows = 6\niterations = 200\n";
    let mut stage = Stage::from_config(&config(grid, "")).unwrap();
    stage.solve();
    let handles: Vec<DVec2> = {
        let points = stage.puppets()[0].rig().points().unwrap();
        vec![points[33], points[2]]
    };
    let mut seen = Vec::new();
    for (k, offset) in [[0.0, 40.0], [30.0, -20.0]].into_iter().enumerate() {
        let downs: Vec<_> = handles
            .iter()
            .enumerate()
            .map(|(i, &at)| (i as u32, Phase::Down, at))
            .collect();
        apply(&mut stage, &contacts("hands", &downs));
        let moves: Vec<_> = handles
            .iter()
            .enumerate()
            .map(|(i, &at)| {
                (
                    i as u32,
                    Phase::Move,
                    at + DVec2::from(offset) * (i + 1) as f64,
                )
            })
            .collect();
        apply(&mut stage, &contacts("hands", &moves));
        seen.push(pose(&stage));
        let at = DVec2::new(0.2 + 0.6 * k as f64, 0.5);
        apply(
            &mut stage,
            &Change::KeyAdd {
                puppet: 0,
                name: format!("k{k}"),
                at,
            },
        );
        let ups: Vec<_> = (0..2).map(|i| (i, Phase::Up, DVec2::ZERO)).collect();
        apply(&mut stage, &contacts("hands", &ups));
    }
    for (k, seen) in seen.iter().enumerate() {
        cursor(&mut stage, DVec2::new(0.2 + 0.6 * k as f64, 0.5));
        let keyed: Vec<_> = stage.puppets()[0]
            .handles()
            .iter()
            .filter(|h| h.kind == HandleKind::Key)
            .map(|h| h.grip)
            .collect();
        assert!(
            keyed
                .iter()
                .all(|g| matches!(g, puppetry_stage::Grip::GridHandle(_))),
            "{keyed:?}"
        );
        assert_eq!(keyed.len(), 2);
        // lp-FFD iterates from its last state, so a pose reached along
        // another path agrees to the solver's convergence, not to the bit.
        let d = max_distance(&pose(&stage), seen);
        assert!(d < 1e-3, "key {k}: {d} off its pose");
    }
}
