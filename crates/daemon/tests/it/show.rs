//! A simulated show through the daemon's stage thread: seeded, shrinking
//! random interleavings of what a show does to it — fingers from several
//! sources, sources vanishing mid-contact, a TUIO table read through its
//! tracker whose sender falls silent mid-touch, pins, resets, undo and redo,
//! stiffness painted and solvers rebuilt on a worker, puppets removed and
//! reordered, folds flipped in front (Alt+click), and above all takes: recorded (by hand or by `serve
//! --record`'s first input), stopped with fingers down, played step by
//! step, overdubbed with a source or a region replaced, and stopped in the
//! middle. Every step is a [`Command`] handed to the
//! [`StageDriver`] — the code the stage thread runs — and played takes come
//! from [`Playback`], the code the player thread runs, so only the pacing
//! is the test's.
//!
//! After every step: every vertex finite and within ten times the stage's
//! size; once no finger is down and no take plays, no contact handle and
//! nothing a played take held remains; when a take ends, nothing of it
//! remains. At the end every take reads to its end intact; it exports (as
//! every format is written from) each frame as the take's latest recorded
//! frame at that instant, and before any the stage as it stood when
//! recording began; and every take that began on a fresh stage replays bit
//! for bit (`takes --verify`).
//!
//! (The stage crate's `simulate` drives the stage itself, on every rig and
//! with more kinds of change; this one is about what the stage thread adds.)
//! A failure writes its shrunk sequence to `target/show-failure-<stage>.json`;
//! copied into `tests/fixtures/show/` it is replayed by
//! `simulated_show_failures_stay_fixed` for ever after.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec2;
use proptest::prelude::*;
use puppetry_daemon::lineup::LineupChange;
use puppetry_daemon::stage_thread::{Command, Edit, StageDriver, TakeSettings};
use puppetry_daemon::takes::{PlayOptions, Playback};
use puppetry_input::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, HandleKind, Owner, Stage};
use puppetry_testkit::simulate::{Spot, cases, failure_file, spot};
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, oneshot};

/// The stages a show is simulated on: a free puppet, a grid, a skeleton
/// with key poses, a rope with a puppet (two puppets), a keyframed stage.
const STAGES: [&str; 5] = ["demo", "grid", "skeleton", "curve", "keyframe"];

/// The live sources: a touch table, a performer's browser, a relay.
const SOURCES: [&str; 3] = ["table", "client:7", "relay:hall:3"];

/// What a played take leaves out for the live performer.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "replace", rename_all = "snake_case")]
enum Replace {
    Nothing,
    Source { source: u8 },
    Region { at: Spot, radius: f64 },
}

/// One thing a show does to the stage thread.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
enum Op {
    Touch {
        source: u8,
        finger: u8,
        at: Spot,
    },
    Lift {
        source: u8,
        finger: u8,
    },
    Gone {
        source: u8,
    },
    Pin {
        at: Spot,
    },
    Paint {
        puppet: u8,
        at: Spot,
        strength: f64,
        /// Painter `stroke % 2`'s stroke `stroke / 2`: two pages number
        /// their strokes alike.
        #[serde(default)]
        stroke: u8,
    },
    /// Rebuilt solvers that reached the channel land.
    Land,
    Undo {
        puppet: u8,
    },
    Redo {
        puppet: u8,
    },
    Reset {
        puppet: u8,
    },
    Remove {
        puppet: u8,
    },
    Reorder {
        seed: u8,
    },
    Record,
    StopRecording,
    /// A finished take starts playing; `overdub`: recorded over as it
    /// plays, as the page's overdub does.
    Play {
        take: u8,
        overdub: bool,
        replace: Replace,
    },
    /// The take playing plays its next steps (and ends after its last).
    PlaySteps {
        steps: u8,
    },
    /// The take playing is stopped in the middle.
    StopPlaying,
    /// The stage thread catches up: it solves, publishes and records.
    Frame,
    /// A finger on the TUIO table (through the input crate's tracker, as
    /// the table's datagrams are read).
    TuioTouch {
        finger: u8,
        at: Spot,
    },
    /// A finger leaves the TUIO table.
    TuioLift {
        finger: u8,
    },
    /// The TUIO sender stops talking without saying goodbye: past the
    /// documented silence, its tracker lets go of what it held.
    TuioSilent,
    /// A performer's Alt+click: the part under the point goes in front
    /// (recorded, replayed and exported with the take).
    DepthFlip {
        at: Spot,
    },
    /// A finger drags one vertex of a puppet onto another's place, in a
    /// few moves (a limb folded across the body), then an Alt+click
    /// there flips the fold; the finger stays down.
    Fold {
        source: u8,
        finger: u8,
        puppet: u8,
        from: u16,
        to: u16,
    },
}

