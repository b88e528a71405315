//! Mice as puppeteering tools: synthetic event sequences through
//! `MouseDecoder` give exactly the expected pair — landing around the cursor,
//! following it, clamped to the stage, turned by the wheel (hi-res notches
//! counted once) and by a right-button drag, lifted on release, after a drop
//! and on `lift_all` — and a hand-written evemu capture of a wheel mouse
//! parses and replays to the expected drag and turn.

use std::f64::consts::PI;
use std::path::PathBuf;

use glam::DVec2;
use puppetry_input::evdev::{EV_KEY, EV_MSC, EV_REL, EV_SYN, InputEvent, SYN_DROPPED, SYN_REPORT};
use puppetry_input::evemu::EvemuFile;
use puppetry_input::mouse::*;
use puppetry_input::{Contact, ContactFrame, Phase, SourceId};

const STAGE: DVec2 = DVec2::new(400.0, 300.0);
const STEP: f64 = PI / 12.0;

fn settings() -> MouseSettings {
    MouseSettings {
        speed: 1.0,
        pair: true,
        pair_spacing: 20.0,
        rotate_step: STEP,
        start: DVec2::new(100.0, 100.0),
    }
}

fn decoder(settings: MouseSettings) -> MouseDecoder {
    MouseDecoder::new(SourceId::from("mouse0"), settings, STAGE).unwrap()
}

fn ev(time: f64, ev_type: u16, code: u16, value: i32) -> InputEvent {
    InputEvent::new(time, ev_type, code, value)
}

fn rel(code: u16, value: i32) -> InputEvent {
    ev(0.0, EV_REL, code, value)
}

fn key(code: u16, value: i32) -> InputEvent {
    ev(0.0, EV_KEY, code, value)
}

fn syn(time: f64) -> InputEvent {
    ev(time, EV_SYN, SYN_REPORT, 0)
}

/// Pushes one report's events and its `SYN_REPORT`; only the report may
/// answer with a frame.
fn report(mouse: &mut MouseDecoder, time: f64, events: &[InputEvent]) -> Option<ContactFrame> {
    for &event in events {
        assert_eq!(
            mouse.push(event),
            None,
            "{event:?} answered before its report"
        );
    }
    mouse.push(syn(time))
}

fn c(id: u32, phase: Phase, x: f64, y: f64) -> Contact {
    Contact::new(id, phase, DVec2::new(x, y))
}

fn frame(time: f64, contacts: Vec<Contact>) -> ContactFrame {
    ContactFrame {
        source: SourceId::from("mouse0"),
        time,
        contacts,
    }
}

fn ids(frame: &ContactFrame) -> Vec<u32> {
    frame.contacts.iter().map(|c| c.id).collect()
}

fn phases(frame: &ContactFrame) -> Vec<Phase> {
    frame.contacts.iter().map(|c| c.phase).collect()
}

fn assert_close(a: DVec2, b: DVec2) {
    assert!((a - b).length() < 1e-9, "{a} is not {b}");
}

/// The difference of two angles, folded into [-π, π).
fn turn(from: f64, to: f64) -> f64 {
    (to - from + PI).rem_euclid(2.0 * PI) - PI
}

/// Checks a pair frame's two contacts sit `spacing` apart, centred on
/// `centre`, the first pointing to the second along `angle`.
fn assert_pair(frame: &ContactFrame, centre: DVec2, angle: f64, spacing: f64) {
    assert_eq!(frame.contacts.len(), 2, "{frame:?}");
    let (tail, head) = (frame.contacts[0].position, frame.contacts[1].position);
    assert_close((tail + head) / 2.0, centre);
    assert!(((head - tail).length() - spacing).abs() < 1e-9);
    let direction = (head - tail).y.atan2((head - tail).x);
    assert!(
        turn(angle, direction).abs() < 1e-9,
        "pair at {direction}, not {angle}"
    );
}

