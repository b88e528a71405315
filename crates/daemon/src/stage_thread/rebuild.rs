//! Rebuilding a free-form puppet's solver with painted weights on a
//! worker thread (seconds of factoring on a big mesh) while frames keep
//! coming from the old one; the worker hands the new solver back as a
//! command, which the stage thread swaps in between two solves.

use tokio::sync::mpsc;

use puppetry_deform::Arap;
use puppetry_stage::Rebuild;

use super::Command;

/// Builds a painted free-form puppet's solver on a thread of its own and
/// sends it back to the stage thread through `wake` (a weak sender, so the
/// worker never keeps a stopping stage thread alive).
pub(super) fn start_rebuild(rebuild: Rebuild, wake: &mpsc::WeakSender<Command>) {
    let wake = wake.clone();
    let started = std::thread::Builder::new()
        .name(format!("rebuild {}", rebuild.puppet))
        .spawn(move || {
            let arap = match Arap::register(&rebuild.mesh) {
                Ok(arap) => Some(Box::new(arap)),
                Err(e) => {
                    tracing::warn!(puppet = rebuild.puppet, "painted weights: {e}");
                    None
                }
            };
            if let Some(commands) = wake.upgrade() {
                let _ = commands.blocking_send(Command::Rebuilt {
                    puppet: rebuild.puppet,
                    generation: rebuild.generation,
                    arap,
                });
            }
        });
    if let Err(e) = started {
        tracing::warn!("cannot start a solver rebuild: {e}");
    }
}
