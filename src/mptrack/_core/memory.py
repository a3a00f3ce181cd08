"""Giving freed memory back to the operating system."""

from __future__ import annotations

import ctypes

import numpy as np

__all__ = ["trim_heap", "grown", "values_at", "arrow_gives_memory_back"]


def grown(values: np.ndarray, size: int, fill=0) -> np.ndarray:
    """``values`` followed by ``fill`` up to ``size``: an array's room to grow, whose pages take no memory
    until written when ``fill`` is 0 (a large zeroed allocation is fresh pages from the OS)."""
    out = np.zeros(size, values.dtype) if fill == 0 else np.full(size, fill, values.dtype)
    out[:len(values)] = values
    return out


def values_at(values: np.ndarray, keys, fill=0) -> np.ndarray:
    """``values[keys]``, with ``fill`` where a key is outside the array (negative, or beyond the room it has
    grown to so far)."""
    keys = np.asarray(keys, np.int64)
    if not len(values):
        return np.full(keys.shape, fill, values.dtype)
    inside = (keys >= 0) & (keys < len(values))
    return np.where(inside, values[np.where(inside, keys, 0)], fill)


def trim_heap() -> None:
    """Give the heap memory freed since (a restart's states read once, a bulk upload's rows) back to the
    OS where the C library can (glibc's ``malloc_trim``; elsewhere nothing): a long-running server's
    resident memory then follows what it holds, not the most it ever held."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (AttributeError, OSError):
        pass


def arrow_gives_memory_back() -> None:
    """Arrow's buffers (its readers', and pandas' text columns) from an allocator that gives freed memory
    back to the OS: jemalloc where this Arrow has it (Arrow lets it return freed pages after a second; it
    is as fast as Arrow's default here), else the C library's.  Arrow's default, mimalloc, kept ~80 MB
    of what a server's bulk uploads had freed for as long as the server ran."""
    import pyarrow as pa

    jemalloc = "jemalloc" in pa.supported_memory_backends()
    pa.set_memory_pool(pa.jemalloc_memory_pool() if jemalloc else pa.system_memory_pool())
