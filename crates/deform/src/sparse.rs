//! Sparse Cholesky factors for the deformers. faer computes the fill-reducing
//! order and the numeric factor once; the solves are ours, so the frame path
//! never allocates, never permutes (callers number their unknowns in the
//! factor's order), and moves an x,y pair — or one complex number — per
//! entry of `L`, reading the factor once per pass instead of once per axis.
//! Large real factors keep faer's supernodes as dense blocks (one row index
//! per block row, one stream of values); small ones and the complex factor
//! are read out column by column. A column factor also reads into a
//! [`PairSolve`] (both passes as gathers, two entries per SIMD lane, each
//! sum ending on the unknowns found last), which the skeleton's stitches use.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMat;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::linalg::{SupernodalThreshold, SymbolicSupernodalParams};
use faer::{Par, Side, c64};
use glam::DVec2;

/// The factorisation failed: numerically the matrix was not positive
/// definite (nearly degenerate triangles or extreme weights), or memory ran
/// out.
#[derive(Debug, thiserror::Error)]
#[error("cannot factor the mesh's matrices ({0}); it is too ill-conditioned to deform")]
pub struct FactorError(String);

fn failed(e: impl std::fmt::Debug) -> FactorError {
    FactorError(format!("{e:?}"))
}

/// A fill-reducing order (approximate minimum degree) of the symmetric
/// pattern given by `edges` over `n` unknowns: `order[new] = old`.
pub fn fill_reducing_order(n: usize, edges: &[(u32, u32)]) -> Result<Vec<u32>, FactorError> {
    let mut pairs: Vec<faer::sparse::Pair<usize, usize>> = Vec::with_capacity(edges.len() * 2 + n);
    for i in 0..n {
        pairs.push(faer::sparse::Pair::new(i, i));
    }
    for &(a, b) in edges {
        pairs.push(faer::sparse::Pair::new(a as usize, b as usize));
        pairs.push(faer::sparse::Pair::new(b as usize, a as usize));
    }
    let (pattern, _) = SymbolicSparseColMat::try_new_from_indices(n, n, &pairs).map_err(failed)?;
    let mut forward = vec![0usize; n];
    let mut inverse = vec![0usize; n];
    let mut work = MemBuffer::try_new(amd::order_scratch::<usize>(n, pattern.compute_nnz()))
        .map_err(failed)?;
    amd::order(
        &mut forward,
        &mut inverse,
        pattern.as_ref(),
        amd::Control::default(),
        MemStack::new(&mut work),
    )
    .map_err(failed)?;
    Ok(forward.into_iter().map(|i| i as u32).collect())
}

/// The structure of a lower-triangular factor without its diagonal:
/// column `j` holds rows `rows[start[j]..start[j + 1]]`, all below `j`.
#[derive(Debug, Clone)]
struct Structure {
    start: Vec<u32>,
    rows: Vec<u32>,
    /// Elimination tree: the parent of column `j` is its first off-diagonal
    /// row, `u32::MAX` for a root.
    parent: Vec<u32>,
}

impl Structure {
    fn new(start: Vec<u32>, rows: Vec<u32>) -> Structure {
        let parent = start
            .windows(2)
            .map(|w| {
                rows[w[0] as usize..w[1] as usize]
                    .iter()
                    .copied()
                    .min()
                    .unwrap_or(u32::MAX)
            })
            .collect();
        Structure {
            start,
            rows,
            parent,
        }
    }

    /// The columns a forward solve touches when the right-hand side is
    /// non-zero only at `nonzeros`: their paths to the root of the
    /// elimination tree, in increasing order.
    fn reach(&self, nonzeros: impl Iterator<Item = usize>) -> Vec<u32> {
        paths_to_root(&self.parent, nonzeros.map(|j| j as u32))
    }

    /// The invariant the unchecked solves rely on.
    fn check(&self, n: usize) -> Result<(), FactorError> {
        let monotone = self.start.len() == n + 1
            && self.start.windows(2).all(|w| w[0] <= w[1])
            && *self.start.last().unwrap() as usize == self.rows.len();
        if monotone && self.rows.iter().all(|&r| (r as usize) < n) {
            Ok(())
        } else {
            Err(FactorError("inconsistent factor structure".into()))
        }
    }
}

/// The upper triangle (diagonal included) of a symmetric sparse pattern in
/// compressed columns, rows sorted: the shape of the deformers' matrices,
/// built once so values can be summed straight into place.
#[derive(Debug, Clone)]
pub struct UpperPattern {
    col_ptr: Vec<usize>,
    rows: Vec<usize>,
}

impl UpperPattern {
    /// The pattern of the graph `edges` over `n` nodes, plus the diagonal.
    pub fn new(n: usize, edges: &[(u32, u32)]) -> UpperPattern {
        let mut entries: Vec<(u32, u32)> = Vec::with_capacity(edges.len() + n);
        entries.extend((0..n as u32).map(|i| (i, i)));
        entries.extend(edges.iter().map(|&(a, b)| (a.max(b), a.min(b))));
        entries.sort_unstable();
        entries.dedup();
        let mut col_ptr = vec![0usize; n + 1];
        for &(col, _) in &entries {
            col_ptr[col as usize + 1] += 1;
        }
        for j in 0..n {
            col_ptr[j + 1] += col_ptr[j];
        }
        let rows = entries.into_iter().map(|(_, row)| row as usize).collect();
        UpperPattern { col_ptr, rows }
    }

    /// Stored entries (diagonal included): the length of the value array
    /// the matrix is assembled into.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether the pattern has no entries at all (no unknowns).
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Number of unknowns: the matrix is `dim × dim`.
    pub fn dim(&self) -> usize {
        self.col_ptr.len() - 1
    }

    /// Where entry (`a`, `b`) or (`b`, `a`) lives in a value array.
    /// Panics if it is not in the pattern (a caller bug, not bad input).
    #[inline]
    pub fn position(&self, a: usize, b: usize) -> usize {
        let (row, col) = (a.min(b), a.max(b));
        let column = &self.rows[self.col_ptr[col]..self.col_ptr[col + 1]];
        self.col_ptr[col] + column.binary_search(&row).expect("entry in the pattern")
    }
}

