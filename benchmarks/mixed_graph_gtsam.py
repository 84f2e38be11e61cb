"""GTSAM 4.3 reference for a mixed graph: SE3 camera poses, landmarks, calibration, odometry, GPS.

Run in the benchmark environment (GTSAM 4.3), from the repository root::

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/mixed_graph_gtsam.py \\
        --out tests/fixtures/optim/mixed_gtsam.json

The scene is generated here from ``--seed`` with NumPy only (no microlie code): ``--cameras``
cameras on a circle of radius 12 around a cloud of ``--points`` landmarks in a 8 x 8 x 3 box,
each looking at the cloud's centre (world z up); a pinhole camera ``(fx, fy, cx, cy)`` with no
skew and no distortion, shared by all cameras and estimated; an observation is kept when the
point projects inside the 640 x 480 image and a coin (probability 0.6) says it is not occluded;
landmarks seen fewer than 3 times are dropped. Measurements: pixels with noise ``sigma_px``;
odometry ``Z_ij = P_i^-1 P_j (Exp of noise)`` between consecutive cameras and the loop closure
(last, first), with ``P = ^wT_c`` the camera-to-world pose; GPS-like positions of every 4th
camera centre; a prior on the calibration. The start perturbs the true poses, landmarks and
calibration.

GTSAM graph: ``GeneralSFMFactor2Cal3_S2`` (pose, landmark, calibration keys; ``Isotropic``
``sigma_px``), ``BetweenFactorPose3`` (``Diagonal`` sigmas, GTSAM's tangent ``(omega, v)``),
``GPSFactor`` (``Isotropic``), ``PriorFactorCal3_S2`` on ``(fx, fy, s, u0, v0)``. Cal3_S2 has a
skew that microlie's :class:`~microlie.optim.PinholeCamera` does not: its prior holds it at zero
with sigma ``SKEW_SIGMA`` = 1e-6 px (the fixture records GTSAM's final skew and the cost that
this prior term contributes, to show that it is negligible at 1e-6 relative).
``LevenbergMarquardtOptimizer`` with relative and absolute error tolerances 1e-14, at most 200
iterations.

The fixture stores the scene (start, measurements, noise), GTSAM's cost at the start and at its
optimum, its optimum (poses given both as GTSAM's camera-to-world ``P`` and as microlie's
world-to-camera ``T_cw = P^-1``, rotation matrix and translation) and the conventions, which
:func:`check_conventions` verifies numerically before anything is solved:

* Pose3: both libraries perturb on the right through the exponential map; GTSAM's tangent is
  ``(omega, v)``, microlie's ``(rho, phi)`` (translation first): ``PERM``.
* ``PinholeCameraCal3_S2(P, K).project(X)`` with zero skew equals microlie's
  ``PinholeCamera().project(R X + t, K)`` with ``(R, t) = P^-1``; ``Cal3DS2.uncalibrate`` with
  zero skew is OpenCV's radial-tangential model, microlie's ``PinholeCamera(distortion=True)``
  with ``(fx, fy, cx, cy, k1, k2, p1, p2)``.
* ``GPSFactor`` error ``P.translation() - z`` is ``-R^T t - z`` for ``T_cw = (R, t)``.
* ``BetweenFactorPose3`` error ``Log(Z^-1 P_i^-1 P_j)`` is ``Log(Z^-1 T_i T_j^-1)`` for
  ``T = P^-1``, the same element: microlie's residual is it with the tangent permuted, noise
  sigmas permuted the same way (microlie's ``BetweenFactor`` on ``T_cw``, ``Log(Z^-1 T_i^-1
  T_j)``, is a different objective).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

PERM = [3, 4, 5, 0, 1, 2]        # microlie tangent [k] = GTSAM tangent [PERM[k]]
SKEW_SIGMA = 1e-6
COMMAND = ("PYTHONPATH=src /work/bench-venv/bin/python benchmarks/mixed_graph_gtsam.py "
           "--out tests/fixtures/optim/mixed_gtsam.json")


# ---------------------------------------------------------------------------- NumPy scene

def _hat(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _rot_exp(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    W = _hat(w)
    if th < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + np.sin(th) / th * W + (1.0 - np.cos(th)) / th**2 * (W @ W)


def _pose_exp(omega: np.ndarray, v: np.ndarray) -> np.ndarray:
    """4x4 ``Exp`` of an SE(3) tangent ``(omega, v)`` (closed form)."""
    th = float(np.linalg.norm(omega))
    W = _hat(omega)
    if th < 1e-12:
        V = np.eye(3) + 0.5 * W
    else:
        V = (np.eye(3) + (1.0 - np.cos(th)) / th**2 * W
             + (th - np.sin(th)) / th**3 * (W @ W))
    T = np.eye(4)
    T[:3, :3] = _rot_exp(omega)
    T[:3, 3] = V @ v
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def make_scene(seed: int, n_cameras: int, n_points: int, sigma_px: float = 1.0) -> dict:
    """The synthetic scene (truth, measurements, start) as plain lists."""
    rng = np.random.default_rng(seed)
    K_true = np.array([500.0, 510.0, 320.0, 240.0])          # fx, fy, cx, cy
    width, height = 640.0, 480.0
    L = rng.uniform([-4.0, -4.0, -1.5], [4.0, 4.0, 1.5], (n_points, 3))
    P_true = []
    for i in range(n_cameras):
        a = 2.0 * np.pi * i / n_cameras
        c = np.array([12.0 * np.cos(a), 12.0 * np.sin(a), 1.0 + 0.5 * rng.standard_normal()])
        z = -c / np.linalg.norm(c)                           # optical axis towards the centre
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)                                   # image y points down
        T = np.eye(4)
        T[:3, :3] = np.stack([x, y, z], 1)                   # camera axes as columns
        T[:3, 3] = c
        P_true.append(T)
    cam, pt, uv = [], [], []
    for i, P in enumerate(P_true):
        Xc = (L - P[:3, 3]) @ P[:3, :3]                      # R^T (X - c)
        u = K_true[0] * Xc[:, 0] / Xc[:, 2] + K_true[2]
        v = K_true[1] * Xc[:, 1] / Xc[:, 2] + K_true[3]
        ok = ((Xc[:, 2] > 0.5) & (u > 0) & (u < width) & (v > 0) & (v < height)
              & (rng.uniform(size=n_points) < 0.6))
        for j in np.flatnonzero(ok):
            cam.append(i)
            pt.append(int(j))
            uv.append([u[j], v[j]])
    cam_a, pt_a = np.array(cam), np.array(pt)
    uv_a = np.array(uv) + sigma_px * rng.standard_normal((len(cam), 2))
    counts = np.bincount(pt_a, minlength=n_points)
    keep_pt = np.flatnonzero(counts >= 3)
    renum = -np.ones(n_points, dtype=int)
    renum[keep_pt] = np.arange(keep_pt.size)
    keep_obs = renum[pt_a] >= 0
    cam_a, pt_a, uv_a = cam_a[keep_obs], renum[pt_a[keep_obs]], uv_a[keep_obs]
    L = L[keep_pt]

    # odometry P_i^-1 P_j Exp(noise) with the noise in GTSAM's (omega, v) order
    sig_rot, sig_trans = 0.01, 0.05
    between = []
    for i in range(n_cameras):
        j = (i + 1) % n_cameras
        w = sig_rot * rng.standard_normal(3)
        v = sig_trans * rng.standard_normal(3)
        Z = _inv(P_true[i]) @ P_true[j] @ _pose_exp(w, v)
        between.append({"i": i, "j": j, "R": Z[:3, :3].tolist(), "t": Z[:3, 3].tolist()})
    sig_gps = 0.1
    gps = [{"i": i, "position": (P_true[i][:3, 3] + sig_gps * rng.standard_normal(3)).tolist()}
           for i in range(0, n_cameras, 4)]
    K_prior_mean = K_true + np.array([-3.0, 4.0, 2.0, -2.5])
    K_prior_sigma = np.array([5.0, 5.0, 5.0, 5.0])

    # start: perturbed truth; the calibration starts at its prior mean
    P_start = [P @ _pose_exp(0.03 * rng.standard_normal(3), 0.2 * rng.standard_normal(3))
               for P in P_true]
    L_start = L + 0.15 * rng.standard_normal(L.shape)
    return {
        "seed": seed, "n_cameras": n_cameras, "n_points": int(L.shape[0]),
        "image_size": [width, height],
        "truth": {"P_wc": [P.tolist() for P in P_true], "landmarks": L.tolist(),
                  "K": K_true.tolist()},
        "observations": {"camera": cam_a.tolist(), "landmark": pt_a.tolist(),
                         "uv": uv_a.tolist(), "sigma_px": sigma_px},
        "between": {"factors": between,
                    "sigmas_gtsam": [sig_rot] * 3 + [sig_trans] * 3,
                    "sigmas_microlie": [sig_trans] * 3 + [sig_rot] * 3},
        "gps": {"factors": gps, "sigma": sig_gps},
        "calibration_prior": {"mean": K_prior_mean.tolist(), "sigmas": K_prior_sigma.tolist(),
                              "skew_sigma_gtsam": SKEW_SIGMA},
        "start": {"P_wc": [P.tolist() for P in P_start], "landmarks": L_start.tolist(),
                  "K": K_prior_mean.tolist()},
    }


# ---------------------------------------------------------------------------- GTSAM

def _pose(gtsam, T) -> object:
    T = np.asarray(T, dtype=float)
    return gtsam.Pose3(gtsam.Rot3(T[:3, :3]), T[:3, 3])


def _cal(gtsam, K) -> object:
    fx, fy, cx, cy = K
    return gtsam.Cal3_S2(fx, fy, 0.0, cx, cy)


def build(gtsam, scene: dict):
    X = lambda i: gtsam.symbol("x", i)  # noqa: E731
    Lk = lambda j: gtsam.symbol("l", j)  # noqa: E731
    Kk = gtsam.symbol("k", 0)
    graph = gtsam.NonlinearFactorGraph()
    obs = scene["observations"]
    px = gtsam.noiseModel.Isotropic.Sigma(2, obs["sigma_px"])
    for c, j, uv in zip(obs["camera"], obs["landmark"], obs["uv"], strict=True):
        graph.add(gtsam.GeneralSFMFactor2Cal3_S2(np.array(uv), px, X(c), Lk(j), Kk))
    bn = gtsam.noiseModel.Diagonal.Sigmas(np.array(scene["between"]["sigmas_gtsam"]))
    for b in scene["between"]["factors"]:
        Z = np.eye(4)
        Z[:3, :3], Z[:3, 3] = b["R"], b["t"]
        graph.add(gtsam.BetweenFactorPose3(X(b["i"]), X(b["j"]), _pose(gtsam, Z), bn))
    gn = gtsam.noiseModel.Isotropic.Sigma(3, scene["gps"]["sigma"])
    for g in scene["gps"]["factors"]:
        graph.add(gtsam.GPSFactor(X(g["i"]), np.array(g["position"]), gn))
    cp = scene["calibration_prior"]
    s = cp["sigmas"]
    cn = gtsam.noiseModel.Diagonal.Sigmas(np.array([s[0], s[1], cp["skew_sigma_gtsam"], s[2],
                                                    s[3]]))
    graph.add(gtsam.PriorFactorCal3_S2(Kk, _cal(gtsam, cp["mean"]), cn))
    init = gtsam.Values()
    st = scene["start"]
    for i, T in enumerate(st["P_wc"]):
        init.insert(X(i), _pose(gtsam, T))
    for j, p in enumerate(st["landmarks"]):
        init.insert(Lk(j), np.array(p))
    init.insert(Kk, _cal(gtsam, st["K"]))
    return graph, init, X, Lk, Kk


def check_conventions(gtsam) -> None:
    """Assert the convention mappings listed in the module docstring (random inputs)."""
    from microlie import SE3
    from microlie.optim import PinholeCamera

    rng = np.random.default_rng(1)
    for _ in range(5):
        xi = rng.standard_normal(6)
        assert np.allclose(gtsam.Pose3.Expmap(xi).matrix(), SE3.exp(xi[PERM]).matrix(),
                           atol=1e-12), "Pose3 tangent mapping"
        P = gtsam.Pose3.Expmap(0.3 * rng.standard_normal(6))
        T = _inv(P.matrix())
        X = P.transformFrom(np.array([0.2, -0.1, 4.0]) + 0.3 * rng.standard_normal(3))
        Pc = T[:3, :3] @ X + T[:3, 3]
        K = np.array([480.0, 520.0, 310.0, 250.0])
        ours = PinholeCamera().project(Pc[None], K[None], jac=False)[0][0]
        theirs = gtsam.PinholeCameraCal3_S2(P, _cal(gtsam, K)).project(X)
        assert np.allclose(ours, theirs, rtol=0, atol=1e-9), "Cal3_S2 projection"
        D = np.array([480.0, 520.0, 310.0, 250.0, -0.2, 0.05, 1e-3, -2e-3])
        ours = PinholeCamera(distortion=True).project(Pc[None], D[None], jac=False)[0][0]
        cal = gtsam.Cal3DS2(D[0], D[1], 0.0, D[2], D[3], D[4], D[5], D[6], D[7])
        theirs = gtsam.PinholeCameraCal3DS2(P, cal).project(X)
        assert np.allclose(ours, theirs, rtol=0, atol=1e-9), "Cal3DS2 = radial-tangential"
        z = rng.standard_normal(3)
        f = gtsam.GPSFactor(1, z, gtsam.noiseModel.Unit.Create(3))
        v = gtsam.Values()
        v.insert(1, P)
        assert np.allclose(f.unwhitenedError(v), -T[:3, :3].T @ T[:3, 3] - z, atol=1e-12)
        Pj = gtsam.Pose3.Expmap(0.3 * rng.standard_normal(6))
        Z = gtsam.Pose3.Expmap(0.1 * rng.standard_normal(6))
        b = gtsam.BetweenFactorPose3(1, 2, Z, gtsam.noiseModel.Unit.Create(6))
        v.insert(2, Pj)
        Tj = SE3.from_matrix(_inv(Pj.matrix()))
        r = (SE3.from_matrix(Z.matrix()).inverse().compose(SE3.from_matrix(T))
             .compose(Tj.inverse())).log()
        assert np.allclose(b.unwhitenedError(v)[PERM], r, atol=1e-10), "Between mapping"


def main(argv: list[str] | None = None) -> None:
    import gtsam

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--cameras", type=int, default=16)
    ap.add_argument("--points", type=int, default=300)
    a = ap.parse_args(argv)
    check_conventions(gtsam)
    scene = make_scene(a.seed, a.cameras, a.points)
    graph, init, X, Lk, Kk = build(gtsam, scene)
    p = gtsam.LevenbergMarquardtParams()
    p.setRelativeErrorTol(1e-14)
    p.setAbsoluteErrorTol(1e-14)
    p.setMaxIterations(200)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, init, p)
    t0 = time.perf_counter()
    res = opt.optimize()
    dt = time.perf_counter() - t0
    K = res.atCal3_S2(Kk)
    skew_cost = 0.5 * (K.skew() / SKEW_SIGMA) ** 2
    P_final = [res.atPose3(X(i)).matrix() for i in range(scene["n_cameras"])]
    out = {
        "command": COMMAND + (f" --seed {a.seed} --cameras {a.cameras} --points {a.points}"
                              if (a.seed, a.cameras, a.points) != (20, 16, 300) else ""),
        "versions": {"gtsam": getattr(gtsam, "__version__", None) or _dist_version("gtsam"),
                     "numpy": np.__version__, "python": platform.python_version()},
        "tangent_perm_microlie_from_gtsam": PERM,
        "scene": scene,
        "gtsam": {
            "initial_error": graph.error(init), "final_error": graph.error(res),
            "iterations": opt.iterations(), "time_s": dt,
            "final_skew": K.skew(), "skew_prior_error": skew_cost,
            "final": {
                "P_wc": [P.tolist() for P in P_final],
                "T_cw": [_inv(P).tolist() for P in P_final],
                "landmarks": [res.atPoint3(Lk(j)).tolist() for j in range(scene["n_points"])],
                "K": [K.fx(), K.fy(), K.px(), K.py()],
            },
        },
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=None, separators=(",", ":")) + "\n")
    g = out["gtsam"]
    print(f"{len(scene['observations']['camera'])} observations, {scene['n_points']} landmarks,"
          f" {scene['n_cameras']} cameras; GTSAM error {g['initial_error']:.10g} -> "
          f"{g['final_error']:.12g} in {g['iterations']} iterations ({dt:.3f} s); final skew "
          f"{g['final_skew']:.3g} (prior term {skew_cost:.3g})", file=sys.stderr)


def _dist_version(name: str) -> str:
    from importlib.metadata import version
    return version(name)


if __name__ == "__main__":
    main()
