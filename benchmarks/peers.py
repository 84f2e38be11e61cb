"""Prepared, convention-matched callables for the peer libraries.

Every peer gets the *same mathematical inputs*, written in microlie's conventions (see
:class:`Inputs`), and converts them to its own conventions once, outside any timed region:

* quaternions: microlie/scipy/PyPose store ``[qx, qy, qz, qw]``; jaxlie stores ``[qw, qx, qy, qz]``
  (SE3: ``[qw, qx, qy, qz, x, y, z]``); GTSAM and spatialmath are built from rotation matrices;
* SE(3) tangents: microlie/jaxlie/PyPose/spatialmath are translation first ``(rho, phi)``;
  GTSAM ``Pose3`` and scipy ``RigidTransform`` exponential coordinates are rotation first
  ``(phi, rho)``, so those inputs are permuted beforehand and their outputs (log, Jacobians)
  permuted back only when they are *checked*, never while timed.

A :class:`Case` is one zero-argument callable that does nothing but the peer's own call(s), plus
a converter from its output back to microlie's conventions, used to check that every peer
computes the same thing as scipy (:func:`reference`) before anything is timed.

Ops: ``exp`` (tangent -> element), ``log`` (element -> tangent), ``compose`` (X * Y), ``act``
(X applied to a 3D point) and ``exp_jac`` (exp together with its right Jacobian Jr).
Canonical outputs used for checking: rotation / homogeneous matrices for elements, tangents in
microlie order, points as (..., 3), Jr as (..., dof, dof) in microlie tangent order.
"""

from __future__ import annotations

import importlib.metadata
import operator
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.spatial.transform import RigidTransform, Rotation

GROUPS = ("SO3", "SE3")
OPS = ("exp", "log", "compose", "act", "exp_jac")
DOF = {"SO3": 3, "SE3": 6}
ALL_PEERS = ("scipy", "jaxlie", "jaxlie-jit", "pypose", "spatialmath", "gtsam")

# permutation between microlie's SE3 tangent (rho, phi) and rotation-first (phi, rho)
_TF_TO_RF = np.array([3, 4, 5, 0, 1, 2])  # rotation-first vector = tf[..., _TF_TO_RF]
_RF_TO_TF = _TF_TO_RF  # the swap of two 3-blocks is its own inverse


def tf_to_rf(tau: np.ndarray) -> np.ndarray:
    """SE3 tangent (rho, phi) -> (phi, rho)."""
    return np.ascontiguousarray(tau[..., _TF_TO_RF])


def rf_to_tf(tau: np.ndarray) -> np.ndarray:
    """SE3 tangent (phi, rho) -> (rho, phi)."""
    return np.ascontiguousarray(np.asarray(tau)[..., _RF_TO_TF])


def jac_rf_to_tf(jac: np.ndarray) -> np.ndarray:
    """A 6x6 Jacobian in rotation-first coordinates (both sides) -> translation-first."""
    jac = np.asarray(jac)
    return jac[..., _RF_TO_TF, :][..., :, _RF_TO_TF]


def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.concatenate([q[..., 3:], q[..., :3]], axis=-1))


# --------------------------------------------------------------------------------------------
# Inputs and the scipy reference
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Inputs:
    """Benchmark inputs in microlie conventions, float64.

    ``tau``: tangents for exp / exp_jac, SE3 ``(rho, phi)``; ``x``, ``y``: element parameters
    (SO3 ``[qx,qy,qz,qw]``, SE3 ``[tx,ty,tz,qx,qy,qz,qw]``) for log / compose / act;
    ``points``: 3D points. Either all batched with leading axis N, or one element (no batch axis).
    """

    group: str
    tau: np.ndarray
    x: np.ndarray
    y: np.ndarray
    points: np.ndarray

    @property
    def batched(self) -> bool:
        return self.tau.ndim == 2

    @property
    def n(self) -> int:
        return self.tau.shape[0] if self.batched else 1

    def single(self, index: int = 0) -> Inputs:
        """One element (the first by default), without a batch axis."""
        return Inputs(self.group, *(np.ascontiguousarray(a[index]) for a in self._arrays()))

    def head(self, n: int) -> Inputs:
        """The first ``n`` elements (still batched)."""
        return Inputs(self.group, *(np.ascontiguousarray(a[:n]) for a in self._arrays()))

    def _arrays(self) -> tuple[np.ndarray, ...]:
        return (self.tau, self.x, self.y, self.points)

    # handy views ---------------------------------------------------------------------------
    def quat(self, which: str) -> np.ndarray:
        p = getattr(self, which)
        return p if self.group == "SO3" else p[..., 3:]

    def trans(self, which: str) -> np.ndarray:
        return getattr(self, which)[..., :3]

    def rotmat(self, which: str) -> np.ndarray:
        return Rotation.from_quat(self.quat(which)).as_matrix()

    def homog(self, which: str) -> np.ndarray:
        return params_to_matrix(self.group, getattr(self, which))


