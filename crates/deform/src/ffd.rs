//! Locality-preserving free-form deformation (lp-FFD, Fukusato, Maejima &
//! Igarashi; `docs/rigs.md` says how a puppet uses it): the mesh is
//! embedded in an `M×N` grid of handles, every vertex a fixed linear blend
//! `V = W P` of them, and the unknowns are the grid handles only. Users pull
//! vertex handles (any point of the mesh) and grid handles; the grid that
//! keeps the mesh's one-rings most rigid is found by local/global iterations.
//!
//! Choices, and why:
//!
//! - **Locality energy.** The paper writes `E_ml = ‖L W P' − T L V̄‖²` but says
//!   it is Sorkine–Alexa's energy (its eq. 3) with `V' = W P'` substituted;
//!   we take eq. 3 literally (the paper's intent):
//!   `E_ml = Σᵢ Σ_{j∈N(i)} w_ij |(v'ᵢ − v'ⱼ) − Rᵢ(v̄ᵢ − v̄ⱼ)|²`. The squared
//!   Laplacian-coordinate reading would not see a uniform stretch of the
//!   interior (interior Laplacian coordinates are near zero).
//! - **Laplacian weights: uniform per triangle edge, scaled by rigidity.**
//!   `w_ij = Σ_{t ∋ ij} w_t` over the (one or two) triangles holding the edge,
//!   with `w_t` the mesh's per-triangle weight. Uniform weights are positive
//!   on any valid mesh (cotangent weights go negative on obtuse triangles and
//!   make the energy indefinite), they match the weighted edge Laplacian of
//!   the ARAP deformer, and on the mesher's near-equilateral triangles they
//!   are proportional to the cotangent ones anyway. Since edges shorten as
//!   the mesh refines, the sum approximates an area integral: the balance
//!   against the handle terms does not depend on the mesh's resolution.
//! - **Bases.** [`Basis::Bernstein`] is the paper's tensor-product Bernstein
//!   basis of degree `(M−1, N−1)` over the grid box (global support: every
//!   handle moves every vertex a little). [`Basis::Lattice`] is bilinear
//!   interpolation in the grid cell holding the vertex (the paper's
//!   "barycentric energy in a cell" option): four handles per vertex, the
//!   grid handles lie on the deformed lattice's nodes, only C⁰ across cell
//!   lines. Both reproduce affine maps exactly (`W P⁰ = V̄` for the regular
//!   rest grid `P⁰`).
//! - **Displacements.** We solve for `Δ = P' − P⁰` and output
//!   `V = V̄ + W Δ` (equal to `W P'` up to rounding, by the line above), so the
//!   rest pose comes back bit for bit and large coordinates lose no
//!   precision.
//!
//! Energy and normal equations (factor 2 from the edge sum counting each
//! edge from both ends):
//! `(2λ_ml WᵀLW + λ_mp Σ_C W_cᵀW_c + Σᵢ λᵢ eᵢeᵢᵀ) Δ = 2λ_ml Wᵀ b̃ + λ_mp Σ_C W_cᵀ(c − v̄_c) + λ_gp Σ_D eᵢ(dᵢ − P⁰ᵢ)`
//! with `λᵢ = λ_gp` for dragged grid handles and `λ_gr` for the others, and
//! `b̃ᵢ = Σⱼ (w_ij/2) ((Rᵢ − I) + (Rⱼ − I)) (v̄ᵢ − v̄ⱼ)`. The matrix (K×K,
//! K = M·N, dense) changes only with the handle sets or the weights, so it is
//! factored and inverted then (Cholesky); a frame's iteration is a local
//! step (per-vertex rotations), two passes over `W` and one product with the
//! inverse. Iterations are warm-started from the previous frame's grid.
//!
//! **Singular cases.** Every handle term is soft (`λ_mp`, `λ_gp`) and every
//! grid handle is tied to its rest place by `λ_gr > 0`, so the global
//! matrix stays positive definite whatever the handles: two vertex handles
//! a hair apart, on a boundary vertex or edge, on a sliver, on a line, or
//! beside a dragged grid handle, pulled anywhere, give a least-squares
//! compromise, never a blow-up (the property tests in
//! `tests/it/singular_others.rs` check it). Vertex handles on one rest
//! point (within 1e-9 of the mesh's size) are one handle and the later
//! wins; so does a grid handle given twice. The warm start carries the last
//! pose into the next update's local steps; the iterations only lower the
//! energy from there, so a sane update after a wild one comes back —
//! slowly where the handles leave a rotation to the weak `λ_gr` (one
//! handle, or two close together); [`LpFfd::rest_pose`] starts over from
//! rest at once.
//!
//! Grid handles are numbered row by row from the box's `min` corner:
//! handle `row·M + column` rests at `min + (column/(M−1), row/(N−1))·(max − min)`.

use std::collections::HashMap;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltParams, LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par, Spec};
use glam::DVec2;

use super::arap::Anchor;
use crate::lanes::{LANES, Packed};
use puppetry_mesh::json::MAX_COORDINATE;
use puppetry_mesh::{MAX_WEIGHT, MIN_WEIGHT, Mesh};

/// Largest grid (handles) accepted: the global matrix is dense K×K.
pub const MAX_GRID_HANDLES: usize = 1024;

/// Margin [`GridSpec::around`] leaves around the mesh, as a fraction of the
/// mesh's longer bounding-box side.
pub const GRID_MARGIN: f64 = 0.05;

/// Local/global iterations per frame by default. Measured on the demo
/// puppet (10×10 grid, four vertex handles wandering on small circles,
/// warm-started; the curve is in docs/rigs.md): after 4 iterations per frame
/// the Bernstein energy trails the converged one by 0.03–0.06% (median,
/// 1k and 10k vertices; 0.11% at worst) and the lattice's by 0.1–0.4%; 2
/// iterations leave about 5.6 times as much. A Bernstein frame of 4 takes
/// about 0.16 ms at 1k vertices and 1.5 ms at 10k on the 2-core
/// development machine. Each iteration costs two passes over `W` (n·K
/// multiply-adds for Bernstein, 4n for the lattice), the one-ring sweeps and
/// the K×K product with the inverse.
pub const DEFAULT_ITERATIONS: usize = 4;

/// How vertices blend grid handles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Basis {
    /// Tensor-product Bernstein polynomials of degree (M−1, N−1), as in the
    /// paper: smooth, global support.
    Bernstein,
    /// Bilinear interpolation in the vertex's grid cell: local support (four
    /// handles per vertex), handles on the lattice nodes.
    Lattice,
}

/// The FFD grid: `columns × rows` handles spanning the box `min..max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSpec {
    /// M, handles along x (at least 2).
    pub columns: usize,
    /// N, handles along y (at least 2).
    pub rows: usize,
    /// The box's lower corner, in the mesh's coordinates: where handle 0
    /// rests. Every rest vertex must lie inside the box.
    pub min: DVec2,
    /// The box's upper corner (greater than `min` on both axes): where the
    /// last handle rests.
    pub max: DVec2,
    /// How vertices blend the handles.
    pub basis: Basis,
}

impl GridSpec {
    /// A grid over the mesh's bounding box grown by [`GRID_MARGIN`] on every
    /// side.
    pub fn around(mesh: &Mesh, columns: usize, rows: usize, basis: Basis) -> GridSpec {
        let mut lo = DVec2::splat(f64::INFINITY);
        let mut hi = DVec2::splat(f64::NEG_INFINITY);
        for &v in mesh.vertices() {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        let margin = (hi - lo).max_element() * GRID_MARGIN;
        GridSpec {
            columns,
            rows,
            min: lo - DVec2::splat(margin),
            max: hi + DVec2::splat(margin),
            basis,
        }
    }

    /// Number of grid handles, `M·N`.
    pub fn handle_count(&self) -> usize {
        self.columns * self.rows
    }

    /// The regular rest grid `P⁰`, row by row from `min`.
    pub fn rest_handles(&self) -> Vec<DVec2> {
        let (m, n) = (self.columns, self.rows);
        let span = self.max - self.min;
        let mut out = Vec::with_capacity(m * n);
        for r in 0..n {
            for c in 0..m {
                let st = DVec2::new(
                    c as f64 / (m - 1).max(1) as f64,
                    r as f64 / (n - 1).max(1) as f64,
                );
                out.push(self.min + st * span);
            }
        }
        out
    }

    fn check(&self) -> Result<(), FfdError> {
        if self.columns < 2 || self.rows < 2 {
            return Err(FfdError::GridSize {
                columns: self.columns,
                rows: self.rows,
            });
        }
        let count = self.columns.saturating_mul(self.rows);
        if count > MAX_GRID_HANDLES {
            return Err(FfdError::GridTooLarge {
                count,
                max: MAX_GRID_HANDLES,
            });
        }
        let finite = |p: DVec2| p.is_finite() && p.abs().max_element() <= MAX_COORDINATE;
        if !(finite(self.min) && finite(self.max) && self.min.cmplt(self.max).all()) {
            return Err(FfdError::GridBox {
                min: self.min,
                max: self.max,
            });
        }
        Ok(())
    }
}

/// The energy weights and the iteration count. `Default` gives the paper's
/// weights and [`DEFAULT_ITERATIONS`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LpParams {
    /// λ_ml, the locality (shape-preservation) term. 0 gives direct FFD.
    pub locality: f64,
    /// λ_mp, vertex handles (soft constraints).
    pub vertex: f64,
    /// λ_gp, dragged grid handles (soft constraints). Must be positive.
    pub grid: f64,
    /// λ_gr, pulls undragged grid handles to rest. Must be positive: it is
    /// what keeps handles that no term sees in place.
    pub regular: f64,
    /// Local/global iterations per [`LpFfd::update`] (at least 1).
    pub iterations: usize,
}

