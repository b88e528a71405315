//! Distortion measures between a rest mesh and a deformed pose, for comparing
//! deformers the way the lp-FFD paper's Table 1 does (angular and area
//! distortion, averaged over triangles).
//!
//! The paper only cites its measures ("as defined in \[WLZS16\]", ARAP++) and
//! the design notes this project started from give no formulas, so
//! these are our standard definitions; the paper's numbers are a guide to
//! orders of magnitude, not directly comparable:
//!
//! - **Angular distortion** of a triangle: `(1/3) Σ_k |θ'_k − θ_k|`, the mean
//!   absolute change of its three interior angles, in radians. Deformed
//!   angles are signed (`atan2(cross, dot)` of the two edges leaving the
//!   corner, counter-clockwise positive), so an inverted triangle counts its
//!   flip instead of looking like its mirror image.
//! - **Area distortion** of a triangle: `|A'/A − 1|` with signed areas
//!   (an inverted triangle scores more than 1).
//!
//! Mesh values are unweighted means over all triangles. Both are 0 exactly
//! for rigid motions (rotations and translations); uniform scaling by `s`
//! leaves the angular one at 0 and gives area `|s² − 1|`.

use glam::DVec2;

use puppetry_mesh::Mesh;
use puppetry_mesh::json::MAX_COORDINATE;

/// Why a deformed pose could not be measured against its mesh.
#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    /// The pose is not one position per mesh vertex.
    #[error("expected {expected} deformed vertices (one per mesh vertex), got {got}")]
    VertexCount {
        /// How many vertices the mesh has.
        expected: usize,
        /// How many positions came.
        got: usize,
    },
    /// A position is NaN, infinite or beyond the mesh format's coordinate
    /// limit.
    #[error("deformed vertex {vertex}: not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    NotFinite {
        /// The first offending vertex.
        vertex: usize,
    },
}

/// Angular (radians) and area distortion, for one triangle or a mean.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Distortion {
    /// Mean absolute change of the interior angles, in radians (0 for a
    /// rigid or uniformly scaled triangle).
    pub angular: f64,
    /// `|A'/A − 1|` with signed areas: 0 when the area is kept, above 1
    /// when the triangle inverted.
    pub area: f64,
}

/// Signed interior angle at `corner` between the edges to `next` and `prev`
/// (counter-clockwise order positive).
fn corner_angle(corner: DVec2, next: DVec2, prev: DVec2) -> f64 {
    let (a, b) = (next - corner, prev - corner);
    a.perp_dot(b).atan2(a.dot(b))
}

/// The distortion of one triangle (corners in the same order in both).
pub fn triangle_distortion(rest: [DVec2; 3], deformed: [DVec2; 3]) -> Distortion {
    let mut angular = 0.0;
    for k in 0..3 {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        let before = corner_angle(rest[k], rest[i], rest[j]);
        let after = corner_angle(deformed[k], deformed[i], deformed[j]);
        angular += (after - before).abs();
    }
    let area_before = (rest[1] - rest[0]).perp_dot(rest[2] - rest[0]);
    let area_after = (deformed[1] - deformed[0]).perp_dot(deformed[2] - deformed[0]);
    Distortion {
        angular: angular / 3.0,
        area: (area_after / area_before - 1.0).abs(),
    }
}

/// Per-triangle distortions of `deformed` against the mesh's rest shape.
pub fn triangle_distortions(
    mesh: &Mesh,
    deformed: &[DVec2],
) -> Result<Vec<Distortion>, MeasureError> {
    let rest = mesh.vertices();
    if deformed.len() != rest.len() {
        return Err(MeasureError::VertexCount {
            expected: rest.len(),
            got: deformed.len(),
        });
    }
    if let Some(vertex) = deformed
        .iter()
        .position(|p| !(p.is_finite() && p.abs().max_element() <= MAX_COORDINATE))
    {
        return Err(MeasureError::NotFinite { vertex });
    }
    Ok(mesh
        .triangles()
        .iter()
        .map(|t| {
            let corners = t.map(|i| i as usize);
            triangle_distortion(corners.map(|i| rest[i]), corners.map(|i| deformed[i]))
        })
        .collect())
}

/// The mean distortion over all triangles of the mesh.
pub fn mesh_distortion(mesh: &Mesh, deformed: &[DVec2]) -> Result<Distortion, MeasureError> {
    let each = triangle_distortions(mesh, deformed)?;
    Ok(mean(&each))
}

/// The mean of some distortions (zero for none).
pub fn mean(distortions: &[Distortion]) -> Distortion {
    if distortions.is_empty() {
        return Distortion::default();
    }
    let count = distortions.len() as f64;
    let (angular, area) = distortions
        .iter()
        .fold((0.0, 0.0), |(a, b), d| (a + d.angular, b + d.area));
    Distortion {
        angular: angular / count,
        area: area / count,
    }
}
