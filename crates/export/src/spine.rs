//! Spine 4.2 JSON: a skeleton of one `root` bone at the origin, one slot
//! per puppet (drawing order = slot order) holding a mesh attachment, and
//! one animation whose deform timelines move the mesh vertices — except a
//! skeleton puppet's: it comes as a rig, one Spine bone per bone of its
//! skeleton (`PUPPET/N`, parented as the skeleton, at rest in the setup
//! pose), its mesh weighted to them and bound at rest, and rotate and
//! translate timelines per bone, a key per frame, fitted to the take by
//! [`crate::skin`] (within the error the export reports; no deform keys).
//!
//! The layout is the one `SkeletonJson` of the Spine runtimes (spine-core
//! 4.2) reads: `skins` is an array of `{name, attachments: {SLOT: {NAME:
//! mesh}}}`, and deform timelines sit under
//! `animations.NAME.attachments.SKIN.SLOT.ATTACHMENT.deform`, each key
//! `{time, offset, vertices}` with `vertices` the offsets from the setup
//! vertices starting at float index `offset` (zeros before and after are
//! left out; a key without `vertices` is the setup pose).
//!
//! - **Setup pose = frame 0.** The attachment's `vertices` are frame 0 in
//!   stage coordinates (Spine is y-up too, and the root bone is the
//!   identity), so key k holds `frame k − frame 0`.
//! - **Keys at `t = k / fps`, linear** (Spine's default curve): applying
//!   the animation at `k / fps` gives frame k exactly, and times in between
//!   blend the neighbouring frames, as the glTF export does — except into
//!   a frame the take stepped into (a let-go, [`AnimatedPuppet::snaps`]):
//!   the key before it is `stepped`, so the held pose stays until the snap.
//! - **Hull first.** Spine wants the mesh's hull — the vertices of its
//!   boundary loop, in loop order — to be the first `hull` vertices. The
//!   vertices are reordered so: the longest boundary loop (counter-
//!   clockwise, as the triangles wind) first, then every other vertex in its
//!   old order; `uvs`, `triangles`, setup vertices and every deform key use
//!   the same permutation, which the export returns ([`SpineLayout`]).
//!   (Spine knows one hull per mesh: a puppet of several islands or with
//!   holes has its other boundary vertices after the hull.)
//! - **Folds.** Spine draws a mesh attachment's triangles in the order it
//!   lists them, for the whole clip. A puppet that overlaps itself lists
//!   them in an order that draws every overlap as the page did
//!   ([`crate::folds`]); where its fold changes sides, its slot switches
//!   (attachment keys) to another attachment of the same vertices and
//!   deform listed in the next order.
//! - **Pictures.** `uvs` are the mesh's own (v down from the picture's top
//!   edge, as Spine's region UVs). Each attachment's `path` names its
//!   picture; [`export_spine`] writes the pictures beside the JSON as
//!   `PATH.png` and sets `skeleton.images` to `./`, so the Spine editor's
//!   "Import Data" finds them.

use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::Path;

use serde::Serialize;
use serde_json::json;

use glam::DVec2;
use serde_json::Value;

use crate::skin::{SkeletonRest, Skin, local};
use crate::{AnimatedPuppet, Animation, ExportError, Progress};

/// Options of a Spine export.
#[derive(Debug, Clone, PartialEq)]
pub struct SpineOptions {
    /// The animation's name.
    pub animation_name: String,
    /// What each picture's name starts with: [`export_spine`] uses the
    /// JSON file's name and a dash (`walk-gingerbread.png` beside
    /// `walk.json`), so pictures of two exports in one folder, or a
    /// picture of the user's own, are never the same file.
    pub image_prefix: String,
}

impl Default for SpineOptions {
    fn default() -> Self {
        SpineOptions {
            animation_name: "take".into(),
            image_prefix: String::new(),
        }
    }
}

/// The version written in `skeleton.spine`.
pub const SPINE_VERSION: &str = "4.2.00";

