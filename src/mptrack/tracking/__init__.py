"""Tracking real logs: position fixes at irregular times (gated KF, optional RTS smoothing),
cellular measurements through the EKF/FEKF/FCS range filters, simulation of synthetic logs
with truth, and evaluation against truth.  ``mptrack track/simulate/evaluate`` are in :mod:`mptrack.cli.tracking`."""

from .._core.moved import moved_names
from ._advice import far_from_band
from ._consistency import USED_FLAGS as NIS_FLAGS
from ._consistency import nis_sentence, nis_stats
from ._cellular import check_cell_ids, ranges_km, resolve_cells, track_cells
from ._evaluate import TRUTH_COLUMNS, attach_truth, evaluate_tracks
from ._fixes import CELL_ONLY, FIX_ONLY, TrackOptions, track_fixes
from ._live import ESTIMATE_FIELDS, LiveTracks
from ._gated import GatedResult, kalman_filter_gated, nis_threshold, rts_smoother_gated, track_gated
from ._noise import SOURCES as NOISE_SOURCES
from ._output import POINT_COLUMNS, ellipse, point_table
from ._pipeline import track, track_file, write_track_report
from ._run import TRACK_COLUMNS
from ._simulate import SCENARIOS, Intervals, simulate, simulate_chunks
from ._track_filter import FLAGS
from ._registry import (
    CELL_METHODS,
    FIX_FILTERS,
    MODELS,
    MotionModel,
    get_cell_method,
    get_fix_filter,
    get_model,
)

__all__ = [
    "TrackOptions",
    "LiveTracks",
    "ESTIMATE_FIELDS",
    "ellipse",
    "FIX_ONLY",
    "CELL_ONLY",
    "simulate",
    "simulate_chunks",
    "Intervals",
    "SCENARIOS",
    "evaluate_tracks",
    "nis_stats",
    "nis_sentence",
    "NIS_FLAGS",
    "far_from_band",
    "attach_truth",
    "TRUTH_COLUMNS",
    "track_file",
    "write_track_report",
    "track",
    "track_gated",
    "POINT_COLUMNS",
    "TRACK_COLUMNS",
    "NOISE_SOURCES",
    "track_fixes",
    "track_cells",
    "point_table",
    "check_cell_ids",
    "resolve_cells",
    "ranges_km",
    "kalman_filter_gated",
    "rts_smoother_gated",
    "nis_threshold",
    "GatedResult",
    "FLAGS",
    "MODELS",
    "MotionModel",
    "get_model",
    "FIX_FILTERS",
    "get_fix_filter",
    "CELL_METHODS",
    "get_cell_method",
]

#: names whose one home is elsewhere, or renamed by the naming rule (docs/design.md; issue 34)
__getattr__ = moved_names(__name__, {"read_output": "mptrack.io", "band_of_arfcn": "mptrack.radio",
                                     "TA_STEP_M": "mptrack.radio",
                                     "smooth_gated": ("mptrack.tracking", "rts_smoother_gated")})
