//! What an export of a take would cost, known before it is made: its
//! frames (the range times the frame rate), the motion it holds in memory
//! (every frame of every puppet's vertices) and the size of the file it
//! writes, computed from the take's header (its puppets' vertex counts)
//! and its length — the take is read through once for that, record by
//! record, in bounded memory — and checked against the limits of
//! `puppetry_limits::exports`. An export past one is refused here, naming
//! the amount and the limit, before a frame is kept: a 20-minute take
//! asked for at 1000 fps was 14.7 GB in the daemon before.
//!
//! The range and its defaults are the exporter's own (`take.rs`): from the
//! start, to the take's last instant included. A `to` past the take's end
//! is counted only to the end (the exporter refuses it, naming `--to`).

use puppetry_limits::exports::{MAX_EXPORT_FILE_BYTES, MAX_EXPORT_FRAMES, MAX_EXPORT_MOTION_BYTES};
use puppetry_take::{TakeError, TakeReader};

use crate::ExportError;
use crate::format::Format;
use crate::take::ExportRequest;

/// Why an export's cost could not be known or is past a limit.
#[derive(Debug, thiserror::Error)]
pub enum BudgetError {
    /// The take cannot be read.
    #[error(transparent)]
    Take(#[from] TakeError),
    /// A bad frame rate or range, naming its flag.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// The export would pass a limit.
    #[error(
        "{take}: {what} at {fps} fps would be {amount}, past the limit of {limit}; export a shorter range (from/to) or at a lower frame rate"
    )]
    TooLarge {
        /// The take's file name (no folder: the daemon sends this to pages).
        take: String,
        /// What is counted: "{n} frames", "the motion of {n} frames × {v}
        /// vertices", "the .glb file".
        what: String,
        /// The frame rate asked for.
        fps: f64,
        /// How much that would be, with its unit.
        amount: String,
        /// The limit it passes, with its unit.
        limit: String,
    },
}

/// What an export would cost.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Frames exported.
    pub frames: u64,
    /// Vertices of every puppet on the stage (all are resampled).
    pub vertices: u64,
    /// Bytes of motion held while exporting.
    pub motion_bytes: u64,
    /// Bytes of the file written, for the formats whose size follows from
    /// the frames (glb, spine); none for videos and PNG sequences.
    pub file_bytes: Option<u64>,
}

/// Per frame and puppet, besides its vertices: the frame's vector and its
/// drawing order's handle.
const MOTION_PER_PUPPET_FRAME: u64 = 48;
/// glTF binary, per vertex and frame: one morph target's x, y, z.
const GLB_PER_VERTEX: u64 = 12;
/// glTF binary, per puppet and frame: its weights (one key of a chunk's
/// 32), its time, and its share of the accessors and names in the JSON.
const GLB_PER_PUPPET_FRAME: u64 = 512;
/// Spine JSON, per vertex and frame: two offsets as text, at most 13
/// characters and a comma each.
const SPINE_PER_VERTEX: u64 = 28;
/// Spine JSON, per puppet and frame: a key's time, offset and brackets.
const SPINE_PER_PUPPET_FRAME: u64 = 64;

/// The cost of `request`: its take as its format at its `fps` over
/// `from..to` (seconds; none: the take's start and end).
pub fn estimate(request: &ExportRequest) -> Result<Estimate, BudgetError> {
    let ExportRequest {
        take,
        format,
        fps,
        from,
        to,
        ..
    } = request;
    let (format, fps) = (*format, *fps);
    let reader = TakeReader::open(take)?;
    let puppets = reader.header.puppets.len() as u64;
    let vertices: u64 = reader
        .header
        .puppets
        .iter()
        .map(|p| p.vertices as u64)
        .sum();
    drop(reader);
    // The take's length: its last intact step, frame or end (damage is
    // the exporter's to refuse or salvage).
    let end = crate::take::survey(take)?.duration;
    crate::check_fps(fps, "--fps")?;
    let from = from.unwrap_or(0.0);
    let last = end + 1.0 / fps;
    let to = match to {
        Some(to) => to.min(last),
        None if end > from => end + 1e-6,
        None => from + 1.0 / fps,
    };
    let frames = if from >= last {
        1
    } else {
        crate::resample::frame_count(fps, from, to)? as u64
    };
    let motion_bytes = frames.saturating_mul(
        vertices
            .saturating_mul(8)
            .saturating_add(puppets * MOTION_PER_PUPPET_FRAME),
    );
    let per_frame = |per_vertex: u64, per_puppet: u64| {
        frames.saturating_mul(
            vertices
                .saturating_mul(per_vertex)
                .saturating_add(puppets * per_puppet),
        )
    };
    // Videos and PNG frames are compressed: their size does not follow.
    let file_bytes = match format {
        Format::Glb => Some(per_frame(GLB_PER_VERTEX, GLB_PER_PUPPET_FRAME)),
        Format::Spine => Some(per_frame(SPINE_PER_VERTEX, SPINE_PER_PUPPET_FRAME)),
        Format::Png | Format::Mp4 | Format::Mov | Format::Webm => None,
    };
    Ok(Estimate {
        frames,
        vertices,
        motion_bytes,
        file_bytes,
    })
}

/// [`estimate`], refused past a limit of `puppetry_limits::exports`.
pub fn check(request: &ExportRequest) -> Result<Estimate, BudgetError> {
    let e = estimate(request)?;
    let too_large = |what: String, amount: String, limit: String| BudgetError::TooLarge {
        take: request
            .take
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        what,
        fps: request.fps,
        amount,
        limit,
    };
    if e.motion_bytes > MAX_EXPORT_MOTION_BYTES {
        return Err(too_large(
            format!(
                "the motion of {} frames × {} vertices",
                e.frames, e.vertices
            ),
            megabytes(e.motion_bytes),
            megabytes(MAX_EXPORT_MOTION_BYTES),
        ));
    }
    if let Some(bytes) = e.file_bytes
        && bytes > MAX_EXPORT_FILE_BYTES
    {
        return Err(too_large(
            format!("the {} file of {} frames", request.format, e.frames),
            megabytes(bytes),
            megabytes(MAX_EXPORT_FILE_BYTES),
        ));
    }
    if e.frames > MAX_EXPORT_FRAMES {
        return Err(too_large(
            "the frames".into(),
            format!("{} frames", e.frames),
            format!("{MAX_EXPORT_FRAMES} frames"),
        ));
    }
    Ok(e)
}

/// Bytes as megabytes (10⁶), one decimal.
fn megabytes(bytes: u64) -> String {
    format!("{:.1} MB", bytes as f64 / 1e6)
}
