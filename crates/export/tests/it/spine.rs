//! Spine JSON: Spine's own runtime (spine-core 4.2, in Node) reads it and
//! poses the meshes at frame times exactly as the frames.

use std::collections::HashSet;

use puppetry_export::spine::{SpineOptions, export_spine, hull};

use crate::common::{arg, node_script, note};
use crate::fixture::two_figures;

const FRAMES: usize = 30;
const FPS: f64 = 30.0;

#[test]
fn spine_runtime_poses_the_frames() {
    let animation = two_figures(FRAMES, FPS);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("take.json");
    let layout = export_spine(&animation, &SpineOptions::default(), &mut (), &path).unwrap();
    // Two puppets of one name get two slots.
    let slots: Vec<&str> = layout.puppets.iter().map(|p| p.slot.as_str()).collect();
    assert_eq!(slots, ["gingerbread", "gingerbread 2"]);
    for p in &layout.puppets {
        assert!(dir.path().join(format!("{}.png", p.path)).is_file());
    }
    let ks = [0usize, 1, 7, 15, 22, 29];
    let times: Vec<String> = ks.iter().map(|&k| (k as f64 / FPS).to_string()).collect();
    let result = node_script(
        "export-spine.mjs",
        &["@esotericsoftware/spine-core"],
        &[arg(&path), "take", &times.join(",")],
    );
    assert_eq!(result["version"], puppetry_export::spine::SPINE_VERSION);
    // The clip lasts as long as the take's video (it lasted (n − 1) / fps).
    let duration = result["duration"].as_f64().unwrap();
    assert!(
        (duration - FRAMES as f64 / FPS).abs() < 1e-9,
        "{duration} s"
    );
    // The atlas beside the JSON: spine-core found every attachment's
    // region in it, one page per picture, each page the picture written.
    let pages = result["atlas"]
        .as_array()
        .expect("an atlas beside the JSON");
    assert_eq!(pages.len(), layout.puppets.len());
    for (page, (p, placed)) in pages
        .iter()
        .zip(animation.puppets.iter().zip(&layout.puppets))
    {
        assert_eq!(page["name"], format!("{}.png", placed.path));
        assert_eq!(
            (page["width"].as_u64(), page["height"].as_u64()),
            (Some(p.image.width as u64), Some(p.image.height as u64))
        );
        let written =
            puppetry_export::load_png(&dir.path().join(format!("{}.png", placed.path))).unwrap();
        assert_eq!(written, p.image);
    }
    // Named after the export, never a picture of the user's own.
    assert!(layout.puppets.iter().all(|p| p.path.starts_with("take-")));
    for p in &layout.puppets {
        assert_eq!(result["hull"][&p.slot], p.hull as u64, "hull of {}", p.slot);
    }
    let samples = result["samples"].as_array().unwrap();
    assert_eq!(samples.len(), ks.len());
    let mut worst_all = 0.0f64;
    for (sample, &k) in samples.iter().zip(&ks) {
        for (p, placed) in animation.puppets.iter().zip(&layout.puppets) {
            let world = sample["slots"][&placed.slot].as_array().unwrap();
            assert_eq!(world.len(), placed.order.len() * 2);
            let mut worst = 0.0f64;
            for (i, &v) in placed.order.iter().enumerate() {
                let e = p.frames[k][v as usize];
                let g = |c: usize| world[i * 2 + c].as_f64().unwrap();
                worst = worst
                    .max((g(0) - e[0] as f64).abs())
                    .max((g(1) - e[1] as f64).abs());
            }
            assert!(worst <= 1e-4, "frame {k}, {}: off by {worst}", placed.slot);
            worst_all = worst_all.max(worst);
        }
    }
    note(&format!(
        "spine-core: every vertex within {worst_all:.2e} stage units of its frame"
    ));
}

