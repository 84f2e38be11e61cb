"""Decoding the text of data files for the readers (g2o, TORO, BAL, trajectories, results).

Files are UTF-8; a leading byte order mark (``EF BB BF``) is dropped, as every reader accepts
it. A byte that is not UTF-8 is a ``ValueError("FILE:LINE: ...")``, the readers' error for a
malformed line, with lines counted as :meth:`str.splitlines` counts them (as the readers do).

>>> from microlie._textfile import decode
>>> decode(b"\\xef\\xbb\\xbf1 2\\n", "f.txt")
'1 2\\n'
>>> decode(b"1 2\\n# caf\\xe9\\n", "f.txt")
Traceback (most recent call last):
...
ValueError: f.txt:2: byte 0xe9 (column 6) is not UTF-8: save the file as UTF-8
"""

from __future__ import annotations

import codecs
import os
import warnings
from pathlib import Path

import numpy as np

__all__ = ["decode", "read_text", "numbers_by_line", "digits_only"]


def decode(data: bytes, name: str) -> str:
    """The UTF-8 text of ``data`` without a leading byte order mark.

    Parameters
    ----------
    data : bytes
        The file's bytes.
    name : str
        The file's name, for the message.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        ``"NAME:LINE: byte 0x.. (column C) is not UTF-8 ..."`` at the first bad byte.
    """
    if data.startswith(codecs.BOM_UTF8):
        data = data[len(codecs.BOM_UTF8):]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        before = data[:exc.start].decode("utf-8")
        lines = (before + "x").splitlines()
        raise ValueError(f"{name}:{len(lines)}: byte 0x{data[exc.start]:02x} (column "
                         f"{len(lines[-1])}) is not UTF-8: save the file as UTF-8") from None


def read_text(path: str | os.PathLike[str]) -> str:
    """The text of the file ``path`` (see :func:`decode`).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    str
    """
    return decode(Path(path).read_bytes(), str(path))


def plain_error(line: str) -> str | None:
    """Why a data line of numbers is not plain ASCII, or ``None`` when it is.

    Python's ``int``/``float`` would read ``1_0`` as 10 and Arabic-Indic digits as digits, and
    ``str.split`` splits at a no-break space: in a data file these are damage, not numbers, so
    every reader refuses them (naming ``FILE:LINE``) rather than repairing them silently.

    Parameters
    ----------
    line : str
        The numbers of one line (a tag before them excluded).

    Returns
    -------
    str or None

    Examples
    --------
    >>> from microlie._textfile import plain_error
    >>> plain_error("1 2.5e-3 -4") is None
    True
    >>> plain_error("1_0 2").split(":")[0]
    "character '_' (U+005F) in '1_0 2'"
    """
    if line.isascii() and "_" not in line:
        return None
    ch = next(c for c in line if c == "_" or not c.isascii())
    return (f"character {ch!r} (U+{ord(ch):04X}) in {line.strip()!r}: write numbers with ASCII "
            "digits, no digit separators, fields separated by spaces or tabs")


# bytes of the bulk parsers: the ASCII whitespace they split at, and what numbers are made of
_WS = np.zeros(256, dtype=bool)
_WS[[9, 10, 13, 32]] = True
_NUMERIC = _WS.copy()
_NUMERIC[np.frombuffer(b"0123456789+-.eE", dtype=np.uint8)] = True
_CHUNK = 1 << 18
_POW10 = 10 ** np.arange(1, 19, dtype=np.int64)


def numbers_by_line(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Every number of ``data`` and how many each line holds, converted in bulk.

    Only digits, ``+-.eE``, spaces, tabs and line ends (``\\n``, ``\\r\\n``) are taken;
    anything else gives ``None`` (the caller then reads line by line, with Python's ``float``,
    and names the bad line). Token starts are found chunk by chunk (little memory beyond the
    numbers) and the numbers are converted by :func:`numpy.fromstring`, which rounds as
    ``float`` does.

    Parameters
    ----------
    data : bytes
        The text.

    Returns
    -------
    values : numpy.ndarray
        ``(T,)`` float64, every number in order.
    starts : numpy.ndarray
        ``(T,)`` the byte offset of each number.
    counts : numpy.ndarray
        ``(L,)`` how many numbers each line holds (blank lines hold 0).

    Examples
    --------
    >>> from microlie._textfile import numbers_by_line
    >>> values, starts, counts = numbers_by_line(b"1 2\\n\\n3.5\\n")
    >>> values.tolist(), starts.tolist(), counts.tolist()
    ([1.0, 2.0, 3.5], [0, 2, 5], [2, 0, 1])
    >>> numbers_by_line(b"1 x\\n") is None
    True
    """
    n = len(data)
    if n == 0 or data.count(b"\r") != data.count(b"\r\n"):
        return None
    arr = np.frombuffer(data, dtype=np.uint8)
    idx = np.int32 if n < 2**31 - 1 else np.int64
    starts: list[np.ndarray] = []
    ends: list[np.ndarray] = []
    prev_ws = True
    for a in range(0, n, _CHUNK):
        chunk = arr[a:a + _CHUNK]
        if not _NUMERIC[chunk].all():
            return None
        ws = _WS[chunk]
        st = ~ws
        st[1:] &= ws[:-1]
        st[0] &= prev_ws
        prev_ws = bool(ws[-1])
        starts.append(np.flatnonzero(st).astype(idx) + a)
        ends.append(np.flatnonzero(chunk == 10).astype(idx) + a)
    if data[-1:] != b"\n":
        ends.append(np.array([n], dtype=idx))
    tok, line_end = np.concatenate(starts), np.concatenate(ends)
    del starts, ends
    counts = np.diff(np.searchsorted(tok, line_end), prepend=0)
    del line_end
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # NumPy warns when a token is not a number
        try:
            values = np.fromstring(data, sep=" ")  # type: ignore[call-overload]
        except (DeprecationWarning, ValueError):
            return None
    if values.size != tok.size:
        return None
    return values, tok, counts


def digits_only(data: bytes, starts: np.ndarray, values: np.ndarray) -> bool:
    """Whether the numbers at byte offsets ``starts`` of ``data`` are written as the plain
    digits of ``values``, integers below ``2**53`` (so that the float64 ``values`` are exact),
    as ``int`` reads them: not ``1.0``, ``1e0``, ``+1`` or ``01``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie._textfile import digits_only
    >>> digits_only(b"10 7", np.array([0, 3]), np.array([10.0, 7.0]))
    True
    >>> digits_only(b"10 7.0", np.array([0, 3]), np.array([10.0, 7.0]))
    False
    >>> digits_only(b"9007199254740993", np.array([0]), np.array([9007199254740993.0]))
    False
    """
    if not starts.size:
        return True
    if not ((values >= 0) & (values < 2**53) & (values == np.floor(values))).all():
        return False
    arr = np.frombuffer(data, dtype=np.uint8)
    n = arr.size
    at = starts.astype(np.int64)
    nd = 1 + np.searchsorted(_POW10, values.astype(np.int64), side="right")
    after = at + nd
    if not ((after == n) | _WS[arr[np.minimum(after, n - 1)]]).all():
        return False
    for d in range(int(nd.max())):
        m = nd > d
        if not (arr[at[m] + d] - 48 < 10).all():
            return False
    return True
