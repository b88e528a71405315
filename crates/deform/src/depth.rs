//! Automatic depth adjustment on self-overlap ("As-rigid-as-possible shape
//! manipulation", Igarashi, Moscovich & Hughes 2005, §5.1): given a rest mesh
//! and each frame's deformed vertex positions, this module owns the depth of
//! every triangle — the static order a caller configures (a layer per
//! triangle, by default the piece), the detection of overlapping regions, the
//! front/back decision per pair of regions with frame-to-frame coherence and
//! performer pins, and per-triangle depths consistent with every decision.
//!
//! Phases as in the deformers: [`DepthOrder::register`] precomputes the
//! topology (edge neighbours, boundary edges per piece) and sizes the
//! scratch; [`DepthOrder::update`] runs per frame and does not allocate in
//! steady state. After an overlap-free frame, a motion bound settles the
//! next frames while every boundary vertex stays within half its distance
//! to the nearest other boundary edge and no triangle inverts. Otherwise a
//! frame first tries the cheap reject — no inverted triangle,
//! no two boundary edges crossing (a uniform grid of boundary edges), no
//! piece inside another — and then the answer is the static order. Otherwise
//! overlapping triangle pairs are grown from the triangles at boundary
//! crossings and at inverted triangles through edge neighbours, like
//! hidden-line removal (Hornung 1984), starting from last frame's pairs;
//! many inverted triangles or a piece inside another fall back to a grid
//! over all triangles. After such an exact frame the triangles are cut into
//! front, middle and back sheets; while the front and back sheets are
//! certified to overlap nothing of their own (per border edge, like the
//! cheap reject), later frames draw each sheet at its rank and the middle
//! sheet in an order fixed at the cut, finding no pairs at all, and widen
//! the middle where the line between the two sides slides out of it. See
//! `docs/depth.md`.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};

use glam::DVec2;
use puppetry_mesh::Mesh;

use crate::lanes::Triangles;

mod geometry;
pub use geometry::triangles_overlap;
use geometry::*;

/// The highest static layer a caller may give: depths above it are left for
/// raising the front side of overlaps.
pub const MAX_LAYER: u16 = 0x7fff;

/// Pins remembered at once; a new pin beyond this forgets the oldest.
pub const MAX_PINS: usize = 32;

/// Frames with at most this many inverted triangles grow the overlaps from
/// them; more send the frame to the grid over all triangles.
const MAX_INVERTED_SEEDS: usize = 32;

const NONE: u32 = u32::MAX;
/// A neighbour that can never make a pair (none, or sharing a vertex).
const INVALID: u32 = u32::MAX - 1;
const FRONT: u8 = 1;
const BACK: u8 = 2;

/// The sheets, by rank: every triangle of a higher sheet is drawn over
/// every triangle of a lower one it overlaps.
const BACK_SHEET: u8 = 0;
const MIDDLE_SHEET: u8 = 1;
const FRONT_SHEET: u8 = 2;
/// Rings of overlapping triangles round the straddling ones (over one
/// triangle, under another) that join the middle sheet, so that the line
/// where the two sides meet can slide that far before the front or back
/// sheet overlaps itself. More rings: fewer exact frames, more of the
/// overlap left to the middle's fixed order rather than to the sheets'
/// ranks (on the bench's fold at 1k, 2 rings gave the fastest frames when
/// the middle's pairs were still found every frame: 7 exact frames in
/// 10000).
const MIDDLE_RINGS: usize = 2;
/// Sheets whose middle holds more than one in this many of the exact
/// frame's pairs are not used: most of the overlap should be ordered by
/// the sheets' ranks, region by region.
const MIDDLE_SHARE: usize = 8;
/// Times a frame may widen the middle over triangles the certificate
/// blames before it takes the exact path instead.
const MAX_WIDENINGS: usize = 3;
/// Triangles the certificate blames at most, for widening the middle over
/// them; more send the frame to the exact path.
const MAX_OFFENDERS: usize = 64;

/// What the sheets' certificate says of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Certificate {
    Holds,
    /// A front or back triangle inverted, or two border edges of one of
    /// those sheets met: the blamed triangles are in `Sheets::offenders`.
    Fails,
    /// No two edges of different sheets cross: the overlap may be over.
    NothingOverlaps,
}

/// Why [`DepthOrder`] refused a static order, a frame or a pin.
#[derive(Debug, thiserror::Error)]
pub enum DepthError {
    /// [`DepthOrder::register`]: the layers given are not one per triangle.
    #[error("layers: has {got} entries, expected one per triangle ({expected})")]
    LayerCount {
        /// How many triangles the mesh has.
        expected: usize,
        /// How many layers came.
        got: usize,
    },
    /// [`DepthOrder::register`]: a layer given is above [`MAX_LAYER`].
    #[error("layers[{triangle}]: {layer} is above the highest layer, {max}", max = MAX_LAYER)]
    LayerTooHigh {
        /// The first triangle with too high a layer.
        triangle: usize,
        /// The layer it was given.
        layer: u16,
    },
    /// [`DepthOrder::register`] without layers: the mesh has more pieces
    /// than there are layers, so one layer per piece cannot be the default.
    #[error(
        "the mesh has {count} pieces, but the default order (one layer per piece) allows at most {max}; give layers explicitly",
        max = MAX_LAYER as usize + 1
    )]
    TooManyPieces {
        /// How many pieces the mesh has.
        count: usize,
    },
    /// [`DepthOrder::update`]: the positions are not one per rest vertex.
    #[error("expected {expected} positions (one per vertex), got {got}")]
    PositionCount {
        /// How many vertices the mesh has.
        expected: usize,
        /// How many positions came.
        got: usize,
    },
    /// [`DepthOrder::update`]: a position is NaN or infinite.
    #[error("position {vertex} is not a finite point")]
    PositionNotFinite {
        /// The first offending vertex.
        vertex: usize,
    },
    /// [`DepthOrder::pin_front`]: the triangle is not in the mesh.
    #[error("triangle {triangle} is out of range (the mesh has {count} triangles)")]
    TriangleOutOfRange {
        /// The triangle asked for.
        triangle: u32,
        /// How many triangles the mesh has.
        count: usize,
    },
    /// [`DepthOrder::pin_front`]: the triangle overlapped nothing in the
    /// last update, so there is no region to put in front.
    #[error(
        "triangle {triangle} overlaps nothing in the last frame: only an overlapping region can be pinned in front"
    )]
    NotOverlapping {
        /// The triangle asked for.
        triangle: u32,
    },
}

/// A mesh edge used by one triangle only, directed as in that triangle.
#[derive(Debug, Clone, Copy)]
struct BoundaryEdge {
    a: u32,
    b: u32,
    triangle: u32,
}

/// The per-frame depth order of one puppet's triangles.
#[derive(Debug)]
pub struct DepthOrder {
    triangles: Triangles,
    rest: Vec<DVec2>,
    piece_of: Vec<u32>,
    layers: Vec<u16>,
    /// Across edge `k` (corners `k`, `k+1`), or `NONE` on the boundary.
    neighbours: Vec<[u32; 3]>,
    /// Grouped by piece: piece `p` owns `boundary[piece_boundary[p]..piece_boundary[p + 1]]`.
    boundary: Vec<BoundaryEdge>,
    piece_boundary: Vec<u32>,
    depth: Vec<u16>,
    changed: bool,
    overlapped: bool,
    pair_count: usize,
    dropped: usize,
    scanned_all: bool,
    /// Per boundary edge, the edge starting at its end.
    next_boundary: Vec<u32>,
    /// A certificate that frames stay overlap-free: set after an
    /// overlap-free frame, it holds while no triangle inverts and every
    /// boundary edge's start stays within its budget (squared distance) of
    /// where it was then (both per boundary edge).
    calm: bool,
    calm_at: Vec<DVec2>,
    calm_budget: Vec<f64>,
    /// Per boundary edge, one over its squared length (zero if it has none).
    calm_inverse: Vec<f64>,
    skipped: bool,
    /// Oldest first; the newest pin of a region wins.
    pins: Vec<u32>,
    /// Last frame's role of each triangle (`FRONT | BACK` bits), the memory
    /// that keeps decisions while an overlap persists.
    role: Vec<u8>,
    involved: Vec<u32>,
    /// Whether the last update was settled by the sheets alone.
    certified: bool,
    /// Whether it widened the middle to do so.
    widened: bool,
    sheets_allowed: bool,
    sheets: Sheets,
    scratch: Scratch,
}

