//! Video through `ffmpeg`: the frames of [`crate::raster`] are piped raw
//! (`-f rawvideo -pix_fmt rgba -s WxH -r FPS -i -`) into an `ffmpeg` found
//! on `PATH`, which encodes by the output's extension:
//!
//! | extension | codec | pixels | alpha |
//! |---|---|---|---|
//! | `.mp4` | H.264 (`libx264`) | `yuv420p` | no: composited over [`VideoOptions::background`] (default the page's stage colour); width and height must be even |
//! | `.mov` | ProRes 4444 (`prores_aw -profile:v 4`, ap4h) | `yuva444p10le` | yes |
//! | `.webm` | VP9 (`libvpx-vp9`) | `yuva420p` | yes (stored beside the colour planes; `ffprobe` shows `yuv420p` with the tag `alpha_mode=1`, and decoding with `-c:v libvpx-vp9` gives it back) |
//!
//! Every kind is BT.709 in limited range, converted so and tagged so
//! (`color_space`, `color_primaries`, `color_transfer` all `bt709`), as
//! browsers and editors read untagged video anyway.
//!
//! ffmpeg's messages are captured; when it fails, the error quotes its last
//! lines. ffmpeg writes a new file beside the output, renamed onto it once
//! finished (see [`crate::write_new`]).

use std::io::{BufRead, Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};

use crate::raster::{check_size, render_frames};
use crate::{Animation, ExportError, Progress, flag};

/// Options of a video export.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoOptions {
    /// Picture width in pixels (`--size WxH`).
    pub width: u32,
    /// Picture height in pixels.
    pub height: u32,
    /// What `.mp4` (no alpha) shows behind the puppets: RGB.
    pub background: [u8; 3],
    /// The `ffmpeg` to run; `None` looks it up on `PATH`.
    pub ffmpeg: Option<std::path::PathBuf>,
    /// A soundtrack to mux in, if any.
    pub audio: Option<Soundtrack>,
}

/// A soundtrack for a video: a sound file ffmpeg reads (WAV, FLAC, MP3,
/// AAC…) and where in it the video's first frame falls.
#[derive(Debug, Clone, PartialEq)]
pub struct Soundtrack {
    /// The sound file.
    pub file: std::path::PathBuf,
    /// Seconds into the sound at the video's first frame: positive skips
    /// the sound's start, negative lets the video run that long before the
    /// sound begins.
    pub at: f64,
}

impl Soundtrack {
    /// ffmpeg's arguments for the sound as its second input, placed so its
    /// second `at` plays with the first frame, and read for no longer than
    /// the video's `duration` (a longer sound is cut; a shorter one ends
    /// early, the picture goes on).
    fn input_args(&self, duration: f64) -> Vec<std::ffi::OsString> {
        let mut args: Vec<std::ffi::OsString> = Vec::new();
        if self.at >= 0.0 {
            args.extend(["-ss".into(), format!("{:.6}", self.at).into()]);
            args.extend(["-t".into(), format!("{duration:.6}").into()]);
        } else {
            // Delayed by a filter (`output_args`), not by an input offset:
            // the sound track then starts with the picture, in silence,
            // as every player and decoder hears it.
            let heard = (duration + self.at).max(0.0);
            args.extend(["-t".into(), format!("{heard:.6}").into()]);
        }
        args.extend(["-i".into(), self.file.clone().into_os_string()]);
        args
    }

    /// ffmpeg's output arguments for the sound: the picture from the
    /// frames and the sound from the file, delayed by silence when it
    /// begins after the first frame.
    fn output_args(&self) -> Vec<String> {
        let mut args: Vec<String> = ["-map", "0:v", "-map", "1:a"].map(String::from).to_vec();
        if self.at < 0.0 {
            let ms = (-self.at * 1000.0).round() as u64;
            args.extend(["-af".into(), format!("adelay={ms}:all=1")]);
        }
        args
    }
}

