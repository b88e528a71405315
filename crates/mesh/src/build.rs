//! Outline to rest mesh: turns a validated [`Shape`] (or a traced PNG) into a
//! [`Mesh`] of near-equilateral triangles of similar size, at a requested
//! vertex count.
//!
//! The recipe: resample every ring at the target edge length (keeping the
//! points the outline needs to stay within a tenth of an edge), seed the interior with a hexagonal lattice at that spacing, take
//! spade's constrained Delaunay triangulation with the rings as constraints,
//! let spade's Delaunay refinement fix whatever the lattice left poorly shaped
//! near the boundary, then relax interior vertices (boundary fixed) and
//! re-triangulate a few times. The edge length is searched so the vertex
//! count lands near the target.

use std::path::Path;

use glam::DVec2;
use spade::handles::{FixedFaceHandle, InnerTag};
use spade::{
    AngleLimit, ConstrainedDelaunayTriangulation, Point2, RefinementParameters, Triangulation,
};

use super::grid::BucketGrid;
use super::polygon::{Shape, bounds, find_crossing, segment_distance, signed_area, simplify_keep};
use super::trace::{PictureWarning, trace_png};
use super::{MIN_THICKNESS, Mesh, MeshError, cross, invalid, thickness};

type Cdt = ConstrainedDelaunayTriangulation<Point2<f64>>;

/// How to mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MeshOptions {
    /// Roughly how many vertices the mesh should have (the result lands
    /// within a few percent for shapes that are not all boundary). `None`
    /// means [`DEFAULT_VERTICES`], or fewer for shapes so small that edges
    /// would get shorter than [`DEFAULT_MIN_EDGE`].
    pub target_vertices: Option<usize>,
    /// Pieces of a picture (islands of opaque pixels) closer than this
    /// many pixels are bridged into one ([`crate::join`]); none: each
    /// piece moves on its own, with a warning.
    pub join: Option<f64>,
}

/// Vertex count when none is asked for: enough to bend smoothly, few enough
/// that a solver runs it at frame rate without effort.
pub const DEFAULT_VERTICES: usize = 1000;

/// Shortest edge (pixels) the default count will go to on small shapes.
pub const DEFAULT_MIN_EDGE: f64 = 2.0;

/// Simplification tolerance (pixels) for outlines traced from pictures. The
/// boundary is resampled at the mesh's edge length afterwards anyway; this
/// only decides which corners survive.
pub const TRACE_DETAIL: f64 = 0.5;

/// Largest vertex count accepted.
pub const MAX_VERTICES: usize = 10_000_000;

/// How far (in edge lengths) the resampled boundary may stray from the
/// given outline.
const FIDELITY: f64 = 0.1;

/// ... and at most this fraction of the ring's bounding-box diagonal.
const RING_FIDELITY: f64 = 0.03;

/// Delaunay refinement bound: no triangle angle below this, where the input
/// permits (corners sharper than this stay as drawn).
const MIN_ANGLE_DEG: f64 = 28.0;

/// Lattice points come no closer to the boundary than this many edge lengths:
/// nearer, they make slivers with the boundary points.
const CLEARANCE: f64 = 0.55;

/// Relax-and-retriangulate rounds after refinement.
const SMOOTHING_ROUNDS: usize = 4;

/// How close to the target a vertex count must come to stop the search.
const COUNT_TOLERANCE: f64 = 0.04;

/// Meshes a shape. The mesh has no uv and default weights; its vertices are
/// in the shape's coordinates.
pub fn triangulate(source: &str, shape: &Shape, options: &MeshOptions) -> Result<Mesh, MeshError> {
    let (vertices, triangles) = build(source, shape, options)?;
    Mesh::new(source, vertices, triangles, None, None)
}

/// Traces a PNG's alpha, meshes the outline and attaches uv (image
/// convention: v down from the top) so the picture maps onto the mesh.
/// Drops the [`PictureWarning`]s: where a person chose the picture, use
/// [`mesh_picture`] and tell them.
pub fn mesh_png(path: &Path, options: &MeshOptions) -> Result<Mesh, MeshError> {
    mesh_picture(path, options).map(|meshed| meshed.mesh)
}

/// A mesh of a picture, and what its maker should hear about the picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Meshed {
    /// The mesh, in the picture's pixels (y-up), with uv mapping the
    /// picture onto it.
    pub mesh: Mesh,
    /// What to tell whoever chose the picture; empty when nothing is worth
    /// saying.
    pub warnings: Vec<PictureWarning>,
}

