//! Key-pose sets for spatial keyframing (§5.3 of "As-rigid-as-possible
//! shape manipulation", Igarashi, Moscovich & Hughes 2005): a performer
//! stores poses of a puppet as keys at points of a 2D pad, then drives the
//! whole puppet by moving one cursor on the pad, which blends the keys with
//! interpolating radial basis functions ([`puppetry_deform::rbf`]).
//!
//! This module owns the key file (its JSON format, validation with errors
//! naming the file and the field, atomic saving) and the live, compiled set
//! ([`KeySet`]) that blends. It knows nothing of the stage's internals: a
//! key's values are a flat vector of numbers whose meaning the stage decides
//! from the file's [`KeyGrip`]s (x, y of held points or grid handles, or a
//! skeleton's roots and unwrapped joint angles). Blending is linear in the
//! values, which is why angles must be unwrapped by whoever stores them.

use std::io;
use std::path::Path;

use glam::DVec2;
use puppetry_deform::rbf::{RbfBlend, RbfError};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

/// Two keys closer than this on the pad (a thousandth of its side) are at
/// the same point: between them the blend would swing from one pose to the
/// other within a hair's width of cursor travel.
pub const SAME_POINT: f64 = 1e-3;

/// A key file (one per puppet, named in the stage file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyFile {
    /// The puppet's name; the stage checks it.
    pub puppet: String,
    /// What each key's values drive, in order.
    pub grips: Vec<KeyGrip>,
    /// The key poses, in index order.
    pub keys: Vec<KeyEntry>,
}

/// What a run of a key's values drives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum KeyGrip {
    /// A material point, by its rest position in the mesh's own
    /// coordinates; two values (x, y, mesh coordinates).
    Point {
        /// The point's rest position, in the mesh's own coordinates.
        at: [f64; 2],
    },
    /// An lp-FFD grid handle by index; two values (mesh coordinates).
    GridHandle {
        /// The handle's index, row by row from the lower left.
        index: usize,
    },
    /// A whole skeleton pose; the stage says how many values.
    Skeleton,
}

/// One key pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyEntry {
    /// Unique within the set, not empty.
    pub name: String,
    /// Where the key sits on the pad, in `[0, 1]²`.
    pub at: [f64; 2],
    /// The pose, as the grips lay it out.
    pub values: Vec<f64>,
}

/// What is wrong with a field of a key file or a key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Problem {
    /// A number is NaN or infinite.
    #[error("not a finite number")]
    NotFinite,
    /// A key's pad point is outside `[0, 1]²`.
    #[error("outside the pad [0,1]²")]
    OutsidePad,
    /// A key's pad point is within [`SAME_POINT`] of an earlier key's.
    #[error("same point as keys[{other}] ({name:?})")]
    SamePoint {
        /// The earlier key's index.
        other: usize,
        /// The earlier key's name.
        name: String,
    },
    /// A name is blank, the file has no grips, or a new key would key
    /// nothing (no contact holds the puppet).
    #[error("empty")]
    Empty,
    /// A key's name is an earlier key's.
    #[error("same name as keys[{other}]")]
    SameName {
        /// The earlier key's index.
        other: usize,
    },
    /// With a skeleton grip, a key's value count differs from the first
    /// key's (the file alone cannot say how many a skeleton takes).
    #[error("has {count} values, keys[{other}] has {expected}")]
    ValueCount {
        /// The values this key has.
        count: usize,
        /// The key it is measured against (the first).
        other: usize,
        /// The values that key has.
        expected: usize,
    },
    /// A key's value count is not what the grips take.
    #[error("has {count} values, the grips take {expected}")]
    Width {
        /// The values this key has.
        count: usize,
        /// The values the grips take.
        expected: usize,
    },
    /// A grip repeats an earlier one.
    #[error("same grip as grips[{other}]")]
    SameGrip {
        /// The earlier grip's index.
        other: usize,
    },
    /// A file with two skeleton grips (one keys the whole skeleton).
    #[error("a second skeleton grip (grips[{other}] is one)")]
    SecondSkeleton {
        /// The first skeleton grip's index.
        other: usize,
    },
    /// The JSON has the wrong shape here: a missing or unknown field, a
    /// value of the wrong type.
    #[error("{0}")]
    Shape(String),
}