/// Factors with faer in the given (identity) order and returns the
/// off-diagonal structure, the off-diagonal values and the diagonal.
///
/// faer picks a supernodal factorisation for large meshes (dense blocks:
/// several times faster to compute at 100k vertices than column by column)
/// and a simplicial one for small ones. Supernodes are not relaxed, so the
/// factor's entries are exactly the simplicial ones, read out here column by
/// column (the real factor keeps the supernodes instead: `Supernodes`).
fn factor<T: faer::traits::ComplexField + Copy>(
    pattern: &UpperPattern,
    values: &[T],
) -> Result<(Structure, Vec<T>, Vec<T>), FactorError> {
    factor_choosing(pattern, values, SupernodalThreshold::AUTO)
}

fn factor_choosing<T: faer::traits::ComplexField + Copy>(
    pattern: &UpperPattern,
    values: &[T],
    supernodal: SupernodalThreshold,
) -> Result<(Structure, Vec<T>, Vec<T>), FactorError> {
    let (symbolic, values) = numeric_factor(pattern, values, supernodal, None)?;
    columns_of(pattern.dim(), &symbolic, &values)
}

/// faer's numeric `L Lᴴ` in the identity order, and its symbolic part.
fn numeric_factor<T: faer::traits::ComplexField + Copy>(
    pattern: &UpperPattern,
    values: &[T],
    supernodal: SupernodalThreshold,
    relax: Option<&'static [(usize, f64)]>,
) -> Result<(SymbolicCholesky<usize>, Vec<T>), FactorError> {
    let n = pattern.dim();
    let symbolic_matrix = faer::sparse::SymbolicSparseColMatRef::new_checked(
        n,
        n,
        &pattern.col_ptr,
        None,
        &pattern.rows,
    );
    let matrix = faer::sparse::SparseColMatRef::new(symbolic_matrix, values);
    let params = CholeskySymbolicParams {
        supernodal_flop_ratio_threshold: supernodal,
        supernodal_params: SymbolicSupernodalParams { relax },
        ..Default::default()
    };
    let symbolic = factorize_symbolic_cholesky(
        symbolic_matrix,
        Side::Upper,
        SymmetricOrdering::Identity,
        params,
    )
    .map_err(failed)?;
    let mut values = vec![T::zero_impl(); symbolic.len_val()];
    let mut work = MemBuffer::try_new(
        symbolic.factorize_numeric_llt_scratch::<T>(Par::Seq, Default::default()),
    )
    .map_err(failed)?;
    symbolic
        .factorize_numeric_llt(
            &mut values,
            matrix,
            Side::Upper,
            Default::default(),
            Par::Seq,
            MemStack::new(&mut work),
            Default::default(),
        )
        .map_err(failed)?;
    Ok((symbolic, values))
}

/// Reads faer's factor out column by column: the off-diagonal structure,
/// the off-diagonal values and the diagonal.
fn columns_of<T: Copy>(
    n: usize,
    symbolic: &SymbolicCholesky<usize>,
    values: &[T],
) -> Result<(Structure, Vec<T>, Vec<T>), FactorError> {
    let mut start = Vec::with_capacity(n + 1);
    let mut rows = Vec::with_capacity(values.len());
    let mut off = Vec::with_capacity(values.len());
    let mut diagonal = Vec::with_capacity(n);
    start.push(0u32);
    match symbolic.raw() {
        SymbolicCholeskyRaw::Simplicial(simplicial) => {
            let col_ptr = simplicial.col_ptr();
            let row_idx = simplicial.row_idx();
            for j in 0..n {
                let (a, b) = (col_ptr[j], col_ptr[j + 1]);
                // faer stores the diagonal first in each column.
                debug_assert_eq!(row_idx[a], j);
                diagonal.push(values[a]);
                for p in a + 1..b {
                    rows.push(row_idx[p] as u32);
                    off.push(values[p]);
                }
                start.push(rows.len() as u32);
            }
        }
        SymbolicCholeskyRaw::Supernodal(supernodal) => {
            // Supernode s: columns begin..end, a dense column-major block
            // whose rows are its own columns, then the rows below it.
            let begins = supernodal.supernode_begin();
            let ends = supernodal.supernode_end();
            let row_ptr = supernodal.col_ptr_for_row_idx();
            let value_ptr = supernodal.col_ptr_for_val();
            for s in 0..supernodal.n_supernodes() {
                let (begin, end) = (begins[s], ends[s]);
                let below = &supernodal.row_idx()[row_ptr[s]..row_ptr[s + 1]];
                let height = end - begin + below.len();
                let block = &values[value_ptr[s]..value_ptr[s + 1]];
                for k in 0..end - begin {
                    let column = &block[k * height..(k + 1) * height];
                    diagonal.push(column[k]);
                    for (i, &value) in column.iter().enumerate().skip(k + 1) {
                        let row = if i < end - begin {
                            begin + i
                        } else {
                            below[i - (end - begin)]
                        };
                        rows.push(row as u32);
                        off.push(value);
                    }
                    start.push(rows.len() as u32);
                }
            }
        }
    }
    let structure = Structure::new(start, rows);
    structure.check(n)?;
    Ok((structure, off, diagonal))
}

/// `L Lᵀ` of a real sparse SPD matrix.
#[derive(Debug, Clone)]
pub struct RealCholesky {
    layout: Layout,
    inverse_diagonal: Vec<f64>,
}

/// How a real factor's entries are stored for the solves.
#[derive(Debug, Clone)]
enum Layout {
    /// Column by column, one row index per entry: small factors.
    Columns {
        structure: Structure,
        values: Vec<f64>,
    },
    /// Dense blocks per supernode: large factors, where most entries sit in
    /// wide supernodes and a row index per entry would double the bytes a
    /// pass reads.
    Supernodes(Supernodes),
}

/// A supernodal factor: supernode `s` owns the consecutive columns
/// `begin[s]..begin[s + 1]` (width `w`), which share the rows `below` them.
/// Its entries are one run of `values` from `start[s]`: the strict lower
/// triangle of its diagonal block, packed column by column, then the block
/// of its rows below, dense row-major (`m × w`). A pass so reads one row
/// index per row instead of per entry, and the factor as a single stream.
#[derive(Debug, Clone)]
struct Supernodes {
    begin: Vec<u32>,
    below_start: Vec<u32>,
    below: Vec<u32>,
    start: Vec<usize>,
    values: Vec<f64>,
    /// The supernode holding each column, and each supernode's parent in the
    /// supernodal elimination tree (`u32::MAX` for a root): the reach of a
    /// sparse right-hand side.
    home: Vec<u32>,
    parent: Vec<u32>,
}

