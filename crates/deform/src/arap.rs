//! The two-step as-rigid-as-possible solver of Igarashi, Moscovich & Hughes
//! (2005), "As-Rigid-As-Possible Shape Manipulation" (SIGGRAPH 2005);
//! `docs/solver.md` explains it as built here.
//!
//! Step 1 finds the scale-free shape (energy `vᵀGv`), step 2a fits a rotated
//! rest triangle to each step-1 triangle, step 2b assembles them (energy with
//! the weighted edge Laplacian `H`). Handles are linear constraints `B v = q`
//! — a vertex, or a barycentric point inside a triangle — so a finger can land
//! anywhere.
//!
//! How handle-set changes stay cheap: each connected piece's `G` and `H` are
//! made positive definite once, at registration, by adding `δ` on a few
//! "anchor" coordinates (`K = A + δ E Eᵀ`), and factored once (`K = L Lᴴ`).
//! The constrained minimum is then `v = K⁻¹(b + B̃ᵀ ξ)` (`B̃ = [B; Eᵀ]`) with
//! `ξ` from a small dense system `(B̃ K⁻¹ B̃ᵀ − diag(0, I/δ)) ξ = [q; 0] −
//! B̃ K⁻¹ b`. This is exactly the KKT solution of the original singular
//! problem — the anchors carry no stiffness, their values are unknowns — so
//! the sparse factors never change with the handles:
//!
//! - step 1 (`b = 0`) keeps per handle the dense column `K₁⁻¹ B̃ₕᵀ`, so a frame
//!   is a sum of columns; a new handle costs one sparse solve;
//! - step 2 keeps per handle only `L₂⁻¹ B̃ₕᵀ`, non-zero along one path of the
//!   elimination tree, so a new handle costs a partial forward solve and a
//!   frame's solve takes a sparse correction between its two passes.
//!
//! Removing a handle costs no sparse work at all.
//!
//! Step 1 is solved in complex numbers (a point is `x + iy`): its energy is
//! invariant under rotation and scale, so `G` is a complex-linear Hermitian
//! operator and a single complex solve gives both the x- and the y-row
//! columns of a handle. Each piece numbers its vertices in the factors'
//! fill-reducing order, so no solve permutes.
//!
//! Pieces with fewer than two handles cannot be solved (rotation and scale are
//! free); they are placed rigidly as `algorithms.md` prescribes.

use faer::Par;
use faer::linalg::lu::partial_pivoting::inverse;
use faer::traits::ComplexField;
use faer::{Mat, c64};
use glam::DVec2;
use std::collections::HashMap;

use super::dense::SequentialLu;
use super::sparse::{
    ComplexCholesky, FactorError, RealCholesky, SparseVector, UpperPattern, fill_reducing_order,
};
use super::targets::{self, TargetError};
use puppetry_mesh::Mesh;

/// Where a handle holds the mesh, in rest terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Anchor {
    /// A mesh vertex.
    Vertex(u32),
    /// A point inside a triangle, as barycentric weights of its corners
    /// (non-negative, summing to 1).
    Point {
        /// Index into the mesh's triangles.
        triangle: u32,
        /// Weights of the triangle's corners, in its corner order.
        bary: [f64; 3],
    },
}

/// Which steps an update runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Steps {
    /// Step 1 only: the scale-free intermediate result.
    ScaleFree,
    /// Steps 1 and 2: the as-rigid-as-possible result.
    Both,
}

/// Why [`Arap`] refused a mesh, a handle set or a frame's targets. A
/// `handle` is the handle's index in the slice given to [`Arap::compile`]
/// (or [`Arap::update`]).
#[derive(Debug, thiserror::Error)]
pub enum ArapError {
    /// [`Arap::compile`]: an [`Anchor::Vertex`] names a vertex the mesh
    /// does not have.
    #[error("handle {handle}: vertex {vertex} is out of range (the mesh has {count} vertices)")]
    VertexOutOfRange {
        /// The offending handle's index.
        handle: usize,
        /// The vertex it named.
        vertex: u32,
        /// How many vertices the mesh has.
        count: usize,
    },
    /// [`Arap::compile`]: an [`Anchor::Point`] names a triangle the mesh
    /// does not have.
    #[error(
        "handle {handle}: triangle {triangle} is out of range (the mesh has {count} triangles)"
    )]
    TriangleOutOfRange {
        /// The offending handle's index.
        handle: usize,
        /// The triangle it named.
        triangle: u32,
        /// How many triangles the mesh has.
        count: usize,
    },
    /// [`Arap::compile`]: an [`Anchor::Point`]'s weights are not finite,
    /// dip below zero, or do not sum to 1 (to within 1e-9).
    #[error(
        "handle {handle}: barycentric weights {bary:?} must be finite, non-negative and sum to 1"
    )]
    BadBarycentric {
        /// The offending handle's index.
        handle: usize,
        /// The weights it gave.
        bary: [f64; 3],
    },
    /// [`Arap::update`]: the targets are not one per anchor of the last
    /// [`Arap::compile`], or one is not a finite point within range.
    #[error(transparent)]
    Targets(#[from] TargetError),
    /// [`Arap::register`]: a piece's matrices could not be factored.
    #[error("piece {piece}: {source}")]
    Factor {
        /// Index of the connected piece, in the mesh's piece order.
        piece: usize,
        /// Why the factorisation failed.
        source: FactorError,
    },
}

