//! Exports an animator can trust (issue 34), through the binary as a user
//! runs it: files already there are never replaced without `--force` (a
//! picture of the user's own beside a Spine export least of all); a
//! damaged take is refused naming the damage and exported in what is
//! intact only with `--salvage`, an empty one refused; without `--config`
//! the take's own stage file is used; a missing folder and an oversized
//! picture are refused before the take is read; a progress bar is ended
//! before an error.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::DVec2;
use puppetry_stage::Stage;
use puppetry_take::{End, Header, Record, TakeWriter};

use crate::common::daemon::{stage_config, stage_text};

/// A take of the test stage, `frames` frames of every puppet a tenth of a
/// second apart (each a little further right), recorded as if on the
/// stage file `stage_file`.
fn write_take(dir: &Path, name: &str, frames: usize, stage_file: &str) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let stage = Stage::from_config(&stage_config("")).unwrap();
    let header = Header::of_stage(name, stage_file, &stage, true);
    let path = dir.join(format!("{name}.take"));
    let mut writer = TakeWriter::create(&path, &header).unwrap();
    for k in 0..frames {
        let t = k as f64 / 10.0;
        for (i, p) in stage.puppets().iter().enumerate() {
            let pose: Vec<DVec2> = p.pose().iter().map(|q| *q + DVec2::X * k as f64).collect();
            let frame = puppetry_take::Frame::of_pose(i as u32, t, &pose);
            writer.write(&Record::Frame(frame)).unwrap();
        }
    }
    let end = End {
        t: frames as f64 / 10.0,
        reason: "stopped".into(),
    };
    writer.write(&Record::End(end)).unwrap();
    writer.flush().unwrap();
    path
}

/// `puppetry export TAKE ARGS…` run in `cwd`.
fn export(cwd: &Path, take: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .current_dir(cwd)
        .arg("export")
        .arg(take)
        .args(args)
        .output()
        .unwrap()
}

fn said(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A stage file `stage.toml` in `dir`; its path as a string.
fn stage_file(dir: &Path) -> String {
    let path = dir.join("stage.toml");
    std::fs::write(&path, stage_text("")).unwrap();
    path.display().to_string()
}

#[test]
fn an_export_never_replaces_a_file_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let stage = stage_file(dir.path());
    let take = write_take(dir.path(), "t", 5, &stage);
    // A file of the user's own where the glb would go: kept, named.
    let glb = dir.path().join("walk.glb");
    std::fs::write(&glb, "the user's own").unwrap();
    let out = export(dir.path(), &take, &["--format", "glb", "-o", "walk.glb"]);
    assert!(!out.status.success());
    assert!(
        said(&out).contains("already there") && said(&out).contains("--force"),
        "{}",
        said(&out)
    );
    assert_eq!(std::fs::read_to_string(&glb).unwrap(), "the user's own");
    let out = export(
        dir.path(),
        &take,
        &["--format", "glb", "-o", "walk.glb", "--force"],
    );
    assert!(out.status.success(), "{}", said(&out));
    assert!(std::fs::read(&glb).unwrap().starts_with(b"glTF"));

    // Spine writes the JSON, its atlas and a picture named after the
    // export: the puppet's own picture file name beside it is not touched
    // (it was overwritten before).
    let own = dir.path().join("gingerbread.png");
    std::fs::write(&own, "a drawing in progress").unwrap();
    let out = export(dir.path(), &take, &["--format", "spine", "-o", "walk.json"]);
    assert!(out.status.success(), "{}", said(&out));
    assert_eq!(
        std::fs::read_to_string(&own).unwrap(),
        "a drawing in progress"
    );
    for made in ["walk.json", "walk.atlas", "walk-gingerbread.png"] {
        assert!(dir.path().join(made).is_file(), "{made} written");
    }
    // Again: each of its files is already there.
    std::fs::remove_file(dir.path().join("walk.json")).unwrap();
    let out = export(dir.path(), &take, &["--format", "spine", "-o", "walk.json"]);
    assert!(!out.status.success());
    assert!(said(&out).contains("walk.atlas"), "{}", said(&out));
    assert!(!dir.path().join("walk.json").exists(), "nothing written");

    // PNG frames into a folder holding frames already: refused.
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    std::fs::write(frames.join("frame_00002.png"), "kept").unwrap();
    let args = ["--format", "png", "--size", "64x36", "-o", "frames"];
    let out = export(dir.path(), &take, &args);
    assert!(!out.status.success());
    assert!(said(&out).contains("frame_00002.png"), "{}", said(&out));
    assert_eq!(
        std::fs::read_to_string(frames.join("frame_00002.png")).unwrap(),
        "kept"
    );
    assert!(!frames.join("frame_00000.png").exists(), "nothing drawn");
}

