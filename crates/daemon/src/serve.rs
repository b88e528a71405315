//! `puppetry serve`: assembles the daemon — stage thread, input tasks and
//! the HTTP/WebSocket stream — from a stage file, and shuts it down cleanly.
//! Input sources feed the stage thread through one bounded channel (a full
//! channel makes a source wait; it never drops a contact down or up).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot, watch};
use tokio::task::JoinHandle;

use crate::config::ShowConfig;
use crate::outputs::Published;
use crate::sources::{
    Replays, SOURCE_QUEUE, SourceError, WhenDone, forward, run_replay, supervise,
};
use crate::stage_thread::{self, Command, CursorState, TakeSettings};
use crate::stream::{self, Shared, StreamError, WebFiles};
use crate::takes::PlayOptions;
use glam::DVec2;
use puppetry_input::config::{InputConfig, PacingConfig};
use puppetry_input::device::{DeviceKind, DeviceMatch};
use puppetry_input::hotplug::{self, DeviceInput};
use puppetry_input::mouse::{Cursor, MouseSettings};
use puppetry_input::replay::{Pacing, ReplaySource, replay};
use puppetry_input::serial::{self, SerialDecoder};
use puppetry_input::{Calibration, CalibrationSpec, ContactFrame, SourceId, hid, tuio};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Stage, StageError};

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error(transparent)]
    Stream(#[from] StreamError),
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Osc(#[from] crate::osc::OscError),
    #[error(transparent)]
    Relay(#[from] crate::relay::RelayError),
    #[error("loading the stage stopped: {0}")]
    Loading(String),
}

/// One attempt of a source (see `sources::supervise`).
type Attempt = std::pin::Pin<Box<dyn std::future::Future<Output = Result<(), SourceError>> + Send>>;
/// Makes each attempt of a source, given the sender its frames go to.
type AttemptMaker = Box<dyn FnMut(mpsc::Sender<ContactFrame>) -> Attempt + Send>;

/// Commands waiting for the stage thread before sources must wait.
const COMMAND_QUEUE: usize = 1024;

/// A running daemon.
pub struct Running {
    pub address: SocketAddr,
    /// Where each TUIO input listens, in stage-file order.
    pub tuio_addresses: Vec<SocketAddr>,
    /// The daemon's clock: frame timestamps are seconds since this.
    pub started: Instant,
    /// Where OSC triggers are received (`[osc].listen`, port resolved).
    pub osc_address: Option<SocketAddr>,
    osc: Option<crate::osc::Osc>,
    /// The stage published over NATS (`[relay]`).
    relay: Option<crate::relay::publish::Publishing>,
    commands: mpsc::Sender<Command>,
    shutdown: oneshot::Sender<()>,
    server: JoinHandle<()>,
    inputs: Vec<JoinHandle<()>>,
    replay_tasks: Vec<JoinHandle<()>>,
    stage_thread: std::thread::JoinHandle<()>,
    shared: Arc<Shared>,
}

impl Running {
    /// Where the daemon's time has gone since it started.
    pub fn timings(&self) -> Arc<crate::stage_thread::Timings> {
        self.shared.timings.clone()
    }

    /// Every input has ended (replays that do not repeat have played, or
    /// are paused) and no take is playing: what was fed is in the stage
    /// thread's queue.
    pub fn inputs_done(&self) -> bool {
        let Ok(links) = self.shared.links() else {
            return true;
        };
        self.inputs.iter().all(|i| i.is_finished())
            && links.replays.idle()
            && links
                .player
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .as_ref()
                .is_none_or(|p| p.is_finished())
    }

    /// Plays `source` into the stage now, through the same path as a
    /// configured replay; finishes when the source is played.
    pub async fn play(&self, source: ReplaySource, pacing: Pacing) {
        play_into(source, pacing, &self.commands, self.started).await;
    }

    /// Feeds the stage the frames sent into `frames`, each stamped as it
    /// arrives, as an input device's reader does; finishes when every
    /// sender is gone. Returns the frames fed.
    pub async fn feed(&self, frames: mpsc::Receiver<ContactFrame>) -> usize {
        forward(frames, &self.commands, self.started).await
    }

    /// Stops accepting, ends the inputs and the stage thread, and waits.
    pub async fn shutdown(self) {
        if let Some(osc) = &self.osc {
            osc.stop();
        }
        if let Some(relay) = self.relay {
            relay.stop().await;
        }
        let _ = self.shutdown.send(());
        let _ = self.server.await;
        for input in self.inputs.iter().chain(&self.replay_tasks) {
            input.abort();
        }
        for input in self.inputs.into_iter().chain(self.replay_tasks) {
            let _ = input.await;
        }
        // Stopping the stage thread closes every client connection.
        let _ = self.commands.send(Command::Stop).await;
        let _ = tokio::task::spawn_blocking(move || self.stage_thread.join()).await;
    }
}

/// How a daemon is started beyond its stage file.
#[derive(Debug, Clone)]
pub struct Options {
    pub web_files: WebFiles,
    /// An extra replay source (a `.jsonl` recording or evemu capture).
    pub extra_replay: Option<(PathBuf, Pacing)>,
    /// Where takes are recorded and listed.
    pub takes_dir: PathBuf,
    /// Where pictures a director adds at runtime are kept, with their
    /// meshes.
    pub puppets_dir: PathBuf,
    /// Record a take from the first input to shutdown.
    pub record: bool,
    /// A take to play into the stage at start.
    pub play: Option<(PathBuf, PlayOptions)>,
    /// The stage file's replay inputs start paused (`serve --no-replay`);
    /// a director plays them from the page.
    pub paused_replays: bool,
    /// How long the edge waits on a connection's request head and a
    /// WebSocket's pong (`puppetry_limits::net`; tests shorten them).
    pub edge: stream::EdgeTimes,
}

impl Options {
    pub fn new(web_files: WebFiles) -> Options {
        Options {
            web_files,
            extra_replay: None,
            takes_dir: PathBuf::from("takes"),
            puppets_dir: PathBuf::from("puppets"),
            record: false,
            play: None,
            paused_replays: false,
            edge: stream::EdgeTimes::default(),
        }
    }
}

/// Starts the daemon for `config`, serving the web client from `web_files`,
/// with an extra replay source if given.
pub async fn start(
    config: &ShowConfig,
    web_files: WebFiles,
    extra_replay: Option<(PathBuf, Pacing)>,
) -> Result<Running, ServeError> {
    let mut options = Options::new(web_files);
    options.extra_replay = extra_replay;
    start_with(config, options).await
}

/// Starts the daemon for `config` with `options`.
#[expect(
    clippy::too_many_lines,
    reason = "the daemon's assembly in order (stage thread, inputs, edge, OSC, relays, shutdown), each step a few lines; it reads top to bottom as the start does"
)]
pub async fn start_with(config: &ShowConfig, options: Options) -> Result<Running, ServeError> {
    let Options {
        web_files,
        extra_replay,
        takes_dir,
        puppets_dir,
        record,
        play,
        paused_replays,
        edge,
    } = options;
    let started = Instant::now();
    // Loading meshes and factoring their solvers takes seconds on a big
    // mesh: not on a tokio worker.
    let (config, stage) = {
        let mut config = config.clone();
        let puppets_dir = puppets_dir.clone();
        tokio::task::spawn_blocking(move || {
            let mut stage = Stage::from_config(&config)?;
            // Pictures directors added before a restart come back.
            stream::restore_pictures(&mut config, &mut stage, &puppets_dir);
            Ok::<_, StageError>((config, stage))
        })
        .await
        .map_err(|e| ServeError::Loading(e.to_string()))??
    };
    let config = &config;
    let (commands, commands_rx) = mpsc::channel(COMMAND_QUEUE);
    let listener = stream::bind(config.stage.listen).await?;
    let address = listener
        .local_addr()
        .map_err(|source| StreamError::Listen {
            address: config.stage.listen,
            source,
        })?;
    // Inputs are read now, so a bad file stops the start with its error.
    let size = DVec2::new(stage.width, stage.height);
    let resolved = resolve_inputs(config, size, extra_replay).await?;
    let people = Arc::new(stream::People::new(config, resolved.source_names()));
    let settings = TakeSettings {
        dir: takes_dir.clone(),
        stage_file: config.file.clone(),
        record_from_first_input: record,
    };
    let (outputs, stage_thread) = stage_thread::spawn(
        config.stage_config.clone(),
        stage,
        commands_rx,
        commands.downgrade(),
        settings,
    );
    let replays = Arc::new(Replays::new(
        resolved
            .replays
            .iter()
            .map(|r| (r.source.to_string(), !(paused_replays && r.from_stage_file)))
            .collect(),
    ));
    let export_state = watch::channel(Published::nothing()).0;
    let shared = Arc::new(Shared {
        lineup: outputs.lineup,
        log: Default::default(),
        addresses: Default::default(),
        web_files,
        max_connections: config.stage.max_connections,
        cursors: outputs.cursors,
        take: outputs.take,
        export: export_state.subscribe(),
        people: people.subscribe(),
        inputs: replays.message(),
        // A daemon never loses its own stage.
        notice: watch::channel(Published::nothing()).1,
        changes: outputs.changes,
        timings: outputs.timings,
        client_timeout: Duration::from_secs_f64(config.stage.client_timeout_s),
        started,
        next_client: AtomicU64::new(1),
        backend: stream::Backend::Stage(stream::StageLinks {
            people,
            commands: commands.clone(),
            takes_dir,
            puppets_dir,
            player: std::sync::Mutex::new(None),
            exporting: std::sync::atomic::AtomicBool::new(false),
            export_state,
            replays: replays.clone(),
            held: Default::default(),
        }),
    });

    // Before the sources, so a bad OSC address stops the start cleanly.
    let osc = match &config.osc {
        Some(osc) => {
            Some(crate::osc::start(osc, crate::osc::Links::of(&shared, commands.clone())).await?)
        }
        None => None,
    };
    // NATS need not be up: the daemon serves its own clients regardless.
    let relay = match &config.relay {
        Some(relay) => Some(
            crate::relay::publish::start(relay, &config.relay_stage_name(), shared.clone()).await?,
        ),
        None => None,
    };
    let Spawned {
        inputs,
        replays: replay_tasks,
        tuio_addresses,
    } = spawn_sources(resolved, &commands, started, size, &replays)?;
    if let Some((path, play_options)) = play {
        let player = crate::takes::play(
            &path,
            &shared.lineup.borrow().take_puppets.clone(),
            play_options,
            commands.clone(),
            started,
        )
        .map_err(|e| ServeError::Input(e.to_string()))?;
        if let Ok(links) = shared.links() {
            *links.player.lock().unwrap_or_else(|p| p.into_inner()) = Some(player);
        }
    }
    let (shutdown, shutdown_rx) = oneshot::channel();
    let server = tokio::spawn(stream::run_with(listener, shared.clone(), edge, async {
        let _ = shutdown_rx.await;
    }));
    Ok(Running {
        address,
        tuio_addresses,
        started,
        osc_address: osc.as_ref().and_then(|o| o.listen),
        osc,
        relay,
        commands,
        shutdown,
        server,
        inputs,
        replay_tasks,
        stage_thread,
        shared,
    })
}

