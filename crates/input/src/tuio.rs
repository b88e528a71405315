//! TUIO over UDP as an input source: OSC datagrams from touch tables and
//! tracking software in, calibrated [`ContactFrame`]s out. It owns the
//! decoding of TUIO 1.1 `/tuio/2Dcur` and TUIO 2.0 `/tuio2/frm`,
//! `/tuio2/ptr`, `/tuio2/alv` messages, the per-source session tracking in
//! [`TuioTracker`] (plain synchronous state, fed one datagram at a time), and
//! [`run_udp`], the only async part, which reads a socket into the daemon's
//! bounded channel.
//!
//! TUIO is state-based rather than event-based: every frame restates which
//! sessions are alive, so a lost datagram costs at most one frame of latency.
//! The tracker turns those snapshots into Down/Move/Up by diffing against
//! what it last saw. Other TUIO profiles (`2Dobj`, `2Dblb`, `tuio2/tok`, …)
//! are not contacts and are skipped without complaint.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::net::SocketAddr;

use glam::DVec2;
use rosc::{OscMessage, OscPacket, OscType};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;

use super::fields;
use super::log_limit::{LogLimiter, MAX_ECHO, clip, summary_timer};
use super::{Calibration, CalibrationError, Contact, ContactFrame, Phase, SourceId};

/// The port TUIO trackers send to unless told otherwise.
pub const DEFAULT_PORT: u16 = 3333;

/// A frame number this far below the last one is not a late datagram but a
/// tracker that restarted (or wrapped); the TUIO reference client uses the
/// same threshold.
const RESTART_GAP: i64 = 100;

/// Source names come off the network; the cap keeps a misbehaving sender
/// from growing the tracker's state without bound.
pub const MAX_SOURCES: usize = 64;

/// How long a TUIO source may be silent before what it holds is let go
/// and it is forgotten, unless the input says otherwise
/// (`release_after_s`). TUIO restates its alive set in every frame, and
/// trackers send frames while idle too (the reference server's periodic
/// messages, about one a second), so a second or two without one is a
/// sender that died mid-touch, not a finger held still.
pub const RELEASE_AFTER: std::time::Duration = std::time::Duration::from_secs(3);

/// Largest UDP payload; one buffer of this size serves every datagram.
const MAX_DATAGRAM: usize = 65_536;

