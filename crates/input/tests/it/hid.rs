//! The HID digitizer decoder against a synthetic Windows-style touch screen:
//! report id 1 with two finger slots, scan time and contact count; report id
//! 2 a Contact Count Maximum feature; report id 3 the Input Mode feature.
//! Then hid-recorder captures (parse, write, errors by line), their replay
//! (a two-finger drag captured in parallel and in hybrid mode plays the same
//! frames, also through the running daemon), device selection, and
//! `run_device` against a stand-in device that fails mid-drag.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use glam::DVec2;
use puppetry_input::hid::{
    HidDeviceInfo, HidError, HidField, HidSelector, HidTouchDecoder, InputMode, ReportDevice,
    Surface, TouchLayout, permission_hint, run_device,
};
use puppetry_input::hid_recording::{HidRecording, HidRecordingError};
use puppetry_input::replay::{ReplayError, ReplaySource};
use puppetry_input::{Calibration, ContactFrame, Phase, SourceId};
use tokio::sync::mpsc;

#[rustfmt::skip]
const FINGER: &[u8] = &[
    0x05, 0x0D,             // Usage Page (Digitizers)
    0x09, 0x22,             // Usage (Finger)
    0xA1, 0x02,             // Collection (Logical)
    0x09, 0x42,             //   Usage (Tip Switch)
    0x15, 0x00,             //   Logical Minimum (0)
    0x25, 0x01,             //   Logical Maximum (1)
    0x75, 0x01,             //   Report Size (1)
    0x95, 0x01,             //   Report Count (1)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0x95, 0x07,             //   Report Count (7)
    0x81, 0x03,             //   Input (Const) padding
    0x75, 0x08,             //   Report Size (8)
    0x95, 0x01,             //   Report Count (1)
    0x25, 0x7F,             //   Logical Maximum (127)
    0x09, 0x51,             //   Usage (Contact Identifier)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0x05, 0x01,             //   Usage Page (Generic Desktop)
    0x26, 0xFF, 0x0F,       //   Logical Maximum (4095)
    0x75, 0x10,             //   Report Size (16)
    0x55, 0x0E,             //   Unit Exponent (-2)
    0x65, 0x11,             //   Unit (cm)
    0x35, 0x00,             //   Physical Minimum (0)
    0x46, 0xB5, 0x04,       //   Physical Maximum (1205)
    0x09, 0x30,             //   Usage (X)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0x46, 0x8A, 0x03,       //   Physical Maximum (906)
    0x09, 0x31,             //   Usage (Y)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0x05, 0x0D,             //   Usage Page (Digitizers)
    0x65, 0x00,             //   Unit (none)
    0x55, 0x00,             //   Unit Exponent (0)
    0x45, 0x00,             //   Physical Maximum (0)
    0x26, 0xFF, 0x00,       //   Logical Maximum (255)
    0x75, 0x08,             //   Report Size (8)
    0x09, 0x30,             //   Usage (Tip Pressure)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0xC0,                   // End Collection
];

#[rustfmt::skip]
const HEAD: &[u8] = &[
    0x05, 0x0D,             // Usage Page (Digitizers)
    0x09, 0x04,             // Usage (Touch Screen)
    0xA1, 0x01,             // Collection (Application)
    0x85, 0x01,             //   Report ID (1)
];

#[rustfmt::skip]
const TAIL: &[u8] = &[
    0x05, 0x0D,             //   Usage Page (Digitizers)
    0x55, 0x0C,             //   Unit Exponent (-4)
    0x66, 0x01, 0x10,       //   Unit (seconds)
    0x47, 0xFF, 0xFF, 0x00, 0x00, // Physical Maximum (65535)
    0x27, 0xFF, 0xFF, 0x00, 0x00, // Logical Maximum (65535)
    0x75, 0x10,             //   Report Size (16)
    0x95, 0x01,             //   Report Count (1)
    0x09, 0x56,             //   Usage (Scan Time)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0x65, 0x00,             //   Unit (none)
    0x55, 0x00,             //   Unit Exponent (0)
    0x45, 0x00,             //   Physical Maximum (0)
    0x25, 0x7F,             //   Logical Maximum (127)
    0x75, 0x08,             //   Report Size (8)
    0x09, 0x54,             //   Usage (Contact Count)
    0x81, 0x02,             //   Input (Data, Var, Abs)
    0x85, 0x02,             //   Report ID (2)
    0x25, 0x0A,             //   Logical Maximum (10)
    0x09, 0x55,             //   Usage (Contact Count Maximum)
    0xB1, 0x02,             //   Feature (Data, Var, Abs)
    0xC0,                   // End Collection
    0x09, 0x0E,             // Usage (Device Configuration)
    0xA1, 0x01,             // Collection (Application)
    0x85, 0x03,             //   Report ID (3)
    0x09, 0x23,             //   Usage (Device Settings)
    0xA1, 0x02,             //   Collection (Logical)
    0x09, 0x52,             //     Usage (Input Mode)
    0x09, 0x53,             //     Usage (Device Index)
    0x15, 0x00,             //     Logical Minimum (0)
    0x25, 0x0A,             //     Logical Maximum (10)
    0x75, 0x08,             //     Report Size (8)
    0x95, 0x02,             //     Report Count (2)
    0xB1, 0x02,             //     Feature (Data, Var, Abs)
    0xC0,                   //   End Collection
    0xC0,                   // End Collection
];

fn descriptor() -> Vec<u8> {
    [HEAD, FINGER, FINGER, TAIL].concat()
}

