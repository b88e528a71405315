//! `puppetry soak`: the daemon (and, with `--relay`, a NATS server and a
//! relay) run for a set time on loopback under the churn a show puts it
//! through, to show that nothing leaks. The bundled recorded drag loops on
//! the stage, and a real device capture with it when one is given; performers join, drag and leave; viewers connect, read,
//! stall past the client timeout and drop; malformed messages are mixed
//! in; takes are recorded, exported (glb) and deleted; a director adds a
//! curve puppet and takes it off again (a new lineup each time); viewers
//! fetch the puppets' pictures, through the relay too. Every interval it
//! prints each process's resident memory and open descriptors, and the
//! frames a second and p99 latency a reference viewer saw; at the end it
//! fits a line through what came after the warm-up and says whether
//! memory and descriptors stayed flat. Its NATS server runs as
//! docs/scaling.md says to run one: a user for the daemon and one for the
//! relay, fresh passwords, each held to its own subjects.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use glam::DVec2;
use serde_json::json;
use tokio::sync::watch;
use tokio_tungstenite::tungstenite::Message;

use crate::viewers_bench::{
    Child, Tier, ViewersError, connect, connect_staged, cpu_seconds, daemon_clock_origin,
    percentile, rss_mb, spawn_serving, this_program,
};
use puppetry_daemon::protocol::{FrameHeader, FrameKind};

/// How a soak runs.
#[derive(Debug, Clone)]
pub struct SoakOptions {
    /// How long the soak runs, warm-up included (`--minutes`).
    pub duration: Duration,
    /// How often a row is printed.
    pub every: Duration,
    /// Viewers connected at once, each churning.
    pub viewers: usize,
    /// Through a relay too (needs nats-server): the churning clients pick
    /// the daemon or the relay at random, and the reference viewer watches
    /// from the relay.
    pub relay: bool,
    /// A capture (evemu `.event`) or recording (`.jsonl`) looped on the
    /// stage besides the bundled recorded drag; `None`: the drag alone.
    pub capture: Option<std::path::PathBuf>,
}

/// Messages a careless or hostile client sends.
const MALFORMED: &[&str] = &[
    "not json",
    "{}",
    r#"{"type":"contacts"}"#,
    r#"{"type":"contacts","contacts":[{"id":1,"phase":"down","x":1e308,"y":0}]}"#,
    r#"{"type":"contacts","contacts":[{"id":1,"phase":"sideways","x":1,"y":2}]}"#,
    r#"{"type":"paint","puppet":99,"x":1,"y":1,"radius":1,"strength":1}"#,
    r#"{"type":"hello","role":"director"}"#,
    r#"{"type":"pin","x":"a","y":2}"#,
    "[1,2,3]",
    r#"{"type":"ping","t":"now"}"#,
];

/// Counts the churn, for the rows.
#[derive(Default)]
struct Counts {
    viewer_connects: AtomicU64,
    stalls: AtomicU64,
    performer_sessions: AtomicU64,
    bad_messages: AtomicU64,
    takes_exported: AtomicU64,
    lineups: AtomicU64,
    pictures: AtomicU64,
    failures: AtomicU64,
}

/// What the reference viewer saw since the last row.
#[derive(Default)]
struct Seen {
    frames: u64,
    latencies_us: Vec<f64>,
}

/// One printed row.
#[derive(Debug, Clone, serde::Serialize)]
struct SoakRow {
    minute: f64,
    daemon_rss_mb: f64,
    daemon_fds: usize,
    daemon_cpu: f64,
    relay_rss_mb: f64,
    relay_fds: usize,
    nats_rss_mb: f64,
    frames_per_s: f64,
    latency_ms_p99: f64,
    viewer_connects: u64,
    stalls: u64,
    performer_sessions: u64,
    bad_messages: u64,
    takes_exported: u64,
    lineups: u64,
    pictures: u64,
    failures: u64,
}

fn fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd")).map_or(0, |d| d.count())
}

/// A small deterministic random source (the churn need not be secret).
struct Dice(u64);

