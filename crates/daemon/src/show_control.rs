//! Show control's one table: what a show controller — an OSC desk, a
//! MIDI controller or a show-control desk — can ask of the stage (a
//! [`Trigger`]), how each is done ([`Actor`]), and the stage's channels it
//! reads and drives ([`Links`]). OSC (`osc`) turns addresses into triggers
//! and MIDI will turn mapped controls into the same ones, so a new
//! trigger is added here once and both doors offer it.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::Bytes;
use glam::DVec2;
use puppetry_input::log_limit::LogLimiter;
use tokio::sync::{mpsc, watch};
use tokio::task::AbortHandle;

use crate::outputs::{Published, State};
use crate::protocol::{KeyView, RigDescription, ServerMessage};
use crate::stage_thread::{Command, PublishedHandles, ShowReading};
use crate::stream::Shared;

/// Why a trigger could not be done: named by where it came from (an OSC
/// address, a MIDI control).
#[derive(Debug, thiserror::Error)]
pub enum TriggerError {
    /// A `key` trigger named no key pose and no keyframing key of the
    /// puppet.
    #[error(
        "{address}: {name}: no key pose {key:?} (stage-file poses: {poses}; keyframing keys: {keys})"
    )]
    NoKey {
        /// Where the trigger came from.
        address: String,
        /// The argument naming the key.
        name: &'static str,
        /// The name given.
        key: String,
        /// The puppet's stage-file poses.
        poses: String,
        /// The puppet's keyframing keys.
        keys: String,
    },
    /// The stage refused it (or is shutting down).
    #[error("{address}: {problem}")]
    Refused {
        /// Where the trigger came from.
        address: String,
        /// The stage's answer.
        problem: String,
    },
}

/// `text`, cut to `MAX_ECHO` characters with "…" when longer, so a
/// hostile datagram cannot make a log line or error of any length.
pub(crate) fn clip(text: &str) -> String {
    puppetry_input::log_limit::clip(text, puppetry_limits::net::MAX_ECHO)
}

/// What a show controller asks of the stage (an OSC address, a mapped MIDI
/// control), as the stage thread is asked to do it.
#[derive(Debug, Clone, PartialEq)]
pub enum Trigger {
    /// Start recording a take (`None`: the next free `take-NNN`).
    StartTake { name: Option<String> },
    /// Stop the take recording and the take playing (an overdub: both).
    StopTake,
    /// Play a take (`None`: the newest in the takes folder); with
    /// `overdub`, record a new take of it and the live hands.
    PlayTake { take: Option<String>, overdub: bool },
    /// Blend a puppet to a named key pose over `seconds` (0: at once): a
    /// skeleton's stage-file pose, or a keyframing key (its cursor moves
    /// to the key's pad point).
    Key {
        puppet: u32,
        name: String,
        seconds: f64,
    },
    /// A skeleton set `t` of the way from key pose `from` to `to`.
    Pose {
        puppet: u32,
        from: String,
        to: String,
        t: f64,
    },
    /// The keyframing cursor moved (pad coordinates) or let go (`None`).
    Cursor { puppet: u32, at: Option<[f64; 2]> },
    /// A puppet back to how the stage file has it.
    Reset { puppet: u32 },
    /// The show's clock (a DAW's or a desk's transport), heard now: a
    /// take recording keeps it beside its own time.
    Clock(ShowReading),
}

impl Trigger {
    /// The puppet it acts on, if one.
    fn puppet(&self) -> Option<u32> {
        match self {
            Trigger::StartTake { .. }
            | Trigger::StopTake
            | Trigger::PlayTake { .. }
            | Trigger::Clock(_) => None,
            Trigger::Key { puppet, .. }
            | Trigger::Pose { puppet, .. }
            | Trigger::Cursor { puppet, .. }
            | Trigger::Reset { puppet } => Some(*puppet),
        }
    }
}

