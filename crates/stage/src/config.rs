//! The stage file (TOML, in `config/`): the stage's size and listen address,
//! access tokens, the puppets on it and the input sources. Parsed with
//! `deny_unknown_fields` so a misspelt key is an error naming it; relative
//! paths are resolved against the file's own folder.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::Deserialize;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: cannot read: {source}")]
    Read {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: {message}")]
    Syntax { file: String, message: String },
    #[error("{file}: {field}: {problem}")]
    Invalid {
        file: String,
        field: String,
        problem: String,
    },
}

/// A whole stage file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    pub stage: StageSection,
    #[serde(default)]
    pub access: Access,
    #[serde(default, rename = "puppet")]
    pub puppets: Vec<PuppetConfig>,
    #[serde(default, rename = "input")]
    pub inputs: Vec<InputConfig>,
    /// Keyframing pads on input sources (spatial keyframing).
    #[serde(default, rename = "pad")]
    pub pads: Vec<PadConfig>,
    /// Where the file was read from; relative paths are resolved against it.
    #[serde(skip)]
    pub folder: PathBuf,
    /// The file's name as given to [`StageConfig::parse`], for errors found
    /// after parsing (a rig the deformers refuse).
    #[serde(skip)]
    pub file: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageSection {
    /// Stage size in stage units (y-up, origin bottom-left).
    pub width: f64,
    pub height: f64,
    /// HTTP and WebSocket address; port 0 picks a free port.
    #[serde(default = "default_listen")]
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

fn default_client_timeout() -> f64 {
    10.0
}

/// Who may perform: a WebSocket client that says `role: performer` must
/// give one of these tokens.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Access {
    #[serde(default)]
    pub performer_tokens: Vec<String>,
}

/// One puppet: its picture and rest mesh, and where it stands on the stage.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PuppetConfig {
    pub name: String,
    pub image: PathBuf,
    pub mesh: PathBuf,
    /// Stage position of the centre of the mesh's bounding box.
    pub at: [f64; 2],
    /// Stage units per mesh unit.
    #[serde(default = "one")]
    pub scale: f64,
    /// Pins that hold from the start, in the mesh's own coordinates.
    #[serde(default)]
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
}

/// Where `save_weights` writes a puppet's painted weights.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
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
    pub area: [f64; 4],
}

fn one() -> f64 {
    1.0
}

/// `[puppet.grid]`: an M×N lp-FFD grid over the puppet's mesh. Weights left
/// out are the paper's (`puppetry_deform::LpParams::default`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridConfig {
    pub columns: usize,
    pub rows: usize,
    #[serde(default)]
    pub basis: BasisConfig,
    #[serde(default)]
    pub locality: Option<f64>,
    #[serde(default)]
    pub vertex: Option<f64>,
    #[serde(default)]
    pub grid: Option<f64>,
    #[serde(default)]
    pub regular: Option<f64>,
    #[serde(default)]
    pub iterations: Option<usize>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BasisConfig {
    #[default]
    Bernstein,
    Lattice,
}

/// `[puppet.skeleton]`: joints (mesh coordinates) and bones
/// (`[parent joint, child joint]`), how contacts drive them, and key poses.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkeletonConfig {
    pub joints: Vec<[f64; 2]>,
    pub bones: Vec<[usize; 2]>,
    #[serde(default)]
    pub mode: SkeletonMode,
    #[serde(default)]
    pub params: SkeletonParamsConfig,
    #[serde(default)]
    pub poses: Vec<KeyPoseConfig>,
}

/// How contacts drive a skeleton.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
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
#[derive(Debug, Clone, Copy, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkeletonParamsConfig {
    #[serde(default)]
    pub bone_weight: Option<f64>,
    #[serde(default)]
    pub joint_weight: Option<f64>,
    #[serde(default)]
    pub rounds: Option<usize>,
    #[serde(default)]
    pub perpendicular_scale: Option<f64>,
    #[serde(default)]
    pub warm_start: Option<bool>,
}

/// A named key pose: the rest pose with some bones turned, or any of the
/// pose's parts given whole (`puppetry_deform::Pose`). Angles are degrees,
/// lengths and root positions mesh units / mesh coordinates.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyPoseConfig {
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
    #[serde(default)]
    pub roots: Option<Vec<[f64; 2]>>,
}

