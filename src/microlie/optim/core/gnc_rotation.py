"""Rotations first: GNC-TLS on the chordal rotation relaxation alone (rotation averaging).

A random wrong edge of a pose graph almost always has a wrong rotation: with the rotation
noise of the usual data sets (a few hundredths of a radian) a uniformly random rotation of
SO(3) is within three standard deviations of the truth with probability below ``1e-4``.
Judging an edge by its rotation alone needs only the rotations, and these can be estimated
without the translations: GNC-TLS whose inner solver is the chordal rotation relaxation
(weighted linear least squares on the entries of the rotation matrices, the anchor held, each
edge's weight times its rotation precision ``rho / trace(Sigma_R)``, projected to SO(n) by
SVD; :mod:`microlie.optim.core.gnc_chordal`), each edge judged on its whitened squared
rotation residual

``s_R = r^T Omega_R r``, ``r = Log(R_z^-1 R_i^-1 R_j)``, ``Omega_R = (Sigma_RR)^-1``

(the marginal rotation information) against ``c_R^2 = chi2.ppf(quantile, dof_R)`` (1 in 2-D,
3 in 3-D), as in the GNC paper's rotation averaging (Yang et al., RA-L 2020). The edges it
rejects are held at weight 0 by the chordal stage that follows
(:func:`~microlie.optim.core.gnc_chordal.chordal_gnc`'s ``rejected``), which judges the others
on the whole residual; the nonlinear GNC after it judges every edge again
(``GNC(first="cycles", rotations=True)``).

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_rotation import rotation_gnc
>>> # a triangle 0-1-2 and a fourth edge 0-2 whose rotation is 2 rad off
>>> Z = SE2.from_xy_theta([1.0, 1.0, 2.0, 2.0], [0.0, 0.0, 0.0, 0.0], [0.1, 0.2, 0.3, 2.3])
>>> R, w = rotation_gnc(SE2, 3, np.array([0, 1, 0, 0]), np.array([1, 2, 2, 2]), Z,
...                     np.tile(np.eye(3) * 100.0, (4, 1, 1)), 0,
...                     np.array([True, True, False, False]))
>>> w.tolist(), np.round(R[:, 0, 0], 6).tolist()  # cos of the rotations 0, 0.1, 0.3
([1.0, 1.0, 1.0, 0.0], [1.0, 0.995004, 0.955336])
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import SE2, SE3, SO2, SO3, LieGroup
from .gnc_chordal import _graduate, _WeightedLS

__all__ = ["rotation_gnc"]


def rotation_gnc(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                 info: np.ndarray, anchor: int, known: np.ndarray, *, quantile: float = 0.99,
                 mu_step: float = 1.4, max_iter: int = 100, weights_tol: float = 1e-4
                 ) -> tuple[np.ndarray, np.ndarray]:
    """GNC-TLS on the chordal rotation relaxation (module docstring).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges ``X_i^-1 X_j = Z``.
    Z : LieGroup
        ``(E,)`` measurements (only their rotations are used).
    info : numpy.ndarray
        ``(E, D, D)`` information matrices (tangent order: translation, then rotation).
    anchor : int
        The vertex whose rotation is held at the identity.
    known : numpy.ndarray
        ``(E,)`` booleans: edges that keep weight 1.
    quantile : float
        Chi-square quantile of the rotation threshold, ``0 < quantile < 1``.
    mu_step : float
        Factor of ``mu`` per outer iteration, > 1.
    max_iter : int
        Outer iterations at most, >= 1.
    weights_tol : float
        Stop when every weight is within this of 0 or 1.

    Returns
    -------
    rotations : numpy.ndarray
        ``(n, d, d)`` the rotation matrices of the last relaxation (the anchor's the
        identity).
    weights : numpy.ndarray
        ``(E,)`` 0 or 1: 0 for an edge whose rotation was judged an outlier.

    Raises
    ------
    ValueError
        A group other than SE2/SE3, bad shapes or options.

    Examples
    --------
    See the module docstring.
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    if group not in (SE2, SE3):
        raise ValueError(f"rotation_gnc: group must be SE2 or SE3, got {group!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    E = ii.size
    known = np.asarray(known, dtype=bool)
    if jj.shape != (E,) or known.shape != (E,) or np.shape(info)[0] != E:
        raise ValueError("rotation_gnc: ii, jj, known and info must have one entry per edge")
    if not 0 <= anchor < n:
        raise ValueError(f"rotation_gnc: anchor must be a vertex in [0, {n}), got {anchor}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"rotation_gnc: quantile must be strictly between 0 and 1, got "
                         f"{quantile!r}")
    if not (np.isfinite(mu_step) and mu_step > 1.0):
        raise ValueError(f"rotation_gnc: mu_step must be a finite number > 1, got {mu_step!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or \
            max_iter < 1:
        raise ValueError(f"rotation_gnc: max_iter must be an integer >= 1, got {max_iter!r}")
    d = 2 if group is SE2 else 3
    rot = SO2 if d == 2 else SO3
    cov = np.linalg.inv(info)
    D = info.shape[-1]
    info_r = np.linalg.inv(cov[:, d:, d:])  # marginal information of the rotation
    omega = (D - d) / np.trace(cov[:, d:, d:], axis1=1, axis2=2)  # chordal rotation weight
    Rz = np.asarray(Z.rotation().matrix(), dtype=np.float64)  # type: ignore[attr-defined]
    Rzinv = rot.from_matrix(np.swapaxes(Rz, 1, 2))
    keep = np.delete(np.arange(n), anchor)
    eye = np.broadcast_to(np.eye(d), (E, d, d))
    rot_ls = _WeightedLS(ii, jj, np.swapaxes(Rz, 1, 2), -eye, np.zeros((E, d, d)), n, anchor,
                         np.eye(d))

    def relax(w: np.ndarray) -> np.ndarray:
        x = rot_ls(w * omega)
        xs = np.empty((n, d, d))
        xs[anchor] = np.eye(d)
        xs[keep] = x.reshape(-1, d, d)
        return np.asarray(rot.from_matrix(np.swapaxes(xs, 1, 2), normalize=True).matrix(),
                          dtype=np.float64)

    def resid(R: np.ndarray) -> np.ndarray:
        rel = rot.from_matrix(np.swapaxes(R[ii], 1, 2) @ R[jj])
        r = np.asarray(Rzinv.compose(rel).log(), dtype=np.float64).reshape(E, -1)
        return np.einsum("ea,eab,eb->e", r, info_r, r)

    w = np.ones(E)
    R, _, _ = _graduate(relax, resid, w, ~known, float(chi2.ppf(quantile, D - d)), mu_step,
                        int(max_iter), weights_tol)
    return R, w
