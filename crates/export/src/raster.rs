//! The software rasteriser behind the PNG sequence and the videos: draws an
//! [`Animation`]'s frame the way `clients/web/renderer.js` draws it, on the
//! CPU, into straight-alpha RGBA8 with a transparent background.
//!
//! What it copies from the web renderer:
//!
//! - **Placement**: the stage is fitted into the picture as `StageView`
//!   (`input.js`) fits it into the window — one uniform scale
//!   `min(W / stage_width, H / stage_height)`, centred — and drawn across
//!   that rectangle as the vertex shader does (`pos / stage * 2 - 1`, stage
//!   and clip space both y-up), so rows run from the stage's top down. The
//!   margins are transparent. (The page rounds its canvas to whole pixels;
//!   here the rectangle is exact.)
//! - **Texture**: bilinear, clamped to the edge (WebGL `LINEAR`,
//!   `CLAMP_TO_EDGE`, no mipmaps), over the picture premultiplied to 8 bits
//!   as `UNPACK_PREMULTIPLY_ALPHA_WEBGL` uploads it, `uv` unflipped.
//! - **Blending**: premultiplied `ONE, ONE_MINUS_SRC_ALPHA`, puppets bottom
//!   to top.
//! - **Antialiasing**: the page asks for `antialias: true`, which is 4×
//!   MSAA: coverage at 4 sample points per pixel, the texture read once per
//!   pixel at its centre. We do the same with the standard 4× *rotated
//!   grid* (samples at (3/8, 1/8), (7/8, 3/8), (1/8, 5/8), (5/8, 7/8)): its 4
//!   samples have 4 distinct x and 4 distinct y offsets, so near-horizontal
//!   and near-vertical edges — the most visible ones — get 5 coverage levels
//!   instead of an ordered 2×2 grid's 3.
//!
//! How: vertices are snapped to 1/256 pixel and edge functions evaluated on
//! those exact values (integers held in `f64`, exact below 2^53), with a
//! tie rule that gives a sample on an edge shared by two triangles to
//! exactly one of them. A puppet's triangles then split each pixel's
//! samples between them, so summing `texel × covered / 4` over its
//! triangles gives the puppet's resolved layer exactly as MSAA would; the
//! layer is then blended over what is below. Only the pixels of each
//! triangle's bounding box are visited.
//!
//! Compared with Chromium's rendering of the same vertices (test
//! `png_frame_matches_the_web_renderer`, both over the page's background)
//! the test allows a mean absolute difference of 1.0 (of 255) per channel
//! and asks 99% of pixels to be within 8 on every channel; measured on the
//! demo puppet: 0.29 and 99.8%. What differs is edge pixels, where the
//! GPU's sample positions and rounding differ from ours; a frame 10 frames
//! off scores 16.5 and 83%.

use crate::{Animation, ExportError, flag};

/// The 4 sample points of a pixel, in 1/256 of a pixel from its top-left
/// corner (x right, y down).
const SAMPLES: [(f64, f64); 4] = [(96.0, 32.0), (224.0, 96.0), (32.0, 160.0), (160.0, 224.0)];
/// Subpixel precision: vertex positions snap to 1/256 pixel.
const SUB: f64 = 256.0;

/// Where the stage lands in a `width × height` picture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Viewport {
    /// The picture's width in pixels.
    pub width: u32,
    /// The picture's height in pixels.
    pub height: u32,
    /// Pixels per stage unit.
    pub scale: f64,
    /// The stage's top-left corner, in pixels from the picture's top left.
    pub left: f64,
    /// Pixels from the picture's top edge to the stage's.
    pub top: f64,
    stage_height: f64,
}

impl Viewport {
    /// Fits a stage into a picture: one uniform scale, centred.
    pub fn fit(stage_width: f64, stage_height: f64, width: u32, height: u32) -> Viewport {
        let scale = (width as f64 / stage_width).min(height as f64 / stage_height);
        Viewport {
            width,
            height,
            scale,
            left: (width as f64 - stage_width * scale) / 2.0,
            top: (height as f64 - stage_height * scale) / 2.0,
            stage_height,
        }
    }

