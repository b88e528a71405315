//! HID multi-touch digitizers as an input source, the part that needs no
//! hardware: it owns reading a touch screen's or touch pad's layout out of its
//! HID report descriptor ([`TouchLayout`]), the Input Mode feature report that
//! switches such a device into multi-touch reporting ([`InputMode`]), and
//! [`HidTouchDecoder`], plain synchronous state that turns raw input reports
//! into calibrated [`ContactFrame`]s.
//!
//! The last section talks to real devices through hidapi (hidraw on Linux,
//! the platform HID APIs elsewhere): [`list_devices`], [`open`] by
//! [`HidSelector`], and [`run_device`], a blocking loop over any
//! [`ReportDevice`] that switches the device to multi-touch reporting and
//! feeds its reports through the decoder. It is written against the trait so
//! tests can stand in for hardware.
//!
//! Descriptor items are parsed by the `hidreport` crate; this module only
//! picks out the digitizer usages (HID Usage Tables, page 0x0D) and the
//! Generic Desktop X/Y inside each Finger collection. Reports are read with a
//! bounds-checked bit reader of our own, because `hidreport`'s extractors
//! index the buffer unchecked and a short report must be an error, not a
//! panic.
//!
//! Devices report in parallel mode (every finger slot in one report) or
//! hybrid mode (a frame spread over several reports: the first carries the
//! frame's Contact Count, the rest a count of 0). Either way the decoder
//! gathers a whole frame before acting, because only a complete frame tells
//! which contacts are gone: any tracked id the frame does not report as down
//! is lifted, so a device that drops a lift report leaves nothing stuck.

use std::collections::BTreeMap;
use std::ops::Range;

use glam::DVec2;
use hidreport::{CollectionType, Field, Report, ReportDescriptor, Usage, VariableField};

use super::log_limit::{LogLimiter, MAX_ECHO, clip};
use super::{Calibration, CalibrationError, Contact, ContactFrame, Phase, SourceId};

const PAGE_GENERIC_DESKTOP: u16 = 0x01;
const PAGE_DIGITIZER: u16 = 0x0D;
const USAGE_X: u16 = 0x30;
const USAGE_Y: u16 = 0x31;
const USAGE_TOUCH_SCREEN: u16 = 0x04;
const USAGE_TOUCH_PAD: u16 = 0x05;
const USAGE_DEVICE_CONFIGURATION: u16 = 0x0E;
const USAGE_FINGER: u16 = 0x22;
const USAGE_TIP_PRESSURE: u16 = 0x30;
const USAGE_TIP_SWITCH: u16 = 0x42;
const USAGE_CONTACT_ID: u16 = 0x51;
const USAGE_INPUT_MODE: u16 = 0x52;
const USAGE_CONTACT_COUNT: u16 = 0x54;
const USAGE_SCAN_TIME: u16 = 0x56;

/// What went wrong with a HID digitizer: its descriptor, one of its
/// reports, or the device itself.
#[derive(Debug, thiserror::Error)]
pub enum HidError {
    /// `hidreport` could not parse the report descriptor.
    #[error("hid: report descriptor: {0}")]
    Descriptor(#[from] hidreport::ParserError),
    /// The descriptor has no multi-touch report: the interface is a pen, a
    /// mouse fallback or a keyboard, not the touch collection.
    #[error(
        "hid: report descriptor has no touch screen or touch pad collection \
         (usage page 0x0D, usage 0x04 or 0x05) with Finger collections in an input report"
    )]
    NoTouchCollection,
    /// The descriptor's touch report cannot be used (a finger without X,
    /// fingers in different units, a field wider than 32 bits), or the
    /// descriptor is past the budgets that keep a hostile one from
    /// exhausting memory.
    #[error("hid: report descriptor: {problem}")]
    Layout {
        /// What is wrong, and where.
        problem: String,
    },
    /// A zero-length input report.
    #[error("hid: empty input report")]
    EmptyReport,
    /// An input report whose id the descriptor does not declare: garbage.
    #[error("hid: input report id {id} is not declared by the report descriptor")]
    UnknownReport {
        /// The report's first byte.
        id: u8,
    },
    /// A report shorter than the descriptor declares: a truncated input
    /// report, or a feature buffer too small for [`InputMode::set`].
    #[error("hid: {}: {got} bytes, the descriptor declares {expected}", report_name(*report_id))]
    ShortReport {
        /// The report's id; `None` when the descriptor numbers no reports.
        report_id: Option<u8>,
        /// Bytes the descriptor declares, report id byte included.
        expected: usize,
        /// Bytes there were.
        got: usize,
    },
    /// One frame names a contact id twice; the whole report is refused.
    #[error("hid: {}: contact id {id} is reported twice in one frame", report_name(*report_id))]
    DuplicateContact {
        /// The touch report's id; `None` when the descriptor numbers no
        /// reports.
        report_id: Option<u8>,
        /// The repeated contact id.
        id: u32,
    },
    /// The fingers' logical X/Y ranges cannot be stretched over the stage:
    /// a range whose minimum equals its maximum, say.
    #[error("hid: {0}")]
    Calibration(#[from] CalibrationError),
    /// hidapi failed to list, open, configure or read the device; on a read,
    /// the device most likely went away.
    #[error("hid: {what}: {source}")]
    Device {
        /// What was being done (`opening /dev/hidraw3`, `reading an input
        /// report`, …).
        what: String,
        /// hidapi's error.
        source: hidapi::HidError,
    },
    /// The node is there but this user may not open it.
    #[error("hid: {path}: permission denied; {hint}")]
    Permission {
        /// The node.
        path: String,
        /// How to fix it: see [`permission_hint`].
        hint: String,
    },
    /// No listed interface matches the selector.
    #[error("hid: no HID device matches {selector}")]
    NotFound {
        /// The selector, as text.
        selector: String,
    },
    /// Several device paths match the selector equally well.
    #[error(
        "hid: {} devices match {selector} ({}); add a serial or a path to pick one",
        paths.len(),
        paths.join(", ")
    )]
    Ambiguous {
        /// The selector, as text.
        selector: String,
        /// Every path that matches.
        paths: Vec<String>,
    },
}

