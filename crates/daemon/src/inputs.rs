//! The stage file's inputs as the daemon runs them. Each `[[input]]` is
//! resolved at start (files read, sockets bound, devices matched), so a bad
//! one stops the start naming `input[N]`; then every input runs under the
//! one supervision policy (`sources::supervise`). Replays are played and
//! paused from the page (`sources::run_replay`); every other kind is a
//! `Supervised` input: its own struct, and how one attempt of it runs.
//! `spawn` has one loop over them. A new input kind is its decoder in
//! `puppetry-input`, its variant of `InputConfig`, an arm of
//! `ResolvedInputs::add` and a `Supervised` impl here.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::DVec2;
use puppetry_input::config::release_after;
use puppetry_input::config::{EvdevInput, InputConfig};
use puppetry_input::device::{DeviceKind, DeviceMatch};
use puppetry_input::hotplug::{self, DeviceInput};
use puppetry_input::mouse::{Cursor, MouseSettings};
use puppetry_input::replay::{Pacing, ReplaySource, replay};
use puppetry_input::serial::{self, SerialDecoder};
use puppetry_input::{Calibration, CalibrationSpec, ContactFrame, SourceId, hid, tuio};
use puppetry_stage::config::StageConfig;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use crate::config::ShowConfig;
use crate::protocol::CursorView;
use crate::sources::{Replays, SourceError, WhenDone, run_replay, supervise};
use crate::stage_thread::Command;

/// An input that cannot be opened or checked, naming `input[N]`.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(String);

/// One attempt of a source (see `sources::supervise`).
type Attempt = std::pin::Pin<Box<dyn std::future::Future<Output = Result<(), SourceError>> + Send>>;
/// Makes each attempt of a source, given the sender its frames go to.
type AttemptMaker = Box<dyn FnMut(mpsc::Sender<ContactFrame>) -> Attempt + Send>;

/// An input run under supervision: a failed attempt lifts its contacts and
/// is tried again after a pause.
trait Supervised: Send {
    /// The name it is supervised (and logged) under.
    fn name(&self) -> SourceId;

    /// Whether its contacts carry that name (a TUIO source's carry its
    /// senders'), so the people list shows it.
    fn names_its_contacts(&self) -> bool {
        true
    }

    /// What makes each of its attempts.
    fn attempts(self: Box<Self>, commands: &mpsc::Sender<Command>) -> AttemptMaker;
}

/// The stage file's inputs, opened or checked.
#[derive(Default)]
pub(crate) struct ResolvedInputs {
    pub(crate) replays: Vec<ReplayInput>,
    /// MIDI inputs: started with show control, whose triggers they do.
    pub(crate) midis: Vec<crate::midi::MidiInput>,
    supervised: Vec<Box<dyn Supervised>>,
    /// Where each TUIO input listens, in file order.
    tuio_addresses: Vec<SocketAddr>,
}

/// A replay input, its file read.
pub(crate) struct ReplayInput {
    pub(crate) source: SourceId,
    file: ReplaySource,
    pacing: Pacing,
    repeat: bool,
    /// Named by the stage file (`--no-replay` pauses these), not `--replay`.
    pub(crate) from_stage_file: bool,
}

impl ResolvedInputs {
    /// The input sources' names, as handles name their owners (TUIO
    /// sources are named by their senders, so are not known yet).
    pub(crate) fn source_names(&self) -> Vec<String> {
        let replays = self.replays.iter().map(|r| r.source.to_string());
        let supervised = self
            .supervised
            .iter()
            .filter(|s| s.names_its_contacts())
            .map(|s| s.name().to_string());
        replays.chain(supervised).collect()
    }
}