    /// A stage point in pixels (x right, y down from the picture's top left).
    pub fn to_pixel(&self, p: [f32; 2]) -> [f64; 2] {
        [
            self.left + p[0] as f64 * self.scale,
            self.top + (self.stage_height - p[1] as f64) * self.scale,
        ]
    }
}

/// Checks an output size (`--size WxH`) against the limits of what is
/// drawn in memory (`puppetry_limits::exports`), before anything is read.
pub fn check_size(width: u32, height: u32) -> Result<(), ExportError> {
    use puppetry_limits::exports::{MAX_EXPORT_PIXELS, MAX_EXPORT_SIDE};
    if width == 0 || height == 0 || width > MAX_EXPORT_SIDE || height > MAX_EXPORT_SIDE {
        return Err(flag(
            "--size",
            format!(
                "{width}x{height}: width and height must be 1 to {MAX_EXPORT_SIDE} pixels \
                 (MAX_EXPORT_SIDE)"
            ),
        ));
    }
    if u64::from(width) * u64::from(height) > MAX_EXPORT_PIXELS {
        return Err(flag(
            "--size",
            format!(
                "{width}x{height}: more than {MAX_EXPORT_PIXELS} pixels a frame \
                 (MAX_EXPORT_PIXELS, 8192x4320)"
            ),
        ));
    }
    Ok(())
}

/// A picture premultiplied to 8 bits, as WebGL holds it after an upload
/// with `UNPACK_PREMULTIPLY_ALPHA_WEBGL`.
pub struct Texture {
    width: usize,
    height: usize,
    texels: Vec<[u8; 4]>,
}

impl Texture {
    /// The picture premultiplied, as the page's WebGL upload holds it.
    pub fn new(image: &crate::RgbaImage) -> Texture {
        let texels = image
            .pixels
            .chunks_exact(4)
            .map(|p| {
                let a = p[3] as u32;
                let m = |c: u8| ((c as u32 * a + 127) / 255) as u8;
                [m(p[0]), m(p[1]), m(p[2]), p[3]]
            })
            .collect();
        Texture {
            width: image.width as usize,
            height: image.height as usize,
            texels,
        }
    }

    /// Bilinear, clamped to the edge: premultiplied RGBA in 0..=255.
    #[inline]
    fn sample(&self, u: f32, v: f32) -> [f32; 4] {
        let s = u * self.width as f32 - 0.5;
        let t = v * self.height as f32 - 0.5;
        // floor() without a libm call: truncation is flooring at and above
        // 0, and clamping to the edge makes everything below -1 alike.
        let floor = |c: f32| (c.max(-1.0) + 1.0) as i32 - 1;
        let (x0, y0) = (floor(s), floor(t));
        let (fx, fy) = (s - x0 as f32, t - y0 as f32);
        let clamp = |c: i32, n: usize| (c.max(0) as usize).min(n - 1);
        let (xa, xb) = (clamp(x0, self.width), clamp(x0 + 1, self.width));
        let (ya, yb) = (clamp(y0, self.height), clamp(y0 + 1, self.height));
        let row_a = ya * self.width;
        let row_b = yb * self.width;
        let [p00, p10, p01, p11] = [
            self.texels[row_a + xa],
            self.texels[row_a + xb],
            self.texels[row_b + xa],
            self.texels[row_b + xb],
        ];
        let w00 = (1.0 - fx) * (1.0 - fy);
        let w10 = fx * (1.0 - fy);
        let w01 = (1.0 - fx) * fy;
        let w11 = fx * fy;
        std::array::from_fn(|c| {
            p00[c] as f32 * w00 + p10[c] as f32 * w10 + p01[c] as f32 * w01 + p11[c] as f32 * w11
        })
    }
}

/// Pixels `x0..x1 × y0..y1` (exclusive ends); empty when `x0 >= x1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Rect {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

impl Rect {
    const EMPTY: Rect = Rect {
        x0: 0,
        y0: 0,
        x1: 0,
        y1: 0,
    };
    fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }
    fn width(&self) -> usize {
        self.x1 - self.x0
    }
    fn union(self, o: Rect) -> Rect {
        if self.is_empty() {
            return o;
        }
        if o.is_empty() {
            return self;
        }
        Rect {
            x0: self.x0.min(o.x0),
            y0: self.y0.min(o.y0),
            x1: self.x1.max(o.x1),
            y1: self.y1.max(o.y1),
        }
    }
}

