//! The take file: records round-trip, a cut or damaged tail is reported and
//! skipped, and foreign files are refused by name.

mod file;
mod fuzz;
