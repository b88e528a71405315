//! Linux input devices (`/dev/input/event*`): finding them, saying what they
//! are, opening them (optionally grabbed, so the desktop does not also
//! react) and reading their raw events and current state. It owns device
//! discovery ([`scan`], [`probe`]), the matching of stage-file entries to
//! devices ([`DeviceMatch`]), the `EVIOCGMTSLOTS` read-back, and the
//! permission advice printed when a node is not readable.
//!
//! A regular file holding an evemu capture stands in for a device node: it
//! describes itself from its header, plays its events at their recorded pace
//! (then stays silent, like a device nobody touches) and answers state
//! read-backs from everything it has played, dropped events included — as
//! the kernel does after `SYN_DROPPED`. Tests and rehearsals use that to run
//! the same reader, decoder and hot-plug code as a real table.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde::Deserialize;

use super::evdev::{
    ABS_MAX, ABS_MT_POSITION_X, ABS_MT_POSITION_Y, ABS_MT_PRESSURE, ABS_MT_SLOT,
    ABS_MT_TRACKING_ID, ABS_X, ABS_Y, AbsAxes, AbsInfo, BTN_TOOL_PEN, BTN_TOUCH, DeviceState,
    EV_ABS, EV_KEY, EV_MAX, EV_REL, EV_SYN, InputEvent, KEY_MAX, MAX_SLOTS, SlotState,
};
use super::evemu::{EvemuDevice, EvemuError, EvemuFile, InputId};

/// Where Linux puts input device nodes.
pub const DEFAULT_DIR: &str = "/dev/input";

const REL_X: u16 = 0x00;
const REL_Y: u16 = 0x01;
const REL_MAX: u16 = 0x0f;
const BTN_LEFT: u16 = 0x110;
const INPUT_PROP_DIRECT: u16 = 0x01;

/// What to do when a node is not readable.
pub(crate) const PERMISSION_ADVICE: &str = "add your user to the `input` group \
(`sudo usermod -aG input $USER`, then log in again), or install a udev rule such as \
`SUBSYSTEM==\"input\", KERNEL==\"event*\", ATTRS{name}==\"<device name>\", MODE=\"0660\", GROUP=\"input\"` \
in /etc/udev/rules.d/70-puppetry.rules and run `sudo udevadm trigger`";

/// Why a device could not be listed, described, opened or read.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// The node is there but this user may not open it; the message says
    /// how to fix that (the `input` group or a udev rule).
    #[error("{path}: permission denied; {PERMISSION_ADVICE}")]
    PermissionDenied {
        /// The node.
        path: String,
    },
    /// Any other failure to open or read the node (it does not exist, say).
    #[error("{path}: {source}")]
    Io {
        /// The node.
        path: String,
        /// What the system said.
        source: io::Error,
    },
    /// A regular file standing in for a device is not a usable evemu
    /// capture.
    #[error(transparent)]
    Capture(#[from] EvemuError),
    /// The path is neither a regular file nor a node the evdev ioctls work
    /// on (a terminal or a hidraw node, say).
    #[error("{path}: not an input device node or evemu capture")]
    NotADevice {
        /// The path.
        path: String,
    },
    /// The device was unplugged (`ENODEV`, or its node was removed): a
    /// reader lifts its contacts and waits for it to come back.
    #[error("{path}: the device went away")]
    Gone {
        /// The node.
        path: String,
    },
    /// The device folder cannot be read.
    #[error("{dir}: cannot list devices: {source}")]
    List {
        /// The folder.
        dir: String,
        /// What the system said.
        source: io::Error,
    },
}

impl DeviceError {
    fn io(path: &Path, source: io::Error) -> DeviceError {
        let path = path.display().to_string();
        match source.kind() {
            io::ErrorKind::PermissionDenied => DeviceError::PermissionDenied { path },
            _ if source.raw_os_error() == Some(libc::ENODEV) => DeviceError::Gone { path },
            _ => DeviceError::Io { path, source },
        }
    }
}

