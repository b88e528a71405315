//! The contact model every input source produces and the stage consumes:
//! [`ContactFrame`]s of [`Contact`]s (a [`Phase`] at a stage point) from a
//! [`SourceId`], and the [`Calibration`] that takes a device's coordinates
//! to the stage's. Plain data with no I/O, so the stage, takes and exports
//! share it without building a device driver or an async runtime; the
//! decoders and device loops that make frames live in `puppetry-input`.
//! Every public item is documented (`missing_docs` is on here).

use std::fmt;
use std::sync::Arc;

use glam::DVec2;
use serde::{Deserialize, Serialize};

/// What happened to a contact in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// The contact landed; its id is new within its source.
    Down,
    /// The contact is still down and something about it changed.
    Move,
    /// The contact lifted; the id may be reused afterwards.
    Up,
}

/// One touch point as the stage sees it. Serialised (takes record the
/// frames the stage applied) with positions as `[x, y]` and absent extras
/// left out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Contact {
    /// Identifies the contact within its source from its `Down` to its `Up`.
    pub id: u32,
    /// What happened to it in this frame.
    pub phase: Phase,
    /// Stage coordinates (y-up). An `Up` carries the last known position.
    pub position: DVec2,
    /// Normalised to 0..=1 over the device's declared range.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pressure: Option<f64>,
    /// How far a pen leans, in radians from upright, as a stage-space vector:
    /// `x` leans towards +x, `y` towards +y.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt: Option<DVec2>,
    /// Direction of the contact's major axis in stage space, radians
    /// counter-clockwise from +x, folded into (-π/2, π/2] because an
    /// ellipse's axis has no head or tail.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle: Option<f64>,
}

impl Contact {
    /// A contact with only a position.
    pub fn new(id: u32, phase: Phase, position: DVec2) -> Contact {
        Contact {
            id,
            phase,
            position,
            pressure: None,
            tilt: None,
            angle: None,
        }
    }
}

/// Names an input source: `evdev0`, `client:3`, `replay`. Cheap to clone
/// because every frame carries one.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(transparent)]
pub struct SourceId(Arc<str>);

impl SourceId {
    /// A source called `name`.
    pub fn new(name: impl AsRef<str>) -> SourceId {
        SourceId(Arc::from(name.as_ref()))
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for SourceId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl From<&str> for SourceId {
    fn from(name: &str) -> SourceId {
        SourceId::new(name)
    }
}

impl From<String> for SourceId {
    fn from(name: String) -> SourceId {
        SourceId(Arc::from(name))
    }
}

impl AsRef<str> for SourceId {
    fn as_ref(&self) -> &str {
        &self.0
    }
}

/// Every contact of one source that changed in one device report. A contact
/// appears at most once per frame; contacts that did not change are absent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactFrame {
    /// The source all its contacts come from.
    pub source: SourceId,
    /// Seconds, on the source's own clock (kernel time for devices, file
    /// time for replays); only differences between frames of one source mean
    /// anything.
    pub time: f64,
    /// The contacts that changed.
    pub contacts: Vec<Contact>,
}

/// A calibration that cannot map a device onto the stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// A field of the calibration, and what is wrong with it.
    #[error("calibration: {field}: {problem}")]
    Invalid {
        /// The field's name in the stage file (`x`, `corners`, …).
        field: &'static str,
        /// Why it cannot be used.
        problem: String,
    },
}

fn invalid(field: &'static str, problem: impl Into<String>) -> CalibrationError {
    CalibrationError::Invalid {
        field,
        problem: problem.into(),
    }
}

/// How device coordinates become stage coordinates, as written in a stage
/// file. `stage_min`/`stage_max` are the stage rectangle's lower-left and
/// upper-right corners (y-up).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum CalibrationSpec {
    /// Device axis ranges stretched onto the stage rectangle. Either range
    /// may be given high-to-low to mirror that axis.
    Range {
        /// Device x that lands on the stage's left and right edges.
        x: [f64; 2],
        /// Device y that lands on the stage's top and bottom edges when
        /// `flip_y` (devices count y downwards), bottom and top otherwise.
        y: [f64; 2],
        /// The device counts y downwards (the default), as screens do.
        #[serde(default = "yes")]
        flip_y: bool,
        /// The stage rectangle's lower-left corner.
        stage_min: [f64; 2],
        /// The stage rectangle's upper-right corner.
        stage_max: [f64; 2],
    },
    /// Where the stage's corners are on the device, in the order the
    /// performer sees them: top-left, top-right, bottom-right, bottom-left.
    /// Fixes a surface that sits skewed or in perspective under a projection.
    Corners {
        /// Device points of the stage's corners, in that order.
        corners: [[f64; 2]; 4],
        /// The stage rectangle's lower-left corner.
        stage_min: [f64; 2],
        /// The stage rectangle's upper-right corner.
        stage_max: [f64; 2],
    },
}

