//! The take side of the stage thread: the take being recorded and the
//! step gathered for it, what its contacts hold down (let go when it
//! stops), the take playing and what its sources hold (let go when it
//! ends), and the take state every client sees.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::watch;

use puppetry_input::Phase;
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, Stage, StageEvent};
use puppetry_take::recorder::Recorder;
use puppetry_take::{Clock, ClockSource, Frame, Header, Record, Step};

use crate::outputs::Published;
use crate::protocol::{ServerMessage, TakeState};

use super::TakeSettings;

/// The take asked to play is the one being recorded: played into itself it
/// would read what it is writing.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("take {take} is being recorded: stop recording before playing it")]
pub struct BeingRecorded {
    /// The take's name.
    pub take: String,
}

/// The take side of the stage thread: the take being recorded, the step
/// being gathered for it, and the take state every client sees.
pub(super) struct Taking {
    pub(super) settings: TakeSettings,
    /// The lineup's stage file: the stage file's puppets, then those added
    /// since, whose entries a take's header carries.
    pub(super) config: Arc<StageConfig>,
    pub(super) recorder: Option<Recorder>,
    /// No change has reached the stage yet.
    pub(super) fresh: bool,
    /// Puppets were added, removed or reordered: the stage is no longer
    /// the one its file makes, so no take from here on is fresh (its
    /// replay into a stage fresh from the file would differ), though
    /// `serve --record` still waits for the first input.
    pub(super) lineup_changed: bool,
    pub(super) step: Vec<Change>,
    pub(super) events: Vec<StageEvent>,
    pub(super) playing: Option<String>,
    /// When the take playing began.
    pub(super) playing_since: Option<Instant>,
    /// The contacts the take being recorded holds down (by source): they
    /// are let go in the take when it stops, so it ends with nothing held
    /// whenever it is stopped.
    pub(super) held: BTreeMap<String, BTreeSet<u32>>,
    /// Played sources (`TAKE/SOURCE`) that reached the stage: what they
    /// hold lets go when their take ends.
    pub(super) played: BTreeSet<String>,
    /// Played sources whose take ended. An undo or redo can put back a pin
    /// one of them held (the history knows pins, not takes): it goes again
    /// at once. A source leaves the set when its take plays again.
    pub(super) ended: BTreeSet<String>,
    /// The take the one recording layers over, if it is an overdub.
    pub(super) overdub_of: Option<String>,
    /// The take state changed where it could not be published at once (a
    /// take started by the first input): publish after the next solve.
    pub(super) announce: bool,
    pub(super) error: Option<String>,
    pub(super) state: watch::Sender<Arc<Published>>,
}

impl Taking {
    pub(super) fn state_message(&self) -> Arc<Published> {
        Published::of(ServerMessage::Take(TakeState {
            recording: self.recorder.as_ref().map(|r| r.name().to_string()),
            elapsed: self.recorder.as_ref().map_or(0.0, |r| r.elapsed()),
            playing: self.playing.clone(),
            played: self
                .playing_since
                .filter(|_| self.playing.is_some())
                .map(|since| since.elapsed().as_secs_f64()),
            clock: self.settings.started.elapsed().as_secs_f64(),
            error: self.error.clone(),
        }))
    }

    pub(super) fn publish(&self, changes: &watch::Sender<u64>) {
        self.state.send_replace(self.state_message());
        changes.send_modify(|c| *c += 1);
    }

