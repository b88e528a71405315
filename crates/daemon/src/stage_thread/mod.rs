//! The stage thread: owns the [`Stage`] and its solvers, takes commands
//! (input frames, pins) from a bounded channel and publishes each solve as a
//! binary frame encoded once. Solving never runs in an async task. When input
//! arrives faster than it solves, every pending command is applied — so no
//! contact down or up is lost — and only the newest state is solved.
//!
//! Painted weights on a free-form puppet mean a new ARAP registration
//! (seconds' worth of factoring on a big mesh): it runs on a worker thread
//! while frames keep coming from the old solver, and the worker hands the
//! new one back as a command, which swaps it in between two solves.

mod batch;
mod publish;
mod rebuild;
mod taking;

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

use tokio::sync::{mpsc, oneshot, watch};

use puppetry_deform::Arap;
use puppetry_stage::{Change, CommandError, GridExport, Stage, WeightsFile};

use crate::lineup::{Lineup, LineupChange};
use crate::protocol::CursorView;
use puppetry_stage::config::StageConfig;

use batch::Batch;
use publish::Publisher;
use taking::Taking;
pub use taking::{BeingRecorded, ShowReading};

pub(crate) use crate::outputs::State;
pub use crate::outputs::Timings;
pub(crate) use crate::outputs::{Published, PublishedHandles, PuppetOutput};
use publish::{cursors_message, published_handles};

/// What the stage thread publishes.
pub struct Outputs {
    /// The puppets on stage and each one's outputs.
    pub(crate) lineup: watch::Receiver<Arc<Lineup>>,
    /// The newest "cursors" message.
    pub(crate) cursors: State,
    /// The newest "take" message (recording and playing now).
    pub(crate) take: State,
    /// Bumped after each publish, so clients wait on one signal.
    pub(crate) changes: watch::Receiver<u64>,
    pub(crate) timings: Arc<Timings>,
}

/// The stage thread's answer to a request.
pub type Reply<T> = oneshot::Sender<Result<T, CommandError>>;

