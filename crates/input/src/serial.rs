//! Serial touch pads (Arduino, Teensy and the like) as an input source: a
//! byte stream from a USB-serial port in, calibrated [`ContactFrame`]s out.
//! It owns the two wire formats such firmware speaks, the sync
//! [`SerialDecoder`] that turns arbitrary read chunks into frames (partial
//! records across reads, resynchronising after garbage, a length cap on every
//! record, device-to-stage mapping), and the async [`run_stream`] /
//! [`run_port`] that feed the daemon's bounded channel.
//!
//! # Formats
//!
//! Chosen by [`WireFormat`]; both are event-based (the pad says `d`/`m`/`u`),
//! and both end a frame explicitly. Positions are device units, mapped to the
//! stage through the decoder's [`Calibration`]; pressure is already
//! normalised to `0..=1`.
//!
//! **`csv`** — text, one record per line:
//!
//! ```text
//! line     = [ record ] [ "\r" ] "\n"
//! record   = contact | "f"                 ; "f", like an empty line, ends a frame
//! contact  = id "," phase "," x "," y [ "," pressure ]
//! id       = decimal u32
//! phase    = "d" | "m" | "u" | "down" | "move" | "up"   ; any case
//! x, y     = finite decimal number (Rust f64 syntax)
//! pressure = finite decimal number in 0..=1
//! ```
//!
//! Spaces and tabs around fields are ignored. A bad line is an error naming
//! its line number (counted from 1 since the decoder was made) and field.
//!
//! **`slip_osc`** — binary: RFC 1055 SLIP packets (END `0xC0`, ESC `0xDB`,
//! ESC_END `0xDC`, ESC_ESC `0xDD`; a leading END is allowed), each an OSC
//! message or bundle of messages:
//!
//! ```text
//! /pad/contact  i:id  s:phase  f:x  f:y  [f:pressure]   ; phase as in csv; f or d accepted
//! /pad/frame                                            ; ends a frame
//! ```
//!
//! A bad packet or message is an error naming the packet's byte offset (from
//! the decoder's first byte) and the message's index and argument.
//!
//! # Semantics
//!
//! A frame's contacts are collected until its end marker; an empty frame is
//! not sent. A bad record is reported and skipped, and the frame goes on
//! without it: dropping the whole frame would drop the good `u`s in it and
//! leave contacts stuck. Phases are made consistent with what the stage has
//! seen, because firmware restarts and late connects are normal: `d` for a
//! contact already down is a move, `m` for one not down is a landing, and
//! `u` for one not down is an error. A contact named twice in one frame
//! (a quick tap, `d` then `u`) splits the frame in two, so every frame names
//! a contact once and no event is lost. Contacts stay down until their `u`;
//! when the port goes away, [`SerialDecoder::lift_all`] lifts the rest.
//! Records longer than [`MAX_RECORD`] bytes are refused and skipped up to
//! the next newline or END, so a stream with no delimiters cannot grow memory.

use std::collections::BTreeMap;
use std::time::Instant;

use glam::DVec2;
use rosc::{OscMessage, OscPacket, OscType};
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::sync::mpsc;

use super::log_limit::{LogLimiter, MAX_ECHO, clip, summary_timer};
use super::{Calibration, CalibrationError, Contact, ContactFrame, Phase, SourceId};

/// The longest line or SLIP packet accepted, in bytes (before SLIP escaping
/// is undone, after it for packets). Real records are tens of bytes; this
/// only bounds the damage of a stream that never sends a delimiter.
pub const MAX_RECORD: usize = 4096;

/// How long a pad may send nothing while a contact is down before its
/// contacts are let go, unless the input says otherwise
/// (`release_after_s`): firmware that hung with its port still open. A
/// pad that holds a contact still should send an empty frame (`f`, or an
/// empty line; `/pad/frame`) about once a second to say it is alive.
pub const RELEASE_AFTER: std::time::Duration = std::time::Duration::from_secs(5);