#[test]
fn a_damaged_take_is_refused_and_salvaged_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let stage = stage_file(dir.path());
    let whole = write_take(dir.path(), "whole", 40, &stage);
    let bytes = std::fs::read(&whole).unwrap();

    // One flipped byte mid-take (a frame's checksum no longer holds).
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x40;
    let damaged = dir.path().join("damaged.take");
    std::fs::write(&damaged, &flipped).unwrap();
    // A take cut mid-record (a daemon killed while writing).
    let cut = dir.path().join("cut.take");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();

    for (bad, what) in [(&damaged, "checksum mismatch"), (&cut, "cannot be read")] {
        let name = bad.file_stem().unwrap().to_str().unwrap().to_string();
        let glb = format!("{name}.glb");
        let out = export(
            dir.path(),
            bad,
            &["--config", &stage, "--format", "glb", "-o", &glb],
        );
        let told = said(&out);
        assert!(!out.status.success(), "{name}: exported with exit 0");
        assert!(
            told.contains("damaged") && told.contains(what),
            "{name}: {told}"
        );
        assert!(told.contains("--salvage"), "{name}: {told}");
        assert!(!dir.path().join(&glb).exists(), "{name}: nothing written");

        let args = [
            "--config",
            &stage,
            "--format",
            "glb",
            "-o",
            &glb,
            "--salvage",
        ];
        let out = export(dir.path(), bad, &args);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{name}: {}", said(&out));
        assert!(
            stdout.contains("salvaged") && stdout.contains("intact frame(s)"),
            "{stdout}"
        );
        assert!(dir.path().join(&glb).is_file());
    }

    // A header and nothing else: nothing to export, salvage or not.
    let empty = write_take(dir.path(), "empty", 0, &stage);
    for salvage in [false, true] {
        let mut args = vec!["--config", &stage, "--format", "glb", "-o", "empty.glb"];
        if salvage {
            args.push("--salvage");
        }
        let out = export(dir.path(), &empty, &args);
        assert!(!out.status.success(), "an empty take exported");
        assert!(said(&out).contains("no frames"), "{}", said(&out));
    }
}

#[test]
fn without_config_the_takes_own_stage_file_is_used() {
    let dir = tempfile::tempdir().unwrap();
    stage_file(dir.path());
    // Recorded by a daemon run in `dir` on "stage.toml", kept in takes/.
    let take = write_take(&dir.path().join("takes"), "t", 5, "stage.toml");
    for cwd in [dir.path().to_path_buf(), dir.path().join("takes")] {
        let out = export(&cwd, &take, &["--format", "glb", "-o", "t.glb"]);
        assert!(
            out.status.success(),
            "from {}: {}",
            cwd.display(),
            said(&out)
        );
        assert!(said(&out).contains("stage file:"), "{}", said(&out));
    }
    // A stage file that is nowhere: named, with what to do.
    let lost = write_take(dir.path(), "lost", 5, "/nowhere/show.toml");
    let out = export(dir.path(), &lost, &["--format", "glb", "-o", "lost.glb"]);
    assert!(!out.status.success());
    let told = said(&out);
    assert!(
        told.contains("/nowhere/show.toml") && told.contains("--config"),
        "{told}"
    );
}

#[test]
fn a_missing_folder_or_an_oversized_picture_is_refused_before_the_take_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let stage = stage_file(dir.path());
    // No such take: what is refused here is refused before reading it.
    let take = dir.path().join("not-read.take");
    let out = export(
        dir.path(),
        &take,
        &[
            "--config",
            &stage,
            "--format",
            "mp4",
            "-o",
            "no-such-folder/t.mp4",
        ],
    );
    assert!(!out.status.success());
    assert!(said(&out).contains("no-such-folder"), "{}", said(&out));
    assert!(!said(&out).contains("not-read.take"), "{}", said(&out));
    for format in ["mp4", "png"] {
        let out_name = format!("t.{format}");
        let args = [
            "--config",
            &stage,
            "--format",
            format,
            "--size",
            "16384x16384",
            "-o",
            &out_name,
        ];
        let out = export(dir.path(), &take, &args);
        assert!(!out.status.success());
        assert!(
            said(&out).contains("--size") && said(&out).contains("MAX_EXPORT_SIDE"),
            "{}",
            said(&out)
        );
    }
}