/// How the export laid out one puppet.
#[derive(Debug, Clone, PartialEq)]
pub struct SpinePuppet {
    /// Slot and attachment name (the puppet's name, made unique).
    pub slot: String,
    /// The attachment's `path`: its picture is `PATH.png`.
    pub path: String,
    /// `order[i]` is the puppet's vertex that became Spine vertex `i`.
    pub order: Vec<u32>,
    /// The number of hull vertices (the first ones in `order`).
    pub hull: usize,
    /// For a skeleton puppet exported as bones: how many, and the largest
    /// and mean distance in stage units between the skinned vertices and
    /// the take's over every frame ([`crate::skin::Skin`]).
    pub bones: Option<(usize, f64, f64)>,
    /// The slot's mesh attachments, each with the frame it is shown from:
    /// one, named as the slot, for a puppet drawn in one triangle order;
    /// for one whose folds change sides, one per run of
    /// [`crate::folds::runs`] (`SLOT`, `SLOT 2`, …: the same vertices and
    /// deform, the triangles listed in that run's order), switched by the
    /// slot's attachment keys.
    pub attachments: Vec<(String, usize)>,
    /// Its folds needed more than [`crate::folds::MAX_RUNS`] orders: drawn
    /// in its mesh's order throughout.
    pub unkept_folds: bool,
}

/// How the export laid out the puppets, in slot order.
#[derive(Debug, Clone, PartialEq)]
pub struct SpineLayout {
    /// One per puppet, bottom first (slot order).
    pub puppets: Vec<SpinePuppet>,
}

/// The boundary loop with the most vertices, in the triangles' winding
/// order (counter-clockwise around the outside for counter-clockwise
/// triangles), each vertex once.
pub fn hull(triangles: &[[u32; 3]]) -> Vec<u32> {
    let directed: HashSet<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    // Boundary edges: those whose reverse no triangle has.
    let mut outgoing: HashMap<u32, Vec<u32>> = HashMap::new();
    let mut boundary: Vec<(u32, u32)> = directed
        .iter()
        .filter(|&&(a, b)| !directed.contains(&(b, a)))
        .copied()
        .collect();
    boundary.sort_unstable();
    for &(a, b) in &boundary {
        outgoing.entry(a).or_default().push(b);
    }
    let mut used: HashSet<(u32, u32)> = HashSet::new();
    let mut best: Vec<u32> = Vec::new();
    for &(a0, b0) in &boundary {
        if used.contains(&(a0, b0)) {
            continue;
        }
        let mut walk = vec![a0];
        used.insert((a0, b0));
        let mut at = b0;
        while at != a0 {
            walk.push(at);
            let next = outgoing
                .get(&at)
                .and_then(|targets| targets.iter().find(|&&t| !used.contains(&(at, t))));
            match next {
                Some(&t) => {
                    used.insert((at, t));
                    at = t;
                }
                None => break, // not a closed loop (a non-manifold mesh)
            }
        }
        let mut seen = HashSet::new();
        walk.retain(|v| seen.insert(*v));
        if walk.len() > best.len() {
            best = walk;
        }
    }
    best
}

/// Spine vertex order of a puppet: hull first, then the rest in order.
fn vertex_order(p: &AnimatedPuppet) -> (Vec<u32>, usize) {
    let hull = hull(&p.triangles);
    let mut in_hull = vec![false; p.vertex_count()];
    for &v in &hull {
        in_hull[v as usize] = true;
    }
    let mut order = hull.clone();
    order.extend((0..p.vertex_count() as u32).filter(|&v| !in_hull[v as usize]));
    (order, hull.len())
}

/// A unique name for each puppet (its slot and attachment), and its
/// picture's file-name-safe path, `prefix` first.
fn names(animation: &Animation, prefix: &str) -> Vec<(String, String)> {
    let mut taken = HashSet::new();
    animation
        .puppets
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let base = if p.name.trim().is_empty() {
                format!("puppet {i}")
            } else {
                p.name.clone()
            };
            let mut name = base.clone();
            let mut n = 2;
            while !taken.insert(name.clone()) {
                name = format!("{base} {n}");
                n += 1;
            }
            let path = prefix
                .chars()
                .chain(name.chars())
                .map(|c| {
                    if c.is_alphanumeric() || "-_ .".contains(c) {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            (name, path)
        })
        .collect()
}

#[derive(Serialize)]
struct Key<'a> {
    time: f64,
    /// `stepped` where the take stepped into the next frame (a let-go):
    /// the pose holds until it instead of blending into it.
    #[serde(skip_serializing_if = "Option::is_none")]
    curve: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    offset: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    vertices: Option<&'a [f32]>,
}

