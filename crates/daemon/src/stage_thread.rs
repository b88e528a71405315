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

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Instant;

use bytes::{Bytes, BytesMut};
use glam::DVec2;
use tokio::sync::{mpsc, oneshot, watch};

use puppetry_deform::Arap;
use puppetry_input::Phase;
use puppetry_stage::{
    Change, CommandError, GridExport, Grip, HandleKind, Rebuild, Stage, StageEvent, WeightsFile,
};
use puppetry_take::recorder::Recorder;
use puppetry_take::{Frame, Header, Record, Step};

use crate::lineup::{Lineup, LineupChange};
use crate::protocol::{
    self, CursorView, FrameHeader, FrameKind, GripKind, HandleView, ServerMessage, TakeState,
    encode_depth_frame, encode_frame_into,
};
use puppetry_stage::config::StageConfig;

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
        change: Change,
        received: Option<f64>,
        reply: Option<Reply<()>>,
    },
    /// A source may grab only these puppets (`None`: any), e.g. a
    /// performer limited to named puppets.
    Limit {
        source: String,
        puppets: Option<Vec<u32>>,
    },
    /// A mouse's cursor moved (`None`: the mouse went away).
    Cursor {
        source: String,
        cursor: Option<CursorState>,
    },
    /// Undo, redo or reset a puppet's edits.
    Edit {
        puppet: u32,
        edit: Edit,
        reply: Reply<()>,
    },
    /// The grid of a grid puppet, rest and deformed.
    ExportGrid {
        puppet: u32,
        reply: Reply<GridExport>,
    },
    /// The puppet's mesh file with the painted weights (the asker makes
    /// the text and writes it: the stage thread does no file I/O).
    SaveWeights {
        puppet: u32,
        reply: Reply<WeightsFile>,
    },
    /// A worker rebuilt a free-form puppet's solver with painted weights
    /// (`None`: it failed).
    Rebuilt {
        puppet: u32,
        generation: u64,
        arap: Option<Box<Arap>>,
    },
    /// One step of a take played back: applied and solved on its own, so
    /// with no live input between it gives the frames the take recorded.
    Played { changes: Vec<Change>, received: f64 },
    /// Start recording a take into the takes folder (`None`: the next free
    /// `take-NNN`); `layers` names takes played into it.
    StartTake {
        name: Option<String>,
        layers: Vec<String>,
        reply: oneshot::Sender<Result<String, String>>,
    },
    /// Stop the take being recorded; answers its name.
    StopTake {
        reply: oneshot::Sender<Result<String, String>>,
    },
    /// The key file of a puppet, to write (the asker writes it).
    SaveKeys {
        puppet: u32,
        reply: Reply<(PathBuf, puppetry_stage::keys::KeyFile)>,
    },
    /// A player asks to start playing a take: refused if it is the take
    /// being recorded, else it is the take playing (the take state says).
    PlayStarting {
        name: String,
        path: PathBuf,
        reply: oneshot::Sender<Result<(), crate::takes::PlayError>>,
    },
    /// The take playing ended (played out, stopped or failed): what its
    /// sources still hold lets go, and an overdub of it stops.
    PlayEnded { name: String },
    /// Add, remove or reorder puppets (refused while a take records);
    /// answers the puppet added or removed (0 for a new order).
    Lineup {
        change: LineupChange,
        reply: Reply<u32>,
    },
    /// End the thread (the daemon is shutting down).
    Stop,
}

/// What an [`Command::Edit`] does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edit {
    Undo,
    Redo,
    Reset,
}

/// Where takes go, and whether one starts by itself.
#[derive(Debug, Clone)]
pub struct TakeSettings {
    pub dir: PathBuf,
    /// The stage file, as takes name it.
    pub stage_file: String,
    /// Start a take with the first change (`serve --record`).
    pub record_from_first_input: bool,
}

/// A mouse cursor's state, as a mouse source reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CursorState {
    pub at: [f64; 2],
    /// Direction of the pair, radians counter-clockwise from +x.
    pub angle: f64,
    /// Distance between the pair's points; 0 for a one-point mouse.
    pub spacing: f64,
    /// A button is down and the points are grabbing.
    pub holding: bool,
}

/// A puppet's handle set as published: the typed list (newcomers' stage
/// messages include it) and the `handles` message made from it once.
#[derive(Debug)]
pub struct PublishedHandles {
    pub handles: Vec<HandleView>,
    pub text: Arc<str>,
    /// The set's generation (handle frames name the one they follow).
    pub generation: u32,
}

/// The "cursors" message: every mouse cursor on the stage.
pub fn cursors_message(cursors: &BTreeMap<String, CursorState>) -> String {
    let cursors = cursors
        .iter()
        .map(|(source, c)| CursorView {
            source: source.clone(),
            at: c.at,
            angle: c.angle,
            spacing: c.spacing,
            holding: c.holding,
        })
        .collect();
    ServerMessage::Cursors { cursors }.to_text()
}

