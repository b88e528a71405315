//! The shape-aware skeletal deformer of Wang, Yang, Peng & Wang (2013)
//! (`docs/rigs.md` says how a puppet uses it): a [`Skeleton`] (joints and
//! bones forming a forest), its forward kinematics ([`Pose`]: root positions,
//! joint angles, bone lengths) and [`ShapeAware`], which drives a rest
//! [`Mesh`] from posed joint positions.
//!
//! Phases: [`ShapeAware::register`] takes the mesh and the skeleton, finds the
//! triangles each bone crosses and each joint's barycentric row, assembles
//! the stitching matrix (the per-triangle weighted edge Laplacian plus the
//! joints' rows) and factors it once; the matrix depends only on the rest
//! mesh, the skeleton and the weights. [`ShapeAware::update`] is the frame:
//! per bone the 2×2 `A_b` from the virtual-joint construction, then
//! `rounds + 1` stitches — each two back substitutions over the shared
//! factor, x and y together — with, between them, every non-bone triangle's
//! transform reset to the best-fit rotation of its rest triangle onto the
//! stitched one. [`ShapeAware::set_weights`] refactors after stiffness is
//! painted. Nothing in the update path allocates.
//!
//! Every frame starts each non-bone triangle at the rotation of the bone
//! passing nearest it (the rotation taking that bone's rest direction to
//! its posed one), so a frame depends only on the joints it is given (free
//! and FK mode agree, rest joints give the rest shape exactly). The paper
//! starts them at the identity (`bone_start: false`); from the bones every
//! round's energy is lower, and [`DEFAULT_ROUNDS`] (8, not the paper's
//! 12) is chosen from the measured curves. [`SkeletonParams`]'s
//! `warm_start` instead starts from the previous frame's rotations, which
//! converges further per frame during continuous motion at the price of that
//! history independence.
//!
//! **Singular cases.** A bone's `A_b` scales what it carries by its
//! stretch `l/l̄`; for a bone far shorter than its triangles (a joint a hair
//! from its parent: 1e-2 long posed 65 long scaled its triangles 6500
//! times and the mesh flew 3e5 away) that is no measure of anything. So a
//! bone's stretch is measured over its **reach**, the longest of the bone,
//! the edges of the triangles it crosses and (for a piece it carries) the
//! farthest vertex of that piece from its parent joint: `k = (reach + l −
//! l̄)/reach`, so the stretch displaces what the bone carries by no more
//! than the joints moved apart. Bones at least as long as their reach
//! (the usual case) keep the paper's `A_b` exactly. Joints are soft rows
//! (`w_p`): joints on one another or a hair apart on different bones, on
//! a boundary vertex or edge (inside the mesh, boundary included), on a
//! line, posed anywhere, give a least-squares compromise. Two joints on one
//! point joined by a bone are refused (`ZeroLengthBone`). Without
//! `warm_start` a frame depends only on its joints, so nothing is carried
//! from a wild frame to the next.
//!
//! Pieces of the mesh holding no joint would leave the stitch singular (their
//! translation is free). They are not solved: each is attached to the bone
//! nearest to it in the rest pose and carried by that bone's transform about
//! its parent joint, `v = p₁ + A_b (v̄ − p̄₁)`.

use std::f64::consts::{PI, TAU};

use glam::{DMat2, DVec2};

use super::sparse::{FactorError, PairSolve, RealCholesky, UpperPattern, fill_reducing_order};
use crate::lanes::{LANES, Packed};
use puppetry_mesh::json::MAX_COORDINATE;
use puppetry_mesh::polygon::segment_distance;
use puppetry_mesh::{Locator, MAX_WEIGHT, MIN_WEIGHT, Mesh};

/// An error in a skeleton, a pose or the deformer's inputs: what and where.
#[derive(Debug, thiserror::Error)]
pub enum SkeletonError {
    /// [`Skeleton::new`]: no bones were given.
    #[error("the skeleton has no bones")]
    NoBones,
    /// A joint position (rest or posed) is NaN, infinite or beyond the
    /// mesh format's coordinate limit.
    #[error("joint {joint}: position is not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    JointNotFinite {
        /// The first offending joint.
        joint: usize,
    },
    /// [`Skeleton::new`]: a bone names a joint that was not given.
    #[error("bone {bone}: joint {joint} is out of range (the skeleton has {count} joints)")]
    BoneJointOutOfRange {
        /// The offending bone.
        bone: usize,
        /// The joint it named.
        joint: usize,
        /// How many joints were given.
        count: usize,
    },
    /// [`Skeleton::new`]: a bone's parent and child are the same joint.
    #[error("bone {bone}: joins joint {joint} to itself")]
    BoneJoinsJointToItself {
        /// The offending bone.
        bone: usize,
        /// The joint at both its ends.
        joint: usize,
    },
    /// [`Skeleton::new`]: a bone's two joints are within 1e-9 of the
    /// joints' extent of each other at rest.
    #[error("bone {bone}: has zero length (joints {parent} and {child} coincide)")]
    ZeroLengthBone {
        /// The offending bone.
        bone: usize,
        /// Its parent joint.
        parent: usize,
        /// Its child joint.
        child: usize,
    },
    /// [`Skeleton::new`]: two bones end at the same joint.
    #[error(
        "joint {joint}: is the child of both bone {first} and bone {second}; a joint has one parent bone"
    )]
    TwoParents {
        /// The joint with two parent bones.
        joint: usize,
        /// The earlier bone ending there.
        first: usize,
        /// The later one.
        second: usize,
    },
    /// [`Skeleton::new`]: a joint is on no bone.
    #[error("joint {joint}: belongs to no bone")]
    UnusedJoint {
        /// The first such joint.
        joint: usize,
    },
    /// [`Skeleton::new`]: the bones are not a forest.
    #[error("bone {bone}: lies on a cycle; the bones must form a forest")]
    Cycle {
        /// The first bone no root reaches.
        bone: usize,
    },
    /// [`ShapeAware::register`]: a rest joint is not on the mesh (its
    /// boundary counts as on it).
    #[error("joint {joint}: rest position {point:?} is not inside the mesh")]
    JointOutsideMesh {
        /// The first such joint.
        joint: usize,
        /// Its rest position, `[x, y]`.
        point: [f64; 2],
    },
    /// A [`SkeletonParams`] field, an interpolation `t`, a rotation or an
    /// aim point is out of range or not finite.
    #[error("parameter {name}: {problem}, got {value}")]
    BadParameter {
        /// The parameter's name (a field or argument name).
        name: &'static str,
        /// What is wrong with it.
        problem: &'static str,
        /// Its value (for a point, `x + y`).
        value: f64,
    },
    /// Posed joints (or an output slice for them) are not one per skeleton
    /// joint.
    #[error("expected {expected} joint positions (one per skeleton joint), got {got}")]
    JointCount {
        /// How many joints the skeleton has.
        expected: usize,
        /// How many came.
        got: usize,
    },
    /// A [`Pose`] field has the wrong length for the skeleton (or, for
    /// [`Pose::interpolate`], for the other pose).
    #[error("pose: {field} has {got} entries, the skeleton needs {expected}")]
    PoseShape {
        /// The field: `roots`, `angles` or `lengths`.
        field: &'static str,
        /// How many entries it needs.
        expected: usize,
        /// How many it has.
        got: usize,
    },
    /// A [`Pose`] entry is not finite (or beyond the coordinate limit, for
    /// a root), or a bone length is negative.
    #[error("pose: {field}[{index}] is not a finite number (bone lengths must also be ≥ 0)")]
    PoseNotFinite {
        /// The field: `roots`, `angles` or `lengths`.
        field: &'static str,
        /// The first offending entry.
        index: usize,
    },
    /// A bone index is not below the number of bones.
    #[error("bone {bone} is out of range (the skeleton has {count} bones)")]
    BoneOutOfRange {
        /// The bone asked for.
        bone: usize,
        /// How many bones there are.
        count: usize,
    },
    /// [`ShapeAware::set_weights`]: the weights are not one per mesh
    /// triangle.
    #[error("weights: has {got} entries, expected one per triangle ({expected})")]
    WeightCount {
        /// How many triangles the mesh has.
        expected: usize,
        /// How many weights came.
        got: usize,
    },
    /// [`ShapeAware::set_weights`]: a weight is outside the mesh's
    /// `MIN_WEIGHT..=MAX_WEIGHT`.
    #[error("weights[{index}]: must be between {MIN_WEIGHT:e} and {MAX_WEIGHT:e}, got {value}")]
    BadWeight {
        /// The first offending triangle.
        index: usize,
        /// Its weight.
        value: f64,
    },
    /// [`ShapeAware::register`] or [`ShapeAware::set_weights`]: the
    /// stitching matrix could not be factored.
    #[error(transparent)]
    Factor(#[from] FactorError),
}

