//! What the workspace's `fuzz_*` property tests share: the case count (small
//! by default so the whole set adds seconds to `cargo test`, raised with
//! `PROPTEST_CASES=100000`, see `docs/fuzzing.md`), and the input makers:
//! random bytes, mutations of real documents at the byte, token and line
//! level, and structure-aware mutations of JSON and TOML documents (a
//! field's value replaced by NaN, a huge or negative number, a wrong type, a
//! deep nest; a key dropped or added; an array emptied or repeated).
//!
//! Mutating real documents reaches far deeper into a parser than random
//! bytes, which mostly die at the first character; random bytes still
//! catch what no seed suggests.

use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::Config;

/// Cases per fuzz test when `PROPTEST_CASES` is not set.
pub const DEFAULT_CASES: u32 = 256;

/// The proptest configuration every fuzz test runs with: `cases` from
/// `PROPTEST_CASES` (else [`DEFAULT_CASES`]), no regression files written
/// into the source tree (a failure is fixed with a named regression test
/// instead), and bounded shrinking so a failure reports in seconds.
pub fn config() -> Config {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(DEFAULT_CASES);
    Config {
        cases,
        failure_persistence: None,
        max_shrink_iters: 2048,
        ..Config::default()
    }
}

/// Tokens that break parsers: non-numbers, overflowing and negative
/// numbers, boundary integers, empty and odd literals.
pub const NASTY_TOKENS: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "Infinity",
    "1e308",
    "-1e308",
    "1e999",
    "-1e999",
    "1e-320",
    "-1",
    "0",
    "-0",
    "0.0",
    "4294967295",
    "4294967296",
    "-2147483649",
    "2147483648",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999999999",
    "1.7976931348623157e308",
    "0x7fffffff",
    "0xffffffffffffffff",
    "true",
    "null",
    "\"\"",
    "[]",
    "{}",
    "",
    "\u{feff}",
    "é",
    "\0",
];

/// Random bytes, up to `max` long.
pub fn bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>(), 0..=max)
}

/// One edit of a byte string; positions are [`Index`]es so any edit fits
/// any input and shrinks well.
#[derive(Debug, Clone)]
pub enum Edit {
    /// Cut the input short at a position.
    Truncate(Index),
    /// Remove up to this many bytes from a position.
    Delete(Index, u8),
    /// Insert these bytes at a position.
    Insert(Index, Vec<u8>),
    /// Replace the byte at a position with this one.
    Overwrite(Index, u8),
    /// Replace the n-th token (a run of letters, digits, `.`, `+`, `-`) with
    /// one of [`NASTY_TOKENS`].
    Token(Index, Index),
    /// Repeat a line right after itself.
    DuplicateLine(Index),
    /// Remove a line with its `\n`.
    DeleteLine(Index),
    /// Copy a slice of the input elsewhere in it.
    Splice(Index, Index, u16),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        any::<Index>().prop_map(Edit::Truncate),
        (any::<Index>(), any::<u8>()).prop_map(|(i, n)| Edit::Delete(i, n)),
        (any::<Index>(), bytes(16)).prop_map(|(i, b)| Edit::Insert(i, b)),
        (any::<Index>(), any::<u8>()).prop_map(|(i, b)| Edit::Overwrite(i, b)),
        (any::<Index>(), any::<Index>()).prop_map(|(i, t)| Edit::Token(i, t)),
        (any::<Index>(), any::<Index>()).prop_map(|(i, t)| Edit::Token(i, t)),
        any::<Index>().prop_map(Edit::DuplicateLine),
        any::<Index>().prop_map(Edit::DeleteLine),
        (any::<Index>(), any::<Index>(), any::<u16>()).prop_map(|(a, b, n)| Edit::Splice(a, b, n)),
    ]
}

fn is_token_byte(b: u8) -> bool {
    b.is_ascii_alphanumeric() || matches!(b, b'.' | b'+' | b'-')
}

/// Byte ranges of the lines (without their `\n`).
fn lines(data: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for (i, &b) in data.iter().enumerate() {
        if b == b'\n' {
            out.push((start, i + 1));
            start = i + 1;
        }
    }
    if start < data.len() {
        out.push((start, data.len()));
    }
    out
}

