//! The web client speaks the daemon's protocol. Its names and numbers
//! (`clients/web/wire.js`) are written from the Rust types by the daemon's
//! own test; here the page's builders (`clients/web/protocol.js`) are run
//! under Node and every message they make is read into the daemon's
//! `ClientMessage`, which refuses an unknown, missing or mistyped field: the
//! page and the daemon agree on every message's shape, and a message type
//! no builder makes fails. No browser needed.

use puppetry_daemon::protocol::ClientMessage;
use strum::VariantNames;

#[test]
fn every_message_the_page_builds_is_a_client_message_and_every_type_has_a_builder() {
    let root = puppetry_testkit::root();
    let output = std::process::Command::new("node")
        .arg(root.join("tests/web/builders.mjs"))
        .output()
        .expect("node runs (install Node.js: apt-get install nodejs)");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let mut built = std::collections::BTreeSet::new();
    for line in String::from_utf8(output.stdout).unwrap().lines() {
        let message: ClientMessage = serde_json::from_str(line)
            .unwrap_or_else(|e| panic!("the page builds {line}, which the daemon refuses: {e}"));
        // Written back, the message is what the page sent: no field the
        // daemon would drop or default differently.
        let back = as_floats(serde_json::to_value(&message).unwrap());
        let sent = as_floats(serde_json::from_str(line).unwrap());
        assert_eq!(back, sent, "the page's {line} reads back differently");
        built.insert(<&'static str>::from(&message));
    }
    let missing: Vec<&str> = ClientMessage::VARIANTS
        .iter()
        .copied()
        .filter(|name| !built.contains(name))
        .collect();
    assert!(
        missing.is_empty(),
        "tests/web/builders.mjs makes no message of these types (add a builder to clients/web/protocol.js and a line there): {missing:?}"
    );
}

/// The value with every number as a float (JavaScript writes `10` where
/// the daemon writes `10.0`).
fn as_floats(value: serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    match value {
        Value::Number(n) => Value::from(n.as_f64().unwrap()),
        Value::Array(items) => Value::Array(items.into_iter().map(as_floats).collect()),
        Value::Object(fields) => {
            Value::Object(fields.into_iter().map(|(k, v)| (k, as_floats(v))).collect())
        }
        other => other,
    }
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
