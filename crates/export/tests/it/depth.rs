//! Depth in exports: a take in which the demo figure's arm is dragged
//! across its pinned chest renders with the arm wholly over the body, as
//! the page draws it: where arm and body overlap and their pictures differ,
//! the exported pixel is the arm's.

use std::path::Path;

use glam::DVec2;
use puppetry_export::raster::{Rasterizer, textures};
use puppetry_export::take::animation_of_take;
use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;

use puppetry_testkit::stage_text::{Gingerbread, STAGE};

const FPS: f64 = 30.0;

fn config(depth: &str) -> StageConfig {
    let text = format!(
        "{STAGE}{}",
        Gingerbread::new("gingerbread")
            .pins("[[168, 58], [344, 58], [256, 250]]")
            .with(&format!("depth = \"{depth}\""))
    );
    StageConfig::parse("depth-take.toml", &text, Path::new("/")).unwrap()
}

/// A take of the right hand dragged across the chest, a step per frame.
fn record_fold(path: &Path, config: &StageConfig) {
    let mut stage = Stage::from_config(config).unwrap();
    let points = fold_points(&mut stage);
    crate::fixture::record_drag(path, &mut stage, "fold", FPS, &points);
}

/// The right hand's path across the chest.
fn fold_points(stage: &mut Stage) -> Vec<DVec2> {
    stage.solve();
    let right = stage.puppets()[0].mesh.vertices().iter().copied().fold(
        DVec2::splat(f64::NEG_INFINITY),
        |a, b| {
            if b.x > a.x { b } else { a }
        },
    );
    let from = right - DVec2::new(15.0, 0.0);
    let to = DVec2::new(610.0, 350.0);
    (0..=12).map(|k| from.lerp(to, k as f64 / 12.0)).collect()
}

/// Of the overlap's sample points where the two triangles' texels differ
/// clearly: (those showing the nearer one, those showing the farther one).
fn overlap_pixels(depth_mode: &str) -> (usize, usize) {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("fold.take");
    // The order to judge by is always the depth order's: with depth off the
    // export draws in mesh order, which this should catch.
    let judged = config("pieces");
    let config = config(depth_mode);
    record_fold(&take, &judged);
    let animation = animation_of_take(&take, &config, FPS, None, None).unwrap();
    let ordered = animation_of_take(&take, &judged, FPS, None, None).unwrap();
    let k = animation.frame_count - 1;
    let rank = rank_of(&ordered.puppets[0].draw_orders[k]);
    drawn_in_rank(&animation, k, &rank)
}

/// Each triangle's place in a drawing order, back to front.
fn rank_of(order: &[u32]) -> Vec<usize> {
    let mut rank = vec![0; order.len()];
    for (i, &t) in order.iter().enumerate() {
        rank[t as usize] = i;
    }
    rank
}

