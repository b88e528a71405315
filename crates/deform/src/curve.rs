//! As-rigid-as-possible curve editing (Igarashi, Moscovich & Hughes 2005,
//! §5.4): an open polyline deformed by handles in two steps, and the peeling
//! interface that grows the edited region as a drag goes further.
//!
//! Step 1 is Laplacian curve editing ("Laplacian surface editing", Sorkine et
//! al. 2004) in rotation-invariant form: each interior rest point is written
//! in the frame of its two neighbours, `v̄ᵢ = v̄ᵢ₋₁ + xᵢ dᵢ + yᵢ R dᵢ` with
//! `dᵢ = v̄ᵢ₊₁ − v̄ᵢ₋₁`, and the deformed curve minimises the squared error of
//! the same expression. In complex numbers (a point is `x + iy`) the pair
//! `(xᵢ, yᵢ)` with the fixed quarter turn `R` is a single complex ratio
//! `zᵢ = (v̄ᵢ − v̄ᵢ₋₁)/(v̄ᵢ₊₁ − v̄ᵢ₋₁)`, so the energy is a complex Hermitian
//! form and one complex solve gives both coordinates. Step 2 (scale
//! adjustment) gives every segment the step-1 direction and its rest length
//! and fits the curve to those segments in least squares.
//!
//! Handles are linear constraints — a point, or a point along a segment — so
//! each step solves the constrained minimum through its KKT system. Points
//! outside a chosen interval are fixed where they are (peeling), so the
//! system only spans the free interval. Unknowns are numbered along the
//! curve with each handle's multiplier right after its points, which keeps
//! the system banded: compile factors it by banded LU with partial pivoting
//! (the KKT matrix is indefinite) in O(n), an update is two banded solves
//! (complex for step 1; real for step 2, whose x and y share the matrix).
//!
//! Phases: [`Curve::register`] (rest curve: validation, local frames),
//! [`Curve::compile`] / [`Curve::compile_within`] (handle set or free
//! interval changed: assembly and factorisation), [`Curve::update`] (handles
//! moved; does not allocate). [`Peel`] turns a drag into the free interval.

use std::ops::RangeInclusive;

use glam::DVec2;
use puppetry_mesh::json::MAX_COORDINATE;

pub use super::arap::Steps;

/// Where a handle holds the curve, in rest terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CurveAnchor {
    /// A point of the polyline.
    Point(u32),
    /// A point along segment `segment` (from point `segment` to
    /// `segment + 1`), at parameter `t` in `[0, 1]`.
    Along { segment: u32, t: f64 },
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CurveError {
    #[error("a curve needs at least 3 points, got {count}")]
    TooFewPoints { count: usize },
    #[error("point {point} is not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    PointNotFinite { point: usize },
    #[error("point {point} repeats point {previous}: segment {previous} has zero length")]
    RepeatedPoint { point: usize, previous: usize },
    #[error("the curve folds back on itself at point {point}: segments {} and {point} overlap", point - 1)]
    FoldsBack { point: usize },
    #[error("segments {first} and {second} cross or touch: the curve intersects itself")]
    SelfIntersection { first: usize, second: usize },
    #[error("resampling spacing {spacing} must be finite and positive")]
    BadSpacing { spacing: f64 },
    #[error("handle {handle}: point {point} is out of range (the curve has {count} points)")]
    PointOutOfRange {
        handle: usize,
        point: u32,
        count: usize,
    },
    #[error("handle {handle}: segment {segment} is out of range (the curve has {count} segments)")]
    SegmentOutOfRange {
        handle: usize,
        segment: u32,
        count: usize,
    },
    #[error("handle {handle}: parameter t = {t} must be finite and within [0, 1]")]
    BadParameter { handle: usize, t: f64 },
    #[error("handle {handle} lies outside the free points {start}..={end}: it cannot move")]
    HandleFixed {
        handle: usize,
        start: usize,
        end: usize,
    },
    #[error("free points {start}..={end} are not within the curve's {count} points")]
    BadFreeRange {
        start: usize,
        end: usize,
        count: usize,
    },
    #[error("step {step}: the handles and fixed points do not determine the curve (add a handle)")]
    Underdetermined { step: u8 },
    #[error("expected {expected} handle targets (one per compiled handle), got {got}")]
    TargetCount { expected: usize, got: usize },
    #[error("handle {handle}: target is not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    TargetNotFinite { handle: usize },
    #[error("grab at arc length {at} is not on the curve (0..={length})")]
    GrabOffCurve { at: f64, length: f64 },
    #[error("pushpin {pushpin} at arc length {at} is not on the curve (0..={length})")]
    PushpinOffCurve {
        pushpin: usize,
        at: f64,
        length: f64,
    },
    #[error("pushpin {pushpin} sits at the grab point: nothing could move")]
    PushpinAtGrab { pushpin: usize },
    #[error("peel {field} = {value} must be finite and non-negative")]
    BadPeelParameter { field: &'static str, value: f64 },
    #[error("drag distance {distance} must be finite and non-negative")]
    BadDragDistance { distance: f64 },
}

/// Complex multiplication on (re, im) pairs.
#[inline]
fn mul(a: DVec2, b: DVec2) -> DVec2 {
    a.rotate(b)
}

#[inline]
fn conj(a: DVec2) -> DVec2 {
    DVec2::new(a.x, -a.y)
}

#[inline]
fn div(a: DVec2, b: DVec2) -> DVec2 {
    mul(a, conj(b)) / b.length_squared()
}

/// An entry of a banded system: a complex number as a (re, im) pair for
/// step 1, a real for step 2. Right-hand sides are always pairs: a complex
/// number, or for a real matrix the x and y of one point solved together.
trait Entry:
    Copy + Default + PartialEq + std::ops::Add<Output = Self> + std::ops::Sub<Output = Self>
{
    fn times(self, other: Self) -> Self;
    /// `self · x` for a right-hand-side pair.
    fn apply(self, x: DVec2) -> DVec2;
    fn magnitude_squared(self) -> f64;
    fn reciprocal(self) -> Self;
}

impl Entry for DVec2 {
    #[inline]
    fn times(self, other: Self) -> Self {
        mul(self, other)
    }
    #[inline]
    fn apply(self, x: DVec2) -> DVec2 {
        mul(self, x)
    }
    #[inline]
    fn magnitude_squared(self) -> f64 {
        self.length_squared()
    }
    #[inline]
    fn reciprocal(self) -> Self {
        conj(self) / self.length_squared()
    }
}

impl Entry for f64 {
    #[inline]
    fn times(self, other: Self) -> Self {
        self * other
    }
    #[inline]
    fn apply(self, x: DVec2) -> DVec2 {
        x * self
    }
    #[inline]
    fn magnitude_squared(self) -> f64 {
        self * self
    }
    #[inline]
    fn reciprocal(self) -> Self {
        1.0 / self
    }
}

/// A square banded matrix and its LU factors with partial pivoting, in
/// LAPACK's band layout (`gbtrf`): column `j` holds rows
/// `j − ku − kl ..= j + kl`, the extra `kl` above for the pivoting's fill.
/// After factoring, the non-zeros of each column of L and U are packed
/// one column after another in the order the solves read them, so a solve
/// streams through about half the memory of the band (whose corners are
/// mostly empty: most columns never pivot) and never tests a zero.
///
/// The packing is in runs of columns of one width: a handle's multiplier
/// row sits between its points and widens the few columns around it, and
/// packing every column as wide as those would make the solves do a third
/// (step 1) or half (step 2) more work on zeros.
#[derive(Debug, Default)]
struct BandLu<T> {
    n: usize,
    kl: usize,
    ku: usize,
    band: Vec<T>,
    pivots: Vec<u32>,
    /// Per column: reciprocal of U's diagonal.
    inverse_diagonal: Vec<T>,
    /// L below the diagonal, per column rows `j + 1 ..` (zero-padded to
    /// its run's width): as wide as the column or its row swap, whichever
    /// is more.
    lower: Vec<T>,
    lower_runs: Vec<Run>,
    /// Per column while factoring: how far L reaches below the diagonal
    /// (or its row swap), and U above.
    widths: Vec<(usize, usize)>,
    /// U above the diagonal with each row scaled by the reciprocal of its
    /// diagonal, per column rows `j − 1, j − 2, …` (nearest first,
    /// zero-padded to its run's width).
    upper: Vec<T>,
    upper_runs: Vec<Run>,
}

/// Columns `start..end` of a packed factor, `width` entries each from
/// `offset`, and whether a row was swapped at any of them.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Run {
    start: usize,
    end: usize,
    width: usize,
    offset: usize,
    swaps: bool,
}