/// What the stage thread is asked to do.
#[derive(Debug)]
pub enum Command {
    /// A change to the stage, from any source: an input frame, a source
    /// gone, a pin, a brush dab, a key pose, the key cursor… (the one
    /// conversion that makes them is [`crate::convert`]). `received`: when
    /// an input frame reached the daemon (seconds since it started);
    /// `reply`: whether it applied, for an asker who waits.
    Change {
        /// What to apply.
        change: Change,
        /// Seconds since the daemon started when an input frame reached
        /// it (the frames it causes carry it as `input_time`); none for
        /// other changes.
        received: Option<f64>,
        /// Told whether it applied; none when no one waits.
        reply: Option<Reply<()>>,
    },
    /// A source may grab only these puppets (`None`: any), e.g. a
    /// performer limited to named puppets.
    Limit {
        /// The source limited (`client:N`, a relay's `relay:…`).
        source: String,
        /// Puppet ids it may grab; `None`: any.
        puppets: Option<Vec<u32>>,
    },
    /// A mouse's cursor moved (`None`: the mouse went away).
    Cursor {
        /// The mouse input's name.
        source: String,
        /// Where it is and what it holds; `None`: it went away.
        cursor: Option<CursorView>,
    },
    /// Undo, redo or reset a puppet's edits.
    Edit {
        /// Whose history.
        puppet: u32,
        /// Which.
        edit: Edit,
        /// Told whether it could be done.
        reply: Reply<()>,
    },
    /// The grid of a grid puppet, rest and deformed.
    ExportGrid {
        /// A grid puppet.
        puppet: u32,
        /// Gets the grid, or why there is none.
        reply: Reply<GridExport>,
    },
    /// The puppet's mesh file with the painted weights (the asker makes
    /// the text and writes it: the stage thread does no file I/O).
    SaveWeights {
        /// The puppet whose weights are saved.
        puppet: u32,
        /// Gets the file's content and where it goes.
        reply: Reply<WeightsFile>,
    },
    /// A worker rebuilt a free-form puppet's solver with painted weights
    /// (`None`: it failed).
    Rebuilt {
        /// The puppet rebuilt.
        puppet: u32,
        /// The weights generation it was built from: when the puppet was
        /// painted again meanwhile, another rebuild follows.
        generation: u64,
        /// The new solver; `None`: registering it failed (logged).
        arap: Option<Box<Arap>>,
    },
    /// One step of a take played back: applied and solved on its own, so
    /// with no live input between it gives the frames the take recorded.
    Played {
        /// The step's changes, its sources renamed and what live
        /// performers replace left out.
        changes: Vec<Change>,
        /// Seconds since the daemon started when the player handed it over.
        received: f64,
    },
    /// Start recording a take into the takes folder (`None`: the next free
    /// `take-NNN`); `layers` names takes played into it.
    StartTake {
        /// The take's name; `None`: the next free `take-NNN`.
        name: Option<String>,
        /// The takes played into it (an overdub's).
        layers: Vec<String>,
        /// Gets the take's name, or why it did not start.
        reply: oneshot::Sender<Result<String, String>>,
    },
    /// Stop the take being recorded; answers its name.
    StopTake {
        /// Gets the take's name, or why nothing stopped.
        reply: oneshot::Sender<Result<String, String>>,
    },
    /// The key file of a puppet, to write (the asker writes it).
    SaveKeys {
        /// The puppet whose keys are saved.
        puppet: u32,
        /// Gets the key file's path and content.
        reply: Reply<(PathBuf, puppetry_stage::keys::KeyFile)>,
    },
    /// A player asks to start playing a take: refused if it is the take
    /// being recorded, else it is the take playing (the take state says).
    PlayStarting {
        /// The take's name (its sources play as `NAME/SOURCE`).
        name: String,
        /// Its file, compared with the take being recorded.
        path: PathBuf,
        /// Told whether it may play.
        reply: oneshot::Sender<Result<(), taking::BeingRecorded>>,
    },
    /// The take playing ended (played out, stopped or failed): what its
    /// sources still hold lets go, and an overdub of it stops.
    PlayEnded {
        /// The take's name, as in its `PlayStarting`.
        name: String,
    },
    /// Add, remove or reorder puppets (refused while a take records);
    /// answers the puppet added or removed (0 for a new order).
    Lineup {
        /// What changes.
        change: LineupChange,
        /// Gets the puppet added or removed (0 for a new order), or why
        /// the change was refused.
        reply: Reply<u32>,
    },
    /// The show's clock was heard (MIDI Time Code, MIDI clock, an OSC
    /// time message): a take recording keeps it beside its own time.
    Clock {
        /// Where the show's clock is.
        show: taking::ShowReading,
        /// When the reading reached the daemon.
        at: std::time::Instant,
    },
    /// End the thread (the daemon is shutting down).
    Stop,
}

/// What an [`Command::Edit`] does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edit {
    /// Put back what the last edit replaced.
    Undo,
    /// Do again what the last undo took back.
    Redo,
    /// Back as loaded (weights, pins, rest pose, cursor let go), as one
    /// undoable step.
    Reset,
}

/// Where takes go, and whether one starts by itself.
#[derive(Debug, Clone)]
pub struct TakeSettings {
    /// The takes folder (`serve --takes`): takes are recorded into it.
    pub dir: PathBuf,
    /// The stage file, as takes name it.
    pub stage_file: String,
    /// How many puppets the stage file itself has: the puppets after them
    /// (pictures brought back from the puppets folder, puppets added from
    /// the page) are carried in the take's header, entries and all.
    pub file_puppets: usize,
    /// Start a take with the first change (`serve --record`).
    pub record_from_first_input: bool,
    /// The daemon's clock (`pong`'s): the take state says when takes
    /// began in it, so a page plays a soundtrack in time.
    pub started: Instant,
}

