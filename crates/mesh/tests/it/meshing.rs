//! Meshing from polygons and pictures: shapes parse and validate, meshes hit
//! their vertex targets with well-shaped counter-clockwise triangles, traced
//! pictures keep their topology, and every kind of bad input is reported
//! with its file, field and problem instead of a panic.

use std::collections::HashSet;
use std::f64::consts::PI;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec2;
use puppetry_mesh::build::{MeshOptions, mesh_picture, mesh_png, quality, triangulate};
use puppetry_mesh::polygon::{Polygon, Shape, signed_area};
use puppetry_mesh::trace::{PictureWarning, trace_png, trace_rgba};
use puppetry_mesh::{Locator, Mesh, MeshError, cross};

// ---------------------------------------------------------------- helpers

fn temp_path(name: &str) -> PathBuf {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    std::env::temp_dir().join(format!(
        "puppetry-meshing-{}-{n}-{name}",
        std::process::id()
    ))
}

fn demo_png() -> PathBuf {
    puppetry_testkit::root().join("assets/gingerbread/gingerbread.png")
}

fn target(n: usize) -> MeshOptions {
    MeshOptions {
        target_vertices: Some(n),
        ..Default::default()
    }
}

fn mesh_area(mesh: &Mesh) -> f64 {
    let v = mesh.vertices();
    mesh.triangles()
        .iter()
        .map(|t| cross(v[t[0] as usize], v[t[1] as usize], v[t[2] as usize]) * 0.5)
        .sum()
}

/// V − E + F: 1 for a disc, 1 − h for a disc with h holes, summed over pieces.
fn euler_characteristic(mesh: &Mesh) -> i64 {
    let mut edges = HashSet::new();
    for t in mesh.triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            edges.insert((a.min(b), a.max(b)));
        }
    }
    mesh.vertices().len() as i64 - edges.len() as i64 + mesh.triangles().len() as i64
}

fn assert_ccw(mesh: &Mesh) {
    let v = mesh.vertices();
    for (k, t) in mesh.triangles().iter().enumerate() {
        let c = cross(v[t[0] as usize], v[t[1] as usize], v[t[2] as usize]);
        assert!(c > 0.0, "triangle {k} is not counter-clockwise: {c}");
    }
}

fn assert_within(got: usize, want: usize, fraction: f64) {
    let miss = (got as f64 / want as f64 - 1.0).abs();
    assert!(
        miss <= fraction,
        "{got} vertices for a target of {want}: off by {:.1}%",
        miss * 100.0
    );
}

fn square(x: f64, y: f64, size: f64) -> Vec<DVec2> {
    vec![
        DVec2::new(x, y),
        DVec2::new(x + size, y),
        DVec2::new(x + size, y + size),
        DVec2::new(x, y + size),
    ]
}

fn invalid_parts(e: MeshError) -> (String, String, String) {
    match e {
        MeshError::Invalid(puppetry_mesh::FieldError {
            file,
            field,
            problem,
        }) => (file, field, problem),
        other => panic!("expected an Invalid error, got {other:?}"),
    }
}

/// An RGBA picture painted by a per-pixel alpha function.
fn picture(width: u32, height: u32, alpha: impl Fn(f64, f64) -> u8) -> Vec<u8> {
    let mut rgba = Vec::with_capacity((width * height * 4) as usize);
    for y in 0..height {
        for x in 0..width {
            let a = alpha(x as f64 + 0.5, y as f64 + 0.5);
            rgba.extend_from_slice(&[200, 120, 60, a]);
        }
    }
    rgba
}

/// Anti-aliased coverage of a disc, as 8-bit alpha.
fn disc_alpha(x: f64, y: f64, cx: f64, cy: f64, r: f64) -> u8 {
    let d = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt() - r;
    ((0.5 - d).clamp(0.0, 1.0) * 255.0).round() as u8
}

fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
    palette: Option<(&[u8], &[u8])>,
) {
    let file = std::fs::File::create(path).unwrap();
    let mut encoder = png::Encoder::new(BufWriter::new(file), width, height);
    encoder.set_color(color);
    encoder.set_depth(depth);
    if let Some((plte, trns)) = palette {
        encoder.set_palette(plte.to_vec());
        encoder.set_trns(trns.to_vec());
    }
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(data).unwrap();
    writer.finish().unwrap();
}

// ------------------------------------------------------- polygon meshing