impl Default for LpParams {
    fn default() -> Self {
        LpParams {
            locality: 1.0,
            vertex: 100.0,
            grid: 100.0,
            regular: 0.01,
            iterations: DEFAULT_ITERATIONS,
        }
    }
}

impl LpParams {
    fn check(&self) -> Result<(), FfdError> {
        let fields = [
            ("locality", self.locality, false),
            ("vertex", self.vertex, false),
            ("grid", self.grid, true),
            ("regular", self.regular, true),
        ];
        for (name, value, positive) in fields {
            let ok = value.is_finite()
                && value <= MAX_WEIGHT * 1e3
                && if positive { value > 0.0 } else { value >= 0.0 };
            if !ok {
                return Err(FfdError::Param { name, value });
            }
        }
        if self.iterations == 0 {
            return Err(FfdError::Iterations);
        }
        Ok(())
    }
}

/// Why [`LpFfd`] refused a grid, parameters, weights, a handle set or a
/// set of targets. A `handle` is the handle's index in the slice given to
/// [`LpFfd::compile`] (or [`LpFfd::direct_ffd`]).
#[derive(Debug, thiserror::Error)]
pub enum FfdError {
    /// The grid has fewer than 2 handles along x or y.
    #[error("grid: {columns}×{rows} handles; it needs at least 2 in each direction")]
    GridSize {
        /// Handles along x asked for.
        columns: usize,
        /// Handles along y asked for.
        rows: usize,
    },
    /// The grid has more than [`MAX_GRID_HANDLES`] handles.
    #[error("grid: {count} handles is more than the {max} the dense solver takes")]
    GridTooLarge {
        /// `columns × rows` asked for.
        count: usize,
        /// The limit, [`MAX_GRID_HANDLES`].
        max: usize,
    },
    /// The grid box is not finite (within the mesh format's coordinate
    /// limit) or is empty along an axis.
    #[error("grid: box {min}..{max} must be finite with min < max on both axes")]
    GridBox {
        /// The box's lower corner as given.
        min: DVec2,
        /// The box's upper corner as given.
        max: DVec2,
    },
    /// [`LpFfd::register`]: a rest vertex lies outside the grid box (by
    /// more than 1e-9 of the box's size).
    #[error("vertex {vertex} at {at} lies outside the grid box {min}..{max}")]
    VertexOutsideGrid {
        /// The first vertex outside.
        vertex: usize,
        /// Its rest position.
        at: DVec2,
        /// The box's lower corner.
        min: DVec2,
        /// The box's upper corner.
        max: DVec2,
    },
    /// An [`LpParams`] weight is not finite, above 1000 times the mesh's
    /// `MAX_WEIGHT`, negative, or zero where it must be positive (`grid`,
    /// `regular`).
    #[error("parameter {name} = {value}: must be finite and {}", if *name == "grid" || *name == "regular" { "positive" } else { "non-negative" })]
    Param {
        /// The field's name: `locality`, `vertex`, `grid` or `regular`.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// [`LpParams::iterations`] is 0.
    #[error("parameter iterations: must be at least 1")]
    Iterations,
    /// An [`Anchor::Vertex`] names a vertex the mesh does not have.
    #[error(
        "vertex handle {handle}: vertex {vertex} is out of range (the mesh has {count} vertices)"
    )]
    VertexOutOfRange {
        /// The offending vertex handle's index.
        handle: usize,
        /// The vertex it named.
        vertex: u32,
        /// How many vertices the mesh has.
        count: usize,
    },
    /// An [`Anchor::Point`] names a triangle the mesh does not have.
    #[error(
        "vertex handle {handle}: triangle {triangle} is out of range (the mesh has {count} triangles)"
    )]
    TriangleOutOfRange {
        /// The offending vertex handle's index.
        handle: usize,
        /// The triangle it named.
        triangle: u32,
        /// How many triangles the mesh has.
        count: usize,
    },
    /// An [`Anchor::Point`]'s weights are not finite, dip below zero, or do
    /// not sum to 1 (to within 1e-9).
    #[error(
        "vertex handle {handle}: barycentric weights {bary:?} must be finite, non-negative and sum to 1"
    )]
    BadBarycentric {
        /// The offending vertex handle's index.
        handle: usize,
        /// The weights it gave.
        bary: [f64; 3],
    },
    /// A grid handle index is not below `columns × rows`.
    #[error("grid handle {handle}: index {index} is out of range (the grid has {count} handles)")]
    GridHandleOutOfRange {
        /// The offending grid handle's position in the slice given.
        handle: usize,
        /// The grid index it named.
        index: usize,
        /// How many handles the grid has.
        count: usize,
    },
    /// A slice of targets, positions or weights has the wrong length.
    #[error("expected {expected} {what} (one per {per}), got {got}")]
    Count {
        /// What came, plural (e.g. `vertex targets`).
        what: &'static str,
        /// What there must be one of each per (e.g. `compiled vertex handle`).
        per: &'static str,
        /// How many were expected.
        expected: usize,
        /// How many came.
        got: usize,
    },
    /// A target or position is NaN, infinite or beyond the mesh format's
    /// coordinate limit.
    #[error("{what} {index}: not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    NotFinite {
        /// What it is (e.g. `grid target`).
        what: &'static str,
        /// The first offending index in its slice.
        index: usize,
    },
    /// [`LpFfd::set_weights`]: a rigidity weight is outside the mesh's
    /// `MIN_WEIGHT..=MAX_WEIGHT`.
    #[error("weights[{triangle}] = {value}: must be between {MIN_WEIGHT:e} and {MAX_WEIGHT:e}")]
    BadWeight {
        /// The first offending triangle.
        triangle: usize,
        /// Its weight.
        value: f64,
    },
    /// The dense global matrix could not be factored or inverted: the
    /// weights are too extreme for double precision. The rig is left as
    /// it was.
    #[error(
        "the global matrix is not positive definite (pivot {pivot}); the weights are too extreme"
    )]
    NotPositiveDefinite {
        /// The grid handle whose pivot failed (0 when the inverse came out
        /// non-finite).
        pivot: usize,
    },
}

/// The blending matrix `W`, one row per vertex: dense rows of K for
/// Bernstein, four (column, weight) pairs for the lattice.
#[derive(Debug, Clone)]
enum Blend {
    /// Row-major n×K (registration and compilation read whole rows), and
    /// the same rows factored for the frame's passes.
    Dense { values: Vec<f64>, tensor: Tensor },
    /// Four entries per row.
    Lattice {
        columns: Vec<[u32; 4]>,
        values: Vec<[f64; 4]>,
    },
}

/// One mesh edge for the locality term.
#[derive(Debug, Clone, Copy)]
struct Edge {
    i: u32,
    j: u32,
    /// `w_ij`: the summed rigidity weights of the triangles holding it.
    weight: f64,
    /// `v̄ᵢ − v̄ⱼ`.
    rest: DVec2,
}

/// A compiled vertex handle.
#[derive(Debug, Clone)]
struct VertexHandle {
    /// Index into the caller's vertex targets.
    target: usize,
    rest_point: DVec2,
}

/// Bernstein basis values `B_k^degree(x)`, k = 0..=degree, into `out`.
fn bernstein(degree: usize, x: f64, out: &mut [f64]) {
    let y = 1.0 - x;
    out.fill(0.0);
    out[0] = 1.0;
    for j in 1..=degree {
        for k in (1..=j).rev() {
            out[k] = y * out[k] + x * out[k - 1];
        }
        out[0] *= y;
    }
}

/// The registered lp-FFD rig for one rest mesh and grid. Phases:
/// [`LpFfd::register`], [`LpFfd::compile`], [`LpFfd::update`].
#[derive(Debug)]
pub struct LpFfd {
    spec: GridSpec,
    params: LpParams,
    rest: Vec<DVec2>,
    triangles: Vec<[u32; 3]>,
    rest_grid: Vec<DVec2>,
    blend: Blend,
    edges: Vec<Edge>,
    rings: Rings,
    /// `WᵀLW`, row-major K×K.
    locality_matrix: Vec<f64>,
    /// Two vertex handles closer than this in rest space are one handle.
    same_point: f64,
    // Handle sets (compile).
    vertex_handles: Vec<VertexHandle>,
    /// Their rows of `W`, row-major |C|×K.
    vertex_rows: Vec<f64>,
    vertex_target_count: usize,
    /// (grid handle, index into the caller's grid targets).
    grid_handles: Vec<(usize, usize)>,
    grid_target_count: usize,
    /// The inverse of the global matrix, row-major K×K (symmetric): a
    /// frame's solve is one dense product, sixteen outputs at a time in
    /// SIMD lanes, instead of two triangular solves whose rows wait on each
    /// other.
    inverse: Vec<f64>,
    // State: Δ, P' = P⁰ + Δ, V = V̄ + WΔ.
    displacement: Vec<DVec2>,
    grid: Vec<DVec2>,
    pose: Vec<DVec2>,
    // Frame scratch.
    fixed_rhs: Vec<DVec2>,
    rhs: Vec<DVec2>,
    /// `rhs` by coordinate, for the dense solve, and its result by
    /// coordinate (`2K`).
    rhs_x: Vec<f64>,
    rhs_y: Vec<f64>,
    product: Vec<f64>,
    /// Per vertex (padded to whole blocks of lanes): one-ring fit sums by
    /// coordinate, then the unit rotations (cos, sin).
    fit_x: Vec<f64>,
    fit_y: Vec<f64>,
    rotations: Vec<DVec2>,
    /// Per vertex (padded to whole blocks), `2λ_ml b̃` by coordinate for the
    /// lattice; the Bernstein basis keeps it in its pass's scratch.
    b_x: Vec<f64>,
    b_y: Vec<f64>,
    scratch: TensorScratch,
}

