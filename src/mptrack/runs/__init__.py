"""Chunked, resumable runs: the one home of chunks, their execution, part files, manifests and the
output lock.

A long run (``mptrack track`` on a large file, a Monte-Carlo study, a batch larger than memory) is
cut into chunks (:class:`Chunk`, :func:`make_chunks`); :func:`run_stream` runs a task on each chunk
serially, in local processes or on a Dask cluster, keeping at most a few chunks in flight, and with
an output directory each worker writes its chunk's tables atomically as part files
(:func:`part_path`, :func:`read_part`) beside a ``manifest.json`` that refuses another run's parts;
a repeated call skips the chunks found there (resume).  :func:`run_chunks` is the same for a task
over ``range(n_items)``, concatenated.  :class:`PartStore` is the part directory of one output
(``.<out>.parts/``), streamed into the output at the end.  :func:`output_lock` holds the exclusive
lock of a run's outputs for the whole run (the parts belong to the run holding it);
:func:`resumable_outputs` takes it once for a resumable run and decides, when the run stops, whether
its finished chunks are kept for ``resume``.

Every chunk is computed by the same function from the same data, so results do not depend on the
executor; per-item random streams ``SeedSequence(seed, spawn_key=(i,))`` make them independent of
the chunking too.
"""

from ._chunks import Chunk, Chunks, make_chunks
from ._lock import lock_path, output_lock
from ._parts import PART_FORMATS, part_path, read_part
from ._store import PartStore, resumable_outputs
from ._stream import EXECUTORS, run_chunks, run_stream

__all__ = [
    "Chunk",
    "Chunks",
    "make_chunks",
    "run_stream",
    "run_chunks",
    "EXECUTORS",
    "PART_FORMATS",
    "part_path",
    "read_part",
    "PartStore",
    "resumable_outputs",
    "output_lock",
    "lock_path",
]
