//! Bones for a skeleton puppet's export: what an animator edits
//! afterwards in Spine is a rig — bones, weighted vertices and bone
//! timelines — not a mesh key per frame (which stores the whole mesh each
//! frame: 36 MB for a minute).
//!
//! The take holds vertices, not joints, so the bones are fitted to the
//! vertices: each bone of the puppet's skeleton owns the rest vertices
//! nearest to it (by distance to its segment), and its motion in frame `k`
//! is the rigid transform (rotation and translation, no stretch) that best
//! carries its vertices from rest onto frame `k` (2D Procrustes, closed
//! form). Each vertex is then bound to its two nearest bones with the
//! weight that best reproduces its motion over all frames (a clamped 1D
//! least squares). The shape-aware deformer bends a puppet more smoothly
//! than two rigid bones per vertex can, so the rig reproduces the take to
//! within [`Skin::max_error`] stage units, measured over every frame and
//! vertex and reported with the export.
//!
//! Singular cases stay bounded: a bone that owns fewer than two vertices
//! (a zero-length bone, one far from the mesh) takes its parent's motion,
//! or none for a root; vertices that coincide give a zero rotation.

use glam::DVec2;

use crate::AnimatedPuppet;

/// A skeleton puppet's skeleton at rest, in stage coordinates: what the
/// export fits bones to.
#[derive(Debug, Clone, PartialEq)]
pub struct SkeletonRest {
    /// The rest joints.
    pub joints: Vec<DVec2>,
    /// Bone `b` goes from joint `bones[b][0]` (its head) to `bones[b][1]`.
    pub bones: Vec<[usize; 2]>,
    /// The bone ending at bone `b`'s head, if any (none for a root's).
    pub parents: Vec<Option<usize>>,
    /// The puppet's rest vertices (the mesh as placed on the stage).
    pub rest: Vec<DVec2>,
}

impl SkeletonRest {
    /// Bone `b`'s rest frame: its head (first joint) and direction
    /// (radians, counter-clockwise from +x) in the stage.
    pub fn frame(&self, b: usize) -> (DVec2, f64) {
        let [a, c] = self.bones[b];
        let (a, c) = (self.joints[a], self.joints[c]);
        (a, (c - a).to_angle())
    }

    /// Bone `b`'s rest length.
    pub fn length(&self, b: usize) -> f64 {
        let [a, c] = self.bones[b];
        self.joints[a].distance(self.joints[c])
    }

    /// The bones, parents before children (the order Spine wants them in,
    /// and the order a motion is built in).
    pub fn order(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.bones.len()).collect();
        order.sort_by_key(|&b| depth(self, b));
        order
    }
}

/// A bone's place relative to its parent's frame (or the stage's, for
/// none): its head in the parent's frame, and its direction from the
/// parent's.
pub fn local(parent: Option<(DVec2, f64)>, (head, angle): (DVec2, f64)) -> (DVec2, f64) {
    match parent {
        Some((p, a)) => (DVec2::from_angle(-a).rotate(head - p), angle - a),
        None => (head, angle),
    }
}

/// A rigid motion of the plane: rotate by `angle` (radians, counter-
/// clockwise) about the origin, then translate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    /// Radians, counter-clockwise (y up).
    pub angle: f64,
    /// Added after the rotation, in stage units.
    pub translation: DVec2,
}

impl Rigid {
    /// No motion.
    pub const IDENTITY: Rigid = Rigid {
        angle: 0.0,
        translation: DVec2::ZERO,
    };

    /// Where `p` goes.
    pub fn apply(&self, p: DVec2) -> DVec2 {
        DVec2::from_angle(self.angle).rotate(p) + self.translation
    }
}

/// The bones fitted to a skeleton puppet's frames.
#[derive(Debug, Clone, PartialEq)]
pub struct Skin {
    /// `motions[k][b]`: bone `b`'s motion from rest in frame `k`.
    pub motions: Vec<Vec<Rigid>>,
    /// Per vertex, its bones and weights (summing to 1): one or two.
    pub weights: Vec<Vec<(usize, f64)>>,
    /// The largest distance, over every frame and vertex, between the
    /// skinned vertex and the take's, in stage units: where a joint bends
    /// far, blending rigid bones cannot follow the deformer's smooth bend
    /// (an elbow bent 69° on the 543-unit demo figure: 13 units).
    pub max_error: f64,
    /// The mean of that distance over every frame and vertex.
    pub mean_error: f64,
}

/// How many bones a vertex may follow: its nearest ones (Spine and glTF
/// skins take any number; three reproduce a bend at a joint better than
/// two, and more add little for a chain).
const BONES_PER_VERTEX: usize = 3;