const STAGE: DVec2 = DVec2::new(400.0, 300.0);
const REPORT_LEN: usize = 1 + 2 * 7 + 2 + 1;

/// One finger slot: tip, contact id, x, y, pressure.
type Slot = (bool, u8, u16, u16, u8);

const EMPTY: Slot = (false, 0, 0, 0, 0);

fn report(slots: [Slot; 2], scan: u16, count: u8) -> Vec<u8> {
    let mut bytes = vec![0x01];
    for (tip, id, x, y, pressure) in slots {
        bytes.push(u8::from(tip));
        bytes.push(id);
        bytes.extend(x.to_le_bytes());
        bytes.extend(y.to_le_bytes());
        bytes.push(pressure);
    }
    bytes.extend(scan.to_le_bytes());
    bytes.push(count);
    assert_eq!(bytes.len(), REPORT_LEN);
    bytes
}

fn decoder() -> HidTouchDecoder {
    HidTouchDecoder::new(&descriptor(), SourceId::new("hid0"), None, STAGE).unwrap()
}

/// (id, phase) of every contact, in frame order.
fn phases(frame: &ContactFrame) -> Vec<(u32, Phase)> {
    frame.contacts.iter().map(|c| (c.id, c.phase)).collect()
}

fn push(decoder: &mut HidTouchDecoder, bytes: &[u8], time: f64) -> ContactFrame {
    decoder
        .push(bytes, time)
        .unwrap()
        .expect("the report completes a frame that changes something")
}

#[test]
fn layout_reads_the_descriptor() {
    let layout = TouchLayout::parse(&descriptor()).unwrap();
    assert_eq!(layout.surface, Surface::TouchScreen);
    assert_eq!(layout.report_id, Some(1));
    assert_eq!(layout.report_len, REPORT_LEN);
    assert_eq!(layout.fingers.len(), 2);
    let second = &layout.fingers[1];
    // Bits count from the report id byte: finger 1 takes bytes 1..8.
    assert_eq!(second.tip_switch.bits, 64..65);
    assert_eq!(second.contact_id.bits, 72..80);
    assert_eq!(second.x.bits, 80..96);
    assert_eq!((second.x.logical_min, second.x.logical_max), (0, 4095));
    assert_eq!(second.y.bits, 96..112);
    assert_eq!(second.tip_pressure.as_ref().unwrap().logical_max, 255);
    assert_eq!(layout.scan_time.as_ref().unwrap().bits, 120..136);
    assert_eq!(layout.contact_count.as_ref().unwrap().bits, 136..144);

    let mode = layout.input_mode.as_ref().unwrap();
    assert_eq!(mode.report_id, Some(3));
    assert_eq!(mode.report_len, 3);
    assert_eq!(
        mode.multi_input_report(),
        vec![3, InputMode::MULTI_INPUT as u8, 0]
    );
    // Read-modify-write keeps the Device Index.
    let mut current = vec![3, 0, 7];
    mode.set(&mut current, InputMode::MULTI_INPUT).unwrap();
    assert_eq!(current, vec![3, 2, 7]);
    assert!(matches!(
        mode.set(&mut [3, 0], 2),
        Err(HidError::ShortReport {
            expected: 3,
            got: 2,
            ..
        })
    ));
}

#[test]
fn parallel_mode_down_move_up() {
    let mut d = decoder();
    let a = (true, 5, 100, 200, 128);
    let b = (true, 9, 3000, 1000, 255);
    let frame = push(&mut d, &report([a, b], 100, 2), 1.0);
    assert_eq!(frame.source.as_str(), "hid0");
    assert_eq!(frame.time, 1.0);
    assert_eq!(phases(&frame), [(5, Phase::Down), (9, Phase::Down)]);
    assert!((frame.contacts[1].pressure.unwrap() - 1.0).abs() < 1e-12);

    // Restating the same contacts is not news.
    assert_eq!(d.push(&report([a, b], 110, 2), 1.01).unwrap(), None);

    let a2 = (true, 5, 150, 200, 128);
    let frame = push(&mut d, &report([a2, b], 120, 2), 1.02);
    assert_eq!(phases(&frame), [(5, Phase::Move)]);

    // Lifting reports the finger once with its tip switch off.
    let frame = push(&mut d, &report([(false, 5, 150, 200, 0), b], 130, 2), 1.03);
    assert_eq!(phases(&frame), [(5, Phase::Up)]);

    let frame = push(&mut d, &report([(false, 9, 0, 0, 0), EMPTY], 140, 1), 1.04);
    assert_eq!(phases(&frame), [(9, Phase::Up)]);
    // Up carries the last position while down, not the zeroes of the lift.
    let up = &frame.contacts[0];
    assert!(
        (up.position - DVec2::new(3000.0 / 4095.0 * 400.0, 300.0 - 1000.0 / 4095.0 * 300.0))
            .length()
            < 1e-9
    );

    // Slots past the contact count are ignored, whatever they hold.
    assert_eq!(
        d.push(&report([EMPTY, (true, 3, 1, 1, 1)], 150, 0), 1.05)
            .unwrap(),
        None
    );
}

