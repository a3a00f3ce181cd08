"""Cellular localisation from ranges to base stations (Bouzera, Oussalah, Mezhoud & Khireddine 2017).

The range measurement model (ranges and their Jacobian from the position part of the state), the
range EKF and the fuzzy fusion filters FEKF and FCS with the paper's fuzzy weight systems (Tables
I and III, as published: :data:`TABLE_I`, :data:`TABLE_III`), their forms over a batch of Monte-Carlo
runs, and the snapshot fix :func:`range_fix`.
State: the position (random walk, the paper's eq. 1) or constant velocity ``[x, vx, y, vy]``, axis
by axis like every model in mptrack.

Positions from one scan of cells as a geolocation service answers them: :func:`locate_cells` (the
posterior over a grid, with co-sited sector cells as one site, the path loss of :func:`signal_prior` /
:func:`signal_fit` and timing-advance rings) and Ichnaea's :func:`weighted_centroid`, its baseline.
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
from ._centroid import CENTROID_ACCURACY_M, station_score, weighted_centroid
from ._locate import CELL_FIELDS, CONFIDENCE, FIX_FIELDS, check_cells, locate_cells
from ._signal_model import RADIO_CODES, RADIOS, Radio, radio_code, signal_fit, signal_prior
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
    "locate_cells",
    "check_cells",
    "CELL_FIELDS",
    "FIX_FIELDS",
    "CONFIDENCE",
    "RADIOS",
    "RADIO_CODES",
    "Radio",
    "radio_code",
    "signal_prior",
    "signal_fit",
    "weighted_centroid",
    "station_score",
    "CENTROID_ACCURACY_M",
]