#[test]
fn for_stage_defaults_centre_the_cursor_and_size_the_pair_to_the_stage() {
    let settings = MouseSettings::for_stage(DVec2::new(1200.0, 600.0));
    assert_eq!(settings.start, DVec2::new(600.0, 300.0));
    assert_eq!(settings.pair_spacing, 50.0);
    assert_eq!(settings.speed, 1.0);
    assert!(settings.pair);
    assert!((settings.rotate_step - 15f64.to_radians()).abs() < 1e-15);
    let mouse = MouseDecoder::new("m".into(), settings, DVec2::new(1200.0, 600.0)).unwrap();
    let cursor = mouse.cursor();
    assert_eq!(cursor.position, DVec2::new(600.0, 300.0));
    assert_eq!(cursor.angle, 0.0);
    assert!(!cursor.holding);
}

#[test]
fn hover_moves_the_cursor_without_frames_and_y_counts_down_the_screen() {
    let mut mouse = decoder(MouseSettings {
        speed: 2.0,
        ..settings()
    });
    assert_eq!(mouse.push(rel(REL_X, 7)), None);
    assert_eq!(mouse.push(rel(REL_Y, 3)), None);
    assert_eq!(
        mouse.cursor().position,
        DVec2::new(100.0, 100.0),
        "the cursor moved before the report ended"
    );
    assert_eq!(mouse.push(syn(0.1)), None);
    assert_eq!(mouse.cursor().position, DVec2::new(114.0, 94.0));
    assert!(!mouse.cursor().holding);
    assert_eq!(mouse.live_contacts(), 0);
}

#[test]
fn press_lands_the_pair_around_the_cursor_and_motion_translates_it() {
    let mut mouse = decoder(settings());
    assert_eq!(
        report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]),
        Some(frame(
            1.0,
            vec![
                c(0, Phase::Down, 90.0, 100.0),
                c(1, Phase::Down, 110.0, 100.0)
            ]
        ))
    );
    assert!(mouse.cursor().holding);
    assert_eq!(mouse.live_contacts(), 2);
    assert_eq!(
        report(&mut mouse, 1.1, &[rel(REL_X, 10), rel(REL_Y, 5)]),
        Some(frame(
            1.1,
            vec![
                c(0, Phase::Move, 100.0, 95.0),
                c(1, Phase::Move, 120.0, 95.0)
            ]
        ))
    );
    // Several events of one axis in one report add up.
    assert_eq!(
        report(&mut mouse, 1.2, &[rel(REL_X, -4), rel(REL_X, -6)]),
        Some(frame(
            1.2,
            vec![
                c(0, Phase::Move, 90.0, 95.0),
                c(1, Phase::Move, 110.0, 95.0)
            ]
        ))
    );
    // A report that moves nothing (here a middle click) gives no frame.
    assert_eq!(report(&mut mouse, 1.3, &[key(BTN_MIDDLE, 1)]), None);
    assert_eq!(report(&mut mouse, 1.4, &[key(BTN_MIDDLE, 0)]), None);
}

#[test]
fn press_with_motion_in_one_report_lands_where_the_report_leaves_the_cursor() {
    let mut mouse = decoder(settings());
    let got = report(&mut mouse, 1.0, &[rel(REL_X, 5), key(BTN_LEFT, 1)]).unwrap();
    assert_eq!(
        got.contacts,
        vec![
            c(0, Phase::Down, 95.0, 100.0),
            c(1, Phase::Down, 115.0, 100.0)
        ]
    );
}

#[test]
fn the_cursor_stops_at_the_stage_edge_and_pushing_further_changes_nothing() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    let got = report(&mut mouse, 1.1, &[rel(REL_X, 1000), rel(REL_Y, 1000)]).unwrap();
    assert_eq!(mouse.cursor().position, DVec2::new(400.0, 0.0));
    assert_eq!(
        got.contacts,
        vec![c(0, Phase::Move, 390.0, 0.0), c(1, Phase::Move, 410.0, 0.0)]
    );
    assert_eq!(report(&mut mouse, 1.2, &[rel(REL_X, 50)]), None);
    let got = report(
        &mut mouse,
        1.3,
        &[rel(REL_X, -1_000_000), rel(REL_Y, -i32::MAX)],
    )
    .unwrap();
    assert_eq!(mouse.cursor().position, DVec2::new(0.0, 300.0));
    assert_eq!(got.contacts[0].position, DVec2::new(-10.0, 300.0));
}

