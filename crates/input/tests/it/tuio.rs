//! The TUIO source end to end: OSC bundles built with rosc's encoder give
//! exactly the expected frames for TUIO 1.1 and 2.0 (down, move, up, lifts
//! by omission from `alive`, late frames ignored, sources kept apart,
//! calibration applied), malformed datagrams are refused without touching
//! state, and [`run_udp`] over loopback recovers from a datagram that never
//! arrives.

use std::time::Duration;

use crate::common::tuio::{bundle, cur, msg, v1};
use glam::DVec2;
use puppetry_input::tuio::{
    DEFAULT_PORT, MAX_SOURCES, TuioError, TuioTracker, default_calibration, run_udp,
};
use puppetry_input::{Calibration, CalibrationSpec, Contact, ContactFrame, Phase, SourceId};
use rosc::{OscTime, OscType};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;

/// 200 × 100 stage: device (0.25, 0.25) is stage (50, 75).
const STAGE: DVec2 = DVec2::new(200.0, 100.0);

fn tracker() -> TuioTracker {
    TuioTracker::new(default_calibration(STAGE).unwrap())
}

/// A TUIO 2.0 bundle: frm, ptrs `(s_id, x, y, press)`, alv.
fn v2(frame: i32, seconds: u32, ptrs: &[(i32, f32, f32, f32)], alive: &[i32]) -> Vec<u8> {
    let mut content = vec![msg(
        "/tuio2/frm",
        vec![
            frame.into(),
            OscType::Time(OscTime::from((seconds, 0))),
            ((640 << 16) | 480).into(),
            "table:0@10.0.0.2".into(),
        ],
    )];
    for &(s, x, y, press) in ptrs {
        content.push(msg(
            "/tuio2/ptr",
            vec![
                s.into(),
                0i32.into(),
                0i32.into(),
                x.into(),
                y.into(),
                0f32.into(),
                0f32.into(),
                0.01f32.into(),
                press.into(),
            ],
        ));
    }
    content.push(msg("/tuio2/alv", alive.iter().map(|&s| s.into()).collect()));
    bundle(content)
}

fn contact(id: u32, phase: Phase, x: f64, y: f64) -> Contact {
    Contact::new(id, phase, DVec2::new(x, y))
}

fn one(frames: Vec<ContactFrame>) -> ContactFrame {
    assert_eq!(frames.len(), 1, "expected one frame, got {frames:?}");
    frames.into_iter().next().unwrap()
}

#[test]
fn default_port_is_tuio_standard() {
    assert_eq!(DEFAULT_PORT, 3333);
}

#[test]
fn v1_down_move_up() {
    let mut t = tracker();
    let f = one(t.push(&v1(None, &[1], &[(1, 0.25, 0.25)], 1), 7.0).unwrap());
    assert_eq!(f.source, SourceId::from("tuio"));
    assert_eq!(f.time, 7.0, "an immediate time tag takes the caller's time");
    assert_eq!(f.contacts, vec![contact(1, Phase::Down, 50.0, 75.0)]);

    let f = one(t.push(&v1(None, &[1], &[(1, 0.5, 0.5)], 2), 8.0).unwrap());
    assert_eq!(f.contacts, vec![contact(1, Phase::Move, 100.0, 50.0)]);

    // An idle restatement is not news.
    assert!(
        t.push(&v1(None, &[1], &[(1, 0.5, 0.5)], 3), 9.0)
            .unwrap()
            .is_empty()
    );
    assert!(t.push(&v1(None, &[1], &[], 4), 9.0).unwrap().is_empty());

    let f = one(t.push(&v1(None, &[], &[], 5), 10.0).unwrap());
    assert_eq!(f.contacts, vec![contact(1, Phase::Up, 100.0, 50.0)]);
}

#[test]
fn v1_alive_lifts_missing_sessions() {
    let mut t = tracker();
    let f = one(t
        .push(&v1(None, &[3, 4], &[(3, 0.0, 0.0), (4, 1.0, 1.0)], 1), 0.0)
        .unwrap());
    assert_eq!(
        f.contacts,
        vec![
            contact(3, Phase::Down, 0.0, 100.0),
            contact(4, Phase::Down, 200.0, 0.0)
        ]
    );
    // Session 3's final frames were lost; the next alive still lifts it, and
    // a set for a session that is not alive is not a contact.
    let f = one(t
        .push(&v1(None, &[4, 9], &[(9, 0.5, 0.5), (3, 0.1, 0.1)], 7), 0.0)
        .unwrap());
    assert_eq!(
        f.contacts,
        vec![
            contact(3, Phase::Up, 0.0, 100.0),
            contact(9, Phase::Down, 100.0, 50.0)
        ]
    );
}

