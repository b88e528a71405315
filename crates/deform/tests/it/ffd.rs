//! The lp-FFD rig against its specification: exact rest pose, direct FFD as
//! the λ_ml = 0 special case, vertex handles within a tolerance derived from
//! the energy weights, multi-piece meshes, rigid translation, painted
//! rigidity, monotone local/global iterations, no allocation per frame, and
//! input errors. (Frame timings: `puppetry bench --rigs`.)

use puppetry_testkit::alloc;

use crate::common::*;
use glam::DVec2;
use puppetry_deform::Anchor;
use puppetry_deform::ffd::{Basis, FfdError, GridSpec, LpFfd, LpParams};
use puppetry_deform::measure;
use puppetry_mesh::Mesh;

// Allocations are counted per thread, so tests running alongside do not
// disturb the count.

const BASES: [Basis; 2] = [Basis::Bernstein, Basis::Lattice];

fn rig(mesh: &Mesh, size: usize, basis: Basis, params: LpParams) -> LpFfd {
    LpFfd::register(mesh, GridSpec::around(mesh, size, size, basis), params).unwrap()
}

fn rest_point(mesh: &Mesh, anchor: &Anchor) -> DVec2 {
    match *anchor {
        Anchor::Vertex(v) => mesh.vertices()[v as usize],
        Anchor::Point { triangle, bary } => mesh.point_at(triangle, bary),
    }
}

/// Anchors at the bar's four corners and a point inside.
fn bar_anchors(mesh: &Mesh) -> Vec<Anchor> {
    let verts = mesh.vertices();
    let corner = |p: DVec2| {
        Anchor::Vertex(
            (0..verts.len())
                .min_by(|&a, &b| verts[a].distance(p).total_cmp(&verts[b].distance(p)))
                .unwrap() as u32,
        )
    };
    vec![
        corner(DVec2::new(0.0, 0.0)),
        corner(DVec2::new(10.0, 0.0)),
        corner(DVec2::new(0.0, 3.0)),
        corner(DVec2::new(10.0, 3.0)),
        Anchor::Point {
            triangle: 17,
            bary: [0.2, 0.3, 0.5],
        },
    ]
}

#[test]
fn rest_targets_give_the_rest_shape_exactly() {
    let mesh = jittered(10, 3);
    for basis in BASES {
        let mut ffd = rig(&mesh, 6, basis, LpParams::default());
        let anchors = bar_anchors(&mesh);
        let targets: Vec<DVec2> = anchors.iter().map(|a| rest_point(&mesh, a)).collect();
        let grid_handles = [0, 7, 20];
        let grid_targets: Vec<DVec2> = grid_handles.iter().map(|&g| ffd.rest_grid()[g]).collect();
        ffd.compile(&anchors, &grid_handles).unwrap();
        for _ in 0..3 {
            let pose = ffd.update(&targets, &grid_targets).unwrap().to_vec();
            let off = max_distance(&pose, mesh.vertices());
            assert!(
                off <= 1e-12 * mesh.size(),
                "{basis:?}: pose off rest by {off}"
            );
            let grid_off = max_distance(ffd.grid(), ffd.rest_grid());
            assert!(
                grid_off <= 1e-12 * mesh.size(),
                "{basis:?}: grid off by {grid_off}"
            );
        }
        // Plain FFD of the rest grid is the rest shape too.
        let plain = ffd.deform_with_grid(ffd.rest_grid()).unwrap();
        assert!(max_distance(&plain, mesh.vertices()) <= 1e-12 * mesh.size());
    }
}

#[test]
fn both_bases_reproduce_affine_maps() {
    // V = W P is exact for an affine map of the regular grid: the property
    // the displacement form (V = V̄ + WΔ) relies on.
    let mesh = jittered(8, 4);
    let map = |p: DVec2| DVec2::new(1.3 * p.x + 0.4 * p.y + 2.0, -0.2 * p.x + 0.8 * p.y - 1.0);
    for basis in BASES {
        let ffd = rig(&mesh, 7, basis, LpParams::default());
        let grid: Vec<DVec2> = ffd.rest_grid().iter().map(|&p| map(p)).collect();
        let pose = ffd.deform_with_grid(&grid).unwrap();
        let expected: Vec<DVec2> = mesh.vertices().iter().map(|&p| map(p)).collect();
        let off = max_distance(&pose, &expected);
        assert!(off < 1e-12 * mesh.size(), "{basis:?}: off by {off}");
    }
}

