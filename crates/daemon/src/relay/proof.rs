//! A relayed performer's token checked by the daemon without the token
//! crossing NATS.
//!
//! Why this design. The daemon alone knows the stage's `[access]`; giving
//! every relay the list of tokens (so that relays check them) would put
//! every secret of the show on every edge machine, where a relay is the
//! part most exposed to the audience. So the daemon checks, and the relay
//! proves the token it was given instead of sending it: it asks the daemon
//! for a nonce (`in.<relay>.challenge`, random, for this relay, used once,
//! short-lived) and sends HMAC-SHA-256 keyed with the token over the
//! nonce, the stage, the client's source and the role asked
//! ([`prove`]). The daemon computes the same for every token it has, each
//! compared in constant time with none skipped ([`matching`]), and lets
//! the client in with the token that matched, as a direct hello with it.
//!
//! What it buys: a reader of the stage's subjects (which the NATS
//! permissions keep to the daemon) sees no token, and what it sees is
//! worth nothing later: a proof is bound to one nonce the daemon has
//! already spent, and to one source and role. A plain digest of the
//! token would instead be a second password, as good as the token to
//! whoever copied it. What it does not buy: a reader who has a nonce and
//! its proof can try guesses offline, so tokens must be long random
//! strings, not words, where NATS is shared. The relay itself sees the
//! token, as the edge the performer connects to must.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use ring::hmac;
use serde::{Deserialize, Serialize};

use crate::protocol::Role;

/// How long a nonce stays good: a relay asks for it right before the join.
pub const NONCE_LIFE: Duration = Duration::from_secs(10);
/// Nonces waiting at once for one relay; past it its oldest goes.
pub const NONCES_PER_RELAY: usize = 64;
/// Nonces waiting at once in all; past it the oldest goes.
pub const NONCES: usize = 4096;

/// A proof of a token, as a join carries it (hex).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Proof {
    pub nonce: String,
    pub mac: String,
}

/// What the MAC covers: everything the join asks, so a proof opens
/// nothing but this join.
fn covered(nonce: &str, stage: &str, source: &str, role: Role) -> Vec<u8> {
    let role = match role {
        Role::Viewer => "viewer",
        Role::Performer => "performer",
        Role::Director => "director",
    };
    ["puppetry relay join", nonce, stage, source, role]
        .join("\n")
        .into_bytes()
}

/// The relay's side: proves `token` for a join of `source` as `role`.
pub fn prove(token: &str, nonce: &str, stage: &str, source: &str, role: Role) -> Proof {
    let key = hmac::Key::new(hmac::HMAC_SHA256, token.as_bytes());
    let tag = hmac::sign(&key, &covered(nonce, stage, source, role));
    Proof {
        nonce: nonce.to_string(),
        mac: hex(tag.as_ref()),
    }
}

/// The daemon's side: the one of `tokens` that `proof` proves, if any.
/// Every token is tried, and each tag compared in constant time, so how
/// long it takes says nothing of which token (if any) matched.
pub fn matching<'a>(
    tokens: impl IntoIterator<Item = &'a str>,
    proof: &Proof,
    stage: &str,
    source: &str,
    role: Role,
) -> Option<&'a str> {
    let given = unhex(&proof.mac)?;
    let message = covered(&proof.nonce, stage, source, role);
    let mut found = None;
    for token in tokens {
        let key = hmac::Key::new(hmac::HMAC_SHA256, token.as_bytes());
        if hmac::verify(&key, &message, &given).is_ok() && found.is_none() {
            found = Some(token);
        }
    }
    found
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A SHA-256 tag's 32 bytes from hex; `None` for anything else.
fn unhex(text: &str) -> Option<Vec<u8>> {
    if text.len() != 64 || !text.is_ascii() {
        return None;
    }
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).ok())
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum NonceError {
    #[error("the system's random source failed")]
    Random,
}

