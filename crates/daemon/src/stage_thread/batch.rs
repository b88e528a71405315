//! A batch: the commands the stage thread applied since its last solve,
//! one arm per command, then one solve, publish and record for all of
//! them (input arriving faster than it solves is all applied, so no
//! contact down or up is lost, and only the newest state is solved).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use tokio::sync::{mpsc, oneshot, watch};

use puppetry_stage::{Change, HandleKind, Stage};

use super::publish::Publisher;
use super::rebuild::start_rebuild;
use super::taking::Taking;
use super::{Command, Edit, Reply, Timings};
use crate::protocol::CursorView;

/// What the stage thread gathered since its last solve.
pub(super) struct Batch {
    /// When the newest input frame reached the daemon.
    pub(super) newest: f64,
    pub(super) stop: bool,
    pub(super) cursors_changed: bool,
    /// Something was applied since the last solve.
    pub(super) dirty: bool,
    pub(super) timings: Arc<Timings>,
    /// When this iteration's commands began.
    pub(super) started: Instant,
    /// The puppets the last solve solved (reused: no allocation).
    pub(super) solved: Vec<(u32, bool)>,
}

impl Batch {
    pub(super) fn new(timings: Arc<Timings>) -> Batch {
        Batch {
            newest: 0.0,
            stop: false,
            cursors_changed: false,
            dirty: false,
            timings,
            started: Instant::now(),
            solved: Vec::new(),
        }
    }

    /// Applies one change to the stage (and the take's step when it took).
    pub(super) fn apply(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        change: Change,
        reply: Option<Reply<()>>,
        wake: &mpsc::WeakSender<Command>,
    ) {
        if taking.settings.record_from_first_input && taking.fresh && taking.recorder.is_none() {
            taking.settings.record_from_first_input = false;
            if let Err(e) = taking.start(stage, None, Vec::new()) {
                tracing::error!("serve --record: {e}");
                taking.error = Some(e);
            }
            taking.announce = true;
        }
        let result = stage.apply_change(&change);
        taking.fresh = false;
        self.dirty = true;
        let result = result.map(|rebuild| {
            if let Some(rebuild) = rebuild {
                start_rebuild(rebuild, wake);
            }
        });
        if result.is_ok() && taking.recorder.is_some() {
            taking.note(&change);
            taking.step.push(change);
        }
        if let Some(reply) = reply {
            let _ = reply.send(result);
        }
    }