#[test]
fn the_wheel_turns_the_pair_about_the_cursor_one_step_per_notch() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[rel(REL_X, 30), key(BTN_LEFT, 1)]).unwrap();
    let centre = DVec2::new(130.0, 100.0);

    let up = report(&mut mouse, 1.1, &[rel(REL_WHEEL, 1)]).unwrap();
    assert_eq!(phases(&up), vec![Phase::Move, Phase::Move]);
    assert_eq!(ids(&up), vec![0, 1]);
    assert_pair(&up, centre, STEP, 20.0);
    assert_close(
        up.contacts[1].position,
        centre + 10.0 * DVec2::new(STEP.cos(), STEP.sin()),
    );
    assert!((mouse.cursor().angle - STEP).abs() < 1e-12);
    assert_eq!(mouse.cursor().position, centre);

    let three_down = report(&mut mouse, 1.2, &[rel(REL_WHEEL, -3)]).unwrap();
    assert_pair(&three_down, centre, -2.0 * STEP, 20.0);
    assert!((turn(STEP, mouse.cursor().angle) + 3.0 * STEP).abs() < 1e-12);
}

#[test]
fn turning_past_a_half_turn_keeps_the_angle_small() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    let got = report(&mut mouse, 1.1, &[rel(REL_WHEEL, 13)]).unwrap();
    assert!(mouse.cursor().angle.abs() <= PI);
    assert_pair(&got, DVec2::new(100.0, 100.0), 13.0 * STEP, 20.0);
    // 24 notches of 15° are a full turn back to where the pair began.
    let got = report(&mut mouse, 1.2, &[rel(REL_WHEEL, 11)]).unwrap();
    assert_close(got.contacts[0].position, DVec2::new(90.0, 100.0));
    assert_close(got.contacts[1].position, DVec2::new(110.0, 100.0));
}

#[test]
fn a_hi_res_wheel_notch_counts_once_and_partial_notches_turn_partly() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    let centre = DVec2::new(100.0, 100.0);
    // The kernel sends the hi-res value and the notch together.
    let got = report(
        &mut mouse,
        1.1,
        &[rel(REL_WHEEL_HI_RES, 120), rel(REL_WHEEL, 1)],
    )
    .unwrap();
    assert_pair(&got, centre, STEP, 20.0);
    // Either order within the report.
    let got = report(
        &mut mouse,
        1.2,
        &[rel(REL_WHEEL, -1), rel(REL_WHEEL_HI_RES, -120)],
    )
    .unwrap();
    assert_pair(&got, centre, 0.0, 20.0);
    // A fine-grained wheel turns by the part of a notch it reports...
    let got = report(&mut mouse, 1.3, &[rel(REL_WHEEL_HI_RES, 30)]).unwrap();
    assert_pair(&got, centre, STEP / 4.0, 20.0);
    // ...and the notch it completes does not add a whole step.
    let got = report(
        &mut mouse,
        1.4,
        &[rel(REL_WHEEL_HI_RES, 90), rel(REL_WHEEL, 1)],
    )
    .unwrap();
    assert_pair(&got, centre, STEP, 20.0);
    // Once a device has shown its hi-res wheel, a lone REL_WHEEL is a repeat.
    assert_eq!(report(&mut mouse, 1.5, &[rel(REL_WHEEL, 1)]), None);
    assert!((mouse.cursor().angle - STEP).abs() < 1e-12);
}

#[test]
fn the_horizontal_wheel_does_not_turn_the_pair() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    assert_eq!(report(&mut mouse, 1.1, &[rel(REL_HWHEEL, 2)]), None);
    assert_eq!(mouse.cursor().angle, 0.0);
}

