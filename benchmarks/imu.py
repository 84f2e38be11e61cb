"""IMU preintegration speed: microlie's vectorised ``Preintegration.integrate`` against GTSAM's
Python loop over ``integrateMeasurement`` on the same samples (both classes: the default
tangent-space ``PreintegratedImuMeasurements`` and ``PreintegratedImuMeasurementsManifold``);
also microlie called once per sample (``microlie-loop``, buffered internally).

Run from the repository root in the benchmark environment (GTSAM 4.3 installed):

    PYTHONPATH=$PWD/src /work/bench-venv/bin/python benchmarks/imu.py [--n 100000] [--repeat 5]

The runs alternate (ours, GTSAM, ours, ...) in one process; the table gives the median and the
spread (min-max) of each, the ratio of the medians, and the machine load. Before timing, the
results are checked equal (deltas to 1e-6 relative after 1e5 samples, to catch a wrong
comparison rather than to test: tests/test_imu_preintegration.py does that).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from microlie.imu import Preintegration


def samples(n: int, dt: float):
    rng = np.random.default_rng(0)
    t = np.arange(n) * dt
    gyro = np.stack([0.6 * np.sin(1.3 * t), 0.4 * np.cos(0.7 * t), 0.9 * np.sin(0.5 * t)], -1)
    accel = np.stack([1.5 * np.cos(2 * t), 0.8 * np.sin(1.1 * t), 9.81 + 0.5 * np.sin(3 * t)], -1)
    return accel + 0.01 * rng.standard_normal((n, 3)), gyro + 1e-3 * rng.standard_normal((n, 3))


BG, BA = np.array([0.01, -0.02, 0.015]), np.array([0.1, -0.05, 0.2])
SG, SA = 1.7e-4, 2.0e-3


def ours(accel, gyro, dt):
    return Preintegration(gyro_noise=SG, accel_noise=SA, bias_gyro=BG,
                          bias_accel=BA).integrate(accel, gyro, dt)


def ours_loop(accel, gyro, dt):
    """One integrate() call per sample, as a GTSAM user would write it."""
    pim = Preintegration(gyro_noise=SG, accel_noise=SA, bias_gyro=BG, bias_accel=BA)
    for a, w in zip(accel, gyro, strict=True):
        pim.integrate(a, w, dt)
    pim.covariance  # noqa: B018 (reading a result integrates the buffered samples)
    return pim


def gtsam_loop(cls, accel, gyro, dt):
    import gtsam

    p = gtsam.PreintegrationParams.MakeSharedU(9.81)
    p.setGyroscopeCovariance(SG**2 * np.eye(3))
    p.setAccelerometerCovariance(SA**2 * np.eye(3))
    p.setIntegrationCovariance(np.zeros((3, 3)))
    pim = cls(p, gtsam.imuBias.ConstantBias(BA, BG))
    for a, w in zip(accel, gyro, strict=True):
        pim.integrateMeasurement(a, w, dt)
    return pim


def main() -> None:
    import gtsam

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    dt = 1.0 / 200.0
    accel, gyro = samples(args.n, dt)
    # accel, gyro as GTSAM receives them (contiguous rows, one call per sample)
    mine = ours(accel, gyro, dt)
    ref = gtsam_loop(gtsam.PreintegratedImuMeasurementsManifold, accel, gyro, dt)
    dv = np.linalg.norm(mine.delta_velocity - ref.deltaVij()) / np.linalg.norm(ref.deltaVij())
    dp = np.linalg.norm(mine.delta_position - ref.deltaPij()) / np.linalg.norm(ref.deltaPij())
    assert dv < 1e-6 and dp < 1e-6, (dv, dp)
    runs: dict[str, list[float]] = {"microlie": [], "microlie-loop": [], "gtsam-manifold": [],
                                    "gtsam-default": []}
    fns = {"microlie": lambda: ours(accel, gyro, dt),
           "microlie-loop": lambda: ours_loop(accel, gyro, dt),
           "gtsam-manifold": lambda: gtsam_loop(gtsam.PreintegratedImuMeasurementsManifold,
                                                accel, gyro, dt),
           "gtsam-default": lambda: gtsam_loop(gtsam.PreintegratedImuMeasurements, accel, gyro,
                                               dt)}
    for _ in range(args.repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            runs[name].append(time.perf_counter() - t0)
    med = {k: float(np.median(v)) for k, v in runs.items()}
    print(f"IMU preintegration of {args.n} samples (200 Hz), {args.repeat} alternating runs; "
          f"load {os.getloadavg()[0]:.2f} (1 min)")
    print("| implementation | median s | min-max s | ratio to microlie |")
    print("|---|---|---|---|")
    for k, v in runs.items():
        print(f"| {k} | {med[k]:.4f} | {min(v):.4f}-{max(v):.4f} | "
              f"{med[k] / med['microlie']:.1f}x |")


if __name__ == "__main__":
    main()
