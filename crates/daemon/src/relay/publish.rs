//! The daemon's side of the relay tier: publishing the stage over NATS,
//! and answering relays. One task follows the puppets exactly as a
//! WebSocket connection does and publishes what changed (frames are the
//! bytes encoded once for every client); while NATS is away it publishes
//! nothing and queues nothing, and when NATS is back it publishes the
//! whole state again. Another task answers relays: `sync`, pictures, and
//! the sessions of remote performers, who are let in and checked exactly
//! as direct clients are (the same `[access]`, roles and puppet limits,
//! their tokens proven rather than sent: [`super::proof`]), named
//! `relay:<relay>:<client>` on the stage, and let go when they leave,
//! their relay stops saying it has them, or goes silent.
//!
//! A relay is who its subject says (`in.<relay>.…`, which nats-server's
//! permissions bind to that relay's credentials): it speaks only for
//! sources `relay:<relay>:…`, acts only for the sessions the daemon
//! admitted through it, and is answered only in its own inbox. Anything
//! else is dropped, with a log line at most every few seconds.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_nats::{Client, HeaderMap, Subject};
use bytes::Bytes;
use futures_util::StreamExt;
use puppetry_input::log_limit::LogLimiter;
use tokio::sync::{Semaphore, mpsc, watch};
use tokio::task::JoinHandle;

use super::proof::{self, Nonces};
use super::{
    ALIVE_EVERY, Alive, Challenge, Heartbeat, JoinAnswer, JoinRequest, Leave, LineupMessage,
    MessageAnswer, MessageRequest, PART, PictureRequest, RELAY_GONE_AFTER, RelayError, Subjects,
    TOTAL_HEADER,
};
use crate::config::RelayConfig;
use crate::outputs::State;
use crate::protocol::Role;
use crate::stream::following::{Following, Payload, STREAMS};
use crate::stream::guard::{Permissions, Refusal};
use crate::stream::{Shared, StageLinks, people};
use puppetry_stage::Picture;

/// Answers handled at once, past which the daemon reads no more requests
/// until one is done (a relay waits for each of its client's answers).
const ANSWERING: usize = 256;
/// At most one line this often about messages dropped (a flood of them
/// must not flood the log).
const DROPPED_LOG_EVERY: Duration = Duration::from_secs(5);

/// The stage published over NATS; stopped with [`Publishing::stop`].
pub struct Publishing {
    client: Client,
    subjects: Subjects,
    boot: u64,
    shared: Arc<Shared>,
    tasks: Vec<JoinHandle<()>>,
}

