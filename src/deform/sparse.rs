//! Sparse symmetric positive-definite factorisations for the deformers: a thin
//! owner of faer's fill-reducing Cholesky factor with the scratch memory its
//! solves need, so that solving on the frame path never allocates.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Par, Side};

/// The factorisation failed: the matrix was not positive definite (a piece
/// the caller believed pinned was not) or memory ran out.
#[derive(Debug, thiserror::Error)]
#[error("sparse Cholesky factorisation failed: {0}")]
pub struct FactorError(String);

/// `L Lᵀ` of a sparse SPD matrix, with room to solve `columns` right-hand
/// sides at once without allocating.
pub struct SpdFactor {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    scratch: MemBuffer,
    columns: usize,
}

impl std::fmt::Debug for SpdFactor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpdFactor")
            .field("n", &self.symbolic.nrows())
            .field("factor_entries", &self.values.len())
            .finish()
    }
}

impl SpdFactor {
    /// Factors the `n`×`n` matrix whose upper-triangle entries are given as
    /// `(row, col, value)` with `row <= col`; repeated positions are summed.
    pub fn new(n: usize, upper: &[(usize, usize, f64)], columns: usize) -> Result<Self, FactorError> {
        let triplets: Vec<Triplet<usize, usize, f64>> =
            upper.iter().map(|&(r, c, v)| Triplet::new(r, c, v)).collect();
        let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &triplets)
            .map_err(|e| FactorError(format!("{e:?}")))?;
        let symbolic = factorize_symbolic_cholesky(
            matrix.symbolic(),
            Side::Upper,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| FactorError(format!("{e:?}")))?;
        let mut values = vec![0.0; symbolic.len_val()];
        let mut work = MemBuffer::try_new(symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()))
            .map_err(|_| FactorError("out of memory".into()))?;
        symbolic
            .factorize_numeric_llt(
                &mut values,
                matrix.as_ref(),
                Side::Upper,
                Default::default(),
                Par::Seq,
                MemStack::new(&mut work),
                Default::default(),
            )
            .map_err(|e| FactorError(format!("{e:?}")))?;
        let scratch = MemBuffer::try_new(symbolic.solve_in_place_scratch::<f64>(columns, Par::Seq))
            .map_err(|_| FactorError("out of memory".into()))?;
        Ok(SpdFactor {
            symbolic,
            values,
            scratch,
            columns,
        })
    }

    pub fn dim(&self) -> usize {
        self.symbolic.nrows()
    }

    /// Number of stored entries of `L`, a proxy for the cost of a solve.
    pub fn factor_entries(&self) -> usize {
        self.values.len()
    }

    /// Overwrites `rhs` (column-major, `dim()` rows, up to `columns` columns)
    /// with the solution of `A x = rhs`.
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) {
        let n = self.dim();
        let k = rhs.len() / n;
        assert!(k * n == rhs.len() && k <= self.columns, "right-hand side shape");
        let rhs = MatMut::from_column_major_slice_mut(rhs, n, k);
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            rhs,
            Par::Seq,
            MemStack::new(&mut self.scratch),
        );
    }
}
