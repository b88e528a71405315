//! Bad input is refused with an error naming the flag, field or file.

use puppetry_export::frames::{PngOptions, export_png_sequence};
use puppetry_export::gltf::{GltfOptions, export_glb};
use puppetry_export::video::{VideoOptions, export_video};
use puppetry_export::{ExportError, load_png};

use crate::fixture::two_figures;

fn text(e: ExportError) -> String {
    e.to_string()
}

#[test]
fn an_unknown_video_extension_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("take.avi");
    let err = text(
        export_video(
            &two_figures(2, 30.0),
            &VideoOptions::new(64, 64),
            &mut (),
            &path,
        )
        .unwrap_err(),
    );
    assert!(
        err.contains("\".avi\"") && err.contains("take.avi"),
        "{err}"
    );
    assert!(err.contains(".mp4, .mov or .webm"), "{err}");
    assert!(!path.exists());
}

#[test]
fn an_odd_size_for_mp4_names_size() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("take.mp4");
    let err = text(
        export_video(
            &two_figures(2, 30.0),
            &VideoOptions::new(321, 240),
            &mut (),
            &path,
        )
        .unwrap_err(),
    );
    assert!(err.starts_with("--size: 321x240"), "{err}");
    assert!(err.contains("even"), "{err}");
}

#[test]
fn a_zero_size_names_size() {
    let dir = tempfile::tempdir().unwrap();
    let options = PngOptions {
        width: 0,
        height: 10,
    };
    let err = text(
        export_png_sequence(&two_figures(1, 30.0), &options, &mut (), dir.path()).unwrap_err(),
    );
    assert!(err.starts_with("--size: 0x10"), "{err}");
}

#[test]
fn mismatched_vertex_counts_name_the_frame() {
    let mut animation = two_figures(5, 30.0);
    animation.puppets[1].frames[3].pop();
    let err = text(animation.validate().unwrap_err());
    assert_eq!(
        err,
        "puppets[1] \"gingerbread\".frames[3]: has 998 vertices, expected 999 (one per uv)"
    );
    // Every exporter checks first.
    let dir = tempfile::tempdir().unwrap();
    let glb = text(
        export_glb(
            &animation,
            &GltfOptions::default(),
            &mut (),
            &dir.path().join("a.glb"),
        )
        .unwrap_err(),
    );
    assert!(
        glb.starts_with("puppets[1] \"gingerbread\".frames[3]"),
        "{glb}"
    );
}

#[test]
fn other_inconsistencies_name_their_field() {
    type Spoil = Box<dyn Fn(&mut puppetry_export::Animation)>;
    let cases: Vec<(&str, Spoil)> = vec![
        (
            "fps: must be a positive frame rate",
            Box::new(|a| a.fps = 0.0),
        ),
        (
            "fps: must be a positive frame rate",
            Box::new(|a| a.fps = f64::NAN),
        ),
        (
            "stage_width: must be a positive number",
            Box::new(|a| a.stage_width = -1.0),
        ),
        (
            "frame_count: the animation has no frames",
            Box::new(|a| {
                a.frame_count = 0;
                for p in &mut a.puppets {
                    p.frames.clear();
                }
            }),
        ),
        (
            "puppets[0] \"gingerbread\".frames: has 4 frames, expected frame_count = 5",
            Box::new(|a| {
                a.puppets[0].frames.pop();
            }),
        ),
        (
            "puppets[0] \"gingerbread\".uv: the puppet has no vertices",
            Box::new(|a| a.puppets[0].uv.clear()),
        ),
        (
            "puppets[0] \"gingerbread\".triangles[7]: vertex index 5000 is out of range",
            Box::new(|a| {
                a.puppets[0].triangles[7][1] = 5000;
            }),
        ),
        (
            "puppets[1] \"gingerbread\".frames[2][10]: is not a finite number",
            Box::new(|a| {
                a.puppets[1].frames[2][10][0] = f32::INFINITY;
            }),
        ),
        (
            "puppets[0] \"gingerbread\".image.pixels: has 3 bytes",
            Box::new(|a| {
                a.puppets[0].image.pixels.truncate(3);
            }),
        ),
    ];
    for (expected, spoil) in cases {
        let mut animation = two_figures(5, 30.0);
        spoil(&mut animation);
        let err = text(animation.validate().unwrap_err());
        assert!(
            err.starts_with(expected),
            "expected {expected:?}, got {err:?}"
        );
    }
}

#[test]
fn a_bad_chunk_size_names_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let options = GltfOptions {
        chunk: 0,
        ..GltfOptions::default()
    };
    let err = text(
        export_glb(
            &two_figures(2, 30.0),
            &options,
            &mut (),
            &dir.path().join("a.glb"),
        )
        .unwrap_err(),
    );
    assert!(err.starts_with("--chunk: "), "{err}");
}

