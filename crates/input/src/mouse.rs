//! Mice as puppeteering tools, after Igarashi et al. 2005 (§3, Figure 16):
//! each mouse drives its own cursor on the stage and can hold a pair of
//! points, moving them with a left-button drag and turning them about the
//! cursor with the wheel or a right-button drag. This module owns the mouse
//! event codes, the [`MouseSettings`] that size the pair, and
//! [`MouseDecoder`], plain synchronous state that turns one mouse's raw
//! relative events into [`ContactFrame`]s, one per `SYN_REPORT` that moved a
//! held contact. Finding and opening mice belongs elsewhere; replays and the
//! live reader feed the same decoder.
//!
//! The pair is the mouse's stand-in for an orientation-sensitive mouse: two
//! contacts `spacing` apart, centred on the cursor, at the pair's angle. The
//! angle belongs to the mouse, not the grab, so a pair turned while hovering
//! lands turned.

use std::f64::consts::{PI, TAU};

use glam::DVec2;

use super::evdev::{EV_KEY, EV_REL, EV_SYN, InputEvent, SYN_DROPPED, SYN_REPORT};
use super::{Contact, ContactFrame, Phase, SourceId};

// `EV_REL` codes, from `linux/input-event-codes.h`.

/// Horizontal motion, counts, + to the right.
pub const REL_X: u16 = 0x00;
/// Vertical motion, counts, + down the screen (the stage is y-up, so the
/// decoder flips it).
pub const REL_Y: u16 = 0x01;
/// The horizontal wheel, often a sideways tilt of the main one; ignored.
pub const REL_HWHEEL: u16 = 0x06;
/// Wheel notches, + rolled away from the user: turns the pair
/// counter-clockwise. Ignored once the mouse has sent `REL_WHEEL_HI_RES`.
pub const REL_WHEEL: u16 = 0x08;
/// The wheel in 120ths of a notch, on mice that have it; used instead of
/// `REL_WHEEL` once seen.
pub const REL_WHEEL_HI_RES: u16 = 0x0b;

// `EV_KEY` codes.

/// Held, the mouse holds its contacts (the pair, or one point) at the
/// cursor.
pub const BTN_LEFT: u16 = 0x110;
/// Held, horizontal motion turns the pair instead of moving the cursor.
pub const BTN_RIGHT: u16 = 0x111;
/// Ignored.
pub const BTN_MIDDLE: u16 = 0x112;

/// `REL_WHEEL_HI_RES` units in one wheel notch (fixed by the kernel ABI).
pub(crate) const HI_RES_PER_NOTCH: f64 = 120.0;

/// Horizontal counts of a right-button drag that turn the pair by one
/// `rotate_step`. Ten counts is a few millimetres on a typical 800–1600 cpi
/// mouse: a flick of the wrist gives a quarter turn, yet the pair can be
/// set to a degree or two.
pub const TWIST_COUNTS_PER_STEP: f64 = 10.0;

/// Settings [`MouseDecoder::new`] refuses.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MouseError {
    /// A setting, or the stage size, is out of range: not finite, not above
    /// zero, a rotation step over a full turn, or a start off the stage.
    #[error("mouse: {field}: {problem}")]
    Invalid {
        /// The setting (`speed`, `pair_spacing`, `rotate_step`, `start`,
        /// `stage_size`).
        field: &'static str,
        /// What is wrong with its value.
        problem: String,
    },
}

fn invalid(field: &'static str, problem: impl Into<String>) -> MouseError {
    MouseError::Invalid {
        field,
        problem: problem.into(),
    }
}

/// How one mouse puppeteers.
#[derive(Debug, Clone, PartialEq)]
pub struct MouseSettings {
    /// Stage units the cursor moves per count of mouse motion.
    pub speed: f64,
    /// Hold two points (the paper's rotatable pair) or just one.
    pub pair: bool,
    /// Stage units between the pair's points.
    pub pair_spacing: f64,
    /// Radians the pair turns per wheel notch (and per
    /// [`TWIST_COUNTS_PER_STEP`] counts of right-button drag).
    pub rotate_step: f64,
    /// Where the cursor starts, in stage coordinates.
    pub start: DVec2,
}