/// One puppet as show control sees it: its names and the watches it reads.
#[derive(Debug, Clone)]
pub struct PuppetLink {
    /// The stage file's key poses of a skeleton (empty otherwise).
    pub poses: Vec<String>,
    pub handles: watch::Receiver<Arc<PublishedHandles>>,
    /// The "keys" message (keyframing keys and cursor).
    pub keys: State,
    /// The "pose" message (a skeleton's key-pose blend), empty until set.
    pub pose: State,
    /// Handle frames (binary kind 3: where each handle's point is on the
    /// solved puppet), when the stage publishes them; else the handles'
    /// `at` stands in.
    pub handle_frames: Option<watch::Receiver<Option<Bytes>>>,
}

/// What show control reads and drives: the same channels as the
/// WebSocket clients.
#[derive(Debug, Clone)]
pub struct Links {
    pub names: Vec<String>,
    pub puppets: Vec<PuppetLink>,
    /// The "take" message.
    pub take: State,
    pub commands: mpsc::Sender<Command>,
    /// The clients' shared state, for what a client's message does the
    /// same way (playing takes); weak, so show control never keeps it.
    pub shared: std::sync::Weak<Shared>,
}

impl Links {
    /// The stage file's puppets (show control's address space is fixed at
    /// start: puppets added at runtime are not in it).
    pub fn of(shared: &Arc<Shared>, commands: mpsc::Sender<Command>) -> Links {
        let lineup = shared.lineup.borrow().clone();
        let puppets = lineup
            .description
            .puppets
            .iter()
            .zip(&lineup.outputs)
            .map(|(p, o)| PuppetLink {
                poses: match &p.rig {
                    RigDescription::Skeleton { poses, .. } => poses.clone(),
                    _ => Vec::new(),
                },
                handles: o.handles.clone(),
                keys: o.keys.clone(),
                // Puppets without key poses never publish one.
                pose: o
                    .pose
                    .clone()
                    .unwrap_or_else(|| watch::channel(Published::nothing()).1),
                handle_frames: Some(o.handle_frame.clone()),
            })
            .collect();
        Links {
            names: lineup
                .description
                .puppets
                .iter()
                .map(|p| p.name.clone())
                .collect(),
            puppets,
            take: shared.take.clone(),
            commands,
            shared: Arc::downgrade(shared),
        }
    }
}

/// The mutex's value, even if a holder panicked (the data stays usable).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// A puppet's key poses and cursor, from its published "keys" message
/// (none published yet: none).
pub(crate) fn keys_of(published: &Published) -> (Vec<KeyView>, Option<[f64; 2]>) {
    match &published.message {
        Some(ServerMessage::Keys { keys, cursor, .. }) => (keys.clone(), *cursor),
        _ => (Vec::new(), None),
    }
}

/// A skeleton's key-pose blend, from its published "pose" message: from,
/// to and how far (none published yet: `None`).
pub(crate) fn pose_of(published: &Published) -> Option<(Option<String>, Option<String>, f64)> {
    match &published.message {
        Some(ServerMessage::Pose { from, to, t, .. }) => Some((from.clone(), to.clone(), *t)),
        _ => None,
    }
}

/// Does triggers: asks the stage thread as a client's message would, and
/// runs `key` blends as tasks (a newer trigger on the puppet stops its
/// blend: the last word wins).
#[derive(Clone)]
pub(crate) struct Actor {
    /// The stage's channels.
    pub(crate) links: Links,
    /// Steps a second of a `key` blend.
    pub(crate) rate: f64,
    /// Per puppet, the `key` blend under way.
    pub(crate) blends: Arc<Mutex<Vec<Option<AbortHandle>>>>,
    /// Where a blend's failure is told, rate-limited.
    pub(crate) log: Arc<Mutex<LogLimiter>>,
}

