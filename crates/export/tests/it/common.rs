//! Running the checks of `tests/web` (Node scripts) and the tools they
//! need, failing with what to install when one is missing.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::fixture::root;

/// Whether Chromium tests are on (always, unless `PUPPETRY_BROWSER_TESTS=0`).
/// When they are not, says so on the process's stderr, which libtest does
/// not hide.
pub fn browser_enabled(test: &str) -> bool {
    use std::io::Write;
    // On unless turned off on purpose: a machine without Chromium or Node
    // fails these tests saying what to install, it does not pass them.
    let off = std::env::var_os("PUPPETRY_BROWSER_TESTS").is_some_and(|v| v == "0");
    if off {
        let _ = writeln!(
            std::io::stderr(),
            "browser test {test}: NOT RUN (PUPPETRY_BROWSER_TESTS=0 turns the headless-Chromium tests off)"
        );
    }
    !off
}

/// Prints on the process's stderr (shown even for passing tests).
pub fn note(text: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{text}");
}

/// `tests/web`, after checking that Node and the npm `packages` are there.
fn web_dir(packages: &[&str]) -> PathBuf {
    let found = Command::new("node").arg("--version").output();
    assert!(
        found.is_ok_and(|o| o.status.success()),
        "node not found on PATH: install Node.js (Debian: apt-get install nodejs npm), then run `npm install` in tests/web"
    );
    let dir = root().join("tests/web");
    for p in packages {
        assert!(
            dir.join("node_modules").join(p).is_dir(),
            "tests/web/node_modules/{p} is missing: run `npm install` in tests/web"
        );
    }
    dir
}

/// Runs `node tests/web/SCRIPT ARGS…` (which needs the npm `packages`) and
/// returns its one-line JSON summary, failing the test unless it says
/// `"ok": true`.
pub fn node_script(script: &str, packages: &[&str], args: &[&str]) -> serde_json::Value {
    let dir = web_dir(packages);
    let output = Command::new("node")
        .arg(dir.join(script))
        .args(args)
        .current_dir(&dir)
        .output()
        .expect("node runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    let last = stdout.lines().last().unwrap_or("");
    let summary: serde_json::Value = serde_json::from_str(last).unwrap_or_else(|e| {
        panic!(
            "{script}: no JSON summary ({e}); stdout: {}\nstderr: {stderr}",
            &stdout[..stdout.len().min(2000)]
        )
    });
    assert!(
        output.status.success() && summary["ok"] == true,
        "{script} failed: {}\nstderr: {stderr}",
        &last[..last.len().min(4000)]
    );
    summary
}

/// Fails the test unless `tool` runs, saying what to install.
pub fn require_tool(tool: &str, install: &str) {
    let found = Command::new(tool).arg("-version").output();
    assert!(
        found.is_ok_and(|o| o.status.success()),
        "{tool} not found on PATH: install it ({install})"
    );
}

/// Path as a `&str` for command lines.
pub fn arg(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 temp path")
}
