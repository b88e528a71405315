//! The relay tier: a stage published over NATS, and `puppetry relay`
//! processes that serve it to viewers on any number of machines and
//! forward remote performers to the daemon. It owns the subjects, the
//! messages between a daemon and its relays, and cutting large messages
//! into parts under NATS's payload limit; `publish` is the daemon's
//! side, [`serve`] the relay's, [`nats`] connecting with credentials and
//! the nats-server configuration that binds each party to its subjects,
//! `proof` how a relayed performer's token is checked without crossing
//! NATS.
//!
//! Everything the daemon publishes is under `puppetry.<stage>.out`, each
//! puppet stream on a subject of its own (`out.p.<id>.frame`, …) carrying
//! exactly the bytes a direct client gets. A relay asks under
//! `puppetry.<stage>.in.<relay>` (its own name in the subject, so that
//! nats-server's permissions can hold each relay to its own subjects) and
//! is answered under `puppetry.<stage>.reply.<relay>` (its inbox). A relay
//! that starts, or comes back after NATS went away, asks `in.<relay>.sync`:
//! the daemon publishes its whole state again (the relay drops what it
//! already has), so state and live messages travel one ordered path. A
//! viewer who joins a relay late is served from the relay's memory at
//! once, as a direct newcomer is.

pub mod nats;
pub(crate) mod proof;
pub(crate) mod publish;
pub mod serve;

pub use serve::{RelayOptions, RelayRunning};

use std::time::Duration;

use async_nats::HeaderMap;
use bytes::Bytes;
use serde::{Deserialize, Serialize};

use crate::protocol::{Person, PuppetDescription, Role, StageSize};
use crate::stream::Admission;
use crate::stream::guard::Refusal;

