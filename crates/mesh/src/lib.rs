//! The rest-shape triangle mesh: its data, its validation, its file format
//! (`.mesh.json`, see `docs/mesh-format.md`), its connected pieces and point
//! location. Building a mesh from a picture or a polygon lives in
//! [`build`] and [`trace`]; deformers only ever see a validated [`Mesh`].
//!
//! Plain synchronous code over data: no I/O beyond the explicit `load`/`save`.
//! Every public item is documented (`missing_docs` is on here).

pub mod build;
pub mod file;
pub(crate) mod grid;
pub mod join;
pub mod json;
pub mod numbers;
pub mod polygon;
pub mod stroke;
pub mod trace;

use std::collections::HashMap;
use std::path::Path;

use glam::DVec2;
use grid::BucketGrid;
use serde::{Deserialize, Serialize};

/// An error in a mesh: which file, which field, what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened or read; so is a picture that does not
    /// decode as a PNG, or whose image data is cut short.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file's path, as given.
        file: String,
        /// What the operating system (or the PNG decoder) said.
        source: std::io::Error,
    },
    /// Not a regular file, or past its size cap.
    #[error(transparent)]
    File(file::FileError),
    /// The text is not JSON, or not JSON of the expected form (an unknown
    /// field, a point that is not `[x, y]`, an index that is negative).
    #[error("{file}: line {line}, column {column}: {message}")]
    Syntax {
        /// What the text is called in messages: its path, or the name the
        /// caller gave it.
        file: String,
        /// The line of the problem, counting from 1.
        line: usize,
        /// The column of the problem within its line, counting from 1.
        column: usize,
        /// serde's complaint, without the position it repeats.
        message: String,
    },
    /// The data was read but breaks a rule: of the mesh format
    /// (`docs/mesh-format.md`), of a shape, of a picture (too large, nothing
    /// opaque) or of a meshing option.
    #[error(transparent)]
    Invalid(#[from] FieldError),
}

/// A field of a file, or an input, that breaks a rule: what every layer's
/// "invalid" error holds (a mesh's, a stage file's), so each is reported
/// as `file: field: problem`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}: {field}: {problem}")]
pub struct FieldError {
    /// Where the data came from: a path, or the name the caller gave it.
    pub file: String,
    /// The offending field as the file spells it (`triangles[12]`,
    /// `puppet[2].grid.columns`), or the input it concerns (`size`,
    /// `alpha`, `target_vertices`).
    pub field: String,
    /// What is wrong, in words a person can act on.
    pub problem: String,
}

impl FieldError {
    /// `field` of `file` is wrong: `problem`.
    pub fn new(file: &str, field: impl Into<String>, problem: impl Into<String>) -> FieldError {
        FieldError {
            file: file.to_string(),
            field: field.into(),
            problem: problem.into(),
        }
    }
}

/// A file that could not be opened stays an `Io` error, as before there
/// were caps; a file refused by its kind or size is a `File` error.
impl From<file::FileError> for MeshError {
    fn from(e: file::FileError) -> MeshError {
        match e {
            file::FileError::Io { file, source } => MeshError::Io { file, source },
            other => MeshError::File(other),
        }
    }
}

/// A validated rest mesh: counter-clockwise, non-degenerate triangles over
/// finite vertices, every vertex used, with one rigidity weight per triangle.
///
/// Coordinates are y-up (x right); `uv` follows image convention (v down from
/// the top edge of the source picture).
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    vertices: Vec<DVec2>,
    triangles: Vec<[u32; 3]>,
    uv: Option<Vec<DVec2>>,
    weights: Vec<f64>,
    /// Painted depth layers, one per triangle (larger is nearer), if any:
    /// the static order depth adjustment starts from (`docs/depth.md`).
    layers: Option<Vec<u16>>,
}

