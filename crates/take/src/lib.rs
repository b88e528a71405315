//! Takes: what the stage did during a performance, written append-only as
//! it happens and read back for replay, overdub and export. A take holds,
//! step by step, the [`Change`]s the stage thread applied (input frames,
//! pins, paint dabs, key poses…), the handle [`StageEvent`]s they caused,
//! and the vertex frames each solve produced, with their times — so
//! replaying the changes into the same stage reproduces the frames bit for
//! bit, and an export shows exactly what was seen. `docs/takes.md`
//! describes the file.
//!
//! The file is a magic line and a run of framed records (length, kind,
//! payload, CRC-32). A daemon killed mid-write leaves at most one partial
//! record at the end: the reader reports it as a truncated tail and keeps
//! everything before it. A damaged record with more of the take after it
//! is not a cut tail: the reader says so as an error naming the record
//! (and can go on past it), so `takes --verify` fails on it. Every record
//! read is bounded (`puppetry_limits::files`): its times, its changes and
//! the contacts it lands or holds, so a crafted take cannot make a replay
//! panic or stall. [`recorder`] writes on a thread of its own so the
//! stage thread only hands records over; [`replay`] replays a take into a
//! [`Stage`]. Every public item is documented (`missing_docs` is on here).

pub mod clock;
pub mod recorder;
pub mod replay;

pub use clock::{Clock, ClockSource};

use std::collections::{HashMap, HashSet};
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use glam::DVec2;
use puppetry_contact::Phase;
use puppetry_limits::files::{MAX_TAKE_CONTACTS, MAX_TAKE_SECONDS, MAX_TAKE_STEP_CHANGES};
use puppetry_mesh::Mesh;
use puppetry_mesh::file::{self as named_file, FileError};
use puppetry_stage::{Change, Stage, StageEvent};
use serde::{Deserialize, Serialize};

/// The first bytes of every take.
pub const MAGIC: &[u8; 8] = b"PTAKE01\n";
/// The file name ending of takes.
pub const EXTENSION: &str = "take";
/// A record longer than this is corruption, not data (a 1M-vertex frame is
/// 8 MB).
const MAX_RECORD: u32 = 64 << 20;

const KIND_HEADER: u8 = 1;
const KIND_STEP: u8 = 2;
const KIND_FRAME: u8 = 3;
const KIND_END: u8 = 4;
const KIND_CLOCK: u8 = 5;

/// Why a take could not be written, read or replayed; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum TakeError {
    /// A take (or, for [`list`], its folder) could not be created, opened,
    /// read or written, or the recorder's writer thread could not start.
    #[error("{file}: {source}")]
    Io {
        /// The take's path (the folder's, for [`list`]), as given.
        file: String,
        /// What the operating system said.
        source: io::Error,
    },
    /// Not a regular file (a FIFO would block the reader for ever).
    #[error(transparent)]
    File(#[from] FileError),
    /// The file does not start with [`MAGIC`].
    #[error("{file}: not a take (it does not start with the take magic)")]
    NotATake {
        /// The file's path, as given.
        file: String,
    },
    /// A record is damaged (an impossible length, a checksum mismatch with
    /// more of the take after it, a payload that does not decode or holds
    /// impossible values), breaks the take budget of
    /// `puppetry_limits::files` (times, changes, contacts), or the header
    /// is missing.
    #[error("{file}: record {index} at byte {offset}: {problem}")]
    Corrupt {
        /// The take's path, as given.
        file: String,
        /// The record's place in the take, the header being record 0.
        index: usize,
        /// Where the record starts in the file (its length field), in bytes.
        offset: u64,
        /// What is wrong with it.
        problem: String,
    },
    /// The header's version is newer than [`VERSION`], the newest this
    /// build reads.
    #[error("{file}: take version {version} is newer than this build reads ({VERSION})")]
    Version {
        /// The take's path, as given.
        file: String,
        /// The version the take's header gives.
        version: u32,
    },
    /// The take does not fit the stage it is replayed into (see
    /// [`Header::check_stage`]), or one of its steps cannot be replayed.
    #[error("{file}: {problem}")]
    Stage {
        /// The take's path, as given.
        file: String,
        /// What does not fit, naming the puppet or the step.
        problem: String,
    },
    /// [`TakeWriter::create`] found a file at the path: a take is never
    /// overwritten.
    #[error("{file}: already exists")]
    Exists {
        /// The path, as given.
        file: String,
    },
}

