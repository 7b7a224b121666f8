"""Where the time goes: wall and CPU seconds per category, and kernel time per point.

The solver and the materials keep a :class:`Stopwatch` each, so that benchmarks read the split of
a Newton iteration (material, assembly, linear solve) from the objects themselves. CPU time
(``time.process_time``) is what a benchmark on a shared machine should compare: it does not count
the time the process waits for a core.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator


class Stopwatch:
    """Accumulated wall and CPU seconds and the number of timed calls, per category.

    ``with clock("assembly"): ...`` adds to ``clock.wall["assembly"]``, ``clock.cpu["assembly"]``
    and ``clock.calls["assembly"]``; categories may nest (each counts its own span).
    """

    def __init__(self) -> None:
        self.wall = defaultdict(float)
        self.cpu = defaultdict(float)
        self.calls = defaultdict(int)

    @contextmanager
    def __call__(self, key: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[key] += time.perf_counter() - wall
            self.cpu[key] += time.process_time() - cpu
            self.calls[key] += 1


def best_time(fn: Callable[[], object], repeats: int = 3) -> tuple[float, object]:
    """``(seconds, result)``: the best wall time of ``fn()`` over ``repeats`` calls and the last
    call's result."""
    best, out = np.inf, None
    for _ in range(max(int(repeats), 1)):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def time_per_point(fn: Callable[[np.ndarray], object], F: np.ndarray, repeats: int = 5) -> float:
    """Best wall time per point (s) of ``fn(F)`` over ``repeats`` runs, F of shape (n, 2, 2)
    (the first run also compiles or loads a Numba kernel, so at least 2 runs are made)."""
    return best_time(lambda: fn(F), max(int(repeats), 2))[0] / len(F)
