//! Helpers of the binary's tests: the workspace's shared fixtures, the
//! daemon binary as a child process, and (shared by path with the
//! daemon's tests, where they live) a daemon with the demo puppet, a
//! WebSocket client's view of it and the headless-browser runner.
#![allow(dead_code)]

pub use puppetry_testkit::*;

// One copy of each helper for both test binaries: a helper crate could not
// hold them (it would depend on the daemon, whose tests depend on it).
#[path = "../../../../daemon/tests/it/common/browser.rs"]
pub mod browser;
#[path = "../../../../daemon/tests/it/common/daemon.rs"]
pub mod daemon;
pub mod served;
