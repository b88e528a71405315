//! Playing takes into the live stage: a player thread reads a take step by
//! step and hands each step to the stage thread at the time it was
//! recorded (or at once with `fast`), renaming its sources so they never
//! collide with live ones. Overdub leaves out what the live performers
//! replace: the played take's contacts from named sources, or those that
//! grabbed a material point inside a region of the rest shape.
//!
//! Reading runs on a thread of its own (takes are files; the async tasks
//! never wait on the disk); steps reach the stage thread through the same
//! bounded command channel as every source, so none is dropped.
//!
//! The stage thread takes a take on before its first step (it refuses the
//! take being recorded: played into itself it would grow as it plays) and
//! is told when it ends however it ends (played out, stopped, a bad
//! record, the player's own failure), so every handle the take's sources
//! hold ends with it: a take recorded with a finger still down must not
//! leave that finger on the stage.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use glam::DVec2;
use puppetry_input::{Phase, SourceId};
use puppetry_stage::{Change, GripEvent, StageEvent};
use puppetry_take::{PuppetInfo, Record, Step, TakeReader};
use tokio::sync::{mpsc, oneshot};

use crate::protocol::Region;
use crate::stage_thread::Command;

/// How a take is played.
#[derive(Debug, Clone, Default)]
pub struct PlayOptions {
    /// As fast as the stage takes the steps, not at their recorded times.
    pub fast: bool,
    /// Contacts that grabbed a material point inside one of these are left
    /// out (a live performer re-records that part).
    pub replace: Vec<Region>,
    /// Contacts of these recorded sources are left out.
    pub replace_sources: Vec<String>,
}

/// Why a take cannot be played, or stopped playing early.
#[derive(Debug, thiserror::Error)]
pub enum PlayError {
    /// The take file cannot be opened or read (missing, not a take, a
    /// damaged record).
    #[error(transparent)]
    Take(#[from] puppetry_take::TakeError),
    /// The take was recorded with other puppets than the stage has (by
    /// name, rest mesh or rig and pins).
    #[error("{file}: {problem}")]
    Stage {
        /// The take file.
        file: String,
        /// Which puppet differs, and how.
        problem: String,
    },
    /// The take asked for is the one being recorded.
    #[error(transparent)]
    Recording(#[from] crate::stage_thread::BeingRecorded),
    /// The stage thread ended (the daemon is shutting down) before or
    /// while the take played.
    #[error("{file}: the stage stopped")]
    StageStopped {
        /// The take, by name (or by file, once it played).
        file: String,
    },
    /// The player's thread could not be started.
    #[error("cannot start a player: {0}")]
    Thread(std::io::Error),
    /// The player's thread panicked.
    #[error("the player panicked")]
    Panicked,
}

/// A take playing.
pub(crate) struct Player {
    pub name: String,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<usize, PlayError>>>,
    /// The stage thread's answer to the take starting, until asked for.
    started: Option<oneshot::Receiver<Result<(), PlayError>>>,
}

impl Player {
    /// Asks the player to stop after the step it is on.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Waits until the stage thread has taken the take on, or refused it
    /// (then the player has ended: nothing of the take was played).
    pub async fn started(&mut self) -> Result<(), PlayError> {
        match self.started.take() {
            Some(answer) => answer.await.unwrap_or_else(|_| {
                Err(PlayError::StageStopped {
                    file: self.name.clone(),
                })
            }),
            None => Ok(()),
        }
    }

    /// Waits for the player; returns the steps played.
    pub fn join(mut self) -> Result<usize, PlayError> {
        match self.thread.take() {
            Some(t) => t.join().unwrap_or(Err(PlayError::Panicked)),
            None => Ok(0),
        }
    }
}

/// Tells the stage thread the take ended when the player thread ends, by
/// returning or by unwinding, so its handles never outlive it.
struct Ending<'a> {
    name: &'a str,
    commands: &'a mpsc::Sender<Command>,
}

impl Drop for Ending<'_> {
    fn drop(&mut self) {
        let _ = self.commands.blocking_send(Command::PlayEnded {
            name: self.name.to_string(),
        });
    }
}

