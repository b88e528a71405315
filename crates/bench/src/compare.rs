//! `puppetry compare`: the lp-FFD paper's comparison (its §4.1, Table 1) on
//! one figure, one grid size and one manipulation. The same vertex handles
//! and targets drive four methods, and each result is scored by the mean
//! angular and area distortion of [`puppetry_deform::measure`]:
//!
//! 1. **direct FFD** (Hsu, Hughes & Kaufman 1992, with the paper's
//!    regulariser `E_gr`): the grid whose plain FFD pulls the handles to their
//!    targets, nothing else ([`LpFfd::direct_ffd`]);
//! 2. **ARAP + inverse FFD**: the ARAP mesh result, then the grid that fits
//!    it best in least squares ([`LpFfd::inverse_ffd`]), and the mesh that grid
//!    deforms to;
//! 3. **plain ARAP**: the two-step ARAP mesh result itself (our mesh
//!    deformer; the paper's is Sorkine–Alexa's, see docs/measures.md);
//! 4. **lp-FFD**, iterated to convergence.
//!
//! All three grid methods share one rig: the same grid box, basis and
//! weights (the paper's defaults). Plain synchronous code, no I/O.

use glam::DVec2;
use serde::Serialize;

use puppetry_deform::arap::{Anchor, Arap, ArapError, Steps};
use puppetry_deform::ffd::{Basis, FfdError, GridSpec, LpFfd, LpParams};
use puppetry_deform::measure::{MeasureError, mesh_distortion};
use puppetry_mesh::Mesh;

/// lp-FFD stops iterating when no vertex moved farther than this fraction
/// of the mesh size in one iteration, or after [`MAX_LP_ITERATIONS`].
const CONVERGED: f64 = 1e-10;
const MAX_LP_ITERATIONS: usize = 5000;

/// Why the comparison could not run. Each variant but the last names the
/// method that failed, as the table does ([`DIRECT_FFD`] and the rest).
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    /// The grid rig refused the mesh or the handles, or a grid method's
    /// solve failed.
    #[error("{method}: {source}")]
    Ffd {
        /// The method being run ([`LP_FFD`] too while registering the rig
        /// the three grid methods share).
        method: &'static str,
        /// What the rig said.
        source: FfdError,
    },
    /// The ARAP solver refused the mesh, the handles or the solve.
    #[error("{method}: {source}")]
    Arap {
        /// Always [`PLAIN_ARAP`] (method 2 starts from the same solve).
        method: &'static str,
        /// What the solver said.
        source: ArapError,
    },
    /// A method's pose could not be measured (not one finite point per
    /// vertex).
    #[error("{method}: measuring the result: {source}")]
    Measure {
        /// The method whose result it was.
        method: &'static str,
        /// What the measure said.
        source: MeasureError,
    },
    /// The handles and their targets differ in number.
    #[error("expected one target per handle: {anchors} handles, {targets} targets")]
    TargetCount {
        /// Handles given.
        anchors: usize,
        /// Targets given.
        targets: usize,
    },
}

/// One method's result.
#[derive(Debug, Clone, Serialize)]
pub struct MethodResult {
    /// Which method: [`DIRECT_FFD`], [`ARAP_INVERSE_FFD`], [`PLAIN_ARAP`]
    /// or [`LP_FFD`].
    pub method: &'static str,
    /// Mean over triangles of the mean absolute corner-angle change, radians.
    pub angular: f64,
    /// Mean over triangles of `|A'/A − 1|`.
    pub area: f64,
    /// Farthest any handle's point ended from its target, in mesh units.
    pub handle_error: f64,
    /// The deformed vertices, in mesh units (not in the JSON).
    #[serde(skip)]
    pub pose: Vec<DVec2>,
    /// The deformed grid's handles for the grid methods; `None` for plain
    /// ARAP (not in the JSON).
    #[serde(skip)]
    pub grid: Option<Vec<DVec2>>,
}

/// The whole comparison.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// Vertices of the mesh.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Separate pieces of the mesh (the bundled figure's layers).
    pub pieces: usize,
    /// Handles dragged, the same for every method.
    pub handles: usize,
    /// Grid handles along x.
    pub grid_columns: usize,
    /// Grid handles along y.
    pub grid_rows: usize,
    /// Local/global iterations lp-FFD took to converge (at most 5000).
    pub lp_ffd_iterations: usize,
    /// One result per method, in the paper's order: direct FFD, ARAP +
    /// inverse FFD, plain ARAP, lp-FFD.
    pub methods: Vec<MethodResult>,
}

/// Method 1's name in the table, the JSON and errors: direct FFD.
pub const DIRECT_FFD: &str = "direct FFD (Hsu et al.)";
/// Method 2's name: the ARAP result fitted by a grid.
pub const ARAP_INVERSE_FFD: &str = "ARAP + inverse FFD";
/// Method 3's name: the ARAP mesh result itself.
pub const PLAIN_ARAP: &str = "ARAP";
/// Method 4's name: lp-FFD iterated to convergence.
pub const LP_FFD: &str = "lp-FFD";

