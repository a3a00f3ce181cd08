"""Timing shared by the benchmark suites."""

from __future__ import annotations

import timeit

__all__ = ["best_time"]


def best_time(fn, repeats: int) -> float:
    """Best wall-clock time (seconds) of ``repeats`` single calls of ``fn()``."""
    return min(timeit.repeat(fn, number=1, repeat=max(1, int(repeats))))
