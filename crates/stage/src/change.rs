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
        /// The source's contacts, in stage coordinates.
        frame: ContactFrame,
    },
    /// A source went away: every contact it held is lifted.
    Release {
        /// The source's id.
        source: String,
    },
    /// A pin on what a contact at `at` would grab.
    Pin {
        /// The source that set it: its limits apply and the pin is its.
        owner: String,
        /// Where, in stage coordinates.
        at: DVec2,
    },
    /// A pin taken out; a handle that is not a pin is left alone.
    Unpin {
        /// The puppet it is on.
        puppet: u32,
        /// The pin's handle id.
        handle: u64,
    },
    /// One dab of the stiffness brush; dabs of one `stroke` undo at once.
    Paint {
        /// The puppet painted.
        puppet: u32,
        /// The brush's centre, in stage coordinates (on the pose as drawn).
        at: DVec2,
        /// The brush's radius in stage units: more than 0, at most the
        /// stage's larger side.
        radius: f64,
        /// What a weight at the centre is multiplied by, falling off to 1
        /// at the rim: [`MIN_STRENGTH`](crate::MIN_STRENGTH) to
        /// [`MAX_STRENGTH`](crate::MAX_STRENGTH), below 1 softens.
        strength: f64,
        /// The stroke the dab belongs to; `None` makes it an undo step of
        /// its own.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stroke: Option<u64>,
        /// Who painted it (a client's source): each painter numbers its
        /// own strokes, so two painters' strokes of one number stay two
        /// undo steps. None in takes recorded before it was kept.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        painter: Option<String>,
    },
    /// One dab of the depth-layer brush: triangles under it take `layer`
    /// as their static depth; the dabs of one `stroke` undo at once.
    PaintDepth {
        /// The puppet painted.
        puppet: u32,
        /// The brush's centre, in stage coordinates.
        at: DVec2,
        /// The brush's radius in stage units, as for [`Change::Paint`].
        radius: f64,
        /// The depth layer to paint, larger nearer; at most
        /// `puppetry_mesh::MAX_LAYER`.
        layer: u16,
        /// The stroke the dab belongs to; `None` makes it an undo step of
        /// its own.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stroke: Option<u64>,
        /// Who painted it (a client's source): each painter numbers its
        /// own strokes, so two painters' strokes of one number stay two
        /// undo steps. None in takes recorded before it was kept.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        painter: Option<String>,
    },
    /// A skeleton set between two of its stage-file key poses.
    KeyPose {
        /// The skeleton puppet.
        puppet: u32,
        /// The key pose at `t` = 0, by its stage-file name.
        from: String,
        /// The key pose at `t` = 1, by its stage-file name.
        to: String,
        /// How far from `from` to `to` (finite).
        t: f64,
    },
    /// A free-form puppet's solver, rebuilt with painted weights of this
    /// generation, was swapped in (the rebuild itself ran elsewhere).
    Rebuilt {
        /// The free-form puppet.
        puppet: u32,
        /// The weights generation the solver was built with.
        generation: u64,
    },
    /// The keyframing pad's control cursor of a puppet moved (pad
    /// coordinates, `[0, 1]²`), or was let go (`None`).
    Cursor {
        /// The puppet whose cursor it is.
        puppet: u32,
        /// The cursor in pad coordinates (clamped into `[0, 1]²`), or
        /// `None` when let go.
        at: Option<DVec2>,
    },
    /// A key pose made from the puppet's current pose, at a pad point.
    KeyAdd {
        /// The puppet keyed.
        puppet: u32,
        /// The key's name: not empty, unique among the puppet's keys.
        name: String,
        /// Where the key sits on the pad, in `[0, 1]²`.
        at: DVec2,
    },
    /// A key pose moved to another pad point.
    KeyMove {
        /// The puppet whose key it is.
        puppet: u32,
        /// The key's index in the puppet's key set.
        key: usize,
        /// Its new pad point, in `[0, 1]²`.
        at: DVec2,
    },
    /// A key pose deleted; the keys after it move down one index.
    KeyDelete {
        /// The puppet whose key it is.
        puppet: u32,
        /// The key's index in the puppet's key set.
        key: usize,
    },
    /// "This part in front": where a puppet overlaps itself at `at`, the
    /// part behind comes in front until the overlap is undone.
    DepthFlip {
        /// The stage point tapped (the topmost puppet there flips).
        at: DVec2,
    },
    /// A puppet's rig back at its rest pose: a reset's last step. The
    /// handles still held pull it again at the next solve.
    Rest {
        /// The puppet reset.
        puppet: u32,
    },
    /// A puppet's edits set wholesale: what an undo, redo or reset did.
    /// Recorded as the state it restored rather than as the undo, so a take
    /// replays the same whatever history the stage had when it began.
    Restore {
        /// The puppet restored.
        puppet: u32,
        /// The parts of its state to set; parts it leaves out stay.
        state: Snapshot,
    },
}

