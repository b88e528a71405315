//! The two-step ARAP solver against its specification: exactness against a
//! dense reference, rigid-motion invariance, scale behaviour of the two steps,
//! rigidity weights, point handles, under-constrained pieces, bad handles.

use crate::common::*;
use glam::DVec2;
use puppetry_deform::targets::TargetError;
use puppetry_deform::{Anchor, Arap, ArapError, Steps};
use puppetry_mesh::{Locator, Mesh};
use puppetry_mesh::{MAX_WEIGHT, MIN_THICKNESS, MIN_WEIGHT};

fn solve(mesh: &Mesh, anchors: &[Anchor], targets: &[DVec2], steps: Steps) -> Vec<DVec2> {
    let mut arap = Arap::register(mesh).unwrap();
    arap.compile(anchors).unwrap();
    arap.update(targets, steps).unwrap().to_vec()
}

/// Both steps of the solver against the dense reference, within `tolerance`
/// of the mesh size; returns the reference's final pose.
fn assert_agrees_with_reference(
    mesh: &Mesh,
    anchors: &[Anchor],
    targets: &[DVec2],
    tolerance: f64,
) -> Vec<DVec2> {
    let (ref1, ref2) = dense_reference(mesh, anchors, targets);
    let tol = tolerance * mesh.size();
    let step1 = solve(mesh, anchors, targets, Steps::ScaleFree);
    let both = solve(mesh, anchors, targets, Steps::Both);
    let (off1, off2) = (max_distance(&step1, &ref1), max_distance(&both, &ref2));
    assert!(off1 < tol, "step 1 off by {off1}");
    assert!(off2 < tol, "step 2 off by {off2}");
    ref2
}

fn point_anchor(mesh: &Mesh, p: DVec2) -> Anchor {
    let loc = Locator::new(mesh)
        .locate(mesh, p)
        .expect("point inside the mesh");
    Anchor::Point {
        triangle: loc.triangle,
        bary: loc.bary,
    }
}

#[test]
fn vertex_handles_agree_with_dense_reference() {
    let mesh = jittered(9, 5);
    let anchors = [
        Anchor::Vertex(0),
        Anchor::Vertex(9),
        Anchor::Vertex(54),
        Anchor::Vertex(30),
    ];
    let targets = [
        DVec2::new(-1.0, 0.5),
        DVec2::new(11.0, -2.0),
        DVec2::new(0.5, 6.5),
        DVec2::new(4.0, 4.0),
    ];
    let ref2 = assert_agrees_with_reference(&mesh, &anchors, &targets, 1e-9);
    // The reference itself must have moved the mesh, or the test proves nothing.
    assert!(max_distance(&ref2, mesh.vertices()) > 1.0);
}

#[test]
fn point_handles_agree_with_dense_reference() {
    let mesh = jittered(8, 6);
    let anchors = [
        point_anchor(&mesh, DVec2::new(0.3, 0.4)),
        point_anchor(&mesh, DVec2::new(7.6, 5.3)),
        point_anchor(&mesh, DVec2::new(4.25, 2.9)),
    ];
    let targets = [
        DVec2::new(-2.0, 1.0),
        DVec2::new(9.0, 3.0),
        DVec2::new(5.0, 5.5),
    ];
    assert_agrees_with_reference(&mesh, &anchors, &targets, 1e-9);
}

#[test]
fn weighted_mesh_agrees_with_dense_reference() {
    let base = jittered(8, 4);
    let weights: Vec<f64> = (0..base.triangles().len())
        .map(|t| {
            if t % 3 == 0 {
                10000.0
            } else {
                1.0 + t as f64 * 0.1
            }
        })
        .collect();
    let mesh = Mesh::new(
        "w",
        base.vertices().to_vec(),
        base.triangles().to_vec(),
        None,
        Some(weights),
    )
    .unwrap();
    let anchors = [
        Anchor::Vertex(0),
        Anchor::Vertex(44),
        point_anchor(&mesh, DVec2::new(4.1, 2.2)),
    ];
    let targets = [
        DVec2::new(0.0, 0.0),
        DVec2::new(6.0, 7.0),
        DVec2::new(2.0, 4.0),
    ];
    assert_agrees_with_reference(&mesh, &anchors, &targets, 1e-9);
}

