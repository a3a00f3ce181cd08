"""Which points of a large track table a report draws: a budget of points shared by every layer.

Each track gets a share of the budget proportional to its length (at least ``MIN_PER_TRACK``).
Within a track the rows are of three kinds: ordinary fixes, rejected fixes (outliers) and breaks
(resets and gaps, where the track's line is broken).  Breaks are all drawn while they take at most
half the track's share (beyond that, every k-th); the rest of the share goes to the ordinary and
the rejected rows alike: every k-th row of each kind, so the map shows rejected fixes in the
proportion they occur and no layer can outgrow the budget.  The last row of every track is drawn.
"""

from __future__ import annotations

import numpy as np

__all__ = ["point_budget", "keep_mask", "DEFAULT_BUDGET", "MIN_PER_TRACK", "ORDINARY", "REJECTED", "BREAK"]

#: Points drawn over all tracks (a 10^6-point table becomes a page of about 10 MB).
DEFAULT_BUDGET = 200_000
#: Every track keeps at least this many points (or all of them), whatever the budget.
MIN_PER_TRACK = 40
#: The kinds of rows ``keep_mask`` thins separately.
ORDINARY, REJECTED, BREAK = 0, 1, 2


def point_budget(counts: np.ndarray, budget: int = DEFAULT_BUDGET) -> np.ndarray:
    """Points to draw of each track (int64, <= counts): all of them when the table fits the budget,
    otherwise a share proportional to the track's length, at least ``MIN_PER_TRACK``."""
    counts = np.asarray(counts, dtype=np.int64)
    if counts.sum() <= budget:
        return counts.copy()
    share = np.floor(counts * (budget / max(int(counts.sum()), 1))).astype(np.int64)
    return np.minimum(counts, np.maximum(share, MIN_PER_TRACK))


def _ceil_div(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return -(-a // np.maximum(b, 1))


def keep_mask(offsets: np.ndarray, budget: np.ndarray, kinds: np.ndarray) -> np.ndarray:
    """Rows to draw of a table sorted by track (track b is rows offsets[b]:offsets[b+1]) with
    ``kinds`` (ORDINARY, REJECTED or BREAK per row): about ``budget[b]`` rows of track b, shared by the
    kinds as the module doc says, and its last row."""
    kinds = np.asarray(kinds, dtype=np.int8)
    counts = np.diff(offsets)
    n = int(offsets[-1])
    track = np.repeat(np.arange(len(counts)), counts)
    per_kind = np.zeros((len(counts), 3), np.int64)
    within = np.zeros(n, np.int64)
    for kind in (ORDINARY, REJECTED, BREAK):
        mine = kinds == kind
        seen = np.concatenate([[0], np.cumsum(mine)])
        start = seen[offsets[:-1]]
        per_kind[:, kind] = seen[offsets[1:]] - start
        within[mine] = (seen[1:] - 1)[mine] - start[track[mine]]
    budget = np.asarray(budget, np.int64)
    breaks = per_kind[:, BREAK]
    break_step = _ceil_div(breaks, np.maximum(budget // 2, 1))
    left = np.maximum(budget - _ceil_div(breaks, break_step), 1)
    step = np.stack([_ceil_div(per_kind[:, ORDINARY] + per_kind[:, REJECTED], left)] * 2 + [break_step], axis=1)
    step = np.maximum(step, 1)
    keep = (within % step[track, kinds]) == 0
    keep[offsets[1:][counts > 0] - 1] = True
    return keep
