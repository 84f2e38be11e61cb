"""The trajectory file formats: one registry for the readers, the writers and the command line.

Importing this module is cheap (no NumPy): the command line builds its choices from it before
deciding what to load. :func:`microlie.traj.read_trajectory` and
:func:`microlie.traj.write_trajectory` dispatch through it, so a new format is one entry here
(plus its reader and writer).

>>> from microlie.traj.formats import FORMATS, WRITABLE
>>> list(FORMATS), WRITABLE
(['tum', 'kitti', 'euroc', 'bag'], ('tum', 'kitti', 'euroc'))
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

__all__ = ["TrajectoryFormat", "FORMATS", "WRITABLE", "trajectory_format"]


@dataclass(frozen=True)
class TrajectoryFormat:
    """One trajectory format: where its reader and writer live and what they take.

    Attributes
    ----------
    name : str
        The format word (``--format``, evo's leading word).
    reader : str
        ``"module:function"`` called as ``reader(path, **options)``.
    writer : str or None
        ``"module:function"`` called as ``writer(path, trajectory)``; ``None``: read only.
    options : tuple of str
        The keyword options its reader takes (``read_trajectory`` passes these only).
    suffix : str
        The file suffix ``--save_as`` gives it.

    Examples
    --------
    >>> from microlie.traj.formats import FORMATS
    >>> FORMATS["kitti"].options
    ('timestamps',)
    """

    name: str
    reader: str
    writer: str | None
    options: tuple[str, ...] = ()
    suffix: str = ""

    def load(self, which: str) -> Any:
        """The reader (``which="reader"``) or the writer, imported on use.

        Parameters
        ----------
        which : {"reader", "writer"}
            The function.

        Returns
        -------
        callable

        Examples
        --------
        >>> from microlie.traj.formats import FORMATS
        >>> FORMATS["tum"].load("reader").__name__
        'read_tum'
        """
        target = getattr(self, which)
        if target is None:
            raise ValueError(f"trajectory format {self.name!r} cannot be written; writable: "
                             f"{', '.join(WRITABLE)}")
        module, _, name = target.partition(":")
        return getattr(importlib.import_module(module), name)


FORMATS: dict[str, TrajectoryFormat] = {f.name: f for f in (
    TrajectoryFormat("tum", "microlie.traj.io:read_tum", "microlie.traj.io:write_tum",
                     suffix=".tum"),
    TrajectoryFormat("kitti", "microlie.traj.io:read_kitti", "microlie.traj.io:write_kitti",
                     ("timestamps",), ".kitti"),
    TrajectoryFormat("euroc", "microlie.traj.io:read_euroc", "microlie.traj.io:write_euroc",
                     suffix=".csv"),
    TrajectoryFormat("bag", "microlie.traj.rosbag:read_bag", None, ("topic",)),
)}
WRITABLE: tuple[str, ...] = tuple(n for n, f in FORMATS.items() if f.writer is not None)


def trajectory_format(name: str, write: bool = False) -> TrajectoryFormat:
    """The registry entry of a format, with the error a user needs when there is none.

    Parameters
    ----------
    name : str
        The format word.
    write : bool
        The format must be writable.

    Returns
    -------
    TrajectoryFormat

    Raises
    ------
    ValueError
        Unknown (or, with ``write``, read-only) format.

    Examples
    --------
    >>> from microlie.traj.formats import trajectory_format
    >>> trajectory_format("euroc", write=True).suffix
    '.csv'
    """
    known = WRITABLE if write else tuple(FORMATS)
    if name not in known:
        raise ValueError(f"unknown trajectory format {name!r} to {'write' if write else 'read'}; "
                         f"expected one of {known}")
    return FORMATS[name]
