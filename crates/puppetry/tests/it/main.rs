//! End-to-end tests, one binary: the daemon on 127.0.0.1:0 driven over
//! WebSocket, by device stand-ins, serial ptys, TUIO and replays; every
//! stage file of `config/`; the rigs live; the web page in headless
//! Chromium; show control over OSC; and the command line.

#![allow(
    clippy::too_many_lines,
    reason = "a test or example is one scenario, read top to bottom"
)]

mod common;

mod bad_input;
mod cli;
mod config;
mod curves;
mod depth;
mod devices;
mod edge;
mod exports;
mod files;
mod fuzz;
mod graph;
mod guarded;
mod hostile;
mod install;
mod lineup;
mod memory;
mod midi;
mod osc;
mod relay;
mod rigs;
mod roles;
mod serve;
mod show;
mod stage_state;
mod stranger;
mod takes;
mod web;
mod web_protocol;
mod web_puppets;
mod web_rigs;