impl Dice {
    fn roll(&mut self, below: u64) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0 % below.max(1)
    }
}

/// Runs the soak, printing a header, a row every `options.every` and at
/// the end a verdict; returns whether memory and descriptors stayed flat
/// after the warm-up (`puppetry soak` exits with 1 when not).
pub async fn soak(options: SoakOptions, print: impl Fn(&str)) -> Result<bool, ViewersError> {
    let wave = puppetry_daemon::bundled::root()?.join("config/wave.toml");
    let text = std::fs::read_to_string(&wave).map_err(|e| ViewersError::Io {
        what: wave.display().to_string(),
        source: e,
    })?;
    let pid = std::process::id();
    let takes = std::env::temp_dir().join(format!("puppetry-soak-takes-{pid}"));
    let _ = std::fs::create_dir_all(&takes);
    let (extra, mut tier) = extra_sections(&options)?;
    let stage_file = wave.with_file_name(format!("soak-{pid}.toml"));
    let text = text.replace(
        "[access]\n",
        &format!("[access]\nmax_per_address = {}\n", options.viewers + 64),
    ) + &extra;
    std::fs::write(&stage_file, text).map_err(|e| ViewersError::Io {
        what: stage_file.display().to_string(),
        source: e,
    })?;
    let mut serve = std::process::Command::new(this_program()?);
    serve
        .args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(&stage_file)
        .arg("--takes")
        .arg(&takes);
    let started = spawn_serving(serve, "puppetry serve");
    let _ = std::fs::remove_file(&stage_file);
    let (daemon_child, daemon) = started?;
    let daemon_child = Child(daemon_child);
    let daemon_pid = daemon_child.0.id();
    if let Some(tier) = &mut tier {
        tier.start_relays(options.viewers + 16)?;
    }
    let relay = tier.as_ref().map(|t| t.relays[0].1.clone());
    let relay_pid = tier.as_ref().map(|t| t.relays[0].0.0.id());
    let nats_pid = tier.as_ref().map(|t| t.nats.0.id());
    // Edges the clients use: the daemon, and the relay too when there is one.
    let edges: Arc<Vec<String>> = Arc::new(
        [Some(daemon.clone()), relay.clone()]
            .into_iter()
            .flatten()
            .collect(),
    );

    let (stop_tx, stop) = watch::channel(false);
    let counts = Arc::new(Counts::default());
    let seen = Arc::new(std::sync::Mutex::new(Seen::default()));
    let crew = Crew {
        edges,
        daemon: daemon.clone(),
        counts: counts.clone(),
        seen: seen.clone(),
        stop,
    };
    let far_end = relay.clone().unwrap_or_else(|| daemon.clone());
    let tasks = start_tasks(&crew, &options, far_end, &takes);

    print(&table_header());
    let start = Instant::now();
    let mut rows = Vec::new();
    let mut cpu_before = cpu_seconds(daemon_pid);
    let mut last = Instant::now();
    while start.elapsed() < options.duration {
        tokio::time::sleep(options.every.min(options.duration - start.elapsed())).await;
        let taken = std::mem::take(&mut *seen.lock().unwrap_or_else(|p| p.into_inner()));
        let mut latencies = taken.latencies_us;
        latencies.sort_by(f64::total_cmp);
        let span = last.elapsed().as_secs_f64();
        last = Instant::now();
        let cpu = cpu_seconds(daemon_pid);
        let row = SoakRow {
            minute: start.elapsed().as_secs_f64() / 60.0,
            daemon_rss_mb: rss_mb(daemon_pid),
            daemon_fds: fds(daemon_pid),
            daemon_cpu: (cpu - cpu_before) / span,
            relay_rss_mb: relay_pid.map_or(0.0, rss_mb),
            relay_fds: relay_pid.map_or(0, fds),
            nats_rss_mb: nats_pid.map_or(0.0, rss_mb),
            frames_per_s: taken.frames as f64 / span,
            latency_ms_p99: percentile(&latencies, 0.99) / 1000.0,
            viewer_connects: counts.viewer_connects.load(Ordering::Relaxed),
            stalls: counts.stalls.load(Ordering::Relaxed),
            performer_sessions: counts.performer_sessions.load(Ordering::Relaxed),
            bad_messages: counts.bad_messages.load(Ordering::Relaxed),
            takes_exported: counts.takes_exported.load(Ordering::Relaxed),
            lineups: counts.lineups.load(Ordering::Relaxed),
            pictures: counts.pictures.load(Ordering::Relaxed),
            failures: counts.failures.load(Ordering::Relaxed),
        };
        cpu_before = cpu;
        print(&table_row(&row));
        rows.push(row);
    }
    let _ = stop_tx.send(true);
    for task in &tasks {
        task.abort();
    }
    drop(tier);
    drop(daemon_child);
    let _ = std::fs::remove_dir_all(&takes);
    let (flat, verdict) = judge(&rows, options.viewers);
    print(&verdict);
    Ok(flat)
}

