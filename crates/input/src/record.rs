//! `puppetry record`: capturing a device's raw events to an evemu file that
//! replay (and evemu's own tools) can play back. The header comes from the
//! device's own description, the events are written as they arrive, with the
//! device's timestamps, and the file is flushed as it goes so a capture
//! interrupted by Ctrl-C or an unplug is still whole up to that point.

use std::io::Write;
use std::path::Path;
use std::time::Duration;

use super::device::{Device, DeviceError};
use super::evemu::write_event;

/// Why [`record`] stopped before its end.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Reading the device failed, other than by its going away (which just
    /// ends the capture).
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// The capture file cannot be created or written.
    #[error("{file}: cannot write: {source}")]
    Write {
        /// The capture file.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
}

/// What a recording captured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Recorded {
    /// Events written, `EV_SYN` markers included.
    pub events: usize,
    /// The device went away before the end.
    pub device_gone: bool,
}

/// Records `device` to `out` until `duration` passes (if given), `stop`
/// resolves, or the device goes away.
pub async fn record(
    mut device: Device,
    out: &Path,
    duration: Option<Duration>,
    stop: impl std::future::Future<Output = ()>,
) -> Result<Recorded, RecordError> {
    let file = out.display().to_string();
    let write_error = |source| RecordError::Write {
        file: file.clone(),
        source,
    };
    let mut writer = std::io::BufWriter::new(std::fs::File::create(out).map_err(write_error)?);
    device
        .info()
        .evemu_header()
        .write(&mut writer)
        .map_err(write_error)?;
    writer.flush().map_err(write_error)?;
    let deadline = async {
        match duration {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(deadline, stop);
    let mut recorded = Recorded {
        events: 0,
        device_gone: false,
    };
    loop {
        let event = tokio::select! {
            // Events already due are written before the deadline is looked
            // at, so a recorder that falls behind still keeps them.
            biased;
            event = device.next_event() => event,
            _ = &mut deadline => break,
            _ = &mut stop => break,
        };
        match event {
            Ok(event) => {
                write_event(&mut writer, &event).map_err(write_error)?;
                recorded.events += 1;
                // A report is the unit worth keeping whole.
                if event.ev_type == super::evdev::EV_SYN {
                    writer.flush().map_err(write_error)?;
                }
            }
            Err(DeviceError::Gone { .. }) => {
                recorded.device_gone = true;
                break;
            }
            Err(e) => return Err(e.into()),
        }
    }
    writer.flush().map_err(write_error)?;
    Ok(recorded)
}