/// Bytes asked of the port per read; a USB-serial chip delivers at most a
/// few hundred at a time.
const READ_CHUNK: usize = 1024;

const END: u8 = 0xC0;
const ESC: u8 = 0xDB;
const ESC_END: u8 = 0xDC;
const ESC_ESC: u8 = 0xDD;

/// What went wrong on a serial pad: a bad record, which is skipped while
/// reading goes on, or the port itself, which ends the reading.
#[derive(Debug, thiserror::Error)]
pub enum SerialError {
    /// A `csv` line that is not a record, or lifts a contact that is not
    /// down.
    #[error("serial: line {line}: {problem}")]
    Line {
        /// The line number, counted from 1 since the decoder was made.
        line: u64,
        /// What is wrong, naming the field.
        problem: String,
    },
    /// A `slip_osc` packet that is not OSC, breaks SLIP, or holds a bad
    /// message (the packet's other messages still apply).
    #[error("serial: packet at byte {offset}: {problem}")]
    Packet {
        /// Where the packet starts, in bytes from the decoder's first.
        offset: u64,
        /// What is wrong; for a bad message, which one and which argument.
        problem: String,
    },
    /// A line or packet longer than [`MAX_RECORD`]; skipped up to the next
    /// delimiter.
    #[error(
        "serial: {record} starting at byte {offset} is longer than {limit} bytes; \
         skipped to the next delimiter"
    )]
    TooLong {
        /// `line N` or `packet`.
        record: String,
        /// Where it starts, in bytes from the decoder's first.
        offset: u64,
        /// The limit it passed, [`MAX_RECORD`].
        limit: usize,
    },
    /// The pad's calibration cannot be made: an empty range, say.
    #[error("serial: {0}")]
    Calibration(#[from] CalibrationError),
    /// The port cannot be opened: missing, busy, or not permitted.
    #[error("serial: opening {path}: {source}")]
    Open {
        /// The port.
        path: String,
        /// What the serial library said.
        #[source]
        source: tokio_serial::Error,
    },
    /// Reading the port failed: the pad was unplugged, say.
    #[error("serial: reading the port: {0}")]
    Read(#[source] std::io::Error),
    /// The port reported the end of its stream.
    #[error("serial: the port closed (end of stream)")]
    Closed,
}

/// Which of the two wire formats a pad speaks (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WireFormat {
    /// `csv`: text lines `id,phase,x,y[,pressure]`, `f` or an empty line
    /// ending a frame.
    Csv,
    /// `slip_osc`: SLIP-framed OSC, `/pad/contact` messages and a
    /// `/pad/frame` ending each frame.
    SlipOsc,
}

/// Serial decoding state for one port. Feed it whatever the port read with
/// [`push`](SerialDecoder::push); it answers with the frames those bytes
/// complete and the errors they contain, in stream order.
#[derive(Debug)]
pub struct SerialDecoder {
    format: WireFormat,
    calibration: Calibration,
    source: SourceId,
    /// Frames carry seconds since the decoder was made: pads send no time.
    clock: Instant,
    /// The line or (unescaped) packet read so far.
    record: Vec<u8>,
    /// Byte offset of `record`'s first byte.
    record_start: u64,
    /// Bytes consumed since the decoder was made.
    offset: u64,
    /// Csv: number of the line being read, from 1.
    line: u64,
    /// Throwing bytes away up to the next delimiter (after an over-long
    /// record or a bad SLIP escape).
    skipping: bool,
    /// Slip: the previous byte was ESC.
    escaped: bool,
    /// The frame being collected; names each contact at most once.
    pending: Vec<Contact>,
    /// Contacts down as of the last sent frame, as last stated; ordered so a
    /// lift-all frame is deterministic.
    down: BTreeMap<u32, Contact>,
}