/// The stage file's sections the options add: a looped capture, and the
/// relay tier (started here: its nats-server and credentials).
fn extra_sections(options: &SoakOptions) -> Result<(String, Option<Tier>), ViewersError> {
    let mut extra = String::new();
    if let Some(capture) = &options.capture {
        let capture = std::path::absolute(capture).map_err(|e| ViewersError::Io {
            what: capture.display().to_string(),
            source: e,
        })?;
        // Its contacts' own range over the stage (a capture knows its axes).
        extra += &format!(
            "\n[[input]]\nkind = \"replay\"\nname = \"capture\"\nfile = {:?}\nrepeat = true\n",
            capture.display().to_string()
        );
    }
    let mut tier = None;
    if options.relay {
        let nats = Tier::start("soak", 1)?;
        extra += &nats.relay_section();
        tier = Some(nats);
    }
    Ok((extra, tier))
}

/// Every task of the soak, started: the reference viewer at `far_end`,
/// churning viewers, performers, a malformed client, takes exported and
/// lineup changes.
fn start_tasks(
    crew: &Crew,
    options: &SoakOptions,
    far_end: String,
    takes: &std::path::Path,
) -> Vec<tokio::task::JoinHandle<()>> {
    let mut tasks = vec![reference_viewer(crew.clone(), far_end)];
    // Viewers churning.
    for slot in 0..options.viewers {
        tasks.push(churning_viewer(crew.clone(), slot));
    }
    // Performers joining, dragging and leaving (on either edge).
    for performer in 0..2u64 {
        tasks.push(performing(crew.clone(), performer));
    }
    // Malformed messages, from a client that is dropped for them.
    tasks.push(malformed_messages(crew.clone()));
    // Takes: recorded for a few seconds, exported, deleted.
    tasks.push(takes_exported(
        crew.clone(),
        takes.to_path_buf(),
        (options.duration / 6).clamp(Duration::from_secs(20), Duration::from_secs(300)),
    ));
    // A curve puppet added and taken off again: a new lineup each time.
    tasks.push(lineup_changes(
        crew.clone(),
        (options.duration / 30).clamp(Duration::from_secs(5), Duration::from_secs(60)),
    ));
    tasks
}

/// What every task of a soak shares: the edges to connect to, the daemon,
/// the counters and the reference viewer's frames, and the stop signal.
#[derive(Clone)]
struct Crew {
    edges: Arc<Vec<String>>,
    daemon: String,
    counts: Arc<Counts>,
    seen: Arc<std::sync::Mutex<Seen>>,
    stop: watch::Receiver<bool>,
}

impl Crew {
    /// The soak goes on.
    fn running(&self) -> bool {
        !*self.stop.borrow()
    }

    /// An edge picked by `dice`.
    fn edge(&self, dice: &mut Dice) -> &str {
        &self.edges[dice.roll(self.edges.len() as u64) as usize]
    }

