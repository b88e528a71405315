//! The fields of the line-based capture formats (evemu, hid-recorder):
//! hexadecimal codes, decimal values and `seconds.microseconds` times, each
//! parsed to a value or to the problem to report — the caller adds the file,
//! line and field. Quoted input is clipped so a garbage line cannot flood a
//! message; [`osc_arg`] quotes an OSC argument the same way for the network
//! decoders.

/// A line of a capture that does not parse, or breaks a rule of its
/// format (an axis described twice, a byte count that does not add up,
/// time going backwards, …).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}:{line}: {field}: {problem}")]
pub struct LineError {
    /// The capture, as messages name it.
    pub file: String,
    /// The line number, from 1; for hid-recorder bytes that fall short,
    /// the `R:` or `E:` line that declared them.
    pub line: usize,
    /// Which field of the line (`event type`, `length`, `time`, …).
    pub field: &'static str,
    /// What is wrong with it.
    pub problem: String,
}

/// A hexadecimal number (an optional `0x`) that fits `T`.
pub(crate) fn hex<T: TryFrom<u64>>(text: &str) -> Result<T, String> {
    let digits = text
        .strip_prefix("0x")
        .or_else(|| text.strip_prefix("0X"))
        .unwrap_or(text);
    u64::from_str_radix(digits, 16)
        .ok()
        .and_then(|v| T::try_from(v).ok())
        .ok_or_else(|| format!("`{}` is not a hexadecimal number in range", clip(text)))
}

/// A whole decimal number that fits `T`.
pub(crate) fn decimal<T: std::str::FromStr>(text: &str) -> Result<T, String> {
    text.parse::<T>()
        .map_err(|_| format!("`{}` is not a whole number in range", clip(text)))
}

/// `seconds.microseconds`, both plain digits. Parsed whole, so the value is
/// the decimal correctly rounded, same as a literal in a test.
pub(crate) fn time(text: &str) -> Result<f64, String> {
    let bad = || format!("`{}` is not `seconds.microseconds`", clip(text));
    let (seconds, micros) = text.split_once('.').ok_or_else(bad)?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !digits(seconds) || !digits(micros) || seconds.len() > 15 || micros.len() > 9 {
        return Err(bad());
    }
    text.parse().map_err(|_| bad())
}

/// A line-based capture parser, which names the file, line and field of
/// every problem: the field readers come with it, written once for evemu
/// and hid-recorder files.
pub(crate) trait Fields {
    type Error;

    /// The error for `field` of the line being read.
    fn field_error(&self, field: &'static str, problem: String) -> Self::Error;

    /// A hexadecimal field (see [`hex`]); a missing one is an error.
    fn hex<T: TryFrom<u64>>(
        &self,
        text: Option<&str>,
        field: &'static str,
    ) -> Result<T, Self::Error> {
        let text = text.ok_or_else(|| self.field_error(field, "missing".into()))?;
        hex(text).map_err(|problem| self.field_error(field, problem))
    }

    /// A decimal field (see [`decimal`]).
    fn decimal<T: std::str::FromStr>(
        &self,
        text: Option<&str>,
        field: &'static str,
    ) -> Result<T, Self::Error> {
        let text = text.ok_or_else(|| self.field_error(field, "missing".into()))?;
        decimal(text).map_err(|problem| self.field_error(field, problem))
    }

    /// The `time` field (see [`time`]).
    fn time(&self, text: Option<&str>) -> Result<f64, Self::Error> {
        let text = text.ok_or_else(|| self.field_error("time", "missing".into()))?;
        time(text).map_err(|problem| self.field_error("time", problem))
    }

    /// Nothing is left on the line.
    fn no_more<'t>(&self, mut rest: impl Iterator<Item = &'t str>) -> Result<(), Self::Error> {
        match rest.next() {
            Some(extra) => {
                Err(self.field_error("line", format!("unexpected `{}` at the end", clip(extra))))
            }
            None => Ok(()),
        }
    }
}

/// Keeps quoted input short in messages: a field's value, shorter than
/// the budget's `MAX_ECHO` since a message may quote several.
pub(crate) fn clip(text: &str) -> String {
    crate::log_limit::clip(text, 40)
}

/// An OSC argument as a message quotes it: its type tag and value, clipped.
/// Not rosc's `Display`, which panics on a time tag before 1970 (any
/// sender can put one in a packet).
pub(crate) fn osc_arg(arg: &rosc::OscType) -> String {
    match arg {
        rosc::OscType::Time(t) => format!("(t) {}.{}", t.seconds, t.fractional),
        rosc::OscType::Array(a) => format!("an array of {} arguments", a.content.len()),
        other => clip(&other.to_string()),
    }
}