/// Why the relay tier could not start: publishing from the daemon,
/// serving as a relay, or writing a nats-server configuration.
#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    /// The NATS client could not be set up for the server.
    #[error("NATS server {url}: {problem}")]
    Connect {
        /// The address as logs show it (the user, never the password).
        url: String,
        /// What the NATS client said.
        problem: String,
    },
    /// A NATS address does not parse, or names two users or an empty one.
    #[error("NATS address {url}: {problem}")]
    Address {
        /// The server address at fault, without credentials.
        url: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A stage name that is not one NATS subject token.
    #[error("stage name {0:?}: use letters, digits, - and _ (one NATS subject token)")]
    StageName(String),
    /// A relay name that is not one NATS subject token (or is the
    /// daemon's user, in a server configuration).
    #[error("relay name {0:?}: use letters, digits, - and _ (one NATS subject token)")]
    RelayName(String),
    /// A nats-server configuration cannot be written as asked (a
    /// password it cannot hold, a relay named twice, no random source).
    #[error("nats-server configuration: {0}")]
    ServerConfig(String),
    /// Subscribing to the stage's subjects failed.
    #[error("NATS subscription {subject}: {problem}")]
    Subscribe {
        /// The subject (a wildcard) subscribed to.
        subject: String,
        /// What the NATS client said.
        problem: String,
    },
    /// A relay cannot listen for its viewers.
    #[error(transparent)]
    Stream(#[from] crate::stream::StreamError),
}

/// Largest part of a message: NATS servers take 1 MiB payloads by default.
pub(crate) const PART: usize = 512 * 1024;
/// Largest message put together from parts.
pub(crate) const MAX_ASSEMBLED: usize = 64 * 1024 * 1024;
/// Header of a message in parts: `i/n`, counted from 1.
const PART_HEADER: &str = "Puppetry-Part";
/// How long a relay waits for the daemon's answer.
pub(crate) const ANSWER_WITHIN: Duration = Duration::from_secs(2);
/// How often a relay says which remote performers it still has, and the
/// daemon says it is live.
pub(crate) const ALIVE_EVERY: Duration = Duration::from_secs(1);
/// A relay silent this long has lost its performers: the daemon ends
/// their sessions (their handles let go).
pub(crate) const RELAY_GONE_AFTER: Duration = Duration::from_secs(5);
/// The daemon silent this long: a relay tells its viewers it lost the stage.
pub(crate) const STAGE_GONE_AFTER: Duration = Duration::from_secs(3);

/// The subjects of one stage.
#[derive(Debug, Clone)]
pub(crate) struct Subjects {
    prefix: String,
}

/// Whether `name` is one NATS subject token of letters, digits, `-`, `_`
/// (a stage's or a relay's name).
pub(crate) fn is_name(name: &str) -> bool {
    !name.is_empty() && name.chars().all(crate::config::is_name_char)
}

impl Subjects {
    pub fn new(stage: &str) -> Result<Subjects, RelayError> {
        if !is_name(stage) {
            return Err(RelayError::StageName(stage.to_string()));
        }
        Ok(Subjects {
            prefix: format!("puppetry.{stage}"),
        })
    }

    /// The stage's name.
    pub fn stage(&self) -> &str {
        self.prefix.strip_prefix("puppetry.").unwrap_or("")
    }

    /// Everything the daemon publishes.
    pub fn out_all(&self) -> String {
        format!("{}.out.>", self.prefix)
    }

    pub fn out(&self, name: &str) -> String {
        format!("{}.out.{name}", self.prefix)
    }

    pub fn puppet(&self, id: usize, stream: &str) -> String {
        format!("{}.out.p.{id}.{stream}", self.prefix)
    }

    pub fn stage_text(&self, name: &str) -> String {
        format!("{}.out.s.{name}", self.prefix)
    }

    /// What `relay` asks as `kind` on (`in.<relay>.<kind>`).
    pub fn ask(&self, relay: &str, kind: &str) -> String {
        format!("{}.in.{relay}.{kind}", self.prefix)
    }

    /// Every relay's `kind` (the daemon's subscription).
    pub fn asks(&self, kind: &str) -> String {
        format!("{}.in.*.{kind}", self.prefix)
    }

    /// Everything any relay asks.
    pub fn in_all(&self) -> String {
        format!("{}.in.>", self.prefix)
    }

    /// Everything `relay` may ask on.
    pub fn in_of(&self, relay: &str) -> String {
        format!("{}.in.{relay}.>", self.prefix)
    }

    /// Where `relay` is answered: its NATS inbox prefix (the client's
    /// replies go to `<inbox>.<id>.<n>`).
    pub fn inbox(&self, relay: &str) -> String {
        format!("{}.reply.{relay}", self.prefix)
    }

    /// Every relay's inbox.
    pub fn reply_all(&self) -> String {
        format!("{}.reply.>", self.prefix)
    }

    /// Whether `reply` is in `relay`'s inbox: the daemon answers nowhere
    /// else (a relay naming another's inbox, or an `out` subject, as its
    /// reply would have the daemon speak for it there).
    pub fn is_inbox_of(&self, relay: &str, reply: &str) -> bool {
        reply
            .strip_prefix(self.inbox(relay).as_str())
            .and_then(|rest| rest.strip_prefix('.'))
            .is_some_and(|rest| !rest.is_empty())
    }

    /// What a published subject names, past `…out.`.
    pub fn published<'a>(&self, subject: &'a str) -> Option<&'a str> {
        subject
            .strip_prefix(self.prefix.as_str())?
            .strip_prefix(".out.")
    }

    /// Who asked what on an asked subject: `(relay, kind)` of
    /// `…in.<relay>.<kind>`.
    pub fn asked<'a>(&self, subject: &'a str) -> Option<(&'a str, &'a str)> {
        let rest = subject
            .strip_prefix(self.prefix.as_str())?
            .strip_prefix(".in.")?;
        let (relay, kind) = rest.split_once('.')?;
        (is_name(relay) && !kind.contains('.')).then_some((relay, kind))
    }
}

/// The lineup as relays get it: the `stage` message's puppets, and who
/// may connect.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct LineupMessage {
    /// Which run of the daemon: a new one starts its revisions again.
    pub boot: u64,
    pub revision: u64,
    pub size: StageSize,
    pub puppets: Vec<PuppetDescription>,
    /// Puppet ids in use, removed ones included (outputs are by id).
    pub ids: usize,
    pub admission: Admission,
}

/// The daemon's heartbeat (`out.live`), every [`ALIVE_EVERY`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Heartbeat {
    pub boot: u64,
    pub revision: u64,
    /// The daemon's clock (seconds since it started: frames' `input_time`).
    pub clock: f64,
    /// False once, as the daemon stops.
    pub live: bool,
}