/// Draws frames of one animation; one per thread (it owns its scratch
/// buffers), sharing the textures.
pub struct Rasterizer<'a> {
    animation: &'a Animation,
    textures: &'a [Texture],
    view: Viewport,
    /// Snapped vertex positions of the puppet being drawn, in 1/256 pixel.
    points: Vec<[f64; 2]>,
    /// The resolved layer of the puppet being drawn, premultiplied 0..=1.
    layer: Vec<[f32; 4]>,
    /// Everything drawn so far (premultiplied 0..=1), over `dirty`.
    canvas: Vec<[f32; 4]>,
    /// For a puppet drawn in depth order: which of each pixel's 4 samples
    /// a nearer triangle already took (bit s: sample s).
    taken: Vec<u8>,
}

/// Premultiplies every puppet's picture once, for [`Rasterizer::new`].
pub fn textures(animation: &Animation) -> Vec<Texture> {
    animation
        .puppets
        .iter()
        .map(|p| Texture::new(&p.image))
        .collect()
}

impl<'a> Rasterizer<'a> {
    /// A rasteriser of `animation` (already validated) into `width × height`
    /// pictures; `textures` from [`textures`].
    pub fn new(
        animation: &'a Animation,
        textures: &'a [Texture],
        width: u32,
        height: u32,
    ) -> Rasterizer<'a> {
        Rasterizer {
            animation,
            textures,
            view: Viewport::fit(animation.stage_width, animation.stage_height, width, height),
            points: Vec::new(),
            layer: Vec::new(),
            canvas: Vec::new(),
            taken: Vec::new(),
        }
    }

    /// Where the stage lands in the picture being drawn.
    pub fn viewport(&self) -> Viewport {
        self.view
    }

    /// Draws frame `frame` into `out`: straight RGBA8, rows top to bottom,
    /// `width × height × 4` bytes, transparent where nothing is drawn.
    pub fn render(&mut self, frame: usize, out: &mut [u8]) {
        let (w, h) = (self.view.width as usize, self.view.height as usize);
        assert_eq!(out.len(), w * h * 4, "output buffer size");
        out.fill(0);
        // The region any puppet touches, and each puppet's own.
        let mut regions = Vec::with_capacity(self.animation.puppets.len());
        let mut dirty = Rect::EMPTY;
        for p in &self.animation.puppets {
            let r = self.bounds(&p.frames[frame]);
            dirty = dirty.union(r);
            regions.push(r);
        }
        if dirty.is_empty() {
            return;
        }
        let dw = dirty.width();
        self.canvas.clear();
        self.canvas.resize(dw * (dirty.y1 - dirty.y0), [0.0; 4]);
        let mut first = true;
        for (i, p) in self.animation.puppets.iter().enumerate() {
            let r = regions[i];
            if r.is_empty() {
                continue;
            }
            // The lowest puppet goes straight onto the empty canvas (its
            // layer over nothing is itself); the others through a layer.
            let direct = std::mem::take(&mut first);
            let rw = r.width();
            if !direct {
                self.layer.clear();
                self.layer.resize(rw * (r.y1 - r.y0), [0.0; 4]);
            }
            self.points.clear();
            let view = self.view;
            self.points.extend(p.frames[frame].iter().map(|&q| {
                let [x, y] = view.to_pixel(q);
                [(x * SUB).round(), (y * SUB).round()]
            }));
            let texture = &self.textures[i];
            let (target, area) = if direct {
                (&mut self.canvas, dirty)
            } else {
                (&mut self.layer, r)
            };
            let points = &self.points;
            let mut draw = |tri: &[u32; 3], taken: Option<&mut [u8]>| {
                let [a, b, c] = tri.map(|v| v as usize);
                draw_triangle(
                    [points[a], points[b], points[c]],
                    [p.uv[a], p.uv[b], p.uv[c]],
                    texture,
                    area,
                    (w, h),
                    target,
                    taken,
                );
            };
            if p.draw_orders.is_empty() {
                p.triangles.iter().for_each(|tri| draw(tri, None));
            } else {
                // A puppet that overlaps itself: front to back, each sample
                // to the nearest triangle over it, so a part folded over
                // another covers it whole (as the page's back-to-front
                // drawing of opaque texels does).
                self.taken.clear();
                self.taken.resize(area.width() * (area.y1 - area.y0), 0);
                for tri in p.triangles_drawn(frame).rev() {
                    draw(tri, Some(&mut self.taken));
                }
            }
            if direct {
                continue;
            }
            // The layer over what is below: ONE, ONE_MINUS_SRC_ALPHA.
            for y in r.y0..r.y1 {
                let src = &self.layer[(y - r.y0) * rw..][..rw];
                let dst = &mut self.canvas[(y - dirty.y0) * dw + (r.x0 - dirty.x0)..][..rw];
                for (d, s) in dst.iter_mut().zip(src) {
                    if s[3] <= 0.0 {
                        continue;
                    }
                    // Folded-over triangles may cover a sample twice.
                    let k = if s[3] > 1.0 { 1.0 / s[3] } else { 1.0 };
                    let keep = 1.0 - s[3] * k;
                    for c in 0..4 {
                        d[c] = s[c] * k + d[c] * keep;
                    }
                }
            }
        }
        // Premultiplied floats to straight bytes.
        for y in dirty.y0..dirty.y1 {
            let src = &self.canvas[(y - dirty.y0) * dw..][..dw];
            let dst = &mut out[(y * w + dirty.x0) * 4..][..dw * 4];
            for (d, s) in dst.chunks_exact_mut(4).zip(src) {
                if s[3] <= 0.0 {
                    continue;
                }
                // (Alpha over 1: folded-over triangles covered a sample
                // twice; the colour is the same either way.)
                let a = s[3].min(1.0);
                let inv = 255.0 / s[3];
                d[0] = (s[0] * inv + 0.5).min(255.0) as u8;
                d[1] = (s[1] * inv + 0.5).min(255.0) as u8;
                d[2] = (s[2] * inv + 0.5).min(255.0) as u8;
                d[3] = (a * 255.0 + 0.5) as u8;
            }
        }
    }

    /// The pixels whose samples a frame's vertices may cover, clipped to
    /// the picture.
    fn bounds(&self, frame: &[[f32; 2]]) -> Rect {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for &q in frame {
            // Snapped as the triangles will be, so they stay inside.
            let [x, y] = self.view.to_pixel(q).map(|c| (c * SUB).round() / SUB);
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        pixel_rect(
            x0,
            y0,
            x1,
            y1,
            self.view.width as usize,
            self.view.height as usize,
        )
    }
}

