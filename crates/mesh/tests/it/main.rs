//! The mesh crate's integration tests, one binary: tracing, meshing and
//! validation of rest shapes.

mod fuzz;
mod meshing;