/// What the simulated shows did, over every sequence run in this process
/// (printed with `--nocapture`: a run that never plays a take checks
/// little).
#[derive(Default)]
struct Tally {
    steps: AtomicUsize,
    played: AtomicUsize,
    overdubs: AtomicUsize,
    stopped_mid_way: AtomicUsize,
    played_out: AtomicUsize,
    verified_exactly: AtomicUsize,
    exported: AtomicUsize,
}

static TALLY: Tally = Tally {
    steps: AtomicUsize::new(0),
    played: AtomicUsize::new(0),
    overdubs: AtomicUsize::new(0),
    stopped_mid_way: AtomicUsize::new(0),
    played_out: AtomicUsize::new(0),
    verified_exactly: AtomicUsize::new(0),
    exported: AtomicUsize::new(0),
};

fn count(counter: &AtomicUsize) {
    counter.fetch_add(1, Ordering::Relaxed);
}

/// A failing sequence, as written for replay.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Sequence {
    stage: String,
    record_from_first_input: bool,
    ops: Vec<Op>,
}

/// The take playing: its name and the rest of it.
struct Playing {
    name: String,
    playback: Playback,
}

/// A TUIO table's sender, read through the input crate's tracker.
struct Tuio {
    tracker: puppetry_input::tuio::TuioTracker,
    down: std::collections::BTreeMap<i32, (f32, f32)>,
    fseq: i32,
    clock: f64,
}

/// A show in progress: the driver, what the performers hold down, the take
/// playing, the takes finished.
struct Show {
    config: StageConfig,
    driver: StageDriver,
    /// Keeps the channel rebuilt solvers come back on open.
    _wake: mpsc::Sender<Command>,
    rebuilt: mpsc::Receiver<Command>,
    dir: tempfile::TempDir,
    down: std::collections::BTreeSet<(u8, u8)>,
    playing: Option<Playing>,
    recording: bool,
    time: f64,
    /// The TUIO table: its tracker, the fingers its sender says are down
    /// (by session), its frame sequence and its clock.
    tuio: Tuio,
    /// Per take begun by hand, every puppet on stage as it stood when
    /// recording began: the take's exported first frame.
    openings: std::collections::BTreeMap<String, Vec<(u32, Points)>>,
}

fn config(stage: &str) -> StageConfig {
    let root = puppetry_testkit::root();
    StageConfig::load(&root.join(format!("config/{stage}.toml"))).unwrap()
}

impl Show {
    fn new(stage: &str, record_from_first_input: bool) -> Show {
        let config = config(stage);
        let dir = tempfile::tempdir().unwrap();
        let takes = TakeSettings {
            dir: dir.path().to_path_buf(),
            stage_file: config.file.clone(),
            file_puppets: config.puppets.len(),
            record_from_first_input,
            started: std::time::Instant::now(),
        };
        let (wake, rebuilt) = mpsc::channel(64);
        let built = Stage::from_config(&config).unwrap();
        let built_size = (built.width, built.height);
        let (driver, _outputs) = StageDriver::new(config.clone(), built, takes, wake.downgrade());
        Show {
            config,
            driver,
            _wake: wake,
            rebuilt,
            dir,
            down: Default::default(),
            playing: None,
            recording: record_from_first_input,
            time: 0.0,
            tuio: Tuio {
                tracker: puppetry_input::tuio::TuioTracker::new(
                    puppetry_input::tuio::default_calibration(DVec2::new(
                        built_size.0,
                        built_size.1,
                    ))
                    .unwrap(),
                ),
                down: Default::default(),
                fseq: 0,
                clock: 0.0,
            },
            openings: Default::default(),
        }
    }

