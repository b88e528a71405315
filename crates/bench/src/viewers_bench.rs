//! `puppetry bench --viewers N,…`: the daemon measured from outside, as an
//! audience meets it. It runs `puppetry serve` on the demo stage as a
//! process of its own, connects N WebSocket viewers and one performer from
//! this process, and has the performer drag the puppet at a touch table's
//! rate. Each viewer times every vertex frame from the input that caused it
//! reaching the daemon to the viewer holding the frame, on one clock: the
//! performer's `ping`s place the daemon's clock on this one (the answer with
//! the shortest round trip, its `clock` at the middle of the trip). The
//! daemon's resident memory and CPU come from `/proc`.
//!
//! With `--relays N` the viewers meet it through the relay tier: a
//! `nats-server` and N `puppetry relay` processes, the viewers spread over
//! the relays, the performer on the daemon (its clock is the one frames
//! carry). Each relay's and the NATS server's CPU and memory come from
//! `/proc` too, and a second performer on a relay times a request the
//! daemon answers against the direct one's: what a remote performer's
//! input pays.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use glam::DVec2;
use serde::Serialize;
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

use puppetry_daemon::protocol::{FrameHeader, FrameKind};

/// How fast the performer's finger reports (a touch table's digitiser).
const INPUT_HZ: f64 = 120.0;

/// How long the performer drags while every viewer reads.
const DRAG: Duration = Duration::from_secs(5);

/// One `bench --viewers` case, as printed with `--json`.
#[derive(Debug, Clone, Serialize)]
pub struct ViewersResult {
    /// Viewers connected (at least 1).
    pub viewers: usize,
    /// Relays the viewers were spread over (0: on the daemon itself).
    pub relays: usize,
    /// Vertices of the demo puppet being dragged.
    pub vertices: usize,
    /// The performer's input rate, Hz: 120 (a touch table) on the daemon,
    /// 60 (an audience's display) through relays.
    pub input_hz: f64,
    /// Input frames the performer sent: 5 s of drag at `input_hz`.
    pub input_frames: usize,
    /// Vertex frames (those caused by an input) each viewer got, on average.
    pub frames_per_viewer: f64,
    /// Median µs from an input reaching the daemon to a viewer holding its
    /// frame, over every frame every viewer got (NaN when an older daemon
    /// timed with `--daemon` does not tell its clock).
    pub latency_us_p50: f64,
    /// 99th percentile of the same latencies, µs.
    pub latency_us_p99: f64,
    /// The daemon's resident set with one viewer connected, MB.
    pub rss_mb_one: f64,
    /// The daemon's resident set with all of them connected while the
    /// performer drags, MB (the larger of mid-drag and just after).
    pub rss_mb_all: f64,
    /// The daemon's CPU while the performer drags, in cores (1.0 = one
    /// core busy).
    pub daemon_cpu: f64,
    /// The relays' CPU while the performer drags, summed over all of them,
    /// in cores (0 without relays).
    pub relays_cpu: f64,
    /// The relays' resident sets just after the drag, summed, MB.
    pub relays_rss_mb: f64,
    /// The NATS server's CPU while the performer drags, in cores.
    pub nats_cpu: f64,
    /// The NATS server's resident set just after the drag, MB.
    pub nats_rss_mb: f64,
    /// Median round trip of a request the daemon answers (`list_takes`)
    /// from a performer on the daemon, µs (0 without relays).
    pub ask_direct_us: f64,
    /// The same from a performer on a relay, through NATS to the daemon
    /// and back, µs (0 without relays): what a remote performer's input
    /// pays over [`ask_direct_us`](Self::ask_direct_us).
    pub ask_relay_us: f64,
}