/// Runs are at least this many columns (but the last), so a factor whose
/// widths alternate does not pay a window reload every few columns.
const SHORTEST_RUN: usize = 32;

/// Splits columns of the given widths (and whether each swaps a row) into
/// runs: a new run starts where either changes, unless the current run is
/// still short (then it widens to take the column).
fn runs_of(columns: impl Iterator<Item = (usize, bool)>, runs: &mut Vec<Run>) {
    runs.clear();
    for (j, (width, swaps)) in columns.enumerate() {
        match runs.last_mut() {
            Some(run)
                if run.end - run.start < SHORTEST_RUN
                    || (run.width == width && run.swaps == swaps) =>
            {
                run.width = run.width.max(width);
                run.swaps |= swaps;
                run.end = j + 1;
            }
            _ => runs.push(Run {
                start: j,
                end: j + 1,
                width,
                offset: 0,
                swaps,
            }),
        }
    }
    let mut offset = 0;
    for run in runs.iter_mut() {
        run.offset = offset;
        offset += run.width * (run.end - run.start);
    }
}

impl<T: Entry> BandLu<T> {
    /// Zeroes an `n`×`n` matrix with the given bandwidths, reusing storage.
    fn reset(&mut self, n: usize, kl: usize, ku: usize) {
        self.n = n;
        self.kl = kl;
        self.ku = ku;
        self.band.clear();
        self.band.resize(n * self.stride(), T::default());
    }

    #[inline]
    fn stride(&self) -> usize {
        2 * self.kl + self.ku + 1
    }

    /// Where entry (i, j) lives; `kl + ku` is the diagonal's place.
    #[inline]
    fn slot(&self, i: usize, j: usize) -> usize {
        debug_assert!(i <= j + self.kl && j <= i + self.ku + self.kl);
        j * self.stride() + self.kl + self.ku + i - j
    }

    #[inline]
    fn add(&mut self, i: usize, j: usize, value: T) {
        let s = self.slot(i, j);
        self.band[s] = self.band[s] + value;
    }

    /// In-place LU, swapping rows where the diagonal's magnitude is below
    /// `threshold` times its column's largest (1: partial pivoting). False
    /// when a pivot vanishes against the matrix's scale (singular) or,
    /// below 1, when the factors grow: the caller then assembles the matrix
    /// again and pivots partially.
    ///
    /// Threshold pivoting ([`PIVOT_THRESHOLD`]) comes first because with
    /// each handle's multiplier after its points the diagonal nearly always
    /// qualifies: the factors keep the matrix's own bandwidths and the
    /// solves' windows stay in registers, where partial pivoting swaps at
    /// almost every column of a curve's step-1 matrix. The few swaps it
    /// makes are where one is needed: at the free end of a long curve the
    /// last point's pivot is tiny (its bending stiffness falls with the cube
    /// of the free length).
    fn factor_with(&mut self, threshold: f64) -> bool {
        let n = self.n;
        let (kl, ku) = (self.kl, self.ku);
        let scale = largest_magnitude(&self.band);
        // Squared magnitudes: a pivot below 1e-13 of the largest entry is
        // too small to divide by.
        let tiny = scale * 1e-26;
        let threshold = threshold * threshold;
        let zero = T::default();
        let stride = self.stride();
        // Row swaps can fill U up to kl columns past ku.
        let reach = kl + ku;
        let diagonal = reach;
        self.pivots.clear();
        self.inverse_diagonal.clear();
        self.widths.clear();
        let mut largest_pivot = 0.0f64;
        for j in 0..n {
            // U's column j (rows above the diagonal) is final: every row
            // above has been a pivot row.
            let column = &self.band[j * stride..(j + 1) * stride];
            let above = (1..=reach.min(j))
                .rev()
                .find(|&k| column[diagonal - k] != zero)
                .unwrap_or(0);
            let last_row = (j + kl).min(n - 1);
            let on_diagonal = self.band[self.slot(j, j)].magnitude_squared();
            let (mut pivot, mut best) = (j, on_diagonal);
            for i in j + 1..=last_row {
                let m = self.band[self.slot(i, j)].magnitude_squared();
                if m > best {
                    best = m;
                    pivot = i;
                }
            }
            if on_diagonal >= threshold * best {
                (pivot, best) = (j, on_diagonal);
            }
            if best.is_nan() || best <= tiny {
                return false;
            }
            largest_pivot = larger(largest_pivot, best);
            self.pivots.push(pivot as u32);
            let last_col = (j + reach).min(n - 1);
            if pivot != j {
                for c in j..=last_col {
                    let (a, b) = (self.slot(j, c), self.slot(pivot, c));
                    self.band.swap(a, b);
                }
            }
            let inverse = self.band[self.slot(j, j)].reciprocal();
            self.inverse_diagonal.push(inverse);
            // Column j's multipliers, then each later column's rows below
            // the diagonal: both contiguous in the band layout.
            let rows = last_row - j;
            let (head, tail) = self.band.split_at_mut((j + 1) * stride);
            let factors = &mut head[j * stride + diagonal + 1..][..rows];
            for factor in factors.iter_mut() {
                *factor = factor.times(inverse);
            }
            let below = (1..=rows)
                .rev()
                .find(|&k| factors[k - 1] != zero)
                .unwrap_or(0);
            self.widths
                .push((below.max(pivot - j).max(1), above.max(1)));
            for (c, column) in (j + 1..=last_col).zip(tail.chunks_exact_mut(stride)) {
                let above = diagonal + j - c;
                let top = column[above];
                if top == T::default() {
                    continue;
                }
                for (entry, &factor) in column[above + 1..][..rows].iter_mut().zip(&*factors) {
                    *entry = *entry - factor.times(top);
                }
            }
        }
        let column = |j: usize| &self.band[j * stride..(j + 1) * stride];
        let mut lower_runs = std::mem::take(&mut self.lower_runs);
        let mut upper_runs = std::mem::take(&mut self.upper_runs);
        let swapped = |j: usize| self.pivots[j] as usize != j;
        runs_of(
            self.widths
                .iter()
                .enumerate()
                .map(|(j, w)| (w.0, swapped(j))),
            &mut lower_runs,
        );
        runs_of(self.widths.iter().map(|w| (w.1, false)), &mut upper_runs);
        // The factors' largest entry, for the growth check: L's, and U's
        // before its rows are scaled (the diagonal is `largest_pivot`).
        let mut largest = [largest_pivot, 0.0];
        let mut lower = std::mem::take(&mut self.lower);
        let mut upper = std::mem::take(&mut self.upper);
        lower.clear();
        upper.clear();
        for run in &lower_runs {
            for j in run.start..run.end {
                let c = column(j);
                for k in 1..=run.width {
                    let entry = if j + k < n && k <= kl {
                        c[diagonal + k]
                    } else {
                        zero
                    };
                    largest[0] = larger(largest[0], entry.magnitude_squared());
                    lower.push(entry);
                }
            }
        }
        for run in &upper_runs {
            for j in run.start..run.end {
                let c = column(j);
                // U's rows are scaled by their diagonal's reciprocal (D⁻¹U
                // has a unit diagonal), so the back substitution's chain
                // from one unknown to the next is one multiply-subtract,
                // not two.
                for k in 1..=run.width {
                    upper.push(if k <= j && k <= reach {
                        let entry = c[diagonal - k];
                        largest[1] = larger(largest[1], entry.magnitude_squared());
                        self.inverse_diagonal[j - k].times(entry)
                    } else {
                        zero
                    });
                }
            }
        }
        self.lower = lower;
        self.upper = upper;
        self.lower_runs = lower_runs;
        self.upper_runs = upper_runs;
        // Growth fails threshold pivoting (partial pivoting bounds it); a
        // NaN fails at its pivot.
        let largest = largest[0].max(largest[1]);
        threshold >= 1.0 || (largest.is_finite() && largest <= scale * 1e12)
    }