#[test]
fn an_unwritable_output_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("missing/folder/take.glb");
    let err = text(
        export_glb(
            &two_figures(2, 30.0),
            &GltfOptions::default(),
            &mut (),
            &path,
        )
        .unwrap_err(),
    );
    assert!(err.starts_with(&format!("{}: ", path.display())), "{err}");
}

/// PNGs of every colour type and depth load as straight RGBA8.
#[test]
fn load_png_expands_every_colour_type() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, color: png::ColorType, depth: png::BitDepth, data: &[u8]| {
        let path = dir.path().join(name);
        let file = std::fs::File::create(&path).unwrap();
        let mut e = png::Encoder::new(file, 2, 1);
        e.set_color(color);
        e.set_depth(depth);
        e.write_header().unwrap().write_image_data(data).unwrap();
        path
    };
    use png::{BitDepth::*, ColorType::*};
    let cases = [
        (
            write("g8.png", Grayscale, Eight, &[10, 200]),
            vec![10, 10, 10, 255, 200, 200, 200, 255],
        ),
        (
            write("ga8.png", GrayscaleAlpha, Eight, &[10, 20, 200, 0]),
            vec![10, 10, 10, 20, 200, 200, 200, 0],
        ),
        (
            write("rgb8.png", Rgb, Eight, &[1, 2, 3, 4, 5, 6]),
            vec![1, 2, 3, 255, 4, 5, 6, 255],
        ),
        (
            write("rgba8.png", Rgba, Eight, &[1, 2, 3, 4, 5, 6, 7, 8]),
            vec![1, 2, 3, 4, 5, 6, 7, 8],
        ),
        (
            write("g16.png", Grayscale, Sixteen, &[0x12, 0x34, 0xff, 0x00]),
            vec![0x12, 0x12, 0x12, 255, 0xff, 0xff, 0xff, 255],
        ),
        (
            write(
                "rgba16.png",
                Rgba,
                Sixteen,
                &[1, 0, 2, 0, 3, 0, 4, 0, 5, 0, 6, 0, 7, 0, 8, 9],
            ),
            vec![1, 2, 3, 4, 5, 6, 7, 8],
        ),
        (
            write("g1.png", Grayscale, One, &[0b1000_0000]),
            vec![255, 255, 255, 255, 0, 0, 0, 255],
        ),
    ];
    for (path, expected) in cases {
        let img = load_png(&path).unwrap();
        assert_eq!((img.width, img.height), (2, 1));
        assert_eq!(img.pixels, expected, "{}", path.display());
    }
    let not_png = dir.path().join("not.png");
    std::fs::write(&not_png, b"hello").unwrap();
    let err = text(load_png(&not_png).unwrap_err());
    assert!(
        err.starts_with(&format!("{}: ", not_png.display())) && err.contains("not a valid PNG"),
        "{err}"
    );
    let missing = dir.path().join("missing.png");
    let err = text(load_png(&missing).unwrap_err());
    assert!(
        err.starts_with(&format!("{}: ", missing.display())),
        "{err}"
    );
}

/// An export reads pictures as the stage does (issue 32): a small PNG
/// claiming 16384 × 16384 pixels (1 GiB as RGBA) is refused from its
/// header, naming the limit, where the decoder used to allocate it; and a
/// device is not read at all.
#[test]
fn load_png_refuses_a_picture_bomb_and_a_device() {
    let dir = tempfile::tempdir().unwrap();
    let bomb = dir.path().join("bomb.png");
    let file = std::io::BufWriter::new(std::fs::File::create(&bomb).unwrap());
    let mut e = png::Encoder::new(file, 16384, 16384);
    e.set_color(png::ColorType::Grayscale);
    e.set_depth(png::BitDepth::One);
    let mut stream = e.write_header().unwrap().into_stream_writer().unwrap();
    let row = [0u8; 16384 / 8];
    for _ in 0..16384 {
        std::io::Write::write_all(&mut stream, &row).unwrap();
    }
    stream.finish().unwrap();
    let err = text(load_png(&bomb).unwrap_err());
    assert!(err.contains("MAX_PICTURE_PIXELS"), "{err}");
    let err = text(load_png(std::path::Path::new("/dev/zero")).unwrap_err());
    assert!(err.contains("not a regular file"), "{err}");
}

#[test]
fn a_missing_ffmpeg_says_how_to_install_it() {
    let dir = tempfile::tempdir().unwrap();
    let err = puppetry_export::video::find_ffmpeg_in(dir.path().as_os_str()).unwrap_err();
    assert_eq!(
        err.to_string(),
        "ffmpeg not found on PATH; install it (Debian: apt-get install ffmpeg)"
    );
}
