//! Fuzzing the input layer's parsers, everything a stranger can feed in:
//! TUIO datagrams off the network, serial pad bytes, HID descriptors and
//! reports, and the capture files replay reads (recordings, evemu,
//! hid-recorder). Random bytes plus mutations of valid inputs; every case
//! must end in a value or an error, never a panic; errors must say where
//! (file and line for files), and those about network and device input,
//! which are logged per packet, must stay short. See `docs/fuzzing.md`.

use glam::DVec2;
use proptest::prelude::*;
use puppetry_input::hid::{HidTouchDecoder, TouchLayout};
use puppetry_input::hid_recording::HidRecording;
use puppetry_input::recording::{RecordingError, parse_recording};
use puppetry_input::replay::{ReplayError, ReplaySource};
use puppetry_input::serial::{SerialDecoder, WireFormat};
use puppetry_input::tuio::{TuioTracker, default_calibration};
use puppetry_input::{Calibration, ContactFrame, LineError, SourceId};
use puppetry_testkit::fuzz::{self, config};
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};

const STAGE: DVec2 = DVec2::new(1280.0, 720.0);

/// No error about a packet may carry a flood of echoed input.
const MAX_MESSAGE: usize = 1000;

fn check_frames(frames: &[ContactFrame]) {
    for frame in frames {
        assert!(!frame.source.as_str().is_empty());
        for contact in &frame.contacts {
            assert!(
                !contact.position.is_nan(),
                "a decoded position is NaN: {frame:?}"
            );
        }
    }
}

fn check_message(message: &str) {
    assert!(
        message.chars().count() <= MAX_MESSAGE,
        "an error message of {} chars: {}…",
        message.len(),
        message.chars().take(200).collect::<String>()
    );
}

// ---------------------------------------------------------------- TUIO

fn osc_arg() -> impl Strategy<Value = OscType> {
    prop_oneof![
        any::<i32>().prop_map(OscType::Int),
        prop_oneof![
            any::<f32>(),
            Just(f32::NAN),
            Just(f32::INFINITY),
            Just(-1.0f32),
            Just(0.5f32),
            Just(1e30f32)
        ]
        .prop_map(OscType::Float),
        prop_oneof![any::<f64>(), Just(f64::NAN), Just(1e300)].prop_map(OscType::Double),
        prop_oneof![
            Just("source".to_string()),
            Just("alive".to_string()),
            Just("set".to_string()),
            Just("fseq".to_string()),
            Just(String::new()),
            "[a-z@:0-9]{0,8}",
            Just("x".repeat(3000)),
        ]
        .prop_map(OscType::String),
        (any::<u32>(), any::<u32>()).prop_map(|t| OscType::Time(OscTime::from(t))),
        any::<i64>().prop_map(OscType::Long),
        proptest::collection::vec(any::<u8>(), 0..8).prop_map(OscType::Blob),
        any::<bool>().prop_map(OscType::Bool),
        Just(OscType::Nil),
        Just(OscType::Inf),
    ]
}

fn osc_message() -> impl Strategy<Value = OscPacket> {
    (
        prop_oneof![
            Just("/tuio/2Dcur"),
            Just("/tuio2/frm"),
            Just("/tuio2/ptr"),
            Just("/tuio2/alv"),
            Just("/tuio/2Dobj"),
            Just("/"),
        ],
        proptest::collection::vec(osc_arg(), 0..12),
    )
        .prop_map(|(addr, args)| {
            OscPacket::Message(OscMessage {
                addr: addr.to_string(),
                args,
            })
        })
}

fn osc_packet() -> impl Strategy<Value = OscPacket> {
    osc_message().prop_recursive(4, 32, 8, |inner| {
        (
            (any::<u32>(), any::<u32>()),
            proptest::collection::vec(inner, 0..8),
        )
            .prop_map(|(time, content)| {
                OscPacket::Bundle(OscBundle {
                    timetag: OscTime::from(time),
                    content,
                })
            })
    })
}

/// Real TUIO 1.1 and 2.0 bundles, for byte-level mutation.
fn tuio_seeds() -> Vec<Vec<u8>> {
    use puppetry_testkit::tuio::*;
    vec![
        v1(None, &[1, 2], &[(1, 0.25, 0.5), (2, 0.75, 0.5)], 7),
        v1(Some("table@host"), &[], &[], -1),
        bundle(vec![
            msg(
                "/tuio2/frm",
                vec![
                    OscType::Int(3),
                    OscType::Time(OscTime::from((1, 2))),
                    OscType::Int(0),
                    OscType::String("tracker".into()),
                ],
            ),
            msg(
                "/tuio2/ptr",
                vec![
                    OscType::Int(5),
                    OscType::Int(0),
                    OscType::Int(0),
                    OscType::Float(0.5),
                    OscType::Float(0.5),
                    OscType::Float(0.0),
                    OscType::Float(0.0),
                    OscType::Float(0.0),
                    OscType::Float(0.7),
                ],
            ),
            msg("/tuio2/alv", vec![OscType::Int(5)]),
        ]),
    ]
}

