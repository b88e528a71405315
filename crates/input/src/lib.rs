//! The input layer: everything between a touch surface (or a file standing
//! in for one) and the stage. Every source produces the normalised event
//! model of `puppetry-contact` (re-exported here) — [`ContactFrame`]s of
//! [`Contact`]s in stage coordinates, through a [`Calibration`] — so no
//! device unit ever leaves this crate.
//!
//! Decoders (plain synchronous state machines): [`evdev`] turns raw kernel
//! events of touch surfaces and pens into frames, [`mouse`] turns a mouse's
//! into a cursor holding a pair of points, [`hid`] decodes HID digitizer
//! reports, [`tuio`] TUIO bundles, [`serial`] pad records and [`midi`] a
//! MIDI byte stream (controllers and show control; its device loop and
//! mapping are to come).
//!
//! Sources: [`device`] finds, describes and opens Linux input devices and
//! [`hotplug`] keeps one configured device read for the daemon's life;
//! [`hid`], [`tuio`] and [`serial`] also hold their own I/O loops; [`evemu`],
//! [`hid_recording`] and [`recording`] read captures and the project's own
//! frame log, which [`replay`] plays into the daemon. [`record`] writes
//! captures and [`calibrate`] turns four taps into a calibration.
//! [`log_limit`] keeps each source's warnings about bad input to a few
//! lines and a count. Every public item is documented (`missing_docs` is
//! on here).

pub mod calibrate;
pub mod config;
pub mod device;
pub mod evdev;
pub mod evemu;
mod fields;
pub mod hid;
pub mod hid_recording;
pub mod hotplug;
pub mod log_limit;
pub mod midi;
pub mod midi_file;
pub mod midi_map;
pub mod midi_port;
pub mod midi_record;
pub mod mouse;
pub mod record;
pub mod recording;
pub mod replay;
pub mod serial;
pub mod show_clock;
pub mod tuio;

pub use fields::LineError;
pub use puppetry_contact::*;
