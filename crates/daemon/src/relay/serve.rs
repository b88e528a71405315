//! `puppetry relay`: the daemon's web page and protocol served from NATS,
//! to viewers on this machine's port. A mirror task keeps the newest of
//! everything the daemon publishes in the same watch channels the daemon
//! has, so the stream module serves relay viewers with the very code (and
//! the very frame bytes) that serves direct ones: newest-only for a slow
//! viewer, the whole state at once for a late one. Messages of a relay's
//! clients go to the daemon, which checks and acts on them; an anonymous
//! viewer stays on the relay, anyone with a role or token has a session on
//! the stage (the token proven to the daemon, never sent: `relay::proof`).
//! When the stage cannot be reached, viewers are told, keep their last
//! picture, and are told again when it is back.

use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_nats::Client;
use bytes::Bytes;
use futures_util::StreamExt;
use tokio::sync::{mpsc, oneshot, watch};
use tokio::task::JoinHandle;

use super::{
    ALIVE_EVERY, ANSWER_WITHIN, Alive, Assembler, Challenge, Heartbeat, JoinAnswer, JoinRequest,
    Leave, LineupMessage, MessageAnswer, MessageRequest, PictureRequest, RelayError,
    STAGE_GONE_AFTER, Subjects, TOTAL_HEADER,
};
use crate::lineup::{Lineup, StageDescription};
use crate::outputs::{Feed, Published, PuppetSenders, PuppetStart, State};
use crate::protocol::{
    ErrorCode, Person, PersonRole, RigDescription, Role, ServerMessage, StageSize,
};
use crate::stage_thread::{PublishedHandles, PuppetOutput, Timings};
use crate::stream::guard::Refusal;
use crate::stream::upstream::UpstreamSeat;
use crate::stream::{self, Admission, Backend, JoinRefused, Joined, Shared, WebFiles};
use futures_util::future::BoxFuture;

/// How a relay runs.
#[derive(Debug, Clone)]
pub struct RelayOptions {
    /// The NATS server, `nats://[user[:password]@]host:port` (a user
    /// without a password takes `PUPPETRY_NATS_PASSWORD`'s: [`super::nats`]).
    pub nats: String,
    /// The stage's name on NATS (`[relay].stage` of its stage file).
    pub stage: String,
    /// This relay's name: remote performers are `relay:<name>:<n>`, and
    /// it asks on `in.<name>.…` (its NATS user's permissions must allow it).
    pub name: String,
    /// Where viewers connect (HTTP and WebSocket); port 0 picks a free
    /// port ([`RelayRunning::address`] says which).
    pub listen: SocketAddr,
    /// The web client it serves.
    pub web_files: WebFiles,
    /// Open connections past which new ones are refused (503).
    pub max_connections: usize,
    /// How long a client may take to say hello, or to take a message
    /// sent to it, before it is dropped.
    pub client_timeout: Duration,
}

/// A running relay.
pub struct RelayRunning {
    /// Where it listens, its port resolved.
    pub address: SocketAddr,
    link: RelayLink,
    shutdown: oneshot::Sender<()>,
    server: JoinHandle<()>,
    tasks: Vec<JoinHandle<()>>,
}

impl RelayRunning {
    /// How many pictures this relay has fetched from the daemon: once per
    /// puppet and daemon run, however many viewers asked at once.
    pub fn picture_fetches(&self) -> u64 {
        self.link.0.picture_fetches.load(Ordering::Relaxed)
    }

    /// Stops serving and leaves NATS.
    pub async fn shutdown(self) {
        for task in &self.tasks {
            task.abort();
        }
        let _ = self.shutdown.send(());
        let _ = self.server.await;
    }
}

