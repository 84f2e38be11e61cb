"""Gradients through device solves (issue 24): implicit and unrolled, on torch and JAX, against
central finite differences of the optimum.

The reference optimum of a perturbed problem is polished by undamped Gauss-Newton steps (the
engine's analytic Jacobians, a dense solve here) from the unperturbed optimum until the
gradient of the cost vanishes: LM stops when the cost no longer decreases in floating point,
which leaves ~1e-8 in the values, too coarse for differences of step 1e-6. Measurements are
perturbed on the group (``Z (+) eps``), square-root informations entry by entry.
"""

import numpy as np
import pytest
from conftest import require

from microlie import SE3
from microlie.optim import BetweenFactor, Diagonal, FactorGraph
from microlie.optim.device import DeviceProblem, LMOptions

N = 5
EI, EJ = [0, 1, 2, 3, 0, 1, 2], [1, 2, 3, 4, 2, 4, 4]
E = len(EI)
H_STEP = 1e-6
OPTS = LMOptions(rel_tol=1e-14, abs_tol=0.0, max_iter=60)
# unrolled: a fixed number of tries (converged problems stop changing within them)
UNROLL = LMOptions(rel_tol=1e-14, abs_tol=0.0, max_iter=60, max_tries=30)


def _data(seed):
    rng = np.random.default_rng(seed)
    X = SE3.random(N, rng=rng)
    Z = X[EI].between(X[EJ]).plus(0.2 * rng.standard_normal((E, 6)))  # residuals ~ 0.2
    sig = 0.5 + rng.random((E, 6))
    x0 = X.plus(0.05 * rng.standard_normal((N, 6)))
    return Z.params, sig, x0.params


class Lib:
    """The few array calls the test needs, on torch or JAX."""

    def __init__(self, name):
        self.name = name
        if name == "torch":
            self.xp = require("torch")
        else:
            jax = require("jax")
            self.jax = jax
            import jax.numpy as jnp

            self.xp = jnp

    def arr(self, a):
        if self.name == "torch":
            return self.xp.tensor(np.asarray(a, dtype=np.float64))
        return self.xp.asarray(np.asarray(a, dtype=np.float64))

    def np(self, a):
        return a.detach().cpu().numpy() if self.name == "torch" else np.asarray(a)

    def solve_linear(self, A, b):
        return self.xp.linalg.solve(A, b[..., None])[..., 0]


def _problem(lib, seed=0):
    Z, sig, x0 = _data(seed)
    g = FactorGraph()
    x = g.add_variables(SE3.from_params(lib.arr(x0)), fixed=[0])
    g.add(BetweenFactor(x, EI, EJ, SE3(Z), Diagonal(sig)))
    return DeviceProblem.from_graph(g)


def _polish(lib, p, theta, x, iters=25):
    """Undamped Gauss-Newton from ``x`` ``(B, N, 7)``; returns the values and the largest
    gradient of the cost left."""
    from microlie.optim.device.dense import normal_equations

    xs = [x]
    for _ in range(iters):
        H, g = normal_equations(p, p.linearize(theta, xs))
        xs = p.retract(xs, -lib.solve_linear(H, g))
    H, g = normal_equations(p, p.linearize(theta, xs))
    return xs[0], float(np.abs(lib.np(g)).max())


def _fd(lib, p, Zb, Lb, xstar):
    """Central differences of the last pose of every problem ``(B, P, 7)`` with respect to the
    ``P = E * 6 + E * 6`` parameters (tangent of each Z, diagonal of each L), all problems
    perturbed at once (they are independent)."""
    B = Zb.shape[0]
    nP = 2 * E * 6
    dZ = np.zeros((nP, 2, E, 6))
    dL = np.zeros((nP, 2, E, 6, 6))
    for k in range(E * 6):
        e, c = divmod(k, 6)
        dZ[k, 0, e, c], dZ[k, 1, e, c] = H_STEP, -H_STEP
        dL[E * 6 + k, 0, e, c, c], dL[E * 6 + k, 1, e, c, c] = H_STEP, -H_STEP
    Zn, Ln = lib.np(Zb), lib.np(Lb)
    Zp = SE3(np.broadcast_to(Zn[:, None, None], (B, nP, 2, E, 7))).plus(
        np.broadcast_to(dZ[None], (B, nP, 2, E, 6))).params
    Lp = Ln[:, None, None] + dL[None]
    M = B * nP * 2
    theta = ({"Z": lib.arr(Zp.reshape(M, E, 7)), "L": lib.arr(Lp.reshape(M, E, 6, 6))},)
    xs = lib.np(xstar)
    x = lib.arr(np.broadcast_to(xs[:, None, None], (B, nP, 2, N, 7)).reshape(M, N, 7))
    xp, gmax = _polish(lib, p, theta, x)
    assert gmax < 1e-11, gmax
    last = lib.np(xp).reshape(B, nP, 2, N, 7)[..., -1, :]
    return (last[:, :, 0] - last[:, :, 1]) / (2 * H_STEP)