/// Writes `animation` as Spine JSON to `out`; returns the vertex orders.
/// `progress` counts frames, per puppet.
pub fn write_spine(
    animation: &Animation,
    options: &SpineOptions,
    progress: &mut dyn Progress,
    out: &mut dyn Write,
) -> Result<SpineLayout, ExportError> {
    animation.validate()?;
    let err = |source| ExportError::Io {
        file: "Spine output".into(),
        source,
    };
    let names = names(animation, &options.image_prefix);
    let mut layout = SpineLayout {
        puppets: Vec::new(),
    };
    let mut slots = Vec::new();
    let mut skin = serde_json::Map::new();
    let mut bones = vec![json!({"name": "root"})];
    let mut rigs: Vec<Option<SpineRig>> = Vec::new();
    for (p, (name, path)) in animation.puppets.iter().zip(&names) {
        let (order, hull) = vertex_order(p);
        let mut new_index = vec![0u32; order.len()];
        for (i, &v) in order.iter().enumerate() {
            new_index[v as usize] = i as u32;
        }
        let uvs: Vec<f32> = order.iter().flat_map(|&v| p.uv[v as usize]).collect();
        // A skeleton puppet: bones, weighted vertices bound at rest, and
        // bone timelines; the others: frame 0 and a deform timeline.
        let fitted = p.skeleton.as_ref().map(|rest| {
            let skin = crate::skin::fit(p, rest);
            let mut rig = SpineRig::new(name, rest, skin);
            rig.snaps = p.snaps.clone();
            rig.push_bones(&mut bones);
            rig
        });
        let setup: Value = match &fitted {
            Some(rig) => json!(rig.weighted_vertices(&order)),
            None => json!(
                order
                    .iter()
                    .flat_map(|&v| p.frames[0][v as usize])
                    .collect::<Vec<f32>>()
            ),
        };
        let mesh = json!({
            "type": "mesh", "path": path,
            "uvs": uvs, "vertices": setup, "hull": hull,
            "width": p.image.width, "height": p.image.height,
        });
        let (meshes, attachments, unkept_folds) = attachments(p, name, mesh, &new_index);
        slots.push(json!({"name": name, "bone": "root", "attachment": name}));
        skin.insert(name.clone(), Value::Object(meshes));
        layout.puppets.push(SpinePuppet {
            slot: name.clone(),
            path: path.clone(),
            order,
            hull,
            bones: fitted
                .as_ref()
                .map(|rig| (rig.names.len(), rig.skin.max_error, rig.skin.mean_error)),
            attachments,
            unkept_folds,
        });
        rigs.push(fitted);
    }
    let head = json!({
        "skeleton": {
            "spine": SPINE_VERSION,
            "x": 0.0, "y": 0.0,
            "width": animation.stage_width, "height": animation.stage_height,
            "fps": animation.fps,
            "images": "./",
        },
        "bones": bones,
        "slots": slots,
        "skins": [{"name": "default", "attachments": skin}],
    });
    // The head, less its closing brace, then the animation streamed key by
    // key (a long take has millions of numbers).
    let mut text = serde_json::to_vec(&head).expect("Spine JSON serialises");
    text.pop();
    out.write_all(&text).map_err(err)?;
    write!(out, ",\"animations\":{{").map_err(err)?;
    serde_json::to_writer(&mut *out, &options.animation_name).map_err(|e| err(e.into()))?;
    write!(out, ":{{\"bones\":{{").map_err(err)?;
    let total = animation.frame_count * animation.puppets.len();
    let mut done = 0;
    let mut first_bone = true;
    for rig in rigs.iter().flatten() {
        for (b, timelines) in rig.timelines(animation) {
            if !first_bone {
                out.write_all(b",").map_err(err)?;
            }
            first_bone = false;
            serde_json::to_writer(&mut *out, &rig.names[b]).map_err(|e| err(e.into()))?;
            out.write_all(b":").map_err(err)?;
            serde_json::to_writer(&mut *out, &timelines).map_err(|e| err(e.into()))?;
        }
        done += animation.frame_count;
        progress.step(done, total);
    }
    write!(out, "}},\"attachments\":{{\"default\":{{").map_err(err)?;
    let mut offsets = Vec::new();
    let mut first_slot = true;
    for ((p, placed), rig) in animation.puppets.iter().zip(&layout.puppets).zip(&rigs) {
        if rig.is_some() {
            continue;
        }
        if !first_slot {
            out.write_all(b",").map_err(err)?;
        }
        first_slot = false;
        write_deform(out, animation, p, placed, &mut offsets, &mut |n| {
            done += n;
            progress.step(done, total);
        })?;
    }
    out.write_all(b"}}").map_err(err)?;
    let switches = attachment_keys(animation, &layout);
    if !switches.is_empty() {
        out.write_all(b",\"slots\":").map_err(err)?;
        serde_json::to_writer(&mut *out, &switches).map_err(|e| err(e.into()))?;
    }
    out.write_all(b"}}}\n").map_err(err)?;
    Ok(layout)
}

