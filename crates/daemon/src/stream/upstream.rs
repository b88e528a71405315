//! A stage this process does not run, as the stream sees it: a relay's link
//! to the daemon over NATS. The stream serves a relay's viewers with the
//! same code as the daemon's own clients, and reaches the stage through
//! these two traits only, so `stream` does not name `relay` (the relay
//! implements them; the dependency runs one way).

use bytes::Bytes;
use futures_util::future::BoxFuture;

use super::guard::Refusal;
use super::{Admission, JoinRefused, Joined};
use crate::protocol::Role;

/// A client seated on a stage elsewhere, with what the stage said of it;
/// or why it was refused.
pub type Seated = Result<(Box<dyn UpstreamSeat>, Joined), JoinRefused>;

/// A link to a stage elsewhere.
pub trait Upstream: Send + Sync {
    /// Who may open the WebSocket, as the stage says now.
    fn admission(&self) -> Admission;

    /// Seats client `client`, which said hello as `asked` with `token`.
    fn join(&self, client: u64, asked: Role, token: Option<String>) -> BoxFuture<'_, Seated>;

    /// Puppet `id`'s picture (none: no such puppet, or the stage did not
    /// answer).
    fn picture(&self, id: u32) -> BoxFuture<'_, Option<Bytes>>;
}

/// A client's place on a stage elsewhere; dropped when the client leaves.
pub trait UpstreamSeat: Send + Sync {
    /// The client's source name (its handles' owner).
    fn source(&self) -> &str;

    /// One text message of the client: the answer to send back, if any.
    fn handle<'a>(&'a self, text: &'a str) -> BoxFuture<'a, Result<Option<String>, Refusal>>;
}
