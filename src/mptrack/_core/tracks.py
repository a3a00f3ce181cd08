"""Many tracks in one table: the rows of each track are consecutive, keyed by a track id column
(shared by the readers of mptrack.io and the tracking pipeline of mptrack.tracking)."""

from __future__ import annotations

import numpy as np

__all__ = ["track_offsets"]


def track_offsets(ids) -> np.ndarray:
    """(B+1,) int64 offsets of the runs of equal track ids (track b is rows offsets[b]:offsets[b+1]);
    [0] for no rows."""
    ids = np.asarray(ids, dtype=object)
    return np.r_[0, np.flatnonzero(ids[1:] != ids[:-1]) + 1, len(ids)].astype(np.int64) if len(ids) \
        else np.zeros(1, np.int64)