#[test]
fn without_locality_a_grid_drag_is_plain_ffd_of_the_dragged_grid() {
    let mesh = jittered(10, 3);
    let params = LpParams {
        locality: 0.0,
        ..LpParams::default()
    };
    for basis in BASES {
        let mut ffd = rig(&mesh, 5, basis, params);
        let dragged = [6, 12, 18];
        let targets = [
            DVec2::new(2.0, 5.0),
            DVec2::new(5.5, -1.0),
            DVec2::new(9.0, 2.0),
        ];
        ffd.compile(&[], &dragged).unwrap();
        let pose = ffd.update(&[], &targets).unwrap().to_vec();
        // The minimiser of λ_gp Σ_D |P − d|² + λ_gr Σ_rest |P − P⁰|²:
        // dragged handles at their targets, the others at rest.
        let mut expected_grid = ffd.rest_grid().to_vec();
        for (&g, &t) in dragged.iter().zip(&targets) {
            expected_grid[g] = t;
        }
        let tol = 1e-12 * mesh.size();
        assert!(max_distance(ffd.grid(), &expected_grid) < tol, "{basis:?}");
        let plain = ffd.deform_with_grid(&expected_grid).unwrap();
        assert!(max_distance(&pose, &plain) < tol, "{basis:?}");
        // The direct-FFD comparison function is the same problem.
        let direct = ffd.direct_ffd(&[], &[], &dragged, &targets).unwrap();
        assert!(max_distance(&direct, &expected_grid) < tol, "{basis:?}");
    }
}

#[test]
fn direct_ffd_is_lp_ffd_without_locality() {
    let mesh = jittered(10, 3);
    let params = LpParams {
        locality: 0.0,
        ..LpParams::default()
    };
    for basis in BASES {
        let mut ffd = rig(&mesh, 6, basis, params);
        let anchors = bar_anchors(&mesh);
        let targets: Vec<DVec2> = anchors
            .iter()
            .enumerate()
            .map(|(h, a)| rest_point(&mesh, a) + DVec2::new(h as f64 * 0.3, 1.0 - h as f64 * 0.2))
            .collect();
        ffd.compile(&anchors, &[3]).unwrap();
        ffd.update(&targets, &[DVec2::new(4.0, -2.0)]).unwrap();
        let direct = ffd
            .direct_ffd(&anchors, &targets, &[3], &[DVec2::new(4.0, -2.0)])
            .unwrap();
        let off = max_distance(&direct, ffd.grid());
        assert!(off < 1e-9 * mesh.size(), "{basis:?}: off by {off}");
    }
}

/// Tolerance for vertex handles, derived from the weights. Starting from
/// rest, the first global step minimises the quadratic `Q_I` (all rotations
/// identity), and every local/global step after it lowers the energy `E`
/// (local: best rotations for the grid; global: exact minimiser for the
/// rotations). So after any number of iterations
/// `λ_mp Σ|rᵢ|² ≤ E ≤ Q_I(P_ref)` for any reference grid `P_ref`. For
/// targets that an affine map `A` of the rest shape meets exactly, take
/// `P_ref = A(P⁰)` (both bases reproduce affine maps): then `E_mp = 0` and
/// `Q_I(P_ref) = λ_ml Σ_t w_t Σ_{edges of t} 2|(A − I)ē|² + λ_gr Σᵢ |A(P⁰ᵢ) − P⁰ᵢ|²`
/// (each edge counted from both ends, `w_ij` the sum over its triangles).
fn affine_bound(mesh: &Mesh, ffd: &LpFfd, map: impl Fn(DVec2) -> DVec2, params: &LpParams) -> f64 {
    let linear = |d: DVec2| map(d) - map(DVec2::ZERO);
    let v = mesh.vertices();
    let mut locality = 0.0;
    for (t, w) in mesh.triangles().iter().zip(mesh.weights()) {
        for c in 0..3 {
            let e = v[t[c] as usize] - v[t[(c + 1) % 3] as usize];
            locality += w * 2.0 * (linear(e) - e).length_squared();
        }
    }
    let regular: f64 = ffd
        .rest_grid()
        .iter()
        .map(|&p| (map(p) - p).length_squared())
        .sum();
    params.locality * locality + params.regular * regular
}

