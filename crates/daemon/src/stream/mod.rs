//! The stream: HTTP and WebSocket on one port. Serves the web renderer and
//! puppet pictures, and speaks the protocol of `docs/protocol.md` to
//! renderer and performer clients. Each client task sends the newest frame
//! of each puppet and skips the ones it was too slow for; a stalled client
//! never delays the stage thread or other clients, and one that stops
//! reading is dropped after the stage's client timeout.

mod edge;
mod exports;
pub(crate) mod following;
pub(crate) mod guard;
mod origin;
pub(crate) mod people;
mod uploads;
pub(crate) mod upstream;
pub(crate) use uploads::restore_pictures;

pub use edge::{EdgeTimes, WebFiles};
pub(crate) use people::People;

use futures_util::SinkExt;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::extract::ws::{Message, WebSocket};
use futures_util::StreamExt;
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};

use crate::convert::Converted;
use crate::lineup::{Lineup, LineupChange};
use crate::outputs::{Feed, State};
use crate::protocol::{ClientMessage, Role, ServerMessage};
use crate::stage_thread::{Command, Edit};
use following::Following;

/// Why the edge (a daemon's or a relay's) could not start.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    /// Binding the listening socket failed (an address in use, a port the
    /// process may not open, an address not of this machine).
    #[error("cannot listen on {address}: {source}")]
    Listen {
        /// The address asked for.
        address: SocketAddr,
        /// What the system said.
        source: std::io::Error,
    },
}

/// Largest message a client may send.
pub use puppetry_limits::net::MAX_CLIENT_MESSAGE_BYTES as MAX_CLIENT_MESSAGE;
/// Read buffer of a client connection (see `serve_connection`).
const READ_BUFFER: usize = 4 * 1024;
/// Bad messages in a row before a client is disconnected.
pub const MAX_BAD_MESSAGES: u32 = 20;

/// What every connection task shares: the edge's settings, the feeds a
/// connection follows, and where its messages go (the stage itself, or a
/// daemon reached over NATS when this edge is a relay).
pub(crate) struct Shared {
    /// The puppets on stage and where each one's output is.
    pub lineup: watch::Receiver<Arc<Lineup>>,
    /// Client mistakes are logged through this, per client address.
    pub log: guard::RateLog,
    /// Open WebSocket connections per client address (`max_per_address`).
    pub addresses: std::sync::Mutex<std::collections::HashMap<std::net::IpAddr, usize>>,
    pub web_files: WebFiles,
    /// Open connections past which new ones are refused.
    pub max_connections: usize,
    /// The newest "cursors" message (mouse cursors on the stage).
    pub cursors: State,
    /// The newest "take" message (recording and playing now).
    pub take: State,
    /// The newest "export" message.
    pub export: State,
    /// The newest "people" message.
    pub people: State,
    /// The newest "inputs" message (the stage's replays).
    pub inputs: State,
    /// The newest "live" notice; empty while there is none (a daemon never
    /// has one: only a relay loses its stage).
    pub notice: State,
    /// Bumped after each publish (by the stage thread, or a relay's feed).
    pub changes: watch::Receiver<u64>,
    /// Where the stage thread's and the client tasks' time goes.
    pub timings: Arc<crate::stage_thread::Timings>,
    pub client_timeout: Duration,
    /// The clock `ping` answers with (a relay answers through the daemon).
    pub started: Instant,
    pub next_client: AtomicU64,
    pub backend: Backend,
}

/// Where a connection's messages go.
pub(crate) enum Backend {
    /// This process runs the stage.
    Stage(StageLinks),
    /// This process is a relay: the stage is a daemon reached over NATS.
    Upstream(std::sync::Arc<dyn upstream::Upstream>),
}

/// What only the process running the stage has.
pub(crate) struct StageLinks {
    /// Who may connect, and who is connected.
    pub people: Arc<People>,
    pub commands: mpsc::Sender<Command>,
    /// Where takes are recorded and listed.
    pub takes_dir: std::path::PathBuf,
    /// The take playing, if any (never locked across an await).
    pub player: std::sync::Mutex<Option<crate::takes::Player>>,
    /// Where pictures added at runtime are kept, with their meshes.
    pub puppets_dir: std::path::PathBuf,
    /// An export is running (one at a time).
    pub exporting: std::sync::atomic::AtomicBool,
    /// An uploaded picture is being read and meshed (one at a time).
    pub meshing: std::sync::atomic::AtomicBool,
    /// The newest "export" message.
    pub export_state: Feed,
    /// The stage's replay inputs, played and paused from the page.
    pub replays: Arc<crate::sources::Replays>,
    /// The contacts each client holds down, counted at the door.
    pub held: guard::Held,
    /// MIDI mappings learnt from the page.
    pub learning: Arc<crate::midi_learn::Learning>,
}

/// Who may open the WebSocket beyond the edge's own pages, and how many
/// per address: the stage file's `[access]`, which a relay learns from
/// the daemon.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Admission {
    pub allowed_origins: Vec<String>,
    pub max_per_address: usize,
}

