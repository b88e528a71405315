//! The HID digitizer decoder against a synthetic Windows-style touch screen:
//! report id 1 with two finger slots, scan time and contact count; report id
//! 2 a Contact Count Maximum feature; report id 3 the Input Mode feature.

use glam::DVec2;
use puppetry::input::hid::{HidError, HidTouchDecoder, InputMode, Surface, TouchLayout};
use puppetry::input::{Calibration, ContactFrame, Phase, SourceId};

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
