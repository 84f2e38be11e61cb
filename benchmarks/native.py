"""microlie against a native C++ loop (benchmarks/native/lie_native.cpp), with and without the
compiled kernels of microlie[fast], at N = 1e6 (batched) and on one element (against gtsam).

    PYTHONPATH=src python benchmarks/native.py [--n 1000000] [--rounds 7]

The C++ source is compiled in the run (g++ -O3 -march=native -fno-math-errno -fopenmp-simd,
glibc's libmvec) into a shared library called through ctypes on the same NumPy arrays, so that
the three variants are timed round-robin in one process ("fast" = with the extra, "generic" =
the NumPy kernels, same process with the replacements unregistered). Prints ns per element
(medians, with the interquartile spread) and the ratios microlie/native. One element: us per
call of the public API, against gtsam's Pose3 binding when gtsam is importable (bench venv).
"""

from __future__ import annotations

import argparse
import ctypes
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from microlie import SE3, SO3
from microlie import _kernels as K

HERE = Path(__file__).parent
SRC = HERE / "native" / "lie_native.cpp"
BLOCKED = HERE / "native" / "lie_blocked.c"
FLAGS = ["-O3", "-march=native", "-fno-math-errno", "-fopenmp-simd", "-shared", "-fPIC"]


def build(blocked: bool = False) -> ctypes.CDLL:
    """The plain native loops (lie_native.cpp) or the blocked ones (lie_blocked.c)."""
    out = Path(tempfile.mkdtemp()) / "liblie_native.so"
    if blocked:
        cmd = ["gcc", *FLAGS, "-std=c11", "-DLM_LIBMVEC",
               f"-I{HERE.parent / 'fast' / 'src' / 'microlie_fast'}",
               str(BLOCKED)]
    else:
        cmd = ["g++", *FLAGS, str(SRC)]
    subprocess.run([*cmd, "-o", str(out), "-lmvec", "-lm"], check=True)
    return ctypes.CDLL(str(out))


