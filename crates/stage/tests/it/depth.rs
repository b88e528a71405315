//! Depth on the stage: the demo figure's arm dragged across its body is
//! drawn wholly over it (every arm triangle that overlaps a body triangle
//! is nearer), the depth's generation changes only when the depth does, and
//! `depth = "off"` keeps the mesh's order.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_deform::depth::triangles_overlap;
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, Stage};
use puppetry_testkit::stage_text::{Gingerbread, STAGE};

fn demo(extra: &str) -> StageConfig {
    let text = format!(
        "{STAGE}{}",
        Gingerbread::new("gingerbread")
            .pins("[[168, 58], [344, 58], [256, 250]]")
            .with(extra)
    );
    StageConfig::parse("depth-test.toml", &text, Path::new("/")).unwrap()
}

fn touch(stage: &mut Stage, phase: Phase, at: DVec2) {
    let change = Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new("finger"),
            time: 0.0,
            contacts: vec![Contact::new(1, phase, at)],
        },
    };
    stage.apply_change(&change).unwrap();
    stage.solve();
}

/// The right hand (a little in from the right-most vertex).
fn hand(stage: &Stage) -> DVec2 {
    let right = stage.puppets()[0].mesh.vertices().iter().copied().fold(
        DVec2::splat(f64::NEG_INFINITY),
        |a, b| {
            if b.x > a.x { b } else { a }
        },
    );
    right - DVec2::new(15.0, 0.0)
}

/// Drags the right hand across the chest, solving every step (the feet
/// and the chest are pinned, so the arm folds over the body rather than
/// pulling the figure over).
fn fold_the_arm(stage: &mut Stage) {
    let from = hand(stage);
    let to = DVec2::new(610.0, 350.0);
    touch(stage, Phase::Down, from);
    for step in 1..=12 {
        touch(stage, Phase::Move, from.lerp(to, step as f64 / 12.0));
    }
}

fn corners(positions: &[DVec2], t: [u32; 3]) -> [DVec2; 3] {
    t.map(|v| positions[v as usize])
}

#[test]
fn an_arm_dragged_across_the_body_is_drawn_wholly_over_it() {
    let mut stage = Stage::from_config(&demo("")).unwrap();
    let (rest_depth, first) = {
        let (d, g) = stage.puppets()[0].depth().expect("depth is on by default");
        (d.to_vec(), g)
    };
    let rest: Vec<DVec2> = stage.puppets()[0].mesh.vertices().to_vec();
    let triangles: Vec<[u32; 3]> = stage.puppets()[0].mesh.triangles().to_vec();
    let centroid = |t: [u32; 3]| corners(&rest, t).iter().sum::<DVec2>() / 3.0;
    let hand_x = hand(&stage).x;
    // At rest: the forearm and hand reach right of the shoulder (the
    // shoulder's crease, where either side may be in front, is left out);
    // the chest is the middle of the figure.
    let arm: Vec<usize> = (0..triangles.len())
        .filter(|&t| centroid(triangles[t]).x > hand_x - 80.0)
        .collect();
    let body: Vec<usize> = (0..triangles.len())
        .filter(|&t| (centroid(triangles[t]) - DVec2::new(640.0, 350.0)).length() < 90.0)
        .collect();
    assert!(
        arm.len() > 20 && body.len() > 20,
        "{} {}",
        arm.len(),
        body.len()
    );

    fold_the_arm(&mut stage);
    let puppet = &stage.puppets()[0];
    let (depth, generation) = puppet.depth().unwrap();
    assert_ne!(generation, first, "the fold changed the depth");
    let pose = puppet.pose();
    let mut overlapping = 0;
    for &a in &arm {
        for &b in &body {
            let (ta, tb) = (triangles[a], triangles[b]);
            if ta.iter().any(|v| tb.contains(v)) {
                continue;
            }
            if triangles_overlap(corners(pose, ta), corners(pose, tb)) {
                overlapping += 1;
                assert!(
                    depth[a] > depth[b],
                    "arm triangle {a} (depth {}) under body triangle {b} (depth {})",
                    depth[a],
                    depth[b]
                );
            }
        }
    }
    assert!(
        overlapping > 50,
        "the arm lies over the chest: {overlapping} pairs"
    );

    // Let go: the arm springs back, the overlap is undone, the depth is the
    // static order again.
    touch(&mut stage, Phase::Up, DVec2::ZERO);
    let (depth, _) = stage.puppets()[0].depth().unwrap();
    assert_eq!(depth, rest_depth.as_slice());
}

#[test]
fn depth_off_keeps_the_mesh_order() {
    let mut stage = Stage::from_config(&demo("depth = \"off\"")).unwrap();
    assert!(stage.puppets()[0].depth().is_none());
    fold_the_arm(&mut stage);
    assert!(stage.puppets()[0].depth().is_none());
}

