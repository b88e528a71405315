//! Builds the layered figure `puppetry compare` runs on, after the lp-FFD
//! paper's "Ginger Man": separate, overlapping mesh pieces for the torso,
//! head, two arms, two legs, two eyes and a mouth, as a cut-out puppet is
//! made of paper layers. Each piece is meshed on its own (so no piece shares
//! a vertex with another) and the pieces are merged into one mesh. Also
//! writes the comparison's manipulation scenario (vertex handles and their
//! targets; see docs/measures.md).
//!
//! Writes `assets/gingerbread-layers/gingerbread-layers.mesh.json` and
//! `assets/gingerbread-layers/handles.json`. Run with
//! `cargo run --release --example gingerbread_layers`.

#![allow(
    clippy::too_many_lines,
    reason = "a test or example is one scenario, read top to bottom"
)]

use std::f64::consts::TAU;
use std::path::Path;

use glam::DVec2;
use puppetry_mesh::Mesh;
use puppetry_mesh::build::{MeshOptions, triangulate};
use puppetry_mesh::polygon::{Polygon, Shape};

/// Outline points per full turn of a round end or circle: the mesher
/// resamples at its own edge length anyway.
const TURN: usize = 64;

fn circle(centre: DVec2, radius_x: f64, radius_y: f64) -> Vec<DVec2> {
    (0..TURN)
        .map(|k| {
            let a = TAU * k as f64 / TURN as f64;
            centre + DVec2::new(radius_x * a.cos(), radius_y * a.sin())
        })
        .collect()
}

/// A stadium: the points within `radius` of the segment `a..b`.
fn capsule(a: DVec2, b: DVec2, radius: f64) -> Vec<DVec2> {
    let along = (b - a).normalize();
    let side = along.perp();
    let half = TURN / 2;
    let mut ring = Vec::with_capacity(TURN + 2);
    // Round end at b (from one side to the other through the tip), then a.
    for (centre, start) in [(b, -side), (a, side)] {
        for k in 0..=half {
            let angle = std::f64::consts::PI * k as f64 / half as f64;
            ring.push(centre + start.rotate(DVec2::from_angle(angle)) * radius);
        }
    }
    ring
}

/// A rounded rectangle (corner radius `r`).
fn rounded_box(centre: DVec2, half: DVec2, r: f64) -> Vec<DVec2> {
    let quarter = TURN / 4;
    let inner = half - DVec2::splat(r);
    let corners = [
        (DVec2::new(inner.x, inner.y), 0.0),
        (DVec2::new(-inner.x, inner.y), 0.25),
        (DVec2::new(-inner.x, -inner.y), 0.5),
        (DVec2::new(inner.x, -inner.y), 0.75),
    ];
    let mut ring = Vec::new();
    for (corner, start) in corners {
        for k in 0..=quarter {
            let a = TAU * (start + 0.25 * k as f64 / quarter as f64);
            ring.push(centre + corner + DVec2::new(a.cos(), a.sin()) * r);
        }
    }
    ring
}

struct Part {
    name: &'static str,
    outline: Vec<DVec2>,
    vertices: usize,
}

