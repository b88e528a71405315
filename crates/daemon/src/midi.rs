//! MIDI inputs: a controller's or a show-control desk's messages, read
//! from a raw MIDI port or played from a Standard MIDI File, mapped by the
//! stage file's `[[input.map]]` (`puppetry_input::midi_map`) and done as
//! show control's triggers (`show_control`), the ones OSC's addresses
//! give. A port that is missing or goes away is reopened every second; a
//! refused trigger is logged, rate-limited, and the input goes on.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use puppetry_input::log_limit::LogLimiter;
use puppetry_input::midi::MidiDecoder;
use puppetry_input::midi_file::TimedMessage;
use puppetry_input::midi_map::{MidiAction, MidiMapper, MidiMapping};
use puppetry_input::midi_port::PortReader;
use puppetry_input::show_clock::{ClockKind, ShowClock};
use puppetry_take::ClockSource;
use tokio::task::JoinHandle;

use crate::midi_learn::Learning;
use crate::show_control::{Actor, Trigger, lock};
use crate::stage_thread::ShowReading;

/// Where a MIDI input's messages come from.
pub(crate) enum MidiSource {
    /// A raw MIDI byte stream (a device node, a FIFO, a serial port).
    Port(RawPort),
    /// An ALSA sequencer port, by (part of) its name (the `alsa-seq`
    /// feature's).
    Sequencer(String),
    /// A Standard MIDI File's messages, played in time.
    File {
        /// The messages, in time order.
        messages: Vec<TimedMessage>,
        /// Play again when it ends.
        repeat: bool,
    },
}

/// Which raw MIDI port a MIDI input reads.
pub(crate) enum RawPort {
    /// This device node (or FIFO, or serial port).
    Path(PathBuf),
    /// The first port of the sound card `card` names, in `dir`: looked
    /// up at each opening, since a card replugged may get another number.
    Card {
        /// The card's name, or part of it.
        card: String,
        /// Where the device nodes are (`/dev/snd`).
        dir: PathBuf,
    },
}

impl RawPort {
    /// The port's device node now.
    fn resolve(&self) -> std::io::Result<PathBuf> {
        use puppetry_input::midi_port::{asound_dir_for, port_of_card, ports};
        match self {
            RawPort::Path(path) => Ok(path.clone()),
            RawPort::Card { card, dir } => {
                let found = ports(dir, &asound_dir_for(dir));
                port_of_card(&found, card)
                    .map(|p| p.path.clone())
                    .map_err(|e| std::io::Error::new(std::io::ErrorKind::NotFound, e))
            }
        }
    }
}

/// A MIDI input, read and checked from the stage file.
pub(crate) struct MidiInput {
    /// Its name in logs and in refusals.
    pub(crate) name: String,
    /// Where its messages come from.
    pub(crate) source: MidiSource,
    /// What its controls do (checked, puppets named exist).
    pub(crate) map: Vec<MidiMapping>,
    /// The show clock it carries, if the stage file follows it.
    pub(crate) clock: Option<ClockKind>,
    /// Its index among the stage file's `[[input]]`s (where a mapping
    /// learnt on it is saved).
    pub(crate) index: usize,
}

/// How long a missing or lost port waits before it is opened again.
const REOPEN_EVERY: Duration = Duration::from_secs(1);

/// Starts each input's task; `actor` does their triggers, and mappings
/// are learnt through `learning`.
pub(crate) fn spawn(
    inputs: Vec<MidiInput>,
    actor: &Actor,
    learning: &Arc<Learning>,
) -> Vec<JoinHandle<()>> {
    inputs
        .into_iter()
        .map(|input| {
            let actor = actor.clone();
            tokio::spawn(run(input, actor, learning.clone()))
        })
        .collect()
}

async fn run(input: MidiInput, actor: Actor, learning: Arc<Learning>) {
    let mut doer = Doer {
        mapper: MidiMapper::new(input.map),
        actor,
        name: input.name,
        log: Arc::new(Mutex::new(LogLimiter::new(Instant::now()))),
        clock: input.clock.map(|kind| (ShowClock::new(kind), kind)),
        learning,
        index: input.index,
    };
    match input.source {
        MidiSource::File { messages, repeat } => loop {
            let start = tokio::time::Instant::now();
            for timed in &messages {
                tokio::time::sleep_until(start + Duration::from_secs_f64(timed.t)).await;
                doer.message(&timed.message).await;
            }
            if !repeat {
                return;
            }
        },
        MidiSource::Sequencer(name) => read_sequencer(&name, &mut doer).await,
        MidiSource::Port(port) => loop {
            match port.resolve() {
                Ok(path) => match PortReader::open(&path) {
                    Ok(reader) => {
                        if let Err(e) = read_port(&reader, &mut doer).await {
                            doer.warn(format_args!("{}: {e}", path.display()));
                        }
                    }
                    Err(e) => doer.warn(format_args!("{}: {e}", path.display())),
                },
                Err(e) => doer.warn(format_args!("{e}")),
            }
            tokio::time::sleep(REOPEN_EVERY).await;
        },
    }
}

/// The source of a MIDI input's `port`: an ALSA sequencer port, in a build
/// that reads them.
pub(crate) fn sequencer(index: usize, port: &str) -> Result<MidiSource, String> {
    if cfg!(feature = "alsa-seq") {
        Ok(MidiSource::Sequencer(port.to_string()))
    } else {
        Err(format!(
            "input[{index}].port: this puppetry reads no ALSA sequencer ports: build it with \
             `cargo build --release --features alsa-seq` (Debian: apt install libasound2-dev), \
             or read the device's raw MIDI port with path = \"/dev/snd/midiC<card>D<device>\" \
             (puppetry devices lists them)"
        ))
    }
}

