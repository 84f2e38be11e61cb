"""Factors: batches of residuals of the same form, evaluated in one call per batch.

Every factor batch holds ``m`` residuals of dimension ``dim`` over ``K`` arguments; argument
``k`` is a :class:`Variables` handle and ``m`` indices into it. A factor type is a subclass of
:class:`Factor` that implements one method, :meth:`Factor.residual`: it receives one batch of
``m`` values per argument and returns the residuals ``(m, dim)`` and, when asked, one Jacobian
``(m, dim, dof_k)`` per argument with respect to the right perturbation of that argument
(``X_k Exp(delta_k)``, tangents translation first; ``x + delta`` for vectors). The graph does
the rest: shape checks (:meth:`Factor.evaluate`), whitening by the noise model, the robust
loss, assembly. :func:`check_jacobians` compares a factor's Jacobians with central
differences on the group.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, final

import numpy as np

from ... import _autodiff, _fast
from ... import groups as _groups
from ..._array import is_device_array, is_host_array
from .noise import NoiseModel, as_noise
from .robust import RobustLoss, corrected_weights, make_loss
from .variables import Values, Variables, VectorVariables, element, host_params

__all__ = ["Factor", "PriorFactor", "BetweenFactor", "CustomFactor", "check_jacobians",
           "JacobianCheck"]

# (factor class, argument count) whose residual signature was checked (inspect is ~0.1 ms a call)
_SIGNATURE_OK: set[tuple[type, int]] = set()

# BetweenFactor and PriorFactor batches of at most this many rows are evaluated row by row by
# the compiled module _factors (one call, no NumPy temporaries: what a factor that arrives alone
# costs); larger batches take the batched group kernels (evaluate_into, SE2 / SE3: the rows
# cost 0.10-0.23x the batched path at 1-16 rows, 0.35-0.53x at 64, 0.8-1.0x at 256, 1.3-1.7x
# from 1024; benchmarks/single_factor.py --threshold, results/single_factor-s10.md)
SMALL_BATCH = 64
_F64 = np.dtype(np.float64)
_row_groups: dict[type, int] = {}


def _row_kernels(group: type, shape: tuple[int, int], *params: Any) -> Any:
    """The compiled row module and the index of ``group`` in it, when it handles ``group`` and
    every array of ``params`` is a float64 NumPy array of ``shape``; else ``None`` (the caller
    takes the batched path)."""
    for p in params:
        if type(p) is not np.ndarray or p.dtype is not _F64 or p.shape != shape:
            return None
    mod = _fast.module("_factors")
    if mod is None:
        return None
    if not _row_groups:
        _row_groups.update({getattr(_groups, n): k for k, n in enumerate(mod.GROUPS)})
    g = _row_groups.get(group)
    return None if g is None else (mod, g)


def _params(var: Variables, X: Any) -> Any:
    """The parameters of ``X`` if it is an element of ``var``'s group, else ``None``."""
    return X.params if isinstance(X, var.group) else None


def _finite(a: np.ndarray) -> bool:
    """Whether every entry of the float array ``a`` is finite (Python floats for small ones:
    one NumPy reduction costs more than the loop)."""
    if a.size <= 64:
        return all(map(math.isfinite, a.ravel().tolist()))
    return bool(np.isfinite(a).all())


