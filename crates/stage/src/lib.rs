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
//! Rooms: this file holds the types (`Stage`, `Puppet`, handles, errors)
//! and the stage's line-up, changes and solving; `puppet` loads a puppet
//! and answers geometry questions about it; `contacts` maps contacts to
//! handles; `painting` the brushes; `keyframing` key poses and cursors;
//! `history` undo, redo and reset; `weights` the weights file and grid
//! export; `rig`, `pad` and `keys` the rigs, pads and key files; `config`
//! the stage's sections of a stage file; `change` the one `Change` every
//! source sends.
//!
//! Plain synchronous state, with no tokio and no wire format in reach (the
//! crate cannot build them: see ARCHITECTURE.md): the daemon's stage
//! thread runs it, with the solvers, on a thread of its own, and turns
//! what it holds into protocol messages. Every public item is documented
//! (`missing_docs` is on here).

pub mod change;
pub mod config;
mod contacts;
mod history;
mod keyframing;
pub mod keys;
pub mod pad;
mod painting;
pub use painting::Stroke;
mod puppet;
pub mod rig;
mod weights;

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
    /// The id names no puppet on stage: past the last, or removed.
    #[error("puppet {puppet}: no such puppet (the stage has {count})")]
    NoSuchPuppet {
        /// The id asked for.
        puppet: u32,
        /// How many puppets are on stage now.
        count: usize,
    },
    /// A grid export asked of a puppet whose rig is not an lp-FFD grid.
    #[error("puppet {puppet}: has no grid")]
    NoGrid {
        /// The puppet asked.
        puppet: u32,
    },
    /// A key-pose blend asked of a puppet that has no skeleton.
    #[error("puppet {puppet}: has no skeleton")]
    NoSkeleton {
        /// The puppet asked.
        puppet: u32,
    },
    /// Saving weights asked of a curve puppet, whose mesh is built from
    /// its curve and has no file to write them to.
    #[error(
        "puppet {puppet}: a curve puppet has no weights to save (its mesh is built from its curve)"
    )]
    NoWeights {
        /// The puppet asked.
        puppet: u32,
    },
    /// A depth-layer dab on a puppet whose stage file says `depth = "off"`.
    #[error("puppet {puppet}: has no depth to paint (depth = \"off\")")]
    NoDepth {
        /// The puppet asked.
        puppet: u32,
    },
    /// A brush dab whose centre is NaN or infinite.
    #[error("paint needs finite x and y")]
    BadBrush,
    /// A number outside its documented range; `field` names it as the
    /// message does (`radius`, `strength`).
    #[error("{field}: {problem}")]
    OutOfRange {
        /// The request's field: `radius`, `strength` or `layer`.
        field: &'static str,
        /// The range it must be in, and the value given.
        problem: String,
    },
    /// Undo, redo, reset or a recorded [`Change::Restore`] brought a state
    /// that does not fit the puppet (wrong counts, a grip it does not
    /// have, a non-finite point); nothing was changed. Also a depth-layer
    /// dab the depth order refused.
    #[error("puppet {puppet}: cannot restore: {problem}")]
    Restore {
        /// The puppet the state was for.
        puppet: u32,
        /// What does not fit.
        problem: String,
    },
    /// Writing a painted-weights file failed.
    #[error("{file}: {source}")]
    Write {
        /// The file being written.
        file: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The puppet's rig refused the request (a key pose name the skeleton
    /// does not have, a pose it cannot take).
    #[error("puppet {puppet}: {source}")]
    Rig {
        /// The puppet asked.
        puppet: u32,
        /// What the rig said.
        source: rig::RigError,
    },
    /// The mesh refused the painted weights or depth layers while the
    /// weights file's text was made ([`WeightsFile::text`]).
    #[error("{file}: {source}")]
    Weights {
        /// The mesh file the weights are for.
        file: String,
        /// What the mesh said.
        source: MeshError,
    },
    /// [`Stage::apply_change`] was given a [`Change::Rebuilt`], which needs
    /// the rebuilt solver: the caller swaps it in with [`Stage::install`].
    #[error("puppet {puppet}: a rebuilt solver is swapped in with install, not applied")]
    NeedsSolver {
        /// The puppet whose solver was rebuilt.
        puppet: u32,
    },
    /// A key-pose edit (add, move, delete) the puppet's key set refused, or
    /// one asked of a puppet that has no keys yet.
    #[error("puppet {puppet}: {source}")]
    Keys {
        /// The puppet asked.
        puppet: u32,
        /// What the key set said.
        source: keys::KeysError,
    },
    /// Saving keys asked of a puppet whose stage-file entry names no key
    /// file (`keys`), so there is nowhere to write them.
    #[error("puppet {puppet}: no key file is named for it in the stage file (`keys`)")]
    NoKeyFile {
        /// The puppet asked.
        puppet: u32,
    },
    /// A keyframing cursor set to a NaN or infinite pad point.
    #[error("pad point [{x}, {y}] is not finite")]
    BadPadPoint {
        /// The point's x, as given.
        x: f64,
        /// The point's y, as given.
        y: f64,
    },
    /// Something else is under way (a take recording) that this would spoil.
    #[error("{problem}")]
    Busy {
        /// What is under way, and what to do about it.
        problem: String,
    },
    /// A puppet could not be put on the stage.
    #[error("{problem}")]
    Load {
        /// Why (the [`StageError`], as text).
        problem: String,
    },
    /// A draw order that is not every puppet on stage once.
    #[error("order: {problem}")]
    BadOrder {
        /// Which puppet is unknown or listed twice, or how many are missing.
        problem: String,
    },
}

