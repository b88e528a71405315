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

/// Triangles by vertex index, every index below `bound` (checked when
/// made), so a kernel may read positions at them unchecked once it knows
/// the positions are at least that many.
#[derive(Debug, Clone)]
pub(crate) struct Triangles {
    list: Vec<[u32; 3]>,
    bound: usize,
}

impl Triangles {
    pub(crate) fn new(list: Vec<[u32; 3]>, bound: usize) -> Triangles {
        assert!(
            list.iter().flatten().all(|&i| (i as usize) < bound),
            "triangle index out of range"
        );
        Triangles { list, bound }
    }

    /// Replaces `out` with every triangle whose signed area at `positions`
    /// is not positive (see [`NotPositive`]).
    pub(crate) fn not_positive(&self, positions: &[DVec2], out: &mut Vec<u32>) {
        out.clear();
        pulp::Arch::new().dispatch(NotPositive {
            triangles: self,
            positions,
            out,
        });
    }
}

impl std::ops::Deref for Triangles {
    type Target = [[u32; 3]];

    fn deref(&self) -> &[[u32; 3]] {
        &self.list
    }
}

/// Appends to `out`, in order, every triangle whose signed area at
/// `positions`, `(b - a).perp_dot(c - a)` to the last bit, is not positive
/// (inverted or flat): [`LANES`] triangles at a time, without a bounds
/// check a corner. `out` never grows past the triangle count.
struct NotPositive<'a> {
    triangles: &'a Triangles,
    positions: &'a [DVec2],
    out: &'a mut Vec<u32>,
}

impl pulp::WithSimd for NotPositive<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let NotPositive {
            triangles,
            positions,
            out,
        } = self;
        assert!(
            positions.len() >= triangles.bound,
            "fewer positions than the triangles' vertices"
        );
        // SAFETY: `Triangles::new` checked every index is below `bound`,
        // and `positions` is at least that long (asserted above).
        let corners = |tri: [u32; 3]| tri.map(|i| unsafe { *positions.get_unchecked(i as usize) });
        let body = triangles.len() - triangles.len() % LANES;
        for (block, chunk) in triangles[..body].chunks_exact(LANES).enumerate() {
            let p: [[DVec2; 3]; LANES] = std::array::from_fn(|l| corners(chunk[l]));
            // By coordinate, so the four areas are computed side by side:
            // the same operations in the same order as `perp_dot`.
            let (ux, uy): ([f64; LANES], [f64; LANES]) = (
                std::array::from_fn(|l| p[l][1].x - p[l][0].x),
                std::array::from_fn(|l| p[l][1].y - p[l][0].y),
            );
            let (vx, vy): ([f64; LANES], [f64; LANES]) = (
                std::array::from_fn(|l| p[l][2].x - p[l][0].x),
                std::array::from_fn(|l| p[l][2].y - p[l][0].y),
            );
            let area: [f64; LANES] = std::array::from_fn(|l| ux[l] * vy[l] - uy[l] * vx[l]);
            if area.iter().fold(false, |any, &a| any | (a <= 0.0)) {
                for (l, &a) in area.iter().enumerate() {
                    if a <= 0.0 {
                        out.push((block * LANES + l) as u32);
                    }
                }
            }
        }
        for (t, &tri) in triangles.iter().enumerate().skip(body) {
            let [a, b, c] = corners(tri);
            if (b - a).perp_dot(c - a) <= 0.0 {
                out.push(t as u32);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernel finds exactly what the scalar rule finds, whole blocks and
    /// tails alike, flat triangles (zero area) included.
    #[test]
    fn not_positive_agrees_with_the_scalar_rule() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5
        };
        let mut positions: Vec<DVec2> = (0..40).map(|_| DVec2::new(next(), next())).collect();
        // Three in a line: any triangle of them is flat.
        positions.extend([DVec2::ZERO, DVec2::new(1.0, 1.0), DVec2::new(2.0, 2.0)]);
        for count in 0..=13 {
            let list: Vec<[u32; 3]> = (0..count)
                .map(|t| {
                    if t % 5 == 4 {
                        [40, 41, 42]
                    } else {
                        let pick = |k: u32| (t * 7 + k * 13) % 40;
                        [pick(0), pick(1), pick(2)]
                    }
                })
                .collect();
            let expected: Vec<u32> = (0..count)
                .filter(|&t| {
                    let [a, b, c] = list[t as usize].map(|i| positions[i as usize]);
                    (b - a).perp_dot(c - a) <= 0.0
                })
                .collect();
            let triangles = Triangles::new(list, positions.len());
            let mut found = vec![99];
            triangles.not_positive(&positions, &mut found);
            assert_eq!(found, expected, "{count} triangles");
            assert!(
                count < 5 || !found.is_empty(),
                "{count}: some flat one found"
            );
        }
    }

    #[test]
    #[should_panic(expected = "fewer positions")]
    fn not_positive_refuses_too_few_positions() {
        let triangles = Triangles::new(vec![[0, 1, 2]], 3);
        triangles.not_positive(&[DVec2::ZERO; 2], &mut Vec::new());
    }
}
