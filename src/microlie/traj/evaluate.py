"""One-call pipelines: pair (associate), align, measure. Used by the ``microlie`` command."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .align import align as _align
from .metrics import KITTI_LENGTHS, KittiResult, PoseError, ape, kitti_odometry, rpe
from .sync import Association, associate
from .trajectory import Trajectory

__all__ = ["prepare", "evaluate_ape", "evaluate_rpe", "evaluate_kitti"]


def prepare(
    ref: Trajectory, est: Trajectory, *, max_diff: float = 0.01, offset: float = 0.0
) -> tuple[Trajectory, Trajectory, Association | None]:
    """Pair the poses of ``ref`` and ``est``.

    With timestamps on both sides they are associated (:func:`associate`); otherwise the
    trajectories must have the same length and are paired index by index.
    """
    if ref.timestamps is not None and est.timestamps is not None:
        r, e, info = associate(ref, est, max_diff, offset, return_info=True)
        return r, e, info
    if len(ref) != len(est):
        raise ValueError(
            f"{ref.name}: {len(ref)} poses, {est.name}: {len(est)} poses; without timestamps "
            "on both sides the trajectories are paired by index and must have equal length "
            "(give KITTI timestamps files to associate by time)"
        )
    return ref, est, None


def _describe(info: dict, assoc: Association | None, method: str, g, n_align) -> None:
    if assoc is not None:
        info["pairs"] = assoc.num_pairs
        info["max_pairs"] = assoc.max_pairs
        if assoc.duplicates_first or assoc.duplicates_second:
            info["duplicate_timestamps"] = [assoc.duplicates_first, assoc.duplicates_second]
    info["alignment"] = method
    if n_align is not None and method not in ("none", "origin"):
        info["aligned_poses"] = int(n_align)
    if g is not None:
        info["alignment_params"] = np.asarray(g.params).tolist()


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
) -> PoseError:
    """Associate, align (``"none" | "se3" | "sim3" | "scale" | "origin"``) and compute the APE.

    ``res.ref`` / ``res.est`` hold the paired reference and the aligned estimate.
    """
    r, e, assoc = prepare(ref, est, max_diff=max_diff, offset=offset)
    e, g = _align(e, r, align, n_align)
    res = ape(r, e, relation, angle_unit=angle_unit)
    _describe(res.info, assoc, align, g, n_align)
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
) -> PoseError:
    """Associate, optionally align, and compute the RPE (see :func:`microlie.traj.rpe`)."""
    r, e, assoc = prepare(ref, est, max_diff=max_diff, offset=offset)
    e, g = _align(e, r, align, n_align)
    res = rpe(r, e, relation, delta, unit, all_pairs=all_pairs, rel_tol=rel_tol,
              pairs_from=pairs_from, angle_unit=angle_unit)
    _describe(res.info, assoc, align, g, n_align)
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
    benchmark does: segment errors are invariant to a global rigid transform)."""
    r, e, _ = prepare(ref, est, max_diff=max_diff, offset=offset)
    return kitti_odometry(r, e, lengths, step)