#[test]
fn single_polygon_from_json_meshes_to_its_exact_area() {
    let text = r#"{"outer": [[0, 0], [200, 0], [200, 200], [0, 200]]}"#;
    let shape = Shape::from_json("square.json", text).unwrap();
    assert_eq!(shape.polygons.len(), 1);
    assert!(shape.polygons[0].holes.is_empty());
    let mesh = triangulate("square.json", &shape, &MeshOptions::default()).unwrap();
    assert_within(mesh.vertices().len(), 1000, 0.15);
    assert_eq!(mesh.pieces().len(), 1);
    assert_eq!(euler_characteristic(&mesh), 1);
    assert!((mesh_area(&mesh) - 40_000.0).abs() < 1e-6 * 40_000.0);
    assert!(mesh.uv().is_none());
    assert_ccw(&mesh);
    // The corners are kept exactly.
    for corner in [[0.0, 0.0], [200.0, 0.0], [200.0, 200.0], [0.0, 200.0]] {
        let c = DVec2::from_array(corner);
        assert!(mesh.vertices().contains(&c), "corner {c} is missing");
    }
}

#[test]
fn polygon_with_a_hole_keeps_the_hole_empty() {
    let text = r#"{
        "outer": [[0, 0], [300, 0], [300, 200], [0, 200]],
        "holes": [[[100, 50], [100, 150], [200, 150], [200, 50]]]
    }"#;
    let shape = Shape::from_json("holed.json", text).unwrap();
    let mesh = triangulate("holed.json", &shape, &target(800)).unwrap();
    assert_eq!(mesh.pieces().len(), 1);
    assert_eq!(euler_characteristic(&mesh), 0, "one hole");
    assert!((mesh_area(&mesh) - (60_000.0 - 10_000.0)).abs() < 1e-6 * 60_000.0);
    let v = mesh.vertices();
    for t in mesh.triangles() {
        let c = (v[t[0] as usize] + v[t[1] as usize] + v[t[2] as usize]) / 3.0;
        let in_hole = c.x > 100.0 && c.x < 200.0 && c.y > 50.0 && c.y < 150.0;
        assert!(!in_hole, "a triangle sits in the hole at {c}");
    }
    assert_ccw(&mesh);
}

#[test]
fn several_islands_become_that_many_pieces() {
    // The third island sits inside the first island's hole.
    let text = r#"{"polygons": [
        {"outer": [[0, 0], [300, 0], [300, 300], [0, 300]],
         "holes": [[[50, 50], [250, 50], [250, 250], [50, 250]]]},
        {"outer": [[400, 0], [500, 0], [450, 90]]},
        {"outer": [[100, 100], [200, 100], [200, 200], [100, 200]]}
    ]}"#;
    let shape = Shape::from_json("islands.json", text).unwrap();
    assert_eq!(shape.polygons.len(), 3);
    let mesh = triangulate("islands.json", &shape, &target(2000)).unwrap();
    let pieces = mesh.pieces();
    assert_eq!(pieces.len(), 3);
    let expected = 90_000.0 - 40_000.0 + 4_500.0 + 10_000.0;
    assert!((mesh_area(&mesh) - expected).abs() < 1e-6 * expected);
    // The holed frame counts 0, each plain island 1.
    assert_eq!(euler_characteristic(&mesh), 2);
    assert_within(mesh.vertices().len(), 2000, 0.15);
    assert_ccw(&mesh);
}

#[test]
fn ring_orientation_and_closing_point_do_not_matter() {
    let ccw = r#"{"outer": [[0, 0], [100, 0], [100, 60], [0, 60]]}"#;
    let cw_closed = r#"{"outer": [[0, 0], [0, 60], [100, 60], [100, 0], [0, 0]]}"#;
    let a = Shape::from_json("a", ccw).unwrap();
    let b = Shape::from_json("b", cw_closed).unwrap();
    assert_eq!(
        b.polygons[0].outer.len(),
        4,
        "the closing repeat is dropped"
    );
    assert!(
        signed_area(&b.polygons[0].outer) > 0.0,
        "outer rings come out CCW"
    );
    let ma = triangulate("a", &a, &target(300)).unwrap();
    let mb = triangulate("b", &b, &target(300)).unwrap();
    assert_eq!(ma.vertices().len(), mb.vertices().len());
    assert!((mesh_area(&ma) - mesh_area(&mb)).abs() < 1e-6);
}

