//! As-rigid-as-possible curve editing (Igarashi, Moscovich & Hughes 2005,
//! §5.4): an open polyline deformed by handles in two steps, and the peeling
//! interface that grows the edited region as a drag goes further.
//!
//! Step 1 is Laplacian curve editing ("Laplacian surface editing", Sorkine et
//! al. 2004) in rotation-invariant form: each interior rest point is written
//! in the frame of its two neighbours, `v̄ᵢ = v̄ᵢ₋₁ + xᵢ dᵢ + yᵢ R dᵢ` with
//! `dᵢ = v̄ᵢ₊₁ − v̄ᵢ₋₁`, and the deformed curve minimises the squared error of
//! the same expression. In complex numbers (a point is `x + iy`) the pair
//! `(xᵢ, yᵢ)` with the fixed quarter turn `R` is a single complex ratio
//! `zᵢ = (v̄ᵢ − v̄ᵢ₋₁)/(v̄ᵢ₊₁ − v̄ᵢ₋₁)`, so the energy is a complex Hermitian
//! form and one complex solve gives both coordinates. Step 2 (scale
//! adjustment) gives every segment the step-1 direction and its rest length
//! and fits the curve to those segments in least squares.
//!
//! Handles are linear constraints — a point, or a point along a segment — so
//! each step solves the constrained minimum through its KKT system. Points
//! outside a chosen interval are fixed where they are (peeling), so the
//! system only spans the free interval. Unknowns are numbered along the
//! curve with each handle's multiplier right after its points, which keeps
//! the system banded: compile factors it by banded LU with partial pivoting
//! (the KKT matrix is indefinite) in O(n), an update is two banded solves
//! (complex for step 1; real for step 2, whose x and y share the matrix).
//! A free interval is numbered instead outward from its first handle, in
//! two arms joined there (`Split`), so that a peel's region growing at
//! its ends appends to the arms' eliminations: a region change factors only
//! the growth.
//!
//! **Singular cases.** Handles are exact constraints, so two of them a
//! small fraction `δ` of a segment apart with targets `D` apart would force
//! the curve between them to length `D/δ` (a finger a hair from the rope's
//! pin sent its end to ~4e5). The policy (`merge_coincident`): handles
//! closer than half a segment along the curve's parameter (point index plus
//! `t`), or nearest the same point, are one handle and **the later wins**;
//! a handle within half a segment of a held point (outside the free
//! points) is dropped — **the held point wins**. What is kept is well
//! conditioned: no segment need stretch beyond about twice the targets'
//! distance. All handles on one point are one handle (the curve is carried
//! rigidly). Rest curves whose frames are themselves singular — a segment
//! under [`MIN_LENGTH_RATIO`] of its neighbour, or a turn almost straight
//! back — are refused by [`validate`]. Nothing is cached from one update to
//! the next (no warm start; the factors depend only on the handle set and
//! the held points), so a sane update after a wild one is exact again. Step
//! 1 alone ([`Steps::ScaleFree`]) still scales the whole curve with the
//! handles' spread — two handles half a segment apart pulled across the
//! stage scale it a few hundred times — by design; both steps keep lengths.
//!
//! Phases: [`Curve::register`] (rest curve: validation, local frames),
//! [`Curve::compile`] / [`Curve::compile_within`] (handle set or free
//! interval changed: assembly and factorisation), [`Curve::update`] (handles
//! moved; does not allocate). [`Peel`] turns a drag into the free interval.

use std::ops::RangeInclusive;

use glam::DVec2;
use puppetry_mesh::json::MAX_COORDINATE;

use crate::targets::{self, TargetError};

pub use super::arap::Steps;

/// Where a handle holds the curve, in rest terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CurveAnchor {
    /// A point of the polyline.
    Point(u32),
    /// A point along segment `segment` (from point `segment` to
    /// `segment + 1`), at parameter `t` in `[0, 1]`.
    Along {
        /// Index of the segment, i.e. of its first point.
        segment: u32,
        /// Where along it: 0 at point `segment`, 1 at point `segment + 1`.
        t: f64,
    },
}

/// Why a rest curve, a resampling, a handle set, a pose, a frame's targets
/// or a peel was refused. Points and segments are indices along the curve;
/// a `handle` is the handle's index in the slice given to compile (or
/// update).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CurveError {
    /// The rest curve has fewer than 3 points ([`resample_evenly`]: fewer
    /// than 2).
    #[error("a curve needs at least 3 points, got {count}")]
    TooFewPoints {
        /// How many points it has.
        count: usize,
    },
    /// A rest point (or a [`Curve::set_pose`] point) is NaN, infinite or
    /// beyond the mesh format's coordinate limit.
    #[error("point {point} is not a finite point within ±{limit:e}", limit = MAX_COORDINATE)]
    PointNotFinite {
        /// The first offending point.
        point: usize,
    },
    /// Two consecutive rest points are equal ([`resample_evenly`]: the
    /// whole polyline has zero length).
    #[error("point {point} repeats point {previous}: segment {previous} has zero length")]
    RepeatedPoint {
        /// The repeating point.
        point: usize,
        /// The point before it, which it repeats.
        previous: usize,
    },
    /// The two segments meeting at a point lie along one line and turn
    /// straight back over each other.
    #[error("the curve folds back on itself at point {point}: segments {} and {point} overlap", point - 1)]
    FoldsBack {
        /// The point where the curve turns back.
        point: usize,
    },
    /// A segment is shorter than [`MIN_LENGTH_RATIO`] times its
    /// neighbour; [`resample_evenly`] fixes this.
    #[error(
        "segment {segment} is under {limit:e} of the length of its neighbour {neighbour}: spacing this uneven makes the solve singular (resample the curve evenly)",
        limit = MIN_LENGTH_RATIO
    )]
    UnevenSpacing {
        /// The short segment.
        segment: usize,
        /// The longer segment next to it.
        neighbour: usize,
    },
    /// A point's two neighbours are closer than [`MIN_LENGTH_RATIO`] of
    /// the longer segment between them: a hairpin, nearly a fold-back.
    #[error(
        "the curve turns almost straight back at point {point}: its neighbours are under {limit:e} of a segment apart, which makes the solve singular",
        limit = MIN_LENGTH_RATIO
    )]
    NearlyFoldsBack {
        /// The point at the hairpin's tip.
        point: usize,
    },
    /// Two non-adjacent segments cross or touch.
    #[error("segments {first} and {second} cross or touch: the curve intersects itself")]
    SelfIntersection {
        /// The lower-numbered segment of the first such pair.
        first: usize,
        /// The other segment.
        second: usize,
    },
    /// [`resample_evenly`] was asked for a spacing that is zero, negative
    /// or not finite.
    #[error("resampling spacing {spacing} must be finite and positive")]
    BadSpacing {
        /// The spacing asked for.
        spacing: f64,
    },
    /// A [`CurveAnchor::Point`] names a point the curve does not have.
    #[error("handle {handle}: point {point} is out of range (the curve has {count} points)")]
    PointOutOfRange {
        /// The offending handle's index.
        handle: usize,
        /// The point it named.
        point: u32,
        /// How many points the curve has.
        count: usize,
    },
    /// A [`CurveAnchor::Along`] names a segment the curve does not have.
    #[error("handle {handle}: segment {segment} is out of range (the curve has {count} segments)")]
    SegmentOutOfRange {
        /// The offending handle's index.
        handle: usize,
        /// The segment it named.
        segment: u32,
        /// How many segments the curve has (one fewer than points).
        count: usize,
    },
    /// A [`CurveAnchor::Along`]'s `t` is not finite or outside `[0, 1]`.
    #[error("handle {handle}: parameter t = {t} must be finite and within [0, 1]")]
    BadParameter {
        /// The offending handle's index.
        handle: usize,
        /// The parameter it gave.
        t: f64,
    },
    /// [`Curve::compile_within`]: a handle holds no free point, so it
    /// could not move anything.
    #[error("handle {handle} lies outside the free points {start}..={end}: it cannot move")]
    HandleFixed {
        /// The offending handle's index.
        handle: usize,
        /// First free point.
        start: usize,
        /// Last free point (inclusive).
        end: usize,
    },
    /// [`Curve::compile_within`]: the free range is empty (start after
    /// end) or runs past the last point.
    #[error("free points {start}..={end} are not within the curve's {count} points")]
    BadFreeRange {
        /// First free point asked for.
        start: usize,
        /// Last free point asked for (inclusive).
        end: usize,
        /// How many points the curve has.
        count: usize,
    },
    /// Compile could not factor a step's system: the handles and held
    /// points leave the curve free to move. The curve keeps its pose and
    /// has no live handles until a compile succeeds.
    #[error("step {step}: the handles and fixed points do not determine the curve (add a handle)")]
    Underdetermined {
        /// Which step's system failed: 1 or 2.
        step: u8,
    },
    /// [`Curve::update`]: the targets are not one per anchor of the last
    /// compile, or one is not a finite point within range;
    /// [`Curve::set_pose`]: the points are not one per rest point.
    #[error(transparent)]
    Targets(#[from] TargetError),
    /// [`Peel::new`]: the grab is not finite or off the rest curve's arc
    /// length range.
    #[error("grab at arc length {at} is not on the curve (0..={length})")]
    GrabOffCurve {
        /// The grab's arc length.
        at: f64,
        /// The rest curve's total length.
        length: f64,
    },
    /// [`Peel::new`]: a pushpin is not finite or off the rest curve's arc
    /// length range.
    #[error("pushpin {pushpin} at arc length {at} is not on the curve (0..={length})")]
    PushpinOffCurve {
        /// The pushpin's index in the slice given.
        pushpin: usize,
        /// Its arc length.
        at: f64,
        /// The rest curve's total length.
        length: f64,
    },
    /// [`Peel::new`]: a pushpin is exactly at the grab, which would pin
    /// the grabbed point itself.
    #[error("pushpin {pushpin} sits at the grab point: nothing could move")]
    PushpinAtGrab {
        /// The pushpin's index in the slice given.
        pushpin: usize,
    },
    /// [`Peel::new`]: a [`PeelParams`] field is negative or not finite.
    #[error("peel {field} = {value} must be finite and non-negative")]
    BadPeelParameter {
        /// The field's name (`initial_radius` or `growth_rate`).
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// [`Peel::drag`]: the distance is negative or not finite.
    #[error("drag distance {distance} must be finite and non-negative")]
    BadDragDistance {
        /// The distance given.
        distance: f64,
    },
}

mod banded;
use banded::*;

/// Where each handle's multiplier goes in a split system with joint
/// `j0..=j1`: after its outermost free point in the left arm (0) or the
/// right (1), or into the joint (2) when it only holds joint points. Each
/// side's entries `(outermost point key, handle, constraint)` sorted.
fn sides(
    constraints: &[Constraint],
    free_of: impl Fn(&Constraint) -> [bool; 2],
    (j0, j1): (usize, usize),
) -> [Vec<(usize, usize, usize)>; 3] {
    let mut sides: [Vec<(usize, usize, usize)>; 3] = Default::default();
    for (i, con) in constraints.iter().enumerate() {
        let free = free_of(con);
        let points = (0..2).filter(|&k| free[k]).map(|k| con.points[k]);
        let (left, right) = (points.clone().min(), points.max());
        match (left, right) {
            (Some(l), _) if l < j0 => sides[0].push((usize::MAX - l, con.target, i)),
            (_, Some(r)) if r > j1 => sides[1].push((r, con.target, i)),
            _ => sides[2].push((0, con.target, i)),
        }
    }
    for side in &mut sides {
        side.sort_unstable();
    }
    sides
}

/// Step 1's term at interior point `i` (of frames `frames`): its
/// coefficients γ = (z − 1, 1, −z) on the points (i − 1, i, i + 1), z the
/// point's rest frame.
#[inline]
fn step1_term(frames: &[DVec2], i: usize) -> ([DVec2; 3], [usize; 3]) {
    let z = frames[i];
    ([z - DVec2::X, DVec2::X, -z], [i - 1, i, i + 1])
}

/// What a split compile keeps to grow its region next time.
#[derive(Debug, Clone, PartialEq)]
struct Grown {
    anchors: Vec<CurveAnchor>,
    lo: usize,
    hi: usize,
    joint: (usize, usize),
    joint_size: usize,
    sizes: [usize; 2],
    /// Per step, per arm.
    widths: [[usize; 2]; 2],
    /// Per step, per arm, per joint unknown: whether they are coupled.
    links: [[[bool; JOINT]; 2]; 2],
    /// Per constraint: which of its points are free.
    free: Vec<[bool; 2]>,
}

/// Which system a compile solves.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Layout {
    /// One banded system numbered along the curve.
    Natural,
    /// Two arms and a joint ([`Split`]).
    Split,
}

