//! Linux input devices end to end, without hardware: evemu captures stand in
//! for device nodes in a temporary device folder, so the daemon's real
//! discovery, matching, reader, state read-back after `SYN_DROPPED`, and
//! inotify hot-plug run against them. Touch tables, pen tablets and two mice
//! at once drive the demo puppet; the handles and frames that come out are
//! checked. Also `puppetry devices` and `puppetry record` on such captures.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::common::daemon::*;
use glam::DVec2;
use puppetry_input::device::{Capabilities, DeviceInfo, DeviceKind, DeviceMatch};
use puppetry_input::evdev::*;
use puppetry_input::evemu::{EvemuFile, InputId, write_event};
use puppetry_input::mouse::{BTN_LEFT, BTN_RIGHT, REL_WHEEL, REL_WHEEL_HI_RES, REL_X, REL_Y};
use serde_json::{Value, json};

const TABLE_RANGE: i32 = 4095;

fn axis(min: i32, max: i32, resolution: i32) -> AbsInfo {
    AbsInfo {
        min,
        max,
        fuzz: 0,
        flat: 0,
        resolution,
    }
}

fn info(name: &str, capabilities: Capabilities) -> DeviceInfo {
    DeviceInfo {
        path: PathBuf::new(),
        name: name.to_string(),
        phys: None,
        uniq: None,
        id: InputId {
            bus: 3,
            vendor: 0x1234,
            product: 0x5678,
            version: 1,
        },
        kind: DeviceKind::of(&capabilities),
        capabilities,
        capture: true,
    }
}

/// A two-slot protocol B touch table, 0..4095 on both axes.
fn table() -> DeviceInfo {
    let range = axis(0, TABLE_RANGE, 0);
    info(
        "Synthetic Table",
        Capabilities {
            keys: BTreeSet::from([BTN_TOUCH]),
            relative: BTreeSet::new(),
            absolute: [
                (ABS_X, range),
                (ABS_Y, range),
                (ABS_MT_SLOT, axis(0, 1, 0)),
                (ABS_MT_POSITION_X, range),
                (ABS_MT_POSITION_Y, range),
                (ABS_MT_TRACKING_ID, axis(0, 65535, 0)),
            ]
            .into(),
            direct: true,
        },
    )
}

/// A Wacom-style pen tablet: 0..20000, pressure 0..2047, tilt ±64 degrees
/// at 57 units per radian.
fn tablet() -> DeviceInfo {
    info(
        "Synthetic Pen",
        Capabilities {
            keys: BTreeSet::from([BTN_TOOL_PEN, BTN_TOUCH]),
            relative: BTreeSet::new(),
            absolute: [
                (ABS_X, axis(0, 20000, 100)),
                (ABS_Y, axis(0, 20000, 100)),
                (ABS_PRESSURE, axis(0, 2047, 0)),
                (ABS_TILT_X, axis(-64, 63, 57)),
                (ABS_TILT_Y, axis(-64, 63, 57)),
            ]
            .into(),
            direct: false,
        },
    )
}

fn mouse() -> DeviceInfo {
    info(
        "Synthetic Mouse",
        Capabilities {
            keys: BTreeSet::from([BTN_LEFT, BTN_RIGHT]),
            relative: BTreeSet::from([REL_X, REL_Y, REL_WHEEL, REL_WHEEL_HI_RES]),
            absolute: Default::default(),
            direct: false,
        },
    )
}

/// An evemu capture of `device` doing `events` (seconds, type, code, value).
fn capture(device: &DeviceInfo, events: &[(f64, u16, u16, i32)]) -> Vec<u8> {
    let mut out = Vec::new();
    device.evemu_header().write(&mut out).unwrap();
    for &(time, ev_type, code, value) in events {
        write_event(&mut out, &InputEvent::new(time, ev_type, code, value)).unwrap();
    }
    out
}

/// Puts a capture into the device folder the way udev adds a node: whole,
/// in one step (written aside, then renamed in).
fn plug(dir: &Path, node: &str, bytes: &[u8]) -> PathBuf {
    let aside = dir.join(format!(".{node}.partial"));
    std::fs::write(&aside, bytes).unwrap();
    let path = dir.join(node);
    std::fs::rename(&aside, &path).unwrap();
    path
}

