//! A simulated show: seeded, shrinking random interleavings of everything a
//! show does to a stage — fingers from several sources landing, moving and
//! lifting, sources vanishing mid-contact, pins and unpins, depth flips,
//! stiffness and depth painting, undo, redo and reset, key poses, the
//! keyframing cursor and its keys, solver rebuilds landing late, puppets
//! added, removed and reordered — on every bundled stage (free, grid,
//! skeleton, curve, keyframing, several puppets). Every step goes through
//! the one entry point the daemon and played takes use,
//! [`Stage::apply_change`], plus the calls the stage thread makes beside it
//! (solve, rebuild and install, undo/redo/reset, the line-up).
//!
//! After every step it checks that every vertex is finite and within ten
//! times the stage's size; that an up (without a position, as a page
//! sends it) moves no cursor and no handle; that once every finger has lifted or its source
//! gone no contact handle remains; that undo then redo gives back the same
//! state; that a reset with no finger down gives the rest pose. At the end
//! the whole log, replayed into a fresh stage as a take replays, must give
//! the same poses bit for bit.
//!
//! A failure writes its shrunk sequence to
//! `target/simulate-failure-<stage>.json`; copied into
//! `tests/fixtures/simulate/`, it is replayed by
//! `simulated_failures_stay_fixed` for ever after. `PROPTEST_CASES=N`
//! runs N sequences per stage (the default run is a few thousand steps).

use std::collections::{BTreeSet, VecDeque};
use std::path::Path;

use glam::DVec2;
use proptest::prelude::*;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_deform::Arap;
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, HandleKind, Puppet, Rebuild, Rig, Stage};
use puppetry_testkit::simulate::{Spot, cases, failure_file, spot};
use puppetry_testkit::stage_text::{Gingerbread, STAGE};
use serde::{Deserialize, Serialize};

/// The stages a show is simulated on: every rig the project has.
const STAGES: [&str; 6] = ["demo", "grid", "skeleton", "curve", "keyframe", "two"];

/// One thing a show does.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
enum Op {
    /// A finger lands, or moves if it is down.
    Touch {
        source: u8,
        finger: u8,
        at: Spot,
    },
    Lift {
        source: u8,
        finger: u8,
    },
    /// A source goes away (a device unplugged, a browser closed).
    Gone {
        source: u8,
    },
    Pin {
        at: Spot,
    },
    Unpin {
        puppet: u8,
        pick: u8,
    },
    Flip {
        at: Spot,
    },
    Paint {
        puppet: u8,
        at: Spot,
        strength: f64,
        /// Painter `stroke % 2`'s stroke `stroke / 2`.
        stroke: u8,
    },
    PaintDepth {
        puppet: u8,
        at: Spot,
        layer: u16,
        /// As [`Op::Paint`]'s.
        stroke: u8,
    },
    Undo {
        puppet: u8,
    },
    Redo {
        puppet: u8,
    },
    /// Undo then redo, checked to give back the same state.
    UndoRedo {
        puppet: u8,
    },
    /// Undo until nothing is left, checked to give back the weights,
    /// pins, painted layers and key pose the puppet was loaded with (a
    /// sequence makes fewer edits than the history keeps).
    UndoAll {
        puppet: u8,
    },
    Reset {
        puppet: u8,
    },
    KeyPose {
        puppet: u8,
        from: u8,
        to: u8,
        t: f64,
    },
    Cursor {
        puppet: u8,
        at: Option<[f64; 2]>,
    },
    KeyAdd {
        puppet: u8,
        at: [f64; 2],
    },
    KeyMove {
        puppet: u8,
        key: u8,
        at: [f64; 2],
    },
    KeyDelete {
        puppet: u8,
        key: u8,
    },
    /// A free-form puppet's painted weights start a rebuild.
    Rebuild {
        puppet: u8,
    },
    /// The oldest rebuild under way lands.
    Land,
    Remove {
        puppet: u8,
    },
    Reorder {
        seed: u8,
    },
    /// Another copy of a stage-file puppet is added.
    Add {
        puppet: u8,
    },
    /// A frame: the stage solves.
    Solve,
}

