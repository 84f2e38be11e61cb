"""A batch of small problems in one call (issue 24 acceptance): ``B`` 10-pose SE3 graphs and
``B`` PnP problems solved by the device engine in one jitted JAX call and one
``torch.compile(fullgraph=True)`` torch call, each problem compared with its own NumPy-engine
solve (max abs parameter difference; goal 1e-8), and timed against the NumPy engine solving
them one by one.

Usage::

    PYTHONPATH=src python benchmarks/device_batch.py --batch 1000 --kinds chain pnp \
        --engines jax torch-compile torch
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from microlie import SE3
from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor, ReprojectionFactor


def chain(seed: int, conv=None, n: int = 10):
    """A 10-pose SE3 chain: prior, odometry, two loop closures, perturbed start."""
    rng = np.random.default_rng(seed)
    X0 = SE3.exp(rng.normal(size=(n, 6)) * 0.3)
    Z = SE3.exp(rng.normal(size=(n - 1, 6)) * 0.5)
    Zc = SE3.exp(rng.normal(size=(2, 6)))
    g = FactorGraph()
    x = g.add_variables(SE3.from_params(conv(X0.params)) if conv else X0)
    g.add(PriorFactor(x, 0, SE3.identity(), Diagonal([0.1] * 6)))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n), Z,
                        Diagonal(np.linspace(0.05, 0.2, 6))))
    g.add(BetweenFactor(x, [0, 2], [n // 2, n - 1], Zc, Diagonal([0.2] * 6)))
    return g, x


def pnp(seed: int, conv=None, n: int = 12):
    """PnP: one world-to-camera SE3 pose from 12 fixed points and noisy pinhole pixels."""
    rng = np.random.default_rng(seed)
    T = SE3.exp(np.r_[0.1 * rng.normal(size=3), 0.1 * rng.normal(size=3)])
    X = rng.uniform(-1, 1, (n, 3)) + [0.0, 0.0, 5.0]
    P = T.act(X)
    K = np.array([500.0, 480.0, 320.0, 240.0])
    uv = K[:2] * P[:, :2] / P[:, 2:] + K[2:] + rng.normal(size=(n, 2))
    T0 = T.compose(SE3.exp(0.05 * rng.normal(size=6)))
    g = FactorGraph()
    pose = g.add_variables(SE3.from_params(conv(T0.params[None]) if conv else T0.params[None]))
    pts = g.add_variables(conv(X) if conv else X, fixed=True)
    g.add(ReprojectionFactor((pose, np.zeros(n, int)), (pts, np.arange(n)), uv,
                             model="pinhole", intrinsics=K, noise=Diagonal([1.0, 1.0])))
    return g, pose


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=1000)
    ap.add_argument("--kinds", nargs="+", default=["chain", "pnp"])
    ap.add_argument("--engines", nargs="+", default=["jax", "torch-compile", "torch"])
    ap.add_argument("--max-tries", type=int, default=None,
                    help="try limit of the compiled torch loop (default: max_iter * 10)")
    ap.add_argument("--compile-backend", default="inductor",
                    help="torch.compile backend of torch-compile (inductor, aot_eager, ...)")
    args = ap.parse_args()
    import jax
    import jax.numpy as jnp
    import torch

    jax.config.update("jax_enable_x64", True)
    from microlie.optim.device import DeviceProblem, LMOptions, solve, stack

    B = args.batch
    print(f"load {os.getloadavg()[0]:.1f}, batch {B}")
    print("| problems | engine | max abs diff to NumPy | converged | time s (first / second "
          "call) | CPU s of the first call | NumPy one by one s | load |")
    print("|---|---|---|---|---|---|---|---|")
    for kind in args.kinds:
        make = chain if kind == "chain" else pnp
        t0 = time.perf_counter()
        refs = []
        for s in range(B):
            g, h = make(s)
            refs.append(g.optimize().values[h].params)
        t_np = time.perf_counter() - t0
        ref = np.stack(refs)
        for eng in args.engines:
            backend = "jax" if eng == "jax" else "torch"
            conv = jnp.asarray if backend == "jax" else (lambda a: torch.tensor(np.array(a)))
            probs = [DeviceProblem.from_graph(make(s, conv)[0]) for s in range(B)]
            theta = stack([p.theta() for p in probs])
            x0 = stack([p.initial() for p in probs])
            p = probs[0]
            if eng == "jax":
                opts = LMOptions()
                fn = jax.jit(lambda th, x, p=p, o=opts: solve(p, th, x, o))
            elif eng == "torch-compile":
                opts = LMOptions(max_tries=args.max_tries)
                torch._dynamo.reset()
                from torch._dynamo.utils import compilation_time_metrics

                compilation_time_metrics.clear()
                fn = torch.compile(lambda th, x, p=p, o=opts: solve(p, th, x, o),
                                   fullgraph=True, dynamic=False,
                                   backend=args.compile_backend)
            else:
                opts = LMOptions()
                fn = lambda th, x, p=p, o=opts: solve(p, th, x, o)  # noqa: E731
            times = []
            cpu0 = _cpu()
            for _ in range(2):
                t0 = time.perf_counter()
                xs, info = fn(theta, x0)
                if eng == "jax":
                    jax.block_until_ready(xs)
                times.append(time.perf_counter() - t0)
                if not times[1:]:
                    cpu1 = _cpu() - cpu0
            got = p.backend.to_numpy(xs[0])
            diff = float(np.abs(got - ref).max())
            conv_n = int((p.backend.to_numpy(info.status) == 1).sum())
            tt = " / ".join(f"{t:.2f}" for t in times)
            print(f"| {B} {kind} | {eng} | {diff:.1e} | {conv_n}/{B} | {tt} | {cpu1:.1f} | "
                  f"{t_np:.2f} | {os.getloadavg()[0]:.1f} |", flush=True)
            if eng == "torch-compile":
                _compile_split()


def _cpu() -> float:
    """CPU seconds of this process and its finished children (the C++ compiler)."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _compile_split() -> None:
    """Where the first compiled call's time went (torch's own timers, seconds)."""
    from torch._dynamo.utils import compilation_time_metrics as times

    keep = ("bytecode_tracing", "create_aot_dispatcher_function", "compile_fx_inner",
            "fx_codegen_and_compile", "async_compile.wait", "compile_file",
            "_compile.compile_inner")
    parts = [f"{k} {sum(v):.1f}" for k, v in times.items() if any(w in k for w in keep)]
    print("   compile split (s): " + ", ".join(parts), flush=True)


if __name__ == "__main__":
    main()
