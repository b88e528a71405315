//! Reading evemu-record captures: the device description (`N:` name, `I:`
//! ids, `P:` property bits, `B:` event-type bits, `A:` axes) and the events
//! (`E: <sec>.<usec> <type> <code> <value>`, type and code in hex). A capture
//! stands in for a real device: its axes size the [`TouchDecoder`] and the
//! default calibration, its events replay through it. Every complaint names
//! the file, the line and the field.

use super::fields::{Fields, clip};
use puppetry_mesh::file;
use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec2;

use super::evdev::{
    ABS_MAX, AbsAxes, AbsInfo, EV_MAX, EvdevError, InputEvent, KEY_MAX, TouchDecoder,
    fit_calibration,
};
use super::{Calibration, SourceId};

/// Why an evemu capture cannot be read or used.
#[derive(Debug, thiserror::Error)]
pub enum EvemuError {
    /// Cannot be read, not a regular file, or past
    /// `MAX_REPLAY_FILE_BYTES`.
    #[error(transparent)]
    File(#[from] file::FileError),
    /// A line that does not parse, or breaks a rule of the format.
    #[error(transparent)]
    Line(#[from] crate::LineError),
    /// The captured device cannot be decoded or fitted to the stage: it
    /// has no position axes, say.
    #[error("{file}: {source}")]
    Device {
        /// The capture, as messages name it.
        file: String,
        /// Why.
        source: EvdevError,
    },
}

/// A device's ids, as the kernel gives them and a capture's `I:` line
/// holds them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct InputId {
    /// Bus type (`BUS_USB` 0x03, `BUS_BLUETOOTH` 0x05, `BUS_I2C` 0x18, …).
    pub bus: u16,
    /// Vendor id (the USB one on USB).
    pub vendor: u16,
    /// Product id.
    pub product: u16,
    /// Version number the driver reports.
    pub version: u16,
}

/// What the header says about the device.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EvemuDevice {
    /// The device's name (`N:`).
    pub name: String,
    /// Its ids (`I:`).
    pub id: InputId,
    /// `INPUT_PROP_*` bits, bytes in file order.
    pub properties: Vec<u8>,
    /// Supported codes per event type, bytes in file order.
    pub event_bits: BTreeMap<u16, Vec<u8>>,
    /// Absolute axes with their ranges (`A:`).
    pub axes: AbsAxes,
}

/// A whole capture, parsed.
#[derive(Debug, Clone, PartialEq)]
pub struct EvemuFile {
    /// How errors name the file.
    pub file: String,
    /// The header: what the device is and can report.
    pub device: EvemuDevice,
    /// Every `E:` event in file order; times never go backwards.
    pub events: Vec<InputEvent>,
}

impl EvemuFile {
    /// [`parse`](EvemuFile::parse) of the capture at `path`, within the size
    /// limit of every replay file (`MAX_REPLAY_FILE_BYTES`).
    pub fn read(path: &Path) -> Result<EvemuFile, EvemuError> {
        file::parse_text(path, file::REPLAY_FILE, EvemuFile::parse)
    }

    /// Parses `text`, named `file` in errors.
    pub fn parse(file: &str, text: &str) -> Result<EvemuFile, EvemuError> {
        let mut parser = Parser {
            file,
            line: 0,
            device: EvemuDevice::default(),
            events: Vec::new(),
        };
        for (index, line) in text.lines().enumerate() {
            parser.line = index + 1;
            parser.parse_line(line)?;
        }
        Ok(EvemuFile {
            file: file.to_string(),
            device: parser.device,
            events: parser.events,
        })
    }

    /// The device's position ranges stretched over a `stage_size` stage.
    pub fn fit_calibration(&self, stage_size: DVec2) -> Result<Calibration, EvemuError> {
        fit_calibration(&self.device.axes, stage_size).map_err(|source| self.device_error(source))
    }

    /// A fresh decoder for this capture's device.
    pub fn decoder(
        &self,
        source: SourceId,
        calibration: Calibration,
    ) -> Result<TouchDecoder, EvemuError> {
        TouchDecoder::new(source, &self.device.axes, calibration)
            .map_err(|source| self.device_error(source))
    }

    fn device_error(&self, source: EvdevError) -> EvemuError {
        EvemuError::Device {
            file: self.file.clone(),
            source,
        }
    }
}

struct Parser<'a> {
    file: &'a str,
    line: usize,
    device: EvemuDevice,
    events: Vec<InputEvent>,
}

impl Fields for Parser<'_> {
    type Error = EvemuError;

    fn field_error(&self, field: &'static str, problem: String) -> EvemuError {
        self.error(field, problem)
    }
}

