#!/usr/bin/env python3
"""Times puppetry's ARAP update against libigl's ARAP on the same problem.

Same mesh (the bundled gingerbread puppet meshed by `puppetry mesh`), same
handle vertices, same per-frame handle targets, same run. See README.md in
this folder for what is compared and how to read the table.

    python3 benches/peers/libigl_arap.py [--sizes 1000,10000] [--handles 2,10]

Needs Python 3.9+ with venv and network access to PyPI on the first run: the
script makes its own virtual environment (default /tmp/puppetry-peers-venv)
and installs libigl and numpy there. Not part of CI.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ["libigl", "numpy"]


def ensure_venv(venv):
    """Re-runs this script inside a virtual environment holding libigl."""
    if os.environ.get("PUPPETRY_PEERS_IN_VENV") == "1":
        return
    python = venv / "bin" / "python"
    if not python.exists():
        print(f"creating {venv}", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    probe = subprocess.run([str(python), "-c", "import igl, numpy"], capture_output=True)
    if probe.returncode != 0:
        print(f"installing {' '.join(PACKAGES)} into {venv}", file=sys.stderr)
        subprocess.run([str(python), "-m", "pip", "install", "-q", *PACKAGES], check=True)
    env = dict(os.environ, PUPPETRY_PEERS_IN_VENV="1")
    os.execve(str(python), [str(python), __file__, *sys.argv[1:]], env)


def find_puppetry(given):
    if given:
        return Path(given)
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    binary = target / "release" / "puppetry"
    if not binary.exists():
        print("building puppetry (release)", file=sys.stderr)
        subprocess.run(["cargo", "build", "--release", "-p", "puppetry"], cwd=REPO, check=True)
    return binary


# --- the problem -----------------------------------------------------------


def farthest_vertices(V, count):
    """`count` handle vertices spread over the mesh: the vertex farthest from
    the centroid, then each next one farthest from those already chosen."""
    import numpy as np

    first = int(np.argmax(((V - V.mean(axis=0)) ** 2).sum(axis=1)))
    chosen = [first]
    dist = ((V - V[first]) ** 2).sum(axis=1)
    while len(chosen) < count:
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, ((V - V[nxt]) ** 2).sum(axis=1))
    return chosen


def animate(rest, size, frames, amplitude):
    """The handle motion of `puppetry bench`: each handle wanders on its own
    circle of radius amplitude·size (size: the bounding-box diagonal)."""
    import numpy as np

    out = np.empty((frames, len(rest), 2))
    for f in range(frames):
        t = f * 0.05
        for h, r in enumerate(rest):
            phase = t + h * 1.3
            out[f, h] = r + amplitude * size * np.array([np.cos(phase), np.sin(phase)])
    return out


# --- the energy both results are measured with ------------------------------


class Energy:
    """libigl's per-element 2D ARAP energy, up to a constant factor:
    E(U) = Σ_t A_t ‖J_t − R_t‖²_F / Σ_t A_t, J_t the affine map of rest
    triangle t onto its deformed triangle, R_t the rotation nearest J_t.
    (Σ over a triangle's edges of ½cot θ·‖e' − R e‖², libigl's element form,
    is 2A‖J − R‖²_F for the same R, so the minimizers and ratios agree.)"""

    def __init__(self, V, F):
        import numpy as np

        self.F = F
        e1 = V[F[:, 1]] - V[F[:, 0]]
        e2 = V[F[:, 2]] - V[F[:, 0]]
        rest = np.stack([e1, e2], axis=2)  # (t, 2, 2): columns are edges
        self.rest_inv = np.linalg.inv(rest)
        self.area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        self.total = self.area.sum()

    def __call__(self, U):
        import numpy as np

        F = self.F
        d = np.stack([U[F[:, 1]] - U[F[:, 0]], U[F[:, 2]] - U[F[:, 0]]], axis=2)
        J = d @ self.rest_inv
        a, b, c, e = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
        # min over rotations R of ‖J − R‖² = ‖J‖² + 2 − 2·max tr(RᵀJ).
        best = np.sqrt((a + e) ** 2 + (c - b) ** 2)
        per = a * a + b * b + c * c + e * e + 2.0 - 2.0 * best
        return float((self.area * np.maximum(per, 0.0)).sum() / self.total)


# --- the two sides -----------------------------------------------------------


def run_ours(puppetry, case_path, poses_path, n, frames):
    import numpy as np

    out = subprocess.run(
        [str(puppetry), "bench-case", str(case_path), "--poses", str(poses_path)],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    times = json.loads(out)
    poses = np.fromfile(poses_path, dtype="<f8").reshape(frames, n, 2)
    return times, poses


def libigl_data(V, F, handles, max_iter):
    import igl
    import numpy as np

    data = igl.ARAPData()
    data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
    data.max_iter = max_iter
    igl.arap_precomputation(V, F, 2, np.asarray(handles, dtype=np.int32), data)
    return data


def solve(data, bc, U, iterations):
    import igl

    data.max_iter = iterations
    return igl.arap_solve(bc, data, U)


def iterations_to(data, energy, bc, start, goal, cap):
    """Local–global iterations from `start` until the energy is at most
    `goal` (or stops falling, or `cap`). Returns (iterations, pose, reached).
    The start itself does not count: it does not hold the handles yet."""
    U = start
    previous = float("inf")
    for k in range(1, cap + 1):
        U = solve(data, bc, U, 1)
        e = energy(U)
        if e <= goal:
            return k, U, True
        if e >= previous * (1.0 - 1e-9):
            return k, U, False
        previous = e
    return cap, U, False


def time_sequence(data, bcs, starts, iterations):
    """Per-frame wall and process CPU times (µs) of `arap_solve` from the
    given starts."""
    import igl

    wall, cpu = [], []
    for bc, U, k in zip(bcs, starts, iterations):
        data.max_iter = k
        c = time.process_time()
        t = time.perf_counter()
        igl.arap_solve(bc, data, U)
        wall.append((time.perf_counter() - t) * 1e6)
        cpu.append((time.process_time() - c) * 1e6)
    return wall, cpu


def igl_version():
    from importlib.metadata import version

    return version("libigl")


def median(xs):
    return statistics.median(xs)


def run_case(args, puppetry, work, mesh_path, size_label, handle_count):
    import igl
    import numpy as np

    mesh = json.loads(mesh_path.read_text())
    V = np.ascontiguousarray(np.array(mesh["vertices"], dtype=np.float64))
    F = np.ascontiguousarray(np.array(mesh["triangles"], dtype=np.int64))
    n = len(V)
    handles = farthest_vertices(V, handle_count)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    targets = animate(V[handles], diag, args.frames, args.amplitude)
    case_path = work / f"case-{size_label}-{handle_count}.json"
    case_path.write_text(
        json.dumps(
            {
                "mesh": mesh_path.name,
                "handles": handles,
                "frames": targets.tolist(),
            }
        )
    )
    poses_path = work / f"poses-{size_label}-{handle_count}.bin"
    energy = Energy(V, F)
    bcs = [np.ascontiguousarray(t) for t in targets]

    t = time.perf_counter()
    data = libigl_data(V, F, handles, 1)
    igl_pre_ms = (time.perf_counter() - t) * 1e3

    # Untimed pass: our poses and energies, then libigl's sequences.
    times, ours = run_ours(puppetry, case_path, poses_path, n, args.frames)
    e_ours = [energy(U) for U in ours]
    miss = float(np.abs(ours[:, handles] - targets).max())
    if miss > 1e-6 * diag:
        sys.exit(f"puppetry's handles miss their targets by {miss}")
    # (a) one iteration a frame, warm-started from its own previous frame.
    one_starts, one_poses = [], []
    U = V.copy()
    for bc in bcs:
        one_starts.append(U)
        U = solve(data, bc, U, 1)
        one_poses.append(U)
    e_one = [energy(U) for U in one_poses]
    miss = max(float(np.abs(U[handles] - t).max()) for U, t in zip(one_poses, targets))
    if miss > 1e-6 * diag:
        sys.exit(f"libigl's handles miss their targets by {miss}")
    # (b) iterations until our energy, warm-started from its own previous frame.
    warm_starts, warm_k, warm_reached, warm_energy = [], [], 0, []
    U = V.copy()
    for bc, goal in zip(bcs, e_ours):
        warm_starts.append(U)
        k, U, ok = iterations_to(data, energy, bc, U, goal, args.cap)
        warm_k.append(k)
        warm_reached += ok
        warm_energy.append(energy(U))
    # (c) the same from the rest pose every frame (history-free, like ours).
    cold_k, cold_reached = [], 0
    for bc, goal in zip(bcs, e_ours):
        k, _, ok = iterations_to(data, energy, bc, V, goal, args.cap)
        cold_k.append(k)
        cold_reached += ok
    # Converged libigl energy from a warm start: what ARAP's minimum is.
    e_min = [energy(solve(data, bc, U, args.cap)) for bc, U in zip(bcs, warm_starts)]

    # The call's own cost: no iteration, just argument and result copies.
    overhead = median(time_sequence(data, bcs, one_starts, [0] * len(bcs))[0])

    # Timed rounds, alternating the two sides. A frame's time is its fastest
    # round (on a shared machine a call is sometimes preempted for a whole
    # scheduler slice, and longer calls more often), then the median frame.
    # Process CPU times are kept too: preemption does not count in them.
    sides = ("ours", "one", "warm", "cold")
    rounds = {k: [] for k in sides}
    cpu_rounds = {k: [] for k in sides}
    for _ in range(args.rounds):
        times, _ = run_ours(puppetry, case_path, poses_path, n, args.frames)
        measured = {
            "ours": (times["update_us"], times["update_cpu_us"]),
            "one": time_sequence(data, bcs, one_starts, [1] * len(bcs)),
            "warm": time_sequence(data, bcs, warm_starts, warm_k),
            "cold": time_sequence(data, bcs, [V] * len(bcs), cold_k),
        }
        for k, (wall, cpu) in measured.items():
            rounds[k].append(wall)
            cpu_rounds[k].append(cpu)
    t = {k: median([min(f) for f in zip(*v)]) for k, v in rounds.items()}
    c = {k: median([min(f) for f in zip(*v)]) for k, v in cpu_rounds.items()}
    round_medians = {k: [round(median(r), 1) for r in v] for k, v in rounds.items()}
    return {
        "mesh": f"gingerbread@{size_label}",
        "vertices": n,
        "triangles": len(F),
        "handles": handle_count,
        "frames": args.frames,
        "ours_register_ms": times["register_ms"],
        "libigl_precompute_ms": igl_pre_ms,
        "ours_us": t["ours"],
        "libigl_one_iter_us": t["one"],
        "libigl_warm_us": t["warm"],
        "libigl_cold_us": t["cold"],
        "libigl_call_overhead_us": overhead,
        "ours_cpu_us": c["ours"],
        "libigl_one_iter_cpu_us": c["one"],
        "libigl_warm_cpu_us": c["warm"],
        "libigl_cold_cpu_us": c["cold"],
        "warm_iterations_p50": median(warm_k),
        "warm_iterations_max": max(warm_k),
        "warm_reached": warm_reached,
        "cold_iterations_p50": median(cold_k),
        "cold_reached": cold_reached,
        "energy_ours_p50": median(e_ours),
        "energy_one_iter_p50": median(e_one),
        "energy_warm_p50": median(warm_energy),
        "energy_min_p50": median(e_min),
        "round_medians_us": round_medians,
        "igl_version": igl_version(),
    }


def print_table(results):
    for title, suffix in (("wall", "_us"), ("process CPU", "_cpu_us")):
        print()
        print(f"{title} time per frame, µs (median frame of its fastest round); × = libigl / ours")
        print(
            f"{'mesh':<18} {'verts':>6} {'hdl':>3} {'ours':>8} "
            f"{'1 iter':>8} {'×':>6} {'warm→E':>8} {'iters':>5} {'×':>6} "
            f"{'cold→E':>8} {'iters':>5} {'×':>6}"
        )
        for r in results:
            o = r["ours" + suffix]
            one = r["libigl_one_iter" + suffix]
            warm = r["libigl_warm" + suffix]
            cold = r["libigl_cold" + suffix]
            print(
                f"{r['mesh']:<18} {r['vertices']:>6} {r['handles']:>3} {o:>8.1f} "
                f"{one:>8.1f} {one / o:>6.2f} {warm:>8.1f} {r['warm_iterations_p50']:>5g} "
                f"{warm / o:>6.2f} {cold:>8.1f} {r['cold_iterations_p50']:>5g} {cold / o:>6.2f}"
            )
    print()
    print("libigl's arap_solve call alone (max_iter = 0), µs: "
          + ", ".join(f"{r['mesh']}/{r['handles']}: {r['libigl_call_overhead_us']:.1f}"
                      for r in results))
    print()
    print("energy Σ A‖J − R‖² / Σ A, median frame; E min: libigl converged")
    print(
        f"{'mesh':<18} {'hdl':>3} {'E ours':>10} {'E 1 iter':>10} "
        f"{'E warm→E':>10} {'E min':>10} {'warm reached':>13} {'cold reached':>13}"
    )
    for r in results:
        print(
            f"{r['mesh']:<18} {r['handles']:>3} {r['energy_ours_p50']:>10.3e} "
            f"{r['energy_one_iter_p50']:>10.3e} {r['energy_warm_p50']:>10.3e} "
            f"{r['energy_min_p50']:>10.3e} "
            f"{r['warm_reached']:>6}/{r['frames']:<6} {r['cold_reached']:>6}/{r['frames']:<6}"
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1000,10000", help="vertex counts to mesh the puppet at")
    parser.add_argument("--handles", default="2,10", help="handle counts")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds, alternating sides")
    parser.add_argument("--amplitude", type=float, default=0.03,
                        help="handle circle radius, times the mesh diagonal")
    parser.add_argument("--cap", type=int, default=200, help="most libigl iterations per frame")
    parser.add_argument("--puppetry", help="the puppetry binary (default: build it)")
    parser.add_argument("--work", default="/tmp/puppetry-peers", help="meshes, cases, poses")
    parser.add_argument("--venv", default="/tmp/puppetry-peers-venv")
    parser.add_argument("--json", action="store_true", help="also print one JSON line a case")
    args = parser.parse_args()
    ensure_venv(Path(args.venv))

    import igl  # noqa: F401  (fail early with a clear import error)

    puppetry = find_puppetry(args.puppetry)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()
    print(f"puppetry: {puppetry}; libigl {igl_version()}; "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    results = []
    for size in [int(s) for s in args.sizes.split(",")]:
        mesh_path = work / f"gingerbread@{size}.mesh.json"
        subprocess.run(
            [str(puppetry), "mesh", str(REPO / "assets/gingerbread/gingerbread.png"),
             "--vertices", str(size), "-o", str(mesh_path)],
            check=True,
        )
        for h in [int(x) for x in args.handles.split(",")]:
            r = run_case(args, puppetry, work, mesh_path, size, h)
            results.append(r)
            if args.json:
                print(json.dumps(r))
            print(f"done: {r['mesh']} {h} handles", file=sys.stderr)
    print_table(results)
    load = os.getloadavg()
    print(f"load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


if __name__ == "__main__":
    main()
