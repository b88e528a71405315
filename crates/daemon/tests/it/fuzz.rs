//! Fuzzing what a stranger can send the daemon over its WebSocket: client
//! text messages (random text; every documented example of
//! `docs/protocol.md` with fields mutated, truncated or nested deep) and
//! binary frames through the protocol's frame decoder. Every case must end
//! in a message or an error, never a panic; a message that parses must
//! survive a round trip. See `docs/fuzzing.md`.

use proptest::prelude::*;
use puppetry_daemon::protocol::{ClientMessage, FRAME_HEADER_BYTES, FrameKind, decode_frame};
use puppetry_testkit::fuzz::{self, config};

/// The client messages documented in `docs/protocol.md` (every JSON value
/// there that parses as one), so new message types are fuzzed as soon as
/// they are documented.
fn client_seeds() -> Vec<String> {
    let doc = std::fs::read_to_string(puppetry_testkit::root().join("docs/protocol.md"))
        .expect("docs/protocol.md");
    let mut seeds = Vec::new();
    let mut rest = doc.as_str();
    while let Some(start) = rest.find("```json") {
        let block = &rest[start + "```json".len()..];
        let Some(end) = block.find("```") else { break };
        for value in serde_json::Deserializer::from_str(&block[..end])
            .into_iter::<serde_json::Value>()
            .flatten()
        {
            let text = value.to_string();
            if serde_json::from_str::<ClientMessage>(&text).is_ok() {
                seeds.push(text);
            }
        }
        rest = &block[end + 3..];
    }
    assert!(seeds.len() >= 8, "only {} client examples", seeds.len());
    seeds
}

fn check_message(text: &str) {
    if let Ok(message) = serde_json::from_str::<ClientMessage>(text) {
        let again = serde_json::to_string(&message).expect("a message serialises");
        let back: ClientMessage = serde_json::from_str(&again).expect("a message re-reads");
        // NaN is not equal to itself; JSON cannot carry one anyway.
        assert_eq!(format!("{back:?}"), format!("{message:?}"));
    }
}

fn check_frame(bytes: &[u8]) {
    if let Ok(frame) = decode_frame(bytes) {
        let payload = if frame.header.kind == FrameKind::Depth {
            // u16 depths, padded to whole 4-byte words.
            (frame.depths.len() * 2).div_ceil(4) * 4
        } else {
            frame.points.len() * 8
        };
        assert_eq!(
            bytes.len(),
            FRAME_HEADER_BYTES + payload,
            "a frame decoded from bytes of another length"
        );
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_client_message_random_text(text in fuzz::text(300)) {
        check_message(&text);
    }

    #[test]
    fn fuzz_client_message_mutated(text in fuzz::mutated_json(client_seeds())) {
        check_message(&text);
    }

    #[test]
    fn fuzz_client_message_mutated_bytes(text in fuzz::mutated_text(client_seeds())) {
        check_message(&text);
    }

    #[test]
    fn fuzz_client_message_deep_nesting(depth in 1usize..20_000, object in any::<bool>()) {
        let nest = if object {
            fuzz::deep("{\"a\":", "0", "}", depth)
        } else {
            fuzz::deep("[", "0", "]", depth)
        };
        check_message(&format!("{{\"type\":\"contacts\",\"contacts\":{nest}}}"));
        check_message(&nest);
    }

    #[test]
    fn fuzz_binary_frame_random_bytes(bytes in fuzz::bytes(120)) {
        check_frame(&bytes);
    }

    #[test]
    fn fuzz_binary_frame_lying_counts(
        head in proptest::collection::vec(any::<u8>(), FRAME_HEADER_BYTES),
        count in prop_oneof![0u32..6, any::<u32>()],
        points in 0usize..6,
    ) {
        let mut bytes = head;
        bytes[24..28].copy_from_slice(&count.to_le_bytes());
        bytes.extend(std::iter::repeat_n(0x7f, points * 8));
        check_frame(&bytes);
    }
}

/// The daemon's reading of a whole stage file (its `[[input]]`, `[access]`,
/// `[osc]` and `[relay]` sections on top of the stage's): a value or an
/// error naming the file.
fn check_show(text: &str) {
    let parsed = puppetry_daemon::config::ShowConfig::parse(
        "fuzz.toml",
        text,
        std::path::Path::new("/nonexistent"),
    );
    if let Err(e) = parsed {
        let message = e.to_string();
        assert!(message.starts_with("fuzz.toml: "), "{message}");
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_show_toml_mutated(text in fuzz::mutated_toml(fuzz::stage_file_seeds())) {
        check_show(&text);
    }

    #[test]
    fn fuzz_show_toml_mutated_bytes(text in fuzz::mutated_text(fuzz::stage_file_seeds())) {
        check_show(&text);
    }
}