/// Renders frame `k` of the first puppet and counts the overlap's telling
/// samples that show the part `rank` puts nearer, and those that do not.
fn drawn_in_rank(
    animation: &puppetry_export::Animation,
    k: usize,
    rank: &[usize],
) -> (usize, usize) {
    let p = &animation.puppets[0];
    let (w, h) = (1280u32, 720u32);
    let textures = textures(animation);
    let mut raster = Rasterizer::new(animation, &textures, w, h);
    let view = raster.viewport();
    let mut out = vec![0u8; (w * h * 4) as usize];
    raster.render(k, &mut out);

    let pos = &p.frames[k];
    let texel = |t: usize, l: [f64; 3]| {
        let [a, b, c] = p.triangles[t].map(|v| v as usize);
        let u = l[0] * p.uv[a][0] as f64 + l[1] * p.uv[b][0] as f64 + l[2] * p.uv[c][0] as f64;
        let v = l[0] * p.uv[a][1] as f64 + l[1] * p.uv[b][1] as f64 + l[2] * p.uv[c][1] as f64;
        let x = ((u * p.image.width as f64) as u32).min(p.image.width - 1);
        let y = ((v * p.image.height as f64) as u32).min(p.image.height - 1);
        let i = ((y * p.image.width + x) * 4) as usize;
        [
            p.image.pixels[i],
            p.image.pixels[i + 1],
            p.image.pixels[i + 2],
            p.image.pixels[i + 3],
        ]
    };
    let inside = |t: usize, q: DVec2| -> Option<[f64; 3]> {
        let [a, b, c] = p.triangles[t]
            .map(|v| DVec2::new(pos[v as usize][0] as f64, pos[v as usize][1] as f64));
        let d = (b - c).perp_dot(a - c);
        if d.abs() < 1e-9 {
            return None;
        }
        let l1 = (b - c).perp_dot(q - c) / d;
        let l2 = (c - a).perp_dot(q - c) / d;
        let l3 = 1.0 - l1 - l2;
        (l1 > 0.1 && l2 > 0.1 && l3 > 0.1).then_some([l1, l2, l3])
    };
    let distance = |a: [u8; 4], b: [u8; 4]| -> u32 {
        (0..3)
            .map(|i| (a[i] as i32 - b[i] as i32).unsigned_abs())
            .sum()
    };
    let (mut near, mut far) = (0, 0);
    for xi in 0..(1280 / 3) {
        for yi in 0..(720 / 3) {
            let q = DVec2::new(xi as f64 * 3.0 + 0.5, yi as f64 * 3.0 + 0.5);
            let mut over: Vec<(usize, [f64; 3])> = (0..p.triangles.len())
                .filter_map(|t| inside(t, q).map(|l| (t, l)))
                .collect();
            if over.len() < 2 {
                continue;
            }
            over.sort_by_key(|(t, _)| rank[*t]);
            let (back, front) = (over[0], over[over.len() - 1]);
            let (tb, tf) = (texel(back.0, back.1), texel(front.0, front.1));
            if tb[3] < 250 || tf[3] < 250 || distance(tb, tf) < 90 {
                continue;
            }
            let [px, py] = view.to_pixel([q.x as f32, q.y as f32]);
            let i = ((py as u32 * w + px as u32) * 4) as usize;
            let drawn = [out[i], out[i + 1], out[i + 2], 255];
            if distance(drawn, tf) < distance(drawn, tb) {
                near += 1;
            } else {
                far += 1;
            }
        }
    }
    eprintln!("{near} samples show the nearer part, {far} the farther");
    (near, far)
}

#[test]
fn an_exported_fold_shows_the_arm_over_the_body() {
    let (near, far) = overlap_pixels("pieces");
    assert!(near >= 30 && far * 10 <= near, "near {near}, far {far}");
}

/// Alt+click during the take: the body under the fold goes in front, live
/// and so in the export (which once ran the depth order over the frames
/// alone and drew the arm in front still).
#[test]
fn an_exported_fold_keeps_a_depth_flip_made_during_the_take() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("flip.take");
    let config = config("pieces");
    let (stage, before) = record_fold_and_flip(&take, &config);
    let live = rank_of(&live_order(&stage));
    let before = rank_of(&before);
    assert_ne!(
        live, before,
        "the flip changed nothing live: nothing to check"
    );
    let animation = animation_of_take(&take, &config, FPS, None, None).unwrap();
    let k = animation.frame_count - 1;
    let (near, far) = drawn_in_rank(&animation, k, &live);
    assert!(near >= 30 && far * 10 <= near, "near {near}, far {far}");
    // And the same frame judged by the order before the flip: the export
    // does not draw that any more.
    let (near, far) = drawn_in_rank(&animation, k, &before);
    assert!(far >= 30 && near * 10 <= far, "near {near}, far {far}");
}