/// Joints and the bones between them, validated: every bone joins two
/// distinct, distant joints; every joint has at most one parent bone and
/// belongs to some bone; the bones form a forest whose roots are the joints
/// without a parent bone.
#[derive(Debug, Clone, PartialEq)]
pub struct Skeleton {
    joints: Vec<DVec2>,
    bones: Vec<[usize; 2]>,
    /// Per joint, the bone whose child it is.
    parent_bone: Vec<Option<usize>>,
    /// Root joints, increasing.
    roots: Vec<usize>,
    /// Per joint, its index in `roots` (`usize::MAX` for non-roots).
    root_index: Vec<usize>,
    /// Bones with every parent before its children.
    order: Vec<usize>,
}

/// A skeleton's intrinsic parameters: each root joint's position (in the
/// order of [`Skeleton::roots`]), each bone's angle — absolute (radians,
/// counter-clockwise from +x) for a bone leaving a root joint, otherwise
/// relative to the bone ending at its parent joint — and each bone's length.
///
/// The skeleton may be a forest, so there is one root position per tree.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Each tree's root joint position, in mesh coordinates, in the order
    /// of [`Skeleton::roots`].
    pub roots: Vec<DVec2>,
    /// Per bone, its angle in radians: absolute for a bone leaving a root,
    /// relative to its parent bone otherwise.
    pub angles: Vec<f64>,
    /// Per bone, its length in mesh units (finite, at least 0).
    pub lengths: Vec<f64>,
}

/// `a` wrapped into [−π, π).
fn wrap_angle(a: f64) -> f64 {
    (a + PI).rem_euclid(TAU) - PI
}

fn finite_point(p: DVec2) -> bool {
    p.is_finite() && p.abs().max_element() <= MAX_COORDINATE
}

impl Pose {
    /// The pose between key poses `a` (t = 0) and `b` (t = 1): root
    /// positions and bone lengths linearly, each angle along the shorter arc.
    /// Joint positions are never averaged, so limbs do not shrink mid-swing.
    pub fn interpolate(a: &Pose, b: &Pose, t: f64) -> Result<Pose, SkeletonError> {
        for (field, x, y) in [
            ("roots", a.roots.len(), b.roots.len()),
            ("angles", a.angles.len(), b.angles.len()),
            ("lengths", a.lengths.len(), b.lengths.len()),
        ] {
            if x != y {
                return Err(SkeletonError::PoseShape {
                    field,
                    expected: x,
                    got: y,
                });
            }
        }
        if !t.is_finite() {
            return Err(SkeletonError::BadParameter {
                name: "t",
                problem: "must be finite",
                value: t,
            });
        }
        Ok(Pose {
            roots: a
                .roots
                .iter()
                .zip(&b.roots)
                .map(|(p, q)| p.lerp(*q, t))
                .collect(),
            angles: a
                .angles
                .iter()
                .zip(&b.angles)
                .map(|(p, q)| p + wrap_angle(q - p) * t)
                .collect(),
            lengths: a
                .lengths
                .iter()
                .zip(&b.lengths)
                .map(|(p, q)| p + (q - p) * t)
                .collect(),
        })
    }

    /// FK mode: turns `bone` about its parent joint by `delta` radians. Its
    /// descendants' angles are relative, so the chain below follows.
    pub fn rotate_joint(&mut self, bone: usize, delta: f64) -> Result<(), SkeletonError> {
        let count = self.angles.len();
        let angle = self
            .angles
            .get_mut(bone)
            .ok_or(SkeletonError::BoneOutOfRange { bone, count })?;
        if !delta.is_finite() {
            return Err(SkeletonError::BadParameter {
                name: "delta",
                problem: "must be finite",
                value: delta,
            });
        }
        *angle = wrap_angle(*angle + delta);
        Ok(())
    }
}