/// The take format's version, in every header: 2 added [`Record::Clock`]
/// (a version 1 reader would refuse its kind as damage, so it says
/// "newer" instead); 3 added [`PuppetInfo::added`] (a version 2 reader
/// refuses the unknown field, so it says "newer" too).
pub const VERSION: u32 = 3;

/// A puppet as the take saw it: its rest mesh's hash tells a take of
/// another stage, or of a mesh changed since, from a replayable one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PuppetInfo {
    /// The puppet's name on the stage.
    pub name: String,
    /// Its rest mesh's vertex count: the points each of its frames holds.
    pub vertices: usize,
    /// Its rest mesh's triangle count.
    pub triangles: usize,
    /// FNV-1a 64 of the rest mesh on the stage (vertices' f64 bits, then
    /// triangles), in hex.
    pub rest_hash: String,
    /// FNV-1a 64 of the puppet's rig and the stage file's pins: the same
    /// mesh rigged or pinned otherwise is another stage.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub setup_hash: String,
    /// The puppet's stage-file entry, for a puppet the stage file does not
    /// have (a picture a director added, kept in the puppets folder by
    /// absolute path; a curve drawn on the page): so the take carries what
    /// exporting, verifying and playing it from the command line need
    /// ([`stage_config`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub added: Option<Box<puppetry_stage::config::PuppetConfig>>,
}

/// The first record of a take.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// The format version the take was written in ([`VERSION`] when
    /// written by this build); a reader refuses a newer one.
    pub version: u32,
    /// The name the take was recorded under (listings name a take by its
    /// file instead, see [`TakeSummary::name`]).
    pub name: String,
    /// The stage file the daemon ran, as it named it.
    pub stage_file: String,
    /// The stage's width when the take began, in stage units.
    pub stage_width: f64,
    /// The stage's height when the take began, in stage units.
    pub stage_height: f64,
    /// Every puppet of the stage, in id order (removed ones included): a
    /// frame's `puppet` indexes it.
    pub puppets: Vec<PuppetInfo>,
    /// Wall-clock start, seconds since the Unix epoch.
    pub started_unix: f64,
    /// The stage had seen no change before the take began, so replaying
    /// the take into a stage fresh from its file reproduces it exactly.
    pub fresh: bool,
    /// Takes played back into this one while it was recorded (overdub).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub layers: Vec<String>,
    /// The puppets on stage, bottom to top, when a director had removed
    /// or reordered puppets (the lineup cannot change while a take
    /// records); none for the stage file's own lineup, every puppet in id
    /// order. Exports draw these and only these.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on_stage: Option<Vec<u32>>,
}

impl Header {
    /// The header of a take of `stage`, as the daemon runs it.
    pub fn of_stage(name: &str, stage_file: &str, stage: &Stage, fresh: bool) -> Header {
        Header {
            version: VERSION,
            name: name.to_string(),
            stage_file: stage_file.to_string(),
            stage_width: stage.width,
            stage_height: stage.height,
            puppets: stage
                .puppets()
                .iter()
                .map(|p| PuppetInfo {
                    name: p.name.clone(),
                    vertices: p.mesh.vertices().len(),
                    triangles: p.mesh.triangles().len(),
                    rest_hash: rest_hash(&p.mesh),
                    setup_hash: setup_hash(p),
                    added: None,
                })
                .collect(),
            started_unix: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs_f64())
                .unwrap_or(0.0),
            fresh,
            layers: Vec::new(),
            on_stage: lineup_if_changed(stage),
        }
    }

    /// The puppets an export draws, bottom to top (see `on_stage`).
    pub fn drawn(&self) -> Vec<u32> {
        self.on_stage
            .clone()
            .unwrap_or_else(|| (0..self.puppets.len() as u32).collect())
    }

    /// Why this take cannot be replayed into `stage`: another stage (puppet
    /// count or names) or a changed rest mesh.
    pub fn check_stage(&self, stage: &Stage) -> Result<(), String> {
        if self.puppets.len() != stage.puppets().len() {
            return Err(format!(
                "recorded with {} puppets, the stage has {}",
                self.puppets.len(),
                stage.puppets().len()
            ));
        }
        let drawn = self.drawn();
        for (i, (recorded, p)) in self.puppets.iter().zip(stage.puppets()).enumerate() {
            if recorded.name != p.name {
                return Err(format!(
                    "puppets[{i}]: recorded as {:?}, the stage has {:?}",
                    recorded.name, p.name
                ));
            }
            // A puppet removed before the take has no part in it (and let
            // go of its stage-file pins when it went).
            if !drawn.contains(&(i as u32)) {
                continue;
            }
            let now = rest_hash(&p.mesh);
            if recorded.rest_hash != now {
                return Err(format!(
                    "puppets[{i}] ({}): rest mesh changed since the take (hash {} then, {now} now)",
                    p.name, recorded.rest_hash
                ));
            }
            let setup = setup_hash(p);
            if !recorded.setup_hash.is_empty() && recorded.setup_hash != setup {
                return Err(format!(
                    "puppets[{i}] ({}): rigged or pinned otherwise than when the take was recorded \
                     (another stage file than {}?)",
                    p.name, self.stage_file
                ));
            }
        }
        Ok(())
    }
}

