"""Marginal covariances against GTSAM 4.3's ``Marginals`` (fixture made by
tests/fixtures/optim/make_marginals.py, command inside) on one SE2 and one SE3 graph."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file

from microlie import SE2, SE3
from microlie.optim import Diagonal, PriorFactor, Values, from_pose_graph
from microlie.optim.io.g2o import read_g2o

FIX = json.loads((Path(__file__).parent / "fixtures" / "optim" / "gtsam_marginals.json")
                 .read_text())


@pytest.mark.parametrize("case", FIX["graphs"], ids=lambda c: c["file"])
def test_marginals_match_gtsam(case):
    G = SE3 if case["is3d"] else SE2
    pg = read_g2o(data_file("pose_graph/gtsam/" + case["file"]))
    g, poses = from_pose_graph(pg)
    poses.unfix()  # the gauge is GTSAM's prior instead
    g.add(PriorFactor(poses, 0, G(np.array(case["prior_mean"]), normalize=True),
                      Diagonal(case["prior_sigmas"])))
    X = G(np.array(case["optimum"]), normalize=True)
    at = Values([poses], [X.params])
    # our cost there equals GTSAM's error (prior included)
    assert g.cost(at) == pytest.approx(case["error"], rel=1e-9)
    # and our optimum is GTSAM's
    r = g.optimize(rel_tol=1e-12, abs_tol=1e-14)
    assert np.abs(r.values[poses].minus(X)).max() < 1e-6
    m = g.marginals(at, poses)
    assert m.frame == "right"
    ref = np.array(case["marginals"])
    np.testing.assert_allclose(m.cov, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
    i, j = case["joint_keys"]
    J = g.marginal_covariance(at, [(poses, i), (poses, j)])
    refj = np.array(case["joint"])
    np.testing.assert_allclose(J, refj, rtol=1e-6, atol=1e-9 * np.abs(refj).max())
