//! One conversion from whatever anyone asks of the stage to the [`Change`]
//! the stage thread applies: a browser's or a relay's message
//! (`client`), a device's frame or a source gone ([`frame`],
//! [`release`]), a show-control trigger (`change`). The stage thread
//! applies only changes, through one [`Command::Change`]; requests that
//! read state (undo's history, a key or weights file, a grid) stay
//! commands of their own. A new way in — another message, another device
//! kind — is an arm here, and a take records what it does like anything
//! else.

use glam::DVec2;
use puppetry_input::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::Change;

use crate::protocol::ClientMessage;
use crate::stage_thread::{Command, Reply};

/// What a client message is to the stage.
#[derive(Debug)]
pub(crate) enum Converted {
    /// A change to apply. `received`: when an input frame reached the
    /// daemon (seconds since it started); `wait`: the client hears whether
    /// it applied (contacts and pins, at the input rate, do not wait).
    Change {
        change: Change,
        received: Option<f64>,
        wait: bool,
    },
    /// Not a change: a request the edge answers itself.
    Other(ClientMessage),
}

/// A message that cannot be a change, naming the field at fault.
#[derive(Debug, PartialEq, thiserror::Error)]
#[error("{problem}")]
pub(crate) struct ConvertError {
    /// Where in the message (e.g. `contacts[2]`), if one field is at fault.
    pub(crate) field: Option<String>,
    pub(crate) problem: String,
}

fn refuse(problem: &str) -> ConvertError {
    ConvertError {
        field: None,
        problem: problem.into(),
    }
}

fn finite(x: f64, y: f64, problem: &str) -> Result<DVec2, ConvertError> {
    if x.is_finite() && y.is_finite() {
        Ok(DVec2::new(x, y))
    } else {
        Err(refuse(problem))
    }
}

/// A client's message from `source`, `now` seconds after the daemon
/// started, as a change, or the message back when it is not one.
pub(crate) fn client(
    message: ClientMessage,
    source: &str,
    now: f64,
) -> Result<Converted, ConvertError> {
    let (change, wait) = match message {
        ClientMessage::Contacts { contacts } => {
            let mut frame = ContactFrame {
                source: SourceId::from(source),
                time: now,
                contacts: Vec::with_capacity(contacts.len()),
            };
            for (i, c) in contacts.into_iter().enumerate() {
                let position = match (c.x, c.y) {
                    (Some(x), Some(y)) if x.is_finite() && y.is_finite() => DVec2::new(x, y),
                    (None, None) if c.phase == Phase::Up => DVec2::ZERO,
                    _ => {
                        return Err(ConvertError {
                            field: Some(format!("contacts[{i}]")),
                            problem: format!(
                                "contact {}: needs x and y (only an up may leave them out)",
                                c.id
                            ),
                        });
                    }
                };
                frame.contacts.push(Contact::new(c.id, c.phase, position));
            }
            return Ok(Converted::Change {
                change: Change::Contacts { frame },
                received: Some(now),
                wait: false,
            });
        }
        ClientMessage::Pin { x, y } => (
            Change::Pin {
                owner: source.to_string(),
                at: finite(x, y, "pin needs finite x and y")?,
            },
            false,
        ),
        ClientMessage::DepthFlip { x, y } => (
            Change::DepthFlip {
                at: finite(x, y, "depth_flip needs finite x and y")?,
            },
            false,
        ),
        ClientMessage::Unpin { puppet, handle } => (Change::Unpin { puppet, handle }, false),
        // A director lets go of what a source holds, as if it had gone.
        ClientMessage::Release { source } => (Change::Release { source }, true),
        // The stage bounds the brushes (`radius`, `strength`, `layer`) and
        // names the field it refuses.
        ClientMessage::Paint {
            puppet,
            x,
            y,
            radius,
            strength,
            stroke,
        } => (
            Change::Paint {
                puppet,
                at: finite(x, y, "paint needs finite x and y")?,
                radius,
                strength,
                stroke,
                painter: Some(source.to_string()),
            },
            true,
        ),
        ClientMessage::PaintDepth {
            puppet,
            x,
            y,
            radius,
            layer,
            stroke,
        } => (
            Change::PaintDepth {
                puppet,
                at: finite(x, y, "paint_depth needs finite x and y")?,
                radius,
                layer,
                stroke,
                painter: Some(source.to_string()),
            },
            true,
        ),
        ClientMessage::Pose {
            puppet,
            from,
            to,
            t,
        } => (key_pose(puppet, from, to, t)?, true),
        ClientMessage::Cursor { puppet, at } => (cursor(puppet, at.map(DVec2::from)), true),
        ClientMessage::KeyAdd { puppet, name, at } => (
            Change::KeyAdd {
                puppet,
                name: name.unwrap_or_else(|| unnamed_key(now)),
                at: DVec2::from(at),
            },
            true,
        ),
        ClientMessage::KeyMove { puppet, key, at } => (
            Change::KeyMove {
                puppet,
                key,
                at: DVec2::from(at),
            },
            true,
        ),
        ClientMessage::KeyDelete { puppet, key } => (Change::KeyDelete { puppet, key }, true),
        other => return Ok(Converted::Other(other)),
    };
    Ok(Converted::Change {
        change,
        received: None,
        wait,
    })
}

