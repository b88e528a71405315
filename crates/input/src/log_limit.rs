//! Rate-limited warnings about bad input. A source that receives garbage
//! (a misconfigured tracker, a noisy serial line, a hostile sender) must not
//! turn each bad packet into a log line: thousands of lines a second bury
//! everything else and cost more than the packets. Each source keeps one
//! [`LogLimiter`], a token bucket: a burst of warnings gets through, then
//! one every few seconds; the rest are counted, and once a quiet spell has
//! passed one summary line says how many were left out (or, through
//! [`LogLimiter::warn`], the next line let through says it). It is the one
//! limiter of log lines: devices, OSC and the relays all use it. [`clip`]
//! keeps the input a message echoes short.

use std::time::{Duration, Instant};

/// Longest echoed input in a warning, in characters (an ellipsis marks the
/// cut): the budget's.
pub(crate) use puppetry_limits::net::MAX_ECHO;

/// Warnings let through at once before the limiter starts counting.
pub(crate) const BURST: u32 = 5;

/// One more warning is let through per this much time.
pub(crate) const REFILL: Duration = Duration::from_secs(5);

/// `text` cut to at most `max` characters, with "…" at the cut.
pub fn clip(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((cut, _)) => {
            let keep = text[..cut].char_indices().nth(max.saturating_sub(1));
            let cut = keep.map_or(cut, |(i, _)| i);
            format!("{}…", &text[..cut])
        }
        None => text.to_string(),
    }
}

/// A token bucket for one source's warnings. Plain state with the time
/// passed in, so it is tested without a clock.
#[derive(Debug, Clone)]
pub struct LogLimiter {
    burst: u32,
    refill: Duration,
    tokens: u32,
    /// When the next token is added (only meaningful below `burst`).
    next_token: Instant,
    /// Warnings left out since the last summary.
    suppressed: u64,
    /// When the first of those was left out.
    suppressed_since: Option<Instant>,
}

impl LogLimiter {
    /// The usual rate: `BURST` (5) warnings at once, then one per `REFILL`
    /// (5 s).
    pub fn new(now: Instant) -> LogLimiter {
        LogLimiter::with_rate(BURST, REFILL, now)
    }

    /// `burst` warnings at once, then one per `refill`; `now` starts the
    /// refill clock.
    pub fn with_rate(burst: u32, refill: Duration, now: Instant) -> LogLimiter {
        LogLimiter {
            burst,
            refill,
            tokens: burst,
            next_token: now + refill,
            suppressed: 0,
            suppressed_since: None,
        }
    }

    fn top_up(&mut self, now: Instant) {
        if self.tokens >= self.burst {
            self.next_token = now + self.refill;
            return;
        }
        while self.tokens < self.burst && now >= self.next_token {
            self.tokens += 1;
            self.next_token += self.refill;
        }
        if self.tokens >= self.burst {
            self.next_token = now + self.refill;
        }
    }

    /// Whether to log the warning at hand; if not, it is counted for the
    /// next summary.
    pub(crate) fn allow(&mut self, now: Instant) -> bool {
        self.top_up(now);
        if self.tokens > 0 {
            self.tokens -= 1;
            return true;
        }
        self.suppressed += 1;
        self.suppressed_since.get_or_insert(now);
        false
    }

    /// When a summary will be due, if warnings were left out.
    pub(crate) fn summary_due(&self) -> Option<Instant> {
        self.suppressed_since.map(|since| since + self.refill)
    }

    /// How many warnings were left out, once [`summary_due`] has passed
    /// (and then the count starts again); the caller logs the summary line.
    ///
    /// [`summary_due`]: LogLimiter::summary_due
    pub(crate) fn take_summary(&mut self, now: Instant) -> Option<u64> {
        let due = self.summary_due()?;
        if now < due {
            return None;
        }
        self.suppressed_since = None;
        Some(std::mem::take(&mut self.suppressed))
    }

    /// Logs `line` as a warning if the bucket lets it through, with how
    /// many were left out since the last line; otherwise counts it. For
    /// callers without a summary timer (OSC, the relays): what was left out
    /// is told with the next line let through.
    pub fn warn(&mut self, line: impl std::fmt::Display) {
        if !self.allow(Instant::now()) {
            return;
        }
        match self.take_remaining() {
            Some(held) => tracing::warn!("{line} (and {held} more not logged since the last line)"),
            None => tracing::warn!("{line}"),
        }
    }

    /// How many warnings were left out and not yet summarised, whatever the
    /// time: for a source that is ending.
    pub(crate) fn take_remaining(&mut self) -> Option<u64> {
        self.suppressed_since = None;
        let n = std::mem::take(&mut self.suppressed);
        (n > 0).then_some(n)
    }
}

/// Sleeps until `due`, or forever when there is nothing due: a `select!`
/// arm that fires when a summary is due.
pub(crate) async fn summary_timer(due: Option<Instant>) {
    match due {
        Some(due) => tokio::time::sleep_until(due.into()).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_burst_gets_through_then_one_per_refill_and_the_rest_are_counted() {
        let start = Instant::now();
        let mut limiter = LogLimiter::with_rate(3, Duration::from_secs(5), start);
        let allowed = (0..1000).filter(|_| limiter.allow(start)).count();
        assert_eq!(allowed, 3);
        assert_eq!(limiter.take_summary(start), None, "not due yet");
        let later = start + Duration::from_secs(5);
        assert_eq!(limiter.take_summary(later), Some(997));
        assert_eq!(limiter.take_summary(later), None, "summarised once");
        // One token came back in those five seconds.
        assert!(limiter.allow(later));
        assert!(!limiter.allow(later));
        // A long quiet refills the bucket, but no further than the burst.
        let much_later = later + Duration::from_secs(3600);
        let allowed = (0..10).filter(|_| limiter.allow(much_later)).count();
        assert_eq!(allowed, 3);
        assert_eq!(limiter.take_remaining(), Some(8));
        assert_eq!(limiter.take_remaining(), None);
    }

    #[test]
    fn clip_keeps_short_text_and_cuts_long_text_on_a_character() {
        assert_eq!(clip("short", 200), "short");
        let long = "é".repeat(3000);
        let clipped = clip(&long, 200);
        assert_eq!(clipped.chars().count(), 200);
        assert!(clipped.ends_with('…'));
        assert_eq!(clip("abcdef", 4), "abc…");
        assert_eq!(clip("abcd", 4), "abcd");
    }
}
