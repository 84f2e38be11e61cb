"""Reading evo's result archives (``evo_ape/evo_rpe --save_results res.zip``) for ``microlie res``.

evo's format (read from its documentation and files; no evo code is used): a zip archive
holding

* ``info.json``: ``title`` (first line e.g. ``"APE w.r.t. translation part (m)"``, then the
  alignment and delta), ``label``, ``ref_name``, ``est_name``;
* ``stats.json``: rmse, mean, median, std, min, max, sse;
* one NumPy array per ``.npy`` member (``.npz`` in evo versions before 1.x, same content):
  ``error_array`` (required), and ``timestamps``, ``seconds_from_start``, ... when present.

Archives whose statistics are not the seven above (``evo_rpe-for-each`` results, keyed by
sub-sequence length) are refused. The stored statistics must agree with the stored errors
(``1e-9`` relative), otherwise the archive is refused too.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from .metrics import RELATION_NAMES, statistics
from .results import Result

__all__ = ["load_evo_result", "is_evo_result"]

# evo's names of the pose relations -> ours
_EVO_RELATIONS = {
    "translation part": "trans",
    "rotation part": "rot_part",
    "full transformation": "full",
    "rotation angle in degrees": "angle_deg",
    "rotation angle in radians": "angle_rad",
    "point distance": "point_distance",
    "point distance error ratio": "point_distance_error_ratio",
}
_STAT_KEYS = {"rmse", "mean", "median", "std", "min", "max", "sse"}
_MAX_MEMBER = 1 << 30  # 1 GiB uncompressed per member: refuse larger (a zip bomb)


def is_evo_result(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a zip archive (evo's result format) rather than our JSON.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.traj.evo_results import is_evo_result
    >>> p = os.path.join(tempfile.mkdtemp(), "r.json")
    >>> _ = open(p, "w").write("{}")
    >>> is_evo_result(p)
    False
    """
    return zipfile.is_zipfile(path)