fn report_name(id: Option<u8>) -> String {
    match id {
        Some(id) => format!("report id {id}"),
        None => "report".to_string(),
    }
}

/// Linux's limit on a report descriptor (`HID_MAX_DESCRIPTOR_SIZE`).
const MAX_DESCRIPTOR: usize = 4096;

/// Budgets of what hidreport (0.6) allocates per descriptor: one field per
/// Report Count of every variable main item (each with a copy of the
/// collections around it), and every usage of a Usage Minimum..Maximum.
/// Real digitizers use a few hundred fields and usages at most.
const MAX_FIELDS: u64 = 8192;
const MAX_RANGE_USAGES: u64 = 1 << 18;
const MAX_COLLECTION_DEPTH: usize = 32;

/// The global items [`check_items`] follows, per Push level.
#[derive(Clone, Copy, Default)]
struct ItemGlobals {
    page_set: bool,
    report_count: u32,
}

/// What hidreport (0.6) does not survive, refused before it sees the
/// descriptor: a Usage without a Usage Page in effect (it panics), and
/// descriptors that make it allocate without bound (it lists every usage of
/// a Usage Minimum..Maximum span, up to 2³², and makes a field per Report
/// Count, up to 2³², each holding the collections around it). Descriptors
/// come from devices and capture files, so either may be hostile.
fn check_items(descriptor: &[u8]) -> Result<(), HidError> {
    if descriptor.len() > MAX_DESCRIPTOR {
        return Err(layout(format!(
            "{} bytes, more than the {MAX_DESCRIPTOR} a descriptor may have",
            descriptor.len()
        )));
    }
    let mut globals = vec![ItemGlobals::default()];
    let mut needs_page = false;
    let (mut minimum, mut maximum) = (None, None);
    let (mut fields, mut range_usages, mut depth) = (0u64, 0u64, 0usize);
    let mut at = 0;
    while at < descriptor.len() {
        let prefix = descriptor[at];
        if prefix == 0xFE {
            // A long item: size, tag, data; hidreport skips them too.
            let size = descriptor.get(at + 1).copied().unwrap_or(0) as usize;
            at += 3 + size;
            continue;
        }
        let size = [0, 1, 2, 4][(prefix & 0x03) as usize];
        let data = descriptor.get(at + 1..at + 1 + size).unwrap_or(&[]);
        let value = data
            .iter()
            .rev()
            .fold(0u32, |v, &b| (v << 8) | u32::from(b));
        let current = globals.last().copied().unwrap_or_default();
        let refuse = |problem: String| Err(layout(format!("byte {at}: {problem}")));
        match ((prefix >> 2) & 0x03, prefix >> 4) {
            // Main items: the locals so far are used, then cleared.
            (0, tag) => {
                if needs_page && !current.page_set {
                    return refuse("a Usage without a Usage Page before it".into());
                }
                if let (Some(min), Some(max)) = (minimum, maximum) {
                    let span = u64::from(u32::saturating_sub(max, min)) + 1;
                    if span > 0x1_0000 {
                        return refuse(format!(
                            "Usage Minimum {min:#x} to Maximum {max:#x} spans more than one \
                             usage page"
                        ));
                    }
                    range_usages += span;
                }
                match tag {
                    // Input, Output, Feature.
                    0x8 | 0x9 | 0xB => fields += u64::from(current.report_count),
                    0xA => depth += 1,
                    0xC => depth = depth.saturating_sub(1),
                    _ => {}
                }
                if fields > MAX_FIELDS {
                    return refuse(format!("more than {MAX_FIELDS} report fields"));
                }
                if range_usages > MAX_RANGE_USAGES {
                    return refuse(format!("more than {MAX_RANGE_USAGES} usages in ranges"));
                }
                if depth > MAX_COLLECTION_DEPTH {
                    return refuse(format!(
                        "collections nested more than {MAX_COLLECTION_DEPTH} deep"
                    ));
                }
                needs_page = false;
                (minimum, maximum) = (None, None);
            }
            (1, 0x0) => {
                if let Some(g) = globals.last_mut() {
                    g.page_set = true;
                }
            }
            (1, 0x9) => {
                if let Some(g) = globals.last_mut() {
                    g.report_count = value;
                }
            }
            (1, 0xA) => globals.push(current),
            // Too many pops is hidreport's own (clean) error.
            (1, 0xB) if globals.len() > 1 => {
                globals.pop();
            }
            (2, tag @ 0x0..=0x2) => {
                // A four-byte usage carries its own page.
                needs_page |= size < 4;
                match tag {
                    0x1 => minimum = Some(value),
                    0x2 => maximum = Some(value),
                    _ => {}
                }
            }
            _ => {}
        }
        at += 1 + size;
    }
    Ok(())
}

fn layout(problem: impl Into<String>) -> HidError {
    HidError::Layout {
        problem: problem.into(),
    }
}

/// Where one value sits in a report and what range the device declares for
/// it. `bits` counts from the start of the report as read from the device,
/// including the report id byte when the descriptor uses report ids.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HidField {
    /// The bits holding the value, least significant first; 1 to 32 of
    /// them.
    pub bits: Range<usize>,
    /// The smallest value the device declares; below zero makes the field
    /// signed.
    pub logical_min: i32,
    /// The largest value the device declares.
    pub logical_max: i32,
}