/// Reads and checks every input of `config` (and an extra replay), so a bad
/// file or address stops the start with its error.
pub(crate) async fn resolve(
    config: &ShowConfig,
    size: DVec2,
    extra_replay: Option<(PathBuf, Pacing)>,
) -> Result<ResolvedInputs, InputError> {
    let mut resolved = ResolvedInputs::default();
    for (index, input) in config.inputs.iter().enumerate() {
        if let Some(name) = input_name(input) {
            reserved_name(name).map_err(|e| InputError(format!("input[{index}].name: {e}")))?;
        }
        resolved.add(config, size, index, input).await?;
    }
    if let Some((file, pacing)) = extra_replay {
        let source = ReplaySource::open(&file, size).map_err(|e| InputError(e.to_string()))?;
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
) -> Result<Option<Calibration>, InputError> {
    spec.clone()
        .map(Calibration::new)
        .transpose()
        .map_err(|e| InputError(format!("input[{index}].calibration: {e}")))
}

impl ResolvedInputs {
    /// Opens or checks `input`, the stage file's `input[index]`, and adds
    /// it to the inputs. One short arm per input kind, kept in one match so
    /// a new kind is one arm (and the compiler asks for it).
    async fn add(
        &mut self,
        config: &ShowConfig,
        size: DVec2,
        index: usize,
        input: &InputConfig,
    ) -> Result<(), InputError> {
        let supervised: Box<dyn Supervised> = match input {
            InputConfig::Midi { .. } => {
                self.midis.push(midi_input(config, index, input)?);
                return Ok(());
            }
            InputConfig::Replay { .. } => {
                self.replays.push(replay_input(config, size, index, input)?);
                return Ok(());
            }
            InputConfig::Tuio {
                listen,
                calibration: spec,
                release_after_s,
            } => {
                let calibration = calibration_or(index, spec, || tuio::default_calibration(size))?;
                let mut input = self.bind_tuio(index, *listen, calibration).await?;
                input.release_after = release_after(*release_after_s, tuio::RELEASE_AFTER);
                Box::new(input)
            }
            InputConfig::Serial {
                path,
                baud,
                format,
                name,
                calibration: spec,
                release_after_s,
            } => Box::new(SerialInput {
                path: path.clone(),
                baud: *baud,
                format: *format,
                source: source_name(name, "serial", index),
                calibration: calibration_or(index, spec, || pad_units_are_stage_units(size))?,
                release_after: release_after(*release_after_s, serial::RELEASE_AFTER),
            }),
            InputConfig::Touch(evdev) | InputConfig::Pen(evdev) => {
                let (kind, label) = match input {
                    InputConfig::Pen(_) => (DeviceKind::Pen, "pen"),
                    _ => (DeviceKind::Touch, "touch"),
                };
                Box::new(DeviceInput {
                    dir: config.resolve(&evdev.dir),
                    wanted: resolve_match(config, &evdev.device),
                    kind: Some(kind),
                    source: source_name(&evdev.name, label, index),
                    calibration: calibration_of(index, &evdev.calibration)?,
                    grab: evdev.grab,
                    mouse: MouseSettings::for_stage(size),
                    stage_size: size,
                })
            }
            InputConfig::Hid {
                device,
                name,
                calibration: spec,
            } => Box::new(HidInput {
                selector: device.clone(),
                source: source_name(name, "hid", index),
                calibration: calibration_of(index, spec)?,
                stage_size: size,
            }),
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
                // The stage file's settings over the stage's defaults.
                let mut mouse = MouseSettings::for_stage(size);
                mouse.start = start.map_or(mouse.start, DVec2::from);
                mouse.speed = speed.unwrap_or(mouse.speed);
                mouse.pair = pair.unwrap_or(mouse.pair);
                mouse.pair_spacing = pair_spacing.unwrap_or(mouse.pair_spacing);
                mouse.rotate_step = rotate_step_deg.map_or(mouse.rotate_step, f64::to_radians);
                Box::new(DeviceInput {
                    dir: config.resolve(dir),
                    wanted: resolve_match(config, device),
                    kind: Some(DeviceKind::Mouse),
                    source: source_name(name, "mouse", index),
                    calibration: None,
                    grab: *grab,
                    mouse,
                    stage_size: size,
                })
            }
        };
        self.supervised.push(supervised);
        Ok(())
    }

    /// Binds a TUIO input's socket now, so a bad address stops the start.
    async fn bind_tuio(
        &mut self,
        index: usize,
        listen: SocketAddr,
        calibration: Calibration,
    ) -> Result<TuioInput, InputError> {
        let socket = tokio::net::UdpSocket::bind(listen).await.map_err(|e| {
            InputError(format!(
                "input[{index}]: cannot receive TUIO on {listen}: {e}"
            ))
        })?;
        let address = socket
            .local_addr()
            .map_err(|e| InputError(format!("input[{index}]: {e}")))?;
        let name = SourceId::from(format!("tuio:{}", self.tuio_addresses.len()));
        self.tuio_addresses.push(address);
        Ok(TuioInput {
            name,
            socket: Some(socket),
            address,
            calibration,
            release_after: tuio::RELEASE_AFTER,
        })
    }
}

