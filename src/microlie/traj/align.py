"""Trajectory alignment: Umeyama SE(3) / Sim(3), scale only, origin, none.

All alignments map the *estimate* onto the *reference*: the returned transform ``g`` is applied
on the left of every estimated pose (``T_i <- g T_i``; with a Sim(3) ``g = (R, t, s)`` the
positions become ``s R p_i + t`` and the orientations ``R R_i``).
"""

from __future__ import annotations

import numpy as np

from microlie import SE3, SO3, Sim3

from .trajectory import Trajectory

__all__ = ["umeyama", "align", "ALIGNMENTS"]

ALIGNMENTS = ("none", "se3", "sim3", "scale", "origin")


def umeyama(
    source: np.ndarray, target: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity ``(R, t, s)`` minimising ``sum |target_i - (s R source_i + t)|^2``.

    Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", IEEE PAMI 13(4), 1991. ``R`` is a proper rotation (reflections are excluded by
    the sign correction of the smallest singular direction).

    Parameters
    ----------
    source, target : array_like
        ``(N, 3)`` corresponding points.
    with_scale : bool
        Estimate ``s``; without it ``s`` is 1.

    Returns
    -------
    R : numpy.ndarray
        ``(3, 3)`` rotation.
    t : numpy.ndarray
        ``(3,)`` translation.
    s : float
        Scale.

    Raises
    ------
    ValueError
        Shapes differ, or the points are degenerate (fewer than two independent directions),
        so that the rotation is not determined.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> from microlie.traj import umeyama
    >>> x = np.random.default_rng(0).normal(size=(10, 3))
    >>> R0 = SO3.exp([0.1, 0.2, 0.3]).matrix()
    >>> R, t, s = umeyama(x, 2.0 * x @ R0.T + [1.0, 0, 0], with_scale=True)
    >>> bool(np.allclose(R, R0)), bool(np.allclose(t, [1, 0, 0])), round(s, 9)
    (True, True, 2.0)
    """
    # contiguous copies (trajectory positions are strided views of the poses: every pass below
    # would be slower on them)
    x = np.ascontiguousarray(source, dtype=np.float64)
    y = np.ascontiguousarray(target, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"umeyama needs two (N, 3) arrays, got {x.shape} and {y.shape}")
    n = x.shape[0]
    # = x.mean(axis=0) (the same sequential sum), without NumPy's slow reduction over axis 0
    mx = np.einsum("ij->j", x) / n
    my = np.einsum("ij->j", y) / n
    xc = x - mx
    yc = y - my
    var_x = np.einsum("ij,ij->", xc, xc) / n
    cov = (yc.T @ xc) / n
    u, d, vt = np.linalg.svd(cov)
    if not d[1] > 1e-12 * d[0]:  # rank < 2 (up to rounding): rotation undetermined
        raise ValueError("degenerate point sets: Umeyama alignment is not determined")
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        sign[2] = -1.0
    r = (u * sign) @ vt
    s = float((d * sign).sum() / var_x) if with_scale else 1.0
    t = my - s * (r @ mx)
    return r, t, s


def align(
    ref: Trajectory,
    est: Trajectory,
    method: str = "se3",
    n: int | None = None,
) -> tuple[Trajectory, SE3 | Sim3 | None]:
    """Align ``est`` to ``ref`` (same length, paired index by index; reference first, as in
    every function of :mod:`microlie.traj`).

    Parameters
    ----------
    ref, est : Trajectory
        Paired trajectories (see :func:`associate`).
    method : {"se3", "sim3", "scale", "origin", "none"}
        ``"se3"`` (rigid Umeyama), ``"sim3"`` (Umeyama with scale, for monocular
        estimates), ``"scale"`` (only the Umeyama scale, no rotation or translation),
        ``"origin"`` (make the first poses coincide: ``g = T_ref,0 T_est,0^-1``) or
        ``"none"``.
    n : int, optional
        Use only the first ``n`` pose pairs to estimate the transform (all if ``None``).

    Returns
    -------
    aligned : Trajectory
        ``g`` applied to ``est`` (see :meth:`Trajectory.transform`).
    g : SE3, Sim3 or None
        The transform applied (``None`` for ``"none"``).

    Examples
    --------
    >>> from microlie.traj import read_tum, associate, align
    >>> from microlie.data import example_paths
    >>> ref, est = associate(*(read_tum(p) for p in example_paths()))
    >>> aligned, g = align(ref, est, "sim3")
    >>> round(float(g.scale()), 4) > 0
    True
    """
    if len(est) != len(ref):
        raise ValueError(f"align needs paired trajectories, got {len(est)} and {len(ref)} poses")
    if method not in ALIGNMENTS:
        raise ValueError(f"unknown alignment {method!r}; expected one of {ALIGNMENTS}")
    if method == "none":
        return est, None
    g: SE3 | Sim3
    if method == "origin":
        g = ref.poses[0] @ est.poses[0].inverse()
        return est.transform(g), g
    k = len(est) if n is None or n < 0 else int(n)
    if k < 3 and method != "scale":
        raise ValueError(f"Umeyama alignment needs at least 3 poses, got {k}")
    r, t, s = umeyama(est.positions[:k], ref.positions[:k], with_scale=method != "se3")
    if method == "se3":
        g = SE3.from_rotation_translation(SO3.from_matrix(r), t)
    elif method == "sim3":
        g = Sim3.from_rotation_translation_scale(SO3.from_matrix(r), t, s)
    else:  # scale only
        g = Sim3.from_rotation_translation_scale(SO3.identity(), np.zeros(3), s)
    return est.transform(g), g