impl Skeleton {
    /// Validates a skeleton. `bones[b] = [parent joint, child joint]`;
    /// joints are rest positions in mesh coordinates.
    pub fn new(joints: Vec<DVec2>, bones: Vec<[usize; 2]>) -> Result<Skeleton, SkeletonError> {
        if bones.is_empty() {
            return Err(SkeletonError::NoBones);
        }
        if let Some(joint) = joints.iter().position(|p| !finite_point(*p)) {
            return Err(SkeletonError::JointNotFinite { joint });
        }
        let count = joints.len();
        let mut lo = DVec2::splat(f64::INFINITY);
        let mut hi = DVec2::splat(f64::NEG_INFINITY);
        for &p in &joints {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        // Shorter than this, a bone's rest frame is numerically meaningless.
        let shortest = (hi - lo).length() * 1e-9;
        let mut parent_bone: Vec<Option<usize>> = vec![None; count];
        let mut used = vec![false; count];
        for (bone, &[parent, child]) in bones.iter().enumerate() {
            for joint in [parent, child] {
                if joint >= count {
                    return Err(SkeletonError::BoneJointOutOfRange { bone, joint, count });
                }
                used[joint] = true;
            }
            if parent == child {
                return Err(SkeletonError::BoneJoinsJointToItself {
                    bone,
                    joint: parent,
                });
            }
            if joints[parent].distance(joints[child]) <= shortest {
                return Err(SkeletonError::ZeroLengthBone {
                    bone,
                    parent,
                    child,
                });
            }
            if let Some(first) = parent_bone[child] {
                return Err(SkeletonError::TwoParents {
                    joint: child,
                    first,
                    second: bone,
                });
            }
            parent_bone[child] = Some(bone);
        }
        if let Some(joint) = used.iter().position(|u| !u) {
            return Err(SkeletonError::UnusedJoint { joint });
        }
        let roots: Vec<usize> = (0..count).filter(|&j| parent_bone[j].is_none()).collect();
        let mut root_index = vec![usize::MAX; count];
        for (k, &r) in roots.iter().enumerate() {
            root_index[r] = k;
        }
        // Breadth-first from the roots: a bone never reached hangs off a
        // cycle (every joint on a cycle has a parent, so no root leads in).
        let mut order = Vec::with_capacity(bones.len());
        let mut frontier = roots.clone();
        while let Some(joint) = frontier.pop() {
            for (bone, &[parent, child]) in bones.iter().enumerate() {
                if parent == joint {
                    order.push(bone);
                    frontier.push(child);
                }
            }
        }
        if order.len() < bones.len() {
            let mut reached = vec![false; bones.len()];
            for &b in &order {
                reached[b] = true;
            }
            let bone = reached.iter().position(|r| !r).unwrap_or(0);
            return Err(SkeletonError::Cycle { bone });
        }
        Ok(Skeleton {
            joints,
            bones,
            parent_bone,
            roots,
            root_index,
            order,
        })
    }

    /// Rest joint positions.
    pub fn joints(&self) -> &[DVec2] {
        &self.joints
    }

    /// `[parent joint, child joint]` per bone.
    pub fn bones(&self) -> &[[usize; 2]] {
        &self.bones
    }

    /// The joints without a parent bone, increasing: one per tree, in the
    /// order of [`Pose::roots`].
    pub fn roots(&self) -> &[usize] {
        &self.roots
    }

    /// The bone ending at `bone`'s parent joint, if any.
    pub fn parent_of(&self, bone: usize) -> Option<usize> {
        self.parent_bone[self.bones[bone][0]]
    }

    /// The rest pose: [`Skeleton::pose_of`] the rest joints.
    pub fn rest_pose(&self) -> Pose {
        self.pose_of(&self.joints)
            .expect("rest joints are validated")
    }

    fn check_pose(&self, pose: &Pose) -> Result<(), SkeletonError> {
        let bones = self.bones.len();
        for (field, expected, got) in [
            ("roots", self.roots.len(), pose.roots.len()),
            ("angles", bones, pose.angles.len()),
            ("lengths", bones, pose.lengths.len()),
        ] {
            if expected != got {
                return Err(SkeletonError::PoseShape {
                    field,
                    expected,
                    got,
                });
            }
        }
        if let Some(index) = pose.roots.iter().position(|p| !finite_point(*p)) {
            return Err(SkeletonError::PoseNotFinite {
                field: "roots",
                index,
            });
        }
        if let Some(index) = pose.angles.iter().position(|a| !a.is_finite()) {
            return Err(SkeletonError::PoseNotFinite {
                field: "angles",
                index,
            });
        }
        if let Some(index) = pose
            .lengths
            .iter()
            .position(|l| !(l.is_finite() && *l >= 0.0))
        {
            return Err(SkeletonError::PoseNotFinite {
                field: "lengths",
                index,
            });
        }
        Ok(())
    }

    /// `bone`'s absolute angle in `pose`: its relative angles summed up the
    /// chain (skeletons are shallow, so walking up beats keeping scratch).
    fn absolute_angle(&self, pose: &Pose, bone: usize) -> f64 {
        let mut angle = 0.0;
        let mut at = Some(bone);
        while let Some(b) = at {
            angle += pose.angles[b];
            at = self.parent_of(b);
        }
        angle
    }

    /// Forward kinematics: the posed joint positions.
    pub fn joints_of(&self, pose: &Pose) -> Result<Vec<DVec2>, SkeletonError> {
        let mut out = vec![DVec2::ZERO; self.joints.len()];
        self.joints_into(pose, &mut out)?;
        Ok(out)
    }

    /// [`Skeleton::joints_of`] into `out` (one entry per joint), without
    /// allocating. `out` is untouched on error.
    pub fn joints_into(&self, pose: &Pose, out: &mut [DVec2]) -> Result<(), SkeletonError> {
        self.check_pose(pose)?;
        if out.len() != self.joints.len() {
            return Err(SkeletonError::JointCount {
                expected: self.joints.len(),
                got: out.len(),
            });
        }
        for (&joint, &at) in self.roots.iter().zip(&pose.roots) {
            out[joint] = at;
        }
        for &bone in &self.order {
            let [parent, child] = self.bones[bone];
            let angle = self.absolute_angle(pose, bone);
            out[child] = out[parent] + DVec2::from_angle(angle) * pose.lengths[bone];
        }
        Ok(())
    }

    /// Inverse kinematics of a full set of joint positions: the pose whose
    /// [`Skeleton::joints_of`] gives them back. A posed bone of zero length
    /// gets angle 0 relative to the x axis.
    pub fn pose_of(&self, joints: &[DVec2]) -> Result<Pose, SkeletonError> {
        if joints.len() != self.joints.len() {
            return Err(SkeletonError::JointCount {
                expected: self.joints.len(),
                got: joints.len(),
            });
        }
        if let Some(joint) = joints.iter().position(|p| !finite_point(*p)) {
            return Err(SkeletonError::JointNotFinite { joint });
        }
        let direction = |bone: usize| {
            let [parent, child] = self.bones[bone];
            joints[child] - joints[parent]
        };
        let absolute = |bone: usize| {
            let d = direction(bone);
            d.y.atan2(d.x)
        };
        let angles = (0..self.bones.len())
            .map(|bone| match self.parent_of(bone) {
                None => absolute(bone),
                Some(parent) => wrap_angle(absolute(bone) - absolute(parent)),
            })
            .collect();
        Ok(Pose {
            roots: self.roots.iter().map(|&r| joints[r]).collect(),
            angles,
            lengths: (0..self.bones.len())
                .map(|bone| direction(bone).length())
                .collect(),
        })
    }

    /// FK mode for a contact: turns `bone` about its parent joint so that it
    /// points at `toward`; the chain below follows. A `toward` on the parent
    /// joint leaves the pose as it is.
    pub fn aim(&self, pose: &mut Pose, bone: usize, toward: DVec2) -> Result<(), SkeletonError> {
        self.check_pose(pose)?;
        if bone >= self.bones.len() {
            return Err(SkeletonError::BoneOutOfRange {
                bone,
                count: self.bones.len(),
            });
        }
        if !finite_point(toward) {
            return Err(SkeletonError::BadParameter {
                name: "toward",
                problem: "must be a finite point",
                value: toward.x + toward.y,
            });
        }
        let angle = self.absolute_angle(pose, bone);
        // The parent joint: walk up, each ancestor's angle peeled off in turn.
        let mut pivot = DVec2::ZERO;
        let mut ancestor_angle = angle - pose.angles[bone];
        let mut joint = self.bones[bone][0];
        while let Some(b) = self.parent_bone[joint] {
            pivot += DVec2::from_angle(ancestor_angle) * pose.lengths[b];
            ancestor_angle -= pose.angles[b];
            joint = self.bones[b][0];
        }
        pivot += pose.roots[self.root_index[joint]];
        let want = toward - pivot;
        if want.length_squared() > 0.0 {
            pose.rotate_joint(bone, wrap_angle(want.y.atan2(want.x) - angle))?;
        }
        Ok(())
    }
}

/// The deformer's tunables; the defaults are the paper's but for the
/// start and the rounds (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkeletonParams {
    /// Stiffness factor of the triangles a bone crosses (paper: 100).
    pub bone_weight: f64,
    /// `w_p`, the weight of the joints' positional rows (paper: 100).
    pub joint_weight: f64,
    /// Shape-matching updates per frame; a frame stitches `rounds + 1`
    /// times. The paper runs about 12 from the identity; [`DEFAULT_ROUNDS`]
    /// from the bones' rotations (`bone_start`) end lower.
    pub rounds: usize,
    /// `s`, the posed virtual joint's distance from the bone over the bone's
    /// length: the scale across the bone (paper: 1).
    pub perpendicular_scale: f64,
    /// Start each frame's non-bone rotations from the previous frame's
    /// (see the module docs). Overrides `bone_start`.
    pub warm_start: bool,
    /// Start each frame's non-bone triangles at the rotation of the bone
    /// passing nearest them (its rest direction onto its posed one)
    /// instead of the paper's identity: the same frame-by-frame history
    /// independence, and the rounds start nearer where they end, so every
    /// round's energy is lower (the tables in docs/rigs.md).
    pub bone_start: bool,
}

impl Default for SkeletonParams {
    fn default() -> Self {
        SkeletonParams {
            bone_weight: 100.0,
            joint_weight: 100.0,
            rounds: DEFAULT_ROUNDS,
            perpendicular_scale: 1.0,
            warm_start: false,
            bone_start: true,
        }
    }
}

impl SkeletonParams {
    fn check(&self) -> Result<(), SkeletonError> {
        let positive = |name, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(SkeletonError::BadParameter {
                    name,
                    problem: "must be a finite number above 0",
                    value,
                })
            }
        };
        positive("bone_weight", self.bone_weight)?;
        positive("joint_weight", self.joint_weight)?;
        positive("perpendicular_scale", self.perpendicular_scale)?;
        if self.rounds > MAX_ROUNDS {
            return Err(SkeletonError::BadParameter {
                name: "rounds",
                problem: "is too many (at most 1000)",
                value: self.rounds as f64,
            });
        }
        Ok(())
    }
}

