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

use std::collections::BTreeMap;
use std::sync::Arc;
use std::thread::JoinHandle;

use bytes::Bytes;
use glam::DVec2;
use tokio::sync::{mpsc, oneshot, watch};

use puppetry_deform::Arap;
use puppetry_input::ContactFrame;
use puppetry_stage::{
    CommandError, GridExport, Grip, HandleKind, Owner, Rebuild, Stage, WeightsFile,
};

use crate::protocol::{
    self, CursorView, FrameKind, GripKind, HandleView, ServerMessage, encode_frame,
};

/// The stage thread's answer to a request.
pub type Reply<T> = oneshot::Sender<Result<T, CommandError>>;

/// What the stage thread is asked to do.
#[derive(Debug)]
pub enum Command {
    /// An input frame, with the time it reached the daemon (seconds since
    /// the daemon started).
    Frame {
        frame: ContactFrame,
        received: f64,
    },
    Pin {
        owner: String,
        at: DVec2,
    },
    Unpin {
        puppet: u32,
        handle: u64,
    },
    /// A source went away: lift all its contacts.
    ReleaseSource(String),
    /// A mouse's cursor moved (`None`: the mouse went away).
    Cursor {
        source: String,
        cursor: Option<CursorState>,
    },
    /// Paint stiffness under a brush (stage coordinates).
    Paint {
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
        reply: Reply<()>,
    },
    /// Set a skeleton to a pose between two key poses.
    KeyPose {
        puppet: u32,
        from: String,
        to: String,
        t: f64,
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
    /// End the thread (the daemon is shutting down).
    Stop,
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
            },
            at: [h.target.x, h.target.y],
            grip: match h.grip {
                Grip::Point(_) => GripKind::Point,
                Grip::GridHandle(_) => GripKind::Grid,
                Grip::Joint(_) => GripKind::Joint,
            },
            index: match h.grip {
                Grip::Point(_) => None,
                Grip::GridHandle(i) | Grip::Joint(i) => Some(i),
            },
        })
        .collect()
}

