"""Small dense linear algebra on one BLAS thread.

NumPy's and SciPy's OpenBLAS wake their worker threads even for the few-by-few matrices of a
Riccati solve, and the workers then spin for a while after the call; the numba kernel that runs
next finds its cores taken.  Measured: a batch steady-state filter (10^7 model-B updates, 2 cores)
took 16.4 ms right after the DARE it needs, 8.3 ms when the DARE ran on one BLAS thread, 8.5 ms
with no DARE before it.  threadpoolctl sets the limit of every BLAS library loaded in the process
for the duration of a block and restores it after.
"""

from __future__ import annotations

from contextlib import contextmanager

__all__ = ["one_blas_thread", "SMALL"]

#: Largest matrix order worked on one thread (larger problems may gain from BLAS's threads).
SMALL = 32

_controller = None


@contextmanager
def one_blas_thread(order: int):
    """Run the block on one BLAS thread when the matrices are of ``order`` <= SMALL."""
    global _controller
    if order > SMALL:
        yield
        return
    if _controller is None:      # made on first use: it lists the BLAS libraries loaded by then
        from threadpoolctl import ThreadpoolController
        _controller = ThreadpoolController()
    with _controller.limit(limits=1, user_api="blas"):
        yield