/// Why a key file could not be read, checked or written, or why a live
/// [`KeySet`] refused an edit.
#[derive(Debug, thiserror::Error)]
pub enum KeysError {
    /// The key file could not be opened or read.
    #[error("{file}: cannot read: {source}")]
    Read {
        /// The key file, as named.
        file: String,
        /// The operating system's error.
        source: io::Error,
    },
    /// Not a regular file, or past `MAX_KEYS_FILE_BYTES`.
    #[error(transparent)]
    File(puppetry_mesh::file::FileError),
    /// Writing the key file (or its temporary file) failed; the old file,
    /// if any, is untouched.
    #[error("{file}: cannot write: {source}")]
    Write {
        /// The key file, as named.
        file: String,
        /// The operating system's error.
        source: io::Error,
    },
    /// Not JSON, with where (1-based line and column).
    #[error("{file}:{line}:{column}: {problem}")]
    Syntax {
        /// The key file, as named.
        file: String,
        /// The line, from 1.
        line: usize,
        /// The column, from 1.
        column: usize,
        /// What is wrong there.
        problem: String,
    },
    /// A field of a key file, by its path (`keys[2].values[5]`).
    #[error("{file}: {path}: {problem}")]
    Invalid {
        /// The key file, as named.
        file: String,
        /// The field's path in the file.
        path: String,
        /// What is wrong with it.
        problem: Problem,
    },
    /// A key of a live set (`field` within the key: `at`, `values[5]`…).
    #[error("keys[{index}] ({name:?}).{field}: {problem}")]
    Key {
        /// The key's index in the set.
        index: usize,
        /// The key's name.
        name: String,
        /// The field at fault, within the key.
        field: String,
        /// What is wrong with it.
        problem: Problem,
    },
    /// An edit named a key index past the end of the set.
    #[error("keys[{index}]: no such key (the set has {count})")]
    NoSuchKey {
        /// The index asked for.
        index: usize,
        /// How many keys the set has.
        count: usize,
    },
    /// Not expected once the keys are checked (they are far enough apart);
    /// an error rather than a panic all the same.
    #[error("keys: {0}")]
    Blend(RbfError),
}

impl KeyFile {
    /// Reads and checks a key file; errors name `path` as given.
    pub fn load(path: &Path) -> Result<KeyFile, KeysError> {
        use puppetry_mesh::file::{self, FileError};
        let file = path.display().to_string();
        let text = file::read_text(path, file::KEYS_FILE).map_err(|e| match e {
            FileError::Io { file, source } => KeysError::Read { file, source },
            other => KeysError::File(other),
        })?;
        KeyFile::parse(&text, &file)
    }

    /// Parses and checks a key file's text; errors name `file_name`.
    pub fn parse(text: &str, file_name: &str) -> Result<KeyFile, KeysError> {
        let value: Value =
            serde_json::from_str(text).map_err(|e| syntax_error(text, file_name, &e))?;
        let invalid = |(path, problem)| KeysError::Invalid {
            file: file_name.to_string(),
            path,
            problem,
        };
        let keys = read_file(&value).map_err(invalid)?;
        keys.check().map_err(invalid)?;
        Ok(keys)
    }

    /// How many values each key has, when the grips alone say (no skeleton
    /// grip): two per grip.
    pub fn width(&self) -> Option<usize> {
        let fixed = !self.grips.iter().any(|g| matches!(g, KeyGrip::Skeleton));
        fixed.then_some(2 * self.grips.len())
    }

    /// The file's text: pretty JSON, ending with a newline.
    pub fn to_json(&self) -> String {
        let mut text = serde_json::to_string_pretty(self).expect("a key file serialises");
        text.push('\n');
        text
    }

    /// Checks the file as [`load`](Self::load) would, then writes it to
    /// `path` atomically (a temporary file in the same folder, renamed over
    /// it), so a crash never leaves half a file and a file that saved loads.
    pub fn save(&self, path: &Path) -> Result<(), KeysError> {
        let file = path.display().to_string();
        self.check().map_err(|(path, problem)| KeysError::Invalid {
            file: file.clone(),
            path,
            problem,
        })?;
        puppetry_mesh::file::write_atomically(path, self.to_json().as_bytes())
            .map_err(|source| KeysError::Write { file, source })
    }

