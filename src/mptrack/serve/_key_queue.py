"""An ordered set of device keys in two arrays: the order they came in, and each key's place in it.

The ingest keeps the devices whose state changed since its last checkpoint this way, oldest change
first.  In a dict, after a bulk upload that changed 10^6 devices, they took ~80 bytes a device (a dict
slot and an int); here 8-12.  A key taken out leaves a hole that scans step over; the queue is compacted
when it fills.  One thread uses it at a time (the ingest's writer).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.memory import grown, values_at

__all__ = ["KeyQueue"]


@nb.njit(cache=True)
def _first(queue, place, head, tail, n, out):
    """Up to ``n`` keys from ``head`` on, holes skipped, into ``out``; returns (how many, the place of the
    first: where the queue starts now)."""
    m, start, i = 0, tail, head
    while i < tail and m < n:
        k = queue[i]
        if place[k] == i + 1:
            if m == 0:
                start = i
            out[m] = k
            m += 1
        i += 1
    return m, start


class KeyQueue:
    """Non-negative integer keys in the order they were added (see the module doc)."""

    def __init__(self):
        self._queue = np.zeros(1024, np.int32)     # keys in the order they came (holes: taken out since)
        self._head = self._tail = 0
        self._place = np.zeros(1024, np.int32)     # each key's place in _queue + 1 (0: not in the set)
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def has(self, keys: np.ndarray) -> np.ndarray:
        """Whether each of ``keys`` is in the set."""
        return values_at(self._place, keys) > 0

    def add(self, keys: np.ndarray) -> np.ndarray:
        """Append those of ``keys`` (distinct) not in the set yet, in their order; returns them."""
        keys = np.asarray(keys, np.int64)
        new = keys[~self.has(keys)]
        if not len(new):
            return new
        if new.max() >= len(self._place):
            self._place = grown(self._place, max(int(new.max()) + 1, 2 * len(self._place)))
        if self._tail + len(new) > len(self._queue):
            self._compact(self._count + len(new))
        self._queue[self._tail:self._tail + len(new)] = new
        self._place[new] = np.arange(self._tail + 1, self._tail + len(new) + 1)
        self._tail += len(new)
        self._count += len(new)
        return new

    def discard(self, keys) -> None:
        """Take ``keys`` out of the set (those in it)."""
        keys = np.asarray(keys, np.int64)
        keys = keys[self.has(keys)]
        self._place[keys] = 0
        self._count -= len(keys)

    def oldest(self, n: int) -> np.ndarray:
        """The first ``n`` keys of the set (all when fewer), in the order they came."""
        out = np.empty(min(int(n), self._count), np.int64)
        if len(out):
            m, self._head = _first(self._queue, self._place, self._head, self._tail, len(out), out)
            out = out[:m]
        return out

    def _compact(self, need: int) -> None:
        """The keys in the set moved to the front of a queue with room for ``need`` of them."""
        live = self.oldest(self._count)
        queue = self._queue if 2 * need <= len(self._queue) else np.zeros(2 * need, np.int32)
        queue[:len(live)] = live
        self._place[live] = np.arange(1, len(live) + 1)
        self._queue, self._head, self._tail = queue, 0, len(live)