    /// Counts a connection that failed, and waits a second before the
    /// next try.
    async fn failed_to_connect(&self) {
        self.counts.failures.fetch_add(1, Ordering::Relaxed);
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
}

/// The reference viewer: at the far end (the relay, when there is one).
fn reference_viewer(mut crew: Crew, edge: String) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        while crew.running() {
            let origin = Instant::now();
            let Ok((mut ws, _)) =
                connect_staged(&edge, json!({"type": "hello", "role": "viewer"})).await
            else {
                crew.failed_to_connect().await;
                continue;
            };
            let Ok(zero) = daemon_clock_origin(&mut ws, origin).await else {
                crew.counts.failures.fetch_add(1, Ordering::Relaxed);
                continue;
            };
            loop {
                tokio::select! {
                    _ = crew.stop.changed() => return,
                    m = ws.next() => match m {
                        Some(Ok(Message::Binary(bytes))) => {
                            if let Ok(h) = FrameHeader::decode(&bytes)
                                && h.kind == FrameKind::Vertices
                            {
                                let now = origin.elapsed().as_secs_f64();
                                let mut seen = crew.seen.lock().unwrap_or_else(|p| p.into_inner());
                                seen.frames += 1;
                                if h.input_time > 0.0 {
                                    seen.latencies_us.push((now - (zero + h.input_time)) * 1e6);
                                }
                            }
                        }
                        Some(Ok(_)) => {}
                        _ => {
                            crew.counts.failures.fetch_add(1, Ordering::Relaxed);
                            break;
                        }
                    },
                }
            }
        }
    })
}

/// Viewers churning.
fn churning_viewer(crew: Crew, slot: usize) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut dice = Dice(0x9E37_79B9_7F4A_7C15 ^ (slot as u64 + 1));
        while crew.running() {
            let edge = crew.edge(&mut dice);
            let Ok((mut ws, _)) = connect(edge, json!({"type": "hello", "role": "viewer"})).await
            else {
                crew.failed_to_connect().await;
                continue;
            };
            crew.counts.viewer_connects.fetch_add(1, Ordering::Relaxed);
            match dice.roll(5) {
                // Stalls: stops reading past the client timeout (the
                // stage's 10 s), then goes without a word.
                0 => {
                    crew.counts.stalls.fetch_add(1, Ordering::Relaxed);
                    tokio::time::sleep(Duration::from_secs(12)).await;
                    drop(ws);
                }
                // Reads a while, then drops the connection unclosed.
                1 => {
                    read_for(&mut ws, Duration::from_millis(500 + 100 * dice.roll(20))).await;
                    drop(ws);
                }
                // Fetches the picture as a page does, reads a while,
                // then closes properly.
                2 => {
                    let picture = http(edge, b"GET /puppets/0/texture.png HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").await;
                    match picture {
                        Ok(answer) if answer.starts_with(b"HTTP/1.1 200") => {
                            crew.counts.pictures.fetch_add(1, Ordering::Relaxed);
                        }
                        _ => {
                            crew.counts.failures.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    read_for(&mut ws, Duration::from_secs(2 + dice.roll(8))).await;
                    let _ = ws.close(None).await;
                }
                // Reads a while, then closes properly.
                _ => {
                    read_for(&mut ws, Duration::from_secs(2 + dice.roll(8))).await;
                    let _ = ws.close(None).await;
                }
            }
        }
    })
}

