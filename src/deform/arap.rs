//! The two-step as-rigid-as-possible solver of Igarashi, Moscovich & Hughes
//! (2005), as restated in `shared/design/algorithms.md` §1.
//!
//! Step 1 finds the scale-free shape (energy `vᵀGv`), step 2a fits a rotated
//! rest triangle to each step-1 triangle, step 2b assembles them (energy with
//! the weighted edge Laplacian `H`). Handles are linear constraints `B v = q`
//! — a vertex, or a barycentric point inside a triangle — so a finger can land
//! anywhere.
//!
//! How handle-set changes stay cheap: each connected piece's `G` and `H` are
//! made positive definite once, at registration, by adding `δ` on a few
//! "anchor" coordinates (`K = A + δ E Eᵀ`), and factored once. The constrained
//! minimum is then `v = K⁻¹b + W ξ` with `W = K⁻¹ [Bᵀ E]` and `ξ` from a small
//! dense system `(B̃ W − diag(0, I/δ)) ξ = [q; 0] − B̃ K⁻¹ b` (`B̃ = [B; Eᵀ]`).
//! This is exactly the KKT solution of the original singular problem — the
//! anchors carry no stiffness, their values are unknowns — so adding a handle
//! costs one sparse solve per column of `W` it adds and removing one costs
//! nothing; the sparse factors never change.
//!
//! Pieces with fewer than two handles cannot be solved (rotation and scale are
//! free); they are placed rigidly as `algorithms.md` prescribes.

use faer::Mat;
use faer::linalg::solvers::DenseSolveCore;
use glam::DVec2;

use super::sparse::{FactorError, SpdFactor};
use crate::mesh::Mesh;

/// Where a handle holds the mesh, in rest terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Anchor {
    /// A mesh vertex.
    Vertex(u32),
    /// A point inside a triangle, as barycentric weights of its corners
    /// (non-negative, summing to 1).
    Point { triangle: u32, bary: [f64; 3] },
}

/// Which steps an update runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Steps {
    /// Step 1 only: the scale-free intermediate result.
    ScaleFree,
    /// Steps 1 and 2: the as-rigid-as-possible result.
    Both,
}

#[derive(Debug, thiserror::Error)]
pub enum ArapError {
    #[error("handle {handle}: vertex {vertex} is out of range (the mesh has {count} vertices)")]
    VertexOutOfRange {
        handle: usize,
        vertex: u32,
        count: usize,
    },
    #[error("handle {handle}: triangle {triangle} is out of range (the mesh has {count} triangles)")]
    TriangleOutOfRange {
        handle: usize,
        triangle: u32,
        count: usize,
    },
    #[error("handle {handle}: barycentric weights {bary:?} must be finite, non-negative and sum to 1")]
    BadBarycentric { handle: usize, bary: [f64; 3] },
    #[error("expected {expected} handle targets (one per compiled handle), got {got}")]
    TargetCount { expected: usize, got: usize },
    #[error("handle {handle}: target is not a finite point")]
    TargetNotFinite { handle: usize },
    #[error("piece {piece}: {source}")]
    Factor { piece: usize, source: FactorError },
}

/// One triangle of a piece, in the piece's local vertex numbering.
#[derive(Debug, Clone)]
struct LocalTriangle {
    corners: [u32; 3],
    weight: f64,
    /// Rest corners relative to the rest centroid: the step-2a fit target.
    centred: [DVec2; 3],
}

/// A handle's constraint row over a piece's local vertices.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Row {
    corners: [u32; 3],
    weights: [f64; 3],
}

impl Row {
    /// `Σ wᵢ x[corner]` over a vector of one value per vertex.
    #[inline]
    fn dot_scalar(&self, x: &[f64]) -> f64 {
        self.weights[0] * x[self.corners[0] as usize]
            + self.weights[1] * x[self.corners[1] as usize]
            + self.weights[2] * x[self.corners[2] as usize]
    }
    /// The same over one coordinate (`axis` 0 = x, 1 = y) of an interleaved
    /// x,y vector.
    #[inline]
    fn dot_axis(&self, x: &[f64], axis: usize) -> f64 {
        self.weights[0] * x[2 * self.corners[0] as usize + axis]
            + self.weights[1] * x[2 * self.corners[1] as usize + axis]
            + self.weights[2] * x[2 * self.corners[2] as usize + axis]
    }
}

