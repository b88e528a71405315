//! The `puppetry` command's own work: the commands that are not the daemon
//! ([`cli`]: mesh, solve, devices, calibrate), the benchmarks ([`bench`](mod@bench),
//! [`viewers_bench`] with the relay tier's fan-out), the long-run leak
//! check ([`soak`]), the lp-FFD paper's comparison ([`compare`]) and what
//! stderr may be drawn with ([`terminal`]). `main.rs` parses the
//! command line and calls into these; the pipeline itself lives in the
//! workspace's other crates.
//!
//! ```text
//!   puppetry-input ──► puppetry-stage ──► puppetry-deform     puppetry-daemon
//!   (contacts from     (contacts →        (ARAP, lp-FFD,      (stage thread,
//!    devices, files)    handles)           skeleton)           protocol, edge)
//!                            ▲                  ▲
//!                            └── puppetry-mesh ─┘
//! ```

pub mod bench;
pub mod bundled;
pub mod cli;
pub mod compare;
pub mod export;
pub mod peers;
pub mod soak;
pub mod take_bench;
pub mod takes;
pub mod terminal;
pub mod viewers_bench;
