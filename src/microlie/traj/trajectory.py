"""The :class:`Trajectory` container: a batch of SE(3) poses with optional timestamps."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from microlie import SE3, SO3, Sim3

__all__ = ["Trajectory"]


class Trajectory:
    """A sequence of N poses ``T_world_body`` stored as one batched :class:`~microlie.SE3`.

    Attributes:
        poses: ``SE3`` with batch shape ``(N,)``; params ``[tx, ty, tz, qx, qy, qz, qw]``.
        timestamps: ``(N,)`` float64 seconds, or ``None`` (e.g. KITTI without a times file).
        name: a label (usually the file name) used in messages and plot legends.

    Instances are treated as immutable: every operation returns a new trajectory.
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
        """Build from ``(N, 3)`` positions and ``(N, 4)`` quaternions ``[qx, qy, qz, qw]``.

        Quaternions are normalised (callers validate how far from unit they may be).
        """
        t = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        rot = SO3.from_quat(np.asarray(quat_xyzw, dtype=np.float64), normalize=True)
        return cls(SE3.from_rotation_translation(rot, t), timestamps, name)

    @classmethod
    def from_rotation_matrices(
        cls,
        positions: Any,
        rotations: Any,
        timestamps: Any = None,
        name: str | None = None,
    ) -> Trajectory:
        """Build from ``(N, 3)`` positions and ``(N, 3, 3)`` rotation matrices."""
        t = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        rot = SO3.from_matrix(np.asarray(rotations, dtype=np.float64), normalize=True)
        return cls(SE3.from_rotation_translation(rot, t), timestamps, name)

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
        return np.asarray(self.poses.rotation().as_quat())

    def matrices(self) -> np.ndarray:
        """``(N, 4, 4)`` homogeneous matrices."""
        return np.asarray(self.poses.matrix())

    def euler(self, seq: str = "xyz", degrees: bool = False) -> np.ndarray:
        """``(N, 3)`` Euler angles of the orientations (default roll, pitch, yaw, extrinsic xyz)."""
        return np.asarray(self.poses.rotation().as_euler(seq, degrees=degrees))

    def step_lengths(self) -> np.ndarray:
        """``(N-1,)`` distances between consecutive positions."""
        d = np.diff(self.positions, axis=0)
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def distances(self) -> np.ndarray:
        """``(N,)`` travelled distance from the first pose (0 at index 0)."""
        out = np.zeros(len(self))
        np.cumsum(self.step_lengths(), out=out[1:])
        return out

    @property
    def path_length(self) -> float:
        """Total travelled distance in metres."""
        return float(self.step_lengths().sum())

    def duplicate_timestamps(self) -> np.ndarray:
        """Indices ``i`` with ``timestamps[i] == timestamps[i - 1]`` (empty if none / no stamps)."""
        if self.timestamps is None:
            return np.zeros(0, dtype=np.intp)
        return np.flatnonzero(np.diff(self.timestamps) == 0) + 1

    # ------------------------------------------------------------------ operations
    def subset(self, index: Sequence[int] | np.ndarray | slice) -> Trajectory:
        """The poses (and timestamps) at ``index`` (an index array or a slice)."""
        idx = index if isinstance(index, slice) else np.asarray(index, dtype=np.intp)
        stamps = None if self.timestamps is None else self.timestamps[idx]
        return Trajectory(self.poses[idx], stamps, self.name)

    def transform(self, g: SE3 | Sim3) -> Trajectory:
        """Left-multiply every pose by ``g`` (a single SE3 or Sim3).

        With a Sim3 ``g = (R, t, s)`` the result is the SE3 pose with rotation ``R R_i`` and
        translation ``s R t_i + t``: the positions are mapped by the similarity, the
        orientations only rotated (a pose has no scale).
        """
        if isinstance(g, Sim3):
            as_sim = Sim3.from_rotation_translation_scale(
                self.poses.rotation(), self.positions, np.ones(len(self))
            )
            moved = g @ as_sim
            poses = SE3.from_rotation_translation(moved.rotation(), moved.translation())
        elif isinstance(g, SE3):
            poses = g @ self.poses
        else:
            raise TypeError(f"cannot transform a trajectory by {type(g).__name__}")
        return Trajectory(poses, self.timestamps, self.name)

    def with_name(self, name: str | None) -> Trajectory:
        """The same trajectory under another name."""
        return Trajectory(self.poses, self.timestamps, name)