/// Why a `--viewers` case or a soak could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum ViewersError {
    /// The bundled demo (its stages and assets) could not be unpacked.
    #[error("the demo stage: {0}")]
    Bundle(#[from] puppetry_daemon::bundled::BundleError),
    /// A file, a process or a socket of the bench itself failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done, or the file it was done to.
        what: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// The daemon, a relay or nats-server did not do its part (no address
    /// printed, no stage, no answer, a failed export); the text says what.
    #[error("the daemon: {0}")]
    Daemon(String),
    /// The daemon's `pong` has no `clock`, so its frames' input times
    /// cannot be placed on this process's clock.
    #[error("the daemon: its pong has no clock (an older build?)")]
    NoClock,
    /// The relay tier was asked for, but no `nats-server` is on the `PATH`
    /// or in `/usr/sbin`.
    #[error("the relay tier needs nats-server: install it (apt-get install nats-server)")]
    NoNats,
    /// A WebSocket connection failed or broke.
    #[error("a WebSocket: {0}")]
    WebSocket(#[from] tokio_tungstenite::tungstenite::Error),
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> ViewersError {
    let what = what.into();
    move |source| ViewersError::Io { what, source }
}

/// A `puppetry serve` child, killed when dropped.
struct Daemon {
    child: std::process::Child,
    address: String,
    stage_file: PathBuf,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.stage_file);
    }
}

impl Daemon {
    /// Serves the bundled demo stage on a free loopback port, taking
    /// `viewers` connections from this one address, with `program` (this
    /// one when `None`).
    fn start(viewers: usize, extra: &str, program: Option<&Path>) -> Result<Daemon, ViewersError> {
        let demo = puppetry_daemon::bundled::demo_stage()?;
        let text = std::fs::read_to_string(&demo).map_err(io(demo.display().to_string()))?;
        // Beside the demo stage, so its relative paths hold.
        let stage_file = demo.with_file_name(format!("bench-viewers-{}.toml", std::process::id()));
        let text = text.replace(
            "[access]\n",
            &format!("[access]\nmax_per_address = {}\n", viewers + 8),
        ) + extra;
        std::fs::write(&stage_file, text).map_err(io(stage_file.display().to_string()))?;
        let program = match program {
            Some(program) => program.to_path_buf(),
            None => this_program()?,
        };
        let mut serve = std::process::Command::new(program);
        serve
            .args(["serve", "--listen", "127.0.0.1:0", "--config"])
            .arg(&stage_file);
        let (child, address) = spawn_serving(serve, "puppetry serve")?;
        Ok(Daemon {
            child,
            address,
            stage_file,
        })
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }
}

pub(crate) fn this_program() -> Result<PathBuf, ViewersError> {
    std::env::current_exe().map_err(io("this program's path"))
}

/// Starts `command`, which prints the `http://ADDRESS/` it serves on its
/// first line; the child and that address.
pub(crate) fn spawn_serving(
    mut command: std::process::Command,
    what: &str,
) -> Result<(std::process::Child, String), ViewersError> {
    let mut child = command
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .map_err(io(format!("starting {what}")))?;
    let mut out = std::io::BufReader::new(child.stdout.take().expect("piped"));
    let mut line = String::new();
    let read = out.read_line(&mut line);
    let address = line
        .split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .map(str::to_string);
    let (Ok(_), Some(address)) = (read, address) else {
        let _ = child.kill();
        let _ = child.wait();
        return Err(ViewersError::Daemon(format!(
            "{what}: no address in its first line {line:?}"
        )));
    };
    // Keep reading, so the child never blocks on a full pipe.
    std::thread::spawn(move || for _ in out.lines() {});
    Ok((child, address))
}

/// A child process killed when dropped.
pub(crate) struct Child(pub(crate) std::process::Child);

impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The relay tier: a nats-server on a free loopback port with users and
/// permissions (`puppetry_daemon::relay::nats`), as the bundled example
/// runs it, for the daemon and relays `r0`, `r1`, … of one stage; and the
/// relay processes once started.
pub(crate) struct Tier {
    pub(crate) nats: Child,
    stage: String,
    /// The daemon's address, with its credentials.
    daemon_url: String,
    /// Each relay's address, with its credentials (on its command line: a
    /// bench's passwords live as long as the bench, on loopback).
    relay_urls: Vec<String>,
    pub(crate) relays: Vec<(Child, String)>,
}