impl Actor {
    /// Does one trigger.
    pub(crate) async fn act(&self, address: &str, trigger: Trigger) -> Result<(), TriggerError> {
        let refused = |problem: String| TriggerError::Refused {
            address: clip(address),
            problem,
        };
        if let Some(puppet) = trigger.puppet() {
            // The newest word on a puppet wins over a blend under way.
            if let Some(blend) = lock(&self.blends)[puppet as usize].take() {
                blend.abort();
            }
        }
        let commands = &self.links.commands;
        match trigger {
            Trigger::Clock(show) => {
                // Stamped as it arrives. A full command queue drops the
                // reading: a take lines up by the median of many, and a
                // clock must never hold up the controls that come with it.
                let at = std::time::Instant::now();
                let _ = commands.try_send(Command::Clock { show, at });
                Ok(())
            }
            Trigger::StartTake { name } => {
                let (reply, answer) = tokio::sync::oneshot::channel();
                send(
                    commands,
                    Command::StartTake {
                        name,
                        layers: Vec::new(),
                        reply,
                    },
                )
                .await
                .map_err(refused)?;
                let name = answer.await.map_err(|_| refused(SHUTTING_DOWN.into()))?;
                let name = name.map_err(refused)?;
                tracing::info!("take {name} started by show control ({})", clip(address));
                Ok(())
            }
            Trigger::StopTake => {
                let (reply, answer) = tokio::sync::oneshot::channel();
                send(commands, Command::StopTake { reply })
                    .await
                    .map_err(refused)?;
                let recording = answer.await.map_err(|_| refused(SHUTTING_DOWN.into()))?;
                let shared = self.shared().map_err(refused)?;
                let playing = crate::stream::stop_playing(&shared).await;
                match (recording, playing) {
                    (Err(_), Err(_)) => Err(refused("no take is recording or playing".into())),
                    _ => Ok(()),
                }
            }
            Trigger::PlayTake { take, overdub } => {
                let shared = self.shared().map_err(refused)?;
                let take = match take {
                    Some(take) => take,
                    None => newest_take(&shared).await.map_err(refused)?,
                };
                crate::stream::play_take(&shared, &take, overdub, Vec::new(), Vec::new())
                    .await
                    .map_err(|r| refused(r.message))?;
                tracing::info!("take {take} played by show control ({})", clip(address));
                Ok(())
            }
            Trigger::Pose {
                puppet,
                from,
                to,
                t,
            } => key_pose(commands, puppet, from, to, t)
                .await
                .map_err(refused),
            Trigger::Cursor { puppet, at } => cursor(commands, puppet, at.map(DVec2::from))
                .await
                .map_err(refused),
            Trigger::Reset { puppet } => reset(commands, puppet).await.map_err(refused),
            Trigger::Key {
                puppet,
                name,
                seconds,
            } => self.key(address, puppet, name, seconds).await,
        }
    }

    /// Blends a puppet to a named key pose: a skeleton's stage-file pose
    /// (from the pose it is nearest now), else a keyframing key (the
    /// cursor glides to the key's pad point).
    async fn key(
        &self,
        address: &str,
        puppet: u32,
        name: String,
        seconds: f64,
    ) -> Result<(), TriggerError> {
        let link = &self.links.puppets[puppet as usize];
        let steps = (seconds * self.rate).ceil().max(1.0) as u32;
        let commands = self.links.commands.clone();
        let log = self.log.clone();
        let period = Duration::from_secs_f64(1.0 / self.rate);
        let refused = |problem: String| TriggerError::Refused {
            address: clip(address),
            problem,
        };
        let blend: std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>> =
            if link.poses.contains(&name) {
                let now = pose_of(&link.pose.borrow());
                // A blend of two poses is not a pose to start from: start
                // from the nearer of the two.
                let start = now
                    .and_then(|(from, to, t)| if t >= 0.5 { to } else { from })
                    .filter(|start| *start != name);
                let Some(start) = start.filter(|_| steps > 1) else {
                    return key_pose(&commands, puppet, name.clone(), name, 0.0)
                        .await
                        .map_err(refused);
                };
                Box::pin(async move {
                    let mut tick = tokio::time::interval(period);
                    for k in 1..=steps {
                        tick.tick().await;
                        let t = f64::from(k) / f64::from(steps);
                        let pose = key_pose(&commands, puppet, start.clone(), name.clone(), t);
                        if let Err(e) = pose.await {
                            lock(&log).warn(format_args!("key {name:?}: {e}"));
                            return;
                        }
                    }
                })
            } else {
                let (keys, at) = keys_of(&link.keys.borrow());
                let Some(target) = keys.iter().find(|k| k.name == name) else {
                    let list = |names: Vec<&str>| {
                        if names.is_empty() {
                            "none".to_string()
                        } else {
                            clip(&names.join(", "))
                        }
                    };
                    return Err(TriggerError::NoKey {
                        address: clip(address),
                        name: "name",
                        key: clip(&name),
                        poses: list(link.poses.iter().map(String::as_str).collect()),
                        keys: list(keys.iter().map(|k| k.name.as_str()).collect()),
                    });
                };
                let to = DVec2::from(target.at);
                let Some(from) = at.map(DVec2::from).filter(|_| steps > 1) else {
                    return cursor(&commands, puppet, Some(to)).await.map_err(refused);
                };
                Box::pin(async move {
                    let mut tick = tokio::time::interval(period);
                    for k in 1..=steps {
                        tick.tick().await;
                        // The last step lands on the key exactly.
                        let at = if k == steps {
                            to
                        } else {
                            from.lerp(to, f64::from(k) / f64::from(steps))
                        };
                        if let Err(e) = cursor(&commands, puppet, Some(at)).await {
                            lock(&log).warn(format_args!("key {name:?}: {e}"));
                            return;
                        }
                    }
                })
            };
        let task = tokio::spawn(blend);
        lock(&self.blends)[puppet as usize] = Some(task.abort_handle());
        Ok(())
    }
}