    /// Everything [`parse`](Self::parse) checks beyond the JSON's shape; the
    /// first problem found, with its field path.
    fn check(&self) -> Result<(), (String, Problem)> {
        if self.puppet.trim().is_empty() {
            return Err(("puppet".into(), Problem::Empty));
        }
        if self.grips.is_empty() {
            return Err(("grips".into(), Problem::Empty));
        }
        for (i, grip) in self.grips.iter().enumerate() {
            let path = |field: &str| format!("grips[{i}]{field}");
            if let KeyGrip::Point { at } = grip
                && let Some(c) = at.iter().position(|v| !v.is_finite())
            {
                return Err((path(&format!(".at[{c}]")), Problem::NotFinite));
            }
            let earlier = &self.grips[..i];
            if matches!(grip, KeyGrip::Skeleton) {
                if let Some(other) = earlier.iter().position(|g| matches!(g, KeyGrip::Skeleton)) {
                    return Err((path(""), Problem::SecondSkeleton { other }));
                }
            } else if let Some(other) = earlier.iter().position(|g| g == grip) {
                return Err((path(""), Problem::SameGrip { other }));
            }
        }
        let fixed = self.width();
        for (index, entry) in self.keys.iter().enumerate() {
            let width = match (fixed, self.keys.first()) {
                (Some(expected), _) => Width::Grips(expected),
                (None, Some(first)) if index > 0 => Width::LikeKey(0, first.values.len()),
                (None, _) => Width::Any,
            };
            check_entry(entry, self.keys[..index].iter().enumerate(), width)
                .map_err(|(field, problem)| (format!("keys[{index}].{field}"), problem))?;
        }
        Ok(())
    }
}

/// How many values a key must have.
#[derive(Clone, Copy)]
enum Width {
    /// As many as the grips take.
    Grips(usize),
    /// As many as key `.0`, which has `.1`.
    LikeKey(usize, usize),
    Any,
}

/// Checks one key against the others of its set; the first problem, with
/// the field (`name`, `at`, `values[5]`…) it is in.
fn check_entry<'a>(
    entry: &KeyEntry,
    others: impl Iterator<Item = (usize, &'a KeyEntry)> + Clone,
    width: Width,
) -> Result<(), (String, Problem)> {
    if entry.name.trim().is_empty() {
        return Err(("name".into(), Problem::Empty));
    }
    if let Some((other, _)) = others.clone().find(|(_, o)| o.name == entry.name) {
        return Err(("name".into(), Problem::SameName { other }));
    }
    if let Some(c) = entry.at.iter().position(|v| !v.is_finite()) {
        return Err((format!("at[{c}]"), Problem::NotFinite));
    }
    if !entry.at.iter().all(|v| (0.0..=1.0).contains(v)) {
        return Err(("at".into(), Problem::OutsidePad));
    }
    let at = DVec2::from(entry.at);
    if let Some((other, o)) = others
        .clone()
        .find(|(_, o)| DVec2::from(o.at).distance(at) < SAME_POINT)
    {
        return Err((
            "at".into(),
            Problem::SamePoint {
                other,
                name: o.name.clone(),
            },
        ));
    }
    let count = entry.values.len();
    match width {
        Width::Grips(expected) if count != expected => {
            return Err(("values".into(), Problem::Width { count, expected }));
        }
        Width::LikeKey(other, expected) if count != expected => {
            return Err((
                "values".into(),
                Problem::ValueCount {
                    count,
                    other,
                    expected,
                },
            ));
        }
        _ => {}
    }
    if let Some(v) = entry.values.iter().position(|v| !v.is_finite()) {
        return Err((format!("values[{v}]"), Problem::NotFinite));
    }
    Ok(())
}

/// A JSON syntax error with its place, and a plain word for the numbers JSON
/// cannot hold (serde_json says "expected value" at a `NaN` and "number out
/// of range" at a `1e999`).
fn syntax_error(text: &str, file: &str, error: &serde_json::Error) -> KeysError {
    let (line, column) = (error.line(), error.column());
    let message = error.to_string();
    let bare = message
        .strip_suffix(&format!(" at line {line} column {column}"))
        .unwrap_or(&message);
    let word = word_at(text, line, column);
    let lower = word.trim_start_matches(['-', '+']).to_ascii_lowercase();
    let problem = if ["nan", "inf", "infinity"].contains(&lower.as_str()) {
        format!("`{word}` is not a finite number (JSON has no NaN or Infinity)")
    } else if bare == "number out of range" {
        format!("`{word}` is not a finite number (out of the range of f64)")
    } else {
        bare.to_string()
    };
    KeysError::Syntax {
        file: file.to_string(),
        line,
        column,
        problem,
    }
}

