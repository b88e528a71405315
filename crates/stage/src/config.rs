//! The stage's part of a stage file (TOML, in `config/`): the stage's size
//! and listen address, the puppets on it and the keyframing pads. Parsed
//! with `deny_unknown_fields` so a misspelt key is an error naming it;
//! relative paths are resolved against the file's own folder. The same
//! file's input, access, OSC and relay sections are parsed by the layers
//! that own them (the daemon's `config::ShowConfig` assembles the whole).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use puppetry_mesh::FieldError;
pub use puppetry_mesh::numbers::{MAX_COORDINATE, MIN_SIZE};
use puppetry_mesh::numbers::{coordinates, exactly, pairs, some_pairs, within};
use serde::de::IgnoredAny;
use serde::{Deserialize, Serialize};

/// Why a stage file could not be used. Each names the file, and the field
/// where there is one, so the message says what to fix.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The stage file could not be opened or read.
    #[error("{file}: cannot read: {source}")]
    Read {
        /// The stage file, as named.
        file: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// Not a regular file, or past its size cap.
    #[error(transparent)]
    File(puppetry_mesh::file::FileError),
    /// Not TOML, or not the stage file's shape (a misspelt or unknown key,
    /// a value of the wrong type).
    #[error("{file}: {message}")]
    Syntax {
        /// The stage file, as named.
        file: String,
        /// The toml crate's message: several lines, with the line of the
        /// file and a `^` under the fault.
        message: String,
    },
    /// A value out of its range, a name used twice, a missing or unreadable
    /// file, a rig that contradicts itself…
    #[error(transparent)]
    Invalid(#[from] FieldError),
}

/// The stage's part of a stage file: `[stage]`, the puppets and the pads.
/// The same file's `[[input]]` (`puppetry_input::config`), `[access]`,
/// `[osc]` and `[relay]` sections belong to the layers that own them and
/// are parsed there from the same text (the daemon's `ShowConfig`): here
/// they are only let through, so the stage crate never builds a device or
/// network setting.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    /// `[stage]`: the stage's size and the server's listen settings.
    pub stage: StageSection,
    /// The `[[puppet]]` entries, in file order: puppet ids follow it, and
    /// the last starts on top.
    #[serde(default, rename = "puppet")]
    pub puppets: Vec<PuppetConfig>,
    /// Keyframing pads on input sources (spatial keyframing).
    #[serde(default, rename = "pad")]
    pub pads: Vec<PadConfig>,
    /// Other layers' sections, checked where they are parsed.
    #[serde(default, rename = "input")]
    _input: Option<IgnoredAny>,
    #[serde(default, rename = "access")]
    _access: Option<IgnoredAny>,
    #[serde(default, rename = "osc")]
    _osc: Option<IgnoredAny>,
    #[serde(default, rename = "relay")]
    _relay: Option<IgnoredAny>,
    /// Where the file was read from; relative paths are resolved against it.
    #[serde(skip)]
    pub folder: PathBuf,
    /// The file's name as given to [`StageConfig::parse`], for errors found
    /// after parsing (a rig the deformers refuse).
    #[serde(skip)]
    pub file: String,
}

/// `[stage]`: the stage's size, and where and how the server listens.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageSection {
    /// Stage size in stage units (y-up, origin bottom-left).
    pub width: f64,
    /// The stage's height in stage units (see `width`).
    pub height: f64,
    /// HTTP and WebSocket address; port 0 picks a free port. Written as
    /// `serve --listen` takes it ([`parse_listen`]).
    #[serde(default = "default_listen", deserialize_with = "listen_address")]
    pub listen: SocketAddr,
    /// Clients that stop reading are dropped after this many seconds.
    #[serde(default = "default_client_timeout")]
    pub client_timeout_s: f64,
    /// Open HTTP and WebSocket connections at most; past it a new one is
    /// answered 503 and closed.
    #[serde(default = "default_max_connections")]
    pub max_connections: usize,
}

fn default_max_connections() -> usize {
    1024
}

fn default_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 8080))
}

fn listen_address<'de, D: serde::Deserializer<'de>>(d: D) -> Result<SocketAddr, D::Error> {
    let text = String::deserialize(d)?;
    parse_listen(&text).map_err(serde::de::Error::custom)
}

