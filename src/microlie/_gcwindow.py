"""Loading modules without cyclic garbage collection.

Importing NumPy and microlie allocates tens of thousands of long-lived objects; the collector
runs over them again and again while they load and finds nothing to free (some 7% of the import
time). ``with no_collection(): ...`` suspends the collector for the block and restores its
previous state.
"""

from __future__ import annotations

import gc
from types import TracebackType

__all__ = ["no_collection"]


class no_collection:  # noqa: N801 - used like a function: ``with no_collection(): ...``
    """Suspend the cyclic garbage collector for a ``with`` block (its state is restored).

    Examples
    --------
    >>> import gc
    >>> from microlie._gcwindow import no_collection
    >>> with no_collection():
    ...     gc.isenabled()
    False
    >>> gc.isenabled()
    True
    """

    def __enter__(self) -> None:
        self._enabled = gc.isenabled()
        gc.disable()

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._enabled:
            gc.enable()
