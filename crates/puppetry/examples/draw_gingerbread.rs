//! Draws the demo puppet, a gingerbread figure, to
//! `assets/gingerbread/gingerbread.png`: a 512×512 RGBA picture on a
//! transparent background. The figure is a union of distance fields (round
//! head, capsule body, arms and legs, smoothly blended), shaded and decorated
//! with icing, eyes, a smile and candy buttons painted on top — details only,
//! never holes, so the traced outline is the silhouette alone. Each pixel
//! averages 4×4 sub-samples, which gives soft anti-aliased edges.
//!
//! Run with `cargo run --release --example draw_gingerbread`.

use std::f64::consts::TAU;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

const SIZE: u32 = 512;
const SUBSAMPLES: u32 = 4;

type Rgb = [f64; 3];

const DOUGH: Rgb = [184.0, 112.0, 58.0];
const DOUGH_LIGHT: Rgb = [212.0, 146.0, 84.0];
const CRUST: Rgb = [134.0, 72.0, 32.0];
const ICING: Rgb = [252.0, 248.0, 238.0];
const EYE: Rgb = [54.0, 28.0, 18.0];
const CHEEK: Rgb = [226.0, 120.0, 110.0];
const CANDY: [Rgb; 3] = [
    [214.0, 38.0, 52.0],
    [44.0, 158.0, 72.0],
    [236.0, 176.0, 40.0],
];

#[derive(Clone, Copy)]
struct P {
    x: f64,
    y: f64,
}

fn p(x: f64, y: f64) -> P {
    P { x, y }
}

fn sub(a: P, b: P) -> P {
    p(a.x - b.x, a.y - b.y)
}

fn dot(a: P, b: P) -> f64 {
    a.x * b.x + a.y * b.y
}

fn len(a: P) -> f64 {
    dot(a, a).sqrt()
}

fn circle(q: P, c: P, r: f64) -> f64 {
    len(sub(q, c)) - r
}

/// Distance to a segment of round thickness `r`, and how far along it (0..1)
/// the closest point lies.
fn capsule(q: P, a: P, b: P, r: f64) -> (f64, f64) {
    let ab = sub(b, a);
    let t = (dot(sub(q, a), ab) / dot(ab, ab)).clamp(0.0, 1.0);
    let closest = p(a.x + ab.x * t, a.y + ab.y * t);
    (len(sub(q, closest)) - r, t)
}

/// Smooth union, so limbs grow out of the body without creases.
fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    let h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0);
    b + (a - b) * h - k * h * (1.0 - h)
}