/// Starts publishing the stage as `stage` on the NATS server of `config`.
/// The daemon starts whether or not the server is up.
pub async fn start(
    config: &RelayConfig,
    stage: &str,
    shared: Arc<Shared>,
) -> Result<Publishing, RelayError> {
    let subjects = Subjects::new(stage)?;
    let address = super::nats::NatsAddress::parse(&config.nats)?;
    let (up_tx, up) = watch::channel(false);
    let options = super::nats::connect_options(&format!("puppetry daemon {stage}"), up_tx)
        // A slow link to NATS holds a few frames at most, never seconds.
        .client_capacity(256);
    let client = address.connect(options).await?;
    // Sessions' keep-alives and syncs on their own subscription, so a
    // burst of requests never delays them.
    let mut control = Vec::new();
    let mut asked = Vec::new();
    for kind in [
        "alive",
        "sync",
        "challenge",
        "join",
        "msg",
        "leave",
        "picture",
    ] {
        let subject = subjects.asks(kind);
        let subscribed = client.subscribe(subject.clone()).await;
        let subscribed = subscribed.map_err(|e| RelayError::Subscribe {
            subject,
            problem: e.to_string(),
        })?;
        if matches!(kind, "alive" | "sync") {
            control.push(subscribed);
        } else {
            asked.push(subscribed);
        }
    }
    let boot = boot_id();
    let (sync_tx, sync_rx) = mpsc::channel(16);
    let sessions = Arc::new(Sessions::default());
    let publisher = Publisher {
        client: client.clone(),
        subjects: subjects.clone(),
        boot,
        shared: shared.clone(),
        frame_every: (config.frame_rate > 0.0)
            .then(|| Duration::from_secs_f64(1.0 / config.frame_rate)),
    };
    let answerer = Answerer {
        client: client.clone(),
        subjects: subjects.clone(),
        shared: shared.clone(),
        sessions: sessions.clone(),
        sync: sync_tx,
        nonces: Nonces::default(),
        dropped: Dropped::default(),
    };
    let open_check = tokio::spawn(super::nats::warn_if_open(client.clone(), up.clone()));
    let expiry = {
        let shared = shared.clone();
        let up = up.clone();
        tokio::spawn(async move { sessions.expire_silent_relays(&shared, up).await })
    };
    let answerer = Arc::new(answerer);
    tracing::info!(
        "publishing the stage as {} on NATS {}",
        subjects.out_all(),
        address.shown()
    );
    Ok(Publishing {
        client,
        subjects,
        boot,
        shared,
        tasks: vec![
            tokio::spawn(publisher.run(up, sync_rx)),
            tokio::spawn(
                answerer
                    .clone()
                    .control(futures_util::stream::select_all(control)),
            ),
            tokio::spawn(answerer.run(futures_util::stream::select_all(asked))),
            expiry,
            open_check,
        ],
    })
}

impl Drop for Publishing {
    fn drop(&mut self) {
        for task in &self.tasks {
            task.abort();
        }
    }
}

impl Publishing {
    /// Says the stage is ending, and stops.
    pub async fn stop(self) {
        for task in &self.tasks {
            task.abort();
        }
        let last = Heartbeat {
            boot: self.boot,
            revision: self.shared.lineup.borrow().revision,
            clock: self.shared.started.elapsed().as_secs_f64(),
            live: false,
        };
        let said = async {
            let _ = self
                .client
                .publish(self.subjects.out("live"), json(&last))
                .await;
            let _ = self.client.flush().await;
        };
        let _ = tokio::time::timeout(Duration::from_secs(1), said).await;
    }
}

/// Which run of the daemon this is, as relays tell runs apart.
fn boot_id() -> u64 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    nanos ^ (u64::from(std::process::id()) << 40)
}

fn json(value: &impl serde::Serialize) -> Bytes {
    Bytes::from(serde_json::to_vec(value).expect("relay messages serialise"))
}

/// The task that publishes the stage.
struct Publisher {
    client: Client,
    subjects: Subjects,
    boot: u64,
    shared: Arc<Shared>,
    /// At most one publish of the puppets' streams this often: an
    /// audience's display rate, whatever the input rate (what comes
    /// between is newest-only, as for a slow client).
    frame_every: Option<Duration>,
}

