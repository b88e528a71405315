//! Helpers of the daemon's tests: the workspace's shared fixtures, a
//! daemon with the demo puppet and a WebSocket client's view of it, the
//! headless-browser runner and a `nats-server` of the tests' own. The
//! binary's tests (`crates/puppetry/tests/it`) share `daemon.rs` and
//! `browser.rs` by path.
#![allow(dead_code)]

pub use puppetry_testkit::*;

pub mod browser;
pub mod daemon;
pub mod nats;
