//! Standard MIDI Files (`.mid`) as timed MIDI messages, so a recorded
//! controller performance (or one written by hand in a DAW) stands in for
//! the controller, as evemu captures stand in for touch screens: every
//! track merged in time, ticks turned into seconds through the file's
//! tempo map (or its SMPTE timing), each event put through the same
//! [`MidiDecoder`] a MIDI port is read with. Parsed by the `midly` crate.
//!
//! The file is read within `MAX_REPLAY_FILE_BYTES` like any replay; its
//! events are bounded by its size. A file that is not MIDI is refused
//! naming it and what `midly` says is wrong; a damaged one plays what can
//! be read, and [`MidiRead::damage`] says where reading stopped.
//!
//! [`write_midi_file`] writes one (`puppetry record` of a MIDI port):
//! channel messages as MIDI events and SysEx as SysEx events, which any
//! DAW reads, and what a file has no event for (time code quarter
//! frames, song position, clock, start and stop) as escape events of
//! their raw bytes, which the reader puts through the decoder too, so a
//! recorded transport replays.

use std::path::Path;

use midly::{MetaMessage, Timing, TrackEventKind};
use puppetry_mesh::file::{FileError, REPLAY_FILE};

use crate::midi::{MidiDecoder, MidiMessage};

/// A `.mid` that cannot be played.
#[derive(Debug, thiserror::Error)]
pub enum MidiFileError {
    /// The file cannot be read (or is past its size limit).
    #[error(transparent)]
    File(#[from] FileError),
    /// The file could not be written.
    #[error("{file}: cannot write: {source}")]
    Write {
        /// The file.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// It is not a Standard MIDI File, or a damaged one.
    #[error("{file}: not a Standard MIDI File: {problem}")]
    Parse {
        /// The file.
        file: String,
        /// What `midly` found wrong.
        problem: String,
    },
}

/// A message and when it is sent, in seconds from the file's start.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedMessage {
    /// Seconds from the start.
    pub t: f64,
    /// The message.
    pub message: MidiMessage,
}

/// A `.mid` read: its messages, and what of it could not be read.
#[derive(Debug, Clone, PartialEq)]
pub struct MidiRead {
    /// Every message, in time order (ties in track order).
    pub messages: Vec<TimedMessage>,
    /// Where reading stopped in a damaged file, one line each naming the
    /// file, the track and the byte (`midly` reads on past damage by
    /// leaving the rest of a track, or a whole chunk, out): empty for a
    /// whole file.
    pub damage: Vec<String>,
}

/// Every message of the file at `path`, in time order (ties in track
/// order), and where a damaged file's reading stopped.
pub fn read_midi_file(path: &Path) -> Result<MidiRead, MidiFileError> {
    let bytes = puppetry_mesh::file::read(path, REPLAY_FILE)?;
    let file = path.display().to_string();
    let (header, mut tracks) = midly::parse(&bytes).map_err(|e| MidiFileError::Parse {
        file: file.clone(),
        problem: e.to_string(),
    })?;
    let at = |rest: &[u8]| rest.as_ptr() as usize - bytes.as_ptr() as usize;
    let mut damage = Vec::new();
    let promised = tracks.size_hint().0;
    // Every event with its absolute tick, merged over the tracks.
    let mut events: Vec<(u64, usize, TrackEventKind)> = Vec::new();
    let mut read = 0usize;
    for (track, events_of) in tracks.by_ref().enumerate() {
        let Ok(mut events_of) = events_of else {
            continue;
        };
        read += 1;
        let mut tick = 0u64;
        let mut count = 0usize;
        loop {
            let left = events_of.unread();
            match events_of.next() {
                Some(Ok(event)) => {
                    tick += u64::from(event.delta.as_int());
                    events.push((tick, track, event.kind));
                    count += 1;
                }
                // Lenient `midly` ends a track at the first event it
                // cannot read, dropping the rest unsaid: say it.
                None if !left.is_empty() => {
                    damage.push(format!(
                        "{file}: track {}: an event it cannot read at byte {} (after {count} \
                         events); the rest of the track ({} bytes) is left out",
                        track + 1,
                        at(left),
                        left.len()
                    ));
                    break;
                }
                Some(Err(_)) | None => break,
            }
        }
    }
    if read < promised {
        damage.push(format!(
            "{file}: its header promises {promised} tracks, {read} could be read (a damaged \
             chunk is left out)"
        ));
    }
    let smf_timing = header.timing;
    events.sort_by_key(|&(tick, track, _)| (tick, track));
    // Seconds a tick: SMPTE timing is fixed; metrical follows the tempo
    // (microseconds a quarter note, 120 bpm until the first tempo event).
    let (mut per_tick, per_beat) = match smf_timing {
        Timing::Metrical(ticks) => (0.5 / f64::from(ticks.as_int().max(1)), Some(ticks)),
        Timing::Timecode(fps, sub) => (
            1.0 / (f64::from(fps.as_f32()) * f64::from(sub.max(1))),
            None,
        ),
    };
    let mut decoder = MidiDecoder::new();
    let mut out = Vec::new();
    let (mut last_tick, mut t) = (0u64, 0.0f64);
    let mut raw = Vec::new();
    for (tick, _, kind) in events {
        t += (tick - last_tick) as f64 * per_tick;
        last_tick = tick;
        if let (TrackEventKind::Meta(MetaMessage::Tempo(micros)), Some(ticks)) = (kind, per_beat) {
            per_tick = f64::from(micros.as_int()) / 1e6 / f64::from(ticks.as_int().max(1));
            continue;
        }
        raw.clear();
        match kind {
            TrackEventKind::Midi { .. } => {
                if let Some(live) = kind.as_live_event() {
                    let _ = live.write_std(&mut raw);
                }
            }
            // A SysEx event's data follows its F0 (and ends in F7 when
            // not split across events).
            TrackEventKind::SysEx(data) => {
                raw.push(0xF0);
                raw.extend_from_slice(data);
            }
            // Raw bytes a file has no event for (what `write_midi_file`
            // writes of a transport), or a SysEx's continued part.
            TrackEventKind::Escape(data) => raw.extend_from_slice(data),
            TrackEventKind::Meta(_) => continue,
        }
        decoder.feed(&raw, |message| out.push(TimedMessage { t, message }));
    }
    Ok(MidiRead {
        messages: out,
        damage,
    })
}

/// Ticks a quarter note in the files written here (at 120 bpm: 960 a
/// second, about a millisecond each).
const WRITTEN_TICKS_PER_BEAT: u16 = 480;
/// Ticks a second in the files written here.
const WRITTEN_TICKS_PER_SECOND: f64 = WRITTEN_TICKS_PER_BEAT as f64 * 2.0;

/// Writes `messages` (in time order) to `path` as a one-track Standard
/// MIDI File at 120 bpm, replacing what is there only once it is whole
/// (written beside it and renamed).
pub fn write_midi_file(messages: &[TimedMessage], path: &Path) -> Result<(), MidiFileError> {
    use midly::num::{u15, u24, u28};
    use midly::{Format, Header, Smf, TrackEvent};
    let mut bytes = Vec::new();
    let mut spans = Vec::with_capacity(messages.len());
    for m in messages {
        let start = bytes.len();
        m.message.encode(&mut bytes);
        spans.push((m.t, start..bytes.len()));
    }
    let mut track = vec![TrackEvent {
        delta: u28::new(0),
        kind: TrackEventKind::Meta(MetaMessage::Tempo(u24::new(500_000))),
    }];
    let mut last = 0u64;
    for (t, span) in spans {
        let raw = &bytes[span];
        let tick = (t.max(0.0) * WRITTEN_TICKS_PER_SECOND).round() as u64;
        let delta = tick
            .saturating_sub(last)
            .min(u64::from(u28::max_value().as_int()));
        last = last.max(tick);
        let kind = match raw[0] {
            0x80..=0xEF => match midly::live::LiveEvent::parse(raw) {
                Ok(midly::live::LiveEvent::Midi { channel, message }) => {
                    TrackEventKind::Midi { channel, message }
                }
                _ => TrackEventKind::Escape(raw),
            },
            0xF0 => TrackEventKind::SysEx(&raw[1..]),
            _ => TrackEventKind::Escape(raw),
        };
        track.push(TrackEvent {
            delta: u28::new(delta as u32),
            kind,
        });
    }
    track.push(TrackEvent {
        delta: u28::new(0),
        kind: TrackEventKind::Meta(MetaMessage::EndOfTrack),
    });
    let mut smf = Smf::new(Header::new(
        Format::SingleTrack,
        Timing::Metrical(u15::new(WRITTEN_TICKS_PER_BEAT)),
    ));
    smf.tracks.push(track);
    let mut out = Vec::new();
    let write_error = |source| MidiFileError::Write {
        file: path.display().to_string(),
        source,
    };
    smf.write_std(&mut out).map_err(write_error)?;
    puppetry_mesh::file::write_atomically(path, &out).map_err(write_error)
}

#[cfg(test)]
mod tests {
    use super::*;
    use midly::num::{u4, u7, u15, u24, u28};
    use midly::{Format, Header, Smf, TrackEvent};

