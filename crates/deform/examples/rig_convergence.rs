//! Measures how far the rigs' fixed per-frame iteration counts leave a
//! frame from its converged solution, on the motion `puppetry bench --rigs`
//! times: the table behind `ffd::DEFAULT_ITERATIONS` and the skeleton's
//! default rounds (docs/rigs.md). Run with
//! `cargo run --release -p puppetry-deform --example rig_convergence -- [ffd|skeleton] MESH.mesh.json…`
//! (`puppetry mesh assets/gingerbread/gingerbread.png --vertices N -o …`
//! makes the bench's meshes).

use glam::DVec2;
use puppetry_deform::arap::Anchor;
use puppetry_deform::ffd::{Basis, GridSpec, LpFfd, LpParams};
use puppetry_deform::skeleton::{ShapeAware, SkeletonParams};
use puppetry_mesh::Mesh;

const FRAMES: usize = 200;
const SAMPLE_EVERY: usize = 10;

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

/// The bench's lp-FFD motion: four vertex handles on small circles.
fn ffd(mesh: &Mesh, basis: Basis) {
    let n = mesh.vertices().len();
    let spacing = n / 4;
    let chosen: Vec<usize> = (0..4)
        .map(|h| (h * spacing + spacing / 2).min(n - 1))
        .collect();
    let anchors: Vec<Anchor> = chosen.iter().map(|&v| Anchor::Vertex(v as u32)).collect();
    let rest: Vec<DVec2> = chosen.iter().map(|&v| mesh.vertices()[v]).collect();
    let spec = GridSpec::around(mesh, 10, 10, basis);
    let rig = |iterations| {
        let params = LpParams {
            iterations,
            ..LpParams::default()
        };
        let mut r = LpFfd::register(mesh, spec, params).unwrap();
        r.compile(&anchors, &[]).unwrap();
        r
    };
    let counts = [1, 2, 3, 4, 6, 8];
    let mut rigs: Vec<LpFfd> = counts.iter().map(|&i| rig(i)).collect();
    let mut converged = rig(200);
    let mut gaps = vec![Vec::new(); counts.len()];
    let mut offsets = vec![Vec::new(); counts.len()];
    let mut targets = rest.clone();
    for f in 0..FRAMES {
        let t = f as f64 * 0.05;
        for (h, (o, r)) in targets.iter_mut().zip(&rest).enumerate() {
            let phase = t + h as f64 * 1.3;
            *o = *r + DVec2::new(phase.cos(), phase.sin()) * (0.03 * mesh.size());
        }
        converged.update(&targets, &[]).unwrap();
        for r in rigs.iter_mut() {
            r.update(&targets, &[]).unwrap();
        }
        if f % SAMPLE_EVERY == SAMPLE_EVERY - 1 {
            let best = converged.energy(converged.grid(), &targets, &[]).unwrap();
            for (k, r) in rigs.iter().enumerate() {
                let e = r.energy(r.grid(), &targets, &[]).unwrap();
                gaps[k].push((e - best) / best);
                offsets[k].push(max_distance(r.pose(), converged.pose()) / mesh.size());
            }
        }
    }
    println!(
        "lp-FFD {basis:?}, {n} vertices: iterations / frame, energy gap (E−E*)/E* median, max; vertex offset / mesh size median, max"
    );
    for (k, &c) in counts.iter().enumerate() {
        let max = |xs: &[f64]| xs.iter().copied().fold(0.0, f64::max);
        println!(
            "  {c:>3}  {:>10.2e} {:>10.2e}   {:>10.2e} {:>10.2e}",
            median(gaps[k].clone()),
            max(&gaps[k]),
            median(offsets[k].clone()),
            max(&offsets[k])
        );
    }
}