impl SerialDecoder {
    /// A decoder for a pad speaking `format`, mapping pad units to the
    /// stage through `calibration` and reporting as `source`. Its clock
    /// starts now: frames carry seconds since.
    pub fn new(format: WireFormat, calibration: Calibration, source: SourceId) -> SerialDecoder {
        SerialDecoder {
            format,
            calibration,
            source,
            clock: Instant::now(),
            record: Vec::new(),
            record_start: 0,
            offset: 0,
            line: 1,
            skipping: false,
            escaped: false,
            pending: Vec::new(),
            down: BTreeMap::new(),
        }
    }

    /// Decodes `bytes`, which may start or end mid-record: the unfinished
    /// part waits for the next call.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Result<ContactFrame, SerialError>> {
        let mut out = Vec::new();
        for &byte in bytes {
            match self.format {
                WireFormat::Csv => self.csv_byte(byte, &mut out),
                WireFormat::SlipOsc => self.slip_byte(byte, &mut out),
            }
            self.offset += 1;
        }
        out
    }

    /// Lifts every contact that is down, as one frame (`None` if none is),
    /// and forgets any unfinished record or frame: what to send when the
    /// port closes, so the stage is never left holding a contact whose `u`
    /// will not come. The unfinished frame is dropped rather than sent
    /// because its landings would be lifted in the same breath.
    pub fn lift_all(&mut self) -> Option<ContactFrame> {
        self.record.clear();
        self.skipping = false;
        self.escaped = false;
        self.pending.clear();
        let contacts: Vec<Contact> = std::mem::take(&mut self.down)
            .into_values()
            .map(|mut contact| {
                contact.phase = Phase::Up;
                contact
            })
            .collect();
        (!contacts.is_empty()).then(|| self.frame(contacts))
    }

    /// Whether a contact is down.
    pub fn holds(&self) -> bool {
        !self.down.is_empty()
    }

    fn frame(&self, contacts: Vec<Contact>) -> ContactFrame {
        ContactFrame {
            source: self.source.clone(),
            time: self.clock.elapsed().as_secs_f64(),
            contacts,
        }
    }

    /// Appends `byte` to the record, or refuses the record once it is too
    /// long and skips to the next delimiter.
    fn keep(&mut self, byte: u8, out: &mut Vec<Result<ContactFrame, SerialError>>) {
        if self.record.len() == MAX_RECORD {
            let record = match self.format {
                WireFormat::Csv => format!("line {}", self.line),
                WireFormat::SlipOsc => "packet".to_owned(),
            };
            out.push(Err(SerialError::TooLong {
                record,
                offset: self.record_start,
                limit: MAX_RECORD,
            }));
            self.record.clear();
            self.skipping = true;
            return;
        }
        self.record.push(byte);
    }

    fn csv_byte(&mut self, byte: u8, out: &mut Vec<Result<ContactFrame, SerialError>>) {
        if byte == b'\n' {
            let line = std::mem::take(&mut self.record);
            if !std::mem::take(&mut self.skipping)
                && let Err(problem) = self.csv_line(&line, out)
            {
                out.push(Err(SerialError::Line {
                    line: self.line,
                    problem,
                }));
            }
            self.record = line;
            self.record.clear();
            self.line += 1;
            self.record_start = self.offset + 1;
        } else if !self.skipping {
            self.keep(byte, out);
        }
    }

    fn csv_line(
        &mut self,
        line: &[u8],
        out: &mut Vec<Result<ContactFrame, SerialError>>,
    ) -> Result<(), String> {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        let text = std::str::from_utf8(line)
            .map_err(|e| format!("not UTF-8 text (at column {})", e.valid_up_to() + 1))?
            .trim();
        if text.is_empty() || text == "f" {
            self.end_frame(out);
            return Ok(());
        }
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        if !(4..=5).contains(&fields.len()) {
            return Err(format!(
                "expected `id,phase,x,y[,pressure]` or `f`, got {} field(s) in `{}`",
                fields.len(),
                shorten(text)
            ));
        }
        let id: u32 = fields[0].parse().map_err(|_| {
            format!(
                "field 1 (id) `{}` is not a contact id (0..=4294967295)",
                shorten(fields[0])
            )
        })?;
        let phase = parse_phase(fields[1]).ok_or_else(|| {
            format!(
                "field 2 (phase) `{}` is not d, m, u, down, move or up",
                shorten(fields[1])
            )
        })?;
        let number = |at: usize, name: &str| -> Result<f64, String> {
            match fields[at].parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(format!(
                    "field {} ({name}) `{}` is not a finite number",
                    at + 1,
                    shorten(fields[at])
                )),
            }
        };
        let position = DVec2::new(number(2, "x")?, number(3, "y")?);
        let pressure = match fields.get(4) {
            Some(_) => Some(check_pressure(
                number(4, "pressure")?,
                "field 5 (pressure)",
            )?),
            None => None,
        };
        self.contact(id, phase, position, pressure, out)
    }

    fn slip_byte(&mut self, byte: u8, out: &mut Vec<Result<ContactFrame, SerialError>>) {
        if byte == END {
            let packet = std::mem::take(&mut self.record);
            let skipped = std::mem::take(&mut self.skipping);
            // An ESC right before END is a truncated packet, not an escape.
            let cut = std::mem::take(&mut self.escaped);
            if !skipped && !packet.is_empty() {
                let result = if cut {
                    Err("ends in the middle of an escape (ESC before END)".to_owned())
                } else {
                    self.osc_packet(&packet, out)
                };
                if let Err(problem) = result {
                    out.push(Err(SerialError::Packet {
                        offset: self.record_start,
                        problem,
                    }));
                }
            }
            self.record = packet;
            self.record.clear();
            self.record_start = self.offset + 1;
            return;
        }
        if self.skipping {
            return;
        }
        if std::mem::take(&mut self.escaped) {
            let byte = match byte {
                ESC_END => END,
                ESC_ESC => ESC,
                other => {
                    out.push(Err(SerialError::Packet {
                        offset: self.record_start,
                        problem: format!(
                            "invalid SLIP escape 0xDB 0x{other:02X} at byte {}; \
                             skipped to the next END",
                            self.offset - 1
                        ),
                    }));
                    self.record.clear();
                    self.skipping = true;
                    return;
                }
            };
            self.keep(byte, out);
        } else if byte == ESC {
            self.escaped = true;
        } else {
            self.keep(byte, out);
        }
    }

    /// Applies one packet's messages in order. A bad message is reported
    /// (with its index) and the rest still apply; only a packet that is not
    /// OSC at all is returned as an error.
    fn osc_packet(
        &mut self,
        packet: &[u8],
        out: &mut Vec<Result<ContactFrame, SerialError>>,
    ) -> Result<(), String> {
        let (_, packet) =
            rosc::decoder::decode_udp(packet).map_err(|e| format!("not an OSC packet: {e}"))?;
        let mut messages = Vec::new();
        flatten(&packet, &mut messages);
        for (index, message) in messages.into_iter().enumerate() {
            if let Err(problem) = self.osc_message(message, out) {
                out.push(Err(SerialError::Packet {
                    offset: self.record_start,
                    problem: format!("message {index} ({}): {problem}", shorten(&message.addr)),
                }));
            }
        }
        Ok(())
    }

    fn osc_message(
        &mut self,
        message: &OscMessage,
        out: &mut Vec<Result<ContactFrame, SerialError>>,
    ) -> Result<(), String> {
        let args = &message.args;
        let get = |at: usize, name: &str| {
            args.get(at)
                .ok_or_else(|| format!("argument {at} ({name}) is missing"))
        };
        let wrong = |at: usize, name: &str, expected: &str, got: &OscType| {
            format!(
                "argument {at} ({name}) should be {expected}, not {}",
                super::fields::osc_arg(got)
            )
        };
        let float = |at: usize, name: &str| -> Result<f64, String> {
            let value = match get(at, name)? {
                OscType::Float(v) => f64::from(*v),
                OscType::Double(v) => *v,
                other => return Err(wrong(at, name, "a float", other)),
            };
            if !value.is_finite() {
                return Err(format!("argument {at} ({name}) is {value}"));
            }
            Ok(value)
        };
        match message.addr.as_str() {
            "/pad/frame" => {
                self.end_frame(out);
                Ok(())
            }
            "/pad/contact" => {
                if args.len() > 5 {
                    return Err(format!(
                        "expected 4 or 5 arguments (i:id s:phase f:x f:y [f:pressure]), got {}",
                        args.len()
                    ));
                }
                let id = match get(0, "id")? {
                    OscType::Int(v) => {
                        u32::try_from(*v).map_err(|_| format!("argument 0 (id) {v} is negative"))?
                    }
                    other => return Err(wrong(0, "id", "an int32", other)),
                };
                let phase = match get(1, "phase")? {
                    OscType::String(s) => parse_phase(s).ok_or_else(|| {
                        format!(
                            "argument 1 (phase) `{}` is not d, m, u, down, move or up",
                            shorten(s)
                        )
                    })?,
                    other => return Err(wrong(1, "phase", "a string", other)),
                };
                let position = DVec2::new(float(2, "x")?, float(3, "y")?);
                let pressure = match args.get(4) {
                    Some(_) => Some(check_pressure(
                        float(4, "pressure")?,
                        "argument 4 (pressure)",
                    )?),
                    None => None,
                };
                self.contact(id, phase, position, pressure, out)
            }
            other => Err(format!(
                "unknown address `{}` (expected /pad/contact or /pad/frame)",
                shorten(other)
            )),
        }
    }

    /// Adds one stated contact (device units) to the pending frame, making
    /// its phase consistent with what the stage has been sent.
    fn contact(
        &mut self,
        id: u32,
        phase: Phase,
        device: DVec2,
        pressure: Option<f64>,
        out: &mut Vec<Result<ContactFrame, SerialError>>,
    ) -> Result<(), String> {
        if self.pending.iter().any(|c| c.id == id) {
            self.end_frame(out);
        }
        let was_down = self.down.contains_key(&id);
        let phase = match (phase, was_down) {
            (Phase::Up, false) => return Err(format!("contact {id} lifts but is not down")),
            (Phase::Up, true) => Phase::Up,
            (_, true) => Phase::Move,
            (_, false) => Phase::Down,
        };
        let mut contact = Contact::new(id, phase, self.calibration.map(device));
        contact.pressure = pressure;
        self.pending.push(contact);
        Ok(())
    }

    /// Sends the pending frame, if it has anything, and records what it left
    /// down.
    fn end_frame(&mut self, out: &mut Vec<Result<ContactFrame, SerialError>>) {
        if self.pending.is_empty() {
            return;
        }
        let contacts = std::mem::take(&mut self.pending);
        for contact in &contacts {
            if contact.phase == Phase::Up {
                self.down.remove(&contact.id);
            } else {
                self.down.insert(contact.id, contact.clone());
            }
        }
        out.push(Ok(self.frame(contacts)));
    }
}

