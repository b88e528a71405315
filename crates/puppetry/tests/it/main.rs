//! The binary's tests, one binary: the command line as a user runs it
//! (every command, bad input, installing from the clone), every stage file
//! of `config/`, devices and MIDI through the binary, show control over
//! OSC, takes and exports end to end, hostile clients against the binary,
//! and the crate graph. The daemon's own tests are in
//! `crates/daemon/tests/it`.

#![allow(
    clippy::too_many_lines,
    reason = "a test or example is one scenario, read top to bottom"
)]

mod common;

mod bad_input;
mod cli;
mod config;
mod devices;
mod exports;
mod files;
mod graph;
mod guarded;
mod hostile;
mod install;
mod memory;
mod midi;
mod osc;
mod takes;