    /// Starts a take named `name` (or the next free `take-NNN`).
    pub(super) fn start(
        &mut self,
        stage: &mut Stage,
        name: Option<String>,
        layers: Vec<String>,
    ) -> Result<String, String> {
        if let Some(r) = &self.recorder {
            return Err(format!("take {} is already recording", r.name()));
        }
        if let Some(name) = &name
            && !puppetry_take::valid_name(name)
        {
            return Err(format!(
                "take name {name:?}: use letters, digits, '-', '_' and '.' (at most 100)"
            ));
        }
        std::fs::create_dir_all(&self.settings.dir)
            .map_err(|e| format!("takes folder {}: {e}", self.settings.dir.display()))?;
        let name = name.unwrap_or_else(|| {
            (1..)
                .map(|n| format!("take-{n:03}"))
                .find(|n| !self.path_of(n).exists())
                .expect("a free take name")
        });
        let fresh = self.fresh && !self.lineup_changed;
        let mut header = Header::of_stage(&name, &self.settings.stage_file, stage, fresh);
        let added = self.config.puppets.iter().enumerate();
        for (id, entry) in added.skip(self.settings.file_puppets) {
            if let Some(recorded) = header.puppets.get_mut(id) {
                recorded.added = Some(Box::new(entry.clone()));
            }
        }
        self.overdub_of = layers.first().cloned();
        header.layers = layers;
        let recorder = Recorder::start(&self.path_of(&name), &header).map_err(|e| e.to_string())?;
        if !fresh && let Err(e) = opening_frames(&recorder, stage) {
            let _ = recorder.finish(&e.to_string());
            return Err(e.to_string());
        }
        tracing::info!("take {name}: recording to {}", recorder.path().display());
        self.recorder = Some(recorder);
        self.error = None;
        self.step.clear();
        self.events.clear();
        self.held.clear();
        stage.keep_events(true);
        Ok(name)
    }

    pub(super) fn path_of(&self, name: &str) -> PathBuf {
        self.settings
            .dir
            .join(format!("{name}.{}", puppetry_take::EXTENSION))
    }

    /// Notes the played sources a played change brings on stage.
    pub(super) fn note_played(&mut self, change: &Change) {
        let source = match change {
            Change::Contacts { frame } => frame.source.as_str(),
            Change::Pin { owner, .. } => owner.as_str(),
            _ => return,
        };
        if !self.played.contains(source) {
            self.ended.remove(source);
            self.played.insert(source.to_string());
        }
    }

    /// A take starts playing, unless it is the take being recorded: played
    /// into itself it would read what it is writing.
    pub(super) fn start_playing(
        &mut self,
        name: String,
        path: &std::path::Path,
        changes: &watch::Sender<u64>,
    ) -> Result<(), BeingRecorded> {
        if let Some(r) = &self.recorder
            && (r.name() == name || r.path() == path)
        {
            let take = r.name().to_string();
            return Err(BeingRecorded { take });
        }
        self.playing = Some(name);
        self.playing_since = Some(Instant::now());
        self.publish(changes);
        Ok(())
    }

    /// The take `name` stopped playing: an overdub of it stops too.
    pub(super) fn ended(&mut self, stage: &mut Stage, name: &str, changes: &watch::Sender<u64>) {
        if self.playing.as_deref() != Some(name) {
            return;
        }
        self.playing = None;
        if self.overdub_of.as_deref() == Some(name) && self.recorder.is_some() {
            let _ = self.stop(stage, "stopped");
        }
        self.publish(changes);
    }

    /// Notes what a change recorded into the take holds down or lets go.
    pub(super) fn note(&mut self, change: &Change) {
        match change {
            Change::Contacts { frame } => {
                let source = frame.source.as_str();
                for c in &frame.contacts {
                    match (c.phase, self.held.get_mut(source)) {
                        (Phase::Down, Some(ids)) => {
                            ids.insert(c.id);
                        }
                        (Phase::Down, None) => {
                            self.held.insert(source.to_string(), BTreeSet::from([c.id]));
                        }
                        (Phase::Up, Some(ids)) => {
                            ids.remove(&c.id);
                            if ids.is_empty() {
                                self.held.remove(source);
                            }
                        }
                        _ => {}
                    }
                }
            }
            Change::Release { source } => {
                self.held.remove(source);
            }
            _ => {}
        }
    }