#[test]
fn a_right_button_drag_turns_the_pair_instead_of_moving_it() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    let centre = DVec2::new(100.0, 100.0);
    assert_eq!(report(&mut mouse, 1.1, &[key(BTN_RIGHT, 1)]), None);

    // Dragging right turns clockwise, one step per TWIST_COUNTS_PER_STEP.
    let counts = (2.0 * TWIST_COUNTS_PER_STEP) as i32;
    let got = report(&mut mouse, 1.2, &[rel(REL_X, counts), rel(REL_Y, 40)]).unwrap();
    assert_eq!(phases(&got), vec![Phase::Move, Phase::Move]);
    assert_pair(&got, centre, -2.0 * STEP, 20.0);
    assert_eq!(mouse.cursor().position, centre, "the pivot moved");

    let counts = (TWIST_COUNTS_PER_STEP / 2.0) as i32;
    let got = report(&mut mouse, 1.3, &[rel(REL_X, -counts)]).unwrap();
    assert_pair(&got, centre, -1.5 * STEP, 20.0);

    // With the right button up again, motion moves the pair, still turned.
    assert_eq!(report(&mut mouse, 1.4, &[key(BTN_RIGHT, 0)]), None);
    let got = report(&mut mouse, 1.5, &[rel(REL_X, 10), rel(REL_Y, 10)]).unwrap();
    assert_pair(&got, DVec2::new(110.0, 90.0), -1.5 * STEP, 20.0);
}

#[test]
fn the_right_button_counts_from_its_event_within_a_report() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    let counts = TWIST_COUNTS_PER_STEP as i32;
    let got = report(
        &mut mouse,
        1.1,
        &[rel(REL_X, 10), key(BTN_RIGHT, 1), rel(REL_X, counts)],
    )
    .unwrap();
    assert_pair(&got, DVec2::new(110.0, 100.0), -STEP, 20.0);
}

#[test]
fn turning_while_hovering_sets_the_angle_the_next_grab_lands_at() {
    let mut mouse = decoder(settings());
    assert_eq!(report(&mut mouse, 1.0, &[rel(REL_WHEEL, 6)]), None);
    assert!((mouse.cursor().angle - PI / 2.0).abs() < 1e-12);
    let got = report(&mut mouse, 1.1, &[key(BTN_LEFT, 1)]).unwrap();
    assert_eq!(phases(&got), vec![Phase::Down, Phase::Down]);
    assert_close(got.contacts[0].position, DVec2::new(100.0, 90.0));
    assert_close(got.contacts[1].position, DVec2::new(100.0, 110.0));
    // The angle outlives the grab.
    report(&mut mouse, 1.2, &[key(BTN_LEFT, 0)]).unwrap();
    let got = report(&mut mouse, 1.3, &[key(BTN_LEFT, 1)]).unwrap();
    assert_close(got.contacts[1].position, DVec2::new(100.0, 110.0));
}

#[test]
fn release_lifts_both_contacts_where_they_last_were() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    report(&mut mouse, 1.1, &[rel(REL_X, 3)]).unwrap();
    assert_eq!(
        report(&mut mouse, 1.2, &[key(BTN_LEFT, 0)]),
        Some(frame(
            1.2,
            vec![c(0, Phase::Up, 93.0, 100.0), c(1, Phase::Up, 113.0, 100.0)]
        ))
    );
    assert!(!mouse.cursor().holding);
    assert_eq!(mouse.live_contacts(), 0);
    // Hover after the release gives nothing.
    assert_eq!(report(&mut mouse, 1.3, &[rel(REL_X, 3)]), None);
    assert_eq!(report(&mut mouse, 1.4, &[rel(REL_WHEEL, 1)]), None);
}

#[test]
fn each_grab_gets_ids_no_earlier_grab_used() {
    let mut mouse = decoder(settings());
    let mut seen = Vec::new();
    for grab in 0..4 {
        let t = f64::from(grab);
        let down = report(&mut mouse, t, &[key(BTN_LEFT, 1)]).unwrap();
        assert_eq!(phases(&down), vec![Phase::Down, Phase::Down]);
        let pair = ids(&down);
        assert_ne!(pair[0], pair[1]);
        for id in &pair {
            assert!(!seen.contains(id), "grab {grab} reuses id {id}");
        }
        let up = report(&mut mouse, t + 0.5, &[key(BTN_LEFT, 0)]).unwrap();
        assert_eq!(ids(&up), pair);
        assert_eq!(phases(&up), vec![Phase::Up, Phase::Up]);
        seen.extend(pair);
    }
}