/// The bench's skeleton motion: every bone swinging ±0.35 rad.
fn skeleton(mesh: &Mesh, bone_start: bool) {
    let skeleton = puppetry_testkit::gingerbread_skeleton();
    let rounds_max = 40;
    let params = |rounds| SkeletonParams {
        rounds,
        bone_start,
        ..SkeletonParams::default()
    };
    let mut long = ShapeAware::register(mesh, skeleton.clone(), params(rounds_max)).unwrap();
    let mut converged = ShapeAware::register(mesh, skeleton.clone(), params(400)).unwrap();
    let checked = [1, 2, 3, 4, 6, 8, 12];
    let mut short: Vec<ShapeAware> = checked
        .iter()
        .map(|&r| ShapeAware::register(mesh, skeleton.clone(), params(r)).unwrap())
        .collect();
    let rest = skeleton.rest_pose();
    let mut pose = rest.clone();
    let mut gaps = vec![Vec::new(); rounds_max + 1];
    let mut offsets = vec![Vec::new(); checked.len()];
    let mut reduction = Vec::new();
    for frame in 0..FRAMES {
        if frame % SAMPLE_EVERY != SAMPLE_EVERY - 1 {
            continue;
        }
        let t = frame as f64 * 0.05;
        for (bone, angle) in pose.angles.iter_mut().enumerate() {
            *angle = rest.angles[bone] + 0.35 * (t + bone as f64 * 0.9).sin();
        }
        let joints = skeleton.joints_of(&pose).unwrap();
        long.update(&joints).unwrap();
        converged.update(&joints).unwrap();
        let best = *converged.energies().last().unwrap();
        let first = long.energies()[0];
        reduction.push((first - best) / best);
        for (k, e) in long.energies().iter().enumerate() {
            gaps[k].push((e - best) / best);
        }
        for (k, d) in short.iter_mut().enumerate() {
            d.update(&joints).unwrap();
            offsets[k].push(max_distance(d.pose(), converged.pose()) / mesh.size());
        }
    }
    println!(
        "skeleton, {} vertices, {}: stitch energy gap (E−E*)/E* after k shape-matching rounds (median over frames; E* after 400; the first stitch's gap is {:.2e})",
        mesh.vertices().len(),
        if bone_start {
            "bone start"
        } else {
            "identity start"
        },
        median(reduction)
    );
    for (k, g) in gaps.iter().enumerate() {
        if [0, 1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 30, 40].contains(&k) {
            let offset = checked
                .iter()
                .position(|&c| c == k)
                .map(|i| format!("{:.2e}", median(offsets[i].clone())))
                .unwrap_or_default();
            println!("  {k:>3}  {:>10.2e}   {offset}", median(g.clone()));
        }
    }
}

/// The deformer test's pose (left arm up, left thigh, head tilt): the
/// energy after k rounds from each start.
fn held_pose(mesh: &Mesh) {
    let skeleton = puppetry_testkit::gingerbread_skeleton();
    let mut pose = skeleton.rest_pose();
    pose.rotate_joint(4, 1.0).unwrap();
    pose.rotate_joint(10, -0.6).unwrap();
    pose.rotate_joint(2, 0.4).unwrap();
    for bone_start in [false, true] {
        let params = SkeletonParams {
            rounds: 40,
            bone_start,
            ..SkeletonParams::default()
        };
        let mut d = ShapeAware::register(mesh, skeleton.clone(), params).unwrap();
        d.update_pose(&pose).unwrap();
        let e = d.energies();
        println!(
            "held pose, bone start {bone_start}: {:?}",
            [0, 2, 4, 5, 6, 7, 8, 10, 12, 16, 20, 40].map(|k| e[k].round())
        );
    }
}

fn main() {
    let mut args = std::env::args().skip(1).peekable();
    // `ffd` or `skeleton` first runs only that rig.
    let only = args.next_if(|a| a == "ffd" || a == "skeleton" || a == "held");
    for path in args {
        let mesh = Mesh::load(std::path::Path::new(&path)).unwrap();
        if only.as_deref() != Some("skeleton") {
            ffd(&mesh, Basis::Bernstein);
            ffd(&mesh, Basis::Lattice);
        }
        if only.as_deref() == Some("held") {
            held_pose(&mesh);
            continue;
        }
        if only.as_deref() != Some("ffd") {
            skeleton(&mesh, false);
            skeleton(&mesh, true);
        }
    }
}
