//! The crate graph is the pipeline (ARCHITECTURE.md, "Crates"): the
//! numeric crates, the stage, takes and exports build no async runtime, no
//! device crate and no network stack. Read from each crate's own
//! `Cargo.toml` (its `[dependencies]`, not its dev-dependencies): none of
//! them may reach `puppetry-input`, the daemon or the binary through the
//! workspace, and every crate they name from outside is one of a short
//! list of plain libraries, so a dependency that would bring tokio in
//! (directly or through a crate of its own) fails here, naming it.

use std::collections::{BTreeMap, BTreeSet};

/// The crates that must stay plain, sync Rust over data.
const PLAIN: [&str; 7] = [
    "puppetry-limits",
    "puppetry-mesh",
    "puppetry-deform",
    "puppetry-contact",
    "puppetry-stage",
    "puppetry-take",
    "puppetry-export",
];

/// What those crates may use from outside the workspace: data, maths,
/// files and error types; nothing with I/O loops of its own. Adding to
/// this list is a decision for ARCHITECTURE.md, not a test fix.
const LIBRARIES: [&str; 14] = [
    "crc32fast",
    "faer",
    "glam",
    "png",
    "pulp",
    "rayon",
    "serde",
    "serde_json",
    "spade",
    "tempfile",
    "thiserror",
    "toml",
    "tracing",
    // The Spine bundle a page downloads (one zip of JSON, atlas, pictures).
    "zip",
];

/// Each workspace crate's normal dependencies, by the names in its
/// `Cargo.toml`.
fn dependencies() -> BTreeMap<String, Vec<String>> {
    let crates = puppetry_testkit::root().join("crates");
    let mut graph = BTreeMap::new();
    for entry in std::fs::read_dir(&crates).unwrap() {
        let manifest = entry.unwrap().path().join("Cargo.toml");
        let Ok(text) = std::fs::read_to_string(&manifest) else {
            continue;
        };
        let name = text
            .lines()
            .find_map(|l| l.strip_prefix("name = "))
            .map(|n| n.trim_matches('"').to_string())
            .unwrap_or_else(|| panic!("{}: no name", manifest.display()));
        let mut section = "";
        let mut names = Vec::new();
        for line in text.lines().map(str::trim) {
            if line.starts_with('[') {
                section = line;
                continue;
            }
            if section != "[dependencies]" || line.is_empty() || line.starts_with('#') {
                continue;
            }
            let key = line
                .split(['=', '.', ' '])
                .next()
                .unwrap_or_default()
                .to_string();
            names.push(key);
        }
        graph.insert(name, names);
    }
    graph
}

#[test]
fn the_stage_takes_and_exports_build_no_runtime_device_or_network_crate() {
    let graph = dependencies();
    let mut wrong = Vec::new();
    for start in PLAIN {
        // Every workspace crate reachable from `start`.
        let mut seen = BTreeSet::from([start.to_string()]);
        let mut stack = vec![start.to_string()];
        while let Some(name) = stack.pop() {
            let deps = graph
                .get(&name)
                .unwrap_or_else(|| panic!("{name} is not a workspace crate"));
            for dep in deps {
                if dep.starts_with("puppetry-") {
                    if !PLAIN.contains(&dep.as_str()) {
                        wrong.push(format!("{start} reaches {dep} (through {name})"));
                    } else if seen.insert(dep.clone()) {
                        stack.push(dep.clone());
                    }
                } else if !LIBRARIES.contains(&dep.as_str()) {
                    wrong.push(format!("{start} reaches {dep} (through {name})"));
                }
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "the plain crates must not depend on these (ARCHITECTURE.md, \"Crates\"):\n{}",
        wrong.join("\n")
    );
}

/// The test reads what it means to: the device crate does depend on tokio
/// and evdev, and the stage did reach it before the contact model moved.
#[test]
fn the_graph_as_read_has_the_device_crates_where_they_live() {
    let graph = dependencies();
    let input = &graph["puppetry-input"];
    for dep in ["tokio", "evdev", "hidapi", "puppetry-contact"] {
        assert!(input.iter().any(|d| d == dep), "input: {input:?}");
    }
    assert!(
        graph["puppetry-stage"]
            .iter()
            .any(|d| d == "puppetry-contact")
    );
}

/// The daemon's top-level modules, and the others each names as
/// `crate::module` (its tests left out: a test may reach anywhere).
fn daemon_module_uses() -> BTreeMap<String, BTreeSet<String>> {
    let src = puppetry_testkit::root().join("crates/daemon/src");
    let mut uses = BTreeMap::new();
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        if name == "lib" {
            continue;
        }
        let mut files = vec![path.clone()];
        let mut named = BTreeSet::new();
        while let Some(file) = files.pop() {
            if file.is_dir() {
                files.extend(std::fs::read_dir(&file).unwrap().map(|e| e.unwrap().path()));
                continue;
            }
            let text = std::fs::read_to_string(&file).unwrap();
            // Test modules sit at the end of a file; comments (doc links
            // among them) are not uses.
            let code: String = text
                .split("#[cfg(test)]")
                .next()
                .unwrap_or_default()
                .lines()
                .filter(|line| !line.trim_start().starts_with("//"))
                .collect::<Vec<_>>()
                .join("\n");
            let mut rest = code.as_str();
            while let Some(at) = rest.find("crate::") {
                rest = &rest[at + "crate::".len()..];
                let module: String = rest
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if let Some(list) = rest.strip_prefix('{') {
                    // `use crate::{a::X, b};`
                    let list = &list[..list.find('}').unwrap_or(list.len())];
                    named.extend(
                        list.split(',')
                            .map(|m| m.trim().split("::").next().unwrap_or_default().to_string()),
                    );
                } else {
                    named.insert(module);
                }
            }
        }
        named.remove(&name);
        uses.insert(name, named);
    }
    uses
}

/// No two of the daemon's modules use each other (ARCHITECTURE.md): a
/// cycle is where a module's concern has leaked into another, and a
/// newcomer cannot read one without the other. The relay reaches the stream
/// through `stream::upstream`'s traits, the player the stage thread through
/// its commands.
#[test]
fn no_two_daemon_modules_use_each_other() {
    let uses = daemon_module_uses();
    assert!(
        uses.get("stream").is_some_and(|u| u.contains("protocol")),
        "the module scan found nothing: {uses:?}"
    );
    let mut cycles = Vec::new();
    for (a, named) in &uses {
        for b in named {
            if a < b && uses.get(b).is_some_and(|u| u.contains(a)) {
                cycles.push(format!("{a} ↔ {b}"));
            }
        }
    }
    assert!(
        cycles.is_empty(),
        "daemon modules that use each other: {cycles:?}"
    );
}