def _array(z: zipfile.ZipFile, member: str, path: Any) -> np.ndarray:
    info = z.getinfo(member)
    if info.file_size > _MAX_MEMBER:
        raise ValueError(f"{path}: member {member} is {info.file_size} bytes uncompressed; "
                         "refusing to read it")
    try:
        arr = np.load(io.BytesIO(z.read(member)), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ValueError(f"{path}: member {member} is not a NumPy array ({exc})") from None
    if isinstance(arr, np.lib.npyio.NpzFile):  # a genuine .npz: one array expected
        if len(arr.files) != 1:
            raise ValueError(f"{path}: member {member} holds {len(arr.files)} arrays, "
                             "expected one")
        arr = arr[arr.files[0]]
    return np.asarray(arr)


def _parse_title(title: str) -> tuple[str | None, str | None, str | None]:
    """(metric, relation, unit) from the first title line ``"APE w.r.t. NAME (UNIT)"``."""
    first = title.split("\n", 1)[0].strip()
    metric, _, rest = first.partition(" w.r.t. ")
    if not rest or metric.lower() not in ("ape", "rpe"):
        return None, None, None
    name, _, unit = rest.rpartition(" (")
    if not unit.endswith(")"):
        return metric.lower(), None, None
    unit = unit[:-1]
    return metric.lower(), _EVO_RELATIONS.get(name, name), "" if unit == "unit-less" else unit


def load_evo_result(path: str | os.PathLike) -> Result:
    """Read an evo result archive (module docstring) as a :class:`~microlie.traj.Result`.

    The relation is translated to microlie's name (``translation part`` -> ``trans``, ...),
    the label written the way microlie writes it, ``info`` keeps evo's ``info.json`` (under
    ``"evo_info"``), and ``timestamps`` are evo's ``timestamps`` array (absolute, s), or its
    ``seconds_from_start`` when only that is stored, or ``None``.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.zip`` archive.

    Returns
    -------
    Result

    Raises
    ------
    ValueError
        Not a zip archive, a member missing or malformed, statistics other than evo's seven
        (e.g. an ``evo_rpe-for-each`` result), or statistics that disagree with the errors.

    Examples
    --------
    >>> import io, json, os, tempfile, zipfile
    >>> import numpy as np
    >>> from microlie.traj import load_evo_result, statistics
    >>> e = np.array([0.1, 0.2, 0.4])
    >>> buf = io.BytesIO(); np.save(buf, e)
    >>> p = os.path.join(tempfile.mkdtemp(), "ape.zip")
    >>> with zipfile.ZipFile(p, "w") as z:
    ...     z.writestr("info.json", json.dumps({"title": "APE w.r.t. translation part (m)",
    ...                "est_name": "est.txt", "ref_name": "gt.txt", "label": "APE (m)"}))
    ...     z.writestr("stats.json", json.dumps(statistics(e)))
    ...     z.writestr("error_array.npy", buf.getvalue())
    >>> r = load_evo_result(p)
    >>> r.metric, r.relation, r.unit, r.label, r.errors.size
    ('ape', 'trans', 'm', 'APE w.r.t. translation part (m)', 3)
    """
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise ValueError(f"{path}: not an evo result archive ({exc})") from None
    with z:
        names = set(z.namelist())
        missing = sorted({"info.json", "stats.json"} - names)
        if missing:
            raise ValueError(f"{path}: not an evo result archive (no {', '.join(missing)})")
        try:
            info = json.loads(z.read("info.json").decode("utf-8"))
            stats = json.loads(z.read("stats.json").decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: info.json / stats.json is not JSON ({exc})") from None
        if not isinstance(info, dict) or not isinstance(stats, dict):
            raise ValueError(f"{path}: info.json and stats.json must hold JSON objects")
        if set(stats) != _STAT_KEYS:
            raise ValueError(
                f"{path}: statistics {sorted(stats)} are not evo's rmse/mean/median/std/min/"
                "max/sse (an evo_rpe-for-each result?): microlie res reads APE/RPE results")
        arrays = {}
        for member in sorted(names):
            stem, ext = os.path.splitext(Path(member).name)
            if ext in (".npy", ".npz") and stem in ("error_array", "timestamps",
                                                    "seconds_from_start"):
                arrays[stem] = _array(z, member, path)
    if "error_array" not in arrays:
        raise ValueError(f"{path}: no error_array.npy in the archive")
    errors = np.asarray(arrays["error_array"], dtype=np.float64)
    if errors.ndim != 1 or errors.size == 0 or not np.all(np.isfinite(errors)):
        raise ValueError(f"{path}: error_array must be a non-empty 1-D array of finite numbers")
    stamps = arrays.get("timestamps", arrays.get("seconds_from_start"))
    if stamps is not None:
        stamps = np.asarray(stamps, dtype=np.float64)
        if stamps.shape != errors.shape:
            raise ValueError(f"{path}: {stamps.size} timestamps for {errors.size} errors")
    try:
        stats_f = {k: float(v) for k, v in stats.items()}
    except (TypeError, ValueError):
        raise ValueError(f"{path}: stats.json holds a non-number") from None
    again = statistics(errors)
    if any(abs(again[k] - stats_f[k]) > 1e-9 * max(1.0, abs(again[k])) for k in again):
        raise ValueError(f"{path}: the stored statistics do not match the stored errors")
    title = str(info.get("title", ""))
    metric, relation, unit = _parse_title(title)
    if metric is None:
        label = str(info.get("label", "")) or title.split("\n", 1)[0] or "evo result"
        metric = label.split(" ", 1)[0].lower() if label.split(" ", 1)[0] in ("APE", "RPE") \
            else "unknown"
    elif relation in RELATION_NAMES:
        label = f"{metric.upper()} w.r.t. {RELATION_NAMES[relation]} ({unit or 'unit-less'})"
    else:
        label = title.split("\n", 1)[0]
    return Result(
        metric, relation or "unknown", label, unit or "", stats_f, errors, stamps, None,
        info.get("ref_name"), info.get("est_name"), {}, {"evo_info": info},
    )
