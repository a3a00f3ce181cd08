"""The resumable parts of a long run: each finished chunk kept in ``.<out>.parts/`` until the
output is streamed from them, one part in memory at a time.

The part store of ``out`` belongs to the run holding the lock of ``out``
(:func:`mptrack._io.output_lock`): only that run creates, resumes, cleans or discards it."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pandas as pd

from .._validation import check_path, renamed
from ._writers import output_format, write_table

__all__ = ["PartStore"]

#: The temporary files of :func:`mptrack._io.atomic_path` for a part (``<name>-NNNNNN.arrow`` or
#: ``.parquet``) or the manifest: ``.<file>.XXXXXXXX.tmp<suffix>``.
_TEMP = re.compile("|".join(rf"\.{name}\.[a-z0-9_]{{8}}\.tmp\.{ext}" for name, ext in
                            ((r"[a-z_]+-\d{6}\.arrow", "arrow"), (r"[a-z_]+-\d{6}\.parquet", "parquet"),
                             (r"manifest\.json", "json"))))


class PartStore:
    """The resumable parts of one run writing ``out``: the directory ``.<out>.parts/`` beside it.

    A run's chunks write their tables there (Arrow IPC files ``<name>-NNNNNN.arrow``,
    by :func:`mptrack.batch.run_stream`, each atomically) with a ``manifest.json``
    describing the run; a resumed run skips the chunks found there.
    :meth:`finish` streams one kind of part, in chunk order and one part in
    memory at a time, into the output (atomically); :meth:`discard` removes
    the directory; :meth:`clean` removes the temporary files of parts whose
    writer was killed.  Call them only while holding the output's lock.
    """

    def __init__(self, out) -> None:
        self.out = check_path("out", out)
        with renamed(path="out"):
            output_format(self.out)
        self.dir = self.out.parent / f".{self.out.name}.parts"

    def parts(self, name: str) -> list[Path]:
        """The part files of kind ``name``, in chunk order."""
        return sorted(self.dir.glob(f"{name}-*.arrow")) if self.dir.exists() else []

    def clean(self) -> list[Path]:
        """Remove the temporary files left in the store by a killed run (the store is private to
        the lock holder, so none of them is being written); the removed paths."""
        stale = sorted(p for p in self.dir.iterdir() if _TEMP.fullmatch(p.name)) if self.dir.is_dir() else []
        for p in stale:
            p.unlink(missing_ok=True)
        return stale

    def finish(self, name: str, to=None, *, empty=None) -> Path:
        """Write the parts of kind ``name`` into ``to`` (default: the output); ``empty`` is the
        (schema-only) table to write when there are none."""
        from ..batch import read_part

        files = self.parts(name)
        tables = (read_part(p) for p in files) if files else [empty if empty is not None else pd.DataFrame()]
        return write_table(tables, self.out if to is None else to)

    def discard(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)
