"""Absolute and relative pose errors, the KITTI odometry metric, and error statistics.

Conventions (specification: MATH.md section 9). For paired poses ``Q_i`` (reference) and
``P_i`` (estimate):

* APE error pose ``E_i = Q_i^-1 P_i``; RPE error pose for a pair ``(i, j)``
  ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``.
* Pose relations (what is measured on ``E``):

  ======================  ====================================================  ======
  relation                value                                                 unit
  ======================  ====================================================  ======
  ``trans``               translation norm ``|t(E)|`` (APE: ``|p_est - p_ref|``)  m
  ``rot`` / ``angle_deg`` rotation angle of ``R(E)`` in degrees                 deg
  ``angle_rad``           rotation angle of ``R(E)`` in radians                 rad
  ``rot_part``            ``|R(E) - I|_F``                                      -
  ``full``                ``|E - I|_F`` on the 4x4 matrix (evo's "full")        -
  ``se3``                 ``|Log(E)|`` with ``Log`` the SE(3) logarithm         mixed
  ``point_distance``      APE: as ``trans``; RPE: ``| |dp_ref| - |dp_est| |``   m
  ======================  ====================================================  ======

  ``point_distance_error_ratio`` (RPE only, evo's, in %): ``100 | |dp_ref| - |dp_est| | /
  |dp_ref|``; pairs whose reference displacement has length 0 are left out.

  For every relation except ``se3`` the value is the same whether ``E`` is ``Q^-1 P`` or
  ``P^-1 Q``, so these agree with evo's numbers.
* Statistics: rmse, mean, median, std (population, ``ddof=0``), min, max, sse (sum of squares).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from microlie import SE3

from .trajectory import Trajectory

__all__ = [
    "RELATIONS",
    "relation_label",
    "statistics",
    "ape",
    "rpe",
    "pose_pairs",
    "PoseError",
    "kitti_odometry",
    "KittiResult",
    "KITTI_LENGTHS",
]

RELATIONS = ("trans", "rot", "angle_deg", "angle_rad", "rot_part", "full", "se3", "point_distance",
             "point_distance_error_ratio")
_ALIASES = {"trans_part": "trans", "translation": "trans", "rotation": "rot"}
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


def _median(e: np.ndarray) -> float:
    """``np.median`` of a finite 1-D array, bit for bit, without the ``numpy.ma`` import that
    ``np.median`` costs on first use (20 ms of a command's start)."""
    k = e.size // 2
    if e.size % 2:
        return float(np.partition(e, k)[k])
    p = np.partition(e, [k - 1, k])
    return float((p[k - 1] + p[k]) / 2)


def statistics(errors: np.ndarray) -> dict[str, float]:
    """Error statistics: rmse, mean, median, std (population), min, max and sse.

    Parameters
    ----------
    errors : array_like
        A non-empty 1-D array.

    Returns
    -------
    dict of str to float

    Examples
    --------
    >>> from microlie.traj import statistics
    >>> s = statistics([3.0, 4.0])
    >>> round(s["rmse"] ** 2, 12), s["mean"], s["std"], s["sse"]
    (12.5, 3.5, 0.5, 25.0)
    """
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or e.size == 0:
        raise ValueError("statistics need a non-empty 1-D error array")
    sq = e * e
    return {
        "rmse": float(np.sqrt(np.mean(sq))),
        "mean": float(np.mean(e)),
        "median": _median(e),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(sq)),
    }


def _relation(relation: str, angle_unit: str) -> str:
    rel = _ALIASES.get(relation, relation)
    if rel not in RELATIONS:
        raise ValueError(f"unknown pose relation {relation!r}; expected one of {RELATIONS}")
    if angle_unit not in ("deg", "rad"):
        raise ValueError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if rel == "rot":
        rel = "angle_deg" if angle_unit == "deg" else "angle_rad"
    return rel


_UNITS = {
    "trans": "m",
    "point_distance": "m",
    "point_distance_error_ratio": "%",
    "angle_deg": "deg",
    "angle_rad": "rad",
    "rot_part": "",
    "full": "",
    "se3": "",
}


# metres per unit (evo's length units) and the angle relation of each angle unit
_METRES = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "km": 1e3}
_ANGLE_RELATIONS = {"deg": "angle_deg", "rad": "angle_rad"}

