"""Trajectories from ROS 1 and ROS 2 bags, through the pure-Python ``rosbags`` package
(Apache-2.0, an optional extra: ``pip install 'microlie[ros]'``, imported only here and only
when a bag is read).

Supported topics (one pose per message, timestamp from the message header,
``sec + nanosec * 1e-9`` seconds):

* ``geometry_msgs/PoseStamped``, ``geometry_msgs/PoseWithCovarianceStamped``,
  ``nav_msgs/Odometry`` (its ``pose.pose``), ``geometry_msgs/TransformStamped``;
* ``/tf`` (and ``/tf_static``, any ``tf2_msgs/TFMessage`` topic) as ``"/tf:PARENT.CHILD"``
  (evo's spelling): the transforms whose ``header.frame_id`` is ``PARENT`` and whose
  ``child_frame_id`` is ``CHILD``, i.e. the pose ``T_PARENT_CHILD``. Only transforms published
  directly between the two frames are used (no chaining through the tf tree).

A ROS 1 bag is a ``.bag`` file; a ROS 2 bag is its directory (with ``metadata.yaml``) or the
``.db3`` / ``.mcap`` file in it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from .trajectory import Trajectory

__all__ = ["read_bag", "bag_topics", "is_bag"]

_POSE_TYPES = {
    "geometry_msgs/msg/PoseStamped": lambda m: (m.pose.position, m.pose.orientation),
    "geometry_msgs/msg/PoseWithCovarianceStamped":
        lambda m: (m.pose.pose.position, m.pose.pose.orientation),
    "nav_msgs/msg/Odometry": lambda m: (m.pose.pose.position, m.pose.pose.orientation),
    "geometry_msgs/msg/TransformStamped":
        lambda m: (m.transform.translation, m.transform.rotation),
}
_TF = "tf2_msgs/msg/TFMessage"


def is_bag(path: str | os.PathLike) -> bool:
    """Whether ``path`` looks like a ROS bag (``.bag``, ``.db3``, ``.mcap`` or a ROS 2 folder).

    Parameters
    ----------
    path : str or os.PathLike
        A file or directory.

    Returns
    -------
    bool

    Examples
    --------
    >>> from microlie.traj.rosbag import is_bag
    >>> is_bag("run.bag"), is_bag("run.mcap"), is_bag("trajectory.txt")
    (True, True, False)
    """
    p = Path(path)
    return p.suffix in (".bag", ".db3", ".mcap") or (p.is_dir() and (p / "metadata.yaml").exists())


def _rosbags() -> Any:
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError as exc:
        raise ImportError("reading ROS bags needs rosbags: pip install 'microlie[ros]'") from exc
    return AnyReader, typestore(Stores, get_types_from_msg, get_typestore)


def typestore(Stores: Any, get_types_from_msg: Any, get_typestore: Any, ros1: bool = False) -> Any:
    """rosbags' ROS 2 Humble (or ROS 1 Noetic) message types plus ``tf2_msgs/TFMessage``, for
    bags that do not embed their message definitions."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if _TF not in store.types:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", _TF))
    return store


def _open(path: str | os.PathLike) -> Any:
    AnyReader, store = _rosbags()
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such bag")
    if p.suffix in (".db3", ".mcap"):
        p = p.parent
    return AnyReader([p], default_typestore=store)


def bag_topics(path: str | os.PathLike) -> dict[str, str]:
    """``{topic: message type}`` of the bag at ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The bag.

    Returns
    -------
    dict of str to str

    Examples
    --------
    Needs a bag file:

    >>> from microlie.traj.rosbag import bag_topics
    >>> bag_topics("run.bag")  # doctest: +SKIP
    {'/pose': 'geometry_msgs/msg/PoseStamped', '/tf': 'tf2_msgs/msg/TFMessage'}
    """
    with _open(path) as reader:
        return {c.topic: c.msgtype for c in reader.connections}


def _stamp(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def read_bag(
    path: str | os.PathLike, topic: str, *, quat_tol: float = 1e-3, name: str | None = None
) -> Trajectory:
    """Read the poses of ``topic`` (module docstring) from the bag at ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        A ROS 1 ``.bag`` file, a ROS 2 bag directory or its ``.db3`` / ``.mcap`` file.
    topic : str
        A pose topic, or ``"/tf:PARENT.CHILD"`` for the transforms between two frames.
    quat_tol : float
        Largest accepted ``| |q| - 1 |``.
    name : str, optional
        The trajectory's label (default: the path and topic).

    Returns
    -------
    Trajectory

    Raises
    ------
    ValueError
        The topic is missing or of an unsupported type, has no message (or no transform
        between the frames), or a quaternion is off unit norm by more than ``quat_tol``.
    ImportError
        ``rosbags`` is not installed.

    Examples
    --------
    Needs a bag file (the tests write their own):

    >>> from microlie.traj.rosbag import read_bag
    >>> traj = read_bag("run.bag", "/tf:map.base_link")  # doctest: +SKIP
    """
    frames: tuple[str, str] | None = None
    wanted = topic
    if ":" in topic:
        wanted, spec = topic.split(":", 1)
        if "." not in spec:
            raise ValueError(f"tf topics are given as '/tf:PARENT.CHILD', got {topic!r}")
        parent, child = spec.split(".", 1)
        frames = (parent.lstrip("/"), child.lstrip("/"))
    stamps: list[float] = []
    values: list[list[float]] = []
    with _open(path) as reader:
        conns = [c for c in reader.connections if c.topic == wanted]
        if not conns:
            have = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
            raise ValueError(f"{path}: no topic {wanted!r} (topics: {have})")
        msgtype = conns[0].msgtype
        if msgtype == _TF:
            if frames is None:
                raise ValueError(
                    f"{path}: {wanted} is a tf topic: give the frames as '{wanted}:PARENT.CHILD'"
                )
        elif msgtype not in _POSE_TYPES:
            raise ValueError(
                f"{path}: topic {wanted} has type {msgtype}; supported: "
                f"{', '.join(sorted(_POSE_TYPES))}, {_TF}"
            )
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if msgtype == _TF:
                assert frames is not None
                for tf in msg.transforms:
                    if (tf.header.frame_id.lstrip("/"), tf.child_frame_id.lstrip("/")) == frames:
                        stamps.append(_stamp(tf.header))
                        t, q = tf.transform.translation, tf.transform.rotation
                        values.append([t.x, t.y, t.z, q.x, q.y, q.z, q.w])
            else:
                p, q = _POSE_TYPES[msgtype](msg)
                stamps.append(_stamp(msg.header))
                values.append([p.x, p.y, p.z, q.x, q.y, q.z, q.w])
    if not values:
        what = f"transform {frames[0]} -> {frames[1]}" if frames else "message"
        raise ValueError(f"{path}: no {what} on {wanted}")
    v = np.asarray(values, dtype=np.float64)
    if not np.isfinite(v).all():
        raise ValueError(f"{path}: {topic}: message {np.argwhere(~np.isfinite(v))[0, 0]} "
                         "has a non-finite value")
    norms = np.linalg.norm(v[:, 3:], axis=1)
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= quat_tol))
    if bad.size:
        raise ValueError(f"{path}: {topic}: message {bad[0]}: quaternion is not unit norm "
                         f"(|q| = {norms[bad[0]]:.6g}, tolerance {quat_tol:g})")
    return Trajectory.from_arrays(v[:, :3], v[:, 3:], np.asarray(stamps),
                                  name=name or f"{path}:{topic}")