fn tracker() -> TuioTracker {
    TuioTracker::new(default_calibration(STAGE).unwrap())
}

fn push_all(datagrams: &[Vec<u8>]) {
    let mut tracker = tracker();
    for (i, datagram) in datagrams.iter().enumerate() {
        match tracker.push(datagram, i as f64) {
            Ok(frames) => check_frames(&frames),
            Err(e) => {
                let message = e.to_string();
                assert!(message.starts_with("tuio: "), "{message}");
                check_message(&message);
            }
        }
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_tuio_random_datagrams(datagrams in proptest::collection::vec(fuzz::bytes(256), 1..4)) {
        push_all(&datagrams);
    }

    #[test]
    fn fuzz_tuio_structured_packets(packets in proptest::collection::vec(osc_packet(), 1..6)) {
        let datagrams: Vec<Vec<u8>> = packets
            .iter()
            .filter_map(|p| rosc::encoder::encode(p).ok())
            .collect();
        push_all(&datagrams);
    }

    #[test]
    fn fuzz_tuio_mutated_bundles(datagrams in proptest::collection::vec(fuzz::mutated_bytes(tuio_seeds()), 1..4)) {
        push_all(&datagrams);
    }
}

// -------------------------------------------------------------- serial

fn serial_decoder(format: WireFormat) -> SerialDecoder {
    let calibration = Calibration::fit([0.0, 1000.0], [0.0, 1000.0], STAGE).unwrap();
    SerialDecoder::new(format, calibration, SourceId::from("pad"))
}

fn slip(packet: &OscPacket) -> Vec<u8> {
    let mut out = vec![0xC0];
    for b in rosc::encoder::encode(packet).unwrap() {
        match b {
            0xC0 => out.extend([0xDB, 0xDC]),
            0xDB => out.extend([0xDB, 0xDD]),
            b => out.push(b),
        }
    }
    out.push(0xC0);
    out
}

fn serial_seeds(format: WireFormat) -> Vec<Vec<u8>> {
    match format {
        WireFormat::Csv => vec![
            b"1,d,10,20\n2,down,500,500,0.5\nf\n1,m,11,21\n\n1,u,11,21\r\n2,UP,1,1\nf\n".to_vec(),
        ],
        WireFormat::SlipOsc => {
            let contact = |id: i32, phase: &str, x: f32, y: f32| {
                OscPacket::Message(OscMessage {
                    addr: "/pad/contact".into(),
                    args: vec![
                        OscType::Int(id),
                        OscType::String(phase.into()),
                        OscType::Float(x),
                        OscType::Float(y),
                        OscType::Float(0.5),
                    ],
                })
            };
            let frame = OscPacket::Message(OscMessage {
                addr: "/pad/frame".into(),
                args: vec![],
            });
            let mut stream = Vec::new();
            for packet in [
                contact(1, "d", 10.0, 20.0),
                frame.clone(),
                contact(1, "m", 11.0, 21.0),
                contact(1, "u", 11.0, 21.0),
                frame,
            ] {
                stream.extend(slip(&packet));
            }
            vec![stream]
        }
    }
}

/// Feeds `bytes` in `chunk`-sized reads, as a port delivers them.
fn feed_serial(format: WireFormat, bytes: &[u8], chunk: usize) {
    let mut decoder = serial_decoder(format);
    for piece in bytes.chunks(chunk.max(1)) {
        for item in decoder.push(piece) {
            match item {
                Ok(frame) => check_frames(&[frame]),
                Err(e) => {
                    let message = e.to_string();
                    assert!(message.starts_with("serial: "), "{message}");
                    check_message(&message);
                }
            }
        }
    }
    let _ = decoder.lift_all();
}

fn wire_format() -> impl Strategy<Value = WireFormat> {
    prop_oneof![Just(WireFormat::Csv), Just(WireFormat::SlipOsc)]
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_serial_random_bytes(format in wire_format(), bytes in fuzz::bytes(600), chunk in 1usize..64) {
        feed_serial(format, &bytes, chunk);
    }

    #[test]
    fn fuzz_serial_mutated_streams(
        (format, bytes) in wire_format().prop_flat_map(|f| (Just(f), fuzz::mutated_bytes(serial_seeds(f)))),
        chunk in 1usize..64,
    ) {
        feed_serial(format, &bytes, chunk);
    }
}

// ---------------------------------------------------------- recordings

fn recording_seeds() -> Vec<String> {
    let wave =
        std::fs::read_to_string(puppetry_testkit::root().join("assets/gingerbread/wave.jsonl"))
            .expect("the wave recording");
    let head: String = wave.lines().take(6).map(|l| format!("{l}\n")).collect();
    vec![
        head,
        concat!(
            "{\"t\":0.5,\"source\":\"pen\",\"contacts\":[{\"id\":7,\"phase\":\"down\",\"x\":1.5,",
            "\"y\":-2,\"pressure\":0.25,\"tilt\":[0.1,-0.2],\"angle\":1.0}]}\n",
            "\n{\"t\":0.6,\"source\":\"pen\",\"contacts\":[]}\n",
        )
        .to_string(),
    ]
}

fn check_recording(text: &str) {
    match parse_recording("fuzz.jsonl", text) {
        Ok(frames) => check_frames(&frames),
        Err(e) => {
            let message = e.to_string();
            match e {
                RecordingError::Line { file, line, .. } => {
                    assert_eq!(file, "fuzz.jsonl");
                    assert!(
                        line >= 1 && line <= text.lines().count().max(1),
                        "{message}"
                    );
                    assert!(
                        message.starts_with(&format!("fuzz.jsonl:{line}: ")),
                        "{message}"
                    );
                }
                other => panic!("a parse error that names no line: {other}"),
            }
        }
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_recording_random_text(text in fuzz::text(400)) {
        check_recording(&text);
    }

    #[test]
    fn fuzz_recording_mutated_lines(text in fuzz::mutated_text(recording_seeds())) {
        check_recording(&text);
    }

    #[test]
    fn fuzz_recording_mutated_fields(
        lines in proptest::collection::vec(fuzz::mutated_json(
            recording_seeds().iter().flat_map(|s| s.lines().filter(|l| !l.is_empty()).map(str::to_string).collect::<Vec<_>>()).collect()
        ), 1..4)
    ) {
        check_recording(&lines.join("\n"));
    }
}

// ------------------------------------------------- evemu and hid captures

/// A two-finger multitouch capture, written for these tests.
const EVEMU_TOUCH: &str = "# EVEMU 1.3
N: Fuzz Touch
I: 0003 0eef 72a1 0210
P: 02 00 00 00 00 00 00 00
B: 00 0b 00 00 00 00 00 00 00
B: 01 00 00 00 00 00 00 00 00
B: 03 03 00 00 00 00 80 73 02
A: 00 0 4095 0 0 0
A: 01 0 4095 0 0 0
A: 2f 0 9 0 0 0
A: 30 0 255 0 0 0
A: 35 0 4095 0 0 12
A: 36 0 4095 0 0 12
A: 39 0 65535 0 0 0
A: 3a 0 255 0 0 0
E: 0.000000 0003 002f 0000
E: 0.000000 0003 0039 0010
E: 0.000000 0003 0035 1000
E: 0.000000 0003 0036 2000
E: 0.000000 0003 003a 0050
E: 0.000000 0003 002f 0001
E: 0.000000 0003 0039 0011
E: 0.000000 0003 0035 3000
E: 0.000000 0003 0036 2000
E: 0.000000 0000 0000 0000
E: 0.010000 0003 002f 0000
E: 0.010000 0003 0035 1010
E: 0.010000 0003 0030 0020
E: 0.010000 0000 0000 0000
E: 0.020000 0003 0039 -001
E: 0.020000 0003 002f 0001
E: 0.020000 0003 0039 -001
E: 0.020000 0000 0000 0000
";

fn capture_seeds() -> Vec<String> {
    let mut seeds = vec![
        EVEMU_TOUCH.to_string(),
        std::fs::read_to_string(puppetry_testkit::root().join("tests/fixtures/mouse-drag.event"))
            .expect("the mouse capture"),
    ];
    for hid in ["touch-parallel.hid", "touch-hybrid.hid"] {
        seeds.push(
            std::fs::read_to_string(puppetry_testkit::root().join("tests/fixtures").join(hid))
                .expect("the hid capture"),
        );
    }
    seeds
}

/// Parses a capture the way `serve` and `puppetry replay` do (sniffing its
/// kind) and plays every frame.
fn check_capture(text: &str) {
    match ReplaySource::parse("fuzz.capture", text, SourceId::from("replay"), STAGE, None) {
        Ok(source) => {
            let frames: Vec<ContactFrame> = source.frames().take(100_000).collect();
            check_frames(&frames);
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.starts_with("fuzz.capture"), "{message}");
            if let ReplayError::Evemu(puppetry_input::evemu::EvemuError::Line(LineError {
                line,
                ..
            })) = e
            {
                assert!(line >= 1, "{message}");
                assert!(
                    message.starts_with(&format!("fuzz.capture:{line}: ")),
                    "{message}"
                );
            }
        }
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_capture_random_text(text in fuzz::text(400)) {
        check_capture(&text);
    }

    #[test]
    fn fuzz_capture_mutated(text in fuzz::mutated_text(capture_seeds())) {
        check_capture(&text);
    }

    #[test]
    fn fuzz_hid_recording_mutated(text in fuzz::mutated_text(capture_seeds()[2..].to_vec())) {
        match HidRecording::parse("fuzz.hid", &text) {
            Ok(recording) => {
                let mut out = Vec::new();
                recording.write(&mut out).unwrap();
            }
            Err(e) => {
                let message = e.to_string();
                assert!(message.starts_with("fuzz.hid"), "{message}");
            }
        }
    }
}

// ------------------------------------------------- HID descriptors, reports

fn descriptors() -> Vec<Vec<u8>> {
    capture_seeds()[2..]
        .iter()
        .map(|text| HidRecording::parse("seed.hid", text).unwrap().descriptor)
        .collect()
}

fn hid_reports(descriptor: &[u8], reports: &[Vec<u8>]) {
    let Ok(_) = TouchLayout::parse(descriptor) else {
        return;
    };
    let Ok(mut decoder) = HidTouchDecoder::new(descriptor, SourceId::from("hid"), None, STAGE)
    else {
        return;
    };
    for (i, report) in reports.iter().enumerate() {
        match decoder.push(report, i as f64 * 0.01) {
            Ok(frame) => check_frames(&frame.into_iter().collect::<Vec<_>>()),
            Err(e) => check_message(&e.to_string()),
        }
    }
    let _ = decoder.lift_all(1.0);
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_hid_random_descriptors(descriptor in fuzz::bytes(300)) {
        if let Err(e) = TouchLayout::parse(&descriptor) {
            check_message(&e.to_string());
        }
    }

    #[test]
    fn fuzz_hid_mutated_descriptors(
        descriptor in fuzz::mutated_bytes(descriptors()),
        reports in proptest::collection::vec(fuzz::bytes(64), 0..8),
    ) {
        hid_reports(&descriptor, &reports);
    }

    #[test]
    fn fuzz_hid_random_reports(
        which in 0usize..2,
        reports in proptest::collection::vec(
            prop_oneof![
                fuzz::bytes(80),
                // The report id a real descriptor uses, then noise.
                fuzz::bytes(60).prop_map(|mut b| { b.insert(0, 1); b }),
            ],
            1..12,
        ),
    ) {
        hid_reports(&descriptors()[which], &reports);
    }
}

// ------------------------------------------- regressions the fuzzing found

#[test]
fn fuzz_regression_a_tuio_time_tag_before_1970_is_an_error_not_a_panic() {
    // rosc's Display of such a time tag panics; the error quotes it itself.
    let datagram = rosc::encoder::encode(&OscPacket::Message(OscMessage {
        addr: "/tuio/2Dcur".into(),
        args: vec![OscType::Time(OscTime::from((0, 0)))],
    }))
    .unwrap();
    let error = tracker().push(&datagram, 0.0).unwrap_err().to_string();
    assert!(error.contains("should be a string, not (t) 0.0"), "{error}");
    // The same argument where a serial pad expects its id.
    let packet = OscPacket::Message(OscMessage {
        addr: "/pad/contact".into(),
        args: vec![
            OscType::Time(OscTime::from((0, 0))),
            OscType::String("d".into()),
            OscType::Float(1.0),
            OscType::Float(1.0),
        ],
    });
    let mut decoder = serial_decoder(WireFormat::SlipOsc);
    let results = decoder.push(&slip(&packet));
    let error = results[0].as_ref().unwrap_err().to_string();
    assert!(error.contains("should be an int32, not (t) 0.0"), "{error}");
}

#[test]
fn fuzz_regression_hid_descriptors_hidreport_cannot_survive_are_refused() {
    // A Usage with no Usage Page before it: hidreport 0.6 panics.
    let no_page = [0x09, 0x01, 0xA1, 0x01, 0xC0];
    let error = TouchLayout::parse(&no_page).unwrap_err().to_string();
    assert!(error.contains("without a Usage Page"), "{error}");
    // A usage range of 2³² usages: hidreport would list every one.
    let huge = [
        0x05, 0x0D, 0x1B, 0x00, 0x00, 0x00, 0x00, 0x2B, 0xFF, 0xFF, 0xFF, 0xFF, 0x75, 0x08, 0x95,
        0x01, 0x81, 0x02,
    ];
    let error = TouchLayout::parse(&huge).unwrap_err().to_string();
    assert!(error.contains("spans more than one usage page"), "{error}");
    // A Report Count of 2³¹: hidreport would make a field for each.
    let many = [
        0x05, 0x0D, 0x09, 0x01, 0x75, 0x08, 0x97, 0xFF, 0xFF, 0xFF, 0x7F, 0x81, 0x02,
    ];
    let error = TouchLayout::parse(&many).unwrap_err().to_string();
    assert!(error.contains("more than 8192 report fields"), "{error}");
    // Real descriptors still pass.
    for descriptor in descriptors() {
        TouchLayout::parse(&descriptor).unwrap();
    }
}

// MIDI: a byte stream from a port anyone can plug into.

/// Decodes `bytes` fed `chunk` bytes at a time.
fn midi(bytes: &[u8], chunk: usize) -> (Vec<puppetry_input::midi::MidiMessage>, u64) {
    let mut decoder = puppetry_input::midi::MidiDecoder::new();
    let mut out = Vec::new();
    for part in bytes.chunks(chunk.max(1)) {
        decoder.feed(part, |m| out.push(m));
    }
    (out, decoder.dropped())
}

/// One channel message, status and data.
fn midi_channel_message() -> impl Strategy<Value = Vec<u8>> {
    (0x80u8..=0xEF, 0u8..128, 0u8..128).prop_map(|(status, a, b)| match status & 0xF0 {
        0xC0 | 0xD0 => vec![status, a],
        _ => vec![status, a, b],
    })
}

proptest! {
    #![proptest_config(config())]

    /// Any bytes, in any chunks: messages or drops, never a panic, and the
    /// same messages however the bytes were cut.
    #[test]
    fn fuzz_midi_random_bytes(bytes in fuzz::bytes(600), chunk in 1usize..64) {
        let whole = midi(&bytes, bytes.len());
        prop_assert_eq!(midi(&bytes, chunk), whole);
    }

    /// Real-time bytes inserted anywhere in a stream of messages change
    /// none of them.
    #[test]
    fn fuzz_midi_real_time_bytes_anywhere(
        messages in proptest::collection::vec(midi_channel_message(), 1..20),
        inserts in proptest::collection::vec(
            (any::<proptest::sample::Index>(), proptest::sample::select(vec![0xF8u8, 0xFA, 0xFB, 0xFC, 0xFE, 0xFF])),
            0..12,
        ),
    ) {
        let plain: Vec<u8> = messages.concat();
        let (expected, dropped) = midi(&plain, plain.len());
        prop_assert_eq!(dropped, 0);
        prop_assert_eq!(expected.len(), messages.len());
        let mut mixed = plain.clone();
        for (at, byte) in &inserts {
            let at = at.index(mixed.len() + 1);
            mixed.insert(at, *byte);
        }
        let (got, dropped) = midi(&mixed, 7);
        prop_assert_eq!(dropped, 0);
        let got: Vec<_> = got.into_iter().filter(|m| !matches!(m,
            puppetry_input::midi::MidiMessage::Clock
            | puppetry_input::midi::MidiMessage::Start
            | puppetry_input::midi::MidiMessage::Continue
            | puppetry_input::midi::MidiMessage::Stop
            | puppetry_input::midi::MidiMessage::ActiveSensing
            | puppetry_input::midi::MidiMessage::Reset)).collect();
        prop_assert_eq!(got, expected);
    }

    /// Whatever the decoder makes of any bytes, encoded and decoded again,
    /// is the same messages: what `puppetry record` writes of a port
    /// replays as it was heard.
    #[test]
    fn fuzz_midi_encoding_reads_back(bytes in fuzz::bytes(600)) {
        let (messages, _) = midi(&bytes, bytes.len());
        let mut encoded = Vec::new();
        for m in &messages {
            m.encode(&mut encoded);
        }
        let (again, dropped) = midi(&encoded, encoded.len());
        prop_assert_eq!(dropped, 0);
        prop_assert_eq!(again, messages);
    }
}
