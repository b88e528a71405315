//! Safe edits and skeleton grabs on the stage: the brush's bounds, undo,
//! redo and reset of painting, pins and poses (as changes that replay
//! exactly), versioned weight files, where handle dots are drawn, and a
//! skeleton grabbed anywhere on its shape.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, CommandError, Grip, Rig, Stage};
use puppetry_testkit::stage_text::{Gingerbread, STAGE, gingerbread_mesh};

fn config(extra_puppet: &str) -> StageConfig {
    let text = format!(
        "{STAGE}{}",
        Gingerbread::new("gingerbread")
            .hand_pins()
            .with(extra_puppet)
    );
    StageConfig::parse("edits-test.toml", &text, Path::new("/")).unwrap()
}

fn skeleton(mode: &str) -> StageConfig {
    let root = puppetry_testkit::root();
    let text = std::fs::read_to_string(root.join("config/skeleton.toml"))
        .unwrap()
        .replace("mode = \"fk\"", &format!("mode = \"{mode}\""));
    StageConfig::parse("skeleton.toml", &text, &root.join("config")).unwrap()
}

fn contact(id: u32, phase: Phase, at: DVec2) -> Change {
    Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new("finger"),
            time: 0.0,
            contacts: vec![Contact::new(id, phase, at)],
        },
    }
}

fn dab(at: [f64; 2], strength: f64, stroke: Option<u64>) -> Change {
    Change::Paint {
        puppet: 0,
        at: DVec2::from(at),
        radius: 60.0,
        strength,
        stroke,
        painter: None,
    }
}

/// Applies a change and solves, as the stage thread does; returns it.
fn apply(stage: &mut Stage, change: Change) -> Change {
    stage.apply_change(&change).unwrap();
    stage.solve();
    change
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|w| w.to_bits()).collect()
}