/// A compiled handle inside a piece, with its columns of `W`.
#[derive(Debug, Clone)]
struct PieceHandle {
    anchor: Anchor,
    row: Row,
    rest_point: DVec2,
    /// Index into the caller's targets.
    target: usize,
    /// `K₁⁻¹` applied to the handle's x-row and y-row (2 columns of 2n).
    step1_columns: Vec<f64>,
    /// `K₂⁻¹` applied to the handle's row (n).
    step2_column: Vec<f64>,
}

/// How a piece is placed for its current handle count.
#[derive(Debug, Clone)]
enum Placement {
    /// No handle: a fixed rigid placement, written at compile time.
    Fixed,
    /// One handle: the rest shape rotated by `rotation` (cos, sin) and carried
    /// by the handle.
    Carried { rotation: DVec2 },
    /// Two or more handles: solved; the inverses of the small systems.
    Solved {
        step1_inverse: Vec<f64>,
        step2_inverse: Vec<f64>,
    },
}

const STEP1_ANCHORS: usize = 4;

/// Everything about one connected piece.
#[derive(Debug)]
struct PieceSolver {
    vertices: Vec<u32>,
    rest: Vec<DVec2>,
    triangles: Vec<LocalTriangle>,
    step1: SpdFactor,
    step2: SpdFactor,
    /// Anchored coordinates of `K₁` (indices into the interleaved 2n vector)
    /// and the anchored vertex of `K₂`.
    step1_anchors: [usize; STEP1_ANCHORS],
    step2_anchor: usize,
    step1_delta: f64,
    step2_delta: f64,
    /// `K₁⁻¹ E₁` (4 columns of 2n) and `K₂⁻¹ E₂` (n).
    step1_anchor_columns: Vec<f64>,
    step2_anchor_column: Vec<f64>,
    handles: Vec<PieceHandle>,
    placement: Placement,
    // Frame scratch, sized at compile time.
    step1_rhs: Vec<f64>,
    step1_xi: Vec<f64>,
    step1_pose: Vec<f64>,
    step2_rhs: Vec<f64>,
    step2_xi: Vec<f64>,
    step2_pose: Vec<f64>,
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
    /// Two handles closer than this in rest space are the same handle.
    same_point: f64,
}

/// Best rotation (as cos, sin) taking `rest` onto `pose` about their
/// centroids, and the two centroids; identity when undetermined.
fn fit_rotation(rest: impl Iterator<Item = (DVec2, DVec2)> + Clone) -> (DVec2, DVec2, DVec2) {
    let mut count = 0.0;
    let (mut rest_mean, mut pose_mean) = (DVec2::ZERO, DVec2::ZERO);
    for (r, p) in rest.clone() {
        rest_mean += r;
        pose_mean += p;
        count += 1.0;
    }
    rest_mean /= count;
    pose_mean /= count;
    let (mut dot, mut crs) = (0.0, 0.0);
    for (r, p) in rest {
        let (r, p) = (r - rest_mean, p - pose_mean);
        dot += r.dot(p);
        crs += r.perp_dot(p);
    }
    (unit_rotation(dot, crs), rest_mean, pose_mean)
}

