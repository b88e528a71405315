//! `puppetry export TAKE --format F -o OUT`: a take exported through
//! `puppetry_export::take`, with a progress bar when stderr is a terminal
//! (none in a file or a log: a bar is redrawn with carriage returns).

use std::io::Write;

use puppetry_export::Progress;

/// A progress bar on standard error, drawn only if it is a terminal.
pub struct Bar {
    what: String,
    shown: usize,
    draw: bool,
}

impl Bar {
    pub fn new(what: &str) -> Bar {
        Bar {
            what: what.to_string(),
            shown: usize::MAX,
            draw: crate::terminal::stderr_is_terminal(),
        }
    }
}

impl Progress for Bar {
    fn step(&mut self, done: usize, total: usize) {
        let percent = (done * 100).checked_div(total).unwrap_or(100);
        if !self.draw || percent == self.shown {
            return;
        }
        self.shown = percent;
        let filled = percent / 4;
        eprint!(
            "\r{} [{}{}] {percent:3}% ({done}/{total})",
            self.what,
            "#".repeat(filled),
            " ".repeat(25 - filled)
        );
        if done >= total {
            eprintln!();
        }
        let _ = std::io::stderr().flush();
    }
}
