"""Timestamp association of two trajectories.

The rule (the one evo uses, so that pair sets and therefore statistics agree):

* The trajectory with fewer poses is the *query* side (the first one on a tie of lengths is the
  *target* side); the time offset is added to the stamps of the second trajectory (in practice
  it is added to the target stamps with the sign that achieves this).
* Each query stamp is matched to the nearest target stamp if ``|difference| <= max_diff``;
  on a tie the earlier target stamp wins. Query stamps are never dropped for being matched
  twice: two query poses may share one target pose.
* Duplicate timestamps are not an error. With sorted target stamps a query stamp equal to a
  repeated target stamp is matched to the *last* pose carrying that stamp; with unsorted target
  stamps the *first* pose at the smallest difference wins. :func:`associate` emits a
  :class:`~microlie.traj.TimestampWarning` when it meets them (:meth:`Trajectory.check`).
* Interpolation (``interpolate="se3"`` or ``"split"``): the same pairs are found, then the pose
  of the trajectory with *more* poses (usually the reference) is replaced by its interpolation
  at the matched stamp of the other one (:func:`interpolate`), so both poses of a pair refer to
  exactly the same time. This is evo's ``--sync_method interpolation`` rule; ``"split"`` is
  evo's interpolation (linear positions, slerp orientations), ``"se3"`` the SE(3) geodesic.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from microlie import SE3

from .trajectory import Trajectory

__all__ = ["match_timestamps", "associate", "Association", "interpolate", "INTERPOLATIONS"]

INTERPOLATIONS = ("se3", "split")


def interpolate(traj: Trajectory, stamps: np.ndarray, method: str = "se3") -> Trajectory:
    """The poses of ``traj`` at the times ``stamps`` (seconds), interpolated between neighbours.

    For ``t_k <= s <= t_{k+1}`` and ``f = (s - t_k) / (t_{k+1} - t_k)``:

    * ``"se3"``: the SE(3) geodesic ``T_k Exp(f Log(T_k^-1 T_{k+1}))`` (screw motion);
    * ``"split"``: positions ``p_k + f (p_{k+1} - p_k)`` and orientations
      ``R_k Exp(f Log(R_k^T R_{k+1}))`` (slerp), as evo interpolates.

    Stamps outside ``[t_0, t_N-1]`` are clamped to the end poses (``f`` in ``[0, 1]``); a zero
    interval (repeated stamps) gives ``f = 0``.

    Parameters
    ----------
    traj : Trajectory
        At least two poses with non-decreasing timestamps.
    stamps : array_like
        The query times, seconds.
    method : {"se3", "split"}
        The interpolation.

    Returns
    -------
    Trajectory
        One pose per stamp, with ``stamps`` as its timestamps.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.traj import Trajectory, interpolate
    >>> t = Trajectory.from_arrays([[0, 0, 0], [2, 0, 0]], [[0, 0, 0, 1], [0, 0, 0, 1]], [0, 1])
    >>> interpolate(t, np.array([0.25])).positions
    array([[0.5, 0. , 0. ]])
    """
    if method not in INTERPOLATIONS:
        raise ValueError(f"unknown interpolation {method!r}; expected one of {INTERPOLATIONS}")
    if traj.timestamps is None or len(traj) < 2:
        raise ValueError("interpolation needs a trajectory with timestamps and at least 2 poses")
    t = traj.timestamps
    if np.any(np.diff(t) < 0):
        raise ValueError(f"{traj.name or 'trajectory'}: timestamps decrease, cannot interpolate")
    s = np.atleast_1d(np.asarray(stamps, dtype=np.float64))
    k = np.clip(np.searchsorted(t, s, side="left"), 1, len(t) - 1)
    dt = t[k] - t[k - 1]
    f = np.where(dt > 0, (s - t[k - 1]) / np.where(dt > 0, dt, 1.0), 0.0)
    f = np.clip(f, 0.0, 1.0)
    a, b = cast(SE3, traj.poses[k - 1]), cast(SE3, traj.poses[k])
    if method == "se3":
        poses = a.interpolate(b, f)
    else:
        pa, pb = traj.positions[k - 1], traj.positions[k]
        rot = a.rotation().interpolate(b.rotation(), f)
        poses = SE3.from_rotation_translation(rot, pa + f[:, None] * (pb - pa))
    return Trajectory(cast(SE3, poses), s, traj.name)


def match_timestamps(
    query: np.ndarray, target: np.ndarray, max_diff: float = 0.01, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(iq, it)`` pairing each query stamp with its nearest ``target + offset`` stamp.

    Pairs farther apart than ``max_diff`` are left out; ``iq`` is increasing.

    Parameters
    ----------
    query, target : array_like
        Timestamps, seconds.
    max_diff : float
        Largest accepted difference, seconds.
    offset : float
        Added to ``target`` before matching.

    Returns
    -------
    iq, it : numpy.ndarray
        Integer indices into ``query`` and ``target``.

    Examples
    --------
    >>> from microlie.traj import match_timestamps
    >>> iq, it = match_timestamps([0.0, 1.0, 2.0], [0.004, 1.5, 1.998], max_diff=0.01)
    >>> iq.tolist(), it.tolist()
    ([0, 2], [0, 2])
    """
    q = np.asarray(query, dtype=np.float64)
    t = np.asarray(target, dtype=np.float64) + offset
    if t.size == 0 or q.size == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    if np.all(np.diff(t) >= 0):
        n = t.size
        inside = (q >= t[0] - max_diff) & (q <= t[-1] + max_diff)
        iq = np.flatnonzero(inside)
        qs = q[iq]
        up = np.minimum(np.searchsorted(t, qs, side="right"), n - 1)
        d_up = t[up] - qs
        d_lo = np.where(up > 0, qs - t[np.maximum(up - 1, 0)], np.inf)
        take_up = (d_up <= max_diff) & (d_up < d_lo)
        take_lo = ~take_up & (d_lo <= max_diff) & (d_lo <= d_up)
        keep = take_up | take_lo
        it = np.where(take_up, up, up - 1)
        return iq[keep], it[keep].astype(np.intp)
    # Unsorted target: brute force in blocks (first index of the smallest difference).
    iq_all, it_all = [], []
    block = max(1, 2_000_000 // t.size)
    for s in range(0, q.size, block):
        d = np.abs(t[None, :] - q[s : s + block, None])
        j = np.argmin(d, axis=1)
        ok = d[np.arange(j.size), j] <= max_diff
        iq_all.append(np.arange(s, s + j.size)[ok])
        it_all.append(j[ok])
    return np.concatenate(iq_all).astype(np.intp), np.concatenate(it_all).astype(np.intp)


@dataclass(frozen=True)
class Association:
    """Result of :func:`associate` with ``return_info=True``: the index pairs and counts.

    Attributes
    ----------
    index_first, index_second : numpy.ndarray
        Indices of the paired poses in the first and the second trajectory.
    max_pairs : int
        The shorter trajectory's length (the most pairs possible).
    duplicates_first, duplicates_second : int
        Repeated timestamps in each trajectory.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import read_tum, associate
    >>> ref, est, info = associate(*(read_tum(p) for p in example_paths()), return_info=True)
    >>> info.num_pairs == len(ref) == len(est), info.num_pairs <= info.max_pairs
    (True, True)
    """

    index_first: np.ndarray
    index_second: np.ndarray
    max_pairs: int
    duplicates_first: int
    duplicates_second: int

    @property
    def num_pairs(self) -> int:
        return int(self.index_first.size)


def associate(
    first: Trajectory,
    second: Trajectory,
    max_diff: float = 0.01,
    offset: float = 0.0,
    *,
    interpolate: str | None = None,
    return_info: bool = False,
) -> tuple[Trajectory, Trajectory] | tuple[Trajectory, Trajectory, Association]:
    """Reduce two timestamped trajectories to their pose pairs with matching stamps.

    Parameters
    ----------
    first, second : Trajectory
        Usually (reference, estimate).
    max_diff : float
        Largest accepted time difference, seconds.
    offset : float
        Added to the timestamps of ``second`` for the matching only.
    interpolate : {None, "se3", "split"}
        ``None`` pairs nearest stamps; otherwise the longer trajectory is interpolated at the
        matched stamps of the shorter one (see :func:`interpolate`).
    return_info : bool
        Also return an :class:`Association` with the indices and duplicate counts.

    Returns
    -------
    first, second : Trajectory
        The paired poses, index by index.
    info : Association
        Only with ``return_info=True``.

    Warns
    -----
    TimestampWarning
        A trajectory has repeated or decreasing timestamps.

    Raises
    ------
    ValueError
        A trajectory has no timestamps, or no pair is found.

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import read_tum, associate
    >>> ref, est = associate(*(read_tum(p) for p in example_paths()))
    >>> len(ref) == len(est)
    True
    """
    if first.timestamps is None or second.timestamps is None:
        raise ValueError("association needs timestamps on both trajectories")
    if interpolate is not None and interpolate not in INTERPOLATIONS:
        raise ValueError(f"unknown interpolation {interpolate!r}; expected one of "
                         f"{INTERPOLATIONS} or None")
    second_longer = len(second) > len(first)
    if second_longer:
        i1, i2 = match_timestamps(first.timestamps, second.timestamps, max_diff, offset)
    else:
        i2, i1 = match_timestamps(second.timestamps, first.timestamps, max_diff, -offset)
    if i1.size == 0:
        raise ValueError(
            f"no matching timestamps between {first.name or 'first trajectory'} and "
            f"{second.name or 'second trajectory'} (max. difference {max_diff} s, "
            f"offset {offset} s)"
        )
    for t in (first, second):
        t.warn_timestamps()
    a, b = _select(first, i1), _select(second, i2)
    if interpolate is not None:
        if second_longer:
            b = _interpolate(second, a.timestamps + offset, interpolate)
        else:
            a = _interpolate(first, b.timestamps - offset, interpolate)
    if not return_info:
        return a, b
    info = Association(
        i1,
        i2,
        min(len(first), len(second)),
        int(first.duplicate_timestamps().size),
        int(second.duplicate_timestamps().size),
    )
    return a, b, info


def _select(traj: Trajectory, index: np.ndarray) -> Trajectory:
    """``traj[index]``; without copying the poses when ``index`` is every pose in order (the
    usual association of two trajectories sampled at the same stamps)."""
    n = len(traj)
    if index.size == n and bool((index == np.arange(n)).all()):
        return Trajectory(traj.poses, traj.timestamps, traj.name)
    return traj[index]


_interpolate = interpolate  # ``associate`` has an argument of that name