/// The stage file as the take knew it, from `config` (the stage file it was
/// recorded on): puppets added to the stage after the take was recorded
/// are left out (with their pads), and puppets added before it, which the
/// stage file lacks, are put back from the entries the take carries
/// ([`PuppetInfo::added`]). Puppet ids are never reused and new puppets are
/// appended, so the take's puppets are the first ones, names and all;
/// anything else is left for [`Header::check_stage`] to refuse.
pub fn stage_config<'a>(
    config: &'a puppetry_stage::config::StageConfig,
    header: &Header,
) -> std::borrow::Cow<'a, puppetry_stage::config::StageConfig> {
    let n = header.puppets.len();
    let names_agree = header
        .puppets
        .iter()
        .zip(&config.puppets)
        .all(|(recorded, p)| recorded.name == p.name);
    if !names_agree || config.puppets.len() == n {
        return std::borrow::Cow::Borrowed(config);
    }
    let mut as_recorded = config.clone();
    if config.puppets.len() > n {
        as_recorded.puppets.truncate(n);
        let kept: Vec<String> = as_recorded.puppets.iter().map(|p| p.name.clone()).collect();
        as_recorded.pads.retain(|pad| kept.contains(&pad.puppet));
    } else {
        for recorded in &header.puppets[config.puppets.len()..] {
            match &recorded.added {
                Some(entry) => as_recorded.puppets.push((**entry).clone()),
                None => break,
            }
        }
    }
    std::borrow::Cow::Owned(as_recorded)
}

/// The stage's lineup, bottom to top, unless it is every puppet in id
/// order (nothing removed or reordered).
fn lineup_if_changed(stage: &Stage) -> Option<Vec<u32>> {
    let lineup: Vec<u32> = stage.on_stage().map(|p| p.id).collect();
    let in_id_order = lineup.len() == stage.puppets().len()
        && lineup.iter().enumerate().all(|(i, &id)| id as usize == i);
    (!in_id_order).then_some(lineup)
}

/// A stable hash of a rest mesh (FNV-1a 64, hex): the same bits give the
/// same hash on every machine and build.
pub fn rest_hash(mesh: &Mesh) -> String {
    let mut h = Fnv::new();
    for v in mesh.vertices() {
        h.eat(&v.x.to_bits().to_le_bytes());
        h.eat(&v.y.to_bits().to_le_bytes());
    }
    for t in mesh.triangles() {
        for i in t {
            h.eat(&i.to_le_bytes());
        }
    }
    h.hex()
}

/// A stable hash of a puppet's rig (kind and shape) and its stage-file pins.
pub fn setup_hash(puppet: &puppetry_stage::Puppet) -> String {
    use puppetry_stage::{Grip, HandleKind, Owner, Rig};
    let mut h = Fnv::new();
    match puppet.rig() {
        Rig::Free(_) => h.eat(b"free"),
        Rig::Grid(r) => {
            let spec = r.ffd().spec();
            h.eat(b"grid");
            h.eat(&(spec.columns as u64).to_le_bytes());
            h.eat(&(spec.rows as u64).to_le_bytes());
        }
        Rig::Skeleton(r) => {
            h.eat(b"skeleton");
            for j in r.deformer().skeleton().joints() {
                h.eat(&j.x.to_bits().to_le_bytes());
                h.eat(&j.y.to_bits().to_le_bytes());
            }
        }
        Rig::Curve(r) => {
            // The centre line is in the rest mesh's hash; how it peels is not.
            h.eat(b"curve");
            let peel = r.peel();
            for v in [r.half_width(), peel.initial_radius, peel.growth_rate] {
                h.eat(&v.to_bits().to_le_bytes());
            }
        }
    }
    for pin in puppet
        .handles()
        .iter()
        .filter(|h| h.kind == HandleKind::Pin && h.owner == Owner::Config)
    {
        if let Grip::Point(puppetry_deform::Anchor::Point { triangle, bary }) = pin.grip {
            h.eat(&triangle.to_le_bytes());
            for b in bary {
                h.eat(&b.to_bits().to_le_bytes());
            }
        }
        h.eat(&pin.target.x.to_bits().to_le_bytes());
        h.eat(&pin.target.y.to_bits().to_le_bytes());
    }
    h.hex()
}

