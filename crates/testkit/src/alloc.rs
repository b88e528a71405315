//! Counts the allocations a thread makes while it is told to, so a test
//! binary whose other tests run on other threads at the same time can still
//! say "this update did not allocate". A test binary installs it with
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOCATOR: puppetry_testkit::alloc::Counting = puppetry_testkit::alloc::Counting;
//! ```
//!
//! and measures with [`count`].

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// The system allocator, counting on threads that are inside [`count`].
pub struct Counting;

thread_local! {
    // Const-initialised cells without destructors: touching them from the
    // allocator never allocates or registers anything.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn note() {
    // `try_with`: a thread being torn down may allocate after its locals
    // are gone; that is never inside `count`.
    let _ = COUNTING.try_with(|on| {
        if on.get() {
            let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        }
    });
}

// SAFETY: every call is passed to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `work` and returns what it returned with the number of allocations
/// this thread made meanwhile. Counts nothing unless [`Counting`] is the
/// binary's global allocator.
pub fn count<R>(work: impl FnOnce() -> R) -> (R, usize) {
    ALLOCATIONS.with(|n| n.set(0));
    COUNTING.with(|on| on.set(true));
    let result = work();
    COUNTING.with(|on| on.set(false));
    (result, ALLOCATIONS.with(|n| n.get()))
}

/// Starts counting this thread's allocations from zero (see [`stop`]).
pub fn start() {
    ALLOCATIONS.with(|n| n.set(0));
    COUNTING.with(|on| on.set(true));
}

/// Stops counting and returns the allocations since [`start`].
pub fn stop() -> usize {
    COUNTING.with(|on| on.set(false));
    ALLOCATIONS.with(|n| n.get())
}
