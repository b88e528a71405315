//! ALSA sequencer MIDI ports: the ones other programs (a DAW, a software
//! instrument, `aconnect`) connect to by name, as `port = "NAME"` on a
//! MIDI input names them. A crate of its own because reading them goes
//! through `midir` and needs libasound's headers: matching a name against
//! the ports is plain code ([`matching_port`]), always built; the reader
//! is built only with this crate's `alsa` feature (the binary's
//! `alsa-seq`: `cargo build --release --features alsa-seq`, with Debian's
//! `libasound2-dev`). Without it a stage file that names a sequencer port
//! is refused at start, saying how to build it; raw ports (`path`) need
//! nothing.
//!
//! midir calls back on a thread of its own with each whole message; the
//! daemon's callback hands the bytes to the runtime through a bounded
//! queue ([`SEQ_QUEUE`] messages; a reader that falls that far behind
//! loses the newest, counted), to the same decoder a raw port's go
//! through. No runtime here: the crate stays small to build with its
//! feature.

/// Messages queued between the sequencer's thread and the runtime.
pub const SEQ_QUEUE: usize = 1024;

/// Which of `names` (the sequencer's ports) `wanted` names: the one named
/// exactly, else the one whose name contains it (any case). None, or
/// several, is an error listing the ports.
pub fn matching_port(names: &[String], wanted: &str) -> Result<usize, String> {
    if let Some(i) = names.iter().position(|n| n == wanted) {
        return Ok(i);
    }
    let lower = wanted.to_lowercase();
    let found: Vec<usize> = (0..names.len())
        .filter(|&i| names[i].to_lowercase().contains(&lower))
        .collect();
    let listed = || {
        if names.is_empty() {
            "the sequencer has no input port".to_string()
        } else {
            format!("its ports: {}", names.join(", "))
        }
    };
    match found.as_slice() {
        [one] => Ok(*one),
        [] => Err(format!("no ALSA sequencer port {wanted:?} ({})", listed())),
        _ => Err(format!(
            "{wanted:?} names several ALSA sequencer ports ({}): give more of the name",
            found
                .iter()
                .map(|&i| names[i].as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )),
    }
}

#[cfg(feature = "alsa")]
pub use reader::{SeqReader, port_names};

#[cfg(feature = "alsa")]
mod reader {
    use super::matching_port;

    /// The sequencer, or why it cannot be opened.
    fn sequencer() -> Result<midir::MidiInput, String> {
        midir::MidiInput::new("puppetry").map_err(|e| {
            format!("the ALSA sequencer cannot be opened ({e}): is /dev/snd/seq there?")
        })
    }

    /// The sequencer's input ports, by name; an error when there is no
    /// sequencer (no `/dev/snd/seq`: a container, a machine without ALSA).
    pub fn port_names() -> Result<Vec<String>, String> {
        let input = sequencer()?;
        Ok(input
            .ports()
            .iter()
            .filter_map(|p| input.port_name(p).ok())
            .collect())
    }

    /// A connection to one sequencer port: `on_message` is called on
    /// midir's thread with each whole message until it is dropped.
    pub struct SeqReader {
        /// The port's full name, as the sequencer gives it.
        pub name: String,
        _connection: midir::MidiInputConnection<()>,
    }

    impl SeqReader {
        /// Connects to the port `wanted` names ([`matching_port`]).
        pub fn open(
            wanted: &str,
            mut on_message: impl FnMut(&[u8]) + Send + 'static,
        ) -> Result<SeqReader, String> {
            let mut input = sequencer()?;
            // Clock, time code and SysEx (show control) are read too.
            input.ignore(midir::Ignore::None);
            let ports = input.ports();
            let names: Vec<String> = ports
                .iter()
                .map(|p| input.port_name(p).unwrap_or_default())
                .collect();
            let index = matching_port(&names, wanted)?;
            let connection = input
                .connect(
                    &ports[index],
                    "puppetry",
                    move |_stamp, bytes: &[u8], _| on_message(bytes),
                    (),
                )
                .map_err(|e| format!("{}: {e}", names[index]))?;
            Ok(SeqReader {
                name: names[index].clone(),
                _connection: connection,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_are_found_by_name_or_part_of_it() {
        let names: Vec<String> = [
            "Midi Through:Midi Through Port-0 14:0",
            "nanoKONTROL2:nanoKONTROL2 nanoKONTROL2 _ CTR 20:0",
            "Ardour:MIDI clock out 128:1",
            "Ardour:MTC out 128:2",
        ]
        .map(String::from)
        .to_vec();
        assert_eq!(matching_port(&names, "nanokontrol2"), Ok(1));
        assert_eq!(matching_port(&names, "Ardour:MTC out 128:2"), Ok(3));
        let several = matching_port(&names, "ardour").unwrap_err();
        assert!(
            several.contains("several") && several.contains("MTC out"),
            "{several}"
        );
        let none = matching_port(&names, "Push 2").unwrap_err();
        assert!(none.contains("Midi Through"), "{none}");
        assert!(
            matching_port(&[], "x")
                .unwrap_err()
                .contains("no input port")
        );
    }

    /// Without a sequencer (this container has no /dev/snd) the error
    /// says what is missing instead of panicking.
    #[cfg(feature = "alsa")]
    #[test]
    fn no_sequencer_is_an_error_naming_it() {
        if std::path::Path::new("/dev/snd/seq").exists() {
            return;
        }
        let e = SeqReader::open("anything", |_| {}).err().unwrap();
        assert!(e.contains("/dev/snd/seq"), "{e}");
    }
}
