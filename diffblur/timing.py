"""Wall-clock timing shared by the benchmark, the demo and the measurement scripts."""

from __future__ import annotations

import statistics
import time
from typing import Any, Callable

__all__ = ["median_ms"]


def median_ms(fn: Callable[[], Any], repeats: int, warmup: int = 1) -> float:
    """Median wall time of `repeats` calls of fn, in milliseconds, after `warmup` untimed calls (a
    first call compiles or traces). fn must block until its result is ready (JAX:
    `block_until_ready`)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)