/// The on-disk shape of a mesh; see `docs/mesh-format.md`.
#[derive(Debug, Serialize, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = "a mesh object {\"vertices\": [[x, y], …], \"triangles\": [[i, j, k], …]}"
)]
struct MeshFile {
    vertices: Vec<json::Point>,
    triangles: Vec<json::Triangle>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    uv: Option<Vec<json::Point>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    weights: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    layers: Option<Vec<u16>>,
}

pub(crate) fn invalid(
    file: &str,
    field: impl Into<String>,
    problem: impl Into<String>,
) -> MeshError {
    MeshError::Invalid(FieldError::new(file, field, problem))
}

/// The softest per-triangle rigidity weight a mesh may hold (1 is the
/// default). The range from here to [`MAX_WEIGHT`] is wide enough for the
/// paper's 10000 for stiff parts and for soft ones, narrow enough that the
/// solver keeps its precision.
pub const MIN_WEIGHT: f64 = 1e-2;
/// The stiffest per-triangle rigidity weight a mesh may hold; see
/// [`MIN_WEIGHT`].
pub const MAX_WEIGHT: f64 = 1e5;

/// The highest depth layer a triangle may be painted with.
pub const MAX_LAYER: u16 = 0x7fff;

/// The thinnest triangle a mesh may hold, as height over longest edge: the
/// step-1 matrix's entries grow like its inverse, and far below this the
/// factorisation loses all precision.
pub const MIN_THICKNESS: f64 = 1e-3;

/// A triangle's height over its longest edge (2·area / longest², signed:
/// negative when clockwise), computed on edges scaled to the longest so it
/// holds at any scale. An equilateral triangle has √3/2.
pub fn thickness(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    let longest = (b - a).length().max((c - b).length()).max((a - c).length());
    if longest > 0.0 {
        ((b - a) / longest).perp_dot((c - a) / longest)
    } else {
        0.0
    }
}

/// Every vertex a finite point within the coordinates' range.
fn check_vertices(file: &str, vertices: &[DVec2]) -> Result<(), MeshError> {
    for (i, v) in vertices.iter().enumerate() {
        if !v.is_finite() {
            return Err(invalid(
                file,
                format!("vertices[{i}]"),
                format!(
                    "coordinate is not a finite number: {}",
                    json::show_point(*v)
                ),
            ));
        }
        if v.abs().max_element() > json::MAX_COORDINATE {
            return Err(invalid(
                file,
                format!("vertices[{i}]"),
                format!(
                    "{} is too far out: coordinates must stay within ±{:e}",
                    json::show_point(*v),
                    json::MAX_COORDINATE
                ),
            ));
        }
    }
    Ok(())
}

/// Every triangle three distinct vertices of the mesh, counter-clockwise
/// and not too thin; every vertex used by one.
fn check_triangles(
    file: &str,
    vertices: &[DVec2],
    triangles: &[[u32; 3]],
) -> Result<(), MeshError> {
    let n = vertices.len();
    let mut used = vec![false; n];
    for (t, tri) in triangles.iter().enumerate() {
        for &i in tri {
            if i as usize >= n {
                return Err(invalid(
                    file,
                    format!("triangles[{t}]"),
                    format!("vertex index {i} is out of range (the mesh has {n} vertices)"),
                ));
            }
            used[i as usize] = true;
        }
        if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
            return Err(invalid(
                file,
                format!("triangles[{t}]"),
                format!("repeats a vertex: {tri:?}"),
            ));
        }
        let [a, b, c] = tri.map(|i| vertices[i as usize]);
        let thickness = thickness(a, b, c);
        if thickness.abs() <= 1e-12 {
            return Err(invalid(
                file,
                format!("triangles[{t}]"),
                format!("has zero area: {tri:?}"),
            ));
        }
        if thickness < 0.0 {
            return Err(invalid(
                file,
                format!("triangles[{t}]"),
                format!("is clockwise (inverted); triangles must be counter-clockwise: {tri:?}"),
            ));
        }
        if thickness < MIN_THICKNESS {
            return Err(invalid(
                file,
                format!("triangles[{t}]"),
                format!(
                    "is too thin to deform stably: its height is {thickness:.1e} of its \
                     longest edge, below {MIN_THICKNESS:e} {tri:?}"
                ),
            ));
        }
    }
    if let Some(i) = used.iter().position(|u| !u) {
        return Err(invalid(
            file,
            format!("vertices[{i}]"),
            "is not used by any triangle",
        ));
    }
    Ok(())
}

