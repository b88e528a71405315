//! The stage: puppets placed in stage coordinates, and the mapping from
//! touch contacts to handles on them. A contact that lands on a puppet grabs
//! the material point under it (a point handle in the triangle it touched,
//! topmost puppet first); moving the contact drags that point; lifting it
//! lets go. Pins are handles that stay. Every handle knows its owner, so
//! contacts from different devices and clients never get confused.
//!
//! Plain synchronous state; [`thread`] runs it, with the solver, on a thread
//! of its own.

pub mod config;
pub mod thread;

use std::collections::HashMap;
use std::path::PathBuf;

use glam::DVec2;

use crate::deform::{Anchor, Arap, ArapError, Steps};
use crate::input::{ContactFrame, Phase};
use crate::mesh::{Mesh, MeshError};
use config::StageConfig;

#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("puppet {puppet}: {source}")]
    Solver { puppet: String, source: ArapError },
    #[error("puppet {puppet}: pin {index} at [{x}, {y}] is not on the puppet")]
    PinOutside {
        puppet: String,
        index: usize,
        x: f64,
        y: f64,
    },
    #[error("puppet {puppet}: image {path}: {problem}")]
    Image {
        puppet: String,
        path: String,
        problem: String,
    },
}

/// Who holds a handle.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Owner {
    /// An input source (a device, a replay, a performer's browser), by id.
    Source(String),
    /// The stage file.
    Config,
}

impl std::fmt::Display for Owner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Owner::Source(id) => f.write_str(id),
            Owner::Config => f.write_str("config"),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HandleKind {
    Contact,
    Pin,
}

/// A handle on a puppet.
#[derive(Debug, Clone)]
pub struct Handle {
    pub id: u64,
    pub owner: Owner,
    pub kind: HandleKind,
    pub anchor: Anchor,
    /// Where the handle is held now (stage coordinates).
    pub target: DVec2,
}

/// A puppet on the stage, with its solver.
pub struct Puppet {
    pub id: u32,
    pub name: String,
    pub image: PathBuf,
    /// The rest mesh, placed on the stage.
    pub mesh: Mesh,
    arap: Arap,
    handles: Vec<Handle>,
    /// The handle set changed since the last solve (recompile needed).
    handles_changed: bool,
    /// Some handle moved since the last solve.
    moved: bool,
    /// Scratch for the solver's targets, in handle order.
    targets: Vec<DVec2>,
}

impl Puppet {
    pub fn handles(&self) -> &[Handle] {
        &self.handles
    }

    /// The deformed vertices (stage coordinates, rest order).
    pub fn pose(&self) -> &[DVec2] {
        self.arap.pose()
    }

    /// The triangle of the current pose under `p` and `p`'s barycentric
    /// coordinates there: what a finger landing at `p` touches.
    pub fn hit(&self, p: DVec2) -> Option<Anchor> {
        let pose = self.arap.pose();
        let mut best: Option<(f64, u32, [f64; 3])> = None;
        for (t, tri) in self.mesh.triangles().iter().enumerate() {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            let lo = a.min(b).min(c);
            let hi = a.max(b).max(c);
            if p.x < lo.x || p.y < lo.y || p.x > hi.x || p.y > hi.y {
                continue;
            }
            let bary = barycentric_in(a, b, c, p);
            let worst = bary[0].min(bary[1]).min(bary[2]);
            // Deformed meshes may fold over: prefer the triangle containing
            // the point most deeply.
            if worst >= -1e-9 && best.is_none_or(|(w, _, _)| worst > w) {
                best = Some((worst, t as u32, bary));
            }
        }
        best.map(|(_, triangle, bary)| {
            let clamped = bary.map(|b| b.max(0.0));
            let sum: f64 = clamped.iter().sum();
            Anchor::Point {
                triangle,
                bary: clamped.map(|b| b / sum),
            }
        })
    }
}