/// A puppet's handles as clients see them.
pub fn handle_views(stage: &Stage, puppet: u32) -> Vec<HandleView> {
    stage.puppets()[puppet as usize]
        .handles()
        .iter()
        .map(|h| HandleView {
            id: h.id,
            owner: h.owner.to_string(),
            kind: match h.kind {
                HandleKind::Contact => protocol::HandleKind::Contact,
                HandleKind::Pin => protocol::HandleKind::Pin,
                HandleKind::Key => protocol::HandleKind::Key,
            },
            at: [h.target.x, h.target.y],
            grip: match h.grip {
                Grip::Point(_) => GripKind::Point,
                Grip::GridHandle(_) => GripKind::Grid,
                Grip::Joint(_) => GripKind::Joint,
                Grip::Bone { .. } => GripKind::Bone,
            },
            index: match h.grip {
                Grip::Point(_) => None,
                Grip::GridHandle(i) | Grip::Joint(i) | Grip::Bone { index: i, .. } => Some(i),
            },
        })
        .collect()
}

/// The "handles" message of a puppet, with the list it was made from.
pub fn published_handles(stage: &Stage, puppet: u32) -> Arc<PublishedHandles> {
    let handles = handle_views(stage, puppet);
    let generation = stage.puppets()[puppet as usize].handles_generation();
    let text = ServerMessage::Handles {
        puppet,
        generation,
        handles: handles.clone(),
    }
    .to_text();
    Arc::new(PublishedHandles {
        handles,
        text: Arc::from(text),
        generation,
    })
}

/// The "weights" message of a puppet: its per-triangle weights now.
pub fn weights_message(stage: &Stage, puppet: u32) -> String {
    let p = &stage.puppets()[puppet as usize];
    ServerMessage::Weights {
        puppet,
        weights: p.weights().to_vec(),
    }
    .to_text()
}

/// The "history" message of a puppet: its undo and redo steps.
pub fn history_message(stage: &Stage, puppet: u32) -> String {
    let (undo, redo) = stage.puppets()[puppet as usize].history();
    ServerMessage::History { puppet, undo, redo }.to_text()
}

/// The "pose" message of a skeleton puppet: its key-pose blend now.
pub fn pose_message(stage: &Stage, puppet: u32) -> String {
    let (key, _) = stage.puppets()[puppet as usize].key_pose();
    ServerMessage::Pose {
        puppet,
        from: key.map(|k| k.from.clone()),
        to: key.map(|k| k.to.clone()),
        t: key.map_or(0.0, |k| k.t),
    }
    .to_text()
}

/// The "keys" message of a puppet: its key poses and cursor now.
pub fn keys_message(stage: &Stage, puppet: u32) -> String {
    let k = stage.puppets()[puppet as usize].keying();
    ServerMessage::Keys {
        puppet,
        keys: k
            .keys()
            .iter()
            .map(|e| protocol::KeyView {
                name: e.name.clone(),
                at: e.at,
            })
            .collect(),
        cursor: k.cursor().map(|c| c.to_array()),
    }
    .to_text()
}

/// The newest output of one puppet.
#[derive(Debug, Clone)]
pub struct PuppetOutput {
    /// The newest encoded vertex frame (none before the first solve).
    pub frame: watch::Receiver<Option<Bytes>>,
    /// The newest rig frame (grid or skeleton puppets only).
    pub rig: watch::Receiver<Option<Bytes>>,
    /// The newest handle set and its "handles" message.
    pub handles: watch::Receiver<Arc<PublishedHandles>>,
    /// The newest "weights" message (changes when a performer paints).
    pub weights: watch::Receiver<Arc<str>>,
    /// The newest "keys" message (key poses and the cursor).
    pub keys: watch::Receiver<Arc<str>>,
    /// The newest handles frame: where each handle is on the solved
    /// puppet (none before the first solve with handles).
    pub handle_frame: watch::Receiver<Option<Bytes>>,
    /// The newest "history" message (undo and redo steps).
    pub history: watch::Receiver<Arc<str>>,
    /// The newest "pose" message (skeleton puppets only).
    pub pose: Option<watch::Receiver<Arc<str>>>,
    /// The newest depth frame (none until the depth first differs from
    /// the mesh's order, or with `depth = "off"`).
    pub depth: watch::Receiver<Option<Bytes>>,
}

/// Where the daemon's time goes, summed since it started: per stage-thread
/// iteration (the commands waiting, then one solve and its publishing) and
/// per client send. Read by `puppetry bench --e2e`; relaxed atomics, a
/// clock read per phase (tens of nanoseconds against a millisecond).
#[derive(Debug, Default)]
pub struct Timings {
    /// Iterations that solved.
    pub solves: AtomicU64,
    /// Applying the commands: contacts to handles, pins, edits.
    pub commands_ns: AtomicU64,
    pub solve_ns: AtomicU64,
    /// Encoding the binary frames once and waking every client.
    pub frames_ns: AtomicU64,
    /// Building the text messages that changed (weights, keys, history,
    /// poses, cursors, take state).
    pub messages_ns: AtomicU64,
    /// Writing the solve into the take being recorded.
    pub record_ns: AtomicU64,
    /// A client task sending what changed after a wake (all its puppets'
    /// messages), and how many such sends.
    pub sends: AtomicU64,
    pub send_ns: AtomicU64,
}

