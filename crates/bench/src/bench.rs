//! `puppetry bench`: timings of the solver phases on meshes of chosen sizes —
//! registration, compilation, per-frame update (median and p99) and the cost
//! of a frame in which a finger lands or lifts. Prints a table or JSON lines.
//!
//! The rig cases time the other two deformers' whole frames through their own
//! bench functions: lp-FFD on a 10×10 grid (both bases) with four vertex
//! handles wandering, and the 15-bone gingerbread skeleton animated in
//! forward kinematics (bone transforms and every propagation round).
//!
//! The depth cases time the depth order's frames (overlap detection and
//! front/back assignment) beside the ARAP updates that posed them, without
//! overlap and with a foot folded over the body.
//!
//! The curve cases (`--curves`) time as-rigid-as-possible curve editing: a
//! wavy curve of 1k and 10k points held at its ends and middle, and peeling
//! drags whose growing region recompiles the system.

use std::time::{Duration, Instant};

use glam::DVec2;
use serde::Serialize;

use puppetry_deform::ffd::{Basis, FfdError, GridSpec, LpFfd, LpParams};
use puppetry_deform::skeleton::{ShapeAware, Skeleton, SkeletonError, SkeletonParams};
use puppetry_deform::{
    Anchor, Arap, ArapError, Curve, CurveAnchor, CurveError, DepthError, DepthOrder, Peel,
    PeelParams, Steps,
};
use puppetry_mesh::Mesh;

/// One measured case, as printed by `puppetry bench --json`.
#[derive(Debug, Clone, Serialize)]
pub struct CaseResult {
    /// The mesh's name as the caller gave it: `puppetry bench` uses the
    /// file's path, or `gingerbread@N` for the demo picture meshed at about
    /// N vertices.
    pub mesh: String,
    /// Vertices of the mesh: what the times scale with.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Point handles held in the plain update frames; the handle-change
    /// frames hold one more, then this many again.
    pub handles: usize,
    /// Registration (`Arap::register`, the rest shape's precomputation),
    /// ms: the median of 3 runs, or the only run on meshes over 50k
    /// vertices.
    pub register_ms: f64,
    /// Compiling the handles (`Arap::compile`), µs, timed once.
    pub compile_us: f64,
    /// Median update (both steps) while the handles wander, µs.
    pub update_us_median: f64,
    /// 99th percentile of the same updates, µs.
    pub update_us_p99: f64,
    /// Median of all frames that add or remove a handle (a compile and an
    /// update), µs: what a frame costs when a finger lands or lifts.
    pub handle_change_frame_us: f64,
    /// 99th percentile of the same frames, µs.
    pub handle_change_frame_us_p99: f64,
    /// Median of the frames that add a handle alone, µs.
    pub handle_add_frame_us: f64,
    /// Median of the frames that remove a handle alone, µs.
    pub handle_remove_frame_us: f64,
    /// Plain update frames timed; the handle-change frames come after them,
    /// about a quarter as many adds and as many removes (at least 5 each).
    pub frames: usize,
}

/// Deterministic pseudo-random numbers, so every run benches the same handles.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` point handles spread over the mesh: random triangles, random
/// interior points, the first few as far apart as possible.
fn spread_anchors(mesh: &Mesh, count: usize, seed: u64) -> Vec<Anchor> {
    let mut rng = Lcg(seed);
    let tris = mesh.triangles().len();
    (0..count)
        .map(|_| {
            let t = ((rng.next() * tris as f64) as usize).min(tris - 1) as u32;
            let (a, b) = (rng.next(), rng.next());
            let (a, b) = if a + b > 1.0 {
                (1.0 - a, 1.0 - b)
            } else {
                (a, b)
            };
            Anchor::Point {
                triangle: t,
                bary: [1.0 - a - b, a, b],
            }
        })
        .collect()
}

fn rest_point(mesh: &Mesh, anchor: &Anchor) -> DVec2 {
    match *anchor {
        Anchor::Vertex(v) => mesh.vertices()[v as usize],
        Anchor::Point { triangle, bary } => mesh.point_at(triangle, bary),
    }
}

/// Handle targets for frame `f`: each handle wanders on its own small circle,
/// so the mesh bends and stretches a little every frame.
fn animate(rest: &[DVec2], size: f64, frame: usize, out: &mut [DVec2]) {
    let t = frame as f64 * 0.05;
    for (h, (o, r)) in out.iter_mut().zip(rest).enumerate() {
        let phase = t + h as f64 * 1.3;
        *o = *r + DVec2::new(phase.cos(), phase.sin()) * (0.03 * size);
    }
}