#[test]
fn the_hull_is_the_boundary_loop_and_comes_first() {
    let animation = two_figures(2, FPS);
    let p = &animation.puppets[0];
    let loop_ = hull(&p.triangles);
    // Every step of the loop (and back to its start) is a boundary edge:
    // an edge of exactly one triangle, run the way that triangle runs it.
    let directed: HashSet<(u32, u32)> = p
        .triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    for i in 0..loop_.len() {
        let (a, b) = (loop_[i], loop_[(i + 1) % loop_.len()]);
        assert!(
            directed.contains(&(a, b)) && !directed.contains(&(b, a)),
            "{a}→{b}"
        );
    }
    // The demo mesh is one piece without holes: every boundary edge is on it.
    let boundary = directed
        .iter()
        .filter(|&&(a, b)| !directed.contains(&(b, a)))
        .count();
    assert_eq!(boundary, loop_.len());
    let dir = tempfile::tempdir().unwrap();
    let layout = export_spine(
        &animation,
        &SpineOptions::default(),
        &mut (),
        &dir.path().join("s.json"),
    )
    .unwrap();
    assert_eq!(&layout.puppets[0].order[..loop_.len()], &loop_[..]);
    assert_eq!(layout.puppets[0].hull, loop_.len());
    // A permutation of all vertices.
    let mut sorted = layout.puppets[0].order.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, (0..p.vertex_count() as u32).collect::<Vec<_>>());
}

/// The bundle the page downloads: one zip of the JSON, its atlas and its
/// pictures, which unpacked into any folder spine-player opens as it is
/// (the page once downloaded the JSON alone: the atlas answered 404).
#[test]
fn spine_player_opens_the_zip_the_page_downloads_unpacked() {
    if !crate::common::browser_enabled("spine_player_opens_the_zip_the_page_downloads_unpacked") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("take-007.zip");
    puppetry_export::spine::export_spine_zip(
        &two_figures(FRAMES, FPS),
        &SpineOptions::default(),
        &mut (),
        &path,
    )
    .unwrap();
    // Nothing but the zip is left where it was written.
    let beside: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(beside.len(), 1, "{beside:?}");
    let unpacked = tempfile::tempdir().unwrap();
    let mut zip = zip::ZipArchive::new(std::fs::File::open(&path).unwrap()).unwrap();
    let mut names: Vec<String> = zip.file_names().map(|n| n.unwrap().into_owned()).collect();
    names.sort();
    assert!(names.contains(&"take-007.json".to_string()), "{names:?}");
    assert!(names.contains(&"take-007.atlas".to_string()), "{names:?}");
    assert!(
        names.iter().filter(|n| n.ends_with(".png")).count() == 2,
        "{names:?}"
    );
    zip.extract(unpacked.path()).unwrap();
    let result = node_script(
        "export-player.mjs",
        &["@esotericsoftware/spine-player", "playwright-core"],
        &[arg(unpacked.path()), "take-007", "take"],
    );
    assert_eq!(result["loaded"], true, "{result}");
    assert_eq!(result["failed"], serde_json::json!([]), "{result}");
    assert!(result["drawn"].as_u64().unwrap() > 1000, "{result}");
}

/// spine-player, Esoteric's web player, opens the export as it is in
/// Chromium: the atlas and its pages load (no request answered 404, as
/// the atlas did before there was one) and the puppets are drawn.
#[test]
fn spine_player_opens_the_export_as_it_is() {
    if !crate::common::browser_enabled("spine_player_opens_the_export_as_it_is") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("take.json");
    export_spine(
        &two_figures(FRAMES, FPS),
        &SpineOptions::default(),
        &mut (),
        &path,
    )
    .unwrap();
    let result = node_script(
        "export-player.mjs",
        &["@esotericsoftware/spine-player", "playwright-core"],
        &[arg(dir.path()), "take", "take"],
    );
    assert_eq!(result["loaded"], true, "{result}");
    assert_eq!(result["failed"], serde_json::json!([]), "{result}");
    assert_eq!(result["errors"], serde_json::json!([]), "{result}");
    let drawn = result["drawn"].as_u64().unwrap();
    assert!(drawn > 1000, "the player drew {drawn} pixels: {result}");
    note(&format!("spine-player: loaded, {drawn} pixels drawn"));
}
