//! `puppetry bench-case`: times the ARAP update on a mesh, handle vertices and
//! per-frame handle targets that someone else chose, so another solver can be
//! timed on exactly the same problem in the same run
//! (`benches/peers/libigl_arap.py` does this against libigl's ARAP).
//!
//! The case is a JSON file; the answer is one JSON line with every frame's
//! update time, and optionally every frame's solved pose written as raw
//! little-endian `f64`s (frame-major, then vertex, then x, y): text would make
//! a 10k-vertex run's poses tens of megabytes of JSON to parse.
//!
//! Only the update is timed, after registration and compilation, exactly as
//! `puppetry bench` times it; writing the poses happens after the timed loop.
//! Each update's process CPU time is kept beside its wall time: on a shared
//! machine a long call is preempted more often than a short one, so wall
//! times alone would favour whichever solver is faster.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use puppetry_deform::{Anchor, Arap, ArapError, Steps};
use puppetry_mesh::{Mesh, MeshError};

/// The problem to time, as read from the case file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Case {
    /// The rest mesh (`.mesh.json`), relative to the case file's folder.
    mesh: PathBuf,
    /// The handle vertices, in the order of each frame's targets.
    handles: Vec<u32>,
    /// Per frame, one target `[x, y]` per handle, in mesh units.
    frames: Vec<Vec<[f64; 2]>>,
}

/// What `puppetry bench-case` prints.
#[derive(Debug, Serialize)]
struct CaseTimes {
    /// Vertices of the mesh.
    vertices: usize,
    /// Triangles of the mesh.
    triangles: usize,
    /// Handle vertices held.
    handles: usize,
    /// Registration, ms.
    register_ms: f64,
    /// Compiling the handle vertices, µs.
    compile_us: f64,
    /// Wall time of each update, µs: one per frame, in frame order.
    update_us: Vec<f64>,
    /// The same updates' process CPU time, µs.
    update_cpu_us: Vec<f64>,
}

/// Why `puppetry bench-case` could not time a case.
#[derive(Debug, thiserror::Error)]
pub enum PeersError {
    /// The case file could not be read.
    #[error("{file}: {source}")]
    Read {
        /// The case file, as given.
        file: String,
        /// What the file system said.
        source: std::io::Error,
    },
    /// The case file is not a case: not JSON, a field missing or one
    /// unknown.
    #[error("{file}: {source}")]
    Parse {
        /// The case file, as given.
        file: String,
        /// What the JSON parser said.
        source: serde_json::Error,
    },
    /// The case's mesh could not be loaded.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// A frame does not give exactly one target per handle.
    #[error("frame {frame}: {got} targets for {expected} handles")]
    FrameSize {
        /// The frame, counted from 0.
        frame: usize,
        /// Targets it gives.
        got: usize,
        /// Handles in the case.
        expected: usize,
    },
    /// The solver refused the mesh or the handles, or an update failed.
    #[error(transparent)]
    Arap(#[from] ArapError),
    /// The poses file could not be written.
    #[error("{file}: {source}")]
    Write {
        /// The poses file, as given.
        file: String,
        /// What the file system said.
        source: std::io::Error,
    },
}

/// Reads a case file; its mesh path is taken relative to the case's folder.
fn load_case(path: &Path) -> Result<(Case, Mesh), PeersError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| PeersError::Read {
        file: file.clone(),
        source,
    })?;
    let case: Case =
        serde_json::from_str(&text).map_err(|source| PeersError::Parse { file, source })?;
    let mesh_path = path.parent().unwrap_or(Path::new(".")).join(&case.mesh);
    let mesh = Mesh::load(&mesh_path)?;
    Ok((case, mesh))
}

/// Registers, compiles the handle vertices, then times one update per frame.
/// Returns the times and, when `keep_poses`, every frame's pose.
fn run(case: &Case, mesh: &Mesh, keep_poses: bool) -> Result<(CaseTimes, Vec<DVec2>), PeersError> {
    let frames: Vec<Vec<DVec2>> = case
        .frames
        .iter()
        .enumerate()
        .map(|(frame, targets)| {
            if targets.len() == case.handles.len() {
                Ok(targets.iter().map(|&t| DVec2::from(t)).collect())
            } else {
                Err(PeersError::FrameSize {
                    frame,
                    got: targets.len(),
                    expected: case.handles.len(),
                })
            }
        })
        .collect::<Result<_, _>>()?;

    let start = Instant::now();
    let mut arap = Arap::register(mesh)?;
    let register_ms = start.elapsed().as_secs_f64() * 1e3;
    let anchors: Vec<Anchor> = case.handles.iter().map(|&v| Anchor::Vertex(v)).collect();
    let start = Instant::now();
    arap.compile(&anchors)?;
    let compile_us = start.elapsed().as_secs_f64() * 1e6;

    let n = mesh.vertices().len();
    // Reserved up front so the timed loop's copies never reallocate.
    let mut poses = Vec::with_capacity(if keep_poses { n * frames.len() } else { 0 });
    let mut update_us = Vec::with_capacity(frames.len());
    let mut update_cpu_us = Vec::with_capacity(frames.len());
    for targets in &frames {
        let cpu = process_cpu_seconds();
        let start = Instant::now();
        arap.update(targets, Steps::Both)?;
        update_us.push(start.elapsed().as_secs_f64() * 1e6);
        update_cpu_us.push((process_cpu_seconds() - cpu) * 1e6);
        if keep_poses {
            poses.extend_from_slice(arap.pose());
        }
    }
    let times = CaseTimes {
        vertices: n,
        triangles: mesh.triangles().len(),
        handles: case.handles.len(),
        register_ms,
        compile_us,
        update_us,
        update_cpu_us,
    };
    Ok((times, poses))
}