/// Parses a listen address, in the stage file's `listen` and `serve
/// --listen` alike: an address (`127.0.0.1:8080`, `[::1]:8080`,
/// `0.0.0.0:8080`), a host name and port (`localhost:8080`, resolved; its
/// IPv4 address first, as browsers on this machine reach `localhost` by
/// either), or a bare port (on 127.0.0.1: this machine only, as the
/// default is).
pub fn parse_listen(text: &str) -> Result<SocketAddr, String> {
    let text = text.trim();
    if let Ok(address) = text.parse::<SocketAddr>() {
        return Ok(address);
    }
    if let Ok(port) = text.parse::<u16>() {
        return Ok(SocketAddr::from(([127, 0, 0, 1], port)));
    }
    let expected = "expected HOST:PORT (localhost:8080, 0.0.0.0:8080, [::1]:8080) or a port";
    let Some((host, port)) = text.rsplit_once(':').filter(|(h, _)| !h.is_empty()) else {
        return Err(format!("{text:?}: {expected}"));
    };
    let port: u16 = port
        .parse()
        .map_err(|_| format!("{text:?}: {port:?} is not a port (0 to 65535); {expected}"))?;
    let addresses: Vec<SocketAddr> = std::net::ToSocketAddrs::to_socket_addrs(&(host, port))
        .map_err(|e| format!("{text:?}: cannot resolve {host:?}: {e}"))?
        .collect();
    addresses
        .iter()
        .find(|a| a.is_ipv4())
        .or(addresses.first())
        .copied()
        .ok_or_else(|| format!("{text:?}: {host:?} resolves to no address"))
}

fn default_client_timeout() -> f64 {
    10.0
}

/// `#RRGGBB`.
pub fn is_colour(text: &str) -> bool {
    text.len() == 7 && text.starts_with('#') && text[1..].chars().all(|c| c.is_ascii_hexdigit())
}

/// One puppet: its picture and rest mesh (or, for a curve puppet, its
/// centre line), and where it stands on the stage.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PuppetConfig {
    /// Unique within the file; pads and key files name the puppet by it.
    pub name: String,
    /// The picture (PNG). A curve puppet's is optional: a texture run along
    /// its length (u along, v across), else the stroke is drawn in `colour`.
    #[serde(default)]
    pub image: PathBuf,
    /// The rest mesh file; none for a curve puppet.
    #[serde(default)]
    pub mesh: PathBuf,
    /// A curve puppet (`docs/curves.md`): a stroke along a centre line,
    /// deformed by as-rigid-as-possible curve editing with peeling.
    #[serde(default)]
    pub curve: Option<CurveConfig>,
    /// Stage position of the centre of the mesh's bounding box.
    #[serde(deserialize_with = "exactly")]
    pub at: [f64; 2],
    /// Stage units per mesh unit.
    #[serde(default = "one")]
    pub scale: f64,
    /// Pins that hold from the start, in the mesh's own coordinates.
    #[serde(default, deserialize_with = "pairs")]
    pub pins: Vec<[f64; 2]>,
    /// An lp-FFD grid rig (see `docs/rigs.md`); without `grid` or
    /// `skeleton` the puppet is free-form (ARAP).
    #[serde(default)]
    pub grid: Option<GridConfig>,
    /// A shape-aware skeleton rig.
    #[serde(default)]
    pub skeleton: Option<SkeletonConfig>,
    /// The puppet's key-pose file (spatial keyframing, `docs/keyframing.md`):
    /// loaded if it exists, written by `save_keys`.
    #[serde(default)]
    pub keys: Option<PathBuf>,
    /// Where `save_weights` writes: a new versioned file beside the mesh
    /// (`NAME.v1.mesh.json`, v2, …; the default) or over the mesh file.
    #[serde(default)]
    pub save_weights: SaveWeights,
    /// Depth where the puppet overlaps itself (`docs/depth.md`): `pieces`
    /// (the default) starts from the static order of its pieces and puts
    /// the part folded over in front; `off` draws triangles in mesh order.
    #[serde(default)]
    pub depth: DepthMode,
}

impl PuppetConfig {
    /// A puppet named `name` at `at` with every other setting at its
    /// default (no picture, mesh or rig yet): for puppets made at runtime.
    pub fn placed(name: String, at: [f64; 2]) -> PuppetConfig {
        PuppetConfig {
            name,
            image: PathBuf::new(),
            mesh: PathBuf::new(),
            curve: None,
            at,
            scale: 1.0,
            pins: Vec::new(),
            grid: None,
            skeleton: None,
            keys: None,
            save_weights: SaveWeights::default(),
            depth: DepthMode::default(),
        }
    }
}