/// A step of the log, replayed as a take replays.
#[derive(Debug, Clone)]
enum Step {
    Change(Change),
    Solve,
    Install {
        puppet: u32,
        generation: u64,
        mesh: puppetry_mesh::Mesh,
    },
    Remove(u32),
    Reorder(Vec<u32>),
    Add(usize),
}

/// A failing sequence, as written for replay.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Sequence {
    stage: String,
    ops: Vec<Op>,
}

fn config(stage: &str) -> StageConfig {
    let root = puppetry_testkit::root();
    if stage == "two" {
        let text = format!(
            "{STAGE}{}{}\
             [[puppet]]\nname = \"ribbon\"\nat = [1100, 300]\npins = [[0, 0]]\n\
             [puppet.curve]\npoints = [[0, 0], [60, 30], [120, 40], [180, 30]]\nwidth = 10\ncolour = \"#1f5fa8\"\n",
            Gingerbread::new("left")
                .at(400.0, 360.0)
                .scale(0.8)
                .pins("[[168, 58]]"),
            Gingerbread::new("right")
                .at(800.0, 360.0)
                .scale(0.8)
                .with("[puppet.grid]\ncolumns = 6\nrows = 6"),
        );
        return StageConfig::parse("two.toml", &text, Path::new("/")).unwrap();
    }
    let file = root.join(format!("config/{stage}.toml"));
    let text = std::fs::read_to_string(&file).unwrap();
    StageConfig::parse(&format!("{stage}.toml"), &text, &root.join("config")).unwrap()
}