/// Starts a relay: connects to NATS (or keeps trying), asks the daemon
/// for its stage, and serves viewers on `options.listen`.
pub async fn start(options: RelayOptions) -> Result<RelayRunning, RelayError> {
    let subjects = Subjects::new(&options.stage)?;
    if !super::is_name(&options.name) {
        return Err(RelayError::RelayName(options.name.clone()));
    }
    let nats = super::nats::NatsAddress::parse(&options.nats)?;
    if let Some(user) = nats.user()
        && user != options.name
    {
        tracing::warn!(
            "relay {} connects to NATS as {user}: a server that binds each relay to its \
             own subjects (docs/scaling.md) will refuse what it asks",
            options.name
        );
    }
    let (up_tx, up) = watch::channel(false);
    let connecting =
        super::nats::connect_options(&format!("puppetry relay {}", options.name), up_tx)
            // Frames of every puppet at the input rate: room for a burst.
            .subscription_capacity(8192)
            // Answers come to this relay's own inbox, which its NATS user
            // alone may read.
            .custom_inbox_prefix(subjects.inbox(&options.name));
    let client = nats.connect(connecting).await?;
    let published =
        client
            .subscribe(subjects.out_all())
            .await
            .map_err(|e| RelayError::Subscribe {
                subject: subjects.out_all(),
                problem: e.to_string(),
            })?;
    let (mirror, feeds) = Mirror::new();
    let link = RelayLink(Arc::new(LinkInner {
        client: client.clone(),
        subjects: subjects.clone(),
        name: options.name.clone(),
        admission: feeds.admission,
        boot: feeds.boot,
        live: feeds.live,
        clock_offset: feeds.clock_offset,
        started: feeds.started,
        pictures: Mutex::default(),
        picture_fetches: AtomicU64::new(0),
        sessions: Mutex::default(),
    }));
    let shared = Arc::new(Shared {
        lineup: feeds.lineup,
        log: Default::default(),
        addresses: Default::default(),
        web_files: options.web_files.clone(),
        max_connections: options.max_connections,
        cursors: feeds.cursors,
        take: feeds.take,
        export: feeds.export,
        people: feeds.people,
        inputs: feeds.inputs,
        notice: feeds.notice,
        changes: feeds.changes,
        timings: Arc::new(Timings::default()),
        client_timeout: options.client_timeout,
        started: Instant::now(),
        next_client: AtomicU64::new(1),
        backend: Backend::Upstream(Arc::new(link.clone())),
    });
    let listener = stream::bind(options.listen).await?;
    let address = listener
        .local_addr()
        .map_err(|source| stream::StreamError::Listen {
            address: options.listen,
            source,
        })?;
    let (shutdown, stopping) = oneshot::channel::<()>();
    let server = tokio::spawn(stream::run(listener, shared, async move {
        let _ = stopping.await;
    }));
    tracing::info!(
        "relay {} serving stage {} from NATS {} on http://{address}/",
        options.name,
        options.stage,
        nats.shown()
    );
    Ok(RelayRunning {
        address,
        link: link.clone(),
        shutdown,
        server,
        tasks: vec![
            tokio::spawn(super::nats::warn_if_open(client.clone(), up.clone())),
            tokio::spawn(mirror.run(
                published,
                client,
                subjects.ask(&options.name, "sync"),
                subjects,
                up,
            )),
            tokio::spawn(link.say_alive()),
        ],
    })
}

/// The relay's ends of the daemon's state, for the stream module.
struct Feeds {
    lineup: watch::Receiver<Arc<Lineup>>,
    cursors: State,
    take: State,
    export: State,
    people: State,
    inputs: State,
    notice: State,
    changes: watch::Receiver<u64>,
    admission: watch::Receiver<Admission>,
    boot: watch::Receiver<u64>,
    live: watch::Receiver<bool>,
    clock_offset: watch::Receiver<Option<f64>>,
    /// What the clock offset is measured from.
    started: Instant,
}

/// A puppet's output channels on the relay: what the daemon's stage
/// thread has for it, fed from NATS.
struct PuppetFeeds(PuppetSenders);

impl PuppetFeeds {
    fn new(skeleton: bool) -> (PuppetFeeds, PuppetOutput) {
        let (senders, output) = PuppetOutput::channels(PuppetStart {
            handles: Arc::new(PublishedHandles {
                handles: Vec::new(),
                text: Arc::from(""),
                generation: 0,
            }),
            weights: Published::nothing(),
            keys: Published::nothing(),
            history: Published::nothing(),
            pose: skeleton.then(Published::nothing),
        });
        (PuppetFeeds(senders), output)
    }

