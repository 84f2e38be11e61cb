"""``result.inliers`` of GNC is its verdict: with TLS the final weights rounded (known inliers
True), so it agrees with the re-test (``core/gnc_retest.py``, which decides by the weights) and
with the estimate; with GM (weights never 0 or 1) whether the final whitened squared residual
is within its threshold. Residuals and thresholds here are computed from the group operations
and SciPy's chi-square quantile, not by the module.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from microlie import SE2
from microlie.optim import BetweenFactor, FactorGraph, Isotropic, LevenbergMarquardt, PriorFactor
from microlie.optim.core.gnc import GNC

SIGMA_TRUE, SIGMA_FILE = 0.002, 0.05  # the file overstates the noise 25-fold
C2 = float(chi2.ppf(0.99, 3))


def _circle(seed=0):
    """Twelve poses on a circle, odometry and six closures measured with noise SIGMA_TRUE;
    closure 15 turned by 0.03 rad (15 true sigmas, 0.6 file sigmas: within the file's
    threshold)."""
    rng = np.random.default_rng(seed)
    n = 12
    truth = SE2.exp(np.c_[np.zeros((n, 2)), np.linspace(0, 2 * np.pi, n, endpoint=False)]) \
        .compose(SE2.exp(np.tile([5.0, 0.0, 0.0], (n, 1))))
    i = np.r_[np.arange(n - 1), [0, 2, 4, 6, 1, 3]]
    j = np.r_[np.arange(1, n), [6, 8, 10, 0, 9, 7]]
    Z = truth[i].between(truth[j]).compose(SE2.exp(rng.normal(0, SIGMA_TRUE, (i.size, 3))))
    Zp = np.asarray(Z.params).copy()
    Zp[15] = np.asarray(Z[15].compose(SE2.exp(np.array([0.0, 0.0, 0.03]))).params)
    return truth, i, j, SE2.from_params(Zp), n


def _s(X, i, j, Z):
    """Whitened squared residuals of the between edges at ``X``."""
    r = np.asarray(X[i].between(X[j]).minus(Z)) / SIGMA_FILE
    return (r ** 2).sum(axis=1)


def test_tls_inliers_are_the_retest_verdict():
    # first="chordal" (with "cycles" the wrong closure closes a short cycle within the
    # overstated noise and becomes a known inlier: nothing to re-test)
    truth, i, j, Z, n = _circle()
    lm = LevenbergMarquardt(abs_tol=0.0, rel_tol=1e-14)
    g = FactorGraph()
    x = g.add_variables(truth[[0] * n], fixed=[0])
    f = g.add(BetweenFactor(x, i, j, Z, Isotropic(3, SIGMA_FILE)))
    res = g.optimize(robust=GNC("tls", known_inliers=[(f, np.arange(n - 1))], first="chordal"),
                     solver=lm, max_iter=200, verbose=False)
    wrong = np.arange(i.size) == 15
    # the re-test rejects the wrong closure, and the verdict says so (the truth)
    assert res.weights[0].tolist() == (~wrong).astype(float).tolist()
    assert res.inliers[0].tolist() == (~wrong).tolist()
    # ... although its residual at the final estimate is within the threshold: the old
    # definition of inliers (final s <= c^2) called it an inlier
    s = _s(res.values[x], i, j, Z)
    assert s[15] <= C2
    # the estimate is the least-squares optimum of the edges judged inliers
    g2 = FactorGraph()
    x2 = g2.add_variables(truth[[0] * n], fixed=[0])
    keep = np.flatnonzero(~wrong)
    g2.add(BetweenFactor(x2, i[keep], j[keep], Z[keep], Isotropic(3, SIGMA_FILE)))
    ref = g2.optimize(solver=lm, max_iter=200).values[x2]
    np.testing.assert_allclose(np.asarray(res.values[x].params), np.asarray(ref.params),
                               atol=1e-6)


def test_tls_inliers_follow_the_weights_gm_the_residuals():
    # priors on one pose at -a (one) and +a (three), started at 0: every residual within
    # half the threshold there, so TLS keeps weight 1 everywhere (least squares: the mean,
    # a / 2); at the mean the -a prior's residual, (1.5 a)^2, exceeds the threshold
    a = 0.97 * np.sqrt(C2 / 2) * 0.1
    z = SE2.exp(np.array([[-a, 0, 0], [a, 0, 0], [a, 0, 0], [a, 0, 0]]))
    g = FactorGraph()
    x = g.add_variables(SE2.identity(1))
    g.add(PriorFactor(x, [0] * 4, z, Isotropic(3, 0.1)))
    res = g.optimize(robust=GNC("tls"), verbose=False)
    np.testing.assert_allclose(res.values[x].log(), [[a / 2, 0.0, 0.0]], atol=1e-9)
    s = ((np.asarray(z.log()) - a / 2 * np.array([1.0, 0, 0])) ** 2).sum(axis=1) / 0.01
    assert s[0] > C2 and np.all(s[1:] < C2)
    assert res.weights[0].tolist() == [1.0] * 4 and res.inliers[0].tolist() == [True] * 4
    # GM: the verdict is the final residual within the threshold
    res_gm = g.optimize(robust=GNC("gm"), verbose=False)
    z_est = np.asarray(res_gm.values[x].log())[0]
    s_gm = ((np.asarray(z.log()) - z_est) ** 2).sum(axis=1) / 0.01
    assert res_gm.inliers[0].tolist() == (s_gm <= C2).tolist()