impl Shared {
    /// The stage's own links; a relay has none (it forwards messages, and
    /// does not serve uploads, takes or exports).
    pub fn links(&self) -> Result<&StageLinks, String> {
        match &self.backend {
            Backend::Stage(links) => Ok(links),
            Backend::Upstream(_) => {
                Err("a relay does not serve this: connect to the daemon itself".to_string())
            }
        }
    }

    /// Who may open the WebSocket, now.
    pub fn admission(&self) -> Admission {
        match &self.backend {
            Backend::Stage(links) => Admission {
                allowed_origins: links.people.access().allowed_origins.clone(),
                max_per_address: links.people.access().max_per_address,
            },
            Backend::Upstream(link) => link.admission(),
        }
    }
}

/// Binds the listener; `run` serves until `shutdown` resolves.
pub(crate) async fn bind(address: SocketAddr) -> Result<TcpListener, StreamError> {
    TcpListener::bind(address)
        .await
        .map_err(|source| StreamError::Listen { address, source })
}

/// Serves HTTP and WebSocket until `shutdown` resolves; each connection is
/// served by its own task, and an error in one is logged and contained.
pub(crate) async fn run(
    listener: TcpListener,
    shared: Arc<Shared>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) {
    run_with(listener, shared, EdgeTimes::default(), shutdown).await
}

/// [`run`], waiting on connections as `times` says.
pub(crate) async fn run_with(
    listener: TcpListener,
    shared: Arc<Shared>,
    times: EdgeTimes,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) {
    edge::serve(listener, shared, times, shutdown).await
}

type Ws = WebSocket;

pub(crate) use crate::protocol::close;

/// Sends a close frame with `code` and `reason`; the connection ends after.
async fn close_with(ws: &mut Ws, code: u16, reason: &str) {
    let frame = axum::extract::ws::CloseFrame {
        code,
        reason: reason.into(),
    };
    let _ =
        tokio::time::timeout(Duration::from_secs(2), ws.send(Message::Close(Some(frame)))).await;
}

/// Sends a refusal, logged (rate-limited) under the client's address.
async fn refuse(
    ws: &mut Ws,
    shared: &Shared,
    peer: &str,
    who: &str,
    refusal: &guard::Refusal,
) -> std::io::Result<()> {
    shared.log.warn(peer, || {
        format!("{who}: refused ({:?}): {}", refusal.code, refusal.message)
    });
    send(ws, Message::text(refusal.to_text()), shared.client_timeout).await
}

/// Whether a read error is a message over the size limit.
fn too_large(error: &axum::Error) -> bool {
    let text = error.to_string();
    text.contains("too long") || text.contains("Space limit")
}

/// The too-large refusal (before closing with 1009).
fn too_large_refusal() -> guard::Refusal {
    guard::Refusal::new(
        crate::protocol::ErrorCode::TooLarge,
        format!("messages are at most {} KiB", MAX_CLIENT_MESSAGE / 1024),
    )
}

/// Waits for the hello (skipping WebSocket pings): its role and token, or
/// the connection is answered and closed.
async fn read_hello(ws: &mut Ws, shared: &Shared, peer: &str) -> Option<(Role, Option<String>)> {
    use crate::protocol::ErrorCode;
    let deadline = tokio::time::Instant::now() + shared.client_timeout;
    let first = loop {
        match tokio::time::timeout_at(deadline, ws.next()).await {
            Err(_) => {
                close_with(ws, close::POLICY, "no hello in time").await;
                return None;
            }
            Ok(None) | Ok(Some(Ok(Message::Close(_)))) => return None,
            Ok(Some(Err(e))) if too_large(&e) => {
                let _ = refuse(ws, shared, peer, "hello", &too_large_refusal()).await;
                close_with(ws, close::TOO_LARGE, "message too large").await;
                return None;
            }
            Ok(Some(Err(_))) => return None,
            Ok(Some(Ok(Message::Ping(_) | Message::Pong(_)))) => continue,
            Ok(Some(Ok(message))) => break message,
        }
    };
    let refusal = match first {
        Message::Text(text) => match serde_json::from_str::<ClientMessage>(&text) {
            Ok(ClientMessage::Hello { role, token }) => return Some((role, token)),
            Ok(other) => guard::Refusal::new(
                ErrorCode::Hello,
                format!(
                    "the first message must be a hello, not {}",
                    guard::type_name(&other)
                ),
            ),
            Err(e) => guard::Refusal::new(
                ErrorCode::Hello,
                format!("the first message must be a hello: {e}"),
            ),
        },
        _ => guard::Refusal::new(
            ErrorCode::Binary,
            "the first message must be a hello (text), not binary",
        ),
    };
    let _ = refuse(ws, shared, peer, "hello", &refusal).await;
    close_with(ws, close::POLICY, "the first message must be a hello").await;
    None
}

