use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::{Change, GripEvent, StageEvent};
use puppetry_take::recorder::Recorder;
use puppetry_take::{Frame, Header, Record, Step, Tail, TakeError, TakeReader, summarize};

fn header(name: &str) -> Header {
    Header {
        version: puppetry_take::VERSION,
        name: name.into(),
        stage_file: "demo.toml".into(),
        stage_width: 1600.0,
        stage_height: 900.0,
        puppets: Vec::new(),
        started_unix: 1.0,
        fresh: true,
        layers: Vec::new(),
        on_stage: None,
    }
}

fn step(i: usize) -> Step {
    Step {
        t: i as f64 * 0.001,
        changes: vec![Change::Contacts {
            frame: ContactFrame {
                source: SourceId::new("evdev0"),
                time: 12.5 + i as f64 / 3.0,
                contacts: vec![Contact::new(
                    7,
                    if i == 0 { Phase::Down } else { Phase::Move },
                    DVec2::new(100.0 + i as f64 / 7.0, 0.1 + 0.2),
                )],
            },
        }],
        events: vec![StageEvent::Made {
            puppet: 0,
            handle: 3,
            owner: "evdev0".into(),
            contact: Some(7),
            kind: "contact".into(),
            grip: GripEvent::Point {
                rest: DVec2::new(1.0 / 3.0, 2.0),
            },
            at: DVec2::new(5.0, 6.0),
        }],
    }
}

fn frame(i: usize) -> Frame {
    Frame {
        puppet: 0,
        t: i as f64 * 0.001,
        points: (0..50)
            .map(|v| [v as f32 / 3.0 + i as f32, -(v as f32) * 1.1])
            .collect(),
    }
}

fn record(path: &Path, steps: usize) {
    let recorder = Recorder::start(path, &header("t1")).unwrap();
    for i in 0..steps {
        recorder.record(Record::Step(step(i))).unwrap();
        recorder.record(Record::Frame(frame(i))).unwrap();
    }
    recorder.finish("stopped").unwrap();
}

fn read_all(path: &Path) -> (Vec<Record>, Tail) {
    let mut reader = TakeReader::open(path).unwrap();
    let records: Vec<Record> = reader.by_ref().map(|r| r.unwrap()).collect();
    (records, reader.tail().cloned().unwrap())
}

#[test]
fn records_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t1.take");
    record(&path, 20);
    let (records, tail) = read_all(&path);
    assert_eq!(records.len(), 41);
    for i in 0..20 {
        assert_eq!(records[2 * i], Record::Step(step(i)));
        assert_eq!(records[2 * i + 1], Record::Frame(frame(i)));
    }
    assert!(matches!(tail, Tail::Ended(ref e) if e.reason == "stopped"));
    let summary = summarize(&path).unwrap();
    assert_eq!((summary.steps, summary.frames), (20, 20));
    assert_eq!(summary.ending, "stopped");
}

#[test]
fn a_cut_tail_is_reported_and_everything_before_it_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t1.take");
    record(&path, 10);
    let whole = std::fs::read(&path).unwrap();
    let (all, _) = read_all(&path);
    // Cut at every byte of the last three records: never an error, never a
    // record lost before the cut.
    let cut_from = whole.len() - 3 * (frame(0).points.len() * 8 + 30);
    for cut in cut_from..whole.len() {
        let cut_path = dir.path().join("cut.take");
        std::fs::write(&cut_path, &whole[..cut]).unwrap();
        let (records, tail) = read_all(&cut_path);
        assert_eq!(records[..], all[..records.len()], "cut at {cut}");
        match tail {
            Tail::Truncated { bytes, .. } => assert!(bytes > 0),
            Tail::Unended => {}
            Tail::Ended(_) => panic!("cut at {cut} still ended"),
        }
        let summary = summarize(&cut_path).unwrap();
        assert_ne!(summary.ending, "stopped");
    }
}

/// A damaged record with more of the take after it is damage, not a cut
/// tail: an error naming the record, which `summarize` (and so `takes`)
/// reports; the records after it can still be read.
#[test]
fn a_damaged_record_mid_take_is_an_error_not_a_cut_tail() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t1.take");
    record(&path, 10);
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes.len() / 2;
    bytes[at] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let mut reader = TakeReader::open(&path).unwrap();
    let (mut good, mut bad) = (0, Vec::new());
    for record in reader.by_ref() {
        match record {
            Ok(_) => good += 1,
            Err(e) => bad.push(e.to_string()),
        }
    }
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(
        bad[0].contains("checksum mismatch") && bad[0].contains("damaged"),
        "{bad:?}"
    );
    assert!(bad[0].starts_with(&path.display().to_string()), "{bad:?}");
    // Every other record, the end among them, is still there.
    assert_eq!(good, 20);
    assert!(matches!(reader.tail(), Some(Tail::Ended(_))));
    let summary = summarize(&path).unwrap_err().to_string();
    assert!(summary.contains("damaged"), "{summary}");
}

/// Both kinds of damage name the damaged record itself: a wrong length
/// field named the record before it (the index was counted after the
/// error was made).
#[test]
fn damage_names_the_damaged_record() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t1.take");
    record(&path, 10);
    let whole = std::fs::read(&path).unwrap();
    // Record k's framing: its length field's offset (the header is 0).
    let mut starts = Vec::new();
    let mut at = puppetry_take::MAGIC.len();
    while at < whole.len() {
        starts.push(at);
        let length = u32::from_le_bytes(whole[at..at + 4].try_into().unwrap()) as usize;
        at += 4 + length + 4;
    }
    let damaged_index = |bytes: &[u8]| {
        std::fs::write(&path, bytes).unwrap();
        let mut reader = TakeReader::open(&path).unwrap();
        reader
            .by_ref()
            .find_map(|r| match r {
                Err(TakeError::Corrupt { index, .. }) => Some(index),
                _ => None,
            })
            .expect("an error names the damage")
    };
    let k = 5;
    let mut bad_length = whole.clone();
    bad_length[starts[k]..starts[k] + 4].copy_from_slice(&0u32.to_le_bytes());
    assert_eq!(damaged_index(&bad_length), k);
    let mut bad_sum = whole.clone();
    bad_sum[starts[k] + 5] ^= 0x40;
    assert_eq!(damaged_index(&bad_sum), k);
}

#[test]
fn foreign_files_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notes.take");
    std::fs::write(&path, "hello").unwrap();
    let err = TakeReader::open(&path).err().unwrap();
    assert!(matches!(err, TakeError::NotATake { .. }));
    assert!(err.to_string().contains("notes.take"), "{err}");
    let missing = TakeReader::open(&dir.path().join("gone.take"))
        .err()
        .unwrap();
    assert!(missing.to_string().contains("gone.take"), "{missing}");
}

#[test]
fn a_take_is_never_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t1.take");
    record(&path, 1);
    let again = Recorder::start(&path, &header("t1")).err().unwrap();
    assert!(matches!(again, TakeError::Exists { .. }), "{again}");
}

#[test]
fn an_unwritable_folder_is_an_error_naming_it() {
    let err = Recorder::start(Path::new("/proc/no/such/t.take"), &header("t"))
        .err()
        .unwrap();
    assert!(err.to_string().contains("/proc/no/such/t.take"), "{err}");
}