def _random_tangents(rng: np.random.Generator, n: int, group: str) -> np.ndarray:
    # rotation angles spread over [0, 3] rad (clear of the log's branch point at pi), random axes
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    phi = axis * rng.uniform(0.0, 3.0, size=(n, 1))
    if group == "SO3":
        return phi
    rho = rng.normal(size=(n, 3))
    return np.concatenate([rho, phi], axis=-1)


def se3_exp_ref(tau: np.ndarray) -> RigidTransform:
    """scipy's SE(3) exponential of microlie-ordered tangents."""
    return RigidTransform.from_exp_coords(tf_to_rf(tau))


def _exp_params(group: str, tau: np.ndarray) -> np.ndarray:
    if group == "SO3":
        return Rotation.from_rotvec(tau).as_quat()
    tf = se3_exp_ref(tau)
    return np.concatenate([tf.translation, tf.rotation.as_quat()], axis=-1)


def make_inputs(group: str, n: int, seed: int = 0) -> Inputs:
    """``n`` random inputs (batched, leading axis ``n``) for ``group``, deterministic in seed."""
    rng = np.random.default_rng(seed)
    tau = _random_tangents(rng, n, group)
    x = _exp_params(group, _random_tangents(rng, n, group))
    y = _exp_params(group, _random_tangents(rng, n, group))
    points = rng.normal(size=(n, 3)) * 2.0
    return Inputs(group, tau, x, y, points)


def params_to_matrix(group: str, params: np.ndarray) -> np.ndarray:
    """Element parameters (microlie conventions) -> rotation / homogeneous matrix."""
    params = np.asarray(params, dtype=np.float64)
    if group == "SO3":
        return Rotation.from_quat(params).as_matrix()
    m = np.zeros(params.shape[:-1] + (4, 4))
    m[..., :3, :3] = Rotation.from_quat(params[..., 3:]).as_matrix()
    m[..., :3, 3] = params[..., :3]
    m[..., 3, 3] = 1.0
    return m


def _group_log_ref(group: str, m: np.ndarray) -> np.ndarray:
    if group == "SO3":
        return Rotation.from_matrix(m).as_rotvec()
    return rf_to_tf(RigidTransform.from_matrix(m).as_exp_coords())


def _group_exp_ref_matrix(group: str, tau: np.ndarray) -> np.ndarray:
    if group == "SO3":
        return Rotation.from_rotvec(tau).as_matrix()
    return se3_exp_ref(tau).as_matrix()


def numeric_right_jacobian(group: str, tau: np.ndarray, h: float = 1e-5) -> np.ndarray:
    """Jr(tau) by central differences of log(exp(tau)^-1 exp(tau + d)), all in scipy."""
    dof = DOF[group]
    inv = np.linalg.inv(_group_exp_ref_matrix(group, tau))
    cols = []
    for j in range(dof):
        e = np.zeros(dof)
        e[j] = h
        plus = _group_log_ref(group, inv @ _group_exp_ref_matrix(group, tau + e))
        minus = _group_log_ref(group, inv @ _group_exp_ref_matrix(group, tau - e))
        cols.append((plus - minus) / (2 * h))
    return np.stack(cols, axis=-1)