/// The stage file's inputs, opened or checked: replays read, TUIO sockets
/// bound, devices resolved.
#[derive(Default)]
struct ResolvedInputs {
    replays: Vec<ReplayInput>,
    tuio: Vec<TuioInput>,
    serials: Vec<SerialInput>,
    devices: Vec<DeviceInput>,
    hids: Vec<HidInput>,
}

/// A replay input, its file read.
struct ReplayInput {
    source: SourceId,
    file: ReplaySource,
    pacing: Pacing,
    repeat: bool,
    /// Named by the stage file (`--no-replay` pauses these), not `--replay`.
    from_stage_file: bool,
}

/// A TUIO input, its socket bound (so a bad address stops the start).
struct TuioInput {
    socket: tokio::net::UdpSocket,
    calibration: Calibration,
}

/// A serial pad input.
struct SerialInput {
    path: String,
    baud: u32,
    format: puppetry_input::serial::WireFormat,
    source: SourceId,
    calibration: Calibration,
}

/// A HID digitizer input.
struct HidInput {
    selector: hid::HidSelector,
    source: SourceId,
    calibration: Option<Calibration>,
}

impl ResolvedInputs {
    /// The input sources' names, as handles name their owners (TUIO
    /// sources are named by their senders, so are not known yet).
    fn source_names(&self) -> Vec<String> {
        let replays = self.replays.iter().map(|r| &r.source);
        let serials = self.serials.iter().map(|s| &s.source);
        let devices = self.devices.iter().map(|d| &d.source);
        let hids = self.hids.iter().map(|h| &h.source);
        replays
            .chain(serials)
            .chain(devices)
            .chain(hids)
            .map(|s| s.to_string())
            .collect()
    }
}