/// A take of the right hand dragged across the chest and held still, with
/// an Alt+click on the fold at step 13; the stage after it, and its first
/// puppet's drawing order just before the flip.
fn record_fold_and_flip(take: &Path, config: &StageConfig) -> (Stage, Vec<u32>) {
    let mut stage = Stage::from_config(config).unwrap();
    let mut points = fold_points(&mut stage);
    let at = *points.last().unwrap();
    // Held still at the fold for a while after the flip.
    points.extend([at; 6]);
    let mut before = Vec::new();
    crate::fixture::record_drag_with(take, &mut stage, "flip", FPS, &points, |k, stage| {
        if k != 13 {
            return Vec::new();
        }
        before = live_order(stage);
        vec![puppetry_stage::Change::DepthFlip {
            at: overlap_point(stage),
        }]
    });
    (stage, before)
}

/// The live stage's drawing order of its first puppet.
fn live_order(stage: &Stage) -> Vec<u32> {
    let (depth, _) = stage.puppets()[0].depth().unwrap();
    let mut order: Vec<u32> = (0..depth.len() as u32).collect();
    order.sort_by_key(|&t| depth[t as usize]);
    order
}

/// A point of the first puppet's pose covered by two triangles of
/// different depths: where an Alt+click flips the fold.
fn overlap_point(stage: &Stage) -> DVec2 {
    let p = &stage.puppets()[0];
    let (depth, _) = p.depth().unwrap();
    let pose = p.pose();
    let tris = p.mesh.triangles();
    let corners = |t: &[u32; 3]| t.map(|v| pose[v as usize]);
    let covers = |[a, b, c]: [DVec2; 3], q: DVec2| {
        let d = (b - c).perp_dot(a - c);
        let l1 = (b - c).perp_dot(q - c) / d;
        let l2 = (c - a).perp_dot(q - c) / d;
        d.abs() > 1e-9 && l1 > 0.0 && l2 > 0.0 && 1.0 - l1 - l2 > 0.0
    };
    tris.iter()
        .enumerate()
        .find_map(|(t, tri)| {
            let [a, b, c] = corners(tri);
            let q = (a + b + c) / 3.0;
            tris.iter()
                .enumerate()
                .any(|(u, other)| u != t && depth[u] != depth[t] && covers(corners(other), q))
                .then_some(q)
        })
        .expect("the fold overlaps")
}

#[test]
fn without_depth_the_export_interleaves_the_fold() {
    // The same take with depth off draws in mesh order: the body shows
    // through the arm in places. (This is what the test above guards.)
    let (near, far) = overlap_pixels("off");
    assert!(far * 5 >= near, "near {near}, far {far}");
}

