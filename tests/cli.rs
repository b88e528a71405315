//! The command line as a user meets it: `puppetry solve` gives the solver's
//! exact answer, `puppetry mesh` meshes the demo puppet, and every bad input
//! fails with a message naming the file, the field or line, and the problem.

mod common;

use std::path::PathBuf;
use std::process::{Command, Output};

use glam::DVec2;
use puppetry::deform::Anchor;
use puppetry::mesh::Mesh;
use tempfile::TempDir;

fn puppetry(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .args(args)
        .output()
        .expect("run puppetry")
}

/// A scratch file with these contents in the test's own temporary
/// directory (removed when the test ends).
fn scratch(dir: &TempDir, name: &str, contents: &[u8]) -> PathBuf {
    let path = dir.path().join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

fn parse_vertices(stdout: &[u8]) -> Vec<DVec2> {
    let value: serde_json::Value = serde_json::from_slice(stdout).expect("solve prints JSON");
    value["vertices"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| DVec2::new(p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
        .collect()
}

#[test]
fn solve_prints_the_dense_least_squares_answer() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = common::jittered(7, 4);
    let mesh_path = scratch(&dir, "solve.mesh.json", mesh.to_json().as_bytes());
    let point = DVec2::new(6.3, 3.6);
    let handles = format!(
        r#"{{"handles": [{{"vertex": 0, "to": [-1, 0]}}, {{"point": [{}, {}], "to": [9, 6]}}]}}"#,
        point.x, point.y
    );
    let handles_path = scratch(&dir, "solve.handles.json", handles.as_bytes());
    let loc = puppetry::mesh::Locator::new(&mesh)
        .locate(&mesh, point)
        .unwrap();
    let anchors = [
        Anchor::Vertex(0),
        Anchor::Point {
            triangle: loc.triangle,
            bary: loc.bary,
        },
    ];
    let targets = [DVec2::new(-1.0, 0.0), DVec2::new(9.0, 6.0)];
    let (step1, both) = common::dense_reference(&mesh, &anchors, &targets);
    let tol = 1e-9 * mesh.size();
    let m = mesh_path.to_str().unwrap();
    let h = handles_path.to_str().unwrap();
    let out = puppetry(&["solve", "--mesh", m, "--handles", h]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(common::max_distance(&parse_vertices(&out.stdout), &both) < tol);
    let out = puppetry(&["solve", "--mesh", m, "--handles", h, "--step1-only"]);
    assert!(out.status.success());
    assert!(common::max_distance(&parse_vertices(&out.stdout), &step1) < tol);
}

#[test]
fn mesh_builds_the_demo_puppet_and_solve_runs_it() {
    let dir = tempfile::tempdir().unwrap();
    let demo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/gingerbread");
    let out_path = scratch(&dir, "demo.mesh.json", b"");
    let out = puppetry(&[
        "mesh",
        demo.join("gingerbread.png").to_str().unwrap(),
        "--vertices",
        "1500",
        "-o",
        out_path.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mesh = Mesh::load(&out_path).unwrap();
    let n = mesh.vertices().len();
    assert!(
        (1275..=1725).contains(&n),
        "{n} vertices for a target of 1500"
    );
    assert!(
        mesh.uv().is_some(),
        "a mesh from a picture carries texture coordinates"
    );
    // The bundled mesh and handles (the README's demo) solve, and the dragged
    // hand moves while the pinned feet stay.
    let out = puppetry(&[
        "solve",
        "--mesh",
        demo.join("gingerbread.mesh.json").to_str().unwrap(),
        "--handles",
        demo.join("handles.json").to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bundled = Mesh::load(&demo.join("gingerbread.mesh.json")).unwrap();
    let pose = parse_vertices(&out.stdout);
    assert_eq!(pose.len(), bundled.vertices().len());
    let moved = pose
        .iter()
        .zip(bundled.vertices())
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max);
    assert!(moved > 40.0, "the dragged hand moved {moved}");
}

/// Runs puppetry, expects failure, and returns its error message.
fn failure(args: &[&str]) -> String {
    let out = puppetry(args);
    assert!(!out.status.success(), "expected failure for {args:?}");
    let message = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!message.contains("panicked"), "panicked: {message}");
    message
}

fn solve_failure(dir: &TempDir, mesh_json: &str, handles_json: &str) -> String {
    let m = scratch(dir, "bad.mesh.json", mesh_json.as_bytes());
    let h = scratch(dir, "bad.handles.json", handles_json.as_bytes());
    failure(&[
        "solve",
        "--mesh",
        m.to_str().unwrap(),
        "--handles",
        h.to_str().unwrap(),
    ])
}

const SQUARE: &str = r#"{"vertices": [[0,0],[1,0],[1,1],[0,1]], "triangles": [[0,1,2],[0,2,3]]}"#;
const NO_HANDLES: &str = r#"{"handles": []}"#;

#[test]
fn bad_meshes_are_named_and_explained() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, &[&str])] = &[
        (
            "{\"vertices\": [[0,0],[1,0]\n,[1,1]], \"triangles\": [[0,1,2]]",
            &["bad.mesh.json", "line 2"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,7]]}"#,
            &["triangles[0]", "out of range"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,1]]}"#,
            &["triangles[0]", "repeats"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[2,0]], "triangles": [[0,1,2]]}"#,
            &["triangles[0]", "zero area"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,2,1]]}"#,
            &["triangles[0]", "clockwise"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1],[5,5]], "triangles": [[0,1,2]]}"#,
            &["vertices[3]", "not used"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1e999]], "triangles": [[0,1,2]]}"#,
            &["bad.mesh.json", "line 1"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,-2]]}"#,
            &["bad.mesh.json", "line 1"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,2]], "weights": [0]}"#,
            &["weights[0]"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,2]], "colour": 1}"#,
            &["unknown field"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1,0]], "triangles": [[0,1,2]]}"#,
            &["line 1", "expected a point [x, y], got 3"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,2,0]]}"#,
            &["expected a triangle [i, j, k]"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1e300]], "triangles": [[0,1,2]]}"#,
            &["vertices[2]", "[1, 1e300]", "too far out"],
        ),
        (
            r#"{"vertices": [[0,0],[1000,0],[500,0.1]], "triangles": [[0,1,2]]}"#,
            &["triangles[0]", "too thin"],
        ),
        (
            r#"{"vertices": [[0,0],[1,0],[1,1]], "triangles": [[0,1,2]], "weights": [1e-300]}"#,
            &["weights[0]", "between"],
        ),
        ("\"my puppet\"", &["a mesh object"]),
    ];
    for (mesh, expected) in cases {
        let message = solve_failure(&dir, mesh, NO_HANDLES);
        for e in *expected {
            assert!(
                message.contains(e),
                "for {mesh}: expected {e:?} in {message:?}"
            );
        }
    }
}

