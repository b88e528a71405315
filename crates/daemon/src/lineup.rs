//! The lineup: which puppets are on the stage, in which order, and where
//! connections find each one's output. It is fixed for the stage file's
//! puppets until a director adds, removes or reorders puppets at runtime;
//! then the stage thread publishes a new one and every connection sends its
//! client a fresh `stage` message and follows the new outputs. Puppet ids
//! never change: a removed puppet's id is not reused, so a frame already on
//! its way cannot land on another puppet.

use std::sync::Arc;

use glam::DVec2;

use crate::outputs::PuppetOutput;
use crate::protocol::{
    GridBasis, PadArea, Person, PuppetDescription, RigDescription, Role, ServerMessage,
    SkeletonMode, StageSize,
};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Picture, Puppet, Rig, Stage};

/// The puppets on stage now, as connections see them.
pub(crate) struct Lineup {
    /// Counts lineup changes since the daemon started.
    pub revision: u64,
    pub description: StageDescription,
    /// Every puppet's outputs, by id (a removed puppet's stay silent).
    pub outputs: Vec<PuppetOutput>,
    /// Every puppet as takes name them (rest-mesh hashes), by id (none on
    /// a relay: it records nothing).
    pub take_puppets: Vec<puppetry_take::PuppetInfo>,
    /// The stage file with the puppets added at runtime after its own, so
    /// a take recorded with them exports. A relay has no stage file: its
    /// lineups carry an empty stage of the same size, never read.
    pub config: Arc<StageConfig>,
}

/// A change to the lineup, asked of the stage thread.
pub enum LineupChange {
    /// A puppet loaded off the stage thread, and the stage-file entry it was
    /// loaded from, put on top of the others.
    Add(Box<(Puppet, puppetry_stage::config::PuppetConfig)>),
    /// A puppet taken off the stage.
    Remove(u32),
    /// The puppets on stage, bottom to top.
    Order(Vec<u32>),
}

impl std::fmt::Debug for LineupChange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LineupChange::Add(added) => write!(f, "Add({:?})", added.1.name),
            LineupChange::Remove(id) => write!(f, "Remove({id})"),
            LineupChange::Order(order) => write!(f, "Order({order:?})"),
        }
    }
}

impl Lineup {
    pub fn of(
        stage: &Stage,
        outputs: Vec<PuppetOutput>,
        revision: u64,
        config: Arc<StageConfig>,
    ) -> Arc<Lineup> {
        Arc::new(Lineup {
            revision,
            config,
            description: StageDescription::of(stage),
            outputs,
            take_puppets: puppetry_take::Header::of_stage("", "", stage, true).puppets,
        })
    }
}

/// What clients are told about the puppets on stage (a `stage` message
/// without handles), made once per lineup.
pub(crate) struct StageDescription {
    /// The puppets on stage, bottom to top: the "stage" message's entries
    /// without their handles.
    pub puppets: Vec<PuppetDescription>,
    pub size: StageSize,
    /// Every puppet's picture, by id (removed puppets' too: ids stay).
    pub images: Vec<Picture>,
    /// Each entry of `puppets` as JSON, split where its handles go: a
    /// connection's `stage` message is these pieces around each puppet's
    /// current handles, not a copy of the meshes serialised again.
    pub puppet_json: Vec<(String, String)>,
}

/// The serialised form of a puppet with no handles holds this exactly once
/// (serde writes fields in declaration order; a string value cannot hold
/// it, since its quotes would be escaped).
const NO_HANDLES: &str = r#","handles":[],"#;

/// `puppet`'s JSON before and after its (empty) handle list.
fn split_at_handles(puppet: &PuppetDescription) -> (String, String) {
    let text = serde_json::to_string(puppet).expect("puppet descriptions serialise");
    let at = text
        .find(NO_HANDLES)
        .expect("a puppet description without handles has an empty handle list");
    (
        text[..at + NO_HANDLES.len() - "[],".len()].to_string(),
        text[at + NO_HANDLES.len() - 1..].to_string(),
    )
}

impl StageDescription {
    pub fn of(stage: &Stage) -> StageDescription {
        let flat = |v: &[DVec2]| {
            v.iter()
                .flat_map(|q| [q.x as f32, q.y as f32])
                .collect::<Vec<f32>>()
        };
        let puppets = stage
            .on_stage()
            .map(|p| PuppetDescription {
                id: p.id,
                name: p.name.clone(),
                texture: format!("/puppets/{}/texture.png", p.id),
                rest: flat(p.mesh.vertices()),
                uv: p.mesh.uv().map(flat).unwrap_or_default(),
                triangles: p.mesh.triangles().iter().flatten().copied().collect(),
                handles: Vec::new(),
                weights: p.mesh.weights().to_vec(),
                rig: rig_description(p.rig()),
                pads: stage
                    .pads()
                    .iter()
                    .filter(|pad| pad.puppet == p.id as usize)
                    .map(|pad| PadArea {
                        area: [pad.min.x, pad.min.y, pad.max.x, pad.max.y],
                        source: pad.source.clone(),
                    })
                    .collect(),
            })
            .collect::<Vec<_>>();
        let size = StageSize {
            width: stage.width,
            height: stage.height,
        };
        let images = stage.puppets().iter().map(|p| p.picture.clone()).collect();
        StageDescription::from_puppets(puppets, size, images)
    }

