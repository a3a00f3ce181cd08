"""Batch engine: many tracks sharing one model, filtered in compiled kernels at memory speed.

Functions take measurements ``z`` of shape (B, T, m) (float64 or float32) and
return a :class:`mptrack.result.BatchFilterResult` whose ``x`` holds the filtered
states (B, T, n), written in place into ``out`` when given (``result.x is out``).
Each one equals its reference in :mod:`mptrack.linear` track by track.
:func:`monte_carlo` and :func:`filter_chunked` run Monte-Carlo studies and batches
larger than memory in chunks (:mod:`mptrack.runs`: serially, in local processes or
on a Dask cluster, with resumable Parquet output).  The chunk runner itself moved
to :mod:`mptrack.runs`; its names still import from here for one release, with a
DeprecationWarning.
"""

from .._core.moved import moved_names
from ._ekf import RangeModel, ekf_ranges
from ._filters import (
    GainSequence,
    fir_filter,
    gain_sequence,
    kalman_filter,
    per_axis,
    predict,
    steady_state_filter,
)
from ._studies import MonteCarloTask, filter_chunked, monte_carlo

__all__ = [
    "steady_state_filter",
    "kalman_filter",
    "fir_filter",
    "predict",
    "per_axis",
    "gain_sequence",
    "GainSequence",
    "monte_carlo",
    "MonteCarloTask",
    "filter_chunked",
    "RangeModel",
    "ekf_ranges",
]

#: names that moved to mptrack.runs, the one home of chunked runs, or were renamed by the naming rule
#: (docs/design.md; issue 34)
MOVED = {**dict.fromkeys(("Chunk", "make_chunks", "run_chunks", "run_stream", "part_path", "read_part", "EXECUTORS"),
                         "mptrack.runs"),
         "range_ekf": ("mptrack.batch", "ekf_ranges")}
__getattr__ = moved_names(__name__, MOVED)
