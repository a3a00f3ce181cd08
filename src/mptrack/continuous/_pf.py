"""The bootstrap particle filter on a continuous-discrete model: particles follow the SDE in sub-steps
(:meth:`ContinuousDiscreteModel.sample_transition`, or the model's compiled kernels) and are weighted by
its measurement density.  :func:`mptrack.nonlinear.particle_filter` runs it (registered with
mptrack._core.model_families by this package's ``__init__``); :func:`pf_substeps` is its default of sub-steps.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ._kernels import SCHEMES, compiled_model
from ._model import ContinuousDiscreteModel

__all__ = ["pf_substeps", "pf_moves", "SPLIT_RATIO", "NOISE_STEP"]

#: default sub-steps of the "rk4-split" scheme (docs/nonlinear.md, study on eq. 42): at least
#: model.substeps / SPLIT_RATIO (2 for the usual 20 per second: the bias of the 2-step split on
#: the Q x 0.01 example is a third of the Monte-Carlo error of 10^4 particles), and enough that the
#: noise per sub-step, sqrt(tr(Q) h), is at most NOISE_STEP state units (the weak error grows
#: with it: Q x 0.1 needs 4-5 sub-steps, Q x 1 about 20-40)
SPLIT_RATIO = 10
NOISE_STEP = 0.5


def pf_substeps(model: ContinuousDiscreteModel, scheme: str = "rk4-split") -> int:
    """The particle filter's default sub-steps per dt on a continuous-discrete model.

    ``model.substeps`` for "heun"; for "rk4-split" max(ceil(model.substeps / 10), ceil(tr(Q) dt /
    0.5^2)): 2 for eq. 42 with Q x 0.01, 5 with Q x 0.1, 41 with Q x 1.

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
    scheme : {"rk4-split", "heun"}, optional

    Returns
    -------
    int
    """
    if scheme not in SCHEMES:
        raise ParameterError(f"scheme: expected one of {SCHEMES}, got {scheme!r}")
    if scheme == "heun":
        return model.substeps
    noise = int(np.ceil(np.trace(model.Q) * model.dt / NOISE_STEP ** 2 - 1e-12))
    return max(-(-model.substeps // SPLIT_RATIO), noise)


def pf_moves(model: ContinuousDiscreteModel, rng: np.random.Generator, *, substeps: int | None, scheme: str,
             compiled: bool | None):
    """(propagate(X, k), log_likelihood(zk, X, k)) of the particle filter on ``model``: ``substeps``
    sub-steps of ``scheme`` per dt (None: :func:`pf_substeps`), with the model's compiled kernels unless
    ``compiled`` is False (True requires them)."""
    if scheme not in SCHEMES:
        raise ParameterError(f"scheme: expected one of {SCHEMES}, got {scheme!r}")
    substeps = pf_substeps(model, scheme) if substeps is None else substeps
    if compiled and model.kernels is None:
        raise ParameterError("compiled: the model has no compiled kernels (BlockKernels)")
    if (model.kernels is not None) if compiled is None else bool(compiled):
        kernels = compiled_model(model)
        advance, weigh = kernels.propagate, kernels.log_likelihood
    else:
        advance, weigh = model.sample_transition, model.log_likelihood

    def propagate(X, k):
        return advance(X, rng, substeps, scheme)

    def log_likelihood(zk, X, k):
        return weigh(zk, X)
    return propagate, log_likelihood