/// Reads and checks every input of `config` (and an extra replay), so a bad
/// file or address stops the start with its error.
async fn resolve_inputs(
    config: &ShowConfig,
    size: DVec2,
    extra_replay: Option<(PathBuf, Pacing)>,
) -> Result<ResolvedInputs, ServeError> {
    let mut resolved = ResolvedInputs::default();
    for (index, input) in config.inputs.iter().enumerate() {
        if let Some(name) = input_name(input) {
            reserved_name(name)
                .map_err(|e| ServeError::Input(format!("input[{index}].name: {e}")))?;
        }
        resolved.add(config, size, index, input).await?;
    }
    if let Some((file, pacing)) = extra_replay {
        let source =
            ReplaySource::open(&file, size).map_err(|e| ServeError::Input(e.to_string()))?;
        resolved.replays.push(ReplayInput {
            source: SourceId::from("replay"),
            file: source,
            pacing,
            repeat: false,
            from_stage_file: false,
        });
    }
    Ok(resolved)
}

/// An input's calibration as the stage file gives it (none: the kind's
/// default), or the error naming `input[index].calibration`.
fn calibration_of(
    index: usize,
    spec: &Option<puppetry_input::CalibrationSpec>,
) -> Result<Option<Calibration>, ServeError> {
    spec.clone()
        .map(Calibration::new)
        .transpose()
        .map_err(|e| ServeError::Input(format!("input[{index}].calibration: {e}")))
}