impl HidField {
    fn from_variable(field: &VariableField, what: &str) -> Result<HidField, HidError> {
        let width = field.bits.len();
        if width == 0 || width > 32 {
            return Err(layout(format!(
                "{what} is {width} bits wide; 1 to 32 are supported"
            )));
        }
        Ok(HidField {
            bits: field.bits.clone(),
            logical_min: field.logical_minimum.into(),
            logical_max: field.logical_maximum.into(),
        })
    }

    /// The field's value, sign-extended when its logical range goes below
    /// zero (the HID rule for signed fields). The caller checks the length.
    fn read(&self, report: &[u8]) -> i64 {
        let mut value: u64 = 0;
        for (i, bit) in self.bits.clone().enumerate() {
            if (report[bit / 8] >> (bit % 8)) & 1 == 1 {
                value |= 1 << i;
            }
        }
        let width = self.bits.len();
        if self.logical_min < 0 && (value >> (width - 1)) & 1 == 1 {
            value as i64 - (1i64 << width)
        } else {
            value as i64
        }
    }

    fn write(&self, report: &mut [u8], value: u32) {
        for (i, bit) in self.bits.clone().enumerate() {
            let mask = 1u8 << (bit % 8);
            if (value >> i) & 1 == 1 {
                report[bit / 8] |= mask;
            } else {
                report[bit / 8] &= !mask;
            }
        }
    }

    fn range(&self) -> [f64; 2] {
        [f64::from(self.logical_min), f64::from(self.logical_max)]
    }
}

/// The fields of one Finger collection: one contact slot of the report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finger {
    /// Tip Switch: non-zero while the finger touches.
    pub tip_switch: HidField,
    /// Contact Identifier: the device's id for the finger, kept while it
    /// is down.
    pub contact_id: HidField,
    /// X, in logical units.
    pub x: HidField,
    /// Y, in logical units, growing downwards.
    pub y: HidField,
    /// Tip Pressure, when the device reports it; normalised over its
    /// logical range.
    pub tip_pressure: Option<HidField>,
}

/// What kind of surface the touch collection says it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// A touch screen (usage 0x04): positions are on a display.
    TouchScreen,
    /// A touch pad (usage 0x05): positions are on a pad of their own.
    TouchPad,
}

/// The Input Mode feature (Device Configuration collection): a device starts
/// out as a mouse and only reports fingers once the host sets this to
/// [`InputMode::MULTI_INPUT`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputMode {
    /// The feature report's id; `None` when the descriptor numbers no
    /// reports.
    pub report_id: Option<u8>,
    /// Bytes of the whole feature report, report id byte included.
    pub report_len: usize,
    /// Where the Input Mode value sits in the report.
    pub field: HidField,
}

impl InputMode {
    /// Input Mode value for "multi-input" (Windows precision touch).
    pub const MULTI_INPUT: u32 = 2;

    /// Writes `value` into a feature report buffer, leaving its other fields
    /// alone: read the report from the device first when it shares the
    /// report with other settings (Device Index, say), then send it back.
    pub fn set(&self, report: &mut [u8], value: u32) -> Result<(), HidError> {
        if report.len() < self.report_len {
            return Err(HidError::ShortReport {
                report_id: self.report_id,
                expected: self.report_len,
                got: report.len(),
            });
        }
        if let Some(id) = self.report_id {
            report[0] = id;
        }
        self.field.write(report, value);
        Ok(())
    }

    /// A fresh feature report selecting multi-input, other fields zero.
    pub fn multi_input_report(&self) -> Vec<u8> {
        let mut report = vec![0; self.report_len];
        self.field.write(&mut report, Self::MULTI_INPUT);
        if let Some(id) = self.report_id {
            report[0] = id;
        }
        report
    }
}

/// What a digitizer's report descriptor says about its touch reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TouchLayout {
    /// Touch screen or touch pad.
    pub surface: Surface,
    /// The input report carrying the fingers; `None` when the descriptor
    /// uses no report ids (and reports have no id byte).
    pub report_id: Option<u8>,
    /// Bytes of the whole input report, report id byte included.
    pub report_len: usize,
    /// Contact slots, in report order.
    pub fingers: Vec<Finger>,
    /// Contact Count: how many slots the frame starting with this report
    /// fills (0 in a hybrid frame's later reports). `None`: every report is
    /// a whole frame of its tip-down slots.
    pub contact_count: Option<HidField>,
    /// Scan Time, which tells a hybrid frame's reports from the next
    /// frame's; `None` when the device has none.
    pub scan_time: Option<HidField>,
    /// The Input Mode feature, when the device has one to switch it to
    /// multi-touch.
    pub input_mode: Option<InputMode>,
    /// Every input report id the descriptor declares, so reports for other
    /// collections (a mouse fallback, a pen) can be told from garbage.
    input_report_ids: Vec<u8>,
}

fn usage_is(usage: &Usage, page: u16, id: u16) -> bool {
    u16::from(usage.usage_page) == page && u16::from(usage.usage_id) == id
}

fn variables(report: &impl Report) -> impl Iterator<Item = &VariableField> {
    report.fields().iter().filter_map(|f| match f {
        Field::Variable(v) => Some(v),
        _ => None,
    })
}

fn report_id_of(report: &impl Report) -> Option<u8> {
    report.report_id().map(u8::from)
}

#[derive(Default)]
struct FingerParts {
    tip_switch: Option<HidField>,
    contact_id: Option<HidField>,
    x: Option<HidField>,
    y: Option<HidField>,
    tip_pressure: Option<HidField>,
}