#[test]
fn v1_late_frames_are_ignored_but_fseq_minus_one_applies() {
    let mut t = tracker();
    one(t
        .push(&v1(None, &[1], &[(1, 0.25, 0.25)], 500), 0.0)
        .unwrap());
    // Older than frame 500: dropped, state unchanged.
    assert!(
        t.push(&v1(None, &[1], &[(1, 0.9, 0.9)], 499), 0.0)
            .unwrap()
            .is_empty()
    );
    assert!(t.push(&v1(None, &[], &[], 495), 0.0).unwrap().is_empty());
    let f = one(t.push(&v1(None, &[1], &[(1, 0.5, 0.5)], 501), 0.0).unwrap());
    assert_eq!(f.contacts, vec![contact(1, Phase::Move, 100.0, 50.0)]);
    // A redundant resend (fseq -1) restates the state whatever the order.
    let f = one(t.push(&v1(None, &[], &[], -1), 0.0).unwrap());
    assert_eq!(f.contacts, vec![contact(1, Phase::Up, 100.0, 50.0)]);
    // ...and does not move the ordering: 502 is still news.
    let f = one(t.push(&v1(None, &[2], &[(2, 0.5, 0.5)], 502), 0.0).unwrap());
    assert_eq!(f.contacts, vec![contact(2, Phase::Down, 100.0, 50.0)]);
    // A far jump back is a restarted tracker, not a late datagram.
    let f = one(t.push(&v1(None, &[], &[], 1), 0.0).unwrap());
    assert_eq!(f.contacts, vec![contact(2, Phase::Up, 100.0, 50.0)]);
}

#[test]
fn v1_sources_are_kept_apart() {
    let mut t = tracker();
    let a = one(t
        .push(&v1(Some("a@host"), &[1], &[(1, 0.25, 0.25)], 50), 0.0)
        .unwrap());
    let b = one(t
        .push(&v1(Some("b@host"), &[1], &[(1, 0.5, 0.5)], 1), 0.0)
        .unwrap());
    assert_eq!(a.source, SourceId::from("tuio:a@host"));
    assert_eq!(b.source, SourceId::from("tuio:b@host"));
    assert_eq!(b.contacts, vec![contact(1, Phase::Down, 100.0, 50.0)]);
    // a's empty alive lifts only a's session 1.
    let a = one(t.push(&v1(Some("a@host"), &[], &[], 51), 0.0).unwrap());
    assert_eq!(a.source, SourceId::from("tuio:a@host"));
    assert_eq!(a.contacts, vec![contact(1, Phase::Up, 50.0, 75.0)]);
    let b = one(t
        .push(&v1(Some("b@host"), &[1], &[(1, 0.75, 0.5)], 2), 0.0)
        .unwrap());
    assert_eq!(b.contacts, vec![contact(1, Phase::Move, 150.0, 50.0)]);
}

#[test]
fn calibration_flips_y() {
    let square = |flip_y| {
        Calibration::new(CalibrationSpec::Range {
            x: [0.0, 1.0],
            y: [0.0, 1.0],
            flip_y,
            stage_min: [-1.0, -1.0],
            stage_max: [1.0, 1.0],
        })
        .unwrap()
    };
    let mut t = TuioTracker::new(square(true));
    let f = one(t
        .push(&v1(None, &[1, 2], &[(1, 0.0, 0.0), (2, 1.0, 0.75)], 1), 0.0)
        .unwrap());
    // TUIO's top-left (y down) is the stage's top-left (y up).
    assert_eq!(
        f.contacts,
        vec![
            contact(1, Phase::Down, -1.0, 1.0),
            contact(2, Phase::Down, 1.0, -0.5)
        ]
    );
    let mut t = TuioTracker::new(square(false));
    let f = one(t.push(&v1(None, &[1], &[(1, 0.0, 0.0)], 1), 0.0).unwrap());
    assert_eq!(f.contacts, vec![contact(1, Phase::Down, -1.0, -1.0)]);
}

