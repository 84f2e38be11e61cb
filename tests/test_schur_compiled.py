"""The compiled Schur complement of bundle adjustment (``microlie._c._schur``): the dense
reduced camera system it forms equals the one computed directly from the dense normal matrix
(``H_cc - H_cp H_pp^-1 H_pc``, an independent computation), as does the NumPy formation it
replaces, with held cameras and points, points seen twice by one camera and a point block that is
not positive definite; bad arguments are errors; a whole bundle adjustment ends at the same cost
with and without it."""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import require

from microlie.optim.linalg import schur
from microlie.optim.linalg.schur import NormalEquations, SchurStructure


def _compiled():
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0: the NumPy formation only")
    require("microlie._c._schur")
    assert schur._fast() is not None


def _problem(rng, nc=6, npt=40, d=9):
    """Random observations: every point seen by 2-5 distinct cameras, one point seen twice more
    by camera 0, sorted by camera then point as the solver sorts them."""
    cam, pt = [], []
    for j in range(npt):
        for c in rng.choice(nc, size=rng.integers(2, min(nc, 5) + 1), replace=False):
            cam.append(c)
            pt.append(j)
    cam += [0, 0]
    pt += [npt - 1, npt - 1]
    cam, pt = np.array(cam), np.array(pt)
    order = np.lexsort((pt, cam))
    cam, pt = cam[order], pt[order]
    n = len(cam)
    return cam, pt, rng.normal(size=(n, 2)), rng.normal(size=(n, 2, d)), \
        rng.normal(size=(n, 2, 3))


def _dense_reference(cam, pt, r, Jc, Jp, nc, npt, Dc2, Dp2, fc=None, fp=None):
    d = Jc.shape[2]
    J = np.zeros((2 * len(cam), nc * d + 3 * npt))
    for k in range(len(cam)):
        J[2 * k:2 * k + 2, d * cam[k]:d * cam[k] + d] = Jc[k]
        J[2 * k:2 * k + 2, nc * d + 3 * pt[k]:nc * d + 3 * pt[k] + 3] = Jp[k]
    keep = np.ones(J.shape[1], bool)
    if fc is not None:
        keep[:nc * d] &= ~fc.reshape(-1)
    if fp is not None:
        keep[nc * d:] &= ~np.repeat(fp, 3)
    J = J * keep  # held unknowns: their columns removed
    H = J.T @ J + np.diag(np.concatenate([Dc2.reshape(-1), Dp2.reshape(-1)]))
    g = J.T @ r.reshape(-1)
    k = nc * d
    Hpp_inv = np.linalg.inv(H[k:, k:])
    S = H[:k, :k] - H[:k, k:] @ Hpp_inv @ H[k:, :k]
    rhs = -(g[:k] - H[:k, k:] @ Hpp_inv @ g[k:])
    return S, rhs, H, g


@pytest.mark.parametrize("held", [False, True])
def test_compiled_reduced_system_equals_the_dense_schur_complement(held, monkeypatch):
    _compiled()
    rng = np.random.default_rng(4)
    nc, npt, d = 6, 40, 9
    cam, pt, r, Jc, Jp = _problem(rng, nc, npt, d)
    Dc2, Dp2 = rng.uniform(0.1, 2.0, (nc, d)), rng.uniform(0.1, 2.0, (npt, 3))
    fc = fp = None
    if held:
        fc = np.zeros((nc, d), bool)
        fc[1] = True  # a whole camera
        fc[3, 6:] = True  # a camera's intrinsics
        fp = np.zeros(npt, bool)
        fp[[2, 7]] = True
    st = SchurStructure(cam, pt, nc, npt, d)
    S_ref, rhs_ref, H, g = _dense_reference(cam, pt, r, Jc, Jp, nc, npt, Dc2, Dp2, fc, fp)
    got, blocks = {}, {}
    for name, module in (("compiled", schur._fast()), ("numpy", False)):
        monkeypatch.setattr(schur, "_fast_module", module)
        ne = NormalEquations(st, r, Jc.copy(), Jp.copy(), fc, fp)
        S, rhs, ci, _ = ne.reduced_system(Dc2, Dp2)
        got[name] = (S, rhs, ci, ne.solve(Dc2, Dp2))
        blocks[name] = (ne.V, ne.gp, ne.U, ne.gc, ne.diag_c, ne.diag_p, ne.gradient)
    free = np.ones(nc * d, bool) if fc is None else ~fc.reshape(-1)
    for name, (S, rhs, _, (dc, dp)) in got.items():
        scale = np.abs(S_ref).max()
        if name == "compiled":
            assert np.array_equal(S, S.T)  # exactly symmetric (the NumPy one to rounding)
        assert np.abs(S[np.ix_(free, free)] - S_ref[np.ix_(free, free)]).max() <= 1e-12 * scale
        assert np.abs(rhs[free] - rhs_ref[free]).max() <= 1e-12 * np.abs(rhs_ref).max(), name
        if fc is not None:  # held camera unknowns: unit rows and a zero right-hand side
            assert np.array_equal(S[~free][:, ~free], np.eye(int((~free).sum())))
            assert not S[~free][:, free].any() and not rhs[~free].any()
        # the step solves the full damped system
        x = np.concatenate([dc.ravel(), dp.ravel()])
        keep = np.concatenate([free, np.ones(3 * npt, bool) if fp is None
                               else ~np.repeat(fp, 3)])
        want = np.zeros_like(x)
        want[keep] = np.linalg.solve(H[np.ix_(keep, keep)], -g[keep])
        assert np.abs(x - want).max() <= 1e-9 * max(1.0, np.abs(want).max()), name
    for a, b in zip(got["compiled"][2], got["numpy"][2], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)
    # the normal-equation blocks (V, gp, U, gc and what is derived from them): compiled sums
    # against NumPy's, and the gradient against J^T r of the dense Jacobian
    for a, b in zip(blocks["compiled"], blocks["numpy"], strict=True):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13 * np.abs(b).max())
    np.testing.assert_allclose(blocks["compiled"][-1], g, rtol=1e-13, atol=1e-13 * np.abs(g).max())


