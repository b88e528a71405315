//! A PNG sequence: `frame_00000.png`, `frame_00001.png`, … in a folder, one
//! picture per frame, drawn by [`crate::raster`] (which matches the web
//! renderer: placement, bilinear texture, premultiplied blending, 4-sample
//! antialiasing) on a transparent background, saved as straight-alpha RGBA.
//!
//! Frames are drawn and compressed on every core; PNGs use the png crate's
//! `Compression::Fast` (fdeflate with adaptive row filters), which keeps a
//! 1280×720 frame of one puppet at a few milliseconds.

use std::path::Path;

use crate::raster::{check_size, render_frames};
use crate::{Animation, ExportError, Progress, io_error};

/// Options of a PNG sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct PngOptions {
    /// Picture width in pixels (`--size WxH`); the stage is fitted inside,
    /// centred.
    pub width: u32,
    /// Picture height in pixels.
    pub height: u32,
}

/// The file name of frame `k`: `frame_00042.png` (more digits past 99999).
pub fn frame_name(k: usize) -> String {
    format!("frame_{k:05}.png")
}

/// Writes every frame of `animation` into `dir` (created if missing) as
/// [`frame_name`] files. `progress` counts frames.
pub fn export_png_sequence(
    animation: &Animation,
    options: &PngOptions,
    progress: &mut dyn Progress,
    dir: &Path,
) -> Result<(), ExportError> {
    animation.validate()?;
    check_size(options.width, options.height)?;
    std::fs::create_dir_all(dir).map_err(io_error(dir))?;
    let (w, h) = (options.width, options.height);
    let total = animation.frame_count;
    render_frames(
        animation,
        w,
        h,
        |k, pixels| write_frame(&dir.join(frame_name(k)), w, h, pixels),
        |k, ()| {
            progress.step(k + 1, total);
            Ok(())
        },
    )
}

/// One frame's PNG, made new ([`crate::write_new`]): encoded in memory,
/// written under a fresh name in the folder and renamed onto its own, so a
/// link planted at a frame's name is replaced, never followed.
fn write_frame(path: &Path, w: u32, h: u32, pixels: &[u8]) -> Result<(), ExportError> {
    let mut bytes = Vec::with_capacity(pixels.len() / 8);
    crate::write_png(&mut bytes, w, h, pixels).map_err(|e| ExportError::File {
        file: path.display().to_string(),
        problem: format!("cannot encode PNG: {e}"),
    })?;
    crate::write_new(path, |out| out.write_all(&bytes).map_err(io_error(path)))
}
