//! What a MIDI controller's controls do on the stage: the `[[input.map]]`
//! entries of a `kind = "midi"` input, and the mapper that turns decoded
//! [`MidiMessage`]s into [`MidiAction`]s — the keyframing cursor's x and y
//! (two faders or knobs), a skeleton's key-pose blend (a fader), a key
//! pose by name, a puppet's reset, and takes (record, stop), with MIDI
//! Show Control GO/STOP/RESUME mappable like a button. The daemon does an
//! action as the same trigger OSC's addresses give (one table of
//! triggers), so what MIDI can do is what OSC can.
//!
//! A control is listened for by what it is (a control change `cc`, a
//! `note`, a `program` change, the `pitch_bend` wheel, a show-control
//! `msc` command) and optionally its `channel` (1 to 16; default any).
//! Continuous actions (`cursor_x`, `cursor_y`, `blend`) take the control's
//! value as a fraction (a CC's 7 bits, or 14 with its fine partner; a
//! note's velocity; the wheel's 14 bits); the others fire on a press (a
//! note on, a CC rising past the middle, a program change, a show-control
//! command).

use serde::{Deserialize, Serialize};

use crate::midi::{ControlValue, Controls, MidiMessage, ShowCommand};

/// What a mapped control does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MidiActionKind {
    /// The puppet's keyframing cursor's x, 0 to 1 across its pad.
    CursorX,
    /// The puppet's keyframing cursor's y, 0 to 1 up its pad.
    CursorY,
    /// The skeleton's blend from `poses[0]` to `poses[1]`, 0 to 1.
    Blend,
    /// Blend the puppet to key pose `key` over `seconds`.
    Key,
    /// The puppet back to how the stage file has it.
    Reset,
    /// Start recording a take.
    Record,
    /// Stop the take (recording, playing or overdubbing).
    Stop,
    /// Play `take` (default: the newest).
    Play,
    /// Play `take` (default: the newest) and record a new take over it.
    Overdub,
}

/// A show-control command, as a mapping names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MscCommand {
    /// GO.
    Go,
    /// STOP.
    Stop,
    /// RESUME.
    Resume,
}

/// One `[[input.map]]` entry: which control, and what it does. Written
/// back (a mapping learnt on the page) with only the fields it uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MidiMapping {
    /// A control change, 0 to 127 (0 to 31 read with their fine CC 32 to
    /// 63 as 14 bits when the controller sends it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cc: Option<u8>,
    /// A note (key or pad), 0 to 127.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<u8>,
    /// A program change to this program, 0 to 127.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub program: Option<u8>,
    /// The pitch wheel.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub pitch_bend: bool,
    /// A MIDI Show Control command (any device id, any cue).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub msc: Option<MscCommand>,
    /// The channel, 1 to 16; default any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<u8>,
    /// What it does.
    pub action: MidiActionKind,
    /// The puppet it acts on, by name (cursor, blend, key and reset).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub puppet: Option<String>,
    /// `blend`: the two stage-file key poses blended between.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses: Option<[String; 2]>,
    /// `key`: the key pose's name (a skeleton pose or a keyframing key).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
    /// `key`: how long the blend takes, seconds; default 0 (at once).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub seconds: f64,
    /// `play`, `overdub`: the take's name; default the newest take.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub take: Option<String>,
}

fn is_zero(seconds: &f64) -> bool {
    *seconds == 0.0
}

impl MidiMapping {
    /// A mapping of no control yet doing `action` (with no puppet, poses,
    /// key or take): what a director asks of the next control moved,
    /// before it is [`learned`](MidiMapping::learned).
    pub fn doing(action: MidiActionKind) -> MidiMapping {
        MidiMapping {
            cc: None,
            note: None,
            program: None,
            pitch_bend: false,
            msc: None,
            channel: None,
            action,
            puppet: None,
            poses: None,
            key: None,
            seconds: 0.0,
            take: None,
        }
    }

