//! One configured device for the daemon's whole life: find it, read it
//! through its decoder, lift its contacts when it goes away, wait for it to
//! come back (inotify on its directory) and reopen it under the same source
//! id and calibration. Nothing a device does — missing, unreadable, yanked
//! mid-touch, spewing garbage — ends the daemon; it is logged and waited out.
//!
//! Touch surfaces and pens go through the evdev [`TouchDecoder`]; mice
//! through the [`MouseDecoder`], whose cursor is published for renderers.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::Duration;

use futures_util::StreamExt;
use glam::DVec2;
use tokio::sync::{mpsc, watch};

use super::device::{Device, DeviceError, DeviceInfo, DeviceKind, DeviceMatch, find};
use super::evdev::{EvdevError, TouchDecoder, fit_calibration};
use super::mouse::{Cursor, MouseDecoder, MouseSettings};
use super::{Calibration, ContactFrame, SourceId};
use crate::evdev::{DeviceState, InputEvent};
use crate::mouse::{BTN_LEFT, BTN_RIGHT};

/// How often to look again when the directory cannot be watched.
const POLL_INTERVAL: Duration = Duration::from_secs(2);

/// How long to wait before trying a device that failed again, when nothing
/// in its folder changes (a permission fixed by hand, say).
const RETRY_INTERVAL: Duration = Duration::from_secs(5);

/// A stage-file device entry, resolved.
#[derive(Debug, Clone)]
pub struct DeviceInput {
    /// Where to look for nodes (`/dev/input`).
    pub dir: PathBuf,
    /// Which device: every field given must match.
    pub wanted: DeviceMatch,
    /// Only devices of this kind; `None`: any usable one.
    pub kind: Option<DeviceKind>,
    /// The source the device's frames carry, the same after every reopen.
    pub source: SourceId,
    /// Device to stage; `None`: the device's position range fitted to the
    /// stage (touch and pen; mice ignore it).
    pub calibration: Option<Calibration>,
    /// Open the device exclusively (`EVIOCGRAB`), so the desktop does not
    /// also react to it.
    pub grab: bool,
    /// How the device puppeteers if it turns out to be a mouse.
    pub mouse: MouseSettings,
    /// The stage's width and height, stage units: what a default
    /// calibration stretches the device over and a mouse's cursor stays in.
    pub stage_size: DVec2,
}