#[test]
fn vertex_handles_land_within_the_derived_tolerance() {
    let mesh = jittered(10, 3);
    let params = LpParams::default();
    let centre = DVec2::new(5.0, 1.5);
    type Map = Box<dyn Fn(DVec2) -> DVec2>;
    let maps: [(&str, Map); 2] = [
        (
            "translation",
            Box::new(|p: DVec2| p + DVec2::new(3.0, -2.0)),
        ),
        (
            "stretch",
            Box::new(move |p: DVec2| centre + (p - centre) * DVec2::new(1.3, 0.9)),
        ),
    ];
    for basis in BASES {
        for (name, map) in &maps {
            for iterations in [1, 4, 30] {
                let params = LpParams {
                    iterations,
                    ..params
                };
                let mut ffd = rig(&mesh, 6, basis, params);
                let anchors = bar_anchors(&mesh);
                let targets: Vec<DVec2> =
                    anchors.iter().map(|a| map(rest_point(&mesh, a))).collect();
                ffd.compile(&anchors, &[]).unwrap();
                let pose = ffd.update(&targets, &[]).unwrap().to_vec();
                let bound = affine_bound(&mesh, &ffd, map, &params);
                let squared: f64 = anchors
                    .iter()
                    .zip(&targets)
                    .map(|(a, t)| {
                        let at = match *a {
                            Anchor::Vertex(v) => pose[v as usize],
                            Anchor::Point { triangle, bary } => {
                                let tri = mesh.triangles()[triangle as usize];
                                (0..3).map(|c| pose[tri[c] as usize] * bary[c]).sum()
                            }
                        };
                        at.distance_squared(*t)
                    })
                    .sum();
                assert!(
                    params.vertex * squared <= bound * (1.0 + 1e-9) + 1e-12,
                    "{basis:?} {name} ×{iterations}: λ_mp Σ|r|² = {} above the bound {bound}",
                    params.vertex * squared
                );
                // The energy the bound rests on.
                let energy = ffd.energy(ffd.grid(), &targets, &[]).unwrap();
                assert!(energy <= bound * (1.0 + 1e-9) + 1e-12, "{basis:?} {name}");
                // And the handles did follow: the residual is a small part of
                // the distance asked for.
                let asked: f64 = anchors
                    .iter()
                    .zip(&targets)
                    .map(|(a, t)| rest_point(&mesh, a).distance_squared(*t))
                    .sum();
                assert!(
                    squared < 0.05 * asked,
                    "{basis:?} {name}: {squared} vs {asked}"
                );
            }
        }
    }
}

#[test]
fn iterations_never_raise_the_energy() {
    let mesh = jittered(10, 3);
    let params = LpParams {
        iterations: 1,
        ..LpParams::default()
    };
    for basis in BASES {
        let mut ffd = rig(&mesh, 6, basis, params);
        // A bend: ends pulled up and down, far from anything affine.
        let anchors = bar_anchors(&mesh);
        let targets: Vec<DVec2> = anchors
            .iter()
            .map(|a| {
                let p = rest_point(&mesh, a);
                p + DVec2::new(0.0, 0.4 * (p.x - 5.0) * (p.x - 5.0) / 5.0)
            })
            .collect();
        ffd.compile(&anchors, &[]).unwrap();
        let mut last = f64::INFINITY;
        let mut energies = Vec::new();
        for _ in 0..40 {
            ffd.update(&targets, &[]).unwrap();
            let e = ffd.energy(ffd.grid(), &targets, &[]).unwrap();
            assert!(e <= last * (1.0 + 1e-10), "{basis:?}: {e} after {last}");
            energies.push(e);
            last = e;
        }
        // The local steps matter: the energy drops after the first step.
        assert!(
            energies[39] < energies[0] * 0.999,
            "{basis:?}: {energies:?}"
        );
    }
}

