//! The wire protocol between the daemon and its clients, in one place: the
//! typed text messages each way ([`ServerMessage`], [`ClientMessage`]) and
//! the binary frame ([`FrameHeader`], [`encode_frame`], [`decode_frame`]).
//! `docs/protocol.md` describes it and a test parses every example there
//! into these types; the daemon's `javascript` writes the browser's names
//! and numbers of it (`clients/web/wire.js`) from these types, and
//! `clients/web/protocol.js` builds and reads messages with them.
//! The daemon, the benchmark client and the tests all speak through here,
//! so no message is built or read by hand anywhere else.

use bytes::{BufMut, Bytes, BytesMut};
use glam::DVec2;
use puppetry_contact::Phase;
use serde::{Deserialize, Serialize};

/// Declares an enum whose variants go on the wire by their snake_case
/// names and into the generated `clients/web/wire.js` with their doc
/// comments (strum's `EnumMessage`): one list of what such an enum
/// derives, for every enum the browser names.
macro_rules! wire_enum {
    ($(#[$meta:meta])* $vis:vis enum $name:ident { $($body:tt)* }) => {
        $(#[$meta])*
        #[derive(
            Debug,
            Clone,
            Copy,
            PartialEq,
            Eq,
            Serialize,
            Deserialize,
            strum::EnumIter,
            strum::IntoStaticStr,
            strum::EnumMessage,
        )]
        #[serde(rename_all = "snake_case")]
        #[strum(serialize_all = "snake_case")]
        $vis enum $name { $($body)* }
    };
}

/// Size of a binary frame's header.
pub const FRAME_HEADER_BYTES: usize = 32;

/// Where each field of a frame header starts (bytes, little-endian):
/// `kind` u32, `puppet` u32, `sequence` u64, `input_time` f64, `count`
/// u32, `generation` u32.
pub mod header {
    /// The frame's [`FrameKind`](super::FrameKind) code, u32.
    pub const KIND: usize = 0;
    /// The puppet's index in the lineup, u32.
    pub const PUPPET: usize = 4;
    /// The puppet's frame sequence number, u64.
    pub const SEQUENCE: usize = 8;
    /// When the input that caused it reached the daemon, seconds, f64.
    pub const INPUT_TIME: usize = 16;
    /// How many points (or depths) follow, u32.
    pub const COUNT: usize = 24;
    /// A handles or depth frame's generation, u32.
    pub const GENERATION: usize = 28;
}

/// Adding a puppet over HTTP: a director POSTs a PNG to [`upload::PATH`]
/// (`?name=…&vertices=…[&x=…&y=…&scale=…]`, the director's bearer token);
/// the answer is [`ServerMessage::PuppetAdded`] or an `error`.
pub mod upload {
    /// Where the picture is POSTed.
    pub const PATH: &str = "/puppets";
    /// The vertex counts a director may ask for: enough to bend, few
    /// enough that the stage keeps its frame rate.
    pub const MIN_VERTICES: usize = 50;
    /// The most vertices a director may ask for.
    pub const MAX_VERTICES: usize = 20_000;
    /// The count when none is asked for (the page's default too).
    pub const DEFAULT_VERTICES: usize = 1000;
}

/// Close frame codes the daemon sends (RFC 6455 and the application range).
pub mod close {
    /// A rule was broken: a foreign origin, no hello, too many bad
    /// messages, a ping left unanswered (the client stopped reading).
    pub const POLICY: u16 = 1008;
    /// A message too large to read.
    pub const TOO_LARGE: u16 = 1009;
    /// Too many connections (from this address, or in total).
    pub const TRY_AGAIN_LATER: u16 = 1013;
    /// The hello's token was refused.
    pub const TOKEN_REFUSED: u16 = 4001;
}

/// What a binary frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// The deformed vertices of a puppet (kind 1).
    Vertices,
    /// The deformed grid handles or posed joints of a rigged puppet (kind 2).
    Rig,
    /// Where each handle of a puppet is on the solved puppet (kind 3), in
    /// the order of the `handles` message whose generation the header
    /// carries.
    Handles,
    /// The depth of each triangle of a puppet (kind 4): `count` u16 values,
    /// larger is nearer, padded to a multiple of 4 bytes; the header's
    /// generation says which depth it is. Sent when the depth changes.
    Depth,
    /// A kind this build does not know; clients skip it.
    Other(u32),
}

impl FrameKind {
    /// Every kind this build sends.
    pub const KNOWN: [FrameKind; 4] = [
        FrameKind::Vertices,
        FrameKind::Rig,
        FrameKind::Handles,
        FrameKind::Depth,
    ];

    /// The kind's number, as the header's first u32 carries it.
    pub fn code(self) -> u32 {
        match self {
            FrameKind::Vertices => 1,
            FrameKind::Rig => 2,
            FrameKind::Handles => 3,
            FrameKind::Depth => 4,
            FrameKind::Other(code) => code,
        }
    }

    /// The kind a header's number means; a number this build does not
    /// know is [`FrameKind::Other`], which clients skip.
    pub fn from_code(code: u32) -> FrameKind {
        match code {
            1 => FrameKind::Vertices,
            2 => FrameKind::Rig,
            3 => FrameKind::Handles,
            4 => FrameKind::Depth,
            other => FrameKind::Other(other),
        }
    }
}

/// The 32-byte little-endian header of a binary frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameHeader {
    /// What the frame carries (byte 0).
    pub kind: FrameKind,
    /// The puppet's id, as the `stage` message lists it (ids are never
    /// reused).
    pub puppet: u32,
    /// Per puppet, increasing; a rig frame shares its vertex frame's.
    pub sequence: u64,
    /// When the input that caused the solve reached the daemon (seconds
    /// since it started).
    pub input_time: f64,
    /// Points that follow the header (f32 x, y pairs); a depth frame's
    /// triangles (u16 depths).
    pub count: u32,
    /// A handles frame: the generation of the handle set its points follow
    /// (the `handles` message's); 0 in other frames.
    pub generation: u32,
}

