//! The daemon: everything of `puppetry serve` that is not numeric. It runs
//! the stage on a thread of its own ([`stage_thread`]), feeds it from the
//! configured input sources ([`inputs`], under [`sources`]' supervision;
//! [`serve`] assembles it all), and serves the web renderer and the
//! WebSocket protocol ([`protocol`], [`stream`]) to renderer and performer
//! clients;
//! show-control desks read its state and trigger it over OSC ([`osc`]).
//! Which puppets are on stage, and where each one's output is, is the
//! [`lineup`]: fixed by the stage file until a director adds, removes or
//! reorders puppets at runtime. With `[relay]`, the stage is also
//! published over NATS, and `puppetry relay` processes serve it to more
//! viewers, on other machines ([`relay`]).
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
pub mod inputs;
pub mod lineup;
pub mod memory;
pub mod osc;
pub mod outputs;
pub mod protocol;
pub mod relay;
pub mod serve;
pub mod sources;
pub mod stage_thread;
pub mod stream;
pub mod takes;
