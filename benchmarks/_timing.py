"""Small timing helpers shared by the benchmark scripts.

Everything is measured with :func:`time.perf_counter`; the reported figure is the best (minimum)
of several repeats, which is the least noisy estimate of what the code itself costs on a shared
machine. The garbage collector is switched off inside a timed region (as :mod:`timeit` does).
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class Timing:
    """Best time of one call of a prepared callable, plus how it was measured."""

    best_s: float  # best (minimum) seconds for ONE call of the callable
    number: int  # calls per repeat
    repeat: int  # repeats

    def per_element_ns(self, n: int) -> float:
        return self.best_s / n * 1e9

    def us(self) -> float:
        return self.best_s * 1e6


def run_loop(fn: Callable[[], object], number: int) -> float:
    """Seconds for ``number`` back-to-back calls of ``fn`` (garbage collector off)."""
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        t1 = time.perf_counter()
    finally:
        if gc_was_enabled:
            gc.enable()
    return t1 - t0


def calibrate(fn: Callable[[], object], target_s: float = 0.05, max_number: int = 1_000_000) -> int:
    """Smallest number of loops (1, 2, 5, 10, 20, ...) whose total time reaches ``target_s``."""
    number = 1
    while True:
        for mult in (1, 2, 5):
            n = number * mult
            if n >= max_number:
                return max_number
            if run_loop(fn, n) >= target_s:
                return n
        number *= 10


def best_of(
    fn: Callable[[], object],
    *,
    repeat: int = 5,
    number: int | None = None,
    target_s: float = 0.05,
    warmup: int = 1,
) -> Timing:
    """Best-of-``repeat`` time of one call of ``fn``.

    ``number`` loops per repeat; when ``None`` it is calibrated so one repeat takes about
    ``target_s`` seconds (use that for the single-element latency regime; pass ``number=1`` for
    the batched regime). ``warmup`` untimed calls come first (JIT caches, allocator, lazy imports).
    """
    for _ in range(warmup):
        fn()
    if number is None:
        number = calibrate(fn, target_s)
    best = min(run_loop(fn, number) for _ in range(repeat))
    return Timing(best / number, number, repeat)


def best_interleaved(
    fns: Mapping[Hashable, Callable[[], object]], plan: Mapping[Hashable, tuple[int, int]]
) -> dict[Hashable, float | Exception]:
    """Best seconds per call of several callables, measured round-robin.

    ``plan[key] = (number, repeat)``. In each round every callable still due runs ``number``
    calls, so a burst of load from another process hits all of them alike instead of the one
    that happened to be running; each keeps its best round. A callable that raises gets the
    exception as its result and drops out.
    """
    best: dict[Hashable, float | Exception] = {key: float("inf") for key in plan}
    for rnd in range(max((rep for _, rep in plan.values()), default=0)):
        for key, (number, repeat) in plan.items():
            if rnd >= repeat or isinstance(best[key], Exception):
                continue
            try:
                best[key] = min(best[key], run_loop(fns[key], number) / number)
            except Exception as e:  # reported by the caller
                best[key] = e
    return best
