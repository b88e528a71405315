//! The geometry under the depth order: whether two triangles overlap
//! (separating axes, edges crossing properly), the distances and
//! predicates the order's decisions use, and the broad phase that finds
//! candidate pairs each frame (`FrameGrid`, a uniform grid binned by
//! multiplication) with the table of pairs already judged (`PairTable`).
//! Plain functions of positions: the ordering itself is in the parent.

use super::*;

/// The span of `corners` projected on `axis`. Positions are finite, so
/// plain comparisons serve for min and max (cheaper than the NaN-aware
/// ones).
pub(super) fn project(axis: DVec2, corners: &[DVec2; 3]) -> (f64, f64) {
    let (min, max) = (
        |x: f64, y: f64| if x < y { x } else { y },
        |x: f64, y: f64| if x > y { x } else { y },
    );
    let d = [
        axis.dot(corners[0]),
        axis.dot(corners[1]),
        axis.dot(corners[2]),
    ];
    (min(min(d[0], d[1]), d[2]), max(max(d[0], d[1]), d[2]))
}

/// Whether triangles `t` and `u`, whose boxes overlap (strictly), can be a
/// pair (they share no vertex) and are one: their interiors intersect at
/// `positions`.
pub(super) fn overlap_apart(triangles: &[[u32; 3]], positions: &[DVec2], t: u32, u: u32) -> bool {
    let (a, b) = (triangles[t as usize], triangles[u as usize]);
    let corners = |tri: [u32; 3]| tri.map(|i| positions[i as usize]);
    !a.iter().any(|v| b.contains(v)) && !separated_by_an_edge(&corners(a), &corners(b))
}

/// Sorts boxes `(low, high, item)` by their low x: when they come in last
/// frame's order (not `fresh`), an insertion sort, linear for a frame's
/// small motion.
pub(super) fn sort_boxes_by_low_x(boxes: &mut [(DVec2, DVec2, u32)], fresh: bool) {
    if fresh {
        boxes.sort_unstable_by(|p, q| p.0.x.total_cmp(&q.0.x));
        return;
    }
    for n in 1..boxes.len() {
        let mut k = n;
        while k > 0 && boxes[k - 1].0.x > boxes[k].0.x {
            boxes.swap(k - 1, k);
            k -= 1;
        }
    }
}

/// Calls `met` with every two of `edges` (by index) that share no vertex
/// and meet, binned on `grid`, until it says stop (true, returned).
pub(super) fn edges_meeting(
    grid: &mut FrameGrid,
    positions: &[DVec2],
    edges: &[BoundaryEdge],
    mut met: impl FnMut(usize, usize) -> bool,
) -> bool {
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    let mut longest = 0.0f64;
    for e in edges {
        let (a, b) = (positions[e.a as usize], positions[e.b as usize]);
        lo = lo.min(a).min(b);
        hi = hi.max(a).max(b);
        longest = longest.max((b - a).abs().max_element());
    }
    let ends = |i: usize| {
        let e = edges[i];
        (positions[e.a as usize], positions[e.b as usize])
    };
    let boxed = |i: usize| {
        let (a, b) = ends(i);
        (a.min(b), a.max(b))
    };
    grid.fill(lo, hi, longest, edges.len(), boxed);
    apart_pairs_on_grid(grid, edges, boxed, |i, j| {
        let ((a, b), (c, d)) = (ends(i), ends(j));
        segments_meet(a, b, c, d) && met(i, j)
    })
}

