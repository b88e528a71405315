//! What a connected client's messages must pass before they act: the role
//! check ([`allowed`]: one place, so a new message is one new arm), the
//! range check of coordinates ([`check_ranges`]), the contacts budget
//! ([`check_contacts`] per message, [`Held`] per client), and the shape of every
//! refusal ([`Refusal`], a typed `error` naming the field). Echoed input is
//! clipped ([`clip`]) so a stranger cannot make the daemon send or log
//! kilobytes, and client errors are logged through a per-source token
//! bucket ([`RateLog`]) so a flood of bad messages is a few lines and a
//! count.

use std::collections::{HashMap, HashSet};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::protocol::{ClientMessage, ErrorCode, Role, ServerMessage};

/// Largest coordinate accepted (stage, pad and region points).
pub const MAX_COORDINATE: f64 = 1e6;

/// Most characters of a client's input echoed back or logged.
pub use puppetry_limits::net::MAX_ECHO;

/// Why a message was refused: the `error` message sent back.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Refusal {
    pub code: ErrorCode,
    pub message: String,
    pub field: Option<String>,
}

impl Refusal {
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Refusal {
        Refusal {
            code,
            message: clip_quoted(&message.into()),
            field: None,
        }
    }

    /// The same refusal, naming the field at fault.
    pub fn at(mut self, field: impl Into<String>) -> Refusal {
        self.field = Some(clip(&field.into(), MAX_ECHO));
        self
    }

    /// The `error` message's text.
    pub fn to_text(&self) -> String {
        ServerMessage::Error {
            code: self.code,
            message: self.message.clone(),
            field: self.field.clone(),
        }
        .to_text()
    }
}

/// Failures reported as plain text (the stage thread's, a take's) are
/// `failed`, or `not_found`/`busy` when they say so.
impl From<String> for Refusal {
    fn from(message: String) -> Refusal {
        let code = if message.contains("no such") || message.contains("not found") {
            ErrorCode::NotFound
        } else if message.contains("already") {
            ErrorCode::Busy
        } else {
            ErrorCode::Failed
        };
        Refusal::new(code, message)
    }
}

impl From<&str> for Refusal {
    fn from(message: &str) -> Refusal {
        Refusal::from(message.to_string())
    }
}

/// `text` cut to `limit` characters, with "…" when cut (one clip for
/// every door: the input crate's).
pub use puppetry_input::log_limit::clip;

/// A message with every quoted part (between backticks or double quotes,
/// where serde and this daemon put echoed input) clipped to [`MAX_ECHO`]
/// characters, and the whole to a few times that.
pub fn clip_quoted(message: &str) -> String {
    let mut out = String::with_capacity(message.len().min(4 * MAX_ECHO));
    let mut rest = message;
    while let Some(open) = rest.find(['`', '"']) {
        let quote = rest[open..].chars().next().unwrap_or('"');
        out.push_str(&rest[..=open]);
        let inside = &rest[open + 1..];
        let close = inside.find(quote).unwrap_or(inside.len());
        out.push_str(&clip(&inside[..close], MAX_ECHO));
        rest = &inside[close..];
        if let Some(q) = rest.strip_prefix(quote) {
            out.push(quote);
            rest = q;
        }
    }
    out.push_str(rest);
    clip(&out, 3 * MAX_ECHO)
}

/// The message's `type` as it is spelled on the wire.
pub fn type_name(message: &ClientMessage) -> String {
    serde_json::to_value(message)
        .ok()
        .and_then(|v| v.get("type").and_then(|t| t.as_str()).map(String::from))
        .unwrap_or_else(|| "message".into())
}

/// Who a connected client is, as far as the checks go.
#[derive(Debug, Clone, PartialEq)]
pub struct Permissions {
    pub role: Role,
    /// The puppets a performer may play (ids); `None`: every puppet.
    pub puppets: Option<Vec<u32>>,
}

impl Permissions {
    fn may_play(&self, puppet: u32) -> bool {
        self.puppets.as_ref().is_none_or(|p| p.contains(&puppet))
    }
}