/// The triangles cut into three sheets after an exact frame with overlap
/// (see `docs/depth.md`, "Sheets"): while the front and back sheets each
/// overlap nothing of their own, the depth is the sheet's rank over each
/// triangle's layer, and the middle sheet's triangles keep an order fixed
/// at the cut.
#[derive(Debug)]
struct Sheets {
    on: bool,
    /// Which depths the frame must write: every one after the cut, the
    /// middle's after a widening (the ranks leave it room), else none.
    stale: Stale,
    /// Per triangle, its sheet, and (while widening) the sheet it had.
    of: Vec<u8>,
    was: Vec<u8>,
    /// The middle's triangles, back to front in its fixed order.
    middle: Vec<u32>,
    /// Per middle triangle, its place in that order: `0..` from the cut,
    /// then above `top` for those joining from the front sheet and below
    /// `bottom` for those joining from the back.
    place: Vec<i32>,
    top: i32,
    bottom: i32,
    /// Per triangle, its distance (triangles crossed) through the middle
    /// from the back sheet and from the front sheet, at the cut.
    from_back: Vec<u32>,
    from_front: Vec<u32>,
    /// Middle triangles ready to be placed at the cut, lowest first:
    /// (from the back less from the front, exact frame's depth, triangle).
    ready: BinaryHeap<Reverse<(i64, u16, u32)>>,
    /// Every edge of a triangle whose neighbour across it lies in another
    /// sheet, or on the mesh boundary: the front sheet's, then the back
    /// sheet's, then the middle's.
    edges: Vec<BoundaryEdge>,
    /// Where the back sheet's edges start, and the middle's.
    back_edges: usize,
    middle_edges: usize,
    /// Two edges of different sheets that crossed properly on the last
    /// frame that looked for such a pair: tried first.
    witness: (u32, u32),
    /// Added to the layer of the back and of the front sheet's triangles
    /// (the middle's entry is its lowest depth, added to each place).
    offset: [u16; 3],
    queue: Vec<u32>,
    ring: Vec<u32>,
    next_ring: Vec<u32>,
    /// The front and the back sheet's border edges' boxes, by their low
    /// x; emptied when the sheets change, else kept in last frame's order,
    /// which a frame's motion barely changes.
    border_boxes: [Vec<(DVec2, DVec2, u32)>; 2],
    /// Triangles of the front or back sheet the certificate blamed this
    /// frame (at most [`MAX_OFFENDERS`]), and the inverted triangles it
    /// found this frame (of any sheet).
    offenders: Vec<u32>,
    inverted: Vec<u32>,
    /// The middle's size when the sheets were cut: widening stops at twice
    /// it.
    cut_middle: usize,
    /// A triangle of the front's and of the back's largest part when last
    /// looked for.
    anchor: [u32; 2],
}

/// The depths a frame on the sheets must write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Stale {
    Nothing,
    Middle,
    All,
}

/// Everything a frame writes, sized at registration.
#[derive(Debug)]
struct Scratch {
    grid: FrameGrid,
    piece_lo: Vec<DVec2>,
    piece_hi: Vec<DVec2>,
    /// Triangle pairs at boundary crossings and at inverted triangles, where
    /// growing starts.
    seeds: Vec<(u32, u32)>,
    inverted: Vec<u32>,
    inverted_flag: Vec<bool>,
    inverted_box: Vec<(DVec2, DVec2)>,
    crossing_pieces: Vec<(u32, u32)>,
    /// Overlapping pairs `(smaller, larger)`; after the decisions, `(back, front)`.
    pairs: Vec<(u32, u32)>,
    tested: PairTable,
    /// Per pair, what each of its six neighbours is (corner `k` of the
    /// first triangle stepped is `2k`, of the second `2k + 1`): a pair's
    /// index, `NONE` (tested, no overlap) or `INVALID`.
    links: Vec<[u32; 6]>,
    /// Last frame's pairs `(smaller, larger)` and links, and where each
    /// pair went this frame.
    last_pairs: Vec<(u32, u32)>,
    last_links: Vec<[u32; 6]>,
    remap: Vec<u32>,
    stack: Vec<u32>,
    parent: Vec<u32>,
    parity: Vec<u8>,
    patch_of_root: Vec<u32>,
    patches: Vec<Patch>,
    new_role: Vec<u8>,
    /// Each triangle's mean corner movement from rest, valid where
    /// `moved_frame` equals `frame`.
    moved: Vec<f64>,
    moved_frame: Vec<u32>,
    frame: u32,
    new_involved: Vec<u32>,
    above: Above,
    level: Vec<u16>,
    queue: Vec<u32>,
}

/// "Front above back" constraints between triangles, for a topological
/// sort: per triangle, the triangles that must lie above it and how many
/// must lie below it.
#[derive(Debug)]
struct Above {
    /// Triangle `t`'s triangles above are `fronts[start[t]..end[t]]`.
    start: Vec<u32>,
    end: Vec<u32>,
    fronts: Vec<u32>,
    /// Constraints putting something below each triangle not yet placed.
    indegree: Vec<u32>,
}

impl Above {
    fn with_capacity(triangles: usize) -> Above {
        Above {
            start: vec![0; triangles],
            end: vec![0; triangles],
            fronts: Vec::with_capacity(triangles),
            indegree: vec![0; triangles],
        }
    }

    /// The constraints `(back, front)` among `triangles` (both ends of each
    /// among them), replacing theirs.
    fn set(&mut self, triangles: &[u32], pairs: impl Iterator<Item = (u32, u32)> + Clone) {
        for &t in triangles {
            self.end[t as usize] = 0;
            self.indegree[t as usize] = 0;
        }
        for (back, front) in pairs.clone() {
            self.end[back as usize] += 1;
            self.indegree[front as usize] += 1;
        }
        let mut next = 0;
        for &t in triangles {
            let t = t as usize;
            self.start[t] = next;
            next += self.end[t];
            self.end[t] = self.start[t];
        }
        self.fronts.clear();
        self.fronts.resize(next as usize, 0);
        for (back, front) in pairs {
            let slot = &mut self.end[back as usize];
            self.fronts[*slot as usize] = front;
            *slot += 1;
        }
    }

    /// Where triangle `t`'s triangles above lie in `fronts`.
    fn of(&self, t: usize) -> std::ops::Range<usize> {
        self.start[t] as usize..self.end[t] as usize
    }
}

/// How [`DepthOrder::decide`] learns which pairs are neighbours.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Link {
    /// Growing joined them already.
    Grown,
    /// Looked up in the table of tested pairs (the all-triangle grid).
    ByTable,
}

/// One connected patch of overlapping pairs: two sides, one goes in front.
#[derive(Debug, Clone, Copy, Default)]
struct Patch {
    /// Last frame's roles of this frame's triangles, as votes for each side.
    votes: [u32; 2],
    /// (pin index + 1, side) of the newest pin inside, or 0.
    pin: (usize, u8),
    layer: [u16; 2],
    displacement: [f64; 2],
    count: [u32; 2],
    lowest: [u32; 2],
    front: u8,
}

impl Scratch {
    /// Scratch for `count` triangles, `boundary` boundary edges and
    /// `pieces` pieces, sized so the update path does not allocate.
    fn new(count: usize, boundary: usize, pieces: usize) -> Scratch {
        let side = |n: usize| (n as f64).sqrt().ceil() as usize + 2;
        // The sheets' edges: up to three per triangle.
        let most = (3 * count).max(boundary);
        Scratch {
            grid: FrameGrid::with_capacity(side(most) * side(most) + 1, 4 * most, most),
            piece_lo: vec![DVec2::ZERO; pieces],
            piece_hi: vec![DVec2::ZERO; pieces],
            seeds: Vec::with_capacity(boundary + 16 * MAX_INVERTED_SEEDS),
            inverted: Vec::with_capacity(count),
            inverted_flag: vec![false; count],
            inverted_box: Vec::with_capacity(MAX_INVERTED_SEEDS),
            crossing_pieces: Vec::with_capacity(boundary),
            pairs: Vec::with_capacity(count),
            // Small enough to stay in cache; doubles on a frame testing more.
            tested: PairTable::with_capacity(2 * count),
            links: Vec::with_capacity(count),
            last_pairs: Vec::with_capacity(count),
            last_links: Vec::with_capacity(count),
            remap: Vec::with_capacity(count),
            stack: Vec::with_capacity(count),
            parent: Vec::with_capacity(count),
            parity: Vec::with_capacity(count),
            patch_of_root: Vec::with_capacity(count),
            patches: Vec::with_capacity(16),
            new_role: vec![0; count],
            moved: vec![0.0; count],
            moved_frame: vec![0; count],
            frame: 0,
            new_involved: Vec::with_capacity(count),
            above: Above::with_capacity(count),
            level: vec![0; count],
            queue: Vec::with_capacity(count),
        }
    }
}

/// The static order: `given` (one layer per triangle, at most
/// [`MAX_LAYER`]) or, without it, each triangle's piece (`piece_of`, of
/// `pieces` pieces).
fn static_layers(
    given: Option<&[u16]>,
    piece_of: &[u32],
    pieces: usize,
) -> Result<Vec<u16>, DepthError> {
    match given {
        Some(given) => {
            if given.len() != piece_of.len() {
                return Err(DepthError::LayerCount {
                    expected: piece_of.len(),
                    got: given.len(),
                });
            }
            if let Some(t) = given.iter().position(|&l| l > MAX_LAYER) {
                return Err(DepthError::LayerTooHigh {
                    triangle: t,
                    layer: given[t],
                });
            }
            Ok(given.to_vec())
        }
        None => {
            if pieces > MAX_LAYER as usize + 1 {
                return Err(DepthError::TooManyPieces { count: pieces });
            }
            Ok(piece_of.iter().map(|&p| p as u16).collect())
        }
    }
}