/// The run of number-like characters around (1-based) `line`, `column`, or
/// just before it (serde_json reports some errors one past the word).
fn word_at(text: &str, line: usize, column: usize) -> String {
    let Some(row) = text.lines().nth(line.saturating_sub(1)) else {
        return String::new();
    };
    let chars: Vec<char> = row.chars().collect();
    let part_of_word = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '+' | '.');
    let mut start = column.saturating_sub(1).min(chars.len());
    if start == chars.len() || !part_of_word(chars[start]) {
        start = start.saturating_sub(1);
    }
    let mut end = start;
    while start > 0 && chars.get(start - 1).is_some_and(|&c| part_of_word(c)) {
        start -= 1;
    }
    while chars.get(end).is_some_and(|&c| part_of_word(c)) {
        end += 1;
    }
    chars[start.min(end)..end].iter().collect()
}

/// Reads a key file from parsed JSON, field by field, so a wrong shape is
/// reported with its path (serde's own messages would only say which field
/// name was wrong, not in which key). Agrees with the derived
/// `Deserialize`, and also refuses fields on a skeleton grip, which serde
/// accepts silently on a unit variant of an internally tagged enum.
fn read_file(value: &Value) -> Result<KeyFile, (String, Problem)> {
    let root = object(value, "", &["puppet", "grips", "keys"])?;
    let puppet = string(field(root, "", "puppet")?, "puppet")?;
    let grips = array(field(root, "", "grips")?, "grips")?
        .iter()
        .enumerate()
        .map(|(i, grip)| read_grip(grip, &format!("grips[{i}]")))
        .collect::<Result<_, _>>()?;
    let keys = array(field(root, "", "keys")?, "keys")?
        .iter()
        .enumerate()
        .map(|(i, key)| read_key(key, &format!("keys[{i}]")))
        .collect::<Result<_, _>>()?;
    Ok(KeyFile {
        puppet,
        grips,
        keys,
    })
}

fn read_grip(value: &Value, path: &str) -> Result<KeyGrip, (String, Problem)> {
    let map = as_object(value, path)?;
    let kind = string(field(map, path, "kind")?, &join(path, "kind"))?;
    let allowed: &[&str] = match kind.as_str() {
        "point" => &["kind", "at"],
        "grid_handle" => &["kind", "index"],
        "skeleton" => &["kind"],
        _ => {
            return Err((
                join(path, "kind"),
                Problem::Shape(format!(
                    "unknown kind {kind:?} (expected \"point\", \"grid_handle\" or \"skeleton\")"
                )),
            ));
        }
    };
    only(map, path, allowed)?;
    Ok(match kind.as_str() {
        "point" => KeyGrip::Point {
            at: pair(field(map, path, "at")?, &join(path, "at"))?,
        },
        "grid_handle" => {
            let index = field(map, path, "index")?;
            let index = index.as_u64().and_then(|i| usize::try_from(i).ok());
            KeyGrip::GridHandle {
                index: index.ok_or_else(|| {
                    (
                        join(path, "index"),
                        Problem::Shape("expected a non-negative integer".into()),
                    )
                })?,
            }
        }
        _ => KeyGrip::Skeleton,
    })
}

fn read_key(value: &Value, path: &str) -> Result<KeyEntry, (String, Problem)> {
    let map = object(value, path, &["name", "at", "values"])?;
    let values_path = join(path, "values");
    let values = array(field(map, path, "values")?, &values_path)?
        .iter()
        .enumerate()
        .map(|(i, v)| number(v, &format!("{values_path}[{i}]")))
        .collect::<Result<_, _>>()?;
    Ok(KeyEntry {
        name: string(field(map, path, "name")?, &join(path, "name"))?,
        at: pair(field(map, path, "at")?, &join(path, "at"))?,
        values,
    })
}

fn join(path: &str, field: &str) -> String {
    if path.is_empty() {
        field.to_string()
    } else {
        format!("{path}.{field}")
    }
}

fn shape(path: &str, problem: String) -> (String, Problem) {
    let path = if path.is_empty() { "(the file)" } else { path };
    (path.to_string(), Problem::Shape(problem))
}

