//! Deformers: given a validated rest [`Mesh`](crate::mesh::Mesh) and handle
//! positions, compute deformed vertex positions. Each deformer separates
//! three phases — register (new rest mesh), compile (handle set changed),
//! update (handles moved) — and the update phase never allocates.
//!
//! Plain synchronous numeric code: the daemon runs it on a thread of its own.

pub mod arap;
pub mod ffd;
pub mod measure;
pub mod skeleton;
pub mod sparse;

pub use arap::{Anchor, Arap, ArapError, Steps};