    fn stage(&self) -> &Stage {
        self.driver.stage()
    }

    fn point(&self, spot: &Spot) -> DVec2 {
        let stage = self.stage();
        match *spot {
            Spot::Stage { x, y } => DVec2::new(x * stage.width, y * stage.height),
            Spot::Vertex {
                puppet,
                vertex,
                dx,
                dy,
            } => {
                let p = &stage.puppets()[puppet as usize % stage.puppets().len()];
                let v = p.mesh.vertices();
                v[vertex as usize % v.len()] + DVec2::new(dx, dy)
            }
        }
    }

    /// A puppet on stage by a pick.
    fn live(&self, pick: u8) -> Option<u32> {
        let live: Vec<u32> = self.stage().on_stage().map(|p| p.id).collect();
        (!live.is_empty()).then(|| live[pick as usize % live.len()])
    }

    fn change(&mut self, change: Change) {
        self.driver.command(Command::Change {
            change,
            received: Some(self.time),
            reply: None,
        });
    }

    fn frame(&mut self, source: u8, contact: Contact) {
        self.time += 0.01;
        let frame = ContactFrame {
            source: SourceId::new(SOURCES[source as usize]),
            time: self.time,
            contacts: vec![contact],
        };
        self.driver
            .command(puppetry_daemon::convert::frame(frame, self.time));
    }

    /// The TUIO sender's next bundle (every finger down restated), read
    /// by the tracker; the frames it completes go to the stage thread.
    fn tuio_send(&mut self) {
        self.tuio.fseq += 1;
        self.tuio.clock += 0.01;
        let alive: Vec<i32> = self.tuio.down.keys().copied().collect();
        let sets: Vec<(i32, f32, f32)> = self
            .tuio
            .down
            .iter()
            .map(|(&s, &(x, y))| (s, x, y))
            .collect();
        let datagram = puppetry_testkit::tuio::v1(Some("table"), &alive, &sets, self.tuio.fseq);
        let frames = self.tuio.tracker.push(&datagram, self.tuio.clock).unwrap();
        self.tuio_forward(frames);
    }

    fn tuio_forward(&mut self, frames: Vec<ContactFrame>) {
        for frame in frames {
            self.time += 0.01;
            self.driver
                .command(puppetry_daemon::convert::frame(frame, self.time));
        }
    }

    /// Sends a command that answers, and takes its answer (the driver
    /// answers before it returns).
    fn ask<T>(&mut self, command: impl FnOnce(oneshot::Sender<T>) -> Command) -> Option<T> {
        let (tx, mut rx) = oneshot::channel();
        self.driver.command(command(tx));
        rx.try_recv().ok()
    }