/// The point a handle holds, in `pose`.
fn handle_point(mesh: &Mesh, pose: &[DVec2], anchor: &Anchor) -> DVec2 {
    match *anchor {
        Anchor::Vertex(v) => pose[v as usize],
        Anchor::Point { triangle, bary } => {
            let t = mesh.triangles()[triangle as usize];
            pose[t[0] as usize] * bary[0]
                + pose[t[1] as usize] * bary[1]
                + pose[t[2] as usize] * bary[2]
        }
    }
}

fn score(
    method: &'static str,
    mesh: &Mesh,
    anchors: &[Anchor],
    targets: &[DVec2],
    pose: Vec<DVec2>,
    grid: Option<Vec<DVec2>>,
) -> Result<MethodResult, CompareError> {
    let distortion =
        mesh_distortion(mesh, &pose).map_err(|source| CompareError::Measure { method, source })?;
    let handle_error = anchors
        .iter()
        .zip(targets)
        .map(|(a, t)| handle_point(mesh, &pose, a).distance(*t))
        .fold(0.0, f64::max);
    Ok(MethodResult {
        method,
        angular: distortion.angular,
        area: distortion.area,
        handle_error,
        pose,
        grid,
    })
}

/// Runs the four methods on `mesh` with a `columns × rows` Bernstein grid
/// around it and the paper's weights.
pub fn compare(
    mesh: &Mesh,
    anchors: &[Anchor],
    targets: &[DVec2],
    columns: usize,
    rows: usize,
) -> Result<Comparison, CompareError> {
    if anchors.len() != targets.len() {
        return Err(CompareError::TargetCount {
            anchors: anchors.len(),
            targets: targets.len(),
        });
    }
    let spec = GridSpec::around(mesh, columns, rows, Basis::Bernstein);
    let params = LpParams {
        iterations: 1,
        ..LpParams::default()
    };
    let ffd = |method| move |source| CompareError::Ffd { method, source };
    let arap_err = |method| move |source| CompareError::Arap { method, source };
    let mut rig = LpFfd::register(mesh, spec, params).map_err(ffd(LP_FFD))?;

    let direct = rig
        .direct_ffd(anchors, targets, &[], &[])
        .map_err(ffd(DIRECT_FFD))?;
    let direct_pose = rig.deform_with_grid(&direct).map_err(ffd(DIRECT_FFD))?;

    let mut arap = Arap::register(mesh).map_err(arap_err(PLAIN_ARAP))?;
    arap.compile(anchors).map_err(arap_err(PLAIN_ARAP))?;
    let arap_pose = arap
        .update(targets, Steps::Both)
        .map_err(arap_err(PLAIN_ARAP))?
        .to_vec();
    let fitted = rig.inverse_ffd(&arap_pose).map_err(ffd(ARAP_INVERSE_FFD))?;
    let fitted_pose = rig
        .deform_with_grid(&fitted)
        .map_err(ffd(ARAP_INVERSE_FFD))?;

    rig.compile(anchors, &[]).map_err(ffd(LP_FFD))?;
    let tolerance = CONVERGED * mesh.size();
    let mut previous = rig.pose().to_vec();
    let mut iterations = 0;
    while iterations < MAX_LP_ITERATIONS {
        let pose = rig.update(targets, &[]).map_err(ffd(LP_FFD))?;
        iterations += 1;
        let step = pose
            .iter()
            .zip(&previous)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f64::max);
        previous.copy_from_slice(pose);
        if step <= tolerance {
            break;
        }
    }

    let methods = vec![
        score(
            DIRECT_FFD,
            mesh,
            anchors,
            targets,
            direct_pose,
            Some(direct),
        )?,
        score(
            ARAP_INVERSE_FFD,
            mesh,
            anchors,
            targets,
            fitted_pose,
            Some(fitted),
        )?,
        score(PLAIN_ARAP, mesh, anchors, targets, arap_pose, None)?,
        score(
            LP_FFD,
            mesh,
            anchors,
            targets,
            previous,
            Some(rig.grid().to_vec()),
        )?,
    ];
    Ok(Comparison {
        vertices: mesh.vertices().len(),
        triangles: mesh.triangles().len(),
        pieces: mesh.pieces().len(),
        handles: anchors.len(),
        grid_columns: columns,
        grid_rows: rows,
        lp_ffd_iterations: iterations,
        methods,
    })
}

/// The comparison as a table: a heading line, then one row per method.
pub fn table(c: &Comparison) -> String {
    let mut out = format!(
        "{} vertices, {} triangles, {} pieces, {} handles, {}×{} grid (lp-FFD: {} iterations)\n",
        c.vertices,
        c.triangles,
        c.pieces,
        c.handles,
        c.grid_columns,
        c.grid_rows,
        c.lp_ffd_iterations
    );
    out.push_str(&format!(
        "{:<24} {:>9} {:>9} {:>13}\n",
        "method", "angular", "area", "handle error"
    ));
    for m in &c.methods {
        out.push_str(&format!(
            "{:<24} {:>9.5} {:>9.5} {:>13.3}\n",
            m.method, m.angular, m.area, m.handle_error
        ));
    }
    out
}
