//! The browser's copy of the protocol's names and numbers, written from the
//! Rust types: message types, roles, error codes, handle and rig kinds,
//! contact phases, close codes, frame kinds and header offsets, and the
//! limits a page checks before it sends (`clients/web/wire.js`). The Rust
//! types are the one definition (as rerun generates its other languages
//! from one): `clients/web/protocol.js` imports these names and adds only
//! what JavaScript does with them (builders, decoders), so a renamed or
//! added variant reaches the page by rewriting the file, never by hand. The
//! daemon's test `the_browsers_wire_names_are_written_from_the_rust_types`
//! writes the file and fails when the committed one differs.

use std::fmt::Write as _;

use puppetry_input::Phase;
use strum::{EnumMessage, IntoEnumIterator, VariantNames};

use crate::protocol::{
    ClientMessage, ErrorCode, FRAME_HEADER_BYTES, FrameKind, GripKind, HandleKind, PersonRole,
    RigDescription, ServerMessage, close, header, upload,
};
use puppetry_limits::net::{MAX_CLIENT_MESSAGE_BYTES, MAX_UPLOAD_BYTES};

/// Where the file lives, from the workspace root.
pub const PATH: &str = "clients/web/wire.js";

/// One named value of a generated object: its JavaScript key, its value
/// (already JavaScript), and what it means (a doc comment, if any).
struct Entry {
    key: String,
    value: String,
    doc: Option<String>,
}

/// The text of `clients/web/wire.js`.
pub fn wire_js() -> String {
    let mut out = String::from(
        "// GENERATED from the Rust types in crates/protocol/src/lib.rs by\n\
         // crates/daemon/src/javascript.rs: do not edit. To rewrite it, run\n\
         //   cargo test --release -p puppetry-daemon --lib wire\n\
         // (the test writes this file and fails when it was out of date).\n\
         // clients/web/protocol.js re-exports these names with the builders.\n",
    );
    text_messages(&mut out);
    adding_puppets(&mut out);
    binary_frames(&mut out);
    exports(&mut out);
    out
}

/// The formats a take downloads as from the page, in `Format::ALL`'s order.
fn exports(out: &mut String) {
    section(out, "exports");
    out.push('\n');
    doc_comment(
        out,
        "",
        "The formats a director downloads a take as (`Format`): `name` is the export \
         route's `format=`, the file is `extension`, served as `mime`; `label` is for people.",
    );
    out.push_str("export const EXPORT_FORMATS = Object.freeze([\n");
    for format in puppetry_export::format::Format::ALL {
        let Some((extension, mime)) = format.download() else {
            continue;
        };
        let _ = writeln!(
            out,
            "  Object.freeze({{ name: {}, extension: {}, mime: {}, label: {} }}),",
            quoted(format.name()),
            quoted(extension),
            quoted(mime),
            quoted(format.label()),
        );
    }
    out.push_str("]);\n");
}

/// The names of the text messages and their fields' values.
fn text_messages(out: &mut String) {
    section(out, "text messages");
    object(
        out,
        "`type` of the messages a client sends (`ClientMessage`).",
        "CLIENT_MESSAGE",
        ClientMessage::VARIANTS.iter().map(|name| named(name)),
    );
    object(
        out,
        "`type` of the text messages the server sends (`ServerMessage`).",
        "SERVER_MESSAGE",
        ServerMessage::VARIANTS.iter().map(|name| named(name)),
    );
    object(
        out,
        "A connection's role (hello, stage and people messages): a `director` may do \
         everything, a `performer` perform, a `viewer` only watch. `device` is the role \
         of the stage's input sources in the people list (`PersonRole`).",
        "ROLE",
        documented::<PersonRole>(),
    );
    object(
        out,
        "`code` of an `error` message, also in the answers of `POST /puppets` (`ErrorCode`).",
        "ERROR_CODE",
        documented::<ErrorCode>(),
    );
    object(
        out,
        "A contact's `phase` (`Phase`).",
        "CONTACT_PHASE",
        phases().into_iter(),
    );
    object(
        out,
        "A handle's `kind` (handles and stage messages; `HandleKind`).",
        "HANDLE_KIND",
        documented::<HandleKind>(),
    );
    object(
        out,
        "What a handle holds (`grip`, handles and stage messages); `grid`, `joint` and \
         `bone` come with an `index` (`GripKind`).",
        "HANDLE_GRIP",
        documented::<GripKind>(),
    );
    object(
        out,
        "A puppet's `rig.kind` (stage message; `RigDescription`).",
        "RIG_KIND",
        RigDescription::VARIANTS.iter().map(|name| named(name)),
    );
    constant(
        out,
        "The `owner` of the stage file's pins.",
        "CONFIG_OWNER",
        &quoted(puppetry_stage::CONFIG_OWNER),
    );
    constant(
        out,
        "The `owner` of the handles the keyframing cursor's blend of key poses holds.",
        "KEYS_OWNER",
        &quoted(puppetry_stage::KEYS_OWNER),
    );
    constant(
        out,
        "The longest text message a client may send (bytes); longer ones close the \
         connection with `CLOSE_CODE.TOO_LARGE`.",
        "MAX_CLIENT_MESSAGE_BYTES",
        &MAX_CLIENT_MESSAGE_BYTES.to_string(),
    );
    constant(
        out,
        "Contacts one `contacts` message may carry, and contacts one client may hold down.",
        "MAX_CONTACTS_PER_MESSAGE",
        &puppetry_limits::contacts::MAX_CONTACTS_PER_MESSAGE.to_string(),
    );
    object(
        out,
        "Close frame codes the server closes with.",
        "CLOSE_CODE",
        [
            (
                "POLICY",
                close::POLICY,
                "A rule was broken (origin, hello, bad messages, no pong).",
            ),
            (
                "TOO_LARGE",
                close::TOO_LARGE,
                "A message too large to read.",
            ),
            (
                "TRY_AGAIN_LATER",
                close::TRY_AGAIN_LATER,
                "Too many connections.",
            ),
            (
                "TOKEN_REFUSED",
                close::TOKEN_REFUSED,
                "The hello's token was refused.",
            ),
        ]
        .into_iter()
        .map(|(key, code, doc)| Entry {
            key: key.into(),
            value: code.to_string(),
            doc: Some(doc.into()),
        }),
    );
}

