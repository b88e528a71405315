//! `puppetry serve`: assembles the daemon — stage thread, input tasks and
//! the HTTP/WebSocket stream — from a stage file, and shuts it down cleanly.
//! Input sources feed the stage thread through one bounded channel (a full
//! channel makes a source wait; it never drops a contact down or up).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicU64;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot, watch};
use tokio::task::JoinHandle;

use crate::config::ShowConfig;
use crate::outputs::Published;
use crate::sources::{Down, Replays, SOURCE_QUEUE, forward, lift};
use crate::stage_thread::{self, Command, TakeSettings};
use crate::stream::{self, Shared, StreamError, WebFiles};
use crate::takes::PlayOptions;
use glam::DVec2;
use puppetry_input::ContactFrame;
use puppetry_input::replay::{Pacing, ReplaySource, replay};
use puppetry_stage::{Stage, StageError};

/// Why the daemon did not start. Each is found before anything runs, so
/// a bad file or address stops the start with its error and nothing is
/// left behind.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// A puppet of the stage file could not be put on the stage.
    #[error(transparent)]
    Stage(#[from] StageError),
    /// The edge cannot listen on the stage's `listen` address.
    #[error(transparent)]
    Stream(#[from] StreamError),
    /// An input source cannot be opened or checked (it names `input[N]`).
    #[error(transparent)]
    Inputs(#[from] crate::inputs::InputError),
    /// The take `serve --play` names cannot be played.
    #[error(transparent)]
    Play(#[from] crate::takes::PlayError),
    /// Show control cannot start (`[osc].listen` cannot be bound, or no
    /// socket to send from).
    #[error(transparent)]
    Osc(#[from] crate::osc::OscError),
    /// Publishing to relays cannot start (`[relay]`).
    #[error(transparent)]
    Relay(#[from] crate::relay::RelayError),
    /// The task loading the stage panicked or was cancelled.
    #[error("loading the stage stopped: {0}")]
    Loading(String),
}

/// Commands waiting for the stage thread before sources must wait.
const COMMAND_QUEUE: usize = 1024;

/// A running daemon.
pub struct Running {
    /// Where the edge listens (HTTP and WebSocket), its port resolved when
    /// the stage file asks for port 0.
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
        forward(frames, &self.commands, self.started, &mut Down::default()).await
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
    /// The web client served: compiled in, or a folder
    /// (`serve --web-root`).
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
    /// `serve`'s defaults: takes in `./takes`, added pictures in
    /// `./puppets`, nothing recorded or played, replays playing, the
    /// edge's waits from `puppetry_limits::net`.
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

/// Starts the daemon for `config` with `options`: the stage loaded, its
/// thread, the inputs read, the edge bound, show control and relays, then
/// the inputs and the edge running.
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
    // Before the kept pictures come back after them.
    let file_puppets = config.puppets.len();
    let (config, stage) = load_stage(config, &puppets_dir).await?;
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
    let mut resolved = crate::inputs::resolve(config, size, extra_replay).await?;
    let midis = std::mem::take(&mut resolved.midis);
    let people = Arc::new(stream::People::new(config, resolved.source_names()));
    let settings = TakeSettings {
        dir: takes_dir.clone(),
        stage_file: config.file.clone(),
        file_puppets,
        record_from_first_input: record,
        started,
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
    let learning = learning(config, &midis, &replays);
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
            meshing: std::sync::atomic::AtomicBool::new(false),
            export_state,
            replays: replays.clone(),
            held: Default::default(),
            learning: learning.clone(),
        }),
    });

    // Before the sources, so a bad OSC address stops the start cleanly.
    let (osc, relay) = show_control(config, &shared, &commands).await?;
    let crate::inputs::Spawned {
        mut inputs,
        replays: replay_tasks,
        tuio_addresses,
    } = crate::inputs::spawn(resolved, &commands, started, &replays);
    if !midis.is_empty() {
        inputs.extend(crate::midi::spawn(
            midis,
            &midi_actor(config, &shared, &commands),
            &learning,
        ));
    }
    if let Some((path, play_options)) = play {
        play_at_start(&path, play_options, &shared, &commands, started)?;
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

/// Loads the stage (and the pictures directors added before a restart) off
/// the tokio workers: meshes and their solvers' factoring take seconds on a
/// big mesh.
async fn load_stage(
    config: &ShowConfig,
    puppets_dir: &std::path::Path,
) -> Result<(ShowConfig, Stage), ServeError> {
    let mut config = config.clone();
    let puppets_dir = puppets_dir.to_path_buf();
    tokio::task::spawn_blocking(move || {
        let mut stage = Stage::from_config(&config)?;
        stream::restore_pictures(&mut config, &mut stage, &puppets_dir);
        Ok::<_, StageError>((config, stage))
    })
    .await
    .map_err(|e| ServeError::Loading(e.to_string()))?
    .map_err(ServeError::from)
}

/// Starts OSC and the relay tier's publishing, if the stage file asks.
/// NATS need not be up: the daemon serves its own clients regardless.
async fn show_control(
    config: &ShowConfig,
    shared: &Arc<Shared>,
    commands: &mpsc::Sender<Command>,
) -> Result<
    (
        Option<crate::osc::Osc>,
        Option<crate::relay::publish::Publishing>,
    ),
    ServeError,
> {
    let osc = match &config.osc {
        Some(osc) => Some(
            crate::osc::start(
                osc,
                crate::show_control::Links::of(shared, commands.clone()),
            )
            .await?,
        ),
        None => None,
    };
    let relay = match &config.relay {
        Some(relay) => Some(
            crate::relay::publish::start(relay, &config.relay_stage_name(), shared.clone()).await?,
        ),
        None => None,
    };
    Ok((osc, relay))
}

/// MIDI learning for the stage's MIDI inputs, saved to its stage file and
/// shown in the `inputs` message `replays` publishes.
fn learning(
    config: &ShowConfig,
    midis: &[crate::midi::MidiInput],
    replays: &Arc<Replays>,
) -> Arc<crate::midi_learn::Learning> {
    Arc::new(crate::midi_learn::Learning::new(
        std::path::PathBuf::from(&config.file),
        midis.iter().map(|m| m.name.clone()).collect(),
        config
            .stage_config
            .puppets
            .iter()
            .map(|p| p.name.clone())
            .collect(),
        replays.clone(),
    ))
}

/// What MIDI inputs do their triggers with: show control's links, and
/// key blends stepped at the OSC rate (its default without `[osc]`).
fn midi_actor(
    config: &ShowConfig,
    shared: &Arc<Shared>,
    commands: &mpsc::Sender<Command>,
) -> crate::show_control::Actor {
    let links = crate::show_control::Links::of(shared, commands.clone());
    let blends = vec![None; links.puppets.len()];
    crate::show_control::Actor {
        rate: config
            .osc
            .as_ref()
            .map_or(crate::config::DEFAULT_OSC_RATE, |osc| osc.rate),
        links,
        blends: Arc::new(std::sync::Mutex::new(blends)),
        log: Arc::new(std::sync::Mutex::new(
            puppetry_input::log_limit::LogLimiter::new(std::time::Instant::now()),
        )),
    }
}

/// Plays the take `serve --play` names; its player is the stage's take
/// playing, stopped from the page like any other.
fn play_at_start(
    path: &std::path::Path,
    options: PlayOptions,
    shared: &Arc<Shared>,
    commands: &mpsc::Sender<Command>,
    started: Instant,
) -> Result<(), ServeError> {
    let player = crate::takes::play(
        path,
        &shared.lineup.borrow().take_puppets.clone(),
        options,
        commands.clone(),
        started,
    )?;
    if let Ok(links) = shared.links() {
        *links.player.lock().unwrap_or_else(|p| p.into_inner()) = Some(player);
    }
    Ok(())
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
    let mut down = Down::default();
    let played = forward(frames_rx, commands, started, &mut down).await;
    player.abort();
    // A file that ends mid-touch holds nothing after it.
    lift(down, commands, started).await;
    played
}