/// The stage's colour on the page (`clients/web/renderer.js`'s
/// `BACKGROUND`, 0.96 0.95 0.92): a video without alpha shows the stage
/// as a viewer saw it.
pub const STAGE_COLOUR: [u8; 3] = [245, 242, 235];

impl VideoOptions {
    /// A video of `width × height` pixels, over the page's stage colour
    /// ([`STAGE_COLOUR`]) where it has no alpha, with the `ffmpeg` on
    /// `PATH`.
    pub fn new(width: u32, height: u32) -> VideoOptions {
        VideoOptions {
            width,
            height,
            background: STAGE_COLOUR,
            ffmpeg: None,
            audio: None,
        }
    }
}

/// The kinds of video, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VideoFormat {
    /// `.mp4`: H.264, opaque.
    Mp4,
    /// `.mov`: ProRes 4444 with alpha.
    ProRes,
    /// `.webm`: VP9 with alpha.
    WebM,
}

impl VideoFormat {
    /// The format an output path asks for, by its extension (any case).
    pub fn of(path: &Path) -> Result<VideoFormat, ExportError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("mp4") => Ok(VideoFormat::Mp4),
            Some("mov") => Ok(VideoFormat::ProRes),
            Some("webm") => Ok(VideoFormat::WebM),
            other => Err(ExportError::File {
                file: path.display().to_string(),
                problem: match other {
                    Some(e) => format!("unknown video extension \".{e}\": use .mp4, .mov or .webm"),
                    None => "no extension: use .mp4, .mov or .webm".into(),
                },
            }),
        }
    }

    /// The video kind of an export format; `None` for the formats that
    /// are not videos.
    pub fn of_format(format: crate::format::Format) -> Option<VideoFormat> {
        use crate::format::Format;
        match format {
            Format::Mp4 => Some(VideoFormat::Mp4),
            Format::Mov => Some(VideoFormat::ProRes),
            Format::Webm => Some(VideoFormat::WebM),
            Format::Glb | Format::Png | Format::Spine => None,
        }
    }

    /// Checks a picture size for this kind: the limits of what is drawn
    /// ([`check_size`]), and an even width and height for H.264's
    /// `yuv420p`.
    pub fn check_size(self, w: u32, h: u32) -> Result<(), ExportError> {
        check_size(w, h)?;
        if self == VideoFormat::Mp4 && !(w.is_multiple_of(2) && h.is_multiple_of(2)) {
            return Err(flag(
                "--size",
                format!("{w}x{h}: H.264 (.mp4, yuv420p) needs an even width and height"),
            ));
        }
        Ok(())
    }

    /// ffmpeg's sound codec for the kind: AAC in an MP4, 16-bit PCM beside
    /// ProRes (what editors expect in a .mov), Opus in a WebM. Opus starts
    /// with a pre-skip (6.5 ms) written as a packet before 0 and the
    /// track's CodecDelay; left to make timestamps non-negative, ffmpeg
    /// shifted the whole file by it, so the first picture came 7 ms after
    /// the start. Negative timestamps are kept instead (Matroska allows
    /// them): the first picture is at 0, and the sound after its pre-skip
    /// too.
    fn audio_args(self) -> &'static [&'static str] {
        match self {
            VideoFormat::Mp4 => &["-c:a", "aac", "-b:a", "192k"],
            VideoFormat::ProRes => &["-c:a", "pcm_s16le"],
            VideoFormat::WebM => &[
                "-c:a",
                "libopus",
                "-b:a",
                "160k",
                "-avoid_negative_ts",
                "disabled",
            ],
        }
    }

    /// ffmpeg's output arguments: the codec, chosen for speed where the
    /// quality allows (x264's `veryfast` preset at CRF 18; VP9 at its
    /// realtime deadline with row threading; ProRes 4444 by `prores_aw`,
    /// twice as fast as `prores_ks` here), and the colour tags.
    fn codec_args(self) -> &'static [&'static str] {
        match self {
            VideoFormat::Mp4 => &[
                "-c:v",
                "libx264",
                "-preset",
                "veryfast",
                "-pix_fmt",
                "yuv420p",
                "-crf",
                "18",
                "-movflags",
                "+faststart",
            ],
            VideoFormat::ProRes => &[
                "-c:v",
                "prores_aw",
                // ap4h: ProRes 4444, which carries alpha.
                "-profile:v",
                "4",
                "-pix_fmt",
                "yuva444p10le",
                "-vendor",
                "apl0",
            ],
            VideoFormat::WebM => &[
                "-c:v",
                "libvpx-vp9",
                "-pix_fmt",
                "yuva420p",
                "-crf",
                "30",
                "-b:v",
                "0",
                "-auto-alt-ref",
                "0",
                "-deadline",
                "realtime",
                "-cpu-used",
                "8",
                "-row-mt",
                "1",
            ],
        }
    }
}