    fn takes(&self) -> Vec<PathBuf> {
        let mut takes: Vec<PathBuf> = std::fs::read_dir(self.dir.path())
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "take"))
            .collect();
        takes.sort();
        takes
    }

    /// The take recording, if any, by the take state the driver publishes.
    fn record(&mut self, layers: Vec<String>) -> bool {
        let started = self.ask(|reply| Command::StartTake {
            name: None,
            layers,
            reply,
        });
        let Some(Ok(name)) = started else {
            return false;
        };
        let opening = self
            .stage()
            .on_stage()
            .map(|p| (p.id, as_f32(p.pose())))
            .collect();
        self.openings.insert(name, opening);
        self.recording = true;
        true
    }

    fn stop_recording(&mut self) {
        let _ = self.ask(|reply| Command::StopTake { reply });
        self.recording = false;
    }

    fn play(&mut self, take: u8, overdub: bool, replace: &Replace) -> Result<(), String> {
        if self.playing.is_some() {
            return Ok(());
        }
        let takes = self.takes();
        let Some(path) = takes.get(take as usize % takes.len().max(1)).cloned() else {
            return Ok(());
        };
        let mut options = PlayOptions {
            fast: true,
            ..PlayOptions::default()
        };
        match replace {
            Replace::Nothing => {}
            Replace::Source { source } => options
                .replace_sources
                .push(SOURCES[*source as usize % SOURCES.len()].to_string()),
            Replace::Region { at, radius } => {
                let at = self.point(at);
                let Some(puppet) = self.live(0) else {
                    return Ok(());
                };
                options.replace.push(puppetry_daemon::protocol::Region {
                    puppet,
                    at: at.into(),
                    radius: *radius,
                });
            }
        }
        let puppets = puppetry_take::Header::of_stage("", "", self.stage(), true).puppets;
        // A take recorded before the line-up changed no longer fits: a
        // typed refusal, as the page shows it.
        let Ok(playback) = Playback::open(&path, &puppets, options) else {
            return Ok(());
        };
        let name = playback.name().to_string();
        let overdubbing = overdub && !self.recording && self.record(vec![name.clone()]);
        let answer = self.ask(|reply| Command::PlayStarting {
            name: name.clone(),
            path: path.clone(),
            reply,
        });
        match answer {
            Some(Ok(())) => {
                count(&TALLY.played);
                if overdubbing {
                    count(&TALLY.overdubs);
                }
                self.playing = Some(Playing { name, playback });
                Ok(())
            }
            Some(Err(_)) => {
                if overdubbing {
                    self.stop_recording();
                }
                Ok(())
            }
            None => Err("the stage thread did not answer a take starting".into()),
        }
    }

    fn play_steps(&mut self, steps: u8) -> Result<(), String> {
        for _ in 0..steps.max(1) {
            let Some(playing) = self.playing.as_mut() else {
                return Ok(());
            };
            match playing.playback.next_step() {
                // A step all replaced sends nothing; it still counts.
                Some(Ok((_, changes))) if changes.is_empty() => {}
                Some(Ok((_, changes))) => {
                    self.time += 0.01;
                    self.driver.command(Command::Played {
                        changes,
                        received: self.time,
                    });
                }
                Some(Err(e)) => return Err(format!("a recorded take does not read: {e}")),
                None => {
                    count(&TALLY.played_out);
                    self.end_playing()?
                }
            }
        }
        Ok(())
    }

    /// The take playing ends (played out or stopped): nothing it held
    /// stays; an overdub of it stops.
    fn end_playing(&mut self) -> Result<(), String> {
        let Some(playing) = self.playing.take() else {
            return Ok(());
        };
        self.driver.command(Command::PlayEnded {
            name: playing.name.clone(),
        });
        // The driver stops an overdub of the take with it.
        if self.recording && self.takes_recording().is_none() {
            self.recording = false;
        }
        let prefix = format!("{}/", playing.name);
        for p in self.stage().puppets() {
            if let Some(h) = p.handles().iter().find(|h| match &h.owner {
                Owner::Source(s) => s.starts_with(&prefix),
                Owner::Config => false,
            }) {
                return Err(format!(
                    "take {} ended, yet puppet {} holds {:?} handle {} of {}",
                    playing.name, p.id, h.kind, h.id, h.owner
                ));
            }
        }
        Ok(())
    }

    /// The take being recorded, by the take state the driver publishes.
    fn takes_recording(&self) -> Option<String> {
        self.driver.recording().map(str::to_string)
    }

    fn edit(&mut self, puppet: u8, edit: Edit) {
        if let Some(puppet) = self.live(puppet) {
            let _ = self.ask(|reply| Command::Edit {
                puppet,
                edit,
                reply,
            });
        }
    }

    /// [`Op::Fold`].
    fn fold(&mut self, source: u8, finger: u8, puppet: u8, from: u16, to: u16) {
        let Some(puppet) = self.live(puppet) else {
            return;
        };
        let vertex = |v: u16| {
            let p = &self.stage().puppets()[puppet as usize];
            let pose = p.pose();
            pose[v as usize % pose.len()]
        };
        let (a, b) = (vertex(from), vertex(to));
        let key = (source % 3, finger % 3);
        for i in 0..=4 {
            let phase = if i == 0 && self.down.insert(key) {
                Phase::Down
            } else {
                Phase::Move
            };
            let at = a.lerp(b, f64::from(i) / 4.0);
            self.frame(key.0, Contact::new(u32::from(key.1), phase, at));
            self.driver.finish();
        }
        self.change(Change::DepthFlip { at: b });
        self.driver.finish();
    }

    fn lineup(&mut self, change: LineupChange) {
        let _ = self.ask(|reply| Command::Lineup { change, reply });
    }

    /// One step, then the invariants. One arm per op, each a command or a
    /// call out; long only because a show does many things.
    fn step(&mut self, op: &Op) -> Result<(), String> {
        match op {
            Op::Touch { source, finger, at } => {
                let key = (*source % 3, *finger % 3);
                let phase = if self.down.insert(key) {
                    Phase::Down
                } else {
                    Phase::Move
                };
                let at = self.point(at);
                self.frame(key.0, Contact::new(u32::from(key.1), phase, at));
            }
            Op::Lift { source, finger } => {
                let key = (*source % 3, *finger % 3);
                if self.down.remove(&key) {
                    self.frame(
                        key.0,
                        Contact::new(u32::from(key.1), Phase::Up, DVec2::ZERO),
                    );
                }
            }
            Op::Gone { source } => {
                let source = *source % 3;
                self.down.retain(|(s, _)| *s != source);
                self.driver
                    .command(puppetry_daemon::convert::release(SOURCES[source as usize]));
            }
            Op::Pin { at } => {
                let at = self.point(at);
                self.change(Change::Pin {
                    owner: "director".into(),
                    at,
                });
            }
            Op::Paint {
                puppet,
                at,
                strength,
                stroke,
            } => {
                let at = self.point(at);
                if let Some(puppet) = self.live(*puppet) {
                    self.change(Change::Paint {
                        puppet,
                        at,
                        radius: 40.0,
                        strength: *strength,
                        stroke: Some(u64::from(*stroke / 2)),
                        painter: Some(format!("client:{}", stroke % 2)),
                    });
                }
            }
            Op::Land => {
                // A rebuild takes its worker a moment; whatever has come
                // back lands, the rest lands later (or never: both happen
                // in a show).
                std::thread::sleep(std::time::Duration::from_millis(5));
                while let Ok(command) = self.rebuilt.try_recv() {
                    self.driver.command(command);
                }
            }
            Op::Undo { puppet } => self.edit(*puppet, Edit::Undo),
            Op::Redo { puppet } => self.edit(*puppet, Edit::Redo),
            Op::Reset { puppet } => self.edit(*puppet, Edit::Reset),
            Op::Remove { puppet } => {
                if self.stage().on_stage().count() > 1
                    && let Some(puppet) = self.live(*puppet)
                {
                    self.lineup(LineupChange::Remove(puppet));
                }
            }
            Op::Reorder { seed } => {
                let mut order: Vec<u32> = self.stage().on_stage().map(|p| p.id).collect();
                let n = order.len();
                order.rotate_left(*seed as usize % n.max(1));
                self.lineup(LineupChange::Order(order));
            }
            Op::Record => {
                self.record(Vec::new());
            }
            Op::StopRecording => self.stop_recording(),
            Op::Play {
                take,
                overdub,
                replace,
            } => self.play(*take, *overdub, replace)?,
            Op::PlaySteps { steps } => self.play_steps(*steps % 8)?,
            Op::StopPlaying => {
                if self.playing.is_some() {
                    count(&TALLY.stopped_mid_way);
                }
                self.end_playing()?
            }
            Op::Frame => self.driver.finish(),
            Op::TuioTouch { finger, at } => {
                let at = self.point(at);
                let stage = self.stage();
                let normalised = (
                    (at.x / stage.width) as f32,
                    (1.0 - at.y / stage.height) as f32,
                );
                self.tuio
                    .down
                    .insert(i32::from(*finger % 3) + 1, normalised);
                self.tuio_send();
            }
            Op::TuioLift { finger } => {
                if self
                    .tuio
                    .down
                    .remove(&(i32::from(*finger % 3) + 1))
                    .is_some()
                {
                    self.tuio_send();
                }
            }
            Op::DepthFlip { at } => {
                let at = self.point(at);
                self.change(Change::DepthFlip { at });
            }
            Op::Fold {
                source,
                finger,
                puppet,
                from,
                to,
            } => self.fold(*source, *finger, *puppet, *from, *to),
            Op::TuioSilent => {
                let after = puppetry_input::tuio::RELEASE_AFTER.as_secs_f64();
                self.tuio.clock += after + 0.1;
                let frames = self.tuio.tracker.expire(self.tuio.clock, after);
                self.tuio.down.clear();
                self.tuio_forward(frames);
            }
        }
        // `serve --record` starts its take with the first change.
        if self.takes_recording().is_some() {
            self.recording = true;
        }
        self.check()
    }

    /// Every vertex finite and near the stage; once no finger is down and
    /// no take plays, no contact handle and nothing of a take remains.
    fn check(&self) -> Result<(), String> {
        let stage = self.stage();
        let size = stage.width.max(stage.height);
        let centre = DVec2::new(stage.width, stage.height) * 0.5;
        for p in stage.on_stage() {
            for (i, v) in p.pose().iter().enumerate() {
                if !v.is_finite() || v.distance(centre) > 10.0 * size {
                    return Err(format!("puppet {} vertex {i} is at {v}", p.id));
                }
            }
        }
        if self.down.is_empty() && self.tuio.down.is_empty() && self.playing.is_none() {
            for p in stage.puppets() {
                let left = p.handles().iter().find(|h| {
                    h.kind == HandleKind::Contact
                        || matches!(&h.owner, Owner::Source(s) if s.starts_with("take-"))
                });
                if let Some(h) = left {
                    return Err(format!(
                        "no finger is down and no take plays, yet puppet {} holds {:?} handle {} of {}",
                        p.id, h.kind, h.id, h.owner
                    ));
                }
            }
        }
        Ok(())
    }

    /// The show ends: the take playing is stopped, the take recording
    /// stops; every take reads to its end intact, and one that began on a
    /// fresh stage replays bit for bit.
    fn end(mut self) -> Result<(), String> {
        self.end_playing()?;
        self.driver.finish();
        self.stop_recording();
        self.driver.shut_down();
        self.check()?;
        for path in self.takes() {
            self.check_export(&path)?;
            let header = puppetry_take::TakeReader::open(&path)
                .map_err(|e| format!("{}: {e}", path.display()))?
                .header;
            let stage = Stage::from_config(&self.config).unwrap();
            let verified = puppetry_take::replay::verify(&path, stage);
            if !header.fresh {
                // Begun mid-show, a take replays only over the stage as it
                // was; reading it through must still not fail.
                if let Err(e) = &verified
                    && !matches!(e, puppetry_take::TakeError::Stage { .. })
                {
                    return Err(format!("{}: {e}", path.display()));
                }
                continue;
            }
            let v = verified.map_err(|e| format!("{}: {e}", path.display()))?;
            if let Some(m) = v.first_mismatch {
                return Err(format!(
                    "{} began on a fresh stage but does not replay exactly: {m}",
                    path.display()
                ));
            }
            if !matches!(v.tail, puppetry_take::Tail::Ended(_)) {
                return Err(format!("{} is damaged: {:?}", path.display(), v.tail));
            }
            count(&TALLY.verified_exactly);
        }
        Ok(())
    }
}