/// Shape-matching rounds per frame by default. Measured (the tables are in
/// docs/rigs.md) from the bones' rotations: on the motion of `puppetry
/// bench --rigs` (every bone swinging ±0.35 rad) 8 rounds leave the
/// stitching energy 1.5% (1k vertices) and 5.6% (10k) above its converged
/// value, where the paper's 12 from the identity leave 1.9% and 7.7%; on a
/// held pose with a limb turned a full radian they end 1.2% and 0.5% above
/// the paper's 12. Each round is one stitch (two sparse triangular solves)
/// and one shape-matching sweep, so 8 rounds cost 9/13 of 12.
pub const DEFAULT_ROUNDS: usize = 8;

/// Far beyond convergence; the cap keeps a typo from sizing a huge buffer.
const MAX_ROUNDS: usize = 1000;

/// A triangle of the solved pieces, corners in unknown numbering.
/// The frame sweeps the bone ones; the free ones are swept as [`FreeLanes`]
/// and `free_corners`.
#[derive(Debug, Clone)]
struct StitchTriangle {
    corners: [u32; 3],
    /// The bone whose transform this triangle takes (bone triangles only).
    bone: u32,
    /// `3·w_t`: the per-triangle edge sum telescopes to
    /// `b_i += w (2ē_i − ē_j − ē_k) = 3w A (v̄_i − c̄)`.
    weight3: f64,
    /// The first two rest corners minus the rest centroid; the third is
    /// minus their sum.
    centred: [DVec2; 2],
}

impl StitchTriangle {
    #[inline(always)]
    fn rest_corners(&self) -> [DVec2; 3] {
        let [a, b] = self.centred;
        [a, b, -(a + b)]
    }

    /// The stitched corners in `x`, about their centroid.
    #[inline(always)]
    fn corners_in(&self, x: &[DVec2]) -> [DVec2; 3] {
        let p = self.corners.map(|c| x[c as usize]);
        let centroid = (p[0] + p[1] + p[2]) * (1.0 / 3.0);
        p.map(|q| q - centroid)
    }
}

/// A joint's positional row over the unknowns.
#[derive(Debug, Clone, Copy)]
struct JointRow {
    corners: [u32; 3],
    bary: [f64; 3],
}

/// A piece holding no joint, carried by one bone.
#[derive(Debug, Clone)]
struct AttachedPiece {
    vertices: Vec<u32>,
    bone: usize,
    /// The length the bone's stretch is measured over for this piece (see
    /// [`stretched_transform`]): the bone's, or the farthest vertex's
    /// distance from the bone's parent joint if that is longer.
    reach: f64,
}

/// A bone's `A_b` with its stretch measured over `reach` instead of its own
/// rest length: the rotation of the rest direction onto the posed one,
/// times `k = (reach + l − l̄)/reach` along the bone and `s·k` across it
/// (`l̄`, `l` the rest and posed lengths). With `reach = l̄` this is the
/// virtual-joint construction's `A_b` (`k = l/l̄`); a longer reach keeps the
/// stretch's displacement over the reach to the joints' own, `l − l̄`.
/// Why: a bone much shorter than what it carries (a joint a hair from its
/// parent) turned `l/l̄` into a scale of 1e6 and more, applied to triangles
/// and pieces far larger than the bone: the mesh flew off. A bone posed to
/// zero length keeps its rest direction.
fn stretched_transform(rest: DVec2, posed: DVec2, reach: f64, across: f64) -> DMat2 {
    let (rest_length, length) = (rest.length(), posed.length());
    let k = (reach + length - rest_length) / reach;
    let from = rest / rest_length;
    let to = if length > 0.0 { posed / length } else { from };
    // k (to ⊗ from + s to⊥ ⊗ from⊥), column by column.
    let column = |x: f64, y: f64| (to * x + to.perp() * (across * y)) * k;
    DMat2::from_cols(column(from.x, from.perp().x), column(from.y, from.perp().y))
}

/// The registered deformer for one rest mesh and skeleton. See the module
/// docs for the phases.
#[derive(Debug)]
pub struct ShapeAware {
    skeleton: Skeleton,
    params: SkeletonParams,
    rest: Vec<DVec2>,
    /// Unknown index → mesh vertex (the factor's fill-reducing order).
    unknown_vertex: Vec<u32>,
    bone_triangles: Vec<StitchTriangle>,
    free_triangles: Vec<StitchTriangle>,
    /// The mesh triangle of each, to re-weight.
    bone_mesh_triangles: Vec<u32>,
    free_mesh_triangles: Vec<u32>,
    /// The free triangles again, four to a block for the fit's SIMD lanes.
    free_lanes: FreeLanes,
    /// Per unknown, the free triangles it is a corner of, with that
    /// corner's `3w_t (v̄ − c̄)`: the right-hand side gathered vertex by
    /// vertex.
    free_corners: Packed,
    /// Per free triangle, its current rotation as (cos, sin), padded to
    /// whole blocks of [`LANES`].
    rotations: Vec<DVec2>,
    /// Per free triangle, the bone passing nearest its rest centroid.
    free_bone: Vec<u32>,
    /// Per bone, the rotation of its rest direction onto its posed one.
    bone_rotations: Vec<DVec2>,
    joint_rows: Vec<JointRow>,
    attached: Vec<AttachedPiece>,
    /// Per mesh triangle, the bone it takes its transform from (`u32::MAX`
    /// when no bone crosses it).
    triangle_bone: Vec<u32>,
    /// Per bone, the mesh triangles it crosses.
    crossed: Vec<Vec<u32>>,
    /// Per bone, `[p̄₂ − p̄₁, p̄₃ − p̄₁]⁻¹`.
    rest_frame_inverse: Vec<DMat2>,
    /// Per bone, the length its stretch is measured over: its rest length,
    /// or the longest edge of a triangle it crosses if that is longer.
    reach: Vec<f64>,
    pattern: UpperPattern,
    mesh_weights: Vec<f64>,
    factor: RealCholesky,
    /// The factor for the stitches' solves, when it is simplicial.
    pairs: Option<PairSolve>,
    // Frame state, sized at registration.
    posed_joints: Vec<DVec2>,
    fk_joints: Vec<DVec2>,
    bone_transforms: Vec<DMat2>,
    /// The last stitch, in unknown order.
    solution: Vec<DVec2>,
    /// The next stitch's right-hand side, solved in place.
    rhs: Vec<DVec2>,
    /// The bone triangles' and joints' share of the right-hand side, fixed
    /// within a frame.
    fixed_rhs: Vec<DVec2>,
    pose: Vec<DVec2>,
    energies: Vec<f64>,
}

/// Whether segment `ab` meets the closed counter-clockwise triangle `tri`:
/// no separating axis among the triangle's edge normals, the segment's
/// normal and the segment's direction (the shapes are convex).
fn segment_meets_triangle(a: DVec2, b: DVec2, tri: [DVec2; 3]) -> bool {
    for k in 0..3 {
        let (p, q) = (tri[k], tri[(k + 1) % 3]);
        let edge = q - p;
        if edge.perp_dot(a - p) < 0.0 && edge.perp_dot(b - p) < 0.0 {
            return false;
        }
    }
    let d = b - a;
    let sides = tri.map(|v| d.perp_dot(v - a));
    if sides.iter().all(|&s| s > 0.0) || sides.iter().all(|&s| s < 0.0) {
        return false;
    }
    let along = tri.map(|v| d.dot(v - a));
    let length2 = d.length_squared();
    !(along.iter().all(|&s| s < 0.0) || along.iter().all(|&s| s > length2))
}

