//! Replaying files as input sources: an evemu capture (through the same
//! [`TouchDecoder`] a live device uses), a hid-recorder capture (through the
//! same [`HidTouchDecoder`] a live HID digitizer uses) or a recording, as a
//! plain iterator
//! of frames ([`ReplaySource::frames`], for tests and benchmarks) or paced
//! into the daemon's bounded channel by [`replay`]. Parsing happens up front
//! in [`ReplaySource::open`], so a bad file fails before anything plays and
//! the iterator itself cannot fail. Only the pacing is async.

use puppetry_mesh::file;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use glam::DVec2;
use tokio::sync::mpsc;
use tokio::time::Instant;

use super::evdev::{InputEvent, TouchDecoder};
use super::evemu::{EvemuError, EvemuFile};
use super::hid::{HidError, HidTouchDecoder};
use super::hid_recording::{HidRecording, HidRecordingError};
use super::recording::{RecordingError, parse_recording};
use super::{Calibration, ContactFrame, SourceId};

/// Why a file cannot be replayed. Everything is checked when the file is
/// opened, so playing it never fails.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// Cannot be read, not a regular file, or past
    /// `MAX_REPLAY_FILE_BYTES`.
    #[error(transparent)]
    File(#[from] file::FileError),
    /// An evemu capture does not parse, or its device cannot be decoded.
    #[error(transparent)]
    Evemu(#[from] EvemuError),
    /// A recording line is not a valid frame.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// A hid-recorder capture does not parse.
    #[error(transparent)]
    HidRecording(#[from] HidRecordingError),
    /// A hid-recorder capture's report descriptor is unusable: not a touch
    /// digitizer, say.
    #[error("{file}: {source}")]
    HidDevice {
        /// The capture, as messages name it.
        file: String,
        /// Why.
        source: HidError,
    },
    /// The decoder refuses one of a hid-recorder capture's reports.
    #[error("{file}: report {index} (at {time} s): {source}")]
    HidReport {
        /// The capture, as messages name it.
        file: String,
        /// Counting from 1, in file order.
        index: usize,
        /// The report's time in the capture, seconds.
        time: f64,
        /// Why.
        source: HidError,
    },
}

/// How fast [`replay`] plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pacing {
    /// Each frame when its timestamp says, counted from the first frame.
    #[default]
    RealTime,
    /// Each frame as soon as the receiver takes it.
    AsFastAsPossible,
}

/// A parsed file ready to play, any number of times. Cheap to clone.
#[derive(Debug, Clone)]
pub struct ReplaySource {
    inner: Arc<Inner>,
}

#[derive(Debug)]
enum Inner {
    Evemu {
        events: Vec<InputEvent>,
        /// Fresh; cloned for every playing so each starts from no contacts.
        decoder: Box<TouchDecoder>,
    },
    Recording(Vec<ContactFrame>),
}

impl ReplaySource {
    /// Reads `path`: a recording when its first non-blank character is `{`,
    /// a hid-recorder capture when it is named `*.hid` or its first item is
    /// an `R:` or `D:` line, else an evemu capture. A capture's frames come
    /// from source `replay` with the device's ranges fitted to a
    /// `stage_size` (width, height) stage.
    pub fn open(path: &Path, stage_size: impl Into<DVec2>) -> Result<ReplaySource, ReplayError> {
        ReplaySource::open_with(path, SourceId::from("replay"), stage_size.into(), None)
    }

    /// [`open`](ReplaySource::open) choosing a capture's source id and, if
    /// given, its calibration. A recording is already in stage coordinates
    /// and keeps the sources it recorded.
    pub fn open_with(
        path: &Path,
        source: SourceId,
        stage_size: DVec2,
        calibration: Option<Calibration>,
    ) -> Result<ReplaySource, ReplayError> {
        let file = path.display().to_string();
        let text = file::read_text(path, file::REPLAY_FILE)?;
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("hid"))
        {
            let capture = HidRecording::parse(&file, &text)?;
            return ReplaySource::from_hid(&file, &capture, source, stage_size, calibration);
        }
        ReplaySource::parse(&file, &text, source, stage_size, calibration)
    }

    /// [`open_with`](ReplaySource::open_with) for text already in memory,
    /// named `file` in errors.
    pub fn parse(
        file: &str,
        text: &str,
        source: SourceId,
        stage_size: DVec2,
        calibration: Option<Calibration>,
    ) -> Result<ReplaySource, ReplayError> {
        if text
            .trim_start_matches('\u{feff}')
            .trim_start()
            .starts_with('{')
        {
            return Ok(ReplaySource::from_frames(parse_recording(file, text)?));
        }
        if is_hid_recording(text) {
            let capture = HidRecording::parse(file, text)?;
            return ReplaySource::from_hid(file, &capture, source, stage_size, calibration);
        }
        let capture = EvemuFile::parse(file, text)?;
        let calibration = match calibration {
            Some(c) => c,
            None => capture.fit_calibration(stage_size)?,
        };
        ReplaySource::from_evemu(&capture, source, calibration)
    }

    /// A capture already parsed, decoded through a fresh [`TouchDecoder`]
    /// that reports as `source`; fails when the captured device has no
    /// position axes.
    pub fn from_evemu(
        capture: &EvemuFile,
        source: SourceId,
        calibration: Calibration,
    ) -> Result<ReplaySource, ReplayError> {
        let decoder = capture.decoder(source, calibration)?;
        Ok(ReplaySource {
            inner: Arc::new(Inner::Evemu {
                events: capture.events.clone(),
                decoder: Box::new(decoder),
            }),
        })
    }

    /// Decodes a hid-recorder capture up front, so a report the decoder
    /// rejects fails here, named by its place in `file`, rather than
    /// mid-play. Without a `calibration` the descriptor's X/Y ranges are
    /// fitted to `stage_size`. Contacts still down at the end are lifted at
    /// the last report's time.
    pub fn from_hid(
        file: &str,
        capture: &HidRecording,
        source: SourceId,
        stage_size: DVec2,
        calibration: Option<Calibration>,
    ) -> Result<ReplaySource, ReplayError> {
        let mut decoder =
            HidTouchDecoder::new(&capture.descriptor, source, calibration, stage_size).map_err(
                |source| ReplayError::HidDevice {
                    file: file.to_string(),
                    source,
                },
            )?;
        let mut frames = Vec::new();
        for (index, (time, report)) in capture.reports.iter().enumerate() {
            let frame = decoder
                .push(report, *time)
                .map_err(|source| ReplayError::HidReport {
                    file: file.to_string(),
                    index: index + 1,
                    time: *time,
                    source,
                })?;
            frames.extend(frame);
        }
        let end = capture.reports.last().map_or(0.0, |(time, _)| *time);
        frames.extend(decoder.lift_all(end));
        Ok(ReplaySource::from_frames(frames))
    }

    /// Frames already in stage coordinates, played as they are.
    pub fn from_frames(frames: Vec<ContactFrame>) -> ReplaySource {
        ReplaySource {
            inner: Arc::new(Inner::Recording(frames)),
        }
    }

    /// Every frame of one playing, from the start. A capture that ends with
    /// contacts still down gets a last frame lifting them.
    pub fn frames(&self) -> Frames {
        let decoder = match &*self.inner {
            Inner::Evemu { decoder, .. } => Some((**decoder).clone()),
            Inner::Recording(_) => None,
        };
        Frames {
            inner: Arc::clone(&self.inner),
            next: 0,
            decoder,
            done: false,
        }
    }
}