    /// The description of `puppets` (without handles) on a stage of
    /// `size`; a relay makes its own from what the daemon publishes, with
    /// no pictures (it fetches them from the daemon).
    pub fn from_puppets(
        puppets: Vec<PuppetDescription>,
        size: StageSize,
        images: Vec<Picture>,
    ) -> StageDescription {
        StageDescription {
            puppet_json: puppets.iter().map(split_at_handles).collect(),
            puppets,
            size,
            images,
        }
    }
}

impl StageDescription {
    /// The "stage" message for a client: the serialised puppets around
    /// each one's handles (`handles(id)`, as JSON).
    pub fn message(
        &self,
        client: u64,
        role: Role,
        you: Person,
        mut handles: impl FnMut(u32) -> String,
    ) -> String {
        let head = ServerMessage::Stage {
            client,
            role,
            you,
            stage: self.size,
            puppets: Vec::new(),
        }
        .to_text();
        // `puppets` is the last field, so the message ends with it.
        let head = head
            .strip_suffix("[]}")
            .expect("the stage message ends with its puppets");
        let pieces: usize = self
            .puppet_json
            .iter()
            .map(|(a, b)| a.len() + b.len())
            .sum();
        let mut text = String::with_capacity(head.len() + pieces + 256 * self.puppets.len() + 2);
        text.push_str(head);
        text.push('[');
        for (k, (p, (before, after))) in self.puppets.iter().zip(&self.puppet_json).enumerate() {
            if k > 0 {
                text.push(',');
            }
            text.push_str(before);
            text.push_str(&handles(p.id));
            text.push_str(after);
        }
        text.push_str("]}");
        text
    }
}

/// The "rig" entry of a puppet in the "stage" message. Rest points are
/// full-precision stage coordinates, row by row / joint by joint.
fn rig_description(rig: &Rig) -> RigDescription {
    let points = |v: &[DVec2]| v.iter().map(|q| [q.x, q.y]).collect::<Vec<_>>();
    match rig {
        Rig::Free(_) => RigDescription::Free,
        Rig::Grid(r) => {
            let spec = r.ffd().spec();
            RigDescription::Grid {
                columns: spec.columns,
                rows: spec.rows,
                basis: match spec.basis {
                    puppetry_deform::ffd::Basis::Bernstein => GridBasis::Bernstein,
                    puppetry_deform::ffd::Basis::Lattice => GridBasis::Lattice,
                },
                min: [spec.min.x, spec.min.y],
                max: [spec.max.x, spec.max.y],
                rest: points(r.ffd().rest_grid()),
            }
        }
        Rig::Skeleton(r) => {
            let skeleton = r.deformer().skeleton();
            RigDescription::Skeleton {
                mode: match r.mode() {
                    puppetry_stage::config::SkeletonMode::Free => SkeletonMode::Free,
                    puppetry_stage::config::SkeletonMode::Fk => SkeletonMode::Fk,
                },
                bones: skeleton.bones().to_vec(),
                rest: points(skeleton.joints()),
                poses: r.pose_names().into_iter().map(String::from).collect(),
            }
        }
        Rig::Curve(r) => RigDescription::Curve {
            width: 2.0 * r.half_width(),
            line: points(r.curve().rest()),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{GripKind, HandleKind, HandleView, PersonRole};

    /// The stage message spliced from the lineup's serialised puppets is
    /// exactly what serialising the whole message would give, for stages
    /// of every rig kind and several puppets with and without handles.
    #[test]
    fn a_spliced_stage_message_is_the_serialised_one() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        for file in ["demo.toml", "grid.toml", "skeleton.toml", "curve.toml"] {
            let config = StageConfig::load(&dir.join(file)).expect("a bundled stage loads");
            let stage = Stage::from_config(&config).expect("a bundled stage builds");
            let description = StageDescription::of(&stage);
            let handles = |id: u32| -> Vec<HandleView> {
                (0..id % 3)
                    .map(|k| HandleView {
                        id: u64::from(k),
                        owner: format!("client:{k}\"\\,\"handles\":[],"),
                        kind: HandleKind::Contact,
                        at: [f64::from(id), 0.5],
                        grip: GripKind::Point,
                        index: (k == 1).then_some(7),
                    })
                    .collect()
            };
            let you = Person {
                owner: "client:3".into(),
                name: "A \"handles\":[], name".into(),
                role: PersonRole::Viewer,
                colour: "#123456".into(),
            };
            let spliced = description.message(3, Role::Viewer, you.clone(), |id| {
                serde_json::to_string(&handles(id)).unwrap()
            });
            let whole = ServerMessage::Stage {
                client: 3,
                role: Role::Viewer,
                you,
                stage: description.size,
                puppets: description
                    .puppets
                    .iter()
                    .map(|p| PuppetDescription {
                        handles: handles(p.id),
                        ..p.clone()
                    })
                    .collect(),
            }
            .to_text();
            assert_eq!(spliced, whole, "{file}");
        }
    }
}