/// FNV-1a 64: stable across machines and builds, unlike std's hasher.
struct Fnv(u64);

impl Fnv {
    fn new() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }

    fn eat(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// One solve of the stage: what was applied before it, and the handle
/// events that caused. The frames it produced follow as [`Record::Frame`]s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Step {
    /// Seconds since the take began.
    pub t: f64,
    /// What the stage thread applied before this solve, in order.
    pub changes: Vec<Change>,
    /// The handle events those changes caused (handles made, moved,
    /// removed), in order; left out of the file when there are none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<StageEvent>,
}

/// A puppet's solved vertices after a step.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The puppet's id: its index in [`Header::puppets`].
    pub puppet: u32,
    /// Seconds since the take began.
    pub t: f64,
    /// The puppet's deformed vertices in stage coordinates, in rest-mesh
    /// order, as f32 `[x, y]` the way clients receive them.
    pub points: Vec<[f32; 2]>,
}

impl Frame {
    /// A frame of a pose, rounded to f32 as clients receive it.
    pub fn of_pose(puppet: u32, t: f64, pose: &[DVec2]) -> Frame {
        Frame {
            puppet,
            t,
            points: pose.iter().map(|p| [p.x as f32, p.y as f32]).collect(),
        }
    }
}

/// How a take ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct End {
    /// Seconds since the take began.
    pub t: f64,
    /// Why: "stopped", "shutdown", or the error that stopped it.
    pub reason: String,
}

/// One record of a take, in the order a take holds them: a [`Header`]
/// first, then each [`Step`] followed by the [`Frame`]s its solve produced,
/// [`Clock`]s as the show's clock is heard, and an [`End`] when the take
/// was stopped rather than killed.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// The first record: the stage the take was recorded on.
    Header(Header),
    /// One solve's changes and the handle events they caused (JSON).
    Step(Step),
    /// A puppet's vertices after the step before it (binary, so a large
    /// mesh's frames stay compact).
    Frame(Frame),
    /// The last record: when and why the take stopped.
    End(End),
    /// The show's clock, read while the take recorded (JSON).
    Clock(Clock),
}

impl Record {
    fn encode(&self, out: &mut Vec<u8>) {
        out.clear();
        out.extend_from_slice(&[0; 4]);
        match self {
            Record::Header(h) => {
                out.push(KIND_HEADER);
                serde_json::to_writer(&mut *out, h).expect("headers serialise");
            }
            Record::Step(s) => {
                out.push(KIND_STEP);
                serde_json::to_writer(&mut *out, s).expect("steps serialise");
            }
            Record::End(e) => {
                out.push(KIND_END);
                serde_json::to_writer(&mut *out, e).expect("ends serialise");
            }
            Record::Clock(c) => {
                out.push(KIND_CLOCK);
                serde_json::to_writer(&mut *out, c).expect("clocks serialise");
            }
            Record::Frame(f) => {
                out.push(KIND_FRAME);
                out.extend_from_slice(&f.puppet.to_le_bytes());
                out.extend_from_slice(&f.t.to_le_bytes());
                out.extend_from_slice(&(f.points.len() as u32).to_le_bytes());
                for p in &f.points {
                    out.extend_from_slice(&p[0].to_le_bytes());
                    out.extend_from_slice(&p[1].to_le_bytes());
                }
            }
        }
        let length = (out.len() - 4) as u32;
        out[..4].copy_from_slice(&length.to_le_bytes());
        let crc = crc32fast::hash(&out[4..]);
        out.extend_from_slice(&crc.to_le_bytes());
    }

