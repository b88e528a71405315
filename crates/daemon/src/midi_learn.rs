//! Learning a MIDI mapping from the page: a director picks what a control
//! should do (a `midi_learn` message with a target: a [`MidiMapping`] of no control), moves the
//! control, and the next control message on any of the stage's MIDI
//! inputs becomes an `[[input.map]]` entry of that input — working at once,
//! and saved to the stage file.
//!
//! The stage file is a person's: it is not rewritten from the parsed
//! config (which would lose its comments and order) but has the new entry
//! inserted as text, after the input's last line (before the next
//! `[[input]]`). The result is parsed before it is written and must hold
//! the input's mapping list with the new entry last, or nothing is
//! written; it is written atomically (`write_atomically`). A mapping that
//! cannot be saved still works until the daemon stops, and the page says
//! why it was not saved.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use puppetry_input::config::InputConfig;
use puppetry_input::midi::MidiMessage;
use puppetry_input::midi_map::{MidiMapper, MidiMapping};

use crate::sources::Replays;

/// Why a learnt mapping was not saved to the stage file.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// The stage file could not be read or written.
    #[error("{file}: {problem}")]
    File {
        /// The stage file.
        file: String,
        /// What went wrong.
        problem: String,
    },
    /// The stage file with the mapping inserted did not read back as the
    /// mapping added to the input (a file edited since the daemon
    /// started, say): nothing was written.
    #[error("{file}: the mapping could not be added to input[{input}] ({problem}); not saved")]
    Insert {
        /// The stage file.
        file: String,
        /// The input's index in the file.
        input: usize,
        /// What did not read back.
        problem: String,
    },
}

/// The stage's MIDI learning: what is awaited, where it is saved, and the
/// `inputs` message that shows it.
pub(crate) struct Learning {
    /// The stage file learnt mappings are saved to.
    stage_file: PathBuf,
    /// The stage's puppets, by name (what a target may name).
    puppets: Vec<String>,
    /// Publishes the learning in the `inputs` message.
    view: Arc<Replays>,
    /// A target is awaited (what the view says, kept apart so the MIDI
    /// inputs look at it for every message without locking).
    waiting: AtomicBool,
}

impl Learning {
    /// Learning for the MIDI inputs `inputs` (by name) of the stage file
    /// `stage_file`, shown through `view`.
    pub(crate) fn new(
        stage_file: PathBuf,
        inputs: Vec<String>,
        puppets: Vec<String>,
        view: Arc<Replays>,
    ) -> Learning {
        if !inputs.is_empty() {
            view.midi(|v| v.inputs = inputs);
        }
        Learning {
            stage_file,
            puppets,
            view,
            waiting: AtomicBool::new(false),
        }
    }

    /// Waits for the next control to do `target` (none: stops waiting).
    pub(crate) fn wait_for(&self, target: Option<MidiMapping>) -> Result<(), String> {
        let Some(target) = target else {
            self.view.midi(|v| {
                v.waiting = None;
                v.passed_over = None;
            });
            self.waiting.store(false, Ordering::Release);
            return Ok(());
        };
        if self.view.midi(|v| v.inputs.is_empty()) {
            return Err(
                "midi_learn: the stage has no MIDI input (add an [[input]] with kind = \"midi\")"
                    .into(),
            );
        }
        if let Some(field) = target.control_field() {
            return Err(format!(
                "midi_learn: target.{field}: a target says what the control will do; \
                 the control is the one moved next"
            ));
        }
        // A control stands in, so the target is checked as a mapping is.
        let any = MidiMessage::ControlChange {
            channel: 0,
            controller: 0,
            value: 0,
        };
        if let Some(Err((field, problem))) = MidiMapping::learned(&any, &target).map(|m| m.check())
        {
            return Err(format!("midi_learn: target.{field}: {problem}"));
        }
        if let Some(puppet) = &target.puppet
            && !self.puppets.contains(puppet)
        {
            return Err(format!(
                "midi_learn: target.puppet: no puppet {:?} on the stage",
                crate::show_control::clip(puppet)
            ));
        }
        self.view.midi(|v| {
            v.waiting = Some(target);
            v.learned = None;
            v.error = None;
            v.passed_over = None;
        });
        self.waiting.store(true, Ordering::Release);
        Ok(())
    }

