//! The spatial-keyframing weights against their specification: exact
//! interpolation at the keys, partition of unity, one key, bounded far field,
//! Lipschitz continuity under a dense sweep, invariance under similarities,
//! bad key points, and no allocation per frame.

use glam::DVec2;
use puppetry_deform::rbf::{MIN_RELATIVE_SEPARATION, RbfBlend, RbfError};
use puppetry_testkit::alloc;

/// A small deterministic generator (xorshift64*), so the point sets are the
/// same on every run.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` points scattered over the unit square, none closer than `gap`.
fn scattered(count: usize, gap: f64, seed: u64) -> Vec<DVec2> {
    let mut rng = Rng(seed);
    let mut points: Vec<DVec2> = Vec::new();
    while points.len() < count {
        let p = DVec2::new(rng.unit(), rng.unit());
        if points.iter().all(|q| q.distance(p) >= gap) {
            points.push(p);
        }
    }
    points
}

/// Point sets of different shapes and sizes, on and off the unit scale.
fn point_sets() -> Vec<(&'static str, Vec<DVec2>)> {
    let grid: Vec<DVec2> = (0..25)
        .map(|i| DVec2::new((i % 5) as f64 / 4.0, (i / 5) as f64 / 4.0))
        .collect();
    vec![
        ("one", vec![DVec2::new(0.3, 0.7)]),
        ("two", vec![DVec2::new(0.2, 0.5), DVec2::new(0.8, 0.5)]),
        // Pairwise one unit apart: where r² log r with a constant term is singular.
        (
            "unit triangle",
            vec![DVec2::ZERO, DVec2::X, DVec2::new(0.5, 3f64.sqrt() / 2.0)],
        ),
        (
            "collinear",
            (0..6).map(|i| DVec2::new(i as f64 * 0.17, 0.4)).collect(),
        ),
        ("grid 5×5", grid),
        ("scattered 12", scattered(12, 0.08, 7)),
        ("scattered 60", scattered(60, 0.03, 11)),
        (
            "far and large",
            scattered(10, 0.1, 3)
                .into_iter()
                .map(|p| p * 250.0 + DVec2::new(1e4, -3e3))
                .collect(),
        ),
    ]
}

fn weights(blend: &RbfBlend, cursor: DVec2) -> Vec<f64> {
    let mut out = vec![0.0; blend.len()];
    blend.weights_into(cursor, &mut out);
    out
}

/// Cursor positions over the points' bounding box widened by half its size
/// on each side, `steps + 1` per side, row by row.
fn sweep(points: &[DVec2], steps: usize) -> (Vec<DVec2>, f64) {
    let lo = points.iter().fold(DVec2::INFINITY, |a, &p| a.min(p));
    let hi = points.iter().fold(DVec2::NEG_INFINITY, |a, &p| a.max(p));
    let size = (hi - lo).max_element().max(1.0);
    let origin = (lo + hi) / 2.0 - DVec2::splat(size);
    let step = 2.0 * size / steps as f64;
    let cursors = (0..=steps)
        .flat_map(|row| {
            (0..=steps).map(move |col| origin + DVec2::new(col as f64, row as f64) * step)
        })
        .collect();
    (cursors, step)
}

#[test]
fn weights_at_each_key_are_kronecker_deltas() {
    for (name, points) in point_sets() {
        let blend = RbfBlend::new(&points).unwrap();
        for (j, &p) in points.iter().enumerate() {
            // Exactly on the key: exactly δ.
            let delta: Vec<f64> = (0..points.len()).map(|k| (k == j) as u8 as f64).collect();
            assert_eq!(weights(&blend, p), delta, "{name}: key {j}");
            // A rounding error away from it (so the weights come from the
            // inverse): δ to 1e-12, beyond what the offset itself explains.
            let offset = DVec2::new(1e-15, -1e-15) * p.abs().max_element().max(1.0);
            assert_ne!(p + offset, p);
            for (k, w) in weights(&blend, p + offset).into_iter().enumerate() {
                let slack = 1e-12 + blend.lipschitz()[k] * offset.length();
                assert!(
                    (w - delta[k]).abs() < slack,
                    "{name}: w_{k}(x_{j}) = {w}, expected {}",
                    delta[k]
                );
            }
        }
    }
}

