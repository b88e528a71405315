//! Videos through ffmpeg: ffprobe must see the codec, the pixel format
//! (with alpha for .mov and .webm), the frame rate and the duration, and a
//! decoded frame must show the puppet — over white for .mp4, over
//! transparency for the others.

use std::path::Path;
use std::process::Command;

use puppetry_export::video::{VideoOptions, export_video, frame_rate_arg};

use crate::common::{arg, require_tool};
use crate::fixture::two_figures;

const FRAMES: usize = 36;
const FPS: f64 = 24.0;
const W: u32 = 320;
const H: u32 = 240;

fn tools() {
    require_tool("ffmpeg", "Debian: apt-get install ffmpeg");
    require_tool("ffprobe", "Debian: apt-get install ffmpeg");
}

/// ffprobe's view of the first video stream and the container.
fn probe(path: &Path) -> serde_json::Value {
    puppetry_testkit::sound::probe(
        path,
        &[
            "-select_streams",
            "v:0",
            "-count_frames",
            "-show_entries",
            "stream=codec_name,profile,pix_fmt,r_frame_rate,nb_read_frames,width,height,color_space,color_primaries,color_transfer,color_range:stream_tags:format=duration",
        ],
    )
}

/// Frame `k` decoded to RGBA by ffmpeg (with `decoder`, when given):
/// as ffmpeg reads the file's tags, or, with `bt709`, as a browser
/// decodes it (BT.709, limited range, whatever the file says).
fn decode_as(path: &Path, decoder: Option<&str>, k: usize, bt709: bool) -> Vec<u8> {
    let mut cmd = Command::new("ffmpeg");
    cmd.args(["-v", "error", "-nostdin"]);
    if let Some(d) = decoder {
        cmd.args(["-c:v", d]);
    }
    let mut filter = format!("select=eq(n\\,{k})");
    if bt709 {
        filter.push_str(",scale=in_color_matrix=bt709:in_range=tv");
    }
    let out = cmd
        .arg("-i")
        .arg(path)
        .args(["-vf", &filter, "-frames:v", "1"])
        .args(["-f", "rawvideo", "-pix_fmt", "rgba", "-"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(out.stdout.len(), (W * H * 4) as usize);
    out.stdout
}

/// Frame `k` decoded to RGBA as ffmpeg reads the file.
fn decode(path: &Path, decoder: Option<&str>, k: usize) -> Vec<u8> {
    decode_as(path, decoder, k, false)
}

/// The pixel format ffmpeg decodes to with `decoder` (ffprobe 5 cannot
/// choose a decoder, and only libvpx returns VP9's alpha).
fn decoded_pix_fmt(path: &Path, decoder: &str) -> String {
    let out = Command::new("ffmpeg")
        .args(["-hide_banner", "-nostdin", "-c:v", decoder, "-i"])
        .arg(path)
        .args(["-frames:v", "1", "-f", "null", "-"])
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    let line = log
        .lines()
        .find(|l| l.contains("Stream #0:0") && l.contains("Video: vp9"))
        .unwrap_or_else(|| panic!("no input stream line in {log}"));
    line.split(", ")
        .nth(1)
        .unwrap()
        .split('(')
        .next()
        .unwrap()
        .to_string()
}

/// Exports a video, then checks it: ffprobe's `codec`, `profile` (when
/// given) and pixel format starting with `pix_fmt`; frame rate, frame count
/// and duration; frame 0's pixels decoded with `decoder`.
fn check(
    ext: &str,
    codec: &str,
    profile: Option<&str>,
    pix_fmt: &str,
    decoder: Option<&str>,
    alpha: bool,
) {
    tools();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(format!("take.{ext}"));
    let mut frames = 0;
    let mut progress = |done, _| frames = done;
    export_video(
        &two_figures(FRAMES, FPS),
        &VideoOptions::new(W, H),
        &mut progress,
        &path,
    )
    .unwrap();
    assert_eq!(frames, FRAMES);
    let info = probe(&path);
    let stream = &info["streams"][0];
    assert_eq!(stream["codec_name"], codec, "{info}");
    if let Some(profile) = profile {
        assert_eq!(stream["profile"], profile, "{info}");
    }
    assert!(
        stream["pix_fmt"].as_str().unwrap().starts_with(pix_fmt),
        "{info}"
    );
    assert_eq!(stream["r_frame_rate"], "24/1", "{info}");
    // BT.709, limited range, tagged: what browsers assume of untagged video.
    for (tag, value) in [
        ("color_space", "bt709"),
        ("color_primaries", "bt709"),
        ("color_transfer", "bt709"),
        ("color_range", "tv"),
    ] {
        assert_eq!(stream[tag], value, "{ext}: {tag} in {info}");
    }
    assert_eq!(
        (stream["width"].as_u64(), stream["height"].as_u64()),
        (Some(W as u64), Some(H as u64))
    );
    assert_eq!(stream["nb_read_frames"], FRAMES.to_string(), "{info}");
    let duration: f64 = info["format"]["duration"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    let expected = FRAMES as f64 / FPS;
    assert!(
        (duration - expected).abs() <= 1.0 / FPS,
        "{ext}: duration {duration} s, expected {expected} s within a frame"
    );
    // Frame 0: a corner is background, the big figure's belly is puppet.
    // (Stage 800×600 at 0.4: the belly (360, 290) is pixel (144, 124).)
    let px = decode(&path, decoder, 0);
    let at = |x: u32, y: u32| &px[((y * W + x) * 4) as usize..][..4];
    if alpha {
        assert!(
            at(2, 2)[3] <= 2,
            "{ext}: corner {:?} is transparent",
            at(2, 2)
        );
    } else {
        // The page's stage colour, as a viewer saw the stage (it was
        // white, unlike the page).
        let stage = puppetry_export::video::STAGE_COLOUR;
        assert!(
            at(2, 2)[..3]
                .iter()
                .zip(stage)
                .all(|(&c, s)| c.abs_diff(s) <= 3),
            "{ext}: corner {:?} is the stage's colour {stage:?}",
            at(2, 2)
        );
    }
    assert!(at(144, 124)[3] >= 250, "{ext}: the puppet is opaque");
    assert!(
        at(144, 124)[..3].iter().any(|&c| c < 230),
        "{ext}: the puppet is not background {:?}",
        at(144, 124)
    );
    if ext == "webm" {
        // ffprobe's own VP9 decoder sees the colour planes (yuv420p) and
        // the tag saying an alpha plane rides beside them; libvpx decodes
        // both.
        assert_eq!(stream["tags"]["alpha_mode"], "1", "{info}");
        assert_eq!(decoded_pix_fmt(&path, "libvpx-vp9"), "yuva420p");
    }
}

#[test]
fn mp4_is_h264_over_the_stage_colour_at_the_frame_rate() {
    check("mp4", "h264", Some("High"), "yuv420p", None, false);
}

#[test]
fn mov_is_prores_4444_with_alpha() {
    // Encoded from yuva444p10le; ffmpeg's ProRes decoder returns 12 bits.
    check("mov", "prores", Some("4444"), "yuva444p1", None, true);
}

#[test]
fn webm_is_vp9_with_alpha() {
    check("webm", "vp9", None, "yuv420p", Some("libvpx-vp9"), true);
}

#[test]
fn frame_rates_reach_ffmpeg_as_exact_fractions() {
    assert_eq!(frame_rate_arg(30.0), "30/1");
    assert_eq!(frame_rate_arg(30000.0 / 1001.0), "30000/1001");
    assert_eq!(frame_rate_arg(12.5), "12500/1000");
    // NTSC rates as people write them (was 2997/100 for 29.97).
    assert_eq!(frame_rate_arg(29.97), "30000/1001");
    assert_eq!(frame_rate_arg(23.976), "24000/1001");
    assert_eq!(frame_rate_arg(59.94), "60000/1001");
    assert_eq!(frame_rate_arg(29.9), "29900/1000");
}

#[test]
fn a_failing_ffmpeg_is_quoted() {
    // A "ffmpeg" that complains and fails: its last lines reach the error.
    tools();
    let dir = tempfile::tempdir().unwrap();
    let fake = dir.path().join("ffmpeg");
    std::fs::write(
        &fake,
        "#!/bin/sh\necho 'first line' >&2\necho 'Unknown encoder libx264' >&2\nexit 3\n",
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let mut options = VideoOptions::new(W, H);
    options.ffmpeg = Some(fake);
    let out = dir.path().join("take.mp4");
    let err = export_video(&two_figures(3, FPS), &options, &mut (), &out).unwrap_err();
    let text = err.to_string();
    assert!(text.contains(arg(&out)), "{text}");
    assert!(text.contains("Unknown encoder libx264"), "{text}");
    assert!(text.contains("exit status: 3"), "{text}");
}

/// A red square filling the stage: the colour a player shows. Decoded as
/// a browser decodes it (BT.709, whatever the file says), the red comes
/// back within a few levels; converted with ffmpeg's default BT.601 and
/// untagged, Chromium showed (231, 55, 52) for (214, 38, 52).
#[test]
fn colours_come_back_as_a_bt709_player_shows_them() {
    tools();
    const RED: [u8; 3] = [214, 38, 52];
    let still: Vec<[f32; 2]> = vec![
        [-10.0, -10.0],
        [810.0, -10.0],
        [810.0, 610.0],
        [-10.0, 610.0],
    ];
    let animation = puppetry_export::Animation {
        stage_width: 800.0,
        stage_height: 600.0,
        fps: FPS,
        frame_count: 2,
        puppets: vec![puppetry_export::AnimatedPuppet {
            name: "red".into(),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            uv: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
            image: puppetry_export::RgbaImage {
                width: 4,
                height: 4,
                pixels: [RED[0], RED[1], RED[2], 255].repeat(16),
            },
            frames: vec![still.clone(), still],
            draw_orders: Vec::new(),
            depths: Vec::new(),
            snaps: Vec::new(),
            skeleton: None,
        }],
    };
    let dir = tempfile::tempdir().unwrap();
    for (ext, decoder) in [("mp4", None), ("mov", None), ("webm", Some("libvpx-vp9"))] {
        let path = dir.path().join(format!("red.{ext}"));
        export_video(&animation, &VideoOptions::new(W, H), &mut (), &path).unwrap();
        let decoded = decode_as(&path, decoder, 0, true);
        let centre = ((H / 2 * W + W / 2) * 4) as usize;
        let got = &decoded[centre..centre + 3];
        let off = got
            .iter()
            .zip(RED)
            .map(|(&g, r)| (g as i32 - r as i32).abs())
            .max()
            .unwrap();
        assert!(off <= 4, "{ext}: red {RED:?} shows as {got:?}");
    }
}

/// Every video shows what the PNG export shows: frames decoded as a
/// BT.709 player decodes them match the PNG sequence's (composited over
/// white for .mp4, premultiplied for the others) within the codec's loss.
#[test]
fn decoded_frames_match_the_png_export() {
    tools();
    let animation = two_figures(FRAMES, FPS);
    let dir = tempfile::tempdir().unwrap();
    let pngs = dir.path().join("png");
    let options = puppetry_export::frames::PngOptions {
        width: W,
        height: H,
    };
    puppetry_export::frames::export_png_sequence(&animation, &options, &mut (), &pngs).unwrap();
    let mut lines = Vec::new();
    for (ext, decoder, opaque, tolerance) in [
        ("mp4", None, true, 2.0),
        ("mov", None, false, 1.0),
        ("webm", Some("libvpx-vp9"), false, 2.5),
    ] {
        let path = dir.path().join(format!("take.{ext}"));
        export_video(&animation, &VideoOptions::new(W, H), &mut (), &path).unwrap();
        let mut worst = 0.0f64;
        for k in [0, FRAMES / 2, FRAMES - 1] {
            let decoded = decode_as(&path, decoder, k, true);
            let png = puppetry_export::load_png(&pngs.join(puppetry_export::frames::frame_name(k)))
                .unwrap()
                .pixels;
            assert_eq!(decoded.len(), png.len());
            // Compared as what is shown: over the stage's colour without alpha,
            // premultiplied colour and alpha with it.
            let shown = |px: &[u8]| -> [f64; 4] {
                let a = px[3] as f64 / 255.0;
                let stage = puppetry_export::video::STAGE_COLOUR;
                let c = |i: usize| {
                    px[i] as f64 * a
                        + if opaque {
                            f64::from(stage[i]) * (1.0 - a)
                        } else {
                            0.0
                        }
                };
                [c(0), c(1), c(2), if opaque { 255.0 } else { px[3] as f64 }]
            };
            let mut sum = 0.0;
            for (got, want) in decoded.chunks_exact(4).zip(png.chunks_exact(4)) {
                let (g, w) = (shown(got), shown(want));
                sum += (0..4).map(|i| (g[i] - w[i]).abs()).sum::<f64>() / 4.0;
            }
            let mean = sum / (W * H) as f64;
            assert!(
                mean <= tolerance,
                "{ext} frame {k}: {mean:.2} levels from the PNG on average (at most {tolerance})"
            );
            worst = worst.max(mean);
        }
        lines.push(format!("{ext} {worst:.2}"));
    }
    crate::common::note(&format!(
        "decoded videos vs the PNG export, mean levels off (worst of 3 frames): {}",
        lines.join(", ")
    ));
}

/// A soundtrack muxed in lines up with the picture: its second `at` plays
/// with the first frame (the click at 1 s heard at 0.5 s with `at` 0.5,
/// at 1.25 s with `at` −0.25), within one video frame, in every kind.
#[test]
fn a_soundtrack_is_muxed_in_time_with_the_frames() {
    tools();
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("click.wav");
    puppetry_testkit::sound::click_track(&wav, 3.0, &[1.0]);
    let animation = two_figures(FRAMES, FPS);
    let mut lines = Vec::new();
    for (ext, codec) in [("mp4", "aac"), ("mov", "pcm_s16le"), ("webm", "opus")] {
        for (at, heard) in [(0.5, 0.5), (-0.25, 1.25)] {
            let path = dir.path().join(format!("take{at}.{ext}"));
            let mut options = VideoOptions::new(W, H);
            options.audio = Some(puppetry_export::video::Soundtrack {
                file: wav.clone(),
                at,
            });
            export_video(&animation, &options, &mut (), &path).unwrap();
            let out = Command::new("ffprobe")
                .args(["-v", "error", "-select_streams", "a:0"])
                .args(["-show_entries", "stream=codec_name", "-of", "csv=p=0"])
                .arg(&path)
                .output()
                .unwrap();
            assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), codec, "{ext}");
            // The pictures start at 0 (a webm's once started 7 ms late,
            // shifted by Opus's pre-skip).
            let picture = &puppetry_testkit::sound::probe(
                &path,
                &[
                    "-select_streams",
                    "v:0",
                    "-show_entries",
                    "stream=start_time",
                ],
            )["streams"][0]["start_time"];
            assert_eq!(
                picture.as_str(),
                Some("0.000000"),
                "{ext}: pictures start at {picture}"
            );
            let onset = puppetry_testkit::sound::first_onset(&path);
            assert!(
                (onset - heard).abs() <= 1.0 / FPS,
                "{ext}, sound at {at} s: the click is heard at {onset:.4} s, expected {heard} s"
            );
            lines.push(format!("{ext} {:+.1} ms", (onset - heard) * 1000.0));
            // The picture is whole: every frame is there.
            assert_eq!(
                probe(&path)["streams"][0]["nb_read_frames"],
                FRAMES.to_string()
            );
        }
    }
    crate::common::note(&format!("soundtrack onsets off by: {}", lines.join(", ")));
}