    /// The field naming its control (or channel), if any: a learn target
    /// names none, the control moved is learnt.
    pub fn control_field(&self) -> Option<&'static str> {
        [
            ("cc", self.cc.is_some()),
            ("note", self.note.is_some()),
            ("program", self.program.is_some()),
            ("pitch_bend", self.pitch_bend),
            ("msc", self.msc.is_some()),
            ("channel", self.channel.is_some()),
        ]
        .into_iter()
        .find_map(|(field, named)| named.then_some(field))
    }

    /// The mapping a director learns by moving a control: the control
    /// (and channel) `message` comes from, doing `target`. `None` for a
    /// message no control is mapped by (a note off, a clock, time code…).
    pub fn learned(message: &MidiMessage, target: &MidiMapping) -> Option<MidiMapping> {
        let mut m = MidiMapping {
            action: target.action,
            puppet: target.puppet.clone(),
            poses: target.poses.clone(),
            key: target.key.clone(),
            seconds: target.seconds,
            take: target.take.clone(),
            ..MidiMapping::doing(target.action)
        };
        let channel = match *message {
            MidiMessage::ControlChange {
                channel,
                controller,
                ..
            } => {
                // As sent: a 14-bit fader sends its coarse half first, and
                // a CC 32-63 sent alone is a control of its own (a
                // nanoKONTROL2's buttons).
                m.cc = Some(controller);
                channel
            }
            MidiMessage::NoteOn { channel, note, .. } => {
                m.note = Some(note);
                channel
            }
            MidiMessage::ProgramChange { channel, program } => {
                m.program = Some(program);
                channel
            }
            MidiMessage::PitchBend { channel, .. } => {
                m.pitch_bend = true;
                channel
            }
            MidiMessage::ShowControl { command, .. } => {
                m.msc = Some(match command {
                    ShowCommand::Go => MscCommand::Go,
                    ShowCommand::Stop => MscCommand::Stop,
                    ShowCommand::Resume => MscCommand::Resume,
                });
                return Some(m);
            }
            _ => return None,
        };
        m.channel = Some(channel + 1);
        Some(m)
    }

    /// Whether `other` listens to the same control as this mapping: the
    /// same CC, note, program, wheel or show-control command, on a channel
    /// both hear (a mapping of no channel hears every channel).
    pub fn same_control(&self, other: &MidiMapping) -> bool {
        let channels = match (self.channel, other.channel) {
            (Some(a), Some(b)) => a == b,
            _ => true,
        };
        channels
            && (self.cc, self.note, self.program, self.pitch_bend, self.msc)
                == (
                    other.cc,
                    other.note,
                    other.program,
                    other.pitch_bend,
                    other.msc,
                )
    }

    /// The control, as people name it (`CC 16 on channel 1`).
    pub fn control_text(&self) -> String {
        let control = match (self.cc, self.note, self.program, self.msc) {
            (Some(cc), ..) => format!("CC {cc}"),
            (_, Some(note), ..) => format!("note {note}"),
            (_, _, Some(program), _) => format!("program {program}"),
            (.., Some(msc)) => format!("show control {}", format!("{msc:?}").to_uppercase()),
            _ => "the pitch wheel".to_string(),
        };
        match self.channel {
            Some(c) => format!("{control} on channel {c}"),
            None => control,
        }
    }
}

impl MidiMapping {
    /// Checks the entry: one control, a channel of 1 to 16, numbers of 0
    /// to 127, and what its action needs. `Err` is (field, problem).
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let controls = [
            self.cc.is_some(),
            self.note.is_some(),
            self.program.is_some(),
            self.pitch_bend,
            self.msc.is_some(),
        ];
        if controls.iter().filter(|&&c| c).count() != 1 {
            return Err((
                "cc",
                "give exactly one control: cc, note, program, pitch_bend or msc".into(),
            ));
        }
        for (field, number) in [
            ("cc", self.cc),
            ("note", self.note),
            ("program", self.program),
        ] {
            if let Some(n) = number.filter(|&n| n > 127) {
                return Err((field, format!("{n} is not 0 to 127")));
            }
        }
        if let Some(c) = self.channel.filter(|c| !(1..=16).contains(c)) {
            return Err(("channel", format!("{c} is not 1 to 16")));
        }
        let needs_puppet = matches!(
            self.action,
            MidiActionKind::CursorX
                | MidiActionKind::CursorY
                | MidiActionKind::Blend
                | MidiActionKind::Key
                | MidiActionKind::Reset
        );
        if needs_puppet && self.puppet.is_none() {
            return Err(("puppet", "this action acts on a puppet: name it".into()));
        }
        if self.action == MidiActionKind::Blend && self.poses.is_none() {
            return Err((
                "poses",
                "blend needs the two key poses, as [from, to]".into(),
            ));
        }
        if self.action == MidiActionKind::Key && self.key.is_none() {
            return Err(("key", "key needs the key pose's name".into()));
        }
        if let Some(take) = &self.take {
            if !matches!(self.action, MidiActionKind::Play | MidiActionKind::Overdub) {
                return Err(("take", "only play and overdub play a take".into()));
            }
            let name_ok = !take.is_empty()
                && take.len() <= 100
                && take
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
            if !name_ok {
                return Err((
                    "take",
                    format!("{take:?}: a take's name (letters, digits, '-', '_', '.')"),
                ));
            }
        }
        if !(self.seconds.is_finite() && (0.0..=3600.0).contains(&self.seconds)) {
            return Err(("seconds", format!("{} is not 0 to 3600", self.seconds)));
        }
        Ok(())
    }
}