/// Device units of the table for a stage point (the default calibration
/// fits the table's range to the 1280×720 stage, y flipped).
fn table_units(p: DVec2) -> (i32, i32) {
    let r = f64::from(TABLE_RANGE);
    (
        (p.x / 1280.0 * r).round() as i32,
        ((1.0 - p.y / 720.0) * r).round() as i32,
    )
}

/// The stage point of table units (the inverse of [`table_units`]).
fn table_stage((x, y): (i32, i32)) -> DVec2 {
    let r = f64::from(TABLE_RANGE);
    DVec2::new(f64::from(x) / r * 1280.0, (1.0 - f64::from(y) / r) * 720.0)
}

/// Contact handles of a "handles" message: (owner, at).
fn contact_handles(m: &Value) -> Vec<(String, DVec2)> {
    m["handles"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|h| h["kind"] == "contact")
        .map(|h| {
            (
                h["owner"].as_str().unwrap().to_string(),
                DVec2::new(h["at"][0].as_f64().unwrap(), h["at"][1].as_f64().unwrap()),
            )
        })
        .collect()
}

/// Reads until a "handles" message whose contact handles satisfy `done`.
async fn until_handles(
    ws: &mut Client,
    mut done: impl FnMut(&[(String, DVec2)]) -> bool,
) -> Vec<(String, DVec2)> {
    loop {
        let m = next_text(ws).await;
        if m["type"] == "handles" {
            let handles = contact_handles(&m);
            if done(&handles) {
                return handles;
            }
        }
    }
}

/// Reads frames until `point` (see [`follow`]) is within `tolerance` of `to`.
async fn until_at(ws: &mut Client, point: &impl Fn(&Frame) -> DVec2, to: DVec2) {
    // Frames carry f32 vertices.
    frame_until(ws, |f| f.puppet == 0 && point(f).distance(to) < 1e-2).await;
}

