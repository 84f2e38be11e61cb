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

# Submodules load on first use (PEP 562), so that the command line (which reads
# microlie.traj.formats to build its choices) does not pay for the readers' imports.
import importlib
from typing import TYPE_CHECKING, Any

# ``align`` is both a submodule and its function: imported now, so that importing the submodule
# (which binds the package attribute ``align`` to it) can never hide the function
from .align import ALIGNMENTS, align, umeyama  # noqa: E402

_LAZY = {
    "evaluate": ("describe_alignment", "evaluate_ape", "evaluate_kitti", "evaluate_rpe", "prepare"),
    "evo_results": ("load_evo_result",),
    "io": ("read_euroc", "read_kitti", "read_timestamps", "read_trajectory", "read_tum",
           "write_euroc", "write_kitti", "write_trajectory", "write_tum"),
    "metrics": ("KITTI_LENGTHS", "RELATIONS", "KittiResult", "PoseError", "ape", "kitti_odometry",
                "pose_pairs", "relation_label", "rpe", "statistics"),
    "results": ("Result", "load_result", "save_result"),
    "sync": ("INTERPOLATIONS", "Association", "associate", "interpolate", "match_timestamps"),
    "trajectory": ("PLANES", "TimestampWarning", "Trajectory", "merge"),
    "formats": ("FORMATS",),
}
_WHERE = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    loaded = importlib.import_module(f".{module}", __name__)
    for other in _LAZY[module]:  # the module's names at once
        globals()[other] = getattr(loaded, other)
    return globals()[name]


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


if TYPE_CHECKING:
    from .evaluate import describe_alignment, evaluate_ape, evaluate_kitti, evaluate_rpe, prepare
    from .evo_results import load_evo_result
    from .formats import FORMATS
    from .io import (
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