/// `[puppet.curve]`: a curve puppet's centre line, in its own coordinates
/// (y up; an SVG path's y-down coordinates are flipped), and its stroke.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CurveConfig {
    /// The centre line as points…
    #[serde(default, deserialize_with = "some_pairs")]
    pub points: Option<Vec<[f64; 2]>>,
    /// …or as an SVG path's `d` (one open subpath: M, L, H, V, C, S, Q, T).
    #[serde(default)]
    pub svg: Option<String>,
    /// Stroke width (own units, scaled with the puppet).
    #[serde(default = "default_stroke_width")]
    pub width: f64,
    /// Stroke colour `#RRGGBB` when there is no `image`.
    #[serde(default = "default_stroke_colour")]
    pub colour: String,
    /// The centre line is resampled to evenly spaced points this far apart
    /// (own units; default: a third of the width, at least 1/2000 of the
    /// length).
    #[serde(default)]
    pub spacing: Option<f64>,
    /// Peeling: how fast the edited region grows along the curve with the
    /// drag distance (arc length per unit dragged).
    #[serde(default = "default_peel_rate")]
    pub peel_rate: f64,
    /// Peeling: the region's half-length (arc length) as the drag starts.
    #[serde(default)]
    pub peel_radius: f64,
}

fn default_stroke_width() -> f64 {
    12.0
}

fn default_stroke_colour() -> String {
    "#2b2b2b".into()
}

fn default_peel_rate() -> f64 {
    1.5
}

impl CurveConfig {
    /// The colour as RGB (checked when the stage file was read).
    pub fn rgb(&self) -> [u8; 3] {
        let channel = |k: usize| u8::from_str_radix(&self.colour[1 + 2 * k..3 + 2 * k], 16);
        [0, 1, 2].map(|k| channel(k).unwrap_or(0))
    }
}

/// Checks what can be checked of a puppet's curve without building it.
fn check_curve(p: &PuppetConfig) -> Result<(), (String, String)> {
    let Some(c) = &p.curve else {
        if p.image.as_os_str().is_empty() {
            return Err(("image".into(), "missing: a puppet needs a picture".into()));
        }
        if p.mesh.as_os_str().is_empty() {
            return Err((
                "mesh".into(),
                "missing: a puppet needs a mesh (or a [puppet.curve])".into(),
            ));
        }
        return Ok(());
    };
    let err = |field: &str, problem: &str| Err((format!("curve.{field}"), problem.to_string()));
    if !p.mesh.as_os_str().is_empty() {
        return Err((
            "mesh".into(),
            "a curve puppet's mesh is built from its curve: leave mesh out".into(),
        ));
    }
    if p.grid.is_some() || p.skeleton.is_some() {
        return Err((
            "curve".into(),
            "a puppet is a curve, a grid or a skeleton, not several".into(),
        ));
    }
    match (&c.points, &c.svg) {
        (Some(_), Some(_)) => return err("points", "give points or svg, not both"),
        (None, None) => return err("points", "missing: give points or svg"),
        _ => {}
    }
    let range = |field: &str, v: f64, lo: f64, hi: f64| {
        within(v, lo, hi).map_err(|problem| (format!("curve.{field}"), problem))
    };
    range("width", c.width, MIN_SIZE, MAX_COORDINATE)?;
    if !is_colour(&c.colour) {
        return err("colour", &format!("{:?} is not #RRGGBB", c.colour));
    }
    if let Some(points) = &c.points {
        coordinates(points.iter().flatten())
            .map_err(|(i, problem)| (format!("curve.points[{}][{}]", i / 2, i % 2), problem))?;
    }
    if let Some(spacing) = c.spacing {
        range("spacing", spacing, MIN_SIZE, MAX_COORDINATE)?;
        // The resampled centre line's points: its length over the
        // spacing (an SVG path measured along its segments' ends, which
        // is no longer than the curve).
        let line: Vec<[f64; 2]> = match (&c.points, &c.svg) {
            (Some(points), _) => points.clone(),
            (None, Some(d)) => puppetry_mesh::stroke::parse_svg_path(d, f64::MAX)
                .map(|p| p.iter().map(|v| v.to_array()).collect())
                .unwrap_or_default(),
            _ => Vec::new(),
        };
        let length: f64 = line
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum();
        if length / spacing > MAX_CURVE_SAMPLES {
            return Err((
                "curve.spacing".into(),
                format!(
                    "{spacing} along a curve {length:.1} long is more than \
                     {MAX_CURVE_SAMPLES} points: space them wider"
                ),
            ));
        }
    }
    range("peel_rate", c.peel_rate, 0.0, 1e6)?;
    range("peel_radius", c.peel_radius, 0.0, MAX_COORDINATE)?;
    Ok(())
}

