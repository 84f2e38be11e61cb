"""Trajectory plots (matplotlib, an optional dependency: ``pip install microlie[plot]``).

* :func:`plot_trajectories`: the path on a plane (``plot_mode``) or in 3-D, and x/y/z and
  roll/pitch/yaw over time;
* :func:`plot_error`: the estimate's path on the plane, coloured by a per-pose error, next to
  the error over time (or index) with its rmse / mean / median lines;
* :func:`plot_results`: several saved results side by side (``microlie res``): a summary
  (errors over time and statistics bars), or one of evo_res's figures (``kind``: the raw
  errors, the statistics, a histogram per result, box plots, violin plots).

Conventions: ``plot_mode`` names the horizontal then the vertical axis (``"xz"``: x to the
right, z up; KITTI's ground plane), ``"xyz"`` draws a 3-D view. All trajectories of one figure
share one time origin (the earliest first timestamp among them), so poses at the same time are
drawn at the same abscissa. Roll, pitch and yaw (extrinsic x-y-z Euler angles) of the first
trajectory are unwrapped; every other trajectory is drawn on the branch nearest to the first
one at the closest time, so that agreeing orientations overlap instead of sitting 360 degrees
apart.

Figures are plain :class:`matplotlib.figure.Figure` objects on an Agg canvas: nothing here
touches pyplot or the caller's backend. :func:`save` writes them with a fixed size in pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._files import save_figure
from .metrics import PoseError
from .trajectory import Trajectory

__all__ = [
    "plot_trajectories",
    "plot_error",
    "plot_results",
    "save",
    "require_matplotlib",
    "default_plot_mode",
    "PLOT_MODES",
    "RESULT_PLOTS",
    "X_DIMENSIONS",
    "FIGSIZE",
    "DPI",
]

FIGSIZE = (12.0, 8.0)  # inches
DPI = 100  # -> 1200 x 800 pixels
PLOT_MODES = ("xy", "xz", "yx", "yz", "zx", "zy", "xyz")
REF_STYLE = {"ls": "--", "color": "0.35"}
# kinds of plot_results: ours, then evo_res's figures
RESULT_PLOTS = ("summary", "raw", "stats", "histogram", "box", "violin")
# abscissa of the error sequence in plot_error (evo's --plot_x_dimension)
X_DIMENSIONS = ("seconds", "index", "distances")
# statistics drawn as bars by plot_results(kind="stats"), in evo's order
RESULT_STATS = ("rmse", "median", "mean", "std", "min", "max")


def require_matplotlib() -> Any:
    """A new, empty ``Figure`` factory on the Agg canvas, or an ImportError saying what to
    install. Does not import pyplot and does not change the matplotlib backend.

    Returns
    -------
    callable
        Builds a ``matplotlib.figure.Figure`` with an Agg canvas.

    Examples
    --------
    >>> from microlie.traj.plot import require_matplotlib
    >>> fig = require_matplotlib()()
    >>> type(fig.canvas).__name__
    'FigureCanvasAgg'
    """
    try:
        import matplotlib  # noqa: F401 - fails first if matplotlib is absent
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:  # exercised with matplotlib hidden
        raise ImportError("plotting needs matplotlib: pip install 'microlie[plot]'") from exc

    def new_figure() -> Any:
        fig = Figure(figsize=FIGSIZE, dpi=DPI, layout="constrained")
        FigureCanvasAgg(fig)
        return fig

    return new_figure


def default_plot_mode(fmt: str) -> str:
    """The default plane of a format: ``"xz"`` for KITTI (camera frame: y points down),
    ``"xy"`` otherwise.

    Parameters
    ----------
    fmt : str
        ``"tum"``, ``"kitti"``, ``"euroc"`` or ``"bag"``.

    Returns
    -------
    str

    Examples
    --------
    >>> from microlie.traj.plot import default_plot_mode
    >>> default_plot_mode("kitti"), default_plot_mode("tum")
    ('xz', 'xy')
    """
    return "xz" if fmt == "kitti" else "xy"


def _check_mode(plot_mode: str) -> list[int]:
    if plot_mode not in PLOT_MODES:
        raise ValueError(f"unknown plot mode {plot_mode!r}; expected one of {PLOT_MODES}")
    return ["xyz".index(c) for c in plot_mode]


def _time_origin(trajs: Sequence[Trajectory]) -> float | None:
    firsts = [float(np.min(t.timestamps)) for t in trajs if t.timestamps is not None]
    return min(firsts) if firsts else None


def _time_axis(t: Trajectory, t0: float | None) -> tuple[np.ndarray, str]:
    if t.timestamps is not None and t0 is not None:
        return t.timestamps - t0, "t (s)"
    return np.arange(len(t), dtype=float), "index"


def _nearest(ref: Trajectory, other: Trajectory) -> np.ndarray:
    """For each pose of ``other``, the index of the reference pose closest in time (or, without
    timestamps, at the same relative position in the sequence)."""
    if ref.timestamps is not None and other.timestamps is not None:
        order = np.argsort(ref.timestamps, kind="stable")
        ts = ref.timestamps[order]
        k = np.clip(np.searchsorted(ts, other.timestamps), 1, max(len(ts) - 1, 1))
        lo = np.maximum(k - 1, 0)
        hi = np.minimum(k, len(ts) - 1)
        take_lo = np.abs(other.timestamps - ts[lo]) <= np.abs(ts[hi] - other.timestamps)
        return order[np.where(take_lo, lo, hi)]
    if len(ref) == len(other):
        return np.arange(len(other))
    return np.round(np.linspace(0, len(ref) - 1, len(other))).astype(np.intp)


def joint_rpy(trajs: Sequence[Trajectory]) -> list[np.ndarray]:
    """Roll, pitch, yaw in degrees (``(N, 3)`` each) on a common branch (module docstring)."""
    base = np.unwrap(trajs[0].euler("xyz"), axis=0)
    out = [np.rad2deg(base)]
    for t in trajs[1:]:
        j = _nearest(trajs[0], t)
        d = t.euler("xyz") - base[j]
        out.append(np.rad2deg(base[j] + (d + np.pi) % (2 * np.pi) - np.pi))
    return out


def _labels(trajs: Sequence[Trajectory], labels: Sequence[str] | None) -> list[str]:
    if labels is None:
        labels = [t.name or f"traj {i}" for i, t in enumerate(trajs)]
    return [Path(str(lab)).name for lab in labels]


def _plane_axes(fig: Any, spec: Any, plot_mode: str) -> Any:
    if plot_mode == "xyz":
        import mpl_toolkits.mplot3d  # type: ignore[import-untyped]  # noqa: F401 - 3-D axes

        ax = fig.add_subplot(spec, projection="3d")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
    else:
        ax = fig.add_subplot(spec)
        ax.set_xlabel(f"{plot_mode[0]} (m)")
        ax.set_ylabel(f"{plot_mode[1]} (m)")
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_gid("path")
    return ax


def _draw_path(ax: Any, p: np.ndarray, dims: list[int], **style: Any) -> Any:
    return ax.plot(*(p[:, k] for k in dims), lw=1, **style)[0]


def plot_trajectories(
    trajs: Sequence[Trajectory],
    labels: Sequence[str] | None = None,
    title: str | None = None,
    plot_mode: str = "xy",
) -> Any:
    """Overview figure of one or more trajectories (the first is drawn as the reference,
    dashed grey, when there are several), on one common time origin.

    Parameters
    ----------
    trajs : sequence of Trajectory
        The trajectories.
    labels : sequence of str, optional
        Legend labels (default: the names).
    plot_mode : {"xy", "xz", "yz", "zy", "xyz"}
        The plane of the path (``"xyz"``: a 3-D view).
    title : str, optional
        The figure title.

    Returns
    -------
    matplotlib.figure.Figure
        The path in ``plot_mode`` (gid ``"path"``), x/y/z over time (gids ``"x"``, ``"y"``,
        ``"z"``) and roll/pitch/yaw in degrees (gids ``"roll"``, ``"pitch"``, ``"yaw"``); each
        line carries its trajectory's label.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import plot, read_tum, evaluate_ape
    >>> ref, est = (read_tum(p) for p in example_paths())
    >>> fig = plot.plot_trajectories([ref, est], plot_mode="xz")
    >>> [a.get_xlabel() for a in fig.axes if a.get_gid() == "path"]
    ['x (m)']
    """
    new_figure = require_matplotlib()
    dims = _check_mode(plot_mode)
    labels = _labels(trajs, labels)
    fig = new_figure()
    gs = fig.add_gridspec(3, 4)
    ax_path = _plane_axes(fig, gs[:, 0:2], plot_mode)
    ax_pos = [fig.add_subplot(gs[k, 2]) for k in range(3)]
    ax_rpy = [fig.add_subplot(gs[k, 3]) for k in range(3)]
    t0 = _time_origin(trajs)
    rpy = joint_rpy(trajs)
    xl = "index"
    for i, (t, lab) in enumerate(zip(trajs, labels, strict=True)):
        p = t.positions
        style = dict(REF_STYLE) if i == 0 and len(trajs) > 1 else {}
        _draw_path(ax_path, p, dims, label=lab, **style)
        x, xl = _time_axis(t, t0)
        for k in range(3):
            ax_pos[k].plot(x, p[:, k], lw=1, label=lab, **style)
            ax_rpy[k].plot(x, rpy[i][:, k], lw=1, label=lab, **style)
    ax_path.set_title("path" if plot_mode == "xyz" else f"path ({plot_mode} plane)")
    ax_path.legend(fontsize="small")
    for k, n in enumerate("xyz"):
        ax_pos[k].set_ylabel(f"{n} (m)")
        ax_pos[k].set_gid(n)
    for k, n in enumerate(("roll", "pitch", "yaw")):
        ax_rpy[k].set_ylabel(f"{n} (deg)")
        ax_rpy[k].set_gid(n)
    ax_pos[-1].set_xlabel(xl)
    ax_rpy[-1].set_xlabel(xl)
    if title:
        fig.suptitle(title)
    return fig


def _error_abscissa(res: PoseError, idx: np.ndarray, x_dimension: str) -> tuple[np.ndarray, str]:
    """Abscissa of the errors: seconds from the common time origin (index without
    timestamps), the pose index, or the distance travelled along the reference."""
    if x_dimension not in X_DIMENSIONS:
        raise ValueError(f"unknown x_dimension {x_dimension!r}; expected one of {X_DIMENSIONS}")
    assert res.ref is not None and res.est is not None
    if x_dimension == "index":
        return idx.astype(float), "index"
    if x_dimension == "distances":
        dist = np.concatenate([[0.0], np.cumsum(res.ref.step_lengths())])
        return dist[idx], "distance along the reference (m)"
    x, xl = _time_axis(res.est, _time_origin([res.ref, res.est]))
    return x[idx], xl


def plot_error(res: PoseError, title: str | None = None, plot_mode: str = "xy",
               x_dimension: str = "seconds") -> Any:
    """The (aligned) estimate's path on ``plot_mode`` coloured by error (gid ``"path"``; the
    reference dashed), and the error sequence with rmse / mean / median (gid ``"error"``).
    The error of an RPE pair is drawn at the pair's first pose.

    Parameters
    ----------
    res : PoseError
        From :func:`~microlie.traj.evaluate_ape` or :func:`~microlie.traj.evaluate_rpe`.
    plot_mode : {"xy", "xz", "yz", "zy", "xyz"}
        The plane of the path (``"xyz"``: a 3-D view).
    title : str, optional
        The figure title.
    x_dimension : {"seconds", "index", "distances"}
        Abscissa of the error sequence (evo's ``--plot_x_dimension``): seconds from the
        common time origin (the index when there are no timestamps), the pose index, or the
        distance travelled along the (paired) reference up to the pose, in metres.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import plot, read_tum, evaluate_ape
    >>> ref, est = (read_tum(p) for p in example_paths())
    >>> fig = plot.plot_error(evaluate_ape(ref, est, align="se3"), x_dimension="distances")
    >>> sorted(a.get_gid() for a in fig.axes if a.get_gid())
    ['error', 'path']
    """
    new_figure = require_matplotlib()
    if res.ref is None or res.est is None:
        raise ValueError("the result carries no trajectories to plot")
    dims = _check_mode(plot_mode)
    if x_dimension not in X_DIMENSIONS:
        raise ValueError(f"unknown x_dimension {x_dimension!r}; expected one of {X_DIMENSIONS}")
    fig = new_figure()
    gs = fig.add_gridspec(1, 2)
    ax_path = _plane_axes(fig, gs[0, 0], plot_mode)
    ax_err = fig.add_subplot(gs[0, 1])
    ax_err.set_gid("error")
    ref_p, est_p = res.ref.positions, res.est.positions
    idx = np.arange(len(res.est)) if res.pairs is None else res.pairs[:, 0]
    _draw_path(ax_path, ref_p, dims, label="reference", **REF_STYLE)
    _draw_path(ax_path, est_p, dims, color="0.75", zorder=0.5, label="estimate")
    sc = ax_path.scatter(*(est_p[idx, k] for k in dims), c=res.errors, s=6, cmap="jet",
                         zorder=2)
    fig.colorbar(sc, ax=ax_path, label=res.label)
    ax_path.legend(fontsize="small")
    x, xl = _error_abscissa(res, idx, x_dimension)
    ax_err.plot(x, res.errors, lw=1, color="tab:gray", label="error")
    for key, c in (("rmse", "tab:blue"), ("mean", "tab:green"), ("median", "tab:red")):
        ax_err.axhline(res.stats[key], color=c, lw=1, label=f"{key} {res.stats[key]:.4g}")
    ax_err.set_xlabel(xl)
    ax_err.set_ylabel(res.label.split(" w.r.t. ", 1)[-1])
    ax_err.legend(fontsize="small")
    fig.suptitle(title or res.label)
    return fig


def _result_x(results: Sequence[Any], rel_time: bool) -> tuple[list[np.ndarray], str]:
    """Abscissae of the results' errors: seconds from one common origin (each result's own
    first stamp with ``rel_time``), the index when a result has no timestamps."""
    if any(r.timestamps is None for r in results):
        return [np.arange(r.errors.size, dtype=float) for r in results], "index"
    t0 = min(float(np.min(r.timestamps)) for r in results)
    return [r.timestamps - (float(r.timestamps[0]) if rel_time else t0) for r in results], \
        "t (s)"


def plot_results(results: Sequence[Any], labels: Sequence[str], title: str | None = None,
                 kind: str = "summary", rel_time: bool = False) -> Any:
    """Saved results side by side, as one figure of ``kind``:

    * ``"summary"``: the errors over time (gid ``"errors"``) next to rmse / mean / median / std
      as grouped bars (gid ``"stats"``);
    * evo_res's figures: ``"raw"`` the errors over time (gid ``"errors"``, one line per
      result); ``"stats"`` rmse, median, mean, std, min, max as grouped bars (gid ``"stats"``);
      ``"histogram"`` one axes per result (gid ``"histogram"``, titled with its label) with
      the density histogram of its errors (NumPy's ``"auto"`` bins); ``"box"`` one box per
      result (gid ``"box"``; median line, quartile box, whiskers at the furthest error within
      1.5 IQR of the box, the rest drawn as outliers; artists with gids ``"boxes"``,
      ``"medians"``, ``"whiskers"``, ``"caps"``, ``"fliers"``); ``"violin"`` one violin per
      result (gid ``"violin"``; Gaussian kernel density with Scott's bandwidth over the
      errors' range, scaled to a half width of 0.25; gids ``"bodies"``, ``"cmedians"``,
      ``"cmins"``, ``"cmaxes"``, ``"cbars"``).

    The time axis is seconds from the earliest first timestamp of all results, or from each
    result's own first timestamp with ``rel_time`` (evo_res ``--use_rel_time``); the index
    when a result has no timestamps.

    Parameters
    ----------
    results : sequence of Result
        :class:`~microlie.traj.results.Result` objects (from :func:`~microlie.traj.load_result`
        or :func:`~microlie.traj.load_evo_result`).
    labels : sequence of str
        One label per result.
    title : str, optional
        The figure title (default: the first result's label).
    kind : {"summary", "raw", "stats", "histogram", "box", "violin"}
        The figure (see above).
    rel_time : bool
        Each result's time axis starts at its own first error.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import plot, read_tum, evaluate_ape
    >>> ref, est = (read_tum(p) for p in example_paths())
    >>> from microlie.traj.results import result_from_error
    >>> runs = [result_from_error(evaluate_ape(ref, est, align=a)) for a in ("none", "se3")]
    >>> fig = plot.plot_results(runs, ["raw", "aligned"])
    >>> sorted(a.get_gid() for a in fig.axes if a.get_gid())
    ['errors', 'stats']
    >>> [a.get_gid() for a in plot.plot_results(runs, ["raw", "aligned"], kind="box").axes]
    ['box']
    """
    if kind not in RESULT_PLOTS:
        raise ValueError(f"unknown plot kind {kind!r}; expected one of {RESULT_PLOTS}")
    if len(labels) != len(results) or not results:
        raise ValueError(f"plot_results needs one label per result (got {len(labels)} labels "
                         f"for {len(results)} results)")
    new_figure = require_matplotlib()
    fig = new_figure()
    ylabel = results[0].label.split(" w.r.t. ", 1)[-1]
    data = [np.asarray(r.errors, dtype=float) for r in results]
    if kind in ("summary", "raw", "stats"):
        axes = fig.subplots(1, 2) if kind == "summary" else [fig.add_subplot()]
        if kind in ("summary", "raw"):
            ax_e = axes[0]
            ax_e.set_gid("errors")
            xs, xl = _result_x(results, rel_time)
            for x, e, lab in zip(xs, data, labels, strict=True):
                ax_e.plot(x, e, lw=1, label=lab)
            ax_e.set_xlabel(xl)
            ax_e.set_ylabel(ylabel)
            ax_e.legend(fontsize="small")
        if kind in ("summary", "stats"):
            ax_s = axes[-1]
            ax_s.set_gid("stats")
            keys = ("rmse", "mean", "median", "std") if kind == "summary" else RESULT_STATS
            width = 0.8 / len(results)
            for i, (r, lab) in enumerate(zip(results, labels, strict=True)):
                ax_s.bar(np.arange(len(keys)) + (i - (len(results) - 1) / 2) * width,
                         [r.stats[k] for k in keys], width, label=lab)
            ax_s.set_xticks(np.arange(len(keys)), keys)
            ax_s.set_ylabel(ylabel)
            ax_s.legend(fontsize="small")
    elif kind == "histogram":
        axes = fig.subplots(1, len(results), sharex=True, sharey=True, squeeze=False)[0]
        for ax, e, lab in zip(axes, data, labels, strict=True):
            ax.hist(e, bins="auto", density=True, alpha=0.7)
            ax.set_gid("histogram")
            ax.set_title(lab, fontsize="small")
            ax.set_xlabel(ylabel)
        axes[0].set_ylabel("density")
    else:
        ax = fig.add_subplot()
        ax.set_gid(kind)
        pos = np.arange(1, len(results) + 1)
        if kind == "box":
            parts = ax.boxplot(data, positions=pos, whis=1.5)
        else:
            parts = ax.violinplot(data, positions=pos, showmedians=True, showextrema=True)
        for name, artists in parts.items():  # gids: boxes, medians, whiskers, bodies, ...
            for a in artists if isinstance(artists, list) else [artists]:
                a.set_gid(name)
        ax.set_xticks(pos, labels)
        ax.set_ylabel(ylabel)
    fig.suptitle(title or (results[0].label if kind != "summary" else "results"))
    return fig


def save(fig: Any, path: str | Path) -> Path:
    """Save ``fig`` at :data:`DPI`, :data:`FIGSIZE` (format from the file suffix).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or pathlib.Path
        The file.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import plot, read_tum, evaluate_ape
    >>> ref, est = (read_tum(p) for p in example_paths())
    >>> import os, tempfile
    >>> out = plot.save(plot.plot_trajectories([ref]), os.path.join(tempfile.mkdtemp(), "t.png"))
    >>> out.suffix, out.stat().st_size > 0
    ('.png', True)
    """
    path = Path(path)
    fig.set_size_inches(*FIGSIZE)
    save_figure(fig, path, dpi=DPI)
    return path