#[test]
fn vertex_counts_land_near_their_targets() {
    // A shape with a sharp notch, a hole and a thin arm.
    let shape = Shape {
        polygons: vec![Polygon {
            outer: vec![
                DVec2::new(0.0, 0.0),
                DVec2::new(400.0, 0.0),
                DVec2::new(400.0, 300.0),
                DVec2::new(220.0, 300.0),
                DVec2::new(200.0, 120.0),
                DVec2::new(180.0, 300.0),
                DVec2::new(40.0, 300.0),
                DVec2::new(40.0, 500.0),
                DVec2::new(20.0, 500.0),
                DVec2::new(0.0, 300.0),
            ],
            holes: vec![
                (0..40)
                    .map(|k| {
                        let a = k as f64 / 40.0 * 2.0 * PI;
                        DVec2::new(300.0 + 50.0 * a.cos(), 150.0 + 50.0 * a.sin())
                    })
                    .collect(),
            ],
        }],
    };
    for n in [300, 3000, 30000] {
        let mesh = triangulate("notched", &shape, &target(n)).unwrap();
        assert_within(mesh.vertices().len(), n, 0.15);
        assert_eq!(mesh.pieces().len(), 1);
        assert_eq!(euler_characteristic(&mesh), 0);
        assert_ccw(&mesh);
    }
    for n in [100, 3000, 30000] {
        let mesh = mesh_png(&demo_png(), &target(n)).unwrap();
        assert_within(mesh.vertices().len(), n, 0.15);
    }
}

#[test]
fn triangles_are_well_shaped_and_evenly_sized() {
    let disc: Vec<DVec2> = (0..500)
        .map(|k| {
            let a = k as f64 / 500.0 * 2.0 * PI;
            DVec2::new(150.0 * a.cos(), 100.0 * a.sin())
        })
        .collect();
    let shape = Shape {
        polygons: vec![Polygon {
            outer: disc,
            holes: vec![square(-40.0, -30.0, 60.0)],
        }],
    };
    for mesh in [
        triangulate("ellipse", &shape, &target(2000)).unwrap(),
        mesh_png(&demo_png(), &target(5000)).unwrap(),
    ] {
        let q = quality(&mesh);
        assert!(q.min_angle_deg > 20.0, "{q:?}");
        assert!(q.max_angle_deg < 125.0, "{q:?}");
        assert!(q.max_area / q.min_area < 6.0, "{q:?}");
        assert!(q.area_spread < 0.3, "{q:?}");
        assert!(q.max_edge / q.min_edge < 4.0, "{q:?}");
        assert!(q.edge_spread < 0.25, "{q:?}");
    }
}

#[test]
fn sharp_input_corners_survive_meshing() {
    // A thin spike: the 5° tip cannot be improved, but it must mesh.
    let tip = DVec2::new(300.0, 0.0) + DVec2::from_angle(2.5f64.to_radians()) * 0.0;
    let shape = Shape {
        polygons: vec![Polygon {
            outer: vec![
                DVec2::new(0.0, -13.0),
                tip,
                DVec2::new(0.0, 13.0),
                DVec2::new(-60.0, 0.0),
            ],
            holes: vec![],
        }],
    };
    let mesh = triangulate("spike", &shape, &target(400)).unwrap();
    assert!(mesh.vertices().contains(&tip));
    assert_within(mesh.vertices().len(), 400, 0.15);
    let expected = signed_area(&shape.polygons[0].outer);
    assert!((mesh_area(&mesh) - expected).abs() < 1e-6 * expected);
}

#[test]
fn meshing_is_deterministic() {
    let a = mesh_png(&demo_png(), &target(700)).unwrap();
    let b = mesh_png(&demo_png(), &target(700)).unwrap();
    assert_eq!(a, b);
}

// ------------------------------------------------------------- tracing

#[test]
fn traced_disc_is_round_and_y_up() {
    // A disc near the top-left corner of a 100×80 picture.
    let (cx, cy, r) = (30.0, 25.0, 18.0);
    let rgba = picture(100, 80, |x, y| disc_alpha(x, y, cx, cy, r));
    let traced = trace_rgba("disc", 100, 80, &rgba, 0.3, None).unwrap();
    assert_eq!((traced.width, traced.height), (100, 80));
    assert_eq!(traced.warnings, [], "a cut-out figure is what is wanted");
    let solid = trace_rgba("solid", 10, 10, &[255; 400], 0.3, None).unwrap();
    assert!(
        matches!(&solid.warnings[..], [PictureWarning::FullyOpaque { file, .. }] if file == "solid"),
        "{:?}",
        solid.warnings
    );
    assert_eq!(traced.shape.polygons.len(), 1);
    let outer = &traced.shape.polygons[0].outer;
    let area = signed_area(outer);
    assert!(area > 0.0, "outer rings are counter-clockwise");
    assert!((area - PI * r * r).abs() < 0.01 * PI * r * r, "area {area}");
    let centre = outer.iter().copied().sum::<DVec2>() / outer.len() as f64;
    assert!(
        (centre - DVec2::new(cx, 80.0 - cy)).length() < 0.5,
        "{centre}"
    );
    for p in outer {
        let d = (*p - DVec2::new(cx, 80.0 - cy)).length();
        assert!((d - r).abs() < 0.5, "point {p} is {d} from the centre");
    }
    let mesh = triangulate("disc", &traced.shape, &target(200)).unwrap();
    assert_eq!(mesh.pieces().len(), 1);
    assert_within(mesh.vertices().len(), 200, 0.15);
}