#[test]
fn hybrid_mode_four_fingers_over_two_reports() {
    let mut d = decoder();
    let f = |id: u8| (true, id, 100 * u16::from(id), 50, 10);
    assert_eq!(d.push(&report([f(1), f(2)], 500, 4), 2.0).unwrap(), None);
    let frame = push(&mut d, &report([f(3), f(4)], 500, 0), 2.001);
    assert_eq!(frame.time, 2.001);
    assert_eq!(
        phases(&frame),
        [
            (1, Phase::Down),
            (2, Phase::Down),
            (3, Phase::Down),
            (4, Phase::Down)
        ]
    );

    // Next frame: three fingers, so the second report has one valid slot;
    // finger 2 is not reported and is lifted.
    let moved = (true, 4, 999, 50, 10);
    assert_eq!(d.push(&report([f(1), f(3)], 600, 3), 2.01).unwrap(), None);
    let frame = push(&mut d, &report([moved, (true, 2, 1, 1, 1)], 600, 0), 2.011);
    assert_eq!(phases(&frame), [(4, Phase::Move), (2, Phase::Up)]);

    // A continuation from another scan means a report was lost: nothing
    // is applied, and the next full frame carries on.
    assert_eq!(d.push(&report([f(1), f(3)], 700, 3), 2.02).unwrap(), None);
    assert_eq!(d.push(&report([moved, EMPTY], 800, 0), 2.03).unwrap(), None);
    let frame = push(&mut d, &report([f(1), EMPTY], 900, 1), 2.04);
    assert_eq!(phases(&frame), [(3, Phase::Up), (4, Phase::Up)]);
}

#[test]
fn tip_switch_off_lifts() {
    let mut d = decoder();
    push(&mut d, &report([(true, 7, 10, 10, 5), EMPTY], 1, 1), 0.0);
    let frame = push(&mut d, &report([(false, 7, 10, 10, 0), EMPTY], 2, 1), 0.01);
    assert_eq!(phases(&frame), [(7, Phase::Up)]);
    // The id is free again.
    let frame = push(&mut d, &report([(true, 7, 20, 20, 5), EMPTY], 3, 1), 0.02);
    assert_eq!(phases(&frame), [(7, Phase::Down)]);
}

#[test]
fn missing_ids_lift() {
    let mut d = decoder();
    push(
        &mut d,
        &report([(true, 1, 10, 10, 5), (true, 2, 20, 20, 5)], 1, 2),
        0.0,
    );
    // The device never sent finger 2's tip-off report.
    let frame = push(&mut d, &report([(true, 1, 11, 10, 5), EMPTY], 2, 1), 0.01);
    assert_eq!(phases(&frame), [(1, Phase::Move), (2, Phase::Up)]);
    // A zero count with nothing pending means nothing is down.
    let frame = push(&mut d, &report([EMPTY, EMPTY], 3, 0), 0.02);
    assert_eq!(phases(&frame), [(1, Phase::Up)]);
}

#[test]
fn malformed_reports_are_errors() {
    let mut d = decoder();
    push(&mut d, &report([(true, 1, 10, 10, 5), EMPTY], 1, 1), 0.0);

    assert!(matches!(d.push(&[], 0.1), Err(HidError::EmptyReport)));
    let short = &report([EMPTY, EMPTY], 2, 0)[..10];
    let err = d.push(short, 0.1).unwrap_err();
    assert!(matches!(
        err,
        HidError::ShortReport {
            report_id: Some(1),
            expected: 18,
            got: 10
        }
    ));
    assert!(err.to_string().contains("report id 1"), "{err}");
    let err = d.push(&[0x42, 0, 0], 0.1).unwrap_err();
    assert!(matches!(err, HidError::UnknownReport { id: 0x42 }), "{err}");
    let twice = report([(true, 4, 1, 1, 1), (true, 4, 2, 2, 2)], 3, 2);
    let err = d.push(&twice, 0.1).unwrap_err();
    assert!(
        matches!(err, HidError::DuplicateContact { id: 4, .. }),
        "{err}"
    );

    // None of that disturbed the state: contact 1 is still down.
    let frame = push(&mut d, &report([EMPTY, EMPTY], 4, 0), 0.2);
    assert_eq!(phases(&frame), [(1, Phase::Up)]);
}

#[test]
fn descriptor_without_touch_collection_is_an_error() {
    #[rustfmt::skip]
    let mouse: &[u8] = &[
        0x05, 0x01, 0x09, 0x02, 0xA1, 0x01, 0x09, 0x01, 0xA1, 0x00,
        0x05, 0x09, 0x19, 0x01, 0x29, 0x03, 0x15, 0x00, 0x25, 0x01,
        0x95, 0x03, 0x75, 0x01, 0x81, 0x02, 0x95, 0x01, 0x75, 0x05, 0x81, 0x03,
        0x05, 0x01, 0x09, 0x30, 0x09, 0x31, 0x15, 0x81, 0x25, 0x7F,
        0x75, 0x08, 0x95, 0x02, 0x81, 0x06, 0xC0, 0xC0,
    ];
    let err = HidTouchDecoder::new(mouse, SourceId::new("m"), None, STAGE).unwrap_err();
    assert!(matches!(err, HidError::NoTouchCollection), "{err}");
    assert!(err.to_string().contains("touch screen"), "{err}");

    let err = TouchLayout::parse(&[]).unwrap_err();
    assert!(err.to_string().contains("empty"), "{err}");
    // A collection that never closes.
    let err = TouchLayout::parse(&[0x05, 0x0D, 0x09, 0x04, 0xA1, 0x01, 0xC0, 0xC0]).unwrap_err();
    assert!(matches!(err, HidError::Descriptor(_)), "{err}");
}

#[test]
fn finger_without_contact_id_is_an_error() {
    // Replace the Contact Identifier usage with an undefined one (0x00).
    let mut finger = FINGER.to_vec();
    let at = finger.windows(2).position(|w| w == [0x09, 0x51]).unwrap();
    finger[at + 1] = 0x3F;
    let descriptor = [HEAD, &finger, FINGER, TAIL].concat();
    let err = TouchLayout::parse(&descriptor).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("finger 1") && text.contains("Contact Identifier"),
        "{text}"
    );
}

