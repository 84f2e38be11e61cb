"""Issue 23: what one factor costs when it arrives alone (the incremental smoother's input).

Per-call times of building a ``BetweenFactor`` / ``PriorFactor`` for one edge (scalar indices,
the measurement one element or its parameter array) with isotropic, diagonal and full
information noise, of the noise constructors, and of evaluating one factor (``evaluate``:
residual and Jacobians; ``linearize``: whitened ``e`` and ``A``), beside GTSAM's pybind
equivalents (``BetweenFactorPose3(...)``, ``noiseModel.Gaussian.Information``, ``error``,
``linearize``). Checkouts of ``src`` run in alternating subprocesses (interleaved: a burst of
load hits all alike) and GTSAM in this process between them; each worker takes the least mean
of short batches of calls (``_least_call``), the table the median over rounds.

Run (one command, from the repository root; GTSAM from the benchmark environment)::

    git archive 06e8723 src | tar -x -C /tmp/before   # the code before the change
    cp /work/main/src/microlie/_c/*.so /tmp/before/src/microlie/_c/   # its compiled kernels
    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/single_factor.py \\
        --python /work/main/.venv/bin/python --before /tmp/before/src --after src --rounds 5

Without ``--before`` only the current code is timed; without GTSAM its column is empty.
``--threshold`` times the compiled row loop against the batched kernels by batch size instead
(where ``microlie.optim.core.factors.SMALL_BATCH`` belongs).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path


def _least_call(fn: Callable[[], object], calls: int, reps: int = 25) -> float:
    """The least mean seconds per call over ``reps`` short batches of ``calls`` calls: on a
    shared machine the batch that no other process interrupted (a batch that spans a
    scheduler slice is inflated, more so for slower calls; the median would favour the
    faster code)."""
    for _ in range(max(calls // 10, 5)):
        fn()
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        out.append((time.perf_counter() - t0) / calls)
    return min(out)


def worker(calls: int) -> dict[str, float]:
    """Our measurements, in the checkout on ``PYTHONPATH``."""
    import gc

    import numpy as np

    from microlie import SE2, SE3
    from microlie.optim import (
        BetweenFactor,
        Diagonal,
        FactorGraph,
        Information,
        Isotropic,
        PriorFactor,
    )

    fns: dict[str, Callable[[], object]] = {}
    for G in (SE2, SE3):
        n, d = G.__name__, G.dof
        g = FactorGraph()
        x = g.add_variables(G.random(10, rng=0))
        Z = G.exp(np.linspace(0.1, 0.5, d))
        info = np.diag(np.linspace(1.0, 4.0, d)) + 0.1  # dense, positive definite
        noises = {"Isotropic": Isotropic(d, 0.1), "Diagonal": Diagonal(np.linspace(0.1, 0.3, d)),
                  "Information": Information(info)}
        for kind, N in noises.items():
            fns[f"{n} BetweenFactor, {kind}"] = lambda x=x, Z=Z, N=N: BetweenFactor(x, 2, 3, Z, N)
        fns[f"{n} BetweenFactor, new Information"] = (
            lambda x=x, Z=Z, info=info: BetweenFactor(x, 2, 3, Z, Information(info)))
        zp = np.array(Z.params)
        fns[f"{n} BetweenFactor, Z as parameters"] = (
            lambda x=x, zp=zp, N=noises["Isotropic"]: BetweenFactor(x, 2, 3, zp, N))
        fns[f"{n} PriorFactor, Isotropic"] = (
            lambda x=x, Z=Z, N=noises["Isotropic"]: PriorFactor(x, 2, Z, N))
        fns[f"{n} noise Information"] = lambda info=info: Information(info)
        fns[f"{n} noise Diagonal"] = lambda d=d: Diagonal(np.linspace(0.1, 0.3, d))
        fns[f"{n} noise Isotropic"] = lambda d=d: Isotropic(d, 0.1)
        f = BetweenFactor(x, 2, 3, Z, noises["Information"])
        pi, pj = x.initial[[2]], x.initial[[3]]
        vals = [x.wrap(pi), x.wrap(pj)]
        fns[f"{n} evaluate (r, J)"] = lambda f=f, vals=vals: f.evaluate(vals, True)
        if hasattr(f, "linearize"):
            fns[f"{n} linearize (e, A)"] = lambda f=f, pi=pi, pj=pj: f.linearize([pi, pj])
    for key, fn in list(fns.items()):  # what this checkout does not offer (the code before)
        try:
            fn()
        except (TypeError, ValueError):
            del fns[key]
    gc.disable()
    try:
        return {k: _least_call(fn, calls) for k, fn in fns.items()}
    finally:
        gc.enable()


def gtsam_times(calls: int) -> dict[str, float]:
    """GTSAM's counterparts (an empty dict without GTSAM)."""
    try:
        import gtsam  # type: ignore[import-not-found]
    except ImportError:
        return {}
    import gc

    import numpy as np

    from microlie import SE2, SE3

    fns: dict[str, Callable[[], object]] = {}
    for G in (SE2, SE3):
        n, d = G.__name__, G.dof
        Z = G.exp(np.linspace(0.1, 0.5, d))
        m = Z.matrix()
        if G is SE3:
            Zg, make, prior = gtsam.Pose3(m), gtsam.BetweenFactorPose3, gtsam.PriorFactorPose3
            X = [gtsam.Pose3(g.matrix()) for g in SE3.random(2, rng=0)]
        else:
            Zg = gtsam.Pose2(m[0, 2], m[1, 2], float(np.arctan2(m[1, 0], m[0, 0])))
            make, prior = gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2
            X = [gtsam.Pose2(*p) for p in np.array([[0.1, 0.2, 0.3], [1.0, -0.5, 2.0]])]
        info = np.diag(np.linspace(1.0, 4.0, d)) + 0.1
        sig = np.linspace(0.1, 0.3, d)
        noises = {"Isotropic": gtsam.noiseModel.Isotropic.Sigma(d, 0.1),
                  "Diagonal": gtsam.noiseModel.Diagonal.Sigmas(sig),
                  "Information": gtsam.noiseModel.Gaussian.Information(info)}
        for kind, N in noises.items():
            fns[f"{n} BetweenFactor, {kind}"] = lambda make=make, Zg=Zg, N=N: make(2, 3, Zg, N)
        fns[f"{n} BetweenFactor, new Information"] = (
            lambda make=make, Zg=Zg, info=info:
            make(2, 3, Zg, gtsam.noiseModel.Gaussian.Information(info)))
        if G is SE3:  # the pose built from (translation, quaternion) first
            q = np.array(Z.params)
            fns[f"{n} BetweenFactor, Z as parameters"] = (
                lambda q=q, N=noises["Isotropic"]: gtsam.BetweenFactorPose3(
                    2, 3, gtsam.Pose3(gtsam.Rot3.Quaternion(q[6], q[3], q[4], q[5]), q[:3]), N))
        fns[f"{n} PriorFactor, Isotropic"] = (
            lambda prior=prior, Zg=Zg, N=noises["Isotropic"]: prior(2, Zg, N))
        fns[f"{n} noise Information"] = lambda info=info: gtsam.noiseModel.Gaussian.Information(
            info)
        fns[f"{n} noise Diagonal"] = lambda d=d: gtsam.noiseModel.Diagonal.Sigmas(
            np.linspace(0.1, 0.3, d))
        fns[f"{n} noise Isotropic"] = lambda d=d: gtsam.noiseModel.Isotropic.Sigma(d, 0.1)
        f = make(2, 3, Zg, noises["Information"])
        v = gtsam.Values()
        v.insert(2, X[0])
        v.insert(3, X[1])
        fns[f"{n} evaluate (r, J)"] = lambda f=f, v=v: f.linearize(v)  # no unwhitened J
        fns[f"{n} linearize (e, A)"] = lambda f=f, v=v: f.linearize(v)
    gc.disable()
    try:
        return {k: _least_call(fn, calls) for k, fn in fns.items()}
    finally:
        gc.enable()