#[test]
fn traced_ring_has_a_hole() {
    let rgba = picture(120, 120, |x, y| {
        let outer = disc_alpha(x, y, 60.0, 60.0, 50.0);
        let inner = disc_alpha(x, y, 60.0, 60.0, 20.0);
        outer.saturating_sub(inner)
    });
    let traced = trace_rgba("ring", 120, 120, &rgba, 0.5, None).unwrap();
    assert_eq!(traced.shape.polygons.len(), 1);
    let polygon = &traced.shape.polygons[0];
    assert_eq!(polygon.holes.len(), 1);
    assert!(signed_area(&polygon.holes[0]) < 0.0, "holes are clockwise");
    let hole = -signed_area(&polygon.holes[0]);
    assert!(
        (hole - PI * 400.0).abs() < 0.03 * PI * 400.0,
        "hole area {hole}"
    );
    let mesh = triangulate("ring", &traced.shape, &target(600)).unwrap();
    assert_eq!(mesh.pieces().len(), 1);
    assert_eq!(euler_characteristic(&mesh), 0);
}

#[test]
fn two_blobs_and_an_island_in_a_hole_are_separate_pieces() {
    let rgba = picture(200, 100, |x, y| {
        let left = disc_alpha(x, y, 50.0, 50.0, 40.0)
            .saturating_sub(disc_alpha(x, y, 50.0, 50.0, 25.0))
            .max(disc_alpha(x, y, 50.0, 50.0, 10.0));
        let right = disc_alpha(x, y, 150.0, 50.0, 30.0);
        left.max(right)
    });
    let traced = trace_rgba("blobs", 200, 100, &rgba, 0.5, None).unwrap();
    assert_eq!(traced.shape.polygons.len(), 3);
    let holes: usize = traced.shape.polygons.iter().map(|p| p.holes.len()).sum();
    assert_eq!(holes, 1);
    let mesh = triangulate("blobs", &traced.shape, &target(1500)).unwrap();
    assert_eq!(mesh.pieces().len(), 3);

    let two = picture(200, 100, |x, y| {
        disc_alpha(x, y, 50.0, 50.0, 40.0).max(disc_alpha(x, y, 150.0, 50.0, 30.0))
    });
    let traced = trace_rgba("two", 200, 100, &two, 0.5, None).unwrap();
    let mesh = triangulate("two", &traced.shape, &target(500)).unwrap();
    assert_eq!(mesh.pieces().len(), 2);
}

/// Issue 45: a head drawn 4 pixels off its body became a piece of its own
/// without a word, and floated off. The tracer says how many pieces and
/// how wide a gap joins them; joined across that gap they mesh as one
/// (and a join too short leaves them apart, still said).
#[test]
fn a_picture_in_pieces_says_so_and_joins_across_its_gap() {
    let figure = picture(200, 200, |x, y| {
        // A body of radius 60 and a head of radius 25 whose edges are 4
        // pixels apart.
        disc_alpha(x, y, 100.0, 70.0, 60.0).max(disc_alpha(x, y, 100.0, 159.0, 25.0))
    });
    let traced = trace_rgba("figure", 200, 200, &figure, 0.5, None).unwrap();
    let Some(PictureWarning::Pieces { pieces, gap, .. }) = traced.warnings.first() else {
        panic!("no warning of the pieces: {:?}", traced.warnings);
    };
    assert_eq!(*pieces, 2);
    assert!((3..=6).contains(gap), "the gap is {gap} pixels");
    let short = trace_rgba("figure", 200, 200, &figure, 0.5, Some(1.0)).unwrap();
    assert_eq!(short.shape.polygons.len(), 2, "a join shorter than the gap");
    assert_eq!(short.warnings.len(), 1);
    let joined = trace_rgba("figure", 200, 200, &figure, 0.5, Some(f64::from(*gap))).unwrap();
    assert!(joined.warnings.is_empty(), "{:?}", joined.warnings);
    let mesh = triangulate("figure", &joined.shape, &target(600)).unwrap();
    assert_eq!(mesh.pieces().len(), 1);
    // The message says what to do.
    let said = traced.warnings[0].to_string();
    assert!(
        said.contains("2 separate pieces") && said.contains("--join"),
        "{said}"
    );
}