#[test]
fn a_flip_brings_the_body_over_the_arm_and_a_touch_grabs_what_is_in_front() {
    let mut stage = Stage::from_config(&demo("")).unwrap();
    let rest: Vec<DVec2> = stage.puppets()[0].mesh.vertices().to_vec();
    let triangles: Vec<[u32; 3]> = stage.puppets()[0].mesh.triangles().to_vec();
    let hand_x = hand(&stage).x;
    let centroid =
        |pose: &[DVec2], t: usize| corners(pose, triangles[t]).iter().sum::<DVec2>() / 3.0;
    let forearm = |t: usize| centroid(&rest, t).x > hand_x - 80.0;
    let chest = |t: usize| (centroid(&rest, t) - DVec2::new(640.0, 350.0)).length() < 90.0;
    fold_the_arm(&mut stage);
    let pose = stage.puppets()[0].pose().to_vec();
    let inside = |t: usize, at: DVec2| {
        let [p, q, r] = corners(&pose, triangles[t]);
        let d = (q - r).perp_dot(p - r);
        let l1 = (q - r).perp_dot(at - r) / d;
        let l2 = (r - p).perp_dot(at - r) / d;
        l1 > 0.05 && l2 > 0.05 && 1.0 - l1 - l2 > 0.05
    };
    // A point where the forearm lies over the chest.
    let at = (0..triangles.len())
        .filter(|&a| forearm(a))
        .map(|a| centroid(&pose, a))
        .find(|&at| (0..triangles.len()).any(|b| chest(b) && inside(b, at)))
        .expect("the forearm over the chest");
    let on_top = |stage: &Stage| {
        let (depth, _) = stage.puppets()[0].depth().unwrap();
        (0..triangles.len())
            .filter(|&t| inside(t, at))
            .max_by_key(|&t| depth[t])
            .unwrap()
    };
    assert!(forearm(on_top(&stage)));
    // A touch there grabs the part in front.
    let grabbed = |stage: &Stage| match stage.puppets()[0].hit(at) {
        Some(puppetry_deform::Anchor::Point { triangle, .. }) => triangle as usize,
        other => panic!("{other:?}"),
    };
    assert!(
        forearm(grabbed(&stage)),
        "a touch on the fold grabs the arm"
    );

    // "The body in front": the flip is a change, so takes replay it.
    stage.apply_change(&Change::DepthFlip { at }).unwrap();
    stage.solve();
    assert!(
        !forearm(on_top(&stage)),
        "after the flip the body is on top"
    );
    assert!(!forearm(grabbed(&stage)), "and a touch grabs the body");

    // Depth painted somewhere else, then undone: the flip stays (it used to
    // be forgotten, the arm jumping back over the body).
    let far = (0..triangles.len())
        .map(|t| centroid(&pose, t))
        .max_by(|a, b| a.distance(at).total_cmp(&b.distance(at)))
        .unwrap();
    stage
        .apply_change(&Change::PaintDepth {
            puppet: 0,
            at: far,
            radius: 30.0,
            layer: 3,
            stroke: Some(1),
            painter: None,
        })
        .unwrap();
    stage.solve();
    assert!(
        !forearm(on_top(&stage)),
        "depth painted elsewhere keeps the flip"
    );
    let undo = stage.undo(0).unwrap().expect("the dab to undo");
    stage.apply_change(&undo).unwrap();
    stage.solve();
    assert!(!forearm(on_top(&stage)), "and so does its undo");
}

