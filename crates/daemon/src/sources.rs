//! Supervision of input sources, written once. Every source the stage file
//! names (replays, TUIO, serial pads, evdev devices, HID digitizers) runs
//! under [`supervise`]: each attempt gets a fresh frame channel forwarded
//! to the stage thread; however an attempt ends, the source's contacts are
//! lifted (a file that ends mid-touch holds nothing after it), and when it
//! failed — the device vanished, the port went away, the task panicked —
//! the error is logged with its type's message (once per distinct message,
//! not on every retry) and it is tried again after a backoff. No source
//! can take the daemon down, and a dead one never spins a core. Sources
//! that can fall silent with their link still open (TUIO senders, serial
//! pads) let go of what they hold after their own `release_after_s`, in
//! their decoders' loops.
//!
//! Replay inputs can also be paused and played from the page
//! ([`Replays`], [`run_replay`]): a paused replay lets go of what it held,
//! so a performer can take the puppet over, and plays from its start again
//! when it is played.

use std::collections::{BTreeMap, HashMap};
use std::future::Future;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};

use crate::outputs::{Feed, Published, State};
use crate::stage_thread::Command;
use puppetry_input::hid::HidError;
use puppetry_input::serial::SerialError;
use puppetry_input::tuio::TuioError;
use puppetry_input::{Contact, ContactFrame, Phase, SourceId};

/// Frames a source may get ahead of its forwarder.
pub const SOURCE_QUEUE: usize = 64;

/// The first wait after a failure; it doubles up to [`MAX_BACKOFF`].
const FIRST_BACKOFF: Duration = Duration::from_secs(1);
const MAX_BACKOFF: Duration = Duration::from_secs(10);
/// An attempt that ran this long before failing counts as healthy: the
/// next failure waits the first backoff again.
const HEALTHY_RUN: Duration = Duration::from_secs(60);