    fn decode(kind: u8, payload: &[u8]) -> Result<Record, String> {
        let json = |what: &str| format!("{what}: ");
        match kind {
            KIND_HEADER => serde_json::from_slice(payload)
                .map(Record::Header)
                .map_err(|e| json("header") + &e.to_string()),
            KIND_STEP => serde_json::from_slice(payload)
                .map(Record::Step)
                .map_err(|e| json("step") + &e.to_string()),
            KIND_END => serde_json::from_slice(payload)
                .map(Record::End)
                .map_err(|e| json("end") + &e.to_string()),
            KIND_CLOCK => serde_json::from_slice(payload)
                .map(Record::Clock)
                .map_err(|e| json("clock") + &e.to_string()),
            KIND_FRAME => {
                if payload.len() < 16 {
                    return Err(format!(
                        "frame: {} bytes, shorter than its head",
                        payload.len()
                    ));
                }
                let u32_at = |o: usize| u32::from_le_bytes(payload[o..o + 4].try_into().unwrap());
                let puppet = u32_at(0);
                let t = f64::from_le_bytes(payload[4..12].try_into().unwrap());
                let count = u32_at(12) as usize;
                if payload.len() != 16 + count * 8 {
                    return Err(format!(
                        "frame: {count} points need {} bytes, the record has {}",
                        16 + count * 8,
                        payload.len()
                    ));
                }
                let f32_at = |o: usize| f32::from_le_bytes(payload[o..o + 4].try_into().unwrap());
                let points = (0..count)
                    .map(|i| [f32_at(16 + i * 8), f32_at(20 + i * 8)])
                    .collect();
                Ok(Record::Frame(Frame { puppet, t, points }))
            }
            other => Err(format!("unknown record kind {other}")),
        }
    }
}

/// Writes a take: the magic, the header, then records as they come.
pub struct TakeWriter {
    file: String,
    out: BufWriter<File>,
    scratch: Vec<u8>,
}

impl TakeWriter {
    /// Creates `path` (never overwriting a take) and writes its header.
    pub fn create(path: &Path, header: &Header) -> Result<TakeWriter, TakeError> {
        let file = path.display().to_string();
        let io = |source| TakeError::Io {
            file: file.clone(),
            source,
        };
        let created = File::options().write(true).create_new(true).open(path);
        let handle = match created {
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                return Err(TakeError::Exists { file });
            }
            other => other.map_err(io)?,
        };
        let mut writer = TakeWriter {
            file: file.clone(),
            out: BufWriter::with_capacity(1 << 16, handle),
            scratch: Vec::new(),
        };
        writer.out.write_all(MAGIC).map_err(io)?;
        writer.write(&Record::Header(header.clone()))?;
        writer.flush()?;
        Ok(writer)
    }

    /// Appends one record, framed with its length and CRC-32, to the
    /// buffer; it reaches the operating system at the next
    /// [`TakeWriter::flush`] or when the buffer fills.
    pub fn write(&mut self, record: &Record) -> Result<(), TakeError> {
        record.encode(&mut self.scratch);
        self.out
            .write_all(&self.scratch)
            .map_err(|source| TakeError::Io {
                file: self.file.clone(),
                source,
            })
    }

    /// Hands what is buffered to the operating system, so a killed daemon
    /// loses nothing written before this.
    pub fn flush(&mut self) -> Result<(), TakeError> {
        self.out.flush().map_err(|source| TakeError::Io {
            file: self.file.clone(),
            source,
        })
    }
}

/// How a take's file ends.
#[derive(Debug, Clone, PartialEq)]
pub enum Tail {
    /// After an end record (the take was stopped).
    Ended(End),
    /// Every record is whole but there is no end record (the daemon was
    /// killed between two records).
    Unended,
    /// The last record is partial or damaged (the daemon was killed while
    /// writing it): it and what follows were skipped.
    Truncated {
        /// Where the skipped record starts in the file, in bytes.
        offset: u64,
        /// How many bytes, from there to the end of the file, were skipped.
        bytes: u64,
        /// What was wrong with it: a partial length, a record shorter than
        /// its length says, a checksum mismatch.
        problem: String,
    },
}