impl Publisher {
    async fn run(self, mut up: watch::Receiver<bool>, mut sync: mpsc::Receiver<Option<Subject>>) {
        let shared = &self.shared;
        let mut lineup = shared.lineup.clone();
        let mut following = Following::of(lineup.borrow_and_update().clone());
        let mut changes = shared.changes.clone();
        let mut cursors = shared.cursors.clone();
        let mut take = shared.take.clone();
        let mut export = shared.export.clone();
        let mut people = shared.people.clone();
        let mut inputs = shared.inputs.clone();
        let mut heartbeat = tokio::time::interval(ALIVE_EVERY);
        let mut whole = true;
        let mut answer_to: Vec<Subject> = Vec::new();
        let mut published = tokio::time::Instant::now();
        loop {
            if let Some(every) = self.frame_every {
                tokio::time::sleep_until(published + every).await;
                published = tokio::time::Instant::now();
            }
            if *up.borrow() {
                if whole {
                    self.publish_lineup(following.lineup()).await;
                    whole = false;
                }
                self.publish_changed(&mut following).await;
                let texts = [
                    ("cursors", &mut cursors),
                    ("take", &mut take),
                    ("export", &mut export),
                    ("people", &mut people),
                    ("inputs", &mut inputs),
                ];
                for (name, feed) in texts {
                    if feed.has_changed().unwrap_or(false) {
                        let text = feed.borrow_and_update().text.clone();
                        self.send(self.subjects.stage_text(name), text_bytes(&text))
                            .await;
                    }
                }
                for reply in answer_to.drain(..) {
                    let said = Heartbeat {
                        boot: self.boot,
                        revision: following.lineup().revision,
                        clock: shared.started.elapsed().as_secs_f64(),
                        live: true,
                    };
                    self.send(reply.to_string(), json(&said)).await;
                }
            } else {
                // Nothing queues while NATS is away: every frame held in
                // the client would keep a stage-thread buffer alive.
                for k in 0..following.on_stage().len() {
                    let i = following.on_stage()[k];
                    let _ = following.changed(i);
                }
                answer_to.clear();
            }
            tokio::select! {
                changed = changes.changed() => {
                    if changed.is_err() {
                        return;
                    }
                }
                changed = lineup.changed() => {
                    if changed.is_ok() {
                        following = Following::of(lineup.borrow_and_update().clone());
                        whole = true;
                    }
                }
                // `changed` marks seen: mark again, so the loop publishes it.
                changed = export.changed() => if changed.is_ok() { export.mark_changed() },
                changed = people.changed() => if changed.is_ok() { people.mark_changed() },
                changed = inputs.changed() => if changed.is_ok() { inputs.mark_changed() },
                asked = sync.recv() => {
                    let Some(reply) = asked else { return };
                    answer_to.extend(reply);
                    // Every relay asking now is answered by one republish.
                    while let Ok(more) = sync.try_recv() {
                        answer_to.extend(more);
                    }
                    everything_again(&mut following, &lineup, &mut [&mut cursors, &mut take, &mut export, &mut people, &mut inputs]);
                    whole = true;
                }
                changed = up.changed() => {
                    if changed.is_err() {
                        return;
                    }
                    if *up.borrow_and_update() {
                        tracing::info!("NATS connected: publishing the whole stage");
                        everything_again(&mut following, &lineup, &mut [&mut cursors, &mut take, &mut export, &mut people, &mut inputs]);
                        whole = true;
                    } else {
                        tracing::warn!("NATS lost: direct clients go on; reconnecting");
                    }
                }
                _ = heartbeat.tick() => {
                    if *up.borrow() {
                        let beat = Heartbeat {
                            boot: self.boot,
                            revision: following.lineup().revision,
                            clock: shared.started.elapsed().as_secs_f64(),
                            live: true,
                        };
                        self.send(self.subjects.out("live"), json(&beat)).await;
                    }
                }
            }
        }
    }

    async fn publish_lineup(&self, lineup: &crate::lineup::Lineup) {
        let admission = self.shared.admission();
        let message = LineupMessage {
            boot: self.boot,
            revision: lineup.revision,
            size: lineup.description.size,
            puppets: lineup.description.puppets.clone(),
            ids: lineup.outputs.len(),
            admission,
        };
        self.send(self.subjects.out("lineup"), json(&message)).await;
    }

    async fn publish_changed(&self, following: &mut Following) {
        for k in 0..following.on_stage().len() {
            let i = following.on_stage()[k];
            for (slot, payload) in following.changed(i).into_iter().enumerate() {
                let bytes = match payload {
                    None => continue,
                    Some(Payload::Binary(bytes)) => bytes,
                    Some(Payload::Text(text)) => text_bytes(&text),
                };
                self.send(self.subjects.puppet(i, STREAMS[slot]), bytes)
                    .await;
            }
        }
    }