#[test]
fn diagonal_pixels_and_noise_trace_to_valid_shapes() {
    // Two squares meeting at one corner: a saddle cell. Transparent
    // neighbours keep the cell's mean alpha at 50%, so the squares stay
    // apart; half-transparent ones lift it and join them through a neck.
    for (others, polygons) in [(0u8, 2usize), (100, 1)] {
        let rgba = picture(20, 20, |x, y| {
            let a = x > 4.0 && x < 10.0 && y > 4.0 && y < 10.0;
            let b = x > 10.0 && x < 16.0 && y > 10.0 && y < 16.0;
            let fringe = x > 4.0 && x < 16.0 && y > 4.0 && y < 16.0;
            if a || b {
                255
            } else if fringe {
                others
            } else {
                0
            }
        });
        let traced = trace_rgba("saddle", 20, 20, &rgba, 0.0, None).unwrap();
        traced.shape.validate("saddle").unwrap();
        assert_eq!(traced.shape.polygons.len(), polygons);
        let mesh = triangulate("saddle", &traced.shape, &target(80)).unwrap();
        assert_eq!(mesh.pieces().len(), polygons);
    }

    // Pseudo-random blotches: many rings, holes, specks and saddles.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut noise = vec![0u8; 64 * 64];
    for v in &mut noise {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        *v = (state >> 56) as u8;
    }
    let rgba = picture(128, 128, |x, y| {
        // Upscaled, so blobs are a few pixels wide rather than single pixels.
        noise[(y as usize / 2) * 64 + x as usize / 2]
    });
    for detail in [0.0, 0.7, 3.0] {
        let traced = trace_rgba("noise", 128, 128, &rgba, detail, None).unwrap();
        traced.shape.validate("noise").unwrap();
        assert!(traced.shape.polygons.len() > 5);
        let mesh = triangulate("noise", &traced.shape, &target(3000)).unwrap();
        assert_ccw(&mesh);
    }
}

#[test]
fn larger_detail_means_fewer_outline_points() {
    let rgba = picture(200, 200, |x, y| disc_alpha(x, y, 100.0, 100.0, 80.0));
    let fine = trace_rgba("disc", 200, 200, &rgba, 0.1, None).unwrap();
    let coarse = trace_rgba("disc", 200, 200, &rgba, 2.0, None).unwrap();
    let n_fine = fine.shape.polygons[0].outer.len();
    let n_coarse = coarse.shape.polygons[0].outer.len();
    assert!(n_coarse * 3 < n_fine, "{n_coarse} vs {n_fine}");
}

#[test]
fn specks_and_pinholes_are_dropped() {
    let rgba = picture(100, 100, |x, y| {
        let speck = (x - 5.5).abs() < 1.0 && (y - 5.5).abs() < 1.0;
        let pinhole = (x - 50.5).abs() < 1.0 && (y - 50.5).abs() < 1.0;
        let body = disc_alpha(x, y, 50.0, 50.0, 30.0);
        if speck {
            255
        } else if pinhole {
            0
        } else {
            body
        }
    });
    let traced = trace_rgba("specks", 100, 100, &rgba, 0.5, None).unwrap();
    assert_eq!(traced.shape.polygons.len(), 1);
    assert!(traced.shape.polygons[0].holes.is_empty());
}

#[test]
fn picture_without_alpha_is_a_rectangle() {
    let (w, h) = (64u32, 40u32);
    let rgb: Vec<u8> = (0..w * h).flat_map(|_| [10u8, 200, 30]).collect();
    let path = temp_path("opaque.png");
    write_png(
        &path,
        w,
        h,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        &rgb,
        None,
    );
    let traced = trace_png(&path, 0.5, None).unwrap();
    assert_eq!(traced.shape.polygons.len(), 1);
    let outer = &traced.shape.polygons[0].outer;
    assert!((signed_area(outer) - (w * h) as f64).abs() < 1e-9);
    // Rarely what was meant, so said plainly, as a value to pass on.
    let expected = PictureWarning::FullyOpaque {
        file: path.display().to_string(),
        width: w,
        height: h,
    };
    assert_eq!(traced.warnings, std::slice::from_ref(&expected));
    let meshed = mesh_picture(&path, &target(300)).unwrap();
    assert_eq!(meshed.warnings, [expected]);
    let message = meshed.warnings[0].to_string();
    assert!(
        message.contains("every pixel is opaque") && message.contains("64×40 rectangle"),
        "{message}"
    );
    let mesh = mesh_png(&path, &target(300)).unwrap();
    assert_eq!(mesh, meshed.mesh);
    assert!((mesh_area(&mesh) - (w * h) as f64).abs() < 1e-6);
    let uv = mesh.uv().unwrap();
    for (v, t) in mesh.vertices().iter().zip(uv) {
        assert!((t.x - v.x / w as f64).abs() < 1e-12);
        assert!((t.y - (h as f64 - v.y) / h as f64).abs() < 1e-12);
        assert!((0.0..=1.0).contains(&t.x) && (0.0..=1.0).contains(&t.y));
    }
    std::fs::remove_file(&path).ok();
}