    /// Solves `A x = b` in place with the factors, run by run. Within a
    /// run each sweep carries the next unknowns in a window of registers
    /// (as wide as the run's columns), so the chain from one unknown to the
    /// next is one multiply-subtract with no store and load between; the
    /// window goes back to `b` at the run's end.
    fn solve(&self, b: &mut [DVec2]) {
        macro_rules! sweep {
            ($f:ident, $wide:ident, $run:expr) => {
                match $run.width {
                    1 => self.$f::<1>(b, $run),
                    2 => self.$f::<2>(b, $run),
                    3 => self.$f::<3>(b, $run),
                    4 => self.$f::<4>(b, $run),
                    5 => self.$f::<5>(b, $run),
                    6 => self.$f::<6>(b, $run),
                    7 => self.$f::<7>(b, $run),
                    WIDEST => self.$f::<WIDEST>(b, $run),
                    _ => self.$wide(b, $run),
                }
            };
        }
        for run in &self.lower_runs {
            sweep!(forward, forward_wide, run);
        }
        for run in self.upper_runs.iter().rev() {
            sweep!(backward, backward_wide, run);
        }
    }
    /// Forward substitution with L (and the row swaps) over one run,
    /// leaving `D⁻¹y`.
    fn forward<const W: usize>(&self, b: &mut [DVec2], run: &Run) {
        if run.swaps {
            self.forward_with::<W, true>(b, run)
        } else {
            self.forward_with::<W, false>(b, run)
        }
    }

    /// Without swaps (`SWAPS` false, a constant) the window is only indexed
    /// by constants, so it stays in registers.
    fn forward_with<const W: usize, const SWAPS: bool>(&self, b: &mut [DVec2], run: &Run) {
        let mut w = [DVec2::ZERO; WIDEST + 1];
        for (k, slot) in w.iter_mut().enumerate().take(W + 1) {
            *slot = b.get(run.start + k).copied().unwrap_or(DVec2::ZERO);
        }
        let lower = &self.lower[run.offset..run.offset + W * (run.end - run.start)];
        for (j, column) in (run.start..run.end).zip(lower.chunks_exact(W)) {
            let p = self.pivots[j] as usize;
            if SWAPS && p != j {
                w.swap(0, p - j);
            }
            let x = w[0];
            for k in 0..W {
                w[k] = w[k + 1] - column[k].apply(x);
            }
            w[W] = b.get(j + W + 1).copied().unwrap_or(DVec2::ZERO);
            b[j] = self.inverse_diagonal[j].apply(x);
        }
        for (k, &value) in w.iter().enumerate().take(W) {
            if let Some(slot) = b.get_mut(run.end + k) {
                *slot = value;
            }
        }
    }

    /// Back substitution with the row-scaled U over one run.
    fn backward<const W: usize>(&self, b: &mut [DVec2], run: &Run) {
        let mut w = [DVec2::ZERO; WIDEST + 1];
        let last = run.end - 1;
        for (k, slot) in w.iter_mut().enumerate().take(W + 1) {
            *slot = if k <= last { b[last - k] } else { DVec2::ZERO };
        }
        let upper = &self.upper[run.offset..run.offset + W * (run.end - run.start)];
        for (j, column) in (run.start..run.end).zip(upper.chunks_exact(W)).rev() {
            let x = w[0];
            for k in 0..W {
                w[k] = w[k + 1] - column[k].apply(x);
            }
            w[W] = if j > W { b[j - W - 1] } else { DVec2::ZERO };
            b[j] = x;
        }
        for (k, &value) in w.iter().enumerate().take(W) {
            if k < run.start {
                b[run.start - 1 - k] = value;
            }
        }
    }

    /// Forward substitution through memory, for a run wider than [`WIDEST`].
    fn forward_wide(&self, b: &mut [DVec2], run: &Run) {
        let width = run.width;
        let lower = &self.lower[run.offset..run.offset + width * (run.end - run.start)];
        for (j, column) in (run.start..run.end).zip(lower.chunks_exact(width)) {
            let p = self.pivots[j] as usize;
            if p != j {
                b.swap(j, p);
            }
            let x = b[j];
            for (out, factor) in b[j + 1..].iter_mut().zip(column) {
                *out -= factor.apply(x);
            }
            b[j] = self.inverse_diagonal[j].apply(x);
        }
    }

    /// Back substitution through memory, for a run wider than [`WIDEST`].
    fn backward_wide(&self, b: &mut [DVec2], run: &Run) {
        let width = run.width;
        let upper = &self.upper[run.offset..run.offset + width * (run.end - run.start)];
        for (j, column) in (run.start..run.end).zip(upper.chunks_exact(width)).rev() {
            let x = b[j];
            for (k, factor) in column.iter().enumerate() {
                if k < j {
                    b[j - 1 - k] -= factor.apply(x);
                }
            }
        }
    }
}

/// The largest squared magnitude among `entries` (NaNs are passed over:
/// a NaN pivot fails on its own), with four running maxima: one would
/// chain every comparison on the last.
fn largest_magnitude<T: Entry>(entries: &[T]) -> f64 {
    let mut largest = [0.0f64; 4];
    let chunks = entries.chunks_exact(4);
    for e in chunks.remainder() {
        largest[0] = larger(largest[0], e.magnitude_squared());
    }
    for chunk in chunks {
        for (l, e) in largest.iter_mut().zip(chunk) {
            *l = larger(*l, e.magnitude_squared());
        }
    }
    largest.into_iter().fold(0.0, larger)
}

