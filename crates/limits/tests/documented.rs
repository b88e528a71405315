//! Every limit is documented: each `pub const NAME: T = VALUE;` in
//! `src/*.rs` has a row in `docs/limits.md` that starts with
//! ``| `NAME` | `VALUE` |``, so the page a show's technician reads says
//! what the code enforces.

use std::path::Path;

#[test]
fn every_limit_has_its_row_in_docs_limits_md() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("../../docs/limits.md")).expect("docs/limits.md");
    let mut missing = Vec::new();
    for entry in std::fs::read_dir(root.join("src")).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        for line in text.lines() {
            let Some(rest) = line.trim().strip_prefix("pub const ") else {
                continue;
            };
            let (name, rest) = rest.split_once(':').expect("pub const NAME: T = VALUE;");
            let value = rest
                .split_once('=')
                .expect("pub const NAME: T = VALUE;")
                .1
                .trim()
                .trim_end_matches(';')
                .trim();
            let row = format!("| `{}` | `{}` |", name.trim(), value);
            if !doc.lines().any(|l| l.starts_with(&row)) {
                missing.push(format!("{}: {row}", path.display()));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "docs/limits.md lacks these rows (name and value as in the code):\n{}",
        missing.join("\n")
    );
}