/// The colour conversion and its tags, the same for every kind: RGB to
/// BT.709 YUV in limited range, and the stream (and each ProRes frame,
/// through `setparams`) tagged so. Untagged, a browser decodes as BT.709
/// what ffmpeg had converted with BT.601: a red (214, 38, 52) showed as
/// (231, 55, 52) in Chromium.
const COLOUR_ARGS: [&str; 10] = [
    "-vf",
    "scale=out_color_matrix=bt709:out_range=tv,\
     setparams=color_primaries=bt709:color_trc=bt709:colorspace=bt709:range=tv",
    "-color_primaries",
    "bt709",
    "-color_trc",
    "bt709",
    "-colorspace",
    "bt709",
    "-color_range",
    "tv",
];

/// The frame rate as ffmpeg reads it, as a fraction so `r_frame_rate`
/// comes out exact: a whole number of frames per 1 or 1001 seconds (30,
/// 30000/1001), the NTSC rates as people write them (29.97, 23.976 and
/// 59.94 are 30000/1001, 24000/1001 and 60000/1001), else per 1000
/// seconds.
pub fn frame_rate_arg(fps: f64) -> String {
    let whole = |v: f64, tolerance: f64| (v - v.round()).abs() < tolerance;
    if whole(fps, 1e-6) {
        return format!("{}/1", fps.round() as u64);
    }
    if whole(fps * 1001.0, 1e-3) {
        return format!("{}/1001", (fps * 1001.0).round() as u64);
    }
    // 29.97 is 30000/1001 to within 3e-5 fps: a rate given to two or
    // three decimals that close to a whole rate × 1000/1001 means it.
    let ntsc = fps * 1.001;
    if whole(ntsc, 5e-4) && ntsc.round() >= 1.0 {
        return format!("{}/1001", ntsc.round() as u64 * 1000);
    }
    if whole(fps * 1000.0, 1e-3) {
        return format!("{}/1000", (fps * 1000.0).round() as u64);
    }
    format!("{fps}")
}

/// Finds `ffmpeg` on `PATH`.
pub fn find_ffmpeg() -> Result<std::path::PathBuf, ExportError> {
    find_ffmpeg_in(&std::env::var_os("PATH").unwrap_or_default())
}

/// Finds `ffmpeg` in the folders of a `PATH`-style list.
pub fn find_ffmpeg_in(path: &std::ffi::OsStr) -> Result<std::path::PathBuf, ExportError> {
    use std::os::unix::fs::PermissionsExt;
    std::env::split_paths(path)
        .map(|dir| dir.join("ffmpeg"))
        .find(|p| {
            std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        })
        .ok_or_else(|| ExportError::ToolMissing {
            tool: "ffmpeg".into(),
            install: "Debian: apt-get install ffmpeg".into(),
        })
}

/// Lines of ffmpeg's messages kept for an error.
const TAIL_LINES: usize = 15;

