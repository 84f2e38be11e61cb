"""BCH: the truncation error of order k shrinks as |a, b|^(k+1) (measured slope), the first-order
forms are exact to first order in the small argument, and the 1/12 erratum of the notes."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GROUPS, to_backend, to_numpy

from microlie import SO2, SO3

NONABELIAN = [G for G in GROUPS if G is not SO2]  # SO(2) is abelian: BCH is exact at order 1


def _exact(G, a, b):
    return (G.exp(a) @ G.exp(b)).log()


def _slope(scales, errors):
    return np.polyfit(np.log(scales), np.log(errors), 1)[0]


@pytest.mark.parametrize("G", NONABELIAN, ids=lambda g: g.__name__)
@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_bch_error_shrinks_as_power_order_plus_one(G, order):
    rng = np.random.default_rng(order)
    a0, b0 = rng.standard_normal((2, 8, G.dof))
    scales = np.geomspace(0.03, 0.3, 6)
    errs = []
    for s in scales:
        a, b = s * a0, s * b0
        errs.append(np.max(np.linalg.norm(G.bch(a, b, order=order) - _exact(G, a, b), axis=-1)))
    slope = _slope(scales, errs)
    assert abs(slope - (order + 1)) < 0.25, (slope, errs)


@pytest.mark.parametrize("G", NONABELIAN, ids=lambda g: g.__name__)
@pytest.mark.parametrize("small", ["a", "b"])
def test_first_order_forms_error_is_quadratic_in_the_small_argument(G, small):
    rng = np.random.default_rng(7)
    big = 0.8 * rng.standard_normal((8, G.dof))  # the other argument is not small
    d0 = rng.standard_normal((8, G.dof))
    scales = np.geomspace(1e-4, 1e-2, 5)
    errs = []
    for s in scales:
        a, b = (s * d0, big) if small == "a" else (big, s * d0)
        approx = G.bch_first_order(a, b, small=small)
        errs.append(np.max(np.linalg.norm(approx - _exact(G, a, b), axis=-1)))
        # order 1 of the full series is much worse here: the big argument does not commute
        assert errs[-1] < 0.1 * np.max(np.linalg.norm(G.bch(a, b, order=1) - _exact(G, a, b),
                                                      axis=-1))
    assert abs(_slope(scales, errs) - 2.0) < 0.2, errs


def test_erratum_bch_first_bracket_is_one_half_not_one_twelfth():
    """MATH.md section 10 erratum: the source notes write ``1/12 [A, B]`` for the first bracket
    term; the residual Log(Exp(a) Exp(b)) - a - b is ``1/2 [a, b]`` to second order."""
    rng = np.random.default_rng(3)
    a, b = 1e-3 * rng.standard_normal((2, 3))
    resid = _exact(SO3, a, b) - a - b
    ab = SO3.bracket(a, b)
    coef = resid @ ab / (ab @ ab)
    assert abs(coef - 0.5) < 1e-3
    assert abs(coef - 1.0 / 12.0) > 0.4
    np.testing.assert_allclose(SO3.bch(a, b, order=2) - a - b, 0.5 * ab, rtol=1e-9, atol=1e-22)


def test_bch_backends_batches_and_bad_input(backend):
    from microlie import SE23

    rng = np.random.default_rng(4)
    a, b = 0.1 * rng.standard_normal((2, 5, 9))
    ref = SE23.bch(a, b, order=4)
    out = SE23.bch(to_backend(a, backend), to_backend(b, backend), order=4)
    np.testing.assert_allclose(to_numpy(out), ref, atol=1e-14)
    out = SE23.bch_first_order(to_backend(a, backend), to_backend(b, backend), small="b")
    np.testing.assert_allclose(to_numpy(out), SE23.bch_first_order(a, b, small="b"), atol=1e-14)
    with pytest.raises(ValueError, match="order"):
        SE23.bch(a, b, order=5)
    with pytest.raises(ValueError, match="small"):
        SE23.bch_first_order(a, b, small="c")
    with pytest.raises(ValueError, match="shape"):
        SE23.bch(a[:, :3], b[:, :3])
