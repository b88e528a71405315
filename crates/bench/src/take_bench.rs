//! `puppetry bench --takes`: what recording a take costs the live path
//! (the stage thread's CPU time per step with and without handing the step
//! and its frame to the recorder, whose writer runs on a thread of its own), and how long exports of a 60 s, 60 fps take of the
//! demo puppet take (glTF and a 1280×720 PNG sequence). Rounds alternate
//! with and without recording so load on the machine hits both alike;
//! medians are printed.

use std::time::Instant;

use glam::DVec2;
use puppetry_export::{AnimatedPuppet, Animation};
use puppetry_input::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, Stage};
use puppetry_take::recorder::Recorder;
use puppetry_take::{Frame, Header, Record, Step};

fn contacts(id: u32, phase: Phase, at: DVec2) -> Change {
    Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new("bench"),
            time: 0.0,
            contacts: vec![Contact::new(id, phase, at)],
        },
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// CPU time of the calling thread, seconds: the stage thread's own cost,
/// whatever the recorder's writer thread (or anything else) takes.
fn thread_cpu() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid timespec to write into.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// One round of `steps` drag steps; the stage thread's CPU µs per step.
fn round(stage: &mut Stage, at: DVec2, steps: usize, recorder: Option<&Recorder>) -> f64 {
    let mut events = Vec::new();
    let _ = stage.apply_change(&contacts(1, Phase::Down, at));
    stage.solve();
    stage.take_events(&mut events);
    let began = thread_cpu();
    for i in 0..steps {
        let phase = i as f64 / steps as f64 * std::f64::consts::TAU;
        let change = contacts(
            1,
            Phase::Move,
            at + DVec2::new(phase.sin(), phase.cos()) * 40.0,
        );
        let _ = stage.apply_change(&change);
        let solved = stage.solve();
        if let Some(r) = recorder {
            stage.take_events(&mut events);
            let t = r.elapsed();
            let _ = r.record(Record::Step(Step {
                t,
                changes: vec![change],
                events: std::mem::take(&mut events),
            }));
            for &(p, _) in &solved {
                let pose = stage.puppets()[p as usize].pose();
                let _ = r.record(Record::Frame(Frame::of_pose(p, t, pose)));
            }
        }
    }
    let per_step = (thread_cpu() - began) * 1e6 / steps as f64;
    let _ = stage.apply_change(&contacts(1, Phase::Up, at));
    stage.solve();
    per_step
}

