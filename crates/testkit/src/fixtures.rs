//! Shared test fixtures: small meshes built in code and an independent dense
//! least-squares reference for the two-step ARAP energies.

use faer::Mat;
use faer::linalg::solvers::{Solve, SolveLstsq};
use glam::DVec2;
use puppetry_deform::Anchor;
use puppetry_mesh::Mesh;

/// A `cols`×`rows` grid of squares over [0, width]×[0, height], each square
/// split into two counter-clockwise triangles, offset by `origin`.
pub fn grid(
    cols: usize,
    rows: usize,
    width: f64,
    height: f64,
    origin: DVec2,
) -> (Vec<DVec2>, Vec<[u32; 3]>) {
    let mut vertices = Vec::new();
    for r in 0..=rows {
        for c in 0..=cols {
            vertices.push(
                origin
                    + DVec2::new(
                        width * c as f64 / cols as f64,
                        height * r as f64 / rows as f64,
                    ),
            );
        }
    }
    let at = |c: usize, r: usize| (r * (cols + 1) + c) as u32;
    let mut triangles = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            // Alternate the diagonal so the grid has no preferred direction.
            if (r + c) % 2 == 0 {
                triangles.push([at(c, r), at(c + 1, r), at(c + 1, r + 1)]);
                triangles.push([at(c, r), at(c + 1, r + 1), at(c, r + 1)]);
            } else {
                triangles.push([at(c, r), at(c + 1, r), at(c, r + 1)]);
                triangles.push([at(c + 1, r), at(c + 1, r + 1), at(c, r + 1)]);
            }
        }
    }
    (vertices, triangles)
}

/// A validated [`grid`] mesh from the origin: a `width` × `height`
/// rectangle of `cols` × `rows` squares, a bar to bend.
pub fn bar(cols: usize, rows: usize, width: f64, height: f64) -> Mesh {
    let (v, t) = grid(cols, rows, width, height, DVec2::ZERO);
    Mesh::new("bar", v, t, None, None).unwrap()
}

/// A mesh of several grids placed side by side (separate pieces).
pub fn islands(count: usize) -> Mesh {
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for i in 0..count {
        let (v, t) = grid(4, 2, 4.0, 2.0, DVec2::new(10.0 * i as f64, 0.0));
        let base = vertices.len() as u32;
        vertices.extend(v);
        triangles.extend(t.into_iter().map(|tri| tri.map(|x| x + base)));
    }
    Mesh::new("islands", vertices, triangles, None, None).unwrap()
}

/// A slightly irregular mesh: the grid with interior vertices jittered
/// deterministically, so tests do not only see right triangles.
pub fn jittered(cols: usize, rows: usize) -> Mesh {
    let (mut v, t) = grid(cols, rows, cols as f64, rows as f64, DVec2::ZERO);
    for r in 1..rows {
        for c in 1..cols {
            let i = r * (cols + 1) + c;
            let phase = (i as f64 * 12.9898).sin() * 43758.5453;
            let jitter = DVec2::new(phase.fract() - 0.5, (phase * 1.7).fract() - 0.5) * 0.3;
            v[i] += jitter;
        }
    }
    Mesh::new("jittered", v, t, None, None).unwrap()
}

/// The constraint rows of the anchors: (vertex, weight) triples.
fn anchor_rows(mesh: &Mesh, anchors: &[Anchor]) -> Vec<Vec<(usize, f64)>> {
    anchors
        .iter()
        .map(|a| match *a {
            Anchor::Vertex(v) => vec![(v as usize, 1.0)],
            Anchor::Point { triangle, bary } => {
                let t = mesh.triangles()[triangle as usize];
                (0..3).map(|k| (t[k] as usize, bary[k])).collect()
            }
        })
        .collect()
}

/// Minimises `‖A x − b‖²` subject to `C x = d` densely, through the KKT
/// system, or by eliminating fixed unknowns when every constraint is a single
/// unknown (the paper's own formulation for vertex handles).
fn constrained_least_squares(
    a: &Mat<f64>,
    b: &[f64],
    c: &[Vec<(usize, f64)>],
    d: &[f64],
) -> Vec<f64> {
    let n = a.ncols();
    let ata = a.transpose() * a;
    let atb: Vec<f64> = (0..n)
        .map(|j| (0..a.nrows()).map(|i| a[(i, j)] * b[i]).sum())
        .collect();
    if c.iter().all(|row| row.len() == 1 && row[0].1 == 1.0) {
        // Vertex handles: eliminate the fixed unknowns and solve the
        // remaining least-squares problem by QR (not the normal equations,
        // which square the condition number of thin triangles).
        let mut fixed = vec![None; n];
        for (row, &value) in c.iter().zip(d) {
            fixed[row[0].0] = Some(value);
        }
        let free: Vec<usize> = (0..n).filter(|&i| fixed[i].is_none()).collect();
        let a_free = Mat::<f64>::from_fn(a.nrows(), free.len(), |i, j| a[(i, free[j])]);
        let rhs = Mat::<f64>::from_fn(a.nrows(), 1, |i, _| {
            let mut r = b[i];
            for (j, f) in fixed.iter().enumerate() {
                if let Some(value) = f {
                    r -= a[(i, j)] * value;
                }
            }
            r
        });
        let u = a_free.col_piv_qr().solve_lstsq(&rhs);
        let mut x: Vec<f64> = fixed.iter().map(|f| f.unwrap_or(0.0)).collect();
        for (i, &f) in free.iter().enumerate() {
            x[f] = u[(i, 0)];
        }
        return x;
    }
    let m = c.len();
    let kkt = Mat::<f64>::from_fn(n + m, n + m, |i, j| {
        if i < n && j < n {
            ata[(i, j)]
        } else if i < n {
            c[j - n].iter().filter(|e| e.0 == i).map(|e| e.1).sum()
        } else if j < n {
            c[i - n].iter().filter(|e| e.0 == j).map(|e| e.1).sum()
        } else {
            0.0
        }
    });
    let rhs = Mat::<f64>::from_fn(n + m, 1, |i, _| if i < n { atb[i] } else { d[i - n] });
    let x = kkt.full_piv_lu().solve(&rhs);
    (0..n).map(|i| x[(i, 0)]).collect()
}

