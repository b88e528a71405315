//! Picture to outline: decodes a PNG, thresholds its alpha at 50%, follows
//! every boundary with marching squares (sub-pixel, interpolated along cell
//! edges), sorts the closed rings into islands and holes, drops specks and
//! simplifies each ring (Douglas–Peucker) without letting rings cross.
//!
//! Output coordinates are the mesh frame: y-up pixel units, the picture
//! spanning [0, width] × [0, height].

use std::collections::HashMap;
use std::io::BufReader;
use std::path::Path;

use glam::DVec2;

use super::polygon::{
    Polygon, Shape, bounds, find_crossing, point_in_ring, signed_area, simplify_keep,
};
use puppetry_limits::files::{
    MAX_OUTLINE_RINGS, MAX_OUTLINE_SEGMENTS, MAX_PICTURE_DECODED_BYTES, MAX_PICTURE_PIXELS,
    MAX_PICTURE_SIDE,
};

use super::{MeshError, cross, file, invalid};

/// An outline traced from a picture, with the picture's size (for uv).
#[derive(Debug, Clone, PartialEq)]
pub struct Traced {
    /// The outline in the mesh frame: y-up pixels, the picture spanning
    /// [0, width] × [0, height]; largest island first.
    pub shape: Shape,
    /// The picture's width, in pixels.
    pub width: u32,
    /// The picture's height, in pixels.
    pub height: u32,
    /// What the user should hear about the picture although it traced.
    pub warnings: Vec<PictureWarning>,
}

/// Something about a picture worth telling the user, though it meshes: a
/// value, not a log line, so the command line prints it and the daemon can
/// send it to the page that uploaded the picture.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PictureWarning {
    /// No pixel is transparent (no alpha channel, or a background that is
    /// not see-through): the figure cannot be told from its background, so
    /// the mesh is the whole picture's rectangle.
    #[error(
        "{file}: every pixel is opaque (no transparent background), so the puppet is the \
         whole {width}×{height} rectangle; to mesh a figure's outline, cut it out onto a \
         transparent background (PNG with alpha)"
    )]
    FullyOpaque {
        /// The picture: its path, or the name given to [`trace_rgba`].
        file: String,
        /// The picture's width, in pixels.
        width: u32,
        /// The picture's height, in pixels.
        height: u32,
    },
    /// The opaque pixels are several islands: each becomes a piece of the
    /// puppet that moves on its own (a head drawn a few pixels off its
    /// body floats away from it).
    #[error(
        "{file}: the picture is {pieces} separate pieces (islands of opaque pixels), and each \
         moves on its own; to make them one puppet, join them across gaps up to {gap} pixels \
         (`puppetry mesh --join {gap}`, or \"join pieces\" on the page) or draw them touching"
    )]
    Pieces {
        /// The picture: its path, or the name given to [`trace_rgba`].
        file: String,
        /// How many pieces (specks left out).
        pieces: usize,
        /// The widest gap that joining them all must bridge, whole pixels.
        gap: u32,
    },
}

/// Rings enclosing less than this many square pixels are specks or pinholes:
/// too small to deform, and they would only force tiny triangles.
pub const SPECK_AREA: f64 = 4.0;

/// Alpha is kept as 16-bit samples (8-bit values scaled by 257) so 8- and
/// 16-bit pictures share one exact threshold halfway up the range.
const THRESHOLD: f64 = 32767.5;

/// Reads a PNG (any colour type and bit depth; palette transparency is
/// honoured, a picture without alpha is fully opaque) and traces it.
/// `detail` is the simplification tolerance in pixels; `join` bridges the
/// picture's pieces across gaps up to that many pixels ([`crate::join`]).
pub fn trace_png(path: &Path, detail: f64, join: Option<f64>) -> Result<Traced, MeshError> {
    let name = path.display().to_string();
    let (width, height, mut alpha) = read_alpha(path, &name)?;
    trace_joined(&name, width, height, &mut alpha, detail, join)
}