#[test]
fn png_colour_types_and_depths_decode_alpha() {
    // The same disc as 16-bit grey+alpha and as a palette with tRNS.
    let (w, h) = (60u32, 50u32);
    let alpha = |x: u32, y: u32| disc_alpha(x as f64 + 0.5, y as f64 + 0.5, 30.0, 25.0, 20.0);
    let mut gray16 = Vec::new();
    let mut indexed = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let a = alpha(x, y) as u16 * 257;
            gray16.extend_from_slice(&[0x80, 0x00]);
            gray16.extend_from_slice(&a.to_be_bytes());
            // Palette entry 0 is transparent, 1 half-transparent, 2 opaque.
            indexed.push(match alpha(x, y) {
                0..=63 => 0,
                64..=191 => 1,
                _ => 2,
            });
        }
    }
    let p16 = temp_path("gray16.png");
    write_png(
        &p16,
        w,
        h,
        png::ColorType::GrayscaleAlpha,
        png::BitDepth::Sixteen,
        &gray16,
        None,
    );
    let p8 = temp_path("palette.png");
    let plte = [0u8, 0, 0, 100, 50, 0, 200, 100, 0];
    let trns = [0u8, 140, 255];
    write_png(
        &p8,
        w,
        h,
        png::ColorType::Indexed,
        png::BitDepth::Eight,
        &indexed,
        Some((&plte, &trns)),
    );
    for path in [&p16, &p8] {
        let traced = trace_png(path, 0.3, None).unwrap();
        assert_eq!(traced.shape.polygons.len(), 1, "{}", path.display());
        let area = signed_area(&traced.shape.polygons[0].outer);
        let want = PI * 400.0;
        assert!(
            (area - want).abs() < 0.04 * want,
            "{}: {area}",
            path.display()
        );
        std::fs::remove_file(path).ok();
    }
}

// ------------------------------------------------------- the demo puppet

#[test]
fn demo_puppet_meshes_and_its_assets_agree() {
    let mesh = mesh_png(&demo_png(), &MeshOptions::default()).unwrap();
    assert_within(mesh.vertices().len(), 1000, 0.15);
    assert_eq!(mesh.pieces().len(), 1);
    assert_eq!(euler_characteristic(&mesh), 1);
    let uv = mesh.uv().unwrap();
    assert!(
        uv.iter()
            .all(|t| (0.0..=1.0).contains(&t.x) && (0.0..=1.0).contains(&t.y))
    );
    // The figure covers a good part of the 512×512 picture, inside it.
    let area = mesh_area(&mesh);
    assert!(area > 60_000.0 && area < 150_000.0, "area {area}");
    assert!(mesh.size() < 512.0 * 2f64.sqrt());

    let dir = puppetry_testkit::root().join("assets/gingerbread");
    let stored = Mesh::load(&dir.join("gingerbread.mesh.json")).unwrap();
    assert_within(stored.vertices().len(), 1000, 0.15);
    assert!(stored.uv().is_some());
    assert_eq!(stored.pieces().len(), 1);

    let handles: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("handles.json")).unwrap()).unwrap();
    let handles = handles["handles"].as_array().unwrap();
    assert_eq!(handles.len(), 3);
    let locator = Locator::new(&stored);
    let mut pinned = 0;
    for h in handles {
        let at = |k: &str| DVec2::new(h[k][0].as_f64().unwrap(), h[k][1].as_f64().unwrap());
        let (point, to) = (at("point"), at("to"));
        assert!(
            locator.locate(&stored, point).is_some(),
            "handle at {point} is outside the mesh"
        );
        if point == to {
            pinned += 1;
        } else {
            assert!((to - point - DVec2::new(0.0, 80.0)).length() < 1e-9);
        }
    }
    assert_eq!(pinned, 2, "both feet are pinned");
}

// ------------------------------------------------------------ bad input

#[test]
fn malformed_json_names_the_line() {
    let text = "{\n  \"outer\": [[0, 0], [1, 0],\n    [1, 1]\n  ,]\n}";
    match Shape::from_json("broken.json", text) {
        Err(MeshError::Syntax { file, line, .. }) => {
            assert_eq!(file, "broken.json");
            assert_eq!(line, 4);
        }
        other => panic!("expected a syntax error, got {other:?}"),
    }
    let unknown = r#"{"outer": [[0, 0], [1, 0], [1, 1]], "colour": "red"}"#;
    let e = Shape::from_json("unknown.json", unknown).unwrap_err();
    assert!(matches!(e, MeshError::Syntax { .. }), "{e:?}");
    assert!(e.to_string().contains("colour"), "{e}");
    let wrong = r#"{"polygons": [{"outer": [[0, 0], [1, "x"], [1, 1]]}]}"#;
    let e = Shape::from_json("wrong.json", wrong).unwrap_err();
    assert!(matches!(e, MeshError::Syntax { line: 1, .. }), "{e:?}");
}