    async fn send(&self, subject: String, payload: Bytes) {
        // Queued messages would wait out the outage, holding frames.
        if self.client.connection_state() != async_nats::connection::State::Connected {
            return;
        }
        if let Err(e) = super::publish(&self.client, subject, payload).await {
            tracing::debug!("NATS publish: {e}");
        }
    }
}

/// The same text as bytes (one copy; texts change at human rates).
fn text_bytes(text: &Arc<str>) -> Bytes {
    Bytes::copy_from_slice(text.as_bytes())
}

/// Marks the whole state to publish again (a relay asked, or NATS is back).
fn everything_again(
    following: &mut Following,
    lineup: &watch::Receiver<Arc<crate::lineup::Lineup>>,
    texts: &mut [&mut State],
) {
    *following = Following::of(lineup.borrow().clone());
    for feed in texts {
        feed.mark_changed();
    }
}

/// The task that answers relays.
struct Answerer {
    client: Client,
    subjects: Subjects,
    shared: Arc<Shared>,
    sessions: Arc<Sessions>,
    sync: mpsc::Sender<Option<Subject>>,
    /// Nonces issued for relays' joins.
    nonces: Nonces,
    dropped: Dropped,
}

/// The log of messages dropped: one line at once, then one per
/// `DROPPED_LOG_EVERY`, the rest counted.
struct Dropped(Mutex<LogLimiter>);

impl Default for Dropped {
    fn default() -> Dropped {
        Dropped(Mutex::new(LogLimiter::with_rate(
            1,
            DROPPED_LOG_EVERY,
            Instant::now(),
        )))
    }
}

impl Dropped {
    /// Logs `why` unless a line was logged lately (then counts it).
    fn note(&self, why: std::fmt::Arguments<'_>) {
        let mut limiter = self.0.lock().unwrap_or_else(|p| p.into_inner());
        limiter.warn(format_args!("NATS: dropped {why}"));
    }
}

