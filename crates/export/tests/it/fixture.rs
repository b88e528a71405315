//! The demo puppet (`assets/gingerbread`: its mesh, uv and picture) moved
//! synthetically: shared by the tests and the benchmark example.

use std::path::PathBuf;

use puppetry_export::{AnimatedPuppet, Animation, load_png};

/// The workspace root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("the workspace root")
}

pub fn mesh_path() -> PathBuf {
    root().join("assets/gingerbread/gingerbread.mesh.json")
}

pub fn picture_path() -> PathBuf {
    root().join("assets/gingerbread/gingerbread.png")
}

/// The gingerbread figure on a `stage` (width, height), its feet at
/// `feet` (stage point) and `scale` times its mesh size, bending over
/// `frames` frames: frame k turns each vertex about the feet by an angle
/// growing with its height (a bend of up to `bend` radians at the head,
/// following `sin(2π k / period + phase)`) and sways it sideways.
#[allow(clippy::too_many_arguments)]
pub fn bending_puppet(
    name: &str,
    frames: usize,
    feet: [f64; 2],
    scale: f64,
    bend: f64,
    period: f64,
    phase: f64,
) -> AnimatedPuppet {
    let mesh = puppetry_mesh::Mesh::load(&mesh_path()).expect("the demo mesh loads");
    let image = load_png(&picture_path()).expect("the demo picture loads");
    let rest = mesh.vertices();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for v in rest {
        x0 = x0.min(v.x);
        x1 = x1.max(v.x);
        y0 = y0.min(v.y);
        y1 = y1.max(v.y);
    }
    let cx = (x0 + x1) / 2.0;
    let frames = (0..frames)
        .map(|k| {
            let s = (std::f64::consts::TAU * k as f64 / period + phase).sin();
            rest.iter()
                .map(|v| {
                    let (dx, dy) = ((v.x - cx) * scale, (v.y - y0) * scale);
                    let h = (v.y - y0) / (y1 - y0);
                    let a = bend * s * h * h;
                    let (sin, cos) = a.sin_cos();
                    let sway = 12.0 * scale * s * h;
                    [
                        (feet[0] + dx * cos - dy * sin + sway) as f32,
                        (feet[1] + dx * sin + dy * cos) as f32,
                    ]
                })
                .collect()
        })
        .collect();
    AnimatedPuppet {
        name: name.to_string(),
        triangles: mesh.triangles().to_vec(),
        uv: mesh
            .uv()
            .expect("the demo mesh has uv")
            .iter()
            .map(|q| [q.x as f32, q.y as f32])
            .collect(),
        image,
        frames,
        draw_orders: Vec::new(),
        depths: Vec::new(),
        snaps: Vec::new(),
        skeleton: None,
    }
}

/// The test scene: an 800×600 stage at `fps`, two gingerbread figures of
/// one name (a big one bending and a small one in front of it, bending the
/// other way), `frames` frames, one bend per 30 frames.
pub fn two_figures(frames: usize, fps: f64) -> Animation {
    Animation {
        stage_width: 800.0,
        stage_height: 600.0,
        fps,
        puppets: vec![
            bending_puppet("gingerbread", frames, [360.0, 60.0], 1.0, 0.6, 30.0, 0.0),
            bending_puppet("gingerbread", frames, [600.0, 40.0], 0.55, 0.8, 30.0, 2.0),
        ],
        frame_count: frames,
    }
}

/// Records at `path` a take of `stage` named `name` in which one finger
/// (source "hand", contact 1) goes down at `points[0]` and drags through
/// the rest: step k at `t = k / fps`, each followed by the frames of the
/// puppets it moved (as a recorder would at that pace). Returns those
/// frames' points, in order.
pub fn record_drag(
    path: &std::path::Path,
    stage: &mut puppetry_stage::Stage,
    name: &str,
    fps: f64,
    points: &[glam::DVec2],
) -> Vec<Vec<[f32; 2]>> {
    record_drag_with(path, stage, name, fps, points, |_, _| Vec::new())
}

/// [`record_drag`], with the changes `more(k, stage)` gives applied after
/// step k's contact (an Alt+click's `DepthFlip`, say).
pub fn record_drag_with(
    path: &std::path::Path,
    stage: &mut puppetry_stage::Stage,
    name: &str,
    fps: f64,
    points: &[glam::DVec2],
    mut more: impl FnMut(usize, &puppetry_stage::Stage) -> Vec<puppetry_stage::Change>,
) -> Vec<Vec<[f32; 2]>> {
    use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
    use puppetry_stage::Change;
    use puppetry_take::{Frame, Header, Record, Step, TakeWriter};
    stage.solve();
    // Steps carry the handle events, as the daemon records them.
    stage.keep_events(true);
    let header = Header::of_stage(name, &format!("{name}.toml"), stage, true);
    let mut writer = TakeWriter::create(path, &header).unwrap();
    let mut frames = Vec::new();
    for (k, &at) in points.iter().enumerate() {
        let phase = if k == 0 { Phase::Down } else { Phase::Move };
        let change = Change::Contacts {
            frame: ContactFrame {
                source: SourceId::new("hand"),
                time: k as f64,
                contacts: vec![Contact::new(1, phase, at)],
            },
        };
        stage.apply_change(&change).unwrap();
        let mut changes = vec![change];
        for change in more(k, stage) {
            stage.apply_change(&change).unwrap();
            changes.push(change);
        }
        let solved = stage.solve();
        let t = k as f64 / fps;
        let mut events = Vec::new();
        stage.take_events(&mut events);
        writer
            .write(&Record::Step(Step { t, changes, events }))
            .unwrap();
        for (p, _) in solved {
            let frame = Frame::of_pose(p, t, stage.puppets()[p as usize].pose());
            frames.push(frame.points.clone());
            writer.write(&Record::Frame(frame)).unwrap();
        }
    }
    writer.flush().unwrap();
    frames
}