/// Applies `edits` to `data` in order.
pub fn apply(mut data: Vec<u8>, edits: &[Edit]) -> Vec<u8> {
    for edit in edits {
        let len = data.len();
        match edit {
            Edit::Truncate(at) => data.truncate(at.index(len + 1)),
            Edit::Delete(at, n) => {
                let at = at.index(len + 1);
                let end = (at + *n as usize).min(len);
                data.drain(at..end);
            }
            Edit::Insert(at, bytes) => {
                let at = at.index(len + 1);
                data.splice(at..at, bytes.iter().copied());
            }
            Edit::Overwrite(at, byte) => {
                if len > 0 {
                    data[at.index(len)] = *byte;
                }
            }
            Edit::Token(which, token) => {
                let mut tokens = Vec::new();
                let mut i = 0;
                while i < len {
                    if is_token_byte(data[i]) {
                        let start = i;
                        while i < len && is_token_byte(data[i]) {
                            i += 1;
                        }
                        tokens.push((start, i));
                    } else {
                        i += 1;
                    }
                }
                if !tokens.is_empty() {
                    let (start, end) = tokens[which.index(tokens.len())];
                    let nasty = NASTY_TOKENS[token.index(NASTY_TOKENS.len())];
                    data.splice(start..end, nasty.bytes());
                }
            }
            Edit::DuplicateLine(which) => {
                let lines = lines(&data);
                if !lines.is_empty() {
                    let (start, end) = lines[which.index(lines.len())];
                    let copy = data[start..end].to_vec();
                    data.splice(end..end, copy);
                }
            }
            Edit::DeleteLine(which) => {
                let lines = lines(&data);
                if !lines.is_empty() {
                    let (start, end) = lines[which.index(lines.len())];
                    data.drain(start..end);
                }
            }
            Edit::Splice(from, to, n) => {
                if len > 0 {
                    let from = from.index(len);
                    let end = (from + *n as usize).min(len);
                    let copy = data[from..end].to_vec();
                    let to = to.index(len + 1);
                    data.splice(to..to, copy);
                }
            }
        }
    }
    data
}

/// One of `seeds`, with one to four byte-, token- or line-level edits.
pub fn mutated_bytes(seeds: Vec<Vec<u8>>) -> impl Strategy<Value = Vec<u8>> {
    assert!(!seeds.is_empty(), "mutating nothing");
    (
        proptest::sample::select(seeds),
        proptest::collection::vec(edit(), 1..=4),
    )
        .prop_map(|(seed, edits)| apply(seed, &edits))
}

/// [`mutated_bytes`] as text (invalid UTF-8 replaced), for parsers that
/// take `&str`.
pub fn mutated_text(seeds: Vec<String>) -> impl Strategy<Value = String> {
    mutated_bytes(seeds.into_iter().map(String::into_bytes).collect())
        .prop_map(|b| String::from_utf8_lossy(&b).into_owned())
}

/// Arbitrary text: random bytes read as UTF-8 (lossily), or runs of
/// printable ASCII, which get further into text parsers.
pub fn text(max: usize) -> impl Strategy<Value = String> {
    prop_oneof![
        bytes(max).prop_map(|b| String::from_utf8_lossy(&b).into_owned()),
        proptest::collection::vec(0x20u8..0x7f, 0..=max)
            .prop_map(|b| String::from_utf8(b).expect("ascii")),
    ]
}

/// A replacement value for one node of a document.
#[derive(Debug, Clone)]
pub enum Replacement {
    /// A finite float: ±1e308, the smallest normal and subnormal, ±0, or
    /// any.
    Number(f64),
    /// An integer: -1, the i64 and i32 bounds, 2³², or any.
    Integer(i64),
    /// An unsigned integer: `u64::MAX`, or any.
    Unsigned(u64),
    /// A string: empty, 5000 characters, `"NaN"`, one holding NUL, a BOM,
    /// `é` and U+10FFFF, or a short identifier.
    Text(String),
    /// `true` or `false`.
    Bool(bool),
    /// `null`.
    Null,
    /// `[]`.
    EmptyArray,
    /// `{}`.
    EmptyObject,
    /// `[[[…0…]]]`, this deep.
    Nested(u16),
    /// The node repeated in an array this many times.
    Repeated(u16),
    /// The node dropped (from its object or array).
    Remove,
    /// An unknown key added beside it (objects) or the node doubled (arrays).
    Extra,
}