def test_a_point_block_that_is_not_positive_definite_gives_no_step(monkeypatch):
    _compiled()
    rng = np.random.default_rng(5)
    cam, pt, r, Jc, Jp = _problem(rng, 4, 10, 9)
    Jp[pt == 3] = 0.0  # point 3 unconstrained and undamped: V = 0
    st = SchurStructure(cam, pt, 4, 10, 9)
    Dp2 = np.ones((10, 3))
    Dp2[3] = 0.0
    for module in (schur._fast(), False):
        monkeypatch.setattr(schur, "_fast_module", module)
        ne = NormalEquations(st, r, Jc, Jp)
        assert ne.reduced_system(np.ones((4, 9)), Dp2) is None
        assert ne.solve(np.ones((4, 9)), Dp2) is None


def test_compiled_reduce_rejects_bad_arguments():
    _compiled()
    m = schur._fast()
    rng = np.random.default_rng(6)
    cam, pt, r, Jc, Jp = _problem(rng, 3, 5, 9)
    st = SchurStructure(cam, pt, 3, 5, 9)
    ne = NormalEquations(st, r, Jc, Jp)
    args = [Jc, Jp, ne.V, ne.gp, ne.U, ne.gc, st.cam, st.point_ptr, st.point_obs]
    assert m.reduce(*args) is not None
    with pytest.raises(ValueError, match="Jp has length"):
        m.reduce(Jc, Jp[:-1], *args[2:])
    with pytest.raises(ValueError, match="V must be a C-contiguous float64"):
        m.reduce(Jc, Jp, ne.V.astype(np.float32), *args[3:])
    bad = st.point_obs.copy()
    bad[0] = len(cam)
    with pytest.raises(ValueError, match="out of range"):
        m.reduce(*args[:8], bad)
    with pytest.raises(TypeError, match="expected 9 arguments"):
        m.reduce(*args[:8])
    V, gp, U, gc = m.blocks(Jc, Jp, r, st.cam, st.pt, 3, 5)
    assert V.shape == (5, 6) and gp.shape == (5, 3) and U.shape == (3, 9, 9) and gc.shape == (3, 9)
    with pytest.raises(ValueError, match="out of range"):
        m.blocks(Jc, Jp, r, st.cam, st.pt, 2, 5)
    with pytest.raises(ValueError, match="r has length"):
        m.blocks(Jc, Jp, r[:-1], st.cam, st.pt, 3, 5)
    dc = np.zeros((3, 9))
    ci = np.ones((6, 5))
    dp, y = m.back(Jc, Jp, dc, st.cam, st.pt, ne.gp, ci, np.zeros(5, bool))
    assert dp.shape == (5, 3) and y.shape == (len(cam), 2) and not y.any()
    with pytest.raises(ValueError, match="Ci has length"):
        m.back(Jc, Jp, dc, st.cam, st.pt, ne.gp, np.ones((6, 4)), np.zeros(5, bool))
    with pytest.raises(ValueError, match="held must be a C-contiguous"):
        m.back(Jc, Jp, dc, st.cam, st.pt, ne.gp, ci, np.zeros(5))


def test_bundle_adjustment_ends_at_the_same_cost_with_and_without_it(monkeypatch):
    _compiled()
    from microlie.optim.sfm.bundle import bundle_adjust, synthetic_scene

    _, start = synthetic_scene(n_cameras=6, n_points=60, seed=2)
    costs = []
    for module in (schur._fast(), False):
        monkeypatch.setattr(schur, "_fast_module", module)
        res = bundle_adjust(start, linear_solver="dense")
        costs.append((res.final_cost, res.iterations))
    assert costs[0][1] == costs[1][1]
    assert abs(costs[0][0] - costs[1][0]) <= 1e-9 * costs[1][0]
