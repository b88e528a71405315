//! Spatial keyframing on the stage (the 2005 paper's §5.3): each puppet's
//! key-pose set placed on it, the keyframing pad's control cursor, and the
//! pads that input sources drive. A key pose holds where a set of grips
//! were (material points or grid handles, in stage coordinates) or a
//! skeleton's roots and joint angles; moving the cursor blends the keys
//! ([`crate::keys::KeySet`]) and the blend drives the puppet through its
//! own solver, every frame. A finger holding a point near a keyed grip
//! takes that grip over until it lets go.
//!
//! Key files keep everything in the mesh's own coordinates, so moving or
//! scaling a puppet in the stage file keeps its keys.

use std::path::PathBuf;

use glam::DVec2;
use puppetry_deform::Anchor;
use puppetry_deform::skeleton::Pose;

use crate::config::PadConfig;
use crate::keys::{KeyEntry, KeyFile, KeyGrip, KeySet, KeysError};
use crate::rig::{Grip, Rig};

/// Where a puppet's mesh sits on the stage: `stage = at + (mesh − centre) · scale`.
#[derive(Debug, Clone, Copy)]
pub struct Placement {
    /// The stage point the mesh's bounding-box centre lands on (the stage
    /// file's `at`).
    pub at: DVec2,
    /// Stage units per mesh unit (the stage file's `scale`).
    pub scale: f64,
    /// The mesh's bounding-box centre, in its own coordinates.
    pub centre: DVec2,
}

impl Placement {
    /// A point in the mesh's own coordinates, on the stage.
    pub fn to_stage(&self, p: DVec2) -> DVec2 {
        self.at + (p - self.centre) * self.scale
    }

    /// A stage point, in the mesh's own coordinates (the inverse of
    /// [`Placement::to_stage`]).
    pub fn to_mesh(&self, q: DVec2) -> DVec2 {
        self.centre + (q - self.at) / self.scale
    }
}

/// A puppet's spatial keyframing state.
#[derive(Debug, Clone)]
pub struct Keying {
    /// The key file named in the stage file: where saving writes.
    pub file: Option<PathBuf>,
    /// What each key's values drive, as files name them.
    pub(crate) grips: Vec<KeyGrip>,
    /// Per point or grid grip: the stage grip and its rest position.
    pub(crate) targets: Vec<(Grip, DVec2)>,
    /// Keys blend a skeleton's pose (roots, then joint angles).
    pub(crate) skeleton: bool,
    /// Keys, with values in stage coordinates; `None` until the grips are
    /// known (the first key sets them).
    pub(crate) set: Option<KeySet>,
    pub(crate) cursor: Option<DVec2>,
    pub(crate) blended: Vec<f64>,
    /// Per target, the key handle holding it now.
    pub(crate) handles: Vec<Option<u64>>,
    /// The cursor or the keys changed since the last drive.
    pub(crate) dirty: bool,
    /// Bumped by every change clients should see (keys or cursor).
    pub generation: u64,
}

impl Keying {
    /// No keys and no cursor yet; `file` is where saving will write (none
    /// when the stage file names no key file for the puppet).
    pub(crate) fn empty(file: Option<PathBuf>) -> Keying {
        Keying {
            file,
            grips: Vec::new(),
            targets: Vec::new(),
            skeleton: false,
            set: None,
            cursor: None,
            blended: Vec::new(),
            handles: Vec::new(),
            dirty: false,
            generation: 0,
        }
    }

    /// The keys (names and pad points), in index order.
    pub fn keys(&self) -> &[KeyEntry] {
        self.set.as_ref().map_or(&[], |s| s.keys())
    }

    /// The control cursor, in pad coordinates (`[0, 1]²`); `None` when no
    /// one holds it, and then the keys drive nothing.
    pub fn cursor(&self) -> Option<DVec2> {
        self.cursor
    }

    pub(crate) fn touch(&mut self) {
        self.dirty = true;
        self.generation += 1;
    }

    /// Loads a key file for a puppet: its grips found on the rest mesh
    /// (`hit` finds the anchor under a stage point) and its values moved
    /// to stage coordinates. Errors are `(field, problem)`.
    pub fn load(
        file: PathBuf,
        key_file: KeyFile,
        puppet: &str,
        rig: &Rig,
        placement: Placement,
        hit: impl Fn(DVec2) -> Option<Anchor>,
    ) -> Result<Keying, (String, String)> {
        if key_file.puppet != puppet {
            return Err((
                "puppet".into(),
                format!("names {:?}, this is puppet {puppet:?}", key_file.puppet),
            ));
        }
        let mut keying = Keying::empty(Some(file));
        keying.set_grips(&key_file.grips, rig, placement, hit)?;
        let width = keying.width(rig);
        let entries = key_file
            .keys
            .into_iter()
            .map(|mut e| {
                keying.values_to_stage(&mut e.values, rig, placement);
                e
            })
            .collect();
        keying.set =
            Some(KeySet::new(entries, width).map_err(|e| ("keys".to_string(), e.to_string()))?);
        Ok(keying)
    }

