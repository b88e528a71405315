//! Takes guarded, exports bounded (issue 32, items 1, 2, 6 and 12): a take
//! and its exports are served to a director's bearer token only, with no
//! folder of the daemon's in what is served; an unknown export parameter is
//! a 400; an export of a long take at a high frame rate is refused before
//! the daemon's memory grows (its peak RSS measured); an export never
//! writes through a link planted at the name the old code used, nor through
//! one at the command line's `-o`; `play` of a missing take is `not_found`.

use std::path::{Path, PathBuf};

use puppetry_daemon::serve::{Options, start_with};
use puppetry_daemon::stream::WebFiles;
use puppetry_stage::Stage;
use puppetry_take::{End, Header, Record, TakeReader, TakeWriter};
use serde_json::json;

use crate::common::daemon::{
    WAIT, connect, http_raw, http_status, next_text, stage_config, stage_text,
};
use crate::common::served::{Served, serve_command};

/// Where the takes' headers say they were recorded: a folder of the show
/// machine's that must not reach a page.
const STAGE_FILE: &str = "/home/show/secret-folder/stage.toml";

/// Writes a take of the test stage named `name` into `dir`, `seconds`
/// long: its header, the puppets' rest pose at 0 and an end. Cheap however
/// long it is: the length is the end's time.
pub(crate) fn write_take(dir: &Path, name: &str, seconds: f64) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let stage = Stage::from_config(&stage_config("")).unwrap();
    let header = Header::of_stage(name, STAGE_FILE, &stage, true);
    let path = dir.join(format!("{name}.take"));
    let mut writer = TakeWriter::create(&path, &header).unwrap();
    for (i, p) in stage.puppets().iter().enumerate() {
        let frame = puppetry_take::Frame::of_pose(i as u32, 0.0, p.pose());
        writer.write(&Record::Frame(frame)).unwrap();
    }
    let end = End {
        t: seconds,
        reason: "stopped".into(),
    };
    writer.write(&Record::End(end)).unwrap();
    writer.flush().unwrap();
    path
}

/// A GET of `path`, with `Authorization: Bearer TOKEN` when given.
async fn get(address: impl tokio::net::ToSocketAddrs, path: &str, token: Option<&str>) -> Vec<u8> {
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    let request = format!("GET {path} HTTP/1.1\r\nHost: x\r\n{auth}Connection: close\r\n\r\n");
    http_raw(address, request.as_bytes()).await
}

fn body(answer: &[u8]) -> &[u8] {
    let at = answer
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("an HTTP answer");
    &answer[at + 4..]
}

fn text(answer: &[u8]) -> String {
    String::from_utf8_lossy(&answer[..answer.len().min(2000)]).into_owned()
}