#: evo's name of each pose relation (in its plot and table labels)
RELATION_NAMES = {
    "trans": "translation part",
    "point_distance": "point distance",
    "point_distance_error_ratio": "point distance error ratio",
    "angle_deg": "rotation angle",
    "angle_rad": "rotation angle",
    "rot_part": "rotation part",
    "full": "full transformation",
    "se3": "SE(3) logarithm norm",
}


def relation_label(relation: str) -> str:
    """Human-readable name and unit of a pose relation.

    Parameters
    ----------
    relation : str
        One of :data:`RELATIONS` or an evo spelling (``trans_part``, ...).

    Returns
    -------
    str

    Examples
    --------
    >>> from microlie.traj import relation_label
    >>> relation_label("rot"), relation_label("trans_part"), relation_label("full")
    ('rotation angle (deg)', 'translation part (m)', 'full transformation (unit-less)')
    """
    rel = _relation(relation, "deg") if relation != "rot" else "angle_deg"
    unit = _UNITS[rel] or "unit-less"
    return f"{RELATION_NAMES[rel]} ({unit})"


def _pose_error_values(e: SE3, rel: str) -> np.ndarray:
    """The chosen scalar of a batch of error poses ``E``."""
    if rel == "trans":
        t = np.asarray(e.translation())
        return np.sqrt(np.einsum("ij,ij->i", t, t))
    if rel in ("angle_deg", "angle_rad"):
        phi = np.asarray(e.rotation().log())
        ang = np.sqrt(np.einsum("ij,ij->i", phi, phi))
        return np.rad2deg(ang) if rel == "angle_deg" else ang
    if rel == "se3":
        xi = np.asarray(e.log())
        return np.sqrt(np.einsum("ij,ij->i", xi, xi))
    m = np.asarray(e.matrix())
    if rel == "rot_part":
        d = m[:, :3, :3] - np.eye(3)
    else:  # full
        d = m - np.eye(4)
    return np.sqrt(np.einsum("ijk,ijk->i", d, d))


