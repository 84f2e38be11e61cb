"""The batched device solve compiled by ``torch.compile(fullgraph=True)`` (issue 24): one graph
(the LM loop is torch's ``while_loop`` operator), compiled by Inductor, each problem of the
batch equal to its own NumPy-engine solve (an independent implementation: sparse Cholesky, its
own linearisation and retraction).

The Inductor compile of the loop takes CPU time (``benchmarks/results/device_compile-s11.md``:
about 40 s for PnP, a few minutes for the SE3 chain): this module compiles one small batch of
each kind, once, and is marked ``slow`` (deselect with ``-m "not slow"``)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require
from test_device_engine import _chain, _np, _pnp

pytestmark = [pytest.mark.slow,  # array_api_compat's lru_cache, traced through by Dynamo:
              pytest.mark.filterwarnings("ignore:Dynamo detected a call to a `functools")]


def _compiled_solve(make, B):
    torch = require("torch")
    from microlie.optim.device import DeviceProblem, LMOptions, solve, stack

    conv = lambda a: torch.tensor(np.array(a))  # noqa: E731
    probs = [DeviceProblem.from_graph(make(conv, b)[0]) for b in range(B)]
    p, opts = probs[0], LMOptions()
    torch._dynamo.reset()
    fn = torch.compile(lambda th, x: solve(p, th, x, opts), fullgraph=True, dynamic=False)
    theta, x0 = stack([q.theta() for q in probs]), stack([q.initial() for q in probs])
    out = fn(theta, x0)
    out2 = fn(theta, x0)  # the second call reuses the graph (no recompile)
    return out, out2


@pytest.mark.parametrize("kind", ["chain", "pnp"])
def test_compiled_batch_each_equal_to_its_numpy_solve(kind):
    require("torch")
    from torch._dynamo.utils import counters

    if kind == "chain":
        def make(conv, b):
            return _chain(conv, seed=300 + b)
    else:
        def make(conv, b):
            return _pnp(40 + b, conv)
    B = 3
    counters.clear()
    (xs, info), (xs2, _) = _compiled_solve(make, B)
    assert counters["stats"]["unique_graphs"] == 1  # one graph, compiled once
    # the second call reuses the graph; Inductor's CPU reductions may sum in another order,
    # so equal to rounding, not bit for bit (the fresh-clone CI saw a difference once)
    assert (xs[0] - xs2[0]).abs().max() <= 1e-12
    for b in range(B):
        gn, xn = make(None, b)
        ref = gn.optimize()
        assert int(info.status[b]) == 1
        assert int(info.iterations[b]) == ref.iterations
        assert np.abs(_np(xs[0][b]) - ref.values[xn].params).max() < 1e-8
        assert abs(float(info.cost[b]) - ref.final_cost) <= 1e-10 * ref.final_cost
        assert abs(float(info.initial_cost[b]) - ref.initial_cost) <= 1e-12 * ref.initial_cost
