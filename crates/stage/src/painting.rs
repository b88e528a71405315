//! Painting on a puppet: the stiffness brush (weights the solver reads,
//! a rebuild when they change) and the depth-layer brush, checked before
//! anything is touched and grouped by stroke for undo.

use super::*;

/// The stroke a dab belongs to: its painter's own number for it (each
/// page counts its strokes from 1) and, when known, who the painter is.
/// A stroke's dabs are one undo step; two painters' strokes never are.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Stroke {
    /// Who painted (a client's source); none for a change recorded before
    /// painters were kept, or made without one.
    pub painter: Option<String>,
    /// The painter's number for the stroke.
    pub number: u64,
}

impl Stroke {
    /// The stroke `number` of `painter`; none without a number (a dab
    /// that is an undo step of its own).
    pub fn of(painter: Option<&str>, number: Option<u64>) -> Option<Stroke> {
        number.map(|number| Stroke {
            painter: painter.map(str::to_string),
            number,
        })
    }
}

impl Stage {
    /// Paints stiffness under a brush (see `docs/rigs.md`). Grid and
    /// skeleton puppets refactor at the next solve; a free-form puppet returns the
    /// rebuild to run off the stage thread (none while one is under way:
    /// the newest weights go in the next when it finishes).
    pub fn paint(
        &mut self,
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
    ) -> Result<Option<Rebuild>, CommandError> {
        self.paint_stroke(puppet, at, radius, strength, None)
    }

    /// The brush's bounds: `radius` in (0, the stage's larger side],
    /// `strength` in [[`MIN_STRENGTH`], [`MAX_STRENGTH`]].
    pub fn check_brush(&self, at: DVec2, radius: f64, strength: f64) -> Result<(), CommandError> {
        if !at.is_finite() {
            return Err(CommandError::BadBrush);
        }
        let largest = self.width.max(self.height);
        if !(radius > 0.0 && radius <= largest) {
            return Err(CommandError::OutOfRange {
                field: "radius",
                problem: format!("must be more than 0 and at most {largest}, got {radius}"),
            });
        }
        if !(MIN_STRENGTH..=MAX_STRENGTH).contains(&strength) {
            return Err(CommandError::OutOfRange {
                field: "strength",
                problem: format!("must be {MIN_STRENGTH} to {MAX_STRENGTH}, got {strength}"),
            });
        }
        Ok(())
    }

    /// One dab of a stroke: as [`Stage::paint`]; the dabs of one `stroke`
    /// are one undo step.
    pub fn paint_stroke(
        &mut self,
        puppet: u32,
        at: DVec2,
        radius: f64,
        strength: f64,
        stroke: Option<Stroke>,
    ) -> Result<Option<Rebuild>, CommandError> {
        self.check_brush(at, radius, strength)?;
        let p = self.puppet_mut(puppet)?;
        let group = stroke.map(Group::Stroke);
        let joins = group.is_some() && p.history.open == group;
        let before = (!joins).then(|| p.weights.clone());
        if !p.paint(at, radius, strength) {
            return Ok(None);
        }
        p.history.edit(
            || Snapshot {
                weights: before,
                ..Snapshot::default()
            },
            group,
        );
        Ok(self.weights_changed(puppet))
    }

    /// After a puppet's weights changed (painted, or put back by undo): a
    /// free-form puppet's solver is rebuilt off the stage thread (the
    /// [`Rebuild`] to start); another rig is refactored once before the
    /// next solve, however many dabs arrive before it.
    pub(crate) fn weights_changed(&mut self, puppet: u32) -> Option<Rebuild> {
        let p = &mut self.puppets[puppet as usize];
        p.weights_generation += 1;
        if let Rig::Free(_) = p.rig {
            return self.rebuild(puppet);
        }
        p.weights_pending = true;
        p.moved = true;
        None
    }

    /// One dab of the depth-layer brush: the triangles whose deformed
    /// centroid lies within `radius` of `at` take `layer` (at most
    /// [`puppetry_mesh::MAX_LAYER`]) as their static depth, larger nearer;
    /// the depth adjustment starts afresh from the new order. Dabs of one
    /// `stroke` undo together.
    pub fn paint_depth_stroke(
        &mut self,
        puppet: u32,
        at: DVec2,
        radius: f64,
        layer: u16,
        stroke: Option<Stroke>,
    ) -> Result<(), CommandError> {
        self.check_brush(at, radius, 1.0)?;
        if layer > puppetry_mesh::MAX_LAYER {
            return Err(CommandError::OutOfRange {
                field: "layer",
                problem: format!("must be 0 to {}", puppetry_mesh::MAX_LAYER),
            });
        }
        let p = self.puppet_mut(puppet)?;
        let Some(mut layers) = p.static_layers() else {
            return Err(CommandError::NoDepth { puppet });
        };
        let before = layers.clone();
        let pose = p.rig.pose();
        let mut changed = false;
        for (tri, l) in p.mesh.triangles().iter().zip(&mut layers) {
            let [a, b, c] = tri.map(|i| pose[i as usize]);
            if ((a + b + c) / 3.0).distance(at) < radius && *l != layer {
                *l = layer;
                changed = true;
            }
        }
        if !changed {
            return Ok(());
        }
        p.history.edit(
            || Snapshot {
                layers: Some(before),
                ..Snapshot::default()
            },
            stroke.map(Group::DepthStroke),
        );
        p.set_layers(layers)
            .map_err(|problem| CommandError::Restore { puppet, problem })
    }
}
