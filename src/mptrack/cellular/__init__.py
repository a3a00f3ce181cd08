"""Cellular localisation from ranges to base stations (Bouzera, Oussalah, Mezhoud & Khireddine 2017).

The range measurement model (ranges and their Jacobian from the position part of the state), the
range EKF and the fuzzy fusion filters FEKF and FCS with the paper's fuzzy weight systems (Tables
I and III, as published: :data:`TABLE_I`, :data:`TABLE_III`), their forms over a batch of Monte-Carlo
runs, and the snapshot fix :func:`range_fix`.
State: the position (random walk, the paper's eq. 1) or constant velocity ``[x, vx, y, vy]``, axis
by axis like every model in mptrack.
"""

from ._ekf import (
    MOTIONS,
    check_stations,
    ekf_ranges,
    ekf_ranges_batch,
    motion_matrix,
    motion_position,
    range_fix,
    range_measurement,
)
from ._fekf import (
    TABLE_I,
    TABLE_III,
    bouzera_fcs_fis,
    bouzera_fekf_fis,
    fcs_ranges,
    fcs_ranges_batch,
    fekf_ranges,
    fekf_ranges_batch,
    fuse_local_solutions,
    local_solutions,
)

__all__ = [
    "MOTIONS",
    "range_measurement",
    "motion_matrix",
    "motion_position",
    "check_stations",
    "ekf_ranges",
    "ekf_ranges_batch",
    "fekf_ranges",
    "fekf_ranges_batch",
    "fcs_ranges",
    "fcs_ranges_batch",
    "bouzera_fekf_fis",
    "bouzera_fcs_fis",
    "TABLE_I",
    "TABLE_III",
    "local_solutions",
    "fuse_local_solutions",
    "range_fix",
]