/// On a terminal the progress bar is drawn; an export failing mid-way
/// ends its line before the error ("(1/299)error: …" before).
#[test]
fn a_failed_export_ends_its_progress_bar_first() {
    use std::io::Read;
    let dir = tempfile::tempdir().unwrap();
    let stage = stage_file(dir.path());
    let take = write_take(dir.path(), "t", 40, &stage);
    // An ffmpeg that reads a little and fails.
    let bin = dir.path().join("bin");
    std::fs::create_dir(&bin).unwrap();
    let fake = bin.join("ffmpeg");
    std::fs::write(
        &fake,
        "#!/bin/sh\n/usr/bin/head -c 100000 >/dev/null\necho 'fake ffmpeg gives up' >&2\nexit 1\n",
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let pty = crate::common::pty::open_pty();
    let terminal = std::fs::OpenOptions::new()
        .write(true)
        .open(&pty.path)
        .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .current_dir(dir.path())
        .env("PATH", &bin)
        .arg("export")
        .arg(&take)
        .args([
            "--config", &stage, "--format", "mp4", "--size", "64x36", "-o", "t.mp4",
        ])
        .stderr(terminal)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success());
    drop(child);
    let mut master = pty.master;
    // Everything written is in the master's buffer: read what is there.
    let mut text = Vec::new();
    let mut buf = [0u8; 4096];
    // SAFETY: fcntl on an fd this test owns, setting O_NONBLOCK.
    unsafe {
        use std::os::fd::AsRawFd;
        let fd = master.as_raw_fd();
        libc::fcntl(
            fd,
            libc::F_SETFL,
            libc::fcntl(fd, libc::F_GETFL) | libc::O_NONBLOCK,
        );
    }
    while let Ok(n) = master.read(&mut buf) {
        if n == 0 {
            break;
        }
        text.extend_from_slice(&buf[..n]);
    }
    let text = String::from_utf8_lossy(&text);
    assert!(text.contains("export mp4 ["), "no bar drawn: {text:?}");
    let error_at = text
        .find("error")
        .unwrap_or_else(|| panic!("no error: {text:?}"));
    let before = text[..error_at].trim_end_matches(' ');
    assert!(
        before.ends_with('\n'),
        "the error does not start a line of its own: {text:?}"
    );
}

/// `--audio` muxes a soundtrack: the sound's second `--audio-offset` plays
/// with the take's start, so with `--from 1` and an offset of 0.5 the
/// click at the sound's 2 s is heard 0.5 s into the video; asked of a
/// format without sound, or of a sound file that is not there, it is
/// refused before the take is read.
#[test]
fn a_soundtrack_plays_in_time_with_the_take() {
    let dir = tempfile::tempdir().unwrap();
    let stage = stage_file(dir.path());
    let take = write_take(dir.path(), "t", 40, &stage);
    let wav = dir.path().join("song.wav");
    puppetry_testkit::sound::click_track(&wav, 6.0, &[2.0]);
    let wav_arg = wav.display().to_string();
    let args = [
        "--config",
        &stage,
        "--format",
        "mp4",
        "--size",
        "64x36",
        "--from",
        "1",
        "--audio",
        &wav_arg,
        "--audio-offset",
        "0.5",
        "-o",
        "t.mp4",
    ];
    let out = export(dir.path(), &take, &args);
    assert!(out.status.success(), "{}", said(&out));
    let onset = puppetry_testkit::sound::first_onset(&dir.path().join("t.mp4"));
    assert!(
        (onset - 0.5).abs() <= 1.0 / 30.0,
        "the click is heard at {onset} s"
    );

    // Without an offset, a take that heard no show clock starts the
    // sound with the take (the range's start counted), and says so.
    let args = [
        "--config", &stage, "--format", "mp4", "--size", "64x36", "--from", "1", "--audio",
        &wav_arg, "-o", "own.mp4",
    ];
    let out = export(dir.path(), &take, &args);
    assert!(out.status.success(), "{}", said(&out));
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(printed.contains("heard no show clock"), "{printed}");
    let onset = puppetry_testkit::sound::first_onset(&dir.path().join("own.mp4"));
    assert!(
        (onset - 1.0).abs() <= 1.0 / 30.0,
        "the click is heard at {onset} s"
    );

    let args = [
        "--config", &stage, "--format", "glb", "--audio", &wav_arg, "-o", "t.glb",
    ];
    let out = export(dir.path(), &take, &args);
    assert!(!out.status.success());
    assert!(said(&out).contains("carries no sound"), "{}", said(&out));
    let missing = dir.path().join("not-read.take");
    let args = [
        "--config", &stage, "--format", "webm", "--audio", "gone.wav", "-o", "t.webm",
    ];
    let out = export(dir.path(), &missing, &args);
    assert!(!out.status.success());
    assert!(said(&out).contains("gone.wav"), "{}", said(&out));
}
