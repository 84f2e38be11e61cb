"""Worked example: IMU navigation with position fixes on EuRoC V1_02-derived data.

1. Fit a smooth trajectory to the EuRoC V1_02 ground truth and synthesise 200 Hz IMU samples
   with the ADIS16448's noise densities and random-walk biases (``microlie.imu.simulate``).
2. Fuse them with noisy position fixes (1 Hz, 0.1 m) in an error-state EKF
   (``Product(SO3, R3, R3, R3, R3)``, right attitude error) and in the invariant EKF
   (``Product(SE23, R3, R3)``, left error on SE_2(3)).
3. Smooth the same data with the factor-graph solver: SE23 keyframes at the fixes, one
   ``ImuFactor`` (preintegrated samples) and one ``BiasRandomWalkFactor`` per interval, the fixes
   as custom factors and a prior on the first state.
4. Print the position RMSE of each against the truth and plot the three trajectories.

Usage::

    python examples/inertial.py [docs/img/inertial_v102.png] [--duration 30] [--seed 0]

Needs matplotlib for the plot (``pip install 'microlie[plot]'``) and ``../shared/data``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from microlie import SE23, SO3, R
from microlie.imu import (
    BiasRandomWalkFactor,
    ImuFactor,
    Preintegration,
    SmoothTrajectory,
    simulate_imu,
)
from microlie.imu.filters import ESKF_STATE, IEKF_STATE, ErrorStateEKF, InvariantEKF
from microlie.imu.simulate import integrate_states, load_euroc_groundtruth
from microlie.optim import CustomFactor, FactorGraph, Isotropic, PriorFactor

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "trajectory" / "evo"
FIX_EVERY = 200  # samples between position fixes (1 Hz at 200 Hz)
FIX_SIGMA = 0.1  # m
P0_STD = np.r_[np.full(3, 0.01), np.full(3, 0.05), np.full(3, 0.05), np.full(3, 0.003),
               np.full(3, 0.02)]  # attitude, position, velocity, b_g, b_a (ESKF order)


def run_filters(data, fixes, rng):
    X0 = data.truth[0]
    e0 = rng.standard_normal(15) * P0_STD  # one initial error, the same for both filters
    Rq = X0.rotation() @ SO3.exp(-e0[0:3])
    vecs = [np.asarray(X0.translation()) - e0[3:6], np.asarray(X0.velocity()) - e0[6:9],
            -e0[9:12], -e0[12:15]]
    eskf = ErrorStateEKF(ESKF_STATE.from_parts(Rq, *(R(3)(v) for v in vecs)),
                         np.diag(P0_STD**2), **data.params)
    iekf_state = IEKF_STATE.from_parts(SE23.from_rotation_translation(Rq, vecs[0], vecs[1]),
                                       R(3)(vecs[2]), R(3)(vecs[3]))
    order = np.r_[3:6, 0:3, 6:15]  # ESKF (theta, p, v, ...) -> IEKF (rho, phi, nu, ...)
    iekf = InvariantEKF(iekf_state, np.diag(P0_STD[order] ** 2), **data.params)
    tracks: dict[str, list] = {"ESKF": [eskf.p.copy()], "IEKF": [iekf.p.copy()]}
    for k in range(len(data.t)):
        for f in (eskf, iekf):
            f.predict(data.accel[k], data.gyro[k], data.dt)
        if (k + 1) % FIX_EVERY == 0:
            z = fixes[(k + 1) // FIX_EVERY]
            eskf.update_position(z, FIX_SIGMA)
            iekf.update_position(z, FIX_SIGMA)
        tracks["ESKF"].append(eskf.p.copy())
        tracks["IEKF"].append(iekf.p.copy())
    return {k: np.array(v) for k, v in tracks.items()}


def run_smoother(data, fixes):
    nk = len(data.t) // FIX_EVERY
    kf = np.arange(nk + 1) * FIX_EVERY
    pims = [Preintegration(gyro_noise=data.params["gyro_noise"],
                           accel_noise=data.params["accel_noise"]).integrate(
        data.accel[kf[k]:kf[k + 1]], data.gyro[kf[k]:kf[k + 1]], data.dt) for k in range(nk)]
    # initial keyframe states: dead reckoning from the (noisy) first state and zero biases
    X = [data.truth[0]]
    for p in pims:
        X.append(p.predict(X[-1]))
    g = FactorGraph()
    x = g.add_variables(SE23(np.stack([np.asarray(s.params) for s in X])))
    b = g.add_variables(np.zeros((nk + 1, 6)))
    i, j = np.arange(nk), np.arange(1, nk + 1)
    g.add(ImuFactor(x, b, i, j, pims))
    g.add(BiasRandomWalkFactor(b, i, j, data.params["gyro_walk"], data.params["accel_walk"],
                               FIX_EVERY * data.dt))
    g.add(PriorFactor(x, 0, data.truth[0], Isotropic(9, 0.05)))
    g.add(PriorFactor(b, 0, np.zeros(6), Isotropic(6, 0.05)))
    g.add(CustomFactor(lambda Xv, z: np.asarray(Xv.translation()) - z, [(x, np.arange(nk + 1))],
                       3, Isotropic(3, FIX_SIGMA), data=[fixes[: nk + 1]]))
    res = g.optimize(max_iter=30)
    Xs, bs = res.values[x], res.values[b]
    # the full-rate path: each keyframe dead-reckoned over its interval with its biases
    dense = [np.asarray(integrate_states(Xs[k], data.accel[kf[k]:kf[k + 1]] - bs[k, 3:],
                                         data.gyro[kf[k]:kf[k + 1]] - bs[k, :3], data.dt,
                                         data.gravity).translation())[:-1] for k in range(nk)]
    return res, np.asarray(Xs.translation()), kf, np.concatenate(dense)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="?", default="docs/img/inertial_v102.png")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    t, poses = load_euroc_groundtruth(DATA / "V102_groundtruth.csv")
    traj = SmoothTrajectory.from_poses(t, poses, knot_dt=0.1)
    data = simulate_imu(traj, duration=args.duration, start=traj.t0 + 5.0, rng=rng)
    truth_p = np.asarray(data.truth.translation())
    fixes = truth_p[::FIX_EVERY] + FIX_SIGMA * rng.standard_normal(
        (len(truth_p[::FIX_EVERY]), 3))
    tracks = run_filters(data, fixes, rng)
    res, smooth_p, kf, smooth_dense = run_smoother(data, fixes)
    print(f"{args.duration:.0f} s of EuRoC V1_02 motion, 200 Hz IMU (ADIS16448 densities), "
          f"position fixes every {FIX_EVERY * data.dt:.0f} s with sigma {FIX_SIGMA} m")
    print(f"smoother: {res.iterations} iterations, cost {res.initial_cost:.3g} -> "
          f"{res.final_cost:.3g} ({res.message})")
    rmse = {k: np.sqrt(np.mean(np.sum((v[kf] - truth_p[kf]) ** 2, -1))) for k, v in
            tracks.items()}
    rmse["smoother"] = np.sqrt(np.mean(np.sum((smooth_p - truth_p[kf]) ** 2, -1)))
    rmse["fixes"] = np.sqrt(np.mean(np.sum((fixes[: len(kf)] - truth_p[kf]) ** 2, -1)))
    for k, v in rmse.items():
        print(f"  position RMSE at the keyframes, {k:8s}: {v:.4f} m")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot")
        return
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.plot(truth_p[:, 0], truth_p[:, 1], "k-", lw=2.5, label="ground truth (fit)")
    for name, st in (("ESKF", "C0-"), ("IEKF", "C1--")):
        ax.plot(tracks[name][:, 0], tracks[name][:, 1], st, lw=1,
                label=f"{name} (RMSE {rmse[name]:.3f} m)")
    ax.plot(smooth_dense[:, 0], smooth_dense[:, 1], "C2-", lw=1,
            label=f"smoother (RMSE {rmse['smoother']:.3f} m)")
    ax.plot(smooth_p[:, 0], smooth_p[:, 1], "C2o", ms=3)
    ax.plot(fixes[:, 0], fixes[:, 1], "x", color="0.5", ms=4, label="position fixes")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax.set_title("EuRoC V1_02: synthetic IMU + 1 Hz position fixes")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90, bbox_inches="tight")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
