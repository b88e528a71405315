//! Curve puppets on the stage: a stroke from points or an SVG path, its
//! ribbon mesh, a drag that peels the curve (the moved part grows with the
//! drag, the rest stays put), pins that bound the peel, segment lengths
//! kept, two performers pulling both ends, undo and reset of the pose, a
//! frame that does not allocate, and bad curves named by file and field.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, Grip, Handle, HandleKind, Owner, Rig, Stage, StageError};
use puppetry_testkit::alloc;

/// A straight rope along x, 400 long, centred at (640, 360), 10 wide,
/// points every 4.
fn rope(extra: &str) -> StageConfig {
    let text = format!(
        r#"
[stage]
width = 1280
height = 720
[[puppet]]
name = "rope"
at = [640, 360]
{extra}
[puppet.curve]
points = [[0, 0], [200, 0], [400, 0]]
width = 10
spacing = 4
"#
    );
    StageConfig::parse("curve-test.toml", &text, Path::new("/")).unwrap()
}

fn centre(stage: &Stage) -> Vec<DVec2> {
    let Rig::Curve(r) = stage.puppets()[0].rig() else {
        panic!("a curve puppet")
    };
    r.curve().pose().to_vec()
}

fn rest_centre(stage: &Stage) -> Vec<DVec2> {
    let Rig::Curve(r) = stage.puppets()[0].rig() else {
        panic!("a curve puppet")
    };
    r.curve().rest().to_vec()
}

fn contacts(source: &str, list: &[(u32, Phase, DVec2)]) -> Change {
    Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new(source),
            time: 0.0,
            contacts: list
                .iter()
                .map(|&(id, phase, at)| Contact::new(id, phase, at))
                .collect(),
        },
    }
}

fn touch(stage: &mut Stage, source: &str, phase: Phase, at: DVec2) {
    stage
        .apply_change(&contacts(source, &[(1, phase, at)]))
        .unwrap();
    stage.solve();
}

/// Points that moved from where they were (beyond rounding).
fn moved(before: &[DVec2], after: &[DVec2]) -> Vec<usize> {
    (0..before.len())
        .filter(|&i| before[i].distance(after[i]) > 1e-9)
        .collect()
}

fn segment_stretch(rest: &[DVec2], pose: &[DVec2]) -> f64 {
    rest.windows(2)
        .zip(pose.windows(2))
        .map(|(r, p)| (p[0].distance(p[1]) / r[0].distance(r[1]) - 1.0).abs())
        .fold(0.0, f64::max)
}

#[test]
fn a_curve_puppet_is_a_ribbon_along_its_evenly_resampled_centre_line() {
    let stage = Stage::from_config(&rope("")).unwrap();
    let p = &stage.puppets()[0];
    let rest = rest_centre(&stage);
    assert_eq!(rest.len(), 101, "400 long every 4");
    for w in rest.windows(2) {
        assert!((w[0].distance(w[1]) - 4.0).abs() < 1e-6);
    }
    // The bounding box's centre is at `at`.
    let (lo, hi) = p.mesh.vertices().iter().fold(
        (DVec2::splat(f64::MAX), DVec2::splat(f64::MIN)),
        |(lo, hi), v| (lo.min(*v), hi.max(*v)),
    );
    assert!(((lo + hi) / 2.0 - DVec2::new(640.0, 360.0)).length() < 1e-6);
    assert!((hi.y - lo.y - 10.0).abs() < 1e-3, "10 wide");
    assert_eq!(p.mesh.vertices().len(), 2 * rest.len());
    assert_eq!(p.mesh.triangles().len(), 2 * (rest.len() - 1));
    assert_eq!(
        p.picture,
        puppetry_stage::Picture::Stroke([0x2b, 0x2b, 0x2b])
    );
    assert_eq!(p.rig().kind(), "curve");
}