/// [`mesh_png`], keeping the warnings (a fully opaque picture meshes as
/// its rectangle, which is rarely what was meant).
pub fn mesh_picture(path: &Path, options: &MeshOptions) -> Result<Meshed, MeshError> {
    let name = path.display().to_string();
    let traced = trace_png(path, TRACE_DETAIL, options.join)?;
    let (vertices, triangles) = build(&name, &traced.shape, options)?;
    let (w, h) = (traced.width as f64, traced.height as f64);
    let uv = vertices
        .iter()
        .map(|v| DVec2::new(v.x / w, (h - v.y) / h))
        .collect();
    Ok(Meshed {
        mesh: Mesh::new(&name, vertices, triangles, Some(uv), None)?,
        warnings: traced.warnings,
    })
}

/// Shape statistics of a mesh, for tests and reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quality {
    /// Smallest triangle angle, in degrees.
    pub min_angle_deg: f64,
    /// Largest triangle angle, in degrees.
    pub max_angle_deg: f64,
    /// Shortest edge length, in the mesh's units.
    pub min_edge: f64,
    /// Longest edge length, in the mesh's units.
    pub max_edge: f64,
    /// Mean edge length, in the mesh's units.
    pub mean_edge: f64,
    /// Standard deviation of edge lengths over their mean.
    pub edge_spread: f64,
    /// Smallest triangle area, in square mesh units.
    pub min_area: f64,
    /// Largest triangle area, in square mesh units.
    pub max_area: f64,
    /// Standard deviation of triangle areas over their mean.
    pub area_spread: f64,
}

/// Measures angles, edge lengths and areas over every triangle (each edge
/// counted once per triangle using it).
pub fn quality(mesh: &Mesh) -> Quality {
    let v = mesh.vertices();
    let mut q = Quality {
        min_angle_deg: 180.0,
        max_angle_deg: 0.0,
        min_edge: f64::INFINITY,
        max_edge: 0.0,
        mean_edge: 0.0,
        edge_spread: 0.0,
        min_area: f64::INFINITY,
        max_area: 0.0,
        area_spread: 0.0,
    };
    let (mut edges, mut edges2, mut areas, mut areas2) = (0.0, 0.0, 0.0, 0.0);
    for t in mesh.triangles() {
        let p = t.map(|i| v[i as usize]);
        for k in 0..3 {
            let a = p[k];
            let b = p[(k + 1) % 3];
            let c = p[(k + 2) % 3];
            let angle = (b - a).angle_to(c - a).abs().to_degrees();
            q.min_angle_deg = q.min_angle_deg.min(angle);
            q.max_angle_deg = q.max_angle_deg.max(angle);
            let len = a.distance(b);
            q.min_edge = q.min_edge.min(len);
            q.max_edge = q.max_edge.max(len);
            edges += len;
            edges2 += len * len;
        }
        let area = cross(p[0], p[1], p[2]) * 0.5;
        q.min_area = q.min_area.min(area);
        q.max_area = q.max_area.max(area);
        areas += area;
        areas2 += area * area;
    }
    let ne = 3.0 * mesh.triangles().len() as f64;
    let nt = mesh.triangles().len() as f64;
    q.mean_edge = edges / ne;
    q.edge_spread = (edges2 / ne - q.mean_edge * q.mean_edge).max(0.0).sqrt() / q.mean_edge;
    let mean_area = areas / nt;
    q.area_spread = (areas2 / nt - mean_area * mean_area).max(0.0).sqrt() / mean_area;
    q
}

/// The edge length at which a shape of this area and perimeter gets about
/// `count` vertices: an equilateral mesh has one vertex per √3/2·h² of area,
/// plus one per h of boundary.
fn edge_for_count(area: f64, perimeter: f64, count: usize) -> f64 {
    let a = area * 2.0 / 3f64.sqrt();
    let n = count as f64;
    // a·x² + perimeter·x − n = 0 for x = 1/h.
    let x = (-perimeter + (perimeter * perimeter + 4.0 * a * n).sqrt()) / (2.0 * a);
    1.0 / x
}

fn default_target(area: f64, perimeter: f64) -> usize {
    let a = area * 2.0 / 3f64.sqrt();
    let h = DEFAULT_MIN_EDGE;
    let at_min_edge = (a / (h * h) + perimeter / h).round() as usize;
    DEFAULT_VERTICES.min(at_min_edge).max(3)
}