impl LpFfd {
    /// Registration: blending weights, edges, `WᵀLW`, and the global matrix
    /// factored for an empty handle set. The pose is the rest shape.
    pub fn register(mesh: &Mesh, grid: GridSpec, params: LpParams) -> Result<LpFfd, FfdError> {
        grid.check()?;
        params.check()?;
        let rest = mesh.vertices().to_vec();
        let span = grid.max - grid.min;
        let slack = span.max_element() * 1e-9;
        let mut normalised = Vec::with_capacity(rest.len());
        for (i, &v) in rest.iter().enumerate() {
            if (v - grid.min).min_element() < -slack || (grid.max - v).min_element() < -slack {
                return Err(FfdError::VertexOutsideGrid {
                    vertex: i,
                    at: v,
                    min: grid.min,
                    max: grid.max,
                });
            }
            normalised.push(((v - grid.min) / span).clamp(DVec2::ZERO, DVec2::ONE));
        }
        let blend = blend_matrix(&grid, &normalised);
        let scratch = TensorScratch::new(&blend);
        let k = grid.handle_count();
        let mut rig = LpFfd {
            spec: grid,
            params,
            same_point: mesh.size() * 1e-9,
            triangles: mesh.triangles().to_vec(),
            rest_grid: grid.rest_handles(),
            blend,
            edges: Vec::new(),
            rings: Rings::default(),
            locality_matrix: Vec::new(),
            vertex_handles: Vec::new(),
            vertex_rows: Vec::new(),
            vertex_target_count: 0,
            grid_handles: Vec::new(),
            grid_target_count: 0,
            inverse: Vec::new(),
            displacement: vec![DVec2::ZERO; k],
            grid: grid.rest_handles(),
            pose: rest.clone(),
            fixed_rhs: vec![DVec2::ZERO; k],
            rhs: vec![DVec2::ZERO; k],
            rhs_x: vec![0.0; k],
            rhs_y: vec![0.0; k],
            product: vec![0.0; 2 * k],
            fit_x: vec![0.0; rest.len().div_ceil(LANES) * LANES],
            fit_y: vec![0.0; rest.len().div_ceil(LANES) * LANES],
            rotations: vec![DVec2::ZERO; rest.len()],
            b_x: vec![0.0; rest.len().div_ceil(LANES) * LANES],
            b_y: vec![0.0; rest.len().div_ceil(LANES) * LANES],
            scratch,
            rest,
        };
        rig.set_edges(mesh.weights());
        rig.refactor()?;
        Ok(rig)
    }

    /// Number of grid handles.
    pub fn handle_count(&self) -> usize {
        self.rest_grid.len()
    }
    /// The grid the rig was registered with.
    pub fn spec(&self) -> &GridSpec {
        &self.spec
    }
    /// Sets the local/global iterations each update runs (warm-started
    /// from the previous frame's grid).
    pub fn set_iterations(&mut self, iterations: usize) {
        self.params.iterations = iterations;
    }

    /// The energy weights and iteration count in effect.
    pub fn params(&self) -> &LpParams {
        &self.params
    }
    /// The rest grid `P⁰`.
    pub fn rest_grid(&self) -> &[DVec2] {
        &self.rest_grid
    }
    /// The deformed grid handles `P'` of the last update.
    pub fn grid(&self) -> &[DVec2] {
        &self.grid
    }
    /// The deformed vertices of the last update.
    pub fn pose(&self) -> &[DVec2] {
        &self.pose
    }
    /// The rest vertex positions the rig was registered with.
    pub fn rest(&self) -> &[DVec2] {
        &self.rest
    }

    /// Changes the per-triangle rigidity weights: the edge weights, `WᵀLW`
    /// and the factor are rebuilt; handles and the current pose stay.
    pub fn set_weights(&mut self, weights: &[f64]) -> Result<(), FfdError> {
        if weights.len() != self.triangles.len() {
            return Err(FfdError::Count {
                what: "weights",
                per: "triangle",
                expected: self.triangles.len(),
                got: weights.len(),
            });
        }
        if let Some(t) = weights
            .iter()
            .position(|w| !(MIN_WEIGHT..=MAX_WEIGHT).contains(w))
        {
            return Err(FfdError::BadWeight {
                triangle: t,
                value: weights[t],
            });
        }
        // Rebuild aside, so a failure leaves the rig as it was.
        let old_edges = std::mem::take(&mut self.edges);
        let old_rings = std::mem::take(&mut self.rings);
        let old_locality = std::mem::take(&mut self.locality_matrix);
        self.set_edges(weights);
        if let Err(e) = self.refactor() {
            self.edges = old_edges;
            self.rings = old_rings;
            self.locality_matrix = old_locality;
            return Err(e);
        }
        Ok(())
    }

    /// Compilation: sets the vertex handles (points of the mesh) and the
    /// grid handles (indices into the grid) that following updates move, and
    /// factors the global matrix. Two vertex handles on the same rest point,
    /// or a grid handle given twice: the later wins. The pose stays, so the
    /// next update warm-starts from it.
    pub fn compile(
        &mut self,
        vertex_handles: &[Anchor],
        grid_handles: &[usize],
    ) -> Result<(), FfdError> {
        let (handles, rows) = self.resolve_vertex_handles(vertex_handles)?;
        let dragged = self.resolve_grid_handles(grid_handles)?;
        // Factor before committing, so a failure leaves the rig as it was.
        let matrix = self.global_matrix(self.params.locality, &rows, &dragged);
        let inverse = spd_inverse(matrix, self.handle_count())?;
        self.vertex_handles = handles;
        self.vertex_rows = rows;
        self.vertex_target_count = vertex_handles.len();
        self.grid_handles = dragged;
        self.grid_target_count = grid_handles.len();
        self.inverse = inverse;
        Ok(())
    }

    /// Update: moves the compiled handles to their targets (same order as
    /// given to [`LpFfd::compile`]) and runs `params.iterations` local/global
    /// iterations from the current pose. Returns the deformed vertices;
    /// [`LpFfd::grid`] holds the deformed grid. Does not allocate.
    pub fn update(
        &mut self,
        vertex_targets: &[DVec2],
        grid_targets: &[DVec2],
    ) -> Result<&[DVec2], FfdError> {
        self.set_targets(vertex_targets, grid_targets)?;
        let locality = self.params.locality > 0.0;
        for _ in 0..self.params.iterations {
            self.rhs.copy_from_slice(&self.fixed_rhs);
            if locality {
                self.local_step();
                self.add_locality_rhs();
            }
            for ((x, y), r) in self.rhs_x.iter_mut().zip(&mut self.rhs_y).zip(&self.rhs) {
                (*x, *y) = (r.x, r.y);
            }
            pulp::Arch::new().dispatch(DenseProduct {
                matrix: &self.inverse,
                x: &self.rhs_x,
                y: &self.rhs_y,
                sums: &mut self.product,
                out: &mut self.displacement,
            });
            apply(
                &self.blend,
                &mut self.scratch,
                &self.rest,
                &self.displacement,
                &mut self.pose,
            );
            if !locality {
                // Nothing depends on the pose: one solve is the minimum.
                break;
            }
        }
        for ((g, r), d) in self
            .grid
            .iter_mut()
            .zip(&self.rest_grid)
            .zip(&self.displacement)
        {
            *g = *r + *d;
        }
        Ok(&self.pose)
    }

    /// Puts the grid and the mesh back at rest (a reset): the local steps
    /// start from the pose, so without this a puppet let go keeps the
    /// rotations of its last drag. The handles stay compiled.
    pub fn rest_pose(&mut self) {
        self.pose.copy_from_slice(&self.rest);
        self.grid.copy_from_slice(&self.rest_grid);
        self.displacement.fill(DVec2::ZERO);
    }

    /// Plain FFD: the mesh deformed by the given grid (`V̄ + W(P − P⁰)`).
    pub fn deform_with_grid(&self, grid: &[DVec2]) -> Result<Vec<DVec2>, FfdError> {
        check_points(
            "grid handle",
            grid,
            self.handle_count(),
            "grid handles",
            "grid handle",
        )?;
        let delta: Vec<DVec2> = grid
            .iter()
            .zip(&self.rest_grid)
            .map(|(p, r)| *p - *r)
            .collect();
        let mut out = vec![DVec2::ZERO; self.rest.len()];
        let mut scratch = TensorScratch::new(&self.blend);
        apply(&self.blend, &mut scratch, &self.rest, &delta, &mut out);
        Ok(out)
    }

