//! The `[[input]]` sections of a stage file: which devices, sockets and
//! files feed the stage, with their calibrations, as the daemon opens
//! them. Parsed from the same file as the stage (each layer reads its own
//! sections, `deny_unknown_fields` within each), so the stage crate never
//! sees a device setting.

use std::net::SocketAddr;
use std::path::PathBuf;

use puppetry_mesh::numbers::{MAX_COORDINATE, MIN_SIZE, coordinates, some_pair, within};
use serde::Deserialize;

/// Which show clock a MIDI input follows (`clock`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockSetting {
    /// MIDI Time Code: quarter frames and full frames.
    TimeCode,
    /// MIDI clock and song position, at the input's `tempo`.
    MidiClock,
}

impl ClockSetting {
    /// The clock `clock` and `tempo` ask for (none: the input follows no
    /// clock), or the field that is wrong and why.
    pub fn kind(
        clock: Option<ClockSetting>,
        tempo: Option<f64>,
    ) -> Result<Option<crate::show_clock::ClockKind>, (&'static str, String)> {
        use crate::show_clock::ClockKind;
        match (clock, tempo) {
            (Some(ClockSetting::MidiClock), Some(tempo)) if (1.0..=1000.0).contains(&tempo) => {
                Ok(Some(ClockKind::Beats { tempo }))
            }
            (Some(ClockSetting::MidiClock), Some(tempo)) => Err((
                "tempo",
                format!("{tempo} is not 1 to 1000 quarter notes a minute"),
            )),
            (Some(ClockSetting::MidiClock), None) => Err((
                "tempo",
                "clock = \"midi_clock\" counts beats: give the song's tempo (quarter notes \
                 a minute) to make them seconds"
                    .into(),
            )),
            (_, Some(_)) => Err(("tempo", "only clock = \"midi_clock\" reads a tempo".into())),
            (Some(ClockSetting::TimeCode), None) => Ok(Some(ClockKind::TimeCode)),
            (None, None) => Ok(None),
        }
    }
}