/// Prints the recording overhead and the export times.
pub fn take_bench(config: &StageConfig, print: &dyn Fn(&str)) -> Result<(), String> {
    let mut stage = Stage::from_config(config).map_err(|e| e.to_string())?;
    let at = DVec2::from(config.puppets[0].at);
    let vertices = stage.puppets()[0].mesh.vertices().len();
    let dir = std::env::temp_dir().join(format!("puppetry-take-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let (mut without, mut with) = (Vec::new(), Vec::new());
    for r in 0..7 {
        without.push(round(&mut stage, at, 1000, None));
        let header = Header::of_stage("bench", "bench", &stage, false);
        stage.keep_events(true);
        let recorder =
            Recorder::start(&dir.join(format!("r{r}.take")), &header).map_err(|e| e.to_string())?;
        with.push(round(&mut stage, at, 1000, Some(&recorder)));
        recorder.finish("stopped").map_err(|e| e.to_string())?;
        stage.keep_events(false);
    }
    let (a, b) = (median(without), median(with));
    print(&format!(
        "take recording, {vertices} vertices, drag steps: stage thread {a:.1} µs CPU per step without, {b:.1} µs with \
         (+{:.1} µs = {:.1}% of the step, {:.2}% of a 1 ms frame at 1 kHz); medians of 7 alternating rounds of 1000 steps",
        b - a,
        (b - a) / a * 100.0,
        (b - a) / 1000.0 * 100.0
    ));

    // A 60 s take at 60 fps of the puppet, each frame a solve of a drag.
    let animation = drag_animation(&mut stage, at, 60.0, 3600)?;
    let began = Instant::now();
    puppetry_export::gltf::export_glb(
        &animation,
        &puppetry_export::gltf::GltfOptions {
            chunk: 32,
            animation_name: "take".into(),
        },
        &mut (),
        &dir.join("bench.glb"),
    )
    .map_err(|e| e.to_string())?;
    print(&format!(
        "export glb, 60 s at 60 fps, {vertices} vertices: {:.2} s",
        began.elapsed().as_secs_f64()
    ));
    let began = Instant::now();
    puppetry_export::frames::export_png_sequence(
        &animation,
        &puppetry_export::frames::PngOptions {
            width: 1280,
            height: 720,
        },
        &mut (),
        &dir.join("png"),
    )
    .map_err(|e| e.to_string())?;
    print(&format!(
        "export png 1280x720, 60 s at 60 fps, {vertices} vertices: {:.2} s",
        began.elapsed().as_secs_f64()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// `frame_count` frames at `fps` of the stage's first puppet dragged in a
/// circle about `at`, each frame a solve, as an export's input.
fn drag_animation(
    stage: &mut Stage,
    at: DVec2,
    fps: f64,
    frame_count: usize,
) -> Result<Animation, String> {
    let mut frames = Vec::with_capacity(frame_count);
    let _ = stage.apply_change(&contacts(2, Phase::Down, at));
    for k in 0..frame_count {
        let phase = k as f64 / 120.0 * std::f64::consts::TAU;
        let _ = stage.apply_change(&contacts(
            2,
            Phase::Move,
            at + DVec2::new(phase.sin(), phase.cos()) * 60.0,
        ));
        stage.solve();
        frames.push(
            stage.puppets()[0]
                .pose()
                .iter()
                .map(|p| [p.x as f32, p.y as f32])
                .collect(),
        );
    }
    let _ = stage.apply_change(&contacts(2, Phase::Up, at));
    let p = &stage.puppets()[0];
    Ok(Animation {
        stage_width: stage.width,
        stage_height: stage.height,
        fps,
        // Mesh order: the bench's drag does not fold the puppet.
        puppets: vec![AnimatedPuppet::of_puppet(p, frames).map_err(|e| e.to_string())?],
        frame_count,
    })
}

/// Prints how long every export format takes for a 60 s take at 30 fps
/// of the stage's first puppet, drawn formats at 1280×720, and how many
/// times real time that is (issue 34's goal: every video format at least
/// twice real time for a 1k-vertex puppet on a 2-core machine). Videos
/// need `ffmpeg` on `PATH`; without it they are skipped, saying so.
pub fn export_bench(config: &StageConfig, print: &dyn Fn(&str)) -> Result<(), String> {
    use puppetry_export::format::Format;
    let mut stage = Stage::from_config(config).map_err(|e| e.to_string())?;
    let at = DVec2::from(config.puppets[0].at);
    let vertices = stage.puppets()[0].mesh.vertices().len();
    let (fps, seconds) = (30.0, 60.0);
    let animation = drag_animation(&mut stage, at, fps, (fps * seconds) as usize)?;
    let dir = std::env::temp_dir().join(format!("puppetry-export-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let (width, height) = (1280, 720);
    let ffmpeg = puppetry_export::video::find_ffmpeg().is_ok();
    for format in Format::ALL {
        if format.is_video() && !ffmpeg {
            print(&format!(
                "export {format}: skipped, ffmpeg not found on PATH"
            ));
            continue;
        }
        let out = dir.join(format!("bench.{}", format.download().map_or("d", |d| d.0)));
        let began = Instant::now();
        let written = match format {
            Format::Glb => puppetry_export::gltf::export_glb(
                &animation,
                &puppetry_export::gltf::GltfOptions::default(),
                &mut (),
                &out,
            ),
            Format::Spine => puppetry_export::spine::export_spine(
                &animation,
                &puppetry_export::spine::SpineOptions::default(),
                &mut (),
                &out,
            )
            .map(|_| ()),
            Format::Png => puppetry_export::frames::export_png_sequence(
                &animation,
                &puppetry_export::frames::PngOptions { width, height },
                &mut (),
                &out,
            ),
            Format::Mp4 | Format::Mov | Format::Webm => puppetry_export::video::export_video(
                &animation,
                &puppetry_export::video::VideoOptions::new(width, height),
                &mut (),
                &out,
            ),
        };
        written.map_err(|e| format!("export {format}: {e}"))?;
        let took = began.elapsed().as_secs_f64();
        print(&format!(
            "export {:<5} 60 s at 30 fps, {width}x{height}, {vertices} vertices: {took:6.2} s ({:5.1}× real time)",
            format.name(),
            seconds / took
        ));
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