/// One triangulation at a given edge length, before smoothing.
struct Draft {
    points: Vec<DVec2>,
    constraints: Vec<[usize; 2]>,
    triangles: Vec<[u32; 3]>,
    /// Points some inside triangle uses: the vertex count the mesh will have.
    used: usize,
}

fn build(
    source: &str,
    shape: &Shape,
    options: &MeshOptions,
) -> Result<(Vec<DVec2>, Vec<[u32; 3]>), MeshError> {
    shape.validate(source)?;
    let shape = shape.normalized();
    let area = shape.area();
    let perimeter = shape.perimeter();
    let target = match options.target_vertices {
        Some(n) if n < 3 => {
            return Err(invalid(
                source,
                "target_vertices",
                format!("must be at least 3, got {n}"),
            ));
        }
        Some(n) if n > MAX_VERTICES => {
            return Err(invalid(
                source,
                "target_vertices",
                format!("must be at most {MAX_VERTICES}, got {n}"),
            ));
        }
        Some(n) => n,
        None => default_target(area, perimeter),
    };
    if !(area.is_finite() && perimeter.is_finite() && area > 0.0) {
        return Err(invalid(
            source,
            "polygons",
            "the shape's area or perimeter is not a finite positive number",
        ));
    }

    // Vertex count falls off about as h⁻² (less where boundary dominates):
    // secant steps on log n against log h, kept inside any bracket found.
    let mut h = edge_for_count(area, perimeter, target);
    let goal = (target as f64).ln();
    let mut tried: Vec<(f64, f64)> = Vec::new();
    let mut best: Option<(f64, Draft)> = None;
    for _ in 0..8 {
        let draft = draft(source, &shape, h)?;
        let n = draft.used;
        let miss = (n as f64 / target as f64).ln().abs();
        tried.push((h.ln(), (n as f64).ln()));
        if best.as_ref().is_none_or(|(m, _)| miss < *m) {
            best = Some((miss, draft));
        }
        if miss < COUNT_TOLERANCE {
            break;
        }
        let (lh, ln) = tried[tried.len() - 1];
        let mut slope = -2.0;
        if tried.len() >= 2 {
            let (ph, pn) = tried[tried.len() - 2];
            let s = (ln - pn) / (lh - ph);
            if s.is_finite() && s < -0.3 {
                slope = s.max(-4.0);
            }
        }
        let mut next = lh + (goal - ln) / slope;
        // Stay strictly between the nearest tries above and below the goal.
        let above = tried
            .iter()
            .filter(|t| t.1 > goal)
            .map(|t| t.0)
            .fold(f64::NEG_INFINITY, f64::max);
        let below = tried
            .iter()
            .filter(|t| t.1 < goal)
            .map(|t| t.0)
            .fold(f64::INFINITY, f64::min);
        if above.is_finite() && below.is_finite() && !(next > above && next < below) {
            next = 0.5 * (above + below);
        }
        let step = (next - lh).clamp(-1.5, 1.5);
        if step.abs() < 1e-4 {
            break;
        }
        h = (lh + step).exp();
    }
    let (_, draft) = best.expect("at least one draft");
    finish(source, draft)
}

/// Boundary at spacing `h`, lattice interior, constrained triangulation and
/// Delaunay refinement.
fn draft(source: &str, shape: &Shape, h: f64) -> Result<Draft, MeshError> {
    let boundary = resample_shape(shape, h);
    let mut points: Vec<DVec2> = Vec::new();
    let mut constraints: Vec<[usize; 2]> = Vec::new();
    for ring in boundary.rings() {
        let first = points.len();
        let n = ring.len();
        points.extend_from_slice(ring);
        constraints.extend((0..n).map(|i| [first + i, first + (i + 1) % n]));
    }
    let rings: Vec<&[DVec2]> = boundary.rings().collect();
    points.extend(lattice(&rings, h, CLEARANCE * h));

    let mut cdt = triangulation(source, &points, &constraints)?;
    let ideal_area = 3f64.sqrt() / 4.0 * h * h;
    let params = RefinementParameters::<f64>::new()
        .exclude_outer_faces(true)
        .with_angle_limit(AngleLimit::from_deg(MIN_ANGLE_DEG))
        .with_max_allowed_area(1.6 * ideal_area)
        // Sharp input corners cannot be fixed; stop chasing them here.
        .with_min_required_area(0.08 * ideal_area)
        .with_max_additional_vertices(points.len() + 64);
    cdt.refine(params);
    let points: Vec<DVec2> = cdt
        .vertices()
        .map(|v| {
            let p = v.position();
            DVec2::new(p.x, p.y)
        })
        .collect();
    let constraints: Vec<[usize; 2]> = cdt
        .undirected_edges()
        .filter(|e| e.is_constraint_edge())
        .map(|e| e.vertices().map(|v| v.fix().index()))
        .collect();
    let triangles = inside_triangles(&cdt);
    let mut referenced = vec![false; points.len()];
    for t in &triangles {
        for &i in t {
            referenced[i as usize] = true;
        }
    }
    Ok(Draft {
        used: referenced.iter().filter(|&&r| r).count(),
        points,
        constraints,
        triangles,
    })
}

