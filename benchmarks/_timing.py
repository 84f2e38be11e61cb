"""Small timing helpers shared by the benchmark scripts.

Everything is measured with :func:`time.perf_counter`, with the garbage collector switched off
inside a timed region (as :mod:`timeit` does). A measurement is several rounds; the reported
figure is the **median** of the rounds with its spread (interquartile range and min-max), never
the best round alone: on a shared machine the minimum flatters whichever code happened to run
in a quiet moment. Competing callables are measured **interleaved** (round-robin), so that a
burst of load hits all of them alike, and compared through the ratio of their medians.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class Stats:
    """Seconds per call over the rounds of one measurement."""

    median: float
    q1: float  # first quartile
    q3: float  # third quartile
    lo: float  # fastest round
    hi: float  # slowest round
    number: int  # calls per round
    rounds: int

    @classmethod
    def of(cls, per_call: list[float], number: int) -> Stats:
        xs = sorted(per_call)
        return cls(_quantile(xs, 0.5), _quantile(xs, 0.25), _quantile(xs, 0.75), xs[0], xs[-1],
                   number, len(xs))

    def spread(self) -> float:
        """Interquartile range relative to the median (0.05 = 5%)."""
        return (self.q3 - self.q1) / self.median if self.median > 0 else 0.0


def _quantile(xs: list[float], q: float) -> float:
    """Linear-interpolation quantile of sorted ``xs``."""
    pos = q * (len(xs) - 1)
    i = int(pos)
    j = min(i + 1, len(xs) - 1)
    return xs[i] + (xs[j] - xs[i]) * (pos - i)


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


def measure(fn: Callable[[], object], *, rounds: int = 7, number: int | None = None,
            target_s: float = 0.05, warmup: int = 1) -> Stats:
    """Median (and spread) of ``rounds`` rounds of ``number`` calls of ``fn``.

    ``number`` is calibrated so one round takes about ``target_s`` when ``None`` (the
    single-element regime); pass ``number=1`` for large batches. ``warmup`` untimed calls come
    first (JIT caches, allocator, lazy imports).
    """
    for _ in range(warmup):
        fn()
    if number is None:
        number = calibrate(fn, target_s)
    return Stats.of([run_loop(fn, number) / number for _ in range(rounds)], number)


def interleaved(
    fns: Mapping[Hashable, Callable[[], object]], plan: Mapping[Hashable, tuple[int, int]]
) -> dict[Hashable, Stats | Exception]:
    """Per-call statistics of several callables, measured round-robin.

    ``plan[key] = (number, rounds)``. In each round every callable still due runs ``number``
    calls, so a burst of load from another process hits all of them alike instead of the one
    that happened to be running. A callable that raises gets the exception as its result and
    drops out.
    """
    times: dict[Hashable, list[float]] = {key: [] for key in plan}
    failed: dict[Hashable, Exception] = {}
    for rnd in range(max((rep for _, rep in plan.values()), default=0)):
        for key, (number, rounds) in plan.items():
            if rnd >= rounds or key in failed:
                continue
            try:
                times[key].append(run_loop(fns[key], number) / number)
            except Exception as e:  # reported by the caller
                failed[key] = e
    return {key: failed[key] if key in failed else Stats.of(times[key], plan[key][0])
            for key in plan}
