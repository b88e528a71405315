//! The Linux input-event state machine: raw `(type, code, value)` events from
//! a touch device in, calibrated [`ContactFrame`]s out, one per `SYN_REPORT`
//! that changed something. It owns the event-code constants, the axis
//! description ([`AbsInfo`]) and contact tracking for the three ways a device
//! can report touches: multi-touch protocol B (slots with tracking ids),
//! protocol A (anonymous contacts, matched here by nearest neighbour) and
//! single-touch (`ABS_X`/`ABS_Y` + `BTN_TOUCH`). Replays and the live device
//! reader feed the same [`TouchDecoder`], so both behave alike.
//!
//! Contact ids are the decoder's own, never the device's tracking ids: a
//! malformed stream that reuses a tracking id in two slots must still give
//! the stage two distinct contacts. No Linux headers or crates are needed:
//! the codes are the values from `linux/input-event-codes.h`.

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};

use glam::DVec2;

use super::{Calibration, CalibrationError, Contact, ContactFrame, Phase, SourceId};

// Event types.

/// Event type: report markers (the `SYN_*` codes).
pub const EV_SYN: u16 = 0x00;
/// Event type: keys and buttons; value 1 pressed, 0 released, 2 autorepeat.
pub const EV_KEY: u16 = 0x01;
/// Event type: relative axes (a mouse's motion and wheels); value the change.
pub const EV_REL: u16 = 0x02;
/// Event type: absolute axes (positions, pressure, slots); value the reading.
pub const EV_ABS: u16 = 0x03;
/// Event type: miscellany such as scan codes and hardware timestamps;
/// decoders skip it, captures keep it.
pub const EV_MSC: u16 = 0x04;
pub(crate) const EV_MAX: u16 = 0x1f;

// `EV_SYN` codes.

/// Ends a report: the events since the previous one happened together.
pub const SYN_REPORT: u16 = 0;
/// Ends one contact within a protocol A report.
pub const SYN_MT_REPORT: u16 = 2;
/// The kernel's event buffer overflowed and events were lost: discard up to
/// the next `SYN_REPORT`, then read the device's state back.
pub const SYN_DROPPED: u16 = 3;

// `EV_KEY` codes.

/// A pen is in range; with x/y axes it makes a device a pen tablet.
pub const BTN_TOOL_PEN: u16 = 0x140;
pub(crate) const BTN_TOOL_RUBBER: u16 = 0x141;
/// Something touches the surface: the single-touch protocol's down and up.
pub const BTN_TOUCH: u16 = 0x14a;
pub(crate) const KEY_MAX: u16 = 0x2ff;

// `EV_ABS` codes. Positions are in device units over the axis's range. The
// codes marked "not decoded" are here so `puppetry devices` can name every
// axis a device has.

/// Single-touch (and pen) x position; also the pointer emulation a
/// multi-touch device sends alongside its slots, which is ignored.
pub const ABS_X: u16 = 0x00;
/// Single-touch (and pen) y position, growing downwards.
pub const ABS_Y: u16 = 0x01;
/// Single-touch and pen pressure, normalised over its range.
pub const ABS_PRESSURE: u16 = 0x18;
/// Pen tilt along x: the axis resolution's units per radian, or degrees
/// when it declares no resolution.
pub const ABS_TILT_X: u16 = 0x1a;
/// Pen tilt along y, counted as [`ABS_TILT_X`] is.
pub const ABS_TILT_Y: u16 = 0x1b;
/// Which protocol B slot the following `ABS_MT_*` events describe; a
/// device with this axis speaks protocol B.
pub const ABS_MT_SLOT: u16 = 0x2f;
/// A contact's long-axis length; not decoded.
pub const ABS_MT_TOUCH_MAJOR: u16 = 0x30;
/// A contact's short-axis length; not decoded.
pub const ABS_MT_TOUCH_MINOR: u16 = 0x31;
/// The approaching tool's long-axis length; not decoded.
pub const ABS_MT_WIDTH_MAJOR: u16 = 0x32;
/// The approaching tool's short-axis length; not decoded.
pub const ABS_MT_WIDTH_MINOR: u16 = 0x33;
/// A contact's long-axis direction, clockwise from the device's up, `max`
/// being a quarter turn (along +x): becomes [`Contact::angle`].
pub const ABS_MT_ORIENTATION: u16 = 0x34;
/// A multi-touch contact's x position.
pub const ABS_MT_POSITION_X: u16 = 0x35;
/// A multi-touch contact's y position, growing downwards.
pub const ABS_MT_POSITION_Y: u16 = 0x36;
/// Finger, pen or palm, per contact; not decoded.
pub const ABS_MT_TOOL_TYPE: u16 = 0x37;
/// Groups several contacts into one blob; not decoded.
pub const ABS_MT_BLOB_ID: u16 = 0x38;
/// The device's id for a slot's contact, -1 when the slot empties. The
/// decoder gives contacts ids of its own.
pub const ABS_MT_TRACKING_ID: u16 = 0x39;
/// A contact's pressure, normalised over its range into
/// [`Contact::pressure`].
pub const ABS_MT_PRESSURE: u16 = 0x3a;
/// How far a hovering contact is above the surface; not decoded.
pub const ABS_MT_DISTANCE: u16 = 0x3b;
pub(crate) const ABS_MAX: u16 = 0x3f;

