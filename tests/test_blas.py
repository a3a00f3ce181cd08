"""mptrack._core.blas: small Riccati solves run on one BLAS thread (OpenBLAS's spinning workers would take the
cores of the numba kernel that follows)."""

import numpy as np
import scipy.linalg  # noqa: F401 - its OpenBLAS is one of the libraries limited
from threadpoolctl import threadpool_info

from mptrack._core import blas as _blas
from mptrack.models import assimakis_model_b
from mptrack.riccati import steady_state


def _blas_threads():
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_small_solves_run_on_one_blas_thread_and_the_limit_is_restored(monkeypatch):
    before = _blas_threads()
    assert before
    with _blas.one_blas_thread(4):
        assert set(_blas_threads()) == {1}
    assert _blas_threads() == before
    with _blas.one_blas_thread(_blas.SMALL + 1):         # large problems keep BLAS's threads
        assert _blas_threads() == before
    seen = []
    real = np.linalg.eigvals
    monkeypatch.setattr(np.linalg, "eigvals", lambda *a, **k: seen.append(_blas_threads()) or real(*a, **k))
    steady_state(assimakis_model_b())                   # its existence checks (PBH) run inside the limit
    assert seen and all(set(s) == {1} for s in seen)
    assert _blas_threads() == before