/// A handle as a constraint row `w₀ v[p₀] + w₁ v[p₁] = q`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Constraint {
    anchor: CurveAnchor,
    points: [usize; 2],
    weights: [f64; 2],
    rest_point: DVec2,
    /// Index into the caller's targets.
    target: usize,
    /// Row of its multiplier in the KKT systems.
    slot: usize,
}

/// How the curve is placed for its current handle set.
#[derive(Debug, Clone, Copy)]
enum Placement {
    /// No handle and nothing fixed: the rigid placement written at compile.
    Still,
    /// One handle and nothing fixed: the rest curve rotated by `rotation`
    /// (cos, sin), carried by the handle.
    Carried { rotation: DVec2 },
    /// Solved through the KKT systems.
    Solved,
}

/// A registered rest curve and its compiled handle set. See the module docs
/// for the phases.
#[derive(Debug)]
pub struct Curve {
    rest: Vec<DVec2>,
    /// Arc length of every rest point from point 0.
    arc: Vec<f64>,
    /// `zᵢ` for interior points (index `i`; entries 0 and n−1 unused).
    frames: Vec<DVec2>,
    rest_lengths: Vec<f64>,
    pose: Vec<DVec2>,
    placement: Placement,
    handle_count: usize,
    constraints: Vec<Constraint>,
    /// The free points, `lo..=hi`; the rest stay where compile found them.
    lo: usize,
    hi: usize,
    /// KKT row of free point `lo + k`.
    point_slot: Vec<usize>,
    step1: BandLu<DVec2>,
    step2: BandLu<f64>,
    /// Which systems the compile filled: `step1`/`step2`, or for a free
    /// interval (peeling) `split1`/`split2`, which grow with the region.
    layout: Layout,
    split1: Split<DVec2>,
    split2: Split<f64>,
    grown: Option<Grown>,
    /// Test only: how many compiles grew the last one's factors.
    #[cfg(test)]
    grew: usize,
    /// Right-hand sides' parts fixed at compile time (the fixed points'
    /// pull), copied into `rhs` every frame.
    step1_base: Vec<DVec2>,
    step2_base: Vec<DVec2>,
    rhs: Vec<DVec2>,
    /// The step-1 curve, fixed points included.
    scale_free: Vec<DVec2>,
}

/// Validates a rest polyline: enough points, finite, no zero-length
/// segment, no segment under [`MIN_LENGTH_RATIO`] of its neighbour, no
/// fold-back (nor a turn back within that ratio), no self-intersection.
pub fn validate(points: &[DVec2]) -> Result<(), CurveError> {
    if points.len() < 3 {
        return Err(CurveError::TooFewPoints {
            count: points.len(),
        });
    }
    if let Some(point) = targets::out_of_range(points) {
        return Err(CurveError::PointNotFinite { point });
    }
    if let Some(w) = points.windows(2).position(|w| w[0] == w[1]) {
        return Err(CurveError::RepeatedPoint {
            point: w + 1,
            previous: w,
        });
    }
    for i in 1..points.len() - 1 {
        let (a, b) = (points[i] - points[i - 1], points[i + 1] - points[i]);
        // Segments meeting at i overlap when they turn back along one line.
        if a.perp_dot(b).abs() <= 1e-12 * a.length() * b.length() && a.dot(b) < 0.0 {
            return Err(CurveError::FoldsBack { point: i });
        }
        // Point i's frame is its neighbours' chord: a segment far shorter
        // than the next, or a chord far shorter than the segments (a
        // hairpin), leaves the step-1 system so ill-conditioned that even
        // the handles at rest came back hundreds of units off.
        let longer = a.length().max(b.length());
        if a.length() < MIN_LENGTH_RATIO * longer || b.length() < MIN_LENGTH_RATIO * longer {
            let (segment, neighbour) = if a.length() < b.length() {
                (i - 1, i)
            } else {
                (i, i - 1)
            };
            return Err(CurveError::UnevenSpacing { segment, neighbour });
        }
        if (a + b).length() < MIN_LENGTH_RATIO * longer {
            return Err(CurveError::NearlyFoldsBack { point: i });
        }
    }
    if let Some((first, second)) = first_crossing(points) {
        return Err(CurveError::SelfIntersection { first, second });
    }
    Ok(())
}

/// Sign of the turn `a → b → c`, exactly zero when collinear.
#[inline]
fn orientation(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - a)
}

