"""How mptrack's parallel numba kernels are started: small work on the calling thread only."""

from __future__ import annotations

import numba

__all__ = ["launch", "SMALL_WORK", "background"]

SMALL_WORK = 1 << 20   # values below which one thread beats waking the others


def launch(kernel, work: int, *args):
    """Call a parallel kernel and return what it returns; for less than SMALL_WORK values of work
    on one thread only.

    Waking the worker threads costs microseconds on an idle machine but a
    scheduler time slice (milliseconds) on a busy one; small batches do not
    need them.
    """
    if work >= SMALL_WORK or numba.get_num_threads() == 1:
        return kernel(*args)
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return kernel(*args)
    finally:
        numba.set_num_threads(previous)


def background() -> None:
    """Make the calling thread a background one: its parallel kernels run on this thread only
    (numba's thread count is per thread), so that work beside a latency-bound one (a server's noise
    estimates beside its ingest) never takes every core from it."""
    numba.set_num_threads(1)