impl ResolvedInputs {
    /// Opens or checks `input`, the stage file's `input[index]`, and adds
    /// it to its kind's list. Longer than most functions here: one short
    /// arm per input kind, kept in one match so a new kind is one arm
    /// (and the compiler asks for it).
    #[expect(
        clippy::too_many_lines,
        reason = "one short arm per input kind, kept in one match so a new kind is one arm and the compiler asks for it"
    )]
    async fn add(
        &mut self,
        config: &ShowConfig,
        size: DVec2,
        index: usize,
        input: &InputConfig,
    ) -> Result<(), ServeError> {
        match input {
            InputConfig::Replay {
                file,
                name,
                calibration: spec,
                pacing,
                repeat,
            } => {
                let source_id =
                    SourceId::from(name.clone().unwrap_or_else(|| format!("replay:{index}")));
                let source = ReplaySource::open_with(
                    &config.resolve(file),
                    source_id.clone(),
                    size,
                    calibration_of(index, spec)?,
                )
                .map_err(|e| ServeError::Input(format!("input[{index}]: {e}")))?;
                let pacing = match pacing {
                    PacingConfig::RealTime => Pacing::RealTime,
                    PacingConfig::AsFastAsPossible => Pacing::AsFastAsPossible,
                };
                self.replays.push(ReplayInput {
                    source: source_id,
                    file: source,
                    pacing,
                    repeat: *repeat,
                    from_stage_file: true,
                });
            }
            InputConfig::Tuio {
                listen,
                calibration: spec,
            } => {
                let calibration = match calibration_of(index, spec)? {
                    Some(c) => c,
                    None => tuio::default_calibration(size)
                        .map_err(|e| ServeError::Input(format!("input[{index}]: {e}")))?,
                };
                let socket = tokio::net::UdpSocket::bind(listen).await.map_err(|e| {
                    ServeError::Input(format!(
                        "input[{index}]: cannot receive TUIO on {listen}: {e}"
                    ))
                })?;
                self.tuio.push(TuioInput {
                    socket,
                    calibration,
                });
            }
            InputConfig::Serial {
                path,
                baud,
                format,
                name,
                calibration: spec,
            } => {
                let calibration = match calibration_of(index, spec)? {
                    Some(c) => c,
                    // Pad units are stage units.
                    None => Calibration::new(CalibrationSpec::Range {
                        x: [0.0, size.x],
                        y: [0.0, size.y],
                        flip_y: false,
                        stage_min: [0.0, 0.0],
                        stage_max: size.to_array(),
                    })
                    .map_err(|e| ServeError::Input(format!("input[{index}]: {e}")))?,
                };
                let source =
                    SourceId::from(name.clone().unwrap_or_else(|| format!("serial:{index}")));
                self.serials.push(SerialInput {
                    path: path.clone(),
                    baud: *baud,
                    format: *format,
                    source,
                    calibration,
                });
            }
            InputConfig::Touch {
                device,
                dir,
                name,
                grab,
                calibration: spec,
            }
            | InputConfig::Pen {
                device,
                dir,
                name,
                grab,
                calibration: spec,
            } => {
                let (kind, label) = match input {
                    InputConfig::Pen { .. } => (DeviceKind::Pen, "pen"),
                    _ => (DeviceKind::Touch, "touch"),
                };
                self.devices.push(DeviceInput {
                    dir: config.resolve(dir),
                    wanted: resolve_match(config, device),
                    kind: Some(kind),
                    source: SourceId::from(
                        name.clone().unwrap_or_else(|| format!("{label}:{index}")),
                    ),
                    calibration: calibration_of(index, spec)?,
                    grab: *grab,
                    mouse: MouseSettings::for_stage(size),
                    stage_size: size,
                });
            }
            InputConfig::Hid {
                device,
                name,
                calibration: spec,
            } => {
                let source = SourceId::from(name.clone().unwrap_or_else(|| format!("hid:{index}")));
                self.hids.push(HidInput {
                    selector: device.clone(),
                    source,
                    calibration: calibration_of(index, spec)?,
                });
            }
            InputConfig::Mouse {
                device,
                dir,
                name,
                grab,
                speed,
                pair,
                pair_spacing,
                rotate_step_deg,
                start,
            } => {
                let mut mouse = MouseSettings::for_stage(size);
                mouse.start = start.map_or(mouse.start, DVec2::from);
                mouse.speed = speed.unwrap_or(mouse.speed);
                mouse.pair = pair.unwrap_or(mouse.pair);
                mouse.pair_spacing = pair_spacing.unwrap_or(mouse.pair_spacing);
                mouse.rotate_step = rotate_step_deg.map_or(mouse.rotate_step, f64::to_radians);
                self.devices.push(DeviceInput {
                    dir: config.resolve(dir),
                    wanted: resolve_match(config, device),
                    kind: Some(DeviceKind::Mouse),
                    source: SourceId::from(
                        name.clone().unwrap_or_else(|| format!("mouse:{index}")),
                    ),
                    calibration: None,
                    grab: *grab,
                    mouse,
                    stage_size: size,
                });
            }
        }
        Ok(())
    }
}

