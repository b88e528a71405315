//! Contacts: how many fingers one message, one source and one datagram may
//! hold down. A hand has ten fingers and a table a few dozen; a message past
//! these is refused whole, never cut (a cut frame would drop an up).
//!
//! Why these numbers: a performer's client is one touch screen (a phone,
//! a tablet, a touch monitor); the largest of those report 40 points at
//! once (four people's hands on one 65" panel), so 40 is a generous
//! message and a generous hold for one WebSocket client. A TUIO source is
//! a table or a tracker watching a surface several people stand around: a
//! few dozen fingers, so 64. What the numbers buy: every down is a handle
//! the stage solves for, and the solve grows with the handles held — 2,000
//! contacts in one message stalled the stage 7.7 s for every puppet; 40
//! cost about as much as a busy frame of two performers.

/// Contacts in one `contacts` message of a WebSocket client (or a relay's
/// client). Past it the message is refused whole (`too_many`).
pub const MAX_CONTACTS_PER_MESSAGE: usize = 40;

/// Contacts one client may hold down at once (downs not yet lifted).
/// A message that would hold more is refused whole (`too_many`); lifting
/// some first makes room.
pub const MAX_HELD_PER_CLIENT: usize = 40;

/// Handles one puppet may hold at once (contacts and pins). A finger that
/// lands on a puppet holding this many holds nothing (as on empty stage)
/// until some let go. Why: the solver keeps a column of the puppet's size
/// per handle and a k × k system besides, so its memory grows with
/// vertices × handles — 400 fingers (ten performers at their 40) on a
/// 20,000-vertex puppet held 210 MB, and handles from many clients have
/// no other bound on one puppet. 128 is a dozen people's hands, every
/// finger down.
pub const MAX_HANDLES_PER_PUPPET: usize = 128;

/// Pointers (TUIO 1.1 `set`, TUIO 2 `ptr`) and alive ids in one TUIO
/// datagram, over all the frames it bundles. Past it the datagram is
/// skipped (logged), as a malformed one is.
pub const MAX_TUIO_CONTACTS_PER_DATAGRAM: usize = 256;

/// Contacts one TUIO source (a tracker, by its source name) may hold
/// alive at once. A frame stating more is skipped whole: what the source
/// held stays held until a frame within the limit restates it.
pub const MAX_TUIO_HELD_PER_SOURCE: usize = 64;

/// Contacts one input's forwarder keeps track of as down, over every
/// source its frames name (a TUIO port's senders, a recording's
/// sources), so it can lift them when the input ends however it ends:
/// every TUIO source holding its most. Past it a down is not tracked;
/// the input's own name is still released when it ends.
pub const MAX_TRACKED_PER_INPUT: usize = 4096;