fn pins(stage: &Stage) -> Vec<(u64, DVec2)> {
    stage.puppets()[0]
        .handles()
        .iter()
        .filter(|h| h.kind == puppetry_stage::HandleKind::Pin)
        .map(|h| (h.id, h.target))
        .collect::<std::collections::BTreeMap<_, _>>()
        .into_iter()
        .collect()
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

#[test]
fn a_huge_brush_is_refused_naming_the_field_and_changes_nothing() {
    let mut stage = Stage::from_config(&config("")).unwrap();
    stage.solve();
    let loaded = stage.puppets()[0].weights().to_vec();
    for (radius, strength, field) in [
        (1e308, 1e308, "radius"),
        (60.0, 1e308, "strength"),
        (0.0, 2.0, "radius"),
        (60.0, 0.0, "strength"),
        (60.0, f64::NAN, "strength"),
        (1281.0, 2.0, "radius"),
    ] {
        let Err(err) = stage.paint(0, DVec2::new(640.0, 400.0), radius, strength) else {
            panic!("{radius} {strength} was accepted");
        };
        match &err {
            CommandError::OutOfRange { field: f, .. } => assert_eq!(*f, field, "{err}"),
            other => panic!("{radius} {strength}: {other}"),
        }
        assert!(err.to_string().starts_with(field), "{err}");
    }
    assert_eq!(stage.puppets()[0].weights(), loaded);
    // The edges of the ranges are allowed.
    stage
        .paint(0, DVec2::new(640.0, 400.0), 1280.0, 10.0)
        .unwrap();
    stage.paint(0, DVec2::new(640.0, 400.0), 1.0, 0.1).unwrap();
}

/// Each page numbers its strokes from 1: two directors painting one
/// puppet, one after the other, both paint "stroke 1". Their strokes are
/// two undo steps (undo takes back the second painter's only); without a
/// painter (a take recorded before painters were kept) dabs of one number
/// join as they always did.
#[test]
fn two_painters_strokes_of_one_number_are_two_undo_steps() {
    let mut stage = Stage::from_config(&config("")).unwrap();
    stage.solve();
    let by = |painter: &str, x: f64| Change::Paint {
        puppet: 0,
        at: DVec2::new(x, 400.0),
        radius: 60.0,
        strength: 3.0,
        stroke: Some(1),
        painter: Some(painter.into()),
    };
    for x in [600.0, 620.0] {
        apply(&mut stage, by("client:1", x));
    }
    let first = stage.puppets()[0].weights().to_vec();
    for x in [640.0, 660.0] {
        apply(&mut stage, by("client:2", x));
    }
    assert_eq!(stage.puppets()[0].history(), (2, 0), "two strokes");
    let change = stage.undo(0).unwrap().expect("something to undo");
    apply(&mut stage, change);
    assert_eq!(
        bits(stage.puppets()[0].weights()),
        bits(&first),
        "the second painter's stroke only"
    );
    // No painter: one number, one step.
    let mut old = Stage::from_config(&config("")).unwrap();
    old.solve();
    for x in [600.0, 620.0, 640.0] {
        apply(&mut old, dab([x, 400.0], 3.0, Some(1)));
    }
    assert_eq!(old.puppets()[0].history(), (1, 0));
}

#[test]
fn undo_redo_and_reset_put_weights_pins_and_cursor_back_exactly() {
    let mut stage = Stage::from_config(&config("")).unwrap();
    stage.solve();
    let loaded = stage.puppets()[0].weights().to_vec();
    let loaded_pins = pins(&stage);
    // One stroke of three dabs, then a single dab, then a pin.
    for (i, x) in [600.0, 620.0, 640.0].into_iter().enumerate() {
        apply(&mut stage, dab([x, 400.0], 3.0, Some(7)));
        assert_eq!(stage.puppets()[0].history(), (1, 0), "dab {i} joins");
    }
    let stroke = stage.puppets()[0].weights().to_vec();
    assert_ne!(bits(&stroke), bits(&loaded));
    apply(&mut stage, dab([640.0, 470.0], 0.2, None));
    let painted = stage.puppets()[0].weights().to_vec();
    apply(
        &mut stage,
        Change::Pin {
            owner: "client:1".into(),
            at: DVec2::new(640.0, 470.0),
        },
    );
    assert_eq!(pins(&stage).len(), 3);
    assert_eq!(stage.puppets()[0].history(), (3, 0));

    let undo = |stage: &mut Stage| {
        let change = stage.undo(0).unwrap().expect("something to undo");
        apply(stage, change);
    };
    let redo = |stage: &mut Stage| {
        let change = stage.redo(0).unwrap().expect("something to redo");
        apply(stage, change);
    };
    undo(&mut stage);
    assert_eq!(pins(&stage), loaded_pins, "the pin is undone");
    undo(&mut stage);
    assert_eq!(bits(stage.puppets()[0].weights()), bits(&stroke));
    undo(&mut stage);
    assert_eq!(
        bits(stage.puppets()[0].weights()),
        bits(&loaded),
        "the whole stroke"
    );
    assert_eq!(stage.puppets()[0].history(), (0, 3));
    assert!(stage.undo(0).unwrap().is_none(), "nothing more to undo");
    redo(&mut stage);
    assert_eq!(bits(stage.puppets()[0].weights()), bits(&stroke));
    redo(&mut stage);
    assert_eq!(bits(stage.puppets()[0].weights()), bits(&painted));
    redo(&mut stage);
    assert_eq!(pins(&stage).len(), 3, "the pin is back");
    assert_eq!(stage.puppets()[0].history(), (3, 0));

    // Unpin a stage-file pin, move the cursor, then reset.
    let config_pin = loaded_pins[0].0;
    apply(
        &mut stage,
        Change::Unpin {
            puppet: 0,
            handle: config_pin,
        },
    );
    apply(
        &mut stage,
        Change::Cursor {
            puppet: 0,
            at: Some(DVec2::new(0.5, 0.5)),
        },
    );
    for change in stage.reset(0).unwrap() {
        apply(&mut stage, change);
    }
    assert_eq!(bits(stage.puppets()[0].weights()), bits(&loaded));
    assert_eq!(pins(&stage), loaded_pins);
    assert_eq!(stage.puppets()[0].keying().cursor(), None);
    // Reset is one step: undoing it brings the edits back.
    undo(&mut stage);
    assert_eq!(bits(stage.puppets()[0].weights()), bits(&painted));
    assert_eq!(pins(&stage).len(), 2);
    assert!(pins(&stage).iter().all(|p| p.0 != config_pin));
}

#[test]
fn restored_states_replay_bit_for_bit_into_a_fresh_stage() {
    // What a take records of an undo is the state it put back: applying
    // the recorded changes to a fresh stage gives the same bits, whatever
    // history the live stage had.
    let mut live = Stage::from_config(&config("")).unwrap();
    live.solve();
    let mut recorded = Vec::new();
    let mut poses = Vec::new();
    let mut step = |stage: &mut Stage, change: Change, recorded: &mut Vec<Change>| {
        recorded.push(apply(stage, change));
        poses.push(stage.puppets()[0].pose().to_vec());
    };
    step(
        &mut live,
        contact(1, Phase::Down, DVec2::new(640.0, 470.0)),
        &mut recorded,
    );
    step(&mut live, dab([600.0, 400.0], 4.0, Some(1)), &mut recorded);
    step(&mut live, dab([620.0, 400.0], 4.0, Some(1)), &mut recorded);
    step(
        &mut live,
        contact(1, Phase::Move, DVec2::new(700.0, 480.0)),
        &mut recorded,
    );
    let undo = live.undo(0).unwrap().unwrap();
    assert!(matches!(undo, Change::Restore { .. }));
    step(&mut live, undo, &mut recorded);
    step(
        &mut live,
        contact(1, Phase::Move, DVec2::new(720.0, 500.0)),
        &mut recorded,
    );
    let redo = live.redo(0).unwrap().unwrap();
    step(&mut live, redo, &mut recorded);
    for change in live.reset(0).unwrap() {
        step(&mut live, change, &mut recorded);
    }
    step(&mut live, contact(1, Phase::Up, DVec2::ZERO), &mut recorded);

    // Through JSON, as a take file holds them.
    let text: Vec<String> = recorded
        .iter()
        .map(|c| serde_json::to_string(c).unwrap())
        .collect();
    let mut fresh = Stage::from_config(&config("")).unwrap();
    fresh.solve();
    for (i, line) in text.iter().enumerate() {
        let change: Change = serde_json::from_str(line).unwrap();
        assert_eq!(change, recorded[i]);
        fresh.apply_change(&change).unwrap();
        fresh.solve();
        let pose: Vec<u64> = fresh.puppets()[0]
            .pose()
            .iter()
            .flat_map(|p| [p.x.to_bits(), p.y.to_bits()])
            .collect();
        let want: Vec<u64> = poses[i]
            .iter()
            .flat_map(|p| [p.x.to_bits(), p.y.to_bits()])
            .collect();
        assert!(pose == want, "step {i}: {line}");
    }
    assert_eq!(
        bits(fresh.puppets()[0].weights()),
        bits(live.puppets()[0].weights())
    );
}

#[test]
fn a_bad_restore_from_a_take_is_refused_and_changes_nothing() {
    let mut stage = Stage::from_config(&config("")).unwrap();
    stage.solve();
    let before = stage.puppets()[0].weights().to_vec();
    let bad = Change::Restore {
        puppet: 0,
        state: puppetry_stage::Snapshot {
            weights: Some(vec![1.0; 3]),
            ..Default::default()
        },
    };
    assert!(stage.apply_change(&bad).is_err());
    let bad = Change::Restore {
        puppet: 0,
        state: puppetry_stage::Snapshot {
            weights: Some(vec![1e300; before.len()]),
            ..Default::default()
        },
    };
    assert!(stage.apply_change(&bad).is_err());
    assert_eq!(stage.puppets()[0].weights(), before);
}

#[test]
fn weights_are_saved_to_a_new_version_beside_the_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("gingerbread.mesh.json");
    std::fs::copy(gingerbread_mesh(), &mesh).unwrap();
    let original = std::fs::read(&mesh).unwrap();
    let text = format!("{STAGE}{}", Gingerbread::new("g").mesh(&mesh));
    let config = StageConfig::parse("v.toml", &text, Path::new("/")).unwrap();
    let mut stage = Stage::from_config(&config).unwrap();
    stage.solve();
    stage.paint(0, DVec2::new(640.0, 400.0), 80.0, 5.0).unwrap();
    let v1 = stage.weights_file(0).unwrap().save().unwrap();
    assert_eq!(v1, dir.path().join("gingerbread.v1.mesh.json"));
    let v2 = stage.weights_file(0).unwrap().save().unwrap();
    assert_eq!(v2, dir.path().join("gingerbread.v2.mesh.json"));
    assert_eq!(
        std::fs::read(&mesh).unwrap(),
        original,
        "the original is untouched"
    );
    let saved = puppetry_mesh::Mesh::load(&v1).unwrap();
    assert_eq!(bits(saved.weights()), bits(stage.puppets()[0].weights()));
    // Saving from a version counts from the name's root.
    assert_eq!(
        puppetry_stage::versioned(&v2, 3),
        dir.path().join("gingerbread.v3.mesh.json")
    );
    assert_eq!(
        puppetry_stage::versioned(Path::new("/a/b.json"), 1),
        Path::new("/a/b.v1.json")
    );

    // Overwrite, when the stage file says so.
    let overwrite = StageConfig::parse(
        "v.toml",
        &format!("{text}save_weights = \"overwrite\"\n"),
        Path::new("/"),
    )
    .unwrap();
    let mut stage = Stage::from_config(&overwrite).unwrap();
    stage.solve();
    stage.paint(0, DVec2::new(640.0, 400.0), 80.0, 5.0).unwrap();
    assert_eq!(stage.weights_file(0).unwrap().save().unwrap(), mesh);
    assert_ne!(std::fs::read(&mesh).unwrap(), original);
    assert!(!dir.path().join("gingerbread.v3.mesh.json").exists());
}

