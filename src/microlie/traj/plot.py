"""Trajectory plots (matplotlib, an optional dependency: ``pip install microlie[plot]``).

* :func:`plot_trajectories`: top view, 3-D view, x/y/z and roll/pitch/yaw over time.
* :func:`plot_error`: the estimate's path coloured by a per-pose error, next to the error
  over time (or index) with its rmse / mean / median lines.

Both return the matplotlib ``Figure``; :func:`save` writes it (PNG by default) with a fixed size
in pixels so files are reproducible.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .metrics import PoseError
from .trajectory import Trajectory

__all__ = ["plot_trajectories", "plot_error", "save", "require_matplotlib", "FIGSIZE", "DPI"]

FIGSIZE = (12.0, 8.0)  # inches
DPI = 100  # -> 1200 x 800 pixels


def require_matplotlib() -> Any:
    """Import ``matplotlib`` with the non-interactive Agg backend, or explain how to get it."""
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - exercised only without matplotlib
        raise ImportError(
            "plotting needs matplotlib: pip install 'microlie[plot]'"
        ) from exc
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _time_axis(t: Trajectory) -> tuple[np.ndarray, str]:
    if t.timestamps is not None:
        return t.timestamps - t.timestamps[0], "t (s)"
    return np.arange(len(t), dtype=float), "index"


def plot_trajectories(
    trajs: Sequence[Trajectory], labels: Sequence[str] | None = None, title: str | None = None
) -> Any:
    """Overview figure of one or more trajectories (the first is drawn as the reference)."""
    plt = require_matplotlib()
    if labels is None:
        labels = [t.name or f"traj {i}" for i, t in enumerate(trajs)]
    labels = [Path(str(lab)).name for lab in labels]
    fig = plt.figure(figsize=FIGSIZE, dpi=DPI)
    gs = fig.add_gridspec(6, 4)
    ax_top = fig.add_subplot(gs[0:3, 0:2])
    ax_3d = fig.add_subplot(gs[3:6, 0:2], projection="3d")
    ax_xyz = [fig.add_subplot(gs[2 * k:2 * k + 2, 2]) for k in range(3)]
    ax_rpy = [fig.add_subplot(gs[2 * k:2 * k + 2, 3]) for k in range(3)]
    for i, (t, lab) in enumerate(zip(trajs, labels, strict=True)):
        p = t.positions
        style = {"ls": "--", "color": "0.3"} if i == 0 and len(trajs) > 1 else {}
        ax_top.plot(p[:, 0], p[:, 1], label=lab, lw=1, **style)
        ax_3d.plot(p[:, 0], p[:, 1], p[:, 2], lw=1, **style)
        x, xl = _time_axis(t)
        rpy = np.rad2deg(np.unwrap(t.euler("xyz"), axis=0))
        for k in range(3):
            ax_xyz[k].plot(x, p[:, k], lw=1, **style)
            ax_rpy[k].plot(x, rpy[:, k], lw=1, **style)
    ax_top.set_xlabel("x (m)")
    ax_top.set_ylabel("y (m)")
    ax_top.set_aspect("equal", adjustable="box")
    ax_top.set_title("top view")
    ax_top.legend(fontsize="small")
    ax_3d.set_xlabel("x")
    ax_3d.set_ylabel("y")
    ax_3d.set_zlabel("z")
    ax_3d.set_title("3-D")
    for k, n in enumerate("xyz"):
        ax_xyz[k].set_ylabel(f"{n} (m)")
    for k, n in enumerate(("roll", "pitch", "yaw")):
        ax_rpy[k].set_ylabel(f"{n} (deg)")
    ax_xyz[-1].set_xlabel(xl)
    ax_rpy[-1].set_xlabel(xl)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_error(res: PoseError, title: str | None = None) -> Any:
    """Path of the (aligned) estimate coloured by error, and the error sequence."""
    plt = require_matplotlib()
    if res.ref is None or res.est is None:
        raise ValueError("the result carries no trajectories to plot")
    fig = plt.figure(figsize=FIGSIZE, dpi=DPI)
    ax_path = fig.add_subplot(1, 2, 1)
    ax_err = fig.add_subplot(1, 2, 2)
    ref_p = res.ref.positions
    est_p = res.est.positions
    idx = np.arange(len(res.est)) if res.pairs is None else res.pairs[:, 1]
    ax_path.plot(ref_p[:, 0], ref_p[:, 1], "--", color="0.4", lw=1, label="reference")
    sc = ax_path.scatter(est_p[idx, 0], est_p[idx, 1], c=res.errors, s=6, cmap="jet")
    ax_path.plot(est_p[:, 0], est_p[:, 1], color="0.7", lw=0.5, zorder=0)
    unit = f" ({res.unit})" if res.unit else ""
    fig.colorbar(sc, ax=ax_path, label=f"{res.metric.upper()} {res.relation}{unit}")
    ax_path.set_aspect("equal", adjustable="datalim")
    ax_path.set_xlabel("x (m)")
    ax_path.set_ylabel("y (m)")
    ax_path.legend(fontsize="small")
    x, xl = _time_axis(res.est)
    ax_err.plot(x[idx], res.errors, lw=1, color="tab:gray")
    for key, c in (("rmse", "tab:blue"), ("mean", "tab:green"), ("median", "tab:red")):
        ax_err.axhline(res.stats[key], color=c, lw=1, label=f"{key} {res.stats[key]:.4g}")
    ax_err.set_xlabel(xl)
    ax_err.set_ylabel(f"{res.relation}{unit}")
    ax_err.legend(fontsize="small")
    fig.suptitle(title or f"{res.metric.upper()} w.r.t. {res.relation}{unit}")
    fig.tight_layout()
    return fig


def save(fig: Any, path: str | Path) -> Path:
    """Save ``fig`` at :data:`DPI` (format from the file suffix) and close it."""
    plt = require_matplotlib()
    path = Path(path)
    fig.set_size_inches(*FIGSIZE)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
