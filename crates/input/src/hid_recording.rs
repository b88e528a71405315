//! Reading and writing the text captures of hid-tools' `hid-recorder`: the
//! raw report descriptor (`R: <length> <hex bytes>`), the device's name
//! (`N:`), physical path (`P:`) and ids (`I: <bus> <vendor> <product>`, hex)
//! and its input reports (`E: <sec>.<usec> <length> <hex bytes>`), with `#`
//! comment lines and `D: <index>` device markers. Such a capture is to a HID
//! digitizer what an evemu capture is to an evdev device: it replays through
//! the same decoder a live device feeds (see [`replay`](super::replay)).
//!
//! `hid-recorder` wraps long byte lists onto following lines of bare hex, so
//! a line of only hex bytes continues the `R:` or `E:` line before it until
//! that line has the bytes its length declares. Only single-device captures
//! are read: a second `D:` index is an error rather than a silent merge of
//! two devices' reports. Every complaint names the file, the line and the
//! field.

use super::fields::{Fields, clip};
use puppetry_mesh::file;
use std::io::Write;
use std::path::Path;

/// Why a hid-recorder capture cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum HidRecordingError {
    /// Cannot be read, not a regular file, or past
    /// `MAX_REPLAY_FILE_BYTES`.
    #[error(transparent)]
    File(#[from] file::FileError),
    /// A line that does not parse, or breaks a rule of the format (a byte
    /// count that does not add up, a second device, …).
    #[error(transparent)]
    Line(#[from] crate::LineError),
    /// The capture has no report descriptor, without which its reports
    /// cannot be decoded.
    #[error("{file}: no `R:` line; a hid-recorder capture starts with the report descriptor")]
    NoDescriptor {
        /// The capture, as messages name it.
        file: String,
    },
}

/// One device's capture.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HidRecording {
    /// The device's name (`N:`).
    pub name: String,
    /// Its physical path (`P:`).
    pub phys: String,
    /// Bus type (`I:`, as in [`InputId::bus`](crate::evemu::InputId::bus)).
    pub bus: u16,
    /// Vendor id (`I:`).
    pub vendor: u16,
    /// Product id (`I:`).
    pub product: u16,
    /// The raw report descriptor (`R:`).
    pub descriptor: Vec<u8>,
    /// Input reports as read from hidraw (report id byte first when the
    /// descriptor numbers its reports), with their time in seconds.
    pub reports: Vec<(f64, Vec<u8>)>,
}

impl HidRecording {
    /// [`parse`](HidRecording::parse) of the capture at `path`, within the size
    /// limit of every replay file (`MAX_REPLAY_FILE_BYTES`).
    pub fn read(path: &Path) -> Result<HidRecording, HidRecordingError> {
        file::parse_text(path, file::REPLAY_FILE, HidRecording::parse)
    }

    /// Parses `text`, named `file` in errors.
    pub fn parse(file: &str, text: &str) -> Result<HidRecording, HidRecordingError> {
        let mut parser = Parser {
            file,
            line: 0,
            recording: HidRecording::default(),
            have_descriptor: false,
            device: None,
            open: None,
        };
        for (index, line) in text.lines().enumerate() {
            parser.line = index + 1;
            parser.parse_line(line)?;
        }
        parser.finish_bytes()?;
        if !parser.have_descriptor {
            return Err(HidRecordingError::NoDescriptor {
                file: file.to_string(),
            });
        }
        Ok(parser.recording)
    }

    /// Writes the capture in `hid-recorder`'s format, one line per item, so
    /// hid-tools (`hid-replay`, `hid-decode`) can read it back.
    pub fn write(&self, out: &mut impl Write) -> std::io::Result<()> {
        writeln!(out, "# {}", one_line(&self.name))?;
        writeln!(out, "# written by puppetry")?;
        write!(out, "R: {}", self.descriptor.len())?;
        write_hex(out, &self.descriptor)?;
        writeln!(out)?;
        // Both are free text to the end of the line; a line break inside
        // would start a new item, so it is flattened.
        writeln!(out, "N: {}", one_line(&self.name))?;
        writeln!(out, "P: {}", one_line(&self.phys))?;
        writeln!(
            out,
            "I: {:x} {:04x} {:04x}",
            self.bus, self.vendor, self.product
        )?;
        for (time, report) in &self.reports {
            let (seconds, micros) = split_time(*time);
            write!(out, "E: {seconds:06}.{micros:06} {}", report.len())?;
            write_hex(out, report)?;
            writeln!(out)?;
        }
        Ok(())
    }
}

fn write_hex(out: &mut impl Write, bytes: &[u8]) -> std::io::Result<()> {
    for byte in bytes {
        write!(out, " {byte:02x}")?;
    }
    Ok(())
}

fn one_line(text: &str) -> String {
    text.replace(['\n', '\r'], " ")
}

/// Whole seconds and microseconds, rounded to the nearest microsecond;
/// negative or non-finite times (which a capture cannot hold) become 0.
fn split_time(time: f64) -> (u64, u64) {
    let micros = if time.is_finite() && time > 0.0 {
        (time * 1e6).round() as u64
    } else {
        0
    };
    (micros / 1_000_000, micros % 1_000_000)
}

/// An `R:` or `E:` line still waiting for continuation lines.
struct OpenBytes {
    line: usize,
    kind: BytesKind,
    expected: usize,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum BytesKind {
    Descriptor,
    Report,
}

impl BytesKind {
    fn field(self) -> &'static str {
        match self {
            BytesKind::Descriptor => "descriptor bytes",
            BytesKind::Report => "report bytes",
        }
    }
}

