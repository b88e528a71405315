//! Key-pose sets: blending reproduces each key and moves continuously over
//! the pad, live edits keep it so, key files are checked with errors naming
//! the file and the field, saving round-trips, and blending does not
//! allocate.

use std::path::{Path, PathBuf};

use glam::DVec2;
use puppetry_stage::keys::{KeyEntry, KeyFile, KeyGrip, KeySet, KeysError, Problem};
use puppetry_testkit::alloc;

/// A small deterministic generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn key(name: &str, at: [f64; 2], values: Vec<f64>) -> KeyEntry {
    KeyEntry {
        name: name.into(),
        at,
        values,
    }
}

/// `count` keys of `width` values at scattered pad points at least 0.1 apart.
fn keys(count: usize, width: usize, seed: u64) -> Vec<KeyEntry> {
    let mut rng = Rng(seed);
    let mut entries: Vec<KeyEntry> = Vec::new();
    while entries.len() < count {
        let at = [rng.unit(), rng.unit()];
        if entries
            .iter()
            .all(|e| DVec2::from(e.at).distance(DVec2::from(at)) >= 0.1)
        {
            let values = (0..width).map(|_| rng.unit() * 200.0 - 100.0).collect();
            entries.push(key(&format!("pose {}", entries.len()), at, values));
        }
    }
    entries
}

fn blend(set: &mut KeySet, cursor: DVec2) -> Vec<f64> {
    let mut out = vec![0.0; set.width()];
    assert!(set.blend_into(cursor, &mut out));
    out
}

/// Every key of `set` comes back exactly (to 1e-9) with the cursor on it.
fn assert_interpolates(set: &mut KeySet) {
    for entry in set.keys().to_vec() {
        let got = blend(set, DVec2::from(entry.at));
        for (i, (g, v)) in got.iter().zip(&entry.values).enumerate() {
            assert!(
                (g - v).abs() < 1e-9,
                "{}: value {i} is {g}, not {v}",
                entry.name
            );
        }
    }
}

#[test]
fn the_cursor_on_a_key_gives_its_values() {
    let mut set = KeySet::new(keys(9, 8, 1), 8).unwrap();
    assert_interpolates(&mut set);
    // Keys on the pad's corners and edges too.
    let corners = vec![
        key("a", [0.0, 0.0], vec![1.0, 2.0]),
        key("b", [1.0, 0.0], vec![-3.0, 5.0]),
        key("c", [1.0, 1.0], vec![7.0, -1.0]),
        key("d", [0.0, 1.0], vec![0.5, 0.25]),
        key("e", [0.5, 0.0], vec![10.0, 10.0]),
    ];
    assert_interpolates(&mut KeySet::new(corners, 2).unwrap());
}

#[test]
fn one_key_gives_its_values_everywhere() {
    let values = vec![3.5, -2.25, 1e3, 0.0];
    let mut set = KeySet::new(vec![key("only", [0.4, 0.6], values.clone())], 4).unwrap();
    for cursor in [
        DVec2::ZERO,
        DVec2::ONE,
        DVec2::new(0.4, 0.6),
        DVec2::new(0.9, 0.1),
        DVec2::new(-5.0, 7.0),
    ] {
        assert_eq!(blend(&mut set, cursor), values, "at {cursor}");
    }
}

#[test]
fn no_keys_blend_nothing() {
    let mut set = KeySet::new(Vec::new(), 4).unwrap();
    assert!(set.blend().is_none());
    let mut out = [9.0; 4];
    assert!(!set.blend_into(DVec2::splat(0.5), &mut out));
    assert_eq!(out, [9.0; 4]);
    // Nor with a wrong-sized output or a cursor that is no point.
    let mut set = KeySet::new(keys(3, 4, 2), 4).unwrap();
    let mut short = [9.0; 3];
    assert!(!set.blend_into(DVec2::splat(0.5), &mut short));
    assert!(!set.blend_into(DVec2::new(f64::NAN, 0.5), &mut out));
    assert_eq!((short, out), ([9.0; 3], [9.0; 4]));
}

#[test]
fn a_cursor_off_the_pad_is_taken_to_its_edge() {
    let mut set = KeySet::new(keys(5, 3, 3), 3).unwrap();
    assert_eq!(
        blend(&mut set, DVec2::new(-0.5, 0.3)),
        blend(&mut set, DVec2::new(0.0, 0.3))
    );
    assert_eq!(
        blend(&mut set, DVec2::new(4.0, 9.0)),
        blend(&mut set, DVec2::ONE)
    );
}

