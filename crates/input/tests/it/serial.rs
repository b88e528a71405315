//! The serial pad source end to end: both wire formats decode to exactly the
//! expected frames however the bytes are split across reads, garbage and
//! over-long records are refused with errors that say where and decoding
//! resumes after them, SLIP escapes round-trip, calibration is applied,
//! phases are kept consistent, and [`run_stream`] (over an in-memory duplex)
//! and [`run_port`] (over a pseudo-terminal) lift every contact when the
//! stream goes away.

use std::time::Duration;

use crate::common::pty::open_pty;

use glam::DVec2;
use puppetry_input::serial::{
    MAX_RECORD, RELEASE_AFTER, SerialDecoder, SerialError, WireFormat, run_port, run_stream,
};
use puppetry_input::{Calibration, CalibrationSpec, Contact, ContactFrame, Phase};
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

/// Device 0..1000 × 0..1000 (y down) on a 200 × 100 stage: device (250, 250)
/// is stage (50, 75).
fn calibration() -> Calibration {
    Calibration::fit([0.0, 1000.0], [0.0, 1000.0], DVec2::new(200.0, 100.0)).unwrap()
}

fn decoder(format: WireFormat) -> SerialDecoder {
    SerialDecoder::new(format, calibration(), "pad".into())
}

fn contact(id: u32, phase: Phase, x: f64, y: f64) -> Contact {
    Contact::new(id, phase, DVec2::new(x, y))
}

fn pressed(mut c: Contact, pressure: f64) -> Contact {
    c.pressure = Some(pressure);
    c
}

/// What a decoder said, with frame times dropped (they come from a clock).
#[derive(Debug, PartialEq)]
enum Said {
    Frame(Vec<Contact>),
    Error(String),
}

fn said(items: Vec<Result<ContactFrame, SerialError>>) -> Vec<Said> {
    items
        .into_iter()
        .map(|item| match item {
            Ok(frame) => {
                assert_eq!(frame.source.as_str(), "pad");
                Said::Frame(frame.contacts)
            }
            Err(e) => Said::Error(e.to_string()),
        })
        .collect()
}

/// Feeds `bytes` whole, split in two at every position, and byte by byte,
/// checks all agree, and returns what was said.
fn decode_all_ways(format: WireFormat, bytes: &[u8]) -> Vec<Said> {
    let whole = said(decoder(format).push(bytes));
    for cut in 0..=bytes.len() {
        let mut d = decoder(format);
        let mut items = d.push(&bytes[..cut]);
        items.extend(d.push(&bytes[cut..]));
        assert_eq!(said(items), whole, "split at byte {cut}");
    }
    let mut d = decoder(format);
    let items: Vec<_> = bytes.iter().flat_map(|b| d.push(&[*b])).collect();
    assert_eq!(said(items), whole, "byte by byte");
    whole
}

fn frame(contacts: Vec<Contact>) -> Said {
    Said::Frame(contacts)
}

fn error_containing(said: &Said, parts: &[&str]) {
    match said {
        Said::Error(message) => {
            for part in parts {
                assert!(message.contains(part), "`{message}` lacks `{part}`");
            }
        }
        other => panic!("expected an error, got {other:?}"),
    }
}

// ---------------------------------------------------------------- csv

#[test]
fn csv_frames_down_move_up_with_pressure() {
    let input = b"1,d,250,250\n2,down,500,500,0.5\nf\n1,m, 500 ,250\r\n\n1,u,500,250\n2,U,0,0\nf\n";
    let got = decode_all_ways(WireFormat::Csv, input);
    assert_eq!(
        got,
        vec![
            frame(vec![
                contact(1, Phase::Down, 50.0, 75.0),
                pressed(contact(2, Phase::Down, 100.0, 50.0), 0.5),
            ]),
            frame(vec![contact(1, Phase::Move, 100.0, 75.0)]),
            frame(vec![
                contact(1, Phase::Up, 100.0, 75.0),
                contact(2, Phase::Up, 0.0, 100.0),
            ]),
        ]
    );
}

#[test]
fn csv_empty_frames_are_not_sent() {
    assert_eq!(said(decoder(WireFormat::Csv).push(b"f\n\n\r\nf\n")), vec![]);
}