def threshold(calls: int) -> None:
    """The row loop against the batched kernels by batch size (``evaluate_into``, dense
    information): where ``SMALL_BATCH`` should be."""
    import numpy as np

    import microlie.optim.core.factors as F
    from microlie import SE2, SE3
    from microlie.optim import BetweenFactor, FactorGraph, Information

    print("| group | rows m | batched us | row loop us | rows / batched |\n|---|---|---|---|---|")
    keep = F.SMALL_BATCH
    try:
        for G in (SE2, SE3):
            for m in (1, 4, 16, 64, 256, 1024, 4096):
                g = FactorGraph()
                x = g.add_variables(G.random(2 * m, rng=0))
                f = BetweenFactor(x, np.arange(m), np.arange(m, 2 * m), G.random(m, rng=1),
                                  Information(np.eye(G.dof) * 4))
                vals = [x.wrap(x.initial[:m]), x.wrap(x.initial[m:])]
                out = np.empty((m, G.dof, 2 * G.dof))
                n = max(3, calls // m)
                t = {}
                for lim in (0, m):  # interleaved: batched, rows, batched, rows, ...
                    F.SMALL_BATCH = lim
                    t[lim] = _least_call(lambda f=f, vals=vals, out=out:
                                          f.evaluate_into(vals, out), n)
                print(f"| {G.__name__} | {m} | {t[0] * 1e6:.1f} | {t[m] * 1e6:.1f} | "
                      f"{t[m] / t[0]:.2f} |")
    finally:
        F.SMALL_BATCH = keep


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", help="the src folder of the code before (optional)")
    ap.add_argument("--after", default="src", help="the src folder of the code after")
    ap.add_argument("--python", default=sys.executable,
                    help="the interpreter of the microlie workers")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--calls", type=int, default=30, help="calls per timed batch")
    ap.add_argument("--threshold", action="store_true",
                    help="time the row loop against the batched kernels by batch size instead")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.threshold:
        threshold(args.calls)
        return 0
    if args.worker:
        print(json.dumps(worker(args.calls)))
        return 0
    which = (["before"] if args.before else []) + ["after"]
    runs: dict[str, list[dict[str, float]]] = {k: [] for k in [*which, "gtsam"]}
    for _ in range(args.rounds):
        for w in which:
            src = str(Path(getattr(args, w)).resolve())
            env = dict(os.environ, PYTHONPATH=src, OPENBLAS_NUM_THREADS="1")
            r = subprocess.run([args.python, __file__, "--worker", "--calls", str(args.calls)],
                               env=env, capture_output=True, text=True, check=True)
            runs[w].append(json.loads(r.stdout))
        runs["gtsam"].append(gtsam_times(args.calls))
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"single_factor.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"{args.rounds} rounds, least of 25 batches of {args.calls} calls; `uptime`: "
          f"{load}\n")

    def med(w: str, key: str) -> float | None:
        vals = [r[key] for r in runs[w] if key in r]
        return statistics.median(vals) * 1e6 if vals else None

    def fmt(v: float | None) -> str:
        return "" if v is None else f"{v:.2f}"

    cols = [*which, "gtsam"]
    print("| per call (us) | " + " | ".join(cols) + " | after / GTSAM |"
          + (" after / before |" if args.before else ""))
    print("|---" * (len(cols) + 2 + bool(args.before)) + "|")
    for key in runs["after"][0]:
        v = {w: med(w, key) for w in cols}
        a, g, b = v["after"], v["gtsam"], v.get("before")
        ratio = f"{a / g:.2f}" if a is not None and g else ""
        line = f"| {key} | " + " | ".join(fmt(v[w]) for w in cols) + f" | {ratio} |"
        if args.before:
            line += f" {a / b:.3f} |" if a is not None and b else " |"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