impl FrameHeader {
    /// Appends the header to `out` (in the order of `header`'s offsets;
    /// a test reads each field back at its offset).
    pub fn encode_into(&self, out: &mut BytesMut) {
        out.put_u32_le(self.kind.code());
        out.put_u32_le(self.puppet);
        out.put_u64_le(self.sequence);
        out.put_f64_le(self.input_time);
        out.put_u32_le(self.count);
        out.put_u32_le(self.generation);
    }

    /// Reads a header from the start of `bytes`.
    pub fn decode(bytes: &[u8]) -> Result<FrameHeader, FrameError> {
        let head: &[u8; FRAME_HEADER_BYTES] = bytes
            .get(..FRAME_HEADER_BYTES)
            .and_then(|h| h.try_into().ok())
            .ok_or(FrameError::Short {
                length: bytes.len(),
            })?;
        let u32_at =
            |o: usize| u32::from_le_bytes([head[o], head[o + 1], head[o + 2], head[o + 3]]);
        let eight = |o: usize| -> [u8; 8] { head[o..o + 8].try_into().expect("8 bytes") };
        Ok(FrameHeader {
            kind: FrameKind::from_code(u32_at(header::KIND)),
            puppet: u32_at(header::PUPPET),
            sequence: u64::from_le_bytes(eight(header::SEQUENCE)),
            input_time: f64::from_le_bytes(eight(header::INPUT_TIME)),
            count: u32_at(header::COUNT),
            generation: u32_at(header::GENERATION),
        })
    }
}

/// A binary frame that does not decode.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    /// Too few bytes to hold even the header.
    #[error("frame of {length} bytes is shorter than its 32-byte header")]
    Short {
        /// The frame's length, bytes.
        length: usize,
    },
    /// The frame is not as long as its header's count says.
    #[error("frame says {count} points ({expected} bytes) but has {length} bytes")]
    Length {
        /// Points (or, in a depth frame, depths) the header says follow.
        count: u32,
        /// Bytes that count makes, header and padding included.
        expected: usize,
        /// Bytes the frame has.
        length: usize,
    },
}

/// Encodes a frame: the header (its `count` taken from `points`), then the
/// points as f32 pairs. Encoded once per solve and shared by every client.
pub fn encode_frame(
    kind: FrameKind,
    puppet: u32,
    sequence: u64,
    input_time: f64,
    points: &[DVec2],
) -> Bytes {
    encode_frame_of(kind, puppet, sequence, input_time, 0, points)
}

/// [`encode_frame`] with the header's `generation` (handles frames).
pub fn encode_frame_of(
    kind: FrameKind,
    puppet: u32,
    sequence: u64,
    input_time: f64,
    generation: u32,
    points: &[DVec2],
) -> Bytes {
    let header = FrameHeader {
        kind,
        puppet,
        sequence,
        input_time,
        count: points.len() as u32,
        generation,
    };
    let mut out = BytesMut::new();
    write_frame(&mut out, &header, points);
    out.freeze()
}

/// Encodes a frame of `points` (the header's count is theirs) from
/// `arena`, a buffer kept for one stream of frames: once every frame split
/// from it earlier is gone (clients drop theirs once sent), its storage is
/// reclaimed, and the frame shares it with a reference count. A publisher
/// that alternates two arenas per stream encodes without allocating.
pub fn encode_frame_into(arena: &mut BytesMut, header: &FrameHeader, points: &[DVec2]) -> Bytes {
    write_frame(arena, header, points);
    arena.split().freeze()
}

fn write_frame(out: &mut BytesMut, header: &FrameHeader, points: &[DVec2]) {
    let length = FRAME_HEADER_BYTES + points.len() * 8;
    out.clear();
    out.reserve(length);
    FrameHeader {
        count: points.len() as u32,
        ..*header
    }
    .encode_into(out);
    // Zeroed then written in place: plain stores, where a `put` per
    // number checks capacity and copies four bytes at a time.
    out.resize(length, 0);
    for (slot, p) in out[FRAME_HEADER_BYTES..].chunks_exact_mut(8).zip(points) {
        slot[..4].copy_from_slice(&(p.x as f32).to_le_bytes());
        slot[4..].copy_from_slice(&(p.y as f32).to_le_bytes());
    }
}

/// A depth frame (kind 4) of a puppet: the depth of each triangle.
pub fn encode_depth_frame(puppet: u32, sequence: u64, generation: u32, depth: &[u16]) -> Bytes {
    let payload = depth_payload_bytes(depth.len());
    let mut out = BytesMut::with_capacity(FRAME_HEADER_BYTES + payload);
    FrameHeader {
        kind: FrameKind::Depth,
        puppet,
        sequence,
        input_time: 0.0,
        count: depth.len() as u32,
        generation,
    }
    .encode_into(&mut out);
    for &d in depth {
        out.put_u16_le(d);
    }
    // Padding keeps every frame a whole number of 4-byte words.
    out.put_bytes(0, payload - depth.len() * 2);
    out.freeze()
}

fn depth_payload_bytes(count: usize) -> usize {
    (count * 2).div_ceil(4) * 4
}

/// A decoded frame: its header and its points (or, for a depth frame, its
/// depths).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The header, as sent.
    pub header: FrameHeader,
    /// The points, stage coordinates (read back from f32); empty for a
    /// depth frame.
    pub points: Vec<DVec2>,
    /// A depth frame's depth of each triangle, in mesh order, larger
    /// nearer; empty for other kinds.
    pub depths: Vec<u16>,
}