    /// Values per key for these grips on this rig.
    fn width(&self, rig: &Rig) -> usize {
        if self.skeleton {
            skeleton_width(rig)
        } else {
            self.targets.len() * 2
        }
    }

    fn set_grips(
        &mut self,
        grips: &[KeyGrip],
        rig: &Rig,
        placement: Placement,
        hit: impl Fn(DVec2) -> Option<Anchor>,
    ) -> Result<(), (String, String)> {
        self.targets.clear();
        self.skeleton = false;
        let grid_size = match rig {
            Rig::Grid(_) => rig.points().map_or(0, |p| p.len()),
            _ => 0,
        };
        for (i, grip) in grips.iter().enumerate() {
            match grip {
                KeyGrip::Point { at } => {
                    if matches!(rig, Rig::Skeleton(_)) {
                        return Err((
                            format!("grips[{i}]"),
                            "a skeleton puppet is keyed by a skeleton grip".into(),
                        ));
                    }
                    let rest = placement.to_stage(DVec2::from(*at));
                    let anchor = hit(rest).ok_or_else(|| {
                        (format!("grips[{i}].at"), "not on the puppet".to_string())
                    })?;
                    self.targets.push((Grip::Point(anchor), rest));
                }
                KeyGrip::GridHandle { index } => {
                    if *index >= grid_size {
                        return Err((
                            format!("grips[{i}].index"),
                            format!("the puppet's grid has {grid_size} handles"),
                        ));
                    }
                    let rest = rig
                        .grip_position(Grip::GridHandle(*index))
                        .unwrap_or_default();
                    self.targets.push((Grip::GridHandle(*index), rest));
                }
                KeyGrip::Skeleton => {
                    if !matches!(rig, Rig::Skeleton(_)) || grips.len() != 1 {
                        return Err((
                            format!("grips[{i}]"),
                            "a skeleton grip is the only grip of a skeleton puppet".into(),
                        ));
                    }
                    self.skeleton = true;
                }
            }
        }
        self.grips = grips.to_vec();
        self.handles = vec![None; self.targets.len()];
        Ok(())
    }

    /// Mesh-coordinate values (as in files) to stage coordinates, in place.
    fn values_to_stage(&self, values: &mut [f64], rig: &Rig, placement: Placement) {
        self.map_points(values, rig, |p| placement.to_stage(p));
    }

    /// Stage-coordinate values to mesh coordinates (for saving), in place.
    fn values_to_mesh(&self, values: &mut [f64], rig: &Rig, placement: Placement) {
        self.map_points(values, rig, |p| placement.to_mesh(p));
    }

    fn map_points(&self, values: &mut [f64], rig: &Rig, f: impl Fn(DVec2) -> DVec2) {
        let points = if self.skeleton {
            skeleton_roots(rig)
        } else {
            self.targets.len()
        };
        for pair in values.chunks_exact_mut(2).take(points) {
            let q = f(DVec2::new(pair[0], pair[1]));
            pair[0] = q.x;
            pair[1] = q.y;
        }
    }

    /// The key file to save: grips and keys in mesh coordinates.
    pub fn key_file(&self, puppet: &str, rig: &Rig, placement: Placement) -> KeyFile {
        let keys = self
            .keys()
            .iter()
            .map(|e| {
                let mut e = e.clone();
                self.values_to_mesh(&mut e.values, rig, placement);
                e
            })
            .collect();
        KeyFile {
            puppet: puppet.to_string(),
            grips: self.grips.clone(),
            keys,
        }
    }