/// One triangle of a piece, in the piece's local vertex numbering.
#[derive(Debug, Clone)]
struct LocalTriangle {
    corners: [u32; 3],
    /// Rest corners relative to the rest centroid, times `3·w`: the step-2a
    /// fit target, scaled so the fitted corners are the right-hand side terms
    /// directly (see `PieceSolver::update`).
    scaled_centred: [DVec2; 3],
}

/// A handle's constraint row over a piece's local vertices.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Row {
    corners: [u32; 3],
    weights: [f64; 3],
}

impl Row {
    /// `Σ wᵢ x[corner]` over one value (real, pair or complex) per vertex.
    #[inline]
    fn dot<T>(&self, x: &[T]) -> T
    where
        T: Copy + std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>,
    {
        x[self.corners[0] as usize] * self.weights[0]
            + x[self.corners[1] as usize] * self.weights[1]
            + x[self.corners[2] as usize] * self.weights[2]
    }
}

impl Row {
    /// The dot product of two rows over the same piece's vertices.
    fn dot_row(&self, other: &Row) -> f64 {
        let mut sum = 0.0;
        for (a, wa) in self.corners.iter().zip(self.weights) {
            for (b, wb) in other.corners.iter().zip(other.weights) {
                if a == b {
                    sum += wa * wb;
                }
            }
        }
        sum
    }
}

/// How far a handle's constraint row must stand from the span of the newer
/// kept handles' rows to be kept: its squared distance from that span over
/// its own squared length. Two kept handles whose weights differ by `d` on
/// a corner make the mesh stretch by about `1/d` times their targets'
/// disagreement there (a corner moves by the disagreement over `d`), and
/// their rows stand about `2d²` apart. At 0.05, `d` is at least about a
/// sixth: a held set stretches at most about six times the distance between
/// its targets, so a pin and a finger a hair apart pulled across the stage
/// stay within a few stages of it (the simulated show found 30 stages at
/// 0.01). Two points in one triangle are kept when about a third of it
/// apart: two fingertips on any mesh the tracer makes.
const INDEPENDENCE: f64 = 0.05;

/// Which handles to keep, given each one's piece and constraint row. Walking
/// from the newest, a handle is kept when its row stands at least
/// [`INDEPENDENCE`] from the span of the rows kept before it, measured by
/// an incremental Cholesky factor of their Gram matrix. Rows meet only
/// through shared vertices, so handles are grouped into clusters joined by
/// shared vertices, each with a factor of its own: handles far apart never
/// meet, and a frame's usual handful of fingers costs a few dot products.
fn independent(rows: &[(u32, Row)]) -> Vec<bool> {
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let k = rows.len();
    let mut parent: Vec<usize> = (0..k).collect();
    let mut first_on: HashMap<(u32, u32), usize> = HashMap::new();
    for (h, (piece, row)) in rows.iter().enumerate() {
        for (&corner, weight) in row.corners.iter().zip(row.weights) {
            if weight == 0.0 {
                continue;
            }
            let earlier = *first_on.entry((*piece, corner)).or_insert(h);
            let (a, b) = (find(&mut parent, earlier), find(&mut parent, h));
            parent[a] = b;
        }
    }
    let mut live = vec![false; k];
    // Per cluster root: the kept handles and the rows of the lower
    // triangular factor of their Gram matrix.
    let mut clusters: HashMap<usize, (Vec<usize>, Vec<Vec<f64>>)> = HashMap::new();
    for h in (0..k).rev() {
        let row = &rows[h].1;
        let (kept, factor) = clusters.entry(find(&mut parent, h)).or_default();
        let own = row.dot_row(row);
        let mut y: Vec<f64> = Vec::with_capacity(kept.len() + 1);
        for (i, &other) in kept.iter().enumerate() {
            let along: f64 = factor[i][..i].iter().zip(&y).map(|(l, y)| l * y).sum();
            y.push((row.dot_row(&rows[other].1) - along) / factor[i][i]);
        }
        let pivot = own - y.iter().map(|v| v * v).sum::<f64>();
        if pivot > INDEPENDENCE * own {
            y.push(pivot.sqrt());
            factor.push(y);
            kept.push(h);
            live[h] = true;
        }
    }
    live
}

/// A compiled handle inside a piece, with its columns of `W`.
#[derive(Debug, Clone)]
struct PieceHandle {
    anchor: Anchor,
    row: Row,
    rest_point: DVec2,
    /// Index into the caller's targets.
    target: usize,
    /// `K₁⁻¹ Bₕᵀ` (complex, n).
    step1_column: SplitComplex,
    /// `L₂⁻¹ Bₕᵀ` with `K₂ = L₂L₂ᵀ`: sparse, since the row has at most
    /// three non-zeros.
    step2_forward: SparseVector<f64>,
}

/// How a piece is placed for its current handle count.
#[derive(Debug, Clone)]
enum Placement {
    /// No handle: a fixed rigid placement, written at compile time.
    Fixed,
    /// One handle: the rest shape rotated by `rotation` (cos, sin) and carried
    /// by the handle.
    Carried { rotation: DVec2 },
    /// Two or more handles: solved; the inverses of the small systems
    /// (column-major; step 1 complex).
    Solved {
        step1_inverse: Vec<DVec2>,
        step2_inverse: Vec<f64>,
    },
}

