//! The command line as a user meets it: `puppetry solve` gives the solver's
//! exact answer, `puppetry mesh` meshes the demo puppet, and every bad input
//! fails with a message naming the file, the field or line, and the problem.

use std::path::PathBuf;
use std::process::{Command, Output};

use glam::DVec2;
use puppetry_deform::Anchor;
use puppetry_mesh::Mesh;
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
    let mesh = crate::common::jittered(7, 4);
    let mesh_path = scratch(&dir, "solve.mesh.json", mesh.to_json().as_bytes());
    let point = DVec2::new(6.3, 3.6);
    let handles = format!(
        r#"{{"handles": [{{"vertex": 0, "to": [-1, 0]}}, {{"point": [{}, {}], "to": [9, 6]}}]}}"#,
        point.x, point.y
    );
    let handles_path = scratch(&dir, "solve.handles.json", handles.as_bytes());
    let loc = puppetry_mesh::Locator::new(&mesh)
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
    let (step1, both) = crate::common::dense_reference(&mesh, &anchors, &targets);
    let tol = 1e-9 * mesh.size();
    let m = mesh_path.to_str().unwrap();
    let h = handles_path.to_str().unwrap();
    let out = puppetry(&["solve", "--mesh", m, "--handles", h]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(crate::common::max_distance(&parse_vertices(&out.stdout), &both) < tol);
    let out = puppetry(&["solve", "--mesh", m, "--handles", h, "--step1-only"]);
    assert!(out.status.success());
    assert!(crate::common::max_distance(&parse_vertices(&out.stdout), &step1) < tol);
}