#[test]
fn v2_down_move_up_and_late_frames() {
    let mut t = tracker();
    let f = one(t
        .push(&v2(1, 100, &[(7, 0.25, 0.25, 0.5)], &[7]), 0.0)
        .unwrap());
    assert_eq!(f.source, SourceId::from("tuio2:table:0@10.0.0.2"));
    assert_eq!(f.time, 100.0, "frm's time is the frame's time");
    let mut down = contact(7, Phase::Down, 50.0, 75.0);
    down.pressure = Some(0.5);
    assert_eq!(f.contacts, vec![down]);

    let f = one(t
        .push(&v2(3, 101, &[(7, 0.5, 0.5, 0.5)], &[7]), 0.0)
        .unwrap());
    let mut moved = contact(7, Phase::Move, 100.0, 50.0);
    moved.pressure = Some(0.5);
    assert_eq!(f.contacts, vec![moved.clone()]);

    // Pressure alone is a change; hover (negative) reads as zero.
    let f = one(t
        .push(&v2(4, 102, &[(7, 0.5, 0.5, -1.0)], &[7]), 0.0)
        .unwrap());
    assert_eq!(f.contacts[0].pressure, Some(0.0));

    // Frame 2 arrives late: ignored.
    assert!(t.push(&v2(2, 100, &[], &[]), 0.0).unwrap().is_empty());

    let f = one(t.push(&v2(5, 103, &[], &[]), 0.0).unwrap());
    assert_eq!(f.contacts.len(), 1);
    assert_eq!(f.contacts[0].phase, Phase::Up);
    assert_eq!(f.contacts[0].position, DVec2::new(100.0, 50.0));
}

#[test]
fn other_profiles_are_skipped() {
    let mut t = tracker();
    let obj = bundle(vec![
        msg("/tuio/2Dobj", vec!["alive".into(), 1i32.into()]),
        msg("/tuio/2Dobj", vec!["fseq".into(), 1i32.into()]),
    ]);
    assert!(t.push(&obj, 0.0).unwrap().is_empty());
}

#[test]
fn malformed_datagrams_are_errors_and_change_nothing() {
    let mut t = tracker();
    one(t.push(&v1(None, &[1], &[(1, 0.25, 0.25)], 1), 0.0).unwrap());

    let err = t.push(b"not osc at all", 0.0).unwrap_err();
    assert!(matches!(err, TuioError::Osc(_)), "{err}");

    // A string where x belongs: the error names the message and argument,
    // and the alive in the same bundle does not lift session 1.
    let bad = bundle(vec![
        cur("alive", vec![]),
        cur("set", vec![1i32.into(), "left".into(), 0.5f32.into()]),
        cur("fseq", vec![2i32.into()]),
    ]);
    let err = t.push(&bad, 0.0).unwrap_err().to_string();
    assert!(err.contains("message 1 (/tuio/2Dcur)"), "{err}");
    assert!(err.contains("argument 2 (x)"), "{err}");

    let no_fseq = bundle(vec![cur("alive", vec![])]);
    assert!(
        t.push(&no_fseq, 0.0)
            .unwrap_err()
            .to_string()
            .contains("fseq")
    );
    let no_alive = bundle(vec![cur("fseq", vec![3i32.into()])]);
    assert!(
        t.push(&no_alive, 0.0)
            .unwrap_err()
            .to_string()
            .contains("alive")
    );
    let stray_ptr = bundle(vec![msg("/tuio2/ptr", vec![1i32.into()])]);
    assert!(
        t.push(&stray_ptr, 0.0)
            .unwrap_err()
            .to_string()
            .contains("frm")
    );

    // Session 1 is still down: the next real frame moves it.
    let f = one(t.push(&v1(None, &[1], &[(1, 0.5, 0.5)], 2), 0.0).unwrap());
    assert_eq!(f.contacts, vec![contact(1, Phase::Move, 100.0, 50.0)]);
}

#[test]
fn source_count_is_capped() {
    let mut t = tracker();
    for i in 0..MAX_SOURCES {
        let name = format!("s{i}");
        t.push(&v1(Some(&name), &[], &[], 1), 0.0).unwrap();
    }
    let err = t
        .push(&v1(Some("one-too-many"), &[], &[], 1), 0.0)
        .unwrap_err();
    assert!(matches!(err, TuioError::TooManySources { .. }), "{err}");
    // Known sources still work.
    one(t
        .push(&v1(Some("s0"), &[1], &[(1, 0.5, 0.5)], 2), 0.0)
        .unwrap());
}

// Generous: loopback UDP on a loaded machine, not the decoder, sets the pace.
const WAIT: Duration = Duration::from_secs(20);

async fn next(rx: &mut mpsc::Receiver<ContactFrame>) -> ContactFrame {
    tokio::time::timeout(WAIT, rx.recv())
        .await
        .expect("a frame within the wait")
        .expect("the source is still running")
}

