//! Fuzzing the mesh and polygon JSON readers, which read files a user hands
//! to `puppetry mesh` and the stage: random text plus valid documents with
//! fields mutated (NaN, huge and negative numbers, wrong types, deep nests,
//! dropped and unknown keys). Every case must end in a value or an error
//! naming the file; a shape that validates must also mesh or fail cleanly.
//! See `docs/fuzzing.md`.

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
    fn fuzz_mesh_json_deep_nesting(depth in 1usize..5000) {
        check_mesh(&format!("{{\"vertices\": {}}}", fuzz::deep("[", "0", "]", depth)));
        check_shape(&format!("{{\"outer\": {}}}", fuzz::deep("[", "0", "]", depth)));
    }
}
