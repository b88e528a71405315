//! Show control over OSC/UDP (`docs/osc.md`), for the desks theatres and
//! VJs already run (TouchDesigner, Max, Resolume, QLab). Out: at the
//! configured rate, every `[osc].send` host gets the stage's state — each
//! puppet's handles, its key-pose blend and keyframing cursor, the take
//! state — read from the same watch channels the WebSocket clients read;
//! each tick sends only what changed, in bundles, with everything sent again
//! once a second so a desk that starts late (or lost a datagram) catches up.
//! In: triggers on `[osc].listen` — start/stop a take, blend to a key pose,
//! move a keyframing cursor, set a pose, reset a puppet — become the same
//! stage-thread commands the WebSocket's messages become. Nothing a
//! datagram holds can panic or flood the log: bad packets and failing
//! hosts are logged a few lines per window, naming the address and
//! argument at fault.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rosc::address::{Matcher, OscAddress};
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};

use puppetry_input::log_limit::LogLimiter;
use tokio::net::UdpSocket;
use tokio::task::{AbortHandle, JoinHandle};

use crate::config::OscConfig;
use crate::outputs::Published;
use crate::protocol::{HandleKind, ServerMessage, TakeState};
use crate::show_control::{Actor, Links, Trigger, TriggerError, clip, keys_of, lock, pose_of};
use crate::stage_thread::{PublishedHandles, ShowReading};

/// What goes wrong in show control; every variant names what it is about.
#[derive(Debug, thiserror::Error)]
pub enum OscError {
    #[error("cannot receive OSC on {address}: {source}")]
    Listen {
        address: SocketAddr,
        source: std::io::Error,
    },
    #[error("cannot open a socket to send OSC: {0}")]
    Socket(std::io::Error),
    #[error("OSC to {host}: {problem}")]
    Send { host: String, problem: String },
    #[error("not an OSC packet: {0}")]
    Decode(String),
    #[error("OSC bundles nested deeper than {MAX_BUNDLE_DEPTH}")]
    TooDeep,
    #[error("{address}: not an address of this stage (see docs/osc.md)")]
    UnknownAddress { address: String },
    #[error("{address}: {problem}")]
    BadPattern { address: String, problem: String },
    #[error("{address}: no puppet {puppet:?}")]
    NoPuppet { address: String, puppet: String },
    #[error("{address}: takes {expected}, got {got} argument(s)")]
    Arity {
        address: String,
        expected: &'static str,
        got: usize,
    },
    #[error("{address}: argument {index} ({name}): expected {expected}, got {got}")]
    Argument {
        address: String,
        index: usize,
        name: &'static str,
        expected: &'static str,
        got: String,
    },
    /// A trigger the stage could not do.
    #[error(transparent)]
    Trigger(#[from] TriggerError),
}

/// Bundles nested deeper than this are refused before decoding: a desk
/// nests one or two, and the decoder recurses once per level.
pub const MAX_BUNDLE_DEPTH: usize = 8;
/// Address patterns (`*`, `?`, `[…]`, `{…}`) longer than this are refused:
/// matching cost grows with them.
const MAX_PATTERN: usize = 256;
/// Bundles are cut to stay in one Ethernet frame (no IP fragmentation).
const MAX_DATAGRAM: usize = 1400;
/// Everything is sent again this often, changed or not.
const FULL_REFRESH: Duration = Duration::from_secs(1);
/// A `key` blend lasts at most this long.
const MAX_BLEND_SECONDS: f64 = 3600.0;
/// Coordinates a trigger may give (as the WebSocket accepts).
const MAX_COORDINATE: f64 = 1e6;

/// The log of one OSC door, as a device's: five lines at once, then one
/// every five seconds, the rest counted (a flood of bad datagrams, or a
/// host that is down, costs a bounded number of lines).
fn limiter() -> LogLimiter {
    LogLimiter::new(Instant::now())
}

/// The stage's OSC addresses: the prefix and each puppet's address part.
#[derive(Debug, Clone)]
pub struct AddressSpace {
    prefix: String,
    /// Per puppet, its part in addresses (its name made OSC-safe, or its
    /// index where the name would be ambiguous).
    parts: Vec<String>,
}

/// A puppet's name as an address part: characters OSC reserves (pattern
/// syntax, space, `/`, non-printable) become `_`.
fn address_part(name: &str) -> String {
    let part: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_graphic() && !"#*,/?[]{}".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    if part.is_empty() { "_".into() } else { part }
}

impl AddressSpace {
    pub fn new(prefix: &str, names: &[String]) -> AddressSpace {
        let mut parts: Vec<String> = Vec::with_capacity(names.len());
        for (i, name) in names.iter().enumerate() {
            let part = address_part(name);
            // A part that is a number would read as an index; one made
            // equal to another's by the replacement would be ambiguous.
            let ambiguous = part.parse::<u64>().is_ok() || parts.contains(&part);
            parts.push(if ambiguous { i.to_string() } else { part });
        }
        AddressSpace {
            prefix: prefix.to_string(),
            parts,
        }
    }

    /// Per puppet, its part in addresses.
    pub fn parts(&self) -> &[String] {
        &self.parts
    }