/// `depth` of a puppet.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthMode {
    /// Static order by piece, adjusted on overlap every frame.
    #[default]
    Pieces,
    /// No depth adjustment.
    Off,
}

/// Where `save_weights` writes a puppet's painted weights.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SaveWeights {
    /// A new file beside the mesh, the next free `NAME.vN.mesh.json`: the
    /// shared asset is never overwritten.
    #[default]
    Version,
    /// Over the mesh file itself.
    Overwrite,
}

/// `[[pad]]`: a rectangle of the stage where contacts (of one source, or
/// any) move a puppet's keyframing cursor instead of grabbing.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PadConfig {
    /// The puppet's name.
    pub puppet: String,
    /// Only this input source's contacts (default: any).
    #[serde(default)]
    pub source: Option<String>,
    /// `[x0, y0, x1, y1]` in stage coordinates: the pad's corners.
    #[serde(deserialize_with = "exactly")]
    pub area: [f64; 4],
}

fn one() -> f64 {
    1.0
}

/// `[puppet.grid]`: an M×N lp-FFD grid over the puppet's mesh. Weights left
/// out are the paper's (`puppetry_deform::LpParams::default`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GridConfig {
    /// Grid handles along x: 2 to [`MAX_GRID_SIDE`].
    pub columns: usize,
    /// Grid handles along y: 2 to [`MAX_GRID_SIDE`].
    pub rows: usize,
    /// How vertices blend the handles (default: `bernstein`).
    #[serde(default)]
    pub basis: BasisConfig,
    /// λ_ml, how strongly the shape is kept (0 is plain FFD; default 1).
    #[serde(default)]
    pub locality: Option<f64>,
    /// λ_mp, how hard held material points pull (default 100).
    #[serde(default)]
    pub vertex: Option<f64>,
    /// λ_gp, how hard held grid handles pull (default 100; must be
    /// positive).
    #[serde(default)]
    pub grid: Option<f64>,
    /// λ_gr, how hard handles no one holds are pulled back to rest
    /// (default 0.01; must be positive).
    #[serde(default)]
    pub regular: Option<f64>,
    /// Solver iterations per frame: 1 to [`MAX_ITERATIONS`] (default 4).
    #[serde(default)]
    pub iterations: Option<usize>,
}

/// `basis` of a `[puppet.grid]`: how each vertex follows the grid handles.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BasisConfig {
    /// Bernstein polynomials over the whole grid, as in the paper: smooth,
    /// and every handle moves every vertex. The default.
    #[default]
    Bernstein,
    /// Bilinear within the vertex's grid cell: each vertex follows only the
    /// four handles around it.
    Lattice,
}

/// `[puppet.skeleton]`: joints (mesh coordinates) and bones
/// (`[parent joint, child joint]`), how contacts drive them, and key poses.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SkeletonConfig {
    /// Joint positions, in the mesh's own coordinates.
    #[serde(deserialize_with = "pairs")]
    pub joints: Vec<[f64; 2]>,
    /// Bones as `[parent joint, child joint]` indices into `joints`.
    pub bones: Vec<[usize; 2]>,
    /// How contacts drive the skeleton (default: `free`).
    #[serde(default)]
    pub mode: SkeletonMode,
    /// Solver settings; those left out are the paper's.
    #[serde(default)]
    pub params: SkeletonParamsConfig,
    /// Named key poses that a `pose` request blends between.
    #[serde(default)]
    pub poses: Vec<KeyPoseConfig>,
}

/// How contacts drive a skeleton.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SkeletonMode {
    /// A contact drags the joint it landed on; the others stay.
    #[default]
    Free,
    /// A contact turns the bone ending at its joint about the parent joint
    /// (a root joint moves the whole skeleton); the chain below follows.
    Fk,
}

