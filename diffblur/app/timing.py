"""Wall-clock timing shared by the benchmark, the demo and the measurement scripts."""

from __future__ import annotations

import statistics
import time
from typing import Any, Callable, Sequence

__all__ = ["median_ms", "median_ms_each"]


def median_ms_each(fns: Sequence[Callable[[], Any]], repeats: int, warmup: int = 1) -> list[float]:
    """Median wall time of each of fns, in milliseconds, after `warmup` untimed rounds (a first call
    compiles or traces). The calls take turns (fns[0], fns[1], ..., fns[0], ...), so a drift in a
    shared machine's speed reaches every fn alike and the ratios of the results hold better than
    those of separate runs. Each fn must block until its result is ready (JAX:
    `block_until_ready`)."""
    for _ in range(warmup):
        for fn in fns:
            fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for fn, fn_times in zip(fns, times):
            start = time.perf_counter()
            fn()
            fn_times.append(time.perf_counter() - start)
    return [1e3 * statistics.median(fn_times) for fn_times in times]


def median_ms(fn: Callable[[], Any], repeats: int, warmup: int = 1) -> float:
    """Median wall time of `repeats` calls of fn, in milliseconds: `median_ms_each` of one fn."""
    return median_ms_each([fn], repeats, warmup)[0]