/// `a.max(b)` for a non-NaN `a`, without `f64::max`'s NaN handling (one
/// instruction instead of four).
#[inline]
fn larger(a: f64, b: f64) -> f64 {
    if b > a { b } else { a }
}

/// Threshold pivoting's ratio: a diagonal at least this fraction of its
/// column's largest entry is kept (growth per column at most `1 + 1/0.1`).
const PIVOT_THRESHOLD: f64 = 0.1;

/// The widest factor columns solved in registers.
const WIDEST: usize = 8;

/// A handle as a constraint row `w₀ v[p₀] + w₁ v[p₁] = q`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Constraint {
    anchor: CurveAnchor,
    points: [usize; 2],
    weights: [f64; 2],
    rest_point: DVec2,
    /// Index into the caller's targets.
    target: usize,
    /// Row of its multiplier in the KKT systems.
    slot: usize,
}

/// How the curve is placed for its current handle set.
#[derive(Debug, Clone, Copy)]
enum Placement {
    /// No handle and nothing fixed: the rigid placement written at compile.
    Still,
    /// One handle and nothing fixed: the rest curve rotated by `rotation`
    /// (cos, sin), carried by the handle.
    Carried { rotation: DVec2 },
    /// Solved through the KKT systems.
    Solved,
}

/// A registered rest curve and its compiled handle set. See the module docs
/// for the phases.
#[derive(Debug)]
pub struct Curve {
    rest: Vec<DVec2>,
    /// Arc length of every rest point from point 0.
    arc: Vec<f64>,
    /// `zᵢ` for interior points (index `i`; entries 0 and n−1 unused).
    frames: Vec<DVec2>,
    rest_lengths: Vec<f64>,
    pose: Vec<DVec2>,
    /// Two handles closer than this in rest space are the same handle.
    same_point: f64,
    placement: Placement,
    handle_count: usize,
    constraints: Vec<Constraint>,
    /// The free points, `lo..=hi`; the rest stay where compile found them.
    lo: usize,
    hi: usize,
    /// KKT row of free point `lo + k`.
    point_slot: Vec<usize>,
    step1: BandLu<DVec2>,
    step2: BandLu<f64>,
    /// Right-hand sides' parts fixed at compile time (the fixed points'
    /// pull), copied into `rhs` every frame.
    step1_base: Vec<DVec2>,
    step2_base: Vec<DVec2>,
    rhs: Vec<DVec2>,
    /// The step-1 curve, fixed points included.
    scale_free: Vec<DVec2>,
}

/// Validates a rest polyline: enough points, finite, no zero-length
/// segment, no fold-back, no self-intersection.
pub fn validate(points: &[DVec2]) -> Result<(), CurveError> {
    if points.len() < 3 {
        return Err(CurveError::TooFewPoints {
            count: points.len(),
        });
    }
    if let Some(point) = points
        .iter()
        .position(|p| !(p.is_finite() && p.abs().max_element() <= MAX_COORDINATE))
    {
        return Err(CurveError::PointNotFinite { point });
    }
    if let Some(w) = points.windows(2).position(|w| w[0] == w[1]) {
        return Err(CurveError::RepeatedPoint {
            point: w + 1,
            previous: w,
        });
    }
    for i in 1..points.len() - 1 {
        let (a, b) = (points[i] - points[i - 1], points[i + 1] - points[i]);
        // Segments meeting at i overlap when they turn back along one line.
        if a.perp_dot(b).abs() <= 1e-12 * a.length() * b.length() && a.dot(b) < 0.0 {
            return Err(CurveError::FoldsBack { point: i });
        }
    }
    if let Some((first, second)) = first_crossing(points) {
        return Err(CurveError::SelfIntersection { first, second });
    }
    Ok(())
}

/// Sign of the turn `a → b → c`, exactly zero when collinear.
#[inline]
fn orientation(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - a)
}

/// Whether closed segments `a–b` and `c–d` share a point.
fn segments_meet(a: DVec2, b: DVec2, c: DVec2, d: DVec2) -> bool {
    let within = |p: DVec2, q: DVec2, r: DVec2| {
        r.x >= p.x.min(q.x) && r.x <= p.x.max(q.x) && r.y >= p.y.min(q.y) && r.y <= p.y.max(q.y)
    };
    let (o1, o2) = (orientation(a, b, c), orientation(a, b, d));
    let (o3, o4) = (orientation(c, d, a), orientation(c, d, b));
    if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
        return true;
    }
    (o1 == 0.0 && within(a, b, c))
        || (o2 == 0.0 && within(a, b, d))
        || (o3 == 0.0 && within(c, d, a))
        || (o4 == 0.0 && within(c, d, b))
}

/// The lowest pair of non-adjacent segments that meet, if any. Segments are
/// binned in a uniform grid of about the mean segment length (capped at
/// ~4n cells), so only segments sharing a cell are tested.
fn first_crossing(points: &[DVec2]) -> Option<(usize, usize)> {
    let segments = points.len() - 1;
    let (mut min, mut max) = (points[0], points[0]);
    for p in points {
        min = min.min(*p);
        max = max.max(*p);
    }
    let total: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
    let extent = (max - min).max(DVec2::splat(f64::MIN_POSITIVE));
    let cap = (2.0 * (segments as f64).sqrt()).ceil() + 1.0;
    let cell = (total / segments as f64).max(extent.max_element() / cap);
    let columns = ((extent.x / cell).floor() as usize + 1).max(1);
    let rows = ((extent.y / cell).floor() as usize + 1).max(1);
    let cell_of = |p: DVec2| -> (usize, usize) {
        let c = ((p - min) / cell).floor();
        (
            (c.x.max(0.0) as usize).min(columns - 1),
            (c.y.max(0.0) as usize).min(rows - 1),
        )
    };
    let covered = |s: usize| {
        let (a, b) = (cell_of(points[s]), cell_of(points[s + 1]));
        let (x0, x1) = (a.0.min(b.0), a.0.max(b.0));
        let (y0, y1) = (a.1.min(b.1), a.1.max(b.1));
        (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| y * columns + x))
    };
    // Counting sort of (cell, segment) pairs.
    let mut starts = vec![0u32; columns * rows + 1];
    for s in 0..segments {
        for c in covered(s) {
            starts[c + 1] += 1;
        }
    }
    for c in 0..columns * rows {
        starts[c + 1] += starts[c];
    }
    let mut fill = starts.clone();
    let mut members = vec![0u32; starts[columns * rows] as usize];
    for s in 0..segments {
        for c in covered(s) {
            members[fill[c] as usize] = s as u32;
            fill[c] += 1;
        }
    }
    let mut found: Option<(usize, usize)> = None;
    for c in 0..columns * rows {
        let bin = &members[starts[c] as usize..starts[c + 1] as usize];
        for (k, &i) in bin.iter().enumerate() {
            for &j in &bin[k + 1..] {
                let (i, j) = (i.min(j) as usize, i.max(j) as usize);
                if j < i + 2 || found.is_some_and(|f| f <= (i, j)) {
                    continue;
                }
                if segments_meet(points[i], points[i + 1], points[j], points[j + 1]) {
                    found = Some((i, j));
                }
            }
        }
    }
    found
}