/// Decodes a whole frame, checking that its length matches its count.
pub fn decode_frame(bytes: &[u8]) -> Result<Frame, FrameError> {
    let header = FrameHeader::decode(bytes)?;
    let depth = header.kind == FrameKind::Depth;
    let expected = FRAME_HEADER_BYTES
        + if depth {
            depth_payload_bytes(header.count as usize)
        } else {
            header.count as usize * 8
        };
    if bytes.len() != expected {
        return Err(FrameError::Length {
            count: header.count,
            expected,
            length: bytes.len(),
        });
    }
    if depth {
        let depths = (0..header.count as usize)
            .map(|i| {
                let o = FRAME_HEADER_BYTES + 2 * i;
                u16::from_le_bytes([bytes[o], bytes[o + 1]])
            })
            .collect();
        return Ok(Frame {
            header,
            points: Vec::new(),
            depths,
        });
    }
    let f32_at =
        |o: usize| f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let points = (0..header.count as usize)
        .map(|i| {
            let o = FRAME_HEADER_BYTES + 8 * i;
            DVec2::new(f64::from(f32_at(o)), f64::from(f32_at(o + 4)))
        })
        .collect();
    Ok(Frame {
        header,
        points,
        depths: Vec::new(),
    })
}

/// What a client may do (`docs/protocol.md`, "Roles").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Watches only.
    Viewer,
    /// Performs: contacts, pins, poses, cursors (maybe on some puppets).
    Performer,
    /// Everything a performer does, and takes, painting, saving, key poses.
    Director,
}

wire_enum! {
    /// A role in the `people` list: a client's ([`Role`]'s `Viewer`,
    /// `Performer` or `Director`, converted by `From`), or `Device` for the
    /// stage's own input sources.
    pub enum PersonRole {
        /// Watches only.
        Viewer,
        /// Performs: contacts, pins, poses, cursors (maybe on some puppets).
        Performer,
        /// Everything a performer does, and takes, painting, saving, key poses.
        Director,
        /// One of the stage's own input sources (a touch table, a pad, a replay).
        Device,
    }
}

impl From<Role> for PersonRole {
    fn from(role: Role) -> PersonRole {
        match role {
            Role::Viewer => PersonRole::Viewer,
            Role::Performer => PersonRole::Performer,
            Role::Director => PersonRole::Director,
        }
    }
}

/// Someone on the stage: a connected client or an input source. Handle
/// owners are looked up here for a name and colour.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Person {
    /// `client:N` or the source's name, as handles' `owner`.
    pub owner: String,
    /// The name pages show: the stage file's name for a person,
    /// `performer N` for an anonymous performer, the source's name for a
    /// device.
    pub name: String,
    /// What they may do; `device` for an input source.
    pub role: PersonRole,
    /// `#RRGGBB`.
    pub colour: String,
}

wire_enum! {
    /// Why something a client sent was refused (`error` messages' `code`).
    pub enum ErrorCode {
        /// Not JSON, or not a message of the protocol.
        BadMessage,
        /// Longer than 64 KiB.
        TooLarge,
        /// A binary message (clients send text).
        Binary,
        /// The client's role may not send this message (or not for this puppet).
        Forbidden,
        /// The hello's token is not one of the stage's.
        BadToken,
        /// A number is not finite or is too large (coordinates: |v| ≤ 1e6).
        OutOfRange,
        /// More than the resource budget allows (`docs/limits.md`): contacts
        /// in one message, or held down at once.
        TooMany,
        /// No such puppet, take, key, handle…
        NotFound,
        /// Something else is running (a take, an export).
        Busy,
        /// An action that failed (a file that could not be written, …).
        Failed,
        /// The first message was not a hello.
        Hello,
        /// An uploaded picture is not a PNG, or cannot be made a puppet.
        BadImage,
        /// An HTTP request's parameters are missing or not well-formed.
        BadRequest,
    }
}

fn one_piece() -> usize {
    1
}

