//! The input crate's integration tests, one binary: decoders over real and
//! synthetic captures, mice, HID reports, serial pads over pty pairs and
//! TUIO over loopback UDP.

mod common {
    pub use puppetry_testkit::*;
}

mod fuzz;
mod hid;
mod input;
mod mouse;
mod serial;
mod tuio;
