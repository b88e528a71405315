//! `puppetry export TAKE --format F -o OUT`: a take exported through
//! `puppetry_export::take`, with a progress bar when stderr is a terminal
//! (none in a file or a log: a bar is redrawn with carriage returns).
//! Its cost is checked first against the same limits the daemon's download
//! keeps (`puppetry_export::budget`): a take too long for its frame rate is
//! refused before a frame is read, and exported in ranges instead. The
//! output is written beside `-o` under a fresh name and renamed onto it.

use std::io::Write;
use std::path::{Path, PathBuf};

use puppetry_export::Progress;
use puppetry_export::budget::BudgetError;
use puppetry_export::take::{ExportRequest, TakeExportError, export_take};

/// Why `puppetry export` refused or failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportCommandError {
    /// The export would pass a limit, or the take cannot be read for its
    /// cost.
    #[error(transparent)]
    Budget(#[from] BudgetError),
    /// The export failed.
    #[error(transparent)]
    Export(#[from] TakeExportError),
    /// No `--config`, and the stage file the take's header names is not
    /// to be found.
    #[error(
        "{take} was recorded on the stage file {recorded:?}, which is not here (looked for {looked}); give it with --config"
    )]
    NoStageFile {
        /// The take's path, as given.
        take: String,
        /// The stage file its header names, as the daemon was given it.
        recorded: String,
        /// Every path tried, comma-separated.
        looked: String,
    },
}

/// The stage file a take was recorded on, for `export` without
/// `--config`: the file its header names (`stage_file`, as the daemon was
/// given it: relative to the folder the daemon ran in, which is usually
/// this one or the takes folder's parent), or, for a take of the bundled
/// demo (whose unpacked folder a newer build moves) or a downloaded take
/// (whose header keeps the file's name only), the bundled stage file of
/// that name. The export then checks the take against it, puppet by
/// puppet, as with `--config`.
pub fn recorded_stage_file(
    take: &Path,
    bundled_config: Option<&Path>,
) -> Result<PathBuf, ExportCommandError> {
    let header = puppetry_take::TakeReader::open(take)
        .map_err(|e| ExportCommandError::Export(e.into()))?
        .header;
    let recorded = Path::new(&header.stage_file);
    let takes = take.parent().unwrap_or(Path::new(""));
    let mut candidates = vec![recorded.to_path_buf()];
    if recorded.is_relative() {
        candidates.push(takes.join(recorded));
        if let Some(above) = takes.parent() {
            candidates.push(above.join(recorded));
        }
    }
    if let (Some(folder), Some(name)) = (bundled_config, recorded.file_name()) {
        candidates.push(folder.join(name));
    }
    candidates.dedup();
    match candidates.iter().find(|c| c.is_file()) {
        Some(found) => Ok(found.clone()),
        None => Err(ExportCommandError::NoStageFile {
            take: take.display().to_string(),
            recorded: header.stage_file.clone(),
            looked: candidates
                .iter()
                .map(|c| c.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        }),
    }
}

/// Runs `puppetry export`: what can be refused at once (the output, the
/// size), the budget, then the export; returns what was written, for the
/// user.
pub fn export(
    request: &ExportRequest,
    progress: &mut dyn Progress,
) -> Result<String, ExportCommandError> {
    puppetry_export::take::preflight(request)?;
    puppetry_export::budget::check(request)?;
    Ok(export_take(request, progress)?)
}

/// A progress bar on standard error, drawn only if it is a terminal.
pub struct Bar {
    what: String,
    shown: usize,
    draw: bool,
}

impl Bar {
    /// A bar labelled `what` (such as "export png"); whether it is drawn is
    /// decided here, once.
    pub fn new(what: &str) -> Bar {
        Bar {
            what: what.to_string(),
            shown: usize::MAX,
            draw: crate::terminal::stderr_is_terminal(),
        }
    }
}

/// A bar left mid-line (the export failed) is ended, so the error that
/// follows starts a line of its own ("(1/299)error: …" before).
impl Drop for Bar {
    fn drop(&mut self) {
        if self.draw && self.shown != usize::MAX && self.shown < 100 {
            eprintln!();
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