/// Whether closed segments `a–b` and `c–d` share a point.
fn segments_meet(a: DVec2, b: DVec2, c: DVec2, d: DVec2) -> bool {
    let within = |p: DVec2, q: DVec2, r: DVec2| {
        r.x >= p.x.min(q.x) && r.x <= p.x.max(q.x) && r.y >= p.y.min(q.y) && r.y <= p.y.max(q.y)
    };
    let (o1, o2) = (orientation(a, b, c), orientation(a, b, d));
    let (o3, o4) = (orientation(c, d, a), orientation(c, d, b));
    if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
        return true;
    }
    (o1 == 0.0 && within(a, b, c))
        || (o2 == 0.0 && within(a, b, d))
        || (o3 == 0.0 && within(c, d, a))
        || (o4 == 0.0 && within(c, d, b))
}

/// The lowest pair of non-adjacent segments that meet, if any. Segments are
/// binned in a uniform grid of about the mean segment length (capped at
/// ~4n cells), so only segments sharing a cell are tested.
fn first_crossing(points: &[DVec2]) -> Option<(usize, usize)> {
    let segments = points.len() - 1;
    let (mut min, mut max) = (points[0], points[0]);
    for p in points {
        min = min.min(*p);
        max = max.max(*p);
    }
    let total: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
    let extent = (max - min).max(DVec2::splat(f64::MIN_POSITIVE));
    let cap = (2.0 * (segments as f64).sqrt()).ceil() + 1.0;
    let cell = (total / segments as f64).max(extent.max_element() / cap);
    let columns = ((extent.x / cell).floor() as usize + 1).max(1);
    let rows = ((extent.y / cell).floor() as usize + 1).max(1);
    let cell_of = |p: DVec2| -> (usize, usize) {
        let c = ((p - min) / cell).floor();
        (
            (c.x.max(0.0) as usize).min(columns - 1),
            (c.y.max(0.0) as usize).min(rows - 1),
        )
    };
    let covered = |s: usize| {
        let (a, b) = (cell_of(points[s]), cell_of(points[s + 1]));
        let (x0, x1) = (a.0.min(b.0), a.0.max(b.0));
        let (y0, y1) = (a.1.min(b.1), a.1.max(b.1));
        (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| y * columns + x))
    };
    // Counting sort of (cell, segment) pairs.
    let mut starts = vec![0u32; columns * rows + 1];
    for s in 0..segments {
        for c in covered(s) {
            starts[c + 1] += 1;
        }
    }
    for c in 0..columns * rows {
        starts[c + 1] += starts[c];
    }
    let mut fill = starts.clone();
    let mut members = vec![0u32; starts[columns * rows] as usize];
    for s in 0..segments {
        for c in covered(s) {
            members[fill[c] as usize] = s as u32;
            fill[c] += 1;
        }
    }
    let mut found: Option<(usize, usize)> = None;
    for c in 0..columns * rows {
        let bin = &members[starts[c] as usize..starts[c + 1] as usize];
        for (k, &i) in bin.iter().enumerate() {
            for &j in &bin[k + 1..] {
                let (i, j) = (i.min(j) as usize, i.max(j) as usize);
                if j < i + 2 || found.is_some_and(|f| f <= (i, j)) {
                    continue;
                }
                if segments_meet(points[i], points[i + 1], points[j], points[j + 1]) {
                    found = Some((i, j));
                }
            }
        }
    }
    found
}

/// The polyline resampled to evenly spaced points along its length, as the
/// paper recommends (§6: with uneven spacing dense regions come out softer).
/// Keeps both ends; the spacing is adjusted down so every segment has the
/// same length, at most `spacing`.
pub fn resample_evenly(points: &[DVec2], spacing: f64) -> Result<Vec<DVec2>, CurveError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(CurveError::BadSpacing { spacing });
    }
    if points.len() < 2 {
        return Err(CurveError::TooFewPoints {
            count: points.len(),
        });
    }
    if let Some(point) = points.iter().position(|p| !p.is_finite()) {
        return Err(CurveError::PointNotFinite { point });
    }
    let total: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
    if total == 0.0 {
        return Err(CurveError::RepeatedPoint {
            point: 1,
            previous: 0,
        });
    }
    let count = (total / spacing).ceil().max(1.0) as usize;
    let step = total / count as f64;
    let mut out = Vec::with_capacity(count + 1);
    out.push(points[0]);
    let mut segment = 0;
    let mut start_arc = 0.0;
    for k in 1..count {
        let want = step * k as f64;
        loop {
            let length = points[segment].distance(points[segment + 1]);
            if start_arc + length >= want || segment + 2 == points.len() {
                let t = if length > 0.0 {
                    ((want - start_arc) / length).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                out.push(points[segment].lerp(points[segment + 1], t));
                break;
            }
            start_arc += length;
            segment += 1;
        }
    }
    out.push(*points.last().expect("at least two points"));
    Ok(out)
}

/// Neighbouring segments' lengths, and a point's chord against its
/// segments, may differ by this factor at most (see [`validate`]): at 2e-3 the handles
/// at rest came back 2e-3 units off a 1000-unit curve, at 1e-2 about 1e-5.
pub const MIN_LENGTH_RATIO: f64 = 1e-2;

/// Handles closer than this along the curve — in its parameter, point
/// index plus `t` — are one handle (see [`merge_coincident`]).
const SAME_HANDLE: f64 = 0.5;

/// Which constraints stay live: the policy for handles on or near one
/// another. Exact constraints a small fraction `δ` of a segment apart with
/// targets `D` apart force the curve between them to length `D/δ`: two
/// handles a hair apart (a finger beside a pin) sent the rope's end to
/// ~4e5, and a handle a hair from a held point did the same to its free
/// neighbour. So, along the curve's parameter `u` (point index, plus `t`
/// along a segment):
///
/// - two handles closer than [`SAME_HANDLE`] (half a segment), or nearest
///   the same point, are one handle: **the later wins** (as two handles on
///   one rest point always did). Kept handles are then at least half a
///   segment apart and each nearest its own point, where it weighs at least
///   ½, so the constraint rows are well conditioned (a chain of them
///   amplifies the targets by at most a small factor) and no segment need
///   stretch beyond about twice the targets' distance;
/// - a handle nearest a held point (within half a segment of one just
///   outside the free points) holds what is held: it is dropped — the held
///   point wins, it cannot move.
fn merge_coincident(constraints: &[Constraint], lo: usize, hi: usize, n: usize) -> Vec<bool> {
    let at = |c: &Constraint| c.points[0] as f64 + c.weights[1];
    let nearest = |u: f64| (u + 0.5).floor();
    let held = |u: f64| (lo > 0 && u < lo as f64 - 0.5) || (hi + 1 < n && u > hi as f64 + 0.5);
    let mut live: Vec<bool> = constraints.iter().map(|c| !held(at(c))).collect();
    for later in (0..constraints.len()).rev() {
        if !live[later] {
            continue;
        }
        let u = at(&constraints[later]);
        for earlier in 0..later {
            let v = at(&constraints[earlier]);
            if (u - v).abs() < SAME_HANDLE || nearest(u) == nearest(v) {
                live[earlier] = false;
            }
        }
    }
    live
}

/// Best rotation (cos, sin) taking `rest` onto `pose` about their centroids,
/// and the two centroids; identity when undetermined.
fn fit_rotation(rest: &[DVec2], pose: &[DVec2]) -> (DVec2, DVec2, DVec2) {
    let count = rest.len() as f64;
    let rest_mean = rest.iter().copied().sum::<DVec2>() / count;
    let pose_mean = pose.iter().copied().sum::<DVec2>() / count;
    let (mut dot, mut crs) = (0.0, 0.0);
    for (r, p) in rest.iter().zip(pose) {
        let (r, p) = (*r - rest_mean, *p - pose_mean);
        dot += r.dot(p);
        crs += r.perp_dot(p);
    }
    let norm = (dot * dot + crs * crs).sqrt();
    let rotation = if norm > 0.0 && norm.is_finite() {
        DVec2::new(dot, crs) / norm
    } else {
        DVec2::X
    };
    (rotation, rest_mean, pose_mean)
}