/// Devices have at most a few dozen slots; a header claiming more is
/// corrupt, and the cap keeps it from sizing an allocation.
pub(crate) const MAX_SLOTS: usize = 256;
/// Protocol A contacts beyond this many in one report are ignored, for the
/// same reason.
pub(crate) const MAX_ANONYMOUS_CONTACTS: usize = 64;

/// One raw event, as read from the device or a capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputEvent {
    /// Seconds (the kernel's timestamp).
    pub time: f64,
    /// The event type (`EV_*`).
    pub ev_type: u16,
    /// The code within the type (`SYN_*`, `BTN_*`, `ABS_*`, `REL_*`).
    pub code: u16,
    /// A key's state, an absolute axis's reading or a relative axis's
    /// change.
    pub value: i32,
}

impl InputEvent {
    /// An event at `time` seconds.
    pub fn new(time: f64, ev_type: u16, code: u16, value: i32) -> InputEvent {
        InputEvent {
            time,
            ev_type,
            code,
            value,
        }
    }
}

/// One absolute axis as the kernel describes it (`struct input_absinfo`
/// without the current value).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AbsInfo {
    /// The smallest value the axis reports.
    pub min: i32,
    /// The largest value the axis reports (inclusive).
    pub max: i32,
    /// Jitter the kernel filters out; kept for captures, unused here.
    pub fuzz: i32,
    /// A joystick's dead zone; kept for captures, unused here.
    pub flat: i32,
    /// Units per millimetre for positions, per radian for tilt; 0 = unknown.
    pub resolution: i32,
}

/// A device's absolute axes by code.
pub type AbsAxes = BTreeMap<u16, AbsInfo>;

/// One multi-touch slot as the device holds it now (`EVIOCGMTSLOTS`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlotState {
    /// The slot's index, from 0.
    pub slot: usize,
    /// -1: the slot is empty.
    pub tracking_id: i32,
    /// x position, device units (left over from the last contact when the
    /// slot is empty).
    pub x: i32,
    /// y position, device units.
    pub y: i32,
    /// `ABS_MT_PRESSURE`; `None` when the device has no such axis.
    pub pressure: Option<i32>,
}

/// What a device says its state is right now, read back with the
/// `EVIOCGKEY`, `EVIOCGABS` and `EVIOCGMTSLOTS` ioctls: on open (fingers may
/// already be down) and after `SYN_DROPPED`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DeviceState {
    /// Keys and buttons held down.
    pub keys: std::collections::BTreeSet<u16>,
    /// Current value of every absolute axis.
    pub abs: BTreeMap<u16, i32>,
    /// Every slot, empty ones included.
    pub slots: Vec<SlotState>,
}

/// Why a device's axes cannot be decoded or fitted to the stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvdevError {
    /// Neither multi-touch nor single-touch positions: not a touch surface
    /// or pen (a mouse or a keyboard, say).
    #[error("the device has no position axes (neither ABS_MT_POSITION_X/Y nor ABS_X/Y)")]
    NoPositionAxes,
    /// The position ranges cannot be stretched over the stage: a range
    /// whose min equals its max, say.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
}

