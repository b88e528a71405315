//! What changes the stage and what the stage did about it, as plain data:
//! a [`Change`] is one thing the stage thread applied (an input frame, a
//! pin, a paint dab, a key pose…), and a [`StageEvent`] is one handle made,
//! moved or removed because of it. Takes record both, so a take can be
//! replayed into the same stage ([`Stage::apply_change`]) and read without
//! one. Both serialise to JSON with positions as `[x, y]`.
//!
//! [`Stage::apply_change`]: crate::Stage::apply_change

use glam::DVec2;
use puppetry_input::ContactFrame;
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
    /// One dab of the stiffness brush.
    Paint {
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
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
}

/// What a handle holds, as events name it: a material point by its rest
/// position (stage coordinates), a grid handle or a joint by index.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum GripEvent {
    Point { rest: DVec2 },
    Grid { index: usize },
    Joint { index: usize },
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