/// A connected client's seat: who it is to the stage, and where its
/// messages go.
enum Seat {
    /// On the stage of this process.
    Stage {
        source: String,
        permissions: guard::Permissions,
        _member: Option<people::Member>,
    },
    /// On a relay: the daemon keeps the session, and checks every message.
    Upstream(Box<dyn upstream::UpstreamSeat>),
}

/// A hello that was refused: what to tell the client, and how to close.
pub(crate) struct JoinRefused {
    pub refusal: guard::Refusal,
    pub close: u16,
    pub reason: String,
}

/// What the stage says of a client it let in.
pub(crate) struct Joined {
    pub role: Role,
    pub you: crate::protocol::Person,
    /// Ids of the puppets a limited performer plays; `None`: all.
    pub puppets: Option<Vec<u32>>,
}

/// The refusal of a hello whose token opens nothing.
pub(crate) fn bad_token() -> JoinRefused {
    JoinRefused {
        refusal: guard::Refusal::new(
            crate::protocol::ErrorCode::BadToken,
            "token refused: this connection may only view (say hello as a viewer)",
        ),
        close: close::TOKEN_REFUSED,
        reason: "token refused".into(),
    }
}

/// Lets `source` onto the stage as `asked` with `token`: its identity
/// checked against the stage's `[access]`, listed in `people` (performers
/// and directors) and limited to its puppets. The same for a direct
/// client and one a relay forwards.
pub(crate) async fn join_stage(
    links: &StageLinks,
    source: &str,
    asked: Role,
    token: Option<&str>,
) -> Result<(Joined, guard::Permissions, Option<people::Member>), JoinRefused> {
    let credential = token.and_then(|t| people::credential(links.people.access(), t));
    if asked != Role::Viewer && credential.is_none() {
        return Err(bad_token());
    }
    let (identity, member) = links.people.join(source, asked, credential);
    let permissions = guard::Permissions {
        role: identity.role,
        puppets: identity.puppets.clone(),
    };
    if let Some(puppets) = &identity.puppets {
        // Before any of this client's input: the stage thread takes
        // commands in order.
        let limit = Command::Limit {
            source: source.to_string(),
            puppets: Some(puppets.clone()),
        };
        let _ = links.commands.send(limit).await;
    }
    let joined = Joined {
        role: identity.role,
        you: identity.person,
        puppets: identity.puppets,
    };
    Ok((joined, permissions, member))
}

/// Lets go of whatever `source` held on the stage, and of its puppet limit.
pub(crate) async fn leave_stage(links: &StageLinks, source: &str, role: Role, limited: bool) {
    links.held.forget(source);
    if role != Role::Viewer {
        let _ = links.commands.send(crate::convert::release(source)).await;
    }
    if limited {
        let _ = links
            .commands
            .send(Command::Limit {
                source: source.to_string(),
                puppets: None,
            })
            .await;
    }
}

impl Seat {
    async fn join(
        shared: &Shared,
        client: u64,
        asked: Role,
        token: Option<String>,
    ) -> Result<(Seat, Joined), JoinRefused> {
        match &shared.backend {
            Backend::Stage(links) => {
                let source = format!("client:{client}");
                let (joined, permissions, member) =
                    join_stage(links, &source, asked, token.as_deref()).await?;
                let seat = Seat::Stage {
                    source,
                    permissions,
                    _member: member,
                };
                Ok((seat, joined))
            }
            Backend::Upstream(link) => {
                let (seat, joined) = link.join(client, asked, token).await?;
                Ok((Seat::Upstream(seat), joined))
            }
        }
    }

    fn source(&self) -> &str {
        match self {
            Seat::Stage { source, .. } => source,
            Seat::Upstream(seat) => seat.source(),
        }
    }

    async fn handle(&self, text: &str, shared: &Shared) -> Result<Option<String>, guard::Refusal> {
        match self {
            Seat::Stage {
                source,
                permissions,
                ..
            } => handle_message(text, permissions, source, shared).await,
            Seat::Upstream(seat) => seat.handle(text).await,
        }
    }

    async fn leave(self, shared: &Shared, joined: &Joined) {
        match (self, &shared.backend) {
            (Seat::Stage { source, .. }, Backend::Stage(links)) => {
                leave_stage(links, &source, joined.role, joined.puppets.is_some()).await;
            }
            // Dropping the seat lets the stage know.
            (Seat::Upstream(_), _) | (Seat::Stage { .. }, Backend::Upstream(_)) => {}
        }
    }
}

/// What the client loop does after a client's message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Next {
    /// Goes on.
    Go,
    /// Ends: the client closed, or was closed.
    End,
}

/// A client's standing in its loop: pings sent and the newest answered
/// (pings carry their number), bad messages in a row.
#[derive(Debug, Default)]
struct Standing {
    pinged: u64,
    answered: u64,
    bad_in_a_row: u32,
}