/// A show in progress: the stage, what is down, what is under way, and the
/// log of everything applied.
struct Show {
    config: StageConfig,
    stage: Stage,
    down: BTreeSet<(u8, u8)>,
    rebuilds: VecDeque<Rebuild>,
    log: Vec<Step>,
    time: f64,
    /// Each puppet's state as loaded (`state`), by id.
    loaded: Vec<[(&'static str, String); 4]>,
}

const SOURCES: [&str; 3] = ["finger-a", "browser-b", "relay:hall:c"];

impl Show {
    fn new(stage: &str) -> Show {
        let config = config(stage);
        let stage = Stage::from_config(&config).unwrap();
        let mut show = Show {
            config,
            stage,
            down: BTreeSet::new(),
            rebuilds: VecDeque::new(),
            log: Vec::new(),
            time: 0.0,
            loaded: Vec::new(),
        };
        show.note_loaded();
        show
    }

    /// Keeps what puppets not seen before were loaded with.
    fn note_loaded(&mut self) {
        for id in self.loaded.len()..self.stage.puppets().len() {
            let state = self.state(id as u32);
            self.loaded.push(state);
        }
    }

    /// Undoes all of a puppet's edits: its weights, pins, layers and key
    /// pose are back as loaded.
    fn undo_all(&mut self, puppet: u8) -> Result<(), String> {
        let Some(puppet) = self.live(puppet) else {
            return Ok(());
        };
        for _ in 0..=puppetry_stage::MAX_HISTORY {
            match self.stage.undo(puppet) {
                Ok(Some(change)) => self.apply(change),
                _ => break,
            }
        }
        self.solve();
        let now = self.state(puppet);
        match Show::differences(&self.loaded[puppet as usize], &now) {
            Some(changed) => Err(format!("puppet {puppet} with every edit undone: {changed}")),
            None => Ok(()),
        }
    }

    fn size(&self) -> f64 {
        self.stage.width.max(self.stage.height)
    }

    /// A puppet on stage by a pick, if any is left.
    fn live(&self, pick: u8) -> Option<u32> {
        let live: Vec<u32> = self
            .stage
            .puppets()
            .iter()
            .filter(|p| !p.removed())
            .map(|p| p.id)
            .collect();
        (!live.is_empty()).then(|| live[pick as usize % live.len()])
    }

    /// Any puppet by a pick, removed ones included: changes naming them
    /// must be refused, not panic.
    fn any(&self, pick: u8) -> u32 {
        pick as u32 % (self.stage.puppets().len() as u32 + 1)
    }

    fn point(&self, spot: &Spot) -> DVec2 {
        match *spot {
            Spot::Stage { x, y } => DVec2::new(x * self.stage.width, y * self.stage.height),
            Spot::Vertex {
                puppet,
                vertex,
                dx,
                dy,
            } => {
                let p = &self.stage.puppets()[puppet as usize % self.stage.puppets().len()];
                let v = p.mesh.vertices();
                v[vertex as usize % v.len()] + DVec2::new(dx, dy)
            }
        }
    }

    fn apply(&mut self, change: Change) {
        // Refusals are typed errors the daemon reports; they must leave the
        // stage as it was, which the invariants check.
        if let Ok(Some(rebuild)) = self.stage.apply_change(&change) {
            self.rebuilds.push_back(rebuild);
        }
        self.log.push(Step::Change(change));
    }

    fn frame(&mut self, source: u8, contact: Contact) {
        self.time += 0.01;
        self.apply(Change::Contacts {
            frame: ContactFrame {
                source: SourceId::new(SOURCES[source as usize % SOURCES.len()]),
                time: self.time,
                contacts: vec![contact],
            },
        });
    }

    fn solve(&mut self) {
        self.stage.solve();
        self.log.push(Step::Solve);
    }

    /// Every cursor and handle target on stage, each a line: an up may take
    /// a handle away but never move one that stays.
    fn held(&self) -> Vec<String> {
        let mut held = Vec::new();
        for p in self.stage.puppets() {
            held.push(format!("puppet {} cursor {:?}", p.id, p.keying().cursor()));
            for h in p.handles() {
                held.push(format!("puppet {} handle {} at {}", p.id, h.id, h.target));
            }
        }
        held
    }

    /// What undo and redo put back, as the stage shows it, by part.
    fn state(&self, puppet: u32) -> [(&'static str, String); 4] {
        let p = &self.stage.puppets()[puppet as usize];
        // By id: a restore puts pins back after the contacts held now.
        let mut pins: Vec<(u64, String)> = p
            .handles()
            .iter()
            .filter(|h| h.kind == HandleKind::Pin)
            .map(|h| (h.id, h.target.to_string()))
            .collect();
        pins.sort_by_key(|pin| pin.0);
        [
            ("weights", format!("{:?}", p.weights())),
            ("pins", format!("{pins:?}")),
            // The painted layers: the order drawn each frame also keeps
            // decisions from earlier frames (docs/depth.md, coherence),
            // which a restore starts afresh.
            ("layers", format!("{:?}", p.static_layers())),
            ("key pose", format!("{:?}", p.key_pose().0)),
        ]
    }

    /// The parts of two states that differ, shortened.
    fn differences(before: &[(&str, String)], after: &[(&str, String)]) -> Option<String> {
        let short = |s: &str| s.chars().take(300).collect::<String>();
        let parts: Vec<String> = before
            .iter()
            .zip(after)
            .filter(|(a, b)| a.1 != b.1)
            .map(|(a, b)| format!("{}: {} became {}", a.0, short(&a.1), short(&b.1)))
            .collect();
        (!parts.is_empty()).then(|| parts.join("; "))
    }

    /// Unpins one of a puppet's pins (or a handle that is none: refused).
    fn unpin(&mut self, puppet: u8, pick: u8) {
        let puppet = self.any(puppet);
        let pins: Vec<u64> = self
            .stage
            .puppets()
            .get(puppet as usize)
            .map(|p| {
                p.handles()
                    .iter()
                    .filter(|h| h.kind == HandleKind::Pin)
                    .map(|h| h.id)
                    .collect()
            })
            .unwrap_or_default();
        let handle = pins.get(pick as usize % pins.len().max(1)).copied();
        self.apply(Change::Unpin {
            puppet,
            handle: handle.unwrap_or(u64::from(pick)),
        });
    }

    /// Undo then redo, checked to give back the same state.
    fn undo_redo(&mut self, puppet: u8) -> Result<(), String> {
        let Some(puppet) = self.live(puppet) else {
            return Ok(());
        };
        // The depth shown follows painted layers at the next solve.
        self.solve();
        let before = self.state(puppet);
        if let Ok(Some(change)) = self.stage.undo(puppet) {
            self.apply(change);
            let change = self.stage.redo(puppet).map_err(|e| e.to_string())?;
            let change = change.ok_or("redo after an undo had nothing to redo")?;
            self.apply(change);
            self.solve();
            let after = self.state(puppet);
            if let Some(changed) = Show::differences(&before, &after) {
                return Err(format!(
                    "undo then redo of puppet {puppet} changed {changed}"
                ));
            }
        }
        Ok(())
    }

    /// A key pose between two names, the skeleton's own or none.
    fn key_pose(&mut self, puppet: u8, from: u8, to: u8, t: f64) {
        let puppet = self.any(puppet);
        let mut names = vec!["rest".to_string(), "nowhere".to_string()];
        if let Some(Rig::Skeleton(s)) = self.stage.puppets().get(puppet as usize).map(|p| p.rig()) {
            names.extend(s.pose_names().into_iter().map(String::from));
        }
        self.apply(Change::KeyPose {
            puppet,
            from: names[from as usize % names.len()].clone(),
            to: names[to as usize % names.len()].clone(),
            t,
        });
    }

    /// A rebuild landing, or the line-up changing.
    fn lineup(&mut self, op: &Op) -> Result<(), String> {
        match op {
            Op::Land => {
                if let Some(rebuild) = self.rebuilds.pop_front() {
                    let arap = Arap::register(&rebuild.mesh).map_err(|e| e.to_string())?;
                    self.log.push(Step::Install {
                        puppet: rebuild.puppet,
                        generation: rebuild.generation,
                        mesh: rebuild.mesh.clone(),
                    });
                    if let Some(next) = self.stage.install(rebuild.puppet, rebuild.generation, arap)
                    {
                        self.rebuilds.push_back(next);
                    }
                }
            }
            Op::Remove { puppet } => {
                if let Some(puppet) = self.live(*puppet) {
                    // The daemon refuses to empty the stage; so does the show.
                    if self.stage.on_stage().count() > 1 && self.stage.remove_puppet(puppet).is_ok()
                    {
                        self.log.push(Step::Remove(puppet));
                    }
                }
            }
            Op::Reorder { seed } => {
                let mut order: Vec<u32> = self.stage.on_stage().map(|p| p.id).collect();
                let n = order.len();
                if n > 1 {
                    order.rotate_left(*seed as usize % n);
                    if *seed % 2 == 1 {
                        order.swap(0, n - 1);
                    }
                }
                if self.stage.set_order(&order).is_ok() {
                    self.log.push(Step::Reorder(order));
                }
            }
            Op::Add { puppet } if self.stage.puppets().len() < 6 => {
                let index = *puppet as usize % self.config.puppets.len();
                add(&mut self.stage, &self.config, index);
                self.log.push(Step::Add(index));
                self.note_loaded();
            }
            _ => {}
        }
        Ok(())
    }

    /// One step, then the invariants. One arm per op, each a change or a
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
                self.frame(key.0, Contact::new(key.1 as u32, phase, at));
            }
            Op::Lift { source, finger } => {
                let key = (*source % 3, *finger % 3);
                if self.down.remove(&key) {
                    // As a page's up, which has no position: an up never
                    // moves anything.
                    let before = self.held();
                    let at = DVec2::ZERO;
                    self.frame(key.0, Contact::new(key.1 as u32, Phase::Up, at));
                    let after = self.held();
                    if let Some(moved) = after.iter().find(|a| !before.contains(a)) {
                        return Err(format!("an up moved {moved}"));
                    }
                }
            }
            Op::Gone { source } => {
                let source = *source % 3;
                self.down.retain(|(s, _)| *s != source);
                self.apply(Change::Release {
                    source: SOURCES[source as usize].to_string(),
                });
            }
            Op::Pin { at } => {
                let at = self.point(at);
                self.apply(Change::Pin {
                    owner: "director".into(),
                    at,
                });
            }
            Op::Unpin { puppet, pick } => self.unpin(*puppet, *pick),
            Op::Flip { at } => {
                let at = self.point(at);
                self.apply(Change::DepthFlip { at });
            }
            Op::Paint {
                puppet,
                at,
                strength,
                stroke,
            } => {
                let at = self.point(at);
                self.apply(Change::Paint {
                    puppet: self.any(*puppet),
                    at,
                    radius: 40.0,
                    strength: *strength,
                    // Two painters numbering strokes alike, as two pages do.
                    stroke: Some(u64::from(*stroke / 2)),
                    painter: Some(format!("client:{}", stroke % 2)),
                });
            }
            Op::PaintDepth {
                puppet,
                at,
                layer,
                stroke,
            } => {
                let at = self.point(at);
                self.apply(Change::PaintDepth {
                    puppet: self.any(*puppet),
                    at,
                    radius: 40.0,
                    layer: *layer,
                    stroke: Some(u64::from(*stroke / 2)),
                    painter: Some(format!("client:{}", stroke % 2)),
                });
            }
            Op::Undo { puppet } => {
                if let Ok(Some(change)) = self.stage.undo(self.any(*puppet)) {
                    self.apply(change);
                }
            }
            Op::Redo { puppet } => {
                if let Ok(Some(change)) = self.stage.redo(self.any(*puppet)) {
                    self.apply(change);
                }
            }
            Op::UndoRedo { puppet } => self.undo_redo(*puppet)?,
            Op::UndoAll { puppet } => self.undo_all(*puppet)?,
            Op::Reset { puppet } => {
                let Some(puppet) = self.live(*puppet) else {
                    return Ok(());
                };
                if let Ok(changes) = self.stage.reset(puppet) {
                    for change in changes {
                        self.apply(change);
                    }
                }
                self.check_rest(puppet)?;
            }
            Op::KeyPose {
                puppet,
                from,
                to,
                t,
            } => self.key_pose(*puppet, *from, *to, *t),
            Op::Cursor { puppet, at } => {
                self.apply(Change::Cursor {
                    puppet: self.any(*puppet),
                    at: at.map(DVec2::from),
                });
            }
            Op::KeyAdd { puppet, at } => {
                let name = format!("key{}", self.log.len());
                self.apply(Change::KeyAdd {
                    puppet: self.any(*puppet),
                    name,
                    at: DVec2::from(*at),
                });
            }
            Op::KeyMove { puppet, key, at } => {
                self.apply(Change::KeyMove {
                    puppet: self.any(*puppet),
                    key: *key as usize,
                    at: DVec2::from(*at),
                });
            }
            Op::KeyDelete { puppet, key } => {
                self.apply(Change::KeyDelete {
                    puppet: self.any(*puppet),
                    key: *key as usize,
                });
            }
            Op::Rebuild { puppet } => {
                if let Some(rebuild) = self.stage.rebuild(self.any(*puppet)) {
                    self.rebuilds.push_back(rebuild);
                }
            }
            Op::Land | Op::Remove { .. } | Op::Reorder { .. } | Op::Add { .. } => {
                self.lineup(op)?
            }
            Op::Solve => self.solve(),
        }
        self.check()
    }