@dataclass
class PoseError:
    """Errors of one metric run (returned by :func:`ape` and :func:`rpe`).

    Attributes
    ----------
    metric : str
        ``"ape"`` or ``"rpe"``.
    relation : str
        The pose relation measured (see the module docstring).
    unit : str
        Unit of ``errors`` (``"m"``, ``"deg"``, ``"rad"`` or ``""``).
    errors : numpy.ndarray
        ``(M,)`` error values.
    stats : dict of str to float
        :func:`statistics` of ``errors``.
    pairs : numpy.ndarray or None
        ``(M, 2)`` index pairs (RPE) or ``None`` (APE, index ``i`` itself).
    ref, est : Trajectory or None
        The paired (and, for APE, aligned) trajectories the errors refer to.
    info : dict
        Free-form description (alignment, delta, ...), JSON serialisable.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> ref, est = associate(*(read_tum(p) for p in example_paths()))
    >>> res = ape(ref, est)
    >>> res.label, res.errors.shape == (len(ref),)
    ('APE w.r.t. translation part (m)', True)
    """

    metric: str
    relation: str
    unit: str
    errors: np.ndarray
    stats: dict[str, float]
    pairs: np.ndarray | None = None
    ref: Trajectory | None = None
    est: Trajectory | None = None
    info: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        return (f"PoseError({self.label}: {self.errors.size} errors, rmse "
                f"{self.stats.get('rmse', float('nan')):.6g} {self.unit})".replace(" )", ")"))

    @property
    def label(self) -> str:
        """``"APE w.r.t. translation part (m)"`` and the like (in :attr:`unit`)."""
        name = RELATION_NAMES.get(self.relation)
        if name is None:
            return f"{self.metric.upper()} w.r.t. {relation_label(self.relation)}"
        return f"{self.metric.upper()} w.r.t. {name} ({self.unit or 'unit-less'})"

    def change_unit(self, unit: str) -> PoseError:
        """The same errors in another unit (evo's ``--change_unit``).

        Lengths convert among ``"mm"``, ``"cm"``, ``"m"`` and ``"km"``, angles between
        ``"deg"`` and ``"rad"`` (the relation becomes ``angle_deg`` / ``angle_rad``); the
        statistics are recomputed. Unit-less relations and percentages have no other unit.

        Parameters
        ----------
        unit : {"mm", "cm", "m", "km", "deg", "rad"}
            The new unit.

        Returns
        -------
        PoseError
            A new result; ``self`` is unchanged.

        Raises
        ------
        ValueError
            ``unit`` is unknown, or the errors cannot be expressed in it.

        Examples
        --------
        >>> from microlie.data import example_paths
        >>> from microlie.traj import associate, ape, read_tum
        >>> res = ape(*associate(*(read_tum(p) for p in example_paths())))
        >>> mm = res.change_unit("mm")
        >>> mm.label, bool(abs(mm.stats["rmse"] - 1000 * res.stats["rmse"]) < 1e-9)
        ('APE w.r.t. translation part (mm)', True)
        """
        if unit not in (*_METRES, *_ANGLE_RELATIONS):
            raise ValueError(f"change_unit: unknown unit {unit!r}; expected one of "
                             f"{(*_METRES, *_ANGLE_RELATIONS)}")
        if unit == self.unit:
            return replace(self)
        relation = self.relation
        if self.unit in _METRES and unit in _METRES:
            errors = self.errors * (_METRES[self.unit] / _METRES[unit])
        elif self.unit in _ANGLE_RELATIONS and unit in _ANGLE_RELATIONS:
            errors = np.deg2rad(self.errors) if unit == "rad" else np.rad2deg(self.errors)
            relation = _ANGLE_RELATIONS[unit]
        else:
            raise ValueError(f"change_unit: errors in {self.unit or 'no unit'!r} "
                             f"({relation_label(self.relation)}) cannot be converted to "
                             f"{unit!r}")
        return replace(self, relation=relation, unit=unit, errors=errors,
                       stats=statistics(errors), info={**self.info, "unit_changed_from":
                                                       self.unit})

    def to_dict(self) -> dict:
        """A JSON-ready summary (no arrays).

        Returns
        -------
        dict
            ``metric``, ``relation``, ``label``, ``unit``, ``num_errors``, ``stats`` (and ``info``).

        Examples
        --------
        >>> from microlie.data import example_paths
        >>> from microlie.traj import *
        >>> ref, est = associate(*(read_tum(p) for p in example_paths()))
        >>> sorted(rpe(ref, est).to_dict())
        ['info', 'label', 'metric', 'num_errors', 'relation', 'stats', 'unit']
        """
        return {
            "metric": self.metric,
            "relation": self.relation,
            "label": self.label,
            "unit": self.unit,
            "num_errors": int(self.errors.size),
            "stats": dict(self.stats),
            **({"info": self.info} if self.info else {}),
        }


def _check_paired(ref: Trajectory, est: Trajectory) -> None:
    if len(ref) != len(est):
        raise ValueError(
            f"reference and estimate must be paired pose by pose ({len(ref)} vs {len(est)} "
            "poses): associate them first"
        )


def ape(
    ref: Trajectory, est: Trajectory, relation: str = "trans", *, angle_unit: str = "deg"
) -> PoseError:
    """Absolute pose error of paired (and, if wanted, already aligned) trajectories.

    Parameters
    ----------
    ref, est : Trajectory
        Paired pose by pose (see :func:`associate`).
    relation : str
        What is measured on ``E_i = Q_i^-1 P_i`` (see the module docstring).
    angle_unit : {"deg", "rad"}
        The unit of ``relation="rot"``.

    Returns
    -------
    PoseError

    Examples
    --------
    The bundled pair; the estimate's rmse after an SE(3) alignment is 0.0617 m:

    >>> from microlie.data import example_paths
    >>> from microlie.traj import align, ape, associate, read_tum
    >>> ref, est = (read_tum(p) for p in example_paths())
    >>> ref, est = associate(ref, est)
    >>> res = ape(ref, align(ref, est, "se3")[0], "trans")
    >>> round(float(res.stats["rmse"]), 4)
    0.0617
    """
    _check_paired(ref, est)
    rel = _relation(relation, angle_unit)
    if rel == "point_distance_error_ratio":
        raise ValueError("relation 'point_distance_error_ratio' is defined for the RPE only "
                         "(a displacement's length error in percent of its length): use rpe "
                         "(microlie rpe -r point_distance_error_ratio)")
    if rel in ("trans", "point_distance"):
        d = est.positions - ref.positions
        err = np.sqrt(np.einsum("ij,ij->i", d, d))
    else:
        err = _pose_error_values(ref.poses.between(est.poses), rel)
    return PoseError("ape", rel, _UNITS[rel], err, statistics(err), None, ref, est)


