//! The `puppetry` command line: the arguments (one `clap::Args` struct per
//! command), one short function per command that hands its arguments to
//! the library (`puppetry::cli` and below, where the work is), and error
//! reporting.

use puppetry_export::format::Format;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use puppetry::cli;
use puppetry_bench::{bench, compare};

#[derive(Parser)]
#[command(
    name = "puppetry",
    version,
    about = "Realtime 2D puppetry: meshing, as-rigid-as-possible deformation"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the daemon: inputs to handles, the solver at the input rate, and
    /// the web renderer and WebSocket stream on one port. Without --config,
    /// serves the bundled demo stage.
    Serve(ServeArgs),
    /// Serve a daemon's stage to viewers from NATS (the daemon's stage file
    /// has `[relay] nats = "…"`): the same web page and protocol, on any
    /// machine; remote performers' messages go to the daemon, which checks
    /// them as it checks direct ones (docs/scaling.md).
    Relay(RelayArgs),
    /// Run the daemon (and with --relay a nats-server and a relay) under a
    /// show's churn on loopback for a set time, printing memory, open
    /// descriptors, frames/s and p99 latency; exits 1 unless memory and
    /// descriptors stay flat after the warm-up. Not in CI: run it before a
    /// release.
    Soak(SoakArgs),
    /// Export a take: glb (glTF 2.0 binary, morph-target chunks), png (a
    /// sequence, rendered here), mp4 (H.264), mov (ProRes 4444 with
    /// alpha), webm (VP9 with alpha) — videos through ffmpeg — or spine
    /// (Spine 4.x JSON with a deform timeline).
    Export(ExportArgs),
    /// List the takes in a folder: name, length, steps, frames, how each
    /// ended. With --verify, replay each into the stage (--config, default
    /// the bundled demo) and check its frames bit for bit.
    Takes(TakesArgs),
    /// Build a triangle mesh from a PNG (traced from its alpha channel) or a
    /// polygon JSON file; writes `.mesh.json` (see docs/mesh-format.md).
    Mesh(MeshArgs),
    /// Deform a mesh by handles and print {"vertices": [[x, y], …]}.
    Solve(SolveArgs),
    /// List the input devices this machine has (name, path, kind, ids, axes
    /// and ranges), its raw MIDI ports, and which entry of a stage file
    /// would use each.
    Devices(DevicesArgs),
    /// Capture a device's raw events to an evemu file (play it back with
    /// `serve --replay FILE` or a `kind = "replay"` input).
    Record(RecordArgs),
    /// Make a `corners` calibration from a capture of four taps on the marks
    /// the web page shows at `/?calibrate` (see docs/calibration.md).
    Calibrate(CalibrateArgs),
    /// Time ARAP updates on a given mesh, handle vertices and per-frame
    /// targets, to compare with another solver on the same problem (see
    /// benches/peers/README.md). Prints one JSON line.
    BenchCase(BenchCaseArgs),
    /// The lp-FFD paper's comparison (its Table 1): direct FFD (Hsu et al.),
    /// ARAP followed by inverse FFD, plain ARAP and lp-FFD on one layered
    /// figure, one grid and one set of vertex handles; prints the mean
    /// angular and area distortion of each (see docs/measures.md).
    Compare(CompareArgs),
    /// Time registration, compilation, updates and handle changes of the
    /// ARAP solver, then whole frames of the two rigs (lp-FFD on a 10×10
    /// grid, the 15-bone skeleton).
    Bench(BenchArgs),
}

#[derive(clap::Args)]
struct ServeArgs {
    /// Stage file (TOML, see config/). Default: the bundled demo stage,
    /// compiled into the binary.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Also play this recording (.jsonl) or evemu capture (.event).
    #[arg(long)]
    replay: Option<PathBuf>,
    /// Play --replay as fast as possible instead of in real time.
    #[arg(long)]
    fast: bool,
    /// Listen here instead of the stage file's address: HOST:PORT
    /// (localhost:8080, 192.168.1.20:8080, 0.0.0.0:8080 for every
    /// interface, [::1]:8080) or a port alone (on 127.0.0.1, this
    /// machine only).
    #[arg(long, value_name = "ADDR", value_parser = cli::parse_listen)]
    listen: Option<std::net::SocketAddr>,
    /// Serve the web client from this folder instead of the copy
    /// compiled into the binary (for client development).
    #[arg(long)]
    web_root: Option<PathBuf>,
    /// Record a take into this folder from the first input to shutdown
    /// (and list and play takes from it).
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
    /// Where takes are recorded, listed and played from (default
    /// ./takes; --record sets it too).
    #[arg(long, value_name = "DIR", conflicts_with = "record")]
    takes: Option<PathBuf>,
    /// Play this take (.take) into the stage at start (with --fast, as
    /// fast as the stage takes it).
    #[arg(long, value_name = "TAKE")]
    play: Option<PathBuf>,
    /// Start the stage file's replay inputs paused: a director plays
    /// them from the page (a `replay` message).
    #[arg(long)]
    no_replay: bool,
    /// Where pictures a director adds from the page are kept, with
    /// their meshes and placements (default ./puppets); they come back
    /// on stage when the daemon starts again.
    #[arg(long, value_name = "DIR")]
    puppets: Option<PathBuf>,
}