/// `M = Σ_t w_t L_t + w_p Σ_j C_jᵀ C_j` over `pattern`, factored.
fn assemble_and_factor<'a>(
    pattern: &UpperPattern,
    triangles: impl Iterator<Item = &'a StitchTriangle>,
    joint_rows: &[JointRow],
    joint_weight: f64,
) -> Result<RealCholesky, SkeletonError> {
    let mut values = vec![0.0; pattern.len()];
    for triangle in triangles {
        let w = triangle.weight3 / 3.0;
        for k in 0..3 {
            let (i, j) = (
                triangle.corners[k] as usize,
                triangle.corners[(k + 1) % 3] as usize,
            );
            values[pattern.position(i, i)] += w;
            values[pattern.position(j, j)] += w;
            values[pattern.position(i, j)] -= w;
        }
    }
    for row in joint_rows {
        for a in 0..3 {
            for b in a..3 {
                let (i, j) = (row.corners[a] as usize, row.corners[b] as usize);
                values[pattern.position(i, j)] += joint_weight * row.bary[a] * row.bary[b];
            }
        }
    }
    Ok(RealCholesky::new(pattern, &values)?)
}

/// The free triangles in blocks of [`LANES`], by coordinate: corners, the
/// first two rest corners about the centroid (`r̄₀`, `r̄₁`; `r̄₂ = −r̄₀ − r̄₁`),
/// `3w_t` and `Σ|r̄|²`. Padding lanes have weight 0 and corners 0.
#[derive(Debug, Clone, Default)]
struct FreeLanes {
    /// The number of unknowns, which every corner is below.
    unknowns: usize,
    corners: Vec<[[u32; LANES]; 3]>,
    /// `r̄₀.x, r̄₀.y, r̄₁.x, r̄₁.y`.
    rest: Vec<[[f64; LANES]; 4]>,
    weight3: Vec<[f64; LANES]>,
    rest_spread: Vec<[f64; LANES]>,
}

impl FreeLanes {
    fn new(triangles: &[StitchTriangle], unknowns: usize) -> FreeLanes {
        assert!(
            triangles
                .iter()
                .all(|t| t.corners.iter().all(|&c| (c as usize) < unknowns)),
            "free triangle corner out of range"
        );
        let blocks = triangles.len().div_ceil(LANES);
        let mut out = FreeLanes {
            unknowns,
            ..FreeLanes::default()
        };
        for b in 0..blocks {
            let t = |l: usize| triangles.get(b * LANES + l);
            out.corners.push(std::array::from_fn(|k| {
                std::array::from_fn(|l| t(l).map_or(0, |t| t.corners[k]))
            }));
            out.rest.push(std::array::from_fn(|q| {
                std::array::from_fn(|l| {
                    t(l).map_or(0.0, |t| {
                        let r = t.centred[q / 2];
                        if q % 2 == 0 { r.x } else { r.y }
                    })
                })
            }));
            out.weight3
                .push(std::array::from_fn(|l| t(l).map_or(0.0, |t| t.weight3)));
            out.rest_spread.push(std::array::from_fn(|l| {
                t(l).map_or(0.0, |t| {
                    t.rest_corners().iter().map(|r| r.length_squared()).sum()
                })
            }));
        }
        out
    }
}

/// Per unknown (`n` of them), the free triangles it is a corner of and that
/// corner's `3w_t r̄`, in triangle order.
fn free_corners(triangles: &[StitchTriangle], n: usize) -> Packed {
    let mut lists: Vec<Vec<(u32, DVec2)>> = vec![Vec::new(); n];
    for (i, t) in triangles.iter().enumerate() {
        let r = t.rest_corners();
        for k in 0..3 {
            lists[t.corners[k] as usize].push((i as u32, r[k] * t.weight3));
        }
    }
    Packed::new(&lists, triangles.len())
}

/// The free triangles' share of the stitching energy under their current
/// rotations, and with `fit` the fit sums `(d, c)` into `rotations`, four
/// triangles at a time. The centroid drops out of the fit (`Σ r̄ = 0`):
/// `d = r̄₀·(p₀ − p₂) + r̄₁·(p₁ − p₂)`, likewise `c`, and `Σ|p − c̄|²` is a
/// third of the squared side lengths' sum.
struct FitTriangles<'a> {
    lanes: &'a FreeLanes,
    x: &'a [DVec2],
    rotations: &'a mut [DVec2],
    fit: bool,
}

impl pulp::WithSimd for FitTriangles<'_> {
    type Output = f64;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> f64 {
        let FreeLanes {
            unknowns: _,
            ref corners,
            ref rest,
            ref weight3,
            ref rest_spread,
        } = *self.lanes;
        let x = &self.x[..self.lanes.unknowns];
        let rotations = &mut self.rotations[..corners.len() * LANES];
        let mut energy = [0.0; LANES];
        let blocks = corners
            .iter()
            .zip(rest)
            .zip(weight3)
            .zip(rest_spread)
            .zip(rotations.chunks_exact_mut(LANES));
        for ((((corners, r), w3), spread0), rotation) in blocks {
            // SAFETY: `FreeLanes::new` checked every corner is below
            // `unknowns`, the length of `x`.
            let p: [[DVec2; LANES]; 3] = std::array::from_fn(|k| {
                std::array::from_fn(|l| unsafe { *x.get_unchecked(corners[k][l] as usize) })
            });
            let px: [[f64; LANES]; 3] = std::array::from_fn(|k| std::array::from_fn(|l| p[k][l].x));
            let py: [[f64; LANES]; 3] = std::array::from_fn(|k| std::array::from_fn(|l| p[k][l].y));
            let rx: [f64; LANES] = std::array::from_fn(|l| rotation[l].x);
            let ry: [f64; LANES] = std::array::from_fn(|l| rotation[l].y);
            let (mut d, mut c) = ([0.0; LANES], [0.0; LANES]);
            for l in 0..LANES {
                let (d0x, d0y) = (px[0][l] - px[2][l], py[0][l] - py[2][l]);
                let (d1x, d1y) = (px[1][l] - px[2][l], py[1][l] - py[2][l]);
                let (ex, ey) = (d0x - d1x, d0y - d1y);
                d[l] = (r[0][l] * d0x + r[1][l] * d0y) + (r[2][l] * d1x + r[3][l] * d1y);
                c[l] = (r[0][l] * d0y - r[1][l] * d0x) + (r[2][l] * d1y - r[3][l] * d1x);
                let sides = (d0x * d0x + d0y * d0y) + (d1x * d1x + d1y * d1y) + (ex * ex + ey * ey);
                let spread = sides * (1.0 / 3.0) + spread0[l];
                energy[l] += w3[l] * (spread - 2.0 * (rx[l] * d[l] + ry[l] * c[l]));
            }
            if self.fit {
                for l in 0..LANES {
                    rotation[l] = DVec2::new(d[l], c[l]);
                }
            }
        }
        (energy[0] + energy[1]) + (energy[2] + energy[3])
    }
}

/// `out = fixed + Σ_t R_t (3w_t r̄)` per unknown, over its free triangles,
/// four unknowns at a time.
struct GatherRotated<'a> {
    packed: &'a Packed,
    rotations: &'a [DVec2],
    fixed: &'a [DVec2],
    out: &'a mut [DVec2],
}

impl pulp::WithSimd for GatherRotated<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let n = self.packed.rows;
        for b in 0..self.packed.start.len().saturating_sub(1) {
            let at = b * LANES;
            let (sx, sy) = self.packed.turned_sums(b, self.rotations);
            for l in 0..LANES.min(n - at) {
                self.out[at + l] = self.fixed[at + l] + DVec2::new(sx[l], sy[l]);
            }
        }
    }
}

