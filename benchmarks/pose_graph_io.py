"""Pose-graph files and initialisation against GTSAM 4.3: reading, and chordal initialisation.

Run (benchmark environment, one command, from the repository root)::

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/pose_graph_io.py [--repeat 5]

Reading: ``gtsam.readG2o(file, is3D)`` against ``microlie.optim.io.g2o.read_g2o(file)`` (which
also checks every line and every information matrix), alternating, medians and the spread of
per-round ratios.

Chordal initialisation: both start from the same file (3-D g2o graphs; GTSAM's 2-D
``lago.initialize`` refuses files with full information matrices, so there is no 2-D peer).
GTSAM: ``readG2o`` plus a prior on pose 0, then ``InitializePose3.initialize(graph)`` (chordal
rotations, then poses), timed alone. microlie: ``chordal(read_g2o(file))``, timed alone. Runs
alternate after one warm-up; the table gives median times, the ratio of medians with the spread
of per-round ratios, and the cost ``0.5 sum r^T Omega r`` of each start over the file's edges
(lower is a better start; both evaluated by ``PoseGraph.cost``). BLAS is held to one thread.
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
from microlie.optim.init import chordal  # noqa: E402
from microlie.optim.io.g2o import read_g2o  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = ["sphere2500.g2o", "parking-garage.g2o", "smallGrid3D.g2o", "tinyGrid3D.g2o"]
READ = [("ais2klinik.g2o", False), ("input_M3500_g2o.g2o", False), ("sphere2500.g2o", True),
        ("parking-garage.g2o", True)]


def _alternate(f, g, repeat: int) -> tuple[float, float, float, float]:
    """Medians of f and g timed alternately after one warm-up, and the min/max of g/f."""
    tf, tg = [], []
    for k in range(repeat + 1):
        t = time.perf_counter()
        f()
        a = time.perf_counter() - t
        t = time.perf_counter()
        g()
        b = time.perf_counter() - t
        if k:
            tf.append(a)
            tg.append(b)
    r = [y / x for x, y in zip(tf, tg, strict=True)]
    return statistics.median(tf), statistics.median(tg), min(r), max(r)


def main() -> None:
    import gtsam

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print("Reading g2o files\n")
    print("| file | GTSAM readG2o ms | microlie read_g2o ms | ratio (spread) |")
    print("|---|---|---|---|")
    for name, is3d in READ:
        path = str(DATA / name)
        mg, mm, lo, hi = _alternate(lambda p=path, d=is3d: gtsam.readG2o(p, d),
                                    lambda p=path: read_g2o(p), args.repeat)
        print(f"| {name} | {mg * 1e3:.1f} | {mm * 1e3:.1f} | {mm / mg:.2f} ({lo:.2f}-{hi:.2f}) |",
              flush=True)
    print("\nChordal initialisation (GTSAM InitializePose3.initialize)\n")
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
        mg, mm, lo, hi = _alternate(lambda f=full: gtsam.InitializePose3.initialize(f),
                                    lambda h=g: chordal(h), args.repeat)
        values = gtsam.InitializePose3.initialize(full)
        X = chordal(g)
        M = np.array([values.atPose3(int(i)).matrix() for i in g.ids])
        cg = g.cost(SE3.from_matrix(M, normalize=True))
        print(f"| {name} | {mg * 1e3:.1f} | {mm * 1e3:.1f} | {mm / mg:.2f} "
              f"({lo:.2f}-{hi:.2f}) | {cg:.6g} | {g.cost(X):.6g} |", flush=True)
    load = os.getloadavg()
    print(f"\nload average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, {args.repeat} rounds")


if __name__ == "__main__":
    main()
