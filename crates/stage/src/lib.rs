//! The stage: puppets placed in stage coordinates, and the mapping from
//! touch contacts to handles on them. A contact that lands near a grid
//! handle or joint of a rigged puppet grabs it ([`rig`]); otherwise one that
//! lands on a puppet grabs the material point under it (a point handle in
//! the triangle it touched, topmost puppet first; skeleton puppets ignore
//! it); moving the contact drags what it holds; lifting it lets go. Painted
//! per-triangle weights live here too. Pins are handles that stay. Every
//! handle knows its owner, so contacts from different devices and clients
//! never get confused. A curve puppet is a mesh puppet too: its mesh is the
//! ribbon built along its centre line, which its rig deforms.
//!
//! Plain synchronous state, with no tokio and no wire format in reach: the
//! daemon's stage thread runs it, with the solvers, on a thread of its own,
//! and turns what it holds into protocol messages.

pub mod change;
pub mod config;
pub mod keys;
pub mod pad;
pub mod rig;

use std::collections::HashMap;
use std::path::PathBuf;

use glam::DVec2;

pub use change::{
    Change, GripEvent, GripRecord, KeyPoseState, PinRecord, PoseRecord, Snapshot, StageEvent,
};
use config::{PuppetConfig, SaveWeights, StageConfig};
use puppetry_contact::{ContactFrame, Phase, SourceId};
use puppetry_deform::{Anchor, Arap};
use puppetry_mesh::{MAX_WEIGHT, MIN_WEIGHT, Mesh, MeshError};
pub use rig::{Grip, Rig};

/// Why a performer's request (paint, pose, export, save) could not be done.
#[derive(Debug, thiserror::Error)]
pub enum CommandError {
    #[error("puppet {puppet}: no such puppet (the stage has {count})")]
    NoSuchPuppet { puppet: u32, count: usize },
    #[error("puppet {puppet}: has no grid")]
    NoGrid { puppet: u32 },
    #[error("puppet {puppet}: has no skeleton")]
    NoSkeleton { puppet: u32 },
    #[error(
        "puppet {puppet}: a curve puppet has no weights to save (its mesh is built from its curve)"
    )]
    NoWeights { puppet: u32 },
    #[error("puppet {puppet}: has no depth to paint (depth = \"off\")")]
    NoDepth { puppet: u32 },
    #[error("paint needs finite x and y")]
    BadBrush,
    /// A number outside its documented range; `field` names it as the
    /// message does (`radius`, `strength`).
    #[error("{field}: {problem}")]
    OutOfRange {
        field: &'static str,
        problem: String,
    },
    #[error("puppet {puppet}: cannot restore: {problem}")]
    Restore { puppet: u32, problem: String },
    #[error("{file}: {source}")]
    Write {
        file: String,
        source: std::io::Error,
    },
    #[error("puppet {puppet}: {source}")]
    Rig { puppet: u32, source: rig::RigError },
    #[error("{file}: {source}")]
    Weights { file: String, source: MeshError },
    #[error("puppet {puppet}: a rebuilt solver is swapped in with install, not applied")]
    NeedsSolver { puppet: u32 },
    #[error("puppet {puppet}: {source}")]
    Keys {
        puppet: u32,
        source: keys::KeysError,
    },
    #[error("puppet {puppet}: no key file is named for it in the stage file (`keys`)")]
    NoKeyFile { puppet: u32 },
    #[error("pad point [{x}, {y}] is not finite")]
    BadPadPoint { x: f64, y: f64 },
    /// Something else is under way (a take recording) that this would spoil.
    #[error("{problem}")]
    Busy { problem: String },
    /// A puppet could not be put on the stage.
    #[error("{problem}")]
    Load { problem: String },
    /// A draw order that is not every puppet on stage once.
    #[error("order: {problem}")]
    BadOrder { problem: String },
}

#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("{file}: puppet[{index}] ({puppet}).{field}: {problem}")]
    Rig {
        file: String,
        index: usize,
        puppet: String,
        field: String,
        problem: String,
    },
    #[error("puppet {puppet}: pin {index} at [{x}, {y}] is not on the puppet")]
    PinOutside {
        puppet: String,
        index: usize,
        x: f64,
        y: f64,
    },
    #[error(transparent)]
    KeyFile(#[from] keys::KeysError),
    #[error("{file}: {field}: {problem}")]
    Keys {
        file: String,
        field: String,
        problem: String,
    },
    #[error("puppet {puppet}: image {path}: {problem}")]
    Image {
        puppet: String,
        path: String,
        problem: String,
    },
}

/// The brush's `strength` range: a dab at most multiplies a weight by
/// 1000 or divides it by 1000 (three of the weight range's seven orders of
/// magnitude per dab).
pub const MIN_STRENGTH: f64 = 1e-3;
pub const MAX_STRENGTH: f64 = 1e3;

/// Undo steps kept per puppet; older ones are forgotten.
pub const MAX_HISTORY: usize = 64;

/// A grid handle or joint within this fraction of the stage's smaller side
/// from where a contact lands is what it grabs.
pub const GRAB_RADIUS_FRACTION: f64 = 1.0 / 60.0;

/// A contact this fraction of the stage's smaller side outside a puppet's
/// outline still grabs it (the nearest point of it), when it lands on no
/// puppet: 6 units on the demo's 720-high stage, about 5 mm on a 1.2 m
/// touch table. A touch table reports the middle of a finger's patch
/// (8–10 mm across), so a finger half on a thin limb's edge lands up to
/// half a finger outside it; half the grab radius (which is what a grid
/// handle or joint may be missed by) takes that and not the background
/// between a hand and the body.
pub const OUTLINE_REACH_FRACTION: f64 = GRAB_RADIUS_FRACTION / 2.0;

/// A point within this fraction of a triangle's perimeter of it is on it:
/// round-off in a solved pose (or a vertex streamed as f32, about 1e-7 of
/// its coordinates) must not decide whether a point on the outline is.
const ON_OUTLINE: f64 = 1e-6;

/// Who holds a handle.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Owner {
    /// An input source (a device, a replay, a performer's browser), by id.
    Source(String),
    /// The stage file.
    Config,
}

impl std::fmt::Display for Owner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Owner::Source(id) => f.write_str(id),
            Owner::Config => f.write_str("config"),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HandleKind {
    Contact,
    Pin,
    /// Held by the keyframing cursor's blend of key poses.
    Key,
}

/// A puppet's picture: a PNG file, or the small texture a plain-coloured
/// stroke (a curve puppet without an image) is drawn with.
#[derive(Debug, Clone, PartialEq)]
pub enum Picture {
    File(PathBuf),
    Stroke([u8; 3]),
}

impl Picture {
    /// The picture as PNG bytes: the file, read as every named file is
    /// (a regular file, at most `MAX_PICTURE_FILE_BYTES`), or a stroke's
    /// texture. Blocks on the file: async callers run it off the runtime.
    pub fn png(&self) -> Result<Vec<u8>, puppetry_mesh::file::FileError> {
        use puppetry_mesh::file;
        match self {
            Picture::File(path) => file::read(path, file::PICTURE_FILE),
            Picture::Stroke(colour) => Ok(puppetry_mesh::stroke::stroke_texture_png(*colour)),
        }
    }
}

impl std::fmt::Display for Picture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Picture::File(path) => write!(f, "{}", path.display()),
            Picture::Stroke([r, g, b]) => write!(f, "stroke #{r:02x}{g:02x}{b:02x}"),
        }
    }
}

/// A handle on a puppet.
#[derive(Debug, Clone)]
pub struct Handle {
    pub id: u64,
    pub owner: Owner,
    pub kind: HandleKind,
    pub grip: Grip,
    /// Where the handle is held now (stage coordinates).
    pub target: DVec2,
    /// From where the contact landed to the grid handle or joint it grabbed:
    /// the rig point keeps that offset, so it does not jump to the finger.
    pub offset: DVec2,
}

impl Handle {
    /// Where the rig is asked to put what this handle holds.
    pub fn rig_target(&self) -> DVec2 {
        self.target + self.offset
    }
}

/// A puppet on the stage, with its rig.
pub struct Puppet {
    pub id: u32,
    pub name: String,
    pub picture: Picture,
    /// The rest mesh, placed on the stage (with the stage file's weights).
    pub mesh: Mesh,
    /// The mesh file, and its mesh in its own coordinates: painted weights
    /// are saved there (a curve puppet has no file: its mesh is built).
    pub mesh_file: PathBuf,
    source_mesh: Mesh,
    /// The per-triangle weights now (painted ones included).
    weights: Vec<f64>,
    /// Bumped by every paint stroke that changed a weight.
    weights_generation: u64,
    rig: Rig,
    handles: Vec<Handle>,
    /// The handle set changed since the last solve (recompile needed).
    handles_changed: bool,
    /// Some handle moved (or the rig changed) since the last solve.
    moved: bool,
    /// Painted weights not yet given to a grid or skeleton rig.
    weights_pending: bool,
    /// Where the mesh sits on the stage.
    placement: pad::Placement,
    /// Spatial keyframing: key poses and the cursor.
    keying: pad::Keying,
    /// Bumped whenever the handle set changes (a handle made or removed):
    /// handle-position frames say which set their points follow.
    handles_generation: u32,
    /// Undo and redo of painting, pins and poses.
    history: History,
    /// The weights, pins and pose as loaded: what reset puts back.
    loaded: Snapshot,
    /// The key-pose blend a `pose` request last set (none at rest).
    key_pose: Option<KeyPoseState>,
    /// Bumped whenever `key_pose` is set.
    pose_generation: u64,
    save_weights: SaveWeights,
    /// Taken off the stage at runtime: not drawn, grabbed or solved; its id
    /// is never reused, so frames already sent cannot land on another.
    removed: bool,
    /// Per-triangle depth, adjusted where the pose overlaps itself (none
    /// with `depth = "off"`).
    depth: Option<puppetry_deform::depth::DepthOrder>,
    /// Bumped whenever the depth changes, so it is sent only then.
    depth_generation: u32,
    /// The static depth layers as painted (one per triangle), or none: the
    /// order of the mesh's pieces.
    layers: Option<Vec<u16>>,
}