/// The source's name: the stage file's, or `KIND:INDEX`.
fn source_name(name: &Option<String>, kind: &str, index: usize) -> SourceId {
    SourceId::from(name.clone().unwrap_or_else(|| format!("{kind}:{index}")))
}

/// The stage file's calibration of `input[index]`, or the kind's default.
fn calibration_or<E: std::fmt::Display>(
    index: usize,
    spec: &Option<CalibrationSpec>,
    default: impl FnOnce() -> Result<Calibration, E>,
) -> Result<Calibration, InputError> {
    match calibration_of(index, spec)? {
        Some(calibration) => Ok(calibration),
        None => default().map_err(|e| InputError(format!("input[{index}]: {e}"))),
    }
}

/// A serial pad's default: its units are stage units.
fn pad_units_are_stage_units(size: DVec2) -> Result<Calibration, puppetry_input::CalibrationError> {
    Calibration::new(CalibrationSpec::Range {
        x: [0.0, size.x],
        y: [0.0, size.y],
        flip_y: false,
        stage_min: [0.0, 0.0],
        stage_max: size.to_array(),
    })
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

/// A replay input of the stage file's `input[index]`, its file read now
/// (a bad file stops the start, naming it).
fn replay_input(
    config: &ShowConfig,
    size: DVec2,
    index: usize,
    input: &InputConfig,
) -> Result<ReplayInput, InputError> {
    let InputConfig::Replay {
        file,
        name,
        calibration: spec,
        pacing,
        repeat,
    } = input
    else {
        return Err(InputError(format!("input[{index}] is not a replay")));
    };
    let source_id = source_name(name, "replay", index);
    let source = ReplaySource::open_with(
        &config.resolve(file),
        source_id.clone(),
        size,
        calibration_of(index, spec)?,
    )
    .map_err(|e| InputError(format!("input[{index}]: {e}")))?;
    Ok(ReplayInput {
        source: source_id,
        file: source,
        pacing: Pacing::from(*pacing),
        repeat: *repeat,
        from_stage_file: true,
    })
}

/// A MIDI input of the stage file's `input[index]`: its `.mid` read now
/// (a bad file stops the start, naming it), the puppets its mapping names
/// checked against the stage file's.
fn midi_input(
    config: &ShowConfig,
    index: usize,
    input: &InputConfig,
) -> Result<crate::midi::MidiInput, InputError> {
    let InputConfig::Midi {
        path,
        card,
        dir,
        file,
        port,
        repeat,
        name,
        map,
        clock,
        tempo,
    } = input
    else {
        return Err(InputError(format!("input[{index}] is not a MIDI input")));
    };
    let clock = puppetry_input::config::ClockSetting::kind(*clock, *tempo)
        .map_err(|(field, problem)| InputError(format!("input[{index}].{field}: {problem}")))?;
    for (j, m) in map.iter().enumerate() {
        if let Some(puppet) = &m.puppet
            && !config
                .stage_config
                .puppets
                .iter()
                .any(|p| &p.name == puppet)
        {
            return Err(InputError(format!(
                "input[{index}].map[{j}].puppet: no puppet {puppet:?} on the stage"
            )));
        }
    }
    let source = match (path, file, port) {
        (Some(path), ..) => crate::midi::MidiSource::Port(crate::midi::RawPort::Path(path.clone())),
        (None, None, None) if card.is_some() => {
            crate::midi::MidiSource::Port(crate::midi::RawPort::Card {
                card: card.clone().unwrap_or_default(),
                dir: dir
                    .clone()
                    .unwrap_or_else(|| puppetry_input::midi_port::DEFAULT_SND_DIR.into()),
            })
        }
        (None, Some(file), _) => {
            let read = puppetry_input::midi_file::read_midi_file(&config.resolve(file))
                .map_err(|e| InputError(format!("input[{index}].file: {e}")))?;
            // A damaged file plays what can be read, said once at start.
            for damage in &read.damage {
                tracing::warn!("input[{index}].file: {damage}");
            }
            crate::midi::MidiSource::File {
                messages: read.messages,
                repeat: *repeat,
            }
        }
        (None, None, Some(port)) => crate::midi::sequencer(index, port).map_err(InputError)?,
        (None, None, None) => {
            return Err(InputError(format!(
                "input[{index}]: a MIDI input needs a path, a port or a file"
            )));
        }
    };
    Ok(crate::midi::MidiInput {
        name: name.clone().unwrap_or_else(|| format!("midi:{index}")),
        source,
        map: map.to_vec(),
        clock,
        index,
    })
}

/// The name a stage file gives an input, if it gives one.
fn input_name(input: &InputConfig) -> Option<&str> {
    match input {
        InputConfig::Replay { name, .. }
        | InputConfig::Serial { name, .. }
        | InputConfig::Touch(EvdevInput { name, .. })
        | InputConfig::Pen(EvdevInput { name, .. })
        | InputConfig::Hid { name, .. }
        | InputConfig::Mouse { name, .. }
        | InputConfig::Midi { name, .. } => name.as_deref(),
        InputConfig::Tuio { .. } => None,
    }
}

/// The tasks of the inputs, and where each TUIO input listens.
pub(crate) struct Spawned {
    pub(crate) inputs: Vec<JoinHandle<()>>,
    /// Replay tasks: they wait while paused, so they never end by themselves.
    pub(crate) replays: Vec<JoinHandle<()>>,
    pub(crate) tuio_addresses: Vec<SocketAddr>,
}

/// Spawns every resolved input: replays under their play/pause control,
/// every other input under the one supervision policy.
pub(crate) fn spawn(
    resolved: ResolvedInputs,
    commands: &mpsc::Sender<Command>,
    started: Instant,
    replay_controls: &Arc<Replays>,
) -> Spawned {
    let ResolvedInputs {
        replays,
        midis,
        supervised,
        tuio_addresses,
    } = resolved;
    // MIDI inputs do show control's triggers: `serve` starts them with it.
    debug_assert!(midis.is_empty(), "serve takes the MIDI inputs first");
    // Replays run while they play (see `sources::run_replay`); they never
    // end by themselves, so `inputs_done` asks whether any plays.
    let replays = replays
        .into_iter()
        .enumerate()
        .map(|(index, input)| {
            let ReplayInput {
                file: source,
                pacing,
                repeat,
                ..
            } = input;
            tokio::spawn(run_replay(
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
            ))
        })
        .collect();
    let inputs = supervised
        .into_iter()
        .map(|input| {
            let name = input.name();
            let attempts = input.attempts(commands);
            tokio::spawn(supervise(
                name,
                WhenDone::Stop,
                commands.clone(),
                started,
                attempts,
            ))
        })
        .collect();
    Spawned {
        inputs,
        replays,
        tuio_addresses,
    }
}

/// A TUIO input, its socket bound (so a bad address stops the start).
struct TuioInput {
    name: SourceId,
    /// The socket bound at start, for the first attempt; later ones bind
    /// `address` again.
    socket: Option<tokio::net::UdpSocket>,
    address: SocketAddr,
    calibration: Calibration,
    /// How long one of its senders may be silent while holding contacts.
    release_after: std::time::Duration,
}

impl Supervised for TuioInput {
    fn name(&self) -> SourceId {
        self.name.clone()
    }

    fn names_its_contacts(&self) -> bool {
        false
    }

    fn attempts(self: Box<Self>, _: &mpsc::Sender<Command>) -> AttemptMaker {
        let TuioInput {
            mut socket,
            address,
            calibration,
            release_after,
            ..
        } = *self;
        Box::new(move |frames| {
            let socket = socket.take();
            let calibration = calibration.clone();
            Box::pin(async move {
                let socket = match socket {
                    Some(socket) => socket,
                    None => tokio::net::UdpSocket::bind(address)
                        .await
                        .map_err(|source| SourceError::Bind { address, source })?,
                };
                Ok(tuio::run_udp(socket, calibration, release_after, frames).await?)
            }) as Attempt
        })
    }
}

/// A serial pad input.
struct SerialInput {
    path: String,
    baud: u32,
    format: puppetry_input::serial::WireFormat,
    source: SourceId,
    calibration: Calibration,
    /// How long the pad may be silent while holding contacts.
    release_after: std::time::Duration,
}

impl Supervised for SerialInput {
    fn name(&self) -> SourceId {
        self.source.clone()
    }

    fn attempts(self: Box<Self>, _: &mpsc::Sender<Command>) -> AttemptMaker {
        let SerialInput {
            path,
            baud,
            format,
            source,
            calibration,
            release_after,
        } = *self;
        Box::new(move |frames| {
            let decoder = SerialDecoder::new(format, calibration.clone(), source.clone());
            let path = path.clone();
            Box::pin(async move {
                Ok(serial::run_port(&path, baud, decoder, release_after, frames).await?)
            }) as Attempt
        })
    }
}

/// An evdev device: a touch screen, a pen tablet or a mouse, read by
/// `hotplug`, which reopens it when it comes back.
impl Supervised for DeviceInput {
    fn name(&self) -> SourceId {
        self.source.clone()
    }

    fn attempts(self: Box<Self>, commands: &mpsc::Sender<Command>) -> AttemptMaker {
        let device = *self;
        let spacing = if device.mouse.pair {
            device.mouse.pair_spacing
        } else {
            0.0
        };
        let commands = commands.clone();
        Box::new(move |frames| {
            // hotplug keeps the device read for the daemon's life: it
            // reopens on inotify events itself.
            let device = device.clone();
            let commands = commands.clone();
            Box::pin(async move {
                let (cursor, cursor_rx) = watch::channel(None);
                let source = device.source.to_string();
                let cursors = tokio::spawn(forward_cursor(cursor_rx, source, spacing, commands));
                hotplug::run(device, frames, cursor).await;
                cursors.abort();
                Ok(())
            }) as Attempt
        })
    }
}

/// A HID digitizer input.
struct HidInput {
    selector: hid::HidSelector,
    source: SourceId,
    calibration: Option<Calibration>,
    stage_size: DVec2,
}

impl Supervised for HidInput {
    fn name(&self) -> SourceId {
        self.source.clone()
    }

    fn attempts(self: Box<Self>, _: &mpsc::Sender<Command>) -> AttemptMaker {
        let HidInput {
            selector,
            source,
            calibration,
            stage_size: size,
        } = *self;
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
        })
    }
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
        let view = cursor.borrow_and_update().map(|c| CursorView {
            source: source.clone(),
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