/// Pixels touching the box `x0..x1 × y0..y1` (pixel units), clipped.
fn pixel_rect(x0: f64, y0: f64, x1: f64, y1: f64, w: usize, h: usize) -> Rect {
    let lo = |v: f64, n: usize| v.floor().clamp(0.0, n as f64) as usize;
    let hi = |v: f64, n: usize| (v.floor() + 1.0).clamp(0.0, n as f64) as usize;
    Rect {
        x0: lo(x0, w),
        y0: lo(y0, h),
        x1: hi(x1, w),
        y1: hi(y1, h),
    }
}

/// Adds one triangle's covered samples × its texture to the layer
/// (which covers `region` of a `size` picture). `p`: snapped pixel
/// positions in 1/256 pixel.
#[inline(never)]
fn draw_triangle(
    mut p: [[f64; 2]; 3],
    mut uv: [[f32; 2]; 3],
    texture: &Texture,
    region: Rect,
    size: (usize, usize),
    layer: &mut [[f32; 4]],
    mut taken: Option<&mut [u8]>,
) {
    let edge = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    };
    let mut area = edge(p[0], p[1], p[2]);
    if area == 0.0 {
        return;
    }
    if area < 0.0 {
        // Clockwise in pixel space (y down): a counter-clockwise stage
        // triangle, or a folded one; WebGL draws both (no culling).
        p.swap(1, 2);
        uv.swap(1, 2);
        area = -area;
    }
    let (w, h) = size;
    let r = pixel_rect(
        p[0][0].min(p[1][0]).min(p[2][0]) / SUB,
        p[0][1].min(p[1][1]).min(p[2][1]) / SUB,
        p[0][0].max(p[1][0]).max(p[2][0]) / SUB,
        p[0][1].max(p[1][1]).max(p[2][1]) / SUB,
        w,
        h,
    );
    if r.is_empty() {
        return;
    }
    // Edge i runs from p[i+1] to p[i+2] (opposite vertex i), so its function
    // is vertex i's barycentric weight × area: E(q) = A·qx + B·qy + C,
    // positive inside.
    let mut ea = [0.0f64; 3];
    let mut eb = [0.0f64; 3];
    let mut ec = [0.0f64; 3];
    let mut bias = [0.0f64; 3];
    for i in 0..3 {
        let a = p[(i + 1) % 3];
        let b = p[(i + 2) % 3];
        ea[i] = -(b[1] - a[1]);
        eb[i] = b[0] - a[0];
        ec[i] = -(ea[i] * a[0] + eb[i] * a[1]);
        // Tie rule: a sample exactly on the edge belongs to the triangle
        // for which the edge runs this way; the neighbour across it runs it
        // the other way, so exactly one of the two takes the sample.
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        // (Edge values are integers: +0.5 turns `E > 0` into `E >= 0`.)
        bias[i] = if dy < 0.0 || (dy == 0.0 && dx > 0.0) {
            0.5
        } else {
            0.0
        };
    }
    // Per edge, each sample's offset from the pixel's corner.
    let offsets: [[f64; 4]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|s| ea[i] * SAMPLES[s].0 + eb[i] * SAMPLES[s].1 + bias[i])
    });
    let centre: [f64; 3] = std::array::from_fn(|i| (ea[i] + eb[i]) * 128.0);
    let step = ea.map(|a| a * SUB);
    let inv_area = 1.0 / area;
    let rw = region.width();
    // Per edge, the largest sample offset: a pixel can only have a sample
    // inside an edge if its corner value plus this is positive.
    let reach: [f64; 3] =
        std::array::from_fn(|i| offsets[i].iter().copied().fold(f64::MIN, f64::max));
    let least: [f64; 3] =
        std::array::from_fn(|i| offsets[i].iter().copied().fold(f64::MAX, f64::min));
    let columns = (r.x1 - r.x0) as f64;
    for y in r.y0..r.y1 {
        let qy = y as f64 * SUB;
        let qx = r.x0 as f64 * SUB;
        let corner: [f64; 3] = std::array::from_fn(|i| ea[i] * qx + eb[i] * qy + ec[i]);
        // The columns (from r.x0) where every edge can still hold a sample,
        // widened by one each side against rounding; exact tests follow.
        let (mut lo, mut hi) = (0.0f64, columns - 1.0);
        for i in 0..3 {
            let v = corner[i] + reach[i];
            if step[i] > 0.0 {
                lo = lo.max((-v / step[i]).floor() - 1.0);
            } else if step[i] < 0.0 {
                hi = hi.min((v / -step[i]).ceil() + 1.0);
            } else if v <= 0.0 {
                hi = -1.0;
            }
        }
        if lo > hi {
            continue;
        }
        let (lo, hi) = (lo as usize, hi as usize);
        let mut e: [f64; 3] = std::array::from_fn(|i| corner[i] + step[i] * lo as f64);
        let row = &mut layer[(y - region.y0) * rw..][..rw];
        for x in r.x0 + lo..=r.x0 + hi {
            // Inside every edge at the least favourable sample: all 4 in
            // (most pixels); else test each.
            let mut inside: u8 =
                if e[0] + least[0] > 0.0 && e[1] + least[1] > 0.0 && e[2] + least[2] > 0.0 {
                    0b1111
                } else {
                    (0..4)
                        .filter(|&s| {
                            e[0] + offsets[0][s] > 0.0
                                && e[1] + offsets[1][s] > 0.0
                                && e[2] + offsets[2][s] > 0.0
                        })
                        .fold(0, |m, s| m | 1 << s)
                };
            if let Some(taken) = taken.as_deref_mut() {
                let cell = &mut taken[(y - region.y0) * rw + (x - region.x0)];
                inside &= !*cell;
                *cell |= inside;
            }
            let covered = inside.count_ones();
            if covered > 0 {
                // Barycentric weights at the pixel's centre (extrapolated
                // when the centre is outside, as a GPU does).
                let l0 = ((e[0] + centre[0]) * inv_area) as f32;
                let l1 = ((e[1] + centre[1]) * inv_area) as f32;
                let l2 = 1.0 - l0 - l1;
                let u = uv[0][0] * l0 + uv[1][0] * l1 + uv[2][0] * l2;
                let v = uv[0][1] * l0 + uv[1][1] * l1 + uv[2][1] * l2;
                let texel = texture.sample(u, v);
                let k = covered as f32 * (0.25 / 255.0);
                let dst = &mut row[x - region.x0];
                for c in 0..4 {
                    dst[c] += texel[c] * k;
                }
            }
            for i in 0..3 {
                e[i] += step[i];
            }
        }
    }
}