#[test]
fn default_calibration_flips_y() {
    let mut d = decoder();
    let corners = [(0, 0), (4095, 0), (0, 4095), (4095, 4095)];
    let frame = push(
        &mut d,
        &report(
            [
                (true, 1, corners[0].0, corners[0].1, 0),
                (true, 2, corners[3].0, corners[3].1, 0),
            ],
            1,
            2,
        ),
        0.0,
    );
    // HID top-left is the stage's top-left: (0, height) in y-up stage space.
    assert!((frame.contacts[0].position - DVec2::new(0.0, 300.0)).length() < 1e-9);
    assert!((frame.contacts[1].position - DVec2::new(400.0, 0.0)).length() < 1e-9);
    let frame = push(
        &mut d,
        &report([(true, 1, 4095, 0, 0), (true, 2, 0, 4095, 0)], 2, 2),
        0.1,
    );
    assert!((frame.contacts[0].position - DVec2::new(400.0, 300.0)).length() < 1e-9);
    assert!((frame.contacts[1].position - DVec2::new(0.0, 0.0)).length() < 1e-9);
}

#[test]
fn explicit_calibration_is_used() {
    // Only the middle half of the device maps onto a 2 × 1 stage.
    let calibration =
        Calibration::fit([1024.0, 3072.0], [1024.0, 3072.0], DVec2::new(2.0, 1.0)).unwrap();
    let mut d = HidTouchDecoder::new(
        &descriptor(),
        SourceId::new("hid0"),
        Some(calibration),
        STAGE,
    )
    .unwrap();
    let frame = push(
        &mut d,
        &report([(true, 1, 2048, 1024, 0), EMPTY], 1, 1),
        0.0,
    );
    assert!((frame.contacts[0].position - DVec2::new(1.0, 1.0)).length() < 1e-9);
}

// hid-recorder captures, replay and device I/O.

fn fixture(name: &str) -> PathBuf {
    puppetry_testkit::root().join("tests/fixtures").join(name)
}

/// The same touch screen with one finger slot, so two fingers take two
/// reports: hybrid mode.
fn one_slot_descriptor() -> Vec<u8> {
    [HEAD, FINGER, TAIL].concat()
}

/// A report with as many slots as given (1 or 2).
fn report_of(slots: &[Slot], scan: u16, count: u8) -> Vec<u8> {
    let mut bytes = vec![0x01];
    for &(tip, id, x, y, pressure) in slots {
        bytes.push(u8::from(tip));
        bytes.push(id);
        bytes.extend(x.to_le_bytes());
        bytes.extend(y.to_le_bytes());
        bytes.push(pressure);
    }
    bytes.extend(scan.to_le_bytes());
    bytes.push(count);
    bytes
}

const DRAG_FRAMES: usize = 13;
const FINGER_A: u8 = 3;
const FINGER_B: u8 = 8;
const PRESSURE: u8 = 100;

/// Frame `k`'s time, minus `early_us` microseconds; worked out in whole
/// microseconds so it survives the capture's six decimals exactly.
fn drag_time_us(k: usize, early_us: usize) -> f64 {
    (1_000_000 + 10_000 * k - early_us) as f64 / 1e6
}

fn drag_time(k: usize) -> f64 {
    drag_time_us(k, 0)
}

fn a_at(k: usize) -> (u16, u16) {
    (1000 + 50 * k as u16, 1500)
}

fn b_at(k: usize) -> (u16, u16) {
    (1000 + 50 * k as u16, 2500 - 20 * k as u16)
}

/// The finger slots of frame `k` of the drag: both fingers down and moving
/// right for frames 0..=9; A lifts in frame 10 while B moves on; B alone in
/// 11; B lifts in 12. A lift report repeats the last position.
fn drag_slots(k: usize) -> Vec<Slot> {
    let slot = |tip, id, (x, y): (u16, u16)| (tip, id, x, y, if tip { PRESSURE } else { 0 });
    match k {
        0..=9 => vec![slot(true, FINGER_A, a_at(k)), slot(true, FINGER_B, b_at(k))],
        10 => vec![
            slot(false, FINGER_A, a_at(9)),
            slot(true, FINGER_B, b_at(10)),
        ],
        11 => vec![slot(true, FINGER_B, b_at(11))],
        _ => vec![slot(false, FINGER_B, b_at(11))],
    }
}

/// The drag as hid-recorder would capture it from the two-slot screen
/// (parallel: one report per frame) or the one-slot screen (hybrid: a
/// two-finger frame is two reports, the second completing it at the frame's
/// time).
fn drag_recording(hybrid: bool) -> HidRecording {
    let mut reports = Vec::new();
    for k in 0..DRAG_FRAMES {
        let slots = drag_slots(k);
        let scan = 100 * k as u16;
        let count = slots.len() as u8;
        if hybrid {
            for (i, slot) in slots.iter().enumerate() {
                let time = drag_time_us(k, 500 * (slots.len() - 1 - i));
                let count = if i == 0 { count } else { 0 };
                reports.push((time, report_of(&[*slot], scan, count)));
            }
        } else {
            let mut padded = slots.clone();
            padded.resize(2, EMPTY);
            reports.push((drag_time(k), report_of(&padded, scan, count)));
        }
    }
    let mode = if hybrid { "hybrid" } else { "parallel" };
    HidRecording {
        name: format!("puppetry synthetic touch screen ({mode})"),
        phys: "synthetic/input0".to_string(),
        bus: 0x18,
        vendor: 0x1234,
        product: if hybrid { 0x0002 } else { 0x0001 },
        descriptor: if hybrid {
            one_slot_descriptor()
        } else {
            descriptor()
        },
        reports,
    }
}