fn micros(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

/// Measures one mesh with `handles` handles over `frames` update frames.
pub fn run_case(
    name: &str,
    mesh: &Mesh,
    handles: usize,
    frames: usize,
) -> Result<CaseResult, ArapError> {
    let registrations = if mesh.vertices().len() > 50_000 { 1 } else { 3 };
    let mut register_times = Vec::new();
    let mut arap = None;
    for _ in 0..registrations {
        let start = Instant::now();
        let a = Arap::register(mesh)?;
        register_times.push(start.elapsed().as_secs_f64() * 1e3);
        arap = Some(a);
    }
    register_times.sort_by(f64::total_cmp);
    let mut arap = arap.expect("registered at least once");
    // One spare handle for the add/remove frames.
    let anchors = spread_anchors(mesh, handles + 1, 0x5eed + handles as u64);
    let rest: Vec<DVec2> = anchors.iter().map(|a| rest_point(mesh, a)).collect();
    let size = mesh.size();
    let mut targets = vec![DVec2::ZERO; handles + 1];

    let start = Instant::now();
    arap.compile(&anchors[..handles])?;
    let compile_us = micros(start.elapsed());

    let mut update = Vec::with_capacity(frames);
    for f in 0..frames {
        animate(&rest[..handles], size, f, &mut targets[..handles]);
        let start = Instant::now();
        arap.update(&targets[..handles], Steps::Both)?;
        update.push(micros(start.elapsed()));
    }
    update.sort_by(f64::total_cmp);

    // A finger lands (handles+1), then lifts (handles): compile + update.
    // Plain frames in between, as when a performer's finger lands now and
    // then, so the caches hold what a live solver's would.
    let change_frames = (frames / 2).max(10);
    let (mut adds, mut removes) = (Vec::new(), Vec::new());
    for f in 0..change_frames * 2 {
        let adding = f % 4 == 0;
        let removing = f % 4 == 2;
        let count = if f % 4 == 0 || f % 4 == 1 {
            handles + 1
        } else {
            handles
        };
        animate(&rest[..count], size, frames + f, &mut targets[..count]);
        let start = Instant::now();
        if adding || removing {
            arap.compile(&anchors[..count])?;
        }
        arap.update(&targets[..count], Steps::Both)?;
        let took = micros(start.elapsed());
        if adding {
            adds.push(took);
        } else if removing {
            removes.push(took);
        }
    }
    let mut change: Vec<f64> = adds.iter().chain(&removes).copied().collect();
    change.sort_by(f64::total_cmp);
    adds.sort_by(f64::total_cmp);
    removes.sort_by(f64::total_cmp);

    Ok(CaseResult {
        mesh: name.to_string(),
        vertices: mesh.vertices().len(),
        triangles: mesh.triangles().len(),
        handles,
        register_ms: percentile(&register_times, 0.5),
        compile_us,
        update_us_median: percentile(&update, 0.5),
        update_us_p99: percentile(&update, 0.99),
        handle_change_frame_us: percentile(&change, 0.5),
        handle_change_frame_us_p99: percentile(&change, 0.99),
        handle_add_frame_us: percentile(&adds, 0.5),
        handle_remove_frame_us: percentile(&removes, 0.5),
        frames,
    })
}

/// Frames to time for a mesh of `vertices`, so each case takes about a second.
pub fn frames_for(vertices: usize) -> usize {
    (2_000_000 / vertices.max(1)).clamp(20, 2000)
}

/// The header of the human-readable table of [`CaseResult`]s.
pub fn table_header() -> String {
    format!(
        "{:<20} {:>8} {:>7} {:>11} {:>11} {:>13} {:>13} {:>10} {:>10}",
        "mesh",
        "vertices",
        "handles",
        "register ms",
        "compile µs",
        "update µs p50",
        "update µs p99",
        "add µs",
        "remove µs"
    )
}

/// One [`CaseResult`] as a row under [`table_header`]'s columns.
pub fn table_row(r: &CaseResult) -> String {
    format!(
        "{:<20} {:>8} {:>7} {:>11.2} {:>11.1} {:>13.1} {:>13.1} {:>10.1} {:>10.1}",
        r.mesh,
        r.vertices,
        r.handles,
        r.register_ms,
        r.compile_us,
        r.update_us_median,
        r.update_us_p99,
        r.handle_add_frame_us,
        r.handle_remove_frame_us
    )
}

/// One end-to-end case, as printed by `puppetry bench --e2e --json`.
#[derive(Debug, Clone, Serialize)]
pub struct EndToEndResult {
    /// The stage's name as the caller gave it (`puppetry bench --e2e`: the
    /// demo stage, the demo puppet at 10k vertices, eight puppets).
    pub mesh: String,
    /// Vertices of each puppet (the first one's count: the bench's stages
    /// give all their puppets one mesh).
    pub vertices: usize,
    /// Puppets on the stage.
    pub puppets: usize,
    /// Input sources, each holding one contact per puppet it plays, all
    /// sending a frame every millisecond of input time.
    pub performers: usize,
    /// Viewers connected on loopback, each reading every frame.
    pub clients: usize,
    /// "real_time" (1 kHz input) or "as_fast_as_possible".
    pub pacing: &'static str,
    /// Input frames each performer sent, 1 ms apart in input time (played
    /// at the pace `pacing` names).
    pub input_frames: usize,
    /// Solves the stage thread published of the least solved puppet, from
    /// the first client's frame sequence numbers (it solves the newest
    /// state when inputs arrive faster than it solves, so this can be
    /// fewer than `input_frames`).
    pub solves: u64,
    /// Those solves per second, between that puppet's first and last frame.
    pub solves_per_s: f64,
    /// Median µs from an input frame reaching the daemon to a client
    /// holding the frame it caused, over every frame every client received.
    pub latency_us_p50: f64,
    /// 99th percentile of the same latencies, µs.
    pub latency_us_p99: f64,
    /// Stage-thread µs per solve applying commands (contacts to handles,
    /// pins, edits).
    pub commands_us: f64,
    /// Stage-thread µs per solve solving.
    pub solve_us: f64,
    /// Stage-thread µs per solve encoding the binary frames and waking the
    /// clients.
    pub frames_us: f64,
    /// Stage-thread µs per solve building the text messages that changed.
    pub messages_us: f64,
    /// Stage-thread µs per solve writing into a take being recorded.
    pub record_us: f64,
    /// A client task's send of what changed after a wake, on average, µs.
    pub send_us: f64,
    /// The stage thread's busy share of the replay's wall time (1.0 = busy
    /// throughout): its phases' clock time, the CPU's plus any time the
    /// thread was preempted inside a phase.
    pub stage_busy: f64,
    /// The stage thread's CPU share of the same wall time, from the
    /// kernel's accounting (10 ms ticks, so coarse on a short run).
    pub stage_cpu: f64,
}

/// CPU seconds the threads named `name` of this process have used (user
/// and system, from `/proc`), or 0 where that cannot be read.
fn thread_cpu_by_name(name: &str) -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    let ticks_per_second = 100.0;
    tasks
        .flatten()
        .filter(|task| {
            std::fs::read_to_string(task.path().join("comm")).is_ok_and(|comm| comm.trim() == name)
        })
        .filter_map(|task| std::fs::read_to_string(task.path().join("stat")).ok())
        .filter_map(|stat| {
            // Fields after the command's closing parenthesis: utime and
            // stime are the 12th and 13th.
            let rest = &stat[stat.rfind(')')? + 2..];
            let fields: Vec<&str> = rest.split_whitespace().collect();
            let user: f64 = fields.get(11)?.parse().ok()?;
            let system: f64 = fields.get(12)?.parse().ok()?;
            Some((user + system) / ticks_per_second)
        })
        .sum()
}

/// How the benches' viewers connect: with a small read buffer, because
/// tungstenite zero-fills its whole read buffer (128 KiB by default) before
/// every read, which would make the bench's own viewers, not the daemon,
/// most of the CPU being spent.
pub(crate) async fn connect_viewer(
    url: &str,
) -> Result<
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>,
    tokio_tungstenite::tungstenite::Error,