/// A complex vector as separate real and imaginary parts, so the per-frame
/// sums over columns run as plain, vectorisable f64 loops.
#[derive(Debug, Clone, Default)]
struct SplitComplex {
    re: Vec<f64>,
    im: Vec<f64>,
}

/// A placeholder column for unused slots of a group.
static EMPTY: &SplitComplex = &SplitComplex {
    re: Vec::new(),
    im: Vec::new(),
};

impl SplitComplex {
    fn from_pairs(pairs: &[DVec2]) -> SplitComplex {
        SplitComplex {
            re: pairs.iter().map(|z| z.x).collect(),
            im: pairs.iter().map(|z| z.y).collect(),
        }
    }
    fn zeros(n: usize) -> SplitComplex {
        SplitComplex {
            re: vec![0.0; n],
            im: vec![0.0; n],
        }
    }
    #[inline]
    fn get(&self, i: usize) -> DVec2 {
        DVec2::new(self.re[i], self.im[i])
    }
    /// `self = Σ zₖ · columnₖ`, up to four columns per pass over the vectors:
    /// at large sizes the sum is bound by memory traffic, and each pass
    /// reads and writes `self` once.
    fn set_combination<'a>(&mut self, terms: impl Iterator<Item = (DVec2, &'a SplitComplex)>) {
        let mut group: [(DVec2, &SplitComplex); 4] = [(DVec2::ZERO, EMPTY); 4];
        let mut filled = 0;
        let mut first = true;
        for term in terms {
            group[filled] = term;
            filled += 1;
            if filled == 4 {
                self.combine::<4>(&group, first);
                first = false;
                filled = 0;
            }
        }
        match filled {
            1 => self.combine::<1>(&group, first),
            2 => self.combine::<2>(&group, first),
            3 => self.combine::<3>(&group, first),
            _ if first => {
                self.re.fill(0.0);
                self.im.fill(0.0);
            }
            _ => {}
        }
    }

    /// `self (= or +=) Σ zₖ · columnₖ` over the first `C` terms.
    #[inline]
    fn combine<const C: usize>(&mut self, terms: &[(DVec2, &SplitComplex); 4], assign: bool) {
        let n = self.re.len();
        let (re, im) = (&mut self.re[..n], &mut self.im[..n]);
        let z: [DVec2; C] = std::array::from_fn(|c| terms[c].0);
        let cr: [&[f64]; C] = std::array::from_fn(|c| &terms[c].1.re[..n]);
        let ci: [&[f64]; C] = std::array::from_fn(|c| &terms[c].1.im[..n]);
        for i in 0..n {
            let (mut r, mut m) = if assign { (0.0, 0.0) } else { (re[i], im[i]) };
            for c in 0..C {
                r += z[c].x * cr[c][i] - z[c].y * ci[c][i];
                m += z[c].x * ci[c][i] + z[c].y * cr[c][i];
            }
            re[i] = r;
            im[i] = m;
        }
    }
}

/// The small systems of a solved piece before inversion, kept so the next
/// handle change can reuse the entries of handles that stay.
#[derive(Debug, Clone)]
struct Gram {
    handles: usize,
    step1: Mat<c64>,
    step2: Mat<f64>,
}

/// Everything about one connected piece.
#[derive(Debug)]
struct PieceSolver {
    /// Global vertex ids, in the factors' order (local index = position).
    vertices: Vec<u32>,
    rest: Vec<DVec2>,
    triangles: Vec<LocalTriangle>,
    step1: ComplexCholesky,
    step2: RealCholesky,
    /// Step 1 anchors two vertices (pins similarity), step 2 one (pins
    /// translation).
    step1_anchors: [usize; 2],
    step1_delta: f64,
    step2_delta: f64,
    /// `K₁⁻¹ E₁` (two complex columns) and `L₂⁻¹ E₂`.
    step1_anchor_columns: [SplitComplex; 2],
    step2_anchor_forward: SparseVector<f64>,
    handles: Vec<PieceHandle>,
    placement: Placement,
    gram: Option<Gram>,
    // Frame scratch, sized at compile time.
    step1_rhs: Vec<DVec2>,
    step1_xi: Vec<DVec2>,
    step1_pose: SplitComplex,
    step2_rhs: Vec<DVec2>,
    step2_xi: Vec<DVec2>,
    step2_pose: Vec<DVec2>,
}

/// The registered solver for one rest mesh. See the module docs for the
/// phases: [`Arap::register`], [`Arap::compile`], [`Arap::update`].
#[derive(Debug)]
pub struct Arap {
    rest: Vec<DVec2>,
    triangles: Vec<[u32; 3]>,
    /// For each vertex, (piece, local index).
    vertex_home: Vec<(u32, u32)>,
    pieces: Vec<PieceSolver>,
    handle_count: usize,
    pose: Vec<DVec2>,
}