/// An input source. Replay files stand in for devices.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
pub enum InputConfig {
    /// A recording (`.jsonl`, stage coordinates) or an evemu capture
    /// (`.event`, device coordinates fitted to the stage).
    Replay {
        file: PathBuf,
        /// The source's name, which owns its contacts' handles; default
        /// `replay:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Device to stage mapping for an evemu capture; default: the
        /// device's full axis ranges fitted to the stage. Recordings are
        /// already in stage coordinates and ignore it.
        #[serde(default)]
        calibration: Option<puppetry_input::CalibrationSpec>,
        #[serde(default)]
        pacing: PacingConfig,
        /// Play again from the start when the file ends.
        #[serde(default)]
        repeat: bool,
    },
    /// TUIO 1.1 (`/tuio/2Dcur`) and 2.0 (`/tuio2/ptr`) over UDP: touch
    /// tables, reacTIVision, TouchDesigner. Each TUIO source is its own
    /// input source (`tuio:NAME`, `tuio2:NAME`).
    Tuio {
        /// Where to receive; default 127.0.0.1:3333 (use 0.0.0.0:3333 to
        /// accept a table on the network).
        #[serde(default = "default_tuio_listen")]
        listen: SocketAddr,
        /// Normalised TUIO coordinates (0..1, y down) to stage; default:
        /// the unit square fitted to the stage, y flipped.
        #[serde(default)]
        calibration: Option<puppetry_input::CalibrationSpec>,
    },
    /// A serial pad (Arduino/Teensy-style): line CSV or SLIP-framed OSC at a
    /// baud rate (see `puppetry::input::serial`). If the port goes away the
    /// daemon lifts its contacts and reopens it every second.
    Serial {
        /// The port, e.g. `/dev/ttyACM0`.
        path: String,
        #[serde(default = "default_baud")]
        baud: u32,
        format: puppetry_input::serial::WireFormat,
        /// The source's name; default `serial:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Pad units to stage; default: pad units are stage units.
        #[serde(default)]
        calibration: Option<puppetry_input::CalibrationSpec>,
    },
    /// A touch table or screen (Linux evdev, multi-touch protocol A or B,
    /// or single touch). Reopened when it comes back after going away.
    // The device fields are repeated in `Pen` and `Mouse` rather than
    // shared with `#[serde(flatten)]`, which would silently turn off
    // `deny_unknown_fields`.
    Touch {
        /// Which device: any of `path`, `name`, `phys`, `uniq`, `vendor`,
        /// `product`, all of which must match; default: the first device of
        /// this kind. `puppetry devices` shows each device's values.
        #[serde(default)]
        device: puppetry_input::device::DeviceMatch,
        /// Where device nodes appear; default `/dev/input`.
        #[serde(default = "default_device_dir")]
        dir: PathBuf,
        /// The source's name; default `KIND:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Take the device exclusively (`EVIOCGRAB`) so the desktop does not
        /// also react to it.
        #[serde(default)]
        grab: bool,
        /// Device units to stage; default: the device's full range fitted
        /// to the stage.
        #[serde(default)]
        calibration: Option<puppetry_input::CalibrationSpec>,
    },
    /// A pen tablet (Linux evdev): the tip is a contact carrying pressure
    /// and tilt.
    Pen {
        /// Which device: any of `path`, `name`, `phys`, `uniq`, `vendor`,
        /// `product`, all of which must match; default: the first device of
        /// this kind. `puppetry devices` shows each device's values.
        #[serde(default)]
        device: puppetry_input::device::DeviceMatch,
        /// Where device nodes appear; default `/dev/input`.
        #[serde(default = "default_device_dir")]
        dir: PathBuf,
        /// The source's name; default `KIND:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Take the device exclusively (`EVIOCGRAB`) so the desktop does not
        /// also react to it.
        #[serde(default)]
        grab: bool,
        #[serde(default)]
        calibration: Option<puppetry_input::CalibrationSpec>,
    },
    /// A HID digitizer read through hidapi (hidraw on Linux): for touch
    /// devices without a kernel driver, and hosts without evdev. The report
    /// descriptor says where the contacts are; parallel and hybrid
    /// reporting both work, and the Input Mode feature is set to multi-touch.
    Hid {
        /// Which device: any of `path` (`/dev/hidraw3`), `vendor_id`,
        /// `product_id`, `serial`; default: the only touch digitizer.
        #[serde(default)]
        device: puppetry_input::hid::HidSelector,
        /// The source's name; default `hid:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Logical units to stage; default: the contacts' logical range
        /// fitted to the stage.
        #[serde(default)]
        calibration: Option<puppetry_input::CalibrationSpec>,
    },
    /// A mouse (Linux evdev) with its own cursor on the stage; it holds a
    /// pair of points: button-drag moves them, the wheel or a right-button
    /// drag rotates them.
    Mouse {
        /// Which device: any of `path`, `name`, `phys`, `uniq`, `vendor`,
        /// `product`, all of which must match; default: the first device of
        /// this kind. `puppetry devices` shows each device's values.
        #[serde(default)]
        device: puppetry_input::device::DeviceMatch,
        /// Where device nodes appear; default `/dev/input`.
        #[serde(default = "default_device_dir")]
        dir: PathBuf,
        /// The source's name; default `KIND:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Take the device exclusively (`EVIOCGRAB`) so the desktop does not
        /// also react to it.
        #[serde(default)]
        grab: bool,
        /// Stage units per mouse count; default 1.
        #[serde(default)]
        speed: Option<f64>,
        /// Hold a pair of points (default) or one.
        #[serde(default)]
        pair: Option<bool>,
        /// Distance between the pair's points, stage units; default a
        /// twelfth of the stage's smaller side.
        #[serde(default)]
        pair_spacing: Option<f64>,
        /// Rotation per wheel notch, degrees; default 15.
        #[serde(default)]
        rotate_step_deg: Option<f64>,
        /// Where the cursor starts, stage coordinates; default the centre.
        #[serde(default)]
        start: Option<[f64; 2]>,
    },
}