/// Whether `who` may send `message`: directors everything; performers
/// input on the puppets they may play; viewers only what reads.
pub fn allowed(who: &Permissions, message: &ClientMessage) -> Result<(), Refusal> {
    use ClientMessage as M;
    let forbidden = || {
        let role = match who.role {
            Role::Viewer => "viewers",
            Role::Performer => "performers",
            Role::Director => "directors",
        };
        Refusal::new(
            ErrorCode::Forbidden,
            format!("{}: not allowed for {role}", type_name(message)),
        )
    };
    // Read-only messages: anyone.
    if matches!(
        message,
        M::Hello { .. } | M::Ping { .. } | M::ListTakes | M::ExportGrid { .. }
    ) {
        return Ok(());
    }
    match who.role {
        Role::Director => Ok(()),
        Role::Viewer => Err(forbidden()),
        Role::Performer => match message {
            // Which puppet a contact or pin lands on is the stage's to say
            // (`Stage::limit_source`): one on another puppet grabs nothing.
            M::Contacts { .. } | M::Pin { .. } | M::DepthFlip { .. } => Ok(()),
            M::Unpin { puppet, .. }
            | M::Pose { puppet, .. }
            | M::Cursor { puppet, .. }
            | M::Undo { puppet }
            | M::Redo { puppet }
            | M::Reset { puppet } => {
                if who.may_play(*puppet) {
                    Ok(())
                } else {
                    Err(Refusal::new(
                        ErrorCode::Forbidden,
                        format!(
                            "{}: puppet {puppet} is not one this performer plays",
                            type_name(message)
                        ),
                    )
                    .at("puppet"))
                }
            }
            _ => Err(forbidden()),
        },
    }
}

/// A coordinate that must be finite and within [`MAX_COORDINATE`].
fn coordinate(field: impl FnOnce() -> String, value: f64) -> Result<(), Refusal> {
    if value.is_finite() && value.abs() <= MAX_COORDINATE {
        Ok(())
    } else {
        let field = field();
        Err(Refusal::new(
            ErrorCode::OutOfRange,
            format!("{field}: {value} is out of range (finite, at most 1e6 either way)"),
        )
        .at(field))
    }
}