/// Per bone, the length its stretch is measured over: at least the bone
/// and the longest edge of the triangles it carries (see
/// `stretched_transform`).
fn bone_reach(
    segments: &[(DVec2, DVec2)],
    crossed: &[Vec<u32>],
    triangles: &[[u32; 3]],
    rest: &[DVec2],
) -> Vec<f64> {
    segments
        .iter()
        .zip(crossed)
        .map(|(&(a, b), carried)| {
            let mut reach = a.distance(b);
            for &t in carried {
                let p = triangles[t as usize].map(|v| rest[v as usize]);
                for k in 0..3 {
                    reach = reach.max(p[k].distance(p[(k + 1) % 3]));
                }
            }
            reach
        })
        .collect()
}

/// The bone of `segments` nearest `p`: its distance and index (the
/// first of equals).
fn nearest_bone(segments: &[(DVec2, DVec2)], p: DVec2) -> (f64, usize) {
    let mut best = (f64::INFINITY, 0);
    for (bone, &(a, b)) in segments.iter().enumerate() {
        let distance = segment_distance(p, a, b);
        if distance < best.0 {
            best = (distance, bone);
        }
    }
    best
}

/// The triangles each bone (segment) crosses, and each triangle's bone
/// (`u32::MAX`: none): a triangle several bones cross takes the bone
/// passing nearest its centroid.
fn bones_triangles(
    segments: &[(DVec2, DVec2)],
    triangles: &[[u32; 3]],
    rest: &[DVec2],
) -> (Vec<Vec<u32>>, Vec<u32>) {
    let mut crossed: Vec<Vec<u32>> = vec![Vec::new(); segments.len()];
    let mut triangle_bone = vec![u32::MAX; triangles.len()];
    for (t, tri) in triangles.iter().enumerate() {
        let corners = tri.map(|v| rest[v as usize]);
        let lo = corners[0].min(corners[1]).min(corners[2]);
        let hi = corners[0].max(corners[1]).max(corners[2]);
        let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
        let mut nearest = f64::INFINITY;
        for (bone, &(a, b)) in segments.iter().enumerate() {
            if a.max(b).cmplt(lo).any() || a.min(b).cmpgt(hi).any() {
                continue;
            }
            if segment_meets_triangle(a, b, corners) {
                crossed[bone].push(t as u32);
                let distance = segment_distance(centroid, a, b);
                if distance < nearest {
                    nearest = distance;
                    triangle_bone[t] = bone as u32;
                }
            }
        }
    }
    (crossed, triangle_bone)
}

/// A skeleton mesh's pieces sorted: those holding a joint are solved,
/// the others attached to their nearest bone.
struct SolvedPieces {
    /// The solved pieces' vertices, piece by piece.
    vertices: Vec<u32>,
    /// The solved pieces' triangles, piece by piece.
    triangles: Vec<u32>,
    /// Each mesh vertex's index in `vertices` (`u32::MAX`: attached).
    local: Vec<u32>,
    /// The pieces that hold no joint.
    attached: Vec<AttachedPiece>,
}

/// Sorts `mesh`'s pieces by whether a joint (at `locations`) is in them.
fn solved_pieces(
    mesh: &Mesh,
    locations: &[puppetry_mesh::Location],
    segments: &[(DVec2, DVec2)],
) -> SolvedPieces {
    let rest = mesh.vertices();
    let triangles = mesh.triangles();
    let pieces = mesh.pieces();
    let mut piece_of_vertex = vec![0usize; rest.len()];
    for (p, piece) in pieces.iter().enumerate() {
        for &v in &piece.vertices {
            piece_of_vertex[v as usize] = p;
        }
    }
    let mut solved = vec![false; pieces.len()];
    for location in locations {
        let v = triangles[location.triangle as usize][0];
        solved[piece_of_vertex[v as usize]] = true;
    }
    let mut sorted = SolvedPieces {
        vertices: Vec::new(),
        triangles: Vec::new(),
        local: vec![u32::MAX; rest.len()],
        attached: Vec::new(),
    };
    for (p, piece) in pieces.into_iter().enumerate() {
        if solved[p] {
            for &v in &piece.vertices {
                sorted.local[v as usize] = sorted.vertices.len() as u32;
                sorted.vertices.push(v);
            }
            sorted.triangles.extend(piece.triangles);
        } else {
            let bone = piece
                .vertices
                .iter()
                .map(|&v| nearest_bone(segments, rest[v as usize]))
                .fold(
                    (f64::INFINITY, 0),
                    |best, b| if b.0 < best.0 { b } else { best },
                )
                .1;
            let (a, b) = segments[bone];
            let reach = piece
                .vertices
                .iter()
                .map(|&v| rest[v as usize].distance(a))
                .fold(a.distance(b), f64::max);
            sorted.attached.push(AttachedPiece {
                vertices: piece.vertices,
                bone,
                reach,
            });
        }
    }
    sorted
}

/// The solved triangles (`solved`) as the stitching sees them, their
/// corners the unknowns `slot` gives: those a bone carries (stiffer by
/// `bone_weight`), then the free ones, each with its mesh index.
fn stitch_triangles(
    mesh: &Mesh,
    solved: &[u32],
    slot: &[u32],
    triangle_bone: &[u32],
    bone_weight: f64,
) -> [Vec<(u32, StitchTriangle)>; 2] {
    let mut bone_triangles = Vec::new();
    let mut free_triangles = Vec::new();
    for &t in solved {
        let tri = mesh.triangles()[t as usize];
        let corners = tri.map(|v| slot[v as usize]);
        let points = tri.map(|v| mesh.vertices()[v as usize]);
        let centroid = (points[0] + points[1] + points[2]) / 3.0;
        let bone = triangle_bone[t as usize];
        let stiffness = if bone == u32::MAX { 1.0 } else { bone_weight };
        let triangle = StitchTriangle {
            corners,
            bone,
            weight3: 3.0 * stiffness * mesh.weights()[t as usize],
            centred: [points[0] - centroid, points[1] - centroid],
        };
        if bone == u32::MAX {
            free_triangles.push((t, triangle));
        } else {
            bone_triangles.push((t, triangle));
        }
    }
    [bone_triangles, free_triangles]
}

/// The stitching's unknowns: the solved vertices in a fill-reducing
/// order, and where each mesh vertex went.
struct Unknowns {
    /// The mesh vertex of each unknown.
    vertex: Vec<u32>,
    /// Each mesh vertex's unknown (`u32::MAX`: not solved).
    slot: Vec<u32>,
    /// The stitching matrix's pattern over them.
    pattern: UpperPattern,
}

/// Orders the solved vertices (`vertices`, numbered by `local`) so the
/// factor of the matrix their triangles (`solved_triangles`) couple
/// fills in little.
fn unknowns(
    triangles: &[[u32; 3]],
    vertices: &[u32],
    solved_triangles: &[u32],
    local: &[u32],
) -> Result<Unknowns, SkeletonError> {
    let n = vertices.len();
    let mut edges = Vec::with_capacity(solved_triangles.len() * 3);
    for &t in solved_triangles {
        let tri = triangles[t as usize].map(|v| local[v as usize]);
        for k in 0..3 {
            edges.push((tri[k], tri[(k + 1) % 3]));
        }
    }
    let order = fill_reducing_order(n, &edges)?;
    let mut slot = vec![u32::MAX; local.len()];
    let unknown_vertex: Vec<u32> = order.iter().map(|&old| vertices[old as usize]).collect();
    for (new, &v) in unknown_vertex.iter().enumerate() {
        slot[v as usize] = new as u32;
    }
    let edges: Vec<(u32, u32)> = edges
        .iter()
        .map(|&(a, b)| {
            (
                slot[vertices[a as usize] as usize],
                slot[vertices[b as usize] as usize],
            )
        })
        .collect();
    let pattern = UpperPattern::new(n, &edges);
    Ok(Unknowns {
        vertex: unknown_vertex,
        slot,
        pattern,
    })
}

