//! The relay tier on a nats-server run as the docs say: a user per party
//! and what each may publish and subscribe (`relay::nats`). A stranger
//! without credentials is refused; a relay's credentials publish only its
//! own subjects, and what a relay publishes there for another relay's
//! clients the daemon drops; a relayed performer's token is proven to the
//! daemon, a wrong one refused, and no token crosses NATS (an
//! all-powerful user reading `>` sees none).

use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

use super::{join, until};
use crate::common::daemon::*;
use crate::common::nats;
use puppetry_daemon::relay::nats::{Secret, server_config, user_entries};
use puppetry_daemon::relay::{RelayOptions, RelayRunning, serve};

const PERFORMER_TOKEN: &str = "performer-token-5a1f0c";
const DIRECTOR_TOKEN: &str = "director-token-9e27b4";
/// The all-powerful user of these tests (not in any configuration the
/// docs give): reads and may publish everything.
const MONITOR: &str = "monitor";

/// A nats-server of the test's own on a free loopback port, with a
/// configuration file; killed when dropped.
struct SecureNats {
    port: u16,
    child: Child,
    _dir: tempfile::TempDir,
}

impl SecureNats {
    /// Runs `config` (text), with `environment` set for nats-server.
    fn start(config: &str, environment: &[(&str, &str)]) -> SecureNats {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("nats-server.conf");
        std::fs::write(&file, config).unwrap();
        let port = nats::free_port();
        let child = Command::new(nats::program())
            .arg("-c")
            .arg(&file)
            .args(["-a", "127.0.0.1", "-p", &port.to_string()])
            .envs(environment.iter().copied())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("nats-server starts");
        let server = SecureNats {
            port,
            child,
            _dir: dir,
        };
        nats::wait_listening(port);
        server
    }

    /// The stage `t` with relays `a` and `b`, as `user_entries` makes it,
    /// and the monitor; passwords are each user's name backwards.
    fn for_stage_t() -> SecureNats {
        let mut entries = user_entries(
            "t",
            &Secret::Literal(password("puppetry")),
            &[
                ("a", Secret::Literal(password("a"))),
                ("b", Secret::Literal(password("b"))),
            ],
        )
        .unwrap();
        entries.push(format!(
            "{{user: \"{MONITOR}\", password: \"{}\"}}",
            password(MONITOR)
        ));
        SecureNats::start(&server_config("127.0.0.1:4222", &entries), &[])
    }

    fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    /// The address with `user`'s credentials.
    fn url_as(&self, user: &str) -> String {
        format!("nats://{user}:{}@127.0.0.1:{}", password(user), self.port)
    }
}