/// Handles what came from the client: a message for `seat` (answered, or
/// refused and counted), a pong, a close; closes the connection for a
/// message too large or too many bad ones in a row.
async fn on_message(
    ws: &mut Ws,
    incoming: Option<Result<Message, axum::Error>>,
    shared: &Shared,
    seat: &Seat,
    peer: &str,
    standing: &mut Standing,
) -> std::io::Result<Next> {
    use crate::protocol::ErrorCode;
    let refusal = match incoming {
        None => return Ok(Next::End),
        Some(Err(e)) if too_large(&e) => {
            let _ = refuse(ws, shared, peer, seat.source(), &too_large_refusal()).await;
            close_with(ws, close::TOO_LARGE, "message too large").await;
            return Ok(Next::End);
        }
        Some(Err(e)) => return Err(std::io::Error::other(e)),
        Some(Ok(Message::Text(text))) => match seat.handle(text.as_str(), shared).await {
            Ok(answer) => {
                standing.bad_in_a_row = 0;
                if let Some(answer) = answer {
                    send(ws, Message::text(answer), shared.client_timeout).await?;
                }
                return Ok(Next::Go);
            }
            Err(refusal) => refusal,
        },
        Some(Ok(Message::Binary(_))) => guard::Refusal::new(
            ErrorCode::Binary,
            "binary messages are not accepted (send JSON text)",
        ),
        Some(Ok(Message::Close(_))) => {
            // Answer the close, so the client sees a clean 1000.
            let _ = ws.send(Message::Close(None)).await;
            return Ok(Next::End);
        }
        Some(Ok(Message::Pong(payload))) => {
            // Only an answer to a ping sent counts.
            if let Ok(number) = <[u8; 8]>::try_from(payload.as_ref()) {
                let number = u64::from_be_bytes(number);
                if number <= standing.pinged {
                    standing.answered = standing.answered.max(number);
                }
            }
            return Ok(Next::Go);
        }
        Some(Ok(_)) => return Ok(Next::Go),
    };
    // The stage failing or busy (or a relay's stage out of
    // reach) is not the client's mistake.
    if !matches!(refusal.code, ErrorCode::Failed | ErrorCode::Busy) {
        standing.bad_in_a_row += 1;
    }
    refuse(ws, shared, peer, seat.source(), &refusal).await?;
    if standing.bad_in_a_row >= MAX_BAD_MESSAGES {
        close_with(ws, close::POLICY, "too many bad messages").await;
        return Ok(Next::End);
    }
    Ok(Next::Go)
}

/// Serves one WebSocket client from its hello to its end. `place` holds
/// the client's place under its address's cap. The client is pinged every
/// `times.ping_every`; one that has not answered by the next ping has
/// stopped reading, and is closed. What a client's message does is
/// [`on_message`]'s.
async fn websocket(
    mut ws: Ws,
    shared: Arc<Shared>,
    peer: std::net::IpAddr,
    _place: edge::AddressPlace,
    times: EdgeTimes,
) -> std::io::Result<()> {
    let peer = peer.to_string();
    let client = shared.next_client.fetch_add(1, Ordering::Relaxed);
    let Some((asked, token)) = read_hello(&mut ws, &shared, &peer).await else {
        return Ok(());
    };
    let (seat, joined) = match Seat::join(&shared, client, asked, token).await {
        Ok(seated) => seated,
        Err(refused) => {
            let who = format!("client:{client}");
            let _ = refuse(&mut ws, &shared, &peer, &who, &refused.refusal).await;
            close_with(&mut ws, refused.close, &refused.reason).await;
            return Ok(());
        }
    };
    let role = joined.role;
    let mut inputs = shared.inputs.clone();
    inputs.mark_changed();
    let mut lineup = shared.lineup.clone();
    let mut following = Following::of(lineup.borrow_and_update().clone());
    let you = joined.you.clone();
    let stage_message = following.stage_message(client, role, you.clone());
    send(&mut ws, Message::text(stage_message), shared.client_timeout).await?;
    let mut changes = shared.changes.clone();
    let mut cursors = shared.cursors.clone();
    let mut take = shared.take.clone();
    let mut export = shared.export.clone();
    let mut people = shared.people.clone();
    let mut notice = shared.notice.clone();
    people.mark_changed();
    cursors.mark_changed();
    take.mark_changed();
    notice.mark_changed();
    let mut notices = true;
    let mut pings = tokio::time::interval_at(
        tokio::time::Instant::now() + times.ping_every,
        times.ping_every,
    );
    pings.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut standing = Standing::default();
    let result: std::io::Result<()> = async {
        loop {
            // Send what is newest before waiting again.
            let sending = std::time::Instant::now();
            following.send_changed(&mut ws, shared.client_timeout).await?;
            crate::stage_thread::Timings::add(&shared.timings.send_ns, sending);
            shared
                .timings
                .sends
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            for feed in [&mut inputs, &mut cursors, &mut take, &mut export, &mut people, &mut notice] {
                send_if_changed(&mut ws, feed, shared.client_timeout).await?;
            }
            tokio::select! {
                // `changed` marks the value seen: send it here.
                changed = export.changed() => {
                    if changed.is_ok() {
                        send_text(&mut ws, &mut export, shared.client_timeout).await?;
                    }
                }
                changed = people.changed() => {
                    if changed.is_ok() {
                        send_text(&mut ws, &mut people, shared.client_timeout).await?;
                    }
                }
                changed = inputs.changed() => {
                    if changed.is_ok() {
                        send_text(&mut ws, &mut inputs, shared.client_timeout).await?;
                    }
                }
                // A daemon's notices never change: its sender is gone.
                changed = notice.changed(), if notices => {
                    match changed {
                        Ok(()) => send_text(&mut ws, &mut notice, shared.client_timeout).await?,
                        Err(_) => notices = false,
                    }
                }
                // Puppets added, removed or reordered: a fresh "stage"
                // message, then everything of the new lineup.
                changed = lineup.changed() => {
                    if changed.is_ok() {
                        following = Following::of(lineup.borrow_and_update().clone());
                        let text = following.stage_message(client, role, you.clone());
                        send(&mut ws, Message::text(text), shared.client_timeout).await?;
                    }
                }
                _ = pings.tick() => {
                    if standing.answered < standing.pinged {
                        close_with(&mut ws, close::POLICY, "no answer to ping (not reading)").await;
                        return Ok(());
                    }
                    standing.pinged += 1;
                    let ping = Message::Ping(standing.pinged.to_be_bytes().to_vec().into());
                    send(&mut ws, ping, shared.client_timeout).await?;
                }
                changed = changes.changed() => {
                    if changed.is_err() {
                        // The stage thread stopped: the daemon is shutting down.
                        close_with(&mut ws, 1001, "the daemon is shutting down").await;
                        return Ok(());
                    }
                }
                incoming = ws.next() => {
                    let next = on_message(&mut ws, incoming, &shared, &seat, &peer, &mut standing).await?;
                    if next == Next::End {
                        return Ok(());
                    }
                }
            }
        }
    }
    .await;
    seat.leave(&shared, &joined).await;
    result
}