    /// The mapping `message` teaches, if one is awaited and `message` is
    /// a control's that the input (`mapper`) has not mapped yet; the wait
    /// ends. A clock or a note off teaches nothing, and a control already
    /// mapped is passed over, saying so (a controller that sends a mapped
    /// CC on its own, or a hand on the wrong knob, would otherwise make one
    /// control do two things): the wait goes on.
    pub(crate) fn claim(&self, message: &MidiMessage, mapper: &MidiMapper) -> Option<MidiMapping> {
        if !self.waiting.load(Ordering::Acquire) {
            return None;
        }
        let mapping = self.view.midi(|v| {
            let mapping = MidiMapping::learned(message, v.waiting.as_ref()?)?;
            if let Some(mapped) = mapper.mapped(&mapping) {
                v.passed_over = Some(format!(
                    "{} already does {}: move another control (to have one control do both, \
                     add the mapping to the stage file)",
                    mapping.control_text(),
                    action_text(mapped)
                ));
                return None;
            }
            v.waiting = None;
            v.passed_over = None;
            Some(mapping)
        })?;
        self.waiting.store(false, Ordering::Release);
        Some(mapping)
    }

    /// Saves `mapping` as input `index`'s (named `input`) in the stage
    /// file, off the runtime, and shows the outcome.
    pub(crate) async fn save(&self, index: usize, input: &str, mapping: &MidiMapping) {
        let file = self.stage_file.clone();
        let entry = mapping.clone();
        let saved = tokio::task::spawn_blocking(move || save(&file, index, &entry))
            .await
            .unwrap_or_else(|e| {
                Err(LearnError::File {
                    file: String::new(),
                    problem: e.to_string(),
                })
            });
        let what = format!(
            "{}: {} does {}",
            input,
            mapping.control_text(),
            action_text(mapping)
        );
        match &saved {
            Ok(()) => tracing::info!(
                "MIDI learnt: {what} (saved to {})",
                self.stage_file.display()
            ),
            Err(e) => tracing::warn!("MIDI learnt: {what}, not saved: {e}"),
        }
        self.view.midi(|v| match saved {
            Ok(()) => {
                v.learned = Some(format!("{what}; saved to {}", self.stage_file.display()));
                v.error = None;
            }
            Err(e) => {
                v.learned = Some(format!("{what} until the daemon stops"));
                v.error = Some(e.to_string());
            }
        });
    }
}

/// What a mapping does, for people (`cursor_x of gingerbread`).
fn action_text(mapping: &MidiMapping) -> String {
    let action = serde_json::to_value(mapping.action)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    match &mapping.puppet {
        Some(puppet) => format!("{action} of {puppet}"),
        None => action,
    }
}

/// Adds `mapping` to input `index` of the stage file at `file`.
pub fn save(file: &std::path::Path, index: usize, mapping: &MidiMapping) -> Result<(), LearnError> {
    let name = file.display().to_string();
    let failed = |problem: String| LearnError::File {
        file: name.clone(),
        problem,
    };
    let text =
        puppetry_stage::config::StageConfig::read_text(file).map_err(|e| failed(e.to_string()))?;
    let new = insert(&text, index, mapping).map_err(failed)?;
    let not_added = |problem: String| LearnError::Insert {
        file: name.clone(),
        input: index,
        problem,
    };
    let folder = file.parent().unwrap_or(std::path::Path::new("."));
    let parsed = crate::config::ShowConfig::parse(&name, &new, folder)
        .map_err(|e| not_added(e.to_string()))?;
    match parsed.inputs.get(index) {
        Some(InputConfig::Midi { map, .. }) if map.last() == Some(mapping) => {}
        Some(InputConfig::Midi { .. }) => {
            return Err(not_added("its last mapping is not the one learnt".into()));
        }
        _ => return Err(not_added("it is not a MIDI input".into())),
    }
    puppetry_mesh::file::write_atomically(file, new.as_bytes()).map_err(|e| failed(e.to_string()))
}

