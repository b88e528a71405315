//! No number in a stage file or a key file can panic, stall or exhaust
//! memory: every numeric field of every bundled stage file (and of the
//! bundled key file) is set in turn to NaN, ±∞, 1e20, 0, −1 and a large
//! integer, and each result must either load, build and solve a stage, or
//! be a typed error — never a panic. The fields are found by walking the
//! parsed files, so a field added later is tried without a list to keep.
//! (`client_timeout_s = 1e20` panicked the daemon at start in
//! `Duration::from_secs_f64`; `at = [1, 2, 3]` and `width = 1e-300`
//! passed.)

use std::path::{Path, PathBuf};
use std::time::Duration;

use glam::DVec2;
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, Stage};

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

/// The values every numeric field is tried with.
fn bad_toml_numbers() -> Vec<toml::Value> {
    use toml::Value::{Float, Integer};
    vec![
        Float(f64::NAN),
        Float(f64::INFINITY),
        Float(f64::NEG_INFINITY),
        Float(1e20),
        Float(1e-300),
        Integer(0),
        Integer(-1),
        Integer(1 << 40),
    ]
}

/// Paths to every numeric leaf of `value` (within an array, its first
/// and last element only: the others are the same field).
fn numeric_leaves<V>(
    value: &V,
    path: &mut Vec<Step>,
    out: &mut Vec<Vec<Step>>,
    walk: &impl Fn(&V) -> Node<'_, V>,
) {
    match walk(value) {
        Node::Number => out.push(path.clone()),
        Node::Table(fields) => {
            for (key, child) in fields {
                path.push(Step::Key(key.to_string()));
                numeric_leaves(child, path, out, walk);
                path.pop();
            }
        }
        Node::Array(items) => {
            let n = items.len();
            for i in [0, n.saturating_sub(1)] {
                if i < n && (i == 0 || n > 1) {
                    path.push(Step::Index(i));
                    numeric_leaves(&items[i], path, out, walk);
                    path.pop();
                }
            }
        }
        Node::Other => {}
    }
}

#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

enum Node<'a, V> {
    Number,
    Table(Vec<(&'a str, &'a V)>),
    Array(&'a [V]),
    Other,
}

fn toml_node(v: &toml::Value) -> Node<'_, toml::Value> {
    match v {
        toml::Value::Integer(_) | toml::Value::Float(_) => Node::Number,
        toml::Value::Table(t) => Node::Table(t.iter().map(|(k, v)| (k.as_str(), v)).collect()),
        toml::Value::Array(a) => Node::Array(a),
        _ => Node::Other,
    }
}

fn json_node(v: &serde_json::Value) -> Node<'_, serde_json::Value> {
    match v {
        serde_json::Value::Number(_) => Node::Number,
        serde_json::Value::Object(t) => {
            Node::Table(t.iter().map(|(k, v)| (k.as_str(), v)).collect())
        }
        serde_json::Value::Array(a) => Node::Array(a),
        _ => Node::Other,
    }
}

fn toml_at<'a>(value: &'a mut toml::Value, path: &[Step]) -> &'a mut toml::Value {
    path.iter().fold(value, |v, step| match step {
        Step::Key(k) => &mut v[k.as_str()],
        Step::Index(i) => &mut v[*i],
    })
}

fn json_at<'a>(value: &'a mut serde_json::Value, path: &[Step]) -> &'a mut serde_json::Value {
    path.iter().fold(value, |v, step| match step {
        Step::Key(k) => &mut v[k.as_str()],
        Step::Index(i) => &mut v[*i],
    })
}

fn shown(path: &[Step]) -> String {
    path.iter()
        .map(|s| match s {
            Step::Key(k) => format!(".{k}"),
            Step::Index(i) => format!("[{i}]"),
        })
        .collect()
}

/// Loads `text` as the stage file `name` would be, then builds, solves
/// and drives the stage a little: every way a number reaches code.
fn try_stage(name: &str, text: &str) -> Result<(), String> {
    let config = StageConfig::parse(name, text, &config_dir()).map_err(|e| e.to_string())?;
    // What the daemon makes of the durations and counts: no overflow.
    Duration::try_from_secs_f64(config.stage.client_timeout_s).map_err(|e| e.to_string())?;
    let mut stage = Stage::from_config(&config).map_err(|e| e.to_string())?;
    stage.solve();
    for puppet in 0..stage.puppets().len() as u32 {
        let _ = stage.apply_change(&Change::Cursor {
            puppet,
            at: Some(DVec2::new(0.3, 0.7)),
        });
    }
    stage.solve();
    Ok(())
}