fn barycentric_in(a: DVec2, b: DVec2, c: DVec2, p: DVec2) -> [f64; 3] {
    let d = (b - a).perp_dot(c - a);
    let l1 = (p - a).perp_dot(c - a) / d;
    let l2 = (b - a).perp_dot(p - a) / d;
    [1.0 - l1 - l2, l1, l2]
}

/// All puppets and the contacts holding them.
pub struct Stage {
    pub width: f64,
    pub height: f64,
    puppets: Vec<Puppet>,
    /// (source, contact id) → (puppet, handle id) for contacts that grabbed
    /// something; contacts on empty stage are absent.
    grabs: HashMap<(String, u32), (usize, u64)>,
    next_handle: u64,
}

impl Stage {
    /// Loads every puppet of the stage file, places it and sets its pins.
    pub fn from_config(config: &StageConfig) -> Result<Stage, StageError> {
        let mut stage = Stage {
            width: config.stage.width,
            height: config.stage.height,
            puppets: Vec::new(),
            grabs: HashMap::new(),
            next_handle: 1,
        };
        for (id, p) in config.puppets.iter().enumerate() {
            let mesh = Mesh::load(&config.resolve(&p.mesh))?;
            let placed = place(&mesh, p.at.into(), p.scale)?;
            let arap = Arap::register(&placed).map_err(|source| StageError::Solver {
                puppet: p.name.clone(),
                source,
            })?;
            stage.puppets.push(Puppet {
                id: id as u32,
                name: p.name.clone(),
                image: config.resolve(&p.image),
                mesh: placed,
                arap,
                handles: Vec::new(),
                handles_changed: false,
                moved: false,
                targets: Vec::new(),
            });
            for (index, pin) in p.pins.iter().enumerate() {
                let at = stage_point(&mesh, p.at.into(), p.scale, DVec2::from(*pin));
                if stage.pin_on(id, Owner::Config, at).is_none() {
                    return Err(StageError::PinOutside {
                        puppet: p.name.clone(),
                        index,
                        x: pin[0],
                        y: pin[1],
                    });
                }
            }
        }
        Ok(stage)
    }

    pub fn puppets(&self) -> &[Puppet] {
        &self.puppets
    }

    /// Applies one input frame: contacts land, move and lift.
    pub fn apply(&mut self, frame: &ContactFrame) {
        let source = frame.source.to_string();
        for contact in &frame.contacts {
            let key = (source.clone(), contact.id);
            match contact.phase {
                Phase::Down => {
                    // A repeated down without an up: the old grab ends first.
                    self.release(&key);
                    if let Some(grab) = self.grab(Owner::Source(source.clone()), contact.position) {
                        self.grabs.insert(key, grab);
                    }
                }
                Phase::Move => {
                    if let Some(&(puppet, handle)) = self.grabs.get(&key) {
                        let puppet = &mut self.puppets[puppet];
                        if let Some(h) = puppet
                            .handles
                            .iter_mut()
                            .find(|h| h.id == handle && h.target != contact.position)
                        {
                            h.target = contact.position;
                            puppet.moved = true;
                        }
                    }
                }
                Phase::Up => self.release(&key),
            }
        }
    }

    /// Lifts every contact of a source (it disconnected or vanished).
    pub fn release_source(&mut self, source: &str) {
        let keys: Vec<_> = self
            .grabs
            .keys()
            .filter(|k| k.0 == source)
            .cloned()
            .collect();
        for key in keys {
            self.release(&key);
        }
    }

    fn release(&mut self, key: &(String, u32)) {
        if let Some((puppet, handle)) = self.grabs.remove(key) {
            self.remove_handle(puppet, handle);
        }
    }

    fn remove_handle(&mut self, puppet: usize, handle: u64) -> bool {
        let p = &mut self.puppets[puppet];
        let before = p.handles.len();
        p.handles.retain(|h| h.id != handle);
        let removed = p.handles.len() != before;
        p.handles_changed |= removed;
        removed
    }

