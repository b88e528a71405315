//! The triangle orders a format that draws a mesh in one fixed order
//! (Spine: a mesh attachment's `triangles`) needs to show a puppet's folds
//! as the page did, and when to switch between them.
//!
//! Only triangles that overlap in a frame have an order that shows: there
//! the one the frame's depths put behind must come first. Over a run of
//! frames those requirements form a graph; while it has no cycle, one
//! order (a topological order of it, mesh order where free) draws every
//! frame of the run right. A fold held throughout is one run; a fold that
//! changes sides (an Alt+click flip, a limb swung from behind the body to
//! in front) starts a new run where the last order would contradict it.
//! Runs are found greedily, frame by frame.

use std::collections::{BTreeSet, HashMap, HashSet};

use crate::AnimatedPuppet;

/// Most runs (so attachments) one puppet's folds are cut into; a puppet
/// that needs more is drawn in its mesh's order, and the export says so.
pub const MAX_RUNS: usize = 64;

/// Runs of frames, each with the triangle order that draws all of it.
#[derive(Debug, Clone, PartialEq)]
pub struct Runs {
    /// Each run's first frame (the first run's is 0), ascending.
    pub starts: Vec<usize>,
    /// Each run's triangle order, back to front (indices into the
    /// puppet's triangles).
    pub orders: Vec<Vec<u32>>,
}

/// A puppet whose folds need more than [`MAX_RUNS`] runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TooManyRuns;

/// The runs of `p`: `Ok(None)` where mesh order draws every frame right
/// (it never overlaps itself, or only as mesh order has it), `Err` where
/// its folds need more than [`MAX_RUNS`] runs.
pub fn runs(p: &AnimatedPuppet) -> Result<Option<Runs>, TooManyRuns> {
    if p.depths.is_empty() {
        return Ok(None);
    }
    let frames = p.frames.len().min(p.depths.len());
    let mut run = Run::default();
    let mut runs = Runs {
        starts: vec![0],
        orders: Vec::new(),
    };
    let mut pairs = Vec::new();
    let mut edges = Vec::new();
    for k in 0..frames {
        overlapping(&p.triangles, &p.frames[k], &mut pairs);
        let depth = &p.depths[k];
        edges.clear();
        edges.extend(pairs.iter().map(|&(a, b)| {
            if depth[a as usize] < depth[b as usize] {
                (a, b)
            } else {
                (b, a)
            }
        }));
        if !run.admit(&edges) {
            if runs.starts.len() == MAX_RUNS {
                return Err(TooManyRuns);
            }
            runs.orders.push(run.order(p.triangles.len()));
            runs.starts.push(k);
            run = Run::default();
            // A frame's own requirements never contradict: its depths
            // order them all.
            run.admit(&edges);
        }
    }
    runs.orders.push(run.order(p.triangles.len()));
    let plain = |o: &Vec<u32>| o.iter().enumerate().all(|(i, &t)| i == t as usize);
    if runs.orders.len() == 1 && plain(&runs.orders[0]) {
        return Ok(None);
    }
    Ok(Some(runs))
}

/// The requirements of one run: `behind[a]` holds every b that a must be
/// drawn before.
#[derive(Default)]
struct Run {
    behind: HashMap<u32, HashSet<u32>>,
}

impl Run {
    /// Takes in a frame's requirements if they make no cycle with the
    /// run's; otherwise leaves the run as it was.
    fn admit(&mut self, edges: &[(u32, u32)]) -> bool {
        let mut added = Vec::new();
        for &(a, b) in edges {
            if self.behind.get(&a).is_some_and(|s| s.contains(&b)) {
                continue;
            }
            if self.reaches(b, a) {
                for (x, y) in added {
                    if let Some(s) = self.behind.get_mut(&x) {
                        s.remove(&y);
                    }
                }
                return false;
            }
            self.behind.entry(a).or_default().insert(b);
            added.push((a, b));
        }
        true
    }

    /// Whether `to` must come after `from` already.
    fn reaches(&self, from: u32, to: u32) -> bool {
        let mut stack = vec![from];
        let mut seen = HashSet::new();
        while let Some(a) = stack.pop() {
            if a == to {
                return true;
            }
            if seen.insert(a) {
                stack.extend(self.behind.get(&a).into_iter().flatten());
            }
        }
        false
    }

    /// All `n` triangles in an order meeting every requirement: among
    /// those free to go next, the lowest in mesh order.
    fn order(&self, n: usize) -> Vec<u32> {
        let mut waiting = vec![0usize; n];
        for set in self.behind.values() {
            for &b in set {
                waiting[b as usize] += 1;
            }
        }
        let mut ready: BTreeSet<u32> = (0..n as u32)
            .filter(|&t| waiting[t as usize] == 0)
            .collect();
        let mut order = Vec::with_capacity(n);
        while let Some(t) = ready.pop_first() {
            order.push(t);
            for &b in self.behind.get(&t).into_iter().flatten() {
                waiting[b as usize] -= 1;
                if waiting[b as usize] == 0 {
                    ready.insert(b);
                }
            }
        }
        order
    }
}

/// The pairs of triangles whose insides overlap in `frame`, into `pairs`:
/// a sweep over their boxes along x, then an exact test of the boxes that
/// meet.
fn overlapping(triangles: &[[u32; 3]], frame: &[[f32; 2]], pairs: &mut Vec<(u32, u32)>) {
    pairs.clear();
    let corners = |t: &[u32; 3]| t.map(|v| frame[v as usize].map(f64::from));
    let boxes: Vec<[f64; 4]> = triangles
        .iter()
        .map(|t| {
            let c = corners(t);
            let (xs, ys) = (c.map(|q| q[0]), c.map(|q| q[1]));
            [
                xs.iter().copied().fold(f64::INFINITY, f64::min),
                ys.iter().copied().fold(f64::INFINITY, f64::min),
                xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            ]
        })
        .collect();
    let mut by_x: Vec<usize> = (0..triangles.len()).collect();
    by_x.sort_by(|&a, &b| boxes[a][0].total_cmp(&boxes[b][0]));
    for (i, &a) in by_x.iter().enumerate() {
        for &b in &by_x[i + 1..] {
            if boxes[b][0] >= boxes[a][2] {
                break;
            }
            if boxes[b][1] >= boxes[a][3] || boxes[a][1] >= boxes[b][3] {
                continue;
            }
            if insides_meet(corners(&triangles[a]), corners(&triangles[b])) {
                pairs.push((a as u32, b as u32));
            }
        }
    }
}

/// Whether two triangles' insides overlap by more than a sliver: no axis
/// across one of their edges separates them (touching along an edge or at
/// a corner, as neighbours do, is not overlapping).
fn insides_meet(a: [[f64; 2]; 3], b: [[f64; 2]; 3]) -> bool {
    const SLIVER: f64 = 1e-6;
    let edges = |t: [[f64; 2]; 3]| (0..3).map(move |i| (t[i], t[(i + 1) % 3]));
    for (p, q) in edges(a).chain(edges(b)) {
        let axis = [q[1] - p[1], p[0] - q[0]];
        let length = axis[0].hypot(axis[1]);
        if length < 1e-12 {
            continue;
        }
        let project = |t: [[f64; 2]; 3]| {
            let d = t.map(|c| (c[0] * axis[0] + c[1] * axis[1]) / length);
            let lo = d.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = d.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (lo, hi)
        };
        let ((a0, a1), (b0, b1)) = (project(a), project(b));
        if a1 - b0 <= SLIVER || b1 - a0 <= SLIVER {
            return false;
        }
    }
    true
}