/// `text` with `mapping` inserted as an `[[input.map]]` table at the end
/// of the `index`-th `[[input]]` (before the next one, or at the end).
fn insert(text: &str, index: usize, mapping: &MidiMapping) -> Result<String, String> {
    let table = toml::to_string(mapping).map_err(|e| e.to_string())?;
    let mut inputs = Vec::new();
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let header = line
            .trim()
            .strip_prefix("[[")
            .and_then(|rest| rest.split_once("]]"))
            .map(|(name, _)| name.trim());
        if header == Some("input") {
            inputs.push(offset);
        }
        offset += line.len();
    }
    if index >= inputs.len() {
        return Err(format!(
            "the file has {} [[input]] tables, not input[{index}]",
            inputs.len()
        ));
    }
    let at = inputs.get(index + 1).copied().unwrap_or(text.len());
    let (before, after) = text.split_at(at);
    let mut out = String::with_capacity(text.len() + table.len() + 64);
    out.push_str(before);
    if !before.is_empty() && !before.ends_with('\n') {
        out.push('\n');
    }
    out.push_str("\n[[input.map]]  # learnt on the page\n");
    out.push_str(&table);
    if !after.is_empty() {
        out.push('\n');
    }
    out.push_str(after);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use puppetry_input::midi_map::MidiActionKind;

    fn mapping() -> MidiMapping {
        let target = MidiMapping::doing(MidiActionKind::Record);
        let pad = MidiMessage::NoteOn {
            channel: 9,
            note: 40,
            velocity: 1,
        };
        MidiMapping::learned(&pad, &target).unwrap()
    }

    /// A target that names a control is refused (the control moved is
    /// what is learnt), as is one naming a puppet the stage lacks; a
    /// target of no control is awaited.
    #[test]
    fn a_target_names_what_a_control_does_not_the_control() {
        let learning = Learning::new(
            PathBuf::from("show.toml"),
            vec!["desk".into()],
            vec!["gingerbread".into()],
            Arc::new(Replays::new(Vec::new())),
        );
        let with_cc = MidiMapping {
            cc: Some(7),
            ..MidiMapping::doing(MidiActionKind::Record)
        };
        let refused = learning.wait_for(Some(with_cc)).unwrap_err();
        assert!(refused.starts_with("midi_learn: target.cc:"), "{refused}");
        let elsewhere = MidiMapping {
            puppet: Some("nobody".into()),
            ..MidiMapping::doing(MidiActionKind::CursorX)
        };
        assert!(learning.wait_for(Some(elsewhere)).is_err());
        assert!(!learning.waiting.load(Ordering::Acquire));
        let record = MidiMapping::doing(MidiActionKind::Record);
        learning.wait_for(Some(record)).unwrap();
        assert!(learning.waiting.load(Ordering::Acquire));
    }

    /// A control the input maps already is passed over, saying what it
    /// does, and the wait goes on; the next free control is learnt.
    #[test]
    fn a_control_already_mapped_is_passed_over() {
        let learning = Learning::new(
            PathBuf::from("show.toml"),
            vec!["desk".into()],
            vec!["gingerbread".into()],
            Arc::new(Replays::new(Vec::new())),
        );
        let cc = |controller| MidiMessage::ControlChange {
            channel: 0,
            controller,
            value: 64,
        };
        let reset = MidiMapping::learned(&cc(0), &MidiMapping::doing(MidiActionKind::Record));
        let mapper = MidiMapper::new(vec![reset.unwrap()]);
        learning
            .wait_for(Some(MidiMapping::doing(MidiActionKind::Stop)))
            .unwrap();
        assert_eq!(learning.claim(&cc(0), &mapper), None);
        assert!(learning.waiting.load(Ordering::Acquire));
        let said = learning.view.midi(|v| v.passed_over.clone()).unwrap();
        assert!(
            said.starts_with("CC 0 on channel 1 already does record: move another control"),
            "{said}"
        );
        let learnt = learning.claim(&cc(7), &mapper).unwrap();
        assert_eq!(learnt.cc, Some(7));
        assert!(!learning.waiting.load(Ordering::Acquire));
        assert_eq!(learning.view.midi(|v| v.passed_over.clone()), None);
    }

    #[test]
    fn the_entry_goes_at_the_end_of_its_input_keeping_the_rest() {
        let text = "# my show\n[stage]\nwidth = 10\n\n[[input]]\nkind = \"midi\" # faders\npath = \"/dev/a\"\n\n# the desk\n[[input]]\nkind = \"midi\"\npath = \"/dev/b\"\n[[input.map]]\nnote = 1\naction = \"stop\"\n";
        let first = insert(text, 0, &mapping()).unwrap();
        assert_eq!(
            first,
            "# my show\n[stage]\nwidth = 10\n\n[[input]]\nkind = \"midi\" # faders\npath = \"/dev/a\"\n\n# the desk\n\n[[input.map]]  # learnt on the page\nnote = 40\nchannel = 10\naction = \"record\"\n\n[[input]]\nkind = \"midi\"\npath = \"/dev/b\"\n[[input.map]]\nnote = 1\naction = \"stop\"\n"
        );
        let last = insert(text, 1, &mapping()).unwrap();
        assert!(last.ends_with(
            "action = \"stop\"\n\n[[input.map]]  # learnt on the page\nnote = 40\nchannel = 10\naction = \"record\"\n"
        ));
        assert!(insert(text, 2, &mapping()).is_err());
    }
}