> {
    let config = tokio_tungstenite::tungstenite::protocol::WebSocketConfig::default()
        .read_buffer_size(16 * 1024);
    let (ws, _) = tokio_tungstenite::connect_async_with_config(url, Some(config), false).await?;
    Ok(ws)
}

/// What a bench viewer saw of the frames: latencies (µs) and each
/// vertices frame's (puppet, sequence, time of arrival).
type Seen = (Vec<f64>, Vec<(u32, u64, f64)>);

/// Connects a viewer to `url` and reads the stage message (its puppets
/// returned); the task it spawns reads the frames until a quiet spell,
/// timing each against the daemon's `started`.
async fn bench_viewer(
    url: &str,
    started: std::time::Instant,
) -> Result<
    (
        tokio::task::JoinHandle<Seen>,
        Vec<puppetry_daemon::protocol::PuppetDescription>,
    ),
    String,
> {
    use futures_util::{SinkExt, StreamExt};
    use puppetry_daemon::protocol::{ClientMessage, FrameHeader, FrameKind, Role, ServerMessage};
    use tokio_tungstenite::tungstenite::Message;
    let mut ws = connect_viewer(url).await.map_err(|e| e.to_string())?;
    let hello = ClientMessage::Hello {
        role: Role::Viewer,
        token: None,
    };
    let hello = serde_json::to_string(&hello).map_err(|e| e.to_string())?;
    ws.send(Message::text(hello))
        .await
        .map_err(|e| e.to_string())?;
    // The stage message, then the frames this client sees.
    let Some(Ok(Message::Text(stage))) = ws.next().await else {
        return Err("no stage message".into());
    };
    let stage: ServerMessage = serde_json::from_str(&stage).map_err(|e| e.to_string())?;
    let ServerMessage::Stage { puppets, .. } = stage else {
        return Err(format!("expected the stage message, got {stage:?}"));
    };
    let reader = tokio::spawn(async move {
        let mut latencies = Vec::new();
        let mut sequences = Vec::new();
        // Stop after a quiet spell: the replay is over and drained.
        while let Ok(Some(Ok(message))) =
            tokio::time::timeout(Duration::from_millis(500), ws.next()).await
        {
            if let Message::Binary(bytes) = message {
                let now = started.elapsed().as_secs_f64();
                let Ok(header) = FrameHeader::decode(&bytes) else {
                    continue;
                };
                let input = header.input_time;
                if header.kind == FrameKind::Vertices && input > 0.0 {
                    latencies.push((now - input) * 1e6);
                    sequences.push((header.puppet, header.sequence, now));
                }
            }
        }
        (latencies, sequences)
    });
    Ok((reader, puppets))
}

/// `input_frames` frames 1 ms apart of one source per entry of
/// `performers`, each holding a contact on every point it lists, all
/// circling (40 stage units across).
fn circling(performers: &[Vec<DVec2>], input_frames: usize) -> Vec<puppetry_input::ContactFrame> {
    use puppetry_input::{Contact, ContactFrame, Phase, SourceId};
    let sources: Vec<SourceId> = (0..performers.len())
        .map(|j| SourceId::new(format!("bench-{j}")))
        .collect();
    (0..input_frames)
        .flat_map(|k| {
            let phase = if k == 0 { Phase::Down } else { Phase::Move };
            let angle = k as f64 * 0.02;
            let offset = DVec2::new(angle.cos() - 1.0, angle.sin()) * 40.0;
            performers
                .iter()
                .zip(&sources)
                .map(move |(points, source)| ContactFrame {
                    source: source.clone(),
                    time: k as f64 * 1e-3,
                    contacts: (1..)
                        .zip(points)
                        .map(|(id, &point)| Contact::new(id, phase, point + offset))
                        .collect(),
                })
        })
        .collect()
}

