"""microlie against a native C++ loop (benchmarks/native/lie_native.cpp), with and without the
compiled kernels (microlie._c), at N = 1e6 (batched) and on one element (against gtsam).

    PYTHONPATH=src python benchmarks/native.py [--n 1000000] [--rounds 7]

The C++ source is compiled in the run (g++ -O3 -march=native -fno-math-errno -fopenmp-simd,
glibc's libmvec) into a shared library called through ctypes on the same NumPy arrays, so that
the three variants are timed round-robin in one process ("fast" = compiled kernels, "generic" =
the NumPy kernels, same process with the replacements unregistered). Prints ns per element
(medians, with the interquartile spread) and the ratios microlie/native. One element: us per
call of the public API, values and with jac=True (exp, log, between with both Jacobians),
against gtsam's Pose3 binding when gtsam is importable (bench venv): Expmap(v, H), Logmap(p, H),
between(q, H1, H2).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from microlie import SE2, SE3, SE23, SO2, SO3, Sim3
from microlie import _kernels as K
from microlie.groups import _single

HERE = Path(__file__).parent
SRC = HERE / "native" / "lie_native.cpp"
BLOCKED = HERE / "native" / "lie_blocked.c"
FLAGS = ["-O3", "-march=native", "-fno-math-errno", "-fopenmp-simd", "-shared", "-fPIC"]

LIBMVEC_VECMATH = """#pragma once
#include <math.h>
#pragma omp declare simd notinbranch
extern double sin(double);
#pragma omp declare simd notinbranch
extern double cos(double);
#pragma omp declare simd notinbranch
extern double tan(double);
#pragma omp declare simd notinbranch
extern double atan2(double, double);
#pragma omp declare simd notinbranch
extern double exp(double);
#pragma omp declare simd notinbranch
extern double log(double);
#define LM_FN static inline __attribute__((always_inline, unused))
LM_FN double lm_sin(double x) { return sin(x); }
LM_FN double lm_cos(double x) { return cos(x + 0.0); }  /* no sincos merge (not vectorised) */
LM_FN double lm_tan(double x) { return tan(x); }
LM_FN double lm_atan2(double y, double x) { return atan2(y, x); }
LM_FN double lm_exp(double x) { return exp(x); }
LM_FN double lm_expm1(double x) { return expm1(x); }
LM_FN double lm_log(double x) { return log(x); }
"""


def build(blocked: bool = False) -> ctypes.CDLL:
    """The plain native loops (lie_native.cpp) or the blocked ones (lie_blocked.c)."""
    out = Path(tempfile.mkdtemp()) / "liblie_native.so"
    if blocked:
        # the reference keeps glibc's libmvec (the package links none: issue 21): a vecmath.h of
        # its own maps the generated kernels' lm_* functions to libm's, declared SIMD-callable
        tmp = out.parent
        (tmp / "vecmath.h").write_text(LIBMVEC_VECMATH)
        gen = HERE.parent / "src" / "microlie" / "_c" / "generated"
        cmd = ["gcc", *FLAGS, "-std=c11", "-fno-trapping-math", f"-I{tmp}", f"-I{gen}",
               str(BLOCKED)]
    else:
        cmd = ["g++", *FLAGS, str(SRC)]
    subprocess.run([*cmd, "-o", str(out), "-lmvec", "-lm"], check=True)
    return ctypes.CDLL(str(out))


def ptr(a: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(a.ctypes.data)


def native_fn(lib: ctypes.CDLL, name: str, ins: list[np.ndarray], shapes: list[tuple],
              fresh: bool):
    """The native loop ``name`` of ``lib`` on ``ins``: writing into outputs allocated once
    (warm pages, what a C++ program reusing its buffers gets) or, with ``fresh``, into new
    outputs on each call (what an API returning new arrays pays: the first touch of each page)."""
    f = getattr(lib, name)
    n = ctypes.c_long(len(ins[0]))
    pin = [ptr(a) for a in ins]
    warm = [np.empty(s) for s in shapes]
    for w in warm:
        w.fill(0.0)
    pw = [ptr(o) for o in warm]

    def call_warm():
        f(*pin, *pw, n)
        return warm

    def call_fresh():
        outs = [np.empty(s) for s in shapes]
        f(*pin, *[ptr(o) for o in outs], n)
        return outs
    return call_fresh if fresh else call_warm


def generic(name: str, fn, single: bool = False):
    """``fn`` with the compiled replacement of kernel ``name`` unregistered during the call (and,
    with ``single``, its compiled one-element function and, for an element operation, the
    compiled single-element path of the class: the traced Python code)."""
    k = K.KERNELS[name]
    group, op = name.split(".")
    cls = {"SE3": SE3, "SO3": SO3, "Sim3": Sim3, "SO2": SO2, "SE2": SE2, "SE23": SE23}[group]
    attr = f"_one_{op}"
    py_one = _single.build(cls).get(op) if single else None

    def call():
        impl, one, k.impl = k.impl, k.one, None
        saved = cls.__dict__.get(attr)
        if single:
            k.one = None
            if py_one is not None:
                setattr(cls, attr, staticmethod(py_one))
        try:
            return fn()
        finally:
            k.impl, k.one = impl, one
            if single and saved is not None:
                setattr(cls, attr, saved)
    return call


def uncached(fn):
    """``fn`` with the output cache of microlie._c._lie switched off (fresh pages every call)."""
    lie = sys.modules.get("microlie._c._lie")
    if lie is None or not hasattr(lie, "set_cache_limit"):
        return None

    def call():
        old = lie.set_cache_limit(0)
        try:
            return fn()
        finally:
            lie.set_cache_limit(old)
    return call


CLOCK = {"cpu": time.thread_time, "wall": time.perf_counter}
clock = time.thread_time
clock_name = "cpu"


def timed(fn, number: int = 1) -> float:
    gc.disable()
    try:
        t0 = clock()
        for _ in range(number):
            fn()
        return (clock() - t0) / number
    finally:
        gc.enable()


def interleaved(fns: dict, rounds: int, number: int = 1) -> dict:
    """Round-robin rounds; in each, every variant is called once untimed before its timed
    calls, so that each is measured in its steady state (e.g. microlie._c._lie's output cache,
    which another variant may have emptied, is refilled) rather than after its neighbour."""
    times: dict = {k: [] for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            f()
            times[k].append(timed(f, number))
    return times


def stat(ts: list[float], scale: float) -> tuple[float, float, float]:
    q = statistics.quantiles([t * scale for t in ts], n=4) if len(ts) > 1 else [ts[0] * scale] * 3
    return statistics.median(ts) * scale, q[0], q[2]


def batched(n: int, rounds: int, only: list[str] | None = None) -> None:
    lib, blk = build(), build(blocked=True)
    rng = np.random.default_rng(0)
    t3 = rng.standard_normal((n, 3))
    t6 = rng.standard_normal((n, 6))
    R, Q = SO3.exp(t3), SO3.exp(rng.standard_normal((n, 3)))
    X, Y = SE3.exp(t6), SE3.exp(rng.standard_normal((n, 6)))
    v = rng.standard_normal((n, 3))
    r, q, x, y = R.params, Q.params, X.params, Y.params
    z7 = rng.standard_normal((n, 7))
    S, U = Sim3.exp(z7), Sim3.exp(rng.standard_normal((n, 7)))
    s8, u8 = S.params, U.params
    t1, t9 = rng.standard_normal((n, 1)), rng.standard_normal((n, 9))
    A2, B2 = SE2.exp(t3), SE2.exp(rng.standard_normal((n, 3)))
    A9, B9 = SE23.exp(t9), SE23.exp(rng.standard_normal((n, 9)))
    a2, b2, a9, b9 = A2.params, B2.params, A9.params, B9.params
    # name, microlie's call, the kernel's inputs, native loops (plain n_, blocked b_)
    cases: list = [
        ("SO3.exp", lambda: SO3.exp(t3), [t3], ["n_"]),
        ("SO3.log", lambda: R.log(), [r], ["n_"]),
        ("SO3.compose", lambda: R @ Q, [r, q], ["n_"]),
        ("SO3.act", lambda: R.act(v), [r, v], ["n_"]),
        ("SE3.exp", lambda: SE3.exp(t6), [t6], ["n_", "b_"]),
        ("SE3.log", lambda: X.log(), [x], ["n_", "b_"]),
        ("SE3.compose", lambda: X @ Y, [x, y], ["n_"]),
        ("SE3.act", lambda: X.act(v), [x, v], ["n_"]),
        ("SO3.exp_jac", lambda: SO3.exp(t3, jac=True), [t3], ["n_"]),
        ("SO3.act_jac", lambda: R.act(v, jac=True), [r, v], ["n_"]),
        ("SO3.minus_jac", lambda: Q.minus(R, jac=True), [q, r], ["n_"]),
        ("SO3.between_jac", lambda: R.between(Q, jac=True), [r, q], ["n_"]),
        ("SE3.exp_jac", lambda: SE3.exp(t6, jac=True), [t6], ["n_", "b_"]),
        ("SE3.act_jac", lambda: X.act(v, jac=True), [x, v], ["n_"]),
        ("SE3.minus_jac", lambda: Y.minus(X, jac=True), [y, x], ["n_", "b_"]),
        ("SE3.between_jac", lambda: X.between(Y, jac=True), [x, y], ["n_", "b_"]),
        # Sim3: no native loop (fast against the generic NumPy kernels only)
        ("Sim3.exp", lambda: Sim3.exp(z7), [z7], []),
        ("Sim3.log", lambda: S.log(), [s8], []),
        ("Sim3.compose", lambda: S @ U, [s8, u8], []),
        ("Sim3.act", lambda: S.act(v), [s8, v], []),
        ("Sim3.jr", lambda: Sim3.jr(z7), [z7], []),
        ("Sim3.jr_inv", lambda: Sim3.jr_inv(z7), [z7], []),
        ("Sim3.minus_jac", lambda: U.minus(S, jac=True), [u8, s8], []),
        # SO2, SE2, SE_2(3): no native loop either
        ("SO2.exp", lambda: SO2.exp(t1), [t1], []),
        ("SE2.exp", lambda: SE2.exp(t3), [t3], []),
        ("SE2.compose", lambda: A2 @ B2, [a2, b2], []),
        ("SE2.minus_jac", lambda: B2.minus(A2, jac=True), [b2, a2], []),
        ("SE23.exp", lambda: SE23.exp(t9), [t9], []),
        ("SE23.compose", lambda: A9 @ B9, [a9, b9], []),
        ("SE23.act", lambda: A9.act(v), [a9, v], []),
    ]
    fast_on = K.KERNELS["SE3.exp"].impl is not None
    print(f"batched, N = {n}, ns per element ({clock_name} time), median [q1, q3] of {rounds} "
          f"interleaved rounds; compiled kernels {'registered' if fast_on else 'NOT registered'}")
    print("fast: microlie with its compiled kernels (output cache on); fast-nc: the same with "
          "the cache off; generic: the NumPy kernels; native: the faster C loop (plain "
          "lie_native.cpp or blocked lie_blocked.c) into outputs allocated once; native+a: "
          "the same loop into fresh outputs each call (both agree with microlie to 1e-9, checked)")
    cols = ["fast", "fast-nc", "generic", "native", "native+a"]
    print(f"{'op':16s} " + " ".join(f"{c:>21s}" for c in cols)
          + f" {'fast/nat':>8s} {'fast/nat+a':>10s} {'fast-nc/nat':>11s} {'gen/nat':>8s}")
    for name, fn, ins, variants in cases:
        if only and name not in only:
            continue
        k = K.KERNELS[name]
        want = K.run(k, *ins)
        want = want if isinstance(want, tuple) else (want,)
        shapes = [(n, int(np.prod(w.shape[1:]))) for w in want]
        base = name.lower().replace(".", "_")
        best = None
        fns = {"fast": fn, "fast-nc": uncached(fn), "generic": generic(name, fn)}
        for pre in variants:
            lb = lib if pre == "n_" else blk
            f = native_fn(lb, pre + base, ins, shapes, fresh=False)
            for g, w in zip(f(), want, strict=True):  # the native loop computes the same thing
                err = float(np.abs(g - w.reshape(n, -1)).max())
                assert err < 1e-9, f"native {pre}{base} disagrees with microlie: {err:.2e}"
            t = statistics.median(timed(f) for _ in range(3))
            if best is None or t < best[0]:
                best = (t, lb, pre)
        if best is not None:
            fns["native"] = native_fn(best[1], best[2] + base, ins, shapes, fresh=False)
            fns["native+a"] = native_fn(best[1], best[2] + base, ins, shapes, fresh=True)
        fns = {c: f for c, f in fns.items() if f is not None}
        ts = interleaved(fns, rounds)
        s = {c: stat(t, 1e9 / n) for c, t in ts.items()}
        cell = {c: f"{m:7.1f} [{a:6.1f},{b:6.1f}]" for c, (m, a, b) in s.items()}
        m = {c: v[0] for c, v in s.items()}
        nan = float("nan")
        nat, nat_a, nc = m.get("native", nan), m.get("native+a", nan), m.get("fast-nc", nan)
        label = name + ("*" if best is not None and best[2] == "b_" else "")
        print(f"{label:16s} " + " ".join(f"{cell.get(c, '-'):>21s}" for c in cols)
              + f" {m['fast'] / nat:8.2f} {m['fast'] / nat_a:10.2f}"
              f" {nc / nat:11.2f} {m['generic'] / nat:8.2f}"
              + ("" if best else f"   generic/fast {m['generic'] / m['fast']:.2f}"))
    print("(* = the blocked native loop was the faster)")


def single(rounds: int) -> None:
    rng = np.random.default_rng(1)
    tau = rng.standard_normal(6) * 0.5
    X, Y = SE3.exp(tau), SE3.exp(rng.standard_normal(6))
    v = rng.standard_normal(3)
    ops = {"SE3.exp": (lambda: SE3.exp(tau)), "SE3.log": (lambda: X.log()),
           "SE3.compose": (lambda: X @ Y), "SE3.act": (lambda: X.act(v)),
           "SE3.exp_jac": (lambda: SE3.exp(tau, jac=True)),
           "SE3.log_jac": (lambda: X.log(jac=True)),
           "SE3.between_jac": (lambda: X.between(Y, jac=True))}
    peers: dict = {}
    try:
        import gtsam

        gx, gy = gtsam.Pose3(X.matrix()), gtsam.Pose3(Y.matrix())
        gt = np.concatenate([tau[3:], tau[:3]])  # gtsam's tangent is (omega, v)
        H, H1, H2 = (np.zeros((6, 6), order="F") for _ in range(3))  # gtsam's Jacobian outputs
        peers = {"SE3.exp": lambda: gtsam.Pose3.Expmap(gt),
                 "SE3.log": lambda: gtsam.Pose3.Logmap(gx),
                 "SE3.compose": lambda: gx.compose(gy),
                 "SE3.act": lambda: gx.transformFrom(v),
                 "SE3.exp_jac": lambda: gtsam.Pose3.Expmap(gt, H),
                 "SE3.log_jac": lambda: gtsam.Pose3.Logmap(gx, H),
                 "SE3.between_jac": lambda: gx.between(gy, H1, H2)}
    except ImportError:
        print("(gtsam not importable: run in the bench venv for the gtsam column)")
    print(f"\none element, us per call, median [q1, q3] of {rounds} interleaved rounds")
    print(f"{'op':12s} {'fast':>20s} {'generic':>20s} {'gtsam':>20s} {'fast/gtsam':>10s}")
    for name, fn in ops.items():
        fns = {"fast": fn, "generic": generic(name, fn, single=True)}
        if name in peers:
            fns["gtsam"] = peers[name]
        ts = interleaved(fns, rounds, number=2000)
        s = {k: stat(t, 1e6) for k, t in ts.items()}
        cell = {k: f"{m:6.2f} [{a:5.2f},{b:5.2f}]" for k, (m, a, b) in s.items()}
        g = s["gtsam"][0] if "gtsam" in s else float("nan")
        print(f"{name:12s} {cell['fast']:>20s} {cell['generic']:>20s} "
              f"{cell.get('gtsam', '-'):>20s} {s['fast'][0] / g:10.2f}")


def main() -> None:
    global clock, clock_name
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--clock", choices=sorted(CLOCK), default="cpu",
                    help="cpu: the thread's CPU time (user + system, page faults included; "
                    "robust to other processes on a loaded machine); wall: elapsed time")
    ap.add_argument("--only", nargs="*", help="operations to run (e.g. SE3.compose)")
    ap.add_argument("--no-single", action="store_true", help="skip the one-element table")
    a = ap.parse_args()
    clock, clock_name = CLOCK[a.clock], a.clock
    print(f"load: {tuple(round(x, 2) for x in os.getloadavg())}, python "
          f"{sys.version.split()[0]}, numpy {np.__version__}")
    batched(a.n, a.rounds, a.only)
    if not a.no_single:
        single(a.rounds)


if __name__ == "__main__":
    main()