/// What a client sends (text).
#[derive(
    Debug, Clone, PartialEq, Serialize, Deserialize, strum::VariantNames, strum::IntoStaticStr,
)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
#[strum(serialize_all = "snake_case")]
pub enum ClientMessage {
    /// The first message of every connection.
    Hello {
        /// The role asked for. With a token, the token's person's role
        /// decides; a `viewer` hello stays a viewer whatever its token.
        role: Role,
        /// A performer's or person's token from the stage file's
        /// `[access]`; none for a viewer.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        token: Option<String>,
    },
    /// One input frame of the client's own contacts.
    Contacts {
        /// The contacts that changed, each id at most once (at most
        /// `puppetry_limits::contacts::MAX_CONTACTS_PER_MESSAGE`).
        contacts: Vec<ClientContact>,
    },
    /// A pin at a stage point, on the topmost puppet there.
    Pin {
        /// Stage units.
        x: f64,
        /// Stage units, y up.
        y: f64,
    },
    /// "This part in front": where a puppet overlaps itself at the point,
    /// the part behind comes in front until the overlap is undone.
    DepthFlip {
        /// Stage units.
        x: f64,
        /// Stage units, y up.
        y: f64,
    },
    /// Remove a pin, the stage file's included.
    Unpin {
        /// The puppet the pin holds.
        puppet: u32,
        /// The pin's handle id ([`HandleView::id`]).
        handle: u64,
    },
    /// One dab of the stiffness brush; the dabs of one `stroke` undo at
    /// once.
    Paint {
        /// The puppet painted.
        puppet: u32,
        /// Centre of the dab, stage units.
        x: f64,
        /// Centre of the dab, stage units, y up.
        y: f64,
        /// Stage units: above 0, at most the stage's larger side.
        radius: f64,
        /// The weight factor at the centre (0.001 to 1000): above 1
        /// stiffens, below 1 softens.
        strength: f64,
        /// Any number the client picks per drag; none: the dab is a step
        /// of its own.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stroke: Option<u64>,
    },
    /// One dab of the depth-layer brush (directors): the triangles under
    /// it take `layer` as their static depth, larger nearer; the dabs of
    /// one `stroke` undo at once.
    PaintDepth {
        /// The puppet painted.
        puppet: u32,
        /// Centre of the dab, stage units.
        x: f64,
        /// Centre of the dab, stage units, y up.
        y: f64,
        /// Stage units.
        radius: f64,
        /// The depth layer given, 0 to 32767.
        layer: u16,
        /// As [`ClientMessage::Paint`]'s.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stroke: Option<u64>,
    },
    /// A curve puppet drawn on the page (directors): its centre line in
    /// stage coordinates, a stroke `width` wide in `colour` (`#RRGGBB`).
    AddCurve {
        /// The new puppet's name.
        name: String,
        /// The centre line, stage coordinates (3 to 4000 points).
        points: Vec<[f64; 2]>,
        /// Stage units: above 0, at most 200.
        width: f64,
        /// `#RRGGBB`.
        colour: String,
    },
    /// Take back the puppet's last edit (paint stroke, pin, pose).
    Undo {
        /// Whose history (each puppet keeps its own).
        puppet: u32,
    },
    /// Do again what the last undo took back.
    Redo {
        /// Whose history.
        puppet: u32,
    },
    /// Weights as loaded, pins as in the stage file, the skeleton at rest,
    /// the key cursor let go (one undo step).
    Reset {
        /// The puppet put back.
        puppet: u32,
    },
    /// Let go of everything a source holds (directors): a sender that
    /// went silent, a stuck device, another page. Its contacts lift as if
    /// it had gone; what it does next lands afresh.
    Release {
        /// The source, as handles name their owner ([`HandleView::owner`]:
        /// `tuio:table`, `client:3`, an input's name).
        source: String,
    },
    /// Play or pause one of the stage's replay inputs.
    Replay {
        /// The replay input's name ([`ReplayView::name`]).
        source: String,
        /// Play it (from its beginning), or pause it (what it holds lets
        /// go).
        playing: bool,
    },
    /// Write the puppet's mesh with its painted weights to a new file
    /// beside its mesh file (answered with `weights_saved`).
    SaveWeights {
        /// The puppet whose weights are saved.
        puppet: u32,
    },
    /// Ask for a grid puppet's grid handles, rest and deformed (answered
    /// with `grid`; viewers may ask too).
    ExportGrid {
        /// A grid puppet.
        puppet: u32,
    },
    /// A skeleton's pose `t` of the way between two key poses.
    Pose {
        /// A skeleton puppet.
        puppet: u32,
        /// The key pose at `t = 0` (one of its rig's `poses`).
        from: String,
        /// The key pose at `t = 1`.
        to: String,
        /// How far from `from` to `to`; outside 0 to 1 extrapolates.
        t: f64,
    },
    /// Start recording a take (named, or `take-NNN`).
    Record {
        /// Letters, digits, `-`, `_` and `.`; none: the next free
        /// `take-NNN`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
    },
    /// Stop the take being recorded.
    StopRecording,
    /// List the takes in the daemon's takes folder.
    ListTakes,
    /// Play a take into the stage. With `overdub`, a new take records the
    /// played motion and the live hands together. Contacts of the played
    /// take from `replace_sources`, or that grabbed a material point within
    /// a `replace` region, are left out: the live performer replaces them.
    Play {
        /// The take's name, as `list_takes` lists it.
        take: String,
        /// Record a new take of the played motion and the live hands
        /// together, stopping when the played take ends.
        #[serde(default)]
        overdub: bool,
        /// Discs of the rest shapes: played contacts that grabbed a
        /// material point inside one are left out.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        replace: Vec<Region>,
        /// Recorded sources whose contacts are left out.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        replace_sources: Vec<String>,
    },
    /// Stop playing (and, if overdubbing, recording).
    StopPlaying,
    /// Take a puppet off the stage (directors). Its id is not reused.
    RemovePuppet {
        /// The puppet taken off.
        puppet: u32,
    },
    /// The draw order: every puppet on stage once, bottom to top
    /// (directors).
    OrderPuppets {
        /// Puppet ids, bottom to top.
        order: Vec<u32>,
    },
    /// Move a puppet's keyframing cursor (pad coordinates `[0, 1]²`), or
    /// let it go (`at` left out).
    Cursor {
        /// The puppet whose cursor it is.
        puppet: u32,
        /// The pad point, y up (a point off the pad is taken to its
        /// edge); none: let go.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        at: Option<[f64; 2]>,
    },
    /// A key pose of the puppet as it is now, at a pad point.
    KeyAdd {
        /// The puppet keyed.
        puppet: u32,
        /// None: named by the time it was added.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        /// Where on the pad (`[0, 1]²`, y up).
        at: [f64; 2],
    },
    /// Move a key pose to another pad point.
    KeyMove {
        /// The puppet whose key it is.
        puppet: u32,
        /// The key's index, as the `keys` message lists it.
        key: usize,
        /// The new pad point.
        at: [f64; 2],
    },
    /// Remove a key pose.
    KeyDelete {
        /// The puppet whose key it is.
        puppet: u32,
        /// The key's index, as the `keys` message lists it.
        key: usize,
    },
    /// Write the puppet's key poses to its key file.
    SaveKeys {
        /// The puppet whose keys are saved.
        puppet: u32,
    },
    /// Answered at once with a `pong` carrying the same `t` (latency).
    Ping {
        /// Any number (the page sends its own clock), echoed back.
        t: f64,
    },
    /// Learn a MIDI mapping (directors): the next control moved on any
    /// of the stage's MIDI inputs does `target`, at once and in the stage
    /// file it is saved to; without a target, stop waiting. The `inputs`
    /// message says what is awaited and what was learnt.
    MidiLearn {
        /// What the control will do: an `[[input.map]]` entry without
        /// its control (no `cc`, `note`, `program`, `pitch_bend`, `msc` or
        /// `channel`); none: stop waiting.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        target: Option<puppetry_input::midi_map::MidiMapping>,
    },
}

/// A key pose on the pad.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyView {
    /// The key pose's name.
    pub name: String,
    /// Where it sits on the pad, `[0, 1]²`, y up.
    pub at: [f64; 2],
}