    /// Takes one message of this puppet's `stream`; whether it was news
    /// (the daemon publishes its whole state again when a relay asks, and
    /// what a relay has already is not sent to its viewers twice).
    fn take(&self, stream: &str, payload: Bytes) -> Result<bool, String> {
        let binary = |feed: &watch::Sender<Option<Bytes>>| {
            feed.send_if_modified(|now| {
                let news = now.as_ref() != Some(&payload);
                if news {
                    *now = Some(payload.clone());
                }
                news
            })
        };
        let text = |feed: &Feed| -> Result<bool, String> {
            let text = std::str::from_utf8(&payload).map_err(|e| e.to_string())?;
            Ok(relay_text(feed, text))
        };
        match stream {
            "frame" => Ok(binary(&self.0.frame)),
            "rig" => Ok(binary(&self.0.rig)),
            "handle_frame" => Ok(binary(&self.0.handle_frame)),
            "depth" => Ok(binary(&self.0.depth)),
            "weights" => text(&self.0.weights),
            "keys" => text(&self.0.keys),
            "history" => text(&self.0.history),
            "pose" => match &self.0.pose {
                Some(pose) => text(pose),
                None => Err("a pose for a puppet without a skeleton".into()),
            },
            "handles" => {
                let text = std::str::from_utf8(&payload).map_err(|e| e.to_string())?;
                if *self.0.handles.borrow().text == *text {
                    return Ok(false);
                }
                let Ok(ServerMessage::Handles {
                    generation,
                    handles,
                    ..
                }) = serde_json::from_str::<ServerMessage>(text)
                else {
                    return Err("a handles message that is not one".into());
                };
                self.0.handles.send_replace(Arc::new(PublishedHandles {
                    handles,
                    text: Arc::from(text),
                    generation,
                }));
                Ok(true)
            }
            other => Err(format!("no puppet stream {other:?}")),
        }
    }
}

/// The relay's copy of the daemon's state, kept by one task.
struct Mirror {
    lineup: watch::Sender<Arc<Lineup>>,
    /// The outputs of the lineup now, by puppet id.
    puppets: Vec<PuppetFeeds>,
    texts: HashMap<&'static str, Feed>,
    notice: Feed,
    changes: watch::Sender<u64>,
    admission: watch::Sender<Admission>,
    boot: watch::Sender<u64>,
    /// The (boot, revision) of the lineup now.
    current: Option<(u64, u64)>,
    /// A new lineup, shown to viewers once every puppet on it has its
    /// handles (the daemon publishes them right after the lineup): a
    /// viewer's `stage` message then has them, as a direct one's does.
    pending: Option<(Arc<Lineup>, HashSet<usize>, Instant)>,
    /// Whether the stage is live now, for the relay's sessions.
    live: watch::Sender<bool>,
    /// The daemon's clock (seconds) minus this process's, from heartbeats.
    clock_offset: watch::Sender<Option<f64>>,
    started: Instant,
    assembler: Assembler,
    /// When the daemon last said it is live.
    heard: Option<Instant>,
    /// The daemon said it stopped.
    stopped: bool,
}

/// Stage-wide text messages, as their subjects name them.
const TEXTS: [&str; 5] = ["cursors", "take", "export", "people", "inputs"];

