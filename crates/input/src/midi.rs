//! MIDI 1.0 bytes to messages: the decoder a raw MIDI port (an ALSA
//! `/dev/snd/midiC*D*`, a serial MIDI interface, a pipe) is read through,
//! one byte at a time, whatever the chunks the bytes arrive in.
//!
//! What a controller and a show-control desk send, and what this keeps:
//!
//! - **Channel messages** (note off/on with velocity — a note on of
//!   velocity 0 is a note off —, polyphonic and channel pressure, control
//!   change, program change, pitch bend as 14 bits), with **running
//!   status**: a data byte after a complete message repeats its status.
//! - **Real-time bytes** (`F8` clock, `FA` start, `FB` continue, `FC` stop,
//!   `FE` active sensing, `FF` reset) may come between any two bytes, in the
//!   middle of a message or a SysEx too: each is a message at once, and
//!   what it interrupted goes on.
//! - **System common**: MIDI Time Code quarter frames (`F1`), song position
//!   (`F2`), song select (`F3`), tune request (`F6`); each cancels running
//!   status, as the standard says.
//! - **SysEx** (`F0 … F7`, any length): MIDI Show Control
//!   (`F0 7F <device> 02 <format> <command> [cue] F7`) GO, STOP and RESUME
//!   with their cue number, and MIDI Time Code full frames
//!   (`F0 7F <device> 01 01 hr mn sc fr F7`, a locate) are messages; any
//!   other SysEx is skipped, only
//!   its first [`MAX_MIDI_SYSEX_BYTES`] kept to read it by.
//! - **Damage** never panics nor stalls: a status byte cutting a message
//!   short drops the partial message, data bytes with no status to go with
//!   them are dropped, an unused status (`F4`, `F5`, `F9`, `FD`) is ignored;
//!   each is counted ([`MidiDecoder::dropped`]) for the device loop's
//!   rate-limited log line.
//!
//! 14-bit controllers (a coarse CC 0–31 and its fine CC 32–63) are paired
//! by [`Controls`], which the mapping reads values through.

use puppetry_limits::midi::MAX_MIDI_SYSEX_BYTES;

/// A MIDI channel, 0 to 15 (shown to people as 1 to 16).
pub type Channel = u8;

/// A decoded MIDI message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MidiMessage {
    /// A key released (or pressed with velocity 0).
    NoteOff {
        /// Its channel.
        channel: Channel,
        /// The key, 0 to 127 (60 is middle C).
        note: u8,
        /// Release velocity, 0 to 127.
        velocity: u8,
    },
    /// A key pressed, velocity 1 to 127.
    NoteOn {
        /// Its channel.
        channel: Channel,
        /// The key, 0 to 127.
        note: u8,
        /// How hard, 1 to 127.
        velocity: u8,
    },
    /// Pressure on one held key (polyphonic aftertouch), 0 to 127.
    KeyPressure {
        /// Its channel.
        channel: Channel,
        /// The key.
        note: u8,
        /// The pressure.
        pressure: u8,
    },
    /// A control change (a fader, knob, button or pedal), 0 to 127.
    ControlChange {
        /// Its channel.
        channel: Channel,
        /// The controller number, 0 to 127.
        controller: u8,
        /// Its value, 0 to 127.
        value: u8,
    },
    /// A program (preset) chosen, 0 to 127.
    ProgramChange {
        /// Its channel.
        channel: Channel,
        /// The program.
        program: u8,
    },
    /// Pressure on the keyboard as a whole (channel aftertouch), 0 to 127.
    ChannelPressure {
        /// Its channel.
        channel: Channel,
        /// The pressure.
        pressure: u8,
    },
    /// The pitch wheel, 14 bits: 0 to 16383, 8192 at rest.
    PitchBend {
        /// Its channel.
        channel: Channel,
        /// The wheel's position.
        value: u16,
    },
    /// A MIDI Time Code quarter frame: which eighth of the time code
    /// (`piece`, 0 to 7) and its four bits.
    QuarterFrame {
        /// Which piece: frames low/high, seconds low/high, minutes
        /// low/high, hours low/high and rate.
        piece: u8,
        /// Its four bits.
        value: u8,
    },
    /// Song position, in sixteenth notes (MIDI beats) from the start.
    SongPosition {
        /// Sixteenth notes, 0 to 16383.
        beats: u16,
    },
    /// A song chosen, 0 to 127.
    SongSelect {
        /// The song.
        song: u8,
    },
    /// Tune request (analogue synths tune themselves).
    TuneRequest,
    /// Timing clock: 24 a quarter note.
    Clock,
    /// Start the sequence from its beginning.
    Start,
    /// Continue from where it stopped.
    Continue,
    /// Stop the sequence.
    Stop,
    /// Active sensing: the sender is alive (every 300 ms at most).
    ActiveSensing,
    /// Reset everything to power-up state.
    Reset,
    /// A MIDI Time Code full frame: the clock located at a time code
    /// (sent when a transport jumps, or parked), its rate in the hour
    /// byte's bits 5–6 as quarter frames' piece 7 has them.
    FullFrame {
        /// Hours (0–23) with the rate in bits 5–6, as sent.
        hours: u8,
        /// Minutes, 0 to 59.
        minutes: u8,
        /// Seconds, 0 to 59.
        seconds: u8,
        /// Frames, 0 to 29.
        frames: u8,
    },
    /// A MIDI Show Control command to the devices `device` addresses
    /// (`0x7F`: all).
    ShowControl {
        /// The device id it is sent to, 0 to 127.
        device: u8,
        /// The command.
        command: ShowCommand,
        /// The cue number, as sent (`"12.5"`), if any.
        cue: Option<String>,
    },
}

