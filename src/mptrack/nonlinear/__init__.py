"""Nonlinear filtering.

Cellular localisation (Bouzera et al. 2017): EKF on base-station ranges and the
fuzzy-weighted fusion filters FEKF and FCS.  Continuous-discrete models (Zhao et
al. 2013): the FEM (Fokker–Planck) grid filter, the unscented Kalman filter, the
bootstrap particle filter and a high-accuracy reference.
"""

from ._ekf import (
    BatchFilterResult,
    check_stations,
    ekf_ranges,
    ekf_ranges_batch,
    motion_matrix,
    motion_position,
    range_fix,
    range_measurement,
)
from ._extended import ekf_filter, ekf_filter_batch, ekf_smoother, ekf_step
from ._fekf import (
    bouzera_fcs_fis,
    bouzera_fekf_fis,
    fcs_ranges,
    fcs_ranges_batch,
    fekf_ranges,
    fekf_ranges_batch,
    fuse_local_solutions,
    local_solutions,
)
from ._fem import FEMGrid, FEMStep, GridDensity, GridMixture, fem_filter, fem_steps, shape_functions
from ._imm import IMMResult, cv_ca_models, imm_filter
from ._model import (
    ZHAO2013_X0,
    BlockKernels,
    ContinuousDiscreteModel,
    linear_sde_model,
    simulate_sde,
    zhao2013_model,
)
from ._pf import particle_filter, pf_substeps, systematic_resample
from ._reference import pf_substep_study, reference_filter
from ._ukf import sigma_points, ukf_filter, ukf_smoother

__all__ = [
    # cellular (seed 003)
    "BatchFilterResult",
    "check_stations",
    "ekf_ranges",
    "ekf_ranges_batch",
    "motion_matrix",
    "motion_position",
    "range_measurement",
    "range_fix",
    "bouzera_fekf_fis",
    "bouzera_fcs_fis",
    "fekf_ranges",
    "fekf_ranges_batch",
    "fcs_ranges",
    "fcs_ranges_batch",
    "fuse_local_solutions",
    "local_solutions",
    # continuous-discrete (seed 004)
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
    "shape_functions",
    "ukf_filter",
    "ukf_smoother",
    "ekf_filter",
    "ekf_smoother",
    "ekf_step",
    "ekf_filter_batch",
    "imm_filter",
    "IMMResult",
    "cv_ca_models",
    "sigma_points",
    "particle_filter",
    "pf_substeps",
    "systematic_resample",
    "reference_filter",
    "pf_substep_study",
]