/// A relay's client said hello with a role or a token
/// (`in.<relay>.join`). The token itself never crosses NATS: the relay
/// proves it holds it ([`proof`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct JoinRequest {
    /// `relay:<relay>:<client>`: how the stage names the client.
    pub source: String,
    pub role: Role,
    /// For a hello with a token: the proof of it, on a nonce the daemon
    /// issued (`in.<relay>.challenge`).
    pub proof: Option<proof::Proof>,
}

/// The daemon's answer to `in.<relay>.challenge`: a nonce for one join.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Challenge {
    pub nonce: String,
}

/// The daemon's answer to a [`JoinRequest`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum JoinAnswer {
    Joined {
        role: Role,
        you: Person,
        puppets: Option<Vec<u32>>,
    },
    Refused {
        refusal: Refusal,
        close: u16,
        reason: String,
    },
}

/// One text message of a relay's client (`in.<relay>.msg`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct MessageRequest {
    pub source: String,
    /// The client joined with a role (a session the daemon keeps); else a
    /// viewer, checked as one.
    pub session: bool,
    pub text: String,
}

/// The daemon's answer to a [`MessageRequest`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum MessageAnswer {
    Answer(Option<String>),
    Refused(Refusal),
}

/// A relay's client with a session left (`in.<relay>.leave`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Leave {
    pub source: String,
}

/// A relay's sessions, every [`ALIVE_EVERY`] (`in.<relay>.alive`: the
/// subject says which relay).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Alive {
    pub sessions: Vec<String>,
}

/// A part of a puppet's picture (`in.<relay>.picture`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct PictureRequest {
    pub id: u32,
    pub offset: usize,
}

/// Header of a picture part: the picture's whole length.
const TOTAL_HEADER: &str = "Puppetry-Total";

/// `payload` as the messages that carry it: itself, or parts of at most
/// [`PART`] bytes with a part header (slices of it, not copies).
pub(crate) fn parts(payload: Bytes) -> Vec<(Option<HeaderMap>, Bytes)> {
    if payload.len() <= PART {
        return vec![(None, payload)];
    }
    let n = payload.len().div_ceil(PART);
    (0..n)
        .map(|i| {
            let mut headers = HeaderMap::new();
            headers.insert(PART_HEADER, format!("{}/{n}", i + 1).as_str());
            let end = ((i + 1) * PART).min(payload.len());
            (Some(headers), payload.slice(i * PART..end))
        })
        .collect()
}

/// Publishes `payload` on `subject`, in parts if it is large.
pub(crate) async fn publish(
    client: &async_nats::Client,
    subject: String,
    payload: Bytes,
) -> Result<(), async_nats::PublishError> {
    for (headers, part) in parts(payload) {
        match headers {
            None => client.publish(subject.clone(), part).await?,
            Some(h) => {
                client
                    .publish_with_headers(subject.clone(), h, part)
                    .await?
            }
        }
    }
    Ok(())
}

/// Puts messages in parts back together, per subject.
#[derive(Default)]
pub(crate) struct Assembler {
    pending: std::collections::HashMap<String, (usize, Vec<u8>)>,
}

#[derive(Debug, PartialEq, thiserror::Error)]
pub(crate) enum PartError {
    #[error("{subject}: part header {value:?} is not i/n")]
    Header { subject: String, value: String },
    #[error("{subject}: part {i} of {n} came without the ones before it")]
    Order { subject: String, i: usize, n: usize },
    #[error("{subject}: more than {MAX_ASSEMBLED} bytes in parts")]
    TooLarge { subject: String },
}

