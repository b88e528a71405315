//! What the simulated shows share (the stage crate's `simulate` and the
//! stage thread's `show`): where a contact, pin or brush lands ([`Spot`])
//! and how proptest draws one, the case count, and where a failing
//! sequence is written for replay.

use std::path::PathBuf;

use proptest::prelude::*;
use serde::{Deserialize, Serialize};

/// Where a contact, a pin or a brush lands.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "on", rename_all = "snake_case")]
pub enum Spot {
    /// Anywhere on (or a little off) the stage, as fractions of its size.
    Stage {
        /// Fraction of the stage's width; -0.1..1.1 from [`spot`].
        x: f64,
        /// Fraction of the stage's height (y up); -0.1..1.1 from [`spot`].
        y: f64,
    },
    /// On a puppet's rest vertex (indices taken modulo the counts), plus a
    /// small offset: the outline, pins and other fingers a hair away.
    Vertex {
        /// Which puppet, taken modulo the stage's puppet count.
        puppet: u8,
        /// Which rest vertex, taken modulo the puppet's vertex count.
        vertex: u32,
        /// Offset added to the vertex's x, in its units.
        dx: f64,
        /// Offset added to the vertex's y, in its units.
        dy: f64,
    },
}

/// A spot: on the stage or a hair from a vertex (exactly on it, 1e-7 or
/// 1e-3 away, half a unit, or up to 4 units).
pub fn spot() -> impl Strategy<Value = Spot> {
    let offset = prop_oneof![Just(0.0), Just(1e-7), Just(-1e-3), Just(0.5), -4.0..4.0f64];
    prop_oneof![
        (-0.1..1.1f64, -0.1..1.1f64).prop_map(|(x, y)| Spot::Stage { x, y }),
        (any::<u8>(), any::<u32>(), offset.clone(), offset).prop_map(|(puppet, vertex, dx, dy)| {
            Spot::Vertex {
                puppet,
                vertex,
                dx,
                dy,
            }
        }),
    ]
}

/// Sequences a simulation runs per stage: `PROPTEST_CASES`, or `default`.
pub fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(default)
}

/// Where a failing sequence is written: `target/<what>-failure-<stage>.json`
/// (or under `CARGO_TARGET_DIR`).
pub fn failure_file(what: &str, stage: &str) -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| crate::root().join("target"));
    target.join(format!("{what}-failure-{stage}.json"))
}
