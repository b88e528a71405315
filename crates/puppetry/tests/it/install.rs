//! The installed binary needs no checkout: `cargo install` puts it in a
//! folder of its own, it runs from another folder with no config and no
//! HOME data, and a WebSocket client receives the bundled demo stage and
//! its frames.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

use futures_util::{SinkExt, StreamExt};
use puppetry_daemon::protocol::{ClientMessage, FrameKind, Role, ServerMessage, decode_frame};
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::{WAIT, http_get, http_status};

/// Stops the daemon however the test ends.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_installed_binary_serves_the_bundled_demo_from_anywhere() {
    let root = puppetry_testkit::root();
    let prefix = tempfile::tempdir().unwrap();
    // The workspace's own target folder: what this test run built is
    // reused, so the install compiles little.
    let target = std::env::current_exe()
        .unwrap()
        .ancestors()
        .nth(3)
        .expect("target/<profile>/deps/<test binary>")
        .to_path_buf();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    // Cargo gives this test process the package's variables (name, version,
    // manifest folder, ...). Build scripts that watch them (ring's watches
    // CARGO_PKG_NAME and CARGO_MANIFEST_DIR) would see them changed from
    // the outer build and compile again, with all that depends on them:
    // minutes, not seconds. The install sees the outer build's environment.
    let set_for_tests = |name: &str| {
        [
            "CARGO_PKG_",
            "CARGO_MANIFEST_",
            "CARGO_CRATE_",
            "CARGO_BIN_",
        ]
        .iter()
        .any(|prefix| name.starts_with(prefix))
            || ["CARGO_PRIMARY_PACKAGE", "CARGO_TARGET_TMPDIR", "OUT_DIR"].contains(&name)
    };
    let test_variables: Vec<std::ffi::OsString> = std::env::vars_os()
        .map(|(name, _)| name)
        .filter(|name| name.to_str().is_some_and(set_for_tests))
        .collect();
    let installed = tokio::task::spawn_blocking({
        let (prefix, target) = (prefix.path().to_path_buf(), target.clone());
        move || {
            let mut install = Command::new(cargo);
            for name in &test_variables {
                install.env_remove(name);
            }
            install
                .args(["install", "--locked", "--offline", "--quiet", "--path"])
                .arg(root.join("crates/puppetry"))
                .arg("--root")
                .arg(&prefix)
                .arg("--target-dir")
                .arg(&target)
                .output()
                .expect("cargo runs")
        }
    })
    .await
    .unwrap();
    assert!(
        installed.status.success(),
        "cargo install: {}",
        String::from_utf8_lossy(&installed.stderr)
    );

    // Nothing in the binary names the checkout: a path baked in at build
    // time (`env!("CARGO_MANIFEST_DIR")` in runtime code) would break the
    // installed binary once the checkout moves, even though it still works
    // here, where the checkout has not moved.
    let binary = std::fs::read(prefix.path().join("bin/puppetry")).unwrap();
    let checkout = puppetry_testkit::root().canonicalize().unwrap();
    let checkout = checkout.to_string_lossy();
    assert!(
        !binary
            .windows(checkout.len())
            .any(|w| w == checkout.as_bytes()),
        "the installed binary names the checkout {checkout}"
    );

    // Elsewhere, with nothing of the checkout in reach.
    let elsewhere = tempfile::tempdir().unwrap();
    let mut daemon = Daemon(
        Command::new(prefix.path().join("bin/puppetry"))
            .args(["serve", "--listen", "127.0.0.1:0"])
            .current_dir(elsewhere.path())
            .env("HOME", elsewhere.path())
            .env("XDG_DATA_HOME", elsewhere.path().join("data"))
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let stdout = daemon.0.stdout.take().unwrap();
    let address = tokio::time::timeout(
        WAIT,
        tokio::task::spawn_blocking(move || {
            for line in BufReader::new(stdout).lines() {
                let line = line.unwrap();
                if let Some(rest) = line.split(" at http://").nth(1) {
                    return rest.trim_end_matches('/').to_string();
                }
            }
            panic!("the daemon printed no address");
        }),
    )
    .await
    .expect("the daemon starts in time")
    .unwrap();

    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{address}/ws"))
        .await
        .unwrap();
    let hello = ClientMessage::Hello {
        role: Role::Viewer,
        token: None,
    };
    ws.send(Message::text(serde_json::to_string(&hello).unwrap()))
        .await
        .unwrap();
    let mut stage = None;
    let mut frame = None;
    while stage.is_none() || frame.is_none() {
        let message = tokio::time::timeout(WAIT, ws.next())
            .await
            .expect("a message in time")
            .expect("open")
            .expect("no error");
        match message {
            Message::Text(text) => {
                if let ServerMessage::Stage { puppets, .. } = serde_json::from_str(&text).unwrap() {
                    stage = Some(puppets);
                }
            }
            Message::Binary(bytes) => {
                let decoded = decode_frame(&bytes).unwrap();
                if decoded.header.kind == FrameKind::Vertices {
                    frame = Some(decoded);
                }
            }
            _ => {}
        }
    }
    let puppets = stage.unwrap();
    assert_eq!(puppets[0].name, "gingerbread");
    assert_eq!(frame.unwrap().points.len() * 2, puppets[0].rest.len());
    // The page and the puppet's picture come from the binary too.
    assert_eq!(http_status(&http_get(address.as_str(), "/").await), 200);
    let picture = http_get(address.as_str(), "/puppets/0/texture.png").await;
    assert_eq!(http_status(&picture), 200);
    // The bundle was unpacked under the data folder, not the working one.
    assert!(elsewhere.path().join("data/puppetry/bundled").is_dir());
    assert_eq!(
        std::fs::read_dir(elsewhere.path()).unwrap().count(),
        1,
        "only the data folder was written"
    );
}