/// An input source. Replay files stand in for devices.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
pub enum InputConfig {
    /// A recording (`.jsonl`, stage coordinates) or an evemu capture
    /// (`.event`, device coordinates fitted to the stage).
    Replay {
        /// The file to play, relative to the stage file's folder. A
        /// hid-recorder capture (`.hid`) plays too, like an evemu one.
        file: PathBuf,
        /// The source's name, which owns its contacts' handles; default
        /// `replay:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Device to stage mapping for an evemu capture; default: the
        /// device's full axis ranges fitted to the stage. Recordings are
        /// already in stage coordinates and ignore it.
        #[serde(default)]
        calibration: Option<crate::CalibrationSpec>,
        /// How fast to play; default `real_time`, the recorded pace.
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
        calibration: Option<crate::CalibrationSpec>,
        /// Seconds a TUIO source may send nothing before what it holds is
        /// let go (a sender that died mid-touch); default 3
        /// ([`RELEASE_AFTER`](crate::tuio::RELEASE_AFTER)), 0.1 to 3600.
        #[serde(default)]
        release_after_s: Option<f64>,
    },
    /// A serial pad (Arduino/Teensy-style): line CSV or SLIP-framed OSC at a
    /// baud rate (see [`serial`](crate::serial)). If the port goes away the
    /// daemon lifts its contacts and reopens it every second.
    Serial {
        /// The port, e.g. `/dev/ttyACM0`.
        path: String,
        /// Bits per second, as the firmware sets them; default 115200, at
        /// most 20 000 000.
        #[serde(default = "default_baud")]
        baud: u32,
        /// What the firmware sends, `csv` or `slip_osc` (no default): see
        /// [`WireFormat`](crate::serial::WireFormat).
        format: crate::serial::WireFormat,
        /// The source's name; default `serial:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Pad units to stage; default: pad units are stage units.
        #[serde(default)]
        calibration: Option<crate::CalibrationSpec>,
        /// Seconds the pad may send nothing while a contact is down before
        /// its contacts are let go (firmware that hung with the port still
        /// open); default 5 ([`RELEASE_AFTER`](crate::serial::RELEASE_AFTER)),
        /// 0.1 to 3600. Firmware that holds a contact still sends an empty
        /// frame now and then to say it is alive.
        #[serde(default)]
        release_after_s: Option<f64>,
    },
    /// A touch table or screen (Linux evdev, multi-touch protocol A or B,
    /// or single touch). Reopened when it comes back after going away.
    Touch(EvdevInput),
    /// A pen tablet (Linux evdev): the tip is a contact carrying pressure
    /// and tilt. Reopened when it comes back after going away.
    Pen(EvdevInput),
    /// A HID digitizer read through hidapi (hidraw on Linux): for touch
    /// devices without a kernel driver, and hosts without evdev. The report
    /// descriptor says where the contacts are; parallel and hybrid
    /// reporting both work, and the Input Mode feature is set to multi-touch.
    Hid {
        /// Which device: any of `path` (`/dev/hidraw3`), `vendor_id`,
        /// `product_id`, `serial`; default: the only touch digitizer.
        #[serde(default)]
        device: crate::hid::HidSelector,
        /// The source's name; default `hid:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// Logical units to stage; default: the contacts' logical range
        /// fitted to the stage.
        #[serde(default)]
        calibration: Option<crate::CalibrationSpec>,
    },
    /// A MIDI controller or show-control desk: its messages mapped to what
    /// a show controller can ask of the stage (`map`), as OSC's triggers
    /// are. Read from a raw MIDI port (`path`: an ALSA
    /// `/dev/snd/midiC1D0`, a FIFO, a serial MIDI interface; reopened when
    /// it comes back), an ALSA sequencer port by name (`port`, in a build
    /// with the `alsa-seq` feature) or played from a Standard MIDI File
    /// (`file`).
    Midi {
        /// A raw MIDI byte stream to read.
        #[serde(default)]
        path: Option<PathBuf>,
        /// A raw MIDI port by its sound card's name, or part of it
        /// (`puppetry devices` shows them): found again whenever the card is
        /// plugged in, whatever number it gets.
        #[serde(default)]
        card: Option<String>,
        /// Where `card`'s device nodes are; default `/dev/snd`.
        #[serde(default)]
        dir: Option<PathBuf>,
        /// An ALSA sequencer port, by its name or part of it (`aconnect -i`
        /// lists them).
        #[serde(default)]
        port: Option<String>,
        /// A `.mid` to play instead, relative to the stage file's folder.
        #[serde(default)]
        file: Option<PathBuf>,
        /// Play `file` again from the start when it ends.
        #[serde(default)]
        repeat: bool,
        /// The input's name in logs; default `midi:N` for the N-th input.
        #[serde(default)]
        name: Option<String>,
        /// What each control does (`[[input.map]]`).
        #[serde(default)]
        map: Vec<crate::midi_map::MidiMapping>,
        /// Follow the show's clock this input carries (`time_code`: MIDI
        /// Time Code; `midi_clock`: MIDI clock and song position, with
        /// `tempo`): takes record it, exports line soundtracks up by it.
        #[serde(default)]
        clock: Option<ClockSetting>,
        /// Quarter notes a minute, for `clock = "midi_clock"` (a song
        /// whose tempo changes is followed by time code instead).
        #[serde(default)]
        tempo: Option<f64>,
    },
    /// A mouse (Linux evdev) with its own cursor on the stage; it holds a
    /// pair of points: button-drag moves them, the wheel or a right-button
    /// drag rotates them.
    // `device`, `dir`, `name` and `grab` are `EvdevInput`'s, written
    // again because serde's `flatten` would silently turn off
    // `deny_unknown_fields`.
    Mouse {
        /// Which device, as [`EvdevInput::device`]; default the first mouse.
        #[serde(default)]
        device: crate::device::DeviceMatch,
        /// As [`EvdevInput::dir`].
        #[serde(default = "default_device_dir")]
        dir: PathBuf,
        /// As [`EvdevInput::name`] (`mouse:N`).
        #[serde(default)]
        name: Option<String>,
        /// As [`EvdevInput::grab`].
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
        #[serde(default, deserialize_with = "some_pair")]
        start: Option<[f64; 2]>,
    },
}

/// An evdev device's section (`kind = "touch"` or `"pen"`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvdevInput {
    /// Which device: any of `path`, `name`, `phys`, `uniq`, `vendor`,
    /// `product`, all of which must match; default: the first device of
    /// this kind. `puppetry devices` shows each device's values.
    #[serde(default)]
    pub device: crate::device::DeviceMatch,
    /// Where device nodes appear; default `/dev/input`.
    #[serde(default = "default_device_dir")]
    pub dir: PathBuf,
    /// The source's name; default `KIND:N` for the N-th input.
    #[serde(default)]
    pub name: Option<String>,
    /// Take the device exclusively (`EVIOCGRAB`) so the desktop does not
    /// also react to it.
    #[serde(default)]
    pub grab: bool,
    /// Device units to stage; default: the device's full range fitted
    /// to the stage.
    #[serde(default)]
    pub calibration: Option<crate::CalibrationSpec>,
}

fn default_device_dir() -> PathBuf {
    PathBuf::from(crate::device::DEFAULT_DIR)
}

fn default_baud() -> u32 {
    115_200
}

fn default_tuio_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], crate::tuio::DEFAULT_PORT))
}

/// A replay input's `pacing` as the stage file spells it; the daemon turns
/// it into a [`Pacing`](crate::replay::Pacing).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PacingConfig {
    /// `real_time` (the default): each frame as long after the first as the
    /// file's timestamps say.
    #[default]
    RealTime,
    /// `as_fast_as_possible`: each frame as soon as the daemon takes it.
    AsFastAsPossible,
}