/// What a device can report.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Capabilities {
    /// Key and button codes (`EV_KEY`): `BTN_TOUCH`, `BTN_TOOL_PEN`,
    /// `BTN_LEFT`, ….
    pub keys: BTreeSet<u16>,
    /// Relative axis codes (`EV_REL`): a mouse's motion and wheels.
    pub relative: BTreeSet<u16>,
    /// Absolute axes (`EV_ABS`) with their ranges: positions, pressure,
    /// tilt, slots.
    pub absolute: AbsAxes,
    /// `INPUT_PROP_DIRECT`: a touch screen or table (positions are on the
    /// display), as opposed to a touchpad.
    pub direct: bool,
}

/// How puppetry would use a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    /// Multi- or single-touch surface: contacts map through a calibration.
    Touch,
    /// Pen tablet: tip contact with pressure and tilt.
    Pen,
    /// Relative pointer: drives a cursor and holds a pair of points.
    Mouse,
    /// Nothing puppetry can use (keyboards, buttons, sensors).
    Other,
}

impl DeviceKind {
    /// Classifies a device by what it reports, first match winning: a pen
    /// tool with x/y is a pen (even on a tablet that also reports touch);
    /// multi-touch positions, or x/y with `BTN_TOUCH`, a touch surface; x/y
    /// motion with a left button a mouse; anything else other.
    pub fn of(caps: &Capabilities) -> DeviceKind {
        let abs = |code| caps.absolute.contains_key(&code);
        if caps.keys.contains(&BTN_TOOL_PEN) && abs(ABS_X) && abs(ABS_Y) {
            DeviceKind::Pen
        } else if (abs(ABS_MT_POSITION_X) && abs(ABS_MT_POSITION_Y))
            || (abs(ABS_X) && abs(ABS_Y) && caps.keys.contains(&BTN_TOUCH))
        {
            DeviceKind::Touch
        } else if caps.relative.contains(&REL_X)
            && caps.relative.contains(&REL_Y)
            && caps.keys.contains(&BTN_LEFT)
        {
            DeviceKind::Mouse
        } else {
            DeviceKind::Other
        }
    }
}

impl fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DeviceKind::Touch => "touch",
            DeviceKind::Pen => "pen",
            DeviceKind::Mouse => "mouse",
            DeviceKind::Other => "other",
        })
    }
}

/// Everything puppetry needs to know about a device before reading it.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    /// The node (or capture file) it was found at.
    pub path: PathBuf,
    /// The name the device gives itself, which a stage file's `name` must
    /// equal.
    pub name: String,
    /// Physical path (`usb-0000:00:14.0-2/input0`): tells identical devices
    /// apart, stably across restarts as long as they stay in their ports.
    pub phys: Option<String>,
    /// Unique id (often a serial number); `None` when the device reports
    /// none, and for captures.
    pub uniq: Option<String>,
    /// Bus, vendor, product and version ids.
    pub id: InputId,
    /// How puppetry would use it, from its capabilities.
    pub kind: DeviceKind,
    /// What it can report.
    pub capabilities: Capabilities,
    /// An evemu capture standing in for a node.
    pub capture: bool,
}

impl DeviceInfo {
    /// The description an evemu capture of this device starts with.
    pub fn evemu_header(&self) -> EvemuDevice {
        let bits = |codes: &mut dyn Iterator<Item = u16>, max: u16| {
            let mut bytes = vec![0u8; usize::from(max) / 8 + 1];
            for code in codes {
                if code <= max {
                    bytes[usize::from(code / 8)] |= 1 << (code % 8);
                }
            }
            bytes
        };
        let caps = &self.capabilities;
        let mut types = vec![EV_SYN];
        let mut event_bits = BTreeMap::new();
        if !caps.keys.is_empty() {
            types.push(EV_KEY);
            event_bits.insert(EV_KEY, bits(&mut caps.keys.iter().copied(), KEY_MAX));
        }
        if !caps.relative.is_empty() {
            types.push(EV_REL);
            event_bits.insert(EV_REL, bits(&mut caps.relative.iter().copied(), REL_MAX));
        }
        if !caps.absolute.is_empty() {
            types.push(EV_ABS);
            event_bits.insert(EV_ABS, bits(&mut caps.absolute.keys().copied(), ABS_MAX));
        }
        event_bits.insert(EV_SYN, bits(&mut types.into_iter(), EV_MAX));
        EvemuDevice {
            name: self.name.clone(),
            id: self.id,
            properties: vec![u8::from(caps.direct) << INPUT_PROP_DIRECT],
            event_bits,
            axes: caps.absolute.clone(),
        }
    }
}

