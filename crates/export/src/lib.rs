//! Exports of a recorded performance. The input is an [`Animation`]: a
//! stage, its puppets (mesh, texture coordinates, picture) and, per puppet,
//! the deformed vertices of every frame, already resampled to a fixed frame
//! rate ([`resample`] turns irregular recorded frames into that). From it:
//!
//! - [`gltf`]: a glTF 2.0 binary (`.glb`), textured meshes animated by
//!   morph targets in chunks;
//! - [`frames`]: a PNG sequence drawn by our own software rasteriser
//!   ([`raster`]), which matches the web renderer;
//! - [`video`]: the same frames piped into `ffmpeg` (`.mp4`, `.mov` ProRes
//!   4444 with alpha, `.webm` VP9 with alpha);
//! - [`spine`]: Spine 4.2 JSON, a mesh attachment per puppet and a deform
//!   timeline;
//! - [`take`]: a recorded take, read and resampled into an [`Animation`]
//!   and exported in any of the above.
//!
//! Plain synchronous code: every exporter is a function taking the
//! animation, its options and a [`Progress`], and writing a file (or a
//! `Write`). Every bad input is refused with an [`ExportError`] naming the
//! file, field or command-line flag.
//!
//! Files are made new ([`write_new`]): written under a fresh random name
//! beside where they go, created exclusively (so a link planted there is
//! never followed), and renamed into place when whole. [`budget`] says
//! what an export of a take would cost before anything is read.

pub mod budget;
mod drawing;
pub mod folds;
pub mod format;
pub mod frames;
pub mod gltf;
pub mod output;
pub mod raster;
pub mod resample;
pub mod skin;
pub mod spine;
pub mod take;
pub mod video;

use std::io::{BufWriter, Write};
use std::path::Path;