impl Curve {
    /// Registration: validates the rest polyline and computes its local
    /// frames and lengths. No handles; [`Curve::pose`] is the rest curve.
    pub fn register(points: &[DVec2]) -> Result<Curve, CurveError> {
        validate(points)?;
        let n = points.len();
        let mut frames = vec![DVec2::ZERO; n];
        for i in 1..n - 1 {
            frames[i] = div(points[i] - points[i - 1], points[i + 1] - points[i - 1]);
        }
        let rest_lengths: Vec<f64> = points.windows(2).map(|w| w[0].distance(w[1])).collect();
        let mut arc = Vec::with_capacity(n);
        arc.push(0.0);
        for l in &rest_lengths {
            arc.push(arc.last().expect("non-empty") + l);
        }
        Ok(Curve {
            rest: points.to_vec(),
            arc,
            frames,
            rest_lengths,
            pose: points.to_vec(),
            placement: Placement::Still,
            handle_count: 0,
            constraints: Vec::new(),
            lo: 0,
            hi: n - 1,
            point_slot: Vec::new(),
            step1: BandLu::default(),
            step2: BandLu::default(),
            layout: Layout::Natural,
            split1: Split::default(),
            split2: Split::default(),
            grown: None,
            #[cfg(test)]
            grew: 0,
            step1_base: Vec::new(),
            step2_base: Vec::new(),
            rhs: Vec::new(),
            scale_free: points.to_vec(),
        })
    }

    /// Number of points (at least 3 for a registered curve).
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// Always false for a registered curve (it has at least 3 points);
    /// here because a `len` wants one.
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// The rest points the curve was registered with.
    pub fn rest(&self) -> &[DVec2] {
        &self.rest
    }

    /// The current deformed points.
    pub fn pose(&self) -> &[DVec2] {
        &self.pose
    }

    /// Puts the curve in a pose (undo, reset): one finite point per rest
    /// point. The compiled handles are dropped, since the points they fix
    /// have moved: compile again before the next update.
    pub fn set_pose(&mut self, points: &[DVec2]) -> Result<(), CurveError> {
        if points.len() != self.rest.len() {
            return Err(TargetError::Count {
                expected: self.rest.len(),
                got: points.len(),
            }
            .into());
        }
        if let Some(point) = targets::out_of_range(points) {
            return Err(CurveError::PointNotFinite { point });
        }
        self.pose.copy_from_slice(points);
        self.grown = None;
        self.constraints.clear();
        self.placement = Placement::Still;
        self.handle_count = 0;
        Ok(())
    }

    /// The rest curve's arc length at each point (0 at point 0).
    pub fn arc_lengths(&self) -> &[f64] {
        &self.arc
    }

    /// The rest curve's total length.
    pub fn length(&self) -> f64 {
        *self.arc.last().expect("a curve has points")
    }

    /// The anchor at arc length `s` along the rest curve (clamped to the
    /// curve).
    pub fn anchor_at(&self, s: f64) -> CurveAnchor {
        let s = s.clamp(0.0, self.length());
        let segment = self
            .arc
            .partition_point(|&a| a <= s)
            .clamp(1, self.len() - 1)
            - 1;
        let t = ((s - self.arc[segment]) / self.rest_lengths[segment]).clamp(0.0, 1.0);
        CurveAnchor::Along {
            segment: segment as u32,
            t,
        }
    }

    /// Where `anchor` is on the current pose (`None` when out of range).
    pub fn pose_point(&self, anchor: CurveAnchor) -> Option<DVec2> {
        Self::point_on(&self.pose, anchor)
    }

    /// Where `anchor` is on the rest curve (`None` when out of range).
    pub fn rest_point(&self, anchor: CurveAnchor) -> Option<DVec2> {
        Self::point_on(&self.rest, anchor)
    }

    fn point_on(points: &[DVec2], anchor: CurveAnchor) -> Option<DVec2> {
        match anchor {
            CurveAnchor::Point(p) => points.get(p as usize).copied(),
            CurveAnchor::Along { segment, t } => {
                let s = segment as usize;
                Some(points.get(s)?.lerp(*points.get(s + 1)?, t))
            }
        }
    }

    /// Compilation with every point free: sets the handle set. Two handles on
    /// or near one point (within half a segment, see the module docs): the
    /// later wins. With fewer than two handles the
    /// curve cannot be solved (rotation and scale are free): with one it
    /// takes its rest shape, rotated as its current pose best fits, and
    /// follows the handle; with none it stays in that rigid placement.
    pub fn compile(&mut self, anchors: &[CurveAnchor]) -> Result<(), CurveError> {
        self.compile_with(anchors, 0..=self.len() - 1, false)
    }

    /// Compilation with only the points `free` movable: the others stay
    /// where the current pose has them and act as handles. Every handle must
    /// hold at least one free point. The systems span only the free points,
    /// so a small interval compiles and updates in proportion.
    ///
    /// A free interval that grew at its ends since the last call, with the
    /// same handles (a peel's region), costs in proportion to the growth:
    /// the systems are split at the first handle into two arms numbered
    /// outward from it (`Split`), whose factors are extended.
    pub fn compile_within(
        &mut self,
        anchors: &[CurveAnchor],
        free: RangeInclusive<usize>,
    ) -> Result<(), CurveError> {
        self.compile_with(anchors, free, true)
    }

    /// Handle `h`'s constraint, holding `anchor` (checked against the
    /// curve, and to hold a point of `free`), its slot not yet numbered.
    fn constraint(
        &self,
        h: usize,
        anchor: CurveAnchor,
        free: RangeInclusive<usize>,
    ) -> Result<Constraint, CurveError> {
        let n = self.len();
        let (lo, hi) = (*free.start(), *free.end());
        let (points, weights) = match anchor {
            CurveAnchor::Point(p) => {
                if p as usize >= n {
                    return Err(CurveError::PointOutOfRange {
                        handle: h,
                        point: p,
                        count: n,
                    });
                }
                ([p as usize; 2], [1.0, 0.0])
            }
            CurveAnchor::Along { segment, t } => {
                if segment as usize >= n - 1 {
                    return Err(CurveError::SegmentOutOfRange {
                        handle: h,
                        segment,
                        count: n - 1,
                    });
                }
                if !(t.is_finite() && (0.0..=1.0).contains(&t)) {
                    return Err(CurveError::BadParameter { handle: h, t });
                }
                let s = segment as usize;
                ([s, s + 1], [1.0 - t, t])
            }
        };
        let holds_free = points
            .iter()
            .zip(weights)
            .any(|(&p, w)| w != 0.0 && (lo..=hi).contains(&p));
        if !holds_free {
            return Err(CurveError::HandleFixed {
                handle: h,
                start: lo,
                end: hi,
            });
        }
        let rest_point = self.rest[points[0]] * weights[0] + self.rest[points[1]] * weights[1];
        Ok(Constraint {
            anchor,
            points,
            weights,
            rest_point,
            target: h,
            slot: 0,
        })
    }

    /// The bandwidths of both steps' systems for the numbering in
    /// `point_slot` (free points `lo..=hi`) and the constraints: step 1
    /// couples points two apart, step 2 neighbours; both couple each
    /// multiplier with its points.
    fn bandwidths(&self, lo: usize, hi: usize) -> [usize; 2] {
        let slot =
            |p: usize| -> Option<usize> { (lo..=hi).contains(&p).then(|| self.point_slot[p - lo]) };
        let mut width1 = 0;
        let mut width2 = 0;
        for p in lo..=hi {
            for q in p + 1..=(p + 2).min(hi) {
                let d = self.point_slot[q - lo] - self.point_slot[p - lo];
                width1 = width1.max(d);
                if q == p + 1 {
                    width2 = width2.max(d);
                }
            }
        }
        for con in &self.constraints {
            for (&p, w) in con.points.iter().zip(con.weights) {
                if let (Some(s), true) = (slot(p), w != 0.0) {
                    width1 = width1.max(s.abs_diff(con.slot));
                    width2 = width2.max(s.abs_diff(con.slot));
                }
            }
        }
        [width1, width2]
    }