/// Calls `visit` with every two of `edges` (by index), binned on `grid` by
/// their `boxed` bounds, that share no vertex and whose boxes meet, each
/// two once (in the cell holding the low corner of their boxes' meeting),
/// until it says stop (true, returned).
pub(super) fn apart_pairs_on_grid(
    grid: &FrameGrid,
    edges: &[BoundaryEdge],
    boxed: impl Fn(usize) -> (DVec2, DVec2),
    mut visit: impl FnMut(usize, usize) -> bool,
) -> bool {
    for cell in 0..grid.cell_count() {
        let members = grid.members(cell);
        for (n, &i) in members.iter().enumerate() {
            let (i, ei) = (i as usize, edges[i as usize]);
            let (ilo, ihi) = boxed(i);
            for &j in &members[n + 1..] {
                let (j, ej) = (j as usize, edges[j as usize]);
                if ei.a == ej.a || ei.a == ej.b || ei.b == ej.a || ei.b == ej.b {
                    continue;
                }
                let (jlo, jhi) = boxed(j);
                let (meet_lo, meet_hi) = (ilo.max(jlo), ihi.min(jhi));
                if meet_lo.x <= meet_hi.x
                    && meet_lo.y <= meet_hi.y
                    && grid.cell_of(meet_lo) == cell
                    && visit(i, j)
                {
                    return true;
                }
            }
        }
    }
    false
}

/// Whether edges `ei` and `ej` cross properly and their triangles share no
/// vertex: those two triangles overlap.
pub(super) fn edges_cross_properly(
    triangles: &[[u32; 3]],
    positions: &[DVec2],
    ei: BoundaryEdge,
    ej: BoundaryEdge,
) -> bool {
    let (a, b) = (positions[ei.a as usize], positions[ei.b as usize]);
    let (c, d) = (positions[ej.a as usize], positions[ej.b as usize]);
    let side = |p: DVec2, q: DVec2, r: DVec2| (q - p).perp_dot(r - p);
    let (ti, tj) = (
        triangles[ei.triangle as usize],
        triangles[ej.triangle as usize],
    );
    side(a, b, c) * side(a, b, d) < 0.0
        && side(c, d, a) * side(c, d, b) < 0.0
        && !ti.iter().any(|v| tj.contains(v))
}

/// Whether two triangles' interiors intersect (separating axes over the six
/// edge normals; touching does not count). Either winding; a degenerate
/// triangle overlaps nothing.
pub fn triangles_overlap(a: [DVec2; 3], b: [DVec2; 3]) -> bool {
    let (alo, ahi) = (a[0].min(a[1]).min(a[2]), a[0].max(a[1]).max(a[2]));
    let (blo, bhi) = (b[0].min(b[1]).min(b[2]), b[0].max(b[1]).max(b[2]));
    if alo.x >= bhi.x || blo.x >= ahi.x || alo.y >= bhi.y || blo.y >= ahi.y {
        return false;
    }
    !separated_by_an_edge(&a, &b)
}

/// Whether the normal of some edge of either triangle is a separating axis.
pub(super) fn separated_by_an_edge(a: &[DVec2; 3], b: &[DVec2; 3]) -> bool {
    for tri in [a, b] {
        for k in 0..3 {
            let axis = (tri[(k + 1) % 3] - tri[k]).perp();
            let ((amin, amax), (bmin, bmax)) = (project(axis, a), project(axis, b));
            if amax <= bmin || bmax <= amin {
                return true;
            }
        }
    }
    false
}

/// Whether segments `ab` and `cd` cross or touch (conservative: a touch
/// sends the frame down the exact path).
pub(super) fn segments_meet(a: DVec2, b: DVec2, c: DVec2, d: DVec2) -> bool {
    let side = |p: DVec2, q: DVec2, r: DVec2| (q - p).perp_dot(r - p);
    side(a, b, c) * side(a, b, d) <= 0.0 && side(c, d, a) * side(c, d, b) <= 0.0
}