impl Supernodes {
    /// Copies faer's supernodal factor; `None` when faer chose a simplicial
    /// one. Also returns the diagonal of `L`.
    fn of(symbolic: &SymbolicCholesky<usize>, values: &[f64]) -> Option<(Supernodes, Vec<f64>)> {
        let SymbolicCholeskyRaw::Supernodal(supernodal) = symbolic.raw() else {
            return None;
        };
        let count = supernodal.n_supernodes();
        let begins = supernodal.supernode_begin();
        let ends = supernodal.supernode_end();
        let row_ptr = supernodal.col_ptr_for_row_idx();
        let value_ptr = supernodal.col_ptr_for_val();
        let n = ends.last().copied().unwrap_or(0);
        let mut out = Supernodes {
            begin: Vec::with_capacity(count + 1),
            below_start: Vec::with_capacity(count + 1),
            below: Vec::with_capacity(supernodal.row_idx().len()),
            start: Vec::with_capacity(count + 1),
            values: Vec::with_capacity(values.len()),
            home: vec![0; n],
            parent: Vec::with_capacity(count),
        };
        let mut diagonal = Vec::with_capacity(n);
        for s in 0..count {
            let (begin, end) = (begins[s], ends[s]);
            let width = end - begin;
            let below = &supernodal.row_idx()[row_ptr[s]..row_ptr[s + 1]];
            let height = width + below.len();
            let block = &values[value_ptr[s]..value_ptr[s + 1]];
            out.begin.push(begin as u32);
            out.below_start.push(out.below.len() as u32);
            out.below.extend(below.iter().map(|&r| r as u32));
            out.start.push(out.values.len());
            for k in 0..width {
                diagonal.push(block[k * height + k]);
                out.values
                    .extend_from_slice(&block[k * height + k + 1..k * height + width]);
            }
            for r in 0..below.len() {
                out.values
                    .extend((0..width).map(|k| block[k * height + width + r]));
            }
            out.home[begin..end].fill(s as u32);
        }
        out.begin.push(n as u32);
        out.below_start.push(out.below.len() as u32);
        out.start.push(out.values.len());
        for s in 0..count {
            let first = out.below_of(s).iter().copied().min();
            out.parent
                .push(first.map_or(u32::MAX, |row| out.home[row as usize]));
        }
        Some((out, diagonal))
    }

    fn count(&self) -> usize {
        self.begin.len() - 1
    }

    fn below_of(&self, s: usize) -> &[u32] {
        &self.below[self.below_start[s] as usize..self.below_start[s + 1] as usize]
    }

    /// The invariant the unchecked solves rely on: every row below a
    /// supernode lies past its columns and inside the matrix, and each run
    /// of values has its size.
    fn check(&self, n: usize) -> Result<(), FactorError> {
        let ok = (0..self.count()).all(|s| {
            let (b, e) = (self.begin[s] as usize, self.begin[s + 1] as usize);
            let m = self.below_of(s).len();
            b < e
                && self.start[s + 1] - self.start[s] == (e - b) * (e - b - 1) / 2 + m * (e - b)
                && self
                    .below_of(s)
                    .iter()
                    .all(|&r| (r as usize) >= e && (r as usize) < n)
        }) && *self.begin.last().unwrap() as usize == n
            && *self.start.last().unwrap() == self.values.len();
        if ok {
            Ok(())
        } else {
            Err(FactorError("inconsistent supernodal factor".into()))
        }
    }

    /// The entries a simplicial factor would hold, diagonal excluded.
    fn entries(&self) -> usize {
        self.values.len()
    }

    /// The supernodes a forward solve touches when the right-hand side is
    /// non-zero only in the given columns, in increasing order.
    fn reach(&self, nonzeros: impl Iterator<Item = usize>) -> Vec<u32> {
        paths_to_root(&self.parent, nonzeros.map(|j| self.home[j]))
    }

    /// `x ← L⁻¹ x` over the supernodes `which` (increasing).
    #[inline(always)]
    fn forward<V: Value>(
        &self,
        inverse_diagonal: &[f64],
        x: &mut [V],
        which: impl Iterator<Item = u32>,
    ) {
        assert!(x.len() == inverse_diagonal.len() && self.home.len() == x.len());
        for s in which {
            let s = s as usize;
            let (b, e) = (self.begin[s] as usize, self.begin[s + 1] as usize);
            let w = e - b;
            let values = &self.values[self.start[s]..self.start[s + 1]];
            let below = self.below_of(s);
            if w == 1 {
                // A lone column, as in the column layout.
                let xj = x[b] * inverse_diagonal[b];
                x[b] = xj;
                for (&i, &l) in below.iter().zip(values) {
                    // SAFETY: `check` guarantees every row below is < n.
                    unsafe {
                        let xi = x.get_unchecked_mut(i as usize);
                        *xi = *xi - xj * l;
                    }
                }
                continue;
            }
            let (diagonal, block) = values.split_at(w * (w - 1) / 2);
            let (head, tail) = x.split_at_mut(e);
            let xs = &mut head[b..];
            let mut column = diagonal;
            for k in 0..w {
                let xk = xs[k] * inverse_diagonal[b + k];
                xs[k] = xk;
                let (here, rest) = column.split_at(w - k - 1);
                column = rest;
                for (xi, &l) in xs[k + 1..].iter_mut().zip(here) {
                    *xi = *xi - xk * l;
                }
            }
            let xs = &*xs;
            let mut rows = below.chunks_exact(4);
            let mut values = block.chunks_exact(4 * w);
            for (r, l) in (&mut rows).zip(&mut values) {
                let (l0, rest) = l.split_at(w);
                let (l1, rest) = rest.split_at(w);
                let (l2, l3) = rest.split_at(w);
                let mut sums = [V::default(); 4];
                for k in 0..w {
                    let v = xs[k];
                    sums[0] = sums[0] + v * l0[k];
                    sums[1] = sums[1] + v * l1[k];
                    sums[2] = sums[2] + v * l2[k];
                    sums[3] = sums[3] + v * l3[k];
                }
                for (lane, sum) in sums.into_iter().enumerate() {
                    // SAFETY: `check` guarantees e <= r < n, so r - e is
                    // inside `tail`.
                    unsafe {
                        let t = tail.get_unchecked_mut(r[lane] as usize - e);
                        *t = *t - sum;
                    }
                }
            }
            for (&r, l) in rows
                .remainder()
                .iter()
                .zip(values.remainder().chunks_exact(w))
            {
                let sum = dot(l, xs);
                // SAFETY: as above.
                unsafe {
                    let t = tail.get_unchecked_mut(r as usize - e);
                    *t = *t - sum;
                }
            }
        }
    }