    /// Direct FFD with the regulariser (Hsu, Hughes & Kaufman 1992 plus
    /// `E_gr`): the grid minimising
    /// `λ_mp Σ|Wᵢ P' − cᵢ|² + λ_gp Σ_D |P'ᵢ − dᵢ|² + λ_gr Σ_{∉D} |P'ᵢ − P⁰ᵢ|²`,
    /// i.e. lp-FFD with `λ_ml = 0`, using this rig's weights. Independent of the compiled handles and the pose.
    pub fn direct_ffd(
        &self,
        vertex_handles: &[Anchor],
        vertex_targets: &[DVec2],
        grid_handles: &[usize],
        grid_targets: &[DVec2],
    ) -> Result<Vec<DVec2>, FfdError> {
        let (handles, rows) = self.resolve_vertex_handles(vertex_handles)?;
        let dragged = self.resolve_grid_handles(grid_handles)?;
        check_points(
            "vertex target",
            vertex_targets,
            vertex_handles.len(),
            "vertex targets",
            "vertex handle",
        )?;
        check_points(
            "grid target",
            grid_targets,
            grid_handles.len(),
            "grid targets",
            "grid handle",
        )?;
        let k = self.handle_count();
        let matrix = self.global_matrix(0.0, &rows, &dragged);
        let (factor, inverse_diagonal) = cholesky(matrix, k)?;
        let mut delta = vec![DVec2::ZERO; k];
        self.constraint_rhs(
            &handles,
            &rows,
            &dragged,
            vertex_targets,
            grid_targets,
            &mut delta,
        );
        Ok(self.rest_grid_moved(&factor, &inverse_diagonal, delta))
    }

    /// The rest grid moved by the solve of `delta` (the right-hand side)
    /// against a Cholesky factor: a one-off solve's grid.
    fn rest_grid_moved(
        &self,
        factor: &[f64],
        inverse_diagonal: &[f64],
        mut delta: Vec<DVec2>,
    ) -> Vec<DVec2> {
        solve_in_place(factor, inverse_diagonal, &mut delta);
        delta
            .iter()
            .zip(&self.rest_grid)
            .map(|(d, r)| *r + *d)
            .collect()
    }

    /// Inverse FFD: the grid whose plain FFD best fits the given vertex
    /// positions, `argmin λ_mp Σᵢ |Wᵢ P' − vᵢ|² + λ_gr Σ |P'ᵢ − P⁰ᵢ|²` (direct
    /// FFD with every vertex a handle; the regulariser fixes the handles no
    /// vertex depends on).
    pub fn inverse_ffd(&self, vertices: &[DVec2]) -> Result<Vec<DVec2>, FfdError> {
        check_points(
            "vertex",
            vertices,
            self.rest.len(),
            "vertex positions",
            "mesh vertex",
        )?;
        let k = self.handle_count();
        let mut matrix = gram(&self.blend, k);
        for a in matrix.iter_mut() {
            *a *= self.params.vertex;
        }
        for i in 0..k {
            matrix[i * k + i] += self.params.regular;
        }
        let (factor, inverse_diagonal) = cholesky(matrix, k)?;
        let residual: Vec<DVec2> = vertices
            .iter()
            .zip(&self.rest)
            .map(|(v, r)| (*v - *r) * self.params.vertex)
            .collect();
        let mut delta = vec![DVec2::ZERO; k];
        let mut scratch = TensorScratch::new(&self.blend);
        add_transposed(&self.blend, &mut scratch, &residual, &mut delta);
        Ok(self.rest_grid_moved(&factor, &inverse_diagonal, delta))
    }

    /// The lp-FFD objective of a grid for the compiled handles and the given
    /// targets, with each vertex's rotation the best one for that grid:
    /// `λ_ml E_ml + λ_mp E_mp + λ_gp E_gp + λ_gr E_gr`. For tests and
    /// convergence measurements; allocates.
    pub fn energy(
        &self,
        grid: &[DVec2],
        vertex_targets: &[DVec2],
        grid_targets: &[DVec2],
    ) -> Result<f64, FfdError> {
        let pose = self.deform_with_grid(grid)?;
        self.check_targets(vertex_targets, grid_targets)?;
        let p = &self.params;
        let mut fits = vec![DVec2::ZERO; self.rest.len()];
        let mut squares = vec![0.0; self.rest.len()];
        for e in &self.edges {
            let now = pose[e.i as usize] - pose[e.j as usize];
            let q = DVec2::new(e.rest.dot(now), e.rest.perp_dot(now)) * e.weight;
            let s = e.weight * (now.length_squared() + e.rest.length_squared());
            for v in [e.i, e.j] {
                fits[v as usize] += q;
                squares[v as usize] += s;
            }
        }
        // min over R of Σ w|e − Rē|² = Σ w(|e|² + |ē|²) − 2|Σ w (ē·e, ē×e)|.
        let locality: f64 = fits
            .iter()
            .zip(&squares)
            .map(|(f, s)| (s - 2.0 * f.length()).max(0.0))
            .sum();
        let k = self.handle_count();
        let mut handles_energy = 0.0;
        for (h, handle) in self.vertex_handles.iter().enumerate() {
            let row = &self.vertex_rows[h * k..(h + 1) * k];
            let mut at = handle.rest_point;
            for (w, (g, r)) in row.iter().zip(grid.iter().zip(&self.rest_grid)) {
                at += (*g - *r) * *w;
            }
            handles_energy += p.vertex * at.distance_squared(vertex_targets[handle.target]);
        }
        let mut dragged = vec![false; k];
        for &(index, target) in &self.grid_handles {
            dragged[index] = true;
            handles_energy += p.grid * grid[index].distance_squared(grid_targets[target]);
        }
        for i in 0..k {
            if !dragged[i] {
                handles_energy += p.regular * grid[i].distance_squared(self.rest_grid[i]);
            }
        }
        Ok(p.locality * locality + handles_energy)
    }

    fn set_edges(&mut self, weights: &[f64]) {
        let mut sums: HashMap<(u32, u32), f64> = HashMap::with_capacity(self.triangles.len() * 2);
        for (tri, &w) in self.triangles.iter().zip(weights) {
            for c in 0..3 {
                let (a, b) = (tri[c], tri[(c + 1) % 3]);
                *sums.entry((a.min(b), a.max(b))).or_insert(0.0) += w;
            }
        }
        let mut edges: Vec<Edge> = sums
            .into_iter()
            .map(|((i, j), weight)| Edge {
                i,
                j,
                weight,
                rest: self.rest[i as usize] - self.rest[j as usize],
            })
            .collect();
        // Sweep order follows the vertex order, for the caches.
        edges.sort_unstable_by_key(|e| (e.i, e.j));
        self.rings = Rings::new(self.rest.len(), &edges);
        self.edges = edges;
        self.locality_matrix = locality_matrix(&self.blend, &self.edges, self.handle_count());
    }

    /// Rebuilds the global matrix for the current handle sets and factors it.
    fn refactor(&mut self) -> Result<(), FfdError> {
        let k = self.handle_count();
        let matrix =
            self.global_matrix(self.params.locality, &self.vertex_rows, &self.grid_handles);
        self.inverse = spd_inverse(matrix, k)?;
        Ok(())
    }

    /// `2λ_ml WᵀLW + λ_mp Σ W_cᵀW_c + diag(λ_gp on dragged, λ_gr elsewhere)`.
    fn global_matrix(
        &self,
        locality: f64,
        vertex_rows: &[f64],
        grid_handles: &[(usize, usize)],
    ) -> Vec<f64> {
        let k = self.handle_count();
        let p = &self.params;
        let mut a: Vec<f64> = self
            .locality_matrix
            .iter()
            .map(|x| 2.0 * locality * x)
            .collect();
        for row in vertex_rows.chunks_exact(k) {
            for (i, &ri) in row.iter().enumerate() {
                if ri == 0.0 {
                    continue;
                }
                let line = &mut a[i * k..(i + 1) * k];
                for (x, &rj) in line.iter_mut().zip(row) {
                    *x += p.vertex * ri * rj;
                }
            }
        }
        for i in 0..k {
            a[i * k + i] += p.regular;
        }
        for &(i, _) in grid_handles {
            a[i * k + i] += p.grid - p.regular;
        }
        a
    }

    /// Validates vertex handles; returns the live ones (later duplicates
    /// win) and their rows of `W`.
    fn resolve_vertex_handles(
        &self,
        anchors: &[Anchor],
    ) -> Result<(Vec<VertexHandle>, Vec<f64>), FfdError> {
        let k = self.handle_count();
        let mut resolved = Vec::with_capacity(anchors.len());
        for (h, anchor) in anchors.iter().enumerate() {
            let (corners, bary) = match *anchor {
                Anchor::Vertex(v) => {
                    if v as usize >= self.rest.len() {
                        return Err(FfdError::VertexOutOfRange {
                            handle: h,
                            vertex: v,
                            count: self.rest.len(),
                        });
                    }
                    ([v; 3], [1.0, 0.0, 0.0])
                }
                Anchor::Point { triangle, bary } => {
                    let Some(&tri) = self.triangles.get(triangle as usize) else {
                        return Err(FfdError::TriangleOutOfRange {
                            handle: h,
                            triangle,
                            count: self.triangles.len(),
                        });
                    };
                    let sum: f64 = bary.iter().sum();
                    if bary.iter().any(|b| !b.is_finite() || *b < -1e-12)
                        || (sum - 1.0).abs() > 1e-9
                    {
                        return Err(FfdError::BadBarycentric { handle: h, bary });
                    }
                    (tri, bary)
                }
            };
            let rest_point = match *anchor {
                Anchor::Vertex(v) => self.rest[v as usize],
                // Same arithmetic as `Mesh::point_at`, so a caller's rest
                // target matches to the bit.
                Anchor::Point { .. } => {
                    self.rest[corners[0] as usize] * bary[0]
                        + self.rest[corners[1] as usize] * bary[1]
                        + self.rest[corners[2] as usize] * bary[2]
                }
            };
            resolved.push((h, corners, bary, rest_point));
        }
        let mut handles = Vec::with_capacity(resolved.len());
        let mut rows = Vec::with_capacity(resolved.len() * k);
        for (n, &(h, corners, bary, rest_point)) in resolved.iter().enumerate() {
            let superseded = resolved[n + 1..]
                .iter()
                .any(|later| later.3.distance(rest_point) <= self.same_point);
            if superseded {
                continue;
            }
            let start = rows.len();
            rows.resize(start + k, 0.0);
            let row = &mut rows[start..];
            for (&v, &b) in corners.iter().zip(&bary) {
                if b != 0.0 {
                    add_blend_row(&self.blend, v as usize, k, b, row);
                }
            }
            handles.push(VertexHandle {
                target: h,
                rest_point,
            });
        }
        Ok((handles, rows))
    }

