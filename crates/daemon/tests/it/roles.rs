//! Identity and roles over the wire (issue 12, observations 2, 3 and 5):
//! performers get distinct palette colours in `you` and `people`; a wrong
//! token is refused with `bad_token` and close 4001, not dropped; the
//! right token opens, near misses do not; a performer cannot paint, save
//! or record and a director can; a performer limited to one puppet grabs
//! nothing on another; a page from a foreign origin cannot open the
//! WebSocket at all.

use crate::common::daemon::*;

use futures_util::SinkExt;
use glam::DVec2;
use puppetry_daemon::serve::{Options, Running, start_with};
use puppetry_daemon::stream::WebFiles;
use puppetry_testkit::stage_text::Gingerbread;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

/// The Okabe–Ito palette the daemon hands out.
const PALETTE: [&str; 7] = [
    "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7",
];

async fn send(ws: &mut Client, m: Value) {
    ws.send(Message::text(m.to_string())).await.unwrap();
}

/// Reads until a text message of `kind` satisfying `done`.
async fn until(ws: &mut Client, kind: &str, done: impl Fn(&Value) -> bool) -> Value {
    loop {
        let m = next_text(ws).await;
        if m["type"] == kind && done(&m) {
            return m;
        }
    }
}

/// Reads until the server's close frame: its code and reason.
pub async fn until_close(ws: &mut Client) -> (u16, String) {
    loop {
        if let Message::Close(frame) = next_message(ws).await {
            let frame = frame.expect("a close frame with a code and reason");
            return (u16::from(frame.code), frame.reason.to_string());
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn performers_get_distinct_palette_colours_in_you_and_people() {
    let running = daemon("").await;
    let mut clients = Vec::new();
    let mut yous = Vec::new();
    for _ in 0..4 {
        let hello = json!({"type": "hello", "role": "performer", "token": "secret"});
        let (ws, stage) = connect(&running, hello).await;
        yous.push(stage["you"].clone());
        clients.push(ws);
    }
    let (mut director, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "boss"}),
    )
    .await;
    assert_eq!(stage["role"], "director", "the person's role decides");
    yous.push(stage["you"].clone());
    let colours: Vec<&str> = yous.iter().map(|y| y["colour"].as_str().unwrap()).collect();
    assert!(colours.iter().all(|c| PALETTE.contains(c)), "{colours:?}");
    let mut distinct = colours.clone();
    distinct.sort();
    distinct.dedup();
    assert_eq!(
        distinct.len(),
        5,
        "every performer a colour of their own: {colours:?}"
    );
    assert_eq!(yous[0]["name"], "performer 1");
    assert_eq!(yous[3]["name"], "performer 4");
    assert_eq!(yous[4]["name"], "Director");
    // Everyone's `people` list says the same, owner by owner.
    let people = until(&mut director, "people", |m| {
        m["people"].as_array().unwrap().len() == 5
    })
    .await;
    for you in &yous {
        assert!(
            people["people"].as_array().unwrap().contains(you),
            "{you} in {people}"
        );
    }
    // One leaves: the list shrinks for the others.
    drop(clients.remove(0));
    until(&mut director, "people", |m| {
        m["people"].as_array().unwrap().len() == 4
    })
    .await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_token_is_refused_with_bad_token_and_close_4001() {
    let running = daemon("").await;
    for token in [
        json!("nope"),
        json!("secre"),
        json!("secret "),
        json!("bos"),
    ] {
        let hello = json!({"type": "hello", "role": "performer", "token": token});
        let (mut ws, refused) = connect(&running, hello).await;
        assert_eq!(refused["type"], "error", "{token}: {refused}");
        assert_eq!(refused["code"], "bad_token", "{refused}");
        assert_eq!(
            until_close(&mut ws).await,
            (4001, "token refused".to_string())
        );
    }
    // No token at all, as a director: the same.
    let (mut ws, refused) = connect(&running, json!({"type": "hello", "role": "director"})).await;
    assert_eq!(refused["code"], "bad_token");
    assert_eq!(until_close(&mut ws).await.0, 4001);
    // The right tokens open; a viewer with a performer's token stays one.
    let (_, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    assert_eq!(
        (stage["type"].as_str(), stage["role"].as_str()),
        (Some("stage"), Some("performer"))
    );
    let (_, stage) = connect(
        &running,
        json!({"type": "hello", "role": "viewer", "token": "boss"}),
    )
    .await;
    assert_eq!(stage["role"], "viewer");
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_performer_cannot_paint_save_or_record_and_a_director_can() {
    let takes = tempfile::tempdir().unwrap();
    let mut options = Options::new(WebFiles::Embedded);
    options.takes_dir = takes.path().to_path_buf();
    let running = start_with(&stage_config(""), options).await.unwrap();
    let (mut performer, _) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "secret"}),
    )
    .await;
    let paint = json!({"type": "paint", "puppet": 0, "x": 640.0, "y": 400.0, "radius": 40.0, "strength": 2.0});
    for (message, kind) in [
        (paint.clone(), "paint"),
        (json!({"type": "save_weights", "puppet": 0}), "save_weights"),
        (json!({"type": "record"}), "record"),
        (
            json!({"type": "key_add", "puppet": 0, "at": [0.5, 0.5]}),
            "key_add",
        ),
        (json!({"type": "play", "take": "take-001"}), "play"),
    ] {
        send(&mut performer, message).await;
        let refused = until(&mut performer, "error", |_| true).await;
        assert_eq!(refused["code"], "forbidden", "{refused}");
        assert!(
            refused["message"].as_str().unwrap().contains(kind),
            "{refused}"
        );
    }
    // A viewer may not even touch.
    let (mut viewer, _) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    send(&mut viewer, json!({"type": "pin", "x": 640.0, "y": 400.0})).await;
    assert_eq!(
        until(&mut viewer, "error", |_| true).await["code"],
        "forbidden"
    );
    // The director paints (everyone gets the weights) and records.
    let (mut director, _) = connect(
        &running,
        json!({"type": "hello", "role": "director", "token": "boss"}),
    )
    .await;
    send(&mut director, paint).await;
    until(&mut viewer, "weights", |_| true).await;
    send(&mut director, json!({"type": "record"})).await;
    until(&mut viewer, "take", |m| m["recording"] == "take-001").await;
    send(&mut director, json!({"type": "stop_recording"})).await;
    until(&mut viewer, "take", |m| m.get("recording").is_none()).await;
    running.shutdown().await;
}

/// Two gingerbread puppets side by side; Ana plays only the left one.
fn two_puppets() -> String {
    format!(
        r#"
[stage]
width = 1280
height = 720
listen = "127.0.0.1:0"

[access]
[[access.person]]
name = "Ana"
role = "performer"
token = "ana"
puppets = ["left"]

{left}
{right}"#,
        left = Gingerbread::new("left").at(320.0, 360.0).scale(0.8),
        right = Gingerbread::new("right").at(960.0, 360.0).scale(0.8),
    )
}

/// A point on puppet `i` of a stage message (its first vertex's triangle's
/// centroid: inside the mesh).
fn on_puppet(stage: &Value, i: usize) -> DVec2 {
    let p = &stage["puppets"][i];
    let rest: Vec<f64> = serde_json::from_value(p["rest"].clone()).unwrap();
    let triangles: Vec<usize> = serde_json::from_value(p["triangles"].clone()).unwrap();
    let corner = |k: usize| DVec2::new(rest[2 * triangles[k]], rest[2 * triangles[k] + 1]);
    (corner(0) + corner(1) + corner(2)) / 3.0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_performer_limited_to_a_puppet_grabs_nothing_on_another() {
    let config = puppetry_daemon::config::ShowConfig::parse(
        "two.toml",
        &two_puppets(),
        std::path::Path::new("/"),
    )
    .unwrap();
    let running: Running = start_with(&config, Options::new(WebFiles::Embedded))
        .await
        .unwrap();
    let (mut ana, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "ana"}),
    )
    .await;
    let owner = stage["you"]["owner"].as_str().unwrap().to_string();
    let (left, right) = (on_puppet(&stage, 0), on_puppet(&stage, 1));
    // Messages naming the other puppet are refused, naming the field.
    for message in [
        json!({"type": "cursor", "puppet": 1, "at": [0.5, 0.5]}),
        json!({"type": "unpin", "puppet": 1, "handle": 0}),
        json!({"type": "pose", "puppet": 1, "from": "rest", "to": "rest", "t": 0.0}),
    ] {
        send(&mut ana, message.clone()).await;
        let refused = until(&mut ana, "error", |_| true).await;
        assert_eq!(refused["code"], "forbidden", "{message}: {refused}");
        assert_eq!(refused["field"], "puppet");
    }
    // A touch and a pin on the right puppet, then a touch on the left.
    send(&mut ana, json!({"type": "pin", "x": right.x, "y": right.y})).await;
    send(
        &mut ana,
        json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": right.x, "y": right.y}]}),
    )
    .await;
    send(
        &mut ana,
        json!({"type": "contacts", "contacts": [{"id": 2, "phase": "down", "x": left.x, "y": left.y}]}),
    )
    .await;
    until(&mut ana, "handles", |m| {
        m["puppet"] == 0 && contact_owners(m).contains(&owner)
    })
    .await;
    // Everything before the left grab has been applied and published: a
    // newcomer sees the left puppet held and the right one untouched.
    let (_, seen) = connect(&running, json!({"type": "hello", "role": "viewer"})).await;
    let owners = |i: usize| -> Vec<String> {
        seen["puppets"][i]["handles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| h["owner"].as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(owners(0), [owner]);
    assert!(owners(1).is_empty(), "{:?}", owners(1));
    running.shutdown().await;
}

/// Opens the WebSocket with an `Origin` header; the HTTP status refusing
/// it, or `None` when it opened.
async fn open_with_origin(running: &Running, origin: &str) -> Option<u16> {
    let mut request = format!("ws://{}/ws", running.address)
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("Origin", origin.parse().unwrap());
    match tokio_tungstenite::connect_async(request).await {
        Ok(_) => None,
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            Some(response.status().as_u16())
        }
        Err(e) => panic!("{origin}: {e}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_from_a_foreign_origin_cannot_open_the_websocket() {
    let running = daemon("").await;
    assert_eq!(
        open_with_origin(&running, "https://evil.example").await,
        Some(403)
    );
    assert_eq!(open_with_origin(&running, "null").await, Some(403));
    // The daemon's own page may.
    let own = format!("http://{}", running.address);
    assert_eq!(open_with_origin(&running, &own).await, None);
    running.shutdown().await;
    // And an origin the stage file lists.
    let mut config = stage_config("");
    config.access.allowed_origins = vec!["https://show.example".into()];
    let running = puppetry_daemon::serve::start(&config, WebFiles::Embedded, None)
        .await
        .unwrap();
    assert_eq!(
        open_with_origin(&running, "https://show.example").await,
        None
    );
    assert_eq!(
        open_with_origin(&running, "https://evil.example").await,
        Some(403)
    );
    running.shutdown().await;
}
