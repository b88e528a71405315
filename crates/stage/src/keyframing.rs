//! Keyframing on the stage: key poses added, moved and saved, a puppet's
//! cursor moved by a client or a pad, and the blend of key poses at the
//! cursor driven into the rig each frame.

use super::*;

impl Stage {
    /// Moves (or lets go, `None`) a puppet's keyframing cursor, in pad
    /// coordinates.
    pub fn set_cursor(&mut self, puppet: u32, at: Option<DVec2>) -> Result<(), CommandError> {
        if let Some(at) = at
            && !at.is_finite()
        {
            return Err(CommandError::BadPadPoint { x: at.x, y: at.y });
        }
        let at = at.map(|a| a.clamp(DVec2::ZERO, DVec2::ONE));
        let k = &mut self.puppet_mut(puppet)?.keying;
        if k.cursor != at {
            k.cursor = at;
            k.touch();
        }
        Ok(())
    }

    /// Adds a key pose of the puppet as it is now at pad point `at`; the
    /// first key of a puppet keys what its contacts hold (or its
    /// skeleton). Returns the key's index.
    pub fn add_key(&mut self, puppet: u32, name: String, at: DVec2) -> Result<usize, CommandError> {
        let p = self.puppet(puppet)?;
        let held: Vec<(Grip, DVec2)> = p
            .handles
            .iter()
            // Pins stay where they are: keys hold what hands hold.
            .filter(|h| h.kind == HandleKind::Contact)
            .filter_map(|h| match h.grip {
                Grip::Point(anchor) => Some((h.grip, anchor_position(&p.mesh, anchor))),
                Grip::GridHandle(i) => Some((h.grip, p.rig.grip_position(Grip::GridHandle(i))?)),
                Grip::Joint(_) | Grip::Bone { .. } => None,
            })
            .collect();
        let now: Vec<Option<DVec2>> = p
            .keying
            .targets
            .iter()
            .chain(&held)
            .map(|&(grip, _)| {
                // Where a hand holds it, what the hand asked for; else where
                // the solve put it.
                let rest = |g: Grip| match g {
                    Grip::Point(a) => Some(anchor_position(&p.mesh, a)),
                    _ => None,
                };
                p.handles
                    .iter()
                    .find(|h| {
                        h.kind != HandleKind::Key
                            && (h.grip == grip
                                || rest(h.grip)
                                    .zip(rest(grip))
                                    .is_some_and(|(a, b)| a.distance(b) < 1e-9))
                    })
                    .map(|h| h.rig_target())
                    .or_else(|| p.grip_now(grip))
            })
            .collect();
        let targets_before = p.keying.targets.clone();
        let placement = p.placement;
        let p = &mut self.puppets[puppet as usize];
        let lookup = |grip: Grip| {
            targets_before
                .iter()
                .chain(&held)
                .position(|&(g, _)| g == grip)
                .and_then(|i| now[i])
        };
        p.keying
            .add_key(name, at, &p.rig, &held, placement, lookup)
            .map_err(|source| CommandError::Keys { puppet, source })
    }

    /// The key file to write for a puppet (`save_keys`): where, and what.
    pub fn key_file(&self, puppet: u32) -> Result<(PathBuf, keys::KeyFile), CommandError> {
        let p = self.puppet(puppet)?;
        let file = p
            .keying
            .file
            .clone()
            .ok_or(CommandError::NoKeyFile { puppet })?;
        Ok((file, p.keying.key_file(&p.name, &p.rig, p.placement)))
    }