    /// Every vertex finite and near the stage; no contact handle once no
    /// finger is down.
    fn check(&self) -> Result<(), String> {
        let size = self.size();
        let centre = DVec2::new(self.stage.width, self.stage.height) * 0.5;
        for p in self.stage.on_stage() {
            for (i, v) in p.pose().iter().enumerate() {
                if !v.is_finite() || v.distance(centre) > 10.0 * size {
                    return Err(format!("puppet {} vertex {i} is at {v}", p.id));
                }
            }
        }
        if self.down.is_empty() {
            for p in self.stage.puppets() {
                if let Some(h) = p.handles().iter().find(|h| h.kind == HandleKind::Contact) {
                    return Err(format!(
                        "every finger is up, yet puppet {} holds contact handle {} of {}",
                        p.id, h.id, h.owner
                    ));
                }
            }
        }
        Ok(())
    }

    /// One line a puppet after a step (`PUPPETRY_SIMULATE_TRACE=1`): how
    /// far its farthest vertex is from the stage's centre, and its handles.
    fn trace(&self, i: usize, op: &Op) {
        eprintln!("step {i}: {op:?}");
        let centre = DVec2::new(self.stage.width, self.stage.height) * 0.5;
        for p in self.stage.puppets() {
            let far = p
                .pose()
                .iter()
                .map(|v| v.distance(centre))
                .fold(0.0, f64::max);
            let handles: Vec<String> = p
                .handles()
                .iter()
                .map(|h| format!("{}:{:?}@{}", h.owner, h.kind, h.target))
                .collect();
            eprintln!("  puppet {} farthest {far:.1} handles {handles:?}", p.id);
        }
    }