/// `POST /puppets`.
fn adding_puppets(out: &mut String) {
    section(out, "adding a puppet (HTTP)");
    constant(
        out,
        "The path a director POSTs a picture to.",
        "PUPPETS_PATH",
        &quoted(upload::PATH),
    );
    object(
        out,
        "The vertex counts a new puppet's mesh may ask for, and the page's default.",
        "PUPPET_VERTICES",
        [
            ("MIN", upload::MIN_VERTICES),
            ("MAX", upload::MAX_VERTICES),
            ("DEFAULT", upload::DEFAULT_VERTICES),
        ]
        .into_iter()
        .map(|(key, value)| Entry {
            key: key.into(),
            value: value.to_string(),
            doc: None,
        }),
    );
    constant(
        out,
        "The largest picture the daemon takes (bytes).",
        "MAX_PICTURE_BYTES",
        &MAX_UPLOAD_BYTES.to_string(),
    );
}

/// The binary frames' kinds and header.
fn binary_frames(out: &mut String) {
    section(out, "binary frames");
    constant(
        out,
        "Every binary frame starts with a header of this many bytes.",
        "FRAME_HEADER_BYTES",
        &FRAME_HEADER_BYTES.to_string(),
    );
    object(
        out,
        "A binary frame's `kind` (the header's first u32); clients skip kinds they do not know.",
        "FRAME_KIND",
        FrameKind::KNOWN.into_iter().map(|kind| Entry {
            key: format!("{kind:?}").to_uppercase(),
            value: kind.code().to_string(),
            doc: None,
        }),
    );
    object(
        out,
        "Where each field of the little-endian header starts (bytes): kind u32, puppet \
         u32, sequence u64, input_time f64, count u32, generation u32.",
        "FRAME_HEADER",
        [
            ("KIND", header::KIND),
            ("PUPPET", header::PUPPET),
            ("SEQUENCE", header::SEQUENCE),
            ("INPUT_TIME", header::INPUT_TIME),
            ("COUNT", header::COUNT),
            ("GENERATION", header::GENERATION),
        ]
        .into_iter()
        .map(|(key, offset)| Entry {
            key: key.into(),
            value: offset.to_string(),
            doc: None,
        }),
    );
}

/// A name whose JavaScript key is its value in capitals.
fn named(name: &str) -> Entry {
    Entry {
        key: name.to_uppercase(),
        value: quoted(name),
        doc: None,
    }
}

/// Every variant of a unit enum, with its doc comment.
fn documented<T>() -> impl Iterator<Item = Entry>
where
    T: IntoEnumIterator + EnumMessage + Into<&'static str>,
{
    T::iter().map(|variant| {
        let doc = variant
            .get_documentation()
            .map(|doc| doc.split_whitespace().collect::<Vec<_>>().join(" "));
        Entry {
            doc,
            ..named(variant.into())
        }
    })
}

/// The contact phases by their serde names (the contact crate has no strum).
fn phases() -> Vec<Entry> {
    // A phase added to the contact model fails to compile here until it
    // is listed.
    let all = [Phase::Down, Phase::Move, Phase::Up];
    for phase in all {
        match phase {
            Phase::Down | Phase::Move | Phase::Up => {}
        }
    }
    all.into_iter()
        .map(|phase| {
            let value = serde_json::to_value(phase).expect("a phase serialises");
            named(value.as_str().expect("a phase is a string"))
        })
        .collect()
}

fn quoted(text: &str) -> String {
    format!("'{}'", text.replace('\\', "\\\\").replace('\'', "\\'"))
}

fn section(out: &mut String, title: &str) {
    let rule = "-".repeat(64);
    let _ = write!(out, "\n// {rule} {title}\n");
}

fn doc_comment(out: &mut String, indent: &str, doc: &str) {
    let _ = writeln!(out, "{indent}/** {doc} */");
}

fn constant(out: &mut String, doc: &str, name: &str, value: &str) {
    out.push('\n');
    doc_comment(out, "", doc);
    let _ = writeln!(out, "export const {name} = {value};");
}

fn object(out: &mut String, doc: &str, name: &str, entries: impl Iterator<Item = Entry>) {
    out.push('\n');
    doc_comment(out, "", doc);
    let _ = writeln!(out, "export const {name} = Object.freeze({{");
    for entry in entries {
        if let Some(doc) = &entry.doc {
            doc_comment(out, "  ", doc);
        }
        let _ = writeln!(out, "  {}: {},", entry.key, entry.value);
    }
    out.push_str("});\n");
}

#[cfg(test)]
mod tests {
    /// The committed `clients/web/wire.js` is what the Rust types say; when
    /// it is not, this test rewrites it (review and commit the change) and
    /// fails, so a fresh clone's CI never runs a page older than its
    /// daemon.
    #[test]
    fn the_browsers_wire_names_are_written_from_the_rust_types() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let path = root.join(super::PATH);
        let want = super::wire_js();
        let have = std::fs::read_to_string(&path).unwrap_or_default();
        if have != want {
            std::fs::write(&path, &want).expect("the file is writable");
            panic!(
                "{} was not what the Rust types say; it has been rewritten from them: \
                 review the change and commit it",
                super::PATH
            );
        }
    }
}