/// The best weights of a vertex over its candidate bones (at least 0,
/// summing to 1), from the candidates' placements of it and its place in
/// the take, frame by frame. Written relative to the first candidate,
/// `x = a₀ + Σⱼ wⱼ (aⱼ − a₀)` for j ≥ 1, so the least squares is over
/// the differences (well scaled, unlike absolute stage positions): the
/// unconstrained optimum if it is feasible, else the best on the
/// triangle's edges and corners. Bounded: a singular system falls to the
/// edges, and the first candidate alone is always a candidate answer.
fn best_weights(placements: &[Vec<DVec2>], target: &[DVec2], k: usize) -> Vec<f64> {
    // Over the frames: G = Σ DᵀD and h = Σ Dᵀ(v − a₀), D the differences.
    let m = k - 1;
    let mut gram = [[0.0f64; 2]; 2];
    let mut h = [0.0f64; 2];
    for (a, &v) in placements.iter().zip(target) {
        for r in 0..m {
            let dr = a[r + 1] - a[0];
            h[r] += dr.dot(v - a[0]);
            for c in 0..m {
                gram[r][c] += dr.dot(a[c + 1] - a[0]);
            }
        }
    }
    let cost = |w: [f64; 2]| {
        let mut f = 0.0;
        for r in 0..m {
            f -= 2.0 * h[r] * w[r];
            for c in 0..m {
                f += w[r] * gram[r][c] * w[c];
            }
        }
        f
    };
    // The best w on the segment from `p` to `q` (a 1D clamped fit).
    let on_segment = |p: [f64; 2], q: [f64; 2]| {
        let d = [q[0] - p[0], q[1] - p[1]];
        let (mut quad, mut lin) = (0.0, 0.0);
        for r in 0..m {
            lin += d[r] * h[r];
            for c in 0..m {
                quad += d[r] * gram[r][c] * d[c];
                lin -= d[r] * gram[r][c] * p[c];
            }
        }
        let t = if quad > 1e-12 {
            (lin / quad).clamp(0.0, 1.0)
        } else {
            0.0
        };
        [p[0] + t * d[0], p[1] + t * d[1]]
    };
    let mut candidates = vec![[0.0, 0.0]];
    match m {
        0 => {}
        1 => candidates.push(on_segment([0.0, 0.0], [1.0, 0.0])),
        _ => {
            let det = gram[0][0] * gram[1][1] - gram[0][1] * gram[1][0];
            if det.abs() > 1e-12 {
                let w = [
                    (h[0] * gram[1][1] - h[1] * gram[0][1]) / det,
                    (gram[0][0] * h[1] - gram[1][0] * h[0]) / det,
                ];
                if w[0] >= 0.0 && w[1] >= 0.0 && w[0] + w[1] <= 1.0 {
                    candidates.push(w);
                }
            }
            candidates.push(on_segment([0.0, 0.0], [1.0, 0.0]));
            candidates.push(on_segment([0.0, 0.0], [0.0, 1.0]));
            candidates.push(on_segment([1.0, 0.0], [0.0, 1.0]));
        }
    }
    let best = candidates
        .into_iter()
        .filter(|w| w.iter().all(|x| x.is_finite()))
        .min_by(|a, b| cost(*a).total_cmp(&cost(*b)))
        .unwrap_or([0.0, 0.0]);
    let mut weights = vec![1.0 - best[..m].iter().sum::<f64>()];
    weights.extend(&best[..m]);
    weights
}

impl Skin {
    /// Bone `b`'s frame (head and direction) in frame `k`; past the last
    /// frame, the last.
    pub fn posed(&self, rest: &SkeletonRest, k: usize, b: usize) -> (DVec2, f64) {
        let motion = self.motions[k.min(self.motions.len() - 1)][b];
        let (head, angle) = rest.frame(b);
        (motion.apply(head), angle + motion.angle)
    }
}

/// Distance from `p` to the segment `ab`.
fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 {
        ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + ab * t)
}

/// The rigid motion that best carries `from[i]` onto `to[i]` (least
/// squares): the centroids' offset and the rotation of the centred points.
fn procrustes(from: impl Iterator<Item = (DVec2, DVec2)> + Clone) -> Rigid {
    let n = from.clone().count() as f64;
    let (cp, cq) = from
        .clone()
        .fold((DVec2::ZERO, DVec2::ZERO), |(a, b), (p, q)| (a + p, b + q));
    let (cp, cq) = (cp / n, cq / n);
    let (mut dot, mut cross) = (0.0, 0.0);
    for (p, q) in from {
        let (p, q) = (p - cp, q - cq);
        dot += p.dot(q);
        cross += p.perp_dot(q);
    }
    let angle = if dot == 0.0 && cross == 0.0 {
        0.0
    } else {
        cross.atan2(dot)
    };
    let translation = cq - DVec2::from_angle(angle).rotate(cp);
    Rigid { angle, translation }
}

