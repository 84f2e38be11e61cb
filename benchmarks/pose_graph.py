"""Pose-graph optimisation: microlie.optim against GTSAM 4.3 Levenberg-Marquardt, interleaved.

Run (benchmark environment, one command)::

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/pose_graph.py [--repeat 5] [--graphs ...]

For each graph both solvers start from the same poses (the file's vertices; ais2klinik from
microlie's chordal initialisation, kitti_00 from the odometry chain) and hold pose 0 (GTSAM: a
prior with sigma 1e-6, excluded from the reported cost; microlie: pose 0 fixed). GTSAM runs
``LevenbergMarquardtOptimizer(graph, initial, LevenbergMarquardtParams()).optimize()`` with the
default parameters; only ``optimize()`` is timed (the optimizer is constructed outside the timed
region). microlie runs ``FactorGraph.optimize()`` (LM, the same lambda schedule and default
tolerances as GTSAM); neither its graph and pattern (``FactorGraph.problem()``) nor the linear
solver's symbolic analysis (once per problem and backend, ``Problem.analysed``; GTSAM's ordering
runs in its untimed constructor) is timed: both are printed, as "setup" and "analysis". Runs
alternate GTSAM, microlie-backend-1, microlie-backend-2, ... ``--repeat`` times after one
warm-up; the table gives medians, the ratio of medians, and the spread of the per-round ratios.
Every BLAS/LAPACK library is held to one thread (GTSAM's wheel is single-threaded).
Costs are GTSAM's ``0.5 sum r^T Omega r`` over the file's edges, both evaluated by microlie's
``PoseGraph.cost`` on the returned poses.

Backends: ``supernodal`` (our NumPy/LAPACK Cholesky) and ``scipy`` (SuperLU) are what
``pip install microlie`` has; ``pardiso`` needs ``microlie[mkl]``, ``qdldl`` ``microlie[sparse]``.
The summary table gives the ratio of ``linear_solver="auto"``'s pick, once with everything of this
environment installed and once restricted to the default install.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from microlie import SE2  # noqa: E402
from microlie.optim import available_solvers, from_pose_graph, make_solver  # noqa: E402
from microlie.optim.g2o import read_g2o  # noqa: E402
from microlie.optim.init import initialize  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {  # name: (file, start)
    "sphere2500": ("sphere2500.g2o", "file"),
    "parking-garage": ("parking-garage.g2o", "file"),
    "M3500": ("input_M3500_g2o.g2o", "file"),
    "ais2klinik": ("ais2klinik.g2o", "chordal"),
    "kitti_00": ("kitti_00.g2o", "odometry"),
}


def gtsam_problem(gtsam, path: Path, pg, X0):
    is3d = pg.group is not SE2
    graph, _ = gtsam.readG2o(str(path), is3d)
    init = gtsam.Values()
    p = np.asarray(X0.params)
    for k, key in enumerate(pg.ids.tolist()):
        if is3d:
            x, y, z, qx, qy, qz, qw = p[k]
            init.insert(key, gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz),
                                         np.array([x, y, z])))
        else:
            init.insert(key, gtsam.Pose2(p[k, 0], p[k, 1], np.arctan2(p[k, 3], p[k, 2])))
    k0 = int(pg.ids[0])
    if is3d:
        graph.add(gtsam.PriorFactorPose3(k0, init.atPose3(k0),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 1e-6))))
    else:
        graph.add(gtsam.PriorFactorPose2(k0, init.atPose2(k0),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-6))))
    return graph, init


def gtsam_poses(gtsam, pg, values):
    G = pg.group
    rows = []
    for key in pg.ids.tolist():
        if G is SE2:
            P = values.atPose2(key)
            rows.append([P.x(), P.y(), np.cos(P.theta()), np.sin(P.theta())])
        else:
            P = values.atPose3(key)
            q = P.rotation().toQuaternion()
            t = P.translation()
            rows.append([t[0], t[1], t[2], q.x(), q.y(), q.z(), q.w()])
    return G(np.array(rows), normalize=True)


def run_gtsam(gtsam, graph, init):
    opt = gtsam.LevenbergMarquardtOptimizer(graph, init, gtsam.LevenbergMarquardtParams())
    t0 = time.perf_counter()
    res = opt.optimize()
    return time.perf_counter() - t0, res, opt.iterations()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--graphs", nargs="*", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--backends", nargs="*", default=None,
                    help="microlie linear solvers (default: supernodal, pardiso, qdldl, scipy "
                         "where installed)")
    ap.add_argument("--out", default=None, help="also write the markdown table to this file")
    args = ap.parse_args(argv)
    import gtsam

    avail = available_solvers()
    backends = args.backends or [b for b in ("supernodal", "pardiso", "qdldl", "scipy")
                                 if b in avail]
    lines = []
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    head = (f"pose_graph.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
            f"repeat {args.repeat}, one BLAS thread; `uptime`: {load}")
    print(head)
    lines += [head, ""]
    cols = " | ".join(f"{b} ms (ratio, spread)" for b in backends)
    hdr = (f"| graph | start | GTSAM LM ms (it) | {cols} | GTSAM cost | "
           + " | ".join(f"{b} cost (it)" for b in backends) + " |")
    sep = "|" + "---|" * (5 + 2 * len(backends))
    print(hdr)
    print(sep)
    lines += [hdr, sep]
    breakdowns = []
    summary = []
    for name in args.graphs:
        fname, start = GRAPHS[name]
        path = DATA / fname
        pg = read_g2o(path)
        X0 = initialize(pg, start)
        fg, handle = from_pose_graph(pg, X0)
        t0 = time.perf_counter()
        fg.problem()  # the fixed pattern and scatter plan, built once per graph (not timed)
        setup = time.perf_counter() - t0
        analysis = {}
        for b in backends:  # the symbolic analysis, once per problem and backend (not timed)
            t0 = time.perf_counter()
            fg.problem().analysed(b)
            analysis[b] = time.perf_counter() - t0
        ggraph, ginit = gtsam_problem(gtsam, path, pg, X0)
        t_g, t_us = [], {b: [] for b in backends}
        res_us, res_g = {}, None
        for rnd in range(args.repeat + 1):
            tg, gres, git = run_gtsam(gtsam, ggraph, ginit)
            for b in backends:
                r = fg.optimize(linear_solver=b, verbose=False)
                if rnd:
                    t_us[b].append(r.time_s)
                res_us[b] = r
            if rnd:
                t_g.append(tg)
            res_g = (gres, git)
        gcost = pg.cost(gtsam_poses(gtsam, pg, res_g[0]))
        mg = statistics.median(t_g)
        cells, costs = [], []
        for b in backends:
            mu = statistics.median(t_us[b])
            ratios = [u / g for u, g in zip(t_us[b], t_g, strict=True)]
            cells.append(f"{mu * 1e3:.0f} ({mu / mg:.2f}x, {min(ratios):.2f}-{max(ratios):.2f})")
            r = res_us[b]
            costs.append(f"{pg.cost(r.values[handle]):.10g} ({r.iterations})")
            breakdowns.append((name, b, r.timings, r.time_s, setup, analysis[b]))
        prob = fg.problem()
        picks = [make_solver("auto", prob.size, prob.block_size).name,
                 make_solver("auto", prob.size, prob.block_size,
                             available=["scipy", "supernodal", "dense"]).name]
        summary.append((name, *[(b, statistics.median(t_us[b]) / mg if b in t_us else None)
                                for b in picks]))
        row = (f"| {name} | {start} | {mg * 1e3:.0f} ({res_g[1]}) | " + " | ".join(cells)
               + f" | {gcost:.10g} | " + " | ".join(costs) + " |")
        print(row, flush=True)
        lines.append(row)
    lines += ["", "Ratio to GTSAM (median time) of linear_solver='auto': with every backend of "
              "this environment installed (goal <= 0.5x) and with the default install, NumPy "
              "and SciPy only (goal <= 1.0x):", "",
              "| graph | auto, all installed | auto, default install |", "|---|---|---|"]
    for name, best, default in summary:
        cell = [f"{b} {r:.2f}x" if r is not None else f"{b} (not run)" for b, r in (best, default)]
        lines.append(f"| {name} | {cell[0]} | {cell[1]} |")
    lines += ["", "Breakdown of microlie's last run (ms): linearise (residuals, Jacobians and "
              "block products) / assemble (scatter into the fixed pattern) / factorise "
              "/ solve / cost (trial points) / other (damping, bookkeeping); 'setup' is the "
              "graph's pattern and scatter plan, built once per graph, and 'analysis' the "
              "linear solver's symbolic analysis, once per problem and backend, both before "
              "the timed solve (like GTSAM's optimizer constructor, which is not timed "
              "either)", "",
              "| graph | backend | linearize | assemble | factorize | solve | cost+retract | "
              "other | total | setup (not timed) | analysis (not timed) |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, b, t, tot, setup, ana in breakdowns:
        lines.append(f"| {name} | {b} | {t['linearize'] * 1e3:.1f} | {t['assemble'] * 1e3:.1f}"
                     f" | {t['factorize'] * 1e3:.1f} | {t['solve'] * 1e3:.1f} | "
                     f"{(t['cost'] + t['retract']) * 1e3:.1f} | {t['other'] * 1e3:.1f} | "
                     f"{tot * 1e3:.1f} | {setup * 1e3:.1f} | {ana * 1e3:.1f} |")
    print("\n".join(lines[3 + len(args.graphs) + 2:]))
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
