//! Helpers of the end-to-end tests: the workspace's shared fixtures, a
//! daemon with the demo puppet and a WebSocket client's view of it, the
//! daemon binary as a child process and the headless-browser runner.
#![allow(dead_code)]

pub use puppetry_testkit::*;

pub mod browser;
pub mod daemon;
pub mod nats;
pub mod served;
