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
from pathlib import Path

__all__ = ["decode", "read_text"]


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
