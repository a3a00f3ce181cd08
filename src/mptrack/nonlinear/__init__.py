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

__all__ = [
    "BatchFilterResult",
    "check_stations",
    "ekf_ranges",
    "ekf_ranges_batch",
    "motion_matrix",
    "range_measurement",
]