#[test]
fn rigid_motion_of_handles_moves_the_mesh_rigidly() {
    let mesh = jittered(10, 4);
    let anchors = [
        Anchor::Vertex(3),
        point_anchor(&mesh, DVec2::new(9.2, 3.1)),
        point_anchor(&mesh, DVec2::new(5.5, 1.7)),
    ];
    let angle = 2.3_f64;
    let rotation = DVec2::from_angle(angle);
    let shift = DVec2::new(40.0, -17.0);
    let motion = |p: DVec2| rotation.rotate(p) + shift;
    let arap = Arap::register(&mesh).unwrap();
    let rest_points: Vec<DVec2> = anchors
        .iter()
        .map(|a| match *a {
            Anchor::Vertex(v) => mesh.vertices()[v as usize],
            Anchor::Point { triangle, bary } => mesh.point_at(triangle, bary),
        })
        .collect();
    drop(arap);
    let targets: Vec<DVec2> = rest_points.iter().map(|&p| motion(p)).collect();
    let expected: Vec<DVec2> = mesh.vertices().iter().map(|&p| motion(p)).collect();
    let tol = 1e-9 * mesh.size();
    for steps in [Steps::ScaleFree, Steps::Both] {
        let pose = solve(&mesh, &anchors, &targets, steps);
        assert!(
            max_distance(&pose, &expected) < tol,
            "{steps:?}: off by {}",
            max_distance(&pose, &expected)
        );
    }
}

/// Height of the bar at its middle column.
fn thickness(pose: &[DVec2], cols: usize, rows: usize) -> f64 {
    let mid = cols / 2;
    pose[rows * (cols + 1) + mid].distance(pose[mid])
}

#[test]
fn stretching_keeps_thickness_after_step_two_only() {
    let (cols, rows) = (30, 3);
    let mesh = bar(cols, rows, 30.0, 3.0);
    let anchors = [
        point_anchor(&mesh, DVec2::new(0.0, 1.5)),
        point_anchor(&mesh, DVec2::new(30.0, 1.5)),
    ];
    let targets = [DVec2::new(-7.5, 1.5), DVec2::new(37.5, 1.5)]; // 1.5× longer
    let step1 = solve(&mesh, &anchors, &targets, Steps::ScaleFree);
    let both = solve(&mesh, &anchors, &targets, Steps::Both);
    let rest = thickness(mesh.vertices(), cols, rows);
    let t1 = thickness(&step1, cols, rows);
    let t2 = thickness(&both, cols, rows);
    assert!(t1 > 1.3 * rest, "step 1 should inflate: {t1} vs {rest}");
    assert!(
        (t2 - rest).abs() < 0.05 * rest,
        "step 2 should keep thickness: {t2} vs {rest}"
    );
    // And the handles are where they were asked to be.
    let ends = [
        both[rows / 2 * (cols + 1)],
        both[rows / 2 * (cols + 1) + cols],
    ];
    assert!(ends[1].x - ends[0].x > 40.0);
}

/// How far the left half of a bent bar is from a rigid copy of its rest shape.
fn left_half_distortion(mesh: &Mesh, pose: &[DVec2], cols: usize) -> f64 {
    let rest = mesh.vertices();
    let left: Vec<usize> = (0..rest.len())
        .filter(|&i| i % (cols + 1) <= cols / 2)
        .collect();
    let mut total = 0.0;
    for (k, &i) in left.iter().enumerate() {
        for &j in &left[k + 1..] {
            total += (pose[i].distance(pose[j]) - rest[i].distance(rest[j])).abs();
        }
    }
    total
}

#[test]
fn weights_stiffen_what_they_cover() {
    let (cols, rows) = (20, 2);
    let plain = bar(cols, rows, 20.0, 2.0);
    let stiff_weights: Vec<f64> = plain
        .triangles()
        .iter()
        .map(|t| {
            let c = t
                .iter()
                .map(|&v| plain.vertices()[v as usize].x)
                .sum::<f64>()
                / 3.0;
            if c < 10.0 { 10000.0 } else { 1.0 }
        })
        .collect();
    let stiff = Mesh::new(
        "stiff",
        plain.vertices().to_vec(),
        plain.triangles().to_vec(),
        None,
        Some(stiff_weights),
    )
    .unwrap();
    let anchors = [
        point_anchor(&plain, DVec2::new(0.0, 1.0)),
        point_anchor(&plain, DVec2::new(20.0, 1.0)),
        point_anchor(&plain, DVec2::new(14.0, 1.0)),
    ];
    // Bend the soft right half; the left half holds only one handle, so it
    // can stay rigid if its triangles insist.
    let targets = [
        DVec2::new(0.0, 1.0),
        DVec2::new(20.0, 1.0),
        DVec2::new(14.0, 5.0),
    ];
    let soft_pose = solve(&plain, &anchors, &targets, Steps::Both);
    let stiff_pose = solve(&stiff, &anchors, &targets, Steps::Both);
    let soft = left_half_distortion(&plain, &soft_pose, cols);
    let hard = left_half_distortion(&stiff, &stiff_pose, cols);
    assert!(
        hard < 0.5 * soft,
        "stiff half distorted {hard}, soft {soft}"
    );
}