impl DepthOrder {
    /// Registration: the static order is `layers` (one per triangle, larger =
    /// nearer, at most [`MAX_LAYER`]) or, without it, the piece index in
    /// [`Mesh::pieces`] order. `mesh`'s vertices are the rest positions the
    /// tie rule measures movement from.
    pub fn register(mesh: &Mesh, layers: Option<&[u16]>) -> Result<DepthOrder, DepthError> {
        let triangles = Triangles::new(mesh.triangles().to_vec(), mesh.vertices().len());
        let count = triangles.len();
        let pieces = mesh.pieces();
        let mut piece_of = vec![0u32; count];
        for (p, piece) in pieces.iter().enumerate() {
            for &t in &piece.triangles {
                piece_of[t as usize] = p as u32;
            }
        }
        let layers = static_layers(layers, &piece_of, pieces.len())?;

        let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(count * 3);
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                directed.insert((tri[k], tri[(k + 1) % 3]), t as u32);
            }
        }
        let mut neighbours = vec![[NONE; 3]; count];
        let mut boundary = Vec::new();
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                match directed.get(&(b, a)) {
                    Some(&other) => neighbours[t][k] = other,
                    None => boundary.push(BoundaryEdge {
                        a,
                        b,
                        triangle: t as u32,
                    }),
                }
            }
        }
        boundary.sort_by_key(|e| (piece_of[e.triangle as usize], e.triangle));
        let mut piece_boundary = vec![0u32; pieces.len() + 1];
        for e in &boundary {
            piece_boundary[piece_of[e.triangle as usize] as usize + 1] += 1;
        }
        for p in 1..piece_boundary.len() {
            piece_boundary[p] += piece_boundary[p - 1];
        }

        // Every boundary vertex starts exactly one boundary edge (the mesh
        // has no bowties).
        let mut starting = HashMap::with_capacity(boundary.len());
        for (i, e) in boundary.iter().enumerate() {
            starting.insert(e.a, i as u32);
        }
        let next_boundary = boundary.iter().map(|e| starting[&e.b]).collect();
        let boundary_count = boundary.len();

        let scratch = Scratch::new(count, boundary.len(), pieces.len());
        Ok(DepthOrder {
            rest: mesh.vertices().to_vec(),
            depth: layers.clone(),
            role: vec![0; count],
            involved: Vec::with_capacity(count),
            triangles,
            piece_of,
            layers,
            neighbours,
            boundary,
            piece_boundary,
            changed: false,
            overlapped: false,
            pair_count: 0,
            dropped: 0,
            scanned_all: false,
            calm: false,
            calm_at: vec![DVec2::ZERO; boundary_count],
            calm_budget: vec![0.0; boundary_count],
            calm_inverse: vec![0.0; boundary_count],
            next_boundary,
            skipped: false,
            pins: Vec::with_capacity(MAX_PINS),
            certified: false,
            widened: false,
            sheets_allowed: true,
            sheets: Sheets {
                on: false,
                stale: Stale::Nothing,
                of: vec![BACK_SHEET; count],
                was: vec![BACK_SHEET; count],
                middle: Vec::with_capacity(count),
                place: vec![0; count],
                top: 0,
                bottom: 0,
                from_back: vec![NONE; count],
                from_front: vec![NONE; count],
                ready: BinaryHeap::with_capacity(count),
                edges: Vec::with_capacity(3 * count),
                back_edges: 0,
                middle_edges: 0,
                witness: (0, 0),
                offset: [0; 3],
                queue: Vec::with_capacity(count),
                ring: Vec::with_capacity(count),
                next_ring: Vec::with_capacity(count),
                border_boxes: [Vec::with_capacity(3 * count), Vec::with_capacity(3 * count)],
                offenders: Vec::with_capacity(MAX_OFFENDERS),
                inverted: Vec::with_capacity(count),
                cut_middle: 0,
                anchor: [NONE; 2],
            },
            scratch,
        })
    }

    /// The same mesh with a new static order (`layers` painted or put
    /// back by an undo), keeping the performer's pins: a flip stays in
    /// force until its triangle overlaps nothing, whatever is painted
    /// meanwhile. The frame-to-frame decisions start afresh from the new
    /// order, which is what painting it asks for.
    pub fn with_layers(&self, mesh: &Mesh, layers: &[u16]) -> Result<DepthOrder, DepthError> {
        let mut order = DepthOrder::register(mesh, Some(layers))?;
        order.pins.clone_from(&self.pins);
        Ok(order)
    }

    /// The static order: each triangle's layer.
    pub fn static_depth(&self) -> &[u16] {
        &self.layers
    }

    /// The depth of each triangle after the last update (larger = nearer);
    /// the static order before the first.
    pub fn depth(&self) -> &[u16] {
        &self.depth
    }

    /// Whether any two triangles overlapped in the last update.
    pub fn overlapped(&self) -> bool {
        self.overlapped
    }

    /// Whether the last update changed any depth (so a server sends depth
    /// only then).
    pub fn changed(&self) -> bool {
        self.changed
    }

    /// Overlapping triangle pairs found by the last update: every pair on an
    /// exact frame; none on a frame settled by the sheets
    /// ([`DepthOrder::certified`]), which orders pairs without finding them.
    pub fn overlap_pairs(&self) -> usize {
        self.pair_count
    }

    /// Triangles in the middle sheet on a frame settled by the sheets (zero
    /// on other frames): those kept in the fixed order cut at the last exact
    /// frame rather than by the sheets' ranks.
    pub fn middle_triangles(&self) -> usize {
        if self.certified {
            self.sheets.middle.len()
        } else {
            0
        }
    }

    /// Whether the last update had to test all triangles (more than 32
    /// inverted triangles, or a piece inside another) instead of growing
    /// from boundary crossings and inverted triangles.
    pub fn scanned_all(&self) -> bool {
        self.scanned_all
    }

    /// Whether the last update was settled by the motion bound alone: every
    /// vertex stayed close enough to where it was at an earlier overlap-free
    /// frame that nothing could have started to overlap (see
    /// `docs/depth.md`).
    pub fn skipped(&self) -> bool {
        self.skipped
    }

    /// Whether frames may be settled by sheets (the default) or always take
    /// the exact path: for comparing the two.
    pub fn use_sheets(&mut self, on: bool) {
        self.sheets_allowed = on;
        if !on {
            self.sheets.on = false;
        }
    }

    /// Whether the last update was settled by the sheets of an earlier
    /// exact frame (see `docs/depth.md`, "Sheets"): then no pair was listed,
    /// and [`DepthOrder::overlap_pairs`] is zero.
    pub fn certified(&self) -> bool {
        self.certified
    }

    /// Whether the last update, settled by the sheets, first widened their
    /// middle over triangles where the line between the two sides had slid
    /// out of it (see `docs/depth.md`, "Sheets").
    pub fn widened(&self) -> bool {
        self.widened
    }

    /// Front-over-back constraints the last update had to drop to break
    /// cycles (see `docs/depth.md`); zero unless decisions contradict.
    pub fn dropped_constraints(&self) -> usize {
        self.dropped
    }

    /// A performer's choice: the overlapping region holding `triangle` goes
    /// in front of what it overlaps, from the next update until the triangle
    /// overlaps nothing any more. The triangle must overlap something in the
    /// last update.
    pub fn pin_front(&mut self, triangle: u32) -> Result<(), DepthError> {
        let count = self.triangles.len();
        if triangle as usize >= count {
            return Err(DepthError::TriangleOutOfRange { triangle, count });
        }
        if self.role[triangle as usize] == 0 {
            return Err(DepthError::NotOverlapping { triangle });
        }
        self.pins.retain(|&p| p != triangle);
        if self.pins.len() == MAX_PINS {
            self.pins.remove(0);
        }
        self.pins.push(triangle);
        Ok(())
    }

    /// Forgets every pin.
    pub fn clear_pins(&mut self) {
        self.pins.clear();
    }

    /// One frame: the depth of each triangle for these vertex positions.
    pub fn update(&mut self, positions: &[DVec2]) -> Result<&[u16], DepthError> {
        if positions.len() != self.rest.len() {
            return Err(DepthError::PositionCount {
                expected: self.rest.len(),
                got: positions.len(),
            });
        }
        if let Some(vertex) = positions.iter().position(|p| !p.is_finite()) {
            return Err(DepthError::PositionNotFinite { vertex });
        }
        self.widened = false;
        self.skipped = self.calm && self.still_calm(positions);
        if self.skipped {
            // The last frame was overlap-free (static depth, no roles, no
            // pins) and this one is too: nothing to write.
            self.changed = false;
            self.certified = false;
            return Ok(&self.depth);
        }
        // The sheets from an earlier exact frame, while they still hold.
        let leaving_sheets = self.sheets.on;
        self.certified = self.sheets.on && self.sheet_frame(positions);
        if self.certified {
            return Ok(&self.depth);
        }
        self.sheets.on = false;
        let s = &mut self.scratch;
        self.triangles.not_positive(positions, &mut s.inverted);
        self.find_boundary_crossings(positions);
        let contained = self.piece_inside_another(positions);
        let s = &mut self.scratch;
        s.pairs.clear();
        s.parent.clear();
        s.parity.clear();
        s.links.clear();
        s.tested.clear();
        self.scanned_all = contained || s.inverted.len() > MAX_INVERTED_SEEDS;
        if self.scanned_all {
            self.all_overlaps(positions);
            let s = &mut self.scratch;
            s.parent.extend(0..s.pairs.len() as u32);
            s.parity.resize(s.pairs.len(), 0);
        } else {
            if !s.inverted.is_empty() {
                for &t in &s.inverted {
                    s.inverted_flag[t as usize] = true;
                }
                self.seed_from_inverted(positions);
                let s = &mut self.scratch;
                for &t in &s.inverted {
                    s.inverted_flag[t as usize] = false;
                }
            }
            if !self.scratch.seeds.is_empty() {
                self.grow_overlaps(positions);
            }
        }
        // Next frame starts from these pairs and their links, unless this
        // frame took the grid (which links nothing).
        let s = &mut self.scratch;
        s.last_pairs.clear();
        s.last_links.clear();
        if !self.scanned_all {
            s.last_pairs.extend_from_slice(&s.pairs);
            std::mem::swap(&mut s.links, &mut s.last_links);
        }
        self.pair_count = self.scratch.pairs.len();
        self.overlapped = self.pair_count > 0;
        self.dropped = 0;
        if self.overlapped {
            self.decide(
                positions,
                if self.scanned_all {
                    Link::ByTable
                } else {
                    Link::Grown
                },
            );
            self.order();
        }
        self.write_depth(leaving_sheets);
        self.calm = !self.overlapped;
        if self.calm {
            self.certify_calm(positions);
        } else {
            self.build_sheets();
        }
        Ok(&self.depth)
    }

    /// After an exact frame with overlap: cuts the triangles into sheets for
    /// the next frames. The triangles both in front of one triangle and
    /// behind another, with [`MIDDLE_RINGS`] rings of overlapping triangles
    /// round them, and the inverted triangles are the middle sheet; the
    /// rest grow from this frame's front triangles (the front sheet) and
    /// back triangles (the back sheet) through edge neighbours, whichever
    /// reaches a triangle first; what neither reaches is in the back sheet.
    /// Of the front and of the back sheet only the largest connected part
    /// stays; the other parts join the middle. The sheets are used only if
    /// this frame's pairs agree with their ranks (none inside the front or
    /// back sheet, none against the ranks), the mesh is one piece, nothing
    /// is pinned, and the ranks fit in a depth.
    fn build_sheets(&mut self) {
        let sh = &mut self.sheets;
        sh.on = false;
        if !self.sheets_allowed || !self.pins.is_empty() || self.piece_boundary.len() != 2 {
            return;
        }
        const UNSET: u8 = u8::MAX;
        sh.of.fill(UNSET);
        sh.ring.clear();
        // The straddling triangles and rings round them, and the inverted
        // ones (a crease).
        let straddling = self
            .involved
            .iter()
            .filter(|&&t| self.role[t as usize] == FRONT | BACK);
        for &t in straddling {
            sh.of[t as usize] = MIDDLE_SHEET;
            sh.ring.push(t);
        }
        for _ in 0..MIDDLE_RINGS {
            sh.next_ring.clear();
            for &t in &sh.ring {
                for &u in &self.neighbours[t as usize] {
                    if u != NONE && sh.of[u as usize] == UNSET && self.role[u as usize] != 0 {
                        sh.of[u as usize] = MIDDLE_SHEET;
                        sh.next_ring.push(u);
                    }
                }
            }
            std::mem::swap(&mut sh.ring, &mut sh.next_ring);
        }
        for &t in &self.scratch.inverted {
            sh.of[t as usize] = MIDDLE_SHEET;
        }
        sh.queue.clear();
        for &t in &self.involved {
            let t = t as usize;
            if sh.of[t] == UNSET {
                sh.of[t] = if self.role[t] == FRONT {
                    FRONT_SHEET
                } else {
                    BACK_SHEET
                };
                sh.queue.push(t as u32);
            }
        }
        let mut head = 0;
        while head < sh.queue.len() {
            let t = sh.queue[head] as usize;
            head += 1;
            for &u in &self.neighbours[t] {
                if u != NONE && sh.of[u as usize] == UNSET {
                    sh.of[u as usize] = sh.of[t];
                    sh.queue.push(u);
                }
            }
        }
        for s in sh.of.iter_mut() {
            if *s == UNSET {
                *s = BACK_SHEET;
            }
        }
        keep_largest_parts(&mut self.sheets, &self.neighbours);
        let sh = &self.sheets;
        // This frame's pairs, now (back, front), must agree with the ranks.
        for &(back, front) in &self.scratch.pairs {
            let (b, f) = (sh.of[back as usize], sh.of[front as usize]);
            if !(b < f || (b == MIDDLE_SHEET && f == MIDDLE_SHEET)) {
                return;
            }
        }
        // A middle holding a large share of the pairs would leave much of
        // the overlap to its fixed order: wait for a better cut.
        let (sh, pairs) = (&self.sheets, &self.scratch.pairs);
        let inside = pairs
            .iter()
            .filter(|&&(b, f)| {
                sh.of[b as usize] == MIDDLE_SHEET && sh.of[f as usize] == MIDDLE_SHEET
            })
            .count();
        if inside * MIDDLE_SHARE > pairs.len() {
            return;
        }
        if !self.rank_sheets() {
            return;
        }
        self.place_sheets();
        self.order_middle_at_cut();
        self.sheets.on = true;
        self.sheets.stale = Stale::All;
    }

    /// At the cut, the sheets' ranks (false if they do not fit in a
    /// depth): every middle depth above every back layer (one depth a
    /// middle triangle, in its fixed order), every front depth above every
    /// middle depth. They leave room for the middle to widen to
    /// [`DepthOrder::widen_middle`]'s limit, so widening changes no rank
    /// and no depth outside the middle.
    fn rank_sheets(&mut self) -> bool {
        let sh = &mut self.sheets;
        let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
        let mut middle = 0;
        for (&s, &layer) in sh.of.iter().zip(&self.layers) {
            let (s, layer) = (s as usize, u32::from(layer));
            lo[s] = lo[s].min(layer);
            hi[s] = hi[s].max(layer);
            middle += usize::from(s == MIDDLE_SHEET as usize);
        }
        sh.cut_middle = middle;
        let back_top = if lo[0] == u32::MAX { 0 } else { hi[0] };
        let middle_top = back_top + widest_middle(middle) as u32;
        let front_offset = if lo[2] == u32::MAX {
            0
        } else {
            (middle_top + 1).saturating_sub(lo[2])
        };
        if hi[2] + front_offset > u32::from(u16::MAX) || middle_top > u32::from(u16::MAX) {
            return false;
        }
        sh.offset = [0, (back_top + 1) as u16, front_offset as u16];
        true
    }

    /// With each triangle's sheet set: the middle list (in triangle order:
    /// the caller puts it in its fixed order) and the sheets' border edges.
    fn place_sheets(&mut self) {
        let count = self.triangles.len();
        let sh = &mut self.sheets;
        sh.middle.clear();
        sh.border_boxes.iter_mut().for_each(Vec::clear);
        sh.middle
            .extend((0..count as u32).filter(|&t| sh.of[t as usize] == MIDDLE_SHEET));
        sh.edges.clear();
        for sheet in [FRONT_SHEET, BACK_SHEET, MIDDLE_SHEET] {
            if sheet == BACK_SHEET {
                sh.back_edges = sh.edges.len();
            } else if sheet == MIDDLE_SHEET {
                sh.middle_edges = sh.edges.len();
            }
            for (t, tri) in self.triangles.iter().enumerate() {
                if sh.of[t] != sheet {
                    continue;
                }
                for k in 0..3 {
                    let u = self.neighbours[t][k];
                    if u == NONE || sh.of[u as usize] != sheet {
                        sh.edges.push(BoundaryEdge {
                            a: tri[k],
                            b: tri[(k + 1) % 3],
                            triangle: t as u32,
                        });
                    }
                }
            }
        }
        sh.witness = (0, 0);
    }

    /// Moves `offenders` (triangles of the front or back sheet that this
    /// frame inverted or whose border edges met another of their sheet)
    /// and the triangles round them into the middle sheet, keeps the
    /// largest part of the front and of the back sheet, and places the
    /// sheets again. False (the frame takes the exact path) when there are
    /// too many offenders or the middle would grow past twice its size at
    /// the cut.
    fn widen_middle(&mut self) -> bool {
        let sh = &mut self.sheets;
        if sh.offenders.len() >= sh.offenders.capacity() {
            return false;
        }
        sh.was.copy_from_slice(&sh.of);
        for k in 0..sh.offenders.len() {
            let t = sh.offenders[k] as usize;
            sh.of[t] = MIDDLE_SHEET;
            for u in self.neighbours[t] {
                if u != NONE {
                    sh.of[u as usize] = MIDDLE_SHEET;
                }
            }
        }
        keep_largest_parts(sh, &self.neighbours);
        let middle = sh.of.iter().filter(|&&s| s == MIDDLE_SHEET).count();
        if middle > widest_middle(sh.cut_middle) {
            return false;
        }
        // Each triangle joining the middle keeps its side of the middle:
        // from the front sheet above all of it, from the back below.
        for t in 0..sh.of.len() {
            if sh.of[t] == MIDDLE_SHEET && sh.was[t] != MIDDLE_SHEET {
                if sh.was[t] == FRONT_SHEET {
                    sh.place[t] = sh.top;
                    sh.top += 1;
                } else {
                    sh.bottom -= 1;
                    sh.place[t] = sh.bottom;
                }
            }
        }
        self.place_sheets();
        let sh = &mut self.sheets;
        let place = &sh.place;
        sh.middle.sort_unstable_by_key(|&t| place[t as usize]);
        sh.stale = sh.stale.max(Stale::Middle);
        true
    }

    /// At the cut, the middle's fixed order, back to front: along the
    /// material from the back sheet to the front sheet (a triangle fewer
    /// triangles from the front than from the back lies nearer), where that
    /// agrees with the exact frame's order of the middle's own pairs, which
    /// it keeps; ties by the exact frame's depth, then by index. It is a
    /// topological sort of those pairs (each from its lower depth to its
    /// higher, so without cycles) that always places the ready triangle
    /// lowest by that measure.
    fn order_middle_at_cut(&mut self) {
        let (sh, s) = (&mut self.sheets, &mut self.scratch);
        for (from, sheet) in [
            (&mut sh.from_back, BACK_SHEET),
            (&mut sh.from_front, FRONT_SHEET),
        ] {
            sh.queue.clear();
            for &t in &sh.middle {
                let next_to_sheet = self.neighbours[t as usize]
                    .iter()
                    .any(|&u| u != NONE && sh.of[u as usize] == sheet);
                from[t as usize] = if next_to_sheet { 0 } else { NONE };
                if next_to_sheet {
                    sh.queue.push(t);
                }
            }
            let mut head = 0;
            while head < sh.queue.len() {
                let t = sh.queue[head] as usize;
                head += 1;
                for &u in &self.neighbours[t] {
                    if u != NONE && sh.of[u as usize] == MIDDLE_SHEET && from[u as usize] == NONE {
                        from[u as usize] = from[t] + 1;
                        sh.queue.push(u);
                    }
                }
            }
        }
        // A triangle neither sheet reaches counts as far from both.
        let far = sh.middle.len() as i64;
        let measure = |t: u32| {
            let reach = |d: u32| if d == NONE { far } else { i64::from(d) };
            let t = t as usize;
            (
                reach(sh.from_back[t]) - reach(sh.from_front[t]),
                self.depth[t],
                t as u32,
            )
        };
        // The exact frame's pairs inside the middle, lower depth first.
        let below = |a: u32, b: u32| (self.depth[a as usize], a) < (self.depth[b as usize], b);
        let inside = s
            .pairs
            .iter()
            .filter(|&&(a, b)| {
                sh.of[a as usize] == MIDDLE_SHEET && sh.of[b as usize] == MIDDLE_SHEET
            })
            .map(|&(a, b)| if below(a, b) { (a, b) } else { (b, a) });
        s.above.set(&sh.middle, inside);
        let above = &mut s.above;
        sh.ready.clear();
        sh.ready.extend(
            sh.middle
                .iter()
                .filter(|&&t| above.indegree[t as usize] == 0)
                .map(|&t| Reverse(measure(t))),
        );
        let mut placed = 0;
        while let Some(Reverse((_, _, t))) = sh.ready.pop() {
            let t = t as usize;
            sh.place[t] = placed;
            placed += 1;
            for e in above.of(t) {
                let high = above.fronts[e] as usize;
                above.indegree[high] -= 1;
                if above.indegree[high] == 0 {
                    sh.ready.push(Reverse(measure(high as u32)));
                }
            }
        }
        debug_assert_eq!(placed as usize, sh.middle.len(), "depths order the pairs");
        (sh.top, sh.bottom) = (placed, 0);
        let place = &sh.place;
        sh.middle.sort_unstable_by_key(|&t| place[t as usize]);
    }

    /// The sheets' certificate for this frame: it holds while no triangle of
    /// the front or back sheet is inverted, no two edges of one of those
    /// sheets' borders (mesh boundary and cuts) meet, and two edges of
    /// different sheets cross (so something still overlaps). Where it
    /// fails, the triangles to blame are in `offenders` (up to its
    /// capacity).
    fn certify_sheets(&mut self, positions: &[DVec2]) -> Certificate {
        let sh = &mut self.sheets;
        sh.offenders.clear();
        for &t in &sh.inverted {
            if sh.of[t as usize] != MIDDLE_SHEET {
                offend(&mut sh.offenders, t);
            }
        }
        // Each of the front and back sheets' borders swept on its own:
        // only two edges of one sheet may not meet. The sweep keeps last
        // frame's order of the edges' boxes, which a frame barely changes.
        let sh = &mut self.sheets;
        for (k, range) in [0..sh.back_edges, sh.back_edges..sh.middle_edges]
            .into_iter()
            .enumerate()
        {
            let boxes = &mut sh.border_boxes[k];
            let fresh = boxes.is_empty();
            if fresh {
                boxes.extend(range.map(|i| (DVec2::ZERO, DVec2::ZERO, i as u32)));
            }
            let edges = &sh.edges;
            let ends = |i: u32| {
                let e = edges[i as usize];
                (positions[e.a as usize], positions[e.b as usize])
            };
            for (lo, hi, i) in boxes.iter_mut() {
                let (a, b) = ends(*i);
                (*lo, *hi) = (a.min(b), a.max(b));
            }
            sort_boxes_by_low_x(boxes, fresh);
            for (n, &(ilo, ihi, i)) in boxes.iter().enumerate() {
                let ei = edges[i as usize];
                for &(jlo, jhi, j) in &boxes[n + 1..] {
                    if jlo.x > ihi.x {
                        break;
                    }
                    let ej = edges[j as usize];
                    if jlo.y > ihi.y
                        || ilo.y > jhi.y
                        || ei.a == ej.a
                        || ei.a == ej.b
                        || ei.b == ej.a
                        || ei.b == ej.b
                    {
                        continue;
                    }
                    let ((a, b), (c, d)) = (ends(i), ends(j));
                    if segments_meet(a, b, c, d) {
                        offend(&mut sh.offenders, ei.triangle);
                        offend(&mut sh.offenders, ej.triangle);
                    }
                }
            }
        }
        // Something still overlaps: last frame's two crossing edges, else
        // any two of different sheets.
        let sh = &self.sheets;
        let mut overlapping =
            sh.witness.0 != sh.witness.1 && self.edges_cross(positions, sh.witness.0, sh.witness.1);
        if !overlapping {
            let (sh, grid) = (&mut self.sheets, &mut self.scratch.grid);
            let mut found = None;
            edges_meeting(grid, positions, &sh.edges, |i, j| {
                let (ei, ej) = (sh.edges[i], sh.edges[j]);
                if sh.of[ei.triangle as usize] == sh.of[ej.triangle as usize]
                    || !edges_cross_properly(&self.triangles, positions, ei, ej)
                {
                    return false;
                }
                found = Some((i as u32, j as u32));
                true
            });
            if let Some(pair) = found {
                sh.witness = pair;
                overlapping = true;
            }
        }
        let sh = &self.sheets;
        if !sh.offenders.is_empty() {
            Certificate::Fails
        } else if overlapping {
            Certificate::Holds
        } else {
            Certificate::NothingOverlaps
        }
    }

    /// Whether the sheets' edges `i` and `j` cross properly and their
    /// triangles share no vertex: those two triangles overlap.
    fn edges_cross(&self, positions: &[DVec2], i: u32, j: u32) -> bool {
        let (ei, ej) = (self.sheets.edges[i as usize], self.sheets.edges[j as usize]);
        edges_cross_properly(&self.triangles, positions, ei, ej)
    }

    /// A frame on the sheets: false (and nothing written) unless they still
    /// hold. They hold while nothing is pinned, no triangle of the front or
    /// back sheet is inverted, no two edges of one of those sheets' borders
    /// (mesh boundary and cuts) meet, and two edges of different sheets
    /// cross (so something still overlaps). Then neither the front nor the
    /// back sheet overlaps itself (as for the pieces in the cheap reject),
    /// every pair between sheets is ordered by their ranks, and every pair
    /// inside the middle by its fixed order: the depths stay as they are,
    /// written again only where the sheets changed.
    fn sheet_frame(&mut self, positions: &[DVec2]) -> bool {
        if !self.pins.is_empty() {
            return false;
        }
        // The inverted triangles once a frame, whatever sheets they fall in.
        self.triangles
            .not_positive(positions, &mut self.sheets.inverted);
        // Where the line between the sides slid out of the middle, the
        // middle widens over it and the certificate is checked again.
        let mut widenings = 0;
        loop {
            match self.certify_sheets(positions) {
                Certificate::Holds => break,
                Certificate::NothingOverlaps => return false,
                Certificate::Fails => {
                    if widenings == MAX_WIDENINGS || !self.widen_middle() {
                        return false;
                    }
                    widenings += 1;
                }
            }
        }
        self.widened = widenings > 0;
        self.pair_count = 0;
        self.overlapped = true;
        self.scanned_all = false;
        self.dropped = 0;
        self.calm = false;
        let sh = &mut self.sheets;
        let mut changed = false;
        let mut set = |t: usize, depth: u16| {
            changed |= self.depth[t] != depth;
            self.depth[t] = depth;
        };
        if sh.stale == Stale::All {
            for (t, &sheet) in sh.of.iter().enumerate() {
                if sheet != MIDDLE_SHEET {
                    set(t, self.layers[t] + sh.offset[sheet as usize]);
                }
            }
        }
        if sh.stale != Stale::Nothing {
            for (place, &t) in sh.middle.iter().enumerate() {
                set(t as usize, sh.offset[MIDDLE_SHEET as usize] + place as u16);
            }
        }
        sh.stale = Stale::Nothing;
        self.changed = changed;
        true
    }

    /// Whether this frame is certainly overlap-free, given the certificate
    /// of an earlier overlap-free frame: no triangle is inverted, and no two
    /// boundary edges can have met on the way here, since every boundary
    /// vertex moved less than half the distance from its edges to any
    /// other. Then no piece can have moved inside another either, and the
    /// exact path would find nothing to grow from.
    fn still_calm(&mut self, positions: &[DVec2]) -> bool {
        let within = self
            .boundary
            .iter()
            .zip(&self.calm_at)
            .zip(&self.calm_budget)
            .all(|((e, at), &budget)| positions[e.a as usize].distance_squared(*at) < budget);
        if !within {
            return false;
        }
        let s = &mut self.scratch;
        self.triangles.not_positive(positions, &mut s.inverted);
        s.inverted.is_empty()
    }

    /// After an overlap-free frame: how far each boundary vertex may move
    /// from here (straight, all at once) before two boundary edges could
    /// meet: less than half their distance. Only edges closer than the
    /// longest edge's extent are measured (a grid of their boxes grown by
    /// half of it); every budget is capped at that half.
    fn certify_calm(&mut self, positions: &[DVec2]) {
        let s = &mut self.scratch;
        let budget = &mut self.calm_budget;
        let edges = &self.boundary;
        if edges.is_empty() {
            return;
        }
        let mut longest = 0.0f64;
        for (inverse, e) in self.calm_inverse.iter_mut().zip(edges) {
            let along = positions[e.b as usize] - positions[e.a as usize];
            longest = longest.max(along.abs().max_element());
            let length = along.length_squared();
            *inverse = if length > 0.0 { 1.0 / length } else { 0.0 };
        }
        let inverse = &self.calm_inverse;
        let reach = longest / 2.0;
        budget.fill(reach * reach);
        for (at, e) in self.calm_at.iter_mut().zip(edges) {
            *at = positions[e.a as usize];
        }
        let ends = |i: usize| {
            let e = edges[i];
            (positions[e.a as usize], positions[e.b as usize])
        };
        let boxed = |i: usize| {
            let (a, b) = ends(i);
            (a.min(b) - reach, a.max(b) + reach)
        };
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for i in 0..edges.len() {
            let (blo, bhi) = boxed(i);
            lo = lo.min(blo);
            hi = hi.max(bhi);
        }
        s.grid
            .fill(lo, hi, longest + 2.0 * reach, edges.len(), boxed);
        apart_pairs_on_grid(&s.grid, edges, boxed, |i, j| {
            let (a, b) = ends(i);
            let (c, d) = ends(j);
            let half = segments_distance_squared((a, b, inverse[i]), (c, d, inverse[j])) / 4.0;
            for k in [
                i,
                j,
                self.next_boundary[i] as usize,
                self.next_boundary[j] as usize,
            ] {
                budget[k] = budget[k].min(half);
            }
            false
        });
    }

    /// Fills `seeds` with the triangle pairs of crossing, non-adjacent
    /// boundary edges, and the piece bounds.
    fn find_boundary_crossings(&mut self, positions: &[DVec2]) {
        let s = &mut self.scratch;
        s.seeds.clear();
        s.crossing_pieces.clear();
        let edges = &self.boundary;
        if edges.is_empty() {
            return;
        }
        for p in 0..self.piece_boundary.len() - 1 {
            let mut plo = DVec2::splat(f64::INFINITY);
            let mut phi = DVec2::splat(f64::NEG_INFINITY);
            for e in &edges[self.piece_boundary[p] as usize..self.piece_boundary[p + 1] as usize] {
                // Every boundary vertex starts exactly one boundary edge (the
                // mesh has no bowties), so these are the boundary's bounds.
                let a = positions[e.a as usize];
                plo = plo.min(a);
                phi = phi.max(a);
            }
            s.piece_lo[p] = plo;
            s.piece_hi[p] = phi;
        }
        let piece_of = &self.piece_of;
        edges_meeting(&mut s.grid, positions, edges, |i, j| {
            let (ti, tj) = (edges[i].triangle, edges[j].triangle);
            s.seeds.push((ti, tj));
            let (pi, pj) = (piece_of[ti as usize], piece_of[tj as usize]);
            if pi != pj {
                s.crossing_pieces.push((pi.min(pj), pi.max(pj)));
            }
            false
        });
        s.crossing_pieces.sort_unstable();
        s.crossing_pieces.dedup();
    }

    /// Whether a piece lies inside another with no boundary crossing between
    /// them (their overlap has no crossing to grow from).
    fn piece_inside_another(&self, positions: &[DVec2]) -> bool {
        let s = &self.scratch;
        let pieces = self.piece_boundary.len() - 1;
        for p in 0..pieces {
            for q in p + 1..pieces {
                let apart = s.piece_lo[p].cmpgt(s.piece_hi[q]).any()
                    || s.piece_lo[q].cmpgt(s.piece_hi[p]).any();
                if apart
                    || s.crossing_pieces
                        .binary_search(&(p as u32, q as u32))
                        .is_ok()
                {
                    continue;
                }
                let corner_of = |piece: usize| {
                    positions[self.boundary[self.piece_boundary[piece] as usize].a as usize]
                };
                if self.inside_piece(positions, corner_of(p), q)
                    || self.inside_piece(positions, corner_of(q), p)
                {
                    return true;
                }
            }
        }
        false
    }

    /// Even-odd test of `point` against every boundary loop of `piece`.
    fn inside_piece(&self, positions: &[DVec2], point: DVec2, piece: usize) -> bool {
        let range = self.piece_boundary[piece] as usize..self.piece_boundary[piece + 1] as usize;
        let mut inside = false;
        for e in &self.boundary[range] {
            let (a, b) = (positions[e.a as usize], positions[e.b as usize]);
            if (a.y > point.y) != (b.y > point.y) {
                let x = a.x + (point.y - a.y) / (b.y - a.y) * (b.x - a.x);
                if point.x < x {
                    inside = !inside;
                }
            }
        }
        inside
    }

    fn corners(&self, positions: &[DVec2], t: u32) -> [DVec2; 3] {
        self.triangles[t as usize].map(|i| positions[i as usize])
    }

    fn share_vertex(&self, t: u32, u: u32) -> bool {
        let (a, b) = (self.triangles[t as usize], self.triangles[u as usize]);
        a.iter().any(|v| b.contains(v))
    }

    /// Tests `(t, u)` once per frame; a new overlapping pair is recorded and
    /// queued for growing. Returns the pair's index if it overlaps, `NONE`
    /// if not, `INVALID` if the two can never be a pair (the same triangle,
    /// or sharing a vertex).
    fn try_pair(&mut self, positions: &[DVec2], t: u32, u: u32) -> u32 {
        if t == u || self.share_vertex(t, u) {
            return INVALID;
        }
        let key = (t.min(u), t.max(u));
        let slot = match self.scratch.tested.insert(key) {
            Ok(slot) => slot,
            Err(index) => return index,
        };
        if !triangles_overlap(self.corners(positions, t), self.corners(positions, u)) {
            return NONE;
        }
        let s = &mut self.scratch;
        let index = s.pairs.len() as u32;
        s.tested.set_at(slot, index);
        s.push_pair(key);
        s.stack.push(index);
        index
    }

    /// Grows the overlapping pairs from the seeds (boundary crossings, and
    /// inverted triangles with what their boxes touch): a pair's neighbours
    /// are the pairs that step one triangle across an edge. Neighbouring
    /// pairs are joined into patches as they are found.
    ///
    /// Last frame's pairs come first: each is tested again, and one that
    /// still overlaps learns its six neighbours from last frame's links
    /// without the table of tested pairs: a neighbour that was a pair was
    /// just tested again, one that was apart is tested directly and only
    /// when it now overlaps is it looked up (and grown from, if new). A
    /// component of this frame's pairs holding a seed is still found whole:
    /// growing reaches each of its pairs through a chain of neighbours, and
    /// every neighbour of a reused pair is known.
    fn grow_overlaps(&mut self, positions: &[DVec2]) {
        self.scratch.stack.clear();
        self.reuse_last_pairs(positions);
        for n in 0..self.scratch.seeds.len() {
            let (t, u) = self.scratch.seeds[n];
            self.try_pair(positions, t, u);
            // A seed whose triangles share a vertex (a tight crease) is not
            // a pair itself, but its neighbours may be.
            self.try_neighbours(positions, NONE, t, u);
        }
        while let Some(i) = self.scratch.stack.pop() {
            let (t, u) = self.scratch.pairs[i as usize];
            self.try_neighbours(positions, i, t, u);
        }
    }

    /// Tests last frame's pairs again and links those still overlapping to
    /// their neighbours (see [`DepthOrder::grow_overlaps`]).
    fn reuse_last_pairs(&mut self, positions: &[DVec2]) {
        let last = self.scratch.last_pairs.len();
        self.scratch.remap.clear();
        for n in 0..last {
            let key = self.scratch.last_pairs[n];
            let overlaps = triangles_overlap(
                self.corners(positions, key.0),
                self.corners(positions, key.1),
            );
            let s = &mut self.scratch;
            let Ok(slot) = s.tested.insert(key) else {
                s.remap.push(NONE);
                continue;
            };
            if overlaps {
                let index = s.pairs.len() as u32;
                s.tested.set_at(slot, index);
                s.push_pair(key);
                s.remap.push(index);
            } else {
                s.remap.push(NONE);
            }
        }
        for n in 0..last {
            let i = self.scratch.remap[n];
            if i == NONE {
                continue;
            }
            let (t, u) = self.scratch.last_pairs[n];
            for c in 0..6 {
                let (own, other) = if c % 2 == 0 { (t, u) } else { (u, t) };
                let step = self.neighbours[own as usize][c / 2];
                let link = self.scratch.last_links[n][c];
                let j = if link < INVALID {
                    // A pair last frame: tested again above.
                    self.scratch.remap[link as usize]
                } else if link == INVALID
                    || !triangles_overlap(
                        self.corners(positions, step),
                        self.corners(positions, other),
                    )
                {
                    link
                } else {
                    // Apart last frame, overlapping now: new, or found already.
                    self.try_pair(positions, step, other)
                };
                let s = &mut self.scratch;
                s.links[i as usize][c] = j;
                if j < INVALID {
                    s.union(i, j, u8::from(own > other) ^ u8::from(step > other));
                }
            }
        }
    }

    /// Tests the six pairs stepping `t` or `u` across an edge and, when `i`
    /// is the pair `(t, u)` (`t < u`), records them as its links and joins
    /// it with those that overlap: the stepping triangles lie on the same
    /// side.
    fn try_neighbours(&mut self, positions: &[DVec2], i: u32, t: u32, u: u32) {
        for k in 0..3 {
            for (c, own, other) in [(2 * k, t, u), (2 * k + 1, u, t)] {
                let step = self.neighbours[own as usize][k];
                let j = if step == NONE {
                    INVALID
                } else {
                    self.try_pair(positions, step, other)
                };
                if i == NONE {
                    continue;
                }
                let s = &mut self.scratch;
                s.links[i as usize][c] = j;
                if j < INVALID {
                    s.union(i, j, u8::from(own > other) ^ u8::from(step > other));
                }
            }
        }
    }

    /// Seeds growing from the inverted triangles: each with every triangle
    /// whose box meets its own. Any overlap whose region is bounded by a
    /// fold (where triangles invert) rather than by a boundary crossing
    /// holds such a pair.
    fn seed_from_inverted(&mut self, positions: &[DVec2]) {
        let s = &mut self.scratch;
        s.inverted_box.clear();
        let mut lo = DVec2::splat(f64::INFINITY);
        let mut hi = DVec2::splat(f64::NEG_INFINITY);
        for &t in &s.inverted {
            let [a, b, c] = self.triangles[t as usize].map(|i| positions[i as usize]);
            let (tlo, thi) = (a.min(b).min(c), a.max(b).max(c));
            lo = lo.min(tlo);
            hi = hi.max(thi);
            s.inverted_box.push((tlo, thi));
        }
        for (u, tri) in self.triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| positions[i as usize]);
            let (ulo, uhi) = (a.min(b).min(c), a.max(b).max(c));
            if ulo.x > hi.x || ulo.y > hi.y || lo.x > uhi.x || lo.y > uhi.y {
                continue;
            }
            for (n, &(tlo, thi)) in s.inverted_box.iter().enumerate() {
                let t = s.inverted[n];
                // Two inverted triangles: seeded once.
                if t == u as u32
                    || ulo.x > thi.x
                    || ulo.y > thi.y
                    || tlo.x > uhi.x
                    || tlo.y > uhi.y
                    || (s.inverted_flag[u] && (u as u32) < t)
                {
                    continue;
                }
                s.seeds.push((t, u as u32));
            }
        }
    }

    /// Every overlapping pair, through a uniform grid over all triangles: for
    /// frames where growing from the boundary could miss some.
    fn all_overlaps(&mut self, positions: &[DVec2]) {
        let mut lo = DVec2::splat(f64::INFINITY);
        let mut hi = DVec2::splat(f64::NEG_INFINITY);
        let mut total = 0.0f64;
        for tri in self.triangles.iter() {
            let [a, b, c] = tri.map(|i| positions[i as usize]);
            let (tlo, thi) = (a.min(b).min(c), a.max(b).max(c));
            lo = lo.min(tlo);
            hi = hi.max(thi);
            total += (thi - tlo).max_element();
        }
        // Cells sized by the mean triangle, not the largest: one triangle
        // stretched across the fold must not put everything in one cell.
        // The few larger triangles span more cells, so the member list may
        // outgrow its registration size (and allocate) on such a frame.
        let typical = total / self.triangles.len().max(1) as f64;
        let bounds = |t: usize| {
            let [a, b, c] = self.triangles[t].map(|i| positions[i as usize]);
            (a.min(b).min(c), a.max(b).max(c))
        };
        let s = &mut self.scratch;
        s.grid.fill(lo, hi, typical, self.triangles.len(), bounds);
        for cell in 0..s.grid.cell_count() {
            let members = s.grid.members(cell);
            for (n, &t) in members.iter().enumerate() {
                let (tlo, thi) = bounds(t as usize);
                for &u in &members[n + 1..] {
                    let (ulo, uhi) = bounds(u as usize);
                    let meet_lo = tlo.max(ulo);
                    let meet_hi = thi.min(uhi);
                    if meet_lo.x >= meet_hi.x || meet_lo.y >= meet_hi.y {
                        continue;
                    }
                    if s.grid.cell_of(meet_lo) != cell {
                        continue;
                    }
                    if overlap_apart(&self.triangles, positions, t, u) {
                        let key = (t.min(u), t.max(u));
                        if let Ok(slot) = s.tested.insert(key) {
                            s.tested.set_at(slot, s.pairs.len() as u32);
                            s.pairs.push(key);
                        }
                    }
                }
            }
        }
    }

    /// Each undecided patch's sides weighed by how far their triangles
    /// moved from rest. Movement only where neither a pin, the votes nor
    /// the layers decide: it costs a square root a triangle.
    fn weigh_movement(&mut self, positions: &[DVec2]) {
        let s = &mut self.scratch;
        let n = s.pairs.len();
        let undecided = |patch: &Patch| {
            patch.pin.0 == 0 && patch.votes[0] == patch.votes[1] && patch.layer[0] == patch.layer[1]
        };
        if !s.patches.iter().any(undecided) {
            return;
        }
        for i in 0..n {
            let (root, side) = s.found(i);
            let patch = &mut s.patches[s.patch_of_root[root as usize] as usize];
            if !undecided(patch) {
                continue;
            }
            let (first, second) = s.pairs[i];
            for (t, side) in [(first, side), (second, side ^ 1)] {
                // Each triangle's movement once a frame, however many
                // pairs it is in.
                if s.moved_frame[t as usize] != s.frame {
                    s.moved_frame[t as usize] = s.frame;
                    let tri = self.triangles[t as usize];
                    let moved = tri
                        .iter()
                        .map(|&v| positions[v as usize] - self.rest[v as usize])
                        .sum::<DVec2>();
                    s.moved[t as usize] = moved.length() / 3.0;
                }
                patch.displacement[side as usize] += s.moved[t as usize];
            }
        }
    }

    /// Groups the pairs into patches (two sides each) and decides which side
    /// of each goes in front; rewrites `pairs` as `(back, front)` and sets
    /// the new roles.
    fn decide(&mut self, positions: &[DVec2], link: Link) {
        let s = &mut self.scratch;
        let n = s.pairs.len();
        s.frame = s.frame.wrapping_add(1);
        if s.frame == 0 {
            s.moved_frame.fill(0);
            s.frame = 1;
        }
        s.patch_of_root.clear();
        s.patch_of_root.resize(n, NONE);
        s.patches.clear();
        let new_patch = Patch {
            lowest: [NONE; 2],
            ..Patch::default()
        };
        // What each triangle of a pair tells its patch, on its side.
        let tally = |patch: &mut Patch, (first, second): (u32, u32), side: u8| {
            for (t, side) in [(first, side), (second, side ^ 1)] {
                let k = side as usize;
                let role = self.role[t as usize];
                if role == FRONT {
                    patch.votes[k] += 1;
                } else if role == BACK {
                    patch.votes[k ^ 1] += 1;
                }
                if let Some(p) = self.pins.iter().rposition(|&p| p == t)
                    && p + 1 > patch.pin.0
                {
                    patch.pin = (p + 1, side);
                }
                patch.layer[k] = patch.layer[k].max(self.layers[t as usize]);
                patch.count[k] += 1;
                patch.lowest[k] = patch.lowest[k].min(t);
            }
        };
        // Two pairs are neighbours when one triangle steps across an edge
        // and the other stays: the stepping triangles lie on the same side.
        if link == Link::Grown {
            // Growing joined them as it found them: each pair is pointed
            // straight at its patch's root by one find, and tallied.
            for i in 0..n {
                let (root, side) = s.find(i as u32);
                if s.patch_of_root[root as usize] == NONE {
                    s.patch_of_root[root as usize] = s.patches.len() as u32;
                    s.patches.push(new_patch);
                }
                let patch = s.patch_of_root[root as usize] as usize;
                tally(&mut s.patches[patch], s.pairs[i], side);
            }
        } else {
            // The all-triangle grid found them without growing: each patch
            // is walked from its lowest pair, every pair reached given its
            // side and tallied. A link contradicting a side already given
            // (a patch wrapping onto itself round a tight crease) is
            // ignored, as `Scratch::union` does.
            s.stack.clear();
            s.parent.fill(NONE);
            for start in 0..n as u32 {
                if s.parent[start as usize] != NONE {
                    continue;
                }
                s.parent[start as usize] = start;
                s.parity[start as usize] = 0;
                s.patch_of_root[start as usize] = s.patches.len() as u32;
                s.patches.push(new_patch);
                let patch = s.patches.len() - 1;
                s.stack.push(start);
                while let Some(i) = s.stack.pop() {
                    let (pair, side) = (s.pairs[i as usize], s.parity[i as usize]);
                    tally(&mut s.patches[patch], pair, side);
                    for (own_position, own, other) in [(0u8, pair.0, pair.1), (1, pair.1, pair.0)] {
                        for &step in &self.neighbours[own as usize] {
                            if step == NONE || step == other {
                                continue;
                            }
                            let j = s.tested.value((step.min(other), step.max(other)));
                            if j == NONE || s.parent[j as usize] != NONE {
                                continue;
                            }
                            let step_position = u8::from(step > other);
                            s.parent[j as usize] = start;
                            s.parity[j as usize] = side ^ own_position ^ step_position;
                            s.stack.push(j);
                        }
                    }
                }
            }
        }
        self.weigh_movement(positions);
        let s = &mut self.scratch;
        for patch in &mut s.patches {
            patch.front = front_side(patch);
        }
        for i in 0..n {
            let (root, side) = s.found(i);
            let front = s.patches[s.patch_of_root[root as usize] as usize].front;
            let (first, second) = s.pairs[i];
            let (back, front) = if side == front {
                (second, first)
            } else {
                (first, second)
            };
            s.pairs[i] = (back, front);
            for (t, role) in [(back, BACK), (front, FRONT)] {
                if s.new_role[t as usize] == 0 {
                    s.new_involved.push(t);
                }
                s.new_role[t as usize] |= role;
            }
        }
    }

    /// Orders the involved triangles so every front triangle lies above its
    /// back triangle: a topological sort from the back, each front raised to
    /// one above the highest triangle it covers.
    fn order(&mut self) {
        let s = &mut self.scratch;
        s.new_involved.sort_unstable();
        for &t in &s.new_involved {
            s.level[t as usize] = self.layers[t as usize];
        }
        s.above.set(&s.new_involved, s.pairs.iter().copied());
        let above = &mut s.above;
        s.queue.clear();
        s.queue.extend(
            s.new_involved
                .iter()
                .filter(|&&t| above.indegree[t as usize] == 0),
        );
        let mut head = 0;
        while s.queue.len() < s.new_involved.len() || head < s.queue.len() {
            if head == s.queue.len() {
                // A cycle: the remaining triangle lowest in the static order
                // (then by index) forgets what should have been below it.
                let stuck = s
                    .new_involved
                    .iter()
                    .copied()
                    .filter(|&t| above.indegree[t as usize] > 0)
                    .min_by_key(|&t| (self.layers[t as usize], t))
                    .expect("fewer queued than involved leaves one waiting");
                self.dropped += above.indegree[stuck as usize] as usize;
                above.indegree[stuck as usize] = 0;
                s.queue.push(stuck);
            }
            let t = s.queue[head] as usize;
            head += 1;
            // A front already placed was placed by breaking a cycle, before
            // this triangle: the constraint turns round (this one goes over
            // it), so the two still get different depths.
            for e in above.of(t) {
                let front = above.fronts[e] as usize;
                if above.indegree[front] == 0 {
                    s.level[t] = s.level[t].max(s.level[front].saturating_add(1));
                }
            }
            for e in above.of(t) {
                let front = above.fronts[e] as usize;
                // Zero: already placed (a cycle dropped this edge).
                if above.indegree[front] == 0 {
                    continue;
                }
                s.level[front] = s.level[front].max(s.level[t].saturating_add(1));
                above.indegree[front] -= 1;
                if above.indegree[front] == 0 {
                    s.queue.push(front as u32);
                }
            }
        }
    }

    /// Writes this frame's depths, noting any change, and moves the new roles
    /// in as next frame's memory.
    /// After frames on the sheets (`after_sheets`), every triangle not
    /// involved now goes back to its layer, not only last frame's involved.
    fn write_depth(&mut self, after_sheets: bool) {
        let s = &mut self.scratch;
        let mut changed = false;
        if after_sheets {
            for (t, depth) in self.depth.iter_mut().enumerate() {
                if s.new_role[t] == 0 && *depth != self.layers[t] {
                    *depth = self.layers[t];
                    changed = true;
                }
            }
        }
        for &t in &self.involved {
            let t = t as usize;
            if s.new_role[t] == 0 && self.depth[t] != self.layers[t] {
                self.depth[t] = self.layers[t];
                changed = true;
            }
            self.role[t] = 0;
        }
        for &t in &s.new_involved {
            let t = t as usize;
            if self.depth[t] != s.level[t] {
                self.depth[t] = s.level[t];
                changed = true;
            }
            self.role[t] = s.new_role[t];
            s.new_role[t] = 0;
        }
        self.changed = changed;
        std::mem::swap(&mut self.involved, &mut s.new_involved);
        s.new_involved.clear();
        let role = &self.role;
        self.pins.retain(|&p| role[p as usize] != 0);
    }
}

