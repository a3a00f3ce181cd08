"""The outputs of a resumable run: their locks, taken once for the whole run, and the part store of
the main output (``.<out>.parts/``, where the finished chunks wait until the output is streamed from
them).

The part store of ``out`` belongs to the run holding the lock of ``out`` (:func:`output_lock`): only
that run creates, resumes, cleans or discards it.
"""

from __future__ import annotations

import contextlib
import re
import shutil
from pathlib import Path
from typing import Iterator

import pandas as pd

from .._core.finiteness import renamed
from .._core.validation import check_path
from ..errors import DataError, MptrackError, OutputError
from ..io import output_format, write_table
from ._lock import output_lock
from ._parts import read_part

__all__ = ["PartStore", "resumable_outputs"]


#: The temporary files of :func:`mptrack._core.files.atomic_path` for a part (``<name>-NNNNNN.arrow`` or
#: ``.parquet``) or the manifest: ``.<file>.XXXXXXXX.tmp<suffix>``.
_TEMP = re.compile("|".join(rf"\.{name}\.[a-z0-9_]{{8}}\.tmp\.{ext}" for name, ext in
                            ((r"[a-z_]+-\d{6}\.arrow", "arrow"), (r"[a-z_]+-\d{6}\.parquet", "parquet"),
                             (r"manifest\.json", "json"))))


class PartStore:
    """The resumable parts of one run writing ``out``: the directory ``.<out>.parts/`` beside it.

    A run's chunks write their tables there (Arrow IPC files ``<name>-NNNNNN.arrow``,
    by :func:`run_stream`, each atomically) with a ``manifest.json``
    describing the run; a resumed run skips the chunks found there.
    :meth:`check` finds every part the run's chunks wrote (or refuses: a part
    or the manifest vanished); :meth:`finish` streams one kind of part, in
    chunk order and one part in memory at a time, into the output
    (atomically); :meth:`discard` removes the directory; :meth:`clean` removes
    the temporary files of parts whose writer was killed.  Call them only
    while holding the output's lock.
    """

    def __init__(self, out) -> None:
        self.out = check_path("out", out)
        with renamed(path="out"):
            output_format(self.out)
        self.dir = self.out.parent / f".{self.out.name}.parts"
        #: the finished chunks' parts found when the run started (:func:`resumable_outputs`)
        self.resumed: list[Path] = []

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

    def check(self, results: list[dict]) -> dict[str, list[Path]]:
        """The part files of a finished run by kind, in chunk order, from ``results`` (what
        :func:`run_stream` returned: each chunk's {kind: path}).

        Every one of them and the manifest must still be there: a store removed or emptied during
        the run (by hand, a clean-up job) would otherwise give an output missing those chunks.
        Then the store (which can no longer be trusted for a resume) is discarded and an
        OutputError names the output, how many parts vanished and the first of them."""
        files = {}
        for res in results:
            for name, path in res.items():
                files.setdefault(name, []).append(Path(path))
        every = [p for paths in files.values() for p in paths]
        gone = [p for p in [self.dir / "manifest.json", *every] if not p.is_file()]
        if gone:
            self.discard()
            raise self._vanished(gone, len(every))
        return files

    def _vanished(self, gone: list, total: int) -> OutputError:
        parts = [p for p in gone if p.name != "manifest.json"]
        what = (f"{len(parts)} of the {total} part files" + (" and the manifest" if len(parts) < len(gone) else "")
                if parts else "the manifest")
        return OutputError(f"{self.out}: {what} of this run vanished from {self.dir} while it ran (first: "
                           f"{gone[0].name}; was the directory deleted?); the output was not written and the "
                           "remaining parts were removed: run again", path=self.out)

    def finish(self, files: list, to=None, *, empty=None) -> Path:
        """Write the parts ``files`` (one kind, in chunk order: :meth:`check`) into ``to`` (default:
        the output); ``empty`` is the (schema-only) table to write when there are none.  A part
        removed meanwhile is the OutputError of :meth:`check` (the output is not written)."""
        def tables():
            for path in files:
                try:
                    yield read_part(path)
                except DataError:          # read_part's error for a part it cannot read: gone, or damaged
                    if Path(path).exists():
                        raise
                    self.discard()
                    raise self._vanished([Path(path)], len(files)) from None

        return write_table(tables() if files else [empty if empty is not None else pd.DataFrame()],
                           self.out if to is None else to)

    def discard(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


@contextlib.contextmanager
def resumable_outputs(out, *also, resume: bool = False, note: str = "", last_part: str) -> Iterator[PartStore]:
    """Hold the outputs of a resumable run: their locks, taken once, and the part store of the main one.

    The store is emptied for a fresh run or, with ``resume``, kept with its killed writers' temporary
    files removed.  When the block raises, the finished chunks are kept for a resumed run after Ctrl-C,
    an OS failure (disk full, ...) or a crash, and whenever this run was itself a resume; after bad input
    or options (an mptrack error: a rerun must change them), or with no chunk finished, the store is
    removed, so nothing is left behind.

    Parameters
    ----------
    out : str or path-like
        The main output, whose parts go to ``.<out>.parts/``.
    *also : str or path-like
        Other outputs of the run, locked too (None is skipped).
    resume : bool, optional
        Keep the parts of an interrupted run.
    note : str, optional
        Shown to another process refused the lock (e.g. the command line).
    last_part : str
        The kind of part written last by each chunk (its presence means the chunk is done).

    Yields
    ------
    PartStore
        With ``resumed``, the finished chunks found at the start.

    Raises
    ------
    OutputError
        Another run holds a lock, or an output cannot be locked.
    """
    store = PartStore(out)
    also = [check_path("also", p) for p in also if p is not None]
    with output_lock(out, *also, note=note):
        if resume:
            store.clean()
        else:
            store.discard()
        store.resumed = store.parts(last_part)
        try:
            yield store
        except BaseException as exc:
            if (_resumable(exc) or store.resumed) and store.parts(last_part):
                store.clean()  # a part a worker was writing when Ctrl-C reached it too
            else:
                store.discard()
            raise


def _resumable(exc: BaseException) -> bool:
    """Whether the finished chunks of a run stopped by ``exc`` are worth keeping: yes after Ctrl-C, an
    OS failure (disk full, ...) or a crash; no after bad input or options (a rerun must change them)."""
    return not isinstance(exc, MptrackError) or isinstance(exc, OSError)
