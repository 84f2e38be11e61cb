"""Fixed-lag visual-inertial-style smoothing on synthetic EuRoC V1_02 IMU data: microlie's
``BatchFixedLagSmoother`` and ``IncrementalFixedLagSmoother`` (IMU preintegration factors,
bias random walk, 10 Hz position fixes) against the error-state Kalman filter and the full
batch smoother on the same measurements.

Run from the repository root (shared data in ../shared/data), with one BLAS thread:

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/main/.venv/bin/python benchmarks/fixed_lag.py \
        --runs 50 [--smoothers batch incremental] [--window 40] [--duration 12] [--resolve]
    ... benchmarks/fixed_lag.py --runs 20 --curve 5 10 20 30 40
    ... benchmarks/fixed_lag.py --steps 100000 --window 10

``--runs M``: Monte Carlo consistency, for each smoother of ``--smoothers``. For each run the
initial state is drawn around the truth with the prior's covariance, the fixes get their
noise, and every estimator sees the same numbers. Printed: the average NEES (15 dof: SE_2(3)
tangent and both biases) of the fixed-lag estimate of each keyframe as it leaves the window
(``x_{k | k + W - 1}``, final) and of the newest keyframe (``x_{k|k}``, the online estimate),
against the 95% chi-square band for ``M`` runs; the position RMSE of each estimator over all
keyframes and runs and their ratios: the smoothed estimate against the full batch smoother
over the whole run (``x_{k|K}``, which also uses the data after the lag), the newest against
the ESKF (a filter: the same data); with ``--resolve`` also against the full batch smoother
re-solved at every keyframe on the data so far (the same data as the window: what
marginalisation costs).

``--curve W1 W2 ...``: the smoothed / whole-run RMSE ratio for each window (no covariances),
over ``--runs`` runs (default 10).

``--steps N``: ``N`` IMU samples at 200 Hz (one keyframe and fix every 20), the trajectory
repeated; prints the median time per update over the first and the last 1,000 IMU steps
(time per step = update time / 20), the resident memory after the first 1000 steps and at the
end, the process peak (ru_maxrss) and, with ``--trace``, the peak of Python's allocations
(tracemalloc, which slows every update: not for the timing).

The functions are imported by tests/test_fixed_lag.py (a smaller Monte Carlo in CI).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from microlie import SE23
from microlie.imu import (
    BiasRandomWalkFactor,
    ErrorStateEKF,
    ImuFactor,
    PositionFactor,
    Preintegration,
    SmoothTrajectory,
    simulate_imu,
)
from microlie.imu.filters import ESKF_STATE
from microlie.imu.simulate import load_euroc_groundtruth
from microlie.optim import Covariance, FactorGraph, Isotropic, PriorFactor
from microlie.optim.online import BatchFixedLagSmoother, IncrementalFixedLagSmoother

ROOT = Path(__file__).resolve().parents[1]
GT = ROOT.parent / "shared" / "data" / "trajectory" / "evo" / "V102_groundtruth.csv"
EVERY, SIGMA = 20, 0.05  # a keyframe and a position fix every 20 samples (10 Hz), 5 cm
WINDOW = 40  # keyframes in the window (4 s): within 10% of the whole-run smoother's RMSE
# prior standard deviations in the SE_2(3) tangent order (rho, phi, nu) then (b_g, b_a)
P0_STD = np.r_[np.full(3, 0.05), np.full(3, 0.01), np.full(3, 0.05), np.full(3, 0.003),
               np.full(3, 0.02)]


def make_data(runs: int, duration: float, seed: int = 7, start: float = 15.0) -> Any:
    """``runs`` noise draws of ``duration`` seconds of IMU data along EuRoC V1_02."""
    t, poses = load_euroc_groundtruth(GT)
    traj = SmoothTrajectory.from_poses(t, poses, knot_dt=0.1)
    return simulate_imu(traj, duration=duration, start=traj.t0 + start, rng=seed, runs=runs)


def truth(data: Any, m: int, K: int) -> tuple[SE23, np.ndarray]:
    """True states and biases ``(b_g, b_a)`` at the keyframes ``0..K`` of run ``m``."""
    s = np.minimum(np.arange(K + 1) * EVERY, len(data.t) - 1)
    X = data.truth[np.arange(K + 1) * EVERY]
    b = np.concatenate([data.bias_gyro[s, m], data.bias_accel[s, m]], -1)
    return X, b


def inputs(data: Any, m: int, rng: np.random.Generator) -> dict:
    """Run ``m``'s prior mean (truth moved by a draw of the prior) and noisy fixes."""
    K = len(data.t) // EVERY
    X, b = truth(data, m, K)
    e0 = rng.standard_normal(15) * P0_STD
    x0 = X[0] @ SE23.exp(-e0[:9])  # truth = x0 Exp(e): the prior's error is e ~ N(0, P0)
    z = np.asarray(X.translation()) + SIGMA * rng.standard_normal((K + 1, 3))
    return {"K": K, "x0": x0, "b0": b[0] - e0[9:], "z": z, "X": X, "b": b}