/// Traces 8-bit RGBA pixels (row-major from the top row); `source` names the
/// picture in errors.
pub fn trace_rgba(
    source: &str,
    width: u32,
    height: u32,
    rgba: &[u8],
    detail: f64,
    join: Option<f64>,
) -> Result<Traced, MeshError> {
    let expected = width as u64 * height as u64 * 4;
    if rgba.len() as u64 != expected {
        return Err(invalid(
            source,
            "rgba",
            format!(
                "has {} bytes, expected {width}×{height}×4 = {expected}",
                rgba.len()
            ),
        ));
    }
    let mut alpha: Vec<u16> = rgba.chunks_exact(4).map(|p| p[3] as u16 * 257).collect();
    trace_joined(source, width, height, &mut alpha, detail, join)
}

/// Traces `alpha`; when it is several pieces, bridges the gaps up to
/// `join` pixels wide and traces again, and warns of the pieces left
/// ([`PictureWarning::Pieces`]).
fn trace_joined(
    source: &str,
    width: u32,
    height: u32,
    alpha: &mut [u16],
    detail: f64,
    join: Option<f64>,
) -> Result<Traced, MeshError> {
    if let Some(reach) = join
        && !(reach.is_finite() && (0.0..=MAX_JOIN).contains(&reach))
    {
        return Err(invalid(
            source,
            "join",
            format!("must be 0 to {MAX_JOIN} pixels, got {reach}"),
        ));
    }
    let mut traced = trace_alpha(source, width, height, alpha, detail)?;
    if traced.shape.polygons.len() < 2 {
        return Ok(traced);
    }
    let opaque = |a: &[u16], i: usize| f64::from(a[i]) > THRESHOLD;
    let mut pieces = crate::join::gaps(width, height, &|i| opaque(alpha, i));
    if let Some(reach) = join {
        // Thick enough to hold, as a neck holds a head: at least the gap
        // and a fiftieth of the picture.
        let side = f64::from(width.max(height));
        let thickness = pieces.widest().min(reach).max(side / 50.0).max(6.0);
        if crate::join::bridge(width, height, alpha, &pieces, reach, thickness, u16::MAX) > 0 {
            traced = trace_alpha(source, width, height, alpha, detail)?;
            pieces = crate::join::gaps(width, height, &|i| opaque(alpha, i));
        }
    }
    if pieces.count > 1 {
        traced.warnings.push(PictureWarning::Pieces {
            file: source.to_string(),
            pieces: pieces.count,
            gap: pieces.widest().ceil() as u32,
        });
    }
    Ok(traced)
}

/// The widest gap a join bridges, pixels: pieces further apart than this
/// are not one figure.
pub const MAX_JOIN: f64 = 512.0;

fn not_png(name: &str, e: png::DecodingError) -> MeshError {
    match e {
        png::DecodingError::IoError(source) => MeshError::Io {
            file: name.to_string(),
            source,
        },
        other => MeshError::Io {
            file: name.to_string(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("not a valid PNG image: {other}"),
            ),
        },
    }
}

/// Whether a picture of `width` × `height` pixels, `bytes` once decoded
/// (None: past `usize`), may be decoded: checked from the PNG header,
/// before a pixel is read, so a small file claiming a huge picture (a
/// "picture bomb") costs nothing. `name` is the picture in errors.
pub fn check_picture_size(
    name: &str,
    width: u32,
    height: u32,
    bytes: Option<usize>,
) -> Result<(), MeshError> {
    let pixels = u64::from(width) * u64::from(height);
    let problem = if width > MAX_PICTURE_SIDE || height > MAX_PICTURE_SIDE {
        format!("a side is longer than {MAX_PICTURE_SIDE} pixels (MAX_PICTURE_SIDE)")
    } else if pixels > MAX_PICTURE_PIXELS {
        format!("{pixels} pixels, more than {MAX_PICTURE_PIXELS} (MAX_PICTURE_PIXELS)")
    } else if bytes.is_none_or(|b| b as u64 > MAX_PICTURE_DECODED_BYTES) {
        format!(
            "its pixels take more than {MAX_PICTURE_DECODED_BYTES} bytes decoded \
             (MAX_PICTURE_DECODED_BYTES)"
        )
    } else {
        return Ok(());
    };
    Err(invalid(
        name,
        "size",
        format!("{width}×{height} pixels is too large: {problem}; scale the picture down"),
    ))
}