    /// Validates grid handles; returns (grid handle, target index) with
    /// later duplicates winning.
    fn resolve_grid_handles(&self, indices: &[usize]) -> Result<Vec<(usize, usize)>, FfdError> {
        let k = self.handle_count();
        let mut target_of = vec![usize::MAX; k];
        for (h, &index) in indices.iter().enumerate() {
            if index >= k {
                return Err(FfdError::GridHandleOutOfRange {
                    handle: h,
                    index,
                    count: k,
                });
            }
            target_of[index] = h;
        }
        Ok(target_of
            .iter()
            .enumerate()
            .filter(|(_, t)| **t != usize::MAX)
            .map(|(i, t)| (i, *t))
            .collect())
    }

    /// One target per compiled handle of each kind, all finite.
    fn check_targets(
        &self,
        vertex_targets: &[DVec2],
        grid_targets: &[DVec2],
    ) -> Result<(), FfdError> {
        check_points(
            "vertex target",
            vertex_targets,
            self.vertex_target_count,
            "vertex targets",
            "compiled vertex handle",
        )?;
        check_points(
            "grid target",
            grid_targets,
            self.grid_target_count,
            "grid targets",
            "compiled grid handle",
        )?;
        Ok(())
    }

    fn set_targets(
        &mut self,
        vertex_targets: &[DVec2],
        grid_targets: &[DVec2],
    ) -> Result<(), FfdError> {
        self.check_targets(vertex_targets, grid_targets)?;
        let mut fixed = std::mem::take(&mut self.fixed_rhs);
        let dragged: &[(usize, usize)] = &self.grid_handles;
        self.constraint_rhs(
            &self.vertex_handles,
            &self.vertex_rows,
            dragged,
            vertex_targets,
            grid_targets,
            &mut fixed,
        );
        self.fixed_rhs = fixed;
        Ok(())
    }

    /// The handle terms of the right-hand side, in displacements:
    /// `λ_mp Σ W_cᵀ(c − v̄_c) + λ_gp Σ_D eᵢ(dᵢ − P⁰ᵢ)`.
    fn constraint_rhs(
        &self,
        handles: &[VertexHandle],
        rows: &[f64],
        dragged: &[(usize, usize)],
        vertex_targets: &[DVec2],
        grid_targets: &[DVec2],
        out: &mut [DVec2],
    ) {
        let k = self.handle_count();
        out.fill(DVec2::ZERO);
        for (handle, row) in handles.iter().zip(rows.chunks_exact(k)) {
            let pull = (vertex_targets[handle.target] - handle.rest_point) * self.params.vertex;
            for (o, &w) in out.iter_mut().zip(row) {
                *o += pull * w;
            }
        }
        for &(index, target) in dragged {
            out[index] += (grid_targets[target] - self.rest_grid[index]) * self.params.grid;
        }
    }

    /// `rhs += Wᵀ (2λ_ml b̃)` from where [`LpFfd::local_step`] left `b̃`.
    fn add_locality_rhs(&mut self) {
        match &self.blend {
            Blend::Dense { tensor, .. } => {
                tensor.add_transposed_scratch(&mut self.scratch, &mut self.rhs)
            }
            Blend::Lattice { columns, values } => {
                let b = self.b_x.iter().zip(&self.b_y);
                for ((c, w), (&x, &y)) in columns.iter().zip(values).zip(b) {
                    for q in 0..4 {
                        self.rhs[c[q] as usize] += DVec2::new(x, y) * w[q];
                    }
                }
            }
        }
    }

    /// Local step and the locality right-hand side: per-vertex best-fit
    /// rotations of the one-ring edges (Sorkine–Alexa), then
    /// `2λ_ml b̃` by coordinate (see [`LpFfd::add_locality_rhs`]). Both sweeps run over four vertices at a
    /// time in SIMD lanes, each lane walking its vertex's one-ring (see
    /// [`Rings`]) with the sums in registers; the edge-by-edge sweep it
    /// replaces scattered into both ends of every edge.
    fn local_step(&mut self) {
        pulp::Arch::new().dispatch(FitKernel {
            rings: &self.rings,
            pose: &self.pose,
            fit_x: &mut self.fit_x,
            fit_y: &mut self.fit_y,
        });
        // A loop of its own, so the square roots run in SIMD lanes.
        pulp::Arch::new().dispatch(crate::lanes::NormaliseLanes {
            x: &self.fit_x,
            y: &self.fit_y,
            out: &mut self.rotations,
        });
        // Straight into the Bernstein pass's input; the lattice's own.
        let (out_x, out_y) = match self.blend {
            Blend::Dense { .. } => (&mut self.scratch.ux, &mut self.scratch.uy),
            Blend::Lattice { .. } => (&mut self.b_x, &mut self.b_y),
        };
        pulp::Arch::new().dispatch(TurnKernel {
            rings: &self.rings,
            rotations: &self.rotations,
            scale: self.params.locality,
            out_x,
            out_y,
        });
    }
}

/// The mesh's one-rings for the local step, four vertices a block (see
/// [`Packed`]): vertex i's neighbours j with `w_ij ē_ij` (`ē_ij = v̄ᵢ −
/// v̄ⱼ`), and per lane `hᵢ = Σ_j w_ij ē_ij`.
#[derive(Debug, Clone, Default)]
struct Rings {
    packed: Packed,
    hx: Vec<[f64; LANES]>,
    hy: Vec<[f64; LANES]>,
}

impl Rings {
    fn new(n: usize, edges: &[Edge]) -> Rings {
        let mut ring: Vec<Vec<(u32, DVec2)>> = vec![Vec::new(); n];
        for e in edges {
            ring[e.i as usize].push((e.j, e.rest * e.weight));
            ring[e.j as usize].push((e.i, -e.rest * e.weight));
        }
        for r in &mut ring {
            r.sort_unstable_by_key(|&(j, _)| j);
        }
        let h = |v: usize| -> DVec2 {
            ring.get(v)
                .map_or(DVec2::ZERO, |r| r.iter().map(|&(_, w)| w).sum())
        };
        let blocks = n.div_ceil(LANES);
        Rings {
            packed: Packed::new(&ring, n),
            hx: (0..blocks)
                .map(|b| std::array::from_fn(|l| h(b * LANES + l).x))
                .collect(),
            hy: (0..blocks)
                .map(|b| std::array::from_fn(|l| h(b * LANES + l).y))
                .collect(),
        }
    }
}

/// Per vertex, the one-ring fit `Σ_j w_ij (ē_ij·e_ij, ē_ij×e_ij)` (e the
/// deformed edge), normalised to a rotation (cos, sin) as
/// [`crate::lanes::Normalise`] does.
struct FitKernel<'a> {
    rings: &'a Rings,
    pose: &'a [DVec2],
    /// The fit sums by coordinate, padded to whole blocks.
    fit_x: &'a mut [f64],
    fit_y: &'a mut [f64],
}

impl pulp::WithSimd for FitKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Packed {
            rows: n,
            ref start,
            index: ref vertex,
            x: ref wx,
            y: ref wy,
            ..
        } = self.rings.packed;
        let pose = &self.pose[..n];
        for (b, range) in start.windows(2).enumerate() {
            let at = b * LANES;
            let own: [DVec2; LANES] = std::array::from_fn(|l| pose[(at + l).min(n - 1)]);
            let ox: [f64; LANES] = std::array::from_fn(|l| own[l].x);
            let oy: [f64; LANES] = std::array::from_fn(|l| own[l].y);
            let (mut d, mut c) = ([0.0; LANES], [0.0; LANES]);
            let slots = range[0] as usize..range[1] as usize;
            for ((j, ax), ay) in vertex[slots.clone()]
                .iter()
                .zip(&wx[slots.clone()])
                .zip(&wy[slots])
            {
                // SAFETY: `Packed::new` checked every index is below n.
                let other: [DVec2; LANES] =
                    std::array::from_fn(|l| unsafe { *pose.get_unchecked(j[l] as usize) });
                let (qx, qy): ([f64; LANES], [f64; LANES]) = (
                    std::array::from_fn(|l| other[l].x),
                    std::array::from_fn(|l| other[l].y),
                );
                for l in 0..LANES {
                    let (ex, ey) = (ox[l] - qx[l], oy[l] - qy[l]);
                    d[l] += ax[l] * ex + ay[l] * ey;
                    c[l] += ax[l] * ey - ay[l] * ex;
                }
            }
            // By coordinate: storing (d, c) pairs here kept the compiler
            // from running the lanes as vectors.
            self.fit_x[at..at + LANES].copy_from_slice(&d);
            self.fit_y[at..at + LANES].copy_from_slice(&c);
        }
    }
}