/// Relaxes interior vertices and re-triangulates a few times, then drops
/// vertices no inside triangle uses and renumbers.
fn finish(source: &str, draft: Draft) -> Result<(Vec<DVec2>, Vec<[u32; 3]>), MeshError> {
    let Draft {
        mut points,
        constraints,
        mut triangles,
        ..
    } = draft;
    let mut fixed = vec![false; points.len()];
    for &[a, b] in &constraints {
        fixed[a] = true;
        fixed[b] = true;
    }
    for _ in 0..SMOOTHING_ROUNDS {
        let before = points.clone();
        relax(&mut points, &fixed, &triangles, 2);
        match triangulation(source, &points, &constraints) {
            Ok(cdt) => triangles = inside_triangles(&cdt),
            Err(_) => {
                // Rounding made the moved points unusable; keep the last good
                // triangulation.
                points = before;
                break;
            }
        }
    }

    // Renumber in the original order (boundary rings, then lattice rows), so
    // neighbouring vertices keep nearby indices.
    let mut remap = vec![u32::MAX; points.len()];
    for t in &triangles {
        for &i in t {
            remap[i as usize] = 0;
        }
    }
    let mut vertices = Vec::with_capacity(points.len());
    for (k, slot) in remap.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = vertices.len() as u32;
            vertices.push(points[k]);
        }
    }
    for t in &mut triangles {
        for i in t.iter_mut() {
            *i = remap[*i as usize];
        }
    }
    if triangles.is_empty() {
        return Err(invalid(
            source,
            "polygons",
            "the shape is too thin to hold a single triangle",
        ));
    }
    for t in &triangles {
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        if thickness(a, b, c) < MIN_THICKNESS {
            let at = (a + b + c) / 3.0;
            return Err(invalid(
                source,
                "polygons",
                format!(
                    "the shape is too thin to mesh near [{:.3}, {:.3}]: a triangle there is \
                     under {MIN_THICKNESS:e} of its length thick; widen that part",
                    at.x, at.y
                ),
            ));
        }
    }
    Ok((vertices, triangles))
}

fn triangulation(
    source: &str,
    points: &[DVec2],
    constraints: &[[usize; 2]],
) -> Result<Cdt, MeshError> {
    let vertices: Vec<Point2<f64>> = points.iter().map(|p| Point2::new(p.x, p.y)).collect();
    let mut conflicts = 0usize;
    let cdt = Cdt::try_bulk_load_cdt(vertices, constraints.to_vec(), |_| conflicts += 1)
        .map_err(|e| invalid(source, "polygons", format!("cannot triangulate: {e:?}")))?;
    if conflicts > 0 || cdt.num_vertices() != points.len() {
        return Err(invalid(
            source,
            "polygons",
            "cannot triangulate: boundary points coincide or boundary edges cross \
             after rounding; the outline is too fine for its coordinates",
        ));
    }
    Ok(cdt)
}