    /// After a reset with no finger down, a solve gives the rest pose.
    fn check_rest(&mut self, puppet: u32) -> Result<(), String> {
        if !self.down.is_empty() {
            return Ok(());
        }
        self.solve();
        let p = &self.stage.puppets()[puppet as usize];
        if p.keying().cursor().is_some() {
            return Ok(());
        }
        let rest = p.mesh.vertices();
        let off = p
            .pose()
            .iter()
            .zip(rest)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f64::max);
        if off > 1e-6 * self.size() {
            return Err(format!("after a reset puppet {puppet} is {off} from rest"));
        }
        Ok(())
    }
}

fn add(stage: &mut Stage, config: &StageConfig, index: usize) {
    let p = &config.puppets[index];
    let puppet = Puppet::load(config, stage.puppets().len(), p).unwrap();
    stage.add_puppet(puppet, p).unwrap();
}

/// The log replayed into a fresh stage, as a take replays: the same poses,
/// bit for bit.
fn replay(show: &Show, name: &str) -> Result<(), String> {
    let mut stage = Stage::from_config(&config(name)).unwrap();
    for step in &show.log {
        match step {
            Step::Change(change) => {
                let _ = stage.apply_change(change);
            }
            Step::Solve => {
                stage.solve();
            }
            Step::Install {
                puppet,
                generation,
                mesh,
            } => {
                let _ = stage.rebuild(*puppet);
                let arap = Arap::register(mesh).map_err(|e| e.to_string())?;
                stage.install(*puppet, *generation, arap);
            }
            Step::Remove(puppet) => stage.remove_puppet(*puppet).map_err(|e| e.to_string())?,
            Step::Reorder(order) => stage.set_order(order).map_err(|e| e.to_string())?,
            Step::Add(index) => add(&mut stage, &show.config, *index),
        }
    }
    stage.solve();
    let mut live = show.stage.puppets().iter().zip(stage.puppets());
    if let Some((a, _)) = live.find(|(a, b)| {
        a.pose().len() != b.pose().len()
            || a.pose()
                .iter()
                .zip(b.pose())
                .any(|(p, q)| p.x.to_bits() != q.x.to_bits() || p.y.to_bits() != q.y.to_bits())
    }) {
        return Err(format!(
            "the replayed take's puppet {} differs from the show",
            a.id
        ));
    }
    Ok(())
}

