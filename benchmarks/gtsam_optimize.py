"""The GTSAM 4.3 script a user writes to do what ``microlie optimize IN --json -o OUT`` does.

Read a g2o pose graph (``gtsam.readG2o``, 3-D when the file has ``VERTEX_SE3`` /
``EDGE_SE3`` lines), hold the first pose with a prior (sigma 1e-6) at its start value,
``LevenbergMarquardtOptimizer(graph, initial, LevenbergMarquardtParams()).optimize()`` from the
file's vertices, write the result with ``gtsam.writeG2o`` and print one JSON line (initial and
final cost ``graph.error``, iterations, solve time). ``pose_graph.py --e2e`` times this script
from process start to exit against the microlie command::

    /work/bench-venv/bin/python benchmarks/gtsam_optimize.py IN.g2o OUT.g2o
"""

import json
import sys
import time

import gtsam
import numpy as np


def main() -> int:
    path, out = sys.argv[1:3]
    with open(path) as f:
        is3d = any(line.startswith(("VERTEX_SE3", "EDGE_SE3")) for line in f)
    graph, initial = gtsam.readG2o(path, is3d)
    k0 = int(initial.keys()[0])
    if is3d:
        graph.add(gtsam.PriorFactorPose3(k0, initial.atPose3(k0),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 1e-6))))
    else:
        graph.add(gtsam.PriorFactorPose2(k0, initial.atPose2(k0),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-6))))
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    result = opt.optimize()
    t1 = time.perf_counter()
    gtsam.writeG2o(graph, result, out)
    print(json.dumps({"initial_cost": graph.error(initial), "final_cost": graph.error(result),
                      "iterations": int(opt.iterations()), "time_s": t1 - t0}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
