"""Generate the example trajectory pair bundled in ``src/microlie/data/``.

Synthetic and therefore free to redistribute (MIT, like microlie). The reference is a smooth
3-D loop sampled at 5 Hz for 30 s; the estimate is sampled at other instants (3 ms later), is
expressed in another world frame (a rigid transform the SE(3) alignment recovers) and carries
an accumulating random-walk drift plus per-pose noise. Run from the repository root::

    python examples/make_example_data.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from microlie import SE3, SO3
from microlie.traj import Trajectory

OUT = Path(__file__).resolve().parents[1] / "src" / "microlie" / "data"


def reference_path(stamps: np.ndarray, t0: float) -> Trajectory:
    """A figure-eight with a gentle climb; the body x axis follows the velocity."""
    t = stamps - t0
    w = 2 * np.pi / 30.0
    p = np.column_stack([4.0 * np.sin(w * t), 2.0 * np.sin(2 * w * t), 0.5 * np.sin(w * t) + 1.0])
    v = np.column_stack([4.0 * w * np.cos(w * t), 4.0 * w * np.cos(2 * w * t),
                         0.5 * w * np.cos(w * t)])
    yaw = np.arctan2(v[:, 1], v[:, 0])
    pitch = -np.arctan2(v[:, 2], np.hypot(v[:, 0], v[:, 1]))
    roll = 0.05 * np.sin(3 * w * t)
    rot = SO3.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
    return Trajectory(SE3.from_rotation_translation(rot, p), stamps, "example_gt")


def main() -> None:
    rng = np.random.default_rng(7)
    t_gt = np.round(np.arange(0.0, 30.0, 0.2), 6) + 1700000000.0
    gt = reference_path(t_gt, t_gt[0])
    t_est = t_gt[2:-3] + 0.003
    est_true = reference_path(t_est, t_gt[0])
    n = len(t_est)
    # accumulated drift: a random walk in the tangent space, applied on the right
    steps = rng.normal(scale=[0.004, 0.004, 0.002, 0.0008, 0.0008, 0.0015], size=(n, 6))
    drift = SE3.exp(np.cumsum(steps, axis=0))
    noise = SE3.exp(rng.normal(scale=[0.01, 0.01, 0.01, 0.002, 0.002, 0.002], size=(n, 6)))
    world = SE3.from_rotation_translation(SO3.from_euler("ZYX", [0.6, 0.05, -0.03]),
                                          np.array([1.5, -0.7, 0.2]))
    est = Trajectory(world @ (est_true.poses @ drift @ noise), t_est, "example_est")
    OUT.mkdir(parents=True, exist_ok=True)
    hdr = "microlie example ({}), synthetic, see examples/make_example_data.py\n" \
          "timestamp tx ty tz qx qy qz qw"
    for name, tr in (("example_gt.tum", gt), ("example_est.tum", est)):
        data = np.column_stack([tr.timestamps, tr.positions, tr.quat_xyzw])
        np.savetxt(OUT / name, data, fmt=["%.6f"] + ["%.6f"] * 3 + ["%.8f"] * 4,
                   header=hdr.format(name))
        print("wrote", OUT / name)


if __name__ == "__main__":
    main()
