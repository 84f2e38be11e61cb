"""Hand-eye calibration on SE(3): ``A_i X = X B_i`` and ``A_i X = Y B_i``.

``A_i``, ``B_i`` are ``SE3`` batches of paired motions (for a camera on a robot hand:
``A_i`` the hand motions, ``B_i`` the camera motions, ``X`` the camera pose in the hand frame).
Each solver starts from a closed form and refines by Gauss-Newton on the residuals
``r_i = Log((A_i X)^-1 X B_i)`` (``Log((A_i X)^-1 Y B_i)``), with the rotation and translation
blocks weighted by their residual spread; the result is a :class:`~microlie.Gaussian` (right
perturbation) whose covariance is the inverse Gauss-Newton information scaled by that spread.

* :func:`hand_eye` (``AX = XB``): Park and Martin's closed form (IEEE T-RA 1994): ``R_X`` from
  the rotation vectors, ``alpha_i = R_X beta_i``, by ``R_X = (M^T M)^-1/2 M^T`` with
  ``M = sum beta_i alpha_i^T``; ``t_X`` by least squares on ``(R_A - I) t_X = R_X t_B - t_A``.
* :func:`hand_eye_robot_world` (``AX = YB``): the rotations from the null space of the stacked
  Kronecker equations ``R_A R_X = R_Y R_B`` (projected onto SO(3)), the translations by linear
  least squares; a ``Gaussian`` on ``Product(SE3, SE3)`` (``(X, Y)``, tangent ``(x, y)``).
* :func:`hand_eye_from_poses`: OpenCV's ``calibrateHandEye`` problem (gripper-to-base and
  target-to-camera poses; solution camera-to-gripper) as maximum likelihood over the poses.
* :func:`motions_from_poses`: the ``(A, B)`` pairs of that convention.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from .groups import SE3, SO3, Product, ProductGroup
from .uncertainty import Gaussian

__all__ = ["hand_eye", "hand_eye_from_poses", "hand_eye_robot_world", "motions_from_poses"]


def _check_pairs(A: Any, B: Any, what: str) -> tuple[SE3, SE3]:
    if not (isinstance(A, SE3) and isinstance(B, SE3)):
        raise TypeError(f"{what}: A and B must be SE3 batches")
    if A.batch_shape != B.batch_shape or len(A.batch_shape) != 1:
        raise ValueError(f"{what}: A and B must be 1-D batches of the same length, got "
                         f"{A.batch_shape} and {B.batch_shape}")
    return A, B


def motions_from_poses(gripper2base: SE3, target2cam: SE3, pairs: str = "all"
                       ) -> tuple[SE3, SE3]:
    """Relative motions ``A_ij = G_j^-1 G_i``, ``B_ij = C_j C_i^-1`` of pose pairs, as OpenCV's
    ``calibrateHandEye`` inputs give them; ``A X = X B`` then holds for ``X`` =
    camera-to-gripper.

    Parameters
    ----------
    gripper2base : SE3
        ``(N,)`` gripper-to-base poses ``G_i``.
    target2cam : SE3
        ``(N,)`` target-to-camera poses ``C_i``.
    pairs : {"all", "consecutive"}
        Every pair ``i < j`` (as OpenCV's methods use them) or consecutive ones.

    Returns
    -------
    A, B : SE3
        The motion batches.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.calibration import motions_from_poses
    >>> X, W = SE3.random(rng=1), SE3.random(rng=2)
    >>> G = SE3.random(4, rng=3)
    >>> C = (G @ X).inverse() @ W
    >>> A, B = motions_from_poses(G, C)
    >>> A.batch_shape, bool(np.allclose((A @ X).matrix(), (X @ B).matrix()))
    ((6,), True)
    """
    G, C = _check_pairs(gripper2base, target2cam, "motions_from_poses")
    if len(G) < 3:
        raise ValueError("motions_from_poses: at least 3 poses are needed")
    if pairs == "all":
        i, j = np.triu_indices(len(G), 1)
    elif pairs == "consecutive":
        i = np.arange(len(G) - 1)
        j = i + 1
    else:
        raise ValueError(f"pairs must be 'all' or 'consecutive', got {pairs!r}")
    A = G[j].inverse() @ G[i]
    B = C[j] @ C[i].inverse()
    return A, B  # type: ignore[return-value]


def _closed_form_axxb(A: SE3, B: SE3) -> SE3:
    a = np.asarray(A.rotation().log())
    b = np.asarray(B.rotation().log())
    M = np.einsum("ni,nj->ij", b, a)
    w, V = np.linalg.eigh(M.T @ M)
    if np.min(w) <= 1e-12 * max(np.max(w), 1e-300):
        raise ValueError("hand_eye: the motions are degenerate (need at least two rotations "
                         "about non-parallel axes)")
    Rx = SO3.from_matrix((V @ np.diag(w**-0.5) @ V.T) @ M.T, normalize=True)  # nearest rotation
    RA = np.asarray(A.rotation().matrix())
    tA, tB = np.asarray(A.translation()), np.asarray(B.translation())
    lhs = (RA - np.eye(3)).reshape(-1, 3)
    rhs = (tB @ np.asarray(Rx.matrix()).T - tA).reshape(-1)
    tx = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return SE3.from_rotation_translation(Rx, tx)  # type: ignore[return-value]


def _residual(A: SE3, B: SE3, X: SE3, Y: SE3 | None, jac: bool) -> Any:
    """``r_i = Log((A_i X)^-1 Y B_i)`` (``Y = X`` if None) and its Jacobians."""
    AX, _, J_AX = A.compose(X, jac=True)
    YY = X if Y is None else Y
    YB, J_YB, _ = YY.compose(B, jac=True)
    D, J1, J2 = AX.between(YB, jac=True)
    r, Jl = D.log(jac=True)
    if not jac:
        return np.asarray(r)
    Jx = Jl @ J1 @ J_AX
    Jy = Jl @ J2 @ J_YB
    if Y is None:
        return np.asarray(r), np.asarray(Jx + Jy)
    return np.asarray(r), np.concatenate([Jx, Jy], -1)


def _refine(A: SE3, B: SE3, X: SE3, Y: SE3 | None, iterations: int) -> tuple:
    n = len(A)
    k = 6 if Y is None else 12
    scale = None
    for _ in range(iterations):
        r, J = _residual(A, B, X, Y, jac=True)
        if scale is None:  # block weights from the spread of the starting residuals
            s_t = np.sqrt(np.mean(r[:, :3] ** 2)) + 1e-15
            s_r = np.sqrt(np.mean(r[:, 3:] ** 2)) + 1e-15
            scale = np.r_[np.full(3, 1 / s_t), np.full(3, 1 / s_r)]
        Jw = (J * scale[:, None]).reshape(-1, k)
        rw = (r * scale).reshape(-1)
        dx = -np.linalg.lstsq(Jw, rw, rcond=None)[0]
        X = X.plus(dx[:6])
        if Y is not None:
            Y = Y.plus(dx[6:])
        if np.linalg.norm(dx) < 1e-13:
            break
    r, J = _residual(A, B, X, Y, jac=True)
    assert scale is not None
    Jw = (J * scale[:, None]).reshape(-1, k)
    rw = (r * scale).reshape(-1)
    dof = max(6 * n - k, 1)
    sigma2 = float(rw @ rw) / dof
    info = Jw.T @ Jw
    cov = np.linalg.inv(info) * max(sigma2, 1e-300)
    return X, Y, 0.5 * (cov + cov.T), r


def hand_eye(A: SE3, B: SE3, iterations: int = 20) -> Gaussian:
    """Solve ``A_i X = X B_i`` for ``X`` (see the module docstring).

    Parameters
    ----------
    A, B : SE3
        ``(N,)`` paired motions (for example from :func:`motions_from_poses`).
    iterations : int
        Gauss-Newton iterations after the closed-form start.

    Returns
    -------
    Gaussian
        Mean ``X``, 6x6 right-perturbation covariance, tangent ``(rho, phi)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.calibration import hand_eye
    >>> X = SE3.exp(np.array([0.1, -0.2, 0.3, 0.4, 0.5, -0.6]))
    >>> B = SE3.random(10, rng=0)
    >>> A = X @ B @ X.inverse()
    >>> est = hand_eye(A, B)
    >>> bool(np.abs(est.mean.log() - X.log()).max() < 1e-10)
    True
    """
    A, B = _check_pairs(A, B, "hand_eye")
    if len(A) < 2:
        raise ValueError("hand_eye: at least 2 motion pairs are needed")
    X0 = _closed_form_axxb(A, B)
    X, _, cov, _ = _refine(A, B, X0, None, iterations)
    return Gaussian(X, cov, frame="right")


def _closed_form_axyb(A: SE3, B: SE3) -> tuple[SE3, SE3]:
    RA = np.asarray(A.rotation().matrix())
    RB = np.asarray(B.rotation().matrix())
    n = len(A)
    # vec (column-major) of R_A R_X - R_Y R_B = 0: (I kron R_A) x - (R_B^T kron I) y = 0
    K = np.zeros((9 * n, 18))
    eye = np.eye(3)
    for i in range(n):
        K[9 * i:9 * i + 9, :9] = np.kron(eye, RA[i])
        K[9 * i:9 * i + 9, 9:] = -np.kron(RB[i].T, eye)
    _, s, Vt = np.linalg.svd(K)
    if s[-2] < 1e-9 * s[0]:
        raise ValueError("hand_eye_robot_world: the motions are degenerate")
    v = Vt[-1]
    Rx = v[:9].reshape(3, 3, order="F")
    Ry = v[9:].reshape(3, 3, order="F")
    c = np.cbrt(np.linalg.det(Rx))
    RX, RY = (SO3.from_matrix(R / c, normalize=True) for R in (Rx, Ry))  # nearest rotations
    tA, tB = np.asarray(A.translation()), np.asarray(B.translation())
    lhs = np.concatenate([RA, -np.broadcast_to(eye, (n, 3, 3))], -1).reshape(-1, 6)
    rhs = (tB @ np.asarray(RY.matrix()).T - tA).reshape(-1)
    t = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    X = SE3.from_rotation_translation(RX, t[:3])
    Y = SE3.from_rotation_translation(RY, t[3:])
    return X, Y  # type: ignore[return-value]


def hand_eye_robot_world(A: SE3, B: SE3, iterations: int = 20, b_noise: str = "right"
                         ) -> Gaussian:
    """Solve ``A_i X = Y B_i`` for ``X`` and ``Y`` (robot-world/hand-eye: with ``A_i`` the
    gripper-to-base poses and ``B_i`` the camera-to-target poses, ``X`` is camera-to-gripper
    and ``Y`` target-to-base).

    The weights assume independent, equal noise on every ``A_i`` (right perturbation) and
    ``B_i``.

    Parameters
    ----------
    A, B : SE3
        ``(N,)`` paired poses.
    iterations : int
        Gauss-Newton iterations after the closed-form start.
    b_noise : {"right", "left"}
        The perturbation side of the noise on ``B_i``: ``"left"`` when the ``B_i`` are
        inverses of right-perturbed poses, as with ``B_i = C_i^-1`` for target-to-camera
        poses ``C_i``.

    Returns
    -------
    Gaussian
        On ``Product(SE3, SE3)`` with mean ``(X, Y)`` (tangent ``(x, y)``, right
        perturbation).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.calibration import hand_eye_robot_world
    >>> X, Y = SE3.random(rng=1), SE3.random(rng=2)
    >>> B = SE3.random(8, rng=3)
    >>> A = Y @ B @ X.inverse()
    >>> est = hand_eye_robot_world(A, B)
    >>> bool(np.abs(est.mean.part(1).log() - Y.log()).max() < 1e-9)
    True
    """
    A, B = _check_pairs(A, B, "hand_eye_robot_world")
    if len(A) < 3:
        raise ValueError("hand_eye_robot_world: at least 3 pairs are needed")
    if b_noise not in ("right", "left"):
        raise ValueError(f"b_noise must be 'right' or 'left', got {b_noise!r}")
    X0, Y0 = _closed_form_axyb(A, B)
    Bmap = None if b_noise == "right" else np.asarray(B.inverse().adjoint())
    X, Y, cov = _refine_ml(A, B, X0, Y0, Bmap, iterations)
    return Gaussian(Product(SE3, SE3).from_parts(X, Y), cov, frame="right")


def _refine_ml(A: SE3, B: SE3, X: SE3, Y: SE3, Bmap: np.ndarray | None,
               iterations: int) -> tuple[SE3, SE3, np.ndarray]:
    """Gauss-Newton on ``r_i = Log((A_i X)^-1 Y B_i)`` weighted by the residual covariance of
    independent right-perturbation noise ``N(0, P)`` on every ``A_i`` and ``B_i``,
    ``P = diag(s_t^2 I, s_r^2 I)``: ``Sigma_i = Ad_X^-1 P Ad_X^-T + T_i P T_i^T`` (``T_i`` maps
    the noise of ``B_i`` into the residual: ``I``, or ``Bmap``). ``s_t``, ``s_r`` are fitted
    to the residuals (method of moments) in the first iterations."""
    n = len(A)
    blocks = [np.diag([1.0, 1, 1, 0, 0, 0]), np.diag([0.0, 0, 0, 1, 1, 1])]
    s = np.ones(2)
    L = None
    for it in range(iterations + 1):
        r, J = _residual(A, B, X, Y, jac=True)
        AdX = np.asarray(X.inverse().adjoint())
        Ms = []
        for D in blocks:
            M = np.broadcast_to(AdX @ D @ AdX.T, (n, 6, 6))
            M = M + (D if Bmap is None else Bmap @ D @ np.swapaxes(Bmap, -1, -2))
            Ms.append(M)
        if it < 5:  # moments of the residuals, corrected for the 12 fitted parameters
            O = np.einsum("ni,nj->nij", r, r).reshape(-1)
            a = np.stack([M.reshape(-1) for M in Ms], -1)
            s = np.maximum(np.linalg.lstsq(a, O, rcond=None)[0], 1e-30) * (6 * n / (6 * n - 12))
        S = s[0] * Ms[0] + s[1] * Ms[1]
        L = np.swapaxes(np.linalg.cholesky(np.linalg.inv(S)), -1, -2)  # L^T L = S^-1
        Jw = (L @ J).reshape(-1, 12)
        if it == iterations:
            break
        rw = (L @ r[..., None])[..., 0].reshape(-1)
        dx = -np.linalg.lstsq(Jw, rw, rcond=None)[0]
        X, Y = X.plus(dx[:6]), Y.plus(dx[6:])
        if np.linalg.norm(dx) < 1e-14:
            r, J = _residual(A, B, X, Y, jac=True)
            Jw = (L @ J).reshape(-1, 12)
            break
    cov = np.linalg.inv(Jw.T @ Jw)
    return X, Y, 0.5 * (cov + cov.T)


def hand_eye_from_poses(gripper2base: SE3, target2cam: SE3, iterations: int = 20) -> Gaussian:
    """Camera-to-gripper ``X`` from the poses OpenCV's ``calibrateHandEye`` takes.

    With gripper-to-base ``G_i`` and target-to-camera ``C_i``, ``G_i X C_i = W`` (the fixed
    target-to-base) for every pose. Solved as ``A_i X = W B_i`` with ``A_i = G_i``,
    ``B_i = C_i^-1`` by :func:`hand_eye_robot_world` (``b_noise="left"``): maximum
    likelihood for independent, equal right-perturbation noise on every ``G_i`` and ``C_i``
    (translation and rotation levels fitted to the residuals).

    Parameters
    ----------
    gripper2base : SE3
        ``(N,)`` gripper-to-base poses ``G_i``.
    target2cam : SE3
        ``(N,)`` target-to-camera poses ``C_i``.
    iterations : int
        Gauss-Newton iterations after the closed-form start.

    Returns
    -------
    Gaussian
        Of ``X`` (the marginal of the joint ``(X, W)`` estimate), right perturbation.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.calibration import hand_eye_from_poses
    >>> X, W = SE3.random(rng=1), SE3.random(rng=2)
    >>> G = SE3.random(10, rng=3)
    >>> C = (G @ X).inverse() @ W
    >>> bool(np.abs(hand_eye_from_poses(G, C).mean.log() - X.log()).max() < 1e-9)
    True
    """
    G, C = _check_pairs(gripper2base, target2cam, "hand_eye_from_poses")
    if len(G) < 3:
        raise ValueError("hand_eye_from_poses: at least 3 poses are needed")
    joint = hand_eye_robot_world(G, C.inverse(), iterations, b_noise="left")
    mean = cast(ProductGroup, joint.mean)
    return Gaussian(mean.part(0), joint.cov[..., :6, :6], frame="right")
