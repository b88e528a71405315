//! One puppet on the stage: loading it from its stage file entry (picture,
//! mesh or curve, rig, weights, depth, keys), what it shows (pose, handles,
//! weights, depth layers) and the geometry of grabbing it (hit tests and
//! reach, a grip's point now), and the records its undo history keeps.

use super::*;

impl Puppet {
    /// Loads the puppet `p` of the stage file `config` (its `index`-th):
    /// mesh, placement, rig and key poses; pins are the stage's to add.
    /// Pure work over files, so a running stage can have it done off its
    /// thread before [`Stage::add_puppet`].
    pub fn load(
        config: &StageConfig,
        index: usize,
        p: &PuppetConfig,
    ) -> Result<Puppet, StageError> {
        let rig_error = |(field, problem): (String, String)| StageError::Rig {
            file: config.file.clone(),
            index,
            puppet: p.name.clone(),
            field,
            problem,
        };
        let (mesh_file, mesh, picture) = match &p.curve {
            Some(c) => {
                let source = format!("{} puppet[{index}].curve", config.file);
                let mesh = curve_rest_mesh(&source, c).map_err(rig_error)?;
                let picture = if p.image.as_os_str().is_empty() {
                    Picture::Stroke(c.rgb())
                } else {
                    Picture::File(config.resolve(&p.image))
                };
                (PathBuf::new(), mesh, picture)
            }
            None => {
                let mesh_file = config.resolve(&p.mesh);
                let mesh = Mesh::load(&mesh_file)?;
                (mesh_file, mesh, Picture::File(config.resolve(&p.image)))
            }
        };
        let placed = place(&mesh, p.at.into(), p.scale)?;
        let rig = Rig::from_config(
            &mesh,
            &placed,
            p.at.into(),
            p.scale,
            p.grid.as_ref(),
            p.skeleton.as_ref(),
            p.curve.as_ref(),
        )
        .map_err(rig_error)?;
        let (lo, hi) = bounds(mesh.vertices());
        let placement = pad::Placement {
            at: p.at.into(),
            scale: p.scale,
            centre: (lo + hi) / 2.0,
        };
        let mut puppet = Puppet {
            placement,
            keying: pad::Keying::empty(None),
            id: index as u32,
            name: p.name.clone(),
            picture,
            weights: placed.weights().to_vec(),
            mesh: placed,
            mesh_file,
            source_mesh: mesh,
            weights_generation: 0,
            rig,
            handles: Vec::new(),
            handles_changed: false,
            moved: false,
            weights_pending: false,
            handles_generation: 0,
            history: History::default(),
            loaded: Snapshot::default(),
            key_pose: None,
            pose_generation: 0,
            save_weights: p.save_weights,
            removed: false,
            depth: None,
            depth_generation: 0,
            layers: None,
        };
        if p.depth == config::DepthMode::Pieces {
            // Registered on the mesh as placed, so "moved further from rest"
            // (which side of a fold goes in front) measures the bend, not
            // where the puppet stands.
            puppet.layers = puppet.mesh.layers().map(|l| l.to_vec());
            let order = puppetry_deform::depth::DepthOrder::register(
                &puppet.mesh,
                puppet.layers.as_deref(),
            )
            .map_err(|e| StageError::Rig {
                file: config.file.clone(),
                index,
                puppet: p.name.clone(),
                field: "depth".into(),
                problem: e.to_string(),
            })?;
            puppet.depth = Some(order);
        }
        if let Some(keys) = &p.keys {
            let file = config.resolve(keys);
            if file.exists() {
                let key_file = keys::KeyFile::load(&file)?;
                puppet.keying = pad::Keying::load(
                    file.clone(),
                    key_file,
                    &p.name,
                    &puppet.rig,
                    puppet.placement,
                    |at| puppet.hit(at),
                )
                .map_err(|(field, problem)| StageError::Keys {
                    file: file.display().to_string(),
                    field,
                    problem,
                })?;
            } else {
                puppet.keying = pad::Keying::empty(Some(file));
            }
        }
        Ok(puppet)
    }

    /// The depth of each triangle (larger is nearer) and its generation,
    /// which changes only when a depth does; `None` with `depth = "off"`.
    pub fn depth(&self) -> Option<(&[u16], u32)> {
        self.depth
            .as_ref()
            .map(|d| (d.depth(), self.depth_generation))
    }

