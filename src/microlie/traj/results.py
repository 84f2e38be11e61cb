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
        The file is not a microlie result, or its errors and statistics disagree.

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
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not a JSON file ({exc})") from None
    if not isinstance(d, dict) or d.get("microlie_result") != FORMAT_VERSION:
        raise ValueError(f"{path}: not a microlie result file (no 'microlie_result': 1)")
    try:
        errors = np.asarray(d["errors"], dtype=np.float64)
        stamps = None if d.get("timestamps") is None else np.asarray(d["timestamps"], float)
        pairs = None if d.get("pairs") is None else np.asarray(d["pairs"], dtype=np.intp)
        res = Result(d["metric"], d["relation"], d["label"], d["unit"],
                     {k: float(v) for k, v in d["stats"].items()}, errors, stamps, pairs,
                     d.get("ref_name"), d.get("est_name"), d.get("options") or {},
                     d.get("info") or {})
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed microlie result ({exc!r})") from None
    if errors.ndim != 1 or errors.size == 0:
        raise ValueError(f"{path}: 'errors' must be a non-empty list of numbers")
    if stamps is not None and stamps.shape != errors.shape:
        raise ValueError(f"{path}: {stamps.size} timestamps for {errors.size} errors")
    again = statistics(errors)
    if any(abs(again[k] - res.stats[k]) > 1e-12 * max(1.0, abs(again[k])) for k in again):
        raise ValueError(f"{path}: the stored statistics do not match the stored errors")
    return res