impl Show {
    /// The take exported as an animation (what every format is written
    /// from): each frame at `k / fps` is the latest recorded frame at or
    /// before it, and before any, the stage as it stood when recording
    /// began (the snapshot taken then, for a take begun by hand).
    fn check_export(&self, path: &Path) -> Result<(), String> {
        const FPS: f64 = 30.0;
        let read = puppetry_export::take::animation_of_take(path, &self.config, FPS, None, None);
        let animation = match read {
            Ok(animation) => animation,
            Err(puppetry_export::take::TakeExportError::Damaged { problem, .. })
                if problem.contains("has no frames") =>
            {
                return Ok(());
            }
            Err(e) => return Err(format!("{} does not export: {e}", path.display())),
        };
        let reader = puppetry_take::TakeReader::open(path).unwrap();
        let header = reader.header.clone();
        // A take begun on a fresh stage replays exactly: alongside, each
        // recorded frame's drawing order as the stage had it (flips too).
        let mut replay = header.fresh.then(|| {
            puppetry_take::replay::Replayer::new(
                Stage::from_config(&puppetry_take::stage_config(&self.config, &header)).unwrap(),
            )
        });
        let mut recorded: std::collections::BTreeMap<u32, Vec<(f64, Points)>> = Default::default();
        let mut drawn: std::collections::BTreeMap<u32, Vec<Option<Vec<u32>>>> = Default::default();
        for record in reader {
            match record {
                Ok(puppetry_take::Record::Step(step)) => {
                    if let Some(r) = &mut replay {
                        r.apply(&step)?;
                    }
                }
                Ok(puppetry_take::Record::Frame(f)) => {
                    let order = replay.as_ref().and_then(|r| {
                        let (depth, _) = r.stage().puppets()[f.puppet as usize].depth()?;
                        let mut order: Vec<u32> = (0..depth.len() as u32).collect();
                        order.sort_by_key(|&t| depth[t as usize]);
                        Some(order)
                    });
                    drawn.entry(f.puppet).or_default().push(order);
                    recorded.entry(f.puppet).or_default().push((f.t, f.points));
                }
                _ => {}
            }
        }
        let start = Stage::from_config(&puppetry_take::stage_config(&self.config, &header))
            .map(puppetry_take::replay::Replayer::new)
            .map_err(|e| e.to_string())?;
        let name = path.file_stem().unwrap().to_string_lossy();
        let opening = self.openings.get(name.as_ref());
        for (puppet, id) in animation.puppets.iter().zip(header.drawn()) {
            let before = match opening.and_then(|o| o.iter().find(|(p, _)| *p == id)) {
                Some((_, pose)) => pose.clone(),
                None => as_f32(start.stage().puppets()[id as usize].pose()),
            };
            let frames = recorded.remove(&id).unwrap_or_default();
            let orders = drawn.remove(&id).unwrap_or_default();
            for (k, exported) in puppet.frames.iter().enumerate() {
                let instant = k as f64 / FPS;
                let latest = frames.iter().rposition(|(t, _)| *t <= instant);
                let expected = latest.map_or(&before, |i| &frames[i].1);
                // Drawn in the order the stage had with that frame.
                if let Some(Some(order)) = latest.map(|i| &orders[i]) {
                    let exported_order: Vec<u32> = match puppet.draw_orders.get(k) {
                        Some(o) => o.to_vec(),
                        None => (0..puppet.triangles.len() as u32).collect(),
                    };
                    if &exported_order != order {
                        return Err(format!(
                            "{name}: puppet {id}'s exported frame {k} ({instant:.3} s) is drawn in \
                             another order than the stage drew the take's frame then"
                        ));
                    }
                }
                if exported != expected {
                    return Err(format!(
                        "{name}: puppet {id}'s exported frame {k} ({instant:.3} s) is not the take's \
                         frame then{}",
                        if k == 0 {
                            " (the stage as recording began)"
                        } else {
                            ""
                        }
                    ));
                }
            }
        }
        count(&TALLY.exported);
        Ok(())
    }
}