    /// Taken off the stage at runtime ([`Stage::remove_puppet`]).
    pub fn removed(&self) -> bool {
        self.removed
    }

    /// The handles on it now (contacts, pins, key handles), oldest first:
    /// the order [`Puppet::handle_points`] reports them in.
    pub fn handles(&self) -> &[Handle] {
        &self.handles
    }

    /// Spatial keyframing: key poses and the cursor.
    pub fn keying(&self) -> &pad::Keying {
        &self.keying
    }

    /// Where an anchor is in the current pose.
    pub(crate) fn posed(&self, anchor: Anchor) -> DVec2 {
        let pose = self.pose();
        match anchor {
            Anchor::Vertex(i) => pose[i as usize],
            Anchor::Point { triangle, bary } => {
                let tri = self.mesh.triangles()[triangle as usize];
                (0..3).map(|k| pose[tri[k] as usize] * bary[k]).sum()
            }
        }
    }

    /// Each handle's point on the puppet now, in handle order: a material
    /// point where the solve put it; a grid handle, joint or bone point
    /// less the offset it was grabbed with (where the finger holds it).
    pub fn handle_points(&self, out: &mut Vec<DVec2>) {
        out.clear();
        out.extend(self.handles.iter().map(|h| {
            match h.grip {
                Grip::Point(anchor) => self.posed(anchor),
                grip => self
                    .rig
                    .grip_position(grip)
                    .map_or(h.target, |q| q - h.offset),
            }
        }));
    }

    /// Bumped whenever the handle set changes.
    pub fn handles_generation(&self) -> u32 {
        self.handles_generation
    }

    /// Undo and redo steps available.
    pub fn history(&self) -> (usize, usize) {
        (self.history.undo.len(), self.history.redo.len())
    }

    /// The key-pose blend a `pose` request last set (none at rest), and a
    /// counter bumped whenever it is set.
    pub fn key_pose(&self) -> (Option<&KeyPoseState>, u64) {
        (self.key_pose.as_ref(), self.pose_generation)
    }

    /// The pins now, exactly.
    pub(crate) fn pin_records(&self) -> Vec<PinRecord> {
        self.handles
            .iter()
            .filter(|h| h.kind == HandleKind::Pin)
            .map(|h| PinRecord {
                handle: h.id,
                owner: h.owner.to_string(),
                grip: grip_record(h.grip),
                at: h.target,
                offset: h.offset,
            })
            .collect()
    }

    /// The skeleton's pose now (none for other rigs).
    pub(crate) fn pose_record(&self) -> Option<PoseRecord> {
        if let Rig::Curve(r) = &self.rig {
            return Some(PoseRecord {
                roots: Vec::new(),
                angles: Vec::new(),
                lengths: Vec::new(),
                joints: r.curve().pose().to_vec(),
                key: None,
            });
        }
        let Rig::Skeleton(r) = &self.rig else {
            return None;
        };
        let (pose, joints) = r.pose_state();
        Some(PoseRecord {
            roots: pose.roots,
            angles: pose.angles,
            lengths: pose.lengths,
            joints,
            key: self.key_pose.clone(),
        })
    }

    /// The state now of the parts `like` holds.
    pub(crate) fn capture(&self, like: &Snapshot) -> Snapshot {
        Snapshot {
            weights: like.weights.as_ref().map(|_| self.weights.clone()),
            pins: like.pins.as_ref().map(|_| self.pin_records()),
            pose: like.pose.as_ref().and_then(|_| self.pose_record()),
            layers: like.layers.as_ref().and_then(|_| self.static_layers()),
        }
    }

    /// The static depth layers now: as painted, else the pieces' order
    /// (none with `depth = "off"`).
    pub fn static_layers(&self) -> Option<Vec<u16>> {
        let depth = self.depth.as_ref()?;
        Some(
            self.layers
                .clone()
                .unwrap_or_else(|| depth.static_depth().to_vec()),
        )
    }