#[test]
fn csv_garbage_is_an_error_naming_the_line_and_decoding_resumes() {
    let input = b"\x00\xffnoise\n1,d,0,0\n1,x,0,0\n1,m,zz,0\n1,m,0,0,2\n3,4\n-1,d,0,0\nf\n";
    let got = decode_all_ways(WireFormat::Csv, input);
    assert_eq!(got.len(), 7, "{got:#?}");
    error_containing(&got[0], &["line 1", "not UTF-8"]);
    error_containing(&got[1], &["line 3", "field 2 (phase)", "`x`"]);
    error_containing(&got[2], &["line 4", "field 3 (x)", "`zz`"]);
    error_containing(&got[3], &["line 5", "field 5 (pressure)", "outside 0..=1"]);
    error_containing(&got[4], &["line 6", "got 2 field(s)"]);
    error_containing(&got[5], &["line 7", "field 1 (id)", "`-1`"]);
    assert_eq!(got[6], frame(vec![contact(1, Phase::Down, 0.0, 100.0)]));
}

#[test]
fn csv_over_long_line_is_refused_once_and_skipped() {
    let mut input = b"1,d,0,0\nf\n".to_vec();
    input.extend(std::iter::repeat_n(b'9', 3 * MAX_RECORD));
    input.extend(b"\n1,u,0,0\nf\n");
    let mut d = decoder(WireFormat::Csv);
    // In small reads, as a port would deliver it: still one error.
    let items: Vec<_> = input.chunks(100).flat_map(|c| d.push(c)).collect();
    let got = said(items);
    assert_eq!(got.len(), 3, "{got:#?}");
    assert_eq!(got[0], frame(vec![contact(1, Phase::Down, 0.0, 100.0)]));
    error_containing(
        &got[1],
        &["line 3", "starting at byte 10", "longer than 4096 bytes"],
    );
    assert_eq!(got[2], frame(vec![contact(1, Phase::Up, 0.0, 100.0)]));
}

#[test]
fn csv_line_of_exactly_the_limit_is_accepted() {
    // y is written with enough leading zeros to fill the limit exactly.
    let mut line = b"1,d,0,".to_vec();
    line.resize(MAX_RECORD, b'0');
    line.extend(b"\nf\n");
    let got = said(decoder(WireFormat::Csv).push(&line));
    assert_eq!(got, vec![frame(vec![contact(1, Phase::Down, 0.0, 100.0)])]);
}

#[test]
fn phases_are_kept_consistent_with_what_was_sent() {
    // d twice is a move; m for an unknown id lands it; u for an unknown id
    // is an error; d then u of one id in one frame splits the frame.
    let input = b"1,d,0,0\nf\n1,d,250,0\n2,m,0,0\nf\n9,u,0,0\n3,d,0,0\n3,u,0,0\nf\n";
    let got = decode_all_ways(WireFormat::Csv, input);
    assert_eq!(got.len(), 5, "{got:#?}");
    assert_eq!(got[0], frame(vec![contact(1, Phase::Down, 0.0, 100.0)]));
    assert_eq!(
        got[1],
        frame(vec![
            contact(1, Phase::Move, 50.0, 100.0),
            contact(2, Phase::Down, 0.0, 100.0),
        ])
    );
    error_containing(&got[2], &["line 6", "contact 9 lifts but is not down"]);
    assert_eq!(got[3], frame(vec![contact(3, Phase::Down, 0.0, 100.0)]));
    assert_eq!(got[4], frame(vec![contact(3, Phase::Up, 0.0, 100.0)]));
}

#[test]
fn lift_all_lifts_what_is_down_and_drops_the_unfinished_frame() {
    let mut d = decoder(WireFormat::Csv);
    d.push(b"1,d,0,0\n2,d,250,250,0.25\nf\n2,m,500,500\nf\n3,d,0,0\n1,u,0,0\n4,m");
    let lifted = d.lift_all().expect("contacts were down");
    assert_eq!(
        lifted.contacts,
        vec![
            contact(1, Phase::Up, 0.0, 100.0),
            contact(2, Phase::Up, 100.0, 50.0),
        ]
    );
    assert_eq!(d.lift_all(), None);
    // The unfinished "4,m" is gone, and state starts afresh.
    let got = said(d.push(b",0,0\n1,d,0,0\nf\n"));
    error_containing(&got[0], &["got 3 field(s)"]);
    assert_eq!(got[1], frame(vec![contact(1, Phase::Down, 0.0, 100.0)]));
}

