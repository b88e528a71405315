//! The show's clock as MIDI tells it: where a DAW's or a show-control
//! desk's transport is, in seconds, read from MIDI Time Code or from MIDI
//! clock and song position. A take records these readings beside its own
//! time, so an export can line its soundtrack up by the music's time
//! rather than by hand.
//!
//! **MIDI Time Code.** A running transport sends a quarter frame (`F1`)
//! every quarter of a frame, eight of them carrying one time code: piece 0
//! is sent as that frame begins, piece 7 a frame and three quarters later.
//! So when piece 7 completes a set, the transport is at the code plus
//! 7/4 frames ([`ShowClock`] reads it then, one reading each two frames).
//! Pieces out of order (a transport running backwards, a byte lost) drop
//! the set; the next piece 0 starts again. A full frame (`F0 7F … 01 01
//! … F7`) is a locate: the transport parked or jumped at that code.
//! Drop-frame 29.97 codes are counted as the frames they name (two frame
//! numbers skipped each minute but every tenth), so a code reads as real
//! seconds.
//!
//! **MIDI clock.** Song position (`F2`, in sixteenth notes) locates,
//! `FA` starts from zero, `FB` continues, `FC` stops, and 24 clocks (`F8`)
//! make a quarter note. Seconds need a tempo: the input's, constant (a
//! song whose tempo changes is followed through time code instead). A
//! reading is made at each sixteenth note while running.

use crate::midi::MidiMessage;

/// Where the show's transport is, as one message told it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShowTime {
    /// Seconds on the show's clock (time code from 00:00:00:00, or from
    /// the song's start).
    pub seconds: f64,
    /// The transport runs (quarter frames, clocks); a locate, a stop or a
    /// song position while stopped say where it is parked.
    pub running: bool,
}

/// What a MIDI input's show clock follows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClockKind {
    /// MIDI Time Code: quarter frames and full frames.
    TimeCode,
    /// MIDI clock and song position, at a constant tempo.
    Beats {
        /// Quarter notes a minute.
        tempo: f64,
    },
}

/// A MIDI time code's frame rate, as its two rate bits give it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameRate {
    /// 24 frames a second (film).
    Fps24,
    /// 25 frames a second (PAL video).
    Fps25,
    /// 29.97 frames a second, drop-frame code (NTSC video).
    Fps2997Drop,
    /// 30 frames a second.
    Fps30,
}

impl FrameRate {
    /// The rate of rate bits `bits` (0 to 3).
    pub fn of_bits(bits: u8) -> FrameRate {
        match bits & 3 {
            0 => FrameRate::Fps24,
            1 => FrameRate::Fps25,
            2 => FrameRate::Fps2997Drop,
            _ => FrameRate::Fps30,
        }
    }

    /// Frames a second, as played (29.97 is 30000/1001).
    pub fn fps(self) -> f64 {
        match self {
            FrameRate::Fps24 => 24.0,
            FrameRate::Fps25 => 25.0,
            FrameRate::Fps2997Drop => 30_000.0 / 1001.0,
            FrameRate::Fps30 => 30.0,
        }
    }
}

/// A time code: hours, minutes, seconds and frames at a rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeCode {
    /// Hours, 0 to 23.
    pub hours: u8,
    /// Minutes, 0 to 59.
    pub minutes: u8,
    /// Seconds, 0 to 59.
    pub seconds: u8,
    /// Frames, 0 to the rate's last.
    pub frames: u8,
    /// Its rate.
    pub rate: FrameRate,
}

impl TimeCode {
    /// The code of an hours byte with its rate in bits 5–6 (as a full
    /// frame and a quarter frames' set carry it) and the other fields.
    pub fn of_bytes(hours: u8, minutes: u8, seconds: u8, frames: u8) -> TimeCode {
        TimeCode {
            hours: hours & 0x1F,
            minutes: minutes & 0x3F,
            seconds: seconds & 0x3F,
            frames: frames & 0x1F,
            rate: FrameRate::of_bits(hours >> 5),
        }
    }