/// Encodes every frame of `animation` into the video `path` (format by
/// extension, see the module doc). `progress` counts frames piped.
pub fn export_video(
    animation: &Animation,
    options: &VideoOptions,
    progress: &mut dyn Progress,
    path: &Path,
) -> Result<(), ExportError> {
    let format = VideoFormat::of(path)?;
    animation.validate()?;
    let (w, h) = (options.width, options.height);
    format.check_size(w, h)?;
    let ffmpeg = match &options.ffmpeg {
        Some(p) => p.clone(),
        None => find_ffmpeg()?,
    };
    let file = path.display().to_string();
    // ffmpeg writes a new file beside `path`, with its extension (which
    // picks the container), renamed onto `path` once finished: a link at
    // `path` is replaced, not followed, and a failure leaves nothing.
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let partial = crate::new_beside(path, &format!(".{extension}"))?;
    let mut child = Command::new(&ffmpeg)
        .args(["-hide_banner", "-nostdin", "-loglevel", "error", "-y"])
        .args(["-f", "rawvideo", "-pix_fmt", "rgba"])
        .args(["-s", &format!("{w}x{h}")])
        .args(["-r", &frame_rate_arg(animation.fps)])
        .args(["-i", "-"])
        .args(
            options
                .audio
                .iter()
                .flat_map(|a| a.input_args(animation.duration())),
        )
        .args(COLOUR_ARGS)
        .args(format.codec_args())
        .args(options.audio.iter().flat_map(Soundtrack::output_args))
        .args(options.audio.iter().flat_map(|_| format.audio_args()))
        .args(["-r", &frame_rate_arg(animation.fps)])
        .arg(partial.path())
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| ExportError::File {
            file: file.clone(),
            problem: format!("cannot run {}: {e}", ffmpeg.display()),
        })?;
    let mut stdin = child.stdin.take().expect("piped stdin");
    let stderr = child.stderr.take().expect("piped stderr");
    // ffmpeg's messages, read as they come so it never blocks on them.
    let log = std::thread::spawn(move || {
        let mut tail = std::collections::VecDeque::new();
        let mut reader = std::io::BufReader::new(stderr);
        let mut line = Vec::new();
        while reader.read_until(b'\n', &mut line).is_ok_and(|n| n > 0) {
            if tail.len() == TAIL_LINES {
                tail.pop_front();
            }
            tail.push_back(String::from_utf8_lossy(&line).trim_end().to_string());
            line.clear();
        }
        let _ = reader.read_to_end(&mut line);
        tail.into_iter().collect::<Vec<_>>().join("\n")
    });
    let total = animation.frame_count;
    let opaque = format == VideoFormat::Mp4;
    let bg = options.background.map(|c| c as u32);
    let piped = render_frames(
        animation,
        w,
        h,
        |_, pixels| {
            let mut frame = pixels.to_vec();
            if opaque {
                over_background(&mut frame, bg);
            }
            Ok(frame)
        },
        |k, frame| {
            stdin.write_all(&frame).map_err(|e| ExportError::File {
                file: file.clone(),
                problem: format!("ffmpeg stopped reading frames at frame {k}: {e}"),
            })?;
            progress.step(k + 1, total);
            Ok(())
        },
    );
    drop(stdin); // end of input: ffmpeg finishes the file
    let status = child.wait().map_err(|e| ExportError::File {
        file: file.clone(),
        problem: format!("waiting for ffmpeg: {e}"),
    })?;
    let tail = log.join().unwrap_or_default();
    if !status.success() {
        return Err(ExportError::File {
            file,
            problem: format!("ffmpeg failed ({status}); its last messages:\n{tail}"),
        });
    }
    piped?;
    partial
        .persist(path)
        .map_err(|e| crate::io_error(path)(e.error))?;
    Ok(())
}

/// Straight RGBA over an opaque colour, in place.
fn over_background(frame: &mut [u8], bg: [u32; 3]) {
    for px in frame.chunks_exact_mut(4) {
        let a = px[3] as u32;
        for c in 0..3 {
            px[c] = ((px[c] as u32 * a + bg[c] * (255 - a) + 127) / 255) as u8;
        }
        px[3] = 255;
    }
}
