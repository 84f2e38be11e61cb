"""Chordal initialisation: microlie.optim.init.chordal against GTSAM 4.3's InitializePose3.

Run (benchmark environment, one command, from the repository root)::

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/pose_graph_init.py [--repeat 5]

Both start from the same file (3-D g2o graphs; GTSAM's 2-D ``lago.initialize`` refuses files
with full information matrices, so there is no 2-D peer). GTSAM: ``readG2o`` plus a prior on
pose 0, then ``InitializePose3.initialize(graph)`` (chordal rotations, then poses), timed alone.
microlie: ``chordal(read_g2o(file))``, timed alone. Runs alternate after one warm-up; the table
gives median times, the ratio of medians with the spread of per-round ratios, and the cost
``0.5 sum r^T Omega r`` of each start over the file's edges (lower is a better start; both
evaluated by ``PoseGraph.cost``). BLAS is held to one thread.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from microlie import SE3  # noqa: E402
from microlie.optim.g2o import read_g2o  # noqa: E402
from microlie.optim.init import chordal  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = ["sphere2500.g2o", "parking-garage.g2o", "smallGrid3D.g2o", "tinyGrid3D.g2o"]


def main() -> None:
    import gtsam

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print("| graph | GTSAM ms | microlie ms | ratio (spread) | start cost GTSAM | "
          "start cost microlie |")
    print("|---|---|---|---|---|---|")
    for name in GRAPHS:
        path = str(DATA / name)
        g = read_g2o(path)
        graph, _ = gtsam.readG2o(path, True)
        full = gtsam.NonlinearFactorGraph(graph)
        full.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(),
                                        gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        tg, tm = [], []
        for k in range(args.repeat + 1):
            t = time.perf_counter()
            values = gtsam.InitializePose3.initialize(full)
            a = time.perf_counter() - t
            t = time.perf_counter()
            X = chordal(g)
            b = time.perf_counter() - t
            if k:
                tg.append(a)
                tm.append(b)
        ratios = [m / q for m, q in zip(tm, tg, strict=True)]
        M = np.array([values.atPose3(int(i)).matrix() for i in g.ids])
        cg = g.cost(SE3.from_matrix(M, normalize=True))
        mg, mm = statistics.median(tg), statistics.median(tm)
        print(f"| {name} | {mg * 1e3:.1f} | {mm * 1e3:.1f} | {mm / mg:.2f} "
              f"({min(ratios):.2f}-{max(ratios):.2f}) | {cg:.6g} | {g.cost(X):.6g} |",
              flush=True)
    load = os.getloadavg()
    print(f"\nload average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, {args.repeat} rounds")


if __name__ == "__main__":
    main()
