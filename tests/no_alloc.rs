//! The update phase must not allocate: this test binary counts every
//! allocation made while updates run.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::DVec2;
use puppetry::deform::{Anchor, Arap, Steps};

mod common;

struct Counting;
static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn updates_do_not_allocate() {
    // Several pieces, so solved, carried and fixed pieces are all exercised.
    let mesh = common::islands(3);
    let pieces = mesh.pieces();
    let mut arap = Arap::register(&mesh).unwrap();
    let anchors = [
        Anchor::Vertex(pieces[0].vertices[0]),
        Anchor::Point {
            triangle: pieces[0].triangles[5],
            bary: [0.2, 0.3, 0.5],
        },
        Anchor::Vertex(pieces[1].vertices[2]),
    ];
    arap.compile(&anchors).unwrap();
    let mut targets = vec![DVec2::ZERO; anchors.len()];
    COUNTING.store(true, Ordering::SeqCst);
    for frame in 0..50 {
        for (h, t) in targets.iter_mut().enumerate() {
            *t = DVec2::new(
                frame as f64 * 0.1 + h as f64 * 4.0,
                (frame as f64 * 0.2).sin(),
            );
        }
        let steps = if frame % 2 == 0 {
            Steps::Both
        } else {
            Steps::ScaleFree
        };
        arap.update(&targets, steps).unwrap();
    }
    COUNTING.store(false, Ordering::SeqCst);
    assert_eq!(ALLOCATIONS.load(Ordering::SeqCst), 0, "update allocated");
    // The counter works: a compile does allocate.
    COUNTING.store(true, Ordering::SeqCst);
    arap.compile(&anchors[..2]).unwrap();
    COUNTING.store(false, Ordering::SeqCst);
    assert!(ALLOCATIONS.load(Ordering::SeqCst) > 0);
}
