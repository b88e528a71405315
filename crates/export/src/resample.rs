//! From recorded frames to a fixed frame rate, by sample and hold: frame k
//! of the export shows the newest recorded frame at or before
//! `from + k / fps` — exactly what a viewer saw at that moment, with no
//! interpolated poses the solver never produced.
//!
//! The frames are the instants `from + k / fps` for `k = 0, 1, …` that lie
//! before `to` (so `from = 0, to = 1, fps = 30` gives 30 frames, the last at
//! 29/30 s); see [`frame_count`].

use crate::{ExportError, check_fps, flag, invalid};

/// How many frames `from..to` has at `fps`: the instants `from + k / fps`
/// before `to` (at least one). Checks the three values, naming the flags
/// `--from`, `--to` and `--fps`.
pub fn frame_count(fps: f64, from: f64, to: f64) -> Result<usize, ExportError> {
    check_fps(fps, "--fps")?;
    if !from.is_finite() {
        return Err(flag("--from", format!("must be a finite time, got {from}")));
    }
    if !to.is_finite() {
        return Err(flag("--to", format!("must be a finite time, got {to}")));
    }
    if from >= to {
        return Err(flag(
            "--to",
            format!("must be after --from ({from} s), got {to} s"),
        ));
    }
    let frames = ((to - from) * fps * (1.0 - 1e-12)).ceil().max(1.0);
    if frames > 100_000_000.0 {
        return Err(flag(
            "--to",
            format!("{} s at {fps} fps is too many frames", to - from),
        ));
    }
    Ok(frames as usize)
}

/// For each frame k (see [`frame_count`]), the index into `times` of the
/// newest recorded frame at or before `from + k / fps`, or `None` while
/// nothing had been recorded yet. `times` (seconds, any origin shared with
/// `from` and `to`) must be finite and non-decreasing; of recorded frames
/// with equal times the last one wins.
pub fn sample_and_hold(
    times: &[f64],
    fps: f64,
    from: f64,
    to: f64,
) -> Result<Vec<Option<usize>>, ExportError> {
    let n = frame_count(fps, from, to)?;
    for (i, t) in times.iter().enumerate() {
        if !t.is_finite() {
            return Err(invalid(format!("times[{i}]"), "is not a finite time"));
        }
        if i > 0 && *t < times[i - 1] {
            return Err(invalid(
                format!("times[{i}]"),
                format!("{t} s is before times[{}] = {} s", i - 1, times[i - 1]),
            ));
        }
    }
    let mut next = 0; // first recorded frame after the current instant
    Ok((0..n)
        .map(|k| {
            let t = from + k as f64 / fps;
            while next < times.len() && times[next] <= t {
                next += 1;
            }
            next.checked_sub(1)
        })
        .collect())
}

/// Resamples recorded frames (`frames[i]` recorded at `times[i]`) to
/// `fps` over `from..to` by sample and hold ([`sample_and_hold`]); frames
/// before the first recording show `initial` (typically the rest pose).
pub fn resample<T: Clone>(
    times: &[f64],
    frames: &[T],
    initial: &T,
    fps: f64,
    from: f64,
    to: f64,
) -> Result<Vec<T>, ExportError> {
    if times.len() != frames.len() {
        return Err(invalid(
            "frames",
            format!(
                "has {} entries but times has {}: one time per frame",
                frames.len(),
                times.len()
            ),
        ));
    }
    Ok(sample_and_hold(times, fps, from, to)?
        .into_iter()
        .map(|i| i.map_or_else(|| initial.clone(), |i| frames[i].clone()))
        .collect())
}