/// Performers joining, dragging and leaving (on either edge).
fn performing(crew: Crew, performer: u64) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut dice = Dice(0xD1B5_4A32_D192_ED03 ^ (performer + 7));
        while crew.running() {
            let edge = crew.edge(&mut dice);
            let hello = json!({"type": "hello", "role": "performer", "token": "demo"});
            let Ok((ws, stage)) = connect_staged(edge, hello).await else {
                crew.failed_to_connect().await;
                continue;
            };
            crew.counts
                .performer_sessions
                .fetch_add(1, Ordering::Relaxed);
            let rest: Vec<f64> =
                serde_json::from_value(stage["puppets"][0]["rest"].clone()).unwrap_or_default();
            let at = rest
                .get(2 * (dice.roll((rest.len() / 2) as u64) as usize)..)
                .and_then(|p| Some(DVec2::new(*p.first()?, *p.get(1)?)))
                .unwrap_or(DVec2::new(640.0, 360.0));
            let (mut sink, mut stream) = ws.split();
            let drag = async {
                let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / 60.0));
                for k in 0..180 {
                    tick.tick().await;
                    let phase = if k == 0 { "down" } else { "move" };
                    let p = at + DVec2::new((k as f64 * 0.1).sin(), (k as f64 * 0.07).cos()) * 20.0;
                    let m = json!({"type": "contacts", "contacts": [{"id": performer + 1, "phase": phase, "x": p.x, "y": p.y}]});
                    sink.send(Message::text(m.to_string())).await?;
                }
                let up =
                    json!({"type": "contacts", "contacts": [{"id": performer + 1, "phase": "up"}]});
                sink.send(Message::text(up.to_string())).await?;
                // Some leave cleanly, some just go.
                if dice.roll(2) == 0 {
                    sink.close().await?;
                }
                Ok::<_, tokio_tungstenite::tungstenite::Error>(())
            };
            let reading = async { while let Some(Ok(_)) = stream.next().await {} };
            tokio::select! {
                done = drag => if done.is_err() { crew.counts.failures.fetch_add(1, Ordering::Relaxed); },
                _ = reading => {}
            }
            tokio::time::sleep(Duration::from_millis(500 + 100 * dice.roll(10))).await;
        }
    })
}

/// Malformed messages, from a client that is dropped for them.
fn malformed_messages(crew: Crew) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut dice = Dice(0xA076_1D64_78BD_642F);
        while crew.running() {
            let edge = crew.edge(&mut dice);
            let hello = json!({"type": "hello", "role": "performer", "token": "demo"});
            let Ok((mut ws, _)) = connect(edge, hello).await else {
                tokio::time::sleep(Duration::from_secs(1)).await;
                continue;
            };
            for _ in 0..25 {
                let bad = MALFORMED[dice.roll(MALFORMED.len() as u64) as usize];
                if ws.send(Message::text(bad)).await.is_err() {
                    break;
                }
                crew.counts.bad_messages.fetch_add(1, Ordering::Relaxed);
                read_for(&mut ws, Duration::from_millis(100)).await;
            }
            drop(ws);
        }
    })
}

/// Takes: recorded for a few seconds, exported, deleted.
fn takes_exported(
    crew: Crew,
    takes: std::path::PathBuf,
    every: Duration,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut n = 0;
        while crew.running() {
            tokio::time::sleep(every).await;
            n += 1;
            let name = format!("soak-{n}");
            if take_and_export(&crew.daemon, &name).await.is_ok() {
                crew.counts.takes_exported.fetch_add(1, Ordering::Relaxed);
            } else {
                crew.counts.failures.fetch_add(1, Ordering::Relaxed);
            }
            let _ = std::fs::remove_file(takes.join(format!("{name}.take")));
        }
    })
}

/// A curve puppet added and taken off again: a new lineup each time.
fn lineup_changes(crew: Crew, every: Duration) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        while crew.running() {
            tokio::time::sleep(every).await;
            match add_and_remove_a_curve(&crew.daemon).await {
                Ok(true) => crew.counts.lineups.fetch_add(2, Ordering::Relaxed),
                Ok(false) => 0,
                Err(_) => crew.counts.failures.fetch_add(1, Ordering::Relaxed),
            };
        }
    })
}

/// Reads (and drops) what comes for `span`.
async fn read_for(ws: &mut crate::viewers_bench::Ws, span: Duration) {
    let _ = tokio::time::timeout(span, async { while let Some(Ok(_)) = ws.next().await {} }).await;
}