    /// Ends the take being recorded (if any), for `reason`. Contacts the
    /// take holds down are let go in its last step (the live stage keeps
    /// them: the fingers are still there), so playing it leaves nothing
    /// held. That step has no frames: nobody saw them let go.
    pub(super) fn stop(&mut self, stage: &mut Stage, reason: &str) -> Result<String, String> {
        let recorder = self
            .recorder
            .take()
            .ok_or_else(|| "no take is recording".to_string())?;
        stage.keep_events(false);
        self.overdub_of = None;
        let name = recorder.name().to_string();
        let held = std::mem::take(&mut self.held);
        let released = if held.is_empty() {
            Ok(())
        } else {
            recorder.record(Record::Step(Step {
                t: recorder.elapsed(),
                changes: held
                    .into_keys()
                    .map(|source| Change::Release { source })
                    .collect(),
                events: Vec::new(),
            }))
        };
        let finished = match released {
            Ok(()) => recorder.finish(reason),
            Err(e) => {
                let _ = recorder.finish(&e.to_string());
                Err(e)
            }
        };
        match finished {
            Ok(()) => {
                tracing::info!("take {name}: {reason}");
                Ok(name)
            }
            Err(e) => {
                tracing::error!("{e}");
                self.error = Some(e.to_string());
                Err(e.to_string())
            }
        }
    }

    /// Records the step just solved and its frames; a take that cannot
    /// keep up or write stops here, with its error shown to everyone.
    pub(super) fn record(&mut self, stage: &mut Stage, solved: &[(u32, bool)]) -> bool {
        let Some(recorder) = &self.recorder else {
            return false;
        };
        stage.take_events(&mut self.events);
        if self.step.is_empty() && solved.is_empty() && self.events.is_empty() {
            return false;
        }
        let t = recorder.elapsed();
        let mut result = recorder.record(Record::Step(Step {
            t,
            changes: std::mem::take(&mut self.step),
            events: std::mem::take(&mut self.events),
        }));
        for &(puppet, _) in solved {
            if result.is_err() {
                break;
            }
            let pose = stage.puppets()[puppet as usize].pose();
            result = recorder.record(Record::Frame(Frame::of_pose(puppet, t, pose)));
        }
        self.failed(stage, result)
    }

    /// Records the show clock's reading `show`, which reached the daemon
    /// at `at` (the take's time is when it arrived, not when the stage
    /// thread got to it); readings from before the take are not its own.
    /// True when the take failed and stopped.
    pub(super) fn clock(&mut self, stage: &mut Stage, show: ShowReading, at: Instant) -> bool {
        let Some(recorder) = &self.recorder else {
            return false;
        };
        let Some(t) = recorder.elapsed_at(at) else {
            return false;
        };
        let result = recorder.record(Record::Clock(Clock {
            t,
            show: show.seconds,
            running: show.running,
            source: show.source,
        }));
        self.failed(stage, result)
    }

    /// A take that cannot keep up or write stops here, with its error
    /// shown to everyone: true when it did.
    fn failed(
        &mut self,
        stage: &mut Stage,
        result: Result<(), puppetry_take::recorder::RecordError>,
    ) -> bool {
        let Err(e) = result else {
            return false;
        };
        tracing::error!("{e}");
        let reason = e.to_string();
        if let Some(recorder) = self.recorder.take() {
            stage.keep_events(false);
            let _ = recorder.finish(&reason);
        }
        self.error = Some(reason);
        true
    }
}

/// Opens a take begun mid-show with the stage as the audience saw it: an
/// empty step at 0 s and every puppet on stage in its current pose. A
/// reader of the take (an export, the page's playback) starts from a
/// stage fresh from its file, so without them a take's first frames would
/// be the rest pose until each puppet next moved. A fresh take needs none:
/// its replay starts where the stage did.
fn opening_frames(
    recorder: &Recorder,
    stage: &Stage,
) -> Result<(), puppetry_take::recorder::RecordError> {
    recorder.record(Record::Step(Step {
        t: 0.0,
        changes: Vec::new(),
        events: Vec::new(),
    }))?;
    for puppet in stage.on_stage() {
        recorder.record(Record::Frame(Frame::of_pose(puppet.id, 0.0, puppet.pose())))?;
    }
    Ok(())
}

/// Where the show's clock is, as an input heard it (MIDI Time Code, MIDI
/// clock, an OSC time message).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShowReading {
    /// Seconds on the show's clock.
    pub seconds: f64,
    /// Whether its transport runs.
    pub running: bool,
    /// What told it.
    pub source: ClockSource,
}