/// A puppet's vertices as a take's frame holds them.
type Points = Vec<[f32; 2]>;

fn as_f32(pose: &[DVec2]) -> Points {
    pose.iter().map(|p| [p.x as f32, p.y as f32]).collect()
}

/// Runs a sequence: the first broken invariant, if any.
fn run(sequence: &Sequence) -> Result<(), String> {
    TALLY.steps.fetch_add(sequence.ops.len(), Ordering::Relaxed);
    let mut show = Show::new(&sequence.stage, sequence.record_from_first_input);
    for (i, op) in sequence.ops.iter().enumerate() {
        show.step(op)
            .map_err(|e| format!("step {i} ({op:?}): {e}"))?;
        if i % 4 == 3 {
            // The stage thread solves when its channel runs dry.
            show.driver.finish();
            show.check().map_err(|e| format!("after step {i}: {e}"))?;
        }
    }
    show.end()
}

fn op() -> impl Strategy<Value = Op> {
    let u = any::<u8>;
    let replace = prop_oneof![
        2 => Just(Replace::Nothing),
        1 => u().prop_map(|source| Replace::Source { source }),
        1 => (spot(), 1.0..200.0f64).prop_map(|(at, radius)| Replace::Region { at, radius }),
    ];
    prop_oneof![
        10 => (u(), u(), spot()).prop_map(|(source, finger, at)| Op::Touch { source, finger, at }),
        4 => (u(), u()).prop_map(|(source, finger)| Op::Lift { source, finger }),
        1 => u().prop_map(|source| Op::Gone { source }),
        1 => spot().prop_map(|at| Op::Pin { at }),
        1 => (u(), spot(), -1.5..1.5f64, 0u8..6).prop_map(|(puppet, at, strength, stroke)| Op::Paint { puppet, at, strength, stroke }),
        1 => Just(Op::Land),
        1 => u().prop_map(|puppet| Op::Undo { puppet }),
        1 => u().prop_map(|puppet| Op::Redo { puppet }),
        1 => u().prop_map(|puppet| Op::Reset { puppet }),
        1 => u().prop_map(|puppet| Op::Remove { puppet }),
        1 => u().prop_map(|seed| Op::Reorder { seed }),
        3 => Just(Op::Record),
        3 => Just(Op::StopRecording),
        3 => (u(), any::<bool>(), replace).prop_map(|(take, overdub, replace)| Op::Play { take, overdub, replace }),
        6 => u().prop_map(|steps| Op::PlaySteps { steps }),
        1 => Just(Op::StopPlaying),
        4 => Just(Op::Frame),
        4 => (u(), spot()).prop_map(|(finger, at)| Op::TuioTouch { finger, at }),
        2 => u().prop_map(|finger| Op::TuioLift { finger }),
        1 => Just(Op::TuioSilent),
        2 => spot().prop_map(|at| Op::DepthFlip { at }),
        2 => (u(), u(), u(), any::<u16>(), any::<u16>()).prop_map(|(source, finger, puppet, from, to)| Op::Fold { source, finger, puppet, from, to }),
    ]
}