/// What a mapped control asks of the stage; puppets by name (the daemon
/// knows the stage's).
#[derive(Debug, Clone, PartialEq)]
pub enum MidiAction {
    /// The keyframing cursor to this pad point.
    Cursor {
        /// The puppet.
        puppet: String,
        /// Pad coordinates, `[0, 1]²` from the pad's lower left.
        at: [f64; 2],
    },
    /// The skeleton set `t` of the way from key pose `from` to `to`.
    Blend {
        /// The puppet.
        puppet: String,
        /// From this stage-file pose…
        from: String,
        /// …to this one.
        to: String,
        /// How far, 0 to 1.
        t: f64,
    },
    /// Blend to the key pose `name` over `seconds`.
    Key {
        /// The puppet.
        puppet: String,
        /// The key pose.
        name: String,
        /// How long.
        seconds: f64,
    },
    /// The puppet back to how the stage file has it.
    Reset {
        /// The puppet.
        puppet: String,
    },
    /// Start recording a take.
    Record,
    /// Stop the take.
    Stop,
    /// Play a take (`None`: the newest); with `overdub`, record over it.
    Play {
        /// The take.
        take: Option<String>,
        /// Record a new take over it.
        overdub: bool,
    },
}

/// Turns messages into actions through a list of mappings, keeping what
/// a controller's state needs: 14-bit pairs, each cursor's other
/// coordinate, and whether a CC button is held (so it fires once a
/// press).
#[derive(Debug, Clone)]
pub struct MidiMapper {
    map: Vec<MidiMapping>,
    controls: Controls,
    /// Per mapping, the cursor's point it last set (its other coordinate
    /// kept from the mapping that moves that one).
    cursors: Vec<(String, [f64; 2])>,
    /// Per mapping, whether its CC was last seen pressed (≥ 64).
    held: Vec<bool>,
}

impl MidiMapper {
    /// A mapper over checked mappings ([`MidiMapping::check`]).
    pub fn new(map: Vec<MidiMapping>) -> MidiMapper {
        let held = vec![false; map.len()];
        MidiMapper {
            map,
            controls: Controls::new(),
            cursors: Vec::new(),
            held,
        }
    }

    /// Adds a mapping (a learnt one), last, as the stage file then has
    /// it: a control already mapped does both (one fader can move two
    /// puppets' cursors).
    pub fn learn(&mut self, mapping: MidiMapping) {
        self.map.push(mapping);
        self.held.push(false);
    }

    /// The first mapping listening to `control`'s control, if any
    /// ([`MidiMapping::same_control`]).
    pub fn mapped(&self, control: &MidiMapping) -> Option<&MidiMapping> {
        self.map.iter().find(|m| m.same_control(control))
    }

    /// The actions `message` asks for, in mapping order.
    pub fn actions(&mut self, message: &MidiMessage) -> Vec<MidiAction> {
        let mut out = Vec::new();
        for i in 0..self.map.len() {
            if let Some(action) = self.action(i, message) {
                out.push(action);
            }
        }
        out
    }