/// An error of an export: which file, field or flag, and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// Reading or writing a file failed.
    #[error("{file}: {source}")]
    Io {
        /// The file (or folder) read or written.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// A file's content or name is unusable (not a PNG, unknown extension),
    /// or a tool working on it failed.
    #[error("{file}: {problem}")]
    File {
        /// The file.
        file: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A field of the [`Animation`] is inconsistent, e.g.
    /// `puppets[0] "gingerbread".frames[3]`.
    #[error("{field}: {problem}")]
    Invalid {
        /// The field's path in the animation.
        field: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A command-line value is out of range: `--fps`, `--from`, `--to`,
    /// `--size`, `--chunk`.
    #[error("{flag}: {problem}")]
    Flag {
        /// The flag, as `--size`.
        flag: String,
        /// What is wrong with its value.
        problem: String,
    },
    /// A picture refused as the stage refuses it (not a regular file, too
    /// large a file, too many pixels, not a PNG).
    #[error(transparent)]
    Picture(#[from] puppetry_mesh::MeshError),
    /// Where the export would write is not usable: the take itself, a
    /// missing folder, or files already there (without `--force`); see
    /// [`output`].
    #[error("-o {path}: {problem}")]
    Output {
        /// The `-o` given.
        path: String,
        /// Why it cannot be written.
        problem: String,
    },
    /// An external program is not installed.
    #[error("{tool} not found on PATH; install it ({install})")]
    ToolMissing {
        /// The program, as `ffmpeg`.
        tool: String,
        /// How to install it.
        install: String,
    },
}

pub(crate) fn io_error(file: &Path) -> impl FnOnce(std::io::Error) -> ExportError + '_ {
    move |source| ExportError::Io {
        file: file.display().to_string(),
        source,
    }
}

/// A new, empty file beside `path` (in its folder), created exclusively
/// (`O_EXCL`) under a random name that starts with a dot and the file's
/// name and ends with `suffix`: nothing planted there beforehand, a link
/// least of all, is opened. It is deleted when dropped unless persisted.
pub fn new_beside(path: &Path, suffix: &str) -> Result<tempfile::NamedTempFile, ExportError> {
    use std::os::unix::fs::PermissionsExt;
    let dir = match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(suffix)
        // What `File::create` gives (less the umask), not tempfile's 0600:
        // the file is the user's export once renamed.
        .permissions(std::fs::Permissions::from_mode(0o666))
        .tempfile_in(dir)
        .map_err(io_error(path))
}

/// Writes the file `path` through `write`, as a new file: into
/// [`new_beside`] `path`, buffered, then renamed onto `path` once whole. A
/// link at `path` is replaced, never followed; a failed write leaves
/// nothing behind. Errors of writing name `path`.
pub fn write_new<T>(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<T, ExportError>,
) -> Result<T, ExportError> {
    let mut file = new_beside(path, ".part")?;
    let mut out = BufWriter::with_capacity(1 << 20, file.as_file_mut());
    let value = write(&mut out).map_err(|e| match e {
        ExportError::Io { source, .. } => io_error(path)(source),
        other => other,
    })?;
    out.flush().map_err(io_error(path))?;
    drop(out);
    file.persist(path).map_err(|e| io_error(path)(e.error))?;
    Ok(value)
}

/// A private folder for an export that has no place of its own (the
/// daemon's downloads): made under the system's temporary folder with a
/// random name, readable by this user only, and removed with everything in
/// it when dropped.
pub struct Scratch(tempfile::TempDir);

impl Scratch {
    /// A new, empty scratch folder.
    pub fn new() -> Result<Scratch, ExportError> {
        tempfile::Builder::new()
            .prefix("puppetry-export-")
            .tempdir()
            .map(Scratch)
            .map_err(|source| ExportError::Io {
                file: std::env::temp_dir().display().to_string(),
                source,
            })
    }

    /// Where the folder is.
    pub fn path(&self) -> &Path {
        self.0.path()
    }
}

pub(crate) fn invalid(field: impl Into<String>, problem: impl Into<String>) -> ExportError {
    ExportError::Invalid {
        field: field.into(),
        problem: problem.into(),
    }
}

pub(crate) fn flag(flag: &str, problem: impl Into<String>) -> ExportError {
    ExportError::Flag {
        flag: flag.to_string(),
        problem: problem.into(),
    }
}

/// Told how far an export is: `done` of `total` steps (frames, or chunks
/// for glTF). Called from the exporting thread, in increasing order, ending
/// with `done == total`.
pub trait Progress {
    /// `done` of `total` steps are done.
    fn step(&mut self, done: usize, total: usize);
}

/// No progress reports.
impl Progress for () {
    fn step(&mut self, _done: usize, _total: usize) {}
}

/// A closure `|done, total| …` reports progress.
impl<F: FnMut(usize, usize)> Progress for F {
    fn step(&mut self, done: usize, total: usize) {
        self(done, total)
    }
}

/// A straight (not premultiplied) RGBA picture, 8 bits per channel, rows
/// top to bottom.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbaImage {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// `width × height × 4` bytes.
    pub pixels: Vec<u8>,
}

/// One puppet of an [`Animation`]: its mesh, picture and motion.
#[derive(Debug, Clone, PartialEq)]
pub struct AnimatedPuppet {
    /// The puppet's name on the stage (exports name nodes, slots and
    /// pictures after it).
    pub name: String,
    /// Counter-clockwise triangles (at rest) over the vertices.
    pub triangles: Vec<[u32; 3]>,
    /// One texture coordinate per vertex, as the web renderer uses them:
    /// `u = px / width`, `v = py / height`, v down from the picture's top
    /// edge (the daemon sends the mesh's `uv` unflipped, and renderer.js
    /// uploads the first image row at t = 0).
    pub uv: Vec<[f32; 2]>,
    /// The puppet's picture, which `uv` maps onto the mesh.
    pub image: RgbaImage,
    /// Frame k: the deformed vertex positions in stage coordinates (y up).
    pub frames: Vec<Vec<[f32; 2]>>,
    /// Frame k's drawing order of the triangles, back to front, where the
    /// puppet overlaps itself (`docs/depth.md`); frames that share an order
    /// share it. Empty: mesh order throughout.
    pub draw_orders: Vec<std::sync::Arc<[u32]>>,
    /// Frame k's depth of each triangle (larger = nearer), which gave
    /// `draw_orders[k]`: overlapping triangles never share one. Empty
    /// with `draw_orders`.
    pub depths: Vec<std::sync::Arc<[u16]>>,
    /// The frames the take stepped into: a handle of the puppet was let
    /// go since the frame before, so the pose jumped there (a puppet let
    /// go springs back in one solve). Keyed formats hold the frame before
    /// until this one instead of blending the two. Ascending.
    pub snaps: Vec<usize>,
    /// A skeleton puppet's skeleton at rest: Spine exports it as bones
    /// fitted to the frames ([`skin`]); none for the other rigs.
    pub skeleton: Option<skin::SkeletonRest>,
}

impl AnimatedPuppet {
    /// A stage puppet moved through `frames`: its name, triangles, texture
    /// coordinates (zeros for a mesh without), picture and, for a skeleton
    /// puppet, its skeleton at rest; drawn in mesh order (set
    /// `draw_orders` for a puppet that folds over itself).
    pub fn of_puppet(
        p: &puppetry_stage::Puppet,
        frames: Vec<Vec<[f32; 2]>>,
    ) -> Result<AnimatedPuppet, ExportError> {
        let skeleton = p.rig().skeleton().map(|s| skin::SkeletonRest {
            joints: s.joints().to_vec(),
            bones: s.bones().to_vec(),
            parents: (0..s.bones().len()).map(|b| s.parent_of(b)).collect(),
            rest: p.mesh.vertices().to_vec(),
        });
        Ok(AnimatedPuppet {
            name: p.name.clone(),
            triangles: p.mesh.triangles().to_vec(),
            uv: p
                .mesh
                .uv()
                .map(|uv| uv.iter().map(|t| [t.x as f32, t.y as f32]).collect())
                .unwrap_or_else(|| vec![[0.0, 0.0]; p.mesh.vertices().len()]),
            image: load_picture(&p.picture)?,
            frames,
            draw_orders: Vec::new(),
            depths: Vec::new(),
            snaps: Vec::new(),
            skeleton,
        })
    }

    /// Whether the take stepped into frame `k` ([`AnimatedPuppet::snaps`]).
    pub fn snaps_into(&self, k: usize) -> bool {
        self.snaps.binary_search(&k).is_ok()
    }

    /// The number of vertices: one per texture coordinate.
    pub fn vertex_count(&self) -> usize {
        self.uv.len()
    }

    /// Frame k's triangles in drawing order, back to front.
    pub fn triangles_drawn(&self, frame: usize) -> impl DoubleEndedIterator<Item = &[u32; 3]> {
        let order = self.draw_orders.get(frame);
        (0..self.triangles.len()).map(move |i| {
            let t = order.map_or(i, |o| o[i] as usize);
            &self.triangles[t]
        })
    }
}

/// A self-contained animation at a fixed frame rate, the input of every
/// exporter. Frame k is shown at `t = k / fps`.
#[derive(Debug, Clone, PartialEq)]
pub struct Animation {
    /// The stage's width in stage units; y up, origin at the lower left.
    pub stage_width: f64,
    /// The stage's height in stage units.
    pub stage_height: f64,
    /// Frames per second: frame k is shown at `k / fps`.
    pub fps: f64,
    /// Drawn in this order: later puppets on top.
    pub puppets: Vec<AnimatedPuppet>,
    /// Every puppet has exactly this many frames.
    pub frame_count: usize,
}

impl Animation {
    /// The length in seconds: `frame_count / fps` (the last frame is shown
    /// for one frame's time).
    pub fn duration(&self) -> f64 {
        self.frame_count as f64 / self.fps
    }

    /// Checks everything the exporters rely on, naming the field at fault:
    /// positive finite stage size and frame rate, at least one frame and
    /// puppet, per puppet a vertex count that the texture coordinates, every
    /// frame and the triangles agree on, finite numbers, and a picture whose
    /// pixel buffer fits its size.
    pub fn validate(&self) -> Result<(), ExportError> {
        for (field, v) in [
            ("stage_width", self.stage_width),
            ("stage_height", self.stage_height),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(
                    field,
                    format!("must be a positive number, got {v}"),
                ));
            }
        }
        check_fps(self.fps, "fps")?;
        if self.frame_count == 0 {
            return Err(invalid("frame_count", "the animation has no frames"));
        }
        if self.puppets.is_empty() {
            return Err(invalid("puppets", "the animation has no puppets"));
        }
        for (i, p) in self.puppets.iter().enumerate() {
            let at = |field: &str| format!("puppets[{i}] {:?}.{field}", p.name);
            let n = p.vertex_count();
            if n == 0 {
                return Err(invalid(at("uv"), "the puppet has no vertices"));
            }
            if n > u32::MAX as usize {
                return Err(invalid(at("uv"), "too many vertices"));
            }
            if let Some(j) = p.uv.iter().position(|q| !q.iter().all(|c| c.is_finite())) {
                return Err(invalid(at(&format!("uv[{j}]")), "is not a finite number"));
            }
            if p.triangles.is_empty() {
                return Err(invalid(at("triangles"), "the puppet has no triangles"));
            }
            for (t, tri) in p.triangles.iter().enumerate() {
                if let Some(&v) = tri.iter().find(|&&v| v as usize >= n) {
                    return Err(invalid(
                        at(&format!("triangles[{t}]")),
                        format!(
                            "vertex index {v} is out of range (the puppet has {n} vertices, one per uv)"
                        ),
                    ));
                }
            }
            if p.frames.len() != self.frame_count {
                return Err(invalid(
                    at("frames"),
                    format!(
                        "has {} frames, expected frame_count = {}",
                        p.frames.len(),
                        self.frame_count
                    ),
                ));
            }
            for (k, frame) in p.frames.iter().enumerate() {
                if frame.len() != n {
                    return Err(invalid(
                        at(&format!("frames[{k}]")),
                        format!("has {} vertices, expected {n} (one per uv)", frame.len()),
                    ));
                }
                if let Some(j) = frame.iter().position(|q| !q.iter().all(|c| c.is_finite())) {
                    return Err(invalid(
                        at(&format!("frames[{k}][{j}]")),
                        "is not a finite number",
                    ));
                }
            }
            let img = &p.image;
            if img.width == 0 || img.height == 0 {
                return Err(invalid(at("image"), "the picture is empty"));
            }
            let expected = img.width as u64 * img.height as u64 * 4;
            if img.pixels.len() as u64 != expected {
                return Err(invalid(
                    at("image.pixels"),
                    format!(
                        "has {} bytes, expected {}×{}×4 = {expected}",
                        img.pixels.len(),
                        img.width,
                        img.height
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Refuses a frame rate that is not a positive finite number, naming
/// `name` (a field or a flag).
pub(crate) fn check_fps(fps: f64, name: &str) -> Result<(), ExportError> {
    if fps.is_finite() && fps > 0.0 && fps <= 1000.0 {
        Ok(())
    } else {
        let problem = format!("must be a positive frame rate (at most 1000), got {fps}");
        Err(if name.starts_with("--") {
            flag(name, problem)
        } else {
            invalid(name, problem)
        })
    }
}

/// A puppet's picture as straight RGBA8: its PNG file, or the texture of a
/// plain-coloured stroke.
pub fn load_picture(picture: &puppetry_stage::Picture) -> Result<RgbaImage, ExportError> {
    match picture {
        puppetry_stage::Picture::File(path) => load_png(path),
        puppetry_stage::Picture::Stroke(colour) => {
            let (width, height, pixels) = puppetry_mesh::stroke::stroke_texture(*colour);
            Ok(RgbaImage {
                width,
                height,
                pixels,
            })
        }
    }
}

/// Reads a PNG into straight RGBA8: palette, grey and grey+alpha, RGB and
/// RGBA at any bit depth (16-bit keeps its high byte; tRNS becomes alpha).
pub fn load_png(path: &Path) -> Result<RgbaImage, ExportError> {
    let name = path.display().to_string();
    let not_png = |e: png::DecodingError| match e {
        png::DecodingError::IoError(source) => ExportError::Io {
            file: name.clone(),
            source,
        },
        other => ExportError::File {
            file: name.clone(),
            problem: format!("not a valid PNG image: {other}"),
        },
    };
    // Checked as the stage checks it: a regular file within its cap, its
    // pixels and decoded bytes within theirs, before anything is decoded.
    // Palette → RGB(A) with tRNS as alpha, low bit depths → 8 bits.
    let mut reader = puppetry_mesh::trace::open_png(path, png::Transformations::EXPAND)?;
    let (width, height) = reader.info().size();
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| ExportError::File {
            file: name.clone(),
            problem: format!("{width}×{height} pixels is too large"),
        })?;
    let mut buf = vec![0u8; size];
    let frame = reader.next_frame(&mut buf).map_err(not_png)?;
    let (color, depth) = reader.output_color_type();
    let bytes = match depth {
        png::BitDepth::Eight => 1,
        png::BitDepth::Sixteen => 2,
        other => {
            return Err(ExportError::File {
                file: name,
                problem: format!("unexpected bit depth {other:?} after expansion"),
            });
        }
    };
    let channels = color.samples();
    let mut pixels = Vec::with_capacity(width as usize * height as usize * 4);
    for row in buf.chunks_exact(frame.line_size).take(height as usize) {
        for px in row[..width as usize * channels * bytes].chunks_exact(channels * bytes) {
            // The high byte of each sample (big-endian in PNG).
            let s = |c: usize| px[c * bytes];
            let rgba = match color {
                png::ColorType::Grayscale => [s(0), s(0), s(0), 255],
                png::ColorType::GrayscaleAlpha => [s(0), s(0), s(0), s(1)],
                png::ColorType::Rgb => [s(0), s(1), s(2), 255],
                png::ColorType::Rgba => [s(0), s(1), s(2), s(3)],
                png::ColorType::Indexed => {
                    return Err(ExportError::File {
                        file: name,
                        problem: "palette left unexpanded".into(),
                    });
                }
            };
            pixels.extend_from_slice(&rgba);
        }
    }
    if pixels.len() != width as usize * height as usize * 4 {
        return Err(ExportError::File {
            file: name,
            problem: "the PNG image data is truncated".into(),
        });
    }
    Ok(RgbaImage {
        width,
        height,
        pixels,
    })
}

/// Writes straight RGBA8 pixels as a PNG, compressed for speed
/// (`Compression::Fast`: fdeflate, adaptive row filters).
pub fn write_png<W: std::io::Write>(
    out: W,
    width: u32,
    height: u32,
    pixels: &[u8],
) -> Result<(), png::EncodingError> {
    let mut encoder = png::Encoder::new(out, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(pixels)?;
    writer.finish()
}
