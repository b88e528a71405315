//! glTF 2.0 binary (`.glb`): per puppet its textured mesh and its motion,
//! which any glTF viewer or DCC tool plays.
//!
//! **The picture.** The puppet's picture is embedded as a PNG, sampled
//! `LINEAR`/`CLAMP_TO_EDGE` like the web renderer. The material is unlit
//! (`KHR_materials_unlit`: a 2D puppet shows its picture's exact colours,
//! not shaded as a surface), `alphaMode: BLEND` for its soft edges, and
//! double-sided, since a folded-over triangle shows its back. glTF's UV
//! origin is the picture's top-left corner, v down — the mesh's own `uv`
//! convention, so the coordinates go in unflipped.
//!
//! **Units and placement.** Positions are stage coordinates (x right, y
//! up, as glTF's y-up): one stage unit is one glTF unit ("metre").
//!
//! **Drawing order.** Puppets are nodes in drawing order, bottom first,
//! puppet `i` lifted to `z = i ×` [`z_step`] (a thousandth of the stage's
//! larger side): three.js sorts transparent meshes by depth and so draws
//! them in the stage's order, and a depth-buffered render (Blender) does
//! not z-fight. Where a puppet overlaps itself (`docs/depth.md`) its
//! triangles are listed back to front in each chunk's drawing order, and
//! a chunk ends where the order changes ([`spans`]), so a viewer drawing a
//! mesh's triangles in index order (three.js, with BLEND materials not
//! writing depth) shows the part in front in front, frame by frame. For a
//! renderer that depth-tests within one mesh (Blender), each vertex also
//! stands off the puppet's plane by its depth (see `Lift`), animated with
//! the frames, so the part in front is nearer.
//!
//! **A skeleton puppet is a skin**: a node per bone
//! under the puppet's node, parented as its skeleton, its mesh at rest
//! weighted to them (`JOINTS_0`, `WEIGHTS_0`, bound relative to the
//! puppet's node so its z step holds) and a translation and a rotation
//! channel per bone, keyed at every frame, fitted to the take by
//! [`crate::skin`] (within the error the export reports); what follows is
//! how the other puppets move.
//!
//! **The motion, in chunks of morph targets.** glTF animates vertices only
//! through morph targets: `POSITION = base + Σ wᵢ · targetᵢ`, with the
//! weights animated. The obvious layout — one target per frame, and a
//! weights track of one key per frame — needs `frame_count²` weights: a
//! 60 s take at 60 fps would be 3600² floats, 50 MB of mostly zeros, and
//! players evaluate every target each frame. So the frames are cut into
//! chunks of `M` frames (default 32): chunk `c` is a node with a mesh of its
//! own whose base `POSITION` is frame `cM` and whose targets are frames
//! `cM + 1 … cM + M` as offsets from it (the chunk's last frame is the next
//! chunk's first, so blending across the seam still works). Its weights
//! channel has a key at each of its frames' times `k / fps`, all zeros at
//! `cM` and a one-hot weight for target `k − cM` at `k`; with `LINEAR`
//! interpolation frame k is exact at `t = k / fps` and a time in between
//! blends the two neighbouring frames, exactly as sampling the frames
//! linearly would — except into a frame the take stepped into (a let-go,
//! [`crate::AnimatedPuppet::snaps`]): a key just before it holds the frame
//! before, so the snap is a step, as the page showed it. A `STEP` scale channel (1 while the chunk plays, 0
//! otherwise) shows each chunk's node only during its own chunk; at a seam
//! either chunk shows the same shared frame, so a player's rounding of the
//! switch time cannot show a wrong pose; the last chunk stays shown to
//! `frame_count / fps`, so a clip lasts as long as the take's video. Weights cost about M floats per
//! frame, the positions one vertex array per frame, and a player blends
//! only M targets. Without animation (a still viewer), chunk 0 shows frame 0
//! and the other chunks have scale 0.
//!
//! glTF keeps times as 32-bit floats, so "exact at `t = k / fps`" holds
//! to that precision: a player asked for `k / fps` lands within half a
//! float step of the key, about `k · 6e-8` of a frame interval, and shows
//! that fraction of the neighbouring frame's motion (at frame 3600, 2e-4
//! of one frame's movement). The weights and positions themselves are
//! exact 32-bit values.
//!
//! Every `POSITION` accessor, the morph targets' too, carries exact
//! `min`/`max`, as do the animation inputs; buffer views are aligned to 4
//! bytes. The file passes the Khronos glTF validator with no errors and no
//! warnings (test `glb_passes_the_khronos_validator`).