/// A director records `name` for a few seconds, then the daemon exports
/// it as glb over HTTP (the director's token in the header: exports are
/// the director's).
async fn take_and_export(daemon: &str, name: &str) -> Result<(), ViewersError> {
    let hello = json!({"type": "hello", "role": "director", "token": "director"});
    let (mut ws, _) = connect(daemon, hello).await?;
    ws.send(Message::text(
        json!({"type": "record", "name": name}).to_string(),
    ))
    .await?;
    read_for(&mut ws, Duration::from_secs(5)).await;
    ws.send(Message::text(json!({"type": "stop_recording"}).to_string()))
        .await?;
    read_for(&mut ws, Duration::from_millis(500)).await;
    let _ = ws.close(None).await;
    let request = format!(
        "GET /takes/{name}/export?format=glb HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer director\r\nConnection: close\r\n\r\n"
    );
    let answer = http(daemon, request.as_bytes()).await?;
    if answer.starts_with(b"HTTP/1.1 200") {
        Ok(())
    } else {
        Err(ViewersError::Daemon(format!(
            "export of {name}: {}",
            String::from_utf8_lossy(&answer[..answer.len().min(900)])
        )))
    }
}

/// A director adds a rope, waits for it, and takes it off the stage;
/// `false` if it was refused because a take is recording.
async fn add_and_remove_a_curve(daemon: &str) -> Result<bool, ViewersError> {
    let hello = json!({"type": "hello", "role": "director", "token": "director"});
    let (mut ws, _) = connect(daemon, hello).await?;
    let points: Vec<[f64; 2]> = (0..40).map(|k| [100.0 + 5.0 * k as f64, 600.0]).collect();
    let add = json!({"type": "add_curve", "name": "soak rope", "points": points, "width": 6.0, "colour": "#336699"});
    ws.send(Message::text(add.to_string())).await?;
    let added = tokio::time::timeout(Duration::from_secs(20), async {
        while let Some(Ok(m)) = ws.next().await {
            if let Message::Text(text) = m {
                let m: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
                if m["type"] == "puppet_added" || m["type"] == "error" {
                    return m;
                }
            }
        }
        serde_json::Value::Null
    })
    .await
    .unwrap_or_default();
    // While a take records the line-up is fixed (refused `busy`, as
    // designed): not a failure, nothing changed.
    if added["code"] == "busy" {
        return Ok(false);
    }
    let Some(puppet) = added["puppet"].as_u64() else {
        return Err(ViewersError::Daemon(format!("add_curve: {added}")));
    };
    read_for(&mut ws, Duration::from_secs(2)).await;
    ws.send(Message::text(
        json!({"type": "remove_puppet", "puppet": puppet}).to_string(),
    ))
    .await?;
    read_for(&mut ws, Duration::from_millis(500)).await;
    let _ = ws.close(None).await;
    Ok(true)
}

async fn http(address: &str, request: &[u8]) -> Result<Vec<u8>, ViewersError> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let failed = |source| ViewersError::Io {
        what: format!("HTTP to {address}"),
        source,
    };
    let mut stream = tokio::net::TcpStream::connect(address)
        .await
        .map_err(failed)?;
    stream.write_all(request).await.map_err(failed)?;
    let mut answer = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(120), stream.read_to_end(&mut answer));
    read.await
        .map_err(|_| ViewersError::Daemon("an export took over 2 minutes".into()))?
        .map_err(failed)?;
    Ok(answer)
}

/// The header of the soak's table.
fn table_header() -> String {
    format!(
        "{:>6} {:>10} {:>9} {:>10} {:>9} {:>9} {:>8} {:>9} {:>10} {:>8} {:>7} {:>10} {:>8} {:>6} {:>8} {:>9} {:>8}",
        "minute",
        "daemon MB",
        "daemon fd",
        "daemon CPU",
        "relay MB",
        "relay fd",
        "NATS MB",
        "frames/s",
        "p99 ms",
        "viewers",
        "stalls",
        "performers",
        "bad msgs",
        "takes",
        "lineups",
        "pictures",
        "failures"
    )
}

/// One [`SoakRow`] under [`table_header`]'s columns.
fn table_row(r: &SoakRow) -> String {
    format!(
        "{:>6.1} {:>10.1} {:>9} {:>9.0}% {:>9.1} {:>9} {:>8.1} {:>9.1} {:>10.2} {:>8} {:>7} {:>10} {:>8} {:>6} {:>8} {:>9} {:>8}",
        r.minute,
        r.daemon_rss_mb,
        r.daemon_fds,
        100.0 * r.daemon_cpu,
        r.relay_rss_mb,
        r.relay_fds,
        r.nats_rss_mb,
        r.frames_per_s,
        r.latency_ms_p99,
        r.viewer_connects,
        r.stalls,
        r.performer_sessions,
        r.bad_messages,
        r.takes_exported,
        r.lineups,
        r.pictures,
        r.failures
    )
}