#[test]
fn point_handle_on_a_vertex_equals_the_vertex_handle() {
    let mesh = jittered(6, 4);
    let v = 17u32;
    let on_vertex = point_anchor(&mesh, mesh.vertices()[v as usize]);
    let other = Anchor::Vertex(0);
    let targets = [DVec2::new(1.0, 9.0), DVec2::new(-3.0, 0.0)];
    let a = solve(&mesh, &[on_vertex, other], &targets, Steps::Both);
    let b = solve(&mesh, &[Anchor::Vertex(v), other], &targets, Steps::Both);
    assert!(max_distance(&a, &b) <= 1e-12 * mesh.size());
}

#[test]
fn pieces_with_zero_or_one_handle_stay_rigid() {
    let mesh = islands(3);
    let pieces = mesh.pieces();
    assert_eq!(pieces.len(), 3);
    let mut arap = Arap::register(&mesh).unwrap();
    // Piece 0: two handles, stretched. Piece 1: one handle. Piece 2: none.
    let p0 = &pieces[0].vertices;
    let p1 = &pieces[1].vertices;
    let anchors = [
        Anchor::Vertex(p0[0]),
        Anchor::Vertex(*p0.last().unwrap()),
        Anchor::Vertex(p1[3]),
    ];
    let shift = DVec2::new(5.0, -2.0);
    let targets = [
        mesh.vertices()[p0[0] as usize] + DVec2::new(0.0, 3.0),
        mesh.vertices()[*p0.last().unwrap() as usize],
        mesh.vertices()[p1[3] as usize] + shift,
    ];
    arap.compile(&anchors).unwrap();
    let pose = arap.update(&targets, Steps::Both).unwrap().to_vec();
    assert!(pose.iter().all(|p| p.is_finite()));
    for &v in p1 {
        let expected = mesh.vertices()[v as usize] + shift;
        assert!(
            pose[v as usize].distance(expected) < 1e-12,
            "one-handle piece translates rigidly"
        );
    }
    for &v in &pieces[2].vertices {
        assert_eq!(
            pose[v as usize],
            mesh.vertices()[v as usize],
            "free piece stays at rest"
        );
    }
    // Lift one handle of piece 0: it becomes a rigid copy of its rest shape
    // in the best-fit rotation of its last pose, carried by the other handle.
    let before: Vec<DVec2> = p0.iter().map(|&v| pose[v as usize]).collect();
    arap.compile(&anchors[1..]).unwrap();
    let moved = [targets[1] + DVec2::new(1.0, 1.0), targets[2]];
    let pose = arap.update(&moved, Steps::Both).unwrap().to_vec();
    let rest = mesh.vertices();
    for &i in p0 {
        for &j in p0 {
            let d_rest = rest[i as usize].distance(rest[j as usize]);
            let d_now = pose[i as usize].distance(pose[j as usize]);
            assert!((d_rest - d_now).abs() < 1e-9, "piece 0 is rigid");
        }
    }
    let handle_vertex = *p0.last().unwrap() as usize;
    assert!(
        pose[handle_vertex].distance(moved[0]) < 1e-12,
        "carried by its handle"
    );
    // Orientation follows the best fit of the deformed pose (it was tilted).
    let now: Vec<DVec2> = p0.iter().map(|&v| pose[v as usize]).collect();
    let tilt = |ps: &[DVec2]| (ps[p0.len() - 1] - ps[0]).to_angle();
    assert!((tilt(&now) - tilt(&before)).abs() < 0.2);
    assert!(
        tilt(&now).abs() > 0.05,
        "rotation kept from the last pose, not reset to rest"
    );
    // No handles at all: everything stays where it was put.
    arap.compile(&[]).unwrap();
    let still = arap.update(&[], Steps::Both).unwrap().to_vec();
    assert!(max_distance(&still, &pose) < 1e-9);
}

#[test]
fn repeated_handle_on_one_point_last_wins() {
    let mesh = jittered(5, 5);
    let anchors = [Anchor::Vertex(7), Anchor::Vertex(30), Anchor::Vertex(7)];
    let targets = [
        DVec2::new(100.0, 100.0),
        DVec2::new(5.0, 5.0),
        DVec2::new(1.0, -1.0),
    ];
    let pose = solve(&mesh, &anchors, &targets, Steps::Both);
    assert!(pose.iter().all(|p| p.is_finite()));
    assert!(pose[7].distance(targets[2]) < 1e-9);
    let expected = solve(&mesh, &anchors[1..], &targets[1..], Steps::Both);
    assert!(max_distance(&pose, &expected) < 1e-9);
}

