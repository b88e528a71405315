//! The real `puppetry serve` binary as a child process: started on a stage
//! file, its HTTP and OSC addresses read from what it prints, its log
//! kept, its memory read from `/proc`, and killed when dropped. For tests
//! that need the daemon as a user runs it (its own process, signals, file
//! limits, peak memory) rather than in the test's runtime.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};

/// A running `puppetry serve`.
pub struct Served {
    pub child: Child,
    /// `host:port` of the page and WebSocket.
    pub http: String,
    /// Where OSC triggers are heard, when the stage has an `[osc]` section.
    pub osc: Option<SocketAddr>,
    log: Arc<Mutex<Vec<String>>>,
    stderr: Option<std::thread::JoinHandle<()>>,
}

/// `puppetry serve --config STAGE`, its added pictures kept in `puppets`
/// beside the stage file, for a caller to add to. (Left to the default,
/// `./puppets`, the pictures one test added came back in every later
/// test's daemon, all started from the crate's folder.)
pub fn serve_command(stage: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_puppetry"));
    command.arg("serve").arg("--config").arg(stage);
    let beside = stage.parent().unwrap_or(Path::new("."));
    command.arg("--puppets").arg(beside.join("puppets"));
    command
}

/// Starts `puppetry serve` on `stage` (written into `dir`), takes in
/// `dir/takes`.
pub fn serve(dir: &Path, stage: &str) -> Served {
    let file = dir.join("stage.toml");
    std::fs::write(&file, stage).unwrap();
    let mut command = serve_command(&file);
    command.arg("--takes").arg(dir.join("takes"));
    Served::start(command)
}

impl Served {
    /// Runs `command` (a `puppetry serve`, perhaps behind `sh -c … exec`)
    /// and waits until it says it is serving.
    pub fn start(mut command: Command) -> Served {
        let mut child = command
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let log = Arc::new(Mutex::new(Vec::new()));
        let lines = log.clone();
        let stderr = child.stderr.take().unwrap();
        let stderr = std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                lines.lock().unwrap().push(line);
            }
        });
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let (mut http, mut osc) = (None, None);
        loop {
            let mut line = String::new();
            if out.read_line(&mut line).unwrap() == 0 {
                let _ = child.wait();
                let _ = stderr.join();
                panic!("the daemon stopped: {}", log.lock().unwrap().join("\n"));
            }
            if let Some(rest) = line.split("http://").nth(1) {
                http = rest.split('/').next().map(String::from);
            }
            if let Some(rest) = line.split("udp://").nth(1) {
                osc = rest.split_whitespace().next().map(|a| a.parse().unwrap());
            }
            if line.contains("stop with Ctrl-C") {
                break;
            }
        }
        // Keep reading stdout so the daemon never blocks on a full pipe.
        std::thread::spawn(move || for _ in out.lines() {});
        Served {
            child,
            http: http.expect("the daemon printed its address"),
            osc,
            log,
            stderr: Some(stderr),
        }
    }

    /// The daemon's WebSocket URL.
    pub fn ws_url(&self) -> String {
        format!("ws://{}/ws", self.http)
    }

    /// Everything the daemon logged so far.
    pub fn log(&self) -> Vec<String> {
        self.log.lock().unwrap().clone()
    }

    /// Whether the process is still running.
    pub fn alive(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// The resident set now (`VmRSS`), KiB.
    pub fn rss_kib(&self) -> u64 {
        self.status_kib("VmRSS")
    }

    /// The peak resident set so far (`VmHWM`), KiB.
    pub fn peak_rss_kib(&self) -> u64 {
        self.status_kib("VmHWM")
    }

    fn status_kib(&self, field: &str) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap();
        status
            .lines()
            .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{field} in /proc/PID/status"))
    }

    /// Stops the daemon with SIGTERM; returns everything it logged, having
    /// checked it exited cleanly.
    pub fn stop(mut self) -> Vec<String> {
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let status = self.child.wait().unwrap();
        if let Some(stderr) = self.stderr.take() {
            stderr.join().unwrap();
        }
        let log = std::mem::take(&mut *self.log.lock().unwrap());
        assert!(status.success(), "{status}: {}", log.join("\n"));
        log
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