/// Draws frames `0..frame_count` of a validated animation at
/// `width × height` on every core. Each worker draws a frame and passes it
/// to `work` (on the worker: encode, convert…); `deliver` then gets the
/// results on the calling thread in frame order. At most a few frames per
/// thread are in flight, so memory stays bounded however slow `deliver`
/// is. The first error stops everything and is returned.
pub fn render_frames<T: Send>(
    animation: &Animation,
    width: u32,
    height: u32,
    work: impl Fn(usize, &[u8]) -> Result<T, ExportError> + Sync,
    mut deliver: impl FnMut(usize, T) -> Result<(), ExportError>,
) -> Result<(), ExportError> {
    use std::collections::BTreeMap;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    use std::sync::{Condvar, Mutex, mpsc};

    let n = animation.frame_count;
    let threads = std::thread::available_parallelism()
        .map_or(2, |t| t.get())
        .clamp(1, n.max(1));
    let window = 4 * threads;
    let textures = textures(animation);
    let next = AtomicUsize::new(0);
    let abort = AtomicBool::new(false);
    // Frames delivered so far; workers wait while they are too far ahead.
    let delivered = (Mutex::new(0usize), Condvar::new());
    let (tx, rx) = mpsc::channel::<(usize, Result<T, ExportError>)>();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            let tx = tx.clone();
            let (textures, next, abort, delivered, work) =
                (&textures, &next, &abort, &delivered, &work);
            scope.spawn(move || {
                let mut raster = Rasterizer::new(animation, textures, width, height);
                let mut buf = vec![0u8; width as usize * height as usize * 4];
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    if k >= n {
                        return;
                    }
                    {
                        let (lock, wake) = delivered;
                        let mut done = lock.lock().unwrap_or_else(|e| e.into_inner());
                        while k >= *done + window && !abort.load(Ordering::Relaxed) {
                            done = wake.wait(done).unwrap_or_else(|e| e.into_inner());
                        }
                    }
                    if abort.load(Ordering::Relaxed) {
                        return;
                    }
                    raster.render(k, &mut buf);
                    if tx.send((k, work(k, &buf))).is_err() {
                        return;
                    }
                }
            });
        }
        drop(tx);
        let mut pending = BTreeMap::new();
        let mut expected = 0;
        let result: Result<(), ExportError> = (|| {
            for (k, r) in rx.iter() {
                pending.insert(k, r);
                while let Some(r) = pending.remove(&expected) {
                    deliver(expected, r?)?;
                    expected += 1;
                    let (lock, wake) = &delivered;
                    *lock.lock().unwrap_or_else(|e| e.into_inner()) = expected;
                    wake.notify_all();
                }
            }
            Ok(())
        })();
        if result.is_err() {
            // Under the lock, so no worker misses it between check and wait.
            let guard = delivered.0.lock().unwrap_or_else(|e| e.into_inner());
            abort.store(true, Ordering::Relaxed);
            drop(guard);
            delivered.1.notify_all();
        }
        result
    })?;
    // A worker that panicked would have left frames undelivered; the scope
    // re-raises its panic, so getting here means all were delivered.
    debug_assert!(next.load(std::sync::atomic::Ordering::Relaxed) >= n);
    Ok(())
}
