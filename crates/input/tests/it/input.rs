//! The input layer end to end: real evemu captures decode to balanced,
//! trackable contacts (also when events are dropped), synthetic event
//! sequences give exactly the expected frames, calibrations map where they
//! say, recordings round-trip, bad files are refused with their line, and
//! replay pacing follows the timestamps on tokio's paused clock.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::time::Duration;

use glam::DVec2;
use puppetry_input::evdev::*;
use puppetry_input::evemu::EvemuFile;
use puppetry_input::recording::{RecordingWriter, parse_recording, read_recording};
use puppetry_input::replay::{Pacing, ReplaySource, replay};
use puppetry_input::{Calibration, CalibrationSpec, Contact, ContactFrame, Phase, SourceId};
use tokio::sync::mpsc;
use tokio::time::Instant;

fn fixture(name: &str) -> PathBuf {
    puppetry_testkit::root()
        .join("../shared/fixtures/evemu")
        .join(name)
}

fn fixture_text(name: &str) -> String {
    std::fs::read_to_string(fixture(name)).expect("read fixture")
}

/// Maps device units onto identical stage numbers (no flip), so positions
/// in frames are the raw device values.
fn device_units(width: f64, height: f64) -> Calibration {
    Calibration::new(CalibrationSpec::Range {
        x: [0.0, width],
        y: [0.0, height],
        flip_y: false,
        stage_min: [0.0, 0.0],
        stage_max: [width, height],
    })
    .unwrap()
}

fn capture_frames(name: &str, text: &str, calibration: Calibration) -> Vec<ContactFrame> {
    let capture = EvemuFile::parse(name, text).unwrap();
    ReplaySource::from_evemu(&capture, SourceId::from("test"), calibration)
        .unwrap()
        .frames()
        .collect()
}

/// Per contact id, its positions in order; checks every id goes Down, Move*,
/// Up, appears at most once per frame, and nothing is left down at the end.
/// Returns the tracks and the most contacts down at once.
fn check_balanced(frames: &[ContactFrame]) -> (BTreeMap<u32, Vec<DVec2>>, usize) {
    let mut tracks: BTreeMap<u32, Vec<DVec2>> = BTreeMap::new();
    let mut down: HashMap<u32, ()> = HashMap::new();
    let mut most = 0;
    for (f, frame) in frames.iter().enumerate() {
        let mut ids: Vec<u32> = frame.contacts.iter().map(|c| c.id).collect();
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), frame.contacts.len(), "frame {f} repeats an id");
        assert!(!frame.contacts.is_empty(), "frame {f} is empty");
        for c in &frame.contacts {
            match c.phase {
                Phase::Down => {
                    assert!(!tracks.contains_key(&c.id), "frame {f}: id {} reused", c.id);
                    down.insert(c.id, ());
                }
                Phase::Move => assert!(down.contains_key(&c.id), "frame {f}: move of {}", c.id),
                Phase::Up => assert!(down.remove(&c.id).is_some(), "frame {f}: up of {}", c.id),
            }
            tracks.entry(c.id).or_default().push(c.position);
        }
        most = most.max(down.len());
    }
    assert!(down.is_empty(), "stuck contacts at the end: {down:?}");
    (tracks, most)
}

fn ev(time: f64, ev_type: u16, code: u16, value: i32) -> InputEvent {
    InputEvent::new(time, ev_type, code, value)
}

fn abs(time: f64, code: u16, value: i32) -> InputEvent {
    ev(time, EV_ABS, code, value)
}

fn syn(time: f64) -> InputEvent {
    ev(time, EV_SYN, SYN_REPORT, 0)
}

fn mt_report(time: f64) -> InputEvent {
    ev(time, EV_SYN, SYN_MT_REPORT, 0)
}

fn axis(min: i32, max: i32) -> AbsInfo {
    AbsInfo {
        min,
        max,
        ..AbsInfo::default()
    }
}

fn slot_axes(slots: i32) -> AbsAxes {
    AbsAxes::from([
        (ABS_X, axis(0, 1000)),
        (ABS_Y, axis(0, 1000)),
        (ABS_MT_SLOT, axis(0, slots - 1)),
        (ABS_MT_POSITION_X, axis(0, 1000)),
        (ABS_MT_POSITION_Y, axis(0, 1000)),
        (ABS_MT_TRACKING_ID, axis(0, 65535)),
        (ABS_MT_PRESSURE, axis(0, 200)),
        (ABS_MT_ORIENTATION, axis(-4, 4)),
    ])
}

fn anonymous_axes() -> AbsAxes {
    AbsAxes::from([
        (ABS_MT_POSITION_X, axis(0, 1000)),
        (ABS_MT_POSITION_Y, axis(0, 1000)),
    ])
}

/// Feeds events, collecting the frames.
fn run(decoder: &mut TouchDecoder, events: &[InputEvent]) -> Vec<ContactFrame> {
    events.iter().filter_map(|&e| decoder.push(e)).collect()
}

fn c(id: u32, phase: Phase, x: f64, y: f64) -> Contact {
    Contact::new(id, phase, DVec2::new(x, y))
}

fn frame(time: f64, contacts: Vec<Contact>) -> ContactFrame {
    ContactFrame {
        source: SourceId::from("dev"),
        time,
        contacts,
    }
}

// ---- real captures ----

