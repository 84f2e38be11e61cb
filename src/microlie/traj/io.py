"""Trajectory files: TUM, KITTI poses and EuRoC ground-truth CSV.

Formats (one pose per line; ``#`` starts a comment line, blank lines are ignored):

* **TUM**: ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, quaternion scalar *last*),
  separated by spaces (commas are accepted too).
* **KITTI**: 12 numbers, the row-major 3x4 matrix ``[R | t]`` of the pose in the world frame.
  No timestamps; a separate file with one timestamp (seconds) per line may be given.
* **EuRoC**: CSV ``timestamp[ns], px, py, pz, qw, qx, qy, qz, ...`` (quaternion scalar *first*,
  more columns allowed and ignored).

Files are UTF-8 (a byte order mark is dropped). Every reader validates each line and raises
:class:`ValueError` naming the file and the 1-based line number for: a byte that is not UTF-8,
a wrong number of fields (EuRoC: a line whose number of fields differs from the first line's),
a non-numeric field, NaN or infinity, a quaternion whose norm is off 1 by more than
``quat_tol`` and (KITTI) a matrix that is not a rotation within ``rot_tol``. Accepted
quaternions are normalised and accepted KITTI rotations are projected onto SO(3) (nearest
rotation in the Frobenius norm, via SVD) before they become :class:`~microlie.SE3` poses.
"""

from __future__ import annotations

import codecs
import mmap
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from microlie import SE3, _fast
from microlie._files import atomic_write
from microlie._textfile import plain_error, read_text

from .formats import FORMATS, trajectory_format
from .trajectory import Trajectory

__all__ = [
    "read_tum",
    "write_tum",
    "read_kitti",
    "write_kitti",
    "write_euroc",
    "write_trajectory",
    "read_euroc",
    "read_timestamps",
    "read_trajectory",
    "FORMATS",
]


PathLike = str | os.PathLike


def _data_lines(path: PathLike, comma: bool) -> tuple[list[int], list[list[str]]]:
    """Return (1-based line numbers, split fields) of the non-comment, non-blank lines."""
    text = read_text(path)
    numbers: list[int] = []
    rows: list[list[str]] = []
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#") or s.startswith("%"):
            continue
        why = plain_error(s)
        if why is not None:
            raise ValueError(f"{path}:{k}: {why}")
        if comma:
            fields = [f.strip() for f in s.split(",")]
        else:
            fields = s.replace(",", " ").split()
        numbers.append(k)
        rows.append(fields)
    return numbers, rows


def _to_matrix(
    path: PathLike,
    numbers: list[int],
    rows: list[list[str]],
    ncols: int,
    at_least: bool = False,
    what: str = "",
) -> np.ndarray:
    """Convert split rows to a float matrix, raising a ValueError naming file and line."""
    if not rows:
        raise ValueError(f"{path}: no data lines found (expected {what})")
    for k, r in zip(numbers, rows, strict=True):
        bad = len(r) < ncols if at_least else len(r) != ncols
        if bad:
            need = f"at least {ncols}" if at_least else str(ncols)
            raise ValueError(
                f"{path}:{k}: expected {need} fields ({what}), found {len(r)}"
            )
    if at_least:
        rows = [r[:ncols] for r in rows]
    try:
        mat = np.array(rows, dtype=np.float64)
    except ValueError:
        for k, r in zip(numbers, rows, strict=True):
            for j, f in enumerate(r):
                try:
                    float(f)
                except ValueError:
                    raise ValueError(
                        f"{path}:{k}: field {j + 1} is not a number: {f!r}"
                    ) from None
        raise  # pragma: no cover - np.array failed for a reason float() accepts
    finite = np.isfinite(mat)
    if not finite.all():
        i, j = np.argwhere(~finite)[0]
        raise ValueError(
            f"{path}:{numbers[i]}: field {j + 1} is not finite ({rows[i][j]!r})"
        )
    return mat


