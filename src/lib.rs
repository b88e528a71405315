//! puppetry: a realtime 2D puppetry server.
//!
//! A performer's touches become handles on a puppet's triangle mesh; a
//! deformer moves the mesh to follow them while keeping it as rigid as
//! possible; the deformed vertices stream to renderer clients.
//!
//! ```text
//!   input ──────────► stage ───────────► deform ─────────► stream
//!  (evdev touch,      (contacts →         (free-form ARAP,  (HTTP + WebSocket,
//!   pens, mice, HID,   handles: points,    lp-FFD grid,      newest frame per
//!   serial, TUIO,      grid handles,       shape-aware       client; web page)
//!   browsers,          joints; pins,       skeleton; on the
//!   replays)           painting; the       stage thread)
//!                      stage thread)
//!                         ▲
//!                        mesh (rest shapes: PNG/polygon → triangle mesh)
//! ```
//!
//! [`input`] turns devices and replay files into contact frames in stage
//! coordinates; [`stage`] maps contacts to handles on puppets — points of
//! the mesh, grid handles or skeleton joints, by the puppet's rig — and runs,
//! on a thread of its own, the [`deform`]ers at the input rate; [`stream`]
//! serves the web renderer and sends every client the newest frames;
//! [`serve`] assembles the daemon. [`mesh`] builds and validates rest meshes;
//! [`cli`], [`bench`] and [`compare`] are the scriptable commands.
//!
//! `mesh` and `deform` are plain synchronous code over data: no async, no I/O
//! on the solving path.

pub mod bench;
pub mod cli;
pub mod compare;
pub mod deform;
pub mod input;
pub mod mesh;
pub mod serve;
pub mod stage;
pub mod stream;