/// A puppet's mesh attachments (`mesh` with its `triangles` listed in each
/// run's order, [`crate::folds::runs`]), each with the frame it shows
/// from, and whether its folds went past [`crate::folds::MAX_RUNS`]. A
/// skeleton puppet keeps its first frame's order (its mesh is weighted to
/// its bones whole).
fn attachments(
    p: &AnimatedPuppet,
    name: &str,
    mesh: Value,
    new_index: &[u32],
) -> (serde_json::Map<String, Value>, Vec<(String, usize)>, bool) {
    let runs = match p.skeleton {
        Some(_) => Ok(None),
        None => crate::folds::runs(p),
    };
    let unkept_folds = runs.is_err();
    let (starts, orders) = match runs {
        Ok(Some(r)) => (r.starts, r.orders),
        _ => (vec![0], vec![(0..p.triangles.len() as u32).collect()]),
    };
    let mut meshes = serde_json::Map::new();
    let mut attachments = Vec::new();
    for (i, (&start, order)) in starts.iter().zip(&orders).enumerate() {
        let attachment = if i == 0 {
            name.to_string()
        } else {
            format!("{name} {}", i + 1)
        };
        let triangles: Vec<u32> = order
            .iter()
            .flat_map(|&t| p.triangles[t as usize])
            .map(|v| new_index[v as usize])
            .collect();
        let mut mesh = mesh.clone();
        mesh["triangles"] = json!(triangles);
        meshes.insert(attachment.clone(), mesh);
        attachments.push((attachment, start));
    }
    (meshes, attachments, unkept_folds)
}

/// The slots' attachment keys (`animations.NAME.slots`): where a folding
/// puppet's order changes, its slot shows the next attachment, half a
/// frame early (Spine keeps key times in f32, and a switch at the frame's
/// own time could come after it).
fn attachment_keys(animation: &Animation, layout: &SpineLayout) -> serde_json::Map<String, Value> {
    layout
        .puppets
        .iter()
        .filter(|placed| placed.attachments.len() > 1)
        .map(|placed| {
            let keys: Vec<Value> = placed.attachments[1..]
                .iter()
                .map(|(name, start)| {
                    json!({"time": (*start as f64 - 0.5) / animation.fps, "name": name})
                })
                .collect();
            (placed.slot.clone(), json!({"attachment": keys}))
        })
        .collect()
}

