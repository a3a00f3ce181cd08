"""Argument handling shared by the nonlinear filters of this package."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_sequence, as_vector, check_covariance, check_int
from ..errors import ParameterError
from ..linear import FilterResult
from ..models import NonlinearModel
from ..continuous._model import ContinuousDiscreteModel

__all__ = ["prepare_nonlinear", "check_rng", "check_prior", "PRIORS", "BatchFilterResult"]

#: where the prior (x0, P0) sits: at time 0, one prediction before the first measurement ("initial"),
#: or at the first measurement itself ("first-measurement": no prediction before it; pykalman, simdkalman
#: and FilterPy's update-first loop)
PRIORS = ("initial", "first-measurement")


def prepare_nonlinear(model, z, x0, P0, substeps=None, *, definite: bool = False,
                      kinds=(ContinuousDiscreteModel, NonlinearModel)):
    """Validate (model, z, x0, P0, substeps) -> (z (T, m), x0 (n,), P0 (n, n), substeps).

    ``substeps`` (sub-steps per dt) only applies to a ContinuousDiscreteModel (None for a NonlinearModel)."""
    if not isinstance(model, kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise ParameterError(f"model: expected a {names}, got {type(model).__name__}")
    # one memory layout (C-contiguous, writable) for the compiled kernels: one compiled variant each
    z = np.require(as_sequence("z", z, model.m, allow_nan=True), dtype=float, requirements=["C", "W"])
    x0 = as_vector("x0", x0, model.n)
    if P0 is None:
        raise ParameterError("P0: the prior covariance is required (there is no safe default)")
    P0 = check_covariance("P0", P0, model.n, definite=definite)
    if isinstance(model, ContinuousDiscreteModel):
        substeps = model.substeps if substeps is None else check_int("substeps", substeps, minimum=1)
    elif substeps is not None:
        raise ParameterError("substeps: only for a ContinuousDiscreteModel (a NonlinearModel is discrete-time)")
    return z, x0, P0, substeps


def check_prior(prior: str) -> bool:
    """True when the prior is at the first measurement."""
    if prior not in PRIORS:
        raise ParameterError(f"prior: expected one of {PRIORS}, got {prior!r}")
    return prior == PRIORS[1]


def check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise ParameterError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    return rng


@dataclass(frozen=True, eq=False)
class BatchFilterResult:
    """A batch of B filter runs: x, x_pred (B, T, n), P, P_pred (B, T, n, n), loglik (B,) or None."""

    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray
    P_pred: np.ndarray
    loglik: np.ndarray | None = None
    method: str = ""

    def run(self, b: int) -> FilterResult:
        """Run ``b`` as a FilterResult."""
        ll = None if self.loglik is None else float(self.loglik[b])
        return FilterResult(x=self.x[b], P=self.P[b], x_pred=self.x_pred[b], P_pred=self.P_pred[b], loglik=ll,
                            method=self.method)