/// Prefixes of the sources the daemon names itself: its WebSocket clients
/// (`client:<n>`) and a relay's (`relay:<relay>:<n>`). An input named so
/// would share handles, pins and limits with that client, and a client's
/// leave would lift the input's contacts.
pub const RESERVED_SOURCE_PREFIXES: [&str; 2] = ["client:", "relay:"];

/// `name` is not one the daemon gives its clients, or why it may not be.
fn reserved_name(name: &str) -> Result<(), String> {
    match RESERVED_SOURCE_PREFIXES
        .iter()
        .find(|prefix| name.starts_with(*prefix))
    {
        Some(prefix) => Err(format!(
            "{:?} starts with `{prefix}`, which names the daemon's own clients: choose another name",
            crate::stream::guard::clip(name, 80)
        )),
        None => Ok(()),
    }
}

/// The name a stage file gives an input, if it gives one.
fn input_name(input: &InputConfig) -> Option<&str> {
    match input {
        InputConfig::Replay { name, .. }
        | InputConfig::Serial { name, .. }
        | InputConfig::Touch { name, .. }
        | InputConfig::Pen { name, .. }
        | InputConfig::Hid { name, .. }
        | InputConfig::Mouse { name, .. } => name.as_deref(),
        InputConfig::Tuio { .. } => None,
    }
}

