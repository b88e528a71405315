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

/// [`Normalise`] for fit sums given by coordinate (`x`, `y`, at least as
/// long as `out`): the rotations into `out`.
pub(crate) struct NormaliseLanes<'a> {
    pub(crate) x: &'a [f64],
    pub(crate) y: &'a [f64],
    pub(crate) out: &'a mut [DVec2],
}

impl pulp::WithSimd for NormaliseLanes<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let n = self.out.len();
        let (x, y) = (&self.x[..n], &self.y[..n]);
        let body = n - n % 4;
        for ((out, x), y) in self.out[..body]
            .chunks_exact_mut(4)
            .zip(x.chunks_exact(4))
            .zip(y.chunks_exact(4))
        {
            let norm2: [f64; 4] = std::array::from_fn(|l| x[l] * x[l] + y[l] * y[l]);
            let scale: [f64; 4] = std::array::from_fn(|l| 1.0 / norm2[l].sqrt());
            for l in 0..4 {
                let ok = (norm2[l] > f64::MIN_POSITIVE) & (norm2[l] <= f64::MAX);
                out[l] = DVec2::new(
                    if ok { x[l] * scale[l] } else { 1.0 },
                    if ok { y[l] * scale[l] } else { 0.0 },
                );
            }
        }
        for i in body..n {
            let norm2 = x[i] * x[i] + y[i] * y[i];
            let ok = (norm2 > f64::MIN_POSITIVE) & (norm2 <= f64::MAX);
            let scale = 1.0 / norm2.sqrt();
            self.out[i] = if ok {
                DVec2::new(x[i] * scale, y[i] * scale)
            } else {
                DVec2::X
            };
        }
    }
}

/// Vertices per block of [`Packed`] rows: one per SIMD lane.
pub(crate) const LANES: usize = 4;

/// Per-vertex lists of (index, 2-vector) in blocks of [`LANES`] vertices,
/// one per SIMD lane: block b's slots are `start[b]..start[b + 1]`, slot s
/// holding each lane's s-th entry. A block has as many slots as its longest
/// list; shorter lists are padded with index 0 and a zero vector (a zero
/// term for any finite value at index 0), as are the lanes past the last
/// vertex. Lets a sweep sum each vertex's terms in registers, four vertices
/// at a time, where scattering into the vertices chained the sums through
/// memory.
#[derive(Debug, Clone, Default)]
pub(crate) struct Packed {
    pub(crate) rows: usize,
    /// Every index is below this (checked when packed).
    bound: usize,
    pub(crate) start: Vec<u32>,
    pub(crate) index: Vec<[u32; LANES]>,
    pub(crate) x: Vec<[f64; LANES]>,
    pub(crate) y: Vec<[f64; LANES]>,
}

impl Packed {
    /// Packs `lists` (one per vertex, entries in the order to sum them).
    /// Every index must be below `bound`, the length of what the sweeps
    /// read at them.
    pub(crate) fn new(lists: &[Vec<(u32, DVec2)>], bound: usize) -> Packed {
        assert!(
            lists.iter().flatten().all(|&(i, _)| (i as usize) < bound),
            "packed index out of range"
        );
        assert!(bound > 0 || lists.iter().all(|l| l.is_empty()));
        let rows = lists.len();
        let blocks = rows.div_ceil(LANES);
        let mut out = Packed {
            rows,
            bound,
            start: Vec::with_capacity(blocks + 1),
            ..Packed::default()
        };
        out.start.push(0);
        for b in 0..blocks {
            let list = |l: usize| lists.get(b * LANES + l).map_or(&[][..], |v| &v[..]);
            let width = (0..LANES).map(|l| list(l).len()).max().unwrap_or(0);
            for slot in 0..width {
                let entry = |l: usize| list(l).get(slot).copied().unwrap_or((0, DVec2::ZERO));
                out.index.push(std::array::from_fn(|l| entry(l).0));
                out.x.push(std::array::from_fn(|l| entry(l).1.x));
                out.y.push(std::array::from_fn(|l| entry(l).1.y));
            }
            out.start.push(out.index.len() as u32);
        }
        out
    }

    /// Block `b`'s per-lane sums `Σ R(rotations[index]) (x, y)`, each
    /// rotation held as (cos, sin): the rotated-vector gather both rigs'
    /// right-hand sides are made of.
    #[inline(always)]
    pub(crate) fn turned_sums(
        &self,
        b: usize,
        rotations: &[DVec2],
    ) -> ([f64; LANES], [f64; LANES]) {
        assert!(
            rotations.len() >= self.bound,
            "rotations shorter than packed indices"
        );
        let (mut sx, mut sy) = ([0.0; LANES], [0.0; LANES]);
        let slots = self.start[b] as usize..self.start[b + 1] as usize;
        for ((i, ax), ay) in self.index[slots.clone()]
            .iter()
            .zip(&self.x[slots.clone()])
            .zip(&self.y[slots])
        {
            // SAFETY: `Packed::new` checked every index is below `bound`,
            // and `rotations` is at least that long (asserted above).
            let r: [DVec2; LANES] =
                std::array::from_fn(|l| unsafe { *rotations.get_unchecked(i[l] as usize) });
            let rx: [f64; LANES] = std::array::from_fn(|l| r[l].x);
            let ry: [f64; LANES] = std::array::from_fn(|l| r[l].y);
            for l in 0..LANES {
                sx[l] += rx[l] * ax[l] - ry[l] * ay[l];
                sy[l] += ry[l] * ax[l] + rx[l] * ay[l];
            }
        }
        (sx, sy)
    }
}
