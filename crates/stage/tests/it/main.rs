//! The stage crate's integration tests, one binary; it counts each thread's
//! allocations (`puppetry_testkit::alloc`) for the rigs' frame path.

#![allow(
    clippy::too_many_lines,
    reason = "a test or example is one scenario, read top to bottom"
)]

#[global_allocator]
static ALLOCATOR: puppetry_testkit::alloc::Counting = puppetry_testkit::alloc::Counting;

mod curve;
mod depth;
mod edits;
mod fuzz;
mod grab;
mod keyframing;
mod keys;
mod lineup;
mod listen;
mod many;
mod numbers;
mod rigs_no_alloc;
mod simulate;