/// The most triangles the middle may widen to, from its size at the cut.
fn widest_middle(cut: usize) -> usize {
    2 * cut.max(16)
}

/// Marks a triangle reached by [`flood_sheet`] (the high bit of its sheet).
const REACHED: u8 = 0x80;

/// Marks with [`REACHED`] every triangle of `start`'s sheet joined to it
/// through edges, not yet reached; returns how many it marked (`queue` is
/// the flood's scratch).
fn flood_sheet(
    of: &mut [u8],
    queue: &mut Vec<u32>,
    neighbours: &[[u32; 3]],
    start: usize,
) -> usize {
    let sheet = of[start];
    queue.clear();
    queue.push(start as u32);
    of[start] |= REACHED;
    let mut head = 0;
    while head < queue.len() {
        let t = queue[head] as usize;
        head += 1;
        for &u in &neighbours[t] {
            if u != NONE && of[u as usize] == sheet {
                of[u as usize] |= REACHED;
                queue.push(u);
            }
        }
    }
    queue.len()
}

/// Blames triangle `t` for a failed certificate, once, while there is room.
fn offend(offenders: &mut Vec<u32>, t: u32) {
    if offenders.len() < offenders.capacity() && !offenders.contains(&t) {
        offenders.push(t);
    }
}

/// Each of the front and back sheets made connected (one part of it then
/// cannot lie inside another with no boundary crossing): its largest part
/// joined through edges stays, smaller ones (bits cut off by the middle)
/// join the middle, whose order orders all their pairs. The part holding
/// the largest part's triangle from the last call is flooded first: when
/// it holds more than half the sheet it is the largest, and no other part
/// needs flooding (the common case when widening cuts a few triangles
/// off).
fn keep_largest_parts(sh: &mut Sheets, neighbours: &[[u32; 3]]) {
    let count = sh.of.len();
    for (k, sheet) in [FRONT_SHEET, BACK_SHEET].into_iter().enumerate() {
        let size = sh.of.iter().filter(|&&s| s == sheet).count();
        let anchor = sh.anchor[k] as usize;
        let first = if anchor < count && sh.of[anchor] == sheet {
            anchor
        } else if let Some(t) = sh.of.iter().position(|&s| s == sheet) {
            t
        } else {
            continue;
        };
        let reached = flood_sheet(&mut sh.of, &mut sh.queue, neighbours, first);
        let mut largest_start = first;
        if 2 * reached <= size {
            let mut largest = reached;
            for start in 0..count {
                if sh.of[start] != sheet {
                    continue;
                }
                let reached = flood_sheet(&mut sh.of, &mut sh.queue, neighbours, start);
                if reached > largest {
                    (largest, largest_start) = (reached, start);
                }
            }
            for s in sh.of.iter_mut() {
                *s &= !REACHED;
            }
            flood_sheet(&mut sh.of, &mut sh.queue, neighbours, largest_start);
        }
        sh.anchor[k] = largest_start as u32;
        for s in sh.of.iter_mut() {
            if *s == sheet {
                *s = MIDDLE_SHEET;
            }
            *s &= !REACHED;
        }
    }
}