/// A free-form or grid puppet's deform timeline in `placed`'s vertex
/// order: a key per frame of the offsets from frame 0 (the setup), the
/// zeros before and after left out, and the last frame held to the clip's
/// end. `counted` is told of each frame written.
fn write_deform(
    out: &mut dyn Write,
    animation: &Animation,
    p: &AnimatedPuppet,
    placed: &SpinePuppet,
    offsets: &mut Vec<f32>,
    counted: &mut dyn FnMut(usize),
) -> Result<(), ExportError> {
    let err = |source| ExportError::Io {
        file: "Spine output".into(),
        source,
    };
    let name = serde_json::to_string(&placed.slot).expect("a string serialises");
    write!(out, "{name}:{{").map_err(err)?;
    for (i, (attachment, start)) in placed.attachments.iter().enumerate() {
        // Each attachment's keys over the frames it is shown, from the
        // frame before its first (it shows from half a frame before) to
        // the next one's first, so it blends across the switch as the
        // frames do; the last is held for its frame's time.
        let end = placed
            .attachments
            .get(i + 1)
            .map_or(animation.frame_count - 1, |&(_, next)| next);
        let from = start.saturating_sub(1);
        if i > 0 {
            out.write_all(b",").map_err(err)?;
        }
        serde_json::to_writer(&mut *out, attachment).map_err(|e| err(e.into()))?;
        out.write_all(b":{\"deform\":[").map_err(err)?;
        for k in from..=end {
            if k > from {
                out.write_all(b",").map_err(err)?;
            }
            write_key(out, animation, p, placed, k, offsets)?;
            if k >= *start && (k < end || i + 1 == placed.attachments.len()) {
                counted(1);
            }
        }
        out.write_all(b"]}").map_err(err)?;
    }
    out.write_all(b"}").map_err(err)?;
    Ok(())
}

/// Frame k's deform key of a puppet (and after the last frame, the key
/// that holds it for its frame's time, so the clip lasts n / fps like the
/// take's video, not (n − 1) / fps).
fn write_key(
    out: &mut dyn Write,
    animation: &Animation,
    p: &AnimatedPuppet,
    placed: &SpinePuppet,
    k: usize,
    offsets: &mut Vec<f32>,
) -> Result<(), ExportError> {
    let err = |source| ExportError::Io {
        file: "Spine output".into(),
        source,
    };
    let setup = &p.frames[0];
    offsets.clear();
    offsets.extend(placed.order.iter().flat_map(|&v| {
        let (q, o) = (p.frames[k][v as usize], setup[v as usize]);
        [q[0] - o[0], q[1] - o[1]]
    }));
    let first = offsets.iter().position(|&d| d != 0.0);
    let last = offsets.iter().rposition(|&d| d != 0.0);
    let time = k as f64 / animation.fps;
    let curve = p.snaps_into(k + 1).then_some("stepped");
    let key = match (first, last) {
        (Some(a), Some(b)) => Key {
            time,
            curve,
            offset: (a > 0).then_some(a),
            vertices: Some(&offsets[a..=b]),
        },
        _ => Key {
            time,
            curve,
            offset: None,
            vertices: None,
        },
    };
    serde_json::to_writer(&mut *out, &key).map_err(|e| err(e.into()))?;
    if k + 1 == animation.frame_count {
        let hold = Key {
            time: animation.duration(),
            ..key
        };
        out.write_all(b",").map_err(err)?;
        serde_json::to_writer(&mut *out, &hold).map_err(|e| err(e.into()))?;
    }
    Ok(())
}

/// A skeleton puppet's bones in the Spine skeleton: one Spine bone per
/// bone of its skeleton, named `PUPPET/N` and parented as the skeleton's
/// (a root bone under Spine's `root`), set up at rest (head at the bone's
/// first joint, pointing along it), moved by the fitted [`Skin`].
struct SpineRig {
    /// Spine bone name per skeleton bone.
    names: Vec<String>,
    /// The skeleton at rest.
    rest: SkeletonRest,
    /// Skeleton bones, parents before children (Spine's bone order).
    order: Vec<usize>,
    /// The fitted motion and weights.
    skin: Skin,
    /// Per skeleton bone, its index among the Spine skeleton's bones.
    index: Vec<usize>,
    /// The frames the take stepped into ([`AnimatedPuppet::snaps`]).
    snaps: Vec<usize>,
}

impl SpineRig {
    fn new(puppet: &str, rest: &SkeletonRest, skin: Skin) -> SpineRig {
        SpineRig {
            names: (0..rest.bones.len())
                .map(|b| format!("{puppet}/{b}"))
                .collect(),
            rest: rest.clone(),
            order: rest.order(),
            skin,
            index: Vec::new(),
            snaps: Vec::new(),
        }
    }