impl Answerer {
    /// `(relay, kind)` of an asked message, if it may be answered: a
    /// reply, if it asks one, in the asking relay's own inbox.
    fn asker<'m>(&self, message: &'m async_nats::Message) -> Option<(&'m str, &'m str)> {
        let (relay, kind) = self.subjects.asked(&message.subject)?;
        if let Some(reply) = &message.reply
            && !self.subjects.is_inbox_of(relay, reply)
        {
            self.dropped.note(format_args!(
                "{}: its reply subject is not relay {relay}'s inbox",
                message.subject
            ));
            return None;
        }
        Some((relay, kind))
    }

    /// Syncs and relays' keep-alives, in order.
    async fn control(
        self: Arc<Self>,
        mut asked: impl futures_util::Stream<Item = async_nats::Message> + Unpin,
    ) {
        while let Some(message) = asked.next().await {
            match self.asker(&message) {
                // A sync already waiting answers this one too.
                Some((_, "sync")) => {
                    let _ = self.sync.try_send(message.reply.clone());
                }
                Some((relay, "alive")) => match serde_json::from_slice::<Alive>(&message.payload) {
                    Ok(alive) => self.sessions.alive(&self.shared, relay, alive).await,
                    Err(e) => tracing::warn!("NATS {}: {e}", message.subject),
                },
                _ => {}
            }
        }
    }

    /// Sessions' requests, each answered by a task of its own (at most
    /// [`ANSWERING`] at once).
    async fn run(
        self: Arc<Self>,
        mut asked: impl futures_util::Stream<Item = async_nats::Message> + Unpin,
    ) {
        let answering = Arc::new(Semaphore::new(ANSWERING));
        let me = self;
        while let Some(message) = asked.next().await {
            let Some((relay, kind)) = me.asker(&message) else {
                continue;
            };
            match kind {
                "challenge" | "join" | "msg" | "leave" | "picture" => {
                    let Ok(permit) = answering.clone().acquire_owned().await else {
                        return;
                    };
                    let me = me.clone();
                    let (relay, kind) = (relay.to_string(), kind.to_string());
                    tokio::spawn(async move {
                        me.answer(&relay, &kind, message).await;
                        drop(permit);
                    });
                }
                other => tracing::debug!("NATS: nothing answers in.{relay}.{other}"),
            }
        }
    }

    async fn answer(&self, relay: &str, kind: &str, message: async_nats::Message) {
        let Ok(links) = self.shared.links() else {
            return;
        };
        let payload = &message.payload;
        let answer = match kind {
            "challenge" => match self.nonces.issue(relay) {
                Ok(nonce) => Some(json(&Challenge { nonce })),
                Err(e) => {
                    tracing::error!("a nonce for relay {relay}: {e}");
                    None
                }
            },
            "join" => match serde_json::from_slice::<JoinRequest>(payload) {
                Ok(request) if !is_source_of(relay, &request.source) => {
                    self.dropped.note(format_args!(
                        "a join from relay {relay} for {:?}, not one of its clients",
                        crate::stream::guard::clip(&request.source, 80)
                    ));
                    None
                }
                Ok(request) => Some(json(&self.join(links, relay, request).await)),
                Err(e) => Some(json(&JoinAnswer::Refused {
                    refusal: Refusal::from(format!("bad join: {e}")),
                    close: crate::protocol::close::POLICY,
                    reason: "bad join".into(),
                })),
            },
            "msg" => match serde_json::from_slice::<MessageRequest>(payload) {
                Ok(request) => self.message(relay, request).await.map(|a| json(&a)),
                Err(e) => Some(json(&MessageAnswer::Refused(Refusal::from(format!(
                    "bad relay message: {e}"
                ))))),
            },
            "leave" => {
                if let Ok(leave) = serde_json::from_slice::<Leave>(payload) {
                    if self.sessions.relay_of(&leave.source).as_deref() == Some(relay) {
                        self.sessions.end(links, &leave.source).await;
                    } else {
                        self.dropped.note(format_args!(
                            "a leave from relay {relay} for {:?}, not a session it has",
                            crate::stream::guard::clip(&leave.source, 80)
                        ));
                    }
                }
                None
            }
            "picture" => {
                let Ok(request) = serde_json::from_slice::<PictureRequest>(payload) else {
                    return;
                };
                if let Some(reply) = message.reply.clone() {
                    let (headers, part) = self.picture(request).await;
                    let _ = self.client.publish_with_headers(reply, headers, part).await;
                }
                None
            }
            _ => None,
        };
        if let (Some(answer), Some(reply)) = (answer, message.reply) {
            let _ = self.client.publish(reply, answer).await;
        }
    }

    /// A relay's client's hello: its token, if it gave one, is the one of
    /// the stage's that the proof proves, on a nonce issued to this relay.
    async fn join(&self, links: &StageLinks, relay: &str, request: JoinRequest) -> JoinAnswer {
        let token = match &request.proof {
            None => None,
            Some(proof) => {
                if !self.nonces.redeem(relay, &proof.nonce) {
                    return JoinAnswer::Refused {
                        refusal: Refusal::new(
                            crate::protocol::ErrorCode::Failed,
                            "the join's nonce is spent, expired or not this relay's: try again",
                        ),
                        close: crate::protocol::close::TRY_AGAIN_LATER,
                        reason: "stale nonce".into(),
                    };
                }
                let access = links.people.access();
                let tokens = access
                    .people
                    .iter()
                    .map(|p| p.token.as_str())
                    .chain(access.performer_tokens.iter().map(String::as_str));
                let matched = proof::matching(
                    tokens,
                    proof,
                    self.subjects.stage(),
                    &request.source,
                    request.role,
                );
                // A proof of no token is a wrong token (or none), answered
                // as a direct hello with one is.
                matched.map(str::to_string)
            }
        };
        self.sessions
            .join(
                links,
                relay,
                &request.source,
                request.role,
                token.as_deref(),
            )
            .await
    }

    /// Acts on a relay's client's message with that client's permissions;
    /// `None` (no answer) for a client that is not the relay's.
    async fn message(&self, relay: &str, request: MessageRequest) -> Option<MessageAnswer> {
        if !is_source_of(relay, &request.source) {
            self.dropped.note(format_args!(
                "a message from relay {relay} for {:?}, not one of its clients",
                crate::stream::guard::clip(&request.source, 80)
            ));
            return None;
        }
        let session = request
            .session
            .then(|| self.sessions.permissions(&request.source));
        let permissions = match session {
            Some(Some(p)) => p,
            Some(None) => {
                return Some(MessageAnswer::Refused(Refusal::new(
                    crate::protocol::ErrorCode::Failed,
                    "the stage ended this session (the relay was away too long): reconnect",
                )));
            }
            None => Permissions {
                role: Role::Viewer,
                puppets: None,
            },
        };
        let answer = match crate::stream::handle_message(
            &request.text,
            &permissions,
            &request.source,
            &self.shared,
        )
        .await
        {
            Ok(answer) => MessageAnswer::Answer(answer),
            Err(refusal) => MessageAnswer::Refused(refusal),
        };
        Some(answer)
    }

    /// A part of a puppet's picture, with the whole picture's length.
    async fn picture(&self, request: PictureRequest) -> (HeaderMap, Bytes) {
        let picture: Option<Picture> = {
            let lineup = self.shared.lineup.borrow();
            lineup.description.images.get(request.id as usize).cloned()
        };
        let read = match picture {
            Some(picture) => tokio::task::spawn_blocking(move || picture.png().ok())
                .await
                .ok()
                .flatten(),
            None => None,
        };
        let mut headers = HeaderMap::new();
        let Some(bytes) = read else {
            headers.insert(TOTAL_HEADER, "none");
            return (headers, Bytes::new());
        };
        headers.insert(TOTAL_HEADER, bytes.len().to_string().as_str());
        let from = request.offset.min(bytes.len());
        let to = (from + PART).min(bytes.len());
        (headers, Bytes::copy_from_slice(&bytes[from..to]))
    }
}