/// Reads a take record by record, in bounded memory. [`TakeReader::open`]
/// reads the header; iterating yields the records after it. An `Err` item
/// for a damaged record may be followed by more records (the framing held
/// past it); once the iterator ends, [`TakeReader::tail`] says how.
pub struct TakeReader {
    file: String,
    input: BufReader<File>,
    /// The take's header, read by [`TakeReader::open`].
    pub header: Header,
    offset: u64,
    index: usize,
    tail: Option<Tail>,
    length: u64,
    /// Contacts held down, by source, as the steps read so far left them:
    /// a take may hold at most `MAX_TAKE_CONTACTS` at once.
    held: HashMap<String, HashSet<u32>>,
}

impl TakeReader {
    /// Opens the take at `path`: a regular file (of any size: each record
    /// is bounded instead) that starts with [`MAGIC`] and a header of a
    /// version this build reads.
    pub fn open(path: &Path) -> Result<TakeReader, TakeError> {
        let file = path.display().to_string();
        let io = |source| TakeError::Io {
            file: file.clone(),
            source,
        };
        let handle = named_file::open_regular(path).map_err(|e| match e {
            FileError::Io { file, source } => TakeError::Io { file, source },
            other => TakeError::File(other),
        })?;
        let length = handle.metadata().map_err(io)?.len();
        let mut input = BufReader::with_capacity(1 << 16, handle);
        let mut magic = [0u8; 8];
        if input.read_exact(&mut magic).is_err() || &magic != MAGIC {
            return Err(TakeError::NotATake { file });
        }
        let mut reader = TakeReader {
            file: file.clone(),
            input,
            header: Header {
                version: 0,
                name: String::new(),
                stage_file: String::new(),
                stage_width: 0.0,
                stage_height: 0.0,
                puppets: Vec::new(),
                started_unix: 0.0,
                fresh: false,
                layers: Vec::new(),
                on_stage: None,
            },
            offset: MAGIC.len() as u64,
            index: 0,
            tail: None,
            length,
            held: HashMap::new(),
        };
        match reader.next_record() {
            Some(Ok(Record::Header(h))) => {
                if h.version > VERSION {
                    return Err(TakeError::Version {
                        file,
                        version: h.version,
                    });
                }
                reader.header = h;
                Ok(reader)
            }
            Some(Err(e)) => Err(e),
            _ => Err(TakeError::Corrupt {
                file,
                index: 0,
                offset: MAGIC.len() as u64,
                problem: "the header record is missing or damaged".into(),
            }),
        }
    }

    /// The take's path as given to [`TakeReader::open`], for messages.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// How the file ended; `None` until every record has been read.
    pub fn tail(&self) -> Option<&Tail> {
        self.tail.as_ref()
    }