use std::io::Write;
use std::path::Path;

use serde_json::{Value, json};

use crate::{Animation, ExportError, Progress, flag};

/// Options of a glTF export.
#[derive(Debug, Clone, PartialEq)]
pub struct GltfOptions {
    /// Frames per chunk, `M` above (`--chunk`, 1 to 1024).
    pub chunk: usize,
    /// The animation's name.
    pub animation_name: String,
}

impl Default for GltfOptions {
    fn default() -> Self {
        GltfOptions {
            chunk: 32,
            animation_name: "take".into(),
        }
    }
}

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_INT: u32 = 5125;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// The file being assembled: its JSON arrays, and the binary chunk's
/// length so far. The bytes themselves go to `out` when there is one: the
/// file is laid out in a first pass without it (to learn the JSON, which
/// comes first in the file) and written in a second, so no more than one
/// chunk's vertex data is ever held.
struct Builder<'a> {
    length: usize,
    out: Option<&'a mut dyn Write>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl<'a> Builder<'a> {
    fn new(out: Option<&'a mut dyn Write>) -> Builder<'a> {
        Builder {
            length: 0,
            out,
            views: Vec::new(),
            accessors: Vec::new(),
        }
    }

    fn write(&mut self, bytes: &[u8]) -> Result<(), ExportError> {
        if let Some(out) = self.out.as_mut() {
            out.write_all(bytes).map_err(write_error)?;
        }
        self.length += bytes.len();
        Ok(())
    }

    /// Appends bytes as a new buffer view (aligned to 4); returns its index.
    fn view(
        &mut self,
        bytes: &[u8],
        target: Option<u32>,
        stride: Option<usize>,
    ) -> Result<usize, ExportError> {
        self.align()?;
        let mut v = json!({"buffer": 0, "byteOffset": self.length, "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.write(bytes)?;
        self.views.push(v);
        Ok(self.views.len() - 1)
    }

    fn align(&mut self) -> Result<(), ExportError> {
        let pad = self.length.next_multiple_of(4) - self.length;
        self.write(&[0; 3][..pad])
    }

    fn accessor(&mut self, a: Value) -> usize {
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A FLOAT accessor of `values` (grouped by `kind`: SCALAR, VEC2, VEC3)
    /// in a view of its own, with min/max when asked.
    fn floats(
        &mut self,
        values: &[f32],
        kind: &str,
        target: Option<u32>,
        bounds: bool,
    ) -> Result<usize, ExportError> {
        let width = components(kind);
        let view = self.view(&f32_bytes(values), target, None)?;
        let mut a = json!({
            "bufferView": view, "componentType": FLOAT,
            "count": values.len() / width, "type": kind,
        });
        if bounds {
            let (min, max) = min_max(values, width);
            a["min"] = json!(min);
            a["max"] = json!(max);
        }
        Ok(self.accessor(a))
    }
}

fn write_error(source: std::io::Error) -> ExportError {
    ExportError::Io {
        file: "glb output".into(),
        source,
    }
}

fn components(kind: &str) -> usize {
    match kind {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC4" => 4,
        "MAT4" => 16,
        _ => 3,
    }
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Per-component min and max of interleaved values.
fn min_max(values: &[f32], width: usize) -> (Vec<f32>, Vec<f32>) {
    let mut min = vec![f32::INFINITY; width];
    let mut max = vec![f32::NEG_INFINITY; width];
    for group in values.chunks_exact(width) {
        for (c, &v) in group.iter().enumerate() {
            min[c] = min[c].min(v);
            max[c] = max[c].max(v);
        }
    }
    (min, max)
}

/// The frames of each chunk: `first..=last`. Consecutive chunks share a
/// frame (the seam); a one-frame animation has one chunk of one frame.
pub fn chunks(frame_count: usize, chunk: usize) -> Vec<(usize, usize)> {
    if frame_count <= 1 {
        return vec![(0, 0)];
    }
    let last = frame_count - 1;
    (0..last.div_ceil(chunk))
        .map(|c| (c * chunk, ((c + 1) * chunk).min(last)))
        .collect()
}

/// [`chunks`] of a puppet whose drawing order changes (`draw_orders`, one
/// per frame; empty: mesh order throughout), cut further where it does:
/// every frame a chunk shows (its first up to, not including, its last,
/// which the next chunk shows) has the chunk's first frame's order, so the
/// chunk's triangles can be listed in it. A last frame whose order is
/// not its chunk's gets a chunk of its own.
pub fn spans(
    frame_count: usize,
    chunk: usize,
    draw_orders: &[std::sync::Arc<[u32]>],
) -> Vec<(usize, usize)> {
    if draw_orders.is_empty() {
        return chunks(frame_count, chunk);
    }
    if frame_count <= 1 {
        return vec![(0, 0)];
    }
    let last = frame_count - 1;
    let mut spans = Vec::new();
    let mut first = 0;
    while first < last {
        let mut end = (first + chunk).min(last);
        if let Some(j) = (first + 1..end).find(|&j| draw_orders[j] != draw_orders[first]) {
            end = j;
        }
        spans.push((first, end));
        first = end;
    }
    // The last frame is its chunk's last, shown by no next chunk: a chunk
    // of its own where its order is not the chunk's.
    if spans
        .last()
        .is_some_and(|&(first, _)| draw_orders[last] != draw_orders[first])
    {
        spans.push((last, last));
    }
    spans
}

/// How far apart puppets lie in z: puppet `i` in drawing order (0 at the
/// bottom) is at `z = i × step`, a thousandth of the stage's larger side,
/// so a viewer that sorts transparent meshes by depth (three.js) draws
/// them in the stage's order, and one with a depth buffer (Blender) does
/// not z-fight, while the stage still looks flat.
pub fn z_step(animation: &Animation) -> f64 {
    animation.stage_width.max(animation.stage_height) / 1000.0
}

/// Where a puppet overlaps itself, how far each vertex stands off its
/// puppet's plane: a renderer that depth-tests within a mesh (Blender's
/// Eevee and Cycles) sees the part in front in front, where at one z it
/// mixed the arm and the body. A vertex rises with the nearest triangle
/// it belongs to, by its depth (`docs/depth.md`) over the take's largest,
/// to at most half the puppets' z step, so it never reaches the puppet
/// above. (Where a triangle behind shares a vertex with one in front, it
/// tilts up towards it: at a fold's crease a depth-tested render may show
/// a sliver of it through.)
struct Lift {
    /// Stage units per depth; zero for a puppet drawn flat.
    per_depth: f32,
}

impl Lift {
    fn of(p: &crate::AnimatedPuppet, z_step: f64) -> Lift {
        let deepest = p
            .depths
            .iter()
            .flat_map(|d| d.iter().copied().max())
            .max()
            .unwrap_or(0);
        Lift {
            per_depth: if deepest == 0 {
                0.0
            } else {
                (z_step / 2.0 / f64::from(deepest)) as f32
            },
        }
    }

    /// Frame k's z per vertex into `z`.
    fn frame(&self, p: &crate::AnimatedPuppet, k: usize, z: &mut Vec<f32>) {
        z.clear();
        z.resize(p.vertex_count(), 0.0);
        let Some(depth) = p.depths.get(k).filter(|_| self.per_depth > 0.0) else {
            return;
        };
        for (t, tri) in p.triangles.iter().enumerate() {
            let h = f32::from(depth[t]) * self.per_depth;
            for &v in tri {
                z[v as usize] = z[v as usize].max(h);
            }
        }
    }
}

/// Writes `animation` as a `.glb` file at `path`. `progress` counts chunks.
/// The file is written beside `path` under a fresh name and renamed onto it
/// when whole ([`crate::write_new`]): a link at `path` is replaced, never
/// followed, and a failed export leaves nothing behind.
pub fn export_glb(
    animation: &Animation,
    options: &GltfOptions,
    progress: &mut dyn Progress,
    path: &Path,
) -> Result<(), ExportError> {
    crate::write_new(path, |out| write_glb(animation, options, progress, out))
}

/// Writes `animation` as glTF binary to `out` (see the module's doc), in
/// two passes over the frames: the first lays the file out (the JSON chunk,
/// which precedes the vertex data, needs every accessor's bounds), the
/// second writes the vertex data a chunk at a time. `progress` counts the
/// second pass's chunks.
pub fn write_glb(
    animation: &Animation,
    options: &GltfOptions,
    progress: &mut dyn Progress,
    out: &mut dyn Write,
) -> Result<(), ExportError> {
    animation.validate()?;
    if !(1..=1024).contains(&options.chunk) {
        return Err(flag(
            "--chunk",
            format!("must be 1 to 1024 frames, got {}", options.chunk),
        ));
    }
    let fps = animation.fps;
    let times: Vec<f32> = (0..animation.frame_count)
        .map(|k| (k as f64 / fps) as f32)
        .collect();
    let end = animation.duration() as f32;
    if times.windows(2).any(|w| w[1] <= w[0]) || times.last().is_some_and(|&t| end <= t) {
        return Err(flag(
            "--fps",
            "the take is too long for glTF's 32-bit times at this frame rate",
        ));
    }
    // The pictures, encoded once for both passes.
    let mut pictures = Vec::with_capacity(animation.puppets.len());
    for (i, p) in animation.puppets.iter().enumerate() {
        let mut png = Vec::new();
        crate::write_png(&mut png, p.image.width, p.image.height, &p.image.pixels).map_err(
            |e| crate::invalid(format!("puppets[{i}] {:?}.image", p.name), e.to_string()),
        )?;
        pictures.push(png);
    }
    // Skeleton puppets' bones, fitted once for both passes.
    let skins: Vec<Option<crate::skin::Skin>> = animation
        .puppets
        .iter()
        .map(|p| p.skeleton.as_ref().map(|rest| crate::skin::fit(p, rest)))
        .collect();
    let pass = Pass {
        animation,
        options,
        times: &times,
        end,
        pictures: &pictures,
        skins: &skins,
    };

    let mut layout = Builder::new(None);
    let gltf = pass.run(&mut layout, &mut ())?;
    if layout.length > u32::MAX as usize - (1 << 24) {
        return Err(flag(
            "--to",
            format!(
                "the take makes {} MB of vertex data, more than a .glb holds (4 GB): export a shorter range",
                layout.length >> 20
            ),
        ));
    }
    let mut text = serde_json::to_vec(&gltf).expect("glTF JSON serialises");
    drop(gltf);
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let length = 12 + 8 + text.len() + 8 + layout.length;
    let mut header = Vec::with_capacity(20);
    header.extend_from_slice(b"glTF");
    header.extend_from_slice(&2u32.to_le_bytes());
    header.extend_from_slice(&(length as u32).to_le_bytes());
    header.extend_from_slice(&(text.len() as u32).to_le_bytes());
    header.extend_from_slice(b"JSON");
    out.write_all(&header).map_err(write_error)?;
    out.write_all(&text).map_err(write_error)?;
    drop(text);
    out.write_all(&(layout.length as u32).to_le_bytes())
        .map_err(write_error)?;
    out.write_all(b"BIN\0").map_err(write_error)?;

    let mut bin = Builder::new(Some(out));
    pass.run(&mut bin, progress)?;
    if bin.length != layout.length {
        return Err(crate::invalid(
            "glb output",
            format!(
                "the vertex data came to {} bytes where {} were laid out",
                bin.length, layout.length
            ),
        ));
    }
    Ok(())
}

/// One pass over the animation: what both the layout and the writing do.
struct Pass<'a> {
    animation: &'a Animation,
    options: &'a GltfOptions,
    /// Each frame's time, `k / fps`, as glTF keeps it.
    times: &'a [f32],
    /// The clip's end, `frame_count / fps`: the last frame is held to it.
    end: f32,
    /// Each puppet's picture as PNG.
    pictures: &'a [Vec<u8>],
    /// Each skeleton puppet's fitted bones (see `Pass::skinned`).
    skins: &'a [Option<crate::skin::Skin>],
}

/// The glTF JSON arrays a pass fills besides the builder's.
#[derive(Default)]
struct Arrays {
    images: Vec<Value>,
    textures: Vec<Value>,
    materials: Vec<Value>,
    meshes: Vec<Value>,
    nodes: Vec<Value>,
    scene_nodes: Vec<usize>,
    samplers: Vec<Value>,
    channels: Vec<Value>,
    skins: Vec<Value>,
}

impl Arrays {
    /// An animation channel moving `path` of node `node` through a
    /// sampler of `input` times and `output` values.
    fn animate(
        &mut self,
        node: usize,
        path: &str,
        input: usize,
        output: usize,
        interpolation: &str,
    ) {
        self.samplers
            .push(json!({"input": input, "output": output, "interpolation": interpolation}));
        self.channels.push(json!({
            "sampler": self.samplers.len() - 1,
            "target": {"node": node, "path": path},
        }));
    }
}

impl Pass<'_> {
    /// Lays out (and, with a builder that has an output, writes) the binary
    /// chunk; returns the file's JSON.
    fn run(&self, b: &mut Builder, progress: &mut dyn Progress) -> Result<Value, ExportError> {
        let animation = self.animation;
        let spans: Vec<Vec<(usize, usize)>> = animation
            .puppets
            .iter()
            .zip(self.skins)
            .map(|(p, skin)| match skin {
                // A skinned puppet is one mesh, one step.
                Some(_) => vec![(0, 0)],
                None => spans(animation.frame_count, self.options.chunk, &p.draw_orders),
            })
            .collect();
        let total = spans.iter().map(Vec::len).sum();
        let mut done = 0;
        let mut arrays = Arrays::default();
        for (i, p) in animation.puppets.iter().enumerate() {
            let uv = self.puppet(b, &mut arrays, i)?;
            if let (Some(skin), Some(rest)) = (&self.skins[i], &p.skeleton) {
                self.skinned(b, &mut arrays, i, uv, skin, rest)?;
                done += 1;
                progress.step(done, total);
                continue;
            }
            // One index accessor per drawing order the puppet takes.
            let mut orders: Vec<(Option<&std::sync::Arc<[u32]>>, usize)> = Vec::new();
            let mut children = Vec::new();
            for (c, &span) in spans[i].iter().enumerate() {
                let order = p.draw_orders.get(span.0);
                let indices = match orders.iter().find(|(o, _)| *o == order) {
                    Some(&(_, indices)) => indices,
                    None => {
                        let indices = self.indices(b, i, span.0)?;
                        orders.push((order, indices));
                        indices
                    }
                };
                let shown = Shown {
                    index: c,
                    last_chunk: c + 1 == spans[i].len(),
                };
                children.push(self.chunk(b, &mut arrays, i, span, shown, uv, indices)?);
                done += 1;
                progress.step(done, total);
            }
            let mut node = json!({"name": p.name, "children": children});
            if i > 0 {
                node["translation"] = json!([0.0, 0.0, i as f64 * z_step(animation)]);
            }
            arrays.nodes.push(node);
            arrays.scene_nodes.push(arrays.nodes.len() - 1);
        }
        b.align()?;
        let fps = animation.fps;
        let mut gltf = json!({
            "asset": {"version": "2.0", "generator": concat!("puppetry-export ", env!("CARGO_PKG_VERSION"))},
            "extensionsUsed": ["KHR_materials_unlit"],
            "scene": 0,
            "scenes": [{"name": "stage", "nodes": arrays.scene_nodes}],
            "nodes": arrays.nodes,
            "meshes": arrays.meshes,
            "materials": arrays.materials,
            "textures": arrays.textures,
            "images": arrays.images,
            "samplers": [{"magFilter": LINEAR, "minFilter": LINEAR, "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE}],
            "animations": [{"name": self.options.animation_name, "samplers": arrays.samplers, "channels": arrays.channels}],
            "accessors": std::mem::take(&mut b.accessors),
            "bufferViews": std::mem::take(&mut b.views),
            "buffers": [{"byteLength": b.length}],
            "extras": {"fps": fps, "frameCount": animation.frame_count,
                       "stage": {"width": animation.stage_width, "height": animation.stage_height}},
        });
        if !arrays.skins.is_empty() {
            gltf["skins"] = Value::Array(arrays.skins);
        }
        Ok(gltf)
    }

    /// Puppet `i`'s picture, texture and material, and what every chunk of
    /// it shares: its texture coordinates (accessor).
    fn puppet(&self, b: &mut Builder, arrays: &mut Arrays, i: usize) -> Result<usize, ExportError> {
        let p = &self.animation.puppets[i];
        let view = b.view(&self.pictures[i], None, None)?;
        arrays
            .images
            .push(json!({"bufferView": view, "mimeType": "image/png", "name": p.name}));
        arrays
            .textures
            .push(json!({"sampler": 0, "source": i, "name": p.name}));
        arrays.materials.push(json!({
            "name": p.name,
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": i},
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
            "alphaMode": "BLEND",
            "doubleSided": true,
            "extensions": {"KHR_materials_unlit": {}},
        }));
        let uv: Vec<f32> = p.uv.iter().flatten().copied().collect();
        b.floats(&uv, "VEC2", Some(ARRAY_BUFFER), false)
    }

    /// A skeleton puppet as a glTF skin: a node per bone under the
    /// puppet's node (parented as its skeleton, at rest), its mesh at rest
    /// weighted to them (`JOINTS_0`/`WEIGHTS_0`, bound at rest relative to
    /// the puppet's node, so its z step holds), and per bone a translation
    /// and a rotation channel keyed at every frame, fitted to the take by
    /// [`crate::skin`]. The mesh's node is a root of the scene, as glTF
    /// asks of skinned meshes.
    fn skinned(
        &self,
        b: &mut Builder,
        arrays: &mut Arrays,
        i: usize,
        uv: usize,
        skin: &crate::skin::Skin,
        rest: &crate::skin::SkeletonRest,
    ) -> Result<(), ExportError> {
        use crate::skin::local;
        let p = &self.animation.puppets[i];
        let order = rest.order();
        let base = arrays.nodes.len();
        // Joint j of the skin is bone order[j], node base + j.
        let mut joint = vec![0usize; rest.bones.len()];
        for (j, &bone) in order.iter().enumerate() {
            joint[bone] = j;
        }
        let quat = |angle: f64| {
            let (s, c) = (angle / 2.0).sin_cos();
            [0.0, 0.0, s as f32, c as f32]
        };
        for &bone in &order {
            let parent = rest.parents[bone];
            let (at, angle) = local(parent.map(|q| rest.frame(q)), rest.frame(bone));
            let children: Vec<usize> = (0..rest.bones.len())
                .filter(|&c| rest.parents[c] == Some(bone))
                .map(|c| base + joint[c])
                .collect();
            let mut node = json!({
                "name": format!("{}/{bone}", p.name),
                "translation": [at.x as f32, at.y as f32, 0.0],
                "rotation": quat(angle),
            });
            if !children.is_empty() {
                node["children"] = json!(children);
            }
            arrays.nodes.push(node);
        }
        let roots: Vec<usize> = order
            .iter()
            .filter(|&&bone| rest.parents[bone].is_none())
            .map(|&bone| base + joint[bone])
            .collect();
        let mut puppet_node = json!({"name": p.name, "children": roots});
        if i > 0 {
            puppet_node["translation"] = json!([0.0, 0.0, i as f64 * z_step(self.animation)]);
        }
        arrays.nodes.push(puppet_node);
        let puppet_index = arrays.nodes.len() - 1;
        arrays.scene_nodes.push(puppet_index);

        // The mesh at rest, weighted.
        let positions: Vec<f32> = rest
            .rest
            .iter()
            .flat_map(|q| [q.x as f32, q.y as f32, 0.0])
            .collect();
        let position = b.floats(&positions, "VEC3", Some(ARRAY_BUFFER), true)?;
        let wide = order.len() > usize::from(u8::MAX);
        let (mut joints, mut weights) = (Vec::new(), Vec::new());
        for w in &skin.weights {
            let mut four = [(0usize, 0.0f32); 4];
            for (slot, &(bone, weight)) in w.iter().take(4).enumerate() {
                four[slot] = (joint[bone], weight as f32);
            }
            // Normalised in 32 bits, as the validator checks them.
            let used = w.len().clamp(1, 4);
            let others: f32 = four[..used - 1].iter().map(|&(_, w)| w).sum();
            four[used - 1].1 = 1.0 - others;
            for (j, w) in four {
                if wide {
                    joints.extend((j as u16).to_le_bytes());
                } else {
                    joints.push(j as u8);
                }
                weights.push(w);
            }
        }
        let view = b.view(&joints, Some(ARRAY_BUFFER), None)?;
        let joints = b.accessor(json!({
            "bufferView": view,
            "componentType": if wide { UNSIGNED_SHORT } else { UNSIGNED_BYTE },
            "count": skin.weights.len(), "type": "VEC4",
        }));
        let weights = b.floats(&weights, "VEC4", Some(ARRAY_BUFFER), false)?;
        let indices = self.indices(b, i, 0)?;
        arrays.meshes.push(json!({
            "name": format!("{} skinned", p.name),
            "primitives": [{
                "attributes": {"POSITION": position, "TEXCOORD_0": uv, "JOINTS_0": joints, "WEIGHTS_0": weights},
                "indices": indices, "material": i, "mode": 4,
            }],
        }));
        // Bound at rest relative to the puppet's node: the inverse of each
        // bone's rest frame (column-major 4×4).
        let inverse_bind: Vec<f32> = order
            .iter()
            .flat_map(|&bone| {
                let (head, angle) = rest.frame(bone);
                let (s, c) = angle.sin_cos();
                // Rz(−θ) · T(−head).
                let tx = -(c * head.x + s * head.y);
                let ty = -(-s * head.x + c * head.y);
                [
                    c, -s, 0.0, 0.0, s, c, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, tx, ty, 0.0, 1.0,
                ]
                .map(|v| v as f32)
            })
            .collect();
        let inverse_bind = b.floats(&inverse_bind, "MAT4", None, false)?;
        let skins_so_far = arrays.skins.len();
        arrays.skins.push(json!({
            "name": p.name,
            "joints": (0..order.len()).map(|j| base + j).collect::<Vec<_>>(),
            "inverseBindMatrices": inverse_bind,
            "skeleton": puppet_index,
        }));
        arrays.nodes.push(json!({
            "name": format!("{} skinned", p.name),
            "mesh": arrays.meshes.len() - 1,
            "skin": skins_so_far,
        }));
        arrays.scene_nodes.push(arrays.nodes.len() - 1);

        self.bone_channels(b, arrays, skin, rest, &order, |bone| base + joint[bone])?;
        Ok(())
    }

    /// Each bone's translation and rotation channels: a key at every
    /// frame, the last held to the clip's end, rotations kept in one
    /// hemisphere so blending turns the short way. `node` is a bone's node.
    fn bone_channels(
        &self,
        b: &mut Builder,
        arrays: &mut Arrays,
        skin: &crate::skin::Skin,
        rest: &crate::skin::SkeletonRest,
        order: &[usize],
        node: impl Fn(usize) -> usize,
    ) -> Result<(), ExportError> {
        use crate::skin::local;
        let quat = |angle: f64| {
            let (s, c) = (angle / 2.0).sin_cos();
            [0.0, 0.0, s as f32, c as f32]
        };
        let n = self.animation.frame_count;
        let mut keys: Vec<f32> = self.times.to_vec();
        keys.push(self.end);
        let input = b.floats(&keys, "SCALAR", None, true)?;
        for &bone in order {
            let parent = rest.parents[bone];
            let (mut translation, mut rotation) = (Vec::new(), Vec::new());
            let mut last = [0.0f32, 0.0, 0.0, 1.0];
            for k in 0..=n {
                let (at, angle) = local(
                    parent.map(|q| skin.posed(rest, k, q)),
                    skin.posed(rest, k, bone),
                );
                translation.extend([at.x as f32, at.y as f32, 0.0]);
                // The same hemisphere as the last key, so blending between
                // keys turns the short way.
                let mut q = quat(angle);
                if q[2] * last[2] + q[3] * last[3] < 0.0 {
                    q = q.map(|v| -v);
                }
                last = q;
                rotation.extend(q);
            }
            for (path, values, kind) in [
                ("translation", translation, "VEC3"),
                ("rotation", rotation, "VEC4"),
            ] {
                let output = b.floats(&values, kind, None, false)?;
                arrays.animate(node(bone), path, input, output, "LINEAR");
            }
        }
        Ok(())
    }

    /// Puppet `i`'s triangles (an index accessor) in frame `k`'s drawing
    /// order, back to front: a viewer draws a mesh's triangles in index
    /// order, so where the puppet overlaps itself the part in front is
    /// drawn last, as on the stage.
    fn indices(&self, b: &mut Builder, i: usize, k: usize) -> Result<usize, ExportError> {
        let p = &self.animation.puppets[i];
        let n = p.vertex_count();
        let flat = p.triangles_drawn(k).flatten();
        let (bytes, component): (Vec<u8>, u32) = if n <= u16::MAX as usize {
            let v: Vec<u8> = flat.flat_map(|&i| (i as u16).to_le_bytes()).collect();
            (v, UNSIGNED_SHORT)
        } else {
            (flat.flat_map(|i| i.to_le_bytes()).collect(), UNSIGNED_INT)
        };
        let view = b.view(&bytes, Some(ELEMENT_ARRAY_BUFFER), None)?;
        let indices = b.accessor(json!({
            "bufferView": view, "componentType": component,
            "count": p.triangles.len() * 3, "type": "SCALAR",
        }));
        Ok(indices)
    }

    /// One chunk `first..=last` of puppet `i`: its mesh of morph targets,
    /// its node, and its weights and visibility channels; returns the node.
    #[allow(clippy::too_many_arguments)]
    fn chunk(
        &self,
        b: &mut Builder,
        arrays: &mut Arrays,
        i: usize,
        (first, last): (usize, usize),
        shown: Shown,
        uv: usize,
        indices: usize,
    ) -> Result<usize, ExportError> {
        let p = &self.animation.puppets[i];
        let n = p.vertex_count();
        let times = self.times;
        let targets = last - first;
        // Base frame and offsets, interleaved x, y, z per vertex, all in
        // one view with a stride of 12 (several accessors share it).
        let base = &p.frames[first];
        let lift = Lift::of(p, z_step(self.animation));
        let mut z = Vec::new();
        let mut z_base = Vec::new();
        lift.frame(p, first, &mut z_base);
        let mut values = Vec::with_capacity((targets + 1) * n * 3);
        values.extend(base.iter().zip(&z_base).flat_map(|(q, &h)| [q[0], q[1], h]));
        for k in first + 1..=last {
            lift.frame(p, k, &mut z);
            values.extend(
                p.frames[k]
                    .iter()
                    .zip(base)
                    .zip(z.iter().zip(&z_base))
                    .flat_map(|((q, o), (h, h0))| [q[0] - o[0], q[1] - o[1], h - h0]),
            );
        }
        let view = b.view(&f32_bytes(&values), Some(ARRAY_BUFFER), Some(12))?;
        let position = |j: usize, b: &mut Builder| {
            let (min, max) = min_max(&values[j * n * 3..(j + 1) * n * 3], 3);
            b.accessor(json!({
                "bufferView": view, "byteOffset": j * n * 12, "componentType": FLOAT,
                "count": n, "type": "VEC3", "min": min, "max": max,
            }))
        };
        let base = position(0, b);
        let target_list: Vec<Value> = (1..=targets)
            .map(|j| json!({"POSITION": position(j, b)}))
            .collect();
        let mut primitive = json!({
            "attributes": {"POSITION": base, "TEXCOORD_0": uv},
            "indices": indices, "material": i, "mode": 4,
        });
        let mut mesh = json!({"name": format!("{} frames {first}-{last}", p.name)});
        if targets > 0 {
            primitive["targets"] = Value::Array(target_list);
            mesh["weights"] = json!(vec![0.0; targets]);
            mesh["extras"] = json!({
                "targetNames": (first + 1..=last).map(|k| format!("frame {k}")).collect::<Vec<_>>()
            });
        }
        mesh["primitives"] = json!([primitive]);
        arrays.meshes.push(mesh);
        let node_index = arrays.nodes.len();
        let mut node = json!({
            "name": format!("{} frames {first}-{last}", p.name),
            "mesh": arrays.meshes.len() - 1,
        });
        if shown.index > 0 {
            node["scale"] = json!([0.0, 0.0, 0.0]);
        }
        arrays.nodes.push(node);

        // Weights: one key per frame of the chunk, one-hot (zeros first);
        // where the take stepped into a frame (a let-go), the frame before
        // is held until just before it instead of blending into it.
        if targets > 0 {
            let one_hot = |j: usize, w: &mut Vec<f32>| {
                let at = w.len();
                w.resize(at + targets, 0.0);
                if j > 0 {
                    w[at + j - 1] = 1.0;
                }
            };
            let (mut keys, mut w) = (Vec::new(), Vec::new());
            for j in 0..=targets {
                let k = first + j;
                if j > 0 && p.snaps_into(k) {
                    keys.push(just_before(times[k]));
                    one_hot(j - 1, &mut w);
                }
                keys.push(times[k]);
                one_hot(j, &mut w);
            }
            let input = b.floats(&keys, "SCALAR", None, true)?;
            let output = b.floats(&w, "SCALAR", None, false)?;
            arrays.animate(node_index, "weights", input, output, "LINEAR");
        }
        // Visibility: scale 1 from the chunk's first frame, 0 from the
        // next chunk's first frame on.
        let mut keys = Vec::new();
        let mut scales = Vec::new();
        if shown.index > 0 {
            keys.push(0.0);
            scales.extend([0.0; 3]);
        }
        keys.push(if shown.index > 0 {
            just_before(times[first])
        } else {
            times[first]
        });
        scales.extend([1.0; 3]);
        if shown.last_chunk {
            // The last frame is held for its frame's time: the clip lasts
            // n / fps like the take's video, not (n − 1) / fps.
            keys.push(self.end);
            scales.extend([1.0; 3]);
        } else {
            keys.push(just_before(times[last]));
            scales.extend([0.0; 3]);
        }
        let input = b.floats(&keys, "SCALAR", None, true)?;
        let output = b.floats(&scales, "VEC3", None, false)?;
        arrays.animate(node_index, "scale", input, output, "STEP");
        Ok(node_index)
    }
}

/// The 32-bit time one step before `t`: where a chunk hands over to the
/// next. A player asked for frame k at `k / fps` in double precision can
/// land a hair below the 32-bit key `k / fps` (0.1666…67 < 0.16666667f);
/// switching one step early shows frame k's own chunk, with frame k's
/// drawing order, at that instant. (Both chunks hold frame k's pose there.)
fn just_before(t: f32) -> f32 {
    if t > 0.0 {
        f32::from_bits(t.to_bits() - 1)
    } else {
        t
    }
}

/// Which chunk of its puppet a chunk is: the first is shown at the start,
/// the last stays shown at the end.
#[derive(Clone, Copy)]
struct Shown {
    index: usize,
    last_chunk: bool,
}