fn kind_of(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// `value` as an object with no fields but `allowed`.
fn object<'v>(
    value: &'v Value,
    path: &str,
    allowed: &[&str],
) -> Result<&'v Map<String, Value>, (String, Problem)> {
    let map = as_object(value, path)?;
    only(map, path, allowed)?;
    Ok(map)
}

fn as_object<'v>(
    value: &'v Value,
    path: &str,
) -> Result<&'v Map<String, Value>, (String, Problem)> {
    value.as_object().ok_or_else(|| {
        shape(
            path,
            format!("expected an object, found {}", kind_of(value)),
        )
    })
}

/// Refuses any field of `map` not in `allowed`.
fn only(map: &Map<String, Value>, path: &str, allowed: &[&str]) -> Result<(), (String, Problem)> {
    match map.keys().find(|k| !allowed.contains(&k.as_str())) {
        Some(unknown) => Err((
            join(path, unknown),
            Problem::Shape(format!("unknown field (expected {})", allowed.join(", "))),
        )),
        None => Ok(()),
    }
}

fn field<'v>(
    map: &'v Map<String, Value>,
    path: &str,
    name: &str,
) -> Result<&'v Value, (String, Problem)> {
    map.get(name)
        .ok_or_else(|| (join(path, name), Problem::Shape("missing".into())))
}

fn array<'v>(value: &'v Value, path: &str) -> Result<&'v Vec<Value>, (String, Problem)> {
    value
        .as_array()
        .ok_or_else(|| shape(path, format!("expected an array, found {}", kind_of(value))))
}

fn string(value: &Value, path: &str) -> Result<String, (String, Problem)> {
    value
        .as_str()
        .map(str::to_string)
        .ok_or_else(|| shape(path, format!("expected a string, found {}", kind_of(value))))
}

fn number(value: &Value, path: &str) -> Result<f64, (String, Problem)> {
    // serde_json's numbers are finite: it refuses NaN, Infinity and
    // out-of-range literals while parsing.
    value
        .as_f64()
        .ok_or_else(|| shape(path, format!("expected a number, found {}", kind_of(value))))
}

fn pair(value: &Value, path: &str) -> Result<[f64; 2], (String, Problem)> {
    match array(value, path)?.as_slice() {
        [x, y] => Ok([
            number(x, &format!("{path}[0]"))?,
            number(y, &format!("{path}[1]"))?,
        ]),
        other => Err(shape(
            path,
            format!("expected two numbers [x, y], found {}", other.len()),
        )),
    }
}

/// A puppet's live key set: the keys, compiled into blending weights.
/// Edits recompile (and allocate); [`blend_into`](Self::blend_into), which
/// runs per input frame, does not.
#[derive(Debug, Clone)]
pub struct KeySet {
    entries: Vec<KeyEntry>,
    width: usize,
    /// `None` when there are no keys.
    blend: Option<RbfBlend>,
    /// One weight per key, rewritten by each blend.
    weights: Vec<f64>,
}

impl KeySet {
    /// Compiles `entries`, each of which must have `width` finite values, a
    /// unique non-empty name and its own point on the pad.
    pub fn new(entries: Vec<KeyEntry>, width: usize) -> Result<KeySet, KeysError> {
        for (index, entry) in entries.iter().enumerate() {
            check_entry(
                entry,
                entries[..index].iter().enumerate(),
                Width::Grips(width),
            )
            .map_err(|(field, problem)| key_error(index, entry, field, problem))?;
        }
        let mut set = KeySet {
            entries,
            width,
            blend: None,
            weights: Vec::new(),
        };
        set.compile()?;
        Ok(set)
    }

    /// The keys, in index order.
    pub fn keys(&self) -> &[KeyEntry] {
        &self.entries
    }

    /// How many values each key has.
    pub fn width(&self) -> usize {
        self.width
    }

    /// How many keys there are.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there are no keys (then nothing blends).
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The compiled weights (`None` when there are no keys), e.g. for their
    /// Lipschitz bounds.
    pub fn blend(&self) -> Option<&RbfBlend> {
        self.blend.as_ref()
    }