    /// One arm per command: long because the commands are many, each arm
    /// short (the longer ones call out to a function of their own).
    pub(super) fn command(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        cursors: &mut BTreeMap<String, CursorView>,
        command: Command,
        wake: &mpsc::WeakSender<Command>,
        changes: &watch::Sender<u64>,
    ) {
        match command {
            Command::Stop => self.stop = true,
            Command::Change {
                change,
                received,
                reply,
            } => {
                if let Some(received) = received {
                    self.newest = received;
                }
                self.apply(stage, taking, change, reply, wake);
            }
            Command::Played { .. } | Command::Lineup { .. } | Command::PlayEnded { .. } => {
                unreachable!(
                    "played steps, a take's end and lineup changes are handled on their own"
                )
            }
            Command::Limit { source, puppets } => stage.limit_source(&source, puppets),
            Command::Edit {
                puppet,
                edit,
                reply,
            } => {
                // The history decides what to put back; the take records
                // the state put back (a `restore`), not the undo, so it
                // replays the same whatever history it began with.
                if edit == Edit::Reset {
                    // Nothing a take no longer playing held stays held.
                    self.let_go_of_played(stage, taking, None, wake);
                }
                let changes = match edit {
                    Edit::Undo => stage.undo(puppet).map(|c| c.into_iter().collect()),
                    Edit::Redo => stage.redo(puppet).map(|c| c.into_iter().collect()),
                    Edit::Reset => stage.reset(puppet),
                };
                match changes {
                    Ok(changes) => {
                        let mut result = Ok(());
                        for change in changes {
                            let (tx, mut rx) = oneshot::channel();
                            self.apply(stage, taking, change, Some(tx), wake);
                            if let Ok(Err(e)) = rx.try_recv()
                                && result.is_ok()
                            {
                                result = Err(e);
                            }
                        }
                        // A pin of a take that ended may be back.
                        self.unpin_ended(stage, taking, wake);
                        // An undo with nothing to undo still changes the
                        // history's counts: publish them.
                        self.dirty = true;
                        let _ = reply.send(result);
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
            }
            Command::ExportGrid { puppet, reply } => {
                let _ = reply.send(stage.export_grid(puppet));
            }
            Command::SaveKeys { puppet, reply } => {
                let _ = reply.send(stage.key_file(puppet));
            }
            Command::SaveWeights { puppet, reply } => {
                let _ = reply.send(stage.weights_file(puppet));
            }
            Command::Rebuilt {
                puppet,
                generation,
                arap,
            } => {
                let next = match arap {
                    Some(arap) => {
                        if taking.recorder.is_some() {
                            taking.step.push(Change::Rebuilt { puppet, generation });
                        }
                        self.dirty = true;
                        stage.install(puppet, generation, *arap)
                    }
                    None => {
                        stage.rebuild_failed(puppet);
                        None
                    }
                };
                if let Some(rebuild) = next {
                    start_rebuild(rebuild, wake);
                }
            }
            Command::Cursor { source, cursor } => {
                // Compared before it moves in: no copy of the cursor.
                self.cursors_changed |= cursors.get(&source) != cursor.as_ref();
                match cursor {
                    Some(c) => cursors.insert(source, c),
                    None => cursors.remove(&source),
                };
            }
            Command::StartTake {
                name,
                layers,
                reply,
            } => {
                let _ = reply.send(taking.start(stage, name, layers));
                taking.publish(changes);
            }
            Command::StopTake { reply } => {
                let _ = reply.send(taking.stop(stage, "stopped"));
                taking.publish(changes);
            }
            Command::PlayStarting { name, path, reply } => {
                let _ = reply.send(taking.start_playing(name, &path, changes));
            }
            Command::Clock { show, at } => {
                if taking.clock(stage, show, at) {
                    taking.publish(changes);
                }
            }
        }
    }

    /// Lets go of what played sources hold: those of the take `ended`, or
    /// (`None`) those of every take but the one playing. Their contacts
    /// lift and their pins go, through changes an overdub records.
    pub(super) fn let_go_of_played(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        ended: Option<&str>,
        wake: &mpsc::WeakSender<Command>,
    ) {
        let of = |source: &str, take: &str| {
            source
                .strip_prefix(take)
                .is_some_and(|rest| rest.starts_with('/'))
        };
        let gone: Vec<String> = match ended {
            Some(take) => taking
                .played
                .iter()
                .filter(|s| of(s.as_str(), take))
                .cloned()
                .collect(),
            None => taking
                .played
                .iter()
                .filter(|s| {
                    !taking
                        .playing
                        .as_deref()
                        .is_some_and(|take| of(s.as_str(), take))
                })
                .cloned()
                .collect(),
        };
        if gone.is_empty() {
            return;
        }
        for source in gone {
            taking.played.remove(&source);
            taking.ended.insert(source.clone());
            self.apply(stage, taking, Change::Release { source }, None, wake);
        }
        self.unpin_ended(stage, taking, wake);
    }

    /// Takes away the pins of played sources whose take ended (just now,
    /// or an undo or redo put them back), through changes an overdub
    /// records.
    fn unpin_ended(
        &mut self,
        stage: &mut Stage,
        taking: &mut Taking,
        wake: &mpsc::WeakSender<Command>,
    ) {
        if taking.ended.is_empty() {
            return;
        }
        let mut pins = Vec::new();
        for p in stage.puppets() {
            for h in p.handles() {
                if h.kind == HandleKind::Pin
                    && let puppetry_stage::Owner::Source(owner) = &h.owner
                    && taking.ended.contains(owner)
                {
                    pins.push((p.id, h.id));
                }
            }
        }
        for (puppet, handle) in pins {
            self.apply(stage, taking, Change::Unpin { puppet, handle }, None, wake);
        }
    }

    /// Solves what was applied, publishes it and records it.
    pub(super) fn finish(
        &mut self,
        stage: &mut Stage,
        publisher: &mut Publisher,
        taking: &mut Taking,
        cursors: &BTreeMap<String, CursorView>,
    ) {
        let t = &self.timings;
        let mut now = Timings::add(&t.commands_ns, self.started);
        if self.dirty {
            self.dirty = false;
            stage.solve_into(&mut self.solved);
            let solved = &self.solved;
            now = Timings::add(&t.solve_ns, now);
            publisher.publish(stage, solved, self.newest);
            now = Timings::add(&t.frames_ns, now);
            publisher.publish_weights(stage);
            now = Timings::add(&t.messages_ns, now);
            let recorded = taking.record(stage, solved);
            now = Timings::add(&t.record_ns, now);
            if recorded || std::mem::take(&mut taking.announce) {
                taking.publish(&publisher.changes);
            }
            t.solves.fetch_add(1, Ordering::Relaxed);
        }
        if self.cursors_changed {
            self.cursors_changed = false;
            publisher.publish_cursors(cursors);
        }
        Timings::add(&t.messages_ns, now);
        // Whatever comes next in this iteration is commands again.
        self.started = Instant::now();
    }
}