/// The dense reference: step 1 over all 2n coordinates, then the paper's
/// own step 2a (similarity fit of each triangle, rescaled), then step 2b.
/// Returns (step-1 pose, final pose).
pub fn dense_reference(
    mesh: &Mesh,
    anchors: &[Anchor],
    targets: &[DVec2],
) -> (Vec<DVec2>, Vec<DVec2>) {
    let n = mesh.vertices().len();
    let rest = mesh.vertices();
    let rot = |d: DVec2| DVec2::new(d.y, -d.x);
    // Step 1 rows: √w (v_c − v_a − x(v_b − v_a) − yR(v_b − v_a)), x and y.
    let tri_count = mesh.triangles().len();
    let mut a1 = Mat::<f64>::zeros(6 * tri_count, 2 * n);
    for (t, tri) in mesh.triangles().iter().enumerate() {
        let sw = mesh.weights()[t].sqrt();
        for k in 0..3 {
            let (a, b, c) = (
                tri[(k + 1) % 3] as usize,
                tri[(k + 2) % 3] as usize,
                tri[k] as usize,
            );
            let d = rest[b] - rest[a];
            let x = (rest[c] - rest[a]).dot(d) / d.length_squared();
            let y = (rest[c] - rest[a]).dot(rot(d)) / d.length_squared();
            // e = v_c − (1−x) v_a − x v_b − y R (v_b − v_a); R(p) = (p.y, −p.x)
            let row = 6 * t + 2 * k;
            a1[(row, 2 * c)] += sw;
            a1[(row + 1, 2 * c + 1)] += sw;
            a1[(row, 2 * a)] -= sw * (1.0 - x);
            a1[(row + 1, 2 * a + 1)] -= sw * (1.0 - x);
            a1[(row, 2 * b)] -= sw * x;
            a1[(row + 1, 2 * b + 1)] -= sw * x;
            // −y R(v_b − v_a): x-row gets −y (v_by − v_ay), y-row gets +y (v_bx − v_ax)
            a1[(row, 2 * b + 1)] -= sw * y;
            a1[(row, 2 * a + 1)] += sw * y;
            a1[(row + 1, 2 * b)] += sw * y;
            a1[(row + 1, 2 * a)] -= sw * y;
        }
    }
    let rows = anchor_rows(mesh, anchors);
    let mut c1 = Vec::new();
    let mut d1 = Vec::new();
    for (row, t) in rows.iter().zip(targets) {
        c1.push(row.iter().map(|&(v, w)| (2 * v, w)).collect());
        d1.push(t.x);
        c1.push(row.iter().map(|&(v, w)| (2 * v + 1, w)).collect());
        d1.push(t.y);
    }
    let zero = vec![0.0; a1.nrows()];
    let v1 = constrained_least_squares(&a1, &zero, &c1, &d1);
    let step1: Vec<DVec2> = (0..n)
        .map(|i| DVec2::new(v1[2 * i], v1[2 * i + 1]))
        .collect();

    // Step 2a as in the paper: fit w0, w1 (w2 follows from the rest local
    // coordinates of corner 2) to the step-1 triangle, then rescale.
    let mut fitted = Vec::with_capacity(tri_count);
    for tri in mesh.triangles() {
        let [p0, p1, p2] = tri.map(|i| rest[i as usize]);
        let d = p1 - p0;
        let x = (p2 - p0).dot(d) / d.length_squared();
        let y = (p2 - p0).dot(rot(d)) / d.length_squared();
        // w2 = w0 + x(w1 − w0) + yR(w1 − w0): linear in (w0x, w0y, w1x, w1y).
        let mut a = Mat::<f64>::zeros(6, 4);
        let mut b = Mat::<f64>::zeros(6, 1);
        let s = tri.map(|i| step1[i as usize]);
        a[(0, 0)] = 1.0;
        a[(1, 1)] = 1.0;
        a[(2, 2)] = 1.0;
        a[(3, 3)] = 1.0;
        a[(4, 0)] = 1.0 - x;
        a[(4, 2)] = x;
        a[(4, 3)] = y;
        a[(4, 1)] = -y;
        a[(5, 1)] = 1.0 - x;
        a[(5, 3)] = x;
        a[(5, 2)] = -y;
        a[(5, 0)] = y;
        for (k, p) in s.iter().enumerate() {
            b[(2 * k, 0)] = p.x;
            b[(2 * k + 1, 0)] = p.y;
        }
        let ata = a.transpose() * &a;
        let atb = a.transpose() * &b;
        let w = ata.full_piv_lu().solve(&atb);
        let w0 = DVec2::new(w[(0, 0)], w[(1, 0)]);
        let w1 = DVec2::new(w[(2, 0)], w[(3, 0)]);
        let w2 = w0 + (w1 - w0) * x + rot(w1 - w0) * y;
        let scale = d.length() / (w1 - w0).length();
        let centre = (w0 + w1 + w2) / 3.0;
        fitted.push([w0, w1, w2].map(|p| centre + (p - centre) * scale));
    }
    // Step 2b: per axis, rows √w ((v_j − v_i) − (f_j − f_i)) over triangle edges.
    let mut a2 = Mat::<f64>::zeros(3 * tri_count, n);
    let mut bx = vec![0.0; 3 * tri_count];
    let mut by = vec![0.0; 3 * tri_count];
    for (t, tri) in mesh.triangles().iter().enumerate() {
        let sw = mesh.weights()[t].sqrt();
        for k in 0..3 {
            let (i, j) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
            let e = fitted[t][(k + 1) % 3] - fitted[t][k];
            a2[(3 * t + k, j)] += sw;
            a2[(3 * t + k, i)] -= sw;
            bx[3 * t + k] = sw * e.x;
            by[3 * t + k] = sw * e.y;
        }
    }
    let dx: Vec<f64> = targets.iter().map(|t| t.x).collect();
    let dy: Vec<f64> = targets.iter().map(|t| t.y).collect();
    let x = constrained_least_squares(&a2, &bx, &rows, &dx);
    let y = constrained_least_squares(&a2, &by, &rows, &dy);
    (step1, (0..n).map(|i| DVec2::new(x[i], y[i])).collect())
}