    /// `{prefix}/{rest}`.
    pub fn address(&self, rest: &str) -> String {
        format!("{}/{rest}", self.prefix)
    }

    /// `{prefix}/puppet/{part}/{leaf}`.
    pub fn puppet_address(&self, puppet: usize, leaf: &str) -> String {
        format!("{}/puppet/{}/{leaf}", self.prefix, self.parts[puppet])
    }

    /// The puppet an address part names: its part, else its index.
    fn puppet(&self, part: &str) -> Option<u32> {
        if let Some(i) = self.parts.iter().position(|p| p == part) {
            return Some(i as u32);
        }
        part.parse::<usize>()
            .ok()
            .filter(|&i| i < self.parts.len())
            .map(|i| i as u32)
    }

    /// Every address a trigger may be sent to (what patterns match).
    fn trigger_addresses(&self) -> Vec<String> {
        let mut all = vec![
            self.address("take/start"),
            self.address("take/stop"),
            self.address("take/play"),
            self.address("take/overdub"),
            self.address("clock"),
        ];
        for p in 0..self.parts.len() {
            for leaf in ["key", "pose", "cursor", "cursor/off", "reset"] {
                all.push(self.puppet_address(p, leaf));
            }
        }
        all
    }

    /// The triggers of one message: one, or for an address pattern
    /// (`/puppetry/puppet/*/reset`) one per address it matches.
    pub fn triggers(&self, message: &OscMessage) -> Result<Vec<Trigger>, OscError> {
        let address = &message.addr;
        if !address.contains(['*', '?', '[', '{']) {
            return self.trigger(address, &message.args).map(|t| vec![t]);
        }
        let bad = |problem: String| OscError::BadPattern {
            address: clip(address),
            problem,
        };
        if address.len() > MAX_PATTERN {
            return Err(bad(format!(
                "address patterns are limited to {MAX_PATTERN} bytes"
            )));
        }
        let matcher = Matcher::new(address).map_err(|e| bad(clip(&e.to_string())))?;
        let matched: Vec<String> = self
            .trigger_addresses()
            .into_iter()
            .filter(|a| OscAddress::new(a.clone()).is_ok_and(|a| matcher.match_address(&a)))
            .collect();
        if matched.is_empty() {
            return Err(OscError::UnknownAddress {
                address: clip(address),
            });
        }
        matched
            .iter()
            .map(|a| self.trigger(a, &message.args))
            .collect()
    }

    /// The trigger of a message to `address` (no pattern) with `args`.
    pub fn trigger(&self, address: &str, args: &[OscType]) -> Result<Trigger, OscError> {
        let unknown = || OscError::UnknownAddress {
            address: clip(address),
        };
        let rest = address
            .strip_prefix(self.prefix.as_str())
            .and_then(|r| r.strip_prefix('/'))
            .ok_or_else(unknown)?;
        let parts: Vec<&str> = rest.split('/').collect();
        let a = Args { address, args };
        match parts.as_slice() {
            ["take", "start"] => {
                a.at_most(1, "no argument or a take name")?;
                Ok(Trigger::StartTake {
                    name: a.optional_string(0, "name")?,
                })
            }
            ["take", "stop"] => {
                a.at_most(0, "no arguments")?;
                Ok(Trigger::StopTake)
            }
            ["take", verb @ ("play" | "overdub")] => {
                a.at_most(1, "no argument or a take name")?;
                Ok(Trigger::PlayTake {
                    take: a.optional_string(0, "name")?,
                    overdub: *verb == "overdub",
                })
            }
            ["clock"] => {
                a.between(
                    1,
                    2,
                    "the show's time in seconds, and 0 if its transport is stopped",
                )?;
                let seconds = a.number(0, "seconds")?;
                if seconds.abs() > puppetry_limits::files::MAX_TAKE_SECONDS {
                    return Err(a.bad(
                        0,
                        "seconds",
                        "seconds within a week (MAX_TAKE_SECONDS)",
                        &seconds.to_string(),
                    ));
                }
                let running = a.args.len() < 2 || a.number(1, "running")? != 0.0;
                Ok(Trigger::Clock(ShowReading {
                    seconds,
                    running,
                    source: puppetry_take::ClockSource::Osc,
                }))
            }
            ["puppet", part, leaf @ ..] => {
                let puppet = self.puppet(part).ok_or_else(|| OscError::NoPuppet {
                    address: clip(address),
                    puppet: clip(part),
                })?;
                match leaf {
                    ["key"] => {
                        a.between(1, 2, "a key pose name and optionally seconds")?;
                        let seconds = match a.args.len() {
                            2 => a.number(1, "seconds")?,
                            _ => 0.0,
                        };
                        if !(0.0..=MAX_BLEND_SECONDS).contains(&seconds) {
                            return Err(a.bad(
                                1,
                                "seconds",
                                "seconds from 0 to 3600",
                                &seconds.to_string(),
                            ));
                        }
                        Ok(Trigger::Key {
                            puppet,
                            name: a.string(0, "name")?,
                            seconds,
                        })
                    }
                    ["pose"] => {
                        a.between(3, 3, "from, to (key pose names) and t")?;
                        Ok(Trigger::Pose {
                            puppet,
                            from: a.string(0, "from")?,
                            to: a.string(1, "to")?,
                            t: a.number(2, "t")?,
                        })
                    }
                    ["cursor"] if a.args.is_empty() => Ok(Trigger::Cursor { puppet, at: None }),
                    ["cursor"] => {
                        a.between(2, 2, "x and y (pad coordinates), or nothing to let go")?;
                        Ok(Trigger::Cursor {
                            puppet,
                            at: Some([a.coordinate(0, "x")?, a.coordinate(1, "y")?]),
                        })
                    }
                    ["cursor", "off"] => {
                        a.at_most(0, "no arguments")?;
                        Ok(Trigger::Cursor { puppet, at: None })
                    }
                    ["reset"] => {
                        a.at_most(0, "no arguments")?;
                        Ok(Trigger::Reset { puppet })
                    }
                    _ => Err(unknown()),
                }
            }
            _ => Err(unknown()),
        }
    }
}

/// A message's arguments, read with errors naming the address and argument.
struct Args<'a> {
    address: &'a str,
    args: &'a [OscType],
}

