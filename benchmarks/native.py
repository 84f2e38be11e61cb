"""microlie against a native C++ loop (benchmarks/native/lie_native.cpp), with and without the
compiled kernels (microlie._c), at N = 1e6 (batched) and on one element (against gtsam), for
every group: SO2, SE2, SO3, SE3, Sim3, SE23.

    PYTHONPATH=src python benchmarks/native.py [--n 1000000] [--rounds 7]

The C++ source is compiled in the run (g++ -O3 -march=native -fno-math-errno -fopenmp-simd,
glibc's libmvec) into a shared library called through ctypes on the same NumPy arrays, so that
the three variants are timed round-robin in one process ("fast" = compiled kernels, "generic" =
the NumPy kernels, same process with the replacements unregistered). The native loops are
written from MATH.md (plain loops, lie_native.cpp) or are the generated element functions in
blocks (lie_blocked.c); the faster one is the reference, after checking that it agrees with
microlie to 1e-9. Prints ns per element (medians, with the interquartile spread) and the ratios
microlie/native. One element: us per call of the public API, values (exp, log, compose, act)
and with jac=True (exp, log, between with both Jacobians), against gtsam's binding when gtsam
is importable (bench venv): Rot2, Pose2, Rot3, Pose3, Similarity3, NavState; Expmap(v, H),
Logmap(p, H), between(q, H1, H2) where the binding has them; gtsam's results are checked equal
to microlie's (1e-9, tangents and Jacobians permuted to microlie's translation-first order)
before timing.
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
    v2 = rng.standard_normal((n, 2))
    R2, Q2 = SO2.exp(t1), SO2.exp(rng.standard_normal((n, 1)))
    A2, B2 = SE2.exp(t3), SE2.exp(rng.standard_normal((n, 3)))
    A9, B9 = SE23.exp(t9), SE23.exp(rng.standard_normal((n, 9)))
    r2, q2, a2, b2, a9, b9 = R2.params, Q2.params, A2.params, B2.params, A9.params, B9.params
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
        ("SO2.exp", lambda: SO2.exp(t1), [t1], ["n_"]),
        ("SO2.log", lambda: R2.log(), [r2], ["n_"]),
        ("SO2.compose", lambda: R2 @ Q2, [r2, q2], ["n_"]),
        ("SO2.act", lambda: R2.act(v2), [r2, v2], ["n_"]),
        ("SO2.exp_jac", lambda: SO2.exp(t1, jac=True), [t1], ["n_"]),
        ("SO2.act_jac", lambda: R2.act(v2, jac=True), [r2, v2], ["n_"]),
        ("SO2.minus_jac", lambda: Q2.minus(R2, jac=True), [q2, r2], ["n_"]),
        ("SO2.between_jac", lambda: R2.between(Q2, jac=True), [r2, q2], ["n_"]),
        ("SE2.exp", lambda: SE2.exp(t3), [t3], ["n_"]),
        ("SE2.log", lambda: A2.log(), [a2], ["n_"]),
        ("SE2.compose", lambda: A2 @ B2, [a2, b2], ["n_"]),
        ("SE2.act", lambda: A2.act(v2), [a2, v2], ["n_"]),
        ("SE2.exp_jac", lambda: SE2.exp(t3, jac=True), [t3], ["n_"]),
        ("SE2.act_jac", lambda: A2.act(v2, jac=True), [a2, v2], ["n_"]),
        ("SE2.minus_jac", lambda: B2.minus(A2, jac=True), [b2, a2], ["n_"]),
        ("SE2.between_jac", lambda: A2.between(B2, jac=True), [a2, b2], ["n_"]),
        # Sim3 exp_jac and minus_jac: the blocked loop only (no hand-written native Jacobian)
        ("Sim3.exp", lambda: Sim3.exp(z7), [z7], ["n_", "b_"]),
        ("Sim3.log", lambda: S.log(), [s8], ["n_", "b_"]),
        ("Sim3.compose", lambda: S @ U, [s8, u8], ["n_"]),
        ("Sim3.act", lambda: S.act(v), [s8, v], ["n_"]),
        ("Sim3.exp_jac", lambda: Sim3.exp(z7, jac=True), [z7], ["b_"]),
        ("Sim3.act_jac", lambda: S.act(v, jac=True), [s8, v], ["n_"]),
        ("Sim3.minus_jac", lambda: U.minus(S, jac=True), [u8, s8], ["b_"]),
        ("Sim3.between_jac", lambda: S.between(U, jac=True), [s8, u8], ["n_", "b_"]),
        ("SE23.exp", lambda: SE23.exp(t9), [t9], ["n_", "b_"]),
        ("SE23.log", lambda: A9.log(), [a9], ["n_", "b_"]),
        ("SE23.compose", lambda: A9 @ B9, [a9, b9], ["n_"]),
        ("SE23.act", lambda: A9.act(v), [a9, v], ["n_"]),
        ("SE23.exp_jac", lambda: SE23.exp(t9, jac=True), [t9], ["n_", "b_"]),
        ("SE23.act_jac", lambda: A9.act(v, jac=True), [a9, v], ["n_"]),
        ("SE23.minus_jac", lambda: B9.minus(A9, jac=True), [b9, a9], ["n_", "b_"]),
        ("SE23.between_jac", lambda: A9.between(B9, jac=True), [a9, b9], ["n_", "b_"]),
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


# gtsam's class of each group, and ours[i] = gtsam's tangent[PERM[i]] (gtsam: rotation first)
GTSAM = {"SO2": "Rot2", "SE2": "Pose2", "SO3": "Rot3", "SE3": "Pose3", "Sim3": "Similarity3",
         "SE23": "NavState"}
PERM = {"SE3": [3, 4, 5, 0, 1, 2], "Sim3": [3, 4, 5, 0, 1, 2, 6],
        "SE23": [3, 4, 5, 0, 1, 2, 6, 7, 8]}
# what gtsam's Python binding does not offer: timed against gtsam's call without Jacobians
# (marked "v": a stricter comparison), or not at all ("-")
NO_GTSAM = {
    "SO2.between_jac": "v: Rot2.between has no Jacobian arguments in the binding",
    "SO3.between_jac": "v: Rot3.between has no Jacobian arguments in the binding",
    "Sim3.exp_jac": "v: Similarity3.Expmap has no Jacobian argument in the binding",
    "Sim3.log_jac": "v: Similarity3.Logmap has no Jacobian argument in the binding",
    "Sim3.between_jac": "v: Similarity3.between has no Jacobian arguments in the binding",
    "SE23.between_jac": "v: NavState.between has no Jacobian arguments in the binding",
    "SE23.act": "NavState has no action on points (ours: the pose part, R x + p)",
}
VALUE_ONLY = {"exp_jac": "exp", "log_jac": "log", "between_jac": "between"}


def gtsam_of(gtsam, G, X):
    """gtsam's element equal to microlie's ``X`` of group ``G``."""
    name = G.__name__
    if name == "SO2":
        return gtsam.Rot2.fromCosSin(*X.params)
    if name == "SE2":
        x, y, c, s = X.params
        return gtsam.Pose2(x, y, np.arctan2(s, c))
    M = X.matrix()
    if name == "SO3":
        return gtsam.Rot3(M)
    if name == "SE3":
        return gtsam.Pose3(M)
    if name == "Sim3":  # ours [[s R, t], [0, 1]] = s [[R, t / s], [0, 1 / s]] (gtsam's matrix)
        s = X.params[7]
        return gtsam.Similarity3(gtsam.Rot3(M[:3, :3] / s), M[:3, 3] / s, s)
    return gtsam.NavState(gtsam.Rot3(M[:3, :3]), M[:3, 3], M[:3, 4])  # SE23


def matrix_of(G, g) -> np.ndarray:
    """microlie's matrix of gtsam's element ``g`` of (the counterpart of) group ``G``."""
    name = G.__name__
    if name == "Sim3":
        M = g.matrix()
        return M / M[3, 3]
    if name == "SE23":
        M = np.eye(5)
        M[:3, :3], M[:3, 3], M[:3, 4] = g.attitude().matrix(), g.position(), g.velocity()
        return M
    return np.asarray(g.matrix())


def single_cases(G, gtsam, rng):
    """(ours, gtsam's, check) per operation of group ``G``: exp, log, compose, act and with
    Jacobians exp, log, between; ``check()`` compares the two results (1e-9) in our
    conventions."""
    name = G.__name__
    tau = rng.standard_normal(G.dof) * 0.5
    X, Y = G.exp(tau), G.exp(rng.standard_normal(G.dof) * 0.5)
    v = rng.standard_normal(G.point_dim)
    ours = {"exp": lambda: G.exp(tau), "log": lambda: X.log(), "compose": lambda: X @ Y,
            "act": lambda: X.act(v), "exp_jac": lambda: G.exp(tau, jac=True),
            "log_jac": lambda: X.log(jac=True), "between_jac": lambda: X.between(Y, jac=True)}
    out = {f"{name}.{op}": (f, None, None) for op, f in ours.items()}
    if gtsam is None:
        return out
    C = getattr(gtsam, GTSAM[name])
    perm = PERM.get(name, list(range(G.dof)))
    P = np.eye(G.dof)[perm]  # ours = P gtsam's
    gt = P.T @ tau
    gx, gy = gtsam_of(gtsam, G, X), gtsam_of(gtsam, G, Y)
    d = G.dof
    H, H1, H2 = (np.zeros((d, d), order="F") for _ in range(3))
    act = {"SO2": "rotate", "SO3": "rotate"}.get(name, "transformFrom")
    peers = {"exp": lambda: C.Expmap(gt), "log": lambda: C.Logmap(gx),
             "compose": lambda: gx.compose(gy), "act": lambda: getattr(gx, act)(v),
             "between": lambda: gx.between(gy),
             "exp_jac": lambda: C.Expmap(gt, H), "log_jac": lambda: C.Logmap(gx, H),
             "between_jac": lambda: gx.between(gy, H1, H2)}

    def mat(g):
        return matrix_of(G, g)

    def jac(J):
        return P @ J @ P.T
    checks = {
        "exp": lambda a, b: [(a.matrix(), mat(b))],
        "log": lambda a, b: [(a, P @ np.ravel(b))],
        "compose": lambda a, b: [(a.matrix(), mat(b))],
        "between": lambda a, b: [(a.matrix(), mat(b))],
        "act": lambda a, b: [(a, b)],
        "exp_jac": lambda a, b: [(a[0].matrix(), mat(b)), (a[1], jac(H))],
        "log_jac": lambda a, b: [(a[0], P @ np.ravel(b)), (a[1], jac(H))],
        "between_jac": lambda a, b: [(a[0].matrix(), mat(b)), (a[1], jac(H1)), (a[2], jac(H2))],
    }
    for op, f in ours.items():
        key = f"{name}.{op}"
        if key not in NO_GTSAM:
            out[key] = (f, peers[op], checks[op])
        elif op in VALUE_ONLY:  # the value part checked, gtsam's call without Jacobians timed
            base = VALUE_ONLY[op]
            out[key] = (f, peers[base], lambda a, b, base=base: checks[base](a[0], b))
    return out


def single(rounds: int, groups: list[str] | None = None) -> None:
    try:
        import gtsam
    except ImportError:
        gtsam = None
        print("(gtsam not importable: run in the bench venv for the gtsam column)")
    rng = np.random.default_rng(1)
    print(f"\none element, us per call, median [q1, q3] of {rounds} interleaved rounds; "
          "gtsam: Rot2, Pose2, Rot3, Pose3, Similarity3, NavState (values and Jacobians checked "
          "equal to microlie's to 1e-9 in microlie's conventions before timing); 'v': gtsam's "
          "binding has no Jacobian form, its call without Jacobians is timed")
    print(f"{'op':18s} {'fast':>20s} {'generic':>20s} {'gtsam':>20s} {'fast/gtsam':>10s}")
    for G in (SO2, SE2, SO3, SE3, Sim3, SE23):
        if groups and G.__name__ not in groups:
            continue
        for name, (fn, peer, check) in single_cases(G, gtsam, rng).items():
            fns = {"fast": fn, "generic": generic(name, fn, single=True)}
            if peer is not None:
                for a, b in check(fn(), peer()):
                    err = float(np.abs(np.asarray(a) - np.asarray(b)).max())
                    assert err < 1e-9, f"{name}: gtsam and microlie disagree by {err:.2e}"
                fns["gtsam"] = peer
            ts = interleaved(fns, rounds, number=2000)
            st = {k: stat(t, 1e6) for k, t in ts.items()}
            cell = {k: f"{m:6.2f} [{a:5.2f},{b:5.2f}]" for k, (m, a, b) in st.items()}
            g = st["gtsam"][0] if "gtsam" in st else float("nan")
            why = f"   ({NO_GTSAM[name]})" if name in NO_GTSAM else ""
            if name in NO_GTSAM and peer is not None:
                name += " v"
            print(f"{name:18s} {cell['fast']:>20s} {cell['generic']:>20s} "
                  f"{cell.get('gtsam', '-'):>20s} {st['fast'][0] / g:10.2f}{why}")


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
    ap.add_argument("--no-batched", action="store_true", help="skip the batched table")
    ap.add_argument("--groups", nargs="*", help="groups of the one-element table (e.g. Sim3)")
    a = ap.parse_args()
    clock, clock_name = CLOCK[a.clock], a.clock
    print(f"load: {tuple(round(x, 2) for x in os.getloadavg())}, python "
          f"{sys.version.split()[0]}, numpy {np.__version__}")
    if not a.no_batched:
        batched(a.n, a.rounds, a.only)
    if not a.no_single:
        single(a.rounds, a.groups)


if __name__ == "__main__":
    main()