#[derive(clap::Args)]
struct RelayArgs {
    /// The NATS server the daemon publishes to, with this relay's
    /// credentials: nats://USER:PASSWORD@HOST:PORT, or nats://USER@HOST:PORT
    /// and the password in PUPPETRY_NATS_PASSWORD (docs/scaling.md).
    #[arg(long, value_name = "URL")]
    nats: String,
    /// The stage's name on NATS: `[relay].stage`, or the daemon's stage
    /// file name without `.toml`.
    #[arg(long)]
    stage: String,
    /// Serve viewers here: HOST:PORT or a port alone (on 127.0.0.1).
    #[arg(long, default_value = "127.0.0.1:8090", value_name = "ADDR",
          value_parser = cli::parse_listen)]
    listen: std::net::SocketAddr,
    /// This relay's name (letters, digits, - and _): remote performers
    /// are `relay:<name>:<n>` on the stage. Default: the NATS user, or
    /// relay-<pid> without one.
    #[arg(long)]
    name: Option<String>,
    /// Serve the web client from this folder instead of the copy
    /// compiled into the binary.
    #[arg(long)]
    web_root: Option<PathBuf>,
    /// Open connections at most.
    #[arg(long, default_value_t = 4096)]
    max_connections: usize,
    /// Clients that stop reading are dropped after this many seconds.
    #[arg(long, default_value_t = 10.0)]
    client_timeout: f64,
}

#[derive(clap::Args)]
struct SoakArgs {
    /// How long to run.
    #[arg(long, default_value_t = 30.0)]
    minutes: f64,
    /// Seconds between rows.
    #[arg(long, default_value_t = 60.0)]
    every: f64,
    /// Viewers connected at once, each connecting, reading, stalling
    /// and dropping in turn.
    #[arg(long, default_value_t = 40)]
    viewers: usize,
    /// Also through the relay tier (needs nats-server).
    #[arg(long)]
    relay: bool,
    /// Also loop this device capture (evemu .event) or recording
    /// (.jsonl) on the stage.
    #[arg(long, value_name = "FILE")]
    capture: Option<PathBuf>,
}

#[derive(clap::Args)]
struct ExportArgs {
    take: PathBuf,
    #[arg(long, ignore_case = true)]
    format: FormatArg,
    /// The stage file the take was recorded on (default: the one its
    /// header names, or the bundled stage file of that name).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Frames per second (29.97, 23.976 and 59.94 reach videos as
    /// 30000/1001, 24000/1001 and 60000/1001).
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Seconds into the take (default: its start).
    #[arg(long)]
    from: Option<f64>,
    /// Seconds into the take (default: its end).
    #[arg(long)]
    to: Option<f64>,
    /// Picture size of png and video exports.
    #[arg(long, default_value = "1280x720", value_parser = parse_size)]
    size: (u32, u32),
    /// The file to write (a folder for png). Files already there are
    /// never replaced without --force.
    #[arg(short, long)]
    output: PathBuf,
    /// Replace files already where the export writes.
    #[arg(long)]
    force: bool,
    /// Export what is intact of a damaged take (otherwise refused, naming
    /// the damage), saying what was kept.
    #[arg(long)]
    salvage: bool,
    /// A soundtrack to mux into a video (mp4, mov, webm): any sound file
    /// ffmpeg reads.
    #[arg(long, value_name = "FILE")]
    audio: Option<PathBuf>,
    /// Seconds into the soundtrack at the take's start (negative: the
    /// sound begins that long after it). Without it, the soundtrack lines
    /// up by the show clock the take recorded (MIDI Time Code, MIDI clock,
    /// OSC time), or starts with the take if it heard none.
    #[arg(long, value_name = "S", requires = "audio", allow_hyphen_values = true)]
    audio_offset: Option<f64>,
    /// The show clock's time, in seconds, at the soundtrack's first sample
    /// (a session starting at 01:00:00:00 is 3600).
    #[arg(
        long,
        value_name = "S",
        default_value_t = 0.0,
        requires = "audio",
        conflicts_with = "audio_offset",
        allow_hyphen_values = true
    )]
    audio_start: f64,
}

#[derive(clap::Args)]
struct TakesArgs {
    dir: PathBuf,
    #[arg(long)]
    verify: bool,
    #[arg(long)]
    config: Option<PathBuf>,
}

#[derive(clap::Args)]
struct MeshArgs {
    /// A .png picture or a .json polygon.
    input: PathBuf,
    /// Target vertex count; the result lands within ±15% unless the outline
    /// itself needs more (many islands, thin parts) or fewer. Default: about
    /// 1000, fewer for tiny shapes.
    #[arg(long, value_parser = clap::value_parser!(u32).range(3..=2_000_000))]
    vertices: Option<u32>,
    /// Output file, replaced if it exists; `-` for standard output.
    /// Default: NAME.mesh.json beside the input (PICTURE.png gives
    /// PICTURE.mesh.json), never replacing a file that is there.
    #[arg(short, long, value_name = "OUT.mesh.json")]
    output: Option<PathBuf>,
    /// Join a picture's pieces (islands of opaque pixels) across gaps up to
    /// this many pixels, so they move as one; without it each moves on its
    /// own, and a picture of the pieces is written beside the mesh.
    #[arg(long, value_name = "PIXELS")]
    join: Option<f64>,
}