impl MidiMessage {
    /// The message's bytes, as a port carries them (every status byte
    /// written, no running status), appended to `out`: what
    /// [`MidiDecoder`] reads back as this message. A show-control command
    /// is written in the "all types" command format with its cue number
    /// only.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let channel = |status: u8, channel: &Channel| status | (channel & 0x0F);
        match self {
            MidiMessage::NoteOff {
                channel: c,
                note,
                velocity,
            } => out.extend([channel(0x80, c), note & 0x7F, velocity & 0x7F]),
            MidiMessage::NoteOn {
                channel: c,
                note,
                velocity,
            } => out.extend([channel(0x90, c), note & 0x7F, velocity & 0x7F]),
            MidiMessage::KeyPressure {
                channel: c,
                note,
                pressure,
            } => out.extend([channel(0xA0, c), note & 0x7F, pressure & 0x7F]),
            MidiMessage::ControlChange {
                channel: c,
                controller,
                value,
            } => out.extend([channel(0xB0, c), controller & 0x7F, value & 0x7F]),
            MidiMessage::ProgramChange {
                channel: c,
                program,
            } => out.extend([channel(0xC0, c), program & 0x7F]),
            MidiMessage::ChannelPressure {
                channel: c,
                pressure,
            } => out.extend([channel(0xD0, c), pressure & 0x7F]),
            MidiMessage::PitchBend { channel: c, value } => out.extend([
                channel(0xE0, c),
                (value & 0x7F) as u8,
                (value >> 7 & 0x7F) as u8,
            ]),
            MidiMessage::QuarterFrame { piece, value } => {
                out.extend([0xF1, (piece & 7) << 4 | (value & 0x0F)]);
            }
            MidiMessage::SongPosition { beats } => {
                out.extend([0xF2, (beats & 0x7F) as u8, (beats >> 7 & 0x7F) as u8]);
            }
            MidiMessage::SongSelect { song } => out.extend([0xF3, song & 0x7F]),
            MidiMessage::TuneRequest => out.push(0xF6),
            MidiMessage::Clock => out.push(0xF8),
            MidiMessage::Start => out.push(0xFA),
            MidiMessage::Continue => out.push(0xFB),
            MidiMessage::Stop => out.push(0xFC),
            MidiMessage::ActiveSensing => out.push(0xFE),
            MidiMessage::Reset => out.push(0xFF),
            MidiMessage::FullFrame {
                hours,
                minutes,
                seconds,
                frames,
            } => out.extend([
                0xF0,
                0x7F,
                0x7F,
                0x01,
                0x01,
                hours & 0x7F,
                minutes & 0x7F,
                seconds & 0x7F,
                frames & 0x7F,
                0xF7,
            ]),
            MidiMessage::ShowControl {
                device,
                command,
                cue,
            } => {
                let command = match command {
                    ShowCommand::Go => 0x01,
                    ShowCommand::Stop => 0x02,
                    ShowCommand::Resume => 0x03,
                };
                out.extend([0xF0, 0x7F, device & 0x7F, 0x02, 0x7F, command]);
                if let Some(cue) = cue {
                    out.extend(cue.bytes().filter(|b| b.is_ascii_digit() || *b == b'.'));
                }
                out.push(0xF7);
            }
        }
    }
}

