"""Worked example: an uncertain planar robot pose composed along a path.

A robot starts at a well-known pose and drives a gentle curve in steps of 0.5 m. Each odometry
step is an uncertain SE(2) increment ``U_k`` with a right-frame (body) covariance ``Q``. The pose
is propagated with eq. (17) of ``../shared/MATH.md``::

    X_k+1 = X_k U_k,    P_k+1 = Ad_U^-1 P_k Ad_U^-T + Q      (right errors)

and the world position's uncertainty is the point Gaussian of ``X_k . (0, 0)``. The plot shows
the mean path with its 2-sigma position ellipses growing along the way, next to Monte Carlo
samples of the exact process: where the heading uncertainty is large the cloud bends into a
"banana" that a Gaussian in the plane (any linearisation) cannot follow.

Usage::

    python examples/uncertainty_path.py [out/uncertainty_path.png] [--samples 5000] [--steps 30]
                                        [--seed 0] [--dpi 90]

Needs matplotlib (``pip install 'microlie[plot]'``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from microlie import SE2
from microlie.uncertainty import Gaussian


def simulate(steps: int, samples: int, seed: int):
    """Propagate the Gaussian and the Monte Carlo particles; return both, step by step."""
    rng = np.random.default_rng(seed)
    step = SE2.from_xy_theta(0.5, 0.0, 0.06)  # 0.5 m forward, turning 0.06 rad
    Q = np.diag([0.02, 0.01, 0.04]) ** 2  # body frame: along, across (m), heading (rad)
    X = Gaussian.from_std(SE2.identity(), [0.01, 0.01, 0.005], frame="right")
    particles = X.sample(samples, rng=rng)
    U = Gaussian(step, Q, frame="right")
    gaussians, clouds = [X], [particles]
    for _ in range(steps):
        X = X.compose(U)  # eq. (17), right frame
        particles = particles @ U.sample(samples, rng=rng)  # the exact process
        gaussians.append(X)
        clouds.append(particles)
    return gaussians, clouds


def require_pyplot():
    """Import matplotlib lazily (optional extra) with the Agg backend."""
    try:
        import matplotlib
    except ImportError as exc:
        raise SystemExit("this example plots with matplotlib: pip install 'microlie[plot]'"
                         ) from exc
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def plot(gaussians, clouds, out: Path, every: int = 5, dpi: int = 90) -> None:
    plt = require_pyplot()
    origin = np.zeros(2)
    positions = [g.act(origin) for g in gaussians]  # world-frame point Gaussians
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11.0, 4.6),
                                  gridspec_kw={"width_ratios": [1.6, 1.0]})
    path = np.array([p.mean for p in positions])
    ax.plot(path[:, 0], path[:, 1], "k-", lw=1.2, label="mean path")
    for k in range(0, len(gaussians), every):
        cloud = clouds[k].translation()
        ax.plot(cloud[:, 0], cloud[:, 1], ".", ms=1.0, alpha=0.25, color="tab:blue",
                label="Monte Carlo (exact)" if k == every else None)
    for k in range(1, len(gaussians)):
        e = positions[k].ellipse(nsigma=2.0)
        strong = k % every == 0
        ax.plot(e[:, 0], e[:, 1], color="tab:red", lw=1.4 if strong else 0.6,
                alpha=1.0 if strong else 0.3,
                label="2-sigma, linearised (eq. 17)" if k == every else None)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Uncertain SE(2) pose composed along a path")
    ax.legend(loc="lower right", fontsize=8, markerscale=8)

    ks = np.arange(len(gaussians))
    lin = np.array([p.std() for p in positions])
    mc = np.array([c.translation().std(axis=0) for c in clouds])
    head_lin = np.array([np.sqrt(g.cov[2, 2]) for g in gaussians])
    for i, name in enumerate("xy"):
        ax2.plot(ks, lin[:, i], "-", color=f"C{i}", label=f"std {name}, linearised")
        ax2.plot(ks, mc[:, i], "o", ms=3, color=f"C{i}", label=f"std {name}, Monte Carlo")
    ax2.plot(ks, head_lin, "--", color="gray", label="std heading [rad]")
    ax2.set_xlabel("step")
    ax2.set_ylabel("standard deviation [m]")
    ax2.set_title("Growth of the position uncertainty")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="out/uncertainty_path.png", type=Path,
                    help="PNG to write (default: out/uncertainty_path.png)")
    ap.add_argument("--samples", type=int, default=5000, help="Monte Carlo particles")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dpi", type=int, default=90, help="resolution of the PNG")
    args = ap.parse_args(argv)
    gaussians, clouds = simulate(args.steps, args.samples, args.seed)
    print(f"{'step':>4s} {'std x lin':>10s} {'std x MC':>9s} {'std y lin':>10s} {'std y MC':>9s}")
    for k in range(0, args.steps + 1, 5):
        lin = gaussians[k].act(np.zeros(2)).std()
        mc = clouds[k].translation().std(axis=0)
        print(f"{k:4d} {lin[0]:10.4f} {mc[0]:9.4f} {lin[1]:10.4f} {mc[1]:9.4f}")
    plot(gaussians, clouds, args.out, dpi=args.dpi)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