#[test]
fn one_point_mode_holds_the_cursor_itself() {
    let mut mouse = decoder(MouseSettings {
        pair: false,
        ..settings()
    });
    assert_eq!(
        report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]),
        Some(frame(1.0, vec![c(0, Phase::Down, 100.0, 100.0)]))
    );
    assert_eq!(mouse.live_contacts(), 1);
    assert_eq!(
        report(&mut mouse, 1.1, &[rel(REL_X, -5), rel(REL_Y, -5)]),
        Some(frame(1.1, vec![c(0, Phase::Move, 95.0, 105.0)]))
    );
    // Turning a single point about itself moves nothing.
    assert_eq!(report(&mut mouse, 1.2, &[rel(REL_WHEEL, 2)]), None);
    assert_eq!(
        report(&mut mouse, 1.3, &[key(BTN_LEFT, 0)]),
        Some(frame(1.3, vec![c(0, Phase::Up, 95.0, 105.0)]))
    );
    let again = report(&mut mouse, 1.4, &[key(BTN_LEFT, 1)]).unwrap();
    assert_eq!(ids(&again), vec![1]);
}

#[test]
fn a_release_lost_in_a_drop_is_lifted_by_resync() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    // A half-written report, the drop, and the events the kernel still had.
    assert_eq!(mouse.push(rel(REL_X, 50)), None);
    assert_eq!(mouse.push(ev(1.1, EV_SYN, SYN_DROPPED, 0)), None);
    assert_eq!(mouse.push(key(BTN_LEFT, 0)), None);
    assert_eq!(mouse.push(rel(REL_X, 20)), None);
    assert_eq!(
        mouse.push(syn(1.2)),
        None,
        "the report ending a drop counts"
    );
    assert_eq!(mouse.cursor().position, DVec2::new(100.0, 100.0));
    assert!(mouse.cursor().holding);
    assert_eq!(
        mouse.resync(1.3, false, false),
        Some(frame(
            1.3,
            vec![c(0, Phase::Up, 90.0, 100.0), c(1, Phase::Up, 110.0, 100.0)]
        ))
    );
    assert!(!mouse.cursor().holding);
    // Back to normal: the next report counts again.
    assert_eq!(report(&mut mouse, 1.4, &[rel(REL_X, 5)]), None);
    assert_eq!(mouse.cursor().position, DVec2::new(105.0, 100.0));
}

#[test]
fn without_resync_a_drop_loses_the_whole_report_it_cut_short() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    mouse.push(rel(REL_X, 50));
    mouse.push(rel(REL_WHEEL, 3));
    mouse.push(key(BTN_RIGHT, 1));
    mouse.push(ev(1.1, EV_SYN, SYN_DROPPED, 0));
    mouse.push(rel(REL_Y, 70));
    assert_eq!(mouse.push(syn(1.2)), None);
    assert_eq!(
        report(&mut mouse, 1.3, &[rel(REL_X, 5)]),
        Some(frame(
            1.3,
            vec![
                c(0, Phase::Move, 95.0, 100.0),
                c(1, Phase::Move, 115.0, 100.0)
            ]
        ))
    );
    assert_eq!(mouse.cursor().angle, 0.0);
}

#[test]
fn resync_lands_a_press_lost_in_a_drop_and_keeps_a_grab_still_held() {
    let mut mouse = decoder(settings());
    mouse.push(ev(1.0, EV_SYN, SYN_DROPPED, 0));
    mouse.push(key(BTN_LEFT, 1));
    mouse.push(syn(1.1));
    let got = mouse.resync(1.2, true, false).unwrap();
    assert_eq!(got.time, 1.2);
    assert_eq!(phases(&got), vec![Phase::Down, Phase::Down]);
    assert_eq!(mouse.resync(1.3, true, false), None);
    // The right button read back makes the next drag turn.
    assert_eq!(mouse.resync(1.4, true, true), None);
    let counts = TWIST_COUNTS_PER_STEP as i32;
    let got = report(&mut mouse, 1.5, &[rel(REL_X, counts)]).unwrap();
    assert_pair(&got, DVec2::new(100.0, 100.0), -STEP, 20.0);
}