#[test]
fn locality_lowers_distortion_against_direct_ffd() {
    // The paper's claim (its Table 1): for the same vertex drags, lp-FFD
    // keeps triangles closer to their rest shape than direct FFD does.
    let mesh = jittered(12, 3);
    let anchors = [
        Anchor::Vertex(0),
        Anchor::Vertex(39),
        Anchor::Vertex(12),
        Anchor::Vertex(51),
    ];
    // Lift the right end: a bend.
    let targets: Vec<DVec2> = anchors
        .iter()
        .map(|a| {
            let p = rest_point(&mesh, a);
            if p.x > 6.0 {
                p + DVec2::new(-1.0, 4.0)
            } else {
                p
            }
        })
        .collect();
    for basis in BASES {
        let mut ffd = rig(&mesh, 8, basis, LpParams::default());
        ffd.compile(&anchors, &[]).unwrap();
        let mut lp = Vec::new();
        for _ in 0..30 {
            lp = ffd.update(&targets, &[]).unwrap().to_vec();
        }
        let direct_grid = ffd.direct_ffd(&anchors, &targets, &[], &[]).unwrap();
        let direct = ffd.deform_with_grid(&direct_grid).unwrap();
        let (a, b) = (
            measure::mesh_distortion(&mesh, &lp).unwrap(),
            measure::mesh_distortion(&mesh, &direct).unwrap(),
        );
        assert!(
            a.angular < b.angular && a.area < b.area,
            "{basis:?}: lp-FFD {a:?}, direct FFD {b:?}"
        );
    }
}

#[test]
fn point_handle_on_a_vertex_equals_the_vertex_handle() {
    let mesh = jittered(10, 3);
    let tri = mesh.triangles()[12];
    let target = [mesh.vertices()[tri[1] as usize] + DVec2::new(1.0, 2.0)];
    let solve = |anchor: Anchor| {
        let mut ffd = rig(&mesh, 6, Basis::Bernstein, LpParams::default());
        ffd.compile(&[anchor], &[]).unwrap();
        ffd.update(&target, &[]).unwrap().to_vec()
    };
    let by_vertex = solve(Anchor::Vertex(tri[1]));
    let by_point = solve(Anchor::Point {
        triangle: 12,
        bary: [0.0, 1.0, 0.0],
    });
    assert!(max_distance(&by_vertex, &by_point) < 1e-12 * mesh.size());
}

#[test]
fn moving_every_grid_handle_by_one_offset_translates_the_mesh() {
    let mesh = jittered(10, 3);
    let shift = DVec2::new(-7.5, 3.25);
    for basis in BASES {
        let mut ffd = rig(&mesh, 5, basis, LpParams::default());
        let all: Vec<usize> = (0..ffd.handle_count()).collect();
        let targets: Vec<DVec2> = ffd.rest_grid().iter().map(|&p| p + shift).collect();
        ffd.compile(&[], &all).unwrap();
        let pose = ffd.update(&[], &targets).unwrap().to_vec();
        let expected: Vec<DVec2> = mesh.vertices().iter().map(|&p| p + shift).collect();
        let off = max_distance(&pose, &expected);
        assert!(off < 1e-12 * mesh.size(), "{basis:?}: off by {off}");
        assert!(max_distance(ffd.grid(), &targets) < 1e-12 * mesh.size());
    }
}

#[test]
fn separate_pieces_share_the_grid() {
    let mesh = islands(3);
    let pieces = mesh.pieces();
    assert_eq!(pieces.len(), 3);
    for basis in BASES {
        let mut ffd = rig(&mesh, 10, basis, LpParams::default());
        // Two handles on the first piece move it up; nothing holds the others.
        let anchors = [
            Anchor::Vertex(pieces[0].vertices[0]),
            Anchor::Vertex(*pieces[0].vertices.last().unwrap()),
        ];
        let lift = DVec2::new(0.0, 1.5);
        let targets: Vec<DVec2> = anchors
            .iter()
            .map(|a| rest_point(&mesh, a) + lift)
            .collect();
        ffd.compile(&anchors, &[]).unwrap();
        let mut pose = Vec::new();
        for _ in 0..10 {
            pose = ffd.update(&targets, &[]).unwrap().to_vec();
        }
        let moved = |piece: usize| -> f64 {
            let vs = &pieces[piece].vertices;
            vs.iter()
                .map(|&v| (pose[v as usize] - mesh.vertices()[v as usize]).y)
                .sum::<f64>()
                / vs.len() as f64
        };
        assert!(
            moved(0) > 0.7 * lift.y,
            "{basis:?}: first piece rose {}",
            moved(0)
        );
        assert!(
            moved(2).abs() < 0.1 * lift.y,
            "{basis:?}: last piece moved {}",
            moved(2)
        );
        if basis == Basis::Lattice {
            // Local support: the last piece's cells share no handle with the
            // first's, so it stays exactly at rest.
            for &v in &pieces[2].vertices {
                assert!(pose[v as usize].distance(mesh.vertices()[v as usize]) < 1e-12);
            }
        }
        // The moved piece keeps its shape: little distortion.
        let first: Vec<measure::Distortion> = measure::triangle_distortions(&mesh, &pose)
            .unwrap()
            .into_iter()
            .enumerate()
            .filter(|(t, _)| pieces[0].triangles.contains(&(*t as u32)))
            .map(|(_, d)| d)
            .collect();
        let d = measure::mean(&first);
        assert!(d.angular < 0.05 && d.area < 0.1, "{basis:?}: {d:?}");
    }
}

