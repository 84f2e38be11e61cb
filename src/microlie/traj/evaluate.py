"""One-call pipelines: preprocess, pair (associate), align, measure. Used by the ``microlie``
command.

The steps, in evo's order (so that the same options give the same numbers):

1. ``downsample``: both trajectories to at most N poses (:meth:`Trajectory.downsample`);
2. ``t_start`` / ``t_end``: the *reference* is cut to the window (absolute seconds); the
   association then keeps the estimate poses that fall inside it;
3. pairing: by timestamps (``max_diff``, ``offset``, optionally ``interpolate``) or, without
   timestamps on both sides, by index;
4. alignment of the estimate (``align``, on the first ``n_align`` pairs);
5. ``project``: both onto a plane (:meth:`Trajectory.project`), after the 3-D alignment;
6. the metric.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from microlie import SE3, SO3, Sim3

from .align import align as _align
from .metrics import KITTI_LENGTHS, KittiResult, PoseError, ape, kitti_odometry, rpe
from .sync import Association, associate
from .trajectory import Trajectory

__all__ = ["prepare", "evaluate_ape", "evaluate_rpe", "evaluate_kitti", "describe_alignment"]


def prepare(
    ref: Trajectory,
    est: Trajectory,
    *,
    max_diff: float = 0.01,
    offset: float = 0.0,
    t_start: float | None = None,
    t_end: float | None = None,
    downsample: int | None = None,
    interpolate: str | None = None,
) -> tuple[Trajectory, Trajectory, Association | None]:
    """Preprocess (steps 1-2 of the module docstring) and pair the poses of ``ref`` and ``est``.

    With timestamps on both sides they are associated (:func:`associate`); otherwise the
    trajectories must have the same length and are paired index by index.

    Parameters
    ----------
    ref, est : Trajectory
        Reference and estimate.
    max_diff : float
        Largest time difference of an associated pair, seconds.
    offset : float
        Added to the estimate's timestamps for the association.
    t_start, t_end : float, optional
        Time window (absolute seconds) applied to the reference before association.
    downsample : int, optional
        Keep at most this many poses of each trajectory (see :meth:`Trajectory.downsample`).
    interpolate : {None, "se3", "split"}
        Interpolate instead of pairing nearest stamps (see :func:`associate`).

    Returns
    -------
    ref, est : Trajectory
        The paired poses.
    association : Association or None
        ``None`` when paired by index.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie import traj
    >>> ref, est = (traj.read_tum(p) for p in example_paths())
    >>> r, e, assoc = traj.prepare(ref, est, t_end=ref.timestamps[0] + 2.0)
    >>> len(r) == len(e) == assoc.num_pairs
    True
    """
    if downsample is not None:
        ref, est = ref.downsample(downsample), est.downsample(downsample)
    if t_start is not None or t_end is not None:
        ref = ref.crop(t_start, t_end)
    if ref.timestamps is not None and est.timestamps is not None:
        found = associate(ref, est, max_diff, offset, interpolate=interpolate, return_info=True)
        return cast(tuple[Trajectory, Trajectory, Association], found)
    if interpolate is not None:
        raise ValueError("interpolation needs timestamps on both trajectories")
    if len(ref) != len(est):
        raise ValueError(
            f"{ref.name}: {len(ref)} poses, {est.name}: {len(est)} poses; without timestamps "
            "on both sides the trajectories are paired by index and must have equal length "
            "(give KITTI timestamps files to associate by time)"
        )
    return ref, est, None


def describe_alignment(g: SE3 | Sim3 | None) -> dict[str, Any]:
    """The alignment transform as JSON-ready, labelled fields (``scale`` is 1 for SE(3)).

    Parameters
    ----------
    g : SE3, Sim3 or None
        The transform returned by :func:`align`.

    Returns
    -------
    dict
        ``rotation_quat_xyzw``, ``translation``, ``scale`` and ``matrix``; empty for ``None``.

    Examples
    --------
    >>> from microlie import Sim3
    >>> from microlie.traj import describe_alignment
    >>> d = describe_alignment(Sim3.identity())
    >>> sorted(d), d["scale"]
    (['matrix', 'rotation_quat_xyzw', 'scale', 'translation'], 1.0)
    """
    if g is None:
        return {}
    scale = float(np.asarray(g.scale())) if isinstance(g, Sim3) else 1.0
    return {
        "rotation_quat_xyzw": np.asarray(cast(SO3, g.rotation()).as_quat()).tolist(),
        "translation": np.asarray(g.translation()).tolist(),
        "scale": scale,
        "matrix": np.asarray(g.matrix()).tolist(),
    }


def _describe(info: dict, assoc: Association | None, method: str, g, n_align,
              options: dict) -> None:
    if assoc is not None:
        info["pairs"] = assoc.num_pairs
        info["max_pairs"] = assoc.max_pairs
        if assoc.duplicates_first or assoc.duplicates_second:
            info["duplicate_timestamps"] = [assoc.duplicates_first, assoc.duplicates_second]
    info["alignment"] = method
    if n_align is not None and method not in ("none", "origin"):
        info["aligned_poses"] = int(n_align)
    if g is not None:
        info["alignment_transform"] = describe_alignment(g)
        info["alignment_scale"] = info["alignment_transform"]["scale"]
    info.update({k: v for k, v in options.items() if v is not None})


def _pipeline(ref, est, align, n_align, project, pre):
    r, e, assoc = prepare(ref, est, **pre)
    e, g = _align(r, e, align, n_align)
    if project is not None:
        r, e = r.project(project), e.project(project)
    return r, e, assoc, g


def evaluate_ape(
    ref: Trajectory,
    est: Trajectory,
    *,
    relation: str = "trans",
    align: str = "none",
    n_align: int | None = None,
    max_diff: float = 0.01,
    offset: float = 0.0,
    angle_unit: str = "deg",
    t_start: float | None = None,
    t_end: float | None = None,
    downsample: int | None = None,
    interpolate: str | None = None,
    project: str | None = None,
) -> PoseError:
    """Preprocess, associate, align, optionally project, and compute the APE (module docstring
    for the order of the steps).

    Parameters
    ----------
    ref, est : Trajectory
        Reference and estimate (any lengths; paired by :func:`prepare`).
    relation : str
        See :func:`ape`.
    align : {"none", "se3", "sim3", "scale", "origin"}
        Alignment of the estimate to the reference (see :func:`align`).
    n_align : int, optional
        Use only the first ``n_align`` pairs to estimate the alignment.
    max_diff : float
        Largest time difference of an associated pair, seconds.
    offset : float
        Added to the estimate's timestamps for the association.
    angle_unit : {"deg", "rad"}
        The unit of ``relation="rot"``.
    project : {None, "xy", "xz", "yz"}
        Project both onto a plane after the alignment (2-D evaluation).
    t_start, t_end : float, optional
        Time window (absolute seconds) applied to the reference before association.
    downsample : int, optional
        Keep at most this many poses of each trajectory (see :meth:`Trajectory.downsample`).
    interpolate : {None, "se3", "split"}
        Interpolate instead of pairing nearest stamps (see :func:`associate`).

    Returns
    -------
    PoseError
        ``res.ref`` / ``res.est`` hold the paired reference and the aligned estimate;
        ``res.info`` the association counts, the alignment (``alignment_transform``,
        ``alignment_scale``) and the preprocessing options used.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie import traj
    >>> ref, est = (traj.read_tum(p) for p in example_paths())
    >>> res = traj.evaluate_ape(ref, est, align="se3")
    >>> round(res.stats["rmse"], 4), res.info["alignment_scale"]
    (0.0617, 1.0)
    """
    pre = dict(max_diff=max_diff, offset=offset, t_start=t_start, t_end=t_end,
               downsample=downsample, interpolate=interpolate)
    r, e, assoc, g = _pipeline(ref, est, align, n_align, project, pre)
    res = ape(r, e, relation, angle_unit=angle_unit)
    _describe(res.info, assoc, align, g, n_align,
              dict(t_start=t_start, t_end=t_end, downsample=downsample,
                   interpolate=interpolate, project=project))
    return res


def evaluate_rpe(
    ref: Trajectory,
    est: Trajectory,
    *,
    relation: str = "trans",
    delta: float = 1,
    unit: str = "frames",
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    pairs_from: str = "est",
    align: str = "none",
    n_align: int | None = None,
    max_diff: float = 0.01,
    offset: float = 0.0,
    angle_unit: str = "deg",
    t_start: float | None = None,
    t_end: float | None = None,
    downsample: int | None = None,
    interpolate: str | None = None,
    project: str | None = None,
) -> PoseError:
    """Preprocess, associate, optionally align and project, and compute the RPE.

    Parameters
    ----------
    ref, est : Trajectory
        Reference and estimate (any lengths; paired by :func:`prepare`).
    relation, delta, unit, all_pairs, rel_tol, pairs_from
        See :func:`rpe` (``unit`` is ``"frames"``, ``"m"``, ``"deg"`` or ``"rad"``).
    align : {"none", "se3", "sim3", "scale", "origin"}
        Alignment of the estimate to the reference (see :func:`align`).
    n_align : int, optional
        Use only the first ``n_align`` pairs to estimate the alignment.
    max_diff : float
        Largest time difference of an associated pair, seconds.
    offset : float
        Added to the estimate's timestamps for the association.
    angle_unit : {"deg", "rad"}
        The unit of ``relation="rot"``.
    project : {None, "xy", "xz", "yz"}
        Project both onto a plane after the alignment (2-D evaluation).
    t_start, t_end : float, optional
        Time window (absolute seconds) applied to the reference before association.
    downsample : int, optional
        Keep at most this many poses of each trajectory (see :meth:`Trajectory.downsample`).
    interpolate : {None, "se3", "split"}
        Interpolate instead of pairing nearest stamps (see :func:`associate`).

    Returns
    -------
    PoseError

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie import traj
    >>> ref, est = (traj.read_tum(p) for p in example_paths())
    >>> res = traj.evaluate_rpe(ref, est, relation="rot", delta=1, unit="m")
    >>> res.metric, res.unit, res.info["delta_unit"]
    ('rpe', 'deg', 'm')
    """
    pre = dict(max_diff=max_diff, offset=offset, t_start=t_start, t_end=t_end,
               downsample=downsample, interpolate=interpolate)
    r, e, assoc, g = _pipeline(ref, est, align, n_align, project, pre)
    res = rpe(r, e, relation, delta, unit, all_pairs=all_pairs, rel_tol=rel_tol,
              pairs_from=pairs_from, angle_unit=angle_unit)
    _describe(res.info, assoc, align, g, n_align,
              dict(t_start=t_start, t_end=t_end, downsample=downsample,
                   interpolate=interpolate, project=project))
    return res


def evaluate_kitti(
    ref: Trajectory,
    est: Trajectory,
    *,
    lengths: Sequence[float] = KITTI_LENGTHS,
    step: int = 10,
    max_diff: float = 0.01,
    offset: float = 0.0,
) -> KittiResult:
    """Pair the trajectories and compute the KITTI odometry metric (no alignment, as the
    benchmark does: segment errors are invariant to a global rigid transform).

    Parameters
    ----------
    ref, est : Trajectory
        Reference and estimate.
    lengths : sequence of float
        Segment lengths, metres.
    step : int
        Index step between segment starts.
    max_diff, offset : float
        Association (see :func:`associate`), when both have timestamps.

    Returns
    -------
    KittiResult

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.traj import Trajectory, evaluate_kitti
    >>> x = np.c_[np.arange(0.0, 150.0), np.zeros((150, 2))]
    >>> t = Trajectory.from_arrays(x, np.tile([0, 0, 0, 1.0], (150, 1)))
    >>> evaluate_kitti(t, t).per_length
    {100.0: (0.0, 0.0, 5)}
    """
    r, e, _ = prepare(ref, est, max_diff=max_diff, offset=offset)
    return kitti_odometry(r, e, lengths, step)