/// Best rotation (as cos, sin) taking `rest` onto `pose` about their
/// centroids, and the two centroids; identity when undetermined.
fn fit_rotation(pairs: impl Iterator<Item = (DVec2, DVec2)> + Clone) -> (DVec2, DVec2, DVec2) {
    let mut count = 0.0;
    let (mut rest_mean, mut pose_mean) = (DVec2::ZERO, DVec2::ZERO);
    for (r, p) in pairs.clone() {
        rest_mean += r;
        pose_mean += p;
        count += 1.0;
    }
    rest_mean /= count;
    pose_mean /= count;
    let (mut dot, mut crs) = (0.0, 0.0);
    for (r, p) in pairs {
        let (r, p) = (r - rest_mean, p - pose_mean);
        dot += r.dot(p);
        crs += r.perp_dot(p);
    }
    (unit_rotation(dot, crs), rest_mean, pose_mean)
}

#[inline]
fn unit_rotation(dot: f64, crs: f64) -> DVec2 {
    let norm2 = dot * dot + crs * crs;
    if norm2 > 0.0 && norm2.is_finite() {
        DVec2::new(dot, crs) / norm2.sqrt()
    } else {
        DVec2::X
    }
}

/// The inverse of a small dense matrix by LU with partial pivoting, on this
/// thread: faer's convenience API would fan out to its thread pool, whose
/// wake-ups cost more than the arithmetic at these sizes.
fn inverse_sequential<T: ComplexField>(matrix: Mat<T>) -> Mat<T> {
    let n = matrix.nrows();
    let mut factored = SequentialLu::new(matrix, inverse::inverse_scratch::<usize, T>(n, Par::Seq));
    let (lu, permutation, stack) = factored.parts();
    let lower = Mat::<T>::from_fn(n, n, |i, j| match i.cmp(&j) {
        std::cmp::Ordering::Greater => lu[(i, j)].clone(),
        std::cmp::Ordering::Equal => T::one_impl(),
        std::cmp::Ordering::Less => T::zero_impl(),
    });
    let upper = Mat::<T>::from_fn(n, n, |i, j| {
        if i <= j {
            lu[(i, j)].clone()
        } else {
            T::zero_impl()
        }
    });
    let mut out = Mat::<T>::zeros(n, n);
    inverse::inverse(
        out.as_mut(),
        lower.as_ref(),
        upper.as_ref(),
        permutation,
        Par::Seq,
        stack,
    );
    out
}

/// Complex division `a / b` on (re, im) pairs.
#[inline]
fn complex_div(a: DVec2, b: DVec2) -> DVec2 {
    a.rotate(DVec2::new(b.x, -b.y)) / b.length_squared()
}

impl Arap {
    /// Registration: precomputes and factors everything that depends only on
    /// the rest mesh. No handles are set; [`Arap::pose`] is the rest shape.
    pub fn register(mesh: &Mesh) -> Result<Arap, ArapError> {
        let rest = mesh.vertices().to_vec();
        let triangles = mesh.triangles().to_vec();
        let mut vertex_home = vec![(0u32, 0u32); rest.len()];
        let mut pieces = Vec::new();
        for (p, piece) in mesh.pieces().into_iter().enumerate() {
            let solver = PieceSolver::register(
                mesh,
                &piece.vertices,
                &piece.triangles,
                &mut vertex_home,
                p as u32,
            )
            .map_err(|source| ArapError::Factor { piece: p, source })?;
            pieces.push(solver);
        }
        Ok(Arap {
            pose: rest.clone(),
            rest,
            triangles,
            vertex_home,
            pieces,
            handle_count: 0,
        })
    }

    /// Compilation: sets the handle set. Handles present in the previous set
    /// keep their precomputed columns; each new one costs one complex and one
    /// real sparse solve in its own piece. Pieces left with fewer than two
    /// handles are fixed rigidly in their current pose.
    ///
    /// Handles that (nearly) repeat newer ones are left out: the later
    /// wins. Two handles on one rest point, three on a line inside one
    /// triangle, four in one triangle, or a finger a hair from a pin ask the
    /// mesh for constraints that are linearly dependent, or so nearly that
    /// the small systems lose every digit and the pose flies off (see
    /// `independent`). Leaving the older handle out keeps the pose where
    /// the newer one puts it, which is what a finger landing on a held point
    /// means.
    pub fn compile(&mut self, anchors: &[Anchor]) -> Result<(), ArapError> {
        let mut rows = Vec::with_capacity(anchors.len());
        for (h, anchor) in anchors.iter().enumerate() {
            rows.push(self.resolve(h, anchor)?);
        }
        let keyed: Vec<(u32, Row)> = rows.iter().map(|r| (r.0 as u32, r.1)).collect();
        let live = independent(&keyed);
        let mut per_piece: Vec<Vec<(usize, Anchor, Row, DVec2)>> =
            vec![Vec::new(); self.pieces.len()];
        for (h, (piece, row, point)) in rows.into_iter().enumerate() {
            if live[h] {
                per_piece[piece].push((h, anchors[h], row, point));
            }
        }
        for (p, wanted) in per_piece.into_iter().enumerate() {
            let piece = &mut self.pieces[p];
            let unchanged = piece.handles.len() == wanted.len()
                && piece
                    .handles
                    .iter()
                    .zip(&wanted)
                    .all(|(old, new)| old.anchor == new.1);
            if unchanged {
                for (old, new) in piece.handles.iter_mut().zip(&wanted) {
                    old.target = new.0;
                }
                continue;
            }
            piece.compile(wanted, &mut self.pose);
        }
        self.handle_count = anchors.len();
        Ok(())
    }