/// A bound on how far the blend moves per unit of cursor travel, from the
/// data: the weights sum to one, so `out(a) − out(b) = Σ_k (w_k(a) −
/// w_k(b)) (v_k − v_0)`, and each weight is `lipschitz()[k]`-Lipschitz.
fn lipschitz_bound(set: &KeySet) -> f64 {
    let blend = set.blend().unwrap();
    let first = &set.keys()[0].values;
    set.keys()
        .iter()
        .zip(blend.lipschitz())
        .map(|(entry, l)| {
            let spread = entry
                .values
                .iter()
                .zip(first)
                .fold(0.0f64, |m, (v, f)| m.max((v - f).abs()));
            l * spread
        })
        .sum()
}

/// The largest change of any value between neighbouring samples of a
/// `(steps + 1)²` sweep of the pad, each checked against `bound · step`.
fn max_jump(set: &mut KeySet, steps: usize, bound: f64) -> f64 {
    let side = steps + 1;
    let step = 1.0 / steps as f64;
    let mut previous_row: Vec<Vec<f64>> = Vec::new();
    let mut largest = 0.0f64;
    for row in 0..side {
        let samples: Vec<Vec<f64>> = (0..side)
            .map(|col| blend(set, DVec2::new(col as f64, row as f64) * step))
            .collect();
        for col in 0..side {
            let left = (col > 0).then(|| &samples[col - 1]);
            let below = previous_row.get(col);
            for neighbour in [left, below].into_iter().flatten() {
                for (a, b) in samples[col].iter().zip(neighbour) {
                    let jump = (a - b).abs();
                    assert!(
                        jump <= bound * step * (1.0 + 1e-9) + 1e-9,
                        "a jump of {jump} at row {row}, column {col} (bound {})",
                        bound * step
                    );
                    largest = largest.max(jump);
                }
            }
        }
        previous_row = samples;
    }
    largest
}

#[test]
fn a_dense_sweep_of_the_pad_never_jumps() {
    let mut set = KeySet::new(keys(7, 6, 4), 6).unwrap();
    let bound = lipschitz_bound(&set);
    assert!(bound.is_finite() && bound > 0.0);
    let coarse = max_jump(&mut set, 200, bound);
    let fine = max_jump(&mut set, 400, bound);
    assert!(coarse > 0.0);
    // Halving the step about halves the largest jump: nothing discontinuous.
    assert!(fine < 0.6 * coarse, "{coarse} then {fine}");
}

#[test]
fn edits_keep_interpolating() {
    let mut set = KeySet::new(keys(4, 4, 5), 4).unwrap();
    let index = set
        .add(key("new", [0.95, 0.05], vec![1.0, 2.0, 3.0, 4.0]))
        .unwrap();
    assert_eq!((index, set.len()), (4, 5));
    assert_interpolates(&mut set);
    assert_eq!(
        blend(&mut set, DVec2::new(0.95, 0.05)),
        vec![1.0, 2.0, 3.0, 4.0]
    );

    set.move_key(1, [0.02, 0.98]).unwrap();
    assert_eq!(set.keys()[1].at, [0.02, 0.98]);
    assert_interpolates(&mut set);

    set.set_values(2, vec![-1.0, -2.0, -3.0, -4.0]).unwrap();
    assert_interpolates(&mut set);
    set.rename(2, "crouch".into()).unwrap();
    assert_eq!(set.keys()[2].name, "crouch");

    let removed = set.remove(0).unwrap();
    assert_eq!(removed.name, "pose 0");
    assert_eq!((set.len(), set.blend().unwrap().len()), (4, 4));
    assert_interpolates(&mut set);

    while !set.is_empty() {
        set.remove(set.len() - 1).unwrap();
        if !set.is_empty() {
            assert_interpolates(&mut set);
        }
    }
    assert!(set.blend().is_none());
    let mut out = [0.0; 4];
    assert!(!set.blend_into(DVec2::splat(0.5), &mut out));
    set.add(key("again", [0.5, 0.5], vec![1.0; 4])).unwrap();
    assert_eq!(blend(&mut set, DVec2::ZERO), vec![1.0; 4]);
}

