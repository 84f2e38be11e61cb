"""The default LM damping on small synthetic bundle adjustments: the NumPy engine's and the torch
engine's solves under the default options (``damping="auto"``), their final costs and
iterations (issue 24: the engines must agree to 1e-8 in float64).

Each scene is ``synthetic_scene(cameras, points, noise, perturb, seed, distance)`` through
``bundle_graph`` (BAL model, 7-dof gauge left free, as on BAL files); the NumPy engine runs LM
with ``linear_solver="schur"``, the device engine ``LMOptions()`` on torch float64. The device
solution's cost is evaluated again by the NumPy engine.

Usage::

    PYTHONPATH=src python benchmarks/device_damping.py
    PYTHONPATH=src python benchmarks/device_damping.py --seeds 0 1 --max-iter 100
"""

from __future__ import annotations

import argparse
import os
import time

SCENES = [(6, 60, 3.0, 0.3, 20.0), (5, 40, 1.0, 0.5, 6.0), (8, 80, 5.0, 0.2, 40.0)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(6)))
    ap.add_argument("--max-iter", type=int, default=100)
    args = ap.parse_args()
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(k, "1")
    import torch

    from microlie.optim.core.variables import Values
    from microlie.optim.device import DeviceProblem, LMOptions, solve
    from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene

    torch.set_num_threads(1)
    print(f"load {os.getloadavg()[0]:.1f}")
    print("| cameras | points | noise px | perturb | distance | seed | NumPy cost | NumPy it. | "
          "torch cost | torch it. | rel. gap | NumPy message | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        for nc, npt, noise, pert, dist in SCENES:
            _, start = synthetic_scene(nc, npt, noise=noise, perturb=pert, seed=seed,
                                       distance=dist)
            g = bundle_graph(start).graph
            t0 = time.perf_counter()
            ref = g.optimize(solver="lm", linear_solver="schur", gauge="none",
                             max_iter=args.max_iter)
            p = DeviceProblem.from_graph(g, gauge="none", backend="torch", dtype="float64")
            x, info = solve(p, p.theta(), p.initial(), LMOptions(max_iter=args.max_iter))
            c = g.cost(Values(p.variables, [a.numpy() for a in x]))
            rel = (c - ref.final_cost) / ref.final_cost
            print(f"| {nc} | {npt} | {noise:g} | {pert:g} | {dist:g} | {seed} | "
                  f"{ref.final_cost:.10g} | {ref.iterations} | {c:.10g} | "
                  f"{int(info.iterations)} | {rel:.1e} | {ref.message[:40]} | "
                  f"{time.perf_counter() - t0:.1f} |", flush=True)


if __name__ == "__main__":
    main()