    /// Appends this puppet's bones to the skeleton's, parents first, and
    /// remembers each one's index there (weighted vertices name bones by
    /// index).
    fn push_bones(&mut self, bones: &mut Vec<Value>) {
        self.index = vec![0; self.names.len()];
        for &b in &self.order {
            self.index[b] = bones.len();
            let parent = self.rest.parents[b];
            let (at, rotation) = local(parent.map(|p| self.rest.frame(p)), self.rest.frame(b));
            bones.push(json!({
                "name": self.names[b],
                "parent": parent.map_or("root", |p| self.names[p].as_str()),
                "x": at.x, "y": at.y,
                "rotation": rotation.to_degrees(),
                "length": self.rest.length(b),
            }));
        }
    }

    /// The weighted vertices in Spine's form, in `order`: per vertex its
    /// bone count, then per bone its index among the skeleton's bones, the
    /// vertex in the bone's rest frame (x along the bone), and its weight.
    fn weighted_vertices(&self, order: &[u32]) -> Vec<f64> {
        let mut out = Vec::new();
        for &v in order {
            let v = v as usize;
            let weights = &self.skin.weights[v];
            out.push(weights.len() as f64);
            for &(b, w) in weights {
                let (head, angle) = self.rest.frame(b);
                let bind = DVec2::from_angle(-angle).rotate(self.rest.rest[v] - head);
                out.extend([self.index[b] as f64, bind.x, bind.y, w]);
            }
        }
        out
    }

    /// Each bone's timelines: per frame (and the last held to the clip's
    /// end) its rotation and translation relative to its setup, as Spine
    /// keys them; rotations unwrapped so linear blending never spins.
    fn timelines(&self, animation: &Animation) -> Vec<(usize, Value)> {
        let n = animation.frame_count;
        let times: Vec<f64> = (0..n)
            .map(|k| k as f64 / animation.fps)
            .chain([animation.duration()])
            .collect();
        self.order
            .iter()
            .map(|&b| {
                let parent = self.rest.parents[b];
                let setup = local(parent.map(|p| self.rest.frame(p)), self.rest.frame(b));
                let posed = |k: usize, bone: usize| self.skin.posed(&self.rest, k, bone);
                let mut rotate = Vec::with_capacity(n + 1);
                let mut translate = Vec::with_capacity(n + 1);
                let mut last = 0.0f64;
                for (k, &time) in times.iter().enumerate() {
                    let (at, rotation) = local(parent.map(|p| posed(k, p)), posed(k, b));
                    let mut degrees = (rotation - setup.1).to_degrees();
                    degrees -= 360.0 * ((degrees - last) / 360.0).round();
                    last = degrees;
                    let offset = at - setup.0;
                    // To 1e-4 (degrees, stage units): a third of the text,
                    // far below what the fit is off by.
                    let short = |v: f64| (v * 1e4).round() / 1e4;
                    let mut turn = json!({"time": time, "value": short(degrees)});
                    let mut shift =
                        json!({"time": time, "x": short(offset.x), "y": short(offset.y)});
                    // Held until the frame the take stepped into.
                    if self.snaps.binary_search(&(k + 1)).is_ok() {
                        turn["curve"] = json!("stepped");
                        shift["curve"] = json!("stepped");
                    }
                    rotate.push(turn);
                    translate.push(shift);
                }
                (b, json!({"rotate": rotate, "translate": translate}))
            })
            .collect()
    }
}

/// The atlas (`.atlas`, libGDX's text format as spine-core 4.2 reads it)
/// of the pictures: one page per puppet's picture, holding one region of
/// its whole size named as the attachment's `path`. Straight alpha
/// (`pma: false`), linear filtering.
pub fn atlas(animation: &Animation, layout: &SpineLayout) -> String {
    let mut text = String::new();
    for (p, placed) in animation.puppets.iter().zip(&layout.puppets) {
        let (w, h) = (p.image.width, p.image.height);
        text.push_str(&format!(
            "{path}.png\nsize: {w},{h}\nfilter: Linear,Linear\npma: false\n{path}\nbounds: 0,0,{w},{h}\n\n",
            path = placed.path
        ));
    }
    text
}

