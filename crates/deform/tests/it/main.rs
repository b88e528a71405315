//! The deformers' integration tests, one binary. The binary counts each
//! thread's allocations (`puppetry_testkit::alloc`), so the update paths'
//! no-allocation tests run beside the others.

#[global_allocator]
static ALLOCATOR: puppetry_testkit::alloc::Counting = puppetry_testkit::alloc::Counting;

mod common {
    pub use puppetry_testkit::*;
}

mod arap;
mod curve;
mod depth;
mod ffd;
mod measure;
mod no_alloc;
mod rbf;
mod singular_arap;
mod singular_others;
mod skeleton;