/// A disc of a puppet's rest shape (stage coordinates of the rest mesh).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Region {
    /// The puppet whose rest shape it is on.
    pub puppet: u32,
    /// The disc's centre.
    pub at: [f64; 2],
    /// Stage units.
    pub radius: f64,
}

/// The take state every client sees.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeState {
    /// The take being recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recording: Option<String>,
    /// Seconds it has been recording when this was sent.
    #[serde(default)]
    pub elapsed: f64,
    /// The take being played.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub playing: Option<String>,
    /// Seconds into the take playing when this was sent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub played: Option<f64>,
    /// The daemon's clock when this was sent (seconds, as `pong`'s): with
    /// `elapsed` and `played` it says when the takes began, so a page
    /// joining later plays a soundtrack from where the take is.
    #[serde(default)]
    pub clock: f64,
    /// Why the last take stopped early (a full disk, …).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// An export's progress (sent to everyone).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportState {
    /// The take exported.
    pub take: String,
    /// The export route's `format=` (`glb`, `mp4`, …).
    pub format: String,
    /// Frames (or chunks) done of `total`.
    pub done: usize,
    /// Frames (or chunks) in all.
    pub total: usize,
    /// The export ended, done or failed.
    pub finished: bool,
    /// Why it failed; none while it runs and when it succeeded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// A take in the `takes` list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeView {
    /// Its file name without `.take` (what `play` names).
    pub name: String,
    /// Seconds from its start to its last step or frame.
    pub duration: f64,
    /// Steps recorded: one per solve, with the changes applied before it.
    pub steps: usize,
    /// Vertex frames recorded.
    pub frames: usize,
    /// "stopped", "shutdown", an error, "recording" (the take being
    /// recorded now), "unended" or "truncated: …".
    pub ending: String,
    /// The takes played into it as it was recorded (an overdub's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub layers: Vec<String>,
}

/// One contact of a [`ClientMessage::Contacts`]; `x`, `y` may be left out
/// of an `up`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClientContact {
    /// The client's own id for the contact, from its down to its up (the
    /// stage keeps it apart from other clients' ids).
    pub id: u32,
    /// Down, move or up.
    pub phase: Phase,
    /// Stage units; required but for an up.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x: Option<f64>,
    /// Stage units, y up; required but for an up.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y: Option<f64>,
}

/// What the daemon sends (text).
#[derive(
    Debug, Clone, PartialEq, Serialize, Deserialize, strum::VariantNames, strum::IntoStaticStr,
)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
#[strum(serialize_all = "snake_case")]
pub enum ServerMessage {
    /// The answer to `hello`: the stage and every puppet on it.
    Stage {
        /// This connection's number: its handles' owner is `client:N`.
        client: u64,
        /// The role granted (a token's person's, which may not be the
        /// hello's).
        role: Role,
        /// Who this client is on the stage (name and colour).
        you: Person,
        /// The stage's size.
        stage: StageSize,
        /// The puppets on stage, bottom to top (later ones drawn over).
        puppets: Vec<PuppetDescription>,
    },
    /// Who is on the stage: connected performers and directors, and the
    /// stage's input sources (on connecting and on every change).
    People {
        /// Performers and directors connected, then the input sources.
        people: Vec<Person>,
    },
    /// The answer to `ping`: its `t`, and the daemon's clock when it
    /// answered (seconds since it started: the clock of frames'
    /// `input_time`), so a client can place frames on its own clock.
    Pong {
        /// The ping's `t`, as sent.
        t: f64,
        /// Seconds since the daemon started, when it answered.
        clock: f64,
    },
    /// From a relay only: whether it reaches the stage. While not, the
    /// picture holds still and messages are refused; when it is back, a
    /// fresh `stage` message may follow (the daemon restarted).
    Live {
        /// The relay reaches the stage now.
        live: bool,
        /// Why it does not, for people; none when live.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        reason: Option<String>,
    },
    /// A puppet's handle set changed; `generation` is the one handles
    /// frames of this set carry.
    Handles {
        /// The puppet whose set it is.
        puppet: u32,
        /// Changes (wrapping) whenever the set does.
        generation: u32,
        /// The whole set, in the order handles frames give their points.
        handles: Vec<HandleView>,
    },
    /// Undo and redo steps a puppet has (on connecting and on change).
    History {
        /// The puppet whose history it is.
        puppet: u32,
        /// Steps `undo` can take back.
        undo: usize,
        /// Steps `redo` can do again.
        redo: usize,
    },
    /// A skeleton's key-pose blend (on connecting and on change); `from`
    /// and `to` are left out at rest (never set, or reset).
    Pose {
        /// A skeleton puppet.
        puppet: u32,
        /// The key pose blended from.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        from: Option<String>,
        /// The key pose blended towards.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        to: Option<String>,
        /// How far from `from` to `to`.
        t: f64,
    },
    /// The stage's replay inputs and whether each is playing (on
    /// connecting and on change).
    Inputs {
        /// Every replay input of the stage.
        replays: Vec<ReplayView>,
        /// The stage's MIDI inputs and learning, when it has any.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        midi: Option<MidiView>,
    },
    /// Every mouse cursor on the stage.
    Cursors {
        /// One per mouse input; a mouse that goes away leaves the list.
        cursors: Vec<CursorView>,
    },
    /// A puppet's per-triangle stiffness after painting.
    Weights {
        /// The puppet painted.
        puppet: u32,
        /// One weight per triangle, in mesh order.
        weights: Vec<f64>,
    },
    /// The answer to `save_weights`.
    WeightsSaved {
        /// The puppet whose weights were saved.
        puppet: u32,
        /// The mesh file written (a new `NAME.vN.mesh.json`, unless the
        /// stage file says to overwrite).
        file: String,
    },
    /// The answer to `export_grid`.
    Grid {
        /// The grid puppet asked about.
        puppet: u32,
        /// Grid handles per row.
        columns: usize,
        /// Rows of grid handles.
        rows: usize,
        /// The handles at rest, row by row from the lower left, stage
        /// coordinates.
        rest: Vec<[f64; 2]>,
        /// The handles as deformed now, in the same order.
        grid: Vec<[f64; 2]>,
    },
    /// A puppet's key poses and keyframing cursor (on connecting and on
    /// every change).
    Keys {
        /// The puppet keyed.
        puppet: u32,
        /// Its key poses, by index (`key_move` and `key_delete` name them
        /// so).
        keys: Vec<KeyView>,
        /// The cursor on the pad; none while it is let go.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        cursor: Option<[f64; 2]>,
    },
    /// The answer to `save_keys`.
    KeysSaved {
        /// The puppet whose keys were saved.
        puppet: u32,
        /// The key file written.
        file: String,
    },
    /// The answer to `POST /puppets`: the puppet made from the picture (a
    /// fresh `stage` message with it goes to everyone). `warnings` says
    /// what about the picture may not be what was meant.
    PuppetAdded {
        /// The new puppet's id.
        puppet: u32,
        /// Its name, made unique (`-2`, `-3`, …).
        name: String,
        /// Vertices of the mesh made for it.
        vertices: usize,
        /// Triangles of that mesh.
        triangles: usize,
        /// Empty when the picture was all it seemed.
        warnings: Vec<String>,
        /// The pieces its mesh has: each moves on its own (more than one
        /// when the picture's opaque pixels are separate islands).
        #[serde(default = "one_piece")]
        pieces: usize,
        /// With more than one piece: the widest gap, in the picture's
        /// pixels, that adding it again with `join` set to this bridges
        /// to make one piece.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        join: Option<f64>,
    },
    /// Recording and playing now (sent to everyone on every change).
    Take(TakeState),
    /// How the export of a take downloading from the page is going.
    Export(ExportState),
    /// The answer to `list_takes`: every take, oldest first (unreadable
    /// files are left out and logged).
    Takes {
        /// Oldest first.
        takes: Vec<TakeView>,
    },
    /// Something the client sent could not be done.
    Error {
        /// What kind of refusal (what a page acts on).
        code: ErrorCode,
        /// What was refused and why, for people (input echoed in it is
        /// clipped).
        message: String,
        /// The field at fault, e.g. `contacts[2].y`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        field: Option<String>,
    },
}