/// A PNG decoder of the picture at `path` that has read the header and
/// checked the picture's size ([`check_picture_size`]) before anything
/// else: the file is read through [`file::reader`] (a regular file within
/// `MAX_PICTURE_FILE_BYTES`) and the decoder's own allocations are capped
/// at `MAX_PICTURE_DECODED_BYTES` too. `transformations` are set first, so
/// the decoded size checked is the one `next_frame` will fill.
pub fn open_png(
    path: &Path,
    transformations: png::Transformations,
) -> Result<png::Reader<BufReader<file::Capped>>, MeshError> {
    let name = path.display().to_string();
    let input = file::reader(path, file::PICTURE_FILE)?;
    let limits = png::Limits {
        bytes: MAX_PICTURE_DECODED_BYTES as usize,
    };
    let mut decoder = png::Decoder::new_with_limits(BufReader::new(input), limits);
    decoder.set_transformations(transformations);
    let (width, height) = decoder
        .read_header_info()
        .map_err(|e| not_png(&name, e))?
        .size();
    check_picture_size(&name, width, height, Some(0))?;
    let reader = decoder.read_info().map_err(|e| not_png(&name, e))?;
    check_picture_size(&name, width, height, reader.output_buffer_size())?;
    Ok(reader)
}

/// Decodes a PNG to one 16-bit alpha sample per pixel.
fn read_alpha(path: &Path, name: &str) -> Result<(u32, u32, Vec<u16>), MeshError> {
    // Palette → RGB(A) with tRNS as alpha, low bit depths → 8 bits.
    let mut reader = open_png(path, png::Transformations::EXPAND)?;
    let (width, height) = reader.info().size();
    let size = reader.output_buffer_size().ok_or_else(|| {
        invalid(
            name,
            "size",
            format!("{width}×{height} pixels is too large to trace"),
        )
    })?;
    let mut buf = vec![0u8; size];
    let frame = reader.next_frame(&mut buf).map_err(|e| not_png(name, e))?;
    let (color, depth) = reader.output_color_type();
    let channels = color.samples();
    let bytes = match depth {
        png::BitDepth::Sixteen => 2,
        png::BitDepth::Eight => 1,
        other => {
            return Err(invalid(
                name,
                "bit depth",
                format!("unexpected bit depth {other:?} after expansion"),
            ));
        }
    };
    let has_alpha = matches!(color, png::ColorType::GrayscaleAlpha | png::ColorType::Rgba);
    let line = frame.line_size;
    let mut alpha = Vec::with_capacity(width as usize * height as usize);
    for row in buf.chunks_exact(line).take(height as usize) {
        for px in 0..width as usize {
            if !has_alpha {
                alpha.push(u16::MAX);
                continue;
            }
            let at = (px * channels + channels - 1) * bytes;
            alpha.push(if bytes == 2 {
                u16::from_be_bytes([row[at], row[at + 1]])
            } else {
                row[at] as u16 * 257
            });
        }
    }
    if alpha.len() != width as usize * height as usize {
        return Err(MeshError::Io {
            file: name.to_string(),
            source: std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "the PNG image data is truncated",
            ),
        });
    }
    Ok((width, height, alpha))
}