/// The touch application collection `field` is in, and what surface it
/// is, if any.
fn touch_application(field: &VariableField) -> Option<(hidreport::CollectionId, Surface)> {
    field.collections.iter().find_map(|c| {
        if c.collection_type() != CollectionType::Application {
            return None;
        }
        c.usages().iter().find_map(|u| {
            if usage_is(u, PAGE_DIGITIZER, USAGE_TOUCH_SCREEN) {
                Some((c.id().clone(), Surface::TouchScreen))
            } else if usage_is(u, PAGE_DIGITIZER, USAGE_TOUCH_PAD) {
                Some((c.id().clone(), Surface::TouchPad))
            } else {
                None
            }
        })
    })
}

/// The Finger collection `field` is in, if any.
fn finger_collection(field: &VariableField) -> Option<hidreport::CollectionId> {
    field
        .collections
        .iter()
        .find(|c| {
            c.usages()
                .iter()
                .any(|u| usage_is(u, PAGE_DIGITIZER, USAGE_FINGER))
        })
        .map(|c| c.id().clone())
}

/// The Input Mode field of a Device Configuration feature report, if the
/// descriptor has one (how a Windows precision touchpad is switched to
/// reporting contacts).
fn input_mode(rdesc: &ReportDescriptor) -> Option<Result<InputMode, HidError>> {
    rdesc.feature_reports().iter().find_map(|report| {
        Report::fields(report).iter().find_map(|f| {
            let Field::Variable(v) = f else { return None };
            let in_config = v.collections.iter().any(|c| {
                c.usages()
                    .iter()
                    .any(|u| usage_is(u, PAGE_DIGITIZER, USAGE_DEVICE_CONFIGURATION))
            });
            (in_config && usage_is(&v.usage, PAGE_DIGITIZER, USAGE_INPUT_MODE)).then(|| {
                HidField::from_variable(v, "Input Mode").map(|field| InputMode {
                    report_id: report_id_of(report),
                    report_len: report.size_in_bytes(),
                    field,
                })
            })
        })
    })
}

impl FingerParts {
    /// Finger `i` (from 0) of the touch report, or an error naming the
    /// field it lacks.
    fn finger(self, i: usize) -> Result<Finger, HidError> {
        let missing = |name: &str| {
            layout(format!(
                "finger {} of the touch report has no {name}",
                i + 1
            ))
        };
        Ok(Finger {
            tip_switch: self
                .tip_switch
                .ok_or_else(|| missing("Tip Switch (0x0D/0x42)"))?,
            contact_id: self
                .contact_id
                .ok_or_else(|| missing("Contact Identifier (0x0D/0x51)"))?,
            x: self.x.ok_or_else(|| missing("X (0x01/0x30)"))?,
            y: self.y.ok_or_else(|| missing("Y (0x01/0x31)"))?,
            tip_pressure: self.tip_pressure,
        })
    }
}

impl TouchLayout {
    /// Reads the touch layout out of a report descriptor, as the device
    /// gives it. A descriptor with no touch report, or one that would make
    /// the parser allocate without bound, is refused.
    pub fn parse(descriptor: &[u8]) -> Result<TouchLayout, HidError> {
        if descriptor.is_empty() {
            return Err(layout("the descriptor is empty"));
        }
        check_items(descriptor)?;
        let rdesc = ReportDescriptor::try_from(descriptor)?;
        let input_report_ids = rdesc
            .input_reports()
            .iter()
            .filter_map(report_id_of)
            .collect();

        // The first input report with a field inside a Finger collection of
        // a touch application collection is the touch report.
        let (report, app, surface) = rdesc
            .input_reports()
            .iter()
            .find_map(|report| {
                variables(report).find_map(|v| {
                    let (app, surface) = touch_application(v)?;
                    finger_collection(v)?;
                    Some((report, app, surface))
                })
            })
            .ok_or(HidError::NoTouchCollection)?;
        let report_id = report_id_of(report);

        // Fingers in order of first appearance; the collection id tells one
        // Finger collection from the next even when their items are equal.
        let mut fingers: Vec<(hidreport::CollectionId, FingerParts)> = Vec::new();
        let mut contact_count = None;
        let mut scan_time = None;
        for v in variables(report) {
            if touch_application(v).is_none_or(|(a, _)| a != app) {
                continue;
            }
            let page = u16::from(v.usage.usage_page);
            let id = u16::from(v.usage.usage_id);
            let Some(finger) = finger_collection(v) else {
                if page == PAGE_DIGITIZER && id == USAGE_CONTACT_COUNT {
                    contact_count = Some(HidField::from_variable(v, "Contact Count")?);
                } else if page == PAGE_DIGITIZER && id == USAGE_SCAN_TIME {
                    scan_time = Some(HidField::from_variable(v, "Scan Time")?);
                }
                continue;
            };
            let index = match fingers.iter().position(|(c, _)| *c == finger) {
                Some(index) => index,
                None => {
                    fingers.push((finger, FingerParts::default()));
                    fingers.len() - 1
                }
            };
            let what = |name: &str| format!("finger {} {name}", index + 1);
            let parts = &mut fingers[index].1;
            let slot = match (page, id) {
                (PAGE_DIGITIZER, USAGE_TIP_SWITCH) => &mut parts.tip_switch,
                (PAGE_DIGITIZER, USAGE_CONTACT_ID) => &mut parts.contact_id,
                (PAGE_DIGITIZER, USAGE_TIP_PRESSURE) => &mut parts.tip_pressure,
                (PAGE_GENERIC_DESKTOP, USAGE_X) => &mut parts.x,
                (PAGE_GENERIC_DESKTOP, USAGE_Y) => &mut parts.y,
                // Width, height, azimuth, confidence: not part of a contact yet.
                _ => continue,
            };
            // Some descriptors declare a usage twice (a second X for a
            // different unit); the first is the one Windows uses too.
            if slot.is_none() {
                *slot = Some(HidField::from_variable(v, &what("field"))?);
            }
        }

        let fingers = fingers
            .into_iter()
            .enumerate()
            .map(|(i, (_, parts))| parts.finger(i))
            .collect::<Result<Vec<Finger>, HidError>>()?;
        let input_mode = input_mode(&rdesc);

        Ok(TouchLayout {
            surface,
            report_id,
            report_len: report.size_in_bytes(),
            fingers,
            contact_count,
            scan_time,
            input_mode: input_mode.transpose()?,
            input_report_ids,
        })
    }