#[test]
fn weights_sum_to_one_everywhere() {
    for (name, points) in point_sets() {
        let blend = RbfBlend::new(&points).unwrap();
        let (cursors, _) = sweep(&points, 40);
        for cursor in cursors {
            let sum: f64 = weights(&blend, cursor).iter().sum();
            assert!((sum - 1.0).abs() < 1e-10, "{name}: Σw({cursor}) = {sum}");
        }
    }
}

#[test]
fn one_key_has_weight_one_everywhere() {
    let blend = RbfBlend::new(&[DVec2::new(-4.0, 9.0)]).unwrap();
    assert_eq!(blend.len(), 1);
    for cursor in [
        DVec2::new(-4.0, 9.0),
        DVec2::ZERO,
        DVec2::new(1e6, -1e6),
        DVec2::new(0.25, 0.75),
    ] {
        assert_eq!(weights(&blend, cursor), vec![1.0], "at {cursor}");
    }
    assert_eq!(blend.lipschitz(), &[0.0]);
}

#[test]
fn weights_stay_bounded_far_from_the_keys() {
    let points = scattered(12, 0.08, 5);
    let blend = RbfBlend::new(&points).unwrap();
    let (cursors, _) = sweep(&points, 40);
    let near = cursors
        .iter()
        .flat_map(|&c| weights(&blend, c))
        .fold(0.0f64, |m, w| m.max(w.abs()));
    for angle in (0..16).map(|i| i as f64 * std::f64::consts::TAU / 16.0) {
        let direction = DVec2::from_angle(angle);
        let at_1e3 = weights(&blend, DVec2::splat(0.5) + direction * 1e3);
        let at_1e6 = weights(&blend, DVec2::splat(0.5) + direction * 1e6);
        for k in 0..points.len() {
            // The weights tend to a limit per direction (the linear growth of
            // the distances cancels), of the order of the weights near the keys.
            assert!(
                at_1e6[k].abs() < 10.0 * near,
                "w_{k} = {} far out",
                at_1e6[k]
            );
            assert!(
                (at_1e6[k] - at_1e3[k]).abs() < 1e-2 * near,
                "w_{k} still moving far out: {} then {}",
                at_1e3[k],
                at_1e6[k]
            );
        }
    }
}

/// The largest change of any weight between horizontally or vertically
/// neighbouring sweep positions, after checking each change against the
/// weights' Lipschitz bound.
fn max_jump(blend: &RbfBlend, points: &[DVec2], steps: usize) -> f64 {
    let (cursors, step) = sweep(points, steps);
    let side = steps + 1;
    let all: Vec<Vec<f64>> = cursors.iter().map(|&c| weights(blend, c)).collect();
    let mut largest = 0.0f64;
    for row in 0..side {
        for col in 0..side {
            let here = row * side + col;
            let neighbours = [
                (col + 1 < side).then_some(here + 1),
                (row + 1 < side).then_some(here + side),
            ];
            for there in neighbours.into_iter().flatten() {
                for (k, (a, b)) in all[here].iter().zip(&all[there]).enumerate() {
                    let jump = (a - b).abs();
                    let bound = blend.lipschitz()[k] * step * (1.0 + 1e-9) + 1e-12;
                    assert!(
                        jump <= bound,
                        "w_{k} jumps {jump} between {} and {} (bound {bound})",
                        cursors[here],
                        cursors[there]
                    );
                    largest = largest.max(jump);
                }
            }
        }
    }
    largest
}

#[test]
fn a_dense_sweep_is_lipschitz_continuous() {
    for (name, points) in point_sets() {
        if points.len() < 2 {
            continue;
        }
        let blend = RbfBlend::new(&points).unwrap();
        let coarse = max_jump(&blend, &points, 100);
        let fine = max_jump(&blend, &points, 200);
        let finer = max_jump(&blend, &points, 400);
        assert!(coarse > 0.0, "{name}: the weights never moved");
        // Halving the step about halves the largest jump: no hidden jumps.
        assert!(fine < 0.6 * coarse, "{name}: {coarse} then {fine}");
        assert!(finer < 0.6 * fine, "{name}: {fine} then {finer}");
    }
}

#[test]
fn weights_are_invariant_under_similarities() {
    let points = scattered(15, 0.06, 13);
    let blend = RbfBlend::new(&points).unwrap();
    let rotation = DVec2::from_angle(0.7);
    let map = |p: DVec2| rotation.rotate(p) * 37.5 + DVec2::new(-120.0, 44.0);
    let moved: Vec<DVec2> = points.iter().map(|&p| map(p)).collect();
    let moved_blend = RbfBlend::new(&moved).unwrap();
    let (cursors, _) = sweep(&points, 20);
    for cursor in cursors {
        let a = weights(&blend, cursor);
        let b = weights(&moved_blend, map(cursor));
        for k in 0..points.len() {
            assert!(
                (a[k] - b[k]).abs() < 1e-9,
                "w_{k}({cursor}): {} vs {}",
                a[k],
                b[k]
            );
        }
    }
}