def reference(op: str, inp: Inputs):
    """Expected canonical output of ``op`` on ``inp``, computed with scipy."""
    g = inp.group
    if op == "exp":
        return _group_exp_ref_matrix(g, inp.tau)
    if op == "log":
        return _group_log_ref(g, inp.homog("x"))
    if op == "compose":
        return inp.homog("x") @ inp.homog("y")
    if op == "act":
        rotated = (inp.rotmat("x") @ inp.points[..., None])[..., 0]
        return rotated if g == "SO3" else rotated + inp.trans("x")
    if op == "exp_jac":
        return _group_exp_ref_matrix(g, inp.tau), numeric_right_jacobian(g, inp.tau)
    raise ValueError(op)


def max_error(op: str, got, want) -> float:
    """Largest absolute difference between a canonical output and the reference."""
    if op == "exp_jac":
        return max(max_error("exp", got[0], want[0]), max_error("jac", got[1], want[1]))
    got = np.asarray(got, dtype=np.float64)
    want = np.asarray(want, dtype=np.float64)
    if got.shape != want.shape:
        raise AssertionError(f"shape {got.shape} != expected {want.shape}")
    return float(np.max(np.abs(got - want)))


# tolerances for the sanity checks; Jacobians are compared to central differences
TOLERANCE = {"exp": 1e-9, "log": 1e-8, "compose": 1e-9, "act": 1e-9, "exp_jac": 1e-6}


# --------------------------------------------------------------------------------------------
# Peers
# --------------------------------------------------------------------------------------------


class Unsupported(Exception):
    """The peer has no such op (the message says why); shown as N/A in the table."""


@dataclass
class Case:
    """A prepared benchmark case.

    ``fn()`` does only the peer's own work (inputs already converted, results not converted);
    ``n`` elements are processed per call; ``to_canonical(fn())`` gives the output in microlie
    conventions for checking; ``note`` is a footnote for the table (e.g. a Python loop).
    """

    fn: Callable[[], object]
    n: int
    to_canonical: Callable[[object], object]
    note: str = ""


def _dist_version(*names: str) -> str:
    for name in names:
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return "?"