/// The nonces the daemon issued and not yet spent, by relay.
#[derive(Default)]
pub struct Nonces {
    issued: Mutex<VecDeque<Issued>>,
}

struct Issued {
    nonce: String,
    relay: String,
    at: Instant,
}

impl Nonces {
    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<Issued>> {
        self.issued.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A fresh nonce for `relay`. A relay asking for many only pushes
    /// out its own older ones (and, past [`NONCES`] in all, the oldest).
    pub fn issue(&self, relay: &str) -> Result<String, NonceError> {
        let mut bytes = [0u8; 32];
        ring::rand::SecureRandom::fill(&ring::rand::SystemRandom::new(), &mut bytes)
            .map_err(|_| NonceError::Random)?;
        let nonce = hex(&bytes);
        let now = Instant::now();
        let mut issued = self.lock();
        issued.retain(|i| now.duration_since(i.at) < NONCE_LIFE);
        if issued.iter().filter(|i| i.relay == relay).count() >= NONCES_PER_RELAY
            && let Some(oldest) = issued.iter().position(|i| i.relay == relay)
        {
            issued.remove(oldest);
        }
        if issued.len() >= NONCES {
            issued.pop_front();
        }
        issued.push_back(Issued {
            nonce: nonce.clone(),
            relay: relay.to_string(),
            at: now,
        });
        Ok(nonce)
    }

    /// Spends `nonce` if it was issued to `relay` and is still good.
    pub fn redeem(&self, relay: &str, nonce: &str) -> bool {
        let now = Instant::now();
        let mut issued = self.lock();
        let Some(at) = issued
            .iter()
            .position(|i| i.nonce == nonce && i.relay == relay)
        else {
            return false;
        };
        let spent = issued.remove(at).expect("the position just found");
        now.duration_since(spent.at) < NONCE_LIFE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_proof_opens_its_own_token_and_join_only() {
        let tokens = ["boss", "secret"];
        let p = prove("secret", "n1", "t", "relay:a:1", Role::Performer);
        assert!(!p.mac.contains("secret"));
        let check = |p: &Proof, source, role| matching(tokens, p, "t", source, role);
        assert_eq!(check(&p, "relay:a:1", Role::Performer), Some("secret"));
        assert_eq!(check(&p, "relay:a:2", Role::Performer), None);
        assert_eq!(check(&p, "relay:a:1", Role::Director), None);
        assert_eq!(
            matching(tokens, &p, "u", "relay:a:1", Role::Performer),
            None
        );
        let wrong = prove("nope", "n1", "t", "relay:a:1", Role::Performer);
        assert_eq!(check(&wrong, "relay:a:1", Role::Performer), None);
        let other_nonce = Proof {
            nonce: "n2".into(),
            ..p.clone()
        };
        assert_eq!(check(&other_nonce, "relay:a:1", Role::Performer), None);
        for bad in ["", "zz", &"g".repeat(64), &"é".repeat(32)] {
            let bad = Proof {
                nonce: "n1".into(),
                mac: bad.to_string(),
            };
            assert_eq!(check(&bad, "relay:a:1", Role::Performer), None);
        }
    }

    #[test]
    fn a_nonce_is_spent_once_and_by_its_relay_only() {
        let nonces = Nonces::default();
        let n = nonces.issue("a").unwrap();
        assert_eq!(n.len(), 64);
        assert!(!nonces.redeem("b", &n), "another relay's nonce");
        assert!(nonces.redeem("a", &n));
        assert!(!nonces.redeem("a", &n), "spent");
        let first = nonces.issue("a").unwrap();
        let other = nonces.issue("b").unwrap();
        for _ in 0..NONCES_PER_RELAY {
            nonces.issue("a").unwrap();
        }
        assert!(!nonces.redeem("a", &first), "pushed out by its own relay");
        assert!(
            nonces.redeem("b", &other),
            "another relay's flood spares it"
        );
        assert!(nonces.lock().len() <= NONCES);
    }
}