    /// `x ← L⁻ᵀ x`.
    fn backward<V: Value>(&self, inverse_diagonal: &[f64], x: &mut [V]) {
        assert!(x.len() == inverse_diagonal.len() && self.home.len() == x.len());
        for s in (0..self.count()).rev() {
            let (b, e) = (self.begin[s] as usize, self.begin[s + 1] as usize);
            let w = e - b;
            let (a, z) = (self.start[s], self.start[s + 1]);
            // The pass walks the factor from its end, which hardware
            // prefetchers follow poorly: ask for the run this far behind.
            prefetch_range(&self.values, a, z);
            let (ba, bz) = (
                self.below_start[s] as usize,
                self.below_start[s + 1] as usize,
            );
            prefetch_range(&self.below, ba, bz);
            let values = &self.values[a..z];
            let below = &self.below[ba..bz];
            if w == 1 {
                let sum = gather_dot(values, below, x);
                x[b] = (x[b] - sum) * inverse_diagonal[b];
                continue;
            }
            let (diagonal, block) = values.split_at(w * (w - 1) / 2);
            let (head, tail) = x.split_at_mut(e);
            let xs = &mut head[b..];
            let mut rows = below.chunks_exact(4);
            let mut values = block.chunks_exact(4 * w);
            for (r, l) in (&mut rows).zip(&mut values) {
                // SAFETY: `check` guarantees e <= r < n.
                let [y0, y1, y2, y3] = std::array::from_fn(|lane| unsafe {
                    *tail.get_unchecked(r[lane] as usize - e)
                });
                let (l0, rest) = l.split_at(w);
                let (l1, rest) = rest.split_at(w);
                let (l2, l3) = rest.split_at(w);
                for k in 0..w {
                    let t = (y0 * l0[k] + y1 * l1[k]) + (y2 * l2[k] + y3 * l3[k]);
                    xs[k] = xs[k] - t;
                }
            }
            for (&r, l) in rows
                .remainder()
                .iter()
                .zip(values.remainder().chunks_exact(w))
            {
                // SAFETY: as above.
                let y = unsafe { *tail.get_unchecked(r as usize - e) };
                for (xk, &lk) in xs.iter_mut().zip(l) {
                    *xk = *xk - y * lk;
                }
            }
            // Column k of the packed triangle starts after the w-1, w-2, …
            // entries of the columns before it.
            for k in (0..w).rev() {
                let at = k * w - k * (k + 1) / 2;
                let column = &diagonal[at..at + (w - k - 1)];
                let sum = dot(column, &xs[k + 1..]);
                xs[k] = (xs[k] - sum) * inverse_diagonal[b + k];
            }
        }
    }
}