#[test]
fn calibration_corners_are_applied() {
    // A skewed device quad: its corners must land on the stage's corners.
    let spec = CalibrationSpec::Corners {
        corners: [[100.0, 50.0], [900.0, 80.0], [950.0, 700.0], [60.0, 650.0]],
        stage_min: [-1.0, -1.0],
        stage_max: [1.0, 1.0],
    };
    let mut d = SerialDecoder::new(
        WireFormat::Csv,
        Calibration::new(spec).unwrap(),
        "pad".into(),
    );
    let got = said(d.push(b"1,d,100,50\n2,d,900,80\n3,d,950,700\n4,d,60,650\nf\n"));
    let Said::Frame(contacts) = &got[0] else {
        panic!("{got:?}")
    };
    let expected = [(-1.0, 1.0), (1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)];
    for (c, (x, y)) in contacts.iter().zip(expected) {
        assert!(
            (c.position - DVec2::new(x, y)).length() < 1e-9,
            "{c:?} vs ({x}, {y})"
        );
    }
}

// ---------------------------------------------------------------- slip + osc

const END: u8 = 0xC0;
const ESC: u8 = 0xDB;

fn msg(addr: &str, args: Vec<OscType>) -> OscPacket {
    OscPacket::Message(OscMessage {
        addr: addr.to_owned(),
        args,
    })
}

fn pad_contact(id: i32, phase: &str, x: f32, y: f32) -> OscPacket {
    msg(
        "/pad/contact",
        vec![
            OscType::Int(id),
            OscType::String(phase.into()),
            OscType::Float(x),
            OscType::Float(y),
        ],
    )
}

fn pad_frame() -> OscPacket {
    msg("/pad/frame", vec![])
}

/// RFC 1055 framing, with the optional leading END.
fn slip(packet: &OscPacket) -> Vec<u8> {
    slip_raw(&rosc::encoder::encode(packet).unwrap())
}

fn slip_raw(bytes: &[u8]) -> Vec<u8> {
    let mut out = vec![END];
    for &b in bytes {
        match b {
            END => out.extend([ESC, 0xDC]),
            ESC => out.extend([ESC, 0xDD]),
            b => out.push(b),
        }
    }
    out.push(END);
    out
}

fn bundle(content: Vec<OscPacket>) -> OscPacket {
    OscPacket::Bundle(OscBundle {
        timetag: OscTime::from((0, 1)),
        content,
    })
}

#[test]
fn slip_osc_frames_from_messages_and_bundles() {
    let mut input = slip(&pad_contact(1, "d", 250.0, 250.0));
    input.extend(slip(&msg(
        "/pad/contact",
        vec![
            OscType::Int(2),
            OscType::String("down".into()),
            OscType::Double(500.0),
            OscType::Float(500.0),
            OscType::Float(0.5),
        ],
    )));
    input.extend(slip(&pad_frame()));
    input.extend(slip(&bundle(vec![
        pad_contact(1, "u", 250.0, 250.0),
        pad_contact(2, "m", 0.0, 0.0),
        pad_frame(),
    ])));
    let got = decode_all_ways(WireFormat::SlipOsc, &input);
    assert_eq!(
        got,
        vec![
            frame(vec![
                contact(1, Phase::Down, 50.0, 75.0),
                pressed(contact(2, Phase::Down, 100.0, 50.0), 0.5),
            ]),
            frame(vec![
                contact(1, Phase::Up, 50.0, 75.0),
                contact(2, Phase::Move, 0.0, 100.0),
            ]),
        ]
    );
}

#[test]
fn slip_escapes_round_trip() {
    // Id 0xC0DB and x's bits both contain END and ESC bytes.
    let x = f32::from_bits(0xC4DB_C000);
    let packet = bundle(vec![pad_contact(0xC0DB, "d", x, 0.0), pad_frame()]);
    let raw = rosc::encoder::encode(&packet).unwrap();
    assert!(raw.contains(&END) && raw.contains(&ESC));
    let got = decode_all_ways(WireFormat::SlipOsc, &slip(&packet));
    let expected = calibration().map(DVec2::new(f64::from(x), 0.0));
    assert_eq!(
        got,
        vec![frame(vec![Contact::new(0xC0DB, Phase::Down, expected)])]
    );
}

