"""Giving freed memory back to the operating system."""

from __future__ import annotations

import ctypes

import numpy as np

__all__ = ["trim_heap", "grown"]


def grown(values: np.ndarray, size: int) -> np.ndarray:
    """``values`` followed by zeros up to ``size``: an array's room to grow, whose pages take no memory
    until written (a large zeroed allocation is fresh pages from the OS)."""
    out = np.zeros(size, values.dtype)
    out[:len(values)] = values
    return out


def trim_heap() -> None:
    """Give the heap memory freed since (a restart's states read once, a bulk upload's rows) back to the
    OS where the C library can (glibc's ``malloc_trim``; elsewhere nothing): a long-running server's
    resident memory then follows what it holds, not the most it ever held."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (AttributeError, OSError):
        pass