#[test]
fn a_press_during_a_grab_ends_it_and_starts_another() {
    // A replay cannot resync: the press after a lost release still must
    // not leave the old pair stuck.
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1)]).unwrap();
    mouse.push(ev(1.1, EV_SYN, SYN_DROPPED, 0));
    mouse.push(key(BTN_LEFT, 0));
    mouse.push(syn(1.1));
    let got = report(&mut mouse, 1.2, &[rel(REL_X, 5), key(BTN_LEFT, 1)]).unwrap();
    assert_eq!(
        got.contacts,
        vec![
            c(0, Phase::Up, 95.0, 100.0),
            c(1, Phase::Up, 115.0, 100.0),
            c(2, Phase::Down, 95.0, 100.0),
            c(3, Phase::Down, 115.0, 100.0),
        ]
    );
    // Autorepeat (value 2) is the button still held, not a new grab.
    assert_eq!(report(&mut mouse, 1.3, &[key(BTN_LEFT, 2)]), None);
    // A click inside one report is a new grab too.
    let got = report(&mut mouse, 1.4, &[key(BTN_LEFT, 0), key(BTN_LEFT, 1)]).unwrap();
    assert_eq!(ids(&got), vec![2, 3, 4, 5]);
    assert_eq!(
        phases(&got),
        vec![Phase::Up, Phase::Up, Phase::Down, Phase::Down]
    );
}

#[test]
fn lift_all_lets_go_and_forgets_the_buttons() {
    let mut mouse = decoder(settings());
    report(&mut mouse, 1.0, &[key(BTN_LEFT, 1), key(BTN_RIGHT, 1)]).unwrap();
    mouse.push(rel(REL_X, 10)); // an unfinished report, lost with the device
    assert_eq!(
        mouse.lift_all(2.0),
        Some(frame(
            2.0,
            vec![c(0, Phase::Up, 90.0, 100.0), c(1, Phase::Up, 110.0, 100.0)]
        ))
    );
    assert_eq!(mouse.lift_all(2.1), None);
    assert!(!mouse.cursor().holding);
    assert_eq!(mouse.cursor().position, DVec2::new(100.0, 100.0));
    // The right button was forgotten: motion moves again.
    assert_eq!(report(&mut mouse, 2.2, &[rel(REL_X, 10)]), None);
    assert_eq!(mouse.cursor().position, DVec2::new(110.0, 100.0));
    assert_eq!(mouse.cursor().angle, 0.0);
}

#[test]
fn bad_settings_are_refused_by_name() {
    let refused = |settings: MouseSettings, stage: DVec2| match MouseDecoder::new(
        "m".into(),
        settings,
        stage,
    ) {
        Err(MouseError::Invalid { field, problem }) => {
            assert!(!problem.is_empty());
            field
        }
        Ok(_) => panic!("accepted"),
    };
    let s = settings;
    assert_eq!(refused(MouseSettings { speed: 0.0, ..s() }, STAGE), "speed");
    assert_eq!(
        refused(MouseSettings { speed: -1.0, ..s() }, STAGE),
        "speed"
    );
    assert_eq!(
        refused(
            MouseSettings {
                speed: f64::NAN,
                ..s()
            },
            STAGE
        ),
        "speed"
    );
    assert_eq!(
        refused(
            MouseSettings {
                pair_spacing: 0.0,
                ..s()
            },
            STAGE
        ),
        "pair_spacing"
    );
    assert_eq!(
        refused(
            MouseSettings {
                pair_spacing: f64::INFINITY,
                ..s()
            },
            STAGE
        ),
        "pair_spacing"
    );
    assert_eq!(
        refused(
            MouseSettings {
                rotate_step: -STEP,
                ..s()
            },
            STAGE
        ),
        "rotate_step"
    );
    assert_eq!(
        refused(
            MouseSettings {
                rotate_step: 7.0,
                ..s()
            },
            STAGE
        ),
        "rotate_step"
    );
    assert_eq!(
        refused(
            MouseSettings {
                start: DVec2::new(401.0, 10.0),
                ..s()
            },
            STAGE
        ),
        "start"
    );
    assert_eq!(
        refused(
            MouseSettings {
                start: DVec2::new(10.0, f64::NAN),
                ..s()
            },
            STAGE
        ),
        "start"
    );
    assert_eq!(refused(s(), DVec2::new(400.0, 0.0)), "stage_size");
    assert_eq!(refused(s(), DVec2::new(f64::INFINITY, 1.0)), "stage_size");
    let message = MouseDecoder::new("m".into(), MouseSettings { speed: 0.0, ..s() }, STAGE)
        .unwrap_err()
        .to_string();
    assert!(message.contains("speed"), "{message}");
    // The corners of the stage are on it.
    for start in [DVec2::ZERO, STAGE] {
        assert!(MouseDecoder::new("m".into(), MouseSettings { start, ..s() }, STAGE).is_ok());
    }
}