/// Overrides of `puppetry_deform::SkeletonParams::default()` (the paper's).
#[derive(Debug, Clone, PartialEq, Copy, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SkeletonParamsConfig {
    /// Stiffness factor of the triangles a bone crosses (default 100).
    #[serde(default)]
    pub bone_weight: Option<f64>,
    /// Weight of the joints' positions in the solve (default 100).
    #[serde(default)]
    pub joint_weight: Option<f64>,
    /// Shape-matching rounds per frame: 1 to [`MAX_ITERATIONS`] (default
    /// `puppetry_deform::skeleton::DEFAULT_ROUNDS`, 8).
    #[serde(default)]
    pub rounds: Option<usize>,
    /// How far from its bone a bone's virtual joint sits, over the bone's
    /// length: the scale across the bone (default 1).
    #[serde(default)]
    pub perpendicular_scale: Option<f64>,
    /// Start each frame from the previous frame's rotations (default
    /// false; overrides `bone_start`).
    #[serde(default)]
    pub warm_start: Option<bool>,
    /// Start each frame's triangles at the rotation of the nearest bone
    /// rather than the identity (default true).
    #[serde(default)]
    pub bone_start: Option<bool>,
}

/// A named key pose: the rest pose with some bones turned, or any of the
/// pose's parts given whole (`puppetry_deform::Pose`). Angles are degrees,
/// lengths and root positions mesh units / mesh coordinates.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct KeyPoseConfig {
    /// What a `pose` request calls it: not empty, unique within the
    /// skeleton.
    pub name: String,
    /// `[bone, degrees]` pairs: turn these bones (relative to their rest
    /// angle, or to `angles` if given) counter-clockwise.
    #[serde(default)]
    pub turn: Vec<(usize, f64)>,
    /// Every bone's angle: absolute for bones leaving a root joint, else
    /// relative to the parent bone.
    #[serde(default)]
    pub angles: Option<Vec<f64>>,
    /// Every bone's length.
    #[serde(default)]
    pub lengths: Option<Vec<f64>>,
    /// Every root joint's position (one per tree of the skeleton).
    #[serde(default, deserialize_with = "some_pairs")]
    pub roots: Option<Vec<[f64; 2]>>,
}

/// The longest `[stage].client_timeout_s`: an hour. A client silent that
/// long is gone; `Duration::from_secs_f64(1e20)` panicked.
pub const MAX_CLIENT_TIMEOUT_S: f64 = 3600.0;

/// Grid rig columns and rows at most (each way): a 64×64 lattice already
/// has 4,096 handles.
pub const MAX_GRID_SIDE: usize = 64;

/// Solver iterations and skeleton rounds at most, per frame.
pub const MAX_ITERATIONS: usize = 1000;

/// A curve puppet's centre line is resampled to at most this many points
/// (its length over its spacing): past it, every frame would solve a
/// curve longer than any screen shows.
pub const MAX_CURVE_SAMPLES: f64 = 20_000.0;

/// Connections (`max_connections`, `max_per_address`) at most.
pub const MAX_CONNECTIONS: usize = 1 << 20;