#[derive(clap::Args)]
struct SolveArgs {
    /// The rest mesh (.mesh.json, see docs/mesh-format.md).
    #[arg(long)]
    mesh: PathBuf,
    /// {"handles": [{"vertex": i, "to": [x, y]} | {"point": [x, y], "to": [x, y]}, …]}
    #[arg(long)]
    handles: PathBuf,
    /// Print the scale-free intermediate result of step 1.
    #[arg(long)]
    step1_only: bool,
    /// Also draw the rest and deformed meshes to this SVG file.
    #[arg(long)]
    svg: Option<PathBuf>,
}

#[derive(clap::Args)]
struct DevicesArgs {
    /// Where device nodes are (or a folder of evemu captures).
    #[arg(long, default_value = puppetry_input::device::DEFAULT_DIR)]
    dir: PathBuf,
    /// Show which of this stage file's inputs would take each device.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Where ALSA's raw MIDI ports are (`midiC<card>D<device>`).
    #[arg(long, default_value = puppetry_input::midi_port::DEFAULT_SND_DIR)]
    midi_dir: PathBuf,
}

#[derive(clap::Args)]
struct RecordArgs {
    /// The device node, e.g. /dev/input/event5 or a /dev/input/by-id link;
    /// or a raw MIDI port (/dev/snd/midiC1D0, a FIFO) recorded to a .mid.
    device: PathBuf,
    /// The capture to write: .event for an input device, .mid for a MIDI
    /// port.
    #[arg(short, long)]
    output: PathBuf,
    /// Stop after this many seconds (default: at Ctrl-C).
    #[arg(long)]
    duration: Option<f64>,
    /// Take the device exclusively while recording.
    #[arg(long)]
    grab: bool,
}

#[derive(clap::Args)]
struct CalibrateArgs {
    /// The capture (`puppetry record DEVICE -o taps.event`).
    capture: PathBuf,
    /// The stage file whose stage the marks were on.
    #[arg(long)]
    config: PathBuf,
    /// How far in from the stage's edges the marks are, as a fraction
    /// of its size (the page's `?calibrate=` value).
    #[arg(long, default_value_t = 0.1)]
    inset: f64,
}

#[derive(clap::Args)]
struct BenchCaseArgs {
    /// {"mesh": "<.mesh.json, relative to this file>", "handles":
    /// [vertex, …], "frames": [[[x, y] per handle], …]}
    case: PathBuf,
    /// Write every frame's pose here as little-endian f64 x, y pairs.
    #[arg(long)]
    poses: Option<PathBuf>,
}

#[derive(clap::Args)]
struct CompareArgs {
    /// Grid handles, COLUMNSxROWS.
    #[arg(long, default_value = "10x10", value_name = "COLUMNSxROWS", value_parser = cli::parse_grid)]
    grid: (usize, usize),
    /// Run on this mesh (.mesh.json) instead of the bundled layered figure.
    #[arg(long, requires = "handles")]
    mesh: Option<PathBuf>,
    /// The vertex handles and targets for --mesh (the `solve` format).
    #[arg(long, requires = "mesh")]
    handles: Option<PathBuf>,
    /// One JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Also draw each method's result to DIR/<method>.svg.
    #[arg(long, value_name = "DIR")]
    svg: Option<PathBuf>,
}

#[derive(clap::Args)]
struct BenchArgs {
    /// One JSON object per case, one per line.
    #[arg(long)]
    json: bool,
    /// Bench this mesh instead of the demo puppet at several sizes (the
    /// skeleton, drawn for the demo puppet, is left out).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Vertex counts to mesh the demo puppet at [default: 1000,10000,100000
    /// for ARAP, 1000,10000 for the rigs].
    #[arg(long, value_delimiter = ',')]
    sizes: Option<Vec<usize>>,
    /// Only the rig cases (lp-FFD and skeleton).
    #[arg(long, conflicts_with = "e2e")]
    rigs: bool,
    /// Only the depth order: per-frame overlap detection and front/back
    /// assignment without overlap and with a fold, beside the ARAP update
    /// of the same mesh [default sizes: 1000,10000].
    #[arg(long, conflicts_with_all = ["e2e", "rigs"])]
    depth: bool,
    /// Bench as-rigid-as-possible curve editing instead: updates of
    /// curves of 1k and 10k points, and peeling drags' recompiles.
    #[arg(long, conflicts_with_all = ["e2e", "rigs", "takes", "depth"])]
    curves: bool,
    /// Bench the daemon end to end instead: a 1 kHz drag replayed as fast
    /// as possible into it, with 1 and 16 WebSocket clients on loopback.
    #[arg(long)]
    e2e: bool,
    /// Bench the daemon from outside instead: `puppetry serve` on the
    /// demo stage in a process of its own, this many WebSocket viewers
    /// (comma-separated counts, one case each) and a performer dragging
    /// at 120 Hz; latency, the daemon's memory and CPU.
    #[arg(long, value_delimiter = ',', conflicts_with_all = ["e2e", "rigs", "depth", "curves"])]
    viewers: Option<Vec<usize>>,
    /// With --viewers: spread the viewers over this many `puppetry
    /// relay` processes fed by a nats-server (the relay tier; 60 Hz
    /// input); their CPU and memory per viewer, and a remote
    /// performer's ping.
    #[arg(long, default_value_t = 0, requires = "viewers")]
    relays: usize,
    /// With --viewers: time this program's `puppetry serve` instead of
    /// this one's, to compare two builds in one run (a build whose
    /// `pong` carries no clock has its latency printed as NaN).
    #[arg(long, requires = "viewers", value_name = "PROGRAM")]
    daemon: Option<PathBuf>,
    /// Bench takes instead: what recording costs the live path, and
    /// exports of a 60 s, 60 fps take (glb, 1280x720 PNG).
    #[arg(long, conflicts_with_all = ["e2e", "rigs", "depth"])]
    takes: bool,
    /// Bench exports instead: every format of a 60 s take at 30 fps
    /// (drawn ones at 1280x720), in seconds and times real time.
    #[arg(long, conflicts_with_all = ["e2e", "rigs", "depth", "takes", "curves"])]
    export: bool,
    /// Handle counts to bench (at most 200: each handle change inverts a
    /// dense system of about that size).
    #[arg(long, value_delimiter = ',', default_value = "2,10,40",
          value_parser = clap::value_parser!(u32).range(1..=200))]
    handles: Vec<u32>,
}