    /// Takes `layers` as the static depth order (painted or put back),
    /// starting the adjustment afresh from it; depth flips stay.
    pub(crate) fn set_layers(&mut self, layers: Vec<u16>) -> Result<(), String> {
        let order = match &self.depth {
            Some(old) => old.with_layers(&self.mesh, &layers),
            None => puppetry_deform::depth::DepthOrder::register(&self.mesh, Some(&layers)),
        }
        .map_err(|e| e.to_string())?;
        self.depth = Some(order);
        self.layers = Some(layers);
        self.depth_generation = self.depth_generation.wrapping_add(1);
        self.moved = true;
        Ok(())
    }

    /// A recorded grip as a grip of this puppet, if it fits its mesh and
    /// rig.
    pub(crate) fn grip_of(&self, record: GripRecord) -> Option<Grip> {
        let rig_points = self.rig.points().map_or(0, |p| p.len());
        let grip = match record {
            GripRecord::Vertex { index } => ((index as usize) < self.mesh.vertices().len())
                .then_some(Grip::Point(Anchor::Vertex(index)))?,
            GripRecord::Point { triangle, bary } => ((triangle as usize)
                < self.mesh.triangles().len()
                && bary.iter().all(|b| b.is_finite()))
            .then_some(Grip::Point(Anchor::Point { triangle, bary }))?,
            GripRecord::Grid { index } => (matches!(self.rig, Rig::Grid(_)) && index < rig_points)
                .then_some(Grip::GridHandle(index))?,
            GripRecord::Joint { index } => (matches!(self.rig, Rig::Skeleton(_))
                && index < rig_points)
                .then_some(Grip::Joint(index))?,
            GripRecord::Bone {
                index,
                along,
                across,
            } => {
                let Rig::Skeleton(r) = &self.rig else {
                    return None;
                };
                (index < r.deformer().skeleton().bones().len()
                    && along.is_finite()
                    && across.is_finite())
                .then_some(Grip::Bone {
                    index,
                    along,
                    across,
                })?
            }
        };
        Some(grip)
    }

    /// Where an anchor is in the current pose.
    pub(crate) fn grip_now(&self, grip: Grip) -> Option<DVec2> {
        match grip {
            Grip::Point(anchor) => Some(self.posed(anchor)),
            other => self.rig.grip_position(other),
        }
    }

    /// The deformer that drives it, with its own points to draw (grid
    /// handles, joints).
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The deformed vertices (stage coordinates, rest order).
    pub fn pose(&self) -> &[DVec2] {
        self.rig.pose()
    }

    /// The per-triangle weights now, painted ones included.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Bumped by every paint dab that changed a weight.
    pub fn weights_generation(&self) -> u64 {
        self.weights_generation
    }

    /// The triangle of the current pose under `p` and `p`'s barycentric
    /// coordinates there: what a finger landing at `p` touches. A point on
    /// the outline (a boundary vertex or edge) is on the puppet.
    pub fn hit(&self, p: DVec2) -> Option<Anchor> {
        self.hit_within(p, 0.0).map(|(anchor, _)| anchor)
    }