/// Prefetches the cache lines of `items[from - lead..to - lead]`, `lead`
/// a fixed distance behind, so a pass walking backwards finds what it
/// needs next already on its way from memory.
#[inline(always)]
fn prefetch_range<T>(items: &[T], from: usize, to: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        const AHEAD_BYTES: usize = 4096;
        let size = std::mem::size_of::<T>().max(1);
        let lead = AHEAD_BYTES / size;
        if from < lead {
            return;
        }
        let line = 64 / size;
        let mut p = from - lead;
        while p < to - lead {
            // SAFETY: prefetching is a hint; p < to <= items.len().
            unsafe {
                use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
                _mm_prefetch::<_MM_HINT_T0>(items.as_ptr().add(p) as *const i8);
            }
            p += line.max(1);
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (items, from, to);
}

/// `Σ l[k] · x[rows[k]]` with four partial sums; `rows` are checked to be
/// inside `x` when the factor is built.
#[inline(always)]
fn gather_dot<V: Value>(l: &[f64], rows: &[u32], x: &[V]) -> V {
    let mut sums = [V::default(); 4];
    let (lc, rc) = (l.chunks_exact(4), rows.chunks_exact(4));
    let (lr, rr) = (lc.remainder(), rc.remainder());
    for (l, r) in lc.zip(rc) {
        for lane in 0..4 {
            // SAFETY: `Supernodes::check` guarantees every row is < n.
            sums[lane] = sums[lane] + unsafe { *x.get_unchecked(r[lane] as usize) } * l[lane];
        }
    }
    for (&l, &r) in lr.iter().zip(rr) {
        // SAFETY: as above.
        sums[0] = sums[0] + unsafe { *x.get_unchecked(r as usize) } * l;
    }
    (sums[0] + sums[1]) + (sums[2] + sums[3])
}

/// `Σ l[k] · x[k]` with four partial sums.
#[inline(always)]
fn dot<V: Value>(l: &[f64], x: &[V]) -> V {
    let mut sums = [V::default(); 4];
    let (lc, xc) = (l.chunks_exact(4), x.chunks_exact(4));
    let (lr, xr) = (lc.remainder(), xc.remainder());
    for (l, x) in lc.zip(xc) {
        for lane in 0..4 {
            sums[lane] = sums[lane] + x[lane] * l[lane];
        }
    }
    for (&l, &x) in lr.iter().zip(xr) {
        sums[0] = sums[0] + x * l;
    }
    (sums[0] + sums[1]) + (sums[2] + sums[3])
}

impl RealCholesky {
    /// Factors the matrix with `values` over `pattern`.
    pub fn new(pattern: &UpperPattern, values: &[f64]) -> Result<Self, FactorError> {
        Self::choosing(pattern, values, SupernodalThreshold::AUTO)
    }

    fn choosing(
        pattern: &UpperPattern,
        values: &[f64],
        supernodal: SupernodalThreshold,
    ) -> Result<Self, FactorError> {
        let n = pattern.dim();
        // Relaxed supernodes (explicit zeros merged in for wider blocks)
        // measured slower at 100k vertices: the passes are bound by the
        // bytes they read, and relaxing adds 10–20% of them.
        let (symbolic, values) = numeric_factor(pattern, values, supernodal, None)?;
        let (layout, diagonal) = match Supernodes::of(&symbolic, &values) {
            Some((supernodes, diagonal)) => {
                supernodes.check(n)?;
                (Layout::Supernodes(supernodes), diagonal)
            }
            None => {
                let (structure, values, diagonal) = columns_of(n, &symbolic, &values)?;
                (Layout::Columns { structure, values }, diagonal)
            }
        };
        Ok(RealCholesky {
            layout,
            inverse_diagonal: diagonal.iter().map(|d| 1.0 / d).collect(),
        })
    }

    /// Number of unknowns: the length a right-hand side must have.
    pub fn dim(&self) -> usize {
        self.inverse_diagonal.len()
    }

    /// The factor as a [`PairSolve`], for a column-by-column (simplicial)
    /// factor; `None` for a supernodal one, whose dense blocks its own
    /// solves already stream.
    pub fn pair_solve(&self) -> Option<PairSolve> {
        match &self.layout {
            Layout::Columns { structure, values } => {
                structure.check(self.dim()).ok()?;
                Some(PairSolve::new(structure, values, &self.inverse_diagonal))
            }
            Layout::Supernodes(_) => None,
        }
    }

    /// Stored entries of `L`, diagonal included: the factor's size (fill),
    /// which the benchmark reports.
    pub fn factor_entries(&self) -> usize {
        self.dim()
            + match &self.layout {
                Layout::Columns { values, .. } => values.len(),
                Layout::Supernodes(supernodes) => supernodes.entries(),
            }
    }

    /// Solves `A x = b` in place, for one right-hand side (`f64`) or two
    /// stored as pairs (`DVec2`: x and y share the factor's pass).
    pub fn solve<V: Value>(&self, x: &mut [V]) {
        self.forward(x);
        self.backward(x);
    }

    /// The forward half of [`RealCholesky::solve`]: `x ← L⁻¹ x`.
    pub fn forward<V: Value>(&self, x: &mut [V]) {
        assert_eq!(x.len(), self.dim(), "right-hand side length");
        let inverse = &self.inverse_diagonal;
        match &self.layout {
            Layout::Columns { structure, values } => {
                let columns = 0..self.dim() as u32;
                forward_solve(structure, values, inverse, x, &|l, v| v * l, columns);
            }
            Layout::Supernodes(supernodes) => {
                supernodes.forward(inverse, x, 0..supernodes.count() as u32)
            }
        }
    }

    /// The backward half of [`RealCholesky::solve`]: `x ← L⁻ᵀ x`.
    pub fn backward<V: Value>(&self, x: &mut [V]) {
        let inverse = &self.inverse_diagonal;
        match &self.layout {
            Layout::Columns { structure, values } => {
                backward_solve(structure, values, inverse, x, &|l, v| v * l)
            }
            Layout::Supernodes(supernodes) => supernodes.backward(inverse, x),
        }
    }

    /// `L⁻¹ b` for a right-hand side with a few non-zero `entries`
    /// (index, value): only the elimination-tree paths above them are
    /// touched, so this is far cheaper than a solve.
    pub fn forward_sparse(&self, entries: &[(usize, f64)]) -> SparseVector<f64> {
        let mut dense = vec![0.0; self.dim()];
        for &(i, v) in entries {
            dense[i] += v;
        }
        let inverse = &self.inverse_diagonal;
        let reach: Vec<u32> = match &self.layout {
            Layout::Columns { structure, values } => {
                let reach = structure.reach(entries.iter().map(|e| e.0));
                let columns = reach.iter().copied();
                forward_solve(
                    structure,
                    values,
                    inverse,
                    &mut dense,
                    &|l, v| v * l,
                    columns,
                );
                reach
            }
            Layout::Supernodes(supernodes) => {
                let reach = supernodes.reach(entries.iter().map(|e| e.0));
                supernodes.forward(inverse, &mut dense, reach.iter().copied());
                reach
                    .iter()
                    .flat_map(|&s| supernodes.begin[s as usize]..supernodes.begin[s as usize + 1])
                    .collect()
            }
        };
        let values = reach.iter().map(|&i| dense[i as usize]).collect();
        SparseVector {
            indices: reach,
            values,
        }
    }
}

/// `L Lᵀ x = b` for x,y pairs with both passes as gathers: the forward pass
/// row by row (`xᵢ = (bᵢ − Σ_{j<i} L_ij x_j) / L_ii`, a row-wise copy of the
/// factor), the backward pass column by column. Each sum moves two entries
/// per 256-bit lane (`[x_a, x_b] · [l_a, l_a, l_b, l_b]`), where the
/// column solves move one x,y pair per operation and scatter in the forward
/// pass. From a factor read out column by column.
#[derive(Debug, Clone)]
pub struct PairSolve {
    inverse_diagonal: Vec<f64>,
    rows: Structure,
    row_values: Vec<f64>,
    columns: Structure,
    column_values: Vec<f64>,
}

impl PairSolve {
    fn new(structure: &Structure, values: &[f64], inverse_diagonal: &[f64]) -> PairSolve {
        let n = inverse_diagonal.len();
        let mut count = vec![0u32; n + 1];
        for &r in &structure.rows {
            count[r as usize + 1] += 1;
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill: Vec<u32> = count[..n].to_vec();
        let mut cols = vec![0u32; structure.rows.len()];
        let mut row_values = vec![0.0; structure.rows.len()];
        for j in 0..n {
            let (a, b) = (structure.start[j] as usize, structure.start[j + 1] as usize);
            for (&i, &value) in structure.rows[a..b].iter().zip(&values[a..b]) {
                let i = i as usize;
                cols[fill[i] as usize] = j as u32;
                row_values[fill[i] as usize] = value;
                fill[i] += 1;
            }
        }
        // Each column's rows decreasing, so the backward pass's newest
        // unknowns (the rows just below the column) come last in its sum.
        let mut columns = structure.clone();
        let mut column_values = values.to_vec();
        for j in 0..n {
            let (a, b) = (structure.start[j] as usize, structure.start[j + 1] as usize);
            columns.rows[a..b].reverse();
            column_values[a..b].reverse();
        }
        PairSolve {
            inverse_diagonal: inverse_diagonal.to_vec(),
            rows: Structure::new(count, cols),
            row_values,
            columns,
            column_values,
        }
    }

    /// Number of unknowns: the length a right-hand side must have.
    pub fn dim(&self) -> usize {
        self.inverse_diagonal.len()
    }

    /// Solves `A x = b` in place.
    pub fn solve(&self, x: &mut [DVec2]) {
        assert_eq!(x.len(), self.dim(), "right-hand side length");
        pulp::Arch::new().dispatch(PairPasses { solve: self, x });
    }
}

struct PairPasses<'a> {
    solve: &'a PairSolve,
    x: &'a mut [DVec2],
}

impl pulp::WithSimd for PairPasses<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let PairSolve {
            ref inverse_diagonal,
            ref rows,
            ref row_values,
            ref columns,
            ref column_values,
        } = *self.solve;
        let x = self.x;
        let n = inverse_diagonal.len();
        assert!(x.len() == n && rows.start.len() == n + 1 && columns.start.len() == n + 1);
        assert!(rows.rows.len() == row_values.len() && columns.rows.len() == column_values.len());
        for i in 0..n {
            let (a, b) = (rows.start[i] as usize, rows.start[i + 1] as usize);
            let sum = pair_dot(&row_values[a..b], &rows.rows[a..b], x);
            x[i] = (x[i] - sum) * inverse_diagonal[i];
        }
        for j in (0..n).rev() {
            let (a, b) = (columns.start[j] as usize, columns.start[j + 1] as usize);
            prefetch_behind(column_values, &columns.rows, a);
            let sum = pair_dot(&column_values[a..b], &columns.rows[a..b], x);
            x[j] = (x[j] - sum) * inverse_diagonal[j];
        }
    }
}

