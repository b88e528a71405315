//! Calibrating a touch surface from four taps: the performer touches four
//! marks the web client draws at known stage points (`?calibrate` on the
//! page) while `puppetry record` captures the device; this turns the
//! capture's first four touch-downs into a `corners` calibration for the
//! stage file. Positions are read raw (device units), through the same
//! decoder the daemon uses, so protocol A, B and single-touch all work.

use std::path::Path;

use glam::DVec2;

use super::evemu::{EvemuError, EvemuFile};
use super::{Calibration, CalibrationSpec, Phase};

/// Why [`from_capture`] made no calibration; each message says what to do
/// differently.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    /// The capture cannot be read or parsed, or its device has no position
    /// axes to decode touches from.
    #[error(transparent)]
    Capture(#[from] EvemuError),
    /// The capture holds fewer than four touch-downs: the performer missed
    /// marks, or the recording stopped early.
    #[error("{file}: {found} touch(es) found; touch the four marks, one at a time")]
    TooFewTouches {
        /// The capture, as messages name it.
        file: String,
        /// How many touch-downs it holds.
        found: usize,
    },
    /// The `inset` (the `--inset` option) is outside 0..=0.45, so the marks
    /// would not be four distinct points inside the stage.
    #[error("--inset: {0} is not between 0 and 0.45")]
    Inset(f64),
    /// The first four touches give a calibration that would not load: three
    /// taps in a line, or corners out of order.
    #[error("{file}: the four touches do not make a usable calibration: {problem}")]
    Degenerate {
        /// The capture, as messages name it.
        file: String,
        /// What the calibration check refused.
        problem: String,
    },
}

/// The stage points of the four marks, in the order they are touched:
/// top-left, top-right, bottom-right, bottom-left, `inset` of the stage's
/// size in from its edges (y-up).
pub fn marks(stage_size: DVec2, inset: f64) -> [DVec2; 4] {
    let lo = stage_size * inset;
    let hi = stage_size * (1.0 - inset);
    [
        DVec2::new(lo.x, hi.y),
        DVec2::new(hi.x, hi.y),
        DVec2::new(hi.x, lo.y),
        DVec2::new(lo.x, lo.y),
    ]
}

/// The calibration that takes the capture's first four touch-downs to the
/// four marks of a `stage_size` stage.
pub fn from_capture(
    path: &Path,
    stage_size: DVec2,
    inset: f64,
) -> Result<CalibrationSpec, CalibrateError> {
    if !(0.0..=0.45).contains(&inset) {
        return Err(CalibrateError::Inset(inset));
    }
    let capture = EvemuFile::read(path)?;
    let file = capture.file.clone();
    // Device units straight through: an identity range map.
    let (x, y) = position_ranges(&capture);
    let raw = Calibration::new(CalibrationSpec::Range {
        x,
        y,
        flip_y: false,
        stage_min: [x[0], y[0]],
        stage_max: [x[1], y[1]],
    })
    .map_err(|e| CalibrateError::Degenerate {
        file: file.clone(),
        problem: e.to_string(),
    })?;
    let mut decoder = capture.decoder("calibrate".into(), raw)?;
    let mut downs = Vec::new();
    for event in &capture.events {
        if let Some(frame) = decoder.push(*event) {
            downs.extend(
                frame
                    .contacts
                    .iter()
                    .filter(|c| c.phase == Phase::Down)
                    .map(|c| c.position),
            );
        }
    }
    if downs.len() < 4 {
        return Err(CalibrateError::TooFewTouches {
            file,
            found: downs.len(),
        });
    }
    let [_, top_right, _, bottom_left] = marks(stage_size, inset);
    let spec = CalibrationSpec::Corners {
        corners: [0, 1, 2, 3].map(|i| downs[i].to_array()),
        stage_min: bottom_left.to_array(),
        stage_max: top_right.to_array(),
    };
    // Refuse what would not load (three taps in a line, say).
    Calibration::new(spec.clone()).map_err(|e| CalibrateError::Degenerate {
        file,
        problem: e.to_string(),
    })?;
    Ok(spec)
}

fn position_ranges(capture: &EvemuFile) -> ([f64; 2], [f64; 2]) {
    use super::evdev::{ABS_MT_POSITION_X, ABS_MT_POSITION_Y, ABS_X, ABS_Y};
    let axes = &capture.device.axes;
    let range = |mt, single| {
        axes.get(&mt)
            .or_else(|| axes.get(&single))
            .map_or([0.0, 1.0], |a| {
                [f64::from(a.min), f64::from(a.max.max(a.min + 1))]
            })
    };
    (
        range(ABS_MT_POSITION_X, ABS_X),
        range(ABS_MT_POSITION_Y, ABS_Y),
    )
}

/// The stage-file line for a calibration.
pub fn toml_line(spec: &CalibrationSpec) -> String {
    let value = toml::Value::try_from(spec).expect("a calibration is plain data");
    let mut line = String::from("calibration = { ");
    if let toml::Value::Table(table) = value {
        let parts: Vec<String> = ["kind", "corners", "stage_min", "stage_max"]
            .iter()
            .filter_map(|k| table.get(*k).map(|v| format!("{k} = {v}")))
            .collect();
        line.push_str(&parts.join(", "));
    }
    line.push_str(" }");
    line
}
