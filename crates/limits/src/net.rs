//! The network edge: connections per address and in all, and how long a
//! connection may take to send its headers or stay silent.
//!
//! The total (`[stage] max_connections`) and the WebSockets per address
//! (`[access] max_per_address`) are the stage file's; what is here holds
//! for every stage: a connection that trickles its request, sits silent,
//! or stops reading its WebSocket gives its place back within seconds, and
//! one address cannot take every place with plain HTTP connections.

use std::time::Duration;

/// A connection must send a whole request head (request line and headers)
/// within this long of the server starting to wait for it: from the
/// connection's opening, and again after each answer on a kept-alive
/// connection. So a silent connection, an idle kept-alive one and one
/// trickling a header line every few seconds (slowloris) are all closed
/// after it. A browser sends its head in one packet.
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);

/// Connections one address may hold open beyond its WebSockets' cap
/// (`[access] max_per_address`): page loads, pictures, exports. Past it a
/// new connection is answered 503 and closed. A browser opens at most six
/// per host at once; sixteen leaves room for a few tabs.
pub const HTTP_PER_ADDRESS: usize = 16;

/// The daemon pings every WebSocket this often; one that has not answered
/// the last ping by the next (it stopped reading) is closed. Frames are
/// dropped for a slow reader already, and a send that blocks is cut after
/// `[stage] client_timeout_s`: this catches the one that reads nothing
/// while the stage is still.
pub const WEBSOCKET_PING_EVERY: Duration = Duration::from_secs(20);

/// The most characters of a stranger's input (a client message's field, a
/// datagram's address, a device's line) quoted back in an error or a log
/// line; longer input is cut with "…". One limit for every door, so no
/// input of any length makes a message of that length.
pub const MAX_ECHO: usize = 200;

/// The longest text message a client may send on the WebSocket (or a
/// relay take from a viewer); a longer one closes the connection with
/// 1009. The largest real message, 40 contacts, is under 4 KiB.
pub const MAX_CLIENT_MESSAGE_BYTES: usize = 64 * 1024;

/// The largest picture a director may POST to add a puppet; the body is
/// not read past it. Its pixels are then checked against
/// `files::MAX_PICTURE_PIXELS` from the header before it is decoded.
pub const MAX_UPLOAD_BYTES: usize = 16 << 20;