/// A puppet's undo and redo stacks: each entry is the state an edit
/// replaced (undo) or an undo replaced (redo).
#[derive(Default)]
struct History {
    undo: Vec<Snapshot>,
    redo: Vec<Snapshot>,
    /// The edit that the next one of the same group joins (the dabs of one
    /// stroke, a run of poses between the same key poses); any other edit,
    /// undo or redo closes it.
    open: Option<Group>,
}

#[derive(Debug, Clone, PartialEq)]
enum Group {
    Stroke(u64),
    Pose(String, String),
}

impl History {
    /// Records that an edit replaced `before` (unless it joins the open
    /// group, whose entry already holds the state before it).
    fn edit(&mut self, before: impl FnOnce() -> Snapshot, group: Option<Group>) {
        if group.is_some() && self.open == group {
            return;
        }
        self.undo.push(before());
        if self.undo.len() > MAX_HISTORY {
            self.undo.remove(0);
        }
        self.redo.clear();
        self.open = group;
    }
}

/// What a contact landing on a puppet finds.
enum Reach {
    Grip(Grip, DVec2),
    /// On a skeleton puppet but away from its joints: ignored, and it does
    /// not fall through to the puppets below.
    Blocked,
    Miss,
}

impl Puppet {
    /// Loads the puppet `p` of the stage file `config` (its `index`-th):
    /// mesh, placement, rig and key poses; pins are the stage's to add.
    /// Pure work over files, so a running stage can have it done off its
    /// thread before [`Stage::add_puppet`].
    pub fn load(
        config: &StageConfig,
        index: usize,
        p: &PuppetConfig,
    ) -> Result<Puppet, StageError> {
        let rig_error = |(field, problem): (String, String)| StageError::Rig {
            file: config.file.clone(),
            index,
            puppet: p.name.clone(),
            field,
            problem,
        };
        let (mesh_file, mesh, picture) = match &p.curve {
            Some(c) => {
                let source = format!("{} puppet[{index}].curve", config.file);
                let mesh = curve_rest_mesh(&source, c).map_err(rig_error)?;
                let picture = if p.image.as_os_str().is_empty() {
                    Picture::Stroke(c.rgb())
                } else {
                    Picture::File(config.resolve(&p.image))
                };
                (PathBuf::new(), mesh, picture)
            }
            None => {
                let mesh_file = config.resolve(&p.mesh);
                let mesh = Mesh::load(&mesh_file)?;
                (mesh_file, mesh, Picture::File(config.resolve(&p.image)))
            }
        };
        let placed = place(&mesh, p.at.into(), p.scale)?;
        let rig = Rig::from_config(
            &mesh,
            &placed,
            p.at.into(),
            p.scale,
            p.grid.as_ref(),
            p.skeleton.as_ref(),
            p.curve.as_ref(),
        )
        .map_err(rig_error)?;
        let (lo, hi) = bounds(mesh.vertices());
        let placement = pad::Placement {
            at: p.at.into(),
            scale: p.scale,
            centre: (lo + hi) / 2.0,
        };
        let mut puppet = Puppet {
            placement,
            keying: pad::Keying::empty(None),
            id: index as u32,
            name: p.name.clone(),
            picture,
            weights: placed.weights().to_vec(),
            mesh: placed,
            mesh_file,
            source_mesh: mesh,
            weights_generation: 0,
            rig,
            handles: Vec::new(),
            handles_changed: false,
            moved: false,
            weights_pending: false,
            handles_generation: 0,
            history: History::default(),
            loaded: Snapshot::default(),
            key_pose: None,
            pose_generation: 0,
            save_weights: p.save_weights,
            removed: false,
            depth: None,
            depth_generation: 0,
            layers: None,
        };
        if p.depth == config::DepthMode::Pieces {
            // Registered on the mesh as placed, so "moved further from rest"
            // (which side of a fold goes in front) measures the bend, not
            // where the puppet stands.
            puppet.layers = puppet.mesh.layers().map(|l| l.to_vec());
            let order = puppetry_deform::depth::DepthOrder::register(
                &puppet.mesh,
                puppet.layers.as_deref(),
            )
            .map_err(|e| StageError::Rig {
                file: config.file.clone(),
                index,
                puppet: p.name.clone(),
                field: "depth".into(),
                problem: e.to_string(),
            })?;
            puppet.depth = Some(order);
        }
        if let Some(keys) = &p.keys {
            let file = config.resolve(keys);
            if file.exists() {
                let key_file = keys::KeyFile::load(&file)?;
                puppet.keying = pad::Keying::load(
                    file.clone(),
                    key_file,
                    &p.name,
                    &puppet.rig,
                    puppet.placement,
                    |at| puppet.hit(at),
                )
                .map_err(|(field, problem)| StageError::Keys {
                    file: file.display().to_string(),
                    field,
                    problem,
                })?;
            } else {
                puppet.keying = pad::Keying::empty(Some(file));
            }
        }
        Ok(puppet)
    }

    /// The depth of each triangle (larger is nearer) and its generation,
    /// which changes only when a depth does; `None` with `depth = "off"`.
    pub fn depth(&self) -> Option<(&[u16], u32)> {
        self.depth
            .as_ref()
            .map(|d| (d.depth(), self.depth_generation))
    }

    /// Taken off the stage at runtime ([`Stage::remove_puppet`]).
    pub fn removed(&self) -> bool {
        self.removed
    }

    pub fn handles(&self) -> &[Handle] {
        &self.handles
    }

    /// Spatial keyframing: key poses and the cursor.
    pub fn keying(&self) -> &pad::Keying {
        &self.keying
    }

    /// Where an anchor is in the current pose.
    fn posed(&self, anchor: Anchor) -> DVec2 {
        let pose = self.pose();
        match anchor {
            Anchor::Vertex(i) => pose[i as usize],
            Anchor::Point { triangle, bary } => {
                let tri = self.mesh.triangles()[triangle as usize];
                (0..3).map(|k| pose[tri[k] as usize] * bary[k]).sum()
            }
        }
    }

    /// Each handle's point on the puppet now, in handle order: a material
    /// point where the solve put it; a grid handle, joint or bone point
    /// less the offset it was grabbed with (where the finger holds it).
    pub fn handle_points(&self, out: &mut Vec<DVec2>) {
        out.clear();
        out.extend(self.handles.iter().map(|h| {
            match h.grip {
                Grip::Point(anchor) => self.posed(anchor),
                grip => self
                    .rig
                    .grip_position(grip)
                    .map_or(h.target, |q| q - h.offset),
            }
        }));
    }

    /// Bumped whenever the handle set changes.
    pub fn handles_generation(&self) -> u32 {
        self.handles_generation
    }

    /// Undo and redo steps available.
    pub fn history(&self) -> (usize, usize) {
        (self.history.undo.len(), self.history.redo.len())
    }

    /// The key-pose blend a `pose` request last set (none at rest), and a
    /// counter bumped whenever it is set.
    pub fn key_pose(&self) -> (Option<&KeyPoseState>, u64) {
        (self.key_pose.as_ref(), self.pose_generation)
    }

    /// The pins now, exactly.
    fn pin_records(&self) -> Vec<PinRecord> {
        self.handles
            .iter()
            .filter(|h| h.kind == HandleKind::Pin)
            .map(|h| PinRecord {
                handle: h.id,
                owner: h.owner.to_string(),
                grip: grip_record(h.grip),
                at: h.target,
                offset: h.offset,
            })
            .collect()
    }

    /// The skeleton's pose now (none for other rigs).
    fn pose_record(&self) -> Option<PoseRecord> {
        if let Rig::Curve(r) = &self.rig {
            return Some(PoseRecord {
                roots: Vec::new(),
                angles: Vec::new(),
                lengths: Vec::new(),
                joints: r.curve().pose().to_vec(),
                key: None,
            });
        }
        let Rig::Skeleton(r) = &self.rig else {
            return None;
        };
        let (pose, joints) = r.pose_state();
        Some(PoseRecord {
            roots: pose.roots,
            angles: pose.angles,
            lengths: pose.lengths,
            joints,
            key: self.key_pose.clone(),
        })
    }

    /// The state now of the parts `like` holds.
    fn capture(&self, like: &Snapshot) -> Snapshot {
        Snapshot {
            weights: like.weights.as_ref().map(|_| self.weights.clone()),
            pins: like.pins.as_ref().map(|_| self.pin_records()),
            pose: like.pose.as_ref().and_then(|_| self.pose_record()),
            layers: like.layers.as_ref().and_then(|_| self.static_layers()),
        }
    }

    /// The static depth layers now: as painted, else the pieces' order
    /// (none with `depth = "off"`).
    pub fn static_layers(&self) -> Option<Vec<u16>> {
        let depth = self.depth.as_ref()?;
        Some(
            self.layers
                .clone()
                .unwrap_or_else(|| depth.static_depth().to_vec()),
        )
    }

    /// Takes `layers` as the static depth order (painted or put back),
    /// starting the adjustment afresh from it; depth flips stay.
    fn set_layers(&mut self, layers: Vec<u16>) -> Result<(), String> {
        let order = match &self.depth {
            Some(old) => old.with_layers(&self.mesh, &layers),
            None => puppetry_deform::depth::DepthOrder::register(&self.mesh, Some(&layers)),
        }
        .map_err(|e| e.to_string())?;
        self.depth = Some(order);
        self.layers = Some(layers);
        self.depth_generation = self.depth_generation.wrapping_add(1);
        self.moved = true;
        Ok(())
    }

