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

use bytes::{BufMut, Bytes, BytesMut};
use glam::DVec2;
use serde::Serialize;
use tokio::sync::{mpsc, oneshot, watch};

use puppetry_deform::Arap;
use puppetry_input::ContactFrame;
use puppetry_stage::{Grip, HandleKind, Owner, Rebuild, Stage, WeightsFile};

/// The stage thread's answer to a request.
pub type Reply<T> = oneshot::Sender<Result<T, String>>;

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
        cursor: Option<CursorView>,
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
    /// The "grid" message of a grid puppet.
    ExportGrid {
        puppet: u32,
        reply: Reply<String>,
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

/// The size of a binary frame's header (see `docs/protocol.md`).
pub const FRAME_HEADER: usize = 32;
/// `kind` of a vertex frame.
pub const FRAME_KIND_VERTICES: u32 = 1;
/// `kind` of a rig frame: the deformed grid handles or the posed joints.
pub const FRAME_KIND_RIG: u32 = 2;

/// Encodes a vertex frame: 32-byte little-endian header, then f32 x,y pairs.
pub fn encode_frame(puppet: u32, sequence: u64, input_time: f64, pose: &[DVec2]) -> Bytes {
    encode_points(FRAME_KIND_VERTICES, puppet, sequence, input_time, pose)
}

/// Encodes a frame of `kind` (same header, then the points as f32 pairs).
pub fn encode_points(
    kind: u32,
    puppet: u32,
    sequence: u64,
    input_time: f64,
    pose: &[DVec2],
) -> Bytes {
    let mut out = BytesMut::with_capacity(FRAME_HEADER + pose.len() * 8);
    out.put_u32_le(kind);
    out.put_u32_le(puppet);
    out.put_u64_le(sequence);
    out.put_f64_le(input_time);
    out.put_u32_le(pose.len() as u32);
    out.put_u32_le(0);
    for p in pose {
        out.put_f32_le(p.x as f32);
        out.put_f32_le(p.y as f32);
    }
    out.freeze()
}

/// One handle as clients see it.
#[derive(Debug, Clone, Serialize)]
pub struct HandleView {
    pub id: u64,
    pub owner: String,
    pub kind: &'static str,
    pub at: [f64; 2],
    /// What it holds: "point", "grid" (a grid handle) or "joint".
    pub grip: &'static str,
    /// The grid handle's or joint's index.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub index: Option<usize>,
}

/// A mouse cursor as clients draw it: where it is, and the pair of points
/// it holds (or would hold) around it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CursorView {
    pub at: [f64; 2],
    /// Direction of the pair, radians counter-clockwise from +x.
    pub angle: f64,
    /// Distance between the pair's points; 0 for a one-point mouse.
    pub spacing: f64,
    /// A button is down and the points are grabbing.
    pub holding: bool,
}

/// The "cursors" message: every mouse cursor on the stage.
pub fn cursors_message(cursors: &BTreeMap<String, CursorView>) -> String {
    let list: Vec<serde_json::Value> = cursors
        .iter()
        .map(|(source, c)| {
            serde_json::json!({
                "source": source,
                "at": c.at,
                "angle": c.angle,
                "spacing": c.spacing,
                "holding": c.holding,
            })
        })
        .collect();
    serde_json::json!({"type": "cursors", "cursors": list}).to_string()
}

/// The "handles" message of a puppet.
pub fn handles_message(stage: &Stage, puppet: u32) -> String {
    let p = &stage.puppets()[puppet as usize];
    let handles: Vec<HandleView> = p
        .handles()
        .iter()
        .map(|h| HandleView {
            id: h.id,
            owner: h.owner.to_string(),
            kind: match h.kind {
                HandleKind::Contact => "contact",
                HandleKind::Pin => "pin",
            },
            at: [h.target.x, h.target.y],
            grip: match h.grip {
                Grip::Point(_) => "point",
                Grip::GridHandle(_) => "grid",
                Grip::Joint(_) => "joint",
            },
            index: match h.grip {
                Grip::Point(_) => None,
                Grip::GridHandle(i) | Grip::Joint(i) => Some(i),
            },
        })
        .collect();
    serde_json::json!({"type": "handles", "puppet": puppet, "handles": handles}).to_string()
}

/// The "weights" message of a puppet: its per-triangle weights now.
pub fn weights_message(stage: &Stage, puppet: u32) -> String {
    let p = &stage.puppets()[puppet as usize];
    serde_json::json!({"type": "weights", "puppet": puppet, "weights": p.weights()}).to_string()
}

/// The newest output of one puppet.
#[derive(Debug, Clone)]
pub struct PuppetOutput {
    /// The newest encoded vertex frame (none before the first solve).
    pub frame: watch::Receiver<Option<Bytes>>,
    /// The newest rig frame (grid or skeleton puppets only).
    pub rig: watch::Receiver<Option<Bytes>>,
    /// The newest "handles" message.
    pub handles: watch::Receiver<Arc<str>>,
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
    handles: Vec<watch::Sender<Arc<str>>>,
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
                puppet,
                self.sequences[i],
                input_time,
                pose,
            )));
            if let Some(points) = stage.puppets()[i].rig().points() {
                self.rigs[i].send_replace(Some(encode_points(
                    FRAME_KIND_RIG,
                    puppet,
                    self.sequences[i],
                    input_time,
                    points,
                )));
            }
            if handles_changed {
                self.handles[i].send_replace(Arc::from(handles_message(stage, puppet)));
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

    fn publish_cursors(&mut self, cursors: &BTreeMap<String, CursorView>) {
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
        let (handles_tx, handles_rx) =
            watch::channel(Arc::<str>::from(handles_message(&stage, p.id)));
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
                        let _ = reply.send(stage.export_grid(puppet).map(|v| v.to_string()));
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
