//! puppetry: a realtime 2D puppetry server.
//!
//! A performer's touches become handles on a puppet's triangle mesh; a
//! deformer moves the mesh to follow them while keeping it as rigid as
//! possible; the deformed vertices stream to renderer clients.
//!
//! ```text
//!   input ──► stage ──► deform ──► stream
//!  (devices,  (contacts   (ARAP      (WebSocket
//!   replays)   → handles)  solver)    frames)
//!                  ▲
//!                 mesh  (rest shapes: PNG/polygon → triangle mesh)
//! ```
//!
//! Built so far: [`mesh`] (rest meshes, meshing from pictures and polygons)
//! and [`deform`] (the two-step as-rigid-as-possible solver), with the
//! `puppetry mesh`, `solve` and `bench` commands in [`cli`] and [`bench`].
//! `input`, `stage`, `stream` and recording arrive with the daemon.
//!
//! `mesh` and `deform` are plain synchronous code over data: no async, no I/O
//! on the solving path.

pub mod bench;
pub mod cli;
pub mod deform;
pub mod input;
pub mod mesh;
pub mod serve;
pub mod stage;
pub mod stream;
