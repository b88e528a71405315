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
        let (body, tail) = self.0.split_at_mut(self.0.len() - self.0.len() % 4);
        for chunk in body.chunks_exact_mut(4) {
            // Split into lanes and branch-free (`&`, selects), so the square
            // roots and divisions vectorise four at a time.
            let x: [f64; 4] = std::array::from_fn(|l| chunk[l].x);
            let y: [f64; 4] = std::array::from_fn(|l| chunk[l].y);
            let norm2: [f64; 4] = std::array::from_fn(|l| x[l] * x[l] + y[l] * y[l]);
            let scale: [f64; 4] = std::array::from_fn(|l| 1.0 / norm2[l].sqrt());
            for l in 0..4 {
                let ok = (norm2[l] > f64::MIN_POSITIVE) & (norm2[l] <= f64::MAX);
                chunk[l] = DVec2::new(
                    if ok { x[l] * scale[l] } else { 1.0 },
                    if ok { y[l] * scale[l] } else { 0.0 },
                );
            }
        }
        for fit in tail {
            let norm2 = fit.x * fit.x + fit.y * fit.y;
            let ok = (norm2 > f64::MIN_POSITIVE) & (norm2 <= f64::MAX);
            let scale = 1.0 / norm2.sqrt();
            *fit = if ok { *fit * scale } else { DVec2::X };
        }
    }
}
