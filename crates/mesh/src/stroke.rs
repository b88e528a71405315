//! Strokes: what a curve puppet is drawn with. It owns reading a centre line
//! from an SVG path's `d` attribute (lines and quadratic and cubic Béziers,
//! flattened to a polyline), the ribbon mesh laid along a centre line (two
//! vertices per point, half the width either side, so the renderers that
//! draw textured triangles draw strokes unchanged) and the small texture a
//! plain-coloured stroke is drawn with.
//!
//! Coordinates: SVG is y-down and meshes are y-up, so a parsed path comes
//! out with y negated and looks on the stage as it does in a drawing
//! program.

use glam::DVec2;

use super::{Mesh, MeshError};

/// What is wrong with an SVG path, and where (byte offset in the `d` text).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum StrokeError {
    /// [`parse_svg_path`] cannot read the `d` text as one open stroke: bad
    /// syntax, a closed path, a second subpath, an arc, or a flattening
    /// step that is not a finite positive number (at byte 0).
    #[error("svg path: at byte {at}: {problem}")]
    Path {
        /// Byte offset into the `d` text where the problem starts.
        at: usize,
        /// What is wrong there.
        problem: String,
    },
    /// The width given to [`ribbon_mesh`] is not a finite positive number.
    #[error("width {width} must be finite and positive")]
    BadWidth {
        /// The width as given.
        width: f64,
    },
    /// The centre line bends tighter than half the width somewhere, so the
    /// ribbon's inner edge would fold over itself.
    #[error(
        "width {width} is too wide for the curve's bend near point {point}: the stroke's inner edge folds over itself (use a narrower width or a gentler curve)"
    )]
    TooWide {
        /// The width as given, in the centre line's units.
        width: f64,
        /// Index of the centre-line point that starts the segment where the
        /// ribbon folds.
        point: usize,
    },
    /// The ribbon failed [`Mesh::new`]'s checks for any other reason.
    #[error("the stroke's ribbon: {problem}")]
    Ribbon {
        /// The mesh's complaint, its field first.
        problem: String,
    },
}

/// Why the path command letter `c` is refused, if it is: a curve
/// puppet is one open stroke of lines and Béziers.
fn unsupported(c: u8) -> Option<String> {
    match c {
        b'Z' | b'z' => {
            Some("closed paths (Z) are not supported: a curve puppet is an open stroke".into())
        }
        b'A' | b'a' => Some("arcs (A) are not supported: convert them to Béziers".into()),
        c if !b"MmLlHhVvCcSsQqTt".contains(&c) => Some(format!("unknown command {:?}", c as char)),
        _ => None,
    }
}

/// The centre line of an SVG path `d`: one open subpath of `M`/`L`/`H`/`V`/
/// `C`/`S`/`Q`/`T` commands (absolute or relative), with Béziers flattened so
/// no flattened segment is longer than `step` (about). Closed paths,
/// several subpaths and arcs are refused: a curve puppet is one open stroke.
pub fn parse_svg_path(d: &str, step: f64) -> Result<Vec<DVec2>, StrokeError> {
    let mut parser = PathParser {
        text: d.as_bytes(),
        at: 0,
    };
    let fail = |at: usize, problem: &str| StrokeError::Path {
        at,
        problem: problem.to_string(),
    };
    if !(step.is_finite() && step > 0.0) {
        return Err(fail(0, "flattening step must be finite and positive"));
    }
    let mut points: Vec<DVec2> = Vec::new();
    let mut current = DVec2::ZERO;
    // The reflected control point for S and T, when the previous command
    // was of the same family.
    let mut last_cubic: Option<DVec2> = None;
    let mut last_quadratic: Option<DVec2> = None;
    let mut command: Option<(u8, usize)> = None;
    loop {
        parser.skip_separators();
        let Some(&c) = parser.text.get(parser.at) else {
            break;
        };
        if c.is_ascii_alphabetic() {
            command = Some((c, parser.at));
            parser.at += 1;
            if let Some(problem) = unsupported(c) {
                return Err(fail(parser.at - 1, &problem));
            }
        } else if command.is_none() {
            return Err(fail(parser.at, "a path starts with M (moveto)"));
        }
        let (cmd, cmd_at) = command.expect("set above");
        if points.is_empty() && cmd != b'M' && cmd != b'm' {
            return Err(fail(cmd_at, "a path starts with M (moveto)"));
        }
        let relative = cmd.is_ascii_lowercase();
        let base = if relative { current } else { DVec2::ZERO };
        let origin = current;
        match cmd.to_ascii_uppercase() {
            b'M' => {
                if !points.is_empty() && c.is_ascii_alphabetic() {
                    return Err(fail(
                        cmd_at,
                        "a second subpath (M) is not supported: a curve puppet is one stroke",
                    ));
                }
                current = base + parser.pair()?;
                points.push(current);
                // Pairs after a moveto are linetos.
                command = Some((if relative { b'l' } else { b'L' }, cmd_at));
                last_cubic = None;
                last_quadratic = None;
            }
            line @ (b'L' | b'H' | b'V') => {
                current = match line {
                    b'L' => base + parser.pair()?,
                    b'H' => DVec2::new(base.x + parser.number()?, current.y),
                    _ => DVec2::new(current.x, base.y + parser.number()?),
                };
                points.push(current);
                last_cubic = None;
                last_quadratic = None;
            }
            b'C' | b'S' => {
                let first = if cmd.eq_ignore_ascii_case(&b'C') {
                    base + parser.pair()?
                } else {
                    last_cubic.map_or(origin, |c| origin * 2.0 - c)
                };
                let second = base + parser.pair()?;
                let end = base + parser.pair()?;
                flatten_cubic(&mut points, [origin, first, second, end], step);
                current = end;
                last_cubic = Some(second);
                last_quadratic = None;
            }
            b'Q' | b'T' => {
                let control = if cmd.eq_ignore_ascii_case(&b'Q') {
                    base + parser.pair()?
                } else {
                    last_quadratic.map_or(origin, |c| origin * 2.0 - c)
                };
                let end = base + parser.pair()?;
                // A quadratic is the cubic with controls two thirds of the
                // way to its control point.
                let first = origin + (control - origin) * (2.0 / 3.0);
                let second = end + (control - end) * (2.0 / 3.0);
                flatten_cubic(&mut points, [origin, first, second, end], step);
                current = end;
                last_quadratic = Some(control);
                last_cubic = None;
            }
            _ => unreachable!("checked when the command was read"),
        }
        if !current.is_finite() {
            return Err(fail(parser.at, "a coordinate is not finite"));
        }
    }
    if points.is_empty() {
        return Err(fail(0, "the path is empty"));
    }
    // SVG is y-down; the stage is y-up.
    Ok(points.into_iter().map(|p| DVec2::new(p.x, -p.y)).collect())
}