/// The polyline resampled to evenly spaced points along its length, as the
/// paper recommends (§6: with uneven spacing dense regions come out softer).
/// Keeps both ends; the spacing is adjusted down so every segment has the
/// same length, at most `spacing`.
pub fn resample_evenly(points: &[DVec2], spacing: f64) -> Result<Vec<DVec2>, CurveError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(CurveError::BadSpacing { spacing });
    }
    if points.len() < 2 {
        return Err(CurveError::TooFewPoints {
            count: points.len(),
        });
    }
    if let Some(point) = points.iter().position(|p| !p.is_finite()) {
        return Err(CurveError::PointNotFinite { point });
    }
    let total: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
    if total == 0.0 {
        return Err(CurveError::RepeatedPoint {
            point: 1,
            previous: 0,
        });
    }
    let count = (total / spacing).ceil().max(1.0) as usize;
    let step = total / count as f64;
    let mut out = Vec::with_capacity(count + 1);
    out.push(points[0]);
    let mut segment = 0;
    let mut start_arc = 0.0;
    for k in 1..count {
        let want = step * k as f64;
        loop {
            let length = points[segment].distance(points[segment + 1]);
            if start_arc + length >= want || segment + 2 == points.len() {
                let t = if length > 0.0 {
                    ((want - start_arc) / length).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                out.push(points[segment].lerp(points[segment + 1], t));
                break;
            }
            start_arc += length;
            segment += 1;
        }
    }
    out.push(*points.last().expect("at least two points"));
    Ok(out)
}

/// Best rotation (cos, sin) taking `rest` onto `pose` about their centroids,
/// and the two centroids; identity when undetermined.
fn fit_rotation(rest: &[DVec2], pose: &[DVec2]) -> (DVec2, DVec2, DVec2) {
    let count = rest.len() as f64;
    let rest_mean = rest.iter().copied().sum::<DVec2>() / count;
    let pose_mean = pose.iter().copied().sum::<DVec2>() / count;
    let (mut dot, mut crs) = (0.0, 0.0);
    for (r, p) in rest.iter().zip(pose) {
        let (r, p) = (*r - rest_mean, *p - pose_mean);
        dot += r.dot(p);
        crs += r.perp_dot(p);
    }
    let norm = (dot * dot + crs * crs).sqrt();
    let rotation = if norm > 0.0 && norm.is_finite() {
        DVec2::new(dot, crs) / norm
    } else {
        DVec2::X
    };
    (rotation, rest_mean, pose_mean)
}

