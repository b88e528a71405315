//! Raw MIDI ports: the ones this machine has, and reading one. ALSA makes
//! one device node per port, `midiC<card>D<device>` in `/dev/snd`, and
//! names each card in `/proc/asound/card<card>/id` (`nanoKONTROL2`,
//! `VirMIDI`…). `puppetry devices` lists them, and which stage-file MIDI
//! input reads each; [`PortReader`] reads one (or a FIFO, or a serial
//! MIDI interface) for the daemon's MIDI inputs and `puppetry record`.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::unix::AsyncFd;

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

/// Where the card names of the ports in `snd_dir` are: [`ASOUND_DIR`] for
/// [`DEFAULT_SND_DIR`]; for another folder (a test's stand-in for the
/// machine), the `asound` folder beside it.
pub fn asound_dir_for(snd_dir: &Path) -> PathBuf {
    if snd_dir == Path::new(DEFAULT_SND_DIR) {
        PathBuf::from(ASOUND_DIR)
    } else {
        snd_dir.with_file_name("asound")
    }
}

/// The port of the sound card `card` names among `ports`: the card whose
/// name is `card` (any case), else the one whose name contains it; its
/// first device. No such card, or several, is an error listing the cards.
pub fn port_of_card<'a>(ports: &'a [MidiPort], card: &str) -> Result<&'a MidiPort, String> {
    let wanted = card.to_lowercase();
    let name_of = |p: &MidiPort| p.name.as_deref().unwrap_or("").to_lowercase();
    let mut cards: Vec<&MidiPort> = ports.iter().filter(|p| name_of(p) == wanted).collect();
    if cards.is_empty() {
        cards = ports
            .iter()
            .filter(|p| name_of(p).contains(&wanted))
            .collect();
    }
    // `ports` is sorted by card and device: a card's first device leads.
    cards.dedup_by_key(|p| p.card);
    let listed = || {
        let names: Vec<String> = ports
            .iter()
            .map(|p| {
                format!(
                    "{} ({})",
                    p.name.as_deref().unwrap_or("?"),
                    p.path.display()
                )
            })
            .collect();
        if names.is_empty() {
            "there is no raw MIDI port".to_string()
        } else {
            format!("the ports: {}", names.join(", "))
        }
    };
    match cards.as_slice() {
        [one] => Ok(one),
        [] => Err(format!(
            "no sound card named {card:?} has a MIDI port ({})",
            listed()
        )),
        _ => Err(format!(
            "{card:?} names several sound cards ({}): give more of the name",
            listed()
        )),
    }
}

/// A raw MIDI byte stream, read in the runtime's reactor: opened without
/// blocking (a FIFO with no writer yet opens at once) and waited on
/// without a thread, so an idle controller never holds up a shutdown.
pub struct PortReader {
    port: AsyncFd<std::fs::File>,
}

/// How long a FIFO with no writer waits before it is read again.
const NO_WRITER_WAIT: Duration = Duration::from_millis(100);

impl PortReader {
    /// Opens `path`. A regular file cannot be waited on so: it is refused,
    /// naming `file` for what plays a `.mid` instead.
    pub fn open(path: &Path) -> std::io::Result<PortReader> {
        use std::os::unix::fs::OpenOptionsExt;
        let port = std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
            .open(path)?;
        // SAFETY: `port` is an open `File` owned by the AsyncFd from here
        // on; a `File`'s descriptor stays the same open file until it is
        // dropped.
        let port = unsafe { AsyncFd::register_with_interest(port, tokio::io::Interest::READABLE) }
            .map_err(|e| {
                let e = e.into_parts().1;
                std::io::Error::new(
                    e.kind(),
                    format!("not a MIDI port, FIFO or device ({e}); a .mid plays with `file`"),
                )
            })?;
        Ok(PortReader { port })
    }

    /// Reads what the port has (at least a byte); an error when it fails
    /// (a device unplugged). A FIFO with no writer (yet, or any more) is
    /// kept open, so a writer that comes finds its reader, and looked at
    /// again every 100 ms.
    pub async fn read(&self, buffer: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let mut ready = self.port.readable().await?;
            // A read of 0 (no writer) leaves the port readable (`try_io`
            // clears readiness only on WouldBlock): the sleep paces it.
            match ready.try_io(|port| (&mut port.get_ref()).read(buffer)) {
                Ok(Ok(0)) => tokio::time::sleep(NO_WRITER_WAIT).await,
                Ok(result) => return result,
                Err(_would_block) => {}
            }
        }
    }
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

        // Found by the card's name, any case or part of it: its first device.
        assert_eq!(port_of_card(&found, "nanokontrol2").unwrap().device, 0);
        assert_eq!(port_of_card(&found, "KONTROL").unwrap().card, 1);
        let none = port_of_card(&found, "Push").unwrap_err();
        assert!(none.contains("nanoKONTROL2 ("), "{none}");
        std::fs::create_dir(asound.path().join("card2")).unwrap();
        std::fs::write(asound.path().join("card2/id"), "nanoKONTROL\n").unwrap();
        let two = ports(snd.path(), asound.path());
        assert_eq!(port_of_card(&two, "nanoKONTROL").unwrap().card, 2);
        assert!(port_of_card(&two, "nano").unwrap_err().contains("several"));
        assert_eq!(
            asound_dir_for(Path::new("/tmp/x/snd")),
            Path::new("/tmp/x/asound")
        );
        assert_eq!(
            asound_dir_for(Path::new("/dev/snd")),
            Path::new("/proc/asound")
        );
    }
}