class Peer:
    """Base class. ``setup()`` imports the library (raises ImportError when it is missing)."""

    name = "?"
    vectorized = True  # False: no batching, the batched regime is a Python loop over singles
    threads = 1
    loop_n = 10_000  # elements in the batched regime of a non-vectorized peer

    def setup(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def version(self) -> str:
        return "?"

    def case(self, op: str, inp: Inputs) -> Case:
        """A :class:`Case` for ``op`` on ``inp`` (single element or batched).

        Raises :class:`Unsupported` when the peer has no such op.
        """
        raise NotImplementedError


# ---- scipy ---------------------------------------------------------------------------------


class ScipyPeer(Peer):
    """``scipy.spatial.transform``: Rotation (SO3) and RigidTransform (SE3, scipy >= 1.16).

    RigidTransform exponential coordinates are rotation first. scipy has no Jacobians.
    """

    name = "scipy"

    def setup(self) -> None:
        import scipy  # noqa: F401

    def version(self) -> str:
        return _dist_version("scipy")

    def case(self, op, inp):
        return getattr(self, f"_{inp.group.lower()}_{op}")(inp)

    # SO3
    def _so3_exp(self, inp):
        return Case(partial(Rotation.from_rotvec, inp.tau), inp.n, lambda r: r.as_matrix())

    def _so3_log(self, inp):
        return Case(Rotation.from_quat(inp.x).as_rotvec, inp.n, np.asarray)

    def _so3_compose(self, inp):
        a, b = Rotation.from_quat(inp.x), Rotation.from_quat(inp.y)
        return Case(partial(operator.mul, a, b), inp.n, lambda r: r.as_matrix())

    def _so3_act(self, inp):
        return Case(partial(Rotation.from_quat(inp.x).apply, inp.points), inp.n, np.asarray)

    def _so3_exp_jac(self, inp):
        raise Unsupported("scipy has no Lie-group Jacobians")

    # SE3
    @staticmethod
    def _tf(inp, which):
        return RigidTransform.from_components(inp.trans(which), Rotation.from_quat(inp.quat(which)))

    def _se3_exp(self, inp):
        xi = tf_to_rf(inp.tau)
        return Case(partial(RigidTransform.from_exp_coords, xi), inp.n, lambda t: t.as_matrix())

    def _se3_log(self, inp):
        return Case(self._tf(inp, "x").as_exp_coords, inp.n, rf_to_tf)

    def _se3_compose(self, inp):
        a, b = self._tf(inp, "x"), self._tf(inp, "y")
        return Case(partial(operator.mul, a, b), inp.n, lambda t: t.as_matrix())

    def _se3_act(self, inp):
        return Case(partial(self._tf(inp, "x").apply, inp.points), inp.n, np.asarray)

    def _se3_exp_jac(self, inp):
        raise Unsupported("scipy has no Lie-group Jacobians")


# ---- jaxlie ---------------------------------------------------------------------------------


class JaxliePeer(Peer):
    """jaxlie (JAX, float64 via ``jax_enable_x64``), eager or ``jax.jit``-compiled.

    Params are wxyz (SE3 ``wxyz_xyz``); tangents translation first like microlie. jaxlie has no
    exp Jacobian (only ``jlog``): ``exp_jac`` uses ``jax.jacfwd`` of
    ``d -> log(exp(tau)^-1 exp(tau + d))`` at 0, i.e. Jr by forward-mode autodiff (vmapped
    when batched). Every call ends with ``block_until_ready`` (JAX dispatches asynchronously,
    eager ops too); jitted functions are compiled and warmed up before timing.
    """

    def __init__(self, jit: bool):
        self.jit = jit
        self.name = "jaxlie-jit" if jit else "jaxlie"

    def setup(self) -> None:
        import jax

        jax.config.update("jax_enable_x64", True)
        import jax.numpy as jnp
        import jaxlie

        self.jax, self.jnp, self.jaxlie = jax, jnp, jaxlie

    def version(self) -> str:
        return f"{_dist_version('jaxlie')} (jax {_dist_version('jax')})"

    def _arr(self, a):
        return self.jax.device_put(self.jnp.asarray(a, dtype=self.jnp.float64))

    def _params(self, inp, which):
        p = getattr(inp, which)
        if inp.group == "SO3":
            return self._arr(xyzw_to_wxyz(p))
        return self._arr(np.concatenate([xyzw_to_wxyz(p[..., 3:]), p[..., :3]], axis=-1))

    def _cls(self, group):
        return self.jaxlie.SO3 if group == "SO3" else self.jaxlie.SE3

    def _make(self, f, args, n, to_canonical, note=""):
        jax = self.jax
        if self.jit:
            f = jax.jit(f)
            jax.block_until_ready(f(*args))  # compile + warm up outside the timed region
        fn = partial(_call_and_block, jax.block_until_ready, f, args)
        return Case(fn, n, to_canonical, note)

    def case(self, op, inp):
        G = self._cls(inp.group)
        to_m = lambda p: np.asarray(G(p).as_matrix())
        if op == "exp":
            return self._make(lambda t: G.exp(t).parameters(), (self._arr(inp.tau),), inp.n, to_m)
        if op == "log":
            return self._make(lambda p: G(p).log(), (self._params(inp, "x"),), inp.n, np.asarray)
        if op == "compose":
            args = (self._params(inp, "x"), self._params(inp, "y"))
            return self._make(lambda a, b: (G(a) @ G(b)).parameters(), args, inp.n, to_m)
        if op == "act":
            args = (self._params(inp, "x"), self._arr(inp.points))
            return self._make(lambda a, p: G(a).apply(p), args, inp.n, np.asarray)
        if op == "exp_jac":
            jax, jnp = self.jax, self.jnp

            def exp_jr(t):
                x = G.exp(t)
                x_inv = x.inverse()
                jr = jax.jacfwd(lambda d: (x_inv @ G.exp(t + d)).log())(jnp.zeros_like(t))
                return x.parameters(), jr

            f = jax.vmap(exp_jr) if inp.batched else exp_jr
            conv = lambda out: (to_m(out[0]), np.asarray(out[1]))
            return self._make(f, (self._arr(inp.tau),), inp.n, conv, "Jr by autodiff (jacfwd)")
        raise ValueError(op)


def _call_and_block(block, f, args):
    return block(f(*args))


# ---- PyPose ----------------------------------------------------------------------------------


class PyPosePeer(Peer):
    """PyPose LieTensors on CPU, ``torch.set_num_threads(threads)``, autograd disabled.

    Params xyzw (SE3 ``[t, q]``) and tangents translation first, like microlie. ``so3.Jr()``
    gives the SO3 right Jacobian; ``se3.Jr()`` raises NotImplementedError (PyPose 0.9.x).
    """

    name = "pypose"

    def setup(self) -> None:
        import torch

        torch.set_num_threads(self.threads)
        torch.set_grad_enabled(False)  # no autograd graph building: microlie (NumPy) has none
        import pypose

        self.torch, self.pp = torch, pypose

    def version(self) -> str:
        return f"{_dist_version('pypose')} (torch {_dist_version('torch')})"

    def _t(self, a):
        return self.torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))

    @staticmethod
    def _np(t):
        return np.asarray(t.tensor() if hasattr(t, "tensor") else t)

    def case(self, op, inp):
        pp = self.pp
        alg, grp = (pp.so3, pp.SO3) if inp.group == "SO3" else (pp.se3, pp.SE3)
        to_m = lambda X: self._np(X.matrix())
        if op == "exp":
            return Case(alg(self._t(inp.tau)).Exp, inp.n, to_m)
        if op == "log":
            return Case(grp(self._t(inp.x)).Log, inp.n, self._np)
        if op == "compose":
            a, b = grp(self._t(inp.x)), grp(self._t(inp.y))
            return Case(partial(operator.matmul, a, b), inp.n, to_m)
        if op == "act":
            return Case(partial(grp(self._t(inp.x)).Act, self._t(inp.points)), inp.n, self._np)
        if op == "exp_jac":
            if inp.group != "SO3":
                raise Unsupported("pypose se3.Jr() raises NotImplementedError")
            x = alg(self._t(inp.tau))
            fn = partial(_exp_and_jr, x)
            return Case(fn, inp.n, lambda out: (to_m(out[0]), self._np(out[1])))
        raise ValueError(op)