    fn compile_with(
        &mut self,
        anchors: &[CurveAnchor],
        free: RangeInclusive<usize>,
        split: bool,
    ) -> Result<(), CurveError> {
        let n = self.len();
        let (lo, hi) = (*free.start(), *free.end());
        if lo > hi || hi >= n {
            return Err(CurveError::BadFreeRange {
                start: lo,
                end: hi,
                count: n,
            });
        }
        let mut constraints = anchors
            .iter()
            .enumerate()
            .map(|(h, anchor)| self.constraint(h, *anchor, lo..=hi))
            .collect::<Result<Vec<_>, _>>()?;
        let live = merge_coincident(&constraints, lo, hi, n);
        let mut kept = live.iter();
        constraints.retain(|_| *kept.next().expect("one flag per constraint"));
        // Multipliers go right after the last free point they hold.
        let last_free = |c: &Constraint| {
            c.points
                .iter()
                .zip(c.weights)
                .filter(|&(&p, w)| w != 0.0 && (lo..=hi).contains(&p))
                .map(|(&p, _)| p)
                .max()
                .expect("checked: holds a free point")
        };
        constraints.sort_by_key(|c| (last_free(c), c.target));

        self.handle_count = anchors.len();
        self.lo = lo;
        self.hi = hi;
        let everything_free = lo == 0 && hi == n - 1;
        if everything_free && constraints.len() < 2 {
            let (rotation, rest_mean, pose_mean) = fit_rotation(&self.rest, &self.pose);
            self.placement = match constraints.first() {
                None => {
                    for (p, r) in self.pose.iter_mut().zip(&self.rest) {
                        *p = pose_mean + rotation.rotate(*r - rest_mean);
                    }
                    Placement::Still
                }
                Some(_) => Placement::Carried { rotation },
            };
            self.constraints = constraints;
            self.grown = None;
            return Ok(());
        }
        if split && self.compile_split(anchors, &mut constraints, lo, hi) {
            self.placement = Placement::Solved;
            return Ok(());
        }
        self.layout = Layout::Natural;
        self.grown = None;

        // Number the unknowns.
        self.point_slot.clear();
        let mut next = 0;
        let mut c = 0;
        for p in lo..=hi {
            self.point_slot.push(next);
            next += 1;
            while c < constraints.len() && last_free(&constraints[c]) == p {
                constraints[c].slot = next;
                next += 1;
                c += 1;
            }
        }
        let size = next;
        self.constraints = constraints;
        self.placement = Placement::Solved;
        self.scale_free.copy_from_slice(&self.pose);

        let [width1, width2] = self.bandwidths(lo, hi);

        self.rhs.clear();
        self.rhs.resize(size, DVec2::ZERO);
        // Each system is factored first with threshold pivoting, then (on
        // growth) partial pivoting; a failed try assembles the system again
        // rather than keep a copy of every band.
        let mut factored = [false; 2];
        for threshold in [PIVOT_THRESHOLD, 1.0] {
            let pending = factored.map(|done| !done);
            self.assemble(size, [width1, width2], pending);
            if pending[0] {
                factored[0] = self.step1.factor_with(threshold);
            }
            if pending[1] {
                factored[1] = self.step2.factor_with(threshold);
            }
            if factored == [true; 2] {
                break;
            }
        }
        let factored = if !factored[0] {
            Err(CurveError::Underdetermined { step: 1 })
        } else if !factored[1] {
            Err(CurveError::Underdetermined { step: 2 })
        } else {
            Ok(())
        };
        if let Err(e) = factored {
            // Keep the curve where it is rather than half-compiled.
            self.constraints.clear();
            self.placement = Placement::Still;
            self.handle_count = anchors.len();
            return Err(e);
        }
        Ok(())
    }

    /// Factors the split systems laid out by `grown`: by growing the last
    /// factors when only the region grew the same arms, else afresh
    /// (threshold pivoting, then partial on growth). False when singular.
    fn factor_split(&mut self, grown: &Grown) -> bool {
        let n = self.len();
        let (lo, hi, (j0, j1), joint) = (grown.lo, grown.hi, grown.joint, grown.joint_size);
        let (sizes, widths, links) = (grown.sizes, grown.widths, grown.links);
        let grows = self.layout == Layout::Split
            && self.grown.as_ref().is_some_and(|g| {
                g.anchors == grown.anchors
                    && g.lo >= lo
                    && g.hi <= hi
                    && (g.joint, g.joint_size, g.widths, g.links)
                        == (grown.joint, joint, widths, links)
                    && g.free == grown.free
            });
        let mut factored = false;
        if grows {
            let old = self.grown.as_ref().expect("checked");
            let (old_lo, old_hi, old_sizes) = (old.lo, old.hi, old.sizes);
            let from = [self.split1.grow(sizes), self.split2.grow(sizes)];
            self.assemble_split(Some((old_lo, old_hi, old_sizes)));
            factored = self.split1.resume(from[0]) && self.split2.resume(from[1]);
            #[cfg(test)]
            {
                self.grew += usize::from(factored);
            }
        }
        if !factored {
            for threshold in [PIVOT_THRESHOLD, 1.0] {
                // The arms reach at most the curve's ends.
                let handles = self.constraints.len();
                let capacity = [j0 + handles, n - j1 + handles];
                self.split1
                    .reset(sizes, capacity, widths[0], joint, links[0]);
                self.split2
                    .reset(sizes, capacity, widths[1], joint, links[1]);
                let all = n + handles;
                for v in [&mut self.step1_base, &mut self.step2_base, &mut self.rhs] {
                    v.reserve(all.saturating_sub(v.len()));
                }
                self.point_slot
                    .reserve(n.saturating_sub(self.point_slot.len()));
                self.assemble_split(None);
                factored = self.split1.factor(threshold) && self.split2.factor(threshold);
                if factored {
                    break;
                }
            }
        }
        factored
    }

    /// Compiles the free points `lo..=hi` as a [`Split`] system, growing
    /// the last one when only the region grew at its ends (same handles):
    /// then only the arms' last columns and the new ones are factored.
    /// False when the joint would take more than [`JOINT`] unknowns or the
    /// split system is singular (the caller compiles it whole).
    fn compile_split(
        &mut self,
        anchors: &[CurveAnchor],
        constraints: &mut [Constraint],
        lo: usize,
        hi: usize,
    ) -> bool {
        let free_of = |c: &Constraint| {
            [0, 1].map(|k| c.weights[k] != 0.0 && (lo..=hi).contains(&c.points[k]))
        };
        // The joint: the first handle's first free point and a neighbour.
        let c = constraints
            .iter()
            .min_by_key(|c| c.target)
            .map_or((lo + hi) / 2, |c| {
                let free = free_of(c);
                c.points[if free[0] { 0 } else { 1 }]
            });
        let (j0, j1) = if c < hi {
            (c, c + 1)
        } else if c > lo {
            (c - 1, c)
        } else {
            (c, c)
        };
        let sides = sides(constraints, free_of, (j0, j1));
        if j1 - j0 + 1 + sides[2].len() > JOINT {
            return false;
        }
        self.point_slot.clear();
        self.point_slot.resize(hi - lo + 1, 0);
        let mut next = 0;
        let mut sizes = [0; 2];
        let arms = [
            (lo..j0).rev().collect::<Vec<_>>(),
            (j1 + 1..=hi).collect::<Vec<_>>(),
        ];
        for (arm, points) in arms.iter().enumerate() {
            let start = next;
            let mut k = 0;
            for &p in points {
                self.point_slot[p - lo] = next;
                next += 1;
                let outer = if arm == 0 { usize::MAX - p } else { p };
                while k < sides[arm].len() && sides[arm][k].0 == outer {
                    constraints[sides[arm][k].2].slot = next;
                    next += 1;
                    k += 1;
                }
            }
            sizes[arm] = next - start;
        }
        for p in j0..=j1 {
            self.point_slot[p - lo] = next;
            next += 1;
        }
        for &(_, _, i) in &sides[2] {
            constraints[i].slot = next;
            next += 1;
        }
        let size = next;
        let joint = size - sizes[0] - sizes[1];
        let arm_of = |s: usize| {
            if s < sizes[0] {
                Some((0, s))
            } else if s < sizes[0] + sizes[1] {
                Some((1, s - sizes[0]))
            } else {
                None
            }
        };
        // Bandwidths per step and arm, from the couplings within an arm.
        let mut widths = [[1; 2]; 2];
        // Which joint unknowns each arm touches (per step): only those
        // border it.
        let mut links = [[[false; JOINT]; 2]; 2];
        let mut couple = |p: usize, q: usize, steps: &[usize]| match (arm_of(p), arm_of(q)) {
            (Some((a, x)), Some((b, y))) if a == b => {
                for &step in steps {
                    widths[step][a] = widths[step][a].max(x.abs_diff(y));
                }
            }
            (Some((a, _)), None) | (None, Some((a, _))) => {
                let k = p.max(q) - sizes[0] - sizes[1];
                for &step in steps {
                    links[step][a][k] = true;
                }
            }
            _ => {}
        };
        for p in lo..=hi {
            for q in p + 1..=(p + 2).min(hi) {
                let steps: &[usize] = if q == p + 1 { &[0, 1] } else { &[0] };
                couple(self.point_slot[p - lo], self.point_slot[q - lo], steps);
            }
        }
        let free: Vec<[bool; 2]> = constraints.iter().map(free_of).collect();
        for (con, free) in constraints.iter().zip(&free) {
            for k in (0..2).filter(|&k| free[k]) {
                couple(self.point_slot[con.points[k] - lo], con.slot, &[0, 1]);
            }
        }
        let grown = Grown {
            anchors: anchors.to_vec(),
            lo,
            hi,
            joint: (j0, j1),
            joint_size: joint,
            sizes,
            widths,
            links,
            free,
        };
        self.constraints = constraints.to_vec();
        let factored = self.factor_split(&grown);
        if !factored {
            self.grown = None;
            return false;
        }
        self.split_bases(size);
        self.rhs.clear();
        self.rhs.resize(size, DVec2::ZERO);
        self.scale_free.copy_from_slice(&self.pose);
        self.grown = Some(grown);
        self.layout = Layout::Split;
        true
    }