/// The prefix of the pictures of an export to `path`: its file name
/// without extension and a dash.
fn image_prefix(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    format!("{stem}-")
}

/// Whether `path` asks for the bundle: one `.zip` of the JSON, its atlas
/// and its pictures ([`export_spine_zip`]), as the page downloads it.
pub fn is_bundle(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("zip"))
}

/// Every file [`export_spine`] writes for `animation` at `path`: the JSON,
/// its atlas (`path` with the extension `.atlas`) and each picture; for a
/// bundle, the `.zip` alone.
pub fn files(animation: &Animation, path: &Path) -> Vec<std::path::PathBuf> {
    if is_bundle(path) {
        return vec![path.to_path_buf()];
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut files = vec![path.to_path_buf(), path.with_extension("atlas")];
    files.extend(
        names(animation, &image_prefix(path))
            .into_iter()
            .map(|(_, picture)| dir.join(format!("{picture}.png"))),
    );
    files
}

/// Writes `animation` as Spine JSON at `path`, its atlas beside it
/// (`path` with the extension `.atlas`, see [`atlas`]) and each puppet's
/// picture as `PATH.png`, PATH the JSON's name, a dash and the puppet's
/// (see [`SpinePuppet::path`]): the Spine editor's Import Data finds the
/// pictures (`skeleton.images` is `./`), spine-player and the runtimes
/// load the atlas. Each file is made new ([`crate::write_new`]): a link
/// in its place is replaced, never followed.
pub fn export_spine(
    animation: &Animation,
    options: &SpineOptions,
    progress: &mut dyn Progress,
    path: &Path,
) -> Result<SpineLayout, ExportError> {
    let options = SpineOptions {
        image_prefix: image_prefix(path),
        ..options.clone()
    };
    let layout = crate::write_new(path, |out| write_spine(animation, &options, progress, out))?;
    let atlas_path = path.with_extension("atlas");
    crate::write_new(&atlas_path, |out| {
        out.write_all(atlas(animation, &layout).as_bytes())
            .map_err(crate::io_error(&atlas_path))
    })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    for (p, placed) in animation.puppets.iter().zip(&layout.puppets) {
        let image = dir.join(format!("{}.png", placed.path));
        crate::write_new(&image, |out| {
            crate::write_png(out, p.image.width, p.image.height, &p.image.pixels).map_err(|e| {
                ExportError::File {
                    file: image.display().to_string(),
                    problem: format!("cannot encode PNG: {e}"),
                }
            })
        })?;
    }
    Ok(layout)
}

/// [`export_spine`] into one zip at `path` (`NAME.zip` holds `NAME.json`,
/// `NAME.atlas` and the pictures, side by side as the editor's Import Data
/// and spine-player want them): what a browser downloads as one file. The
/// files are made in a private folder, then packed (the JSON and atlas
/// deflated, the PNGs stored: they are compressed already) into a new file
/// ([`crate::write_new`]).
pub fn export_spine_zip(
    animation: &Animation,
    options: &SpineOptions,
    progress: &mut dyn Progress,
    path: &Path,
) -> Result<SpineLayout, ExportError> {
    let scratch = crate::Scratch::new()?;
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "take".into());
    let json = scratch.path().join(format!("{stem}.json"));
    let layout = export_spine(animation, options, progress, &json)?;
    let packed = files(animation, &json);
    crate::write_new(path, |out| {
        let zipped = |e: zip::result::ZipError| ExportError::File {
            file: path.display().to_string(),
            problem: format!("cannot write the zip: {e}"),
        };
        let mut zip = zip::ZipWriter::new_stream(out);
        for file in &packed {
            let name = file
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let method = if name.ends_with(".png") {
                zip::CompressionMethod::Stored
            } else {
                zip::CompressionMethod::Deflated
            };
            let options = zip::write::SimpleFileOptions::default()
                .compression_method(method)
                .unix_permissions(0o644);
            zip.start_file(name, options).map_err(zipped)?;
            let bytes = std::fs::read(file).map_err(crate::io_error(file))?;
            zip.write_all(&bytes).map_err(crate::io_error(path))?;
        }
        zip.finish().map_err(zipped)?;
        Ok(())
    })?;
    Ok(layout)
}