fn yes() -> bool {
    true
}

/// A checked [`CalibrationSpec`] with its projective map worked out. Both
/// kinds are one 3×3 matrix: the range fit is its affine special case.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "CalibrationSpec", into = "CalibrationSpec")]
pub struct Calibration {
    spec: CalibrationSpec,
    /// Row-major; device (x, y, 1) ↦ stage (X·w, Y·w, w).
    matrix: [[f64; 3]; 3],
    /// Below this `w` a device point is at or beyond the map's horizon;
    /// clamping keeps such points finite (far away) instead of infinite.
    min_w: f64,
}

impl Calibration {
    /// Checks `spec` and works out its map, or says which field is wrong.
    pub fn new(spec: CalibrationSpec) -> Result<Calibration, CalibrationError> {
        let (matrix, centre) = match &spec {
            CalibrationSpec::Range {
                x,
                y,
                flip_y,
                stage_min,
                stage_max,
            } => {
                let (lo, hi) = stage_rect(*stage_min, *stage_max)?;
                for (field, range) in [("x", x), ("y", y)] {
                    if !range.iter().all(|v| v.is_finite()) {
                        return Err(invalid(field, "the range must be finite numbers"));
                    }
                    if range[0] == range[1] {
                        return Err(invalid(
                            field,
                            format!("the range [{}, {}] is empty", range[0], range[1]),
                        ));
                    }
                }
                let sx = (hi.x - lo.x) / (x[1] - x[0]);
                let sy = (hi.y - lo.y) / (y[1] - y[0]);
                let (sy, ty) = if *flip_y {
                    (-sy, hi.y + y[0] * sy)
                } else {
                    (sy, lo.y - y[0] * sy)
                };
                let matrix = [[sx, 0.0, lo.x - x[0] * sx], [0.0, sy, ty], [0.0, 0.0, 1.0]];
                let centre = DVec2::new(x[0] + x[1], y[0] + y[1]) / 2.0;
                (matrix, centre)
            }
            CalibrationSpec::Corners {
                corners,
                stage_min,
                stage_max,
            } => {
                let (lo, hi) = stage_rect(*stage_min, *stage_max)?;
                let device = corners.map(|[x, y]| DVec2::new(x, y));
                check_quad(&device)?;
                let stage = [DVec2::new(lo.x, hi.y), hi, DVec2::new(hi.x, lo.y), lo];
                // Through the unit square: square → stage after device → square.
                let to_device = square_to_quad(&device)
                    .ok_or_else(|| invalid("corners", "the four points are degenerate"))?;
                let to_stage = square_to_quad(&stage)
                    .ok_or_else(|| invalid("stage_min", "the stage rectangle is degenerate"))?;
                let matrix = mul(&to_stage, &adjugate(&to_device));
                let centre = device.iter().sum::<DVec2>() / 4.0;
                (matrix, centre)
            }
        };
        // Scale so that w is +1 at the centre of the calibrated area: then the
        // whole convex area has w > 0 and the horizon lies outside it.
        let w = matrix[2][0] * centre.x + matrix[2][1] * centre.y + matrix[2][2];
        if !w.is_finite() || w == 0.0 {
            return Err(invalid("corners", "the four points are degenerate"));
        }
        let matrix = matrix.map(|row| row.map(|v| v / w));
        if matrix.iter().flatten().any(|v| !v.is_finite()) {
            return Err(invalid("corners", "the map is not finite"));
        }
        Ok(Calibration {
            spec,
            matrix,
            min_w: 1e-6,
        })
    }

    /// Fits a device's full axis ranges to a `size.x` × `size.y` stage with
    /// its origin at the lower left, flipping y: what a stage gets when its
    /// file says nothing about calibration.
    pub fn fit(x: [f64; 2], y: [f64; 2], size: DVec2) -> Result<Calibration, CalibrationError> {
        Calibration::new(CalibrationSpec::Range {
            x,
            y,
            flip_y: true,
            stage_min: [0.0, 0.0],
            stage_max: [size.x, size.y],
        })
    }

    /// The calibration as the stage file gave it.
    pub fn spec(&self) -> &CalibrationSpec {
        &self.spec
    }

    fn w(&self, p: DVec2) -> f64 {
        let m = &self.matrix;
        (m[2][0] * p.x + m[2][1] * p.y + m[2][2]).max(self.min_w)
    }

