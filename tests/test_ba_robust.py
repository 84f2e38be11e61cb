"""Robust losses of the solver (Huber, Cauchy) on reprojection residuals with gross outliers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microlie.optim.sfm.bundle import BundleProblem, bundle_adjust, synthetic_scene


def _relative_rotation_errors_deg(p: BundleProblem, truth: BundleProblem) -> np.ndarray:
    # gauge invariant: R_i R_0^T
    rel = p.rotations @ p.rotations[0].T
    rel_t = truth.rotations @ truth.rotations[0].T
    return np.degrees(Rotation.from_matrix(rel @ np.swapaxes(rel_t, 1, 2)).magnitude())


def test_huber_recovers_cameras_with_5_percent_gross_outliers():
    truth, start = synthetic_scene(6, 300, noise=0.5, perturb=0.02, seed=4, distance=2.5)
    rng = np.random.default_rng(5)
    n = len(start.observations)
    bad = rng.choice(n, size=n // 20, replace=False)          # 5% of the observations
    obs = start.observations.copy()
    obs[bad] += rng.uniform(50.0, 200.0, (len(bad), 2)) * rng.choice([-1, 1], (len(bad), 2))
    clean_start = start
    start = replace(start, observations=obs)
    # calibrated cameras (intrinsics held), gauge held by camera 0's pose
    kw = dict(fix_cameras=[0], fix_intrinsics=True)
    clean = bundle_adjust(clean_start, **kw)
    plain = bundle_adjust(start, **kw)
    huber = bundle_adjust(start, robust="huber:1.0", **kw)
    cauchy = bundle_adjust(start, robust="cauchy:1.0", **kw)
    e_plain = _relative_rotation_errors_deg(start.with_values(plain.values), truth)
    e_huber = _relative_rotation_errors_deg(start.with_values(huber.values), truth)
    e_cauchy = _relative_rotation_errors_deg(start.with_values(cauchy.values), truth)
    e_clean = _relative_rotation_errors_deg(clean_start.with_values(clean.values), truth)
    assert e_clean.max() < 0.06   # no outliers
    assert e_huber.max() < 0.1
    assert e_cauchy.max() < 0.1
    assert e_plain.max() > 1.0
    assert huber.converged and cauchy.converged


def test_unknown_loss_rejected():
    truth, start = synthetic_scene(2, 5, seed=0)
    with pytest.raises(ValueError, match="unknown robust loss"):
        bundle_adjust(start, robust="hubr:1")
