"""What the pose-graph readers do with information matrices that are not positive definite.

A g2o or TORO file gives each edge a symmetric information matrix ``Omega`` (in our tangent
order, translation first). A factor needs ``Omega`` positive definite: it whitens the residual
with the Cholesky factor of ``Omega``. Some benchmark files break this (cubicle.g2o: 5,021 of its
16,869 edges are indefinite). The readers take ``information=`` (and ``microlie optimize``
``--information``):

* ``"strict"`` (default): such a file is refused with ``FILE:LINE`` of the first bad edge and
  the number of bad edges. Nothing is changed.
* ``"nearest-psd"``: each matrix that is not positive definite is replaced by the nearest
  symmetric matrix, in the Frobenius norm, whose eigenvalues are at least
  ``delta = PSD_FLOOR * lambda_max`` (Higham, "Computing a nearest symmetric positive
  semidefinite matrix", 1988: for a symmetric ``A = V diag(lam) V^T`` it is
  ``V diag(max(lam, delta)) V^T``). With ``delta = 0`` this is the nearest positive
  semi-definite matrix, but that is singular, and a singular ``Omega`` has no Cholesky factor;
  the floor, relative to the matrix's own largest eigenvalue so that it does not depend on the
  units, keeps the condition number at most ``1 / PSD_FLOOR = 1e9`` and moves the matrix by at
  most ``sqrt(k) delta`` more than the semi-definite projection (``k`` clipped eigenvalues).
  The positive definite matrices are kept bit for bit. A matrix with no positive eigenvalue
  carries no information to keep and is refused.
* ``"isotropic"``: every matrix is replaced by SE-Sync's isotropic precisions (Rosen et al.,
  IJRR 2019; ``SESync_utils.cpp``) from the translation block ``Omega_t`` and the rotation
  block ``Omega_R``: in 3-D ``tau = 3 / tr(Omega_t^-1)``, ``kappa = 3 / (2 tr(Omega_R^-1))``; in
  2-D ``tau = 2 / tr(Omega_t^-1)``, ``kappa = Omega_R`` (the theta-theta entry). SE-Sync
  minimises ``sum kappa |R_j - R_i R_ij|_F^2 + tau |t_j - t_i - R_i t_ij|^2``; as
  ``|R_j - R_i R_ij|_F^2 = 2 |theta|^2`` to second order in the rotation error ``theta`` (2-D
  and 3-D), the information of our residual ``(rho, theta)`` is ``diag(tau I, 2 kappa I)``, and
  our cost ``0.5 r^T Omega r`` is half SE-Sync's to second order. A 3-D matrix that is already
  isotropic, ``diag(a I, b I)``, is kept; in 2-D the rotation precision doubles, as in SE-Sync.
  Each block must be positive definite (else ``FILE:LINE``).

The readers report the edges whose file matrix was not positive definite in
:attr:`PoseGraph.repaired <microlie.optim.io.pose_graph.PoseGraph.repaired>` (the command: the
JSON ``repaired_edges``).

>>> import numpy as np
>>> from microlie.optim.io.information import nearest_psd
>>> A = np.array([[2.0, 0.0], [0.0, -1.0]])
>>> np.round(nearest_psd(A), 12).tolist()  # -1 clipped to 1e-9 * 2
[[2.0, 0.0], [0.0, 2e-09]]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["INFORMATION_POLICIES", "PSD_FLOOR", "nearest_psd", "isotropic_information",
           "apply_information_policy"]

#: The readers' ``information=`` choices (``microlie optimize --information``).
INFORMATION_POLICIES = ("strict", "nearest-psd", "isotropic")
#: ``"nearest-psd"``'s eigenvalue floor, relative to each matrix's largest eigenvalue.
PSD_FLOOR = 1e-9


def nearest_psd(information: np.ndarray, floor: float = PSD_FLOOR) -> np.ndarray:
    r"""The nearest symmetric matrices, in the Frobenius norm, whose eigenvalues are at least
    ``floor`` times their largest one (Higham 1988; see the module docstring).

    Parameters
    ----------
    information : numpy.ndarray
        ``(..., d, d)`` symmetric matrices (the symmetric part is used) with a positive
        eigenvalue.
    floor : float
        The relative eigenvalue floor, in ``[0, 1)`` (0: the nearest positive semi-definite
        matrix, singular when the input is indefinite).

    Returns
    -------
    numpy.ndarray
        ``(..., d, d)``, symmetric.

    Raises
    ------
    ValueError
        ``floor`` outside ``[0, 1)``, or a matrix with no positive eigenvalue.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.io.information import nearest_psd
    >>> A = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    >>> np.round(nearest_psd(A, floor=0.0), 12).tolist()  # 3 v v^T, v = (1, 1) / sqrt(2)
    [[1.5, 1.5], [1.5, 1.5]]
    """
    if not 0.0 <= floor < 1.0:
        raise ValueError(f"floor must be in [0, 1), got {floor!r}")
    A = np.asarray(information, dtype=np.float64)
    if A.ndim < 2 or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"information must be (..., d, d), got shape {A.shape}")
    S = 0.5 * (A + np.swapaxes(A, -1, -2))
    lam, V = np.linalg.eigh(S)
    top = lam[..., -1:]
    if np.any(top <= 0):
        raise ValueError("information: a matrix has no positive eigenvalue; there is no "
                         "information to keep (drop the edge)")
    lam = np.maximum(lam, floor * top)
    out = (V * lam[..., None, :]) @ np.swapaxes(V, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def isotropic_information(information: np.ndarray, dim: int) -> np.ndarray:
    r"""SE-Sync's isotropic precisions as information matrices ``diag(tau I, 2 kappa I)`` of our
    residual (see the module docstring for the formulas).

    Parameters
    ----------
    information : numpy.ndarray
        ``(..., d, d)`` information matrices, translation first: ``d = 3`` (SE2) or ``6``
        (SE3).
    dim : int
        The pose dimension: 2 or 3.

    Returns
    -------
    numpy.ndarray
        ``(..., d, d)`` diagonal.

    Raises
    ------
    ValueError
        A shape that does not match ``dim``, or a translation or rotation block that is not
        positive definite.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.io.information import isotropic_information
    >>> W = np.diag([4.0, 1.0, 10.0])  # tau = 2 / (1/4 + 1) = 1.6, kappa = 10
    >>> np.round(np.diag(isotropic_information(W, 2)), 12).tolist()
    [1.6, 1.6, 20.0]
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    r = 1 if dim == 2 else 3
    d = dim + r
    A = np.asarray(information, dtype=np.float64)
    if A.shape[-2:] != (d, d):
        raise ValueError(f"information must be (..., {d}, {d}) for dim={dim}, got {A.shape}")
    t, R = A[..., :dim, :dim], A[..., dim:, dim:]
    for name, B in (("translation", t), ("rotation", R)):
        if np.any(np.linalg.eigvalsh(0.5 * (B + np.swapaxes(B, -1, -2)))[..., 0] <= 0):
            raise ValueError(f"information: a {name} block is not positive definite, so it has "
                             "no isotropic precision (use nearest-psd)")
    tau = dim / np.trace(np.linalg.inv(t), axis1=-2, axis2=-1)
    kappa = R[..., 0, 0] if dim == 2 else 3.0 / (2.0 * np.trace(np.linalg.inv(R), axis1=-2,
                                                                 axis2=-1))
    diag = np.concatenate([np.repeat(tau[..., None], dim, axis=-1),
                           np.repeat(2.0 * kappa[..., None], r, axis=-1)], axis=-1)
    out = np.zeros(A.shape)
    idx = np.arange(d)
    out[..., idx, idx] = diag
    return out