#[test]
fn bad_edits_are_refused_and_change_nothing() {
    let entries = vec![
        key("crouch", [0.2, 0.2], vec![1.0, 2.0]),
        key("jump", [0.8, 0.8], vec![3.0, 4.0]),
    ];
    let mut set = KeySet::new(entries.clone(), 2).unwrap();
    let refused = |result: Result<usize, KeysError>| result.unwrap_err().to_string();
    assert_eq!(
        refused(set.add(key("wave", [1.5, 0.5], vec![0.0, 0.0]))),
        "keys[2] (\"wave\").at: outside the pad [0,1]²"
    );
    assert_eq!(
        refused(set.add(key("wave", [0.2, 0.2005], vec![0.0, 0.0]))),
        "keys[2] (\"wave\").at: same point as keys[0] (\"crouch\")"
    );
    assert_eq!(
        refused(set.add(key("wave", [0.5, 0.5], vec![0.0; 3]))),
        "keys[2] (\"wave\").values: has 3 values, the grips take 2"
    );
    assert_eq!(
        refused(set.add(key("wave", [0.5, 0.5], vec![0.0, f64::INFINITY]))),
        "keys[2] (\"wave\").values[1]: not a finite number"
    );
    assert_eq!(
        refused(set.add(key("wave", [f64::NAN, 0.5], vec![0.0, 0.0]))),
        "keys[2] (\"wave\").at[0]: not a finite number"
    );
    assert_eq!(
        refused(set.add(key("jump", [0.5, 0.5], vec![0.0, 0.0]))),
        "keys[2] (\"jump\").name: same name as keys[1]"
    );
    assert_eq!(
        refused(set.add(key(" ", [0.5, 0.5], vec![0.0, 0.0]))),
        "keys[2] (\" \").name: empty"
    );
    let error = set.move_key(1, [0.2, 0.2]).unwrap_err();
    assert!(matches!(
        &error,
        KeysError::Key {
            index: 1,
            problem: Problem::SamePoint { other: 0, .. },
            ..
        }
    ));
    assert_eq!(
        error.to_string(),
        "keys[1] (\"jump\").at: same point as keys[0] (\"crouch\")"
    );
    // Moving a key onto (nearly) its own place is no clash.
    set.move_key(1, [0.8, 0.8]).unwrap();
    assert_eq!(
        set.set_values(0, vec![1.0]).unwrap_err().to_string(),
        "keys[0] (\"crouch\").values: has 1 values, the grips take 2"
    );
    assert_eq!(
        set.rename(0, "jump".into()).unwrap_err().to_string(),
        "keys[0] (\"jump\").name: same name as keys[1]"
    );
    assert_eq!(
        set.remove(2).unwrap_err().to_string(),
        "keys[2]: no such key (the set has 2)"
    );
    assert!(matches!(
        set.move_key(7, [0.5, 0.5]),
        Err(KeysError::NoSuchKey { index: 7, count: 2 })
    ));
    assert_eq!(set.keys(), &entries[..]);
    assert_interpolates(&mut set);

    // The same checks when a set is built.
    let mut twins = entries.clone();
    twins[1].at = twins[0].at;
    assert_eq!(
        KeySet::new(twins, 2).unwrap_err().to_string(),
        "keys[1] (\"jump\").at: same point as keys[0] (\"crouch\")"
    );
    assert_eq!(
        KeySet::new(entries, 3).unwrap_err().to_string(),
        "keys[0] (\"crouch\").values: has 2 values, the grips take 3"
    );
}

const GOOD: &str = r#"{
  "puppet": "gingerbread",
  "grips": [
    { "kind": "point", "at": [12.5, -3.0] },
    { "kind": "grid_handle", "index": 4 }
  ],
  "keys": [
    { "name": "rest", "at": [0.1, 0.1], "values": [12.5, -3.0, 40.0, 40.0] },
    { "name": "wave", "at": [0.9, 0.2], "values": [20.0, 5.0, 41.0, 38.5] },
    { "name": "bow", "at": [0.5, 0.9], "values": [10.0, -10.0, 35.0, 45.0] }
  ]
}
"#;

#[test]
fn a_good_file_loads() {
    let file = KeyFile::parse(GOOD, "gingerbread.keys.json").unwrap();
    assert_eq!(file.puppet, "gingerbread");
    assert_eq!(
        file.grips,
        vec![
            KeyGrip::Point { at: [12.5, -3.0] },
            KeyGrip::GridHandle { index: 4 }
        ]
    );
    assert_eq!(file.width(), Some(4));
    assert_eq!(file.keys[1].name, "wave");
    // The field-by-field reader agrees with the derived Deserialize.
    let derived: KeyFile = serde_json::from_str(GOOD).unwrap();
    assert_eq!(derived, file);
    let mut set = KeySet::new(file.keys, 4).unwrap();
    assert_eq!(
        blend(&mut set, DVec2::new(0.9, 0.2)),
        vec![20.0, 5.0, 41.0, 38.5]
    );

    // A skeleton file: the stage says the width; keys must agree.
    let skeleton = r#"{"puppet": "p", "grips": [{"kind": "skeleton"}],
        "keys": [{"name": "a", "at": [0, 0], "values": [1, 2, 3]}]}"#;
    let file = KeyFile::parse(skeleton, "p.keys.json").unwrap();
    assert_eq!(file.width(), None);
    // No keys yet is fine.
    let empty = r#"{"puppet": "p", "grips": [{"kind": "skeleton"}], "keys": []}"#;
    assert!(
        KeyFile::parse(empty, "p.keys.json")
            .unwrap()
            .keys
            .is_empty()
    );
}