/// Why an attempt of a source ended badly.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error(transparent)]
    Serial(#[from] SerialError),
    #[error(transparent)]
    Tuio(#[from] TuioError),
    #[error(transparent)]
    Hid(#[from] HidError),
    #[error("cannot receive TUIO on {address}: {source}")]
    Bind {
        address: std::net::SocketAddr,
        source: std::io::Error,
    },
    #[error("the source failed unexpectedly: {0}")]
    Panicked(String),
}

/// What to do when an attempt ends without error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WhenDone {
    /// The source is finished (a replay played once).
    Stop,
}

/// Runs `attempt` for source `name` until it is done or the stage stops.
/// Each call of `attempt` gets the sender its frames go to; the attempt
/// ends when its future does.
pub async fn supervise<F, Fut>(
    name: SourceId,
    when_done: WhenDone,
    commands: mpsc::Sender<Command>,
    started: Instant,
    mut attempt: F,
) where
    F: FnMut(mpsc::Sender<ContactFrame>) -> Fut,
    Fut: Future<Output = Result<(), SourceError>> + Send + 'static,
{
    let mut backoff = FIRST_BACKOFF;
    let mut last_complaint: Option<String> = None;
    loop {
        let (frames, frames_rx) = mpsc::channel(SOURCE_QUEUE);
        let began = Instant::now();
        // Spawned, so a panic in the source is contained and reported here.
        let running = tokio::spawn(attempt(frames));
        let mut down = Down::default();
        let forwarded = forward(frames_rx, &commands, started, &mut down).await;
        let outcome = match running.await {
            Ok(outcome) => outcome,
            Err(e) => Err(SourceError::Panicked(e.to_string())),
        };
        if commands.is_closed() {
            return;
        }
        // However the attempt ended, whatever it held is let go, whether
        // or not the source managed to say so itself (a file that ends
        // mid-touch, a sender gone).
        let_go(&name, down, &commands, started).await;
        match outcome {
            Ok(()) => {
                tracing::info!("{name}: {forwarded} frames");
                match when_done {
                    WhenDone::Stop => return,
                }
            }
            Err(e) => {
                if began.elapsed() >= HEALTHY_RUN {
                    backoff = FIRST_BACKOFF;
                }
                let message = e.to_string();
                if last_complaint.as_deref() == Some(message.as_str()) {
                    tracing::debug!("{name}: {message}; retrying in {backoff:?}");
                } else {
                    tracing::warn!("{name}: {message}; retrying in {backoff:?}");
                    last_complaint = Some(message);
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(MAX_BACKOFF);
            }
        }
    }
}

/// The stage's replay inputs, each playing or paused: the replay tasks
/// wait while theirs is paused, the stream toggles them, and every client
/// gets the `inputs` message made here on every change. The message also
/// carries the MIDI inputs' learning (`midi_learn`), which changes
/// through [`Replays::midi`].
pub struct Replays {
    names: Vec<String>,
    playing: Vec<watch::Sender<bool>>,
    /// The MIDI inputs and what is being learnt; none without MIDI inputs.
    /// Never held across an await.
    midi: std::sync::Mutex<Option<crate::protocol::MidiView>>,
    message: Feed,
}

impl Replays {
    /// Replays by name, each playing or not at start.
    pub fn new(replays: Vec<(String, bool)>) -> Replays {
        let (names, playing): (Vec<_>, Vec<_>) = replays
            .into_iter()
            .map(|(name, playing)| (name, watch::channel(playing).0))
            .unzip();
        let replays = Replays {
            names,
            playing,
            midi: std::sync::Mutex::new(None),
            message: watch::channel(Published::nothing()).0,
        };
        replays.publish();
        replays
    }

    /// The newest `inputs` message.
    pub fn message(&self) -> State {
        self.message.subscribe()
    }

    /// Plays or pauses the replay called `name`.
    pub fn set(&self, name: &str, playing: bool) -> Result<(), String> {
        let index = self
            .names
            .iter()
            .position(|n| n == name)
            .ok_or_else(|| format!("source: no replay input is called {name:?}"))?;
        self.set_index(index, playing);
        Ok(())
    }

    fn set_index(&self, index: usize, playing: bool) {
        if self.playing[index].send_replace(playing) != playing {
            self.publish();
        }
    }

    /// No replay is playing.
    pub fn idle(&self) -> bool {
        self.playing.iter().all(|p| !*p.borrow())
    }

    /// Looks at or changes the MIDI part of the message (made with no
    /// input named when there was none), publishing it if it changed;
    /// returns what `change` did.
    pub fn midi<T>(&self, change: impl FnOnce(&mut crate::protocol::MidiView) -> T) -> T {
        let (done, changed) = {
            let mut midi = self.midi.lock().unwrap_or_else(|p| p.into_inner());
            let view = midi.get_or_insert_with(Default::default);
            let before = view.clone();
            let done = change(view);
            (done, *view != before)
        };
        if changed {
            self.publish();
        }
        done
    }

    fn publish(&self) {
        let midi = self.midi.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let replays = self
            .names
            .iter()
            .zip(&self.playing)
            .map(|(name, playing)| crate::protocol::ReplayView {
                name: name.clone(),
                playing: *playing.borrow(),
            })
            .collect();
        self.message
            .send_replace(Published::of(crate::protocol::ServerMessage::Inputs {
                replays,
                midi,
            }));
    }
}

/// Runs replay `index` of `replays` whenever it is playing: each run gets a
/// fresh frame channel (from `attempt`) forwarded to the stage thread. A
/// pause stops the run and lifts its contacts; playing again starts it
/// from the beginning. A run that ends repeats (`repeat`) or pauses the
/// replay. Returns when the stage stops.
pub async fn run_replay<F, Fut>(
    replays: Arc<Replays>,
    index: usize,
    repeat: bool,
    commands: mpsc::Sender<Command>,
    started: Instant,
    mut attempt: F,
) where
    F: FnMut(mpsc::Sender<ContactFrame>) -> Fut,
    Fut: Future<Output = ()> + Send + 'static,
{
    let name = replays.names[index].clone();
    let mut playing = replays.playing[index].subscribe();
    loop {
        if playing.wait_for(|p| *p).await.is_err() {
            return;
        }
        let (frames, frames_rx) = mpsc::channel(SOURCE_QUEUE);
        // Spawned, so a panic in the source is contained.
        let running = tokio::spawn(attempt(frames));
        // Outside the forwarding, so a pause that cuts it short keeps it.
        let mut down = Down::default();
        let paused = tokio::select! {
            forwarded = forward(frames_rx, &commands, started, &mut down) => {
                tracing::info!("{name}: {forwarded} frames");
                false
            }
            _ = playing.wait_for(|p| !*p) => true,
        };
        if paused {
            running.abort();
            let _ = running.await;
            tracing::info!("{name}: paused");
        } else {
            let _ = running.await;
        }
        if commands.is_closed() {
            return;
        }
        // Whatever it held is let go: a run cut short never lifted it, and
        // a file may end (or its writer vanish) mid-touch.
        let_go(&SourceId::from(name.as_str()), down, &commands, started).await;
        if !paused && !repeat {
            replays.set_index(index, false);
        }
    }
}

/// What an input's frames put down and did not lift, by the source each
/// frame names (a recording's sources, a TUIO port's senders: not the
/// input's own name), kept as they pass the forwarder so that whatever is
/// still down when the input ends is lifted, however it ends. At most
/// `MAX_TRACKED_PER_INPUT` contacts.
#[derive(Debug, Default)]
pub struct Down {
    /// By source: its last frame's time, and each contact down with where
    /// it was last.
    held: HashMap<SourceId, (f64, BTreeMap<u32, glam::DVec2>)>,
    count: usize,
}

impl Down {
    /// Notes what `frame` puts down, moves and lifts.
    fn note(&mut self, frame: &ContactFrame) {
        use puppetry_limits::contacts::MAX_TRACKED_PER_INPUT;
        let entry = self.held.entry(frame.source.clone()).or_default();
        entry.0 = frame.time;
        for c in &frame.contacts {
            match c.phase {
                Phase::Up => {
                    self.count -= usize::from(entry.1.remove(&c.id).is_some());
                }
                Phase::Down | Phase::Move => {
                    if let Some(at) = entry.1.get_mut(&c.id) {
                        *at = c.position;
                    } else if self.count < MAX_TRACKED_PER_INPUT {
                        entry.1.insert(c.id, c.position);
                        self.count += 1;
                    }
                }
            }
        }
        if entry.1.is_empty() {
            self.held.remove(&frame.source);
        }
    }

    /// A frame lifting each source's contacts still down, by source name.
    fn lifts(self) -> Vec<ContactFrame> {
        let mut lifts: Vec<ContactFrame> = self
            .held
            .into_iter()
            .map(|(source, (time, down))| ContactFrame {
                source,
                time,
                contacts: down
                    .into_iter()
                    .map(|(id, at)| Contact::new(id, Phase::Up, at))
                    .collect(),
            })
            .collect();
        lifts.sort_by(|a, b| a.source.cmp(&b.source));
        lifts
    }
}

/// An input has ended: everything its frames left down is lifted, and
/// whatever its own name holds is let go.
async fn let_go(name: &SourceId, down: Down, commands: &mpsc::Sender<Command>, started: Instant) {
    lift(down, commands, started).await;
    let _ = commands.send(crate::convert::release(name.as_str())).await;
}

/// Lifts everything `down` holds, as frames of their sources.
pub async fn lift(down: Down, commands: &mpsc::Sender<Command>, started: Instant) {
    for frame in down.lifts() {
        let received = started.elapsed().as_secs_f64();
        if commands
            .send(crate::convert::frame(frame, received))
            .await
            .is_err()
        {
            return;
        }
    }
}

/// Forwards a source's frames to the stage thread, stamping each with its
/// arrival on the daemon's clock, until the source ends or the stage stops;
/// returns how many went through, noting in `down` what they left down. A
/// full command queue makes the source wait: no contact down or up is
/// dropped.
pub async fn forward(
    mut frames: mpsc::Receiver<ContactFrame>,
    commands: &mpsc::Sender<Command>,
    started: Instant,
    down: &mut Down,
) -> usize {
    let mut forwarded = 0;
    while let Some(frame) = frames.recv().await {
        down.note(&frame);
        let received = started.elapsed().as_secs_f64();
        if commands
            .send(crate::convert::frame(frame, received))
            .await
            .is_err()
        {
            break;
        }
        forwarded += 1;
    }
    forwarded
}

#[cfg(test)]
mod tests {
    use super::*;
    use puppetry_input::{Contact, Phase};
    use puppetry_stage::Change;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[tokio::test(start_paused = true)]
    async fn a_failing_source_is_lifted_and_retried_and_a_panic_is_contained() {
        let (commands, mut received) = mpsc::channel(16);
        let attempts = Arc::new(AtomicUsize::new(0));
        let counted = attempts.clone();
        let started = Instant::now();
        let paused_clock = tokio::time::Instant::now();
        let supervisor = tokio::spawn(supervise(
            SourceId::from("flaky"),
            WhenDone::Stop,
            commands,
            started,
            move |frames: mpsc::Sender<ContactFrame>| {
                let attempt = counted.fetch_add(1, Ordering::SeqCst);
                async move {
                    match attempt {
                        0 => Err(SourceError::Panicked("the port went away".into())),
                        1 => panic!("a bug in a decoder"),
                        _ => {
                            let frame = ContactFrame {
                                source: SourceId::from("flaky"),
                                time: 0.0,
                                contacts: vec![Contact::new(1, Phase::Down, glam::DVec2::ZERO)],
                            };
                            let _ = frames.send(frame).await;
                            Ok(())
                        }
                    }
                }
            },
        ));
        let mut seen = Vec::new();
        while let Some(command) = received.recv().await {
            seen.push(match command {
                Command::Change {
                    change: Change::Release { source },
                    ..
                } => format!("release {source}"),
                Command::Change {
                    change: Change::Contacts { frame },
                    ..
                } => format!("frame {}", frame.source),
                other => format!("{other:?}"),
            });
        }
        supervisor.await.unwrap();
        // Each attempt's end lets go of what it held, the good one's too:
        // its finger, left down, is lifted (a frame), then its name.
        assert_eq!(
            seen,
            [
                "release flaky",
                "release flaky",
                "frame flaky",
                "frame flaky",
                "release flaky"
            ]
        );
        assert_eq!(attempts.load(Ordering::SeqCst), 3, "done after a good run");
        // Two backoffs were waited, 1 s then 2 s (tokio's paused clock
        // jumps through them).
        assert!(paused_clock.elapsed() >= Duration::from_secs(3));
    }
}
