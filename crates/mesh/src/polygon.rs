//! Polygon outlines as meshing input: the [`Shape`] type (islands, each an
//! outer ring with holes), its JSON form, and its validation — finite
//! points, rings that neither cross nor touch themselves or each other, holes
//! inside their outer ring, islands that do not overlap. Also the geometric
//! helpers the tracer and the mesher share: signed area, point in ring and a
//! grid-bucketed segment crossing search that stays fast on rings with
//! thousands of points.
//!
//! Coordinates are y-up in pixel units; ring orientation on input is free.

use glam::DVec2;
use serde::Deserialize;

use super::grid::BucketGrid;
use super::json::{self, Point};
use super::{MeshError, cross, invalid};

/// Largest coordinate magnitude accepted: far beyond any picture, yet small
/// enough that areas and tolerances stay finite and meaningful.
pub use super::json::MAX_COORDINATE;

/// One island: an outer ring and the holes cut out of it. Rings are closed
/// implicitly (the last point connects back to the first).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Polygon {
    /// The island's boundary: at least 3 distinct points, either orientation
    /// (counter-clockwise once [`Shape::normalized`]).
    pub outer: Vec<DVec2>,
    /// Rings cut out of the island, each inside `outer` and none inside
    /// another (clockwise once normalised).
    pub holes: Vec<Vec<DVec2>>,
}

/// Everything to mesh: one or more islands. An island may sit inside another
/// island's hole, but islands never overlap.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Shape {
    /// The islands; at least one for a valid shape. A traced picture lists
    /// its largest island first.
    pub polygons: Vec<Polygon>,
}

/// The JSON form: either a single polygon (`outer`, optional `holes`) or a
/// list of them (`polygons`). One struct with optional fields rather than an
/// untagged enum, so serde keeps precise line/column positions in errors.
#[derive(Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = "a polygon object {\"outer\": [[x, y], …], \"holes\": […]} or {\"polygons\": […]}"
)]
struct ShapeFile {
    outer: Option<Vec<Point>>,
    holes: Option<Vec<Vec<Point>>>,
    polygons: Option<Vec<PolygonFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PolygonFile {
    outer: Vec<Point>,
    #[serde(default)]
    holes: Vec<Vec<Point>>,
}

fn to_points(ring: Vec<Point>) -> Vec<DVec2> {
    ring.into_iter().map(|p| DVec2::from(p.0)).collect()
}

/// Which ring of a shape: the island and, for a hole, its index.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct RingId {
    pub polygon: usize,
    pub hole: Option<usize>,
}

impl RingId {
    /// The ring's field name as the JSON spells it; a lone island is written
    /// without the `polygons` wrapper, so it is named without it too.
    fn name(self, islands: usize) -> String {
        let ring = match self.hole {
            None => "outer".to_string(),
            Some(h) => format!("holes[{h}]"),
        };
        if islands == 1 {
            ring
        } else {
            format!("polygons[{}].{ring}", self.polygon)
        }
    }
}

impl Shape {
    /// Parses and validates a shape; `source` names the text in errors. The
    /// result has repeated consecutive points dropped, outer rings
    /// counter-clockwise and holes clockwise.
    pub fn from_json(source: &str, text: &str) -> Result<Shape, MeshError> {
        let file: ShapeFile = json::parse(source, text)?;
        let shape = match (file.outer, file.holes, file.polygons) {
            (Some(outer), holes, None) => Shape {
                polygons: vec![Polygon {
                    outer: to_points(outer),
                    holes: holes
                        .unwrap_or_default()
                        .into_iter()
                        .map(to_points)
                        .collect(),
                }],
            },
            (None, None, Some(polygons)) => Shape {
                polygons: polygons
                    .into_iter()
                    .map(|p| Polygon {
                        outer: to_points(p.outer),
                        holes: p.holes.into_iter().map(to_points).collect(),
                    })
                    .collect(),
            },
            (None, Some(_), None) => {
                return Err(invalid(
                    source,
                    "outer",
                    "is missing: \"holes\" needs an \"outer\" ring to cut them from",
                ));
            }
            (None, None, None) => {
                return Err(invalid(
                    source,
                    "outer",
                    "is missing: give either \"outer\" (one polygon, optional \"holes\") \
                     or \"polygons\" (a list of them)",
                ));
            }
            (_, _, Some(_)) => {
                return Err(invalid(
                    source,
                    "polygons",
                    "cannot be combined with a top-level \"outer\" or \"holes\"; \
                     put every polygon inside \"polygons\"",
                ));
            }
        };
        shape.validate(source)?;
        Ok(shape.normalized())
    }