/// Two pieces, one dragged over the other: unpainted, the later piece is
/// drawn in front (the pieces' order); with the first piece painted a layer
/// above (the brush, one stroke), the first is. Undo puts the pieces' order
/// back; the saved mesh keeps the painted layers for the next load.
#[test]
fn painted_layers_decide_which_piece_is_in_front_and_are_saved() {
    let dir = tempfile::tempdir().unwrap();
    let mesh_file = dir.path().join("two.mesh.json");
    std::fs::write(&mesh_file, puppetry_testkit::fixtures::islands(2).to_json()).unwrap();
    let text = |mesh: &Path| {
        format!(
            "[stage]\nwidth = 1280\nheight = 720\n[[puppet]]\nname = \"two\"\nimage = \"two.png\"\nmesh = \"{}\"\nat = [640, 360]\nscale = 20\n",
            mesh.display(),
        )
    };
    let config = StageConfig::parse("layers.toml", &text(&mesh_file), Path::new("/")).unwrap();
    // Pieces at rest: the first over x 500..580, the second 700..780.
    let (first, second) = (DVec2::new(540.0, 360.0), DVec2::new(740.0, 360.0));
    let triangles = stage_triangles(&config);
    let piece = |t: usize| usize::from(t >= triangles / 2);
    // Drags the second piece over the first and says which piece is in
    // front where they overlap.
    let front_after_drag = |stage: &mut Stage| {
        touch(stage, Phase::Down, second);
        for step in 1..=10 {
            touch(stage, Phase::Move, second.lerp(first, step as f64 / 10.0));
        }
        let p = &stage.puppets()[0];
        let (depth, _) = p.depth().unwrap();
        let pose = p.pose();
        let tris = p.mesh.triangles();
        let mut fronts = Vec::new();
        for a in 0..triangles / 2 {
            for b in triangles / 2..triangles {
                if triangles_overlap(corners(pose, tris[a]), corners(pose, tris[b])) {
                    fronts.push(if depth[a] > depth[b] {
                        piece(a)
                    } else {
                        piece(b)
                    });
                }
            }
        }
        touch(stage, Phase::Up, first);
        assert!(fronts.len() > 10, "the pieces overlap: {}", fronts.len());
        fronts.dedup();
        assert_eq!(fronts.len(), 1, "one piece wholly in front");
        fronts[0]
    };

    let mut stage = Stage::from_config(&config).unwrap();
    assert_eq!(
        front_after_drag(&mut stage),
        1,
        "unpainted: the later piece"
    );

    let mut stage = Stage::from_config(&config).unwrap();
    let paint = Change::PaintDepth {
        puppet: 0,
        at: first,
        radius: 60.0,
        layer: 5,
        stroke: Some(1),
        painter: None,
    };
    stage.apply_change(&paint).unwrap();
    stage.solve();
    let (depth, _) = stage.puppets()[0].depth().unwrap();
    assert!((0..triangles).all(|t| depth[t] == if piece(t) == 0 { 5 } else { 1 }));
    // Saved beside the mesh before the drag, and loaded again from there.
    let saved = stage.weights_file(0).unwrap().save().unwrap();
    assert_eq!(front_after_drag(&mut stage), 0, "painted: the first piece");
    let again = StageConfig::parse("layers.toml", &text(&saved), Path::new("/")).unwrap();
    let mut reloaded = Stage::from_config(&again).unwrap();
    assert_eq!(front_after_drag(&mut reloaded), 0, "as saved");

    // Undo the stroke: the pieces' order again.
    let mut stage = Stage::from_config(&config).unwrap();
    stage.apply_change(&paint).unwrap();
    let undo = stage.undo(0).unwrap().expect("the stroke can be undone");
    stage.apply_change(&undo).unwrap();
    stage.solve();
    assert_eq!(front_after_drag(&mut stage), 1, "undone: the later piece");
    // A layer past the highest is refused, naming the field.
    let too_high = Change::PaintDepth {
        puppet: 0,
        at: first,
        radius: 60.0,
        layer: u16::MAX,
        stroke: None,
        painter: None,
    };
    match stage.apply_change(&too_high) {
        Err(e) => assert!(e.to_string().contains("layer"), "{e}"),
        Ok(_) => panic!("a layer past the highest was taken"),
    }
}

fn stage_triangles(config: &StageConfig) -> usize {
    Stage::from_config(config).unwrap().puppets()[0]
        .mesh
        .triangles()
        .len()
}

/// A stiffness dab and a depth dab of one painter's stroke number (a
/// client may send both) are two undo steps: joined, the depth dab's
/// layers were never kept, and undo put back the weights alone, leaving
/// the painted layers on the puppet for good.
#[test]
fn a_depth_dab_never_joins_a_stiffness_stroke_of_the_same_number() {
    let mut stage = Stage::from_config(&demo("")).unwrap();
    stage.solve();
    let loaded_weights = stage.puppets()[0].weights().to_vec();
    let loaded_depth = stage.puppets()[0].depth().unwrap().0.to_vec();
    let at = DVec2::new(640.0, 350.0);
    let painter = Some("client:1".to_string());
    let stiffness = Change::Paint {
        puppet: 0,
        at,
        radius: 60.0,
        strength: 3.0,
        stroke: Some(1),
        painter: painter.clone(),
    };
    let depth = Change::PaintDepth {
        puppet: 0,
        at,
        radius: 60.0,
        layer: 4,
        stroke: Some(1),
        painter,
    };
    for change in [stiffness, depth] {
        stage.apply_change(&change).unwrap();
        stage.solve();
    }
    assert_ne!(
        stage.puppets()[0].depth().unwrap().0,
        loaded_depth.as_slice()
    );
    assert_eq!(stage.puppets()[0].history(), (2, 0), "two steps");
    while let Some(undo) = stage.undo(0).unwrap() {
        stage.apply_change(&undo).unwrap();
        stage.solve();
    }
    assert_eq!(
        stage.puppets()[0].depth().unwrap().0,
        loaded_depth.as_slice()
    );
    assert_eq!(stage.puppets()[0].weights(), loaded_weights.as_slice());
}
