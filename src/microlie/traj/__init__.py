"""Trajectory evaluation: files, timestamp association, alignment, APE / RPE / KITTI metrics.

All pose mathematics runs on :class:`microlie.SE3`, :class:`microlie.Sim3` and
:class:`microlie.SO3`. Conventions: poses are ``T_world_body``; quaternions in files follow each
format (TUM ``qx qy qz qw``, EuRoC ``qw qx qy qz``); errors are ``E = T_ref^-1 T_est`` (APE) and
``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (RPE). See ``docs/trajectory.md``.

Example:
    >>> from microlie import traj
    >>> from microlie.data import example_paths
    >>> gt_path, est_path = example_paths()
    >>> res = traj.evaluate_ape(traj.read_tum(gt_path), traj.read_tum(est_path), align="se3")
    >>> round(res.stats["rmse"], 3) > 0
    True
"""

from .align import ALIGNMENTS, align, umeyama
from .evaluate import describe_alignment, evaluate_ape, evaluate_kitti, evaluate_rpe, prepare
from .evo_results import load_evo_result
from .io import (
    FORMATS,
    read_euroc,
    read_kitti,
    read_timestamps,
    read_trajectory,
    read_tum,
    write_euroc,
    write_kitti,
    write_trajectory,
    write_tum,
)
from .metrics import (
    KITTI_LENGTHS,
    RELATIONS,
    KittiResult,
    PoseError,
    ape,
    kitti_odometry,
    pose_pairs,
    relation_label,
    rpe,
    statistics,
)
from .results import Result, load_result, save_result
from .sync import INTERPOLATIONS, Association, associate, interpolate, match_timestamps
from .trajectory import PLANES, TimestampWarning, Trajectory, merge

__all__ = [
    "Trajectory",
    "TimestampWarning",
    "merge",
    "PLANES",
    "interpolate",
    "INTERPOLATIONS",
    "relation_label",
    "describe_alignment",
    "read_tum",
    "write_tum",
    "read_kitti",
    "write_kitti",
    "write_euroc",
    "write_trajectory",
    "save_result",
    "load_result",
    "load_evo_result",
    "Result",
    "read_euroc",
    "read_timestamps",
    "read_trajectory",
    "FORMATS",
    "associate",
    "match_timestamps",
    "Association",
    "align",
    "umeyama",
    "ALIGNMENTS",
    "ape",
    "rpe",
    "pose_pairs",
    "statistics",
    "kitti_odometry",
    "KittiResult",
    "PoseError",
    "RELATIONS",
    "KITTI_LENGTHS",
    "prepare",
    "evaluate_ape",
    "evaluate_rpe",
    "evaluate_kitti",
]