#[test]
fn json_must_say_outer_or_polygons() {
    let (file, field, _) = invalid_parts(Shape::from_json("empty.json", "{}").unwrap_err());
    assert_eq!((file.as_str(), field.as_str()), ("empty.json", "outer"));
    let both = r#"{"outer": [[0, 0], [1, 0], [1, 1]], "polygons": []}"#;
    let (_, field, _) = invalid_parts(Shape::from_json("both.json", both).unwrap_err());
    assert_eq!(field, "polygons");
    let none = r#"{"polygons": []}"#;
    let (_, field, _) = invalid_parts(Shape::from_json("none.json", none).unwrap_err());
    assert_eq!(field, "polygons");
}

#[test]
fn self_intersecting_polygon_names_both_segments() {
    // A bow tie: segment 0 (0,0)-(10,10) crosses segment 2 (10,0)-(0,10).
    let text = r#"{"outer": [[0, 0], [10, 10], [10, 0], [0, 10]]}"#;
    let (file, field, problem) = invalid_parts(Shape::from_json("bowtie.json", text).unwrap_err());
    assert_eq!(file, "bowtie.json");
    assert_eq!(field, "outer");
    assert!(problem.contains("segment 0 ([0, 0]-[10, 10])"), "{problem}");
    assert!(problem.contains("segment 2 ([10, 0]-[0, 10])"), "{problem}");

    // A hole crossing its outer ring, in the several-islands form.
    let text = r#"{"polygons": [
        {"outer": [[100, 0], [110, 0], [105, 5]]},
        {"outer": [[0, 0], [10, 0], [10, 10], [0, 10]],
         "holes": [[[5, 5], [15, 5], [15, 6]]]}
    ]}"#;
    let (_, field, problem) = invalid_parts(Shape::from_json("cross.json", text).unwrap_err());
    assert_eq!(field, "polygons[1].outer");
    assert!(
        problem.contains("polygons[1].holes[0] segment"),
        "{problem}"
    );

    // A ring touching itself at a vertex counts too.
    let text = r#"{"outer": [[0, 0], [10, 0], [5, 5], [10, 10], [0, 10], [5, 5]]}"#;
    let (_, _, problem) = invalid_parts(Shape::from_json("touch.json", text).unwrap_err());
    assert!(problem.contains("crosses or touches"), "{problem}");
}

#[test]
fn misplaced_holes_and_overlapping_islands_are_rejected() {
    let outside = r#"{"outer": [[0, 0], [10, 0], [10, 10], [0, 10]],
                      "holes": [[[20, 20], [30, 20], [30, 30]]]}"#;
    let (_, field, problem) = invalid_parts(Shape::from_json("o.json", outside).unwrap_err());
    assert_eq!(field, "holes[0]");
    assert!(problem.contains("outside"), "{problem}");

    let overlap = r#"{"polygons": [
        {"outer": [[0, 0], [10, 0], [10, 10], [0, 10]]},
        {"outer": [[2, 2], [8, 2], [8, 8], [2, 8]]}
    ]}"#;
    let (_, field, problem) = invalid_parts(Shape::from_json("ov.json", overlap).unwrap_err());
    assert_eq!(field, "polygons[1].outer");
    assert!(problem.contains("overlap"), "{problem}");

    let nested = r#"{"outer": [[0, 0], [10, 0], [10, 10], [0, 10]],
                     "holes": [[[1, 1], [9, 1], [9, 9], [1, 9]], [[3, 3], [6, 3], [6, 6]]]}"#;
    let (_, field, _) = invalid_parts(Shape::from_json("n.json", nested).unwrap_err());
    assert_eq!(field, "holes[1]");

    let few = r#"{"outer": [[0, 0], [1, 1], [1, 1], [0, 0]]}"#;
    let (_, field, problem) = invalid_parts(Shape::from_json("f.json", few).unwrap_err());
    assert_eq!(field, "outer");
    assert!(problem.contains("at least 3"), "{problem}");

    let flat = r#"{"outer": [[0, 0], [1, 1], [2, 2]]}"#;
    assert!(Shape::from_json("flat.json", flat).is_err());
}