/// Opens the take at `path`, checks it against the stage's puppets and
/// starts playing it. The stage thread may still refuse it (the take being
/// recorded): [`Player::started`] says.
pub(crate) fn play(
    path: &Path,
    puppets: &[PuppetInfo],
    options: PlayOptions,
    commands: mpsc::Sender<Command>,
    started: Instant,
) -> Result<Player, PlayError> {
    let playback = Playback::open(path, puppets, options)?;
    let name = playback.name().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let stopping = stop.clone();
    let label = name.clone();
    let (answer, started_rx) = oneshot::channel();
    let file = path.to_path_buf();
    let thread = std::thread::Builder::new()
        .name(format!("play {name}"))
        .spawn(move || {
            let (reply, taken) = oneshot::channel();
            let asked = commands.blocking_send(Command::PlayStarting {
                name: label.clone(),
                path: file,
                reply,
            });
            let taken = match asked {
                Ok(()) => match taken.blocking_recv() {
                    Ok(started) => started.map_err(PlayError::from),
                    Err(_) => Err(PlayError::StageStopped {
                        file: label.clone(),
                    }),
                },
                Err(_) => Err(PlayError::StageStopped {
                    file: label.clone(),
                }),
            };
            if let Err(e) = taken {
                let _ = answer.send(Err(e));
                return Ok(0);
            }
            let _ = answer.send(Ok(()));
            // From here the take's end reaches the stage thread whatever
            // happens, a panic included.
            let _ending = Ending {
                name: &label,
                commands: &commands,
            };
            run(playback, &commands, started, &stopping)
        })
        .map_err(PlayError::Thread)?;
    Ok(Player {
        name,
        stop,
        thread: Some(thread),
        started: Some(started_rx),
    })
}

/// Why a take does not fit the stage it is played into.
fn check(recorded: &[PuppetInfo], stage: &[PuppetInfo]) -> Result<(), String> {
    if recorded.len() != stage.len() {
        return Err(format!(
            "recorded with {} puppets, the stage has {}",
            recorded.len(),
            stage.len()
        ));
    }
    for (i, (r, s)) in recorded.iter().zip(stage).enumerate() {
        let setup_differs = !r.setup_hash.is_empty() && r.setup_hash != s.setup_hash;
        if r.name != s.name || r.rest_hash != s.rest_hash || setup_differs {
            return Err(format!(
                "puppets[{i}]: recorded as {:?} (rest mesh {}, rig and pins {}), the stage has {:?} (rest mesh {}, rig and pins {})",
                r.name, r.rest_hash, r.setup_hash, s.name, s.rest_hash, s.setup_hash
            ));
        }
    }
    Ok(())
}

/// Plays `playback` into the stage at its recorded times (or at once).
fn run(
    mut playback: Playback,
    commands: &mpsc::Sender<Command>,
    started: Instant,
    stop: &AtomicBool,
) -> Result<usize, PlayError> {
    let began = Instant::now();
    let mut played = 0;
    let fast = playback.filter.options.fast;
    while let Some(step) = playback.next_step() {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let (t, changes) = step?;
        if !fast {
            let due = began + Duration::from_secs_f64(t.max(0.0));
            // Sleep in short slices so a stop request is heard.
            while let Some(wait) = due.checked_duration_since(Instant::now()) {
                if stop.load(Ordering::Relaxed) {
                    return Ok(played);
                }
                std::thread::sleep(wait.min(Duration::from_millis(50)));
            }
        }
        if changes.is_empty() {
            continue;
        }
        let received = started.elapsed().as_secs_f64();
        if commands
            .blocking_send(Command::Played { changes, received })
            .is_err()
        {
            return Err(PlayError::StageStopped {
                file: playback.file,
            });
        }
        played += 1;
    }
    tracing::info!("take {}: played {played} steps", playback.name);
    Ok(played)
}

/// A take read step by step as the stage plays it: each recorded step
/// becomes the changes one played step applies, its sources renamed and
/// what is replaced left out. The player thread paces it at the recorded
/// times; a simulated show steps it by hand between its other commands.
pub struct Playback {
    name: String,
    file: String,
    reader: TakeReader,
    filter: Filter,
}

impl Playback {
    /// Opens the take at `path` and checks it against the stage's puppets.
    pub fn open(
        path: &Path,
        puppets: &[PuppetInfo],
        options: PlayOptions,
    ) -> Result<Playback, PlayError> {
        let reader = TakeReader::open(path)?;
        check(&reader.header.puppets, puppets).map_err(|problem| PlayError::Stage {
            file: path.display().to_string(),
            problem,
        })?;
        let name = reader.header.name.clone();
        Ok(Playback {
            file: reader.file().to_string(),
            filter: Filter::new(&name, options),
            name,
            reader,
        })
    }