/// The "input" column of `bench --e2e`: how fast, from how many performers.
fn input_label(r: &bench::EndToEndResult) -> String {
    let rate = if r.pacing == "real_time" {
        "1 kHz real time"
    } else {
        "as fast as possible"
    };
    if r.performers > 1 {
        format!("{} × {rate}", r.performers)
    } else {
        rate.to_string()
    }
}

/// `--size WxH`.
fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{text:?}: expected WIDTHxHEIGHT, e.g. 1280x720"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (1..=16384).contains(n))
            .ok_or_else(|| format!("{text:?}: {v:?} is not a size from 1 to 16384"))
    };
    Ok((parse(w)?, parse(h)?))
}

/// Logs to stderr, at `RUST_LOG`'s levels (default: info), coloured only
/// on a terminal and without `NO_COLOR`.
fn log_to_stderr() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(puppetry::terminal::colour_on_stderr())
        .init();
}

/// What `serve` says on starting: the URLs to open, where TUIO and OSC
/// arrive, and a warning when demo tokens are open to the network.
fn print_serving(
    file: &std::path::Path,
    stage: &puppetry_daemon::config::ShowConfig,
    running: &puppetry_daemon::serve::Running,
) {
    let bundled = puppetry_daemon::bundled::root().is_ok_and(|root| file.starts_with(root));
    let network = if running.address.ip().is_unspecified() {
        cli::network_addresses()
    } else {
        Vec::new()
    };
    let served = cli::Served {
        file,
        bundled,
        address: running.address,
        network: &network,
    };
    let said = cli::serving(
        &served,
        &stage.access,
        &puppetry_daemon::bundled::demo_tokens(),
    );
    if let Some(warning) = &said.warning {
        // Logged (a service's log keeps it) and on the terminal both.
        tracing::warn!("{warning}");
    }
    for line in &said.lines {
        println!("{line}");
    }
    // Said, because a stage file may ask for port 0.
    for tuio in &running.tuio_addresses {
        println!("  TUIO: receiving on udp {tuio}");
    }
    if let Some(osc) = running.osc_address {
        println!("  OSC triggers: udp://{osc} (docs/osc.md)");
    }
    println!("  stop with Ctrl-C (or SIGTERM)");
}

/// `puppetry mesh`: meshes, warns, writes (beside the input by default)
/// and says what it made.
fn mesh(
    input: &std::path::Path,
    vertices: Option<u32>,
    output: Option<&std::path::Path>,
    join: Option<f64>,
) -> anyhow::Result<()> {
    let vertices = vertices.map(|n| n as usize);
    let meshed = cli::mesh_command(input, vertices, join)?;
    for warning in &meshed.warnings {
        eprintln!("warning: {warning}");
    }
    let mesh = meshed.mesh;
    let got = mesh.vertices().len();
    if let Some(n) = vertices.filter(|&n| got * 100 < n * 85 || got * 100 > n * 115) {
        eprintln!(
            "note: asked for {n} vertices, got {got}: the outline needs {}",
            if got > n {
                "more (many islands or thin parts)"
            } else {
                "fewer (the shape is small)"
            }
        );
    }
    let output = cli::MeshOutput::new(input, output);
    let written = output.write(&mesh.to_json())?;
    eprintln!(
        "meshed {}{}: {} vertices, {} triangles, {} piece(s)",
        input.display(),
        written
            .map(|file| format!(" into {}", file.display()))
            .unwrap_or_default(),
        mesh.vertices().len(),
        mesh.triangles().len(),
        mesh.pieces().len()
    );
    if let Some(file) = written
        && mesh.pieces().len() > 1
    {
        let name = file.to_string_lossy();
        let stem = name.strip_suffix(".mesh.json").unwrap_or(&name);
        let picture = std::path::PathBuf::from(format!("{stem}.pieces.svg"));
        std::fs::write(&picture, cli::pieces_svg(&mesh))?;
        eprintln!("the pieces, each in its colour: {}", picture.display());
    }
    Ok(())
}