/// The rig sections' own checks (what the deformers check again on
/// registration is left to them, so their errors name it precisely).
fn check_rigs(i: usize, p: &PuppetConfig) -> Result<(), (String, String)> {
    if p.grid.is_some() && p.skeleton.is_some() {
        return Err((
            format!("puppet[{i}]"),
            "has both a grid and a skeleton; a puppet has one rig".into(),
        ));
    }
    if let Some(g) = &p.grid {
        let field = |f: &str| format!("puppet[{i}].grid.{f}");
        for (name, side) in [("columns", g.columns), ("rows", g.rows)] {
            if !(2..=MAX_GRID_SIDE).contains(&side) {
                return Err((
                    field(name),
                    format!("{side}: columns and rows must be 2 to {MAX_GRID_SIDE}"),
                ));
            }
        }
        for (name, value) in [
            ("locality", g.locality),
            ("vertex", g.vertex),
            ("grid", g.grid),
            ("regular", g.regular),
        ] {
            if let Some(v) = value {
                within(v, 0.0, 1e6).map_err(|problem| (field(name), problem))?;
            }
        }
        if let Some(n) = g.iterations
            && !(1..=MAX_ITERATIONS).contains(&n)
        {
            return Err((
                field("iterations"),
                format!("{n} is not 1 to {MAX_ITERATIONS}"),
            ));
        }
    }
    if let Some(s) = &p.skeleton {
        let field = |f: &str| format!("puppet[{i}].skeleton.{f}");
        if !p.pins.is_empty() {
            return Err((
                format!("puppet[{i}].pins"),
                "a skeleton puppet takes no pins (its joints are its handles)".into(),
            ));
        }
        coordinates(s.joints.iter().flatten())
            .map_err(|(j, problem)| (field(&format!("joints[{}][{}]", j / 2, j % 2)), problem))?;
        let params = &s.params;
        for (name, value) in [
            ("bone_weight", params.bone_weight),
            ("joint_weight", params.joint_weight),
            ("perpendicular_scale", params.perpendicular_scale),
        ] {
            if let Some(v) = value {
                within(v, 0.0, 1e6)
                    .map_err(|problem| (field(&format!("params.{name}")), problem))?;
            }
        }
        if let Some(n) = params.rounds
            && !(1..=MAX_ITERATIONS).contains(&n)
        {
            return Err((
                field("params.rounds"),
                format!("{n} is not 1 to {MAX_ITERATIONS}"),
            ));
        }
        for (k, pose) in s.poses.iter().enumerate() {
            let pose_field = |f: &str| field(&format!("poses[{k}].{f}"));
            if pose.name.is_empty() {
                return Err((pose_field("name"), "must not be empty".into()));
            }
            if s.poses[..k].iter().any(|q| q.name == pose.name) {
                return Err((pose_field("name"), "is used by another pose".into()));
            }
            // Degrees and lengths within a coordinate's range: a turn of
            // 1e20 degrees is no pose, and its sine is noise.
            let finite = pose
                .turn
                .iter()
                .all(|(_, d)| within(*d, -MAX_COORDINATE, MAX_COORDINATE).is_ok())
                && coordinates(pose.angles.iter().flatten()).is_ok()
                && pose
                    .lengths
                    .iter()
                    .flatten()
                    .all(|v| within(*v, 0.0, MAX_COORDINATE).is_ok())
                && coordinates(pose.roots.iter().flatten().flatten()).is_ok();
            if !finite {
                return Err((
                    pose_field("turn"),
                    format!(
                        "turns, angles, lengths and roots must be numbers within \
                         ±{MAX_COORDINATE} (lengths ≥ 0)"
                    ),
                ));
            }
        }
    }
    Ok(())
}

impl StageConfig {
    /// Reads and checks a stage file.
    pub fn load(path: &Path) -> Result<StageConfig, ConfigError> {
        let text = StageConfig::read_text(path)?;
        let folder = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let config = StageConfig::parse(&path.display().to_string(), &text, &folder)?;
        config.check_files()?;
        Ok(config)
    }

    /// A stage file's text, read as every named file is (a regular file
    /// within `MAX_STAGE_FILE_BYTES`): for the layers that parse their own
    /// sections of it.
    pub fn read_text(path: &Path) -> Result<String, ConfigError> {
        use puppetry_mesh::file::{self, FileError};
        file::read_text(path, file::STAGE_FILE).map_err(|e| match e {
            FileError::Io { file, source } => ConfigError::Read { file, source },
            other => ConfigError::File(other),
        })
    }