    /// A recorded grip as a grip of this puppet, if it fits its mesh and
    /// rig.
    fn grip_of(&self, record: GripRecord) -> Option<Grip> {
        let rig_points = self.rig.points().map_or(0, |p| p.len());
        let grip = match record {
            GripRecord::Vertex { index } => ((index as usize) < self.mesh.vertices().len())
                .then_some(Grip::Point(Anchor::Vertex(index)))?,
            GripRecord::Point { triangle, bary } => ((triangle as usize)
                < self.mesh.triangles().len()
                && bary.iter().all(|b| b.is_finite()))
            .then_some(Grip::Point(Anchor::Point { triangle, bary }))?,
            GripRecord::Grid { index } => (matches!(self.rig, Rig::Grid(_)) && index < rig_points)
                .then_some(Grip::GridHandle(index))?,
            GripRecord::Joint { index } => (matches!(self.rig, Rig::Skeleton(_))
                && index < rig_points)
                .then_some(Grip::Joint(index))?,
            GripRecord::Bone {
                index,
                along,
                across,
            } => {
                let Rig::Skeleton(r) = &self.rig else {
                    return None;
                };
                (index < r.deformer().skeleton().bones().len()
                    && along.is_finite()
                    && across.is_finite())
                .then_some(Grip::Bone {
                    index,
                    along,
                    across,
                })?
            }
        };
        Some(grip)
    }

    /// Where an anchor is in the current pose.
    fn grip_now(&self, grip: Grip) -> Option<DVec2> {
        match grip {
            Grip::Point(anchor) => Some(self.posed(anchor)),
            other => self.rig.grip_position(other),
        }
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The deformed vertices (stage coordinates, rest order).
    pub fn pose(&self) -> &[DVec2] {
        self.rig.pose()
    }

    /// The per-triangle weights now, painted ones included.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Bumped by every paint dab that changed a weight.
    pub fn weights_generation(&self) -> u64 {
        self.weights_generation
    }

    /// The triangle of the current pose under `p` and `p`'s barycentric
    /// coordinates there: what a finger landing at `p` touches. A point on
    /// the outline (a boundary vertex or edge) is on the puppet.
    pub fn hit(&self, p: DVec2) -> Option<Anchor> {
        self.hit_within(p, 0.0).map(|(anchor, _)| anchor)
    }

    /// As [`Puppet::hit`], and when nothing is under `p`, the point of the
    /// puppet nearest `p` if it is within `reach` (stage units): the anchor
    /// and where it is now. A contact's position is where the middle of a
    /// finger is, or a vertex streamed as f32 and sent back: either can
    /// land a hair outside the outline it is on.
    pub fn hit_within(&self, p: DVec2, reach: f64) -> Option<(Anchor, DVec2)> {
        let pose = self.pose();
        let mut inside: Option<(u16, f64, u32, [f64; 3])> = None;
        let mut nearest: Option<(f64, u16, u32, DVec2)> = None;
        for (t, tri) in self.mesh.triangles().iter().enumerate() {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            // The box test must not be stricter than the tests below: an
            // exact one dropped points on the outline that round-off in
            // the pose put a hair outside (issue 31).
            let slack = reach + ON_OUTLINE * (a.distance(b) + b.distance(c) + c.distance(a));
            let lo = a.min(b).min(c) - DVec2::splat(slack);
            let hi = a.max(b).max(c) + DVec2::splat(slack);
            if p.x < lo.x || p.y < lo.y || p.x > hi.x || p.y > hi.y {
                continue;
            }
            // Deformed meshes may fold over: the part drawn in front is the
            // one under the finger; then the triangle containing the point
            // most deeply.
            let near = self.depth.as_ref().map_or(0, |d| d.depth()[t]);
            let bary = barycentric_in(a, b, c, p);
            if !bary.iter().all(|b| b.is_finite()) {
                // Collapsed to a segment in this pose: its neighbours,
                // which share its edges, are hit instead.
                continue;
            }
            let worst = bary[0].min(bary[1]).min(bary[2]);
            if worst >= 0.0 {
                if inside.is_none_or(|(n, w, _, _)| (near, worst) > (n, w)) {
                    inside = Some((near, worst, t as u32, bary));
                }
                continue;
            }
            // Outside this triangle: how far, in stage units (barycentric
            // coordinates are no distance: a thin triangle's grow fast).
            let q = [(a, b), (b, c), (c, a)]
                .map(|(u, v)| closest_on_segment(u, v, p))
                .into_iter()
                .min_by(|x, y| x.distance_squared(p).total_cmp(&y.distance_squared(p)))
                .unwrap_or(a);
            let d = q.distance(p);
            let on = ON_OUTLINE * (a.distance(b) + b.distance(c) + c.distance(a));
            if d <= reach.max(on)
                && nearest.is_none_or(|(nd, n, _, _)| {
                    (d, std::cmp::Reverse(near)) < (nd, std::cmp::Reverse(n))
                })
            {
                nearest = Some((d, near, t as u32, q));
            }
        }
        let anchor = |triangle: u32, bary: [f64; 3]| {
            let clamped = bary.map(|b| b.max(0.0));
            let sum: f64 = clamped.iter().sum();
            Anchor::Point {
                triangle,
                bary: clamped.map(|b| b / sum),
            }
        };
        if let Some((_, _, triangle, bary)) = inside {
            return Some((anchor(triangle, bary), p));
        }
        let (_, _, triangle, q) = nearest?;
        let [a, b, c] = self.mesh.triangles()[triangle as usize].map(|i| pose[i as usize]);
        let found = anchor(triangle, barycentric_in(a, b, c, q));
        Some((found, self.posed(found)))
    }

    /// How events name a grip: a material point by its rest position.
    fn grip_event(&self, grip: Grip) -> GripEvent {
        match grip {
            Grip::Point(anchor) => GripEvent::Point {
                rest: anchor_position(&self.mesh, anchor),
            },
            Grip::GridHandle(index) => GripEvent::Grid { index },
            Grip::Joint(index) => GripEvent::Joint { index },
            Grip::Bone {
                index,
                along,
                across,
            } => GripEvent::Bone {
                index,
                along,
                across,
            },
        }
    }

    /// A grid handle or joint near `p` first, then the material point.
    /// What a contact at `p` grabs of this puppet: a grid handle or joint
    /// within `radius`, else the point under it, or (with `outline` > 0)
    /// the nearest point within `outline` outside it, held where it is.
    fn reach(&self, p: DVec2, radius: f64, outline: f64) -> Reach {
        if let Some(grip) = self.rig.point_near(p, radius) {
            let at = self.rig.grip_position(grip).unwrap_or(p);
            return Reach::Grip(grip, at - p);
        }
        match self.hit_within(p, outline) {
            Some((anchor, at)) if self.rig.takes_points() => {
                Reach::Grip(Grip::Point(anchor), at - p)
            }
            // A skeleton is held by its bones: the nearest one, at the
            // point under the finger.
            Some(_) => match self.rig.bone_near(p) {
                Some(grip) => Reach::Grip(grip, DVec2::ZERO),
                None => Reach::Blocked,
            },
            None => Reach::Miss,
        }
    }

    /// Multiplies the weights of the triangles whose deformed centroid lies
    /// within `radius` of `at` by `strength` raised to the brush's falloff
    /// (1 at the centre, 0 at the rim), clamped to the mesh's weight range.
    /// Returns whether any weight changed.
    fn paint(&mut self, at: DVec2, radius: f64, strength: f64) -> bool {
        let pose = self.rig.pose();
        let mut changed = false;
        for (tri, w) in self.mesh.triangles().iter().zip(&mut self.weights) {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            let d = ((a + b + c) / 3.0).distance(at);
            if d >= radius {
                continue;
            }
            let painted = (*w * strength.powf(1.0 - d / radius)).clamp(MIN_WEIGHT, MAX_WEIGHT);
            if painted != *w {
                *w = painted;
                changed = true;
            }
        }
        changed
    }
}

/// A curve puppet's ribbon mesh, in its own coordinates: the centre line
/// (points or SVG path) checked, resampled evenly (the paper's §7) and
/// widened. Errors are `(field, problem)`.
pub fn curve_rest_mesh(source: &str, c: &config::CurveConfig) -> Result<Mesh, (String, String)> {
    use puppetry_deform::curve::{resample_evenly, validate};
    use puppetry_mesh::stroke::{parse_svg_path, ribbon_mesh};
    let (field, given) = match (&c.points, &c.svg) {
        (Some(points), _) => (
            "curve.points",
            points.iter().map(|&p| DVec2::from(p)).collect::<Vec<_>>(),
        ),
        (None, Some(d)) => {
            let step = c.spacing.unwrap_or(c.width / 3.0) / 4.0;
            let mut points =
                parse_svg_path(d, step).map_err(|e| ("curve.svg".to_string(), e.to_string()))?;
            // Béziers with a control point on an end repeat it: not the
            // author's doing, so not an error.
            points.dedup();
            ("curve.svg", points)
        }
        (None, None) => {
            return Err(("curve.points".into(), "missing: give points or svg".into()));
        }
    };
    validate(&given).map_err(|e| (field.to_string(), e.to_string()))?;
    let length: f64 = given.windows(2).map(|w| w[0].distance(w[1])).sum();
    let spacing = c.spacing.unwrap_or((c.width / 3.0).max(length / 2000.0));
    let centre = resample_evenly(&given, spacing)
        .map_err(|e| ("curve.spacing".to_string(), e.to_string()))?;
    validate(&centre).map_err(|e| ("curve.spacing".to_string(), format!("resampled: {e}")))?;
    ribbon_mesh(source, &centre, c.width).map_err(|e| ("curve.width".to_string(), e.to_string()))
}

/// Where an anchor lies on a mesh.
fn anchor_position(mesh: &Mesh, anchor: Anchor) -> DVec2 {
    let v = mesh.vertices();
    match anchor {
        Anchor::Vertex(i) => v[i as usize],
        Anchor::Point { triangle, bary } => {
            let tri = mesh.triangles()[triangle as usize];
            (0..3).map(|k| v[tri[k] as usize] * bary[k]).sum()
        }
    }
}

/// A grip, exactly, as a record.
fn grip_record(grip: Grip) -> GripRecord {
    match grip {
        Grip::Point(Anchor::Vertex(index)) => GripRecord::Vertex { index },
        Grip::Point(Anchor::Point { triangle, bary }) => GripRecord::Point { triangle, bary },
        Grip::GridHandle(index) => GripRecord::Grid { index },
        Grip::Joint(index) => GripRecord::Joint { index },
        Grip::Bone {
            index,
            along,
            across,
        } => GripRecord::Bone {
            index,
            along,
            across,
        },
    }
}

/// The point of the segment `u`–`v` nearest `p`.
fn closest_on_segment(u: DVec2, v: DVec2, p: DVec2) -> DVec2 {
    let along = v - u;
    let length = along.length_squared();
    if length == 0.0 {
        return u;
    }
    u + along * ((p - u).dot(along) / length).clamp(0.0, 1.0)
}

fn barycentric_in(a: DVec2, b: DVec2, c: DVec2, p: DVec2) -> [f64; 3] {
    let d = (b - a).perp_dot(c - a);
    let l1 = (p - a).perp_dot(c - a) / d;
    let l2 = (b - a).perp_dot(p - a) / d;
    [1.0 - l1 - l2, l1, l2]
}

/// A free-form puppet's solver rebuild with painted weights: the mesh to
/// register, and the weights generation it carries.
pub struct Rebuild {
    pub puppet: u32,
    pub generation: u64,
    pub mesh: Mesh,
}

/// A grid puppet's grid, as an export request is answered.
#[derive(Debug, Clone, PartialEq)]
pub struct GridExport {
    pub puppet: u32,
    pub columns: usize,
    pub rows: usize,
    /// Rest grid handles, row by row from the lower left.
    pub rest: Vec<[f64; 2]>,
    /// Deformed grid handles, in the same order.
    pub grid: Vec<[f64; 2]>,
}

/// A puppet's mesh file with painted weights, not yet written.
#[derive(Debug)]
pub struct WeightsFile {
    /// The puppet's mesh file.
    pub path: PathBuf,
    /// The mesh as loaded, in its own coordinates.
    mesh: Mesh,
    weights: Vec<f64>,
    layers: Option<Vec<u16>>,
    mode: SaveWeights,
}

impl WeightsFile {
    /// The `.mesh.json` text: the loaded mesh with the painted weights
    /// and depth layers.
    pub fn text(self) -> Result<String, CommandError> {
        let file = self.path.display().to_string();
        let fail = |source| CommandError::Weights {
            file: file.clone(),
            source,
        };
        let mut mesh = self.mesh;
        mesh.set_weights(self.weights).map_err(fail)?;
        let mesh = match self.layers {
            Some(layers) => mesh.with_layers(&file, Some(layers)).map_err(fail)?,
            None => mesh,
        };
        Ok(mesh.to_json())
    }