    /// Stretches the device's logical X/Y ranges over a `size.x` × `size.y`
    /// stage, flipping y because HID y grows downwards.
    pub(crate) fn default_calibration(&self, stage_size: DVec2) -> Result<Calibration, HidError> {
        let first = &self.fingers[0];
        Ok(Calibration::fit(
            first.x.range(),
            first.y.range(),
            stage_size,
        )?)
    }
}

/// One slot of a report as the device filled it in, in device units.
#[derive(Debug, Clone)]
struct Slot {
    tip: bool,
    id: u32,
    position: DVec2,
    pressure: Option<f64>,
}

/// A hybrid-mode frame still waiting for reports.
#[derive(Debug)]
struct Pending {
    expected: usize,
    scan_time: Option<i64>,
    slots: Vec<Slot>,
}

#[derive(Debug, Clone)]
struct Tracked {
    position: DVec2,
    pressure: Option<f64>,
}

/// Turns one digitizer's input reports into [`ContactFrame`]s. Feed it every
/// input report the device sends with [`push`](HidTouchDecoder::push).
#[derive(Debug)]
pub struct HidTouchDecoder {
    layout: TouchLayout,
    source: SourceId,
    calibration: Calibration,
    pending: Option<Pending>,
    /// Contacts currently down, by HID contact id; ordered so lifts come out
    /// deterministically.
    down: BTreeMap<u32, Tracked>,
}

impl HidTouchDecoder {
    /// Reads the layout from `descriptor`. Without a `calibration`, the
    /// device's logical X/Y ranges are stretched over a stage of
    /// `stage_size`, y flipped because HID y grows downwards. Fails when
    /// the fingers count X or Y over different ranges, since one
    /// calibration serves them all.
    pub fn new(
        descriptor: &[u8],
        source: SourceId,
        calibration: Option<Calibration>,
        stage_size: DVec2,
    ) -> Result<HidTouchDecoder, HidError> {
        let layout = TouchLayout::parse(descriptor)?;
        // One calibration serves every slot, so every slot must count in
        // the same units.
        let first = &layout.fingers[0];
        for (i, finger) in layout.fingers.iter().enumerate().skip(1) {
            if finger.x.range() != first.x.range() || finger.y.range() != first.y.range() {
                return Err(layout_error_ranges(i));
            }
        }
        let calibration = match calibration {
            Some(calibration) => calibration,
            None => layout.default_calibration(stage_size)?,
        };
        Ok(HidTouchDecoder {
            layout,
            source,
            calibration,
            pending: None,
            down: BTreeMap::new(),
        })
    }

    pub(crate) fn layout(&self) -> &TouchLayout {
        &self.layout
    }

    /// Lifts every contact that is down and drops any half-gathered hybrid
    /// frame: for the end of a capture or a device that went away.
    pub fn lift_all(&mut self, time: f64) -> Option<ContactFrame> {
        self.pending = None;
        let contacts: Vec<Contact> = std::mem::take(&mut self.down)
            .into_iter()
            .map(|(id, was)| Contact {
                pressure: was.pressure,
                ..Contact::new(id, Phase::Up, self.calibration.map(was.position))
            })
            .collect();
        (!contacts.is_empty()).then(|| ContactFrame {
            source: self.source.clone(),
            time,
            contacts,
        })
    }

    /// Decodes one input report (report id byte first when the descriptor
    /// uses report ids, as hidapi delivers them). Returns the frame it
    /// completes when that frame changed anything; `None` while a hybrid
    /// frame waits for more reports, for reports of the device's other
    /// collections, and for frames that restate what is already known.
    /// `time` is the report's arrival time in seconds; a frame takes the
    /// time of the report that completes it.
    ///
    /// A malformed report is an error and leaves the state untouched.
    pub fn push(&mut self, report: &[u8], time: f64) -> Result<Option<ContactFrame>, HidError> {
        let Some(&first) = report.first() else {
            return Err(HidError::EmptyReport);
        };
        if let Some(id) = self.layout.report_id
            && first != id
        {
            return if self.layout.input_report_ids.contains(&first) {
                Ok(None)
            } else {
                Err(HidError::UnknownReport { id: first })
            };
        }
        if report.len() < self.layout.report_len {
            return Err(HidError::ShortReport {
                report_id: self.layout.report_id,
                expected: self.layout.report_len,
                got: report.len(),
            });
        }

        let slots_here = self.layout.fingers.len();
        let scan_time = self.layout.scan_time.as_ref().map(|f| f.read(report));
        // A negative count can only be garbage; treat it as none valid.
        let count = (self.layout.contact_count.as_ref())
            .map(|field| usize::try_from(field.read(report)).unwrap_or(0));

        // Which frame this report joins, and how many of its slots are valid.
        let (continuing, expected, take) = match (count, &self.pending) {
            // Without a count every report is a whole frame and only slots
            // with the tip down say anything.
            (None, _) => (false, 0, slots_here),
            // Continuation of a hybrid frame. A different scan time means the
            // frame's earlier reports belong to a scan that was cut short,
            // and this report alone cannot make a frame either.
            (Some(0), Some(pending)) if pending.scan_time == scan_time => {
                let remaining = pending.expected - pending.slots.len();
                (true, pending.expected, remaining.min(slots_here))
            }
            (Some(0), Some(_)) => {
                self.pending = None;
                return Ok(None);
            }
            // A new frame (a count of 0 with nothing pending: nothing is
            // down). An unfinished frame before it lost a report; it is
            // dropped rather than applied, since applying it would lift the
            // fingers that were in the lost report.
            (Some(expected), _) => (false, expected, expected.min(slots_here)),
        };

        let earlier: &[Slot] = match (&self.pending, continuing) {
            (Some(pending), true) => &pending.slots,
            _ => &[],
        };
        let mut fresh: Vec<Slot> = Vec::with_capacity(take);
        for finger in &self.layout.fingers[..take] {
            let tip = finger.tip_switch.read(report) != 0;
            if count.is_none() && !tip {
                continue;
            }
            let id = u32::try_from(finger.contact_id.read(report)).unwrap_or(u32::MAX);
            if earlier.iter().chain(&fresh).any(|s| s.id == id) {
                return Err(HidError::DuplicateContact {
                    report_id: self.layout.report_id,
                    id,
                });
            }
            let position = DVec2::new(finger.x.read(report) as f64, finger.y.read(report) as f64);
            let pressure = finger.tip_pressure.as_ref().map(|p| {
                let [lo, hi] = p.range();
                ((p.read(report) as f64 - lo) / (hi - lo)).clamp(0.0, 1.0)
            });
            fresh.push(Slot {
                tip,
                id,
                position,
                pressure,
            });
        }

        let mut slots = match self.pending.take() {
            Some(pending) if continuing => pending.slots,
            _ => Vec::new(),
        };
        slots.append(&mut fresh);
        if count.is_some() && slots.len() < expected {
            self.pending = Some(Pending {
                expected,
                scan_time,
                slots,
            });
            return Ok(None);
        }
        Ok(self.apply(slots, time))
    }