def _grads(lib, p, Zb, Lb, x0, batched, differentiate):
    """The implicit (or unrolled) Jacobian of the last pose of every problem, ``(B, P, 7)``,
    with respect to the tangent of each Z and the diagonal of each L; and the optimum."""
    from microlie.optim.device.implicit import solve_differentiable

    B = Zb.shape[0]
    opts = OPTS if differentiate == "implicit" else UNROLL
    if lib.name == "torch":
        torch = lib.xp
        eps = torch.zeros(B, E, 6, dtype=torch.float64, requires_grad=True)
        dl = torch.zeros(B, E, 6, dtype=torch.float64, requires_grad=True)
        Z = SE3.from_params(Zb, check=False).plus(eps).params
        L = Lb + torch.diag_embed(dl)
        if batched:
            xs, _ = solve_differentiable(p, ({"Z": Z, "L": L},), [x0], opts, differentiate)
            last = xs[0][:, -1]
        else:
            last = torch.stack([solve_differentiable(p, ({"Z": Z[b], "L": L[b]},), [x0[b]],
                                                     opts, differentiate)[0][0][-1]
                                for b in range(B)])
        rows = []
        for k in range(7):
            ge, gl = torch.autograd.grad(last[:, k].sum(), [eps, dl], retain_graph=True)
            rows.append(torch.cat([ge.reshape(B, -1), gl.reshape(B, -1)], 1))
        return torch.stack(rows, -1).detach().numpy(), last
    jax, jnp = lib.jax, lib.xp

    def last_pose(eps, dl, b=None):
        Z = SE3.from_params(Zb if b is None else Zb[b], check=False).plus(eps).params
        L = (Lb if b is None else Lb[b]) + jnp.eye(6) * dl[..., None]
        if b is None:
            xs, _ = solve_differentiable(p, ({"Z": Z, "L": L},), [x0], opts, differentiate)
            return xs[0][:, -1]
        xs, _ = solve_differentiable(p, ({"Z": Z, "L": L},), [x0[b]], opts, differentiate)
        return xs[0][-1]

    if batched:
        z = jnp.zeros((B, E, 6))
        f = jax.jit(lambda e, d: last_pose(e, d))
        Je, Jl = jax.jacrev(f, argnums=(0, 1))(z, z)       # (B, 7, B, E, 6)
        Je = jnp.stack([Je[b, :, b] for b in range(B)])
        Jl = jnp.stack([Jl[b, :, b] for b in range(B)])
        last = f(z, z)
    else:
        z = jnp.zeros((E, 6))
        f1 = jax.jit(lambda e, d: last_pose(e, d, 0))
        Je, Jl = jax.jacrev(f1, argnums=(0, 1))(z, z)
        Je, Jl = Je[None], Jl[None]
        last = f1(z, z)[None]
    J = np.concatenate([np.asarray(Je).reshape(B, 7, -1), np.asarray(Jl).reshape(B, 7, -1)], 2)
    return J.transpose(0, 2, 1), last


def _setup(lib, B):
    p = _problem(lib)
    th = p.theta()
    Zs, Ls, x0s = [], [], []
    for b in range(B):
        Z, sig, x0 = _data(b)
        Zs.append(Z)
        Ls.append(np.eye(6) / sig[:, :, None])
        x0s.append(x0)
    assert tuple(th[0]["Z"].shape) == (E, 7)
    return p, lib.arr(np.stack(Zs)), lib.arr(np.stack(Ls)), lib.arr(np.stack(x0s))


