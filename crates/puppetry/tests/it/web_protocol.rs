//! The web client's mirror of the wire protocol (`clients/web/protocol.js`)
//! names every message type and every value of the fields clients branch on
//! that `docs/protocol.md` shows. Every JSON example there is a real message
//! (the daemon's tests parse each), so a message or kind added to the
//! protocol and its documentation but not to the page fails here. No
//! browser needed.

/// The fields whose values the page's code compares against constants.
const FIELDS: [&str; 5] = ["type", "kind", "grip", "role", "phase"];

#[test]
fn the_web_protocol_mirror_names_every_documented_value() {
    let root = puppetry_testkit::root();
    let docs = std::fs::read_to_string(root.join("docs/protocol.md")).unwrap();
    let mirror = std::fs::read_to_string(root.join("clients/web/protocol.js")).unwrap();
    let mut seen = std::collections::BTreeSet::new();
    for field in FIELDS {
        let key = format!("\"{field}\":");
        let mut rest = docs.as_str();
        while let Some(at) = rest.find(&key) {
            rest = &rest[at + key.len()..];
            let value = rest.trim_start();
            // Only string values ("kind": 1 of a frame header table is not JSON).
            let Some(value) = value.strip_prefix('"') else {
                continue;
            };
            let end = value.find('"').unwrap();
            seen.insert((field, value[..end].to_string()));
        }
    }
    assert!(
        seen.iter().any(|(f, v)| *f == "type" && v == "hello"),
        "no message types found in docs/protocol.md"
    );
    let missing: Vec<String> = seen
        .iter()
        .filter(|(_, value)| !mirror.contains(&format!("'{value}'")))
        .map(|(field, value)| format!("{field} {value:?}"))
        .collect();
    assert!(
        missing.is_empty(),
        "clients/web/protocol.js does not name these values of docs/protocol.md: {}",
        missing.join(", ")
    );
}

/// The page's pure pieces (`tests/web/unit.test.mjs`: the address's view
/// options and token handling, the latency median, owner colours, handle
/// frames and where a handle is drawn) pass their unit tests under Node.
/// No browser and no Node packages needed, only Node itself.
#[test]
fn the_pages_pure_pieces_pass_their_unit_tests() {
    let root = puppetry_testkit::root();
    let output = std::process::Command::new("node")
        .arg("--test")
        .arg(root.join("tests/web/unit.test.mjs"))
        .output()
        .expect("node runs (install Node.js: apt-get install nodejs)");
    assert!(
        output.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
}
