//! The `puppetry` command's own work: the commands that are not the daemon
//! ([`cli`]: mesh, solve, devices, calibrate), exports and takes from the
//! command line ([`export`], [`takes`]) and what stderr may be drawn with
//! ([`terminal`]). `main.rs` parses the command line and calls into these,
//! into `puppetry-bench` (the benchmarks, the soak, `compare`) and into the
//! daemon; the pipeline itself lives in the workspace's other crates.
//!
//! ```text
//!   puppetry-input ──► puppetry-stage ──► puppetry-deform     puppetry-daemon
//!   (contacts from     (contacts →        (ARAP, lp-FFD,      (stage thread,
//!    devices, files)    handles)           skeleton)           protocol, edge)
//!                            ▲                  ▲
//!                            └── puppetry-mesh ─┘
//! ```

pub mod cli;
pub mod export;
pub mod takes;
pub mod terminal;