def pose_pairs(
    traj: Trajectory,
    delta: float,
    unit: str = "frames",
    *,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
) -> np.ndarray:
    """Index pairs ``(i, j)`` of ``traj`` separated by ``delta`` frames, metres or degrees.

    * frames, consecutive: ``(0, d), (d, 2d), ...``; all pairs: ``(i, i + d)`` for every ``i``.
    * metres, consecutive: walk along the path summing the step lengths; each time the sum
      reaches ``delta`` the current index closes a pair and the sum restarts at 0.
    * metres, all pairs: for every ``i`` the ``j > i`` whose travelled distance from ``i`` is
      closest to ``delta`` (first such ``j`` on ties), kept if within ``rel_tol * delta``.
    * degrees / radians, consecutive: as metres with the rotation angles of consecutive
      relative orientations summed; all pairs: *every* ``j > i`` whose direct relative
      rotation angle is within ``rel_tol * delta`` of ``delta`` (evo's rules).

    Parameters
    ----------
    traj : Trajectory
        The trajectory the pairs are chosen on.
    delta : float
        The separation (an integer for frames).
    unit : {"frames", "f", "m", "deg", "d", "rad", "r"}
        The unit of ``delta``.
    all_pairs : bool
        Every admissible pair instead of consecutive, non-overlapping ones.
    rel_tol : float
        Relative tolerance of the all-pairs metre and angle modes.

    Returns
    -------
    numpy.ndarray
        ``(M, 2)`` integer pairs.

    Raises
    ------
    ValueError
        No pair fits.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.traj import Trajectory, pose_pairs
    >>> t = Trajectory.from_arrays(np.c_[np.arange(6.0), np.zeros((6, 2))],
    ...                            np.tile([0, 0, 0, 1.0], (6, 1)))
    >>> pose_pairs(t, 2).tolist(), pose_pairs(t, 2.0, "m").tolist()
    ([[0, 2], [2, 4]], [[0, 2], [2, 4]])
    """
    n = len(traj)
    if not delta > 0:
        raise ValueError(f"delta must be positive, got {delta}")
    unit = _delta_unit(unit)
    if unit == "frames":
        if float(delta) != int(delta):
            raise ValueError(f"a frame delta must be an integer, got {delta}")
        d = int(delta)
        if all_pairs:
            i = np.arange(max(n - d, 0))
            pairs = np.stack([i, i + d], axis=1)
        else:
            ids = np.arange(0, n, d)
            pairs = np.stack([ids[:-1], ids[1:]], axis=1)
    elif unit == "m":
        steps = traj.step_lengths()
        if all_pairs:
            pairs = _all_pairs_by_distance(np.concatenate([[0.0], np.cumsum(steps)]),
                                           float(delta), float(delta) * rel_tol)
        else:
            pairs = _consecutive_by_sum(steps, float(delta))
    else:
        bound = 180.0 if unit == "deg" else np.pi
        if delta > bound:
            raise ValueError(f"an angle delta must be at most {bound:g} {unit}, got {delta}")
        rad = float(np.deg2rad(delta)) if unit == "deg" else float(delta)
        tol = float(np.deg2rad(delta * rel_tol)) if unit == "deg" else float(delta * rel_tol)
        rot = traj.poses.rotation()
        if all_pairs:
            pairs = _all_pairs_by_angle(rot, rad, tol)
        else:
            steps = _angles(rot[:-1].between(rot[1:])) if n > 1 else np.zeros(0)
            pairs = _consecutive_by_sum(steps, rad)
    pairs = pairs.astype(np.intp).reshape(-1, 2)
    if pairs.shape[0] == 0:
        raise ValueError(
            f"delta = {delta} {unit} gives no pose pairs in a trajectory of {n} poses "
            f"({traj.path_length:.3f} m): use a smaller delta"
        )
    return pairs


