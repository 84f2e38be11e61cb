"""Incremental smoothing against GTSAM 4.3's ISAM2, replaying pose graphs pose by pose.

Both sides replay the same schedule (:func:`microlie.optim.online.replay.replay_schedule`):
vertices in id order, each edge added when its later vertex arrives, the new pose predicted
from the current estimate through its odometry edge (from the file where there is none), a
prior (sigma 1e-6) on the first pose. GTSAM: ``gtsam.ISAM2()`` with default parameters
(relinearizeThreshold 0.1, relinearizeSkip 10, wildfire 0.001), one ``update`` per pose and
``calculateEstimate`` of the previous pose for the prediction. Ours: ``replay_pose_graph`` with
``IncrementalSmoother()`` (the same defaults). Times are per pose (prediction, factor
construction and update: the Python loop included on both sides) and in total; the runs
alternate ours / GTSAM within each repeat. The final cost is GTSAM's error over the file's
edges, against the batch optimum of ``../shared/data/README.md``; ours also after one final
batch ``optimize()``. Run with the benchmark environment::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/bench-venv/bin/python benchmarks/incremental.py \\
        --graphs M3500 sphere2500 kitti_00 --repeat 1
"""

from __future__ import annotations

import argparse
import collections
import json
import time
from pathlib import Path

import numpy as np

from microlie import SE2
from microlie.optim.io.g2o import read_g2o
from microlie.optim.online.incremental import IncrementalSmoother
from microlie.optim.online.replay import replay_pose_graph, replay_schedule

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "pose_graph"
GRAPHS = {"M3500": "input_M3500_g2o.g2o", "sphere2500": "sphere2500.g2o",
          "kitti_00": "kitti_00.g2o"}
OPTIMUM = {"M3500": 68.95743912, "sphere2500": 675.7009629, "kitti_00": 49.16106912}  # README


def run_gtsam(graph, until: int) -> dict:
    import gtsam

    V = min(until, graph.num_vertices)
    ii, jj = graph.edge_index()
    _, edges, odometry = replay_schedule(graph)
    two = graph.group is SE2
    M = graph.measurements.matrix()
    if two:
        Z = [gtsam.Pose2(float(m[0, 2]), float(m[1, 2]), float(np.arctan2(m[1, 0], m[0, 0])))
             for m in M]
        info = graph.information
        start = (graph.poses.matrix() if graph.poses is not None else np.eye(3)[None])
        P0 = [gtsam.Pose2(float(m[0, 2]), float(m[1, 2]), float(np.arctan2(m[1, 0], m[0, 0])))
              for m in start]
        Between, Prior = gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2
        est = "calculateEstimatePose2"
    else:
        Z = [gtsam.Pose3(m) for m in M]
        p = [3, 4, 5, 0, 1, 2]  # ours: translation first; GTSAM: rotation first
        info = graph.information[:, p][:, :, p]
        start = (graph.poses.matrix() if graph.poses is not None else np.eye(4)[None])
        P0 = [gtsam.Pose3(m) for m in start]
        Between, Prior = gtsam.BetweenFactorPose3, gtsam.PriorFactorPose3
        est = "calculateEstimatePose3"
    noise = [gtsam.noiseModel.Gaussian.Information(np.ascontiguousarray(a)) for a in info]
    isam = gtsam.ISAM2()
    times = np.empty(V)
    t_start = time.perf_counter()
    for k in range(V):
        t0 = time.perf_counter()
        fg = gtsam.NonlinearFactorGraph()
        vals = gtsam.Values()
        if k == 0:
            fg.add(Prior(0, P0[0], gtsam.noiseModel.Isotropic.Sigma(graph.group.dof, 1e-6)))
            vals.insert(0, P0[0])
        else:
            for e in edges[k]:
                fg.add(Between(int(ii[e]), int(jj[e]), Z[e], noise[e]))
            o = odometry[k]
            if o >= 0:
                prev = getattr(isam, est)(k - 1)
                vals.insert(k, prev.compose(Z[o]) if ii[o] == k - 1 else
                            prev.compose(Z[o].inverse()))
            else:
                vals.insert(k, P0[k])
        isam.update(fg, vals)
        times[k] = time.perf_counter() - t0
    total = time.perf_counter() - t_start
    result = isam.calculateEstimate()
    full = gtsam.NonlinearFactorGraph()
    for e in np.flatnonzero(np.maximum(ii, jj) < V):
        full.add(Between(int(ii[e]), int(jj[e]), Z[e], noise[e]))
    ms = times * 1e3
    return {"final_cost": float(full.error(result)), "total_s": total,
            "update_ms_median": float(np.median(ms)),
            "update_ms_p99": float(np.percentile(ms, 99))}