/// An argument's type as OSC names it, for errors.
fn type_name(arg: &OscType) -> String {
    match arg {
        OscType::Int(_) => "an int (i)".into(),
        OscType::Float(_) => "a float (f)".into(),
        OscType::String(s) => format!("a string (s) {:?}", clip(s)),
        OscType::Blob(_) => "a blob (b)".into(),
        OscType::Time(_) => "a time tag (t)".into(),
        OscType::Long(_) => "an int64 (h)".into(),
        OscType::Double(_) => "a double (d)".into(),
        OscType::Char(_) => "a char (c)".into(),
        OscType::Color(_) => "a colour (r)".into(),
        OscType::Midi(_) => "a MIDI message (m)".into(),
        OscType::Bool(_) => "a boolean (T/F)".into(),
        OscType::Array(_) => "an array ([ ])".into(),
        OscType::Nil => "nil (N)".into(),
        OscType::Inf => "infinitum (I)".into(),
    }
}

impl Args<'_> {
    fn bad(&self, index: usize, name: &'static str, expected: &'static str, got: &str) -> OscError {
        OscError::Argument {
            address: clip(self.address),
            index,
            name,
            expected,
            got: got.to_string(),
        }
    }

    fn between(&self, min: usize, max: usize, expected: &'static str) -> Result<(), OscError> {
        if (min..=max).contains(&self.args.len()) {
            Ok(())
        } else {
            Err(OscError::Arity {
                address: clip(self.address),
                expected,
                got: self.args.len(),
            })
        }
    }

    fn at_most(&self, max: usize, expected: &'static str) -> Result<(), OscError> {
        self.between(0, max, expected)
    }

    /// A finite number: any of OSC's number types (desks differ in which
    /// they send).
    fn number(&self, index: usize, name: &'static str) -> Result<f64, OscError> {
        let value = match &self.args[index] {
            OscType::Int(v) => f64::from(*v),
            OscType::Float(v) => f64::from(*v),
            OscType::Double(v) => *v,
            OscType::Long(v) => *v as f64,
            other => return Err(self.bad(index, name, "a number", &type_name(other))),
        };
        if value.is_finite() {
            Ok(value)
        } else {
            Err(self.bad(index, name, "a finite number", &value.to_string()))
        }
    }

    fn coordinate(&self, index: usize, name: &'static str) -> Result<f64, OscError> {
        let value = self.number(index, name)?;
        if value.abs() <= MAX_COORDINATE {
            Ok(value)
        } else {
            Err(self.bad(index, name, "a number within ±1e6", &value.to_string()))
        }
    }

    fn string(&self, index: usize, name: &'static str) -> Result<String, OscError> {
        match &self.args[index] {
            OscType::String(s) if !s.is_empty() => Ok(s.clone()),
            other => Err(self.bad(index, name, "a non-empty string", &type_name(other))),
        }
    }

    fn optional_string(
        &self,
        index: usize,
        name: &'static str,
    ) -> Result<Option<String>, OscError> {
        match self.args.get(index) {
            None => Ok(None),
            Some(_) => self.string(index, name).map(Some),
        }
    }
}

/// How deeply bundles nest in a datagram, counted without decoding (and
/// without recursing past `limit`).
fn bundle_depth(bytes: &[u8], limit: usize) -> usize {
    const TAG: &[u8] = b"#bundle\0";
    if !bytes.starts_with(TAG) {
        return 0;
    }
    if limit == 0 {
        return 1;
    }
    // The tag, the 8-byte time tag, then (size, element) pairs.
    let mut at = 16;
    let mut deepest = 0;
    while let Some(size) = bytes.get(at..at + 4) {
        let size = u32::from_be_bytes([size[0], size[1], size[2], size[3]]) as usize;
        let start = at + 4;
        let Some(element) = bytes.get(start..start.saturating_add(size)) else {
            break;
        };
        deepest = deepest.max(bundle_depth(element, limit - 1));
        if deepest >= limit {
            break;
        }
        at = start + size;
    }
    1 + deepest
}

