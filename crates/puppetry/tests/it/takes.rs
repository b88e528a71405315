//! Takes end to end: a take recorded from two real touch captures replays
//! bit for bit (offline and through a second daemon), a killed daemon's
//! take reads back, a full disk stops the take but not the show, and
//! performers record, list, play and overdub takes over WebSocket.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use futures_util::SinkExt;
use puppetry_daemon::config::ShowConfig;
use puppetry_daemon::serve::{Options, Running, start_with};
use puppetry_daemon::stream::WebFiles;
use puppetry_stage::{Change, Stage};
use puppetry_take::replay::verify;
use puppetry_take::{Frame, Record, Tail, TakeReader, summarize};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::{
    PLAYS, WAIT, connect, looping_capture, next_text, root, stage_config, stage_text,
};

/// Two real captures, each calibrated onto the puppet, played once at
/// their own pace (so the stage solves between their frames).
fn two_captures() -> String {
    let evemu = root().join("../shared/fixtures/evemu");
    format!(
        r#"
[[input]]
kind = "replay"
name = "wetab"
file = "{wetab}"
calibration = {{ kind = "range", x = [0, 32760], y = [0, 32760], flip_y = true, stage_min = [590, 320], stage_max = [690, 400] }}

[[input]]
kind = "replay"
name = "ntrig"
file = "{ntrig}"
calibration = {{ kind = "range", x = [0, 9600], y = [0, 7200], flip_y = true, stage_min = [600, 330], stage_max = [680, 420] }}
"#,
        wetab = evemu.join("wetab.event").display(),
        ntrig = evemu.join("ntrig-dell-xt2.event").display(),
    )
}

fn options(takes: &Path) -> Options {
    let mut o = Options::new(WebFiles::Embedded);
    o.takes_dir = takes.to_path_buf();
    o
}