/// The tracer proper, over one alpha sample per pixel (0..=65535).
fn trace_alpha(
    source: &str,
    width: u32,
    height: u32,
    alpha: &[u16],
    detail: f64,
) -> Result<Traced, MeshError> {
    if !(detail.is_finite() && detail >= 0.0) {
        return Err(invalid(
            source,
            "detail",
            format!("must be a finite number of pixels, 0 or more, got {detail}"),
        ));
    }
    if width == 0 || height == 0 {
        return Err(invalid(
            source,
            "size",
            format!("the picture is empty ({width}×{height} pixels)"),
        ));
    }
    check_picture_size(source, width, height, Some(alpha.len() * 2))?;
    let opaque = |a: u16| a as f64 > THRESHOLD;
    let opaque_count = alpha.iter().filter(|&&a| opaque(a)).count();
    if opaque_count == 0 {
        return Err(invalid(
            source,
            "alpha",
            "no pixel is opaque (alpha at least 50%): there is nothing to mesh",
        ));
    }
    if opaque_count == alpha.len() {
        // The whole picture: its exact rectangle, not a traced one with
        // corners cut by the half-pixel sampling.
        let (w, h) = (width as f64, height as f64);
        return Ok(Traced {
            shape: Shape {
                polygons: vec![Polygon {
                    outer: vec![
                        DVec2::new(0.0, 0.0),
                        DVec2::new(w, 0.0),
                        DVec2::new(w, h),
                        DVec2::new(0.0, h),
                    ],
                    holes: Vec::new(),
                }],
            },
            width,
            height,
            warnings: vec![PictureWarning::FullyOpaque {
                file: source.to_string(),
                width,
                height,
            }],
        });
    }

    let too_detailed = |problem: String| {
        invalid(
            source,
            "alpha",
            format!("{problem}: too detailed an outline to mesh; smooth or simplify the cut-out"),
        )
    };
    let rings: Vec<Vec<DVec2>> = march(width, height, alpha)
        .ok_or_else(|| {
            too_detailed(format!(
                "more than {MAX_OUTLINE_SEGMENTS} boundary segments (MAX_OUTLINE_SEGMENTS)"
            ))
        })?
        .into_iter()
        .filter(|r| signed_area(r).abs() >= SPECK_AREA)
        .collect();
    if rings.len() as u64 > MAX_OUTLINE_RINGS {
        return Err(too_detailed(format!(
            "{} islands and holes, more than {MAX_OUTLINE_RINGS} (MAX_OUTLINE_RINGS)",
            rings.len()
        )));
    }
    if rings.is_empty() {
        return Err(invalid(
            source,
            "alpha",
            format!(
                "only specks smaller than {SPECK_AREA} square pixels are opaque \
                 (alpha at least 50%): there is nothing to mesh"
            ),
        ));
    }
    let nested = nest(rings);
    let shape = simplify_shape(&nested, detail);
    Ok(Traced {
        shape,
        width,
        height,
        warnings: Vec::new(),
    })
}