@pytest.mark.parametrize("batched", [True, False], ids=["batched", "one"])
@pytest.mark.parametrize("name", ["torch", "jax"])
@pytest.mark.parametrize("differentiate", ["implicit", "unroll"])
def test_gradient_of_last_pose_equals_central_differences(name, batched, differentiate):
    """d(last pose) / d(every measurement and noise diagonal) to 1e-6 relative."""
    lib = Lib(name)
    if name == "jax":
        ctx = lib.jax.enable_x64(True)
    else:
        import contextlib

        ctx = contextlib.nullcontext()
    with ctx:
        B = 2 if batched else 1
        p, Zb, Lb, x0 = _setup(lib, B)
        J, last = _grads(lib, p, Zb, Lb, x0, batched, differentiate)
        # the FD base point: the returned optimum, polished
        xs = _polish(lib, p, ({"Z": Zb, "L": Lb},), x0)[0]
        assert np.abs(lib.np(xs)[:, -1] - lib.np(last)).max() < 1e-7
        Jfd = _fd(lib, p, Zb, Lb, xs)
    err = np.abs(J - Jfd).max() / np.abs(Jfd).max()
    assert err < 1e-6, err
    assert np.abs(Jfd).max() > 0.1  # a real dependence


@pytest.mark.parametrize("name", ["torch", "jax"])
def test_start_values(name):
    """Free variables' starts get no gradient; the fixed one's equals central differences
    (on the group), through the cost and through the output."""
    from microlie.optim.device.implicit import solve_differentiable

    lib = Lib(name)
    import contextlib

    ctx = lib.jax.enable_x64(True) if name == "jax" else contextlib.nullcontext()
    with ctx:
        p, Zb, Lb, x0 = _setup(lib, 1)
        th = ({"Z": Zb[0], "L": Lb[0]},)
        x0 = x0[0]
        w = lib.arr(np.random.default_rng(3).standard_normal((N, 7)))
        if name == "torch":
            torch = lib.xp
            d = torch.zeros(N, 6, dtype=torch.float64, requires_grad=True)
            xs, _ = solve_differentiable(p, th, [SE3.from_params(x0, check=False).plus(d).params],
                                         OPTS)
            (xs[0] * w).sum().backward()
            G = d.grad.numpy()
        else:
            jax = lib.jax

            def f(d):
                xs, _ = solve_differentiable(
                    p, th, [SE3.from_params(x0, check=False).plus(d).params], OPTS)
                return (xs[0] * w).sum()

            G = np.asarray(jax.grad(f)(lib.xp.zeros((N, 6))))
        assert np.abs(G[1:]).max() == 0.0
        xstar = _polish(lib, p, ({"Z": Zb, "L": Lb},), x0[None])[0]
        fd = np.zeros(6)
        wn = lib.np(w)
        for c in range(6):
            vals = []
            for s in (1, -1):
                dd = np.zeros((N, 6))
                dd[0, c] = s * H_STEP
                x0p = SE3(lib.np(xstar)[0]).plus(dd).params  # fixed pose 0 moved, others kept
                xp, gmax = _polish(lib, p, ({"Z": Zb, "L": Lb},), lib.arr(x0p[None]))
                assert gmax < 1e-11
                vals.append((lib.np(xp)[0] * wn).sum())
            fd[c] = (vals[0] - vals[1]) / (2 * H_STEP)
    assert np.abs(G[0] - fd).max() / np.abs(fd).max() < 1e-6, (G[0], fd)


def test_differentiate_must_be_named():
    from microlie.optim.device.implicit import solve_differentiable

    lib = Lib("torch")
    p = _problem(lib)
    with pytest.raises(ValueError, match="differentiate must be one of"):
        solve_differentiable(p, p.theta(), p.initial(), OPTS, differentiate="backprop")


# ------------------------------------------------------------------ through FactorGraph.optimize
def _linear_case():
    """Vector variables on a line: a prior on x_0, odometry between neighbours and one loop
    closure; the optimum is linear in the measurements, ``x* = M z`` with ``M = (A^T W A)^-1
    A^T W`` (dense linear algebra, the reference)."""
    n, d = 4, 2
    pairs = [(0, 1), (1, 2), (2, 3), (0, 3)]
    rng = np.random.default_rng(7)
    z0 = rng.standard_normal(d)
    zb = rng.standard_normal((len(pairs), d))
    sig0, sigb = 0.5, 0.2 + rng.random((len(pairs), d))
    rows, w = [], []
    for c in range(d):
        r = np.zeros((n, d))
        r[0, c] = 1.0
        rows.append(r.ravel())
        w.append(1 / sig0 ** 2)
    for k, (i, j) in enumerate(pairs):
        for c in range(d):
            r = np.zeros((n, d))
            r[j, c], r[i, c] = 1.0, -1.0
            rows.append(r.ravel())
            w.append(1 / sigb[k, c] ** 2)
    A, W = np.array(rows), np.diag(w)
    M = np.linalg.solve(A.T @ W @ A, A.T @ W)   # (n d, d + m d)
    return n, d, pairs, z0, zb, sig0, sigb, M