impl Timings {
    /// Adds the time since `since` to `counter`; returns now.
    pub fn add(counter: &AtomicU64, since: Instant) -> Instant {
        let now = Instant::now();
        counter.fetch_add((now - since).as_nanos() as u64, Ordering::Relaxed);
        now
    }
}

/// What the stage thread publishes.
pub struct Outputs {
    /// The puppets on stage and each one's outputs.
    pub lineup: watch::Receiver<Arc<Lineup>>,
    /// The newest "cursors" message.
    pub cursors: watch::Receiver<Arc<str>>,
    /// The newest "take" message (recording and playing now).
    pub take: watch::Receiver<Arc<str>>,
    /// Bumped after each publish, so clients wait on one signal.
    pub changes: watch::Receiver<u64>,
    pub timings: Arc<Timings>,
}

/// The stage thread's publishing ends: per puppet its newest frame and
/// handles, and a counter bumped after each publish so clients wait on one
/// signal.
struct Publisher {
    frames: Vec<watch::Sender<Option<Bytes>>>,
    rigs: Vec<watch::Sender<Option<Bytes>>>,
    handles: Vec<watch::Sender<Arc<PublishedHandles>>>,
    weights: Vec<watch::Sender<Arc<str>>>,
    /// Per puppet, the weights generation last published.
    weights_published: Vec<u64>,
    keys: Vec<watch::Sender<Arc<str>>>,
    keys_published: Vec<u64>,
    handle_frames: Vec<watch::Sender<Option<Bytes>>>,
    /// Scratch for handle positions, reused by every publish.
    handle_points: Vec<DVec2>,
    history: Vec<watch::Sender<Arc<str>>>,
    history_published: Vec<(usize, usize)>,
    poses: Vec<Option<watch::Sender<Arc<str>>>>,
    poses_published: Vec<u64>,
    depths: Vec<watch::Sender<Option<Bytes>>>,
    /// Per puppet, the depth generation last published.
    depths_published: Vec<u32>,
    sequences: Vec<u64>,
    /// Per puppet, two arenas for each stream of frames (vertices, rig,
    /// handles), used in turn: while one holds the newest frame, the other's
    /// earlier frame has been sent and dropped, so its storage comes back
    /// ([`encode_frame_into`]) and a steady stream does not allocate.
    arenas: Vec<[[BytesMut; 2]; 3]>,
    cursors: watch::Sender<Arc<str>>,
    changes: watch::Sender<u64>,
}

impl Publisher {
    fn publish(&mut self, stage: &Stage, solved: &[(u32, bool)], input_time: f64) {
        for &(puppet, handles_changed) in solved {
            let i = puppet as usize;
            self.sequences[i] += 1;
            let header = |kind| FrameHeader {
                kind,
                puppet,
                sequence: self.sequences[i],
                input_time,
                count: 0,
                generation: 0,
            };
            let turn = (self.sequences[i] % 2) as usize;
            let [frame_arenas, rig_arenas, handles_arenas] = &mut self.arenas[i];
            let pose = stage.puppets()[i].pose();
            self.frames[i].send_replace(Some(encode_frame_into(
                &mut frame_arenas[turn],
                &header(FrameKind::Vertices),
                pose,
            )));
            if let Some(points) = stage.puppets()[i].rig().points() {
                self.rigs[i].send_replace(Some(encode_frame_into(
                    &mut rig_arenas[turn],
                    &header(FrameKind::Rig),
                    points,
                )));
            }
            if handles_changed {
                self.handles[i].send_replace(published_handles(stage, puppet));
            }
            let p = &stage.puppets()[i];
            if let Some((depth, generation)) = p.depth()
                && generation != self.depths_published[i]
            {
                self.depths_published[i] = generation;
                self.depths[i].send_replace(Some(encode_depth_frame(
                    puppet,
                    self.sequences[i],
                    generation,
                    depth,
                )));
            }
            if handles_changed || !p.handles().is_empty() {
                p.handle_points(&mut self.handle_points);
                self.handle_frames[i].send_replace(Some(encode_frame_into(
                    &mut handles_arenas[turn],
                    &FrameHeader {
                        generation: p.handles_generation(),
                        ..header(FrameKind::Handles)
                    },
                    &self.handle_points,
                )));
            }
        }
        if !solved.is_empty() {
            self.changes.send_modify(|c| *c += 1);
        }
    }

