//! glTF binary: the Khronos validator passes it, its structure holds what
//! the module promises, and three.js plays it back to the exact frames.

use puppetry_export::gltf::{GltfOptions, chunks, export_glb};

use crate::common::{arg, browser_enabled, node_script, note};
use crate::fixture::two_figures;

const FRAMES: usize = 30;
const FPS: f64 = 30.0;
/// Small chunks, so 30 frames make 4 chunks and the seams get tested.
const CHUNK: usize = 8;

fn export(dir: &std::path::Path) -> std::path::PathBuf {
    let path = dir.join("take.glb");
    let options = GltfOptions {
        chunk: CHUNK,
        ..GltfOptions::default()
    };
    let mut steps = Vec::new();
    let mut progress = |done: usize, total: usize| steps.push((done, total));
    export_glb(&two_figures(FRAMES, FPS), &options, &mut progress, &path).unwrap();
    // 4 chunks × 2 puppets, reported in order, ending at the total.
    assert_eq!(steps.len(), 8);
    assert_eq!(steps.last(), Some(&(8, 8)));
    path
}

/// The JSON chunk of a .glb, after checking the container.
fn glb_json(bytes: &[u8]) -> serde_json::Value {
    let u32_at = |i: usize| u32::from_le_bytes(bytes[i..i + 4].try_into().unwrap()) as usize;
    assert_eq!(&bytes[0..4], b"glTF");
    assert_eq!(u32_at(4), 2);
    assert_eq!(u32_at(8), bytes.len());
    let json_len = u32_at(12);
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(json_len % 4, 0);
    let bin_at = 20 + json_len;
    assert_eq!(&bytes[bin_at + 4..bin_at + 8], b"BIN\0");
    assert_eq!(u32_at(bin_at) % 4, 0);
    serde_json::from_slice(&bytes[20..bin_at]).unwrap()
}

#[test]
fn chunks_share_their_seam_frames() {
    assert_eq!(chunks(1, 32), vec![(0, 0)]);
    assert_eq!(chunks(2, 32), vec![(0, 1)]);
    assert_eq!(chunks(33, 32), vec![(0, 32)]);
    assert_eq!(chunks(34, 32), vec![(0, 32), (32, 33)]);
    assert_eq!(chunks(30, 8), vec![(0, 8), (8, 16), (16, 24), (24, 29)]);
    // Where the drawing order changes (at 3, and at the last frame), a
    // chunk ends; a frame a chunk shows has its first frame's order.
    let a: std::sync::Arc<[u32]> = vec![0, 1].into();
    let b: std::sync::Arc<[u32]> = vec![1, 0].into();
    let orders = [&a, &a, &a, &b, &b, &b, &b, &a].map(|o| o.clone());
    assert_eq!(
        puppetry_export::gltf::spans(8, 32, &orders),
        vec![(0, 3), (3, 7), (7, 7)]
    );
    assert_eq!(
        puppetry_export::gltf::spans(8, 2, &orders),
        vec![(0, 2), (2, 3), (3, 5), (5, 7), (7, 7)]
    );
    assert_eq!(puppetry_export::gltf::spans(30, 8, &[]), chunks(30, 8));
}

#[test]
fn glb_holds_chunked_morph_targets_with_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(export(dir.path())).unwrap();
    let gltf = glb_json(&bytes);
    // Per puppet: a node with 4 chunk children; 8 meshes of 8, 8, 8, 5 targets.
    let scene: Vec<usize> = gltf["scenes"][0]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_u64().unwrap() as usize)
        .collect();
    assert_eq!(scene.len(), 2);
    let targets: Vec<usize> = gltf["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            m["primitives"][0]["targets"]
                .as_array()
                .map_or(0, |t| t.len())
        })
        .collect();
    assert_eq!(targets, [8, 8, 8, 5, 8, 8, 8, 5]);
    for &p in &scene {
        assert_eq!(gltf["nodes"][p]["children"].as_array().unwrap().len(), 4);
    }
    let material = &gltf["materials"][0];
    assert_eq!(material["alphaMode"], "BLEND");
    assert_eq!(material["doubleSided"], true);
    assert!(material["extensions"]["KHR_materials_unlit"].is_object());
    // Every POSITION accessor (bases and targets) has min and max, z = 0.
    let accessors = gltf["accessors"].as_array().unwrap();
    let mut positions = 0;
    for m in gltf["meshes"].as_array().unwrap() {
        let prim = &m["primitives"][0];
        let mut all = vec![prim["attributes"]["POSITION"].as_u64().unwrap()];
        for t in prim["targets"].as_array().into_iter().flatten() {
            all.push(t["POSITION"].as_u64().unwrap());
        }
        for a in all {
            let a = &accessors[a as usize];
            assert_eq!(a["min"][2], 0.0);
            assert_eq!(a["max"][2], 0.0);
            positions += 1;
        }
    }
    assert_eq!(positions, 2 * (4 + 29));
    for view in gltf["bufferViews"].as_array().unwrap() {
        assert_eq!(view["byteOffset"].as_u64().unwrap() % 4, 0);
    }
}