impl DeviceInput {
    /// The directory whose changes mean the device may have come or gone.
    fn watched_dir(&self) -> PathBuf {
        match self.wanted.path.as_ref().and_then(|p| p.parent()) {
            Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
            _ => self.dir.clone(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub(crate) enum HotplugError {
    #[error(transparent)]
    Device(#[from] DeviceError),
    #[error("{path}: {source}")]
    Decoder { path: String, source: EvdevError },
    #[error("{path}: {problem}")]
    Mouse { path: String, problem: String },
}

/// Reads `input` until the frame receiver closes. `cursor` carries a
/// mouse's cursor (`None` while no mouse is open).
pub async fn run(
    input: DeviceInput,
    frames: mpsc::Sender<ContactFrame>,
    cursor: watch::Sender<Option<Cursor>>,
) {
    let mut watcher = DirWatcher::new(&input.watched_dir());
    // A device that stays missing is reported once, not every poll.
    let mut last_complaint = String::new();
    let complain = |last: &mut String, message: String| {
        if message != *last {
            tracing::warn!("{}: {message}", input.source);
            *last = message;
        }
    };
    loop {
        if frames.is_closed() {
            return;
        }
        match find(&input.dir, &input.wanted, input.kind) {
            Ok(Some(info)) => match Device::open(&info.path, input.grab) {
                Ok(device) => {
                    tracing::info!(
                        "{}: reading {} ({}, {})",
                        input.source,
                        info.path.display(),
                        info.name,
                        info.kind
                    );
                    last_complaint.clear();
                    let result = read(&input, device, &frames, &cursor, &mut watcher).await;
                    cursor.send_replace(None);
                    match result {
                        Ok(()) => {
                            tracing::info!(
                                "{}: {} went away; its contacts are lifted; waiting for it",
                                input.source,
                                info.path.display()
                            );
                            continue;
                        }
                        // Still there but unusable: wait for a change (or a
                        // while) rather than reopening it in a tight loop.
                        Err(e) => complain(
                            &mut last_complaint,
                            format!("{e}; its contacts are lifted; trying again later"),
                        ),
                    }
                }
                Err(e) => complain(&mut last_complaint, e.to_string()),
            },
            Ok(None) => complain(
                &mut last_complaint,
                format!(
                    "no device matches {} in {}; waiting for one",
                    input.wanted,
                    input.dir.display()
                ),
            ),
            Err(e) => complain(&mut last_complaint, e.to_string()),
        }
        tokio::select! {
            _ = watcher.changed(None) => {}
            _ = tokio::time::sleep(RETRY_INTERVAL) => {}
            _ = frames.closed() => return,
        }
    }
}

enum Decoder {
    Touch(Box<TouchDecoder>),
    Mouse(Box<MouseDecoder>),
}

impl Decoder {
    fn new(input: &DeviceInput, info: &DeviceInfo) -> Result<Decoder, HotplugError> {
        let path = info.path.display().to_string();
        if info.kind == DeviceKind::Mouse {
            return MouseDecoder::new(input.source.clone(), input.mouse.clone(), input.stage_size)
                .map(|d| Decoder::Mouse(Box::new(d)))
                .map_err(|e| HotplugError::Mouse {
                    path,
                    problem: e.to_string(),
                });
        }
        let axes = &info.capabilities.absolute;
        let calibration = match &input.calibration {
            Some(c) => c.clone(),
            None => {
                fit_calibration(axes, input.stage_size).map_err(|source| HotplugError::Decoder {
                    path: path.clone(),
                    source,
                })?
            }
        };
        TouchDecoder::new(input.source.clone(), axes, calibration)
            .map(|d| Decoder::Touch(Box::new(d)))
            .map_err(|source| HotplugError::Decoder { path, source })
    }

    fn push(&mut self, event: InputEvent) -> Option<ContactFrame> {
        match self {
            Decoder::Touch(d) => d.push(event),
            Decoder::Mouse(d) => d.push(event),
        }
    }

    fn needs_resync(&self) -> bool {
        match self {
            Decoder::Touch(d) => d.needs_resync(),
            Decoder::Mouse(d) => d.needs_resync(),
        }
    }

    fn restore(&mut self, time: f64, state: &DeviceState) -> Option<ContactFrame> {
        match self {
            Decoder::Touch(d) => d.restore(time, state),
            Decoder::Mouse(d) => d.resync(
                time,
                state.keys.contains(&BTN_LEFT),
                state.keys.contains(&BTN_RIGHT),
            ),
        }
    }

    fn lift_all(&mut self, time: f64) -> Option<ContactFrame> {
        match self {
            Decoder::Touch(d) => d.lift_all(time),
            Decoder::Mouse(d) => d.lift_all(time),
        }
    }

    fn cursor(&self) -> Option<Cursor> {
        match self {
            Decoder::Touch(_) => None,
            Decoder::Mouse(d) => Some(d.cursor()),
        }
    }
}

/// Reads one opened device until it goes away (or the receiver closes);
/// whatever ends it, every contact it holds is lifted.
async fn read(
    input: &DeviceInput,
    mut device: Device,
    frames: &mpsc::Sender<ContactFrame>,
    cursor: &watch::Sender<Option<Cursor>>,
    watcher: &mut DirWatcher,
) -> Result<(), HotplugError> {
    let mut decoder = Decoder::new(input, device.info())?;
    let node_name = device.info().path.file_name().map(OsString::from);
    // Fingers may already be down when the device is opened.
    let opened = device
        .state()
        .map(|state| decoder.restore(device.now(), &state));
    let mut result = match opened {
        Ok(frame) => {
            send(frames, frame).await;
            Ok(())
        }
        Err(e) => Err(HotplugError::from(e)),
    };
    cursor.send_replace(decoder.cursor());
    while result.is_ok() {
        let event = tokio::select! {
            event = device.next_event() => event,
            _ = watcher.changed(node_name.as_deref()) => Err(DeviceError::Gone {
                path: device.info().path.display().to_string(),
            }),
            _ = frames.closed() => break,
        };
        let event = match event {
            Ok(event) => event,
            Err(DeviceError::Gone { .. }) => break,
            Err(e) => {
                result = Err(e.into());
                break;
            }
        };
        let mut frame = decoder.push(event);
        if decoder.needs_resync() {
            // After SYN_DROPPED: the device's own account replaces what was
            // missed (EVIOCGMTSLOTS for slots, EVIOCGKEY for buttons).
            match device.state() {
                Ok(state) => {
                    let restored = decoder.restore(event.time, &state);
                    frame = merge(frame, restored);
                }
                Err(e) => result = Err(e.into()),
            }
        }
        if let Some(c) = decoder.cursor() {
            cursor.send_if_modified(|old| {
                let changed = *old != Some(c);
                *old = Some(c);
                changed
            });
        }
        if result.is_ok() {
            if let Some(f) = &frame {
                tracing::trace!("{}: {f:?}", input.source);
            }
            send(frames, frame).await;
        }
    }
    send(frames, decoder.lift_all(device.now())).await;
    result
}

fn merge(a: Option<ContactFrame>, b: Option<ContactFrame>) -> Option<ContactFrame> {
    match (a, b) {
        (Some(mut a), Some(b)) => {
            a.time = b.time;
            a.contacts.extend(b.contacts);
            Some(a)
        }
        (a, b) => a.or(b),
    }
}

/// Sends a frame, waiting for room: downs and ups are never dropped.
async fn send(frames: &mpsc::Sender<ContactFrame>, frame: Option<ContactFrame>) {
    if let Some(frame) = frame {
        // A closed receiver means the daemon is stopping; the caller sees
        // `frames.closed()` next.
        let _ = frames.send(frame).await;
    }
}

/// Changes in a device directory, by inotify; falls back to polling when
/// the directory cannot be watched (it does not exist yet, say).
struct DirWatcher {
    events: Option<inotify::EventStream<Vec<u8>>>,
}

impl DirWatcher {
    fn new(dir: &Path) -> DirWatcher {
        let events = (|| {
            use inotify::{Inotify, WatchMask};
            let inotify = Inotify::init()?;
            inotify.watches().add(
                dir,
                WatchMask::CREATE
                    | WatchMask::DELETE
                    | WatchMask::ATTRIB
                    | WatchMask::MOVED_TO
                    | WatchMask::MOVED_FROM
                    | WatchMask::CLOSE_WRITE,
            )?;
            inotify.into_event_stream(vec![0u8; 4096])
        })();
        match events {
            Ok(events) => DirWatcher {
                events: Some(events),
            },
            Err(e) => {
                tracing::debug!("cannot watch {}: {e}; polling", dir.display());
                DirWatcher { events: None }
            }
        }
    }

    /// Waits for a change. With `removed`, only for that entry's removal;
    /// without, for anything that might mean a device appeared.
    async fn changed(&mut self, removed: Option<&std::ffi::OsStr>) {
        let Some(events) = self.events.as_mut() else {
            match removed {
                // Without inotify a vanished node shows up as a read error.
                Some(_) => std::future::pending::<()>().await,
                None => tokio::time::sleep(POLL_INTERVAL).await,
            }
            return;
        };
        use inotify::EventMask;
        while let Some(event) = events.next().await {
            let Ok(event) = event else {
                tokio::time::sleep(POLL_INTERVAL).await;
                return;
            };
            match removed {
                Some(name) => {
                    let gone = event
                        .mask
                        .intersects(EventMask::DELETE | EventMask::MOVED_FROM);
                    if gone && event.name.as_deref() == Some(name) {
                        return;
                    }
                }
                None => {
                    if event.mask.intersects(
                        EventMask::CREATE
                            | EventMask::ATTRIB
                            | EventMask::MOVED_TO
                            | EventMask::CLOSE_WRITE,
                    ) {
                        return;
                    }
                }
            }
        }
        std::future::pending::<()>().await
    }
}