/// Per vertex, `2λ_ml b̃ᵢ = λ_ml Σ_j w_ij ((Rᵢ − I) + (Rⱼ − I)) ē_ij =
/// λ_ml (Rᵢhᵢ − 2hᵢ + Σ_j Rⱼ w_ij ē_ij)`.
struct TurnKernel<'a> {
    rings: &'a Rings,
    rotations: &'a [DVec2],
    scale: f64,
    /// By coordinate, padded to whole blocks (the padding lanes get 0).
    out_x: &'a mut [f64],
    out_y: &'a mut [f64],
}

impl pulp::WithSimd for TurnKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let n = self.rings.packed.rows;
        let (hx, hy) = (&self.rings.hx, &self.rings.hy);
        let rotations = &self.rotations[..n];
        for b in 0..self.rings.packed.start.len().saturating_sub(1) {
            let at = b * LANES;
            let (tx, ty) = self.rings.packed.turned_sums(b, rotations);
            let own: [DVec2; LANES] = std::array::from_fn(|l| rotations[(at + l).min(n - 1)]);
            let (hx, hy) = (&hx[b], &hy[b]);
            let (mut bx, mut by) = ([0.0; LANES], [0.0; LANES]);
            for l in 0..LANES {
                let turned_x = own[l].x * hx[l] - own[l].y * hy[l];
                let turned_y = own[l].y * hx[l] + own[l].x * hy[l];
                bx[l] = ((turned_x - 2.0 * hx[l]) + tx[l]) * self.scale;
                by[l] = ((turned_y - 2.0 * hy[l]) + ty[l]) * self.scale;
            }
            self.out_x[at..at + LANES].copy_from_slice(&bx);
            self.out_y[at..at + LANES].copy_from_slice(&by);
        }
    }
}

fn check_points(
    what: &'static str,
    points: &[DVec2],
    expected: usize,
    plural: &'static str,
    per: &'static str,
) -> Result<(), FfdError> {
    if points.len() != expected {
        return Err(FfdError::Count {
            what: plural,
            per,
            expected,
            got: points.len(),
        });
    }
    if let Some(index) = points
        .iter()
        .position(|t| !(t.is_finite() && t.abs().max_element() <= MAX_COORDINATE))
    {
        return Err(FfdError::NotFinite { what, index });
    }
    Ok(())
}

fn blend_matrix(spec: &GridSpec, normalised: &[DVec2]) -> Blend {
    let (m, n) = (spec.columns, spec.rows);
    match spec.basis {
        Basis::Bernstein => {
            let k = m * n;
            let mut values = vec![0.0; normalised.len() * k];
            let (mut bs, mut bt) = (vec![0.0; m], vec![0.0; n]);
            for (row, st) in values.chunks_exact_mut(k).zip(normalised) {
                bernstein(m - 1, st.x, &mut bs);
                bernstein(n - 1, st.y, &mut bt);
                for (r, &wt) in bt.iter().enumerate() {
                    for (c, &ws) in bs.iter().enumerate() {
                        row[r * m + c] = ws * wt;
                    }
                }
            }
            Blend::Dense {
                values,
                tensor: Tensor::new(m, n, normalised),
            }
        }
        Basis::Lattice => {
            let mut columns = Vec::with_capacity(normalised.len());
            let mut values = Vec::with_capacity(normalised.len());
            for st in normalised {
                let cell = |x: f64, count: usize| {
                    let scaled = x * (count - 1) as f64;
                    let index = (scaled.floor() as usize).min(count - 2);
                    (index, scaled - index as f64)
                };
                let (c, a) = cell(st.x, m);
                let (r, b) = cell(st.y, n);
                let at = |c: usize, r: usize| (r * m + c) as u32;
                columns.push([at(c, r), at(c + 1, r), at(c, r + 1), at(c + 1, r + 1)]);
                values.push([(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b]);
            }
            Blend::Lattice { columns, values }
        }
    }
}

/// `row += scale · W_v`.
fn add_blend_row(blend: &Blend, v: usize, k: usize, scale: f64, row: &mut [f64]) {
    match blend {
        Blend::Dense { values, .. } => {
            for (o, w) in row.iter_mut().zip(&values[v * k..(v + 1) * k]) {
                *o += scale * w;
            }
        }
        Blend::Lattice { columns, values } => {
            for (c, w) in columns[v].iter().zip(&values[v]) {
                row[*c as usize] += scale * w;
            }
        }
    }
}

/// `out = base + W Δ`, per vertex.
fn apply(
    blend: &Blend,
    scratch: &mut TensorScratch,
    base: &[DVec2],
    delta: &[DVec2],
    out: &mut [DVec2],
) {
    match blend {
        Blend::Dense { tensor, .. } => tensor.apply(scratch, base, delta, out),
        Blend::Lattice { columns, values } => {
            for (((c, w), o), b) in columns.iter().zip(values).zip(out.iter_mut()).zip(base) {
                *o = *b
                    + (delta[c[0] as usize] * w[0]
                        + delta[c[1] as usize] * w[1]
                        + delta[c[2] as usize] * w[2]
                        + delta[c[3] as usize] * w[3]);
            }
        }
    }
}

/// `out += Wᵀ x`.
fn add_transposed(blend: &Blend, scratch: &mut TensorScratch, x: &[DVec2], out: &mut [DVec2]) {
    match blend {
        Blend::Dense { tensor, .. } => tensor.add_transposed(scratch, x, out),
        Blend::Lattice { columns, values } => {
            for ((c, w), xi) in columns.iter().zip(values).zip(x) {
                for q in 0..4 {
                    out[c[q] as usize] += *xi * w[q];
                }
            }
        }
    }
}

/// `AᵀB` (row-major K×K) of two row-major N×K matrices.
fn transposed_product(a: &[f64], b: &[f64], n: usize, k: usize) -> Vec<f64> {
    let mut out = Mat::<f64>::zeros(k, k);
    matmul(
        out.as_mut(),
        Accum::Replace,
        MatRef::from_row_major_slice(a, n, k).transpose(),
        MatRef::from_row_major_slice(b, n, k),
        1.0,
        Par::Seq,
    );
    row_major(&out)
}

/// `WᵀLW` (row-major K×K) with `L` the edge-weighted graph Laplacian.
fn locality_matrix(blend: &Blend, edges: &[Edge], k: usize) -> Vec<f64> {
    match blend {
        Blend::Dense { values, .. } => {
            let n = values.len() / k;
            let mut lw = vec![0.0; n * k];
            for e in edges {
                let (i, j) = (e.i as usize, e.j as usize);
                for c in 0..k {
                    let d = e.weight * (values[i * k + c] - values[j * k + c]);
                    lw[i * k + c] += d;
                    lw[j * k + c] -= d;
                }
            }
            transposed_product(values, &lw, n, k)
        }
        Blend::Lattice { columns, values } => {
            let mut out = vec![0.0; k * k];
            for e in edges {
                let (i, j) = (e.i as usize, e.j as usize);
                let entries: [(u32, f64); 8] = std::array::from_fn(|q| {
                    if q < 4 {
                        (columns[i][q], values[i][q])
                    } else {
                        (columns[j][q - 4], -values[j][q - 4])
                    }
                });
                for &(a, wa) in &entries {
                    for &(b, wb) in &entries {
                        out[a as usize * k + b as usize] += e.weight * wa * wb;
                    }
                }
            }
            out
        }
    }
}

/// `WᵀW` (row-major K×K).
fn gram(blend: &Blend, k: usize) -> Vec<f64> {
    match blend {
        Blend::Dense { values, .. } => {
            let n = values.len() / k;
            transposed_product(values, values, n, k)
        }
        Blend::Lattice { columns, values } => {
            let mut out = vec![0.0; k * k];
            for (c, w) in columns.iter().zip(values) {
                for a in 0..4 {
                    for b in 0..4 {
                        out[c[a] as usize * k + c[b] as usize] += w[a] * w[b];
                    }
                }
            }
            out
        }
    }
}

fn row_major(m: &Mat<f64>) -> Vec<f64> {
    let mut out = Vec::with_capacity(m.nrows() * m.ncols());
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            out.push(m[(i, j)]);
        }
    }
    out
}

/// Cholesky factor of a symmetric positive definite row-major K×K matrix,
/// on this thread: the lower factor (row-major) and its diagonal's
/// reciprocals.
fn cholesky(matrix: Vec<f64>, k: usize) -> Result<(Vec<f64>, Vec<f64>), FfdError> {
    let mut a = Mat::<f64>::from_fn(k, k, |i, j| matrix[i * k + j]);
    let params: Spec<LltParams, f64> = Default::default();
    let mut memory = MemBuffer::new(cholesky_in_place_scratch::<f64>(k, Par::Seq, params));
    cholesky_in_place(
        a.as_mut(),
        LltRegularization::default(),
        Par::Seq,
        MemStack::new(&mut memory),
        params,
    )
    .map_err(|e| match e {
        faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
            FfdError::NotPositiveDefinite { pivot: index }
        }
    })?;
    let mut factor = vec![0.0; k * k];
    let mut inverse_diagonal = vec![0.0; k];
    for i in 0..k {
        for j in 0..=i {
            factor[i * k + j] = a[(i, j)];
        }
        inverse_diagonal[i] = 1.0 / a[(i, i)];
        if !inverse_diagonal[i].is_finite() {
            return Err(FfdError::NotPositiveDefinite { pivot: i });
        }
    }
    Ok((factor, inverse_diagonal))
}