    fn next_record(&mut self) -> Option<Result<Record, TakeError>> {
        if self.tail.is_some() {
            return None;
        }
        let start = self.offset;
        let truncated = |reader: &mut TakeReader, problem: String| {
            reader.tail = Some(Tail::Truncated {
                offset: start,
                bytes: reader.length.saturating_sub(start),
                problem,
            });
            None
        };
        let mut head = [0u8; 5];
        match self.input.read_exact(&mut head[..4]) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => {
                if start == self.length {
                    self.tail = Some(Tail::Unended);
                    return None;
                }
                return truncated(self, "a partial record length".into());
            }
            Err(source) => {
                return Some(Err(TakeError::Io {
                    file: self.file.clone(),
                    source,
                }));
            }
        }
        let length = u32::from_le_bytes(head[..4].try_into().unwrap());
        let remaining = self.length - start - 4;
        if length == 0 || length > MAX_RECORD {
            // The writer never frames an empty record or one this long, and
            // a cut leaves a whole length field or none: damage, after which
            // the records cannot be found again.
            self.tail = Some(Tail::Truncated {
                offset: start,
                bytes: self.length - start,
                problem: format!("a record length of {length} bytes"),
            });
            // Counted, so the error names this record (see `corrupt`).
            self.index += 1;
            return Some(Err(self.corrupt(
                start,
                format!(
                    "a record length of {length} bytes (1 to {MAX_RECORD}): the take is \
                     damaged here; the {} bytes after it were not read",
                    self.length - start
                ),
            )));
        }
        if u64::from(length) + 4 > remaining {
            return truncated(
                self,
                format!("a record of {length} bytes, but {remaining} remain"),
            );
        }
        let mut body = vec![0u8; length as usize + 4];
        if let Err(e) = self.input.read_exact(&mut body) {
            return truncated(self, format!("cannot read the record: {e}"));
        }
        let (data, crc) = body.split_at(length as usize);
        let end = start + 4 + u64::from(length) + 4;
        if crc32fast::hash(data) != u32::from_le_bytes(crc.try_into().unwrap()) {
            if end == self.length {
                // The last record, torn as it was written: a cut tail.
                return truncated(self, "checksum mismatch".into());
            }
            // A whole record with more of the take after it was damaged
            // after it was written: an error, and the reader goes on past
            // it (its framing held) for whoever wants the rest.
            self.offset = end;
            self.index += 1;
            return Some(Err(self.corrupt(
                start,
                format!(
                    "checksum mismatch, with {} bytes of the take after it: the take is \
                     damaged here (a cut tail would be the last record)",
                    self.length - end
                ),
            )));
        }
        self.offset = end;
        let index = self.index;
        self.index += 1;
        let record = Record::decode(data[0], &data[1..]).and_then(|r| self.check(r));
        match record {
            Ok(Record::End(end)) => {
                self.tail = Some(Tail::Ended(end.clone()));
                Some(Ok(Record::End(end)))
            }
            Ok(record) => Some(Ok(record)),
            Err(problem) => Some(Err(TakeError::Corrupt {
                file: self.file.clone(),
                index,
                offset: start,
                problem,
            })),
        }
    }

    /// A damaged record starting at `offset` (the one just counted).
    fn corrupt(&self, offset: u64, problem: String) -> TakeError {
        TakeError::Corrupt {
            file: self.file.clone(),
            index: self.index.saturating_sub(1),
            offset,
            problem,
        }
    }

    /// Whether a decoded record is within the take budget: its time a
    /// number of seconds within `MAX_TAKE_SECONDS` (a player turns it into
    /// a `Duration`), a step's changes and contacts within theirs, and the
    /// contacts the take holds down at once too. A step refused here
    /// leaves the held count as it was.
    fn check(&mut self, record: Record) -> Result<Record, String> {
        let time = |what: &str, t: f64| {
            if t.is_finite() && (0.0..=MAX_TAKE_SECONDS).contains(&t) {
                Ok(())
            } else {
                Err(format!(
                    "{what}: t = {t} is not 0 to {MAX_TAKE_SECONDS} seconds (MAX_TAKE_SECONDS)"
                ))
            }
        };
        match &record {
            Record::Header(h) => {
                let size_ok = |v: f64| v.is_finite() && v > 0.0;
                if !(size_ok(h.stage_width) && size_ok(h.stage_height)) {
                    return Err("header: stage_width and stage_height must be positive".into());
                }
                if !h.started_unix.is_finite() {
                    return Err("header: started_unix must be a number of seconds".into());
                }
            }
            Record::Step(step) => {
                time("step", step.t)?;
                if step.changes.len() as u64 > MAX_TAKE_STEP_CHANGES {
                    return Err(format!(
                        "step: {} changes, more than {MAX_TAKE_STEP_CHANGES} \
                         (MAX_TAKE_STEP_CHANGES)",
                        step.changes.len()
                    ));
                }
                self.hold(step)?;
            }
            Record::Frame(f) => time("frame", f.t)?,
            Record::End(e) => time("end", e.t)?,
            Record::Clock(c) => {
                time("clock", c.t)?;
                if !c.show.is_finite() || c.show.abs() > MAX_TAKE_SECONDS {
                    return Err(format!(
                        "clock: show = {} is not within {MAX_TAKE_SECONDS} seconds \
                         (MAX_TAKE_SECONDS)",
                        c.show
                    ));
                }
            }
        }
        Ok(record)
    }

    /// Counts the contacts `step` lands, moves and lifts against
    /// `MAX_TAKE_CONTACTS`, and keeps the held ones if it is within it.
    fn hold(&mut self, step: &Step) -> Result<(), String> {
        let mut held = None::<HashMap<String, HashSet<u32>>>;
        let mut in_step = 0u64;
        for change in &step.changes {
            let held = held.get_or_insert_with(|| self.held.clone());
            match change {
                Change::Contacts { frame } => {
                    in_step += frame.contacts.len() as u64;
                    let ids = held.entry(frame.source.to_string()).or_default();
                    for c in &frame.contacts {
                        match c.phase {
                            Phase::Up => ids.remove(&c.id),
                            _ => ids.insert(c.id),
                        };
                    }
                }
                Change::Release { source } => {
                    held.remove(source);
                }
                _ => {}
            }
        }
        if in_step > MAX_TAKE_CONTACTS {
            return Err(format!(
                "step: {in_step} contacts, more than {MAX_TAKE_CONTACTS} (MAX_TAKE_CONTACTS)"
            ));
        }
        if let Some(held) = held {
            let total: usize = held.values().map(HashSet::len).sum();
            if total as u64 > MAX_TAKE_CONTACTS {
                return Err(format!(
                    "step: {total} contacts held down at once, more than {MAX_TAKE_CONTACTS} \
                     (MAX_TAKE_CONTACTS)"
                ));
            }
            self.held = held;
            self.held.retain(|_, ids| !ids.is_empty());
        }
        Ok(())
    }
}