impl ServerMessage {
    /// The message as the text sent on the wire.
    pub fn to_text(&self) -> String {
        serde_json::to_string(self).expect("server messages serialise")
    }
}

/// A replay input of the stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayView {
    /// The input's name in the stage file (what `replay` names).
    pub name: String,
    /// Playing now; false while paused, and once a replay that does not
    /// repeat has played out.
    pub playing: bool,
}

/// The stage's MIDI inputs, and a mapping being learnt from the page.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MidiView {
    /// The MIDI inputs' names.
    pub inputs: Vec<String>,
    /// What the next control moved will do (a `midi_learn` waiting).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waiting: Option<puppetry_input::midi_map::MidiMapping>,
    /// The last mapping learnt, for people: which input's control does
    /// what, and the file it was saved to.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learned: Option<String>,
    /// Why the last mapping learnt could not be saved (it works until the
    /// daemon stops).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// While waiting: the last control moved that was passed over because
    /// the input already maps it, and what it does, for people.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub passed_over: Option<String>,
}

/// The stage's size, in stage units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageSize {
    /// Stage units.
    pub width: f64,
    /// Stage units (y up, from 0 at the bottom).
    pub height: f64,
}

/// A puppet as the stage message describes it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PuppetDescription {
    /// What frames and messages name it by; never reused.
    pub id: u32,
    /// Its name in the stage file, or as added at runtime.
    pub name: String,
    /// Where its picture is served.
    pub texture: String,
    /// The rest mesh placed on the stage: x0, y0, x1, y1, …
    pub rest: Vec<f32>,
    /// Texture coordinates (v down from the picture's top), or empty.
    pub uv: Vec<f32>,
    /// Vertex indices, three per triangle.
    pub triangles: Vec<u32>,
    /// Its handles when the message was made, as the `handles` message
    /// gives them.
    pub handles: Vec<HandleView>,
    /// Per-triangle stiffness as loaded.
    pub weights: Vec<f64>,
    /// How it is rigged.
    pub rig: RigDescription,
    /// The stage's `[[pad]]` areas that drive this puppet's key cursor:
    /// a contact landing in one moves the cursor instead of grabbing, so
    /// the page draws them. Absent when none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pads: Vec<PadArea>,
}

/// A keyframing pad on the stage (`[[pad]]` in the stage file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PadArea {
    /// Lower left and upper right corners, stage units: `[x0, y0, x1, y1]`.
    pub area: [f64; 4],
    /// Only this input source's contacts drive it (none: every source's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
}

/// How a puppet is rigged.
#[derive(
    Debug, Clone, PartialEq, Serialize, Deserialize, strum::VariantNames, strum::IntoStaticStr,
)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
#[strum(serialize_all = "snake_case")]
pub enum RigDescription {
    /// Free-form (ARAP): handles hold material points; no rig frames.
    Free,
    /// A grid (lp-FFD) puppet: rig frames carry its grid handles deformed.
    Grid {
        /// Grid handles per row.
        columns: usize,
        /// Rows of grid handles.
        rows: usize,
        /// How the grid handles move the mesh.
        basis: GridBasis,
        /// The grid's lower left corner, stage coordinates.
        min: [f64; 2],
        /// The grid's upper right corner.
        max: [f64; 2],
        /// The grid handles at rest, row by row from `min`.
        rest: Vec<[f64; 2]>,
    },
    /// A skeleton puppet: rig frames carry its joints posed.
    Skeleton {
        /// How a dragged joint moves the others.
        mode: SkeletonMode,
        /// `[parent joint, child joint]` pairs.
        bones: Vec<[usize; 2]>,
        /// The joints at rest.
        rest: Vec<[f64; 2]>,
        /// The key poses a `pose` message may name.
        poses: Vec<String>,
    },
    /// A curve puppet: a stroke `width` wide along a centre line; its mesh
    /// is the ribbon along it (vertices `2i`, `2i + 1` beside point `i`).
    Curve {
        /// The stroke's width, stage units.
        width: f64,
        /// The centre line at rest (not rig points: nothing to draw or grab
        /// but the stroke itself).
        line: Vec<[f64; 2]>,
    },
}