    /// Diffs a complete frame against the contacts that are down.
    fn apply(&mut self, slots: Vec<Slot>, time: f64) -> Option<ContactFrame> {
        let mut contacts = Vec::new();
        let mut seen = Vec::with_capacity(slots.len());
        for slot in slots {
            seen.push(slot.id);
            let contact = |phase, position, pressure| Contact {
                pressure,
                ..Contact::new(slot.id, phase, self.calibration.map(position))
            };
            match (slot.tip, self.down.get(&slot.id)) {
                (true, None) => {
                    contacts.push(contact(Phase::Down, slot.position, slot.pressure));
                }
                (true, Some(was)) => {
                    if was.position != slot.position || was.pressure != slot.pressure {
                        contacts.push(contact(Phase::Move, slot.position, slot.pressure));
                    }
                }
                // Lift reports carry the final position on most devices, but
                // some zero it; the last position while down is the safe one.
                (false, Some(was)) => {
                    contacts.push(contact(Phase::Up, was.position, was.pressure));
                }
                (false, None) => {}
            }
            if slot.tip {
                self.down.insert(
                    slot.id,
                    Tracked {
                        position: slot.position,
                        pressure: slot.pressure,
                    },
                );
            } else {
                self.down.remove(&slot.id);
            }
        }
        let gone: Vec<u32> = self
            .down
            .keys()
            .copied()
            .filter(|id| !seen.contains(id))
            .collect();
        for id in gone {
            if let Some(was) = self.down.remove(&id) {
                contacts.push(Contact {
                    pressure: was.pressure,
                    ..Contact::new(id, Phase::Up, self.calibration.map(was.position))
                });
            }
        }
        (!contacts.is_empty()).then(|| ContactFrame {
            source: self.source.clone(),
            time,
            contacts,
        })
    }
}

fn layout_error_ranges(finger: usize) -> HidError {
    layout(format!(
        "finger {} declares different X/Y logical ranges from finger 1; \
         one calibration cannot serve both",
        finger + 1
    ))
}

// Device I/O: hidapi, and the loop that runs one device.

/// Bytes read at once; hidraw truncates a report to the buffer, and no
/// full-speed or high-speed report is longer than this.
const READ_BUFFER: usize = 4096;
/// How long one read waits before the loop looks at its stop flag again.
const READ_TIMEOUT_MS: i32 = 100;

/// One HID interface (one top-level collection's usage) as the platform
/// lists it. hidapi lists a device once per top-level usage, so a touch
/// screen with a mouse fallback shows up twice under one path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HidDeviceInfo {
    /// What [`open`] needs: `/dev/hidraw3` on Linux, a platform path
    /// elsewhere.
    pub path: String,
    /// Vendor id.
    pub vendor_id: u16,
    /// Product id.
    pub product_id: u16,
    /// Serial number; `None` when the device has none (or an empty one).
    pub serial: Option<String>,
    /// Manufacturer name; `None` when empty.
    pub manufacturer: Option<String>,
    /// Product name; `None` when empty.
    pub product: Option<String>,
    /// Usage page of the interface's top-level collection (0x0D:
    /// digitizers).
    pub usage_page: u16,
    /// Usage of that collection (0x04 touch screen, 0x05 touch pad, …).
    pub usage: u16,
    /// USB interface number; -1 when the bus has none.
    pub interface: i32,
}

fn non_empty(text: Option<&str>) -> Option<String> {
    text.filter(|t| !t.is_empty()).map(str::to_string)
}

impl From<&hidapi::DeviceInfo> for HidDeviceInfo {
    fn from(info: &hidapi::DeviceInfo) -> HidDeviceInfo {
        HidDeviceInfo {
            path: info.path().to_string_lossy().into_owned(),
            vendor_id: info.vendor_id(),
            product_id: info.product_id(),
            serial: non_empty(info.serial_number()),
            manufacturer: non_empty(info.manufacturer_string()),
            product: non_empty(info.product_string()),
            usage_page: info.usage_page(),
            usage: info.usage(),
            interface: info.interface_number(),
        }
    }
}