    fn resolve(&self, handle: usize, anchor: &Anchor) -> Result<(usize, Row, DVec2), ArapError> {
        let (vertices, weights) = match *anchor {
            Anchor::Vertex(v) => {
                if v as usize >= self.rest.len() {
                    return Err(ArapError::VertexOutOfRange {
                        handle,
                        vertex: v,
                        count: self.rest.len(),
                    });
                }
                ([v; 3], [1.0, 0.0, 0.0])
            }
            Anchor::Point { triangle, bary } => {
                let Some(&tri) = self.triangles.get(triangle as usize) else {
                    return Err(ArapError::TriangleOutOfRange {
                        handle,
                        triangle,
                        count: self.triangles.len(),
                    });
                };
                let sum: f64 = bary.iter().sum();
                if bary.iter().any(|b| !b.is_finite() || *b < -1e-12) || (sum - 1.0).abs() > 1e-9 {
                    return Err(ArapError::BadBarycentric { handle, bary });
                }
                (tri, bary)
            }
        };
        let (piece, _) = self.vertex_home[vertices[0] as usize];
        let row = Row {
            corners: vertices.map(|v| self.vertex_home[v as usize].1),
            weights,
        };
        let point = vertices
            .iter()
            .zip(weights)
            .map(|(&v, w)| self.rest[v as usize] * w)
            .sum();
        Ok((piece as usize, row, point))
    }

    /// Update: moves the compiled handles to `targets` (same order as the
    /// anchors given to [`Arap::compile`]; a handle left out as dependent
    /// has its target read and ignored) and recomputes the pose.
    /// Does not allocate.
    pub fn update(&mut self, targets: &[DVec2], steps: Steps) -> Result<&[DVec2], ArapError> {
        targets::check(targets, self.handle_count)?;
        for piece in &mut self.pieces {
            piece.update(targets, steps, &mut self.pose);
        }
        Ok(&self.pose)
    }

    /// Puts every vertex back at rest and forgets the handle set (a
    /// reset): pieces with fewer than two handles keep whatever pose they
    /// were left in, so without this a puppet dropped off its pins stays
    /// where it was dropped. The next [`Arap::compile`] starts afresh.
    pub fn rest_pose(&mut self) {
        self.pose.copy_from_slice(&self.rest);
        for piece in &mut self.pieces {
            piece.handles.clear();
            piece.gram = None;
            piece.placement = Placement::Fixed;
        }
        self.handle_count = 0;
    }

    /// The current deformed vertex positions (rest order).
    pub fn pose(&self) -> &[DVec2] {
        &self.pose
    }

    /// The rest vertex positions the solver was registered with.
    pub fn rest(&self) -> &[DVec2] {
        &self.rest
    }

    /// Number of connected pieces.
    pub fn piece_count(&self) -> usize {
        self.pieces.len()
    }
}

/// Two far-apart points of `rest` (not empty): the leftmost and the one
/// farthest from it. Anchored there, the similarity modes are well
/// conditioned.
fn far_apart(rest: &[DVec2]) -> [usize; 2] {
    let n = rest.len();
    let first = (0..n)
        .min_by(|&i, &j| rest[i].x.total_cmp(&rest[j].x))
        .expect("a piece has vertices");
    let second = (0..n)
        .max_by(|&i, &j| {
            rest[i]
                .distance_squared(rest[first])
                .total_cmp(&rest[j].distance_squared(rest[first]))
        })
        .expect("a piece has vertices");
    [first, second]
}