impl Mirror {
    fn new() -> (Mirror, Feeds) {
        let (lineup, lineup_rx) = watch::channel(empty_lineup());
        let mut texts = HashMap::new();
        let mut receivers = HashMap::new();
        for name in TEXTS {
            let (tx, rx) = watch::channel(Published::nothing());
            texts.insert(name, tx);
            receivers.insert(name, rx);
        }
        let mut text = |name| receivers.remove(name).expect("every text has a channel");
        let (notice, notice_rx) = watch::channel(Published::nothing());
        let (changes, changes_rx) = watch::channel(0);
        // Until the daemon says otherwise, a stage file's defaults.
        let (admission, admission_rx) = watch::channel(Admission {
            allowed_origins: Vec::new(),
            max_per_address: crate::config::Access::default().max_per_address,
        });
        let (boot, boot_rx) = watch::channel(0);
        let started = Instant::now();
        let (live, live_rx) = watch::channel(false);
        let (clock_offset, clock_offset_rx) = watch::channel(None);
        let feeds = Feeds {
            started,
            live: live_rx,
            clock_offset: clock_offset_rx,
            lineup: lineup_rx,
            cursors: text("cursors"),
            take: text("take"),
            export: text("export"),
            people: text("people"),
            inputs: text("inputs"),
            notice: notice_rx,
            changes: changes_rx,
            admission: admission_rx,
            boot: boot_rx,
        };
        let mirror = Mirror {
            lineup,
            puppets: Vec::new(),
            texts,
            notice,
            changes,
            admission,
            boot,
            current: None,
            pending: None,
            live,
            clock_offset,
            started,
            assembler: Assembler::default(),
            heard: None,
            stopped: false,
        };
        (mirror, feeds)
    }

    async fn run(
        mut self,
        mut published: async_nats::Subscriber,
        client: Client,
        sync: String,
        subjects: Subjects,
        mut up: watch::Receiver<bool>,
    ) {
        let mut every = tokio::time::interval(Duration::from_millis(250));
        let (synced_tx, mut synced_rx) = mpsc::channel::<bool>(1);
        let mut synced = false;
        let mut syncing = false;
        loop {
            tokio::select! {
                message = published.next() => {
                    let Some(message) = message else { return };
                    let news = self.take(&subjects, message);
                    if news {
                        self.changes.send_modify(|n| *n += 1);
                    }
                }
                // Any drop, however short, may have lost messages: sync again.
                changed = up.changed() => {
                    if changed.is_err() {
                        return;
                    }
                    up.borrow_and_update();
                    synced = false;
                }
                done = synced_rx.recv() => {
                    syncing = false;
                    synced = done == Some(true);
                    if synced {
                        self.heard = Some(Instant::now());
                    }
                }
                _ = every.tick() => {
                    let connected = *up.borrow();
                    // A lineup whose handles never came (lost on the way).
                    let stuck = self
                        .pending
                        .as_ref()
                        .is_some_and(|(_, _, since)| since.elapsed() > Duration::from_secs(1));
                    if !connected || stuck {
                        synced = false;
                    }
                    if connected && !synced && !syncing {
                        syncing = true;
                        let client = client.clone();
                        let asking = sync.clone();
                        let done = synced_tx.clone();
                        tokio::spawn(async move {
                            let asked = tokio::time::timeout(
                                ANSWER_WITHIN,
                                client.request(asking, Bytes::new()),
                            )
                            .await;
                            let _ = done.send(matches!(asked, Ok(Ok(_)))).await;
                        });
                    }
                    let heard = self.heard.is_some_and(|t| t.elapsed() < STAGE_GONE_AFTER);
                    let lost = if !connected {
                        Some("the relay lost NATS; reconnecting")
                    } else if self.stopped {
                        Some("the stage stopped")
                    } else if !synced || !heard || self.pending.is_some() {
                        Some("the stage is not reachable; waiting for it")
                    } else {
                        None
                    };
                    self.tell(lost);
                }
            }
        }
    }

    /// Tells viewers whether the stage is live (only what changed; nothing
    /// while it never was lost).
    fn tell(&self, lost: Option<&str>) {
        self.live.send_if_modified(|now| {
            let news = *now != lost.is_none();
            *now = lost.is_none();
            news
        });
        let notice = Published::of(ServerMessage::Live {
            live: lost.is_none(),
            reason: lost.map(str::to_string),
        });
        self.notice.send_if_modified(|now| {
            if (now.text.is_empty() && lost.is_none()) || now.text == notice.text {
                return false;
            }
            *now = notice;
            true
        });
    }

