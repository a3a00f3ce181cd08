"""Scans of large float arrays for infinities or NaN, in parallel and in the array's own dtype.

NumPy's ``np.isinf(a).any()`` builds a boolean temporary and ``min``/``max`` read the
array twice, on one thread; for the 10^7-value arrays of the batch engine such checks
cost more than the filter.  Here the floats are read as unsigned integers: a value is
infinite or NaN exactly when its exponent field is all ones, and infinite when, in
addition, its mantissa is zero.  The matches are counted with integer adds, which
vectorise (a float test with an early exit, or a boolean OR, does not), so a scan
runs at memory speed, split over numba's threads by segments.
"""

from __future__ import annotations

import numba
import numpy as np

from . import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .threads import launch

__all__ = ["any_nonfinite", "any_infinite"]

#: Segment length of a flat array (values).
_SEGMENT = 1 << 16

_UINT = {np.dtype(np.float64): np.uint64, np.dtype(np.float32): np.uint32}
_EXPONENT = {np.dtype(np.float64): 0x7FF0000000000000, np.dtype(np.float32): 0x7F800000}
_MAGNITUDE = {np.dtype(np.float64): 0x7FFFFFFFFFFFFFFF, np.dtype(np.float32): 0x7FFFFFFF}


@numba.njit(parallel=True, cache=True, nogil=True)
def _segments_hit(bits, starts, counts, keep, target):  # pragma: no cover - compiled
    """True when some word w of a segment bits[starts[s]:starts[s] + counts[s]] has
    ``w & keep == target``.  Counted with integer adds over a slice, which vectorise; a boolean
    OR, a minimum of ``(w & keep) ^ target`` or an index loop over the flat array compiled to code
    3-10x slower."""
    hits = np.zeros(starts.shape[0], np.int64)
    for s in numba.prange(starts.shape[0]):
        segment = bits[starts[s]:starts[s] + counts[s]]
        hit = 0
        for j in range(segment.shape[0]):
            hit += (segment[j] & keep) == target
        hits[s] = hit
    return hits.sum() > 0


def _scan(arr: np.ndarray, keep_of: dict, starts, counts) -> bool:
    flat = arr.reshape(-1)
    if starts is None:
        starts = np.arange(0, flat.size, _SEGMENT, dtype=np.int64)
        counts = np.minimum(_SEGMENT, flat.size - starts)
    uint = _UINT[arr.dtype]
    args = (flat.view(uint), starts, counts, uint(keep_of[arr.dtype]), uint(_EXPONENT[arr.dtype]))
    return bool(launch(_segments_hit, flat.size, *args))


def any_nonfinite(arr: np.ndarray, starts=None, counts=None) -> bool:
    """True when the C-contiguous float64/float32 ``arr`` holds a NaN or an infinity; with
    ``starts`` and ``counts`` (int64 arrays, offsets in the flattened array) only those segments
    are read (a batch's tracks up to their lengths)."""
    return _scan(arr, _EXPONENT, starts, counts)


def any_infinite(arr: np.ndarray) -> bool:
    """True when the C-contiguous float64/float32 ``arr`` holds +-infinity (NaN is not looked at)."""
    return _scan(arr, _MAGNITUDE, None, None)
