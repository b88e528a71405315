//! The update phase must not allocate: this test binary counts every
//! allocation made while updates run.

use puppetry_testkit::alloc;

use glam::DVec2;
use puppetry_deform::{Anchor, Arap, Steps};

#[test]
fn updates_do_not_allocate() {
    // Several pieces, so solved, carried and fixed pieces are all exercised.
    let mesh = crate::common::islands(3);
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
    alloc::start();
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
    assert_eq!(alloc::stop(), 0, "update allocated");
    // The counter works: a compile does allocate.
    alloc::start();
    arap.compile(&anchors[..2]).unwrap();
    assert!(alloc::stop() > 0);
}