/// `Σ l[k] · x[index[k]]`, two entries per four-lane sum.
#[inline(always)]
fn pair_dot(l: &[f64], index: &[u32], x: &[DVec2]) -> DVec2 {
    let mut acc = [[0.0f64; 4]; 2];
    let (lc, ic) = (l.chunks_exact(4), index.chunks_exact(4));
    let (lr, ir) = (lc.remainder(), ic.remainder());
    for (l, i) in lc.zip(ic) {
        for h in 0..2 {
            // SAFETY: `Structure::check` guarantees every index is below n
            // = x.len().
            let (a, b) = unsafe {
                (
                    *x.get_unchecked(i[2 * h] as usize),
                    *x.get_unchecked(i[2 * h + 1] as usize),
                )
            };
            let v = [a.x, a.y, b.x, b.y];
            let w = [l[2 * h], l[2 * h], l[2 * h + 1], l[2 * h + 1]];
            for q in 0..4 {
                acc[h][q] = w[q].mul_add(v[q], acc[h][q]);
            }
        }
    }
    let mut sum = DVec2::new(
        (acc[0][0] + acc[1][0]) + (acc[0][2] + acc[1][2]),
        (acc[0][1] + acc[1][1]) + (acc[0][3] + acc[1][3]),
    );
    for (&l, &i) in lr.iter().zip(ir) {
        // SAFETY: as above.
        let v = unsafe { *x.get_unchecked(i as usize) };
        sum = DVec2::new(l.mul_add(v.x, sum.x), l.mul_add(v.y, sum.y));
    }
    sum
}

/// The forward pass `L y = b` over `columns` (increasing), generic over the
/// column iterator so the full sweep compiles to a plain counted loop.
#[inline(always)]
fn forward_solve<L: Copy, V>(
    structure: &Structure,
    values: &[L],
    inverse_diagonal: &[f64],
    x: &mut [V],
    lower: &impl Fn(L, V) -> V,
    columns: impl Iterator<Item = u32>,
) where
    V: Value,
{
    let Structure { start, rows, .. } = structure;
    for j in columns {
        let j = j as usize;
        let xj = x[j] * inverse_diagonal[j];
        x[j] = xj;
        let (a, b) = (start[j] as usize, start[j + 1] as usize);
        for p in a..b {
            // SAFETY: `Structure::check` guarantees start is non-decreasing
            // up to rows.len() and every row index is below n = x.len().
            unsafe {
                let i = *rows.get_unchecked(p) as usize;
                let l = *values.get_unchecked(p);
                let xi = x.get_unchecked_mut(i);
                *xi = *xi - lower(l, xj);
            }
        }
    }
}

/// What the solves move through the factor: a number, an x,y pair, or a
/// complex number as (re, im).
pub trait Value:
    Copy
    + Default
    + std::ops::Sub<Output = Self>
    + std::ops::Add<Output = Self>
    + std::ops::Mul<f64, Output = Self>
{
}
impl Value for f64 {}
impl Value for DVec2 {}

/// Asks for the factor entries well before `position` — the backward pass
/// walks the factor from its end, a direction hardware prefetchers follow
/// poorly — so they arrive from memory before they are needed.
#[inline(always)]
fn prefetch_behind<L>(values: &[L], rows: &[u32], position: usize) {
    prefetch_one(values, position);
    prefetch_one(rows, position);
}

