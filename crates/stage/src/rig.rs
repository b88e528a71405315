//! A puppet's rig: which deformer drives it and how a contact's grip on it
//! (a material point, a grid handle, a joint) becomes that deformer's
//! handles. Free-form puppets run the ARAP solver, grid puppets lp-FFD and
//! skeleton puppets the shape-aware skeletal deformer; all three honour the
//! puppet's per-triangle weights. Curve puppets run as-rigid-as-possible
//! curve editing on their centre line, with peeling, and lay their ribbon
//! mesh along it. Built from the stage file by [`Rig::from_config`], in
//! stage coordinates.

use glam::DVec2;

use std::ops::RangeInclusive;

use super::config::{
    BasisConfig, CurveConfig, GridConfig, KeyPoseConfig, SkeletonConfig, SkeletonMode,
};
use super::{Handle, HandleKind, stage_point};
use puppetry_deform::curve::{Curve, CurveAnchor, Peel, PeelParams};
use puppetry_deform::ffd::{Basis, GridSpec, LpFfd, LpParams};
use puppetry_deform::skeleton::{Pose, ShapeAware, Skeleton, SkeletonParams};
use puppetry_deform::{Anchor, Arap, Steps};
use puppetry_mesh::Mesh;
use puppetry_mesh::stroke::{ribbon_triangle, ribbon_vertices};

/// What a handle holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Grip {
    /// A material point of the mesh (free-form and grid puppets).
    Point(Anchor),
    /// A grid handle of an lp-FFD puppet, by index (row by row).
    GridHandle(usize),
    /// A joint of a skeleton puppet, by index.
    Joint(usize),
    /// A point on a skeleton puppet's bone, in the bone's own frame:
    /// `along` it (0 at the parent joint, 1 at the child) and `across` it
    /// (stage units, to the left). FK turns the bone about its parent joint
    /// so the point follows the finger; free mode moves both joints with it.
    Bone {
        /// The bone's index.
        index: usize,
        /// Along the bone: 0 at its parent joint, 1 at its child.
        along: f64,
        /// Across the bone, in stage units, to the left.
        across: f64,
    },
}

/// A free-form puppet's solver.
pub struct FreeRig {
    pub(super) arap: Arap,
    targets: Vec<DVec2>,
    /// Weights generation the solver was built with, and whether a rebuild
    /// with newer weights is under way on a worker thread.
    pub(super) built_generation: u64,
    pub(super) rebuilding: bool,
}

/// A grid puppet's rig: the lp-FFD solver, and the handles it was last
/// compiled with.
pub struct GridRig {
    pub(super) ffd: LpFfd,
    vertex_anchors: Vec<Anchor>,
    grid_indices: Vec<usize>,
    vertex_targets: Vec<DVec2>,
    grid_targets: Vec<DVec2>,
}

/// A skeleton puppet's rig: the shape-aware deformer, how contacts drive
/// it, both modes' state and the stage file's key poses.
pub struct SkeletonRig {
    pub(super) deformer: ShapeAware,
    pub(super) mode: SkeletonMode,
    /// FK mode's state: the current pose.
    pub(super) pose: Pose,
    /// Free mode's state: the current joint positions.
    pub(super) joints: Vec<DVec2>,
    /// Per joint, the bone ending at it (`None` for roots).
    bone_ending: Vec<Option<usize>>,
    /// Key poses, in stage coordinates.
    pub(super) key_poses: Vec<(String, Pose)>,
}

/// A curve puppet's rig: the centre line's solver and the drags peeling
/// it. Its mesh is the ribbon along the centre line (vertices `2i` and
/// `2i + 1` beside point `i`), so a contact grips a point of the ribbon as
/// on any mesh puppet, and the rig reads that grip as a point of the centre
/// line (arc length along it) and a distance across it.
pub struct CurveRig {
    pub(super) curve: Curve,
    half_width: f64,
    peel: PeelParams,
    /// One per contact holding the curve: its peeled region.
    drags: Vec<Drag>,
    /// The free points compiled now (none while nothing drags).
    free: Option<RangeInclusive<usize>>,
    /// Per compiled curve handle, the stage handle (index) it follows.
    held_by: Vec<usize>,
    anchors: Vec<CurveAnchor>,
    targets: Vec<DVec2>,
    pushpins: Vec<f64>,
    ribbon: Vec<DVec2>,
}