#[test]
fn slip_garbage_and_bad_escapes_resync_at_the_next_end() {
    let mut input = b"hello\r\n".to_vec(); // boot banner before the first END
    input.extend(slip(&pad_contact(1, "d", 0.0, 0.0)));
    let bad_escape_at = input.len() + 2;
    input.extend([1, 2, ESC, 0x01, 3, 4]); // ESC followed by neither ESC_END nor ESC_ESC
    input.extend(slip(&pad_frame()));
    let got = decode_all_ways(WireFormat::SlipOsc, &input);
    assert_eq!(got.len(), 3, "{got:#?}");
    error_containing(&got[0], &["packet at byte 0", "not an OSC packet"]);
    error_containing(
        &got[1],
        &[
            "invalid SLIP escape 0xDB 0x01",
            &format!("at byte {bad_escape_at}"),
        ],
    );
    assert_eq!(got[2], frame(vec![contact(1, Phase::Down, 0.0, 100.0)]));
}

#[test]
fn slip_over_long_packet_is_refused_once_and_skipped() {
    let mut input = vec![END];
    input.extend(std::iter::repeat_n(0x41, 2 * MAX_RECORD));
    input.extend(slip(&bundle(vec![
        pad_contact(1, "d", 0.0, 0.0),
        pad_frame(),
    ])));
    let mut d = decoder(WireFormat::SlipOsc);
    let items: Vec<_> = input.chunks(64).flat_map(|c| d.push(c)).collect();
    let got = said(items);
    assert_eq!(got.len(), 2, "{got:#?}");
    error_containing(&got[0], &["packet starting at byte 1", "longer than 4096"]);
    assert_eq!(got[1], frame(vec![contact(1, Phase::Down, 0.0, 100.0)]));
}

#[test]
fn slip_bad_messages_name_index_and_argument_and_the_rest_apply() {
    let input = slip(&bundle(vec![
        msg(
            "/pad/contact",
            vec![
                OscType::String("1".into()),
                OscType::String("d".into()),
                OscType::Float(0.0),
                OscType::Float(0.0),
            ],
        ),
        msg(
            "/pad/contact",
            vec![OscType::Int(1), OscType::String("d".into())],
        ),
        pad_contact(-3, "d", 0.0, 0.0),
        pad_contact(4, "sideways", 0.0, 0.0),
        msg("/pad/blink", vec![]),
        pad_contact(5, "d", 0.0, 0.0),
        pad_frame(),
    ]));
    let got = decode_all_ways(WireFormat::SlipOsc, &input);
    assert_eq!(got.len(), 6, "{got:#?}");
    error_containing(
        &got[0],
        &["message 0 (/pad/contact)", "argument 0 (id)", "int32"],
    );
    error_containing(&got[1], &["message 1", "argument 2 (x) is missing"]);
    error_containing(&got[2], &["message 2", "-3 is negative"]);
    error_containing(&got[3], &["message 3", "argument 1 (phase) `sideways`"]);
    error_containing(&got[4], &["message 4", "unknown address `/pad/blink`"]);
    assert_eq!(got[5], frame(vec![contact(5, Phase::Down, 0.0, 100.0)]));
}

// ---------------------------------------------------------------- async

async fn recv(rx: &mut mpsc::Receiver<ContactFrame>) -> ContactFrame {
    tokio::time::timeout(Duration::from_secs(20), rx.recv())
        .await
        .expect("a frame within 10 s")
        .expect("the sink is open")
}

#[tokio::test]
async fn run_stream_sends_frames_and_lifts_all_at_end_of_stream() {
    let (mut device, port) = tokio::io::duplex(4096);
    // A capacity-1 sink: the reader must wait for it, not drop frames.
    let (tx, mut rx) = mpsc::channel(1);
    let task = tokio::spawn(run_stream(
        port,
        decoder(WireFormat::Csv),
        RELEASE_AFTER,
        tx,
    ));
    let mut script = String::new();
    for i in 0..20 {
        script.push_str(&format!("{i},d,0,0\nf\n"));
    }
    script.push_str("junk\n0,u,0,0\nf\n");
    device.write_all(script.as_bytes()).await.unwrap();
    for i in 0..20 {
        assert_eq!(
            recv(&mut rx).await.contacts,
            vec![contact(i, Phase::Down, 0.0, 100.0)]
        );
    }
    assert_eq!(
        recv(&mut rx).await.contacts,
        vec![contact(0, Phase::Up, 0.0, 100.0)]
    );
    device.write_all(b"7,m,500,500\n").await.unwrap(); // unfinished frame
    drop(device);
    let lifted = recv(&mut rx).await;
    assert_eq!(lifted.contacts.len(), 19);
    assert!(lifted.contacts.iter().all(|c| c.phase == Phase::Up));
    assert_eq!(lifted.contacts[0].id, 1);
    let result = tokio::time::timeout(Duration::from_secs(20), task)
        .await
        .expect("run_stream returns")
        .unwrap();
    assert!(matches!(result, Err(SerialError::Closed)), "{result:?}");
}