/// The largest distance between corresponding points of two poses: how
/// far apart two solutions are at their worst. Panics unless both have the
/// same length.
pub fn max_distance(a: &[DVec2], b: &[DVec2]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

/// The demo skeleton of `config/skeleton.toml` (15 bones, in the
/// coordinates `mesh_png` gives the demo picture), read from the checkout
/// so tests and the stage file never disagree.
pub fn gingerbread_skeleton() -> puppetry_deform::skeleton::Skeleton {
    let path = crate::root().join("config/skeleton.toml");
    let text = std::fs::read_to_string(&path).expect("config/skeleton.toml");
    let stage: toml::Value = toml::from_str(&text).expect("a TOML stage file");
    let skeleton = &stage["puppet"][0]["skeleton"];
    let pair = |v: &toml::Value| {
        let a = v.as_array().expect("a pair");
        let num = |x: &toml::Value| {
            x.as_float()
                .or(x.as_integer().map(|i| i as f64))
                .expect("a number")
        };
        (num(&a[0]), num(&a[1]))
    };
    let joints = skeleton["joints"]
        .as_array()
        .expect("joints")
        .iter()
        .map(|j| {
            let (x, y) = pair(j);
            DVec2::new(x, y)
        })
        .collect();
    let bones = skeleton["bones"]
        .as_array()
        .expect("bones")
        .iter()
        .map(|b| {
            let (p, c) = pair(b);
            [p as usize, c as usize]
        })
        .collect();
    puppetry_deform::skeleton::Skeleton::new(joints, bones).expect("the demo skeleton is valid")
}

/// Points along a circular arc of length 99 turning `angle` radians
/// (straight when 0), centred on the origin's x.
fn arc_point(angle: f64, s: f64) -> DVec2 {
    if angle == 0.0 {
        return DVec2::new(s - 49.5, 0.0);
    }
    let radius = 99.0 / angle;
    let a = s / radius - angle / 2.0;
    DVec2::new(radius * a.sin(), radius * (1.0 - a.cos()))
}

/// The curve bend of the scale-adjustment test and `docs/curve-bend.svg`: a
/// 100-point arc turning 2.5 rad, held at its ends and middle, bent the other
/// way onto an arc of the same length turning −1 rad. Rest, anchors,
/// targets.
pub fn curve_bend() -> (Vec<DVec2>, Vec<puppetry_deform::CurveAnchor>, Vec<DVec2>) {
    use puppetry_deform::CurveAnchor;
    let rest = (0..100).map(|i| arc_point(2.5, i as f64)).collect();
    let anchors = vec![
        CurveAnchor::Point(0),
        CurveAnchor::Along {
            segment: 49,
            t: 0.5,
        },
        CurveAnchor::Point(99),
    ];
    let targets = [0.0, 49.5, 99.0]
        .map(|s| arc_point(-1.0, s) + DVec2::new(0.0, 40.0))
        .to_vec();
    (rest, anchors, targets)
}
