//! A picture's pieces, and the bridges that join them: islands of opaque
//! pixels a few pixels apart (a head drawn beside its body) would each
//! move on their own. [`gaps`] finds the nearest gap between every two
//! islands that face each other — a breadth-first growth of every island
//! at once over the mask, each pixel remembering the island pixel it grew
//! from — and keeps those a spanning tree of the pieces needs, nearest
//! first (Kruskal). [`bridge`] paints a bridge across each gap no longer
//! than asked into the alpha mask that is traced, so the pieces mesh as
//! one; the picture drawn is not changed, so a bridge is solved (the
//! pieces move together) but, transparent there, never seen.
//!
//! Pictures larger than [`ANALYSED_PIXELS`] are analysed on a coarser mask
//! (a block is opaque when any of its pixels is), so the search costs at
//! most a few tens of MiB whatever the picture; bridges are painted at
//! full resolution.

use std::collections::{HashMap, VecDeque};

use glam::DVec2;

/// The most mask pixels the gap search looks at (8 bytes each): a larger
/// picture is searched on blocks of pixels.
pub const ANALYSED_PIXELS: u64 = 1 << 22;

/// Islands with fewer opaque pixels than this are specks (as the tracer's
/// `SPECK_AREA`): never a piece, never bridged.
const SPECK_PIXELS: u32 = 4;

/// A gap between two pieces: where it is narrowest, in picture pixels
/// (x right, y down, pixel centres), and how wide.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// The point on one piece's edge.
    pub from: DVec2,
    /// The point on the other's.
    pub to: DVec2,
    /// From one to the other, pixels.
    pub width: f64,
}

/// A picture's pieces and the gaps between them.
#[derive(Debug, Clone, PartialEq)]
pub struct Pieces {
    /// Islands of opaque pixels (specks left out).
    pub count: usize,
    /// The gaps a spanning tree of the pieces crosses, narrowest first:
    /// bridging all of them makes one piece (`count - 1` of them).
    pub gaps: Vec<Gap>,
}

impl Pieces {
    /// The widest gap that must be bridged to make one piece; 0 for one.
    pub fn widest(&self) -> f64 {
        self.gaps.last().map_or(0.0, |g| g.width)
    }
}

/// The pieces of a `width` × `height` mask (`opaque`, row by row from the
/// top) and the gaps between them.
pub fn gaps(width: u32, height: u32, opaque: &dyn Fn(usize) -> bool) -> Pieces {
    let (w, h) = (width as usize, height as usize);
    let pixels = (w * h) as u64;
    // Blocks of `k` × `k` pixels, so at most ANALYSED_PIXELS are searched.
    let mut k = 1usize;
    while pixels.div_ceil((k * k) as u64) > ANALYSED_PIXELS {
        k += 1;
    }
    let (bw, bh) = (w.div_ceil(k), h.div_ceil(k));
    let block_opaque = |bx: usize, by: usize| {
        (by * k..((by + 1) * k).min(h))
            .any(|y| (bx * k..((bx + 1) * k).min(w)).any(|x| opaque(y * w + x)))
    };
    let mask: Vec<bool> = (0..bw * bh).map(|i| block_opaque(i % bw, i / bw)).collect();
    let (labels, sizes) = label(bw, bh, &mask);
    let pieces: Vec<u32> = (1..sizes.len() as u32)
        .filter(|&l| sizes[l as usize] >= SPECK_PIXELS)
        .collect();
    if pieces.len() < 2 {
        return Pieces {
            count: pieces.len(),
            gaps: Vec::new(),
        };
    }
    let grown = grow(bw, bh, &labels, &sizes);
    let scale = k as f64;
    let centre = |i: usize| DVec2::new((i % bw) as f64 + 0.5, (i / bw) as f64 + 0.5) * scale;
    // The narrowest crossing between each two pieces whose growths meet.
    let mut nearest: HashMap<(u32, u32), Gap> = HashMap::new();
    for y in 0..bh {
        for x in 0..bw {
            let i = y * bw + x;
            let neighbours = [(x + 1 < bw).then(|| i + 1), (y + 1 < bh).then(|| i + bw)];
            for j in neighbours.into_iter().flatten() {
                let (Some(a), Some(b)) = (grown[i], grown[j]) else {
                    continue;
                };
                let (la, lb) = (labels[a as usize], labels[b as usize]);
                if la == lb {
                    continue;
                }
                let (from, to) = (centre(a as usize), centre(b as usize));
                let gap = Gap {
                    from,
                    to,
                    width: (from.distance(to) - scale).max(0.0),
                };
                let key = (la.min(lb), la.max(lb));
                let better = nearest.get(&key).is_none_or(|g| gap.width < g.width);
                if better {
                    nearest.insert(key, gap);
                }
            }
        }
    }
    let mut candidates: Vec<((u32, u32), Gap)> = nearest.into_iter().collect();
    candidates.sort_by(|a, b| a.1.width.total_cmp(&b.1.width).then(a.0.cmp(&b.0)));
    let mut parent: Vec<u32> = (0..sizes.len() as u32).collect();
    let mut tree = Vec::new();
    for ((a, b), gap) in candidates {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        if ra != rb {
            parent[ra as usize] = rb;
            tree.push(gap);
        }
    }
    Pieces {
        count: pieces.len(),
        gaps: tree,
    }
}