/// A contact's drag along a curve: its peel, and where the finger was
/// when it took hold (the drag distance is measured from there).
struct Drag {
    handle: u64,
    peel: Peel,
    from: DVec2,
}

/// Why a rig could not solve, take weights or take a pose.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// The free-form (ARAP) solver refused the handles or their targets.
    #[error(transparent)]
    Arap(#[from] puppetry_deform::ArapError),
    /// The lp-FFD solver refused the handles, targets or weights.
    #[error("lp-FFD: {0}")]
    Ffd(#[from] puppetry_deform::ffd::FfdError),
    /// The skeletal deformer refused the joints, weights or a pose (one
    /// that does not fit the skeleton, a non-finite one).
    #[error("skeleton: {0}")]
    Skeleton(#[from] puppetry_deform::skeleton::SkeletonError),
    /// The curve solver refused the drags or a pose.
    #[error("curve: {0}")]
    Curve(#[from] puppetry_deform::curve::CurveError),
    /// A key-pose blend named a pose the stage file does not give the
    /// skeleton.
    #[error("no key pose named {name:?}")]
    UnknownPose {
        /// The name asked for.
        name: String,
    },
}

/// The deformer that drives a puppet, chosen by its stage-file entry: a
/// `curve`, a `grid`, a `skeleton`, or else free-form.
pub enum Rig {
    /// Free-form: ARAP on the mesh, held by material points.
    Free(FreeRig),
    /// lp-FFD: a grid of handles over the mesh, held by its handles or by
    /// material points.
    Grid(Box<GridRig>),
    /// Shape-aware skeletal deformation, held by joints and bones.
    Skeleton(Box<SkeletonRig>),
    /// A curve puppet's ribbon, laid along a centre line that
    /// as-rigid-as-possible curve editing bends.
    Curve(Box<CurveRig>),
}

impl Rig {
    /// The rig the stage file asks for, over `placed` (the mesh on the
    /// stage); `source` is the mesh in its own coordinates, where the stage
    /// file gives joints. Errors are `(field, problem)`.
    pub fn from_config(
        source: &Mesh,
        placed: &Mesh,
        at: DVec2,
        scale: f64,
        grid: Option<&GridConfig>,
        skeleton: Option<&SkeletonConfig>,
        curve: Option<&CurveConfig>,
    ) -> Result<Rig, (String, String)> {
        if let Some(c) = curve {
            // The ribbon's vertex pairs sit either side of the centre line.
            let centre: Vec<DVec2> = placed
                .vertices()
                .chunks_exact(2)
                .map(|pair| (pair[0] + pair[1]) / 2.0)
                .collect();
            let curve =
                Curve::register(&centre).map_err(|e| ("curve".to_string(), e.to_string()))?;
            return Ok(Rig::Curve(Box::new(CurveRig {
                curve,
                half_width: c.width * scale / 2.0,
                peel: PeelParams {
                    initial_radius: c.peel_radius * scale,
                    growth_rate: c.peel_rate,
                },
                drags: Vec::new(),
                free: None,
                held_by: Vec::new(),
                anchors: Vec::new(),
                targets: Vec::new(),
                pushpins: Vec::new(),
                ribbon: placed.vertices().to_vec(),
            })));
        }
        if let Some(g) = grid {
            let basis = match g.basis {
                BasisConfig::Bernstein => Basis::Bernstein,
                BasisConfig::Lattice => Basis::Lattice,
            };
            let d = LpParams::default();
            let params = LpParams {
                locality: g.locality.unwrap_or(d.locality),
                vertex: g.vertex.unwrap_or(d.vertex),
                grid: g.grid.unwrap_or(d.grid),
                regular: g.regular.unwrap_or(d.regular),
                iterations: g.iterations.unwrap_or(d.iterations),
            };
            let spec = GridSpec::around(placed, g.columns, g.rows, basis);
            let ffd = LpFfd::register(placed, spec, params)
                .map_err(|e| ("grid".to_string(), e.to_string()))?;
            return Ok(Rig::Grid(Box::new(GridRig {
                ffd,
                vertex_anchors: Vec::new(),
                grid_indices: Vec::new(),
                vertex_targets: Vec::new(),
                grid_targets: Vec::new(),
            })));
        }
        if let Some(s) = skeleton {
            fn err(
                field: &'static str,
            ) -> impl Fn(puppetry_deform::skeleton::SkeletonError) -> (String, String) {
                move |e| (format!("skeleton.{field}"), e.to_string())
            }
            let own = Skeleton::new(
                s.joints.iter().map(|&j| DVec2::from(j)).collect(),
                s.bones.clone(),
            )
            .map_err(err("bones"))?;
            let to_stage = |p: DVec2| stage_point(source, at, scale, p);
            let skeleton = Skeleton::new(
                own.joints().iter().map(|&j| to_stage(j)).collect(),
                own.bones().to_vec(),
            )
            .map_err(err("joints"))?;
            let mut key_poses = Vec::new();
            for (k, p) in s.poses.iter().enumerate() {
                let pose = key_pose(&own, p)
                    .map_err(|problem| (format!("skeleton.poses[{k}]"), problem))?;
                let placed_pose = Pose {
                    roots: pose.roots.iter().map(|&r| to_stage(r)).collect(),
                    angles: pose.angles,
                    lengths: pose.lengths.iter().map(|l| l * scale).collect(),
                };
                key_poses.push((p.name.clone(), placed_pose));
            }
            let d = SkeletonParams::default();
            let c = &s.params;
            let params = SkeletonParams {
                bone_weight: c.bone_weight.unwrap_or(d.bone_weight),
                joint_weight: c.joint_weight.unwrap_or(d.joint_weight),
                rounds: c.rounds.unwrap_or(d.rounds),
                perpendicular_scale: c.perpendicular_scale.unwrap_or(d.perpendicular_scale),
                warm_start: c.warm_start.unwrap_or(d.warm_start),
                bone_start: c.bone_start.unwrap_or(d.bone_start),
            };
            let mut bone_ending = vec![None; skeleton.joints().len()];
            for (b, &[_, child]) in skeleton.bones().iter().enumerate() {
                bone_ending[child] = Some(b);
            }
            let pose = skeleton.rest_pose();
            let joints = skeleton.joints().to_vec();
            let deformer = ShapeAware::register(placed, skeleton, params).map_err(err("joints"))?;
            return Ok(Rig::Skeleton(Box::new(SkeletonRig {
                deformer,
                mode: s.mode,
                pose,
                joints,
                bone_ending,
                key_poses,
            })));
        }
        let arap = Arap::register(placed).map_err(|e| ("mesh".to_string(), e.to_string()))?;
        Ok(Rig::Free(FreeRig {
            arap,
            targets: Vec::new(),
            built_generation: 0,
            rebuilding: false,
        }))
    }

    /// The rig's kind as a word (`free`, `grid`, `skeleton` or `curve`),
    /// for messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Rig::Free(_) => "free",
            Rig::Grid(_) => "grid",
            Rig::Skeleton(_) => "skeleton",
            Rig::Curve(_) => "curve",
        }
    }

    /// The deformed vertices (stage coordinates, rest order).
    pub fn pose(&self) -> &[DVec2] {
        match self {
            Rig::Free(r) => r.arap.pose(),
            Rig::Grid(r) => r.ffd.pose(),
            Rig::Skeleton(r) => r.deformer.pose(),
            Rig::Curve(r) => &r.ribbon,
        }
    }

    /// A skeleton puppet's skeleton at rest (stage coordinates); none for
    /// the other rigs.
    pub fn skeleton(&self) -> Option<&Skeleton> {
        match self {
            Rig::Skeleton(r) => Some(r.deformer.skeleton()),
            Rig::Free(_) | Rig::Grid(_) | Rig::Curve(_) => None,
        }
    }

    /// The rig's own points as clients draw them: the deformed grid
    /// handles, or the posed joints; none for free-form puppets.
    pub fn points(&self) -> Option<&[DVec2]> {
        match self {
            Rig::Free(_) | Rig::Curve(_) => None,
            Rig::Grid(r) => Some(r.ffd.grid()),
            Rig::Skeleton(r) => Some(r.deformer.joints()),
        }
    }

    /// The nearest rig point (grid handle or joint) within `radius` of `p`.
    pub fn point_near(&self, p: DVec2, radius: f64) -> Option<Grip> {
        let points = self.points()?;
        let (index, d) = points
            .iter()
            .enumerate()
            .map(|(i, q)| (i, q.distance(p)))
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        if d > radius {
            return None;
        }
        Some(match self {
            Rig::Skeleton(_) => Grip::Joint(index),
            _ => Grip::GridHandle(index),
        })
    }

    /// Whether a point grip (a material point) can be held on this rig.
    pub fn takes_points(&self) -> bool {
        !matches!(self, Rig::Skeleton(_))
    }

    /// Where a grip's rig point is now (stage coordinates).
    pub fn grip_position(&self, grip: Grip) -> Option<DVec2> {
        match grip {
            Grip::Point(_) => None,
            Grip::GridHandle(i) | Grip::Joint(i) => self.points()?.get(i).copied(),
            Grip::Bone {
                index,
                along,
                across,
            } => {
                let Rig::Skeleton(r) = self else { return None };
                let [a, c] = *r.deformer.skeleton().bones().get(index)?;
                let joints = r.deformer.joints();
                Some(bone_point(joints[a], joints[c], along, across))
            }
        }
    }

    /// The bone of a skeleton puppet nearest to `p`, as a grip on the
    /// point of the bone's frame that lies at `p`.
    pub fn bone_near(&self, p: DVec2) -> Option<Grip> {
        let Rig::Skeleton(r) = self else { return None };
        let joints = r.deformer.joints();
        let (index, _) = r
            .deformer
            .skeleton()
            .bones()
            .iter()
            .enumerate()
            .map(|(b, &[a, c])| (b, segment_distance(p, joints[a], joints[c])))
            .min_by(|x, y| x.1.total_cmp(&y.1))?;
        let [a, c] = r.deformer.skeleton().bones()[index];
        let (from, d) = (joints[a], joints[c] - joints[a]);
        let length = d.length();
        if length <= 0.0 || !length.is_finite() {
            return None;
        }
        let unit = d / length;
        let local = p - from;
        Some(Grip::Bone {
            index,
            along: local.dot(unit) / length,
            across: unit.perp_dot(local),
        })
    }

    /// Compiles (if `changed`) and solves for the handles' targets.
    /// Grips that do not belong to this rig are skipped (they cannot be
    /// made: the stage only grips what [`Rig::point_near`] or a hit test
    /// found).
    pub fn solve(&mut self, handles: &[Handle], changed: bool) -> Result<(), RigError> {
        match self {
            Rig::Free(r) => {
                if changed {
                    let anchors: Vec<Anchor> = handles
                        .iter()
                        .filter_map(|h| match h.grip {
                            Grip::Point(a) => Some(a),
                            _ => None,
                        })
                        .collect();
                    r.arap.compile(&anchors)?;
                }
                r.targets.clear();
                r.targets.extend(
                    handles
                        .iter()
                        .filter(|h| matches!(h.grip, Grip::Point(_)))
                        .map(|h| h.rig_target()),
                );
                r.arap.update(&r.targets, Steps::Both)?;
            }
            Rig::Grid(r) => r.solve(handles, changed)?,
            Rig::Skeleton(r) => {
                match r.mode {
                    SkeletonMode::Free => {
                        for h in handles {
                            match h.grip {
                                Grip::Joint(j) => {
                                    if let Some(joint) = r.joints.get_mut(j) {
                                        *joint = h.rig_target();
                                    }
                                }
                                Grip::Bone {
                                    index,
                                    along,
                                    across,
                                } => {
                                    // The bone keeps its shape and moves so
                                    // its grabbed point is under the finger.
                                    let Some(&[a, c]) = r.deformer.skeleton().bones().get(index)
                                    else {
                                        continue;
                                    };
                                    let (from, to) = (r.joints[a], r.joints[c]);
                                    let shift =
                                        h.rig_target() - bone_point(from, to, along, across);
                                    r.joints[a] = from + shift;
                                    r.joints[c] = to + shift;
                                }
                                _ => {}
                            }
                        }
                        r.deformer.update(&r.joints)?;
                    }
                    SkeletonMode::Fk => {
                        let skeleton = r.deformer.skeleton();
                        for h in handles {
                            match h.grip {
                                Grip::Joint(j) => match r.bone_ending.get(j).copied().flatten() {
                                    Some(bone) => {
                                        skeleton.aim(&mut r.pose, bone, h.rig_target())?
                                    }
                                    None => {
                                        if let Some(k) =
                                            skeleton.roots().iter().position(|&x| x == j)
                                        {
                                            r.pose.roots[k] = h.rig_target();
                                        }
                                    }
                                },
                                Grip::Bone {
                                    index,
                                    along,
                                    across,
                                } => {
                                    let Some(&[a, _]) = skeleton.bones().get(index) else {
                                        continue;
                                    };
                                    // The grabbed point lies `phi` off the
                                    // bone's direction, seen from its parent
                                    // joint: aim the bone that much short of
                                    // the finger, and the point is on the ray
                                    // to it. (`joints` is scratch here: it is
                                    // set from the deformer below.)
                                    skeleton.joints_into(&r.pose, &mut r.joints)?;
                                    let pivot = r.joints[a];
                                    let length = r.pose.lengths[index];
                                    let phi = across.atan2(along * length);
                                    let toward = pivot
                                        + DVec2::from_angle(-phi).rotate(h.rig_target() - pivot);
                                    skeleton.aim(&mut r.pose, index, toward)?;
                                }
                                _ => {}
                            }
                        }
                        r.deformer.update_pose(&r.pose)?;
                    }
                }
                // Both modes keep both states, so a key pose or a mode's
                // next frame starts from what is on stage.
                r.joints.copy_from_slice(r.deformer.joints());
            }
            Rig::Curve(r) => r.solve(handles, changed)?,
        }
        Ok(())
    }

    /// Back at rest (a reset): a free-form or grid puppet's solver keeps
    /// the pose its last handles left, so a puppet let go would otherwise
    /// stay where it was dropped. Skeletons and curves are put at rest by
    /// the pose a reset restores.
    pub fn rest_pose(&mut self) {
        match self {
            Rig::Free(r) => r.arap.rest_pose(),
            Rig::Grid(r) => r.ffd.rest_pose(),
            Rig::Skeleton(_) | Rig::Curve(_) => {}
        }
    }

    /// Applies painted weights: the grid and skeleton refactor now; a
    /// free-form puppet's solver is rebuilt elsewhere (see `thread`).
    pub fn set_weights(&mut self, weights: &[f64]) -> Result<(), RigError> {
        match self {
            // A stroke is as stiff as its curve: weights do not apply.
            Rig::Free(_) | Rig::Curve(_) => Ok(()),
            Rig::Grid(r) => Ok(r.ffd.set_weights(weights)?),
            Rig::Skeleton(r) => Ok(r.deformer.set_weights(weights)?),
        }
    }
}

impl GridRig {
    /// Compiles the handles when they changed and moves them to their
    /// targets (see [`Rig::solve`]).
    fn solve(&mut self, handles: &[Handle], changed: bool) -> Result<(), RigError> {
        if changed {
            self.vertex_anchors.clear();
            self.grid_indices.clear();
            for h in handles {
                match h.grip {
                    Grip::Point(a) => self.vertex_anchors.push(a),
                    Grip::GridHandle(i) => self.grid_indices.push(i),
                    Grip::Joint(_) | Grip::Bone { .. } => {}
                }
            }
            self.ffd.compile(&self.vertex_anchors, &self.grid_indices)?;
            // The last hand let go: back to rest, as a free puppet
            // springs back. The local steps start from the pose,
            // so without this the grid kept its last drag's turns
            // (48 units off on the demo) until a reset.
            if handles.iter().all(|h| h.kind != HandleKind::Contact) {
                self.ffd.rest_pose();
            }
        }
        self.vertex_targets.clear();
        self.grid_targets.clear();
        for h in handles {
            match h.grip {
                Grip::Point(_) => self.vertex_targets.push(h.rig_target()),
                Grip::GridHandle(_) => self.grid_targets.push(h.rig_target()),
                Grip::Joint(_) | Grip::Bone { .. } => {}
            }
        }
        self.ffd.update(&self.vertex_targets, &self.grid_targets)?;
        Ok(())
    }

    /// The lp-FFD solver (its grid, spec and pose).
    pub fn ffd(&self) -> &LpFfd {
        &self.ffd
    }
}

impl SkeletonRig {
    /// The deformer (its skeleton and posed joints).
    pub fn deformer(&self) -> &ShapeAware {
        &self.deformer
    }

    /// How contacts drive the skeleton (the stage file's `mode`).
    pub fn mode(&self) -> SkeletonMode {
        self.mode
    }

    /// Sets the skeleton to the pose between two key poses.
    pub fn set_key_pose(&mut self, from: &str, to: &str, t: f64) -> Result<(), RigError> {
        let find = |name: &str| {
            self.key_poses
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, p)| p)
                .ok_or_else(|| RigError::UnknownPose {
                    name: name.to_string(),
                })
        };
        let pose = Pose::interpolate(find(from)?, find(to)?, t)?;
        let joints = self.deformer.skeleton().joints_of(&pose)?;
        self.pose = pose;
        self.joints = joints;
        Ok(())
    }

    /// The FK pose now.
    pub fn pose(&self) -> &Pose {
        &self.pose
    }

    /// Sets the skeleton to a pose (a blend of key poses).
    pub fn set_pose(&mut self, pose: Pose) -> Result<(), RigError> {
        let joints = self.deformer.skeleton().joints_of(&pose)?;
        self.pose = pose;
        self.joints = joints;
        Ok(())
    }

    /// The pose state undo keeps: the FK pose and the joints.
    pub(super) fn pose_state(&self) -> (Pose, Vec<DVec2>) {
        (self.pose.clone(), self.joints.clone())
    }

    /// Puts back a pose state kept by [`SkeletonRig::pose_state`] (checked
    /// against the skeleton, so a recorded one cannot break the solve).
    pub(super) fn restore_pose(&mut self, pose: Pose, joints: Vec<DVec2>) -> Result<(), RigError> {
        let skeleton = self.deformer.skeleton();
        skeleton.joints_of(&pose)?;
        if joints.len() != skeleton.joints().len() || !joints.iter().all(|j| j.is_finite()) {
            return Err(RigError::Skeleton(
                puppetry_deform::skeleton::SkeletonError::BadParameter {
                    name: "joints",
                    problem: "must be one finite point per joint",
                    value: joints.len() as f64,
                },
            ));
        }
        self.pose = pose;
        self.joints = joints;
        Ok(())
    }

    /// The key poses' names, in the stage file's order: what a `pose`
    /// request may name.
    pub fn pose_names(&self) -> Vec<&str> {
        self.key_poses.iter().map(|(n, _)| n.as_str()).collect()
    }
}