/// How a grid puppet's handles move its mesh (`docs/rigs.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GridBasis {
    /// Tensor-product Bernstein polynomials over the grid box: smooth,
    /// every handle moves every vertex a little.
    Bernstein,
    /// Bilinear in each grid cell: a vertex follows its cell's four
    /// handles, which lie on the deformed lattice's nodes.
    Lattice,
}

/// How a skeleton puppet follows a dragged joint (`docs/rigs.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkeletonMode {
    /// The dragged joint goes where the contact goes and the others stay
    /// (the bones at it stretch).
    Free,
    /// Forward kinematics: the bone ending at the dragged joint turns
    /// about its parent joint and the bones below follow (a root moves the
    /// whole skeleton).
    Fk,
}

/// One handle as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandleView {
    /// The handle's id, unique on the stage (`unpin` names a pin by it).
    pub id: u64,
    /// `client:N`, an input source's name, or `config` for the stage
    /// file's pins.
    pub owner: String,
    /// What holds it.
    pub kind: HandleKind,
    /// Where it was held when the handle set changed.
    pub at: [f64; 2],
    /// What it holds.
    pub grip: GripKind,
    /// The grid handle's, joint's or bone's index.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub index: Option<usize>,
}

wire_enum! {
    /// What holds a handle.
    pub enum HandleKind {
        /// Held by a finger, mouse or pen (a client's or an input source's).
        Contact,
        /// Held by a pin (the stage file's or one placed since).
        Pin,
        /// Held by the keyframing cursor's blend of key poses.
        Key,
    }
}

wire_enum! {
    /// What a handle holds.
    pub enum GripKind {
        /// A material point of the mesh.
        Point,
        /// A grid handle of a grid puppet.
        Grid,
        /// A joint of a skeleton puppet.
        Joint,
        /// A point on a skeleton puppet's bone (`index`: the bone).
        Bone,
    }
}