#[tokio::test]
async fn udp_loopback_survives_alost_datagram() {
    let server = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let addr = server.local_addr().unwrap();
    let (tx, mut rx) = mpsc::channel(2);
    let task = tokio::spawn(run_udp(
        server,
        default_calibration(STAGE).unwrap(),
        puppetry_input::tuio::RELEASE_AFTER,
        tx,
    ));
    let client = UdpSocket::bind("127.0.0.1:0").await.unwrap();

    client
        .send_to(
            &v1(None, &[1, 2], &[(1, 0.25, 0.25), (2, 0.75, 0.75)], 1),
            addr,
        )
        .await
        .unwrap();
    let f = next(&mut rx).await;
    assert_eq!(
        f.contacts,
        vec![
            contact(1, Phase::Down, 50.0, 75.0),
            contact(2, Phase::Down, 150.0, 25.0)
        ]
    );

    // Frame 2 (session 1 moves, session 2 lifts) is "lost": never sent.
    let lost = v1(None, &[1], &[(1, 0.5, 0.25)], 2);
    // A malformed datagram is skipped, not fatal.
    client.send_to(b"garbage", addr).await.unwrap();
    // Frame 3 restates the state: 2 is gone, 1 is somewhere new.
    client
        .send_to(&v1(None, &[1], &[(1, 0.5, 0.5)], 3), addr)
        .await
        .unwrap();
    let f = next(&mut rx).await;
    assert_eq!(
        f.contacts,
        vec![
            contact(2, Phase::Up, 150.0, 25.0),
            contact(1, Phase::Move, 100.0, 50.0)
        ]
    );

    // A late copy of frame 2 arriving now is ignored; frame 4 lifts 1.
    client.send_to(&lost, addr).await.unwrap();
    client.send_to(&v1(None, &[], &[], 4), addr).await.unwrap();
    let f = next(&mut rx).await;
    assert_eq!(f.contacts, vec![contact(1, Phase::Up, 100.0, 50.0)]);

    // Closing the sink ends the source, even while it waits on the socket.
    drop(rx);
    let ended = tokio::time::timeout(WAIT, task)
        .await
        .expect("run_udp ends once the sink closes")
        .unwrap();
    assert!(ended.is_ok(), "{ended:?}");
}

#[test]
fn a_source_silent_past_its_timeout_lets_go_and_lands_afresh_when_it_returns() {
    let mut t = tracker();
    one(t
        .push(&v1(Some("s0"), &[1], &[(1, 0.25, 0.25)], 1), 0.0)
        .unwrap());
    one(t
        .push(&v1(Some("s1"), &[2], &[(2, 0.75, 0.75)], 1), 0.0)
        .unwrap());
    // s1 restates its state (nothing new, so no frame): it is alive.
    assert!(
        t.push(&v1(Some("s1"), &[2], &[(2, 0.75, 0.75)], 2), 2.0)
            .unwrap()
            .is_empty()
    );
    assert!(t.expire(2.5, 3.0).is_empty(), "no one silent for 3 s yet");
    let lifted = t.expire(3.5, 3.0);
    assert_eq!(lifted.len(), 1, "only s0 fell silent: {lifted:?}");
    assert_eq!(lifted[0].source.as_str(), "tuio:s0");
    assert_eq!(lifted[0].contacts, vec![contact(1, Phase::Up, 50.0, 75.0)]);
    // Back, even with an old frame number: a new session, its contact lands.
    let back = one(t
        .push(&v1(Some("s0"), &[1], &[(1, 0.5, 0.5)], 1), 4.0)
        .unwrap());
    assert_eq!(back.contacts, vec![contact(1, Phase::Down, 100.0, 50.0)]);
    // What is left lifts when the loop ends.
    let all = t.lift_all();
    assert_eq!(all.len(), 2);
    assert!(
        all.iter()
            .all(|f| f.contacts.iter().all(|c| c.phase == Phase::Up))
    );
    assert!(!t.holds());
}

#[tokio::test]
async fn udp_a_sender_that_dies_mid_touch_is_let_go() {
    let server = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let addr = server.local_addr().unwrap();
    let (tx, mut rx) = mpsc::channel(2);
    let silence = Duration::from_millis(300);
    let task = tokio::spawn(run_udp(
        server,
        default_calibration(STAGE).unwrap(),
        silence,
        tx,
    ));
    let client = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    client
        .send_to(&v1(Some("table"), &[7], &[(7, 0.25, 0.25)], 1), addr)
        .await
        .unwrap();
    assert_eq!(next(&mut rx).await.contacts[0].phase, Phase::Down);
    // The sender is gone without a goodbye (no empty alive set).
    drop(client);
    let lifted = next(&mut rx).await;
    assert_eq!(lifted.source.as_str(), "tuio:table");
    assert_eq!(lifted.contacts, vec![contact(7, Phase::Up, 50.0, 75.0)]);
    drop(rx);
    let _ = tokio::time::timeout(WAIT, task).await;
}