/// The part of a puppet's state that undo, redo and reset put back: its
/// painted weights, its pins, its skeleton's pose (each only if present).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Snapshot {
    /// The per-triangle stiffness weights, one per triangle, within the
    /// mesh's weight range.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<Vec<f64>>,
    /// Every pin of the puppet: restoring removes pins not listed and puts
    /// back listed ones that are missing, with their ids.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pins: Option<Vec<PinRecord>>,
    /// A skeleton's or curve's pose.
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
    /// The pin's handle id, kept when it is put back.
    pub handle: u64,
    /// An input source's id, or `config` for the stage file's pins.
    pub owner: String,
    /// What it holds.
    pub grip: GripRecord,
    /// Where it holds it (the handle's target, stage coordinates).
    pub at: DVec2,
    /// From `at` to the rig point or material point it took hold of
    /// (stage units), so what it holds does not jump to `at`.
    pub offset: DVec2,
}

/// Declares a grip enum of a file format: its own variants for a
/// material point, then the rig's (a grid handle, a joint, a point on a
/// bone), the same in every format. One list, because serde's tagged
/// enums cannot hold another under `deny_unknown_fields` without losing
/// its errors.
macro_rules! grip_enum {
    ($(#[$meta:meta])* $vis:vis enum $name:ident { $($points:tt)* }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
        $vis enum $name {
            $($points)*
            /// A grid handle of an lp-FFD puppet.
            Grid {
                /// The handle's index, row by row from the lower left.
                index: usize,
            },
            /// A joint of a skeleton puppet.
            Joint {
                /// The joint's index.
                index: usize,
            },
            /// A point on a skeleton's bone, in the bone's frame.
            Bone {
                /// The bone's index.
                index: usize,
                /// Along the bone: 0 at its parent joint, 1 at its child.
                along: f64,
                /// Across the bone, in stage units, to the left.
                across: f64,
            },
        }
    };
}

grip_enum! {
    /// A grip, exactly (a material point by triangle and barycentric
    /// coordinates, not by position, so restoring it is bit for bit).
    pub enum GripRecord {
        /// A vertex of the mesh.
        Vertex {
            /// The vertex's index.
            index: u32,
        },
        /// A material point inside a triangle.
        Point {
            /// The triangle's index.
            triangle: u32,
            /// The point's barycentric coordinates in it (summing to 1).
            bary: [f64; 3],
        },
    }
}

/// A curve puppet's pose is its centre line, in `joints` (the rest empty).
///
/// A skeleton's pose: its FK state, its joints, and the key-pose blend it
/// was last set to (if any).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseRecord {
    /// Each root joint's position (stage coordinates), one per tree.
    pub roots: Vec<DVec2>,
    /// Each bone's angle in radians: counter-clockwise from +x for a bone
    /// leaving a root joint, else relative to its parent bone.
    pub angles: Vec<f64>,
    /// Each bone's length, in stage units.
    pub lengths: Vec<f64>,
    /// A skeleton's joint positions, or a curve's centre-line points
    /// (stage coordinates).
    pub joints: Vec<DVec2>,
    /// The key-pose blend the skeleton was last set to; none when it was
    /// posed otherwise (or is a curve).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<KeyPoseState>,
}

/// A skeleton's blend between two of its stage-file key poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyPoseState {
    /// The key pose at `t` = 0, by its stage-file name.
    pub from: String,
    /// The key pose at `t` = 1, by its stage-file name.
    pub to: String,
    /// How far from `from` to `to`.
    pub t: f64,
}

grip_enum! {
    /// What a handle holds, as events name it: a material point by its
    /// rest position (stage coordinates), a grid handle or a joint by
    /// index.
    pub enum GripEvent {
        /// A material point of the mesh.
        Point {
            /// Where the point is in the rest mesh as placed on the stage.
            rest: DVec2,
        },
    }
}

/// One handle-level thing the stage did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum StageEvent {
    /// A handle was made (a contact grabbed, a pin was set, a key pose's
    /// cursor took hold).
    Made {
        /// The puppet it is on.
        puppet: u32,
        /// The new handle's id.
        handle: u64,
        /// Who holds it: a source's id, `config` or `keys`.
        owner: String,
        /// The owner's contact that grabbed it (none for pins).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        contact: Option<u32>,
        /// `contact`, `pin` or `key` (see [`HandleKind`](crate::HandleKind)).
        kind: String,
        /// What it holds.
        grip: GripEvent,
        /// Where it is held, in stage coordinates.
        at: DVec2,
    },
    /// A contact moved the handle it holds.
    Moved {
        /// The puppet it is on.
        puppet: u32,
        /// The handle's id.
        handle: u64,
        /// Where it is held now, in stage coordinates.
        at: DVec2,
    },
    /// A handle was let go: its contact lifted or its source went, a pin
    /// was removed, the keys let go, or its puppet left the stage.
    Removed {
        /// The puppet it was on.
        puppet: u32,
        /// The handle's id.
        handle: u64,
    },
}