    /// Publishes the weights of every puppet painted since the last call,
    /// and the keys of every puppet whose keys or cursor changed; returns
    /// whether there were any.
    fn publish_weights(&mut self, stage: &Stage) -> bool {
        let mut any = false;
        for p in stage.puppets() {
            let i = p.id as usize;
            if p.keying().generation != self.keys_published[i] {
                self.keys_published[i] = p.keying().generation;
                self.keys[i].send_replace(Arc::from(keys_message(stage, p.id)));
                any = true;
            }
        }
        for p in stage.puppets() {
            let i = p.id as usize;
            if p.history() != self.history_published[i] {
                self.history_published[i] = p.history();
                self.history[i].send_replace(Arc::from(history_message(stage, p.id)));
                any = true;
            }
            let (_, generation) = p.key_pose();
            if generation != self.poses_published[i]
                && let Some(pose) = &self.poses[i]
            {
                self.poses_published[i] = generation;
                pose.send_replace(Arc::from(pose_message(stage, p.id)));
                any = true;
            }
            if p.weights_generation() != self.weights_published[i] {
                self.weights_published[i] = p.weights_generation();
                self.weights[i].send_replace(Arc::from(weights_message(stage, p.id)));
                any = true;
            }
        }
        if any {
            self.changes.send_modify(|c| *c += 1);
        }
        any
    }

    /// Channels for a puppet new to the stage (all of them at the start),
    /// each holding its state now; returns the ends connections read.
    fn add_puppet(&mut self, stage: &Stage, id: u32) -> PuppetOutput {
        let p = &stage.puppets()[id as usize];
        let (frame_tx, frame_rx) = watch::channel(None);
        self.frames.push(frame_tx);
        let (rig_tx, rig_rx) = watch::channel(None);
        self.rigs.push(rig_tx);
        let (weights_tx, weights_rx) = watch::channel(Arc::<str>::from(weights_message(stage, id)));
        self.weights.push(weights_tx);
        self.weights_published.push(p.weights_generation());
        let (keys_tx, keys_rx) = watch::channel(Arc::<str>::from(keys_message(stage, id)));
        self.keys.push(keys_tx);
        self.keys_published.push(p.keying().generation);
        let (handles_tx, handles_rx) = watch::channel(published_handles(stage, id));
        self.handles.push(handles_tx);
        let (handle_frame_tx, handle_frame_rx) = watch::channel(None);
        self.handle_frames.push(handle_frame_tx);
        let (history_tx, history_rx) = watch::channel(Arc::<str>::from(history_message(stage, id)));
        self.history.push(history_tx);
        self.history_published.push(p.history());
        let pose = matches!(p.rig(), puppetry_stage::Rig::Skeleton(_))
            .then(|| watch::channel(Arc::<str>::from(pose_message(stage, id))));
        let (pose_tx, pose_rx) = pose.unzip();
        self.poses.push(pose_tx);
        self.poses_published.push(p.key_pose().1);
        let (depth_tx, depth_rx) = watch::channel(None);
        self.depths.push(depth_tx);
        self.depths_published
            .push(p.depth().map_or(0, |(_, generation)| generation));
        self.sequences.push(0);
        self.arenas.push(Default::default());
        PuppetOutput {
            frame: frame_rx,
            rig: rig_rx,
            handles: handles_rx,
            weights: weights_rx,
            keys: keys_rx,
            handle_frame: handle_frame_rx,
            history: history_rx,
            pose: pose_rx,
            depth: depth_rx,
        }
    }

    fn publish_cursors(&mut self, cursors: &BTreeMap<String, CursorState>) {
        self.cursors
            .send_replace(Arc::from(cursors_message(cursors)));
        self.changes.send_modify(|c| *c += 1);
    }
}

/// Builds a painted free-form puppet's solver on a thread of its own and
/// sends it back to the stage thread through `wake` (a weak sender, so the
/// worker never keeps a stopping stage thread alive).
fn start_rebuild(rebuild: Rebuild, wake: &mpsc::WeakSender<Command>) {
    let wake = wake.clone();
    let started = std::thread::Builder::new()
        .name(format!("rebuild {}", rebuild.puppet))
        .spawn(move || {
            let arap = match Arap::register(&rebuild.mesh) {
                Ok(arap) => Some(Box::new(arap)),
                Err(e) => {
                    tracing::warn!(puppet = rebuild.puppet, "painted weights: {e}");
                    None
                }
            };
            if let Some(commands) = wake.upgrade() {
                let _ = commands.blocking_send(Command::Rebuilt {
                    puppet: rebuild.puppet,
                    generation: rebuild.generation,
                    arap,
                });
            }
        });
    if let Err(e) = started {
        tracing::warn!("cannot start a solver rebuild: {e}");
    }
}