    /// Adds a key; returns its index (the last).
    pub fn add(&mut self, entry: KeyEntry) -> Result<usize, KeysError> {
        let index = self.entries.len();
        check_entry(
            &entry,
            self.entries.iter().enumerate(),
            Width::Grips(self.width),
        )
        .map_err(|(field, problem)| key_error(index, &entry, field, problem))?;
        self.entries.push(entry);
        if let Err(e) = self.compile() {
            self.entries.pop();
            self.compile_or_clear();
            return Err(e);
        }
        Ok(index)
    }

    /// Moves key `index` to another point of the pad.
    pub fn move_key(&mut self, index: usize, at: [f64; 2]) -> Result<(), KeysError> {
        let mut entry = self.entry(index)?.clone();
        entry.at = at;
        self.replace(index, entry)
    }

    /// Gives key `index` a new pose.
    pub fn set_values(&mut self, index: usize, values: Vec<f64>) -> Result<(), KeysError> {
        let mut entry = self.entry(index)?.clone();
        entry.values = values;
        self.replace(index, entry)
    }

    /// Renames key `index`.
    pub fn rename(&mut self, index: usize, name: String) -> Result<(), KeysError> {
        let mut entry = self.entry(index)?.clone();
        entry.name = name;
        self.replace(index, entry)
    }

    /// Removes key `index` and returns it; the keys after it move down one.
    pub fn remove(&mut self, index: usize) -> Result<KeyEntry, KeysError> {
        self.entry(index)?;
        let removed = self.entries.remove(index);
        // Fewer distinct points than before: compiles whenever the old set did.
        self.compile_or_clear();
        Ok(removed)
    }

    /// Writes the blend of the keys' values at `cursor` (pad coordinates)
    /// into `out`: `out = Σ_k w_k(cursor) · values_k`. A cursor off the pad
    /// is taken to its nearest point on it: the pad is the whole blending
    /// space, and beyond it the weights would extrapolate. Returns false, and
    /// leaves `out` alone, when there are no keys, `out` is not
    /// [`width`](Self::width) long or the cursor is not finite. No
    /// allocation.
    pub fn blend_into(&mut self, cursor: DVec2, out: &mut [f64]) -> bool {
        let Some(blend) = &self.blend else {
            return false;
        };
        if out.len() != self.width || !cursor.is_finite() {
            return false;
        }
        blend.weights_into(cursor.clamp(DVec2::ZERO, DVec2::ONE), &mut self.weights);
        out.fill(0.0);
        for (&weight, entry) in self.weights.iter().zip(&self.entries) {
            for (o, &v) in out.iter_mut().zip(&entry.values) {
                *o += weight * v;
            }
        }
        true
    }

    fn entry(&self, index: usize) -> Result<&KeyEntry, KeysError> {
        self.entries.get(index).ok_or(KeysError::NoSuchKey {
            index,
            count: self.entries.len(),
        })
    }

    /// Puts `entry` in place of key `index` if it passes against the others,
    /// and recompiles; on any error the set is as it was.
    fn replace(&mut self, index: usize, entry: KeyEntry) -> Result<(), KeysError> {
        let others = self.entries.iter().enumerate().filter(|&(i, _)| i != index);
        check_entry(&entry, others, Width::Grips(self.width))
            .map_err(|(field, problem)| key_error(index, &entry, field, problem))?;
        let old = std::mem::replace(&mut self.entries[index], entry);
        if let Err(e) = self.compile() {
            self.entries[index] = old;
            self.compile_or_clear();
            return Err(e);
        }
        Ok(())
    }

    /// Rebuilds the weights for the current keys.
    fn compile(&mut self) -> Result<(), KeysError> {
        if self.entries.is_empty() {
            self.blend = None;
            self.weights.clear();
            return Ok(());
        }
        let points: Vec<DVec2> = self.entries.iter().map(|e| DVec2::from(e.at)).collect();
        let blend = RbfBlend::new(&points).map_err(KeysError::Blend)?;
        self.weights = vec![0.0; points.len()];
        self.blend = Some(blend);
        Ok(())
    }

    /// After restoring keys that compiled before: compiles, or (never
    /// expected) drops the blend so that nothing blends stale weights.
    fn compile_or_clear(&mut self) {
        if self.compile().is_err() {
            self.blend = None;
        }
    }
}

fn key_error(index: usize, entry: &KeyEntry, field: String, problem: Problem) -> KeysError {
    KeysError::Key {
        index,
        name: entry.name.clone(),
        field,
        problem,
    }
}