/// Per puppet (of `puppets`), the solves between its first and last frame
/// in `sequences` and how many a second that was; the least solved puppet
/// speaks for the run.
fn least_solved(sequences: &[(u32, u64, f64)], puppets: u32) -> (u64, f64) {
    (0..puppets)
        .map(|puppet| {
            let mut of = sequences.iter().filter(|s| s.0 == puppet);
            match (of.next(), of.next_back()) {
                (Some(a), Some(b)) if b.2 > a.2 => (b.1 - a.1, (b.1 - a.1) as f64 / (b.2 - a.2)),
                _ => (0, 0.0),
            }
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or((0, 0.0))
}

/// Runs the daemon on `config`, connects `clients` viewers on loopback and
/// replays drags of `input_frames` frames (1 ms apart) into it with
/// `pacing`: one input source per entry of `performers`, each holding a
/// contact on every point it lists (stage units: a finger per puppet), all
/// circling. The daemon runs in this process on a runtime of its own (two
/// workers); errors come back as text.
pub async fn end_to_end(
    name: &str,
    config: &puppetry_daemon::config::ShowConfig,
    performers: &[Vec<DVec2>],
    clients: usize,
    input_frames: usize,
    pacing: puppetry_input::replay::Pacing,
) -> Result<EndToEndResult, String> {
    use puppetry_input::replay::{Pacing, ReplaySource};
    let pacing_name = match pacing {
        Pacing::RealTime => "real_time",
        Pacing::AsFastAsPossible => "as_fast_as_possible",
    };

    // The daemon gets a runtime of its own, as it would in its own
    // process: the viewers' reading here then competes with it for the
    // cores (as browsers on the same machine would), not for its tokio
    // workers and timer.
    let daemon_runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("daemon")
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?;
    let config = config.clone();
    let running = daemon_runtime
        .spawn(async move {
            puppetry_daemon::serve::start(
                &config,
                puppetry_daemon::stream::WebFiles::Embedded,
                None,
            )
            .await
        })
        .await
        .map_err(|e| e.to_string())?
        .map_err(|e| e.to_string())?;
    let started = running.started;
    let url = format!("ws://{}/ws", running.address);
    let mut readers = Vec::new();
    let (mut vertices, mut puppet_count) = (0, 0);
    for _ in 0..clients {
        let (reader, stage) = bench_viewer(&url, started).await?;
        vertices = stage.first().map_or(0, |p| p.rest.len() / 2);
        puppet_count = stage.len();
        readers.push(reader);
    }
    let frames = circling(performers, input_frames);
    let timings = running.timings();
    let stage_cpu_before = thread_cpu_by_name("stage");
    let playing = std::time::Instant::now();
    let running = daemon_runtime
        .spawn(async move {
            match pacing {
                // In real time the frames come from a thread of their own
                // that sleeps to each frame's time, as a device's events
                // come when they happen: a replay's tokio timer ticks in
                // whole milliseconds and would hand over two frames at once.
                Pacing::RealTime => {
                    let (sender, frames_rx) = tokio::sync::mpsc::channel(64);
                    let feeder = std::thread::spawn(move || feed_in_real_time(frames, &sender));
                    running.feed(frames_rx).await;
                    let _ = feeder.join();
                }
                Pacing::AsFastAsPossible => {
                    running
                        .play(ReplaySource::from_frames(frames), pacing)
                        .await;
                }
            }
            running
        })
        .await
        .map_err(|e| e.to_string())?;
    let mut latencies = Vec::new();
    let mut first_reader = None;
    for reader in readers {
        let (l, s) = reader.await.map_err(|e| e.to_string())?;
        latencies.extend(l);
        first_reader.get_or_insert(s);
    }
    let played = playing.elapsed().as_secs_f64();
    let stage_cpu = thread_cpu_by_name("stage") - stage_cpu_before;
    daemon_runtime
        .spawn(running.shutdown())
        .await
        .map_err(|e| e.to_string())?;
    // Its tasks are done; dropping a runtime here would block.
    daemon_runtime.shutdown_background();
    let load = |counter: &std::sync::atomic::AtomicU64| {
        counter.load(std::sync::atomic::Ordering::Relaxed) as f64
    };
    let t = &timings;
    let us_per_solve =
        |ns: &std::sync::atomic::AtomicU64| load(ns) / 1e3 / load(&t.solves).max(1.0);
    let stage_ns = [
        &t.commands_ns,
        &t.solve_ns,
        &t.frames_ns,
        &t.messages_ns,
        &t.record_ns,
    ]
    .into_iter()
    .map(load)
    .sum::<f64>();
    let (solves, solves_per_s) =
        least_solved(&first_reader.unwrap_or_default(), puppet_count as u32);
    latencies.sort_by(f64::total_cmp);
    if latencies.is_empty() {
        return Err("no frames reached the clients".into());
    }
    Ok(EndToEndResult {
        mesh: name.to_string(),
        vertices,
        puppets: puppet_count,
        performers: performers.len(),
        clients,
        pacing: pacing_name,
        input_frames,
        solves,
        solves_per_s,
        latency_us_p50: percentile(&latencies, 0.5),
        latency_us_p99: percentile(&latencies, 0.99),
        commands_us: us_per_solve(&t.commands_ns),
        solve_us: us_per_solve(&t.solve_ns),
        frames_us: us_per_solve(&t.frames_ns),
        messages_us: us_per_solve(&t.messages_ns),
        record_us: us_per_solve(&t.record_ns),
        send_us: load(&t.send_ns) / 1e3 / load(&t.sends).max(1.0),
        stage_busy: stage_ns / 1e9 / played.max(1e-9),
        stage_cpu: stage_cpu / played.max(1e-9),
    })
}

/// Sends each of `frames` when its time (from the first) has come, sleeping
/// the thread in between (to within the kernel's timer slack, about 50 µs).
fn feed_in_real_time(
    frames: Vec<puppetry_input::ContactFrame>,
    sender: &tokio::sync::mpsc::Sender<puppetry_input::ContactFrame>,
) {
    let start = std::time::Instant::now();
    let first = frames.first().map_or(0.0, |f| f.time);
    for frame in frames {
        let due = start + Duration::from_secs_f64((frame.time - first).max(0.0));
        if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
            std::thread::sleep(wait);
        }
        if sender.blocking_send(frame).is_err() {
            return;
        }
    }
}

/// The grid the rig cases use (the paper's size).
const RIG_GRID: (usize, usize) = (10, 10);

/// Vertex handles the lp-FFD cases drag.
const RIG_VERTEX_HANDLES: usize = 4;

/// One measured rig case, as printed by `puppetry bench --json` (tagged by
/// `"rig"`).
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "rig")]
pub enum RigResult {
    /// An lp-FFD case, from [`run_lp_ffd_case`].
    #[serde(rename = "lp-ffd")]
    LpFfd {
        /// The mesh's name, as in [`CaseResult::mesh`].
        mesh: String,
        /// The grid's basis: "bernstein" or "lattice".
        basis: &'static str,
        /// The timings, flattened into the same JSON object.
        #[serde(flatten)]
        bench: FfdBench,
    },
    /// A skeleton case, from [`run_skeleton_case`].
    #[serde(rename = "skeleton")]
    Skeleton(SkeletonBench),
}

/// An lp-FFD case: a 10×10 grid around `mesh` with `basis`, the paper's
/// weights and 4 vertex handles wandering, over `frames` frames.
pub fn run_lp_ffd_case(
    name: &str,
    mesh: &Mesh,
    basis: Basis,
    frames: usize,
) -> Result<RigResult, FfdError> {
    let spec = GridSpec::around(mesh, RIG_GRID.0, RIG_GRID.1, basis);
    let bench = ffd_bench(mesh, spec, LpParams::default(), RIG_VERTEX_HANDLES, frames)?;
    Ok(RigResult::LpFfd {
        mesh: name.to_string(),
        basis: match basis {
            Basis::Bernstein => "bernstein",
            Basis::Lattice => "lattice",
        },
        bench,
    })
}

/// A skeleton case: `skeleton` driving `mesh` with the paper's parameters
/// over `frames` frames.
pub fn run_skeleton_case(
    name: &str,
    mesh: &Mesh,
    skeleton: &Skeleton,
    frames: usize,
) -> Result<RigResult, SkeletonError> {
    let bench = skeleton_bench(name, mesh, skeleton, SkeletonParams::default(), frames)?;
    Ok(RigResult::Skeleton(bench))
}