    /// Takes one published message; whether anything changed.
    fn take(&mut self, subjects: &Subjects, message: async_nats::Message) -> bool {
        let Some(name) = subjects.published(&message.subject) else {
            return false;
        };
        let payload =
            match self
                .assembler
                .take(&message.subject, message.headers.as_ref(), message.payload)
            {
                Ok(Some(payload)) => payload,
                Ok(None) => return false,
                Err(e) => {
                    tracing::warn!("NATS: {e}");
                    return false;
                }
            };
        let taken = if name == "lineup" {
            self.take_lineup(&payload)
        } else if name == "live" {
            self.take_heartbeat(&payload)
        } else if let Some(text) = name.strip_prefix("s.") {
            match (self.texts.get(text), std::str::from_utf8(&payload)) {
                (Some(feed), Ok(text)) => Ok(relay_text(feed, text)),
                _ => Err(format!("no stage message {text:?}")),
            }
        } else if let Some(puppet) = name.strip_prefix("p.") {
            let (id, stream) = puppet.split_once('.').unwrap_or((puppet, ""));
            let id = id.parse::<usize>().ok();
            let taken = match id.and_then(|i| self.puppets.get(i)) {
                Some(feeds) => feeds.take(stream, payload),
                // Before its lineup: a sync publishes it again after.
                None => Ok(false),
            };
            if stream == "handles"
                && let (Some(id), Some((_, waiting, _))) = (id, self.pending.as_mut())
            {
                waiting.remove(&id);
                if waiting.is_empty() {
                    let (lineup, _, _) = self.pending.take().expect("a pending lineup");
                    self.lineup.send_replace(lineup);
                    return true;
                }
            }
            taken
        } else {
            Err(format!("nothing is published as {name:?}"))
        };
        taken.unwrap_or_else(|e| {
            tracing::warn!("NATS {}: {e}", message.subject);
            false
        })
    }

    fn take_heartbeat(&mut self, payload: &[u8]) -> Result<bool, String> {
        let beat: Heartbeat = serde_json::from_slice(payload).map_err(|e| e.to_string())?;
        self.heard = Some(Instant::now());
        // A heartbeat is under a millisecond old on arrival: close enough
        // for `pong`s, which clients use to place frames on their clocks.
        let offset = beat.clock - self.started.elapsed().as_secs_f64();
        self.clock_offset.send_replace(Some(offset));
        self.stopped = !beat.live;
        Ok(false)
    }

    fn take_lineup(&mut self, payload: &[u8]) -> Result<bool, String> {
        let message: LineupMessage = serde_json::from_slice(payload).map_err(|e| e.to_string())?;
        self.admission.send_if_modified(|now| {
            let news = *now != message.admission;
            if news {
                *now = message.admission.clone();
            }
            news
        });
        self.heard = Some(Instant::now());
        self.stopped = false;
        if self.current == Some((message.boot, message.revision)) {
            return Ok(false);
        }
        let skeletons: HashSet<u32> = message
            .puppets
            .iter()
            .filter(|p| matches!(p.rig, RigDescription::Skeleton { .. }))
            .map(|p| p.id)
            .collect();
        let (feeds, outputs): (Vec<_>, Vec<_>) = (0..message.ids)
            .map(|id| PuppetFeeds::new(skeletons.contains(&(id as u32))))
            .unzip();
        if message.puppets.iter().any(|p| p.id as usize >= message.ids) {
            return Err("a puppet id past the lineup's ids".into());
        }
        let lineup = Lineup {
            revision: message.revision,
            description: StageDescription::from_puppets(message.puppets, message.size, Vec::new()),
            outputs,
            take_puppets: Vec::new(),
            config: no_stage_file(message.size),
        };
        let waiting: HashSet<usize> = lineup
            .description
            .puppets
            .iter()
            .map(|p| p.id as usize)
            .collect();
        self.puppets = feeds;
        self.current = Some((message.boot, message.revision));
        self.boot.send_replace(message.boot);
        if waiting.is_empty() {
            self.lineup.send_replace(Arc::new(lineup));
            return Ok(true);
        }
        self.pending = Some((Arc::new(lineup), waiting, Instant::now()));
        Ok(false)
    }
}

