"""Continuous-discrete filtering: a stochastic differential equation observed at discrete times
(Zhao, Chen & Ma 2013).

    dx = f(x) dt + dβ,  E[dβ dβ^T] = Q dt;      z(k) = h(x(t_k)) + e(k),  e(k) ~ N(0, R)

The model (:class:`ContinuousDiscreteModel`, with optional compiled :class:`BlockKernels`), its
simulation, the named models (:func:`zhao2013_model`, :func:`linear_sde_model`), the FEM
(Fokker–Planck) grid filter and a high-accuracy reference (a many-particle PF).  The unscented
Kalman filter and the particle filter of :mod:`mptrack.nonlinear` take these models too
(:func:`pf_substeps`: the particle filter's default sub-steps on them).
"""

from .._core.model_families import ModelFamily, register_family
from ._fem import fem_filter, fem_steps
from ._fem_density import FEMStep, GridDensity, GridMixture
from ._fem_grid import FEMGrid, shape_functions
from ._fem_profile import fem_profile
from ._fem_schemes import SCHEMES as FEM_SCHEMES
from ._fem_schemes import fem_substeps
from ._model import (
    ZHAO2013_X0,
    BlockKernels,
    ContinuousDiscreteModel,
    linear_sde_model,
    simulate_sde,
    zhao2013_model,
)
from ._pf import pf_moves, pf_substeps
from ._reference import pf_substep_study, reference_filter
from ._ukf import cd_ukf

# mptrack.nonlinear's UKF and particle filter run this package's models through this registration (this
# package depends on mptrack.nonlinear, not the other way round: docs/design.md, Layout)
register_family(ModelFamily(ContinuousDiscreteModel, ukf=cd_ukf, pf=pf_moves))

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
    "fem_profile",
    "FEM_SCHEMES",
    "shape_functions",
    "reference_filter",
    "pf_substeps",
    "pf_substep_study",
]
