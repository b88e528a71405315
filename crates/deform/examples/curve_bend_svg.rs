//! Draws `docs/curve-bend.svg`: the bend of the scale-adjustment test — the
//! rest arc, the Laplacian step alone (stretched) and both steps — so the
//! picture in `docs/curves.md` is the tested case. Run with
//! `cargo run -p puppetry-deform --example curve_bend_svg`.

use std::fmt::Write as _;

use glam::DVec2;
use puppetry_deform::{Curve, Steps};

fn polyline(points: &[DVec2], colour: &str, dash: &str) -> String {
    let mut d = String::new();
    for p in points {
        let _ = write!(d, "{:.2},{:.2} ", p.x, -p.y);
    }
    format!(
        r#"  <polyline points="{}" fill="none" stroke="{colour}" stroke-width="0.8" {dash}/>
"#,
        d.trim_end()
    )
}

fn main() -> std::io::Result<()> {
    let (rest, anchors, targets) = puppetry_testkit::curve_bend();
    let mut curve = Curve::register(&rest).expect("the bend's rest curve is valid");
    curve.compile(&anchors).expect("three handles compile");
    let step1 = curve.update(&targets, Steps::ScaleFree).unwrap().to_vec();
    let both = curve.update(&targets, Steps::Both).unwrap().to_vec();

    let all = rest.iter().chain(&step1).chain(&both);
    let (min, max) = all.fold((DVec2::MAX, DVec2::MIN), |(lo, hi), p| {
        (lo.min(*p), hi.max(*p))
    });
    let pad = 6.0;
    let mut svg = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="{:.1} {:.1} {:.1} {:.1}" width="640">
  <rect x="{0:.1}" y="{1:.1}" width="{2:.1}" height="{3:.1}" fill="white"/>
"#,
        min.x - pad,
        -max.y - pad,
        max.x - min.x + 2.0 * pad,
        max.y - min.y + 2.0 * pad + 16.0
    );
    svg += &polyline(&rest, "#999999", r#"stroke-dasharray="2 1.5""#);
    svg += &polyline(&step1, "#d0542c", "");
    svg += &polyline(&both, "#2c6fd0", "");
    for p in &both {
        let _ = writeln!(
            svg,
            r##"  <circle cx="{:.2}" cy="{:.2}" r="0.45" fill="#2c6fd0"/>"##,
            p.x, -p.y
        );
    }
    for t in &targets {
        let _ = writeln!(
            svg,
            r##"  <circle cx="{:.2}" cy="{:.2}" r="1.6" fill="none" stroke="black" stroke-width="0.5"/>"##,
            t.x, -t.y
        );
    }
    let legend_y = -min.y + 6.0;
    for (k, (label, colour)) in [
        ("rest", "#999999"),
        ("step 1 only (Laplacian)", "#d0542c"),
        ("both steps (scale-adjusted)", "#2c6fd0"),
    ]
    .iter()
    .enumerate()
    {
        let (x, y) = (min.x, legend_y + k as f64 * 4.5);
        let _ = writeln!(
            svg,
            r#"  <text x="{x:.1}" y="{y:.1}" font-size="3.5" font-family="sans-serif" fill="{colour}">{label}</text>"#
        );
    }
    svg += "</svg>\n";
    let path = puppetry_testkit::root().join("docs/curve-bend.svg");
    std::fs::write(&path, svg)?;
    println!("wrote {}", path.display());
    Ok(())
}