/// Which device a stage-file entry means. Every given field must match;
/// `path` may be a stable symlink such as `/dev/input/by-path/…`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceMatch {
    /// The node; symlinks on either side are resolved before comparing.
    #[serde(default)]
    pub path: Option<PathBuf>,
    /// The device's name, exactly.
    #[serde(default)]
    pub name: Option<String>,
    /// Physical path, exactly: tells identical devices apart by port.
    #[serde(default)]
    pub phys: Option<String>,
    /// Unique id (a serial number), exactly.
    #[serde(default)]
    pub uniq: Option<String>,
    /// Vendor id; TOML takes hex too (`vendor = 0x0eef`).
    #[serde(default)]
    pub vendor: Option<u16>,
    /// Product id.
    #[serde(default)]
    pub product: Option<u16>,
}

impl DeviceMatch {
    /// Whether `info` is a device this entry means: every field given is
    /// equal; fields left out match anything.
    pub fn matches(&self, info: &DeviceInfo) -> bool {
        let same_path = |wanted: &PathBuf| {
            let resolve = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
            resolve(wanted) == resolve(&info.path)
        };
        self.path.as_ref().is_none_or(same_path)
            && self.name.as_ref().is_none_or(|n| *n == info.name)
            && self
                .phys
                .as_ref()
                .is_none_or(|p| info.phys.as_ref() == Some(p))
            && self
                .uniq
                .as_ref()
                .is_none_or(|u| info.uniq.as_ref() == Some(u))
            && self.vendor.is_none_or(|v| v == info.id.vendor)
            && self.product.is_none_or(|p| p == info.id.product)
    }
}

impl fmt::Display for DeviceMatch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts = Vec::new();
        if let Some(p) = &self.path {
            parts.push(format!("path {}", p.display()));
        }
        if let Some(n) = &self.name {
            parts.push(format!("name {n:?}"));
        }
        if let Some(p) = &self.phys {
            parts.push(format!("phys {p:?}"));
        }
        if let Some(u) = &self.uniq {
            parts.push(format!("uniq {u:?}"));
        }
        if let Some(v) = self.vendor {
            parts.push(format!("vendor {v:#06x}"));
        }
        if let Some(p) = self.product {
            parts.push(format!("product {p:#06x}"));
        }
        if parts.is_empty() {
            f.write_str("any device")
        } else {
            f.write_str(&parts.join(", "))
        }
    }
}

/// Describes the device at `path` without reading events.
pub fn probe(path: &Path) -> Result<DeviceInfo, DeviceError> {
    let metadata = std::fs::metadata(path).map_err(|e| DeviceError::io(path, e))?;
    if metadata.is_file() {
        let capture = EvemuFile::read(path)?;
        return Ok(capture_info(path, &capture));
    }
    let device = open_node(path)?;
    Ok(node_info(path, &device))
}

/// A folder entry and what it turned out to be.
pub(crate) type Scanned = (PathBuf, Result<DeviceInfo, DeviceError>);

/// Every `event*` entry in `dir`, in number order, each described or with
/// the reason it could not be (typically permissions).
pub fn scan(dir: &Path) -> Result<Vec<Scanned>, DeviceError> {
    let entries = std::fs::read_dir(dir).map_err(|source| DeviceError::List {
        dir: dir.display().to_string(),
        source,
    })?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| is_event_node_name(p))
        .collect();
    paths.sort_by_key(|p| node_number(p));
    Ok(paths
        .into_iter()
        .map(|p| {
            let info = probe(&p);
            (p, info)
        })
        .collect())
}

/// The first device in `dir` (or at the entry's `path`) that `wanted`
/// matches and is of `kind` (any usable kind when `None`).
pub(crate) fn find(
    dir: &Path,
    wanted: &DeviceMatch,
    kind: Option<DeviceKind>,
) -> Result<Option<DeviceInfo>, DeviceError> {
    let kind_ok = |info: &DeviceInfo| match kind {
        Some(k) => info.kind == k,
        None => info.kind != DeviceKind::Other,
    };
    if let Some(path) = &wanted.path {
        return match probe(path) {
            Ok(info) if wanted.matches(&info) && kind_ok(&info) => Ok(Some(info)),
            Ok(_) => Ok(None),
            Err(DeviceError::Io { source, .. }) if source.kind() == io::ErrorKind::NotFound => {
                Ok(None)
            }
            Err(e) => Err(e),
        };
    }
    let mut denied = None;
    for (_, info) in scan(dir)? {
        match info {
            Ok(info) if wanted.matches(&info) && kind_ok(&info) => return Ok(Some(info)),
            Ok(_) => {}
            // Remember it: if nothing readable matches, that is the answer.
            Err(e @ DeviceError::PermissionDenied { .. }) => denied = denied.or(Some(e)),
            Err(_) => {}
        }
    }
    denied.map_or(Ok(None), Err)
}

