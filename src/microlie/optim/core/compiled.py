"""The compiled edge loops of ``microlie._c._graph`` for factor batches (built by ``pip install
microlie`` where a C compiler exists; ``microlie --version`` says whether they were).

A batch of SE(3) or SE(2) :class:`~microlie.optim.BetweenFactor` edges is linearised in one pass of
``microlie._c._graph``: residuals, right Jacobians, whitening, the robust correction, the block
products ``A^T A`` and ``A^T e``, added straight into the CSC values of the problem's fixed
pattern. So is a batch of :class:`~microlie.optim.ReprojectionFactor` observations with the BAL
camera model and an ``SO3`` x ``R(3)`` world-to-camera pose (what
:func:`~microlie.optim.sfm.bundle.bundle_graph` builds), by ``microlie._c._reproj``
(:class:`ReprojectionPlan`). The NumPy path of :class:`~microlie.optim.core.problem.Problem`
stays the reference and the fallback; both give the same linear system to rounding
(``tests/test_optim_compiled.py``, ``tests/test_reprojection_compiled.py``).
``MICROLIE_FAST=0`` (read when a problem is built) keeps the NumPy path.

>>> from microlie.optim.core.compiled import available
>>> isinstance(available(), bool)
True
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._fast import compiled as compiled_module
from .factors import BetweenFactor, Factor

__all__ = ["available", "EdgePlan", "ReprojectionPlan", "plan"]

# the groups with a compiled BetweenFactor loop: class name -> kernel prefix
_KERNELS = {"SE3": "se3", "SE2": "se2"}


def _graph() -> Any:
    """``microlie._c._graph``, or ``None`` (not installed, an older build, or
    ``MICROLIE_FAST=0``)."""
    return compiled_module("_graph")


def available() -> bool:
    """Whether the compiled edge loops are in use for problems built now.

    Returns
    -------
    bool

    Examples
    --------
    >>> from microlie.optim.core.compiled import available
    >>> available() in (True, False)
    True
    """
    return _graph() is not None


class EdgePlan:
    """One factor batch on the compiled path: its arguments as contiguous arrays and its
    destinations in the pattern (built by :func:`plan`).

    Parameters
    ----------
    kernels : tuple
        ``(cost, normal)`` functions of ``microlie._c._graph``.
    key : int
        The position of the variable batch in the problem's states.
    ii, jj : numpy.ndarray
        ``(m,)`` int64 indices of both ends in that batch.
    Z : numpy.ndarray
        ``(m, param_dim)`` measurements.
    L : numpy.ndarray
        ``(1 or m, dim, dim)`` square-root information.
    starts, lens, goff : numpy.ndarray
        ``(m, 4)`` CSC positions of entry (0, 0) of the blocks (i, i), (i, j), (j, i), (j, j)
        (-1: a fixed end), ``(m, 2)`` column lengths of both ends' block columns, ``(m, 2)``
        gradient offsets (-1: fixed).

    Examples
    --------
    >>> from microlie import SE3
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.compiled import plan
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE3.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, 0, 1, SE3.exp([1.0, 0, 0, 0, 0, 0.3])))
    >>> p = g.problem()
    >>> pl = plan(p, p.factors[0])
    >>> pl is None or pl.starts.tolist() == [[-1, -1, -1, 0]]
    True
    """

    def __init__(self, kernels: tuple, key: int, ii: np.ndarray, jj: np.ndarray,
                 Z: np.ndarray, L: np.ndarray, starts: np.ndarray, lens: np.ndarray,
                 goff: np.ndarray) -> None:
        self._cost, self._normal = kernels
        self.key = key
        self.ii, self.jj, self.Z, self.L = ii, jj, Z, L
        self.starts, self.lens, self.goff = starts, lens, goff

    def cost(self, states: list[np.ndarray]) -> np.ndarray:
        """``s_k = |L_k r_k|^2`` per factor.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in problem order.

        Returns
        -------
        numpy.ndarray
            ``(m,)``.

        Examples
        --------
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> from microlie.optim.core.compiled import plan
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE3.identity(2), fixed=[0])
        >>> _ = g.add(BetweenFactor(x, 0, 1, SE3.exp([1.0, 0, 0, 0, 0, 0.0])))
        >>> p = g.problem()
        >>> pl = plan(p, p.factors[0])
        >>> s = pl.cost([v.initial for v in p.variables]) if pl else [1.0]  # |r|^2 = 1
        >>> round(float(s[0]), 12)
        1.0
        """
        s = np.empty(self.ii.size)
        self._cost(_rows(states[self.key]), self.ii, self.jj, self.Z, self.L, s)
        return s

    def normal(self, states: list[np.ndarray], data: np.ndarray, grad: np.ndarray,
               wts: np.ndarray | None) -> np.ndarray:
        """Add the batch's ``A^T A`` into ``data`` and ``A^T e`` into ``grad``; return ``s``.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in problem order.
        data, grad : numpy.ndarray
            The CSC values ``(nnz,)`` and the gradient ``(size,)``, added to in place.
        wts : numpy.ndarray or None
            ``(m, 3)`` rows ``(sqrt(rho'), residual scale, alpha / s)`` of the robust
            correction, or ``None`` without a loss.

        Returns
        -------
        numpy.ndarray
            ``(m,)`` the squared whitened residuals before the correction.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> from microlie.optim.core.compiled import plan
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE3.identity(2), fixed=[0])
        >>> _ = g.add(BetweenFactor(x, 0, 1, SE3.exp([1.0, 0, 0, 0, 0, 0.0])))
        >>> p = g.problem()
        >>> pl = plan(p, p.factors[0])
        >>> data, grad = np.zeros(p.nnz), np.zeros(p.size)
        >>> s = pl.normal([v.initial for v in p.variables], data, grad, None) if pl else [1.0]
        >>> round(float(s[0]), 12), pl is None or bool(data.max() > 0)
        (1.0, True)
        """
        s = np.empty(self.ii.size)
        self._normal(_rows(states[self.key]), self.ii, self.jj, self.Z, self.L, wts,
                     self.starts, self.lens, self.goff, s, data, grad)
        return s


class ReprojectionPlan:
    """A batch of BAL :class:`~microlie.optim.ReprojectionFactor` observations on the compiled
    path (``microlie._c._reproj``; built by :func:`plan`): the rotations ``R`` are formed once
    per camera variable, not per observation, and each observation's residual, Jacobians,
    whitening, robust correction and products are one pass, added straight into the pattern.

    Parameters
    ----------
    module : module
        ``microlie._c._reproj``.
    keys : tuple of int or None
        The positions in the problem's states of the rotation, translation, point and
        intrinsics batches (``None``: constant intrinsics).
    idx : numpy.ndarray
        ``(m, 4)`` intp rows of each observation in those batches (in the constant intrinsics
        when they are constants).
    obs : numpy.ndarray
        ``(m, 2)`` observed pixels.
    L : numpy.ndarray
        ``(1 or m, 2, 2)`` square-root information.
    drop : bool
        ``behind="drop"``.
    K : numpy.ndarray or None
        ``(m, 3)`` constant intrinsics.
    starts, lens, goff : numpy.ndarray
        ``(m, 16)`` CSC positions of entry (0, 0) of the blocks of each pair of arguments
        (rotation, translation, point, intrinsics; ``4 k + l``, -1: one of them fixed or
        constant), ``(m, 4)`` column lengths of each argument's block column, ``(m, 4)``
        gradient offsets (-1: fixed or constant).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.compiled import plan
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> _, start = synthetic_scene(3, 10, seed=1)
    >>> bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
    >>> p = bg.graph.problem()
    >>> pl = plan(p, p.factors[0])
    >>> states = [v.initial for v in p.variables]
    >>> e = p.whiten(p.factors[0], p.factors[0].evaluate(p.gather(p.factors[0], states), False))
    >>> pl is None or bool(np.allclose(pl.cost(states), (e ** 2).sum(1), rtol=1e-12))
    True
    """

    def __init__(self, module: Any, keys: tuple[int, int, int, int | None], idx: np.ndarray,
                 obs: np.ndarray, L: np.ndarray, drop: bool, K: np.ndarray | None,
                 starts: np.ndarray, lens: np.ndarray, goff: np.ndarray) -> None:
        self._mod = module
        self.keys, self.idx, self.obs, self.L, self.drop, self.K = keys, idx, obs, L, drop, K
        self.starts, self.lens, self.goff = starts, lens, goff

    def _arrays(self, states: list[np.ndarray]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``R`` (one matrix per rotation variable), ``t``, ``X`` and ``K`` as the kernel
        reads them."""
        from ...groups import SO3

        kr, kt, kx, kk = self.keys
        R = np.ascontiguousarray(SO3.from_params(states[kr], check=False).matrix(),
                                 dtype=np.float64)
        K = _rows(states[kk]) if kk is not None else self.K
        assert K is not None
        return R, _rows(states[kt]), _rows(states[kx]), K

    def cost(self, states: list[np.ndarray]) -> np.ndarray:
        """``s_k = |L_k r_k|^2`` per observation.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in problem order.

        Returns
        -------
        numpy.ndarray
            ``(m,)``.

        Examples
        --------
        >>> from microlie.optim.core.compiled import plan
        >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
        >>> _, start = synthetic_scene(3, 10, seed=1)
        >>> p = bundle_graph(start, fix_cameras=[0], fix_points=[0]).graph.problem()
        >>> pl = plan(p, p.factors[0])
        >>> pl is None or pl.cost([v.initial for v in p.variables]).shape == (30,)
        True
        """
        s = np.empty(self.idx.shape[0])
        self._mod.cost(*self._arrays(states), self.idx, self.obs, self.L, self.drop, s)
        return s

    def normal(self, states: list[np.ndarray], data: np.ndarray, grad: np.ndarray,
               wts: np.ndarray | None) -> np.ndarray:
        """Add the batch's ``A^T A`` into ``data`` and ``A^T e`` into ``grad``; return ``s``.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in problem order.
        data, grad : numpy.ndarray
            The CSC values ``(nnz,)`` and the gradient ``(size,)``, added to in place.
        wts : numpy.ndarray or None
            ``(m, 3)`` rows ``(sqrt(rho'), residual scale, alpha / s)`` of the robust
            correction, or ``None`` without a loss.

        Returns
        -------
        numpy.ndarray
            ``(m,)`` the squared whitened residuals before the correction.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.core.compiled import plan
        >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
        >>> _, start = synthetic_scene(3, 10, seed=1)
        >>> p = bundle_graph(start, fix_cameras=[0], fix_points=[0]).graph.problem()
        >>> pl = plan(p, p.factors[0])
        >>> data, grad = np.zeros(p.nnz), np.zeros(p.size)
        >>> s = pl.normal([v.initial for v in p.variables], data, grad, None) if pl else [1.0]
        >>> pl is None or bool(np.allclose(grad, p.linearize([v.initial for v in
        ...                                               p.variables]).grad))
        True
        """
        s = np.empty(self.idx.shape[0])
        self._mod.normal(*self._arrays(states), self.idx, self.obs, self.L, self.drop, wts,
                         self.starts, self.lens, self.goff, s, data, grad)
        return s


def _reprojection_plan(problem: Any, f: Factor) -> ReprojectionPlan | None:
    """:class:`ReprojectionPlan` of a BAL reprojection batch, or ``None``."""
    if type(f).__name__ != "ReprojectionFactor":  # no import of sfm for other factors
        return None
    from ..sfm.camera import BALCamera
    from ..sfm.reprojection import ReprojectionFactor

    if type(f) is not ReprojectionFactor or type(f.model) is not BALCamera \
            or f.pose_form != "SO3xR3" or f.camera_to_world:
        return None
    mod = compiled_module("_reproj")
    if mod is None:
        return None
    m = f.count
    args: list[tuple[Any, Any]] = list(f.args)
    const = f.intrinsics
    if const is not None:
        args.append((None, np.arange(m)))
    keys = tuple(None if var is None else problem.key(var) for var, _ in args)
    idx = np.stack([np.broadcast_to(np.asarray(i, np.intp), (m,)) for _, i in args], axis=1)
    nodes = [np.full(m, -1, np.int64) if var is None else
             np.asarray(problem.node_of[problem.key(var)][np.asarray(i, np.intp)], np.int64)
             for var, i in args]
    starts, lens, goff = problem.scatter_positions(
        np.stack([np.broadcast_to(n, (m,)) for n in nodes], axis=1))
    L = np.ascontiguousarray(np.asarray(f.noise.sqrt_info, np.float64).reshape(-1, 2, 2))
    K = None if const is None else np.ascontiguousarray(np.broadcast_to(const, (m, 3)),
                                                        dtype=np.float64)
    return ReprojectionPlan(mod, keys, np.ascontiguousarray(idx, np.intp),  # type: ignore[arg-type]
                            np.ascontiguousarray(f.observations, np.float64), L,
                            f.behind == "drop", K, np.ascontiguousarray(starts, np.intp),
                            np.ascontiguousarray(lens, np.intp),
                            np.ascontiguousarray(goff, np.intp))


def _rows(p: np.ndarray) -> np.ndarray:
    """Parameters as the C-contiguous float64 rows the compiled loop reads (no copy when they
    are already)."""
    return np.ascontiguousarray(p, dtype=np.float64)


def plan(problem: Any, f: Factor) -> EdgePlan | ReprojectionPlan | None:
    """The compiled plan of a factor batch of ``problem``, or ``None`` when it takes the NumPy
    path (no compiled loop for its type, or the extra not in use).

    Parameters
    ----------
    problem : Problem
        The problem (its pattern built).
    f : Factor
        One of its factor batches.

    Returns
    -------
    EdgePlan or ReprojectionPlan or None

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.core.compiled import plan
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> p = g.problem()
    >>> plan(p, p.factors[0]) is None  # priors take the NumPy path
    True
    """
    if type(f) is not BetweenFactor:
        return _reprojection_plan(problem, f)
    mod = _graph()
    if mod is None:
        return None
    (var, ii), (_, jj) = f.args
    name = _KERNELS.get(var.group.__name__)
    if name is None or not hasattr(mod, f"{name}_between_normal"):
        return None
    d = f.dim
    k = problem.key(var)
    nodes = np.empty((f.count, 2), np.intp)
    nodes[:, 0], nodes[:, 1] = problem.node_of[k][ii], problem.node_of[k][jj]
    starts, lens, goff = problem.scatter_positions(nodes)
    L = f.noise.sqrt_info
    L = np.ascontiguousarray(L.reshape(-1, d, d), dtype=np.float64)
    Z = np.ascontiguousarray(f.Z.params, dtype=np.float64)
    kernels = (getattr(mod, f"{name}_between_cost"), getattr(mod, f"{name}_between_normal"))
    return EdgePlan(kernels, k,
                    np.ascontiguousarray(ii, np.int64), np.ascontiguousarray(jj, np.int64), Z, L,
                    np.ascontiguousarray(starts, np.int64), np.ascontiguousarray(lens, np.int64),
                    np.ascontiguousarray(goff, np.int64))