#[inline(always)]
fn prefetch_one<T>(items: &[T], position: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        const AHEAD_BYTES: usize = 2048;
        let lead = AHEAD_BYTES / std::mem::size_of::<T>().max(1);
        if position >= lead && position - lead < items.len() {
            // SAFETY: prefetching is a hint; the address is in bounds.
            unsafe {
                use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
                _mm_prefetch::<_MM_HINT_T0>(items.as_ptr().add(position - lead) as *const i8);
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (items, position);
}

/// The backward pass `Lᴴ x = y`, in place: `upper(l, v)` applies the
/// entry of `Lᴴ` matching `l`. Four partial sums let the dependent
/// additions overlap.
#[inline(always)]
fn backward_solve<L: Copy, V>(
    structure: &Structure,
    values: &[L],
    inverse_diagonal: &[f64],
    x: &mut [V],
    upper: &impl Fn(L, V) -> V,
) where
    V: Value,
{
    let Structure { start, rows, .. } = structure;
    let n = inverse_diagonal.len();
    assert!(x.len() == n && start.len() == n + 1 && rows.len() == values.len());
    for j in (0..n).rev() {
        let (a, b) = (start[j] as usize, start[j + 1] as usize);
        prefetch_behind(values, rows, a);
        let mut sums = [V::default(); 4];
        let mut p = a;
        while p + 4 <= b {
            for (lane, sum) in sums.iter_mut().enumerate() {
                // SAFETY: `Structure::check` guarantees start is
                // non-decreasing up to rows.len() and every row is below n.
                unsafe {
                    let i = *rows.get_unchecked(p + lane) as usize;
                    *sum = *sum + upper(*values.get_unchecked(p + lane), *x.get_unchecked(i));
                }
            }
            p += 4;
        }
        while p < b {
            // SAFETY: as above.
            unsafe {
                let i = *rows.get_unchecked(p) as usize;
                sums[0] = sums[0] + upper(*values.get_unchecked(p), *x.get_unchecked(i));
            }
            p += 1;
        }
        let total = (sums[0] + sums[1]) + (sums[2] + sums[3]);
        x[j] = (x[j] - total) * inverse_diagonal[j];
    }
}

/// A sparse vector: the forward-solved image `L⁻¹ b` of a right-hand side
/// `b` with few non-zeros, which is non-zero only on their reach.
#[derive(Debug, Clone, Default)]
pub struct SparseVector<T> {
    /// The unknowns the vector may be non-zero at (the right-hand side's
    /// reach in the elimination tree), in increasing order.
    pub indices: Vec<u32>,
    /// The entry at each of `indices`, in the same order.
    pub values: Vec<T>,
}

impl<T: Copy> SparseVector<T> {
    /// `Σ values[k] · x[indices[k]]` with `mul(value, x)`.
    #[inline]
    pub fn dot<V: Copy + std::ops::Add<Output = V>>(
        &self,
        x: &[V],
        zero: V,
        mul: impl Fn(T, V) -> V,
    ) -> V {
        self.indices
            .iter()
            .zip(&self.values)
            .fold(zero, |acc, (&i, &v)| acc + mul(v, x[i as usize]))
    }
}

/// Complex numbers as `DVec2` (re, im): `a.rotate(b)` is the product.
#[inline(always)]
fn complex_lower(l: DVec2, v: DVec2) -> DVec2 {
    l.rotate(v)
}

/// `conj(l) · v`.
#[inline(always)]
fn complex_upper(l: DVec2, v: DVec2) -> DVec2 {
    DVec2::new(l.x * v.x + l.y * v.y, l.x * v.y - l.y * v.x)
}

/// `L Lᴴ` of a complex Hermitian positive-definite sparse matrix; complex
/// numbers are `DVec2` (re, im).
#[derive(Debug, Clone)]
pub struct ComplexCholesky {
    structure: Structure,
    values: Vec<DVec2>,
    inverse_diagonal: Vec<f64>,
}

impl ComplexCholesky {
    /// Factors the Hermitian matrix whose upper triangle has `values`
    /// (complex as re, im) over `pattern`.
    pub fn new(pattern: &UpperPattern, values: &[DVec2]) -> Result<Self, FactorError> {
        let values: Vec<c64> = values.iter().map(|v| c64::new(v.x, v.y)).collect();
        let (structure, values, diagonal) = factor(pattern, &values)?;
        Ok(ComplexCholesky {
            structure,
            values: values.iter().map(|z| DVec2::new(z.re, z.im)).collect(),
            inverse_diagonal: diagonal.iter().map(|d| 1.0 / d.re).collect(),
        })
    }

    /// Number of unknowns: the length a right-hand side must have.
    pub fn dim(&self) -> usize {
        self.inverse_diagonal.len()
    }

    /// Stored entries of `L`, diagonal included: the factor's size (fill).
    pub fn factor_entries(&self) -> usize {
        self.values.len() + self.dim()
    }

    /// Solves `A x = b` in place.
    pub fn solve(&self, x: &mut [DVec2]) {
        assert_eq!(x.len(), self.dim(), "right-hand side length");
        let columns = 0..self.dim() as u32;
        forward_solve(
            &self.structure,
            &self.values,
            &self.inverse_diagonal,
            x,
            &complex_lower,
            columns,
        );
        backward_solve(
            &self.structure,
            &self.values,
            &self.inverse_diagonal,
            x,
            &complex_upper,
        );
    }

    /// Solves `A x = b` where `b` (in `x`) is zero outside `nonzeros`;
    /// the forward pass touches only the elimination-tree paths above them.
    pub fn solve_sparse(&self, x: &mut [DVec2], nonzeros: &[usize]) {
        assert_eq!(x.len(), self.dim(), "right-hand side length");
        let reach = self.structure.reach(nonzeros.iter().copied());
        forward_solve(
            &self.structure,
            &self.values,
            &self.inverse_diagonal,
            x,
            &complex_lower,
            reach.iter().copied(),
        );
        backward_solve(
            &self.structure,
            &self.values,
            &self.inverse_diagonal,
            x,
            &complex_upper,
        );
    }
}

/// The nodes on the paths from `starts` to the root of the tree `parent`
/// (`u32::MAX` above the root), each once, in increasing order: the
/// columns or supernodes a sparse right-hand side reaches in a forward
/// solve.
fn paths_to_root(parent: &[u32], starts: impl Iterator<Item = u32>) -> Vec<u32> {
    let mut seen = vec![false; parent.len()];
    let mut nodes = Vec::new();
    for mut node in starts {
        // Paths merge: stop at the first node already on one.
        while node != u32::MAX && !seen[node as usize] {
            seen[node as usize] = true;
            nodes.push(node);
            node = parent[node as usize];
        }
    }
    nodes.sort_unstable();
    nodes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A side×side grid graph's Laplacian plus the identity, in AMD order.
    fn grid_laplacian(side: u32) -> (UpperPattern, Vec<f64>, usize) {
        let n = (side * side) as usize;
        let mut edges = Vec::new();
        for y in 0..side {
            for x in 0..side {
                let v = y * side + x;
                if x + 1 < side {
                    edges.push((v, v + 1));
                }
                if y + 1 < side {
                    edges.push((v, v + side));
                }
                if x + 1 < side && y + 1 < side {
                    edges.push((v, v + side + 1));
                }
            }
        }
        let order = fill_reducing_order(n, &edges).unwrap();
        let mut new_of = vec![0u32; n];
        for (new, &old) in order.iter().enumerate() {
            new_of[old as usize] = new as u32;
        }
        let edges: Vec<(u32, u32)> = edges
            .iter()
            .map(|&(a, b)| (new_of[a as usize], new_of[b as usize]))
            .collect();
        let pattern = UpperPattern::new(n, &edges);
        let mut values = vec![0.0f64; pattern.len()];
        for i in 0..n {
            values[pattern.position(i, i)] += 1.0;
        }
        for &(a, b) in &edges {
            let (a, b) = (a as usize, b as usize);
            values[pattern.position(a, a)] += 1.0;
            values[pattern.position(b, b)] += 1.0;
            values[pattern.position(a, b)] -= 1.0;
        }
        (pattern, values, n)
    }

    /// Both of faer's factorisations read out into the same columns: the
    /// supernodal one (chosen for large meshes) gives the simplicial one's
    /// structure and values.
    #[test]
    fn supernodal_and_simplicial_factors_agree_column_by_column() {
        let (pattern, values, _) = grid_laplacian(12);
        let (s1, v1, d1) =
            factor_choosing(&pattern, &values, SupernodalThreshold::FORCE_SIMPLICIAL).unwrap();
        let (s2, v2, d2) =
            factor_choosing(&pattern, &values, SupernodalThreshold::FORCE_SUPERNODAL).unwrap();
        assert_eq!(s1.start, s2.start);
        assert_eq!(s1.rows, s2.rows);
        assert_eq!(s1.parent, s2.parent);
        assert!(
            s1.rows.len() > 2 * (pattern.len() - pattern.dim()) / 3,
            "fill-in to compare"
        );
        for (&a, &b) in v1.iter().zip(&v2).chain(d1.iter().zip(&d2)) {
            assert!((a - b).abs() <= 1e-12 * (1.0 + a.abs()), "{a} vs {b}");
        }
    }

    /// The supernodal solves (dense blocks, chosen for large factors) give
    /// the column-by-column solves' results, for pairs and single values,
    /// whole and sparse.
    #[test]
    fn supernodal_and_column_solves_agree() {
        let (pattern, values, n) = grid_laplacian(14);
        let columns =
            RealCholesky::choosing(&pattern, &values, SupernodalThreshold::FORCE_SIMPLICIAL)
                .unwrap();
        let blocks =
            RealCholesky::choosing(&pattern, &values, SupernodalThreshold::FORCE_SUPERNODAL)
                .unwrap();
        assert!(matches!(columns.layout, Layout::Columns { .. }));
        let Layout::Supernodes(supernodes) = &blocks.layout else {
            panic!("expected a supernodal factor");
        };
        assert!(
            (0..supernodes.count()).any(|s| supernodes.begin[s + 1] - supernodes.begin[s] >= 4),
            "wide supernodes to exercise the blocks"
        );
        assert_eq!(columns.factor_entries(), blocks.factor_entries());
        let rhs: Vec<DVec2> = (0..n)
            .map(|i| DVec2::new((i as f64 * 0.37).sin(), (i as f64 * 0.11).cos()))
            .collect();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-10 * (1.0 + a.abs());
        let (mut a, mut b) = (rhs.clone(), rhs.clone());
        columns.forward(&mut a);
        blocks.forward(&mut b);
        assert!(
            a.iter()
                .zip(&b)
                .all(|(p, q)| close(p.x, q.x) && close(p.y, q.y))
        );
        columns.backward(&mut a);
        blocks.backward(&mut b);
        assert!(
            a.iter()
                .zip(&b)
                .all(|(p, q)| close(p.x, q.x) && close(p.y, q.y))
        );
        let (mut a, mut b): (Vec<f64>, Vec<f64>) = (
            rhs.iter().map(|v| v.x).collect(),
            rhs.iter().map(|v| v.x).collect(),
        );
        columns.solve(&mut a);
        blocks.solve(&mut b);
        assert!(a.iter().zip(&b).all(|(&p, &q)| close(p, q)));
        for entries in [
            vec![(0, 1.0)],
            vec![(n / 2, 0.5), (n / 2 + 1, 0.25), (7, 0.25)],
        ] {
            let (sa, sb) = (
                columns.forward_sparse(&entries),
                blocks.forward_sparse(&entries),
            );
            let mut da = vec![0.0; n];
            let mut db = vec![0.0; n];
            for (&i, &v) in sa.indices.iter().zip(&sa.values) {
                da[i as usize] = v;
            }
            for (&i, &v) in sb.indices.iter().zip(&sb.values) {
                db[i as usize] = v;
            }
            let mut full = vec![0.0; n];
            for &(i, v) in &entries {
                full[i] += v;
            }
            columns.forward(&mut full);
            assert!(
                da.iter()
                    .zip(&db)
                    .zip(&full)
                    .all(|((&p, &q), &r)| close(p, r) && close(q, r))
            );
        }
    }

    /// The gather-only pair solves give the column solves' results, and
    /// solve the system: `A x` reproduces the right-hand side.
    #[test]
    fn pair_solves_agree_with_column_solves() {
        let (pattern, values, n) = grid_laplacian(13);
        let factor =
            RealCholesky::choosing(&pattern, &values, SupernodalThreshold::FORCE_SIMPLICIAL)
                .unwrap();
        let pairs = factor.pair_solve().expect("a column factor");
        let b: Vec<DVec2> = (0..n)
            .map(|i| DVec2::new((i as f64 * 0.7).sin(), (i as f64 * 0.3).cos() + 0.5))
            .collect();
        let (mut x, mut y) = (b.clone(), b.clone());
        factor.solve(&mut x);
        pairs.solve(&mut y);
        let scale = x.iter().map(|v| v.length()).fold(0.0, f64::max);
        for (p, q) in x.iter().zip(&y) {
            assert!(p.distance(*q) <= 1e-12 * scale, "{p} vs {q}");
        }
        // A y, from the upper triangle stored in the pattern.
        let mut product = vec![DVec2::ZERO; n];
        for col in 0..n {
            let (a, b) = (pattern.col_ptr[col], pattern.col_ptr[col + 1]);
            for (&row, &value) in pattern.rows[a..b].iter().zip(&values[a..b]) {
                product[row] += y[col] * value;
                if row != col {
                    product[col] += y[row] * value;
                }
            }
        }
        for (p, q) in product.iter().zip(&b) {
            assert!(p.distance(*q) <= 1e-10, "{p} vs {q}");
        }
        let supernodal =
            RealCholesky::choosing(&pattern, &values, SupernodalThreshold::FORCE_SUPERNODAL)
                .unwrap();
        assert!(supernodal.pair_solve().is_none());
    }
}