/// The take side of the stage thread: the take being recorded, the step
/// being gathered for it, and the take state every client sees.
struct Taking {
    settings: TakeSettings,
    recorder: Option<Recorder>,
    /// No change has reached the stage yet.
    fresh: bool,
    step: Vec<Change>,
    events: Vec<StageEvent>,
    playing: Option<String>,
    /// The contacts the take being recorded holds down (by source): they
    /// are let go in the take when it stops, so it ends with nothing held
    /// whenever it is stopped.
    held: BTreeMap<String, BTreeSet<u32>>,
    /// Played sources (`TAKE/SOURCE`) that reached the stage: what they
    /// hold lets go when their take ends.
    played: BTreeSet<String>,
    /// The take the one recording layers over, if it is an overdub.
    overdub_of: Option<String>,
    /// The take state changed where it could not be published at once (a
    /// take started by the first input): publish after the next solve.
    announce: bool,
    error: Option<String>,
    state: watch::Sender<Arc<str>>,
}

impl Taking {
    fn state_message(&self) -> String {
        ServerMessage::Take(TakeState {
            recording: self.recorder.as_ref().map(|r| r.name().to_string()),
            elapsed: self.recorder.as_ref().map_or(0.0, |r| r.elapsed()),
            playing: self.playing.clone(),
            error: self.error.clone(),
        })
        .to_text()
    }

    fn publish(&self, changes: &watch::Sender<u64>) {
        self.state.send_replace(Arc::from(self.state_message()));
        changes.send_modify(|c| *c += 1);
    }

    /// Starts a take named `name` (or the next free `take-NNN`).
    fn start(
        &mut self,
        stage: &mut Stage,
        name: Option<String>,
        layers: Vec<String>,
    ) -> Result<String, String> {
        if let Some(r) = &self.recorder {
            return Err(format!("take {} is already recording", r.name()));
        }
        if let Some(name) = &name
            && !puppetry_take::valid_name(name)
        {
            return Err(format!(
                "take name {name:?}: use letters, digits, '-', '_' and '.' (at most 100)"
            ));
        }
        std::fs::create_dir_all(&self.settings.dir)
            .map_err(|e| format!("takes folder {}: {e}", self.settings.dir.display()))?;
        let name = name.unwrap_or_else(|| {
            (1..)
                .map(|n| format!("take-{n:03}"))
                .find(|n| !self.path_of(n).exists())
                .expect("a free take name")
        });
        let mut header = Header::of_stage(&name, &self.settings.stage_file, stage, self.fresh);
        self.overdub_of = layers.first().cloned();
        header.layers = layers;
        let recorder = Recorder::start(&self.path_of(&name), &header).map_err(|e| e.to_string())?;
        tracing::info!("take {name}: recording to {}", recorder.path().display());
        self.recorder = Some(recorder);
        self.error = None;
        self.step.clear();
        self.events.clear();
        self.held.clear();
        stage.keep_events(true);
        Ok(name)
    }

    fn path_of(&self, name: &str) -> PathBuf {
        self.settings
            .dir
            .join(format!("{name}.{}", puppetry_take::EXTENSION))
    }

    /// Notes the played sources a played change brings on stage.
    fn note_played(&mut self, change: &Change) {
        let source = match change {
            Change::Contacts { frame } => frame.source.as_str(),
            Change::Pin { owner, .. } => owner.as_str(),
            _ => return,
        };
        if !self.played.contains(source) {
            self.played.insert(source.to_string());
        }
    }

    /// A take starts playing, unless it is the take being recorded: played
    /// into itself it would read what it is writing.
    fn start_playing(
        &mut self,
        name: String,
        path: &std::path::Path,
        changes: &watch::Sender<u64>,
    ) -> Result<(), crate::takes::PlayError> {
        if let Some(r) = &self.recorder
            && (r.name() == name || r.path() == path)
        {
            let take = r.name().to_string();
            return Err(crate::takes::PlayError::Recording { take });
        }
        self.playing = Some(name);
        self.publish(changes);
        Ok(())
    }

    /// The take `name` stopped playing: an overdub of it stops too.
    fn ended(&mut self, stage: &mut Stage, name: &str, changes: &watch::Sender<u64>) {
        if self.playing.as_deref() != Some(name) {
            return;
        }
        self.playing = None;
        if self.overdub_of.as_deref() == Some(name) && self.recorder.is_some() {
            let _ = self.stop(stage, "stopped");
        }
        self.publish(changes);
    }

    /// Notes what a change recorded into the take holds down or lets go.
    fn note(&mut self, change: &Change) {
        match change {
            Change::Contacts { frame } => {
                let source = frame.source.as_str();
                for c in &frame.contacts {
                    match (c.phase, self.held.get_mut(source)) {
                        (Phase::Down, Some(ids)) => {
                            ids.insert(c.id);
                        }
                        (Phase::Down, None) => {
                            self.held.insert(source.to_string(), BTreeSet::from([c.id]));
                        }
                        (Phase::Up, Some(ids)) => {
                            ids.remove(&c.id);
                            if ids.is_empty() {
                                self.held.remove(source);
                            }
                        }
                        _ => {}
                    }
                }
            }
            Change::Release { source } => {
                self.held.remove(source);
            }
            _ => {}
        }
    }

