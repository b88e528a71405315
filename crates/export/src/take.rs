//! Exports of recorded takes: a take's vertex frames, resampled by sample
//! and hold to a frame rate (so each frame is exactly what a viewer saw at
//! that instant), with the puppets' meshes and pictures from the stage
//! file, handed to one of the exporters. Frames are read streaming: only
//! the sampled ones are kept. `puppetry export` and the daemon's download
//! of a take both run through [`export_take`].

use std::path::{Path, PathBuf};

use crate::format::Format;
use crate::{AnimatedPuppet, Animation, ExportError, Progress};
use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;
use puppetry_take::{Record, TakeError, TakeReader};

#[derive(Debug, thiserror::Error)]
pub enum TakeExportError {
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
    #[error("--format: {0}")]
    Format(#[from] crate::format::UnknownFormat),
    #[error("-o {path}: {problem}")]
    Output { path: String, problem: String },
}

/// What to export.
#[derive(Debug, Clone)]
pub struct ExportRequest {
    pub take: PathBuf,
    pub config: PathBuf,
    pub format: Format,
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
) -> Result<Animation, TakeExportError> {
    let summary = puppetry_take::summarize(take)?;
    let mut reader = TakeReader::open(take)?;
    let stage = Stage::from_config(&as_recorded(config, &reader.header))?;
    reader
        .header
        .check_stage(&stage)
        .map_err(|problem| TakeExportError::Mismatch {
            file: take.display().to_string(),
            problem,
        })?;
    let end = summary.duration;
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
    let n = crate::resample::frame_count(fps, from, to)?;
    // Before the first recorded frame a puppet shows its pose at the start.
    let replayer = puppetry_take::replay::Replayer::new(stage);
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
            return Err(TakeExportError::Mismatch {
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
    // Bottom to top as the stage drew them; a puppet a director had
    // removed before the take is not drawn.
    let mut motions: Vec<Option<_>> = frames.into_iter().map(Some).collect();
    let mut puppets = Vec::new();
    for id in reader.header.drawn() {
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
        let image = crate::load_picture(&p.picture)?;
        let draw_orders = if p.depth().is_some() {
            draw_orders(&p.mesh, &motion)
        } else {
            Vec::new()
        };
        puppets.push(AnimatedPuppet {
            draw_orders,
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

/// The stage file as the take knew it: puppets added to the stage after
/// the take was recorded are left out (with their pads). Puppet ids are
/// never reused and new puppets are appended, so the take's puppets are
/// the first ones, names and all; anything else is left for
/// `Header::check_stage` to refuse.
fn as_recorded<'a>(
    config: &'a StageConfig,
    header: &puppetry_take::Header,
) -> std::borrow::Cow<'a, StageConfig> {
    let n = header.puppets.len();
    let prefix = config.puppets.len() > n
        && header
            .puppets
            .iter()
            .zip(&config.puppets)
            .all(|(recorded, p)| recorded.name == p.name);
    if !prefix {
        return std::borrow::Cow::Borrowed(config);
    }
    let mut cut = config.clone();
    cut.puppets.truncate(n);
    let kept: Vec<String> = cut.puppets.iter().map(|p| p.name.clone()).collect();
    cut.pads.retain(|pad| kept.contains(&pad.puppet));
    std::borrow::Cow::Owned(cut)
}

/// A take is a performance that cannot be repeated: an output that is
/// the take itself (the same file, by any path or link) is refused before
/// anything is read or written. `export T.take -o T.take` used to replace
/// the take with the export, exit 0.
fn refuse_the_take_itself(take: &Path, output: &Path) -> Result<(), TakeExportError> {
    use std::os::unix::fs::MetadataExt;
    let same = match (std::fs::metadata(take), std::fs::metadata(output)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    };
    if same {
        return Err(TakeExportError::Output {
            path: output.display().to_string(),
            problem: format!(
                "is the take being exported ({}); give the export another name",
                take.display()
            ),
        });
    }
    Ok(())
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
    refuse_the_take_itself(&request.take, &request.output)?;
    let animation =
        animation_of_take(&request.take, config, request.fps, request.from, request.to)?;
    let out = &request.output;
    let (width, height) = request.size;
    match request.format {
        Format::Glb => {
            let options = crate::gltf::GltfOptions {
                chunk: 32,
                animation_name: "take".into(),
            };
            crate::gltf::export_glb(&animation, &options, progress, out)?;
        }
        Format::Png => {
            let options = crate::frames::PngOptions { width, height };
            crate::frames::export_png_sequence(&animation, &options, progress, out)?;
        }
        Format::Spine => {
            crate::spine::export_spine(
                &animation,
                &crate::spine::SpineOptions::default(),
                progress,
                out,
            )?;
        }
        video @ (Format::Mp4 | Format::Mov | Format::Webm) => {
            let wanted = out.extension().and_then(|e| e.to_str()).unwrap_or("");
            if !wanted.eq_ignore_ascii_case(video.name()) {
                return Err(TakeExportError::Output {
                    path: out.display().to_string(),
                    problem: format!("--format {video} writes a .{video} file"),
                });
            }
            let options = crate::video::VideoOptions::new(width, height);
            crate::video::export_video(&animation, &options, progress, out)?;
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

/// Each frame's triangle order, back to front, as the live stage draws it
/// (`docs/depth.md`): the depth order run over the frames in turn, so its
/// frame-to-frame coherence holds. It runs at the export's frame rate, not
/// the live solve rate, so where the live decision depended on the path
/// between two exported frames the export may decide otherwise.
fn draw_orders(mesh: &puppetry_mesh::Mesh, frames: &[Vec<[f32; 2]>]) -> Vec<std::sync::Arc<[u32]>> {
    let Ok(mut depth) = puppetry_deform::depth::DepthOrder::register(mesh, None) else {
        return Vec::new();
    };
    let mesh_order: std::sync::Arc<[u32]> = (0..mesh.triangles().len() as u32).collect();
    let mut last = mesh_order.clone();
    let mut positions = Vec::new();
    let orders: Vec<std::sync::Arc<[u32]>> = frames
        .iter()
        .map(|frame| {
            positions.clear();
            positions.extend(
                frame
                    .iter()
                    .map(|q| glam::DVec2::new(f64::from(q[0]), f64::from(q[1]))),
            );
            // A pose that cannot be ordered keeps the last order.
            if depth.update(&positions).is_ok() && depth.changed() {
                let d = depth.depth();
                let mut order: Vec<u32> = (0..d.len() as u32).collect();
                // Stable: ties keep the mesh's order, as the page does.
                order.sort_by_key(|&t| d[t as usize]);
                last = order.into();
            }
            last.clone()
        })
        .collect();
    // Never folded: mesh order throughout, drawn the plain way.
    if orders
        .iter()
        .all(|o| std::sync::Arc::ptr_eq(o, &mesh_order))
    {
        Vec::new()
    } else {
        orders
    }
}
