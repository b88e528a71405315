//! MIDI: what a controller or a show-control desk on a MIDI port can make
//! the decoder hold.
//!
//! A MIDI port is a byte stream anyone with a cable (or a USB device, or a
//! network MIDI session) can fill. Channel messages are at most three
//! bytes; a SysEx can be any length (firmware dumps run to megabytes), and
//! the only SysEx the stage reads is MIDI Show Control, a few dozen bytes.
//! So the decoder keeps a SysEx's first bytes only and skips the rest,
//! never growing with what it is sent.

/// Bytes of one SysEx the MIDI decoder keeps (a MIDI Show Control command
/// with its cue, list and path is under 40). A longer SysEx is skipped
/// whole (counted as dropped); what follows it is read as usual.
pub const MAX_MIDI_SYSEX_BYTES: usize = 256;

/// Messages `puppetry record` keeps of a MIDI port (about 9 hours of a
/// busy controller at 60 messages a second, a file of a few megabytes,
/// well within `MAX_REPLAY_FILE_BYTES` for its replay): a flooding port
/// ends the recording, saying so, instead of growing it without end.
pub const MAX_MIDI_RECORD_MESSAGES: usize = 2_000_000;
