//! Puppets at runtime: a director adds a picture to the running stage
//! (`POST /puppets`), removes and reorders puppets; every client follows
//! with a fresh `stage` message, performers play the new puppet, and bad
//! pictures and requests get typed errors that name what is wrong.

use futures_util::SinkExt;
use puppetry_daemon::serve::{Options, Running, start_with};
use puppetry_daemon::stream::WebFiles;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::*;

const DIRECTOR: &str = "boss";
const PERFORMER: &str = "secret";

/// A daemon of the test stage whose added pictures go to `dir`.
async fn daemon_keeping_pictures_in(dir: &std::path::Path) -> Running {
    let mut options = Options::new(WebFiles::Embedded);
    options.puppets_dir = dir.join("puppets");
    options.takes_dir = dir.join("takes");
    start_with(&stage_config(""), options).await.unwrap()
}

/// A `width`×`height` RGBA PNG whose pixels `rgba` gives.
fn png(width: u32, height: u32, rgba: impl Fn(u32, u32) -> [u8; 4]) -> Vec<u8> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        let pixels: Vec<u8> = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .flat_map(|(x, y)| rgba(x, y))
            .collect();
        writer.write_image_data(&pixels).unwrap();
    }
    bytes
}

/// A red disc on a transparent background.
fn disc() -> Vec<u8> {
    png(120, 100, |x, y| {
        let (dx, dy) = (x as f64 - 60.0, y as f64 - 50.0);
        if dx * dx + dy * dy < 40.0 * 40.0 {
            [200, 30, 30, 255]
        } else {
            [0, 0, 0, 0]
        }
    })
}

/// POSTs `body` to `/puppets?query` with `headers`; the status and the
/// JSON answer.
async fn post(running: &Running, query: &str, headers: &[&str], body: &[u8]) -> (u16, Value) {
    let mut request = format!(
        "POST /puppets?{query} HTTP/1.1\r\nHost: {}\r\nContent-Type: image/png\r\nContent-Length: {}\r\nConnection: close\r\n",
        running.address,
        body.len()
    );
    for h in headers {
        request.push_str(h);
        request.push_str("\r\n");
    }
    request.push_str("\r\n");
    let mut bytes = request.into_bytes();
    bytes.extend_from_slice(body);
    let answer = http_raw(running.address, &bytes).await;
    let status = http_status(&answer);
    let at = answer
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a header end");
    let json = serde_json::from_slice(&answer[at + 4..]).unwrap_or_else(|e| {
        panic!(
            "{status}: not JSON ({e}): {:?}",
            String::from_utf8_lossy(&answer[at + 4..])
        )
    });
    (status, json)
}

const AS_DIRECTOR: &str = "Authorization: Bearer boss";

async fn send(ws: &mut Client, m: Value) {
    ws.send(Message::text(m.to_string())).await.unwrap();
}

/// Reads until a text message of `kind` satisfies `done`.
async fn until(ws: &mut Client, kind: &str, done: impl Fn(&Value) -> bool) -> Value {
    loop {
        let m = next_text(ws).await;
        if m["type"] == kind && done(&m) {
            return m;
        }
    }
}