/// Appends the cubic Bézier `c` (without its start point) as segments no
/// longer than `step`: the curve's speed is at most three times its longest
/// control-polygon edge, so that many pieces per step suffice.
fn flatten_cubic(points: &mut Vec<DVec2>, c: [DVec2; 4], step: f64) {
    let longest = c[0]
        .distance(c[1])
        .max(c[1].distance(c[2]))
        .max(c[2].distance(c[3]));
    let pieces = (3.0 * longest / step).ceil().clamp(1.0, 100_000.0) as usize;
    for k in 1..=pieces {
        let t = k as f64 / pieces as f64;
        let u = 1.0 - t;
        points.push(
            c[0] * (u * u * u)
                + c[1] * (3.0 * u * u * t)
                + c[2] * (3.0 * u * t * t)
                + c[3] * (t * t * t),
        );
    }
}

struct PathParser<'a> {
    text: &'a [u8],
    at: usize,
}

impl PathParser<'_> {
    fn skip_separators(&mut self) {
        while self
            .text
            .get(self.at)
            .is_some_and(|c| c.is_ascii_whitespace() || *c == b',')
        {
            self.at += 1;
        }
    }

    fn pair(&mut self) -> Result<DVec2, StrokeError> {
        let x = self.number()?;
        let y = self.number()?;
        Ok(DVec2::new(x, y))
    }

    /// An SVG number: sign, digits, fraction, exponent ("-1.5e3", ".5").
    fn number(&mut self) -> Result<f64, StrokeError> {
        self.skip_separators();
        let start = self.at;
        let digits = |p: &mut Self| {
            let from = p.at;
            while p.text.get(p.at).is_some_and(u8::is_ascii_digit) {
                p.at += 1;
            }
            p.at > from
        };
        if matches!(self.text.get(self.at), Some(b'+' | b'-')) {
            self.at += 1;
        }
        let whole = digits(self);
        let mut fraction = false;
        if self.text.get(self.at) == Some(&b'.') {
            self.at += 1;
            fraction = digits(self);
        }
        if !whole && !fraction {
            self.at = start;
            return Err(StrokeError::Path {
                at: start,
                problem: match self.text.get(start) {
                    Some(&c) => format!("expected a number, found {:?}", c as char),
                    None => "expected a number, found the end of the path".into(),
                },
            });
        }
        if matches!(self.text.get(self.at), Some(b'e' | b'E')) {
            let mark = self.at;
            self.at += 1;
            if matches!(self.text.get(self.at), Some(b'+' | b'-')) {
                self.at += 1;
            }
            if !digits(self) {
                self.at = mark;
            }
        }
        let text = std::str::from_utf8(&self.text[start..self.at]).expect("ASCII");
        text.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| StrokeError::Path {
                at: start,
                problem: format!("{text:?} is not a finite number"),
            })
    }
}