#[test]
fn painted_rigidity_stiffens_its_region() {
    let plain = jittered(12, 3);
    // Paint the left third stiff.
    let painted_triangles: Vec<usize> = plain
        .triangles()
        .iter()
        .enumerate()
        .filter(|(_, t)| t.iter().all(|&v| plain.vertices()[v as usize].x <= 4.0))
        .map(|(i, _)| i)
        .collect();
    let mut weights = vec![1.0; plain.triangles().len()];
    for &t in &painted_triangles {
        weights[t] = 1e4;
    }
    let painted = Mesh::new(
        "painted",
        plain.vertices().to_vec(),
        plain.triangles().to_vec(),
        None,
        Some(weights.clone()),
    )
    .unwrap();
    // Squash the bar lengthwise: somebody has to give.
    let anchors = [
        Anchor::Vertex(0),
        Anchor::Vertex(12),
        Anchor::Vertex(39),
        Anchor::Vertex(51),
    ];
    let targets: Vec<DVec2> = anchors
        .iter()
        .map(|a| {
            let p = rest_point(&plain, a);
            DVec2::new(6.0 + (p.x - 6.0) * 0.7, p.y)
        })
        .collect();
    let solve = |ffd: &mut LpFfd| {
        ffd.compile(&anchors, &[]).unwrap();
        let mut pose = Vec::new();
        for _ in 0..20 {
            pose = ffd.update(&targets, &[]).unwrap().to_vec();
        }
        pose
    };
    for basis in BASES {
        let soft_pose = solve(&mut rig(&plain, 8, basis, LpParams::default()));
        let stiff_pose = solve(&mut rig(&painted, 8, basis, LpParams::default()));
        let region = |pose: &[DVec2]| {
            let all = measure::triangle_distortions(&plain, pose).unwrap();
            let chosen: Vec<_> = painted_triangles.iter().map(|&t| all[t]).collect();
            measure::mean(&chosen)
        };
        let (soft, stiff) = (region(&soft_pose), region(&stiff_pose));
        assert!(
            stiff.area < 0.5 * soft.area,
            "{basis:?}: painted area distortion {} vs unpainted {}",
            stiff.area,
            soft.area
        );
        // Live repainting gives what registering the painted mesh gives.
        let mut live = rig(&plain, 8, basis, LpParams::default());
        live.set_weights(&weights).unwrap();
        let live_pose = solve(&mut live);
        assert!(max_distance(&live_pose, &stiff_pose) < 1e-9 * plain.size());
        // And repainting mid-drag keeps the handles and warm start.
        let mut switched = rig(&plain, 8, basis, LpParams::default());
        solve(&mut switched);
        switched.set_weights(&weights).unwrap();
        let mut pose = Vec::new();
        for _ in 0..60 {
            pose = switched.update(&targets, &[]).unwrap().to_vec();
        }
        assert!(region(&pose).area < 0.5 * soft.area, "{basis:?}");
    }
}