/// Marching squares over pixel centres, with a transparent border so every
/// contour closes. Each segment is oriented with the opaque side on its left
/// (y-up), so islands come out counter-clockwise and holes clockwise.
/// None past `MAX_OUTLINE_SEGMENTS` segments, before their memory is spent.
fn march(width: u32, height: u32, alpha: &[u16]) -> Option<Vec<Vec<DVec2>>> {
    let (w, h) = (width as usize, height as usize);
    let sx = w + 2;
    let sy = h + 2;
    let sample = |i: usize, j: usize| -> u16 {
        if i == 0 || j == 0 || i > w || j > h {
            0
        } else {
            alpha[(j - 1) * w + (i - 1)]
        }
    };
    let inside = |i: usize, j: usize| sample(i, j) as f64 > THRESHOLD;
    // Sample (i, j) sits at the centre of pixel (i - 1, j - 1).
    let at = |i: usize, j: usize| DVec2::new(i as f64 - 0.5, h as f64 - (j as f64 - 0.5));
    let vertical_base = (sx * sy) as u64;
    let h_edge = |i: usize, j: usize| (j * sx + i) as u64;
    let v_edge = |i: usize, j: usize| vertical_base + (j * sx + i) as u64;
    // The sample pair an edge joins.
    let ends = |e: u64| -> ((usize, usize), (usize, usize)) {
        if e < vertical_base {
            let (j, i) = ((e as usize) / sx, (e as usize) % sx);
            ((i, j), (i + 1, j))
        } else {
            let k = (e - vertical_base) as usize;
            let (j, i) = (k / sx, k % sx);
            ((i, j), (i, j + 1))
        }
    };
    // Where the interpolated alpha crosses the threshold; kept off the
    // samples themselves so neighbouring crossings never coincide.
    let crossing = |e: u64| -> (DVec2, DVec2) {
        let (p, q) = ends(e);
        let (vp, vq) = (sample(p.0, p.1) as f64, sample(q.0, q.1) as f64);
        let t = ((THRESHOLD - vp) / (vq - vp)).clamp(0.05, 0.95);
        let (pp, pq) = (at(p.0, p.1), at(q.0, q.1));
        let point = pp + (pq - pp) * t;
        let opaque_end = if vp > THRESHOLD { pp } else { pq };
        (point, opaque_end)
    };

    let mut segments: Vec<(u64, u64)> = Vec::new();
    for j in 0..sy - 1 {
        for i in 0..sx - 1 {
            let tl = inside(i, j);
            let tr = inside(i + 1, j);
            let br = inside(i + 1, j + 1);
            let bl = inside(i, j + 1);
            if tl == tr && tr == br && br == bl {
                continue;
            }
            let top = h_edge(i, j);
            let bottom = h_edge(i, j + 1);
            let left = v_edge(i, j);
            let right = v_edge(i + 1, j);
            let mut pairs: [(u64, u64); 2] = [(0, 0); 2];
            let count;
            if tl == br && tr == bl {
                // Saddle: the mean of the four samples decides whether the
                // opaque corners join, the same rule for every cell so the
                // two contours through it never disagree.
                let mean = (sample(i, j) as f64
                    + sample(i + 1, j) as f64
                    + sample(i + 1, j + 1) as f64
                    + sample(i, j + 1) as f64)
                    / 4.0;
                let centre_opaque = mean > THRESHOLD;
                if tl != centre_opaque {
                    pairs = [(top, left), (right, bottom)];
                } else {
                    pairs = [(top, right), (bottom, left)];
                }
                count = 2;
            } else {
                let mut crossed = [0u64; 2];
                let mut n = 0;
                for (edge, a, b) in [
                    (top, tl, tr),
                    (right, tr, br),
                    (bottom, bl, br),
                    (left, tl, bl),
                ] {
                    if a != b {
                        crossed[n] = edge;
                        n += 1;
                    }
                }
                pairs[0] = (crossed[0], crossed[1]);
                count = 1;
            }
            for &(e1, e2) in &pairs[..count] {
                let (p, opaque_end) = crossing(e1);
                let (q, _) = crossing(e2);
                if cross(p, q, opaque_end) > 0.0 {
                    segments.push((e1, e2));
                } else {
                    segments.push((e2, e1));
                }
            }
            if segments.len() as u64 > MAX_OUTLINE_SEGMENTS {
                return None;
            }
        }
    }
    Some(join_rings(&segments, |e| crossing(e).0))
}

/// Joins oriented segments (edge to edge) into rings of the points
/// `point` gives for their first edges; a ring of fewer than three points
/// is dropped.
fn join_rings(segments: &[(u64, u64)], point: impl Fn(u64) -> DVec2) -> Vec<Vec<DVec2>> {
    let from: HashMap<u64, usize> = segments
        .iter()
        .enumerate()
        .map(|(k, &(a, _))| (a, k))
        .collect();
    let mut used = vec![false; segments.len()];
    let mut rings = Vec::new();
    for start in 0..segments.len() {
        if used[start] {
            continue;
        }
        let mut ring = Vec::new();
        let mut k = start;
        while !used[k] {
            used[k] = true;
            let (a, b) = segments[k];
            ring.push(point(a));
            match from.get(&b) {
                Some(&next) => k = next,
                None => break,
            }
        }
        if ring.len() >= 3 {
            rings.push(ring);
        }
    }
    rings
}