    /// Real seconds from 00:00:00:00 to this code.
    pub fn to_seconds(self) -> f64 {
        let minutes = u32::from(self.hours) * 60 + u32::from(self.minutes);
        let seconds = minutes * 60 + u32::from(self.seconds);
        match self.rate {
            FrameRate::Fps2997Drop => {
                // Frame numbers 0 and 1 are skipped at each minute but
                // every tenth: the code names fewer frames than 30 a second.
                let named = seconds * 30 + u32::from(self.frames);
                let dropped = 2 * (minutes - minutes / 10);
                f64::from(named - dropped.min(named)) / self.rate.fps()
            }
            rate => f64::from(seconds) + f64::from(self.frames) / rate.fps(),
        }
    }
}

/// MIDI clocks a quarter note.
const CLOCKS_PER_BEAT: f64 = 24.0;
/// MIDI clocks a sixteenth note (a song position's unit).
const CLOCKS_PER_SIXTEENTH: u32 = 6;

/// Follows one input's show clock: see the module's doc.
#[derive(Debug, Clone)]
pub struct ShowClock {
    kind: ClockKind,
    /// The quarter frames of the set being gathered.
    pieces: [u8; 8],
    /// The next piece the set wants (8: none, wait for a piece 0).
    next: u8,
    /// MIDI clocks from the song's start.
    clocks: u32,
    running: bool,
}

impl ShowClock {
    /// A clock that has heard nothing yet.
    pub fn new(kind: ClockKind) -> ShowClock {
        ShowClock {
            kind,
            pieces: [0; 8],
            next: 8,
            clocks: 0,
            running: false,
        }
    }

    /// Reads one message: the show's time it tells, if it tells one.
    pub fn message(&mut self, message: &MidiMessage) -> Option<ShowTime> {
        match self.kind {
            ClockKind::TimeCode => self.time_code(message),
            ClockKind::Beats { tempo } => self.beats(message, tempo),
        }
    }

    fn time_code(&mut self, message: &MidiMessage) -> Option<ShowTime> {
        match *message {
            MidiMessage::QuarterFrame { piece, value } => {
                let piece = piece & 7;
                if piece == 0 {
                    self.next = 0;
                }
                if piece != self.next {
                    self.next = 8;
                    return None;
                }
                self.pieces[usize::from(piece)] = value & 0x0F;
                self.next += 1;
                if piece < 7 {
                    return None;
                }
                self.next = 8;
                let byte = |i: usize| self.pieces[i] | self.pieces[i + 1] << 4;
                let code = TimeCode::of_bytes(byte(6), byte(4), byte(2), byte(0));
                Some(ShowTime {
                    seconds: code.to_seconds() + 1.75 / code.rate.fps(),
                    running: true,
                })
            }
            MidiMessage::FullFrame {
                hours,
                minutes,
                seconds,
                frames,
            } => {
                self.next = 8;
                Some(ShowTime {
                    seconds: TimeCode::of_bytes(hours, minutes, seconds, frames).to_seconds(),
                    running: false,
                })
            }
            _ => None,
        }
    }

    fn beats(&mut self, message: &MidiMessage, tempo: f64) -> Option<ShowTime> {
        match *message {
            MidiMessage::SongPosition { beats } => {
                self.clocks = u32::from(beats) * CLOCKS_PER_SIXTEENTH;
            }
            MidiMessage::Start => {
                self.clocks = 0;
                self.running = true;
            }
            MidiMessage::Continue => self.running = true,
            MidiMessage::Stop => self.running = false,
            MidiMessage::Clock if self.running => {
                self.clocks = self.clocks.saturating_add(1);
                if !self.clocks.is_multiple_of(CLOCKS_PER_SIXTEENTH) {
                    return None;
                }
            }
            _ => return None,
        }
        Some(ShowTime {
            seconds: f64::from(self.clocks) / CLOCKS_PER_BEAT * 60.0 / tempo,
            running: self.running,
        })
    }
}