impl Tier {
    pub(crate) fn start(stage: &str, relays: usize) -> Result<Tier, ViewersError> {
        use puppetry_daemon::relay::nats::{self as access, Secret};
        let failed = |e: puppetry_daemon::relay::RelayError| ViewersError::Daemon(e.to_string());
        let daemon_password = access::random_password().map_err(failed)?;
        let mut relay_users = Vec::new();
        for k in 0..relays {
            let password = access::random_password().map_err(failed)?;
            relay_users.push((format!("r{k}"), password));
        }
        let named: Vec<(&str, Secret)> = relay_users
            .iter()
            .map(|(name, password)| (name.as_str(), Secret::Literal(password.clone())))
            .collect();
        let entries =
            access::user_entries(stage, &Secret::Literal(daemon_password.clone()), &named)
                .map_err(failed)?;
        let program = std::env::var_os("PATH")
            .map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
            .unwrap_or_default()
            .into_iter()
            .chain([PathBuf::from("/usr/sbin")])
            .map(|d| d.join("nats-server"))
            .find(|p| p.is_file())
            .ok_or(ViewersError::NoNats)?;
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(io("a free port"))?
            .port();
        let listen = format!("127.0.0.1:{port}");
        // Only this user may read the passwords; gone once the server has
        // read them.
        let file =
            std::env::temp_dir().join(format!("puppetry-bench-nats-{}.conf", std::process::id()));
        let written = {
            use std::io::Write;
            use std::os::unix::fs::OpenOptionsExt;
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(&file)
                .and_then(|mut f| f.write_all(access::server_config(&listen, &entries).as_bytes()))
        };
        written.map_err(io(&file.display().to_string()))?;
        let spawned = std::process::Command::new(program)
            .arg("-c")
            .arg(&file)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn();
        let nats = spawned.map(Child);
        let address = std::net::SocketAddr::from(([127, 0, 0, 1], port));
        let mut listening = false;
        if nats.is_ok() {
            for _ in 0..500 {
                if std::net::TcpStream::connect(address).is_ok() {
                    listening = true;
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        let _ = std::fs::remove_file(&file);
        let nats = nats.map_err(io("starting nats-server"))?;
        if !listening {
            return Err(ViewersError::Daemon(format!(
                "nats-server did not listen on {address}"
            )));
        }
        let relay_urls = relay_users
            .iter()
            .map(|(name, password)| format!("nats://{name}:{password}@{listen}"))
            .collect();
        Ok(Tier {
            nats,
            stage: stage.to_string(),
            daemon_url: format!("nats://{}:{daemon_password}@{listen}", access::DAEMON_USER),
            relay_urls,
            relays: Vec::new(),
        })
    }

    /// The daemon's `[relay]` section for this tier.
    pub(crate) fn relay_section(&self) -> String {
        format!(
            "\n[relay]\nnats = \"{}\"\nstage = \"{}\"\n",
            self.daemon_url, self.stage
        )
    }

    /// Starts one relay per user of the tier, each serving up to
    /// `viewers` connections.
    pub(crate) fn start_relays(&mut self, viewers: usize) -> Result<(), ViewersError> {
        for (k, url) in self.relay_urls.iter().enumerate() {
            let mut relay = std::process::Command::new(this_program()?);
            relay.args([
                "relay",
                "--nats",
                url,
                "--stage",
                &self.stage,
                "--listen",
                "127.0.0.1:0",
                "--name",
                &format!("r{k}"),
                "--max-connections",
                &viewers.to_string(),
            ]);
            let (child, address) = spawn_serving(relay, "puppetry relay")?;
            self.relays.push((Child(child), address));
        }
        Ok(())
    }

    fn pids(&self) -> Vec<u32> {
        self.relays.iter().map(|(c, _)| c.0.id()).collect()
    }
}

/// A process's resident set, MB.
pub(crate) fn rss_mb(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|status| {
            status
                .lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.split_whitespace().next())
                .and_then(|v| v.parse::<f64>().ok())
        })
        .map_or(0.0, |kib| kib / 1024.0)
}

/// A process's CPU seconds (user and system).
pub(crate) fn cpu_seconds(pid: u32) -> f64 {
    let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
        return 0.0;
    };
    let Some(close) = stat.rfind(')') else {
        return 0.0;
    };
    let fields: Vec<&str> = stat[close + 2..].split_whitespace().collect();
    let ticks = |k: usize| fields.get(k).and_then(|f| f.parse::<f64>().ok());
    match (ticks(11), ticks(12)) {
        (Some(user), Some(system)) => (user + system) / 100.0,
        _ => 0.0,
    }
}