    /// As [`Puppet::hit`], and when nothing is under `p`, the point of the
    /// puppet nearest `p` if it is within `reach` (stage units): the anchor
    /// and where it is now. A contact's position is where the middle of a
    /// finger is, or a vertex streamed as f32 and sent back: either can
    /// land a hair outside the outline it is on.
    pub fn hit_within(&self, p: DVec2, reach: f64) -> Option<(Anchor, DVec2)> {
        let pose = self.pose();
        let mut inside: Option<(u16, f64, u32, [f64; 3])> = None;
        let mut nearest: Option<(f64, u16, u32, DVec2)> = None;
        for (t, tri) in self.mesh.triangles().iter().enumerate() {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            // The box test must not be stricter than the tests below: an
            // exact one dropped points on the outline that round-off in
            // the pose put a hair outside (issue 31).
            let slack = reach + ON_OUTLINE * (a.distance(b) + b.distance(c) + c.distance(a));
            let lo = a.min(b).min(c) - DVec2::splat(slack);
            let hi = a.max(b).max(c) + DVec2::splat(slack);
            if p.x < lo.x || p.y < lo.y || p.x > hi.x || p.y > hi.y {
                continue;
            }
            // Deformed meshes may fold over: the part drawn in front is the
            // one under the finger; then the triangle containing the point
            // most deeply.
            let near = self.depth.as_ref().map_or(0, |d| d.depth()[t]);
            let bary = barycentric_in(a, b, c, p);
            if !bary.iter().all(|b| b.is_finite()) {
                // Collapsed to a segment in this pose: its neighbours,
                // which share its edges, are hit instead.
                continue;
            }
            let worst = bary[0].min(bary[1]).min(bary[2]);
            if worst >= 0.0 {
                if inside.is_none_or(|(n, w, _, _)| (near, worst) > (n, w)) {
                    inside = Some((near, worst, t as u32, bary));
                }
                continue;
            }
            // Outside this triangle: how far, in stage units (barycentric
            // coordinates are no distance: a thin triangle's grow fast).
            let q = [(a, b), (b, c), (c, a)]
                .map(|(u, v)| closest_on_segment(u, v, p))
                .into_iter()
                .min_by(|x, y| x.distance_squared(p).total_cmp(&y.distance_squared(p)))
                .unwrap_or(a);
            let d = q.distance(p);
            let on = ON_OUTLINE * (a.distance(b) + b.distance(c) + c.distance(a));
            if d <= reach.max(on)
                && nearest.is_none_or(|(nd, n, _, _)| {
                    (d, std::cmp::Reverse(near)) < (nd, std::cmp::Reverse(n))
                })
            {
                nearest = Some((d, near, t as u32, q));
            }
        }
        let anchor = |triangle: u32, bary: [f64; 3]| {
            let clamped = bary.map(|b| b.max(0.0));
            let sum: f64 = clamped.iter().sum();
            Anchor::Point {
                triangle,
                bary: clamped.map(|b| b / sum),
            }
        };
        if let Some((_, _, triangle, bary)) = inside {
            return Some((anchor(triangle, bary), p));
        }
        let (_, _, triangle, q) = nearest?;
        let [a, b, c] = self.mesh.triangles()[triangle as usize].map(|i| pose[i as usize]);
        let found = anchor(triangle, barycentric_in(a, b, c, q));
        Some((found, self.posed(found)))
    }

    /// How events name a grip: a material point by its rest position.
    pub(crate) fn grip_event(&self, grip: Grip) -> GripEvent {
        match grip {
            Grip::Point(anchor) => GripEvent::Point {
                rest: anchor_position(&self.mesh, anchor),
            },
            Grip::GridHandle(index) => GripEvent::Grid { index },
            Grip::Joint(index) => GripEvent::Joint { index },
            Grip::Bone {
                index,
                along,
                across,
            } => GripEvent::Bone {
                index,
                along,
                across,
            },
        }
    }

    /// A grid handle or joint near `p` first, then the material point.
    /// What a contact at `p` grabs of this puppet: a grid handle or joint
    /// within `radius`, else the point under it, or (with `outline` > 0)
    /// the nearest point within `outline` outside it, held where it is.
    pub(crate) fn reach(&self, p: DVec2, radius: f64, outline: f64) -> Reach {
        if let Some(grip) = self.rig.point_near(p, radius) {
            let at = self.rig.grip_position(grip).unwrap_or(p);
            return Reach::Grip(grip, at - p);
        }
        match self.hit_within(p, outline) {
            Some((anchor, at)) if self.rig.takes_points() => {
                Reach::Grip(Grip::Point(anchor), at - p)
            }
            // A skeleton is held by its bones: the nearest one, at the
            // point under the finger.
            Some(_) => match self.rig.bone_near(p) {
                Some(grip) => Reach::Grip(grip, DVec2::ZERO),
                None => Reach::Blocked,
            },
            None => Reach::Miss,
        }
    }

    /// Multiplies the weights of the triangles whose deformed centroid lies
    /// within `radius` of `at` by `strength` raised to the brush's falloff
    /// (1 at the centre, 0 at the rim), clamped to the mesh's weight range.
    /// Returns whether any weight changed.
    pub(crate) fn paint(&mut self, at: DVec2, radius: f64, strength: f64) -> bool {
        let pose = self.rig.pose();
        let mut changed = false;
        for (tri, w) in self.mesh.triangles().iter().zip(&mut self.weights) {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            let d = ((a + b + c) / 3.0).distance(at);
            if d >= radius {
                continue;
            }
            let painted = (*w * strength.powf(1.0 - d / radius)).clamp(MIN_WEIGHT, MAX_WEIGHT);
            if painted != *w {
                *w = painted;
                changed = true;
            }
        }
        changed
    }
}