const SHUTTING_DOWN: &str = "the stage is shutting down";

impl Actor {
    /// The clients' shared state, while the daemon runs.
    fn shared(&self) -> Result<Arc<Shared>, String> {
        self.links
            .shared
            .upgrade()
            .ok_or_else(|| SHUTTING_DOWN.to_string())
    }
}

/// The newest take in the takes folder (by when its file last changed),
/// which a `play` with no take named plays.
async fn newest_take(shared: &Shared) -> Result<String, String> {
    let dir = shared.links()?.takes_dir.clone();
    tokio::task::spawn_blocking(move || {
        let entries = std::fs::read_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        entries
            .filter_map(Result::ok)
            .filter(|e| {
                e.path()
                    .extension()
                    .is_some_and(|x| x == puppetry_take::EXTENSION)
            })
            .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
            .max()
            .and_then(|(_, path)| Some(path.file_stem()?.to_string_lossy().into_owned()))
            .ok_or_else(|| format!("no take in {} to play", dir.display()))
    })
    .await
    .map_err(|e| e.to_string())?
}

async fn send(commands: &mpsc::Sender<Command>, command: Command) -> Result<(), String> {
    commands
        .send(command)
        .await
        .map_err(|_| SHUTTING_DOWN.to_string())
}

/// Asks the stage thread and waits for its answer.
async fn ask(
    commands: &mpsc::Sender<Command>,
    command: impl FnOnce(crate::stage_thread::Reply<()>) -> Command,
) -> Result<(), String> {
    let (reply, answer) = tokio::sync::oneshot::channel();
    send(commands, command(reply)).await?;
    answer
        .await
        .map_err(|_| SHUTTING_DOWN.to_string())?
        .map_err(|e| e.to_string())
}

async fn key_pose(
    commands: &mpsc::Sender<Command>,
    puppet: u32,
    from: String,
    to: String,
    t: f64,
) -> Result<(), String> {
    let change = crate::convert::key_pose(puppet, from, to, t).map_err(|e| e.to_string())?;
    ask(commands, |reply| {
        crate::convert::change(change, Some(reply))
    })
    .await
}

async fn cursor(
    commands: &mpsc::Sender<Command>,
    puppet: u32,
    at: Option<DVec2>,
) -> Result<(), String> {
    let change = crate::convert::cursor(puppet, at);
    ask(commands, |reply| {
        crate::convert::change(change, Some(reply))
    })
    .await
}

/// Resets a puppet (as the page's reset button): every reset trigger
/// comes through here.
async fn reset(commands: &mpsc::Sender<Command>, puppet: u32) -> Result<(), String> {
    ask(commands, |reply| Command::Edit {
        puppet,
        edit: crate::stage_thread::Edit::Reset,
        reply,
    })
    .await
}