/// The squared distance between segments `ab` and `cd`, each given with
/// one over its squared length (zero for a point): zero where they cross,
/// else the nearest of each end to the other segment (so collinear segments
/// in a row are apart, unlike for [`segments_meet`]).
pub(super) fn segments_distance_squared(
    (a, b, over_ab): (DVec2, DVec2, f64),
    (c, d, over_cd): (DVec2, DVec2, f64),
) -> f64 {
    let side = |p: DVec2, q: DVec2, r: DVec2| (q - p).perp_dot(r - p);
    if side(a, b, c) * side(a, b, d) < 0.0 && side(c, d, a) * side(c, d, b) < 0.0 {
        return 0.0;
    }
    let to_segment = |p: DVec2, q: DVec2, r: DVec2, over: f64| {
        let along = r - q;
        let t = ((p - q).dot(along) * over).clamp(0.0, 1.0);
        p.distance_squared(q + along * t)
    };
    to_segment(a, c, d, over_cd)
        .min(to_segment(b, c, d, over_cd))
        .min(to_segment(c, a, b, over_ab))
        .min(to_segment(d, a, b, over_ab))
}

/// A uniform grid rebuilt every frame into buffers sized at registration:
/// there are at most about as many cells as items, and with cells at least
/// as large as the largest item (the boundary edges) an item touches at most
/// four.
#[derive(Debug)]
pub(super) struct FrameGrid {
    pub(super) lo: DVec2,
    /// One over the cell's side: binning multiplies (any monotone binning
    /// keeps each pair judged in a cell holding both).
    pub(super) per_cell: f64,
    pub(super) columns: usize,
    pub(super) rows: usize,
    pub(super) start: Vec<u32>,
    pub(super) members: Vec<u32>,
    pub(super) fill: Vec<u32>,
    /// Per item, its cells' columns and rows `[c0, r0, c1, r1]`.
    pub(super) ranges: Vec<[u32; 4]>,
}

impl FrameGrid {
    pub(super) fn with_capacity(cells: usize, members: usize, items: usize) -> FrameGrid {
        FrameGrid {
            lo: DVec2::ZERO,
            per_cell: 1.0,
            columns: 1,
            rows: 1,
            start: Vec::with_capacity(cells + 1),
            members: Vec::with_capacity(members),
            fill: Vec::with_capacity(cells + 1),
            ranges: Vec::with_capacity(items),
        }
    }

    pub(super) fn fill(
        &mut self,
        lo: DVec2,
        hi: DVec2,
        largest_item: f64,
        count: usize,
        bounds: impl Fn(usize) -> (DVec2, DVec2),
    ) {
        let extent = (hi - lo).max_element();
        let per_side = ((count as f64).sqrt().ceil()).max(1.0);
        let mut cell = largest_item.max(extent / per_side);
        if cell.is_nan() || cell <= 0.0 {
            cell = 1.0;
        }
        // Rounding at the edges: never more cells per side than planned.
        let cells_along =
            |length: f64| ((length / cell).max(0.0) as usize + 1).min(per_side as usize + 1);
        self.lo = lo;
        self.per_cell = 1.0 / cell;
        self.columns = cells_along(hi.x - lo.x);
        self.rows = cells_along(hi.y - lo.y);
        let cells = self.columns * self.rows;
        self.start.clear();
        self.start.resize(cells + 1, 0);
        // Each item's cell range once, kept for the second pass.
        self.ranges.clear();
        for i in 0..count {
            let (a, b) = bounds(i);
            let (c0, r0) = self.column_row(a);
            let (c1, r1) = self.column_row(b);
            let range = [c0 as u32, r0 as u32, c1 as u32, r1 as u32];
            self.ranges.push(range);
            for r in r0..=r1 {
                for c in c0..=c1 {
                    self.start[r * self.columns + c + 1] += 1;
                }
            }
        }
        for k in 1..=cells {
            self.start[k] += self.start[k - 1];
        }
        self.fill.clear();
        self.fill.extend_from_slice(&self.start);
        self.members.clear();
        self.members.resize(self.start[cells] as usize, 0);
        for (i, &[c0, r0, c1, r1]) in self.ranges.iter().enumerate() {
            for r in r0 as usize..=r1 as usize {
                for c in c0 as usize..=c1 as usize {
                    let k = r * self.columns + c;
                    self.members[self.fill[k] as usize] = i as u32;
                    self.fill[k] += 1;
                }
            }
        }
    }