/// MIDI Time Code's quarter frames of `code`, in order: the bytes a
/// transport sends from the moment the code's frame begins.
pub fn quarter_frames(code: TimeCode) -> [[u8; 2]; 8] {
    let rate = match code.rate {
        FrameRate::Fps24 => 0,
        FrameRate::Fps25 => 1,
        FrameRate::Fps2997Drop => 2,
        FrameRate::Fps30 => 3,
    };
    let hours = code.hours | rate << 5;
    let bytes = [code.frames, code.seconds, code.minutes, hours];
    std::array::from_fn(|piece| {
        let byte = bytes[piece / 2];
        let nibble = if piece % 2 == 0 {
            byte & 0x0F
        } else {
            byte >> 4
        };
        [0xF1, (piece as u8) << 4 | nibble]
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::midi::MidiDecoder;

    fn feed(clock: &mut ShowClock, bytes: &[u8]) -> Vec<ShowTime> {
        let mut times = Vec::new();
        MidiDecoder::new().feed(bytes, |m| times.extend(clock.message(&m)));
        times
    }

    fn code(h: u8, m: u8, s: u8, f: u8, rate: FrameRate) -> TimeCode {
        TimeCode {
            hours: h,
            minutes: m,
            seconds: s,
            frames: f,
            rate,
        }
    }

    #[test]
    fn a_set_of_quarter_frames_reads_at_its_last_piece() {
        let mut clock = ShowClock::new(ClockKind::TimeCode);
        let bytes: Vec<u8> = quarter_frames(code(1, 2, 3, 4, FrameRate::Fps25))
            .concat()
            .into_iter()
            .collect();
        let times = feed(&mut clock, &bytes);
        let expected = 3723.0 + (4.0 + 1.75) / 25.0;
        assert_eq!(times.len(), 1);
        assert!((times[0].seconds - expected).abs() < 1e-9, "{times:?}");
        assert!(times[0].running);
    }

    #[test]
    fn pieces_out_of_order_drop_the_set() {
        let mut clock = ShowClock::new(ClockKind::TimeCode);
        let mut frames = quarter_frames(code(0, 0, 10, 0, FrameRate::Fps30));
        frames.swap(3, 4);
        assert!(feed(&mut clock, &frames.concat()).is_empty());
        // Starting late (at piece 2) reads nothing until the next piece 0.
        let late: Vec<u8> = quarter_frames(code(0, 0, 10, 2, FrameRate::Fps30))[2..].concat();
        assert!(feed(&mut clock, &late).is_empty());
    }

    #[test]
    fn drop_frame_code_is_real_seconds() {
        // 00:10:00;00 drop-frame is exactly 17982 frames of 29.97.
        let ten = code(0, 10, 0, 0, FrameRate::Fps2997Drop).to_seconds();
        assert!((ten - 17_982.0 * 1001.0 / 30_000.0).abs() < 1e-9, "{ten}");
        // 00:01:00;02 is frame 1800 (frames ;00 and ;01 do not exist).
        let one = code(0, 1, 0, 2, FrameRate::Fps2997Drop).to_seconds();
        assert!((one - 1800.0 * 1001.0 / 30_000.0).abs() < 1e-9, "{one}");
    }

    #[test]
    fn a_full_frame_locates_without_running() {
        let mut clock = ShowClock::new(ClockKind::TimeCode);
        let times = feed(
            &mut clock,
            &[0xF0, 0x7F, 0x7F, 0x01, 0x01, 0x60, 0, 1, 15, 0xF7],
        );
        assert_eq!(
            times,
            [ShowTime {
                seconds: 1.5,
                running: false
            }]
        );
    }

    #[test]
    fn midi_clock_counts_sixteenths_from_the_song_position() {
        let mut clock = ShowClock::new(ClockKind::Beats { tempo: 120.0 });
        // Song position at bar 2 (16 sixteenths = 2 s at 120), continue,
        // then a sixteenth's six clocks.
        let mut bytes = vec![0xF2, 16, 0, 0xFB];
        bytes.extend([0xF8; 6]);
        bytes.push(0xFC);
        let times = feed(&mut clock, &bytes);
        let seconds: Vec<f64> = times.iter().map(|t| t.seconds).collect();
        assert_eq!(seconds, [2.0, 2.0, 2.125, 2.125]);
        assert_eq!(
            times.iter().map(|t| t.running).collect::<Vec<_>>(),
            [false, true, true, false]
        );
        // Clocks while stopped move nothing.
        assert!(feed(&mut clock, &[0xF8; 12]).is_empty());
    }
}