/// The MIDI Show Control commands the stage answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShowCommand {
    /// `01`: go to the cue (or the next one).
    Go,
    /// `02`: stop.
    Stop,
    /// `03`: resume what was stopped.
    Resume,
}

/// How a decoder is in the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Within {
    /// Waiting for a status byte (or data under running status).
    Idle,
    /// Collecting a message of `status`: `have` of its data bytes.
    Message { status: u8, have: usize },
    /// Inside a SysEx, until `F7` (or a status byte cutting it short).
    SysEx,
}

/// Decodes a MIDI byte stream, byte by byte: see the module's doc.
/// Holds at most [`MAX_MIDI_SYSEX_BYTES`] of a SysEx; allocates only the
/// cue text of a show-control message.
#[derive(Debug, Clone)]
pub struct MidiDecoder {
    within: Within,
    /// The status data bytes are read under (running status); none after a
    /// system message.
    running: Option<u8>,
    data: [u8; 2],
    sysex: Vec<u8>,
    /// Bytes of the current SysEx past what is kept.
    sysex_overflow: bool,
    dropped: u64,
}

impl Default for MidiDecoder {
    fn default() -> Self {
        MidiDecoder::new()
    }
}

/// Data bytes a channel message of `status` carries.
fn data_bytes(status: u8) -> usize {
    match status & 0xF0 {
        0xC0 | 0xD0 => 1,
        _ => 2,
    }
}

impl MidiDecoder {
    /// A decoder at the start of a stream.
    pub fn new() -> MidiDecoder {
        MidiDecoder {
            within: Within::Idle,
            running: None,
            data: [0; 2],
            sysex: Vec::with_capacity(MAX_MIDI_SYSEX_BYTES),
            sysex_overflow: false,
            dropped: 0,
        }
    }

    /// Bytes and partial messages dropped so far (data with no status, a
    /// message cut short, an unused status, a SysEx cut short).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Decodes `bytes`, calling `out` with each complete message in order.
    pub fn feed(&mut self, bytes: &[u8], mut out: impl FnMut(MidiMessage)) {
        for &b in bytes {
            if let Some(message) = self.push(b) {
                out(message);
            }
        }
    }

    /// Takes one byte; returns the message it completes, if any.
    pub fn push(&mut self, byte: u8) -> Option<MidiMessage> {
        if byte >= 0xF8 {
            // Real time: between any two bytes, disturbing nothing.
            return self.real_time(byte);
        }
        if byte & 0x80 != 0 {
            return self.status(byte);
        }
        match self.within {
            Within::SysEx => {
                if self.sysex.len() < MAX_MIDI_SYSEX_BYTES {
                    self.sysex.push(byte);
                } else {
                    self.sysex_overflow = true;
                }
                None
            }
            Within::Message { status, have } => self.data_byte(status, have, byte),
            Within::Idle => match self.running {
                Some(status) => self.data_byte(status, 0, byte),
                None => {
                    self.dropped += 1;
                    None
                }
            },
        }
    }

    fn real_time(&mut self, byte: u8) -> Option<MidiMessage> {
        Some(match byte {
            0xF8 => MidiMessage::Clock,
            0xFA => MidiMessage::Start,
            0xFB => MidiMessage::Continue,
            0xFC => MidiMessage::Stop,
            0xFE => MidiMessage::ActiveSensing,
            0xFF => MidiMessage::Reset,
            _ => {
                // F9, FD: undefined.
                self.dropped += 1;
                return None;
            }
        })
    }