#[test]
fn an_svg_path_makes_the_same_kind_of_puppet_flipped_to_y_up() {
    let text = r##"
[stage]
width = 1280
height = 720
[[puppet]]
name = "wave"
at = [640, 360]
[puppet.curve]
svg = "M 0 0 C 50 -60 150 60 200 0 S 350 -60 400 0"
width = 8
colour = "#c03020"
"##;
    let config = StageConfig::parse("svg.toml", text, Path::new("/")).unwrap();
    let stage = Stage::from_config(&config).unwrap();
    let rest = rest_centre(&stage);
    let first = rest[0];
    let last = *rest.last().unwrap();
    assert!((last - first - DVec2::new(400.0, 0.0)).length() < 1e-6);
    // SVG's first hump goes up the page (y − in SVG), so up the stage.
    let hump = rest
        .iter()
        .min_by(|a, b| {
            (a.x - first.x - 50.0)
                .abs()
                .total_cmp(&(b.x - first.x - 50.0).abs())
        })
        .unwrap();
    assert!(hump.y > first.y + 10.0, "{hump} above {first}");
    let spacing = rest[0].distance(rest[1]);
    for w in rest.windows(2) {
        assert!((w[0].distance(w[1]) - spacing).abs() < 0.05 * spacing);
    }
    assert_eq!(
        stage.puppets()[0].picture,
        puppetry_stage::Picture::Stroke([0xc0, 0x30, 0x20])
    );
}

#[test]
fn a_drag_peels_the_curve_more_the_further_it_goes_spreading_the_stretch() {
    let mut stage = Stage::from_config(&rope("")).unwrap();
    let rest = centre(&stage);
    let grab = DVec2::new(640.0, 361.0);
    touch(&mut stage, "finger", Phase::Down, grab);
    let mut reach = Vec::new();
    for step in 1..=8 {
        touch(
            &mut stage,
            "finger",
            Phase::Move,
            grab + DVec2::new(0.0, 10.0 * step as f64),
        );
        let now = centre(&stage);
        let moving = moved(&rest, &now);
        reach.push(moving.len());
        // The moved points are one run around the grab; the ends stay put
        // until the region reaches them.
        assert!(moving.contains(&50), "the grabbed point moves");
        let (lo, hi) = (moving[0], *moving.last().unwrap());
        assert_eq!(moving.len(), hi - lo + 1, "one run: {moving:?}");
        // Within the peeled region the ends are held, so pulling across
        // must lengthen it: at least by √(1 + (1/rate)²) − 1 (20% at the
        // default rate 1.5) for a straight rope. The scale adjustment
        // spreads that evenly instead of stretching a few segments more.
        let least = (1.0 + 1.0 / (1.5f64 * 1.5)).sqrt() - 1.0;
        let stretch = segment_stretch(&rest, &now);
        assert!(stretch < least * 1.15, "step {step}: stretch {stretch}");
        // The grabbed point follows the finger (less the grip's offset of
        // 1 across the stroke).
        let finger = grab + DVec2::new(0.0, 10.0 * step as f64);
        assert!((now[50].distance(finger) - 1.0).abs() < 0.5, "{}", now[50]);
    }
    assert!(
        reach.windows(2).all(|w| w[1] >= w[0]),
        "the region grows monotonically: {reach:?}"
    );
    assert!(reach[0] < reach[7], "and does grow: {reach:?}");
    assert!(reach[0] < 101 && reach[7] > 20, "{reach:?}");
    // Letting go leaves the curve where it is.
    let before = centre(&stage);
    touch(
        &mut stage,
        "finger",
        Phase::Up,
        grab + DVec2::new(0.0, 80.0),
    );
    assert_eq!(centre(&stage), before);
}