    /// Adds the split systems' entries for the free points `lo..=hi`
    /// numbered as `point_slot` says: all of them, or after growing from
    /// `old` (its free points and arm sizes) only those in a new row or
    /// column. Entries between points that were free are unchanged by a
    /// region growing: every energy term holding a free point was already
    /// counted, its new points having been held (their part went to the
    /// right-hand side, which is made again).
    fn assemble_split(&mut self, old: Option<(usize, usize, [usize; 2])>) {
        let (lo, hi, n) = (self.lo, self.hi, self.len());
        let slot =
            |p: usize| -> Option<usize> { (lo..=hi).contains(&p).then(|| self.point_slot[p - lo]) };
        let first_term = lo.saturating_sub(1).max(1);
        let last_term = (hi + 1).min(n - 2);
        let first_segment = lo.saturating_sub(1);
        let last_segment = hi.min(n - 2);
        // Terms and segments holding a new point (or all), each once.
        #[allow(clippy::reversed_empty_ranges)]
        let none = 1..=0;
        let (new, block, terms, segments) = match old {
            None => (
                [0, 0],
                true,
                [first_term..=last_term, none.clone()],
                [first_segment..=last_segment, none],
            ),
            Some((old_lo, old_hi, sizes)) => {
                let left_terms = if lo < old_lo {
                    first_term..=old_lo.min(n - 2)
                } else {
                    none.clone()
                };
                let mut right_start = old_hi.max(1);
                if !left_terms.is_empty() {
                    right_start = right_start.max(*left_terms.end() + 1);
                }
                let right_terms = if hi > old_hi {
                    right_start..=last_term
                } else {
                    none.clone()
                };
                let left_segments = if lo < old_lo {
                    first_segment..=old_lo - 1
                } else {
                    none.clone()
                };
                let right_segments = if hi > old_hi {
                    old_hi..=last_segment
                } else {
                    none
                };
                (
                    sizes,
                    false,
                    [left_terms, right_terms],
                    [left_segments, right_segments],
                )
            }
        };
        let split1 = &mut self.split1;
        for i in terms.into_iter().flatten() {
            let (gamma, points) = step1_term(&self.frames, i);
            let slots = points.map(slot);
            for r in 0..3 {
                let Some(row) = slots[r] else { continue };
                for s in 0..3 {
                    if let Some(col) = slots[s] {
                        split1.add(row, col, mul(conj(gamma[r]), gamma[s]), new, block);
                    }
                }
            }
        }
        let split2 = &mut self.split2;
        for s in segments.into_iter().flatten() {
            let ends = [s, s + 1].map(slot);
            let coefficient = [-1.0, 1.0];
            for r in 0..2 {
                let Some(row) = ends[r] else { continue };
                for k in 0..2 {
                    if let Some(col) = ends[k] {
                        split2.add(row, col, coefficient[r] * coefficient[k], new, block);
                    }
                }
            }
        }
        // A handle's free points are the same as before when growing.
        for con in self.constraints.iter().filter(|_| old.is_none()) {
            for (&p, w) in con.points.iter().zip(con.weights) {
                if let (Some(s), true) = (slot(p), w != 0.0) {
                    self.split1.add(con.slot, s, DVec2::new(w, 0.0), new, block);
                    self.split1.add(s, con.slot, DVec2::new(w, 0.0), new, block);
                    self.split2.add(con.slot, s, w, new, block);
                    self.split2.add(s, con.slot, w, new, block);
                }
            }
        }
    }

    /// The split systems' fixed right-hand sides: the held points' pull
    /// on the free ones, across the region's two ends, and on the
    /// handles.
    fn split_bases(&mut self, size: usize) {
        let (lo, hi, n) = (self.lo, self.hi, self.len());
        let slot =
            |p: usize| -> Option<usize> { (lo..=hi).contains(&p).then(|| self.point_slot[p - lo]) };
        for base in [&mut self.step1_base, &mut self.step2_base] {
            base.clear();
            base.resize(size, DVec2::ZERO);
        }
        let near_lo = lo.saturating_sub(1).max(1)..=(lo + 1).min(n - 2);
        let near_hi = (hi.saturating_sub(1).max(1)).max(lo + 2)..=(hi + 1).min(n - 2);
        for i in near_lo.chain(near_hi) {
            let (gamma, points) = step1_term(&self.frames, i);
            let slots = points.map(slot);
            for r in 0..3 {
                let Some(row) = slots[r] else { continue };
                for s in (0..3).filter(|&s| slots[s].is_none()) {
                    self.step1_base[row] -=
                        mul(mul(conj(gamma[r]), gamma[s]), self.pose[points[s]]);
                }
            }
        }
        let mut segments = [lo.checked_sub(1), (hi + 1 < n).then_some(hi)];
        if segments[0] == segments[1] {
            segments[1] = None;
        }
        for s in segments.into_iter().flatten() {
            let ends = [s, s + 1];
            let coefficient = [-1.0, 1.0];
            for r in 0..2 {
                let Some(row) = slot(ends[r]) else { continue };
                for k in (0..2).filter(|&k| slot(ends[k]).is_none()) {
                    self.step2_base[row] -= self.pose[ends[k]] * (coefficient[r] * coefficient[k]);
                }
            }
        }
        for con in &self.constraints {
            for (&p, w) in con.points.iter().zip(con.weights) {
                if w != 0.0 && slot(p).is_none() {
                    self.step1_base[con.slot] -= self.pose[p] * w;
                    self.step2_base[con.slot] -= self.pose[p] * w;
                }
            }
        }
    }

    /// Fills both systems and their fixed right-hand sides for the free
    /// points `lo..=hi` and the constraints, numbered as `point_slot` says.
    fn assemble(&mut self, size: usize, widths: [usize; 2], which: [bool; 2]) {
        let (lo, hi, n) = (self.lo, self.hi, self.len());
        let [width1, width2] = widths;
        let slot =
            |p: usize| -> Option<usize> { (lo..=hi).contains(&p).then(|| self.point_slot[p - lo]) };
        // Step 1: Σᵢ |γᵢ·(vᵢ₋₁, vᵢ, vᵢ₊₁)|² with γ = (z − 1, 1, −z).
        if which[0] {
            self.step1.reset(size, width1, width1);
            self.step1_base.clear();
            self.step1_base.resize(size, DVec2::ZERO);
        }
        let first_term = lo.saturating_sub(1).max(1);
        let last_term = (hi + 1).min(n - 2);
        let (stride, diagonal) = (self.step1.stride(), self.step1.kl + self.step1.ku);
        let band = &mut self.step1.band;
        for i in (first_term..=last_term).filter(|_| which[0]) {
            let (gamma, points) = step1_term(&self.frames, i);
            let slots = points.map(slot);
            for r in 0..3 {
                let Some(row) = slots[r] else { continue };
                for s in 0..3 {
                    let value = mul(conj(gamma[r]), gamma[s]);
                    match slots[s] {
                        // The band's slot(row, col), without re-reading the
                        // layout from the matrix for every entry.
                        Some(col) => {
                            let entry = &mut band[col * stride + diagonal + row - col];
                            *entry += value;
                        }
                        None => self.step1_base[row] -= mul(value, self.pose[points[s]]),
                    }
                }
            }
        }
        // Step 2: Σₛ |vₛ₊₁ − vₛ − fₛ|² over segments with a free end.
        if which[1] {
            self.step2.reset(size, width2, width2);
            self.step2_base.clear();
            self.step2_base.resize(size, DVec2::ZERO);
        }
        for s in (lo.saturating_sub(1)..=hi.min(n - 2)).filter(|_| which[1]) {
            let ends = [s, s + 1];
            let coefficient = [-1.0, 1.0];
            for r in 0..2 {
                let Some(row) = slot(ends[r]) else { continue };
                for k in 0..2 {
                    let value: f64 = coefficient[r] * coefficient[k];
                    match slot(ends[k]) {
                        Some(col) => self.step2.add(row, col, value),
                        None => self.step2_base[row] -= self.pose[ends[k]] * value,
                    }
                }
            }
        }
        for con in &self.constraints {
            for (&p, w) in con.points.iter().zip(con.weights) {
                if w == 0.0 {
                    continue;
                }
                match slot(p) {
                    Some(s) if which[0] || which[1] => {
                        if which[1] {
                            self.step2.add(con.slot, s, w);
                            self.step2.add(s, con.slot, w);
                        }
                        if which[0] {
                            let w = DVec2::new(w, 0.0);
                            self.step1.add(con.slot, s, w);
                            self.step1.add(s, con.slot, w);
                        }
                    }
                    Some(_) => {}
                    None => {
                        if which[0] {
                            self.step1_base[con.slot] -= self.pose[p] * w;
                        }
                        if which[1] {
                            self.step2_base[con.slot] -= self.pose[p] * w;
                        }
                    }
                }
            }
        }
    }

