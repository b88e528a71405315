//! Small kernels the deformers share, written as `pulp` SIMD operations:
//! `pulp::Arch::new().dispatch(kernel)` runs the kernel's plain loops
//! compiled for the widest instruction set this CPU has (AVX2 and FMA on
//! the development machine), found at run time, so the release build needs
//! no target flags and stays portable.

use glam::DVec2;

/// Normalises fit sums `(Σ r̄·p, Σ r̄×p)` into rotations (cos, sin); a
/// vanishing or non-finite fit gets the identity.
pub(crate) struct Normalise<'a>(pub(crate) &'a mut [DVec2]);

impl pulp::WithSimd for Normalise<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        for fit in self.0.iter_mut() {
            let norm2 = fit.x * fit.x + fit.y * fit.y;
            let ok = norm2 > f64::MIN_POSITIVE && norm2 <= f64::MAX;
            let scale = 1.0 / norm2.sqrt();
            // Branch-free, so the loop vectorises.
            fit.x = if ok { fit.x * scale } else { 1.0 };
            fit.y = if ok { fit.y * scale } else { 0.0 };
        }
    }
}