/// Sends a text feed's newest message if it changed since last sent;
/// an empty message is nothing to send.
async fn send_if_changed(ws: &mut Ws, feed: &mut State, timeout: Duration) -> std::io::Result<()> {
    if feed.has_changed().unwrap_or(false) {
        send_text(ws, feed, timeout).await?;
    }
    Ok(())
}

/// Sends a text feed's newest message (marking it seen); an empty one is
/// nothing to send.
async fn send_text(ws: &mut Ws, feed: &mut State, timeout: Duration) -> std::io::Result<()> {
    let text = feed.borrow_and_update().text.clone();
    if text.is_empty() {
        return Ok(());
    }
    send(ws, Message::text(text.to_string()), timeout).await
}

async fn send(ws: &mut Ws, message: Message, timeout: Duration) -> std::io::Result<()> {
    within(timeout, ws.send(message)).await
}

/// Queues a message without flushing: what one wake sends goes out in one
/// write ([`flush`] after the last).
async fn feed(ws: &mut Ws, message: Message, timeout: Duration) -> std::io::Result<()> {
    within(timeout, ws.feed(message)).await
}

async fn flush(ws: &mut Ws, timeout: Duration) -> std::io::Result<()> {
    within(timeout, ws.flush()).await
}

async fn within(
    timeout: Duration,
    sending: impl std::future::Future<Output = Result<(), axum::Error>>,
) -> std::io::Result<()> {
    match tokio::time::timeout(timeout, sending).await {
        Ok(result) => result.map_err(std::io::Error::other),
        Err(_) => Err(std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            "client stopped reading",
        )),
    }
}

/// Sends a request to the stage thread and waits for its answer.
async fn ask<T>(
    shared: &Shared,
    command: impl FnOnce(crate::stage_thread::Reply<T>) -> Command,
) -> Result<T, guard::Refusal> {
    use crate::protocol::ErrorCode;
    use puppetry_stage::CommandError as E;
    let (reply, answer) = tokio::sync::oneshot::channel();
    shared
        .links()?
        .commands
        .send(command(reply))
        .await
        .map_err(|_| "the stage is shutting down".to_string())?;
    answer
        .await
        .map_err(|_| "the stage is shutting down".to_string())?
        .map_err(|e| {
            let code = match &e {
                E::NoSuchPuppet { .. }
                | E::NoGrid { .. }
                | E::NoSkeleton { .. }
                | E::NoKeyFile { .. } => ErrorCode::NotFound,
                E::BadBrush | E::BadPadPoint { .. } | E::BadOrder { .. } => ErrorCode::OutOfRange,
                E::Busy { .. } => ErrorCode::Busy,
                _ => ErrorCode::Failed,
            };
            guard::Refusal::new(code, e.to_string())
        })
}

/// What a client message comes to: an answer for this client (or none),
/// or the problem to report back.
type Handled = Result<Option<String>, guard::Refusal>;