#[test]
fn handle_points_are_on_the_solved_puppet_under_the_finger() {
    let mut stage = Stage::from_config(&config("")).unwrap();
    stage.solve();
    let generation = stage.puppets()[0].handles_generation();
    apply(
        &mut stage,
        contact(1, Phase::Down, DVec2::new(640.0, 470.0)),
    );
    assert_ne!(stage.puppets()[0].handles_generation(), generation);
    let finger = DVec2::new(700.0, 520.0);
    apply(&mut stage, contact(1, Phase::Move, finger));
    let mut points = Vec::new();
    stage.puppets()[0].handle_points(&mut points);
    assert_eq!(points.len(), stage.puppets()[0].handles().len());
    let held = stage.puppets()[0]
        .handles()
        .iter()
        .position(|h| h.kind == puppetry_stage::HandleKind::Contact)
        .unwrap();
    assert!(points[held].distance(finger) < 1e-6, "{}", points[held]);
}

fn joints(stage: &Stage) -> Vec<DVec2> {
    match stage.puppets()[0].rig() {
        Rig::Skeleton(r) => r.deformer().joints().to_vec(),
        _ => panic!("a skeleton"),
    }
}

/// A point on the left forearm (bone 5: elbow 5 → hand 6), between its
/// joints and away from both.
fn mid_forearm(stage: &Stage) -> DVec2 {
    let j = joints(stage);
    j[5].lerp(j[6], 0.5) + DVec2::new(0.0, 3.0)
}