fn mix(a: Rgb, b: Rgb, t: f64) -> Rgb {
    let t = t.clamp(0.0, 1.0);
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

struct Limb {
    from: P,
    to: P,
    radius: f64,
}

const HEAD: (f64, f64, f64) = (256.0, 118.0, 78.0);

fn limbs() -> [Limb; 5] {
    [
        // Body, then arms (slightly raised) and legs (apart).
        Limb {
            from: p(256.0, 218.0),
            to: p(256.0, 318.0),
            radius: 82.0,
        },
        Limb {
            from: p(214.0, 246.0),
            to: p(86.0, 212.0),
            radius: 35.0,
        },
        Limb {
            from: p(298.0, 246.0),
            to: p(426.0, 212.0),
            radius: 35.0,
        },
        Limb {
            from: p(222.0, 334.0),
            to: p(168.0, 454.0),
            radius: 39.0,
        },
        Limb {
            from: p(290.0, 334.0),
            to: p(344.0, 454.0),
            radius: 39.0,
        },
    ]
}

/// The colour (if the point is on the figure) and the figure's signed
/// distance there.
fn shade(q: P, limbs: &[Limb]) -> (f64, Rgb) {
    let head = circle(q, p(HEAD.0, HEAD.1), HEAD.2);
    let mut d = head;
    for limb in limbs {
        let (dl, _) = capsule(q, limb.from, limb.to, limb.radius);
        d = smooth_min(d, dl, 14.0);
    }

    // Baked look: lighter toward the middle, a darker crust at the rim.
    let glow = (-d / 60.0).clamp(0.0, 1.0);
    let mut colour = mix(DOUGH, DOUGH_LIGHT, glow * 0.55);
    colour = mix(colour, CRUST, 1.0 - (-d / 7.0).clamp(0.0, 1.0));

    // Wavy icing across each wrist and ankle.
    for limb in &limbs[1..] {
        let axis = sub(limb.to, limb.from);
        let length = len(axis);
        let along_dir = p(axis.x / length, axis.y / length);
        let across_dir = p(-along_dir.y, along_dir.x);
        let rel = sub(q, limb.from);
        let along = dot(rel, along_dir);
        let across = dot(rel, across_dir);
        if across.abs() > limb.radius - 5.0 {
            continue;
        }
        for offset in [length - 8.0, length - 22.0] {
            let wave = offset + 5.0 * (across * TAU / 16.0).sin();
            if (along - wave).abs() < 2.6 && d < -4.0 {
                colour = ICING;
            }
        }
    }

    // Face: cheeks, eyes with a glint, an icing smile.
    for cx in [220.0, 292.0] {
        let c = circle(q, p(cx, 134.0), 11.0);
        colour = mix(colour, CHEEK, (0.5 - c / 2.0).clamp(0.0, 1.0) * 0.7);
    }
    for cx in [228.0, 284.0] {
        if circle(q, p(cx, 104.0), 10.0) < 0.0 {
            colour = EYE;
        }
        if circle(q, p(cx + 3.5, 100.0), 3.0) < 0.0 {
            colour = ICING;
        }
    }
    let smile = sub(q, p(256.0, 112.0));
    let angle = smile.y.atan2(smile.x).to_degrees();
    if (len(smile) - 36.0).abs() < 3.2 && (35.0..145.0).contains(&angle) {
        colour = ICING;
    }
    // Icing scallops along the top of the head.
    let top = sub(q, p(HEAD.0, HEAD.1));
    let top_angle = top.y.atan2(top.x);
    if top_angle < -0.35 && top_angle > -std::f64::consts::PI + 0.35 {
        let scallop = HEAD.2 - 12.0 + 3.0 * (top_angle * 14.0).cos();
        if (len(top) - scallop).abs() < 2.4 {
            colour = ICING;
        }
    }

    // Candy buttons with an icing rim.
    for (k, cy) in [238.0, 282.0, 326.0].into_iter().enumerate() {
        let c = circle(q, p(256.0, cy), 13.0);
        if c < 0.0 {
            colour = if c > -3.0 { ICING } else { CANDY[k] };
            if circle(q, p(252.0, cy - 4.0), 3.0) < 0.0 {
                colour = mix(CANDY[k], ICING, 0.7);
            }
        }
    }
    (d, colour)
}

fn main() {
    let limbs = limbs();
    let mut pixels = vec![0u8; (SIZE * SIZE * 4) as usize];
    let step = 1.0 / f64::from(SUBSAMPLES);
    for py in 0..SIZE {
        for px in 0..SIZE {
            let mut coverage = 0.0;
            let mut sum = [0.0; 3];
            for sy in 0..SUBSAMPLES {
                for sx in 0..SUBSAMPLES {
                    let q = p(
                        f64::from(px) + (f64::from(sx) + 0.5) * step,
                        f64::from(py) + (f64::from(sy) + 0.5) * step,
                    );
                    let (d, colour) = shade(q, &limbs);
                    if d < 0.0 {
                        coverage += 1.0;
                        for c in 0..3 {
                            sum[c] += colour[c];
                        }
                    }
                }
            }
            let at = ((py * SIZE + px) * 4) as usize;
            if coverage > 0.0 {
                for c in 0..3 {
                    pixels[at + c] = (sum[c] / coverage).round().clamp(0.0, 255.0) as u8;
                }
            }
            let total = f64::from(SUBSAMPLES * SUBSAMPLES);
            pixels[at + 3] = (coverage / total * 255.0).round() as u8;
        }
    }

    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/gingerbread/gingerbread.png");
    std::fs::create_dir_all(path.parent().expect("has a parent")).expect("create asset folder");
    let file = File::create(&path).expect("create the PNG");
    let mut encoder = png::Encoder::new(BufWriter::new(file), SIZE, SIZE);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().expect("write the PNG header");
    writer
        .write_image_data(&pixels)
        .expect("write the PNG pixels");
    writer.finish().expect("finish the PNG");
    println!("wrote {}", path.display());
}