fn ids(stage: &Value) -> Vec<u64> {
    stage["puppets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["id"].as_u64().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_picture_a_director_adds_reaches_every_client_and_performers_play_it() {
    let dir = tempfile::tempdir().unwrap();
    let running = daemon_keeping_pictures_in(dir.path()).await;
    let (mut viewer, first) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    assert_eq!(ids(&first), [0]);
    let (mut performer, _) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": PERFORMER}),
    )
    .await;

    let picture = disc();
    let (status, added) = post(
        &running,
        "name=ball&vertices=300&x=200&y=200",
        &[AS_DIRECTOR],
        &picture,
    )
    .await;
    assert_eq!(status, 200, "{added}");
    assert_eq!(added["type"], "puppet_added");
    assert_eq!(added["puppet"], 1);
    assert_eq!(added["name"], "ball");
    assert_eq!(added["warnings"], json!([]));
    let vertices = added["vertices"].as_u64().unwrap();
    assert!((255..=345).contains(&vertices), "asked 300, got {vertices}");

    // Every client gets the new lineup, the new puppet on top.
    let stage = until(&mut viewer, "stage", |_| true).await;
    assert_eq!(ids(&stage), [0, 1]);
    let ball = &stage["puppets"][1];
    assert_eq!(ball["name"], "ball");
    assert_eq!(ball["rest"].as_array().unwrap().len() as u64, 2 * vertices);
    let texture = http_get(running.address, "/puppets/1/texture.png").await;
    assert!(
        texture.ends_with(&picture),
        "the picture is served as the texture"
    );
    for file in ["ball.png", "ball.mesh.json"] {
        assert!(
            dir.path().join("puppets").join(file).exists(),
            "{file} kept"
        );
    }

    // A performer grabs it and it moves.
    until(&mut performer, "stage", |m| ids(m) == [0, 1]).await;
    send(
        &mut performer,
        json!({"type": "contacts", "contacts": [{"id": 7, "phase": "down", "x": 200.0, "y": 200.0}]}),
    )
    .await;
    until(&mut viewer, "handles", |m| {
        m["puppet"] == 1 && contact_owners(m).len() == 1
    })
    .await;
    send(
        &mut performer,
        json!({"type": "contacts", "contacts": [{"id": 7, "phase": "move", "x": 230.0, "y": 210.0}]}),
    )
    .await;
    frame_until(&mut viewer, |f| f.puppet == 1).await;

    // The same name again is made unique, files and all.
    let (status, again) = post(&running, "name=ball&vertices=300", &[AS_DIRECTOR], &picture).await;
    assert_eq!(status, 200, "{again}");
    assert_eq!(again["puppet"], 2);
    assert_eq!(again["name"], "ball-2");
    assert!(dir.path().join("puppets/ball-2.png").exists());
    running.shutdown().await;
}