/// Fits bones to `puppet`'s frames (see the module's doc).
pub fn fit(puppet: &AnimatedPuppet, skeleton: &SkeletonRest) -> Skin {
    let bones = skeleton.bones.len();
    let rest = &skeleton.rest;
    let segment = |b: usize| {
        let [a, c] = skeleton.bones[b];
        (skeleton.joints[a], skeleton.joints[c])
    };
    // Each vertex's nearest bones, nearest first.
    let nearest: Vec<Vec<usize>> = rest
        .iter()
        .map(|&p| {
            let mut by: Vec<(f64, usize)> = (0..bones)
                .map(|b| {
                    let (a, c) = segment(b);
                    (segment_distance(p, a, c), b)
                })
                .collect();
            by.sort_by(|x, y| x.0.total_cmp(&y.0));
            by.into_iter()
                .take(BONES_PER_VERTEX)
                .map(|(_, b)| b)
                .collect()
        })
        .collect();
    let owned: Vec<Vec<usize>> = (0..bones)
        .map(|b| (0..rest.len()).filter(|&i| nearest[i][0] == b).collect())
        .collect();
    // Parents before children, so an empty bone can take its parent's.
    let order = skeleton.order();
    let point = |q: [f32; 2]| DVec2::new(f64::from(q[0]), f64::from(q[1]));
    let motions: Vec<Vec<Rigid>> = puppet
        .frames
        .iter()
        .map(|frame| {
            let mut motion = vec![Rigid::IDENTITY; bones];
            for &b in &order {
                motion[b] = if owned[b].len() >= 2 {
                    procrustes(owned[b].iter().map(|&i| (rest[i], point(frame[i]))))
                } else {
                    skeleton.parents[b].map_or(Rigid::IDENTITY, |p| motion[p])
                };
            }
            motion
        })
        .collect();
    // Each vertex's weights over its bones, best over the frames.
    let weights: Vec<Vec<(usize, f64)>> = (0..rest.len())
        .map(|i| {
            let candidates = &nearest[i];
            let k = candidates.len();
            let placements: Vec<Vec<DVec2>> = motions
                .iter()
                .map(|motion| {
                    candidates
                        .iter()
                        .map(|&b| motion[b].apply(rest[i]))
                        .collect()
                })
                .collect();
            let target: Vec<DVec2> = puppet.frames.iter().map(|f| point(f[i])).collect();
            let w = best_weights(&placements, &target, k);
            let kept: Vec<(usize, f64)> = candidates
                .iter()
                .zip(w)
                .filter(|&(_, w)| w > 1e-4)
                .map(|(&b, w)| (b, w))
                .collect();
            let total: f64 = kept.iter().map(|&(_, w)| w).sum();
            kept.into_iter().map(|(b, w)| (b, w / total)).collect()
        })
        .collect();
    let (mut max_error, mut sum) = (0.0f64, 0.0f64);
    for (frame, motion) in puppet.frames.iter().zip(&motions) {
        for (i, w) in weights.iter().enumerate() {
            let skinned: DVec2 = w.iter().map(|&(b, w)| motion[b].apply(rest[i]) * w).sum();
            let e = skinned.distance(point(frame[i]));
            max_error = max_error.max(e);
            sum += e;
        }
    }
    let count = (puppet.frames.len() * rest.len()).max(1);
    Skin {
        motions,
        weights,
        max_error,
        mean_error: sum / count as f64,
    }
}

/// How many bones lie above bone `b`.
fn depth(skeleton: &SkeletonRest, b: usize) -> usize {
    let mut depth = 0;
    let mut at = b;
    while let Some(p) = skeleton.parents[at] {
        depth += 1;
        at = p;
        if depth > skeleton.bones.len() {
            break; // not a forest; `Skeleton::new` refuses those
        }
    }
    depth
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn procrustes_recovers_a_rigid_motion_and_is_bounded_when_degenerate() {
        let motion = Rigid {
            angle: 0.7,
            translation: DVec2::new(3.0, -2.0),
        };
        let points = [
            DVec2::new(0.0, 0.0),
            DVec2::new(2.0, 0.5),
            DVec2::new(-1.0, 4.0),
        ];
        let fitted = procrustes(points.iter().map(|&p| (p, motion.apply(p))));
        assert!((fitted.angle - motion.angle).abs() < 1e-12);
        assert!(fitted.translation.distance(motion.translation) < 1e-12);
        // Coincident points: no rotation, the offset only.
        let same = [DVec2::ONE; 3];
        let fitted = procrustes(same.iter().map(|&p| (p, p + DVec2::X)));
        assert_eq!(fitted.angle, 0.0);
        assert!(fitted.translation.distance(DVec2::X) < 1e-12);
    }
}