/// Ctrl-C and SIGTERM (as systemd and docker stop daemons), caught from
/// before the daemon says it serves: a stop sent the moment it says so
/// (a test, a supervisor) must end it cleanly, not kill it by the
/// signal's default (seen once: a SIGTERM just after the serving line
/// killed the daemon before its handler was in place).
struct Stop {
    terminate: tokio::signal::unix::Signal,
    interrupt: tokio::signal::unix::Signal,
}

impl Stop {
    /// Catches both signals from now on.
    fn catch() -> std::io::Result<Stop> {
        use tokio::signal::unix::{SignalKind, signal};
        Ok(Stop {
            terminate: signal(SignalKind::terminate())?,
            interrupt: signal(SignalKind::interrupt())?,
        })
    }

    /// Waits for either.
    async fn until_stopped(mut self) {
        tokio::select! {
            _ = self.interrupt.recv() => {}
            _ = self.terminate.recv() => {}
        }
    }
}

fn main() -> ExitCode {
    // Past a file-size limit (`ulimit -f`) the kernel sends SIGXFSZ, whose
    // default kills the process: the whole show would stop for one take.
    // Ignored, the write fails with EFBIG instead and the take stops with
    // that error, as docs/protocol.md says ("File too large"). Children
    // (ffmpeg for video exports) inherit it and fail the same way.
    // SAFETY: at the start of main, before any thread exists; SIG_IGN
    // installs no handler code.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            // Our messages already quote their cause; print each link of the
            // chain only when it adds something.
            let mut message = String::new();
            for link in error.chain() {
                let text = link.to_string();
                if !message.contains(&text) {
                    if !message.is_empty() {
                        message.push_str(": ");
                    }
                    message.push_str(&text);
                }
            }
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

/// Hands each command to its function.
fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Serve(args) => serve_command(args),
        Command::Relay(args) => relay_command(args),
        Command::Soak(args) => soak_command(args),
        Command::Export(args) => export_command(args),
        Command::Takes(args) => takes_command(args),
        Command::Devices(args) => devices_command(args),
        Command::Calibrate(args) => calibrate_command(args),
        Command::Record(args) => record_command(args),
        Command::Mesh(args) => mesh_command(args),
        Command::Solve(args) => solve_command(args),
        Command::BenchCase(args) => bench_case_command(args),
        Command::Compare(args) => compare_command(args),
        Command::Bench(args) => bench_command(args),
    }
}

/// `puppetry record PORT -o FILE.mid`: a MIDI port to a Standard MIDI
/// File.
async fn record_midi(port: &Path, output: &Path, duration: Option<f64>) -> anyhow::Result<()> {
    eprintln!(
        "recording MIDI from {} to {}; stop with Ctrl-C",
        port.display(),
        output.display()
    );
    let stop = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    let recorded = puppetry_input::midi_record::record_midi(
        port,
        output,
        duration.map(std::time::Duration::from_secs_f64),
        stop,
    )
    .await?;
    eprintln!(
        "recorded {} MIDI messages{}{}{}",
        recorded.messages,
        match recorded.dropped {
            0 => String::new(),
            n => format!(" ({n} stray or cut bytes dropped)"),
        },
        if recorded.full {
            "; stopped there, at MAX_MIDI_RECORD_MESSAGES (docs/limits.md)"
        } else {
            ""
        },
        match &recorded.gone {
            Some(why) => format!("; the port went away ({why})"),
            None => String::new(),
        }
    );
    Ok(())
}

/// `puppetry serve`.
fn serve_command(
    ServeArgs {
        config,
        replay,
        fast,
        listen,
        web_root,
        record,
        takes,
        play,
        no_replay,
        puppets,
    }: ServeArgs,
) -> anyhow::Result<()> {
    log_to_stderr();
    puppetry_daemon::memory::for_a_long_run();
    let path = match config {
        Some(path) => path,
        None => puppetry_daemon::bundled::demo_stage()?,
    };
    let web_files = match web_root {
        Some(dir) => puppetry_daemon::stream::WebFiles::Folder(dir),
        None => puppetry_daemon::stream::WebFiles::Embedded,
    };
    let mut stage = puppetry_daemon::config::ShowConfig::load(&path)?;
    if let Some(listen) = listen {
        stage.stage.listen = listen;
    }
    let pacing = if fast {
        puppetry_input::replay::Pacing::AsFastAsPossible
    } else {
        puppetry_input::replay::Pacing::RealTime
    };
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let mut options = puppetry_daemon::serve::Options::new(web_files);
        options.extra_replay = replay.map(|file| (file, pacing));
        options.record = record.is_some();
        options.paused_replays = no_replay;
        if let Some(dir) = puppets {
            options.puppets_dir = dir;
        }
        if let Some(dir) = record.or(takes) {
            options.takes_dir = dir;
        }
        options.play = play.map(|take| {
            let play = puppetry_daemon::takes::PlayOptions {
                fast,
                ..Default::default()
            };
            (take, play)
        });
        let stop = Stop::catch()?;
        let running = puppetry_daemon::serve::start_with(&stage, options).await?;
        print_serving(&path, &stage, &running);
        // Either way a take being recorded is ended cleanly.
        stop.until_stopped().await;
        running.shutdown().await;
        anyhow::Ok(())
    })?;

    Ok(())
}