impl Curve {
    /// Registration: validates the rest polyline and computes its local
    /// frames and lengths. No handles; [`Curve::pose`] is the rest curve.
    pub fn register(points: &[DVec2]) -> Result<Curve, CurveError> {
        validate(points)?;
        let n = points.len();
        let mut frames = vec![DVec2::ZERO; n];
        for i in 1..n - 1 {
            frames[i] = div(points[i] - points[i - 1], points[i + 1] - points[i - 1]);
        }
        let rest_lengths: Vec<f64> = points.windows(2).map(|w| w[0].distance(w[1])).collect();
        let mut arc = Vec::with_capacity(n);
        arc.push(0.0);
        for l in &rest_lengths {
            arc.push(arc.last().expect("non-empty") + l);
        }
        let (min, max) = points.iter().fold((points[0], points[0]), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
        Ok(Curve {
            rest: points.to_vec(),
            same_point: (max - min).length() * 1e-9,
            arc,
            frames,
            rest_lengths,
            pose: points.to_vec(),
            placement: Placement::Still,
            handle_count: 0,
            constraints: Vec::new(),
            lo: 0,
            hi: n - 1,
            point_slot: Vec::new(),
            step1: BandLu::default(),
            step2: BandLu::default(),
            step1_base: Vec::new(),
            step2_base: Vec::new(),
            rhs: Vec::new(),
            scale_free: points.to_vec(),
        })
    }

    pub fn len(&self) -> usize {
        self.rest.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    pub fn rest(&self) -> &[DVec2] {
        &self.rest
    }

    /// The current deformed points.
    pub fn pose(&self) -> &[DVec2] {
        &self.pose
    }

    /// Puts the curve in a pose (undo, reset): one finite point per rest
    /// point. The compiled handles are dropped, since the points they fix
    /// have moved: compile again before the next update.
    pub fn set_pose(&mut self, points: &[DVec2]) -> Result<(), CurveError> {
        if points.len() != self.rest.len() {
            return Err(CurveError::TargetCount {
                expected: self.rest.len(),
                got: points.len(),
            });
        }
        if let Some(point) = points
            .iter()
            .position(|p| !(p.is_finite() && p.abs().max_element() <= MAX_COORDINATE))
        {
            return Err(CurveError::PointNotFinite { point });
        }
        self.pose.copy_from_slice(points);
        self.constraints.clear();
        self.placement = Placement::Still;
        self.handle_count = 0;
        Ok(())
    }

    /// The rest curve's arc length at each point (0 at point 0).
    pub fn arc_lengths(&self) -> &[f64] {
        &self.arc
    }

    /// The rest curve's total length.
    pub fn length(&self) -> f64 {
        *self.arc.last().expect("a curve has points")
    }

    /// The anchor at arc length `s` along the rest curve (clamped to the
    /// curve).
    pub fn anchor_at(&self, s: f64) -> CurveAnchor {
        let s = s.clamp(0.0, self.length());
        let segment = self
            .arc
            .partition_point(|&a| a <= s)
            .clamp(1, self.len() - 1)
            - 1;
        let t = ((s - self.arc[segment]) / self.rest_lengths[segment]).clamp(0.0, 1.0);
        CurveAnchor::Along {
            segment: segment as u32,
            t,
        }
    }

    /// Where `anchor` is on the current pose (`None` when out of range).
    pub fn pose_point(&self, anchor: CurveAnchor) -> Option<DVec2> {
        Self::point_on(&self.pose, anchor)
    }

    /// Where `anchor` is on the rest curve (`None` when out of range).
    pub fn rest_point(&self, anchor: CurveAnchor) -> Option<DVec2> {
        Self::point_on(&self.rest, anchor)
    }

    fn point_on(points: &[DVec2], anchor: CurveAnchor) -> Option<DVec2> {
        match anchor {
            CurveAnchor::Point(p) => points.get(p as usize).copied(),
            CurveAnchor::Along { segment, t } => {
                let s = segment as usize;
                Some(points.get(s)?.lerp(*points.get(s + 1)?, t))
            }
        }
    }

    /// Compilation with every point free: sets the handle set. Two handles on
    /// the same rest point: the later wins. With fewer than two handles the
    /// curve cannot be solved (rotation and scale are free): with one it
    /// takes its rest shape, rotated as its current pose best fits, and
    /// follows the handle; with none it stays in that rigid placement.
    pub fn compile(&mut self, anchors: &[CurveAnchor]) -> Result<(), CurveError> {
        self.compile_within(anchors, 0..=self.len() - 1)
    }

    /// Compilation with only the points `free` movable: the others stay
    /// where the current pose has them and act as handles. Every handle must
    /// hold at least one free point. The systems span only the free points,
    /// so a small interval compiles and updates in proportion.
    pub fn compile_within(
        &mut self,
        anchors: &[CurveAnchor],
        free: RangeInclusive<usize>,
    ) -> Result<(), CurveError> {
        let n = self.len();
        let (lo, hi) = (*free.start(), *free.end());
        if lo > hi || hi >= n {
            return Err(CurveError::BadFreeRange {
                start: lo,
                end: hi,
                count: n,
            });
        }
        let mut constraints = Vec::with_capacity(anchors.len());
        for (h, anchor) in anchors.iter().enumerate() {
            let (points, weights) = match *anchor {
                CurveAnchor::Point(p) => {
                    if p as usize >= n {
                        return Err(CurveError::PointOutOfRange {
                            handle: h,
                            point: p,
                            count: n,
                        });
                    }
                    ([p as usize; 2], [1.0, 0.0])
                }
                CurveAnchor::Along { segment, t } => {
                    if segment as usize >= n - 1 {
                        return Err(CurveError::SegmentOutOfRange {
                            handle: h,
                            segment,
                            count: n - 1,
                        });
                    }
                    if !(t.is_finite() && (0.0..=1.0).contains(&t)) {
                        return Err(CurveError::BadParameter { handle: h, t });
                    }
                    let s = segment as usize;
                    ([s, s + 1], [1.0 - t, t])
                }
            };
            let holds_free = points
                .iter()
                .zip(weights)
                .any(|(&p, w)| w != 0.0 && (lo..=hi).contains(&p));
            if !holds_free {
                return Err(CurveError::HandleFixed {
                    handle: h,
                    start: lo,
                    end: hi,
                });
            }
            let rest_point = self.rest[points[0]] * weights[0] + self.rest[points[1]] * weights[1];
            constraints.push(Constraint {
                anchor: *anchor,
                points,
                weights,
                rest_point,
                target: h,
                slot: 0,
            });
        }
        // The later of two handles on one rest point wins.
        let mut live = vec![true; constraints.len()];
        for later in (0..constraints.len()).rev() {
            if !live[later] {
                continue;
            }
            for earlier in 0..later {
                if live[earlier]
                    && constraints[earlier]
                        .rest_point
                        .distance(constraints[later].rest_point)
                        <= self.same_point
                {
                    live[earlier] = false;
                }
            }
        }
        let mut kept = live.iter();
        constraints.retain(|_| *kept.next().expect("one flag per constraint"));
        // Multipliers go right after the last free point they hold.
        let last_free = |c: &Constraint| {
            c.points
                .iter()
                .zip(c.weights)
                .filter(|&(&p, w)| w != 0.0 && (lo..=hi).contains(&p))
                .map(|(&p, _)| p)
                .max()
                .expect("checked: holds a free point")
        };
        constraints.sort_by_key(|c| (last_free(c), c.target));

        self.handle_count = anchors.len();
        self.lo = lo;
        self.hi = hi;
        let everything_free = lo == 0 && hi == n - 1;
        if everything_free && constraints.len() < 2 {
            let (rotation, rest_mean, pose_mean) = fit_rotation(&self.rest, &self.pose);
            self.placement = match constraints.first() {
                None => {
                    for (p, r) in self.pose.iter_mut().zip(&self.rest) {
                        *p = pose_mean + rotation.rotate(*r - rest_mean);
                    }
                    Placement::Still
                }
                Some(_) => Placement::Carried { rotation },
            };
            self.constraints = constraints;
            return Ok(());
        }

        // Number the unknowns.
        self.point_slot.clear();
        let mut next = 0;
        let mut c = 0;
        for p in lo..=hi {
            self.point_slot.push(next);
            next += 1;
            while c < constraints.len() && last_free(&constraints[c]) == p {
                constraints[c].slot = next;
                next += 1;
                c += 1;
            }
        }
        let size = next;
        self.constraints = constraints;
        self.placement = Placement::Solved;
        self.scale_free.copy_from_slice(&self.pose);

        let slot =
            |p: usize| -> Option<usize> { (lo..=hi).contains(&p).then(|| self.point_slot[p - lo]) };
        // Bandwidths from the couplings: step 1 couples points two apart,
        // step 2 neighbours; both couple each multiplier with its points.
        let mut width1 = 0;
        let mut width2 = 0;
        for p in lo..=hi {
            for q in p + 1..=(p + 2).min(hi) {
                let d = self.point_slot[q - lo] - self.point_slot[p - lo];
                width1 = width1.max(d);
                if q == p + 1 {
                    width2 = width2.max(d);
                }
            }
        }
        for con in &self.constraints {
            for (&p, w) in con.points.iter().zip(con.weights) {
                if let (Some(s), true) = (slot(p), w != 0.0) {
                    width1 = width1.max(s.abs_diff(con.slot));
                    width2 = width2.max(s.abs_diff(con.slot));
                }
            }
        }

        self.rhs.clear();
        self.rhs.resize(size, DVec2::ZERO);
        // Each system is factored first with threshold pivoting, then (on
        // growth) partial pivoting; a failed try assembles the system again
        // rather than keep a copy of every band.
        let mut factored = [false; 2];
        for threshold in [PIVOT_THRESHOLD, 1.0] {
            let pending = factored.map(|done| !done);
            self.assemble(size, [width1, width2], pending);
            if pending[0] {
                factored[0] = self.step1.factor_with(threshold);
            }
            if pending[1] {
                factored[1] = self.step2.factor_with(threshold);
            }
            if factored == [true; 2] {
                break;
            }
        }
        let factored = if !factored[0] {
            Err(CurveError::Underdetermined { step: 1 })
        } else if !factored[1] {
            Err(CurveError::Underdetermined { step: 2 })
        } else {
            Ok(())
        };
        if let Err(e) = factored {
            // Keep the curve where it is rather than half-compiled.
            self.constraints.clear();
            self.placement = Placement::Still;
            self.handle_count = anchors.len();
            return Err(e);
        }
        Ok(())
    }

    /// Fills both systems and their fixed right-hand sides for the free
    /// points `lo..=hi` and the constraints, numbered as `point_slot` says.
    fn assemble(&mut self, size: usize, widths: [usize; 2], which: [bool; 2]) {
        let (lo, hi, n) = (self.lo, self.hi, self.len());
        let [width1, width2] = widths;
        let slot =
            |p: usize| -> Option<usize> { (lo..=hi).contains(&p).then(|| self.point_slot[p - lo]) };
        // Step 1: Σᵢ |γᵢ·(vᵢ₋₁, vᵢ, vᵢ₊₁)|² with γ = (z − 1, 1, −z).
        if which[0] {
            self.step1.reset(size, width1, width1);
            self.step1_base.clear();
            self.step1_base.resize(size, DVec2::ZERO);
        }
        let first_term = lo.saturating_sub(1).max(1);
        let last_term = (hi + 1).min(n - 2);
        let (stride, diagonal) = (self.step1.stride(), self.step1.kl + self.step1.ku);
        let band = &mut self.step1.band;
        for i in (first_term..=last_term).filter(|_| which[0]) {
            let z = self.frames[i];
            let gamma = [z - DVec2::X, DVec2::X, -z];
            let points = [i - 1, i, i + 1];
            let slots = points.map(slot);
            for r in 0..3 {
                let Some(row) = slots[r] else { continue };
                for s in 0..3 {
                    let value = mul(conj(gamma[r]), gamma[s]);
                    match slots[s] {
                        // The band's slot(row, col), without re-reading the
                        // layout from the matrix for every entry.
                        Some(col) => {
                            let entry = &mut band[col * stride + diagonal + row - col];
                            *entry += value;
                        }
                        None => self.step1_base[row] -= mul(value, self.pose[points[s]]),
                    }
                }
            }
        }
        // Step 2: Σₛ |vₛ₊₁ − vₛ − fₛ|² over segments with a free end.
        if which[1] {
            self.step2.reset(size, width2, width2);
            self.step2_base.clear();
            self.step2_base.resize(size, DVec2::ZERO);
        }
        for s in (lo.saturating_sub(1)..=hi.min(n - 2)).filter(|_| which[1]) {
            let ends = [s, s + 1];
            let coefficient = [-1.0, 1.0];
            for r in 0..2 {
                let Some(row) = slot(ends[r]) else { continue };
                for k in 0..2 {
                    let value: f64 = coefficient[r] * coefficient[k];
                    match slot(ends[k]) {
                        Some(col) => self.step2.add(row, col, value),
                        None => self.step2_base[row] -= self.pose[ends[k]] * value,
                    }
                }
            }
        }
        for con in &self.constraints {
            for (&p, w) in con.points.iter().zip(con.weights) {
                if w == 0.0 {
                    continue;
                }
                match slot(p) {
                    Some(s) if which[0] || which[1] => {
                        if which[1] {
                            self.step2.add(con.slot, s, w);
                            self.step2.add(s, con.slot, w);
                        }
                        if which[0] {
                            let w = DVec2::new(w, 0.0);
                            self.step1.add(con.slot, s, w);
                            self.step1.add(s, con.slot, w);
                        }
                    }
                    Some(_) => {}
                    None => {
                        if which[0] {
                            self.step1_base[con.slot] -= self.pose[p] * w;
                        }
                        if which[1] {
                            self.step2_base[con.slot] -= self.pose[p] * w;
                        }
                    }
                }
            }
        }
    }

    /// Update: moves the compiled handles to `targets` (same order as the
    /// anchors given to compile) and recomputes the pose. Does not allocate.
    pub fn update(&mut self, targets: &[DVec2], steps: Steps) -> Result<&[DVec2], CurveError> {
        if targets.len() != self.handle_count {
            return Err(CurveError::TargetCount {
                expected: self.handle_count,
                got: targets.len(),
            });
        }
        if let Some(handle) = targets
            .iter()
            .position(|t| !(t.is_finite() && t.abs().max_element() <= MAX_COORDINATE))
        {
            return Err(CurveError::TargetNotFinite { handle });
        }
        match self.placement {
            Placement::Still => {}
            Placement::Carried { rotation } => {
                let handle = &self.constraints[0];
                let to = targets[handle.target];
                for (p, r) in self.pose.iter_mut().zip(&self.rest) {
                    *p = to + rotation.rotate(*r - handle.rest_point);
                }
            }
            Placement::Solved => self.solve(targets, steps),
        }
        Ok(&self.pose)
    }

    fn solve(&mut self, targets: &[DVec2], steps: Steps) {
        let (lo, hi, n) = (self.lo, self.hi, self.len());
        self.rhs.copy_from_slice(&self.step1_base);
        for con in &self.constraints {
            self.rhs[con.slot] += targets[con.target];
        }
        self.step1.solve(&mut self.rhs);
        for (p, &s) in (lo..=hi).zip(&self.point_slot) {
            self.scale_free[p] = self.rhs[s];
        }
        if steps == Steps::ScaleFree {
            self.pose[lo..=hi].copy_from_slice(&self.scale_free[lo..=hi]);
            return;
        }
        self.rhs.copy_from_slice(&self.step2_base);
        for con in &self.constraints {
            self.rhs[con.slot] += targets[con.target];
        }
        // fₛ: the step-1 segment's direction at the rest segment's length.
        for s in lo.saturating_sub(1)..=hi.min(n - 2) {
            let d = self.scale_free[s + 1] - self.scale_free[s];
            let length = d.length();
            let f = if length > 0.0 {
                d * (self.rest_lengths[s] / length)
            } else {
                // A collapsed step-1 segment has no direction: keep rest.
                self.rest[s + 1] - self.rest[s]
            };
            // s runs from lo − 1 to at most hi: its start point is free
            // from lo on, its end point up to hi.
            if s >= lo {
                self.rhs[self.point_slot[s - lo]] -= f;
            }
            if s < hi {
                self.rhs[self.point_slot[s + 1 - lo]] += f;
            }
        }
        self.step2.solve(&mut self.rhs);
        for (p, &s) in (lo..=hi).zip(&self.point_slot) {
            self.pose[p] = self.rhs[s];
        }
    }

    /// The free points of the compiled system.
    pub fn free_points(&self) -> RangeInclusive<usize> {
        self.lo..=self.hi
    }

    /// The compiled handles that are in effect, in the caller's numbering.
    pub fn live_handles(&self) -> impl Iterator<Item = (usize, CurveAnchor)> + '_ {
        self.constraints.iter().map(|c| (c.target, c.anchor))
    }
}

/// How the peeled region grows: radius `initial_radius + growth_rate · d`
/// (arc length) for drag distance `d`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeelParams {
    pub initial_radius: f64,
    pub growth_rate: f64,
}

