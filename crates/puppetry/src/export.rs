//! `puppetry export TAKE --format F -o OUT`: a take exported through
//! `puppetry_export::take`, with a progress bar when stderr is a terminal
//! (none in a file or a log: a bar is redrawn with carriage returns).
//! Its cost is checked first against the same limits the daemon's download
//! keeps (`puppetry_export::budget`): a take too long for its frame rate is
//! refused before a frame is read, and exported in ranges instead. The
//! output is written beside `-o` under a fresh name and renamed onto it.

use std::io::Write;

use puppetry_export::Progress;
use puppetry_export::budget::BudgetError;
use puppetry_export::take::{ExportRequest, TakeExportError, export_take};

#[derive(Debug, thiserror::Error)]
pub enum ExportCommandError {
    #[error(transparent)]
    Budget(#[from] BudgetError),
    #[error(transparent)]
    Export(#[from] TakeExportError),
}

/// Runs `puppetry export`: the budget, then the export; returns what was
/// written, for the user.
pub fn export(
    request: &ExportRequest,
    progress: &mut dyn Progress,
) -> Result<String, ExportCommandError> {
    puppetry_export::budget::check(
        &request.take,
        request.format,
        request.fps,
        request.from,
        request.to,
    )?;
    Ok(export_take(request, progress)?)
}

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