impl CurveRig {
    /// The curve solver (its rest and posed centre line).
    pub fn curve(&self) -> &Curve {
        &self.curve
    }

    /// The stroke's half-width (stage units).
    pub fn half_width(&self) -> f64 {
        self.half_width
    }

    /// How the drags peel.
    pub fn peel(&self) -> PeelParams {
        self.peel
    }

    /// The free points of the drags now (none while nothing drags).
    pub fn free_points(&self) -> Option<RangeInclusive<usize>> {
        self.free.clone()
    }

    /// Puts the centre line in a pose (undo, reset); the drags go on from
    /// there (the next solve compiles again).
    pub(super) fn set_pose(&mut self, points: &[DVec2]) -> Result<(), RigError> {
        self.curve.set_pose(points)?;
        self.free = None;
        self.held_by.clear();
        ribbon_vertices(self.curve.pose(), self.half_width, &mut self.ribbon);
        Ok(())
    }

    /// A grip on the ribbon as a point of the centre line: its arc length
    /// along the rest curve and its distance across (left positive).
    fn on_centre_line(&self, anchor: Anchor) -> (f64, f64) {
        let arc = self.curve.arc_lengths();
        let side = |v: u32| if v.is_multiple_of(2) { 1.0 } else { -1.0 };
        match anchor {
            Anchor::Vertex(v) => (arc[(v / 2) as usize], side(v) * self.half_width),
            Anchor::Point { triangle, bary } => {
                let tri = ribbon_triangle(triangle as usize);
                let (mut s, mut across) = (0.0, 0.0);
                for k in 0..3 {
                    s += bary[k] * arc[(tri[k] / 2) as usize];
                    across += bary[k] * side(tri[k]);
                }
                (s, across * self.half_width)
            }
        }
    }