impl From<PacingConfig> for crate::replay::Pacing {
    fn from(pacing: PacingConfig) -> crate::replay::Pacing {
        match pacing {
            PacingConfig::RealTime => crate::replay::Pacing::RealTime,
            PacingConfig::AsFastAsPossible => crate::replay::Pacing::AsFastAsPossible,
        }
    }
}

/// The shortest silence a source's `release_after_s` may set: less would
/// let go of a finger between two frames of a slow sender.
pub const MIN_RELEASE_AFTER_S: f64 = 0.1;
/// The longest: an hour, so a source that died is let go within the show.
pub const MAX_RELEASE_AFTER_S: f64 = 3600.0;

/// A `release_after_s` as the source's timeout, or its kind's default.
pub fn release_after(seconds: Option<f64>, default: std::time::Duration) -> std::time::Duration {
    seconds.map_or(default, std::time::Duration::from_secs_f64)
}

/// The numbers of `[[input]]` entries: a baud rate a port can run at, a
/// mouse's speeds and spacing within a coordinate's range, a cursor start
/// on the stage's scale, every calibration number a coordinate.
pub fn check_inputs(inputs: &[InputConfig]) -> Result<(), (String, String)> {
    for (i, input) in inputs.iter().enumerate() {
        let field = |f: &str| format!("input[{i}].{f}");
        if let InputConfig::Serial {
            release_after_s: Some(seconds),
            ..
        }
        | InputConfig::Tuio {
            release_after_s: Some(seconds),
            ..
        } = input
        {
            within(*seconds, MIN_RELEASE_AFTER_S, MAX_RELEASE_AFTER_S)
                .map_err(|problem| (field("release_after_s"), problem))?;
        }
        let calibration = match input {
            InputConfig::Serial {
                baud, calibration, ..
            } => {
                if !(1..=20_000_000).contains(baud) {
                    return Err((field("baud"), format!("{baud} is not 1 to 20000000")));
                }
                calibration
            }
            InputConfig::Mouse {
                speed,
                pair_spacing,
                rotate_step_deg,
                start,
                ..
            } => {
                for (name, value, lo, hi) in [
                    ("speed", *speed, 1e-6, 1e6),
                    ("pair_spacing", *pair_spacing, MIN_SIZE, MAX_COORDINATE),
                    ("rotate_step_deg", *rotate_step_deg, -360.0, 360.0),
                ] {
                    if let Some(v) = value {
                        within(v, lo, hi).map_err(|problem| (field(name), problem))?;
                    }
                }
                if let Some(start) = start {
                    coordinates(start)
                        .map_err(|(k, problem)| (field(&format!("start[{k}]")), problem))?;
                }
                &None
            }
            InputConfig::Midi {
                path,
                card,
                dir,
                file,
                port,
                map,
                clock,
                tempo,
                ..
            } => {
                let sources = [
                    path.is_some(),
                    card.is_some(),
                    file.is_some(),
                    port.is_some(),
                ];
                if sources.iter().filter(|&&s| s).count() != 1 {
                    return Err((
                        field("path"),
                        "give one of: a raw MIDI port's path, its sound card's name (card), \
                         an ALSA sequencer port's name (port), or a .mid file to play"
                            .into(),
                    ));
                }
                if dir.is_some() && card.is_none() {
                    return Err((
                        field("dir"),
                        "dir is where a card's port is looked for: give card".into(),
                    ));
                }
                ClockSetting::kind(*clock, *tempo)
                    .map_err(|(name, problem)| (field(name), problem))?;
                for (j, m) in map.iter().enumerate() {
                    m.check()
                        .map_err(|(name, problem)| (field(&format!("map[{j}].{name}")), problem))?;
                }
                &None
            }
            InputConfig::Replay { calibration, .. }
            | InputConfig::Tuio { calibration, .. }
            | InputConfig::Hid { calibration, .. } => calibration,
            InputConfig::Touch(device) | InputConfig::Pen(device) => &device.calibration,
        };
        if let Some(spec) = calibration {
            let numbers =
                toml::Value::try_from(spec).map_err(|e| (field("calibration"), e.to_string()))?;
            let mut all = Vec::new();
            collect_numbers(&numbers, &mut all);
            coordinates(&all).map_err(|(_, problem)| (field("calibration"), problem))?;
        }
    }
    Ok(())
}

/// Every number in `value`, depth first.
fn collect_numbers(value: &toml::Value, out: &mut Vec<f64>) {
    match value {
        toml::Value::Float(v) => out.push(*v),
        toml::Value::Integer(v) => out.push(*v as f64),
        toml::Value::Array(items) => items.iter().for_each(|v| collect_numbers(v, out)),
        toml::Value::Table(t) => t.values().for_each(|v| collect_numbers(v, out)),
        _ => {}
    }
}