fn default_device_dir() -> PathBuf {
    PathBuf::from(puppetry_input::device::DEFAULT_DIR)
}

fn default_baud() -> u32 {
    115_200
}

fn default_tuio_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], puppetry_input::tuio::DEFAULT_PORT))
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PacingConfig {
    #[default]
    RealTime,
    AsFastAsPossible,
}

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
        if g.columns < 2 || g.rows < 2 {
            return Err((
                field("columns"),
                "columns and rows must be at least 2".into(),
            ));
        }
        for (name, value) in [
            ("locality", g.locality),
            ("vertex", g.vertex),
            ("grid", g.grid),
            ("regular", g.regular),
        ] {
            if let Some(v) = value
                && !(v.is_finite() && v >= 0.0)
            {
                return Err((field(name), "must be a finite number ≥ 0".into()));
            }
        }
        if g.iterations == Some(0) {
            return Err((field("iterations"), "must be at least 1".into()));
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
        if s.joints.iter().flatten().any(|v| !v.is_finite()) {
            return Err((field("joints"), "must be finite points".into()));
        }
        for (k, pose) in s.poses.iter().enumerate() {
            let pose_field = |f: &str| field(&format!("poses[{k}].{f}"));
            if pose.name.is_empty() {
                return Err((pose_field("name"), "must not be empty".into()));
            }
            if s.poses[..k].iter().any(|q| q.name == pose.name) {
                return Err((pose_field("name"), "is used by another pose".into()));
            }
            let finite = pose.turn.iter().all(|(_, d)| d.is_finite())
                && pose.angles.iter().flatten().all(|v| v.is_finite())
                && pose
                    .lengths
                    .iter()
                    .flatten()
                    .all(|v| v.is_finite() && *v >= 0.0)
                && pose.roots.iter().flatten().flatten().all(|v| v.is_finite());
            if !finite {
                return Err((
                    pose_field("turn"),
                    "angles, lengths and roots must be finite (lengths ≥ 0)".into(),
                ));
            }
        }
    }
    Ok(())
}

impl StageConfig {
    /// Reads and checks a stage file.
    pub fn load(path: &Path) -> Result<StageConfig, ConfigError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            file: file.clone(),
            source,
        })?;
        let folder = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        StageConfig::parse(&file, &text, &folder)
    }

    /// Parses stage TOML; `file` names it in errors, `folder` anchors its
    /// relative paths.
    pub fn parse(file: &str, text: &str, folder: &Path) -> Result<StageConfig, ConfigError> {
        let mut config: StageConfig = toml::from_str(text).map_err(|e| ConfigError::Syntax {
            file: file.to_string(),
            message: e.to_string().trim_end().replace('\n', " "),
        })?;
        config.folder = folder.to_path_buf();
        config.file = file.to_string();
        let invalid = |field: String, problem: &str| ConfigError::Invalid {
            file: file.to_string(),
            field,
            problem: problem.to_string(),
        };
        let s = &config.stage;
        if !(s.width.is_finite() && s.height.is_finite() && s.width > 0.0 && s.height > 0.0) {
            return Err(invalid(
                "stage".into(),
                "width and height must be positive numbers",
            ));
        }
        if !(s.client_timeout_s.is_finite() && s.client_timeout_s > 0.0) {
            return Err(invalid(
                "stage.client_timeout_s".into(),
                "must be a positive number of seconds",
            ));
        }
        if s.max_connections == 0 {
            return Err(invalid(
                "stage.max_connections".into(),
                "must be at least 1",
            ));
        }
        for (i, p) in config.puppets.iter().enumerate() {
            if !(p.scale.is_finite() && p.scale > 0.0) {
                return Err(invalid(
                    format!("puppet[{i}].scale"),
                    "must be a positive number",
                ));
            }
            if !p.at.iter().all(|v| v.is_finite()) {
                return Err(invalid(format!("puppet[{i}].at"), "must be finite"));
            }
            if config.puppets[..i].iter().any(|q| q.name == p.name) {
                return Err(invalid(
                    format!("puppet[{i}].name"),
                    "is used by another puppet",
                ));
            }
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
            if !pad.area.iter().all(|v| v.is_finite()) || x0 == x1 || y0 == y1 {
                return Err(invalid(
                    format!("pad[{i}].area"),
                    "must be [x0, y0, x1, y1], finite, with some width and height",
                ));
            }
        }
        if config.access.performer_tokens.iter().any(|t| t.is_empty()) {
            return Err(invalid(
                "access.performer_tokens".into(),
                "a token must not be empty",
            ));
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