    /// Update: moves the compiled handles to `targets` (same order as the
    /// anchors given to compile) and recomputes the pose. Does not allocate.
    pub fn update(&mut self, targets: &[DVec2], steps: Steps) -> Result<&[DVec2], CurveError> {
        targets::check(targets, self.handle_count)?;
        match self.placement {
            Placement::Still => {}
            Placement::Carried { rotation } => {
                let handle = &self.constraints[0];
                let to = targets[handle.target];
                for (p, r) in self.pose.iter_mut().zip(&self.rest) {
                    *p = to + rotation.rotate(*r - handle.rest_point);
                }
            }
            Placement::Solved => self.solve(targets, steps),
        }
        Ok(&self.pose)
    }

    fn solve(&mut self, targets: &[DVec2], steps: Steps) {
        let (lo, hi, n) = (self.lo, self.hi, self.len());
        self.rhs.copy_from_slice(&self.step1_base);
        for con in &self.constraints {
            self.rhs[con.slot] += targets[con.target];
        }
        match self.layout {
            Layout::Natural => self.step1.solve(&mut self.rhs),
            Layout::Split => self.split1.solve(&mut self.rhs),
        }
        for (p, &s) in (lo..=hi).zip(&self.point_slot) {
            self.scale_free[p] = self.rhs[s];
        }
        if steps == Steps::ScaleFree {
            self.pose[lo..=hi].copy_from_slice(&self.scale_free[lo..=hi]);
            return;
        }
        self.rhs.copy_from_slice(&self.step2_base);
        for con in &self.constraints {
            self.rhs[con.slot] += targets[con.target];
        }
        // fₛ: the step-1 segment's direction at the rest segment's length.
        for s in lo.saturating_sub(1)..=hi.min(n - 2) {
            let d = self.scale_free[s + 1] - self.scale_free[s];
            let length = d.length();
            let f = if length > 0.0 {
                d * (self.rest_lengths[s] / length)
            } else {
                // A collapsed step-1 segment has no direction: keep rest.
                self.rest[s + 1] - self.rest[s]
            };
            // s runs from lo − 1 to at most hi: its start point is free
            // from lo on, its end point up to hi.
            if s >= lo {
                self.rhs[self.point_slot[s - lo]] -= f;
            }
            if s < hi {
                self.rhs[self.point_slot[s + 1 - lo]] += f;
            }
        }
        match self.layout {
            Layout::Natural => self.step2.solve(&mut self.rhs),
            Layout::Split => self.split2.solve(&mut self.rhs),
        }
        for (p, &s) in (lo..=hi).zip(&self.point_slot) {
            self.pose[p] = self.rhs[s];
        }
    }

    /// The free points of the compiled system.
    pub fn free_points(&self) -> RangeInclusive<usize> {
        self.lo..=self.hi
    }

    /// The compiled handles that are in effect, in the caller's numbering.
    pub fn live_handles(&self) -> impl Iterator<Item = (usize, CurveAnchor)> + '_ {
        self.constraints.iter().map(|c| (c.target, c.anchor))
    }
}

/// How the peeled region grows: radius `initial_radius + growth_rate · d`
/// (arc length) for drag distance `d`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeelParams {
    /// Region radius at the grab, as arc length in the curve's units
    /// (default 0: just the grabbed segment). Finite and non-negative.
    pub initial_radius: f64,
    /// Arc length the region gains per unit of drag distance (default
    /// 1.5). Finite and non-negative.
    pub growth_rate: f64,
}

impl Default for PeelParams {
    /// The region starts with the grabbed segment and reaches a little
    /// further than the finger has travelled.
    fn default() -> Self {
        PeelParams {
            initial_radius: 0.0,
            growth_rate: 1.5,
        }
    }
}

/// The peeling interface (the paper's Figure 12): one drag's influence
/// region along the rest curve. It grows with the largest drag distance so
/// far (never shrinks during a drag), stops at the nearest virtual pushpin on
/// either side and at the curve's ends. Points outside it stay put.
#[derive(Debug, Clone)]
pub struct Peel {
    params: PeelParams,
    grab: f64,
    grab_anchor: CurveAnchor,
    /// The region may not pass these arc lengths (pushpins or the ends).
    limits: (f64, f64),
    /// Whether each limit is an end of the curve (which then moves too).
    open_ends: (bool, bool),
    largest_drag: f64,
    region: (f64, f64),
    free: RangeInclusive<usize>,
}

