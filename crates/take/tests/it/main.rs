//! The take file: records round-trip, a cut tail is reported and skipped,
//! damage mid-take is an error, foreign files are refused by name, and what
//! is read is bounded.

mod bounds;
mod file;
mod fuzz;
