//! What the stage thread publishes: per puppet, the watch channels its
//! frames, handles and state messages travel on ([`PuppetOutput`]), and the
//! thread's own timings. Connections, relays, show control and the lineup
//! read them; only the stage thread writes them.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use bytes::Bytes;
use tokio::sync::watch;

use crate::protocol::{HandleView, ServerMessage};

/// A state message as published: the typed message, which show control
/// and the daemon's own code read (no JSON parsed back), and its text,
/// which connections and relays send, made from it once.
#[derive(Debug)]
pub struct Published {
    /// The message; none before anything is published, and none on a
    /// relay, which forwards a text it does not read.
    pub message: Option<ServerMessage>,
    pub text: Arc<str>,
}

impl Published {
    pub fn of(message: ServerMessage) -> Arc<Published> {
        Arc::new(Published {
            text: Arc::from(message.to_text()),
            message: Some(message),
        })
    }

    /// Nothing published yet (an empty text, which nobody sends).
    pub fn nothing() -> Arc<Published> {
        Published::relayed(Arc::from(""))
    }

    /// A text a relay received and forwards as it is.
    pub fn relayed(text: Arc<str>) -> Arc<Published> {
        Arc::new(Published {
            message: None,
            text,
        })
    }
}

/// A published state message's channel, as read.
pub type State = watch::Receiver<Arc<Published>>;
/// A published state message's channel, as written.
pub type Feed = watch::Sender<Arc<Published>>;

/// A puppet's handle set as published: the typed list (newcomers' stage
/// messages include it) and the `handles` message made from it once.
#[derive(Debug)]
pub struct PublishedHandles {
    pub handles: Vec<HandleView>,
    pub text: Arc<str>,
    /// The set's generation (handle frames name the one they follow).
    pub generation: u32,
}

/// The newest output of one puppet.
#[derive(Debug, Clone)]
pub struct PuppetOutput {
    /// The newest encoded vertex frame (none before the first solve).
    pub frame: watch::Receiver<Option<Bytes>>,
    /// The newest rig frame (grid or skeleton puppets only).
    pub rig: watch::Receiver<Option<Bytes>>,
    /// The newest handle set and its "handles" message.
    pub handles: watch::Receiver<Arc<PublishedHandles>>,
    /// The newest "weights" message (changes when a performer paints).
    pub weights: State,
    /// The newest "keys" message (key poses and the cursor).
    pub keys: State,
    /// The newest handles frame: where each handle is on the solved
    /// puppet (none before the first solve with handles).
    pub handle_frame: watch::Receiver<Option<Bytes>>,
    /// The newest "history" message (undo and redo steps).
    pub history: State,
    /// The newest "pose" message (skeleton puppets only).
    pub pose: Option<State>,
    /// The newest depth frame (none until the depth first differs from
    /// the mesh's order, or with `depth = "off"`).
    pub depth: watch::Receiver<Option<Bytes>>,
}

/// What a puppet's channels hold before its first solve: its handles,
/// weights, keys, history and (a skeleton's) pose as they are now.
pub(crate) struct PuppetStart {
    pub handles: Arc<PublishedHandles>,
    pub weights: Arc<Published>,
    pub keys: Arc<Published>,
    pub history: Arc<Published>,
    /// `Some` for a skeleton puppet, which alone has a pose channel.
    pub pose: Option<Arc<Published>>,
}

/// The sending ends of a puppet's channels, one for each of
/// [`PuppetOutput`]'s: the stage thread's publisher writes into them, or
/// a relay from NATS.
pub(crate) struct PuppetSenders {
    pub frame: watch::Sender<Option<Bytes>>,
    pub rig: watch::Sender<Option<Bytes>>,
    pub handles: watch::Sender<Arc<PublishedHandles>>,
    pub weights: Feed,
    pub keys: Feed,
    pub handle_frame: watch::Sender<Option<Bytes>>,
    pub history: Feed,
    pub pose: Option<Feed>,
    pub depth: watch::Sender<Option<Bytes>>,
}

impl PuppetOutput {
    /// A puppet's channels holding `start` and no frames yet: the ends
    /// to publish into, and the ends connections read.
    pub(crate) fn channels(start: PuppetStart) -> (PuppetSenders, PuppetOutput) {
        let (frame, frame_rx) = watch::channel(None);
        let (rig, rig_rx) = watch::channel(None);
        let (handles, handles_rx) = watch::channel(start.handles);
        let (weights, weights_rx) = watch::channel(start.weights);
        let (keys, keys_rx) = watch::channel(start.keys);
        let (handle_frame, handle_frame_rx) = watch::channel(None);
        let (history, history_rx) = watch::channel(start.history);
        let (pose, pose_rx) = start.pose.map(watch::channel).unzip();
        let (depth, depth_rx) = watch::channel(None);
        let senders = PuppetSenders {
            frame,
            rig,
            handles,
            weights,
            keys,
            handle_frame,
            history,
            pose,
            depth,
        };
        let output = PuppetOutput {
            frame: frame_rx,
            rig: rig_rx,
            handles: handles_rx,
            weights: weights_rx,
            keys: keys_rx,
            handle_frame: handle_frame_rx,
            history: history_rx,
            pose: pose_rx,
            depth: depth_rx,
        };
        (senders, output)
    }
}

/// Where the daemon's time goes, summed since it started: per stage-thread
/// iteration (the commands waiting, then one solve and its publishing) and
/// per client send. Read by `puppetry bench --e2e`; relaxed atomics, a
/// clock read per phase (tens of nanoseconds against a millisecond).
#[derive(Debug, Default)]
pub struct Timings {
    /// Iterations that solved.
    pub solves: AtomicU64,
    /// Applying the commands: contacts to handles, pins, edits.
    pub commands_ns: AtomicU64,
    /// Solving every puppet the batch moved.
    pub solve_ns: AtomicU64,
    /// Encoding the binary frames once and waking every client.
    pub frames_ns: AtomicU64,
    /// Building the text messages that changed (weights, keys, history,
    /// poses, cursors, take state).
    pub messages_ns: AtomicU64,
    /// Writing the solve into the take being recorded.
    pub record_ns: AtomicU64,
    /// A client task sending what changed after a wake (all its puppets'
    /// messages), and how many such sends.
    pub sends: AtomicU64,
    /// The time those sends took.
    pub send_ns: AtomicU64,
}

impl Timings {
    /// Adds the time since `since` to `counter`; returns now.
    pub(crate) fn add(counter: &AtomicU64, since: Instant) -> Instant {
        let now = Instant::now();
        counter.fetch_add((now - since).as_nanos() as u64, Ordering::Relaxed);
        now
    }
}