#[test]
fn inverse_ffd_fits_within_the_regulariser_bound() {
    // With P = G the fit costs λ_gr Σ|G − P⁰|², so at the optimum
    // λ_mp Σ|W P' − vᵢ|² ≤ λ_gr Σ|G − P⁰|².
    let mesh = jittered(10, 3);
    let params = LpParams::default();
    for basis in BASES {
        let ffd = rig(&mesh, 6, basis, params);
        let grid: Vec<DVec2> = ffd
            .rest_grid()
            .iter()
            .enumerate()
            .map(|(i, &p)| p + DVec2::new((i as f64 * 0.7).sin(), (i as f64 * 1.3).cos()) * 0.5)
            .collect();
        let vertices = ffd.deform_with_grid(&grid).unwrap();
        let fitted = ffd.inverse_ffd(&vertices).unwrap();
        let refit = ffd.deform_with_grid(&fitted).unwrap();
        let residual: f64 = refit
            .iter()
            .zip(&vertices)
            .map(|(a, b)| a.distance_squared(*b))
            .sum();
        let bound: f64 = params.regular
            * grid
                .iter()
                .zip(ffd.rest_grid())
                .map(|(a, b)| a.distance_squared(*b))
                .sum::<f64>();
        assert!(
            params.vertex * residual <= bound * (1.0 + 1e-9),
            "{basis:?}"
        );
        // Not trivially: the rest grid would miss by far more.
        let at_rest: f64 = mesh
            .vertices()
            .iter()
            .zip(&vertices)
            .map(|(a, b)| a.distance_squared(*b))
            .sum();
        assert!(residual < 1e-3 * at_rest, "{basis:?}");
    }
}

#[test]
fn updates_do_not_allocate() {
    let mesh = islands(3);
    let pieces = mesh.pieces();
    for basis in BASES {
        for locality in [1.0, 0.0] {
            let params = LpParams {
                locality,
                ..LpParams::default()
            };
            let mut ffd = rig(&mesh, 8, basis, params);
            let anchors = [
                Anchor::Vertex(pieces[0].vertices[0]),
                Anchor::Point {
                    triangle: pieces[1].triangles[3],
                    bary: [0.2, 0.3, 0.5],
                },
            ];
            let grid_handles = [5, 40];
            ffd.compile(&anchors, &grid_handles).unwrap();
            let rest_targets: Vec<DVec2> = anchors.iter().map(|a| rest_point(&mesh, a)).collect();
            let rest_grid: Vec<DVec2> = grid_handles.iter().map(|&g| ffd.rest_grid()[g]).collect();
            let mut targets = rest_targets.clone();
            let mut grid_targets = rest_grid.clone();
            alloc::start();
            for frame in 0..30 {
                let wobble = DVec2::new((frame as f64 * 0.3).sin(), (frame as f64 * 0.2).cos());
                for (t, r) in targets.iter_mut().zip(&rest_targets) {
                    *t = *r + wobble;
                }
                for (t, r) in grid_targets.iter_mut().zip(&rest_grid) {
                    *t = *r - wobble * 0.5;
                }
                ffd.update(&targets, &grid_targets).unwrap();
                let _ = ffd.grid();
            }
            let count = alloc::stop();
            assert_eq!(count, 0, "{basis:?}, λ_ml = {locality}: update allocated");
            // The counter works: a compile does allocate.
            alloc::start();
            ffd.compile(&anchors[..1], &[]).unwrap();
            assert!(alloc::stop() > 0);
        }
    }
}

#[test]
fn bad_grids_are_rejected() {
    let mesh = jittered(6, 3);
    let params = LpParams::default();
    let good = GridSpec::around(&mesh, 5, 5, Basis::Bernstein);
    let with = |f: &dyn Fn(&mut GridSpec)| {
        let mut spec = good;
        f(&mut spec);
        LpFfd::register(&mesh, spec, params).err()
    };
    assert!(matches!(
        with(&|s| s.columns = 1),
        Some(FfdError::GridSize { columns: 1, .. })
    ));
    assert!(matches!(
        with(&|s| s.rows = 0),
        Some(FfdError::GridSize { rows: 0, .. })
    ));
    assert!(matches!(
        with(&|s| {
            s.columns = 100;
            s.rows = 100
        }),
        Some(FfdError::GridTooLarge { count: 10000, .. })
    ));
    assert!(matches!(
        with(&|s| s.max.x = s.min.x),
        Some(FfdError::GridBox { .. })
    ));
    assert!(matches!(
        with(&|s| s.min.y = f64::NAN),
        Some(FfdError::GridBox { .. })
    ));
    // A box that misses part of the mesh.
    match with(&|s| s.max.x = 3.0) {
        Some(FfdError::VertexOutsideGrid { vertex, at, .. }) => {
            assert_eq!(mesh.vertices()[vertex], at);
            assert!(at.x > 3.0);
        }
        other => panic!("expected VertexOutsideGrid, got {other:?}"),
    }
    // The box may touch the mesh exactly.
    let tight = GridSpec {
        min: DVec2::ZERO,
        max: DVec2::new(6.0, 3.0),
        ..good
    };
    assert!(LpFfd::register(&mesh, tight, params).is_ok());
}

