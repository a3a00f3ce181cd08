"""Nonlinear filtering: continuous-discrete models, the FEM (Fokker–Planck) grid filter,
the unscented Kalman filter, the bootstrap particle filter and a high-accuracy reference."""

from ._fem import FEMGrid, FEMStep, GridDensity, fem_filter, fem_steps, shape_functions
from ._model import ZHAO2013_X0, ContinuousDiscreteModel, linear_sde_model, simulate_sde, zhao2013_model
from ._pf import particle_filter, systematic_resample
from ._reference import reference_filter
from ._ukf import sigma_points, ukf_filter

__all__ = [
    "ContinuousDiscreteModel",
    "zhao2013_model",
    "linear_sde_model",
    "simulate_sde",
    "ZHAO2013_X0",
    "FEMGrid",
    "GridDensity",
    "FEMStep",
    "fem_filter",
    "fem_steps",
    "shape_functions",
    "ukf_filter",
    "sigma_points",
    "particle_filter",
    "systematic_resample",
    "reference_filter",
]
