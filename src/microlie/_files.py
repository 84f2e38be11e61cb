"""Writing files safely: every writer of the package goes through :func:`atomic_write`.

:func:`atomic_write` writes a temporary file in the target's folder and renames it over the
target only once everything is written and flushed to disk, so a write that fails midway (a
full disk, an exception while formatting) leaves the old file byte-identical and no temporary
file behind. :func:`save_figure` does the same for a Matplotlib figure. :func:`check_not_input`
is the commands' refusal to write onto one of their own input files without ``--force``.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator
from typing import IO, Any

__all__ = ["atomic_write", "save_figure", "check_not_input"]

PathLike = str | os.PathLike


@contextlib.contextmanager
def atomic_write(path: PathLike, mode: str = "w", *,
                 encoding: str | None = "utf-8") -> Iterator[IO[Any]]:
    r"""Open a temporary file next to ``path`` for writing; rename it to ``path`` on success.

    On an exception inside the ``with`` block (or while flushing) the temporary file is removed,
    ``path`` is left as it was and the exception propagates (an ``OSError`` names ``path``). A
    symbolic link is followed (the file it points to is replaced); a new file gets the usual
    permissions (``0o666`` less the umask), a replaced file keeps its own.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    mode : {"w", "wb"}
        Text or binary.
    encoding : str, optional
        Text encoding (``mode="w"`` only; default UTF-8).

    Yields
    ------
    file object
        The open temporary file.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie._files import atomic_write
    >>> path = os.path.join(tempfile.mkdtemp(), "a.txt")
    >>> with atomic_write(path) as f:
    ...     _ = f.write("new\n")
    >>> open(path).read()
    'new\n'
    >>> try:
    ...     with atomic_write(path) as f:
    ...         _ = f.write("partial")
    ...         raise RuntimeError("failed midway")
    ... except RuntimeError:
    ...     pass
    >>> open(path).read(), os.listdir(os.path.dirname(path))
    ('new\n', ['a.txt'])
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    target = os.path.realpath(os.fspath(path))
    folder, name = os.path.split(target)
    try:
        st_mode = os.stat(target).st_mode & 0o7777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        st_mode = 0o666 & ~umask
    import tempfile  # on use: not on the import path of the commands

    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, st_mode)
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename is None:
            raise OSError(exc.errno, f"{path}: writing failed ({exc.strerror or exc}); the file "
                                     "was left unchanged") from exc
        raise


def save_figure(fig: Any, path: PathLike, **kwargs: Any) -> None:
    """``fig.savefig(path, **kwargs)`` through :func:`atomic_write` (format from the suffix).

    Examples
    --------
    >>> import os, tempfile
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> from matplotlib.figure import Figure
    >>> from microlie._files import save_figure
    >>> path = os.path.join(tempfile.mkdtemp(), "f.png")
    >>> save_figure(Figure(), path)
    >>> open(path, "rb").read(4)
    b'\\x89PNG'
    """
    suffix = os.path.splitext(os.fspath(path))[1].lstrip(".").lower()
    kwargs.setdefault("format", suffix or None)
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, **kwargs)


def check_not_input(output: PathLike | None, inputs: Iterable[PathLike | None], *,
                    option: str = "-o", force: bool = False) -> None:
    """Refuse to write ``output`` when it is one of ``inputs`` (the same file, through links
    too), unless ``force``.

    Raises
    ------
    ValueError
        Naming ``option``, the file and what to do (``--force``, or another path).

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie._files import check_not_input
    >>> path = os.path.join(tempfile.mkdtemp(), "c.g2o")
    >>> _ = open(path, "w").write("FIX 0\\n")
    >>> check_not_input(path, [path], force=True)
    >>> check_not_input(path + ".out", [path])
    >>> try:
    ...     check_not_input(path, [path])
    ... except ValueError as e:
    ...     print(str(e).split(": ")[0])
    -o
    """
    if output is None or not os.path.exists(output):
        return
    for inp in inputs:
        if inp is not None and not force and os.path.exists(inp) and os.path.samefile(output,
                                                                                        inp):
            raise ValueError(f"{option}: {os.fspath(output)} is the input file "
                             f"{os.fspath(inp)}; writing it would replace the input. Pass "
                             "--force to overwrite it, or choose another path")