impl IntoIterator for ReplaySource {
    type Item = ContactFrame;
    type IntoIter = Frames;

    fn into_iter(self) -> Frames {
        self.frames()
    }
}

/// Whether the first item of `text` (skipping blank and `#` lines) is a
/// hid-recorder `R:` descriptor or `D:` device line; evemu captures have
/// neither.
fn is_hid_recording(text: &str) -> bool {
    text.lines()
        .map(|line| line.trim_start_matches('\u{feff}').trim())
        .find(|line| !line.is_empty() && !line.starts_with('#'))
        .is_some_and(|line| line.starts_with("R:") || line.starts_with("D:"))
}

/// One playing of a [`ReplaySource`]; owns what it needs, so it can move
/// into a task.
#[derive(Debug)]
pub struct Frames {
    inner: Arc<Inner>,
    next: usize,
    decoder: Option<TouchDecoder>,
    done: bool,
}

impl Iterator for Frames {
    type Item = ContactFrame;

    fn next(&mut self) -> Option<ContactFrame> {
        if self.done {
            return None;
        }
        match (&*self.inner, &mut self.decoder) {
            (Inner::Recording(frames), _) => {
                let frame = frames.get(self.next).cloned();
                self.next += 1;
                self.done = frame.is_none();
                frame
            }
            (Inner::Evemu { events, .. }, Some(decoder)) => {
                while let Some(&event) = events.get(self.next) {
                    self.next += 1;
                    if let Some(frame) = decoder.push(event) {
                        return Some(frame);
                    }
                }
                self.done = true;
                let end = events.last().map_or(0.0, |e| e.time);
                decoder.lift_all(end)
            }
            (Inner::Evemu { .. }, None) => None,
        }
    }
}

/// How a [`replay`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplaySummary {
    /// Frames the receiver took.
    pub frames_sent: usize,
    /// The receiver went away before the end; the replay stopped there.
    pub sink_closed: bool,
}

/// Longest wait honoured between two frames; a larger gap is a broken
/// timestamp, and the cap keeps the deadline arithmetic from overflowing.
const MAX_GAP_SECONDS: f64 = 1e9;

/// Plays `frames` into `sink` until they run out. Every frame is delivered:
/// a full channel makes the replay wait, never skip. In real time, frame `i`
/// is sent no earlier than `time[i] − time[0]` after the start; a frame
/// that is late (because the receiver was slow) goes at once, and the
/// schedule does not slip. Timestamps that go backwards send at once.
pub async fn replay<I>(frames: I, pacing: Pacing, sink: mpsc::Sender<ContactFrame>) -> ReplaySummary
where
    I: IntoIterator<Item = ContactFrame>,
{
    let start = Instant::now();
    let mut first_time = None;
    let mut frames_sent = 0;
    for frame in frames {
        if pacing == Pacing::RealTime {
            let first = *first_time.get_or_insert(frame.time);
            let offset = (frame.time - first).clamp(0.0, MAX_GAP_SECONDS);
            let offset = Duration::try_from_secs_f64(offset).unwrap_or(Duration::ZERO);
            let due = start + offset;
            if due > Instant::now() {
                tokio::time::sleep_until(due).await;
            }
        }
        if sink.send(frame).await.is_err() {
            return ReplaySummary {
                frames_sent,
                sink_closed: true,
            };
        }
        frames_sent += 1;
    }
    ReplaySummary {
        frames_sent,
        sink_closed: false,
    }
}