/// A request that must be refused: query, headers, body, and the HTTP
/// status, error code and field it gets.
type Refused<'a> = (
    &'a str,
    Vec<&'a str>,
    Vec<u8>,
    u16,
    &'a str,
    Option<&'a str>,
);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_pictures_and_requests_get_typed_errors_and_leave_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let running = daemon_keeping_pictures_in(dir.path()).await;
    let picture = disc();
    let refusals: Vec<Refused> = vec![
        (
            "name=notes",
            vec![AS_DIRECTOR],
            b"these are notes, not a picture".to_vec(),
            400,
            "bad_image",
            None,
        ),
        (
            "name=ball&vertices=5",
            vec![AS_DIRECTOR],
            picture.clone(),
            400,
            "out_of_range",
            Some("vertices"),
        ),
        (
            "name=ball&x=99999",
            vec![AS_DIRECTOR],
            picture.clone(),
            400,
            "out_of_range",
            Some("x"),
        ),
        (
            "name=ball&size=9",
            vec![AS_DIRECTOR],
            picture.clone(),
            400,
            "bad_request",
            Some("size"),
        ),
        (
            "name=../../escape",
            vec![AS_DIRECTOR],
            picture.clone(),
            400,
            "bad_request",
            Some("name"),
        ),
        (
            "name=ball",
            vec!["Authorization: Bearer secret"],
            picture.clone(),
            403,
            "forbidden",
            None,
        ),
        ("name=ball", vec![], picture.clone(), 401, "bad_token", None),
        (
            "name=ball",
            vec![AS_DIRECTOR, "Origin: http://elsewhere.example"],
            picture.clone(),
            403,
            "forbidden",
            None,
        ),
        (
            "name=ball",
            vec![AS_DIRECTOR],
            {
                let mut huge = picture.clone();
                huge.resize((16 << 20) + 1, 0);
                huge
            },
            413,
            "too_large",
            None,
        ),
        (
            "name=blank",
            vec![AS_DIRECTOR],
            png(40, 30, |_, _| [0, 0, 0, 0]),
            400,
            "bad_image",
            None,
        ),
    ];
    for (query, headers, body, status, code, field) in refusals {
        let (got, answer) = post(&running, query, &headers, &body).await;
        assert_eq!(got, status, "{query} {headers:?}: {answer}");
        assert_eq!(answer["type"], "error", "{answer}");
        assert_eq!(answer["code"], code, "{query} {headers:?}: {answer}");
        assert_eq!(answer["field"].as_str(), field, "{answer}");
        assert!(!answer["message"].as_str().unwrap().is_empty());
    }
    let kept = |dir: &std::path::Path| {
        std::fs::read_dir(dir.join("puppets"))
            .map(|d| d.count())
            .unwrap_or(0)
    };
    assert_eq!(kept(dir.path()), 0, "refused pictures leave no files");

    // A fully opaque picture is the whole rectangle: accepted, with a warning.
    let opaque = png(80, 60, |x, _| [x as u8, 90, 160, 255]);
    let (status, added) = post(&running, "name=photo&vertices=100", &[AS_DIRECTOR], &opaque).await;
    assert_eq!(status, 200, "{added}");
    let warnings = added["warnings"].as_array().unwrap();
    assert_eq!(warnings.len(), 1, "{added}");
    let warning = warnings[0].as_str().unwrap();
    assert!(
        warning.contains("opaque") && warning.contains("80×60"),
        "{warning}"
    );
    assert!(
        !warning.contains(&dir.path().display().to_string()),
        "{warning}"
    );
    // The picture, its mesh and its placement.
    assert_eq!(kept(dir.path()), 3);

    // DNS rebinding: a page on a name that resolves to the daemon sends
    // its own name as Origin and Host alike; the check goes by the
    // address the connection reached, so it is refused.
    let port = running.address.port();
    let mut request = format!(
        "POST /puppets?name=rebound HTTP/1.1\r\nHost: evil.example:{port}\r\nOrigin: http://evil.example:{port}\r\n{AS_DIRECTOR}\r\nContent-Type: image/png\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        picture.len()
    )
    .into_bytes();
    request.extend_from_slice(&picture);
    let answer = http_raw(running.address, &request).await;
    assert_eq!(http_status(&answer), 403, "a rebound page added a puppet");
    assert_eq!(kept(dir.path()), 3);
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn directors_reorder_and_remove_puppets_and_performers_cannot() {
    let dir = tempfile::tempdir().unwrap();
    let running = daemon_keeping_pictures_in(dir.path()).await;
    let (status, added) = post(
        &running,
        "name=ball&vertices=200&x=200&y=200",
        &[AS_DIRECTOR],
        &disc(),
    )
    .await;
    assert_eq!(status, 200, "{added}");
    let (mut director, stage) = connect(
        &running,
        json!({"type": "hello", "role": "director", "token": DIRECTOR}),
    )
    .await;
    assert_eq!(ids(&stage), [0, 1]);
    let (mut performer, _) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": PERFORMER}),
    )
    .await;

    send(
        &mut performer,
        json!({"type": "remove_puppet", "puppet": 1}),
    )
    .await;
    let error = until(&mut performer, "error", |_| true).await;
    assert_eq!(error["code"], "forbidden", "{error}");

    send(
        &mut director,
        json!({"type": "order_puppets", "order": [1, 0]}),
    )
    .await;
    let stage = until(&mut director, "stage", |_| true).await;
    assert_eq!(ids(&stage), [1, 0], "the ball is now below the gingerbread");
    for bad in [json!([1]), json!([1, 1]), json!([0, 1, 9])] {
        send(
            &mut director,
            json!({"type": "order_puppets", "order": bad}),
        )
        .await;
        let error = until(&mut director, "error", |_| true).await;
        assert_eq!(error["code"], "out_of_range", "{bad}: {error}");
        assert!(
            error["message"].as_str().unwrap().starts_with("order:"),
            "{error}"
        );
    }

    // A take's puppets are fixed when it starts.
    send(&mut director, json!({"type": "record", "name": "fixed"})).await;
    until(&mut director, "take", |m| m["recording"] == "fixed").await;
    send(&mut director, json!({"type": "remove_puppet", "puppet": 1})).await;
    let error = until(&mut director, "error", |_| true).await;
    assert_eq!(error["code"], "busy", "{error}");
    let (status, busy) = post(&running, "name=late", &[AS_DIRECTOR], &disc()).await;
    assert_eq!(
        (status, busy["code"].as_str()),
        (409, Some("busy")),
        "{busy}"
    );
    send(&mut director, json!({"type": "stop_recording"})).await;
    until(&mut director, "take", |m| m.get("recording").is_none()).await;

    send(&mut director, json!({"type": "remove_puppet", "puppet": 1})).await;
    let stage = until(&mut director, "stage", |_| true).await;
    assert_eq!(ids(&stage), [0]);
    until(&mut performer, "stage", |m| ids(m) == [0]).await;
    // Nothing is left of it to grab or edit: a contact where it was grabs
    // nothing, and the one after it lands on the gingerbread as usual.
    let hand = hand(&placed_mesh(&stage));
    send(
        &mut performer,
        json!({"type": "contacts", "contacts": [
            {"id": 1, "phase": "down", "x": 200.0, "y": 200.0},
            {"id": 2, "phase": "down", "x": hand.x, "y": hand.y}]}),
    )
    .await;
    loop {
        let m = next_text(&mut performer).await;
        if m["type"] == "handles" {
            assert_eq!(m["puppet"], 0, "no handle on the removed puppet: {m}");
            if contact_owners(&m).len() == 1 {
                break;
            }
        }
    }
    for message in [
        json!({"type": "remove_puppet", "puppet": 1}),
        json!({"type": "undo", "puppet": 1}),
    ] {
        send(&mut director, message.clone()).await;
        let error = until(&mut director, "error", |_| true).await;
        assert_eq!(error["code"], "not_found", "{message}: {error}");
    }
    running.shutdown().await;
}