impl HidDeviceInfo {
    /// Anything on the Digitizers usage page: touch screens, touch pads,
    /// pens, and their configuration collections.
    pub fn is_digitizer(&self) -> bool {
        self.usage_page == PAGE_DIGITIZER
    }

    /// A touch screen or touch pad collection, what [`run_device`] reads.
    pub fn is_touch(&self) -> bool {
        self.is_digitizer() && matches!(self.usage, USAGE_TOUCH_SCREEN | USAGE_TOUCH_PAD)
    }

    /// Whether this process may open the device, with the fix when it may
    /// not. Listing needs no permission (the descriptor comes from sysfs),
    /// so `puppetry devices` can show what it could not open.
    pub fn check_access(&self) -> Result<(), HidError> {
        check_access(&self.path, Some(self.vendor_id))
    }
}

/// What to do when a hidraw node is not readable; with the vendor id when
/// it is known, so the udev rule can be pasted as is.
pub fn permission_hint(vendor_id: Option<u16>) -> String {
    let vendor = vendor_id.map_or_else(|| "XXXX".to_string(), |v| format!("{v:04x}"));
    format!(
        "add the user to the `input` or `plugdev` group, or install a udev rule such as \
         `KERNEL==\"hidraw*\", ATTRS{{idVendor}}==\"{vendor}\", MODE=\"0660\", GROUP=\"input\"` \
         in /etc/udev/rules.d/70-puppetry.rules, then replug the device"
    )
}

/// hidapi reports a refused open as a message, so the node is tried
/// directly first to tell "permission denied" from the rest.
fn check_access(path: &str, vendor_id: Option<u16>) -> Result<(), HidError> {
    #[cfg(target_os = "linux")]
    if let Err(e) = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        && e.kind() == std::io::ErrorKind::PermissionDenied
    {
        return Err(HidError::Permission {
            path: path.to_string(),
            hint: permission_hint(vendor_id),
        });
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (path, vendor_id);
    Ok(())
}

fn api() -> Result<hidapi::HidApi, HidError> {
    hidapi::HidApi::new().map_err(|source| HidError::Device {
        what: "listing devices".to_string(),
        source,
    })
}

/// Every HID interface the platform knows of, in its order. Filter with
/// [`HidDeviceInfo::is_touch`] for what [`run_device`] can read.
pub fn list_devices() -> Result<Vec<HidDeviceInfo>, HidError> {
    Ok(api()?.device_list().map(HidDeviceInfo::from).collect())
}

/// Which device to open. Every field given must match; none given matches
/// any device.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HidSelector {
    /// The platform path (`/dev/hidraw3`), exactly; [`open`] tries it even
    /// when the platform does not list it.
    pub path: Option<String>,
    /// Vendor id.
    pub vendor_id: Option<u16>,
    /// Product id.
    pub product_id: Option<u16>,
    /// Serial number, exactly.
    pub serial: Option<String>,
}

impl HidSelector {
    /// Whether `info` is an interface this selector names: every field
    /// given is equal.
    pub fn matches(&self, info: &HidDeviceInfo) -> bool {
        self.path.as_ref().is_none_or(|p| *p == info.path)
            && self.vendor_id.is_none_or(|v| v == info.vendor_id)
            && self.product_id.is_none_or(|p| p == info.product_id)
            && self
                .serial
                .as_ref()
                .is_none_or(|s| info.serial.as_ref() == Some(s))
    }

    /// Of the listed interfaces that match, the one path to open: touch
    /// collections first, then any digitizer, then anything, because a
    /// vendor:product pair often names a device with several interfaces.
    /// More than one path at the best level is ambiguous.
    pub fn pick<'a>(&self, devices: &'a [HidDeviceInfo]) -> Result<&'a HidDeviceInfo, HidError> {
        let matching: Vec<&HidDeviceInfo> = devices.iter().filter(|d| self.matches(d)).collect();
        let levels: [&dyn Fn(&HidDeviceInfo) -> bool; 3] = [
            &HidDeviceInfo::is_touch,
            &HidDeviceInfo::is_digitizer,
            &|_| true,
        ];
        for level in levels {
            let mut paths: Vec<&HidDeviceInfo> = Vec::new();
            for device in matching.iter().copied().filter(|d| level(d)) {
                if !paths.iter().any(|p| p.path == device.path) {
                    paths.push(device);
                }
            }
            match paths.len() {
                0 => continue,
                1 => return Ok(paths[0]),
                _ => {
                    return Err(HidError::Ambiguous {
                        selector: self.to_string(),
                        paths: paths.iter().map(|d| d.path.clone()).collect(),
                    });
                }
            }
        }
        Err(HidError::NotFound {
            selector: self.to_string(),
        })
    }
}

impl std::fmt::Display for HidSelector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if let Some(path) = &self.path {
            parts.push(format!("path {path}"));
        }
        match (self.vendor_id, self.product_id) {
            (Some(v), Some(p)) => parts.push(format!("{v:04x}:{p:04x}")),
            (Some(v), None) => parts.push(format!("vendor {v:04x}")),
            (None, Some(p)) => parts.push(format!("product {p:04x}")),
            (None, None) => {}
        }
        if let Some(serial) = &self.serial {
            parts.push(format!("serial {serial:?}"));
        }
        if parts.is_empty() {
            f.write_str("any device")
        } else {
            f.write_str(&parts.join(", "))
        }
    }
}

/// Opens the device `selector` picks (see [`HidSelector::pick`]). A path
/// the platform does not list is still tried, since it was named outright.
pub fn open(selector: &HidSelector) -> Result<hidapi::HidDevice, HidError> {
    let api = api()?;
    let devices: Vec<HidDeviceInfo> = api.device_list().map(HidDeviceInfo::from).collect();
    let (path, vendor_id) = match (selector.pick(&devices), &selector.path) {
        (Ok(device), _) => (device.path.clone(), Some(device.vendor_id)),
        (Err(HidError::NotFound { .. }), Some(path)) => (path.clone(), selector.vendor_id),
        (Err(e), _) => return Err(e),
    };
    check_access(&path, vendor_id)?;
    let c_path = std::ffi::CString::new(path.clone()).map_err(|_| HidError::NotFound {
        selector: selector.to_string(),
    })?;
    api.open_path(&c_path).map_err(|source| HidError::Device {
        what: format!("opening {path}"),
        source,
    })
}

