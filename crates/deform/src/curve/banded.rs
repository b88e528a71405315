//! The banded solver of the curve deformer: a square banded matrix's LU
//! factors with partial pivoting in LAPACK's band layout, packed in runs so
//! the solves stream through about half the band, and the KKT system split
//! at a joint (`Split`) whose arms grow by appending to their eliminations
//! as a peel's region grows. Entries are complex numbers as (re, im) pairs
//! (step 1) or reals (step 2), through [`Entry`]. See the curve module's
//! doc for why the systems are banded and indefinite.

use glam::DVec2;

/// Complex multiplication on (re, im) pairs.
#[inline]
pub(super) fn mul(a: DVec2, b: DVec2) -> DVec2 {
    a.rotate(b)
}

#[inline]
pub(super) fn conj(a: DVec2) -> DVec2 {
    DVec2::new(a.x, -a.y)
}

#[inline]
pub(super) fn div(a: DVec2, b: DVec2) -> DVec2 {
    mul(a, conj(b)) / b.length_squared()
}

/// An entry of a banded system: a complex number as a (re, im) pair for
/// step 1, a real for step 2. Right-hand sides are always pairs: a complex
/// number, or for a real matrix the x and y of one point solved together.
pub(super) trait Entry:
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
pub(super) struct BandLu<T> {
    pub(super) n: usize,
    pub(super) kl: usize,
    pub(super) ku: usize,
    pub(super) band: Vec<T>,
    pub(super) pivots: Vec<u32>,
    /// Per column: reciprocal of U's diagonal.
    pub(super) inverse_diagonal: Vec<T>,
    /// L below the diagonal, per column rows `j + 1 ..` (zero-padded to
    /// its run's width): as wide as the column or its row swap, whichever
    /// is more.
    pub(super) lower: Vec<T>,
    pub(super) lower_runs: Vec<Run>,
    /// Per column while factoring: how far L reaches below the diagonal
    /// (or its row swap), and U above.
    pub(super) widths: Vec<(usize, usize)>,
    /// U above the diagonal with each row scaled by the reciprocal of its
    /// diagonal, per column rows `j − 1, j − 2, …` (nearest first,
    /// zero-padded to its run's width).
    pub(super) upper: Vec<T>,
    pub(super) upper_runs: Vec<Run>,
    /// The matrix's largest squared magnitude (pivots below 1e-13 of it
    /// are singular), and the factors' so far (the growth check).
    pub(super) scale: f64,
    pub(super) largest: f64,
    /// An arm of a [`Split`] system is bordered by the joint's `joint`
    /// unknowns, eliminated after it: `border_row[j·joint + a]` is joint
    /// row `a` in column `j` (while factoring, its Schur value; after, the
    /// value column `j` met, which times `j`'s solution is L's border
    /// term), `border_col[j·joint + a]` joint column `a` in row `j` (after
    /// factoring, U's border entry scaled like U's row), and `border_sum`
    /// what the arm's elimination takes off the joint block.
    pub(super) joint: usize,
    pub(super) border_row: Vec<T>,
    pub(super) border_col: Vec<T>,
    pub(super) border_sum: [[T; JOINT]; JOINT],
    /// What growing the matrix at its end needs: the state just before
    /// column `saved_at` was eliminated, the first column whose
    /// elimination reaches the last `kl + ku` rows or columns. Columns
    /// before it keep their factors when rows and columns are appended.
    pub(super) resumable: bool,
    pub(super) saved_at: usize,
    pub(super) saved_band: Vec<T>,
    pub(super) saved_row: Vec<T>,
    pub(super) saved_col: Vec<T>,
    pub(super) saved_sum: [[T; JOINT]; JOINT],
    pub(super) saved_largest: f64,
    /// Test only: grow as if the last columns' factors stayed valid (the
    /// mistake the growth test must catch).
    #[cfg(test)]
    pub(super) stale: bool,
}

/// The most unknowns a [`Split`] system's joint may have (its two points
/// and two handles' multipliers).
pub(super) const JOINT: usize = 4;

/// Columns `start..end` of a packed factor, `width` entries each from
/// `offset`, and whether a row was swapped at any of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Run {
    pub(super) start: usize,
    pub(super) end: usize,
    pub(super) width: usize,
    pub(super) offset: usize,
    pub(super) swaps: bool,
}

/// Runs are at least this many columns (but the last), so a factor whose
/// widths alternate does not pay a window reload every few columns.
pub(super) const SHORTEST_RUN: usize = 32;

