//! Blending weights for spatial keyframing: key poses sit at points of a 2D
//! pad, and a cursor on the pad blends them (§5.3 of "As-rigid-as-possible
//! shape manipulation", Igarashi, Moscovich & Hughes 2005, after Ngo et al.
//! 2000 and Lewis et al. 2000). This module owns only the weights: given `n`
//! distinct key points it precomputes an interpolating radial basis function
//! and then, per input frame, turns a cursor position into one weight per
//! key, without allocating. What the weights blend (handle positions, joint
//! angles) is the caller's business.
//!
//! The blend of any per-key data `v_k` is the interpolant
//! `f(x) = Σ_j c_j φ(|x − x_j|) + d` with `f(x_k) = v_k` and `Σ_j c_j = 0`,
//! i.e. the `(n+1)×(n+1)` system `[Φ 1; 1ᵀ 0] [c; d] = [v; 0]`. It is linear in
//! the data, so `f(x) = Σ_k w_k(x) v_k` with weights that depend only on the
//! key points: row `k` of the system's inverse applied to `[φ(|x − x_j|); 1]`.
//! Hence:
//!
//! - `w_k(x_j) = δ_kj`: the cursor on a key gives exactly that key's pose
//!   (exactly in floating point too: a cursor equal to a key point gets the
//!   weights 1 and 0 as such);
//! - `Σ_k w_k(x) = 1` everywhere: the constant term reproduces constants, so a
//!   single key gives a constant pose, and blending never drifts toward zero;
//! - the weights are not convex: between and beyond keys they can be negative
//!   or exceed 1, so a blended pose may overshoot its keys a little (that is
//!   the price of exact interpolation; it is what makes motion "lively").
//!
//! Why the kernel is `φ(r) = r` (the polyharmonic spline of order 1):
//!
//! - With a constant polynomial term it is solvable for *any* set of distinct
//!   points: `−r` is conditionally positive definite of order 1 (Micchelli
//!   1986), so `Φ` is definite on the vectors summing to zero and
//!   `[Φ 1; 1ᵀ 0]` is non-singular. One or two keys work too.
//! - It has no shape parameter. A Gaussian `exp(−(r/σ)²)` needs a width `σ`:
//!   too narrow and the pose sags toward zero between keys (Gaussians carry no
//!   constant term, so far from every key all weights vanish), too wide and the
//!   system is badly conditioned; keys placed unevenly on the pad admit no good
//!   single `σ`. With `φ(r) = r` the weights are invariant under moving,
//!   rotating and uniformly scaling the pad.
//! - The thin-plate spline `r² log r` is conditionally positive definite only
//!   of order 2: it needs the linear terms `x, y` too (hence at least three
//!   non-collinear keys), and with the constant term alone its system can be
//!   singular — two keys exactly one unit apart give `Φ = 0` and
//!   `[0 1; 1ᵀ 0]` of rank 2 in dimension 3.
//! - The weights are Lipschitz (`|∇φ| = 1`): dragging the cursor never makes
//!   the pose jump, and [`RbfBlend::lipschitz`] bounds how fast it can move.
//!   They have kinks (not jumps) at the key points, and far from the keys they
//!   stay bounded, because `Σ_j c_j = 0` cancels the linear growth of `r`.

use faer::linalg::lu::partial_pivoting::solve::{solve_in_place, solve_in_place_scratch};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use glam::DVec2;

use crate::dense::SequentialLu;

/// Two key points closer than this fraction of the points' extent (the larger
/// side of their bounding box) are one point: the system would be singular,
/// or so badly conditioned that the weights between them would swing wildly.
pub const MIN_RELATIVE_SEPARATION: f64 = 1e-9;

/// Why [`RbfBlend::new`] refused a set of key points.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RbfError {
    /// The set is empty.
    #[error("no key points: blending needs at least one")]
    NoPoints,
    /// A key point has a NaN or infinite coordinate.
    #[error("key point {index} is not finite ({x}, {y})")]
    NotFinite {
        /// The first offending key.
        index: usize,
        /// Its x coordinate on the pad.
        x: f64,
        /// Its y coordinate on the pad.
        y: f64,
    },
    /// Two keys are within [`MIN_RELATIVE_SEPARATION`] of the points'
    /// extent of each other (or every key is at one point).
    #[error(
        "key points {first} and {second} are the same point ({distance:e} apart, within {tolerance:e})"
    )]
    SamePoint {
        /// The earlier key of the first such pair.
        first: usize,
        /// The later key.
        second: usize,
        /// How far apart they are, in pad units.
        distance: f64,
        /// The separation they needed to exceed, in pad units.
        tolerance: f64,
    },
    /// Not expected for distinct points (see the module documentation); kept
    /// so that a numerical breakdown is an error and never a NaN weight.
    #[error("the interpolation system of {count} key points could not be solved")]
    Singular {
        /// How many key points there were.
        count: usize,
    },
}

/// Interpolating RBF weights over fixed key points (see the module
/// documentation). Built once per key-point set; [`RbfBlend::weights_into`]
/// runs per frame and does not allocate.
#[derive(Debug, Clone)]
pub struct RbfBlend {
    points: Vec<DVec2>,
    /// `n×n`, column `j` contiguous: the coefficient of `|x − x_j|` in each
    /// key's weight (the inverse's upper-left block, divided by the scale
    /// the system was built in).
    radial: Vec<f64>,
    /// The constant term of each key's weight.
    constant: Vec<f64>,
    /// Per key, the Lipschitz constant of its weight.
    lipschitz: Vec<f64>,
}