impl MouseSettings {
    /// One count per stage unit, a pair a twelfth of the stage's short side
    /// across, 15° per notch, starting at the centre.
    pub fn for_stage(size: DVec2) -> MouseSettings {
        MouseSettings {
            speed: 1.0,
            pair: true,
            pair_spacing: size.min_element() / 12.0,
            rotate_step: 15f64.to_radians(),
            start: size / 2.0,
        }
    }

    fn check(&self, stage_size: DVec2) -> Result<(), MouseError> {
        if !stage_size.is_finite() || stage_size.min_element() <= 0.0 {
            return Err(invalid(
                "stage_size",
                format!("{stage_size} must be finite and positive"),
            ));
        }
        for (field, value) in [
            ("speed", self.speed),
            ("pair_spacing", self.pair_spacing),
            ("rotate_step", self.rotate_step),
        ] {
            if !value.is_finite() || value <= 0.0 {
                return Err(invalid(
                    field,
                    format!("{value} must be a finite number above 0"),
                ));
            }
        }
        if self.rotate_step > TAU {
            return Err(invalid(
                "rotate_step",
                format!("{} is more than a full turn", self.rotate_step),
            ));
        }
        let on_stage = self.start.is_finite()
            && self.start.cmpge(DVec2::ZERO).all()
            && self.start.cmple(stage_size).all();
        if !on_stage {
            return Err(invalid(
                "start",
                format!(
                    "{} is not on the stage [0, {}] × [0, {}]",
                    self.start, stage_size.x, stage_size.y
                ),
            ));
        }
        Ok(())
    }
}

/// What a renderer draws for one mouse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cursor {
    /// Stage coordinates (y-up), always on the stage.
    pub position: DVec2,
    /// The pair's direction, radians counter-clockwise from +x, in [-π, π].
    pub angle: f64,
    /// Whether the mouse holds contacts right now.
    pub holding: bool,
}

/// Everything one report changes, gathered until its `SYN_REPORT`: the
/// kernel's events within a report happen together, and a report cut short
/// by `SYN_DROPPED` must change nothing.
#[derive(Debug, Clone, Copy, Default)]
struct Pending {
    motion: [i64; 2],
    /// Horizontal counts that arrived while the right button was down.
    twist: i64,
    wheel: i64,
    wheel_hi_res: i64,
    left: Option<bool>,
    right: Option<bool>,
    /// A press arrived while a grab was on: its release went missing, or
    /// came in this same report. Either way the old grab ends.
    regrab: bool,
}

/// A grab in progress: its first contact id (a pair uses the next one too)
/// and where the stage was last told its contacts are.
#[derive(Debug, Clone, Copy)]
struct Grab {
    first_id: u32,
    told: [DVec2; 2],
}

/// One mouse's state machine. Feed it the mouse's events with
/// [`push`](MouseDecoder::push); it answers each `SYN_REPORT` that changed a
/// held contact with a frame in stage coordinates. Cursor motion with
/// nothing held gives no frame, only a new [`cursor`](MouseDecoder::cursor).
///
/// Within a report, motion, wheel and buttons apply together: a press lands
/// where the report leaves the cursor, a release lifts from there. A
/// report's horizontal motion turns the pair instead of moving the cursor
/// when the right button is down at that event; vertical motion is then
/// dropped so the pivot stays put. Ids come from one counter, a pair taking
/// two consecutive ones, so no id returns while any grab could hold it.
///
/// After `SYN_DROPPED` the decoder discards events through the next
/// `SYN_REPORT`; a live reader should then read the buttons back
/// (`EVIOCGKEY`) and call [`resync`](MouseDecoder::resync). Without that (a
/// replay), a press that arrives during a grab is taken as a lost release
/// followed by a new grab, so a pair can be let go late but never twice.
#[derive(Debug, Clone)]
pub struct MouseDecoder {
    source: SourceId,
    settings: MouseSettings,
    stage_size: DVec2,
    position: DVec2,
    angle: f64,
    left: bool,
    right: bool,
    /// The device sends `REL_WHEEL_HI_RES`; its `REL_WHEEL` repeats the
    /// same notches coarser and is ignored from then on.
    hi_res_wheel: bool,
    grab: Option<Grab>,
    pending: Pending,
    dropping: bool,
    /// A drop just ended: the buttons should be read back now.
    resync_due: bool,
    next_id: u32,
}