/// Waits (bounded) until every input and player has ended, then shuts the
/// daemon down: the stage thread applies what is queued before it stops.
async fn finish(running: Running) {
    let deadline = Instant::now() + PLAYS;
    while !running.inputs_done() {
        assert!(Instant::now() < deadline, "the inputs did not end");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    running.shutdown().await;
}

fn only_take(dir: &Path) -> PathBuf {
    let takes: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(takes.len(), 1, "{takes:?}");
    takes[0].clone()
}

fn frames_and_steps(path: &Path) -> (Vec<Frame>, Vec<puppetry_take::Step>) {
    let (mut frames, mut steps) = (Vec::new(), Vec::new());
    for record in TakeReader::open(path).unwrap() {
        match record.unwrap() {
            Record::Frame(f) => frames.push(f),
            Record::Step(s) => steps.push(s),
            _ => {}
        }
    }
    (frames, steps)
}

fn sources(steps: &[puppetry_take::Step]) -> Vec<String> {
    let mut sources: Vec<String> = steps
        .iter()
        .flat_map(|s| &s.changes)
        .filter_map(|c| match c {
            Change::Contacts { frame } => Some(frame.source.to_string()),
            _ => None,
        })
        .collect();
    sources.sort();
    sources.dedup();
    sources
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_of_two_real_captures_replays_bit_for_bit() {
    let config = stage_config(&two_captures());
    let first = tempfile::tempdir().unwrap();
    let mut o = options(first.path());
    o.record = true;
    finish(start_with(&config, o).await.unwrap()).await;
    let take = only_take(first.path());
    let (recorded, steps) = frames_and_steps(&take);
    assert_eq!(sources(&steps), ["ntrig", "wetab"], "both sources recorded");
    assert!(recorded.len() > 20, "{} frames", recorded.len());
    let summary = summarize(&take).unwrap();
    assert_eq!(summary.ending, "shutdown");
    assert!(summary.fresh);

    // Offline: the steps replayed into a fresh stage give every frame.
    let v = verify(&take, Stage::from_config(&config).unwrap()).unwrap();
    assert_eq!(v.first_mismatch, None);
    assert_eq!(v.frames, recorded.len());

    // Through a daemon: play the take, as fast as it goes and in real
    // time, recording each playback.
    for fast in [true, false] {
        let quiet = stage_config("");
        let second = tempfile::tempdir().unwrap();
        let mut o = options(second.path());
        o.record = true;
        o.play = Some((
            take.clone(),
            puppetry_daemon::takes::PlayOptions {
                fast,
                ..Default::default()
            },
        ));
        finish(start_with(&quiet, o).await.unwrap()).await;
        let (replayed, _) = frames_and_steps(&only_take(second.path()));
        assert_eq!(replayed.len(), recorded.len(), "fast: {fast}");
        for (k, (a, b)) in recorded.iter().zip(&replayed).enumerate() {
            assert_eq!(a.puppet, b.puppet, "frame {k}");
            let bits = |f: &Frame| -> Vec<u32> {
                f.points
                    .iter()
                    .flat_map(|p| [p[0].to_bits(), p[1].to_bits()])
                    .collect()
            };
            assert!(bits(a) == bits(b), "frame {k} differs (fast: {fast})");
        }
    }
}

/// A stage file on disk (for the binary) with a looping real-time replay.
fn stage_file(dir: &Path) -> PathBuf {
    let path = dir.join("stage.toml");
    std::fs::write(&path, stage_text(&looping_capture())).unwrap();
    path
}

/// Starts the binary serving `stage` and recording into `takes`, through
/// `sh` so a file-size limit can stand in for a full disk; returns the child
/// and its address.
fn serve_binary(
    stage: &Path,
    takes: &Path,
    size_limit_kb: Option<u32>,
) -> (std::process::Child, String) {
    use std::io::BufRead;
    let limit = size_limit_kb
        .map(|kb| format!("trap '' XFSZ; ulimit -f {kb}; "))
        .unwrap_or_default();
    let script = format!(
        "{limit}exec '{bin}' serve --config '{stage}' --record '{takes}'",
        bin = env!("CARGO_BIN_EXE_puppetry"),
        stage = stage.display(),
        takes = takes.display(),
    );
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg(script)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let address = line
        .split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .to_string();
    // Keep reading stdout so the daemon never blocks on a full pipe.
    std::thread::spawn(move || for _ in out.lines() {});
    (child, address)
}

#[test]
fn a_killed_daemon_leaves_a_take_that_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let (mut child, _) = serve_binary(&stage_file(dir.path()), &takes, None);
    // Until the take holds frames on disk (bounded).
    let deadline = Instant::now() + PLAYS;
    let take = takes.join("take-001.take");
    loop {
        if let Ok(s) = summarize(&take)
            && s.frames >= 20
        {
            break;
        }
        assert!(Instant::now() < deadline, "no frames reached the take");
        std::thread::sleep(Duration::from_millis(50));
    }
    // SIGKILL: no chance to finish the take.
    child.kill().unwrap();
    child.wait().unwrap();
    let summary = summarize(&take).unwrap();
    assert!(
        summary.ending == "unended" || summary.ending.starts_with("truncated"),
        "{}",
        summary.ending
    );
    assert!(summary.frames >= 20);
    let config = ShowConfig::load(&dir.path().join("stage.toml")).unwrap();
    let v = verify(&take, Stage::from_config(&config).unwrap()).unwrap();
    assert_eq!(v.first_mismatch, None, "what was kept replays exactly");
    assert!(!matches!(v.tail, Tail::Ended(_)));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_stops_the_take_and_the_show_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    // 64 KB of file at most: the take fails within a second of playing.
    let (mut child, address) = serve_binary(&stage_file(dir.path()), &takes, Some(64));
    let url = format!("ws://{address}/ws");
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    ws.send(Message::text(
        json!({"type": "hello", "role": "viewer"}).to_string(),
    ))
    .await
    .unwrap();
    let error = tokio::time::timeout(PLAYS, async {
        loop {
            let m = next_text(&mut ws).await;
            if m["type"] == "take"
                && let Some(error) = m["error"].as_str()
            {
                return error.to_string();
            }
        }
    })
    .await
    .expect("the take's error reached the page");
    assert!(error.contains("take-001"), "{error}");
    assert!(error.to_lowercase().contains("file too large"), "{error}");
    // The show goes on: frames keep coming after the take stopped.
    let mut frames = 0;
    tokio::time::timeout(WAIT, async {
        while frames < 5 {
            if let Message::Binary(_) = crate::common::daemon::next_message(&mut ws).await {
                frames += 1;
            }
        }
    })
    .await
    .expect("frames after the take stopped");
    child.kill().unwrap();
    child.wait().unwrap();
    // What was written before the limit still reads.
    summarize(&takes.join("take-001.take")).unwrap();
}

async fn take_state(
    ws: &mut crate::common::daemon::Client,
    done: impl Fn(&Value) -> bool,
) -> Value {
    tokio::time::timeout(WAIT, async {
        loop {
            let m = next_text(ws).await;
            if m["type"] == "take" && done(&m) {
                return m;
            }
        }
    })
    .await
    .expect("the take state")
}

async fn send(ws: &mut crate::common::daemon::Client, m: Value) {
    ws.send(Message::text(m.to_string())).await.unwrap();
}

async fn drag(ws: &mut crate::common::daemon::Client, id: u32, from: [f64; 2], to: [f64; 2]) {
    send(ws, json!({"type": "contacts", "contacts": [{"id": id, "phase": "down", "x": from[0], "y": from[1]}]})).await;
    for i in 1..=20 {
        let t = i as f64 / 20.0;
        let x = from[0] + (to[0] - from[0]) * t;
        let y = from[1] + (to[1] - from[1]) * t;
        send(
            ws,
            json!({"type": "contacts", "contacts": [{"id": id, "phase": "move", "x": x, "y": y}]}),
        )
        .await;
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    send(
        ws,
        json!({"type": "contacts", "contacts": [{"id": id, "phase": "up"}]}),
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn performers_record_list_play_and_overdub_takes() {
    let dir = tempfile::tempdir().unwrap();
    let running = start_with(&stage_config(""), options(dir.path()))
        .await
        .unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello.clone()).await;
    let (mut other, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;

    send(&mut ws, json!({"type": "record"})).await;
    // Every client sees the red state.
    take_state(&mut other, |m| m["recording"] == "take-001").await;
    // Two hands: the head up-left, the right hand right.
    drag(&mut ws, 1, [640.0, 470.0], [600.0, 500.0]).await;
    drag(&mut ws, 2, [720.0, 380.0], [760.0, 380.0]).await;
    send(&mut ws, json!({"type": "stop_recording"})).await;
    take_state(&mut other, |m| m.get("recording").is_none()).await;

    send(&mut other, json!({"type": "list_takes"})).await;
    let list = tokio::time::timeout(WAIT, async {
        loop {
            let m = next_text(&mut other).await;
            if m["type"] == "takes" {
                return m;
            }
        }
    })
    .await
    .unwrap();
    assert_eq!(list["takes"][0]["name"], "take-001");
    assert!(list["takes"][0]["steps"].as_u64().unwrap() > 20);

    // Overdub: play take-001, replacing what its hand on the head did, while
    // the live performer plays the left hand.
    send(
        &mut ws,
        json!({"type": "play", "take": "take-001", "overdub": true,
               "replace": [{"puppet": 0, "at": [640.0, 470.0], "radius": 15.0}]}),
    )
    .await;
    take_state(&mut other, |m| {
        m["playing"] == "take-001" && m["recording"] == "take-002"
    })
    .await;
    drag(&mut ws, 3, [560.0, 380.0], [520.0, 380.0]).await;
    // The overdub stops by itself when take-001 ends.
    tokio::time::timeout(PLAYS, async {
        loop {
            let m = next_text(&mut other).await;
            if m["type"] == "take" && m.get("playing").is_none() && m.get("recording").is_none() {
                return;
            }
        }
    })
    .await
    .expect("the overdub ended with its take");
    running.shutdown().await;

    let overdub = dir.path().join("take-002.take");
    assert_eq!(summarize(&overdub).unwrap().layers, ["take-001"]);
    let (_, steps) = frames_and_steps(&overdub);
    let sources = sources(&steps);
    assert!(
        sources.iter().any(|s| s.starts_with("take-001/")),
        "{sources:?}"
    );
    assert!(
        sources.iter().any(|s| s.starts_with("client:")),
        "{sources:?}"
    );
    // The replaced hand (contact 1 of take-001) was left out; contact 2 played.
    let played: Vec<u32> = steps
        .iter()
        .flat_map(|s| &s.changes)
        .filter_map(|c| match c {
            Change::Contacts { frame } if frame.source.as_str().starts_with("take-001/") => {
                Some(frame.contacts.iter().map(|c| c.id).collect::<Vec<_>>())
            }
            _ => None,
        })
        .flatten()
        .collect();
    assert!(played.contains(&2) && !played.contains(&1), "{played:?}");
}

/// Runs the binary; fails the test with its error output if it fails.
fn succeeds(args: &[&str]) {
    let out = puppetry(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn puppetry(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .args(args)
        .output()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_command_line_lists_verifies_and_exports_a_take() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let mut o = options(&takes);
    o.record = true;
    finish(start_with(&stage_config(&two_captures()), o).await.unwrap()).await;
    let stage = stage_file(dir.path());
    let s = |p: &Path| p.display().to_string();

    let listed = puppetry(&["takes", &s(&takes), "--verify", "--config", &s(&stage)]);
    let text = String::from_utf8_lossy(&listed.stdout);
    assert!(listed.status.success(), "{text}");
    assert!(
        text.contains("take-001") && text.contains("replays exactly"),
        "{text}"
    );

    let take = s(&takes.join("take-001.take"));
    let summary = summarize(&takes.join("take-001.take")).unwrap();
    let glb = dir.path().join("take.glb");
    succeeds(&[
        "export",
        &take,
        "--config",
        &s(&stage),
        "--format",
        "glb",
        "--fps",
        "30",
        "-o",
        &s(&glb),
    ]);
    assert_eq!(&std::fs::read(&glb).unwrap()[..4], b"glTF");

    let png = dir.path().join("png");
    succeeds(&[
        "export",
        &take,
        "--config",
        &s(&stage),
        "--format",
        "png",
        "--fps",
        "10",
        "--size",
        "320x180",
        "-o",
        &s(&png),
    ]);
    let frames = std::fs::read_dir(&png).unwrap().count();
    let expected = ((summary.duration + 0.1) * 10.0).ceil() as usize;
    assert!(
        frames.abs_diff(expected) <= 1,
        "{frames} frames, expected {expected}"
    );

    // Bad requests name what is wrong.
    let bad = |args: &[&str], needle: &str| {
        let out = puppetry(args);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(
            !out.status.success() && err.contains(needle),
            "{args:?}: {err}"
        );
    };
    let cfg = s(&stage);
    bad(
        &[
            "export", &take, "--config", &cfg, "--format", "gif", "-o", "x.gif",
        ],
        "--format",
    );
    bad(
        &[
            "export", &take, "--config", &cfg, "--format", "glb", "--from", "3", "--to", "1", "-o",
            "x.glb",
        ],
        "--to",
    );
    bad(
        &[
            "export",
            &take,
            "--config",
            &cfg,
            "--format",
            "mp4",
            "-o",
            &s(&dir.path().join("x.webm")),
        ],
        "x.webm",
    );
    let cut = dir.path().join("cut.take");
    std::fs::write(&cut, &std::fs::read(&take).unwrap()[..100]).unwrap();
    bad(
        &[
            "export",
            &s(&cut),
            "--config",
            &cfg,
            "--format",
            "glb",
            "-o",
            "x.glb",
        ],
        "cut.take",
    );
    // The same mesh rigged otherwise is another stage.
    let gridded = std::fs::read_to_string(&stage).unwrap().replace(
        "pins = [[168, 58], [344, 58]]",
        "pins = [[168, 58], [344, 58]]\n[puppet.grid]\ncolumns = 4\nrows = 4",
    );
    let grid = dir.path().join("grid.toml");
    std::fs::write(&grid, gridded).unwrap();
    let out = puppetry(&["takes", &s(&takes), "--verify", "--config", &s(&grid)]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        !out.status.success() && text.contains("rigged or pinned otherwise"),
        "{text}"
    );
    bad(
        &[
            "export",
            &take,
            "--config",
            &s(&grid),
            "--format",
            "glb",
            "-o",
            "x.glb",
        ],
        "rigged or pinned otherwise",
    );
    bad(
        &[
            "export",
            &take,
            "--config",
            &cfg,
            "--format",
            "glb",
            "--from=-1",
            "-o",
            "x.glb",
        ],
        "--from",
    );
    // A take of another stage: a changed mesh is told by its rest hash.
    let moved = std::fs::read_to_string(&stage)
        .unwrap()
        .replace("at = [640, 360]", "at = [600, 360]");
    let other = dir.path().join("other.toml");
    std::fs::write(&other, moved).unwrap();
    bad(
        &[
            "export",
            &take,
            "--config",
            &s(&other),
            "--format",
            "glb",
            "-o",
            "x.glb",
        ],
        "rest mesh changed",
    );
}

/// The next text message of `kind` that satisfies `done`.
async fn until(
    ws: &mut crate::common::daemon::Client,
    kind: &str,
    done: impl Fn(&Value) -> bool,
) -> Value {
    tokio::time::timeout(WAIT, async {
        loop {
            let m = next_text(ws).await;
            if m["type"] == kind && done(&m) {
                return m;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no {kind} message came"))
}

fn contact(id: u32, phase: &str, at: [f64; 2]) -> Value {
    json!({"type": "contacts", "contacts": [{"id": id, "phase": phase, "x": at[0], "y": at[1]}]})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn performers_keyframe_over_the_wire_and_the_take_replays_it() {
    let dir = tempfile::tempdir().unwrap();
    let key_file = dir.path().join("g.keys.json");
    let config = stage_config(&format!("keys = \"{}\"", key_file.display()));
    let takes = dir.path().join("takes");
    let running = start_with(&config, options(&takes)).await.unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    until(&mut viewer, "keys", |m| {
        m["keys"].as_array().unwrap().is_empty()
    })
    .await;
    send(&mut ws, json!({"type": "record"})).await;
    until(&mut viewer, "take", |m| m["recording"] == "take-001").await;

    // Two key poses of the head, set by a hand holding it.
    let head = [640.0, 470.0];
    send(&mut ws, contact(1, "down", head)).await;
    send(&mut ws, contact(1, "move", [600.0, 500.0])).await;
    send(
        &mut ws,
        json!({"type": "key_add", "puppet": 0, "name": "left", "at": [0.1, 0.5]}),
    )
    .await;
    send(&mut ws, contact(1, "move", [690.0, 500.0])).await;
    send(
        &mut ws,
        json!({"type": "key_add", "puppet": 0, "name": "right", "at": [0.9, 0.5]}),
    )
    .await;
    send(
        &mut ws,
        json!({"type": "contacts", "contacts": [{"id": 1, "phase": "up"}]}),
    )
    .await;
    let keys = until(&mut viewer, "keys", |m| {
        m["keys"].as_array().unwrap().len() == 2
    })
    .await;
    assert_eq!(keys["keys"][1]["name"], "right");

    // The cursor drives the head: a key handle, and every page sees the cursor.
    for i in 0..=20 {
        let u = 0.1 + 0.8 * i as f64 / 20.0;
        send(
            &mut ws,
            json!({"type": "cursor", "puppet": 0, "at": [u, 0.5]}),
        )
        .await;
    }
    let (mut cursor_seen, mut key_handles) = (false, None);
    tokio::time::timeout(WAIT, async {
        while !(cursor_seen && key_handles.is_some()) {
            let m = next_text(&mut viewer).await;
            cursor_seen |= m["type"] == "keys" && m["cursor"] == json!([0.9, 0.5]);
            if m["type"] == "handles" {
                let keyed = m["handles"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .filter(|h| h["kind"] == "key" && h["owner"] == "keys")
                    .count();
                if keyed > 0 {
                    key_handles = Some(keyed);
                }
            }
        }
    })
    .await
    .expect("the cursor and its key handle reached the viewer");
    assert_eq!(key_handles, Some(1), "one keyed point: the head");
    send(&mut ws, json!({"type": "save_keys", "puppet": 0})).await;
    let saved = until(&mut ws, "keys_saved", |_| true).await;
    assert_eq!(saved["file"], key_file.display().to_string());
    send(&mut ws, json!({"type": "stop_recording"})).await;
    until(&mut viewer, "take", |m| m.get("recording").is_none()).await;
    running.shutdown().await;

    // The key file loads with the stage; the take holds the keyframing and
    // replays bit for bit.
    let again = Stage::from_config(&config).unwrap();
    assert_eq!(again.puppets()[0].keying().keys().len(), 2);
    let take = takes.join("take-001.take");
    let (_, steps) = frames_and_steps(&take);
    let changes: Vec<&Change> = steps.iter().flat_map(|s| &s.changes).collect();
    assert_eq!(
        changes
            .iter()
            .filter(|c| matches!(c, Change::KeyAdd { .. }))
            .count(),
        2
    );
    assert!(
        changes
            .iter()
            .filter(|c| matches!(c, Change::Cursor { .. }))
            .count()
            >= 2
    );
    std::fs::remove_file(&key_file).unwrap();
    let v = verify(&take, Stage::from_config(&config).unwrap()).unwrap();
    assert_eq!(v.first_mismatch, None);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_downloads_takes_and_their_exports() {
    use crate::common::daemon::{http_raw, http_status};
    // As the page asks: the director's token as a bearer token.
    let http_get = |address: std::net::SocketAddr, path: &str| {
        let request = format!(
            "GET {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer boss\r\nConnection: close\r\n\r\n"
        );
        async move { http_raw(address, request.as_bytes()).await }
    };
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let running = start_with(&stage_config(""), options(&takes))
        .await
        .unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    send(&mut ws, json!({"type": "record"})).await;
    until(&mut viewer, "take", |m| m["recording"] == "take-001").await;
    drag(&mut ws, 1, [640.0, 470.0], [600.0, 500.0]).await;
    send(&mut ws, json!({"type": "stop_recording"})).await;
    until(&mut viewer, "take", |m| m.get("recording").is_none()).await;

    let body = |answer: &[u8]| {
        let at = answer.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        answer[at + 4..].to_vec()
    };
    let file = http_get(running.address, "/takes/take-001.take").await;
    assert_eq!(http_status(&file), 200);
    // The take as recorded (its header's stage file, a name here already,
    // is served as its name).
    assert_eq!(
        body(&file),
        std::fs::read(takes.join("take-001.take")).unwrap()
    );

    let glb = http_get(running.address, "/takes/take-001/export?format=glb&fps=24").await;
    assert_eq!(
        http_status(&glb),
        200,
        "{}",
        String::from_utf8_lossy(&glb[..glb.len().min(400)])
    );
    assert!(String::from_utf8_lossy(&glb[..400.min(glb.len())]).contains("take-001.glb"));
    assert_eq!(&body(&glb)[..4], b"glTF");
    // Every page saw the export finish.
    until(&mut viewer, "export", |m| {
        m["finished"] == true && m["error"].is_null()
    })
    .await;

    // Spine comes as one zip of what the editor and player need.
    let spine = http_get(running.address, "/takes/take-001/export?format=spine").await;
    assert_eq!(http_status(&spine), 200);
    let head = String::from_utf8_lossy(&spine[..400.min(spine.len())]).to_string();
    assert!(
        head.contains("take-001.zip") && head.contains("application/zip"),
        "{head}"
    );
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(body(&spine))).unwrap();
    let names: Vec<String> = zip.file_names().map(|n| n.unwrap().into_owned()).collect();
    assert!(names.contains(&"take-001.atlas".to_string()), "{names:?}");
    assert!(names.iter().any(|n| n.ends_with(".png")), "{names:?}");
    let json: Value = serde_json::from_reader(zip.by_name("take-001.json").unwrap()).unwrap();
    assert!(json["skeleton"]["spine"].as_str().unwrap().starts_with('4'));

    assert_eq!(
        http_status(&http_get(running.address, "/takes/take-001/export?format=png").await),
        400
    );
    assert_eq!(
        http_status(&http_get(running.address, "/takes/take-001/export?fps=x").await),
        400
    );
    assert_eq!(
        http_status(&http_get(running.address, "/takes/nope/export").await),
        404
    );
    assert_eq!(
        http_status(&http_get(running.address, "/takes/..%2Fstage.take").await),
        404
    );
    let late = http_get(
        running.address,
        "/takes/take-001/export?format=glb&from=5&to=1",
    )
    .await;
    assert_eq!(http_status(&late), 400);
    assert!(String::from_utf8_lossy(&late).contains("to: 1 s is not after from"));
    // Past the take's end: refused, naming the parameter, not padded.
    let past = http_get(running.address, "/takes/take-001/export?format=glb&to=500").await;
    assert_eq!(http_status(&past), 400);
    assert!(String::from_utf8_lossy(&past).contains("to: 500 s is past the take's end"));
    let no_format = http_get(running.address, "/takes/take-001/export").await;
    assert_eq!(http_status(&no_format), 400);
    assert!(String::from_utf8_lossy(&no_format).contains("format: required"));
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_started_by_the_first_input_is_announced_to_every_page() {
    let dir = tempfile::tempdir().unwrap();
    let mut o = options(dir.path());
    o.record = true;
    let running = start_with(&stage_config(""), o).await.unwrap();
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    drag(&mut ws, 1, [640.0, 470.0], [600.0, 500.0]).await;
    take_state(&mut viewer, |m| m["recording"] == "take-001").await;
    // Takes are listed oldest first, by file name.
    send(&mut ws, json!({"type": "stop_recording"})).await;
    take_state(&mut viewer, |m| m.get("recording").is_none()).await;
    send(&mut ws, json!({"type": "record", "name": "b-second"})).await;
    take_state(&mut viewer, |m| m["recording"] == "b-second").await;
    send(&mut ws, json!({"type": "stop_recording"})).await;
    take_state(&mut viewer, |m| m.get("recording").is_none()).await;
    send(&mut ws, json!({"type": "list_takes"})).await;
    let list = until(&mut ws, "takes", |_| true).await;
    let names: Vec<&str> = list["takes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["take-001", "b-second"]);
    // A bad replace region is refused.
    send(&mut ws, json!({"type": "play", "take": "take-001", "replace": [{"puppet": 9, "at": [0, 0], "radius": 1}]})).await;
    let error = until(&mut ws, "error", |_| true).await;
    assert!(
        error["message"]
            .as_str()
            .unwrap()
            .contains("replace[0].puppet"),
        "{error}"
    );
    running.shutdown().await;
}

#[test]
fn sigterm_ends_the_take_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let (mut child, _) = serve_binary(&stage_file(dir.path()), &takes, None);
    let take = takes.join("take-001.take");
    let deadline = Instant::now() + PLAYS;
    while !summarize(&take).is_ok_and(|s| s.frames >= 5) {
        assert!(Instant::now() < deadline, "no frames reached the take");
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: signalling our own child process.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let status = child.wait().unwrap();
    assert!(status.success(), "the daemon stopped with {status}");
    assert_eq!(summarize(&take).unwrap().ending, "shutdown");
}

/// Writes a take of `stage` named `name` into `dir`: a pin on the right
/// hand, then a finger lands on the puppet's middle, moves, and never lifts
/// (the take ends with it down, as a take stopped with a finger down did
/// before such takes let go at their end). With `last`, a step that
/// changes nothing comes at that time.
fn write_held_take(config: &ShowConfig, dir: &Path, name: &str, last: Option<f64>) {
    use puppetry_input::{Contact, ContactFrame, Phase, SourceId};
    let stage = Stage::from_config(config).unwrap();
    let header = puppetry_take::Header::of_stage(name, "test.toml", &stage, true);
    let path = dir.join(format!("{name}.take"));
    let mut writer = puppetry_take::TakeWriter::create(&path, &header).unwrap();
    let mut steps: Vec<puppetry_take::Step> = (0..10)
        .map(|k| {
            let phase = if k == 0 { Phase::Down } else { Phase::Move };
            let at = glam::DVec2::new(640.0 + 3.0 * k as f64, 470.0);
            let frame = ContactFrame {
                source: SourceId::new("client:9"),
                time: 0.0,
                contacts: vec![Contact::new(1, phase, at)],
            };
            puppetry_take::Step {
                t: 0.02 * k as f64,
                changes: vec![Change::Contacts { frame }],
                events: Vec::new(),
            }
        })
        .collect();
    steps[0].changes.push(Change::Pin {
        owner: "client:9".into(),
        at: glam::DVec2::new(720.0, 380.0),
    });
    if let Some(t) = last {
        // A depth flip off the stage: nothing there to flip.
        let at = glam::DVec2::new(-100.0, -100.0);
        steps.push(puppetry_take::Step {
            t,
            changes: vec![Change::DepthFlip { at }],
            events: Vec::new(),
        });
    }
    for step in steps {
        writer.write(&Record::Step(step)).unwrap();
    }
    writer.flush().unwrap();
}

/// Owners of every handle on stage but the stage file's pins, as a client
/// connecting now is told.
async fn handle_owners(running: &Running) -> Vec<String> {
    let (_ws, stage) = connect(running, json!({"type": "hello", "role": "viewer"})).await;
    stage["puppets"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|p| p["handles"].as_array().unwrap())
        .map(|h| h["owner"].as_str().unwrap().to_string())
        .filter(|owner| owner != "config")
        .collect()
}

/// The take state a client connecting now is told.
async fn take_state_now(running: &Running) -> Value {
    let (mut ws, _) = connect(running, json!({"type": "hello", "role": "viewer"})).await;
    take_state(&mut ws, |_| true).await
}

/// Waits (bounded) until no take plays. `ws` asked for the play: its ping
/// answered means the play was taken on, so "not playing" after it means
/// the take ended.
async fn until_played(running: &Running, ws: &mut crate::common::daemon::Client) {
    send(ws, json!({"type": "ping", "t": 1.0})).await;
    until(ws, "pong", |_| true).await;
    let deadline = Instant::now() + PLAYS;
    while take_state_now(running).await.get("playing").is_some() {
        assert!(Instant::now() < deadline, "the take did not end");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The issue's stuck handle: a take that ends with a finger still down,
/// played to its end or stopped in the middle, leaves nothing held (its
/// finger held the puppet while it played).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_played_take_lets_go_of_what_it_holds_when_it_ends_or_is_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let config = stage_config("");
    write_held_take(&config, dir.path(), "held", None);
    write_held_take(&config, dir.path(), "long", Some(3600.0));
    let running = start_with(&config, options(dir.path())).await.unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;

    send(&mut ws, json!({"type": "play", "take": "held"})).await;
    until_played(&running, &mut ws).await;
    assert_eq!(handle_owners(&running).await, Vec::<String>::new());

    // Stopped while its finger is down (its last step is an hour off).
    send(&mut ws, json!({"type": "play", "take": "long"})).await;
    let deadline = Instant::now() + PLAYS;
    // Its pin and its finger.
    while handle_owners(&running)
        .await
        .iter()
        .filter(|o| *o == "long/client:9")
        .count()
        < 2
    {
        assert!(
            Instant::now() < deadline,
            "the played finger never held the puppet"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    send(&mut ws, json!({"type": "stop_playing"})).await;
    until_played(&running, &mut ws).await;
    assert_eq!(handle_owners(&running).await, Vec::<String>::new());
    running.shutdown().await;
}

/// Replays a take's steps into a fresh stage: the owners of the handles
/// left at its end, but the stage file's pins.
fn held_after_replay(config: &ShowConfig, take: &Path) -> Vec<String> {
    let mut replayer = puppetry_take::replay::Replayer::new(Stage::from_config(config).unwrap());
    for step in frames_and_steps(take).1 {
        replayer.apply(&step).unwrap();
    }
    replayer
        .stage()
        .puppets()
        .iter()
        .flat_map(|p| p.handles())
        .map(|h| h.owner.to_string())
        .filter(|owner| owner != "config")
        .collect()
}

/// The releases in a take's last step.
fn last_releases(take: &Path) -> Vec<String> {
    let (_, steps) = frames_and_steps(take);
    steps
        .last()
        .unwrap()
        .changes
        .iter()
        .filter_map(|c| match c {
            Change::Release { source } => Some(source.clone()),
            _ => None,
        })
        .collect()
}

/// The issue's recipe: ● rec, a finger holds the puppet, ■ stop while it
/// is down, lift, play the take to its end: nothing stays held. The take
/// lets go of the finger in its last step, so it ends as it began.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_stopped_with_a_finger_down_lets_go_of_it_in_the_take() {
    let dir = tempfile::tempdir().unwrap();
    let config = stage_config("");
    let running = start_with(&config, options(dir.path())).await.unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;

    send(&mut ws, json!({"type": "record"})).await;
    take_state(&mut ws, |m| m["recording"] == "take-001").await;
    send(&mut ws, contact(1, "down", [640.0, 470.0])).await;
    for k in 1..=10 {
        send(&mut ws, contact(1, "move", [640.0 - 2.0 * k as f64, 470.0])).await;
    }
    send(&mut ws, json!({"type": "stop_recording"})).await;
    take_state(&mut ws, |m| m.get("recording").is_none()).await;
    // The live finger still holds the puppet until it lifts.
    let live = handle_owners(&running).await;
    assert!(
        live.len() == 1 && live[0].starts_with("client:"),
        "{live:?}"
    );
    send(
        &mut ws,
        json!({"type": "contacts", "contacts": [{"id": 1, "phase": "up"}]}),
    )
    .await;

    let take = dir.path().join("take-001.take");
    assert_eq!(last_releases(&take), live);
    assert_eq!(held_after_replay(&config, &take), Vec::<String>::new());
    assert_eq!(
        verify(&take, Stage::from_config(&config).unwrap())
            .unwrap()
            .first_mismatch,
        None
    );

    send(&mut ws, json!({"type": "play", "take": "take-001"})).await;
    until_played(&running, &mut ws).await;
    assert_eq!(handle_owners(&running).await, Vec::<String>::new());
    running.shutdown().await;
}

/// An overdub that stops with its played take while a live hand is down:
/// the overdub lets go of the hand and of the played finger in its last
/// step, the live stage keeps the hand until it lifts, and nothing of the
/// played take stays.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_overdub_ending_with_a_hand_down_leaves_nothing_held() {
    let dir = tempfile::tempdir().unwrap();
    let config = stage_config("");
    // Its last step an hour off: it ends when stopped, which is also how
    // a take played out ends (the player's end).
    write_held_take(&config, dir.path(), "long", Some(3600.0));
    let running = start_with(&config, options(dir.path())).await.unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;

    send(
        &mut ws,
        json!({"type": "play", "take": "long", "overdub": true}),
    )
    .await;
    send(&mut ws, json!({"type": "ping", "t": 1.0})).await;
    until(&mut ws, "pong", |_| true).await;
    send(&mut ws, contact(1, "down", [560.0, 380.0])).await;
    send(&mut ws, contact(1, "move", [550.0, 380.0])).await;
    let deadline = Instant::now() + PLAYS;
    let live = loop {
        let owners = handle_owners(&running).await;
        let live: Vec<String> = owners
            .iter()
            .filter(|o| o.starts_with("client:"))
            .cloned()
            .collect();
        if owners.iter().any(|o| o == "long/client:9") && live.len() == 1 {
            break live;
        }
        assert!(Instant::now() < deadline, "{owners:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    send(&mut ws, json!({"type": "stop_playing"})).await;
    until_played(&running, &mut ws).await;
    assert_eq!(
        handle_owners(&running).await,
        live,
        "only the live hand holds"
    );

    let overdub = dir.path().join("take-001.take");
    assert_eq!(summarize(&overdub).unwrap().ending, "stopped");
    let mut released: Vec<String> = frames_and_steps(&overdub)
        .1
        .iter()
        .flat_map(|s| &s.changes)
        .filter_map(|c| match c {
            Change::Release { source } => Some(source.clone()),
            _ => None,
        })
        .collect();
    released.sort();
    assert_eq!(released, [live[0].clone(), "long/client:9".to_string()]);
    assert_eq!(held_after_replay(&config, &overdub), Vec::<String>::new());
    running.shutdown().await;
}

/// The take being recorded is not offered: playing or overdubbing it is
/// refused (`busy`) and nothing plays; the list says it is recording.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_take_being_recorded_cannot_be_played_into_itself() {
    let dir = tempfile::tempdir().unwrap();
    let running = start_with(&stage_config(""), options(dir.path()))
        .await
        .unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    send(&mut ws, json!({"type": "record"})).await;
    take_state(&mut ws, |m| m["recording"] == "take-001").await;
    drag(&mut ws, 1, [640.0, 470.0], [600.0, 500.0]).await;

    for overdub in [false, true] {
        send(
            &mut ws,
            json!({"type": "play", "take": "take-001", "overdub": overdub}),
        )
        .await;
        let error = until(&mut ws, "error", |_| true).await;
        assert_eq!(error["code"], "busy", "overdub {overdub}: {error}");
        assert!(
            error["message"].as_str().unwrap().contains("take-001"),
            "{error}"
        );
    }
    let state = take_state_now(&running).await;
    assert_eq!(state["recording"], "take-001", "{state}");
    assert!(state.get("playing").is_none(), "{state}");

    send(&mut ws, json!({"type": "list_takes"})).await;
    let list = until(&mut ws, "takes", |_| true).await;
    assert_eq!(list["takes"][0]["name"], "take-001");
    assert_eq!(list["takes"][0]["ending"], "recording", "{list}");

    send(&mut ws, json!({"type": "stop_recording"})).await;
    take_state(&mut ws, |m| m.get("recording").is_none()).await;
    send(&mut ws, json!({"type": "list_takes"})).await;
    let list = until(&mut ws, "takes", |_| true).await;
    assert_eq!(list["takes"][0]["ending"], "stopped", "{list}");
    running.shutdown().await;
}

/// `puppetry serve` on the bundled demo, from the working folder `work`
/// (its bundle unpacked under `work/data`), as a user runs it.
fn serve_demo_in(work: &Path) -> crate::common::served::Served {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"));
    command
        .current_dir(work)
        .env("XDG_DATA_HOME", work.join("data"))
        .args(["serve", "--listen", "127.0.0.1:0"]);
    crate::common::served::Served::start(command)
}

/// Records a take of a drag on the `index`-th puppet of the stage a
/// director's connection to `served` sees.
async fn record_a_drag(served: &crate::common::served::Served, index: usize) {
    let hello = json!({"type": "hello", "role": "director", "token": "director"});
    let (mut ws, stage) = crate::common::daemon::connect_url(&served.ws_url(), hello).await;
    let mesh = crate::common::daemon::puppet_mesh(&stage, index);
    let v = mesh.vertices();
    let [a, b, c] = mesh.triangles()[0];
    let on = (v[a as usize] + v[b as usize] + v[c as usize]) / 3.0;
    send(&mut ws, json!({"type": "record"})).await;
    take_state(&mut ws, |m| m["recording"].is_string()).await;
    drag(&mut ws, 1, on.into(), [on.x + 40.0, on.y + 30.0]).await;
}

/// Issue 45: a picture a director added from the page did not come back
/// after a restart unless the daemon ran from the stage file's folder —
/// the README's own flow, `serve` on the bundled demo from anywhere — and
/// a take with it could not be verified or exported ("recorded with 2
/// puppets, the stage has 1"). From a working folder of its own: a
/// picture added and a take of it recorded, the daemon killed (-9); started
/// again, the picture is back and a second take records it; from the
/// command line both takes verify and export, with no stage file written
/// by hand.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_picture_added_from_the_page_comes_back_and_its_takes_export_from_anywhere() {
    let work = tempfile::tempdir().unwrap();
    let mut served = serve_demo_in(work.path());
    let png = std::fs::read(puppetry_testkit::stage_text::gingerbread_png()).unwrap();
    let mut request = format!(
        "POST /puppets?name=robot&vertices=300 HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n\
         Authorization: Bearer director\r\nContent-Type: image/png\r\nContent-Length: {}\r\n\
         Connection: close\r\n\r\n",
        png.len(),
        host = served.http
    )
    .into_bytes();
    request.extend_from_slice(&png);
    let answer = crate::common::daemon::http_raw(served.http.as_str(), &request).await;
    assert_eq!(
        crate::common::daemon::http_status(&answer),
        200,
        "{}",
        String::from_utf8_lossy(&answer)
    );
    record_a_drag(&served, 1).await;
    let take = work.path().join("takes/take-001.take");
    let deadline = Instant::now() + PLAYS;
    while summarize(&take).map_or(true, |s| s.frames < 5) {
        assert!(Instant::now() < deadline, "no frames reached the take");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    served.child.kill().unwrap();
    served.child.wait().unwrap();

    let served = serve_demo_in(work.path());
    let hello = json!({"type": "hello", "role": "viewer"});
    let (_viewer, stage) = crate::common::daemon::connect_url(&served.ws_url(), hello).await;
    let names: Vec<&str> = stage["puppets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["gingerbread", "robot"], "{:?}", served.log());
    record_a_drag(&served, 1).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let log = served.stop().join("\n");
    assert!(!log.contains("not brought back"), "{log}");

    let data = work.path().join("data");
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
            .current_dir(work.path())
            .env("XDG_DATA_HOME", &data)
            .args(args)
            .output()
            .unwrap()
    };
    let listing = run(&["takes", "takes", "--verify"]);
    let text = String::from_utf8_lossy(&listing.stdout);
    assert!(
        listing.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&listing.stderr)
    );
    assert!(!text.contains("cannot replay"), "{text}");
    // The second take began on the stage as it came back: it replays
    // exactly; the first (killed mid-take) keeps what reached the disk.
    assert!(text.contains("replays exactly"), "{text}");
    for name in ["take-001", "take-002"] {
        let out = format!("{name}.glb");
        let exported = run(&[
            "export",
            &format!("takes/{name}.take"),
            "--format",
            "glb",
            "-o",
            &out,
        ]);
        assert!(
            exported.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&exported.stderr)
        );
        assert!(work.path().join(&out).is_file());
    }
}