/// The inverse of a symmetric positive definite row-major K×K matrix, by
/// its Cholesky factor (row-major, both triangles).
fn spd_inverse(matrix: Vec<f64>, k: usize) -> Result<Vec<f64>, FfdError> {
    let (factor, _) = cholesky(matrix, k)?;
    let lower = Mat::<f64>::from_fn(k, k, |i, j| if j <= i { factor[i * k + j] } else { 0.0 });
    let mut memory =
        MemBuffer::new(faer::linalg::cholesky::llt::inverse::inverse_scratch::<f64>(k, Par::Seq));
    let mut out = Mat::<f64>::zeros(k, k);
    faer::linalg::cholesky::llt::inverse::inverse(
        out.as_mut(),
        lower.as_ref(),
        Par::Seq,
        MemStack::new(&mut memory),
    );
    let mut inverse = vec![0.0; k * k];
    for i in 0..k {
        for j in 0..=i {
            inverse[i * k + j] = out[(i, j)];
            inverse[j * k + i] = out[(i, j)];
        }
    }
    if inverse.iter().all(|x| x.is_finite()) {
        Ok(inverse)
    } else {
        Err(FfdError::NotPositiveDefinite { pivot: 0 })
    }
}

/// `out = A (x, y)` for the symmetric row-major K×K `matrix`: by symmetry
/// column j is row j, so each step adds `x_j`, `y_j` times a run of row j
/// to sums for up to sixteen outputs held in registers (eight independent
/// sums a lane, each over j in order).
struct DenseProduct<'a> {
    matrix: &'a [f64],
    x: &'a [f64],
    y: &'a [f64],
    /// Scratch, `2K`: the sums by coordinate.
    sums: &'a mut [f64],
    out: &'a mut [DVec2],
}

/// Outputs `i..i + G·LANES` of [`DenseProduct`].
#[inline(always)]
fn dense_group<const G: usize>(
    matrix: &[f64],
    k: usize,
    i: usize,
    x: &[f64],
    y: &[f64],
    out: &mut [f64],
) {
    let (mut ax, mut ay) = ([[0.0; LANES]; G], [[0.0; LANES]; G]);
    for ((row, &xj), &yj) in matrix.chunks_exact(k).zip(x).zip(y) {
        let run = &row[i..][..G * LANES];
        for g in 0..G {
            let a: &[f64; LANES] = run[g * LANES..][..LANES].try_into().unwrap();
            for l in 0..LANES {
                ax[g][l] = a[l].mul_add(xj, ax[g][l]);
                ay[g][l] = a[l].mul_add(yj, ay[g][l]);
            }
        }
    }
    let (ox, oy) = out.split_at_mut(out.len() / 2);
    for g in 0..G {
        ox[i + g * LANES..][..LANES].copy_from_slice(&ax[g]);
        oy[i + g * LANES..][..LANES].copy_from_slice(&ay[g]);
    }
}

impl pulp::WithSimd for DenseProduct<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let k = self.x.len();
        let (x, y, matrix) = (&self.x[..k], &self.y[..k], &self.matrix[..k * k]);
        let body = k - k % LANES;
        let out = &mut *self.sums;
        let mut i = 0;
        while i < body {
            match (body - i) / LANES {
                1 => dense_group::<1>(matrix, k, i, x, y, out),
                2 => dense_group::<2>(matrix, k, i, x, y, out),
                3 => dense_group::<3>(matrix, k, i, x, y, out),
                _ => dense_group::<4>(matrix, k, i, x, y, out),
            }
            i += 4 * LANES;
        }
        let (ox, oy) = out.split_at(k);
        for (o, (x, y)) in self.out[..body].iter_mut().zip(ox.iter().zip(oy)) {
            *o = DVec2::new(*x, *y);
        }
        for i in body..k {
            let mut sum = DVec2::ZERO;
            for ((row, &xj), &yj) in matrix.chunks_exact(k).zip(x).zip(y) {
                sum = DVec2::new(row[i].mul_add(xj, sum.x), row[i].mul_add(yj, sum.y));
            }
            self.out[i] = sum;
        }
    }
}

/// Solves `L Lᵀ x = x` in place (x and y together).
fn solve_in_place(factor: &[f64], inverse_diagonal: &[f64], x: &mut [DVec2]) {
    let k = x.len();
    for i in 0..k {
        let row = &factor[i * k..i * k + i];
        let (done, rest) = x.split_at_mut(i);
        // Four partial sums: the row's products pipeline instead of
        // waiting on one running sum (a K-long dependency chain per row).
        let mut acc = [DVec2::ZERO; 4];
        let (body, tail) = row.split_at(i - i % 4);
        let (dbody, dtail) = done.split_at(i - i % 4);
        for (l, y) in body.chunks_exact(4).zip(dbody.chunks_exact(4)) {
            for q in 0..4 {
                acc[q] += y[q] * l[q];
            }
        }
        for (l, y) in tail.iter().zip(dtail) {
            acc[0] += *y * *l;
        }
        rest[0] = (rest[0] - ((acc[0] + acc[1]) + (acc[2] + acc[3]))) * inverse_diagonal[i];
    }
    for i in (0..k).rev() {
        let (before, rest) = x.split_at_mut(i);
        let xi = rest[0] * inverse_diagonal[i];
        rest[0] = xi;
        for (y, l) in before.iter_mut().zip(&factor[i * k..i * k + i]) {
            *y -= xi * *l;
        }
    }
}

/// Vertices per cache block of the transposed pass: the block's M rows of
/// `s`, one row of `t` and its `t_r ⊙ u` stay in the first-level cache
/// while every grid row r reuses them.
const BLOCK: usize = 128;

/// Bernstein rows of `W` in factored form: vertex v's row is the tensor
/// product of its M column weights and N row weights,
/// `W_v[r·M + c] = t_r(v)·s_c(v)`, so a frame's pass reads M + N numbers a
/// vertex instead of M·N. Stored weight-major (all vertices' `s_c`, then
/// `s_{c+1}`…) with the vertex count padded to whole lanes by zero weights,
/// so the kernels run across vertices in SIMD lanes. Each pass still does
/// the M·N multiply-adds per vertex the dense row needs (the basis has
/// global support: no weight is zero inside the box).
#[derive(Debug, Clone)]
struct Tensor {
    columns: usize,
    rows: usize,
    /// Vertex count rounded up to a multiple of [`LANES`].
    padded: usize,
    /// `columns × padded`.
    s: Vec<f64>,
    /// `rows × padded`.
    t: Vec<f64>,
}

/// The frame passes' scratch, sized at registration.
#[derive(Debug, Clone)]
struct TensorScratch {
    /// Δ column-major, x and y interleaved: `2K`.
    d: Vec<f64>,
    /// Per (padded) vertex by coordinate: `WΔ` out of [`Tensor::apply`],
    /// the vector multiplied by `Wᵀ` into [`Tensor::add_transposed`].
    ux: Vec<f64>,
    uy: Vec<f64>,
    /// `t_r ⊙ x` for one block and grid row, `BLOCK` each.
    yx: Vec<f64>,
    yy: Vec<f64>,
    /// Lane partial sums of `Wᵀ x`, x and y per handle.
    sums: Vec<[f64; LANES]>,
}

impl TensorScratch {
    fn new(blend: &Blend) -> TensorScratch {
        let (k, padded, rows) = match blend {
            Blend::Dense { tensor, .. } => {
                (tensor.columns * tensor.rows, tensor.padded, tensor.rows)
            }
            Blend::Lattice { .. } => (0, 0, 0),
        };
        TensorScratch {
            d: vec![0.0; 2 * k],
            ux: vec![0.0; padded],
            uy: vec![0.0; padded],
            yx: vec![0.0; if rows > 0 { BLOCK } else { 0 }],
            yy: vec![0.0; if rows > 0 { BLOCK } else { 0 }],
            sums: vec![[0.0; LANES]; 2 * k],
        }
    }
}

impl Tensor {
    fn new(columns: usize, rows: usize, normalised: &[DVec2]) -> Tensor {
        let padded = normalised.len().div_ceil(LANES) * LANES;
        let mut s = vec![0.0; columns * padded];
        let mut t = vec![0.0; rows * padded];
        let (mut bs, mut bt) = (vec![0.0; columns], vec![0.0; rows]);
        for (v, st) in normalised.iter().enumerate() {
            bernstein(columns - 1, st.x, &mut bs);
            bernstein(rows - 1, st.y, &mut bt);
            for (c, &w) in bs.iter().enumerate() {
                s[c * padded + v] = w;
            }
            for (r, &w) in bt.iter().enumerate() {
                t[r * padded + v] = w;
            }
        }
        Tensor {
            columns,
            rows,
            padded,
            s,
            t,
        }
    }

    /// `out = base + W Δ`.
    fn apply(
        &self,
        scratch: &mut TensorScratch,
        base: &[DVec2],
        delta: &[DVec2],
        out: &mut [DVec2],
    ) {
        let (m, n) = (self.columns, self.rows);
        for (h, d) in delta.iter().enumerate() {
            let (r, c) = (h / m, h % m);
            scratch.d[c * 2 * n + 2 * r] = d.x;
            scratch.d[c * 2 * n + 2 * r + 1] = d.y;
        }
        pulp::Arch::new().dispatch(ApplyKernel {
            tensor: self,
            d: &scratch.d,
            ux: &mut scratch.ux,
            uy: &mut scratch.uy,
        });
        for (((o, b), x), y) in out.iter_mut().zip(base).zip(&scratch.ux).zip(&scratch.uy) {
            *o = *b + DVec2::new(*x, *y);
        }
    }