impl MouseDecoder {
    /// A decoder for one mouse on a `stage_size` stage (lower-left corner at
    /// the origin), reporting as `source`.
    pub fn new(
        source: SourceId,
        settings: MouseSettings,
        stage_size: DVec2,
    ) -> Result<MouseDecoder, MouseError> {
        settings.check(stage_size)?;
        Ok(MouseDecoder {
            source,
            position: settings.start,
            settings,
            stage_size,
            angle: 0.0,
            left: false,
            right: false,
            hi_res_wheel: false,
            grab: None,
            pending: Pending::default(),
            dropping: false,
            resync_due: false,
            next_id: 0,
        })
    }

    /// Where the cursor is, as of the last complete report.
    pub fn cursor(&self) -> Cursor {
        Cursor {
            position: self.position,
            angle: self.angle,
            holding: self.grab.is_some(),
        }
    }

    /// How many contacts the stage currently believes this mouse holds.
    pub fn live_contacts(&self) -> usize {
        if self.grab.is_some() {
            self.points().1
        } else {
            0
        }
    }

    /// Takes one event; returns a frame when it completes a report that
    /// changed a held contact.
    pub fn push(&mut self, event: InputEvent) -> Option<ContactFrame> {
        self.resync_due = false;
        if self.dropping {
            if (event.ev_type, event.code) == (EV_SYN, SYN_REPORT) {
                self.dropping = false;
                self.resync_due = true;
            }
            return None;
        }
        let value = i64::from(event.value);
        let p = &mut self.pending;
        match (event.ev_type, event.code) {
            (EV_SYN, SYN_REPORT) => return self.report(event.time),
            (EV_SYN, SYN_DROPPED) => {
                self.pending = Pending::default();
                self.dropping = true;
            }
            (EV_REL, REL_X) if p.right.unwrap_or(self.right) => {
                p.twist = p.twist.saturating_add(value);
            }
            (EV_REL, REL_Y) if p.right.unwrap_or(self.right) => {}
            (EV_REL, REL_X) => p.motion[0] = p.motion[0].saturating_add(value),
            (EV_REL, REL_Y) => p.motion[1] = p.motion[1].saturating_add(value),
            (EV_REL, REL_WHEEL) => p.wheel = p.wheel.saturating_add(value),
            (EV_REL, REL_WHEEL_HI_RES) => {
                p.wheel_hi_res = p.wheel_hi_res.saturating_add(value);
                self.hi_res_wheel = true;
            }
            // Value 2 is autorepeat: still down, not a new press.
            (EV_KEY, BTN_LEFT) => {
                if event.value == 1 && self.grab.is_some() {
                    p.regrab = true;
                }
                p.left = Some(event.value != 0);
            }
            (EV_KEY, BTN_RIGHT) => p.right = Some(event.value != 0),
            // The horizontal wheel is often a sideways tilt of the main
            // wheel; turning the pair with it would fight the wheel itself.
            _ => {}
        }
        None
    }

    /// True right after the `SYN_REPORT` that ends a drop: the reader should
    /// read the buttons back and call [`resync`](MouseDecoder::resync).
    pub(crate) fn needs_resync(&self) -> bool {
        self.resync_due
    }

