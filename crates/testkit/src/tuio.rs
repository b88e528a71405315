//! TUIO bundles built with rosc, as a touch table would send them.

use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};

/// An OSC message to `addr` carrying `args`.
pub fn msg(addr: &str, args: Vec<OscType>) -> OscPacket {
    OscPacket::Message(OscMessage {
        addr: addr.to_owned(),
        args,
    })
}

/// `content` encoded as one OSC bundle timed "immediately": the bytes of
/// one UDP datagram from a table.
pub fn bundle(content: Vec<OscPacket>) -> Vec<u8> {
    rosc::encoder::encode(&OscPacket::Bundle(OscBundle {
        timetag: OscTime::from((0, 1)),
        content,
    }))
    .unwrap()
}

/// A `/tuio/2Dcur` message: `command` (`source`, `alive`, `set`, `fseq`)
/// followed by `args`.
pub fn cur(command: &str, mut args: Vec<OscType>) -> OscPacket {
    args.insert(0, OscType::String(command.to_owned()));
    msg("/tuio/2Dcur", args)
}

/// A TUIO 1.1 bundle: optional source, alive, sets `(s_id, x, y)`, fseq.
pub fn v1(source: Option<&str>, alive: &[i32], sets: &[(i32, f32, f32)], fseq: i32) -> Vec<u8> {
    let mut content = Vec::new();
    if let Some(source) = source {
        content.push(cur("source", vec![source.into()]));
    }
    content.push(cur("alive", alive.iter().map(|&s| s.into()).collect()));
    for &(s, x, y) in sets {
        content.push(cur(
            "set",
            vec![
                s.into(),
                x.into(),
                y.into(),
                0f32.into(),
                0f32.into(),
                0f32.into(),
            ],
        ));
    }
    content.push(cur("fseq", vec![fseq.into()]));
    bundle(content)
}
