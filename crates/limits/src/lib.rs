//! The resource budget: every resource a stranger on the show network (or a
//! hostile file) can make puppetry spend — contacts, bytes, pixels,
//! connections, time — has its limit here, written once, and each door
//! (the WebSocket stream, OSC and TUIO, relays, the files a stage, key or
//! take file names, uploads, exports) enforces it from here.
//!
//! `docs/limits.md` lists every constant with its value and what a client
//! gets past it; a test (`tests/documented.rs`) keeps the two equal, so a
//! limit added here without its row fails the build's tests.
//!
//! The crate has no dependencies: numeric, stage and device crates alike
//! read it without pulling anything in. Every limit is documented
//! (`missing_docs` is on here).

pub mod contacts;
pub mod exports;
pub mod files;
pub mod midi;
pub mod net;