    /// Ends the take being recorded (if any), for `reason`. Contacts the
    /// take holds down are let go in its last step (the live stage keeps
    /// them: the fingers are still there), so playing it leaves nothing
    /// held. That step has no frames: nobody saw them let go.
    fn stop(&mut self, stage: &mut Stage, reason: &str) -> Result<String, String> {
        let recorder = self
            .recorder
            .take()
            .ok_or_else(|| "no take is recording".to_string())?;
        stage.keep_events(false);
        self.overdub_of = None;
        let name = recorder.name().to_string();
        let held = std::mem::take(&mut self.held);
        let released = if held.is_empty() {
            Ok(())
        } else {
            recorder.record(Record::Step(Step {
                t: recorder.elapsed(),
                changes: held
                    .into_keys()
                    .map(|source| Change::Release { source })
                    .collect(),
                events: Vec::new(),
            }))
        };
        let finished = match released {
            Ok(()) => recorder.finish(reason),
            Err(e) => {
                let _ = recorder.finish(&e.to_string());
                Err(e)
            }
        };
        match finished {
            Ok(()) => {
                tracing::info!("take {name}: {reason}");
                Ok(name)
            }
            Err(e) => {
                tracing::error!("{e}");
                self.error = Some(e.to_string());
                Err(e.to_string())
            }
        }
    }

    /// Records the step just solved and its frames; a take that cannot
    /// keep up or write stops here, with its error shown to everyone.
    fn record(&mut self, stage: &mut Stage, solved: &[(u32, bool)]) -> bool {
        let Some(recorder) = &self.recorder else {
            return false;
        };
        stage.take_events(&mut self.events);
        if self.step.is_empty() && solved.is_empty() && self.events.is_empty() {
            return false;
        }
        let t = recorder.elapsed();
        let mut result = recorder.record(Record::Step(Step {
            t,
            changes: std::mem::take(&mut self.step),
            events: std::mem::take(&mut self.events),
        }));
        for &(puppet, _) in solved {
            if result.is_err() {
                break;
            }
            let pose = stage.puppets()[puppet as usize].pose();
            result = recorder.record(Record::Frame(Frame::of_pose(puppet, t, pose)));
        }
        if let Err(e) = result {
            tracing::error!("{e}");
            let reason = e.to_string();
            if let Some(recorder) = self.recorder.take() {
                stage.keep_events(false);
                let _ = recorder.finish(&reason);
            }
            self.error = Some(reason);
            return true;
        }
        false
    }
}