/// The header of the rig table.
pub fn rig_table_header() -> String {
    format!(
        "{:<9} {:<20} {:>8} {:<34} {:>11} {:>13} {:>13} {:>13} {:>12}",
        "rig",
        "mesh",
        "vertices",
        "setup",
        "register ms",
        "frame µs p50",
        "frame µs p99",
        "frame µs min",
        "cpu µs p50"
    )
}

/// One row of the rig table.
pub fn rig_table_row(r: &RigResult) -> String {
    let (rig, mesh, vertices, setup, register, p50, p99, min, cpu) = match r {
        RigResult::LpFfd { mesh, basis, bench } => (
            "lp-FFD",
            mesh.as_str(),
            bench.vertices,
            format!(
                "{}×{} {basis}, {} handles, {} it",
                bench.grid_columns, bench.grid_rows, bench.vertex_handles, bench.iterations
            ),
            bench.register_ms,
            bench.update_us_median,
            bench.update_us_p99,
            bench.update_us_min,
            // The lp-FFD bench times wall clock only.
            "-".to_string(),
        ),
        RigResult::Skeleton(b) => (
            "skeleton",
            b.mesh.as_str(),
            b.vertices,
            format!("{} bones, {} stitches", b.bones, b.stitches),
            b.register_ms,
            b.update_us_median,
            b.update_us_p99,
            b.update_us_min,
            format!("{:.1}", b.update_cpu_us_median),
        ),
    };
    format!(
        "{rig:<9} {mesh:<20} {vertices:>8} {setup:<34} {register:>11.2} {p50:>13.1} {p99:>13.1} {min:>13.1} {cpu:>12}"
    )
}

/// Timings of the lp-FFD phases on one mesh. Every update time is 0 when
/// no frame was timed.
#[derive(Debug, Clone, Serialize)]
pub struct FfdBench {
    /// Vertices of the mesh.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Grid handles along x.
    pub grid_columns: usize,
    /// Grid handles along y.
    pub grid_rows: usize,
    /// Vertex handles dragged, spread evenly by vertex index.
    pub vertex_handles: usize,
    /// Local/global iterations per update (the paper's default in the rig
    /// cases).
    pub iterations: usize,
    /// Registration (`LpFfd::register`), ms, timed once.
    pub register_ms: f64,
    /// Compiling the vertex handles, µs, timed once.
    pub compile_us: f64,
    /// The fastest update, µs: the least disturbed by a shared machine.
    pub update_us_min: f64,
    /// Median update, µs.
    pub update_us_median: f64,
    /// 99th percentile of the updates, µs.
    pub update_us_p99: f64,
    /// Update frames timed.
    pub frames: usize,
    /// After the last frame: `(E − E*)/E*`, with `E*` the energy after 200
    /// more iterations on the same targets — how far the warm-started
    /// per-frame iterations trail the converged solution.
    pub energy_gap: f64,
}

/// Times `frames` updates of an lp-FFD rig over `mesh` with
/// `vertex_handles` vertex handles (spread by index) wandering on small
/// circles, like the ARAP bench's handles.
fn ffd_bench(
    mesh: &Mesh,
    spec: GridSpec,
    params: LpParams,
    vertex_handles: usize,
    frames: usize,
) -> Result<FfdBench, FfdError> {
    let start = Instant::now();
    let mut rig = LpFfd::register(mesh, spec, params)?;
    let register_ms = start.elapsed().as_secs_f64() * 1e3;
    let n = mesh.vertices().len();
    let spacing = n / vertex_handles.max(1);
    let chosen: Vec<usize> = (0..vertex_handles)
        .map(|h| (h * spacing + spacing / 2).min(n - 1))
        .collect();
    let anchors: Vec<Anchor> = chosen.iter().map(|&v| Anchor::Vertex(v as u32)).collect();
    let rest: Vec<DVec2> = chosen.iter().map(|&v| mesh.vertices()[v]).collect();
    let start = Instant::now();
    rig.compile(&anchors, &[])?;
    let compile_us = start.elapsed().as_secs_f64() * 1e6;
    let size = mesh.size();
    let mut targets = rest.clone();
    let mut times = Vec::with_capacity(frames);
    for f in 0..frames {
        let t = f as f64 * 0.05;
        for (h, (o, r)) in targets.iter_mut().zip(&rest).enumerate() {
            let phase = t + h as f64 * 1.3;
            *o = *r + DVec2::new(phase.cos(), phase.sin()) * (0.03 * size);
        }
        let start = Instant::now();
        rig.update(&targets, &[])?;
        times.push(start.elapsed().as_secs_f64() * 1e6);
    }
    times.sort_by(f64::total_cmp);
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    let energy = rig.energy(rig.grid(), &targets, &[])?;
    // The same rig run on to convergence from where the frames left it.
    rig.set_iterations(200);
    rig.update(&targets, &[])?;
    let best = rig.energy(rig.grid(), &targets, &[])?;
    Ok(FfdBench {
        vertices: n,
        triangles: mesh.triangles().len(),
        grid_columns: spec.columns,
        grid_rows: spec.rows,
        vertex_handles,
        iterations: params.iterations,
        register_ms,
        compile_us,
        update_us_min: if times.is_empty() { 0.0 } else { at(0.0) },
        update_us_median: if times.is_empty() { 0.0 } else { at(0.5) },
        update_us_p99: if times.is_empty() { 0.0 } else { at(0.99) },
        frames,
        energy_gap: if best > 0.0 {
            (energy - best) / best
        } else {
            0.0
        },
    })
}

/// One measured skeleton case.
#[derive(Debug, Clone, Serialize)]
pub struct SkeletonBench {
    /// The mesh's name, as in [`CaseResult::mesh`].
    pub mesh: String,
    /// Vertices of the mesh.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Bones of the skeleton (15 for the demo's gingerbread).
    pub bones: usize,
    /// Stitches per frame (`rounds + 1`).
    pub stitches: usize,
    /// Entries of the stitching factor: its memory and per-stitch work.
    pub factor_entries: usize,
    /// Registration (`ShapeAware::register`), ms: the median of 3 runs.
    pub register_ms: f64,
    /// Median whole frame, µs: bone transforms and every propagation round.
    pub update_us_median: f64,
    /// 99th percentile of the frames, µs.
    pub update_us_p99: f64,
    /// The median frame in this thread's CPU time, µs: on a shared machine,
    /// the cost without the time other processes held the core.
    pub update_cpu_us_median: f64,
    /// 99th percentile of the frames' CPU time, µs.
    pub update_cpu_us_p99: f64,
    /// The fastest frame, µs: the least disturbed by a shared machine.
    pub update_us_min: f64,
    /// Frames timed (at least 1).
    pub frames: usize,
}

