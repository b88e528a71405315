//! Exports: the output size an export may reach, computed from the take
//! before anything is allocated.
//!
//! An export holds the take's motion resampled to its frame rate — every
//! frame's vertices, 8 bytes each — in memory while it writes, and writes
//! a file the page then downloads. Both grow with the take's length times
//! the frame rate asked for: a 20-minute take at 1000 fps is 1.2 million
//! frames, 9.6 GB of motion for the demo puppet's 999 vertices. So the
//! frames, the motion held and the file written are computed from the take's
//! header and length first, and an export past any of them is refused,
//! naming the size and the limit, before a frame is read. A shorter range
//! (`from`/`to`) or a lower frame rate fits: the message says which.
//!
//! Why these numbers: the daemon's whole budget is under 500 MB, and an
//! export at the limits holds the motion (at most 256 MiB) and, for glb,
//! the file's JSON; the vertex data streams to disk. Measured: a glb of
//! 30,001 frames × 999 vertices (241 MB of motion, a 381 MB file) took the
//! daemon's peak RSS from 15 MB to 400 MB. 256 MiB is a 15-minute take of the demo
//! puppet at 30 fps (27,000 frames × 999 vertices × 8 bytes = 216 MB), or
//! 5 minutes at 30 fps of a stage of 3,500 vertices; longer takes export
//! in ranges. The frames bound what is not stored but drawn (videos and
//! PNG sequences): 2¹⁸ frames is 72 minutes at 60 fps.

/// Frames one export may have: the take's range times the frame rate
/// (`ceil((to − from) × fps)`). 72 minutes at 60 fps. Past it the export
/// is refused (HTTP 413; `puppetry export` fails) naming the frames and
/// the limit.
pub const MAX_EXPORT_FRAMES: u64 = 1 << 18;

/// Bytes of motion one export may hold: frames × the vertices of the
/// puppets it draws × 8 (two 32-bit floats a vertex), plus a small
/// overhead per frame and puppet. Past it the export is refused (HTTP
/// 413; `puppetry export` fails) naming the size and the limit.
pub const MAX_EXPORT_MOTION_BYTES: u64 = 1 << 28;

/// Bytes one export's file may reach, as estimated from the frames and
/// vertices before it is written: glTF binary 12 bytes a vertex a frame
/// (and its morph weights and accessors), Spine JSON at most 28 (two
/// numbers as text). Videos and PNG sequences are compressed as they are
/// written and bounded by the frames instead. Past it the export is
/// refused (HTTP 413; `puppetry export` fails) naming the size and the
/// limit.
pub const MAX_EXPORT_FILE_BYTES: u64 = 1 << 30;

/// Pixels one frame of a drawn export (PNG frames, videos) may have: 8K
/// (8192 × 4320), the largest picture libx264, libvpx-vp9 and prores_ks
/// each encoded here. A frame is drawn whole in memory, 4 bytes a pixel
/// and one per core: `--size 16384x16384` drew two 1 GiB frames (2.8 GB
/// peak) before ffmpeg refused the size. Past it `--size` is refused
/// before the take is read.
pub const MAX_EXPORT_PIXELS: u64 = 8192 * 4320;

/// Pixels one side of a drawn export's frame may have (`--size WxH`).
pub const MAX_EXPORT_SIDE: u32 = 8192;
