"""Saved metric results: one JSON file per APE / RPE run, for ``microlie res``.

File format (JSON, UTF-8; floats written with full precision, so they read back bit-identical):

=====================  ===================================================================
key                    value
=====================  ===================================================================
``microlie_result``    format version, ``1``
``microlie_version``   the version that wrote the file
``metric``             ``"ape"`` or ``"rpe"``
``relation``           the pose relation (``"trans"``, ``"angle_deg"``, ...)
``label``              e.g. ``"APE w.r.t. translation part (m)"``
``unit``               unit of the errors (``"m"``, ``"deg"``, ``"rad"`` or ``""``)
``ref_name``           name (path) of the reference
``est_name``           name (path) of the estimate
``options``            the options of the run (alignment, delta, max. time difference, ...)
``info``               what the run found (pairs associated, alignment transform and scale)
``stats``              rmse, mean, median, std, min, max, sse
``errors``             the per-pose (APE) or per-pair (RPE) errors, a list of M numbers
``timestamps``         estimate timestamp of each error (RPE: of the pair's first pose),
                       seconds, or ``null`` without timestamps
``pairs``              RPE: the ``[i, j]`` index pairs into the paired trajectories; APE
                       ``null``
=====================  ===================================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._files import atomic_write
from .._textfile import read_text
from .metrics import PoseError, statistics

__all__ = ["Result", "save_result", "load_result", "result_from_error"]

FORMAT_VERSION = 1


@dataclass
class Result:
    """A metric result as saved on disk (no trajectories): see the module docstring.

    Attributes
    ----------
    metric, relation, label, unit : str
        As in :class:`~microlie.traj.PoseError`.
    stats : dict of str to float
        The statistics of ``errors``.
    errors : numpy.ndarray
        ``(M,)`` per-pose (APE) or per-pair (RPE) errors.
    timestamps : numpy.ndarray or None
        ``(M,)`` estimate stamps of the errors (the first pose of each RPE pair).
    pairs : numpy.ndarray or None
        ``(M, 2)`` RPE index pairs.
    ref_name, est_name : str or None
        The trajectories' labels.
    options : dict
        The options of the run.
    info : dict
        Association, alignment and preprocessing details.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie import traj
    >>> from microlie.data import example_paths
    >>> res = traj.evaluate_ape(*(traj.read_tum(p) for p in example_paths()), align="se3")
    >>> path = os.path.join(tempfile.mkdtemp(), "ape.json")
    >>> back = traj.load_result(traj.save_result(res, path))
    >>> back.metric, back.errors.size == res.errors.size
    ('ape', True)
    """

    metric: str
    relation: str
    label: str
    unit: str
    stats: dict[str, float]
    errors: np.ndarray
    timestamps: np.ndarray | None = None
    pairs: np.ndarray | None = None
    ref_name: str | None = None
    est_name: str | None = None
    options: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        return (f"Result({self.label}: {self.errors.size} errors, rmse "
                f"{self.stats.get('rmse', float('nan')):.6g} {self.unit}, est "
                f"{self.est_name})".replace(" ,", ","))

    def to_json(self) -> dict[str, Any]:
        """The JSON document written by :func:`save_result`.

        Returns
        -------
        dict
            The attributes, plus ``microlie_result`` (format version) and ``microlie_version``.

        Examples
        --------
        >>> import os, tempfile
        >>> from microlie import traj
        >>> from microlie.data import example_paths
        >>> res = traj.evaluate_ape(*(traj.read_tum(p) for p in example_paths()), align="se3")
        >>> path = os.path.join(tempfile.mkdtemp(), "ape.json")
        >>> d = traj.load_result(traj.save_result(res, path)).to_json()
        >>> d["microlie_result"], d["label"]
        (1, 'APE w.r.t. translation part (m)')
        """
        from microlie import __version__

        return {
            "microlie_result": FORMAT_VERSION,
            "microlie_version": __version__,
            "metric": self.metric,
            "relation": self.relation,
            "label": self.label,
            "unit": self.unit,
            "ref_name": self.ref_name,
            "est_name": self.est_name,
            "options": self.options,
            "info": self.info,
            "stats": self.stats,
            "errors": self.errors.tolist(),
            "timestamps": None if self.timestamps is None else self.timestamps.tolist(),
            "pairs": None if self.pairs is None else self.pairs.tolist(),
        }


def result_from_error(res: PoseError, options: dict[str, Any] | None = None) -> Result:
    """The :class:`Result` of a :class:`~microlie.traj.PoseError` (with the run's options)."""
    stamps = None
    if res.est is not None and res.est.timestamps is not None:
        idx = np.arange(res.errors.size) if res.pairs is None else res.pairs[:, 0]
        stamps = res.est.timestamps[idx]
    return Result(
        res.metric, res.relation, res.label, res.unit, dict(res.stats),
        np.asarray(res.errors, dtype=np.float64), stamps,
        None if res.pairs is None else np.asarray(res.pairs),
        None if res.ref is None else res.ref.name,
        None if res.est is None else res.est.name,
        dict(options or {}), dict(res.info),
    )


def save_result(
    res: PoseError | Result, path: str | os.PathLike, options: dict[str, Any] | None = None
) -> Path:
    """Write ``res`` to ``path`` as JSON (module docstring).

    Parameters
    ----------
    res : PoseError or Result
        The result to save.
    path : str or os.PathLike
        The file to write.
    options : dict, optional
        The run's options, stored with it.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie import traj
    >>> from microlie.data import example_paths
    >>> res = traj.evaluate_ape(*(traj.read_tum(p) for p in example_paths()), align="se3")
    >>> path = os.path.join(tempfile.mkdtemp(), "ape.json")
    >>> back = traj.load_result(traj.save_result(res, path, {"align": "se3"}))
    >>> back.stats == res.stats, back.errors.shape == res.errors.shape
    (True, True)
    """
    r = res if isinstance(res, Result) else result_from_error(res, options)
    if options is not None and isinstance(res, Result):
        r.options = dict(options)
    path = Path(path)
    with atomic_write(path) as f:
        f.write(json.dumps(r.to_json(), indent=1) + "\n")
    return path


def load_result(path: str | os.PathLike) -> Result:
    """Read a file written by :func:`save_result` (``microlie ape/rpe --save-results``).

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file.

    Returns
    -------
    Result

    Raises
    ------
    ValueError
        The file is not UTF-8 JSON (naming ``FILE:LINE``), not a microlie result, has a
        field of the wrong type or a number that is not finite, or its errors and
        statistics disagree (naming ``FILE``).

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie import traj
    >>> from microlie.data import example_paths
    >>> res = traj.evaluate_ape(*(traj.read_tum(p) for p in example_paths()), align="se3")
    >>> path = os.path.join(tempfile.mkdtemp(), "ape.json")
    >>> traj.load_result(traj.save_result(res, path)).options
    {}
    """
    text = read_text(path)
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}: not a JSON file ({exc.msg}, column "
                         f"{exc.colno})") from None
    except (ValueError, RecursionError) as exc:  # an integer of > 4300 digits, deep nesting
        raise ValueError(f"{path}: not a readable JSON file ({exc})") from None
    if not isinstance(d, dict) or d.get("microlie_result") != FORMAT_VERSION:
        raise ValueError(f"{path}: not a microlie result file (no 'microlie_result': 1)")

    def get(key: str, kind: type | tuple[type, ...], what: str, optional: bool = False) -> Any:
        v = d.get(key)
        if not (isinstance(v, kind) or (optional and v is None)):
            raise ValueError(f"{path}: malformed microlie result: {key!r} must be {what}, "
                             f"got {str(v)[:40]!r}")
        return v

    def numbers(key: str, v: Any) -> np.ndarray:
        if not isinstance(v, list) or not v or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            raise ValueError(f"{path}: malformed microlie result: {key} must be a non-empty "
                             "list of numbers")
        try:
            a = np.array(v, dtype=np.float64)
        except OverflowError:
            a = np.array([np.inf])
        if not np.isfinite(a).all():
            raise ValueError(f"{path}: malformed microlie result: {key} holds a number "
                             "that is not finite")
        return a

    metric, relation, label, unit = (get(k, str, "a string")
                                     for k in ("metric", "relation", "label", "unit"))
    ref_name, est_name = (get(k, str, "a string or null", True) for k in ("ref_name", "est_name"))
    options, info = (get(k, dict, "an object or null", True) or {} for k in ("options", "info"))
    errors = numbers("'errors'", d.get("errors"))
    stamps = None if d.get("timestamps") is None else numbers("'timestamps'", d["timestamps"])
    if stamps is not None and stamps.shape != errors.shape:
        raise ValueError(f"{path}: {stamps.size} timestamps for {errors.size} errors")
    pairs = None
    if d.get("pairs") is not None:
        rows = d["pairs"]
        if not (isinstance(rows, list) and len(rows) == errors.size and all(
                isinstance(r, list) and len(r) == 2 and all(
                    type(x) is int and 0 <= x < 2**62 for x in r) for r in rows)):
            raise ValueError(f"{path}: malformed microlie result: 'pairs' must be "
                             f"{errors.size} pairs [i, j] of indices")
        pairs = np.array(rows, dtype=np.intp).reshape(-1, 2)
    again = statistics(errors)
    stats_in = get("stats", dict, "an object")
    stats = {k: float(numbers(f"stats[{k!r}]", [v])[0]) for k, v in stats_in.items()}
    if any(k not in stats or abs(again[k] - stats[k]) > 1e-12 * max(1.0, abs(again[k]))
           for k in again):
        raise ValueError(f"{path}: the stored statistics do not match the stored errors")
    return Result(metric, relation, label, unit, stats, errors, stamps, pairs, ref_name,
                  est_name, options, info)
