//! The project's own recording format: one [`ContactFrame`] per line as a
//! JSON object, in stage coordinates (see `docs/recording-format.md`). It
//! owns the line schema, the [`RecordingWriter`] and the reader behind
//! [`read_recording`]; a reader's complaint names the file, the line and,
//! where serde can tell, the column and field.

use puppetry_mesh::file;
use std::io::{BufRead, Read, Write};
use std::path::Path;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use super::{Contact, ContactFrame, Phase, SourceId};
use puppetry_mesh::json::MAX_COORDINATE;

/// A longer line is refused rather than buffered: a recording line is a
/// frame of a few contacts, so this is a corrupt file.
pub(crate) const MAX_LINE_BYTES: usize = 1 << 20;

/// Why a recording could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// Cannot be read, not a regular file, or past
    /// `MAX_REPLAY_FILE_BYTES`.
    #[error(transparent)]
    File(#[from] file::FileError),
    /// Writing or flushing failed.
    #[error("cannot write the recording: {0}")]
    Write(#[from] std::io::Error),
    /// A line is not a frame: not UTF-8 or JSON, an unknown field, a number
    /// out of range, a contact named twice, or longer than 1 MiB. Reading
    /// stops there.
    #[error("{file}:{line}: {problem}")]
    Line {
        /// The recording, as messages name it.
        file: String,
        /// The line number, from 1.
        line: usize,
        /// What is wrong, with the column or field where known.
        problem: String,
    },
    /// A frame to write holds a number JSON cannot (NaN or an infinity);
    /// nothing of it is written.
    #[error("cannot record frame at t = {time}: {field} is {value}, not a finite number")]
    NotFinite {
        /// The frame's time, seconds.
        time: f64,
        /// Which number (`t`, `x`, `y`, `pressure`, `tilt`, `angle`).
        field: &'static str,
        /// Its value.
        value: f64,
    },
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FrameLine {
    t: f64,
    source: String,
    contacts: Vec<ContactLine>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ContactLine {
    id: u32,
    phase: Phase,
    x: f64,
    y: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pressure: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    tilt: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    angle: Option<f64>,
}

/// Writes frames, one line each. Wrap the file in a `BufWriter`; call
/// [`flush`](RecordingWriter::flush) before dropping to see write errors.
pub struct RecordingWriter<W: Write> {
    out: W,
}

impl<W: Write> RecordingWriter<W> {
    /// A writer onto `out`, which gets one line per frame.
    pub fn new(out: W) -> RecordingWriter<W> {
        RecordingWriter { out }
    }

    /// Writes one frame. Non-finite numbers are refused: JSON cannot hold
    /// them, and a reader would reject the line later, far from the cause.
    pub fn write_frame(&mut self, frame: &ContactFrame) -> Result<(), RecordingError> {
        let not_finite = |field, value: f64| RecordingError::NotFinite {
            time: frame.time,
            field,
            value,
        };
        if !frame.time.is_finite() {
            return Err(not_finite("t", frame.time));
        }
        let mut contacts = Vec::with_capacity(frame.contacts.len());
        for c in &frame.contacts {
            let numbers = [
                ("x", Some(c.position.x)),
                ("y", Some(c.position.y)),
                ("pressure", c.pressure),
                ("tilt", c.tilt.map(|t| t.x)),
                ("tilt", c.tilt.map(|t| t.y)),
                ("angle", c.angle),
            ];
            for (field, value) in numbers {
                if let Some(value) = value.filter(|v| !v.is_finite()) {
                    return Err(not_finite(field, value));
                }
            }
            contacts.push(ContactLine {
                id: c.id,
                phase: c.phase,
                x: c.position.x,
                y: c.position.y,
                pressure: c.pressure,
                tilt: c.tilt.map(|t| [t.x, t.y]),
                angle: c.angle,
            });
        }
        let line = FrameLine {
            t: frame.time,
            source: frame.source.to_string(),
            contacts,
        };
        serde_json::to_writer(&mut self.out, &line).map_err(std::io::Error::from)?;
        self.out.write_all(b"\n")?;
        Ok(())
    }

    /// Flushes `out`, reporting what buffered writes could not do.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        Ok(self.out.flush()?)
    }

    /// Gives `out` back without flushing it (a `Vec<u8>` holding the
    /// text, say).
    pub fn into_inner(self) -> W {
        self.out
    }
}

/// Reads frames one line at a time; blank lines are skipped.
pub(crate) struct RecordingReader<R: BufRead> {
    file: String,
    input: R,
    line: usize,
    buffer: Vec<u8>,
    failed: bool,
}

impl<R: BufRead> RecordingReader<R> {
    /// Reads from `input`, named `file` in errors.
    pub fn new(file: &str, input: R) -> RecordingReader<R> {
        RecordingReader {
            file: file.to_string(),
            input,
            line: 0,
            buffer: Vec::new(),
            failed: false,
        }
    }

    fn error(&self, problem: impl Into<String>) -> RecordingError {
        RecordingError::Line {
            file: self.file.clone(),
            line: self.line,
            problem: problem.into(),
        }
    }

    fn next_line(&mut self) -> Result<Option<ContactFrame>, RecordingError> {
        loop {
            self.buffer.clear();
            let limit = MAX_LINE_BYTES as u64 + 1;
            let read = Read::take(&mut self.input, limit)
                .read_until(b'\n', &mut self.buffer)
                .map_err(|source| file::FileError::Io {
                    file: self.file.clone(),
                    source,
                })?;
            if read == 0 {
                return Ok(None);
            }
            self.line += 1;
            if self.buffer.len() > MAX_LINE_BYTES {
                return Err(self.error(format!("line is longer than {MAX_LINE_BYTES} bytes")));
            }
            let Ok(text) = std::str::from_utf8(&self.buffer) else {
                return Err(self.error("not UTF-8 text"));
            };
            let text = if self.line == 1 {
                text.trim_start_matches('\u{feff}')
            } else {
                text
            };
            if text.trim().is_empty() {
                continue;
            }
            return self.parse(text).map(Some);
        }
    }

    fn parse(&self, text: &str) -> Result<ContactFrame, RecordingError> {
        let line: FrameLine = serde_json::from_str(text).map_err(|e| {
            let message = e.to_string();
            let position = format!(" at line {} column {}", e.line(), e.column());
            let message = message.strip_suffix(&position).unwrap_or(&message);
            self.error(format!("column {}: {message}", e.column()))
        })?;
        let field_error = |field: String, problem: &str| self.error(format!("{field}: {problem}"));
        if !line.t.is_finite() {
            return Err(field_error("t".into(), "must be a finite number"));
        }
        if line.source.is_empty() {
            return Err(field_error("source".into(), "must not be empty"));
        }
        let mut contacts: Vec<Contact> = Vec::with_capacity(line.contacts.len());
        for (i, c) in line.contacts.into_iter().enumerate() {
            let field = |name: &str| format!("contacts[{i}].{name}");
            for (name, value) in [("x", c.x), ("y", c.y)] {
                if !value.is_finite() || value.abs() > MAX_COORDINATE {
                    return Err(field_error(
                        field(name),
                        &format!("{value} is not a coordinate within ±{MAX_COORDINATE}"),
                    ));
                }
            }
            if let Some(p) = c.pressure
                && !(0.0..=1.0).contains(&p)
            {
                return Err(field_error(
                    field("pressure"),
                    &format!("{p} is not within 0..=1"),
                ));
            }
            if let Some(t) = c.tilt
                && !t.iter().all(|v| v.is_finite())
            {
                return Err(field_error(field("tilt"), "must be finite numbers"));
            }
            if let Some(a) = c.angle
                && !a.is_finite()
            {
                return Err(field_error(field("angle"), "must be a finite number"));
            }
            if contacts.iter().any(|other| other.id == c.id) {
                return Err(field_error(
                    field("id"),
                    &format!("contact {} appears twice in one frame", c.id),
                ));
            }
            contacts.push(Contact {
                id: c.id,
                phase: c.phase,
                position: DVec2::new(c.x, c.y),
                pressure: c.pressure,
                tilt: c.tilt.map(DVec2::from),
                angle: c.angle,
            });
        }
        Ok(ContactFrame {
            source: SourceId::from(line.source),
            time: line.t,
            contacts,
        })
    }
}

impl<R: BufRead> Iterator for RecordingReader<R> {
    type Item = Result<ContactFrame, RecordingError>;

    /// Stops after the first error: later lines' numbers would be guesses.
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let result = self.next_line().transpose();
        if matches!(result, Some(Err(_))) {
            self.failed = true;
        }
        result
    }
}

/// Reads a whole recording file.
pub fn read_recording(path: &Path) -> Result<Vec<ContactFrame>, RecordingError> {
    let file = path.display().to_string();
    let input = file::reader(path, file::REPLAY_FILE)?;
    RecordingReader::new(&file, std::io::BufReader::new(input)).collect()
}

/// Parses a whole recording held in memory, named `file` in errors.
pub fn parse_recording(file: &str, text: &str) -> Result<Vec<ContactFrame>, RecordingError> {
    RecordingReader::new(file, text.as_bytes()).collect()
}
