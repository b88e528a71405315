//! Exports of recorded takes: a take's vertex frames, resampled by sample
//! and hold to a frame rate (so each frame is exactly what a viewer saw at
//! that instant), with the puppets' meshes and pictures from the stage
//! file, handed to one of the exporters. Frames are read streaming: only
//! the sampled ones are kept. `puppetry export` and the daemon's download
//! of a take both run through [`export_take`].

use std::path::{Path, PathBuf};

use crate::drawing::Drawn;
use crate::format::Format;
use crate::{AnimatedPuppet, Animation, ExportError, Progress};
use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;
use puppetry_take::clock::ShowTrack;
use puppetry_take::{Record, Tail, TakeError, TakeReader};

/// Why a take could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum TakeExportError {
    /// The take cannot be opened or read.
    #[error(transparent)]
    Take(#[from] TakeError),
    /// The exporter refused the animation, a flag or the output.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// The stage file cannot be read.
    #[error(transparent)]
    Config(#[from] puppetry_stage::config::ConfigError),
    /// The stage file's puppets cannot be built.
    #[error(transparent)]
    Stage(#[from] puppetry_stage::StageError),
    /// The take was recorded on another stage than the one given.
    #[error("{file}: {problem}")]
    Mismatch {
        /// The take.
        file: String,
        /// How take and stage differ.
        problem: String,
    },
    /// The take is damaged (refused unless salvaged, saying what
    /// `--salvage` would keep) or holds no frame at all.
    #[error("{file}: {problem}")]
    Damaged {
        /// The take.
        file: String,
        /// What is damaged, and what `--salvage` would keep.
        problem: String,
    },
    /// `--format` names no format.
    #[error("--format: {0}")]
    Format(#[from] crate::format::UnknownFormat),
}

/// What to export.
#[derive(Debug, Clone)]
pub struct ExportRequest {
    /// The take file.
    pub take: PathBuf,
    /// The stage file the take was recorded on.
    pub config: PathBuf,
    /// What to write.
    pub format: Format,
    /// Frames per second of the export (the take is sampled at them).
    pub fps: f64,
    /// Seconds into the take (none: its start).
    pub from: Option<f64>,
    /// Seconds into the take (none: its end, included).
    pub to: Option<f64>,
    /// Pixels, for the formats drawn here (PNG frames and videos).
    pub size: (u32, u32),
    /// The file (or a PNG sequence's folder) to write.
    pub output: PathBuf,
    /// Whether files already at the output may be replaced (`--force`).
    pub overwrite: crate::output::Overwrite,
    /// Export what is intact of a damaged take (`--salvage`) instead of
    /// refusing it.
    pub salvage: bool,
    /// A soundtrack muxed into a video (`--audio FILE`), and how it lines
    /// up with the take.
    pub audio: Option<AudioRequest>,
}

/// A soundtrack to mux into a video export.
#[derive(Debug, Clone, PartialEq)]
pub struct AudioRequest {
    /// The sound file (anything ffmpeg reads).
    pub file: PathBuf,
    /// How the sound lines up with the take.
    pub align: AudioAlign,
}

/// How a soundtrack lines up with the take it is exported with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AudioAlign {
    /// The sound's second at the take's start (`--audio-offset S`;
    /// negative: the sound begins that long after it). The export's
    /// `--from` is added.
    Offset(f64),
    /// By the show's clock the take recorded (MIDI Time Code, MIDI clock,
    /// OSC time): the sound's first sample plays at show time `start`
    /// (`--audio-start`, default 0). A take that heard no running clock
    /// starts the sound with the take, and the export says so.
    ShowClock {
        /// The show's time, in seconds, of the sound's start.
        start: f64,
    },
}

impl AudioRequest {
    /// The sound's second at the export's first frame (the take's second
    /// `from`), and a line for the user saying how it was found.
    fn place(&self, show: &ShowTrack, from: f64) -> crate::video::Soundtrack {
        let at = match self.align {
            AudioAlign::Offset(offset) => offset + from,
            AudioAlign::ShowClock { start } => match show.show_at(from) {
                Some((time, _)) => time - start,
                None => from,
            },
        };
        crate::video::Soundtrack {
            file: self.file.clone(),
            at,
        }
    }

    /// What the user is told about the alignment.
    fn note(&self, show: &ShowTrack, from: f64, at: f64) -> String {
        let how = match self.align {
            AudioAlign::Offset(offset) => format!("--audio-offset {offset}"),
            AudioAlign::ShowClock { start } => match show.show_at(from) {
                Some((time, source)) => format!(
                    "the take's show clock ({}): its second {from:.3} is show time {} \
                     and the sound starts at show time {}",
                    match source {
                        puppetry_take::ClockSource::TimeCode => "MIDI Time Code",
                        puppetry_take::ClockSource::MidiClock => "MIDI clock",
                        puppetry_take::ClockSource::Osc => "OSC",
                    },
                    clock_text(time),
                    clock_text(start)
                ),
                None => "the take's start (it heard no show clock running; \
                         --audio-offset places the sound by hand)"
                    .to_string(),
            },
        };
        format!(
            "soundtrack {}: its second {at:.3} plays with the first frame, by {how}",
            self.file.display()
        )
    }
}

/// A show time as `h:mm:ss.mmm`.
fn clock_text(seconds: f64) -> String {
    let sign = if seconds < 0.0 { "-" } else { "" };
    let ms = (seconds.abs() * 1000.0).round() as u64;
    format!(
        "{sign}{}:{:02}:{:02}.{:03}",
        ms / 3_600_000,
        ms / 60_000 % 60,
        ms / 1000 % 60,
        ms % 1000
    )
}

/// A take read through once before it is exported: its length and
/// frames, and every damaged record or cut tail found on the way (the
/// reader goes on past a damaged record whose framing held).
#[derive(Debug, Clone, PartialEq)]
pub struct Survey {
    /// Seconds from the start to the last intact step, frame or end.
    pub duration: f64,
    /// Intact vertex frames (of any puppet).
    pub frames: usize,
    /// What is damaged, one line each; empty for a whole take.
    pub damage: Vec<String>,
    /// The show's clock readings the take heard, in order.
    pub clocks: Vec<puppetry_take::Clock>,
}

/// Reads `take` through for its [`Survey`]; only an unreadable file or
/// header is an error.
pub fn survey(take: &Path) -> Result<Survey, TakeError> {
    let mut reader = TakeReader::open(take)?;
    let mut survey = Survey {
        duration: 0.0,
        frames: 0,
        damage: Vec::new(),
        clocks: Vec::new(),
    };
    for record in reader.by_ref() {
        let t = match record {
            Ok(Record::Step(s)) => s.t,
            Ok(Record::Frame(f)) => {
                survey.frames += 1;
                f.t
            }
            Ok(Record::End(e)) => e.t,
            Ok(Record::Clock(c)) => {
                survey.clocks.push(c);
                continue;
            }
            Ok(Record::Header(_)) => continue,
            Err(e @ TakeError::Corrupt { .. }) => {
                survey.damage.push(e.to_string());
                continue;
            }
            Err(e) => return Err(e),
        };
        survey.duration = survey.duration.max(t);
    }
    if let Some(Tail::Truncated { bytes, problem, .. }) = reader.tail() {
        survey.damage.push(format!(
            "its last {bytes} bytes cannot be read ({problem}): the daemon stopped while \
             writing, or the file was damaged"
        ));
    }
    Ok(survey)
}

/// Refuses a take with no frame to show, and a damaged one unless
/// `salvage`; returns, for a salvaged one, what was kept.
fn judge(take: &Path, survey: &Survey, salvage: bool) -> Result<Option<String>, TakeExportError> {
    let damaged = |problem: String| TakeExportError::Damaged {
        file: take.display().to_string(),
        problem,
    };
    if survey.frames == 0 {
        return Err(damaged(if survey.damage.is_empty() {
            "the take has no frames (nothing moved while it recorded): nothing to export".into()
        } else {
            format!(
                "no frame of the take can be read: {}",
                survey.damage.join("; ")
            )
        }));
    }
    if survey.damage.is_empty() {
        return Ok(None);
    }
    let kept = format!(
        "{} intact frame(s) over {:.2} s",
        survey.frames, survey.duration
    );
    if !salvage {
        return Err(damaged(format!(
            "the take is damaged: {}; --salvage exports what is intact ({kept})",
            survey.damage.join("; ")
        )));
    }
    Ok(Some(format!(
        "salvaged {kept}; skipped: {}",
        survey.damage.join("; ")
    )))
}

/// A take read into an [`Animation`], and for a salvaged take what was
/// kept and skipped.
#[derive(Debug, Clone)]
pub struct TakeAnimation {
    /// The frames at the export's rate.
    pub animation: Animation,
    /// For a damaged take read with `salvage`: what was kept and skipped.
    pub salvaged: Option<String>,
    /// The show's time along the take, from the clock it heard.
    pub show: ShowTrack,
}

/// The take as an animation at `fps` over `from..to` (default: the whole
/// take, its last frame included); a damaged or empty take is refused.
pub fn animation_of_take(
    take: &Path,
    config: &StageConfig,
    fps: f64,
    from: Option<f64>,
    to: Option<f64>,
) -> Result<Animation, TakeExportError> {
    read_take(take, config, fps, from, to, false).map(|read| read.animation)
}

/// [`animation_of_take`], keeping what is intact of a damaged take when
/// `salvage` is set (its damaged records are skipped, a cut tail left
/// out).
pub fn read_take(
    take: &Path,
    config: &StageConfig,
    fps: f64,
    from: Option<f64>,
    to: Option<f64>,
    salvage: bool,
) -> Result<TakeAnimation, TakeExportError> {
    let survey = survey(take)?;
    let salvaged = judge(take, &survey, salvage)?;
    let mut reader = TakeReader::open(take)?;
    let stage = Stage::from_config(&puppetry_take::stage_config(config, &reader.header))?;
    reader
        .header
        .check_stage(&stage)
        .map_err(|problem| TakeExportError::Mismatch {
            file: take.display().to_string(),
            problem,
        })?;
    let (from, n) = range(survey.duration, fps, from, to)?;
    // Before the first recorded frame a puppet shows its pose at the start.
    let replayer = puppetry_take::replay::Replayer::new(stage);
    let stage = replayer.stage();
    let current: Vec<Vec<[f32; 2]>> = stage
        .puppets()
        .iter()
        .map(|p| p.pose().iter().map(|q| [q.x as f32, q.y as f32]).collect())
        .collect();
    // The drawing order as the live stage had it, where a puppet folds
    // over itself: from a replay of the steps while it holds.
    let depth = if stage.puppets().iter().any(|p| p.depth().is_some()) {
        let fresh = Stage::from_config(&puppetry_take::stage_config(config, &reader.header))?;
        Some(crate::drawing::DepthReplay::new(fresh))
    } else {
        None
    };
    let mut sampling = Sampling::new(current, depth, from, fps, n);
    for record in reader.by_ref() {
        let frame = match record {
            Ok(Record::Frame(frame)) => frame,
            Ok(Record::Step(step)) => {
                sampling.step(&step);
                continue;
            }
            Ok(_) => continue,
            // A damaged record: `judge` refused the take unless salvaging.
            Err(TakeError::Corrupt { .. }) if salvage => continue,
            Err(e) => return Err(e.into()),
        };
        let p = frame.puppet as usize;
        if p >= sampling.current.len() || frame.points.len() != sampling.current[p].len() {
            return Err(TakeExportError::Mismatch {
                file: take.display().to_string(),
                problem: format!(
                    "a frame of puppet {} with {} points does not fit the stage",
                    frame.puppet,
                    frame.points.len()
                ),
            });
        }
        sampling.frame(frame);
    }
    sampling.finish();
    let puppets = sampling.puppets(take, stage, &reader.header)?;
    Ok(TakeAnimation {
        animation: Animation {
            stage_width: stage.width,
            stage_height: stage.height,
            fps,
            puppets,
            frame_count: n,
        },
        salvaged,
        show: ShowTrack::new(&survey.clocks),
    })
}

/// A take's frames sampled at the export's instants `from + k / fps`,
/// per puppet: the pose each instant showed (the last recorded before it),
/// its drawing order, and where the take stepped (a let-go).
struct Sampling {
    from: f64,
    fps: f64,
    n: usize,
    /// Per puppet, its latest recorded pose.
    current: Vec<Vec<[f32; 2]>>,
    frames: Vec<Vec<Vec<[f32; 2]>>>,
    depth: Option<crate::drawing::DepthReplay>,
    order_now: Vec<Option<Drawn>>,
    orders: Vec<Vec<Option<Drawn>>>,
    /// Per puppet: a handle was let go since its last frame.
    let_go: Vec<bool>,
    snaps: Vec<Vec<usize>>,
}

impl Sampling {
    fn new(
        current: Vec<Vec<[f32; 2]>>,
        depth: Option<crate::drawing::DepthReplay>,
        from: f64,
        fps: f64,
        n: usize,
    ) -> Sampling {
        let puppets = current.len();
        Sampling {
            from,
            fps,
            n,
            order_now: (0..puppets as u32)
                .map(|q| depth.as_ref().and_then(|d| d.order(q)))
                .collect(),
            depth,
            current,
            frames: vec![Vec::with_capacity(n); puppets],
            orders: vec![Vec::with_capacity(n); puppets],
            let_go: vec![false; puppets],
            snaps: vec![Vec::new(); puppets],
        }
    }

    fn step(&mut self, step: &puppetry_take::Step) {
        for event in &step.events {
            if let puppetry_stage::StageEvent::Removed { puppet, .. } = event
                && let Some(let_go) = self.let_go.get_mut(*puppet as usize)
            {
                *let_go = true;
            }
        }
        if let Some(d) = &mut self.depth {
            d.step(step);
        }
    }

    /// Takes a recorded frame (of a puppet on the stage, of its size).
    fn frame(&mut self, frame: puppetry_take::Frame) {
        let p = frame.puppet as usize;
        // Every instant before this frame shows what was current then.
        self.fill(|instant| instant < frame.t);
        if let Some(d) = &mut self.depth {
            self.order_now[p] = d.frame(&frame);
        }
        // The next exported frame shows this pose: the take stepped into
        // it where a handle was let go since the last one.
        let next = self.frames[p].len();
        if std::mem::take(&mut self.let_go[p])
            && next < self.n
            && self.snaps[p].last() != Some(&next)
        {
            self.snaps[p].push(next);
        }
        self.current[p] = frame.points;
    }

    /// Samples every puppet's current pose at the instants `before` holds.
    fn fill(&mut self, before: impl Fn(f64) -> bool) {
        let (from, fps, n) = (self.from, self.fps, self.n);
        for (q, out) in self.frames.iter_mut().enumerate() {
            while out.len() < n && before(from + out.len() as f64 / fps) {
                out.push(self.current[q].clone());
                self.orders[q].push(self.order_now[q].clone());
            }
        }
    }

    /// The instants after the last frame show it.
    fn finish(&mut self) {
        self.fill(|_| true);
    }

    /// The puppets drawn, bottom to top as the stage drew them (a puppet a
    /// director had removed before the take is not drawn).
    fn puppets(
        mut self,
        take: &Path,
        stage: &Stage,
        header: &puppetry_take::Header,
    ) -> Result<Vec<AnimatedPuppet>, TakeExportError> {
        let replayed = self.depth.as_ref().is_some_and(|d| d.holds());
        let mut motions: Vec<Option<_>> = std::mem::take(&mut self.frames)
            .into_iter()
            .map(Some)
            .collect();
        let mut puppets = Vec::new();
        for id in header.drawn() {
            let (Some(p), Some(motion)) = (
                stage.puppets().get(id as usize),
                motions.get_mut(id as usize).and_then(Option::take),
            ) else {
                return Err(TakeExportError::Mismatch {
                    file: take.display().to_string(),
                    problem: format!(
                        "the header's lineup names puppet {id} twice or one not on the stage"
                    ),
                });
            };
            let (depths, draw_orders) = match p.depth() {
                None => (Vec::new(), Vec::new()),
                Some(_) if replayed => {
                    let plain = Drawn::plain(p.mesh.triangles().len());
                    crate::drawing::unless_plain(
                        std::mem::take(&mut self.orders[id as usize])
                            .into_iter()
                            .map(|o| o.unwrap_or_else(|| plain.clone()))
                            .collect(),
                    )
                }
                Some(_) => crate::drawing::orders_of_frames(&p.mesh, &motion),
            };
            let mut puppet = AnimatedPuppet::of_puppet(p, motion)?;
            puppet.draw_orders = draw_orders;
            puppet.depths = depths;
            // The first frame has nothing before it to hold.
            puppet.snaps = std::mem::take(&mut self.snaps[id as usize]);
            puppet.snaps.retain(|&k| k > 0);
            puppets.push(puppet);
        }
        Ok(puppets)
    }
}

/// The export's start and frame count over `from..to` of a take `end`
/// seconds long (default: all of it, its last instant included); a range
/// outside the take is refused, naming its flag.
fn range(
    end: f64,
    fps: f64,
    from: Option<f64>,
    to: Option<f64>,
) -> Result<(f64, usize), TakeExportError> {
    let from = from.unwrap_or(0.0);
    if from < 0.0 {
        return Err(ExportError::Flag {
            flag: "--from".into(),
            problem: format!("{from} s is before the take's start (0 s)"),
        }
        .into());
    }
    if from >= end && end > 0.0 {
        return Err(ExportError::Flag {
            flag: "--from".into(),
            problem: format!("{from} s is past the take's end ({end:.3} s)"),
        }
        .into());
    }
    // Past the end, every frame would hold the last pose: refuse rather
    // than pad silently (one frame's slack for rounding).
    if let Some(to) = to
        && to > end + 1.0 / fps
    {
        return Err(ExportError::Flag {
            flag: "--to".into(),
            problem: format!("{to} s is past the take's end ({end:.3} s)"),
        }
        .into());
    }
    // Up to and including the take's end (a frame recorded at its very
    // last instant is shown).
    let to = to.unwrap_or(if end > from {
        end + 1e-6
    } else {
        from + 1.0 / fps
    });
    Ok((from, crate::resample::frame_count(fps, from, to)?))
}

/// Runs an export; returns what was written, for the user.
pub fn export_take(
    request: &ExportRequest,
    progress: &mut dyn Progress,
) -> Result<String, TakeExportError> {
    let config = StageConfig::load(&request.config)?;
    export_take_with(request, &config, progress)
}

/// [`export_take`] with the stage file already read.
pub fn export_take_with(
    request: &ExportRequest,
    config: &StageConfig,
    progress: &mut dyn Progress,
) -> Result<String, TakeExportError> {
    preflight(request)?;
    let read = read_take(
        &request.take,
        config,
        request.fps,
        request.from,
        request.to,
        request.salvage,
    )?;
    let animation = &read.animation;
    let out = &request.output;
    let files = match request.format {
        Format::Png => (0..animation.frame_count)
            .map(|k| out.join(crate::frames::frame_name(k)))
            .collect(),
        Format::Spine => crate::spine::files(animation, out),
        Format::Glb | Format::Mp4 | Format::Mov | Format::Webm => vec![out.clone()],
    };
    crate::output::check_new(out, &files, request.overwrite)?;
    let (width, height) = request.size;
    let mut notes = Vec::new();
    match request.format {
        Format::Glb => {
            let options = crate::gltf::GltfOptions {
                chunk: 32,
                animation_name: "take".into(),
            };
            crate::gltf::export_glb(animation, &options, progress, out)?;
        }
        Format::Png => {
            let options = crate::frames::PngOptions { width, height };
            crate::frames::export_png_sequence(animation, &options, progress, out)?;
        }
        Format::Spine => {
            let export = if crate::spine::is_bundle(out) {
                crate::spine::export_spine_zip
            } else {
                crate::spine::export_spine
            };
            let layout = export(
                animation,
                &crate::spine::SpineOptions::default(),
                progress,
                out,
            )?;
            for p in &layout.puppets {
                if p.unkept_folds {
                    notes.push(format!(
                        "{}: its folds change sides more than {} times: Spine draws it in its \
                         mesh's order, so where it overlaps itself it may show otherwise than \
                         the page did",
                        p.slot,
                        crate::folds::MAX_RUNS
                    ));
                } else if p.attachments.len() > 1 {
                    notes.push(format!(
                        "{}: {} attachments, one per drawing order its folds take, switched \
                         by attachment keys",
                        p.slot,
                        p.attachments.len()
                    ));
                }
                if let Some((bones, max, mean)) = p.bones {
                    notes.push(format!(
                        "{}: {bones} bones; the skinned mesh is within {max:.2} stage units \
                         of the take (mean {mean:.2})",
                        p.slot
                    ));
                }
            }
        }
        Format::Mp4 | Format::Mov | Format::Webm => {
            let mut options = crate::video::VideoOptions::new(width, height);
            if let Some(audio) = &request.audio {
                let from = request.from.unwrap_or(0.0);
                let soundtrack = audio.place(&read.show, from);
                notes.push(audio.note(&read.show, from, soundtrack.at));
                options.audio = Some(soundtrack);
            }
            crate::video::export_video(animation, &options, progress, out)?;
        }
    }
    let mut written = format!(
        "{}: {} frames at {} fps ({:.2} s) of {} puppet(s)",
        out.display(),
        animation.frame_count,
        animation.fps,
        animation.duration(),
        animation.puppets.len()
    );
    for note in notes {
        written.push('\n');
        written.push_str(&note);
    }
    if let Some(salvaged) = &read.salvaged {
        written.push('\n');
        written.push_str(salvaged);
    }
    Ok(written)
}

/// What can be refused before the take is read or a frame drawn: an
/// output that is the take, a missing folder, a video whose extension is
/// not its format's, a picture size past the format's limits.
pub fn preflight(request: &ExportRequest) -> Result<(), TakeExportError> {
    let out = &request.output;
    crate::output::refuse_the_take_itself(&request.take, out)?;
    let (width, height) = request.size;
    if let Some(audio) = &request.audio {
        let flag = |problem: String| ExportError::Flag {
            flag: "--audio".into(),
            problem,
        };
        if !request.format.is_video() {
            return Err(flag(format!(
                "--format {} carries no sound; use mp4, mov or webm",
                request.format
            ))
            .into());
        }
        let (name, seconds) = match audio.align {
            AudioAlign::Offset(s) => ("--audio-offset", s),
            AudioAlign::ShowClock { start } => ("--audio-start", start),
        };
        if !seconds.is_finite() || seconds.abs() > puppetry_limits::files::MAX_TAKE_SECONDS {
            return Err(flag(format!("{name} {seconds} is not a number of seconds")).into());
        }
        if !std::fs::metadata(&audio.file).is_ok_and(|m| m.is_file()) {
            return Err(flag(format!("{} is not a sound file here", audio.file.display())).into());
        }
    }
    match request.format {
        Format::Glb | Format::Spine => crate::output::check_folder(out)?,
        Format::Png => crate::raster::check_size(width, height)?,
        video @ (Format::Mp4 | Format::Mov | Format::Webm) => {
            crate::output::check_folder(out)?;
            let kind = crate::video::VideoFormat::of(out)?;
            if crate::video::VideoFormat::of_format(video) != Some(kind) {
                return Err(ExportError::Output {
                    path: out.display().to_string(),
                    problem: format!("--format {video} writes a .{video} file"),
                }
                .into());
            }
            kind.check_size(width, height)?;
        }
    }
    Ok(())
}