struct Parser<'a> {
    file: &'a str,
    line: usize,
    recording: HidRecording,
    have_descriptor: bool,
    /// The `D:` index in force, once one is seen.
    device: Option<u32>,
    open: Option<OpenBytes>,
}

impl Fields for Parser<'_> {
    type Error = HidRecordingError;

    fn field_error(&self, field: &'static str, problem: String) -> HidRecordingError {
        self.error(field, problem)
    }
}

impl Parser<'_> {
    fn error(&self, field: &'static str, problem: impl Into<String>) -> HidRecordingError {
        self.error_at(self.line, field, problem)
    }

    fn error_at(
        &self,
        line: usize,
        field: &'static str,
        problem: impl Into<String>,
    ) -> HidRecordingError {
        HidRecordingError::Line(crate::LineError {
            file: self.file.to_string(),
            line,
            field,
            problem: problem.into(),
        })
    }

    fn bytes_of(&mut self, kind: BytesKind) -> &mut Vec<u8> {
        match kind {
            BytesKind::Descriptor => &mut self.recording.descriptor,
            BytesKind::Report => {
                let (_, bytes) = self
                    .recording
                    .reports
                    .last_mut()
                    .expect("a report line opened the bytes");
                bytes
            }
        }
    }

    /// Closes the open `R:`/`E:` line; it must have all its bytes by now.
    fn finish_bytes(&mut self) -> Result<(), HidRecordingError> {
        let Some(open) = self.open.take() else {
            return Ok(());
        };
        let got = self.bytes_of(open.kind).len();
        if got != open.expected {
            return Err(self.error_at(
                open.line,
                open.kind.field(),
                format!("the length says {} bytes, found {got}", open.expected),
            ));
        }
        Ok(())
    }

    /// Appends hex bytes to the open line, refusing more than it declared.
    fn take_bytes<'t>(
        &mut self,
        words: impl Iterator<Item = &'t str>,
    ) -> Result<(), HidRecordingError> {
        let Some(open) = &self.open else {
            return Ok(());
        };
        let (kind, expected) = (open.kind, open.expected);
        let mut bytes = Vec::new();
        for word in words {
            bytes.push(self.hex::<u8>(Some(word), kind.field())?);
        }
        let target = self.bytes_of(kind);
        target.extend(bytes);
        let got = target.len();
        if got > expected {
            return Err(self.error(
                kind.field(),
                format!("the length says {expected} bytes, found {got}"),
            ));
        }
        if got == expected {
            self.open = None;
        }
        Ok(())
    }

    fn parse_line(&mut self, line: &str) -> Result<(), HidRecordingError> {
        let line = line.trim_start_matches('\u{feff}');
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            return Ok(());
        }
        let Some((kind, rest)) = trimmed.split_once(':') else {
            if self.open.is_some() {
                return self.take_bytes(trimmed.split_whitespace());
            }
            return Err(self.error("line", format!("expected `X: …`, got `{}`", clip(trimmed))));
        };
        self.finish_bytes()?;
        let rest = rest.trim();
        match kind {
            // Free text to the end of the line: names may hold `#`.
            "N" => self.recording.name = rest.to_string(),
            "P" => self.recording.phys = rest.to_string(),
            "D" => {
                let mut fields = rest.split_whitespace();
                let index = self.decimal::<u32>(fields.next(), "device index")?;
                self.no_more(fields)?;
                match self.device {
                    Some(first) if first != index => {
                        return Err(self.error(
                            "device index",
                            format!(
                                "device {index} after device {first}: captures of several \
                                 devices are not supported; record one device per file"
                            ),
                        ));
                    }
                    _ => self.device = Some(index),
                }
            }
            "I" => {
                let mut fields = rest.split_whitespace();
                self.recording.bus = self.hex(fields.next(), "bus")?;
                self.recording.vendor = self.hex(fields.next(), "vendor")?;
                self.recording.product = self.hex(fields.next(), "product")?;
                self.no_more(fields)?;
            }
            "R" => {
                if self.have_descriptor {
                    return Err(self.error(
                        "line",
                        "a second `R:` line; one device has one report descriptor",
                    ));
                }
                let mut fields = rest.split_whitespace();
                let expected = self.decimal::<usize>(fields.next(), "length")?;
                if expected == 0 {
                    return Err(self.error("length", "a report descriptor cannot be empty"));
                }
                self.have_descriptor = true;
                self.open = Some(OpenBytes {
                    line: self.line,
                    kind: BytesKind::Descriptor,
                    expected,
                });
                self.take_bytes(fields)?;
            }
            "E" => {
                if !self.have_descriptor {
                    return Err(
                        self.error("line", "an `E:` report before the `R:` report descriptor")
                    );
                }
                let mut fields = rest.split_whitespace();
                let time = self.time(fields.next())?;
                let expected = self.decimal::<usize>(fields.next(), "length")?;
                if expected == 0 {
                    return Err(self.error("length", "an input report cannot be empty"));
                }
                if let Some((previous, _)) = self.recording.reports.last()
                    && time < *previous
                {
                    return Err(self.error(
                        "time",
                        format!("{time} is earlier than the previous report's {previous}"),
                    ));
                }
                self.recording.reports.push((time, Vec::new()));
                self.open = Some(OpenBytes {
                    line: self.line,
                    kind: BytesKind::Report,
                    expected,
                });
                self.take_bytes(fields)?;
            }
            other => {
                return Err(self.error(
                    "line",
                    format!(
                        "unknown line kind `{}:`; expected D, R, N, P, I or E",
                        clip(other)
                    ),
                ));
            }
        }
        Ok(())
    }
}
