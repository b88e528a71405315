//! `puppetry export TAKE --format F -o OUT`: a take's recorded vertex
//! frames, resampled by sample and hold to a frame rate (so each frame is
//! exactly what a viewer saw at that instant), handed to an exporter of
//! `puppetry-export` with the puppets' meshes and pictures from the stage
//! file. Frames are read streaming: only the sampled ones are kept.

use std::io::Write;
use std::path::{Path, PathBuf};

use puppetry_export::{AnimatedPuppet, Animation, ExportError, Progress};
use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;
use puppetry_take::{Record, TakeError, TakeReader};

#[derive(Debug, thiserror::Error)]
pub enum ExportCliError {
    #[error(transparent)]
    Take(#[from] TakeError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[error(transparent)]
    Config(#[from] puppetry_stage::config::ConfigError),
    #[error(transparent)]
    Stage(#[from] puppetry_stage::StageError),
    #[error("{file}: {problem}")]
    Mismatch { file: String, problem: String },
    #[error("--format: {0:?} is not one of glb, png, mp4, mov, webm, spine")]
    Format(String),
    #[error("-o {path}: {problem}")]
    Output { path: String, problem: String },
}

/// What to export.
#[derive(Debug, Clone)]
pub struct ExportRequest {
    pub take: PathBuf,
    pub config: PathBuf,
    pub format: String,
    pub fps: f64,
    pub from: Option<f64>,
    pub to: Option<f64>,
    pub size: (u32, u32),
    pub output: PathBuf,
}

/// The take as an animation at `fps` over `from..to` (default: the whole
/// take, its last frame included).
pub fn animation_of_take(
    take: &Path,
    config: &StageConfig,
    fps: f64,
    from: Option<f64>,
    to: Option<f64>,
) -> Result<Animation, ExportCliError> {
    let stage = Stage::from_config(config)?;
    let summary = puppetry_take::summarize(take)?;
    let mut reader = TakeReader::open(take)?;
    reader
        .header
        .check_stage(&stage)
        .map_err(|problem| ExportCliError::Mismatch {
            file: take.display().to_string(),
            problem,
        })?;
    let from = from.unwrap_or(0.0);
    let to = to.unwrap_or(summary.duration + 1.0 / fps);
    let n = puppetry_export::resample::frame_count(fps, from, to)?;
    // Before the first recorded frame a puppet shows its pose at the start.
    let mut replayer = puppetry_take::replay::Replayer::new(stage);
    let _ = &mut replayer;
    let stage = replayer.stage();
    let mut current: Vec<Vec<[f32; 2]>> = stage
        .puppets()
        .iter()
        .map(|p| p.pose().iter().map(|q| [q.x as f32, q.y as f32]).collect())
        .collect();
    let mut frames: Vec<Vec<Vec<[f32; 2]>>> = vec![Vec::with_capacity(n); current.len()];
    let instant = |k: usize| from + k as f64 / fps;
    for record in reader.by_ref() {
        let Record::Frame(frame) = record? else {
            continue;
        };
        let p = frame.puppet as usize;
        if p >= current.len() || frame.points.len() != current[p].len() {
            return Err(ExportCliError::Mismatch {
                file: take.display().to_string(),
                problem: format!(
                    "a frame of puppet {} with {} points does not fit the stage",
                    frame.puppet,
                    frame.points.len()
                ),
            });
        }
        // Every instant before this frame shows what was current then.
        for (q, out) in frames.iter_mut().enumerate() {
            while out.len() < n && instant(out.len()) < frame.t {
                out.push(current[q].clone());
            }
        }
        current[p] = frame.points;
    }
    for (q, out) in frames.iter_mut().enumerate() {
        while out.len() < n {
            out.push(current[q].clone());
        }
    }
    let mut puppets = Vec::new();
    for (p, motion) in stage.puppets().iter().zip(frames) {
        let image = puppetry_export::load_png(&p.image)?;
        puppets.push(AnimatedPuppet {
            name: p.name.clone(),
            triangles: p.mesh.triangles().to_vec(),
            uv: p
                .mesh
                .uv()
                .map(|uv| uv.iter().map(|t| [t.x as f32, t.y as f32]).collect())
                .unwrap_or_else(|| vec![[0.0, 0.0]; p.mesh.vertices().len()]),
            image,
            frames: motion,
        });
    }
    Ok(Animation {
        stage_width: stage.width,
        stage_height: stage.height,
        fps,
        puppets,
        frame_count: n,
    })
}

/// A progress bar on standard error.
pub struct Bar {
    what: String,
    shown: usize,
}

impl Bar {
    pub fn new(what: &str) -> Bar {
        Bar {
            what: what.to_string(),
            shown: usize::MAX,
        }
    }
}

impl Progress for Bar {
    fn step(&mut self, done: usize, total: usize) {
        let percent = (done * 100).checked_div(total).unwrap_or(100);
        if percent == self.shown {
            return;
        }
        self.shown = percent;
        let filled = percent / 4;
        eprint!(
            "\r{} [{}{}] {percent:3}% ({done}/{total})",
            self.what,
            "#".repeat(filled),
            " ".repeat(25 - filled)
        );
        if done >= total {
            eprintln!();
        }
        let _ = std::io::stderr().flush();
    }
}

/// Runs an export; returns what was written, for the user.
pub fn export_command(
    request: &ExportRequest,
    progress: &mut dyn Progress,
) -> Result<String, ExportCliError> {
    let format = request.format.to_ascii_lowercase();
    if !matches!(
        format.as_str(),
        "glb" | "png" | "mp4" | "mov" | "webm" | "spine"
    ) {
        return Err(ExportCliError::Format(request.format.clone()));
    }
    let config = StageConfig::load(&request.config)?;
    let animation = animation_of_take(
        &request.take,
        &config,
        request.fps,
        request.from,
        request.to,
    )?;
    let out = &request.output;
    let (width, height) = request.size;
    match format.as_str() {
        "glb" => {
            let options = puppetry_export::gltf::GltfOptions {
                chunk: 32,
                animation_name: "take".into(),
            };
            puppetry_export::gltf::export_glb(&animation, &options, progress, out)?;
        }
        "png" => {
            let options = puppetry_export::frames::PngOptions { width, height };
            puppetry_export::frames::export_png_sequence(&animation, &options, progress, out)?;
        }
        "spine" => {
            puppetry_export::spine::export_spine(
                &animation,
                &puppetry_export::spine::SpineOptions::default(),
                progress,
                out,
            )?;
        }
        video => {
            let wanted = out.extension().and_then(|e| e.to_str()).unwrap_or("");
            if !wanted.eq_ignore_ascii_case(video) {
                return Err(ExportCliError::Output {
                    path: out.display().to_string(),
                    problem: format!("--format {video} writes a .{video} file"),
                });
            }
            let options = puppetry_export::video::VideoOptions::new(width, height);
            puppetry_export::video::export_video(&animation, &options, progress, out)?;
        }
    }
    Ok(format!(
        "{}: {} frames at {} fps ({:.2} s) of {} puppet(s)",
        out.display(),
        animation.frame_count,
        animation.fps,
        animation.duration(),
        animation.puppets.len()
    ))
}