/// A skeleton set `t` of the way from key pose `from` to `to`, as a
/// client's `pose` and a show desk's `/pose` and key glides ask.
pub(crate) fn key_pose(
    puppet: u32,
    from: String,
    to: String,
    t: f64,
) -> Result<Change, ConvertError> {
    if !t.is_finite() {
        return Err(refuse("pose needs a finite t"));
    }
    Ok(Change::KeyPose {
        puppet,
        from,
        to,
        t,
    })
}

/// The keyframing cursor moved (pad coordinates) or let go (`None`), from
/// a client or a show desk.
pub(crate) fn cursor(puppet: u32, at: Option<DVec2>) -> Change {
    Change::Cursor { puppet, at }
}

/// A key added without a name is named by the time, so two differ.
fn unnamed_key(now: f64) -> String {
    let wall = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis())
        .unwrap_or((now * 1000.0) as u128);
    format!("key {}", wall % 100_000)
}

/// A device's (or a replay's) frame, `received` seconds after the daemon
/// started.
pub fn frame(frame: ContactFrame, received: f64) -> Command {
    Command::Change {
        change: Change::Contacts { frame },
        received: Some(received),
        reply: None,
    }
}

/// A source went away (unplugged, closed, timed out): all it held lifts.
pub fn release(source: &str) -> Command {
    change(
        Change::Release {
            source: source.to_string(),
        },
        None,
    )
}

/// Any other change, with the asker's reply if it waits.
pub(crate) fn change(change: Change, reply: Option<Reply<()>>) -> Command {
    Command::Change {
        change,
        received: None,
        reply,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::ClientContact as ContactIn;

    #[test]
    fn a_contact_without_a_position_is_refused_naming_it_unless_it_lifts() {
        let contact = |phase, x: Option<f64>| ContactIn {
            id: 7,
            phase,
            x,
            y: x,
        };
        let bad = ClientMessage::Contacts {
            contacts: vec![contact(Phase::Down, Some(1.0)), contact(Phase::Move, None)],
        };
        let error = client(bad, "client:1", 0.5).unwrap_err();
        assert_eq!(error.field.as_deref(), Some("contacts[1]"));
        let up = ClientMessage::Contacts {
            contacts: vec![contact(Phase::Up, None)],
        };
        let Ok(Converted::Change {
            change: Change::Contacts { frame },
            received: Some(t),
            wait: false,
        }) = client(up, "client:1", 0.5)
        else {
            panic!("an up without a position is a frame");
        };
        assert_eq!((frame.source.as_str(), t), ("client:1", 0.5));
    }

    #[test]
    fn brushes_and_poses_wait_and_requests_are_not_changes() {
        let pose = ClientMessage::Pose {
            puppet: 0,
            from: "rest".into(),
            to: "cheer".into(),
            t: f64::NAN,
        };
        assert!(client(pose, "c", 0.0).is_err());
        let dab = ClientMessage::Paint {
            puppet: 0,
            x: 1.0,
            y: 2.0,
            radius: 10.0,
            strength: 0.5,
            stroke: None,
        };
        // The dab is the client's: its strokes are numbered by its page.
        assert!(matches!(
            client(dab, "c", 0.0),
            Ok(Converted::Change {
                wait: true,
                change: Change::Paint { painter: Some(p), .. },
                ..
            }) if p == "c"
        ));
        assert!(matches!(
            client(ClientMessage::ListTakes, "c", 0.0),
            Ok(Converted::Other(ClientMessage::ListTakes))
        ));
    }
}