impl Assembler {
    /// The whole message once its last part is in (at once for a message
    /// not in parts); `None` while parts are missing.
    pub fn take(
        &mut self,
        subject: &str,
        headers: Option<&HeaderMap>,
        payload: Bytes,
    ) -> Result<Option<Bytes>, PartError> {
        let Some(value) = headers.and_then(|h| h.get(PART_HEADER)) else {
            self.pending.remove(subject);
            return Ok(Some(payload));
        };
        let value = value.as_str();
        let bad = || PartError::Header {
            subject: subject.to_string(),
            value: value.to_string(),
        };
        let (i, n) = value.split_once('/').ok_or_else(bad)?;
        let (i, n): (usize, usize) = (i.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?);
        if i == 0 || i > n {
            return Err(bad());
        }
        if n.saturating_mul(PART) > MAX_ASSEMBLED + PART {
            self.pending.remove(subject);
            return Err(PartError::TooLarge {
                subject: subject.to_string(),
            });
        }
        if i == 1 {
            self.pending
                .insert(subject.to_string(), (1, payload.to_vec()));
        } else {
            let Some((seen, bytes)) = self
                .pending
                .get_mut(subject)
                .filter(|(seen, _)| *seen + 1 == i)
            else {
                self.pending.remove(subject);
                return Err(PartError::Order {
                    subject: subject.to_string(),
                    i,
                    n,
                });
            };
            *seen = i;
            bytes.extend_from_slice(&payload);
            if bytes.len() > MAX_ASSEMBLED {
                self.pending.remove(subject);
                return Err(PartError::TooLarge {
                    subject: subject.to_string(),
                });
            }
        }
        if i < n {
            return Ok(None);
        }
        let (_, bytes) = self.pending.remove(subject).expect("the parts so far");
        Ok(Some(Bytes::from(bytes)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_message_goes_in_parts_and_comes_back_whole() {
        let payload: Bytes = (0..(2 * PART + 17)).map(|i| (i % 251) as u8).collect();
        let parts = parts(payload.clone());
        assert_eq!(parts.len(), 3);
        assert!(parts.iter().all(|(h, p)| h.is_some() && p.len() <= PART));
        let mut assembler = Assembler::default();
        let mut whole = None;
        for (k, (headers, part)) in parts.into_iter().enumerate() {
            let got = assembler.take("s", headers.as_ref(), part).unwrap();
            assert_eq!(got.is_some(), k == 2);
            whole = got.or(whole);
        }
        assert_eq!(whole.unwrap(), payload);
        let small = Bytes::from_static(b"small");
        assert_eq!(parts_of_one(&small), 1);
        assert_eq!(
            assembler.take("s", None, small.clone()).unwrap(),
            Some(small)
        );
    }

    fn parts_of_one(payload: &Bytes) -> usize {
        parts(payload.clone()).len()
    }

    #[test]
    fn parts_out_of_order_or_too_many_are_refused() {
        let payload: Bytes = vec![7u8; 3 * PART].into();
        let mut parts = parts(payload);
        let mut assembler = Assembler::default();
        let (h, p) = parts.remove(1);
        assert!(matches!(
            assembler.take("s", h.as_ref(), p),
            Err(PartError::Order { i: 2, n: 3, .. })
        ));
        let mut huge = HeaderMap::new();
        huge.insert(PART_HEADER, "1/100000");
        assert!(matches!(
            assembler.take("s", Some(&huge), Bytes::new()),
            Err(PartError::TooLarge { .. })
        ));
        let mut bad = HeaderMap::new();
        bad.insert(PART_HEADER, "3/2");
        assert!(matches!(
            assembler.take("s", Some(&bad), Bytes::new()),
            Err(PartError::Header { .. })
        ));
    }

    #[test]
    fn stage_names_are_one_subject_token() {
        assert!(Subjects::new("show-1_a").is_ok());
        for bad in ["", "a.b", "a b", "a>", "*"] {
            assert!(Subjects::new(bad).is_err(), "{bad:?}");
        }
        let s = Subjects::new("t").unwrap();
        assert_eq!(s.published("puppetry.t.out.p.3.frame"), Some("p.3.frame"));
        assert_eq!(s.published("puppetry.tt.out.lineup"), None);
        assert_eq!(s.asked("puppetry.t.in.hall.msg"), Some(("hall", "msg")));
        for bad in [
            "puppetry.t.in.msg",
            "puppetry.t.in.a.b.msg",
            "puppetry.t.in.*.msg",
            "puppetry.tt.in.a.msg",
        ] {
            assert_eq!(s.asked(bad), None, "{bad}");
        }
        assert!(s.is_inbox_of("hall", "puppetry.t.reply.hall.x1.3"));
        for bad in [
            "puppetry.t.reply.hall",
            "puppetry.t.reply.hall.",
            "puppetry.t.reply.hall2.x.1",
            "puppetry.t.reply.b.x.1",
            "puppetry.t.out.lineup",
        ] {
            assert!(!s.is_inbox_of("hall", bad), "{bad}");
        }
    }
}
