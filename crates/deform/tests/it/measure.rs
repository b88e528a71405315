//! Distortion measures: zero for the identity and rigid motions, the
//! closed-form values for known stretches, flips counted, bad input rejected.

use std::f64::consts::{FRAC_PI_4, PI};

use crate::common::*;
use glam::DVec2;
use puppetry_deform::measure::{
    Distortion, MeasureError, mean, mesh_distortion, triangle_distortion, triangle_distortions,
};

#[test]
fn identity_and_rigid_motions_measure_zero() {
    let mesh = jittered(8, 4);
    let rest = mesh.vertices().to_vec();
    assert_eq!(
        mesh_distortion(&mesh, &rest).unwrap(),
        Distortion::default()
    );
    for angle in [0.3, -2.0, PI] {
        let rotation = DVec2::from_angle(angle);
        let moved: Vec<DVec2> = rest
            .iter()
            .map(|&p| rotation.rotate(p) + DVec2::new(40.0, -7.0))
            .collect();
        let d = mesh_distortion(&mesh, &moved).unwrap();
        assert!(d.angular < 1e-12 && d.area < 1e-12, "{angle}: {d:?}");
    }
}

#[test]
fn stretching_a_right_triangle_gives_the_closed_form() {
    // Right isosceles triangle stretched 2× along x: the right angle stays,
    // the 45° corners become atan(1/2) and atan(2).
    let rest = [DVec2::ZERO, DVec2::new(1.0, 0.0), DVec2::new(0.0, 1.0)];
    let stretched = rest.map(|p| p * DVec2::new(2.0, 1.0));
    let d = triangle_distortion(rest, stretched);
    let expected = ((FRAC_PI_4 - 0.5f64.atan()) + (2.0f64.atan() - FRAC_PI_4)) / 3.0;
    assert!((d.angular - expected).abs() < 1e-15, "{d:?} vs {expected}");
    assert!((d.area - 1.0).abs() < 1e-15);
}

#[test]
fn uniform_scaling_changes_area_only() {
    let mesh = jittered(6, 3);
    for s in [0.5, 1.5, 3.0] {
        let scaled: Vec<DVec2> = mesh.vertices().iter().map(|&p| p * s).collect();
        let d = mesh_distortion(&mesh, &scaled).unwrap();
        assert!(d.angular < 1e-12, "{s}: {d:?}");
        assert!((d.area - (s * s - 1.0).abs()).abs() < 1e-12, "{s}: {d:?}");
    }
}

#[test]
fn mesh_value_is_the_mean_over_triangles() {
    // A bar of right isosceles triangles (both diagonal directions) stretched
    // along x: every triangle has the same area change, and the angular
    // value is the mean of the per-triangle values.
    let mesh = bar(6, 2, 6.0, 2.0);
    let stretched: Vec<DVec2> = mesh
        .vertices()
        .iter()
        .map(|&p| p * DVec2::new(1.5, 1.0))
        .collect();
    let each = triangle_distortions(&mesh, &stretched).unwrap();
    assert_eq!(each.len(), mesh.triangles().len());
    let d = mesh_distortion(&mesh, &stretched).unwrap();
    assert!((d.area - 0.5).abs() < 1e-12);
    let angular: f64 = each.iter().map(|e| e.angular).sum::<f64>() / each.len() as f64;
    assert!((d.angular - angular).abs() < 1e-15);
    assert!(d.angular > 0.0);
    assert_eq!(mean(&each), d);
    assert_eq!(mean(&[]), Distortion::default());
}

#[test]
fn an_inverted_triangle_counts_its_flip() {
    let rest = [DVec2::ZERO, DVec2::new(1.0, 0.0), DVec2::new(0.0, 1.0)];
    let mirrored = rest.map(|p| DVec2::new(-p.x, p.y));
    let d = triangle_distortion(rest, mirrored);
    // Area −1 against +1; each angle changes sign.
    assert!((d.area - 2.0).abs() < 1e-15);
    let expected = (PI / 2.0 * 2.0 + FRAC_PI_4 * 2.0 * 2.0) / 3.0;
    assert!((d.angular - expected).abs() < 1e-12, "{d:?} vs {expected}");
}

#[test]
fn bad_poses_are_rejected() {
    let mesh = jittered(4, 2);
    let mut pose = mesh.vertices().to_vec();
    assert!(matches!(
        mesh_distortion(&mesh, &pose[1..]),
        Err(MeasureError::VertexCount { got, .. }) if got == pose.len() - 1
    ));
    pose[3].y = f64::NAN;
    assert!(matches!(
        mesh_distortion(&mesh, &pose),
        Err(MeasureError::NotFinite { vertex: 3 })
    ));
}
