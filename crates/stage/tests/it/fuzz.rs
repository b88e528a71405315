//! Fuzzing the stage's file readers: stage TOML (every file of `config/` as
//! a seed, mutated in structure and in bytes, plus random text and deep
//! nests) and key-pose files (mutated, then blended at random cursors when
//! they load). Every case must end in a value or an error naming the file
//! (and, for a bad field, the field). See `docs/fuzzing.md`.

use std::path::Path;

use proptest::prelude::*;
use puppetry_stage::config::{ConfigError, StageConfig};
use puppetry_stage::keys::{KeyFile, KeySet, KeysError};
use puppetry_testkit::fuzz::{self, config};

fn check_stage(text: &str) {
    match StageConfig::parse("fuzz.toml", text, Path::new("/nonexistent")) {
        Ok(config) => {
            assert!(config.stage.width.is_finite() && config.stage.width > 0.0);
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.starts_with("fuzz.toml: "), "{message}");
            if let ConfigError::Invalid(puppetry_mesh::FieldError { field, .. }) = &e {
                assert!(!field.is_empty(), "{message}");
            }
        }
    }
}

fn key_seeds() -> Vec<String> {
    vec![
        std::fs::read_to_string(
            puppetry_testkit::root().join("assets/gingerbread/gingerbread.keys.json"),
        )
        .expect("the demo key file"),
        r#"{"puppet": "p", "grips": [{"kind": "grid_handle", "index": 3}, {"kind": "skeleton"}],
            "keys": [{"name": "a", "at": [0, 0], "values": [1, 2, 3]}, {"name": "b", "at": [1, 1], "values": [4, 5, 6]}]}"#
            .into(),
    ]
}

fn check_keys(text: &str, cursors: &[(f64, f64)]) {
    match KeyFile::parse(text, "fuzz.keys.json") {
        Ok(file) => {
            let width = file
                .width()
                .unwrap_or_else(|| file.keys.first().map_or(0, |k| k.values.len()));
            if let Ok(mut set) = KeySet::new(file.keys.clone(), width) {
                let mut out = vec![0.0; set.width()];
                for &(x, y) in cursors {
                    // Values are only bounded to finite numbers, so sums
                    // may overflow; what matters here is no panic.
                    let _ = set.blend_into(glam::DVec2::new(x, y), &mut out);
                }
            }
            let _ =
                KeyFile::parse(&file.to_json(), "again.keys.json").expect("a key file re-reads");
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.starts_with("fuzz.keys.json"), "{message}");
            if let KeysError::Syntax { line, .. } = e {
                assert!(line >= 1, "{message}");
            }
        }
    }
}

fn cursors() -> impl Strategy<Value = Vec<(f64, f64)>> {
    proptest::collection::vec(
        (
            prop_oneof![-1.0..2.0, any::<f64>()],
            prop_oneof![-1.0..2.0, any::<f64>()],
        ),
        0..4,
    )
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_stage_toml_random_text(text in fuzz::text(300)) {
        check_stage(&text);
    }

    #[test]
    fn fuzz_stage_toml_mutated(text in fuzz::mutated_toml(fuzz::stage_file_seeds())) {
        check_stage(&text);
    }

    #[test]
    fn fuzz_stage_toml_mutated_bytes(text in fuzz::mutated_text(fuzz::stage_file_seeds())) {
        check_stage(&text);
    }

    #[test]
    fn fuzz_stage_toml_deep_nesting(depth in 1usize..5000, table in any::<bool>()) {
        let value = if table {
            fuzz::deep("{a=", "1", "}", depth)
        } else {
            fuzz::deep("[", "1", "]", depth)
        };
        check_stage(&format!("[stage]\nwidth = {value}\nheight = 1\n"));
    }

    #[test]
    fn fuzz_keys_random_text(text in fuzz::text(300)) {
        check_keys(&text, &[]);
    }

    #[test]
    fn fuzz_keys_mutated(text in fuzz::mutated_json(key_seeds()), cursors in cursors()) {
        check_keys(&text, &cursors);
    }

    #[test]
    fn fuzz_keys_mutated_bytes(text in fuzz::mutated_text(key_seeds()), cursors in cursors()) {
        check_keys(&text, &cursors);
    }
}