def _header_lines(data: bytes) -> tuple[int, int]:
    """(number of leading comment / blank lines, offset of the first data line) of ``data``.

    Lines end at ``\n`` here (a ``\r`` before it is stripped as whitespace); only used when
    ``data`` has no other line break.
    """
    offset = count = 0
    while True:
        nl = data.find(b"\n", offset)
        s = data[offset : nl if nl >= 0 else len(data)].strip()
        if s and not s.startswith((b"#", b"%")):
            return count, offset
        if nl < 0:
            return count + 1, len(data)
        offset, count = nl + 1, count + 1


# What sends a file from the direct path to the line-list path: line breaks of
# ``str.splitlines`` other than ``\n`` and ``\r\n`` anywhere (the careful path splits lines
# with it; \x85, \u2028 and \u2029 are excluded by ``isascii``), and comments below the
# header.
_BREAKS = (b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e")


def _data_block(text: str) -> list[str]:
    """The lines of ``text`` without comment lines (``#`` or ``%`` first, after indentation).

    Lines are split exactly as :func:`_data_lines` splits them (``str.splitlines``), so that
    the fast path sees the same lines as the careful one. Header comments are the usual case
    and cost nothing; comment lines further down are filtered in Python.
    """
    lines = text.splitlines()
    k = 0
    for k, line in enumerate(lines):  # noqa: B007 - k is used after the loop
        s = line.lstrip()
        if s and not s.startswith(("#", "%")):
            break
    else:
        return []
    head = lines[:k]
    n_hash = sum(ln.count("#") for ln in head)
    n_pct = sum(ln.count("%") for ln in head)
    if text.count("#") == n_hash and text.count("%") == n_pct:
        return lines[k:]
    return [ln for ln in lines[k:] if not ln.lstrip().startswith(("#", "%"))]


def _loadtxt(
    source: PathLike | list[str], ncols: int, comma: bool, at_least: bool, skiprows: int = 0
) -> np.ndarray | None:
    """Parse data lines (a file after ``skiprows`` header lines, or a list) in C.

    Returns ``None`` if anything is off; only a fast path: the caller then re-parses line by
    line to name the bad line. :func:`numpy.loadtxt` converts numbers with Python's own
    ``float`` parser (so values are bit-identical to the careful path); anything it rejects
    is re-read and reported line by line (the careful path refuses ``1_000`` and non-ASCII
    characters, :func:`~microlie._textfile.plain_error`; blank lines are skipped by both).
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": handled below
            mat = np.loadtxt(
                source,
                dtype=np.float64,
                comments=None,
                delimiter="," if comma else None,
                usecols=range(ncols) if at_least else None,
                ndmin=2,
                quotechar=None,
                skiprows=skiprows,
                # the direct path only takes ASCII files; a BOM makes it fail -> list path
                encoding="ascii",
            )
    except ValueError:
        return None
    if mat.shape[0] == 0 or mat.shape[1] != ncols or not np.isfinite(mat).all():
        return None
    return mat


def _fast_matrix(
    path: PathLike, data: bytes, ncols: int, comma: bool, at_least: bool
) -> np.ndarray | None:
    """The float matrix of the data lines of ``data`` (the bytes of ``path``), or ``None``.

    1. The usual file (ASCII, comments only in the header, ``\n`` or ``\r\n`` line ends and,
       unless ``comma``, no commas) is parsed by ``loadtxt`` straight from the file; the checks
       run on the bytes (no decoding).
    2. Otherwise the lines of the text, split as the careful path splits them and without
       comment lines, are handed to ``loadtxt`` as a list.
    """
    skip, offset = _header_lines(data)
    if offset >= len(data):
        return None
    below_header = (b"#", b"%") if comma else (b"#", b"%", b",")
    if (
        data.isascii()
        and not any(c in data for c in _BREAKS)
        and (b"\r" not in data or data.count(b"\r") == data.count(b"\r\n"))
        and not any(data.find(c, offset) >= 0 for c in below_header)
    ):
        return _loadtxt(path, ncols, comma, at_least, skip)
    text = read_text(path)  # as the careful path reads it
    lines = _data_block(text)
    if not all(ln.isascii() for ln in lines):
        return None  # refused by the careful path, naming the line (plain_error)
    if not comma and "," in text:
        # commas separate fields like spaces (see _data_lines); a line of commas only has
        # no fields (an error the careful path reports), it must not become a blank line
        if any("," in ln and not ln.replace(",", "").strip() for ln in lines):
            return None
        lines = [ln.replace(",", " ") for ln in lines]
    return _loadtxt(lines, ncols, comma, at_least) if lines else None


class _LineNumbers:
    """1-based file line numbers of the data rows, computed only when an error is reported."""

    def __init__(self, path: PathLike, comma: bool, known: list[int] | None = None) -> None:
        self._path, self._comma, self._known = path, comma, known

    def __getitem__(self, i: int) -> int:
        if self._known is None:
            self._known = _data_lines(self._path, self._comma)[0]
        return self._known[i]


def _compiled_matrix(
    parse: Callable[..., np.ndarray | None], path: PathLike, ncols: int, comma: bool,
    at_least: bool
) -> np.ndarray | None:
    """``parse`` (the compiled reader) on the bytes of ``path``, memory-mapped when possible
    (no copy of the file), without a UTF-8 byte order mark."""
    with open(path, "rb") as f:
        try:
            data: Any = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError):  # empty file, pipe, ...
            data = f.read()
        try:
            view = memoryview(data)
            try:
                return parse(view[3:] if view[:3] == codecs.BOM_UTF8 else view, ncols, comma,
                             at_least)
            finally:
                view.release()
        finally:
            if isinstance(data, mmap.mmap):
                data.close()


def _read_matrix(
    path: PathLike, ncols: int, *, comma: bool = False, at_least: bool = False, what: str = ""
) -> tuple[_LineNumbers, np.ndarray]:
    """(line numbers of the data rows, float matrix) of a numeric text file.

    With the compiled kernels the bytes are parsed by the compiled reader (same values as
    ``float``); a file it does not take (anything but plain ASCII numbers, see
    ``microlie._c._text``) goes through the NumPy and line-by-line paths below.
    """
    parse = _fast.text_parser()
    if parse is not None:
        mat = _compiled_matrix(parse, path, ncols, comma, at_least)
        if mat is not None:
            return _LineNumbers(path, comma), mat
    mat = _fast_matrix(path, Path(path).read_bytes(), ncols, comma, at_least)
    if mat is not None:
        return _LineNumbers(path, comma), mat
    numbers, rows = _data_lines(path, comma)
    mat = _to_matrix(path, numbers, rows, ncols, at_least=at_least, what=what)
    return _LineNumbers(path, comma, numbers), mat


def _quat_trajectory(
    path: PathLike,
    numbers: _LineNumbers,
    stamps: np.ndarray,
    params: np.ndarray,
    tol: float,
    name: str | None,
) -> Trajectory:
    """Check ``|q| = 1`` within ``tol`` (naming the line) and build the normalised poses from
    ``params``, an ``(N, 7)`` array ``[t, q_xyzw]`` (a view of the reader's matrix: the
    quaternions are normalised in place).

    The rows are already known to be finite (the readers check every field), so the poses are
    wrapped without the group constructors' checks; the values are bit-identical to
    ``Trajectory.from_arrays(positions, q_xyzw)`` (same ``q / sqrt(sum(q * q))``).
    """
    q_xyzw = params[:, 3:]
    # |q|^2 = ((x^2 + y^2) + z^2) + w^2, the order of np.sum over the last axis, one column at
    # a time (a reduction over an axis of 4 is slow)
    sq = q_xyzw[:, 0] * q_xyzw[:, 0]
    tmp = np.empty_like(sq)
    for k in (1, 2, 3):
        sq += np.multiply(q_xyzw[:, k], q_xyzw[:, k], out=tmp)
    norms = np.sqrt(sq, out=sq)
    if not (np.abs(norms - 1.0, out=tmp) <= tol).all() or not norms.all():
        i = int(np.flatnonzero(~(np.abs(norms - 1.0) <= tol) | (norms == 0.0))[0])
        raise ValueError(
            f"{path}:{numbers[i]}: quaternion is not unit norm (|q| = {norms[i]:.6g}, "
            f"tolerance {tol:g})"
        )
    q_xyzw /= norms[:, None]
    return Trajectory(SE3.from_params(params, check=False), np.ascontiguousarray(stamps), name)


def read_tum(path: PathLike, *, quat_tol: float = 1e-3, name: str | None = None) -> Trajectory:
    """Read a TUM trajectory ``timestamp tx ty tz qx qy qz qw`` (quaternion scalar last).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    quat_tol : float
        Largest accepted ``| |q| - 1 |`` (quaternions are then normalised).
    name : str, optional
        The trajectory's label (default: the path).

    Returns
    -------
    Trajectory

    Raises
    ------
    ValueError
        Naming the file and line of a malformed line (see the module docstring).

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import read_tum
    >>> traj = read_tum(example_paths()[0])
    >>> len(traj), traj.poses.params.shape
    (150, (150, 7))
    """
    numbers, mat = _read_matrix(path, 8, what="timestamp tx ty tz qx qy qz qw")
    return _quat_trajectory(path, numbers, mat[:, 0], mat[:, 1:], quat_tol, name or str(path))


def read_timestamps(path: PathLike) -> np.ndarray:
    """Read one timestamp (seconds) per line, e.g. KITTI's ``times.txt``.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` float64 seconds.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.traj import read_timestamps
    >>> path = os.path.join(tempfile.mkdtemp(), "times.txt")
    >>> import numpy as np
    >>> np.savetxt(path, [0.0, 0.1, 0.2])
    >>> read_timestamps(path).tolist()
    [0.0, 0.1, 0.2]
    """
    return _read_matrix(path, 1, what="timestamp")[1][:, 0]


def read_kitti(
    path: PathLike,
    timestamps: PathLike | np.ndarray | None = None,
    *,
    rot_tol: float = 1e-3,
    name: str | None = None,
) -> Trajectory:
    """Read KITTI poses (12 numbers per line, row-major ``[R | t]``).

    Rotations must satisfy ``|R^T R - I| <= rot_tol`` and ``det R > 0``; they are then
    projected onto SO(3).

    Parameters
    ----------
    path : str or os.PathLike
        The poses file.
    timestamps : str, os.PathLike or numpy.ndarray, optional
        A times file (one time in seconds per line) or an array; without it the trajectory
        has no timestamps and is compared index by index.
    rot_tol : float
        Largest accepted ``max |R^T R - I|``.
    name : str, optional
        The label (default: the path).

    Returns
    -------
    Trajectory

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> traj = read_tum(example_paths()[0])
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> write_kitti(path, traj)
    >>> back = read_kitti(path)
    >>> back.timestamps is None, bool(abs(back.positions - traj.positions).max() < 1e-12)
    (True, True)
    """
    numbers, mat = _read_matrix(path, 12, what="row-major 3x4 [R|t]")
    m = mat.reshape(-1, 3, 4)
    r = m[:, :, :3]
    t = m[:, :, 3]
    defect = np.abs(np.swapaxes(r, -1, -2) @ r - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(r)
    bad = np.flatnonzero((defect > rot_tol) | (det <= 0))
    if bad.size:
        i = bad[0]
        raise ValueError(
            f"{path}:{numbers[i]}: 3x3 block is not a rotation "
            f"(max |R^T R - I| = {defect[i]:.3g}, det = {det[i]:.6g}, tolerance {rot_tol:g})"
        )
    stamps = None
    if timestamps is not None:
        if isinstance(timestamps, (str, os.PathLike)):
            stamps = read_timestamps(timestamps)
            src = str(timestamps)
        else:
            stamps = np.asarray(timestamps, dtype=np.float64)
            src = "timestamps array"
        if stamps.shape != (len(mat),):
            raise ValueError(
                f"{src}: {stamps.shape[0]} timestamps for {len(mat)} poses in {path}"
            )
    return Trajectory.from_rotation_matrices(  # projects onto SO(3) (SO3.from_matrix)
        t, r, timestamps=stamps, name=name or str(path)
    )


def read_euroc(path: PathLike, *, quat_tol: float = 1e-3, name: str | None = None) -> Trajectory:
    """Read a EuRoC ground-truth CSV: ``t[ns], px, py, pz, qw, qx, qy, qz, ...``.

    Timestamps are converted from nanoseconds to seconds (``t_ns / 1e9`` in float64, as the
    other tools do, so associations agree). The quaternion is scalar-*first* in this format;
    further columns are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    quat_tol : float
        Largest accepted ``| |q| - 1 |``.
    name : str, optional
        The label (default: the path).

    Returns
    -------
    Trajectory

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> traj = read_tum(example_paths()[0])
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> write_euroc(path, traj)
    >>> back = read_euroc(path)
    >>> bool(abs(back.quat_xyzw - traj.quat_xyzw).max() < 1e-12)
    True
    """
    numbers, mat = _read_matrix(
        path, 8, comma=True, at_least=True, what="timestamp[ns], px, py, pz, qw, qx, qy, qz"
    )
    _same_columns(path)
    params = mat[:, [1, 2, 3, 5, 6, 7, 4]]  # [p, q_xyzw]: the file's quaternion is w first
    return _quat_trajectory(path, numbers, mat[:, 0] / 1e9, params, quat_tol, name or str(path))


def _same_columns(path: PathLike) -> None:
    """Every data line of a CSV file has the fields of the first one (a field inserted in or
    dropped from one line would shift the columns read from it)."""
    data = Path(path).read_bytes()
    skip, offset = _header_lines(data)
    if (data.isascii() and not any(c in data for c in _BREAKS)
            and data.count(b"\r") == data.count(b"\r\n")
            and not any(data.find(c, offset) >= 0 for c in (b"#", b"%"))):
        # the usual file: commas per line in bulk (a line without commas is blank, or has
        # one field and was refused by the reader already)
        arr = np.frombuffer(data, dtype=np.uint8)[offset:]
        starts = np.flatnonzero(arr[:-1] == 10) + 1
        per_line = np.add.reduceat((arr == 44).view(np.uint8), np.append(0, starts),
                                   dtype=np.int64) if arr.size else np.zeros(0, np.int64)
        counts = per_line[per_line > 0]
        if not counts.size or (counts == counts[0]).all():
            return
    lines = [ln for ln in _data_block(read_text(path)) if ln.strip()]
    counts = np.fromiter((ln.count(",") for ln in lines), dtype=np.intp, count=len(lines))
    bad = np.flatnonzero(counts != counts[:1])
    if bad.size:
        numbers = _data_lines(path, True)[0]
        k = int(bad[0])
        raise ValueError(
            f"{path}:{numbers[k]}: {counts[k] + 1} fields, but line {numbers[0]} has "
            f"{counts[0] + 1}: every line of the file must have the same columns"
        )


def read_trajectory(
    path: PathLike,
    fmt: str = "tum",
    *,
    timestamps: PathLike | None = None,
    topic: str | None = None,
) -> Trajectory:
    """Read ``path`` in format ``fmt``.

    Parameters
    ----------
    path : str or os.PathLike
        The file (or bag).
    fmt : {"tum", "kitti", "euroc", "bag"}
        The format.
    timestamps : str or os.PathLike, optional
        KITTI's times file.
    topic : str, optional
        The bag topic (see :func:`microlie.traj.rosbag.read_bag`), required for ``"bag"``.

    Returns
    -------
    Trajectory

    Examples
    --------
    >>> from microlie.data import example_paths
    >>> from microlie.traj import read_trajectory
    >>> len(read_trajectory(example_paths()[1], "tum"))
    145
    """
    entry = trajectory_format(fmt)
    given = {"timestamps": timestamps, "topic": topic}
    if "topic" in entry.options and not topic:
        raise ValueError(f"{path}: reading a bag needs a topic")
    options = {k: v for k, v in given.items() if k in entry.options and v is not None}
    reader: Callable[..., Trajectory] = entry.load("reader")
    return reader(path, **options)


def write_tum(path: PathLike, traj: Trajectory, *, header: str | None = None) -> None:
    """Write ``traj`` as TUM text (``timestamp tx ty tz qx qy qz qw``, full precision).

    A trajectory without timestamps is written with its pose index as the timestamp.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    traj : Trajectory
        The poses.
    header : str, optional
        The ``#`` comment line (default: the column names).

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> traj = read_tum(example_paths()[0])
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> write_tum(path, traj)
    >>> bool(abs(read_tum(path).poses.params - traj.poses.params).max() < 1e-15)
    True
    """
    stamps = traj.timestamps if traj.timestamps is not None else np.arange(len(traj), dtype=float)
    data = np.column_stack([stamps, traj.positions, traj.quat_xyzw])
    hdr = "timestamp tx ty tz qx qy qz qw" if header is None else header
    with atomic_write(path) as f:  # a temporary file renamed over ``path``
        np.savetxt(f, data, fmt="%.17g", header=hdr)


def write_kitti(path: PathLike, traj: Trajectory) -> None:
    """Write ``traj`` as KITTI poses (row-major 3x4 ``[R | t]``, full precision; no timestamps).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    traj : Trajectory
        The poses.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> traj = read_tum(example_paths()[0])
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> write_kitti(path, traj)
    >>> len(open(path).readline().split())
    12
    """
    m = traj.matrices()[:, :3, :].reshape(-1, 12)
    with atomic_write(path) as f:
        np.savetxt(f, m, fmt="%.17g")


def write_euroc(path: PathLike, traj: Trajectory) -> None:
    """Write ``traj`` as a EuRoC CSV (``#timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z``).

    Timestamps are rounded to integer nanoseconds; a trajectory without timestamps is
    written with its pose index as the time in seconds.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    traj : Trajectory
        The poses.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> traj = read_tum(example_paths()[0])
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> write_euroc(path, traj)
    >>> open(path).readline().startswith("#timestamp [ns]")
    True
    """
    stamps = traj.timestamps if traj.timestamps is not None else np.arange(len(traj), dtype=float)
    q = traj.quat_xyzw
    with atomic_write(path) as f:
        f.write("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],"
                "q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n")
        for t, p, qq in zip(np.rint(stamps * 1e9).astype(np.int64).tolist(),
                            traj.positions.tolist(), q.tolist(), strict=True):
            f.write(f"{t},{p[0]!r},{p[1]!r},{p[2]!r},{qq[3]!r},{qq[0]!r},{qq[1]!r},{qq[2]!r}\n")


def write_trajectory(path: PathLike, traj: Trajectory, fmt: str = "tum") -> None:
    """Write ``traj`` in format ``fmt``.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    traj : Trajectory
        The poses.
    fmt : {"tum", "kitti", "euroc"}
        The format.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.data import example_paths
    >>> from microlie.traj import *
    >>> traj = read_tum(example_paths()[0])
    >>> path = os.path.join(tempfile.mkdtemp(), "out.txt")
    >>> write_trajectory(path, traj, "tum")
    >>> len(read_tum(path)) == len(traj)
    True
    """
    trajectory_format(fmt, write=True).load("writer")(path, traj)
