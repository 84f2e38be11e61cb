"""Check the rows of docs/coming_from.md: run each row's peer call and its microlie call on the
same random inputs and compare the numbers (or, for the evo rows, run the command line with the
spellings the table shows).

Run in the benchmark venv (it has gtsam, jaxlie, pypose, scipy)::

    PYTHONPATH=$PWD/src /work/bench-venv/bin/python benchmarks/check_coming_from.py

Prints one line per row (PASS / FAIL with the largest difference) and exits 1 if any row fails.
manif and Sophus are not installed there: their rows are checked on the microlie side only
(the call exists and satisfies the identity the row states).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

os.environ.setdefault("JAX_ENABLE_X64", "1")

from microlie import SE2, SE3, SO3, Sim3  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "trajectory" / "evo"
TOL = 1e-9
RESULTS: list[tuple[str, str, bool, str]] = []


def row(table: str, text: str) -> Callable[[Callable[[], float | bool]], None]:
    """Register one table row; the function returns the largest difference or a boolean."""

    def run(fn: Callable[[], float | bool]) -> None:
        try:
            out = fn()
        except Exception as exc:  # a row that cannot run is a failing row
            RESULTS.append((table, text, False, f"{type(exc).__name__}: {exc}"))
            return
        if isinstance(out, bool | np.bool_):
            RESULTS.append((table, text, bool(out), ""))
        else:
            RESULTS.append((table, text, out < TOL, f"max diff {out:.1e}"))
    return run


def diff(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))))


rng = np.random.default_rng(7)
tau, tau2, d = rng.normal(size=6), rng.normal(size=6), 0.3 * rng.normal(size=6)
phi, p = rng.normal(size=3), rng.normal(size=3)
T, U = SE3.exp(tau), SE3.exp(tau2)
P = np.roll(np.eye(6), 3, axis=0)  # the permutation of the GTSAM table


# ---------------------------------------------------------------- manif (microlie side only)
@row("manif", "Y.minus(X, jac=True) returns (tau, J_o_y, J_o_x)")
def _():
    tau_, jy, jx = U.minus(T, jac=True)
    e = 1e-6
    fd_y = np.stack([(U.plus(e * np.eye(6)[i]).minus(T) - U.plus(-e * np.eye(6)[i]).minus(T))
                     / (2 * e) for i in range(6)], axis=-1)
    fd_x = np.stack([(U.minus(T.plus(e * np.eye(6)[i])) - U.minus(T.plus(-e * np.eye(6)[i])))
                     / (2 * e) for i in range(6)], axis=-1)
    return max(diff(tau_, U.minus(T)), diff(jy, fd_y), diff(jx, fd_x)) * 1e-3  # FD ~1e-9


@row("manif", "X.coeffs() (x, y, z, qx, qy, qz, qw) = X.params")
def _():
    q = T.rotation().as_quat()
    return diff(T.params, np.r_[T.translation(), q])


@row("manif", "tau.hat(), tau.smallAdj() = SE3.hat(tau), SE3.ad(tau)")
def _():
    from scipy.linalg import expm
    return max(diff(expm(SE3.hat(tau)), T.matrix()),
               diff(SE3.ad(tau) @ tau2, -SE3.ad(tau2) @ tau))


# ---------------------------------------------------------------- Sophus (microlie side only)
@row("Sophus", "T.matrix(), T.translation(), T.rotation()")
def _():
    M = T.matrix()
    return max(diff(M[:3, 3], T.translation()), diff(M[:3, :3], T.rotation().matrix()))


@row("Sophus", "Sim3.exp(zeta) matrix [s R, t; 0 1], s = exp(sigma)")
def _():
    z = np.r_[tau, 0.4]
    S = Sim3.exp(z).matrix()
    return max(diff(np.linalg.det(S[:3, :3]) ** (1 / 3), np.exp(0.4)), diff(S[3], [0, 0, 0, 1]))


# ---------------------------------------------------------------- jaxlie
def _jaxlie():
    import jaxlie
    return jaxlie, jaxlie.SE3.exp(tau), jaxlie.SE3.exp(tau2)


@row("jaxlie", "jaxlie.SE3.exp(tau) = SE3.exp(tau)")
def _():
    _, Tj, _ = _jaxlie()
    return diff(Tj.as_matrix(), T.matrix())


@row("jaxlie", "T.log() = T.log()")
def _():
    _, Tj, _ = _jaxlie()
    return diff(Tj.log(), T.log())


@row("jaxlie", "T @ U, T.multiply(U) = T @ U")
def _():
    _, Tj, Uj = _jaxlie()
    return max(diff((Tj @ Uj).as_matrix(), (T @ U).matrix()),
               diff(Tj.multiply(Uj).as_matrix(), (T @ U).matrix()))


@row("jaxlie", "T @ p, T.apply(p) = T.act(p)")
def _():
    _, Tj, _ = _jaxlie()
    return max(diff(Tj @ p, T.act(p)), diff(Tj.apply(p), T.act(p)))


@row("jaxlie", "T.inverse(), T.adjoint()")
def _():
    _, Tj, _ = _jaxlie()
    return max(diff(Tj.inverse().as_matrix(), T.inverse().matrix()),
               diff(Tj.adjoint(), T.adjoint()))


@row("jaxlie", "jaxlie.manifold.rplus(T, d) = T.plus(d)")
def _():
    jaxlie, Tj, _ = _jaxlie()
    return diff(jaxlie.manifold.rplus(Tj, d).as_matrix(), T.plus(d).matrix())


@row("jaxlie", "jaxlie.manifold.rminus(T, U) = U.minus(T)")
def _():
    jaxlie, Tj, Uj = _jaxlie()
    return diff(jaxlie.manifold.rminus(Tj, Uj), U.minus(T))


@row("jaxlie", "T.jlog() = SE3.jr_inv(T.log())")
def _():
    _, Tj, _ = _jaxlie()
    return diff(Tj.jlog(), SE3.jr_inv(T.log()))


@row("jaxlie", "jaxlie.SO3(wxyz) = SO3.from_quat(wxyz, scalar_first=True)")
def _():
    import jaxlie
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return diff(jaxlie.SO3(q).as_matrix(), SO3.from_quat(q, scalar_first=True).matrix())


@row("jaxlie", "T.wxyz_xyz vs T.params (x, y, z, qx, qy, qz, qw)")
def _():
    _, Tj, _ = _jaxlie()
    w = np.asarray(Tj.wxyz_xyz)
    return diff(np.r_[w[4:], w[1:4], w[0]], T.params)


@row("jaxlie", "jax.jit, jax.vmap work unchanged on microlie elements (pytrees)")
def _():
    import jax
    import jax.numpy as jnp
    taus = jnp.asarray(rng.normal(size=(4, 6)))
    jit_log = jax.jit(lambda X: X.log())(SE3.exp(taus))
    vmap_log = jax.vmap(lambda t: SE3.exp(t).log())(taus)
    return max(diff(jit_log, SE3.exp(np.asarray(taus)).log()),
               diff(vmap_log, SE3.exp(np.asarray(taus)).log()))


# ---------------------------------------------------------------- PyPose
def _pp():
    import pypose as pp
    import torch
    return pp, torch


@row("PyPose", "pp.se3(tau).Exp() = SE3.exp(tau); X.Log() = X.log()")
def _():
    pp, torch = _pp()
    X = pp.se3(torch.tensor(tau)).Exp()
    return max(diff(X.matrix().numpy(), T.matrix()), diff(X.Log().numpy(), T.log()),
               diff(X.numpy(), T.params))


@row("PyPose", "X * Y, X @ Y, X.Inv() = X @ Y, X.inverse()")
def _():
    pp, torch = _pp()
    X, Y = pp.se3(torch.tensor(tau)).Exp(), pp.se3(torch.tensor(tau2)).Exp()
    return max(diff((X * Y).matrix().numpy(), (T @ U).matrix()),
               diff((X @ Y).matrix().numpy(), (T @ U).matrix()),
               diff(X.Inv().matrix().numpy(), T.inverse().matrix()))


@row("PyPose", "X.Act(p), X @ p = X.act(p)")
def _():
    pp, torch = _pp()
    X = pp.se3(torch.tensor(tau)).Exp()
    return max(diff(X.Act(torch.tensor(p)).numpy(), T.act(p)),
               diff((X @ torch.tensor(p)).numpy(), T.act(p)))


@row("PyPose", "X.Retr(a) (left) = X.lplus(a)")
def _():
    pp, torch = _pp()
    X = pp.se3(torch.tensor(tau)).Exp()
    return diff(X.Retr(pp.se3(torch.tensor(d))).matrix().numpy(), T.lplus(d).matrix())


@row("PyPose", "X.Adj(a) = X.adjoint() @ a")
def _():
    pp, torch = _pp()
    X = pp.se3(torch.tensor(tau)).Exp()
    return diff(X.Adj(pp.se3(torch.tensor(d))).numpy(), T.adjoint() @ d)


@row("PyPose", "pp.so3(phi).Jr() = SO3.jr(phi)")
def _():
    pp, torch = _pp()
    return diff(pp.so3(torch.tensor(phi)).Jr().numpy(), SO3.jr(phi))


@row("PyPose", "SE3 Jr: not available in PyPose")
def _():
    pp, torch = _pp()
    try:
        pp.se3(torch.tensor(tau)).Jr()
    except NotImplementedError:
        return True
    return False


# ---------------------------------------------------------------- GTSAM
def _g(v):
    import gtsam
    return gtsam.Pose3.Expmap(np.r_[v[3:], v[:3]])


@row("GTSAM", "gtsam.Pose3.Expmap(np.r_[w, v]) = SE3.exp(np.r_[v, w])")
def _():
    return diff(_g(tau).matrix(), T.matrix())


@row("GTSAM", "gtsam.Pose3.Logmap(T) ([w, v]) = T.log() ([v, w])")
def _():
    import gtsam
    return diff(gtsam.Pose3.Logmap(_g(tau)), P @ T.log())


@row("GTSAM", "T.compose(U), T.between(U), T.inverse()")
def _():
    g, h = _g(tau), _g(tau2)
    return max(diff(g.compose(h).matrix(), (T @ U).matrix()),
               diff(g.between(h).matrix(), T.between(U).matrix()),
               diff(g.inverse().matrix(), T.inverse().matrix()))


@row("GTSAM", "T.transformFrom(p) = T.act(p)")
def _():
    return diff(_g(tau).transformFrom(p), T.act(p))


@row("GTSAM", "T.AdjointMap() = P @ T.adjoint() @ P.T")
def _():
    return diff(_g(tau).AdjointMap(), P @ T.adjoint() @ P.T)


@row("GTSAM", "covariance: S_microlie = P.T @ S_gtsam @ P (push-forward of a right perturbation)")
def _():
    # GTSAM's Pose3 retract is X Exp(xi) with xi = [w, v]; map a microlie tangent sample
    # through GTSAM's convention and back: the permutation is the whole change.
    xi_m = 0.1 * rng.normal(size=(200, 6))
    g = _g(tau)
    back = np.stack([SE3.from_matrix(g.retract(P @ x).matrix()).minus(T) for x in xi_m])
    S_m = np.cov(xi_m.T)
    S_g = P @ S_m @ P.T  # GTSAM's covariance of the same perturbations
    return max(diff(back, xi_m), diff(P.T @ S_g @ P, S_m))


@row("GTSAM", "gtsam.Rot3.Quaternion(w, x, y, z) = SO3.from_quat([x, y, z, w])")
def _():
    import gtsam
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    x, y, z, w = q
    return diff(gtsam.Rot3.Quaternion(w, x, y, z).matrix(), SO3.from_quat([x, y, z, w]).matrix())


@row("GTSAM", "gtsam.Rot3.Expmap(w), R.rotate(p) = SO3.exp(w), R.act(p)")
def _():
    import gtsam
    R = gtsam.Rot3.Expmap(phi)
    return max(diff(R.matrix(), SO3.exp(phi).matrix()), diff(R.rotate(p), SO3.exp(phi).act(p)))


@row("GTSAM", "gtsam.Pose2(x, y, theta) = SE2.from_xy_theta(x, y, theta)")
def _():
    import gtsam
    return diff(gtsam.Pose2(0.3, -1.2, 2.5).matrix(), SE2.from_xy_theta(0.3, -1.2, 2.5).matrix())


@row("GTSAM", "gtsam.Similarity3(R, t, s) matrix [R t; 0 1/s]; Sim3 matrix [s R, t; 0 1]")
def _():
    import gtsam
    R, t, s = SO3.exp(phi), p, 1.7
    G = gtsam.Similarity3(gtsam.Rot3(R.matrix()), t, s).matrix()
    S = Sim3(np.r_[t, R.as_quat(), s]).matrix()  # params (t, q, s)
    return max(diff(G[:3, :3], R.matrix()), diff(G[3, 3], 1 / s),
               diff(S[:3, :3], s * R.matrix()), diff(S[:3, 3], t), diff(G[:3, 3], t))


# ---------------------------------------------------------------- SciPy Rotation
def _r():
    from scipy.spatial.transform import Rotation
    return Rotation


@row("SciPy", "from_rotvec/as_rotvec = SO3.exp/from_rotvec, log/as_rotvec")
def _():
    Rotation = _r()
    r = Rotation.from_rotvec(phi)
    return max(diff(r.as_matrix(), SO3.exp(phi).matrix()),
               diff(r.as_matrix(), SO3.from_rotvec(phi).matrix()),
               diff(r.as_rotvec(), SO3.exp(phi).log()),
               diff(r.as_rotvec(), SO3.exp(phi).as_rotvec()))


@row("SciPy", "from_quat (xyzw), as_quat; scalar_first=True")
def _():
    Rotation = _r()
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    q *= np.sign(q[3])
    return max(diff(Rotation.from_quat(q).as_matrix(), SO3.from_quat(q).matrix()),
               diff(Rotation.from_quat(q).as_quat(canonical=True),
                    SO3.from_quat(q).as_quat() * np.sign(SO3.from_quat(q).as_quat()[3])),
               diff(Rotation.from_quat(q, scalar_first=True).as_matrix(),
                    SO3.from_quat(q, scalar_first=True).matrix()))


@row("SciPy", "from_matrix/as_matrix = SO3.from_matrix, matrix()")
def _():
    Rotation = _r()
    M = SO3.exp(phi).matrix()
    return diff(Rotation.from_matrix(M).as_matrix(), SO3.from_matrix(M).matrix())


@row("SciPy", "from_euler('xyz', a), as_euler('xyz') = SO3.from_euler, as_euler")
def _():
    Rotation = _r()
    a = np.array([0.3, -0.7, 1.1])
    out = 0.0
    for seq in ("xyz", "XYZ", "zyx", "ZYX", "zxz"):
        out = max(out, diff(Rotation.from_euler(seq, a).as_matrix(),
                            SO3.from_euler(seq, a).matrix()),
                  diff(Rotation.from_euler(seq, a).as_euler(seq),
                       SO3.from_euler(seq, a).as_euler(seq)))
    return out


@row("SciPy", "r1 * r2, r.inv(), r.apply(v) = R1 @ R2, R.inverse(), R.act(v)")
def _():
    Rotation = _r()
    r1, r2 = Rotation.from_rotvec(phi), Rotation.from_rotvec(p)
    R1, R2 = SO3.exp(phi), SO3.exp(p)
    return max(diff((r1 * r2).as_matrix(), (R1 @ R2).matrix()),
               diff(r1.inv().as_matrix(), R1.inverse().matrix()), diff(r1.apply(p), R1.act(p)))


@row("SciPy", "Rotation.random(n) = SO3.random(n) (a batch of n)")
def _():
    return SO3.random(5).params.shape == (5, 4)


@row("SciPy", "r.magnitude() = np.linalg.norm(R.log(), axis=-1)")
def _():
    Rotation = _r()
    rv = rng.normal(size=(5, 3))
    return diff(Rotation.from_rotvec(rv).magnitude(), np.linalg.norm(SO3.exp(rv).log(), axis=-1))


@row("SciPy", "SO3.from_matrix(noisy) raises unless normalize=True (SciPy projects silently)")
def _():
    Rotation = _r()
    M = SO3.exp(phi).matrix() + 1e-3 * rng.normal(size=(3, 3))
    Rotation.from_matrix(M)
    try:
        SO3.from_matrix(M)
    except ValueError:
        return diff(SO3.from_matrix(M, normalize=True).matrix(),
                    Rotation.from_matrix(M).as_matrix()) < 1e-9
    return False


# ---------------------------------------------------------------- evo (the command line)
def _cli(*args: str, cwd: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "microlie.cli", *args], cwd=cwd,
                          capture_output=True, text=True, env=env, timeout=600)


TUM_GT = str(DATA / "freiburg1_xyz-groundtruth.txt")
TUM_EST = str(DATA / "freiburg1_xyz-rgbdslam.txt")
KITTI_GT, KITTI_EST = str(DATA / "KITTI_00_gt.txt"), str(DATA / "KITTI_00_ORB.txt")
EVO_ROWS = [
    ["ape", "tum", TUM_GT, TUM_EST, "-va"],
    ["ape", "kitti", KITTI_GT, KITTI_EST, "-as", "-r", "trans_part"],
    ["rpe", "tum", TUM_GT, TUM_EST, "-d", "1", "-u", "m", "-r", "angle_deg"],
    ["ape", TUM_GT, TUM_EST, "--plot", "ape.png", "--plot-mode", "xz"],
    ["ape", TUM_GT, TUM_EST, "--save-results", "a.json"],
    ["ape", TUM_GT, TUM_EST, "-a", "--save-results", "b.json"],
    ["res", "a.json", "b.json"],
    ["rpe", "tum", TUM_GT, TUM_EST, "-d", "1", "-u", "m", "-r", "point_distance_error_ratio"],
    ["res", str(DATA / "res_files" / "orb_ape.zip"), str(DATA / "res_files" / "sptam_ape.zip"),
     "--save_plot", "res.png", "--plot-kind", "all"],
    ["traj", TUM_EST, "--ref", TUM_GT, "--plot", "traj.png"],
    ["kitti", KITTI_GT, KITTI_EST],
]
with tempfile.TemporaryDirectory() as tmp:
    for args in EVO_ROWS:
        shown = " ".join(Path(a).name if "/" in a else a for a in args)

        @row("evo", f"microlie {shown}")
        def _(args=args, tmp=tmp):
            r = _cli(*args, cwd=tmp)
            if r.returncode != 0:
                raise RuntimeError(r.stderr.strip().splitlines()[-1] if r.stderr else r.returncode)
            return True


def main() -> int:
    width = max(len(t) for _, t, _, _ in RESULTS)
    for table, text, ok, note in RESULTS:
        print(f"{'PASS' if ok else 'FAIL'}  {table:7s} {text:{width}s}  {note}")
    failed = sum(not ok for *_, ok, _ in RESULTS)
    print(f"{len(RESULTS) - failed}/{len(RESULTS)} rows agree")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
