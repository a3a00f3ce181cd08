"""The resumable parts of a long run: each finished chunk kept in ``.<out>.parts/`` until the
output is streamed from them, one part in memory at a time."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd

from ._writers import output_format, write_table

__all__ = ["PartStore"]


class PartStore:
    """The resumable parts of one run writing ``out``: the directory ``.<out>.parts/`` beside it.

    A run's chunks write their tables there (Arrow IPC files ``<name>-NNNNNN.arrow``,
    by :func:`mptrack.batch.run_stream`, each atomically) with a ``manifest.json``
    describing the run; a resumed run skips the chunks found there.
    :meth:`finish` streams one kind of part, in chunk order and one part in
    memory at a time, into the output (atomically); :meth:`discard` removes
    the directory.
    """

    def __init__(self, out) -> None:
        self.out = Path(out)
        output_format(self.out)
        self.dir = self.out.parent / f".{self.out.name}.parts"

    def parts(self, name: str) -> list[Path]:
        """The part files of kind ``name``, in chunk order."""
        return sorted(self.dir.glob(f"{name}-*.arrow")) if self.dir.exists() else []

    def finish(self, name: str, to=None, *, empty=None) -> Path:
        """Write the parts of kind ``name`` into ``to`` (default: the output); ``empty`` is the
        (schema-only) table to write when there are none."""
        from ..batch import read_part

        files = self.parts(name)
        tables = (read_part(p) for p in files) if files else [empty if empty is not None else pd.DataFrame()]
        return write_table(tables, self.out if to is None else to)

    def discard(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)