#[test]
fn non_finite_coordinates_are_rejected_through_the_api() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut outer = square(0.0, 0.0, 10.0);
        outer[2].y = bad;
        let shape = Shape {
            polygons: vec![Polygon {
                outer,
                holes: vec![],
            }],
        };
        let (file, field, problem) = invalid_parts(shape.validate("api").unwrap_err());
        assert_eq!((file.as_str(), field.as_str()), ("api", "outer"));
        assert!(
            problem.contains("point 2") && problem.contains("finite"),
            "{problem}"
        );
        assert!(triangulate("api", &shape, &MeshOptions::default()).is_err());
    }
    let mut far = square(0.0, 0.0, 10.0);
    far[1].x = 1e300;
    let shape = Shape {
        polygons: vec![Polygon {
            outer: far,
            holes: vec![],
        }],
    };
    let (_, field, problem) = invalid_parts(shape.validate("api").unwrap_err());
    assert_eq!(field, "outer");
    assert!(problem.contains("point 1"), "{problem}");
    let empty = Shape { polygons: vec![] };
    assert!(triangulate("api", &empty, &MeshOptions::default()).is_err());
    let shape = Shape {
        polygons: vec![Polygon {
            outer: square(0.0, 0.0, 10.0),
            holes: vec![],
        }],
    };
    let (_, field, _) = invalid_parts(triangulate("api", &shape, &target(0)).unwrap_err());
    assert_eq!(field, "target_vertices");
}

#[test]
fn picture_with_nothing_opaque_is_rejected() {
    let rgba = picture(32, 32, |_, _| 100); // below 50% everywhere
    let (file, field, problem) =
        invalid_parts(trace_rgba("faint", 32, 32, &rgba, 0.5, None).unwrap_err());
    assert_eq!((file.as_str(), field.as_str()), ("faint", "alpha"));
    assert!(problem.contains("no pixel is opaque"), "{problem}");

    let path = temp_path("clear.png");
    write_png(
        &path,
        16,
        16,
        png::ColorType::Rgba,
        png::BitDepth::Eight,
        &[0u8; 16 * 16 * 4],
        None,
    );
    let (file, field, _) = invalid_parts(mesh_png(&path, &MeshOptions::default()).unwrap_err());
    assert_eq!(file, path.display().to_string());
    assert_eq!(field, "alpha");
    std::fs::remove_file(&path).ok();

    let specks = picture(32, 32, |x, y| if x < 1.0 && y < 1.0 { 255 } else { 0 });
    let (_, field, problem) =
        invalid_parts(trace_rgba("specks", 32, 32, &specks, 0.5, None).unwrap_err());
    assert_eq!(field, "alpha");
    assert!(problem.contains("specks"), "{problem}");

    let (_, field, _) = invalid_parts(trace_rgba("short", 4, 4, &[0; 10], 0.5, None).unwrap_err());
    assert_eq!(field, "rgba");
    let (_, field, _) =
        invalid_parts(trace_rgba("nan", 4, 4, &[255; 64], f64::NAN, None).unwrap_err());
    assert_eq!(field, "detail");
}

#[test]
fn unreadable_files_are_io_errors_naming_the_file() {
    let path = temp_path("not-a.png");
    std::fs::write(&path, b"{\"outer\": []} this is not a picture").unwrap();
    let e = mesh_png(&path, &MeshOptions::default()).unwrap_err();
    match &e {
        MeshError::Io { file, .. } => assert_eq!(file, &path.display().to_string()),
        other => panic!("expected an Io error, got {other:?}"),
    }
    assert!(e.to_string().contains("PNG"), "{e}");
    std::fs::remove_file(&path).ok();

    // A PNG cut short after its header.
    let good = temp_path("cut.png");
    write_png(
        &good,
        8,
        8,
        png::ColorType::Rgba,
        png::BitDepth::Eight,
        &[255u8; 8 * 8 * 4],
        None,
    );
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(&good, &bytes[..40]).unwrap();
    let e = trace_png(&good, 0.5, None).unwrap_err();
    assert!(matches!(e, MeshError::Io { .. }), "{e:?}");
    std::fs::remove_file(&good).ok();

    let missing = temp_path("missing.png");
    let e = trace_png(&missing, 0.5, None).unwrap_err();
    assert!(matches!(e, MeshError::Io { .. }), "{e:?}");
    assert!(e.to_string().contains(&missing.display().to_string()));
}

#[test]
fn long_rings_validate_quickly_and_crossings_are_found_in_them() {
    let n = 20_000;
    let mut ring: Vec<DVec2> = (0..n)
        .map(|k| {
            let a = k as f64 / n as f64 * 2.0 * PI;
            let r = 1000.0 + 30.0 * (a * 40.0).sin();
            DVec2::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let shape = Shape {
        polygons: vec![Polygon {
            outer: ring.clone(),
            holes: vec![],
        }],
    };
    shape.validate("wavy").unwrap();

    // Pull one point across the ring.
    ring[5000] = DVec2::new(-1200.0, 3.0);
    let shape = Shape {
        polygons: vec![Polygon {
            outer: ring,
            holes: vec![],
        }],
    };
    let (_, _, problem) = invalid_parts(shape.validate("wavy").unwrap_err());
    assert!(
        problem.contains("segment 4999") || problem.contains("segment 5000"),
        "{problem}"
    );
}