/// A lineup with no puppets: a relay's before the daemon answers.
fn empty_lineup() -> Arc<Lineup> {
    let size = StageSize {
        width: 1.0,
        height: 1.0,
    };
    Arc::new(Lineup {
        revision: 0,
        description: StageDescription::from_puppets(Vec::new(), size, Vec::new()),
        outputs: Vec::new(),
        take_puppets: Vec::new(),
        config: no_stage_file(size),
    })
}

/// A relay has no stage file: an empty stage of the same size stands in
/// where a lineup carries one (only the daemon reads it).
fn no_stage_file(size: StageSize) -> Arc<puppetry_stage::config::StageConfig> {
    let text = format!(
        "[stage]\nwidth = {}\nheight = {}\n",
        size.width.max(f64::MIN_POSITIVE),
        size.height.max(f64::MIN_POSITIVE)
    );
    Arc::new(
        puppetry_stage::config::StageConfig::parse("relay", &text, std::path::Path::new("."))
            .expect("an empty stage of a positive size parses"),
    )
}

/// Where a relay's clients' messages go: the daemon, over NATS.
#[derive(Clone)]
pub(crate) struct RelayLink(Arc<LinkInner>);

/// A picture being fetched or fetched, shared by all who asked for it.
type PictureCell = Arc<tokio::sync::OnceCell<Bytes>>;

struct LinkInner {
    client: Client,
    subjects: Subjects,
    name: String,
    admission: watch::Receiver<Admission>,
    boot: watch::Receiver<u64>,
    /// Whether the stage is live (the mirror says).
    live: watch::Receiver<bool>,
    /// The daemon's clock minus `started`'s, once a heartbeat came.
    clock_offset: watch::Receiver<Option<f64>>,
    started: Instant,
    /// Pictures, by (daemon run, puppet id): each fetched once, by the
    /// first viewer to ask; those who ask meanwhile wait for that fetch
    /// rather than each asking the daemon (a page load per viewer when a
    /// show starts would otherwise be as many fetches).
    pictures: Mutex<HashMap<(u64, u32), PictureCell>>,
    picture_fetches: AtomicU64,
    /// Clients with a session on the stage.
    sessions: Mutex<HashSet<String>>,
}

/// The refusal while the daemon does not answer.
fn unreachable() -> Refusal {
    Refusal::new(
        ErrorCode::Failed,
        "the stage is not reachable from this relay; try again",
    )
}

impl LinkInner {
    async fn ask(&self, name: &str, body: Bytes) -> Result<async_nats::Message, Refusal> {
        let asking = self
            .client
            .request(self.subjects.ask(&self.name, name), body);
        match tokio::time::timeout(ANSWER_WITHIN, asking).await {
            Ok(Ok(answer)) => Ok(answer),
            _ => Err(unreachable()),
        }
    }
}

impl RelayLink {
    /// Who may open the WebSocket: the daemon's `[access]` as it published.
    pub fn admission(&self) -> Admission {
        self.0.admission.borrow().clone()
    }

