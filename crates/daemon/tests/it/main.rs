//! The daemon's tests, one binary: the daemon on 127.0.0.1:0 driven over
//! WebSocket, by device stand-ins, serial ptys, TUIO and replays; the rigs
//! live; the web page in headless Chromium; relays over a real
//! `nats-server`; the simulated show; and the wire protocol's, the
//! relay's, show control's and the edge's own parts.

#![allow(
    clippy::too_many_lines,
    reason = "a test or example is one scenario, read top to bottom"
)]

mod common;

mod curves;
mod depth;
mod edge;
mod fuzz;
mod lineup;
mod relay;
mod rigs;
mod roles;
mod serve;
mod show;
mod stage_state;
mod stranger;
mod web;
mod web_protocol;
mod web_puppets;
mod web_rigs;