fn options(takes: &Path) -> Options {
    let mut o = Options::new(WebFiles::Embedded);
    o.takes_dir = takes.to_path_buf();
    o
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn takes_and_exports_are_served_to_a_directors_token_only() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let take = write_take(&takes, "take-001", 2.0);
    let running = start_with(&stage_config(""), options(&takes))
        .await
        .unwrap();
    let at = running.address;
    for path in ["/takes/take-001.take", "/takes/take-001/export?format=glb"] {
        // What an <img> or a link on any page fires: no header.
        let bare = get(at, path, None).await;
        assert_eq!(http_status(&bare), 401, "{path}: {}", text(&bare));
        assert!(
            text(&bare)
                .to_ascii_lowercase()
                .contains("www-authenticate: bearer"),
            "{}",
            text(&bare)
        );
        // A token in the query opens nothing either.
        let query = get(
            at,
            &format!(
                "{path}{}token=boss",
                if path.contains('?') { '&' } else { '?' }
            ),
            None,
        )
        .await;
        assert_eq!(http_status(&query), 401, "{path}: {}", text(&query));
        let wrong = get(at, path, Some("not-a-token")).await;
        assert_eq!(http_status(&wrong), 401, "{path}: {}", text(&wrong));
        let performer = get(at, path, Some("secret")).await;
        assert_eq!(http_status(&performer), 403, "{path}: {}", text(&performer));
    }

    // The director gets the take, its header naming the stage file by its
    // name only; every record after the header is the file's own.
    let served = get(at, "/takes/take-001.take", Some("boss")).await;
    assert_eq!(http_status(&served), 200, "{}", text(&served));
    let served = body(&served).to_vec();
    assert!(
        !String::from_utf8_lossy(&served).contains("secret-folder"),
        "the served take names the daemon's folder"
    );
    let copy = dir.path().join("served.take");
    std::fs::write(&copy, &served).unwrap();
    let mut reader = TakeReader::open(&copy).unwrap();
    assert_eq!(reader.header.stage_file, "stage.toml");
    let mut original = TakeReader::open(&take).unwrap();
    assert_eq!(
        original.header.stage_file, STAGE_FILE,
        "the file on disk is left as recorded"
    );
    let mut expected = original.header.clone();
    expected.stage_file = "stage.toml".into();
    assert_eq!(reader.header, expected);
    let records: Vec<Record> = reader.by_ref().map(Result::unwrap).collect();
    let on_disk: Vec<Record> = original.by_ref().map(Result::unwrap).collect();
    assert_eq!(records, on_disk);
    assert!(matches!(reader.tail(), Some(puppetry_take::Tail::Ended(_))));

    // And its export, streamed.
    let glb = get(at, "/takes/take-001/export?format=glb&fps=10", Some("boss")).await;
    assert_eq!(http_status(&glb), 200, "{}", text(&glb));
    assert_eq!(&body(&glb)[..4], b"glTF");
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unknown_export_parameter_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    write_take(&takes, "take-001", 1.0);
    let running = start_with(&stage_config(""), options(&takes))
        .await
        .unwrap();
    let answer = get(
        running.address,
        "/takes/take-001/export?format=glb&fsp=24",
        Some("boss"),
    )
    .await;
    assert_eq!(http_status(&answer), 400, "{}", text(&answer));
    assert!(
        text(&answer).contains("fsp: not a parameter"),
        "{}",
        text(&answer)
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn play_of_a_missing_take_is_not_found_and_names_no_folder() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    std::fs::create_dir_all(&takes).unwrap();
    let running = start_with(&stage_config(""), options(&takes))
        .await
        .unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut ws, _) = connect(&running, hello).await;
    for overdub in [false, true] {
        let play = json!({"type": "play", "take": "nope", "overdub": overdub});
        futures_util::SinkExt::send(
            &mut ws,
            tokio_tungstenite::tungstenite::Message::text(play.to_string()),
        )
        .await
        .unwrap();
        let error = tokio::time::timeout(WAIT, async {
            loop {
                let m = next_text(&mut ws).await;
                if m["type"] == "error" {
                    return m;
                }
            }
        })
        .await
        .expect("an answer to play");
        assert_eq!(error["code"], "not_found", "{error}");
        let message = error["message"].as_str().unwrap();
        assert!(message.contains("nope"), "{error}");
        let folder = takes.display().to_string();
        assert!(
            !message.contains(&folder) && !message.contains('/'),
            "{error}"
        );
    }
    // Nothing was recorded by the refused overdub.
    assert_eq!(std::fs::read_dir(&takes).unwrap().count(), 0);
    running.shutdown().await;
}

/// The daemon binary serving `stage` with the takes of `takes`.
fn serve_binary(stage: &Path, takes: &Path) -> Served {
    let mut command = serve_command(stage);
    command.arg("--takes").arg(takes);
    Served::start(command)
}

