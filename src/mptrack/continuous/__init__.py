"""Continuous-discrete filtering: a stochastic differential equation observed at discrete times
(Zhao, Chen & Ma 2013).

    dx = f(x) dt + dβ,  E[dβ dβ^T] = Q dt;      z(k) = h(x(t_k)) + e(k),  e(k) ~ N(0, R)

The model (:class:`ContinuousDiscreteModel`, with optional compiled :class:`BlockKernels`), its
simulation, the named models (:func:`zhao2013_model`, :func:`linear_sde_model`), the FEM
(Fokker–Planck) grid filter and a high-accuracy reference (a many-particle PF).  The unscented
Kalman filter and the particle filter of :mod:`mptrack.nonlinear` take these models too.
"""

# this package's filters use mptrack.nonlinear's and those take this package's model: whichever of the
# two packages is imported first imports the other one first (docs/design.md, Layout)
from .. import nonlinear as _nonlinear  # noqa: F401  (isort: skip)
from ._fem import SCHEMES as FEM_SCHEMES
from ._fem import FEMGrid, FEMStep, GridDensity, GridMixture, fem_filter, fem_steps, fem_substeps, shape_functions
from ._model import (
    ZHAO2013_X0,
    BlockKernels,
    ContinuousDiscreteModel,
    linear_sde_model,
    simulate_sde,
    zhao2013_model,
)
from ._reference import pf_substep_study, reference_filter

__all__ = [
    "ContinuousDiscreteModel",
    "BlockKernels",
    "zhao2013_model",
    "linear_sde_model",
    "simulate_sde",
    "ZHAO2013_X0",
    "FEMGrid",
    "GridDensity",
    "GridMixture",
    "FEMStep",
    "fem_filter",
    "fem_steps",
    "fem_substeps",
    "FEM_SCHEMES",
    "shape_functions",
    "reference_filter",
    "pf_substep_study",
]