/// Acts on one text message of a connected client: parsed, checked (role,
/// ranges, contacts budget), then answered if it only reads, handed to the
/// stage as a `Change` if it is one (`crate::convert`), or acted on.
pub(crate) async fn handle_message(
    text: &str,
    who: &guard::Permissions,
    source: &str,
    shared: &Shared,
) -> Handled {
    use crate::protocol::ErrorCode;
    if text.len() > MAX_CLIENT_MESSAGE {
        return Err(too_large_refusal());
    }
    let message: ClientMessage = serde_json::from_str(text)
        .map_err(|e| guard::Refusal::new(ErrorCode::BadMessage, format!("bad message: {e}")))?;
    guard::allowed(who, &message)?;
    guard::check_ranges(&message)?;
    guard::check_contacts(&message)?;
    if let Some(answer) = read_only(&message, shared).await {
        return answer;
    }
    if let ClientMessage::Unpin { puppet, .. } = message {
        // The stage takes an unpin without a reply (it is input-rate, like
        // a pin): a puppet that is not on stage is refused here.
        on_stage(shared, puppet)?;
    }
    let now = shared.started.elapsed().as_secs_f64();
    match crate::convert::client(message, source, now) {
        Ok(Converted::Change {
            change,
            received,
            wait,
        }) => send_change(shared, source, change, received, wait).await,
        Ok(Converted::Other(message)) => act(shared, message).await,
        Err(e) => {
            let refusal = guard::Refusal::new(ErrorCode::BadMessage, e.problem);
            Err(match e.field {
                Some(field) => refusal.at(field),
                None => refusal,
            })
        }
    }
}

/// The answer to a message that only reads (any role may send these), or
/// `None` for any other.
async fn read_only(message: &ClientMessage, shared: &Shared) -> Option<Handled> {
    match *message {
        ClientMessage::Ping { t } => {
            let clock = shared.started.elapsed().as_secs_f64();
            Some(Ok(Some(ServerMessage::Pong { t, clock }.to_text())))
        }
        ClientMessage::ExportGrid { puppet } => Some(
            ask(shared, |reply| Command::ExportGrid { puppet, reply })
                .await
                .map(|g| {
                    Some(
                        ServerMessage::Grid {
                            puppet: g.puppet,
                            columns: g.columns,
                            rows: g.rows,
                            rest: g.rest,
                            grid: g.grid,
                        }
                        .to_text(),
                    )
                }),
        ),
        ClientMessage::ListTakes => Some(list_takes(shared).await.map(Some).map_err(Into::into)),
        _ => None,
    }
}

/// Hands a change to the stage thread: waiting for its answer when the
/// client is owed one (`wait`), else queued at input rate with the
/// source's held contacts counted against its budget first.
async fn send_change(
    shared: &Shared,
    source: &str,
    change: puppetry_stage::Change,
    received: Option<f64>,
    wait: bool,
) -> Handled {
    if wait {
        ask(shared, |reply| Command::Change {
            change,
            received,
            reply: Some(reply),
        })
        .await?;
        return Ok(None);
    }
    let links = shared.links()?;
    if let puppetry_stage::Change::Contacts { frame } = &change {
        links.held.take(source, &frame.contacts)?;
    }
    let command = Command::Change {
        change,
        received,
        reply: None,
    };
    links
        .commands
        .send(command)
        .await
        .map(|()| None)
        .map_err(|_| "the stage is shutting down".into())
}

/// Acts on a message that is neither a read nor a stage change: edits
/// with undo, files saved, takes, the line-up.
async fn act(shared: &Shared, message: ClientMessage) -> Handled {
    use crate::protocol::ErrorCode;
    match message {
        // A client's mistake, not something busy: it counts.
        ClientMessage::Hello { .. } => Err(guard::Refusal::new(
            ErrorCode::BadMessage,
            "already said hello: a connection says hello once",
        )),
        ClientMessage::Undo { puppet } => edit(shared, puppet, Edit::Undo).await,
        ClientMessage::Redo { puppet } => edit(shared, puppet, Edit::Redo).await,
        ClientMessage::Reset { puppet } => edit(shared, puppet, Edit::Reset).await,
        ClientMessage::Replay { source, playing } => {
            shared.links()?.replays.set(&source, playing)?;
            Ok(None)
        }
        ClientMessage::SaveWeights { puppet } => save_weights(shared, puppet).await,
        ClientMessage::SaveKeys { puppet } => save_keys(shared, puppet).await,
        ClientMessage::MidiLearn { target } => {
            shared
                .links()?
                .learning
                .wait_for(target)
                .map_err(|e| guard::Refusal::new(ErrorCode::BadRequest, e))?;
            Ok(None)
        }
        ClientMessage::ExportGrid { .. }
        | ClientMessage::ListTakes
        | ClientMessage::Ping { .. } => {
            unreachable!("answered above")
        }
        ClientMessage::Contacts { .. }
        | ClientMessage::Release { .. }
        | ClientMessage::Pin { .. }
        | ClientMessage::DepthFlip { .. }
        | ClientMessage::Unpin { .. }
        | ClientMessage::Paint { .. }
        | ClientMessage::PaintDepth { .. }
        | ClientMessage::Pose { .. }
        | ClientMessage::Cursor { .. }
        | ClientMessage::KeyAdd { .. }
        | ClientMessage::KeyMove { .. }
        | ClientMessage::KeyDelete { .. } => {
            unreachable!("changes are converted above (crate::convert)")
        }
        ClientMessage::Record { name } => {
            start_take(shared, name, Vec::new()).await?;
            Ok(None)
        }
        ClientMessage::StopRecording => {
            stop_take(shared).await?;
            Ok(None)
        }
        ClientMessage::Play {
            take,
            overdub,
            replace,
            replace_sources,
        } => {
            play_take(shared, &take, overdub, replace, replace_sources).await?;
            Ok(None)
        }
        ClientMessage::StopPlaying => stop_playing(shared).await,
        ClientMessage::AddCurve {
            name,
            points,
            width,
            colour,
        } => {
            let added = uploads::add_curve(shared, name, points, width, colour).await?;
            Ok(Some(added.to_text()))
        }
        ClientMessage::RemovePuppet { puppet } => remove_puppet(shared, puppet).await,
        ClientMessage::OrderPuppets { order } => {
            change_lineup(shared, LineupChange::Order(order)).await?;
            Ok(None)
        }
    }
}