_DELTA_UNITS = {"frames": "frames", "f": "frames", "m": "m", "meters": "m", "metres": "m",
                "deg": "deg", "d": "deg", "degrees": "deg", "rad": "rad", "r": "rad",
                "radians": "rad"}


def _delta_unit(unit: str) -> str:
    try:
        return _DELTA_UNITS[unit]
    except KeyError:
        raise ValueError(
            f"unknown delta unit {unit!r}; expected 'frames', 'm', 'deg' or 'rad'"
        ) from None


def _angles(rot) -> np.ndarray:
    """Rotation angles (rad) of a batch of SO(3) elements."""
    phi = np.asarray(rot.log())
    return np.sqrt(np.einsum("ij,ij->i", phi, phi))


def _consecutive_by_sum(steps: np.ndarray, delta: float) -> np.ndarray:
    """Walk the steps summing them; each time the sum reaches ``delta`` the current index closes
    a pair, opens the next one, and the sum restarts at 0 (pose 0 opens the first pair)."""
    ids = [0]
    acc = 0.0
    for k, s in enumerate(steps.tolist(), start=1):
        acc += s
        if acc >= delta:
            ids.append(k)
            acc = 0.0
    a = np.asarray(ids)
    return np.stack([a[:-1], a[1:]], axis=1)


