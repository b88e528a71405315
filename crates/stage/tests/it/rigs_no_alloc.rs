//! A rigged puppet's frame (handles moved, no handle set change) must not
//! allocate, for grids and for skeletons in both modes: this test binary
//! counts every allocation made while the rigs solve.

use puppetry_testkit::alloc;

use std::path::{Path, PathBuf};

use glam::DVec2;
use puppetry_mesh::Mesh;
use puppetry_stage::config::{GridConfig, SkeletonConfig, SkeletonMode, StageConfig};
use puppetry_stage::{Grip, Handle, HandleKind, Owner, Rig, Stage};

fn root() -> PathBuf {
    puppetry_testkit::root()
}

/// The demo skeleton's stage file section.
fn demo_skeleton() -> SkeletonConfig {
    let config = StageConfig::load(&root().join("config/skeleton.toml")).unwrap();
    config.puppets[0].skeleton.clone().unwrap()
}

fn handle(id: u64, grip: Grip, at: DVec2) -> Handle {
    Handle {
        id,
        owner: Owner::Source("test".into()),
        kind: HandleKind::Contact,
        grip,
        target: at,
        offset: DVec2::ZERO,
    }
}

/// Solves once with the handle set (compile), then 30 frames of moves;
/// returns the allocations the moves made.
fn frame_allocations(rig: &mut Rig, handles: &mut [Handle]) -> usize {
    rig.solve(handles, true).unwrap();
    alloc::start();
    for frame in 0..30 {
        for (k, h) in handles.iter_mut().enumerate() {
            h.target += DVec2::new(0.5, (frame + k) as f64 * 0.1);
        }
        rig.solve(handles, false).unwrap();
    }
    alloc::stop()
}

#[test]
fn rig_frames_do_not_allocate() {
    let mesh_file = root().join("assets/gingerbread/gingerbread.mesh.json");
    let source = Mesh::load(&mesh_file).unwrap();
    let text = format!(
        "[stage]\nwidth = 1280\nheight = 720\n[[puppet]]\nname = \"g\"\nimage = \"x.png\"\nmesh = \"{}\"\nat = [640, 360]\nscale = 1.2\n",
        mesh_file.display()
    );
    let stage =
        Stage::from_config(&StageConfig::parse("t.toml", &text, Path::new("/")).unwrap()).unwrap();
    let placed = stage.puppets()[0].mesh.clone();
    let at = DVec2::new(640.0, 360.0);

    let grid = GridConfig {
        columns: 10,
        rows: 10,
        basis: Default::default(),
        locality: None,
        vertex: None,
        grid: None,
        regular: None,
        iterations: None,
    };
    let mut rig = Rig::from_config(&source, &placed, at, 1.2, Some(&grid), None, None).unwrap();
    let grid_handle = rig.points().unwrap()[95];
    let point = stage.puppets()[0].hit(at).unwrap();
    let mut handles = [
        handle(1, Grip::GridHandle(95), grid_handle),
        handle(2, Grip::Point(point), at),
    ];
    assert_eq!(
        frame_allocations(&mut rig, &mut handles),
        0,
        "grid frames allocated"
    );
    assert!(rig.pose() != placed.vertices(), "it moved");

    for mode in [SkeletonMode::Free, SkeletonMode::Fk] {
        let mut skeleton = demo_skeleton();
        skeleton.mode = mode;
        let mut rig =
            Rig::from_config(&source, &placed, at, 1.2, None, Some(&skeleton), None).unwrap();
        let joints = rig.points().unwrap().to_vec();
        let mut handles = [
            handle(1, Grip::Joint(9), joints[9]),
            handle(2, Grip::Joint(0), joints[0]),
        ];
        assert_eq!(
            frame_allocations(&mut rig, &mut handles),
            0,
            "{mode:?} skeleton frames allocated"
        );
        assert!(
            rig.points().unwrap()[9].distance(joints[9]) > 1.0,
            "the hand moved"
        );
    }

    // The counter works: a compile does allocate.
    let mut rig = Rig::from_config(&source, &placed, at, 1.2, Some(&grid), None, None).unwrap();
    alloc::start();
    rig.solve(&[handle(1, Grip::GridHandle(3), DVec2::ZERO)], true)
        .unwrap();
    assert!(alloc::stop() > 0);
}
