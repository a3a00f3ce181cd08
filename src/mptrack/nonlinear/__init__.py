"""Nonlinear filters for any model: the extended and unscented Kalman filters and their RTS smoothers,
the bootstrap particle filter and the IMM.

They take a discrete-time :class:`mptrack.models.NonlinearModel` (e.g. ``nonlinear_model(motion,
ranges(...))``) and, for the UKF and the PF, a continuous-discrete
:class:`mptrack.continuous.ContinuousDiscreteModel` too (they dispatch on the model type).  The model
families live in their own packages: :mod:`mptrack.cellular` (range filtering of Bouzera et al. 2017)
and :mod:`mptrack.continuous` (SDE models and the FEM grid filter of Zhao et al. 2013); their names
still import from here for one release, with a DeprecationWarning.
"""

from .._core.moved import moved_names
from ._extended import ekf_filter, ekf_filter_batch, ekf_smoother, ekf_step
from ._imm import IMMResult, cv_ca_models, imm_filter
from ._pf import particle_filter, systematic_resample
from ._ukf import sigma_points, ukf_filter, ukf_smoother

__all__ = [
    "ekf_filter",
    "ekf_smoother",
    "ekf_step",
    "ekf_filter_batch",
    "ukf_filter",
    "ukf_smoother",
    "sigma_points",
    "particle_filter",
    "systematic_resample",
    "imm_filter",
    "IMMResult",
    "cv_ca_models",
]

#: names that moved to their model family's package (issue 19) or to their one home (issue 34)
MOVED = {
    "BatchFilterResult": "mptrack.result",
    **dict.fromkeys(("check_stations", "ekf_ranges", "ekf_ranges_batch", "motion_matrix", "motion_position",
                     "range_fix", "range_measurement", "bouzera_fekf_fis", "bouzera_fcs_fis", "fekf_ranges",
                     "fekf_ranges_batch", "fcs_ranges", "fcs_ranges_batch", "fuse_local_solutions",
                     "local_solutions"), "mptrack.cellular"),
    **dict.fromkeys(("ContinuousDiscreteModel", "BlockKernels", "zhao2013_model", "linear_sde_model",
                     "simulate_sde", "ZHAO2013_X0", "FEMGrid", "GridDensity", "GridMixture", "FEMStep",
                     "fem_filter", "fem_steps", "shape_functions", "reference_filter", "pf_substep_study", "pf_substeps"),
                    "mptrack.continuous"),
}
__getattr__ = moved_names(__name__, MOVED)