#[test]
fn recompiling_reuses_handles_and_matches_a_fresh_solver() {
    let mesh = jittered(7, 5);
    let a = [Anchor::Vertex(2), point_anchor(&mesh, DVec2::new(6.2, 4.4))];
    let b = [a[1], point_anchor(&mesh, DVec2::new(3.3, 2.2)), a[0]];
    let targets_b = [
        DVec2::new(8.0, 8.0),
        DVec2::new(3.0, 0.0),
        DVec2::new(-1.0, 0.0),
    ];
    let mut live = Arap::register(&mesh).unwrap();
    live.compile(&a).unwrap();
    live.update(&[DVec2::new(2.0, 0.0), DVec2::new(6.0, 5.0)], Steps::Both)
        .unwrap();
    live.compile(&b).unwrap();
    let incremental = live.update(&targets_b, Steps::Both).unwrap().to_vec();
    let fresh = solve(&mesh, &b, &targets_b, Steps::Both);
    assert!(max_distance(&incremental, &fresh) < 1e-9 * mesh.size());
}

#[test]
fn bad_handles_are_reported() {
    let mesh = jittered(3, 3);
    let mut arap = Arap::register(&mesh).unwrap();
    let n = mesh.vertices().len() as u32;
    assert!(matches!(
        arap.compile(&[Anchor::Vertex(n)]),
        Err(ArapError::VertexOutOfRange { handle: 0, .. })
    ));
    let t = mesh.triangles().len() as u32;
    let bad_triangle = Anchor::Point {
        triangle: t,
        bary: [1.0, 0.0, 0.0],
    };
    assert!(matches!(
        arap.compile(&[Anchor::Vertex(0), bad_triangle]),
        Err(ArapError::TriangleOutOfRange { handle: 1, .. })
    ));
    let bad_bary = Anchor::Point {
        triangle: 0,
        bary: [0.5, 0.5, 0.5],
    };
    assert!(matches!(
        arap.compile(&[bad_bary]),
        Err(ArapError::BadBarycentric { .. })
    ));
    let nan_bary = Anchor::Point {
        triangle: 0,
        bary: [f64::NAN, 0.5, 0.5],
    };
    assert!(matches!(
        arap.compile(&[nan_bary]),
        Err(ArapError::BadBarycentric { .. })
    ));
    arap.compile(&[Anchor::Vertex(0), Anchor::Vertex(5)])
        .unwrap();
    assert!(matches!(
        arap.update(&[DVec2::ZERO], Steps::Both),
        Err(ArapError::Targets(TargetError::Count {
            expected: 2,
            got: 1
        }))
    ));
    let err = arap
        .update(&[DVec2::ZERO, DVec2::new(f64::INFINITY, 0.0)], Steps::Both)
        .unwrap_err();
    assert!(matches!(
        err,
        ArapError::Targets(TargetError::NotFinite { handle: 1 })
    ));
    assert!(err.to_string().contains("handle 1"));
}

#[test]
fn coincident_distinct_anchors_on_one_point_never_give_nan() {
    // The same rest point reached as a vertex and as a point handle.
    let mesh = jittered(4, 4);
    let p = mesh.vertices()[6];
    let tri = mesh
        .triangles()
        .iter()
        .position(|t| t.contains(&6))
        .unwrap() as u32;
    let corner = mesh.triangles()[tri as usize]
        .iter()
        .position(|&v| v == 6)
        .unwrap();
    let mut bary = [0.0; 3];
    bary[corner] = 1.0;
    let anchors = [
        Anchor::Point {
            triangle: tri,
            bary,
        },
        Anchor::Vertex(6),
        Anchor::Vertex(0),
    ];
    let targets = [p, p + DVec2::new(1.0, 0.0), DVec2::ZERO];
    let pose = solve(&mesh, &anchors, &targets, Steps::Both);
    assert!(pose.iter().all(|q| q.is_finite()));
    assert!(pose[6].distance(targets[1]) < 1e-9);
}