def _exp_and_jr(x):
    return x.Exp(), x.Jr()


# ---- loop peers: spatialmath, GTSAM ---------------------------------------------------------


class _LoopPeer(Peer):
    """A peer without batching: one element per call; the batched regime loops in Python.

    Subclasses implement ``_single(op, group)`` -> (prepare, call, to_canonical): ``prepare``
    turns one single-element :class:`Inputs` into the argument tuple of ``call``; ``call`` is
    the peer's own work on one element.
    """

    vectorized = False

    def case(self, op, inp):
        prepare, call, to_canonical = self._single(op, inp.group)
        if not inp.batched:
            return Case(partial(call, *prepare(inp)), 1, to_canonical)
        inp = inp.head(min(inp.n, self.loop_n))
        columns = list(zip(*(prepare(_row(inp, i)) for i in range(inp.n)), strict=True))
        fn = partial(_map_list, call, columns)
        conv = lambda outs: _stack_canonical([to_canonical(o) for o in outs])
        return Case(fn, inp.n, conv, f"Python loop over N={inp.n:,} single calls")


def _row(inp: Inputs, i: int) -> Inputs:
    return Inputs(inp.group, inp.tau[i], inp.x[i], inp.y[i], inp.points[i])


def _map_list(call, columns):
    return list(map(call, *columns))


def _stack_canonical(items):
    if isinstance(items[0], tuple):
        return tuple(np.stack(parts) for parts in zip(*items, strict=True))
    return np.stack(items)