/// CPU time this thread has used.
fn thread_cpu_seconds() -> f64 {
    let mut now = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `now` is a valid timespec for the call to fill.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut now) };
    now.tv_sec as f64 + now.tv_nsec as f64 * 1e-9
}

/// Times registration and `frames` FK-animated frames (every bone swinging
/// on its own phase) of `skeleton` driving `mesh`.
fn skeleton_bench(
    name: &str,
    mesh: &Mesh,
    skeleton: &Skeleton,
    params: SkeletonParams,
    frames: usize,
) -> Result<SkeletonBench, SkeletonError> {
    let mut register_times = Vec::new();
    let mut deformer = None;
    for _ in 0..3 {
        let start = Instant::now();
        let d = ShapeAware::register(mesh, skeleton.clone(), params)?;
        register_times.push(start.elapsed().as_secs_f64() * 1e3);
        deformer = Some(d);
    }
    let mut deformer = deformer.expect("registered");
    register_times.sort_by(f64::total_cmp);
    let rest = skeleton.rest_pose();
    let mut pose = rest.clone();
    let mut joints = vec![DVec2::ZERO; skeleton.joints().len()];
    let mut times = Vec::with_capacity(frames);
    let mut cpu_times = Vec::with_capacity(frames);
    for frame in 0..frames.max(1) {
        let t = frame as f64 * 0.05;
        for (bone, angle) in pose.angles.iter_mut().enumerate() {
            *angle = rest.angles[bone] + 0.35 * (t + bone as f64 * 0.9).sin();
        }
        skeleton.joints_into(&pose, &mut joints)?;
        let (start, cpu_start) = (Instant::now(), thread_cpu_seconds());
        deformer.update(&joints)?;
        times.push(start.elapsed().as_secs_f64() * 1e6);
        cpu_times.push((thread_cpu_seconds() - cpu_start) * 1e6);
    }
    times.sort_by(f64::total_cmp);
    cpu_times.sort_by(f64::total_cmp);
    let percentile =
        |sorted: &[f64], q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
    let at = |q: f64| percentile(&times, q);
    Ok(SkeletonBench {
        mesh: name.to_string(),
        vertices: mesh.vertices().len(),
        triangles: mesh.triangles().len(),
        bones: skeleton.bones().len(),
        stitches: params.rounds + 1,
        factor_entries: deformer.factor_entries(),
        register_ms: register_times[1],
        update_us_median: at(0.5),
        update_us_p99: at(0.99),
        update_cpu_us_median: percentile(&cpu_times, 0.5),
        update_cpu_us_p99: percentile(&cpu_times, 0.99),
        update_us_min: times[0],
        frames: times.len(),
    })
}

/// One depth case, as printed by `puppetry bench --depth --json`: the depth
/// order's frames beside the ARAP updates that produced the same poses.
#[derive(Debug, Clone, Serialize)]
pub struct DepthResult {
    /// The mesh's name, as in [`CaseResult::mesh`].
    pub mesh: String,
    /// Vertices of the mesh.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Registering the depth order (`DepthOrder::register`), ms, timed once.
    pub register_ms: f64,
    /// Median ARAP update (3 handles) over every frame, the ramp between
    /// the phases included, µs.
    pub arap_us_median: f64,
    /// Mean of the same updates, µs: what the table's `mean/arap` divides by.
    pub arap_us_mean: f64,
    /// 99th percentile of the same updates, µs.
    pub arap_us_p99: f64,
    /// Median depth frame while the handles wander without any overlap, µs.
    pub flat_us_median: f64,
    /// 99th percentile of those frames, µs.
    pub flat_us_p99: f64,
    /// Median depth frame while a foot is held folded over the body, µs.
    pub fold_us_median: f64,
    /// Mean of those frames, µs.
    pub fold_us_mean: f64,
    /// 99th percentile of those frames, µs.
    pub fold_us_p99: f64,
    /// Fold frames on which triangles overlapped.
    pub fold_frames_overlapping: usize,
    /// Median overlapping pairs listed per fold frame (frames the sheets
    /// settle list none).
    pub fold_pairs_median: usize,
    /// Median triangles in the middle sheet per fold frame (0 on frames
    /// the sheets do not settle).
    pub fold_middle_median: usize,
    /// Fold frames settled by the sheets of an earlier exact frame (see
    /// `docs/depth.md`, "Sheets").
    pub fold_frames_certified: usize,
    /// Of the fold frames the sheets settled, those that first widened the
    /// middle sheet.
    pub fold_frames_widened: usize,
    /// No-overlap frames that tested all triangles (more than 32 inverted
    /// triangles, or a piece inside another) instead of growing from
    /// boundary crossings.
    pub flat_frames_scanning_all: usize,
    /// Fold frames that tested all triangles.
    pub fold_frames_scanning_all: usize,
    /// Frames of the no-overlap phase on which an overlap was found all the
    /// same: a check that the phase is what it says.
    pub flat_frames_overlapping: usize,
    /// Frames of the no-overlap phase settled by the motion bound alone.
    pub flat_frames_skipped: usize,
    /// Frames of each phase, no-overlap and fold (the 60-frame ramp between
    /// them is not counted).
    pub frames: usize,
}

/// One timed depth frame of [`run_depth_case`] and what the order said of it.
struct DepthFrame {
    took: f64,
    overlapped: bool,
    pairs: usize,
    middle: usize,
    scanned_all: bool,
    skipped: bool,
    certified: bool,
    widened: bool,
}