    /// A new contact handle at `at` on the topmost puppet there.
    fn grab(&mut self, owner: Owner, at: DVec2) -> Option<(usize, u64)> {
        let puppet = (0..self.puppets.len())
            .rev()
            .find(|&i| self.puppets[i].hit(at).is_some())?;
        let id = self.add_handle(puppet, owner, HandleKind::Contact, at)?;
        Some((puppet, id))
    }

    fn add_handle(
        &mut self,
        puppet: usize,
        owner: Owner,
        kind: HandleKind,
        at: DVec2,
    ) -> Option<u64> {
        let anchor = self.puppets[puppet].hit(at)?;
        let id = self.next_handle;
        self.next_handle += 1;
        let p = &mut self.puppets[puppet];
        p.handles.push(Handle {
            id,
            owner,
            kind,
            anchor,
            target: at,
        });
        p.handles_changed = true;
        Some(id)
    }

    /// Pins the topmost puppet under `at`; returns (puppet, handle id).
    pub fn pin(&mut self, owner: Owner, at: DVec2) -> Option<(u32, u64)> {
        let puppet = (0..self.puppets.len())
            .rev()
            .find(|&i| self.puppets[i].hit(at).is_some())?;
        self.pin_on(puppet, owner, at).map(|id| (puppet as u32, id))
    }

    fn pin_on(&mut self, puppet: usize, owner: Owner, at: DVec2) -> Option<u64> {
        self.add_handle(puppet, owner, HandleKind::Pin, at)
    }

    /// Removes a pin; contacts cannot be unpinned.
    pub fn unpin(&mut self, puppet: u32, handle: u64) -> bool {
        let Some(p) = self.puppets.get(puppet as usize) else {
            return false;
        };
        if !p
            .handles
            .iter()
            .any(|h| h.id == handle && h.kind == HandleKind::Pin)
        {
            return false;
        }
        self.remove_handle(puppet as usize, handle)
    }

    /// Solves every puppet whose handles changed or moved; returns, per
    /// solved puppet, whether its handle set changed.
    pub fn solve(&mut self) -> Vec<(u32, bool)> {
        let mut solved = Vec::new();
        for p in &mut self.puppets {
            if !(p.handles_changed || p.moved) {
                continue;
            }
            if p.handles_changed {
                let anchors: Vec<Anchor> = p.handles.iter().map(|h| h.anchor).collect();
                // Anchors come from hit tests on this mesh, so they are valid.
                p.arap
                    .compile(&anchors)
                    .expect("anchors from hit tests are valid");
            }
            p.targets.clear();
            p.targets.extend(p.handles.iter().map(|h| h.target));
            if p.arap.update(&p.targets, Steps::Both).is_err() {
                // Only a non-finite target can fail here; keep the last pose.
                tracing::warn!(puppet = %p.name, "ignored a frame with a non-finite target");
            }
            solved.push((p.id, p.handles_changed));
            p.handles_changed = false;
            p.moved = false;
        }
        solved
    }
}

/// A mesh point in stage coordinates: scaled about the mesh's bounding-box
/// centre, which lands at `at`.
fn stage_point(mesh: &Mesh, at: DVec2, scale: f64, p: DVec2) -> DVec2 {
    let (lo, hi) = bounds(mesh.vertices());
    at + (p - (lo + hi) / 2.0) * scale
}

fn bounds(points: &[DVec2]) -> (DVec2, DVec2) {
    points.iter().fold(
        (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    )
}

/// The mesh moved onto the stage (same triangles, uv and weights).
fn place(mesh: &Mesh, at: DVec2, scale: f64) -> Result<Mesh, MeshError> {
    let vertices = mesh
        .vertices()
        .iter()
        .map(|&p| stage_point(mesh, at, scale, p))
        .collect();
    Mesh::new(
        "placed mesh",
        vertices,
        mesh.triangles().to_vec(),
        mesh.uv().map(|uv| uv.to_vec()),
        Some(mesh.weights().to_vec()),
    )
}
