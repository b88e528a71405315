//! The mesh crate's integration tests, one binary: tracing, meshing and
//! validation of rest shapes; pictures and files bounded before they are read.

mod fuzz;
mod meshing;
mod pictures;