/// Where each centre-line point's two ribbon vertices go: `left` and
/// `right` of the direction of travel, `half_width` away along the mitred
/// normal (capped so a sharp turn does not spike). `out` holds two
/// vertices per point: left at `2i`, right at `2i + 1`. Does not allocate.
pub fn ribbon_vertices(centre: &[DVec2], half_width: f64, out: &mut [DVec2]) {
    let n = centre.len();
    debug_assert_eq!(out.len(), 2 * n);
    if n < 2 {
        return;
    }
    let direction = |i: usize| (centre[i + 1] - centre[i]).normalize_or_zero();
    let mut before = direction(0);
    for i in 0..n {
        let after = if i + 1 < n { direction(i) } else { before };
        let normal = (before.perp() + after.perp()).normalize_or(after.perp());
        // The mitre: the offset that keeps both adjacent edges half a width
        // away, at most twice that at a sharp turn.
        let cos = normal.dot(after.perp()).max(0.5);
        let offset = normal * (half_width / cos);
        out[2 * i] = centre[i] + offset;
        out[2 * i + 1] = centre[i] - offset;
        before = after;
    }
}

/// The two triangles of segment `i`: right `i`, right `i+1`, left `i`; and
/// right `i+1`, left `i+1`, left `i` (counter-clockwise, y-up).
pub fn ribbon_triangle(triangle: usize) -> [u32; 3] {
    let i = (triangle / 2) as u32;
    if triangle.is_multiple_of(2) {
        [2 * i + 1, 2 * i + 3, 2 * i]
    } else {
        [2 * i + 3, 2 * i + 2, 2 * i]
    }
}

/// The ribbon mesh along a (resampled) centre line: texture u runs along
/// the length (0 to 1), v across it (0 on the left edge, 1 on the right).
pub fn ribbon_mesh(source: &str, centre: &[DVec2], width: f64) -> Result<Mesh, StrokeError> {
    if !(width.is_finite() && width > 0.0) {
        return Err(StrokeError::BadWidth { width });
    }
    let mut vertices = vec![DVec2::ZERO; 2 * centre.len()];
    ribbon_vertices(centre, width / 2.0, &mut vertices);
    let mut arc = vec![0.0];
    for w in centre.windows(2) {
        arc.push(arc.last().expect("non-empty") + w[0].distance(w[1]));
    }
    let length = arc.last().copied().unwrap_or(0.0).max(f64::MIN_POSITIVE);
    let uv = arc
        .iter()
        .flat_map(|&s| [DVec2::new(s / length, 0.0), DVec2::new(s / length, 1.0)])
        .collect();
    let triangles: Vec<[u32; 3]> = (0..2 * centre.len().saturating_sub(1))
        .map(ribbon_triangle)
        .collect();
    // A bend tighter than half the width folds the inner edge: find where,
    // to say so in the curve's terms rather than the mesh's.
    for (t, tri) in triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|k| vertices[k as usize]);
        if super::thickness(a, b, c) < super::MIN_THICKNESS {
            return Err(StrokeError::TooWide {
                width,
                point: t / 2,
            });
        }
    }
    Mesh::new(source, vertices, triangles, Some(uv), None).map_err(|e| match e {
        MeshError::Invalid(crate::FieldError { field, problem, .. }) => StrokeError::Ribbon {
            problem: format!("{field}: {problem}"),
        },
        other => StrokeError::Ribbon {
            problem: other.to_string(),
        },
    })
}

/// An 8×16 RGBA texture for a stroke of one colour: opaque across the
/// middle, fading over the outermost rows so its edges are smooth when the
/// renderer filters the texture.
pub fn stroke_texture(colour: [u8; 3]) -> (u32, u32, Vec<u8>) {
    let (width, height) = (8u32, 16u32);
    let mut pixels = Vec::with_capacity((width * height * 4) as usize);
    for row in 0..height {
        let edge = row.min(height - 1 - row);
        let alpha = match edge {
            0 => 96,
            1 => 208,
            _ => 255,
        };
        for _ in 0..width {
            pixels.extend_from_slice(&[colour[0], colour[1], colour[2], alpha]);
        }
    }
    (width, height, pixels)
}