impl PieceSolver {
    /// Registers one piece: orders its vertices, assembles `K₁` and `K₂`,
    /// factors them and solves the anchor columns. Fills `vertex_home`.
    fn register(
        mesh: &Mesh,
        piece_vertices: &[u32],
        piece_triangles: &[u32],
        vertex_home: &mut [(u32, u32)],
        piece: u32,
    ) -> Result<PieceSolver, FactorError> {
        let n = piece_vertices.len();
        for (local, &v) in piece_vertices.iter().enumerate() {
            vertex_home[v as usize] = (piece, local as u32);
        }
        let local = |v: u32, home: &[(u32, u32)]| home[v as usize].1;
        let mut edges = Vec::with_capacity(piece_triangles.len() * 3);
        for &t in piece_triangles {
            let tri = mesh.triangles()[t as usize];
            for k in 0..3 {
                edges.push((
                    local(tri[k], vertex_home),
                    local(tri[(k + 1) % 3], vertex_home),
                ));
            }
        }
        let order = fill_reducing_order(n, &edges)?;
        let vertices: Vec<u32> = order.iter().map(|&o| piece_vertices[o as usize]).collect();
        for (new, &v) in vertices.iter().enumerate() {
            vertex_home[v as usize] = (piece, new as u32);
        }
        let rest: Vec<DVec2> = vertices
            .iter()
            .map(|&v| mesh.vertices()[v as usize])
            .collect();

        let local_edges: Vec<(u32, u32)> = edges
            .iter()
            .map(|&(a, b)| {
                (
                    local(piece_vertices[a as usize], vertex_home),
                    local(piece_vertices[b as usize], vertex_home),
                )
            })
            .collect();
        let pattern = UpperPattern::new(n, &local_edges);
        let mut triangles = Vec::with_capacity(piece_triangles.len());
        let mut g = vec![DVec2::ZERO; pattern.len()];
        let mut h = vec![0.0; pattern.len()];
        for &t in piece_triangles {
            let w = mesh.weights()[t as usize];
            let corners = mesh.triangles()[t as usize].map(|v| local(v, vertex_home));
            let pts = corners.map(|c| rest[c as usize]);
            let centroid = (pts[0] + pts[1] + pts[2]) / 3.0;
            triangles.push(LocalTriangle {
                corners,
                scaled_centred: pts.map(|q| (q - centroid) * (3.0 * w)),
            });
            // The triangle's six entries in the pattern, looked up once:
            // `at[a][b]` for corners a and b.
            let mut at = [[0usize; 3]; 3];
            for a in 0..3 {
                for b in a..3 {
                    let position = pattern.position(corners[a] as usize, corners[b] as usize);
                    at[a][b] = position;
                    at[b][a] = position;
                }
            }
            for k in 0..3 {
                // Corner c in the frame of the opposite edge a→b, as the
                // complex ratio z = (c − a)/(b − a); the error
                // e = v_c − v_a − z (v_b − v_a) has coefficients γ over (a, b, c).
                let which = [(k + 1) % 3, (k + 2) % 3, k];
                let idx = which.map(|c| corners[c] as usize);
                let [pa, pb, pc] = idx.map(|i| rest[i]);
                let z = complex_div(pc - pa, pb - pa);
                let gamma = [z - DVec2::X, -z, DVec2::X];
                for r in 0..3 {
                    for s in 0..3 {
                        if idx[r] <= idx[s] {
                            // A_rs += w conj(γ_r) γ_s (upper triangle only).
                            let value = DVec2::new(gamma[r].x, -gamma[r].y).rotate(gamma[s]) * w;
                            g[at[which[r]][which[s]]] += value;
                        }
                    }
                }
                let (i, j) = (which[0], which[1]);
                h[at[i][i]] += w;
                h[at[j][j]] += w;
                h[at[i][j]] -= w;
            }
        }
        // Cache-friendly sweep order for the per-frame fit.
        triangles.sort_by_key(|t| *t.corners.iter().min().unwrap());

        let diagonal = |i: usize| pattern.position(i, i);
        let step1_delta = (0..n).map(|i| g[diagonal(i)].x).sum::<f64>() / n as f64;
        let step2_delta = (0..n).map(|i| h[diagonal(i)]).sum::<f64>() / n as f64;
        let [first, second] = far_apart(&rest);
        for a in [first, second] {
            g[diagonal(a)].x += step1_delta;
        }
        h[diagonal(first)] += step2_delta;
        let step1 = ComplexCholesky::new(&pattern, &g)?;
        let step2 = RealCholesky::new(&pattern, &h)?;
        let step1_anchor_columns = [first, second].map(|a| {
            let mut column = vec![DVec2::ZERO; n];
            column[a] = DVec2::X;
            step1.solve(&mut column);
            SplitComplex::from_pairs(&column)
        });
        let step2_anchor_forward = step2.forward_sparse(&[(first, 1.0)]);
        Ok(PieceSolver {
            vertices,
            rest,
            triangles,
            step1,
            step2,
            step1_anchors: [first, second],
            step1_delta,
            step2_delta,
            step1_anchor_columns,
            step2_anchor_forward,
            handles: Vec::new(),
            placement: Placement::Fixed,
            gram: None,
            step1_rhs: Vec::new(),
            step1_xi: Vec::new(),
            step1_pose: SplitComplex::zeros(n),
            step2_rhs: Vec::new(),
            step2_xi: Vec::new(),
            step2_pose: vec![DVec2::ZERO; n],
        })
    }

    fn n(&self) -> usize {
        self.rest.len()
    }

    fn compile(&mut self, wanted: Vec<(usize, Anchor, Row, DVec2)>, pose: &mut [DVec2]) {
        let n = self.n();
        let mut old: Vec<Option<PieceHandle>> = std::mem::take(&mut self.handles)
            .into_iter()
            .map(Some)
            .collect();
        // Where each handle sat in the previous set, to reuse its entries of
        // the small systems.
        let mut previous_index = Vec::with_capacity(wanted.len());
        for (target, anchor, row, rest_point) in wanted {
            let found = old
                .iter()
                .position(|h| h.as_ref().is_some_and(|h| h.anchor == anchor));
            previous_index.push(found);
            let handle = match found.and_then(|i| old[i].take()) {
                Some(mut h) => {
                    h.target = target;
                    h
                }
                None => {
                    let mut step1_column = vec![DVec2::ZERO; n];
                    let entries: [(usize, f64); 3] =
                        std::array::from_fn(|c| (row.corners[c] as usize, row.weights[c]));
                    for &(v, weight) in &entries {
                        step1_column[v].x += weight;
                    }
                    self.step1
                        .solve_sparse(&mut step1_column, &entries.map(|e| e.0));
                    let step1_column = SplitComplex::from_pairs(&step1_column);
                    let step2_forward = self.step2.forward_sparse(&entries);

                    PieceHandle {
                        anchor,
                        row,
                        rest_point,
                        target,
                        step1_column,
                        step2_forward,
                    }
                }
            };
            self.handles.push(handle);
        }
        let current = |pose: &[DVec2], vertices: &[u32]| -> Vec<DVec2> {
            vertices.iter().map(|&v| pose[v as usize]).collect()
        };
        if self.handles.len() < 2 {
            // The kept systems describe a handle set that is gone.
            self.gram = None;
        }
        self.placement = match self.handles.len() {
            0 => {
                // Keep the best rigid placement of the current pose.
                let now = current(pose, &self.vertices);
                let (rotation, rest_mean, pose_mean) =
                    fit_rotation(self.rest.iter().copied().zip(now.iter().copied()));
                for (local, &v) in self.vertices.iter().enumerate() {
                    pose[v as usize] = pose_mean + rotation.rotate(self.rest[local] - rest_mean);
                }
                Placement::Fixed
            }
            1 => {
                let now = current(pose, &self.vertices);
                let (rotation, _, _) =
                    fit_rotation(self.rest.iter().copied().zip(now.iter().copied()));
                Placement::Carried { rotation }
            }
            k => {
                let previous = self.gram.take().map(|gram| (gram, previous_index));
                let (step1_inverse, step2_inverse) = self.small_inverses(previous);
                self.step1_rhs = vec![DVec2::ZERO; k + 2];
                self.step1_xi = vec![DVec2::ZERO; k + 2];
                self.step2_rhs = vec![DVec2::ZERO; k + 1];
                self.step2_xi = vec![DVec2::ZERO; k + 1];
                Placement::Solved {
                    step1_inverse,
                    step2_inverse,
                }
            }
        };
    }