    /// Seats a relay client: an anonymous viewer here; anyone else with a
    /// session on the stage, if the daemon lets them in.
    pub(crate) async fn join(
        &self,
        client: u64,
        asked: Role,
        token: Option<String>,
    ) -> Result<(Session, Joined), JoinRefused> {
        let source = format!("relay:{}:{client}", self.0.name);
        if asked == Role::Viewer && token.is_none() {
            let you = Person {
                owner: source.clone(),
                name: "viewer".into(),
                role: PersonRole::Viewer,
                colour: stream::people::GREY.into(),
            };
            let joined = Joined {
                role: Role::Viewer,
                you,
                puppets: None,
            };
            let session = Session {
                link: self.0.clone(),
                source,
                remote: false,
            };
            return Ok((session, joined));
        }
        let refused_for = |refusal: Refusal| JoinRefused {
            refusal,
            close: crate::protocol::close::TRY_AGAIN_LATER,
            reason: "the stage is not reachable".into(),
        };
        // The token stays here: the daemon gets a proof of it, on a nonce
        // it issued for this join.
        let proof = match token {
            None => None,
            Some(token) => {
                let answer = self
                    .0
                    .ask("challenge", Bytes::new())
                    .await
                    .map_err(refused_for)?;
                let challenge: Challenge =
                    serde_json::from_slice(&answer.payload).map_err(|e| {
                        refused_for(Refusal::new(
                            ErrorCode::Failed,
                            format!("the stage's challenge: {e}"),
                        ))
                    })?;
                Some(super::proof::prove(
                    &token,
                    &challenge.nonce,
                    self.0.subjects.stage(),
                    &source,
                    asked,
                ))
            }
        };
        let request = JoinRequest {
            source: source.clone(),
            role: asked,
            proof,
        };
        let body = Bytes::from(serde_json::to_vec(&request).expect("joins serialise"));
        let answer = self.0.ask("join", body).await.map_err(refused_for)?;
        match serde_json::from_slice::<JoinAnswer>(&answer.payload) {
            Ok(JoinAnswer::Joined { role, you, puppets }) => {
                self.0
                    .sessions
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .insert(source.clone());
                let session = Session {
                    link: self.0.clone(),
                    source,
                    remote: true,
                };
                Ok((session, Joined { role, you, puppets }))
            }
            Ok(JoinAnswer::Refused {
                refusal,
                close,
                reason,
            }) => Err(JoinRefused {
                refusal,
                close,
                reason,
            }),
            Err(e) => Err(refused_for(Refusal::new(
                ErrorCode::Failed,
                format!("the stage's answer: {e}"),
            ))),
        }
    }

    /// A puppet's picture, fetched from the daemon once per run of it.
    pub(crate) async fn picture(&self, id: u32) -> Option<Bytes> {
        let key = (*self.0.boot.borrow(), id);
        let cell = {
            let mut pictures = self.0.pictures.lock().unwrap_or_else(|p| p.into_inner());
            // Another run's pictures are no one's any more.
            pictures.retain(|(boot, _), _| *boot == key.0);
            pictures.entry(key).or_default().clone()
        };
        // A failed fetch leaves the cell empty: the next to ask tries again.
        cell.get_or_try_init(|| self.fetch_picture(id))
            .await
            .ok()
            .cloned()
    }

    /// A puppet's picture from the daemon, in as many parts as it takes.
    async fn fetch_picture(&self, id: u32) -> Result<Bytes, ()> {
        self.0.picture_fetches.fetch_add(1, Ordering::Relaxed);
        let mut bytes = Vec::new();
        loop {
            let request = PictureRequest {
                id,
                offset: bytes.len(),
            };
            let body = Bytes::from(serde_json::to_vec(&request).expect("requests serialise"));
            let answer = self.0.ask("picture", body).await.map_err(|_| ())?;
            let total: usize = answer
                .headers
                .as_ref()
                .and_then(|h| h.get(TOTAL_HEADER))
                .and_then(|v| v.as_str().parse().ok())
                .ok_or(())?;
            if answer.payload.is_empty() && bytes.len() < total {
                return Err(());
            }
            bytes.extend_from_slice(&answer.payload);
            if bytes.len() >= total {
                break;
            }
        }
        Ok(Bytes::from(bytes))
    }

    /// Tells the daemon, every [`ALIVE_EVERY`], which sessions this relay
    /// still has: a relay that stops saying so (killed, or cut off) has
    /// its performers' handles let go.
    async fn say_alive(self) {
        let mut every = tokio::time::interval(ALIVE_EVERY);
        loop {
            every.tick().await;
            let sessions = self
                .0
                .sessions
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .iter()
                .cloned()
                .collect();
            let alive = Alive { sessions };
            let body = Bytes::from(serde_json::to_vec(&alive).expect("alive serialises"));
            if self.0.client.connection_state() == async_nats::connection::State::Connected {
                let _ = self
                    .0
                    .client
                    .publish(self.0.subjects.ask(&self.0.name, "alive"), body)
                    .await;
            }
        }
    }
}

/// A relay client's seat: its messages go to the daemon, which acts on
/// them with the permissions it gave the client.
pub(crate) struct Session {
    link: Arc<LinkInner>,
    source: String,
    /// The daemon keeps a session for this client (it has a role or token).
    remote: bool,
}

