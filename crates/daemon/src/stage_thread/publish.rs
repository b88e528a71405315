//! Publishing a solve: each moved puppet's frame encoded once into a
//! reused buffer and sent on its watch channel, and the state messages
//! (handles, weights, keys, history, pose, depth, cursors) made once when
//! they change, for every connection to share.

use std::collections::BTreeMap;
use std::sync::Arc;

use bytes::{Bytes, BytesMut};
use glam::DVec2;
use tokio::sync::watch;

use puppetry_stage::{Grip, HandleKind, Stage};

use crate::protocol::{
    self, CursorView, FrameHeader, FrameKind, GripKind, HandleView, ServerMessage,
    encode_depth_frame, encode_frame_into,
};

use crate::outputs::{Feed, Published, PublishedHandles, PuppetOutput, PuppetStart};

/// The "cursors" message: every mouse cursor on the stage.
pub fn cursors_message(cursors: &BTreeMap<String, CursorView>) -> Arc<Published> {
    let cursors = cursors.values().cloned().collect();
    Published::of(ServerMessage::Cursors { cursors })
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
pub fn weights_message(stage: &Stage, puppet: u32) -> Arc<Published> {
    let p = &stage.puppets()[puppet as usize];
    Published::of(ServerMessage::Weights {
        puppet,
        weights: p.weights().to_vec(),
    })
}

/// The "history" message of a puppet: its undo and redo steps.
pub fn history_message(stage: &Stage, puppet: u32) -> Arc<Published> {
    let (undo, redo) = stage.puppets()[puppet as usize].history();
    Published::of(ServerMessage::History { puppet, undo, redo })
}

/// The "pose" message of a skeleton puppet: its key-pose blend now.
pub fn pose_message(stage: &Stage, puppet: u32) -> Arc<Published> {
    let (key, _) = stage.puppets()[puppet as usize].key_pose();
    Published::of(ServerMessage::Pose {
        puppet,
        from: key.map(|k| k.from.clone()),
        to: key.map(|k| k.to.clone()),
        t: key.map_or(0.0, |k| k.t),
    })
}

/// The "keys" message of a puppet: its key poses and cursor now.
pub fn keys_message(stage: &Stage, puppet: u32) -> Arc<Published> {
    let k = stage.puppets()[puppet as usize].keying();
    Published::of(ServerMessage::Keys {
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
    })
}

/// The stage thread's publishing ends: per puppet its newest frame and
/// handles, and a counter bumped after each publish so clients wait on one
/// signal.
pub(super) struct Publisher {
    pub(super) frames: Vec<watch::Sender<Option<Bytes>>>,
    pub(super) rigs: Vec<watch::Sender<Option<Bytes>>>,
    pub(super) handles: Vec<watch::Sender<Arc<PublishedHandles>>>,
    pub(super) weights: Vec<Feed>,
    /// Per puppet, the weights generation last published.
    pub(super) weights_published: Vec<u64>,
    pub(super) keys: Vec<watch::Sender<Arc<Published>>>,
    pub(super) keys_published: Vec<u64>,
    pub(super) handle_frames: Vec<watch::Sender<Option<Bytes>>>,
    /// Scratch for handle positions, reused by every publish.
    pub(super) handle_points: Vec<DVec2>,
    pub(super) history: Vec<Feed>,
    pub(super) history_published: Vec<(usize, usize)>,
    pub(super) poses: Vec<Option<watch::Sender<Arc<Published>>>>,
    pub(super) poses_published: Vec<u64>,
    pub(super) depths: Vec<watch::Sender<Option<Bytes>>>,
    /// Per puppet, the depth generation last published.
    pub(super) depths_published: Vec<u32>,
    pub(super) sequences: Vec<u64>,
    /// Per puppet, two arenas for each stream of frames (vertices, rig,
    /// handles), used in turn: while one holds the newest frame, the other's
    /// earlier frame has been sent and dropped, so its storage comes back
    /// ([`encode_frame_into`]) and a steady stream does not allocate.
    pub(super) arenas: Vec<[[BytesMut; 2]; 3]>,
    pub(super) cursors: Feed,
    pub(super) changes: watch::Sender<u64>,
}

impl Publisher {
    pub(super) fn publish(&mut self, stage: &Stage, solved: &[(u32, bool)], input_time: f64) {
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
    pub(super) fn publish_weights(&mut self, stage: &Stage) -> bool {
        let mut any = false;
        for p in stage.puppets() {
            let i = p.id as usize;
            if p.keying().generation != self.keys_published[i] {
                self.keys_published[i] = p.keying().generation;
                self.keys[i].send_replace(keys_message(stage, p.id));
                any = true;
            }
        }
        for p in stage.puppets() {
            let i = p.id as usize;
            if p.history() != self.history_published[i] {
                self.history_published[i] = p.history();
                self.history[i].send_replace(history_message(stage, p.id));
                any = true;
            }
            let (_, generation) = p.key_pose();
            if generation != self.poses_published[i]
                && let Some(pose) = &self.poses[i]
            {
                self.poses_published[i] = generation;
                pose.send_replace(pose_message(stage, p.id));
                any = true;
            }
            if p.weights_generation() != self.weights_published[i] {
                self.weights_published[i] = p.weights_generation();
                self.weights[i].send_replace(weights_message(stage, p.id));
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
    pub(super) fn add_puppet(&mut self, stage: &Stage, id: u32) -> PuppetOutput {
        let p = &stage.puppets()[id as usize];
        let skeleton = matches!(p.rig(), puppetry_stage::Rig::Skeleton(_));
        let (senders, output) = PuppetOutput::channels(PuppetStart {
            handles: published_handles(stage, id),
            weights: weights_message(stage, id),
            keys: keys_message(stage, id),
            history: history_message(stage, id),
            pose: skeleton.then(|| pose_message(stage, id)),
        });
        self.frames.push(senders.frame);
        self.rigs.push(senders.rig);
        self.weights.push(senders.weights);
        self.weights_published.push(p.weights_generation());
        self.keys.push(senders.keys);
        self.keys_published.push(p.keying().generation);
        self.handles.push(senders.handles);
        self.handle_frames.push(senders.handle_frame);
        self.history.push(senders.history);
        self.history_published.push(p.history());
        self.poses.push(senders.pose);
        self.poses_published.push(p.key_pose().1);
        self.depths.push(senders.depth);
        self.depths_published
            .push(p.depth().map_or(0, |(_, generation)| generation));
        self.sequences.push(0);
        self.arenas.push(Default::default());
        output
    }

    pub(super) fn publish_cursors(&mut self, cursors: &BTreeMap<String, CursorView>) {
        self.cursors.send_replace(cursors_message(cursors));
        self.changes.send_modify(|c| *c += 1);
    }
}