/// `relay:<relay>:<client>`, each part one subject token's characters.
fn is_relay_source(source: &str) -> bool {
    let mut parts = source.split(':');
    parts.next() == Some("relay")
        && parts.next().is_some_and(super::is_name)
        && parts
            .next()
            .is_some_and(|n| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()))
        && parts.next().is_none()
}

/// Whether `source` is a client of `relay` (`relay:<relay>:<n>`).
fn is_source_of(relay: &str, source: &str) -> bool {
    is_relay_source(source) && source.split(':').nth(1) == Some(relay)
}

/// Remote performers' sessions, by source.
#[derive(Default)]
struct Sessions {
    by_source: Mutex<HashMap<String, RemoteSession>>,
    /// When each relay last said which sessions it has.
    relays: Mutex<HashMap<String, Instant>>,
}

struct RemoteSession {
    relay: String,
    permissions: Permissions,
    limited: bool,
    since: Instant,
    /// Their place in the `people` list.
    _member: Option<people::Member>,
}

impl Sessions {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, RemoteSession>> {
        self.by_source.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn permissions(&self, source: &str) -> Option<Permissions> {
        self.lock().get(source).map(|s| s.permissions.clone())
    }

    /// Which relay admitted `source`, if it has a session.
    fn relay_of(&self, source: &str) -> Option<String> {
        self.lock().get(source).map(|s| s.relay.clone())
    }