impl ShapeAware {
    /// Registration: locates the joints, finds the bones' triangles, orders,
    /// assembles and factors the stitching matrix. The pose is the rest mesh.
    pub fn register(
        mesh: &Mesh,
        skeleton: Skeleton,
        params: SkeletonParams,
    ) -> Result<ShapeAware, SkeletonError> {
        params.check()?;
        let rest = mesh.vertices().to_vec();
        let triangles = mesh.triangles();
        let locator = Locator::new(mesh);
        let mut locations = Vec::with_capacity(skeleton.joints.len());
        for (joint, &p) in skeleton.joints.iter().enumerate() {
            let location = locator
                .locate(mesh, p)
                .ok_or(SkeletonError::JointOutsideMesh {
                    joint,
                    point: p.to_array(),
                })?;
            locations.push(location);
        }

        let bone_count = skeleton.bones.len();
        let segments: Vec<(DVec2, DVec2)> = skeleton
            .bones
            .iter()
            .map(|&[p, c]| (skeleton.joints[p], skeleton.joints[c]))
            .collect();
        let (crossed, triangle_bone) = bones_triangles(&segments, triangles, &rest);
        let SolvedPieces {
            vertices: solved_vertices,
            triangles: solved_triangles,
            local,
            attached,
        } = solved_pieces(mesh, &locations, &segments);

        let n = solved_vertices.len();
        let Unknowns {
            vertex: unknown_vertex,
            slot,
            pattern,
        } = unknowns(triangles, &solved_vertices, &solved_triangles, &local)?;

        let [mut bone_triangles, mut free_triangles] = stitch_triangles(
            mesh,
            &solved_triangles,
            &slot,
            &triangle_bone,
            params.bone_weight,
        );
        // Cache-friendly sweep order.
        for list in [&mut bone_triangles, &mut free_triangles] {
            list.sort_by_key(|(_, t)| *t.corners.iter().min().unwrap());
        }
        let (bone_mesh_triangles, bone_triangles): (Vec<u32>, Vec<StitchTriangle>) =
            bone_triangles.into_iter().unzip();
        let (free_mesh_triangles, free_triangles): (Vec<u32>, Vec<StitchTriangle>) =
            free_triangles.into_iter().unzip();
        let free_bone = free_triangles
            .iter()
            .map(|t| {
                let centroid = rest[unknown_vertex[t.corners[0] as usize] as usize] - t.centred[0];
                nearest_bone(&segments, centroid).1 as u32
            })
            .collect();
        let joint_rows: Vec<JointRow> = locations
            .iter()
            .map(|location| JointRow {
                corners: triangles[location.triangle as usize].map(|v| slot[v as usize]),
                bary: location.bary,
            })
            .collect();
        let rest_frame_inverse = segments
            .iter()
            .map(|&(a, b)| {
                let d = b - a;
                DMat2::from_cols(d, d * 0.5 + d.perp()).inverse()
            })
            .collect();
        let reach = bone_reach(&segments, &crossed, triangles, &rest);

        let factor = assemble_and_factor(
            &pattern,
            bone_triangles.iter().chain(&free_triangles),
            &joint_rows,
            params.joint_weight,
        )?;
        let joint_count = skeleton.joints.len();
        Ok(ShapeAware {
            params,
            rest: rest.clone(),
            unknown_vertex,
            // Whole blocks of lanes: the padding lanes' rotations are
            // computed (from zero fits: the identity) and never read.
            rotations: vec![DVec2::X; free_triangles.len().div_ceil(LANES) * LANES],
            free_lanes: FreeLanes::new(&free_triangles, n),
            free_corners: free_corners(&free_triangles, n),
            free_bone,
            bone_rotations: vec![DVec2::X; bone_count],
            bone_triangles,
            free_triangles,
            bone_mesh_triangles,
            free_mesh_triangles,
            joint_rows,
            attached,
            triangle_bone,
            crossed,
            rest_frame_inverse,
            reach,
            pairs: factor.pair_solve(),
            factor,
            pattern,
            mesh_weights: mesh.weights().to_vec(),
            posed_joints: skeleton.joints.clone(),
            fk_joints: vec![DVec2::ZERO; joint_count],
            bone_transforms: vec![DMat2::IDENTITY; bone_count],
            solution: vec![DVec2::ZERO; n],
            rhs: vec![DVec2::ZERO; n],
            fixed_rhs: vec![DVec2::ZERO; n],
            pose: rest,
            energies: vec![0.0; params.rounds + 1],
            skeleton,
        })
    }

    /// Live stiffness painting: replaces the per-triangle weights (one per
    /// mesh triangle, within the mesh's weight range) and refactors.
    pub fn set_weights(&mut self, weights: &[f64]) -> Result<(), SkeletonError> {
        if weights.len() != self.mesh_weights.len() {
            return Err(SkeletonError::WeightCount {
                expected: self.mesh_weights.len(),
                got: weights.len(),
            });
        }
        if let Some(index) = weights
            .iter()
            .position(|w| !(MIN_WEIGHT..=MAX_WEIGHT).contains(w))
        {
            return Err(SkeletonError::BadWeight {
                index,
                value: weights[index],
            });
        }
        let old = std::mem::replace(&mut self.mesh_weights, weights.to_vec());
        let bone_weight = self.params.bone_weight;
        let reweigh = |list: &mut [StitchTriangle], of: &[u32], stiffness: f64, weights: &[f64]| {
            for (t, &mesh_triangle) in list.iter_mut().zip(of) {
                t.weight3 = 3.0 * stiffness * weights[mesh_triangle as usize];
            }
        };
        reweigh(
            &mut self.bone_triangles,
            &self.bone_mesh_triangles,
            bone_weight,
            weights,
        );
        reweigh(
            &mut self.free_triangles,
            &self.free_mesh_triangles,
            1.0,
            weights,
        );
        let factor = assemble_and_factor(
            &self.pattern,
            self.bone_triangles.iter().chain(&self.free_triangles),
            &self.joint_rows,
            self.params.joint_weight,
        );
        match factor {
            Ok(factor) => {
                self.pairs = factor.pair_solve();
                self.factor = factor;
                self.free_lanes = FreeLanes::new(&self.free_triangles, self.rhs.len());
                self.free_corners = free_corners(&self.free_triangles, self.rhs.len());
                Ok(())
            }
            Err(e) => {
                reweigh(
                    &mut self.bone_triangles,
                    &self.bone_mesh_triangles,
                    bone_weight,
                    &old,
                );
                reweigh(
                    &mut self.free_triangles,
                    &self.free_mesh_triangles,
                    1.0,
                    &old,
                );
                self.mesh_weights = old;
                Err(e)
            }
        }
    }

    /// Free mode: deforms the mesh to the posed `joints` (one per skeleton
    /// joint) and returns the vertex positions (mesh order). Does not
    /// allocate.
    pub fn update(&mut self, joints: &[DVec2]) -> Result<&[DVec2], SkeletonError> {
        if joints.len() != self.posed_joints.len() {
            return Err(SkeletonError::JointCount {
                expected: self.posed_joints.len(),
                got: joints.len(),
            });
        }
        if let Some(joint) = joints.iter().position(|p| !finite_point(*p)) {
            return Err(SkeletonError::JointNotFinite { joint });
        }
        self.posed_joints.copy_from_slice(joints);
        self.solve_frame();
        Ok(&self.pose)
    }

    /// FK mode: [`ShapeAware::update`] with the joints of `pose`. Does not
    /// allocate.
    pub fn update_pose(&mut self, pose: &Pose) -> Result<&[DVec2], SkeletonError> {
        self.skeleton.joints_into(pose, &mut self.fk_joints)?;
        if let Some(joint) = self.fk_joints.iter().position(|p| !finite_point(*p)) {
            return Err(SkeletonError::JointNotFinite { joint });
        }
        std::mem::swap(&mut self.posed_joints, &mut self.fk_joints);
        self.solve_frame();
        Ok(&self.pose)
    }