/// Steps run, over every sequence of every stage (printed with
/// `--nocapture`, for the long run's count).
static STEPS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Runs a sequence on a stage: the first broken invariant, if any.
fn run(name: &str, ops: &[Op]) -> Result<(), String> {
    STEPS.fetch_add(ops.len(), std::sync::atomic::Ordering::Relaxed);
    let mut show = Show::new(name);
    let trace = std::env::var_os("PUPPETRY_SIMULATE_TRACE").is_some();
    for (i, op) in ops.iter().enumerate() {
        show.step(op)
            .map_err(|e| format!("step {i} ({op:?}): {e}"))?;
        if trace {
            show.trace(i, op);
        }
    }
    show.solve();
    show.check()?;
    replay(&show, name)
}

fn op() -> impl Strategy<Value = Op> {
    let u = any::<u8>;
    let pad = || (-0.2..1.2f64, -0.2..1.2f64).prop_map(|(x, y)| [x, y]);
    prop_oneof![
        8 => (u(), u(), spot()).prop_map(|(source, finger, at)| Op::Touch { source, finger, at }),
        3 => (u(), u()).prop_map(|(source, finger)| Op::Lift { source, finger }),
        1 => u().prop_map(|source| Op::Gone { source }),
        1 => spot().prop_map(|at| Op::Pin { at }),
        1 => (u(), u()).prop_map(|(puppet, pick)| Op::Unpin { puppet, pick }),
        1 => spot().prop_map(|at| Op::Flip { at }),
        1 => (u(), spot(), -1.5..1.5f64, 0u8..6).prop_map(|(puppet, at, strength, stroke)| Op::Paint { puppet, at, strength, stroke }),
        1 => (u(), spot(), 0u16..5, 0u8..6).prop_map(|(puppet, at, layer, stroke)| Op::PaintDepth { puppet, at, layer, stroke }),
        1 => u().prop_map(|puppet| Op::Undo { puppet }),
        1 => u().prop_map(|puppet| Op::Redo { puppet }),
        1 => u().prop_map(|puppet| Op::UndoRedo { puppet }),
        1 => u().prop_map(|puppet| Op::UndoAll { puppet }),
        1 => u().prop_map(|puppet| Op::Reset { puppet }),
        1 => (u(), u(), u(), -0.5..1.5f64).prop_map(|(puppet, from, to, t)| Op::KeyPose { puppet, from, to, t }),
        1 => (u(), proptest::option::of(pad())).prop_map(|(puppet, at)| Op::Cursor { puppet, at }),
        1 => (u(), pad()).prop_map(|(puppet, at)| Op::KeyAdd { puppet, at }),
        1 => (u(), 0u8..4, pad()).prop_map(|(puppet, key, at)| Op::KeyMove { puppet, key, at }),
        1 => (u(), 0u8..4).prop_map(|(puppet, key)| Op::KeyDelete { puppet, key }),
        1 => u().prop_map(|puppet| Op::Rebuild { puppet }),
        1 => Just(Op::Land),
        1 => u().prop_map(|puppet| Op::Remove { puppet }),
        1 => u().prop_map(|seed| Op::Reorder { seed }),
        1 => u().prop_map(|puppet| Op::Add { puppet }),
        6 => Just(Op::Solve),
    ]
}