/// Why a datagram was refused (leaving the tracker as it was), or why
/// reading the socket stopped.
#[derive(Debug, thiserror::Error)]
pub enum TuioError {
    /// The datagram is not OSC; the text is the OSC decoder's complaint.
    #[error("tuio: not an OSC packet: {0}")]
    Osc(String),
    /// A TUIO message is malformed or out of place: an argument missing or
    /// of the wrong type, a `ptr` outside a frame, an unknown 2Dcur command.
    #[error("tuio: message {index} ({address}): {problem}")]
    Message {
        /// Position of the message within the datagram, counting from 0
        /// through nested bundles in order.
        index: usize,
        /// The message's address, clipped.
        address: String,
        /// What is wrong, naming the argument.
        problem: String,
    },
    /// The datagram ends in the middle of a frame: 2Dcur messages without
    /// their `fseq`, or a `frm` without its `alv`.
    #[error("tuio: {problem}")]
    Bundle {
        /// Which frame is unfinished.
        problem: String,
    },
    /// The datagram names a new source when [`MAX_SOURCES`] are already
    /// tracked.
    #[error("tuio: already tracking {MAX_SOURCES} sources; refusing new source `{name}`")]
    TooManySources {
        /// The refused source, clipped.
        name: String,
    },
    /// Past the contacts budget (`puppetry_limits::contacts`): the whole
    /// datagram is skipped, never cut (a cut frame would lose a lift).
    #[error("tuio: {count} {what}: at most {limit} (docs/limits.md)")]
    TooManyContacts {
        /// Which count is over.
        what: &'static str,
        /// The count.
        count: usize,
        /// Its limit.
        limit: usize,
    },
    /// The calibration cannot be made: an empty range, say.
    #[error("tuio: {0}")]
    Calibration(#[from] CalibrationError),
    /// Receiving failed, for a reason other than a bounced earlier send.
    #[error("tuio: receiving from the socket: {0}")]
    Socket(#[source] std::io::Error),
}

/// What to do with TUIO's 0..1 × 0..1 (y down) when nothing else is said:
/// stretch it over a `size.x` × `size.y` stage with the origin at the lower
/// left, flipping y so the top of the surface is the top of the stage.
pub fn default_calibration(stage_size: DVec2) -> Result<Calibration, TuioError> {
    Ok(Calibration::fit([0.0, 1.0], [0.0, 1.0], stage_size)?)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Protocol {
    V1,
    V2,
}

/// One pointer as a frame states it, still in TUIO's normalised coordinates.
#[derive(Debug, Clone, PartialEq)]
struct Pointer {
    session: i32,
    position: DVec2,
    pressure: Option<f64>,
}

/// One complete TUIO frame (up to `fseq` or `alv`), decoded but not yet
/// applied, so a datagram that turns out malformed changes nothing.
#[derive(Debug, Clone, PartialEq)]
struct Snapshot {
    protocol: Protocol,
    source: Option<String>,
    /// `fseq` (1.1) or the `frm` frame id (2.0).
    sequence: i32,
    /// Sender's clock in seconds, when it gave one.
    time: Option<f64>,
    alive: Vec<i32>,
    pointers: Vec<Pointer>,
}

impl Snapshot {
    fn source_id(&self) -> SourceId {
        let prefix = match self.protocol {
            Protocol::V1 => "tuio",
            Protocol::V2 => "tuio2",
        };
        match &self.source {
            Some(name) => SourceId::from(format!("{prefix}:{name}")),
            None => SourceId::from(prefix),
        }
    }
}

#[derive(Debug, Clone)]
struct Tracked {
    position: DVec2,
    pressure: Option<f64>,
}

#[derive(Debug)]
struct SourceState {
    last_sequence: Option<i32>,
    /// By session id; ordered so frames list contacts deterministically.
    contacts: BTreeMap<i32, Tracked>,
    /// When its last frame arrived (the `now` of [`TuioTracker::push`]),
    /// late ones included: any frame says the sender is alive.
    heard: f64,
    /// The time its last frame carried, which the lift of a silent
    /// source's contacts carries too.
    time: f64,
}

impl SourceState {
    /// Whether a frame numbered `sequence` is news. UDP may reorder, and an
    /// older snapshot applied after a newer one would move contacts back or
    /// resurrect lifted ones.
    fn accept(&mut self, protocol: Protocol, sequence: i32) -> bool {
        // TUIO 1.1 reserves fseq -1 for redundant resends of the current
        // state; like the reference client, apply them without ordering.
        // Applying a restatement is idempotent, and it repairs state a lost
        // datagram left behind.
        if protocol == Protocol::V1 && sequence == -1 {
            return true;
        }
        if let Some(last) = self.last_sequence {
            let behind = i64::from(last) - i64::from(sequence);
            if behind > 0 && behind <= RESTART_GAP {
                return false;
            }
        }
        self.last_sequence = Some(sequence);
        true
    }
}

/// TUIO session tracking for every source that sends to one port. Feed it
/// datagrams with [`push`](TuioTracker::push); it answers with the frames
/// they complete. State is kept per TUIO source name, so several trackers
/// sharing a port never lift each other's contacts.
#[derive(Debug)]
pub struct TuioTracker {
    calibration: Calibration,
    sources: HashMap<SourceId, SourceState>,
}

impl TuioTracker {
    /// A tracker with no sources yet, mapping TUIO's normalised
    /// coordinates to the stage through `calibration`.
    pub fn new(calibration: Calibration) -> TuioTracker {
        TuioTracker {
            calibration,
            sources: HashMap::new(),
        }
    }

    /// Decodes one datagram and applies every frame it completes, returning
    /// one [`ContactFrame`] per frame that changed something (an idle tracker
    /// restates its state many times a second; those frames are not news).
    /// Frames that arrive late are dropped. `now` stands in for the frame's
    /// time when the sender gave none (a TUIO 1.1 bundle with an "immediate"
    /// time tag), so callers should pass a clock that only goes forward.
    ///
    /// A malformed datagram is an error and leaves the state untouched.
    pub fn push(&mut self, datagram: &[u8], now: f64) -> Result<Vec<ContactFrame>, TuioError> {
        let (_, packet) =
            rosc::decoder::decode_udp(datagram).map_err(|e| TuioError::Osc(e.to_string()))?;
        let snapshots = parse_packet(&packet)?;
        within_budget(&snapshots)?;
        let new_sources: HashSet<SourceId> = snapshots
            .iter()
            .map(Snapshot::source_id)
            .filter(|id| !self.sources.contains_key(id))
            .collect();
        if self.sources.len() + new_sources.len() > MAX_SOURCES
            && let Some(name) = new_sources.into_iter().min()
        {
            return Err(TuioError::TooManySources {
                name: fields::clip(name.as_str()),
            });
        }
        Ok(snapshots
            .into_iter()
            .filter_map(|snapshot| self.apply(snapshot, now))
            .collect())
    }

    fn apply(&mut self, snapshot: Snapshot, now: f64) -> Option<ContactFrame> {
        let source = snapshot.source_id();
        let state = self
            .sources
            .entry(source.clone())
            .or_insert_with(|| SourceState {
                last_sequence: None,
                contacts: BTreeMap::new(),
                heard: now,
                time: now,
            });
        state.heard = now;
        if !state.accept(snapshot.protocol, snapshot.sequence) {
            return None;
        }
        let alive: HashSet<i32> = snapshot.alive.iter().copied().collect();
        let mut contacts = Vec::new();
        // Lifts first: whatever is not restated as alive is gone, which is
        // also what clears a contact whose final frame was lost.
        state.contacts.retain(|&session, tracked| {
            let keep = alive.contains(&session);
            if !keep {
                let mut up = Contact::new(contact_id(session), Phase::Up, tracked.position);
                up.pressure = tracked.pressure;
                contacts.push(up);
            }
            keep
        });
        // A frame may state one session twice; the later statement wins, and
        // the contact still appears once.
        let mut stated = HashSet::new();
        let mut pointers: Vec<&Pointer> = snapshot
            .pointers
            .iter()
            .rev()
            .filter(|p| alive.contains(&p.session) && stated.insert(p.session))
            .collect();
        pointers.reverse();
        for pointer in pointers {
            let position = self.calibration.map(pointer.position);
            let phase = match state.contacts.get_mut(&pointer.session) {
                None => Phase::Down,
                Some(t) if t.position != position || t.pressure != pointer.pressure => Phase::Move,
                Some(_) => continue,
            };
            state.contacts.insert(
                pointer.session,
                Tracked {
                    position,
                    pressure: pointer.pressure,
                },
            );
            let mut contact = Contact::new(contact_id(pointer.session), phase, position);
            contact.pressure = pointer.pressure;
            contacts.push(contact);
        }
        state.time = snapshot.time.unwrap_or(now);
        if contacts.is_empty() {
            return None;
        }
        Some(ContactFrame {
            source,
            time: state.time,
            contacts,
        })
    }

    /// Forgets every source last heard more than `after` seconds before
    /// `now` (on [`push`](TuioTracker::push)'s clock): a sender that died
    /// mid-touch. Returns a frame lifting each such source's contacts, so
    /// nothing stays held by a sender that is gone; a source that comes
    /// back starts afresh (its contacts land again).
    pub fn expire(&mut self, now: f64, after: f64) -> Vec<ContactFrame> {
        let mut lifted = Vec::new();
        self.sources.retain(|source, state| {
            if now - state.heard <= after {
                return true;
            }
            if !state.contacts.is_empty() {
                lifted.push(lift(source, state));
            }
            false
        });
        // Deterministic: by source name, whatever the map's order.
        lifted.sort_by(|a, b| a.source.cmp(&b.source));
        lifted
    }

    /// A frame lifting every contact of every source, forgetting them all
    /// (the socket's loop ends, so nothing it said may stay held).
    pub fn lift_all(&mut self) -> Vec<ContactFrame> {
        self.expire(f64::INFINITY, f64::NEG_INFINITY)
    }

    /// Whether any source holds a contact.
    pub fn holds(&self) -> bool {
        self.sources.values().any(|s| !s.contacts.is_empty())
    }
}

/// A frame lifting every contact `state` holds, at its last frame's time.
fn lift(source: &SourceId, state: &SourceState) -> ContactFrame {
    let contacts = state
        .contacts
        .iter()
        .map(|(&session, tracked)| {
            let mut up = Contact::new(contact_id(session), Phase::Up, tracked.position);
            up.pressure = tracked.pressure;
            up
        })
        .collect();
    ContactFrame {
        source: source.clone(),
        time: state.time,
        contacts,
    }
}

/// A datagram's frames within the contacts budget: pointers and alive ids
/// over the whole datagram, and alive ids per frame (what its source holds).
/// Checked before any frame is applied, so a refused datagram changes
/// nothing.
fn within_budget(snapshots: &[Snapshot]) -> Result<(), TuioError> {
    use puppetry_limits::contacts::{MAX_TUIO_CONTACTS_PER_DATAGRAM, MAX_TUIO_HELD_PER_SOURCE};
    let stated: usize = snapshots
        .iter()
        .map(|s| s.pointers.len() + s.alive.len())
        .sum();
    if stated > MAX_TUIO_CONTACTS_PER_DATAGRAM {
        return Err(TuioError::TooManyContacts {
            what: "pointers and alive ids in one datagram",
            count: stated,
            limit: MAX_TUIO_CONTACTS_PER_DATAGRAM,
        });
    }
    for snapshot in snapshots {
        let alive: HashSet<i32> = snapshot.alive.iter().copied().collect();
        if alive.len() > MAX_TUIO_HELD_PER_SOURCE {
            return Err(TuioError::TooManyContacts {
                what: "contacts alive in one source's frame",
                count: alive.len(),
                limit: MAX_TUIO_HELD_PER_SOURCE,
            });
        }
    }
    Ok(())
}

/// TUIO session ids are OSC int32s; reinterpreting the bits keeps distinct
/// sessions distinct, even from senders that count past `i32::MAX`.
fn contact_id(session: i32) -> u32 {
    u32::from_ne_bytes(session.to_ne_bytes())
}

/// Seconds since the OSC epoch, or `None` for the "immediately" tag (which
/// carries no time at all).
fn osc_seconds(tag: rosc::OscTime) -> Option<f64> {
    if (tag.seconds, tag.fractional) == (0, 1) {
        return None;
    }
    Some(f64::from(tag.seconds) + f64::from(tag.fractional) / 4_294_967_296.0)
}

/// Every message of a packet in order, each with its enclosing bundle's time.
fn flatten<'a>(
    packet: &'a OscPacket,
    time: Option<f64>,
    out: &mut Vec<(Option<f64>, &'a OscMessage)>,
) {
    match packet {
        OscPacket::Message(message) => out.push((time, message)),
        OscPacket::Bundle(bundle) => {
            let time = osc_seconds(bundle.timetag);
            for inner in &bundle.content {
                flatten(inner, time, out);
            }
        }
    }
}

#[derive(Default)]
struct PendingV1 {
    source: Option<String>,
    alive: Option<Vec<i32>>,
    pointers: Vec<Pointer>,
}

struct PendingV2 {
    source: Option<String>,
    sequence: i32,
    time: Option<f64>,
    pointers: Vec<Pointer>,
}

fn parse_packet(packet: &OscPacket) -> Result<Vec<Snapshot>, TuioError> {
    let mut messages = Vec::new();
    flatten(packet, None, &mut messages);
    let mut snapshots = Vec::new();
    let mut v1: Option<PendingV1> = None;
    let mut v2: Option<PendingV2> = None;
    for (index, &(bundle_time, message)) in messages.iter().enumerate() {
        let args = Args { index, message };
        match message.addr.as_str() {
            "/tuio/2Dcur" => {
                let command = args.string(0, "command")?;
                let pending = v1.get_or_insert_with(PendingV1::default);
                match command {
                    "source" => pending.source = source_name(args.string(1, "source")?),
                    "alive" => pending.alive = Some(args.ints_from(1)?),
                    "set" => pending.pointers.push(Pointer {
                        session: args.int(1, "s_id")?,
                        position: DVec2::new(args.float(2, "x")?, args.float(3, "y")?),
                        pressure: None,
                    }),
                    "fseq" => {
                        let sequence = args.int(1, "fseq")?;
                        let pending = v1.take().unwrap_or_default();
                        let alive = pending.alive.ok_or_else(|| {
                            args.error("fseq ends a frame that has no alive message")
                        })?;
                        snapshots.push(Snapshot {
                            protocol: Protocol::V1,
                            source: pending.source,
                            sequence,
                            time: bundle_time,
                            alive,
                            pointers: pending.pointers,
                        });
                    }
                    other => {
                        return Err(
                            args.error(format!("unknown 2Dcur command `{}`", fields::clip(other)))
                        );
                    }
                }
            }
            "/tuio2/frm" => {
                if v2.is_some() {
                    return Err(args.error("frm before the previous frame's alv"));
                }
                v2 = Some(PendingV2 {
                    sequence: args.int(0, "f_id")?,
                    time: osc_seconds(args.time(1, "time")?),
                    // dim (argument 2) is the sensor's resolution; positions
                    // are already normalised, so it is not needed.
                    source: match message.args.get(3) {
                        Some(_) => source_name(args.string(3, "source")?),
                        None => None,
                    },
                    pointers: Vec::new(),
                });
            }
            "/tuio2/ptr" => {
                let pending = v2
                    .as_mut()
                    .ok_or_else(|| args.error("ptr outside a frame (no frm before it)"))?;
                // s_id tu_id c_id x y angle shear radius press …
                let pressure = match message.args.get(8) {
                    // Negative pressure means hovering; the stage only knows
                    // touching, so it reads as the lightest touch.
                    Some(_) => Some(args.float(8, "press")?.clamp(0.0, 1.0)),
                    None => None,
                };
                pending.pointers.push(Pointer {
                    session: args.int(0, "s_id")?,
                    position: DVec2::new(args.float(3, "x")?, args.float(4, "y")?),
                    pressure,
                });
            }
            "/tuio2/alv" => {
                let pending = v2
                    .take()
                    .ok_or_else(|| args.error("alv outside a frame (no frm before it)"))?;
                snapshots.push(Snapshot {
                    protocol: Protocol::V2,
                    source: pending.source,
                    sequence: pending.sequence,
                    time: pending.time,
                    alive: args.ints_from(0)?,
                    pointers: pending.pointers,
                });
            }
            _ => {}
        }
    }
    if v1.is_some() {
        return Err(TuioError::Bundle {
            problem: "2Dcur messages without the fseq that ends their frame".into(),
        });
    }
    if v2.is_some() {
        return Err(TuioError::Bundle {
            problem: "tuio2 frm without the alv that ends its frame".into(),
        });
    }
    Ok(snapshots)
}

/// An empty source name is as good as none.
fn source_name(name: &str) -> Option<String> {
    (!name.is_empty()).then(|| name.to_owned())
}

/// Typed access to one message's arguments, with errors that say where.
struct Args<'a> {
    index: usize,
    message: &'a OscMessage,
}

impl<'a> Args<'a> {
    fn error(&self, problem: impl Into<String>) -> TuioError {
        TuioError::Message {
            index: self.index,
            // Off the network, so any length: quoted short.
            address: fields::clip(&self.message.addr),
            problem: problem.into(),
        }
    }

    fn get(&self, at: usize, name: &str) -> Result<&'a OscType, TuioError> {
        self.message
            .args
            .get(at)
            .ok_or_else(|| self.error(format!("argument {at} ({name}) is missing")))
    }

    fn wrong(&self, at: usize, name: &str, expected: &str, got: &OscType) -> TuioError {
        self.error(format!(
            "argument {at} ({name}) should be {expected}, not {}",
            fields::osc_arg(got)
        ))
    }

    fn int(&self, at: usize, name: &str) -> Result<i32, TuioError> {
        match self.get(at, name)? {
            OscType::Int(v) => Ok(*v),
            other => Err(self.wrong(at, name, "an int32", other)),
        }
    }

    fn ints_from(&self, first: usize) -> Result<Vec<i32>, TuioError> {
        (first..self.message.args.len())
            .map(|at| self.int(at, "s_id"))
            .collect()
    }

    fn float(&self, at: usize, name: &str) -> Result<f64, TuioError> {
        let value = match self.get(at, name)? {
            OscType::Float(v) => f64::from(*v),
            OscType::Double(v) => *v,
            other => return Err(self.wrong(at, name, "a float", other)),
        };
        if !value.is_finite() {
            return Err(self.error(format!("argument {at} ({name}) is {value}")));
        }
        Ok(value)
    }

    fn string(&self, at: usize, name: &str) -> Result<&'a str, TuioError> {
        match self.get(at, name)? {
            OscType::String(v) => Ok(v),
            other => Err(self.wrong(at, name, "a string", other)),
        }
    }

