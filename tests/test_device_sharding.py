"""The batched device solve sharded over 4 fake CPU devices (issue 24): 20 runs in a row, each
equal to the unsharded solve. Runs in a subprocess (the device count is fixed when JAX starts),
bounded by a timeout: a hang fails the test instead of stalling the suite."""

import os
import subprocess
import sys
from pathlib import Path

from conftest import require

SCRIPT = r'''
import sys, time
import numpy as np, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from microlie import SE3
from microlie.optim import BetweenFactor, Diagonal, FactorGraph
from microlie.optim.device import DeviceProblem, LMOptions, solve, stack
from microlie.optim.device.sharding import batch_mesh, sharded_solve

assert len(jax.devices()) == 4, jax.devices()
EI, EJ = [0, 1, 2, 3, 0, 1], [1, 2, 3, 4, 2, 4]
thetas, starts = [], []
for b in range(10):  # 10 problems over 4 devices: padded to 12
    rng = np.random.default_rng(b)
    X = SE3.random(5, rng=rng)
    Z = X[EI].between(X[EJ]).plus(0.2 * rng.standard_normal((6, 6)))
    sig = 0.5 + rng.random((6, 6))
    x0 = X.plus(0.1 * rng.standard_normal((5, 6)))
    g = FactorGraph()
    x = g.add_variables(SE3.from_params(jnp.asarray(x0.params)), fixed=[0])
    g.add(BetweenFactor(x, EI, EJ, Z, Diagonal(sig)))
    p = DeviceProblem.from_graph(g)
    thetas.append(p.theta())
    starts.append(p.initial())
theta, x0 = stack(thetas), stack(starts)
opts = LMOptions(rel_tol=1e-12, abs_tol=0.0, max_iter=50)
ref, rinfo = jax.jit(lambda th, x: solve(p, th, x, opts))(theta, x0)
mesh = batch_mesh()
for k in range(20):
    t = time.time()
    x, info = sharded_solve(p, theta, x0, opts, mesh)
    x[0].block_until_ready()
    err = float(np.abs(np.asarray(x[0]) - np.asarray(ref[0])).max())
    assert err < 1e-10, (k, err)
    assert np.array_equal(np.asarray(info.status), np.asarray(rinfo.status))
    print(k, round(time.time() - t, 3), err, flush=True)
print("OK")
'''


def test_sharded_solve_20_runs_equal_unsharded():
    require("jax")
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                          os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-4000:]
    lines = r.stdout.split("\n")
    assert "OK" in lines and sum(1 for s in lines if s[:2].strip().isdigit()) == 20