def ptr(a: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(a.ctypes.data)


def native_call(lib: ctypes.CDLL, name: str, ins: list[np.ndarray], outs: list[np.ndarray],
                prefix: str = "n_"):
    """The native loop writing into preallocated (warm) outputs."""
    f = getattr(lib, prefix + name)
    args = [ptr(a) for a in ins] + [ptr(o) for o in outs] + [ctypes.c_long(len(ins[0]))]

    def call():
        return f(*args)
    call.fresh = native_fresh(lib, name, ins, outs, prefix)  # type: ignore[attr-defined]
    return call


def native_fresh(lib: ctypes.CDLL, name: str, ins: list[np.ndarray], outs: list[np.ndarray],
                 prefix: str = "n_"):
    """The native loop writing into fresh outputs each call (what microlie returns): the
    difference to :func:`native_call` is the cost of the new pages."""
    f = getattr(lib, prefix + name)
    n = ctypes.c_long(len(ins[0]))
    pin = [ptr(a) for a in ins]
    shapes = [o.shape for o in outs]

    def call():
        fresh = [np.empty(s) for s in shapes]
        f(*pin, *[ptr(o) for o in fresh], n)
        return fresh
    return call


def generic(name: str, fn):
    """``fn`` with the compiled replacement of kernel ``name`` unregistered during the call."""
    k = K.KERNELS[name]

    def call():
        impl, k.impl = k.impl, None
        try:
            return fn()
        finally:
            k.impl = impl
    return call


def timed(fn, number: int = 1) -> float:
    t0 = time.perf_counter()
    for _ in range(number):
        fn()
    return (time.perf_counter() - t0) / number


def interleaved(fns: dict, rounds: int, number: int = 1) -> dict:
    for f in fns.values():
        f()  # warm up
    times: dict = {k: [] for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            times[k].append(timed(f, number))
    return times


def stat(ts: list[float], scale: float) -> tuple[float, float, float]:
    q = statistics.quantiles([t * scale for t in ts], n=4) if len(ts) > 1 else [ts[0] * scale] * 3
    return statistics.median(ts) * scale, q[0], q[2]


def batched(n: int, rounds: int) -> None:
    lib, blk = build(), build(blocked=True)
    rng = np.random.default_rng(0)
    t3 = rng.standard_normal((n, 3))
    t6 = rng.standard_normal((n, 6))
    R = SO3.exp(t3)
    X, Y = SE3.exp(t6), SE3.exp(rng.standard_normal((n, 6)))
    v = rng.standard_normal((n, 3))
    o = {k: np.empty((n, k)) for k in (3, 4, 6, 7)}
    j18, j9, j36 = np.empty((n, 18)), np.empty((n, 9)), np.empty((n, 36))
    cases: list = [
        ("SO3.exp", lambda: SO3.exp(t3), native_call(lib, "so3_exp", [t3], [o[4]])),
        ("SO3.log", lambda: R.log(), native_call(lib, "so3_log", [R.params], [o[3]])),
        ("SE3.exp", lambda: SE3.exp(t6), native_call(lib, "se3_exp", [t6], [o[7]])),
        ("SE3.log", lambda: X.log(), native_call(lib, "se3_log", [X.params], [o[6]])),
        ("SE3.compose", lambda: X @ Y,
         native_call(lib, "se3_compose", [X.params, Y.params], [o[7]])),
        ("SE3.act", lambda: X.act(v), native_call(lib, "se3_act", [X.params, v], [o[3]])),
        ("SE3.exp_jac", lambda: SE3.exp(t6, jac=True),
         native_call(lib, "se3_exp_jac", [t6], [o[7], j36])),
        ("SE3.act_jac", lambda: X.act(v, jac=True),
         native_call(lib, "se3_act_jac", [X.params, v], [o[3], j18, j9])),
        ("SE3.minus_jac", lambda: Y.minus(X, jac=True), None),
        ("SE3.between_jac", lambda: X.between(Y, jac=True), None),
    ]
    fast_on = K.KERNELS["SE3.exp"].impl is not None
    print(f"batched, N = {n}, ns per element, median [q1, q3] of {rounds} interleaved rounds; "
          f"compiled kernels {'registered' if fast_on else 'NOT registered'}")
    print("native: into preallocated outputs; native+alloc: into fresh outputs each call, "
          "like microlie; SE3.exp/log/exp_jac: native is the faster of the plain loop "
          "(lie_native.cpp) and the blocked loop (lie_blocked.c), both printed below")
    blocked = {"SE3.exp": native_call(blk, "se3_exp", [t6], [o[7]], "b_"),
               "SE3.log": native_call(blk, "se3_log", [X.params], [o[6]], "b_"),
               "SE3.exp_jac": native_call(blk, "se3_exp_jac", [t6], [o[7], j36], "b_")}
    print(f"{'op':16s} {'fast':>20s} {'generic':>20s} {'native':>20s} {'native+alloc':>20s} "
          f"{'fast/native':>11s} {'fast/n+alloc':>12s} {'generic/native':>14s} "
          f"{'generic/fast':>12s}")
    for name, fn, nat in cases:
        fns = {"fast": fn, "generic": generic(name, fn)}
        if nat is not None:
            fns["native"] = nat
            fns["native+alloc"] = nat.fresh
        if name in blocked:
            fns["blocked"], fns["blocked+alloc"] = blocked[name], blocked[name].fresh
        ts = interleaved(fns, rounds)
        s = {k: stat(t, 1e9 / n) for k, t in ts.items()}
        if name in blocked:
            print(f"  ({name}: plain {s['native'][0]:.1f} / {s['native+alloc'][0]:.1f}, "
                  f"blocked {s['blocked'][0]:.1f} / {s['blocked+alloc'][0]:.1f} ns)")
            for a in ("", "+alloc"):
                if s["blocked" + a][0] < s["native" + a][0]:
                    s["native" + a] = s["blocked" + a]
        cell = {k: f"{m:7.1f} [{a:6.1f},{b:6.1f}]" for k, (m, a, b) in s.items()}
        nat_m = s["native"][0] if "native" in s else float("nan")  # the faster native
        nal_m = s["native+alloc"][0] if "native" in s else float("nan")
        print(f"{name:16s} {cell['fast']:>20s} {cell['generic']:>20s} "
              f"{cell.get('native', '-'):>20s} {cell.get('native+alloc', '-'):>20s} "
              f"{s['fast'][0] / nat_m:11.2f} {s['fast'][0] / nal_m:12.2f} "
              f"{s['generic'][0] / nat_m:14.2f} {s['generic'][0] / s['fast'][0]:12.2f}")


def single(rounds: int) -> None:
    rng = np.random.default_rng(1)
    tau = rng.standard_normal(6) * 0.5
    X, Y = SE3.exp(tau), SE3.exp(rng.standard_normal(6))
    v = rng.standard_normal(3)
    ops = {"SE3.exp": (lambda: SE3.exp(tau)), "SE3.log": (lambda: X.log()),
           "SE3.compose": (lambda: X @ Y), "SE3.act": (lambda: X.act(v))}
    peers: dict = {}
    try:
        import gtsam

        gx, gy = gtsam.Pose3(X.matrix()), gtsam.Pose3(Y.matrix())
        gt = np.concatenate([tau[3:], tau[:3]])  # gtsam's tangent is (omega, v)
        peers = {"SE3.exp": lambda: gtsam.Pose3.Expmap(gt),
                 "SE3.log": lambda: gtsam.Pose3.Logmap(gx),
                 "SE3.compose": lambda: gx.compose(gy),
                 "SE3.act": lambda: gx.transformFrom(v)}
    except ImportError:
        print("(gtsam not importable: run in the bench venv for the gtsam column)")
    print(f"\none element, us per call, median [q1, q3] of {rounds} interleaved rounds")
    print(f"{'op':12s} {'fast':>20s} {'generic':>20s} {'gtsam':>20s} {'fast/gtsam':>10s}")
    for name, fn in ops.items():
        fns = {"fast": fn, "generic": generic(name, fn)}
        if name in peers:
            fns["gtsam"] = peers[name]
        ts = interleaved(fns, rounds, number=2000)
        s = {k: stat(t, 1e6) for k, t in ts.items()}
        cell = {k: f"{m:6.2f} [{a:5.2f},{b:5.2f}]" for k, (m, a, b) in s.items()}
        g = s["gtsam"][0] if "gtsam" in s else float("nan")
        print(f"{name:12s} {cell['fast']:>20s} {cell['generic']:>20s} "
              f"{cell.get('gtsam', '-'):>20s} {s['fast'][0] / g:10.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=7)
    a = ap.parse_args()
    print(f"load: {os.getloadavg()}, python {sys.version.split()[0]}")
    batched(a.n, a.rounds)
    single(a.rounds)


if __name__ == "__main__":
    main()
