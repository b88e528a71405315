//! Sound for the soundtrack tests: a click track to mux in, and when the
//! first click is heard in what an export made of it (decoded by ffmpeg,
//! as a player decodes it).

use std::path::Path;
use std::process::Command;

/// A mono 16-bit WAV at 48 kHz, `seconds` long: silence but for a 10 ms
/// click at each of `clicks` (seconds).
pub fn click_track(path: &Path, seconds: f64, clicks: &[f64]) {
    const RATE: u32 = 48_000;
    let n = (seconds * f64::from(RATE)) as usize;
    let mut samples = vec![0i16; n];
    for &c in clicks {
        let first = (c * f64::from(RATE)) as usize;
        for (i, s) in samples.iter_mut().enumerate().skip(first).take(480) {
            *s = if (i - first) % 20 < 10 {
                24_000
            } else {
                -24_000
            };
        }
    }
    let data: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
    let mut wav = Vec::new();
    wav.extend(b"RIFF");
    wav.extend((36 + data.len() as u32).to_le_bytes());
    wav.extend(b"WAVEfmt ");
    wav.extend(16u32.to_le_bytes());
    wav.extend(1u16.to_le_bytes()); // PCM
    wav.extend(1u16.to_le_bytes()); // mono
    wav.extend(RATE.to_le_bytes());
    wav.extend((RATE * 2).to_le_bytes());
    wav.extend(2u16.to_le_bytes());
    wav.extend(16u16.to_le_bytes());
    wav.extend(b"data");
    wav.extend((data.len() as u32).to_le_bytes());
    wav.extend(data);
    std::fs::write(path, wav).unwrap();
}

/// When the first click is heard in `video`'s sound, in seconds.
pub fn first_onset(video: &Path) -> f64 {
    let out = Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-i"])
        .arg(video)
        .args([
            "-map", "0:a", "-f", "s16le", "-ac", "1", "-ar", "48000", "-",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let first = out
        .stdout
        .chunks_exact(2)
        .position(|s| i16::from_le_bytes([s[0], s[1]]).unsigned_abs() > 8_000)
        .expect("a click in the sound");
    first as f64 / 48_000.0
}

/// What ffprobe says of `media`, as JSON: `args` choose the stream and
/// the entries (`-select_streams a:0 -show_entries stream=start_time`).
pub fn probe(media: &Path, args: &[&str]) -> serde_json::Value {
    let out = Command::new("ffprobe")
        .args(["-v", "error"])
        .args(args)
        .args(["-of", "json"])
        .arg(media)
        .output()
        .expect("ffprobe runs (install ffmpeg: apt-get install ffmpeg)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// When `video`'s sound stream starts against its pictures, in seconds,
/// as ffprobe reads it (a player starts the sound that late).
pub fn audio_start(video: &Path) -> f64 {
    let probed = probe(
        video,
        &[
            "-select_streams",
            "a:0",
            "-show_entries",
            "stream=start_time",
        ],
    );
    let start = &probed["streams"][0]["start_time"];
    start
        .as_str()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no sound stream start in {probed}"))
}