/// Decodes a datagram into its messages, bundles flattened in order
/// (triggers act on arrival; bundle time tags are not scheduled).
pub fn decode(datagram: &[u8]) -> Result<Vec<OscMessage>, OscError> {
    if bundle_depth(datagram, MAX_BUNDLE_DEPTH) > MAX_BUNDLE_DEPTH {
        return Err(OscError::TooDeep);
    }
    let (_, packet) =
        rosc::decoder::decode_udp(datagram).map_err(|e| OscError::Decode(clip(&e.to_string())))?;
    let mut messages = Vec::new();
    let mut pending = vec![packet];
    while let Some(packet) = pending.pop() {
        match packet {
            OscPacket::Message(m) => messages.push(m),
            // Reversed onto a stack: popped in the bundle's order.
            OscPacket::Bundle(b) => pending.extend(b.content.into_iter().rev()),
        }
    }
    Ok(messages)
}

/// Show control running: its tasks end when this is dropped or shut down.
pub struct Osc {
    /// Where triggers are received (the bound address, port 0 resolved).
    pub listen: Option<SocketAddr>,
    tasks: Vec<JoinHandle<()>>,
    blends: Arc<Mutex<Vec<Option<AbortHandle>>>>,
}

impl Osc {
    /// Stops receiving and sending, and any blend under way.
    pub fn stop(&self) {
        for task in &self.tasks {
            task.abort();
        }
        for blend in lock(&self.blends).iter_mut().filter_map(Option::take) {
            blend.abort();
        }
    }
}