fn fixture_name(hybrid: bool) -> &'static str {
    if hybrid {
        "touch-hybrid.hid"
    } else {
        "touch-parallel.hid"
    }
}

/// Regenerates the committed captures:
/// `cargo test --release --test hid -- --ignored write_drag_fixtures`.
#[test]
#[ignore]
fn write_drag_fixtures() {
    for hybrid in [false, true] {
        let mut text = Vec::new();
        drag_recording(hybrid).write(&mut text).unwrap();
        std::fs::write(fixture(fixture_name(hybrid)), text).unwrap();
    }
}

#[test]
fn fixtures_are_the_drag_captures() {
    for hybrid in [false, true] {
        let read = HidRecording::read(&fixture(fixture_name(hybrid))).unwrap();
        assert_eq!(read, drag_recording(hybrid), "{}", fixture_name(hybrid));
    }
}

/// What the drag must play as: (time, [(id, phase, device x, device y)]).
/// One expected contact: id, phase, device position.
type Expected = (u32, Phase, (u16, u16));

fn expected_drag() -> Vec<(f64, Vec<Expected>)> {
    let (a, b) = (u32::from(FINGER_A), u32::from(FINGER_B));
    (0..DRAG_FRAMES)
        .map(|k| {
            let contacts = match k {
                0 => vec![(a, Phase::Down, a_at(0)), (b, Phase::Down, b_at(0))],
                1..=9 => vec![(a, Phase::Move, a_at(k)), (b, Phase::Move, b_at(k))],
                10 => vec![(a, Phase::Up, a_at(9)), (b, Phase::Move, b_at(10))],
                11 => vec![(b, Phase::Move, b_at(11))],
                _ => vec![(b, Phase::Up, b_at(11))],
            };
            (drag_time(k), contacts)
        })
        .collect()
}

fn assert_drag(frames: &[ContactFrame], source: &str) {
    let fit = Calibration::fit([0.0, 4095.0], [0.0, 4095.0], STAGE).unwrap();
    let expected = expected_drag();
    assert_eq!(frames.len(), expected.len());
    for (frame, (time, contacts)) in frames.iter().zip(&expected) {
        assert_eq!(frame.source.as_str(), source);
        assert!((frame.time - time).abs() < 1e-9, "{} vs {time}", frame.time);
        assert_eq!(frame.contacts.len(), contacts.len(), "at {time}");
        for (got, &(id, phase, (x, y))) in frame.contacts.iter().zip(contacts) {
            assert_eq!((got.id, got.phase), (id, phase), "at {time}");
            let want = fit.map(DVec2::new(f64::from(x), f64::from(y)));
            assert!((got.position - want).length() < 1e-9, "at {time}");
            let pressure = got.pressure.unwrap();
            assert!((pressure - f64::from(PRESSURE) / 255.0).abs() < 1e-12);
        }
    }
}

#[test]
fn parallel_and_hybrid_captures_replay_the_same_drag() {
    let parallel: Vec<ContactFrame> = ReplaySource::open(&fixture("touch-parallel.hid"), STAGE)
        .unwrap()
        .frames()
        .collect();
    let hybrid: Vec<ContactFrame> = ReplaySource::open(&fixture("touch-hybrid.hid"), STAGE)
        .unwrap()
        .frames()
        .collect();
    assert_drag(&parallel, "replay");
    assert_eq!(parallel, hybrid);
}

/// Writes `recording` to a temporary file without the `.hid` extension.
fn unnamed_capture(recording: &HidRecording) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("capture.txt");
    let mut text = Vec::new();
    recording.write(&mut text).unwrap();
    std::fs::write(&path, text).unwrap();
    (dir, path)
}

#[test]
fn a_capture_is_recognised_by_content_and_contacts_left_down_are_lifted() {
    for hybrid in [false, true] {
        let mut cut = drag_recording(hybrid);
        // Keep frames 0..=4: both fingers still down at the end.
        let last = drag_time(4);
        cut.reports.retain(|(time, _)| *time <= last + 1e-9);
        let (_dir, path) = unnamed_capture(&cut);
        let calibration =
            Calibration::fit([0.0, 4095.0], [0.0, 4095.0], DVec2::new(2.0, 1.0)).unwrap();
        let source = ReplaySource::open_with(
            &path,
            SourceId::new("table"),
            STAGE,
            Some(calibration.clone()),
        )
        .unwrap();
        let frames: Vec<ContactFrame> = source.frames().collect();
        assert_eq!(frames.len(), 6);
        let end = frames.last().unwrap();
        assert_eq!(end.source.as_str(), "table");
        assert!((end.time - last).abs() < 1e-9);
        assert_eq!(
            phases(end),
            [
                (u32::from(FINGER_A), Phase::Up),
                (u32::from(FINGER_B), Phase::Up)
            ]
        );
        let (x, y) = b_at(4);
        let want = calibration.map(DVec2::new(f64::from(x), f64::from(y)));
        assert!((end.contacts[1].position - want).length() < 1e-12);
    }
}