def apply_information_policy(information: np.ndarray, policy: str, dim: int, *,
                             name: str = "information", lines: Sequence[int] | None = None
                             ) -> tuple[np.ndarray, np.ndarray]:
    r"""Apply a reader's ``information=`` policy to a file's edge information matrices.

    Parameters
    ----------
    information : numpy.ndarray
        ``(E, d, d)`` symmetric, translation first.
    policy : {"strict", "nearest-psd", "isotropic"}
        See the module docstring.
    dim : int
        The pose dimension: 2 or 3.
    name : str
        The file, for messages.
    lines : sequence of int, optional
        The file line of each edge, for messages (default: the edge's index from 1).

    Returns
    -------
    information : numpy.ndarray
        ``(E, d, d)``: the input itself when nothing changes.
    repaired : numpy.ndarray
        The indices of the edges whose matrix was not positive definite (and was replaced).

    Raises
    ------
    ValueError
        An unknown policy; with ``"strict"`` a matrix that is not positive definite, naming
        ``FILE:LINE``, its smallest eigenvalue and how many edges have one; a matrix that
        the policy cannot repair (``FILE:LINE``).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.io.information import apply_information_policy
    >>> W = np.stack([np.eye(3), np.diag([1.0, -1.0, 1.0])])
    >>> try:
    ...     apply_information_policy(W, "strict", 2, name="g.g2o", lines=[7, 8])
    ... except ValueError as e:
    ...     print(str(e)[:80])
    g.g2o:8: information matrix is not positive definite (smallest eigenvalue -1); 1
    >>> fixed, repaired = apply_information_policy(W, "nearest-psd", 2)
    >>> repaired.tolist(), float(fixed[1, 1, 1])
    ([1], 1e-09)
    """
    if policy not in INFORMATION_POLICIES:
        raise ValueError(f"information must be one of {', '.join(map(repr, INFORMATION_POLICIES))}"
                         f", got {policy!r}")
    info = np.asarray(information, dtype=np.float64)
    at = (np.arange(1, info.shape[0] + 1) if lines is None else np.asarray(lines)).tolist()
    try:
        np.linalg.cholesky(info)
        bad = np.zeros(0, dtype=np.int64)
    except np.linalg.LinAlgError:
        lam = np.linalg.eigvalsh(info)
        bad = np.flatnonzero(lam[:, 0] <= PSD_FLOOR * np.maximum(lam[:, -1], 0.0))
        if bad.size == 0:  # Cholesky fails on a matrix the eigenvalues call definite
            bad = np.array([int(np.argmin(lam[:, 0] / np.abs(lam[:, -1])))])
        if policy == "strict":
            k = int(bad[0])
            raise ValueError(
                f"{name}:{at[k]}: information matrix is not positive definite (smallest "
                f"eigenvalue {lam[k, 0]:.6g}); {bad.size} of {info.shape[0]} edges have such a "
                "matrix: refused by information='strict' (microlie optimize --information "
                "strict, the default); 'nearest-psd' replaces each by the nearest positive "
                "definite one, 'isotropic' by SE-Sync's isotropic precisions") from None
    if policy == "strict" or (policy == "nearest-psd" and bad.size == 0):
        return info, bad
    rows = bad if policy == "nearest-psd" else np.arange(info.shape[0])

    def fix(m: np.ndarray) -> np.ndarray:
        return nearest_psd(m) if policy == "nearest-psd" else isotropic_information(m, dim)

    out = info.copy()
    try:
        out[rows] = fix(info[rows])
    except ValueError:
        for k in rows.tolist():  # the first row it refuses, for the message
            try:
                fix(info[k])
            except ValueError as e:
                raise ValueError(f"{name}:{at[k]}: {e} ({policy})") from None
        raise
    return out, bad