def run_ours(graph, until: int, final_batch: bool) -> dict:
    rep = replay_pose_graph(graph, IncrementalSmoother(), until=until)
    s = rep["smoother"]
    parts = collections.Counter()
    for r in s.records:
        for k, v in r.times.items():
            parts[k] += v
    in_update = sum(r.time_s for r in s.records)
    parts["update, other"] = in_update - sum(parts.values())
    parts["outside update (prediction, factors, loop)"] = rep["total_s"] - in_update
    out = {k: rep[k] for k in ("final_cost", "total_s", "update_ms_median", "update_ms_p99",
                               "relinearized", "reeliminated", "converged")}
    out["parts"] = dict(parts)
    # the wildfire's own estimate (stale steps below the threshold), beside the best estimate
    sub = graph if until >= graph.num_vertices else None
    out["estimate_cost"] = (float(sub.cost(s.calculate_estimate()[rep["poses"]]))
                            if sub is not None else float("nan"))
    if final_batch:
        t0 = time.perf_counter()
        res = s.optimize()
        out["batch_cost"] = float(res.final_cost)
        out["batch_s"] = time.perf_counter() - t0
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graphs", nargs="+", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--until", type=int, default=10 ** 9, help="replay the first N poses")
    ap.add_argument("--json", metavar="FILE", help="also write the raw figures")
    args = ap.parse_args()
    raw = {}
    print("| graph | poses | ours total s | ISAM2 total s | total ratio (goal <= 0.5) | median "
          "ms ours / ISAM2 | ratio | p99 ms ours / ISAM2 | ratio | final cost ours / ISAM2 / "
          "optimum | rel. gap ours | after optimize() |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.graphs:
        graph = read_g2o(DATA / GRAPHS[name])
        n = min(args.until, graph.num_vertices)
        runs = []
        for r in range(args.repeat):
            o = run_ours(graph, n, final_batch=(r == args.repeat - 1))
            g = run_gtsam(graph, n)
            runs.append((o, g))
        o = min((x[0] for x in runs), key=lambda d: d["total_s"])
        g = min((x[1] for x in runs), key=lambda d: d["total_s"])
        raw[name] = {"ours": [x[0] for x in runs], "gtsam": [x[1] for x in runs]}
        best = OPTIMUM[name] if n == graph.num_vertices else float("nan")
        last = runs[-1][0]
        print(f"| {name} | {n} | {o['total_s']:.3f} | {g['total_s']:.3f} | "
              f"{o['total_s'] / g['total_s']:.1f} | {o['update_ms_median']:.3f} / "
              f"{g['update_ms_median']:.3f} | {o['update_ms_median'] / g['update_ms_median']:.1f}"
              f" | {o['update_ms_p99']:.2f} / {g['update_ms_p99']:.2f} | "
              f"{o['update_ms_p99'] / g['update_ms_p99']:.1f} | {o['final_cost']:.6g} / "
              f"{g['final_cost']:.6g} / {best:.10g} | {(o['final_cost'] - best) / best:.2e} | "
              f"{last.get('batch_cost', float('nan')):.10g} |")
        tot = o["total_s"]
        print("|  | where our time goes: " + ", ".join(
            f"{k} {v:.2f} s ({100 * v / tot:.0f}%)" for k, v in o["parts"].items())
              + f"; {o['relinearized']} relinearisations, {o['reeliminated']} nodes "
              f"re-eliminated; cost at calculate_estimate() (no best estimate) "
              f"{o['estimate_cost']:.6g}, gap {(o['estimate_cost'] - best) / best:.2e} |")
    if args.json:
        for runs in raw.values():
            for d in runs["ours"]:
                d["parts"] = dict(d["parts"])
        Path(args.json).write_text(json.dumps(raw, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