/// Splits columns `from..` of the given widths (and whether each swaps a
/// row) into runs after `runs` (which end at `from`): a new run starts
/// where either changes, unless the current run is still short (then it
/// widens to take the column).
pub(super) fn runs_of(
    from: usize,
    columns: impl Iterator<Item = (usize, bool)>,
    runs: &mut Vec<Run>,
) {
    let first = runs.len();
    for (j, (width, swaps)) in (from..).zip(columns) {
        // A run packed before (cut back by a growth) only takes columns
        // like its own: a wider one would change its packing.
        let own = runs.len() > first;
        match runs.last_mut() {
            Some(run)
                if (run.width == width && run.swaps == swaps)
                    || (own && run.end - run.start < SHORTEST_RUN) =>
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
    let mut offset = first.checked_sub(1).map_or(0, |i| {
        runs[i].offset + runs[i].width * (runs[i].end - runs[i].start)
    });
    for run in &mut runs[first..] {
        run.offset = offset;
        offset += run.width * (run.end - run.start);
    }
}

/// Cuts packed runs back to the columns before `at`: the run holding `at`
/// ends there (keeping its width, which still covers its columns: zero
/// padding changes no solve), later runs go. Returns the packed length.
pub(super) fn truncate_runs(runs: &mut Vec<Run>, at: usize) -> usize {
    runs.retain(|r| r.start < at);
    match runs.last_mut() {
        Some(run) => {
            run.end = run.end.min(at);
            run.offset + run.width * (run.end - run.start)
        }
        None => 0,
    }
}

impl<T: Entry> BandLu<T> {
    /// Zeroes an `n`×`n` matrix with the given bandwidths, reusing storage;
    /// `joint` border unknowns (0: none), `resumable` to keep what growing
    /// needs.
    pub(super) fn reset_bordered(
        &mut self,
        n: usize,
        kl: usize,
        ku: usize,
        joint: usize,
        resumable: bool,
    ) {
        self.n = n;
        self.kl = kl;
        self.ku = ku;
        self.band.clear();
        self.band.resize(n * self.stride(), T::default());
        self.joint = joint;
        self.resumable = resumable;
        for border in [&mut self.border_row, &mut self.border_col] {
            border.clear();
            border.resize(n * joint, T::default());
        }
    }

    pub(super) fn reset(&mut self, n: usize, kl: usize, ku: usize) {
        self.reset_bordered(n, kl, ku, 0, false);
    }

    #[inline]
    pub(super) fn stride(&self) -> usize {
        2 * self.kl + self.ku + 1
    }

    /// Where entry (i, j) lives; `kl + ku` is the diagonal's place.
    #[inline]
    pub(super) fn slot(&self, i: usize, j: usize) -> usize {
        debug_assert!(i <= j + self.kl && j <= i + self.ku + self.kl);
        j * self.stride() + self.kl + self.ku + i - j
    }

    #[inline]
    pub(super) fn add(&mut self, i: usize, j: usize, value: T) {
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
    pub(super) fn factor_with(&mut self, threshold: f64) -> bool {
        self.scale = largest_magnitude(&self.band)
            .max(largest_magnitude(&self.border_row))
            .max(largest_magnitude(&self.border_col));
        self.largest = 0.0;
        self.border_sum = Default::default();
        self.lower_runs.clear();
        self.upper_runs.clear();
        self.eliminate(0, threshold)
    }

    /// Appends rows and columns up to `n` (a resumable matrix, same
    /// bandwidths): the band goes back to its state before column
    /// `saved_at` was eliminated, the new columns are zero. The caller then
    /// adds the entries in new rows or columns and calls [`BandLu::resume`].
    /// Returns the column elimination resumes at.
    pub(super) fn grow(&mut self, n: usize) -> usize {
        debug_assert!(self.resumable && n >= self.n);
        #[cfg(test)]
        if self.stale {
            let (old, stride, joint) = (self.n, self.stride(), self.joint);
            self.band.resize(n * stride, T::default());
            self.border_row.resize(n * joint, T::default());
            self.border_col.resize(n * joint, T::default());
            self.saved_band.clear();
            self.saved_sum = self.border_sum;
            self.saved_largest = self.largest;
            self.n = n;
            return old;
        }
        let (from, stride, joint) = (self.saved_at, self.stride(), self.joint);
        self.band.truncate(from * stride);
        self.band.extend_from_slice(&self.saved_band);
        self.band.resize(n * stride, T::default());
        self.border_row.truncate(from * joint);
        self.border_row.extend_from_slice(&self.saved_row);
        self.border_row.resize(n * joint, T::default());
        self.border_col.truncate(from * joint);
        self.border_col.extend_from_slice(&self.saved_col);
        self.border_col.resize(n * joint, T::default());
        self.n = n;
        from
    }

    /// Factors a grown matrix from column `from` (what [`BandLu::grow`]
    /// returned): the columns before keep their factors, the new entries'
    /// scale joins the old.
    pub(super) fn resume(&mut self, from: usize, threshold: f64) -> bool {
        let (stride, joint) = (self.stride(), self.joint);
        let fresh = from + self.saved_band.len() / stride.max(1);
        self.scale = self
            .scale
            .max(largest_magnitude(&self.band[fresh * stride..]))
            .max(largest_magnitude(&self.border_row[fresh * joint..]))
            .max(largest_magnitude(&self.border_col[fresh * joint..]));
        self.largest = self.saved_largest;
        self.border_sum = self.saved_sum;
        self.eliminate(from, threshold)
    }

    /// Eliminates columns `from..n` (the ones before are factored), then
    /// packs them.
    pub(super) fn eliminate(&mut self, from: usize, threshold: f64) -> bool {
        let n = self.n;
        let (kl, ku, joint) = (self.kl, self.ku, self.joint);
        // Squared magnitudes: a pivot below 1e-13 of the largest entry is
        // too small to divide by.
        let tiny = self.scale * 1e-26;
        let threshold = threshold * threshold;
        let zero = T::default();
        let stride = self.stride();
        // Row swaps can fill U up to kl columns past ku.
        let reach = kl + ku;
        let diagonal = reach;
        self.pivots.truncate(from);
        self.inverse_diagonal.truncate(from);
        self.widths.truncate(from);
        let save_at = n.saturating_sub(reach).max(from);
        let mut largest = self.largest;
        for j in from..=n {
            if j == save_at && self.resumable {
                self.saved_at = j;
                self.saved_band.clear();
                self.saved_band
                    .extend_from_slice(&self.band[j * stride..n * stride]);
                self.saved_row.clear();
                self.saved_row
                    .extend_from_slice(&self.border_row[j * joint..n * joint]);
                self.saved_col.clear();
                self.saved_col
                    .extend_from_slice(&self.border_col[j * joint..n * joint]);
                self.saved_sum = self.border_sum;
                self.saved_largest = largest;
            }
            if j == n {
                break;
            }
            // U's column j (rows above the diagonal) is final: every row
            // above has been a pivot row.
            let column = &self.band[j * stride..(j + 1) * stride];
            let mut above = 0;
            for k in 1..=reach.min(j) {
                let entry = column[diagonal - k];
                if entry != zero {
                    above = k;
                    largest = larger(largest, entry.magnitude_squared());
                }
            }
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
            largest = larger(largest, best);
            self.pivots.push(pivot as u32);
            let last_col = (j + reach).min(n - 1);
            if pivot != j {
                for c in j..=last_col {
                    let (a, b) = (self.slot(j, c), self.slot(pivot, c));
                    self.band.swap(a, b);
                }
                for a in 0..joint {
                    self.border_col.swap(j * joint + a, pivot * joint + a);
                }
            }
            let inverse = self.band[self.slot(j, j)].reciprocal();
            self.inverse_diagonal.push(inverse);
            // Column j's multipliers, then each later column's rows below
            // the diagonal: both contiguous in the band layout.
            let rows = last_row - j;
            let (head, tail) = self.band.split_at_mut((j + 1) * stride);
            let factors = &mut head[j * stride + diagonal + 1..][..rows];
            let mut below = 0;
            for (k, factor) in factors.iter_mut().enumerate() {
                *factor = factor.times(inverse);
                if *factor != zero {
                    below = k + 1;
                    largest = larger(largest, factor.magnitude_squared());
                }
            }
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
            if joint > 0 {
                self.eliminate_border(j, inverse, &mut largest);
            }
        }
        // Growth fails threshold pivoting (partial pivoting bounds it); a
        // NaN fails at its pivot.
        self.largest = largest;
        self.pack(from);
        threshold >= 1.0 || (largest.is_finite() && largest <= self.scale * 1e12)
    }

    /// Column `j`'s elimination of the border: the joint rows' values in
    /// column `j` (final now) times the pivot row update the joint rows
    /// further on, L's column updates the joint columns further down, and
    /// their product comes off the joint block.
    pub(super) fn eliminate_border(&mut self, j: usize, inverse: T, largest: &mut f64) {
        let (n, joint, stride) = (self.n, self.joint, self.stride());
        let diagonal = self.kl + self.ku;
        let last_row = (j + self.kl).min(n - 1);
        let last_col = (j + self.kl + self.ku).min(n - 1);
        // Joint rows in column j (ρ, kept: ρ·(D⁻¹y)ⱼ is L's border term in
        // a solve), their multipliers X = ρ/uⱼⱼ, and joint columns in row j
        // (Y, kept scaled like U's row).
        let mut row = [T::default(); JOINT];
        let mut col = [T::default(); JOINT];
        row[..joint].copy_from_slice(&self.border_row[j * joint..][..joint]);
        col[..joint].copy_from_slice(&self.border_col[j * joint..][..joint]);
        let multiplier = row.map(|r| r.times(inverse));
        let scaled = col.map(|c| inverse.times(c));
        for (m, c) in multiplier.iter().zip(&col) {
            *largest = larger(*largest, c.magnitude_squared());
            *largest = larger(*largest, m.magnitude_squared());
        }
        // X·Y = ρ·(Y/uⱼⱼ) comes off the joint block.
        for (sums, r) in self.border_sum.iter_mut().zip(&row).take(joint) {
            for (sum, y) in sums.iter_mut().zip(&scaled).take(joint) {
                *sum = *sum + r.times(*y);
            }
        }
        self.border_col[j * joint..][..joint].copy_from_slice(&scaled[..joint]);
        for c in j + 1..=last_col {
            // Row j of U in column c.
            let u = self.band[c * stride + diagonal + j - c];
            if u == T::default() {
                continue;
            }
            let entries = &mut self.border_row[c * joint..][..joint];
            for (entry, m) in entries.iter_mut().zip(&multiplier) {
                *entry = *entry - m.times(u);
            }
        }
        for i in j + 1..=last_row {
            let l = self.band[j * stride + diagonal + i - j];
            if l == T::default() {
                continue;
            }
            let entries = &mut self.border_col[i * joint..][..joint];
            for (entry, y) in entries.iter_mut().zip(&col) {
                *entry = *entry - l.times(*y);
            }
        }
    }

    /// Packs columns `from..n` of the factors after the runs before.
    pub(super) fn pack(&mut self, from: usize) {
        let (n, kl, stride) = (self.n, self.kl, self.stride());
        let reach = self.kl + self.ku;
        let diagonal = reach;
        let zero = T::default();
        let mut lower_runs = std::mem::take(&mut self.lower_runs);
        let mut upper_runs = std::mem::take(&mut self.upper_runs);
        let lower_len = truncate_runs(&mut lower_runs, from);
        let upper_len = truncate_runs(&mut upper_runs, from);
        let (first_lower, first_upper) = (lower_runs.len(), upper_runs.len());
        let swapped = |j: usize| self.pivots[j] as usize != j;
        runs_of(
            from,
            self.widths[from..]
                .iter()
                .enumerate()
                .map(|(k, w)| (w.0, swapped(from + k))),
            &mut lower_runs,
        );
        runs_of(
            from,
            self.widths[from..].iter().map(|w| (w.1, false)),
            &mut upper_runs,
        );
        let column = |j: usize| &self.band[j * stride..(j + 1) * stride];
        let mut lower = std::mem::take(&mut self.lower);
        let mut upper = std::mem::take(&mut self.upper);
        lower.truncate(lower_len);
        upper.truncate(upper_len);
        // From the run a growth cut back, which may have taken columns.
        for run in &lower_runs[first_lower.saturating_sub(1)..] {
            for j in run.start.max(from)..run.end {
                let c = column(j);
                for k in 1..=run.width {
                    lower.push(if j + k < n && k <= kl {
                        c[diagonal + k]
                    } else {
                        zero
                    });
                }
            }
        }
        for run in &upper_runs[first_upper.saturating_sub(1)..] {
            for j in run.start.max(from)..run.end {
                let c = column(j);
                // U's rows are scaled by their diagonal's reciprocal (D⁻¹U
                // has a unit diagonal), so the back substitution's chain
                // from one unknown to the next is one multiply-subtract,
                // not two.
                for k in 1..=run.width {
                    upper.push(if k <= j && k <= reach {
                        self.inverse_diagonal[j - k].times(c[diagonal - k])
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
    }

    /// Solves `A x = b` in place with the factors.
    pub(super) fn solve(&self, b: &mut [DVec2]) {
        let mut sums = [DVec2::ZERO; JOINT];
        self.forward_all(b, &mut sums);
        self.backward_all(b, &[DVec2::ZERO; JOINT]);
    }

    /// The forward substitution of a solve with the factors, run by run,
    /// leaving `D⁻¹y`; with a border, `sums[a]` gains joint row `a`'s
    /// `Σⱼ ρⱼ (D⁻¹y)ⱼ`. Within a run each sweep carries the next unknowns
    /// in a window of registers (as wide as the run's columns), so the
    /// chain from one unknown to the next is one multiply-subtract with no
    /// store and load between; the window goes back to `b` at the run's
    /// end. The border's sums are taken in the same sweep, off that chain.
    pub(super) fn forward_all(&self, b: &mut [DVec2], sums: &mut [DVec2; JOINT]) {
        match self.joint {
            0 => self.forward_runs::<0>(b, sums),
            1 => self.forward_runs::<1>(b, sums),
            2 => self.forward_runs::<2>(b, sums),
            3 => self.forward_runs::<3>(b, sums),
            _ => self.forward_runs::<JOINT>(b, sums),
        }
    }

    pub(super) fn forward_runs<const K: usize>(&self, b: &mut [DVec2], sums: &mut [DVec2; JOINT]) {
        for run in &self.lower_runs {
            match run.width {
                1 => self.forward::<1, K>(b, run, sums),
                2 => self.forward::<2, K>(b, run, sums),
                3 => self.forward::<3, K>(b, run, sums),
                4 => self.forward::<4, K>(b, run, sums),
                5 => self.forward::<5, K>(b, run, sums),
                6 => self.forward::<6, K>(b, run, sums),
                7 => self.forward::<7, K>(b, run, sums),
                WIDEST => self.forward::<WIDEST, K>(b, run, sums),
                _ => self.forward_wide::<K>(b, run, sums),
            }
        }
    }

    /// The back substitution of [`BandLu::forward_all`]'s solve, given the
    /// joint's solution (with a border: each `(D⁻¹y)ⱼ` loses `ŷⱼ·joint`
    /// as it enters the window).
    pub(super) fn backward_all(&self, b: &mut [DVec2], joint: &[DVec2; JOINT]) {
        match self.joint {
            0 => self.backward_runs::<0>(b, joint),
            1 => self.backward_runs::<1>(b, joint),
            2 => self.backward_runs::<2>(b, joint),
            3 => self.backward_runs::<3>(b, joint),
            _ => self.backward_runs::<JOINT>(b, joint),
        }
    }

    pub(super) fn backward_runs<const K: usize>(&self, b: &mut [DVec2], joint: &[DVec2; JOINT]) {
        // Entries from here on have had their border term taken off.
        let mut bordered = b.len();
        for run in self.upper_runs.iter().rev() {
            match run.width {
                1 => self.backward::<1, K>(b, run, joint, &mut bordered),
                2 => self.backward::<2, K>(b, run, joint, &mut bordered),
                3 => self.backward::<3, K>(b, run, joint, &mut bordered),
                4 => self.backward::<4, K>(b, run, joint, &mut bordered),
                5 => self.backward::<5, K>(b, run, joint, &mut bordered),
                6 => self.backward::<6, K>(b, run, joint, &mut bordered),
                7 => self.backward::<7, K>(b, run, joint, &mut bordered),
                WIDEST => self.backward::<WIDEST, K>(b, run, joint, &mut bordered),
                _ => self.backward_wide::<K>(b, run, joint, &mut bordered),
            }
        }
    }

    /// Forward substitution with L (and the row swaps) over one run.
    pub(super) fn forward<const W: usize, const K: usize>(
        &self,
        b: &mut [DVec2],
        run: &Run,
        sums: &mut [DVec2; JOINT],
    ) {
        if run.swaps {
            self.forward_with::<W, true, K>(b, run, sums)
        } else {
            self.forward_with::<W, false, K>(b, run, sums)
        }
    }

    /// Without swaps (`SWAPS` false, a constant) the window is only indexed
    /// by constants, so it stays in registers.
    pub(super) fn forward_with<const W: usize, const SWAPS: bool, const K: usize>(
        &self,
        b: &mut [DVec2],
        run: &Run,
        sums: &mut [DVec2; JOINT],
    ) {
        let mut w = [DVec2::ZERO; WIDEST + 1];
        for (k, slot) in w.iter_mut().enumerate().take(W + 1) {
            *slot = b.get(run.start + k).copied().unwrap_or(DVec2::ZERO);
        }
        let mut sum = [DVec2::ZERO; K];
        sum.copy_from_slice(&sums[..K]);
        let lower = &self.lower[run.offset..run.offset + W * (run.end - run.start)];
        let rows = &self.border_row[run.start * K..run.end * K];
        for ((j, column), row) in (run.start..run.end).zip(lower.chunks_exact(W)).zip(
            rows.chunks_exact(K.max(1))
                .chain(std::iter::repeat(&[][..])),
        ) {
            let p = self.pivots[j] as usize;
            if SWAPS && p != j {
                w.swap(0, p - j);
            }
            let x = w[0];
            for k in 0..W {
                w[k] = w[k + 1] - column[k].apply(x);
            }
            w[W] = b.get(j + W + 1).copied().unwrap_or(DVec2::ZERO);
            let y = self.inverse_diagonal[j].apply(x);
            b[j] = y;
            for k in 0..K {
                sum[k] += row[k].apply(y);
            }
        }
        sums[..K].copy_from_slice(&sum);
        for (k, &value) in w.iter().enumerate().take(W) {
            if let Some(slot) = b.get_mut(run.end + k) {
                *slot = value;
            }
        }
    }

    /// Entry `i` of `b` as the back substitution first reads it: less its
    /// border term, unless taken off already (from `bordered` on).
    #[inline(always)]
    pub(super) fn entering<const K: usize>(
        &self,
        b: &[DVec2],
        i: usize,
        joint: &[DVec2; JOINT],
        bordered: usize,
    ) -> DVec2 {
        let mut value = b[i];
        if K > 0 && i < bordered {
            let col = &self.border_col[i * K..(i + 1) * K];
            for k in 0..K {
                value -= col[k].apply(joint[k]);
            }
        }
        value
    }

    /// Back substitution with the row-scaled U over one run.
    pub(super) fn backward<const W: usize, const K: usize>(
        &self,
        b: &mut [DVec2],
        run: &Run,
        joint: &[DVec2; JOINT],
        bordered: &mut usize,
    ) {
        let mut w = [DVec2::ZERO; WIDEST + 1];
        let last = run.end - 1;
        let from = *bordered;
        for (k, slot) in w.iter_mut().enumerate().take(W + 1) {
            *slot = if k <= last {
                self.entering::<K>(b, last - k, joint, from)
            } else {
                DVec2::ZERO
            };
        }
        let upper = &self.upper[run.offset..run.offset + W * (run.end - run.start)];
        for (j, column) in (run.start..run.end).zip(upper.chunks_exact(W)).rev() {
            let x = w[0];
            for k in 0..W {
                w[k] = w[k + 1] - column[k].apply(x);
            }
            w[W] = if j > W {
                self.entering::<K>(b, j - W - 1, joint, from)
            } else {
                DVec2::ZERO
            };
            b[j] = x;
        }
        for (k, &value) in w.iter().enumerate().take(W) {
            if k < run.start {
                b[run.start - 1 - k] = value;
            }
        }
        // The window went back to the W entries below the run; the one
        // read after them was dropped as read.
        *bordered = run.start.saturating_sub(W);
    }

    /// Forward substitution through memory, for a run wider than [`WIDEST`].
    pub(super) fn forward_wide<const K: usize>(
        &self,
        b: &mut [DVec2],
        run: &Run,
        sums: &mut [DVec2; JOINT],
    ) {
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
            let y = self.inverse_diagonal[j].apply(x);
            b[j] = y;
            for (sum, r) in sums.iter_mut().zip(&self.border_row[j * K..(j + 1) * K]) {
                *sum += r.apply(y);
            }
        }
    }

    /// Back substitution through memory, for a run wider than [`WIDEST`]:
    /// its entries lose their border terms first.
    pub(super) fn backward_wide<const K: usize>(
        &self,
        b: &mut [DVec2],
        run: &Run,
        joint: &[DVec2; JOINT],
        bordered: &mut usize,
    ) {
        for i in run.start..run.end.min(*bordered) {
            b[i] = self.entering::<K>(b, i, joint, *bordered);
        }
        *bordered = run.start;
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
pub(super) fn largest_magnitude<T: Entry>(entries: &[T]) -> f64 {
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
pub(super) fn larger(a: f64, b: f64) -> f64 {
    if b > a { b } else { a }
}

/// Threshold pivoting's ratio: a diagonal at least this fraction of its
/// column's largest entry is kept (growth per column at most `1 + 1/0.1`).
pub(super) const PIVOT_THRESHOLD: f64 = 0.1;

/// The widest factor columns solved in registers.
pub(super) const WIDEST: usize = 8;

/// A KKT system split at a **joint** for peeling: the unknowns of two arms
/// (the free points left and right of the joint, each numbered outward
/// from it with its handles' multipliers after their points) and the
/// joint's (its two points and the multipliers of handles only on them),
/// eliminated last. The arms do not touch each other, so each is a banded
/// system bordered by the joint, and a region growing at its ends appends
/// rows and columns to the arms' eliminations: the columns before the
/// last `kl + ku` keep their factors, and the joint's small Schur
/// complement is factored again.
#[derive(Debug, Default)]
pub(super) struct Split<T> {
    pub(super) arms: [BandLu<T>; 2],
    pub(super) joint: usize,
    /// Per arm: the joint unknowns it touches (the border's columns, in
    /// order), how many, and each joint unknown's place among them.
    pub(super) bordered: [[usize; JOINT]; 2],
    pub(super) border_count: [usize; 2],
    pub(super) border_place: [[usize; JOINT]; 2],
    /// The joint block as assembled.
    pub(super) block: [[T; JOINT]; JOINT],
    /// LU of the joint's Schur complement (partial pivoting, rows swapped
    /// whole, reciprocals on the diagonal).
    pub(super) schur: [[T; JOINT]; JOINT],
    pub(super) schur_pivots: [usize; JOINT],
    /// The pivoting threshold the arms were factored with.
    pub(super) threshold: f64,
}

/// Where a [`Split`] system's unknown lives.
pub(super) enum Place {
    Arm(usize, usize),
    Joint(usize),
}

impl<T: Entry> Split<T> {
    /// Zeroes arms of the given sizes and bandwidths and a joint of
    /// `joint` unknowns.
    /// Each arm's storage is reserved for `capacity[arm]` unknowns, as
    /// far as the region may grow, so growing never moves it.
    pub(super) fn reset(
        &mut self,
        sizes: [usize; 2],
        capacity: [usize; 2],
        widths: [usize; 2],
        joint: usize,
        links: [[bool; JOINT]; 2],
    ) {
        for a in 0..2 {
            let mut count = 0;
            for k in (0..joint).filter(|&k| links[a][k]) {
                self.bordered[a][count] = k;
                self.border_place[a][k] = count;
                count += 1;
            }
            self.border_count[a] = count;
            let arm = &mut self.arms[a];
            arm.reset_bordered(sizes[a], widths[a], widths[a], count, true);
            let more = capacity[a].saturating_sub(sizes[a]);
            arm.band.reserve(more * arm.stride());
            arm.border_row.reserve(more * count);
            arm.border_col.reserve(more * count);
            for factor in [&mut arm.lower, &mut arm.upper] {
                factor.reserve(capacity[a] * (widths[a] + 1));
            }
            arm.pivots.reserve(more);
            arm.inverse_diagonal.reserve(more);
            arm.widths.reserve(more);
        }
        self.joint = joint;
        self.block = Default::default();
    }

    #[inline]
    pub(super) fn place(&self, slot: usize) -> Place {
        let [n0, n1] = [self.arms[0].n, self.arms[1].n];
        if slot < n0 {
            Place::Arm(0, slot)
        } else if slot < n0 + n1 {
            Place::Arm(1, slot - n0)
        } else {
            Place::Joint(slot - n0 - n1)
        }
    }

    /// Adds `value` at (row, col) in the whole system's numbering, if the
    /// entry is new: in an arm's row or column from `new[arm]` on, or in
    /// the joint block when `block`.
    pub(super) fn add(&mut self, row: usize, col: usize, value: T, new: [usize; 2], block: bool) {
        match (self.place(row), self.place(col)) {
            (Place::Arm(a, i), Place::Arm(b, j)) => {
                debug_assert_eq!(a, b, "the arms do not touch");
                if i >= new[a] || j >= new[a] {
                    self.arms[a].add(i, j, value);
                }
            }
            (Place::Arm(a, i), Place::Joint(k)) => {
                if i >= new[a] {
                    let (width, k) = (self.border_count[a], self.border_place[a][k]);
                    let entry = &mut self.arms[a].border_col[i * width + k];
                    *entry = *entry + value;
                }
            }
            (Place::Joint(k), Place::Arm(a, j)) => {
                if j >= new[a] {
                    let (width, k) = (self.border_count[a], self.border_place[a][k]);
                    let entry = &mut self.arms[a].border_row[j * width + k];
                    *entry = *entry + value;
                }
            }
            (Place::Joint(k), Place::Joint(m)) => {
                if block {
                    self.block[k][m] = self.block[k][m] + value;
                }
            }
        }
    }

    /// Factors the arms and the joint.
    pub(super) fn factor(&mut self, threshold: f64) -> bool {
        self.threshold = threshold;
        self.arms.iter_mut().all(|arm| arm.factor_with(threshold)) && self.factor_joint()
    }

    /// Grows the arms to `sizes` (see [`BandLu::grow`]); returns where
    /// each resumes.
    pub(super) fn grow(&mut self, sizes: [usize; 2]) -> [usize; 2] {
        [self.arms[0].grow(sizes[0]), self.arms[1].grow(sizes[1])]
    }

    /// Factors the grown arms from `from` on and the joint again.
    pub(super) fn resume(&mut self, from: [usize; 2]) -> bool {
        let threshold = self.threshold;
        self.arms
            .iter_mut()
            .zip(from)
            .all(|(arm, from)| arm.resume(from, threshold))
            && self.factor_joint()
    }

    /// The joint block less what the arms' eliminations take off it, by
    /// dense LU with partial pivoting.
    pub(super) fn factor_joint(&mut self) -> bool {
        let m = self.joint;
        let mut s = self.block;
        let mut scale = self.arms[0].scale.max(self.arms[1].scale);
        for row in &s[..m] {
            for entry in &row[..m] {
                scale = larger(scale, entry.magnitude_squared());
            }
        }
        for (a, arm) in self.arms.iter().enumerate() {
            let joint = &self.bordered[a][..self.border_count[a]];
            for (x, &r) in joint.iter().enumerate() {
                for (y, &c) in joint.iter().enumerate() {
                    s[r][c] = s[r][c] - arm.border_sum[x][y];
                }
            }
        }
        for k in 0..m {
            let mut p = k;
            for i in k + 1..m {
                if s[i][k].magnitude_squared() > s[p][k].magnitude_squared() {
                    p = i;
                }
            }
            let best = s[p][k].magnitude_squared();
            if best.is_nan() || best <= scale * 1e-26 {
                return false;
            }
            s.swap(k, p);
            self.schur_pivots[k] = p;
            let inverse = s[k][k].reciprocal();
            s[k][k] = inverse;
            let pivot_row = s[k];
            for row in &mut s[k + 1..m] {
                let l = row[k].times(inverse);
                row[k] = l;
                for (entry, u) in row[k + 1..m].iter_mut().zip(&pivot_row[k + 1..m]) {
                    *entry = *entry - l.times(*u);
                }
            }
        }
        self.schur = s;
        true
    }

    /// Solves the system in place: `b` is the left arm's unknowns, the
    /// right arm's, then the joint's.
    pub(super) fn solve(&self, b: &mut [DVec2]) {
        let m = self.joint;
        let (left, rest) = b.split_at_mut(self.arms[0].n);
        let (right, joint) = rest.split_at_mut(self.arms[1].n);
        let mut parts = [left, right];
        for (a, (arm, part)) in self.arms.iter().zip(parts.iter_mut()).enumerate() {
            let mut sums = [DVec2::ZERO; JOINT];
            arm.forward_all(part, &mut sums);
            for (&k, sum) in self.bordered[a][..self.border_count[a]].iter().zip(sums) {
                joint[k] -= sum;
            }
        }
        let s = &self.schur;
        for k in 0..m {
            joint.swap(k, self.schur_pivots[k]);
        }
        for k in 0..m {
            for i in k + 1..m {
                let x = joint[k];
                joint[i] -= s[i][k].apply(x);
            }
        }
        for k in (0..m).rev() {
            let mut x = joint[k];
            for c in k + 1..m {
                x -= s[k][c].apply(joint[c]);
            }
            joint[k] = s[k][k].apply(x);
        }
        for (a, (arm, part)) in self.arms.iter().zip(parts.iter_mut()).enumerate() {
            let mut x = [DVec2::ZERO; JOINT];
            for (x, &k) in x.iter_mut().zip(&self.bordered[a][..self.border_count[a]]) {
                *x = joint[k];
            }
            arm.backward_all(part, &x);
        }
    }
}