/// `puppetry relay`.
fn relay_command(
    RelayArgs {
        nats,
        stage,
        listen,
        name,
        web_root,
        max_connections,
        client_timeout,
    }: RelayArgs,
) -> anyhow::Result<()> {
    log_to_stderr();
    puppetry_daemon::memory::for_a_long_run();
    if !(client_timeout.is_finite() && client_timeout > 0.0) {
        anyhow::bail!("--client-timeout must be a positive number of seconds");
    }
    // Named as its NATS user, whose permissions name its subjects.
    let name = name.or_else(|| {
        let address = puppetry_daemon::relay::nats::NatsAddress::parse(&nats);
        address.ok()?.user().map(str::to_string)
    });
    let options = puppetry_daemon::relay::RelayOptions {
        nats,
        stage,
        name: name.unwrap_or_else(|| format!("relay-{}", std::process::id())),
        listen,
        web_files: match web_root {
            Some(dir) => puppetry_daemon::stream::WebFiles::Folder(dir),
            None => puppetry_daemon::stream::WebFiles::Embedded,
        },
        max_connections,
        client_timeout: std::time::Duration::from_secs_f64(client_timeout),
    };
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let stage = options.stage.clone();
        let stop = Stop::catch()?;
        let running = puppetry_daemon::relay::serve::start(options).await?;
        println!(
            "puppetry: relaying stage {stage} at http://{}/",
            cli::url_address(running.address)
        );
        println!("  stop with Ctrl-C (or SIGTERM)");
        stop.until_stopped().await;
        running.shutdown().await;
        anyhow::Ok(())
    })?;

    Ok(())
}

/// `puppetry soak`.
fn soak_command(
    SoakArgs {
        minutes,
        every,
        viewers,
        relay,
        capture,
    }: SoakArgs,
) -> anyhow::Result<()> {
    let valid = |v: f64| v.is_finite() && v > 0.0;
    if !(valid(minutes) && valid(every)) {
        anyhow::bail!("--minutes and --every must be positive numbers");
    }
    let options = puppetry_bench::soak::SoakOptions {
        duration: std::time::Duration::from_secs_f64(minutes * 60.0),
        every: std::time::Duration::from_secs_f64(every),
        viewers,
        relay,
        capture,
    };
    let runtime = tokio::runtime::Runtime::new()?;
    let flat = runtime.block_on(puppetry_bench::soak::soak(options, |line| {
        println!("{line}")
    }))?;
    if !flat {
        std::process::exit(1);
    }

    Ok(())
}

/// `--format`: clap lists (in `--help`, with each one's label) and checks
/// the names of `Format::ALL`, so a format added there is offered here.
#[derive(Clone, Copy)]
struct FormatArg(Format);

static FORMAT_ARGS: std::sync::LazyLock<Vec<FormatArg>> =
    std::sync::LazyLock::new(|| Format::ALL.into_iter().map(FormatArg).collect());

impl clap::ValueEnum for FormatArg {
    fn value_variants<'a>() -> &'a [Self] {
        &FORMAT_ARGS
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.0.name()).help(self.0.label()))
    }
}

/// `puppetry export`.
fn export_command(
    ExportArgs {
        take,
        format,
        config,
        fps,
        from,
        to,
        size,
        output,
        force,
        salvage,
        audio,
        audio_offset,
        audio_start,
    }: ExportArgs,
) -> anyhow::Result<()> {
    let config = match config {
        Some(path) => path,
        None => {
            let bundled = puppetry_daemon::bundled::root()
                .ok()
                .map(|root| root.join("config"));
            let found = puppetry::export::recorded_stage_file(&take, bundled.as_deref())?;
            eprintln!("stage file: {} (from the take's header)", found.display());
            found
        }
    };
    let request = puppetry_export::take::ExportRequest {
        take,
        config,
        format: format.0,
        fps,
        from,
        to,
        size,
        output,
        overwrite: if force {
            puppetry_export::output::Overwrite::Replace
        } else {
            puppetry_export::output::Overwrite::Never
        },
        salvage,
        audio: audio.map(|file| puppetry_export::take::AudioRequest {
            file,
            align: match audio_offset {
                Some(offset) => puppetry_export::take::AudioAlign::Offset(offset),
                None => puppetry_export::take::AudioAlign::ShowClock { start: audio_start },
            },
        }),
    };
    let format = format.0;
    let mut bar = puppetry::export::Bar::new(&format!("export {format}"));
    println!("{}", puppetry::export::export(&request, &mut bar)?);

    Ok(())
}

/// `puppetry takes`.
fn takes_command(
    TakesArgs {
        dir,
        verify,
        config,
    }: TakesArgs,
) -> anyhow::Result<()> {
    let config = match config {
        Some(path) => path,
        None => puppetry_daemon::bundled::demo_stage()?,
    };
    let (report, ok) = puppetry::takes::takes_command(&dir, verify.then_some(config.as_path()))?;
    print!("{report}");
    if !ok {
        anyhow::bail!("a take did not replay exactly (see above)");
    }

    Ok(())
}

