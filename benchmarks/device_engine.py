"""The device engine (``microlie.optim.device``) on the shared pose graphs and BAL problem:
final cost against the NumPy engine's (issue 24 acceptance: 1e-8 relative in float64, 1e-4 in
float32) and time, torch and JAX against the NumPy engine.

Every device solution's cost is evaluated again by the NumPy engine (``FactorGraph.cost`` at
the returned values, float64). JAX times are given for the first call (tracing and XLA
compilation included) and a second call of the same jitted function.

Usage::

    PYTHONPATH=src python benchmarks/device_engine.py --cases M3500 sphere2500 \
        parking-garage problem-49-7776 --backends torch jax --dtypes float64 float32
    PYTHONPATH=src python benchmarks/device_engine.py --cases problem-49-7776 --linear schur \
        --rel-tol 1e-10 --abs-tol 0
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
CASES = {"sphere2500": "pose_graph/sphere2500.g2o",
         "parking-garage": "pose_graph/parking-garage.g2o",
         "M3500": "pose_graph/input_M3500_g2o.g2o",
         "problem-49-7776": "bal/problem-49-7776-pre.txt"}


def build(case: str):
    from microlie.optim import from_pose_graph, read_bal, read_g2o
    from microlie.optim.sfm.bundle import bundle_graph

    path = DATA / CASES[case]
    if case.startswith("problem"):
        bg = bundle_graph(read_bal(str(path)))
        return bg.graph, {"solver": "lm", "linear_solver": "schur", "gauge": "none"}
    g, _ = from_pose_graph(read_g2o(str(path)))
    return g, {}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--backends", nargs="+", default=["torch", "jax"])
    ap.add_argument("--dtypes", nargs="+", default=["float64", "float32"])
    ap.add_argument("--max-iter", type=int, default=100)
    ap.add_argument("--cg-max-iter", type=int, default=None)
    ap.add_argument("--eta-max", type=float, default=None)
    ap.add_argument("--precondition", default=None, choices=["auto", "jacobi", "tree"])
    ap.add_argument("--coarse", type=int, default=None,
                    help="aggregate size of the coarse level (-1 automatic, 0 none)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    ap.add_argument("--linear", default="pcg", choices=["auto", "dense", "schur", "pcg"],
                    help="the device step solve (LMOptions.linear)")
    ap.add_argument("--rel-tol", type=float, default=None,
                    help="rel_tol of both engines (default GTSAM's 1e-5)")
    ap.add_argument("--abs-tol", type=float, default=None,
                    help="abs_tol of both engines (default GTSAM's 1e-5)")
    ap.add_argument("--damping", default=None, choices=["auto", "identity", "diagonal"],
                    help="the LM damping of both engines (default 'auto')")
    args = ap.parse_args()
    # one BLAS/XLA thread (several threads on 2 shared cores made JAX's LAPACK Cholesky of a
    # 441 x 441 matrix take 0.2-1.8 s instead of 5 ms); set before JAX or BLAS start
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(k, str(args.threads))
    os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false "
                                       "intra_op_parallelism_threads=1")
    if "jax" in args.backends:
        import jax

        jax.config.update("jax_enable_x64", True)
    from microlie.optim.core.variables import Values
    from microlie.optim.device import DeviceProblem, LMOptions, solve

    tols = {k: v for k, v in (("rel_tol", args.rel_tol), ("abs_tol", args.abs_tol),
                              ("damping", args.damping)) if v is not None}
    extra = {k: v for k, v in (("cg_max_iter", args.cg_max_iter),
                               ("eta_max", args.eta_max),
                               ("precondition", args.precondition),
                               ("coarse", args.coarse)) if v is not None}
    extra.update(tols)
    print(f"load {os.getloadavg()[0]:.1f}; device step {args.linear}; "
          f"tolerances {tols or 'default'}")
    print("| case | engine | dtype | final cost (NumPy cost at the values) | rel. to NumPy | "
          "iterations | CG iterations | time s (first / second call) |")
    print("|---|---|---|---|---|---|---|---|")
    for case in args.cases:
        g, kw = build(case)
        t0 = time.perf_counter()
        ref = g.optimize(max_iter=args.max_iter, **kw, **tols)
        t_np = time.perf_counter() - t0
        print(f"| {case} | numpy | float64 | {ref.final_cost:.13g} | 0 | {ref.iterations} | - | "
              f"{t_np:.2f} |", flush=True)
        gauge = kw.get("gauge", "check")
        for backend in args.backends:
            for dtype in args.dtypes:
                p = DeviceProblem.from_graph(g, gauge=gauge, backend=backend, dtype=dtype)
                opts = LMOptions(max_iter=args.max_iter, linear=args.linear, **extra)
                th, x0 = p.theta(), p.initial()
                if backend == "jax":
                    import jax

                    fn = jax.jit(lambda th, x, p=p, o=opts: solve(p, th, x, o))
                else:
                    import torch

                    torch.set_num_threads(args.threads)
                    fn = lambda th, x, p=p, o=opts: solve(p, th, x, o)  # noqa: E731
                times = []
                for _ in range(2 if backend == "jax" else 1):
                    t0 = time.perf_counter()
                    x, info = fn(th, x0)
                    if backend == "jax":
                        jax.block_until_ready(x)
                    times.append(time.perf_counter() - t0)
                vals = Values(p.variables, [np.asarray(p.backend.to_numpy(a), dtype=np.float64)
                                            for a in x])
                c = g.cost(vals)
                rel = (c - ref.final_cost) / ref.final_cost
                tt = " / ".join(f"{t:.2f}" for t in times)
                print(f"| {case} | {backend} | {dtype} | {c:.13g} | {rel:.1e} | "
                      f"{int(p.backend.to_numpy(info.iterations))} | "
                      f"{int(p.backend.to_numpy(info.cg_iterations))} | {tt} |", flush=True)


if __name__ == "__main__":
    main()
