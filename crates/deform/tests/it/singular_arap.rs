//! ARAP at its singular cases: handles on or near one another, on pins, on
//! boundary vertices, edges and degenerate triangles, all on one point or
//! on a line. Every pose stays finite and bounded.