    /// `out += Wᵀ x`.
    fn add_transposed(&self, scratch: &mut TensorScratch, x: &[DVec2], out: &mut [DVec2]) {
        for ((ux, uy), v) in scratch.ux.iter_mut().zip(&mut scratch.uy).zip(x) {
            (*ux, *uy) = (v.x, v.y);
        }
        self.add_transposed_scratch(scratch, out);
    }

    /// `out += Wᵀ x` for x already in `scratch.ux`, `scratch.uy` (the
    /// padding lanes zero).
    fn add_transposed_scratch(&self, scratch: &mut TensorScratch, out: &mut [DVec2]) {
        pulp::Arch::new().dispatch(TransposedKernel {
            tensor: self,
            ux: &scratch.ux,
            uy: &scratch.uy,
            yx: &mut scratch.yx,
            yy: &mut scratch.yy,
            sums: &mut scratch.sums,
        });
        let lane_sum = |a: &[f64; LANES]| (a[0] + a[1]) + (a[2] + a[3]);
        for (o, pair) in out.iter_mut().zip(scratch.sums.chunks_exact(2)) {
            *o += DVec2::new(lane_sum(&pair[0]), lane_sum(&pair[1]));
        }
    }
}

/// `u = WΔ` over all vertex lanes. `f64::mul_add` is one instruction where
/// dispatch found FMA and an exact library call elsewhere, so every machine
/// computes the same bits.
struct ApplyKernel<'a> {
    tensor: &'a Tensor,
    d: &'a [f64],
    ux: &'a mut [f64],
    uy: &'a mut [f64],
}

/// Columns of `s` a transposed step carries at once, and grid rows of `Δ`
/// an apply step on a lone lane block does: 2·5 independent sums per lane
/// hide the multiply-add latency on two pipes, and with the operands they
/// fit the sixteen SIMD registers.
const GROUP: usize = 5;
const APPLY_GROUP: usize = 5;

/// For grid rows `r..r + G` of the B vertex lane blocks from `at`:
/// `a_g = Σ_c s_c Δ_(r+g)c` (each over c in order, so the bits depend on
/// neither G nor B), then `u += t_(r+g) a_g` in row order. `d` holds Δ
/// column-major with x and y interleaved (`d[c·2N + 2r + {0, 1}]`), so one
/// short run of it feeds a step, and each value loaded feeds B blocks.
#[inline(always)]
fn apply_group<const B: usize, const G: usize>(
    tensor: &Tensor,
    at: usize,
    r: usize,
    d: &[f64],
    ux: &mut [[f64; LANES]; B],
    uy: &mut [[f64; LANES]; B],
) {
    let (n, padded) = (tensor.rows, tensor.padded);
    let (mut ax, mut ay) = ([[[0.0; LANES]; G]; B], [[[0.0; LANES]; G]; B]);
    for (sc, dc) in tensor.s.chunks_exact(padded).zip(d.chunks_exact(2 * n)) {
        let sc = &sc[at..][..B * LANES];
        let dc = &dc[2 * r..][..2 * G];
        for g in 0..G {
            let (gx, gy) = (dc[2 * g], dc[2 * g + 1]);
            for b in 0..B {
                for l in 0..LANES {
                    let w = sc[b * LANES + l];
                    ax[b][g][l] = w.mul_add(gx, ax[b][g][l]);
                    ay[b][g][l] = w.mul_add(gy, ay[b][g][l]);
                }
            }
        }
    }
    for g in 0..G {
        let tr = &tensor.t[(r + g) * padded + at..][..B * LANES];
        for b in 0..B {
            for l in 0..LANES {
                let w = tr[b * LANES + l];
                ux[b][l] = w.mul_add(ax[b][g][l], ux[b][l]);
                uy[b][l] = w.mul_add(ay[b][g][l], uy[b][l]);
            }
        }
    }
}

/// [`apply_group`] over all grid rows for B blocks from `at`, into `ox`,
/// `oy` (`B·LANES` each).
#[inline(always)]
fn apply_blocks<const B: usize, const G: usize>(
    tensor: &Tensor,
    at: usize,
    d: &[f64],
    ox: &mut [f64],
    oy: &mut [f64],
) {
    let n = tensor.rows;
    let (mut ux, mut uy) = ([[0.0; LANES]; B], [[0.0; LANES]; B]);
    let mut r = 0;
    while r < n {
        match (n - r).min(G) {
            1 => apply_group::<B, 1>(tensor, at, r, d, &mut ux, &mut uy),
            2 => apply_group::<B, 2>(tensor, at, r, d, &mut ux, &mut uy),
            3 => apply_group::<B, 3>(tensor, at, r, d, &mut ux, &mut uy),
            4 => apply_group::<B, 4>(tensor, at, r, d, &mut ux, &mut uy),
            _ => apply_group::<B, 5>(tensor, at, r, d, &mut ux, &mut uy),
        }
        r += G;
    }
    for b in 0..B {
        ox[b * LANES..][..LANES].copy_from_slice(&ux[b]);
        oy[b * LANES..][..LANES].copy_from_slice(&uy[b]);
    }
}

impl pulp::WithSimd for ApplyKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        // Σ_r t_r Σ_c s_c Δ_rc: (M + 1)·N per coordinate, the weight
        // products never formed. Two blocks at a time, three grid rows a
        // step: twelve independent sums, and each broadcast Δ serves eight
        // vertices.
        let (t, d) = (self.tensor, self.d);
        let padded = t.padded;
        let pairs = padded / (2 * LANES) * (2 * LANES);
        let (mut at, ux, uy) = (0, &mut *self.ux, &mut *self.uy);
        while at < pairs {
            let (ox, oy) = (&mut ux[at..][..2 * LANES], &mut uy[at..][..2 * LANES]);
            apply_blocks::<2, 3>(t, at, d, ox, oy);
            at += 2 * LANES;
        }
        if at < padded {
            let (ox, oy) = (&mut ux[at..][..LANES], &mut uy[at..][..LANES]);
            apply_blocks::<1, APPLY_GROUP>(t, at, d, ox, oy);
        }
    }
}

/// Lane partial sums of `Wᵀ u` into `sums`: per cache block of vertices and
/// grid row r, `y = t_r ⊙ u`, then for every handle (r, c) the lane dot
/// product of `s_c` with `y`, [`GROUP`] columns at a time.
struct TransposedKernel<'a> {
    tensor: &'a Tensor,
    ux: &'a [f64],
    uy: &'a [f64],
    yx: &'a mut [f64],
    yy: &'a mut [f64],
    sums: &'a mut [[f64; LANES]],
}

/// `sums[2q] += Σ s_{c+q} ⊙ yx`, `sums[2q+1] += Σ s_{c+q} ⊙ yy` over
/// `len` lanes from `at`, for the G columns from `c`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn transposed_group<const G: usize>(
    s: &[f64],
    padded: usize,
    c: usize,
    at: usize,
    yx: &[f64],
    yy: &[f64],
    sums: &mut [[f64; LANES]],
) {
    let len = yx.len().min(yy.len()) / LANES * LANES;
    let rows: [&[f64]; G] = std::array::from_fn(|q| &s[(c + q) * padded + at..][..len]);
    let mut acc = [[0.0; LANES]; 2 * GROUP];
    for q in 0..G {
        acc[2 * q] = sums[2 * q];
        acc[2 * q + 1] = sums[2 * q + 1];
    }
    let mut i = 0;
    while i < len {
        // SAFETY: i + LANES <= len, the length of `rows[q]`, `yx` and `yy`
        // (checked by the slicing above).
        let (x, y) = unsafe {
            (
                yx.get_unchecked(i..i + LANES),
                yy.get_unchecked(i..i + LANES),
            )
        };
        for q in 0..G {
            // SAFETY: as above.
            let sc = unsafe { rows[q].get_unchecked(i..i + LANES) };
            for l in 0..LANES {
                acc[2 * q][l] = sc[l].mul_add(x[l], acc[2 * q][l]);
                acc[2 * q + 1][l] = sc[l].mul_add(y[l], acc[2 * q + 1][l]);
            }
        }
        i += LANES;
    }
    sums[..2 * G].copy_from_slice(&acc[..2 * G]);
}

impl pulp::WithSimd for TransposedKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Tensor {
            columns: m,
            rows: n,
            padded,
            ref s,
            ref t,
        } = *self.tensor;
        self.sums.fill([0.0; LANES]);
        let mut at = 0;
        while at < padded {
            let len = BLOCK.min(padded - at);
            for r in 0..n {
                let tr = &t[r * padded + at..][..len];
                let (yx, yy) = (&mut self.yx[..len], &mut self.yy[..len]);
                for i in 0..len {
                    yx[i] = tr[i] * self.ux[at + i];
                    yy[i] = tr[i] * self.uy[at + i];
                }
                let (yx, yy) = (&*yx, &*yy);
                let mut c = 0;
                while c < m {
                    let sums = &mut self.sums[2 * (r * m + c)..];
                    match m - c {
                        1 => transposed_group::<1>(s, padded, c, at, yx, yy, sums),
                        2 => transposed_group::<2>(s, padded, c, at, yx, yy, sums),
                        3 => transposed_group::<3>(s, padded, c, at, yx, yy, sums),
                        4 => transposed_group::<4>(s, padded, c, at, yx, yy, sums),
                        _ => transposed_group::<GROUP>(s, padded, c, at, yx, yy, sums),
                    }
                    c += GROUP;
                }
            }
            at += len;
        }
    }
}