    /// The take's name (its sources play as `NAME/SOURCE`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The next step: its recorded time and its changes (`None` at the
    /// take's end). A step whose changes were all left out (replaced by a
    /// live performer) comes too, empty: its time still paces the take, so
    /// an overdub lasts as long as the take it layers over.
    pub fn next_step(&mut self) -> Option<Result<(f64, Vec<Change>), PlayError>> {
        loop {
            let step = match self.reader.next()? {
                Ok(Record::Step(step)) => step,
                Ok(_) => continue,
                Err(e) => return Some(Err(e.into())),
            };
            let t = step.t;
            return Some(Ok((t, self.filter.step(step))));
        }
    }
}

/// Renames a played take's sources and leaves out what is replaced.
struct Filter {
    prefix: String,
    options: PlayOptions,
    /// Recorded (source, contact) left out until they lift.
    muted: HashSet<(String, u32)>,
}

impl Filter {
    fn new(name: &str, options: PlayOptions) -> Filter {
        Filter {
            prefix: format!("{name}/"),
            options,
            muted: HashSet::new(),
        }
    }

    fn renamed(&self, source: &str) -> String {
        format!("{}{source}", self.prefix)
    }

    /// Whether the contact that made a handle in this step is replaced.
    fn replaced(&self, events: &[StageEvent], source: &str, contact: u32) -> bool {
        if self.options.replace_sources.iter().any(|s| s == source) {
            return true;
        }
        events.iter().any(|e| match e {
            StageEvent::Made {
                puppet,
                owner,
                contact: Some(c),
                grip: GripEvent::Point { rest },
                ..
            } if owner == source && *c == contact => self
                .options
                .replace
                .iter()
                .any(|r| r.puppet == *puppet && rest.distance(DVec2::from(r.at)) <= r.radius),
            _ => false,
        })
    }

    fn step(&mut self, step: Step) -> Vec<Change> {
        let mut out = Vec::with_capacity(step.changes.len());
        for change in step.changes {
            match change {
                Change::Contacts { mut frame } => {
                    let source = frame.source.to_string();
                    let mut kept = Vec::with_capacity(frame.contacts.len());
                    for contact in frame.contacts {
                        let key = (source.clone(), contact.id);
                        let skip = match contact.phase {
                            Phase::Down => {
                                let replaced = self.replaced(&step.events, &source, contact.id);
                                if replaced {
                                    self.muted.insert(key);
                                } else {
                                    self.muted.remove(&key);
                                }
                                replaced
                            }
                            Phase::Move => self.muted.contains(&key),
                            Phase::Up => self.muted.remove(&key),
                        };
                        if !skip {
                            kept.push(contact);
                        }
                    }
                    if !kept.is_empty() {
                        frame.contacts = kept;
                        frame.source = SourceId::new(self.renamed(&source));
                        out.push(Change::Contacts { frame });
                    }
                }
                Change::Release { source } => {
                    self.muted.retain(|(s, _)| *s != source);
                    out.push(Change::Release {
                        source: self.renamed(&source),
                    });
                }
                Change::Pin { owner, at } => out.push(Change::Pin {
                    owner: self.renamed(&owner),
                    at,
                }),
                // The live daemon swaps in its own rebuilt solvers.
                Change::Rebuilt { .. } => {}
                // An undo, redo or reset puts weights and poses back as
                // recorded; its pins are handles of the recorded stage
                // (their ids mean other handles here), so they stay out.
                Change::Restore { puppet, mut state } => {
                    state.pins = None;
                    if state != puppetry_stage::Snapshot::default() {
                        out.push(Change::Restore { puppet, state });
                    }
                }
                other => out.push(other),
            }
        }
        out
    }
}

/// The takes folder's file for a take name, refusing names that would
/// leave the folder.
pub(crate) fn take_path(dir: &Path, name: &str) -> Result<PathBuf, String> {
    let name = name.strip_suffix(".take").unwrap_or(name);
    if !puppetry_take::valid_name(name) {
        return Err(format!(
            "take {name:?}: not a take name (letters, digits, '-', '_' and '.', as `list_takes` names them)"
        ));
    }
    Ok(dir.join(format!("{name}.{}", puppetry_take::EXTENSION)))
}