/// The tasks of the inputs, and where each TUIO input listens.
struct Spawned {
    inputs: Vec<JoinHandle<()>>,
    /// Replay tasks: they wait while paused, so they never end by themselves.
    replays: Vec<JoinHandle<()>>,
    tuio_addresses: Vec<SocketAddr>,
}

/// Spawns every resolved input under the one supervision policy
/// (`sources::supervise`), each kind its own loop; replays under their
/// play/pause control. One function though long: each loop is short and
/// shares the supervision closure, and a new kind is one more loop here.
#[expect(
    clippy::too_many_lines,
    reason = "one short loop per input kind sharing the supervision closure; a new kind is one more loop here"
)]
fn spawn_sources(
    resolved: ResolvedInputs,
    commands: &mpsc::Sender<Command>,
    started: Instant,
    size: DVec2,
    replay_controls: &Arc<Replays>,
) -> Result<Spawned, ServeError> {
    let ResolvedInputs {
        replays,
        tuio,
        serials,
        devices,
        hids,
    } = resolved;
    // Every source runs under the one supervision policy (`sources`).
    let supervised = |name: SourceId, when_done, attempt: AttemptMaker| {
        tokio::spawn(supervise(
            name,
            when_done,
            commands.clone(),
            started,
            attempt,
        ))
    };
    let mut inputs: Vec<JoinHandle<()>> = Vec::new();
    // Replays run while they play (see `sources::run_replay`); they never
    // end by themselves, so `inputs_done` asks whether any plays.
    let mut replay_tasks = Vec::new();
    for (index, input) in replays.into_iter().enumerate() {
        let ReplayInput {
            file: source,
            pacing,
            repeat,
            ..
        } = input;
        replay_tasks.push(tokio::spawn(run_replay(
            replay_controls.clone(),
            index,
            repeat,
            commands.clone(),
            started,
            move |frames| {
                let source = source.clone();
                async move {
                    replay(source, pacing, frames).await;
                }
            },
        )));
    }
    let mut tuio_addresses = Vec::new();
    for (
        index,
        TuioInput {
            socket,
            calibration,
        },
    ) in tuio.into_iter().enumerate()
    {
        let address = socket
            .local_addr()
            .map_err(|e| ServeError::Input(e.to_string()))?;
        tuio_addresses.push(address);
        // The first attempt uses the socket bound at start (so a bad
        // address stops the start); later ones bind the same address again.
        let mut bound = Some(socket);
        inputs.push(supervised(
            SourceId::from(format!("tuio:{index}")),
            WhenDone::Stop,
            Box::new(move |frames| {
                let socket = bound.take();
                let calibration = calibration.clone();
                Box::pin(async move {
                    let socket = match socket {
                        Some(socket) => socket,
                        None => tokio::net::UdpSocket::bind(address)
                            .await
                            .map_err(|source| SourceError::Bind { address, source })?,
                    };
                    Ok(tuio::run_udp(socket, calibration, frames).await?)
                }) as Attempt
            }),
        ));
    }
    for SerialInput {
        path,
        baud,
        format,
        source,
        calibration,
    } in serials
    {
        inputs.push(supervised(
            source.clone(),
            WhenDone::Stop,
            Box::new(move |frames| {
                let decoder = SerialDecoder::new(format, calibration.clone(), source.clone());
                let path = path.clone();
                Box::pin(async move { Ok(serial::run_port(&path, baud, decoder, frames).await?) })
                    as Attempt
            }),
        ));
    }
    for device in devices {
        let name = device.source.clone();
        let spacing = if device.mouse.pair {
            device.mouse.pair_spacing
        } else {
            0.0
        };
        let commands = commands.clone();
        inputs.push(supervised(
            name,
            WhenDone::Stop,
            Box::new(move |frames| {
                // hotplug keeps the device read for the daemon's life: it
                // reopens on inotify events itself.
                let device = device.clone();
                let commands = commands.clone();
                Box::pin(async move {
                    let (cursor, cursor_rx) = watch::channel(None);
                    let source = device.source.to_string();
                    let cursors =
                        tokio::spawn(forward_cursor(cursor_rx, source, spacing, commands));
                    hotplug::run(device, frames, cursor).await;
                    cursors.abort();
                    Ok(())
                }) as Attempt
            }),
        ));
    }
    for HidInput {
        selector,
        source,
        calibration,
    } in hids
    {
        let name = source.clone();
        inputs.push(supervised(
            name,
            WhenDone::Stop,
            Box::new(move |frames| {
                let (selector, source, calibration) =
                    (selector.clone(), source.clone(), calibration.clone());
                Box::pin(async move {
                    // hidapi blocks: each attempt reads on a blocking thread,
                    // told to stop when the attempt is dropped (shutdown).
                    let stop = StopOnDrop(Arc::new(AtomicBool::new(false)));
                    let thread_stop = stop.0.clone();
                    let read = tokio::task::spawn_blocking(move || {
                        let device = hid::open(&selector)?;
                        tracing::info!("{source}: reading HID device {selector}");
                        hid::run_device(&device, source, calibration, size, &frames, &thread_stop)
                    });
                    let result = read.await;
                    drop(stop);
                    match result {
                        Ok(read) => Ok(read?),
                        Err(e) => Err(SourceError::Panicked(e.to_string())),
                    }
                }) as Attempt
            }),
        ));
    }
    Ok(Spawned {
        inputs,
        replays: replay_tasks,
        tuio_addresses,
    })
}