fn parse_phase(text: &str) -> Option<Phase> {
    match text.to_ascii_lowercase().as_str() {
        "d" | "down" => Some(Phase::Down),
        "m" | "move" => Some(Phase::Move),
        "u" | "up" => Some(Phase::Up),
        _ => None,
    }
}

fn check_pressure(value: f64, what: &str) -> Result<f64, String> {
    if (0.0..=1.0).contains(&value) {
        Ok(value)
    } else {
        Err(format!("{what} {value} is outside 0..=1"))
    }
}

/// Garbage can be long; an error message quotes at most its start.
fn shorten(text: &str) -> String {
    const KEEP: usize = 40;
    match text.char_indices().nth(KEEP) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_owned(),
    }
}

fn flatten<'a>(packet: &'a OscPacket, out: &mut Vec<&'a OscMessage>) {
    match packet {
        OscPacket::Message(message) => out.push(message),
        OscPacket::Bundle(bundle) => {
            for inner in &bundle.content {
                flatten(inner, out);
            }
        }
    }
}

/// Reads `reader` until it ends or fails, sending every frame it completes
/// to `sink`. A full sink makes this wait (the port's kernel buffer absorbs
/// the burst; if it overflows, the decoder resynchronises at the next
/// delimiter), so no decoded frame is discarded here. Bad records are
/// skipped, and logged through a [`LogLimiter`]: a few lines, then a count.
///
/// Returns `Ok` once the sink is closed. When the stream ends or a read
/// fails, sends a frame lifting every contact still down and returns
/// [`SerialError::Closed`] or [`SerialError::Read`]: the caller decides
/// whether to reopen. When nothing at all arrives for `release_after`
/// while a contact is down, the contacts are lifted and reading goes on
/// (a pad that speaks again lands its contacts afresh).
pub async fn run_stream<R: AsyncRead + Unpin>(
    mut reader: R,
    mut decoder: SerialDecoder,
    release_after: std::time::Duration,
    sink: mpsc::Sender<ContactFrame>,
) -> Result<(), SerialError> {
    let mut buffer = vec![0u8; READ_CHUNK];
    let mut complaints = LogLimiter::new(Instant::now());
    let summary = |skipped: u64| {
        tracing::warn!("serial: {skipped} more bad records were skipped unlogged");
    };
    let mut heard = tokio::time::Instant::now();
    let error = loop {
        let holds = decoder.holds();
        let read = tokio::select! {
            read = reader.read(&mut buffer) => read,
            () = tokio::time::sleep_until(heard + release_after), if holds => {
                if let Some(frame) = decoder.lift_all() {
                    tracing::warn!(
                        "{}: silent for {release_after:?} holding {} contacts: letting go",
                        frame.source,
                        frame.contacts.len()
                    );
                    if sink.send(frame).await.is_err() {
                        return Ok(());
                    }
                }
                continue;
            }
            () = sink.closed() => {
                if let Some(skipped) = complaints.take_remaining() {
                    summary(skipped);
                }
                return Ok(());
            }
            () = summary_timer(complaints.summary_due()) => {
                if let Some(skipped) = complaints.take_summary(Instant::now()) {
                    summary(skipped);
                }
                continue;
            }
        };
        let len = match read {
            Ok(0) => break SerialError::Closed,
            Ok(len) => {
                heard = tokio::time::Instant::now();
                len
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => break SerialError::Read(e),
        };
        for item in decoder.push(&buffer[..len]) {
            match item {
                Ok(frame) => {
                    if sink.send(frame).await.is_err() {
                        return Ok(());
                    }
                }
                Err(e) => {
                    if complaints.allow(Instant::now()) {
                        let error = clip(&e.to_string(), MAX_ECHO);
                        tracing::warn!(%error, "serial: skipping bad input");
                    }
                }
            }
        }
    };
    if let Some(skipped) = complaints.take_remaining() {
        summary(skipped);
    }
    if let Some(frame) = decoder.lift_all() {
        // A closed sink has nobody left to tell; the error still goes back.
        let _ = sink.send(frame).await;
    }
    Err(error)
}

/// Opens the serial port at `path` (`/dev/ttyACM0`, …) at `baud` and runs
/// [`run_stream`] on it. Fails with [`SerialError::Open`] if the port cannot
/// be opened; otherwise as [`run_stream`].
pub async fn run_port(
    path: &str,
    baud: u32,
    decoder: SerialDecoder,
    release_after: std::time::Duration,
    sink: mpsc::Sender<ContactFrame>,
) -> Result<(), SerialError> {
    use tokio_serial::SerialPortBuilderExt;
    let port = tokio_serial::new(path, baud)
        .open_native_async()
        .map_err(|source| SerialError::Open {
            path: path.to_owned(),
            source,
        })?;
    run_stream(port, decoder, release_after, sink).await
}
