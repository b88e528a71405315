//! `puppetry export TAKE --format F -o OUT`: a take exported through
//! `puppetry_export::take`, with a progress bar on the terminal.

use std::io::Write;

use puppetry_export::Progress;

/// A progress bar on standard error.
pub struct Bar {
    what: String,
    shown: usize,
}

impl Bar {
    pub fn new(what: &str) -> Bar {
        Bar {
            what: what.to_string(),
            shown: usize::MAX,
        }
    }
}

impl Progress for Bar {
    fn step(&mut self, done: usize, total: usize) {
        let percent = (done * 100).checked_div(total).unwrap_or(100);
        if percent == self.shown {
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