/// A query of `POST /puppets`: known and unknown parameters with values
/// from plain to hostile (NaN, huge, negative, empty, path tricks, bytes
/// that need escaping).
fn upload_query() -> impl proptest::strategy::Strategy<Value = String> {
    use proptest::prelude::*;
    let key = prop_oneof![
        Just("name".to_string()),
        Just("vertices".to_string()),
        Just("x".to_string()),
        Just("y".to_string()),
        Just("scale".to_string()),
        "[a-z]{1,8}",
    ];
    let value = prop_oneof![
        Just("1000".to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("-1".to_string()),
        Just("1e308".to_string()),
        Just("".to_string()),
        Just("..%2F..%2Fetc".to_string()),
        Just("%00".to_string()),
        "[0-9]{1,6}",
        "[ -~]{0,80}".prop_map(|s| {
            s.bytes()
                .map(|b| {
                    if b.is_ascii_alphanumeric() {
                        (b as char).to_string()
                    } else {
                        format!("%{b:02X}")
                    }
                })
                .collect()
        }),
    ];
    proptest::collection::vec((key, value), 0..6).prop_map(|pairs| {
        pairs
            .into_iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join("&")
    })
}

#[test]
fn fuzz_upload_requests_get_an_answer_never_a_failure() {
    // Whatever a director's page (or a script with the token) posts, the
    // answer is JSON: the puppet or a typed 4xx error, never a 5xx or a cut
    // connection.
    use proptest::prelude::*;
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let running = runtime.block_on(daemon_keeping_pictures_in(dir.path()));
    let picture = disc();
    let mut config = puppetry_testkit::fuzz::config();
    // Each accepted case meshes a picture and puts a puppet on stage.
    config.cases = config.cases.min(64);
    let mut runner = proptest::test_runner::TestRunner::new(config);
    let body = prop_oneof![
        Just(picture.clone()),
        puppetry_testkit::fuzz::mutated_bytes(vec![picture.clone()]),
        proptest::collection::vec(any::<u8>(), 0..64),
    ];
    runner
        .run(&(upload_query(), body), |(query, body)| {
            let (status, answer) = runtime.block_on(post(&running, &query, &[AS_DIRECTOR], &body));
            prop_assert!(
                status == 200 || (400..500).contains(&status),
                "{query}: {status} {answer}"
            );
            let kind = if status == 200 {
                "puppet_added"
            } else {
                "error"
            };
            prop_assert_eq!(&answer["type"], kind, "{}: {}", query, answer);
            Ok(())
        })
        .unwrap();
    runtime.block_on(running.shutdown());
}

/// Each puppet's rest box on the stage: [x0, y0, x1, y1], by name.
fn boxes(stage: &Value) -> Vec<(String, [f64; 4])> {
    stage["puppets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let rest: Vec<f64> = p["rest"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
            for q in rest.chunks_exact(2) {
                b = [
                    b[0].min(q[0]),
                    b[1].min(q[1]),
                    b[2].max(q[0]),
                    b[3].max(q[1]),
                ];
            }
            (p["name"].as_str().unwrap().to_string(), b)
        })
        .collect()
}