/// How a device reports touches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Multi-touch protocol B: per-slot state with tracking ids.
    Slots,
    /// Multi-touch protocol A: every report lists all contacts, anonymously.
    Anonymous,
    /// `ABS_X`/`ABS_Y` + `BTN_TOUCH` only.
    SingleTouch,
}

impl Protocol {
    /// The kernel gives every protocol B device an `ABS_MT_SLOT` axis, so
    /// the axes alone tell the protocols apart.
    pub(crate) fn detect(axes: &AbsAxes) -> Option<Protocol> {
        let has = |code| axes.contains_key(&code);
        if has(ABS_MT_POSITION_X) && has(ABS_MT_POSITION_Y) {
            Some(if has(ABS_MT_SLOT) {
                Protocol::Slots
            } else {
                Protocol::Anonymous
            })
        } else if has(ABS_X) && has(ABS_Y) {
            Some(Protocol::SingleTouch)
        } else {
            None
        }
    }

    fn position_axes(self) -> (u16, u16) {
        match self {
            Protocol::Slots | Protocol::Anonymous => (ABS_MT_POSITION_X, ABS_MT_POSITION_Y),
            Protocol::SingleTouch => (ABS_X, ABS_Y),
        }
    }
}

/// The default calibration: the device's position ranges stretched over a
/// `stage_size` stage, y flipped.
pub fn fit_calibration(axes: &AbsAxes, stage_size: DVec2) -> Result<Calibration, EvdevError> {
    let protocol = Protocol::detect(axes).ok_or(EvdevError::NoPositionAxes)?;
    let (x, y) = protocol.position_axes();
    let range = |code| {
        let info = axes[&code];
        [f64::from(info.min), f64::from(info.max)]
    };
    Ok(Calibration::fit(range(x), range(y), stage_size)?)
}

/// Everything known about one contact, in device units.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Values {
    x: i32,
    y: i32,
    pressure: Option<i32>,
    orientation: Option<i32>,
    tilt_x: Option<i32>,
    tilt_y: Option<i32>,
}

#[derive(Debug, Clone)]
struct Slot {
    tracking_id: i32,
    values: Values,
    /// The contact the stage has been told about, and what it was told.
    live: Option<(u32, Values)>,
    /// A live contact replaced by a new tracking id within this report: its
    /// up goes out before the newcomer's down.
    ended: Option<(u32, Values)>,
    /// Lifted by a resync guess; stays silent until the device mentions the
    /// slot again, so a stale tracking id cannot resurrect the contact.
    suspended: bool,
    /// Mentioned in the current report (only tracked while resyncing).
    seen: bool,
}

impl Slot {
    fn new() -> Slot {
        Slot {
            tracking_id: -1,
            values: Values::default(),
            live: None,
            ended: None,
            suspended: false,
            seen: false,
        }
    }

    fn set_tracking_id(&mut self, id: i32) {
        if id == self.tracking_id {
            return;
        }
        // A new id on a slot whose contact the stage knows is that contact
        // lifting and a new one landing, even when the device skipped the -1.
        if id >= 0
            && let Some(live) = self.live.take()
        {
            self.ended = Some((live.0, self.values));
        }
        self.tracking_id = id;
    }
}

/// Where the decoder stands after a `SYN_DROPPED`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SyncState {
    Normal,
    /// Events are being discarded up to and including the next `SYN_REPORT`.
    Dropping,
    /// The first report after a drop: protocol B slots it does not mention
    /// are taken as lifted (unless [`TouchDecoder::resync`] comes first).
    Resyncing,
}

/// The multi-touch state machine. Feed it every event of one device with
/// [`push`](TouchDecoder::push); it answers each `SYN_REPORT` with the frame
/// of contacts that changed, already in stage coordinates.
///
/// After `SYN_DROPPED` it discards events through the next `SYN_REPORT`, as
/// the kernel asks. A live reader should then read the slots back
/// (`EVIOCGMTSLOTS`) and call [`resync`](TouchDecoder::resync); without
/// that (a replay), the next report is taken as the truth: protocol B slots
/// it does not mention lift, and land again as new contacts when the device
/// next mentions them. Contacts may thus be lifted early, but never stay
/// stuck and never miss their up. Protocol A reports are complete anyway.
#[derive(Debug, Clone)]
pub struct TouchDecoder {
    source: SourceId,
    protocol: Protocol,
    calibration: Calibration,
    pressure: Option<AbsInfo>,
    orientation: Option<AbsInfo>,
    tilt_resolution: (i32, i32),
    match_distance: f64,
    next_id: u32,
    time: f64,
    sync: SyncState,
    // Protocol B.
    slots: Vec<Slot>,
    current_slot: Option<usize>,
    // Protocol A.
    pending: Values,
    pending_xy: (bool, bool),
    report: Vec<Values>,
    tracked: Vec<(u32, Values)>,
    // Single touch.
    touching: bool,
    single: Values,
    single_live: Option<(u32, Values)>,
}