/// `save_weights`: the stage hands over the puppet's weights; written off
/// the runtime as a new versioned file beside the mesh, unless the stage
/// file says to overwrite it (`WeightsFile::save`).
async fn save_weights(shared: &Shared, puppet: u32) -> Handled {
    let file = ask(shared, |reply| Command::SaveWeights { puppet, reply }).await?;
    let written = tokio::task::spawn_blocking(move || file.save());
    let path = written
        .await
        .map_err(|e| format!("save_weights: {e}"))?
        .map_err(|e| format!("save_weights: {e}"))?;
    Ok(Some(
        ServerMessage::WeightsSaved {
            puppet,
            file: path.display().to_string(),
        }
        .to_text(),
    ))
}

/// `save_keys`: the puppet's key poses written to its key file, off the
/// runtime.
async fn save_keys(shared: &Shared, puppet: u32) -> Handled {
    let (path, file) = ask(shared, |reply| Command::SaveKeys { puppet, reply }).await?;
    let target = path.clone();
    tokio::task::spawn_blocking(move || file.save(&target))
        .await
        .map_err(|e| format!("save_keys: {e}"))?
        .map_err(|e| format!("save_keys: {e}"))?;
    Ok(Some(
        ServerMessage::KeysSaved {
            puppet,
            file: path.display().to_string(),
        }
        .to_text(),
    ))
}

/// `remove_puppet`: off the stage, and its uploaded files forgotten so a
/// restart does not bring it back.
async fn remove_puppet(shared: &Shared, puppet: u32) -> Handled {
    let entry = shared
        .lineup
        .borrow()
        .config
        .puppets
        .get(puppet as usize)
        .cloned();
    change_lineup(shared, LineupChange::Remove(puppet)).await?;
    if let (Some(entry), Ok(links)) = (entry, shared.links()) {
        uploads::forget(&links.puppets_dir, &entry).await;
    }
    Ok(None)
}

/// `stop_playing`: the player stopped and joined off the runtime.
pub(crate) async fn stop_playing(shared: &Shared) -> Handled {
    let player = shared
        .links()?
        .player
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .take();
    match player {
        Some(player) => {
            player.stop();
            let _ = tokio::task::spawn_blocking(move || player.join()).await;
            Ok(None)
        }
        None => Err("no take is playing".into()),
    }
}