/// A mouse cursor as clients draw it: where it is, and the pair of points
/// it holds (or would hold) around it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CursorView {
    /// The input source the mouse is.
    pub source: String,
    /// The cursor, stage coordinates.
    pub at: [f64; 2],
    /// Direction of the pair, radians counter-clockwise from +x.
    pub angle: f64,
    /// Distance between the pair's points; 0 for a one-point mouse.
    pub spacing: f64,
    /// A button is down and the points are grabbing.
    pub holding: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_round_trip_and_bad_lengths_are_named() {
        let points = [DVec2::new(1.5, -2.0), DVec2::new(1e3, 0.25)];
        let bytes = encode_frame(FrameKind::Rig, 3, 99, 1.25, &points);
        let frame = decode_frame(&bytes).unwrap();
        assert_eq!(frame.header.kind, FrameKind::Rig);
        assert_eq!(frame.header.puppet, 3);
        assert_eq!(frame.header.sequence, 99);
        assert_eq!(frame.header.input_time, 1.25);
        assert_eq!(frame.points, points);
        assert_eq!(frame.header.generation, 0);
        let handles = encode_frame_of(FrameKind::Handles, 1, 5, 0.5, 7, &points);
        let frame = decode_frame(&handles).unwrap();
        assert_eq!(frame.header.kind, FrameKind::Handles);
        assert_eq!(frame.header.generation, 7);
        assert_eq!(u32::from_le_bytes(handles[28..32].try_into().unwrap()), 7);
        assert_eq!(
            decode_frame(&bytes[..40]),
            Err(FrameError::Length {
                count: 2,
                expected: 48,
                length: 40
            })
        );
        assert_eq!(
            decode_frame(&bytes[..10]),
            Err(FrameError::Short { length: 10 })
        );
        assert_eq!(FrameKind::from_code(7), FrameKind::Other(7));
    }

    /// The header's fields sit at the offsets `header` names (and
    /// `clients/web/wire.js` tells the page).
    #[test]
    fn header_fields_sit_at_their_offsets() {
        let bytes = encode_frame_of(
            FrameKind::Handles,
            0x0102_0304,
            0x0a0b_0c0d_0e0f,
            2.5,
            9,
            &[DVec2::ZERO],
        );
        let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
        let eight = |o: usize| -> [u8; 8] { bytes[o..o + 8].try_into().unwrap() };
        assert_eq!(u32_at(header::KIND), FrameKind::Handles.code());
        assert_eq!(u32_at(header::PUPPET), 0x0102_0304);
        assert_eq!(
            u64::from_le_bytes(eight(header::SEQUENCE)),
            0x0a0b_0c0d_0e0f
        );
        assert_eq!(f64::from_le_bytes(eight(header::INPUT_TIME)), 2.5);
        assert_eq!(u32_at(header::COUNT), 1);
        assert_eq!(u32_at(header::GENERATION), 9);
        assert_eq!(header::GENERATION + 4, FRAME_HEADER_BYTES);
        for kind in FrameKind::KNOWN {
            assert_eq!(FrameKind::from_code(kind.code()), kind);
        }
    }

    /// strum's names (what `clients/web/wire.js` is written from) are
    /// serde's (what the wire carries), variant for variant.
    #[test]
    fn the_generated_names_are_the_wire_names() {
        use strum::{IntoEnumIterator, VariantNames};
        let sorted = |names: &[&str]| {
            let mut names: Vec<String> = names.iter().map(|n| n.to_string()).collect();
            names.sort();
            names
        };
        let serde_sorted = |mut names: Vec<String>| {
            names.sort();
            names
        };
        assert_eq!(
            sorted(ClientMessage::VARIANTS),
            serde_sorted(type_names::<ClientMessage>())
        );
        assert_eq!(
            sorted(ServerMessage::VARIANTS),
            serde_sorted(type_names::<ServerMessage>())
        );
        assert_eq!(
            sorted(RigDescription::VARIANTS),
            serde_sorted(tag_names::<RigDescription>("kind"))
        );
        fn units<T: IntoEnumIterator + Serialize + Into<&'static str>>() {
            for variant in T::iter() {
                let wire = serde_json::to_value(&variant).unwrap();
                let name: &'static str = variant.into();
                assert_eq!(wire, serde_json::Value::from(name));
            }
        }
        units::<PersonRole>();
        units::<ErrorCode>();
        units::<HandleKind>();
        units::<GripKind>();
    }

    #[test]
    fn unknown_fields_and_types_are_refused() {
        let ok = r#"{"type": "pin", "x": 1.0, "y": 2.0}"#;
        assert!(serde_json::from_str::<ClientMessage>(ok).is_ok());
        for bad in [
            r#"{"type": "pin", "x": 1.0, "y": 2.0, "z": 3.0}"#,
            r#"{"type": "teleport"}"#,
            r#"{"x": 1.0}"#,
        ] {
            assert!(serde_json::from_str::<ClientMessage>(bad).is_err(), "{bad}");
        }
    }

    /// `docs/protocol.md`, compiled in so editing it reruns this test.
    const DOC: &str = include_str!("../../../docs/protocol.md");

    /// The JSON values of every ```json block of the document.
    fn documented_values() -> Vec<serde_json::Value> {
        let mut values = Vec::new();
        let mut rest = DOC;
        while let Some(start) = rest.find("```json") {
            let block = &rest[start + "```json".len()..];
            let end = block.find("```").expect("a closed code block");
            for value in serde_json::Deserializer::from_str(&block[..end]).into_iter() {
                let value: serde_json::Value =
                    value.unwrap_or_else(|e| panic!("docs/protocol.md: not JSON: {e}\n{block}"));
                values.push(value);
            }
            rest = &block[end + 3..];
        }
        values
    }

    /// Equal as JSON, numbers compared as numbers (the document may write
    /// `1280` where the type writes `1280.0`).
    fn same(a: &serde_json::Value, b: &serde_json::Value) -> bool {
        use serde_json::Value;
        match (a, b) {
            (Value::Number(x), Value::Number(y)) => {
                let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
                (x - y).abs() <= 1e-6 * x.abs().max(1.0)
            }
            (Value::Array(x), Value::Array(y)) => {
                x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same(x, y))
            }
            (Value::Object(x), Value::Object(y)) => {
                x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same(v, w)))
            }
            _ => a == b,
        }
    }

    /// The `type` names a message enum accepts, read from serde's own
    /// "expected one of" list, so a new variant is never missed.
    fn type_names<T: serde::de::DeserializeOwned>() -> Vec<String> {
        tag_names::<T>("type")
    }

    /// The names an internally tagged enum accepts in its `tag` field.
    fn tag_names<T: serde::de::DeserializeOwned>(tag: &str) -> Vec<String> {
        let error = serde_json::from_value::<T>(serde_json::json!({ tag: "?" }))
            .err()
            .expect("no variant is called ?")
            .to_string();
        let list = error
            .split("expected one of ")
            .nth(1)
            .unwrap_or_else(|| panic!("serde's message changed: {error}"));
        list.split(',')
            .map(|name| name.trim().trim_matches('`').to_string())
            .map(|name| name.split('`').next().unwrap_or_default().to_string())
            .collect()
    }

    fn round_trips<T: serde::de::DeserializeOwned + Serialize>(value: &serde_json::Value) {
        let typed: T = serde_json::from_value(value.clone())
            .unwrap_or_else(|e| panic!("docs/protocol.md: {value} does not fit the type: {e}"));
        let back = serde_json::to_value(&typed).unwrap();
        assert!(
            same(value, &back),
            "docs/protocol.md: {value} reads as {back}: a field is missing from the document or the type"
        );
    }

    #[test]
    fn every_documented_message_is_a_typed_message_and_every_type_is_documented() {
        let client = type_names::<ClientMessage>();
        let server = type_names::<ServerMessage>();
        assert!(
            client.len() >= 8 && server.len() >= 7,
            "{client:?} {server:?}"
        );
        let mut seen = std::collections::BTreeSet::new();
        let mut rigs = std::collections::BTreeSet::new();
        for value in documented_values() {
            if let Some(name) = value.get("type").and_then(|t| t.as_str()) {
                if client.iter().any(|c| c == name) {
                    round_trips::<ClientMessage>(&value);
                } else {
                    round_trips::<ServerMessage>(&value);
                }
                seen.insert(name.to_string());
            } else if let Some(kind) = value.get("kind").and_then(|k| k.as_str()) {
                round_trips::<RigDescription>(&value);
                rigs.insert(kind.to_string());
            } else {
                panic!("docs/protocol.md: {value} is neither a message nor a rig");
            }
        }
        for name in client.iter().chain(&server) {
            assert!(
                seen.contains(name),
                "docs/protocol.md shows no `{name}` message"
            );
        }
        assert_eq!(
            rigs.into_iter().collect::<Vec<_>>(),
            ["curve", "free", "grid", "skeleton"],
            "every rig kind is shown"
        );
        // The frame table ends its header where the code does.
        assert!(
            DOC.contains(&format!("| {FRAME_HEADER_BYTES} | f32 × 2n |")),
            "the frame table's points start at byte {FRAME_HEADER_BYTES}"
        );
    }
}