    /// Sets the buttons from a read-back of the device (`EVIOCGKEY`), as
    /// after a drop: a release lost in the drop lifts the grab, a lost press
    /// starts one at the cursor. Call it once the `SYN_REPORT` that ends the
    /// drop has been pushed. Returns the frame of what changed, stamped
    /// `time`.
    pub fn resync(&mut self, time: f64, left: bool, right: bool) -> Option<ContactFrame> {
        self.dropping = false;
        self.resync_due = false;
        self.pending = Pending::default();
        self.right = right;
        self.left = left;
        let mut contacts = Vec::new();
        self.settle_grab(false, &mut contacts);
        self.frame(time, contacts)
    }

    /// Lets go of everything and forgets the buttons: for the end of a
    /// replay or a mouse that went away. The cursor stays where it was.
    pub fn lift_all(&mut self, time: f64) -> Option<ContactFrame> {
        self.dropping = false;
        self.pending = Pending::default();
        self.left = false;
        self.right = false;
        let mut contacts = Vec::new();
        self.settle_grab(false, &mut contacts);
        self.frame(time, contacts)
    }

    fn report(&mut self, time: f64) -> Option<ContactFrame> {
        let p = std::mem::take(&mut self.pending);
        let notches = if self.hi_res_wheel {
            p.wheel_hi_res as f64 / HI_RES_PER_NOTCH
        } else {
            p.wheel as f64
        };
        // Dragging right pushes the top of the pair right: clockwise.
        let turns = notches - p.twist as f64 / TWIST_COUNTS_PER_STEP;
        if turns != 0.0 {
            self.angle = wrap_angle(self.angle + turns * self.settings.rotate_step);
        }
        // Mice count y downwards on the screen; the stage is y-up.
        let motion = DVec2::new(p.motion[0] as f64, -(p.motion[1] as f64));
        self.position =
            (self.position + motion * self.settings.speed).clamp(DVec2::ZERO, self.stage_size);
        self.left = p.left.unwrap_or(self.left);
        self.right = p.right.unwrap_or(self.right);

        let mut contacts = Vec::new();
        self.settle_grab(p.regrab, &mut contacts);
        self.frame(time, contacts)
    }

    /// Brings the grab in line with the left button and the cursor, ending
    /// an old grab before starting a new one.
    fn settle_grab(&mut self, regrab: bool, contacts: &mut Vec<Contact>) {
        let (points, count) = self.points();
        if let Some(grab) = self.grab {
            if regrab || !self.left {
                self.grab = None;
                for (i, &at) in points[..count].iter().enumerate() {
                    let id = grab.first_id.wrapping_add(i as u32);
                    contacts.push(Contact::new(id, Phase::Up, at));
                }
            } else {
                for (i, &at) in points[..count].iter().enumerate() {
                    if at != grab.told[i] {
                        let id = grab.first_id.wrapping_add(i as u32);
                        contacts.push(Contact::new(id, Phase::Move, at));
                    }
                }
                self.grab = Some(Grab {
                    told: points,
                    ..grab
                });
            }
        }
        if self.left && self.grab.is_none() {
            let first_id = self.next_id;
            self.next_id = self.next_id.wrapping_add(count as u32);
            for (i, &at) in points[..count].iter().enumerate() {
                contacts.push(Contact::new(
                    first_id.wrapping_add(i as u32),
                    Phase::Down,
                    at,
                ));
            }
            self.grab = Some(Grab {
                first_id,
                told: points,
            });
        }
    }

    /// Where held contacts sit for the current cursor, and how many there
    /// are: the pair's tail then head, or the cursor alone.
    fn points(&self) -> ([DVec2; 2], usize) {
        if self.settings.pair {
            let half = DVec2::from_angle(self.angle) * (self.settings.pair_spacing / 2.0);
            ([self.position - half, self.position + half], 2)
        } else {
            ([self.position; 2], 1)
        }
    }

    fn frame(&self, time: f64, contacts: Vec<Contact>) -> Option<ContactFrame> {
        (!contacts.is_empty()).then(|| ContactFrame {
            source: self.source.clone(),
            time,
            contacts,
        })
    }
}

/// Keeps the angle small so that precision does not drain away over a long
/// session of turning one way.
fn wrap_angle(a: f64) -> f64 {
    (a + PI).rem_euclid(TAU) - PI
}