impl Peel {
    /// A drag grabbing `curve` at arc length `grab` (rest curve), with
    /// pushpins at the given arc lengths. Allocates nothing afterwards.
    pub fn new(
        curve: &Curve,
        grab: f64,
        pushpins: &[f64],
        params: PeelParams,
    ) -> Result<Peel, CurveError> {
        for (field, value) in [
            ("initial_radius", params.initial_radius),
            ("growth_rate", params.growth_rate),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(CurveError::BadPeelParameter { field, value });
            }
        }
        let length = curve.length();
        if !(grab.is_finite() && (0.0..=length).contains(&grab)) {
            return Err(CurveError::GrabOffCurve { at: grab, length });
        }
        let (mut below, mut above) = (0.0, length);
        let (mut open_below, mut open_above) = (true, true);
        for (pushpin, &at) in pushpins.iter().enumerate() {
            if !(at.is_finite() && (0.0..=length).contains(&at)) {
                return Err(CurveError::PushpinOffCurve {
                    pushpin,
                    at,
                    length,
                });
            }
            if at == grab {
                return Err(CurveError::PushpinAtGrab { pushpin });
            }
            if at < grab && (at > below || open_below) {
                below = at;
                open_below = false;
            }
            if at > grab && (at < above || open_above) {
                above = at;
                open_above = false;
            }
        }
        let mut peel = Peel {
            params,
            grab,
            grab_anchor: curve.anchor_at(grab),
            limits: (below, above),
            open_ends: (open_below, open_above),
            largest_drag: 0.0,
            region: (grab, grab),
            free: 0..=0,
        };
        peel.free = peel.free_for(curve, peel.region_for(0.0));
        peel.region = peel.region_for(0.0);
        Ok(peel)
    }

    /// The grabbed point, as a handle for [`Curve::compile_within`].
    pub fn grab_anchor(&self) -> CurveAnchor {
        self.grab_anchor
    }

    /// The drag moved `distance` from the grab point. Returns whether the
    /// free points changed (then compile again with [`Peel::free_points`]).
    pub fn drag(&mut self, curve: &Curve, distance: f64) -> Result<bool, CurveError> {
        if !(distance.is_finite() && distance >= 0.0) {
            return Err(CurveError::BadDragDistance { distance });
        }
        if distance <= self.largest_drag {
            return Ok(false);
        }
        self.largest_drag = distance;
        self.region = self.region_for(distance);
        let free = self.free_for(curve, self.region);
        let changed = free != self.free;
        self.free = free;
        Ok(changed)
    }

    /// The influence region as arc lengths along the rest curve.
    pub fn region(&self) -> (f64, f64) {
        self.region
    }

    /// The points the region frees.
    pub fn free_points(&self) -> RangeInclusive<usize> {
        self.free.clone()
    }

    fn region_for(&self, distance: f64) -> (f64, f64) {
        let radius = self.params.initial_radius + self.params.growth_rate * distance;
        (
            (self.grab - radius).max(self.limits.0),
            (self.grab + radius).min(self.limits.1),
        )
    }

    /// Points strictly inside the region, the curve's ends once the region
    /// reaches them, and always the grabbed segment's ends, so the grab can
    /// move.
    fn free_for(&self, curve: &Curve, (below, above): (f64, f64)) -> RangeInclusive<usize> {
        let arc = curve.arc_lengths();
        let last = arc.len() - 1;
        let mut start = arc.partition_point(|&a| a <= below);
        if self.open_ends.0 && below <= 0.0 {
            start = 0;
        }
        let mut end = arc.partition_point(|&a| a < above).saturating_sub(1);
        if self.open_ends.1 && above >= arc[last] {
            end = last;
        }
        let (grab_first, grab_last) = match self.grab_anchor {
            CurveAnchor::Point(p) => (p as usize, p as usize),
            CurveAnchor::Along { segment, .. } => (segment as usize, segment as usize + 1),
        };
        start.min(grab_first)..=end.max(grab_last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic band matrix with zeros on some diagonal entries, so
    /// factoring must fall back to pivoting.
    fn band_matrix(n: usize, kl: usize, ku: usize) -> Vec<Vec<f64>> {
        let mut a = vec![vec![0.0; n]; n];
        for (i, row) in a.iter_mut().enumerate() {
            for (j, entry) in row.iter_mut().enumerate() {
                if j + kl >= i && i + ku >= j {
                    *entry = ((i * 7 + j * 13) % 11) as f64 - 5.0 + if i == j { 0.5 } else { 0.0 };
                }
            }
            if i % 4 == 0 {
                row[i] = 0.0;
            }
        }
        a
    }

    /// Factors `a` and solves it for a known `x`; returns the factors.
    fn solves(a: &[Vec<f64>], kl: usize, ku: usize) -> BandLu<f64> {
        let n = a.len();
        let mut lu = BandLu::<f64>::default();
        let assemble = |lu: &mut BandLu<f64>| {
            lu.reset(n, kl, ku);
            for (i, row) in a.iter().enumerate() {
                for (j, &v) in row.iter().enumerate() {
                    if v != 0.0 {
                        lu.add(i, j, v);
                    }
                }
            }
        };
        assemble(&mut lu);
        if !lu.factor_with(PIVOT_THRESHOLD) {
            assemble(&mut lu);
            assert!(lu.factor_with(1.0), "the matrix is nonsingular");
        }
        let x: Vec<DVec2> = (0..n)
            .map(|i| DVec2::new(i as f64 * 0.5 - 3.0, (i % 5) as f64))
            .collect();
        let mut b: Vec<DVec2> = a
            .iter()
            .map(|row| row.iter().zip(&x).map(|(&v, &xi)| xi * v).sum())
            .collect();
        lu.solve(&mut b);
        for (got, want) in b.iter().zip(&x) {
            assert!(got.distance(*want) < 1e-9, "{got} != {want}");
        }
        lu
    }

    fn swapped(lu: &BandLu<f64>) -> bool {
        lu.lower_runs.iter().any(|r| r.swaps)
    }

    fn widest(runs: &[Run]) -> usize {
        runs.iter().map(|r| r.width).max().unwrap_or(0)
    }

    #[test]
    fn a_matrix_that_needs_row_swaps_is_solved_in_registers_and_wide() {
        let lu = solves(&band_matrix(40, 2, 2), 2, 2);
        assert!(
            swapped(&lu) && widest(&lu.upper_runs) <= WIDEST,
            "pivoted, in registers"
        );
        let lu = solves(&band_matrix(40, 5, 5), 5, 5);
        assert!(
            swapped(&lu) && widest(&lu.upper_runs) > WIDEST,
            "pivoted, through memory"
        );
    }

    /// A tridiagonal matrix with two wider stretches (like a multiplier's
    /// row among its points) is packed in runs of different widths, and
    /// each run hands its window on to the next.
    #[test]
    fn a_matrix_of_varying_width_is_solved_run_by_run() {
        let n = 200;
        let mut a = vec![vec![0.0; n]; n];
        for i in 0..n {
            a[i][i] = 4.0 + (i % 3) as f64;
            if i + 1 < n {
                a[i][i + 1] = -1.0 - (i % 2) as f64 * 0.5;
                a[i + 1][i] = -1.0;
            }
        }
        for &(i, j) in &[(70, 73), (150, 154)] {
            a[i][j] = 0.7;
            a[j][i] = -0.4;
        }
        let lu = solves(&a, 4, 4);
        assert!(!swapped(&lu));
        for runs in [&lu.lower_runs, &lu.upper_runs] {
            let widths: Vec<usize> = runs.iter().map(|r| r.width).collect();
            assert!(widths.len() >= 3 && widths.contains(&1), "{widths:?}");
            assert!(widest(runs) >= 3, "{widths:?}");
            assert_eq!(runs.first().map(|r| r.start), Some(0));
            assert_eq!(runs.last().map(|r| r.end), Some(n));
            assert!(runs.windows(2).all(|w| w[0].end == w[1].start));
        }
    }

    fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(p, q)| p.distance(*q))
            .fold(0.0, f64::max)
    }

    /// A wavy curve that is not at rest: every point has moved, so the
    /// held points pull on the free ones.
    fn posed_wave(n: usize) -> Curve {
        let rest: Vec<DVec2> = (0..n)
            .map(|i| {
                let x = i as f64;
                DVec2::new(x, 3.0 * (x * 0.35).sin() + 0.002 * x * x)
            })
            .collect();
        let mut curve = Curve::register(&rest).unwrap();
        let ends = [CurveAnchor::Point(0), CurveAnchor::Point(n as u32 - 1)];
        curve.compile(&ends).unwrap();
        curve
            .update(
                &[DVec2::new(3.0, 1.0), DVec2::new(n as f64 - 9.0, 20.0)],
                Steps::Both,
            )
            .unwrap();
        curve
    }

    /// Grows a region step by step (both ends, one end, by one point, up
    /// to the curve's ends) and measures how far each grown compile's
    /// solves are from a fresh compile of the same region; with `stale`
    /// the arms keep their last columns' factors when growing.
    fn grown_against_fresh(stale: bool) -> f64 {
        let n = 300;
        let mut curve = posed_wave(n);
        let pose = curve.pose().to_vec();
        // The grab (the joint) and a second handle in the left arm.
        let anchors = [
            CurveAnchor::Along {
                segment: 150,
                t: 0.4,
            },
            CurveAnchor::Point(140),
        ];
        let targets = [
            curve.pose_point(anchors[0]).unwrap() + DVec2::new(4.0, 30.0),
            curve.pose_point(anchors[1]).unwrap() + DVec2::new(-2.0, 10.0),
        ];
        let regions = [
            130..=170,
            120..=176,
            100..=176,
            100..=177,
            60..=240,
            0..=n - 1,
        ];
        let mut worst = 0.0f64;
        for (k, free) in regions.into_iter().enumerate() {
            curve.compile_within(&anchors, free.clone()).unwrap();
            assert_eq!(curve.layout, Layout::Split);
            assert_eq!(curve.grew, k, "region {free:?} grew the last one");
            for arm in curve.split1.arms.iter_mut() {
                arm.stale = stale;
            }
            for arm in curve.split2.arms.iter_mut() {
                arm.stale = stale;
            }
            let mut fresh = Curve::register(curve.rest()).unwrap();
            fresh.set_pose(&pose).unwrap();
            fresh.compile_within(&anchors, free.clone()).unwrap();
            assert_eq!(fresh.grew, 0);
            // And the one banded system along the curve, which solves the
            // same problem in another order.
            let mut natural = Curve::register(curve.rest()).unwrap();
            natural.set_pose(&pose).unwrap();
            natural.compile_with(&anchors, free.clone(), false).unwrap();
            assert_eq!(natural.layout, Layout::Natural);
            for steps in [Steps::ScaleFree, Steps::Both] {
                let want = fresh.update(&targets, steps).unwrap().to_vec();
                let along = natural.update(&targets, steps).unwrap();
                let off = max_distance(along, &want);
                // Rounding differs between the orders, amplified by the
                // conditioning: a free end's bending stiffness falls with
                // the cube of its length (the whole curve here has two
                // handles near its middle).
                let tolerance = if free == (0..=n - 1) { 1e-4 } else { 1e-7 };
                assert!(
                    off < tolerance,
                    "{free:?} {steps:?}: split off natural by {off}"
                );
                let got = curve.update(&targets, steps).unwrap();
                worst = worst.max(max_distance(got, &want));
            }
        }
        worst
    }

    #[test]
    fn a_grown_region_solves_as_a_fresh_compile_of_it() {
        let off = grown_against_fresh(false);
        assert!(off <= 1e-12, "grown off fresh by {off}");
        // The check catches factors kept where the growth changed them.
        let stale = grown_against_fresh(true);
        assert!(stale > 1e-3, "stale factors off fresh by only {stale}");
    }
}
