"""Chunks: items ``start .. stop-1`` of a run, with the run's seed and, optionally, their data.

Determinism: item ``i`` of a run draws from the stream ``SeedSequence(seed, spawn_key=(i,))`` -- the
i-th child that ``SeedSequence(seed).spawn`` would give -- so an item's numbers do not depend on the
chunking, the executor or the order in which chunks finish.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._core.validation import check_int
from ..errors import ParameterError

__all__ = ["Chunk", "Chunks", "make_chunks"]


@dataclass(frozen=True, eq=False)
class Chunk:
    """Items ``start .. stop-1`` of a study, handed to a task.

    seed  the study's root entropy (None when the task draws nothing)
    data  the slice ``data[start:stop]`` of the array given to :func:`run_chunks`, or None
    """

    index: int
    start: int
    stop: int
    seed: int | None = None
    data: Any = field(default=None, repr=False)

    @property
    def size(self) -> int:
        return self.stop - self.start

    def seed_sequences(self) -> list[np.random.SeedSequence]:
        """Per-item streams: item i gets ``SeedSequence(seed, spawn_key=(i,))``."""
        if self.seed is None:
            raise ParameterError("seed: this study was started without a seed")
        return [np.random.SeedSequence(self.seed, spawn_key=(i,)) for i in range(self.start, self.stop)]

    def generators(self) -> list[np.random.Generator]:
        return [np.random.default_rng(s) for s in self.seed_sequences()]


class Chunks(Sequence):
    """The chunks of ``range(n_items)``, made on access (a study of 10^12 items costs no memory).

    A read-only sequence: ``len``, indexing (negative too), slicing and iteration, like ``range``."""

    def __init__(self, n_items: int, chunk_size: int, seed: int | None):
        self.n_items, self.chunk_size, self.seed = n_items, chunk_size, seed
        self._range = range(0, n_items, chunk_size)

    def __len__(self) -> int:
        return len(self._range)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        lo = self._range[index]   # IndexError / TypeError as for range
        return Chunk(lo // self.chunk_size, lo, min(lo + self.chunk_size, self.n_items), self.seed)

    def __eq__(self, other) -> bool:
        if isinstance(other, Chunks):
            return (self.n_items, self.chunk_size, self.seed) == (other.n_items, other.chunk_size, other.seed)
        return isinstance(other, (list, tuple)) and len(other) == len(self) and list(self) == list(other)

    def __repr__(self) -> str:
        return f"Chunks(n_items={self.n_items}, chunk_size={self.chunk_size}, seed={self.seed})"


def make_chunks(n_items: int, chunk_size: int, seed: int | None = None) -> Chunks:
    """Split ``range(n_items)`` into consecutive chunks (the last may be shorter), made lazily.

    Parameters
    ----------
    n_items : int
        >= 1; a huge count costs no memory.
    chunk_size : int
        Items per chunk, >= 1.
    seed : int, optional
        The run's root entropy: item i draws from ``SeedSequence(seed, spawn_key=(i,))``.

    Returns
    -------
    Chunks
        A read-only sequence of :class:`Chunk` (len, indexing, slicing, iteration).

    Examples
    --------
    >>> from mptrack.runs import make_chunks
    >>> [(c.start, c.stop) for c in make_chunks(7, 3)]
    [(0, 3), (3, 6), (6, 7)]
    """
    n_items = check_int("n_items", n_items, minimum=1)
    chunk_size = check_int("chunk_size", chunk_size, minimum=1)
    if seed is not None:
        seed = check_int("seed", seed, minimum=0)
    return Chunks(n_items, chunk_size, seed)
