"""What users asked for: ``from_params``, ``stack``/``concatenate``, ``allclose``, the Karcher
``mean``. References: the constructor's own validation, NumPy stacking of the parameters,
matrices compared entry by entry, and means known in closed form (symmetric sets, geodesics)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GROUPS, require, tangent_with_angle

from microlie import SE3, SO3, Sim3


def test_from_params_checked_and_unchecked():
    q = np.array([0.0, 0.0, 0.6, 0.8])
    R = SO3.from_params(q)
    np.testing.assert_array_equal(R.params, q)
    with pytest.raises(ValueError, match="norm differs from 1"):
        SO3.from_params(2 * q)
    with pytest.raises(ValueError, match="shape"):
        SO3.from_params(q[:3])
    # unchecked: taken as is (a solver that produces valid parameters by construction)
    U = SO3.from_params(2 * q, check=False)
    np.testing.assert_array_equal(U.params, 2 * q)
    assert SO3.from_params([0, 0, 0, 1], check=False).params.dtype == np.float64


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_stack_and_concatenate(G):
    rng = np.random.default_rng(0)
    a, b = G.random((2, 3), rng=rng), G.random((2, 3), rng=rng)
    s = G.stack([a, b])
    assert s.batch_shape == (2, 2, 3)
    np.testing.assert_array_equal(s.params, np.stack([a.params, b.params]))
    s = G.stack([a, b], axis=-1)
    np.testing.assert_array_equal(s.params, np.stack([a.params, b.params], axis=-2))
    c = G.concatenate([a, b], axis=1)
    np.testing.assert_array_equal(c.params, np.concatenate([a.params, b.params], axis=1))
    c = G.concatenate([a, b], axis=-2)
    np.testing.assert_array_equal(c.params, np.concatenate([a.params, b.params], axis=0))
    singles = G.stack([G.random(rng=rng) for _ in range(4)])
    assert singles.batch_shape == (4,)
    with pytest.raises(ValueError, match="axis"):
        G.stack([a, b], axis=3)
    with pytest.raises(ValueError, match="stack"):
        G.concatenate([a[0, 0], b[0, 0]])
    with pytest.raises(ValueError):
        G.stack([])


def test_stack_rejects_other_groups_and_keeps_backends():
    with pytest.raises(TypeError, match="SE3"):
        SE3.stack([SE3.identity(), SO3.identity()])
    torch = require("torch")
    X = SE3(torch.tensor(SE3.random(3, rng=1).params))
    assert isinstance(SE3.concatenate([X, X]).params, torch.Tensor)


def test_allclose_compares_on_the_group():
    R = SO3.exp(np.array([0.0, 0.0, 1.0]))
    assert R.allclose(SO3(-R.params))  # q and -q are the same rotation
    assert not R.allclose(SO3.exp(np.array([0.0, 0.0, 1.0 + 1e-4])))
    assert R.allclose(SO3.exp(np.array([0.0, 0.0, 1.0 + 1e-6])), atol=2e-6)
    # rotations by pi - e and -(pi - e) about one axis are 2e apart, not 2 pi
    a = SO3.exp(np.array([np.pi - 1e-9, 0.0, 0.0]))
    b = SO3.exp(np.array([-(np.pi - 1e-9), 0.0, 0.0]))
    assert a.allclose(b, atol=1e-8)
    X = SE3.random(5, rng=2)
    Y = X.plus(np.tile([1e4 * 1e-7, 0, 0, 0, 0, 0], (5, 1)))
    assert not X.allclose(Y, rtol=0.0)
    assert X.allclose(Y, atol=2e-3)
    with pytest.raises(TypeError):
        X.allclose(SO3.identity())


def _symmetric_set(G, rng, center, n=6, scale=0.5):
    """Elements ``C Exp(+-v_i)``: their Karcher mean is ``C`` exactly."""
    v = tangent_with_angle(G, rng, scale, n) * rng.uniform(0.2, 1.0, (n, 1))
    return G.stack([center.plus(v), center.plus(-v)]).params.reshape(2 * n, -1)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_karcher_mean_of_a_symmetric_set_is_its_center(G):
    rng = np.random.default_rng(3)
    C = G.random(rng=rng)
    X = G(_symmetric_set(G, rng, C))
    M = G.mean(X)
    np.testing.assert_allclose(M.matrix(), C.matrix(), atol=1e-10)
    # batch axes: two independent sets side by side, mean along axis 1
    C2 = G.random(rng=rng)
    X2 = G(np.stack([_symmetric_set(G, rng, C), _symmetric_set(G, rng, C2)]))
    M2 = G.mean(X2, axis=1)
    assert M2.batch_shape == (2,)
    np.testing.assert_allclose(M2.matrix(), np.stack([C.matrix(), C2.matrix()]), atol=1e-10)
    M3 = G.mean(G(np.swapaxes(X2.params, 0, 1)), axis=-2)
    np.testing.assert_allclose(M3.matrix(), M2.matrix(), atol=1e-12)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_weighted_mean_of_two_elements_is_on_the_geodesic(G):
    """``sum w_i Log(M^-1 X_i) = 0`` for two elements: ``M = X (+) w_Y (Y (-) X)``."""
    rng = np.random.default_rng(4)
    X = G.random(rng=rng)
    Y = X.plus(tangent_with_angle(G, rng, 1.0))
    M = G.mean(G.stack([X, Y]), weights=[0.25, 0.75])
    np.testing.assert_allclose(M.matrix(), X.interpolate(Y, 0.75).matrix(), atol=1e-10)
    with pytest.raises(ValueError, match="non-negative"):
        G.mean(G.stack([X, Y]), weights=[-1.0, 2.0])
    with pytest.raises(ValueError, match="shape"):
        G.mean(G.stack([X, Y]), weights=[1.0, 2.0, 3.0])


def test_karcher_mean_against_a_rotation_average_in_closed_form():
    """Rotations about one axis: the Karcher mean is the rotation by the mean angle."""
    angles = np.array([0.1, 0.4, 1.3, -0.2])
    X = SO3.exp(angles[:, None] * np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(SO3.mean(X).log(), [0.0, angles.mean(), 0.0], atol=1e-12)
    w = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(SO3.mean(X, weights=w).log(),
                               [0.0, (w * angles).sum() / w.sum(), 0.0], atol=1e-12)
    X32 = SO3(X.params.astype(np.float32))
    m32 = SO3.mean(X32)
    assert m32.dtype == np.float32
    np.testing.assert_allclose(m32.log(), [0.0, angles.mean(), 0.0], atol=1e-6)


def test_sim3_mean_recovers_the_scale():
    s = np.array([0.5, 2.0])  # geometric mean 1
    X = Sim3.from_rotation_translation_scale(SO3.identity(), np.zeros(3), s)
    np.testing.assert_allclose(Sim3.mean(X).scale(), 1.0, atol=1e-12)