/// Kernel nodes are `eventN`; captures standing in for them may also be
/// any `*.event` file.
fn is_event_node_name(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with("event") || n.ends_with(".event"))
}

fn node_number(path: &Path) -> (u64, String) {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    let digits: String = name.chars().filter(|c| c.is_ascii_digit()).collect();
    (digits.parse().unwrap_or(u64::MAX), name.to_string())
}

fn capture_info(path: &Path, capture: &EvemuFile) -> DeviceInfo {
    let d = &capture.device;
    let codes = |ev_type: u16| -> BTreeSet<u16> {
        d.event_bits
            .get(&ev_type)
            .map(|bytes| {
                bytes
                    .iter()
                    .enumerate()
                    .flat_map(|(i, byte)| {
                        (0..8).filter_map(move |bit| {
                            (byte & (1 << bit) != 0).then_some((i * 8 + bit) as u16)
                        })
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    let capabilities = Capabilities {
        keys: codes(EV_KEY),
        relative: codes(EV_REL),
        absolute: d.axes.clone(),
        direct: d
            .properties
            .first()
            .is_some_and(|b| b & (1 << INPUT_PROP_DIRECT) != 0),
    };
    DeviceInfo {
        path: path.to_path_buf(),
        name: d.name.clone(),
        phys: None,
        uniq: None,
        id: d.id,
        kind: DeviceKind::of(&capabilities),
        capabilities,
        capture: true,
    }
}

fn open_node(path: &Path) -> Result<evdev::raw_stream::RawDevice, DeviceError> {
    evdev::raw_stream::RawDevice::open(path).map_err(|e| match e.raw_os_error() {
        Some(libc::ENOTTY | libc::EINVAL) => DeviceError::NotADevice {
            path: path.display().to_string(),
        },
        _ => DeviceError::io(path, e),
    })
}

fn node_info(path: &Path, device: &evdev::raw_stream::RawDevice) -> DeviceInfo {
    let keys = device
        .supported_keys()
        .map(|k| k.iter().map(|k| k.code()).collect())
        .unwrap_or_default();
    let relative = device
        .supported_relative_axes()
        .map(|r| r.iter().map(|r| r.0).collect())
        .unwrap_or_default();
    let absolute = device
        .get_absinfo()
        .map(|axes| {
            axes.map(|(code, info)| {
                (
                    code.0,
                    AbsInfo {
                        min: info.minimum(),
                        max: info.maximum(),
                        fuzz: info.fuzz(),
                        flat: info.flat(),
                        resolution: info.resolution(),
                    },
                )
            })
            .collect()
        })
        .unwrap_or_default();
    let capabilities = Capabilities {
        keys,
        relative,
        absolute,
        direct: device
            .properties()
            .contains(evdev::PropType(INPUT_PROP_DIRECT)),
    };
    let id = device.input_id();
    let text = |s: Option<&str>| s.filter(|s| !s.is_empty()).map(str::to_string);
    DeviceInfo {
        path: path.to_path_buf(),
        name: device.name().unwrap_or_default().to_string(),
        phys: text(device.physical_path()),
        uniq: text(device.unique_name()),
        id: InputId {
            bus: id.bus_type().0,
            vendor: id.vendor(),
            product: id.product(),
            version: id.version(),
        },
        kind: DeviceKind::of(&capabilities),
        capabilities,
        capture: false,
    }
}

/// An open device: a kernel node or a capture standing in for one.
pub struct Device {
    info: DeviceInfo,
    inner: Inner,
}

enum Inner {
    Node(evdev::raw_stream::EventStream),
    Capture(CapturePlayer),
}

impl Device {
    /// Opens the device at `path`; `grab` takes it exclusively (`EVIOCGRAB`),
    /// so the desktop does not also move its pointer.
    pub fn open(path: &Path, grab: bool) -> Result<Device, DeviceError> {
        let metadata = std::fs::metadata(path).map_err(|e| DeviceError::io(path, e))?;
        if metadata.is_file() {
            let capture = EvemuFile::read(path)?;
            let info = capture_info(path, &capture);
            return Ok(Device {
                info,
                inner: Inner::Capture(CapturePlayer::new(capture.events)),
            });
        }
        let mut device = open_node(path)?;
        let info = node_info(path, &device);
        if grab {
            device.grab().map_err(|e| DeviceError::io(path, e))?;
        }
        let stream = device
            .into_event_stream()
            .map_err(|e| DeviceError::io(path, e))?;
        Ok(Device {
            info,
            inner: Inner::Node(stream),
        })
    }

    /// What the device is, as read when it was opened.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// The next raw event; waits for it.
    pub(crate) async fn next_event(&mut self) -> Result<InputEvent, DeviceError> {
        match &mut self.inner {
            Inner::Node(stream) => {
                let event = stream
                    .next_event()
                    .await
                    .map_err(|e| DeviceError::io(&self.info.path, e))?;
                let time = event
                    .timestamp()
                    .duration_since(UNIX_EPOCH)
                    .unwrap_or_default()
                    .as_secs_f64();
                Ok(InputEvent::new(
                    time,
                    event.event_type().0,
                    event.code(),
                    event.value(),
                ))
            }
            Inner::Capture(player) => Ok(player.next_event().await),
        }
    }

    /// The device's state now, as the kernel holds it.
    pub(crate) fn state(&self) -> Result<DeviceState, DeviceError> {
        match &self.inner {
            Inner::Node(stream) => node_state(stream.device(), &self.info)
                .map_err(|e| DeviceError::io(&self.info.path, e)),
            Inner::Capture(player) => Ok(player.state(&self.info)),
        }
    }

    /// Seconds on the device's clock now, to stamp frames the reader makes
    /// itself (on open, after a drop, when the device goes away).
    pub(crate) fn now(&self) -> f64 {
        match &self.inner {
            Inner::Node(_) => SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .unwrap_or_default()
                .as_secs_f64(),
            Inner::Capture(player) => player.now(),
        }
    }
}

fn node_state(device: &evdev::raw_stream::RawDevice, info: &DeviceInfo) -> io::Result<DeviceState> {
    let keys = device.get_key_state()?.iter().map(|k| k.code()).collect();
    let abs: BTreeMap<u16, i32> = device
        .get_absinfo()?
        .map(|(code, info)| (code.0, info.value()))
        .collect();
    let slots = match info.capabilities.absolute.get(&ABS_MT_SLOT) {
        Some(axis) => {
            let count = (i64::from(axis.max) + 1).clamp(1, MAX_SLOTS as i64) as usize;
            let fd = std::os::fd::AsRawFd::as_raw_fd(device);
            let column = |code| read_mt_slots(fd, code, count);
            let ids = column(ABS_MT_TRACKING_ID)?;
            let xs = column(ABS_MT_POSITION_X)?;
            let ys = column(ABS_MT_POSITION_Y)?;
            let pressures = if info.capabilities.absolute.contains_key(&ABS_MT_PRESSURE) {
                Some(column(ABS_MT_PRESSURE)?)
            } else {
                None
            };
            (0..count)
                .map(|slot| SlotState {
                    slot,
                    tracking_id: ids[slot],
                    x: xs[slot],
                    y: ys[slot],
                    pressure: pressures.as_ref().map(|p| p[slot]),
                })
                .collect()
        }
        None => Vec::new(),
    };
    Ok(DeviceState { keys, abs, slots })
}

/// `EVIOCGMTSLOTS`: one axis's value in every slot. The kernel fills a
/// `struct input_mt_request_layout { __u32 code; __s32 values[n]; }`.
fn read_mt_slots(fd: std::os::fd::RawFd, code: u16, count: usize) -> io::Result<Vec<i32>> {
    let mut layout = vec![0i32; count + 1];
    layout[0] = i32::from(code);
    let bytes = layout.len() * std::mem::size_of::<i32>();
    // _IOC(_IOC_READ, 'E', 0x0a, bytes) on the generic ioctl layout.
    let request = (2u64 << 30) | ((bytes as u64) << 16) | (u64::from(b'E') << 8) | 0x0a;
    // SAFETY: the buffer is `bytes` long and the kernel writes at most that.
    let result = unsafe { libc::ioctl(fd, request as _, layout.as_mut_ptr()) };
    if result < 0 {
        return Err(io::Error::last_os_error());
    }
    layout.remove(0);
    Ok(layout)
}

/// Plays a capture as a device would deliver it, and keeps the state the
/// kernel would report. A `SYN_DROPPED` in the capture is delivered where it
/// stands; the reader must then discard the partial report that follows it
/// and read the state back, which includes that report, as the kernel's does.
struct CapturePlayer {
    events: Vec<InputEvent>,
    next: usize,
    started: Instant,
    keys: BTreeSet<u16>,
    abs: BTreeMap<u16, i32>,
    slots: BTreeMap<usize, BTreeMap<u16, i32>>,
    current_slot: usize,
}

impl CapturePlayer {
    fn new(events: Vec<InputEvent>) -> CapturePlayer {
        CapturePlayer {
            events,
            next: 0,
            started: Instant::now(),
            keys: BTreeSet::new(),
            abs: BTreeMap::new(),
            slots: BTreeMap::new(),
            current_slot: 0,
        }
    }

    fn first_time(&self) -> f64 {
        self.events.first().map_or(0.0, |e| e.time)
    }

    fn now(&self) -> f64 {
        self.first_time() + self.started.elapsed().as_secs_f64()
    }

    async fn next_event(&mut self) -> InputEvent {
        let Some(&event) = self.events.get(self.next) else {
            // A device nobody touches: silent until it goes away.
            return std::future::pending().await;
        };
        let due = Duration::from_secs_f64((event.time - self.first_time()).max(0.0));
        tokio::time::sleep_until((self.started + due).into()).await;
        self.next += 1;
        self.apply(&event);
        event
    }

    fn apply(&mut self, event: &InputEvent) {
        match event.ev_type {
            EV_KEY => {
                if event.value != 0 {
                    self.keys.insert(event.code);
                } else {
                    self.keys.remove(&event.code);
                }
            }
            EV_ABS => {
                if event.code == ABS_MT_SLOT {
                    self.current_slot = usize::try_from(event.value).unwrap_or(0);
                } else if event.code > ABS_MT_SLOT {
                    self.slots
                        .entry(self.current_slot)
                        .or_default()
                        .insert(event.code, event.value);
                }
                self.abs.insert(event.code, event.value);
            }
            _ => {}
        }
    }

    fn state(&self, info: &DeviceInfo) -> DeviceState {
        let mut abs = self.abs.clone();
        abs.insert(ABS_MT_SLOT, self.current_slot as i32);
        let slot_count = info.capabilities.absolute.get(&ABS_MT_SLOT).map_or(0, |a| {
            (i64::from(a.max) + 1).clamp(0, MAX_SLOTS as i64) as usize
        });
        let slots = (0..slot_count)
            .map(|slot| {
                let values = self.slots.get(&slot);
                let value = |code| values.and_then(|v| v.get(&code)).copied();
                SlotState {
                    slot,
                    tracking_id: value(ABS_MT_TRACKING_ID).unwrap_or(-1),
                    x: value(ABS_MT_POSITION_X).unwrap_or(0),
                    y: value(ABS_MT_POSITION_Y).unwrap_or(0),
                    pressure: value(ABS_MT_PRESSURE),
                }
            })
            .collect();
        DeviceState {
            keys: self.keys.clone(),
            abs,
            slots,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unreadable_node_says_what_to_do() {
        let denied = DeviceError::io(
            Path::new("/dev/input/event5"),
            io::Error::from(io::ErrorKind::PermissionDenied),
        );
        let text = denied.to_string();
        assert!(
            text.starts_with("/dev/input/event5: permission denied"),
            "{text}"
        );
        assert!(text.contains("usermod -aG input"), "{text}");
        assert!(text.contains("udev rule"), "{text}");
        let gone = DeviceError::io(
            Path::new("/dev/input/event5"),
            io::Error::from_raw_os_error(libc::ENODEV),
        );
        assert!(matches!(gone, DeviceError::Gone { .. }));
    }
}