    /// Adds a key pose made from the puppet now. The first key of a
    /// puppet without grips keys what its handles hold (or the skeleton).
    pub fn add_key(
        &mut self,
        name: String,
        at: DVec2,
        rig: &Rig,
        held: &[(Grip, DVec2)],
        placement: Placement,
        pose_at: impl Fn(Grip) -> Option<DVec2>,
    ) -> Result<usize, KeysError> {
        if self.set.is_none() {
            let grips: Vec<KeyGrip> = match rig {
                Rig::Skeleton(_) => vec![KeyGrip::Skeleton],
                _ => held
                    .iter()
                    .map(|&(grip, rest)| match grip {
                        Grip::GridHandle(index) => KeyGrip::GridHandle { index },
                        _ => KeyGrip::Point {
                            at: placement.to_mesh(rest).to_array(),
                        },
                    })
                    .collect(),
            };
            if grips.is_empty() {
                return Err(KeysError::Key {
                    index: 0,
                    name,
                    field: "values".into(),
                    problem: crate::keys::Problem::Empty,
                });
            }
            self.grips = grips;
            self.targets = held
                .iter()
                .filter(|_| !matches!(rig, Rig::Skeleton(_)))
                .copied()
                .collect();
            self.skeleton = matches!(rig, Rig::Skeleton(_));
            self.handles = vec![None; self.targets.len()];
            self.set = Some(KeySet::new(Vec::new(), self.width(rig))?);
        }
        let values = if self.skeleton {
            let first = self
                .keys()
                .first()
                .map(|k| k.values[skeleton_roots(rig) * 2..].to_vec());
            skeleton_values(rig, first.as_deref())
        } else {
            self.targets
                .iter()
                .flat_map(|&(grip, _)| {
                    let p = pose_at(grip).unwrap_or(DVec2::NAN);
                    [p.x, p.y]
                })
                .collect()
        };
        let set = self.set.as_mut().expect("made above");
        let index = set.add(KeyEntry {
            name,
            at: at.to_array(),
            values,
        })?;
        self.touch();
        Ok(index)
    }
}

/// Configured pads of input sources, resolved to puppet indices.
#[derive(Debug, Clone)]
pub struct Pad {
    /// The puppet whose cursor it moves (its index, which is its id).
    pub puppet: usize,
    /// Only this input source's contacts use the pad; `None`: any source's.
    pub source: Option<String>,
    /// The pad's lower-left corner, in stage coordinates.
    pub min: DVec2,
    /// The pad's upper-right corner, in stage coordinates.
    pub max: DVec2,
}

impl Pad {
    /// A `[[pad]]` for the puppet at index `puppet`, its corners put in
    /// order (the file may give them either way round).
    pub(crate) fn from_config(config: &PadConfig, puppet: usize) -> Pad {
        let [x0, y0, x1, y1] = config.area;
        Pad {
            puppet,
            source: config.source.clone(),
            min: DVec2::new(x0.min(x1), y0.min(y1)),
            max: DVec2::new(x0.max(x1), y0.max(y1)),
        }
    }

    /// Whether a contact of `source` landing at `at` (stage coordinates)
    /// moves this pad's cursor: the pad takes that source, and `at` is in
    /// its area, edges included.
    pub(crate) fn takes(&self, source: &str, at: DVec2) -> bool {
        self.source.as_deref().is_none_or(|s| s == source)
            && at.cmpge(self.min).all()
            && at.cmple(self.max).all()
    }

    /// Pad coordinates (`[0, 1]²`) of a stage point, clamped to the pad.
    pub fn cursor(&self, at: DVec2) -> DVec2 {
        ((at - self.min) / (self.max - self.min)).clamp(DVec2::ZERO, DVec2::ONE)
    }
}

fn skeleton_roots(rig: &Rig) -> usize {
    match rig {
        Rig::Skeleton(r) => r.deformer().skeleton().roots().len(),
        _ => 0,
    }
}

fn skeleton_width(rig: &Rig) -> usize {
    match rig {
        Rig::Skeleton(r) => {
            let s = r.deformer().skeleton();
            s.roots().len() * 2 + s.bones().len()
        }
        _ => 0,
    }
}

/// A skeleton's pose as key values: roots (stage), then joint angles
/// unwrapped to within half a turn of `first`'s so blends turn the short way.
fn skeleton_values(rig: &Rig, first: Option<&[f64]>) -> Vec<f64> {
    let Rig::Skeleton(r) = rig else {
        return Vec::new();
    };
    let pose = r.pose();
    let mut values: Vec<f64> = pose.roots.iter().flat_map(|p| [p.x, p.y]).collect();
    for (i, &a) in pose.angles.iter().enumerate() {
        let reference = first.and_then(|f| f.get(i)).copied().unwrap_or(a);
        let turns = ((a - reference) / std::f64::consts::TAU).round();
        values.push(a - turns * std::f64::consts::TAU);
    }
    values
}

/// A skeleton pose from blended key values (lengths stay the rig's).
pub(crate) fn skeleton_pose(rig: &Rig, values: &[f64]) -> Option<Pose> {
    let Rig::Skeleton(r) = rig else {
        return None;
    };
    let mut pose = r.pose().clone();
    let roots = pose.roots.len();
    if values.len() != roots * 2 + pose.angles.len() {
        return None;
    }
    for (i, root) in pose.roots.iter_mut().enumerate() {
        *root = DVec2::new(values[2 * i], values[2 * i + 1]);
    }
    pose.angles.copy_from_slice(&values[roots * 2..]);
    Some(pose)
}
