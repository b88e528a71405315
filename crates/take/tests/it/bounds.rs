//! A take is bounded as it is read (`puppetry_limits::files`): a step's
//! time, its changes and its contacts, and the contacts held at once, so a
//! crafted take can neither panic a player (`t = 1e20` made a `Duration`
//! overflow) nor stall a replay (20,000 contacts in one step drove
//! `takes --verify` past 30 s and 6.6 GB). A FIFO named as a take is
//! refused before it is opened.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_limits::files::{MAX_TAKE_CONTACTS, MAX_TAKE_STEP_CHANGES};
use puppetry_stage::Change;
use puppetry_take::{Header, Record, Step, TakeError, TakeReader, TakeWriter};

fn header() -> Header {
    Header {
        version: puppetry_take::VERSION,
        name: "t".into(),
        stage_file: "demo.toml".into(),
        stage_width: 1280.0,
        stage_height: 720.0,
        puppets: Vec::new(),
        started_unix: 1.0,
        fresh: true,
        layers: Vec::new(),
        on_stage: None,
    }
}

fn contacts(source: &str, ids: std::ops::Range<u32>, phase: Phase) -> Change {
    Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new(source),
            time: 0.0,
            contacts: ids
                .map(|id| Contact::new(id, phase, DVec2::new(10.0, 10.0)))
                .collect(),
        },
    }
}

fn write(path: &Path, steps: Vec<Step>) {
    let mut writer = TakeWriter::create(path, &header()).unwrap();
    for step in steps {
        writer.write(&Record::Step(step)).unwrap();
    }
    writer.flush().unwrap();
}

/// Every error the take gives when read, as text.
fn errors(path: &Path) -> Vec<String> {
    TakeReader::open(path)
        .unwrap()
        .filter_map(|r| r.err().map(|e| e.to_string()))
        .collect()
}

fn step(t: f64, changes: Vec<Change>) -> Step {
    Step {
        t,
        changes,
        events: Vec::new(),
    }
}

#[test]
fn a_step_time_past_a_week_or_below_zero_is_refused_by_record() {
    let dir = tempfile::tempdir().unwrap();
    for (i, t) in [1e20, -1.0, f64::MAX].into_iter().enumerate() {
        let path = dir.path().join(format!("t{i}.take"));
        write(&path, vec![step(0.5, vec![]), step(t, vec![])]);
        let errors = errors(&path);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].contains("record 2") && errors[0].contains("MAX_TAKE_SECONDS"),
            "{errors:?}"
        );
    }
}

#[test]
fn a_step_of_twenty_thousand_contacts_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crowd.take");
    write(
        &path,
        vec![step(
            0.1,
            vec![contacts("client:1", 0..20_000, Phase::Down)],
        )],
    );
    let errors = errors(&path);
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].contains("MAX_TAKE_CONTACTS"), "{errors:?}");
}

#[test]
fn contacts_held_across_steps_are_bounded_and_lifting_makes_room() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("held.take");
    let n = MAX_TAKE_CONTACTS as u32;
    // Many sources each landing a few, never lifting: the step that would
    // hold one more than the budget is refused, and only it.
    let mut steps: Vec<Step> = (0..n / 8)
        .map(|s| step(0.1, vec![contacts(&format!("s{s}"), 0..8, Phase::Down)]))
        .collect();
    steps.push(step(0.2, vec![contacts("late", 0..1, Phase::Down)]));
    // A source going away lifts what it held: then there is room.
    steps.push(step(
        0.3,
        vec![Change::Release {
            source: "s0".into(),
        }],
    ));
    steps.push(step(0.4, vec![contacts("late", 0..8, Phase::Down)]));
    write(&path, steps);
    let errors = errors(&path);
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].contains("held down at once"), "{errors:?}");
}

#[test]
fn a_step_of_too_many_changes_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("changes.take");
    let changes = (0..=MAX_TAKE_STEP_CHANGES)
        .map(|_| Change::Release { source: "x".into() })
        .collect();
    write(&path, vec![step(0.1, changes)]);
    let errors = errors(&path);
    assert!(errors[0].contains("MAX_TAKE_STEP_CHANGES"), "{errors:?}");
}

#[test]
fn a_fifo_named_as_a_take_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pipe.take");
    let made = std::process::Command::new("mkfifo").arg(&path).status();
    if !made.is_ok_and(|s| s.success()) {
        eprintln!("skipped: mkfifo is not available");
        return;
    }
    // Before the fix this blocked for ever, waiting for a writer.
    let error = TakeReader::open(&path).err().expect("refused");
    assert!(matches!(error, TakeError::File(_)), "{error}");
    assert!(error.to_string().contains("FIFO"), "{error}");
}

/// A show clock reading reads back as written; one whose take time or
/// show time is not a number of seconds within a week is refused by
/// record, and a take of a newer version than this build is refused as
/// newer, not as damage.
#[test]
fn clock_readings_round_trip_and_are_bounded() {
    use puppetry_take::{Clock, ClockSource};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("clock.take");
    let clock = |t: f64, show: f64| Clock {
        t,
        show,
        running: true,
        source: ClockSource::TimeCode,
    };
    let mut writer = TakeWriter::create(&path, &header()).unwrap();
    for c in [clock(0.08, 11.31), clock(0.16, 1e300), clock(-1.0, 3.0)] {
        writer.write(&Record::Clock(c)).unwrap();
    }
    writer.write(&Record::Clock(clock(0.24, -1e9))).unwrap();
    writer.flush().unwrap();
    let records: Vec<_> = TakeReader::open(&path).unwrap().collect();
    assert_eq!(records.len(), 4);
    assert_eq!(
        records[0].as_ref().unwrap(),
        &Record::Clock(clock(0.08, 11.31))
    );
    for (i, r) in records[1..].iter().enumerate() {
        let e = r.as_ref().unwrap_err().to_string();
        assert!(
            e.contains(&format!("record {}", i + 2)) && e.contains("MAX_TAKE_SECONDS"),
            "{e}"
        );
    }

    let newer = dir.path().join("newer.take");
    let mut h = header();
    h.version = puppetry_take::VERSION + 1;
    TakeWriter::create(&newer, &h).unwrap().flush().unwrap();
    let e = TakeReader::open(&newer).err().unwrap().to_string();
    assert!(e.contains("newer than this build reads"), "{e}");
}
