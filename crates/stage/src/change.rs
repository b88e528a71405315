//! What changes the stage and what the stage did about it, as plain data:
//! a [`Change`] is one thing the stage thread applied (an input frame, a
//! pin, a paint dab, a key pose…), and a [`StageEvent`] is one handle made,
//! moved or removed because of it. Takes record both, so a take can be
//! replayed into the same stage ([`Stage::apply_change`]) and read without
//! one. Both serialise to JSON with positions as `[x, y]`.
//!
//! [`Stage::apply_change`]: crate::Stage::apply_change

use glam::DVec2;
use puppetry_contact::ContactFrame;
use serde::{Deserialize, Serialize};

/// One thing the stage thread applied. Everything that changes the stage's
/// handles, weights or rig state is one of these, so a list of them, with
/// where the solves fell, reproduces a performance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Change {
    /// An input frame: contacts landed, moved or lifted.
    Contacts {
        frame: ContactFrame,
    },
    /// A source went away: every contact it held is lifted.
    Release {
        source: String,
    },
    /// A pin on what a contact at `at` would grab.
    Pin {
        owner: String,
        at: DVec2,
    },
    Unpin {
        puppet: u32,
        handle: u64,
    },
    /// One dab of the stiffness brush; dabs of one `stroke` undo at once.
    Paint {
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stroke: Option<u64>,
    },
    /// One dab of the depth-layer brush: triangles under it take `layer`
    /// as their static depth; the dabs of one `stroke` undo at once.
    PaintDepth {
        puppet: u32,
        at: DVec2,
        radius: f64,
        layer: u16,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stroke: Option<u64>,
    },
    /// A skeleton set between two of its stage-file key poses.
    KeyPose {
        puppet: u32,
        from: String,
        to: String,
        t: f64,
    },
    /// A free-form puppet's solver, rebuilt with painted weights of this
    /// generation, was swapped in (the rebuild itself ran elsewhere).
    Rebuilt {
        puppet: u32,
        generation: u64,
    },
    /// The keyframing pad's control cursor of a puppet moved (pad
    /// coordinates, `[0, 1]²`), or was let go (`None`).
    Cursor {
        puppet: u32,
        at: Option<DVec2>,
    },
    /// A key pose made from the puppet's current pose, at a pad point.
    KeyAdd {
        puppet: u32,
        name: String,
        at: DVec2,
    },
    /// A key pose moved to another pad point.
    KeyMove {
        puppet: u32,
        key: usize,
        at: DVec2,
    },
    KeyDelete {
        puppet: u32,
        key: usize,
    },
    /// "This part in front": where a puppet overlaps itself at `at`, the
    /// part behind comes in front until the overlap is undone.
    DepthFlip {
        at: DVec2,
    },
    /// A puppet's rig back at its rest pose: a reset's last step. The
    /// handles still held pull it again at the next solve.
    Rest {
        puppet: u32,
    },
    /// A puppet's edits set wholesale: what an undo, redo or reset did.
    /// Recorded as the state it restored rather than as the undo, so a take
    /// replays the same whatever history the stage had when it began.
    Restore {
        puppet: u32,
        state: Snapshot,
    },
}

/// The part of a puppet's state that undo, redo and reset put back: its
/// painted weights, its pins, its skeleton's pose (each only if present).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Snapshot {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pins: Option<Vec<PinRecord>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<PoseRecord>,
    /// The static depth layers, one per triangle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layers: Option<Vec<u16>>,
}

/// A pin, exactly: its handle id, owner, grip and where it holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinRecord {
    pub handle: u64,
    /// An input source's id, or `config` for the stage file's pins.
    pub owner: String,
    pub grip: GripRecord,
    pub at: DVec2,
    pub offset: DVec2,
}

/// A grip, exactly (a material point by triangle and barycentric
/// coordinates, not by position, so restoring it is bit for bit).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum GripRecord {
    Vertex {
        index: u32,
    },
    Point {
        triangle: u32,
        bary: [f64; 3],
    },
    Grid {
        index: usize,
    },
    Joint {
        index: usize,
    },
    Bone {
        index: usize,
        along: f64,
        across: f64,
    },
}

/// A curve puppet's pose is its centre line, in `joints` (the rest empty).
///
/// A skeleton's pose: its FK state, its joints, and the key-pose blend it
/// was last set to (if any).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseRecord {
    pub roots: Vec<DVec2>,
    pub angles: Vec<f64>,
    pub lengths: Vec<f64>,
    pub joints: Vec<DVec2>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<KeyPoseState>,
}

/// A skeleton's blend between two of its stage-file key poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyPoseState {
    pub from: String,
    pub to: String,
    pub t: f64,
}

/// What a handle holds, as events name it: a material point by its rest
/// position (stage coordinates), a grid handle or a joint by index.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum GripEvent {
    Point {
        rest: DVec2,
    },
    Grid {
        index: usize,
    },
    Joint {
        index: usize,
    },
    /// A point on a skeleton's bone: `along` the bone (0 at its parent
    /// joint, 1 at its child) and `across` it (stage units, to the left).
    Bone {
        index: usize,
        along: f64,
        across: f64,
    },
}

/// One handle-level thing the stage did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum StageEvent {
    /// A handle was made (a contact grabbed, a pin was set, a key pose's
    /// cursor took hold).
    Made {
        puppet: u32,
        handle: u64,
        owner: String,
        /// The owner's contact that grabbed it (none for pins).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        contact: Option<u32>,
        kind: String,
        grip: GripEvent,
        at: DVec2,
    },
    Moved {
        puppet: u32,
        handle: u64,
        at: DVec2,
    },
    Removed {
        puppet: u32,
        handle: u64,
    },
}
