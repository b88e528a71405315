//! puppetry: a realtime 2D puppetry server.
//!
//! A performer's touches become handles on a puppet's triangle mesh; a
//! deformer moves the mesh to follow them while keeping it as rigid as
//! possible; the deformed vertices stream to renderer clients.
//!
//! ```text
//!   input ───────► stage ─────────► deform ──────► stream
//!  (TUIO, replays, (contacts →       (ARAP solver,   (HTTP + WebSocket,
//!   evdev state,    handles, pins;    on the stage    newest frame per
//!   serial, HID)    stage thread)     thread)         client; web page)
//!                      ▲
//!                     mesh (rest shapes: PNG/polygon → triangle mesh)
//! ```
//!
//! [`input`] turns devices and replay files into contact frames in stage
//! coordinates; [`stage`] maps contacts to handles on puppets and runs, on a
//! thread of its own, the [`deform`] solver at the input rate; [`stream`]
//! serves the web renderer and sends every client the newest frames;
//! [`serve`] assembles the daemon. [`mesh`] builds and validates rest meshes;
//! [`cli`] and [`bench`] are the scriptable commands.
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
