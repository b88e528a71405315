//! Sparse Cholesky factors for the deformers. faer computes the fill-reducing
//! order and the numeric factor once; the solves are ours, so the frame path
//! never allocates, never permutes (callers number their unknowns in the
//! factor's order), and moves an x,y pair — or one complex number — per
//! entry of `L`, reading the factor once per pass instead of once per axis.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMat;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, SymbolicCholeskyRaw, SymmetricOrdering, factorize_symbolic_cholesky,
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
        let mut seen = vec![false; self.parent.len()];
        let mut columns = Vec::new();
        for mut j in nonzeros.map(|j| j as u32) {
            // Paths merge: stop at the first column already on one.
            while j != u32::MAX && !seen[j as usize] {
                seen[j as usize] = true;
                columns.push(j);
                j = self.parent[j as usize];
            }
        }
        columns.sort_unstable();
        columns
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

    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

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
/// factor's entries are exactly the simplicial ones, read out column by
/// column into the layout our solves use either way.
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
        supernodal_params: SymbolicSupernodalParams { relax: None },
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
    structure: Structure,
    values: Vec<f64>,
    inverse_diagonal: Vec<f64>,
}

impl RealCholesky {
    /// Factors the matrix with `values` over `pattern`.
    pub fn new(pattern: &UpperPattern, values: &[f64]) -> Result<Self, FactorError> {
        let (structure, values, diagonal) = factor(pattern, values)?;
        Ok(RealCholesky {
            structure,
            values,
            inverse_diagonal: diagonal.iter().map(|d| 1.0 / d).collect(),
        })
    }

    pub fn dim(&self) -> usize {
        self.inverse_diagonal.len()
    }

    pub fn factor_entries(&self) -> usize {
        self.values.len() + self.dim()
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
        let columns = 0..self.dim() as u32;
        let (values, inverse) = (&self.values, &self.inverse_diagonal);
        forward_solve(&self.structure, values, inverse, x, &|l, v| v * l, columns);
    }

    /// The backward half of [`RealCholesky::solve`]: `x ← L⁻ᵀ x`.
    pub fn backward<V: Value>(&self, x: &mut [V]) {
        let (values, inverse) = (&self.values, &self.inverse_diagonal);
        backward_solve(&self.structure, values, inverse, x, &|l, v| v * l);
    }

    /// `L⁻¹ b` for a right-hand side with a few non-zero `entries`
    /// (index, value): only the elimination-tree paths above them are
    /// touched, so this is far cheaper than a solve.
    pub fn forward_sparse(&self, entries: &[(usize, f64)]) -> SparseVector<f64> {
        let reach = self.structure.reach(entries.iter().map(|e| e.0));
        let mut dense = vec![0.0; self.dim()];
        for &(i, v) in entries {
            dense[i] += v;
        }
        forward_solve(
            &self.structure,
            &self.values,
            &self.inverse_diagonal,
            &mut dense,
            &|l, v| v * l,
            reach.iter().copied(),
        );
        let values = reach.iter().map(|&i| dense[i as usize]).collect();
        SparseVector {
            indices: reach,
            values,
        }
    }
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
    #[cfg(target_arch = "x86_64")]
    {
        const AHEAD_BYTES: usize = 2048;
        let value_lead = AHEAD_BYTES / std::mem::size_of::<L>().max(1);
        if position >= value_lead {
            // SAFETY: prefetching is a hint; the addresses are in bounds.
            unsafe {
                use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
                _mm_prefetch::<_MM_HINT_T0>(values.as_ptr().add(position - value_lead) as *const i8);
                _mm_prefetch::<_MM_HINT_T0>(rows.as_ptr().add(position - value_lead) as *const i8);
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (values, rows, position);
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
    pub indices: Vec<u32>,
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

    pub fn dim(&self) -> usize {
        self.inverse_diagonal.len()
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    /// Both of faer's factorisations read out into the same columns: the
    /// supernodal one (chosen for large meshes) gives the simplicial one's
    /// structure and values.
    #[test]
    fn supernodal_and_simplicial_factors_agree_column_by_column() {
        // A 12×12 grid graph's Laplacian plus the identity, in AMD order.
        let side = 12u32;
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
        let (s1, v1, d1) =
            factor_choosing(&pattern, &values, SupernodalThreshold::FORCE_SIMPLICIAL).unwrap();
        let (s2, v2, d2) =
            factor_choosing(&pattern, &values, SupernodalThreshold::FORCE_SUPERNODAL).unwrap();
        assert_eq!(s1.start, s2.start);
        assert_eq!(s1.rows, s2.rows);
        assert_eq!(s1.parent, s2.parent);
        assert!(s1.rows.len() > 2 * edges.len() / 3, "fill-in to compare");
        for (&a, &b) in v1.iter().zip(&v2).chain(d1.iter().zip(&d2)) {
            assert!((a - b).abs() <= 1e-12 * (1.0 + a.abs()), "{a} vs {b}");
        }
    }
}