/// The side of a patch that goes in front: a pin, else last frame's roles,
/// else the higher static layer, else the side that moved further from rest,
/// else the side whose lowest triangle index is higher.
fn front_side(patch: &Patch) -> u8 {
    if patch.pin.0 > 0 {
        return patch.pin.1;
    }
    if patch.votes[0] != patch.votes[1] {
        return u8::from(patch.votes[1] > patch.votes[0]);
    }
    if patch.layer[0] != patch.layer[1] {
        return u8::from(patch.layer[1] > patch.layer[0]);
    }
    let moved = [0, 1].map(|k| patch.displacement[k] / patch.count[k].max(1) as f64);
    let scale = moved[0].abs().max(moved[1].abs());
    if (moved[0] - moved[1]).abs() > 1e-9 * scale {
        return u8::from(moved[1] > moved[0]);
    }
    u8::from(patch.lowest[1] > patch.lowest[0])
}

impl Scratch {
    /// Appends an overlapping pair: its own patch, links unknown.
    fn push_pair(&mut self, key: (u32, u32)) {
        let index = self.pairs.len() as u32;
        self.pairs.push(key);
        self.parent.push(index);
        self.parity.push(0);
        self.links.push([NONE; 6]);
    }

    /// The root of pair `i`'s patch and `i`'s parity (the side of its first
    /// triangle) relative to the root.
    fn find(&mut self, i: u32) -> (u32, u8) {
        let (mut root, mut parity) = (i, 0u8);
        while self.parent[root as usize] != root {
            parity ^= self.parity[root as usize];
            root = self.parent[root as usize];
        }
        let (mut at, mut at_parity) = (i, parity);
        while self.parent[at as usize] != at {
            let next = self.parent[at as usize];
            let next_parity = at_parity ^ self.parity[at as usize];
            self.parent[at as usize] = root;
            self.parity[at as usize] = at_parity;
            at = next;
            at_parity = next_parity;
        }
        (root, parity)
    }

    /// Pair `i`'s root and parity once [`Scratch::find`] has run for it
    /// (which points it at its root) and no union since.
    fn found(&self, i: usize) -> (u32, u8) {
        (self.parent[i], self.parity[i])
    }

    /// Joins the patches of pairs `i` and `j`, whose first triangles lie on
    /// sides differing by `relation`. A link contradicting the sides already
    /// known (a patch wrapping onto itself round a tight crease) is ignored:
    /// the patch is decided as one, and any cycle that leaves among its
    /// triangles is broken by the ordering.
    fn union(&mut self, i: u32, j: u32, relation: u8) {
        let (ri, pi) = self.find(i);
        let (rj, pj) = self.find(j);
        if ri != rj {
            self.parent[rj as usize] = ri;
            self.parity[rj as usize] = pi ^ pj ^ relation;
        }
    }
}
