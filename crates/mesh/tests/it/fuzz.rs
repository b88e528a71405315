//! Fuzzing the mesh and polygon JSON readers, which read files a user hands
//! to `puppetry mesh` and the stage: random text plus valid documents with
//! fields mutated (NaN, huge and negative numbers, wrong types, deep nests,
//! dropped and unknown keys). Every case must end in a value or an error
//! naming the file; a shape that validates must also mesh or fail cleanly.
//! Pictures too, as a director uploads them to a running stage: random
//! small RGBA images and valid PNGs with bytes changed or cut off must mesh
//! or fail with an error. See `docs/fuzzing.md`.

use proptest::prelude::*;
use puppetry_mesh::polygon::Shape;
use puppetry_mesh::{Mesh, MeshError};
use puppetry_testkit::fuzz::{self, config};

fn mesh_seeds() -> Vec<String> {
    vec![
        puppetry_testkit::bar(3, 2, 30.0, 20.0).to_json(),
        puppetry_testkit::islands(2).to_json(),
    ]
}

fn shape_seeds() -> Vec<String> {
    vec![
        r#"{"outer": [[0, 0], [100, 0], [100, 80], [0, 80]], "holes": [[[20, 20], [20, 40], [40, 40], [40, 20]]]}"#.into(),
        r#"{"polygons": [{"outer": [[0, 0], [10, 0], [5, 8]]}, {"outer": [[20, 0], [30, 0], [30, 10], [20, 10]], "holes": []}]}"#.into(),
    ]
}

/// `pixels` (RGBA rows) as a PNG file's bytes.
fn png_bytes(width: u32, height: u32, pixels: &[u8]) -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(pixels).unwrap();
    writer.finish().unwrap();
    bytes
}

/// A small image whose pixels are opaque where `mask` says, with the
/// alpha values proptest chose elsewhere.
fn picture() -> impl Strategy<Value = (u32, u32, Vec<u8>)> {
    (1u32..24, 1u32..24).prop_flat_map(|(w, h)| {
        let n = (w * h) as usize;
        (
            Just(w),
            Just(h),
            prop::collection::vec(prop_oneof![Just(0u8), Just(255u8), any::<u8>()], n)
                .prop_map(|alpha| alpha.into_iter().flat_map(|a| [90, 40, 20, a]).collect()),
        )
    })
}

/// Meshes `bytes` as a picture file, as `POST /puppets` and `puppetry mesh`
/// do: a mesh with finite vertices, or an error naming the file.
fn check_picture(bytes: &[u8]) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("fuzz.png");
    std::fs::write(&file, bytes).unwrap();
    let options = puppetry_mesh::build::MeshOptions {
        target_vertices: Some(60),
        ..Default::default()
    };
    match puppetry_mesh::build::mesh_picture(&file, &options) {
        Ok(meshed) => assert!(meshed.mesh.vertices().iter().all(|v| v.is_finite())),
        Err(e) => assert!(e.to_string().contains(&file.display().to_string()), "{e}"),
    }
}

fn check_error(e: &MeshError) {
    let message = e.to_string();
    assert!(message.starts_with("fuzz.json: "), "{message}");
    if let MeshError::Syntax { line, .. } = e {
        assert!(*line >= 1, "{message}");
    }
}

fn check_mesh(text: &str) {
    match Mesh::from_json("fuzz.json", text) {
        Ok(mesh) => {
            assert!(mesh.vertices().iter().all(|v| v.is_finite()));
            let _ = Mesh::from_json("again.json", &mesh.to_json()).expect("a mesh re-reads");
        }
        Err(e) => check_error(&e),
    }
}

fn check_shape(text: &str) {
    match Shape::from_json("fuzz.json", text) {
        Ok(shape) => {
            assert!(shape.area().is_finite());
            // Small shapes only: meshing is the slow part, and its own tests
            // cover large ones.
            let options = puppetry_mesh::build::MeshOptions {
                target_vertices: Some(40),
                ..Default::default()
            };
            if let Err(e) = puppetry_mesh::build::triangulate("fuzz.json", &shape, &options) {
                check_error(&e);
            }
        }
        Err(e) => check_error(&e),
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_mesh_json_random_text(text in fuzz::text(300)) {
        check_mesh(&text);
        check_shape(&text);
    }

    #[test]
    fn fuzz_mesh_json_mutated(text in fuzz::mutated_json(mesh_seeds())) {
        check_mesh(&text);
    }

    #[test]
    fn fuzz_mesh_json_mutated_bytes(text in fuzz::mutated_text(mesh_seeds())) {
        check_mesh(&text);
    }

    #[test]
    fn fuzz_polygon_json_mutated(text in fuzz::mutated_json(shape_seeds())) {
        check_shape(&text);
    }

    #[test]
    fn fuzz_polygon_json_mutated_bytes(text in fuzz::mutated_text(shape_seeds())) {
        check_shape(&text);
    }

    #[test]
    fn fuzz_picture_random_small_images((w, h, pixels) in picture()) {
        check_picture(&png_bytes(w, h, &pixels));
    }

    #[test]
    fn fuzz_picture_bytes_changed_or_cut(
        (w, h, pixels) in picture(),
        changes in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        cut_it in any::<bool>(),
    ) {
        let mut bytes = png_bytes(w, h, &pixels);
        for (at, byte) in changes {
            let i = at.index(bytes.len());
            bytes[i] = byte;
        }
        if cut_it {
            bytes.truncate(cut.index(bytes.len()));
        }
        check_picture(&bytes);
    }

    #[test]
    fn fuzz_mesh_json_deep_nesting(depth in 1usize..5000) {
        check_mesh(&format!("{{\"vertices\": {}}}", fuzz::deep("[", "0", "]", depth)));
        check_shape(&format!("{{\"outer\": {}}}", fuzz::deep("[", "0", "]", depth)));
    }
}
