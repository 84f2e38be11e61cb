"""Factors: batches of residuals of the same form, evaluated in one call per batch.

Every factor batch holds ``m`` residuals of dimension ``dim`` over ``K`` arguments; argument
``k`` is a :class:`Variables` handle and ``m`` indices into it. ``evaluate`` returns the
residuals ``(m, dim)`` and, when asked, one Jacobian ``(m, dim, dof_k)`` per argument with
respect to the right perturbation of that argument (``X_k Exp(delta_k)``; ``x + delta`` for
vectors).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .. import _autodiff
from .noise import NoiseModel, as_noise
from .robust import RobustLoss, make_loss
from .variables import Variables, element

__all__ = ["Factor", "PriorFactor", "BetweenFactor", "CustomFactor"]


class Factor:
    """Base class of factor batches (see the module docstring).

    A subclass sets up its arguments and implements :meth:`evaluate`; the solver whitens the
    residuals with ``noise`` and applies ``loss``.

    Examples
    --------
    >>> from microlie import SO3
    >>> from microlie.optim import Factor, FactorGraph, PriorFactor
    >>> g = FactorGraph()
    >>> f = PriorFactor(g.add_variables(SO3.identity(2)), [0, 1], SO3.identity())
    >>> isinstance(f, Factor), len(f), f.dim
    (True, 2, 3)
    """

    args: list[tuple[Variables, np.ndarray]]
    #: whether :meth:`evaluate` with Jacobians costs little more than without (a solver then
    #: evaluates them at a trial point already, for the linearisation that follows)
    jacobians_with_residuals: bool = False
    dim: int
    noise: NoiseModel
    loss: RobustLoss | None
    name: str

    def _setup(self, args: list[tuple[Variables, Any]], dim: int, noise: Any, loss: Any,
               what: str) -> None:
        self.name = what
        checked = []
        m = None
        for var, idx in args:
            if not isinstance(var, Variables):
                raise TypeError(f"{what}: expected a Variables handle from "
                                f"FactorGraph.add_variables, got {type(var).__name__}")
            ix = var.indices(idx)
            if m is None:
                m = ix.size
            elif ix.size == 1 and m != 1:
                ix = np.repeat(ix, m)
            elif ix.size != m:
                if m == 1:
                    checked = [(v, np.repeat(i, ix.size)) for v, i in checked]
                    m = ix.size
                else:
                    raise ValueError(f"{what}: index arrays of different lengths {m} and "
                                     f"{ix.size}")
            checked.append((var, ix))
        if not m:
            raise ValueError(f"{what}: no factors (empty index array)")
        graphs = {id(v.graph) for v, _ in checked}
        if len(graphs) != 1:
            raise ValueError(f"{what}: arguments belong to different graphs")
        self.args = checked
        self.count = int(m)
        self.dim = int(dim)
        self.noise = as_noise(noise, self.dim, what)
        L = self.noise.sqrt_info
        if L.ndim == 3 and L.shape[0] not in (1, self.count):
            raise ValueError(f"{what}: {L.shape[0]} noise matrices for {self.count} factors")
        self.loss = make_loss(loss)

    def evaluate(self, values: list[Any], jac: bool) -> Any:
        """The residuals of the batch and, with ``jac``, their Jacobians.

        Parameters
        ----------
        values : list
            One batch of ``m`` elements (or ``(m, d)`` array for vectors) per argument.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` of shape ``(m, dim)``; with ``jac``, ``(r, [J_1, ..., J_K])`` with ``J_k`` of
            shape ``(m, dim, dof_k)``, right Jacobians (``d r / d delta`` for ``X_k Exp(delta)``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> g = FactorGraph()
        >>> f = PriorFactor(g.add_variables(SE2.identity(1)), 0, SE2.exp([0.5, 0.0, 0.2]))
        >>> r, (J,) = f.evaluate([SE2.identity(1)], True)
        >>> np.round(r, 6).tolist(), J.shape
        ([[-0.5, 0.0, -0.2]], (1, 3, 3))
        """
        raise NotImplementedError

    def evaluate_into(self, values: list[Any], out: np.ndarray) -> np.ndarray:
        """The residuals of the batch, with its Jacobians written side by side into ``out``
        (what the solver calls; a subclass may write them there without temporaries).

        Parameters
        ----------
        values : list
            One batch of ``m`` elements (or ``(m, d)`` array for vectors) per argument.
        out : numpy.ndarray
            ``(m, dim, D)`` with ``D`` the sum of the arguments' dofs: receives
            ``[J_1 ... J_K]`` (right Jacobians, as :meth:`evaluate` returns them).

        Returns
        -------
        numpy.ndarray
            ``r`` of shape ``(m, dim)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(2))
        >>> f = BetweenFactor(x, 0, 1, SE2.exp([1.0, 0.0, 0.0]))
        >>> X = [SE2.identity(1), SE2.exp([[0.5, 0.0, 0.3]])]
        >>> J = np.empty((1, 3, 6))
        >>> r = f.evaluate_into(X, J)
        >>> r2, (Ji, Jj) = f.evaluate(X, True)
        >>> bool(np.allclose(r, r2) and np.allclose(J, np.concatenate([Ji, Jj], axis=2)))
        True
        """
        r, Js = self.evaluate(values, True)
        o = 0
        for J in Js:
            k = J.shape[-1]
            out[:, :, o:o + k] = J
            o += k
        return np.asarray(r, dtype=np.float64)

    def __len__(self) -> int:
        return self.count

    def __repr__(self) -> str:
        return f"{type(self).__name__}(count={self.count}, dim={self.dim})"


def _measurement(var: Variables, Z: Any, m: int, what: str) -> Any:
    if var.group is None:
        z = np.asarray(Z, dtype=np.float64)
        if z.shape not in ((var.dof,), (m, var.dof)):
            raise ValueError(f"{what}: vector measurement must have shape ({var.dof},) or "
                             f"({m}, {var.dof}), got {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError(f"{what}: measurement has non-finite entries")
        return np.broadcast_to(z, (m, var.dof)).copy()
    if not isinstance(Z, var.group):
        raise TypeError(f"{what}: measurement must be a {var.group.__name__} "
                        f"(batch of {m} or a single element), got {type(Z).__name__}")
    p = np.asarray(Z.params, dtype=np.float64)
    if p.shape not in ((var.group.param_dim,), (m, var.group.param_dim)):
        raise ValueError(f"{what}: measurement batch shape {Z.batch_shape} for {m} factors")
    return element(var.group, np.broadcast_to(p, (m, var.group.param_dim)).copy())


class PriorFactor(Factor):
    """``r = X_idx (-) Z = Log(Z^-1 X_idx)`` (right minus; ``x - z`` for vectors).

    Parameters
    ----------
    variables : Variables
        The handle.
    idx : int or array_like
        Indices of the constrained variables (``m`` factors).
    Z : LieGroup or array_like
        The prior means: one element or a batch of ``m`` (vectors: ``(d,)`` or ``(m, d)``).
    noise : NoiseModel, optional
        The residual's noise (default :class:`Unit`); one model or one per factor.
    loss : str or RobustLoss, optional
        A robust loss (``"huber:1.0"``, ... see :func:`make_loss`).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2))
    >>> _ = g.add(PriorFactor(x, [0, 1], SE2.exp([1.0, 0.0, 0.5]), Isotropic(3, 0.1)))
    >>> round(g.cost(), 6)  # 0.5 * (1 + 0.25) / 0.01 per factor
    125.0
    """

    jacobians_with_residuals = True

    def __init__(self, variables: Variables, idx: Any, Z: Any, noise: NoiseModel | None = None,
                 loss: RobustLoss | str | None = None) -> None:
        self._setup([(variables, idx)], variables.dof, noise, loss, "PriorFactor")
        self.Z = _measurement(variables, Z, self.count, "PriorFactor")
        if variables.group is not None:
            self._Zinv = self.Z.inverse()

    def evaluate(self, values: list[Any], jac: bool) -> Any:
        (X,) = values
        if self.args[0][0].group is None:
            r = X - self.Z
            if not jac:
                return r
            return r, [np.broadcast_to(np.eye(self.dim), (self.count, self.dim, self.dim))]
        E = self._Zinv.compose(X)
        if not jac:
            return np.asarray(E.log())
        r, J = E.log(jac=True)
        return r, [J]


class BetweenFactor(Factor):
    """The pose-graph edge ``r = (X_i^-1 X_j) (-) Z_ij = Log(Z_ij^-1 X_i^-1 X_j)``
    (``x_j - x_i - z`` for vectors).

    Jacobians (right): ``d r / d X_j = Jr^-1(r)``, ``d r / d X_i = -Jl^-1(r) Ad_(Z^-1)
    = -Jr^-1(r) Ad_((X_i^-1 X_j)^-1)``.

    Parameters
    ----------
    variables : Variables
        The handle of both ends.
    i, j : int or array_like
        Indices of the first and second variable of each edge.
    Z : LieGroup or array_like
        The measured relative poses ``X_i^-1 X_j`` (one or a batch of ``m``).
    noise : NoiseModel, optional
        The residual's noise (default :class:`Unit`); one model or one per factor.
    loss : str or RobustLoss, optional
        A robust loss (``"huber:1.0"``, ... see :func:`make_loss`).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.optim import FactorGraph, BetweenFactor, Diagonal
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE3.identity(2), fixed=[0])
    >>> Z = SE3.exp([1.0, 0, 0, 0, 0, 0.3])
    >>> _ = g.add(BetweenFactor(x, 0, 1, Z, Diagonal([0.1] * 6)))
    >>> res = g.optimize()
    >>> bool(np.allclose(res.values[x][1].matrix(), Z.matrix()))
    True
    """

    jacobians_with_residuals = True

    def __init__(self, variables: Variables, i: Any, j: Any, Z: Any,
                 noise: NoiseModel | None = None, loss: RobustLoss | str | None = None) -> None:
        self._setup([(variables, i), (variables, j)], variables.dof, noise, loss,
                    "BetweenFactor")
        same = self.args[0][1] == self.args[1][1]
        if np.any(same):
            k = int(np.flatnonzero(same)[0])
            raise ValueError(f"BetweenFactor {k}: i == j == {int(self.args[0][1][k])}")
        self.Z = _measurement(variables, Z, self.count, "BetweenFactor")
        if variables.group is not None:
            # r = Log((X_i Z)^-1 X_j) = X_j (-) (X_i Z): one fused minus with its Jacobians;
            # d r / d X_i = d r / d (X_i Z) . Ad_(Z^-1), a constant of the factor
            self._Ad_Zinv = np.ascontiguousarray(self.Z.inverse().adjoint())

    def evaluate(self, values: list[Any], jac: bool) -> Any:
        Xi, Xj = values
        if self.args[0][0].group is None:
            r = Xj - Xi - self.Z
            if not jac:
                return r
            eye = np.broadcast_to(np.eye(self.dim), (self.count, self.dim, self.dim))
            return r, [-eye, eye]
        if not jac:
            return np.asarray(Xj.minus(Xi.compose(self.Z)))
        d = self.dim
        out = np.empty((self.count, d, 2 * d))
        r = self.evaluate_into(values, out)
        return r, [out[:, :, :d], out[:, :, d:]]

    def evaluate_into(self, values: list[Any], out: np.ndarray) -> np.ndarray:
        if self.args[0][0].group is None:
            return super().evaluate_into(values, out)
        Xi, Xj = values
        r, Jj, Jc = Xj.minus(Xi.compose(self.Z), jac=True)
        d = self.dim
        # Jc (component-major from the kernel) copied row-major into the second half first:
        # the product then runs on contiguous rows (measured 2-3x faster than on Jc itself)
        np.copyto(out[:, :, d:], Jc)
        np.matmul(out[:, :, d:], self._Ad_Zinv, out=out[:, :, :d])
        out[:, :, d:] = Jj
        return np.asarray(r, dtype=np.float64)


class CustomFactor(Factor):
    """A factor from a user function ``fn(*elements, *data) -> residuals (m, dim)``.

    ``fn`` receives one batch of ``m`` elements (or ``(m, d)`` arrays for vectors) per
    argument, then the arrays in ``data`` (each with ``m`` rows).

    Parameters
    ----------
    fn : callable
        The residual function.
    args : sequence of (Variables, indices)
        One pair per argument of ``fn``.
    dim : int
        The residual dimension.
    noise : NoiseModel, optional
        The residual's noise (default :class:`Unit`).
    data : sequence of array_like
        Extra per-factor arrays passed after the elements.
    jac : {"numerical", "analytic", "jax", "torch"}
        * ``"numerical"`` (default): central differences in the tangent space of each argument
          (``X Exp(+-h e_a)``), step ``h = step``;
        * ``"analytic"``: ``fn`` returns ``(r, [J_1, ..., J_K])`` with ``J_k`` of shape
          ``(m, dim, dof_k)``, right Jacobians (``d r / d delta`` for ``X_k Exp(delta)``);
        * ``"jax"`` / ``"torch"``: automatic differentiation through that backend (imported
          only then); ``fn`` must use microlie group operations or the backend's array
          functions.
    step : float
        The numerical-difference step.
    loss : str or RobustLoss, optional
        A robust loss.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, CustomFactor, Isotropic
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> def gps(X, z):  # position of the pose minus a measured position
    ...     return X.params[..., :2] - z
    >>> z = np.array([[1.0, 2.0]])
    >>> _ = g.add(CustomFactor(gps, [(x, 0)], 2, Isotropic(2, 1.0), data=[z]))
    >>> round(g.cost(), 6)
    2.5
    """

    def __init__(self, fn: Callable[..., Any], args: Sequence[tuple[Variables, Any]], dim: int,
                 noise: NoiseModel | None = None, *, data: Sequence[Any] = (),
                 jac: str = "numerical", step: float = 1e-6,
                 loss: RobustLoss | str | None = None) -> None:
        self._setup(list(args), dim, noise, loss, "CustomFactor")
        if jac not in ("numerical", "analytic", "jax", "torch"):
            raise ValueError(f"CustomFactor: jac must be 'numerical', 'analytic', 'jax' or "
                             f"'torch', got {jac!r}")
        self.fn = fn
        self.mode = jac
        self.step = float(step)
        self.data = []
        for k, d in enumerate(data):
            a = np.asarray(d)
            if a.shape[:1] == (1,) and self.count != 1:
                a = np.broadcast_to(a, (self.count, *a.shape[1:]))
            if a.ndim == 0 or a.shape[0] != self.count:
                raise ValueError(f"CustomFactor: data[{k}] must have {self.count} rows, got "
                                 f"shape {a.shape}")
            self.data.append(a)
        self._ad: Callable[[list[Any], bool], Any] | None = None

    def _residual(self, values: list[Any]) -> np.ndarray:
        r = np.asarray(self.fn(*values, *self.data), dtype=np.float64)
        if r.shape != (self.count, self.dim):
            raise ValueError(f"CustomFactor: fn returned shape {r.shape}, expected "
                             f"({self.count}, {self.dim})")
        return r

    def evaluate(self, values: list[Any], jac: bool) -> Any:
        if self.mode == "analytic":
            out = self.fn(*values, *self.data)
            if not (isinstance(out, tuple) and len(out) == 2):
                raise ValueError("CustomFactor(jac='analytic'): fn must return (r, [J_1, ...])")
            r = np.asarray(out[0], dtype=np.float64)
            if not jac:
                return r
            Js = [np.asarray(J, dtype=np.float64) for J in out[1]]
            for (var, _), J in zip(self.args, Js, strict=False):
                if J.shape != (self.count, self.dim, var.dof):
                    raise ValueError(f"CustomFactor: Jacobian of shape {J.shape}, expected "
                                     f"({self.count}, {self.dim}, {var.dof})")
            return r, Js
        if self.mode == "numerical":
            r = self._residual(values)
            return (r, self._numerical(values)) if jac else r
        if self._ad is None:
            self._ad = _make_autodiff(self)
        return self._ad(values, jac)

    def _numerical(self, values: list[Any]) -> list[np.ndarray]:
        h = self.step
        Js = []
        for k, (var, _) in enumerate(self.args):
            J = np.empty((self.count, self.dim, var.dof))
            p = values[k] if var.group is None else np.asarray(values[k].params)
            for a in range(var.dof):
                d = np.zeros((self.count, var.dof))
                d[:, a] = h
                vp, vm = list(values), list(values)
                vp[k] = var.wrap(var.retract(p, d))
                vm[k] = var.wrap(var.retract(p, -d))
                J[:, :, a] = (self._residual(vp) - self._residual(vm)) / (2 * h)
            Js.append(J)
        return Js


def _parts(factor: CustomFactor, values: list[Any]) -> list[np.ndarray]:
    return [np.asarray(v if var.group is None else v.params)
            for (var, _), v in zip(factor.args, values, strict=False)]


def _make_autodiff(factor: CustomFactor) -> Callable[[list[Any], bool], Any]:
    """The residuals and Jacobians of ``factor`` by JAX or torch (:mod:`microlie._autodiff`):
    ``fn`` of the perturbed arguments ``X_k Exp(delta_k)`` (``x + delta`` for vectors)."""
    groups = [var.group for var, _ in factor.args]

    def f(deltas, params, data):
        vals = [p + d if G is None else element(G, p).plus(d)
                for G, d, p in zip(groups, deltas, params, strict=True)]
        return factor.fn(*vals, *data)

    run = _autodiff.residual_jacobians(factor.mode, f, [var.dof for var, _ in factor.args],
                                       factor.count, factor.dim)
    return lambda values, jac: run(_parts(factor, values), factor.data, jac)