    /// Where the centre line is asked to go for a handle: the finger less
    /// the grip's offset across the curve, along the curve's normal now.
    fn centre_target(&self, handle: &Handle, anchor: Anchor) -> DVec2 {
        let (s, across) = self.on_centre_line(anchor);
        let CurveAnchor::Along { segment, .. } = self.curve.anchor_at(s) else {
            return handle.rig_target();
        };
        let pose = self.curve.pose();
        let s = segment as usize;
        let normal = (pose[s + 1] - pose[s]).normalize_or_zero().perp();
        handle.rig_target() - normal * across
    }

    /// Follows the drags (peeling: each contact's region grows with how
    /// far it has dragged), recompiling when the handles or the freed
    /// points change; pins are the pushpins that bound the regions.
    fn solve(&mut self, handles: &[Handle], changed: bool) -> Result<(), RigError> {
        let grip_of = |h: &Handle| match h.grip {
            Grip::Point(anchor) => Some(anchor),
            _ => None,
        };
        let mut recompile = changed;
        if changed {
            self.pushpins.clear();
            for h in handles.iter().filter(|h| h.kind == HandleKind::Pin) {
                if let Some(anchor) = grip_of(h) {
                    self.pushpins.push(self.on_centre_line(anchor).0);
                }
            }
            self.drags.retain(|d| {
                handles
                    .iter()
                    .any(|h| h.id == d.handle && h.kind != HandleKind::Pin)
            });
            for h in handles.iter().filter(|h| h.kind != HandleKind::Pin) {
                let Some(anchor) = grip_of(h) else { continue };
                if self.drags.iter().any(|d| d.handle == h.id) {
                    continue;
                }
                let (s, _) = self.on_centre_line(anchor);
                // A pin exactly under the grab cannot bound it.
                let pins: Vec<f64> = self.pushpins.iter().copied().filter(|&p| p != s).collect();
                let peel = Peel::new(&self.curve, s, &pins, self.peel)?;
                self.drags.push(Drag {
                    handle: h.id,
                    peel,
                    from: h.target,
                });
            }
        }
        let mut hull: Option<(usize, usize)> = None;
        for d in &mut self.drags {
            let Some(h) = handles.iter().find(|h| h.id == d.handle) else {
                continue;
            };
            recompile |= d.peel.drag(&self.curve, (h.target - d.from).length())?;
            let free = d.peel.free_points();
            hull = Some(hull.map_or((*free.start(), *free.end()), |(lo, hi)| {
                (lo.min(*free.start()), hi.max(*free.end()))
            }));
        }
        let Some((lo, hi)) = hull else {
            // Nothing drags: the curve stays as it was left.
            self.free = None;
            return Ok(());
        };
        if recompile || self.free != Some(lo..=hi) {
            self.anchors.clear();
            self.held_by.clear();
            for (i, h) in handles.iter().enumerate() {
                let Some(anchor) = grip_of(h) else { continue };
                let curve_anchor = self.curve.anchor_at(self.on_centre_line(anchor).0);
                let holds_free = match curve_anchor {
                    CurveAnchor::Point(p) => (lo..=hi).contains(&(p as usize)),
                    CurveAnchor::Along { segment, t } => {
                        let s = segment as usize;
                        ((lo..=hi).contains(&s) && t < 1.0)
                            || ((lo..=hi).contains(&(s + 1)) && t > 0.0)
                    }
                };
                // Pins outside the freed points hold nothing that moves.
                if h.kind == HandleKind::Pin && !holds_free {
                    continue;
                }
                self.anchors.push(curve_anchor);
                self.held_by.push(i);
            }
            self.curve.compile_within(&self.anchors, lo..=hi)?;
            self.free = Some(lo..=hi);
        }
        self.targets.clear();
        for &i in &self.held_by {
            let h = &handles[i];
            let Some(anchor) = grip_of(h) else { continue };
            let target = self.centre_target(h, anchor);
            self.targets.push(target);
        }
        self.curve.update(&self.targets, Steps::Both)?;
        ribbon_vertices(self.curve.pose(), self.half_width, &mut self.ribbon);
        Ok(())
    }
}