    /// Lets `source` (a client of `relay`: the caller checked) onto the
    /// stage with `token` (the daemon's own copy of the one proven).
    async fn join(
        &self,
        links: &StageLinks,
        relay: &str,
        source: &str,
        role: Role,
        token: Option<&str>,
    ) -> JoinAnswer {
        // A relay restarted under the same name numbers its clients anew:
        // whatever the old one of this name held goes first.
        self.end(links, source).await;
        match crate::stream::join_stage(links, source, role, token).await {
            Ok((joined, permissions, member)) => {
                let session = RemoteSession {
                    relay: relay.to_string(),
                    limited: joined.puppets.is_some(),
                    permissions,
                    since: Instant::now(),
                    _member: member,
                };
                self.lock().insert(source.to_string(), session);
                tracing::info!("{source} joined through a relay as {:?}", joined.role);
                JoinAnswer::Joined {
                    role: joined.role,
                    you: joined.you,
                    puppets: joined.puppets,
                }
            }
            Err(refused) => JoinAnswer::Refused {
                refusal: refused.refusal,
                close: refused.close,
                reason: refused.reason,
            },
        }
    }

    /// Ends a session: its handles let go, its limit lifted, its place in
    /// `people` given up.
    async fn end(&self, links: &StageLinks, source: &str) {
        let Some(session) = self.lock().remove(source) else {
            return;
        };
        crate::stream::leave_stage(links, source, session.permissions.role, session.limited).await;
        tracing::info!("{source} left (relay {})", session.relay);
    }

    /// A relay's list of sessions: any of its sessions it no longer lists
    /// (a leave lost on the way) ends.
    async fn alive(&self, shared: &Shared, relay: &str, alive: Alive) {
        let now = Instant::now();
        self.relays
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(relay.to_string(), now);
        let gone: Vec<String> = self
            .lock()
            .iter()
            .filter(|(source, s)| {
                s.relay == relay
                    && now.duration_since(s.since) > 2 * ALIVE_EVERY
                    && !alive.sessions.contains(source)
            })
            .map(|(source, _)| source.clone())
            .collect();
        if let Ok(links) = shared.links() {
            for source in gone {
                self.end(links, &source).await;
            }
        }
    }

    /// Ends the sessions of relays that went silent (killed, or cut off
    /// from NATS), so nothing stays held on stage by someone gone.
    async fn expire_silent_relays(&self, shared: &Shared, up: watch::Receiver<bool>) {
        let mut every = tokio::time::interval(ALIVE_EVERY);
        let mut was_up = true;
        loop {
            every.tick().await;
            let now = Instant::now();
            // The daemon's own outage silences every relay: no one's fault.
            if !*up.borrow() {
                was_up = false;
                continue;
            }
            if !was_up {
                was_up = true;
                let mut relays = self.relays.lock().unwrap_or_else(|p| p.into_inner());
                relays.values_mut().for_each(|heard| *heard = now);
                self.lock().values_mut().for_each(|s| s.since = now);
                continue;
            }
            let silent = |relay: &str, since: Instant| {
                let heard = self
                    .relays
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .get(relay)
                    .copied()
                    .unwrap_or(since);
                now.duration_since(heard) > RELAY_GONE_AFTER
            };
            let gone: Vec<String> = self
                .lock()
                .iter()
                .filter(|(_, s)| silent(&s.relay, s.since))
                .map(|(source, _)| source.clone())
                .collect();
            let Ok(links) = shared.links() else {
                return;
            };
            for source in gone {
                tracing::warn!("{source}: its relay went silent; letting go of its handles");
                self.end(links, &source).await;
            }
            // Relays long gone with no sessions are forgotten.
            let with_sessions: std::collections::HashSet<String> =
                self.lock().values().map(|s| s.relay.clone()).collect();
            self.relays
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .retain(|relay, heard| {
                    with_sessions.contains(relay) || now.duration_since(*heard) < RELAY_GONE_AFTER
                });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relay_sources_are_checked() {
        assert!(is_relay_source("relay:hall-2:17"));
        for bad in [
            "client:3",
            "relay::3",
            "relay:a:",
            "relay:a:3:4",
            "relay:a.b:3",
            "relay:a:x",
        ] {
            assert!(!is_relay_source(bad), "{bad}");
        }
        assert!(is_source_of("hall-2", "relay:hall-2:17"));
        assert!(!is_source_of("hall", "relay:hall-2:17"));
        assert!(!is_source_of("hall", "relay:hall:x"));
    }
}