impl TouchDecoder {
    /// A decoder for a device with these axes, reporting as `source`.
    pub fn new(
        source: SourceId,
        axes: &AbsAxes,
        calibration: Calibration,
    ) -> Result<TouchDecoder, EvdevError> {
        let protocol = Protocol::detect(axes).ok_or(EvdevError::NoPositionAxes)?;
        let (x, y) = protocol.position_axes();
        let span = |code| {
            let info = axes[&code];
            f64::from(info.max) - f64::from(info.min)
        };
        let diagonal = span(x).hypot(span(y));
        let slot_count = axes
            .get(&ABS_MT_SLOT)
            .map(|s| (i64::from(s.max) + 1).clamp(1, MAX_SLOTS as i64) as usize)
            .unwrap_or(1);
        let pressure_axis = match protocol {
            Protocol::SingleTouch => ABS_PRESSURE,
            _ => ABS_MT_PRESSURE,
        };
        let resolution = |code| axes.get(&code).map_or(0, |a: &AbsInfo| a.resolution);
        Ok(TouchDecoder {
            source,
            protocol,
            calibration,
            pressure: axes.get(&pressure_axis).copied(),
            orientation: axes.get(&ABS_MT_ORIENTATION).copied(),
            tilt_resolution: (resolution(ABS_TILT_X), resolution(ABS_TILT_Y)),
            // A finger moves a few percent of the surface per report at
            // most; farther than this it is a lift and a new touch.
            match_distance: 0.1 * diagonal,
            next_id: 1,
            time: 0.0,
            sync: SyncState::Normal,
            slots: vec![Slot::new(); slot_count],
            current_slot: Some(0),
            pending: Values::default(),
            pending_xy: (false, false),
            report: Vec::new(),
            tracked: Vec::new(),
            touching: false,
            single: Values::default(),
            single_live: None,
        })
    }

    /// How the device reports touches, as its axes told.
    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// How many contacts the stage currently believes are down.
    pub fn live_contacts(&self) -> usize {
        match self.protocol {
            Protocol::Slots => self.slots.iter().filter(|s| s.live.is_some()).count(),
            Protocol::Anonymous => self.tracked.len(),
            Protocol::SingleTouch => usize::from(self.single_live.is_some()),
        }
    }

    /// Takes one event; returns a frame when it completes a report that
    /// changed some contact.
    pub fn push(&mut self, event: InputEvent) -> Option<ContactFrame> {
        self.time = event.time;
        if self.sync == SyncState::Dropping {
            if (event.ev_type, event.code) == (EV_SYN, SYN_REPORT) {
                self.clear_partial_report();
                self.sync = match self.protocol {
                    Protocol::Anonymous => SyncState::Normal,
                    _ => SyncState::Resyncing,
                };
            }
            return None;
        }
        match (event.ev_type, event.code) {
            (EV_SYN, SYN_REPORT) => self.report(),
            (EV_SYN, SYN_DROPPED) => {
                self.sync = SyncState::Dropping;
                None
            }
            (EV_SYN, SYN_MT_REPORT) => {
                self.mt_report();
                None
            }
            (EV_ABS, code) => {
                self.abs(code, event.value);
                None
            }
            (EV_KEY, BTN_TOUCH) => {
                self.touching = event.value != 0;
                None
            }
            // A pen leaving proximity is lifted even if its tip-up was lost.
            (EV_KEY, BTN_TOOL_PEN | BTN_TOOL_RUBBER) if event.value == 0 => {
                self.touching = false;
                None
            }
            _ => None,
        }
    }

    /// True after the `SYN_REPORT` that ends a drop, until
    /// [`restore`](TouchDecoder::restore) or the next report: the reader
    /// should read the device's state back now.
    pub(crate) fn needs_resync(&self) -> bool {
        self.sync == SyncState::Resyncing
    }