#[test]
fn every_number_of_every_bundled_stage_file_loads_or_is_a_typed_error() {
    let mut files: Vec<PathBuf> = std::fs::read_dir(config_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 10, "{files:?}");
    let mut tried = 0;
    for file in files {
        let name = file.display().to_string();
        let text = std::fs::read_to_string(&file).unwrap();
        let parsed: toml::Value = toml::from_str(&text).unwrap();
        let mut leaves = Vec::new();
        numeric_leaves(&parsed, &mut Vec::new(), &mut leaves, &toml_node);
        for leaf in leaves {
            for bad in bad_toml_numbers() {
                let mut value = parsed.clone();
                *toml_at(&mut value, &leaf) = bad.clone();
                let text = toml::to_string(&value).unwrap();
                // A panic here fails the test, naming the field and value.
                eprintln!("{name}{} = {bad}", shown(&leaf));
                let _ = try_stage(&name, &text);
                tried += 1;
            }
        }
    }
    assert!(tried > 100, "{tried}");
}

#[test]
fn the_bundled_key_file_with_any_number_changed_loads_or_is_a_typed_error() {
    let keys = config_dir().join("../assets/gingerbread/gingerbread.keys.json");
    let stage_text = std::fs::read_to_string(config_dir().join("keyframe.toml")).unwrap();
    let parsed: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&keys).unwrap()).unwrap();
    let mut leaves = Vec::new();
    numeric_leaves(&parsed, &mut Vec::new(), &mut leaves, &json_node);
    assert!(leaves.len() > 5);
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.keys.json");
    let stage_text = stage_text.replace(
        "\"../assets/gingerbread/gingerbread.keys.json\"",
        &format!("{:?}", file.display().to_string()),
    );
    assert!(stage_text.contains("bad.keys.json"));
    for leaf in leaves {
        for bad in [
            "1e20", "-1e20", "0", "-1", "1e308", "-1e308", "5e-324", "NaN", "1e999",
        ] {
            let mut value = parsed.clone();
            *json_at(&mut value, &leaf) = serde_json::Value::Null;
            let text = serde_json::to_string(&value)
                .unwrap()
                .replacen("null", bad, 1);
            std::fs::write(&file, text).unwrap();
            eprintln!("{}{} = {bad}", file.display(), shown(&leaf));
            let _ = try_stage("keyframe.toml", &stage_text);
        }
    }
}

#[test]
fn the_issue_s_numbers_are_refused_naming_their_field() {
    let demo = std::fs::read_to_string(config_dir().join("demo.toml")).unwrap();
    for (from, to, field) in [
        (
            "height = 720",
            "height = 720\nclient_timeout_s = 1e20",
            "client_timeout_s",
        ),
        ("at = [640, 360]", "at = [640, 360, 3]", "at"),
        ("width = 1280", "width = 1e-300", "stage"),
    ] {
        let text = demo.replacen(from, to, 1);
        assert_ne!(text, demo);
        let error = StageConfig::parse("demo.toml", &text, &config_dir())
            .err()
            .unwrap_or_else(|| panic!("{to} was accepted"))
            .to_string();
        assert!(error.contains(field), "{to}: {error}");
    }
}

#[test]
fn a_stage_file_naming_dev_zero_is_refused_at_once_naming_it() {
    let demo = std::fs::read_to_string(config_dir().join("demo.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for (key, from) in [
        ("mesh", "\"../assets/gingerbread/gingerbread.mesh.json\""),
        ("image", "\"../assets/gingerbread/gingerbread.png\""),
    ] {
        let assets = config_dir().join("../assets");
        let text = demo
            .replacen(from, "\"/dev/zero\"", 1)
            .replace("\"../assets", &format!("\"{}", assets.display()));
        assert!(text.contains("/dev/zero"));
        let path = dir.path().join("zero.toml");
        std::fs::write(&path, text).unwrap();
        let error = StageConfig::load(&path).unwrap_err().to_string();
        assert!(
            error.contains(&format!("puppet[0].{key}")) && error.contains("/dev/zero"),
            "{error}"
        );
        assert!(error.contains("not a regular file"), "{error}");
    }
}