fn overlap(a: [f64; 4], b: [f64; 4]) -> f64 {
    (a[2].min(b[2]) - a[0].max(b[0])).max(0.0) * (a[3].min(b[3]) - a[1].max(b[1])).max(0.0)
}

/// Issue 31: pictures added from the page were gone after a restart (their
/// files stayed in the puppets folder) and each new one landed on the
/// others at the centre. Now each goes where it covers no other, a restart
/// brings them back where they were (a bad file in the folder is skipped,
/// not fatal), and a removed one stays removed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn added_pictures_go_in_free_space_and_come_back_after_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let running = daemon_keeping_pictures_in(dir.path()).await;
    for name in ["ball", "moon", "sun"] {
        let query = format!("name={name}&vertices=200");
        let (status, added) = post(&running, &query, &[AS_DIRECTOR], &disc()).await;
        assert_eq!(status, 200, "{added}");
    }
    let (_viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let before = boxes(&stage);
    assert_eq!(before.len(), 4, "{before:?}");
    for (i, (a, box_a)) in before.iter().enumerate() {
        for (b, box_b) in &before[i + 1..] {
            assert_eq!(
                overlap(*box_a, *box_b),
                0.0,
                "{a} {box_a:?} covers {b} {box_b:?}"
            );
        }
    }
    running.shutdown().await;

    // What a start must survive in the folder: a picture that is not one,
    // one without its mesh, a placement that is not JSON.
    let kept = dir.path().join("puppets");
    std::fs::write(kept.join("junk.png"), b"not a picture").unwrap();
    std::fs::write(kept.join("junk.mesh.json"), b"{").unwrap();
    std::fs::write(kept.join("lonely.png"), disc()).unwrap();
    std::fs::write(kept.join("odd.png"), disc()).unwrap();
    std::fs::copy(kept.join("ball.mesh.json"), kept.join("odd.mesh.json")).unwrap();
    std::fs::write(kept.join("odd.puppet.json"), b"[1, 2").unwrap();

    let running = daemon_keeping_pictures_in(dir.path()).await;
    let (mut director, stage) = connect(
        &running,
        json!({"type": "hello", "role": "director", "token": DIRECTOR}),
    )
    .await;
    let after = boxes(&stage);
    let near = |a: [f64; 4], b: [f64; 4]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-3);
    assert_eq!(
        after.len(),
        before.len(),
        "the kept pictures, no more: {after:?}"
    );
    for ((a, box_a), (b, box_b)) in before.iter().zip(&after) {
        assert_eq!(a, b);
        assert!(
            near(*box_a, *box_b),
            "{a} was at {box_a:?}, is at {box_b:?}"
        );
    }

    // A removed puppet's files go with it.
    send(&mut director, json!({"type": "remove_puppet", "puppet": 2})).await;
    until(&mut director, "stage", |s| {
        s["puppets"].as_array().unwrap().len() == 3
    })
    .await;
    running.shutdown().await;
    let running = daemon_keeping_pictures_in(dir.path()).await;
    let (_viewer, stage) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let names: Vec<String> = boxes(&stage).into_iter().map(|(n, _)| n).collect();
    assert_eq!(names, ["gingerbread", "ball", "sun"]);
    assert!(!kept.join("moon.png").exists());
    running.shutdown().await;
}