impl Parser<'_> {
    fn error(&self, field: &'static str, problem: impl Into<String>) -> EvemuError {
        EvemuError::Line(crate::LineError {
            file: self.file.to_string(),
            line: self.line,
            field,
            problem: problem.into(),
        })
    }

    fn parse_line(&mut self, line: &str) -> Result<(), EvemuError> {
        let line = line.trim_start_matches('\u{feff}');
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            return Ok(());
        }
        let Some((kind, rest)) = trimmed.split_once(':') else {
            return Err(self.error("line", format!("expected `X: …`, got `{}`", clip(trimmed))));
        };
        if kind == "N" {
            // Names may contain '#', so no comment stripping here.
            self.device.name = rest.trim().to_string();
            return Ok(());
        }
        let rest = rest.split('#').next().unwrap_or("");
        let mut fields = rest.split_whitespace();
        match kind {
            "I" => {
                let mut next = |field| self.hex::<u16>(fields.next(), field);
                self.device.id = InputId {
                    bus: next("bus")?,
                    vendor: next("vendor")?,
                    product: next("product")?,
                    version: next("version")?,
                };
            }
            "P" => {
                for byte in fields {
                    let byte = self.hex::<u8>(Some(byte), "property bits")?;
                    self.device.properties.push(byte);
                }
                return Ok(());
            }
            "B" => {
                let ev_type = self.hex::<u16>(fields.next(), "event type")?;
                if ev_type > EV_MAX {
                    return Err(self.error("event type", format!("{ev_type:#x} is above EV_MAX")));
                }
                let mut bytes = Vec::new();
                for byte in fields {
                    bytes.push(self.hex::<u8>(Some(byte), "event bits")?);
                }
                self.device
                    .event_bits
                    .entry(ev_type)
                    .or_default()
                    .extend(bytes);
                return Ok(());
            }
            "A" => {
                let code = self.hex::<u16>(fields.next(), "axis code")?;
                if code > ABS_MAX {
                    return Err(self.error("axis code", format!("{code:#x} is above ABS_MAX")));
                }
                let min = self.decimal(fields.next(), "min")?;
                let max = self.decimal(fields.next(), "max")?;
                let fuzz = self.decimal(fields.next(), "fuzz")?;
                let flat = self.decimal(fields.next(), "flat")?;
                let resolution = match fields.next() {
                    Some(text) => self.decimal(Some(text), "resolution")?,
                    None => 0,
                };
                if min > max {
                    return Err(self.error("max", format!("{max} is below min {min}")));
                }
                let info = AbsInfo {
                    min,
                    max,
                    fuzz,
                    flat,
                    resolution,
                };
                if self.device.axes.insert(code, info).is_some() {
                    return Err(
                        self.error("axis code", format!("axis {code:#04x} is described twice"))
                    );
                }
            }
            "E" => {
                let time = self.time(fields.next())?;
                let ev_type = self.hex::<u16>(fields.next(), "event type")?;
                let code = self.hex::<u16>(fields.next(), "event code")?;
                let value = self.decimal(fields.next(), "value")?;
                if ev_type > EV_MAX {
                    return Err(self.error("event type", format!("{ev_type:#x} is above EV_MAX")));
                }
                if code > KEY_MAX {
                    return Err(self.error("event code", format!("{code:#x} is above KEY_MAX")));
                }
                if let Some(previous) = self.events.last()
                    && time < previous.time
                {
                    return Err(self.error(
                        "time",
                        format!(
                            "{time} is earlier than the previous event's {}",
                            previous.time
                        ),
                    ));
                }
                self.events
                    .push(InputEvent::new(time, ev_type, code, value));
            }
            // LED and switch states: nothing a touch surface needs.
            "L" | "S" => return Ok(()),
            other => {
                return Err(self.error(
                    "line",
                    format!(
                        "unknown line kind `{}:`; expected N, I, P, B, A, L, S or E",
                        clip(other)
                    ),
                ));
            }
        }
        self.no_more(fields)
    }
}

impl EvemuDevice {
    /// Writes the description as `evemu-record` does (`N:`, `I:`, `P:`,
    /// `B:` eight bytes a line, `A:`), so evemu tools and [`EvemuFile`]
    /// read it back.
    pub fn write(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(out, "# EVEMU 1.3")?;
        writeln!(out, "# Input device name: \"{}\"", self.name)?;
        writeln!(out, "N: {}", self.name)?;
        let id = &self.id;
        writeln!(
            out,
            "I: {:04x} {:04x} {:04x} {:04x}",
            id.bus, id.vendor, id.product, id.version
        )?;
        let mut properties = self.properties.clone();
        properties.resize(properties.len().max(8), 0);
        write!(out, "P:")?;
        for byte in &properties {
            write!(out, " {byte:02x}")?;
        }
        writeln!(out)?;
        for (ev_type, bits) in &self.event_bits {
            for chunk in bits.chunks(8) {
                write!(out, "B: {ev_type:02x}")?;
                for byte in chunk {
                    write!(out, " {byte:02x}")?;
                }
                writeln!(out)?;
            }
        }
        for (code, a) in &self.axes {
            writeln!(
                out,
                "A: {code:02x} {} {} {} {} {}",
                a.min, a.max, a.fuzz, a.flat, a.resolution
            )?;
        }
        Ok(())
    }
}

/// Writes one `E:` line: `seconds.microseconds type code value`.
pub fn write_event(out: &mut impl std::io::Write, event: &InputEvent) -> std::io::Result<()> {
    let micros = (event.time * 1e6).round().max(0.0) as u64;
    writeln!(
        out,
        "E: {}.{:06} {:04x} {:04x} {}",
        micros / 1_000_000,
        micros % 1_000_000,
        event.ev_type,
        event.code,
        event.value
    )
}
