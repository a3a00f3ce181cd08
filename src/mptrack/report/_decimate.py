"""Which points of a large track table a report draws: every k-th point of each track beyond a budget,
and always the points that carry an event (first and last, rejected fixes, resets, gaps)."""

from __future__ import annotations

import numpy as np

__all__ = ["point_budget", "keep_mask", "DEFAULT_BUDGET"]

#: Points drawn over all tracks (a 10^6-point table becomes a page of about 10 MB).
DEFAULT_BUDGET = 200_000
#: Every track keeps at least this many points (or all of them), whatever the budget.
MIN_PER_TRACK = 40


def point_budget(counts: np.ndarray, budget: int = DEFAULT_BUDGET) -> np.ndarray:
    """Points to draw of each track (int64, <= counts): all of them when the table fits the budget,
    otherwise a share proportional to the track's length, at least ``MIN_PER_TRACK``."""
    counts = np.asarray(counts, dtype=np.int64)
    if counts.sum() <= budget:
        return counts.copy()
    share = np.floor(counts * (budget / max(int(counts.sum()), 1))).astype(np.int64)
    return np.minimum(counts, np.maximum(share, MIN_PER_TRACK))


def keep_mask(offsets: np.ndarray, budget: np.ndarray, events: np.ndarray) -> np.ndarray:
    """Rows to draw of a table sorted by track (track b is rows offsets[b]:offsets[b+1]): every
    k-th row of each track with k = ceil(length / budget), its last row, and every row where
    ``events`` is True."""
    counts = np.diff(offsets)
    n = int(offsets[-1])
    track = np.repeat(np.arange(len(counts)), counts)
    within = np.arange(n, dtype=np.int64) - offsets[:-1][track]
    step = np.maximum(1, -(-counts // np.maximum(budget, 1)))  # ceil division
    keep = (within % step[track]) == 0
    keep[offsets[1:][counts > 0] - 1] = True
    return keep | events