fn capture_path() -> PathBuf {
    puppetry_testkit::root().join("tests/fixtures/mouse-drag.event")
}

#[test]
fn the_wheel_mouse_capture_parses_as_evemu() {
    let capture = EvemuFile::read(&capture_path()).unwrap();
    assert_eq!(capture.device.name, "Puppetry Synthetic Wheel Mouse");
    assert!(
        capture.device.axes.is_empty(),
        "a mouse has no absolute axes"
    );
    let bit = |ev_type: u16, code: u16| {
        let bytes = &capture.device.event_bits[&ev_type];
        bytes
            .get(usize::from(code / 8))
            .is_some_and(|b| b & (1 << (code % 8)) != 0)
    };
    for button in [BTN_LEFT, BTN_RIGHT, BTN_MIDDLE] {
        assert!(bit(EV_KEY, button), "button {button:#x}");
    }
    for axis in [REL_X, REL_Y, REL_WHEEL, REL_WHEEL_HI_RES] {
        assert!(bit(EV_REL, axis), "axis {axis:#x}");
    }
    assert!(!bit(EV_REL, REL_HWHEEL));
    let reports = capture
        .events
        .iter()
        .filter(|e| (e.ev_type, e.code) == (EV_SYN, SYN_REPORT))
        .count();
    assert_eq!(reports, 10);
    assert!(capture.events.iter().any(|e| e.ev_type == EV_MSC));
}

#[test]
fn the_wheel_mouse_capture_drags_and_turns_the_pair() {
    let capture = EvemuFile::read(&capture_path()).unwrap();
    let stage = DVec2::new(640.0, 480.0);
    let settings = MouseSettings {
        pair_spacing: 40.0,
        ..MouseSettings::for_stage(stage)
    };
    let mut mouse = MouseDecoder::new("capture".into(), settings, stage).unwrap();
    let frames: Vec<ContactFrame> = capture
        .events
        .iter()
        .filter_map(|&e| mouse.push(e))
        .collect();
    // The capture hovers by (-40, +20) counts, drags by (+15, -10), turns
    // two notches up and lets go.
    let grabbed_at = DVec2::new(280.0, 220.0);
    let dropped_at = DVec2::new(295.0, 230.0);
    let kinds: Vec<Vec<Phase>> = frames.iter().map(phases).collect();
    let mut expected = vec![vec![Phase::Down; 2]];
    expected.extend(vec![vec![Phase::Move; 2]; 6]);
    expected.push(vec![Phase::Up; 2]);
    assert_eq!(kinds, expected);
    assert!(frames.iter().all(|f| ids(f) == vec![0, 1]));

    assert_eq!(frames[0].time, 0.5);
    assert_pair(&frames[0], grabbed_at, 0.0, 40.0);
    assert_pair(&frames[4], dropped_at, 0.0, 40.0);
    assert_pair(&frames[5], dropped_at, STEP, 40.0);
    assert_pair(&frames[6], dropped_at, 2.0 * STEP, 40.0);
    assert_pair(&frames[7], dropped_at, 2.0 * STEP, 40.0);
    assert_eq!(frames[7].time, 1.6);
    assert_eq!(
        mouse.cursor(),
        Cursor {
            position: dropped_at,
            angle: mouse.cursor().angle,
            holding: false
        }
    );
    assert!((mouse.cursor().angle - 2.0 * STEP).abs() < 1e-12);
}
