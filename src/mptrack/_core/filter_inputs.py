"""Argument handling shared by the filters for nonlinear models: the generic filters of mptrack.nonlinear
(any :class:`mptrack.models.NonlinearModel`, and the model types registered in mptrack._core.model_families)
and the filters of mptrack.continuous (FEM grid filter, reference filter)."""

from __future__ import annotations

import numpy as np

from .model_families import family_kinds
from .validation import as_sequence, as_vector, check_covariance, check_int
from ..errors import ParameterError
from ..models import NonlinearModel

__all__ = ["prepare_nonlinear", "check_prior", "PRIORS"]

#: where the prior (x0, P0) sits: at time 0, one prediction before the first measurement ("initial"),
#: or at the first measurement itself ("first-measurement": no prediction before it; pykalman, simdkalman
#: and FilterPy's update-first loop)
PRIORS = ("initial", "first-measurement")


def prepare_nonlinear(model, z, x0, P0, substeps=None, *, definite: bool = False, kinds=None):
    """Validate (model, z, x0, P0, substeps) -> (z (T, m), x0 (n,), P0 (n, n), substeps).

    ``kinds``: the model types accepted (default: the registered families and NonlinearModel).
    ``substeps`` (sub-steps per dt) only applies to a continuous-discrete model (None for a NonlinearModel)."""
    kinds = family_kinds() + (NonlinearModel,) if kinds is None else kinds
    if not isinstance(model, kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise ParameterError(f"model: expected a {names}, got {type(model).__name__}")
    # one memory layout (C-contiguous, writable) for the compiled kernels: one compiled variant each
    z = np.require(as_sequence("z", z, model.m, allow_nan=True), dtype=float, requirements=["C", "W"])
    x0 = as_vector("x0", x0, model.n)
    if P0 is None:
        raise ParameterError("P0: the prior covariance is required (there is no safe default)")
    P0 = check_covariance("P0", P0, model.n, definite=definite)
    if not isinstance(model, NonlinearModel):  # a continuous-discrete model: sub-steps per dt
        substeps = model.substeps if substeps is None else check_int("substeps", substeps, minimum=1)
    elif substeps is not None:
        raise ParameterError("substeps: only for a ContinuousDiscreteModel (a NonlinearModel is discrete-time)")
    return z, x0, P0, substeps


def check_prior(prior: str) -> bool:
    """True when the prior is at the first measurement."""
    if prior not in PRIORS:
        raise ParameterError(f"prior: expected one of {PRIORS}, got {prior!r}")
    return prior == PRIORS[1]