    /// Every picture and mesh file the stage file names can be
    /// read — a regular file within its size cap (`puppetry_limits::files`),
    /// so `/dev/zero` or a FIFO is refused here by name, before anything
    /// reads it — and pictures and meshes are what their keys say. A stage file
    /// copied elsewhere keeps its relative paths, which then point nowhere:
    /// the error says what the path became and that it is relative to the
    /// stage file's folder, not the working one. (Key files may be missing:
    /// `save_keys` creates them.)
    pub fn check_files(&self) -> Result<(), ConfigError> {
        use puppetry_mesh::file::{self, Cap};
        let mut named: Vec<(String, &'static str, &Path, Cap)> = Vec::new();
        for (i, p) in self.puppets.iter().enumerate() {
            for (key, path, cap) in [
                ("image", &p.image, file::PICTURE_FILE),
                ("mesh", &p.mesh, file::MESH_FILE),
            ] {
                if !path.as_os_str().is_empty() {
                    named.push((format!("puppet[{i}].{key}"), key, path, cap));
                }
            }
            // A key file may be missing (`save_keys` makes it), not be
            // something else.
            if let Some(keys) = &p.keys {
                let resolved = self.resolve(keys);
                match file::open(&resolved, file::KEYS_FILE) {
                    Err(e) if e.io_kind() != Some(std::io::ErrorKind::NotFound) => {
                        return Err(ConfigError::Invalid(FieldError::new(
                            &self.file,
                            format!("puppet[{i}].keys"),
                            e.to_string(),
                        )));
                    }
                    _ => {}
                }
            }
        }
        for (field, key, path, cap) in named {
            self.check_file(field, key, path, cap)?;
        }
        Ok(())
    }

    /// One file the stage file names at `field` (its key `key`: `image`,
    /// `mesh`, `file`…) is a regular file within `cap` that can be read,
    /// and of the kind its key says; the error says where a relative path
    /// led. Other layers check the files of their own sections with it (a
    /// replay input's `file`).
    pub fn check_file(
        &self,
        field: String,
        key: &'static str,
        path: &Path,
        cap: puppetry_mesh::file::Cap,
    ) -> Result<(), ConfigError> {
        let problem = match head_of(&self.resolve(path), cap) {
            Err(HeadError::File(e)) => {
                return Err(ConfigError::Invalid(FieldError::new(
                    &self.file,
                    field,
                    e.to_string(),
                )));
            }
            Err(HeadError::Io(e)) => Err(e),
            Ok(head) => Ok(head),
        };
        let problem = match problem {
            Ok(head) => match wrong_kind(key, picture_kind(&head)) {
                Some(problem) => format!("{}: {problem}", path.display()),
                None => return Ok(()),
            },
            Err(error) if path.is_absolute() => {
                format!("{}: cannot read: {error}", path.display())
            }
            Err(error) => {
                let folder = absolute(&self.folder);
                format!(
                    "{}: cannot read {}: {error} (paths in a stage file are relative \
                     to the stage file's folder, {})",
                    path.display(),
                    tidy(&folder.join(path)).display(),
                    folder.display()
                )
            }
        };
        Err(ConfigError::Invalid(FieldError::new(
            &self.file, field, problem,
        )))
    }

    /// Parses stage TOML; `file` names it in errors, `folder` anchors its
    /// relative paths.
    pub fn parse(file: &str, text: &str, folder: &Path) -> Result<StageConfig, ConfigError> {
        // The toml crate's message is several lines: the line of the file
        // and a `^` under the fault. Kept whole, so the marker still points.
        let mut config: StageConfig = toml::from_str(text).map_err(|e| ConfigError::Syntax {
            file: file.to_string(),
            message: e.to_string().trim_end().to_string(),
        })?;
        config.folder = folder.to_path_buf();
        config.file = file.to_string();
        let invalid = |field: String, problem: &str| {
            ConfigError::Invalid(FieldError::new(file, field, problem))
        };
        let range = |field: String, v: f64, lo: f64, hi: f64| {
            within(v, lo, hi).map_err(|problem| invalid(field, &problem))
        };
        let s = &config.stage;
        for (name, v) in [("width", s.width), ("height", s.height)] {
            within(v, MIN_SIZE, MAX_COORDINATE).map_err(|problem| {
                invalid(
                    "stage".into(),
                    &format!("{name}: width and height must be positive numbers: {problem}"),
                )
            })?;
        }
        range(
            "stage.client_timeout_s".into(),
            s.client_timeout_s,
            MIN_SIZE,
            MAX_CLIENT_TIMEOUT_S,
        )?;
        if !(1..=MAX_CONNECTIONS).contains(&s.max_connections) {
            return Err(invalid(
                "stage.max_connections".into(),
                &format!("must be 1 to {MAX_CONNECTIONS}"),
            ));
        }
        for (i, p) in config.puppets.iter().enumerate() {
            range(format!("puppet[{i}].scale"), p.scale, MIN_SIZE, 1e3)?;
            coordinates(&p.at)
                .map_err(|(k, problem)| invalid(format!("puppet[{i}].at[{k}]"), &problem))?;
            coordinates(p.pins.iter().flatten()).map_err(|(k, problem)| {
                invalid(format!("puppet[{i}].pins[{}][{}]", k / 2, k % 2), &problem)
            })?;
            if config.puppets[..i].iter().any(|q| q.name == p.name) {
                return Err(invalid(
                    format!("puppet[{i}].name"),
                    "is used by another puppet",
                ));
            }
            check_curve(p)
                .map_err(|(field, problem)| invalid(format!("puppet[{i}].{field}"), &problem))?;
            check_rigs(i, p).map_err(|(field, problem)| invalid(field, &problem))?;
        }
        for (i, pad) in config.pads.iter().enumerate() {
            if !config.puppets.iter().any(|p| p.name == pad.puppet) {
                return Err(invalid(
                    format!("pad[{i}].puppet"),
                    &format!("no puppet is named {:?}", pad.puppet),
                ));
            }
            let [x0, y0, x1, y1] = pad.area;
            if coordinates(&pad.area).is_err() || x0 == x1 || y0 == y1 {
                return Err(invalid(
                    format!("pad[{i}].area"),
                    "must be [x0, y0, x1, y1], finite, with some width and height",
                ));
            }
        }
        Ok(config)
    }

    /// A path from the file, resolved against the file's folder.
    pub fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.folder.join(path)
        }
    }
}

