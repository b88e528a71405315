//! Handle targets as every solver takes them: one per compiled handle,
//! each a finite point within the mesh format's coordinate limit (a point
//! past it could square to infinity inside a solve). ARAP and the curve
//! solver check their updates here and refuse with [`TargetError`].

use glam::DVec2;
use puppetry_mesh::json::MAX_COORDINATE;

/// Handle targets a solver refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TargetError {
    /// The targets are not one per handle of the last compile.
    #[error("expected {expected} handle targets (one per compiled handle), got {got}")]
    Count {
        /// How many the last compile made.
        expected: usize,
        /// How many came.
        got: usize,
    },
    /// A target is NaN, infinite or farther out than the mesh format's
    /// coordinate limit.
    #[error("handle {handle}: target is not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    NotFinite {
        /// The first offending handle's index.
        handle: usize,
    },
}

/// The first of `points` that is not finite or lies past the coordinate
/// limit.
pub(crate) fn out_of_range(points: &[DVec2]) -> Option<usize> {
    points
        .iter()
        .position(|p| !(p.is_finite() && p.abs().max_element() <= MAX_COORDINATE))
}

/// Checks `targets` for a compile of `expected` handles.
pub(crate) fn check(targets: &[DVec2], expected: usize) -> Result<(), TargetError> {
    if targets.len() != expected {
        return Err(TargetError::Count {
            expected,
            got: targets.len(),
        });
    }
    match out_of_range(targets) {
        Some(handle) => Err(TargetError::NotFinite { handle }),
        None => Ok(()),
    }
}
