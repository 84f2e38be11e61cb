"""A tour of microlie's groups: run ``python examples/quickstart.py``.

Prints what it computes: a robot pose chain on SE(3), a round trip through Exp/Log at the hard
angles, analytic Jacobians next to finite differences, and a Sim(3) alignment-style transform.
"""

from __future__ import annotations

import numpy as np

from microlie import SE2, SE3, SO3, Sim3


def main() -> None:
    rng = np.random.default_rng(0)

    print("== SE(3) odometry chain (tangent order: rho then phi, right plus) ==")
    step = np.array([1.0, 0.0, 0.0, 0.0, 0.0, np.pi / 8])  # 1 m forward, turn 22.5 deg left
    T = SE3.identity()
    for _ in range(16):
        T = T.plus(step)
    print("after 16 steps of a 22.5 deg turn the robot is back at the start:")
    print("  translation", np.round(T.translation(), 12), " rotation angle",
          round(float(np.linalg.norm(T.rotation().log())), 12))

    print("\n== Log(Exp(phi)) at the hard angles (SO(3), float64) ==")
    for theta in (0.0, 1e-12, 1e-8, 1.0, np.pi - 1e-9, np.pi):
        phi = theta * np.array([0.6, 0.0, 0.8])
        err = np.abs(SO3.exp(phi).log() - phi).max()
        print(f"  theta = {theta:<22.16g} |Log(Exp(phi)) - phi| = {err:.1e}")

    print("\n== Analytic right Jacobian of X.act(p) vs central finite differences ==")
    X = SE3.random(rng=rng)
    p = np.array([0.5, -1.0, 2.0])
    _, J_X, J_p = X.act(p, jac=True)
    h = 1e-6
    fd = np.stack([(X.plus(h * e).act(p) - X.plus(-h * e).act(p)) / (2 * h) for e in np.eye(6)],
                  axis=-1)
    print("  max |J_X - finite differences| =", f"{np.abs(J_X - fd).max():.1e}")
    print("  J_p equals R:", np.allclose(J_p, X.rotation().matrix()))

    print("\n== Batches broadcast: (1000,) poses times one pose ==")
    Xs = SE3.random(1000, rng=rng)
    Zs, J1, J2 = Xs.compose(X, jac=True)
    print("  result batch", Zs.batch_shape, " Jacobians", J1.shape, J2.shape)

    print("\n== Sim(3): scale, rotation, translation ==")
    S = Sim3.from_rotation_translation_scale(SO3.from_rpy(0.1, 0.2, 0.3), [1.0, 2.0, 3.0], 2.5)
    zeta = S.log()
    print("  Log(S) = (rho, phi, sigma) =", np.round(zeta, 6))
    print("  exp(sigma) =", round(float(np.exp(zeta[6])), 12), " scale =", float(S.scale()))

    print("\n== SE(2): planar pose, heading accessor ==")
    P = SE2.from_xy_theta(1.0, 2.0, np.pi / 2)
    print("  P.act([1, 0]) =", np.round(P.act(np.array([1.0, 0.0])), 12),
          " heading =", float(P.angle()))


if __name__ == "__main__":
    main()
