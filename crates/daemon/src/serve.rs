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

use crate::stage_thread::{self, Command, CursorState};
use crate::stream::{self, Shared, StageDescription, StreamError, WebFiles};
use glam::DVec2;
use puppetry_input::device::{DeviceKind, DeviceMatch};
use puppetry_input::hotplug::{self, DeviceInput};
use puppetry_input::mouse::{Cursor, MouseSettings};
use puppetry_input::replay::{Pacing, ReplaySource, replay};
use puppetry_input::serial::{self, SerialDecoder};
use puppetry_input::{Calibration, CalibrationSpec, ContactFrame, SourceId, hid, tuio};
use puppetry_stage::config::{InputConfig, PacingConfig, StageConfig};
use puppetry_stage::{Stage, StageError};

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error(transparent)]
    Stream(#[from] StreamError),
    #[error("{0}")]
    Input(String),
}

/// Frames a source may get ahead of its forwarder.
const SOURCE_QUEUE: usize = 64;

/// Commands waiting for the stage thread before sources must wait.
const COMMAND_QUEUE: usize = 1024;

/// A running daemon.
pub struct Running {
    pub address: SocketAddr,
    /// Where each TUIO input listens, in stage-file order.
    pub tuio_addresses: Vec<SocketAddr>,
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

/// Starts the daemon for `config`, serving the web client from `web_files`,
/// with an extra replay source if given.
pub async fn start(
    config: &StageConfig,
    web_files: WebFiles,
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
    // Inputs are read now, so a bad file stops the start with its error.
    let size = DVec2::new(stage.width, stage.height);
    let mut replays = Vec::new();
    let mut tuio = Vec::new();
    let mut serials = Vec::new();
    let mut devices = Vec::new();
    let mut hids = Vec::new();
    for (index, input) in config.inputs.iter().enumerate() {
        let calibration = |spec: &Option<puppetry_input::CalibrationSpec>| {
            spec.clone()
                .map(Calibration::new)
                .transpose()
                .map_err(|e| ServeError::Input(format!("input[{index}].calibration: {e}")))
        };
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
                    source_id,
                    size,
                    calibration(spec)?,
                )
                .map_err(|e| ServeError::Input(format!("input[{index}]: {e}")))?;
                let pacing = match pacing {
                    PacingConfig::RealTime => Pacing::RealTime,
                    PacingConfig::AsFastAsPossible => Pacing::AsFastAsPossible,
                };
                replays.push((source, pacing, *repeat));
            }
            InputConfig::Tuio {
                listen,
                calibration: spec,
            } => {
                let calibration = match calibration(spec)? {
                    Some(c) => c,
                    None => tuio::default_calibration(size)
                        .map_err(|e| ServeError::Input(format!("input[{index}]: {e}")))?,
                };
                let socket = tokio::net::UdpSocket::bind(listen).await.map_err(|e| {
                    ServeError::Input(format!(
                        "input[{index}]: cannot receive TUIO on {listen}: {e}"
                    ))
                })?;
                tuio.push((socket, calibration));
            }
            InputConfig::Serial {
                path,
                baud,
                format,
                name,
                calibration: spec,
            } => {
                let calibration = match calibration(spec)? {
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
                serials.push((path.clone(), *baud, *format, source, calibration));
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
                devices.push(DeviceInput {
                    dir: config.resolve(dir),
                    wanted: resolve_match(config, device),
                    kind: Some(kind),
                    source: SourceId::from(
                        name.clone().unwrap_or_else(|| format!("{label}:{index}")),
                    ),
                    calibration: calibration(spec)?,
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
                hids.push((device.clone(), source, calibration(spec)?));
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
                devices.push(DeviceInput {
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
    }
    if let Some((file, pacing)) = extra_replay {
        let source =
            ReplaySource::open(&file, size).map_err(|e| ServeError::Input(e.to_string()))?;
        replays.push((source, pacing, false));
    }
    let description = StageDescription::of(&stage);
    let (outputs, stage_thread) = stage_thread::spawn(stage, commands_rx, commands.downgrade());
    let shared = Arc::new(Shared {
        stage: description,
        tokens: config.access.performer_tokens.clone(),
        web_files,
        max_connections: config.stage.max_connections,
        commands: commands.clone(),
        outputs: outputs.puppets,
        cursors: outputs.cursors,
        changes: outputs.changes,
        client_timeout: Duration::from_secs_f64(config.stage.client_timeout_s),
        started,
        next_client: AtomicU64::new(1),
    });

    let mut inputs: Vec<JoinHandle<()>> = replays
        .into_iter()
        .map(|(source, pacing, repeat)| {
            let commands = commands.clone();
            tokio::spawn(async move {
                loop {
                    let played = play_into(source.clone(), pacing, &commands, started).await;
                    tracing::info!("replay: {played} frames played");
                    if !repeat || commands.is_closed() {
                        return;
                    }
                }
            })
        })
        .collect();
    let mut tuio_addresses = Vec::new();
    for (socket, calibration) in tuio {
        tuio_addresses.push(
            socket
                .local_addr()
                .map_err(|e| ServeError::Input(e.to_string()))?,
        );
        let commands = commands.clone();
        inputs.push(tokio::spawn(async move {
            let (frames, frames_rx) = mpsc::channel::<ContactFrame>(SOURCE_QUEUE);
            let receiver = tokio::spawn(tuio::run_udp(socket, calibration, frames));
            forward(frames_rx, &commands, started).await;
            receiver.abort();
        }));
    }
    for (path, baud, format, source, calibration) in serials {
        let commands = commands.clone();
        inputs.push(tokio::spawn(async move {
            let (frames, frames_rx) = mpsc::channel::<ContactFrame>(SOURCE_QUEUE);
            let forwarder = tokio::spawn({
                let commands = commands.clone();
                async move { forward(frames_rx, &commands, started).await }
            });
            // A device that disappears is logged, its contacts lifted (by
            // run_port), and reopened; the daemon never exits because of it.
            loop {
                let decoder = SerialDecoder::new(format, calibration.clone(), source.clone());
                match serial::run_port(&path, baud, decoder, frames.clone()).await {
                    Ok(()) => break,
                    Err(e) => tracing::warn!("serial {path}: {e}; retrying in 1 s"),
                }
                if commands.is_closed() {
                    break;
                }
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
            drop(frames);
            let _ = forwarder.await;
        }));
    }
    for device in devices {
        let commands = commands.clone();
        inputs.push(tokio::spawn(async move {
            let (frames, frames_rx) = mpsc::channel::<ContactFrame>(SOURCE_QUEUE);
            let (cursor, cursor_rx) = watch::channel(None);
            let source = device.source.to_string();
            let spacing = if device.mouse.pair {
                device.mouse.pair_spacing
            } else {
                0.0
            };
            let reader = tokio::spawn(hotplug::run(device, frames, cursor));
            let cursors =
                tokio::spawn(forward_cursor(cursor_rx, source, spacing, commands.clone()));
            forward(frames_rx, &commands, started).await;
            reader.abort();
            cursors.abort();
        }));
    }
    for (selector, source, calibration) in hids {
        let commands = commands.clone();
        inputs.push(tokio::spawn(async move {
            let (frames, frames_rx) = mpsc::channel::<ContactFrame>(SOURCE_QUEUE);
            // hidapi blocks, so the device has a thread of its own; it stops
            // when this task ends (dropping the guard) or the stage closes.
            let stop = StopOnDrop(Arc::new(AtomicBool::new(false)));
            let thread_stop = stop.0.clone();
            std::thread::Builder::new()
                .name(format!("hid {source}"))
                .spawn(move || run_hid(&selector, source, calibration, size, &frames, &thread_stop))
                .ok();
            forward(frames_rx, &commands, started).await;
            drop(stop);
        }));
    }
    let (shutdown, shutdown_rx) = oneshot::channel();
    let server = tokio::spawn(stream::run(listener, shared, async {
        let _ = shutdown_rx.await;
    }));
    Ok(Running {
        address,
        tuio_addresses,
        started,
        commands,
        shutdown,
        server,
        inputs,
        stage_thread,
    })
}

/// Sets its flag when dropped: tells a device thread its task has ended.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// One HID digitizer for the daemon's life: open, read, and when it fails
/// (unplugged, not there yet, not readable) log it and try again every
/// second, until stopped.
fn run_hid(
    selector: &hid::HidSelector,
    source: SourceId,
    calibration: Option<Calibration>,
    size: DVec2,
    frames: &mpsc::Sender<ContactFrame>,
    stop: &AtomicBool,
) {
    let mut last_complaint = String::new();
    while !stop.load(Ordering::Relaxed) && !frames.is_closed() {
        let result = hid::open(selector).and_then(|device| {
            tracing::info!("{source}: reading HID device {selector}");
            last_complaint.clear();
            hid::run_device(
                &device,
                source.clone(),
                calibration.clone(),
                size,
                frames,
                stop,
            )
        });
        if let Err(e) = result {
            let message = e.to_string();
            if message != last_complaint {
                tracing::warn!("{source}: {message}; retrying every second");
                last_complaint = message;
            }
        }
        std::thread::sleep(Duration::from_secs(1));
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

/// Forwards a source's frames to the stage thread, stamping each with its
/// arrival on the daemon's clock, until the source ends or the stage stops;
/// returns how many went through.
async fn forward(
    mut frames: mpsc::Receiver<ContactFrame>,
    commands: &mpsc::Sender<Command>,
    started: Instant,
) -> usize {
    let mut forwarded = 0;
    while let Some(frame) = frames.recv().await {
        let received = started.elapsed().as_secs_f64();
        if commands
            .send(Command::Frame { frame, received })
            .await
            .is_err()
        {
            break;
        }
        forwarded += 1;
    }
    forwarded
}
