"""Reading and writing "Bundle Adjustment in the Large" (BAL) problem files.

Format (Agarwal et al., ECCV 2010): a header ``n_cameras n_points n_observations``; one line
``camera_index point_index x y`` per observation; then ``9 n_cameras`` camera numbers
(angle-axis rotation (3), translation (3), focal length, k1, k2) and ``3 n_points`` point
coordinates, one per line (as BAL's files and :func:`write_bal` have them) or one camera (9)
and one point (3) per line. The file is UTF-8 (a byte order mark is dropped). The camera maps
a world point to its frame with ``P = R X + t`` and looks down ``-z`` (see
:mod:`microlie.optim.sfm.camera`).

Malformed files raise ``ValueError`` naming ``file:line``: a byte that is not UTF-8, truncated
files, counts that do not match, wrong field counts on any line, non-numeric or non-finite
values, observations of missing cameras or points.

>>> import numpy as np, io
>>> text = "1 1 1\\n0 0 10.0 -20.0\\n" + "\\n".join(["0"] * 5 + ["-5", "500", "0", "0"]
...                                            + ["0.1", "-0.2", "0"]) + "\\n"
>>> p = read_bal(io.StringIO(text))
>>> p.n_cameras, p.n_points, p.n_observations
(1, 1, 1)
>>> round(p.cost(), 12)
0.0
"""

from __future__ import annotations

import codecs
import io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from ..._files import atomic_write
from ..._textfile import decode, digits_only, numbers_by_line, plain_error

__all__ = ["BALProblem", "read_bal", "write_bal"]