#[inline]
fn unit_rotation(dot: f64, crs: f64) -> DVec2 {
    let norm = dot.hypot(crs);
    if norm > 0.0 && norm.is_finite() {
        DVec2::new(dot / norm, crs / norm)
    } else {
        DVec2::X
    }
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
            for (local, &v) in piece.vertices.iter().enumerate() {
                vertex_home[v as usize] = (p as u32, local as u32);
            }
            let local_triangles = piece
                .triangles
                .iter()
                .map(|&t| {
                    let tri = triangles[t as usize];
                    let pts = tri.map(|v| rest[v as usize]);
                    let centroid = (pts[0] + pts[1] + pts[2]) / 3.0;
                    LocalTriangle {
                        corners: tri.map(|v| vertex_home[v as usize].1),
                        weight: mesh.weights()[t as usize],
                        centred: pts.map(|q| q - centroid),
                    }
                })
                .collect();
            let local_rest = piece.vertices.iter().map(|&v| rest[v as usize]).collect();
            pieces.push(
                PieceSolver::register(piece.vertices, local_rest, local_triangles)
                    .map_err(|source| ArapError::Factor { piece: p, source })?,
            );
        }
        Ok(Arap {
            pose: rest.clone(),
            same_point: mesh.size() * 1e-9,
            rest,
            triangles,
            vertex_home,
            pieces,
            handle_count: 0,
        })
    }

    /// Compilation: sets the handle set. Handles present in the previous set
    /// keep their precomputed columns; each new one costs a few sparse solves
    /// in its own piece. Two handles on the same rest point: the later wins.
    /// Pieces left with fewer than two handles are fixed rigidly in their
    /// current pose.
    pub fn compile(&mut self, anchors: &[Anchor]) -> Result<(), ArapError> {
        let mut rows = Vec::with_capacity(anchors.len());
        for (h, anchor) in anchors.iter().enumerate() {
            rows.push(self.resolve(h, anchor)?);
        }
        // Later handles shadow earlier ones on the same point.
        let mut live = vec![true; anchors.len()];
        for later in (0..anchors.len()).rev() {
            if !live[later] {
                continue;
            }
            for earlier in 0..later {
                if live[earlier]
                    && rows[earlier].0 == rows[later].0
                    && rows[earlier].2.distance(rows[later].2) <= self.same_point
                {
                    live[earlier] = false;
                }
            }
        }
        let mut per_piece: Vec<Vec<(usize, Anchor, Row, DVec2)>> = vec![Vec::new(); self.pieces.len()];
        for (h, (piece, row, point)) in rows.into_iter().enumerate() {
            if live[h] {
                per_piece[piece].push((h, anchors[h], row, point));
            }
        }
        for (p, wanted) in per_piece.into_iter().enumerate() {
            let piece = &mut self.pieces[p];
            let unchanged = piece.handles.len() == wanted.len()
                && piece.handles.iter().zip(&wanted).all(|(old, new)| old.anchor == new.1);
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
    /// anchors given to [`Arap::compile`]) and recomputes the pose.
    /// Does not allocate.
    pub fn update(&mut self, targets: &[DVec2], steps: Steps) -> Result<&[DVec2], ArapError> {
        if targets.len() != self.handle_count {
            return Err(ArapError::TargetCount {
                expected: self.handle_count,
                got: targets.len(),
            });
        }
        if let Some(h) = targets.iter().position(|t| !t.is_finite()) {
            return Err(ArapError::TargetNotFinite { handle: h });
        }
        for piece in &mut self.pieces {
            piece.update(targets, steps, &mut self.pose);
        }
        Ok(&self.pose)
    }

    /// The current deformed vertex positions (rest order).
    pub fn pose(&self) -> &[DVec2] {
        &self.pose
    }

    pub fn rest(&self) -> &[DVec2] {
        &self.rest
    }

    /// Number of connected pieces.
    pub fn piece_count(&self) -> usize {
        self.pieces.len()
    }
}

impl PieceSolver {
    fn register(
        vertices: Vec<u32>,
        rest: Vec<DVec2>,
        triangles: Vec<LocalTriangle>,
    ) -> Result<PieceSolver, FactorError> {
        let n = rest.len();
        let mut g = Vec::with_capacity(triangles.len() * 3 * 21);
        let mut h = Vec::with_capacity(triangles.len() * 6);
        for tri in &triangles {
            let w = tri.weight;
            for k in 0..3 {
                // Corner c expressed in the frame of the opposite edge a→b.
                let (a, b, c) = (tri.corners[(k + 1) % 3], tri.corners[(k + 2) % 3], tri.corners[k]);
                let (pa, pb, pc) = (rest[a as usize], rest[b as usize], rest[c as usize]);
                let edge = pb - pa;
                let rot_edge = DVec2::new(edge.y, -edge.x); // R·edge, R = [[0,1],[-1,0]]
                let len2 = edge.length_squared();
                let x = (pc - pa).dot(edge) / len2;
                let y = (pc - pa).dot(rot_edge) / len2;
                // e = v_c − v_a − x(v_b − v_a) − yR(v_b − v_a) = J [v_a; v_b; v_c].
                // M_a = −(1−x)I + yR, M_b = −xI − yR, M_c = I.
                let j: [[f64; 6]; 2] = [
                    [-(1.0 - x), y, -x, -y, 1.0, 0.0],
                    [-y, -(1.0 - x), y, -x, 0.0, 1.0],
                ];
                let index = |q: usize| 2 * [a, b, c][q / 2] as usize + q % 2;
                for r in 0..6 {
                    for s in 0..6 {
                        let (ir, is) = (index(r), index(s));
                        if ir <= is {
                            let value = w * (j[0][r] * j[0][s] + j[1][r] * j[1][s]);
                            if value != 0.0 {
                                g.push((ir, is, value));
                            }
                        }
                    }
                }
                let (i, jj) = (a.min(b) as usize, a.max(b) as usize);
                h.push((i, i, w));
                h.push((jj, jj, w));
                h.push((i, jj, -w));
            }
        }
        let mean_diagonal = |m: &[(usize, usize, f64)], dim: usize| {
            m.iter().filter(|e| e.0 == e.1).map(|e| e.2).sum::<f64>() / dim as f64
        };
        let step1_delta = mean_diagonal(&g, 2 * n);
        let step2_delta = mean_diagonal(&h, n);
        // Anchor two far-apart vertices for step 1 (pins similarity), one for
        // step 2 (pins translation).
        let first = (0..n)
            .min_by(|&i, &j| rest[i].x.total_cmp(&rest[j].x))
            .unwrap();
        let second = (0..n)
            .max_by(|&i, &j| {
                rest[i]
                    .distance_squared(rest[first])
                    .total_cmp(&rest[j].distance_squared(rest[first]))
            })
            .unwrap();
        let step1_anchors = [2 * first, 2 * first + 1, 2 * second, 2 * second + 1];
        for &a in &step1_anchors {
            g.push((a, a, step1_delta));
        }
        h.push((first, first, step2_delta));
        let mut step1 = SpdFactor::new(2 * n, &g, 2)?;
        let mut step2 = SpdFactor::new(n, &h, 2)?;
        let mut step1_anchor_columns = vec![0.0; 2 * n * STEP1_ANCHORS];
        for (c, &a) in step1_anchors.iter().enumerate() {
            step1_anchor_columns[c * 2 * n + a] = 1.0;
        }
        for chunk in step1_anchor_columns.chunks_mut(4 * n) {
            step1.solve_in_place(chunk);
        }
        let mut step2_anchor_column = vec![0.0; n];
        step2_anchor_column[first] = 1.0;
        step2.solve_in_place(&mut step2_anchor_column);
        Ok(PieceSolver {
            vertices,
            rest,
            triangles,
            step1,
            step2,
            step1_anchors,
            step2_anchor: first,
            step1_delta,
            step2_delta,
            step1_anchor_columns,
            step2_anchor_column,
            handles: Vec::new(),
            placement: Placement::Fixed,
            step1_rhs: Vec::new(),
            step1_xi: Vec::new(),
            step1_pose: vec![0.0; 2 * n],
            step2_rhs: Vec::new(),
            step2_xi: Vec::new(),
            step2_pose: vec![0.0; 2 * n],
        })
    }

    fn n(&self) -> usize {
        self.rest.len()
    }

    fn compile(&mut self, wanted: Vec<(usize, Anchor, Row, DVec2)>, pose: &mut [DVec2]) {
        let n = self.n();
        let mut old = std::mem::take(&mut self.handles);
        for (target, anchor, row, rest_point) in wanted {
            let reused = old.iter().position(|h| h.anchor == anchor).map(|i| old.swap_remove(i));
            let handle = match reused {
                Some(mut h) => {
                    h.target = target;
                    h
                }
                None => {
                    let mut step1_columns = vec![0.0; 4 * n];
                    let mut step2_column = vec![0.0; n];
                    for c in 0..3 {
                        let v = row.corners[c] as usize;
                        step1_columns[2 * v] += row.weights[c];
                        step1_columns[2 * n + 2 * v + 1] += row.weights[c];
                        step2_column[v] += row.weights[c];
                    }
                    self.step1.solve_in_place(&mut step1_columns);
                    self.step2.solve_in_place(&mut step2_column);
                    PieceHandle {
                        anchor,
                        row,
                        rest_point,
                        target,
                        step1_columns,
                        step2_column,
                    }
                }
            };
            self.handles.push(handle);
        }
        let current = |pose: &[DVec2], vertices: &[u32]| -> Vec<DVec2> {
            vertices.iter().map(|&v| pose[v as usize]).collect()
        };
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
                let (rotation, _, _) = fit_rotation(self.rest.iter().copied().zip(now.iter().copied()));
                Placement::Carried { rotation }
            }
            _ => {
                let (step1_inverse, step2_inverse) = self.small_inverses();
                let m1 = 2 * self.handles.len() + STEP1_ANCHORS;
                let m2 = self.handles.len() + 1;
                self.step1_rhs = vec![0.0; m1];
                self.step1_xi = vec![0.0; m1];
                self.step2_rhs = vec![0.0; 2 * m2];
                self.step2_xi = vec![0.0; 2 * m2];
                Placement::Solved {
                    step1_inverse,
                    step2_inverse,
                }
            }
        };
    }

    /// Inverses of `B̃ W − diag(0, I/δ)` for both steps (column-major).
    fn small_inverses(&self) -> (Vec<f64>, Vec<f64>) {
        let n = self.n();
        let k = self.handles.len();
        // Step 1: rows/columns 2h (x) and 2h+1 (y) per handle, then anchors.
        let m1 = 2 * k + STEP1_ANCHORS;
        let column1 = |j: usize| -> &[f64] {
            if j < 2 * k {
                let h = &self.handles[j / 2];
                &h.step1_columns[(j % 2) * 2 * n..(j % 2 + 1) * 2 * n]
            } else {
                let a = j - 2 * k;
                &self.step1_anchor_columns[a * 2 * n..(a + 1) * 2 * n]
            }
        };
        let row1 = |i: usize, col: &[f64]| -> f64 {
            if i < 2 * k {
                self.handles[i / 2].row.dot_axis(col, i % 2)
            } else {
                col[self.step1_anchors[i - 2 * k]]
            }
        };
        let s1 = Mat::<f64>::from_fn(m1, m1, |i, j| {
            let mut value = row1(i, column1(j));
            if i == j && i >= 2 * k {
                value -= 1.0 / self.step1_delta;
            }
            value
        });
        let m2 = k + 1;
        let column2 = |j: usize| -> &[f64] {
            if j < k {
                &self.handles[j].step2_column
            } else {
                &self.step2_anchor_column
            }
        };
        let row2 = |i: usize, col: &[f64]| -> f64 {
            if i < k {
                self.handles[i].row.dot_scalar(col)
            } else {
                col[self.step2_anchor]
            }
        };
        let s2 = Mat::<f64>::from_fn(m2, m2, |i, j| {
            let mut value = row2(i, column2(j));
            if i == k && j == k {
                value -= 1.0 / self.step2_delta;
            }
            value
        });
        let to_vec = |m: Mat<f64>| {
            let mut out = Vec::with_capacity(m.nrows() * m.ncols());
            for j in 0..m.ncols() {
                for i in 0..m.nrows() {
                    out.push(m[(i, j)]);
                }
            }
            out
        };
        (
            to_vec(s1.full_piv_lu().inverse()),
            to_vec(s2.full_piv_lu().inverse()),
        )
    }

    fn update(&mut self, targets: &[DVec2], steps: Steps, pose: &mut [DVec2]) {
        let n = self.n();
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
                // Step 1: v₁ = W₁ ξ₁, ξ₁ = S₁⁻¹ [q; 0].
                let m1 = 2 * k + STEP1_ANCHORS;
                for (h, handle) in self.handles.iter().enumerate() {
                    let q = targets[handle.target];
                    self.step1_rhs[2 * h] = q.x;
                    self.step1_rhs[2 * h + 1] = q.y;
                }
                self.step1_rhs[2 * k..].fill(0.0);
                small_multiply(step1_inverse, &self.step1_rhs, &mut self.step1_xi, m1);
                let v1 = &mut self.step1_pose;
                v1.fill(0.0);
                for (h, handle) in self.handles.iter().enumerate() {
                    let (x, y) = handle.step1_columns.split_at(2 * n);
                    axpy2(v1, self.step1_xi[2 * h], x, self.step1_xi[2 * h + 1], y);
                }
                let (a01, a23) = self.step1_anchor_columns.split_at(4 * n);
                let xi = &self.step1_xi[2 * k..];
                axpy2(v1, xi[0], &a01[..2 * n], xi[1], &a01[2 * n..]);
                axpy2(v1, xi[2], &a23[..2 * n], xi[3], &a23[2 * n..]);
                if steps == Steps::ScaleFree {
                    for (local, &v) in self.vertices.iter().enumerate() {
                        pose[v as usize] = DVec2::new(v1[2 * local], v1[2 * local + 1]);
                    }
                    return;
                }
                // Step 2a + the right-hand side of 2b: b = Σ_t w_t Σ_edges ±R_t ē.
                let b = &mut self.step2_pose; // n×2, column-major: x then y
                b.fill(0.0);
                for tri in &self.triangles {
                    let [i, j, l] = tri.corners.map(|c| c as usize);
                    let p = [
                        DVec2::new(v1[2 * i], v1[2 * i + 1]),
                        DVec2::new(v1[2 * j], v1[2 * j + 1]),
                        DVec2::new(v1[2 * l], v1[2 * l + 1]),
                    ];
                    // Σ r̄ = 0, so the pose need not be centred.
                    let r = &tri.centred;
                    let dot = r[0].dot(p[0]) + r[1].dot(p[1]) + r[2].dot(p[2]);
                    let crs = r[0].perp_dot(p[0]) + r[1].perp_dot(p[1]) + r[2].perp_dot(p[2]);
                    let rotation = unit_rotation(dot, crs) * tri.weight;
                    // Weighted fitted corners: the edge terms telescope to
                    // b_i += w(2 f_i − f_j − f_l) with f the fitted corners.
                    let f = [rotation.rotate(r[0]), rotation.rotate(r[1]), rotation.rotate(r[2])];
                    let g = [
                        2.0 * f[0] - f[1] - f[2],
                        2.0 * f[1] - f[2] - f[0],
                        2.0 * f[2] - f[0] - f[1],
                    ];
                    for (c, gi) in [i, j, l].into_iter().zip(g) {
                        b[c] += gi.x;
                        b[n + c] += gi.y;
                    }
                }
                self.step2.solve_in_place(b);
                // Step 2b: v = y + W₂ ξ₂, ξ₂ = S₂⁻¹ ([q; 0] − B̃ y), per axis.
                let m2 = k + 1;
                let (bx, by) = b.split_at(n);
                for (h, handle) in self.handles.iter().enumerate() {
                    let q = targets[handle.target];
                    self.step2_rhs[h] = q.x - handle.row.dot_scalar(bx);
                    self.step2_rhs[m2 + h] = q.y - handle.row.dot_scalar(by);
                }
                self.step2_rhs[k] = -bx[self.step2_anchor];
                self.step2_rhs[m2 + k] = -by[self.step2_anchor];
                let (rx, ry) = self.step2_rhs.split_at(m2);
                let (xx, xy) = self.step2_xi.split_at_mut(m2);
                small_multiply(step2_inverse, rx, xx, m2);
                small_multiply(step2_inverse, ry, xy, m2);
                let (px, py) = b.split_at_mut(n);
                for (h, handle) in self.handles.iter().enumerate() {
                    axpy(px, xx[h], &handle.step2_column);
                    axpy(py, xy[h], &handle.step2_column);
                }
                axpy(px, xx[k], &self.step2_anchor_column);
                axpy(py, xy[k], &self.step2_anchor_column);
                for (local, &v) in self.vertices.iter().enumerate() {
                    pose[v as usize] = DVec2::new(px[local], py[local]);
                }
            }
        }
    }
}

/// `out = M x` for a column-major `m`×`m` matrix.
#[inline]
fn small_multiply(matrix: &[f64], x: &[f64], out: &mut [f64], m: usize) {
    out[..m].fill(0.0);
    for (j, &xj) in x[..m].iter().enumerate() {
        for (o, &a) in out[..m].iter_mut().zip(&matrix[j * m..(j + 1) * m]) {
            *o += a * xj;
        }
    }
}

#[inline]
fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    for (yi, &xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// `y += a·x + b·z`, fused so `y` is read and written once.
#[inline]
fn axpy2(y: &mut [f64], a: f64, x: &[f64], b: f64, z: &[f64]) {
    for ((yi, &xi), &zi) in y.iter_mut().zip(x).zip(z) {
        *yi += a * xi + b * zi;
    }
}