#[test]
fn bad_handles_are_named_and_explained() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, &[&str])] = &[
        (
            r#"{"handles": [{"point": [5, 5], "to": [0, 0]}]}"#,
            &["handles[0].point", "outside the mesh"],
        ),
        (
            r#"{"handles": [{"vertex": 0, "to": [0, 0]}, {"vertex": 9, "to": [0, 0]}]}"#,
            &["handles[1].vertex", "out of range"],
        ),
        (
            r#"{"handles": [{"vertex": 0, "point": [0.5, 0.5], "to": [0, 0]}]}"#,
            &["handles[0]", "not both"],
        ),
        (r#"{"handles": [{"to": [0, 0]}]}"#, &["handles[0]", "needs"]),
        (
            r#"{"handles": [{"vertex": 0}]}"#,
            &["bad.handles.json", "to"],
        ),
        (
            "{\"handles\": [\n{\"vertex\": 0, \"to\": [0, 0]},\n]}",
            &["bad.handles.json", "line 3"],
        ),
    ];
    for (handles, expected) in cases {
        let message = solve_failure(&dir, SQUARE, handles);
        for e in *expected {
            assert!(
                message.contains(e),
                "for {handles}: expected {e:?} in {message:?}"
            );
        }
    }
}

#[test]
fn bad_mesh_inputs_are_named_and_explained() {
    let dir = tempfile::tempdir().unwrap();
    let crossing = scratch(
        &dir,
        "bowtie.json",
        br#"{"outer": [[0,0],[10,10],[10,0],[0,10]]}"#,
    );
    let message = failure(&["mesh", crossing.to_str().unwrap()]);
    assert!(
        message.contains("bowtie.json") && message.contains("outer"),
        "{message}"
    );
    assert!(message.contains("cross"), "{message}");

    // A valid PNG whose pixels are all transparent.
    let mut png_bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut png_bytes, 8, 8);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&[0u8; 8 * 8 * 4]).unwrap();
    }
    let clear = scratch(&dir, "clear.png", &png_bytes);
    let message = failure(&["mesh", clear.to_str().unwrap()]);
    assert!(
        message.contains("clear.png") && message.contains("opaque"),
        "{message}"
    );

    let not_png = scratch(&dir, "fake.png", b"GIF89a not a png at all");
    let message = failure(&["mesh", not_png.to_str().unwrap()]);
    assert!(message.contains("fake.png"), "{message}");

    let missing = failure(&["mesh", "/nonexistent/puppet.png"]);
    assert!(missing.contains("/nonexistent/puppet.png"), "{missing}");

    let picture_as_json = scratch(&dir, "picture.json", &png_bytes);
    let message = failure(&["mesh", picture_as_json.to_str().unwrap()]);
    assert!(
        message.contains("picture.json") && message.contains("not UTF-8"),
        "{message}"
    );

    let sliver = scratch(
        &dir,
        "sliver.json",
        br#"{"outer": [[0,0],[1000,0],[500,0.001]]}"#,
    );
    let message = failure(&["mesh", sliver.to_str().unwrap()]);
    assert!(
        message.contains("sliver.json") && message.contains("too thin"),
        "{message}"
    );

    let message = failure(&["mesh", crossing.to_str().unwrap(), "--vertices", "0"]);
    assert!(message.contains("--vertices"), "{message}");
}

#[test]
fn a_byte_order_mark_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = scratch(
        &dir,
        "bom.mesh.json",
        format!("\u{feff}{SQUARE}").as_bytes(),
    );
    let handles = scratch(
        &dir,
        "bom.handles.json",
        format!("\u{feff}{NO_HANDLES}").as_bytes(),
    );
    let out = puppetry(&[
        "solve",
        "--mesh",
        mesh.to_str().unwrap(),
        "--handles",
        handles.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