/// Why a puppet of a stage file could not be put on the stage (at start-up,
/// or when one is added at runtime). Errors name the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    /// The puppet's mesh file could not be read or is not a valid mesh, or
    /// the mesh refused its placement on the stage.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The puppet's rig, curve or depth as the stage file gives it was
    /// refused, by this crate's checks or by the deformer registering it
    /// (bones that are no skeleton, a centre line that folds back, a mesh a
    /// solver cannot register…).
    #[error("{file}: puppet[{index}] ({puppet}).{field}: {problem}")]
    Rig {
        /// The stage file, as named to [`config::StageConfig::parse`].
        file: String,
        /// The puppet's place among the file's `[[puppet]]` entries.
        index: usize,
        /// The puppet's name.
        puppet: String,
        /// The field at fault, within the puppet (`curve.points`,
        /// `skeleton.joints`, `grid`, `depth`…).
        field: String,
        /// What is wrong with it.
        problem: String,
    },
    /// One of the stage file's `pins` lands on no triangle of the puppet.
    #[error("puppet {puppet}: pin {index} at [{x}, {y}] is not on the puppet")]
    PinOutside {
        /// The puppet's name.
        puppet: String,
        /// The pin's place in the puppet's `pins`.
        index: usize,
        /// The pin's x, as the file gives it (mesh coordinates).
        x: f64,
        /// The pin's y, as the file gives it (mesh coordinates).
        y: f64,
    },
    /// The puppet's key file exists but could not be read or is not a
    /// valid key file.
    #[error(transparent)]
    KeyFile(#[from] keys::KeysError),
    /// The puppet's key file is valid but does not fit the puppet: it
    /// names another puppet, or its grips are not on this one's mesh or rig.
    #[error("{file}: {field}: {problem}")]
    Keys {
        /// The key file, resolved against the stage file's folder.
        file: String,
        /// The key file's field at fault (`puppet`, `grips[1].at`, `keys`).
        field: String,
        /// What is wrong with it.
        problem: String,
    },
    /// The puppet's picture cannot be used. Nothing in this crate returns
    /// it (pictures are checked by [`config::StageConfig::check_files`]);
    /// it is kept for callers that check a picture themselves.
    #[error("puppet {puppet}: image {path}: {problem}")]
    Image {
        /// The puppet's name.
        puppet: String,
        /// The picture's path, as named.
        path: String,
        /// What is wrong with it.
        problem: String,
    },
}

/// The brush's `strength` range: a dab at most multiplies a weight by
/// 1000 or divides it by 1000 (three of the weight range's seven orders of
/// magnitude per dab).
pub const MIN_STRENGTH: f64 = 1e-3;
/// The top of the brush's `strength` range (see [`MIN_STRENGTH`]): a dab
/// at most multiplies a weight by 1000.
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

/// The owner name of the stage file's pins ([`Owner::Config`]).
pub const CONFIG_OWNER: &str = "config";

/// The owner name of the handles a keyframing cursor's blend of key poses
/// holds.
pub const KEYS_OWNER: &str = "keys";

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
            Owner::Config => f.write_str(CONFIG_OWNER),
        }
    }
}

/// What a handle is, which decides how long it lasts and who may end it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HandleKind {
    /// Held by a contact: made when it lands, moved as it moves, gone when
    /// it lifts (or its source goes away).
    Contact,
    /// Stays where it was put until unpinned (by a client, undo or reset);
    /// the stage file's pins are these too.
    Pin,
    /// Held by the keyframing cursor's blend of key poses.
    Key,
}

/// A puppet's picture: a PNG file, or the small texture a plain-coloured
/// stroke (a curve puppet without an image) is drawn with.
#[derive(Debug, Clone, PartialEq)]
pub enum Picture {
    /// A PNG file, resolved against the stage file's folder.
    File(PathBuf),
    /// A curve puppet with no image: its stroke's colour (RGB).
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
    /// Unique on the stage (across puppets); a pin put back by undo or a
    /// take keeps the id it had.
    pub id: u64,
    /// Who made it; contacts of other owners never move it.
    pub owner: Owner,
    /// Contact, pin or key handle.
    pub kind: HandleKind,
    /// What it holds on the puppet.
    pub grip: Grip,
    /// Where the handle is held now (stage coordinates).
    pub target: DVec2,
    /// From where the contact landed to what it grabbed (a grid handle or
    /// joint, or the nearest point of an outline it landed just outside):
    /// that point keeps the offset, so it does not jump to the finger.
    pub offset: DVec2,
}

