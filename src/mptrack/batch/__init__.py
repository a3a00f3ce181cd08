"""Batch engine: many tracks sharing one model, filtered in compiled kernels at memory speed.

Functions take measurements ``z`` of shape (B, T, m) (float64 or float32) and
return a :class:`mptrack.result.BatchFilterResult` whose ``x`` holds the filtered
states (B, T, n), written in place into ``out`` when given (``result.x is out``).
Each one equals its reference in :mod:`mptrack.linear` track by track.
:func:`run_chunks` and friends split large batches and Monte-Carlo studies into
chunks run serially, in local processes or on a Dask cluster, with resumable
Parquet output.
"""

from ._ekf import RangeModel, range_ekf
from ._filters import (
    GainSequence,
    fir_filter,
    gain_sequence,
    kalman_filter,
    per_axis,
    predict,
    steady_state_filter,
)
from ._runner import (
    EXECUTORS,
    Chunk,
    MonteCarloTask,
    filter_chunked,
    make_chunks,
    monte_carlo,
    part_path,
    read_part,
    run_chunks,
    run_stream,
)

__all__ = [
    "steady_state_filter",
    "kalman_filter",
    "fir_filter",
    "predict",
    "per_axis",
    "gain_sequence",
    "GainSequence",
    "run_chunks",
    "run_stream",
    "part_path",
    "read_part",
    "make_chunks",
    "Chunk",
    "monte_carlo",
    "MonteCarloTask",
    "filter_chunked",
    "EXECUTORS",
    "RangeModel",
    "range_ekf",
]