    /// Takes the device's own account of its state — on open, or after a
    /// drop — and returns the frame of what the stage must be told.
    /// Protocol A devices keep no state; their next report is complete.
    pub fn restore(&mut self, time: f64, state: &DeviceState) -> Option<ContactFrame> {
        match self.protocol {
            Protocol::Slots => {
                let slots: Vec<_> = state
                    .slots
                    .iter()
                    .filter(|s| s.tracking_id >= 0)
                    .map(|s| (s.slot, s.tracking_id, s.x, s.y))
                    .collect();
                for s in &state.slots {
                    if let Some(slot) = self.slots.get_mut(s.slot) {
                        slot.values.pressure = s.pressure;
                    }
                }
                self.current_slot = state
                    .abs
                    .get(&ABS_MT_SLOT)
                    .and_then(|&s| usize::try_from(s).ok())
                    .filter(|&s| s < self.slots.len());
                self.resync(time, &slots)
            }
            Protocol::Anonymous => {
                self.sync = SyncState::Normal;
                None
            }
            Protocol::SingleTouch => {
                self.time = time;
                let v = &mut self.single;
                let axis = |code| state.abs.get(&code).copied();
                v.x = axis(ABS_X).unwrap_or(v.x);
                v.y = axis(ABS_Y).unwrap_or(v.y);
                v.pressure = axis(ABS_PRESSURE).or(v.pressure);
                v.tilt_x = axis(ABS_TILT_X).or(v.tilt_x);
                v.tilt_y = axis(ABS_TILT_Y).or(v.tilt_y);
                self.touching = state.keys.contains(&BTN_TOUCH);
                self.clear_partial_report();
                self.report()
            }
        }
    }

    /// Sets protocol B state from a read-back of the device's slots
    /// `(slot, tracking_id, x, y)`, as after `EVIOCGMTSLOTS`; slots not listed
    /// are taken as empty. Call it once the `SYN_REPORT` that ends a drop
    /// has been pushed. Returns the frame of what changed, stamped `time`.
    pub fn resync(&mut self, time: f64, slots: &[(usize, i32, i32, i32)]) -> Option<ContactFrame> {
        self.time = time;
        if self.protocol != Protocol::Slots {
            self.sync = SyncState::Normal;
            return None;
        }
        for (index, slot) in self.slots.iter_mut().enumerate() {
            slot.suspended = false;
            slot.seen = false;
            match slots.iter().find(|s| s.0 == index) {
                Some(&(_, tracking_id, x, y)) => {
                    slot.set_tracking_id(tracking_id);
                    slot.values.x = x;
                    slot.values.y = y;
                }
                None => slot.set_tracking_id(-1),
            }
        }
        self.sync = SyncState::Normal;
        let contacts = self.slot_changes();
        self.frame(contacts)
    }

    /// Lifts every contact the stage believes is down and forgets all state:
    /// for the end of a replay or a device that went away.
    pub fn lift_all(&mut self, time: f64) -> Option<ContactFrame> {
        self.time = time;
        let mut ups = Vec::new();
        for slot in &mut self.slots {
            ups.extend(slot.ended.take());
            ups.extend(slot.live.take());
            *slot = Slot::new();
        }
        ups.append(&mut self.tracked);
        ups.extend(self.single_live.take());
        self.touching = false;
        self.sync = SyncState::Normal;
        self.clear_partial_report();
        let contacts = ups
            .into_iter()
            .map(|(id, values)| self.contact(id, Phase::Up, &values))
            .collect();
        self.frame(contacts)
    }

    fn clear_partial_report(&mut self) {
        self.pending = Values::default();
        self.pending_xy = (false, false);
        self.report.clear();
    }

    fn abs(&mut self, code: u16, value: i32) {
        match self.protocol {
            Protocol::Slots => self.slot_abs(code, value),
            Protocol::Anonymous => {
                let p = &mut self.pending;
                match code {
                    ABS_MT_POSITION_X => {
                        p.x = value;
                        self.pending_xy.0 = true;
                    }
                    ABS_MT_POSITION_Y => {
                        p.y = value;
                        self.pending_xy.1 = true;
                    }
                    ABS_MT_PRESSURE => p.pressure = Some(value),
                    ABS_MT_ORIENTATION => p.orientation = Some(value),
                    _ => {}
                }
            }
            Protocol::SingleTouch => {
                let v = &mut self.single;
                match code {
                    ABS_X => v.x = value,
                    ABS_Y => v.y = value,
                    ABS_PRESSURE => v.pressure = Some(value),
                    ABS_TILT_X => v.tilt_x = Some(value),
                    ABS_TILT_Y => v.tilt_y = Some(value),
                    _ => {}
                }
            }
        }
    }