impl Default for PeelParams {
    /// The region starts with the grabbed segment and reaches a little
    /// further than the finger has travelled.
    fn default() -> Self {
        PeelParams {
            initial_radius: 0.0,
            growth_rate: 1.5,
        }
    }
}

/// The peeling interface (the paper's Figure 12): one drag's influence
/// region along the rest curve. It grows with the largest drag distance so
/// far (never shrinks during a drag), stops at the nearest virtual pushpin on
/// either side and at the curve's ends. Points outside it stay put.
#[derive(Debug, Clone)]
pub struct Peel {
    params: PeelParams,
    grab: f64,
    grab_anchor: CurveAnchor,
    /// The region may not pass these arc lengths (pushpins or the ends).
    limits: (f64, f64),
    /// Whether each limit is an end of the curve (which then moves too).
    open_ends: (bool, bool),
    largest_drag: f64,
    region: (f64, f64),
    free: RangeInclusive<usize>,
}

impl Peel {
    /// A drag grabbing `curve` at arc length `grab` (rest curve), with
    /// pushpins at the given arc lengths. Allocates nothing afterwards.
    pub fn new(
        curve: &Curve,
        grab: f64,
        pushpins: &[f64],
        params: PeelParams,
    ) -> Result<Peel, CurveError> {
        for (field, value) in [
            ("initial_radius", params.initial_radius),
            ("growth_rate", params.growth_rate),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(CurveError::BadPeelParameter { field, value });
            }
        }
        let length = curve.length();
        if !(grab.is_finite() && (0.0..=length).contains(&grab)) {
            return Err(CurveError::GrabOffCurve { at: grab, length });
        }
        let (mut below, mut above) = (0.0, length);
        let (mut open_below, mut open_above) = (true, true);
        for (pushpin, &at) in pushpins.iter().enumerate() {
            if !(at.is_finite() && (0.0..=length).contains(&at)) {
                return Err(CurveError::PushpinOffCurve {
                    pushpin,
                    at,
                    length,
                });
            }
            if at == grab {
                return Err(CurveError::PushpinAtGrab { pushpin });
            }
            if at < grab && (at > below || open_below) {
                below = at;
                open_below = false;
            }
            if at > grab && (at < above || open_above) {
                above = at;
                open_above = false;
            }
        }
        let mut peel = Peel {
            params,
            grab,
            grab_anchor: curve.anchor_at(grab),
            limits: (below, above),
            open_ends: (open_below, open_above),
            largest_drag: 0.0,
            region: (grab, grab),
            free: 0..=0,
        };
        peel.free = peel.free_for(curve, peel.region_for(0.0));
        peel.region = peel.region_for(0.0);
        Ok(peel)
    }

    /// The grabbed point, as a handle for [`Curve::compile_within`].
    pub fn grab_anchor(&self) -> CurveAnchor {
        self.grab_anchor
    }

    /// The drag moved `distance` from the grab point. Returns whether the
    /// free points changed (then compile again with [`Peel::free_points`]).
    pub fn drag(&mut self, curve: &Curve, distance: f64) -> Result<bool, CurveError> {
        if !(distance.is_finite() && distance >= 0.0) {
            return Err(CurveError::BadDragDistance { distance });
        }
        if distance <= self.largest_drag {
            return Ok(false);
        }
        self.largest_drag = distance;
        self.region = self.region_for(distance);
        let free = self.free_for(curve, self.region);
        let changed = free != self.free;
        self.free = free;
        Ok(changed)
    }

    /// The influence region as arc lengths along the rest curve.
    pub fn region(&self) -> (f64, f64) {
        self.region
    }

    /// The points the region frees.
    pub fn free_points(&self) -> RangeInclusive<usize> {
        self.free.clone()
    }

    fn region_for(&self, distance: f64) -> (f64, f64) {
        let radius = self.params.initial_radius + self.params.growth_rate * distance;
        (
            (self.grab - radius).max(self.limits.0),
            (self.grab + radius).min(self.limits.1),
        )
    }

    /// Points strictly inside the region, the curve's ends once the region
    /// reaches them, and always the grabbed segment's ends, so the grab can
    /// move.
    fn free_for(&self, curve: &Curve, (below, above): (f64, f64)) -> RangeInclusive<usize> {
        let arc = curve.arc_lengths();
        let last = arc.len() - 1;
        let mut start = arc.partition_point(|&a| a <= below);
        if self.open_ends.0 && below <= 0.0 {
            start = 0;
        }
        let mut end = arc.partition_point(|&a| a < above).saturating_sub(1);
        if self.open_ends.1 && above >= arc[last] {
            end = last;
        }
        let (grab_first, grab_last) = match self.grab_anchor {
            CurveAnchor::Point(p) => (p as usize, p as usize),
            CurveAnchor::Along { segment, .. } => (segment as usize, segment as usize + 1),
        };
        start.min(grab_first)..=end.max(grab_last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic band matrix with zeros on some diagonal entries, so
    /// factoring must fall back to pivoting.
    fn band_matrix(n: usize, kl: usize, ku: usize) -> Vec<Vec<f64>> {
        let mut a = vec![vec![0.0; n]; n];
        for (i, row) in a.iter_mut().enumerate() {
            for (j, entry) in row.iter_mut().enumerate() {
                if j + kl >= i && i + ku >= j {
                    *entry = ((i * 7 + j * 13) % 11) as f64 - 5.0 + if i == j { 0.5 } else { 0.0 };
                }
            }
            if i % 4 == 0 {
                row[i] = 0.0;
            }
        }
        a
    }

    /// Factors `a` and solves it for a known `x`; returns the factors.
    fn solves(a: &[Vec<f64>], kl: usize, ku: usize) -> BandLu<f64> {
        let n = a.len();
        let mut lu = BandLu::<f64>::default();
        let assemble = |lu: &mut BandLu<f64>| {
            lu.reset(n, kl, ku);
            for (i, row) in a.iter().enumerate() {
                for (j, &v) in row.iter().enumerate() {
                    if v != 0.0 {
                        lu.add(i, j, v);
                    }
                }
            }
        };
        assemble(&mut lu);
        if !lu.factor_with(PIVOT_THRESHOLD) {
            assemble(&mut lu);
            assert!(lu.factor_with(1.0), "the matrix is nonsingular");
        }
        let x: Vec<DVec2> = (0..n)
            .map(|i| DVec2::new(i as f64 * 0.5 - 3.0, (i % 5) as f64))
            .collect();
        let mut b: Vec<DVec2> = a
            .iter()
            .map(|row| row.iter().zip(&x).map(|(&v, &xi)| xi * v).sum())
            .collect();
        lu.solve(&mut b);
        for (got, want) in b.iter().zip(&x) {
            assert!(got.distance(*want) < 1e-9, "{got} != {want}");
        }
        lu
    }

    fn swapped(lu: &BandLu<f64>) -> bool {
        lu.lower_runs.iter().any(|r| r.swaps)
    }

    fn widest(runs: &[Run]) -> usize {
        runs.iter().map(|r| r.width).max().unwrap_or(0)
    }

    #[test]
    fn a_matrix_that_needs_row_swaps_is_solved_in_registers_and_wide() {
        let lu = solves(&band_matrix(40, 2, 2), 2, 2);
        assert!(
            swapped(&lu) && widest(&lu.upper_runs) <= WIDEST,
            "pivoted, in registers"
        );
        let lu = solves(&band_matrix(40, 5, 5), 5, 5);
        assert!(
            swapped(&lu) && widest(&lu.upper_runs) > WIDEST,
            "pivoted, through memory"
        );
    }

    /// A tridiagonal matrix with two wider stretches (like a multiplier's
    /// row among its points) is packed in runs of different widths, and
    /// each run hands its window on to the next.
    #[test]
    fn a_matrix_of_varying_width_is_solved_run_by_run() {
        let n = 200;
        let mut a = vec![vec![0.0; n]; n];
        for i in 0..n {
            a[i][i] = 4.0 + (i % 3) as f64;
            if i + 1 < n {
                a[i][i + 1] = -1.0 - (i % 2) as f64 * 0.5;
                a[i + 1][i] = -1.0;
            }
        }
        for &(i, j) in &[(70, 73), (150, 154)] {
            a[i][j] = 0.7;
            a[j][i] = -0.4;
        }
        let lu = solves(&a, 4, 4);
        assert!(!swapped(&lu));
        for runs in [&lu.lower_runs, &lu.upper_runs] {
            let widths: Vec<usize> = runs.iter().map(|r| r.width).collect();
            assert!(widths.len() >= 3 && widths.contains(&1), "{widths:?}");
            assert!(widest(runs) >= 3, "{widths:?}");
            assert_eq!(runs.first().map(|r| r.start), Some(0));
            assert_eq!(runs.last().map(|r| r.end), Some(n));
            assert!(runs.windows(2).all(|w| w[0].end == w[1].start));
        }
    }
}