    /// Writes the file: over the mesh file (`save_weights = "overwrite"`)
    /// atomically, else as the next free `NAME.vN.mesh.json` beside it,
    /// created new so an existing file is never replaced. Returns the path
    /// written.
    pub fn save(self) -> Result<PathBuf, CommandError> {
        use std::io::Write;
        let path = self.path.clone();
        let mode = self.mode;
        let text = self.text()?;
        let failed = |file: &std::path::Path| {
            let file = file.display().to_string();
            move |source| CommandError::Write { file, source }
        };
        if mode == SaveWeights::Overwrite {
            write_atomically(&path, &text).map_err(failed(&path))?;
            return Ok(path);
        }
        for n in 1..=u32::MAX {
            let target = versioned(&path, n);
            let mut file = match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&target)
            {
                Ok(file) => file,
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(failed(&target)(e)),
            };
            let written = file
                .write_all(text.as_bytes())
                .and_then(|()| file.sync_all());
            if let Err(e) = written {
                let _ = std::fs::remove_file(&target);
                return Err(failed(&target)(e));
            }
            return Ok(target);
        }
        Err(failed(&path)(std::io::Error::other(
            "no free version number",
        )))
    }
}

/// Version `n` of a mesh file: `NAME.mesh.json` (or `NAME.vK.mesh.json`)
/// becomes `NAME.vN.mesh.json`; another name gets `.vN` before its
/// extension.
pub fn versioned(path: &std::path::Path, n: u32) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (stem, extension) = match name.strip_suffix(".mesh.json") {
        Some(stem) => (stem, ".mesh.json"),
        None => match name.rfind('.') {
            Some(i) if i > 0 => name.split_at(i),
            _ => (name.as_str(), ""),
        },
    };
    let stem = match stem.rfind(".v") {
        Some(i) if stem.len() > i + 2 && stem[i + 2..].bytes().all(|b| b.is_ascii_digit()) => {
            &stem[..i]
        }
        _ => stem,
    };
    path.with_file_name(format!("{stem}.v{n}{extension}"))
}

