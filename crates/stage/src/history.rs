//! Undo, redo and reset of a puppet's edits: each edit (a paint stroke, a
//! pin, a pose, key poses) keeps a snapshot of what it changed in the
//! puppet's `History`; undo and redo swap snapshots and `restore` puts one
//! back on the stage, rebuilding the solver when weights change.

use super::*;

impl History {
    /// Records that an edit replaced `before` (unless it joins the open
    /// group, whose entry already holds the state before it).
    pub(crate) fn edit(&mut self, before: impl FnOnce() -> Snapshot, group: Option<Group>) {
        if group.is_some() && self.open == group {
            return;
        }
        self.undo.push(before());
        if self.undo.len() > MAX_HISTORY {
            self.undo.remove(0);
        }
        self.redo.clear();
        self.open = group;
    }
}

impl Stage {
    /// Takes back the puppet's last edit (a paint stroke, a pin, a pose):
    /// the change that puts back what it replaced, to apply and record like
    /// any other (none when there is nothing to undo).
    pub fn undo(&mut self, puppet: u32) -> Result<Option<Change>, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let Some(state) = p.history.undo.pop() else {
            return Ok(None);
        };
        let now = p.capture(&state);
        p.history.redo.push(now);
        p.history.open = None;
        Ok(Some(Change::Restore { puppet, state }))
    }

    /// Does again the edit the last undo took back.
    pub fn redo(&mut self, puppet: u32) -> Result<Option<Change>, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let Some(state) = p.history.redo.pop() else {
            return Ok(None);
        };
        let now = p.capture(&state);
        p.history.undo.push(now);
        p.history.open = None;
        Ok(Some(Change::Restore { puppet, state }))
    }

    /// Puts the puppet back as loaded: weights from its mesh file, pins as
    /// in the stage file, its rig at rest, the key cursor let go
    /// (contacts keep their grip). One undo step. Returns the changes to
    /// apply and record.
    pub fn reset(&mut self, puppet: u32) -> Result<Vec<Change>, CommandError> {
        let p = self.puppet_mut(puppet)?;
        let loaded = p.loaded.clone();
        let now = p.capture(&loaded);
        if now != loaded {
            p.history.edit(|| now, None);
        }
        p.history.open = None;
        Ok(vec![
            Change::Restore {
                puppet,
                state: loaded,
            },
            Change::Cursor { puppet, at: None },
            Change::Rest { puppet },
        ])
    }

    /// Sets a puppet's weights, pins and pose (those `state` holds) as they
    /// were. Checked first, so a bad record (from a take file) changes
    /// nothing. A free-form puppet whose weights changed returns the solver
    /// rebuild to run (as [`Stage::paint`]).
    pub(crate) fn restore(
        &mut self,
        puppet: u32,
        state: &Snapshot,
    ) -> Result<Option<Rebuild>, CommandError> {
        let p = self.puppet(puppet)?;
        let refuse = |problem: String| CommandError::Restore { puppet, problem };
        if let Some(w) = &state.weights {
            if w.len() != p.weights.len() {
                return Err(refuse(format!(
                    "{} weights for {} triangles",
                    w.len(),
                    p.weights.len()
                )));
            }
            if !w.iter().all(|w| (MIN_WEIGHT..=MAX_WEIGHT).contains(w)) {
                return Err(refuse(format!(
                    "weights must be {MIN_WEIGHT} to {MAX_WEIGHT}"
                )));
            }
        }
        let mut pins = Vec::new();
        for pin in state.pins.iter().flatten() {
            let grip = p
                .grip_of(pin.grip)
                .ok_or_else(|| refuse(format!("pin {}: not a grip of this puppet", pin.handle)))?;
            if !(pin.at.is_finite() && pin.offset.is_finite()) {
                return Err(refuse(format!("pin {}: not a finite point", pin.handle)));
            }
            pins.push((pin, grip));
        }
        if state.pose.is_some() && !matches!(p.rig, Rig::Skeleton(_) | Rig::Curve(_)) {
            return Err(refuse(
                "a pose, but the puppet has no skeleton or curve".into(),
            ));
        }
        let index = puppet as usize;
        if let Some(pose) = &state.pose
            && let Rig::Curve(r) = &mut self.puppets[index].rig
        {
            r.set_pose(&pose.joints)
                .map_err(|e| refuse(e.to_string()))?;
            self.puppets[index].moved = true;
        } else if let Some(pose) = &state.pose {
            let p = &mut self.puppets[index];
            let Rig::Skeleton(r) = &mut p.rig else {
                unreachable!("checked above")
            };
            let fk = puppetry_deform::skeleton::Pose {
                roots: pose.roots.clone(),
                angles: pose.angles.clone(),
                lengths: pose.lengths.clone(),
            };
            r.restore_pose(fk, pose.joints.clone())
                .map_err(|e| refuse(e.to_string()))?;
            p.key_pose = pose.key.clone();
            p.pose_generation += 1;
            p.moved = true;
        }
        if state.pins.is_some() {
            let keep: Vec<u64> = pins.iter().map(|(pin, _)| pin.handle).collect();
            let gone: Vec<u64> = self.puppets[index]
                .handles
                .iter()
                .filter(|h| h.kind == HandleKind::Pin && !keep.contains(&h.id))
                .map(|h| h.id)
                .collect();
            for id in gone {
                self.remove_handle(index, id);
            }
            for (pin, grip) in pins {
                if self.puppets[index]
                    .handles
                    .iter()
                    .any(|h| h.id == pin.handle)
                {
                    continue;
                }
                let owner = match pin.owner.as_str() {
                    crate::CONFIG_OWNER => Owner::Config,
                    other => Owner::Source(other.to_string()),
                };
                let new = NewHandle {
                    owner,
                    kind: HandleKind::Pin,
                    grip,
                    at: pin.at,
                    offset: pin.offset,
                    contact: None,
                };
                self.insert_handle(index, pin.handle, new);
            }
        }
        if let Some(layers) = &state.layers {
            let p = &mut self.puppets[index];
            if p.depth.is_none() || layers.len() != p.mesh.triangles().len() {
                return Err(refuse(format!(
                    "{} depth layers for {} triangles (or depth is off)",
                    layers.len(),
                    p.mesh.triangles().len()
                )));
            }
            if p.static_layers().as_ref() != Some(layers) {
                p.set_layers(layers.clone()).map_err(refuse)?;
            }
        }
        if let Some(w) = &state.weights {
            let p = &mut self.puppets[index];
            if *w != p.weights {
                p.weights.clone_from(w);
                return Ok(self.weights_changed(puppet));
            }
        }
        Ok(None)
    }
}