#[tokio::test]
async fn run_stream_returns_ok_when_the_sink_closes() {
    let (_device, port) = tokio::io::duplex(64);
    let (tx, rx) = mpsc::channel(1);
    let task = tokio::spawn(run_stream(
        port,
        decoder(WireFormat::Csv),
        RELEASE_AFTER,
        tx,
    ));
    drop(rx);
    let result = tokio::time::timeout(Duration::from_secs(20), task)
        .await
        .expect("run_stream returns")
        .unwrap();
    assert!(result.is_ok(), "{result:?}");
}

#[tokio::test]
async fn run_port_refuses_a_missing_port() {
    let (tx, _rx) = mpsc::channel(1);
    let result = run_port(
        "/nonexistent/ttyPAD",
        115_200,
        decoder(WireFormat::Csv),
        RELEASE_AFTER,
        tx,
    )
    .await;
    match result {
        Err(e @ SerialError::Open { .. }) => {
            assert!(e.to_string().contains("/nonexistent/ttyPAD"), "{e}")
        }
        other => panic!("{other:?}"),
    }
}

#[tokio::test]
async fn run_port_reads_a_pty_and_lifts_all_when_it_hangs_up() {
    use std::io::Write;
    let mut pty = open_pty();
    let (tx, mut rx) = mpsc::channel(4);
    let path = pty.path.clone();
    let task = tokio::spawn(async move {
        run_port(&path, 115_200, decoder(WireFormat::Csv), RELEASE_AFTER, tx).await
    });
    pty.master
        .write_all(b"1,d,250,250\n2,d,0,0\nf\n1,m,500,250\nf\n")
        .unwrap();
    assert_eq!(
        recv(&mut rx).await.contacts,
        vec![
            contact(1, Phase::Down, 50.0, 75.0),
            contact(2, Phase::Down, 0.0, 100.0),
        ]
    );
    assert_eq!(
        recv(&mut rx).await.contacts,
        vec![contact(1, Phase::Move, 100.0, 75.0)]
    );
    // Hanging up the master is the pad unplugged: the slave reads fail.
    drop(pty.master);
    let lifted = recv(&mut rx).await;
    assert_eq!(
        lifted.contacts,
        vec![
            contact(1, Phase::Up, 100.0, 75.0),
            contact(2, Phase::Up, 0.0, 100.0),
        ]
    );
    let result = tokio::time::timeout(Duration::from_secs(20), task)
        .await
        .expect("run_port returns")
        .unwrap();
    assert!(
        matches!(result, Err(SerialError::Read(_) | SerialError::Closed)),
        "{result:?}"
    );
}

// On tokio's paused clock: the silences are exact, whatever the machine's
// load.
#[tokio::test(start_paused = true)]
async fn a_pad_that_falls_silent_holding_a_contact_lets_go_and_lands_again_when_it_speaks() {
    let (mut device, port) = tokio::io::duplex(4096);
    let (tx, mut rx) = mpsc::channel(4);
    let silence = Duration::from_millis(200);
    let task = tokio::spawn(run_stream(port, decoder(WireFormat::Csv), silence, tx));
    // Empty frames are the pad saying it is alive: a contact held still
    // stays down however long they keep coming.
    device.write_all(b"1,d,250,250\nf\n").await.unwrap();
    assert_eq!(recv(&mut rx).await.contacts[0].phase, Phase::Down);
    for _ in 0..6 {
        tokio::time::sleep(silence / 2).await;
        device.write_all(b"f\n").await.unwrap();
    }
    assert!(
        rx.try_recv().is_err(),
        "a pad that says it is alive holds on"
    );
    // Then the firmware hangs with the port still open: let go.
    let lifted = recv(&mut rx).await;
    assert_eq!(lifted.contacts, vec![contact(1, Phase::Up, 50.0, 75.0)]);
    // It speaks again: the contact lands again, it does not move a grab
    // that is gone.
    device.write_all(b"1,m,500,250\nf\n").await.unwrap();
    assert_eq!(
        recv(&mut rx).await.contacts,
        vec![contact(1, Phase::Down, 100.0, 75.0)]
    );
    drop(rx);
    drop(device);
    let _ = tokio::time::timeout(Duration::from_secs(20), task).await;
}