/// Issue 45: a picture with a gap between its head and body was added with
/// a green "added", and the head floated off on its own. The answer says
/// how many pieces it has and the join that makes one; added with that
/// join it is one piece.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_picture_in_pieces_is_said_to_be_so_and_joins_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let running = daemon_keeping_pictures_in(dir.path()).await;
    let split = png(160, 160, |x, y| {
        let inside =
            |cx: f64, cy: f64, r: f64| (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy) <= r;
        // A head 5 pixels above its body.
        if inside(80.0, 105.0, 45.0) || inside(80.0, 35.0, 20.0) {
            [30, 120, 200, 255]
        } else {
            [0, 0, 0, 0]
        }
    });
    let (status, added) = post(&running, "name=split&vertices=300", &[AS_DIRECTOR], &split).await;
    assert_eq!(status, 200, "{added}");
    assert_eq!(added["pieces"], 2, "{added}");
    let join = added["join"].as_f64().unwrap();
    assert!((4.0..=8.0).contains(&join), "{added}");
    assert!(
        added["warnings"][0]
            .as_str()
            .unwrap()
            .contains("separate pieces"),
        "{added}"
    );
    let query = format!("name=joined&vertices=300&join={join}");
    let (status, joined) = post(&running, &query, &[AS_DIRECTOR], &split).await;
    assert_eq!(status, 200, "{joined}");
    assert_eq!(joined["pieces"], 1, "{joined}");
    assert_eq!(joined["warnings"].as_array().unwrap().len(), 0, "{joined}");
    assert!(joined.get("join").is_none(), "{joined}");
    // A join out of range is refused, naming it.
    let (status, refused) = post(&running, "name=far&join=-1", &[AS_DIRECTOR], &split).await;
    assert_eq!(
        (status, refused["field"].as_str()),
        (400, Some("join")),
        "{refused}"
    );
    running.shutdown().await;
}

/// One picture is added at a time (several at the size limits, meshed at
/// once, summed hundreds of MB each): while one is still arriving, a
/// second is answered 429 busy; once the first is added, the next is
/// taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_picture_while_one_is_added_is_busy() {
    use tokio::io::AsyncWriteExt;
    let dir = tempfile::tempdir().unwrap();
    let running = daemon_keeping_pictures_in(dir.path()).await;
    let picture = disc();
    // The first upload's body arrives slowly: all but its last bytes.
    let mut first = tokio::net::TcpStream::connect(running.address)
        .await
        .unwrap();
    let head = format!(
        "POST /puppets?name=first HTTP/1.1\r\nHost: {}\r\nContent-Type: image/png\r\nContent-Length: {}\r\nConnection: close\r\n{AS_DIRECTOR}\r\n\r\n",
        running.address,
        picture.len()
    );
    first.write_all(head.as_bytes()).await.unwrap();
    first
        .write_all(&picture[..picture.len() - 10])
        .await
        .unwrap();
    first.flush().await.unwrap();
    // The daemon takes the first request before the second is sent.
    let mut busy = None;
    for _ in 0..100 {
        let (status, answer) = post(&running, "name=second", &[AS_DIRECTOR], &picture).await;
        if status == 429 {
            busy = Some(answer);
            break;
        }
        assert_eq!(status, 200, "{answer}");
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    let busy = busy.expect("a second picture while the first arrives is busy");
    assert_eq!(busy["code"], "busy", "{busy}");
    // The first finishes and is added; then another is taken.
    first
        .write_all(&picture[picture.len() - 10..])
        .await
        .unwrap();
    let mut answer = Vec::new();
    tokio::io::AsyncReadExt::read_to_end(&mut first, &mut answer)
        .await
        .unwrap();
    assert_eq!(
        http_status(&answer),
        200,
        "{}",
        String::from_utf8_lossy(&answer)
    );
    let (status, answer) = post(&running, "name=third", &[AS_DIRECTOR], &picture).await;
    assert_eq!(status, 200, "{answer}");
}