    fn time(&self, at: usize, name: &str) -> Result<rosc::OscTime, TuioError> {
        match self.get(at, name)? {
            OscType::Time(v) => Ok(*v),
            other => Err(self.wrong(at, name, "a time tag", other)),
        }
    }
}

/// Reads TUIO datagrams from `socket` until `sink` closes, sending every
/// frame they complete. A full sink makes this wait (the socket's own buffer
/// absorbs the burst; TUIO's restated state repairs whatever the kernel then
/// drops), so no decoded frame is ever discarded here. Malformed datagrams
/// are skipped, and logged through a [`LogLimiter`]: a few lines, then a
/// count. Frames without a sender time are stamped with
/// seconds since this call started. A source silent for `release_after`
/// lets go of what it held ([`TuioTracker::expire`]), and so does every
/// source when receiving fails.
///
/// Returns `Ok` once the sink is closed, or the socket's error if receiving
/// fails for a reason other than a bounced earlier send.
pub async fn run_udp(
    socket: UdpSocket,
    calibration: Calibration,
    release_after: std::time::Duration,
    sink: mpsc::Sender<ContactFrame>,
) -> Result<(), TuioError> {
    let mut tracker = TuioTracker::new(calibration);
    let start = std::time::Instant::now();
    let mut buffer = vec![0u8; MAX_DATAGRAM];
    let mut complaints = LogLimiter::new(start);
    // Silence is looked for a few times within its timeout.
    let period = (release_after / 4).clamp(
        std::time::Duration::from_millis(10),
        std::time::Duration::from_millis(500),
    );
    let mut silence = tokio::time::interval(period);
    silence.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let received: std::io::Result<(usize, SocketAddr)> = tokio::select! {
            received = socket.recv_from(&mut buffer) => received,
            _ = silence.tick() => {
                let now = start.elapsed().as_secs_f64();
                for frame in tracker.expire(now, release_after.as_secs_f64()) {
                    let held = frame.contacts.len();
                    tracing::warn!(
                        "{}: silent for {release_after:?} holding {held} contacts: letting go",
                        frame.source
                    );
                    if sink.send(frame).await.is_err() {
                        return Ok(());
                    }
                }
                continue;
            }
            () = sink.closed() => {
                if let Some(skipped) = complaints.take_remaining() {
                    tracing::warn!("tuio: {skipped} more malformed datagrams were skipped unlogged");
                }
                return Ok(());
            }
            () = summary_timer(complaints.summary_due()) => {
                if let Some(skipped) = complaints.take_summary(std::time::Instant::now()) {
                    tracing::warn!("tuio: {skipped} more malformed datagrams were skipped unlogged");
                }
                continue;
            }
        };
        let (len, peer) = match received {
            Ok(received) => received,
            // An ICMP bounce from some earlier send (reported on some
            // platforms): says nothing about the datagrams still to come.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {
                tracing::warn!(error = %e, "tuio: ignoring a reset on the socket");
                continue;
            }
            Err(e) => {
                for frame in tracker.lift_all() {
                    let _ = sink.send(frame).await;
                }
                return Err(TuioError::Socket(e));
            }
        };
        let frames = match tracker.push(&buffer[..len], start.elapsed().as_secs_f64()) {
            Ok(frames) => frames,
            Err(e) => {
                // A flood of garbage gets a few lines and a count, not a
                // line per datagram.
                if complaints.allow(std::time::Instant::now()) {
                    let error = clip(&e.to_string(), MAX_ECHO);
                    tracing::warn!(%peer, %error, "tuio: skipping a malformed datagram");
                }
                continue;
            }
        };
        for frame in frames {
            if sink.send(frame).await.is_err() {
                return Ok(());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use puppetry_limits::contacts::{MAX_TUIO_CONTACTS_PER_DATAGRAM, MAX_TUIO_HELD_PER_SOURCE};

    /// A TUIO 1.1 frame with `fingers` pointers alive, as one datagram.
    fn frame(source: &str, fingers: i32, fseq: i32) -> Vec<u8> {
        let message = |args: Vec<OscType>| {
            OscPacket::Message(OscMessage {
                addr: "/tuio/2Dcur".into(),
                args,
            })
        };
        let mut content = vec![
            message(vec!["source".into(), source.into()]),
            message(
                std::iter::once(OscType::from("alive"))
                    .chain((0..fingers).map(OscType::Int))
                    .collect(),
            ),
        ];
        for s in 0..fingers {
            content.push(message(vec![
                "set".into(),
                OscType::Int(s),
                OscType::Float(0.5),
                OscType::Float(0.5),
                OscType::Float(0.0),
                OscType::Float(0.0),
                OscType::Float(0.0),
            ]));
        }
        content.push(message(vec!["fseq".into(), OscType::Int(fseq)]));
        let bundle = OscPacket::Bundle(rosc::OscBundle {
            timetag: rosc::OscTime {
                seconds: 0,
                fractional: 1,
            },
            content,
        });
        rosc::encoder::encode(&bundle).unwrap()
    }

    #[test]
    fn a_datagram_past_the_contacts_budget_is_refused_whole() {
        let calibration = default_calibration(DVec2::new(100.0, 100.0)).unwrap();
        let mut tracker = TuioTracker::new(calibration);
        // A table's worth is taken.
        let frames = tracker.push(&frame("table", 10, 1), 0.0).unwrap();
        assert_eq!(frames[0].contacts.len(), 10);
        // More alive in one source's frame than a source may hold.
        let fingers = MAX_TUIO_HELD_PER_SOURCE as i32 + 1;
        let error = tracker.push(&frame("table", fingers, 2), 0.1).unwrap_err();
        assert!(
            matches!(error, TuioError::TooManyContacts { count, .. } if count == fingers as usize),
            "{error}"
        );
        // More than a datagram may state, over two sources' frames.
        let half = MAX_TUIO_CONTACTS_PER_DATAGRAM as i32 / 4 + 1;
        let packets = [frame("a", half, 1), frame("b", half, 1)];
        let bundle = OscPacket::Bundle(rosc::OscBundle {
            timetag: rosc::OscTime {
                seconds: 0,
                fractional: 1,
            },
            content: packets
                .iter()
                .map(|p| rosc::decoder::decode_udp(p).unwrap().1)
                .collect(),
        });
        let error = tracker
            .push(&rosc::encoder::encode(&bundle).unwrap(), 0.2)
            .unwrap_err();
        assert!(
            matches!(error, TuioError::TooManyContacts { limit, .. } if limit == MAX_TUIO_CONTACTS_PER_DATAGRAM),
            "{error}"
        );
        // Nothing of the refused datagrams was applied: the ten are still
        // held, unmoved, and lift together.
        let frames = tracker.push(&frame("table", 0, 3), 0.3).unwrap();
        assert_eq!(frames[0].contacts.len(), 10);
        assert!(frames[0].contacts.iter().all(|c| c.phase == Phase::Up));
    }
}
