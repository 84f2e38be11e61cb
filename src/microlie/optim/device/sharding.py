"""A batch of problems solved across devices with JAX's own sharding.

:func:`sharded_solve` splits the problem axis of ``theta`` and ``x0`` over the devices of a
``jax.sharding.Mesh`` (``NamedSharding`` with ``PartitionSpec(axis)``) and runs the batched
solve (:func:`~microlie.optim.device.solve`) on every shard with ``jax.shard_map``: each device
solves its own problems with its own loop, and no collective operation runs inside the solve.

Why ``shard_map`` and not ``jax.jit`` of the batched solve on sharded inputs: partitioned by
the compiler, the loop's stopping test (``any problem still running``) and the relinearisation
test become all-reduces across devices inside a ``while_loop``, once per try. Over fake CPU
devices (``XLA_FLAGS=--xla_force_host_platform_device_count=4``) on a machine with fewer cores
than devices, such collectives inside a loop can wait on each other's threads; the per-shard
loop has none, and each device stops when its own problems are done (the others are not held
back by the slowest shard). A batch that does not divide by the number of devices is padded
with copies of its last problem, whose results are dropped.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["batch_mesh", "sharded_solve"]


def batch_mesh(devices: Any = None, axis: str = "batch") -> Any:
    """A one-axis ``jax.sharding.Mesh`` over ``devices`` (default: all of JAX's devices).

    Parameters
    ----------
    devices : sequence of jax.Device, optional
        The devices.
    axis : str
        The mesh axis name.

    Returns
    -------
    jax.sharding.Mesh

    Examples
    --------
    >>> import jax
    >>> batch_mesh().axis_names
    ('batch',)
    """
    import jax

    devs = list(jax.devices()) if devices is None else list(devices)
    if not devs:
        raise ValueError("devices: no device given")
    return jax.sharding.Mesh(np.array(devs), (axis,))


def sharded_solve(problem: Any, theta: Any, x0: list, options: Any = None, mesh: Any = None,
                  axis: str | None = None) -> tuple[list, Any]:
    """Solve a batch of problems of one structure with the batch split over ``mesh``.

    Parameters
    ----------
    problem : DeviceProblem
        The structure (a JAX problem).
    theta : tuple of dict
        The factors' data with a leading problem axis ``B`` on every array that varies (an
        array without it is shared and replicated on every device).
    x0 : list of arrays
        ``(B, n_k, param_dim)`` starting parameters.
    options : LMOptions, optional
        The solve's rules (the same for every shard).
    mesh : jax.sharding.Mesh, optional
        A mesh with the axis ``axis`` (default: :func:`batch_mesh` over all devices).
    axis : str, optional
        The mesh axis the batch is split over (default: the mesh's first).

    Returns
    -------
    x : list of arrays
        ``(B, n_k, param_dim)``, sharded over ``mesh`` along the batch.
    info : SolveInfo
        ``(B,)`` arrays.

    Raises
    ------
    ValueError
        A problem that is not on JAX, ``x0`` without the batch axis, or an axis not in the
        mesh.

    Examples
    --------
    >>> import jax, jax.numpy as jnp
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.device import DeviceProblem, stack
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(jnp.zeros((1, 2))), 0, jnp.zeros(2)))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = stack([({"Z": jnp.array([[float(b), 1.0]]), "L": p.theta()[0]["L"]},)
    ...             for b in range(3)])
    >>> x, info = sharded_solve(p, th, [jnp.zeros((3, 1, 2))])
    >>> [round(v, 6) for v in x[0][:, 0, 0].tolist()]  # LM stops within its tolerances
    [0.0, 1.0, 2.0]
    """
    import jax
    from jax.sharding import NamedSharding
    from jax.sharding import PartitionSpec as P

    from .lm import solve

    if problem.backend.name != "jax":
        raise ValueError(f"sharded_solve: the problem is on {problem.backend.name}; sharding "
                         "runs JAX problems (build the graph from JAX arrays)")
    if not x0 or any(a.ndim != 3 for a in x0):
        raise ValueError("x0: sharded_solve takes a batch, (B, n_k, param_dim) per variable "
                         "batch (stack problems with microlie.optim.device.stack)")
    mesh = batch_mesh() if mesh is None else mesh
    axis = mesh.axis_names[0] if axis is None else axis
    if axis not in mesh.axis_names:
        raise ValueError(f"axis: {axis!r} is not an axis of the mesh {mesh.axis_names}")
    B = int(x0[0].shape[0])
    n_dev = int(mesh.shape[axis])
    pad = (-B) % n_dev
    ref = problem.theta()
    batched = jax.tree_util.tree_map(lambda a, r: a.ndim == r.ndim + 1, theta, ref)

    def padded(a: Any) -> Any:
        if pad == 0:
            return a
        import jax.numpy as jnp

        return jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)], axis=0)

    theta_p = jax.tree_util.tree_map(lambda a, b: padded(a) if b else a, theta, batched)
    x0_p = [padded(a) for a in x0]
    th_specs = jax.tree_util.tree_map(lambda b: P(axis) if b else P(), batched)
    x_specs = [P(axis)] * len(x0)
    put = jax.tree_util.tree_map(
        lambda a, s: jax.device_put(a, NamedSharding(mesh, s)), (theta_p, x0_p),
        (th_specs, x_specs), is_leaf=lambda s: isinstance(s, P))

    def local(th: Any, xs: list) -> tuple[list, Any]:
        return solve(problem, th, list(xs), options)

    from .lm import SolveInfo

    key = (options, mesh, axis, tuple(jax.tree_util.tree_leaves(batched)), len(x0))
    cache = problem.__dict__.setdefault("_sharded_solves", {})
    f = cache.get(key)
    if f is None:  # one compiled function per problem, options and mesh
        info_specs = SolveInfo(*[P(axis)] * len(SolveInfo._fields))
        f = cache[key] = jax.jit(jax.shard_map(local, mesh=mesh, in_specs=(th_specs, x_specs),
                                               out_specs=(x_specs, info_specs),
                                               check_vma=False))
    x, info = f(*put)
    if pad:
        x = [a[:B] for a in x]
        info = SolveInfo(*(v[:B] for v in info))
    return x, info
