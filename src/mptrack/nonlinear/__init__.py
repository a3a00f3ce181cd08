"""Nonlinear filtering for cellular localisation: EKF on base-station ranges, and the
fuzzy-weighted fusion filters FEKF and FCS of Bouzera et al. (2017)."""

from ._ekf import (
    BatchFilterResult,
    check_stations,
    ekf_ranges,
    ekf_ranges_batch,
    motion_matrix,
    range_measurement,
)
from ._fekf import (
    bouzera_fcs_fis,
    bouzera_fekf_fis,
    fcs_ranges,
    fcs_ranges_batch,
    fekf_ranges,
    fekf_ranges_batch,
    fuse_local_solutions,
)

__all__ = [
    "BatchFilterResult",
    "check_stations",
    "ekf_ranges",
    "ekf_ranges_batch",
    "motion_matrix",
    "range_measurement",
    "bouzera_fekf_fis",
    "bouzera_fcs_fis",
    "fekf_ranges",
    "fekf_ranges_batch",
    "fcs_ranges",
    "fcs_ranges_batch",
    "fuse_local_solutions",
]
