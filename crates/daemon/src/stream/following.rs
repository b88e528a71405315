//! What one connection follows of the puppets: its ends of every puppet's
//! output channels in one lineup, and sending what changed since it last
//! looked. A connection makes a new one, and tells its client with a fresh
//! `stage` message, whenever the lineup changes. A daemon's NATS
//! publisher follows the puppets the same way, so relays get what a
//! direct client gets.

use std::sync::Arc;
use std::time::Duration;

use axum::extract::ws::Message;
use bytes::Bytes;
use tokio::sync::watch;

use super::{Ws, feed, flush};
use crate::lineup::Lineup;
use crate::outputs::State;
use crate::protocol::{Person, Role};
use crate::stage_thread::PublishedHandles;

/// A connection's ends of one lineup's outputs, by puppet id.
pub(crate) struct Following {
    lineup: Arc<Lineup>,
    /// Ids of the puppets on stage: a removed puppet's channels are not
    /// followed (its client no longer knows it).
    on_stage: Vec<usize>,
    frames: Vec<watch::Receiver<Option<Bytes>>>,
    rigs: Vec<watch::Receiver<Option<Bytes>>>,
    handles: Vec<watch::Receiver<Arc<PublishedHandles>>>,
    weights: Vec<State>,
    keys: Vec<State>,
    handle_frames: Vec<watch::Receiver<Option<Bytes>>>,
    history: Vec<State>,
    poses: Vec<Option<State>>,
    depths: Vec<watch::Receiver<Option<Bytes>>>,
}

impl Following {
    /// Follows `lineup` with everything in it counting as new: a newcomer,
    /// or a client after a lineup change, gets the whole live state
    /// (painted weights, key poses, undo history, skeleton poses, the handle
    /// set with its generation and where each handle is, the newest frames).
    pub(crate) fn of(lineup: Arc<Lineup>) -> Following {
        fn all<T>(
            lineup: &Lineup,
            end: impl Fn(&crate::stage_thread::PuppetOutput) -> watch::Receiver<T>,
        ) -> Vec<watch::Receiver<T>> {
            lineup
                .outputs
                .iter()
                .map(|o| {
                    let mut r = end(o);
                    r.mark_changed();
                    r
                })
                .collect()
        }
        Following {
            frames: all(&lineup, |o| o.frame.clone()),
            rigs: all(&lineup, |o| o.rig.clone()),
            handles: all(&lineup, |o| o.handles.clone()),
            weights: all(&lineup, |o| o.weights.clone()),
            keys: all(&lineup, |o| o.keys.clone()),
            handle_frames: all(&lineup, |o| o.handle_frame.clone()),
            history: all(&lineup, |o| o.history.clone()),
            depths: all(&lineup, |o| o.depth.clone()),
            poses: lineup
                .outputs
                .iter()
                .map(|o| {
                    o.pose.clone().map(|mut r| {
                        r.mark_changed();
                        r
                    })
                })
                .collect(),
            on_stage: lineup
                .description
                .puppets
                .iter()
                .map(|p| p.id as usize)
                .collect(),
            lineup,
        }
    }

    /// The "stage" message of this lineup, with each puppet's handles now
    /// (the "handles" messages that follow repeat them with their text).
    pub(crate) fn stage_message(&self, client: u64, role: Role, you: Person) -> String {
        self.lineup.description.message(client, role, you, |id| {
            serde_json::to_string(&self.handles[id as usize].borrow().handles)
                .expect("handles serialise")
        })
    }

    /// The lineup followed.
    pub(crate) fn lineup(&self) -> &Arc<Lineup> {
        &self.lineup
    }

    /// Whatever of puppet `i` changed since the last call, in the order
    /// clients need it (the handle set before frames of its generation),
    /// each the newest, never a backlog. An empty text is nothing yet (a
    /// relay's channels before the daemon's first message).
    pub(crate) fn changed(&mut self, i: usize) -> [Option<Payload>; STREAMS.len()] {
        let mut out: [Option<Payload>; STREAMS.len()] = Default::default();
        out[0] = newest(&mut self.frames[i]).map(Payload::Binary);
        // The depth to draw the vertices with.
        out[1] = newest(&mut self.depths[i]).map(Payload::Binary);
        out[2] = newest(&mut self.rigs[i]).map(Payload::Binary);
        out[3] = newest_text(&mut self.keys[i]).map(Payload::Text);
        out[4] = newest_text(&mut self.weights[i]).map(Payload::Text);
        if self.handles[i].has_changed().unwrap_or(false) {
            let text = self.handles[i].borrow_and_update().text.clone();
            out[5] = (!text.is_empty()).then_some(Payload::Text(text));
        }
        // After the handles message, so its generation is known.
        out[6] = newest(&mut self.handle_frames[i]).map(Payload::Binary);
        out[7] = newest_text(&mut self.history[i]).map(Payload::Text);
        out[8] = self.poses[i]
            .as_mut()
            .and_then(newest_text)
            .map(Payload::Text);
        out
    }

    /// Ids of the puppets on stage, bottom to top.
    pub(crate) fn on_stage(&self) -> &[usize] {
        &self.on_stage
    }

    /// Sends, puppet by puppet, whatever changed since the last call: the
    /// newest of each, never a backlog, in one write.
    pub(super) async fn send_changed(
        &mut self,
        ws: &mut Ws,
        timeout: Duration,
    ) -> std::io::Result<()> {
        let mut queued = false;
        for k in 0..self.on_stage.len() {
            let i = self.on_stage[k];
            for payload in self.changed(i).into_iter().flatten() {
                let message = match payload {
                    Payload::Binary(bytes) => Message::binary(bytes),
                    Payload::Text(text) => Message::text(text.to_string()),
                };
                feed(ws, message, timeout).await?;
                queued = true;
            }
        }
        if queued {
            flush(ws, timeout).await?;
        }
        Ok(())
    }
}

/// What each slot of [`Following::changed`] holds, as NATS subjects name
/// it (`…out.p.<puppet>.<stream>`).
pub(crate) const STREAMS: [&str; 9] = [
    "frame",
    "depth",
    "rig",
    "keys",
    "weights",
    "handles",
    "handle_frame",
    "history",
    "pose",
];

/// One message of a puppet's output: a binary frame (the very bytes
/// encoded once for everyone) or a text message.
pub(crate) enum Payload {
    Binary(Bytes),
    Text(Arc<str>),
}

/// The newest frame, if it changed since last seen (none before the first).
fn newest(frame: &mut watch::Receiver<Option<Bytes>>) -> Option<Bytes> {
    if frame.has_changed().unwrap_or(false) {
        frame.borrow_and_update().clone()
    } else {
        None
    }
}

/// The newest text message, if it changed since last seen and is not
/// empty.
fn newest_text(text: &mut State) -> Option<Arc<str>> {
    if !text.has_changed().unwrap_or(false) {
        return None;
    }
    let text = text.borrow_and_update().text.clone();
    (!text.is_empty()).then_some(text)
}