    fn solve_frame(&mut self) {
        let s = self.params.perpendicular_scale;
        for (bone, &[parent, child]) in self.skeleton.bones.iter().enumerate() {
            let (p1, p2) = (self.posed_joints[parent], self.posed_joints[child]);
            let d = p2 - p1;
            let rest = self.skeleton.joints[child] - self.skeleton.joints[parent];
            self.bone_transforms[bone] = if self.reach[bone] > rest.length() {
                stretched_transform(rest, d, self.reach[bone], s)
            } else {
                let virtual_joint = (p1 + p2) * 0.5 + d.perp() * s;
                DMat2::from_cols(d, virtual_joint - p1) * self.rest_frame_inverse[bone]
            };
        }
        if !self.params.warm_start && !self.params.bone_start {
            self.rotations.fill(DVec2::X);
        } else if !self.params.warm_start {
            for (bone, &[parent, child]) in self.skeleton.bones.iter().enumerate() {
                let rest = self.skeleton.joints[child] - self.skeleton.joints[parent];
                let posed = self.posed_joints[child] - self.posed_joints[parent];
                self.bone_rotations[bone] = DVec2::new(rest.dot(posed), rest.perp_dot(posed));
            }
            pulp::Arch::new().dispatch(crate::lanes::Normalise(&mut self.bone_rotations));
            for (rotation, &bone) in self.rotations.iter_mut().zip(&self.free_bone) {
                *rotation = self.bone_rotations[bone as usize];
            }
        }
        self.assemble_fixed_rhs();
        // The first right-hand side; later ones are scattered by the fit.
        self.assemble_rhs();
        let rounds = self.params.rounds;
        for round in 0..=rounds {
            match &self.pairs {
                Some(pairs) => pairs.solve(&mut self.rhs),
                None => self.factor.solve(&mut self.rhs),
            }
            std::mem::swap(&mut self.rhs, &mut self.solution);
            self.energies[round] = self.measure_and_fit(round < rounds);
        }
        for (&v, &p) in self.unknown_vertex.iter().zip(&self.solution) {
            self.pose[v as usize] = p;
        }
        for piece in &self.attached {
            let [parent, child] = self.skeleton.bones[piece.bone];
            let (from, to) = (self.skeleton.joints[parent], self.posed_joints[parent]);
            let rest = self.skeleton.joints[child] - from;
            let transform = if piece.reach > rest.length() {
                let posed = self.posed_joints[child] - to;
                stretched_transform(rest, posed, piece.reach, s)
            } else {
                self.bone_transforms[piece.bone]
            };
            for &v in &piece.vertices {
                self.pose[v as usize] = to + transform * (self.rest[v as usize] - from);
            }
        }
    }

    /// The part of the right-hand side `Σ_t 3w_t A_t (v̄ − c̄) + w_p Σ_j
    /// C_jᵀ p_j` that stays fixed through a frame's rounds: the bone
    /// triangles' and the joints'.
    fn assemble_fixed_rhs(&mut self) {
        let b = &mut self.fixed_rhs;
        b.fill(DVec2::ZERO);
        for t in &self.bone_triangles {
            let a = self.bone_transforms[t.bone as usize] * t.weight3;
            let r = t.rest_corners();
            for k in 0..3 {
                b[t.corners[k] as usize] += a * r[k];
            }
        }
        let wp = self.params.joint_weight;
        for (row, &p) in self.joint_rows.iter().zip(&self.posed_joints) {
            for k in 0..3 {
                b[row.corners[k] as usize] += p * (wp * row.bary[k]);
            }
        }
    }

    /// The stitching energy of the last stitch under the transforms it used;
    /// with `fit`, then resets each free triangle's rotation to the best fit
    /// of its rest triangle onto the stitched one (which, over a triangle,
    /// minimises exactly its share of that energy, so the energy never rises
    /// from one stitch to the next) and assembles the next right-hand side.
    fn measure_and_fit(&mut self, fit: bool) -> f64 {
        let x = &self.solution;
        let mut energy = 0.0;
        for t in &self.bone_triangles {
            let a = self.bone_transforms[t.bone as usize];
            let p = t.corners_in(x);
            let r = t.rest_corners();
            let residual: f64 = (0..3).map(|k| (p[k] - a * r[k]).length_squared()).sum();
            energy += t.weight3 * residual;
        }
        let wp = self.params.joint_weight;
        for (row, &p) in self.joint_rows.iter().zip(&self.posed_joints) {
            let at: DVec2 = (0..3)
                .map(|k| x[row.corners[k] as usize] * row.bary[k])
                .sum();
            energy += wp * (at - p).length_squared();
        }
        // With d = Σ r̄·p and c = Σ r̄×p (rest corners r̄ and stitched corners
        // p about their centroids), the residual under rotation (cos, sin) is
        // Σ|p|² + Σ|r̄|² − 2(cos·d + sin·c), and the best rotation is (d, c)
        // normalised. Three sweeps — fit sums, normalisation, right-hand
        // side — so the square roots and divisions overlap in a plain loop.
        energy += pulp::Arch::new().dispatch(FitTriangles {
            lanes: &self.free_lanes,
            x,
            rotations: &mut self.rotations,
            fit,
        });
        if fit {
            // A collapsed triangle fits no rotation: rest orientation.
            pulp::Arch::new().dispatch(crate::lanes::Normalise(&mut self.rotations));
            self.assemble_rhs();
        }
        energy
    }

    /// The stitch's right-hand side for the current free rotations,
    /// vertex by vertex (`free_corners`).
    fn assemble_rhs(&mut self) {
        pulp::Arch::new().dispatch(GatherRotated {
            packed: &self.free_corners,
            rotations: &self.rotations,
            fixed: &self.fixed_rhs,
            out: &mut self.rhs,
        });
    }

    /// The deformed vertex positions (mesh order) of the last update; the
    /// rest mesh before the first.
    pub fn pose(&self) -> &[DVec2] {
        &self.pose
    }

    /// The stitching energy `E_s + w_p E_p` after each of the last update's
    /// `rounds + 1` stitches (zeros before the first update). It never rises
    /// from one entry to the next.
    pub fn energies(&self) -> &[f64] {
        &self.energies
    }

    /// The skeleton the deformer was registered with (its rest joints).
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// The tunables the deformer was registered with.
    pub fn params(&self) -> &SkeletonParams {
        &self.params
    }

    /// The posed joints of the last update (the rest joints before it).
    pub fn joints(&self) -> &[DVec2] {
        &self.posed_joints
    }

    /// Bone `bone`'s 2×2 transform `A_b` in the last update.
    pub fn bone_transform(&self, bone: usize) -> DMat2 {
        self.bone_transforms[bone]
    }

    /// The mesh triangles bone `bone` crosses (touching included).
    pub fn crossed_triangles(&self, bone: usize) -> &[u32] {
        &self.crossed[bone]
    }

    /// The bone whose transform mesh triangle `triangle` takes, if a bone
    /// crosses it (of several, the one passing nearest its centroid).
    pub fn triangle_bone(&self, triangle: usize) -> Option<usize> {
        match self.triangle_bone[triangle] {
            u32::MAX => None,
            b => Some(b as usize),
        }
    }

    /// How many connected pieces hold no joint and are carried rigidly by
    /// their nearest bone.
    pub fn attached_pieces(&self) -> usize {
        self.attached.len()
    }

    /// The bone carrying each attached piece, with the piece's vertices.
    pub fn attachments(&self) -> impl Iterator<Item = (usize, &[u32])> {
        self.attached
            .iter()
            .map(|a| (a.bone, a.vertices.as_slice()))
    }

    /// Entries of the stitching factor (its memory and per-stitch work).
    pub fn factor_entries(&self) -> usize {
        self.factor.factor_entries()
    }
}