@dataclass(frozen=True)
class BALProblem:
    """A Bundle Adjustment in the Large problem, as stored in a BAL file.

    Parameters
    ----------
    cameras : numpy.ndarray
        ``(n_cameras, 9)``: rotation vector, translation, ``f``, ``k1``, ``k2``.
    points : numpy.ndarray
        ``(n_points, 3)``.
    camera_index, point_index : numpy.ndarray
        ``(n_observations,)`` the camera and point of each observation.
    observations : numpy.ndarray
        ``(n_observations, 2)`` in pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> bal.cost()
    0.0
    """

    cameras: np.ndarray
    points: np.ndarray
    camera_index: np.ndarray
    point_index: np.ndarray
    observations: np.ndarray

    @property
    def n_cameras(self) -> int:
        return int(self.cameras.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_observations(self) -> int:
        return int(self.observations.shape[0])

    def __repr__(self) -> str:
        return (f"BALProblem({self.n_cameras} cameras, {self.n_points} points, "
                f"{self.n_observations} observations)")

    def residuals(self, behind: str = "evaluate") -> np.ndarray:
        """Reprojection residuals (predicted minus observed) of the BAL model at these values.

        Parameters
        ----------
        behind : {"evaluate", "drop"}
            Points behind a camera: evaluated (BAL convention) or dropped (GTSAM/COLMAP), see
            :mod:`microlie.optim.sfm.camera`.

        Returns
        -------
        numpy.ndarray
            ``(n_observations, 2)``, pixels.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> float(np.abs(bal.residuals()).max())
        0.0
        """
        from ...groups import SO3
        from ..sfm.camera import BALCamera, reproject

        R = np.asarray(SO3.exp(np.asarray(self.cameras[:, :3], dtype=float)).matrix())
        return reproject(BALCamera(), R, self.cameras[:, 3:6], self.cameras[:, 6:9],
                         self.points, self.camera_index, self.point_index, self.observations,
                         jac=False, behind=behind).residuals  # type: ignore[arg-type]

    def cost(self, behind: str = "evaluate") -> float:
        """``0.5 * sum |r|^2`` in pixels (no robust loss).

        Parameters
        ----------
        behind : {"evaluate", "drop"}
            Points behind a camera: evaluated (BAL convention) or dropped (GTSAM/COLMAP), see
            :mod:`microlie.optim.sfm.camera`.

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> moved = BALProblem(cams, pts + 0.01, ci, pi, uv)
        >>> moved.cost() > 0
        True
        """
        r = self.residuals(behind)
        return 0.5 * float(np.sum(r * r))


def _source(src: str | os.PathLike | IO[str]) -> tuple[bytes | None, str, str]:
    """(the file's bytes, or ``None`` for a stream; the stream's text, or ``""``; a name)."""
    if isinstance(src, (str, os.PathLike)):
        return Path(src).read_bytes(), "", os.fspath(src)
    text = src.read()
    return None, text[1:] if text.startswith("\ufeff") else text, getattr(src, "name",
                                                                              "<stream>")


def read_bal(src: str | os.PathLike | IO[str]) -> BALProblem:
    """Read a BAL file.

    The file is UTF-8 text (a byte order mark is dropped). The parameters come one per line
    (BAL's layout) or one camera (9 numbers) and one point (3) per line; every line's count is
    checked, so a number moved from one line to another is an error, not a shifted value.
    Numbers follow Python's ``int`` and ``float`` rules in plain ASCII (no ``_`` separators,
    no other scripts' digits, no non-ASCII spaces); plain files are parsed in bulk
    (bit-identical values).

    Parameters
    ----------
    src : str, os.PathLike or text stream
        The file or an open stream.

    Returns
    -------
    BALProblem

    Raises
    ------
    ValueError
        A malformed file, with ``file:line``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> import io
    >>> from microlie.optim import read_bal, write_bal
    >>> buf = io.StringIO()
    >>> write_bal(buf, bal)
    >>> back = read_bal(io.StringIO(buf.getvalue()))
    >>> bool((back.points == bal.points).all())
    True
    """
    data, text, name = _source(src)
    if data is None and text.isascii():
        data = text.encode("ascii")
    if data is not None:
        if data.startswith(codecs.BOM_UTF8):
            data = data[len(codecs.BOM_UTF8):]
        if data.isascii():
            problem = _read_bulk(data)
            if problem is not None:
                return problem
        text = decode(data, name)
        del data
    return _read_lines(text, name)


def _read_bulk(data: bytes) -> BALProblem | None:
    """The problem of a well-formed plain file, converted in bulk; ``None`` for anything
    else (the line-by-line reader then reads it, or names the bad line). See
    :func:`microlie._textfile.numbers_by_line`."""
    bulk = numbers_by_line(data)
    if bulk is None:
        return None
    vals, tok, per_line = bulk
    counts = per_line[per_line > 0]  # blank lines are skipped
    del per_line
    if not counts.size or counts[0] != 3 or not digits_only(data, tok[:3], vals[:3]):
        return None
    nc, npt, no = (int(h) for h in vals[:3])
    need = 9 * nc + 3 * npt
    if (min(nc, npt, no) <= 0 or counts.size < 1 + no or tok.size != 3 + 4 * no + need
            or not (counts[1:1 + no] == 4).all()):
        return None
    par = counts[1 + no:]
    if not ((par == 1).all() or (par.size == nc + npt and (par[:nc] == 9).all()
                                 and (par[nc:] == 3).all())):
        return None
    del counts, par
    if not np.isfinite(vals).all():
        return None
    obs = vals[3:3 + 4 * no].reshape(no, 4)
    index = np.empty((2, no), dtype=np.intp)
    for col, limit in ((0, nc), (1, npt)):
        v = obs[:, col]
        if not ((v < limit).all() and digits_only(data, tok[3 + col:3 + 4 * no:4], v)):
            return None
        index[col] = v
    del tok
    return BALProblem(vals[3 + 4 * no:3 + 4 * no + 9 * nc].reshape(nc, 9).copy(),
                      vals[3 + 4 * no + 9 * nc:].reshape(npt, 3).copy(),
                      index[0], index[1], obs[:, 2:].copy())


def _read_lines(text: str, name: str) -> BALProblem:
    """Read line by line with Python's ``int`` and ``float`` on plain ASCII lines, naming the
    first bad line."""
    raw = text.splitlines()
    numbers = [k + 1 for k, ln in enumerate(raw) if ln.strip()]   # blank lines are skipped
    lines = [raw[k - 1] for k in numbers]

    def fail(k: int, msg: str) -> ValueError:
        """An error at the ``k``-th non-blank line (1-based); past the end: the last line + 1."""
        lineno = numbers[k - 1] if k <= len(numbers) else len(raw) + 1
        return ValueError(f"{name}:{lineno}: {msg}")

    for k, ln in enumerate(lines, start=1):
        why = plain_error(ln)
        if why is not None:
            raise fail(k, why)
    if not lines or not lines[0].split():
        raise fail(1, "empty file: expected the header 'n_cameras n_points n_observations'")
    head = lines[0].split()
    if len(head) != 3:
        raise fail(1, f"header must be 'n_cameras n_points n_observations', got {lines[0]!r}")
    try:
        nc, npt, no = (int(h) for h in head)
    except ValueError:
        raise fail(1, f"header counts must be integers, got {lines[0]!r}") from None
    if nc <= 0 or npt <= 0 or no <= 0:
        raise fail(1, f"header counts must be positive, got {nc} {npt} {no}")
    if len(lines) < 1 + no:
        raise fail(len(lines) + 1, f"unexpected end of file: the header announces {no} "
                   f"observations, only {len(lines) - 1} observation lines follow")
    obs_lines = lines[1:1 + no]
    fields = [ln.split() for ln in obs_lines]
    for k, f in enumerate(fields):
        if len(f) != 4:
            raise fail(2 + k, f"an observation line has 4 fields 'camera point x y', got "
                       f"{len(f)}: {obs_lines[k]!r}")
    index = np.zeros((no, 2), dtype=np.int64)
    for k, f in enumerate(fields):
        if not (_is_int(f[0]) and _is_int(f[1])):
            raise fail(2 + k, f"camera and point indices must be integers: {obs_lines[k]!r}")
        for col, what, limit, kind in ((0, "camera", nc, "cameras"),
                                       (1, "point", npt, "points")):
            v = int(f[col])
            if not 0 <= v < limit:
                raise fail(2 + k, f"observation of missing {what} {v} (the header declares "
                           f"{limit} {kind})")
            index[k, col] = v
    try:
        uv = np.array([(f[2], f[3]) for f in fields], dtype=float).reshape(no, 2)
    except (ValueError, OverflowError):
        for k, f in enumerate(fields):
            if not (_is_float(f[2]) and _is_float(f[3])):
                raise fail(2 + k, f"observation coordinates must be numbers: "
                           f"{obs_lines[k]!r}") from None
        raise
    bad = np.nonzero(~np.isfinite(uv).all(axis=1))[0]
    if len(bad):
        k = int(bad[0])
        raise fail(2 + k, f"non-finite observation: {obs_lines[k]!r}")
    # parameters: a token stream with line numbers
    need = 9 * nc + 3 * npt
    tokens: list[str] = []
    token_line: list[int] = []
    per_line: list[int] = []
    for k in range(1 + no, len(lines)):
        toks = lines[k].split()
        tokens.extend(toks)
        token_line.extend([k + 1] * len(toks))
        per_line.append(len(toks))
    if len(tokens) < need:
        raise fail(len(lines) + 1, f"unexpected end of file: expected {need} parameters "
                   f"(9 x {nc} cameras + 3 x {npt} points), found {len(tokens)}")
    if len(tokens) > need:
        raise fail(token_line[need], f"unexpected data after the {need} parameters: the "
                   f"counts in the header do not match the file ({len(tokens)} values)")
    layout = [9] * nc + [3] * npt if per_line[0] == 9 else [1] * need
    for k, (got, want) in enumerate(zip(per_line, layout, strict=False)):
        if got != want:
            raise fail(2 + no + k, f"{got} numbers on a parameter line where {want} "
                       "belong: BAL parameters come one per line (or 9 per camera line and "
                       "3 per point line)")
    try:
        vals = np.array(tokens, dtype=float)
    except (ValueError, OverflowError):
        for k, t in enumerate(tokens):
            if not _is_float(t):
                raise fail(token_line[k], f"parameter is not a number: {t!r}") from None
        raise
    bad = np.nonzero(~np.isfinite(vals))[0]
    if len(bad):
        k = int(bad[0])
        what = (f"camera {k // 9} parameter {k % 9}" if k < 9 * nc
                else f"point {(k - 9 * nc) // 3} coordinate {(k - 9 * nc) % 3}")
        raise fail(token_line[k], f"non-finite value {tokens[k]!r} ({what})")
    return BALProblem(vals[:9 * nc].reshape(nc, 9), vals[9 * nc:].reshape(npt, 3),
                      index[:, 0].astype(np.intp), index[:, 1].astype(np.intp), uv)


def _is_int(s: str) -> bool:
    try:
        int(s)
    except ValueError:
        return False
    return True


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def write_bal(dst: str | os.PathLike | IO[str], problem: BALProblem) -> None:
    """Write ``problem`` in BAL format (shortest round-trip digits: reading it back is exact).

    Parameters
    ----------
    dst : str, os.PathLike or text stream
        The file or an open stream.
    problem : BALProblem
        The problem.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> import io
    >>> from microlie.optim import write_bal
    >>> buf = io.StringIO()
    >>> write_bal(buf, bal)
    >>> buf.getvalue().split(chr(10))[0]
    '2 6 12'
    """
    p = problem
    buf = io.StringIO()
    buf.write(f"{p.n_cameras} {p.n_points} {p.n_observations}\n")
    for c, j, (x, y) in zip(p.camera_index.tolist(), p.point_index.tolist(),
                            p.observations.tolist(), strict=True):
        buf.write(f"{c} {j} {x!r} {y!r}\n")
    vals = np.concatenate([p.cameras.reshape(-1), p.points.reshape(-1)]).tolist()
    buf.write("\n".join(repr(v) for v in vals))
    buf.write("\n")
    if isinstance(dst, (str, os.PathLike)):
        with atomic_write(dst) as fh:  # a temporary file renamed over ``dst``
            fh.write(buf.getvalue())
    else:
        dst.write(buf.getvalue())
