//! `puppetry bench --viewers N,…`: the daemon measured from outside, as an
//! audience meets it. It runs `puppetry serve` on the demo stage as a
//! process of its own, connects N WebSocket viewers and one performer from
//! this process, and has the performer drag the puppet at a touch table's
//! rate. Each viewer times every vertex frame from the input that caused it
//! reaching the daemon to the viewer holding the frame, on one clock: the
//! performer's `ping`s place the daemon's clock on this one (the answer with
//! the shortest round trip, its `clock` at the middle of the trip). The
//! daemon's resident memory and CPU come from `/proc`.

use std::io::BufRead;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use glam::DVec2;
use serde::Serialize;
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

use puppetry_daemon::protocol::{FrameHeader, FrameKind};

/// How fast the performer's finger reports (a touch table's digitiser).
pub const INPUT_HZ: f64 = 120.0;

/// How long the performer drags while every viewer reads.
const DRAG: Duration = Duration::from_secs(5);

/// One `bench --viewers` case, as printed with `--json`.
#[derive(Debug, Clone, Serialize)]
pub struct ViewersResult {
    pub viewers: usize,
    pub vertices: usize,
    pub input_hz: f64,
    /// Input frames the performer sent, and vertex frames each viewer got
    /// on average.
    pub input_frames: usize,
    pub frames_per_viewer: f64,
    /// From an input reaching the daemon to a viewer holding its frame,
    /// over every frame every viewer got.
    pub latency_us_p50: f64,
    pub latency_us_p99: f64,
    /// The daemon's resident set with one viewer connected and with all of
    /// them while the performer drags.
    pub rss_mb_one: f64,
    pub rss_mb_all: f64,
    /// The daemon's CPU while the performer drags, in cores (1.0 = one
    /// core busy).
    pub daemon_cpu: f64,
}

/// Why a `--viewers` case could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum ViewersError {
    #[error("the demo stage: {0}")]
    Bundle(#[from] crate::bundled::BundleError),
    #[error("{what}: {source}")]
    Io {
        what: String,
        source: std::io::Error,
    },
    #[error("the daemon: {0}")]
    Daemon(String),
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
    /// `viewers` connections from this one address.
    fn start(viewers: usize) -> Result<Daemon, ViewersError> {
        let demo = crate::bundled::demo_stage()?;
        let text = std::fs::read_to_string(&demo).map_err(io(demo.display().to_string()))?;
        // Beside the demo stage, so its relative paths hold.
        let stage_file = demo.with_file_name(format!("bench-viewers-{}.toml", std::process::id()));
        let text = text.replace(
            "[access]\n",
            &format!("[access]\nmax_per_address = {}\n", viewers + 8),
        );
        std::fs::write(&stage_file, text).map_err(io(stage_file.display().to_string()))?;
        let exe = std::env::current_exe().map_err(io("this program's path"))?;
        let mut child = std::process::Command::new(exe)
            .args(["serve", "--listen", "127.0.0.1:0", "--config"])
            .arg(&stage_file)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .map_err(io("starting puppetry serve"))?;
        let mut out = std::io::BufReader::new(child.stdout.take().expect("piped"));
        let mut daemon = Daemon {
            child,
            address: String::new(),
            stage_file,
        };
        let mut line = String::new();
        out.read_line(&mut line)
            .map_err(io("the daemon's first line"))?;
        daemon.address = line
            .split("http://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .ok_or_else(|| ViewersError::Daemon(format!("no address in {line:?}")))?
            .to_string();
        // Keep reading, so the daemon never blocks on a full pipe.
        std::thread::spawn(move || for _ in out.lines() {});
        Ok(daemon)
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }
}

/// A process's resident set, MB.
fn rss_mb(pid: u32) -> f64 {
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
fn cpu_seconds(pid: u32) -> f64 {
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

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(
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
async fn daemon_clock_origin(ws: &mut Ws, origin: Instant) -> Result<f64, ViewersError> {
    let mut best: Option<(f64, f64)> = None;
    for _ in 0..50 {
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
                        break m["clock"].as_f64().ok_or_else(|| {
                            ViewersError::Daemon("its pong has no clock (an older build?)".into())
                        })?;
                    }
                }
                Some(Ok(_)) => continue,
                Some(Err(e)) => return Err(e.into()),
                None => return Err(ViewersError::Daemon("closed while pinging".into())),
            }
        };
        let received = origin.elapsed().as_secs_f64();
        let trip = received - sent;
        if best.is_none_or(|(t, _)| trip < t) {
            best = Some((trip, (sent + received) / 2.0 - clock));
        }
    }
    Ok(best.map_or(0.0, |(_, zero)| zero))
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// One case: the daemon, `viewers` viewers, a performer dragging.
pub async fn viewers_case(viewers: usize) -> Result<ViewersResult, ViewersError> {
    let viewers = viewers.max(1);
    let daemon = Daemon::start(viewers)?;
    let origin = Instant::now();
    let (mut performer, stage) = connect(
        &daemon.address,
        json!({"type": "hello", "role": "performer", "token": "demo"}),
    )
    .await?;
    let zero = daemon_clock_origin(&mut performer, origin).await?;
    let puppet = &stage["puppets"][0];
    let rest: Vec<f64> = serde_json::from_value(puppet["rest"].clone()).unwrap_or_default();
    let vertices = rest.len() / 2;
    // Grab the vertex nearest the middle of the puppet.
    let points: Vec<DVec2> = rest.chunks(2).map(|p| DVec2::new(p[0], p[1])).collect();
    let middle = points.iter().copied().sum::<DVec2>() / points.len().max(1) as f64;
    let grab = points
        .iter()
        .copied()
        .min_by(|a, b| a.distance(middle).total_cmp(&b.distance(middle)))
        .ok_or_else(|| ViewersError::Daemon("the demo puppet has no vertices".into()))?;

    let stop = std::sync::Arc::new(tokio::sync::Notify::new());
    let mut readers = Vec::with_capacity(viewers);
    let mut rss_one = 0.0;
    for k in 0..viewers {
        let (mut ws, _) =
            connect(&daemon.address, json!({"type": "hello", "role": "viewer"})).await?;
        let stop = stop.clone();
        readers.push(tokio::spawn(async move {
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
        }));
        if k == 0 {
            tokio::time::sleep(Duration::from_millis(300)).await;
            rss_one = rss_mb(daemon.pid());
        }
    }

    // The drag: a circle around the grab point at the input rate.
    let period = Duration::from_secs_f64(1.0 / INPUT_HZ);
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let steps = (DRAG.as_secs_f64() * INPUT_HZ) as usize;
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
    let daemon_cpu = (cpu_seconds(daemon.pid()) - cpu_before) / dragging.elapsed().as_secs_f64();
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
    drop(daemon);
    latencies.sort_by(f64::total_cmp);
    if latencies.is_empty() {
        return Err(ViewersError::Daemon("no frame reached a viewer".into()));
    }
    Ok(ViewersResult {
        viewers,
        vertices,
        input_hz: INPUT_HZ,
        input_frames: steps,
        frames_per_viewer: received as f64 / viewers as f64,
        latency_us_p50: percentile(&latencies, 0.5),
        latency_us_p99: percentile(&latencies, 0.99),
        rss_mb_one: rss_one,
        rss_mb_all: rss_all,
        daemon_cpu,
    })
}

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
