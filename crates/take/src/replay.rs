//! Replaying a take into a stage without the daemon: each step's changes
//! are applied and the stage solved, as the stage thread did, so the frames
//! come out bit for bit as recorded when the take began on a fresh stage.
//! [`verify`] checks exactly that; the daemon plays takes through its own
//! stage thread instead (live, mixed with performers).

use std::collections::HashMap;
use std::path::Path;

use puppetry_deform::Arap;
use puppetry_stage::{Change, Rebuild, Stage};

use crate::{Record, Step, Tail, TakeError, TakeReader};

/// A stage driven by recorded steps.
pub struct Replayer {
    stage: Stage,
    /// Per free-form puppet, the solver rebuild its last paint dab started
    /// (the live daemon ran it on a worker; here it runs when the take says
    /// it was swapped in).
    rebuilds: HashMap<u32, Rebuild>,
}

impl Replayer {
    /// Takes a stage as built from its file and solves it once, as the
    /// daemon does before any input.
    pub fn new(mut stage: Stage) -> Replayer {
        stage.solve();
        Replayer {
            stage,
            rebuilds: HashMap::new(),
        }
    }

    /// The stage as the steps applied so far left it.
    pub fn stage(&self) -> &Stage {
        &self.stage
    }

    /// Applies one step's changes and solves; returns the puppets solved.
    pub fn apply(&mut self, step: &Step) -> Result<Vec<(u32, bool)>, String> {
        for change in &step.changes {
            self.apply_change(change)?;
        }
        Ok(self.stage.solve())
    }

    fn apply_change(&mut self, change: &Change) -> Result<(), String> {
        if let Change::Rebuilt { puppet, generation } = change {
            let rebuild = self
                .rebuilds
                .remove(puppet)
                .filter(|r| r.generation == *generation)
                .ok_or_else(|| {
                    format!("puppet {puppet}: a rebuilt solver (weights {generation}) that no paint dab started")
                })?;
            let arap = Arap::register(&rebuild.mesh).map_err(|e| e.to_string())?;
            if let Some(next) = self.stage.install(*puppet, *generation, arap) {
                self.rebuilds.insert(next.puppet, next);
            }
            return Ok(());
        }
        // A change the live stage refused (a paint dab off the puppet, a
        // pose name it did not know) is refused here the same way.
        if let Ok(Some(rebuild)) = self.stage.apply_change(change) {
            self.rebuilds.insert(rebuild.puppet, rebuild);
        }
        Ok(())
    }
}

/// What [`verify`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Verification {
    /// How many steps were replayed.
    pub steps: usize,
    /// How many recorded frames were read (compared until the first
    /// mismatch).
    pub frames: usize,
    /// The first frame that differs: (frame index, puppet, vertex, recorded,
    /// replayed).
    pub first_mismatch: Option<String>,
    /// How the take's file ended.
    pub tail: Tail,
}

/// Replays the take at `path` into `stage` (fresh from the same stage
/// file) and compares every recorded frame with the replayed pose, bit for
/// bit in f32.
pub fn verify(path: &Path, stage: Stage) -> Result<Verification, TakeError> {
    let mut reader = TakeReader::open(path)?;
    reader
        .header
        .check_stage(&stage)
        .map_err(|problem| TakeError::Stage {
            file: reader.file().to_string(),
            problem,
        })?;
    let mut replayer = Replayer::new(stage);
    let (mut steps, mut frames) = (0, 0);
    let mut first_mismatch = None;
    for record in reader.by_ref() {
        match record? {
            Record::Step(step) => {
                steps += 1;
                replayer.apply(&step).map_err(|problem| TakeError::Stage {
                    file: path.display().to_string(),
                    problem: format!("step {steps}: {problem}"),
                })?;
            }
            Record::Frame(frame) => {
                frames += 1;
                if first_mismatch.is_some() {
                    continue;
                }
                let Some(p) = replayer.stage().puppets().get(frame.puppet as usize) else {
                    first_mismatch = Some(format!("frame {frames}: no puppet {}", frame.puppet));
                    continue;
                };
                let pose = p.pose();
                if pose.len() != frame.points.len() {
                    first_mismatch = Some(format!(
                        "frame {frames}: {} points recorded, the puppet has {}",
                        frame.points.len(),
                        pose.len()
                    ));
                    continue;
                }
                if let Some((v, (r, q))) =
                    frame
                        .points
                        .iter()
                        .zip(pose)
                        .enumerate()
                        .find(|(_, (r, q))| {
                            r[0].to_bits() != (q.x as f32).to_bits()
                                || r[1].to_bits() != (q.y as f32).to_bits()
                        })
                {
                    first_mismatch = Some(format!(
                        "frame {frames} (puppet {}, t {:.4}): vertex {v} recorded {:?}, replayed [{}, {}]",
                        frame.puppet, frame.t, r, q.x as f32, q.y as f32
                    ));
                }
            }
            Record::Header(_) | Record::End(_) | Record::Clock(_) => {}
        }
    }
    Ok(Verification {
        steps,
        frames,
        first_mismatch,
        tail: reader.tail().cloned().unwrap_or(Tail::Unended),
    })
}