/// `puppet` is on stage now, or the refusal naming it.
fn on_stage(shared: &Shared, puppet: u32) -> Result<(), guard::Refusal> {
    let lineup = shared.lineup.borrow();
    let puppets = &lineup.description.puppets;
    if puppets.iter().any(|p| p.id == puppet) {
        return Ok(());
    }
    Err(guard::Refusal::new(
        crate::protocol::ErrorCode::NotFound,
        format!(
            "no puppet {puppet} on stage (there are {}: {})",
            puppets.len(),
            guard::clip(
                &puppets
                    .iter()
                    .map(|p| p.id.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                80
            )
        ),
    )
    .at("puppet"))
}

/// Adds, removes or reorders puppets; answers the puppet's id. Refused
/// while a take plays (its steps name puppets by id) or records.
async fn change_lineup(shared: &Shared, change: LineupChange) -> Result<u32, guard::Refusal> {
    let playing = shared
        .links()?
        .player
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .as_ref()
        .filter(|p| !p.is_finished())
        .map(|p| p.name.clone());
    if let Some(take) = playing {
        return Err(guard::Refusal::new(
            crate::protocol::ErrorCode::Busy,
            format!("take {take} is playing: stop it first"),
        ));
    }
    ask(shared, |reply| Command::Lineup { change, reply }).await
}

/// Undo, redo or reset a puppet's edits.
async fn edit(shared: &Shared, puppet: u32, edit: Edit) -> Result<Option<String>, guard::Refusal> {
    ask(shared, |reply| Command::Edit {
        puppet,
        edit,
        reply,
    })
    .await
    .map(|()| None)
}

async fn start_take(
    shared: &Shared,
    name: Option<String>,
    layers: Vec<String>,
) -> Result<String, String> {
    let (reply, answer) = tokio::sync::oneshot::channel();
    shared
        .links()?
        .commands
        .send(Command::StartTake {
            name,
            layers,
            reply,
        })
        .await
        .map_err(|_| "the stage is shutting down".to_string())?;
    answer
        .await
        .map_err(|_| "the stage is shutting down".to_string())?
}

async fn stop_take(shared: &Shared) -> Result<String, String> {
    let (reply, answer) = tokio::sync::oneshot::channel();
    shared
        .links()?
        .commands
        .send(Command::StopTake { reply })
        .await
        .map_err(|_| "the stage is shutting down".to_string())?;
    answer
        .await
        .map_err(|_| "the stage is shutting down".to_string())?
}

/// Plays a take; with `overdub`, records a new take of it and the live
/// hands, which stops when the played take ends. The take being recorded
/// is refused (`busy`).
pub(crate) async fn play_take(
    shared: &Shared,
    take: &str,
    overdub: bool,
    replace: Vec<crate::protocol::Region>,
    replace_sources: Vec<String>,
) -> Result<(), guard::Refusal> {
    let links = shared.links()?;
    let path = crate::takes::take_path(&links.takes_dir, take)?;
    // A take that is not there is `not_found`, named as the client named
    // it: the player's own error would name the daemon's folder.
    if !path.is_file() {
        return Err(guard::Refusal::new(
            crate::protocol::ErrorCode::NotFound,
            format!("no take {take:?} (list_takes names them)"),
        ));
    }
    let puppets = shared.lineup.borrow().take_puppets.len();
    for (i, r) in replace.iter().enumerate() {
        if r.puppet as usize >= puppets {
            return Err(format!(
                "replace[{i}].puppet: no puppet {} (the stage has {puppets})",
                r.puppet
            )
            .into());
        }
        if !(r.radius.is_finite() && r.radius > 0.0 && r.at.iter().all(|v| v.is_finite())) {
            return Err(
                format!("replace[{i}]: needs a finite `at` and a positive `radius`").into(),
            );
        }
    }
    {
        let mut slot = links.player.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(p) = slot.as_ref() {
            if !p.is_finished() {
                return Err(format!("take {} is already playing", p.name).into());
            }
            *slot = None;
        }
    }
    if overdub {
        start_take(shared, None, vec![take.to_string()]).await?;
    }
    let options = crate::takes::PlayOptions {
        fast: false,
        replace,
        replace_sources,
    };
    let puppets = shared.lineup.borrow().take_puppets.clone();
    let commands = links.commands.clone();
    let started = shared.started;
    let opened = tokio::task::spawn_blocking(move || {
        crate::takes::play(&path, &puppets, options, commands, started)
    })
    .await
    .map_err(|e| e.to_string())?;
    let started = match opened {
        Ok(mut player) => player.started().await.map(|()| player),
        Err(e) => Err(e),
    };
    let player = match started {
        Ok(player) => player,
        Err(e) => {
            if overdub {
                let _ = stop_take(shared).await;
            }
            let code = match e {
                crate::takes::PlayError::Recording(_) => crate::protocol::ErrorCode::Busy,
                _ => crate::protocol::ErrorCode::Failed,
            };
            return Err(guard::Refusal::new(code, e.to_string()));
        }
    };
    let mut slot = links.player.lock().unwrap_or_else(|p| p.into_inner());
    *slot = Some(player);
    Ok(())
}

/// The `takes` message: every take in the takes folder.
async fn list_takes(shared: &Shared) -> Result<String, String> {
    let dir = shared.links()?.takes_dir.clone();
    let listed = tokio::task::spawn_blocking(move || {
        if !dir.exists() {
            return Ok(Vec::new());
        }
        puppetry_take::list(&dir)
    })
    .await
    .map_err(|e| e.to_string())?
    .map_err(|e| e.to_string())?;
    // The take being recorded reads as unended: say what it is instead
    // (it cannot be played until it stops).
    let recording = match &shared.take.borrow().message {
        Some(ServerMessage::Take(take)) => take.recording.clone(),
        _ => None,
    };
    let takes = listed
        .into_iter()
        .filter_map(|t| match t {
            Ok(t) => Some(crate::protocol::TakeView {
                ending: if recording.as_deref() == Some(t.name.as_str()) {
                    "recording".to_string()
                } else {
                    t.ending
                },
                name: t.name,
                duration: t.duration,
                steps: t.steps,
                frames: t.frames,
                layers: t.layers,
            }),
            Err(e) => {
                tracing::warn!("{e}");
                None
            }
        })
        .collect();
    Ok(ServerMessage::Takes { takes }.to_text())
}
