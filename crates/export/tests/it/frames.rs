//! PNG sequences: the files, the placement of the stage, and — in Chromium
//! — the pixels against the real web renderer drawing the same vertices.
//!
//! Tolerance against the web renderer (both composited over the page's
//! background): per channel, the mean absolute difference over the whole
//! picture ≤ 1.0 (of 255), and at least 99% of pixels within 8 on every
//! channel. The differences left are at the puppets' edges: the GPU's 4×
//! MSAA sample positions, rounding and texture filtering precision differ
//! slightly from ours. A frame 10 frames off must fail.

use puppetry_export::frames::{PngOptions, export_png_sequence, frame_name};
use puppetry_export::load_png;

use crate::common::{arg, browser_enabled, node_script, note};
use crate::fixture::{picture_path, two_figures};

const FRAMES: usize = 30;

#[test]
fn png_sequence_names_every_frame_and_keeps_the_background_transparent() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("frames");
    let animation = two_figures(FRAMES, 30.0);
    let mut steps = Vec::new();
    let options = PngOptions {
        width: 400,
        height: 300,
    };
    let mut progress = |done, total| steps.push((done, total));
    export_png_sequence(&animation, &options, &mut progress, &out).unwrap();
    // Every frame once, in order.
    assert_eq!(steps, (1..=FRAMES).map(|k| (k, FRAMES)).collect::<Vec<_>>());
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    let expected: Vec<String> = (0..FRAMES).map(frame_name).collect();
    assert_eq!(names, expected);
    assert_eq!(names[0], "frame_00000.png");
    let img = load_png(&out.join("frame_00012.png")).unwrap();
    assert_eq!((img.width, img.height), (400, 300));
    let px = |x: u32, y: u32| {
        let i = ((y * img.width + x) * 4) as usize;
        [
            img.pixels[i],
            img.pixels[i + 1],
            img.pixels[i + 2],
            img.pixels[i + 3],
        ]
    };
    assert_eq!(px(0, 0), [0, 0, 0, 0], "the background is transparent");
    assert_eq!(px(399, 299)[3], 0);
    // The big figure's belly, half size: stage (360, 60 + 230) → (180, 155).
    assert_eq!(px(180, 155)[3], 255, "the puppet is opaque");
    let coverage: usize = img.pixels.chunks_exact(4).filter(|p| p[3] > 0).count();
    assert!(coverage > 5000, "{coverage} pixels drawn");
}

#[test]
fn the_stage_is_fitted_and_centred_as_the_page_does() {
    // A 4:3 stage in a 2:1 picture: scale 300/600, centred, 100 px of
    // transparent margin each side.
    let dir = tempfile::tempdir().unwrap();
    let animation = two_figures(1, 30.0);
    let wide = PngOptions {
        width: 600,
        height: 300,
    };
    export_png_sequence(&animation, &wide, &mut (), dir.path()).unwrap();
    let img = load_png(&dir.path().join(frame_name(0))).unwrap();
    let narrow = tempfile::tempdir().unwrap();
    let exact = PngOptions {
        width: 400,
        height: 300,
    };
    export_png_sequence(&animation, &exact, &mut (), narrow.path()).unwrap();
    let reference = load_png(&narrow.path().join(frame_name(0))).unwrap();
    for y in 0..300usize {
        let row = &img.pixels[y * 600 * 4..][..600 * 4];
        assert!(
            row[..100 * 4].iter().all(|&b| b == 0),
            "left margin row {y}"
        );
        assert!(
            row[500 * 4..].iter().all(|&b| b == 0),
            "right margin row {y}"
        );
        assert_eq!(
            &row[100 * 4..500 * 4],
            &reference.pixels[y * 400 * 4..][..400 * 4]
        );
    }
}

/// Straight RGBA over the page's background (renderer.js BACKGROUND).
fn over_page(pixels: &[u8]) -> Vec<f64> {
    const BACKGROUND: [f64; 3] = [0.96 * 255.0, 0.95 * 255.0, 0.92 * 255.0];
    pixels
        .chunks_exact(4)
        .flat_map(|p| {
            let a = p[3] as f64 / 255.0;
            (0..3).map(move |c| p[c] as f64 * a + BACKGROUND[c] * (1.0 - a))
        })
        .collect()
}

/// (mean absolute difference per channel, fraction of pixels within 8).
fn compare(ours: &[f64], browser: &[u8]) -> (f64, f64) {
    let mut sum = 0.0;
    let mut close = 0usize;
    let pixels = ours.len() / 3;
    for p in 0..pixels {
        let mut worst = 0.0f64;
        for c in 0..3 {
            let d = (ours[p * 3 + c] - browser[p * 4 + c] as f64).abs();
            sum += d;
            worst = worst.max(d);
        }
        close += (worst <= 8.0) as usize;
    }
    (sum / (pixels * 3) as f64, close as f64 / pixels as f64)
}

#[test]
fn png_frame_matches_the_web_renderer() {
    if !browser_enabled("png_frame_matches_the_web_renderer") {
        return;
    }
    let (w, h) = (800u32, 600u32);
    let animation = two_figures(FRAMES, 30.0);
    let dir = tempfile::tempdir().unwrap();
    let ours_dir = dir.path().join("ours");
    let options = PngOptions {
        width: w,
        height: h,
    };
    export_png_sequence(&animation, &options, &mut (), &ours_dir).unwrap();
    // The page draws frames 5 and 15 from the same vertices.
    let frames = [5usize, 15];
    let scene = serde_json::json!({
        "stage": {"width": animation.stage_width, "height": animation.stage_height},
        "size": [w, h],
        "puppets": animation.puppets.iter().map(|p| serde_json::json!({
            "name": p.name,
            "texture": picture_path(),
            "uv": p.uv.iter().flatten().collect::<Vec<_>>(),
            "triangles": p.triangles.iter().flatten().collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "frames": frames.iter().map(|&k| serde_json::json!({
            "name": format!("frame{k}"),
            "positions": animation.puppets.iter()
                .map(|p| p.frames[k].iter().flatten().collect::<Vec<_>>())
                .collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    });
    let scene_file = dir.path().join("scene.json");
    std::fs::write(&scene_file, scene.to_string()).unwrap();
    let browser_dir = dir.path().join("browser");
    node_script(
        "export-render.mjs",
        &["playwright-core", "ws"],
        &[arg(&scene_file), arg(&browser_dir)],
    );
    for &k in &frames {
        let browser = std::fs::read(browser_dir.join(format!("frame{k}.rgba"))).unwrap();
        assert_eq!(browser.len(), (w * h * 4) as usize);
        let ours = over_page(&load_png(&ours_dir.join(frame_name(k))).unwrap().pixels);
        let (mean, within) = compare(&ours, &browser);
        note(&format!(
            "PNG frame {k} vs the web renderer: mean |Δ| {mean:.3} per channel, {:.3}% of pixels within 8",
            within * 100.0
        ));
        assert!(mean <= 1.0, "frame {k}: mean difference {mean}");
        assert!(
            within >= 0.99,
            "frame {k}: only {within} of pixels within 8"
        );
        // A wrong frame must not pass.
        let wrong = over_page(&load_png(&ours_dir.join(frame_name(k + 10))).unwrap().pixels);
        let (mean, within) = compare(&wrong, &browser);
        note(&format!(
            "PNG frame {} vs the web renderer's frame {k}: mean |Δ| {mean:.3}, {:.3}% within 8",
            k + 10,
            within * 100.0
        ));
        assert!(
            !(mean <= 1.0 && within >= 0.99),
            "frame {} passes for frame {k}: mean {mean}, within {within}",
            k + 10
        );
    }
}
