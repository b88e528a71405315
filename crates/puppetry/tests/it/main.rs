//! End-to-end tests, one binary: the daemon on 127.0.0.1:0 driven over
//! WebSocket, by device stand-ins, serial ptys, TUIO and replays; every
//! stage file of `config/`; the rigs live; the web page in headless
//! Chromium; and the command line.

mod common;

mod cli;
mod config;
mod devices;
mod edge;
mod install;
mod rigs;
mod serve;
mod stage_state;
mod takes;
mod web;
mod web_protocol;
mod web_rigs;