#[test]
fn wetab_capture_decodes_to_balanced_one_finger_touches() {
    let capture = EvemuFile::read(&fixture("wetab.event")).unwrap();
    assert_eq!(
        capture.device.name,
        "eGalax-Inc.-USB-TouchController Virtual Device"
    );
    assert_eq!(capture.device.id.vendor, 0x0eef);
    let x = capture.device.axes[&ABS_MT_POSITION_X];
    let y = capture.device.axes[&ABS_MT_POSITION_Y];
    assert_eq!((x.min, x.max, x.fuzz), (0, 32760, 31));
    assert_eq!((y.min, y.max), (0, 32760));
    assert_eq!(capture.device.axes[&ABS_MT_SLOT].max, 1);
    assert_eq!(capture.events.len(), 170);

    let frames = capture_frames(
        "wetab.event",
        &fixture_text("wetab.event"),
        device_units(32760.0, 32760.0),
    );
    let (tracks, most) = check_balanced(&frames);
    // The capture holds eleven one-finger touches on slot 0 and never
    // selects slot 1; two-finger protocol B is covered synthetically below.
    assert_eq!(tracks.len(), 11);
    assert_eq!(most, 1);
    assert_eq!(frames.len(), 42);
    for frame in &frames {
        for c in &frame.contacts {
            assert!((0.0..=32760.0).contains(&c.position.x), "{c:?}");
            assert!((0.0..=32760.0).contains(&c.position.y), "{c:?}");
            assert_eq!(c.pressure, None);
        }
    }
    assert_eq!(
        frames[0].contacts,
        vec![c(1, Phase::Down, 13552.0, 27360.0)]
    );
    assert_eq!(frames[0].time, 1288981453.966);
    assert_eq!(frames[1].contacts, vec![c(1, Phase::Up, 13552.0, 27360.0)]);
    assert_eq!(
        frames[3].contacts,
        vec![c(2, Phase::Move, 18864.0, 29392.0)]
    );

    // Fitted to a 1920×1080 stage, y flipped: device y grows downwards.
    let fitted = capture.fit_calibration(DVec2::new(1920.0, 1080.0)).unwrap();
    let staged = capture_frames("wetab.event", &fixture_text("wetab.event"), fitted);
    let first = staged[0].contacts[0].position;
    assert!((first.x - 13552.0 / 32760.0 * 1920.0).abs() < 1e-9);
    assert!((first.y - (1080.0 - 27360.0 / 32760.0 * 1080.0)).abs() < 1e-9);
}