/// Writes `text` to `path` atomically: a temporary file beside it, synced,
/// then renamed over it, so readers see the old file or the new, never half.
fn write_atomically(path: &std::path::Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::other("not a file path"))?
        .to_string_lossy();
    let temporary = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| {
        let mut file = std::fs::File::create(&temporary)?;
        file.write_all(text.as_bytes())?;
        file.sync_all()?;
        std::fs::rename(&temporary, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

/// All puppets and the contacts holding them.
pub struct Stage {
    pub width: f64,
    pub height: f64,
    puppets: Vec<Puppet>,
    /// (source, contact id) → (puppet, handle id) for contacts that grabbed
    /// something; contacts on empty stage are absent.
    grabs: HashMap<(SourceId, u32), (usize, u64)>,
    /// Keyframing pads of input sources, and the contacts moving them.
    pads: Vec<pad::Pad>,
    pad_contacts: HashMap<(SourceId, u32), usize>,
    next_handle: u64,
    /// Handle events since the last [`Stage::take_events`], kept only while
    /// a take records them.
    events: Option<Vec<StageEvent>>,
    /// Sources that may grab only these puppets (by id): a performer
    /// limited to named puppets. A grab landing on another grabs nothing.
    limits: HashMap<String, Vec<u32>>,
    /// The puppets on stage (indices), bottom to top: drawn in this order,
    /// hit tested in reverse. Removed puppets are not in it.
    order: Vec<usize>,
}

impl Stage {
    /// Loads every puppet of the stage file, places it, rigs it and sets
    /// its pins.
    pub fn from_config(config: &StageConfig) -> Result<Stage, StageError> {
        let mut stage = Stage {
            width: config.stage.width,
            height: config.stage.height,
            puppets: Vec::new(),
            grabs: HashMap::new(),
            pads: Vec::new(),
            pad_contacts: HashMap::new(),
            limits: HashMap::new(),
            next_handle: 1,
            events: None,
            order: Vec::new(),
        };
        for p in &config.puppets {
            let puppet = Puppet::load(config, stage.puppets.len(), p)?;
            stage.insert(puppet, p)?;
        }
        for pad in &config.pads {
            if let Some(puppet) = stage.puppets.iter().position(|p| p.name == pad.puppet) {
                stage.pads.push(pad::Pad::from_config(pad, puppet));
            }
        }
        Ok(stage)
    }

    /// Puts a loaded puppet on top of the others, with its stage-file pins
    /// (`p`'s), and returns its id: the next one, never a removed puppet's.
    fn insert(&mut self, mut puppet: Puppet, p: &PuppetConfig) -> Result<u32, StageError> {
        let id = self.puppets.len();
        puppet.id = id as u32;
        self.puppets.push(puppet);
        self.order.push(id);
        for (index, pin) in p.pins.iter().enumerate() {
            let puppet = &self.puppets[id];
            let at = stage_point(&puppet.source_mesh, p.at.into(), p.scale, DVec2::from(*pin));
            let anchor = puppet.hit(at);
            let pinned = anchor.and_then(|anchor| {
                self.add_handle(
                    id,
                    Owner::Config,
                    HandleKind::Pin,
                    Grip::Point(anchor),
                    at,
                    DVec2::ZERO,
                    None,
                )
            });
            if pinned.is_none() {
                self.puppets.pop();
                self.order.pop();
                return Err(StageError::PinOutside {
                    puppet: p.name.clone(),
                    index,
                    x: pin[0],
                    y: pin[1],
                });
            }
        }
        let puppet = &mut self.puppets[id];
        puppet.loaded = Snapshot {
            weights: Some(puppet.weights.clone()),
            pins: Some(puppet.pin_records()),
            pose: puppet.pose_record(),
            layers: puppet.static_layers(),
        };
        Ok(id as u32)
    }

    /// Adds a puppet to the running stage on top of the others (a picture
    /// a director brought in), loaded with [`Puppet::load`] off the stage
    /// thread; returns its id.
    pub fn add_puppet(&mut self, puppet: Puppet, p: &PuppetConfig) -> Result<u32, StageError> {
        self.insert(puppet, p)
    }

    /// Takes a puppet off the stage: every handle on it is let go (contacts
    /// holding it grab nothing until lifted), and it is no longer drawn,
    /// hit or solved. Its id is not reused.
    pub fn remove_puppet(&mut self, puppet: u32) -> Result<(), CommandError> {
        self.puppet(puppet)?;
        let index = puppet as usize;
        self.grabs.retain(|_, (p, _)| *p != index);
        let pads: Vec<usize> = (0..self.pads.len())
            .filter(|&i| self.pads[i].puppet == index)
            .collect();
        self.pad_contacts.retain(|_, pad| !pads.contains(pad));
        let ids: Vec<u64> = self.puppets[index].handles.iter().map(|h| h.id).collect();
        for id in ids {
            self.remove_handle(index, id);
        }
        let p = &mut self.puppets[index];
        p.removed = true;
        p.handles_changed = false;
        p.moved = false;
        // Never solved, drawn or hit again: what only a live puppet needs
        // goes now, so a show that adds and removes puppets for hours does
        // not grow. The rest mesh and rig stay, small beside these: a take
        // names every puppet by id with their hashes.
        p.depth = None;
        p.layers = None;
        p.history = History::default();
        self.order.retain(|&i| i != index);
        Ok(())
    }

    /// "This part in front": on the topmost puppet that overlaps itself at
    /// `at`, the part behind there comes in front (until the overlap is
    /// undone; see `docs/depth.md`). Returns whether something flipped.
    pub fn depth_flip(&mut self, at: DVec2) -> bool {
        for place in (0..self.order.len()).rev() {
            let p = &mut self.puppets[self.order[place]];
            let Some(depth) = &p.depth else { continue };
            let pose = p.rig.pose();
            let mut under: Option<(u16, u32)> = None;
            let mut any = false;
            for (t, tri) in p.mesh.triangles().iter().enumerate() {
                let [a, b, c] = tri.map(|i| pose[i as usize]);
                let bary = barycentric_in(a, b, c, at);
                if bary.iter().all(|&w| w >= 0.0) {
                    any = true;
                    let d = depth.depth()[t];
                    if under.is_none_or(|(u, _)| d < u) {
                        under = Some((d, t as u32));
                    }
                }
            }
            if !any {
                continue;
            }
            let Some((_, triangle)) = under else {
                return false;
            };
            let flipped = p
                .depth
                .as_mut()
                .is_some_and(|d| d.pin_front(triangle).is_ok());
            // The next solve reorders with the pin.
            p.moved |= flipped;
            return flipped;
        }
        false
    }

    /// Sets the draw order: every puppet on stage once, bottom to top.
    pub fn set_order(&mut self, order: &[u32]) -> Result<(), CommandError> {
        let mut seen = vec![false; self.puppets.len()];
        for &id in order {
            let p = self.puppet(id).map_err(|e| CommandError::BadOrder {
                problem: e.to_string(),
            })?;
            let seen = &mut seen[p.id as usize];
            if std::mem::replace(seen, true) {
                return Err(CommandError::BadOrder {
                    problem: format!("puppet {id} is listed twice"),
                });
            }
        }
        if order.len() != self.order.len() {
            return Err(CommandError::BadOrder {
                problem: format!(
                    "lists {} puppets; the stage has {} (every puppet on stage, once)",
                    order.len(),
                    self.order.len()
                ),
            });
        }
        self.order = order.iter().map(|&id| id as usize).collect();
        Ok(())
    }

    /// The puppets on stage, bottom to top.
    pub fn on_stage(&self) -> impl Iterator<Item = &Puppet> {
        self.order.iter().map(|&i| &self.puppets[i])
    }

    pub fn puppets(&self) -> &[Puppet] {
        &self.puppets
    }

    /// The stage file's keyframing pads (a removed puppet's too).
    pub fn pads(&self) -> &[pad::Pad] {
        &self.pads
    }

    /// How far from a grid handle or joint a contact may land to grab it.
    pub fn grab_radius(&self) -> f64 {
        self.width.min(self.height) * GRAB_RADIUS_FRACTION
    }

    /// Applies one input frame: contacts land, move and lift.
    pub fn apply(&mut self, frame: &ContactFrame) {
        let source = frame.source.as_str();
        for contact in &frame.contacts {
            // A shared name: no allocation per contact.
            let key = (frame.source.clone(), contact.id);
            // Most stages have no pads: no lookup per contact then.
            if let Some(&pad) = (!self.pad_contacts.is_empty())
                .then(|| self.pad_contacts.get(&key))
                .flatten()
            {
                self.move_cursor(pad, contact.position);
                if contact.phase != Phase::Move {
                    self.pad_contacts.remove(&key);
                }
                if contact.phase != Phase::Down {
                    continue;
                }
            }
            match contact.phase {
                Phase::Down => {
                    // A repeated down without an up: the old grab ends first.
                    self.release(&key);
                    if let Some(pad) = self.pads.iter().position(|p| {
                        !self.puppets[p.puppet].removed && p.takes(source, contact.position)
                    }) {
                        self.pad_contacts.insert(key, pad);
                        self.move_cursor(pad, contact.position);
                        continue;
                    }
                    if let Some(grab) = self.grab(
                        Owner::Source(source.to_string()),
                        HandleKind::Contact,
                        contact.position,
                        Some(contact.id),
                    ) {
                        self.grabs.insert(key, grab);
                    }
                }
                Phase::Move => {
                    if let Some(&(puppet, handle)) = self.grabs.get(&key) {
                        let puppet = &mut self.puppets[puppet];
                        if let Some(h) = puppet
                            .handles
                            .iter_mut()
                            .find(|h| h.id == handle && h.target != contact.position)
                        {
                            h.target = contact.position;
                            puppet.moved = true;
                            if let Some(events) = &mut self.events {
                                events.push(StageEvent::Moved {
                                    puppet: puppet.id,
                                    handle,
                                    at: contact.position,
                                });
                            }
                        }
                    }
                }
                Phase::Up => self.release(&key),
            }
        }
    }

    fn move_cursor(&mut self, pad: usize, at: DVec2) {
        let pad = &self.pads[pad];
        let cursor = pad.cursor(at);
        let k = &mut self.puppets[pad.puppet].keying;
        if k.cursor != Some(cursor) {
            k.cursor = Some(cursor);
            k.touch();
        }
    }

    /// Limits what a source's contacts and pins may grab to these puppets
    /// (by id), or lifts the limit (`None`).
    pub fn limit_source(&mut self, source: &str, puppets: Option<Vec<u32>>) {
        match puppets {
            Some(puppets) => {
                self.limits.insert(source.to_string(), puppets);
            }
            None => {
                self.limits.remove(source);
            }
        }
    }

    /// Lifts every contact of a source (it disconnected or vanished).
    pub fn release_source(&mut self, source: &str) {
        self.pad_contacts.retain(|k, _| k.0.as_str() != source);
        let keys: Vec<_> = self
            .grabs
            .keys()
            .filter(|k| k.0.as_str() == source)
            .cloned()
            .collect();
        for key in keys {
            self.release(&key);
        }
    }

    fn release(&mut self, key: &(SourceId, u32)) {
        if let Some((puppet, handle)) = self.grabs.remove(key) {
            self.remove_handle(puppet, handle);
        }
    }

    fn remove_handle(&mut self, puppet: usize, handle: u64) -> bool {
        let p = &mut self.puppets[puppet];
        let before = p.handles.len();
        p.handles.retain(|h| h.id != handle);
        let removed = p.handles.len() != before;
        p.handles_changed |= removed;
        if removed {
            p.handles_generation = p.handles_generation.wrapping_add(1);
        }
        if removed && let Some(events) = &mut self.events {
            events.push(StageEvent::Removed {
                puppet: p.id,
                handle,
            });
        }
        removed
    }

    /// A new handle at `at` on the topmost puppet there: a grid handle or
    /// joint within the grab radius, else the material point.
    fn grab(
        &mut self,
        owner: Owner,
        kind: HandleKind,
        at: DVec2,
        contact: Option<u32>,
    ) -> Option<(usize, u64)> {
        let radius = self.grab_radius();
        // On a puppet first, top to bottom; only when the contact is on
        // none, a hair outside one: the edge of the puppet on top must not
        // take a finger that is on the one below.
        let outline = self.width.min(self.height) * OUTLINE_REACH_FRACTION;
        let places = self.order.len();
        let passes = (0..places).rev().map(|place| (place, 0.0));
        for (place, outline) in passes.chain((0..places).rev().map(|place| (place, outline))) {
            let puppet = self.order[place];
            match self.puppets[puppet].reach(at, radius, outline) {
                Reach::Grip(grip, offset) => {
                    if let Owner::Source(source) = &owner
                        && let Some(puppets) = self.limits.get(source)
                        && !puppets.contains(&self.puppets[puppet].id)
                    {
                        return None;
                    }
                    let id = self.add_handle(puppet, owner, kind, grip, at, offset, contact)?;
                    return Some((puppet, id));
                }
                Reach::Blocked => return None,
                Reach::Miss => {}
            }
        }
        None
    }

    #[allow(clippy::too_many_arguments)]
    fn add_handle(
        &mut self,
        puppet: usize,
        owner: Owner,
        kind: HandleKind,
        grip: Grip,
        at: DVec2,
        offset: DVec2,
        contact: Option<u32>,
    ) -> Option<u64> {
        let id = self.next_handle;
        self.next_handle += 1;
        self.insert_handle(puppet, id, owner, kind, grip, at, offset, contact)
    }

    /// Adds a handle with a given id (a new one, or a pin put back).
    #[allow(clippy::too_many_arguments)]
    fn insert_handle(
        &mut self,
        puppet: usize,
        id: u64,
        owner: Owner,
        kind: HandleKind,
        grip: Grip,
        at: DVec2,
        offset: DVec2,
        contact: Option<u32>,
    ) -> Option<u64> {
        let p = &mut self.puppets[puppet];
        if let Some(events) = &mut self.events {
            events.push(StageEvent::Made {
                puppet: p.id,
                handle: id,
                owner: owner.to_string(),
                contact,
                kind: match kind {
                    HandleKind::Contact => "contact",
                    HandleKind::Pin => "pin",
                    HandleKind::Key => "key",
                }
                .to_string(),
                grip: p.grip_event(grip),
                at,
            });
        }
        p.handles.push(Handle {
            id,
            owner,
            kind,
            grip,
            target: at,
            offset,
        });
        p.handles_changed = true;
        p.handles_generation = p.handles_generation.wrapping_add(1);
        Some(id)
    }

    /// Starts (or stops) keeping handle events for [`Stage::take_events`].
    pub fn keep_events(&mut self, keep: bool) {
        self.events = keep.then(Vec::new);
    }

    /// Moves the handle events kept since the last call to the end of `out`.
    pub fn take_events(&mut self, out: &mut Vec<StageEvent>) {
        if let Some(events) = &mut self.events {
            out.append(events);
        }
    }

    /// Applies one recorded or live change. A [`Change::Rebuilt`] needs the
    /// rebuilt solver, which only the caller has: use [`Stage::install`].
    /// A paint dab on a free-form puppet may return the solver rebuild to
    /// run (as [`Stage::paint`]).
    pub fn apply_change(&mut self, change: &Change) -> Result<Option<Rebuild>, CommandError> {
        match change {
            Change::Contacts { frame } => self.apply(frame),
            Change::Release { source } => self.release_source(source),
            Change::Pin { owner, at } => {
                if let Some((puppet, id)) = self.pin(Owner::Source(owner.clone()), *at) {
                    let p = &mut self.puppets[puppet as usize];
                    let mut pins = p.pin_records();
                    pins.retain(|pin| pin.handle != id);
                    p.history.edit(
                        || Snapshot {
                            pins: Some(pins),
                            ..Snapshot::default()
                        },
                        None,
                    );
                }
            }
            Change::Unpin { puppet, handle } => {
                let before = self.puppet(*puppet).ok().map(|p| p.pin_records());
                if self.unpin(*puppet, *handle)
                    && let Some(pins) = before
                {
                    self.puppets[*puppet as usize].history.edit(
                        || Snapshot {
                            pins: Some(pins),
                            ..Snapshot::default()
                        },
                        None,
                    );
                }
            }
            Change::Paint {
                puppet,
                at,
                radius,
                strength,
                stroke,
            } => return self.paint_stroke(*puppet, *at, *radius, *strength, *stroke),
            Change::PaintDepth {
                puppet,
                at,
                radius,
                layer,
                stroke,
            } => self.paint_depth_stroke(*puppet, *at, *radius, *layer, *stroke)?,
            Change::Restore { puppet, state } => return self.restore(*puppet, state),
            Change::Rest { puppet } => {
                let p = self.puppet_mut(*puppet)?;
                p.rig.rest_pose();
                p.handles_changed = true;
                p.moved = true;
            }
            Change::KeyPose {
                puppet,
                from,
                to,
                t,
            } => {
                let p = self.puppet(*puppet)?;
                let before = p.pose_record();
                self.set_key_pose(*puppet, from, to, *t)?;
                let p = &mut self.puppets[*puppet as usize];
                p.history.edit(
                    || Snapshot {
                        pose: before,
                        ..Snapshot::default()
                    },
                    Some(Group::Pose(from.clone(), to.clone())),
                );
            }
            Change::Rebuilt { puppet, .. } => {
                return Err(CommandError::NeedsSolver { puppet: *puppet });
            }
            Change::Cursor { puppet, at } => self.set_cursor(*puppet, *at)?,
            Change::KeyAdd { puppet, name, at } => {
                self.add_key(*puppet, name.clone(), *at)?;
            }
            Change::KeyMove { puppet, key, at } => {
                let p = self.puppet_mut(*puppet)?;
                let set = p.keying.set.as_mut().ok_or(CommandError::Keys {
                    puppet: *puppet,
                    source: keys::KeysError::NoSuchKey {
                        index: *key,
                        count: 0,
                    },
                })?;
                set.move_key(*key, at.to_array())
                    .map_err(|source| CommandError::Keys {
                        puppet: *puppet,
                        source,
                    })?;
                p.keying.touch();
            }
            Change::DepthFlip { at } => {
                self.depth_flip(*at);
            }
            Change::KeyDelete { puppet, key } => {
                let p = self.puppet_mut(*puppet)?;
                let set = p.keying.set.as_mut().ok_or(CommandError::Keys {
                    puppet: *puppet,
                    source: keys::KeysError::NoSuchKey {
                        index: *key,
                        count: 0,
                    },
                })?;
                set.remove(*key).map_err(|source| CommandError::Keys {
                    puppet: *puppet,
                    source,
                })?;
                p.keying.touch();
            }
        }
        Ok(None)
    }

    /// Pins what a contact landing at `at` would grab (a material point, a
    /// grid handle or a joint); returns (puppet, handle id).
    pub fn pin(&mut self, owner: Owner, at: DVec2) -> Option<(u32, u64)> {
        self.grab(owner, HandleKind::Pin, at, None)
            .map(|(puppet, id)| (puppet as u32, id))
    }

    /// Removes a pin; contacts cannot be unpinned.
    pub fn unpin(&mut self, puppet: u32, handle: u64) -> bool {
        let Some(p) = self.puppets.get(puppet as usize) else {
            return false;
        };
        if !p
            .handles
            .iter()
            .any(|h| h.id == handle && h.kind == HandleKind::Pin)
        {
            return false;
        }
        self.remove_handle(puppet as usize, handle)
    }

    /// A puppet on stage (a removed one is no such puppet).
    fn puppet(&self, puppet: u32) -> Result<&Puppet, CommandError> {
        let count = self.order.len();
        self.puppets
            .get(puppet as usize)
            .filter(|p| !p.removed)
            .ok_or(CommandError::NoSuchPuppet { puppet, count })
    }

    fn puppet_mut(&mut self, puppet: u32) -> Result<&mut Puppet, CommandError> {
        let count = self.order.len();
        self.puppets
            .get_mut(puppet as usize)
            .filter(|p| !p.removed)
            .ok_or(CommandError::NoSuchPuppet { puppet, count })
    }

    /// Paints stiffness under a brush (see `docs/rigs.md`). Grid and
    /// skeleton puppets refactor at the next solve; a free-form puppet returns the
    /// rebuild to run off the stage thread (none while one is under way:
    /// the newest weights go in the next when it finishes).
    pub fn paint(
        &mut self,
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
    ) -> Result<Option<Rebuild>, CommandError> {
        self.paint_stroke(puppet, at, radius, strength, None)
    }

    /// The brush's bounds: `radius` in (0, the stage's larger side],
    /// `strength` in [[`MIN_STRENGTH`], [`MAX_STRENGTH`]].
    pub fn check_brush(&self, at: DVec2, radius: f64, strength: f64) -> Result<(), CommandError> {
        if !at.is_finite() {
            return Err(CommandError::BadBrush);
        }
        let largest = self.width.max(self.height);
        if !(radius > 0.0 && radius <= largest) {
            return Err(CommandError::OutOfRange {
                field: "radius",
                problem: format!("must be more than 0 and at most {largest}, got {radius}"),
            });
        }
        if !(MIN_STRENGTH..=MAX_STRENGTH).contains(&strength) {
            return Err(CommandError::OutOfRange {
                field: "strength",
                problem: format!("must be {MIN_STRENGTH} to {MAX_STRENGTH}, got {strength}"),
            });
        }
        Ok(())
    }

    /// One dab of a stroke: as [`Stage::paint`]; the dabs of one `stroke`
    /// are one undo step.
    pub fn paint_stroke(
        &mut self,
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
        stroke: Option<u64>,
    ) -> Result<Option<Rebuild>, CommandError> {
        self.check_brush(at, radius, strength)?;
        let p = self.puppet_mut(puppet)?;
        let group = stroke.map(Group::Stroke);
        let joins = group.is_some() && p.history.open == group;
        let before = (!joins).then(|| p.weights.clone());
        if !p.paint(at, radius, strength) {
            return Ok(None);
        }
        p.history.edit(
            || Snapshot {
                weights: before,
                ..Snapshot::default()
            },
            group,
        );
        p.weights_generation += 1;
        if let Rig::Free(_) = p.rig {
            return Ok(self.rebuild(puppet));
        }
        // Refactored once before the next solve, however many dabs arrive
        // before it.
        p.weights_pending = true;
        p.moved = true;
        Ok(None)
    }

    /// One dab of the depth-layer brush: the triangles whose deformed
    /// centroid lies within `radius` of `at` take `layer` (at most
    /// [`puppetry_mesh::MAX_LAYER`]) as their static depth, larger nearer;
    /// the depth adjustment starts afresh from the new order. Dabs of one
    /// `stroke` undo together.
    pub fn paint_depth_stroke(
        &mut self,
        puppet: u32,
        at: DVec2,
        radius: f64,
        layer: u16,
        stroke: Option<u64>,
    ) -> Result<(), CommandError> {
        self.check_brush(at, radius, 1.0)?;
        if layer > puppetry_mesh::MAX_LAYER {
            return Err(CommandError::OutOfRange {
                field: "layer",
                problem: format!("must be 0 to {}", puppetry_mesh::MAX_LAYER),
            });
        }
        let p = self.puppet_mut(puppet)?;
        let Some(mut layers) = p.static_layers() else {
            return Err(CommandError::NoDepth { puppet });
        };
        let before = layers.clone();
        let pose = p.rig.pose();
        let mut changed = false;
        for (tri, l) in p.mesh.triangles().iter().zip(&mut layers) {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            if ((a + b + c) / 3.0).distance(at) < radius && *l != layer {
                *l = layer;
                changed = true;
            }
        }
        if !changed {
            return Ok(());
        }
        p.history.edit(
            || Snapshot {
                layers: Some(before),
                ..Snapshot::default()
            },
            stroke.map(Group::Stroke),
        );
        p.set_layers(layers)
            .map_err(|problem| CommandError::Restore { puppet, problem })
    }

    /// The rebuild a free-form puppet needs, if its weights are newer than
    /// its solver and no rebuild is under way; marks it under way.
    pub fn rebuild(&mut self, puppet: u32) -> Option<Rebuild> {
        let p = self.puppets.get_mut(puppet as usize)?;
        let Rig::Free(r) = &mut p.rig else {
            return None;
        };
        if r.rebuilding || r.built_generation == p.weights_generation {
            return None;
        }
        let mesh = Mesh::new(
            "painted mesh",
            p.mesh.vertices().to_vec(),
            p.mesh.triangles().to_vec(),
            p.mesh.uv().map(|uv| uv.to_vec()),
            Some(p.weights.clone()),
        )
        .ok()?;
        r.rebuilding = true;
        Some(Rebuild {
            puppet,
            generation: p.weights_generation,
            mesh,
        })
    }

    /// Swaps in a rebuilt solver (the next solve compiles it with the
    /// current handles); returns a further rebuild if the weights moved on
    /// meanwhile.
    pub fn install(&mut self, puppet: u32, generation: u64, arap: Arap) -> Option<Rebuild> {
        let p = self.puppets.get_mut(puppet as usize)?;
        let Rig::Free(r) = &mut p.rig else {
            return None;
        };
        r.arap = arap;
        r.built_generation = generation;
        r.rebuilding = false;
        p.handles_changed = true;
        p.moved = true;
        self.rebuild(puppet)
    }

    /// A rebuild failed: allow the next one.
    pub fn rebuild_failed(&mut self, puppet: u32) {
        if let Some(Puppet {
            rig: Rig::Free(r), ..
        }) = self.puppets.get_mut(puppet as usize)
        {
            r.rebuilding = false;
        }
    }

    /// Sets a skeleton puppet to the pose `t` of the way from key pose
    /// `from` to key pose `to`.
    pub fn set_key_pose(
        &mut self,
        puppet: u32,
        from: &str,
        to: &str,
        t: f64,
    ) -> Result<(), CommandError> {
        let p = self.puppet_mut(puppet)?;
        let Rig::Skeleton(r) = &mut p.rig else {
            return Err(CommandError::NoSkeleton { puppet });
        };
        r.set_key_pose(from, to, t)
            .map_err(|source| CommandError::Rig { puppet, source })?;
        p.moved = true;
        p.key_pose = Some(KeyPoseState {
            from: from.to_string(),
            to: to.to_string(),
            t,
        });
        p.pose_generation += 1;
        Ok(())
    }

    /// Takes back the puppet's last edit (a paint stroke, a pin, a pose):
    /// the change that puts back what it replaced, to apply and record like
    /// any other (none when there is nothing to undo).
    pub fn undo(&mut self, puppet: u32) -> Result<Option<Change>, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let Some(state) = p.history.undo.pop() else {
            return Ok(None);
        };
        let now = p.capture(&state);
        p.history.redo.push(now);
        p.history.open = None;
        Ok(Some(Change::Restore { puppet, state }))
    }

    /// Does again the edit the last undo took back.
    pub fn redo(&mut self, puppet: u32) -> Result<Option<Change>, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let Some(state) = p.history.redo.pop() else {
            return Ok(None);
        };
        let now = p.capture(&state);
        p.history.undo.push(now);
        p.history.open = None;
        Ok(Some(Change::Restore { puppet, state }))
    }

    /// Puts the puppet back as loaded: weights from its mesh file, pins as
    /// in the stage file, its rig at rest, the key cursor let go
    /// (contacts keep their grip). One undo step. Returns the changes to
    /// apply and record.
    pub fn reset(&mut self, puppet: u32) -> Result<Vec<Change>, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let loaded = p.loaded.clone();
        let now = p.capture(&loaded);
        if now != loaded {
            p.history.edit(|| now, None);
        }
        p.history.open = None;
        Ok(vec![
            Change::Restore {
                puppet,
                state: loaded,
            },
            Change::Cursor { puppet, at: None },
            Change::Rest { puppet },
        ])
    }

    /// Sets a puppet's weights, pins and pose (those `state` holds) as they
    /// were. Checked first, so a bad record (from a take file) changes
    /// nothing. A free-form puppet whose weights changed returns the solver
    /// rebuild to run (as [`Stage::paint`]).
    fn restore(&mut self, puppet: u32, state: &Snapshot) -> Result<Option<Rebuild>, CommandError> {
        let p = self.puppet(puppet)?;
        let refuse = |problem: String| CommandError::Restore { puppet, problem };
        if let Some(w) = &state.weights {
            if w.len() != p.weights.len() {
                return Err(refuse(format!(
                    "{} weights for {} triangles",
                    w.len(),
                    p.weights.len()
                )));
            }
            if !w.iter().all(|w| (MIN_WEIGHT..=MAX_WEIGHT).contains(w)) {
                return Err(refuse(format!(
                    "weights must be {MIN_WEIGHT} to {MAX_WEIGHT}"
                )));
            }
        }
        let mut pins = Vec::new();
        for pin in state.pins.iter().flatten() {
            let grip = p
                .grip_of(pin.grip)
                .ok_or_else(|| refuse(format!("pin {}: not a grip of this puppet", pin.handle)))?;
            if !(pin.at.is_finite() && pin.offset.is_finite()) {
                return Err(refuse(format!("pin {}: not a finite point", pin.handle)));
            }
            pins.push((pin, grip));
        }
        if state.pose.is_some() && !matches!(p.rig, Rig::Skeleton(_) | Rig::Curve(_)) {
            return Err(refuse(
                "a pose, but the puppet has no skeleton or curve".into(),
            ));
        }
        let index = puppet as usize;
        if let Some(pose) = &state.pose
            && let Rig::Curve(r) = &mut self.puppets[index].rig
        {
            r.set_pose(&pose.joints)
                .map_err(|e| refuse(e.to_string()))?;
            self.puppets[index].moved = true;
        } else if let Some(pose) = &state.pose {
            let p = &mut self.puppets[index];
            let Rig::Skeleton(r) = &mut p.rig else {
                unreachable!("checked above")
            };
            let fk = puppetry_deform::skeleton::Pose {
                roots: pose.roots.clone(),
                angles: pose.angles.clone(),
                lengths: pose.lengths.clone(),
            };
            r.restore_pose(fk, pose.joints.clone())
                .map_err(|e| refuse(e.to_string()))?;
            p.key_pose = pose.key.clone();
            p.pose_generation += 1;
            p.moved = true;
        }
        if state.pins.is_some() {
            let keep: Vec<u64> = pins.iter().map(|(pin, _)| pin.handle).collect();
            let gone: Vec<u64> = self.puppets[index]
                .handles
                .iter()
                .filter(|h| h.kind == HandleKind::Pin && !keep.contains(&h.id))
                .map(|h| h.id)
                .collect();
            for id in gone {
                self.remove_handle(index, id);
            }
            for (pin, grip) in pins {
                if self.puppets[index]
                    .handles
                    .iter()
                    .any(|h| h.id == pin.handle)
                {
                    continue;
                }
                let owner = match pin.owner.as_str() {
                    "config" => Owner::Config,
                    other => Owner::Source(other.to_string()),
                };
                self.insert_handle(
                    index,
                    pin.handle,
                    owner,
                    HandleKind::Pin,
                    grip,
                    pin.at,
                    pin.offset,
                    None,
                );
            }
        }
        if let Some(layers) = &state.layers {
            let p = &mut self.puppets[index];
            if p.depth.is_none() || layers.len() != p.mesh.triangles().len() {
                return Err(refuse(format!(
                    "{} depth layers for {} triangles (or depth is off)",
                    layers.len(),
                    p.mesh.triangles().len()
                )));
            }
            if p.static_layers().as_ref() != Some(layers) {
                p.set_layers(layers.clone()).map_err(refuse)?;
            }
        }
        if let Some(w) = &state.weights {
            let p = &mut self.puppets[index];
            if *w != p.weights {
                p.weights.clone_from(w);
                p.weights_generation += 1;
                if let Rig::Free(_) = p.rig {
                    return Ok(self.rebuild(puppet));
                }
                p.weights_pending = true;
                p.moved = true;
            }
        }
        Ok(None)
    }

    /// The grid of a grid puppet for an export request: its size, rest
    /// and deformed handles (stage coordinates, row by row from the lower
    /// left).
    pub fn export_grid(&self, puppet: u32) -> Result<GridExport, CommandError> {
        let p = self.puppet(puppet)?;
        let Rig::Grid(r) = &p.rig else {
            return Err(CommandError::NoGrid { puppet });
        };
        let points = |v: &[DVec2]| v.iter().map(|q| [q.x, q.y]).collect::<Vec<_>>();
        let spec = r.ffd.spec();
        Ok(GridExport {
            puppet,
            columns: spec.columns,
            rows: spec.rows,
            rest: points(r.ffd.rest_grid()),
            grid: points(r.ffd.grid()),
        })
    }

    /// What saving the puppet's painted weights writes, to be turned into
    /// text off the stage thread ([`WeightsFile::text`]).
    pub fn weights_file(&self, puppet: u32) -> Result<WeightsFile, CommandError> {
        let p = self.puppet(puppet)?;
        if let Rig::Curve(_) = p.rig {
            return Err(CommandError::NoWeights { puppet });
        }
        Ok(WeightsFile {
            path: p.mesh_file.clone(),
            mesh: p.source_mesh.clone(),
            weights: p.weights.clone(),
            layers: p.layers.clone(),
            mode: p.save_weights,
        })
    }

    /// Moves (or lets go, `None`) a puppet's keyframing cursor, in pad
    /// coordinates.
    pub fn set_cursor(&mut self, puppet: u32, at: Option<DVec2>) -> Result<(), CommandError> {
        if let Some(at) = at
            && !at.is_finite()
        {
            return Err(CommandError::BadPadPoint { x: at.x, y: at.y });
        }
        let at = at.map(|a| a.clamp(DVec2::ZERO, DVec2::ONE));
        let k = &mut self.puppet_mut(puppet)?.keying;
        if k.cursor != at {
            k.cursor = at;
            k.touch();
        }
        Ok(())
    }

    /// Adds a key pose of the puppet as it is now at pad point `at`; the
    /// first key of a puppet keys what its contacts hold (or its
    /// skeleton). Returns the key's index.
    pub fn add_key(&mut self, puppet: u32, name: String, at: DVec2) -> Result<usize, CommandError> {
        let p = self.puppet(puppet)?;
        let held: Vec<(Grip, DVec2)> = p
            .handles
            .iter()
            // Pins stay where they are: keys hold what hands hold.
            .filter(|h| h.kind == HandleKind::Contact)
            .filter_map(|h| match h.grip {
                Grip::Point(anchor) => Some((h.grip, anchor_position(&p.mesh, anchor))),
                Grip::GridHandle(i) => Some((h.grip, p.rig.grip_position(Grip::GridHandle(i))?)),
                Grip::Joint(_) | Grip::Bone { .. } => None,
            })
            .collect();
        let now: Vec<Option<DVec2>> = p
            .keying
            .targets
            .iter()
            .chain(&held)
            .map(|&(grip, _)| {
                // Where a hand holds it, what the hand asked for; else where
                // the solve put it.
                let rest = |g: Grip| match g {
                    Grip::Point(a) => Some(anchor_position(&p.mesh, a)),
                    _ => None,
                };
                p.handles
                    .iter()
                    .find(|h| {
                        h.kind != HandleKind::Key
                            && (h.grip == grip
                                || rest(h.grip)
                                    .zip(rest(grip))
                                    .is_some_and(|(a, b)| a.distance(b) < 1e-9))
                    })
                    .map(|h| h.rig_target())
                    .or_else(|| p.grip_now(grip))
            })
            .collect();
        let targets_before = p.keying.targets.clone();
        let placement = p.placement;
        let p = &mut self.puppets[puppet as usize];
        let lookup = |grip: Grip| {
            targets_before
                .iter()
                .chain(&held)
                .position(|&(g, _)| g == grip)
                .and_then(|i| now[i])
        };
        p.keying
            .add_key(name, at, &p.rig, &held, placement, lookup)
            .map_err(|source| CommandError::Keys { puppet, source })
    }

    /// The key file to write for a puppet (`save_keys`): where, and what.
    pub fn key_file(&self, puppet: u32) -> Result<(PathBuf, keys::KeyFile), CommandError> {
        let p = self.puppet(puppet)?;
        let file = p
            .keying
            .file
            .clone()
            .ok_or(CommandError::NoKeyFile { puppet })?;
        Ok((file, p.keying.key_file(&p.name, &p.rig, p.placement)))
    }

    /// Puts each keyed puppet's handles where its cursor's blend of key
    /// poses says, adding or removing key handles as fingers take keyed
    /// grips over or let go.
    fn drive_keys(&mut self) {
        let radius = self.grab_radius();
        for index in 0..self.puppets.len() {
            let p = &self.puppets[index];
            let k = &p.keying;
            if p.removed {
                continue;
            }
            if !(k.dirty || (p.handles_changed && !k.targets.is_empty())) {
                continue;
            }
            let wanted = k.cursor.is_some() && k.set.as_ref().is_some_and(|s| !s.is_empty());
            if k.skeleton {
                let p = &mut self.puppets[index];
                let k = &mut p.keying;
                k.dirty = false;
                if let (true, Some(set), Some(cursor)) = (wanted, k.set.as_mut(), k.cursor) {
                    k.blended.resize(set.width(), 0.0);
                    if set.blend_into(cursor, &mut k.blended)
                        && let Some(pose) = pad::skeleton_pose(&p.rig, &k.blended)
                        && let Rig::Skeleton(r) = &mut p.rig
                        && r.set_pose(pose).is_ok()
                    {
                        p.moved = true;
                    }
                }
                continue;
            }
            // A finger on or near a keyed grip takes it over.
            let taken: Vec<bool> = k
                .targets
                .iter()
                .map(|&(grip, rest)| {
                    p.handles.iter().any(|h| {
                        h.kind != HandleKind::Key
                            && match (h.grip, grip) {
                                (Grip::Point(a), Grip::Point(_)) => {
                                    anchor_position(&p.mesh, a).distance(rest) <= radius
                                }
                                (a, b) => a == b,
                            }
                    })
                })
                .collect();
            let mut plan = Vec::new();
            for (i, &(grip, _)) in k.targets.iter().enumerate() {
                let want = wanted && !taken[i];
                match (k.handles[i], want) {
                    (Some(id), false) => plan.push((i, Some(id), None)),
                    (None, true) => plan.push((i, None, Some(grip))),
                    _ => {}
                }
            }
            for (i, remove, add) in plan {
                if let Some(id) = remove {
                    self.remove_handle(index, id);
                    self.puppets[index].keying.handles[i] = None;
                }
                if let Some(grip) = add {
                    let at = self.puppets[index].grip_now(grip).unwrap_or_default();
                    let offset = DVec2::ZERO;
                    let id = self.add_handle(
                        index,
                        Owner::Source("keys".into()),
                        HandleKind::Key,
                        grip,
                        at,
                        offset,
                        None,
                    );
                    self.puppets[index].keying.handles[i] = id;
                }
            }
            let p = &mut self.puppets[index];
            let k = &mut p.keying;
            k.dirty = false;
            if let (true, Some(set), Some(cursor)) = (wanted, k.set.as_mut(), k.cursor) {
                k.blended.resize(set.width(), 0.0);
                if set.blend_into(cursor, &mut k.blended) {
                    for (i, id) in k.handles.iter().enumerate() {
                        let Some(id) = id else { continue };
                        let target = DVec2::new(k.blended[2 * i], k.blended[2 * i + 1]);
                        if let Some(h) = p.handles.iter_mut().find(|h| h.id == *id)
                            && h.target != target
                        {
                            h.target = target;
                            p.moved = true;
                        }
                    }
                }
            }
        }
    }

    /// Solves every puppet whose handles changed or moved; returns, per
    /// solved puppet, whether its handle set changed.
    pub fn solve(&mut self) -> Vec<(u32, bool)> {
        let mut solved = Vec::new();
        self.solve_into(&mut solved);
        solved
    }

    /// [`Stage::solve`] into a caller's list (cleared first), so a loop
    /// that reuses one does not allocate. When more than one puppet moved,
    /// they are solved side by side on rayon's pool (each puppet's rig and
    /// depth are its own), so several performers on several puppets get
    /// every frame solved on two cores.
    pub fn solve_into(&mut self, solved: &mut Vec<(u32, bool)>) {
        solved.clear();
        self.drive_keys();
        solved.extend(
            self.puppets
                .iter()
                .filter(|p| p.needs_solve())
                .map(|p| (p.id, p.handles_changed)),
        );
        if solved.len() > 1 {
            use rayon::prelude::*;
            self.puppets
                .par_iter_mut()
                .filter(|p| p.needs_solve())
                .for_each(Puppet::solve_frame);
        } else {
            self.puppets
                .iter_mut()
                .filter(|p| p.needs_solve())
                .for_each(Puppet::solve_frame);
        }
    }
}