    fn slot_abs(&mut self, code: u16, value: i32) {
        if code == ABS_MT_SLOT {
            self.current_slot = usize::try_from(value)
                .ok()
                .filter(|&s| s < self.slots.len());
            return;
        }
        if !(ABS_MT_TOUCH_MAJOR..=ABS_MAX).contains(&code) {
            return; // pointer emulation (ABS_X, ABS_Y, …) repeats the slots
        }
        let Some(slot) = self.current_slot.map(|s| &mut self.slots[s]) else {
            return;
        };
        slot.seen = true;
        slot.suspended = false;
        match code {
            ABS_MT_TRACKING_ID => slot.set_tracking_id(value),
            ABS_MT_POSITION_X => slot.values.x = value,
            ABS_MT_POSITION_Y => slot.values.y = value,
            ABS_MT_PRESSURE => slot.values.pressure = Some(value),
            ABS_MT_ORIENTATION => slot.values.orientation = Some(value),
            _ => {}
        }
    }

    /// Closes one protocol A contact; one with no position (the empty
    /// `SYN_MT_REPORT` that means "no contacts") adds nothing.
    fn mt_report(&mut self) {
        if self.protocol != Protocol::Anonymous {
            return;
        }
        if self.pending_xy == (true, true) && self.report.len() < MAX_ANONYMOUS_CONTACTS {
            self.report.push(self.pending);
        }
        self.pending = Values::default();
        self.pending_xy = (false, false);
    }

    fn report(&mut self) -> Option<ContactFrame> {
        let contacts = match self.protocol {
            Protocol::Slots => {
                if self.sync == SyncState::Resyncing {
                    self.lift_unseen_slots();
                }
                self.slot_changes()
            }
            Protocol::Anonymous => self.anonymous_changes(),
            Protocol::SingleTouch => self.single_changes(),
        };
        self.sync = SyncState::Normal;
        for slot in &mut self.slots {
            slot.seen = false;
        }
        self.frame(contacts)
    }

    fn lift_unseen_slots(&mut self) {
        for slot in &mut self.slots {
            if !slot.seen && slot.live.is_some() {
                slot.ended = slot.live.take();
                slot.suspended = true;
            }
        }
    }

    /// Slot order; a replaced contact's up comes just before its successor.
    fn slot_changes(&mut self) -> Vec<Contact> {
        let mut out = Vec::new();
        for index in 0..self.slots.len() {
            let slot = &mut self.slots[index];
            let ended = slot.ended.take();
            let change = if slot.suspended {
                None
            } else {
                match (slot.tracking_id >= 0, slot.live) {
                    (true, None) => {
                        let id = next(&mut self.next_id);
                        slot.live = Some((id, slot.values));
                        Some((id, Phase::Down, slot.values))
                    }
                    (true, Some((id, told))) if told != slot.values => {
                        slot.live = Some((id, slot.values));
                        Some((id, Phase::Move, slot.values))
                    }
                    (false, Some((id, _))) => {
                        slot.live = None;
                        Some((id, Phase::Up, slot.values))
                    }
                    _ => None,
                }
            };
            if let Some((id, values)) = ended {
                out.push(self.contact(id, Phase::Up, &values));
            }
            if let Some((id, phase, values)) = change {
                out.push(self.contact(id, phase, &values));
            }
        }
        out
    }