/// Least-squares slope of `y` over `x`.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    if sxx == 0.0 { 0.0 } else { sxy / sxx }
}

/// Whether memory and descriptors stayed flat after the warm-up (the
/// first sixth of the run, at least one row): a line fitted through the
/// rest may rise by at most 3 MB of memory and 4 descriptors plus one
/// per ten churning viewers over that span (viewers come and go, so the
/// descriptors at any instant wander by about that).
fn judge(rows: &[SoakRow], viewers: usize) -> (bool, String) {
    let warm = (rows.len() / 6).max(1);
    let after = rows.get(warm..).unwrap_or(&[]);
    if after.len() < 2 {
        return (
            false,
            "too short to judge: run it longer (--minutes)".to_string(),
        );
    }
    let span = after.last().expect("rows").minute - after[0].minute;
    let fit = |f: &dyn Fn(&SoakRow) -> f64| {
        slope(&after.iter().map(|r| (r.minute, f(r))).collect::<Vec<_>>()) * span
    };
    let memory = fit(&|r| r.daemon_rss_mb);
    let descriptors = fit(&|r| r.daemon_fds as f64);
    let relay_memory = fit(&|r| r.relay_rss_mb);
    let relay_descriptors = fit(&|r| r.relay_fds as f64);
    let fd_allowance = 4.0 + viewers as f64 / 10.0;
    let flat = memory < 3.0
        && descriptors < fd_allowance
        && relay_memory < 3.0
        && relay_descriptors < fd_allowance;
    let verdict = format!(
        "after the warm-up ({:.1} min), over {span:.1} min the fitted lines rose: daemon {memory:+.2} MB, {descriptors:+.1} fds; relay {relay_memory:+.2} MB, {relay_descriptors:+.1} fds (allowed: 3 MB, {fd_allowance:.0} fds): {}",
        after[0].minute,
        if flat { "FLAT" } else { "GROWING" }
    );
    (flat, verdict)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(minute: f64, mb: f64, fds: usize) -> SoakRow {
        SoakRow {
            minute,
            daemon_rss_mb: mb,
            daemon_fds: fds,
            daemon_cpu: 0.0,
            relay_rss_mb: 0.0,
            relay_fds: 0,
            nats_rss_mb: 0.0,
            frames_per_s: 0.0,
            latency_ms_p99: 0.0,
            viewer_connects: 0,
            stalls: 0,
            performer_sessions: 0,
            bad_messages: 0,
            takes_exported: 0,
            lineups: 0,
            pictures: 0,
            failures: 0,
        }
    }

    #[test]
    fn a_leak_after_the_warm_up_is_told_from_noise() {
        // Warm-up growth, then noise around a level: flat.
        let noisy: Vec<SoakRow> = (0..30)
            .map(|m| {
                let level = if m < 5 { 20.0 + 4.0 * m as f64 } else { 40.0 };
                row(m as f64, level + [0.4, -0.3, 0.1][m % 3], 50 + m % 7)
            })
            .collect();
        assert!(judge(&noisy, 20).0, "{}", judge(&noisy, 20).1);
        // 0.2 MB a minute for 25 minutes: growing.
        let leaking: Vec<SoakRow> = (0..30)
            .map(|m| row(m as f64, 40.0 + 0.2 * m as f64, 50))
            .collect();
        assert!(!judge(&leaking, 20).0);
        // A descriptor a minute: growing.
        let fd_leak: Vec<SoakRow> = (0..30).map(|m| row(m as f64, 40.0, 50 + m)).collect();
        assert!(!judge(&fd_leak, 20).0);
        assert!(!judge(&noisy[..2], 20).0, "two rows are too few to judge");
    }
}