#[test]
fn a_capture_led_by_a_device_line_is_sniffed_too() {
    let mut text = Vec::new();
    drag_recording(false).write(&mut text).unwrap();
    let text = format!(
        "# two devices would differ\nD: 0\n{}",
        String::from_utf8(text).unwrap()
    );
    let frames: Vec<ContactFrame> =
        ReplaySource::parse("mem", &text, SourceId::new("replay"), STAGE, None)
            .unwrap()
            .frames()
            .collect();
    assert_drag(&frames, "replay");
}

#[test]
fn a_bad_report_in_a_capture_fails_the_open_with_its_place() {
    let mut capture = drag_recording(false);
    capture.reports[3].1.truncate(10);
    let (_dir, path) = unnamed_capture(&capture);
    let err = ReplaySource::open(&path, STAGE).unwrap_err();
    assert!(
        matches!(err, ReplayError::HidReport { index: 4, .. }),
        "{err}"
    );
    let text = err.to_string();
    assert!(
        text.contains("capture.txt") && text.contains("report 4"),
        "{text}"
    );

    // A descriptor that is no touch screen fails as well, naming the file.
    capture.descriptor = vec![0x05, 0x01, 0x09, 0x02, 0xA1, 0x01, 0xC0];
    let (_dir, path) = unnamed_capture(&capture);
    let err = ReplaySource::open(&path, STAGE).unwrap_err();
    assert!(matches!(err, ReplayError::HidDevice { .. }), "{err}");
    assert!(err.to_string().contains("capture.txt"), "{err}");
}

