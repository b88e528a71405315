//! Files: bytes read from any file a stage, key or take file names, and the
//! pixels of a picture, checked before anything is allocated.
//!
//! Every file is read through one function (`puppetry_mesh::file`, the
//! lowest crate that reads files) that refuses anything but a regular file
//! and reads at most its cap plus one byte, so a stage file naming
//! `/dev/zero`, a FIFO or a 10 GB file is refused at once by name. The caps
//! are generous for a show (several times the largest file a bundled stage
//! uses) and small enough that reading and parsing the largest stays far
//! under 500 MB of memory.

/// Bytes of a stage file (TOML). The bundled ones are under 4 KiB; a
/// stage of a hundred puppets with skeletons and key poses is under 100 KiB.
pub const MAX_STAGE_FILE_BYTES: u64 = 1 << 20;

/// Bytes of a `.mesh.json` rest mesh: about 600,000 vertices, thirty
/// times what an upload may ask for.
pub const MAX_MESH_FILE_BYTES: u64 = 32 << 20;

/// Bytes of a key-pose file (`keys = …`): thousands of key poses.
pub const MAX_KEYS_FILE_BYTES: u64 = 4 << 20;

/// Bytes of a replay input's file (a `.jsonl` recording, an evemu
/// `.event` capture or a hid-recorder capture): hours of one device.
pub const MAX_REPLAY_FILE_BYTES: u64 = 64 << 20;

/// Bytes of a picture file (PNG) as stored, before decoding.
pub const MAX_PICTURE_FILE_BYTES: u64 = 64 << 20;

/// Pixels (width × height) of a picture, read from its header before any
/// pixel is decoded: 4096 × 4096, larger than any screen a show projects
/// on and the texture size every WebGL implementation draws.
pub const MAX_PICTURE_PIXELS: u64 = 1 << 24;

/// Pixels along either side of a picture (a long strip for a curve
/// puppet's texture may be narrow and long, within `MAX_PICTURE_PIXELS`).
pub const MAX_PICTURE_SIDE: u32 = 16384;

/// Bytes a picture's pixels take once decoded (16-bit RGBA at
/// `MAX_PICTURE_PIXELS` is 128 MiB); also the PNG decoder's own memory
/// limit, so its buffers stop at it too.
pub const MAX_PICTURE_DECODED_BYTES: u64 = 1 << 27;

/// Boundary segments a traced outline may have (a hair-fine figure at
/// 4096² has a few hundred thousand); a checkerboard picture would have
/// one per pixel and its tracing gigabytes.
pub const MAX_OUTLINE_SEGMENTS: u64 = 1 << 21;

/// Islands and holes of a traced outline, after specks are dropped.
pub const MAX_OUTLINE_RINGS: u64 = 4096;

/// Changes in one take step: the stage thread applies what arrived during
/// one solve, a few dozen at most in a crowded show.
pub const MAX_TAKE_STEP_CHANGES: u64 = 4096;

/// Contacts in one take step, over all its input frames, and contacts held
/// down at once at any point of a take: every contact a stage accepts
/// from every client and device together, with room to spare.
pub const MAX_TAKE_CONTACTS: u64 = 1024;

/// Seconds since a take began, of any step, frame or end: a week. Past it
/// a time is damage, and converting it to a `Duration` could overflow.
pub const MAX_TAKE_SECONDS: f64 = 604_800.0;
