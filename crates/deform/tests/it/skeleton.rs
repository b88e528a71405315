//! The shape-aware skeletal deformer: rest identity, bones carrying their
//! triangles, propagation lowering the distortion, forward kinematics and
//! key-pose interpolation, stiffness, errors, several pieces, and an update
//! path that never allocates (this binary counts allocations per thread).

use puppetry_testkit::alloc;

use std::f64::consts::{FRAC_PI_2, PI};

use glam::{DMat2, DVec2};
use puppetry_deform::skeleton::{Pose, ShapeAware, Skeleton, SkeletonError, SkeletonParams};
use puppetry_mesh::Mesh;
use puppetry_testkit::gingerbread_skeleton;

/// Allocations this thread makes while running `f`.
fn allocations_in(f: impl FnOnce()) -> usize {
    alloc::count(f).1
}

fn gingerbread() -> Mesh {
    let path = puppetry_testkit::root().join("assets/gingerbread/gingerbread.mesh.json");
    Mesh::load(&path).unwrap()
}

/// A 30×6 bar with a two-bone arm along its middle: joints at x = 1, 15, 29.
fn bar_arm() -> (Mesh, Skeleton) {
    let mesh = crate::common::bar(30, 6, 30.0, 6.0);
    let skeleton = Skeleton::new(
        vec![
            DVec2::new(1.0, 3.1),
            DVec2::new(15.0, 3.1),
            DVec2::new(29.0, 3.1),
        ],
        vec![[0, 1], [1, 2]],
    )
    .unwrap();
    (mesh, skeleton)
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

fn rotation(angle: f64) -> DMat2 {
    DMat2::from_angle(angle)
}

#[test]
fn rest_joints_give_the_rest_shape() {
    for (mesh, skeleton) in [bar_arm(), (gingerbread(), gingerbread_skeleton())] {
        let rest_joints = skeleton.joints().to_vec();
        let mut deformer =
            ShapeAware::register(&mesh, skeleton, SkeletonParams::default()).unwrap();
        let pose = deformer.update(&rest_joints).unwrap();
        let error = max_distance(pose, mesh.vertices());
        assert!(
            error <= 1e-12 * mesh.size(),
            "rest joints moved the mesh by {error:e} (size {})",
            mesh.size()
        );
        // And back to rest after a bend.
        let mut bent = rest_joints.clone();
        *bent.last_mut().unwrap() += DVec2::new(1.0, 2.0);
        deformer.update(&bent).unwrap();
        let pose = deformer.update(&rest_joints).unwrap();
        assert!(max_distance(pose, mesh.vertices()) <= 1e-12 * mesh.size());
    }
}

#[test]
fn a_rotated_bone_carries_the_triangles_it_crosses() {
    let (mesh, skeleton) = bar_arm();
    let mut deformer =
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    let angle = 40f64.to_radians();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(1, angle).unwrap();
    let vertices = deformer.update_pose(&pose).unwrap().to_vec();
    assert!(
        (deformer.bone_transform(1) - rotation(angle)).abs_diff_eq(DMat2::ZERO, 1e-12),
        "A_b of a rotated bone is the rotation"
    );
    let pivot = skeleton.joints()[1];
    let rigid = |v: DVec2| pivot + rotation(angle) * (v - pivot);
    let carried: Vec<usize> = (0..mesh.triangles().len())
        .filter(|&t| deformer.triangle_bone(t) == Some(1))
        .collect();
    assert!(carried.len() >= 28, "bone 1 crosses a row of triangles");
    // The stitch is a least-squares compromise with the unrotated bone 0 at
    // the shared joint; a quarter of the bone away from it, the triangles
    // turn with the bone.
    let (mut worst, mut worst_away, mut moved) = (0.0f64, 0.0f64, 0.0f64);
    for &t in &carried {
        let corners = mesh.triangles()[t].map(|v| mesh.vertices()[v as usize]);
        let away = corners.iter().all(|c| c.distance(pivot) > 3.5);
        for v in mesh.triangles()[t] {
            let rest = mesh.vertices()[v as usize];
            let error = vertices[v as usize].distance(rigid(rest));
            worst = worst.max(error);
            if away {
                worst_away = worst_away.max(error);
            }
            moved = moved.max(rigid(rest).distance(rest));
        }
    }
    assert!(
        worst_away < 0.01 * moved,
        "bone triangles strayed {worst_away} from the rigid rotation (moved {moved})"
    );
    assert!(
        worst < 0.05 * moved,
        "{worst} near the joint (moved {moved})"
    );
    // Away from the joint, bone 0's triangles stay put.
    for t in (0..mesh.triangles().len()).filter(|&t| deformer.triangle_bone(t) == Some(0)) {
        for v in mesh.triangles()[t] {
            let rest = mesh.vertices()[v as usize];
            if rest.x < 8.0 {
                assert!(vertices[v as usize].distance(rest) < 0.03 * moved);
            }
        }
    }
}

#[test]
fn propagation_never_raises_the_distortion_and_lowers_it_overall() {
    let mesh = gingerbread();
    let skeleton = gingerbread_skeleton();
    // The paper's propagation: 12 rounds from the identity.
    let paper = SkeletonParams {
        rounds: 12,
        bone_start: false,
        ..SkeletonParams::default()
    };
    let mut deformer = ShapeAware::register(&mesh, skeleton.clone(), paper).unwrap();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(4, 1.0).unwrap(); // left upper arm up
    pose.rotate_joint(10, -0.6).unwrap(); // left thigh
    pose.rotate_joint(2, 0.4).unwrap(); // head tilt
    deformer.update_pose(&pose).unwrap();
    let energies = deformer.energies().to_vec();
    assert_eq!(energies.len(), paper.rounds + 1);
    for pair in energies.windows(2) {
        assert!(
            pair[1] <= pair[0] * (1.0 + 1e-9),
            "energy rose between rounds: {energies:?}"
        );
    }
    assert!(
        energies[energies.len() - 1] < 0.5 * energies[0],
        "propagation barely helped: {energies:?}"
    );
    // More rounds go further.
    let params = SkeletonParams {
        rounds: 40,
        ..paper
    };
    let mut longer = ShapeAware::register(&mesh, skeleton, params).unwrap();
    longer.update_pose(&pose).unwrap();
    assert!(longer.energies()[40] < energies[12]);
    assert_eq!(longer.energies()[12], energies[12]);
}

#[test]
fn starting_from_the_bones_goes_further_per_round() {
    // A held pose with a limb turned a full radian: the hard case for the
    // default's fewer rounds (docs/rigs.md has the curves).
    let mesh = gingerbread();
    let skeleton = gingerbread_skeleton();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(4, 1.0).unwrap();
    pose.rotate_joint(10, -0.6).unwrap();
    pose.rotate_joint(2, 0.4).unwrap();
    let energies = |params: SkeletonParams| {
        let mut d = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
        d.update_pose(&pose).unwrap();
        d.energies().to_vec()
    };
    let rounds = 12;
    let from_bones = energies(SkeletonParams {
        rounds,
        ..SkeletonParams::default()
    });
    let paper = energies(SkeletonParams {
        rounds,
        bone_start: false,
        ..SkeletonParams::default()
    });
    // Every round ends lower from the bones than from the identity.
    for (k, (ours, theirs)) in from_bones.iter().zip(&paper).enumerate() {
        assert!(ours < theirs, "round {k}: {ours} vs {theirs}");
    }
    // The default rounds end close to the paper's 12 even here.
    let defaults = SkeletonParams::default().rounds;
    assert!(
        from_bones[defaults] <= paper[rounds] * 1.015,
        "{} after {defaults} rounds vs {} after {rounds}",
        from_bones[defaults],
        paper[rounds]
    );
}

#[test]
fn warm_start_goes_further_on_a_held_pose() {
    let mesh = gingerbread();
    let skeleton = gingerbread_skeleton();
    let params = SkeletonParams {
        warm_start: true,
        ..SkeletonParams::default()
    };
    let mut deformer = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(7, -1.0).unwrap();
    deformer.update_pose(&pose).unwrap();
    let first = *deformer.energies().last().unwrap();
    deformer.update_pose(&pose).unwrap();
    let second = *deformer.energies().last().unwrap();
    assert!(second < first, "{second} vs {first}");
}

#[test]
fn fk_and_free_modes_agree() {
    let mesh = gingerbread();
    let skeleton = gingerbread_skeleton();
    let params = SkeletonParams::default();
    let mut fk = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
    let mut free = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(3, 0.5).unwrap();
    pose.rotate_joint(4, -0.7).unwrap();
    pose.rotate_joint(12, 0.3).unwrap();
    pose.roots[0] += DVec2::new(10.0, -4.0);
    pose.lengths[1] *= 1.2;
    let by_fk = fk.update_pose(&pose).unwrap().to_vec();
    let joints = skeleton.joints_of(&pose).unwrap();
    let by_joints = free.update(&joints).unwrap();
    assert_eq!(by_fk, by_joints);
    assert_eq!(fk.joints(), joints.as_slice());
    // The posed mesh really moved.
    assert!(max_distance(&by_fk, mesh.vertices()) > 10.0);
}

#[test]
fn rotating_a_joint_in_fk_mode_moves_the_chain_below() {
    let skeleton = gingerbread_skeleton();
    let rest = skeleton.joints().to_vec();
    let mut pose = skeleton.rest_pose();
    // Bone 3 is the left collar (chest → shoulder); 4 and 5 hang off it.
    pose.rotate_joint(3, 0.3).unwrap();
    let joints = skeleton.joints_of(&pose).unwrap();
    let pivot = rest[1];
    for j in [4, 5, 6] {
        let expected = pivot + rotation(0.3) * (rest[j] - pivot);
        assert!(joints[j].distance(expected) < 1e-9, "joint {j}");
    }
    for j in (0..rest.len()).filter(|j| ![4, 5, 6].contains(j)) {
        assert!(
            joints[j].distance(rest[j]) < 1e-9,
            "joint {j} should not move"
        );
    }
    // Aiming the forearm at a point puts the hand on the ray toward it.
    let mut aimed = skeleton.rest_pose();
    let target = rest[5] + DVec2::new(0.0, 100.0);
    skeleton.aim(&mut aimed, 5, target).unwrap();
    let joints = skeleton.joints_of(&aimed).unwrap();
    let direction = (joints[6] - joints[5]).normalize();
    assert!(direction.distance(DVec2::Y) < 1e-9);
    assert!((joints[6].distance(joints[5]) - rest[6].distance(rest[5])).abs() < 1e-9);
    // Aiming a deep bone of an already-bent chain.
    skeleton.aim(&mut pose, 5, target).unwrap();
    let joints = skeleton.joints_of(&pose).unwrap();
    let direction = (joints[6] - joints[5]).normalize();
    let wanted = (target - joints[5]).normalize();
    assert!(direction.distance(wanted) < 1e-9);
}

#[test]
fn pose_of_and_joints_of_round_trip() {
    let skeleton = gingerbread_skeleton();
    let rest = skeleton.rest_pose();
    let back = skeleton.joints_of(&rest).unwrap();
    assert!(max_distance(&back, skeleton.joints()) < 1e-10);
    for seed in 0..5 {
        let mut pose = rest.clone();
        for (b, angle) in pose.angles.iter_mut().enumerate() {
            *angle += ((seed * 31 + b * 17) as f64).sin() * 2.5;
        }
        for (b, length) in pose.lengths.iter_mut().enumerate() {
            *length *= 1.0 + 0.3 * ((seed + b) as f64).cos();
        }
        pose.roots[0] = DVec2::new(seed as f64 * 7.0, -3.0);
        let joints = skeleton.joints_of(&pose).unwrap();
        let again = skeleton.pose_of(&joints).unwrap();
        for (a, b) in pose.angles.iter().zip(&again.angles) {
            let difference = (a - b).rem_euclid(2.0 * PI);
            assert!(difference.min(2.0 * PI - difference) < 1e-9, "{a} vs {b}");
        }
        for (a, b) in pose.lengths.iter().zip(&again.lengths) {
            assert!((a - b).abs() < 1e-9);
        }
        assert!(again.roots[0].distance(pose.roots[0]) < 1e-12);
        assert!(max_distance(&skeleton.joints_of(&again).unwrap(), &joints) < 1e-9);
    }
}

#[test]
fn key_poses_interpolate_angles_not_positions() {
    let skeleton = gingerbread_skeleton();
    let a = skeleton.rest_pose();
    let mut b = a.clone();
    b.rotate_joint(4, 2.4).unwrap(); // left upper arm swings 2.4 rad
    b.lengths[5] *= 1.5;
    b.roots[0] += DVec2::new(20.0, 0.0);
    let at = |t| Pose::interpolate(&a, &b, t).unwrap();
    assert_eq!(at(0.0), a);
    let end = at(1.0);
    for (x, y) in end.angles.iter().zip(&b.angles) {
        assert!((x - y).abs() < 1e-12);
    }
    assert_eq!(end.lengths, b.lengths);
    assert_eq!(end.roots, b.roots);
    let half = at(0.5);
    assert!((half.angles[4] - (a.angles[4] + 1.2)).abs() < 1e-12);
    assert!((half.lengths[5] - a.lengths[5] * 1.25).abs() < 1e-12);
    assert_eq!(half.roots[0], a.roots[0] + DVec2::new(10.0, 0.0));
    // Not a joint-position average: the elbow keeps its distance from the
    // shoulder, which a straight average of positions would shorten.
    let mid = skeleton.joints_of(&half).unwrap();
    let (ja, jb) = (
        skeleton.joints_of(&a).unwrap(),
        skeleton.joints_of(&b).unwrap(),
    );
    let upper_arm = ja[5].distance(ja[4]);
    assert!((mid[5].distance(mid[4]) - upper_arm).abs() < 1e-9);
    let averaged = (ja[5] + jb[5]) / 2.0 - (ja[4] + jb[4]) / 2.0;
    assert!(averaged.length() < 0.5 * upper_arm);
    // The shorter arc: from +170° to −170° passes through 180°.
    let mut c = a.clone();
    let mut d = a.clone();
    c.angles[0] = 170f64.to_radians();
    d.angles[0] = -170f64.to_radians();
    let halfway = Pose::interpolate(&c, &d, 0.5).unwrap().angles[0];
    assert!((halfway.abs() - PI).abs() < 1e-9, "{halfway}");
    // Poses of different skeletons do not mix.
    let mut short = a.clone();
    short.angles.pop();
    assert!(matches!(
        Pose::interpolate(&a, &short, 0.5),
        Err(SkeletonError::PoseShape {
            field: "angles",
            ..
        })
    ));
}

#[test]
fn stiffness_weights_change_the_result() {
    let mesh = gingerbread();
    let skeleton = gingerbread_skeleton();
    let params = SkeletonParams::default();
    let mut deformer = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(3, 0.8).unwrap();
    pose.rotate_joint(6, -0.8).unwrap();
    let soft = deformer.update_pose(&pose).unwrap().to_vec();
    // Stiffen the head's free triangles (above the neck joint).
    let neck = skeleton.joints()[2].y;
    let weights: Vec<f64> = mesh
        .triangles()
        .iter()
        .map(|t| {
            if mesh.vertices()[t[0] as usize].y > neck {
                1000.0
            } else {
                1.0
            }
        })
        .collect();
    deformer.set_weights(&weights).unwrap();
    let stiff = deformer.update_pose(&pose).unwrap().to_vec();
    assert!(max_distance(&soft, &stiff) > 1e-3);
    // The same as a deformer registered with those weights in the mesh.
    let mut weighted_mesh = mesh.clone();
    weighted_mesh.set_weights(weights.clone()).unwrap();
    let mut fresh = ShapeAware::register(&weighted_mesh, skeleton, params).unwrap();
    let again = fresh.update_pose(&pose).unwrap();
    assert!(max_distance(again, &stiff) < 1e-9 * mesh.size());
    // Bad weights are refused and change nothing.
    let mut bad = weights.clone();
    bad[7] = f64::NAN;
    assert!(matches!(
        deformer.set_weights(&bad),
        Err(SkeletonError::BadWeight { index: 7, .. })
    ));
    assert!(matches!(
        deformer.set_weights(&weights[1..]),
        Err(SkeletonError::WeightCount { .. })
    ));
    assert_eq!(deformer.update_pose(&pose).unwrap(), stiff.as_slice());
}

#[test]
fn perpendicular_scale_widens_the_bone_triangles() {
    let (mesh, skeleton) = bar_arm();
    let params = SkeletonParams {
        perpendicular_scale: 2.0,
        ..SkeletonParams::default()
    };
    let mut deformer = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
    deformer.update(skeleton.joints()).unwrap();
    let a = deformer.bone_transform(0);
    assert!((a * DVec2::X).distance(DVec2::X) < 1e-12);
    assert!((a * DVec2::Y).distance(DVec2::Y * 2.0) < 1e-12);
    // Bones of a longer skeleton scale along themselves, uniformly by default.
    let mut plain =
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    let mut pose = skeleton.rest_pose();
    pose.lengths[0] *= 1.5;
    pose.angles[0] += FRAC_PI_2;
    plain.update_pose(&pose).unwrap();
    let expected = rotation(FRAC_PI_2) * 1.5;
    assert!((plain.bone_transform(0) - expected).abs_diff_eq(DMat2::ZERO, 1e-12));
}

#[test]
fn bad_skeletons_and_inputs_are_named() {
    let p = |x, y| DVec2::new(x, y);
    let joints = vec![p(1.0, 1.0), p(5.0, 1.0), p(9.0, 1.0)];
    let check = |bones: Vec<[usize; 2]>, joints: Vec<DVec2>| Skeleton::new(joints, bones);
    assert!(matches!(
        check(vec![[0, 1], [1, 3]], joints.clone()),
        Err(SkeletonError::BoneJointOutOfRange {
            bone: 1,
            joint: 3,
            count: 3
        })
    ));
    assert!(matches!(
        check(vec![[0, 1], [1, 1]], joints.clone()),
        Err(SkeletonError::BoneJoinsJointToItself { bone: 1, joint: 1 })
    ));
    assert!(matches!(
        check(
            vec![[0, 1], [1, 2]],
            vec![p(1.0, 1.0), p(5.0, 1.0), p(5.0, 1.0)]
        ),
        Err(SkeletonError::ZeroLengthBone { bone: 1, .. })
    ));
    assert!(matches!(
        check(vec![[0, 1], [2, 1]], joints.clone()),
        Err(SkeletonError::TwoParents {
            joint: 1,
            first: 0,
            second: 1
        })
    ));
    assert!(matches!(
        check(vec![[0, 1], [1, 2], [2, 0]], joints.clone()),
        Err(SkeletonError::TwoParents { .. }) | Err(SkeletonError::Cycle { .. })
    ));
    // A cycle hanging off nothing: 1 → 2 → 1 with 0 a separate root.
    let four = vec![p(1.0, 1.0), p(5.0, 1.0), p(9.0, 1.0), p(3.0, 4.0)];
    assert!(matches!(
        check(vec![[0, 3], [1, 2], [2, 1]], four),
        Err(SkeletonError::Cycle { bone: 1 })
    ));
    assert!(matches!(
        check(vec![[0, 1]], joints.clone()),
        Err(SkeletonError::UnusedJoint { joint: 2 })
    ));
    assert!(matches!(
        check(vec![], joints.clone()),
        Err(SkeletonError::NoBones)
    ));
    assert!(matches!(
        check(
            vec![[0, 1], [1, 2]],
            vec![p(1.0, 1.0), p(f64::NAN, 1.0), p(2.0, 2.0)]
        ),
        Err(SkeletonError::JointNotFinite { joint: 1 })
    ));

    // A joint off the mesh: the bar spans [0, 30] × [0, 6].
    let mesh = crate::common::bar(30, 6, 30.0, 6.0);
    let outside = Skeleton::new(
        vec![p(1.0, 3.0), p(15.0, 3.0), p(31.0, 3.0)],
        vec![[0, 1], [1, 2]],
    )
    .unwrap();
    let error = ShapeAware::register(&mesh, outside, SkeletonParams::default()).unwrap_err();
    assert!(matches!(
        error,
        SkeletonError::JointOutsideMesh { joint: 2, .. }
    ));
    assert!(error.to_string().contains("joint 2"), "{error}");

    let (mesh, skeleton) = bar_arm();
    let bad_params = SkeletonParams {
        joint_weight: 0.0,
        ..SkeletonParams::default()
    };
    assert!(matches!(
        ShapeAware::register(&mesh, skeleton.clone(), bad_params),
        Err(SkeletonError::BadParameter {
            name: "joint_weight",
            ..
        })
    ));
    let mut deformer =
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    assert!(matches!(
        deformer.update(&skeleton.joints()[..2]),
        Err(SkeletonError::JointCount {
            expected: 3,
            got: 2
        })
    ));
    let mut joints = skeleton.joints().to_vec();
    joints[1].y = f64::INFINITY;
    assert!(matches!(
        deformer.update(&joints),
        Err(SkeletonError::JointNotFinite { joint: 1 })
    ));
    let mut pose = skeleton.rest_pose();
    pose.lengths[1] = -1.0;
    assert!(matches!(
        deformer.update_pose(&pose),
        Err(SkeletonError::PoseNotFinite {
            field: "lengths",
            index: 1
        })
    ));
    assert!(matches!(
        pose.rotate_joint(2, 0.1),
        Err(SkeletonError::BoneOutOfRange { bone: 2, count: 2 })
    ));
}

#[test]
fn pieces_without_joints_ride_their_nearest_bone() {
    // Three 4×2 islands at x = 0, 10, 20. Joints in the first two only.
    let mesh = crate::common::islands(3);
    let skeleton = Skeleton::new(
        vec![
            DVec2::new(0.5, 1.0),
            DVec2::new(3.5, 1.0),
            DVec2::new(10.5, 1.2),
            DVec2::new(13.5, 0.8),
        ],
        vec![[0, 1], [2, 3]],
    )
    .unwrap();
    let mut deformer =
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    assert_eq!(deformer.attached_pieces(), 1);
    let (bone, vertices) = deformer.attachments().next().unwrap();
    assert_eq!(bone, 1, "the third island is nearest the second bone");
    let vertices = vertices.to_vec();
    let pieces = mesh.pieces();
    assert_eq!(vertices, pieces[2].vertices);

    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(0, 0.5).unwrap();
    pose.rotate_joint(1, -0.9).unwrap();
    pose.roots[1] += DVec2::new(2.0, 1.0);
    let posed = deformer.update_pose(&pose).unwrap().to_vec();
    let joints = skeleton.joints_of(&pose).unwrap();
    // The attached island is carried rigidly about bone 1's parent joint.
    let carry = rotation(-0.9);
    for &v in &vertices {
        let rest = mesh.vertices()[v as usize];
        let expected = joints[2] + carry * (rest - skeleton.joints()[2]);
        assert!(posed[v as usize].distance(expected) < 1e-9);
    }
    // Each solved island follows its own bone. The first bone runs along
    // its island's middle grid line and touches every triangle there, so the
    // island turns exactly with it; the second crosses its island slantwise,
    // leaving free triangles that propagation brings close to the rotation.
    for (piece, from, angle, tolerance) in [(0, 0, 0.5, 1e-9), (1, 2, -0.9, 0.01)] {
        let mut worst: f64 = 0.0;
        let mut moved: f64 = 0.0;
        for &v in &pieces[piece].vertices {
            let rest = mesh.vertices()[v as usize];
            let expected = joints[from] + rotation(angle) * (rest - skeleton.joints()[from]);
            worst = worst.max(posed[v as usize].distance(expected));
            moved = moved.max(expected.distance(rest));
        }
        assert!(
            worst <= tolerance * moved,
            "piece {piece}: {worst} off the bone's rotation (moved {moved})"
        );
    }
}

#[test]
fn updates_do_not_allocate() {
    let mesh = crate::common::islands(3);
    let skeleton = Skeleton::new(
        vec![
            DVec2::new(0.5, 1.0),
            DVec2::new(2.0, 1.0),
            DVec2::new(3.5, 1.5),
            DVec2::new(10.5, 1.0),
            DVec2::new(13.5, 1.0),
        ],
        vec![[0, 1], [1, 2], [3, 4]],
    )
    .unwrap();
    for warm_start in [false, true] {
        let params = SkeletonParams {
            warm_start,
            ..SkeletonParams::default()
        };
        let mut deformer = ShapeAware::register(&mesh, skeleton.clone(), params).unwrap();
        assert_eq!(deformer.attached_pieces(), 1);
        let mut pose = skeleton.rest_pose();
        let mut joints = vec![DVec2::ZERO; skeleton.joints().len()];
        let count = allocations_in(|| {
            for frame in 0..30 {
                pose.rotate_joint(frame % 3, 0.05).unwrap();
                if frame % 2 == 0 {
                    deformer.update_pose(&pose).unwrap();
                } else {
                    skeleton.joints_into(&pose, &mut joints).unwrap();
                    deformer.update(&joints).unwrap();
                }
            }
        });
        assert_eq!(count, 0, "update allocated");
    }
    // The counter works: registering allocates.
    let count = allocations_in(|| {
        ShapeAware::register(&mesh, skeleton.clone(), SkeletonParams::default()).unwrap();
    });
    assert!(count > 0);
}
