//! The raw MIDI ports this machine has: ALSA makes one device node per
//! port, `midiC<card>D<device>` in `/dev/snd`, and names each card in
//! `/proc/asound/card<card>/id` (`nanoKONTROL2`, `VirMIDI`…). `puppetry
//! devices` lists them, and which stage-file MIDI input reads each.

use std::path::{Path, PathBuf};

/// Where ALSA's device nodes are.
pub const DEFAULT_SND_DIR: &str = "/dev/snd";
/// Where ALSA names its cards.
pub const ASOUND_DIR: &str = "/proc/asound";

/// A raw MIDI port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MidiPort {
    /// Its device node, as a MIDI input's `path` names it.
    pub path: PathBuf,
    /// Its sound card's number.
    pub card: u32,
    /// Its device number on the card.
    pub device: u32,
    /// The card's name, when ALSA gives one.
    pub name: Option<String>,
}

/// The card and device numbers of a `midiC<card>D<device>` node's name.
fn numbers(name: &str) -> Option<(u32, u32)> {
    let rest = name.strip_prefix("midiC")?;
    let (card, device) = rest.split_once('D')?;
    Some((card.parse().ok()?, device.parse().ok()?))
}

/// The raw MIDI ports in `snd_dir`, by card and device, named from
/// `asound_dir`; none when the folder cannot be read (a machine without
/// sound, a container).
pub fn ports(snd_dir: &Path, asound_dir: &Path) -> Vec<MidiPort> {
    let Ok(entries) = std::fs::read_dir(snd_dir) else {
        return Vec::new();
    };
    let mut ports: Vec<MidiPort> = entries
        .filter_map(Result::ok)
        .filter_map(|entry| {
            let (card, device) = numbers(entry.file_name().to_str()?)?;
            let name = std::fs::read_to_string(asound_dir.join(format!("card{card}/id")))
                .ok()
                .map(|id| id.trim().to_string())
                .filter(|id| !id.is_empty());
            Some(MidiPort {
                path: entry.path(),
                card,
                device,
                name,
            })
        })
        .collect();
    ports.sort_by_key(|p| (p.card, p.device));
    ports
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_are_listed_by_card_with_their_names() {
        let snd = tempfile::tempdir().unwrap();
        let asound = tempfile::tempdir().unwrap();
        for node in [
            "midiC2D0",
            "midiC1D1",
            "midiC1D0",
            "pcmC0D0p",
            "controlC1",
            "midiCxD0",
        ] {
            std::fs::write(snd.path().join(node), "").unwrap();
        }
        std::fs::create_dir(asound.path().join("card1")).unwrap();
        std::fs::write(asound.path().join("card1/id"), "nanoKONTROL2\n").unwrap();
        let found = ports(snd.path(), asound.path());
        let summary: Vec<(u32, u32, Option<&str>)> = found
            .iter()
            .map(|p| (p.card, p.device, p.name.as_deref()))
            .collect();
        assert_eq!(
            summary,
            [
                (1, 0, Some("nanoKONTROL2")),
                (1, 1, Some("nanoKONTROL2")),
                (2, 0, None)
            ]
        );
        assert!(ports(&snd.path().join("missing"), asound.path()).is_empty());
    }
}