#[test]
fn a_skeleton_grabbed_mid_bone_turns_the_bone_in_fk() {
    let mut stage = Stage::from_config(&skeleton("fk")).unwrap();
    stage.solve();
    let before = joints(&stage);
    let at = mid_forearm(&stage);
    apply(&mut stage, contact(1, Phase::Down, at));
    let h = &stage.puppets()[0].handles()[0];
    assert!(
        matches!(h.grip, Grip::Bone { index: 5, .. }),
        "{:?}",
        h.grip
    );
    // Swing the finger up about the elbow.
    let elbow = before[5];
    let finger = elbow + (at - elbow).rotate(DVec2::from_angle(0.6));
    apply(&mut stage, contact(1, Phase::Move, finger));
    let after = joints(&stage);
    assert!(after[5].distance(elbow) < 1e-6, "the elbow stays");
    let turned = (after[6] - after[5]).angle_to(before[6] - before[5]).abs();
    assert!((turned - 0.6).abs() < 1e-3, "the forearm turned {turned}");
    // The dot: the grabbed point, on the ray to the finger.
    let mut points = Vec::new();
    stage.puppets()[0].handle_points(&mut points);
    assert!(
        points[0].distance(finger) < 1e-6,
        "{} vs {finger}",
        points[0]
    );
    assert!(after[4].distance(before[4]) < 1e-9, "the upper arm stays");
}