/// The daemon's memory may grow this much at most while refusing: a
/// 90-second take at 1000 fps is 720 MB of motion for the test puppet's
/// 999 vertices, and the glb over 1 GB; before the budget the daemon built
/// both.
const REFUSAL_GROWTH_KB: u64 = 64 * 1024;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_export_of_a_long_take_at_a_high_frame_rate_is_refused_before_memory_grows() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let take = write_take(&takes, "long", 90.0);
    let stage = dir.path().join("stage.toml");
    std::fs::write(&stage, stage_text("")).unwrap();
    let daemon = serve_binary(&stage, &takes);
    // The daemon at rest, having served a page's worth of requests.
    let small = get(
        &daemon.http,
        "/takes/long/export?format=glb&fps=1&to=2",
        Some("boss"),
    )
    .await;
    assert_eq!(http_status(&small), 200, "{}", text(&small));
    let before = daemon.peak_rss_kib();
    for format in ["glb", "spine"] {
        let path = format!("/takes/long/export?format={format}&fps=1000");
        let answer = get(&daemon.http, &path, Some("boss")).await;
        let after = daemon.peak_rss_kib();
        println!(
            "{path}: {} — daemon peak RSS {before} kB before, {after} kB after",
            text(&answer).lines().last().unwrap_or("")
        );
        assert_eq!(http_status(&answer), 413, "{}", text(&answer));
        let said = text(&answer);
        assert!(
            said.contains("MB") && said.contains("past the limit of 268.4 MB"),
            "{said}"
        );
        assert!(
            after < before + REFUSAL_GROWTH_KB,
            "the daemon grew from {before} kB to {after} kB refusing {path}"
        );
    }
    // A range of it at that rate fits.
    let range = get(
        &daemon.http,
        "/takes/long/export?format=glb&fps=1000&to=3",
        Some("boss"),
    )
    .await;
    assert_eq!(http_status(&range), 200, "{}", text(&range));

    // The command line keeps the same limits, and writes nothing.
    let out = dir.path().join("long.glb");
    let cli = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .arg("export")
        .arg(&take)
        .arg("--config")
        .arg(&stage)
        .args(["--format", "glb", "--fps", "1000", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&cli.stderr);
    println!("puppetry export --fps 1000: {}", said.trim());
    assert!(!cli.status.success());
    assert!(said.contains("past the limit"), "{said}");
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["stage.toml", "takes"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_export_never_writes_through_a_planted_link() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let take = write_take(&takes, "take-001", 1.0);
    let stage = dir.path().join("stage.toml");
    std::fs::write(&stage, stage_text("")).unwrap();
    let precious = dir.path().join("precious.txt");
    std::fs::write(&precious, "the show's running order").unwrap();

    // The name the daemon used to export to, in the system's temporary
    // folder, linked to a file of the user's.
    let daemon = serve_binary(&stage, &takes);
    let planted = std::env::temp_dir().join(format!(
        "puppetry-export-{}-take-001.glb",
        daemon.child.id()
    ));
    let _ = std::fs::remove_file(&planted);
    std::os::unix::fs::symlink(&precious, &planted).unwrap();
    let glb = get(
        &daemon.http,
        "/takes/take-001/export?format=glb&fps=10",
        Some("boss"),
    )
    .await;
    let kept = std::fs::read_to_string(&precious).unwrap();
    let _ = std::fs::remove_file(&planted);
    assert_eq!(http_status(&glb), 200, "{}", text(&glb));
    assert_eq!(&body(&glb)[..4], b"glTF");
    assert_eq!(
        kept, "the show's running order",
        "the export wrote through the link"
    );

    // `-o` itself a link: refused as a file already there; with --force
    // replaced by the export, its target untouched.
    let out = dir.path().join("take.glb");
    std::os::unix::fs::symlink(&precious, &out).unwrap();
    let export = |force: bool| {
        let mut cli = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"));
        cli.arg("export")
            .arg(&take)
            .arg("--config")
            .arg(&stage)
            .args(["--format", "glb", "--fps", "10", "-o"])
            .arg(&out);
        if force {
            cli.arg("--force");
        }
        cli.output().unwrap()
    };
    let cli = export(false);
    assert!(
        !cli.status.success(),
        "a link at -o replaced without --force"
    );
    assert!(std::fs::symlink_metadata(&out).unwrap().is_symlink());
    let cli = export(true);
    assert!(
        cli.status.success(),
        "{}",
        String::from_utf8_lossy(&cli.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(&precious).unwrap(),
        "the show's running order",
        "the export wrote through -o's link"
    );
    assert!(!std::fs::symlink_metadata(&out).unwrap().is_symlink());
    assert_eq!(&std::fs::read(&out).unwrap()[..4], b"glTF");
    // Nothing else was left in the folder.
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["precious.txt", "stage.toml", "take.glb", "takes"]);
}

/// A take recorded before a puppet was added exports (found by `puppetry
/// soak`: the daemon exported with the line-up of now, one puppet more
/// than the take's, and answered 422 "recorded with 1 puppets, the stage
/// has 2"). Puppet ids are never reused, so those added later come after
/// the take's own.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_exports_after_a_puppet_was_added() {
    use futures_util::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    write_take(&takes, "before-the-rope", 1.0);
    let running = start_with(&stage_config(""), options(&takes))
        .await
        .unwrap();
    let hello = json!({"type": "hello", "role": "director", "token": "boss"});
    let (mut director, _) = crate::common::daemon::connect(&running, hello).await;
    let points: Vec<[f64; 2]> = (0..20).map(|k| [100.0 + 10.0 * k as f64, 600.0]).collect();
    let add = json!({"type": "add_curve", "name": "rope", "points": points, "width": 6.0, "colour": "#336699"});
    director.send(Message::text(add.to_string())).await.unwrap();
    loop {
        let m = crate::common::daemon::next_text(&mut director).await;
        assert_ne!(m["type"], "error", "{m}");
        if m["type"] == "puppet_added" {
            break;
        }
    }
    for format in ["glb", "spine"] {
        let path = format!("/takes/before-the-rope/export?format={format}&fps=10");
        let answer = get(running.address, &path, Some("boss")).await;
        assert_eq!(http_status(&answer), 200, "{format}: {}", text(&answer));
    }
    running.shutdown().await;
}

/// `export T.take -o T.take` (or through a link to it) is refused and the
/// take is kept byte for byte (issue 34: it was replaced by the glb, exit 0).
#[test]
fn an_export_never_replaces_the_take_it_reads() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    let take = write_take(&takes, "take-001", 1.0);
    let stage = dir.path().join("stage.toml");
    std::fs::write(&stage, stage_text("")).unwrap();
    let link = dir.path().join("link.take");
    std::os::unix::fs::symlink(&take, &link).unwrap();
    let before = std::fs::read(&take).unwrap();
    for output in [&take, &link] {
        for format in ["glb", "spine"] {
            let cli = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
                .arg("export")
                .arg(&take)
                .arg("--config")
                .arg(&stage)
                .args(["--format", format, "--fps", "10", "-o"])
                .arg(output)
                .output()
                .unwrap();
            let said = String::from_utf8_lossy(&cli.stderr);
            assert!(!cli.status.success(), "{format} -o {}", output.display());
            assert!(said.contains("is the take being exported"), "{said}");
            assert_eq!(std::fs::read(&take).unwrap(), before, "the take changed");
        }
    }
}
