//! Recording a take while the show runs: the stage thread hands records to
//! a bounded queue and a writer thread of the recorder's own, polling it,
//! encodes and appends them, flushing at least every [`FLUSH_EVERY`] (plus
//! one poll), so the stage thread never waits on the disk nor wakes the
//! writer, and a killed daemon loses at most the last tenth of a second. A full queue (the disk cannot keep up) or a
//! failed write (full disk, folder gone) stops the take with an error the
//! daemon reports; the show goes on.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, SyncSender, TryRecvError, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::{End, Header, Record, TakeError, TakeWriter};

/// Written data reaches the operating system at least this often.
pub const FLUSH_EVERY: Duration = Duration::from_millis(50);

/// How long the writer sleeps when it has caught up.
const POLL: Duration = Duration::from_millis(10);

/// Records waiting for the writer at most; a 1k-vertex frame is 8 KB, so
/// this bounds the queue to tens of megabytes.
pub const QUEUE: usize = 4096;

/// Why a take stopped before it was asked to.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RecordError {
    /// [`QUEUE`] records were already waiting: the disk is not keeping up.
    #[error("take {name}: the disk is not keeping up ({QUEUE} records waiting); the take stopped")]
    Behind {
        /// The take's name, from its header.
        name: String,
    },
    /// The writer thread failed to write (a full disk, the folder gone)
    /// or is no longer running.
    #[error("take {name}: {problem}; the take stopped")]
    Write {
        /// The take's name, from its header.
        name: String,
        /// The writer's error.
        problem: String,
    },
}

/// A take being recorded.
pub struct Recorder {
    name: String,
    path: PathBuf,
    queue: Option<SyncSender<Record>>,
    failure: Arc<Mutex<Option<String>>>,
    writer: Option<JoinHandle<()>>,
    started: Instant,
}

impl Recorder {
    /// Creates the take's file, writes its header and starts the writer.
    pub fn start(path: &Path, header: &Header) -> Result<Recorder, TakeError> {
        let mut writer = TakeWriter::create(path, header)?;
        let (queue, records) = mpsc::sync_channel::<Record>(QUEUE);
        let failure = Arc::new(Mutex::new(None));
        let failed = failure.clone();
        let thread = std::thread::Builder::new()
            .name(format!("take {}", header.name))
            .spawn(move || {
                let mut last_flush = Instant::now();
                let mut dirty = false;
                let outcome: Result<(), TakeError> = (|| {
                    loop {
                        match records.try_recv() {
                            Ok(record) => {
                                writer.write(&record)?;
                                dirty = true;
                            }
                            Err(TryRecvError::Disconnected) => {
                                writer.flush()?;
                                return Ok(());
                            }
                            // Polling, not waiting on the queue: a waiting
                            // receiver makes every send a wake-up system
                            // call on the stage thread.
                            Err(TryRecvError::Empty) => std::thread::sleep(POLL),
                        }
                        if dirty && last_flush.elapsed() >= FLUSH_EVERY {
                            writer.flush()?;
                            dirty = false;
                            last_flush = Instant::now();
                        }
                    }
                })();
                if let Err(e) = outcome {
                    *failed.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.to_string());
                }
            })
            .map_err(|source| TakeError::Io {
                file: path.display().to_string(),
                source,
            })?;
        Ok(Recorder {
            name: header.name.clone(),
            path: path.to_path_buf(),
            queue: Some(queue),
            failure,
            writer: Some(thread),
            started: Instant::now(),
        })
    }

    /// The take's name, from its header.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The take's file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Seconds since the take began: the time records carry.
    pub fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Seconds from the take's start to `at`; `None` before it began.
    pub fn elapsed_at(&self, at: Instant) -> Option<f64> {
        at.checked_duration_since(self.started)
            .map(|d| d.as_secs_f64())
    }

    /// Hands a record to the writer without waiting. An error means the
    /// take has stopped: finish it.
    pub fn record(&self, record: Record) -> Result<(), RecordError> {
        let Some(queue) = &self.queue else {
            return Err(self.failed());
        };
        match queue.try_send(record) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(_)) => Err(RecordError::Behind {
                name: self.name.clone(),
            }),
            Err(TrySendError::Disconnected(_)) => Err(self.failed()),
        }
    }

    fn failed(&self) -> RecordError {
        let problem = self
            .failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
            .unwrap_or_else(|| "the writer stopped".into());
        RecordError::Write {
            name: self.name.clone(),
            problem,
        }
    }

    /// Ends the take: writes the end record (if the writer still runs),
    /// waits for everything to reach the file and reports a write failure.
    pub fn finish(mut self, reason: &str) -> Result<(), RecordError> {
        let end = Record::End(End {
            t: self.elapsed(),
            reason: reason.to_string(),
        });
        let mut result = match &self.queue {
            // Blocking is fine here: the writer drains at disk speed and
            // this happens once per take.
            Some(queue) => queue.send(end).map_err(|_| self.failed()),
            None => Err(self.failed()),
        };
        self.queue = None;
        if let Some(writer) = self.writer.take() {
            let _ = writer.join();
        }
        if result.is_ok() && self.failure.lock().map(|f| f.is_some()).unwrap_or(true) {
            result = Err(self.failed());
        }
        result
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.queue = None;
        if let Some(writer) = self.writer.take() {
            let _ = writer.join();
        }
    }
}
