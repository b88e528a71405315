//! Times the glTF and PNG-sequence exports of a synthetic 60 s take at 60
//! fps (3600 frames) of the demo puppet (999 vertices) on a 1280×720 stage,
//! drawn at 1280×720:
//!
//!     cargo run --release -p puppetry-export --example bench [-- --frames N] [--keep DIR]
//!
//! Writes into a temporary folder (removed afterwards unless `--keep`).

#[path = "../tests/it/fixture.rs"]
#[allow(dead_code)]
mod fixture;

use std::time::Instant;

use puppetry_export::Animation;
use puppetry_export::frames::{PngOptions, export_png_sequence};
use puppetry_export::gltf::{GltfOptions, export_glb};

fn main() {
    let mut frames = 3600;
    let mut keep = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--frames" => {
                frames = args
                    .next()
                    .and_then(|v| v.parse().ok())
                    .expect("--frames N")
            }
            "--keep" => keep = args.next().map(std::path::PathBuf::from),
            other => panic!("unknown argument {other}"),
        }
    }
    let fps = 60.0;
    let animation = Animation {
        stage_width: 1280.0,
        stage_height: 720.0,
        fps,
        puppets: vec![fixture::bending_puppet(
            "gingerbread",
            frames,
            [640.0, 60.0],
            1.2,
            0.6,
            120.0,
            0.0,
        )],
        frame_count: frames,
    };
    let vertices = animation.puppets[0].vertex_count();
    if std::env::var_os("BENCH_PHASES").is_some() {
        phases(&animation);
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = keep.clone().unwrap_or_else(|| dir.path().to_path_buf());
    std::fs::create_dir_all(&out).unwrap();
    println!(
        "{frames} frames at {fps} fps ({:.0} s), {vertices} vertices, {} triangles",
        frames as f64 / fps,
        animation.puppets[0].triangles.len()
    );

    let glb = out.join("take.glb");
    let t = Instant::now();
    export_glb(&animation, &GltfOptions::default(), &mut (), &glb).unwrap();
    let seconds = t.elapsed().as_secs_f64();
    let size = std::fs::metadata(&glb).unwrap().len();
    println!("glb: {seconds:.2} s, {:.1} MB", size as f64 / 1e6);

    let pngs = out.join("frames");
    let t = Instant::now();
    let options = PngOptions {
        width: 1280,
        height: 720,
    };
    export_png_sequence(&animation, &options, &mut (), &pngs).unwrap();
    let seconds = t.elapsed().as_secs_f64();
    let size: u64 = std::fs::read_dir(&pngs)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    println!(
        "png sequence 1280x720: {seconds:.2} s ({:.2} ms per frame on {} threads), {:.1} MB",
        seconds * 1e3 / frames as f64,
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        size as f64 / 1e6
    );
}

/// One thread: drawing alone, then PNG encoding alone, per frame.
fn phases(animation: &Animation) {
    use puppetry_export::raster::{Rasterizer, textures};
    let textures = textures(animation);
    let mut r = Rasterizer::new(animation, &textures, 1280, 720);
    let mut buf = vec![0u8; 1280 * 720 * 4];
    let n = animation.frame_count.min(300);
    let t = Instant::now();
    for k in 0..n {
        r.render(k, &mut buf);
    }
    println!(
        "draw: {:.2} ms per frame",
        t.elapsed().as_secs_f64() * 1e3 / n as f64
    );
    let t = Instant::now();
    let mut bytes = 0;
    for _ in 0..n {
        let mut out = Vec::new();
        puppetry_export::write_png(&mut out, 1280, 720, &buf).unwrap();
        bytes += out.len();
    }
    println!(
        "encode: {:.2} ms per frame, {} KB",
        t.elapsed().as_secs_f64() * 1e3 / n as f64,
        bytes / n / 1024
    );
}