    /// Inverses of `B̃ K⁻¹ B̃ᵀ − diag(0, I/δ)` for both steps (column-major).
    /// Entries between handles that were already in the `previous` set (with
    /// each new handle's index there) are copied, not recomputed: a finger
    /// landing costs one new row and column.
    fn small_inverses(
        &mut self,
        previous: Option<(Gram, Vec<Option<usize>>)>,
    ) -> (Vec<DVec2>, Vec<f64>) {
        let k = self.handles.len();
        // Index of row/column i in the previous systems, anchors included.
        let old_index = |i: usize| -> Option<usize> {
            let (gram, map) = previous.as_ref()?;
            let old_k = gram.handles;
            if i < k { map[i] } else { Some(old_k + (i - k)) }
        };
        let column1 = |j: usize| -> &SplitComplex {
            if j < k {
                &self.handles[j].step1_column
            } else {
                &self.step1_anchor_columns[j - k]
            }
        };
        let row1 = |i: usize, col: &SplitComplex| -> DVec2 {
            if i < k {
                let row = &self.handles[i].row;
                DVec2::new(row.dot(&col.re), row.dot(&col.im))
            } else {
                col.get(self.step1_anchors[i - k])
            }
        };
        let m1 = k + 2;
        let s1 = Mat::<c64>::from_fn(m1, m1, |i, j| {
            if let (Some(oi), Some(oj), Some((gram, _))) =
                (old_index(i), old_index(j), previous.as_ref())
            {
                return gram.step1[(oi, oj)];
            }
            let mut value = row1(i, column1(j));
            if i == j && i >= k {
                value.x -= 1.0 / self.step1_delta;
            }
            c64::new(value.x, value.y)
        });
        // S₂ = YᵀY − diag(0, 1/δ) with Y = L₂⁻¹ B̃ᵀ: B̃ K₂⁻¹ B̃ᵀ = YᵀY.
        let forward2 = |j: usize| -> &SparseVector<f64> {
            if j < k {
                &self.handles[j].step2_forward
            } else {
                &self.step2_anchor_forward
            }
        };
        let m2 = k + 1;
        let mut dense = vec![0.0; self.n()];
        let mut s2 = Mat::<f64>::zeros(m2, m2);
        for j in 0..m2 {
            let y = forward2(j);
            let mut scattered = false;
            for i in 0..m2 {
                if let (Some(oi), Some(oj), Some((gram, _))) =
                    (old_index(i), old_index(j), previous.as_ref())
                {
                    s2[(i, j)] = gram.step2[(oi, oj)];
                    continue;
                }
                if !scattered {
                    for (&r, &v) in y.indices.iter().zip(&y.values) {
                        dense[r as usize] = v;
                    }
                    scattered = true;
                }
                s2[(i, j)] = forward2(i).dot(&dense, 0.0, |a, b| a * b);
                if i == k && j == k {
                    s2[(i, j)] -= 1.0 / self.step2_delta;
                }
            }
            if scattered {
                for &r in &y.indices {
                    dense[r as usize] = 0.0;
                }
            }
        }
        self.gram = Some(Gram {
            handles: k,
            step1: s1.clone(),
            step2: s2.clone(),
        });
        let inverse1 = inverse_sequential(s1);
        let inverse2 = inverse_sequential(s2);
        let mut out1 = Vec::with_capacity(m1 * m1);
        for j in 0..m1 {
            for i in 0..m1 {
                let z = inverse1[(i, j)];
                out1.push(DVec2::new(z.re, z.im));
            }
        }
        let mut out2 = Vec::with_capacity(m2 * m2);
        for j in 0..m2 {
            for i in 0..m2 {
                out2.push(inverse2[(i, j)]);
            }
        }
        (out1, out2)
    }