/// glTF carries the fold too: three.js draws a mesh's triangles in index
/// order, and each chunk of the exported puppet lists them in its frames'
/// drawing order, so at every sampled frame the triangles three.js draws
/// are the stage's, back to front (they were mesh order throughout).
#[test]
fn the_glb_lists_each_frames_triangles_in_its_drawing_order() {
    if !crate::common::browser_enabled("the_glb_lists_each_frames_triangles_in_its_drawing_order") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("fold.take");
    let config = config("pieces");
    record_fold(&take, &config);
    let animation = animation_of_take(&take, &config, FPS, None, None).unwrap();
    let p = &animation.puppets[0];
    let mesh_order: Vec<[u32; 3]> = p.triangles.clone();
    let frames: Vec<usize> = (0..animation.frame_count).collect();
    let folded = frames
        .iter()
        .filter(|&&k| p.triangles_drawn(k).copied().collect::<Vec<_>>() != mesh_order)
        .count();
    assert!(folded > 0, "the take never folds: nothing to check");
    let glb = dir.path().join("fold.glb");
    let options = puppetry_export::gltf::GltfOptions {
        chunk: 4,
        ..Default::default()
    };
    puppetry_export::gltf::export_glb(&animation, &options, &mut (), &glb).unwrap();
    // Chunks cut where the order changes, each with its own indices: the
    // file still validates clean.
    let report = crate::common::node_script(
        "export-validate.mjs",
        &["gltf-validator"],
        &[crate::common::arg(&glb)],
    );
    assert_eq!(report["issues"]["numErrors"], 0, "{report}");
    assert_eq!(report["issues"]["numWarnings"], 0, "{report}");
    let times: Vec<String> = frames
        .iter()
        .map(|&k| (k as f64 / FPS).to_string())
        .collect();
    let result = crate::common::node_script(
        "export-three.mjs",
        &["three", "playwright-core"],
        &[crate::common::arg(&glb), &times.join(","), "indices"],
    );
    for (&k, sample) in frames.iter().zip(result["samples"].as_array().unwrap()) {
        let drawn: Vec<u32> = sample["puppets"][0]["indices"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as u32)
            .collect();
        let expected: Vec<u32> = p.triangles_drawn(k).flatten().copied().collect();
        assert_eq!(drawn, expected, "frame {k}: three.js draws another order");
    }
    crate::common::note(&format!(
        "three.js draws the stage's order at all {} frames, {folded} of them folded",
        frames.len()
    ));
    // A depth-tested render (Blender) sees the part in front nearer: at
    // the last frame, where two triangles overlap, the one drawn in front
    // stands higher in z as three.js reads the positions.
    let k = animation.frame_count - 1;
    let xyz: Vec<f64> = result["samples"][k]["puppets"][0]["positions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let (higher, lower) = nearer_in_z(p, k, &xyz);
    crate::common::note(&format!(
        "glb z: {higher} overlap samples nearer in front, {lower} behind"
    ));
    assert!(
        higher >= 100 && lower * 50 <= higher,
        "{higher} in front, {lower} behind"
    );
}

/// Of the sample points where two triangles of frame `k` overlap: those
/// where the one drawn in front (by depth) is the higher in z (`xyz`,
/// three.js's positions), and those where it is lower.
fn nearer_in_z(p: &puppetry_export::AnimatedPuppet, k: usize, xyz: &[f64]) -> (usize, usize) {
    let corner = |v: u32| DVec2::new(xyz[3 * v as usize], xyz[3 * v as usize + 1]);
    let (mut higher, mut lower) = (0, 0);
    for xi in 0..(1280 / 4) {
        for yi in 0..(720 / 4) {
            let q = DVec2::new(xi as f64 * 4.0 + 0.5, yi as f64 * 4.0 + 0.5);
            let over: Vec<(usize, f64)> = (0..p.triangles.len())
                .filter_map(|t| {
                    let [a, b, c] = p.triangles[t].map(corner);
                    let d = (b - c).perp_dot(a - c);
                    let l1 = (b - c).perp_dot(q - c) / d;
                    let l2 = (c - a).perp_dot(q - c) / d;
                    let l3 = 1.0 - l1 - l2;
                    let inside = d.abs() > 1e-9 && l1 > 0.05 && l2 > 0.05 && l3 > 0.05;
                    let [za, zb, zc] = p.triangles[t].map(|v| xyz[3 * v as usize + 2]);
                    inside.then_some((t, l1 * za + l2 * zb + l3 * zc))
                })
                .collect();
            if over.len() < 2 {
                continue;
            }
            let front = *over.iter().max_by_key(|(t, _)| p.depths[k][*t]).unwrap();
            // Strictly nearer than every other: at one z a depth test mixes them.
            let others = over.iter().filter(|&&(t, _)| t != front.0);
            if others.map(|&(_, z)| z).all(|z| front.1 > z + 1e-6) {
                higher += 1;
            } else {
                lower += 1;
            }
        }
    }
    (higher, lower)
}

/// Spine draws a mesh attachment's triangles in one order, so a puppet
/// whose fold changes sides comes as one attachment per drawing order,
/// switched by attachment keys. Read back in spine-core at every frame,
/// wherever two triangles of the frame overlap, the one the page drew in
/// front is the later in the attachment Spine shows (the fold, and after
/// the Alt+click flip the body), and the vertices are the frame's.
#[test]
fn spine_shows_a_fold_and_its_flip_as_the_page_did() {
    if !crate::common::browser_enabled("spine_shows_a_fold_and_its_flip_as_the_page_did") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("flip.take");
    let config = config("pieces");
    record_fold_and_flip(&take, &config);
    let animation = animation_of_take(&take, &config, FPS, None, None).unwrap();
    let p = &animation.puppets[0];
    let json = dir.path().join("flip.json");
    let layout = puppetry_export::spine::export_spine(
        &animation,
        &puppetry_export::spine::SpineOptions::default(),
        &mut (),
        &json,
    )
    .unwrap();
    let placed = &layout.puppets[0];
    assert!(placed.attachments.len() >= 2, "{:?}", placed.attachments);
    // A triangle by its corners, as the puppet's vertices.
    let key = |mut t: [u32; 3]| {
        t.sort_unstable();
        t
    };
    let triangle_of: std::collections::HashMap<[u32; 3], usize> = p
        .triangles
        .iter()
        .enumerate()
        .map(|(i, &t)| (key(t), i))
        .collect();
    let ks: Vec<usize> = (0..animation.frame_count).collect();
    let times: Vec<String> = ks.iter().map(|&k| (k as f64 / FPS).to_string()).collect();
    let result = crate::common::node_script(
        "export-spine.mjs",
        &["@esotericsoftware/spine-core"],
        &[crate::common::arg(&json), "take", &times.join(",")],
    );
    let (mut checked, mut wrong) = (0, 0);
    let mut shown = std::collections::HashSet::new();
    for (sample, &k) in result["samples"].as_array().unwrap().iter().zip(&ks) {
        let attached = &sample["attached"][&placed.slot];
        shown.insert(attached["name"].as_str().unwrap().to_string());
        let indices: Vec<u32> = attached["triangles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| placed.order[v.as_u64().unwrap() as usize])
            .collect();
        let mut rank = vec![usize::MAX; p.triangles.len()];
        for (i, corners) in indices.chunks(3).enumerate() {
            rank[triangle_of[&key([corners[0], corners[1], corners[2]])]] = i;
        }
        assert!(
            rank.iter().all(|&r| r != usize::MAX),
            "frame {k}: a triangle is missing"
        );
        let pos = &p.frames[k];
        let corner = |v: u32| DVec2::new(pos[v as usize][0] as f64, pos[v as usize][1] as f64);
        let boxes: Vec<(DVec2, DVec2)> = p
            .triangles
            .iter()
            .map(|t| {
                let c = t.map(corner);
                (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]))
            })
            .collect();
        for xi in 0..(1280 / 4) {
            for yi in 0..(720 / 4) {
                let q = DVec2::new(xi as f64 * 4.0 + 0.5, yi as f64 * 4.0 + 0.5);
                let over: Vec<usize> = (0..p.triangles.len())
                    .filter(|&t| boxes[t].0.cmple(q).all() && q.cmple(boxes[t].1).all())
                    .filter(|&t| {
                        let [a, b, c] = p.triangles[t].map(corner);
                        let d = (b - c).perp_dot(a - c);
                        let l1 = (b - c).perp_dot(q - c) / d;
                        let l2 = (c - a).perp_dot(q - c) / d;
                        d.abs() > 1e-9 && l1 > 0.05 && l2 > 0.05 && 1.0 - l1 - l2 > 0.05
                    })
                    .collect();
                if over.len() < 2 {
                    continue;
                }
                checked += 1;
                let front = *over.iter().max_by_key(|&&t| p.depths[k][t]).unwrap();
                let last = *over.iter().max_by_key(|&&t| rank[t]).unwrap();
                if front != last {
                    wrong += 1;
                }
            }
        }
        let world = sample["slots"][&placed.slot].as_array().unwrap();
        for (i, &v) in placed.order.iter().enumerate() {
            let e = p.frames[k][v as usize];
            for c in 0..2 {
                let got = world[i * 2 + c].as_f64().unwrap();
                assert!((got - e[c] as f64).abs() <= 1e-4, "frame {k}, vertex {v}");
            }
        }
    }
    eprintln!(
        "spine: {checked} overlap samples, {wrong} drawn otherwise than the page; attachments shown: {shown:?}"
    );
    assert!(checked >= 100, "{checked} samples");
    assert_eq!(wrong, 0, "{wrong} of {checked} samples");
    assert!(shown.len() >= 2, "{shown:?}");
}
