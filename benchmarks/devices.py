"""Least-squares solves on arrays and devices: microlie (NumPy/C engine; JAX and torch engines
where they are built) against jaxls, PyPose's ``pp.optim.LM`` and Theseus, in one run,
interleaved (issue 24).

Run (the peers' environment ``$PEERS_VENV``, built as ``benchmarks/README.md`` says;
microlie from ``src``):

    PYTHONPATH=src "$PEERS_VENV"/bin/python benchmarks/devices.py --rounds 5 \
        --out benchmarks/results/devices-s12.md

The problems, built identically for every contender from one seeded generator:

* ``posegraph``: a batch of ``--batch`` (1000) SE(3) pose graphs of 10 poses (9 odometry edges,
  3 loop closures at the same poses in every problem, diagonal noise, a prior on pose 0), each
  started from its ground truth perturbed by about 0.3 m and 0.1 rad;
* ``pnp``: a batch of ``--batch`` (1000) PnP problems (pinhole camera, ``--pnp-points`` (40)
  known world points, 1 px noise), each started from its ground-truth pose perturbed by about
  0.2 m and 0.05 rad;
* ``bal``: BAL problem-49-7776 (Ladybug-49; ``--bal``), 30 Levenberg-Marquardt iterations as
  in jaxls's published figure, BAL camera model, points behind a camera evaluated.

Every cost is ``0.5 * sum |W r|^2`` with the same residuals (``Log(Z^-1 X_i^-1 X_j)``,
translation first, for the pose graphs; ``project(R X + t) - uv`` for the cameras), evaluated
by one NumPy function in this file on the values each contender returns, so a contender whose
solve stopped short shows it: the table prints the largest relative excess over the NumPy
engine's optimum (per problem for the batches).

Each contender is the solve a user of that library would write: its own LM, its default
linear solver unless it documents a better one (stated in the table), squared loss; the batch
rows share one stop rule (``--max-iter``, ``--rel-tol``, ``--abs-tol``: GTSAM's defaults) given
to every contender that has the knob, and each row reports the iterations it ran. Timing:
``setup`` (building the library's problem objects, analysis) once; ``first call`` (includes
JIT / ``torch.compile`` compilation) once; then ``--rounds`` interleaved rounds (the order
rotated each round) of the steady-state solve, reported as median (min-max) with the median
of the per-round ratios to the microlie rows. All on one thread (``torch.set_num_threads(1)``,
XLA's CPU thread pool off, BLAS at one thread), float64.

``--device cuda`` places the JAX and torch contenders' arrays on the first GPU and runs the
same code; it has not been run here (no GPU on this machine): its goals (Ladybug-49 in at most
0.08 s for 30 iterations, at least 5x over the CPU engine) are unmeasured.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_BAL = ROOT / ".." / "shared" / "data" / "bal" / "problem-49-7776-pre.txt"


# ------------------------------------------------------------------------------- numpy helpers
# Independent NumPy formulas (not microlie's kernels) for the shared cost and the conversions.

def hat(w: np.ndarray) -> np.ndarray:
    """``(..., 3)`` -> ``(..., 3, 3)`` skew matrices."""
    z = np.zeros(w.shape[:-1])
    return np.stack([np.stack([z, -w[..., 2], w[..., 1]], -1),
                     np.stack([w[..., 2], z, -w[..., 0]], -1),
                     np.stack([-w[..., 1], w[..., 0], z], -1)], -2)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: ``(..., 3)`` rotation vectors -> ``(..., 3, 3)`` matrices."""
    t = np.linalg.norm(w, axis=-1)[..., None, None]
    small = t < 1e-2                                     # Taylor series to t^4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t**2 / 6 + t**4 / 120, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t**2 / 24 + t**4 / 720, (1 - np.cos(ts)) / ts**2)
    K = hat(w)
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` -> rotation vectors (angles well below pi here)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1) / 2
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], -1)           # 2 sin(t) axis
    t = np.arctan2(0.5 * np.linalg.norm(v, axis=-1), c)
    small = t < 1e-2
    f = np.where(small, 0.5 + t**2 / 12 + 7 * t**4 / 720,
                 t / (2 * np.sin(np.where(small, 1.0, t))))
    return f[..., None] * v


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """``(..., 6)`` tangent ``[rho, phi]`` -> ``(..., 4, 4)`` matrices."""
    rho, phi = xi[..., :3], xi[..., 3:]
    t = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = t < 1e-2
    ts = np.where(small, 1.0, t)
    b = np.where(small, 0.5 - t**2 / 24 + t**4 / 720, (1 - np.cos(ts)) / ts**2)
    c = np.where(small, 1 / 6 - t**2 / 120 + t**4 / 5040, (ts - np.sin(ts)) / ts**3)
    K = hat(phi)
    V = np.eye(3) + b * K + c * (K @ K)
    T = np.zeros((*xi.shape[:-1], 4, 4))
    T[..., :3, :3] = so3_exp(phi)
    T[..., :3, 3] = (V @ rho[..., None])[..., 0]
    T[..., 3, 3] = 1.0
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` -> tangent ``[rho, phi]`` (translation first)."""
    phi = so3_log(T[..., :3, :3])
    t = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = t < 1e-2
    ts = np.where(small, 1.0, t)
    K = hat(phi)
    # V^-1 = I - K/2 + (1/t^2)(1 - t sin t / (2 (1 - cos t))) K^2
    d = np.where(small, 1 / 12 + t**2 / 720 + t**4 / 30240,
                 (1 - ts * np.sin(ts) / (2 * (1 - np.cos(ts)))) / ts**2)
    Vi = np.eye(3) - 0.5 * K + d * (K @ K)
    rho = (Vi @ T[..., :3, 3:4])[..., 0]
    return np.concatenate([rho, phi], -1)


def se3_inv(T: np.ndarray) -> np.ndarray:
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ t[..., None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def quat_xyzw_from_matrix(R: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` -> unit quaternions ``(x, y, z, w)``, ``w >= 0`` (Shepperd)."""
    m = R.reshape(-1, 3, 3)
    q = np.empty((m.shape[0], 4))
    tr = np.trace(m, axis1=1, axis2=2)
    d = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], tr], 1)
    k = np.argmax(d, 1)
    for i in range(m.shape[0]):
        a = m[i]
        if k[i] == 3:
            s = 2 * np.sqrt(1 + tr[i])
            q[i] = [(a[2, 1] - a[1, 2]) / s, (a[0, 2] - a[2, 0]) / s, (a[1, 0] - a[0, 1]) / s,
                    s / 4]
        else:
            j, l_, m_ = k[i], (k[i] + 1) % 3, (k[i] + 2) % 3
            s = 2 * np.sqrt(1 + a[j, j] - a[l_, l_] - a[m_, m_])
            v = np.empty(4)
            v[j] = s / 4
            v[l_] = (a[l_, j] + a[j, l_]) / s
            v[m_] = (a[m_, j] + a[j, m_]) / s
            v[3] = (a[m_, l_] - a[l_, m_]) / s
            q[i] = v
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q.reshape(*R.shape[:-2], 4)