impl Drop for Osc {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Starts show control for `config`: binds `listen` now (so a bad address
/// stops the start with its error) and sends to `send` from a task.
pub async fn start(config: &OscConfig, links: Links) -> Result<Osc, OscError> {
    let space = AddressSpace::new(&config.prefix, &links.names);
    let blends = Arc::new(Mutex::new(vec![None; links.puppets.len()]));
    let mut tasks = Vec::new();
    let mut listen = None;
    if let Some(address) = config.listen {
        let socket = UdpSocket::bind(address)
            .await
            .map_err(|source| OscError::Listen { address, source })?;
        listen = Some(
            socket
                .local_addr()
                .map_err(|source| OscError::Listen { address, source })?,
        );
        tracing::info!("OSC triggers on udp://{}", listen.expect("bound"));
        let log = Arc::new(Mutex::new(limiter()));
        let receiver = Receiver {
            space: space.clone(),
            actor: Actor {
                links: links.clone(),
                rate: config.rate,
                blends: blends.clone(),
                log: log.clone(),
            },
            log,
        };
        tasks.push(tokio::spawn(receiver.run(socket)));
    }
    if !config.send.is_empty() {
        let sender = Sender::new(space, links, &config.send).await?;
        tracing::info!("OSC state to {}", config.send.join(", "));
        tasks.push(tokio::spawn(sender.run(config.rate)));
    }
    Ok(Osc {
        listen,
        tasks,
        blends,
    })
}

/// The take state, from the published "take" message.
fn take_of(published: &Published) -> TakeState {
    match &published.message {
        Some(ServerMessage::Take(take)) => take.clone(),
        _ => TakeState::default(),
    }
}

/// Receives triggers and acts on them.
struct Receiver {
    space: AddressSpace,
    /// Does the triggers, as MIDI's does.
    actor: Actor,
    log: Arc<Mutex<LogLimiter>>,
}

impl Receiver {
    async fn run(self, socket: UdpSocket) {
        let mut buffer = vec![0u8; 65_536];
        loop {
            let (length, from) = match socket.recv_from(&mut buffer).await {
                Ok(received) => received,
                Err(e) => {
                    // ICMP errors of earlier sends land here on some
                    // systems: not fatal to the socket.
                    lock(&self.log).warn(format_args!("receive: {e}"));
                    continue;
                }
            };
            let messages = match decode(&buffer[..length]) {
                Ok(messages) => messages,
                Err(e) => {
                    lock(&self.log).warn(format_args!("from {from}: {e}"));
                    continue;
                }
            };
            for message in messages {
                let triggers = match self.space.triggers(&message) {
                    Ok(triggers) => triggers,
                    Err(e) => {
                        lock(&self.log).warn(format_args!("from {from}: {e}"));
                        continue;
                    }
                };
                for trigger in triggers {
                    if let Err(e) = self.actor.act(&message.addr, trigger).await {
                        lock(&self.log).warn(format_args!("from {from}: {e}"));
                    }
                }
            }
        }
    }
}

/// One `send` host: where it resolved to, and its own log window.
struct Host {
    name: String,
    address: Option<SocketAddr>,
    log: LogLimiter,
}

/// Sends the stage's state to the `send` hosts.
struct Sender {
    space: AddressSpace,
    links: Links,
    hosts: Vec<Host>,
    v4: Option<UdpSocket>,
    v6: Option<UdpSocket>,
    /// What each address was last sent with.
    sent: HashMap<String, Vec<OscType>>,
    /// Per puppet, the handle slots sent last time.
    slots: Vec<usize>,
    /// When the take being recorded started (daemon clock), from the
    /// newest take message.
    recording_since: Option<Instant>,
    take: TakeState,
    /// Host names being looked up, off the tick: a slow resolver never
    /// holds up the state to the other hosts.
    resolving: Option<JoinHandle<Vec<Resolved>>>,
}

/// A host's lookup: its index and address, or why not.
type Resolved = (usize, Result<SocketAddr, String>);

impl Sender {
    async fn new(space: AddressSpace, links: Links, send: &[String]) -> Result<Sender, OscError> {
        let hosts: Vec<Host> = send
            .iter()
            .map(|name| Host {
                name: name.clone(),
                // Literal addresses need no lookup.
                address: name.parse().ok(),
                log: limiter(),
            })
            .collect();
        let v4 = UdpSocket::bind("0.0.0.0:0")
            .await
            .map_err(OscError::Socket)?;
        // IPv6 may be off on the machine: only needed for v6 hosts.
        let v6 = UdpSocket::bind("[::]:0").await.ok();
        let puppets = links.puppets.len();
        Ok(Sender {
            space,
            links,
            hosts,
            v4: Some(v4),
            v6,
            sent: HashMap::new(),
            slots: vec![0; puppets],
            recording_since: None,
            take: TakeState::default(),
            resolving: None,
        })
    }

    async fn run(mut self, rate: f64) {
        let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut refreshed: Option<Instant> = None;
        loop {
            tick.tick().await;
            let now = Instant::now();
            let full = refreshed.is_none_or(|r| now.duration_since(r) >= FULL_REFRESH);
            if full {
                refreshed = Some(now);
                self.resolve();
            }
            if let Some(lookup) = self.resolving.take_if(|r| r.is_finished()) {
                for (i, result) in lookup.await.unwrap_or_default() {
                    let host = &mut self.hosts[i];
                    match result {
                        Ok(address) => host.address = Some(address),
                        Err(problem) => host.log.warn(OscError::Send {
                            host: host.name.clone(),
                            problem,
                        }),
                    }
                }
            }
            let state = self.state(now, full);
            let mut changed = Vec::new();
            for (addr, args) in state {
                if full || self.sent.get(&addr) != Some(&args) {
                    self.sent.insert(addr.clone(), args.clone());
                    changed.push(OscMessage { addr, args });
                }
            }
            if changed.is_empty() {
                continue;
            }
            for datagram in bundles(changed) {
                self.send_all(&datagram).await;
            }
        }
    }

    /// Starts looking up the hosts not resolved yet (unless a lookup is
    /// under way); a name that does not resolve is logged and looked up
    /// again at the next full refresh.
    fn resolve(&mut self) {
        let names: Vec<(usize, String)> = (self.hosts.iter().enumerate())
            .filter(|(_, h)| h.address.is_none())
            .map(|(i, h)| (i, h.name.clone()))
            .collect();
        if names.is_empty() || self.resolving.is_some() {
            return;
        }
        self.resolving = Some(tokio::spawn(async move {
            let mut resolved = Vec::new();
            for (i, name) in names {
                let found = match tokio::net::lookup_host(name.as_str()).await {
                    Ok(mut found) => found
                        .next()
                        .ok_or_else(|| "resolves to no address".to_string()),
                    Err(e) => Err(format!("cannot resolve: {e}")),
                };
                resolved.push((i, found));
            }
            resolved
        }));
    }

    /// Sends one datagram to every host; a failing host is logged (a few
    /// lines per window) and the others still get it.
    async fn send_all(&mut self, datagram: &[u8]) {
        for host in &mut self.hosts {
            let Some(address) = host.address else {
                continue;
            };
            let socket = if address.is_ipv4() {
                self.v4.as_ref()
            } else {
                self.v6.as_ref()
            };
            let result = match socket {
                Some(socket) => socket.send_to(datagram, address).await.map(drop),
                None => Err(std::io::Error::other("IPv6 is not available")),
            };
            if let Err(e) = result {
                let error = OscError::Send {
                    host: host.name.clone(),
                    problem: e.to_string(),
                };
                host.log.warn(error);
            }
        }
    }

    /// The whole state now as (address, arguments), in a stable order.
    fn state(&mut self, now: Instant, full: bool) -> Vec<(String, Vec<OscType>)> {
        let mut out = Vec::new();
        let s = |v: &str| OscType::String(v.to_string());
        let f = |v: f64| OscType::Float(v as f32);
        if full {
            let names = self.space.parts().iter().map(|p| s(p)).collect();
            out.push((self.space.address("puppets"), names));
        }
        for (i, link) in self.links.puppets.iter_mut().enumerate() {
            let handles = link.handles.borrow_and_update().clone();
            let positions = link
                .handle_frames
                .as_mut()
                .and_then(|w| handle_positions(w.borrow_and_update().as_deref()?, &handles));
            let count = handles.handles.len();
            out.push((
                self.space.puppet_address(i, "handles"),
                vec![OscType::Int(count as i32)],
            ));
            for (k, h) in handles.handles.iter().enumerate() {
                let at = positions.as_ref().map_or(h.at, |p| p[k]);
                let kind = match h.kind {
                    HandleKind::Contact => "contact",
                    HandleKind::Pin => "pin",
                    HandleKind::Key => "key",
                };
                out.push((
                    self.space.puppet_address(i, &format!("handle/{k}")),
                    vec![
                        OscType::Int(i32::try_from(h.id).unwrap_or(-1)),
                        s(&h.owner),
                        s(kind),
                        f(at[0]),
                        f(at[1]),
                    ],
                ));
            }
            // Slots emptied since the last tick say so once (id 0).
            for k in count..self.slots[i] {
                out.push((
                    self.space.puppet_address(i, &format!("handle/{k}")),
                    vec![OscType::Int(0), s(""), s(""), f(0.0), f(0.0)],
                ));
            }
            self.slots[i] = count;
            let (_, at) = keys_of(&link.keys.borrow_and_update());
            let cursor = match at {
                Some([x, y]) => vec![OscType::Int(1), f(x), f(y)],
                None => vec![OscType::Int(0), f(0.0), f(0.0)],
            };
            out.push((self.space.puppet_address(i, "cursor"), cursor));
            if let Some((from, to, t)) = pose_of(&link.pose.borrow_and_update()) {
                out.push((
                    self.space.puppet_address(i, "pose"),
                    vec![
                        s(from.as_deref().unwrap_or("")),
                        s(to.as_deref().unwrap_or("")),
                        f(t),
                    ],
                ));
            }
        }
        if self.links.take.has_changed().unwrap_or(false) || self.recording_since.is_none() {
            let take = take_of(&self.links.take.borrow_and_update());
            self.recording_since = Some(now - Duration::from_secs_f64(take.elapsed.max(0.0)));
            self.take = take;
        }
        let take = &self.take;
        let on = |v: &Option<String>| OscType::Int(i32::from(v.is_some()));
        out.push((
            self.space.address("take/recording"),
            vec![
                on(&take.recording),
                s(take.recording.as_deref().unwrap_or("")),
            ],
        ));
        let elapsed = match (&take.recording, self.recording_since) {
            (Some(_), Some(since)) => now.duration_since(since).as_secs_f64(),
            _ => 0.0,
        };
        // Tenths: a desk's clock needs no more, and fewer datagrams.
        out.push((
            self.space.address("take/elapsed"),
            vec![f((elapsed * 10.0).floor() / 10.0)],
        ));
        out.push((
            self.space.address("take/playing"),
            vec![on(&take.playing), s(take.playing.as_deref().unwrap_or(""))],
        ));
        out.push((
            self.space.address("take/error"),
            vec![s(&clip(take.error.as_deref().unwrap_or("")))],
        ));
        out
    }
}

/// Each handle's point from a handle frame (binary kind 3), if the frame
/// follows this handle set (the two watches are read one after the other,
/// so a set may be newer than the frame, or older, for a moment).
fn handle_positions(frame: &[u8], handles: &PublishedHandles) -> Option<Vec<[f64; 2]>> {
    let decoded = crate::protocol::decode_frame(frame).ok()?;
    (decoded.header.generation == handles.generation
        && decoded.points.len() == handles.handles.len())
    .then(|| decoded.points.iter().map(|p| [p.x, p.y]).collect())
}

/// Packs messages into as few bundles as fit a datagram each (a message
/// too big for one goes alone), encoded.
fn bundles(messages: Vec<OscMessage>) -> Vec<Vec<u8>> {
    // "#bundle\0" and the time tag.
    const HEADER: usize = 16;
    let mut out = Vec::new();
    let mut content: Vec<OscPacket> = Vec::new();
    let mut size = HEADER;
    let flush = |content: &mut Vec<OscPacket>, out: &mut Vec<Vec<u8>>| {
        if content.is_empty() {
            return;
        }
        let bundle = OscPacket::Bundle(OscBundle {
            timetag: OscTime::from((0, 1)),
            content: std::mem::take(content),
        });
        match rosc::encoder::encode(&bundle) {
            Ok(bytes) => out.push(bytes),
            Err(e) => tracing::error!("cannot encode a bundle: {e}"),
        }
    };
    for message in messages {
        let packet = OscPacket::Message(message);
        let length = match rosc::encoder::encode(&packet) {
            Ok(bytes) => bytes.len() + 4,
            Err(e) => {
                tracing::error!("cannot encode a message: {e}");
                continue;
            }
        };
        if size + length > MAX_DATAGRAM {
            flush(&mut content, &mut out);
            size = HEADER;
        }
        size += length;
        content.push(packet);
    }
    flush(&mut content, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn space() -> AddressSpace {
        AddressSpace::new(
            "/puppetry",
            &["gingerbread".into(), "big bad/wolf".into(), "7".into()],
        )
    }

    fn message(addr: &str, args: Vec<OscType>) -> OscMessage {
        OscMessage {
            addr: addr.into(),
            args,
        }
    }

    fn one(addr: &str, args: Vec<OscType>) -> Result<Trigger, OscError> {
        space().trigger(addr, &args)
    }

    fn s(v: &str) -> OscType {
        OscType::String(v.into())
    }

    #[test]
    fn puppets_are_named_by_an_osc_safe_part_or_their_index() {
        let space = space();
        assert_eq!(space.parts(), ["gingerbread", "big_bad_wolf", "2"]);
        assert_eq!(space.puppet("gingerbread"), Some(0));
        assert_eq!(space.puppet("big_bad_wolf"), Some(1));
        assert_eq!(space.puppet("1"), Some(1));
        assert_eq!(space.puppet("2"), Some(2));
        assert_eq!(space.puppet("3"), None);
        assert_eq!(space.puppet("wolf"), None);
        assert_eq!(
            space.puppet_address(1, "handle/0"),
            "/puppetry/puppet/big_bad_wolf/handle/0"
        );
    }

    #[test]
    fn every_trigger_parses_with_its_arguments() {
        let clock = |seconds, running| {
            Trigger::Clock(ShowReading {
                seconds,
                running,
                source: puppetry_take::ClockSource::Osc,
            })
        };
        assert_eq!(
            one("/puppetry/clock", vec![OscType::Double(3600.5)]).unwrap(),
            clock(3600.5, true)
        );
        assert_eq!(
            one(
                "/puppetry/clock",
                vec![OscType::Float(12.0), OscType::Int(0)]
            )
            .unwrap(),
            clock(12.0, false)
        );
        assert!(one("/puppetry/clock", vec![OscType::Double(1e12)]).is_err());
        assert!(one("/puppetry/clock", vec![s("noon")]).is_err());
        assert_eq!(
            one("/puppetry/take/play", vec![]).unwrap(),
            Trigger::PlayTake {
                take: None,
                overdub: false
            }
        );
        assert_eq!(
            one("/puppetry/take/overdub", vec![s("take-002")]).unwrap(),
            Trigger::PlayTake {
                take: Some("take-002".into()),
                overdub: true
            }
        );
        assert_eq!(
            one("/puppetry/take/start", vec![]).unwrap(),
            Trigger::StartTake { name: None }
        );
        assert_eq!(
            one("/puppetry/take/start", vec![s("scene-1")]).unwrap(),
            Trigger::StartTake {
                name: Some("scene-1".into())
            }
        );
        assert_eq!(
            one("/puppetry/take/stop", vec![]).unwrap(),
            Trigger::StopTake
        );
        assert_eq!(
            one("/puppetry/puppet/gingerbread/key", vec![s("cheer")]).unwrap(),
            Trigger::Key {
                puppet: 0,
                name: "cheer".into(),
                seconds: 0.0
            }
        );
        assert_eq!(
            one("/puppetry/puppet/1/key", vec![s("cheer"), OscType::Int(2)]).unwrap(),
            Trigger::Key {
                puppet: 1,
                name: "cheer".into(),
                seconds: 2.0
            }
        );
        assert_eq!(
            one(
                "/puppetry/puppet/gingerbread/pose",
                vec![s("rest"), s("cheer"), OscType::Double(0.25)]
            )
            .unwrap(),
            Trigger::Pose {
                puppet: 0,
                from: "rest".into(),
                to: "cheer".into(),
                t: 0.25
            }
        );
        assert_eq!(
            one(
                "/puppetry/puppet/gingerbread/cursor",
                vec![OscType::Float(0.5), OscType::Int(1)]
            )
            .unwrap(),
            Trigger::Cursor {
                puppet: 0,
                at: Some([0.5, 1.0])
            }
        );
        for off in [
            "/puppetry/puppet/gingerbread/cursor",
            "/puppetry/puppet/0/cursor/off",
        ] {
            assert_eq!(
                one(off, vec![]).unwrap(),
                Trigger::Cursor {
                    puppet: 0,
                    at: None
                }
            );
        }
        assert_eq!(
            one("/puppetry/puppet/big_bad_wolf/reset", vec![]).unwrap(),
            Trigger::Reset { puppet: 1 }
        );
    }

    #[test]
    fn bad_triggers_name_the_address_and_argument() {
        let cases: Vec<(&str, Vec<OscType>, &str)> = vec![
            (
                "/puppetry/take/begin",
                vec![],
                "/puppetry/take/begin: not an address",
            ),
            (
                "/other/take/start",
                vec![],
                "/other/take/start: not an address",
            ),
            ("/puppetry", vec![], "/puppetry: not an address"),
            (
                "/puppetry/take/start",
                vec![OscType::Int(3)],
                "/puppetry/take/start: argument 0 (name): expected a non-empty string, got an int (i)",
            ),
            (
                "/puppetry/take/stop",
                vec![s("now")],
                "/puppetry/take/stop: takes no arguments, got 1 argument(s)",
            ),
            (
                "/puppetry/puppet/wolf/reset",
                vec![],
                "/puppetry/puppet/wolf/reset: no puppet \"wolf\"",
            ),
            (
                "/puppetry/puppet/gingerbread/pose",
                vec![s("rest"), s("cheer"), s("half")],
                "argument 2 (t): expected a number, got a string (s) \"half\"",
            ),
            (
                "/puppetry/puppet/gingerbread/pose",
                vec![s("rest"), s("cheer"), OscType::Float(f32::NAN)],
                "argument 2 (t): expected a finite number",
            ),
            (
                "/puppetry/puppet/gingerbread/pose",
                vec![s("rest")],
                "takes from, to (key pose names) and t, got 1",
            ),
            (
                "/puppetry/puppet/gingerbread/cursor",
                vec![OscType::Float(0.5), OscType::Double(1e12)],
                "argument 1 (y): expected a number within ±1e6, got 1000000000000",
            ),
            (
                "/puppetry/puppet/gingerbread/key",
                vec![s("cheer"), OscType::Int(-1)],
                "argument 1 (seconds): expected seconds from 0 to 3600, got -1",
            ),
            (
                "/puppetry/puppet/gingerbread/key",
                vec![OscType::Blob(vec![1, 2])],
                "argument 0 (name): expected a non-empty string, got a blob (b)",
            ),
            (
                "/puppetry/puppet/gingerbread/wave",
                vec![],
                "/puppetry/puppet/gingerbread/wave: not an address",
            ),
        ];
        for (address, args, says) in cases {
            let error = one(address, args).expect_err(address).to_string();
            assert!(error.contains(says), "{address}: {error}");
        }
    }

    #[test]
    fn echoed_input_is_cut_short() {
        let long = format!("/puppetry/{}", "x".repeat(5000));
        let error = one(&long, vec![]).unwrap_err().to_string();
        assert!(error.chars().count() < 300, "{} chars", error.len());
        assert!(error.contains('…'));
        let error = one(
            "/puppetry/take/start",
            vec![OscType::Int(1), s(&"y".repeat(5000))],
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("no argument or a take name"), "{error}");
        assert!(error.len() < 300);
    }

    #[test]
    fn patterns_match_every_trigger_address_they_cover() {
        let all = space()
            .triggers(&message("/puppetry/puppet/*/reset", vec![]))
            .unwrap();
        assert_eq!(
            all,
            [0, 1, 2].map(|puppet| Trigger::Reset { puppet }).to_vec()
        );
        let some = space()
            .triggers(&message(
                "/puppetry/puppet/{gingerbread,7}/cursor/off",
                vec![],
            ))
            .unwrap();
        assert_eq!(some.len(), 1, "7 is not a part: the third puppet is 2");
        let error = space()
            .triggers(&message("/puppetry/puppet/*/dance", vec![]))
            .unwrap_err();
        assert!(matches!(error, OscError::UnknownAddress { .. }), "{error}");
        let error = space()
            .triggers(&message("/puppetry/[", vec![]))
            .unwrap_err();
        assert!(matches!(error, OscError::BadPattern { .. }), "{error}");
        let long = format!("/puppetry/{}*", "a".repeat(300));
        let error = space().triggers(&message(&long, vec![])).unwrap_err();
        assert!(error.to_string().contains("limited to 256"), "{error}");
    }

    fn encode(packet: &OscPacket) -> Vec<u8> {
        rosc::encoder::encode(packet).unwrap()
    }

    #[test]
    fn datagrams_decode_to_their_messages_in_order() {
        let inner = OscPacket::Bundle(OscBundle {
            timetag: OscTime::from((0, 1)),
            content: vec![
                OscPacket::Message(message("/b", vec![])),
                OscPacket::Message(message("/c", vec![])),
            ],
        });
        let outer = OscPacket::Bundle(OscBundle {
            timetag: OscTime::from((0, 1)),
            content: vec![OscPacket::Message(message("/a", vec![])), inner],
        });
        let addresses: Vec<String> = decode(&encode(&outer))
            .unwrap()
            .into_iter()
            .map(|m| m.addr)
            .collect();
        assert_eq!(addresses, ["/a", "/b", "/c"]);
        assert!(matches!(decode(b"garbage!"), Err(OscError::Decode(_))));
        assert!(matches!(decode(&[]), Err(OscError::Decode(_))));
    }

    #[test]
    fn deeply_nested_bundles_are_refused_before_decoding() {
        let mut packet = OscPacket::Message(message("/a", vec![]));
        for _ in 0..MAX_BUNDLE_DEPTH {
            packet = OscPacket::Bundle(OscBundle {
                timetag: OscTime::from((0, 1)),
                content: vec![packet],
            });
        }
        assert_eq!(decode(&encode(&packet)).unwrap().len(), 1);
        packet = OscPacket::Bundle(OscBundle {
            timetag: OscTime::from((0, 1)),
            content: vec![packet],
        });
        assert!(matches!(decode(&encode(&packet)), Err(OscError::TooDeep)));
        // Thousands of levels, as a hostile datagram nests them: refused
        // without the decoder's recursion.
        let mut deep = Vec::new();
        for level in 0..3000usize {
            deep.extend_from_slice(b"#bundle\0\0\0\0\0\0\0\0\x01");
            let rest = (3000 - level - 1) * 20 + 8;
            deep.extend_from_slice(&(rest as u32).to_be_bytes());
        }
        deep.extend_from_slice(b"/a\0\0,\0\0\0");
        assert!(matches!(decode(&deep), Err(OscError::TooDeep)));
    }

    #[test]
    fn bundles_stay_within_a_datagram() {
        let messages: Vec<OscMessage> = (0..200)
            .map(|k| {
                message(
                    &format!("/puppetry/puppet/gingerbread/handle/{k}"),
                    vec![
                        OscType::Int(k),
                        s("client:1"),
                        s("contact"),
                        OscType::Float(1.0),
                        OscType::Float(2.0),
                    ],
                )
            })
            .collect();
        let datagrams = bundles(messages.clone());
        assert!(datagrams.len() > 1);
        let mut back = Vec::new();
        for d in &datagrams {
            assert!(d.len() <= MAX_DATAGRAM, "{} bytes", d.len());
            back.extend(decode(d).unwrap());
        }
        assert_eq!(back, messages);
    }
}
