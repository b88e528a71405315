//! As-rigid-as-possible curve editing against its specification: rigid
//! motions are reproduced exactly, scale adjustment keeps segment lengths
//! where the Laplacian step alone stretches them, both steps agree with a
//! dense least-squares reference, peeling grows and stops at pushpins, bad
//! rest curves and handles are reported by index, updates do not allocate.

use glam::DVec2;
use puppetry_deform::curve::{resample_evenly, validate};
use puppetry_deform::targets::TargetError;
use puppetry_deform::{Curve, CurveAnchor, CurveError, Peel, PeelParams, Steps};
use puppetry_testkit::alloc;

/// A wavy open curve: `n` points along a sine, so neighbours' frames differ.
fn wave(n: usize, amplitude: f64) -> Vec<DVec2> {
    (0..n)
        .map(|i| {
            let x = i as f64;
            DVec2::new(x, amplitude * (x * 0.35).sin() + 0.01 * x * x)
        })
        .collect()
}

fn line(n: usize) -> Vec<DVec2> {
    (0..n).map(|i| DVec2::new(i as f64, 0.0)).collect()
}

fn solve(points: &[DVec2], anchors: &[CurveAnchor], targets: &[DVec2], steps: Steps) -> Vec<DVec2> {
    let mut curve = Curve::register(points).unwrap();
    curve.compile(anchors).unwrap();
    curve.update(targets, steps).unwrap().to_vec()
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

/// Largest relative change of a segment's length.
fn worst_stretch(rest: &[DVec2], pose: &[DVec2]) -> f64 {
    rest.windows(2)
        .zip(pose.windows(2))
        .map(|(r, p)| (p[0].distance(p[1]) / r[0].distance(r[1]) - 1.0).abs())
        .fold(0.0, f64::max)
}

fn anchor_rows(anchor: CurveAnchor) -> ([usize; 2], [f64; 2]) {
    match anchor {
        CurveAnchor::Point(p) => ([p as usize; 2], [1.0, 0.0]),
        CurveAnchor::Along { segment, t } => {
            ([segment as usize, segment as usize + 1], [1.0 - t, t])
        }
    }
}

/// Dense Gaussian elimination with partial pivoting.
fn dense_solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Vec<f64> {
    let n = b.len();
    for j in 0..n {
        let p = (j..n)
            .max_by(|&x, &y| a[x][j].abs().total_cmp(&a[y][j].abs()))
            .unwrap();
        a.swap(j, p);
        b.swap(j, p);
        assert!(a[j][j].abs() > 1e-14, "reference system is singular");
        let (above, below) = a.split_at_mut(j + 1);
        let pivot_row = &above[j];
        for (k, row) in below.iter_mut().enumerate() {
            let f = row[j] / pivot_row[j];
            if f != 0.0 {
                for (x, y) in row[j..].iter_mut().zip(&pivot_row[j..]) {
                    *x -= f * y;
                }
                b[j + 1 + k] -= f * b[j];
            }
        }
    }
    let mut x = vec![0.0; n];
    for j in (0..n).rev() {
        let s: f64 = (j + 1..n).map(|c| a[j][c] * x[c]).sum();
        x[j] = (b[j] - s) / a[j][j];
    }
    x
}

/// Minimises `Σ |J v − r|²` (rows of J over the 2n real coordinates) subject
/// to the constraints `C v = q`, by the dense KKT system of the normal
/// equations.
fn constrained_least_squares(
    n: usize,
    rows: &[(Vec<(usize, f64)>, f64)],
    constraints: &[(Vec<(usize, f64)>, f64)],
) -> Vec<DVec2> {
    let size = 2 * n + constraints.len();
    let mut a = vec![vec![0.0; size]; size];
    let mut b = vec![0.0; size];
    for (row, r) in rows {
        for &(i, x) in row {
            for &(j, y) in row {
                a[i][j] += x * y;
            }
            b[i] += x * r;
        }
    }
    for (k, (row, q)) in constraints.iter().enumerate() {
        for &(i, w) in row {
            a[2 * n + k][i] += w;
            a[i][2 * n + k] += w;
        }
        b[2 * n + k] = *q;
    }
    let x = dense_solve(a, b);
    (0..n).map(|i| DVec2::new(x[2 * i], x[2 * i + 1])).collect()
}

/// The two energies written out independently of the solver: step 1 with
/// real local coordinates `(x, y)` and `R(a, b) = (b, −a)`, step 2 from the
/// reference's own step 1. Points in `fixed` are held where `pose` has them.
fn dense_reference(
    rest: &[DVec2],
    anchors: &[CurveAnchor],
    targets: &[DVec2],
    fixed: &[usize],
    pose: &[DVec2],
) -> (Vec<DVec2>, Vec<DVec2>) {
    let n = rest.len();
    let rot = |d: DVec2| DVec2::new(d.y, -d.x);
    let mut constraints = Vec::new();
    for (anchor, q) in anchors.iter().zip(targets) {
        let (points, weights) = anchor_rows(*anchor);
        for axis in 0..2 {
            let row = points
                .iter()
                .zip(weights)
                .map(|(&p, w)| (2 * p + axis, w))
                .collect();
            constraints.push((row, q[axis]));
        }
    }
    for &p in fixed {
        for (axis, value) in pose[p].to_array().into_iter().enumerate() {
            constraints.push((vec![(2 * p + axis, 1.0)], value));
        }
    }
    let mut rows1 = Vec::new();
    for i in 1..n - 1 {
        let d = rest[i + 1] - rest[i - 1];
        let e = rest[i] - rest[i - 1];
        // Solve e = x d + y R d for (x, y).
        let (rd, det) = (rot(d), d.x * rot(d).y - rot(d).x * d.y);
        let x = (e.x * rd.y - rd.x * e.y) / det;
        let y = (d.x * e.y - e.x * d.y) / det;
        // Residual v_i − v_{i−1} − x (v_{i+1} − v_{i−1}) − y R(v_{i+1} − v_{i−1}).
        // R(a, b) = (b, −a): its x-row takes +y of the difference, its
        // y-row −x.
        let mut rx = Vec::new();
        let mut ry = Vec::new();
        rx.push((2 * i, 1.0));
        ry.push((2 * i + 1, 1.0));
        for (p, sign) in [(i + 1, 1.0), (i - 1, -1.0)] {
            rx.push((2 * p, -x * sign));
            ry.push((2 * p + 1, -x * sign));
            rx.push((2 * p + 1, -y * sign));
            ry.push((2 * p, y * sign));
        }
        rx.push((2 * (i - 1), -1.0));
        ry.push((2 * (i - 1) + 1, -1.0));
        rows1.push((rx, 0.0));
        rows1.push((ry, 0.0));
    }
    let step1 = constrained_least_squares(n, &rows1, &constraints);
    let mut rows2 = Vec::new();
    for s in 0..n - 1 {
        let d = step1[s + 1] - step1[s];
        let f = d * (rest[s].distance(rest[s + 1]) / d.length());
        for axis in 0..2 {
            rows2.push((
                vec![(2 * (s + 1) + axis, 1.0), (2 * s + axis, -1.0)],
                f[axis],
            ));
        }
    }
    let step2 = constrained_least_squares(n, &rows2, &constraints);
    (step1, step2)
}

#[test]
fn rigid_motion_of_the_handles_moves_the_curve_rigidly() {
    let rest = wave(60, 4.0);
    let anchors = [
        CurveAnchor::Point(0),
        CurveAnchor::Along {
            segment: 30,
            t: 0.25,
        },
        CurveAnchor::Point(59),
    ];
    let rotation = DVec2::from_angle(1.1);
    let shift = DVec2::new(-40.0, 17.5);
    let moved = |p: DVec2| rotation.rotate(p) + shift;
    let curve = Curve::register(&rest).unwrap();
    let targets: Vec<DVec2> = anchors
        .iter()
        .map(|a| moved(curve.rest_point(*a).unwrap()))
        .collect();
    let expected: Vec<DVec2> = rest.iter().map(|p| moved(*p)).collect();
    for steps in [Steps::ScaleFree, Steps::Both] {
        let pose = solve(&rest, &anchors, &targets, steps);
        let off = max_distance(&pose, &expected);
        assert!(off < 1e-9, "{steps:?}: off by {off}");
    }
}

#[test]
fn scale_adjustment_keeps_segment_lengths_where_step_one_stretches() {
    // The paper's Figure 11: held at its ends and middle, an arc is bent the
    // other way. Step 1 keeps each point's frame and so grows the stretched
    // part; step 2 restores the lengths.
    let (rest, anchors, targets) = puppetry_testkit::curve_bend();
    let step1 = solve(&rest, &anchors, &targets, Steps::ScaleFree);
    let both = solve(&rest, &anchors, &targets, Steps::Both);
    let (stretch1, stretch2) = (worst_stretch(&rest, &step1), worst_stretch(&rest, &both));
    println!(
        "bend: worst segment length change, step 1 only {:.1}%, both steps {:.2}%",
        stretch1 * 100.0,
        stretch2 * 100.0
    );
    assert!(stretch1 > 0.10, "step 1 stretched only {stretch1}");
    assert!(stretch2 < 0.01, "scale adjustment left {stretch2}");
}

#[test]
fn both_steps_agree_with_a_dense_reference() {
    let rest = wave(40, 3.0);
    let anchors = [
        CurveAnchor::Point(2),
        CurveAnchor::Along {
            segment: 17,
            t: 0.6,
        },
        CurveAnchor::Point(33),
    ];
    let targets = [
        DVec2::new(1.0, 4.0),
        DVec2::new(20.0, 14.0),
        DVec2::new(30.0, -3.0),
    ];
    let (ref1, ref2) = dense_reference(&rest, &anchors, &targets, &[], &rest);
    let step1 = solve(&rest, &anchors, &targets, Steps::ScaleFree);
    let both = solve(&rest, &anchors, &targets, Steps::Both);
    let (off1, off2) = (max_distance(&step1, &ref1), max_distance(&both, &ref2));
    println!("dense reference: step 1 off by {off1:e}, both steps by {off2:e}");
    assert!(off1 < 1e-9, "step 1 off by {off1}");
    assert!(off2 < 1e-9, "step 2 off by {off2}");
}

#[test]
fn a_free_interval_agrees_with_a_dense_reference_holding_the_rest() {
    let rest = wave(40, 3.0);
    let mut curve = Curve::register(&rest).unwrap();
    // A first pose to hold the fixed points somewhere other than rest.
    curve
        .compile(&[CurveAnchor::Point(0), CurveAnchor::Point(39)])
        .unwrap();
    curve
        .update(&[DVec2::new(2.0, 1.0), DVec2::new(35.0, 6.0)], Steps::Both)
        .unwrap();
    let pose = curve.pose().to_vec();
    let anchors = [CurveAnchor::Along {
        segment: 20,
        t: 0.3,
    }];
    let targets = [curve.pose_point(anchors[0]).unwrap() + DVec2::new(1.0, 5.0)];
    let free = 12..=27;
    let fixed: Vec<usize> = (0..40).filter(|p| !free.contains(p)).collect();
    let (ref1, ref2) = dense_reference(&rest, &anchors, &targets, &fixed, &pose);
    for (steps, reference) in [(Steps::ScaleFree, &ref1), (Steps::Both, &ref2)] {
        curve.compile_within(&anchors, free.clone()).unwrap();
        let out = curve.update(&targets, steps).unwrap();
        let off = max_distance(out, reference);
        assert!(off < 1e-9, "{steps:?} off by {off}");
        for &p in &fixed {
            assert_eq!(out[p], pose[p], "fixed point {p} moved");
        }
    }
}

#[test]
fn point_handle_equals_along_handle_at_a_segment_end() {
    let rest = wave(30, 2.0);
    let targets = [DVec2::new(-1.0, 0.0), DVec2::new(12.0, 9.0)];
    let a = solve(
        &rest,
        &[CurveAnchor::Point(0), CurveAnchor::Point(14)],
        &targets,
        Steps::Both,
    );
    let b = solve(
        &rest,
        &[
            CurveAnchor::Point(0),
            CurveAnchor::Along {
                segment: 13,
                t: 1.0,
            },
        ],
        &targets,
        Steps::Both,
    );
    assert!(max_distance(&a, &b) < 1e-9);
}

#[test]
fn fewer_than_two_handles_move_the_curve_rigidly() {
    let rest = wave(20, 2.0);
    let mut curve = Curve::register(&rest).unwrap();
    curve.compile(&[CurveAnchor::Point(5)]).unwrap();
    let to = DVec2::new(100.0, -3.0);
    let pose = curve.update(&[to], Steps::Both).unwrap().to_vec();
    let shift = to - rest[5];
    assert!(max_distance(&pose, &rest.iter().map(|p| *p + shift).collect::<Vec<_>>()) < 1e-12);
    curve.compile(&[]).unwrap();
    let still = curve.update(&[], Steps::Both).unwrap();
    assert!(max_distance(still, &pose) < 1e-9);
}

#[test]
fn peeled_region_grows_with_the_drag_and_never_shrinks() {
    let rest = line(200);
    let curve = Curve::register(&rest).unwrap();
    let params = PeelParams {
        initial_radius: 2.0,
        growth_rate: 1.5,
    };
    let mut peel = Peel::new(&curve, 100.5, &[], params).unwrap();
    assert_eq!(peel.region(), (98.5, 102.5));
    assert_eq!(peel.free_points(), 99..=102);
    let mut widths = Vec::new();
    for d in [0.0, 1.0, 5.0, 3.0, 10.0, 2.0, 40.0, 100.0] {
        peel.drag(&curve, d).unwrap();
        let (lo, hi) = peel.region();
        widths.push(hi - lo);
    }
    println!("peeled region widths: {widths:?}");
    assert!(widths.windows(2).all(|w| w[1] >= w[0]), "{widths:?}");
    assert_eq!(widths[3], widths[2], "a shorter drag does not shrink it");
    // At 100 the region covers the whole curve, ends included.
    assert_eq!(peel.region(), (0.0, 199.0));
    assert_eq!(peel.free_points(), 0..=199);
}

#[test]
fn peeled_region_stops_at_pushpins() {
    let rest = line(200);
    let curve = Curve::register(&rest).unwrap();
    let params = PeelParams {
        initial_radius: 0.0,
        growth_rate: 2.0,
    };
    let mut peel = Peel::new(&curve, 100.0, &[150.0, 60.5, 20.0, 170.0], params).unwrap();
    assert_eq!(
        peel.grab_anchor(),
        CurveAnchor::Along {
            segment: 100,
            t: 0.0
        }
    );
    assert!(peel.drag(&curve, 10.0).unwrap());
    assert_eq!(peel.region(), (80.0, 120.0));
    assert_eq!(peel.free_points(), 81..=119);
    peel.drag(&curve, 1000.0).unwrap();
    assert_eq!(peel.region(), (60.5, 150.0));
    // Point 150 is the pushpin: it stays.
    assert_eq!(peel.free_points(), 61..=149);
}

#[test]
fn peeling_drag_moves_only_the_region() {
    let rest = wave(120, 3.0);
    let mut curve = Curve::register(&rest).unwrap();
    let params = PeelParams {
        initial_radius: 3.0,
        growth_rate: 1.0,
    };
    let grab = curve.length() * 0.5;
    let mut peel = Peel::new(&curve, grab, &[grab + 20.0], params).unwrap();
    let anchors = [peel.grab_anchor()];
    let start = curve.pose_point(anchors[0]).unwrap();
    curve.compile_within(&anchors, peel.free_points()).unwrap();
    let mut recompiles = 0;
    for frame in 1..=40 {
        let target = start + DVec2::new(0.0, frame as f64 * 0.5);
        if peel.drag(&curve, target.distance(start)).unwrap() {
            curve.compile_within(&anchors, peel.free_points()).unwrap();
            recompiles += 1;
        }
        curve.update(&[target], Steps::Both).unwrap();
        let held = curve.pose_point(anchors[0]).unwrap();
        assert!(held.distance(target) < 1e-9, "the grab follows the drag");
    }
    assert!(recompiles > 3, "the region grew {recompiles} times");
    let free = peel.free_points();
    for (p, (now, was)) in curve.pose().iter().zip(&rest).enumerate() {
        if !free.contains(&p) {
            assert_eq!(now, was, "point {p} outside the region moved");
        }
    }
    // The pushpin's side stays put beyond it.
    let pin_point = curve.arc_lengths().partition_point(|&a| a < grab + 20.0);
    assert!(*free.end() < pin_point);
}

#[test]
fn bad_rest_curves_name_the_offending_points() {
    let ok = wave(10, 2.0);
    assert_eq!(
        Curve::register(&ok[..2]).unwrap_err(),
        CurveError::TooFewPoints { count: 2 }
    );
    let mut nan = ok.clone();
    nan[4].y = f64::NAN;
    assert_eq!(
        Curve::register(&nan).unwrap_err(),
        CurveError::PointNotFinite { point: 4 }
    );
    let mut repeated = ok.clone();
    repeated[6] = repeated[5];
    assert_eq!(
        Curve::register(&repeated).unwrap_err(),
        CurveError::RepeatedPoint {
            point: 6,
            previous: 5
        }
    );
    let folded = [
        DVec2::ZERO,
        DVec2::new(2.0, 0.0),
        DVec2::new(1.0, 0.0),
        DVec2::new(1.0, 5.0),
    ];
    assert_eq!(
        Curve::register(&folded).unwrap_err(),
        CurveError::FoldsBack { point: 1 }
    );
    // Segment 2 comes back across segment 0.
    let crossing = [
        DVec2::new(0.0, 0.0),
        DVec2::new(2.0, 0.0),
        DVec2::new(2.0, 2.0),
        DVec2::new(1.0, -1.0),
        DVec2::new(0.0, -2.0),
    ];
    assert_eq!(
        Curve::register(&crossing).unwrap_err(),
        CurveError::SelfIntersection {
            first: 0,
            second: 2
        }
    );
    // A curve that comes back to touch itself.
    let mut touching = line(8);
    touching.extend([
        DVec2::new(7.0, 3.0),
        DVec2::new(3.0, 3.0),
        DVec2::new(3.0, 0.0),
    ]);
    assert_eq!(
        Curve::register(&touching).unwrap_err(),
        CurveError::SelfIntersection {
            first: 2,
            second: 9
        }
    );
    let message = CurveError::SelfIntersection {
        first: 2,
        second: 9,
    }
    .to_string();
    assert!(message.contains("segments 2 and 9"), "{message}");
}

#[test]
fn bad_handles_and_targets_are_reported() {
    let rest = wave(10, 2.0);
    let mut curve = Curve::register(&rest).unwrap();
    assert_eq!(
        curve.compile(&[CurveAnchor::Point(3), CurveAnchor::Point(10)]),
        Err(CurveError::PointOutOfRange {
            handle: 1,
            point: 10,
            count: 10
        })
    );
    assert_eq!(
        curve.compile(&[CurveAnchor::Along { segment: 9, t: 0.5 }]),
        Err(CurveError::SegmentOutOfRange {
            handle: 0,
            segment: 9,
            count: 9
        })
    );
    assert!(matches!(
        curve.compile(&[CurveAnchor::Along {
            segment: 2,
            t: f64::NAN
        }]),
        Err(CurveError::BadParameter { handle: 0, .. })
    ));
    assert_eq!(
        curve.compile_within(&[CurveAnchor::Point(1)], 3..=6),
        Err(CurveError::HandleFixed {
            handle: 0,
            start: 3,
            end: 6
        })
    );
    curve
        .compile(&[CurveAnchor::Point(0), CurveAnchor::Point(9)])
        .unwrap();
    assert_eq!(
        curve.update(&[DVec2::ZERO], Steps::Both).unwrap_err(),
        CurveError::Targets(TargetError::Count {
            expected: 2,
            got: 1
        })
    );
    assert_eq!(
        curve
            .update(&[DVec2::ZERO, DVec2::new(f64::INFINITY, 0.0)], Steps::Both)
            .unwrap_err(),
        CurveError::Targets(TargetError::NotFinite { handle: 1 })
    );
    assert_eq!(
        Peel::new(&curve, 3.0, &[3.0], PeelParams::default()).unwrap_err(),
        CurveError::PushpinAtGrab { pushpin: 0 }
    );
}

#[test]
fn self_intersection_check_is_fast_on_ten_thousand_points() {
    // A spiral: many segments near each other, none crossing.
    let points: Vec<DVec2> = (0..10_000)
        .map(|i| {
            let a = i as f64 * 0.05;
            DVec2::from_angle(a) * (10.0 + a * 2.0)
        })
        .collect();
    let start = std::time::Instant::now();
    validate(&points).unwrap();
    println!("validated 10k points in {:?}", start.elapsed());
    let mut crossing = points.clone();
    crossing.push(DVec2::ZERO.lerp(points[5000], 2.0));
    crossing.push(DVec2::ZERO);
    assert!(matches!(
        validate(&crossing),
        Err(CurveError::SelfIntersection { .. })
    ));
}

#[test]
fn resampling_spaces_points_evenly_and_keeps_the_ends() {
    let points = [
        DVec2::ZERO,
        DVec2::new(10.0, 0.0),
        DVec2::new(10.0, 0.5),
        DVec2::new(10.0, 7.0),
    ];
    let out = resample_evenly(&points, 1.0).unwrap();
    assert_eq!(out.len(), 18);
    assert_eq!(out[0], points[0]);
    assert_eq!(*out.last().unwrap(), points[3]);
    let lengths: Vec<f64> = out.windows(2).map(|w| w[0].distance(w[1])).collect();
    // Along the polyline each step is 1; across the corner the chord is
    // shorter.
    assert!(
        lengths.iter().all(|&l| l <= 1.0 + 1e-12 && l > 0.7),
        "{lengths:?}"
    );
    assert_eq!(
        resample_evenly(&points, 0.0),
        Err(CurveError::BadSpacing { spacing: 0.0 })
    );
    assert_eq!(
        resample_evenly(&[DVec2::ZERO, DVec2::new(f64::NAN, 1.0)], 1.0),
        Err(CurveError::PointNotFinite { point: 1 })
    );
}

#[test]
fn updates_do_not_allocate() {
    let rest = wave(500, 3.0);
    let mut curve = Curve::register(&rest).unwrap();
    let anchors = [
        CurveAnchor::Point(0),
        CurveAnchor::Along {
            segment: 250,
            t: 0.5,
        },
        CurveAnchor::Point(499),
    ];
    let mut targets: Vec<DVec2> = anchors
        .iter()
        .map(|a| curve.rest_point(*a).unwrap())
        .collect();
    curve.compile(&anchors).unwrap();
    let mut peel = Peel::new(&curve, 100.0, &[150.0], PeelParams::default()).unwrap();
    alloc::start();
    for frame in 0..50 {
        targets[1].y += 0.3;
        targets[2].x -= 0.1;
        let steps = if frame % 2 == 0 {
            Steps::Both
        } else {
            Steps::ScaleFree
        };
        curve.update(&targets, steps).unwrap();
        peel.drag(&curve, frame as f64).unwrap();
    }
    assert_eq!(alloc::stop(), 0, "update or drag allocated");
    // A free interval (split at its handle into two arms and a joint),
    // grown once.
    curve.compile_within(&anchors[1..2], 200..=300).unwrap();
    curve.compile_within(&anchors[1..2], 180..=330).unwrap();
    alloc::start();
    for _ in 0..20 {
        targets[1].y += 0.3;
        curve.update(&targets[1..2], Steps::Both).unwrap();
    }
    assert_eq!(alloc::stop(), 0, "a free interval's update allocated");
    alloc::start();
    curve.compile(&anchors[..2]).unwrap();
    assert!(alloc::stop() > 0, "the counter counts");
}