def _samples(data: Any, m: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    s = slice((k - 1) * EVERY, k * EVERY)
    return data.accel[s, m], data.gyro[s, m]


class _Dropping(BatchFixedLagSmoother):
    """The smoother with its marginal priors thrown away (what the tests show fails)."""

    def update(self, *a: Any, **k: Any) -> Any:
        res = super().update(*a, **k)
        self._records = [r for r in self._records if r.prior is None]
        self._graph = None
        return res


class _DroppingIncremental(IncrementalFixedLagSmoother):
    """The incremental smoother with its marginal priors thrown away."""

    def update(self, *a: Any, **k: Any) -> Any:
        res = super().update(*a, **k)
        for rec in [r for r in self._records if r.prior is not None]:
            self._records.remove(rec)
            self._to_add = [r for r in self._to_add if r is not rec]
            for key in rec.keys:
                self._count[key] -= 1
        return res


def make_smoother(smoother: str, window: int, variant: str = "fej", **options: Any) -> Any:
    """``"batch"``: BatchFixedLagSmoother (20 LM iterations at most per update);
    ``"incremental"``: IncrementalFixedLagSmoother (GTSAM's ISAM2 defaults unless
    ``options`` say otherwise)."""
    if smoother == "batch":
        cls: Any = _Dropping if variant == "drop" else BatchFixedLagSmoother
        return cls(window=window, **{"max_iter": 20, **options})
    cls = _DroppingIncremental if variant == "drop" else IncrementalFixedLagSmoother
    return cls(window=window, **options)


def fixed_lag_run(data: Any, m: int, inp: dict, window: int = 10, variant: str = "fej",
                  cov: bool = True, smoother: str = "batch", **options: Any) -> dict:
    """One run of a fixed-lag smoother (:func:`make_smoother`); returns, per keyframe, the
    estimate (and joint 15x15 covariance of ``(x_k, b_k)``) when it is the oldest in the window
    and when it is the newest, and the preintegrations it made (with the bias estimate of their
    start)."""
    prm = data.params
    s = make_smoother(smoother, window, variant, **options)
    P0 = np.diag(P0_STD**2)
    x0, b0 = inp["x0"], inp["b0"]
    s.update([lambda b: PriorFactor(*b[("x", 0)], x0, Covariance(P0[:9, :9])),
              lambda b: PriorFactor(*b[("b", 0)], b0, Covariance(P0[9:, 9:]))],
             {("x", 0): x0, ("b", 0): b0.copy()}, {("x", 0): 0.0, ("b", 0): 0.0})
    oldest: dict[int, tuple] = {}
    newest: dict[int, tuple] = {}
    pims = []

    def record(pairs: list[tuple[dict, int]]) -> None:
        est = s.calculate_estimate()
        keys = [key for _, k in pairs for key in (("x", k), ("b", k))]
        C = s.joint_covariance(keys) if cov else None
        for n, (into, k) in enumerate(pairs):
            Ck = None if C is None else C[15 * n:15 * n + 15, 15 * n:15 * n + 15]
            into[k] = (np.asarray(est[("x", k)].params).copy(), est[("b", k)].copy(), Ck)

    record([(newest, 0)])
    for k in range(1, inp["K"] + 1):
        est = s.calculate_estimate()
        xi, bi = est[("x", k - 1)], est[("b", k - 1)]
        pim = Preintegration(prm["gyro_noise"], prm["accel_noise"], bi[:3], bi[3:])
        pim.integrate(*_samples(data, m, k), data.dt)
        pims.append(pim)
        z = inp["z"][k]
        fns = [
            lambda b, k=k, pim=pim: ImuFactor(b.var(("x", k)), b.var(("b", k - 1)),
                                              b.idx(("x", k - 1)), b.idx(("x", k)), [pim]),
            lambda b, k=k, pim=pim: BiasRandomWalkFactor(
                b.var(("b", k)), b.idx(("b", k - 1)), b.idx(("b", k)), prm["gyro_walk"],
                prm["accel_walk"], pim.dt),
            lambda b, k=k, z=z: PositionFactor(b.var(("x", k)), b.idx(("x", k)), z,
                                               Isotropic(3, SIGMA)),
        ]
        xk = pim.predict(xi)
        s.update(fns, {("x", k): xk, ("b", k): bi.copy()},
                 {("x", k): k * EVERY * data.dt, ("b", k): k * EVERY * data.dt})
        first = min(j for (n, j) in s.timestamps() if n == "x")
        record([(oldest, first), (newest, k)])
    return {"oldest": oldest, "newest": newest, "pims": pims}


def batch_run(inp: dict, pims: list, prm: dict, cov: bool = True) -> dict:
    """The full batch smoother over every keyframe of the run (same prior, preintegrations and
    fixes), from the dead-reckoned start."""
    K = inp["K"]
    g = FactorGraph()
    X0 = [inp["x0"]]
    for p in pims:
        X0.append(p.predict(X0[-1]))
    x = g.add_variables(SE23(np.stack([np.asarray(v.params) for v in X0])))
    b = g.add_variables(np.tile(inp["b0"], (K + 1, 1)))
    P0 = np.diag(P0_STD**2)
    i, j = np.arange(K), np.arange(1, K + 1)
    g.add(PriorFactor(x, 0, inp["x0"], Covariance(P0[:9, :9])))
    g.add(PriorFactor(b, 0, inp["b0"], Covariance(P0[9:, 9:])))
    g.add(ImuFactor(x, b, i, j, pims))
    g.add(BiasRandomWalkFactor(b, i, j, prm["gyro_walk"], prm["accel_walk"],
                               np.array([p.dt for p in pims])))
    g.add(PositionFactor(x, j, inp["z"][1:], Isotropic(3, SIGMA)))
    res = g.optimize(max_iter=50)
    out = {"X": np.asarray(res.values.params(x)), "b": np.asarray(res.values[b])}
    if cov:
        items = [it for k in range(K + 1) for it in ((x, k), (b, k))]
        C = g.marginal_covariance(res.values, items)
        out["C"] = [C[15 * k:15 * k + 15, 15 * k:15 * k + 15] for k in range(K + 1)]
    return out


def resolved(inp: dict, pims: list, prm: dict, window: int) -> tuple[np.ndarray, dict]:
    """The full batch smoother re-solved at every keyframe ``j`` over the data up to ``j`` (what
    a user without a fixed-lag smoother runs; the same information as the window then): the
    positions of the newest keyframe ``x_{j|j}``, ``(K, 3)``, and of the window's oldest,
    ``{k: x_{k|k+W-1}}``."""
    newest = np.zeros((inp["K"], 3))
    oldest = {}
    for j in range(1, inp["K"] + 1):
        sub = dict(inp, K=j, z=inp["z"][: j + 1])
        X = batch_run(sub, pims[:j], prm, cov=False)["X"]
        newest[j - 1] = np.asarray(SE23(X[j]).translation())
        if j - window + 1 >= 1:
            oldest[j - window + 1] = np.asarray(SE23(X[j - window + 1]).translation())
    return newest, oldest


def nees(Xp: np.ndarray, bp: np.ndarray, C: np.ndarray, Xt: SE23, bt: np.ndarray) -> float:
    """``e^T C^-1 e`` with ``e = (Log(X^-1 X_true), b_true - b)``."""
    e = np.r_[np.asarray(Xt.minus(SE23(Xp))), bt - bp]
    return float(e @ np.linalg.solve(C, e))


def eskf_positions(data: Any, runs: list[dict]) -> np.ndarray:
    """The ESKF (right error, batched over the runs) from the same prior and fixes; its
    position estimates at the keyframes ``1..K``, ``(K, M, 3)``."""
    M = len(runs)
    K = runs[0]["K"]
    x0 = SE23(np.stack([np.asarray(r["x0"].params) for r in runs]))
    b0 = np.stack([r["b0"] for r in runs])
    from microlie import R

    state = ESKF_STATE.from_parts(x0.rotation(), R(3)(np.asarray(x0.translation())),
                                  R(3)(np.asarray(x0.velocity())), R(3)(b0[:, :3]),
                                  R(3)(b0[:, 3:]))
    # the prior in the ESKF order (dtheta, dp, dv, b_g, b_a); x0 Exp(rho, phi, nu) moves the
    # position by R rho: the same distribution to first order with p's covariance R S R^T
    perm = np.r_[3:6, 0:3, 6:9, 9:15]
    P = np.diag(P0_STD[perm] ** 2)
    Rm = np.asarray(x0.rotation().matrix())
    Pb = np.broadcast_to(P, (M, 15, 15)).copy()
    for blk in (slice(3, 6), slice(6, 9)):
        Pb[:, blk, blk] = Rm @ P[blk, blk] @ np.swapaxes(Rm, -1, -2)
    f = ErrorStateEKF(state, Pb, side="right", **data.params)
    out = np.zeros((K, M, 3))
    for k in range(1, K + 1):
        for n in range((k - 1) * EVERY, k * EVERY):
            f.predict(data.accel[n], data.gyro[n], data.dt)
        f.update_position(np.stack([r["z"][k] for r in runs]), SIGMA)
        out[k - 1] = f.p
    return out


def monte_carlo(runs: int, duration: float, window: int, variant: str = "fej",
                seed: int = 11, eskf: bool = True, resolve: bool = False,
                smoother: str = "batch", cov: bool = True, **options: Any) -> dict:
    """NEES and RMSE of a fixed-lag smoother (:func:`make_smoother`), the full batch smoother
    and the ESKF over ``runs`` Monte Carlo runs (see the module docstring); with ``resolve``
    also the full batch smoother re-solved at every keyframe on the data so far
    (:func:`resolved`): its newest keyframe (``resolve_newest``, against the fixed-lag
    smoother's newest estimate on the same keyframes, ``newest_same``) and the window's oldest
    (``resolve_lag``, against the fixed-lag estimate ``x_{k|k+W-1}`` on the same keyframes,
    ``lag_same``); without ``cov`` no covariances (no NEES: NaN)."""
    data = make_data(runs, duration)
    rng = np.random.default_rng(seed)
    ins = [inputs(data, m, rng) for m in range(runs)]
    K = ins[0]["K"]
    lag_nees = np.full((runs, K + 1), np.nan)
    new_nees = np.full((runs, K + 1), np.nan)
    bat_nees = np.zeros((runs, K + 1))
    err: dict[str, list] = {"lag": [], "newest": [], "batch": [], "resolve_newest": [],
                            "newest_same": [], "resolve_lag": [], "lag_same": []}
    t_lag = t_bat = 0.0
    for m in range(runs):
        t0 = time.perf_counter()
        fl = fixed_lag_run(data, m, ins[m], window, variant, cov, smoother, **options)
        t_lag += time.perf_counter() - t0
        t0 = time.perf_counter()
        bt = batch_run(ins[m], fl["pims"], data.params, cov)
        t_bat += time.perf_counter() - t0
        Xt, btrue = ins[m]["X"], ins[m]["b"]
        for k in range(1, K + 1):
            for name, table, store in (("lag", fl["oldest"], lag_nees),
                                       ("newest", fl["newest"], new_nees)):
                if k in table:
                    Xp, bp, C = table[k]
                    if C is not None:
                        store[m, k] = nees(Xp, bp, C, Xt[k], btrue[k])
                    err[name].append(np.asarray(SE23(Xp).translation()) -
                                     np.asarray(Xt[k].translation()))
            bat_nees[m, k] = (nees(bt["X"][k], bt["b"][k], bt["C"][k], Xt[k], btrue[k])
                              if cov else np.nan)
            if k in fl["oldest"]:
                err["batch"].append(np.asarray(SE23(bt["X"][k]).translation()) -
                                    np.asarray(Xt[k].translation()))
        if resolve:
            pr, po = resolved(ins[m], fl["pims"], data.params, window)
            err["resolve_newest"].extend(pr - np.asarray(Xt.translation())[1:])
            err["newest_same"].extend(
                np.asarray(SE23(fl["newest"][k][0]).translation()) -
                np.asarray(Xt[k].translation()) for k in range(1, K + 1))
            for k, p in po.items():
                if k in fl["oldest"]:
                    err["resolve_lag"].append(p - np.asarray(Xt[k].translation()))
                    err["lag_same"].append(np.asarray(SE23(fl["oldest"][k][0]).translation())
                                           - np.asarray(Xt[k].translation()))
    rmse = {n: float(np.sqrt(np.mean(np.sum(np.array(v) ** 2, -1)))) for n, v in err.items()
            if v}
    if eskf:
        pe = eskf_positions(data, ins)
        pt = np.stack([np.asarray(r["X"].translation())[1:] for r in ins], 1)
        rmse["eskf"] = float(np.sqrt(np.mean(np.sum((pe - pt) ** 2, -1))))
    return {"lag_nees": lag_nees, "newest_nees": new_nees, "batch_nees": bat_nees,
            "rmse": rmse, "K": K, "time_lag": t_lag, "time_batch": t_bat}


def band(runs: int, dof: int = 15, p: float = 0.95) -> tuple[float, float]:
    """The two-sided ``p`` band of the average NEES of ``runs`` consistent runs."""
    from scipy.stats import chi2  # type: ignore[import-untyped]

    lo, hi = chi2.ppf([(1 - p) / 2, (1 + p) / 2], dof * runs) / runs
    return float(lo), float(hi)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=0, help="Monte Carlo runs (0: skip)")
    ap.add_argument("--duration", type=float, default=12.0, help="seconds per run")
    ap.add_argument("--window", type=int, default=WINDOW, help="keyframes in the window")
    ap.add_argument("--smoothers", nargs="+", default=["batch", "incremental"],
                    choices=["batch", "incremental"], help="the fixed-lag smoothers to run")
    ap.add_argument("--variant", default="fej", choices=["fej", "drop"])
    ap.add_argument("--resolve", action="store_true",
                    help="also re-solve the full batch at every keyframe (slow)")
    ap.add_argument("--curve", type=int, nargs="*", default=[],
                    help="windows (keyframes) of the RMSE-ratio curve over --runs runs (default "
                         "10), no covariances; replaces the NEES pass")
    ap.add_argument("--trace", action="store_true",
                    help="also trace Python allocations (tracemalloc; slows every update)")
    ap.add_argument("--steps", type=int, default=0, help="IMU steps of the timing run (0: skip)")
    a = ap.parse_args()
    print(f"load (1, 5, 15 min): {os.getloadavg()}")
    lo, hi = band(a.runs) if a.runs else (0.0, 0.0)
    for sm in a.smoothers if a.runs and not a.curve else []:
        r = monte_carlo(a.runs, a.duration, a.window, a.variant, resolve=a.resolve, smoother=sm)
        e = r["rmse"]
        print(f"{sm}: {a.runs} runs of {a.duration} s, {r['K']} keyframes, window {a.window}, "
              f"variant {a.variant}; 95% band of the average NEES: [{lo:.2f}, {hi:.2f}]")
        for name in ("lag_nees", "newest_nees", "batch_nees"):
            t = r[name][:, 1:]
            v = t[:, np.isfinite(t).all(0)].mean(0)
            print(f"  {name:12s} average over runs: mean {v.mean():.2f}, final {v[-1]:.2f}, "
                  f"outside the band at {np.mean((v < lo) | (v > hi)):.0%} of keyframes")
        print("  position RMSE (m): " + ", ".join(f"{k} {v:.4f}" for k, v in e.items()
                                                   if np.isfinite(v)))
        print(f"  RMSE ratios: smoothed x_k|k+W-1 / whole-run batch smoother x_k|K "
              f"{e['lag'] / e['batch']:.3f}; newest x_k|k / ESKF x_k|k "
              f"{e['newest'] / e['eskf']:.3f}; smoothed / ESKF {e['lag'] / e['eskf']:.3f}")
        if a.resolve:
            print(f"  same data (batch re-solved at each keyframe): newest "
                  f"{e['newest_same'] / e['resolve_newest']:.3f}, smoothed "
                  f"{e['lag_same'] / e['resolve_lag']:.3f}")
        print(f"  time: fixed-lag {r['time_lag']:.1f} s, batch {r['time_batch']:.1f} s",
              flush=True)
    for sm in a.smoothers if a.curve else []:
        for w in a.curve:
            r = monte_carlo(a.runs or 10, a.duration, w, smoother=sm, cov=False, eskf=False)
            print(f"{sm} window {w}: smoothed x_k|k+W-1 / whole-run batch smoother RMSE "
                  f"{r['rmse']['lag'] / r['rmse']['batch']:.3f} ({r['rmse']['lag']:.4f} / "
                  f"{r['rmse']['batch']:.4f} m)", flush=True)
    for sm in a.smoothers if a.steps else []:
        steps(a.steps, a.window, sm, a.trace)


