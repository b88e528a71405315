//! `puppetry record` of a MIDI port: a controller's (or a DAW's
//! transport's) messages as they arrive, timed from the recording's start,
//! written as a Standard MIDI File that a `kind = "midi"` input's `file`
//! plays back in the controller's place (and any DAW opens). The file is
//! written whole every second while messages come, each time beside it
//! and renamed, so a recording cut short by a crash keeps all but its
//! last second. At most `MAX_MIDI_RECORD_MESSAGES` are kept.

use std::path::Path;
use std::time::Duration;

use puppetry_limits::midi::MAX_MIDI_RECORD_MESSAGES;

use crate::midi::MidiDecoder;
use crate::midi_file::{MidiFileError, TimedMessage, write_midi_file};
use crate::midi_port::PortReader;

/// Why a MIDI recording stopped before its end.
#[derive(Debug, thiserror::Error)]
pub enum MidiRecordError {
    /// The port cannot be opened or read.
    #[error("{port}: {source}")]
    Port {
        /// The port's path.
        port: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file cannot be written.
    #[error(transparent)]
    File(#[from] MidiFileError),
}

/// What a MIDI recording kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedMidi {
    /// Messages written.
    pub messages: usize,
    /// Bytes and partial messages the decoder dropped.
    pub dropped: u64,
    /// It stopped at `MAX_MIDI_RECORD_MESSAGES`.
    pub full: bool,
    /// The port failed (a controller unplugged), why: what came before
    /// is kept.
    pub gone: Option<String>,
}

/// How often the file is written again while messages come.
const CHECKPOINT_EVERY: Duration = Duration::from_secs(1);

/// Records the MIDI port at `port` to `out` until `duration` passes (if
/// given), `stop` resolves, the port fails, or
/// [`MAX_MIDI_RECORD_MESSAGES`] are kept.
pub async fn record_midi(
    port: &Path,
    out: &Path,
    duration: Option<Duration>,
    stop: impl std::future::Future<Output = ()>,
) -> Result<RecordedMidi, MidiRecordError> {
    let port_error = |source| MidiRecordError::Port {
        port: port.display().to_string(),
        source,
    };
    let reader = PortReader::open(port).map_err(port_error)?;
    // An empty file at once: the output can be written, and a recording
    // of nothing is still a file that plays.
    write_midi_file(&[], out)?;
    let start = tokio::time::Instant::now();
    let deadline = async {
        match duration {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(deadline, stop);
    let mut checkpoint = tokio::time::interval(CHECKPOINT_EVERY);
    let mut decoder = MidiDecoder::new();
    let mut messages: Vec<TimedMessage> = Vec::new();
    let mut written = 0;
    let mut buffer = [0u8; 512];
    let mut gone = None;
    let full = loop {
        let n = tokio::select! {
            biased;
            read = reader.read(&mut buffer) => match read {
                Ok(n) => n,
                Err(e) => {
                    gone = Some(e.to_string());
                    break false;
                }
            },
            _ = checkpoint.tick() => {
                if messages.len() > written {
                    write_midi_file(&messages, out)?;
                    written = messages.len();
                }
                continue;
            }
            _ = &mut deadline => break false,
            _ = &mut stop => break false,
        };
        let t = start.elapsed().as_secs_f64();
        decoder.feed(&buffer[..n], |message| {
            if messages.len() < MAX_MIDI_RECORD_MESSAGES {
                messages.push(TimedMessage { t, message });
            }
        });
        if messages.len() >= MAX_MIDI_RECORD_MESSAGES {
            break true;
        }
    };
    write_midi_file(&messages, out)?;
    Ok(RecordedMidi {
        messages: messages.len(),
        dropped: decoder.dropped(),
        full,
        gone,
    })
}
