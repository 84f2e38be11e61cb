"""Trajectory files: TUM, KITTI poses and EuRoC ground-truth CSV.

Formats (one pose per line; ``#`` starts a comment line, blank lines are ignored):

* **TUM**: ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, quaternion scalar *last*),
  separated by spaces (commas are accepted too).
* **KITTI**: 12 numbers, the row-major 3x4 matrix ``[R | t]`` of the pose in the world frame.
  No timestamps; a separate file with one timestamp (seconds) per line may be given.
* **EuRoC**: CSV ``timestamp[ns], px, py, pz, qw, qx, qy, qz, ...`` (quaternion scalar *first*,
  more columns allowed and ignored).

Every reader validates each line and raises :class:`ValueError` naming the file and the
1-based line number for: a wrong number of fields, a non-numeric field, NaN or infinity, a
quaternion whose norm is off 1 by more than ``quat_tol`` and (KITTI) a matrix that is not a
rotation within ``rot_tol``. Accepted quaternions are normalised and accepted KITTI rotations
are projected onto SO(3) (nearest rotation in the Frobenius norm, via SVD) before they become
:class:`~microlie.SE3` poses.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .trajectory import Trajectory

__all__ = [
    "read_tum",
    "write_tum",
    "read_kitti",
    "write_kitti",
    "read_euroc",
    "read_timestamps",
    "read_trajectory",
    "FORMATS",
]

FORMATS = ("tum", "kitti", "euroc")

PathLike = str | os.PathLike


def _data_lines(path: PathLike, comma: bool) -> tuple[list[int], list[list[str]]]:
    """Return (1-based line numbers, split fields) of the non-comment, non-blank lines."""
    text = Path(path).read_text(encoding="utf-8-sig")
    numbers: list[int] = []
    rows: list[list[str]] = []
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#") or s.startswith("%"):
            continue
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


def _tokens_per_line(body: str, n: int) -> np.ndarray:
    """Number of whitespace-separated tokens on each of the ``n`` lines of ``body``."""
    b = np.frombuffer(body.encode("utf-8"), dtype=np.uint8)
    newline = b == 10
    ws = newline | (b == 32) | (b == 9) | (b == 13)
    start = ~ws
    start[1:] &= ws[:-1]
    line_of = np.searchsorted(np.flatnonzero(newline), np.flatnonzero(start))
    return np.bincount(line_of, minlength=n)[:n]


def _strip_comments(text: str) -> str:
    """Drop comment lines (``#`` or ``%`` first); header comments are the fast, usual case."""
    start = 0
    while True:
        probe = text[start:start + 1024].lstrip(" \t")
        if not probe.startswith(("#", "%")):
            break
        nl = text.find("\n", start)
        if nl < 0:
            return ""
        start = nl + 1
    body = text[start:]
    if "#" not in body and "%" not in body:
        return body
    return "\n".join(ln for ln in body.splitlines() if not ln.lstrip().startswith(("#", "%")))


def _fast_matrix(body: str, ncols: int, comma: bool, at_least: bool) -> np.ndarray | None:
    """Parse the data lines ``body`` (comments removed) in C; ``None`` if anything is off.

    Only a fast path: on ``None`` the caller re-parses line by line to name the bad line.
    """
    body = body.rstrip("\r\n")
    if not body:
        return None
    n = body.count("\n") + 1
    if comma or "," in body:
        body = body.replace(",", " ")
    if comma:
        first = body[: body.find("\n")] if n > 1 else body
        width = len(first.split())
        if width < ncols or (width != ncols and not at_least):
            return None
    else:
        width = ncols
    if not np.all(_tokens_per_line(body, n) == width):
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            vals = np.fromstring(body, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    if vals.size != n * width:
        return None
    mat = vals.reshape(n, width)[:, :ncols]
    if not np.isfinite(mat).all():
        return None
    return mat


class _LineNumbers:
    """1-based file line numbers of the data rows, computed only when an error is reported."""

    def __init__(self, path: PathLike, comma: bool, known: list[int] | None = None) -> None:
        self._path, self._comma, self._known = path, comma, known

    def __getitem__(self, i: int) -> int:
        if self._known is None:
            self._known = _data_lines(self._path, self._comma)[0]
        return self._known[i]


def _read_matrix(
    path: PathLike, ncols: int, *, comma: bool = False, at_least: bool = False, what: str = ""
) -> tuple[_LineNumbers, np.ndarray]:
    """(line numbers of the data rows, float matrix) of a numeric text file."""
    text = Path(path).read_text(encoding="utf-8-sig")
    body = _strip_comments(text)
    mat = _fast_matrix(body, ncols, comma, at_least)
    if mat is not None:
        return _LineNumbers(path, comma), mat
    numbers, rows = _data_lines(path, comma)
    mat = _to_matrix(path, numbers, rows, ncols, at_least=at_least, what=what)
    return _LineNumbers(path, comma, numbers), mat


def _check_quat(path: PathLike, numbers: _LineNumbers, q: np.ndarray, tol: float) -> None:
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > tol)
    if bad.size:
        i = bad[0]
        raise ValueError(
            f"{path}:{numbers[i]}: quaternion is not unit norm (|q| = {norms[i]:.6g}, "
            f"tolerance {tol:g})"
        )


def read_tum(path: PathLike, *, quat_tol: float = 1e-3, name: str | None = None) -> Trajectory:
    """Read a TUM trajectory ``timestamp tx ty tz qx qy qz qw`` (quaternion scalar last).

    Example:
        >>> traj = read_tum("groundtruth.txt")  # doctest: +SKIP
    """
    numbers, mat = _read_matrix(path, 8, what="timestamp tx ty tz qx qy qz qw")
    q = mat[:, 4:8]
    _check_quat(path, numbers, q, quat_tol)
    return Trajectory.from_arrays(
        mat[:, 1:4], q, timestamps=mat[:, 0], name=name or str(path)
    )


def read_timestamps(path: PathLike) -> np.ndarray:
    """Read one timestamp (seconds) per line, e.g. KITTI's ``times.txt``."""
    return _read_matrix(path, 1, what="timestamp")[1][:, 0]


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    """Project a batch of 3x3 matrices onto SO(3) (closest in the Frobenius norm)."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def read_kitti(
    path: PathLike,
    timestamps: PathLike | np.ndarray | None = None,
    *,
    rot_tol: float = 1e-3,
    name: str | None = None,
) -> Trajectory:
    """Read KITTI poses (12 numbers per line, row-major ``[R | t]``).

    ``timestamps`` is an optional file (one time in seconds per line) or array; without it
    the trajectory has no timestamps and is compared index by index. Rotations must satisfy
    ``|R^T R - I| <= rot_tol`` and ``det R > 0``; they are then projected onto SO(3).
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
    return Trajectory.from_rotation_matrices(
        t, _nearest_rotation(r), timestamps=stamps, name=name or str(path)
    )


def read_euroc(path: PathLike, *, quat_tol: float = 1e-3, name: str | None = None) -> Trajectory:
    """Read a EuRoC ground-truth CSV: ``t[ns], px, py, pz, qw, qx, qy, qz, ...``.

    Timestamps are converted from nanoseconds to seconds (``t_ns / 1e9`` in float64, as the
    other tools do, so associations agree). The quaternion is scalar-*first* in this format.
    """
    numbers, mat = _read_matrix(
        path, 8, comma=True, at_least=True, what="timestamp[ns], px, py, pz, qw, qx, qy, qz"
    )
    q_wxyz = mat[:, 4:8]
    _check_quat(path, numbers, q_wxyz, quat_tol)
    q_xyzw = np.roll(q_wxyz, -1, axis=1)
    return Trajectory.from_arrays(
        mat[:, 1:4], q_xyzw, timestamps=mat[:, 0] / 1e9, name=name or str(path)
    )


def read_trajectory(
    path: PathLike, fmt: str = "tum", *, timestamps: PathLike | None = None
) -> Trajectory:
    """Read ``path`` in format ``fmt`` (``"tum"``, ``"kitti"`` or ``"euroc"``)."""
    if fmt == "tum":
        return read_tum(path)
    if fmt == "kitti":
        return read_kitti(path, timestamps)
    if fmt == "euroc":
        return read_euroc(path)
    raise ValueError(f"unknown trajectory format {fmt!r}; expected one of {FORMATS}")


def write_tum(path: PathLike, traj: Trajectory, *, header: str | None = None) -> None:
    """Write ``traj`` as TUM text (``timestamp tx ty tz qx qy qz qw``, full precision).

    A trajectory without timestamps is written with its pose index as the timestamp.
    """
    stamps = traj.timestamps if traj.timestamps is not None else np.arange(len(traj), dtype=float)
    data = np.column_stack([stamps, traj.positions, traj.quat_xyzw])
    hdr = "timestamp tx ty tz qx qy qz qw" if header is None else header
    np.savetxt(path, data, fmt="%.17g", header=hdr)


def write_kitti(path: PathLike, traj: Trajectory) -> None:
    """Write ``traj`` as KITTI poses (row-major 3x4 ``[R | t]``, full precision)."""
    m = traj.matrices()[:, :3, :].reshape(-1, 12)
    np.savetxt(path, m, fmt="%.17g")