/// Reads the sequencer port `wanted` names whenever it is there, doing
/// what each message asks; looks for it again every second while it is
/// away, and every second whether it went away (midir says nothing when a
/// port goes).
#[cfg(feature = "alsa-seq")]
async fn read_sequencer(wanted: &str, doer: &mut Doer) {
    use puppetry_midi_seq::{SEQ_QUEUE, SeqReader, port_names};
    use std::sync::atomic::{AtomicU64, Ordering};
    loop {
        let (send, mut received) = tokio::sync::mpsc::channel::<Vec<u8>>(SEQ_QUEUE);
        let lost = Arc::new(AtomicU64::new(0));
        let counted = lost.clone();
        // On midir's thread: never waits on the runtime.
        let on_message = move |bytes: &[u8]| {
            if send.try_send(bytes.to_vec()).is_err() {
                counted.fetch_add(1, Ordering::Relaxed);
            }
        };
        // A few calls into libasound: quick, and the input's own task.
        match SeqReader::open(wanted, on_message) {
            Ok(reader) => {
                tracing::info!("MIDI input {}: reading {}", doer.name, reader.name);
                let mut decoder = MidiDecoder::new();
                let mut messages = Vec::new();
                let mut check = tokio::time::interval(REOPEN_EVERY);
                loop {
                    tokio::select! {
                        bytes = received.recv() => {
                            let Some(bytes) = bytes else { break };
                            decoder.feed(&bytes, |m| messages.push(m));
                            for message in messages.drain(..) {
                                doer.message(&message).await;
                            }
                        }
                        _ = check.tick() => {
                            if !port_names().is_ok_and(|names| names.contains(&reader.name)) {
                                doer.warn(format_args!("{} went away", reader.name));
                                break;
                            }
                            let n = lost.swap(0, Ordering::Relaxed);
                            if n > 0 {
                                doer.warn(format_args!("{n} messages lost to a full queue"));
                            }
                        }
                    }
                }
            }
            Err(e) => doer.warn(format_args!("{e}")),
        }
        tokio::time::sleep(REOPEN_EVERY).await;
    }
}

/// Without the `alsa-seq` feature no sequencer source is made
/// ([`sequencer`] refuses the stage file).
#[cfg(not(feature = "alsa-seq"))]
async fn read_sequencer(_wanted: &str, _doer: &mut Doer) {}

/// Reads a port until it fails (a device unplugged), doing what each
/// message asks.
async fn read_port(port: &PortReader, doer: &mut Doer) -> std::io::Result<()> {
    let mut decoder = MidiDecoder::new();
    let mut buffer = [0u8; 512];
    let mut messages = Vec::new();
    loop {
        let n = port.read(&mut buffer).await?;
        decoder.feed(&buffer[..n], |m| messages.push(m));
        for message in messages.drain(..) {
            doer.message(&message).await;
        }
    }
}

/// Maps one input's messages and does their triggers.
struct Doer {
    mapper: MidiMapper,
    actor: Actor,
    name: String,
    log: Arc<Mutex<LogLimiter>>,
    /// The show clock this input follows, and which.
    clock: Option<(ShowClock, ClockKind)>,
    /// Mappings learnt from the page.
    learning: Arc<Learning>,
    /// The input's index among the stage file's inputs.
    index: usize,
}

impl Doer {
    fn warn(&self, message: std::fmt::Arguments<'_>) {
        lock(&self.log).warn(format_args!("MIDI input {}: {message}", self.name));
    }

    async fn message(&mut self, message: &puppetry_input::midi::MidiMessage) {
        if let Some((clock, kind)) = &mut self.clock
            && let Some(time) = clock.message(message)
        {
            let show = ShowReading {
                seconds: time.seconds,
                running: time.running,
                source: match kind {
                    ClockKind::TimeCode => ClockSource::TimeCode,
                    ClockKind::Beats { .. } => ClockSource::MidiClock,
                },
            };
            // Never refused: it only queues the reading.
            let _ = self.actor.act(&self.name, Trigger::Clock(show)).await;
        }
        if let Some(mapping) = self.learning.claim(message, &self.mapper) {
            // The control moved to teach is not also acted on.
            self.mapper.learn(mapping.clone());
            self.learning.save(self.index, &self.name, &mapping).await;
            return;
        }
        for action in self.mapper.actions(message) {
            let Some(trigger) = self.trigger(action) else {
                continue;
            };
            if let Err(e) = self.actor.act(&self.name, trigger).await {
                self.warn(format_args!("{e}"));
            }
        }
    }

    /// The trigger of an action: puppets by their index on the stage.
    fn trigger(&self, action: MidiAction) -> Option<Trigger> {
        let index = |name: &str| {
            let found = self.actor.links.names.iter().position(|n| n == name);
            if found.is_none() {
                self.warn(format_args!("no puppet {name:?}"));
            }
            found.map(|i| i as u32)
        };
        Some(match action {
            MidiAction::Cursor { puppet, at } => Trigger::Cursor {
                puppet: index(&puppet)?,
                at: Some(at),
            },
            MidiAction::Blend {
                puppet,
                from,
                to,
                t,
            } => Trigger::Pose {
                puppet: index(&puppet)?,
                from,
                to,
                t,
            },
            MidiAction::Key {
                puppet,
                name,
                seconds,
            } => Trigger::Key {
                puppet: index(&puppet)?,
                name,
                seconds,
            },
            MidiAction::Reset { puppet } => Trigger::Reset {
                puppet: index(&puppet)?,
            },
            MidiAction::Record => Trigger::StartTake { name: None },
            MidiAction::Stop => Trigger::StopTake,
            MidiAction::Play { take, overdub } => Trigger::PlayTake { take, overdub },
        })
    }
}
