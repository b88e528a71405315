//! Each exported frame's triangle order, back to front, for a puppet that
//! folds over itself (`docs/depth.md`): what the page drew, flips and
//! painted layers included.
//!
//! The live stage's order depends on more than the vertices: a performer's
//! Alt+click pins a part in front (`depth_flip`), a director paints depth
//! layers, and the order keeps its frame-to-frame coherence. So the export
//! replays the take's steps through a stage of its own ([`DepthReplay`]),
//! as `takes --verify` does, and reads each puppet's order after the step
//! its frame follows: exactly the live order whenever the replay gives the
//! recorded frames bit for bit. Once it does not (a take begun mid-show, a
//! salvaged take with steps lost) the replay is dropped and the depth order
//! is run over the recorded frames instead ([`orders_of_frames`]), which
//! knows no flips.

use std::sync::Arc;

use glam::DVec2;
use puppetry_stage::Stage;
use puppetry_take::replay::Replayer;
use puppetry_take::{Frame, Step};

/// A frame's depths (per triangle, larger = nearer) and the triangle order
/// they give, back to front; frames that share them share them.
#[derive(Clone)]
pub(crate) struct Drawn {
    pub(crate) depth: Arc<[u16]>,
    pub(crate) order: Arc<[u32]>,
}

impl Drawn {
    /// Triangles sorted back to front by depth; ties keep the mesh's
    /// order, as the page's sort does.
    fn of(depth: &[u16]) -> Drawn {
        let mut order: Vec<u32> = (0..depth.len() as u32).collect();
        order.sort_by_key(|&t| depth[t as usize]);
        Drawn {
            depth: depth.into(),
            order: order.into(),
        }
    }

    /// Every triangle at one depth: the mesh's own order.
    pub(crate) fn plain(triangles: usize) -> Drawn {
        Drawn::of(&vec![0; triangles])
    }
}

/// The take's steps replayed for the drawing order, while the replay holds.
pub(crate) struct DepthReplay {
    /// `None` once a replayed pose left the recording (or a step failed).
    replayer: Option<Replayer>,
    /// Per puppet, its order now and the depth generation it was read at.
    now: Vec<Option<(u32, Drawn)>>,
}

impl DepthReplay {
    /// Replays on `stage`, fresh from the take's stage file.
    pub(crate) fn new(stage: Stage) -> DepthReplay {
        let replayer = Replayer::new(stage);
        let mut replay = DepthReplay {
            now: vec![None; replayer.stage().puppets().len()],
            replayer: Some(replayer),
        };
        replay.read_orders();
        replay
    }

    /// Whether every frame so far came out of the replay as recorded.
    pub(crate) fn holds(&self) -> bool {
        self.replayer.is_some()
    }

    /// Puppet `puppet`'s order now (`None` without a depth order, or once
    /// the replay has been dropped).
    pub(crate) fn order(&self, puppet: u32) -> Option<Drawn> {
        self.replayer.as_ref()?;
        self.now
            .get(puppet as usize)?
            .as_ref()
            .map(|(_, o)| o.clone())
    }

    /// Applies a recorded step.
    pub(crate) fn step(&mut self, step: &Step) {
        if let Some(r) = &mut self.replayer
            && r.apply(step).is_err()
        {
            self.replayer = None;
        }
        self.read_orders();
    }

    /// The order puppet `frame.puppet` is drawn in with this recorded
    /// frame, or `None` (for good) once the replay does not give it.
    pub(crate) fn frame(&mut self, frame: &Frame) -> Option<Drawn> {
        let r = self.replayer.as_ref()?;
        let same = r
            .stage()
            .puppets()
            .get(frame.puppet as usize)
            .is_some_and(|p| {
                let pose = p.pose();
                pose.len() == frame.points.len()
                    && pose.iter().zip(&frame.points).all(|(q, f)| {
                        (q.x as f32).to_bits() == f[0].to_bits()
                            && (q.y as f32).to_bits() == f[1].to_bits()
                    })
            });
        if !same {
            self.replayer = None;
        }
        self.order(frame.puppet)
    }

    /// The order of each puppet with a depth order, read again only where
    /// its generation moved on.
    fn read_orders(&mut self) {
        let Some(r) = &self.replayer else { return };
        for (p, now) in r.stage().puppets().iter().zip(&mut self.now) {
            let Some((depth, generation)) = p.depth() else {
                *now = None;
                continue;
            };
            if now.as_ref().is_some_and(|(g, _)| *g == generation) {
                continue;
            }
            *now = Some((generation, Drawn::of(depth)));
        }
    }
}

/// A puppet's exported frames' depths and orders
/// ([`crate::AnimatedPuppet::depths`], [`crate::AnimatedPuppet::draw_orders`]).
pub(crate) type Drawing = (Vec<Arc<[u16]>>, Vec<Arc<[u32]>>);

/// The depths and orders of a puppet's exported frames, or none where
/// every order is the mesh's own (drawn the plain way).
pub(crate) fn unless_plain(frames: Vec<Drawn>) -> Drawing {
    let plain = |d: &Drawn| d.order.iter().enumerate().all(|(i, &t)| i == t as usize);
    if frames.iter().all(plain) {
        return (Vec::new(), Vec::new());
    }
    frames.into_iter().map(|d| (d.depth, d.order)).unzip()
}

/// Each frame's order as the depth order run over the recorded frames in
/// turn, from the mesh's own layers (its frame-to-frame coherence holds;
/// flips and layers painted during the show are not known). It runs
/// at the export's frame rate, not the live solve rate, so where the live
/// decision depended on the path between two exported frames the export
/// may decide otherwise.
pub(crate) fn orders_of_frames(mesh: &puppetry_mesh::Mesh, frames: &[Vec<[f32; 2]>]) -> Drawing {
    let Ok(mut depth) = puppetry_deform::depth::DepthOrder::register(mesh, mesh.layers()) else {
        return (Vec::new(), Vec::new());
    };
    let mut last = Drawn::plain(mesh.triangles().len());
    let mut positions = Vec::new();
    let orders = frames
        .iter()
        .map(|frame| {
            positions.clear();
            positions.extend(
                frame
                    .iter()
                    .map(|q| DVec2::new(f64::from(q[0]), f64::from(q[1]))),
            );
            // A pose that cannot be ordered keeps the last order.
            if depth.update(&positions).is_ok() && depth.changed() {
                last = Drawn::of(depth.depth());
            }
            last.clone()
        })
        .collect();
    unless_plain(orders)
}
