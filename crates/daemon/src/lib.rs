//! The daemon: everything of `puppetry serve` that is not numeric. It runs
//! the stage on a thread of its own ([`stage_thread`]), feeds it from the
//! configured input sources (`inputs`, under `sources`' supervision;
//! [`serve`] assembles it all), and serves the web renderer and the
//! WebSocket protocol ([`protocol`], [`stream`]) to renderer and performer
//! clients;
//! show-control desks read its state and trigger it over OSC (`osc`).
//! Which puppets are on stage, and where each one's output is, is the
//! [`lineup`]: fixed by the stage file until a director adds, removes or
//! reorders puppets at runtime. With `[relay]`, the stage is also
//! published over NATS, and `puppetry relay` processes serve it to more
//! viewers, on other machines ([`relay`]).
//!
//! The public surface is what the `puppetry` binary, its tests and the
//! benchmarks use: starting a daemon ([`serve`]) or a relay, the stage
//! file ([`config`]), the protocol's types ([`protocol`]), and the stage
//! thread's loop for simulated shows ([`stage_thread::StageDriver`]); the
//! rest is the crate's own. Every public item is documented
//! (`missing_docs` is on here).
//!
//! ```text
//!   puppetry-input ──► stage_thread ──────────────► stream ──► clients
//!   (inputs, under     (owns the puppetry-stage      (HTTP + WebSocket: newest
//!    supervision)       Stage; solves with            frame per client; the
//!                       puppetry-deform; encodes      web page)
//!                       each frame once)
//!                              │
//!                              └──► relay::publish ──► NATS ──► relay::serve ──► stream ──► viewers
//!                                   (the same frames,          (another process: the same
//!                                    newest only)               edge, fed from NATS)
//! ```

pub mod bundled;
pub mod config;
pub mod convert;
pub(crate) mod inputs;
// Writes `clients/web/wire.js` from the protocol's types, in its test.
#[cfg(test)]
mod javascript;
pub mod lineup;
pub mod memory;
pub(crate) mod midi;
pub mod midi_learn;
pub(crate) mod osc;
pub(crate) mod outputs;
/// The wire protocol: the crate `puppetry-protocol`, which the daemon
/// speaks and re-exports (its frame encoder runs at every solve, and is
/// built optimised in a crate of its own).
pub use puppetry_protocol as protocol;
pub mod relay;
pub mod serve;
pub(crate) mod show_control;
pub(crate) mod sources;
pub mod stage_thread;
pub mod stream;
pub mod takes;
