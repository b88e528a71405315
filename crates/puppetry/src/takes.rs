//! `puppetry takes DIR [--verify]`: the takes in a folder, and whether each
//! replays bit for bit into its stage.

use std::fmt::Write;
use std::path::Path;

use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;
use puppetry_take::replay::verify;
use puppetry_take::{Tail, TakeError};

/// Why `puppetry takes` could not list or check at all; a take that is
/// unreadable or fails to replay is reported in the listing instead.
#[derive(Debug, thiserror::Error)]
pub enum TakesError {
    /// The folder could not be read.
    #[error(transparent)]
    Take(#[from] TakeError),
    /// The stage file to verify against could not be loaded.
    #[error(transparent)]
    Config(#[from] puppetry_stage::config::ConfigError),
    /// The stage file loaded but its stage could not be built (a puppet
    /// could not be loaded, rigged or placed).
    #[error(transparent)]
    Stage(#[from] puppetry_stage::StageError),
}

/// The listing (and, with a stage file, the replay check of each take);
/// the flag is false when a take failed to replay exactly.
pub fn takes_command(dir: &Path, verify_with: Option<&Path>) -> Result<(String, bool), TakesError> {
    let config = verify_with.map(StageConfig::load).transpose()?;
    let mut out = String::new();
    let mut ok = true;
    let takes = puppetry_take::list(dir)?;
    if takes.is_empty() {
        let _ = writeln!(out, "no takes in {}", dir.display());
    }
    for take in takes {
        let take = match take {
            Ok(t) => t,
            Err(e) => {
                ok = false;
                let _ = writeln!(out, "{e}");
                continue;
            }
        };
        let _ = writeln!(
            out,
            "{}  {:.2} s  {} steps  {} frames  {}{}{}",
            take.name,
            take.duration,
            take.steps,
            take.frames,
            take.ending,
            if take.layers.is_empty() {
                String::new()
            } else {
                format!("  overdub of {}", take.layers.join(", "))
            },
            if take.fresh { "" } else { "  (began mid-show)" },
        );
        if let Some(config) = &config {
            // With the puppets a director had added, which the take carries.
            let header = match puppetry_take::TakeReader::open(&take.file) {
                Ok(reader) => reader.header,
                Err(e) => {
                    ok = false;
                    let _ = writeln!(out, "  cannot replay: {e}");
                    continue;
                }
            };
            // A puppet the take carries may be gone (its kept files
            // deleted): that take cannot replay, the others still can.
            let stage = match Stage::from_config(&puppetry_take::stage_config(config, &header)) {
                Ok(stage) => stage,
                Err(e) => {
                    ok = false;
                    let _ = writeln!(out, "  cannot replay: {e}");
                    continue;
                }
            };
            match verify(&take.file, stage) {
                Ok(v) => {
                    let tail = match &v.tail {
                        Tail::Truncated { bytes, .. } => {
                            format!(", {bytes} bytes of cut tail skipped")
                        }
                        _ => String::new(),
                    };
                    match v.first_mismatch {
                        None => {
                            let _ = writeln!(
                                out,
                                "  replays exactly: {} frames of {} steps{tail}",
                                v.frames, v.steps
                            );
                        }
                        Some(m) if take.fresh => {
                            ok = false;
                            let _ = writeln!(out, "  differs: {m}");
                        }
                        Some(m) => {
                            let _ = writeln!(
                                out,
                                "  replays approximately, as expected of a take begun mid-show \
                                 (the handles held when it began are not in it): {m}"
                            );
                        }
                    }
                }
                Err(e) => {
                    ok = false;
                    let _ = writeln!(out, "  cannot replay: {e}");
                }
            }
        }
    }
    Ok((out, ok))
}