    pub(super) fn column_row(&self, p: DVec2) -> (usize, usize) {
        let rel = (p - self.lo) * self.per_cell;
        // Truncation is the floor here (clamped at zero first), without a
        // libm call on targets lacking a rounding instruction.
        let at = |x: f64, n: usize| (x.max(0.0) as usize).min(n - 1);
        (at(rel.x, self.columns), at(rel.y, self.rows))
    }

    pub(super) fn cell_of(&self, p: DVec2) -> usize {
        let (c, r) = self.column_row(p);
        r * self.columns + c
    }

    pub(super) fn cell_count(&self) -> usize {
        self.columns * self.rows
    }

    pub(super) fn members(&self, cell: usize) -> &[u32] {
        &self.members[self.start[cell] as usize..self.start[cell + 1] as usize]
    }
}

/// The pairs tested this frame and, for overlapping ones, their index:
/// open addressing with a frame stamp, so clearing costs nothing. Key,
/// value and stamp share a slot, so a probe touches one cache line.
#[derive(Debug)]
pub(super) struct PairTable {
    pub(super) slots: Vec<Slot>,
    pub(super) stamp: u32,
    pub(super) len: usize,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Slot {
    pub(super) key: u64,
    pub(super) value: u32,
    pub(super) stamp: u32,
}

pub(super) const EMPTY_SLOT: Slot = Slot {
    key: 0,
    value: NONE,
    stamp: 0,
};

pub(super) fn pair_key(pair: (u32, u32)) -> u64 {
    (u64::from(pair.0) << 32) | u64::from(pair.1)
}

impl PairTable {
    pub(super) fn with_capacity(entries: usize) -> PairTable {
        let size = (entries * 2).next_power_of_two().max(64);
        PairTable {
            slots: vec![EMPTY_SLOT; size],
            stamp: 1,
            len: 0,
        }
    }

    pub(super) fn clear(&mut self) {
        self.len = 0;
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.slots.fill(EMPTY_SLOT);
            self.stamp = 1;
        }
    }

    pub(super) fn slot(&self, key: u64) -> (usize, bool) {
        let mask = self.slots.len() - 1;
        let mut at = (key.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 32) as usize & mask;
        loop {
            let slot = &self.slots[at];
            if slot.stamp != self.stamp {
                return (at, false);
            }
            if slot.key == key {
                return (at, true);
            }
            at = (at + 1) & mask;
        }
    }

    /// Records `pair` (value `NONE`) unless it was already recorded this
    /// frame: `Ok(slot)` for a new pair, for [`PairTable::set_at`]; else
    /// `Err(value)`, the value recorded before.
    pub(super) fn insert(&mut self, pair: (u32, u32)) -> Result<usize, u32> {
        if (self.len + 1) * 2 > self.slots.len() {
            self.grow();
        }
        let key = pair_key(pair);
        let (at, found) = self.slot(key);
        if found {
            return Err(self.slots[at].value);
        }
        self.slots[at] = Slot {
            key,
            value: NONE,
            stamp: self.stamp,
        };
        self.len += 1;
        Ok(at)
    }

    pub(super) fn set_at(&mut self, slot: usize, value: u32) {
        self.slots[slot].value = value;
    }

    /// The value of a recorded pair, `NONE` if unrecorded.
    pub(super) fn value(&self, pair: (u32, u32)) -> u32 {
        match self.slot(pair_key(pair)) {
            (at, true) => self.slots[at].value,
            _ => NONE,
        }
    }

    /// Doubles the table: allocates, only when a frame tests more pairs than
    /// any frame before.
    pub(super) fn grow(&mut self) {
        let old = std::mem::take(&mut self.slots);
        self.slots = vec![EMPTY_SLOT; old.len() * 2];
        for slot in old {
            if slot.stamp == self.stamp {
                let (at, _) = self.slot(slot.key);
                self.slots[at] = slot;
            }
        }
    }
}