impl Drop for SecureNats {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn password(user: &str) -> String {
    format!("pw-{}", user.chars().rev().collect::<String>())
}

/// A NATS client of the test's, and the server's refusals it hears.
async fn client_as(
    url: &str,
    user: &str,
    password: &str,
    inbox: Option<&str>,
) -> Result<(async_nats::Client, tokio::sync::mpsc::Receiver<String>), async_nats::ConnectError> {
    let (tx, rx) = tokio::sync::mpsc::channel(64);
    let mut options =
        async_nats::ConnectOptions::with_user_and_password(user.into(), password.into())
            // A request the daemon drops is not waited for long.
            .request_timeout(Some(Duration::from_secs(2)))
            .event_callback(move |event| {
                let tx = tx.clone();
                async move {
                    if let async_nats::Event::ServerError(e) = event {
                        let _ = tx.try_send(e.to_string());
                    }
                }
            });
    if let Some(inbox) = inbox {
        options = options.custom_inbox_prefix(inbox);
    }
    let client = options.connect(url).await?;
    Ok((client, rx))
}

/// Waits for the server to refuse `what` on `subject` (a permissions
/// violation, as nats-server words it).
async fn refused(errors: &mut tokio::sync::mpsc::Receiver<String>, what: &str, subject: &str) {
    let waiting = async {
        while let Some(e) = errors.recv().await {
            let e = e.to_lowercase();
            if e.contains("permissions violation")
                && e.contains(what)
                && e.contains(&format!("\"{subject}\""))
            {
                return;
            }
        }
        panic!("the client was closed");
    };
    tokio::time::timeout(WAIT, waiting)
        .await
        .unwrap_or_else(|_| panic!("nats-server did not refuse {what} {subject}"));
}

/// The stage `t` on `nats` (as the daemon's user), with long tokens (so
/// that finding them in a frame's bytes is no accident), recording takes
/// in a folder of its own (gone with it).
async fn daemon_on(nats: &SecureNats) -> (puppetry_daemon::serve::Running, tempfile::TempDir) {
    let text = stage_text(&format!(
        "\n[relay]\nnats = \"{}\"\nstage = \"t\"\n",
        nats.url_as("puppetry")
    ))
    .replace("\"secret\"", &format!("\"{PERFORMER_TOKEN}\""))
    .replace("\"boss\"", &format!("\"{DIRECTOR_TOKEN}\""));
    let config =
        puppetry_daemon::config::ShowConfig::parse("t.toml", &text, std::path::Path::new("/"))
            .unwrap();
    let takes = tempfile::tempdir().unwrap();
    let mut options =
        puppetry_daemon::serve::Options::new(puppetry_daemon::stream::WebFiles::Embedded);
    options.takes_dir = takes.path().to_path_buf();
    let running = puppetry_daemon::serve::start_with(&config, options)
        .await
        .unwrap();
    (running, takes)
}

/// A relay named and connecting as `name`, once it serves the stage (a
/// viewer of it has the puppets) and passes messages on (it refuses them
/// until it has heard the daemon live, a moment after the stage).
async fn relay_as(nats: &SecureNats, name: &str) -> RelayRunning {
    let relay = serve::start(RelayOptions {
        nats: nats.url_as(name),
        stage: "t".into(),
        name: name.into(),
        listen: "127.0.0.1:0".parse().unwrap(),
        web_files: puppetry_daemon::stream::WebFiles::Embedded,
        max_connections: 64,
        client_timeout: Duration::from_secs(10),
    })
    .await
    .unwrap();
    let (mut viewer, stage) = join(relay.address, super::viewer()).await;
    assert_eq!(stage["type"], "stage", "{stage}");
    let list = Message::text(json!({"type": "list_takes"}).to_string());
    let live = async {
        loop {
            viewer.send(list.clone()).await.unwrap();
            let answer = loop {
                let m = next_text(&mut viewer).await;
                if m["type"] == "takes" || m["type"] == "error" {
                    break m;
                }
            };
            if answer["type"] == "takes" {
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    tokio::time::timeout(PLAYS, live)
        .await
        .expect("the relay passes messages on");
    relay
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_bundled_nats_configuration_refuses_strangers_and_holds_relays_to_their_subjects() {
    // This crate's own tree (the test kit's root may be another build's).
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/nats/nats-server.conf");
    let bundled =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let nats = SecureNats::start(
        &bundled,
        &[
            ("PUPPETRY_NATS_DAEMON_PASSWORD", "pDaemon1"),
            ("PUPPETRY_NATS_HALL_PASSWORD", "pHall2"),
        ],
    );
    let url = nats.url();

    // No credentials, or wrong ones: refused at the door.
    let anonymous = async_nats::ConnectOptions::new()
        .connect(url.as_str())
        .await;
    assert!(anonymous.is_err(), "a client without credentials got in");
    for (user, password) in [
        ("hall", "pDaemon1"),
        ("puppetry", "wrong"),
        ("nobody", "pHall2"),
    ] {
        assert!(
            client_as(&url, user, password, None).await.is_err(),
            "{user} got in with password {password}"
        );
    }

    // The daemon reads what relays ask; the relay hall may ask only as
    // itself, and may not publish the stage.
    let (daemon, _) = client_as(&url, "puppetry", "pDaemon1", None).await.unwrap();
    let mut asked = daemon.subscribe("puppetry.demo.in.>").await.unwrap();
    daemon.flush().await.unwrap();
    let (hall, mut refusals) = client_as(&url, "hall", "pHall2", Some("puppetry.demo.reply.hall"))
        .await
        .unwrap();
    let mut reading = hall.subscribe("puppetry.demo.out.>").await.unwrap();
    let forbidden = [
        "puppetry.demo.in.foyer.leave",
        "puppetry.demo.out.p.0.frame",
        "puppetry.demo.reply.foyer.x.1",
    ];
    for subject in forbidden {
        hall.publish(subject, "hall speaking for another".into())
            .await
            .unwrap();
        refused(&mut refusals, "publish", subject).await;
    }
    hall.publish("puppetry.demo.in.hall.alive", "marker".into())
        .await
        .unwrap();
    // Messages from one client arrive in order: the marker is the first
    // thing the daemon hears, so nothing refused above reached it.
    let first = tokio::time::timeout(WAIT, asked.next())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(first.subject.as_str(), "puppetry.demo.in.hall.alive");
    // Nor may hall read what other relays ask (their performers' joins).
    let mut eavesdropping = hall.subscribe("puppetry.demo.in.>").await.unwrap();
    refused(&mut refusals, "subscription", "puppetry.demo.in.>").await;
    hall.publish("puppetry.demo.in.hall.alive", "heard?".into())
        .await
        .unwrap();
    hall.flush().await.unwrap();
    daemon
        .publish("puppetry.demo.out.live", "after".into())
        .await
        .unwrap();
    let next = tokio::time::timeout(WAIT, reading.next())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(next.payload.as_ref(), b"after");
    assert!(
        futures_util::FutureExt::now_or_never(eavesdropping.next()).is_none(),
        "hall read a relay's request"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_relay_cannot_act_for_another_relays_clients() {
    let nats = SecureNats::for_stage_t();
    let (running, _takes) = daemon_on(&nats).await;
    let relay_a = relay_as(&nats, "a").await;

    // Through relay a: a director, and a performer holding the puppet.
    let hello = |role: &str, token: &str| json!({"type": "hello", "role": role, "token": token});
    let (mut director, seated) = join(relay_a.address, hello("director", DIRECTOR_TOKEN)).await;
    assert_eq!(seated["role"], "director", "{seated}");
    let director_source = seated["you"]["owner"].as_str().unwrap().to_string();
    let (mut performer, seated) = join(relay_a.address, hello("performer", PERFORMER_TOKEN)).await;
    assert_eq!(seated["role"], "performer", "{seated}");
    let performer_source = seated["you"]["owner"].as_str().unwrap().to_string();
    let (mut watcher, _) = join(running.address, super::viewer()).await;
    let grab = hand(&placed_mesh(&seated));
    let down = json!({"type": "contacts", "contacts": [{"id": 1, "phase": "down", "x": grab.x, "y": grab.y}]});
    performer
        .send(Message::text(down.to_string()))
        .await
        .unwrap();
    until_contact_owners(&mut watcher, |o| o.contains(&performer_source)).await;

    let (monitor, _) = client_as(&nats.url(), MONITOR, &password(MONITOR), None)
        .await
        .unwrap();
    let mut everything = monitor.subscribe(">").await.unwrap();
    monitor.flush().await.unwrap();
    // A rogue with relay b's credentials.
    let (rogue, mut refusals) =
        client_as(&nats.url(), "b", &password("b"), Some("puppetry.t.reply.b"))
            .await
            .unwrap();
    let take = |source: &str| {
        json!({"source": source, "session": true, "text": json!({"type": "record", "name": "rogue"}).to_string()})
            .to_string()
    };
    let leave = json!({"source": performer_source}).to_string();

    // First layer, nats-server: b may not publish as a, nor the stage.
    for (subject, payload) in [
        ("puppetry.t.in.a.msg", take(&director_source)),
        ("puppetry.t.in.a.leave", leave.clone()),
        ("puppetry.t.out.p.0.frame", "rogue frame".to_string()),
    ] {
        rogue.publish(subject, payload.into()).await.unwrap();
        refused(&mut refusals, "publish", subject).await;
    }

    // Second layer, the daemon: what b asks on its own subjects for a's
    // clients, or to be answered in a's inbox, is dropped unanswered.
    rogue
        .publish("puppetry.t.in.b.leave", leave.clone().into())
        .await
        .unwrap();
    let asked = rogue
        .request("puppetry.t.in.b.msg", take(&director_source).into())
        .await;
    assert!(
        asked.is_err(),
        "the daemon answered b acting for a's director: {:?}",
        asked.map(|m| m.payload)
    );
    let own_viewer =
        json!({"source": "relay:b:7", "session": false, "text": "{\"type\":\"list_takes\"}"});
    rogue
        .publish_with_reply(
            "puppetry.t.in.b.msg",
            "puppetry.t.reply.a.x.1",
            own_viewer.to_string().into(),
        )
        .await
        .unwrap();
    // b's own viewer, answered in b's inbox, is answered: the daemon hears b.
    let answered = rogue
        .request("puppetry.t.in.b.msg", own_viewer.to_string().into())
        .await
        .expect("the daemon answers b for b's own client");
    assert!(
        std::str::from_utf8(&answered.payload)
            .unwrap()
            .contains("answer"),
        "{:?}",
        answered.payload
    );
    rogue
        .publish("puppetry.t.in.b.marker", "marker".into())
        .await
        .unwrap();

    // Nothing b published reached a's subjects, a's inbox or the stage's.
    let seen = async {
        let mut seen = Vec::new();
        while let Some(m) = everything.next().await {
            if m.subject.as_str() == "puppetry.t.in.b.marker" {
                return seen;
            }
            let text = String::from_utf8_lossy(&m.payload).to_string();
            if text.contains("rogue") || m.subject.as_str() == "puppetry.t.reply.a.x.1" {
                seen.push((m.subject.to_string(), text));
            }
        }
        panic!("the monitor's subscription ended");
    };
    let seen = tokio::time::timeout(WAIT, seen).await.expect("the marker");
    assert!(
        seen.iter()
            .all(|(subject, _)| subject.starts_with("puppetry.t.in.b.")),
        "b's messages got past its subjects: {seen:?}"
    );

    // a's clients are as they were: the performer still has its session
    // (its paint is refused as a performer's, not as a session ended, as
    // it would be had the leave been taken); no take started.
    let paint = json!({"type": "paint", "puppet": 0, "x": 640.0, "y": 400.0, "radius": 40.0, "strength": 2.0});
    performer
        .send(Message::text(paint.to_string()))
        .await
        .unwrap();
    let refused_paint = until(&mut performer, "error", |_| true).await;
    assert_eq!(refused_paint["code"], "forbidden", "{refused_paint}");
    director
        .send(Message::text(json!({"type": "list_takes"}).to_string()))
        .await
        .unwrap();
    let takes = until(&mut director, "takes", |_| true).await;
    assert!(!takes.to_string().contains("rogue"), "{takes}");

    drop((director, performer, watcher));
    relay_a.shutdown().await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relayed_tokens_are_proven_to_the_daemon_and_never_cross_nats() {
    let nats = SecureNats::for_stage_t();
    // Everything on the server, from before the daemon starts: any
    // message carrying a token's text, and the joins that went by.
    let (monitor, _) = client_as(&nats.url(), MONITOR, &password(MONITOR), None)
        .await
        .unwrap();
    let mut everything = monitor.subscribe(">").await.unwrap();
    monitor.flush().await.unwrap();
    let joins = Arc::new(AtomicUsize::new(0));
    let (leaks_tx, mut leaks) = tokio::sync::mpsc::channel::<String>(16);
    let (marker_tx, mut marker) = tokio::sync::mpsc::channel::<()>(1);
    let watching = {
        let joins = joins.clone();
        tokio::spawn(async move {
            while let Some(m) = everything.next().await {
                let subject = m.subject.as_str();
                if subject == "puppetry.t.in.a.join" {
                    joins.fetch_add(1, Ordering::Relaxed);
                }
                if subject == "test.marker" {
                    let _ = marker_tx.send(()).await;
                }
                for token in [PERFORMER_TOKEN, DIRECTOR_TOKEN] {
                    let bytes = token.as_bytes();
                    if m.payload.windows(bytes.len()).any(|w| w == bytes) {
                        let _ = leaks_tx.try_send(format!(
                            "{subject}: {}",
                            String::from_utf8_lossy(&m.payload)
                        ));
                    }
                }
            }
        })
    };
    let (running, _takes) = daemon_on(&nats).await;
    let relay_a = relay_as(&nats, "a").await;

    // A wrong token is refused as on the daemon; the right ones let in.
    let hello = |role: &str, token: &str| json!({"type": "hello", "role": role, "token": token});
    let wrong = format!("{PERFORMER_TOKEN}x");
    let (mut refused_ws, refused) = join(relay_a.address, hello("performer", &wrong)).await;
    assert_eq!(refused["code"], "bad_token", "{refused}");
    let closed = loop {
        if let Message::Close(frame) = next_message(&mut refused_ws).await {
            break frame.map(|f| u16::from(f.code));
        }
    };
    assert_eq!(closed, Some(4001));
    let (_performer, seated) = join(relay_a.address, hello("performer", PERFORMER_TOKEN)).await;
    assert_eq!(seated["role"], "performer", "{seated}");
    let (_director, seated) = join(relay_a.address, hello("director", DIRECTOR_TOKEN)).await;
    assert_eq!(seated["role"], "director", "{seated}");
    assert_eq!(seated["you"]["name"], "Director", "{seated}");

    // Everything the joins sent is in the monitor's hands once its own
    // marker comes back after them.
    monitor.publish("test.marker", "".into()).await.unwrap();
    tokio::time::timeout(WAIT, marker.recv())
        .await
        .expect("the marker in time");
    assert!(
        joins.load(Ordering::Relaxed) >= 3,
        "the monitor saw {} joins",
        joins.load(Ordering::Relaxed)
    );
    if let Ok(leak) = leaks.try_recv() {
        panic!("a token crossed NATS: {leak}");
    }
    watching.abort();
    relay_a.shutdown().await;
    running.shutdown().await;
}