    /// Stage position of a device point.
    pub fn map(&self, device: DVec2) -> DVec2 {
        let m = &self.matrix;
        let w = self.w(device);
        DVec2::new(
            (m[0][0] * device.x + m[0][1] * device.y + m[0][2]) / w,
            (m[1][0] * device.x + m[1][1] * device.y + m[1][2]) / w,
        )
    }

    /// A small device-space displacement `d` at `at`, carried to stage space
    /// (the map's Jacobian): how orientations and tilts follow the surface.
    pub fn map_direction(&self, at: DVec2, d: DVec2) -> DVec2 {
        let m = &self.matrix;
        let w = self.w(at);
        let p = self.map(at);
        let column =
            |c: usize| DVec2::new((m[0][c] - p.x * m[2][c]) / w, (m[1][c] - p.y * m[2][c]) / w);
        column(0) * d.x + column(1) * d.y
    }
}

impl TryFrom<CalibrationSpec> for Calibration {
    type Error = CalibrationError;

    fn try_from(spec: CalibrationSpec) -> Result<Calibration, CalibrationError> {
        Calibration::new(spec)
    }
}

impl From<Calibration> for CalibrationSpec {
    fn from(calibration: Calibration) -> CalibrationSpec {
        calibration.spec
    }
}

fn stage_rect(min: [f64; 2], max: [f64; 2]) -> Result<(DVec2, DVec2), CalibrationError> {
    let (lo, hi) = (DVec2::from(min), DVec2::from(max));
    if !lo.is_finite() || !hi.is_finite() {
        return Err(invalid("stage_min", "the stage rectangle must be finite"));
    }
    if hi.x <= lo.x || hi.y <= lo.y {
        return Err(invalid(
            "stage_max",
            format!("stage_max {hi} must be above and right of stage_min {lo}"),
        ));
    }
    Ok((lo, hi))
}

/// A homography from a quadrilateral is only one-to-one over it when the
/// quadrilateral is convex; a bow-tie or a sliver means mis-tapped corners.
fn check_quad(p: &[DVec2; 4]) -> Result<(), CalibrationError> {
    if !p.iter().all(|v| v.is_finite()) {
        return Err(invalid("corners", "the corners must be finite numbers"));
    }
    let scale = (0..4)
        .map(|i| (p[(i + 1) % 4] - p[i]).length_squared())
        .fold(0.0, f64::max);
    let turns: Vec<f64> = (0..4)
        .map(|i| (p[(i + 1) % 4] - p[i]).perp_dot(p[(i + 2) % 4] - p[(i + 1) % 4]))
        .collect();
    let convex =
        turns.iter().all(|&t| t > 1e-9 * scale) || turns.iter().all(|&t| t < -1e-9 * scale);
    if scale == 0.0 || !convex {
        return Err(invalid(
            "corners",
            "the four points must form a convex quadrilateral, in order top-left, \
             top-right, bottom-right, bottom-left",
        ));
    }
    Ok(())
}

/// The projective map taking the unit square's corners (0,0), (1,0), (1,1),
/// (0,1) to `p[0..4]` (Heckbert's closed form), or `None` when degenerate.
fn square_to_quad(p: &[DVec2; 4]) -> Option<[[f64; 3]; 3]> {
    let s = p[0] - p[1] + p[2] - p[3];
    let d1 = p[1] - p[2];
    let d2 = p[3] - p[2];
    let den = d1.perp_dot(d2);
    if den == 0.0 {
        return None;
    }
    let g = s.perp_dot(d2) / den;
    let h = d1.perp_dot(s) / den;
    Some([
        [
            p[1].x - p[0].x + g * p[1].x,
            p[3].x - p[0].x + h * p[3].x,
            p[0].x,
        ],
        [
            p[1].y - p[0].y + g * p[1].y,
            p[3].y - p[0].y + h * p[3].y,
            p[0].y,
        ],
        [g, h, 1.0],
    ])
}

/// The inverse up to scale, which is all a projective map needs.
fn adjugate(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let c =
        |r0: usize, r1: usize, c0: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    [
        [c(1, 2, 1, 2), -c(0, 2, 1, 2), c(0, 1, 1, 2)],
        [-c(1, 2, 0, 2), c(0, 2, 0, 2), -c(0, 1, 0, 2)],
        [c(1, 2, 0, 1), -c(0, 2, 0, 1), c(0, 1, 0, 1)],
    ]
}

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[r][k] * b[k][c]).sum();
        }
    }
    out
}