    fn cc(delta: u32, controller: u8, value: u8) -> TrackEvent<'static> {
        TrackEvent {
            delta: u28::new(delta),
            kind: TrackEventKind::Midi {
                channel: u4::new(0),
                message: midly::MidiMessage::Controller {
                    controller: u7::new(controller),
                    value: u7::new(value),
                },
            },
        }
    }

    /// Two tracks merged in time; 120 bpm, then 60 bpm from beat 1; a
    /// show-control GO as a SysEx event.
    #[test]
    fn tracks_merge_and_ticks_follow_the_tempo_map() {
        let mut smf = Smf::new(Header::new(
            Format::Parallel,
            Timing::Metrical(u15::new(480)),
        ));
        smf.tracks.push(vec![
            cc(0, 1, 10),
            cc(480, 1, 20), // beat 1 at 120 bpm: 0.5 s
            TrackEvent {
                delta: u28::new(0),
                kind: TrackEventKind::Meta(MetaMessage::Tempo(u24::new(1_000_000))),
            },
            cc(480, 1, 30), // one beat at 60 bpm later: 1.5 s
        ]);
        let go: &[u8] = &[0x7F, 0x01, 0x02, 0x01, 0x01, b'4', 0xF7];
        smf.tracks.push(vec![
            cc(240, 2, 99), // 0.25 s
            TrackEvent {
                delta: u28::new(720),
                kind: TrackEventKind::SysEx(go), // tick 960, as track 0's last
            },
        ]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("show.mid");
        smf.save(&path).unwrap();
        let timed = read_midi_file(&path).unwrap();
        assert_eq!(timed.damage, Vec::<String>::new());
        let at: Vec<(f64, &MidiMessage)> =
            timed.messages.iter().map(|m| (m.t, &m.message)).collect();
        let control = |controller, value| MidiMessage::ControlChange {
            channel: 0,
            controller,
            value,
        };
        assert_eq!(
            at,
            [
                (0.0, &control(1, 10)),
                (0.25, &control(2, 99)),
                (0.5, &control(1, 20)),
                // Tick 960 in both tracks: track order.
                (1.5, &control(1, 30)),
                (
                    1.5,
                    &MidiMessage::ShowControl {
                        device: 1,
                        command: crate::midi::ShowCommand::Go,
                        cue: Some("4".into())
                    }
                ),
            ]
        );
        std::fs::write(&path, b"MThd garbage").unwrap();
        let e = read_midi_file(&path).unwrap_err().to_string();
        assert!(
            e.contains("show.mid") && e.contains("not a Standard MIDI File"),
            "{e}"
        );
    }

    /// Time code written as raw `F1` events (not `F7`-escaped, as some
    /// tools do) stops `midly` in its track: what was read plays, and the
    /// damage names the file, the track and the byte where reading
    /// stopped. A chunk that cannot be read is said too.
    #[test]
    fn a_damaged_file_says_where_reading_stopped() {
        let track: &[u8] = &[
            0x00, 0xB0, 0x01, 0x0A, // CC 1 = 10
            0x00, 0xF1, 0x23, // a raw quarter frame: no SMF event
            0x00, 0xB0, 0x01, 0x14, // never read
            0x00, 0xFF, 0x2F, 0x00, // end of track
        ];
        let mut bytes = b"MThd\0\0\0\x06\0\x01\0\x03\x01\xE0".to_vec();
        bytes.extend_from_slice(b"MTrk");
        bytes.extend_from_slice(&(track.len() as u32).to_be_bytes());
        bytes.extend_from_slice(track);
        // The second of three tracks promised is cut short, the third
        // never comes.
        bytes.extend_from_slice(b"MTrk\0\0\x01\0\0");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("desk.mid");
        std::fs::write(&path, &bytes).unwrap();
        let read = read_midi_file(&path).unwrap();
        assert_eq!(
            read.messages,
            [TimedMessage {
                t: 0.0,
                message: MidiMessage::ControlChange {
                    channel: 0,
                    controller: 1,
                    value: 10
                }
            }]
        );
        assert_eq!(read.damage.len(), 3, "{:?}", read.damage);
        let file = path.display();
        assert_eq!(
            read.damage[0],
            format!(
                "{file}: track 1: an event it cannot read at byte 26 (after 1 events); the rest \
                 of the track (11 bytes) is left out"
            )
        );
        assert!(
            read.damage[1].starts_with(&format!(
                "{file}: track 2: an event it cannot read at byte 45"
            )),
            "{}",
            read.damage[1]
        );
        assert!(
            read.damage[2].starts_with(&format!(
                "{file}: its header promises 3 tracks, 2 could be read"
            )),
            "{}",
            read.damage[2]
        );
    }

    #[test]
    fn a_written_file_reads_back_with_its_transport() {
        use crate::midi::ShowCommand;
        let at = |t: f64, message| TimedMessage { t, message };
        let messages = vec![
            at(
                0.0,
                MidiMessage::ControlChange {
                    channel: 0,
                    controller: 16,
                    value: 100,
                },
            ),
            at(0.01, MidiMessage::QuarterFrame { piece: 0, value: 3 }),
            at(0.02, MidiMessage::QuarterFrame { piece: 1, value: 1 }),
            at(0.25, MidiMessage::SongPosition { beats: 300 }),
            at(0.25, MidiMessage::Continue),
            at(0.3, MidiMessage::Clock),
            at(
                0.5,
                MidiMessage::NoteOn {
                    channel: 9,
                    note: 36,
                    velocity: 90,
                },
            ),
            at(
                0.75,
                MidiMessage::ShowControl {
                    device: 1,
                    command: ShowCommand::Go,
                    cue: Some("12.5".into()),
                },
            ),
            at(
                1.0,
                MidiMessage::FullFrame {
                    hours: 0x21,
                    minutes: 0,
                    seconds: 3,
                    frames: 4,
                },
            ),
            at(
                1.5,
                MidiMessage::PitchBend {
                    channel: 2,
                    value: 12_345,
                },
            ),
        ];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("take.mid");
        write_midi_file(&messages, &path).unwrap();
        let read = read_midi_file(&path).unwrap().messages;
        assert_eq!(read.len(), messages.len(), "{read:?}");
        for (r, m) in read.iter().zip(&messages) {
            assert_eq!(r.message, m.message);
            assert!((r.t - m.t).abs() <= 1.0 / 960.0, "{r:?} against {m:?}");
        }
        // midly reads it as a plain file too: a DAW would.
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(Smf::parse(&bytes).unwrap().tracks.len(), 1);
    }
}