#[test]
fn ntrig_capture_tracks_anonymous_contacts_with_stable_ids() {
    let capture = EvemuFile::read(&fixture("ntrig-dell-xt2.event")).unwrap();
    let x = capture.device.axes[&ABS_MT_POSITION_X];
    let y = capture.device.axes[&ABS_MT_POSITION_Y];
    assert_eq!((x.min, x.max, y.min, y.max), (0, 9600, 0, 7200));
    let decoder = capture
        .decoder(SourceId::from("t"), device_units(9600.0, 7200.0))
        .unwrap();
    assert_eq!(decoder.protocol(), Protocol::Anonymous);

    let frames = capture_frames(
        "ntrig-dell-xt2.event",
        &fixture_text("ntrig-dell-xt2.event"),
        device_units(9600.0, 7200.0),
    );
    let (tracks, most) = check_balanced(&frames);
    assert_eq!(frames.len(), 8);
    assert_eq!(most, 4);
    assert_eq!(tracks.len(), 4);
    // Three fingers land together, a fourth joins in the fourth report.
    let downs = |f: &ContactFrame| f.contacts.iter().filter(|c| c.phase == Phase::Down).count();
    assert_eq!(downs(&frames[0]), 3);
    assert_eq!(downs(&frames[3]), 1);
    // Continuity: each id moves by small steps only (fingers ≥1000 apart).
    for (id, track) in &tracks {
        for step in track.windows(2) {
            let d = step[0].distance(step[1]);
            assert!(d < 60.0, "contact {id} jumped {d}: {track:?}");
        }
    }
    // The finger near (5900, 1500) is the last one down and lifts last.
    let last = frames.last().unwrap();
    assert_eq!(last.contacts.len(), 1);
    assert_eq!(last.contacts[0].phase, Phase::Up);
    assert_eq!(last.contacts[0].position, DVec2::new(5897.0, 1513.0));
    assert_eq!(tracks[&last.contacts[0].id].len(), 8);
    // ABS_MT_ORIENTATION 0..1: 1 means along x, 0 along y.
    let first = &frames[0].contacts;
    assert!(first[0].angle.unwrap().abs() < 1e-12);
    assert!((first[2].angle.unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
}

/// Copies of a capture with `SYN_DROPPED` inserted before each event line in
/// turn; every copy must still balance every down with an up.
fn inject_drops_everywhere(name: &str, axes_width: f64, axes_height: f64) -> usize {
    let text = fixture_text(name);
    let lines: Vec<&str> = text.lines().collect();
    let mut variants = 0;
    for (i, line) in lines.iter().enumerate() {
        let Some(rest) = line.strip_prefix("E: ") else {
            continue;
        };
        let time = rest.split_whitespace().next().unwrap();
        let mut copy: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        copy.insert(i, format!("E: {time} 0000 0003 0000\t# SYN_DROPPED"));
        let frames = capture_frames(
            name,
            &copy.join("\n"),
            device_units(axes_width, axes_height),
        );
        check_balanced(&frames);
        variants += 1;
    }
    variants
}

#[test]
fn dropped_events_leave_no_stuck_contact_and_lose_no_up() {
    assert_eq!(
        inject_drops_everywhere("wetab.event", 32760.0, 32760.0),
        170
    );
    assert_eq!(
        inject_drops_everywhere("ntrig-dell-xt2.event", 9600.0, 7200.0),
        146
    );
}

#[test]
fn dropped_up_report_is_recovered_at_the_next_report() {
    let text = fixture_text("wetab.event");
    let cut = "E: 1288981454.968899 0003 0039 -001";
    assert!(text.contains(cut));
    // The drop swallows the lift of touch 2; the slot's next tracking id then
    // ends it, before touch 3 lands.
    let copy = text.replace(cut, &format!("E: 1288981454.968899 0000 0003 0000\n{cut}"));
    let frames = capture_frames("wetab.event", &copy, device_units(32760.0, 32760.0));
    let (tracks, _) = check_balanced(&frames);
    assert_eq!(tracks.len(), 11);
    let handover = frames.iter().find(|f| f.time == 1288981455.241944).unwrap();
    assert_eq!(
        handover.contacts,
        vec![
            c(2, Phase::Up, 18864.0, 29324.0),
            c(3, Phase::Down, 16944.0, 29350.0)
        ]
    );

    // A dropped motion report changes nothing but that motion.
    let cut = "E: 1288981454.807912 0003 0036 29388";
    let copy = text.replace(cut, &format!("E: 1288981454.807912 0000 0003 0000\n{cut}"));
    let dropped = capture_frames("wetab.event", &copy, device_units(32760.0, 32760.0));
    let full = capture_frames("wetab.event", &text, device_units(32760.0, 32760.0));
    assert_eq!(dropped.len(), full.len() - 1);
    assert_eq!(check_balanced(&dropped).0.len(), 11);
}

#[test]
fn capture_ending_mid_touch_lifts_it() {
    let text = fixture_text("wetab.event");
    let end = text.find("E: 1288981458.603723").unwrap();
    let frames = capture_frames("wetab.event", &text[..end], device_units(32760.0, 32760.0));
    check_balanced(&frames);
    let last = frames.last().unwrap();
    assert_eq!(last.time, 1288981458.569752);
    assert_eq!(last.contacts, vec![c(11, Phase::Up, 21520.0, 27629.0)]);
}

// ---- synthetic sequences ----

#[test]
fn protocol_b_two_slots_exact_frames() {
    let mut d =
        TouchDecoder::new("dev".into(), &slot_axes(2), device_units(1000.0, 1000.0)).unwrap();
    assert_eq!(d.protocol(), Protocol::Slots);
    let frames = run(
        &mut d,
        &[
            abs(1.0, ABS_MT_SLOT, 0),
            abs(1.0, ABS_MT_TRACKING_ID, 40),
            abs(1.0, ABS_MT_POSITION_X, 100),
            abs(1.0, ABS_MT_POSITION_Y, 200),
            abs(1.0, ABS_MT_PRESSURE, 50),
            ev(1.0, EV_KEY, BTN_TOUCH, 1),
            abs(1.0, ABS_X, 100),
            syn(1.0),
            // Second finger: only slot 1 reported.
            abs(2.0, ABS_MT_SLOT, 1),
            abs(2.0, ABS_MT_TRACKING_ID, 41),
            abs(2.0, ABS_MT_POSITION_X, 300),
            abs(2.0, ABS_MT_POSITION_Y, 400),
            syn(2.0),
            // Slot 0 moves in x only.
            abs(3.0, ABS_MT_SLOT, 0),
            abs(3.0, ABS_MT_POSITION_X, 110),
            syn(3.0),
            // A value that did not change: no frame at all.
            abs(4.0, ABS_MT_SLOT, 1),
            abs(4.0, ABS_MT_POSITION_Y, 400),
            syn(4.0),
            // Slot 0 gets a new tracking id without -1: up + down; slot 1
            // lifts; all in one report.
            abs(5.0, ABS_MT_SLOT, 0),
            abs(5.0, ABS_MT_TRACKING_ID, 42),
            abs(5.0, ABS_MT_POSITION_X, 500),
            abs(5.0, ABS_MT_SLOT, 1),
            abs(5.0, ABS_MT_TRACKING_ID, -1),
            syn(5.0),
            abs(6.0, ABS_MT_SLOT, 0),
            abs(6.0, ABS_MT_TRACKING_ID, -1),
            ev(6.0, EV_KEY, BTN_TOUCH, 0),
            syn(6.0),
        ],
    );
    let mut first = c(1, Phase::Down, 100.0, 200.0);
    first.pressure = Some(0.25);
    let mut moved = c(1, Phase::Move, 110.0, 200.0);
    moved.pressure = Some(0.25);
    let mut lifted = c(1, Phase::Up, 110.0, 200.0);
    lifted.pressure = Some(0.25);
    // A slot's values persist: the new contact inherits y and pressure.
    let mut replacement = c(3, Phase::Down, 500.0, 200.0);
    replacement.pressure = Some(0.25);
    let mut last = c(3, Phase::Up, 500.0, 200.0);
    last.pressure = Some(0.25);
    assert_eq!(
        frames,
        vec![
            frame(1.0, vec![first]),
            frame(2.0, vec![c(2, Phase::Down, 300.0, 400.0)]),
            frame(3.0, vec![moved]),
            frame(
                5.0,
                vec![lifted, replacement, c(2, Phase::Up, 300.0, 400.0)]
            ),
            frame(6.0, vec![last]),
        ]
    );
    assert_eq!(d.live_contacts(), 0);
}

#[test]
fn protocol_b_tap_within_one_report_and_lift_then_land_in_one_report() {
    let mut d =
        TouchDecoder::new("dev".into(), &slot_axes(2), device_units(1000.0, 1000.0)).unwrap();
    let frames = run(
        &mut d,
        &[
            // Lands and lifts before any report: never shown.
            abs(1.0, ABS_MT_TRACKING_ID, 1),
            abs(1.0, ABS_MT_POSITION_X, 10),
            abs(1.0, ABS_MT_TRACKING_ID, -1),
            syn(1.0),
            abs(2.0, ABS_MT_TRACKING_ID, 2),
            abs(2.0, ABS_MT_POSITION_Y, 20),
            syn(2.0),
            // -1 then a new id in the same report.
            abs(3.0, ABS_MT_TRACKING_ID, -1),
            abs(3.0, ABS_MT_TRACKING_ID, 3),
            abs(3.0, ABS_MT_POSITION_X, 30),
            syn(3.0),
        ],
    );
    assert_eq!(
        frames,
        vec![
            frame(2.0, vec![c(1, Phase::Down, 10.0, 20.0)]),
            frame(
                3.0,
                vec![c(1, Phase::Up, 10.0, 20.0), c(2, Phase::Down, 30.0, 20.0)]
            ),
        ]
    );
    assert_eq!(
        d.lift_all(4.0),
        Some(frame(4.0, vec![c(2, Phase::Up, 30.0, 20.0)]))
    );
    assert_eq!(d.lift_all(5.0), None);
}

#[test]
fn protocol_b_syn_dropped_takes_the_next_report_as_truth() {
    let mut d =
        TouchDecoder::new("dev".into(), &slot_axes(2), device_units(1000.0, 1000.0)).unwrap();
    let frames = run(
        &mut d,
        &[
            abs(1.0, ABS_MT_SLOT, 0),
            abs(1.0, ABS_MT_TRACKING_ID, 7),
            abs(1.0, ABS_MT_POSITION_X, 100),
            abs(1.0, ABS_MT_SLOT, 1),
            abs(1.0, ABS_MT_TRACKING_ID, 8),
            abs(1.0, ABS_MT_POSITION_X, 500),
            syn(1.0),
            ev(2.0, EV_SYN, SYN_DROPPED, 0),
            // Discarded, report included.
            abs(2.0, ABS_MT_SLOT, 0),
            abs(2.0, ABS_MT_TRACKING_ID, -1),
            syn(2.0),
            // The truth: slot 1 moved, slot 0 is not mentioned, so it lifts.
            abs(3.0, ABS_MT_SLOT, 1),
            abs(3.0, ABS_MT_POSITION_X, 510),
            syn(3.0),
            // Slot 1 again: a plain move now that we are in sync.
            abs(4.0, ABS_MT_POSITION_X, 520),
            syn(4.0),
            // Slot 0 mentioned again with its stale id: lands anew.
            abs(5.0, ABS_MT_SLOT, 0),
            abs(5.0, ABS_MT_POSITION_Y, 50),
            syn(5.0),
            abs(6.0, ABS_MT_TRACKING_ID, -1),
            abs(6.0, ABS_MT_SLOT, 1),
            abs(6.0, ABS_MT_TRACKING_ID, -1),
            syn(6.0),
        ],
    );
    assert_eq!(
        frames,
        vec![
            frame(
                1.0,
                vec![c(1, Phase::Down, 100.0, 0.0), c(2, Phase::Down, 500.0, 0.0)]
            ),
            frame(
                3.0,
                vec![c(1, Phase::Up, 100.0, 0.0), c(2, Phase::Move, 510.0, 0.0)]
            ),
            frame(4.0, vec![c(2, Phase::Move, 520.0, 0.0)]),
            frame(5.0, vec![c(3, Phase::Down, 100.0, 50.0)]),
            frame(
                6.0,
                vec![c(3, Phase::Up, 100.0, 50.0), c(2, Phase::Up, 520.0, 0.0)]
            ),
        ]
    );
}

#[test]
fn protocol_b_resync_from_slot_read_back() {
    let mut d =
        TouchDecoder::new("dev".into(), &slot_axes(4), device_units(1000.0, 1000.0)).unwrap();
    let events = [
        abs(1.0, ABS_MT_SLOT, 0),
        abs(1.0, ABS_MT_TRACKING_ID, 7),
        abs(1.0, ABS_MT_POSITION_X, 100),
        abs(1.0, ABS_MT_SLOT, 1),
        abs(1.0, ABS_MT_TRACKING_ID, 8),
        abs(1.0, ABS_MT_POSITION_X, 500),
        syn(1.0),
        ev(2.0, EV_SYN, SYN_DROPPED, 0),
        abs(2.0, ABS_MT_POSITION_X, 900),
        syn(2.0),
    ];
    assert_eq!(run(&mut d, &events).len(), 1);
    // The device says: slot 0 kept its contact and moved, slot 1 is empty,
    // slot 2 has a new contact.
    let frame_back = d.resync(2.5, &[(0, 7, 150, 150), (2, 9, 700, 700)]);
    assert_eq!(
        frame_back,
        Some(frame(
            2.5,
            vec![
                c(1, Phase::Move, 150.0, 150.0),
                c(2, Phase::Up, 500.0, 0.0),
                c(3, Phase::Down, 700.0, 700.0),
            ]
        ))
    );
    // In sync again: a report that mentions only slot 2 lifts nobody.
    let after = run(
        &mut d,
        &[
            abs(3.0, ABS_MT_SLOT, 2),
            abs(3.0, ABS_MT_POSITION_Y, 710),
            syn(3.0),
        ],
    );
    assert_eq!(
        after,
        vec![frame(3.0, vec![c(3, Phase::Move, 700.0, 710.0)])]
    );
    assert_eq!(d.live_contacts(), 2);
}

#[test]
fn protocol_a_nearest_neighbour_exact_frames() {
    let mut d = TouchDecoder::new(
        "dev".into(),
        &anonymous_axes(),
        device_units(1000.0, 1000.0),
    )
    .unwrap();
    assert_eq!(d.protocol(), Protocol::Anonymous);
    let point = |t, x, y| {
        [
            abs(t, ABS_MT_POSITION_X, x),
            abs(t, ABS_MT_POSITION_Y, y),
            mt_report(t),
        ]
    };
    let mut events = Vec::new();
    events.extend(point(1.0, 100, 100));
    events.extend(point(1.0, 800, 800));
    events.push(syn(1.0));
    // Reported in the other order: ids follow positions, not order.
    events.extend(point(2.0, 805, 790));
    events.extend(point(2.0, 102, 101));
    events.push(syn(2.0));
    // One contact missing: it lifted; the other did not change.
    events.extend(point(3.0, 805, 790));
    events.push(syn(3.0));
    events.extend(point(4.0, 805, 790));
    events.extend(point(4.0, 400, 400));
    events.push(syn(4.0));
    // Too far to be the same finger: lift and land.
    events.extend(point(5.0, 805, 790));
    events.extend(point(5.0, 400, 600));
    events.push(syn(5.0));
    // An empty SYN_MT_REPORT: no contacts at all.
    events.push(mt_report(6.0));
    events.push(syn(6.0));
    events.extend(point(7.0, 10, 10));
    events.push(syn(7.0));
    // A report with no SYN_MT_REPORT at all is empty too.
    events.push(ev(8.0, EV_KEY, BTN_TOUCH, 0));
    events.push(syn(8.0));
    let frames = run(&mut d, &events);
    assert_eq!(
        frames,
        vec![
            frame(
                1.0,
                vec![
                    c(1, Phase::Down, 100.0, 100.0),
                    c(2, Phase::Down, 800.0, 800.0)
                ]
            ),
            frame(
                2.0,
                vec![
                    c(2, Phase::Move, 805.0, 790.0),
                    c(1, Phase::Move, 102.0, 101.0)
                ]
            ),
            frame(3.0, vec![c(1, Phase::Up, 102.0, 101.0)]),
            frame(4.0, vec![c(3, Phase::Down, 400.0, 400.0)]),
            frame(
                5.0,
                vec![
                    c(3, Phase::Up, 400.0, 400.0),
                    c(4, Phase::Down, 400.0, 600.0)
                ]
            ),
            frame(
                6.0,
                vec![c(2, Phase::Up, 805.0, 790.0), c(4, Phase::Up, 400.0, 600.0)]
            ),
            frame(7.0, vec![c(5, Phase::Down, 10.0, 10.0)]),
            frame(8.0, vec![c(5, Phase::Up, 10.0, 10.0)]),
        ]
    );
}

#[test]
fn protocol_a_syn_dropped_discards_the_broken_report() {
    let mut d = TouchDecoder::new(
        "dev".into(),
        &anonymous_axes(),
        device_units(1000.0, 1000.0),
    )
    .unwrap();
    let events = [
        abs(1.0, ABS_MT_POSITION_X, 100),
        abs(1.0, ABS_MT_POSITION_Y, 100),
        mt_report(1.0),
        syn(1.0),
        abs(2.0, ABS_MT_POSITION_X, 900),
        ev(2.0, EV_SYN, SYN_DROPPED, 0),
        abs(2.0, ABS_MT_POSITION_Y, 900),
        mt_report(2.0),
        syn(2.0),
        abs(3.0, ABS_MT_POSITION_X, 101),
        abs(3.0, ABS_MT_POSITION_Y, 100),
        mt_report(3.0),
        syn(3.0),
    ];
    assert_eq!(
        run(&mut d, &events),
        vec![
            frame(1.0, vec![c(1, Phase::Down, 100.0, 100.0)]),
            frame(3.0, vec![c(1, Phase::Move, 101.0, 100.0)]),
        ]
    );
}

#[test]
fn single_touch_fallback_with_pressure_and_tilt() {
    let axes = AbsAxes::from([
        (ABS_X, axis(0, 1000)),
        (ABS_Y, axis(0, 1000)),
        (ABS_PRESSURE, axis(0, 1000)),
        (
            ABS_TILT_X,
            AbsInfo {
                min: -64,
                max: 63,
                resolution: 50,
                ..AbsInfo::default()
            },
        ),
        (
            ABS_TILT_Y,
            AbsInfo {
                min: -64,
                max: 63,
                resolution: 50,
                ..AbsInfo::default()
            },
        ),
    ]);
    // Stage is y-up: device y 0 (top) is stage y 1000.
    let flip = Calibration::fit([0.0, 1000.0], [0.0, 1000.0], DVec2::new(1000.0, 1000.0)).unwrap();
    let mut d = TouchDecoder::new("dev".into(), &axes, flip).unwrap();
    assert_eq!(d.protocol(), Protocol::SingleTouch);
    let frames = run(
        &mut d,
        &[
            abs(1.0, ABS_X, 200),
            abs(1.0, ABS_Y, 100),
            abs(1.0, ABS_PRESSURE, 500),
            abs(1.0, ABS_TILT_X, 25),
            abs(1.0, ABS_TILT_Y, 50),
            // Hovering: no contact yet.
            syn(1.0),
            ev(2.0, EV_KEY, BTN_TOUCH, 1),
            syn(2.0),
            abs(3.0, ABS_X, 300),
            syn(3.0),
            ev(4.0, EV_KEY, BTN_TOUCH, 0),
            syn(4.0),
        ],
    );
    let pen = |phase, x| Contact {
        id: 1,
        phase,
        position: DVec2::new(x, 900.0),
        pressure: Some(0.5),
        // Leaning towards device +y (the performer) is stage −y.
        tilt: Some(DVec2::new(0.5, -1.0)),
        angle: None,
    };
    assert_eq!(
        frames,
        vec![
            frame(2.0, vec![pen(Phase::Down, 200.0)]),
            frame(3.0, vec![pen(Phase::Move, 300.0)]),
            frame(4.0, vec![pen(Phase::Up, 300.0)]),
        ]
    );
}

#[test]
fn orientation_becomes_a_stage_angle() {
    let flip = Calibration::fit([0.0, 1000.0], [0.0, 1000.0], DVec2::new(1000.0, 1000.0)).unwrap();
    let mut d = TouchDecoder::new("dev".into(), &slot_axes(1), flip).unwrap();
    let angle_after = |d: &mut TouchDecoder, t: f64, orientation: i32| {
        let frames = run(d, &[abs(t, ABS_MT_ORIENTATION, orientation), syn(t)]);
        frames[0].contacts[0].angle.unwrap()
    };
    run(&mut d, &[abs(0.0, ABS_MT_TRACKING_ID, 1), syn(0.0)]);
    // 0: along the device's y axis; max: along +x; in between: the diagonal
    // towards device +x, −y, which is stage up-right once y is flipped.
    assert!((angle_after(&mut d, 1.0, 0) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert!(angle_after(&mut d, 2.0, 4).abs() < 1e-12);
    assert!((angle_after(&mut d, 3.0, 2) - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
    assert!((angle_after(&mut d, 4.0, -2) + std::f64::consts::FRAC_PI_4).abs() < 1e-12);
}

#[test]
fn decoder_refuses_a_device_without_position_axes() {
    let axes = AbsAxes::from([(ABS_PRESSURE, axis(0, 10))]);
    let err = TouchDecoder::new("dev".into(), &axes, device_units(1.0, 1.0)).unwrap_err();
    assert!(err.to_string().contains("no position axes"), "{err}");
}

// ---- calibration ----

#[test]
fn range_fit_flips_y_onto_the_stage() {
    let near = |got: DVec2, x: f64, y: f64| {
        assert!(
            got.distance(DVec2::new(x, y)) < 1e-9,
            "{got} is not [{x}, {y}]"
        );
    };
    let cal = Calibration::fit([0.0, 32760.0], [0.0, 32760.0], DVec2::new(1920.0, 1080.0)).unwrap();
    near(cal.map(DVec2::new(0.0, 0.0)), 0.0, 1080.0);
    near(cal.map(DVec2::new(32760.0, 32760.0)), 1920.0, 0.0);
    near(cal.map(DVec2::new(16380.0, 8190.0)), 960.0, 810.0);
    // Offset ranges and stage rectangles, no flip, mirrored x.
    let cal = Calibration::new(CalibrationSpec::Range {
        x: [1000.0, 0.0],
        y: [100.0, 300.0],
        flip_y: false,
        stage_min: [10.0, 20.0],
        stage_max: [110.0, 220.0],
    })
    .unwrap();
    near(cal.map(DVec2::new(1000.0, 100.0)), 10.0, 20.0);
    near(cal.map(DVec2::new(0.0, 300.0)), 110.0, 220.0);
    near(cal.map(DVec2::new(250.0, 150.0)), 85.0, 70.0);
}

#[test]
fn four_corner_homography_maps_the_corners_exactly() {
    let corners = [
        [120.0, 300.0],
        [31000.0, 250.0],
        [32100.0, 32500.0],
        [90.0, 31000.0],
    ];
    let cal = Calibration::new(CalibrationSpec::Corners {
        corners,
        stage_min: [0.0, 0.0],
        stage_max: [1600.0, 900.0],
    })
    .unwrap();
    let stage = [[0.0, 900.0], [1600.0, 900.0], [1600.0, 0.0], [0.0, 0.0]];
    for (device, want) in corners.iter().zip(stage) {
        let got = cal.map(DVec2::from(*device));
        assert!(
            got.distance(DVec2::from(want)) < 1e-9,
            "{device:?} → {got}, not {want:?}"
        );
    }
    // Lines stay lines: the diagonals' crossing is the stage's centre.
    let p: Vec<DVec2> = corners.iter().map(|&c| DVec2::from(c)).collect();
    let (d1, d2) = (p[2] - p[0], p[3] - p[1]);
    let s = (p[1] - p[0]).perp_dot(d2) / d1.perp_dot(d2);
    let crossing = p[0] + d1 * s;
    assert!(cal.map(crossing).distance(DVec2::new(800.0, 450.0)) < 1e-9);
}

#[test]
fn calibration_from_stage_file_text() {
    #[derive(serde::Deserialize)]
    struct Section {
        calibration: Calibration,
    }
    let parsed: Section = toml::from_str(
        r#"calibration = { kind = "corners", corners = [[0, 0], [100, 0], [100, 100], [0, 100]], stage_min = [0, 0], stage_max = [10, 10] }"#,
    )
    .unwrap();
    assert!(
        parsed
            .calibration
            .map(DVec2::new(50.0, 25.0))
            .distance(DVec2::new(5.0, 7.5))
            < 1e-12
    );
    let parsed: Section = toml::from_str(
        r#"calibration = { kind = "range", x = [0, 100], y = [0, 100], stage_min = [0, 0], stage_max = [10, 10] }"#,
    )
    .unwrap();
    // flip_y defaults to true.
    assert_eq!(
        parsed.calibration.map(DVec2::new(0.0, 0.0)),
        DVec2::new(0.0, 10.0)
    );
    let back = serde_json::to_value(&parsed.calibration).unwrap();
    assert_eq!(back["kind"], "range");
    assert_eq!(back["flip_y"], true);

    let misspelt = toml::from_str::<Section>(
        r#"calibration = { kind = "range", x = [0, 100], y = [0, 100], flipy = true, stage_min = [0, 0], stage_max = [10, 10] }"#,
    );
    let err = misspelt.err().unwrap().to_string();
    assert!(err.contains("flipy"), "{err}");
    let bowtie = toml::from_str::<Section>(
        r#"calibration = { kind = "corners", corners = [[0, 0], [100, 100], [100, 0], [0, 100]], stage_min = [0, 0], stage_max = [10, 10] }"#,
    );
    let err = bowtie.err().unwrap().to_string();
    assert!(err.contains("corners") && err.contains("convex"), "{err}");
    let empty = Calibration::fit([5.0, 5.0], [0.0, 1.0], DVec2::new(1.0, 1.0)).unwrap_err();
    assert!(
        empty.to_string().contains("x: the range [5, 5] is empty"),
        "{empty}"
    );
    let stage = Calibration::fit([0.0, 5.0], [0.0, 1.0], DVec2::new(0.0, 1.0)).unwrap_err();
    assert!(stage.to_string().contains("stage_max"), "{stage}");
}

// ---- recordings ----

fn sample_frames() -> Vec<ContactFrame> {
    let mut rich = c(1, Phase::Move, 812.5, 400.25);
    rich.pressure = Some(0.75);
    rich.tilt = Some(DVec2::new(0.125, -0.5));
    rich.angle = Some(-1.25);
    vec![
        ContactFrame {
            source: SourceId::from("evdev0"),
            time: 0.5,
            contacts: vec![
                c(1, Phase::Down, 800.0, 400.0),
                c(2, Phase::Down, 10.0, 20.0),
            ],
        },
        ContactFrame {
            source: SourceId::from("evdev0"),
            time: 0.516,
            contacts: vec![rich],
        },
        ContactFrame {
            source: SourceId::from("client:3"),
            time: 0.6,
            contacts: vec![c(7, Phase::Up, -3.0, 1e6)],
        },
    ]
}

#[test]
fn recording_round_trips() {
    let frames = sample_frames();
    let mut writer = RecordingWriter::new(Vec::new());
    for f in &frames {
        writer.write_frame(f).unwrap();
    }
    let text = String::from_utf8(writer.into_inner()).unwrap();
    assert_eq!(text.lines().count(), 3);
    assert_eq!(
        text.lines().next().unwrap(),
        r#"{"t":0.5,"source":"evdev0","contacts":[{"id":1,"phase":"down","x":800.0,"y":400.0},{"id":2,"phase":"down","x":10.0,"y":20.0}]}"#
    );
    assert_eq!(parse_recording("mem", &text).unwrap(), frames);

    // Through a file, with a real capture's frames (arbitrary floats).
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wetab.jsonl");
    let capture = EvemuFile::read(&fixture("wetab.event")).unwrap();
    let cal = capture.fit_calibration(DVec2::new(1920.0, 1080.0)).unwrap();
    let staged = capture_frames("wetab.event", &fixture_text("wetab.event"), cal);
    let mut writer = RecordingWriter::new(std::io::BufWriter::new(
        std::fs::File::create(&path).unwrap(),
    ));
    for f in &staged {
        writer.write_frame(f).unwrap();
    }
    writer.flush().unwrap();
    drop(writer);
    let back = read_recording(&path).unwrap();
    assert_eq!(back.len(), staged.len());
    for (a, b) in back.iter().zip(&staged) {
        assert_eq!((a.time, &a.source), (b.time, &b.source));
        for (ca, cb) in a.contacts.iter().zip(&b.contacts) {
            assert_eq!((ca.id, ca.phase), (cb.id, cb.phase));
            assert!(ca.position.distance(cb.position) < 1e-9);
        }
    }
    // And it replays as a recording, keeping its sources.
    let source = ReplaySource::open(&path, (1920.0, 1080.0)).unwrap();
    assert_eq!(source.frames().count(), staged.len());
    assert_eq!(source.frames().next().unwrap().source.as_str(), "test");
}

#[test]
fn recording_writer_refuses_non_finite_numbers() {
    let mut bad = sample_frames().remove(0);
    bad.contacts[1].position.y = f64::NAN;
    let err = RecordingWriter::new(Vec::new())
        .write_frame(&bad)
        .unwrap_err();
    assert!(err.to_string().contains("y is NaN"), "{err}");
}

#[test]
fn malformed_recording_lines_name_the_line() {
    let good =
        r#"{"t": 0.0, "source": "a", "contacts": [{"id": 1, "phase": "down", "x": 1, "y": 2}]}"#;
    let cases = [
        (
            r#"{"t": 1.0, "source": "a", "contacts": [{"id": 1, "phase": "move", "y": 2}]}"#,
            "missing field `x`",
        ),
        (
            r#"{"t": 1.0, "source": "a", "contacts": [], "extra": 1}"#,
            "unknown field `extra`",
        ),
        (
            r#"{"t": 1.0, "source": "a", "contacts": [{"id": 1, "phase": "hover", "x": 1, "y": 2}]}"#,
            "unknown variant `hover`",
        ),
        (
            r#"{"t": 1.0, "source": "a", "contacts": [{"id": -1, "phase": "up", "x": 1, "y": 2}]}"#,
            "-1",
        ),
        (
            r#"{"t": 1.0, "source": "a", "contacts": [{"id": 1, "phase": "up", "x": 1, "y": 2, "pressure": 1.5}]}"#,
            "contacts[0].pressure: 1.5 is not within 0..=1",
        ),
        (
            r#"{"t": 1.0, "source": "a", "contacts": [{"id": 1, "phase": "up", "x": 1, "y": 2}, {"id": 1, "phase": "down", "x": 1, "y": 2}]}"#,
            "contacts[1].id: contact 1 appears twice",
        ),
        (
            r#"{"t": 1.0, "source": "", "contacts": []}"#,
            "source: must not be empty",
        ),
        (
            r#"{"t": 1.0, "source": "a", "contacts": [{"id": 1, "phase": "up", "x": 1e10, "y": 2}]}"#,
            "contacts[0].x",
        ),
        ("garbage", "column 1: expected value"),
    ];
    for (line, expected) in cases {
        let text = format!("{good}\n\n{line}\n{good}\n");
        let err = parse_recording("take.jsonl", &text)
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("take.jsonl:3: "), "{err}");
        assert!(err.contains(expected), "{line}: {err}");
        assert!(!err.contains("at line 1 column"), "{err}");
    }
    let err = read_recording(std::path::Path::new("/nonexistent/take.jsonl")).unwrap_err();
    assert!(
        err.to_string()
            .starts_with("/nonexistent/take.jsonl: cannot read"),
        "{err}"
    );
}

#[test]
fn malformed_evemu_lines_name_the_line_and_field() {
    let header = "# EVEMU 1.1\nN: Test # device\nI: 0003 0eef 72a1 0210\nA: 35 0 1000 0 0\nA: 36 0 1000 0 0 0\n";
    let cases = [
        (
            "E: 1.000010 0003 00zz 5",
            "event code: `00zz` is not a hexadecimal",
        ),
        ("E: 1.000010 0003 0035", "value: missing"),
        (
            "E: 1.000010 0003 0035 x5",
            "value: `x5` is not a whole number",
        ),
        (
            "E: 1,5 0003 0035 5",
            "time: `1,5` is not `seconds.microseconds`",
        ),
        ("E: -1.5 0003 0035 5", "time:"),
        ("E: 1.000010 0003 0035 5 9", "line: unexpected `9`"),
        (
            "E: 1.000010 0020 0035 5",
            "event type: 0x20 is above EV_MAX",
        ),
        (
            "E: 0.5 0003 0035 5",
            "time: 0.5 is earlier than the previous event's 1.00001",
        ),
        ("A: 40 0 10 0 0", "axis code: 0x40 is above ABS_MAX"),
        ("A: 30 10 0 0 0", "max: 0 is below min 10"),
        ("A: 35 0 10 0 0", "axis code: axis 0x35 is described twice"),
        ("I: 0003 0eef", "product: missing"),
        ("B: 03 0g", "event bits"),
        ("Q: what", "unknown line kind `Q:`"),
        ("hello", "expected `X: …`"),
    ];
    for (line, expected) in cases {
        let text =
            format!("{header}E: 1.000010 0003 0035 0004\n{line}\nE: 2.000000 0000 0000 0000\n");
        let err = EvemuFile::parse("bad.event", &text)
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("bad.event:7: "), "{line}: {err}");
        assert!(err.contains(expected), "{line}: {err}");
    }
    let parsed = EvemuFile::parse(
        "ok.event",
        &format!("{header}E: 1.000010 0003 0035 0004 # comment\n"),
    )
    .unwrap();
    assert_eq!(parsed.device.name, "Test # device");
    assert_eq!(
        parsed.events,
        vec![InputEvent::new(1.00001, EV_ABS, ABS_MT_POSITION_X, 4)]
    );
    // No Y axis, no X axis: cannot be decoded or calibrated.
    let bare = EvemuFile::parse("bare.event", "A: 18 0 10 0 0\n").unwrap();
    let err = bare.fit_calibration(DVec2::ONE).unwrap_err().to_string();
    assert!(
        err.starts_with("bare.event: the device has no position axes"),
        "{err}"
    );
    let err = EvemuFile::read(std::path::Path::new("/nonexistent/x.event")).unwrap_err();
    assert!(
        err.to_string()
            .starts_with("/nonexistent/x.event: cannot read"),
        "{err}"
    );
}

// ---- replay ----

fn timed_frames(times: &[f64]) -> Vec<ContactFrame> {
    times
        .iter()
        .enumerate()
        .map(|(i, &t)| ContactFrame {
            source: SourceId::from("replay"),
            time: t,
            contacts: vec![c(
                1,
                if i == 0 { Phase::Down } else { Phase::Move },
                i as f64,
                0.0,
            )],
        })
        .collect()
}

#[tokio::test(flavor = "current_thread")]
async fn real_time_pacing_waits_for_each_timestamp() {
    tokio::time::pause();
    let frames = timed_frames(&[100.0, 100.5, 101.25, 101.25]);
    let source = ReplaySource::from_frames(frames.clone());
    let (tx, mut rx) = mpsc::channel(1);
    let start = Instant::now();
    let player = tokio::spawn(replay(source, Pacing::RealTime, tx));

    assert_eq!(rx.recv().await.as_ref(), Some(&frames[0]));
    assert_eq!(start.elapsed(), Duration::ZERO);
    // Not before its time…
    tokio::time::advance(Duration::from_millis(499)).await;
    tokio::task::yield_now().await;
    assert!(rx.try_recv().is_err());
    // …and at its time.
    assert_eq!(rx.recv().await.as_ref(), Some(&frames[1]));
    // Tokio's timers tick in whole milliseconds, rounding deadlines up.
    let waited = start.elapsed();
    assert!(waited >= Duration::from_millis(500) && waited <= Duration::from_millis(501));
    assert_eq!(rx.recv().await.as_ref(), Some(&frames[2]));
    assert_eq!(rx.recv().await.as_ref(), Some(&frames[3]));
    assert!(start.elapsed() >= Duration::from_millis(1250));
    assert_eq!(rx.recv().await, None);
    let summary = player.await.unwrap();
    assert_eq!(summary.frames_sent, 4);
    assert!(!summary.sink_closed);
}

#[tokio::test(flavor = "current_thread")]
async fn real_time_pacing_of_a_capture_takes_its_duration() {
    tokio::time::pause();
    let source = ReplaySource::open(&fixture("wetab.event"), (1920.0, 1080.0)).unwrap();
    let expected: Vec<ContactFrame> = source.frames().collect();
    let duration = expected.last().unwrap().time - expected[0].time;
    let (tx, mut rx) = mpsc::channel(4);
    let start = Instant::now();
    let player = tokio::spawn(replay(source, Pacing::RealTime, tx));
    let mut got = Vec::new();
    while let Some(frame) = rx.recv().await {
        // No frame arrives before its offset from the first.
        let due = frame.time - expected[0].time;
        assert!(start.elapsed().as_secs_f64() >= due - 1e-9);
        got.push(frame);
    }
    assert_eq!(got, expected);
    assert!(start.elapsed().as_secs_f64() >= duration - 1e-9);
    assert_eq!(player.await.unwrap().frames_sent, expected.len());
}

#[tokio::test(flavor = "current_thread")]
async fn as_fast_as_possible_delivers_every_frame_without_waiting() {
    tokio::time::pause();
    let times: Vec<f64> = (0..200).map(|i| f64::from(i) * 10.0).collect();
    let frames = timed_frames(&times);
    let (tx, mut rx) = mpsc::channel(1);
    let start = Instant::now();
    let player = tokio::spawn(replay(frames.clone(), Pacing::AsFastAsPossible, tx));
    let mut got = Vec::new();
    while let Some(frame) = rx.recv().await {
        got.push(frame);
    }
    assert_eq!(got, frames);
    assert_eq!(start.elapsed(), Duration::ZERO);
    assert_eq!(player.await.unwrap().frames_sent, 200);
}

#[tokio::test(flavor = "current_thread")]
async fn replay_stops_when_the_receiver_goes_away() {
    let (tx, mut rx) = mpsc::channel(1);
    let player = tokio::spawn(replay(
        timed_frames(&[0.0, 0.0, 0.0, 0.0]),
        Pacing::AsFastAsPossible,
        tx,
    ));
    assert!(rx.recv().await.is_some());
    drop(rx);
    let summary = player.await.unwrap();
    assert!(summary.sink_closed);
    assert!(summary.frames_sent < 4);
}

#[test]
fn replay_source_reads_either_format_and_plays_again() {
    let source = ReplaySource::open(&fixture("ntrig-dell-xt2.event"), (960.0, 720.0)).unwrap();
    let first: Vec<ContactFrame> = source.frames().collect();
    let second: Vec<ContactFrame> = source.clone().into_iter().collect();
    assert_eq!(first, second);
    assert_eq!(first.len(), 8);
    assert!(first.iter().all(|f| f.source.as_str() == "replay"));
    for contact in first.iter().flat_map(|f| &f.contacts) {
        assert!((0.0..=960.0).contains(&contact.position.x));
        assert!((0.0..=720.0).contains(&contact.position.y));
    }
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.jsonl");
    std::fs::write(&bad, "{\"t\": 0}\n").unwrap();
    let err = ReplaySource::open(&bad, (1.0, 1.0))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("bad.jsonl:1: ") && err.contains("missing field"),
        "{err}"
    );
}