impl RbfBlend {
    /// Precomputes the weights' coefficients for these key points (an LU of
    /// the `(n+1)×(n+1)` system, inverted and refined once: `O(n³)`, meant for
    /// up to a few hundred keys).
    pub fn new(points: &[DVec2]) -> Result<RbfBlend, RbfError> {
        let n = points.len();
        if n == 0 {
            return Err(RbfError::NoPoints);
        }
        if let Some(index) = points.iter().position(|p| !p.is_finite()) {
            let p = points[index];
            return Err(RbfError::NotFinite {
                index,
                x: p.x,
                y: p.y,
            });
        }
        let (lo, hi) = points.iter().fold(
            (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let extent = (hi - lo).max_element();
        let tolerance = MIN_RELATIVE_SEPARATION * extent;
        for (first, &a) in points.iter().enumerate() {
            for (second, &b) in points.iter().enumerate().skip(first + 1) {
                let distance = a.distance(b);
                // `<=`: with every point equal the extent and the tolerance
                // are both zero.
                if distance <= tolerance {
                    return Err(RbfError::SamePoint {
                        first,
                        second,
                        distance,
                        tolerance,
                    });
                }
            }
        }
        // The weights are invariant under scaling the points (φ(sr) = sφ(r)
        // scales c by 1/s and leaves d alone), so the system is built on the
        // unit scale, where its two blocks have comparable entries.
        let scale = if extent > 0.0 { extent } else { 1.0 };
        let system = Mat::<f64>::from_fn(n + 1, n + 1, |i, j| match (i < n, j < n) {
            (true, true) => points[i].distance(points[j]) / scale,
            (false, false) => 0.0,
            _ => 1.0,
        });
        let inverse = invert_refined(&system).ok_or(RbfError::Singular { count: n })?;
        let mut radial = vec![0.0; n * n];
        for j in 0..n {
            for k in 0..n {
                radial[j * n + k] = inverse[(k, j)] / scale;
            }
        }
        let constant: Vec<f64> = (0..n).map(|k| inverse[(k, n)]).collect();
        let lipschitz = (0..n)
            .map(|k| (0..n).map(|j| radial[j * n + k].abs()).sum())
            .collect();
        Ok(RbfBlend {
            points: points.to_vec(),
            radial,
            constant,
            lipschitz,
        })
    }

    /// The key points, in the order the weights are given.
    pub fn points(&self) -> &[DVec2] {
        &self.points
    }

    /// The number of key points (and of weights).
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Never true: a blend has at least one key point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Per key, a Lipschitz constant of its weight: `|w_k(a) − w_k(b)| ≤
    /// lipschitz()[k] · |a − b|` for any two cursor positions (each weight is
    /// a combination of distances, each 1-Lipschitz, so the sum of the
    /// coefficients' magnitudes bounds it). A blend of values `v_k` therefore
    /// moves by at most `Σ_k lipschitz()[k] · |v_k|` per unit of cursor travel.
    pub fn lipschitz(&self) -> &[f64] {
        &self.lipschitz
    }

    /// Writes each key's weight at `cursor` into `out` (`out[k]` for key `k`;
    /// `out` should be [`len`](Self::len) long — extra entries are left
    /// alone, missing ones are not computed). A non-finite cursor gives NaN
    /// weights. `O(n²)`, no allocation.
    pub fn weights_into(&self, cursor: DVec2, out: &mut [f64]) {
        let n = self.points.len();
        let used = n.min(out.len());
        let out = &mut out[..used];
        if !cursor.is_finite() {
            out.fill(f64::NAN);
            return;
        }
        // On a key the weights are exactly δ: the key's pose comes back bit for
        // bit, not rounded through the inverse (which is off by ~1e-15).
        if let Some(j) = self.points.iter().position(|&p| p == cursor) {
            out.fill(0.0);
            if let Some(w) = out.get_mut(j) {
                *w = 1.0;
            }
            return;
        }
        out.copy_from_slice(&self.constant[..out.len()]);
        for (j, &point) in self.points.iter().enumerate() {
            let r = cursor.distance(point);
            let column = &self.radial[j * n..j * n + out.len()];
            for (w, &c) in out.iter_mut().zip(column) {
                *w += c * r;
            }
        }
    }
}

/// The inverse of a small dense non-singular matrix, by LU with partial
/// pivoting on this thread (faer's convenience API would wake its thread
/// pool, which costs more than the arithmetic here), then one step of
/// iterative refinement, `X ← X + A⁻¹(I − A X)`, so that the interpolation
/// conditions hold to rounding of the data rather than of the factorisation.
/// `None` when the result is not finite (a zero pivot).
fn invert_refined(matrix: &Mat<f64>) -> Option<Mat<f64>> {
    let n = matrix.nrows();
    let mut factored = SequentialLu::new(
        matrix.clone(),
        solve_in_place_scratch::<usize, f64>(n, n, Par::Seq),
    );
    let (lu, permutation, stack) = factored.parts();
    // The unit lower factor and the upper factor share `lu`; each solve reads
    // only its own triangle.
    let mut inverse = Mat::<f64>::identity(n, n);
    solve_in_place(lu, lu, permutation, inverse.as_mut(), Par::Seq, stack);
    let mut residual = Mat::<f64>::identity(n, n);
    matmul(
        residual.as_mut(),
        Accum::Add,
        matrix.as_ref(),
        inverse.as_ref(),
        -1.0,
        Par::Seq,
    );
    solve_in_place(lu, lu, permutation, residual.as_mut(), Par::Seq, stack);
    let refined = inverse + residual;
    let finite = (0..n).all(|j| (0..n).all(|i| refined[(i, j)].is_finite()));
    finite.then_some(refined)
}