    /// Mapping `i`'s action for `message`, if it listens for it.
    fn action(&mut self, i: usize, message: &MidiMessage) -> Option<MidiAction> {
        let m = &self.map[i];
        let on_channel = |c: u8| m.channel.is_none_or(|want| want == c + 1);
        // (value as a fraction, pressed now)
        let (value, pressed) = match *message {
            MidiMessage::ControlChange {
                channel,
                controller,
                value,
            } if on_channel(channel) => {
                // CC 32-63 refine CC 0-31 (14 bits), unless a mapping
                // listens for one itself: controllers such as the
                // nanoKONTROL2 send their buttons there, alone.
                let own = (32..64).contains(&controller)
                    && self.map.iter().any(|other| other.cc == Some(controller));
                let read = if own {
                    ControlValue {
                        channel,
                        controller,
                        value: f64::from(value) / 127.0,
                    }
                } else {
                    self.controls.read(channel, controller, value)
                };
                if m.cc != Some(read.controller) {
                    return None;
                }
                let down = read.value >= 0.5;
                let rising = down && !self.held[i];
                self.held[i] = down;
                (read.value, rising)
            }
            MidiMessage::NoteOn {
                channel,
                note,
                velocity,
            } if on_channel(channel) && m.note == Some(note) => (f64::from(velocity) / 127.0, true),
            MidiMessage::ProgramChange { channel, program }
                if on_channel(channel) && m.program == Some(program) =>
            {
                (1.0, true)
            }
            MidiMessage::PitchBend { channel, value } if on_channel(channel) && m.pitch_bend => {
                (f64::from(value) / 16383.0, false)
            }
            MidiMessage::ShowControl { command, .. } if m.msc.is_some() => {
                let matches = matches!(
                    (m.msc?, command),
                    (MscCommand::Go, ShowCommand::Go)
                        | (MscCommand::Stop, ShowCommand::Stop)
                        | (MscCommand::Resume, ShowCommand::Resume)
                );
                if !matches {
                    return None;
                }
                (1.0, true)
            }
            _ => return None,
        };
        let m = &self.map[i];
        let puppet = || m.puppet.clone().unwrap_or_default();
        match m.action {
            MidiActionKind::CursorX | MidiActionKind::CursorY => {
                let name = puppet();
                let at = match self.cursors.iter_mut().find(|(p, _)| *p == name) {
                    Some((_, at)) => at,
                    None => {
                        self.cursors.push((name.clone(), [0.5, 0.5]));
                        &mut self.cursors.last_mut().expect("pushed").1
                    }
                };
                at[usize::from(m.action == MidiActionKind::CursorY)] = value;
                Some(MidiAction::Cursor {
                    puppet: name,
                    at: *at,
                })
            }
            MidiActionKind::Blend => {
                let [from, to] = m.poses.clone()?;
                Some(MidiAction::Blend {
                    puppet: puppet(),
                    from,
                    to,
                    t: value,
                })
            }
            MidiActionKind::Key if pressed => Some(MidiAction::Key {
                puppet: puppet(),
                name: m.key.clone()?,
                seconds: m.seconds,
            }),
            MidiActionKind::Reset if pressed => Some(MidiAction::Reset { puppet: puppet() }),
            MidiActionKind::Record if pressed => Some(MidiAction::Record),
            MidiActionKind::Stop if pressed => Some(MidiAction::Stop),
            MidiActionKind::Play | MidiActionKind::Overdub if pressed => Some(MidiAction::Play {
                take: m.take.clone(),
                overdub: m.action == MidiActionKind::Overdub,
            }),
            MidiActionKind::Key
            | MidiActionKind::Reset
            | MidiActionKind::Record
            | MidiActionKind::Stop
            | MidiActionKind::Play
            | MidiActionKind::Overdub => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mapping(text: &str) -> MidiMapping {
        let m: MidiMapping = toml::from_str(text).unwrap();
        m.check().unwrap();
        m
    }

    #[test]
    fn two_faders_move_a_cursor_and_a_pad_starts_a_take() {
        let mut mapper = MidiMapper::new(vec![
            mapping("cc = 16\naction = \"cursor_x\"\npuppet = \"g\""),
            mapping("cc = 17\naction = \"cursor_y\"\npuppet = \"g\""),
            mapping("note = 36\nchannel = 10\naction = \"record\""),
            mapping("msc = \"stop\"\naction = \"stop\""),
        ]);
        let cc = |controller, value| MidiMessage::ControlChange {
            channel: 0,
            controller,
            value,
        };
        assert_eq!(
            mapper.actions(&cc(16, 127)),
            [MidiAction::Cursor {
                puppet: "g".into(),
                at: [1.0, 0.5]
            }]
        );
        assert_eq!(
            mapper.actions(&cc(17, 0)),
            [MidiAction::Cursor {
                puppet: "g".into(),
                at: [1.0, 0.0]
            }]
        );
        // A note on channel 10 only.
        let note = |channel| MidiMessage::NoteOn {
            channel,
            note: 36,
            velocity: 90,
        };
        assert_eq!(mapper.actions(&note(0)), []);
        assert_eq!(mapper.actions(&note(9)), [MidiAction::Record]);
        let go = |command| MidiMessage::ShowControl {
            device: 1,
            command,
            cue: None,
        };
        assert_eq!(mapper.actions(&go(ShowCommand::Go)), []);
        assert_eq!(mapper.actions(&go(ShowCommand::Stop)), [MidiAction::Stop]);
    }

    #[test]
    fn a_cc_button_fires_once_a_press_and_a_blend_reads_14_bits() {
        let mut mapper = MidiMapper::new(vec![
            mapping("cc = 64\naction = \"reset\"\npuppet = \"g\""),
            mapping("cc = 1\naction = \"blend\"\npuppet = \"g\"\nposes = [\"rest\", \"cheer\"]"),
        ]);
        let cc = |controller, value| MidiMessage::ControlChange {
            channel: 2,
            controller,
            value,
        };
        let reset = [MidiAction::Reset { puppet: "g".into() }];
        assert_eq!(mapper.actions(&cc(64, 127)), reset);
        assert_eq!(mapper.actions(&cc(64, 120)), []);
        assert_eq!(mapper.actions(&cc(64, 0)), []);
        assert_eq!(mapper.actions(&cc(64, 100)), reset);
        mapper.actions(&cc(1, 64));
        let fine = mapper.actions(&cc(33, 127));
        let [MidiAction::Blend { t, .. }] = fine.as_slice() else {
            panic!("{fine:?}");
        };
        assert_eq!(*t, 8319.0 / 16383.0);
    }

    #[test]
    fn a_control_moved_is_learnt_and_written_back_as_read() {
        let target = MidiMapping {
            puppet: Some("gingerbread".into()),
            ..MidiMapping::doing(MidiActionKind::CursorX)
        };
        // Clocks and note offs teach nothing; a button on CC 39 (a
        // nanoKONTROL2's) is learnt as itself, and read as itself beside
        // the 14-bit fader CC 7 whose fine half it would otherwise be.
        assert_eq!(MidiMapping::learned(&MidiMessage::Clock, &target), None);
        let button = MidiMessage::ControlChange {
            channel: 2,
            controller: 39,
            value: 127,
        };
        let learnt = MidiMapping::learned(&button, &target).unwrap();
        assert_eq!((learnt.cc, learnt.channel), (Some(39), Some(3)));
        assert_eq!(learnt.control_text(), "CC 39 on channel 3");
        let text = toml::to_string(&learnt).unwrap();
        assert_eq!(
            text,
            "cc = 39\nchannel = 3\naction = \"cursor_x\"\npuppet = \"gingerbread\"\n"
        );
        assert_eq!(mapping(&text), learnt);
        let mut mapper = MidiMapper::new(vec![mapping(
            "cc = 7\naction = \"cursor_y\"\npuppet = \"gingerbread\"",
        )]);
        mapper.learn(learnt);
        let fader = MidiMessage::ControlChange {
            channel: 2,
            controller: 7,
            value: 64,
        };
        assert_eq!(mapper.actions(&fader).len(), 1);
        assert_eq!(
            mapper.actions(&button),
            [MidiAction::Cursor {
                puppet: "gingerbread".into(),
                at: [1.0, 64.0 / 127.0]
            }]
        );
    }

    #[test]
    fn mappings_say_what_is_wrong() {
        let problem = |text: &str| {
            let m: MidiMapping = toml::from_str(text).unwrap();
            m.check().unwrap_err()
        };
        assert_eq!(problem("action = \"record\"").0, "cc");
        assert_eq!(problem("cc = 1\nnote = 2\naction = \"record\"").0, "cc");
        assert_eq!(problem("cc = 200\naction = \"record\"").0, "cc");
        assert_eq!(
            problem("cc = 1\nchannel = 0\naction = \"record\"").0,
            "channel"
        );
        assert_eq!(problem("cc = 1\naction = \"reset\"").0, "puppet");
        assert_eq!(
            problem("cc = 1\naction = \"blend\"\npuppet = \"g\"").0,
            "poses"
        );
        assert!(toml::from_str::<MidiMapping>("cc = 1\naction = \"fly\"").is_err());
    }
}