fn main() {
    let parts = [
        Part {
            name: "torso",
            outline: rounded_box(DVec2::new(256.0, 255.0), DVec2::new(72.0, 100.0), 40.0),
            vertices: 260,
        },
        Part {
            name: "head",
            outline: circle(DVec2::new(256.0, 405.0), 68.0, 68.0),
            vertices: 170,
        },
        Part {
            name: "left arm",
            outline: capsule(DVec2::new(200.0, 305.0), DVec2::new(80.0, 298.0), 25.0),
            vertices: 110,
        },
        Part {
            name: "right arm",
            outline: capsule(DVec2::new(312.0, 305.0), DVec2::new(432.0, 298.0), 25.0),
            vertices: 110,
        },
        Part {
            name: "left leg",
            outline: capsule(DVec2::new(228.0, 185.0), DVec2::new(180.0, 52.0), 29.0),
            vertices: 130,
        },
        Part {
            name: "right leg",
            outline: capsule(DVec2::new(284.0, 185.0), DVec2::new(332.0, 52.0), 29.0),
            vertices: 130,
        },
        Part {
            name: "left eye",
            outline: circle(DVec2::new(230.0, 420.0), 10.0, 12.0),
            vertices: 14,
        },
        Part {
            name: "right eye",
            outline: circle(DVec2::new(282.0, 420.0), 10.0, 12.0),
            vertices: 14,
        },
        Part {
            name: "mouth",
            outline: circle(DVec2::new(256.0, 377.0), 24.0, 8.0),
            vertices: 24,
        },
    ];
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut ranges = Vec::new();
    for part in &parts {
        let shape = Shape {
            polygons: vec![Polygon {
                outer: part.outline.clone(),
                holes: Vec::new(),
            }],
        };
        let options = MeshOptions {
            target_vertices: Some(part.vertices),
            ..Default::default()
        };
        let piece = triangulate(part.name, &shape, &options).expect("each part meshes");
        let offset = vertices.len() as u32;
        triangles.extend(piece.triangles().iter().map(|t| t.map(|i| i + offset)));
        vertices.extend_from_slice(piece.vertices());
        ranges.push((part.name, offset as usize..vertices.len()));
        println!("{:<10} {:>4} vertices", part.name, piece.vertices().len());
    }
    let mesh = Mesh::new("gingerbread-layers", vertices, triangles, None, None)
        .expect("the merged pieces are a valid mesh");
    assert_eq!(mesh.pieces().len(), parts.len(), "one mesh piece per part");

    // The scenario: the nearest vertex of the named part to each point.
    let nearest = |part: &str, at: DVec2| -> usize {
        let (_, range) = ranges.iter().find(|(n, _)| *n == part).expect("a part");
        range
            .clone()
            .min_by(|&a, &b| {
                mesh.vertices()[a]
                    .distance(at)
                    .total_cmp(&mesh.vertices()[b].distance(at))
            })
            .expect("parts have vertices")
    };
    let rotate_about = |pivot: DVec2, p: DVec2, degrees: f64| {
        pivot + (p - pivot).rotate(DVec2::from_angle(degrees.to_radians()))
    };
    let mut handles: Vec<(usize, DVec2)> = Vec::new();
    // The torso is pinned at chest and belly.
    for at in [DVec2::new(256.0, 320.0), DVec2::new(256.0, 190.0)] {
        let v = nearest("torso", at);
        handles.push((v, mesh.vertices()[v]));
    }
    // The right arm is raised 35° about its shoulder, which stays pinned.
    let shoulder = nearest("right arm", DVec2::new(318.0, 305.0));
    let hand = nearest("right arm", DVec2::new(430.0, 298.0));
    let pivot = mesh.vertices()[shoulder];
    handles.push((shoulder, pivot));
    handles.push((hand, rotate_about(pivot, mesh.vertices()[hand], 35.0)));
    // The left leg bends at the knee: hip pinned, thigh swung 20° outwards,
    // shin 20° inwards from rest — a 40° bend, segment lengths kept.
    let hip = nearest("left leg", DVec2::new(228.0, 180.0));
    let knee = nearest("left leg", DVec2::new(204.0, 118.0));
    let foot = nearest("left leg", DVec2::new(181.0, 56.0));
    let [hip_at, knee_at, foot_at] = [hip, knee, foot].map(|v| mesh.vertices()[v]);
    let knee_to = rotate_about(hip_at, knee_at, -20.0);
    let foot_to = knee_to + (foot_at - knee_at).rotate(DVec2::from_angle(20f64.to_radians()));
    handles.push((hip, hip_at));
    handles.push((knee, knee_to));
    handles.push((foot, foot_to));

    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/gingerbread-layers");
    std::fs::create_dir_all(&out).expect("create the assets folder");
    std::fs::write(out.join("gingerbread-layers.mesh.json"), mesh.to_json())
        .expect("write the mesh");
    let entries: Vec<String> = handles
        .iter()
        .map(|(v, to)| {
            // Shortest round-trip digits: pinned targets equal their rest
            // vertices exactly.
            format!("    {{\"vertex\": {v}, \"to\": [{}, {}]}}", to.x, to.y)
        })
        .collect();
    std::fs::write(
        out.join("handles.json"),
        format!("{{\n  \"handles\": [\n{}\n  ]\n}}\n", entries.join(",\n")),
    )
    .expect("write the handles");
    println!(
        "{} vertices, {} triangles, {} pieces, {} handles -> {}",
        mesh.vertices().len(),
        mesh.triangles().len(),
        mesh.pieces().len(),
        handles.len(),
        out.display()
    );
}