/// The "handles" message of a puppet, with the list it was made from.
pub fn published_handles(stage: &Stage, puppet: u32) -> Arc<PublishedHandles> {
    let handles = handle_views(stage, puppet);
    let text = ServerMessage::Handles {
        puppet,
        handles: handles.clone(),
    }
    .to_text();
    Arc::new(PublishedHandles {
        handles,
        text: Arc::from(text),
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
}

/// What the stage thread publishes.
pub struct Outputs {
    pub puppets: Vec<PuppetOutput>,
    /// The newest "cursors" message.
    pub cursors: watch::Receiver<Arc<str>>,
    /// Bumped after each publish, so clients wait on one signal.
    pub changes: watch::Receiver<u64>,
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
    sequences: Vec<u64>,
    cursors: watch::Sender<Arc<str>>,
    changes: watch::Sender<u64>,
}

impl Publisher {
    fn publish(&mut self, stage: &Stage, solved: &[(u32, bool)], input_time: f64) {
        for &(puppet, handles_changed) in solved {
            let i = puppet as usize;
            self.sequences[i] += 1;
            let pose = stage.puppets()[i].pose();
            self.frames[i].send_replace(Some(encode_frame(
                FrameKind::Vertices,
                puppet,
                self.sequences[i],
                input_time,
                pose,
            )));
            if let Some(points) = stage.puppets()[i].rig().points() {
                self.rigs[i].send_replace(Some(encode_frame(
                    FrameKind::Rig,
                    puppet,
                    self.sequences[i],
                    input_time,
                    points,
                )));
            }
            if handles_changed {
                self.handles[i].send_replace(published_handles(stage, puppet));
            }
        }
        if !solved.is_empty() {
            self.changes.send_modify(|c| *c += 1);
        }
    }

    /// Publishes the weights of every puppet painted since the last call;
    /// returns whether there were any.
    fn publish_weights(&mut self, stage: &Stage) -> bool {
        let mut any = false;
        for p in stage.puppets() {
            let i = p.id as usize;
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

/// Starts the stage thread; returns what it publishes. The thread stops
/// when every command sender is dropped; `wake` (a weak sender of the same
/// channel) is how solver rebuilds come back.
pub fn spawn(
    mut stage: Stage,
    mut commands: mpsc::Receiver<Command>,
    wake: mpsc::WeakSender<Command>,
) -> (Outputs, JoinHandle<()>) {
    let (changes, changes_rx) = watch::channel(0u64);
    let mut cursors = BTreeMap::new();
    let (cursors_tx, cursors_rx) = watch::channel(Arc::<str>::from(cursors_message(&cursors)));
    let mut publisher = Publisher {
        frames: Vec::new(),
        rigs: Vec::new(),
        handles: Vec::new(),
        weights: Vec::new(),
        weights_published: vec![0; stage.puppets().len()],
        sequences: vec![0; stage.puppets().len()],
        cursors: cursors_tx,
        changes,
    };
    let mut outputs = Vec::new();
    for p in stage.puppets() {
        let (frame_tx, frame_rx) = watch::channel(None);
        let (rig_tx, rig_rx) = watch::channel(None);
        publisher.rigs.push(rig_tx);
        let (weights_tx, weights_rx) =
            watch::channel(Arc::<str>::from(weights_message(&stage, p.id)));
        publisher.weights.push(weights_tx);
        let (handles_tx, handles_rx) = watch::channel(published_handles(&stage, p.id));
        publisher.frames.push(frame_tx);
        publisher.handles.push(handles_tx);
        outputs.push(PuppetOutput {
            frame: frame_rx,
            rig: rig_rx,
            handles: handles_rx,
            weights: weights_rx,
        });
    }
    // Pins from the stage file are handles before any input: solve once.
    let solved = stage.solve();
    publisher.publish(&stage, &solved, 0.0);
    let thread = std::thread::Builder::new()
        .name("stage".into())
        .spawn(move || {
            while let Some(first) = commands.blocking_recv() {
                let mut newest = 0.0;
                let mut stop = false;
                let mut cursors_changed = false;
                let mut apply = |stage: &mut Stage, command: Command| match command {
                    Command::Stop => stop = true,
                    Command::Frame { frame, received } => {
                        newest = received;
                        stage.apply(&frame);
                    }
                    Command::Pin { owner, at } => {
                        stage.pin(Owner::Source(owner), at);
                    }
                    Command::Unpin { puppet, handle } => {
                        stage.unpin(puppet, handle);
                    }
                    Command::ReleaseSource(source) => stage.release_source(&source),
                    Command::Paint {
                        puppet,
                        at,
                        radius,
                        strength,
                        reply,
                    } => {
                        let result = stage.paint(puppet, at, radius, strength);
                        let _ = reply.send(result.map(|rebuild| {
                            if let Some(rebuild) = rebuild {
                                start_rebuild(rebuild, &wake);
                            }
                        }));
                    }
                    Command::KeyPose {
                        puppet,
                        from,
                        to,
                        t,
                        reply,
                    } => {
                        let r = stage.set_key_pose(puppet, &from, &to, t);
                        let _ = reply.send(r);
                    }
                    Command::ExportGrid { puppet, reply } => {
                        let _ = reply.send(stage.export_grid(puppet));
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
                            Some(arap) => stage.install(puppet, generation, *arap),
                            None => {
                                stage.rebuild_failed(puppet);
                                None
                            }
                        };
                        if let Some(rebuild) = next {
                            start_rebuild(rebuild, &wake);
                        }
                    }
                    Command::Cursor { source, cursor } => {
                        let old = match cursor {
                            Some(c) => cursors.insert(source, c),
                            None => cursors.remove(&source),
                        };
                        cursors_changed |= old != cursor;
                    }
                };
                apply(&mut stage, first);
                // Catch up: apply everything already waiting, solve once.
                while let Ok(next) = commands.try_recv() {
                    apply(&mut stage, next);
                }
                if stop {
                    // Dropping the publisher tells every client to close.
                    return;
                }
                let solved = stage.solve();
                publisher.publish(&stage, &solved, newest);
                publisher.publish_weights(&stage);
                if cursors_changed {
                    publisher.publish_cursors(&cursors);
                }
            }
        })
        .expect("spawn the stage thread");
    (
        Outputs {
            puppets: outputs,
            cursors: cursors_rx,
            changes: changes_rx,
        },
        thread,
    )
}