/// One finite texture coordinate per vertex.
fn check_uv(file: &str, uv: &[DVec2], n: usize) -> Result<(), MeshError> {
    if uv.len() != n {
        return Err(invalid(
            file,
            "uv",
            format!("has {} entries, expected one per vertex ({n})", uv.len()),
        ));
    }
    if let Some(i) = uv.iter().position(|p| !p.is_finite()) {
        return Err(invalid(file, format!("uv[{i}]"), "is not a finite number"));
    }
    Ok(())
}

/// The triangles' weights, one each within the weights' range, or 1 for
/// every triangle when the file gives none.
fn weights_or_ones(
    file: &str,
    weights: Option<Vec<f64>>,
    triangles: usize,
) -> Result<Vec<f64>, MeshError> {
    match weights {
        None => Ok(vec![1.0; triangles]),
        Some(w) => {
            if w.len() != triangles {
                return Err(invalid(
                    file,
                    "weights",
                    format!(
                        "has {} entries, expected one per triangle ({})",
                        w.len(),
                        triangles
                    ),
                ));
            }
            if let Some(i) = w
                .iter()
                .position(|x| !(MIN_WEIGHT..=MAX_WEIGHT).contains(x))
            {
                return Err(invalid(
                    file,
                    format!("weights[{i}]"),
                    format!(
                        "must be between {MIN_WEIGHT:e} and {MAX_WEIGHT:e}, got {}",
                        json::show(w[i])
                    ),
                ));
            }
            Ok(w)
        }
    }
}

/// Twice the signed area of triangle `abc` (positive when counter-clockwise).
pub fn cross(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - a)
}

impl Mesh {
    /// Validates and builds a mesh. `source` names where the data came from,
    /// for error messages. `weights` defaults to 1 for every triangle. One
    /// check per rule of the format, each naming its field, in the format's
    /// order.
    pub fn new(
        source: &str,
        vertices: Vec<DVec2>,
        triangles: Vec<[u32; 3]>,
        uv: Option<Vec<DVec2>>,
        weights: Option<Vec<f64>>,
    ) -> Result<Mesh, MeshError> {
        let file = source;
        if vertices.is_empty() {
            return Err(invalid(file, "vertices", "the mesh has no vertices"));
        }
        if triangles.is_empty() {
            return Err(invalid(file, "triangles", "the mesh has no triangles"));
        }
        check_vertices(file, &vertices)?;
        let n = vertices.len();
        if n > u32::MAX as usize / 2 {
            return Err(invalid(file, "vertices", "too many vertices"));
        }
        check_triangles(file, &vertices, &triangles)?;
        check_manifold(file, &triangles, n)?;
        if let Some(uv) = &uv {
            check_uv(file, uv, n)?;
        }
        let weights = weights_or_ones(file, weights, triangles.len())?;
        Ok(Mesh {
            vertices,
            triangles,
            uv,
            weights,
            layers: None,
        })
    }

    /// Parses a `.mesh.json` document; `source` names it in errors.
    pub fn from_json(source: &str, text: &str) -> Result<Mesh, MeshError> {
        let file: MeshFile = json::parse(source, text)?;
        let to_vec = |p: json::Point| DVec2::from(p.0);
        Mesh::new(
            source,
            file.vertices.into_iter().map(to_vec).collect(),
            file.triangles.into_iter().map(|t| t.0).collect(),
            file.uv.map(|uv| uv.into_iter().map(to_vec).collect()),
            file.weights,
        )?
        .with_layers(source, file.layers)
    }

