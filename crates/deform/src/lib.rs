//! Deformers: given a validated rest [`Mesh`](puppetry_mesh::Mesh) and handle
//! positions, compute deformed vertex positions. Each deformer separates
//! three phases — register (new rest mesh), compile (handle set changed),
//! update (handles moved) — and the update phase never allocates.
//! [`arap`] is the free-form two-step solver (Igarashi et al. 2005), [`ffd`]
//! the locality-preserving FFD grid rig, [`skeleton`] the shape-aware
//! skeletal deformer (Wang et al. 2013), [`curve`] the same paper's
//! as-rigid-as-possible curve editing with peeling; [`sparse`] holds their
//! factorisations and [`measure`] the distortion measures they are compared
//! by. [`depth`] orders the triangles front to back per frame, so parts
//! that fold over each other overlap cleanly instead of interpenetrating.
//!
//! Plain synchronous numeric code: the daemon runs it on a thread of its own.
//! Every public item is documented (`missing_docs` is on here).

pub mod arap;
pub mod curve;
mod dense;
pub mod depth;
pub mod ffd;
mod lanes;
pub mod measure;
pub mod rbf;
pub mod skeleton;
pub mod sparse;
pub mod targets;

pub use arap::{Anchor, Arap, ArapError, Steps};
pub use curve::{Curve, CurveAnchor, CurveError, Peel, PeelParams};
pub use depth::{DepthError, DepthOrder};
pub use rbf::{RbfBlend, RbfError};