#[test]
fn mesh_builds_the_demo_puppet_and_solve_runs_it() {
    let dir = tempfile::tempdir().unwrap();
    let demo = puppetry_testkit::root().join("assets/gingerbread");
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

/// Issue 45: a picture with a head drawn 4 pixels off its body meshed into
/// two pieces with nothing said, and the head floated off. `puppetry mesh`
/// says how many pieces and the join that makes them one, draws the pieces
/// beside the mesh, and `--join` makes one piece.
#[test]
fn mesh_says_a_picture_is_in_pieces_draws_them_and_joins_them() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (200u32, 200u32);
    let mut png_bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut png_bytes, w, h);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        let inside = |x: f64, y: f64, cx: f64, cy: f64, r: f64| (x - cx).hypot(y - cy) <= r;
        let pixels: Vec<u8> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x as f64 + 0.5, y as f64 + 0.5)))
            .flat_map(|(x, y)| {
                // A head of radius 25 four pixels above a body of radius 60.
                if inside(x, y, 100.0, 130.0, 60.0) || inside(x, y, 100.0, 41.0, 25.0) {
                    [200, 60, 30, 255]
                } else {
                    [0, 0, 0, 0]
                }
            })
            .collect();
        writer.write_image_data(&pixels).unwrap();
    }
    let picture = scratch(&dir, "figure.png", &png_bytes);
    let out = puppetry(&["mesh", picture.to_str().unwrap(), "--vertices", "400"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    assert!(said.contains("2 separate pieces"), "{said}");
    assert!(said.contains("2 piece(s)"), "{said}");
    let svg = std::fs::read_to_string(dir.path().join("figure.pieces.svg")).unwrap();
    assert_eq!(svg.matches("<path").count(), 2, "one shape per piece");
    let gap: u32 = said
        .split("--join ")
        .nth(1)
        .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no join in {said}"));
    let joined = scratch(&dir, "joined.mesh.json", b"");
    let out = puppetry(&[
        "mesh",
        picture.to_str().unwrap(),
        "--vertices",
        "400",
        "--join",
        &gap.to_string(),
        "-o",
        joined.to_str().unwrap(),
    ]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    assert!(!said.contains("separate pieces"), "{said}");
    assert_eq!(Mesh::load(&joined).unwrap().pieces().len(), 1);
    assert!(!dir.path().join("joined.pieces.svg").exists());
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

    // A PNG by any name is meshed as a picture (this one is all clear).
    let picture_as_json = scratch(&dir, "picture.json", &png_bytes);
    let message = failure(&["mesh", picture_as_json.to_str().unwrap()]);
    assert!(
        message.contains("picture.json") && message.contains("opaque"),
        "{message}"
    );
    let binary = scratch(&dir, "binary.json", b"{\xff\xfe\x00 not text");
    let message = failure(&["mesh", binary.to_str().unwrap()]);
    assert!(
        message.contains("binary.json") && message.contains("not UTF-8"),
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

/// The bundled layered figure and its scenario, loaded through the library.
fn layered_figure() -> (Mesh, Vec<Anchor>, Vec<DVec2>) {
    let dir = puppetry_testkit::root().join("assets/gingerbread-layers");
    let (mesh_path, handles_path) = (
        dir.join("gingerbread-layers.mesh.json"),
        dir.join("handles.json"),
    );
    let mesh = Mesh::load(&mesh_path).unwrap();
    let text = std::fs::read_to_string(&handles_path).unwrap();
    let (anchors, targets) = puppetry::cli::parse_handles("handles.json", &text, &mesh).unwrap();
    (mesh, anchors, targets)
}

const METHODS: [&str; 4] = [
    puppetry_bench::compare::DIRECT_FFD,
    puppetry_bench::compare::ARAP_INVERSE_FFD,
    puppetry_bench::compare::PLAIN_ARAP,
    puppetry_bench::compare::LP_FFD,
];

#[test]
fn compare_prints_all_four_methods_on_the_layered_figure() {
    let (mesh, _, _) = layered_figure();
    assert!(
        mesh.pieces().len() >= 6,
        "the figure is made of separate layers"
    );
    let out = puppetry(&["compare"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("10×10 grid"), "{table}");
    for method in METHODS {
        let row = table
            .lines()
            // Names are padded to a column: "ARAP" must not take the
            // "ARAP + inverse FFD" row.
            .find(|l| l.starts_with(&format!("{method}  ")))
            .unwrap_or_else(|| panic!("no row for {method} in {table}"));
        let numbers: Vec<f64> = row[method.len()..]
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        assert_eq!(numbers.len(), 3, "{row}");
        assert!(numbers.iter().all(|x| x.is_finite() && *x >= 0.0), "{row}");
    }

    let out = puppetry(&["compare", "--json", "--grid", "6x8"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let value: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(value["grid_columns"], 6);
    assert_eq!(value["grid_rows"], 8);
    assert_eq!(
        value["vertices"].as_u64().unwrap() as usize,
        mesh.vertices().len()
    );
    let methods = value["methods"].as_array().unwrap();
    let names: Vec<&str> = methods
        .iter()
        .map(|m| m["method"].as_str().unwrap())
        .collect();
    assert_eq!(names, METHODS);
    for m in methods {
        for field in ["angular", "area", "handle_error"] {
            let x = m[field].as_f64().unwrap();
            assert!(x.is_finite() && x >= 0.0, "{field} of {m}");
        }
        // Every method really deformed the figure.
        assert!(m["angular"].as_f64().unwrap() > 0.0, "{m}");
    }
    // ARAP takes its handles as hard constraints; the grid methods only
    // approximately, but within a few percent of the figure.
    let size = mesh.size();
    for m in methods {
        let error = m["handle_error"].as_f64().unwrap();
        if m["method"] == puppetry_bench::compare::PLAIN_ARAP {
            assert!(error < 1e-9 * size, "{m}");
        } else {
            assert!(error < 0.05 * size, "{m}");
        }
    }
}

#[test]
fn arap_plus_inverse_ffd_is_the_grid_fit_of_the_arap_result() {
    use puppetry_deform::ffd::{Basis, GridSpec, LpFfd, LpParams};
    use puppetry_deform::{Arap, Steps};

    let (mesh, anchors, targets) = layered_figure();
    let comparison = puppetry_bench::compare::compare(&mesh, &anchors, &targets, 10, 10).unwrap();
    let by_name = |name| {
        comparison
            .methods
            .iter()
            .find(|m| m.method == name)
            .unwrap()
    };
    // The ARAP row is the ARAP solver's answer.
    let mut arap = Arap::register(&mesh).unwrap();
    arap.compile(&anchors).unwrap();
    let arap_pose = arap.update(&targets, Steps::Both).unwrap().to_vec();
    let plain = by_name(puppetry_bench::compare::PLAIN_ARAP);
    assert!(crate::common::max_distance(&plain.pose, &arap_pose) < 1e-9 * mesh.size());

    // The fitted grid satisfies the normal equations of
    // λ_mp Σ_v |W_v P − a_v|² + λ_gr Σ_k |P_k − P⁰_k|², with W's columns
    // read off plain FFD by moving one grid handle at a time.
    let fitted = by_name(puppetry_bench::compare::ARAP_INVERSE_FFD);
    let grid = fitted.grid.clone().expect("a grid method");
    let params = LpParams::default();
    let rig = LpFfd::register(
        &mesh,
        GridSpec::around(&mesh, 10, 10, Basis::Bernstein),
        params,
    )
    .unwrap();
    let fitted_pose = rig.deform_with_grid(&grid).unwrap();
    assert!(crate::common::max_distance(&fitted.pose, &fitted_pose) < 1e-9 * mesh.size());
    let rest_grid = rig.rest_grid().to_vec();
    let gradient = |p: &[DVec2]| -> Vec<DVec2> {
        let pose = rig.deform_with_grid(p).unwrap();
        (0..rest_grid.len())
            .map(|k| {
                let mut nudged = rest_grid.clone();
                nudged[k].x += 1.0;
                let column = rig.deform_with_grid(&nudged).unwrap();
                let mut g = (p[k] - rest_grid[k]) * params.regular;
                for ((c, r), (v, a)) in column
                    .iter()
                    .zip(mesh.vertices())
                    .zip(pose.iter().zip(&arap_pose))
                {
                    g += (*v - *a) * ((c.x - r.x) * params.vertex);
                }
                g
            })
            .collect()
    };
    let norm = |g: &[DVec2]| g.iter().map(|x| x.length_squared()).sum::<f64>().sqrt();
    let at_rest = norm(&gradient(&rest_grid));
    let at_fit = norm(&gradient(&grid));
    assert!(at_rest > 0.0);
    assert!(
        at_fit < 1e-8 * at_rest,
        "gradient {at_fit} at the fit, {at_rest} at rest"
    );
    // And the fit is not the ARAP pose itself: the grid cannot follow
    // separate pieces moving on their own.
    assert!(crate::common::max_distance(&fitted_pose, &arap_pose) > 1e-3 * mesh.size());
}

#[test]
fn compare_runs_on_a_figure_of_your_own() {
    let dir = tempfile::tempdir().unwrap();
    // Two overlapping bars, each a piece of its own with two handles.
    let (mut vertices, mut triangles) = crate::common::grid(8, 2, 8.0, 2.0, DVec2::ZERO);
    let (v, t) = crate::common::grid(2, 6, 2.0, 6.0, DVec2::new(3.0, -2.0));
    let base = vertices.len() as u32;
    vertices.extend(v);
    triangles.extend(t.into_iter().map(|tri| tri.map(|x| x + base)));
    let mesh = Mesh::new("cross", vertices, triangles, None, None).unwrap();
    assert_eq!(mesh.pieces().len(), 2);
    let mesh_path = scratch(&dir, "cross.mesh.json", mesh.to_json().as_bytes());
    let last = base - 1;
    let handles = format!(
        r#"{{"handles": [{{"vertex": 0, "to": [0, 0]}}, {{"vertex": {last}, "to": [7, 4]}},
            {{"vertex": {base}, "to": [3, -2]}}, {{"vertex": {}, "to": [6, 2]}}]}}"#,
        mesh.vertices().len() - 1
    );
    let handles_path = scratch(&dir, "cross.handles.json", handles.as_bytes());
    let out = puppetry(&[
        "compare",
        "--mesh",
        mesh_path.to_str().unwrap(),
        "--handles",
        handles_path.to_str().unwrap(),
        "--grid",
        "4x4",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let value: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(value["pieces"], 2);
    assert_eq!(value["handles"], 4);
    assert_eq!(value["methods"].as_array().unwrap().len(), 4);
}

#[test]
fn bad_compare_inputs_are_named_and_explained() {
    let dir = tempfile::tempdir().unwrap();
    for (grid, expected) in [
        ("1x5", "at least 2"),
        ("ten", "COLUMNSxROWS"),
        ("10x", "COLUMNSxROWS"),
        ("100x100", "more than"),
    ] {
        let message = failure(&["compare", "--grid", grid]);
        assert!(
            message.contains("--grid") && message.contains(expected),
            "{grid}: {message}"
        );
    }
    let mesh = scratch(&dir, "square.mesh.json", SQUARE.as_bytes());
    let m = mesh.to_str().unwrap();
    let handles = scratch(
        &dir,
        "far.handles.json",
        br#"{"handles": [{"vertex": 7, "to": [0, 0]}]}"#,
    );
    let message = failure(&[
        "compare",
        "--mesh",
        m,
        "--handles",
        handles.to_str().unwrap(),
    ]);
    assert!(
        message.contains("far.handles.json") && message.contains("handles[0].vertex"),
        "{message}"
    );
    let broken = scratch(&dir, "broken.mesh.json", b"{\"vertices\": [");
    let message = failure(&[
        "compare",
        "--mesh",
        broken.to_str().unwrap(),
        "--handles",
        handles.to_str().unwrap(),
    ]);
    assert!(message.contains("broken.mesh.json"), "{message}");
    let message = failure(&[
        "compare",
        "--mesh",
        m,
        "--handles",
        "/nonexistent/handles.json",
    ]);
    assert!(message.contains("/nonexistent/handles.json"), "{message}");
    let message = failure(&["compare", "--mesh", m]);
    assert!(message.contains("--handles"), "{message}");
}

#[test]
fn the_rig_bench_runs_both_rigs() {
    let out = puppetry(&["bench", "--rigs", "--sizes", "300", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cases: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let rigs: Vec<&str> = cases.iter().map(|c| c["rig"].as_str().unwrap()).collect();
    assert_eq!(rigs, ["lp-ffd", "lp-ffd", "skeleton"]);
    assert_eq!(cases[0]["basis"], "bernstein");
    assert_eq!(cases[1]["basis"], "lattice");
    assert_eq!(cases[2]["bones"], 15);
    for c in &cases {
        assert!(c["frames"].as_u64().unwrap() > 0, "{c}");
        let vertices = c["vertices"].as_u64().unwrap();
        assert!((200..=400).contains(&vertices), "{c}");
        for field in ["update_us_median", "update_us_p99", "update_us_min"] {
            let x = c[field].as_f64().unwrap();
            assert!(x.is_finite() && x > 0.0, "{field} of {c}");
        }
    }
    for c in &cases[..2] {
        assert_eq!(c["grid_columns"], 10);
        assert_eq!(c["grid_rows"], 10);
    }

    let out = puppetry(&["bench", "--rigs", "--sizes", "300"]);
    assert!(out.status.success());
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.lines().any(|l| l.starts_with("lp-FFD")), "{table}");
    assert!(table.lines().any(|l| l.starts_with("skeleton")), "{table}");
}

#[test]
fn the_lp_ffd_row_minimises_the_lp_ffd_energy() {
    use puppetry_deform::ffd::{Basis, GridSpec, LpFfd, LpParams};

    let (mesh, anchors, targets) = layered_figure();
    let comparison = puppetry_bench::compare::compare(&mesh, &anchors, &targets, 10, 10).unwrap();
    let grid_of = |name| {
        comparison
            .methods
            .iter()
            .find(|m| m.method == name)
            .unwrap()
            .grid
            .clone()
            .unwrap()
    };
    let mut rig = LpFfd::register(
        &mesh,
        GridSpec::around(&mesh, 10, 10, Basis::Bernstein),
        LpParams::default(),
    )
    .unwrap();
    rig.compile(&anchors, &[]).unwrap();
    let energy = |grid: &[DVec2]| rig.energy(grid, &targets, &[]).unwrap();
    let best = energy(&grid_of(puppetry_bench::compare::LP_FFD));
    for other in [
        puppetry_bench::compare::DIRECT_FFD,
        puppetry_bench::compare::ARAP_INVERSE_FFD,
    ] {
        let e = energy(&grid_of(other));
        assert!(best < e, "lp-FFD {best}, {other} {e}");
    }
    // A local minimum: nudging any grid handle a little costs energy.
    let grid = grid_of(puppetry_bench::compare::LP_FFD);
    let step = 1e-3 * mesh.size();
    for k in (0..grid.len()).step_by(7) {
        for d in [DVec2::X, DVec2::Y, -DVec2::X, -DVec2::Y] {
            let mut nudged = grid.clone();
            nudged[k] += d * step;
            assert!(energy(&nudged) >= best, "handle {k} nudged by {d}");
        }
    }
}

#[test]
fn a_fully_opaque_picture_meshes_as_its_rectangle_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    // A photo-like picture: RGB, no alpha channel at all.
    let mut png_bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut png_bytes, 40, 30);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&[200u8; 40 * 30 * 3]).unwrap();
    }
    let photo = scratch(&dir, "photo.png", &png_bytes);
    let out_path = dir.path().join("photo.mesh.json");
    let out = puppetry(&[
        "mesh",
        photo.to_str().unwrap(),
        "-o",
        out_path.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let warning = stderr
        .lines()
        .find(|l| l.starts_with("warning: "))
        .unwrap_or_else(|| panic!("no warning for an opaque picture:\n{stderr}"));
    assert!(
        warning.contains("photo.png")
            && warning.contains("opaque")
            && warning.contains("40×30 rectangle"),
        "{warning}"
    );
    let mesh = Mesh::load(&out_path).unwrap();
    assert!(mesh.vertices().len() > 4, "still meshed");

    // The demo puppet has a transparent background: no warning.
    let demo = puppetry_testkit::root().join("assets/gingerbread/gingerbread.png");
    let out = puppetry(&[
        "mesh",
        demo.to_str().unwrap(),
        "--vertices",
        "200",
        "-o",
        dir.path().join("demo.mesh.json").to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
}

/// The first bytes of a JPEG (JFIF) file and a little more.
const JPEG: &[u8] = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00\xff\xdb";

#[test]
fn a_jpeg_is_named_with_what_is_taken_instead() {
    let dir = tempfile::tempdir().unwrap();
    let photo = scratch(&dir, "photo.jpg", JPEG);
    // Where a picture is meshed, by either name.
    let disguised = scratch(&dir, "disguised.png", JPEG);
    for picture in [&photo, &disguised] {
        let message = failure(&["mesh", picture.to_str().unwrap()]);
        assert!(
            message.contains(picture.to_str().unwrap())
                && message.contains("JPEG picture")
                && message.contains("PNG picture")
                && message.contains("polygon .json"),
            "{message}"
        );
        assert!(!message.contains("UTF-8"), "{message}");
    }
    // Where a mesh is expected.
    let handles = scratch(&dir, "h.json", NO_HANDLES.as_bytes());
    let message = failure(&[
        "solve",
        "--mesh",
        photo.to_str().unwrap(),
        "--handles",
        handles.to_str().unwrap(),
    ]);
    assert!(
        message.contains("photo.jpg")
            && message.contains("JPEG picture")
            && message.contains(".mesh.json")
            && message.contains("puppetry mesh"),
        "{message}"
    );
    // Where a handles file is expected.
    let mesh = scratch(&dir, "square.mesh.json", SQUARE.as_bytes());
    let message = failure(&[
        "solve",
        "--mesh",
        mesh.to_str().unwrap(),
        "--handles",
        photo.to_str().unwrap(),
    ]);
    assert!(
        message.contains("photo.jpg")
            && message.contains("JPEG picture")
            && message.contains("JSON"),
        "{message}"
    );
    // As a puppet's picture or mesh in a stage file.
    let assets = puppetry_testkit::root().join("assets/gingerbread");
    let real_mesh = assets.join("gingerbread.mesh.json");
    let real_image = assets.join("gingerbread.png");
    for (image, mesh, field, says) in [
        (&photo, &real_mesh, "puppet[0].image", "must be a PNG"),
        (&real_image, &photo, "puppet[0].mesh", ".mesh.json"),
    ] {
        let stage = dir.path().join("stage.toml");
        std::fs::write(
            &stage,
            format!(
                "[stage]\nwidth = 1280\nheight = 720\n[[puppet]]\nname = \"g\"\nimage = \"{}\"\nmesh = \"{}\"\nat = [640, 360]\n",
                image.display(),
                mesh.display()
            ),
        )
        .unwrap();
        let message = failure(&[
            "takes",
            dir.path().to_str().unwrap(),
            "--verify",
            "--config",
            stage.to_str().unwrap(),
        ]);
        assert!(
            message.contains("stage.toml")
                && message.contains(field)
                && message.contains("JPEG picture")
                && message.contains(says),
            "{message}"
        );
    }
}

/// A small PNG: an opaque disc on a clear square.
fn disc_png() -> Vec<u8> {
    let size = 64u32;
    let mut pixels = Vec::new();
    for y in 0..size {
        for x in 0..size {
            let (dx, dy) = (x as f64 - 31.5, y as f64 - 31.5);
            let alpha = if dx * dx + dy * dy < 28.0 * 28.0 {
                255
            } else {
                0
            };
            pixels.extend([200, 120, 40, alpha]);
        }
    }
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, size, size);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(&pixels).unwrap();
    drop(writer);
    bytes
}

#[test]
fn mesh_without_an_output_writes_beside_the_picture_and_never_replaces() {
    let dir = tempfile::tempdir().unwrap();
    let picture = scratch(&dir, "disc.png", &disc_png());
    let beside = dir.path().join("disc.mesh.json");
    let args = ["mesh", picture.to_str().unwrap(), "--vertices", "100"];
    let out = puppetry(&args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(out.stdout.is_empty(), "nothing on standard output");
    let mesh = Mesh::load(&beside).unwrap();
    assert!(mesh.vertices().len() > 10);
    assert!(
        stderr.contains(beside.to_str().unwrap()),
        "says where it wrote: {stderr}"
    );
    // Again: the mesh beside it may be one a stage uses, so it stays.
    std::fs::write(&beside, "kept").unwrap();
    let message = failure(&args);
    assert!(
        message.contains("disc.mesh.json") && message.contains("-o"),
        "{message}"
    );
    assert_eq!(std::fs::read_to_string(&beside).unwrap(), "kept");
    // `-o -` is standard output; `-o FILE` replaces FILE.
    let out = puppetry(&["mesh", picture.to_str().unwrap(), "-o", "-"]);
    assert!(out.status.success());
    let printed: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(printed["vertices"].as_array().is_some_and(|v| v.len() > 10));
    let out = puppetry(&[
        "mesh",
        picture.to_str().unwrap(),
        "-o",
        beside.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    Mesh::load(&beside).unwrap();
}

/// `puppetry serve ARGS` run until it has printed its URLs: its standard
/// output to there, and its standard error once it is stopped.
fn serve_until_ready(args: &[&str], env: &[(&str, &str)]) -> (String, String) {
    serve_and(args, env, |_| {})
}

/// [`serve_until_ready`], calling `meanwhile` with the standard output
/// while the daemon still runs.
fn serve_and(
    args: &[&str],
    env: &[(&str, &str)],
    meanwhile: impl FnOnce(&str),
) -> (String, String) {
    use std::io::{BufRead, BufReader, Read};
    use std::process::Stdio;
    let mut command = Command::new(env!("CARGO_BIN_EXE_puppetry"));
    command
        .arg("serve")
        .args(args)
        .env_remove("NO_COLOR")
        .env_remove("RUST_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (key, value) in env {
        command.env(key, value);
    }
    let mut child = command.spawn().unwrap();
    let stdout = child.stdout.take().unwrap();
    let (said, heard) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut text = String::new();
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            text.push_str(&line);
            text.push('\n');
            if line.contains("stop with Ctrl-C") {
                break;
            }
        }
        let _ = said.send(text);
    });
    let stdout = heard.recv_timeout(std::time::Duration::from_secs(120));
    if let Ok(stdout) = &stdout {
        meanwhile(stdout);
    }
    let _ = child.kill();
    let _ = child.wait();
    let mut stderr = String::new();
    let _ = child.stderr.take().unwrap().read_to_string(&mut stderr);
    let stdout = stdout.unwrap_or_else(|_| panic!("serve {args:?} never said it serves: {stderr}"));
    (stdout, stderr)
}

/// The address in `serve`'s first line, `… at http://ADDRESS/`.
fn served_at(stdout: &str) -> std::net::SocketAddr {
    let first = stdout.lines().next().unwrap_or_default();
    let address = first
        .split(" at http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .unwrap_or_else(|| panic!("no URL in {stdout:?}"));
    address
        .parse()
        .unwrap_or_else(|_| panic!("{address:?} in {stdout:?}"))
}

/// The addresses `serve` printed for other machines to use.
fn network_urls(stdout: &str) -> Vec<std::net::SocketAddr> {
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("  from other machines: "))
        .unwrap_or_default();
    line.split_whitespace()
        .filter_map(|url| url.strip_prefix("http://")?.strip_suffix('/')?.parse().ok())
        .collect()
}

/// A stage file of the demo puppet whose anonymous performers' token is
/// `token`.
fn stage_with_token(dir: &TempDir, token: &str) -> PathBuf {
    let text =
        crate::common::daemon::stage_text("").replace("[\"secret\"]", &format!("[\"{token}\"]"));
    scratch(dir, &format!("{token}.toml"), text.as_bytes())
}

#[test]
fn listen_takes_a_host_name_or_a_bare_port() {
    let dir = tempfile::tempdir().unwrap();
    let stage = stage_with_token(&dir, "secret");
    let stage = stage.to_str().unwrap();
    for listen in ["localhost:0", "0"] {
        let (stdout, stderr) = serve_until_ready(&["--config", stage, "--listen", listen], &[]);
        let address = served_at(&stdout);
        assert!(
            address.ip().is_loopback() && address.port() != 0,
            "{listen}: {stdout}"
        );
        assert!(!stderr.contains("WARN"), "{listen}: {stderr}");
    }
    for (listen, says) in [
        ("no-such-host.invalid:8080", "no-such-host.invalid"),
        ("localhost", "HOST:PORT"),
        ("localhost:http", "not a port"),
    ] {
        let message = failure(&["serve", "--config", stage, "--listen", listen]);
        assert!(message.contains(says), "{listen}: {message}");
    }
}

#[test]
fn listening_on_every_interface_prints_a_usable_url_and_warns_of_demo_tokens() {
    let dir = tempfile::tempdir().unwrap();
    // Tokens of one's own: usable URLs, no warning.
    let own = stage_with_token(&dir, "secret");
    let args = ["--config", own.to_str().unwrap(), "--listen", "0.0.0.0:0"];
    let (stdout, stderr) = serve_and(&args, &[], |stdout| {
        std::net::TcpStream::connect(served_at(stdout)).expect("the printed URL opens");
        // So does every address it prints for other machines.
        for url in network_urls(stdout) {
            std::net::TcpStream::connect(url).expect("the printed network address opens");
        }
    });
    let address = served_at(&stdout);
    assert_eq!(address.ip(), std::net::Ipv4Addr::LOCALHOST, "{stdout}");
    assert!(
        stdout.contains("all interfaces") && !stdout.contains("0.0.0.0/"),
        "{stdout}"
    );
    assert!(
        stdout.contains("  from other machines: "),
        "no network addresses: {stdout}"
    );
    assert!(
        stdout.contains(&format!("http://{address}/?view=show")),
        "no show view: {stdout}"
    );
    assert!(
        stdout.contains(&format!("http://{address}/?role=performer&token=secret")),
        "{stdout}"
    );
    assert!(!stderr.contains("demo tokens"), "{stderr}");
    // The bundled demo's token: a loud warning, in plain text when stderr
    // is not a terminal (a log file, here a pipe).
    let demo = stage_with_token(&dir, "demo");
    let (stdout, stderr) = serve_until_ready(
        &["--config", demo.to_str().unwrap(), "--listen", "0.0.0.0:0"],
        &[],
    );
    served_at(&stdout);
    let warning = stderr
        .lines()
        .find(|l| l.contains("demo tokens"))
        .unwrap_or_else(|| panic!("no warning: {stderr}"));
    assert!(
        warning.contains("WARN") && warning.contains("(demo)") && warning.contains("[access]"),
        "{warning}"
    );
    assert!(
        !stderr.contains('\x1b'),
        "colour codes in a pipe: {stderr:?}"
    );
    // The bundled demo itself: the warning says to copy the stage file,
    // not to edit the hash-named copy the next build replaces.
    let data = tempfile::tempdir().unwrap();
    let (_, stderr) = serve_until_ready(
        &["--listen", "0.0.0.0:0"],
        &[("XDG_DATA_HOME", data.path().to_str().unwrap())],
    );
    let warning = stderr
        .lines()
        .find(|l| l.contains("demo tokens"))
        .unwrap_or_else(|| panic!("no warning: {stderr}"));
    assert!(
        warning.contains("cp config/demo.toml config/mine.toml")
            && !warning.contains("puppetry/bundled"),
        "{warning}"
    );
    // On loopback the demo tokens are fine.
    let (_, stderr) = serve_until_ready(
        &[
            "--config",
            demo.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
        ],
        &[],
    );
    assert!(!stderr.contains("demo tokens"), "{stderr}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn export_draws_no_progress_bar_into_a_pipe() {
    use crate::common::daemon::{PLAYS, looping_capture, stage_config, stage_text};
    use puppetry_daemon::serve::{Options, start_with};
    // A take of one pass of a real capture.
    let once = looping_capture().replace("repeat = true\n", "");
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let mut options = Options::new(puppetry_daemon::stream::WebFiles::Embedded);
    options.takes_dir = takes.clone();
    options.record = true;
    let running = start_with(&stage_config(&once), options).await.unwrap();
    let deadline = std::time::Instant::now() + PLAYS;
    while !running.inputs_done() {
        assert!(
            std::time::Instant::now() < deadline,
            "the replay did not end"
        );
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    running.shutdown().await;
    let stage = scratch(&dir, "stage.toml", stage_text(&once).as_bytes());
    let take = takes.join("take-001.take");
    let glb = dir.path().join("take.glb");
    // Standard error is a pipe here, as in a log or `2> file`.
    let out = puppetry(&[
        "export",
        take.to_str().unwrap(),
        "--config",
        stage.to_str().unwrap(),
        "--format",
        "glb",
        "-o",
        glb.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(std::fs::metadata(&glb).unwrap().len() > 0);
    assert!(
        !stderr.contains('\r') && !stderr.contains('#') && !stderr.contains('\x1b'),
        "a progress bar in a pipe: {stderr:?}"
    );
}

/// `mesh` and `solve` read the files they are given as every other reader
/// does (issue 32): a device that never ends is refused by name at once,
/// where `mesh /dev/zero` used to read until memory ran out.
#[test]
fn mesh_and_solve_refuse_a_file_that_never_ends() {
    let mesh = puppetry_testkit::root().join("assets/gingerbread/gingerbread.mesh.json");
    for args in [
        vec!["mesh", "/dev/zero"],
        vec![
            "solve",
            "--mesh",
            mesh.to_str().unwrap(),
            "--handles",
            "/dev/zero",
        ],
    ] {
        let out = puppetry(&args);
        let said = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(
            said.contains("/dev/zero: is a character device, not a regular file"),
            "{args:?}: {said}"
        );
    }
}

/// `export --format` offers every format the export crate has, with its
/// label, takes any case, and names the formats when given another.
#[test]
fn export_offers_every_format_by_name() {
    use puppetry_export::format::Format;
    let help = puppetry(&["export", "--help"]);
    let help = String::from_utf8_lossy(&help.stdout);
    for format in Format::ALL {
        assert!(
            help.contains(&format!("{}:", format.name())) && help.contains(format.label()),
            "export --help does not offer {format}: {help}"
        );
    }
    let refused = failure(&["export", "t.take", "--format", "avi", "--output", "t.avi"]);
    assert!(
        refused.contains("invalid value 'avi'")
            && Format::ALL.iter().all(|f| refused.contains(f.name())),
        "{refused}"
    );
    // Any case: the take is what is missing, not the format.
    let missing = failure(&["export", "t.take", "--format", "GLB", "--output", "t.glb"]);
    assert!(missing.contains("t.take"), "{missing}");
}

/// A `.mid` whose time code was written as raw `F1` events (midly stops
/// its track there) plays what can be read, and `serve` warns naming the
/// file, the track and the byte where reading stopped: it used to play
/// the truncated track unsaid.
#[test]
fn serving_a_damaged_midi_file_warns_where_reading_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let track: &[u8] = &[
        0x00, 0xB0, 0x01, 0x0A, // CC 1 = 10
        0x00, 0xF1, 0x23, // a raw quarter frame
        0x00, 0xFF, 0x2F, 0x00,
    ];
    let mut bytes = b"MThd\0\0\0\x06\0\0\0\x01\x01\xE0MTrk".to_vec();
    bytes.extend_from_slice(&(track.len() as u32).to_be_bytes());
    bytes.extend_from_slice(track);
    let mid = scratch(&dir, "desk.mid", &bytes);
    let extra = format!(
        "[[input]]\nkind = \"midi\"\nname = \"desk\"\nfile = \"{}\"\n",
        mid.display()
    );
    let stage = scratch(
        &dir,
        "show.toml",
        crate::common::daemon::stage_text(&extra).as_bytes(),
    );
    let (stdout, stderr) = serve_until_ready(&["--config", stage.to_str().unwrap()], &[]);
    served_at(&stdout);
    let warning = stderr
        .lines()
        .find(|l| l.contains("cannot read"))
        .unwrap_or_else(|| panic!("no warning: {stderr}"));
    assert!(
        warning.contains("WARN")
            && warning.contains(&format!(
                "{}: track 1: an event it cannot read at byte 26",
                mid.display()
            )),
        "{warning}"
    );
}