/// `puppetry devices`.
fn devices_command(
    DevicesArgs {
        dir,
        config,
        midi_dir,
    }: DevicesArgs,
) -> anyhow::Result<()> {
    let config = config
        .map(|path| puppetry_daemon::config::ShowConfig::load(&path))
        .transpose()?;
    print!("{}", cli::devices_report(&dir, &midi_dir, config.as_ref())?);

    Ok(())
}

/// `puppetry calibrate`.
fn calibrate_command(
    CalibrateArgs {
        capture,
        config,
        inset,
    }: CalibrateArgs,
) -> anyhow::Result<()> {
    let stage = puppetry_stage::config::StageConfig::load(&config)?;
    let size = glam::DVec2::new(stage.stage.width, stage.stage.height);
    let spec = puppetry_input::calibrate::from_capture(&capture, size, inset)?;
    println!("{}", puppetry_input::calibrate::toml_line(&spec));

    Ok(())
}

/// `puppetry record`.
fn record_command(
    RecordArgs {
        device,
        output,
        duration,
        grab,
    }: RecordArgs,
) -> anyhow::Result<()> {
    if let Some(d) = duration.filter(|d| !(d.is_finite() && *d > 0.0)) {
        anyhow::bail!("--duration: {d} is not a positive number of seconds");
    }
    let runtime = tokio::runtime::Runtime::new()?;
    if output.extension().is_some_and(|e| e == "mid") {
        return runtime.block_on(record_midi(&device, &output, duration));
    }
    let recorded = runtime.block_on(async {
        let opened = puppetry_input::device::Device::open(&device, grab)?;
        eprintln!(
            "recording {} (\"{}\") to {}; stop with Ctrl-C",
            device.display(),
            opened.info().name,
            output.display()
        );
        let stop = async {
            let _ = tokio::signal::ctrl_c().await;
        };
        puppetry_input::record::record(
            opened,
            &output,
            duration.map(std::time::Duration::from_secs_f64),
            stop,
        )
        .await
    })?;
    eprintln!(
        "recorded {} events{}",
        recorded.events,
        if recorded.device_gone {
            " (the device went away)"
        } else {
            ""
        }
    );

    Ok(())
}

/// `puppetry mesh`.
fn mesh_command(
    MeshArgs {
        input,
        vertices,
        output,
        join,
    }: MeshArgs,
) -> anyhow::Result<()> {
    mesh(&input, vertices, output.as_deref(), join)?;
    Ok(())
}

/// `puppetry solve`.
fn solve_command(
    SolveArgs {
        mesh,
        handles,
        step1_only,
        svg,
    }: SolveArgs,
) -> anyhow::Result<()> {
    let out = cli::solve_command(&mesh, &handles, step1_only, svg.as_deref())?;
    println!("{out}");

    Ok(())
}

/// `puppetry bench-case`.
fn bench_case_command(BenchCaseArgs { case, poses }: BenchCaseArgs) -> anyhow::Result<()> {
    println!(
        "{}",
        puppetry_bench::peers::bench_case_command(&case, poses.as_deref())?
    );

    Ok(())
}

/// `puppetry compare`.
fn compare_command(
    CompareArgs {
        grid,
        mesh,
        handles,
        json,
        svg,
    }: CompareArgs,
) -> anyhow::Result<()> {
    let figure = mesh.as_deref().zip(handles.as_deref());
    let comparison = cli::compare_command(figure, grid, svg.as_deref())?;
    if json {
        println!("{}", serde_json::to_string(&comparison)?);
    } else {
        print!("{}", compare::table(&comparison));
    }

    Ok(())
}

/// `puppetry bench`: the case its flags pick, the solvers by default.
fn bench_command(args: BenchArgs) -> anyhow::Result<()> {
    if args.curves {
        return bench_curves(args);
    }
    if args.viewers.is_some() {
        return bench_viewers(args);
    }
    if args.takes {
        return bench_takes(args);
    }
    if args.export {
        return bench_exports(args);
    }
    if args.e2e {
        return bench_end_to_end(args);
    }
    bench_solvers(args)
}

fn bench_curves(BenchArgs { json, .. }: BenchArgs) -> anyhow::Result<()> {
    if !json {
        println!("{}", bench::curve_table_header());
    }
    for points in [1000, 10_000] {
        for handles in [2, 3] {
            let frames = if points > 5000 { 3000 } else { 10_000 };
            let drags = if points > 5000 { 10 } else { 50 };
            let result = bench::curve_bench(points, handles, frames, drags)?;
            if json {
                println!("{}", serde_json::to_string(&result)?);
            } else {
                println!("{}", bench::curve_table_row(&result));
            }
        }
    }

    Ok(())
}

fn bench_viewers(
    BenchArgs {
        viewers,
        relays,
        daemon,
        json,
        ..
    }: BenchArgs,
) -> anyhow::Result<()> {
    let counts = viewers.unwrap_or_default();
    use puppetry_bench::viewers_bench as vb;
    let runtime = tokio::runtime::Runtime::new()?;
    if !json {
        if relays > 0 {
            println!("{}", vb::relays_table_header());
        } else {
            println!("{}", vb::viewers_table_header());
        }
    }
    for viewers in counts {
        let r = runtime.block_on(vb::viewers_case(viewers, relays, daemon.as_deref()))?;
        if json {
            println!("{}", serde_json::to_string(&r)?);
        } else if relays > 0 {
            println!("{}", vb::relays_table_row(&r));
        } else {
            println!("{}", vb::viewers_table_row(&r));
        }
    }

    Ok(())
}