#[test]
fn bad_key_points_are_refused() {
    assert_eq!(RbfBlend::new(&[]).unwrap_err(), RbfError::NoPoints);

    let nan = [DVec2::ZERO, DVec2::new(1.0, f64::NAN)];
    let error = RbfBlend::new(&nan).unwrap_err();
    assert!(
        matches!(error, RbfError::NotFinite { index: 1, .. }),
        "{error:?}"
    );
    assert!(
        error.to_string().starts_with("key point 1 is not finite"),
        "{error}"
    );
    let infinite = [DVec2::new(f64::INFINITY, 0.0)];
    assert!(matches!(
        RbfBlend::new(&infinite).unwrap_err(),
        RbfError::NotFinite { index: 0, .. }
    ));

    let duplicate = [
        DVec2::ZERO,
        DVec2::new(0.5, 0.5),
        DVec2::X,
        DVec2::new(0.5, 0.5),
    ];
    let error = RbfBlend::new(&duplicate).unwrap_err();
    assert!(
        matches!(
            error,
            RbfError::SamePoint {
                first: 1,
                second: 3,
                ..
            }
        ),
        "{error:?}"
    );
    assert!(
        error
            .to_string()
            .starts_with("key points 1 and 3 are the same point"),
        "{error}"
    );

    let all_equal = [DVec2::ONE; 3];
    assert!(matches!(
        RbfBlend::new(&all_equal).unwrap_err(),
        RbfError::SamePoint {
            first: 0,
            second: 1,
            ..
        }
    ));

    // Within the relative tolerance is the same point; just beyond it is not.
    let scale = 1e3;
    let close = [
        DVec2::ZERO,
        DVec2::new(scale, scale),
        DVec2::new(0.5 * MIN_RELATIVE_SEPARATION * scale, 0.0),
    ];
    assert!(matches!(
        RbfBlend::new(&close).unwrap_err(),
        RbfError::SamePoint {
            first: 0,
            second: 2,
            ..
        }
    ));
    let apart = [DVec2::ZERO, DVec2::new(1.0, 1.0), DVec2::new(1e-6, 0.0)];
    let blend = RbfBlend::new(&apart).unwrap();
    let at = weights(&blend, DVec2::new(1e-6, 0.0));
    assert!((at[2] - 1.0).abs() < 1e-6 && at[0].abs() < 1e-6, "{at:?}");
}

#[test]
fn odd_output_slices_and_cursors_do_not_panic() {
    let points = scattered(5, 0.1, 17);
    let blend = RbfBlend::new(&points).unwrap();
    let full = weights(&blend, DVec2::new(0.3, 0.3));
    let mut short = [7.0; 3];
    blend.weights_into(DVec2::new(0.3, 0.3), &mut short);
    assert_eq!(short[..], full[..3]);
    let mut long = [7.0; 8];
    blend.weights_into(DVec2::new(0.3, 0.3), &mut long);
    assert_eq!(long[..5], full[..]);
    assert_eq!(long[5..], [7.0; 3]);
    let mut out = [0.0; 5];
    blend.weights_into(DVec2::new(f64::NAN, 0.0), &mut out);
    assert!(out.iter().all(|w| w.is_nan()));
}

#[test]
fn weights_into_does_not_allocate() {
    let points = scattered(80, 0.02, 19);
    let blend = RbfBlend::new(&points).unwrap();
    let mut out = vec![0.0; blend.len()];
    let mut total = 0.0;
    let ((), allocations) = alloc::count(|| {
        for frame in 0..1000 {
            let t = frame as f64 * 0.01;
            blend.weights_into(DVec2::new(t.sin(), (1.3 * t).cos()) * 0.6 + 0.5, &mut out);
            total += out[frame % out.len()];
        }
    });
    assert_eq!(allocations, 0, "weights_into allocated");
    assert!(total.is_finite());
    // The counter works: building a blend does allocate.
    let (_, allocations) = alloc::count(|| RbfBlend::new(&points).unwrap());
    assert!(allocations > 0);
}