impl Puppet {
    /// Whether its handles moved or changed since it was last solved.
    fn needs_solve(&self) -> bool {
        self.handles_changed || self.moved
    }

    /// Solves the puppet's rig for its handles and orders its depth.
    fn solve_frame(&mut self) {
        if self.weights_pending {
            self.weights_pending = false;
            if let Err(problem) = self.rig.set_weights(&self.weights) {
                // Painted weights are clamped to the mesh's range, so
                // this is not expected; the rig keeps its old weights.
                tracing::warn!(puppet = %self.name, "painted weights refused: {problem}");
            }
        }
        if let Err(problem) = self.rig.solve(&self.handles, self.handles_changed) {
            // Grips come from hit tests on this rig, so only a
            // non-finite target can fail here; keep the last pose.
            tracing::warn!(puppet = %self.name, "ignored a frame: {problem}");
        }
        if let Some(depth) = &mut self.depth {
            // Poses are finite (the rig refuses others), so an error
            // is not expected; the last depth stays.
            if let Err(problem) = depth.update(self.rig.pose()) {
                tracing::warn!(puppet = %self.name, "depth: {problem}");
            } else if depth.changed() {
                self.depth_generation = self.depth_generation.wrapping_add(1);
            }
        }
        self.handles_changed = false;
        self.moved = false;
    }
}

/// A mesh point in stage coordinates: scaled about the mesh's bounding-box
/// centre, which lands at `at`.
pub(crate) fn stage_point(mesh: &Mesh, at: DVec2, scale: f64, p: DVec2) -> DVec2 {
    let (lo, hi) = bounds(mesh.vertices());
    at + (p - (lo + hi) / 2.0) * scale
}

fn bounds(points: &[DVec2]) -> (DVec2, DVec2) {
    points.iter().fold(
        (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    )
}

/// The mesh moved onto the stage (same triangles, uv and weights).
fn place(mesh: &Mesh, at: DVec2, scale: f64) -> Result<Mesh, MeshError> {
    let vertices = mesh
        .vertices()
        .iter()
        // The box's centre once, not per vertex (that was quadratic).
        .map({
            let (lo, hi) = bounds(mesh.vertices());
            let centre = (lo + hi) / 2.0;
            move |&p| at + (p - centre) * scale
        })
        .collect();
    Mesh::new(
        "placed mesh",
        vertices,
        mesh.triangles().to_vec(),
        mesh.uv().map(|uv| uv.to_vec()),
        Some(mesh.weights().to_vec()),
    )?
    .with_layers("placed mesh", mesh.layers().map(|l| l.to_vec()))
}