def _linear_graph(conv, n, d, pairs, z0, zb, sig0, sigb):
    from microlie.optim import Isotropic, PriorFactor

    g = FactorGraph()
    x = g.add_variables(conv(np.zeros((n, d))))
    g.add(PriorFactor(x, 0, z0, Isotropic(d, sig0)))
    g.add(BetweenFactor(x, [i for i, _ in pairs], [j for _, j in pairs], zb, Diagonal(sigb)))
    return g, x


@pytest.mark.parametrize("differentiate", ["implicit", "unroll"])
def test_torch_measurements_requiring_grad_get_gradients(differentiate):
    torch = require("torch")
    n, d, pairs, z0, zb, sig0, sigb, M = _linear_case()
    z0t = torch.tensor(z0, requires_grad=True)
    zbt = torch.tensor(zb, requires_grad=True)
    g, x = _linear_graph(torch.tensor, n, d, pairs, z0t, zbt, sig0, sigb)
    res = g.optimize(differentiate=differentiate, rel_tol=1e-14, abs_tol=0.0)
    X = res.values[x]
    assert np.allclose(X.detach().numpy().ravel(), M @ np.concatenate([z0, zb.ravel()]),
                       atol=1e-12)
    J = np.stack([np.concatenate([gg.numpy().ravel() for gg in
                                  torch.autograd.grad(X.ravel()[k], [z0t, zbt],
                                                      retain_graph=True)])
                  for k in range(n * d)])
    assert np.abs(J - M).max() < 1e-9


def test_jax_graph_built_inside_jit_and_grad():
    """A FactorGraph made from JAX arrays inside a function that jax.jit compiles and jax.grad
    differentiates: the gradient of a weighted sum of the optimum is ``w^T M``."""
    jax = require("jax")
    import jax.numpy as jnp

    n, d, pairs, z0, zb, sig0, sigb, M = _linear_case()
    w = np.random.default_rng(1).standard_normal(n * d)
    with jax.enable_x64(True):
        def loss(z0, zb):
            g, x = _linear_graph(jnp.asarray, n, d, pairs, z0, zb, sig0, sigb)
            res = g.optimize(rel_tol=1e-14, abs_tol=0.0)
            return jnp.sum(res.values[x].ravel() * w), res.converged

        (val, ok), (g0, gb) = jax.jit(jax.value_and_grad(loss, argnums=(0, 1), has_aux=True))(
            jnp.asarray(z0), jnp.asarray(zb))
        G = np.concatenate([np.asarray(g0).ravel(), np.asarray(gb).ravel()])
    assert bool(ok)
    assert abs(float(val) - w @ M @ np.concatenate([z0, zb.ravel()])) < 1e-10
    assert np.abs(G - w @ M).max() < 1e-9


def test_graph_gradients_equal_functional_ones():
    """g.optimize on an SE3 graph whose measurement tensor requires grad gives the gradient of
    the functional implicit solve (checked against central differences above)."""
    torch = require("torch")
    from microlie.optim.device.implicit import solve_differentiable

    Z, sig, x0 = _data(0)
    Zt = torch.tensor(Z, requires_grad=True)
    g = FactorGraph()
    x = g.add_variables(SE3.from_params(torch.tensor(x0)), fixed=[0])
    g.add(BetweenFactor(x, EI, EJ, SE3.from_params(Zt), Diagonal(sig)))
    res = g.optimize(rel_tol=1e-14, abs_tol=0.0, max_iter=60)
    (G,) = torch.autograd.grad(res.values[x].params[-1].sum(), [Zt])
    p = DeviceProblem.from_graph(g)
    Z2 = torch.tensor(Z, requires_grad=True)
    xs, _ = solve_differentiable(p, ({"Z": Z2, "L": p.theta()[0]["L"]},), p.initial(), OPTS)
    (G2,) = torch.autograd.grad(xs[0][-1].sum(), [Z2])
    G, G2 = G.numpy(), G2.numpy()
    # SE3(Zt) (checked) normalises the quaternion: its gradient has no radial part
    q = Z[:, 3:]
    G2[:, 3:] -= (G2[:, 3:] * q).sum(1, keepdims=True) * q
    assert np.abs(G - G2).max() < 1e-10 * np.abs(G2).max()
    assert np.abs(G2).max() > 0.1