def _all_pairs_by_angle(rot, delta: float, tol: float) -> np.ndarray:
    """Every ``(i, j > i)`` whose relative rotation angle is within ``tol`` of ``delta``."""
    n = rot.batch_shape[0]
    out = []
    block = max(1, 1_000_000 // max(n, 1))
    for s in range(0, n - 1, block):
        i = np.arange(s, min(s + block, n - 1))
        ii, jj = np.nonzero(np.arange(n)[None, :] > i[:, None])
        ii = i[ii]
        ang = _angles(rot[ii].between(rot[jj]))
        ok = (ang >= delta - tol) & (ang <= delta + tol)
        out.append(np.stack([ii[ok], jj[ok]], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 2), dtype=np.intp)


def _all_pairs_by_distance(dist: np.ndarray, delta: float, tol: float) -> np.ndarray:
    """For each i, the j > i minimising ``|(dist[j] - dist[i]) - delta|`` (first on ties)."""
    n = dist.size
    if n < 2:
        return np.zeros((0, 2), dtype=np.intp)
    i = np.arange(n - 1)
    # Candidate neighbourhood from a binary search; the exact criterion is then evaluated on
    # a few indices around it so that rounding cannot move the choice.
    k = np.searchsorted(dist, dist[i] + delta, side="left")
    cand = k[:, None] + np.arange(-2, 2)[None, :]
    cand = np.clip(cand, (i + 1)[:, None], n - 1)
    cost = np.abs((dist[cand] - dist[i][:, None]) - delta)
    best = np.argmin(cost, axis=1)
    j = cand[i, best]
    c = cost[i, best]
    # First index on ties: walk back over equal distances (plateaus, i.e. standing still).
    first_equal = np.searchsorted(dist, dist[j], side="left")
    j = np.maximum(first_equal, i + 1)
    keep = c <= tol
    return np.stack([i[keep], j[keep]], axis=1)


def rpe(
    ref: Trajectory,
    est: Trajectory,
    relation: str = "trans",
    delta: float = 1,
    unit: str = "frames",
    *,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    pairs_from: str = "est",
    angle_unit: str = "deg",
    pairs: np.ndarray | None = None,
) -> PoseError:
    """Relative pose error over pose pairs ``delta`` frames, metres or degrees apart.

    The error pose of a pair ``(i, j)`` is ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``.

    Parameters
    ----------
    ref, est : Trajectory
        Paired pose by pose (see :func:`associate`).
    relation : str
        See the module docstring (``point_distance`` compares the lengths of the
        displacements only).
    delta : float
        Pair separation.
    unit : {"frames", "m", "deg", "rad"}
        Unit of ``delta`` (see :func:`pose_pairs`).
    all_pairs : bool
        Every admissible pair instead of consecutive, non-overlapping ones.
    rel_tol : float
        Relative tolerance of the all-pairs modes.
    pairs_from : {"est", "ref"}
        Choose pairs on the estimate (evo's default) or the reference.
    angle_unit : {"deg", "rad"}
        The unit of ``relation="rot"``.
    pairs : numpy.ndarray, optional
        Explicit ``(M, 2)`` index pairs; then ``delta``, ``unit`` and ``all_pairs`` are unused.

    Returns
    -------
    PoseError

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> ref, est = associate(*(read_tum(p) for p in example_paths()))
    >>> res = rpe(ref, est, "rot", delta=1, unit="m")
    >>> res.unit, res.pairs.shape[1]
    ('deg', 2)
    """
    _check_paired(ref, est)
    rel = _relation(relation, angle_unit)
    if pairs_from not in ("est", "ref"):
        raise ValueError(f"pairs_from must be 'est' or 'ref', got {pairs_from!r}")
    if pairs is None:
        pairs = pose_pairs(est if pairs_from == "est" else ref, delta, unit,
                           all_pairs=all_pairs, rel_tol=rel_tol)
    else:
        pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
        if pairs.size == 0 or pairs.min() < 0 or pairs.max() >= len(ref):
            raise ValueError("explicit pairs must be non-empty indices into the trajectories")
    i, j = pairs[:, 0], pairs[:, 1]
    info: dict = {}
    if rel in ("point_distance", "point_distance_error_ratio"):
        dr = ref.positions[j] - ref.positions[i]
        de = est.positions[j] - est.positions[i]
        len_r = np.sqrt(np.einsum("ij,ij->i", dr, dr))
        err = np.abs(len_r - np.sqrt(np.einsum("ij,ij->i", de, de)))
        if rel == "point_distance_error_ratio":
            keep = len_r != 0
            if not keep.any():
                raise ValueError("point_distance_error_ratio: every reference displacement "
                                 "has length 0 (no ratio): use another delta or relation")
            if not keep.all():
                info["zero_distance_pairs_dropped"] = int(np.count_nonzero(~keep))
            pairs = pairs[keep]
            err = 100.0 * err[keep] / len_r[keep]
    else:
        q_rel = ref.poses[i].between(ref.poses[j])
        p_rel = est.poses[i].between(est.poses[j])
        err = _pose_error_values(q_rel.between(p_rel), rel)
    info = {"delta": delta, "delta_unit": _delta_unit(unit),
            "all_pairs": all_pairs, "pairs_from": pairs_from, **info}
    return PoseError("rpe", rel, _UNITS[rel], err, statistics(err), pairs, ref, est, info)


@dataclass
class KittiResult:
    """KITTI odometry metric (Geiger et al., CVPR 2012; the devkit's ``evaluate_odometry``).

    Attributes
    ----------
    t_err : float
        Average translational error in percent (``100 * |t(E)| / length``).
    r_err : float
        Average rotational error in degrees per metre (``angle(E) / length``).
    per_length : dict
        ``{length: (t_err %, r_err deg/m, number of segments)}``.
    segments : numpy.ndarray
        ``(K, 4)`` rows ``(first index, length, t_err ratio, r_err rad/m)``.

    Examples
    --------
    A straight 300 m path estimated 1 % too long:

    >>> import numpy as np
    >>> from microlie.traj import Trajectory, kitti_odometry
    >>> x = np.c_[np.arange(0.0, 300.5, 0.5), np.zeros((601, 2))]
    >>> q = np.tile([0, 0, 0, 1.0], (601, 1))
    >>> res = kitti_odometry(Trajectory.from_arrays(x, q), Trajectory.from_arrays(1.01 * x, q))
    >>> sorted(res.per_length), round(res.t_err, 2), res.r_err
    ([100.0, 200.0], 1.0, 0.0)
    """

    t_err: float
    r_err: float
    per_length: dict[float, tuple[float, float, int]]
    segments: np.ndarray

    def __repr__(self) -> str:
        return (f"KittiResult(t_err {self.t_err:.6g} %, r_err {self.r_err:.6g} deg/m, "
                f"{self.segments.shape[0]} segments)")

    def to_dict(self) -> dict:
        """A JSON-ready summary (no arrays).

        Returns
        -------
        dict
            ``t_err_percent``, ``r_err_deg_per_m``, ``r_err_deg_per_100m``, ``num_segments`` and
            ``per_length``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory, kitti_odometry
        >>> x = np.c_[np.arange(0.0, 150.0), np.zeros((150, 2))]
        >>> t = Trajectory.from_arrays(x, np.tile([0, 0, 0, 1.0], (150, 1)))
        >>> kitti_odometry(t, t).to_dict()["t_err_percent"]
        0.0
        """
        return {
            "metric": "kitti",
            "t_err_percent": self.t_err,
            "r_err_deg_per_m": self.r_err,
            "r_err_deg_per_100m": 100.0 * self.r_err,
            "num_segments": int(self.segments.shape[0]),
            "per_length": {
                f"{k:g}": {"t_err_percent": v[0], "r_err_deg_per_m": v[1], "segments": v[2]}
                for k, v in self.per_length.items()
            },
        }


def kitti_odometry(
    ref: Trajectory,
    est: Trajectory,
    lengths: Sequence[float] = KITTI_LENGTHS,
    step: int = 10,
) -> KittiResult:
    """The KITTI odometry segment metric on paired trajectories.

    For every start index ``f = 0, step, 2 step, ...`` and every length ``L``, the end index is
    the first ``l`` with ``d(l) > d(f) + L`` (``d``: distance travelled along the reference).
    The segment error is ``E = (P_f^-1 P_l)^-1 (Q_f^-1 Q_l)``; it contributes
    ``|t(E)| / L`` and ``angle(E) / L``. Results are the plain means over all segments, in %
    and deg/m. Segments running past the end are skipped.

    Parameters
    ----------
    ref, est : Trajectory
        Paired pose by pose.
    lengths : sequence of float
        Segment lengths, metres (default 100, 200, ..., 800).
    step : int
        Index step between segment starts (the devkit's 10).

    Returns
    -------
    KittiResult

    Raises
    ------
    ValueError
        No segment fits in the reference path.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.traj import Trajectory, kitti_odometry
    >>> x = np.c_[np.arange(0.0, 300.5, 0.5), np.zeros((601, 2))]
    >>> q = np.tile([0, 0, 0, 1.0], (601, 1))
    >>> res = kitti_odometry(Trajectory.from_arrays(x, q), Trajectory.from_arrays(1.01 * x, q))
    >>> round(res.t_err, 2)
    1.0
    """
    _check_paired(ref, est)
    dist = ref.distances()
    n = len(ref)
    firsts = np.arange(0, n, step)
    rows_f, rows_l, rows_len = [], [], []
    for length in lengths:
        last = np.searchsorted(dist, dist[firsts] + length, side="right")
        ok = last < n
        rows_f.append(firsts[ok])
        rows_l.append(last[ok])
        rows_len.append(np.full(int(ok.sum()), float(length)))
    f = np.concatenate(rows_f)
    ln = np.concatenate(rows_l)
    seg_len = np.concatenate(rows_len)
    if f.size == 0:
        raise ValueError(
            f"no KITTI segment fits: the reference path is {dist[-1]:.1f} m, the shortest "
            f"segment {min(lengths):g} m"
        )
    # sort by (first, length) like the devkit's loop order
    order = np.lexsort((seg_len, f))
    f, ln, seg_len = f[order], ln[order], seg_len[order]
    d_gt = ref.poses[f].between(ref.poses[ln])
    d_est = est.poses[f].between(est.poses[ln])
    e = d_est.between(d_gt)
    t = np.asarray(e.translation())
    t_err = np.sqrt(np.einsum("ij,ij->i", t, t)) / seg_len
    phi = np.asarray(e.rotation().log())
    r_err = np.sqrt(np.einsum("ij,ij->i", phi, phi)) / seg_len
    per_length = {}
    for length in lengths:
        m = seg_len == float(length)
        if m.any():
            per_length[float(length)] = (
                float(100.0 * t_err[m].mean()),
                float(np.rad2deg(r_err[m].mean())),
                int(m.sum()),
            )
    segments = np.column_stack([f, seg_len, t_err, r_err])
    return KittiResult(
        float(100.0 * t_err.mean()), float(np.rad2deg(r_err.mean())), per_length, segments
    )