/// The triangles inside the shape, counter-clockwise: a face is inside when
/// reaching it from outside the hull crosses an odd number of constraints.
fn inside_triangles(cdt: &Cdt) -> Vec<[u32; 3]> {
    const UNSEEN: u8 = 2;
    let mut parity = vec![UNSEEN; cdt.num_all_faces()];
    let mut stack: Vec<(FixedFaceHandle<InnerTag>, u8)> = Vec::new();
    for edge in cdt.convex_hull() {
        if let Some(face) = edge.rev().face().as_inner() {
            stack.push((face.fix(), edge.is_constraint_edge() as u8));
        }
    }
    while let Some((face, p)) = stack.pop() {
        if parity[face.index()] != UNSEEN {
            continue;
        }
        parity[face.index()] = p;
        for edge in cdt.face(face).adjacent_edges() {
            if let Some(next) = edge.rev().face().as_inner()
                && parity[next.fix().index()] == UNSEEN
            {
                stack.push((next.fix(), p ^ edge.is_constraint_edge() as u8));
            }
        }
    }
    let mut triangles = Vec::new();
    for face in cdt.inner_faces() {
        if parity[face.fix().index()] != 1 {
            continue;
        }
        let [a, b, c] = face.vertices().map(|v| v.fix().index() as u32);
        let [pa, pb, pc] = face.positions().map(|p| DVec2::new(p.x, p.y));
        if cross(pa, pb, pc) >= 0.0 {
            triangles.push([a, b, c]);
        } else {
            triangles.push([a, c, b]);
        }
    }
    triangles
}

/// Gauss–Seidel sweeps of optimal-Delaunay relaxation: each free vertex moves
/// to the area-weighted mean of its triangles' circumcentres (the position
/// that best evens out its star), or halfway, or stays, whichever first keeps
/// every triangle of its star counter-clockwise.
fn relax(points: &mut [DVec2], fixed: &[bool], triangles: &[[u32; 3]], sweeps: usize) {
    let n = points.len();
    let mut start = vec![0usize; n + 1];
    for t in triangles {
        for &i in t {
            start[i as usize + 1] += 1;
        }
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut star = vec![0u32; start[n]];
    for (k, t) in triangles.iter().enumerate() {
        for &i in t {
            star[fill[i as usize]] = k as u32;
            fill[i as usize] += 1;
        }
    }
    for _ in 0..sweeps {
        for v in 0..n {
            if fixed[v] || start[v] == start[v + 1] {
                continue;
            }
            let around = &star[start[v]..start[v + 1]];
            let mut weighted = DVec2::ZERO;
            let mut total = 0.0;
            let mut smallest = f64::INFINITY;
            for &k in around {
                let [a, b, c] = triangles[k as usize].map(|i| points[i as usize]);
                let area = cross(a, b, c) * 0.5;
                weighted += circumcentre(a, b, c) * area;
                total += area;
                smallest = smallest.min(area);
            }
            if total <= 0.0 || !weighted.is_finite() {
                continue;
            }
            let old = points[v];
            let target = weighted / total;
            // Triangles may shrink, but not toward a sliver.
            let floor = 0.1 * smallest.max(0.0);
            for step in [1.0, 0.5] {
                let candidate = old + (target - old) * step;
                let ok = around.iter().all(|&k| {
                    let t = triangles[k as usize];
                    let p = t.map(|i| {
                        if i as usize == v {
                            candidate
                        } else {
                            points[i as usize]
                        }
                    });
                    cross(p[0], p[1], p[2]) * 0.5 > floor
                });
                if ok {
                    points[v] = candidate;
                    break;
                }
            }
        }
    }
}

fn circumcentre(a: DVec2, b: DVec2, c: DVec2) -> DVec2 {
    let ab = b - a;
    let ac = c - a;
    let d = 2.0 * ab.perp_dot(ac);
    let ab2 = ab.length_squared();
    let ac2 = ac.length_squared();
    a + DVec2::new(ac.y * ab2 - ab.y * ac2, ab.x * ac2 - ac.x * ab2) / d
}

/// Every ring resampled at spacing `h`. A ring whose resampling crosses a
/// ring (itself included) is resampled finer, and in the end falls back to
/// its own points with long edges split, which is valid because the input
/// is.
fn resample_shape(shape: &Shape, h: f64) -> Shape {
    const FALLBACK: u32 = 3;
    let ids = shape.ring_ids();
    let mut level = vec![0u32; ids.len()];
    let mut out = shape.clone();
    loop {
        for (k, &id) in ids.iter().enumerate() {
            let ring = shape.ring(id);
            let spacing = h / f64::from(1 << level[k].min(FALLBACK));
            let mut r = if level[k] >= FALLBACK {
                subdivide(ring, h)
            } else {
                resample_ring(ring, spacing)
            };
            let (a0, a1) = (signed_area(ring), signed_area(&r));
            if level[k] < FALLBACK && (a0 * a1 <= 0.0 || a1.abs() < 0.25 * a0.abs()) {
                level[k] = FALLBACK;
                r = subdivide(ring, h);
            }
            *out.ring_mut(id) = r;
        }
        let rings: Vec<&[DVec2]> = ids.iter().map(|&id| out.ring(id)).collect();
        if let Some(c) = find_crossing(&rings) {
            let mut bumped = false;
            for r in [c.ring_a, c.ring_b] {
                if level[r] < FALLBACK {
                    level[r] += 1;
                    bumped = true;
                }
            }
            if bumped {
                continue;
            }
            // Cannot happen with a valid input; give back the safe version.
            return fallback(shape, h);
        }
        if out.validate("resampled outline").is_ok() {
            return out;
        }
        if level.iter().all(|&l| l >= FALLBACK) {
            return fallback(shape, h);
        }
        for l in &mut level {
            *l = (*l + 1).min(FALLBACK);
        }
    }
}

fn fallback(shape: &Shape, h: f64) -> Shape {
    let mut out = shape.clone();
    for id in shape.ring_ids() {
        *out.ring_mut(id) = subdivide(shape.ring(id), h);
    }
    out
}

/// The ring's own points, with every edge longer than `h` split evenly.
fn subdivide(ring: &[DVec2], h: f64) -> Vec<DVec2> {
    let n = ring.len();
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let a = ring[i];
        let b = ring[(i + 1) % n];
        let pieces = (a.distance(b) / h).ceil().max(1.0) as usize;
        for k in 0..pieces {
            out.push(a.lerp(b, k as f64 / pieces as f64));
        }
    }
    out
}