/// Starts the stage thread; returns what it publishes. The thread stops
/// when every command sender is dropped; `wake` (a weak sender of the same
/// channel) is how solver rebuilds come back.
pub(crate) fn spawn(
    config: StageConfig,
    stage: Stage,
    mut commands: mpsc::Receiver<Command>,
    wake: mpsc::WeakSender<Command>,
    takes: TakeSettings,
) -> (Outputs, JoinHandle<()>) {
    let (mut driver, outputs) = StageDriver::new(config, stage, takes, wake);
    let pool = solve_pool();
    let thread = std::thread::Builder::new()
        .name("stage".into())
        .spawn(move || {
            // The loop runs on a worker of the stage's own pool: when a
            // frame moves several puppets they are solved side by side on
            // the pool, the loop's own thread taking its share instead of
            // waiting, and no other user of rayon's global pool competes.
            pool.install(move || {
                while let Some(first) = commands.blocking_recv() {
                    driver.begin();
                    let mut next = Some(first);
                    while let Some(command) = next.take() {
                        driver.command(command);
                        if driver.stopped() {
                            // Dropping the publisher tells every client to close.
                            driver.shut_down();
                            return;
                        }
                        // Catch up: apply everything already waiting, solve once.
                        next = commands.try_recv().ok();
                    }
                    driver.finish();
                }
                driver.shut_down();
            });
        })
        .expect("spawn the stage thread");
    (outputs, thread)
}

/// The stage thread's loop, one command at a time: `spawn` runs it on
/// its thread, draining the command channel and solving once per batch; a
/// simulated show drives it by hand, so it runs exactly the code a show
/// does (takes recorded, played, overdubbed and stopped included) with the
/// interleavings chosen by the test.
pub struct StageDriver {
    stage: Stage,
    publisher: Publisher,
    taking: Taking,
    cursors: BTreeMap<String, CursorView>,
    batch: Batch,
    lineup: watch::Sender<Arc<Lineup>>,
    wake: mpsc::WeakSender<Command>,
}

impl StageDriver {
    /// The loop for `stage`, solved once (pins from the stage file are
    /// handles before any input), and the publishing ends for its
    /// puppets. Solver rebuilds come back through `wake` as
    /// [`Command::Rebuilt`].
    pub fn new(
        config: StageConfig,
        mut stage: Stage,
        takes: TakeSettings,
        wake: mpsc::WeakSender<Command>,
    ) -> (StageDriver, Outputs) {
        let (changes, changes_rx) = watch::channel(0u64);
        let cursors = BTreeMap::new();
        let (cursors_tx, cursors_rx) = watch::channel(cursors_message(&cursors));
        let mut publisher = Publisher {
            frames: Vec::new(),
            rigs: Vec::new(),
            handles: Vec::new(),
            weights: Vec::new(),
            weights_published: Vec::new(),
            keys: Vec::new(),
            keys_published: Vec::new(),
            handle_frames: Vec::new(),
            handle_points: Vec::new(),
            history: Vec::new(),
            history_published: Vec::new(),
            poses: Vec::new(),
            poses_published: Vec::new(),
            depths: Vec::new(),
            depths_published: Vec::new(),
            sequences: Vec::new(),
            arenas: Vec::new(),
            cursors: cursors_tx,
            changes,
        };
        // The first weights, keys, history and pose messages hold the state
        // as loaded: connections send them at once, so nothing is published
        // for them.
        let outputs: Vec<PuppetOutput> = (0..stage.puppets().len() as u32)
            .map(|id| publisher.add_puppet(&stage, id))
            .collect();
        let config = Arc::new(config);
        let (lineup_tx, lineup_rx) = watch::channel(Lineup::of(&stage, outputs, 0, config.clone()));
        let (state_tx, state_rx) = watch::channel(Published::nothing());
        let taking = Taking {
            settings: takes,
            config,
            recorder: None,
            fresh: true,
            lineup_changed: false,
            step: Vec::new(),
            events: Vec::new(),
            playing: None,
            playing_since: None,
            held: BTreeMap::new(),
            played: BTreeSet::new(),
            ended: BTreeSet::new(),
            overdub_of: None,
            announce: false,
            error: None,
            state: state_tx,
        };
        taking.state.send_replace(taking.state_message());
        let solved = stage.solve();
        publisher.publish(&stage, &solved, 0.0);
        let timings = Arc::new(Timings::default());
        let outputs = Outputs {
            lineup: lineup_rx,
            cursors: cursors_rx,
            take: state_rx,
            changes: changes_rx,
            timings: timings.clone(),
        };
        let driver = StageDriver {
            stage,
            publisher,
            taking,
            cursors,
            batch: Batch::new(timings),
            lineup: lineup_tx,
            wake,
        };
        (driver, outputs)
    }

    /// The stage as the last command left it.
    pub fn stage(&self) -> &Stage {
        &self.stage
    }