    /// Matches this report's contacts to the tracked ones, closest pairs
    /// first. Ups come first, then the report's contacts in its order.
    fn anonymous_changes(&mut self) -> Vec<Contact> {
        let report = std::mem::take(&mut self.report);
        let tracked = std::mem::take(&mut self.tracked);
        let mut pairs = Vec::new();
        for (i, (_, old)) in tracked.iter().enumerate() {
            for (j, new) in report.iter().enumerate() {
                let d = f64::from(old.x - new.x).hypot(f64::from(old.y - new.y));
                if d <= self.match_distance {
                    pairs.push((d, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let mut match_of_new = vec![None; report.len()];
        let mut matched_old = vec![false; tracked.len()];
        for (_, i, j) in pairs {
            if !matched_old[i] && match_of_new[j].is_none() {
                matched_old[i] = true;
                match_of_new[j] = Some(i);
            }
        }
        let mut out = Vec::new();
        for (i, (id, old)) in tracked.iter().enumerate() {
            if !matched_old[i] {
                out.push(self.contact(*id, Phase::Up, old));
            }
        }
        for (j, new) in report.iter().enumerate() {
            match match_of_new[j] {
                Some(i) => {
                    let (id, old) = tracked[i];
                    if old != *new {
                        out.push(self.contact(id, Phase::Move, new));
                    }
                    self.tracked.push((id, *new));
                }
                None => {
                    let id = next(&mut self.next_id);
                    out.push(self.contact(id, Phase::Down, new));
                    self.tracked.push((id, *new));
                }
            }
        }
        out
    }

    fn single_changes(&mut self) -> Vec<Contact> {
        let change = match (self.touching, self.single_live) {
            (true, None) => {
                let id = next(&mut self.next_id);
                self.single_live = Some((id, self.single));
                Some((id, Phase::Down))
            }
            (true, Some((id, told))) if told != self.single => {
                self.single_live = Some((id, self.single));
                Some((id, Phase::Move))
            }
            (false, Some((id, _))) => {
                self.single_live = None;
                Some((id, Phase::Up))
            }
            _ => None,
        };
        change
            .map(|(id, phase)| self.contact(id, phase, &self.single))
            .into_iter()
            .collect()
    }

    fn frame(&self, contacts: Vec<Contact>) -> Option<ContactFrame> {
        (!contacts.is_empty()).then(|| ContactFrame {
            source: self.source.clone(),
            time: self.time,
            contacts,
        })
    }

    fn contact(&self, id: u32, phase: Phase, v: &Values) -> Contact {
        let at = DVec2::new(f64::from(v.x), f64::from(v.y));
        let pressure = v.pressure.zip(self.pressure).and_then(|(p, axis)| {
            let span = f64::from(axis.max) - f64::from(axis.min);
            (span > 0.0).then(|| ((f64::from(p) - f64::from(axis.min)) / span).clamp(0.0, 1.0))
        });
        // ABS_MT_ORIENTATION counts clockwise quarter turns from the device's
        // north (y-down), with `max` meaning along +x.
        let angle = v.orientation.zip(self.orientation).and_then(|(o, axis)| {
            if axis.max <= 0 {
                return None;
            }
            let turn = f64::from(o) / f64::from(axis.max) * FRAC_PI_2;
            let axis_dir = DVec2::new(turn.sin(), -turn.cos());
            let d = self.calibration.map_direction(at, axis_dir);
            (d != DVec2::ZERO && d.is_finite()).then(|| fold_axis_angle(d.y.atan2(d.x)))
        });
        // Tilt axes without a resolution count degrees (older Wacom drivers).
        let per_radian = |r: i32| if r > 0 { f64::from(r) } else { 180.0 / PI };
        let (rx, ry) = (
            per_radian(self.tilt_resolution.0),
            per_radian(self.tilt_resolution.1),
        );
        let tilt = match (v.tilt_x, v.tilt_y) {
            (Some(tx), Some(ty)) => {
                let t = DVec2::new(f64::from(tx) / rx, f64::from(ty) / ry);
                let d = self.calibration.map_direction(at, t);
                Some(if d.length() > 0.0 && d.is_finite() {
                    d * (t.length() / d.length())
                } else {
                    DVec2::ZERO
                })
            }
            _ => None,
        };
        Contact {
            id,
            phase,
            position: self.calibration.map(at),
            pressure,
            tilt,
            angle,
        }
    }
}

fn next(counter: &mut u32) -> u32 {
    let id = *counter;
    *counter = counter.wrapping_add(1);
    id
}

fn fold_axis_angle(a: f64) -> f64 {
    if a <= -FRAC_PI_2 {
        a + PI
    } else if a > FRAC_PI_2 {
        a - PI
    } else {
        a
    }
}