def matrix_from_quat_xyzw(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def params_from_matrix(T: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` -> ``(..., 7)`` ``[t, qx, qy, qz, qw]`` (microlie's and PyPose's)."""
    return np.concatenate([T[..., :3, 3], quat_xyzw_from_matrix(T[..., :3, :3])], -1)


def matrix_from_params(p: np.ndarray) -> np.ndarray:
    T = np.zeros((*p.shape[:-1], 4, 4))
    T[..., :3, :3] = matrix_from_quat_xyzw(p[..., 3:])
    T[..., :3, 3] = p[..., :3]
    T[..., 3, 3] = 1.0
    return T


# ---------------------------------------------------------------------------------- problems

@dataclasses.dataclass
class PoseGraphBatch:
    """``B`` SE(3) pose graphs of the same structure (matrices ``(B, n, 4, 4)``)."""
    edges: np.ndarray          # (E, 2) int: (i, j), the same in every problem
    Z: np.ndarray              # (B, E, 4, 4) measured X_i^-1 X_j
    w_edge: np.ndarray         # (6,) sqrt-information diagonal of every edge, [rho, phi]
    Z0: np.ndarray             # (B, 4, 4) prior on pose 0
    w_prior: np.ndarray        # (6,)
    X0: np.ndarray             # (B, n, 4, 4) start
    truth: np.ndarray          # (B, n, 4, 4)

    @property
    def batch(self) -> int:
        return self.Z.shape[0]

    @property
    def n(self) -> int:
        return self.X0.shape[1]


def make_pose_graphs(batch: int, seed: int, n: int = 10, loops: int = 3) -> PoseGraphBatch:
    """Random walks of ``n`` poses (1 m steps, turns of about 0.15 rad), odometry plus ``loops``
    closures between poses at least 3 apart (chosen once: the same structure in every problem),
    measurements with 5 cm / 0.02 rad noise, a 1 cm / 0.01 rad prior on pose 0, start = truth
    perturbed by 0.3 m / 0.1 rad (pose 0 too)."""
    rng = np.random.default_rng(seed)
    steps = np.concatenate([np.array([1.0, 0, 0]) + 0.2 * rng.standard_normal((batch, n - 1, 3)),
                            0.15 * rng.standard_normal((batch, n - 1, 3))], -1)
    truth = np.empty((batch, n, 4, 4))
    truth[:, 0] = np.eye(4)
    S = se3_exp(steps)
    for i in range(1, n):
        truth[:, i] = truth[:, i - 1] @ S[:, i - 1]
    pairs = [(i, j) for i in range(n) for j in range(i + 3, n)]
    pick = rng.choice(len(pairs), size=loops, replace=False)
    edges = np.array([(i, i + 1) for i in range(n - 1)] + [pairs[k] for k in sorted(pick)])
    sig = np.array([0.05, 0.05, 0.05, 0.02, 0.02, 0.02])
    sig0 = np.full(6, 0.01)
    rel = se3_inv(truth[:, edges[:, 0]]) @ truth[:, edges[:, 1]]
    Z = rel @ se3_exp(sig * rng.standard_normal((batch, len(edges), 6)))
    Z0 = truth[:, 0] @ se3_exp(sig0 * rng.standard_normal((batch, 6)))
    X0 = truth @ se3_exp(np.concatenate([0.3 * rng.standard_normal((batch, n, 3)),
                                         0.1 * rng.standard_normal((batch, n, 3))], -1))
    return PoseGraphBatch(edges, Z, 1 / sig, Z0, 1 / sig0, X0, truth)


def pose_graph_costs(p: PoseGraphBatch, X: np.ndarray) -> np.ndarray:
    """``(B,)`` costs ``0.5 sum |W Log(Z^-1 X_i^-1 X_j)|^2 + 0.5 |W0 Log(Z0^-1 X_0)|^2``."""
    e = se3_log(se3_inv(p.Z) @ se3_inv(X[:, p.edges[:, 0]]) @ X[:, p.edges[:, 1]]) * p.w_edge
    e0 = se3_log(se3_inv(p.Z0) @ X[:, 0]) * p.w_prior
    return 0.5 * (np.sum(e**2, axis=(1, 2)) + np.sum(e0**2, axis=1))


@dataclasses.dataclass
class PnPBatch:
    """``B`` PnP problems: world points, pixels, a pinhole ``K`` and world-to-camera poses."""
    points: np.ndarray         # (B, m, 3) world points (known)
    uv: np.ndarray             # (B, m, 2) observed pixels
    K: np.ndarray              # (4,) fx, fy, cx, cy
    T0: np.ndarray             # (B, 4, 4) start T_cw
    truth: np.ndarray          # (B, 4, 4)

    @property
    def batch(self) -> int:
        return self.uv.shape[0]


def make_pnp(batch: int, seed: int, m: int = 40) -> PnPBatch:
    """Points at depths 4-10 m inside a 60-degree field of view of a random camera pose,
    1 px pixel noise; start = truth perturbed by 0.2 m / 0.05 rad."""
    rng = np.random.default_rng(seed + 1)
    K = np.array([500.0, 500.0, 320.0, 240.0])
    z = rng.uniform(4.0, 10.0, (batch, m))
    xy = rng.uniform(-0.55, 0.55, (batch, m, 2)) * z[..., None]
    Pc = np.concatenate([xy, z[..., None]], -1)
    T_wc = se3_exp(np.concatenate([3.0 * rng.standard_normal((batch, 3)),
                                   rng.uniform(-np.pi, np.pi, (batch, 1))
                                   * _unit(rng.standard_normal((batch, 3)))], -1))
    Xw = (T_wc[:, None, :3, :3] @ Pc[..., None])[..., 0] + T_wc[:, None, :3, 3]
    uv = project_pinhole(Pc, K) + rng.standard_normal((batch, m, 2))
    truth = se3_inv(T_wc)
    T0 = truth @ se3_exp(np.concatenate([0.2 * rng.standard_normal((batch, 3)),
                                         0.05 * rng.standard_normal((batch, 3))], -1))
    return PnPBatch(Xw, uv, K, T0, truth)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def project_pinhole(P: np.ndarray, K: np.ndarray) -> np.ndarray:
    return np.stack([K[0] * P[..., 0] / P[..., 2] + K[2], K[1] * P[..., 1] / P[..., 2] + K[3]],
                    -1)


def pnp_costs(p: PnPBatch, T: np.ndarray) -> np.ndarray:
    P = (T[:, None, :3, :3] @ p.points[..., None])[..., 0] + T[:, None, :3, 3]
    return 0.5 * np.sum((project_pinhole(P, p.K) - p.uv) ** 2, axis=(1, 2))


@dataclasses.dataclass
class BAL:
    """A BAL file's arrays (cameras ``[rotvec, t, f, k1, k2]``)."""
    cameras: np.ndarray        # (nc, 9)
    points: np.ndarray         # (np, 3)
    cam: np.ndarray            # (m,) int
    pt: np.ndarray             # (m,) int
    uv: np.ndarray             # (m, 2)
    iterations: int = 30


def read_bal_arrays(path: Path) -> BAL:
    with open(path) as f:
        nc, npt, m = (int(x) for x in f.readline().split())
        obs = np.loadtxt(f, max_rows=m)
        rest = np.loadtxt(f).ravel()
    return BAL(rest[:9 * nc].reshape(nc, 9).copy(), rest[9 * nc:].reshape(npt, 3).copy(),
               obs[:, 0].astype(np.int64), obs[:, 1].astype(np.int64), obs[:, 2:4].copy())


def bal_residuals(b: BAL, cameras: np.ndarray, points: np.ndarray) -> np.ndarray:
    c = cameras[b.cam]
    P = (so3_exp(c[:, :3]) @ points[b.pt][..., None])[..., 0] + c[:, 3:6]
    x = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(x**2, -1, keepdims=True)
    return c[:, 6:7] * (1 + c[:, 7:8] * r2 + c[:, 8:9] * r2**2) * x - b.uv


def bal_cost(b: BAL, cameras: np.ndarray, points: np.ndarray) -> float:
    return float(0.5 * np.sum(bal_residuals(b, cameras, points) ** 2))


# ------------------------------------------------------------------------------- contenders

@dataclasses.dataclass
class Contender:
    """A prepared solve: ``run()`` returns the solution as NumPy (pose matrices, or BAL
    ``(cameras, points)``), synchronised with the device."""
    name: str
    how: str
    run: Callable[[], Any]
    setup_s: float = 0.0
    scale: float = 1.0          # time multiplier (a contender timed on a subset of the batch)
    note: str = ""
    ours: bool = False
    stats: dict[str, str] = dataclasses.field(default_factory=dict)   # "iterations" of the last run


def _spread(v: Any) -> str:
    """Per-problem counts as ``median (min-max)``, or the one count."""
    a = np.asarray(v).ravel()
    if a.size == 1:
        return f"{int(a[0])}"
    return f"{np.median(a):g} ({int(a.min())}-{int(a.max())})"


def _stop(kw: dict[str, Any]) -> tuple[int, float | None, float | None]:
    """The shared stop rule of the batch rows: ``(max_iter, rel_tol, abs_tol)``."""
    return kw.get("max_iter", 100), kw.get("rel_tol"), kw.get("abs_tol")


def _sync_torch(device: str) -> None:
    import torch
    if device == "cuda":
        torch.cuda.synchronize()


# ---- microlie, NumPy/C engine

def build_graph(kind: str, prob: Any, count: int) -> tuple[Any, Any]:
    """The first ``count`` problems of a batch as one microlie ``FactorGraph`` (disconnected
    components) and the handle of their poses: the NumPy engine's graph (all problems) and
    the device engine's structure (one problem)."""
    from microlie import SE3
    from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor, ReprojectionFactor
    g = FactorGraph()
    if kind == "posegraph":
        n = prob.n
        X = g.add_variables(SE3(params_from_matrix(prob.X0[:count].reshape(-1, 4, 4))))
        off = (np.arange(count) * n)[:, None]
        g.add(BetweenFactor(X, (off + prob.edges[:, 0]).ravel(), (off + prob.edges[:, 1]).ravel(),
                            SE3(params_from_matrix(prob.Z[:count].reshape(-1, 4, 4))),
                            Diagonal(1 / prob.w_edge)))
        g.add(PriorFactor(X, off[:, 0], SE3(params_from_matrix(prob.Z0[:count])),
                          Diagonal(1 / prob.w_prior)))
        return g, X
    m = prob.points.shape[1]
    T = g.add_variables(SE3(params_from_matrix(prob.T0[:count])))
    P = g.add_variables(prob.points[:count].reshape(-1, 3), fixed=True)
    g.add(ReprojectionFactor((T, np.repeat(np.arange(count), m)), (P, np.arange(count * m)),
                             prob.uv[:count].reshape(-1, 2), model="pinhole", intrinsics=prob.K))
    return g, T


def microlie_numpy(kind: str, prob: Any, device: str, **kw: Any) -> Contender:
    t0 = time.perf_counter()
    stats: dict[str, str] = {}
    max_iter, rel_tol, abs_tol = _stop(kw)
    if kind == "posegraph":
        B, n = prob.batch, prob.n
        g, X = build_graph(kind, prob, B)

        def run() -> np.ndarray:
            r = g.optimize(max_iter=max_iter, rel_tol=rel_tol, abs_tol=abs_tol)
            stats["iterations"] = f"{r.iterations} (all problems at once)"
            return matrix_from_params(np.asarray(r.values[X].params)).reshape(B, n, 4, 4)
        how = "one FactorGraph of all problems, LM (GTSAM rules), sparse Cholesky"
    elif kind == "pnp":
        g, T = build_graph(kind, prob, prob.batch)

        def run() -> np.ndarray:
            r = g.optimize(max_iter=max_iter, rel_tol=rel_tol, abs_tol=abs_tol)
            stats["iterations"] = f"{r.iterations} (all problems at once)"
            return matrix_from_params(np.asarray(r.values[T].params))
        how = "one FactorGraph of all problems, LM (GTSAM rules), sparse Cholesky"
    else:
        from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        bp = BundleProblem.from_bal(BALProblem(prob.cameras, prob.points, prob.cam, prob.pt,
                                               prob.uv))

        def run() -> tuple[np.ndarray, np.ndarray]:
            r = bundle_adjust(bp, max_iter=prob.iterations)
            stats["iterations"] = f"{r.iterations}"
            out = bp.with_values(r.values).to_bal()
            return out.cameras, out.points
        how = f"bundle_adjust, TrustRegion (Ceres rules), Schur, {prob.iterations} tries"
    return Contender("microlie NumPy/C", how, run, time.perf_counter() - t0, ours=True,
                     stats=stats)


# ---- microlie on torch and JAX (microlie.optim.device)

def _device_template(kind: str, prob: Any) -> tuple[Any, Any, Any]:
    """The graph of the batch's first problem (NumPy), and the batch's ``theta`` and ``x0``
    arrays (NumPy, leading axis ``B``) in the layout of :meth:`DeviceProblem.theta`."""
    g, _ = build_graph(kind, prob, 1)
    if kind == "posegraph":
        theta = [{"Z": params_from_matrix(prob.Z)}, {"Z": params_from_matrix(prob.Z0)[:, None]}]
        x0 = [params_from_matrix(prob.X0)]
    else:
        theta = [{"obs": prob.uv}]
        x0 = [params_from_matrix(prob.T0)[:, None], prob.points]
    return g, theta, x0


def microlie_device(kind: str, prob: Any, device: str, backend: str, compiled: bool = False,
                    **kw: Any) -> Contender:
    """The device engine (``microlie.optim.device``): the structure from one graph, the batch
    as arrays with a leading axis (``solve(problem, theta, x0, options)``); on JAX the solve
    under ``jax.jit``; on torch eager, or ``torch.compile(fullgraph=True)`` with
    ``compiled``."""
    from microlie.optim.device import DeviceProblem, LMOptions, solve
    t0 = time.perf_counter()
    if backend == "jax":
        import jax
        dev: Any = _jax_device(device)

        def put(x: np.ndarray) -> Any:
            return jax.device_put(np.asarray(x, dtype=np.float64), dev)
    else:
        import torch
        dev = torch.device(device)

        def put(x: np.ndarray) -> Any:
            return torch.as_tensor(np.array(x, dtype=np.float64), device=dev)

    if kind == "bal":
        from microlie.optim import BALProblem, BundleProblem
        from microlie.optim.sfm.bundle import bundle_graph
        bg = bundle_graph(BundleProblem.from_bal(BALProblem(prob.cameras, prob.points, prob.cam,
                                                            prob.pt, prob.uv)))
        problem = DeviceProblem.from_graph(bg.graph, gauge="none", backend=backend,
                                           dtype="float64", device=dev)
        # theta as DeviceProblem.theta() lays it out (unit noise, the pixels); built here
        # because theta() re-checks the gauge with the graph's default ("check"), which a BAL
        # graph (gauge left to the damping, as bundle_adjust does) fails
        theta = ({"L": put(np.broadcast_to(np.eye(2), (len(prob.uv), 2, 2))),
                  "obs": put(prob.uv)},)
        x0 = problem.initial()
        n = prob.iterations
        # the default damping ("auto"): a problem with landmarks is damped by diag(H) from
        # lambda 1e-4 (Ceres' start; jaxls and Ceres scale by the Jacobian's columns)
        opts = LMOptions(max_iter=n, max_tries=n, rel_tol=0.0, abs_tol=0.0, linear="schur",
                         loop="fixed" if compiled else "auto")
        how = (f"LM (GTSAM rules, default damping: diag(H) from 1e-4), Schur + dense "
               f"Cholesky of the reduced camera system, {n} tries")
    else:
        g, th_b, x0_b = _device_template(kind, prob)
        problem = DeviceProblem.from_graph(g, backend=backend, dtype="float64", device=dev)
        theta = tuple({**{k: v for k, v in d.items()}, **{k: put(v) for k, v in b.items()}}
                      for d, b in zip(problem.theta(), th_b, strict=True))
        x0 = [put(v) for v in x0_b]
        max_iter, rel_tol, abs_tol = _stop(kw)
        opts = LMOptions(max_iter=max_iter, linear="dense", loop="fixed" if compiled else "auto",
                         **({} if rel_tol is None else {"rel_tol": rel_tol}),
                         **({} if abs_tol is None else {"abs_tol": abs_tol}))
        how = "batch axis, LM (GTSAM rules), batched dense Cholesky"

    if backend == "jax":
        import jax
        f = jax.jit(solve, static_argnums=(0, 3))

        def run() -> Any:
            x, info = jax.block_until_ready(f(problem, theta, x0, opts))
            return finish(x, info)
        name, how = "microlie JAX", how + ", jax.jit"
    else:
        import torch
        f = torch.compile(solve, fullgraph=True) if compiled else solve

        def run() -> Any:
            with torch.no_grad():
                x, info = f(problem, theta, x0, opts)
            _sync_torch(device)
            return finish(x, info)
        name = "microlie torch" + (" compiled" if compiled else "")
        how += ", torch.compile(fullgraph=True)" if compiled else ", eager"

    stats: dict[str, str] = {}

    def finish(x: list[Any], info: Any) -> Any:
        xs = [np.asarray(v.cpu() if hasattr(v, "cpu") else v) for v in x]
        it = np.asarray(info.iterations.cpu() if hasattr(info.iterations, "cpu")
                        else info.iterations)
        tr = np.asarray(info.tries.cpu() if hasattr(info.tries, "cpu") else info.tries)
        stats["iterations"] = f"{_spread(it)}; tries {_spread(tr)}"
        if kind == "posegraph":
            return matrix_from_params(xs[0])
        if kind == "pnp":
            return matrix_from_params(xs[0][:, 0])
        vals = {v: xs[k] for k, v in enumerate(problem.variables)}
        return _bal_arrays(bg, vals)
    return Contender(name, how, run, time.perf_counter() - t0, ours=True, stats=stats)


def _bal_arrays(bg: Any, vals: dict[Any, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """BAL ``(cameras, points)`` from the parameters of a :func:`bundle_graph`'s variables."""
    rot = so3_log(matrix_from_quat_xyzw(vals[bg.rotations]))
    cams = np.concatenate([rot, vals[bg.translations], vals[bg.intrinsics]], -1)
    return cams, vals[bg.points]


# ---- jaxls

def _jax_device(device: str) -> Any:
    import jax
    return jax.devices("gpu" if device == "cuda" else "cpu")[0]


def jaxls_contender(kind: str, prob: Any, device: str, **kw: Any) -> Contender:
    import jax
    import jax.numpy as jnp
    import jaxlie
    import jaxls

    dev = _jax_device(device)
    t0 = time.perf_counter()
    stats: dict[str, str] = {}
    max_iter, rel_tol, _ = _stop(kw)
    term = jaxls.TerminationConfig(max_iterations=max_iter,
                                   **({} if rel_tol is None else {"cost_tolerance": rel_tol}))

    def put(x: np.ndarray) -> Any:
        return jax.device_put(jnp.asarray(x), dev)

    def solved(problem: Any, init: Any, **opts: Any) -> Any:
        sol, summary = problem.solve(init, verbose=False, return_summary=True, **opts)
        sol = jax.block_until_ready(sol)
        crit = [n for n, f in zip(("cost", "gradient", "parameter"),
                                  np.asarray(summary.termination_criteria), strict=True) if f]
        stats["iterations"] = (f"{int(summary.iterations)} "
                               f"({'stopped on ' + '+'.join(crit) if crit else 'cap'})")
        return sol

    def wxyz_xyz(T: np.ndarray) -> np.ndarray:
        p = params_from_matrix(T)
        return np.concatenate([p[..., 6:7], p[..., 3:6], p[..., :3]], -1)

    if kind == "posegraph":
        B, n = prob.batch, prob.n
        E = len(prob.edges)
        off = (np.arange(B) * n)[:, None]
        i = put((off + prob.edges[:, 0]).ravel())
        j = put((off + prob.edges[:, 1]).ravel())
        w, w0 = put(prob.w_edge), put(prob.w_prior)

        def between(vals: Any, a: Any, b: Any, z: Any) -> Any:
            return w * (z.inverse() @ vals[a].inverse() @ vals[b]).log()

        def prior(vals: Any, a: Any, z: Any) -> Any:
            return w0 * (z.inverse() @ vals[a]).log()

        Zb = jaxlie.SE3(put(wxyz_xyz(prob.Z.reshape(B * E, 4, 4))))
        Z0 = jaxlie.SE3(put(wxyz_xyz(prob.Z0)))
        costs = [jaxls.Cost(between, (jaxls.SE3Var(i), jaxls.SE3Var(j), Zb)),
                 jaxls.Cost(prior, (jaxls.SE3Var(put(off[:, 0])), Z0))]
        ids = put(np.arange(B * n))
        problem = jaxls.LeastSquaresProblem(costs, [jaxls.SE3Var(ids)]).analyze()
        init = jaxls.VarValues.make(
            [jaxls.SE3Var(ids).with_value(jaxlie.SE3(put(wxyz_xyz(prob.X0.reshape(-1, 4, 4)))))])

        def run() -> np.ndarray:
            sol = solved(problem, init, termination=term)
            v = np.asarray(sol[jaxls.SE3Var(ids)].wxyz_xyz)
            return matrix_from_params(np.concatenate([v[:, 4:], v[:, 1:4], v[:, :1]], -1)
                                      ).reshape(B, n, 4, 4)
        how = "one problem of all graphs, LM, default CG"
    elif kind == "pnp":
        B, m = prob.batch, prob.points.shape[1]
        K = put(prob.K)

        def reproj(vals: Any, a: Any, X: Any, uv: Any) -> Any:
            P = vals[a] @ X
            return jnp.stack([K[0] * P[0] / P[2] + K[2], K[1] * P[1] / P[2] + K[3]]) - uv

        cam = put(np.repeat(np.arange(B), m))
        ids = put(np.arange(B))
        problem = jaxls.LeastSquaresProblem(
            [jaxls.Cost(reproj, (jaxls.SE3Var(cam), put(prob.points.reshape(-1, 3)),
                                 put(prob.uv.reshape(-1, 2))))],
            [jaxls.SE3Var(ids)]).analyze()
        init = jaxls.VarValues.make(
            [jaxls.SE3Var(ids).with_value(jaxlie.SE3(put(wxyz_xyz(prob.T0))))])

        def run() -> np.ndarray:
            sol = solved(problem, init, termination=term)
            v = np.asarray(sol[jaxls.SE3Var(ids)].wxyz_xyz)
            return matrix_from_params(np.concatenate([v[:, 4:], v[:, 1:4], v[:, :1]], -1))
        how = "one problem of all PnPs, LM, default CG"
    else:
        class CameraVar(jaxls.Var[jax.Array], default_factory=lambda: jnp.zeros(9)):
            pass

        class PointVar(jaxls.Var[jax.Array], default_factory=lambda: jnp.zeros(3)):
            pass

        def rodrigues(aa: Any, x: Any) -> Any:
            th2 = jnp.dot(aa, aa)
            safe = th2 > 1e-24
            th = jnp.sqrt(jnp.where(safe, th2, 1.0))
            k = aa / th
            rot = (x * jnp.cos(th) + jnp.cross(k, x) * jnp.sin(th)
                   + k * jnp.dot(k, x) * (1.0 - jnp.cos(th)))
            return jnp.where(safe, rot, x + jnp.cross(aa, x))

        def reproj(vals: Any, c: Any, p: Any, uv: Any) -> Any:
            cam, X = vals[c], vals[p]
            P = rodrigues(cam[:3], X) + cam[3:6]
            x = -P[:2] / P[2]
            r2 = jnp.sum(x**2)
            return cam[6] * (1.0 + cam[7] * r2 + cam[8] * r2**2) * x - uv

        nc, npt = len(prob.cameras), len(prob.points)
        problem = jaxls.LeastSquaresProblem(
            [jaxls.Cost(reproj, (CameraVar(put(prob.cam)), PointVar(put(prob.pt)),
                                 put(prob.uv)))],
            [CameraVar(put(np.arange(nc))), PointVar(put(np.arange(npt)))]).analyze()
        cv, pv = CameraVar(put(np.arange(nc))), PointVar(put(np.arange(npt)))
        init = jaxls.VarValues.make([cv.with_value(put(prob.cameras)),
                                     pv.with_value(put(prob.points))])
        solver = kw.get("jaxls_solver", "dense_cholesky")
        early = not kw.get("jaxls_no_early_stop", False)
        bterm = jaxls.TerminationConfig(max_iterations=prob.iterations, early_termination=early)

        def run() -> tuple[np.ndarray, np.ndarray]:
            sol = solved(problem, init, linear_solver=solver, termination=bterm)
            return np.asarray(sol[cv]), np.asarray(sol[pv])
        how = (f"LM, Schur elimination + {solver} (its documented best for BA), "
               f"at most {prob.iterations} iterations, "
               + ("its own stop rule (default tolerances)" if early else "no early stop"))
    if kind != "bal":
        how += (f"; its stop rule: relative cost change < "
                f"{term.cost_tolerance:g}, <= {max_iter} iterations")
    return Contender("jaxls", how, run, time.perf_counter() - t0, stats=stats)


# ---- PyPose

def pypose_contender(kind: str, prob: Any, device: str, subset: int = 20, **kw: Any
                     ) -> Contender:
    """``pp.optim.LM`` (its TrustRegion strategy, Cholesky solver) with the ``StopOnPlateau``
    scheduler, one problem at a time (its LM builds one dense Jacobian of the whole model, so a
    batch of independent problems is a loop), on the first ``subset`` problems; the time is
    scaled to the whole batch."""
    import pypose as pp
    import torch

    if kind == "bal":
        raise NotImplementedError(
            "PyPose on BAL: pp.optim.LM builds the dense Jacobian (63,686 x 23,769 float64 = "
            "12 GB); its sparse mode needs the bae backend, which builds only with CUDA")
    dev = torch.device(device)
    t0 = time.perf_counter()
    K = min(subset, prob.batch)
    max_iter = _stop(kw)[0]

    def tt(x: np.ndarray) -> Any:
        return torch.as_tensor(x, dtype=torch.float64, device=dev)

    if kind == "posegraph":
        w, w0 = tt(prob.w_edge), tt(prob.w_prior)
        i, j = (torch.as_tensor(prob.edges[:, c], device=dev) for c in (0, 1))

        class Graph(torch.nn.Module):
            def __init__(self, X: np.ndarray) -> None:
                super().__init__()
                self.X = pp.Parameter(pp.SE3(tt(params_from_matrix(X))))

            def forward(self, Z: Any, Z0: Any) -> Any:
                e = (Z.Inv() @ self.X[i].Inv() @ self.X[j]).Log().tensor() * w
                e0 = (Z0.Inv() @ self.X[0]).Log().tensor() * w0
                return torch.cat([e, e0[None]])

        inputs = [(pp.SE3(tt(params_from_matrix(prob.Z[b]))),
                   pp.SE3(tt(params_from_matrix(prob.Z0[b])))) for b in range(K)]
        starts = [prob.X0[b] for b in range(K)]
    else:
        Kc = tt(prob.K)

        class Graph(torch.nn.Module):   # type: ignore[no-redef]
            def __init__(self, T: np.ndarray) -> None:
                super().__init__()
                self.T = pp.Parameter(pp.SE3(tt(params_from_matrix(T))))

            def forward(self, X: Any, uv: Any) -> Any:
                P = self.T.unsqueeze(0).Act(X)
                return torch.stack([Kc[0] * P[:, 0] / P[:, 2] + Kc[2],
                                    Kc[1] * P[:, 1] / P[:, 2] + Kc[3]], -1) - uv

        inputs = [(tt(prob.points[b]), tt(prob.uv[b])) for b in range(K)]
        starts = [prob.T0[b] for b in range(K)]

    def run() -> np.ndarray:
        out = []
        for b in range(K):
            model = Graph(starts[b]).to(dev)
            opt = pp.optim.LM(model)
            sched = pp.optim.scheduler.StopOnPlateau(opt, steps=max_iter, patience=2,
                                                     decreasing=1e-8)
            sched.optimize(input=inputs[b])
            p = next(iter(model.parameters())).detach()
            out.append(matrix_from_params(p.tensor().cpu().numpy()))
        _sync_torch(device)
        return np.stack(out)
    return Contender("PyPose", f"pp.optim.LM (TrustRegion, Cholesky) + StopOnPlateau, a loop "
                     f"over problems; timed on {K}, scaled x{prob.batch / K:g}", run,
                     time.perf_counter() - t0, scale=prob.batch / K,
                     note=f"first {K} problems")


# ---- Theseus

def theseus_contender(kind: str, prob: Any, device: str, **kw: Any) -> Contender:
    """``th.LevenbergMarquardt`` in a ``th.TheseusLayer`` (vectorised costs), its default
    dense Cholesky solver, the batch axis of Theseus's variables for the batch of problems."""
    import theseus as th
    import torch

    dev = torch.device(device)
    t0 = time.perf_counter()

    def tt(x: np.ndarray) -> Any:
        return torch.as_tensor(x, dtype=torch.float64, device=dev)

    if kind == "posegraph":
        B, n = prob.batch, prob.n
        X = [th.SE3(tensor=tt(prob.X0[:, k, :3, :]), name=f"x{k}") for k in range(n)]
        costs: list[Any] = []
        w = th.DiagonalCostWeight(tt(np.broadcast_to(prob.w_edge, (B, 6)).copy()))
        for e, (a, b) in enumerate(prob.edges):
            Z = th.SE3(tensor=tt(prob.Z[:, e, :3, :]), name=f"z{e}")
            costs.append(th.Between(X[a], X[b], Z, w, name=f"between{e}"))
        Z0 = th.SE3(tensor=tt(prob.Z0[:, :3, :]), name="z_prior")
        w0 = th.DiagonalCostWeight(tt(np.broadcast_to(prob.w_prior, (B, 6)).copy()))
        costs.append(th.Difference(X[0], Z0, w0, name="prior"))
        start = {f"x{k}": tt(prob.X0[:, k, :3, :]) for k in range(n)}
        names = [f"x{k}" for k in range(n)]
    elif kind == "pnp":
        B, m = prob.batch, prob.points.shape[1]
        Kc = tt(prob.K)
        T = th.SE3(tensor=tt(prob.T0[:, :3, :]), name="T")
        pts = th.Variable(tt(prob.points.reshape(B, -1)), name="points")
        uv = th.Variable(tt(prob.uv.reshape(B, -1)), name="uv")

        def err(optim_vars: Any, aux_vars: Any) -> Any:
            Tm = optim_vars[0].tensor                     # (B, 3, 4)
            Xw = aux_vars[0].tensor.view(-1, m, 3)
            P = Xw @ Tm[:, :, :3].transpose(1, 2) + Tm[:, None, :, 3]
            proj = torch.stack([Kc[0] * P[..., 0] / P[..., 2] + Kc[2],
                                Kc[1] * P[..., 1] / P[..., 2] + Kc[3]], -1)
            return (proj - aux_vars[1].tensor.view(-1, m, 2)).reshape(-1, 2 * m)

        unit = th.ScaleCostWeight(tt(np.ones(1)))
        costs = [th.AutoDiffCostFunction([T], err, 2 * m, unit, aux_vars=[pts, uv],
                                         name="reproj")]
        start = {"T": tt(prob.T0[:, :3, :])}
        names = ["T"]
    else:
        return theseus_bal(prob, device, **kw)

    objective = th.Objective(dtype=torch.float64)
    for c in costs:
        objective.add(c)
    objective.to(dev)
    maxit, rel_tol, abs_tol = _stop(kw)
    tol = {**({} if rel_tol is None else {"rel_err_tolerance": rel_tol}),
           **({} if abs_tol is None else {"abs_err_tolerance": abs_tol})}
    lm = th.LevenbergMarquardt(objective, max_iterations=maxit, **tol)
    layer = th.TheseusLayer(lm)
    layer.to(dev)
    stats: dict[str, str] = {}

    def run() -> np.ndarray:
        with torch.no_grad():
            sol, info = layer.forward(dict(start), optimizer_kwargs={
                "track_best_solution": False, "verbose": False, "adaptive_damping": True})
        _sync_torch(device)
        stats["iterations"] = f"{_spread(info.converged_iter.cpu().numpy())} (tries)"
        out = np.stack([sol[k].cpu().numpy() for k in names], 1)   # (B, n, 3, 4)
        M = np.zeros((*out.shape[:2], 4, 4))
        M[..., :3, :] = out
        M[..., 3, 3] = 1.0
        return M if kind == "posegraph" else M[:, 0]
    return Contender("Theseus", f"LevenbergMarquardt (adaptive damping, dense Cholesky), "
                     f"batch axis, <= {maxit} iterations, relative / absolute cost change < "
                     f"{lm.params.rel_err_tolerance:g} / {lm.params.abs_err_tolerance:g}",
                     run, time.perf_counter() - t0, stats=stats)


def theseus_bal(prob: BAL, device: str, **kw: Any) -> Contender:
    """BAL with Theseus: one ``th.SE3`` pose, one ``th.Vector`` of intrinsics per camera and
    one ``th.Point3`` per point, one ``AutoDiffCostFunction`` per observation (its
    ``th.eb.Reprojection`` holds the intrinsics constant, BAL optimises them), LM with its
    fixed damping ``--theseus-damping`` (100: its default 1e-3 fails, CHOLMOD finds the damped
    system not positive definite; its adaptive damping refuses CHOLMOD) and
    ``CholmodSparseSolver`` (the dense default would need a 23,769^2 matrix),
    ``prob.iterations`` iterations, no early stop."""
    import theseus as th
    import torch

    dev = torch.device(device)
    t0 = time.perf_counter()

    def tt(x: np.ndarray) -> Any:
        return torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float64, device=dev)

    R = so3_exp(prob.cameras[:, :3])
    Rt = np.concatenate([R, prob.cameras[:, 3:6, None]], -1)
    poses = [th.SE3(tensor=tt(Rt[c:c + 1]), name=f"pose{c}") for c in range(len(Rt))]
    intr = [th.Vector(tensor=tt(prob.cameras[c:c + 1, 6:]), name=f"K{c}")
            for c in range(len(Rt))]
    pts = [th.Point3(tensor=tt(prob.points[k:k + 1]), name=f"p{k}")
           for k in range(len(prob.points))]

    def err(optim_vars: Any, aux_vars: Any) -> Any:
        pose, K, X = optim_vars
        P = pose.transform_from(X).tensor
        x = -P[:, :2] / P[:, 2:3]
        r2 = (x * x).sum(1, keepdim=True)
        k = K.tensor
        return k[:, :1] * (1 + k[:, 1:2] * r2 + k[:, 2:3] * r2 * r2) * x - aux_vars[0].tensor

    objective = th.Objective(dtype=torch.float64)
    unit = th.ScaleCostWeight(tt(np.ones(1)))
    for o in range(len(prob.uv)):
        c, k = int(prob.cam[o]), int(prob.pt[o])
        objective.add(th.AutoDiffCostFunction(
            [poses[c], intr[c], pts[k]], err, 2, unit,
            aux_vars=[th.Variable(tt(prob.uv[o:o + 1]), name=f"uv{o}")], name=f"r{o}"))
    objective.to(dev)
    n = prob.iterations
    damping = kw.get("theseus_damping", 100.0)
    opt = th.LevenbergMarquardt(objective, linear_solver_cls=th.CholmodSparseSolver,
                                max_iterations=n, abs_err_tolerance=0.0, rel_err_tolerance=0.0)
    layer = th.TheseusLayer(opt)
    layer.to(dev)
    start = {**{f"pose{c}": tt(Rt[c:c + 1]) for c in range(len(Rt))},
             **{f"K{c}": tt(prob.cameras[c:c + 1, 6:]) for c in range(len(Rt))},
             **{f"p{k}": tt(prob.points[k:k + 1]) for k in range(len(prob.points))}}

    stats: dict[str, str] = {}

    def run() -> tuple[np.ndarray, np.ndarray]:
        with torch.no_grad():
            sol, info = layer.forward(dict(start), optimizer_kwargs={
                "track_best_solution": False, "verbose": False, "damping": damping})
        _sync_torch(device)
        # fixed damping: every step is taken (no rejection), one linear solve per iteration;
        # with both tolerances 0 it stops only at the cap (status MAX_ITERATIONS)
        done = info.status[0] == th.NonlinearOptimizerStatus.MAX_ITERATIONS
        stats["iterations"] = (f"{n} (cap); solves {n}" if done
                               else f"{int(info.converged_iter[0])}")
        M = np.concatenate([sol[f"pose{c}"].cpu().numpy() for c in range(len(Rt))])
        cams = np.concatenate([so3_log(M[:, :, :3]), M[:, :, 3],
                               np.concatenate([sol[f"K{c}"].cpu().numpy()
                                               for c in range(len(Rt))])], -1)
        return cams, np.concatenate([sol[f"p{k}"].cpu().numpy()
                                     for k in range(len(prob.points))])
    return Contender("Theseus", f"LevenbergMarquardt, fixed damping {damping:g} (its default "
                     f"1e-3 fails: CHOLMOD 'not positive definite'; its adaptive damping "
                     f"refuses CHOLMOD), CholmodSparseSolver, "
                     f"AutoDiffCostFunction per observation, {n} iterations", run,
                     time.perf_counter() - t0, stats=stats)


# ---------------------------------------------------------------------------------- runner

PEERS: dict[str, Callable[..., Contender]] = {
    "numpy": microlie_numpy,
    "jax": lambda *a, **k: microlie_device(*a, backend="jax", **k),
    "torch": lambda *a, **k: microlie_device(*a, backend="torch", **k),
    "torch-compiled": lambda *a, **k: microlie_device(*a, backend="torch", compiled=True, **k),
    "jaxls": jaxls_contender,
    "pypose": pypose_contender,
    "theseus": theseus_contender,
}
COSTS: dict[str, Callable[[Any, Any], Any]] = {
    "posegraph": pose_graph_costs,
    "pnp": pnp_costs,
}


def load() -> str:
    a, b, c = os.getloadavg()
    return f"{a:.2f} {b:.2f} {c:.2f} (1/5/15 min; {os.cpu_count()} cores)"


def make_problem(kind: str, args: argparse.Namespace) -> Any:
    if kind == "posegraph":
        return make_pose_graphs(args.batch, args.seed)
    if kind == "pnp":
        return make_pnp(args.batch, args.seed, args.pnp_points)
    b = read_bal_arrays(Path(args.bal))
    b.iterations = args.iterations
    return b


def costs_of(kind: str, prob: Any, sol: Any) -> np.ndarray:
    """Per-problem costs of a solution (the first ``len(sol)`` problems of a batch)."""
    if kind == "bal":
        return np.array([bal_cost(prob, *sol)])
    n = len(sol)
    sub = dataclasses.replace(prob, **{f.name: getattr(prob, f.name)[:n]
                                       for f in dataclasses.fields(prob)
                                       if f.name not in ("edges", "w_edge", "w_prior", "K")})
    return COSTS[kind](sub, sol)


def reference(kind: str, prob: Any) -> np.ndarray:
    """The NumPy engine's optimum, tight tolerances (per problem for the batches; for BAL
    the converged cost, not the 30-iteration one)."""
    from microlie.optim import BALProblem, BundleProblem, bundle_adjust
    if kind == "bal":
        bp = BundleProblem.from_bal(BALProblem(prob.cameras, prob.points, prob.cam, prob.pt,
                                               prob.uv))
        r = bundle_adjust(bp, max_iter=200)
        out = bp.with_values(r.values).to_bal()
        return np.array([bal_cost(prob, out.cameras, out.points)])
    c = microlie_numpy(kind, prob, "cpu")
    return costs_of(kind, prob, c.run())


@dataclasses.dataclass
class Row:
    name: str
    how: str = ""
    setup_s: float = float("nan")
    first_s: float = float("nan")
    times: list[float] = dataclasses.field(default_factory=list)
    excess: float = float("nan")      # max relative cost excess over the reference
    cost: float = float("nan")        # total cost of the solution
    skipped: str = ""
    ours: bool = False
    note: str = ""
    iterations: str = ""              # as the contender counts them, its last run


def run_problem(kind: str, args: argparse.Namespace, out: list[str]) -> list[Row]:
    prob = make_problem(kind, args)
    print(f"[{kind}] reference solve (NumPy engine)...", file=sys.stderr, flush=True)
    ref = reference(kind, prob)
    rows: dict[str, Row] = {}
    live: list[tuple[Row, Contender]] = []
    for name in args.contenders:
        row = rows.setdefault(name, Row(name))
        try:
            c = PEERS[name](kind, prob, args.device, subset=args.pypose_subset,
                            jaxls_solver=args.jaxls_solver,
                            jaxls_no_early_stop=args.jaxls_no_early_stop,
                            theseus_damping=args.theseus_damping, max_iter=args.max_iter,
                            rel_tol=args.rel_tol, abs_tol=args.abs_tol)
        except NotImplementedError as e:
            row.skipped = str(e)
            continue
        except Exception as e:   # a peer that fails to build its problem is reported, not fatal
            row.skipped = f"failed to build: {type(e).__name__}: {e}"
            traceback.print_exc()
            continue
        row.name, row.how, row.setup_s, row.ours, row.note = (c.name, c.how, c.setup_s,
                                                              c.ours, c.note)
        print(f"[{kind}] {c.name}: first call...", file=sys.stderr, flush=True)
        try:
            t0 = time.perf_counter()
            sol = c.run()
            row.first_s = (time.perf_counter() - t0) * c.scale
        except Exception as e:
            row.skipped = f"failed: {type(e).__name__}: {e}"
            traceback.print_exc()
            continue
        row.iterations = c.stats.get("iterations", "")
        cs = costs_of(kind, prob, sol)
        row.cost = float(np.sum(cs))
        row.excess = float(np.max((cs - ref[:len(cs)]) / ref[:len(cs)]))
        if row.first_s / c.scale > args.slow:     # the wall time, not a scaled one
            row.note = (f"steady state not timed: first call over --slow {args.slow:g} s "
                        f"(no compilation on this path: the first call is its time)"
                        if row.name == "microlie torch" else
                        f"steady state not timed: first call over --slow {args.slow:g} s")
            continue
        live.append((row, c))
    rounds = args.bal_rounds if kind == "bal" else args.rounds
    for r in range(rounds):
        k = r % max(len(live), 1)
        for row, c in live[k:] + live[:k]:
            t0 = time.perf_counter()
            c.run()
            row.times.append((time.perf_counter() - t0) * c.scale)
        print(f"[{kind}] round {r + 1}/{rounds}: "
              + ", ".join(f"{row.name} {row.times[-1]:.3g} s" for row, _ in live),
              file=sys.stderr, flush=True)
    if args.json:
        raw = {"kind": kind, "reference": ref.tolist(), "load": load(),
               "rows": [dataclasses.asdict(r) for r in rows.values()]}
        with open(args.json, "a") as f:
            f.write(json.dumps(raw) + "\n")
    out.extend(table(kind, prob, ref, list(rows.values()), args))
    return list(rows.values())


def _fmt(t: float) -> str:
    return "-" if t != t else (f"{t:.3g}" if t < 100 else f"{t:.0f}")


def table(kind: str, prob: Any, ref: np.ndarray, rows: list[Row],
          args: argparse.Namespace) -> list[str]:
    title = {"posegraph": f"{args.batch} SE(3) pose graphs of 10 poses (12 edges + a prior)",
             "pnp": f"{args.batch} PnP problems of {args.pnp_points} points",
             "bal": f"BAL problem-49-7776 (Ladybug-49), {args.iterations} LM iterations"}[kind]
    refs = (f"optimum (sum) {float(np.sum(ref)):.10g}" if kind != "bal" else
            f"converged optimum {float(ref[0]):.10g}")
    ours = [r for r in rows if r.ours and r.times]
    lines = [f"### {title}", "",
             f"Reference: the NumPy engine's {refs}; `excess` = largest relative cost excess "
             f"over it ({'per problem' if kind != 'bal' else 'after the iterations run'}).", "",
             "| contender | solve | setup s | first call s | steady s, median (min-max) | "
             "cost | excess | iterations | " + " | ".join(f"/ {o.name}" for o in ours) + " |",
             "|---|---|---:|---:|---:|---:|---:|---|" + "---:|" * len(ours)]
    for r in rows:
        if r.skipped:
            lines.append(f"| {r.name} | not run: {r.skipped} | | | | | | |" + " |" * len(ours))
            continue
        med = statistics.median(r.times) if r.times else float("nan")
        span = f"{_fmt(med)} ({_fmt(min(r.times))}-{_fmt(max(r.times))})" if r.times else "-"
        ratios = []
        for o in ours:
            if r.times:
                per = [a / b for a, b in zip(r.times, o.times, strict=True)]
                ratios.append(f"{statistics.median(per):.3g}x")
            else:   # timed once: its first call over that row's median (marked)
                ratios.append(f"{r.first_s / statistics.median(o.times):.3g}x*")
        if not r.times and r.note:
            span = r.note
        lines.append(f"| {r.name} | {r.how} | {_fmt(r.setup_s)} | {_fmt(r.first_s)} | {span} | "
                     f"{r.cost:.10g}{f' ({r.note})' if r.note and r.times else ''} | "
                     f"{r.excess:.1e} | {r.iterations or '-'} | " + " | ".join(ratios) + " |")
    if any(not r.times and not r.skipped for r in rows):
        lines += ["", "`*`: a contender timed once (its first call, over `--slow`) over that "
                  "row's median."]
    lines.append("")
    return lines


def versions() -> str:
    out = [f"python {platform.python_version()}", f"numpy {np.__version__}"]
    for mod in ("torch", "jax", "jaxls", "pypose", "theseus"):
        try:
            m = __import__(mod)
            out.append(f"{mod} {getattr(m, '__version__', '?')}")
        except Exception:
            out.append(f"{mod} (not installed)")
    return ", ".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", nargs="+", default=["posegraph", "pnp", "bal"],
                    choices=["posegraph", "pnp", "bal"])
    ap.add_argument("--contenders", nargs="+", choices=list(PEERS),
                    default=[c for c in PEERS if c != "torch-compiled"],
                    help="default: all but torch-compiled (its compile takes minutes)")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--batch", type=int, default=1000, help="problems per batch (1000)")
    ap.add_argument("--pnp-points", type=int, default=40, help="points per PnP problem (40)")
    ap.add_argument("--bal", default=str(DEFAULT_BAL), help="the BAL file (problem-49-7776)")
    ap.add_argument("--iterations", type=int, default=30, help="LM iterations on BAL (30)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved timed rounds (5)")
    ap.add_argument("--bal-rounds", type=int, default=3, help="timed rounds on BAL (3)")
    ap.add_argument("--pypose-subset", type=int, default=10,
                    help="PyPose solves this many problems of a batch, time scaled (10)")
    ap.add_argument("--jaxls-solver", default="dense_cholesky",
                    help="jaxls's linear solver on BAL (dense_cholesky: Schur + dense, the one "
                         "its results.md finds fastest; conjugate_gradient is its default)")
    ap.add_argument("--theseus-damping", type=float, default=100.0,
                    help="Theseus's fixed LM damping on BAL (100; its default 1e-3 stops at "
                         "the first step: CHOLMOD finds the damped system not positive "
                         "definite)")
    ap.add_argument("--max-iter", type=int, default=100,
                    help="iteration cap of the batch rows, for every contender that has one "
                         "(100)")
    ap.add_argument("--rel-tol", type=float, default=1e-5,
                    help="relative cost-change stop of the batch rows (microlie, Theseus, "
                         "jaxls's cost_tolerance; 1e-5)")
    ap.add_argument("--abs-tol", type=float, default=1e-5,
                    help="absolute cost-change stop of the batch rows (microlie, Theseus; "
                         "1e-5)")
    ap.add_argument("--jaxls-no-early-stop", action="store_true",
                    help="BAL: jaxls runs exactly --iterations (default: its own stop rule)")
    ap.add_argument("--slow", type=float, default=150.0,
                    help="a contender whose first call takes longer is not timed again (150 s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="also write the markdown report here")
    ap.add_argument("--json", help="append each problem's raw rows (JSON lines) here")
    args = ap.parse_args(argv)
    if min(args.batch, args.rounds, args.bal_rounds, args.iterations, args.pypose_subset,
           args.max_iter) < 1 or args.pnp_points < 6:
        ap.error("--batch, --rounds, --bal-rounds, --iterations, --pypose-subset and "
                 "--max-iter must be >= 1, --pnp-points >= 6")
    if not (args.rel_tol >= 0 and args.abs_tol >= 0):
        ap.error("--rel-tol and --abs-tol must be >= 0")
    if "bal" in args.problems and not Path(args.bal).is_file():
        ap.error(f"--bal: {args.bal} not found (the shared BAL data, ../shared/data/bal)")

    # one thread each; set here, not at import (tests import this module), before JAX starts
    os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false "
                                       "intra_op_parallelism_threads=1")
    from threadpoolctl import threadpool_limits
    blas = threadpool_limits(1, user_api="blas")
    try:
        import torch
        torch.set_num_threads(1)
        if args.device == "cuda" and not torch.cuda.is_available():
            ap.error("--device cuda: torch sees no CUDA device")
    except ImportError:
        pass
    try:
        import jax
        jax.config.update("jax_enable_x64", True)     # float64, as every other contender
        from loguru import logger  # jaxls logs every analyze() at INFO
        logger.remove()
    except ImportError:
        pass

    head = ["# Solves on arrays and devices: microlie against jaxls, PyPose, Theseus", "",
            "Command: `PYTHONPATH=src " + " ".join([Path(sys.executable).as_posix(),
                                                    "benchmarks/devices.py", *sys.argv[1:]])
            + "`", "",
            f"Date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {platform.machine()}, "
            f"{versions()}; device `{args.device}`; one thread each (torch, XLA, BLAS); "
            f"float64; seed {args.seed}.", "",
            f"Load at start: {load()}.", "",
            f"Stop rule of the batch rows, for every contender with the knob: at most "
            f"{args.max_iter} iterations, relative / absolute cost change below "
            f"{args.rel_tol:g} / {args.abs_tol:g} (GTSAM's and Theseus's meaning; jaxls has the "
            f"relative one only, PyPose neither). BAL: {args.iterations} iterations.", ""]
    if args.device == "cuda":
        head += ["**CUDA:** this path runs the same code with the arrays on the GPU; it was "
                 "written and run on CPU only (no GPU at hand), so treat any CUDA figure as "
                 "the first of its kind.", ""]
    else:
        head += ["CUDA (`--device cuda`): the same code, unmeasured until a GPU is at hand "
                 "(goals: Ladybug-49 in at most 0.08 s for 30 iterations, at least 5x over "
                 "the CPU engine).", ""]
    body: list[str] = []
    for kind in args.problems:
        run_problem(kind, args, body)
    report = "\n".join(head + body + [f"Load at end: {load()}.", ""])
    print(report)
    if args.out:
        Path(args.out).write_text(report)
    blas.restore_original_limits()
    return 0


if __name__ == "__main__":
    sys.exit(main())
