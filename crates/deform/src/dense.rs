//! Small dense systems factored on the calling thread: ARAP's inverse of
//! its handle system and the RBF interpolant's refined inverse both start
//! from one LU factorisation with partial pivoting. faer's convenience API
//! would fan out to its thread pool, whose wake-ups cost more than the
//! arithmetic at these sizes.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::lu::partial_pivoting::factor::{lu_in_place, lu_in_place_scratch};
use faer::perm::PermRef;
use faer::traits::ComplexField;
use faer::{Mat, MatRef, Par};

/// A square matrix factored in place, `P A = L U`, with the scratch its
/// caller asked room for.
pub(crate) struct SequentialLu<T: ComplexField> {
    /// The unit lower factor below the diagonal and the upper factor on
    /// and above it, in one matrix.
    lu: Mat<T>,
    forward: Vec<usize>,
    backward: Vec<usize>,
    memory: MemBuffer,
}

impl<T: ComplexField> SequentialLu<T> {
    /// Factors `matrix`, keeping scratch for the factorisation and for
    /// `then` (what the caller does with the factors).
    pub(crate) fn new(mut matrix: Mat<T>, then: StackReq) -> SequentialLu<T> {
        let n = matrix.nrows();
        let mut forward = vec![0usize; n];
        let mut backward = vec![0usize; n];
        let scratch = lu_in_place_scratch::<usize, T>(n, n, Par::Seq, Default::default()).or(then);
        let mut memory = MemBuffer::new(scratch);
        lu_in_place(
            matrix.as_mut(),
            &mut forward,
            &mut backward,
            Par::Seq,
            MemStack::new(&mut memory),
            Default::default(),
        );
        SequentialLu {
            lu: matrix,
            forward,
            backward,
            memory,
        }
    }

    /// The factors (as [`SequentialLu::lu`] holds them), the row
    /// permutation, and the scratch.
    pub(crate) fn parts(&mut self) -> (MatRef<'_, T>, PermRef<'_, usize>, &mut MemStack) {
        let n = self.lu.nrows();
        (
            self.lu.as_ref(),
            PermRef::new_checked(&self.forward, &self.backward, n),
            MemStack::new(&mut self.memory),
        )
    }
}
