//! `puppetry serve`: assembles the daemon — stage thread, input tasks and
//! the HTTP/WebSocket stream — from a stage file, and shuts it down cleanly.
//! Input sources feed the stage thread through one bounded channel (a full
//! channel makes a source wait; it never drops a contact down or up).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicU64;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinHandle;

use crate::input::ContactFrame;
use crate::input::replay::{Pacing, ReplaySource, replay};
use crate::stage::config::{InputConfig, PacingConfig, StageConfig};
use crate::stage::thread::{self, Command};
use crate::stage::{Stage, StageError};
use crate::stream::{self, Shared, StageDescription, StreamError};

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error(transparent)]
    Stream(#[from] StreamError),
}

/// Commands waiting for the stage thread before sources must wait.
const COMMAND_QUEUE: usize = 1024;

/// A running daemon.
pub struct Running {
    pub address: SocketAddr,
    /// The daemon's clock: frame timestamps are seconds since this.
    pub started: Instant,
    commands: mpsc::Sender<Command>,
    shutdown: oneshot::Sender<()>,
    server: JoinHandle<()>,
    inputs: Vec<JoinHandle<()>>,
    stage_thread: std::thread::JoinHandle<()>,
}

impl Running {
    /// Plays `source` into the stage now, through the same path as a
    /// configured replay; finishes when the source is played.
    pub async fn play(&self, source: ReplaySource, pacing: Pacing) {
        play_into(source, pacing, &self.commands, self.started).await;
    }

    /// Stops accepting, ends the inputs and the stage thread, and waits.
    pub async fn shutdown(self) {
        let _ = self.shutdown.send(());
        let _ = self.server.await;
        for input in &self.inputs {
            input.abort();
        }
        for input in self.inputs {
            let _ = input.await;
        }
        // Stopping the stage thread closes every client connection.
        let _ = self.commands.send(Command::Stop).await;
        let _ = tokio::task::spawn_blocking(move || self.stage_thread.join()).await;
    }
}

/// Starts the daemon for `config`, serving the web client from `web_root`,
/// with an extra replay source if given.
pub async fn start(
    config: &StageConfig,
    web_root: PathBuf,
    extra_replay: Option<(PathBuf, Pacing)>,
) -> Result<Running, ServeError> {
    let started = Instant::now();
    let stage = Stage::from_config(config)?;
    let (commands, commands_rx) = mpsc::channel(COMMAND_QUEUE);
    let listener = stream::bind(config.stage.listen).await?;
    let address = listener
        .local_addr()
        .map_err(|source| StreamError::Listen {
            address: config.stage.listen,
            source,
        })?;
    let mut replays: Vec<(PathBuf, Pacing, bool)> = config
        .inputs
        .iter()
        .map(|input| match input {
            InputConfig::Replay {
                file,
                pacing,
                repeat,
            } => (
                config.resolve(file),
                match pacing {
                    PacingConfig::RealTime => Pacing::RealTime,
                    PacingConfig::AsFastAsPossible => Pacing::AsFastAsPossible,
                },
                *repeat,
            ),
        })
        .collect();
    if let Some((file, pacing)) = extra_replay {
        replays.push((file, pacing, false));
    }
    let description = StageDescription::of(&stage);
    let stage_size = (stage.width, stage.height);
    let (outputs, changes, stage_thread) = thread::spawn(stage, commands_rx);
    let shared = Arc::new(Shared {
        stage: description,
        tokens: config.access.performer_tokens.clone(),
        web_root,
        commands: commands.clone(),
        outputs,
        changes,
        client_timeout: Duration::from_secs_f64(config.stage.client_timeout_s),
        started,
        next_client: AtomicU64::new(1),
    });

    let inputs = replays
        .into_iter()
        .map(|(file, pacing, repeat)| {
            let commands = commands.clone();
            tokio::spawn(async move {
                run_replay(file, pacing, repeat, stage_size, commands, started).await;
            })
        })
        .collect();
    let (shutdown, shutdown_rx) = oneshot::channel();
    let server = tokio::spawn(stream::run(listener, shared, async {
        let _ = shutdown_rx.await;
    }));
    Ok(Running {
        address,
        started,
        commands,
        shutdown,
        server,
        inputs,
        stage_thread,
    })
}

/// Plays one source into the stage thread's commands, stamping each frame
/// with its arrival on the daemon's clock; returns the frames played.
async fn play_into(
    source: ReplaySource,
    pacing: Pacing,
    commands: &mpsc::Sender<Command>,
    started: Instant,
) -> usize {
    let (frames, mut frames_rx) = mpsc::channel::<ContactFrame>(64);
    let player = tokio::spawn(replay(source, pacing, frames));
    let mut played = 0;
    while let Some(frame) = frames_rx.recv().await {
        let received = started.elapsed().as_secs_f64();
        if commands
            .send(Command::Frame { frame, received })
            .await
            .is_err()
        {
            break;
        }
        played += 1;
    }
    player.abort();
    played
}

/// Plays a replay file into the stage; errors are logged, never fatal.
async fn run_replay(
    file: PathBuf,
    pacing: Pacing,
    repeat: bool,
    stage_size: (f64, f64),
    commands: mpsc::Sender<Command>,
    started: Instant,
) {
    loop {
        let source = match ReplaySource::open(&file, stage_size) {
            Ok(source) => source,
            Err(e) => {
                tracing::error!("replay {}: {e}", file.display());
                return;
            }
        };
        let (frames, mut frames_rx) = mpsc::channel::<ContactFrame>(64);
        let player = tokio::spawn(replay(source, pacing, frames));
        while let Some(frame) = frames_rx.recv().await {
            let received = started.elapsed().as_secs_f64();
            if commands
                .send(Command::Frame { frame, received })
                .await
                .is_err()
            {
                return;
            }
        }
        if let Ok(summary) = player.await {
            tracing::info!(
                "replay {}: {} frames played",
                file.display(),
                summary.frames_sent
            );
        }
        if !repeat {
            return;
        }
    }
}