    /// Checks that the shape can be meshed; errors name the offending ring
    /// (`outer`, `holes[1]`, `polygons[2].outer`) and, for crossings, both
    /// segments by their index in the ring as given.
    pub fn validate(&self, source: &str) -> Result<(), MeshError> {
        let islands = self.polygons.len();
        if islands == 0 {
            return Err(invalid(source, "polygons", "there are no polygons"));
        }
        let ids = self.ring_ids();
        let cleaned = ids
            .iter()
            .map(|&id| self.cleaned_ring(source, id))
            .collect::<Result<Vec<_>, _>>()?;
        check_crossings(source, islands, &ids, &cleaned)?;
        // Crossings first: a bow tie may have zero area, and its crossing is
        // the better message. A ring that passed is degenerate only if flat.
        for (k, (points, _)) in cleaned.iter().enumerate() {
            if signed_area(points) == 0.0 {
                return Err(invalid(source, ids[k].name(islands), "encloses no area"));
            }
        }

        self.check_nesting(source, &cleaned)
    }

    /// Ring `id` without repeated points, with the index each kept point
    /// had as given; an error for a point that is not finite or too far
    /// out, or fewer than three distinct points.
    fn cleaned_ring(
        &self,
        source: &str,
        id: RingId,
    ) -> Result<(Vec<DVec2>, Vec<usize>), MeshError> {
        let islands = self.polygons.len();
        let ring = self.ring(id);
        if let Some(i) = ring.iter().position(|p| !p.is_finite()) {
            return Err(invalid(
                source,
                id.name(islands),
                format!(
                    "point {i} is not a finite number: {}",
                    json::show_point(ring[i])
                ),
            ));
        }
        if let Some(i) = ring
            .iter()
            .position(|p| p.abs().max_element() > MAX_COORDINATE)
        {
            return Err(invalid(
                source,
                id.name(islands),
                format!(
                    "point {i} ({}) is too far out: coordinates are pixels and \
                     must stay within ±{MAX_COORDINATE:e}",
                    json::show_point(ring[i])
                ),
            ));
        }
        let (points, index) = drop_repeats(ring);
        if points.len() < 3 {
            return Err(invalid(
                source,
                id.name(islands),
                format!(
                    "has {} distinct points; a ring needs at least 3",
                    points.len()
                ),
            ));
        }
        Ok((points, index))
    }