class SpatialmathPeer(_LoopPeer):
    """spatialmath-python ``SO3`` / ``SE3`` objects (matrix based, one element per object).

    Twists are translation first. For the SO3 Jacobian, ``spatialmath.base.exp2jac(v)`` maps
    exponential-coordinate rates to world-frame angular velocity, i.e. the *left* Jacobian
    Jl(v); Jr(v) = Jl(-v), so it is called on the negated tangent (negated beforehand).
    """

    name = "spatialmath"

    def setup(self) -> None:
        import spatialmath
        import spatialmath.base

        self.sm, self.smb = spatialmath, spatialmath.base

    def version(self) -> str:
        return _dist_version("spatialmath-python")

    def _single(self, op, group):
        sm = self.sm
        G = sm.SO3 if group == "SO3" else sm.SE3
        to_m = lambda X: np.asarray(X.A)
        elem = lambda inp, w: G(inp.rotmat(w) if group == "SO3" else inp.homog(w), check=False)
        if op == "exp":
            return (lambda inp: (inp.tau.copy(),)), G.Exp, to_m
        if op == "log":
            return (lambda inp: (elem(inp, "x"),)), _sm_log, np.asarray
        if op == "compose":
            return (lambda inp: (elem(inp, "x"), elem(inp, "y"))), operator.mul, to_m
        if op == "act":
            prep = lambda inp: (elem(inp, "x"), inp.points.copy())
            return prep, operator.mul, lambda p: np.asarray(p).reshape(3)
        if op == "exp_jac":
            if group != "SO3":
                raise Unsupported("spatialmath has no SE(3) exp Jacobian")
            exp2jac = self.smb.exp2jac

            def call(v, minus_v):
                return G.Exp(v), exp2jac(minus_v)

            prep = lambda inp: (inp.tau.copy(), -inp.tau)
            return prep, call, lambda out: (to_m(out[0]), np.asarray(out[1]))
        raise ValueError(op)


def _sm_log(x):
    return x.log(twist=True)


class GtsamPeer(_LoopPeer):
    """GTSAM Python wrapper: ``Rot3`` / ``Pose3`` (one element per object).

    Pose3 tangents are rotation first ``[omega, v]``. ``Expmap(xi, H)`` fills the right
    Jacobian (``ExpmapDerivative``) into a preallocated array; for Pose3 it is rotation first
    and gets permuted only for checking.
    """

    name = "gtsam"

    def setup(self) -> None:
        import gtsam

        self.gtsam = gtsam

    def version(self) -> str:
        return _dist_version("gtsam")

    def _single(self, op, group):
        gtsam = self.gtsam
        so3 = group == "SO3"
        G = gtsam.Rot3 if so3 else gtsam.Pose3
        to_m = lambda X: np.asarray(X.matrix())

        def elem(inp, w):
            r = gtsam.Rot3(inp.rotmat(w))
            return r if so3 else gtsam.Pose3(r, inp.trans(w).copy())

        tangent = (lambda inp: inp.tau.copy()) if so3 else (lambda inp: tf_to_rf(inp.tau))
        from_tangent = np.asarray if so3 else rf_to_tf
        if op == "exp":
            return (lambda inp: (tangent(inp),)), G.Expmap, to_m
        if op == "log":
            return (lambda inp: (elem(inp, "x"),)), G.Logmap, from_tangent
        if op == "compose":
            return (lambda inp: (elem(inp, "x"), elem(inp, "y"))), operator.mul, to_m
        if op == "act":
            act = G.rotate if so3 else G.transformFrom
            return (lambda inp: (elem(inp, "x"), inp.points.copy())), act, np.asarray
        if op == "exp_jac":
            dof = DOF[group]
            from_jac = np.array if so3 else jac_rf_to_tf

            def call(xi, h):
                return G.Expmap(xi, h), h

            prep = lambda inp: (tangent(inp), np.zeros((dof, dof)))
            return prep, call, lambda out: (to_m(out[0]), from_jac(out[1]))
        raise ValueError(op)


def make_peer(name: str) -> Peer:
    """A fresh (not yet set up) peer by name; see :data:`ALL_PEERS`."""
    factories: dict[str, Callable[[], Peer]] = {
        "scipy": ScipyPeer,
        "jaxlie": lambda: JaxliePeer(jit=False),
        "jaxlie-jit": lambda: JaxliePeer(jit=True),
        "pypose": PyPosePeer,
        "spatialmath": SpatialmathPeer,
        "gtsam": GtsamPeer,
    }
    try:
        return factories[name]()
    except KeyError:
        raise ValueError(f"unknown peer {name!r}; known: {', '.join(ALL_PEERS)}") from None