/// Why a depth case could not run.
#[derive(Debug, thiserror::Error)]
pub enum DepthBenchError {
    /// The ARAP solver posing the mesh refused it, its handles or a frame.
    #[error(transparent)]
    Solve(#[from] ArapError),
    /// The depth order refused the mesh or a pose.
    #[error(transparent)]
    Depth(#[from] DepthError),
}

/// Times the depth order on `mesh` posed by ARAP with three handles: the
/// top (held), the middle (held) and the lowest vertex right of the middle
/// (a foot). First `frames` frames wander without overlap, then the foot is
/// dragged up over the body and `frames` frames wiggle it there.
pub fn run_depth_case(
    name: &str,
    mesh: &Mesh,
    frames: usize,
) -> Result<DepthResult, DepthBenchError> {
    let rest = mesh.vertices();
    let centre = rest.iter().sum::<DVec2>() / rest.len() as f64;
    let nearest = |p: DVec2| {
        (0..rest.len())
            .min_by(|&a, &b| rest[a].distance(p).total_cmp(&rest[b].distance(p)))
            .unwrap_or(0)
    };
    let top = (0..rest.len())
        .max_by(|&a, &b| rest[a].y.total_cmp(&rest[b].y))
        .unwrap_or(0);
    let middle = nearest(centre);
    let foot = (0..rest.len())
        .filter(|&v| rest[v].x > centre.x)
        .min_by(|&a, &b| rest[a].y.total_cmp(&rest[b].y))
        .unwrap_or(0);
    let chosen = [top, middle, foot];
    let anchors: Vec<Anchor> = chosen.iter().map(|&v| Anchor::Vertex(v as u32)).collect();
    let held: Vec<DVec2> = chosen.iter().map(|&v| rest[v]).collect();
    let mut arap = Arap::register(mesh)?;
    arap.compile(&anchors)?;
    let start = Instant::now();
    let mut depth = DepthOrder::register(mesh, None)?;
    let register_ms = start.elapsed().as_secs_f64() * 1e3;
    let size = mesh.size();

    let mut arap_times = Vec::with_capacity(2 * frames);
    let mut frame = |targets: &[DVec2],
                     arap: &mut Arap,
                     depth: &mut DepthOrder|
     -> Result<DepthFrame, DepthBenchError> {
        let start = Instant::now();
        arap.update(targets, Steps::Both)?;
        arap_times.push(micros(start.elapsed()));
        let start = Instant::now();
        depth.update(arap.pose())?;
        let took = micros(start.elapsed());
        Ok(DepthFrame {
            took,
            overlapped: depth.overlapped(),
            pairs: depth.overlap_pairs(),
            middle: depth.middle_triangles(),
            scanned_all: depth.scanned_all(),
            skipped: depth.skipped(),
            certified: depth.certified(),
            widened: depth.widened(),
        })
    };
    let mut targets = held.clone();
    let mut flat = Vec::with_capacity(frames);
    let (mut flat_scanning, mut flat_overlapping, mut flat_skipped) = (0, 0, 0);
    for f in 0..frames {
        animate(&held, size * 0.3, f, &mut targets);
        let f = frame(&targets, &mut arap, &mut depth)?;
        flat.push(f.took);
        flat_skipped += usize::from(f.skipped);
        flat_overlapping += usize::from(f.overlapped);
        flat_scanning += usize::from(f.scanned_all);
    }
    // The foot dragged up to the body's middle, a little above it.
    let over = centre + DVec2::new(-0.05, 0.1) * size;
    let ramp = 60;
    for f in 0..ramp {
        let along = (f + 1) as f64 / ramp as f64;
        targets = held.clone();
        targets[2] = held[2].lerp(over, along);
        frame(&targets, &mut arap, &mut depth)?;
    }
    let mut fold = Vec::with_capacity(frames);
    let mut pairs = Vec::with_capacity(frames);
    let mut middle = Vec::with_capacity(frames);
    let (mut overlapping, mut fold_scanning, mut certified, mut widened) = (0, 0, 0, 0);
    for f in 0..frames {
        let t = f as f64 * 0.05;
        targets[2] = over + DVec2::new(t.cos(), t.sin()) * (0.02 * size);
        let f = frame(&targets, &mut arap, &mut depth)?;
        certified += usize::from(f.certified);
        widened += usize::from(f.widened);
        fold.push(f.took);
        pairs.push(f.pairs);
        middle.push(f.middle);
        overlapping += usize::from(f.overlapped);
        fold_scanning += usize::from(f.scanned_all);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let (arap_mean, fold_mean) = (mean(&arap_times), mean(&fold));
    for v in [&mut arap_times, &mut flat, &mut fold] {
        v.sort_by(f64::total_cmp);
    }
    pairs.sort_unstable();
    middle.sort_unstable();
    Ok(DepthResult {
        mesh: name.to_string(),
        vertices: rest.len(),
        triangles: mesh.triangles().len(),
        register_ms,
        arap_us_median: percentile(&arap_times, 0.5),
        arap_us_mean: arap_mean,
        arap_us_p99: percentile(&arap_times, 0.99),
        flat_us_median: percentile(&flat, 0.5),
        flat_us_p99: percentile(&flat, 0.99),
        fold_us_median: percentile(&fold, 0.5),
        fold_us_mean: fold_mean,
        fold_us_p99: percentile(&fold, 0.99),
        fold_frames_overlapping: overlapping,
        fold_pairs_median: pairs[pairs.len() / 2],
        fold_middle_median: middle[middle.len() / 2],
        fold_frames_certified: certified,
        fold_frames_widened: widened,
        flat_frames_scanning_all: flat_scanning,
        flat_frames_skipped: flat_skipped,
        fold_frames_scanning_all: fold_scanning,
        flat_frames_overlapping: flat_overlapping,
        frames,
    })
}

/// The header of the depth table.
pub fn depth_table_header() -> String {
    format!(
        "{:<20} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} {:>10} {:>9}",
        "mesh",
        "vertices",
        "arap p50",
        "arap p99",
        "flat p50",
        "flat p99",
        "fold p50",
        "fold mean",
        "fold p99",
        "mean/arap",
        "p99/arap",
        "overlaps"
    )
}

/// One row of the depth table (µs; ratios to the ARAP update's mean and
/// median).
pub fn depth_table_row(r: &DepthResult) -> String {
    format!(
        "{:<20} {:>8} {:>9.1} {:>9.1} {:>9.2} {:>9.2} {:>9.1} {:>9.1} {:>9.1} {:>10.0}% {:>9.0}% {:>4}/{:<4}",
        r.mesh,
        r.vertices,
        r.arap_us_median,
        r.arap_us_p99,
        r.flat_us_median,
        r.flat_us_p99,
        r.fold_us_median,
        r.fold_us_mean,
        r.fold_us_p99,
        100.0 * r.fold_us_mean / r.arap_us_mean,
        100.0 * r.fold_us_p99 / r.arap_us_median,
        r.fold_frames_overlapping,
        r.frames
    )
}

/// One measured curve case, as printed by `puppetry bench --curves --json`.
#[derive(Debug, Clone, Serialize)]
pub struct CurveBench {
    /// Points of the wavy curve (about 1 apart).
    pub points: usize,
    /// Handles held: the two ends, and the middle when 3.
    pub handles: usize,
    /// Registration (`Curve::register`), ms: the median of 5 runs.
    pub register_ms: f64,
    /// Median compile of the handles with the whole curve free (both
    /// steps), over 20 runs, µs.
    pub compile_us_median: f64,
    /// Median update (both steps) while the handles circle, µs.
    pub update_us_median: f64,
    /// 99th percentile of the same updates, µs.
    pub update_us_p99: f64,
    /// Median recompile when a peeling drag's region grew (every region
    /// size up to the whole curve), µs.
    pub peel_change_us_median: f64,
    /// 99th percentile of those recompiles, µs.
    pub peel_change_us_p99: f64,
    /// Median update during the peeling drags, between the recompiles, µs.
    pub peel_update_us_median: f64,
    /// Recompiles timed over all the peeling drags.
    pub peel_changes: usize,
    /// Plain update frames timed.
    pub frames: usize,
}

/// A wavy curve of `points` points, evenly spaced (about 1 apart).
fn bench_curve(points: usize) -> Vec<DVec2> {
    (0..points)
        .map(|i| {
            let x = i as f64 * 0.8;
            DVec2::new(x, 8.0 * (x * 0.05).sin())
        })
        .collect()
}

/// Times a curve of `points` points with `handles` (2 or 3: the ends, and
/// the middle) over `frames` frames, then `drags` peeling drags from the
/// middle until the region covers the curve.
pub fn curve_bench(
    points: usize,
    handles: usize,
    frames: usize,
    drags: usize,
) -> Result<CurveBench, CurveError> {
    let rest = bench_curve(points);
    let mut register = Vec::new();
    let mut curve = None;
    for _ in 0..5 {
        let start = Instant::now();
        curve = Some(Curve::register(&rest)?);
        register.push(start.elapsed().as_secs_f64() * 1e3);
    }
    register.sort_by(f64::total_cmp);
    let mut curve = curve.expect("registered");
    let last = points as u32 - 1;
    let mut anchors = vec![CurveAnchor::Point(0), CurveAnchor::Point(last)];
    if handles >= 3 {
        anchors.insert(
            1,
            CurveAnchor::Along {
                segment: last / 2,
                t: 0.5,
            },
        );
    }
    let rest_targets: Vec<DVec2> = anchors
        .iter()
        .map(|a| curve.rest_point(*a).expect("anchors on the curve"))
        .collect();
    let mut targets = rest_targets.clone();

    let mut compile = Vec::new();
    for _ in 0..20 {
        let start = Instant::now();
        curve.compile(&anchors)?;
        compile.push(micros(start.elapsed()));
    }
    compile.sort_by(f64::total_cmp);
    let mut update = Vec::with_capacity(frames);
    for f in 0..frames {
        let phase = f as f64 * 0.05;
        for (h, (t, r)) in targets.iter_mut().zip(&rest_targets).enumerate() {
            *t = *r + DVec2::new((phase + h as f64).cos(), (phase + h as f64).sin()) * 3.0;
        }
        let start = Instant::now();
        curve.update(&targets, Steps::Both)?;
        update.push(micros(start.elapsed()));
    }
    update.sort_by(f64::total_cmp);

    // Peeling: grab the middle and pull sideways until the region covers
    // the curve; each drag starts again from rest.
    let (mut changes, mut peel_updates) = (Vec::new(), Vec::new());
    let params = PeelParams {
        initial_radius: 5.0,
        growth_rate: 2.0,
    };
    for _ in 0..drags {
        let mut curve = Curve::register(&rest)?;
        let mut peel = Peel::new(&curve, curve.length() / 2.0, &[], params)?;
        let grab = [peel.grab_anchor()];
        let from = curve.rest_point(grab[0]).expect("on the curve");
        curve.compile_within(&grab, peel.free_points())?;
        let reach = curve.length() / 2.0 / params.growth_rate;
        let steps = 200;
        for s in 1..=steps {
            let target = from + DVec2::new(0.0, reach * s as f64 / steps as f64);
            if peel.drag(&curve, target.distance(from))? {
                let start = Instant::now();
                curve.compile_within(&grab, peel.free_points())?;
                changes.push(micros(start.elapsed()));
            }
            let start = Instant::now();
            curve.update(&[target], Steps::Both)?;
            peel_updates.push(micros(start.elapsed()));
        }
    }
    changes.sort_by(f64::total_cmp);
    peel_updates.sort_by(f64::total_cmp);
    Ok(CurveBench {
        points,
        handles: anchors.len(),
        register_ms: percentile(&register, 0.5),
        compile_us_median: percentile(&compile, 0.5),
        update_us_median: percentile(&update, 0.5),
        update_us_p99: percentile(&update, 0.99),
        peel_change_us_median: percentile(&changes, 0.5),
        peel_change_us_p99: percentile(&changes, 0.99),
        peel_update_us_median: percentile(&peel_updates, 0.5),
        peel_changes: changes.len(),
        frames,
    })
}

/// The header of the curve table.
pub fn curve_table_header() -> String {
    format!(
        "{:>7} {:>7} {:>11} {:>12} {:>13} {:>13} {:>15} {:>15} {:>14}",
        "points",
        "handles",
        "register ms",
        "compile µs",
        "update µs p50",
        "update µs p99",
        "peel change p50",
        "peel change p99",
        "peel update p50"
    )
}

/// One row of the curve table.
pub fn curve_table_row(r: &CurveBench) -> String {
    format!(
        "{:>7} {:>7} {:>11.3} {:>12.1} {:>13.1} {:>13.1} {:>15.1} {:>15.1} {:>14.1}",
        r.points,
        r.handles,
        r.register_ms,
        r.compile_us_median,
        r.update_us_median,
        r.update_us_p99,
        r.peel_change_us_median,
        r.peel_change_us_p99,
        r.peel_update_us_median
    )
}