    /// The take being recorded, if any.
    pub fn recording(&self) -> Option<&str> {
        self.taking.recorder.as_ref().map(|r| r.name())
    }

    /// A batch of commands begins (for the timings).
    pub(crate) fn begin(&mut self) {
        self.batch.started = Instant::now();
    }

    /// Whether a [`Command::Stop`] came.
    pub(crate) fn stopped(&self) -> bool {
        self.batch.stop
    }

    /// Applies one command. Most wait for [`StageDriver::finish`] to be
    /// solved with the rest of their batch; a line-up change, a played step
    /// and a take's start, stop or end solve what came before them first,
    /// so each lands on the stage (and in the take) it belongs to.
    pub fn command(&mut self, command: Command) {
        let StageDriver {
            stage,
            publisher,
            taking,
            cursors,
            batch,
            lineup,
            wake,
        } = self;
        match command {
            Command::Lineup { change, reply } => {
                // What came before lands on the old lineup.
                batch.finish(stage, publisher, taking, cursors);
                let result = change_lineup(stage, publisher, taking, lineup, change);
                let _ = reply.send(result);
                batch.dirty = true;
                batch.finish(stage, publisher, taking, cursors);
            }
            Command::Played { changes, received } => {
                // A played step is solved on its own, as it was when it
                // was recorded.
                batch.finish(stage, publisher, taking, cursors);
                for change in changes {
                    taking.note_played(&change);
                    batch.apply(stage, taking, change, None, wake);
                }
                batch.newest = received;
                batch.finish(stage, publisher, taking, cursors);
            }
            Command::PlayEnded { name } => {
                // What came before is solved (and recorded) first; the
                // take's sources let go in a step of their own, recorded
                // into an overdub before it stops.
                batch.finish(stage, publisher, taking, cursors);
                batch.let_go_of_played(stage, taking, Some(&name), wake);
                batch.finish(stage, publisher, taking, cursors);
                taking.ended(stage, &name, &publisher.changes);
            }
            command => {
                if matches!(
                    command,
                    Command::StartTake { .. } | Command::StopTake { .. }
                ) {
                    // What came before belongs to the take stopping (or to
                    // none, not the take starting): solve and record it
                    // first.
                    batch.finish(stage, publisher, taking, cursors);
                }
                batch.command(stage, taking, cursors, command, wake, &publisher.changes);
            }
        }
    }

    /// Solves what the batch applied, publishes it and records it.
    pub fn finish(&mut self) {
        self.batch.finish(
            &mut self.stage,
            &mut self.publisher,
            &mut self.taking,
            &self.cursors,
        );
    }

    /// The loop ends: the take being recorded stops ("shutdown").
    pub fn shut_down(&mut self) {
        if self.taking.recorder.is_some() {
            let _ = self.taking.stop(&mut self.stage, "shutdown");
        }
    }
}

/// The threads the stage thread's loop and its puppets' solves run on: one
/// per core, up to 4 (the loop's own is one of them). Named "stage" like
/// the thread that starts them, so the kernel's accounting of "stage" is
/// all the stage's work.
fn solve_pool() -> rayon::ThreadPool {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get().clamp(2, 4));
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|_| "stage".into())
        .build()
        .expect("start the stage's solver threads")
}