/// A handle about to be made (`Stage::add_handle`, `insert_handle`): whose,
/// what kind, holding what, where, and the contact it follows, if any.
pub(crate) struct NewHandle {
    owner: Owner,
    kind: HandleKind,
    grip: Grip,
    /// Where it is held (its first `target`).
    at: DVec2,
    /// As [`Handle::offset`].
    offset: DVec2,
    /// The contact it follows; none for pins and key handles.
    contact: Option<u32>,
}

impl Handle {
    /// Where the rig is asked to put what this handle holds.
    pub fn rig_target(&self) -> DVec2 {
        self.target + self.offset
    }
}

/// A puppet on the stage, with its rig.
pub struct Puppet {
    /// Its index in [`Stage::puppets`]: the order it was loaded or added
    /// in. Never reused, even after the puppet is removed.
    pub id: u32,
    /// The stage file's `name`, unique on the stage; pads and key files
    /// name the puppet by it.
    pub name: String,
    /// What it is drawn with.
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

/// What joins edits into one undo step: a stroke of one brush (each
/// brush's dabs keep their own state, so the two never join), a run of
/// poses between the same key poses.
#[derive(Debug, Clone, PartialEq)]
enum Group {
    Stroke(Stroke),
    DepthStroke(Stroke),
    Pose(String, String),
}

/// What a contact landing on a puppet finds.
enum Reach {
    Grip(Grip, DVec2),
    /// On a skeleton puppet but away from its joints: ignored, and it does
    /// not fall through to the puppets below.
    Blocked,
    Miss,
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
    /// The puppet to rebuild.
    pub puppet: u32,
    /// The weights generation `mesh` has: give it back to
    /// [`Stage::install`] with the solver, so a newer paint is not lost.
    pub generation: u64,
    /// The puppet's mesh on the stage, with its painted weights: register
    /// the new solver on it.
    pub mesh: Mesh,
}

/// A grid puppet's grid, as an export request is answered.
#[derive(Debug, Clone, PartialEq)]
pub struct GridExport {
    /// The puppet exported.
    pub puppet: u32,
    /// Grid handles along x (per row).
    pub columns: usize,
    /// Grid handles along y (rows of handles).
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

/// All puppets and the contacts holding them.
pub struct Stage {
    /// The stage's width in stage units (`[stage].width`).
    pub width: f64,
    /// The stage's height in stage units (`[stage].height`); y is up.
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
            let pinned = anchor.map(|anchor| {
                let new = NewHandle {
                    owner: Owner::Config,
                    kind: HandleKind::Pin,
                    grip: Grip::Point(anchor),
                    at,
                    offset: DVec2::ZERO,
                    contact: None,
                };
                self.add_handle(id, new)
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

    /// Every puppet loaded, indexed by id, removed ones included (see
    /// [`Puppet::removed`]); [`Stage::on_stage`] gives only those on stage,
    /// in draw order.
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
                painter,
            } => {
                let stroke = Stroke::of(painter.as_deref(), *stroke);
                return self.paint_stroke(*puppet, *at, *radius, *strength, stroke);
            }
            Change::PaintDepth {
                puppet,
                at,
                radius,
                layer,
                stroke,
                painter,
            } => {
                let stroke = Stroke::of(painter.as_deref(), *stroke);
                self.paint_depth_stroke(*puppet, *at, *radius, *layer, stroke)?;
            }
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
                self.edit_keys(*puppet, *key, |set| set.move_key(*key, at.to_array()))?;
            }
            Change::DepthFlip { at } => {
                self.depth_flip(*at);
            }
            Change::KeyDelete { puppet, key } => {
                self.edit_keys(*puppet, *key, |set| set.remove(*key))?;
            }
        }
        Ok(None)
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

    /// Edits a keyframed puppet's keys (`key` is the one `edit` names, for
    /// the error when the puppet has none), marking them changed.
    fn edit_keys<T>(
        &mut self,
        puppet: u32,
        key: usize,
        edit: impl FnOnce(&mut keys::KeySet) -> Result<T, keys::KeysError>,
    ) -> Result<T, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let set = p.keying.set.as_mut().ok_or(CommandError::Keys {
            puppet,
            source: keys::KeysError::NoSuchKey {
                index: key,
                count: 0,
            },
        })?;
        let done = edit(set).map_err(|source| CommandError::Keys { puppet, source })?;
        p.keying.touch();
        Ok(done)
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