#[test]
fn thin_triangles_at_the_limit_still_solve_accurately() {
    // A bar whose bottom row of cells is squashed to the thinnest triangles
    // a mesh may hold, with the paper's stiff weight on every other one.
    let (cols, rows) = (12, 2);
    let (mut v, t) = grid(cols, rows, 12.0, 2.0, DVec2::ZERO);
    for vertex in v.iter_mut().take(cols + 1) {
        vertex.y = 1.0 - 1.2 * MIN_THICKNESS;
    }
    let weights: Vec<f64> = (0..t.len())
        .map(|i| if i % 2 == 0 { 1e4 } else { 1.0 })
        .collect();
    let mesh = Mesh::new("thin", v.clone(), t.clone(), None, Some(weights)).unwrap();
    let anchors = [
        Anchor::Vertex(0),
        Anchor::Vertex((rows * (cols + 1) + cols) as u32),
    ];
    let targets = [DVec2::new(-1.0, 0.0), DVec2::new(14.0, 5.0)];
    // Cholesky of the energies' matrices loses digits with the square of a
    // triangle's thinness and with the weights' contrast: 1e-8 here, 1e-9 on
    // ordinary meshes.
    assert_agrees_with_reference(&mesh, &anchors, &targets, 1e-8);
    // Thinner than the limit is refused, naming the triangle.
    let mut thinner = v;
    for vertex in thinner.iter_mut().take(cols + 1) {
        vertex.y = 1.0 - 0.5 * MIN_THICKNESS;
    }
    let err = Mesh::new("thinner", thinner, t, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("triangles[0]") && err.contains("too thin"),
        "{err}"
    );
}

#[test]
fn extreme_weights_within_limits_still_solve() {
    let base = jittered(8, 4);
    let count = base.triangles().len();
    let weights: Vec<f64> = (0..count)
        .map(|i| if i % 2 == 0 { MAX_WEIGHT } else { MIN_WEIGHT })
        .collect();
    let mesh = Mesh::new(
        "w",
        base.vertices().to_vec(),
        base.triangles().to_vec(),
        None,
        Some(weights),
    )
    .unwrap();
    let anchors = [Anchor::Vertex(0), Anchor::Vertex(44)];
    let targets = [DVec2::new(-1.0, 0.0), DVec2::new(10.0, 6.0)];
    let (_, ref2) = dense_reference(&mesh, &anchors, &targets);
    let both = solve(&mesh, &anchors, &targets, Steps::Both);
    // Precision falls with the weights' contrast (1e7 here): 1e-7, not 1e-9.
    let off = max_distance(&both, &ref2);
    assert!(off < 1e-7 * mesh.size(), "off by {off}");
    let outside = |w: f64| {
        let mut ws = vec![1.0; count];
        ws[3] = w;
        Mesh::new(
            "w",
            base.vertices().to_vec(),
            base.triangles().to_vec(),
            None,
            Some(ws),
        )
        .unwrap_err()
        .to_string()
    };
    assert!(outside(MIN_WEIGHT / 10.0).contains("weights[3]"));
    assert!(outside(MAX_WEIGHT * 10.0).contains("weights[3]"));
}

#[test]
fn any_sequence_of_handle_sets_matches_fresh_solvers() {
    // Fingers land and lift in every pattern: growing, shrinking, reordered,
    // down to one and back; each solved result equals a solver compiled from
    // scratch for the same set. (With one handle the piece keeps its last
    // pose by design, so that round is not compared.)
    let mesh = jittered(9, 6);
    let pool: Vec<Anchor> = (0..8)
        .map(|i| {
            let p = DVec2::new(0.4 + i as f64 * 1.1, 0.3 + (i as f64 * 1.7) % 5.4);
            point_anchor(&mesh, p)
        })
        .collect();
    let sets: &[&[usize]] = &[
        &[0, 1],
        &[0, 1, 2],
        &[2, 0, 1, 3],
        &[3, 1],
        &[1, 3, 4, 5, 6],
        &[6, 5],
        &[5],
        &[4, 5, 0],
        &[6, 5, 7, 0],
    ];
    let mut live = Arap::register(&mesh).unwrap();
    for (round, set) in sets.iter().enumerate() {
        let anchors: Vec<Anchor> = set.iter().map(|&i| pool[i]).collect();
        let targets: Vec<DVec2> = set
            .iter()
            .map(|&i| DVec2::new(i as f64 * 1.3 - round as f64, (i * round) as f64 * 0.4))
            .collect();
        live.compile(&anchors).unwrap();
        let incremental = live.update(&targets, Steps::Both).unwrap().to_vec();
        if set.len() < 2 {
            continue;
        }
        let fresh = solve(&mesh, &anchors, &targets, Steps::Both);
        let off = max_distance(&incremental, &fresh);
        assert!(off < 1e-9 * mesh.size(), "round {round}: off by {off}");
    }
}