    /// The mesh with painted depth layers (one per triangle, at most
    /// [`MAX_LAYER`]), or none.
    pub fn with_layers(
        mut self,
        source: &str,
        layers: Option<Vec<u16>>,
    ) -> Result<Mesh, MeshError> {
        if let Some(layers) = &layers {
            if layers.len() != self.triangles.len() {
                return Err(invalid(
                    source,
                    "layers",
                    format!(
                        "has {} entries for {} triangles",
                        layers.len(),
                        self.triangles.len()
                    ),
                ));
            }
            if let Some(t) = layers.iter().position(|&l| l > MAX_LAYER) {
                return Err(invalid(
                    source,
                    format!("layers[{t}]"),
                    format!("{} is above the highest layer, {MAX_LAYER}", layers[t]),
                ));
            }
        }
        self.layers = layers;
        Ok(self)
    }

    /// The painted depth layers, one per triangle, if any.
    pub fn layers(&self) -> Option<&[u16]> {
        self.layers.as_deref()
    }

    /// Reads and validates a `.mesh.json` file.
    pub fn load(path: &Path) -> Result<Mesh, MeshError> {
        let name = path.display().to_string();
        let text = file::read_text(path, file::MESH_FILE)?;
        Mesh::from_json(&name, &text)
    }

    /// The `.mesh.json` text of this mesh. Weights are written only when some
    /// differ from the default of 1.
    pub fn to_json(&self) -> String {
        let file = MeshFile {
            vertices: self
                .vertices
                .iter()
                .map(|v| json::Point(v.to_array()))
                .collect(),
            triangles: self.triangles.iter().map(|&t| json::Triangle(t)).collect(),
            uv: self
                .uv
                .as_ref()
                .map(|uv| uv.iter().map(|v| json::Point(v.to_array())).collect()),
            weights: if self.weights.iter().all(|&w| w == 1.0) {
                None
            } else {
                Some(self.weights.clone())
            },
            layers: self.layers.clone(),
        };
        serde_json::to_string(&file).expect("a validated mesh serialises")
    }

    /// The rest positions, y-up, in the mesh's units (pixels for a mesh
    /// made from a picture). Never empty; every one is used by a triangle.
    pub fn vertices(&self) -> &[DVec2] {
        &self.vertices
    }
    /// Each triangle's three vertex indices, counter-clockwise in the y-up
    /// frame. Never empty.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// One texture coordinate per vertex into the source picture (image
    /// convention: v grows down from the top edge), or `None` when the mesh
    /// has no picture (made from a polygon, or a file without `uv`).
    pub fn uv(&self) -> Option<&[DVec2]> {
        self.uv.as_deref()
    }
    /// One rigidity weight per triangle, from [`MIN_WEIGHT`] to
    /// [`MAX_WEIGHT`]; larger is stiffer, and 1 where none was given.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Replaces the per-triangle rigidity weights (e.g. painted stiffness).
    pub fn set_weights(&mut self, weights: Vec<f64>) -> Result<(), MeshError> {
        let layers = self.layers.take();
        let checked = Mesh::new(
            "weights",
            std::mem::take(&mut self.vertices),
            std::mem::take(&mut self.triangles),
            self.uv.take(),
            Some(weights),
        );
        match checked {
            Ok(mut mesh) => {
                mesh.layers = layers;
                *self = mesh;
                Ok(())
            }
            Err(e) => Err(e),
        }
    }

    /// Length of the bounding box diagonal: the mesh's scale for tolerances.
    pub fn size(&self) -> f64 {
        bounding_diagonal(&self.vertices)
    }