/// CPU time of the whole process (as Python's `time.process_time`, which
/// the peer script times the other side with).
fn process_cpu_seconds() -> f64 {
    let mut now = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `now` is a valid timespec for the call to fill.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut now) };
    now.tv_sec as f64 + now.tv_nsec as f64 * 1e-9
}

/// Writes poses as little-endian `f64` pairs.
fn write_poses(path: &Path, poses: &[DVec2]) -> Result<(), PeersError> {
    let mut bytes = Vec::with_capacity(poses.len() * 16);
    for p in poses {
        bytes.extend_from_slice(&p.x.to_le_bytes());
        bytes.extend_from_slice(&p.y.to_le_bytes());
    }
    std::fs::write(path, bytes).map_err(|source| PeersError::Write {
        file: path.display().to_string(),
        source,
    })
}

/// `puppetry bench-case CASE [--poses FILE]`: the JSON line to print
/// (sizes, registration and compile times, and every frame's update wall
/// and CPU time, µs), after writing every frame's pose to `poses` when
/// given.
pub fn bench_case_command(case: &Path, poses: Option<&Path>) -> Result<String, PeersError> {
    let (case, mesh) = load_case(case)?;
    let (times, solved) = run(&case, &mesh, poses.is_some())?;
    if let Some(path) = poses {
        write_poses(path, &solved)?;
    }
    Ok(serde_json::to_string(&times).expect("plain numbers serialize"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Mesh {
        // A 3×3 grid of vertices, two triangles per cell.
        let mut vertices = Vec::new();
        for y in 0..3 {
            for x in 0..3 {
                vertices.push(DVec2::new(x as f64, y as f64));
            }
        }
        let mut triangles = Vec::new();
        for y in 0..2u32 {
            for x in 0..2u32 {
                let a = y * 3 + x;
                triangles.push([a, a + 1, a + 4]);
                triangles.push([a, a + 4, a + 3]);
            }
        }
        let text = format!(
            "{{\"vertices\":{},\"triangles\":{}}}",
            serde_json::to_string(&vertices.iter().map(|v| [v.x, v.y]).collect::<Vec<_>>())
                .unwrap(),
            serde_json::to_string(&triangles).unwrap()
        );
        Mesh::from_json("square", &text).unwrap()
    }

    #[test]
    fn handles_land_on_their_targets_in_every_frame() {
        let mesh = square();
        let case = Case {
            mesh: PathBuf::new(),
            handles: vec![0, 8],
            frames: vec![
                vec![[0.0, 0.0], [2.0, 2.0]],
                vec![[0.0, 0.0], [3.0, 1.0]],
                vec![[1.0, 0.0], [1.0, 3.0]],
            ],
        };
        let (times, poses) = run(&case, &mesh, true).unwrap();
        assert_eq!(times.update_us.len(), 3);
        assert_eq!(times.update_cpu_us.len(), 3);
        assert_eq!(poses.len(), 3 * 9);
        for (f, targets) in case.frames.iter().enumerate() {
            let pose = &poses[f * 9..(f + 1) * 9];
            assert!(pose[0].distance(DVec2::from(targets[0])) < 1e-9);
            assert!(pose[8].distance(DVec2::from(targets[1])) < 1e-9);
        }
        // The first frame holds the rest shape's diagonal: the rest pose.
        for (p, r) in poses[..9].iter().zip(mesh.vertices()) {
            assert!(p.distance(*r) < 1e-9, "{p} vs {r}");
        }
    }

    #[test]
    fn a_frame_with_the_wrong_target_count_is_refused() {
        let mesh = square();
        let case = Case {
            mesh: PathBuf::new(),
            handles: vec![0, 8],
            frames: vec![vec![[0.0, 0.0]]],
        };
        assert!(matches!(
            run(&case, &mesh, false),
            Err(PeersError::FrameSize { frame: 0, .. })
        ));
    }

    #[test]
    fn poses_are_written_as_little_endian_pairs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("poses.bin");
        write_poses(&path, &[DVec2::new(1.5, -2.0)]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 16);
        assert_eq!(f64::from_le_bytes(bytes[..8].try_into().unwrap()), 1.5);
        assert_eq!(f64::from_le_bytes(bytes[8..].try_into().unwrap()), -2.0);
    }
}