#[test]
fn hid_recorder_text_parses_and_round_trips() {
    // As hid-recorder writes it: descriptor comments, a wrapped R: line, a
    // name with a `#`, decoded-report comments between events.
    let d = descriptor();
    let hex = |bytes: &[u8]| {
        bytes
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let first = report([(true, 5, 100, 200, 128), EMPTY], 7, 1);
    let second = report([(false, 5, 100, 200, 0), EMPTY], 8, 1);
    let text = format!(
        "# ACME Touch #2\n\
         # 0x05, 0x0d,  // Usage Page (Digitizers)  0\n\
         #\n\
         D: 0\n\
         R: {len} {head}\n\
         {tail}\n\
         N: ACME Touch #2\n\
         P: usb-0000:00:14.0-4/input0\n\
         I: 3 0eef 7224\n\
         # ReportID: 1 / Tip Switch: 1 | Contact Id: 5\n\
         E: 000012.500000 {n} {first}\n\
         \n\
         E: 000012.508123 {n} {second}\n",
        len = d.len(),
        head = hex(&d[..40]),
        tail = hex(&d[40..]),
        n = REPORT_LEN,
        first = hex(&first),
        second = hex(&second),
    );
    let recording = HidRecording::parse("touch.hid", &text).unwrap();
    assert_eq!(recording.name, "ACME Touch #2");
    assert_eq!(recording.phys, "usb-0000:00:14.0-4/input0");
    assert_eq!(
        (recording.bus, recording.vendor, recording.product),
        (3, 0x0eef, 0x7224)
    );
    assert_eq!(recording.descriptor, d);
    assert_eq!(
        recording.reports,
        vec![(12.5, first.clone()), (12.508123, second.clone())]
    );

    let mut written = Vec::new();
    recording.write(&mut written).unwrap();
    let written = String::from_utf8(written).unwrap();
    assert!(written.contains("\nI: 3 0eef 7224\n"), "{written}");
    assert!(
        written.contains("\nE: 000012.508123 18 01 00 05"),
        "{written}"
    );
    assert_eq!(HidRecording::parse("again", &written).unwrap(), recording);

    // A line break in the name cannot start a new item.
    let odd = HidRecording {
        name: "two\nE: lines".to_string(),
        ..recording.clone()
    };
    let mut written = Vec::new();
    odd.write(&mut written).unwrap();
    let back = HidRecording::parse("odd", std::str::from_utf8(&written).unwrap()).unwrap();
    assert_eq!(
        (back.name.as_str(), back.reports.len()),
        ("two E: lines", 2)
    );
}

fn parse_error(text: &str) -> (usize, &'static str, String) {
    match HidRecording::parse("bad.hid", text).unwrap_err() {
        e @ HidRecordingError::Line(puppetry_input::LineError { line, field, .. }) => {
            (line, field, e.to_string())
        }
        other => panic!("expected a line error, got {other}"),
    }
}

#[test]
fn bad_captures_name_their_line_and_field() {
    let r = "R: 3 05 0d 09\n";
    let cases: &[(&str, usize, &str)] = &[
        ("# x\nE: 000000.000000 1 01\n", 2, "line"),
        ("R: 3 05 0d\nN: cut short\n", 1, "descriptor bytes"),
        ("R: 2 05 0d 09\n", 1, "descriptor bytes"),
        ("R: x 05\n", 1, "length"),
        ("R: 3 05 0d\n0g\n", 2, "descriptor bytes"),
        (&format!("{r}E: 000000.000000 2 01 zz\n"), 2, "report bytes"),
        (&format!("{r}E: 1.5 1 01\nE: 1.25 1 01\n"), 3, "time"),
        (&format!("{r}E: -1.0 1 01\n"), 2, "time"),
        (&format!("{r}E: 000000.000000 0\n"), 2, "length"),
        (&format!("{r}I: 3 xyz 0001\n"), 2, "vendor"),
        (&format!("{r}I: 3 0001\n"), 2, "product"),
        (&format!("{r}I: 3 0001 0002 0003\n"), 2, "line"),
        (&format!("D: 0\n{r}D: 1\n"), 3, "device index"),
        (&format!("{r}R: 1 c0\n"), 2, "line"),
        (&format!("{r}X: 1\n"), 2, "line"),
        (&format!("{r}05 0d\n"), 2, "line"),
    ];
    for &(text, line, field) in cases {
        let (got_line, got_field, message) = parse_error(text);
        assert_eq!((got_line, got_field), (line, field), "{text:?}: {message}");
        assert!(
            message.starts_with(&format!("bad.hid:{line}: {field}: ")),
            "{message}"
        );
    }
    let err = HidRecording::parse("empty.hid", "# nothing\nN: x\n").unwrap_err();
    assert!(
        matches!(err, HidRecordingError::NoDescriptor { .. }),
        "{err}"
    );
    assert!(err.to_string().starts_with("empty.hid: "), "{err}");
    let err = HidRecording::read(Path::new("/nonexistent/touch.hid")).unwrap_err();
    assert!(
        matches!(&err, HidRecordingError::File(e) if e.io_kind().is_some()),
        "{err}"
    );
}

fn info(
    path: &str,
    vendor: u16,
    product: u16,
    serial: &str,
    page: u16,
    usage: u16,
) -> HidDeviceInfo {
    HidDeviceInfo {
        path: path.to_string(),
        vendor_id: vendor,
        product_id: product,
        serial: (!serial.is_empty()).then(|| serial.to_string()),
        manufacturer: None,
        product: None,
        usage_page: page,
        usage,
        interface: 0,
    }
}

#[test]
fn selectors_pick_the_touch_interface_and_refuse_ambiguity() {
    let devices = [
        // A touch screen listed per top-level collection, with its mouse
        // fallback on another interface.
        info("/dev/hidraw1", 0x0eef, 0x7224, "A1", 0x01, 0x02),
        info("/dev/hidraw2", 0x0eef, 0x7224, "A1", 0x0D, 0x0E),
        info("/dev/hidraw2", 0x0eef, 0x7224, "A1", 0x0D, 0x04),
        // A second, identical screen.
        info("/dev/hidraw5", 0x0eef, 0x7224, "B2", 0x0D, 0x04),
        info("/dev/hidraw7", 0x046d, 0xc52b, "", 0x01, 0x06),
    ];
    assert!(devices[2].is_touch() && devices[1].is_digitizer() && !devices[1].is_touch());

    let by_serial = HidSelector {
        vendor_id: Some(0x0eef),
        serial: Some("A1".to_string()),
        ..HidSelector::default()
    };
    assert_eq!(by_serial.pick(&devices).unwrap().path, "/dev/hidraw2");
    assert!(by_serial.matches(&devices[0]) && !by_serial.matches(&devices[3]));

    let by_ids = HidSelector {
        vendor_id: Some(0x0eef),
        product_id: Some(0x7224),
        ..HidSelector::default()
    };
    let err = by_ids.pick(&devices).unwrap_err();
    assert!(
        matches!(&err, HidError::Ambiguous { paths, .. } if paths == &["/dev/hidraw2", "/dev/hidraw5"]),
        "{err}"
    );
    assert!(err.to_string().contains("0eef:7224"), "{err}");

    // A named path wins even when it is not the touch interface.
    let by_path = HidSelector {
        path: Some("/dev/hidraw1".to_string()),
        ..HidSelector::default()
    };
    assert_eq!(by_path.pick(&devices).unwrap().usage, 0x02);

    let missing = HidSelector {
        vendor_id: Some(0xdead),
        ..HidSelector::default()
    };
    let err = missing.pick(&devices).unwrap_err();
    assert!(matches!(err, HidError::NotFound { .. }), "{err}");
    assert!(err.to_string().contains("vendor dead"), "{err}");

    let hint = permission_hint(Some(0x0eef));
    assert!(hint.contains(r#"ATTRS{idVendor}=="0eef""#), "{hint}");
    assert!(hint.contains("plugdev"), "{hint}");
}

/// A device that plays back a capture's reports, then either fails like an
/// unplugged device or keeps timing out and raises a stop flag.
struct FakeDevice<'a> {
    descriptor: Vec<u8>,
    reports: RefCell<VecDeque<Vec<u8>>>,
    features: RefCell<Vec<Vec<u8>>>,
    reject_features: bool,
    /// When set, running out of reports stops the loop instead of failing.
    stop_when_done: Option<&'a AtomicBool>,
    /// Reads answered with a timeout, to show they are skipped.
    timeouts: RefCell<usize>,
}

impl<'a> FakeDevice<'a> {
    fn new(recording: &HidRecording, frames: usize) -> FakeDevice<'a> {
        // Frames are reports in parallel mode.
        FakeDevice {
            descriptor: recording.descriptor.clone(),
            reports: RefCell::new(
                recording.reports[..frames]
                    .iter()
                    .map(|(_, r)| r.clone())
                    .collect(),
            ),
            features: RefCell::new(Vec::new()),
            reject_features: false,
            stop_when_done: None,
            timeouts: RefCell::new(0),
        }
    }
}

impl ReportDevice for FakeDevice<'_> {
    fn descriptor(&self) -> Result<Vec<u8>, HidError> {
        Ok(self.descriptor.clone())
    }

    fn send_feature(&self, report: &[u8]) -> Result<(), HidError> {
        if self.reject_features {
            return Err(unplugged("feature rejected"));
        }
        self.features.borrow_mut().push(report.to_vec());
        Ok(())
    }

    fn read(&self, buf: &mut [u8], _timeout_ms: i32) -> Result<usize, HidError> {
        // Every other read times out.
        let mut timeouts = self.timeouts.borrow_mut();
        let reports = self.reports.borrow().len();
        if *timeouts < reports {
            *timeouts = reports;
            return Ok(0);
        }
        match self.reports.borrow_mut().pop_front() {
            Some(report) => {
                buf[..report.len()].copy_from_slice(&report);
                Ok(report.len())
            }
            None => match self.stop_when_done {
                Some(stop) => {
                    stop.store(true, Ordering::Relaxed);
                    Ok(0)
                }
                None => Err(unplugged("device disconnected")),
            },
        }
    }
}

