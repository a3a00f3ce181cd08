"""Argument handling shared by the linear filters."""

from __future__ import annotations

import numpy as np

from .._core.validation import as_sequence, as_vector, check_covariance
from ..models import require_model

__all__ = ["prepare_inputs"]


def prepare_inputs(model, z, x0, P0, *, allow_nan: bool = True):
    """Validate (model, z, x0, P0); defaults x0 = 0 and P0 = 0 as in the papers' example.

    Returns (z (T, m), x0 (n,), P0 (n, n), missing (T,) bool) where ``missing``
    marks time steps whose measurement has a NaN (those steps only predict).
    """
    require_model(model)
    # One memory layout (C-contiguous, writable) for the compiled loops: rows are streamed,
    # and a read-only or strided input would otherwise compile a second version of each loop.
    z = np.require(as_sequence("z", z, model.m, allow_nan=allow_nan), requirements=["C", "W"])
    x0 = np.zeros(model.n) if x0 is None else np.require(as_vector("x0", x0, model.n), requirements=["C", "W"])
    P0 = np.zeros((model.n, model.n)) if P0 is None else check_covariance("P0", P0, model.n)
    missing = np.isnan(z).any(axis=1)
    return z, x0, P0, missing