fn simulate(stage: &'static str) {
    let cases = cases(8);
    let config = ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    };
    proptest!(config, |(record_from_first_input in any::<bool>(), ops in proptest::collection::vec(op(), 1..80))| {
        let sequence = Sequence { stage: stage.to_string(), record_from_first_input, ops };
        if let Err(problem) = run(&sequence) {
            let file = failure_file("show", stage);
            let _ = std::fs::write(&file, serde_json::to_string_pretty(&sequence).unwrap());
            return Err(TestCaseError::fail(format!("{problem}\n(sequence written to {})", file.display())));
        }
    });
    let t = &TALLY;
    let n = |c: &AtomicUsize| c.load(Ordering::Relaxed);
    eprintln!(
        "show {stage}: {cases} sequences; so far in this process {} steps, {} takes played ({} overdubbed; {} played out, {} stopped mid-way), {} fresh takes replayed exactly, {} exported and checked",
        n(&t.steps),
        n(&t.played),
        n(&t.overdubs),
        n(&t.played_out),
        n(&t.stopped_mid_way),
        n(&t.verified_exactly),
        n(&t.exported)
    );
}

#[test]
fn show_demo() {
    simulate(STAGES[0]);
}

#[test]
fn show_grid() {
    simulate(STAGES[1]);
}

#[test]
fn show_skeleton() {
    simulate(STAGES[2]);
}

#[test]
fn show_curve() {
    simulate(STAGES[3]);
}

#[test]
fn show_keyframe() {
    simulate(STAGES[4]);
}

/// Every sequence the simulated show ever failed on, replayed.
#[test]
fn simulated_show_failures_stay_fixed() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/show");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return;
    };
    for entry in entries {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        let sequence: Sequence = serde_json::from_str(&text).unwrap();
        if let Err(problem) = run(&sequence) {
            panic!("{}: {problem}", path.display());
        }
    }
}