class Factor:
    """Base class of factor batches: subclass it to write a factor with analytic Jacobians.

    A subclass calls ``super().__init__(args, dim, noise, loss)`` and implements
    :meth:`residual`; the graph checks the shapes it returns (:meth:`evaluate`, errors name the
    class), whitens the residuals and Jacobians with ``noise``, applies ``loss`` (Ceres' rules)
    and assembles every batch into the normal equations. ``check_jacobians(factor)`` compares
    the Jacobians with finite differences on the group.

    Parameters
    ----------
    args : sequence of (Variables, indices)
        One pair per argument: a handle from :meth:`FactorGraph.add_variables` and the indices
        of the ``m`` variables it takes (an int, an array of ``m`` or a boolean mask). A single
        index is repeated to the length of the others.
    dim : int
        The residual dimension.
    noise : NoiseModel, optional
        The residual's noise (default :class:`Unit`); one model or one per factor.
    loss : str or RobustLoss, optional
        A robust loss (``"huber:1.0"``, ... see :func:`make_loss`).

    Attributes
    ----------
    args : list of (Variables, numpy.ndarray)
        The arguments, with ``m`` int64 indices each.
    count : int
        ``m``, the number of factors in the batch (also ``len(factor)``).
    dim : int
        The residual dimension.
    noise : NoiseModel
        The noise model.
    loss : RobustLoss or None
        The robust loss.
    name : str
        The class name, used in messages.
    jacobians_with_residuals : bool
        Class attribute: ``True`` when :meth:`residual` with Jacobians costs little more than
        without (a solver then evaluates them at a trial point already, for the linearisation
        that follows). Default ``False``.

    Examples
    --------
    A range measurement ``r = |l_j - t_i| - z`` between SE(2) poses and 2-D landmarks:

    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import Factor, FactorGraph, check_jacobians
    >>> class Range(Factor):
    ...     def __init__(self, poses, i, points, j, z, noise=None):
    ...         super().__init__([(poses, i), (points, j)], 1, noise)
    ...         self.z = self.per_factor(z, "z").reshape(-1, 1)
    ...     def residual(self, X, p, jac=False):
    ...         d = p - X.translation()
    ...         n = np.linalg.norm(d, axis=1, keepdims=True)
    ...         if not jac:
    ...             return n - self.z
    ...         u = (d / n)[:, None, :]  # d r / d p
    ...         dt = np.concatenate([X.rotation().matrix(), np.zeros((len(n), 2, 1))], 2)
    ...         return n - self.z, [-u @ dt, u]  # d t / d delta = [R 0] (right, t first)
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_xy_theta([0.0, 1.0], [0.0, 0.0], [0.3, -0.2]))
    >>> p = g.add_variables(np.array([[3.0, 4.0]]))
    >>> f = g.add(Range(x, [0, 1], p, 0, [5.0, 4.5]))
    >>> np.round(f.evaluate([x.wrap(x.initial), p.initial[[0, 0]]], False), 6).tolist()
    [[0.0], [-0.027864]]
    >>> check_jacobians(f).ok
    True
    """

    args: list[tuple[Variables, np.ndarray]]
    jacobians_with_residuals: bool = False
    count: int
    dim: int
    noise: NoiseModel
    loss: RobustLoss | None
    name: str

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "evaluate" in vars(cls):
            raise TypeError(f"{cls.__name__}: a Factor subclass implements residual(*values, "
                            f"jac=False), not evaluate (the graph's checked call of residual)")

    def __init__(self, args: Sequence[tuple[Variables, Any]], dim: int,
                 noise: NoiseModel | None = None, loss: RobustLoss | str | None = None) -> None:
        what = self.name = type(self).__name__
        if type(self).residual is Factor.residual:
            raise TypeError(f"{what}: a Factor subclass must implement residual(*values, "
                            f"jac=False)")
        checked: list[tuple[Variables, np.ndarray]] = []
        m = None
        for k, pair in enumerate(args):
            if not (isinstance(pair, tuple | list) and len(pair) == 2):
                raise ValueError(f"{what}: argument {k} must be a pair (Variables, indices), "
                                 f"got {type(pair).__name__}")
            var, idx = pair
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
            raise ValueError(f"{what}: no factors (no arguments or an empty index array)")
        graphs = {id(v.graph) for v, _ in checked}
        if len(graphs) != 1:
            raise ValueError(f"{what}: arguments belong to different graphs")
        sig_key = (type(self), len(checked))
        if sig_key not in _SIGNATURE_OK or "residual" in vars(self):
            try:
                inspect.signature(self.residual).bind(*checked, jac=False)
            except TypeError as e:
                raise TypeError(f"{what}: residual must take one value per argument "
                                f"({len(checked)}) and the keyword jac: {e}") from None
            if "residual" not in vars(self):  # checked once per class and argument count
                _SIGNATURE_OK.add(sig_key)
        if int(dim) != dim or dim < 1:
            raise ValueError(f"{what}: dim must be a positive integer, got {dim!r}")
        self.args = checked
        self.count = int(m)
        self.dim = int(dim)
        self.noise = as_noise(noise, self.dim, what)
        L = self.noise.sqrt_info
        if L.ndim == 3 and L.shape[0] not in (1, self.count):
            raise ValueError(f"{what}: {L.shape[0]} noise matrices for {self.count} factors")
        self.loss = make_loss(loss)

    def residual(self, *values: Any, **kwargs: Any) -> Any:
        """The residuals of the batch and, with ``jac=True``, their Jacobians: the one method
        a subclass implements (the graph calls it through :meth:`evaluate`).

        Parameters
        ----------
        *values : LieGroup or numpy.ndarray
            One value per argument, in the order of ``args``: a batch of ``m`` elements of the
            argument's group, or an ``(m, d)`` array for vector variables.

        Other Parameters
        ----------------
        jac : bool
            Keyword (the one ``**kwargs`` takes; a subclass declares it ``jac=False``): also
            return the Jacobians (default ``False``).

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` of shape ``(m, dim)``; with ``jac``, ``(r, [J_1, ..., J_K])`` with ``J_k`` of
            shape ``(m, dim, dof_k)``: ``d r / d delta_k`` for the right perturbation
            ``X_k Exp(delta_k)`` (tangent translation first, as the groups' ``exp``; ``x +
            delta`` for vectors). A constant Jacobian may be a read-only
            ``numpy.broadcast_to`` view.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> g = FactorGraph()
        >>> f = PriorFactor(g.add_variables(SE2.identity(1)), 0, SE2.exp([0.5, 0.0, 0.2]))
        >>> r, (J,) = f.residual(SE2.identity(1), jac=True)
        >>> np.round(r, 6).tolist(), J.shape
        ([[-0.5, 0.0, -0.2]], (1, 3, 3))
        """
        raise NotImplementedError(f"{self.name}: a Factor subclass must implement "
                                  f"residual(*values, jac=False)")

    @final
    def evaluate(self, values: Sequence[Any], jac: bool) -> Any:
        """:meth:`residual` with its output checked: what the graph, the solver and
        :func:`check_jacobians` call (a subclass implements :meth:`residual`, not this).

        Parameters
        ----------
        values : sequence
            One batch of ``m`` elements (or ``(m, d)`` array for vectors) per argument.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r``, float64 ``(m, dim)``; with ``jac``, ``(r, [J_1, ..., J_K])``, float64
            ``J_k`` of shape ``(m, dim, dof_k)`` (see :meth:`residual`).

        Raises
        ------
        ValueError
            The residual or a Jacobian has the wrong shape or form (the message names the
            class and the argument).

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
        what, m, K = self.name, self.count, len(self.args)
        if len(values) != K:
            raise ValueError(f"{what}: {len(values)} values for {K} arguments")
        out = self.residual(*values, jac=jac)
        if not jac:
            if isinstance(out, tuple):
                raise ValueError(f"{what}.residual(..., jac=False) must return the residuals "
                                 f"alone, got a tuple")
            return self._checked_residuals(out)
        if not (isinstance(out, tuple) and len(out) == 2 and isinstance(out[1], list | tuple)):
            raise ValueError(f"{what}.residual(..., jac=True) must return (r, [J_1, ..., J_{K}])"
                             f", got {type(out).__name__}")
        r, Js = out
        if len(Js) != K:
            raise ValueError(f"{what}.residual returned {len(Js)} Jacobians for {K} arguments")
        checked = []
        for k, ((var, _), J) in enumerate(zip(self.args, Js, strict=True)):
            J = np.asarray(J, dtype=np.float64)
            if J.shape != (m, self.dim, var.dof):
                raise ValueError(f"{what}.residual: Jacobian {k} (argument {var.name}) has shape "
                                 f"{J.shape}, expected ({m}, {self.dim}, {var.dof}) = (factors, "
                                 f"residual dim, the argument's dof)")
            checked.append(J)
        return self._checked_residuals(r), checked

    def _checked_residuals(self, r: Any) -> np.ndarray:
        r = np.asarray(r, dtype=np.float64)
        if r.shape != (self.count, self.dim):
            raise ValueError(f"{self.name}.residual returned residuals of shape {r.shape}, "
                             f"expected ({self.count}, {self.dim}) = (factors, residual dim)")
        return r

    def evaluate_into(self, values: Sequence[Any], out: np.ndarray) -> np.ndarray:
        """The residuals of the batch, with its Jacobians written side by side into ``out``
        (what the solver's linearisation calls; a subclass may override it to write them
        there without temporaries).

        Parameters
        ----------
        values : sequence
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
        return r

    def linearize(self, params: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
        """The whitened linear system of the batch at ``params``: ``e = L r`` and ``A = L [J_1
        ... J_K]``, with the robust loss's correction (Ceres' rule, as the solver) when the
        factor has one; what an incremental solver adds for the factor (``A^T A`` and
        ``A^T e``).

        One call for the whole batch; :class:`BetweenFactor` and :class:`PriorFactor` batches
        of up to :data:`SMALL_BATCH` rows run in one compiled call (float64 NumPy parameters,
        with the compiled kernels), every other factor through :meth:`evaluate` (checked).

        Parameters
        ----------
        params : sequence of numpy.ndarray
            One ``(m, param_dim)`` parameter array per argument (``(m, d)`` for vectors): the
            rows of the argument's variables, e.g. ``values.params(var)[idx]``.

        Returns
        -------
        e : numpy.ndarray
            ``(m, dim)`` whitened (and robustly scaled) residuals; ``0.5 |e|^2`` is the cost
            without a loss.
        A : numpy.ndarray
            ``(m, dim, D)`` whitened Jacobians side by side, ``D`` the sum of the arguments'
            dofs (right Jacobians, as :meth:`evaluate`).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import BetweenFactor, FactorGraph, Isotropic
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(2))
        >>> f = BetweenFactor(x, 0, 1, SE2.exp([1.0, 0.0, 0.0]), Isotropic(3, 0.5))
        >>> e, A = f.linearize([x.initial[[0]], x.initial[[1]]])
        >>> e.tolist(), A.shape
        ([[-2.0, 0.0, 0.0]], (1, 3, 6))
        >>> r, (Ji, Jj) = f.evaluate([SE2.identity(1), SE2.identity(1)], True)
        >>> bool(np.allclose(A, 2.0 * np.concatenate([Ji, Jj], axis=2)))
        True
        """
        if len(params) != len(self.args):
            raise ValueError(f"{self.name}.linearize: {len(params)} parameter arrays for "
                             f"{len(self.args)} arguments")
        sc = self.noise.scales
        d = self.dim
        L = sc.reshape(-1, d) if sc is not None else self.noise.sqrt_info.reshape(-1, d, d)
        out = self._rows(params, L)
        if out is None:
            vals = [var.wrap(p) for (var, _), p in zip(self.args, params, strict=True)]
            r, Js = self.evaluate(vals, True)
            if sc is not None:
                e = r * sc
                A = np.concatenate(Js, axis=2) * sc[..., :, None]
            else:
                A = np.matmul(self.noise.sqrt_info, np.concatenate(Js, axis=2))
                e = np.matmul(self.noise.sqrt_info, r[:, :, None])[:, :, 0]
        else:
            e, A = out
        if self.loss is not None:
            s = np.einsum("mi,mi->m", e, e)
            _, scale, aos = corrected_weights(self.loss, s)
            sq = np.sqrt(np.maximum(self.loss.evaluate(s)[1], 0.0))
            eA = np.einsum("mi,mij->mj", e, A)
            A = sq[:, None, None] * (A - (aos[:, None] * e)[:, :, None] * eA[:, None, :])
            e = e * scale[:, None]
        return e, A

    def _rows(self, params: Sequence[Any], L: np.ndarray | None
              ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(L r, L [J_1 ... J_K])`` from a compiled row loop (``L`` ``(1 or m, d)`` scales,
        ``(1 or m, d, d)`` matrices or ``None``), or ``None`` where there is none for these
        parameters (the caller evaluates the batch). Only :class:`BetweenFactor` and
        :class:`PriorFactor` have one."""
        return None

    def per_factor(self, data: Any, name: str) -> np.ndarray:
        """``data`` as one row per factor of the batch (a measurement, a constant): an array
        of ``m`` rows is kept, a scalar or a single row is repeated.

        Parameters
        ----------
        data : array_like
            A scalar, ``(m, ...)`` or ``(1, ...)``.
        name : str
            Its name, for the error message.

        Returns
        -------
        numpy.ndarray
            An ``(m, ...)`` copy.

        Raises
        ------
        ValueError
            Another number of rows, or non-finite floats (the message names the class and
            ``name``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> g = FactorGraph()
        >>> f = PriorFactor(g.add_variables(SE2.identity(3)), [0, 1, 2], SE2.identity())
        >>> f.per_factor(2.0, "z").tolist(), f.per_factor([[1.0, 2.0]], "z").shape
        ([2.0, 2.0, 2.0], (3, 2))
        """
        a = np.array(data)
        if a.ndim == 0 or (a.shape[0] == 1 and self.count != 1):
            a = np.broadcast_to(a, (self.count, *a.shape[1:]))
        if a.shape[0] != self.count:
            raise ValueError(f"{self.name}: {name} must have {self.count} rows (one per factor) "
                             f"or 1, got shape {a.shape}")
        if np.issubdtype(a.dtype, np.inexact) and not np.all(np.isfinite(a)):
            raise ValueError(f"{self.name}: {name} has non-finite entries")
        return np.array(a, order="C")  # the factor's own copy

    def __len__(self) -> int:
        return self.count

    def __repr__(self) -> str:
        return f"{type(self).__name__}(count={self.count}, dim={self.dim})"


def _measurement(var: Variables, Z: Any, m: int, what: str) -> Any:
    """``Z`` as ``m`` values of ``var``'s kind (a group batch, an ``(m, d)`` array for
    vectors). A group's measurement may also be given by its parameters, a NumPy array
    ``(param_dim,)`` or ``(m, param_dim)``, checked as the group's constructor does (unit
    quaternions, ...)."""
    pd = var.group.param_dim
    if is_host_array(Z) and not isinstance(var, VectorVariables):
        if Z.shape not in ((pd,), (m, pd)):
            raise ValueError(f"{what}: measurement parameters must have shape ({pd},) or "
                             f"({m}, {pd}), got {Z.shape}")
        try:
            Z = var.group(Z)
        except ValueError as e:
            raise ValueError(f"{what}: measurement: {e}") from None
    try:
        p = np.asarray(host_params(var.params_of(Z), var.group), dtype=np.float64)
    except TypeError:
        raise TypeError(f"{what}: measurement must be a {var.group.__name__} (batch of {m} or "
                        f"a single element) or its parameters, got {type(Z).__name__}") from None
    if p.shape not in ((pd,), (m, pd)):
        raise ValueError(f"{what}: measurement must have parameters of shape ({pd},) or "
                         f"({m}, {pd}), got {p.shape}")
    if not _finite(p):
        raise ValueError(f"{what}: measurement has non-finite entries")
    if p.ndim == 1:
        p = p.reshape(1, pd) if m == 1 else np.repeat(p.reshape(1, pd), m, axis=0)
    if isinstance(var, VectorVariables):
        return np.array(p, order="C")  # the factor's own copy
    return var.wrap(p)  # a group element copies the caller's array (from_params)


def measurement_source(var: Variables, Z: Any) -> Any:
    """The torch tensor or JAX array of measurement ``Z``'s parameters (kept for the device
    engine, which solves with it and differentiates through it), or ``None``."""
    if is_host_array(Z):  # NumPy parameters (:func:`_measurement`)
        return None
    p = var.params_of(Z)
    return p if is_device_array(p) else None


class PriorFactor(Factor):
    """``r = X_idx (-) Z = Log(Z^-1 X_idx)`` (right minus; ``x - z`` for vectors).

    Jacobian (right): ``d r / d X = Jr^-1(r)`` (the identity for vectors).

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
        super().__init__([(variables, idx)], variables.dof, noise, loss)
        self.Z = _measurement(variables, Z, self.count, self.name)
        self.Z_source = measurement_source(variables, Z)
        self._Zinv: Any = None  # Z^-1 for the batched path, made on first use

    def residual(self, X: Any, jac: bool = False) -> Any:
        """``r = Log(Z^-1 X)`` and, with ``jac``, ``[Jr^-1(r)]`` (:meth:`Factor.residual`).

        Parameters
        ----------
        X : LieGroup or numpy.ndarray
            The batch of ``m`` constrained values.
        jac : bool
            Also return the Jacobian.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` ``(m, dof)``, or ``(r, [J])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> g = FactorGraph()
        >>> f = PriorFactor(g.add_variables(SO2.identity(1)), 0, SO2.exp([0.25]))
        >>> r, (J,) = f.residual(SO2.exp([[1.0]]), jac=True)
        >>> np.round(r, 12).tolist(), J.tolist()
        ([[0.75]], [[[1.0]]])
        """
        var = self.args[0][0]
        if self.count <= SMALL_BATCH:
            out = self._rows([_params(var, X)], None)
            if out is not None:
                return (out[0], [out[1]]) if jac else out[0]
        if self._Zinv is None:
            self._Zinv = var.inverse(self.Z)
        E = var.compose(self._Zinv, X)
        if not jac:
            return var.log(E)
        r, J = var.log(E, jac=True)
        return r, [J]

    def _rows(self, params: Sequence[Any], L: np.ndarray | None
              ) -> tuple[np.ndarray, np.ndarray] | None:
        var = self.args[0][0]
        (p,) = params
        m, d = self.count, self.dim
        rk = _row_kernels(var.group, (m, var.group.param_dim), p) if m <= SMALL_BATCH else None
        if rk is None:
            return None
        r, J = np.empty((m, d)), np.empty((m, d, d))
        rk[0].prior(rk[1], p, self.Z.params, L, r, J)
        return r, J


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
        super().__init__([(variables, i), (variables, j)], variables.dof, noise, loss)
        ii, jj = self.args[0][1], self.args[1][1]
        if self.count <= SMALL_BATCH:  # Python ints: cheaper than two NumPy calls
            pairs = zip(ii.tolist(), jj.tolist(), strict=True)
            same = [k for k, (a, b) in enumerate(pairs) if a == b]
        else:
            same = np.flatnonzero(ii == jj).tolist()
        if same:
            raise ValueError(f"BetweenFactor {same[0]}: i == j == {int(ii[same[0]])}")
        self.Z = _measurement(variables, Z, self.count, self.name)
        self.Z_source = measurement_source(variables, Z)
        self._Ad: Any = False  # Ad_(Z^-1) of the batched path, made on first use (_ad_zinv)

    def _ad_zinv(self) -> np.ndarray | None:
        """``Ad_(Z^-1)``, ``(m, d, d)``, or ``None`` when every one is the identity."""
        if self._Ad is False:
            # r = Log((X_i Z)^-1 X_j) = X_j (-) (X_i Z): one fused minus with its Jacobians;
            # d r / d X_i = d r / d (X_i Z) . Ad_(Z^-1), a constant of the factor
            # (None when every Ad_(Z^-1) is the identity, as in the abelian groups R(d) and
            # SO2: then d r / d X_i = d r / d (X_i Z), no product)
            var = self.args[0][0]
            Zinv = element(var.group, var.params_of(self.Z)).inverse()
            Ad = np.ascontiguousarray(Zinv.adjoint())
            eye = np.eye(self.dim)
            ident = (Ad.reshape(-1, self.dim, self.dim)[0] == eye).all() and (Ad == eye).all()
            self._Ad = None if ident else Ad
        return self._Ad  # type: ignore[no-any-return]

    def residual(self, Xi: Any, Xj: Any, jac: bool = False) -> Any:
        """``r = Log((X_i Z)^-1 X_j)`` and, with ``jac``, ``[d r / d X_i, d r / d X_j]``
        (:meth:`Factor.residual`).

        Parameters
        ----------
        Xi, Xj : LieGroup or numpy.ndarray
            The batches of first and second ends.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` ``(m, dof)``, or ``(r, [J_i, J_j])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> g = FactorGraph()
        >>> f = BetweenFactor(g.add_variables(SO2.identity(2)), 0, 1, SO2.exp([0.25]))
        >>> r, (Ji, Jj) = f.residual(SO2.exp([[0.5]]), SO2.exp([[1.0]]), jac=True)
        >>> np.round(r, 12).tolist(), Ji.tolist(), Jj.tolist()
        ([[0.25]], [[[-1.0]]], [[[1.0]]])
        """
        var = self.args[0][0]
        d = self.dim
        if not jac:
            if self.count <= SMALL_BATCH:
                out = self._rows([_params(var, Xi), _params(var, Xj)], None)
                if out is not None:
                    return out[0]
            return var.minus(Xj, var.compose(Xi, self.Z))
        J = np.empty((self.count, d, 2 * d))
        r = self._fill(Xi, Xj, J)
        return r, [J[:, :, :d], J[:, :, d:]]

    def evaluate_into(self, values: Sequence[Any], out: np.ndarray) -> np.ndarray:
        Xi, Xj = values
        return self._fill(Xi, Xj, out)

    def _rows(self, params: Sequence[Any], L: np.ndarray | None,
              out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        var = self.args[0][0]
        pi, pj = params
        m, d = self.count, self.dim
        rk = (_row_kernels(var.group, (m, var.group.param_dim), pi, pj)
              if m <= SMALL_BATCH else None)
        if rk is None or (out is not None and out.dtype is not _F64):
            return None
        r = np.empty((m, d))
        J = np.empty((m, d, 2 * d)) if out is None else out
        rk[0].between(rk[1], pi, pj, self.Z.params, L, r, J)
        return r, J

    def _fill(self, Xi: Any, Xj: Any, out: np.ndarray) -> np.ndarray:
        """The residuals, with ``[J_i J_j]`` written into ``out`` ``(m, d, 2 d)``."""
        var = self.args[0][0]
        if self.count <= SMALL_BATCH:
            done = self._rows([_params(var, Xi), _params(var, Xj)], None, out)
            if done is not None:
                return done[0]
        r, Jj, Jc = var.minus(Xj, var.compose(Xi, self.Z), jac=True)
        d = self.dim
        Ad = self._ad_zinv()
        # Jc (component-major from the kernel) copied row-major into the second half first:
        # the product then runs on contiguous rows (measured 2-3x faster than on Jc itself)
        if Ad is None:
            np.copyto(out[:, :, :d], Jc)
        else:
            np.copyto(out[:, :, d:], Jc)
            np.matmul(out[:, :, d:], Ad, out=out[:, :, :d])
        out[:, :, d:] = Jj
        return np.asarray(r, dtype=np.float64)


def _numerical_jacobians(fn: Callable[[list[Any]], np.ndarray],
                         args: Sequence[tuple[Variables, Any]], values: Sequence[Any],
                         step: float) -> list[np.ndarray]:
    """Central differences of ``fn(values) -> (m, dim)`` in the tangent of each argument:
    column ``a`` of ``J_k`` is ``(fn(.. X_k Exp(h e_a) ..) - fn(.. X_k Exp(-h e_a) ..)) / 2h``
    (``x +- h e_a`` for vectors), every row of the batch at once."""
    Js = []
    for k, (var, _) in enumerate(args):
        p = np.asarray(var.params_of(values[k]))
        cols = []
        for a in range(var.dof):
            d = np.zeros((p.shape[0], var.dof), dtype=p.dtype)
            d[:, a] = step
            vp, vm = list(values), list(values)
            vp[k] = var.wrap(var.retract(p, d))
            vm[k] = var.wrap(var.retract(p, -d))
            cols.append((np.asarray(fn(vp), dtype=np.float64)
                         - np.asarray(fn(vm), dtype=np.float64)) / (2 * step))
        Js.append(np.stack(cols, axis=-1))
    return Js


class CustomFactor(Factor):
    """A factor from a user function ``fn(*elements, *data) -> residuals (m, dim)``.

    ``fn`` receives one batch of ``m`` elements (or ``(m, d)`` arrays for vectors) per
    argument, then the arrays in ``data`` (each with ``m`` rows). For a factor type of your
    own with analytic Jacobians, subclass :class:`Factor` instead.

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
        Extra per-factor arrays passed after the elements (``m`` rows, or one row repeated).
    jac : {"numerical", "analytic", "jax", "torch"}
        * ``"numerical"`` (default): central differences in the tangent space of each argument
          (``X Exp(+-h e_a)``), step ``h = step``;
        * ``"analytic"``: ``fn`` returns ``(r, [J_1, ..., J_K])`` with ``J_k`` of shape
          ``(m, dim, dof_k)``, right Jacobians (``d r / d delta`` for ``X_k Exp(delta)``);
        * ``"jax"`` / ``"torch"``: automatic differentiation through that backend (imported
          only then); ``fn`` must use microlie group operations or the backend's array
          functions. ``"jax"`` needs ``jax_enable_x64`` on (``ValueError`` otherwise; the
          program sets it: microlie never changes it).
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
        super().__init__(args, dim, noise, loss)
        if jac not in ("numerical", "analytic", "jax", "torch"):
            raise ValueError(f"CustomFactor: jac must be 'numerical', 'analytic', 'jax' or "
                             f"'torch', got {jac!r}")
        if not step > 0:
            raise ValueError(f"CustomFactor: step must be positive, got {step!r}")
        if jac in _autodiff.BACKENDS:
            _autodiff.check_backend(jac, f"CustomFactor(jac={jac!r})")
        self.fn = fn
        self.mode = jac
        self.step = float(step)
        self.data = [self.per_factor(d, f"data[{k}]") for k, d in enumerate(data)]
        self._ad: Callable[[list[Any], bool], Any] | None = None

    def _residual(self, values: Sequence[Any]) -> np.ndarray:
        r = np.asarray(self.fn(*values, *self.data), dtype=np.float64)
        if r.shape != (self.count, self.dim):
            raise ValueError(f"CustomFactor: fn returned shape {r.shape}, expected "
                             f"({self.count}, {self.dim})")
        return r

    def residual(self, *values: Any, jac: bool = False) -> Any:
        """``fn``'s residuals and, with ``jac``, their Jacobians by the factor's ``jac`` mode
        (:meth:`Factor.residual`).

        Parameters
        ----------
        *values : LieGroup or numpy.ndarray
            One batch per argument.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` ``(m, dim)``, or ``(r, [J_1, ..., J_K])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import CustomFactor, FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> f = CustomFactor(lambda v: v ** 2, [(x, 0)], 2)
        >>> r, (J,) = f.residual(np.array([[1.0, 2.0]]), jac=True)
        >>> r.tolist(), np.round(J, 6).tolist()
        ([[1.0, 4.0]], [[[2.0, 0.0], [0.0, 4.0]]])
        """
        if self.mode == "analytic":
            out = self.fn(*values, *self.data)
            if not (isinstance(out, tuple) and len(out) == 2):
                raise ValueError("CustomFactor(jac='analytic'): fn must return (r, [J_1, ...])")
            return out if jac else out[0]
        if self.mode == "numerical":
            r = self._residual(values)
            if not jac:
                return r
            return r, _numerical_jacobians(self._residual, self.args, values, self.step)
        if self._ad is None:
            self._ad = _make_autodiff(self)
        return self._ad(list(values), jac)


def _parts(factor: CustomFactor, values: list[Any]) -> list[np.ndarray]:
    return [np.asarray(var.params_of(v)) for (var, _), v in zip(factor.args, values, strict=False)]


def _make_autodiff(factor: CustomFactor) -> Callable[[list[Any], bool], Any]:
    """The residuals and Jacobians of ``factor`` by JAX or torch (:mod:`microlie._autodiff`):
    ``fn`` of the perturbed arguments ``X_k Exp(delta_k)`` (``x + delta`` for vectors)."""
    handles = [var for var, _ in factor.args]

    def f(deltas, params, data):
        vals = [var.plus(p, d) for var, d, p in zip(handles, deltas, params, strict=True)]
        return factor.fn(*vals, *data)

    run = _autodiff.residual_jacobians(factor.mode, f, [var.dof for var, _ in factor.args],
                                       factor.count, factor.dim)
    return lambda values, jac: run(_parts(factor, values), factor.data, jac)


@dataclass(frozen=True)
class JacobianCheck:
    """The result of :func:`check_jacobians`.

    Attributes
    ----------
    ok : bool
        Every argument's ``error`` is at most ``tol``.
    errors : list of float
        Per argument, ``max |J - J_num| / max(1, max |J_num|)`` over the batch.
    worst : str
        Where the largest error is: argument, factor row, residual row and tangent column,
        with both values.
    analytic, numerical : list of numpy.ndarray
        The Jacobians ``(m, dim, dof_k)`` of :meth:`Factor.evaluate` and of the central
        differences.
    tol : float
        The tolerance used.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> from microlie.optim import FactorGraph, PriorFactor, check_jacobians
    >>> g = FactorGraph()
    >>> f = PriorFactor(g.add_variables(SO3.exp([[0.1, 0.2, 0.3]])), 0, SO3.identity())
    >>> c = check_jacobians(f)
    >>> c.ok, len(c.errors), c.analytic[0].shape
    (True, 1, (1, 3, 3))
    """

    ok: bool
    errors: list[float]
    worst: str
    analytic: list[np.ndarray]
    numerical: list[np.ndarray]
    tol: float

    def __repr__(self) -> str:
        errs = ", ".join(f"{e:.1e}" for e in self.errors)
        return f"JacobianCheck(ok={self.ok}, errors=[{errs}], tol={self.tol:.0e}; {self.worst})"


def check_jacobians(factor: Factor, values: Any = None, *, step: float | None = None,
                    tol: float | None = None) -> JacobianCheck:
    """Compare a factor's Jacobians (:meth:`Factor.evaluate`) with central differences on
    the manifold: column ``a`` of argument ``k`` is ``(r(X_k Exp(h e_a)) - r(X_k Exp(-h
    e_a))) / 2h`` (the group's right ``plus``; ``x +- h e_a`` for vectors), every factor of
    the batch at once. What Ceres' ``GradientChecker`` and GTSAM's
    ``EXPECT_CORRECT_FACTOR_JACOBIANS`` do.

    Parameters
    ----------
    factor : Factor
        The factor batch to check.
    values : Values or sequence, optional
        Where: the graph's :class:`Values` (``result.values``, ``graph.initial_values()``),
        or one batch of ``m`` values per argument (as :meth:`Factor.residual` receives them:
        group elements, or ``(m, d)`` arrays; float32 is checked in float32). Default: the
        graph's initial values.
    step : float, optional
        The difference step ``h``; default ``eps ** (1/3)`` of the values' dtype (6e-6 for
        float64, 5e-3 for float32).
    tol : float, optional
        The largest accepted error (see :attr:`JacobianCheck.errors`); default ``1e-6`` for
        float64, ``1e-2`` for float32.

    Returns
    -------
    JacobianCheck
        ``ok``, the error per argument, where the worst one is, and both Jacobians.

    Raises
    ------
    ValueError
        ``values`` does not match the factor's arguments, or the factor returns wrong shapes.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.optim import BetweenFactor, FactorGraph, check_jacobians
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE3.random(3, rng=0))
    >>> f = BetweenFactor(x, [0, 1], [1, 2], SE3.random(2, rng=1))
    >>> check_jacobians(f).ok
    True
    >>> bad = [SE3.random(2, rng=2), SE3.random(2, rng=3)]
    >>> check_jacobians(f, bad).errors[0] < 1e-6
    True
    """
    if not isinstance(factor, Factor):
        raise TypeError(f"check_jacobians: expected a Factor, got {type(factor).__name__}")
    what = factor.name
    if values is None:
        values = factor.args[0][0].graph.initial_values()
    if isinstance(values, Values):
        vals: list[Any] = [var.wrap(np.asarray(values.params(var))[idx])
                           for var, idx in factor.args]
    elif isinstance(values, Sequence) and not isinstance(values, str | bytes):
        vals = list(values)
    else:
        raise TypeError(f"check_jacobians({what}): values must be Values or one batch per "
                        f"argument, got {type(values).__name__}")
    if len(vals) != len(factor.args):
        raise ValueError(f"check_jacobians({what}): {len(vals)} values for "
                         f"{len(factor.args)} arguments")
    dtypes = []
    for k, ((var, _), v) in enumerate(zip(factor.args, vals, strict=True)):
        want = (factor.count, var.group.param_dim)
        try:
            p = np.asarray(var.params_of(v))
        except TypeError:
            p = None
        if p is None or p.shape != want:
            raise ValueError(f"check_jacobians({what}): value {k} (argument {var.name}) must be "
                             f"{var.value_type} batch of {factor.count} (params {want}), "
                             f"got {type(v).__name__} of shape {np.shape(v)}")
        vals[k] = var.wrap(p)  # an R(d) batch of a vector variable: its array
        dtypes.append(p.dtype)
    single = all(d == np.float32 for d in dtypes)
    eps = float(np.finfo(np.float32 if single else np.float64).eps)
    h = float(step) if step is not None else eps ** (1 / 3)
    tol = float(tol) if tol is not None else (1e-2 if single else 1e-6)
    if not h > 0:
        raise ValueError(f"check_jacobians({what}): step must be positive, got {step!r}")
    _, Ja = factor.evaluate(vals, True)
    Jn = _numerical_jacobians(lambda vs: factor.evaluate(vs, False), factor.args, vals, h)
    errors, worst, at = [], -1.0, ""
    for k, ((var, _), A, N) in enumerate(zip(factor.args, Ja, Jn, strict=True)):
        diff = np.abs(A - N)
        scale = max(1.0, float(np.abs(N).max(initial=0.0)))
        e = float(diff.max(initial=0.0)) / scale if np.all(np.isfinite(diff)) else np.inf
        errors.append(e)
        if e > worst:
            worst = e
            i, r, c = np.unravel_index(int(np.argmax(np.where(np.isnan(diff), np.inf, diff))),
                                       diff.shape)
            at = (f"worst: argument {k} ({var.name}), factor {i}, residual {r}, tangent {c}: "
                  f"{A[i, r, c]:.6g} against {N[i, r, c]:.6g} numerically")
    return JacobianCheck(all(e <= tol for e in errors), errors, at, list(Ja), Jn, tol)