/// Sorts rings (counter-clockwise islands, clockwise holes) into polygons:
/// each hole goes to the smallest island around it.
fn nest(rings: Vec<Vec<DVec2>>) -> Shape {
    let mut outers: Vec<(f64, Vec<DVec2>, (DVec2, DVec2))> = Vec::new();
    let mut holes: Vec<Vec<DVec2>> = Vec::new();
    for ring in rings {
        let area = signed_area(&ring);
        if area > 0.0 {
            let b = bounds(&ring);
            outers.push((area, ring, b));
        } else {
            holes.push(ring);
        }
    }
    outers.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut polygons: Vec<Polygon> = outers
        .iter()
        .map(|(_, ring, _)| Polygon {
            outer: ring.clone(),
            holes: Vec::new(),
        })
        .collect();
    for hole in holes {
        let (lo, hi) = bounds(&hole);
        let parent = outers.iter().position(|(_, ring, (olo, ohi))| {
            olo.x <= lo.x
                && olo.y <= lo.y
                && ohi.x >= hi.x
                && ohi.y >= hi.y
                && point_in_ring(hole[0], ring)
        });
        // Contours of a thresholded picture always nest; a hole with no
        // island around it cannot happen, but dropping it is the safe answer.
        if let Some(p) = parent {
            polygons[p].holes.push(hole);
        }
    }
    // Largest first: the main body leads the list.
    polygons.reverse();
    Shape { polygons }
}

/// Simplifies every ring at `detail`, lowering the tolerance of rings that
/// end up crossing (themselves or another ring) or collapsing, until the
/// shape is valid again. The unsimplified contours are valid, so this ends.
fn simplify_shape(raw: &Shape, detail: f64) -> Shape {
    let ids = raw.ring_ids();
    let mut tolerance = vec![detail; ids.len()];
    let mut shape = raw.clone();
    let mut rounds = 0;
    loop {
        for (k, &id) in ids.iter().enumerate() {
            let original = raw.ring(id);
            let mut t = tolerance[k];
            *shape.ring_mut(id) = loop {
                if t < 0.01 {
                    tolerance[k] = 0.0;
                    break original.to_vec();
                }
                match simplify_ring(original, t) {
                    Some(r) => break r,
                    None => {
                        t *= 0.5;
                        tolerance[k] = t;
                    }
                }
            };
        }
        let rings: Vec<&[DVec2]> = ids.iter().map(|&id| shape.ring(id)).collect();
        match find_crossing(&rings) {
            Some(c) => {
                for r in [c.ring_a, c.ring_b] {
                    tolerance[r] = if tolerance[r] < 0.01 {
                        0.0
                    } else {
                        tolerance[r] * 0.5
                    };
                }
            }
            None => {
                if shape.validate("traced outline").is_ok() {
                    return shape;
                }
                // A ring moved past a whole neighbour without crossing it:
                // be more careful everywhere.
                for t in &mut tolerance {
                    *t *= 0.5;
                }
            }
        }
        rounds += 1;
        if rounds > 200 || tolerance.iter().all(|&t| t == 0.0) {
            return raw.clone();
        }
    }
}

/// Douglas–Peucker on a closed ring; `None` when the result would no longer
/// be a proper ring (fewer than 3 points, or flipped or collapsed area).
fn simplify_ring(ring: &[DVec2], tolerance: f64) -> Option<Vec<DVec2>> {
    let keep = simplify_keep(ring, tolerance);
    let out: Vec<DVec2> = ring
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(p, _)| *p)
        .collect();
    let before = signed_area(ring);
    let after = signed_area(&out);
    if out.len() < 3 || after * before <= 0.0 || after.abs() < 0.5 * before.abs() {
        return None;
    }
    Some(out)
}