/// Points spaced about `spacing` apart along the ring, keeping its corners:
/// between consecutive corners the arc is cut into equal lengths.
fn resample_ring(ring: &[DVec2], spacing: f64) -> Vec<DVec2> {
    let n = ring.len();
    let mut arc = vec![0.0; n + 1];
    for i in 0..n {
        arc[i + 1] = arc[i] + ring[i].distance(ring[(i + 1) % n]);
    }
    let total = arc[n];
    let (lo, hi) = bounds(ring);
    // The outline may stray by a tenth of an edge, but never by more than a
    // small part of the ring's own size, so small holes and islands keep
    // their shape however coarse the mesh.
    let tolerance = (FIDELITY * spacing).min(RING_FIDELITY * (hi - lo).length());
    let needed = simplify_keep(ring, tolerance);
    let mut corners: Vec<usize> = (0..n).filter(|&i| needed[i]).collect();
    // Kept points closer than this along the ring make short edges and small
    // triangles; of such a pair, drop the one the outline misses least, if it
    // misses it by no more than the tolerance.
    let min_gap = 0.4 * spacing;
    let gap = |a: usize, b: usize| {
        if b > a {
            arc[b] - arc[a]
        } else {
            total - arc[a] + arc[b]
        }
    };
    for _ in 0..4 {
        let m = corners.len();
        if m <= 3 {
            break;
        }
        let mut drop = vec![false; m];
        let mut j = 0;
        while j < m {
            let (f, g) = (corners[j], corners[(j + 1) % m]);
            let (prev, next) = (corners[(j + m - 1) % m], corners[(j + 2) % m]);
            if gap(f, g) < min_gap && !drop[(j + m - 1) % m] && !drop[(j + 2) % m] {
                let miss_f = segment_distance(ring[f], ring[prev], ring[g]);
                let miss_g = segment_distance(ring[g], ring[f], ring[next]);
                if miss_f.min(miss_g) <= tolerance {
                    drop[if miss_f <= miss_g { j } else { (j + 1) % m }] = true;
                    // The neighbours of a dropped point wait for the next pass.
                    j += 2;
                    continue;
                }
            }
            j += 1;
        }
        if !drop.contains(&true) {
            break;
        }
        let kept: Vec<usize> = (0..m).filter(|&k| !drop[k]).map(|k| corners[k]).collect();
        if kept.len() < 3 {
            break;
        }
        corners = kept;
    }
    if corners.is_empty() {
        corners.push(0);
    }

    let m = corners.len();
    let span = |j: usize| {
        let a = corners[j];
        let b = corners[(j + 1) % m];
        if m == 1 {
            total
        } else if b > a {
            arc[b] - arc[a]
        } else {
            total - arc[a] + arc[b]
        }
    };
    let mut pieces: Vec<usize> = (0..m)
        .map(|j| ((span(j) / spacing).round() as usize).max(1))
        .collect();
    while pieces.iter().sum::<usize>() < 3 {
        let longest = (0..m)
            .max_by(|&a, &b| (span(a) / pieces[a] as f64).total_cmp(&(span(b) / pieces[b] as f64)))
            .expect("at least one span");
        pieces[longest] += 1;
    }

    // Walk the ring once, unrolled from the first corner.
    let start = corners[0];
    let point_at = |s: f64, seg: &mut usize| -> DVec2 {
        // `s` is arc length from `start`; `seg` counts edges walked so far.
        loop {
            let i = (start + *seg) % n;
            let from = arc[i] - arc[start] + if i < start { total } else { 0.0 };
            let len = arc[i + 1] - arc[i];
            if s <= from + len || *seg + 1 >= n {
                let t = if len > 0.0 {
                    ((s - from) / len).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                return ring[i].lerp(ring[(i + 1) % n], t);
            }
            *seg += 1;
        }
    };
    let mut out = Vec::with_capacity(pieces.iter().sum());
    let mut seg = 0usize;
    let mut offset = 0.0;
    for j in 0..m {
        let length = span(j);
        out.push(ring[corners[j]]);
        for q in 1..pieces[j] {
            out.push(point_at(
                offset + length * q as f64 / pieces[j] as f64,
                &mut seg,
            ));
        }
        offset += length;
    }
    out
}

/// Hexagonal lattice points at spacing `h` inside the rings (even-odd), at
/// least `clearance` from every ring segment.
fn lattice(rings: &[&[DVec2]], h: f64, clearance: f64) -> Vec<DVec2> {
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    let mut segments: Vec<(DVec2, DVec2)> = Vec::new();
    for ring in rings {
        let (l, u) = bounds(ring);
        lo = lo.min(l);
        hi = hi.max(u);
        let n = ring.len();
        segments.extend((0..n).map(|i| (ring[i], ring[(i + 1) % n])));
    }
    let grid = BucketGrid::new(
        lo,
        hi,
        clearance.max(h),
        segments.len(),
        |shape, i, visit| {
            let (a, b) = segments[i];
            shape.visit_box(a.min(b), a.max(b), visit);
        },
    );
    let dy = h * 3f64.sqrt() / 2.0;
    let rows = ((hi.y - lo.y) / dy).floor() as usize;
    let y0 = lo.y + ((hi.y - lo.y) - rows as f64 * dy) / 2.0;
    let columns = ((hi.x - lo.x) / h).floor() as usize;
    let x0 = lo.x + ((hi.x - lo.x) - columns as f64 * h) / 2.0;
    let mut out = Vec::new();
    let mut xs: Vec<f64> = Vec::new();
    for r in 0..=rows {
        let y = y0 + r as f64 * dy;
        xs.clear();
        for &(a, b) in &segments {
            if (a.y > y) != (b.y > y) {
                xs.push(a.x + (y - a.y) / (b.y - a.y) * (b.x - a.x));
            }
        }
        xs.sort_by(f64::total_cmp);
        let shift = if r % 2 == 1 { 0.5 * h } else { 0.0 };
        for pair in xs.chunks_exact(2) {
            let first = ((pair[0] - x0 - shift) / h).ceil() as i64;
            let last = ((pair[1] - x0 - shift) / h).floor() as i64;
            for c in first..=last {
                let p = DVec2::new(x0 + shift + c as f64 * h, y);
                if clear_of(&grid, &segments, p, clearance) {
                    out.push(p);
                }
            }
        }
    }
    out
}

/// Whether no segment comes within `radius` of `p`; `grid` buckets the
/// segments by bounding box in cells at least `radius` wide, so only the
/// 3×3 cells around `p` need looking at.
fn clear_of(grid: &BucketGrid, segments: &[(DVec2, DVec2)], p: DVec2, radius: f64) -> bool {
    let shape = grid.shape();
    let mut clear = true;
    shape.visit_box(
        p - DVec2::splat(shape.cell),
        p + DVec2::splat(shape.cell),
        &mut |k| {
            for &s in grid.members(k) {
                let (a, b) = segments[s as usize];
                let ab = b - a;
                let t =
                    ((p - a).dot(ab) / ab.length_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
                if p.distance_squared(a + ab * t) < radius * radius {
                    clear = false;
                }
            }
        },
    );
    clear
}
