"""Log lines that may come many times a second (refused requests, fixes stamped ahead): the first of
each kind at once, then at most one every ``every_s`` seconds, saying how many were held back."""

from __future__ import annotations

import math
import time

__all__ = ["LogThrottle"]


class LogThrottle:
    """When a line of a kind may be logged.

    Parameters
    ----------
    every_s : float
        The shortest time between two lines of one kind (s).
    """

    def __init__(self, every_s: float):
        self.every_s = float(every_s)
        self._next: dict[str, float] = {}     # kind -> when its next line may be written (monotonic)
        self._held: dict[str, int] = {}       # kind -> events held back since its last line

    def due(self, kind: str, n: int = 1) -> int | None:
        """The events of ``kind`` held back since its last line if a line is due now (these ``n`` events
        are then logged), else None (they are held back, and counted)."""
        now = time.monotonic()
        if now < self._next.get(kind, -math.inf):
            self._held[kind] = self._held.get(kind, 0) + n
            return None
        self._next[kind] = now + self.every_s
        return self._held.pop(kind, 0)
