"""Argument handling shared by the nonlinear filters of this package."""

from __future__ import annotations

import numpy as np

from .._validation import as_sequence, as_vector, check_covariance, check_int
from ..errors import ParameterError
from ._model import ContinuousDiscreteModel

__all__ = ["prepare_nonlinear", "check_rng"]


def prepare_nonlinear(model, z, x0, P0, substeps, *, definite: bool = False):
    """Validate (model, z, x0, P0, substeps) -> (z (T, m), x0 (n,), P0 (n, n), substeps)."""
    if not isinstance(model, ContinuousDiscreteModel):
        raise ParameterError(f"model: expected a ContinuousDiscreteModel, got {type(model).__name__}")
    z = as_sequence("z", z, model.m, allow_nan=True)
    x0 = as_vector("x0", x0, model.n)
    P0 = check_covariance("P0", P0, model.n, definite=definite)
    substeps = model.substeps if substeps is None else check_int("substeps", substeps, minimum=1)
    return z, x0, P0, substeps


def check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise ParameterError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    return rng
