//! Bad input from the network does not flood the log: the real `puppetry
//! serve` binary with a TUIO input on a free loopback port is sent 3000
//! malformed datagrams, one of them echoing 3 KB of garbage, and its stderr
//! is read back: a few warnings, a summary that counts the rest, and no
//! line long enough to carry the garbage.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use rosc::{OscMessage, OscPacket, OscType};

/// Kills the daemon however the test ends.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A datagram that is valid OSC but bad TUIO, whose error quotes what it
/// was sent: a 2Dcur command `length` characters long.
fn echoing_datagram(length: usize) -> Vec<u8> {
    rosc::encoder::encode(&OscPacket::Message(OscMessage {
        addr: "/tuio/2Dcur".into(),
        args: vec![OscType::String("x".repeat(length))],
    }))
    .unwrap()
}

#[test]
fn a_flood_of_malformed_tuio_datagrams_logs_a_few_short_lines_and_a_count() {
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("tuio.toml");
    std::fs::write(
        &stage,
        crate::common::daemon::stage_text("[[input]]\nkind = \"tuio\"\nlisten = \"127.0.0.1:0\"\n"),
    )
    .unwrap();
    let mut daemon = Daemon(
        Command::new(env!("CARGO_BIN_EXE_puppetry"))
            .args(["serve", "--config"])
            .arg(&stage)
            .env_remove("RUST_LOG")
            .env("NO_COLOR", "1")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let stdout = daemon.0.stdout.take().unwrap();
    let (address, said) = mpsc::channel();
    // Read to the end: a closed pipe would fail the daemon's next print.
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(tuio) = line.split("TUIO: receiving on udp ").nth(1) {
                let _ = address.send(tuio.to_string());
            }
        }
    });
    let tuio = said
        .recv_timeout(Duration::from_secs(60))
        .expect("the daemon says where it receives TUIO");
    let (lines, received) = mpsc::channel();
    let stderr = daemon.0.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if lines.send(line).is_err() {
                return;
            }
        }
    });

    let udp = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    // 3 KB quoted back first, while warnings still get through; then
    // garbage that is not OSC at all and more bad TUIO.
    udp.send_to(&echoing_datagram(3000), &tuio).unwrap();
    for i in 1..3000u32 {
        let datagram = if i % 2 == 0 {
            format!("garbage {i}").into_bytes()
        } else {
            echoing_datagram(40)
        };
        udp.send_to(&datagram, &tuio).unwrap();
        if i % 200 == 0 {
            // Loopback drops what overflows the socket's buffer; pausing
            // now and then lets most of the flood arrive.
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    // The summary comes once the limiter's refill period has passed since
    // the first line it held back; the old code never writes one, so the
    // wait is bounded and the counts below decide.
    let mut log = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while Instant::now() < deadline {
        match received.recv_timeout(Duration::from_millis(200)) {
            Ok(line) => {
                let summary = line.contains("skipped unlogged");
                log.push(line);
                if summary {
                    break;
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
    drop(daemon);
    log.extend(received.try_iter());

    let warnings: Vec<&String> = log
        .iter()
        .filter(|l| l.contains("malformed datagram"))
        .collect();
    let summaries: Vec<&String> = log
        .iter()
        .filter(|l| l.contains("skipped unlogged"))
        .collect();
    assert!(
        !warnings.is_empty(),
        "the first bad datagrams are reported:\n{}",
        log.join("\n")
    );
    assert!(
        warnings.len() <= 20,
        "{} warnings about malformed datagrams (at most 20 wanted)",
        warnings.len()
    );
    assert_eq!(summaries.len(), 1, "one summary counts the rest");
    let counted: u64 = summaries[0]
        .split_whitespace()
        .find_map(|word| word.parse().ok())
        .expect("the summary says how many");
    assert!(counted >= 1, "{}", summaries[0]);
    let longest = log.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    assert!(
        longest <= 400,
        "a log line of {longest} characters: echoed input is not cut short"
    );
    assert!(
        warnings[0].contains('…'),
        "the 3 KB command is quoted cut short: {}",
        warnings[0]
    );
}