/// What kind of picture (or document) a file beginning with `head` is —
/// "a PNG picture", "a JPEG picture", … — for errors about a file given
/// where another kind was expected; None for anything else (text, JSON).
/// Eight signatures, written out rather than a dependency.
pub fn picture_kind(head: &[u8]) -> Option<&'static str> {
    const SIGNATURES: &[(&[u8], &str)] = &[
        (b"\x89PNG\r\n\x1a\n", "a PNG picture"),
        (b"\xff\xd8\xff", "a JPEG picture"),
        (b"GIF87a", "a GIF picture"),
        (b"GIF89a", "a GIF picture"),
        (b"II*\0", "a TIFF picture"),
        (b"MM\0*", "a TIFF picture"),
        (b"BM", "a BMP picture"),
        (b"%PDF", "a PDF document"),
    ];
    // RIFF and ISO media files name their kind after a size field.
    if head.len() >= 12 && &head[..4] == b"RIFF" && &head[8..12] == b"WEBP" {
        return Some("a WebP picture");
    }
    if head.len() >= 12 && &head[4..8] == b"ftyp" {
        match &head[8..12] {
            b"avif" | b"avis" => return Some("an AVIF picture"),
            b"heic" | b"heix" | b"mif1" | b"msf1" => return Some("a HEIF picture"),
            _ => {}
        }
    }
    SIGNATURES
        .iter()
        .find(|(signature, _)| head.starts_with(signature))
        .map(|(_, kind)| *kind)
}

/// What is wrong with a file of `kind` given for a puppet's `image` or
/// `mesh`; None when it may be right.
fn wrong_kind(key: &str, kind: Option<&str>) -> Option<String> {
    match (key, kind) {
        ("image", Some(kind)) if kind != "a PNG picture" => Some(format!(
            "this is {kind}; a puppet's picture must be a PNG (with a transparent background)"
        )),
        ("mesh", Some(kind)) => Some(format!(
            "this is {kind}; a puppet's mesh is a .mesh.json file (`puppetry mesh \
             PICTURE.png -o NAME.mesh.json` makes one)"
        )),
        _ => None,
    }
}

/// Why [`head_of`] read nothing: the file could not be opened (`Io`, told
/// with where a relative path led) or is not a file to read at all (`File`:
/// not a regular file, or past its cap).
enum HeadError {
    Io(std::io::Error),
    File(puppetry_mesh::file::FileError),
}

/// The first bytes of a file (fewer if it is shorter), for [`picture_kind`],
/// once it is known to be a regular file within `cap`.
fn head_of(path: &Path, cap: puppetry_mesh::file::Cap) -> Result<Vec<u8>, HeadError> {
    use puppetry_mesh::file::{self, FileError};
    use std::io::Read;
    let handle = file::open(path, cap).map_err(|e| match e {
        FileError::Io { source, .. } => HeadError::Io(source),
        other => HeadError::File(other),
    })?;
    let mut head = Vec::with_capacity(16);
    handle
        .take(16)
        .read_to_end(&mut head)
        .map_err(HeadError::Io)?;
    Ok(head)
}

/// `path` made absolute against the working folder (as given when that
/// cannot be read), for messages a person acts on.
fn absolute(path: &Path) -> PathBuf {
    let path = if path.as_os_str().is_empty() {
        Path::new(".")
    } else {
        path
    };
    tidy(&std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()))
}

/// `path` without `.` and with each `..` taking back the folder before it,
/// as a person would write it (the file system is not asked: a message
/// only).
fn tidy(path: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for part in path.components() {
        match part {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push(part);
                }
            }
            other => out.push(other),
        }
    }
    out
}