#[test]
fn bad_parameters_are_rejected() {
    let mesh = jittered(6, 3);
    let spec = GridSpec::around(&mesh, 4, 4, Basis::Lattice);
    let check = |params: LpParams, name: &str| match LpFfd::register(&mesh, spec, params) {
        Err(FfdError::Param { name: n, .. }) => assert_eq!(n, name),
        other => panic!("{name}: expected Param, got {other:?}"),
    };
    let d = LpParams::default();
    check(
        LpParams {
            locality: -1.0,
            ..d
        },
        "locality",
    );
    check(
        LpParams {
            vertex: f64::NAN,
            ..d
        },
        "vertex",
    );
    check(LpParams { grid: 0.0, ..d }, "grid");
    check(LpParams { regular: 0.0, ..d }, "regular");
    check(
        LpParams {
            regular: f64::INFINITY,
            ..d
        },
        "regular",
    );
    assert!(matches!(
        LpFfd::register(&mesh, spec, LpParams { iterations: 0, ..d }),
        Err(FfdError::Iterations)
    ));
}

#[test]
fn bad_handles_and_targets_are_rejected() {
    let mesh = jittered(6, 3);
    let mut ffd = rig(&mesh, 4, Basis::Bernstein, LpParams::default());
    let n = mesh.vertices().len() as u32;
    let t = mesh.triangles().len() as u32;
    assert!(matches!(
        ffd.compile(&[Anchor::Vertex(0), Anchor::Vertex(n)], &[]),
        Err(FfdError::VertexOutOfRange { handle: 1, .. })
    ));
    assert!(matches!(
        ffd.compile(
            &[Anchor::Point {
                triangle: t,
                bary: [1.0, 0.0, 0.0]
            }],
            &[]
        ),
        Err(FfdError::TriangleOutOfRange { handle: 0, .. })
    ));
    for bary in [[0.5, 0.6, 0.0], [-0.5, 1.0, 0.5], [f64::NAN, 0.5, 0.5]] {
        assert!(matches!(
            ffd.compile(&[Anchor::Point { triangle: 0, bary }], &[]),
            Err(FfdError::BadBarycentric { handle: 0, .. })
        ));
    }
    assert!(matches!(
        ffd.compile(&[], &[3, 16]),
        Err(FfdError::GridHandleOutOfRange {
            handle: 1,
            index: 16,
            count: 16
        })
    ));
    // A failed compile keeps the previous handle set.
    ffd.compile(&[Anchor::Vertex(2)], &[5]).unwrap();
    assert!(ffd.compile(&[Anchor::Vertex(n)], &[]).is_err());
    let p = DVec2::ONE;
    assert!(ffd.update(&[p], &[p]).is_ok());
    assert!(matches!(
        ffd.update(&[p, p], &[p]),
        Err(FfdError::Count {
            expected: 1,
            got: 2,
            ..
        })
    ));
    assert!(matches!(
        ffd.update(&[p], &[]),
        Err(FfdError::Count {
            expected: 1,
            got: 0,
            ..
        })
    ));
    assert!(matches!(
        ffd.update(&[DVec2::new(f64::NAN, 0.0)], &[p]),
        Err(FfdError::NotFinite { index: 0, .. })
    ));
    assert!(matches!(
        ffd.update(&[p], &[DVec2::splat(1e300)]),
        Err(FfdError::NotFinite { index: 0, .. })
    ));
    assert!(matches!(
        ffd.deform_with_grid(&[p; 3]),
        Err(FfdError::Count { expected: 16, .. })
    ));
    assert!(matches!(
        ffd.inverse_ffd(&[p; 3]),
        Err(FfdError::Count { .. })
    ));
    assert!(matches!(
        ffd.set_weights(&[1.0; 3]),
        Err(FfdError::Count { .. })
    ));
    let mut weights = vec![1.0; t as usize];
    weights[4] = 0.0;
    assert!(matches!(
        ffd.set_weights(&weights),
        Err(FfdError::BadWeight { triangle: 4, .. })
    ));
    weights[4] = f64::NAN;
    assert!(matches!(
        ffd.set_weights(&weights),
        Err(FfdError::BadWeight { triangle: 4, .. })
    ));
}