#[test]
fn a_skeleton_grabbed_mid_bone_drags_it_in_free_mode() {
    let mut stage = Stage::from_config(&skeleton("free")).unwrap();
    stage.solve();
    let before = joints(&stage);
    let at = mid_forearm(&stage);
    apply(&mut stage, contact(1, Phase::Down, at));
    let shift = DVec2::new(25.0, -10.0);
    apply(&mut stage, contact(1, Phase::Move, at + shift));
    let after = joints(&stage);
    for j in [5, 6] {
        assert!(
            after[j].distance(before[j] + shift) < 1e-6,
            "joint {j}: {} vs {}",
            after[j],
            before[j] + shift
        );
    }
    assert!(after[4].distance(before[4]) < 1e-9, "the shoulder stays");
    let mut points = Vec::new();
    stage.puppets()[0].handle_points(&mut points);
    assert!(points[0].distance(at + shift) < 1e-6);
}

#[test]
fn a_pose_undoes_and_resets_to_rest() {
    let mut stage = Stage::from_config(&skeleton("fk")).unwrap();
    stage.solve();
    let rest = stage.puppets()[0].pose().to_vec();
    let names: Vec<String> = match stage.puppets()[0].rig() {
        Rig::Skeleton(r) => r.pose_names().iter().map(|s| s.to_string()).collect(),
        _ => unreachable!(),
    };
    let (from, to) = (names[0].clone(), names[1].clone());
    let pose = |t: f64, stage: &mut Stage| {
        apply(
            stage,
            Change::KeyPose {
                puppet: 0,
                from: from.clone(),
                to: to.clone(),
                t,
            },
        );
    };
    pose(0.25, &mut stage);
    pose(0.5, &mut stage);
    assert_eq!(stage.puppets()[0].history(), (1, 0), "one slide, one step");
    let (key, _) = stage.puppets()[0].key_pose();
    assert_eq!(key.unwrap().t, 0.5);
    let posed = stage.puppets()[0].pose().to_vec();
    assert!(max_distance(&posed, &rest) > 10.0);
    // The shape-matching rounds start from the pose before, so a pose put
    // back is solved to within their tolerance, not to the bit.
    let change = stage.undo(0).unwrap().unwrap();
    apply(&mut stage, change);
    assert!(stage.puppets()[0].key_pose().0.is_none());
    let d = max_distance(stage.puppets()[0].pose(), &rest);
    assert!(d < 0.5, "undone to rest within {d}");
    let change = stage.redo(0).unwrap().unwrap();
    apply(&mut stage, change);
    let d = max_distance(stage.puppets()[0].pose(), &posed);
    assert!(d < 0.5, "redone within {d}");
    assert_eq!(stage.puppets()[0].key_pose().0.unwrap().to, to);
    for change in stage.reset(0).unwrap() {
        apply(&mut stage, change);
    }
    assert!(stage.puppets()[0].key_pose().0.is_none());
    let d = max_distance(stage.puppets()[0].pose(), &rest);
    assert!(d < 0.5, "reset to rest within {d}");
}