    /// A status byte (not real time): ends a SysEx or cuts short what was
    /// being collected, then starts its own message.
    fn status(&mut self, byte: u8) -> Option<MidiMessage> {
        let ended = match self.within {
            Within::SysEx if byte == 0xF7 => {
                self.within = Within::Idle;
                return self.sysex_done();
            }
            Within::SysEx => {
                // Cut short by a status byte: what it held is not a message.
                self.dropped += 1;
                None
            }
            Within::Message { .. } => {
                self.dropped += 1;
                None
            }
            Within::Idle => None,
        };
        self.within = Within::Idle;
        match byte {
            0x80..=0xEF => {
                self.running = Some(byte);
                self.within = Within::Message {
                    status: byte,
                    have: 0,
                };
            }
            0xF0 => {
                self.running = None;
                self.sysex.clear();
                self.sysex_overflow = false;
                self.within = Within::SysEx;
            }
            0xF1..=0xF3 => {
                self.running = None;
                self.within = Within::Message {
                    status: byte,
                    have: 0,
                };
            }
            0xF6 => {
                self.running = None;
                return Some(MidiMessage::TuneRequest);
            }
            _ => {
                // F4, F5 undefined; F7 without a SysEx.
                self.running = None;
                self.dropped += 1;
            }
        }
        ended
    }

    fn data_byte(&mut self, status: u8, have: usize, byte: u8) -> Option<MidiMessage> {
        self.data[have] = byte;
        let need = match status {
            0xF1 | 0xF3 => 1,
            0xF2 => 2,
            s => data_bytes(s),
        };
        if have + 1 < need {
            self.within = Within::Message {
                status,
                have: have + 1,
            };
            return None;
        }
        self.within = Within::Idle;
        let [a, b] = self.data;
        let channel = status & 0x0F;
        Some(match status {
            0xF1 => MidiMessage::QuarterFrame {
                piece: a >> 4,
                value: a & 0x0F,
            },
            0xF2 => MidiMessage::SongPosition {
                beats: u16::from(a) | u16::from(b) << 7,
            },
            0xF3 => MidiMessage::SongSelect { song: a },
            s => match s & 0xF0 {
                0x80 => MidiMessage::NoteOff {
                    channel,
                    note: a,
                    velocity: b,
                },
                0x90 if b == 0 => MidiMessage::NoteOff {
                    channel,
                    note: a,
                    velocity: 0,
                },
                0x90 => MidiMessage::NoteOn {
                    channel,
                    note: a,
                    velocity: b,
                },
                0xA0 => MidiMessage::KeyPressure {
                    channel,
                    note: a,
                    pressure: b,
                },
                0xB0 => MidiMessage::ControlChange {
                    channel,
                    controller: a,
                    value: b,
                },
                0xC0 => MidiMessage::ProgramChange {
                    channel,
                    program: a,
                },
                0xD0 => MidiMessage::ChannelPressure {
                    channel,
                    pressure: a,
                },
                _ => MidiMessage::PitchBend {
                    channel,
                    value: u16::from(a) | u16::from(b) << 7,
                },
            },
        })
    }

    /// A whole SysEx ended by `F7`: a show-control command, a time code
    /// full frame, or skipped.
    fn sysex_done(&mut self) -> Option<MidiMessage> {
        if self.sysex_overflow {
            return None;
        }
        show_control(&self.sysex).or_else(|| full_frame(&self.sysex))
    }
}

/// A MIDI Show Control SysEx's body (between `F0` and `F7`): `7F`, the
/// device id, `02`, the command format, the command and its data (the cue
/// number in ASCII, its list and path after `00`s).
fn show_control(body: &[u8]) -> Option<MidiMessage> {
    let [0x7F, device, 0x02, _format, command, data @ ..] = body else {
        return None;
    };
    let command = match command {
        0x01 => ShowCommand::Go,
        0x02 => ShowCommand::Stop,
        0x03 => ShowCommand::Resume,
        _ => return None,
    };
    let number = data.split(|&b| b == 0).next().unwrap_or(&[]);
    let cue = (!number.is_empty() && number.iter().all(|&b| b.is_ascii_digit() || b == b'.'))
        .then(|| String::from_utf8_lossy(number).into_owned());
    Some(MidiMessage::ShowControl {
        device: *device,
        command,
        cue,
    })
}

