"""Timing shared by the benchmark suites."""

from __future__ import annotations

import timeit

import numba as nb

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["best_time", "copy_kernel"]


def best_time(fn, repeats: int) -> float:
    """Best wall-clock time (seconds) of ``repeats`` single calls of ``fn()``."""
    return min(timeit.repeat(fn, number=1, repeat=max(1, int(repeats))))


@nb.njit(parallel=True, cache=True, nogil=True, boundscheck=False)
def copy_kernel(src, dst):
    """The memory-copy baseline: dst[i] = src[i], parallel over the same two cores (the options of the
    batch kernels, so both see the same threading)."""
    N = src.shape[0]
    nchunk = 64
    step = (N + nchunk - 1) // nchunk
    for k in nb.prange(nchunk):
        lo = k * step
        hi = min(N, lo + step)
        for i in range(lo, hi):
            dst[i] = src[i]