impl Iterator for TakeReader {
    type Item = Result<Record, TakeError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_record()
    }
}

/// A take's summary, as `puppetry takes` and the `takes` message list it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeSummary {
    /// The take's name: its file name without `.take` (how takes are
    /// played and downloaded).
    pub name: String,
    /// The take's path.
    pub file: PathBuf,
    /// When recording began, in seconds since the Unix epoch.
    pub started_unix: f64,
    /// Seconds from the start to the last step or frame.
    pub duration: f64,
    /// How many steps the take holds.
    pub steps: usize,
    /// How many vertex frames the take holds.
    pub frames: usize,
    /// The names of the stage's puppets when it was recorded, in id order.
    pub puppets: Vec<String>,
    /// Whether it began on a stage fresh from its file, so it replays
    /// exactly (see [`Header::fresh`]).
    pub fresh: bool,
    /// "stopped"/"shutdown"/an error, "unended" (killed between records)
    /// or "truncated: …" (killed mid-record; the tail was skipped).
    pub ending: String,
    /// Takes played into this one while it was recorded (overdub), as
    /// [`Header::layers`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub layers: Vec<String>,
}

/// Reads a whole take for its summary.
pub fn summarize(path: &Path) -> Result<TakeSummary, TakeError> {
    let mut reader = TakeReader::open(path)?;
    let (mut steps, mut frames, mut duration) = (0, 0, 0.0f64);
    for record in reader.by_ref() {
        match record? {
            Record::Step(s) => {
                steps += 1;
                duration = duration.max(s.t);
            }
            Record::Frame(f) => {
                frames += 1;
                duration = duration.max(f.t);
            }
            Record::End(e) => duration = duration.max(e.t),
            Record::Header(_) | Record::Clock(_) => {}
        }
    }
    let ending = match reader.tail() {
        Some(Tail::Ended(end)) => end.reason.clone(),
        Some(Tail::Truncated { bytes, problem, .. }) => {
            format!("truncated: {bytes} bytes at the end skipped ({problem})")
        }
        _ => "unended".to_string(),
    };
    let h = &reader.header;
    // Takes are named by their file (that is how they are played and
    // downloaded); the header keeps the name they were recorded under.
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| h.name.clone());
    Ok(TakeSummary {
        name,
        file: path.to_path_buf(),
        started_unix: h.started_unix,
        duration,
        steps,
        frames,
        puppets: h.puppets.iter().map(|p| p.name.clone()).collect(),
        fresh: h.fresh,
        ending,
        layers: h.layers.clone(),
    })
}

/// Every take in a folder (`*.take`), oldest first (by when each began);
/// unreadable ones are listed as errors, after the others, not hidden.
pub fn list(dir: &Path) -> Result<Vec<Result<TakeSummary, TakeError>>, TakeError> {
    let entries = std::fs::read_dir(dir).map_err(|source| TakeError::Io {
        file: dir.display().to_string(),
        source,
    })?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == EXTENSION))
        .collect();
    paths.sort();
    let mut takes: Vec<_> = paths.iter().map(|p| summarize(p)).collect();
    takes.sort_by(|a, b| match (a, b) {
        (Ok(a), Ok(b)) => a.started_unix.total_cmp(&b.started_unix),
        (Ok(_), Err(_)) => std::cmp::Ordering::Less,
        (Err(_), Ok(_)) => std::cmp::Ordering::Greater,
        (Err(_), Err(_)) => std::cmp::Ordering::Equal,
    });
    Ok(takes)
}

/// A take name safe as a file name: letters, digits, `-`, `_` and `.`,
/// not starting with a dot, at most 100 characters.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 100
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}