/// A MIDI Time Code full frame's body: `7F`, the device id, `01 01`, then
/// hours (with the rate), minutes, seconds and frames, each a data byte.
fn full_frame(body: &[u8]) -> Option<MidiMessage> {
    let [0x7F, _device, 0x01, 0x01, hours, minutes, seconds, frames] = *body else {
        return None;
    };
    Some(MidiMessage::FullFrame {
        hours,
        minutes,
        seconds,
        frames,
    })
}

/// Control changes read as a performer turns them: 7-bit controllers as
/// they come, and the 14-bit pairs (a coarse CC 0–31 with its fine CC
/// 32–63) put together: a coarse value resets its fine part to 0 (as the
/// standard says), a fine value refines the last coarse one. Values are
/// fractions, 0 to 1.
#[derive(Debug, Clone)]
pub struct Controls {
    /// Per channel and coarse controller (0–31), its last coarse value.
    coarse: [[u8; 32]; 16],
}

impl Default for Controls {
    fn default() -> Self {
        Controls::new()
    }
}

/// A controller's value as a fraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlValue {
    /// Its channel.
    pub channel: Channel,
    /// The controller, by its coarse number for a 14-bit pair.
    pub controller: u8,
    /// 0 to 1.
    pub value: f64,
}

impl Controls {
    /// No controller moved yet.
    pub fn new() -> Controls {
        Controls {
            coarse: [[0; 32]; 16],
        }
    }