    /// With no crossings anywhere (the rings `cleaned`, in `ring_ids`
    /// order), one point decides which side of a ring another ring lies
    /// on: every hole inside its own outer ring and no other hole, no
    /// island inside another but in a hole.
    fn check_nesting(
        &self,
        source: &str,
        cleaned: &[(Vec<DVec2>, Vec<usize>)],
    ) -> Result<(), MeshError> {
        let islands = self.polygons.len();
        let ring_boxes: Vec<(DVec2, DVec2)> = cleaned.iter().map(|(p, _)| bounds(p)).collect();
        let first_ring: Vec<usize> = self
            .polygons
            .iter()
            .scan(0, |next, p| {
                let first = *next;
                *next += 1 + p.holes.len();
                Some(first)
            })
            .collect();
        let slot = |id: RingId| first_ring[id.polygon] + id.hole.map_or(0, |h| h + 1);
        let ring_of = |id: RingId| cleaned[slot(id)].0.as_slice();
        // Whether ring `a`'s box holds ring `b`'s: a cheap filter before the
        // point-in-ring test.
        let box_holds = |a: RingId, b: RingId| {
            let (lo_a, hi_a) = ring_boxes[slot(a)];
            let (lo_b, hi_b) = ring_boxes[slot(b)];
            lo_b.x >= lo_a.x && lo_b.y >= lo_a.y && hi_b.x <= hi_a.x && hi_b.y <= hi_a.y
        };
        for (p, polygon) in self.polygons.iter().enumerate() {
            let outer = ring_of(RingId {
                polygon: p,
                hole: None,
            });
            for h in 0..polygon.holes.len() {
                let id = RingId {
                    polygon: p,
                    hole: Some(h),
                };
                let hole = ring_of(id);
                if !point_in_ring(hole[0], outer) {
                    return Err(invalid(
                        source,
                        id.name(islands),
                        format!(
                            "lies outside its polygon's outer ring ({})",
                            RingId {
                                polygon: p,
                                hole: None
                            }
                            .name(islands)
                        ),
                    ));
                }
                for g in 0..polygon.holes.len() {
                    let other = RingId {
                        polygon: p,
                        hole: Some(g),
                    };
                    if g != h && box_holds(other, id) && point_in_ring(hole[0], ring_of(other)) {
                        return Err(invalid(
                            source,
                            id.name(islands),
                            format!(
                                "lies inside {}; a hole inside a hole is an island, \
                                 give it as a separate polygon",
                                other.name(islands)
                            ),
                        ));
                    }
                }
            }
        }

        for a in 0..islands {
            let outer_a = ring_of(RingId {
                polygon: a,
                hole: None,
            });
            for b in 0..islands {
                if a == b {
                    continue;
                }
                let outer = |p: usize| RingId {
                    polygon: p,
                    hole: None,
                };
                if !box_holds(outer(a), outer(b)) {
                    continue;
                }
                let probe = ring_of(RingId {
                    polygon: b,
                    hole: None,
                })[0];
                if !point_in_ring(probe, outer_a) {
                    continue;
                }
                let in_hole = (0..self.polygons[a].holes.len()).any(|h| {
                    point_in_ring(
                        probe,
                        ring_of(RingId {
                            polygon: a,
                            hole: Some(h),
                        }),
                    )
                });
                if !in_hole {
                    return Err(invalid(
                        source,
                        RingId {
                            polygon: b,
                            hole: None,
                        }
                        .name(islands),
                        format!(
                            "lies inside polygons[{a}]: islands must not overlap \
                             (an island may only sit inside another island's hole)"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The same shape with repeated consecutive points dropped, outer rings
    /// counter-clockwise and holes clockwise (y-up), so the inside is always
    /// on the left of a ring's direction.
    pub fn normalized(&self) -> Shape {
        let orient = |ring: &[DVec2], ccw: bool| {
            let mut points = drop_repeats(ring).0;
            if (signed_area(&points) > 0.0) != ccw {
                points.reverse();
            }
            points
        };
        Shape {
            polygons: self
                .polygons
                .iter()
                .map(|p| Polygon {
                    outer: orient(&p.outer, true),
                    holes: p.holes.iter().map(|h| orient(h, false)).collect(),
                })
                .collect(),
        }
    }

    /// The enclosed area: outer rings minus their holes.
    pub fn area(&self) -> f64 {
        self.polygons
            .iter()
            .map(|p| {
                signed_area(&p.outer).abs()
                    - p.holes.iter().map(|h| signed_area(h).abs()).sum::<f64>()
            })
            .sum()
    }

    /// The total length of every ring.
    pub fn perimeter(&self) -> f64 {
        self.rings().map(ring_length).sum()
    }

    /// Every ring, outer rings before their holes, island by island.
    pub fn rings(&self) -> impl Iterator<Item = &[DVec2]> {
        self.polygons.iter().flat_map(|p| {
            std::iter::once(p.outer.as_slice()).chain(p.holes.iter().map(Vec::as_slice))
        })
    }

    pub(crate) fn ring_ids(&self) -> Vec<RingId> {
        let mut ids = Vec::new();
        for (p, polygon) in self.polygons.iter().enumerate() {
            ids.push(RingId {
                polygon: p,
                hole: None,
            });
            ids.extend((0..polygon.holes.len()).map(|h| RingId {
                polygon: p,
                hole: Some(h),
            }));
        }
        ids
    }

    pub(crate) fn ring(&self, id: RingId) -> &[DVec2] {
        let polygon = &self.polygons[id.polygon];
        match id.hole {
            None => &polygon.outer,
            Some(h) => &polygon.holes[h],
        }
    }

    pub(crate) fn ring_mut(&mut self, id: RingId) -> &mut Vec<DVec2> {
        let polygon = &mut self.polygons[id.polygon];
        match id.hole {
            None => &mut polygon.outer,
            Some(h) => &mut polygon.holes[h],
        }
    }
}

/// An error naming the first crossing or touching of the rings
/// `cleaned` (named by `ids`), if they have one: both segments by their
/// index in the ring as given.
fn check_crossings(
    source: &str,
    islands: usize,
    ids: &[RingId],
    cleaned: &[(Vec<DVec2>, Vec<usize>)],
) -> Result<(), MeshError> {
    let rings: Vec<&[DVec2]> = cleaned.iter().map(|(p, _)| p.as_slice()).collect();
    if let Some(c) = find_crossing(&rings) {
        let segment = |r: usize, s: usize| {
            let (points, index) = &cleaned[r];
            let a = points[s];
            let b = points[(s + 1) % points.len()];
            format!(
                "segment {} ({}-{})",
                index[s],
                json::show_point(a),
                json::show_point(b)
            )
        };
        let first = segment(c.ring_a, c.seg_a);
        let mut second = segment(c.ring_b, c.seg_b);
        if c.ring_a != c.ring_b {
            second = format!("{} {second}", ids[c.ring_b].name(islands));
        }
        let verb = if c.ring_a == c.ring_b && c.folds {
            "folds back onto"
        } else {
            "crosses or touches"
        };
        return Err(invalid(
            source,
            ids[c.ring_a].name(islands),
            format!("{first} {verb} {second}"),
        ));
    }

    Ok(())
}

/// The ring without repeated consecutive points (the closing pair included),
/// and for each kept point its index in the input.
fn drop_repeats(ring: &[DVec2]) -> (Vec<DVec2>, Vec<usize>) {
    let mut points = Vec::with_capacity(ring.len());
    let mut index = Vec::with_capacity(ring.len());
    for (i, &p) in ring.iter().enumerate() {
        if points.last() != Some(&p) {
            points.push(p);
            index.push(i);
        }
    }
    while points.len() > 1 && points.first() == points.last() {
        points.pop();
        index.pop();
    }
    (points, index)
}

/// The signed area of a ring (positive when counter-clockwise in the y-up
/// frame).
pub fn signed_area(ring: &[DVec2]) -> f64 {
    let n = ring.len();
    if n < 3 {
        return 0.0;
    }
    // Relative to the first point, so large offsets do not eat precision.
    let o = ring[0];
    let mut sum = 0.0;
    for i in 1..n - 1 {
        sum += cross(o, ring[i], ring[i + 1]);
    }
    sum * 0.5
}

/// The length of a closed ring.
pub fn ring_length(ring: &[DVec2]) -> f64 {
    let n = ring.len();
    (0..n).map(|i| ring[i].distance(ring[(i + 1) % n])).sum()
}

/// Whether `p` lies inside a closed ring (even-odd rule; points exactly on
/// the ring may go either way).
pub fn point_in_ring(p: DVec2, ring: &[DVec2]) -> bool {
    let n = ring.len();
    let mut inside = false;
    let mut j = n.wrapping_sub(1);
    for i in 0..n {
        let a = ring[i];
        let b = ring[j];
        if (a.y > p.y) != (b.y > p.y) {
            let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
            if p.x < x {
                inside = !inside;
            }
        }
        j = i;
    }
    inside
}

pub(crate) fn bounds(points: &[DVec2]) -> (DVec2, DVec2) {
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    for &p in points {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    (lo, hi)
}

/// Two ring segments that meet where they must not. Segment `s` of a ring
/// runs from point `s` to point `s + 1` (wrapping).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Crossing {
    pub ring_a: usize,
    pub seg_a: usize,
    pub ring_b: usize,
    pub seg_b: usize,
    /// Neighbouring segments of one ring that overlap by doubling back.
    pub folds: bool,
}

/// The first pair of segments that cross, touch or overlap, among all rings
/// (repeated consecutive points must already be gone). Segments are bucketed
/// in a uniform grid along the cells they actually pass through, so the cost
/// is about linear in the number of segments for sane inputs. Touching is
/// judged with a tolerance of 1e-9 of the overall size, so nearly touching
/// rings are rejected rather than left to rounding.
pub(crate) fn find_crossing(rings: &[&[DVec2]]) -> Option<Crossing> {
    let mut segs: Vec<(u32, u32)> = Vec::new();
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    let mut total_len = 0.0;
    for (r, ring) in rings.iter().enumerate() {
        let (l, h) = bounds(ring);
        lo = lo.min(l);
        hi = hi.max(h);
        total_len += ring_length(ring);
        segs.extend((0..ring.len() as u32).map(|s| (r as u32, s)));
    }
    let m = segs.len();
    if m == 0 {
        return None;
    }
    let extent = (hi - lo).max(DVec2::splat(f64::MIN_POSITIVE));
    let tol = 1e-9 * extent.length();
    let mut cell = (extent.x * extent.y / m as f64)
        .sqrt()
        .max(total_len / m as f64)
        .max(extent.max_element() / 4096.0);
    let dims = |cell: f64| {
        (
            ((extent.x / cell).floor() as usize + 1),
            ((extent.y / cell).floor() as usize + 1),
        )
    };
    while {
        let (c, r) = dims(cell);
        c * r > 4 * m + 64
    } {
        cell *= 1.5;
    }
    let endpoints = |(r, s): (u32, u32)| {
        let ring = rings[r as usize];
        let s = s as usize;
        (ring[s], ring[(s + 1) % ring.len()])
    };
    // Cells a segment passes through, column strip by column strip, padded
    // by the touching tolerance.
    let grid = BucketGrid::new(lo, hi, cell, segs.len(), |shape, i, visit| {
        let (a, b) = endpoints(segs[i]);
        let (a, b) = if a.x <= b.x { (a, b) } else { (b, a) };
        for c in shape.column(a.x - tol)..=shape.column(b.x + tol) {
            let x0 = (lo.x + c as f64 * cell).max(a.x);
            let x1 = (lo.x + (c + 1) as f64 * cell).min(b.x);
            let y_at = |x: f64| {
                if b.x - a.x <= 0.0 {
                    a.y
                } else {
                    a.y + (b.y - a.y) * ((x - a.x) / (b.x - a.x)).clamp(0.0, 1.0)
                }
            };
            let (y0, y1) = if b.x - a.x <= 0.0 {
                (a.y.min(b.y), a.y.max(b.y))
            } else {
                let (p, q) = (y_at(x0.min(x1)), y_at(x1.max(x0)));
                (p.min(q), p.max(q))
            };
            for r in shape.row(y0 - tol)..=shape.row(y1 + tol) {
                visit(r * shape.columns + c);
            }
        }
    });

    let mut best: Option<Crossing> = None;
    for k in 0..grid.cell_count() {
        let bucket = grid.members(k);
        for (x, &i) in bucket.iter().enumerate() {
            for &j in &bucket[x + 1..] {
                let (si, sj) = (segs[i as usize], segs[j as usize]);
                let (si, sj) = if si <= sj { (si, sj) } else { (sj, si) };
                if let Some(folds) = conflict(rings, si, sj, tol) {
                    let found = Crossing {
                        ring_a: si.0 as usize,
                        seg_a: si.1 as usize,
                        ring_b: sj.0 as usize,
                        seg_b: sj.1 as usize,
                        folds,
                    };
                    // Keep the lowest pair so messages do not depend on the grid.
                    let key = |c: &Crossing| (c.ring_a, c.seg_a, c.ring_b, c.seg_b);
                    if best.is_none_or(|b| key(&found) < key(&b)) {
                        best = Some(found);
                    }
                }
            }
        }
    }
    best
}

/// Whether two distinct segments conflict: `Some(true)` when neighbours in a
/// ring double back over each other, `Some(false)` for any other contact.
fn conflict(
    rings: &[&[DVec2]],
    (ra, sa): (u32, u32),
    (rb, sb): (u32, u32),
    tol: f64,
) -> Option<bool> {
    let ring_a = rings[ra as usize];
    let ring_b = rings[rb as usize];
    let (a, b) = (
        ring_a[sa as usize],
        ring_a[(sa as usize + 1) % ring_a.len()],
    );
    let (c, d) = (
        ring_b[sb as usize],
        ring_b[(sb as usize + 1) % ring_b.len()],
    );
    if ra == rb {
        let n = ring_a.len() as u32;
        // Neighbours share a point by construction; they conflict only by
        // running back along each other.
        let shared = if (sa + 1) % n == sb {
            Some((a, b, d))
        } else if (sb + 1) % n == sa {
            Some((c, d, b))
        } else {
            None
        };
        if let Some((before, v, after)) = shared {
            let u = before - v;
            let w = after - v;
            let folded = u.perp_dot(w).abs() <= tol * u.length().max(w.length()) && u.dot(w) > 0.0;
            return folded.then_some(true);
        }
    }
    segments_meet(a, b, c, d, tol).then_some(false)
}

/// Whether segments `ab` and `cd` share a point, counting points within
/// `tol` of each other as shared.
fn segments_meet(a: DVec2, b: DVec2, c: DVec2, d: DVec2, tol: f64) -> bool {
    if a.x.min(b.x) > c.x.max(d.x) + tol
        || c.x.min(d.x) > a.x.max(b.x) + tol
        || a.y.min(b.y) > c.y.max(d.y) + tol
        || c.y.min(d.y) > a.y.max(b.y) + tol
    {
        return false;
    }
    let side = |p: DVec2, q: DVec2, r: DVec2| {
        let v = cross(p, q, r);
        if v.abs() <= tol * (q - p).length() {
            0
        } else if v > 0.0 {
            1
        } else {
            -1
        }
    };
    let s1 = side(a, b, c);
    let s2 = side(a, b, d);
    let s3 = side(c, d, a);
    let s4 = side(c, d, b);
    if s1 * s2 < 0 && s3 * s4 < 0 {
        return true;
    }
    let on = |p: DVec2, q: DVec2, r: DVec2| {
        let pq = q - p;
        let len2 = pq.length_squared();
        if len2 == 0.0 {
            return p.distance(r) <= tol;
        }
        let t = (r - p).dot(pq) / len2;
        let slack = tol / len2.sqrt();
        (-slack..=1.0 + slack).contains(&t)
    };
    (s1 == 0 && on(a, b, c))
        || (s2 == 0 && on(a, b, d))
        || (s3 == 0 && on(c, d, a))
        || (s4 == 0 && on(c, d, b))
}

/// Douglas–Peucker on a closed ring: which points to keep so that every
/// dropped point lies within `tolerance` of the kept outline. The sharpest
/// corner and the point farthest from it anchor the two halves, so anchors
/// are points the outline needs anyway.
pub(crate) fn simplify_keep(ring: &[DVec2], tolerance: f64) -> Vec<bool> {
    let n = ring.len();
    if n <= 3 || tolerance <= 0.0 {
        return vec![true; n];
    }
    let turn = |i: usize| {
        let u = ring[i] - ring[(i + n - 1) % n];
        let v = ring[(i + 1) % n] - ring[i];
        u.perp_dot(v).atan2(u.dot(v)).abs()
    };
    let first = (0..n)
        .max_by(|&a, &b| turn(a).total_cmp(&turn(b)))
        .unwrap_or(0);
    let at = |k: usize| ring[(first + k) % n];
    let far = (1..n)
        .max_by(|&a, &b| {
            at(0)
                .distance_squared(at(a))
                .total_cmp(&at(0).distance_squared(at(b)))
        })
        .unwrap_or(1);
    // Indices below are offsets from `first`; `n` is `first` again.
    let mut keep = vec![false; n];
    keep[first] = true;
    keep[(first + far) % n] = true;
    let mut stack = vec![(0usize, far), (far, n)];
    while let Some((i, j)) = stack.pop() {
        if j <= i + 1 {
            continue;
        }
        let (a, b) = (at(i), at(j));
        let mut worst = 0.0;
        let mut worst_k = i;
        for k in i + 1..j {
            let d = segment_distance(at(k), a, b);
            if d > worst {
                worst = d;
                worst_k = k;
            }
        }
        if worst > tolerance {
            keep[(first + worst_k) % n] = true;
            stack.push((i, worst_k));
            stack.push((worst_k, j));
        }
    }
    keep
}

/// Distance from `p` to the segment `ab`.
pub fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let len2 = ab.length_squared();
    if len2 == 0.0 {
        return p.distance(a);
    }
    let t = ((p - a).dot(ab) / len2).clamp(0.0, 1.0);
    p.distance(a + ab * t)
}