    fn update(&mut self, targets: &[DVec2], steps: Steps, pose: &mut [DVec2]) {
        match &self.placement {
            Placement::Fixed => {}
            Placement::Carried { rotation } => {
                let handle = &self.handles[0];
                let to = targets[handle.target];
                for (local, &v) in self.vertices.iter().enumerate() {
                    pose[v as usize] = to + rotation.rotate(self.rest[local] - handle.rest_point);
                }
            }
            Placement::Solved {
                step1_inverse,
                step2_inverse,
            } => {
                let k = self.handles.len();
                // Step 1: v₁ = W₁ ξ₁ with ξ₁ = S₁⁻¹ [q; 0], all complex.
                for (h, handle) in self.handles.iter().enumerate() {
                    self.step1_rhs[h] = targets[handle.target];
                }
                self.step1_rhs[k..].fill(DVec2::ZERO);
                for (i, out) in self.step1_xi.iter_mut().enumerate() {
                    *out = DVec2::ZERO;
                    for (j, r) in self.step1_rhs.iter().enumerate() {
                        *out += step1_inverse[j * (k + 2) + i].rotate(*r);
                    }
                }
                let v1 = &mut self.step1_pose;
                let columns = self
                    .handles
                    .iter()
                    .map(|h| &h.step1_column)
                    .chain(self.step1_anchor_columns.iter());
                v1.set_combination(self.step1_xi.iter().copied().zip(columns));
                if steps == Steps::ScaleFree {
                    for (local, &v) in self.vertices.iter().enumerate() {
                        pose[v as usize] = v1.get(local);
                    }
                    return;
                }
                // Step 2a and the right-hand side of 2b. Per triangle the edge
                // terms telescope to b_i += w(2f_i − f_j − f_l) = 3w·f_i
                // (the fitted corners f sum to zero about the centroid), so
                // with r̃ = 3w·r̄ precomputed, b_i += unit_rotation · r̃_i.
                // Per chunk of triangles, three sweeps: gather the fit sums,
                // normalise them (a plain loop the compiler vectorises,
                // hiding sqrt/div latency), scatter the rotated corners. The
                // chunk's triangles are still in L1 for the scatter, so at
                // large sizes the triangles stream from memory once.
                const CHUNK: usize = 64;
                let mut fits = [DVec2::ZERO; CHUNK];
                let b = &mut self.step2_pose;
                b.fill(DVec2::ZERO);
                for triangles in self.triangles.chunks(CHUNK) {
                    let fits = &mut fits[..triangles.len()];
                    for (tri, fit) in triangles.iter().zip(fits.iter_mut()) {
                        let [i, j, l] = tri.corners.map(|c| c as usize);
                        let (p0, p1, p2) = (v1.get(i), v1.get(j), v1.get(l));
                        let r = &tri.scaled_centred;
                        let dot = r[0].dot(p0) + r[1].dot(p1) + r[2].dot(p2);
                        let crs = r[0].perp_dot(p0) + r[1].perp_dot(p1) + r[2].perp_dot(p2);
                        *fit = DVec2::new(dot, crs);
                    }
                    for fit in fits.iter_mut() {
                        let norm2 = fit.length_squared();
                        let scale = 1.0 / norm2.sqrt();
                        // A collapsed step-1 triangle fits no rotation: keep
                        // rest.
                        *fit = if norm2 > f64::MIN_POSITIVE && scale > 0.0 {
                            *fit * scale
                        } else {
                            DVec2::X
                        };
                    }
                    for (tri, rotation) in triangles.iter().zip(fits.iter()) {
                        let [i, j, l] = tri.corners.map(|c| c as usize);
                        let r = &tri.scaled_centred;
                        b[i] += rotation.rotate(r[0]);
                        b[j] += rotation.rotate(r[1]);
                        b[l] += rotation.rotate(r[2]);
                    }
                }
                // Step 2b: v = K₂⁻¹(b + B̃ᵀξ₂) = L₂⁻ᵀ(z + Y ξ₂) with z = L₂⁻¹b and
                // ξ₂ = S₂⁻¹([q; 0] − Yᵀz); x and y travel together as a pair.
                self.step2.forward(b);
                let pair = |v: f64, x: DVec2| x * v;
                for (h, handle) in self.handles.iter().enumerate() {
                    self.step2_rhs[h] =
                        targets[handle.target] - handle.step2_forward.dot(b, DVec2::ZERO, pair);
                }
                self.step2_rhs[k] = -self.step2_anchor_forward.dot(b, DVec2::ZERO, pair);
                for (i, out) in self.step2_xi.iter_mut().enumerate() {
                    *out = DVec2::ZERO;
                    for (j, r) in self.step2_rhs.iter().enumerate() {
                        *out += *r * step2_inverse[j * (k + 1) + i];
                    }
                }
                let forwards = self
                    .handles
                    .iter()
                    .map(|h| &h.step2_forward)
                    .chain(std::iter::once(&self.step2_anchor_forward));
                for (xi, y) in self.step2_xi.iter().zip(forwards) {
                    for (&i, &v) in y.indices.iter().zip(&y.values) {
                        b[i as usize] += *xi * v;
                    }
                }
                self.step2.backward(b);
                for (&v, p) in self.vertices.iter().zip(b.iter()) {
                    pose[v as usize] = *p;
                }
            }
        }
    }
}
