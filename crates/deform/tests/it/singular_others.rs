//! lp-FFD grids, shape-aware skeletons and curves at their singular cases:
//! handles on or near one another and on pins, on one point, on a line.
//! Every pose stays finite and bounded.