/// The point of a bone's frame `along` it from `from` to `to` and
/// `across` it (to the left).
fn bone_point(from: DVec2, to: DVec2, along: f64, across: f64) -> DVec2 {
    let d = to - from;
    from + d * along + d.normalize_or_zero().perp() * across
}

/// Distance from `p` to the segment `a`–`b`.
fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let d = b - a;
    let t = if d.length_squared() > 0.0 {
        ((p - a).dot(d) / d.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + d * t)
}

/// A key pose of the stage file, in the mesh's coordinates.
fn key_pose(skeleton: &Skeleton, config: &KeyPoseConfig) -> Result<Pose, String> {
    let mut pose = skeleton.rest_pose();
    let bones = skeleton.bones().len();
    let count = |what: &str, got: usize, expected: usize| {
        if got == expected {
            Ok(())
        } else {
            Err(format!(
                "{what}: has {got} entries, the skeleton needs {expected}"
            ))
        }
    };
    if let Some(angles) = &config.angles {
        count("angles", angles.len(), bones)?;
        pose.angles = angles.iter().map(|a| a.to_radians()).collect();
    }
    if let Some(lengths) = &config.lengths {
        count("lengths", lengths.len(), bones)?;
        pose.lengths = lengths.clone();
    }
    if let Some(roots) = &config.roots {
        count("roots", roots.len(), skeleton.roots().len())?;
        pose.roots = roots.iter().map(|&r| DVec2::from(r)).collect();
    }
    for &(bone, degrees) in &config.turn {
        pose.rotate_joint(bone, degrees.to_radians())
            .map_err(|e| format!("turn: {e}"))?;
    }
    skeleton.joints_of(&pose).map_err(|e| e.to_string())?;
    Ok(pose)
}