pub(crate) type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Connects and reads until a `stage` message with puppets (a relay that
/// has not heard the daemon yet sends an empty one first).
pub(crate) async fn connect_staged(
    address: &str,
    hello: serde_json::Value,
) -> Result<(Ws, serde_json::Value), ViewersError> {
    let (mut ws, mut stage) = connect(address, hello).await?;
    for _ in 0..10_000 {
        let staged =
            stage["type"] == "stage" && stage["puppets"].as_array().is_some_and(|p| !p.is_empty());
        if staged {
            return Ok((ws, stage));
        }
        stage = match ws.next().await {
            Some(Ok(Message::Text(text))) => serde_json::from_str(&text).unwrap_or_default(),
            Some(Ok(_)) => continue,
            Some(Err(e)) => return Err(e.into()),
            None => return Err(ViewersError::Daemon("closed before the stage".into())),
        };
    }
    Err(ViewersError::Daemon("no stage with puppets came".into()))
}

pub(crate) async fn connect(
    address: &str,
    hello: serde_json::Value,
) -> Result<(Ws, serde_json::Value), ViewersError> {
    let mut ws = crate::bench::connect_viewer(&format!("ws://{address}/ws")).await?;
    ws.send(Message::text(hello.to_string())).await?;
    loop {
        match ws.next().await {
            Some(Ok(Message::Text(text))) => {
                let stage: serde_json::Value = serde_json::from_str(&text)
                    .map_err(|e| ViewersError::Daemon(format!("a bad stage message: {e}")))?;
                return Ok((ws, stage));
            }
            Some(Ok(_)) => continue,
            Some(Err(e)) => return Err(e.into()),
            None => {
                return Err(ViewersError::Daemon(
                    "closed before the stage message".into(),
                ));
            }
        }
    }
}

/// Where the daemon's clock reads 0, on `origin`'s clock (seconds): from
/// the performer's pings, the one with the shortest round trip.
pub(crate) async fn daemon_clock_origin(ws: &mut Ws, origin: Instant) -> Result<f64, ViewersError> {
    let mut best: Option<(f64, f64)> = None;
    let mut answered = 0;
    // A relay that does not reach the stage yet refuses a ping it cannot
    // answer: asked again a little later, a bounded number of times.
    for _ in 0..250 {
        if answered == 50 {
            break;
        }
        let sent = origin.elapsed().as_secs_f64();
        ws.send(Message::text(
            json!({"type": "ping", "t": sent}).to_string(),
        ))
        .await?;
        let clock = loop {
            match ws.next().await {
                Some(Ok(Message::Text(text))) => {
                    let m: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
                    if m["type"] == "pong" && m["t"] == sent {
                        break Some(m["clock"].as_f64().ok_or(ViewersError::NoClock)?);
                    }
                    if m["type"] == "error" {
                        break None;
                    }
                }
                Some(Ok(_)) => continue,
                Some(Err(e)) => return Err(e.into()),
                None => return Err(ViewersError::Daemon("closed while pinging".into())),
            }
        };
        let Some(clock) = clock else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        answered += 1;
        let received = origin.elapsed().as_secs_f64();
        let trip = received - sent;
        if best.is_none_or(|(t, _)| trip < t) {
            best = Some((trip, (sent + received) / 2.0 - clock));
        }
    }
    best.map(|(_, zero)| zero)
        .ok_or_else(|| ViewersError::Daemon("no ping was answered".into()))
}

pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Median round trip of `count` requests the daemon itself answers
/// (`list_takes`: a relay forwards it, as it forwards a performer's
/// touches) on `ws`, µs.
async fn request_median(ws: &mut Ws, count: usize) -> Result<f64, ViewersError> {
    let origin = Instant::now();
    let mut trips = Vec::with_capacity(count);
    // A relay refuses (`failed`) until it has the stage: those are not
    // timed, and asked again a little later.
    let mut refused = 0;
    while trips.len() < count {
        let sent = origin.elapsed().as_secs_f64();
        ws.send(Message::text(json!({"type": "list_takes"}).to_string()))
            .await?;
        let answered = loop {
            match ws.next().await {
                Some(Ok(Message::Text(text))) => {
                    let m: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
                    if m["type"] == "takes" {
                        break true;
                    }
                    if m["type"] == "error" {
                        break false;
                    }
                }
                Some(Ok(_)) => continue,
                Some(Err(e)) => return Err(e.into()),
                None => return Err(ViewersError::Daemon("closed while asking".into())),
            }
        };
        if answered {
            trips.push((origin.elapsed().as_secs_f64() - sent) * 1e6);
        } else {
            refused += 1;
            if refused > 200 {
                return Err(ViewersError::Daemon(
                    "the stage refused list_takes 200 times".into(),
                ));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    trips.sort_by(f64::total_cmp);
    Ok(percentile(&trips, 0.5))
}

/// Frames a second the relay tier is benched at (an audience's display).
const RELAY_INPUT_HZ: f64 = 60.0;

/// The first puppet of a stage message: its vertex count, and the vertex
/// nearest its middle (where the bench grabs it).
fn middle_vertex(stage: &serde_json::Value) -> Result<(usize, DVec2), ViewersError> {
    let puppet = &stage["puppets"][0];
    let rest: Vec<f64> = serde_json::from_value(puppet["rest"].clone()).unwrap_or_default();
    let points: Vec<DVec2> = rest.chunks(2).map(|p| DVec2::new(p[0], p[1])).collect();
    let middle = points.iter().copied().sum::<DVec2>() / points.len().max(1) as f64;
    let grab = points
        .iter()
        .copied()
        .min_by(|a, b| a.distance(middle).total_cmp(&b.distance(middle)))
        .ok_or_else(|| ViewersError::Daemon("the demo puppet has no vertices".into()))?;
    Ok((points.len(), grab))
}

/// A viewer's frames' latencies (µs) until `stop`: each vertices frame's
/// arrival (since `origin`) against its input's time on the daemon's
/// clock (which started at `zero` on ours).
async fn latencies(
    mut ws: Ws,
    stop: std::sync::Arc<tokio::sync::Notify>,
    origin: Instant,
    zero: f64,
) -> Vec<f64> {
    let mut latencies = Vec::with_capacity(1024);
    let stopped = stop.notified();
    tokio::pin!(stopped);
    loop {
        tokio::select! {
            _ = &mut stopped => break,
            m = ws.next() => match m {
                Some(Ok(Message::Binary(bytes))) => {
                    let now = origin.elapsed().as_secs_f64();
                    if let Ok(h) = FrameHeader::decode(&bytes)
                        && h.kind == FrameKind::Vertices
                        && h.input_time > 0.0
                    {
                        latencies.push((now - (zero + h.input_time)) * 1e6);
                    }
                }
                Some(Ok(_)) => {}
                _ => break,
            },
        }
    }
    latencies
}

/// The median round trip (µs) of a request to the daemon from
/// `performer`, then from a performer on the tier's first relay.
async fn asked_both_ways(performer: &mut Ws, tier: &Tier) -> Result<(f64, f64), ViewersError> {
    let direct = request_median(performer, 200).await?;
    let (mut remote, _) = connect_staged(
        &tier.relays[0].1,
        json!({"type": "hello", "role": "performer", "token": "demo"}),
    )
    .await?;
    Ok((direct, request_median(&mut remote, 200).await?))
}

/// One case: the daemon, `viewers` viewers (on `relays` relays, or on the
/// daemon with none), a performer dragging. The daemon is `daemon_program`
/// when given (another build to compare with), this program otherwise.
pub async fn viewers_case(
    viewers: usize,
    relays: usize,
    daemon_program: Option<&Path>,
) -> Result<ViewersResult, ViewersError> {
    let viewers = viewers.max(1);
    let input_hz = if relays > 0 { RELAY_INPUT_HZ } else { INPUT_HZ };
    let mut tier = None;
    let mut extra = String::new();
    if relays > 0 {
        let nats = Tier::start("bench", relays)?;
        extra = nats.relay_section();
        tier = Some(nats);
    }
    let daemon = Daemon::start(viewers, &extra, daemon_program)?;
    if let Some(tier) = &mut tier {
        tier.start_relays(viewers + 16)?;
    }
    let origin = Instant::now();
    let (mut performer, stage) = connect(
        &daemon.address,
        json!({"type": "hello", "role": "performer", "token": "demo"}),
    )
    .await?;
    // An older build timed for comparison may not tell its clock: its
    // frames are still counted, their latency is NaN.
    let zero = match daemon_clock_origin(&mut performer, origin).await {
        Err(ViewersError::NoClock) if daemon_program.is_some() => f64::NAN,
        zero => zero?,
    };
    let (ask_direct_us, ask_relay_us) = match &tier {
        Some(tier) => asked_both_ways(&mut performer, tier).await?,
        None => (0.0, 0.0),
    };
    let (vertices, grab) = middle_vertex(&stage)?;

    let stop = std::sync::Arc::new(tokio::sync::Notify::new());
    let mut readers = Vec::with_capacity(viewers);
    let mut rss_one = 0.0;
    for k in 0..viewers {
        let address = match &tier {
            Some(tier) => &tier.relays[k % tier.relays.len()].1,
            None => &daemon.address,
        };
        let (ws, _) = connect_staged(address, json!({"type": "hello", "role": "viewer"})).await?;
        readers.push(tokio::spawn(latencies(ws, stop.clone(), origin, zero)));
        if k == 0 {
            tokio::time::sleep(Duration::from_millis(300)).await;
            rss_one = rss_mb(daemon.pid());
        }
    }

    // The drag: a circle around the grab point at the input rate.
    let period = Duration::from_secs_f64(1.0 / input_hz);
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let steps = (DRAG.as_secs_f64() * input_hz) as usize;
    let relay_pids = tier.as_ref().map(Tier::pids).unwrap_or_default();
    let nats_pid = tier.as_ref().map(|t| t.nats.0.id());
    let relays_cpu_of = |pids: &[u32]| pids.iter().map(|&p| cpu_seconds(p)).sum::<f64>();
    let relays_before = relays_cpu_of(&relay_pids);
    let nats_before = nats_pid.map_or(0.0, cpu_seconds);
    let cpu_before = cpu_seconds(daemon.pid());
    let dragging = Instant::now();
    let mut rss_all: f64 = 0.0;
    for k in 0..steps {
        tick.tick().await;
        let phase = if k == 0 { "down" } else { "move" };
        let a = k as f64 * 0.05;
        let at = grab + DVec2::new(a.cos() - 1.0, a.sin()) * 30.0;
        let m = json!({"type": "contacts", "contacts": [{"id": 1, "phase": phase, "x": at.x, "y": at.y}]});
        performer.send(Message::text(m.to_string())).await?;
        if k == steps / 2 {
            rss_all = rss_mb(daemon.pid());
        }
    }
    let up = json!({"type": "contacts", "contacts": [{"id": 1, "phase": "up"}]});
    performer.send(Message::text(up.to_string())).await?;
    let dragged = dragging.elapsed().as_secs_f64();
    let daemon_cpu = (cpu_seconds(daemon.pid()) - cpu_before) / dragged;
    let relays_cpu = (relays_cpu_of(&relay_pids) - relays_before) / dragged;
    let nats_cpu = (nats_pid.map_or(0.0, cpu_seconds) - nats_before) / dragged;
    let relays_rss_mb = relay_pids.iter().map(|&p| rss_mb(p)).sum();
    let nats_rss_mb = nats_pid.map_or(0.0, rss_mb);
    tokio::time::sleep(Duration::from_millis(300)).await;
    rss_all = rss_all.max(rss_mb(daemon.pid()));
    stop.notify_waiters();
    let mut latencies = Vec::new();
    let mut received = 0;
    for reader in readers {
        let l = reader
            .await
            .map_err(|e| ViewersError::Daemon(format!("a viewer's task: {e}")))?;
        received += l.len();
        latencies.extend(l);
    }
    drop(tier);
    drop(daemon);
    latencies.sort_by(f64::total_cmp);
    if latencies.is_empty() {
        return Err(ViewersError::Daemon("no frame reached a viewer".into()));
    }
    Ok(ViewersResult {
        viewers,
        relays,
        vertices,
        input_hz,
        input_frames: steps,
        frames_per_viewer: received as f64 / viewers as f64,
        latency_us_p50: percentile(&latencies, 0.5),
        latency_us_p99: percentile(&latencies, 0.99),
        rss_mb_one: rss_one,
        rss_mb_all: rss_all,
        daemon_cpu,
        relays_cpu,
        relays_rss_mb,
        nats_cpu,
        nats_rss_mb,
        ask_direct_us,
        ask_relay_us,
    })
}

/// The header of the table `bench --viewers` prints with `--relays`.
pub fn relays_table_header() -> String {
    format!(
        "{:>7} {:>6} {:>8} {:>9} {:>17} {:>14} {:>14} {:>11} {:>11} {:>12} {:>13} {:>10} {:>10} {:>15} {:>14}",
        "viewers",
        "relays",
        "input Hz",
        "published",
        "frames per viewer",
        "latency µs p50",
        "latency µs p99",
        "daemon CPU",
        "relays CPU",
        "relays RSS MB",
        "per viewer",
        "NATS CPU",
        "NATS MB",
        "ask direct µs",
        "ask relay µs"
    )
}

/// One [`ViewersResult`] under [`relays_table_header`]'s columns; `per
/// viewer` is the relays' CPU (millicores) and memory (KiB) per viewer.
pub fn relays_table_row(r: &ViewersResult) -> String {
    let per_viewer = format!(
        "{:.1}m/{:.0}K",
        1000.0 * r.relays_cpu / r.viewers as f64,
        1024.0 * r.relays_rss_mb / r.viewers as f64
    );
    format!(
        "{:>7} {:>6} {:>8.0} {:>9} {:>17.0} {:>14.0} {:>14.0} {:>10.0}% {:>10.0}% {:>12.1} {:>13} {:>9.0}% {:>10.1} {:>15.0} {:>14.0}",
        r.viewers,
        r.relays,
        r.input_hz,
        r.input_frames,
        r.frames_per_viewer,
        r.latency_us_p50,
        r.latency_us_p99,
        100.0 * r.daemon_cpu,
        100.0 * r.relays_cpu,
        r.relays_rss_mb,
        per_viewer,
        100.0 * r.nats_cpu,
        r.nats_rss_mb,
        r.ask_direct_us,
        r.ask_relay_us
    )
}

/// The header of the table `bench --viewers` prints without relays.
pub fn viewers_table_header() -> String {
    format!(
        "{:>7} {:>8} {:>9} {:>12} {:>17} {:>14} {:>14} {:>13} {:>13} {:>11}",
        "viewers",
        "vertices",
        "input Hz",
        "input frames",
        "frames per viewer",
        "latency µs p50",
        "latency µs p99",
        "RSS MB 1 view",
        "RSS MB all",
        "daemon CPU"
    )
}

/// One [`ViewersResult`] under [`viewers_table_header`]'s columns.
pub fn viewers_table_row(r: &ViewersResult) -> String {
    format!(
        "{:>7} {:>8} {:>9.0} {:>12} {:>17.0} {:>14.0} {:>14.0} {:>13.1} {:>13.1} {:>10.0}%",
        r.viewers,
        r.vertices,
        r.input_hz,
        r.input_frames,
        r.frames_per_viewer,
        r.latency_us_p50,
        r.latency_us_p99,
        r.rss_mb_one,
        r.rss_mb_all,
        100.0 * r.daemon_cpu
    )
}