fn bench_exports(_: BenchArgs) -> anyhow::Result<()> {
    let stages = cli::end_to_end_stages()?;
    let print = |line: &str| println!("{line}");
    puppetry_bench::take_bench::export_bench(&stages[0].1, &print).map_err(anyhow::Error::msg)?;

    Ok(())
}

fn bench_takes(_: BenchArgs) -> anyhow::Result<()> {
    let stages = cli::end_to_end_stages()?;
    let print = |line: &str| println!("{line}");
    puppetry_bench::take_bench::take_bench(&stages[0].1, &print).map_err(anyhow::Error::msg)?;

    Ok(())
}

fn bench_end_to_end(BenchArgs { json, .. }: BenchArgs) -> anyhow::Result<()> {
    let stages = cli::end_to_end_stages()?;
    let runtime = tokio::runtime::Runtime::new()?;
    let mut breakdown = Vec::new();
    if !json {
        println!(
            "{:<20} {:>8} {:>7} {:>24} {:>12} {:>8} {:>10} {:>14} {:>14}",
            "stage",
            "vertices",
            "clients",
            "input",
            "input frames",
            "solves",
            "solves/s",
            "latency µs p50",
            "latency µs p99"
        );
    }
    for (name, stage) in &stages {
        let performers = cli::end_to_end_performers(stage);
        use puppetry_input::replay::Pacing;
        let mut cases = vec![(1, Pacing::RealTime), (16, Pacing::RealTime)];
        if stage.puppets.len() == 1 {
            cases.extend([
                (1, Pacing::AsFastAsPossible),
                (16, Pacing::AsFastAsPossible),
            ]);
        }
        for (clients, pacing) in cases {
            let frames = if pacing == Pacing::RealTime {
                2000
            } else {
                20000
            };
            let r = runtime
                .block_on(bench::end_to_end(
                    name,
                    stage,
                    &performers,
                    clients,
                    frames,
                    pacing,
                ))
                .map_err(anyhow::Error::msg)?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                let input = input_label(&r);
                println!(
                    "{:<20} {:>8} {:>7} {:>24} {:>12} {:>8} {:>10.0} {:>14.0} {:>14.0}",
                    r.mesh,
                    r.vertices,
                    r.clients,
                    input,
                    r.input_frames,
                    r.solves,
                    r.solves_per_s,
                    r.latency_us_p50,
                    r.latency_us_p99
                );
            }
            breakdown.push(r);
        }
    }
    if !json {
        println!();
        println!("where the time goes, µs per solve on the stage thread (and per client send):");
        println!(
            "{:<20} {:>7} {:>24} {:>9} {:>8} {:>8} {:>9} {:>8} {:>11} {:>10} {:>10}",
            "stage",
            "clients",
            "input",
            "commands",
            "solve",
            "frames",
            "messages",
            "record",
            "stage busy",
            "stage cpu",
            "send"
        );
        for r in &breakdown {
            println!(
                "{:<20} {:>7} {:>24} {:>9.1} {:>8.1} {:>8.1} {:>9.1} {:>8.1} {:>10.0}% {:>9.0}% {:>10.1}",
                r.mesh,
                r.clients,
                input_label(r),
                r.commands_us,
                r.solve_us,
                r.frames_us,
                r.messages_us,
                r.record_us,
                100.0 * r.stage_busy,
                100.0 * r.stage_cpu,
                r.send_us
            );
        }
    }

    Ok(())
}

fn bench_solvers(
    BenchArgs {
        json,
        mesh,
        sizes,
        handles,
        rigs,
        depth,
        ..
    }: BenchArgs,
) -> anyhow::Result<()> {
    let stdout = std::io::stdout();
    let print = |line: &str| {
        let mut out = stdout.lock();
        let _ = writeln!(out, "{line}");
        let _ = out.flush();
    };
    if depth {
        let sizes = sizes.unwrap_or_else(|| vec![1000, 10_000]);
        let meshes =
            cli::bench_meshes(mesh.as_deref(), &sizes).context("preparing bench meshes")?;
        cli::depth_bench_command(&meshes, json, print)?;
        return Ok(());
    }
    if !rigs {
        let sizes = sizes.clone().unwrap_or_else(|| vec![1000, 10_000, 100_000]);
        let meshes =
            cli::bench_meshes(mesh.as_deref(), &sizes).context("preparing bench meshes")?;
        let handles: Vec<usize> = handles.into_iter().map(|h| h as usize).collect();
        cli::bench_command(&meshes, &handles, json, print)?;
        if !json {
            print("");
        }
    }
    let sizes = sizes.unwrap_or_else(|| vec![1000, 10_000]);
    let meshes = cli::bench_meshes(mesh.as_deref(), &sizes).context("preparing bench meshes")?;
    cli::rig_bench_command(&meshes, mesh.is_none(), json, print)?;

    Ok(())
}