/// Paints a bridge `thickness` pixels wide across every gap of `pieces` no
/// wider than `reach` into `alpha` (one sample per pixel, `opaque_value`
/// where painted); returns how many it painted.
pub fn bridge(
    width: u32,
    height: u32,
    alpha: &mut [u16],
    pieces: &Pieces,
    reach: f64,
    thickness: f64,
    opaque_value: u16,
) -> usize {
    let (w, h) = (width as i64, height as i64);
    let radius = thickness / 2.0;
    let mut painted = 0;
    for gap in pieces.gaps.iter().filter(|g| g.width <= reach) {
        let lo = gap.from.min(gap.to) - DVec2::splat(radius + 1.0);
        let hi = gap.from.max(gap.to) + DVec2::splat(radius + 1.0);
        for y in (lo.y.floor() as i64).max(0)..=(hi.y.ceil() as i64).min(h - 1) {
            for x in (lo.x.floor() as i64).max(0)..=(hi.x.ceil() as i64).min(w - 1) {
                let at = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                if segment_distance(at, gap.from, gap.to) <= radius {
                    alpha[(y * w + x) as usize] = opaque_value;
                }
            }
        }
        painted += 1;
    }
    painted
}

fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 {
        ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + ab * t)
}

fn root(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

/// 8-connected components of `mask`: a label per pixel (0 transparent,
/// islands from 1) and each label's pixel count (index 0 unused).
fn label(w: usize, h: usize, mask: &[bool]) -> (Vec<u32>, Vec<u32>) {
    let mut labels = vec![0u32; w * h];
    let mut sizes = vec![0u32];
    let mut queue = VecDeque::new();
    for start in 0..w * h {
        if !mask[start] || labels[start] != 0 {
            continue;
        }
        let l = sizes.len() as u32;
        sizes.push(0);
        labels[start] = l;
        queue.push_back(start);
        while let Some(i) = queue.pop_front() {
            sizes[l as usize] += 1;
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            for (dx, dy) in NEIGHBOURS_8 {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if mask[j] && labels[j] == 0 {
                    labels[j] = l;
                    queue.push_back(j);
                }
            }
        }
    }
    (labels, sizes)
}

const NEIGHBOURS_8: [(i64, i64); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// Every pixel's nearest island pixel (of an island that is no speck), as
/// a growth of every island at once: each pixel takes the source of the
/// neighbour it was reached from (8-connected, so distances are close to
/// Euclidean for the short gaps that matter).
fn grow(w: usize, h: usize, labels: &[u32], sizes: &[u32]) -> Vec<Option<u32>> {
    let mut source: Vec<Option<u32>> = vec![None; w * h];
    let mut queue = VecDeque::new();
    for (i, &l) in labels.iter().enumerate() {
        if l != 0 && sizes[l as usize] >= SPECK_PIXELS {
            source[i] = Some(i as u32);
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        for (dx, dy) in NEIGHBOURS_8 {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                continue;
            }
            let j = ny as usize * w + nx as usize;
            if source[j].is_none() {
                source[j] = source[i];
                queue.push_back(j);
            }
        }
    }
    source
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two discs `gap` pixels apart on a line, and a speck.
    fn two_discs(gap: f64) -> (u32, u32, Vec<u16>) {
        let (w, h) = (200u32, 100u32);
        let mut alpha = vec![0u16; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let a = DVec2::new(50.0, 50.0);
                let b = DVec2::new(50.0 + 60.0 + gap, 50.0);
                if p.distance(a) <= 30.0 || p.distance(b) <= 30.0 {
                    alpha[(y * w + x) as usize] = u16::MAX;
                }
            }
        }
        alpha[(5 * w + 190) as usize] = u16::MAX;
        (w, h, alpha)
    }

    #[test]
    fn two_pieces_have_one_gap_of_about_their_distance_and_a_bridge_joins_them() {
        let (w, h, mut alpha) = two_discs(6.0);
        let opaque = |a: &[u16], i: usize| a[i] > u16::MAX / 2;
        let pieces = gaps(w, h, &|i| opaque(&alpha, i));
        assert_eq!(pieces.count, 2, "the speck is no piece");
        assert_eq!(pieces.gaps.len(), 1);
        assert!((pieces.widest() - 6.0).abs() <= 1.5, "{pieces:?}");
        assert_eq!(bridge(w, h, &mut alpha, &pieces, 3.0, 10.0, u16::MAX), 0);
        assert_eq!(bridge(w, h, &mut alpha, &pieces, 8.0, 10.0, u16::MAX), 1);
        let after = gaps(w, h, &|i| opaque(&alpha, i));
        assert_eq!(after.count, 1, "{after:?}");
    }

    #[test]
    fn one_piece_and_none_have_no_gap() {
        let (w, h) = (10u32, 10u32);
        assert_eq!(gaps(w, h, &|_| false).count, 0);
        let one = gaps(w, h, &|i| i % 10 < 5);
        assert_eq!((one.count, one.widest()), (1, 0.0));
    }
}