fn replacement() -> impl Strategy<Value = Replacement> {
    prop_oneof![
        prop_oneof![
            Just(1e308),
            Just(-1e308),
            Just(f64::MAX),
            Just(f64::MIN_POSITIVE),
            Just(5e-324),
            Just(0.0),
            Just(-0.0),
            Just(-1.0),
            Just(0.5),
            Just(1e12),
            Just(-1e12),
            any::<f64>().prop_filter("JSON numbers are finite", |v| v.is_finite()),
        ]
        .prop_map(Replacement::Number),
        prop_oneof![
            Just(-1i64),
            Just(i64::MIN),
            Just(i64::MAX),
            Just(i64::from(i32::MIN)),
            Just(i64::from(u32::MAX) + 1),
            any::<i64>(),
        ]
        .prop_map(Replacement::Integer),
        prop_oneof![Just(u64::MAX), any::<u64>()].prop_map(Replacement::Unsigned),
        prop_oneof![
            Just(String::new()),
            Just("x".repeat(5000)),
            Just("NaN".to_string()),
            Just("\u{0}\u{feff}é\u{10ffff}".to_string()),
            "[a-z_]{0,12}",
        ]
        .prop_map(Replacement::Text),
        any::<bool>().prop_map(Replacement::Bool),
        Just(Replacement::Null),
        Just(Replacement::EmptyArray),
        Just(Replacement::EmptyObject),
        (1u16..400).prop_map(Replacement::Nested),
        (0u16..300).prop_map(Replacement::Repeated),
        Just(Replacement::Remove),
        Just(Replacement::Extra),
    ]
}

fn nested(depth: u16) -> serde_json::Value {
    let mut value = serde_json::Value::from(0);
    for _ in 0..depth {
        value = serde_json::Value::Array(vec![value]);
    }
    value
}

/// Every node's path (object keys and array indices), depth first.
fn paths(value: &serde_json::Value, here: &mut Vec<PathStep>, out: &mut Vec<Vec<PathStep>>) {
    out.push(here.clone());
    match value {
        serde_json::Value::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                here.push(PathStep::Index(i));
                paths(item, here, out);
                here.pop();
            }
        }
        serde_json::Value::Object(map) => {
            for (key, item) in map {
                here.push(PathStep::Key(key.clone()));
                paths(item, here, out);
                here.pop();
            }
        }
        _ => {}
    }
}

#[derive(Debug, Clone)]
enum PathStep {
    Key(String),
    Index(usize),
}

fn node_mut<'a>(
    value: &'a mut serde_json::Value,
    path: &[PathStep],
) -> Option<&'a mut serde_json::Value> {
    let mut node = value;
    for step in path {
        node = match step {
            PathStep::Key(key) => node.get_mut(key.as_str())?,
            PathStep::Index(i) => node.get_mut(*i)?,
        };
    }
    Some(node)
}

/// Applies `replacement` at the `which`-th node of `value`.
pub fn mutate_value(value: &mut serde_json::Value, which: Index, replacement: &Replacement) {
    let mut all = Vec::new();
    paths(value, &mut Vec::new(), &mut all);
    let path = &all[which.index(all.len())];
    let structural = matches!(replacement, Replacement::Remove | Replacement::Extra);
    if structural && let Some((last, parent_path)) = path.split_last() {
        let Some(parent) = node_mut(value, parent_path) else {
            return;
        };
        match (parent, last, replacement) {
            (serde_json::Value::Object(map), PathStep::Key(key), Replacement::Remove) => {
                map.remove(key);
            }
            (serde_json::Value::Object(map), _, _) => {
                map.insert("unexpected_field".into(), serde_json::Value::from(1));
            }
            (serde_json::Value::Array(items), PathStep::Index(i), Replacement::Remove) => {
                items.remove(*i);
            }
            (serde_json::Value::Array(items), PathStep::Index(i), _) => {
                let copy = items[*i].clone();
                items.insert(*i, copy);
            }
            _ => {}
        }
        return;
    }
    let Some(node) = node_mut(value, path) else {
        return;
    };
    *node = match replacement {
        Replacement::Number(v) => serde_json::Value::from(*v),
        Replacement::Integer(v) => serde_json::Value::from(*v),
        Replacement::Unsigned(v) => serde_json::Value::from(*v),
        Replacement::Text(s) => serde_json::Value::from(s.clone()),
        Replacement::Bool(b) => serde_json::Value::from(*b),
        Replacement::Null => serde_json::Value::Null,
        Replacement::EmptyArray => serde_json::Value::Array(Vec::new()),
        Replacement::EmptyObject => serde_json::Value::Object(Default::default()),
        Replacement::Nested(depth) => nested(*depth),
        Replacement::Repeated(n) => serde_json::Value::Array(vec![node.clone(); *n as usize]),
        Replacement::Remove | Replacement::Extra => serde_json::Value::Null,
    };
}