/// `GOOD` with `from` replaced by `to` (which must occur).
fn edited(from: &str, to: &str) -> String {
    assert!(GOOD.contains(from), "{from}");
    GOOD.replacen(from, to, 1)
}

#[test]
fn bad_files_name_the_file_and_the_field() {
    let skeleton = |keys: &str| {
        format!(r#"{{"puppet": "p", "grips": [{{"kind": "skeleton"}}], "keys": [{keys}]}}"#)
    };
    let cases: Vec<(String, &str)> = vec![
        (
            edited("[20.0, 5.0, 41.0, 38.5]", "[20.0, 5.0, NaN, 38.5]"),
            "g.keys.json:9:63: `NaN` is not a finite number (JSON has no NaN or Infinity)",
        ),
        (
            edited("[20.0, 5.0, 41.0, 38.5]", "[20.0, 5.0, -Infinity, 38.5]"),
            "g.keys.json:9:64: `-Infinity` is not a finite number (JSON has no NaN or Infinity)",
        ),
        (
            edited("[20.0, 5.0, 41.0, 38.5]", "[20.0, 5.0, 1e999, 38.5]"),
            "g.keys.json:9:67: `1e999` is not a finite number (out of the range of f64)",
        ),
        (
            edited("\"bow\",", "\"bow\", \"colour\": 3,"),
            "g.keys.json: keys[2].colour: unknown field (expected name, at, values)",
        ),
        (
            edited("\"puppet\"", "\"stage\": 1, \"puppet\""),
            "g.keys.json: stage: unknown field (expected puppet, grips, keys)",
        ),
        (
            edited(
                "\"grid_handle\", \"index\": 4",
                "\"skeleton\", \"index\": 4",
            ),
            "g.keys.json: grips[1].index: unknown field (expected kind)",
        ),
        (
            edited("\"grid_handle\"", "\"bone\""),
            "g.keys.json: grips[1].kind: unknown kind \"bone\" (expected \"point\", \"grid_handle\" or \"skeleton\")",
        ),
        (
            edited("\"index\": 4", "\"index\": -4"),
            "g.keys.json: grips[1].index: expected a non-negative integer",
        ),
        (
            edited(", \"at\": [0.9, 0.2]", ""),
            "g.keys.json: keys[1].at: missing",
        ),
        (
            edited("[0.9, 0.2]", "[0.9, 0.2, 0.3]"),
            "g.keys.json: keys[1].at: expected two numbers [x, y], found 3",
        ),
        (
            edited("[20.0, 5.0, 41.0, 38.5]", "[20.0, 5.0, \"41\", 38.5]"),
            "g.keys.json: keys[1].values[2]: expected a number, found a string",
        ),
        (
            edited("[20.0, 5.0, 41.0, 38.5]", "[20.0, 5.0, 41.0]"),
            "g.keys.json: keys[1].values: has 3 values, the grips take 4",
        ),
        (
            skeleton(
                r#"{"name": "a", "at": [0, 0], "values": [1, 2, 3, 4, 5, 6, 7, 8]},
                   {"name": "b", "at": [1, 1], "values": [1, 2, 3, 4, 5, 6, 7]}"#,
            ),
            "g.keys.json: keys[1].values: has 7 values, keys[0] has 8",
        ),
        (
            edited("[0.5, 0.9]", "[0.1, 0.1]"),
            "g.keys.json: keys[2].at: same point as keys[0] (\"rest\")",
        ),
        (
            edited("[0.9, 0.2]", "[0.9, 1.2]"),
            "g.keys.json: keys[1].at: outside the pad [0,1]²",
        ),
        (
            edited("[0.9, 0.2]", "[-0.1, 0.2]"),
            "g.keys.json: keys[1].at: outside the pad [0,1]²",
        ),
        (
            edited("\"bow\"", "\"rest\""),
            "g.keys.json: keys[2].name: same name as keys[0]",
        ),
        (
            edited("\"rest\"", "\"\""),
            "g.keys.json: keys[0].name: empty",
        ),
        (
            edited("\"gingerbread\"", "\"\""),
            "g.keys.json: puppet: empty",
        ),
        (
            r#"{"puppet": "p", "grips": [], "keys": []}"#.into(),
            "g.keys.json: grips: empty",
        ),
        (
            r#"{"puppet": "p", "grips": [{"kind": "skeleton"}, {"kind": "skeleton"}], "keys": []}"#
                .into(),
            "g.keys.json: grips[1]: a second skeleton grip (grips[0] is one)",
        ),
        (
            edited(
                "\"grid_handle\", \"index\": 4",
                "\"point\", \"at\": [12.5, -3.0]",
            ),
            "g.keys.json: grips[1]: same grip as grips[0]",
        ),
        (
            "[1, 2]".into(),
            "g.keys.json: (the file): expected an object, found an array",
        ),
        (
            edited("\"keys\": [", "\"keys\": [,"),
            "g.keys.json:7:12: expected value",
        ),
        (
            GOOD.trim_end().trim_end_matches('}').into(),
            "g.keys.json:12:0: EOF while parsing an object",
        ),
    ];
    for (text, expected) in cases {
        let error = KeyFile::parse(&text, "g.keys.json").unwrap_err();
        assert_eq!(error.to_string(), expected, "in\n{text}");
    }
}

/// A fresh, empty folder for this test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("puppetry-keys-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn a_missing_file_is_named() {
    let path = scratch("missing").join("nobody.keys.json");
    let error = KeyFile::load(&path).unwrap_err();
    assert!(matches!(error, KeysError::Read { .. }));
    let message = error.to_string();
    assert!(
        message.starts_with(&format!("{}: cannot read: ", path.display())),
        "{message}"
    );
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn save_then_load_is_identical() {
    let dir = scratch("round-trip");
    let path = dir.join("gingerbread.keys.json");
    let mut rng = Rng(6);
    let mut file = KeyFile {
        puppet: "gingerbread".into(),
        grips: vec![
            KeyGrip::Point {
                at: [0.1 + 0.2, -1e-300],
            },
            KeyGrip::GridHandle { index: 17 },
        ],
        keys: keys(5, 4, 7),
    };
    file.keys[0].values = vec![0.1 + 0.2, 1.0 / 3.0, -5e-324, 1.7976931348623157e308];
    file.keys[1].name = "ünïcode \"quoted\" name".into();
    for entry in &mut file.keys[2..] {
        entry.values = (0..4).map(|_| (rng.unit() - 0.5) * 1e6).collect();
    }
    file.save(&path).unwrap();
    assert_eq!(KeyFile::load(&path).unwrap(), file);
    assert_eq!(std::fs::read_to_string(&path).unwrap(), file.to_json());
    // Saving over it again leaves just the file, no temporaries.
    file.keys.pop();
    file.save(&path).unwrap();
    assert_eq!(KeyFile::load(&path).unwrap(), file);
    assert_eq!(files_in(&dir), vec!["gingerbread.keys.json"]);

    // A file that would not load is not saved, and the old one stays.
    let mut bad = file.clone();
    bad.keys[1].values[0] = f64::NAN;
    assert_eq!(
        bad.save(&path).unwrap_err().to_string(),
        format!("{}: keys[1].values[0]: not a finite number", path.display())
    );
    assert_eq!(KeyFile::load(&path).unwrap(), file);
    // Nor into a folder that is not there.
    let nowhere = dir.join("no such folder").join("k.keys.json");
    let error = file.save(&nowhere).unwrap_err();
    assert!(matches!(error, KeysError::Write { .. }), "{error}");
    assert!(
        error
            .to_string()
            .starts_with(&format!("{}: cannot write: ", nowhere.display()))
    );
    assert_eq!(files_in(&dir), vec!["gingerbread.keys.json"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn blend_into_does_not_allocate() {
    let mut set = KeySet::new(keys(20, 30, 8), 30).unwrap();
    let mut out = vec![0.0; 30];
    alloc::start();
    for frame in 0..500 {
        let t = frame as f64 * 0.013;
        let cursor = DVec2::new(t.sin(), (0.7 * t).cos()) * 0.6 + 0.5;
        assert!(set.blend_into(cursor, &mut out));
    }
    assert_eq!(alloc::stop(), 0, "blend_into allocated");
    // The counter works: an edit does allocate.
    alloc::start();
    set.move_key(0, [0.99, 0.99]).unwrap();
    assert!(alloc::stop() > 0);
}
