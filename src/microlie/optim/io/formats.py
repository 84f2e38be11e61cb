"""The estimation file formats: one registry for reading, writing, detection and the command line.

Each entry names its reader, its writer and the ``microlie optimize`` handler as
``"module:function"`` strings imported on use, so building the command line's choices costs no
import. A new format is one entry here (plus its reader, writer and, if it is a new kind of
problem, its handler).

>>> from microlie.optim.io.formats import FORMATS
>>> [(f.name, f.kind) for f in FORMATS.values()]
[('g2o', 'pose_graph'), ('toro', 'pose_graph'), ('bal', 'bundle')]
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["GraphFormat", "FORMATS", "detect_format", "output_format"]


@dataclass(frozen=True)
class GraphFormat:
    """One file format of an estimation problem.

    Attributes
    ----------
    name : str
        The ``--format`` word.
    kind : {"pose_graph", "bundle"}
        What a file holds.
    reader, writer : str
        ``"module:function"``: ``reader(path)`` (a pose-graph reader also takes
        ``information=``, :mod:`microlie.optim.io.information`) and
        ``writer(path, problem, ...)``.
    handler : str
        ``"module:function"`` that ``microlie optimize`` runs as ``handler(args, err) -> dict``.
    suffixes : tuple of str
        File suffixes that select this format for an output file.
    tags : tuple of str
        First words of a data line that identify the format (exact match).
    prefixes : tuple of str
        First-word prefixes that identify it.
    int_header : int
        A first data line of this many non-negative integers identifies it (0: no such rule).

    Examples
    --------
    >>> from microlie.optim.io.formats import FORMATS
    >>> FORMATS["toro"].suffixes
    ('.graph', '.toro')
    """

    name: str
    kind: str
    reader: str
    writer: str
    handler: str
    suffixes: tuple[str, ...] = ()
    tags: tuple[str, ...] = ()
    prefixes: tuple[str, ...] = ()
    int_header: int = 0

    def load(self, which: str) -> Any:
        """``reader``, ``writer`` or ``handler``, imported on use.

        Parameters
        ----------
        which : {"reader", "writer", "handler"}
            The function.

        Returns
        -------
        callable

        Examples
        --------
        >>> from microlie.optim.io.formats import FORMATS
        >>> FORMATS["g2o"].load("reader").__name__
        'read_g2o'
        """
        module, _, name = getattr(self, which).partition(":")
        return getattr(importlib.import_module(module), name)

    def matches(self, tokens: list[str]) -> bool:
        """Whether a data line's words identify this format.

        Parameters
        ----------
        tokens : list of str
            The words of the first data line.

        Returns
        -------
        bool

        Examples
        --------
        >>> from microlie.optim.io.formats import FORMATS
        >>> FORMATS["bal"].matches(["16", "22106", "83718"])
        True
        """
        tag = tokens[0]
        if tag in self.tags or tag.startswith(self.prefixes or ("\0",)):
            return True
        return bool(self.int_header) and len(tokens) == self.int_header and all(
            t.isdigit() for t in tokens)


_POSE_GRAPH = "microlie.optim.command:run_pose_graph"
FORMATS: dict[str, GraphFormat] = {f.name: f for f in (
    GraphFormat("g2o", "pose_graph", "microlie.optim.io.g2o:read_g2o",
                "microlie.optim.io.g2o:write_g2o", _POSE_GRAPH, (".g2o",), tags=("FIX",),
                prefixes=("VERTEX_", "EDGE_")),
    GraphFormat("toro", "pose_graph", "microlie.optim.io.toro:read_toro",
                "microlie.optim.io.toro:write_toro", _POSE_GRAPH, (".graph", ".toro"),
                tags=("VERTEX2", "EDGE2", "VERTEX3", "EDGE3")),
    GraphFormat("bal", "bundle", "microlie.optim.io.bal:read_bal",
                "microlie.optim.io.bal:write_bal", "microlie.optim.command_bal:run_bal",
                (".bal",), int_header=3),
)}


def detect_format(path: str | Path) -> str:
    r"""The format of a file from its first data line.

    Parameters
    ----------
    path : str or pathlib.Path
        The file.

    Returns
    -------
    str
        A key of :data:`FORMATS`.

    Raises
    ------
    ValueError
        No known format (``FILE:LINE``), or no data line.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.optim.io.formats import detect_format
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write("VERTEX_SE2 0 0 0 0\n")
    >>> detect_format(path)
    'g2o'
    """
    # only the tag is needed here: a byte that is not UTF-8 is left to the reader to report
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for lineno, line in enumerate(f, start=1):
            toks = line.split()
            if not toks or toks[0].startswith("#"):
                continue
            for fmt in FORMATS.values():  # no first word matches two of them
                if fmt.matches(toks):
                    return fmt.name
            raise ValueError(f"{path}:{lineno}: cannot tell the file format from {toks[0]!r}; "
                             "give --format")
    raise ValueError(f"{path}: the file has no data lines")


def output_format(path: str | Path, fmt: str) -> GraphFormat:
    """The format to write ``path`` in: the one its suffix names among those of the same kind
    as ``fmt``, else ``fmt``.

    Parameters
    ----------
    path : str or pathlib.Path
        The output file.
    fmt : str
        The input's format.

    Returns
    -------
    GraphFormat

    Examples
    --------
    >>> from microlie.optim.io.formats import output_format
    >>> output_format("out.graph", "g2o").name, output_format("out.txt", "toro").name
    ('toro', 'toro')
    """
    suffix = Path(path).suffix.lower()
    kind = FORMATS[fmt].kind
    for f in FORMATS.values():
        if f.kind == kind and suffix in f.suffixes:
            return f
    return FORMATS[fmt]