/// Starts the stage thread; returns what it publishes. The thread stops
/// when every command sender is dropped; `wake` (a weak sender of the same
/// channel) is how solver rebuilds come back.
pub fn spawn(
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

/// The stage thread's loop, one command at a time: [`spawn`] runs it on
/// its thread, draining the command channel and solving once per batch; a
/// simulated show drives it by hand, so it runs exactly the code a show
/// does (takes recorded, played, overdubbed and stopped included) with the
/// interleavings chosen by the test.
pub struct StageDriver {
    stage: Stage,
    publisher: Publisher,
    taking: Taking,
    cursors: BTreeMap<String, CursorState>,
    batch: Batch,
    lineup: watch::Sender<Arc<Lineup>>,
    wake: mpsc::WeakSender<Command>,
}

impl StageDriver {
    /// The loop for `stage`, solved once (pins from the stage file are
    /// handles before any input), and what it publishes. Solver rebuilds
    /// come back through `wake` as [`Command::Rebuilt`].
    pub fn new(
        config: StageConfig,
        mut stage: Stage,
        takes: TakeSettings,
        wake: mpsc::WeakSender<Command>,
    ) -> (StageDriver, Outputs) {
        let StageLoop {
            publisher,
            taking,
            cursors,
            batch,
            lineup,
            outputs,
        } = StageLoop::new(config, &mut stage, takes);
        let driver = StageDriver {
            stage,
            publisher,
            taking,
            cursors,
            batch,
            lineup,
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
    pub fn begin(&mut self) {
        self.batch.started = Instant::now();
    }

    /// Whether a [`Command::Stop`] came.
    pub fn stopped(&self) -> bool {
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

/// What the stage thread owns besides the stage, made before it starts.
struct StageLoop {
    publisher: Publisher,
    taking: Taking,
    cursors: BTreeMap<String, CursorState>,
    batch: Batch,
    lineup: watch::Sender<Arc<Lineup>>,
    outputs: Outputs,
}

impl StageLoop {
    /// The publishing ends for `stage`'s puppets, with the stage solved
    /// once (pins from the stage file are handles before any input).
    fn new(config: StageConfig, stage: &mut Stage, takes: TakeSettings) -> StageLoop {
        let (changes, changes_rx) = watch::channel(0u64);
        let cursors = BTreeMap::new();
        let (cursors_tx, cursors_rx) = watch::channel(Arc::<str>::from(cursors_message(&cursors)));
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
            .map(|id| publisher.add_puppet(stage, id))
            .collect();
        let (lineup_tx, lineup_rx) =
            watch::channel(Lineup::of(stage, outputs, 0, Arc::new(config)));
        let (state_tx, state_rx) = watch::channel(Arc::<str>::from(""));
        let taking = Taking {
            settings: takes,
            recorder: None,
            fresh: true,
            step: Vec::new(),
            events: Vec::new(),
            playing: None,
            held: BTreeMap::new(),
            played: BTreeSet::new(),
            overdub_of: None,
            announce: false,
            error: None,
            state: state_tx,
        };
        taking.state.send_replace(Arc::from(taking.state_message()));
        let solved = stage.solve();
        publisher.publish(stage, &solved, 0.0);
        let timings = Arc::new(Timings::default());
        StageLoop {
            publisher,
            taking,
            cursors,
            batch: Batch::new(timings.clone()),
            lineup: lineup_tx,
            outputs: Outputs {
                lineup: lineup_rx,
                cursors: cursors_rx,
                take: state_rx,
                changes: changes_rx,
                timings,
            },
        }
    }
}

/// Adds, removes or reorders puppets and publishes the new lineup, which
/// every connection follows. Refused while a take records: a take's puppets
/// are fixed when it starts.
fn change_lineup(
    stage: &mut Stage,
    publisher: &mut Publisher,
    taking: &Taking,
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
    lineup.send_modify(|old| {
        let mut outputs = old.outputs.clone();
        outputs.extend(added);
        *old = Lineup::of(stage, outputs, old.revision + 1, config);
    });
    Ok(answer)
}

/// What the stage thread gathered since its last solve.
struct Batch {
    /// When the newest input frame reached the daemon.
    newest: f64,
    stop: bool,
    cursors_changed: bool,
    /// Something was applied since the last solve.
    dirty: bool,
    timings: Arc<Timings>,
    /// When this iteration's commands began.
    started: Instant,
    /// The puppets the last solve solved (reused: no allocation).
    solved: Vec<(u32, bool)>,
}

impl Batch {
    fn new(timings: Arc<Timings>) -> Batch {
        Batch {
            newest: 0.0,
            stop: false,
            cursors_changed: false,
            dirty: false,
            timings,
            started: Instant::now(),
            solved: Vec::new(),
        }
    }

    /// Applies one change to the stage (and the take's step when it took).
    fn apply(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        change: Change,
        reply: Option<Reply<()>>,
        wake: &mpsc::WeakSender<Command>,
    ) {
        if taking.settings.record_from_first_input && taking.fresh && taking.recorder.is_none() {
            taking.settings.record_from_first_input = false;
            if let Err(e) = taking.start(stage, None, Vec::new()) {
                tracing::error!("serve --record: {e}");
                taking.error = Some(e);
            }
            taking.announce = true;
        }
        let result = stage.apply_change(&change);
        taking.fresh = false;
        self.dirty = true;
        let result = result.map(|rebuild| {
            if let Some(rebuild) = rebuild {
                start_rebuild(rebuild, wake);
            }
        });
        if result.is_ok() && taking.recorder.is_some() {
            taking.note(&change);
            taking.step.push(change);
        }
        if let Some(reply) = reply {
            let _ = reply.send(result);
        }
    }

    /// One arm per command: long because the commands are many, each arm
    /// short (the longer ones call out to a function of their own).
    fn command(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        cursors: &mut BTreeMap<String, CursorState>,
        command: Command,
        wake: &mpsc::WeakSender<Command>,
        changes: &watch::Sender<u64>,
    ) {
        match command {
            Command::Stop => self.stop = true,
            Command::Change {
                change,
                received,
                reply,
            } => {
                if let Some(received) = received {
                    self.newest = received;
                }
                self.apply(stage, taking, change, reply, wake);
            }
            Command::Played { .. } | Command::Lineup { .. } | Command::PlayEnded { .. } => {
                unreachable!(
                    "played steps, a take's end and lineup changes are handled on their own"
                )
            }
            Command::Limit { source, puppets } => stage.limit_source(&source, puppets),
            Command::Edit {
                puppet,
                edit,
                reply,
            } => {
                // The history decides what to put back; the take records
                // the state put back (a `restore`), not the undo, so it
                // replays the same whatever history it began with.
                if edit == Edit::Reset {
                    // Nothing a take no longer playing held stays held.
                    self.let_go_of_played(stage, taking, None, wake);
                }
                let changes = match edit {
                    Edit::Undo => stage.undo(puppet).map(|c| c.into_iter().collect()),
                    Edit::Redo => stage.redo(puppet).map(|c| c.into_iter().collect()),
                    Edit::Reset => stage.reset(puppet),
                };
                match changes {
                    Ok(changes) => {
                        let mut result = Ok(());
                        for change in changes {
                            let (tx, mut rx) = oneshot::channel();
                            self.apply(stage, taking, change, Some(tx), wake);
                            if let Ok(Err(e)) = rx.try_recv()
                                && result.is_ok()
                            {
                                result = Err(e);
                            }
                        }
                        // An undo with nothing to undo still changes the
                        // history's counts: publish them.
                        self.dirty = true;
                        let _ = reply.send(result);
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
            }
            Command::ExportGrid { puppet, reply } => {
                let _ = reply.send(stage.export_grid(puppet));
            }
            Command::SaveKeys { puppet, reply } => {
                let _ = reply.send(stage.key_file(puppet));
            }
            Command::SaveWeights { puppet, reply } => {
                let _ = reply.send(stage.weights_file(puppet));
            }
            Command::Rebuilt {
                puppet,
                generation,
                arap,
            } => {
                let next = match arap {
                    Some(arap) => {
                        if taking.recorder.is_some() {
                            taking.step.push(Change::Rebuilt { puppet, generation });
                        }
                        self.dirty = true;
                        stage.install(puppet, generation, *arap)
                    }
                    None => {
                        stage.rebuild_failed(puppet);
                        None
                    }
                };
                if let Some(rebuild) = next {
                    start_rebuild(rebuild, wake);
                }
            }
            Command::Cursor { source, cursor } => {
                let old = match cursor {
                    Some(c) => cursors.insert(source, c),
                    None => cursors.remove(&source),
                };
                self.cursors_changed |= old != cursor;
            }
            Command::StartTake {
                name,
                layers,
                reply,
            } => {
                let _ = reply.send(taking.start(stage, name, layers));
                taking.publish(changes);
            }
            Command::StopTake { reply } => {
                let _ = reply.send(taking.stop(stage, "stopped"));
                taking.publish(changes);
            }
            Command::PlayStarting { name, path, reply } => {
                let _ = reply.send(taking.start_playing(name, &path, changes));
            }
        }
    }

    /// Lets go of what played sources hold: those of the take `ended`, or
    /// (`None`) those of every take but the one playing. Their contacts
    /// lift and their pins go, through changes an overdub records.
    fn let_go_of_played(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        ended: Option<&str>,
        wake: &mpsc::WeakSender<Command>,
    ) {
        let of = |source: &str, take: &str| {
            source
                .strip_prefix(take)
                .is_some_and(|rest| rest.starts_with('/'))
        };
        let gone: Vec<String> = match ended {
            Some(take) => taking
                .played
                .iter()
                .filter(|s| of(s.as_str(), take))
                .cloned()
                .collect(),
            None => taking
                .played
                .iter()
                .filter(|s| {
                    !taking
                        .playing
                        .as_deref()
                        .is_some_and(|take| of(s.as_str(), take))
                })
                .cloned()
                .collect(),
        };
        if gone.is_empty() {
            return;
        }
        let mut pins = Vec::new();
        for p in stage.puppets() {
            for h in p.handles() {
                if h.kind == HandleKind::Pin
                    && let puppetry_stage::Owner::Source(owner) = &h.owner
                    && gone.contains(owner)
                {
                    pins.push((p.id, h.id));
                }
            }
        }
        for source in gone {
            taking.played.remove(&source);
            self.apply(stage, taking, Change::Release { source }, None, wake);
        }
        for (puppet, handle) in pins {
            self.apply(stage, taking, Change::Unpin { puppet, handle }, None, wake);
        }
    }

    /// Solves what was applied, publishes it and records it.
    fn finish(
        &mut self,
        stage: &mut Stage,
        publisher: &mut Publisher,
        taking: &mut Taking,
        cursors: &BTreeMap<String, CursorState>,
    ) {
        let t = &self.timings;
        let mut now = Timings::add(&t.commands_ns, self.started);
        if self.dirty {
            self.dirty = false;
            stage.solve_into(&mut self.solved);
            let solved = &self.solved;
            now = Timings::add(&t.solve_ns, now);
            publisher.publish(stage, solved, self.newest);
            now = Timings::add(&t.frames_ns, now);
            publisher.publish_weights(stage);
            now = Timings::add(&t.messages_ns, now);
            let recorded = taking.record(stage, solved);
            now = Timings::add(&t.record_ns, now);
            if recorded || std::mem::take(&mut taking.announce) {
                taking.publish(&publisher.changes);
            }
            t.solves.fetch_add(1, Ordering::Relaxed);
        }
        if self.cursors_changed {
            self.cursors_changed = false;
            publisher.publish_cursors(cursors);
        }
        Timings::add(&t.messages_ns, now);
        // Whatever comes next in this iteration is commands again.
        self.started = Instant::now();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
        let mut stage = Stage::from_config(&config).expect("the demo stage builds");
        let at = DVec2::from(config.puppets[0].at);
        let takes = TakeSettings {
            dir: std::env::temp_dir(),
            stage_file: "demo.toml".into(),
            record_from_first_input: false,
        };
        let StageLoop {
            mut publisher,
            mut taking,
            cursors,
            mut batch,
            outputs,
            ..
        } = StageLoop::new(config, &mut stage, takes);
        let (_keep, wake) = {
            let (tx, _rx) = mpsc::channel::<Command>(1);
            let weak = tx.downgrade();
            (tx, weak)
        };
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