    /// The connected pieces: for each, its vertices and its triangles, in
    /// increasing index order. Pieces are ordered by their lowest vertex.
    pub fn pieces(&self) -> Vec<Piece> {
        let n = self.vertices.len();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn find(parent: &mut [u32], mut i: u32) -> u32 {
            while parent[i as usize] != i {
                parent[i as usize] = parent[parent[i as usize] as usize];
                i = parent[i as usize];
            }
            i
        }
        for tri in &self.triangles {
            for k in 1..3 {
                let a = find(&mut parent, tri[0]);
                let b = find(&mut parent, tri[k]);
                if a != b {
                    parent[a.max(b) as usize] = a.min(b);
                }
            }
        }
        // Indexed by root vertex (a table, not a map: this runs on every
        // registration, 100k vertices and more).
        let mut piece_of_root = vec![u32::MAX; n];
        let mut pieces: Vec<Piece> = Vec::new();
        for v in 0..n as u32 {
            let root = find(&mut parent, v) as usize;
            if piece_of_root[root] == u32::MAX {
                piece_of_root[root] = pieces.len() as u32;
                pieces.push(Piece::default());
            }
            pieces[piece_of_root[root] as usize].vertices.push(v);
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            let root = find(&mut parent, tri[0]) as usize;
            pieces[piece_of_root[root] as usize]
                .triangles
                .push(t as u32);
        }
        pieces
    }

    /// The rest position of a barycentric point in a triangle.
    pub fn point_at(&self, triangle: u32, bary: [f64; 3]) -> DVec2 {
        let tri = self.triangles[triangle as usize];
        self.vertices[tri[0] as usize] * bary[0]
            + self.vertices[tri[1] as usize] * bary[1]
            + self.vertices[tri[2] as usize] * bary[2]
    }
}

/// One connected piece of a mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Piece {
    /// Indices of its vertices into the mesh's, in increasing order.
    pub vertices: Vec<u32>,
    /// Indices of its triangles into the mesh's, in increasing order.
    pub triangles: Vec<u32>,
}

fn bounding_diagonal(vertices: &[DVec2]) -> f64 {
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    for &v in vertices {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    (hi - lo).length()
}

/// Rejects what the deformers cannot treat as a surface: an edge used twice in
/// the same direction (overlap or mixed orientation), an edge shared by more
/// than two triangles, and "bowtie" vertices whose triangles touch only at the
/// vertex (their pieces would rotate freely about it).
fn check_manifold(file: &str, triangles: &[[u32; 3]], n: usize) -> Result<(), MeshError> {
    let mut directed: HashMap<(u32, u32), usize> = HashMap::with_capacity(triangles.len() * 3);
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            let edge = (tri[k], tri[(k + 1) % 3]);
            if let Some(other) = directed.insert(edge, t) {
                return Err(invalid(
                    file,
                    format!("triangles[{t}]"),
                    format!(
                        "edge {}-{} is also used in the same direction by triangles[{other}]: \
                         the triangles overlap",
                        edge.0, edge.1
                    ),
                ));
            }
        }
    }
    // Fan check: around each vertex, triangles must form one chain linked by
    // shared edges.
    let mut fans: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (t, tri) in triangles.iter().enumerate() {
        for &v in tri {
            fans[v as usize].push(t as u32);
        }
    }
    for (v, fan) in fans.iter().enumerate() {
        if fan.len() < 2 {
            continue;
        }
        let v = v as u32;
        // Each triangle in the fan has an outgoing edge v→a and incoming b→v.
        let mut reached = vec![false; fan.len()];
        let mut stack = vec![0usize];
        reached[0] = true;
        while let Some(i) = stack.pop() {
            let tri = triangles[fan[i] as usize];
            let k = tri.iter().position(|&x| x == v).unwrap();
            let next = tri[(k + 1) % 3];
            let prev = tri[(k + 2) % 3];
            for (j, &other) in fan.iter().enumerate() {
                if reached[j] {
                    continue;
                }
                let o = triangles[other as usize];
                if o.contains(&next) || o.contains(&prev) {
                    reached[j] = true;
                    stack.push(j);
                }
            }
        }
        if let Some(j) = reached.iter().position(|r| !r) {
            return Err(invalid(
                file,
                format!("vertices[{v}]"),
                format!(
                    "triangles[{}] and triangles[{}] meet only at this vertex (a bowtie); \
                     give each side its own copy of the vertex",
                    fan[0], fan[j]
                ),
            ));
        }
    }
    Ok(())
}