/// What [`run_device`] needs from a device; [`hidapi::HidDevice`] is one,
/// a test double another.
pub trait ReportDevice {
    /// The device's raw report descriptor.
    fn descriptor(&self) -> Result<Vec<u8>, HidError>;
    /// Sends a feature report; the first byte is the report id, 0 when the
    /// device does not number its reports (hidapi's convention).
    fn send_feature(&self, report: &[u8]) -> Result<(), HidError>;
    /// Reads one input report into `buf`, waiting at most `timeout_ms`;
    /// `Ok(0)` when none came in time.
    fn read(&self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, HidError>;
}

impl ReportDevice for hidapi::HidDevice {
    fn descriptor(&self) -> Result<Vec<u8>, HidError> {
        let mut buf = vec![0; hidapi::MAX_REPORT_DESCRIPTOR_SIZE];
        let len = self
            .get_report_descriptor(&mut buf)
            .map_err(|source| HidError::Device {
                what: "reading the report descriptor".to_string(),
                source,
            })?;
        buf.truncate(len);
        Ok(buf)
    }

    fn send_feature(&self, report: &[u8]) -> Result<(), HidError> {
        self.send_feature_report(report)
            .map_err(|source| HidError::Device {
                what: "sending a feature report".to_string(),
                source,
            })
    }

    fn read(&self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, HidError> {
        self.read_timeout(buf, timeout_ms)
            .map_err(|source| HidError::Device {
                what: "reading an input report".to_string(),
                source,
            })
    }
}

impl InputMode {
    /// The multi-input feature report as hidapi sends it: with a leading 0
    /// standing in for the report id when the device has none.
    pub fn multi_input_feature(&self) -> Vec<u8> {
        let report = self.multi_input_report();
        match self.report_id {
            Some(_) => report,
            None => std::iter::once(0).chain(report).collect(),
        }
    }
}

/// Runs one digitizer until told to stop: reads its descriptor, switches it
/// to multi-input when it has an Input Mode feature (a failure is logged and
/// the device read anyway: many report fingers from power-up), then decodes
/// every input report and sends each frame to `frames`. A full channel makes
/// this wait, so no frame is dropped; being blocking, it belongs on its own
/// thread (`std::thread` or `spawn_blocking`), never on an async task.
///
/// Times are seconds since this call started. Malformed reports are
/// skipped, and logged through a [`LogLimiter`]: a few lines, then a
/// count. Returns `Ok` once `stop` is set (lifting whatever is still down
/// first) or `frames` is closed. A failed read lifts every contact
/// still down and returns the error: the device went away, and the caller
/// decides whether to reopen it.
pub fn run_device(
    device: &impl ReportDevice,
    source: SourceId,
    calibration: Option<Calibration>,
    stage_size: DVec2,
    frames: &tokio::sync::mpsc::Sender<ContactFrame>,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<(), HidError> {
    use std::sync::atomic::Ordering;
    let started = std::time::Instant::now();
    let descriptor = device.descriptor()?;
    let mut decoder = HidTouchDecoder::new(&descriptor, source.clone(), calibration, stage_size)?;
    if let Some(mode) = &decoder.layout().input_mode
        && let Err(e) = device.send_feature(&mode.multi_input_feature())
    {
        tracing::warn!(%source, error = %e, "hid: could not select multi-input mode; reading anyway");
    }
    let mut buffer = vec![0u8; READ_BUFFER];
    let mut complaints = LogLimiter::new(std::time::Instant::now());
    let summary = |skipped: u64| {
        tracing::warn!(%source, "hid: {skipped} more malformed reports were skipped unlogged");
    };
    loop {
        if let Some(skipped) = complaints.take_summary(std::time::Instant::now()) {
            summary(skipped);
        }
        if frames.is_closed() {
            if let Some(skipped) = complaints.take_remaining() {
                summary(skipped);
            }
            return Ok(());
        }
        if stop.load(Ordering::Relaxed) {
            if let Some(skipped) = complaints.take_remaining() {
                summary(skipped);
            }
            if let Some(frame) = decoder.lift_all(started.elapsed().as_secs_f64()) {
                let _ = frames.blocking_send(frame);
            }
            return Ok(());
        }
        let len = match device.read(&mut buffer, READ_TIMEOUT_MS) {
            Ok(len) => len,
            Err(error) => {
                if let Some(skipped) = complaints.take_remaining() {
                    summary(skipped);
                }
                if let Some(frame) = decoder.lift_all(started.elapsed().as_secs_f64()) {
                    // A closed channel has nobody left to tell; the error
                    // still goes back.
                    let _ = frames.blocking_send(frame);
                }
                return Err(error);
            }
        };
        if len == 0 {
            continue;
        }
        let time = started.elapsed().as_secs_f64();
        match decoder.push(&buffer[..len.min(buffer.len())], time) {
            Ok(Some(frame)) => {
                if frames.blocking_send(frame).is_err() {
                    return Ok(());
                }
            }
            Ok(None) => {}
            Err(e) => {
                // A device stuck sending garbage would flood the log; the
                // summaries still say how bad it is.
                if complaints.allow(std::time::Instant::now()) {
                    let error = clip(&e.to_string(), MAX_ECHO);
                    tracing::warn!(%source, %error, "hid: skipping a malformed report");
                }
            }
        }
    }
}