/// One of `seeds` (JSON documents), with one to three of its fields'
/// values replaced, dropped or duplicated, written back as JSON; sometimes
/// with byte-level edits on top (truncation, NaN tokens, …).
pub fn mutated_json(seeds: Vec<String>) -> impl Strategy<Value = String> {
    let values: Vec<serde_json::Value> = seeds
        .iter()
        .map(|s| serde_json::from_str(s).expect("a JSON seed parses"))
        .collect();
    assert!(!values.is_empty(), "mutating nothing");
    (
        proptest::sample::select(values),
        proptest::collection::vec((any::<Index>(), replacement()), 1..=3),
        proptest::collection::vec(edit(), 0..=1),
    )
        .prop_map(|(mut value, changes, edits)| {
            for (which, replacement) in &changes {
                mutate_value(&mut value, *which, replacement);
            }
            let text = serde_json::to_string(&value).expect("a JSON value serialises");
            String::from_utf8_lossy(&apply(text.into_bytes(), &edits)).into_owned()
        })
}

/// [`mutated_json`] for TOML documents: each seed is read as a tree,
/// mutated like JSON and written back as TOML (a mutation TOML cannot hold,
/// such as a null, leaves that seed as it was), then sometimes edited at the
/// byte level too, which is where TOML's `nan` and `inf` come in.
pub fn mutated_toml(seeds: Vec<String>) -> impl Strategy<Value = String> {
    let values: Vec<(String, serde_json::Value)> = seeds
        .into_iter()
        .map(|s| {
            let tree: toml::Table = toml::from_str(&s).expect("a TOML seed parses");
            let value = serde_json::to_value(tree).expect("TOML is JSON-shaped");
            (s, value)
        })
        .collect();
    assert!(!values.is_empty(), "mutating nothing");
    (
        proptest::sample::select(values),
        proptest::collection::vec((any::<Index>(), replacement()), 1..=3),
        proptest::collection::vec(edit(), 0..=2),
    )
        .prop_map(|((seed, mut value), changes, edits)| {
            for (which, replacement) in &changes {
                mutate_value(&mut value, *which, replacement);
            }
            let text = toml::to_string(&value).unwrap_or(seed);
            String::from_utf8_lossy(&apply(text.into_bytes(), &edits)).into_owned()
        })
}

/// Brackets nested `depth` deep around `inner`, e.g. `[[[1]]]`: what a
/// hostile client sends to exhaust a recursive parser's stack.
pub fn deep(open: &str, inner: &str, close: &str, depth: usize) -> String {
    format!("{}{inner}{}", open.repeat(depth), close.repeat(depth))
}

/// The text of every stage file in `config/`: the seeds of the stage
/// file parsers (the stage's and the daemon's), so a new example stage is
/// fuzzed as soon as it is added.
pub fn stage_file_seeds() -> Vec<String> {
    let dir = crate::root().join("config");
    let mut seeds: Vec<String> = std::fs::read_dir(&dir)
        .expect("config/")
        .map(|entry| entry.expect("a config entry").path())
        .filter(|path| path.extension().is_some_and(|e| e == "toml"))
        .map(|path| std::fs::read_to_string(path).expect("a stage file"))
        .collect();
    seeds.sort();
    assert!(seeds.len() >= 5, "the stage files of config/ are the seeds");
    seeds
}