#[test]
fn a_pin_bounds_the_peel() {
    let mut stage = Stage::from_config(&rope("")).unwrap();
    let rest = centre(&stage);
    // A pushpin at point 60 (x = 480 + 240 = 680 on the stage).
    stage
        .pin(Owner::Source("director".into()), DVec2::new(680.0, 360.0))
        .unwrap();
    stage.solve();
    let grab = DVec2::new(640.0, 360.0);
    touch(&mut stage, "finger", Phase::Down, grab);
    for step in 1..=10 {
        touch(
            &mut stage,
            "finger",
            Phase::Move,
            grab + DVec2::new(0.0, 15.0 * step as f64),
        );
    }
    let now = centre(&stage);
    let moving = moved(&rest, &now);
    assert!(moving.contains(&50) && moving.contains(&20), "{moving:?}");
    assert!(
        moving.iter().all(|&i| i < 60),
        "nothing beyond the pin moves: {moving:?}"
    );
    assert!(now[60].distance(rest[60]) < 1e-6);
}

#[test]
fn two_performers_pull_both_ends() {
    let mut stage = Stage::from_config(&rope("")).unwrap();
    let rest = centre(&stage);
    let (left, right) = (rest[0] + DVec2::X, rest[100] - DVec2::X);
    touch(&mut stage, "ana", Phase::Down, left);
    touch(&mut stage, "ben", Phase::Down, right);
    for step in 1..=10 {
        let lift = DVec2::new(0.0, 12.0 * step as f64);
        stage
            .apply_change(&contacts("ana", &[(1, Phase::Move, left + lift)]))
            .unwrap();
        stage
            .apply_change(&contacts("ben", &[(1, Phase::Move, right + lift)]))
            .unwrap();
        stage.solve();
    }
    let now = centre(&stage);
    let lift = DVec2::new(0.0, 120.0);
    assert!(now[0].distance(rest[0] + lift) < 1.5, "{}", now[0]);
    assert!(now[100].distance(rest[100] + lift) < 1.5, "{}", now[100]);
    assert!(segment_stretch(&rest, &now) < 0.01);
    assert_eq!(stage.puppets()[0].handles().len(), 2);
}

#[test]
fn reset_and_undo_put_the_curve_back() {
    let mut stage = Stage::from_config(&rope("")).unwrap();
    let rest = centre(&stage);
    let grab = DVec2::new(640.0, 360.0);
    touch(&mut stage, "finger", Phase::Down, grab);
    touch(
        &mut stage,
        "finger",
        Phase::Move,
        grab + DVec2::new(30.0, 60.0),
    );
    touch(
        &mut stage,
        "finger",
        Phase::Up,
        grab + DVec2::new(30.0, 60.0),
    );
    let bent = centre(&stage);
    assert!(!moved(&rest, &bent).is_empty());
    for change in stage.reset(0).unwrap() {
        stage.apply_change(&change).unwrap();
    }
    stage.solve();
    assert_eq!(centre(&stage), rest, "reset puts the rest curve back");
    let ribbon = stage.puppets()[0].pose();
    let mesh = stage.puppets()[0].mesh.vertices();
    assert!(
        ribbon.iter().zip(mesh).all(|(a, b)| a.distance(*b) < 1e-9),
        "and its ribbon"
    );
    let undo = stage.undo(0).unwrap().expect("the reset can be undone");
    stage.apply_change(&undo).unwrap();
    stage.solve();
    assert_eq!(centre(&stage), bent, "undo puts the bend back");
    // A drag goes on from the pose undo left.
    touch(&mut stage, "finger", Phase::Down, bent[50]);
    touch(
        &mut stage,
        "finger",
        Phase::Move,
        bent[50] + DVec2::new(0.0, 5.0),
    );
    assert!(centre(&stage)[50].distance(bent[50] + DVec2::new(0.0, 5.0)) < 0.5);
}