def steps(n: int, window: int, smoother: str = "batch", trace: bool = False) -> None:
    """Time per update and peak memory over ``n`` IMU steps (see the module docstring)."""
    import resource
    import tracemalloc

    dur = 8.0
    data = make_data(1, dur)
    rng = np.random.default_rng(3)
    inp = inputs(data, 0, rng)
    per = inp["K"]
    prm = data.params
    P0 = np.diag(P0_STD**2)
    s = make_smoother(smoother, window)
    x0, b0 = inp["x0"], inp["b0"]
    s.update([lambda b: PriorFactor(*b[("x", 0)], x0, Covariance(P0[:9, :9])),
              lambda b: PriorFactor(*b[("b", 0)], b0, Covariance(P0[9:, 9:]))],
             {("x", 0): x0, ("b", 0): b0.copy()}, {("x", 0): 0.0, ("b", 0): 0.0})
    updates = n // EVERY
    times = np.zeros(updates)
    if trace:
        tracemalloc.start()
    rss = []
    offset = np.zeros(3)
    for k in range(1, updates + 1):
        kk = (k - 1) % per + 1  # the trajectory's samples, repeated; fixes shifted to follow
        if kk == 1 and k > 1:
            est = s.calculate_estimate()[("x", k - 1)]
            offset = np.asarray(est.translation()) - np.asarray(inp["X"][0].translation())
        est = s.calculate_estimate()
        xi, bi = est[("x", k - 1)], est[("b", k - 1)]
        t0 = time.perf_counter()
        pim = Preintegration(prm["gyro_noise"], prm["accel_noise"], bi[:3], bi[3:])
        pim.integrate(*_samples(data, 0, kk), data.dt)
        z = inp["z"][kk] + offset
        fns = [
            lambda b, k=k, pim=pim: ImuFactor(b.var(("x", k)), b.var(("b", k - 1)),
                                              b.idx(("x", k - 1)), b.idx(("x", k)), [pim]),
            lambda b, k=k, pim=pim: BiasRandomWalkFactor(
                b.var(("b", k)), b.idx(("b", k - 1)), b.idx(("b", k)), prm["gyro_walk"],
                prm["accel_walk"], pim.dt),
            lambda b, k=k, z=z: PositionFactor(b.var(("x", k)), b.idx(("x", k)), z,
                                               Isotropic(3, SIGMA)),
        ]
        tk = k * EVERY * data.dt
        s.update(fns, {("x", k): pim.predict(xi), ("b", k): bi.copy()},
                 {("x", k): tk, ("b", k): tk})
        times[k - 1] = time.perf_counter() - t0
        if k in (1000 // EVERY, updates):
            with open("/proc/self/statm") as fh:
                rss.append(int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6)
        if k % 1000 == 0:
            with open("/proc/self/statm") as fh:
                now = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
            print(f"  {k * EVERY} steps: median update over the last 1000 steps "
                  f"{1e3 * np.median(times[k - 1000 // EVERY:k]):.2f} ms, window "
                  f"{len(s.calculate_estimate())} keys, {len(s.priors)} prior(s), resident "
                  f"{now:.1f} MB", flush=True)
    first, last = times[: 1000 // EVERY], times[-(1000 // EVERY):]
    print(f"{smoother}: {n} IMU steps ({updates} updates, window {window} keyframes): "
          f"median update {1e3 * np.median(first):.2f} ms over the first 1000 steps, "
          f"{1e3 * np.median(last):.2f} ms over the last 1000 (ratio "
          f"{np.median(last) / np.median(first):.3f}); per IMU step "
          f"{1e3 * np.median(last) / EVERY:.3f} ms")
    print(f"resident memory after the first 1000 steps {rss[0]:.1f} MB, at the end "
          f"{rss[-1]:.1f} MB; process peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB")
    if trace:
        cur, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(f"peak traced Python memory {peak / 1e6:.2f} MB (now {cur / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