fn unplugged(message: &str) -> HidError {
    HidError::Device {
        what: "reading an input report".to_string(),
        source: hidapi::HidError::HidApiError {
            message: message.to_string(),
        },
    }
}

fn drain(mut rx: mpsc::Receiver<ContactFrame>) -> Vec<ContactFrame> {
    let mut frames = Vec::new();
    while let Ok(frame) = rx.try_recv() {
        frames.push(frame);
    }
    frames
}

/// Compares frames ignoring time (run_device stamps its own clock).
fn same_contacts(got: &[ContactFrame], want: &[ContactFrame]) {
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(want) {
        assert_eq!(g.source, w.source);
        assert_eq!(g.contacts, w.contacts);
    }
}

#[test]
fn run_device_selects_multi_input_and_lifts_contacts_when_the_device_fails() {
    let recording = drag_recording(false);
    // Six frames in, both fingers are down when the device goes away.
    let device = FakeDevice::new(&recording, 6);
    let (tx, rx) = mpsc::channel(64);
    let stop = AtomicBool::new(false);
    let result = run_device(&device, SourceId::new("hid0"), None, STAGE, &tx, &stop);
    let err = result.unwrap_err();
    assert!(err.to_string().contains("device disconnected"), "{err}");
    // Report id 3: Input Mode 2 (multi-input), Device Index 0.
    assert_eq!(*device.features.borrow(), vec![vec![3, 2, 0]]);

    let frames = drain(rx);
    let mut want: Vec<ContactFrame> = ReplaySource::from_hid(
        "drag",
        &HidRecording {
            reports: recording.reports[..6].to_vec(),
            ..recording.clone()
        },
        SourceId::new("hid0"),
        STAGE,
        None,
    )
    .unwrap()
    .frames()
    .collect();
    assert_eq!(want.len(), 7, "six frames and the lift");
    same_contacts(&frames, &want);
    let lift = want.pop().unwrap();
    assert!(lift.contacts.iter().all(|c| c.phase == Phase::Up));
    assert!(frames.windows(2).all(|w| w[0].time <= w[1].time));
}

#[test]
fn run_device_stops_on_request_and_reads_on_when_the_mode_is_refused() {
    let recording = drag_recording(false);
    let stop = AtomicBool::new(false);
    let mut device = FakeDevice::new(&recording, 3);
    device.reject_features = true;
    device.stop_when_done = Some(&stop);
    let (tx, rx) = mpsc::channel(64);
    run_device(&device, SourceId::new("hid0"), None, STAGE, &tx, &stop).unwrap();
    assert!(device.features.borrow().is_empty());
    let frames = drain(rx);
    let phases: Vec<Vec<(u32, Phase)>> = frames.iter().map(phases).collect();
    let (a, b) = (u32::from(FINGER_A), u32::from(FINGER_B));
    assert_eq!(
        phases,
        [
            vec![(a, Phase::Down), (b, Phase::Down)],
            vec![(a, Phase::Move), (b, Phase::Move)],
            vec![(a, Phase::Move), (b, Phase::Move)],
            vec![(a, Phase::Up), (b, Phase::Up)],
        ]
    );

    // A closed channel ends the loop before anything is read.
    let device = FakeDevice::new(&recording, 3);
    let (tx, rx) = mpsc::channel(64);
    drop(rx);
    run_device(
        &device,
        SourceId::new("hid0"),
        None,
        STAGE,
        &tx,
        &AtomicBool::new(false),
    )
    .unwrap();
    assert_eq!(device.reports.borrow().len(), 3);
}

#[test]
fn a_device_without_report_ids_gets_a_zero_report_id_byte() {
    let mode = InputMode {
        report_id: None,
        report_len: 2,
        field: HidField {
            bits: 0..8,
            logical_min: 0,
            logical_max: 10,
        },
    };
    assert_eq!(mode.multi_input_report(), vec![2, 0]);
    assert_eq!(mode.multi_input_feature(), vec![0, 2, 0]);
    let numbered = TouchLayout::parse(&descriptor())
        .unwrap()
        .input_mode
        .unwrap();
    assert_eq!(
        numbered.multi_input_feature(),
        numbered.multi_input_report()
    );
}

/// Whatever this host has (nothing, in CI), listing works, each listed
/// interface is found again by its path, and opening what is not there
/// says so instead of panicking.
#[test]
fn listing_and_opening_without_hardware() {
    let devices = puppetry_input::hid::list_devices().unwrap();
    for device in &devices {
        let by_path = HidSelector {
            path: Some(device.path.clone()),
            ..HidSelector::default()
        };
        assert_eq!(by_path.pick(&devices).unwrap().path, device.path);
    }
    let nowhere = HidSelector {
        path: Some("/nonexistent/hidraw99".to_string()),
        ..HidSelector::default()
    };
    let err = puppetry_input::hid::open(&nowhere).unwrap_err();
    assert!(
        matches!(err, HidError::Device { .. }) && err.to_string().contains("hidraw99"),
        "{err}"
    );
}