#[test]
fn glb_passes_the_khronos_validator() {
    let dir = tempfile::tempdir().unwrap();
    let path = export(dir.path());
    let report = node_script("export-validate.mjs", &["gltf-validator"], &[arg(&path)]);
    let issues = &report["issues"];
    let messages = issues["messages"].as_array().unwrap();
    let mut seen = std::collections::BTreeMap::new();
    for m in messages {
        let key = format!(
            "severity {} {}: {}",
            m["severity"],
            m["code"].as_str().unwrap(),
            m["message"].as_str().unwrap()
        );
        *seen.entry(key).or_insert(0) += 1;
    }
    let listing: Vec<String> = seen.iter().map(|(k, n)| format!("{n}× {k}")).collect();
    note(&format!(
        "gltf-validator: {} errors, {} warnings, {} infos, {} hints\n  {}",
        issues["numErrors"],
        issues["numWarnings"],
        issues["numInfos"],
        issues["numHints"],
        listing.join("\n  ")
    ));
    assert_eq!(issues["numErrors"], 0, "{listing:#?}");
    assert_eq!(issues["numWarnings"], 0, "{listing:#?}");
}

#[test]
fn three_js_plays_the_glb_back_to_the_frames() {
    if !browser_enabled("three_js_plays_the_glb_back_to_the_frames") {
        return;
    }
    let animation = two_figures(FRAMES, FPS);
    let dir = tempfile::tempdir().unwrap();
    let path = export(dir.path());
    // Frames inside chunks, on seams (8, 16, 24), the first and the last;
    // then halfway between frames, which must blend the two neighbours.
    let exact = [0usize, 3, 8, 15, 16, 24, 29];
    let between = [4usize, 7, 16, 27];
    let mut times: Vec<String> = exact
        .iter()
        .map(|&k| (k as f64 / FPS).to_string())
        .collect();
    times.extend(
        between
            .iter()
            .map(|&k| ((k as f64 + 0.5) / FPS).to_string()),
    );
    let result = node_script(
        "export-three.mjs",
        &["three", "playwright-core"],
        &[arg(&path), &times.join(",")],
    );
    let samples = result["samples"].as_array().unwrap();
    assert_eq!(samples.len(), exact.len() + between.len());
    // The clip lasts as long as the take's video: the last frame is held
    // for its frame's time (it lasted (n − 1) / fps).
    let duration = result["duration"].as_f64().unwrap();
    assert!(
        (duration - FRAMES as f64 / FPS).abs() < 1e-5,
        "clip of {duration} s, expected {} s",
        FRAMES as f64 / FPS
    );
    // Stacked in drawing order: the later puppet nearer, so three.js
    // (sorting transparent meshes by depth) draws it on top.
    let z: Vec<f64> = samples[0]["puppets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["z"].as_f64().unwrap())
        .collect();
    assert!(
        z[0] < z[1],
        "puppets at z {z:?}: the top one must be nearer"
    );
    let mut worst_all = 0.0f64;
    for (s, sample) in samples.iter().enumerate() {
        let puppets = sample["puppets"].as_array().unwrap();
        assert_eq!(puppets.len(), 2);
        for (i, p) in puppets.iter().enumerate() {
            assert_eq!(p["chunks"], 4);
            let shown = p["shown"].as_array().unwrap();
            assert_eq!(
                shown.len(),
                1,
                "t = {}: one chunk shown: {shown:?}",
                sample["t"]
            );
            let got = p["positions"].as_array().unwrap();
            let frames = &animation.puppets[i].frames;
            let expected: Vec<[f64; 2]> = if s < exact.len() {
                frames[exact[s]].iter().map(|q| q.map(f64::from)).collect()
            } else {
                let k = between[s - exact.len()];
                frames[k]
                    .iter()
                    .zip(&frames[k + 1])
                    .map(|(a, b)| {
                        [
                            (a[0] as f64 + b[0] as f64) / 2.0,
                            (a[1] as f64 + b[1] as f64) / 2.0,
                        ]
                    })
                    .collect()
            };
            assert_eq!(got.len(), expected.len() * 3);
            let mut worst = 0.0f64;
            for (v, e) in expected.iter().enumerate() {
                let g = |c: usize| got[v * 3 + c].as_f64().unwrap();
                worst = worst
                    .max((g(0) - e[0]).abs())
                    .max((g(1) - e[1]).abs())
                    .max(g(2).abs());
            }
            assert!(
                worst <= 1e-4,
                "t = {}, puppet {i}: off by {worst} stage units",
                sample["t"]
            );
            worst_all = worst_all.max(worst);
        }
    }
    note(&format!(
        "three.js: every sampled vertex within {worst_all:.2e} stage units of its frame"
    ));
}

#[test]
fn short_and_uneven_takes_validate_too() {
    // One frame (no morph targets, one visibility key), two frames, and a
    // last chunk of one target.
    let dir = tempfile::tempdir().unwrap();
    for frames in [1usize, 2, 34] {
        let path = dir.path().join(format!("take{frames}.glb"));
        export_glb(
            &two_figures(frames, FPS),
            &GltfOptions::default(),
            &mut (),
            &path,
        )
        .unwrap();
        let report = node_script("export-validate.mjs", &["gltf-validator"], &[arg(&path)]);
        let issues = &report["issues"];
        assert_eq!(issues["numErrors"], 0, "{frames} frames: {issues}");
        assert_eq!(issues["numWarnings"], 0, "{frames} frames: {issues}");
    }
}

/// A solid square puppet of `colour` over `x0..x1 × y0..y1`, still, its
/// picture `side` pixels square.
fn square(
    name: &str,
    colour: [u8; 3],
    [x0, y0, x1, y1]: [f32; 4],
    side: u32,
) -> puppetry_export::AnimatedPuppet {
    let corners = vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
    puppetry_export::AnimatedPuppet {
        name: name.into(),
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        uv: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        image: puppetry_export::RgbaImage {
            width: side,
            height: side,
            pixels: [colour[0], colour[1], colour[2], 255].repeat((side * side) as usize),
        },
        frames: vec![corners.clone(), corners],
        draw_orders: Vec::new(),
        depths: Vec::new(),
        snaps: Vec::new(),
        skeleton: None,
    }
}

/// three.js renders two overlapping puppets in the stage's order: where
/// they overlap, the one drawn later on the stage is the one seen, both
/// ways round (every puppet lay at z = 0 before, and three.js chose).
#[test]
fn three_js_draws_the_top_puppet_on_top() {
    if !browser_enabled("three_js_draws_the_top_puppet_on_top") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // The bottom puppet's picture large, the top one's tiny: three.js
    // then makes the top mesh first (its texture decodes first), and with
    // every puppet at one depth it drew them in that order, the bottom
    // one last, on top.
    let (big, small) = (2048, 4);
    let cases = [
        (
            square("red", [255, 0, 0], [100.0, 100.0, 500.0, 500.0], big),
            square("blue", [0, 0, 255], [300.0, 100.0, 700.0, 500.0], small),
        ),
        (
            square("blue", [0, 0, 255], [300.0, 100.0, 700.0, 500.0], big),
            square("red", [255, 0, 0], [100.0, 100.0, 500.0, 500.0], small),
        ),
    ];
    let red = &cases[0].0;
    let blue = &cases[0].1;
    for (bottom, top) in &cases {
        let animation = puppetry_export::Animation {
            stage_width: 800.0,
            stage_height: 600.0,
            fps: FPS,
            frame_count: 2,
            puppets: vec![bottom.clone(), top.clone()],
        };
        let path = dir
            .path()
            .join(format!("{}-under-{}.glb", bottom.name, top.name));
        export_glb(&animation, &GltfOptions::default(), &mut (), &path).unwrap();
        let result = node_script(
            "export-three.mjs",
            &["three", "playwright-core"],
            &[
                arg(&path),
                "render",
                "0",
                "200,300,400,300,600,300",
                "800",
                "600",
            ],
        );
        let colours: Vec<Vec<u64>> = result["colours"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| {
                c.as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_u64().unwrap())
                    .collect()
            })
            .collect();
        let is = |c: &Vec<u64>, p: &puppetry_export::AnimatedPuppet| {
            let want = &p.image.pixels[..3];
            c.iter()
                .zip(want)
                .all(|(&g, &w)| (g as i64 - w as i64).abs() <= 8)
        };
        let (left, middle, right) = (&colours[0], &colours[1], &colours[2]);
        let lone = |c: &Vec<u64>| {
            if is(c, red) {
                "red"
            } else if is(c, blue) {
                "blue"
            } else {
                "neither"
            }
        };
        assert_eq!((lone(left), lone(right)), ("red", "blue"), "{colours:?}");
        assert!(
            is(middle, top),
            "{} over {}: three.js shows {} where they overlap ({colours:?})",
            top.name,
            bottom.name,
            lone(middle)
        );
    }
}