    /// The value a control change sets.
    pub fn read(&mut self, channel: Channel, controller: u8, value: u8) -> ControlValue {
        let ch = usize::from(channel & 0x0F);
        let at = |controller: u8, value: f64| ControlValue {
            channel,
            controller,
            value,
        };
        match controller {
            0..=31 => {
                let c = usize::from(controller);
                self.coarse[ch][c] = value;
                at(controller, f64::from(value) / 127.0)
            }
            32..=63 => {
                let c = usize::from(controller - 32);
                let full = u16::from(self.coarse[ch][c]) << 7 | u16::from(value);
                at(controller - 32, f64::from(full) / 16383.0)
            }
            _ => at(controller, f64::from(value) / 127.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (Vec<MidiMessage>, u64) {
        let mut d = MidiDecoder::new();
        let mut out = Vec::new();
        d.feed(bytes, |m| out.push(m));
        (out, d.dropped())
    }

    #[test]
    fn channel_messages_and_running_status() {
        let (out, dropped) = decode(&[0x90, 60, 100, 62, 90, 64, 0, 0xB3, 7, 127, 8, 0]);
        assert_eq!(dropped, 0);
        assert_eq!(
            out,
            [
                MidiMessage::NoteOn {
                    channel: 0,
                    note: 60,
                    velocity: 100
                },
                MidiMessage::NoteOn {
                    channel: 0,
                    note: 62,
                    velocity: 90
                },
                MidiMessage::NoteOff {
                    channel: 0,
                    note: 64,
                    velocity: 0
                },
                MidiMessage::ControlChange {
                    channel: 3,
                    controller: 7,
                    value: 127
                },
                MidiMessage::ControlChange {
                    channel: 3,
                    controller: 8,
                    value: 0
                },
            ]
        );
        let (out, _) = decode(&[0xC5, 9, 10, 0xE1, 0x00, 0x40, 0x7F, 0x7F]);
        assert_eq!(
            out,
            [
                MidiMessage::ProgramChange {
                    channel: 5,
                    program: 9
                },
                MidiMessage::ProgramChange {
                    channel: 5,
                    program: 10
                },
                MidiMessage::PitchBend {
                    channel: 1,
                    value: 8192
                },
                MidiMessage::PitchBend {
                    channel: 1,
                    value: 16383
                },
            ]
        );
    }

    #[test]
    fn real_time_bytes_inside_a_message_and_a_sysex_change_nothing() {
        let (out, dropped) = decode(&[0x90, 0xF8, 60, 0xFE, 100, 0xF0, 0x7D, 0xF8, 1, 0xF7, 0xF8]);
        assert_eq!(dropped, 0);
        assert_eq!(
            out,
            [
                MidiMessage::Clock,
                MidiMessage::ActiveSensing,
                MidiMessage::NoteOn {
                    channel: 0,
                    note: 60,
                    velocity: 100
                },
                MidiMessage::Clock,
                MidiMessage::Clock,
            ]
        );
    }

    #[test]
    fn a_cut_message_is_dropped_and_the_next_one_read() {
        // A note on cut after its key by a control change; then data with
        // no status after a system message.
        let (out, dropped) = decode(&[0x90, 60, 0xB0, 1, 64, 0xF6, 5, 0x80, 60, 0]);
        assert_eq!(
            out,
            [
                MidiMessage::ControlChange {
                    channel: 0,
                    controller: 1,
                    value: 64
                },
                MidiMessage::TuneRequest,
                MidiMessage::NoteOff {
                    channel: 0,
                    note: 60,
                    velocity: 0
                },
            ]
        );
        assert_eq!(dropped, 2);
    }

    #[test]
    fn a_time_code_full_frame_is_a_locate() {
        // 01:02:03:04 at 25 fps (rate bits 01), to all devices.
        let (out, dropped) = decode(&[0xF0, 0x7F, 0x7F, 0x01, 0x01, 0x21, 2, 3, 4, 0xF7]);
        assert_eq!(
            out,
            [MidiMessage::FullFrame {
                hours: 0x21,
                minutes: 2,
                seconds: 3,
                frames: 4
            }]
        );
        assert_eq!(dropped, 0);
        // A user bits message (01 02) is not a time.
        let (out, _) = decode(&[
            0xF0, 0x7F, 0x7F, 0x01, 0x02, 1, 2, 3, 4, 5, 6, 7, 8, 0, 0xF7,
        ]);
        assert!(out.is_empty());
    }

    #[test]
    fn show_control_go_stop_and_resume_with_their_cues() {
        let go = [
            0xF0, 0x7F, 0x01, 0x02, 0x01, 0x01, b'1', b'2', b'.', b'5', 0x00, b'3', 0xF7,
        ];
        let (out, _) = decode(&go);
        assert_eq!(
            out,
            [MidiMessage::ShowControl {
                device: 1,
                command: ShowCommand::Go,
                cue: Some("12.5".into())
            }]
        );
        let (out, _) = decode(&[0xF0, 0x7F, 0x7F, 0x02, 0x01, 0x02, 0xF7]);
        assert_eq!(
            out,
            [MidiMessage::ShowControl {
                device: 0x7F,
                command: ShowCommand::Stop,
                cue: None
            }]
        );
        // Other SysEx, and one too long to keep, are skipped whole.
        let mut long = vec![0xF0, 0x7F, 0x01, 0x02, 0x01, 0x01];
        long.extend(std::iter::repeat_n(b'1', 10_000));
        long.push(0xF7);
        long.extend([0x90, 1, 2]);
        let (out, _) = decode(&long);
        assert_eq!(
            out,
            [MidiMessage::NoteOn {
                channel: 0,
                note: 1,
                velocity: 2
            }]
        );
    }

    #[test]
    fn time_code_and_song_position() {
        let (out, _) = decode(&[0xF1, 0x25, 0xF2, 0x10, 0x02, 0xF3, 4]);
        assert_eq!(
            out,
            [
                MidiMessage::QuarterFrame { piece: 2, value: 5 },
                MidiMessage::SongPosition {
                    beats: 0x10 | 2 << 7
                },
                MidiMessage::SongSelect { song: 4 },
            ]
        );
    }

    #[test]
    fn fourteen_bit_controllers_pair_coarse_and_fine() {
        let mut c = Controls::new();
        assert_eq!(c.read(0, 1, 127).value, 1.0);
        // Coarse 64, then fine 0 and 127: 8192/16383 and 8319/16383.
        assert_eq!(c.read(0, 1, 64).value, 64.0 / 127.0);
        let fine = c.read(0, 33, 0);
        assert_eq!((fine.controller, fine.value), (1, 8192.0 / 16383.0));
        assert_eq!(c.read(0, 33, 127).value, 8319.0 / 16383.0);
        // Another channel's pair is its own.
        assert_eq!(c.read(1, 33, 127).value, 127.0 / 16383.0);
        assert_eq!(c.read(0, 74, 0).value, 0.0);
    }
}