const VIEWER: fn() -> Value = || json!({"type": "hello", "role": "viewer"});

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_table_unplugged_mid_touch_is_lifted_and_comes_back_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let extra = format!(
        "[[input]]\nkind = \"touch\"\nname = \"table\"\ndir = \"{}\"\ndevice = {{ name = \"Synthetic Table\" }}\n",
        dir.path().display()
    );
    let running = daemon(&extra).await;
    let (mut viewer, stage) = connect(&running, VIEWER()).await;
    let grab = hand(&placed_mesh(&stage));
    let (x, y) = table_units(grab);
    let (_, y_up) = table_units(grab + DVec2::new(0.0, 40.0));
    let drag_end = table_stage((x, y_up));
    // A finger lands on the hand and drags it up, and stays down.
    let touch = capture(
        &table(),
        &[
            (0.0, EV_ABS, ABS_MT_SLOT, 0),
            (0.0, EV_ABS, ABS_MT_TRACKING_ID, 7),
            (0.0, EV_ABS, ABS_MT_POSITION_X, x),
            (0.0, EV_ABS, ABS_MT_POSITION_Y, y),
            (0.0, EV_KEY, BTN_TOUCH, 1),
            (0.0, EV_SYN, SYN_REPORT, 0),
            (0.05, EV_ABS, ABS_MT_POSITION_Y, y_up),
            (0.05, EV_SYN, SYN_REPORT, 0),
        ],
    );
    let landing = table_stage((x, y));
    assert!(landing.distance(grab) < 0.5, "{landing} vs {grab}");
    // A handles message names the contact where it is when the set changes:
    // where it landed, or already dragged if the stage took the landing and
    // the drag in one batch (a loaded machine may hold it back that long).
    let where_it_is = |at: DVec2| at.distance(landing) < 1e-6 || at.distance(drag_end) < 1e-6;
    let node = plug(dir.path(), "event7", &touch);
    let first = until_handles(&mut viewer, |h| h.len() == 1).await;
    assert_eq!(first[0].0, "table");
    assert!(where_it_is(first[0].1), "{first:?} vs {landing}");
    // The drag carries the touched point of the puppet up with it.
    let mesh = placed_mesh(&stage);
    let dragged = follow(&mesh, landing);
    until_at(&mut viewer, &dragged, drag_end).await;
    // Unplugged with the finger down: its contact is lifted.
    std::fs::remove_file(&node).unwrap();
    until_handles(&mut viewer, |h| h.is_empty()).await;
    // Back under another node number: the same source and calibration.
    plug(dir.path(), "event12", &touch);
    let again = until_handles(&mut viewer, |h| h.len() == 1).await;
    assert_eq!(again[0].0, "table");
    assert!(where_it_is(again[0].1), "same calibration: {again:?}");
    // The puppet went back to rest when the finger was lifted, so the same
    // touch grabs the same point of it and drags it to the same place.
    until_at(&mut viewer, &dragged, drag_end).await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dropped_events_are_recovered_from_the_device_state() {
    // The kernel's buffer overflows twice: once while a finger lands, once
    // while it lifts. The reader misses both reports entirely and must
    // read the slots back (EVIOCGMTSLOTS) to see the landing and the lift;
    // nothing after the second drop would tell it otherwise.
    let dir = tempfile::tempdir().unwrap();
    let extra = format!(
        "[[input]]\nkind = \"touch\"\nname = \"table\"\ndir = \"{}\"\n",
        dir.path().display()
    );
    let running = daemon(&extra).await;
    let (mut viewer, stage) = connect(&running, VIEWER()).await;
    let grab = hand(&placed_mesh(&stage));
    let (x, y) = table_units(grab);
    let touch = capture(
        &table(),
        &[
            (0.0, EV_SYN, SYN_DROPPED, 0),
            (0.0, EV_ABS, ABS_MT_SLOT, 0),
            (0.0, EV_ABS, ABS_MT_TRACKING_ID, 3),
            (0.0, EV_ABS, ABS_MT_POSITION_X, x),
            (0.0, EV_ABS, ABS_MT_POSITION_Y, y),
            (0.0, EV_KEY, BTN_TOUCH, 1),
            (0.0, EV_SYN, SYN_REPORT, 0),
            // Far enough apart that the stage publishes the landing before
            // the lift even on a loaded machine.
            (4.0, EV_SYN, SYN_DROPPED, 0),
            (4.0, EV_ABS, ABS_MT_TRACKING_ID, -1),
            (4.0, EV_KEY, BTN_TOUCH, 0),
            (4.0, EV_SYN, SYN_REPORT, 0),
        ],
    );
    plug(dir.path(), "event0", &touch);
    let landed = until_handles(&mut viewer, |h| h.len() == 1).await;
    assert_eq!(landed[0].0, "table");
    assert!(landed[0].1.distance(grab) < 0.5);
    until_handles(&mut viewer, |h| h.is_empty()).await;
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pen_grabs_with_its_tip_and_lets_go_when_it_leaves() {
    let dir = tempfile::tempdir().unwrap();
    let extra = format!(
        "[[input]]\nkind = \"pen\"\nname = \"pen\"\ndir = \"{}\"\n",
        dir.path().display()
    );
    let running = daemon(&extra).await;
    let (mut viewer, stage) = connect(&running, VIEWER()).await;
    let grab = hand(&placed_mesh(&stage));
    let units = |p: DVec2| {
        (
            (p.x / 1280.0 * 20000.0).round() as i32,
            ((1.0 - p.y / 720.0) * 20000.0).round() as i32,
        )
    };
    let (x, y) = units(grab);
    let (x2, y2) = units(grab + DVec2::new(-30.0, 30.0));
    let tip_end = DVec2::new(
        f64::from(x2) / 20000.0 * 1280.0,
        (1.0 - f64::from(y2) / 20000.0) * 720.0,
    );
    let landing = DVec2::new(
        f64::from(x) / 20000.0 * 1280.0,
        (1.0 - f64::from(y) / 20000.0) * 720.0,
    );
    assert!(landing.distance(grab) < 0.5);
    let strokes = pen_stroke(x, y, x2, y2);
    let path = plug(dir.path(), "event4", &capture(&tablet(), &strokes));
    let held = until_handles(&mut viewer, |h| h.len() == 1).await;
    assert_eq!(held[0].0, "pen");
    // Where the tip landed, or already at the end of the stroke if the
    // stage took both in one batch.
    assert!(
        held[0].1.distance(landing) < 1e-6 || held[0].1.distance(tip_end) < 1e-6,
        "{held:?}"
    );
    let tip = follow(&placed_mesh(&stage), landing);
    until_at(&mut viewer, &tip, tip_end).await;
    // The pen leaves proximity; its tip-up was never sent.
    until_handles(&mut viewer, |h| h.is_empty()).await;
    running.shutdown().await;

    // Pressure and tilt travel on the contacts, from the same capture.
    let file = EvemuFile::read(&path).unwrap();
    let calibration = file.fit_calibration(DVec2::new(1280.0, 720.0)).unwrap();
    let mut decoder = file.decoder("pen".into(), calibration).unwrap();
    let frames: Vec<_> = file
        .events
        .iter()
        .filter_map(|e| decoder.push(*e))
        .collect();
    let down = &frames[0].contacts[0];
    assert_eq!(down.phase, puppetry_input::Phase::Down);
    assert!((down.pressure.unwrap() - 900.0 / 2047.0).abs() < 1e-12);
    // Tilted 20 units right and 10 towards the user (device y is down):
    // the lean keeps its size and turns with the calibration, which
    // squeezes the square tablet onto the wide stage.
    let lean = DVec2::new(20.0, 10.0) / 57.0;
    let towards = DVec2::new(lean.x * 1280.0, -lean.y * 720.0).normalize() * lean.length();
    let tilt = down.tilt.unwrap();
    assert!(tilt.distance(towards) < 1e-9, "{tilt:?} vs {towards:?}");
    let last = frames.last().unwrap();
    assert_eq!(last.contacts[0].phase, puppetry_input::Phase::Up);
}

/// Hover in, tip down with pressure and tilt, drag, then out of proximity
/// without the tip-up (as when a pen is snatched away quickly).
fn pen_stroke(x: i32, y: i32, x2: i32, y2: i32) -> Vec<(f64, u16, u16, i32)> {
    vec![
        (0.0, EV_KEY, BTN_TOOL_PEN, 1),
        (0.0, EV_ABS, ABS_X, x),
        (0.0, EV_ABS, ABS_Y, y),
        (0.0, EV_SYN, SYN_REPORT, 0),
        (0.02, EV_KEY, BTN_TOUCH, 1),
        (0.02, EV_ABS, ABS_PRESSURE, 900),
        (0.02, EV_ABS, ABS_TILT_X, 20),
        (0.02, EV_ABS, ABS_TILT_Y, 10),
        (0.02, EV_SYN, SYN_REPORT, 0),
        (0.04, EV_ABS, ABS_X, x2),
        (0.04, EV_ABS, ABS_Y, y2),
        (0.04, EV_SYN, SYN_REPORT, 0),
        (4.0, EV_KEY, BTN_TOOL_PEN, 0),
        (4.0, EV_SYN, SYN_REPORT, 0),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_mice_each_move_and_rotate_a_pair_on_the_puppet() {
    // Two identical mice, told apart by their stable by-path links (as udev
    // makes them from the USB port), each holding a pair of points: one
    // drags its pair, the other turns its pair with the wheel.
    let dir = tempfile::tempdir().unwrap();
    let by_path = dir.path().join("by-path");
    std::fs::create_dir(&by_path).unwrap();
    let extra = format!(
        r#"[[input]]
kind = "mouse"
name = "left"
dir = "{dir}"
device = {{ path = "{by_path}/usb-0:1-event-mouse" }}
pair_spacing = 40
start = [{lx}, {ly}]

[[input]]
kind = "mouse"
name = "right"
dir = "{dir}"
device = {{ path = "{by_path}/usb-0:2-event-mouse" }}
pair_spacing = 40
rotate_step_deg = 15
start = [{rx}, {ry}]
"#,
        dir = dir.path().display(),
        by_path = by_path.display(),
        lx = 610.0,
        ly = 360.0,
        rx = 0.0,
        ry = 0.0,
    );
    // The right mouse's place on the puppet is found from the stage message,
    // so it starts in the corner and moves there (counts are stage units).
    let running = daemon(&extra).await;
    let (mut viewer, stage) = connect(&running, VIEWER()).await;
    let mesh = placed_mesh(&stage);
    let locator = puppetry_mesh::Locator::new(&mesh);
    let left_start = DVec2::new(610.0, 360.0);
    // Where a pair 40 apart lies wholly on the puppet, level or at 30°,
    // with room to spare for what the other mouse does to the puppet.
    let roomy = |p: DVec2| {
        [0f64, 30f64.to_radians()].iter().all(|a| {
            let half = DVec2::new(a.cos(), a.sin()) * 35.0;
            locator.locate(&mesh, p - half).is_some() && locator.locate(&mesh, p + half).is_some()
        })
    };
    assert!(roomy(left_start), "the left mouse starts on the puppet");
    let on_hand = (0..40)
        .flat_map(|i| {
            (0..40).map(move |j| DVec2::new(640.0 + 8.0 * i as f64, 100.0 + 12.0 * j as f64))
        })
        .filter(|p| p.distance(left_start) > 120.0 && roomy(*p))
        .max_by(|a, b| a.y.total_cmp(&b.y))
        .expect("a second place for a pair on the puppet");
    // Each mouse lands, then moves 2 s later: the two are separate sources
    // and nothing orders them, so both pairs must have landed on the puppet
    // at rest before either changes it, even when one opens late.
    let left = capture(
        &mouse(),
        &[
            (0.0, EV_KEY, BTN_LEFT, 1),
            (0.0, EV_SYN, SYN_REPORT, 0),
            (2.0, EV_REL, REL_X, -25),
            (2.0, EV_REL, REL_Y, -15),
            (2.0, EV_SYN, SYN_REPORT, 0),
            (2.05, EV_REL, REL_X, -25),
            (2.05, EV_REL, REL_Y, -15),
            (2.05, EV_SYN, SYN_REPORT, 0),
        ],
    );
    let (dx, dy) = (on_hand.x.round() as i32, -(on_hand.y.round() as i32));
    let right = capture(
        &mouse(),
        &[
            // Over to the hand (from the stage's corner: y counts go down).
            (0.0, EV_REL, REL_X, dx),
            (0.0, EV_REL, REL_Y, dy),
            (0.0, EV_KEY, BTN_LEFT, 1),
            (0.0, EV_SYN, SYN_REPORT, 0),
            (2.0, EV_REL, REL_WHEEL, 1),
            (2.0, EV_REL, REL_WHEEL_HI_RES, 120),
            (2.0, EV_SYN, SYN_REPORT, 0),
            (2.05, EV_REL, REL_WHEEL, 1),
            (2.05, EV_REL, REL_WHEEL_HI_RES, 120),
            (2.05, EV_SYN, SYN_REPORT, 0),
        ],
    );
    let left_node = plug(dir.path(), "event1", &left);
    let right_node = plug(dir.path(), "event2", &right);
    std::os::unix::fs::symlink("../event1", by_path.join("usb-0:1-event-mouse")).unwrap();
    std::os::unix::fs::symlink("../event2", by_path.join("usb-0:2-event-mouse")).unwrap();

    let left_end = left_start + DVec2::new(-50.0, 30.0);
    let right_at = DVec2::new(f64::from(dx), -f64::from(dy));
    let turned = 30f64.to_radians();
    let half = |angle: f64| DVec2::new(angle.cos(), angle.sin()) * 20.0;
    // Each pair lands level, around its cursor.
    let landed = [
        ("left", left_start - half(0.0)),
        ("left", left_start + half(0.0)),
        ("right", right_at - half(0.0)),
        ("right", right_at + half(0.0)),
    ];
    // Each owner's points as they were in the first message naming it.
    let mut first_seen: Vec<(String, DVec2)> = Vec::new();
    until_handles(&mut viewer, |h| {
        for owner in ["left", "right"] {
            if !first_seen.iter().any(|(o, _)| o == owner) {
                first_seen.extend(h.iter().filter(|(o, _)| o == owner).cloned());
            }
        }
        first_seen.len() == 4
    })
    .await;
    for (owner, at) in &landed {
        assert!(
            first_seen
                .iter()
                .any(|(o, p)| o == owner && p.distance(*at) < 1e-6),
            "{owner} landed at {at}: {first_seen:?}"
        );
    }
    // Then the left pair is dragged and the right pair turned 30° about its
    // cursor; the grabbed points of the puppet go with them.
    let points: Vec<_> = landed.iter().map(|(_, at)| follow(&mesh, *at)).collect();
    let ends = [
        left_end - half(0.0),
        left_end + half(0.0),
        right_at - half(turned),
        right_at + half(turned),
    ];
    frame_until(&mut viewer, |f| {
        points
            .iter()
            .zip(&ends)
            .all(|(point, end)| point(f).distance(*end) < 1e-2)
    })
    .await;
    // Both cursors are streamed for the renderer; a viewer joining now is
    // told where they are.
    let (mut late, _) = connect(&running, VIEWER()).await;
    loop {
        let m = next_text(&mut late).await;
        if m["type"] == "cursors" {
            let cursors = m["cursors"].as_array().unwrap();
            let at = |name: &str| {
                cursors
                    .iter()
                    .find(|c| c["source"] == name)
                    .map(|c| DVec2::new(c["at"][0].as_f64().unwrap(), c["at"][1].as_f64().unwrap()))
            };
            if at("left").is_some_and(|p| p.distance(left_end) < 1e-9)
                && at("right").is_some_and(|p| p.distance(right_at) < 1e-9)
            {
                let right = cursors.iter().find(|c| c["source"] == "right").unwrap();
                assert!((right["angle"].as_f64().unwrap() - turned).abs() < 1e-9);
                assert_eq!(right["holding"], true);
                break;
            }
        }
    }
    // Both mice unplugged (udev removes the nodes and their links): all four
    // points let go, the cursors go.
    for node in [left_node, right_node] {
        std::fs::remove_file(&node).unwrap();
    }
    for link in ["usb-0:1-event-mouse", "usb-0:2-event-mouse"] {
        std::fs::remove_file(by_path.join(link)).unwrap();
    }
    // A mouse's lift and its cursor leaving reach the stage by different
    // paths, in either order: wait until the newest of each is empty.
    let (mut holding, mut pointing) = (true, true);
    while holding || pointing {
        let m = next_text(&mut viewer).await;
        if m["type"] == "handles" {
            holding = !contact_handles(&m).is_empty();
        } else if m["type"] == "cursors" {
            pointing = !m["cursors"].as_array().unwrap().is_empty();
        }
    }
    running.shutdown().await;
}

#[test]
fn entries_match_devices_by_name_phys_and_ids() {
    let mut a = mouse();
    a.phys = Some("usb-0000:00:14.0-1/input0".into());
    let mut b = mouse();
    b.phys = Some("usb-0000:00:14.0-2/input0".into());
    let wanted = DeviceMatch {
        phys: Some("usb-0000:00:14.0-2/input0".into()),
        ..Default::default()
    };
    assert!(!wanted.matches(&a));
    assert!(wanted.matches(&b));
    let by_ids = DeviceMatch {
        name: Some("Synthetic Mouse".into()),
        vendor: Some(0x1234),
        product: Some(0x5678),
        ..Default::default()
    };
    assert!(by_ids.matches(&a) && by_ids.matches(&b));
    let other_product = DeviceMatch {
        product: Some(0x9999),
        ..Default::default()
    };
    assert!(!other_product.matches(&a));
    assert_eq!(DeviceKind::of(&table().capabilities), DeviceKind::Touch);
    assert_eq!(DeviceKind::of(&tablet().capabilities), DeviceKind::Pen);
    assert_eq!(DeviceKind::of(&mouse().capabilities), DeviceKind::Mouse);
}

#[test]
fn a_written_capture_reads_back_as_the_same_device_and_events() {
    let dir = tempfile::tempdir().unwrap();
    for device in [table(), tablet(), mouse()] {
        let events = pen_stroke(1, 2, 3, 4);
        let path = plug(dir.path(), "event3", &capture(&device, &events));
        let read = puppetry_input::device::probe(&path).unwrap();
        assert_eq!(read.name, device.name);
        assert_eq!(read.id, device.id);
        assert_eq!(read.kind, device.kind);
        assert_eq!(read.capabilities, device.capabilities);
        let file = EvemuFile::read(&path).unwrap();
        let times: Vec<_> = file
            .events
            .iter()
            .map(|e| (e.time, e.code, e.value))
            .collect();
        let wanted: Vec<_> = events.iter().map(|e| (e.0, e.2, e.3)).collect();
        assert_eq!(times, wanted);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn record_captures_a_device_that_replay_then_plays() {
    // `puppetry record` on a capture standing in for a node: the file it
    // writes is an evemu capture with the device's header and events.
    let dir = tempfile::tempdir().unwrap();
    let source = plug(
        dir.path(),
        "event5",
        &capture(&tablet(), &pen_stroke(100, 200, 300, 400)),
    );
    let out = dir.path().join("recorded.event");
    let status = tokio::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .arg("record")
        .arg(&source)
        .arg("-o")
        .arg(&out)
        // The stroke lasts 4 s; the margin is for a loaded machine.
        .args(["--duration", "8"])
        .status()
        .await
        .unwrap();
    assert!(status.success());
    let original = EvemuFile::read(&source).unwrap();
    let recorded = EvemuFile::read(&out).unwrap();
    assert_eq!(recorded.device.name, original.device.name);
    assert_eq!(recorded.device.axes, original.device.axes);
    assert_eq!(recorded.events, original.events);
    // And replay takes it.
    puppetry_input::replay::ReplaySource::open(&out, DVec2::new(1280.0, 720.0)).unwrap();
}

#[test]
fn devices_lists_captures_with_axes_and_the_entries_that_take_them() {
    let dir = tempfile::tempdir().unwrap();
    plug(dir.path(), "event0", &capture(&table(), &[]));
    plug(dir.path(), "event1", &capture(&mouse(), &[]));
    std::fs::write(dir.path().join("event2"), "not a capture").unwrap();
    let config = dir.path().join("stage.toml");
    std::fs::write(
        &config,
        format!(
            "[stage]\nwidth = 100\nheight = 100\n\n[[input]]\nkind = \"mouse\"\nname = \"m\"\ndir = \"{d}\"\n\n[[input]]\nkind = \"pen\"\nname = \"p\"\ndir = \"{d}\"\n",
            d = dir.path().display()
        ),
    )
    .unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .args(["devices", "--dir"])
        .arg(dir.path())
        .arg("--config")
        .arg(&config)
        .output()
        .unwrap();
    assert!(output.status.success());
    let text = String::from_utf8(output.stdout).unwrap();
    assert!(
        text.contains("touch (direct)  \"Synthetic Table\""),
        "{text}"
    );
    assert!(text.contains("ABS_MT_POSITION_X  0 .. 4095"), "{text}");
    assert!(text.contains("mouse  \"Synthetic Mouse\""), "{text}");
    assert!(text.contains("used by input[0] \"m\""), "{text}");
    assert!(text.contains("event2: not readable"), "{text}");
    assert!(
        text.contains("input[1] \"p\" (pen, any device): no such device now"),
        "{text}"
    );
}

#[test]
fn fingers_already_down_when_a_table_is_opened_are_taken_up() {
    // What the reader does on open: the device's own state (EVIOCGMTSLOTS,
    // EVIOCGKEY) becomes contacts before any event arrives.
    let device = table();
    let calibration =
        fit_calibration(&device.capabilities.absolute, DVec2::new(1280.0, 720.0)).unwrap();
    let mut decoder =
        TouchDecoder::new("table".into(), &device.capabilities.absolute, calibration).unwrap();
    let state = DeviceState {
        keys: BTreeSet::from([BTN_TOUCH]),
        abs: [(ABS_MT_SLOT, 1)].into(),
        slots: vec![
            SlotState {
                slot: 0,
                tracking_id: -1,
                x: 0,
                y: 0,
                pressure: None,
            },
            SlotState {
                slot: 1,
                tracking_id: 40,
                x: 4095,
                y: 4095,
                pressure: None,
            },
        ],
    };
    let frame = decoder.restore(1.0, &state).expect("a finger is down");
    assert_eq!(frame.contacts.len(), 1);
    assert_eq!(frame.contacts[0].phase, puppetry_input::Phase::Down);
    assert!(frame.contacts[0].position.distance(DVec2::new(1280.0, 0.0)) < 1e-9);
    // The slot is current, so a move that names no slot moves that finger.
    let moved = [
        InputEvent::new(1.1, EV_ABS, ABS_MT_POSITION_X, 0),
        InputEvent::new(1.1, EV_SYN, SYN_REPORT, 0),
    ]
    .into_iter()
    .filter_map(|e| decoder.push(e))
    .next()
    .unwrap();
    assert_eq!(moved.contacts[0].id, frame.contacts[0].id);
    assert!(moved.contacts[0].position.distance(DVec2::new(0.0, 0.0)) < 1e-9);
}

#[test]
fn four_taps_on_the_marks_calibrate_a_skewed_table() {
    // A table mounted slightly rotated and offset under the projection: the
    // performer taps the four marks; the calibration made from the capture
    // takes each tap to its mark, and stage points in between follow.
    let dir = tempfile::tempdir().unwrap();
    let stage_size = DVec2::new(1280.0, 720.0);
    let marks = puppetry_input::calibrate::marks(stage_size, 0.1);
    // Stage to device: 3 units per stage unit, turned 3°, shifted; y down.
    let turn = 3f64.to_radians();
    let to_device = |p: DVec2| {
        let q = DVec2::new(p.x, stage_size.y - p.y) * 3.0;
        let r = DVec2::new(
            q.x * turn.cos() - q.y * turn.sin(),
            q.x * turn.sin() + q.y * turn.cos(),
        );
        (r + DVec2::new(150.0, 40.0)).round()
    };
    let mut events = Vec::new();
    for (i, mark) in marks.iter().enumerate() {
        let at = to_device(*mark);
        let t = i as f64;
        events.extend([
            (t, EV_ABS, ABS_MT_SLOT, 0),
            (t, EV_ABS, ABS_MT_TRACKING_ID, i as i32 + 1),
            (t, EV_ABS, ABS_MT_POSITION_X, at.x as i32),
            (t, EV_ABS, ABS_MT_POSITION_Y, at.y as i32),
            (t, EV_SYN, SYN_REPORT, 0),
            (t + 0.5, EV_ABS, ABS_MT_TRACKING_ID, -1),
            (t + 0.5, EV_SYN, SYN_REPORT, 0),
        ]);
    }
    let taps = plug(dir.path(), "taps.event", &capture(&table(), &events));
    let config = dir.path().join("stage.toml");
    std::fs::write(&config, "[stage]\nwidth = 1280\nheight = 720\n").unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .arg("calibrate")
        .arg(&taps)
        .arg("--config")
        .arg(&config)
        .output()
        .unwrap();
    assert!(output.status.success(), "{output:?}");
    let line = String::from_utf8(output.stdout).unwrap();
    // The printed line is a stage-file input's calibration as it stands.
    let entry = format!("[stage]\nwidth = 1280\nheight = 720\n[[input]]\nkind = \"touch\"\n{line}");
    let parsed =
        puppetry_daemon::config::ShowConfig::parse("t.toml", &entry, Path::new("/")).unwrap();
    let puppetry_input::config::InputConfig::Touch(puppetry_input::config::EvdevInput {
        calibration: Some(spec),
        ..
    }) = &parsed.inputs[0]
    else {
        panic!("a touch input with a calibration: {line}");
    };
    let calibration = puppetry_input::Calibration::new(spec.clone()).unwrap();
    for mark in marks {
        let d = to_device(mark);
        assert!(calibration.map(d).distance(mark) < 1e-6, "{mark}");
    }
    // Between the marks the map is the table's (up to rounding of taps).
    let centre = stage_size / 2.0;
    assert!(calibration.map(to_device(centre)).distance(centre) < 1.0);

    // Fewer than four taps is refused, saying what to do.
    let three = plug(dir.path(), "three.event", &capture(&table(), &events[..21]));
    let err = puppetry_input::calibrate::from_capture(&three, stage_size, 0.1).unwrap_err();
    assert!(err.to_string().contains("3 touch(es) found"), "{err}");
}