/// [`stroke_texture`] as PNG bytes.
pub fn stroke_texture_png(colour: [u8; 3]) -> Vec<u8> {
    let (width, height, pixels) = stroke_texture(colour);
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder
        .write_header()
        .expect("writing a PNG header to memory cannot fail");
    writer
        .write_image_data(&pixels)
        .expect("the pixel count matches the header");
    writer
        .finish()
        .expect("finishing a PNG in memory cannot fail");
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(d: &str) -> Result<Vec<DVec2>, StrokeError> {
        parse_svg_path(d, 1.0)
    }

    #[test]
    fn lines_absolute_relative_and_implicit_flip_y() {
        let p = path("M 0 0 L 10 0 l 0,10 H 0 v-5 5 -2").unwrap();
        let want = [
            (0.0, 0.0),
            (10.0, 0.0),
            (10.0, 10.0),
            (0.0, 10.0),
            (0.0, 5.0),
            (0.0, 10.0),
            (0.0, 8.0),
        ];
        assert_eq!(p.len(), want.len());
        for (got, (x, y)) in p.iter().zip(want) {
            assert_eq!(*got, DVec2::new(x, -y));
        }
        // Pairs after a moveto are linetos; numbers may run together.
        let q = path("m1-2 3.5.5e1").unwrap();
        assert_eq!(q, vec![DVec2::new(1.0, 2.0), DVec2::new(4.5, -3.0)]);
    }

    #[test]
    fn beziers_end_at_their_end_points_and_stay_within_their_hull() {
        let p = path("M0 0 C 0 50 100 50 100 0 S 200 -50 200 0 Q 250 50 300 0 T 400 0").unwrap();
        let last = *p.last().unwrap();
        assert!((last - DVec2::new(400.0, 0.0)).length() < 1e-9, "{last}");
        // Segments are about the step long.
        for w in p.windows(2) {
            assert!(w[0].distance(w[1]) <= 1.0 + 1e-9);
        }
        // The first cubic's midpoint is at y = 37.5 (flipped: −37.5).
        let mid = p
            .iter()
            .min_by(|a, b| (a.x - 50.0).abs().total_cmp(&(b.x - 50.0).abs()))
            .unwrap();
        assert!((mid.y + 37.5).abs() < 0.5, "{mid}");
    }

    #[test]
    fn bad_paths_say_what_and_where() {
        let cases = [
            ("", 0, "empty"),
            ("L 1 2", 0, "starts with M"),
            ("M 1 2 L 3", 9, "end of the path"),
            ("M 1 2 L 3 x", 10, "found 'x'"),
            ("M 0 0 L 1 1 Z", 12, "closed"),
            ("M 0 0 A 1 1 0 0 0 2 2", 6, "arcs"),
            ("M 0 0 L 1 1 M 5 5 L 6 6", 12, "second subpath"),
            ("M 0 0 L 1e999 0", 8, "not a finite"),
            ("M 0 0 K 1 1", 6, "unknown command"),
        ];
        for (d, at, says) in cases {
            match path(d) {
                Err(StrokeError::Path { at: got, problem }) => {
                    assert_eq!(got, at, "{d:?}: {problem}");
                    assert!(problem.contains(says), "{d:?}: {problem}");
                }
                other => panic!("{d:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn a_ribbon_is_width_wide_and_counter_clockwise() {
        let centre: Vec<DVec2> = (0..20)
            .map(|i| DVec2::new(i as f64 * 5.0, (i as f64 * 0.3).sin() * 10.0))
            .collect();
        let mesh = ribbon_mesh("test", &centre, 4.0).unwrap();
        assert_eq!(mesh.vertices().len(), 40);
        assert_eq!(mesh.triangles().len(), 38);
        for (pair, c) in mesh.vertices().chunks_exact(2).zip(&centre) {
            let (l, r) = (pair[0], pair[1]);
            assert!((l + r - *c * 2.0).length() < 1e-9);
            assert!(l.distance(r) >= 4.0 - 1e-9 && l.distance(r) <= 8.0 + 1e-9);
        }
        let uv = mesh.uv().unwrap();
        assert_eq!(uv[0], DVec2::new(0.0, 0.0));
        assert_eq!(uv[39], DVec2::new(1.0, 1.0));
    }

    #[test]
    fn a_ribbon_too_wide_for_its_bend_is_refused_naming_the_point() {
        // A hairpin of radius 2 cannot carry a stroke 10 wide.
        let centre: Vec<DVec2> = (0..=12)
            .map(|i| {
                let a = std::f64::consts::PI * i as f64 / 12.0;
                DVec2::new(a.cos() * 2.0, a.sin() * 2.0)
            })
            .collect();
        match ribbon_mesh("test", &centre, 10.0) {
            Err(StrokeError::TooWide { point, .. }) => assert!(point < 12),
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            ribbon_mesh("test", &centre, f64::NAN),
            Err(StrokeError::BadWidth { .. })
        ));
    }

    #[test]
    fn the_stroke_texture_is_a_png_of_the_colour() {
        let png = stroke_texture_png([200, 40, 30]);
        let decoder = png::Decoder::new(std::io::Cursor::new(png));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (8, 16));
        let middle = ((8 * 8 + 3) * 4) as usize;
        assert_eq!(&buf[middle..middle + 4], &[200, 40, 30, 255]);
        assert!(buf[3] < 255);
    }
}