/// Every coordinate of `message` finite and within range, else the first
/// that is not, named (`contacts[2].y`, `x`, `at[0]`).
pub fn check_ranges(message: &ClientMessage) -> Result<(), Refusal> {
    use ClientMessage as M;
    let pair = |name: &str, at: &[f64; 2]| -> Result<(), Refusal> {
        coordinate(|| format!("{name}[0]"), at[0])?;
        coordinate(|| format!("{name}[1]"), at[1])
    };
    match message {
        M::Contacts { contacts } => {
            for (i, c) in contacts.iter().enumerate() {
                if let Some(x) = c.x {
                    coordinate(|| format!("contacts[{i}].x"), x)?;
                }
                if let Some(y) = c.y {
                    coordinate(|| format!("contacts[{i}].y"), y)?;
                }
            }
            Ok(())
        }
        M::Pin { x, y }
        | M::DepthFlip { x, y }
        | M::Paint { x, y, .. }
        | M::PaintDepth { x, y, .. } => {
            coordinate(|| "x".into(), *x)?;
            coordinate(|| "y".into(), *y)
        }
        M::Cursor { at: Some(at), .. } | M::KeyAdd { at, .. } | M::KeyMove { at, .. } => {
            pair("at", at)
        }
        M::AddCurve { points, .. } => {
            for (i, p) in points.iter().enumerate() {
                pair(&format!("points[{i}]"), p)?;
            }
            Ok(())
        }
        M::Play { replace, .. } => {
            for (i, r) in replace.iter().enumerate() {
                pair(&format!("replace[{i}].at"), &r.at)?;
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// A `contacts` message within the budget: at most
/// [`MAX_CONTACTS_PER_MESSAGE`](puppetry_limits::contacts::MAX_CONTACTS_PER_MESSAGE)
/// contacts, each id once. Refused whole otherwise — a frame cut short
/// could lose an up, leaving a handle held for good.
pub fn check_contacts(message: &ClientMessage) -> Result<(), Refusal> {
    use puppetry_limits::contacts::MAX_CONTACTS_PER_MESSAGE;
    let ClientMessage::Contacts { contacts } = message else {
        return Ok(());
    };
    if contacts.len() > MAX_CONTACTS_PER_MESSAGE {
        return Err(Refusal::new(
            ErrorCode::TooMany,
            format!(
                "{} contacts in one message: at most {MAX_CONTACTS_PER_MESSAGE} (docs/limits.md)",
                contacts.len()
            ),
        )
        .at("contacts"));
    }
    let mut seen = HashSet::with_capacity(contacts.len());
    for (i, c) in contacts.iter().enumerate() {
        if !seen.insert(c.id) {
            return Err(Refusal::new(
                ErrorCode::BadMessage,
                format!("contact id {} is named twice in one message", c.id),
            )
            .at(format!("contacts[{i}].id")));
        }
    }
    Ok(())
}

/// The contacts each client holds down, as the door sees them: every id
/// whose last phase was down or move. The stage keeps its own count, but
/// the door must refuse a message before it reaches the stage thread, and
/// a client's messages pass here in order (a relayed client's too: the
/// daemon handles them one source at a time).
#[derive(Default)]
pub struct Held {
    /// Boxed: the stage's links are one variant of the edge's backend,
    /// and a relay's is small.
    by_source: Box<Mutex<HashMap<String, HashSet<u32>>>>,
}

impl Held {
    /// Takes `contacts` (a message already within [`check_contacts`]) as
    /// `source`'s next frame, or refuses it whole if `source` would hold
    /// more than
    /// [`MAX_HELD_PER_CLIENT`](puppetry_limits::contacts::MAX_HELD_PER_CLIENT)
    /// down after it. A refused message changes nothing.
    pub fn take(&self, source: &str, contacts: &[puppetry_input::Contact]) -> Result<(), Refusal> {
        use puppetry_input::Phase;
        use puppetry_limits::contacts::MAX_HELD_PER_CLIENT;
        let mut by_source = self.by_source.lock().unwrap_or_else(|p| p.into_inner());
        let held = by_source.get(source);
        let mut after: HashSet<u32> = held.cloned().unwrap_or_default();
        for c in contacts {
            match c.phase {
                Phase::Up => after.remove(&c.id),
                Phase::Down | Phase::Move => after.insert(c.id),
            };
        }
        if after.len() > MAX_HELD_PER_CLIENT {
            return Err(Refusal::new(
                ErrorCode::TooMany,
                format!(
                    "this would hold {} contacts down at once: at most {MAX_HELD_PER_CLIENT} \
                     per client (lift some first; docs/limits.md)",
                    after.len()
                ),
            )
            .at("contacts"));
        }
        if after.is_empty() {
            by_source.remove(source);
        } else {
            by_source.insert(source.to_string(), after);
        }
        Ok(())
    }

    /// `source` left: whatever it held is let go by the stage.
    pub fn forget(&self, source: &str) {
        self.by_source
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .remove(source);
    }
}

/// Per-source token buckets for log lines about clients' mistakes: a
/// source may log a burst of [`RateLog::BURST`] lines, then one per
/// [`RateLog::EVERY`]; what is held back is counted and said with the next
/// line that gets through.
#[derive(Default)]
pub struct RateLog {
    buckets: Mutex<HashMap<String, Bucket>>,
}

struct Bucket {
    tokens: f64,
    at: Instant,
    suppressed: u64,
}

impl RateLog {
    pub const BURST: f64 = 5.0;
    pub const EVERY: Duration = Duration::from_secs(1);
    /// Sources remembered at most; past it the quietest are forgotten.
    const SOURCES: usize = 4096;

    /// Logs `line()` for `source` at warn level if its bucket allows.
    pub fn warn(&self, source: &str, line: impl FnOnce() -> String) {
        match self.admit(source, Instant::now()) {
            Some(0) => tracing::warn!("{source}: {}", line()),
            Some(n) => tracing::warn!("{source}: {} ({n} more suppressed)", line()),
            None => {}
        }
    }

    /// Whether a line from `source` at `now` gets through: `Some(n)` with
    /// the lines suppressed since the last one, `None` to hold it back.
    pub fn admit(&self, source: &str, now: Instant) -> Option<u64> {
        let mut buckets = self.buckets.lock().unwrap_or_else(|p| p.into_inner());
        if buckets.len() >= Self::SOURCES && !buckets.contains_key(source) {
            buckets.retain(|_, b| b.suppressed > 0);
            if buckets.len() >= Self::SOURCES {
                buckets.clear();
            }
        }
        let bucket = buckets.entry(source.to_string()).or_insert(Bucket {
            tokens: Self::BURST,
            at: now,
            suppressed: 0,
        });
        let refill =
            now.saturating_duration_since(bucket.at).as_secs_f64() / Self::EVERY.as_secs_f64();
        bucket.tokens = (bucket.tokens + refill).min(Self::BURST);
        bucket.at = now;
        if bucket.tokens >= 1.0 {
            bucket.tokens -= 1.0;
            Some(std::mem::take(&mut bucket.suppressed))
        } else {
            bucket.suppressed += 1;
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::ClientContact;
    use puppetry_input::Phase;

    #[test]
    fn echoed_input_is_clipped() {
        let long = "x".repeat(3000);
        let serde = serde_json::from_str::<ClientMessage>(&format!(r#"{{"type":"{long}"}}"#))
            .unwrap_err()
            .to_string();
        assert!(serde.len() > 3000);
        let clipped = Refusal::new(ErrorCode::BadMessage, serde).message;
        assert!(clipped.chars().count() <= 3 * MAX_ECHO + 1, "{clipped}");
        assert!(
            clipped.contains(&format!("`{}…`", "x".repeat(MAX_ECHO - 1))),
            "{clipped}"
        );
        // The list of types after the echo survives.
        assert!(clipped.contains("expected one of"), "{clipped}");
        assert_eq!(clip("short", 200), "short");
        // At most the limit, the ellipsis included.
        assert_eq!(clip("ééé", 2), "é…");
    }

    #[test]
    fn roles_decide_what_passes() {
        let director = Permissions {
            role: Role::Director,
            puppets: None,
        };
        let performer = Permissions {
            role: Role::Performer,
            puppets: Some(vec![1]),
        };
        let viewer = Permissions {
            role: Role::Viewer,
            puppets: None,
        };
        let save = ClientMessage::SaveWeights { puppet: 1 };
        let record = ClientMessage::Record { name: None };
        let paint = ClientMessage::Paint {
            puppet: 1,
            x: 0.0,
            y: 0.0,
            radius: 1.0,
            strength: 1.0,
            stroke: None,
        };
        for m in [&save, &record, &paint] {
            assert!(allowed(&director, m).is_ok());
            let refused = allowed(&performer, m).unwrap_err();
            assert_eq!(refused.code, ErrorCode::Forbidden);
            assert!(refused.message.contains(&type_name(m)), "{refused:?}");
            assert!(allowed(&viewer, m).is_err());
        }
        let cursor = |puppet| ClientMessage::Cursor { puppet, at: None };
        assert!(allowed(&performer, &cursor(1)).is_ok());
        assert_eq!(
            allowed(&performer, &cursor(0))
                .unwrap_err()
                .field
                .as_deref(),
            Some("puppet")
        );
        assert!(allowed(&viewer, &ClientMessage::ListTakes).is_ok());
        assert!(allowed(&viewer, &ClientMessage::Ping { t: 1.0 }).is_ok());
        assert!(allowed(&viewer, &ClientMessage::Pin { x: 0.0, y: 0.0 }).is_err());
    }

    #[test]
    fn coordinates_out_of_range_name_the_field() {
        let contacts = ClientMessage::Contacts {
            contacts: (0..3)
                .map(|i| ClientContact {
                    id: i,
                    phase: Phase::Move,
                    x: Some(1.0),
                    y: Some(if i == 2 { 1e12 } else { 1e6 }),
                })
                .collect(),
        };
        let refused = check_ranges(&contacts).unwrap_err();
        assert_eq!(refused.code, ErrorCode::OutOfRange);
        assert_eq!(refused.field.as_deref(), Some("contacts[2].y"));
        let pin = ClientMessage::Pin {
            x: f64::NAN,
            y: 0.0,
        };
        assert_eq!(check_ranges(&pin).unwrap_err().field.as_deref(), Some("x"));
        let key = ClientMessage::KeyMove {
            puppet: 0,
            key: 0,
            at: [0.5, -2e6],
        };
        assert_eq!(
            check_ranges(&key).unwrap_err().field.as_deref(),
            Some("at[1]")
        );
        assert!(check_ranges(&ClientMessage::Pin { x: -1e6, y: 1e6 }).is_ok());
    }

    #[test]
    fn a_flood_of_lines_is_a_burst_then_one_a_second_with_a_count() {
        let log = RateLog::default();
        let t0 = Instant::now();
        let passed = (0..1000)
            .filter(|_| log.admit("1.2.3.4", t0).is_some())
            .count();
        assert_eq!(passed, RateLog::BURST as usize);
        // Another source has its own bucket.
        assert_eq!(log.admit("5.6.7.8", t0), Some(0));
        // A second later one line gets through, saying what was held back.
        assert_eq!(
            log.admit("1.2.3.4", t0 + RateLog::EVERY),
            Some(1000 - RateLog::BURST as u64)
        );
        assert_eq!(log.admit("1.2.3.4", t0 + RateLog::EVERY), None);
    }
}
