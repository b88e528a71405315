//! What the command may draw on standard error. Progress bars (redrawn with
//! carriage returns) and coloured log levels are for a person watching a
//! terminal; in a file, a pipe or a service's log they are noise, so they
//! are drawn only when stderr is a terminal, and colour not at all when
//! `NO_COLOR` is set (<https://no-color.org>).

use std::io::IsTerminal;

/// Whether stderr is a terminal (progress bars are drawn on it).
pub fn stderr_is_terminal() -> bool {
    std::io::stderr().is_terminal()
}

/// Whether log lines on stderr may carry colour codes.
pub fn colour_on_stderr() -> bool {
    stderr_is_terminal() && !no_colour(std::env::var_os("NO_COLOR").as_deref())
}

/// `NO_COLOR`'s rule: set to anything but the empty string turns colour off.
fn no_colour(value: Option<&std::ffi::OsStr>) -> bool {
    value.is_some_and(|v| !v.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_color_set_and_not_empty_turns_colour_off() {
        assert!(!no_colour(None));
        assert!(!no_colour(Some("".as_ref())));
        assert!(no_colour(Some("1".as_ref())));
    }
}