fn simulate(name: &'static str) {
    let cases = cases(24);
    let config = ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    };
    proptest!(config, |(ops in proptest::collection::vec(op(), 1..60))| {
        if let Err(problem) = run(name, &ops) {
            let file = failure_file("simulate", name);
            let sequence = Sequence { stage: name.to_string(), ops: ops.clone() };
            let _ = std::fs::write(&file, serde_json::to_string_pretty(&sequence).unwrap());
            return Err(TestCaseError::fail(format!("{problem}\n(sequence written to {})", file.display())));
        }
    });
    let steps = STEPS.load(std::sync::atomic::Ordering::Relaxed);
    eprintln!("simulated {name}: {cases} sequences; {steps} steps so far in this process");
}

#[test]
fn simulate_demo() {
    simulate(STAGES[0]);
}

#[test]
fn simulate_grid() {
    simulate(STAGES[1]);
}

#[test]
fn simulate_skeleton() {
    simulate(STAGES[2]);
}

#[test]
fn simulate_curve() {
    simulate(STAGES[3]);
}

#[test]
fn simulate_keyframe() {
    simulate(STAGES[4]);
}

#[test]
fn simulate_two_puppets() {
    simulate(STAGES[5]);
}

/// Every sequence the simulation ever failed on, replayed.
#[test]
fn simulated_failures_stay_fixed() {
    let dir = puppetry_testkit::root().join("crates/stage/tests/fixtures/simulate");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return;
    };
    for entry in entries {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        let sequence: Sequence = serde_json::from_str(&text).unwrap();
        if let Err(problem) = run(&sequence.stage, &sequence.ops) {
            panic!("{}: {problem}", path.display());
        }
    }
}