/// Adds, removes or reorders puppets and publishes the new lineup, which
/// every connection follows. Refused while a take records: a take's puppets
/// are fixed when it starts.
fn change_lineup(
    stage: &mut Stage,
    publisher: &mut Publisher,
    taking: &mut Taking,
    lineup: &watch::Sender<Arc<Lineup>>,
    change: LineupChange,
) -> Result<u32, CommandError> {
    if let Some(r) = &taking.recorder {
        return Err(CommandError::Busy {
            problem: format!("take {} is recording: stop it first", r.name()),
        });
    }
    let mut config = lineup.borrow().config.clone();
    let (answer, added) = match change {
        LineupChange::Add(added) => {
            let (puppet, entry) = *added;
            let id = stage
                .add_puppet(puppet, &entry)
                .map_err(|e| CommandError::Load {
                    problem: e.to_string(),
                })?;
            Arc::make_mut(&mut config).puppets.push(entry);
            (id, Some(publisher.add_puppet(stage, id)))
        }
        LineupChange::Remove(id) => {
            stage.remove_puppet(id)?;
            // Its handles let go: show control, which keeps following the
            // stage file's puppets, sees the set empty.
            publisher.handles[id as usize].send_replace(published_handles(stage, id));
            (id, None)
        }
        LineupChange::Order(order) => {
            stage.set_order(&order)?;
            (0, None)
        }
    };
    taking.config = config.clone();
    lineup.send_modify(|old| {
        let mut outputs = old.outputs.clone();
        outputs.extend(added);
        *old = Lineup::of(stage, outputs, old.revision + 1, config);
    });
    taking.lineup_changed = true;
    Ok(answer)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytes::Bytes;
    use glam::DVec2;
    use puppetry_input::{Contact, ContactFrame, Phase, SourceId};

    #[global_allocator]
    static ALLOCATOR: puppetry_testkit::alloc::Counting = puppetry_testkit::alloc::Counting;

    /// The stage thread's whole iteration — a contact frame in, applied
    /// to the stage, the puppet solved, its frames encoded and published,
    /// the clients woken — allocates nothing once a drag is under way and
    /// the clients keep up (they drop each frame once sent, so its buffer
    /// comes back for the next).
    #[test]
    fn a_stage_iteration_from_contacts_to_frame_bytes_does_not_allocate() {
        let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/demo.toml");
        let config = StageConfig::load(&file).expect("the demo stage loads");
        let stage = Stage::from_config(&config).expect("the demo stage builds");
        let at = DVec2::from(config.puppets[0].at);
        let takes = TakeSettings {
            dir: std::env::temp_dir(),
            stage_file: "demo.toml".into(),
            file_puppets: config.puppets.len(),
            record_from_first_input: false,
            started: Instant::now(),
        };
        let (_keep, wake) = {
            let (tx, _rx) = mpsc::channel::<Command>(1);
            let weak = tx.downgrade();
            (tx, weak)
        };
        let (driver, outputs) = StageDriver::new(config, stage, takes, wake.clone());
        let StageDriver {
            mut stage,
            mut publisher,
            mut taking,
            cursors,
            mut batch,
            ..
        } = driver;
        let lineup = outputs.lineup.borrow().clone();
        let mut clients: Vec<watch::Receiver<Option<Bytes>>> = lineup
            .outputs
            .iter()
            .flat_map(|o| [o.frame.clone(), o.handle_frame.clone()])
            .collect();
        let source = SourceId::from("test");
        let frame = |k: usize, phase| {
            let angle = k as f64 * 0.05;
            crate::convert::frame(
                ContactFrame {
                    source: source.clone(),
                    time: k as f64 * 1e-3,
                    contacts: vec![Contact::new(
                        1,
                        phase,
                        at + DVec2::new(angle.cos() - 1.0, angle.sin()) * 20.0,
                    )],
                },
                k as f64 * 1e-3,
            )
        };
        let mut commands: Vec<Command> = (0..200)
            .map(|k| frame(k, if k == 0 { Phase::Down } else { Phase::Move }))
            .collect();
        let changes = publisher.changes.clone();
        let mut sent = 0;
        let mut iterate =
            |command: Command,
             stage: &mut Stage,
             publisher: &mut Publisher,
             clients: &mut [watch::Receiver<Option<Bytes>>]| {
                batch.command(
                    stage,
                    &mut taking,
                    &mut BTreeMap::new(),
                    command,
                    &wake,
                    &changes,
                );
                batch.finish(stage, publisher, &mut taking, &cursors);
                // A client sends what changed and lets it go.
                for client in clients.iter_mut() {
                    if client.has_changed().unwrap_or(false) {
                        let frame = client.borrow_and_update().clone();
                        sent += usize::from(frame.is_some());
                    }
                }
            };
        let warm_up: Vec<Command> = commands.drain(..20).collect();
        for command in warm_up {
            iterate(command, &mut stage, &mut publisher, &mut clients);
        }
        let ((), allocations) = puppetry_testkit::alloc::count(|| {
            for command in commands.drain(..) {
                iterate(command, &mut stage, &mut publisher, &mut clients);
            }
        });
        assert!(
            sent >= 2 * 200,
            "every iteration published a frame and handles: {sent}"
        );
        assert_eq!(
            allocations, 0,
            "180 iterations allocated {allocations} times"
        );
    }
}