#[test]
fn a_curve_frame_does_not_allocate() {
    let config = rope("");
    let stage = Stage::from_config(&config).unwrap();
    let p = &stage.puppets()[0];
    let grab = DVec2::new(640.0, 360.0);
    let anchor = p.hit(grab).expect("on the rope");
    let mut rig = Rig::from_config(
        &p.mesh,
        &p.mesh,
        grab,
        1.0,
        None,
        None,
        config.puppets[0].curve.as_ref(),
    )
    .unwrap();
    let mut handles = [Handle {
        id: 1,
        owner: Owner::Source("finger".into()),
        kind: HandleKind::Contact,
        grip: Grip::Point(anchor),
        target: grab,
        offset: DVec2::ZERO,
    }];
    rig.solve(&handles, true).unwrap();
    // Far enough that the peel reaches both ends: from here on the free
    // points do not change, so nothing recompiles.
    handles[0].target = grab + DVec2::new(0.0, 200.0);
    rig.solve(&handles, false).unwrap();
    alloc::start();
    for k in 0..30 {
        let a = k as f64 * 0.2;
        handles[0].target = grab + DVec2::new(0.0, 150.0) + DVec2::new(a.cos(), a.sin()) * 20.0;
        rig.solve(&handles, false).unwrap();
    }
    assert_eq!(alloc::stop(), 0, "the curve's frames allocated");
}

#[test]
fn bad_curves_are_named_by_file_and_field() {
    let cases: [(&str, &str, &str); 9] = [
        (
            "points = [[0, 0], [1, 1]]",
            "curve.points",
            "at least 3 points",
        ),
        (
            "points = [[0, 0], [10, 0], [10, 0], [20, 5]]",
            "curve.points",
            "repeats",
        ),
        (
            "points = [[0, 0], [100, 0], [100, 100], [50, -50]]",
            "curve.points",
            "intersects itself",
        ),
        (
            "points = [[0, 0], [10, 0], [nan, 5]]",
            "curve.points",
            "finite",
        ),
        ("svg = \"M 0 0 L 10 0 L 20 20 Z\"", "curve.svg", "closed"),
        ("svg = \"M 0 0 Q 5\"", "curve.svg", "expected a number"),
        (
            "points = [[0, 0], [10, 0], [20, 0]]\nwidth = -1",
            "curve.width",
            "positive",
        ),
        (
            "points = [[0, 0], [10, 0], [20, 0]]\ncolour = \"red\"",
            "curve.colour",
            "#RRGGBB",
        ),
        (
            "points = [[0, 0], [100, 0], [100, 4], [0, 4]]\nwidth = 30",
            "curve.width",
            "too wide",
        ),
    ];
    for (curve, field, says) in cases {
        let text = format!(
            "[stage]\nwidth = 100\nheight = 100\n[[puppet]]\nname = \"c\"\nat = [50, 50]\n[puppet.curve]\n{curve}\n"
        );
        let message = match StageConfig::parse("bad-curve.toml", &text, Path::new("/")) {
            Err(e) => e.to_string(),
            Ok(config) => match Stage::from_config(&config) {
                Err(e @ StageError::Rig { .. }) => e.to_string(),
                Err(other) => panic!("{curve}: {other}"),
                Ok(_) => panic!("{curve}: accepted"),
            },
        };
        assert!(
            message.contains("bad-curve.toml") && message.contains(field) && message.contains(says),
            "{curve}: {message}"
        );
    }
    // A curve puppet has no mesh; a mesh puppet needs one.
    let both = "[stage]\nwidth = 100\nheight = 100\n[[puppet]]\nname = \"c\"\nmesh = \"m.json\"\nat = [50, 50]\n[puppet.curve]\npoints = [[0, 0], [10, 0], [20, 0]]\n";
    let e = StageConfig::parse("bad-curve.toml", both, Path::new("/")).unwrap_err();
    assert!(e.to_string().contains("puppet[0].mesh"), "{e}");
    let neither = "[stage]\nwidth = 100\nheight = 100\n[[puppet]]\nname = \"c\"\nimage = \"c.png\"\nat = [50, 50]\n";
    let e = StageConfig::parse("bad-curve.toml", neither, Path::new("/")).unwrap_err();
    assert!(e.to_string().contains("puppet[0].mesh"), "{e}");
}