impl Session {
    pub fn source(&self) -> &str {
        &self.source
    }

    pub(crate) async fn handle(&self, text: &str) -> Result<Option<String>, Refusal> {
        if text.len() > stream::MAX_CLIENT_MESSAGE {
            return Err(Refusal::new(
                ErrorCode::TooLarge,
                format!(
                    "messages are at most {} KiB",
                    stream::MAX_CLIENT_MESSAGE / 1024
                ),
            ));
        }
        if let Some(pong) = self.pong(text) {
            return Ok(Some(pong));
        }
        // Not sent while the stage is away: it would only wait, and run
        // late (out of its time) once NATS is back.
        if !*self.link.live.borrow() {
            return Err(unreachable());
        }
        let request = MessageRequest {
            source: self.source.clone(),
            session: self.remote,
            text: text.to_string(),
        };
        let body = Bytes::from(serde_json::to_vec(&request).expect("messages serialise"));
        let answer = self.link.ask("msg", body).await?;
        match serde_json::from_slice::<MessageAnswer>(&answer.payload) {
            Ok(MessageAnswer::Answer(answer)) => Ok(answer),
            Ok(MessageAnswer::Refused(refusal)) => Err(refusal),
            Err(e) => Err(Refusal::new(
                ErrorCode::Failed,
                format!("the stage's answer: {e}"),
            )),
        }
    }

    /// The answer to a `ping`, here: an audience's pings would otherwise
    /// all travel to the daemon. The clock is the daemon's, from its
    /// heartbeats.
    fn pong(&self, text: &str) -> Option<String> {
        if !text.contains("\"ping\"") {
            return None;
        }
        let Ok(crate::protocol::ClientMessage::Ping { t }) = serde_json::from_str(text) else {
            return None;
        };
        let offset = (*self.link.clock_offset.borrow())?;
        let clock = self.link.started.elapsed().as_secs_f64() + offset;
        Some(ServerMessage::Pong { t, clock }.to_text())
    }
}

impl stream::upstream::Upstream for RelayLink {
    fn admission(&self) -> Admission {
        RelayLink::admission(self)
    }

    fn join(
        &self,
        client: u64,
        asked: Role,
        token: Option<String>,
    ) -> BoxFuture<'_, stream::upstream::Seated> {
        Box::pin(async move {
            let (session, joined) = RelayLink::join(self, client, asked, token).await?;
            Ok((Box::new(session) as Box<dyn UpstreamSeat>, joined))
        })
    }

    fn picture(&self, id: u32) -> BoxFuture<'_, Option<Bytes>> {
        Box::pin(RelayLink::picture(self, id))
    }
}

impl UpstreamSeat for Session {
    fn source(&self) -> &str {
        Session::source(self)
    }

    fn handle<'a>(&'a self, text: &'a str) -> BoxFuture<'a, Result<Option<String>, Refusal>> {
        Box::pin(Session::handle(self, text))
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        if !self.remote {
            return;
        }
        self.link
            .sessions
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .remove(&self.source);
        let leave = Leave {
            source: self.source.clone(),
        };
        let body = Bytes::from(serde_json::to_vec(&leave).expect("leaves serialise"));
        let client = self.link.client.clone();
        let subject = self.link.subjects.ask(&self.link.name, "leave");
        // If this is lost, the relay's next `alive` no longer lists the
        // session, and the stage ends it then.
        if let Ok(runtime) = tokio::runtime::Handle::try_current() {
            runtime.spawn(async move {
                let _ = tokio::time::timeout(ANSWER_WITHIN, client.publish(subject, body)).await;
            });
        }
    }
}

/// Forwards a text the daemon published to the relay's viewers; whether it
/// was news (the daemon publishes its whole state again when a relay asks).
fn relay_text(feed: &Feed, text: &str) -> bool {
    feed.send_if_modified(|now| {
        let news = &*now.text != text;
        if news {
            *now = Published::relayed(Arc::from(text));
        }
        news
    })
}
