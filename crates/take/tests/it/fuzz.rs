//! Fuzzing the take reader, which reads files anyone can drop into the
//! takes folder or upload: random bytes after the magic, byte edits of a
//! real take (which mostly trip the checksum), and takes re-framed with
//! valid lengths and checksums around mutated record payloads (header, step
//! and end JSON with fields mutated; frame records with lying counts), so
//! the decoding behind the checksum is reached too. Every case must end in
//! records, a tail, or an error naming the file. See `docs/fuzzing.md`.

use std::path::Path;

use proptest::prelude::*;
use puppetry_take::{MAGIC, TakeReader, summarize};
use puppetry_testkit::fuzz::{self, config};

const HEADER: &str = r#"{"version":1,"name":"t","stage_file":"demo.toml","stage_width":1600.0,"stage_height":900.0,"puppets":[{"name":"gingerbread","vertices":3,"triangles":1,"rest_hash":"00ff"}],"started_unix":1.0,"fresh":true}"#;
const STEP: &str = r#"{"t":0.5,"changes":[{"type":"contacts","frame":{"source":"evdev0","time":1.0,"contacts":[{"id":7,"phase":"down","position":[1.0,2.0]}]}}],"events":[]}"#;
const END: &str = r#"{"t":1.0,"reason":"stopped"}"#;

fn record(kind: u8, payload: &[u8]) -> Vec<u8> {
    let mut data = vec![kind];
    data.extend_from_slice(payload);
    let mut out = (data.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(&data);
    out.extend_from_slice(&crc32fast::hash(&data).to_le_bytes());
    out
}

fn frame_payload(puppet: u32, t: f64, count: u32, points: usize) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&puppet.to_le_bytes());
    out.extend_from_slice(&t.to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    for i in 0..points * 2 {
        out.extend_from_slice(&(i as f32).to_le_bytes());
    }
    out
}

fn valid_take() -> Vec<u8> {
    let mut take = MAGIC.to_vec();
    take.extend(record(1, HEADER.as_bytes()));
    take.extend(record(2, STEP.as_bytes()));
    take.extend(record(3, &frame_payload(0, 0.5, 3, 3)));
    take.extend(record(4, END.as_bytes()));
    take
}

/// Reads `bytes` as a take file every way the daemon does.
fn check_take(bytes: &[u8]) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz.take");
    std::fs::write(&path, bytes).unwrap();
    let name = path.display().to_string();
    match TakeReader::open(&path) {
        Ok(reader) => {
            for record in reader {
                if let Err(e) = record {
                    assert!(e.to_string().starts_with(&name), "{e}");
                }
            }
        }
        Err(e) => assert!(e.to_string().starts_with(&name), "{e}"),
    }
    if let Err(e) = summarize(&path) {
        assert!(e.to_string().starts_with(&name), "{e}");
    }
    let _ = puppetry_take::list(dir.path());
}

fn framed_record() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        fuzz::mutated_json(vec![HEADER.into()]).prop_map(|j| record(1, j.as_bytes())),
        fuzz::mutated_json(vec![STEP.into()]).prop_map(|j| record(2, j.as_bytes())),
        fuzz::mutated_json(vec![END.into()]).prop_map(|j| record(4, j.as_bytes())),
        (
            any::<u32>(),
            any::<f64>(),
            prop_oneof![0u32..8, any::<u32>()],
            0usize..8
        )
            .prop_map(|(p, t, c, n)| record(3, &frame_payload(p, t, c, n))),
        (any::<u8>(), fuzz::bytes(40)).prop_map(|(k, b)| record(k, &b)),
    ]
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_take_random_bytes(bytes in fuzz::bytes(200), magic in any::<bool>()) {
        let mut take = if magic { MAGIC.to_vec() } else { Vec::new() };
        take.extend(bytes);
        check_take(&take);
    }

    #[test]
    fn fuzz_take_mutated_bytes(take in fuzz::mutated_bytes(vec![valid_take()])) {
        check_take(&take);
    }

    #[test]
    fn fuzz_take_mutated_records(
        header in prop_oneof![Just(record(1, HEADER.as_bytes())), framed_record()],
        records in proptest::collection::vec(framed_record(), 0..5),
        cut in any::<proptest::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let mut take = MAGIC.to_vec();
        take.extend(header);
        for r in records {
            take.extend(r);
        }
        if truncate {
            take.truncate(cut.index(take.len() + 1));
        }
        check_take(&take);
    }
}

#[test]
fn the_fuzz_seed_is_a_whole_take() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("seed.take");
    std::fs::write(&path, valid_take()).unwrap();
    let summary = summarize(Path::new(&path)).unwrap();
    assert_eq!((summary.steps, summary.frames), (1, 1));
    assert_eq!(summary.ending, "stopped");
}