    /// Puts each keyed puppet's handles where its cursor's blend of key
    /// poses says, adding or removing key handles as fingers take keyed
    /// grips over or let go.
    pub(crate) fn drive_keys(&mut self) {
        let radius = self.grab_radius();
        for index in 0..self.puppets.len() {
            let p = &self.puppets[index];
            let k = &p.keying;
            if p.removed {
                continue;
            }
            if !(k.dirty || (p.handles_changed && !k.targets.is_empty())) {
                continue;
            }
            let wanted = k.cursor.is_some() && k.set.as_ref().is_some_and(|s| !s.is_empty());
            if k.skeleton {
                let p = &mut self.puppets[index];
                let k = &mut p.keying;
                k.dirty = false;
                if let (true, Some(set), Some(cursor)) = (wanted, k.set.as_mut(), k.cursor) {
                    k.blended.resize(set.width(), 0.0);
                    if set.blend_into(cursor, &mut k.blended)
                        && let Some(pose) = pad::skeleton_pose(&p.rig, &k.blended)
                        && let Rig::Skeleton(r) = &mut p.rig
                        && r.set_pose(pose).is_ok()
                    {
                        p.moved = true;
                    }
                }
                continue;
            }
            // A finger on or near a keyed grip takes it over.
            let taken: Vec<bool> = k
                .targets
                .iter()
                .map(|&(grip, rest)| {
                    p.handles.iter().any(|h| {
                        h.kind != HandleKind::Key
                            && match (h.grip, grip) {
                                (Grip::Point(a), Grip::Point(_)) => {
                                    anchor_position(&p.mesh, a).distance(rest) <= radius
                                }
                                (a, b) => a == b,
                            }
                    })
                })
                .collect();
            let mut plan = Vec::new();
            for (i, &(grip, _)) in k.targets.iter().enumerate() {
                let want = wanted && !taken[i];
                match (k.handles[i], want) {
                    (Some(id), false) => plan.push((i, Some(id), None)),
                    (None, true) => plan.push((i, None, Some(grip))),
                    _ => {}
                }
            }
            for (i, remove, add) in plan {
                if let Some(id) = remove {
                    self.remove_handle(index, id);
                    self.puppets[index].keying.handles[i] = None;
                }
                if let Some(grip) = add {
                    let new = NewHandle {
                        owner: Owner::Source(crate::KEYS_OWNER.into()),
                        kind: HandleKind::Key,
                        grip,
                        at: self.puppets[index].grip_now(grip).unwrap_or_default(),
                        offset: DVec2::ZERO,
                        contact: None,
                    };
                    let id = self.add_handle(index, new);
                    self.puppets[index].keying.handles[i] = Some(id);
                }
            }
            let p = &mut self.puppets[index];
            let k = &mut p.keying;
            k.dirty = false;
            if let (true, Some(set), Some(cursor)) = (wanted, k.set.as_mut(), k.cursor) {
                k.blended.resize(set.width(), 0.0);
                if set.blend_into(cursor, &mut k.blended) {
                    for (i, id) in k.handles.iter().enumerate() {
                        let Some(id) = id else { continue };
                        let target = DVec2::new(k.blended[2 * i], k.blended[2 * i + 1]);
                        if let Some(h) = p.handles.iter_mut().find(|h| h.id == *id)
                            && h.target != target
                        {
                            h.target = target;
                            p.moved = true;
                        }
                    }
                }
            }
        }
    }

    /// Sets a skeleton puppet to the pose `t` of the way from key pose
    /// `from` to key pose `to`.
    pub fn set_key_pose(
        &mut self,
        puppet: u32,
        from: &str,
        to: &str,
        t: f64,
    ) -> Result<(), CommandError> {
        let p = self.puppet_mut(puppet)?;
        let Rig::Skeleton(r) = &mut p.rig else {
            return Err(CommandError::NoSkeleton { puppet });
        };
        r.set_key_pose(from, to, t)
            .map_err(|source| CommandError::Rig { puppet, source })?;
        p.moved = true;
        p.key_pose = Some(KeyPoseState {
            from: from.to_string(),
            to: to.to_string(),
            t,
        });
        p.pose_generation += 1;
        Ok(())
    }

    pub(crate) fn move_cursor(&mut self, pad: usize, at: DVec2) {
        let pad = &self.pads[pad];
        let cursor = pad.cursor(at);
        let k = &mut self.puppets[pad.puppet].keying;
        if k.cursor != Some(cursor) {
            k.cursor = Some(cursor);
            k.touch();
        }
    }
}