/// Sets its flag when dropped: tells a device thread its task has ended.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// A device entry's relative `path` is relative to the stage file.
fn resolve_match(config: &StageConfig, wanted: &DeviceMatch) -> DeviceMatch {
    let mut wanted = wanted.clone();
    wanted.path = wanted.path.map(|p| config.resolve(&p));
    wanted
}

/// Tells the stage thread where a mouse's cursor is whenever it moves. Only
/// the newest position matters, so a watch channel (which keeps only that)
/// feeds it.
async fn forward_cursor(
    mut cursor: watch::Receiver<Option<Cursor>>,
    source: String,
    spacing: f64,
    commands: mpsc::Sender<Command>,
) {
    while cursor.changed().await.is_ok() {
        let view = cursor.borrow_and_update().map(|c| CursorState {
            at: c.position.to_array(),
            angle: c.angle,
            spacing,
            holding: c.holding,
        });
        let command = Command::Cursor {
            source: source.clone(),
            cursor: view,
        };
        if commands.send(command).await.is_err() {
            return;
        }
    }
}

/// Plays one replay source into the stage thread; returns the frames played.
async fn play_into(
    source: ReplaySource,
    pacing: Pacing,
    commands: &mpsc::Sender<Command>,
    started: Instant,
) -> usize {
    let (frames, frames_rx) = mpsc::channel::<ContactFrame>(SOURCE_QUEUE);
    let player = tokio::spawn(replay(source, pacing, frames));
    let played = forward(frames_rx, commands, started).await;
    player.abort();
    played
}
