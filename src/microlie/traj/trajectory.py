"""The :class:`Trajectory` container: a batch of SE(3) poses with optional timestamps."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from microlie import SE3, SO3, Sim3

__all__ = ["Trajectory", "TimestampWarning", "PLANES", "merge"]

PLANES = ("xy", "xz", "yz")


class TimestampWarning(UserWarning):
    """Timestamps that make time association ambiguous (repeated or decreasing stamps)."""


class Trajectory:
    """A sequence of N poses ``T_world_body`` stored as one batched :class:`~microlie.SE3`.

    Instances are treated as immutable: every operation returns a new trajectory. Indexing
    with a slice, a boolean mask of length N or an integer index array returns a
    :class:`Trajectory` (``traj[10:20]``, ``traj[traj.timestamps > t0]``); one pose is
    ``traj.poses[i]``.

    Repeated or decreasing timestamps are not an error (files have them), but they make the
    pairing by time ambiguous: :meth:`check` lists them, and :func:`~microlie.traj.associate`
    emits a :class:`TimestampWarning` when it meets them.

    Parameters
    ----------
    poses : SE3
        Batch shape ``(N,)``, ``N >= 1``; params ``[tx, ty, tz, qx, qy, qz, qw]``.
    timestamps : array_like, optional
        ``(N,)`` seconds (stored as float64), or ``None`` (KITTI without a times file).
    name : str, optional
        A label (usually the file name) used in messages and plot legends.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.traj import Trajectory
    >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
    >>> t = Trajectory.from_arrays(np.arange(12.0).reshape(4, 3), q, [0.0, 0.1, 0.1, 0.3])
    >>> len(t[1:3]), len(t[t.timestamps > 0.05])
    (2, 3)
    >>> t.check()
    ['1 repeated timestamp (first at index 2, t = 0.1)']
    """

    __slots__ = ("poses", "timestamps", "name", "_positions")

    def __init__(
        self, poses: SE3, timestamps: Any = None, name: str | None = None
    ) -> None:
        if not isinstance(poses, SE3):
            raise TypeError(f"poses must be an SE3 batch, got {type(poses).__name__}")
        if len(poses.batch_shape) != 1:
            raise ValueError(f"poses must have batch shape (N,), got {poses.batch_shape}")
        n = poses.batch_shape[0]
        if n == 0:
            raise ValueError("a trajectory needs at least one pose")
        if timestamps is not None:
            timestamps = np.asarray(timestamps, dtype=np.float64)
            if timestamps.shape != (n,):
                raise ValueError(f"{timestamps.shape} timestamps for {n} poses")
        self.poses = poses
        self.timestamps = timestamps
        self.name = name
        self._positions: np.ndarray | None = None

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_arrays(
        cls,
        positions: Any,
        quat_xyzw: Any,
        timestamps: Any = None,
        name: str | None = None,
    ) -> Trajectory:
        """Build from positions and quaternions ``[qx, qy, qz, qw]`` (scalar last).

        Quaternions are normalised (callers validate how far from unit they may be).

        Parameters
        ----------
        positions : array_like
            ``(N, 3)`` positions.
        quat_xyzw : array_like
            ``(N, 4)`` quaternions, scalar last.
        timestamps : array_like, optional
            ``(N,)`` seconds.
        name : str, optional
            The label.

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> t = Trajectory.from_arrays([[1.0, 2, 3]], [[0, 0, 0, 2.0]], [0.5])
        >>> t.positions.tolist(), t.quat_xyzw.tolist()
        ([[1.0, 2.0, 3.0]], [[0.0, 0.0, 0.0, 1.0]])
        """
        t = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        rot = SO3.from_quat(np.asarray(quat_xyzw, dtype=np.float64), normalize=True)
        return cls(cast(SE3, SE3.from_rotation_translation(rot, t)), timestamps, name)

    @classmethod
    def from_rotation_matrices(
        cls,
        positions: Any,
        rotations: Any,
        timestamps: Any = None,
        name: str | None = None,
    ) -> Trajectory:
        """Build from positions and rotation matrices (projected onto SO(3)).

        Parameters
        ----------
        positions : array_like
            ``(N, 3)`` positions.
        rotations : array_like
            ``(N, 3, 3)`` rotation matrices.
        timestamps : array_like, optional
            ``(N,)`` seconds.
        name : str, optional
            The label.

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> t = Trajectory.from_rotation_matrices(np.zeros((2, 3)), np.stack([np.eye(3)] * 2))
        >>> len(t), t.timestamps is None
        (2, True)
        """
        t = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        rot = SO3.from_matrix(np.asarray(rotations, dtype=np.float64), normalize=True)
        return cls(cast(SE3, SE3.from_rotation_translation(rot, t)), timestamps, name)

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return self.poses.batch_shape[0]

    def __repr__(self) -> str:
        span = ""
        if self.timestamps is not None:
            span = f", {self.timestamps[-1] - self.timestamps[0]:.3f} s"
        return f"Trajectory({self.name!r}, {len(self)} poses, {self.path_length:.3f} m{span})"

    @property
    def positions(self) -> np.ndarray:
        """``(N, 3)`` positions (translations of the poses)."""
        if self._positions is None:
            self._positions = np.asarray(self.poses.translation())
        return self._positions

    @property
    def quat_xyzw(self) -> np.ndarray:
        """``(N, 4)`` unit quaternions, scalar last."""
        return np.asarray(self._rotations().as_quat())

    def _rotations(self) -> SO3:
        return cast(SO3, self.poses.rotation())

    def matrices(self) -> np.ndarray:
        """The poses as homogeneous matrices.

        Returns
        -------
        numpy.ndarray
            ``(N, 4, 4)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.matrices()[1, :3, 3].tolist()
        [1.0, 0.0, 0.0]
        """
        return np.asarray(self.poses.matrix())

    def euler(self, seq: str = "xyz", degrees: bool = False) -> np.ndarray:
        """Euler angles of the orientations (default roll, pitch, yaw: extrinsic ``"xyz"``).

        Parameters
        ----------
        seq : str
            Axis sequence as in :meth:`microlie.SO3.as_euler` (lower case extrinsic, upper case
            intrinsic).
        degrees : bool
            Degrees instead of radians.

        Returns
        -------
        numpy.ndarray
            ``(N, 3)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.euler(degrees=True)[0].tolist()
        [0.0, 0.0, 0.0]
        """
        return np.asarray(self._rotations().as_euler(seq, degrees=degrees))

    def step_lengths(self) -> np.ndarray:
        """Distances between consecutive positions.

        Returns
        -------
        numpy.ndarray
            ``(N - 1,)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.step_lengths().tolist()
        [1.0, 1.0, 1.0]
        """
        d = np.diff(self.positions, axis=0)
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def distances(self) -> np.ndarray:
        """Travelled distance from the first pose (0 at index 0).

        Returns
        -------
        numpy.ndarray
            ``(N,)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.distances().tolist(), t.path_length
        ([0.0, 1.0, 2.0, 3.0], 3.0)
        """
        out = np.zeros(len(self))
        np.cumsum(self.step_lengths(), out=out[1:])
        return out

    @property
    def path_length(self) -> float:
        """Total travelled distance in metres."""
        return float(self.step_lengths().sum())

    def duplicate_timestamps(self) -> np.ndarray:
        """Indices ``i`` with ``timestamps[i] == timestamps[i - 1]``.

        Returns
        -------
        numpy.ndarray
            Integer indices; empty if there are none or no timestamps.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> t = Trajectory.from_arrays(np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)), [0, 1, 1])
        >>> t.duplicate_timestamps().tolist()
        [2]
        """
        if self.timestamps is None:
            return np.zeros(0, dtype=np.intp)
        return np.flatnonzero(np.diff(self.timestamps) == 0) + 1

    def check(self) -> list[str]:
        """Problems of the timestamps that affect time association, one sentence each.

        Reports repeated timestamps and timestamps that decrease.

        Returns
        -------
        list of str
            Empty when there are none (also for a trajectory without timestamps).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> t = Trajectory.from_arrays(np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)), [0, 2, 1])
        >>> t.check()
        ['1 decreasing timestamp (first at index 2, t = 1)']
        """
        if self.timestamps is None:
            return []
        problems = []
        d = np.diff(self.timestamps)
        for mask, what in ((d == 0, "repeated timestamp"), (d < 0, "decreasing timestamp")):
            k = np.flatnonzero(mask) + 1
            if k.size:
                problems.append(
                    f"{k.size} {what}{'s' if k.size > 1 else ''} (first at index {k[0]}, "
                    f"t = {self.timestamps[k[0]]:.9g})"
                )
        return problems

    def warn_timestamps(self) -> None:
        """Emit a :class:`TimestampWarning` with :meth:`check`'s findings, if there are any.

        Examples
        --------
        >>> import warnings
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> t = Trajectory.from_arrays(np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), [1, 1],
        ...                            name="gt")
        >>> with warnings.catch_warnings(record=True) as w:
        ...     warnings.simplefilter("always")
        ...     t.warn_timestamps()
        >>> str(w[0].message)
        'gt: 1 repeated timestamp (first at index 1, t = 1)'
        """
        problems = self.check()
        if problems:
            warnings.warn(f"{self.name or 'trajectory'}: {'; '.join(problems)}",
                          TimestampWarning, stacklevel=3)

    # ------------------------------------------------------------------ operations
    def __getitem__(self, index: slice | Sequence[int] | np.ndarray) -> Trajectory:
        if isinstance(index, (int, np.integer)):
            raise TypeError(
                "index a Trajectory with a slice, a boolean mask or an index array "
                f"(traj[{index}:{index + 1}]); one pose is traj.poses[{index}]"
            )
        if isinstance(index, slice):
            idx: slice | np.ndarray = index
        else:
            idx = np.asarray(index)
            if idx.dtype == bool:
                if idx.shape != (len(self),):
                    raise ValueError(
                        f"a boolean mask must have shape ({len(self)},), got {idx.shape}"
                    )
                idx = np.flatnonzero(idx)
            elif idx.ndim != 1 or not (idx.size == 0 or np.issubdtype(idx.dtype, np.integer)):
                raise TypeError(f"index arrays must be 1-D integers, got {idx.dtype} {idx.shape}")
            else:
                idx = idx.astype(np.intp)
                if idx.size and (idx.max() >= len(self) or idx.min() < -len(self)):
                    raise IndexError(f"index out of range for a trajectory of {len(self)} poses")
        sel = np.arange(len(self))[idx]
        if sel.size == 0:
            raise ValueError("the selection is empty (a trajectory needs at least one pose)")
        stamps = None if self.timestamps is None else self.timestamps[sel]
        return Trajectory(cast(SE3, self.poses[sel]), stamps, self.name)

    def subset(self, index: Sequence[int] | np.ndarray | slice) -> Trajectory:
        """The poses (and timestamps) at ``index``; the same as ``traj[index]``.

        Parameters
        ----------
        index : slice, sequence of int or numpy.ndarray
            A slice, integer indices or a boolean mask of length N.

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.subset([0, 3]).positions.tolist()
        [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
        """
        return self[index]

    def crop(self, t_start: float | None = None, t_end: float | None = None) -> Trajectory:
        """The poses with ``t_start <= timestamp <= t_end`` (absolute seconds).

        Parameters
        ----------
        t_start, t_end : float, optional
            The window; ``None`` leaves that side open.

        Returns
        -------
        Trajectory

        Raises
        ------
        ValueError
            No timestamps, ``t_start > t_end``, or no pose in the window.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.crop(0.5, 2.0).timestamps.tolist()
        [1.0, 2.0]
        """
        if self.timestamps is None:
            raise ValueError(f"{self.name or 'trajectory'} has no timestamps to crop by")
        lo = -np.inf if t_start is None else float(t_start)
        hi = np.inf if t_end is None else float(t_end)
        if lo > hi:
            raise ValueError(f"t_start {lo} is after t_end {hi}")
        keep = (self.timestamps >= lo) & (self.timestamps <= hi)
        if not keep.any():
            raise ValueError(
                f"{self.name or 'trajectory'}: no pose between t = {lo} and {hi} s "
                f"(its stamps span {self.timestamps[0]:.9g} .. {self.timestamps[-1]:.9g})"
            )
        return self[keep]

    def downsample(self, num_poses: int) -> Trajectory:
        """At most ``num_poses`` poses, evenly spaced by index (first and last kept).

        Indices ``floor(linspace(0, N - 1, num_poses))``, as evo's ``downsample`` chooses them;
        a trajectory with no more than ``num_poses`` poses is returned unchanged.

        Parameters
        ----------
        num_poses : int
            A positive number of poses.

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> t = Trajectory.from_arrays(np.zeros((10, 3)), np.tile([0, 0, 0, 1.0], (10, 1)),
        ...                            np.arange(10.0))
        >>> t.downsample(4).timestamps.tolist()
        [0.0, 3.0, 6.0, 9.0]
        """
        if int(num_poses) != num_poses or num_poses < 1:
            raise ValueError(f"num_poses must be a positive integer, got {num_poses}")
        if len(self) <= num_poses:
            return self
        return self[np.linspace(0, len(self) - 1, int(num_poses), dtype=int)]

    def project(self, plane: str = "xy") -> Trajectory:
        """Project onto a coordinate plane for 2-D evaluation.

        The out-of-plane coordinate is set to 0 and each orientation is replaced by the
        rotation about the plane normal ``n`` closest to it: its *twist* about ``n``, angle
        ``atan2(n . v, (tr R - n^T R n) / 2)`` with ``v`` the axial vector of
        ``(R - R^T) / 2``. This is the heading in the plane for any orientation (evo takes
        an Euler angle instead, which folds headings beyond 90 degrees for ``xz`` / ``yz``).

        Parameters
        ----------
        plane : {"xy", "xz", "yz"}
            The plane kept.

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> from microlie.traj import Trajectory
        >>> R = SO3.from_euler("xyz", [0.0, 0.0, 2.5]).matrix()
        >>> p = Trajectory.from_rotation_matrices([[1.0, 2, 3]], R[None]).project("xy")
        >>> p.positions.tolist(), np.round(p.euler(), 12).tolist()
        ([[1.0, 2.0, 0.0]], [[0.0, 0.0, 2.5]])
        """
        if plane not in PLANES:
            raise ValueError(f"unknown plane {plane!r}; expected one of {PLANES}")
        k = {"xy": 2, "xz": 1, "yz": 0}[plane]
        r = np.asarray(self.poses.rotation().matrix())
        a, b = [(1, 2), (2, 0), (0, 1)][k]  # the two in-plane axes, right-handed about n
        sin_part = r[:, b, a] - r[:, a, b]  # 4 w q_n in quaternion terms
        cos_part = r[:, a, a] + r[:, b, b]  # 2 (w^2 - q_n^2): atan2 gives the twist angle
        theta = np.arctan2(sin_part, cos_part)
        phi = np.zeros((len(self), 3))
        phi[:, k] = theta
        p = self.positions.copy()
        p[:, k] = 0.0
        poses = cast(SE3, SE3.from_rotation_translation(SO3.exp(phi), p))
        return Trajectory(poses, self.timestamps, self.name)

    def transform(self, g: SE3 | Sim3) -> Trajectory:
        """Left-multiply every pose by ``g`` (a single SE3 or Sim3).

        With a Sim3 ``g = (R, t, s)`` the result is the SE3 pose with rotation ``R R_i`` and
        translation ``s R t_i + t``: the positions are mapped by the similarity, the
        orientations only rotated (a pose has no scale).

        Parameters
        ----------
        g : SE3 or Sim3
            One element (empty batch shape).

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import Sim3, SO3
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> t = Trajectory.from_arrays([[1.0, 0, 0]], [[0, 0, 0, 1.0]])
        >>> g = Sim3.from_rotation_translation_scale(SO3.identity(), [0, 0, 1.0], 2.0)
        >>> t.transform(g).positions.tolist()
        [[2.0, 0.0, 1.0]]
        """
        if isinstance(g, Sim3):
            as_sim = Sim3.from_rotation_translation_scale(
                self.poses.rotation(), self.positions, np.ones(len(self))
            )
            moved = cast(Sim3, g @ as_sim)
            poses = cast(SE3, SE3.from_rotation_translation(moved.rotation(), moved.translation()))
        elif isinstance(g, SE3):
            poses = cast(SE3, g @ self.poses)
        else:
            raise TypeError(f"cannot transform a trajectory by {type(g).__name__}")
        return Trajectory(poses, self.timestamps, self.name)

    def with_name(self, name: str | None) -> Trajectory:
        """The same trajectory under another name.

        Parameters
        ----------
        name : str or None
            The new label.

        Returns
        -------
        Trajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.traj import Trajectory
        >>> q = np.tile([0, 0, 0, 1.0], (4, 1))
        >>> p = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]
        >>> t = Trajectory.from_arrays(p, q, [0, 1, 2, 3.0])
        >>> t.with_name("estimate").name
        'estimate'
        """
        return Trajectory(self.poses, self.timestamps, name)


def merge(trajs: Sequence[Trajectory], name: str = "merged") -> Trajectory:
    """One trajectory of all poses of ``trajs``, sorted by timestamp (stable: on equal stamps
    the earlier trajectory's pose comes first).

    Parameters
    ----------
    trajs : sequence of Trajectory
        Each with timestamps.
    name : str
        The merged trajectory's label.

    Returns
    -------
    Trajectory

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.traj import Trajectory, merge
    >>> a = Trajectory.from_arrays(np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), [0, 2])
    >>> b = Trajectory.from_arrays(np.ones((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), [1, 3])
    >>> merge([a, b]).timestamps
    array([0., 1., 2., 3.])
    """
    if not trajs:
        raise ValueError("nothing to merge")
    if any(t.timestamps is None for t in trajs):
        raise ValueError("merging needs timestamps on every trajectory")
    stamps = np.concatenate([t.timestamps for t in trajs if t.timestamps is not None])
    order = np.argsort(stamps, kind="stable")
    params = np.concatenate([np.asarray(t.poses.params) for t in trajs])[order]
    return Trajectory(SE3(params), stamps[order], name)