/// Finds which triangle holds a point: a uniform grid of triangle bounding
/// boxes, built once per rest mesh, so a touch resolves in constant time.
#[derive(Debug, Clone)]
pub struct Locator {
    grid: BucketGrid,
}

/// A point inside a mesh, as its triangle and barycentric coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Location {
    /// Index of the triangle holding the point.
    pub triangle: u32,
    /// The point's barycentric coordinates in that triangle, one per corner
    /// in the triangle's vertex order: each at least 0, summing to 1.
    pub bary: [f64; 3],
}

impl Locator {
    /// Buckets `mesh`'s triangles by bounding box into a grid of about one
    /// triangle per cell. [`Locator::locate`] must be given the same mesh.
    pub fn new(mesh: &Mesh) -> Locator {
        let verts = mesh.vertices();
        let mut lo = DVec2::splat(f64::INFINITY);
        let mut hi = DVec2::splat(f64::NEG_INFINITY);
        for &v in verts {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        let extent = (hi - lo).max(DVec2::splat(f64::MIN_POSITIVE));
        // About one triangle per cell.
        let target_cells = mesh.triangles().len().max(1) as f64;
        let cell = ((extent.x * extent.y) / target_cells)
            .sqrt()
            .max(extent.max_element() / 4096.0);
        let grid = BucketGrid::new(lo, hi, cell, mesh.triangles().len(), |shape, t, visit| {
            let ps = mesh.triangles()[t].map(|i| verts[i as usize]);
            shape.visit_box(
                ps[0].min(ps[1]).min(ps[2]),
                ps[0].max(ps[1]).max(ps[2]),
                visit,
            );
        });
        Locator { grid }
    }

    /// The triangle containing `p` (boundary included, with a tolerance of
    /// 1e-9 of the triangle's size) and `p`'s barycentric coordinates in it.
    pub fn locate(&self, mesh: &Mesh, p: DVec2) -> Option<Location> {
        if !p.is_finite() {
            return None;
        }
        let shape = self.grid.shape();
        let rel = (p - shape.lo) / shape.cell;
        let slack = 1e-9;
        if rel.x < -slack
            || rel.y < -slack
            || rel.x > shape.columns as f64 + slack
            || rel.y > shape.rows as f64 + slack
        {
            return None;
        }
        let cell = shape.row(p.y) * shape.columns + shape.column(p.x);
        let mut best: Option<(f64, Location)> = None;
        for &t in self.grid.members(cell) {
            let bary = barycentric(mesh, t, p);
            let worst = bary[0].min(bary[1]).min(bary[2]);
            if worst >= 0.0 {
                return Some(Location { triangle: t, bary });
            }
            if worst > -1e-9 && best.is_none_or(|(w, _)| worst > w) {
                best = Some((worst, Location { triangle: t, bary }));
            }
        }
        best.map(|(_, mut loc)| {
            // Project onto the triangle so the weights stay a convex blend.
            let clamped = loc.bary.map(|b| b.max(0.0));
            let sum: f64 = clamped.iter().sum();
            loc.bary = clamped.map(|b| b / sum);
            loc
        })
    }
}

/// Barycentric coordinates of `p` in a triangle. Exact (1, 0, 0) etc. when
/// `p` is exactly a corner, so a touch on a vertex is a vertex handle.
pub fn barycentric(mesh: &Mesh, triangle: u32, p: DVec2) -> [f64; 3] {
    let [a, b, c] = mesh.triangles()[triangle as usize].map(|i| mesh.vertices()[i as usize]);
    let d = (b - a).perp_dot(c - a);
    let l1 = (p - a).perp_dot(c - a) / d;
    let l2 = (b - a).perp_dot(p - a) / d;
    [1.0 - l1 - l2, l1, l2]
}
