"""The server's noise estimates in a process of their own.

Re-estimating the noise of a round of devices reads their recent fixes and runs ``mptrack track``'s
maximum likelihood over them: tens of milliseconds of pandas, NumPy and compiled kernels, most of it
holding the interpreter lock.  On a thread of the server's process that lock kept the event loop
waiting, milliseconds at a time, for as long as a round ran (OsmAnd requests at half the maximum rate:
p99 12-16 ms with the estimates on a thread, 8-11 ms in this process, 5-6 ms with no estimates at all;
docs/serve.md).  A process of its own -- started with the server, with its own read-only store and a
live filter of the same options -- shares no lock with ingest; the server's estimator thread waits
for its answer.  It costs ~160-180 MiB (proportional set size: the numerical libraries it imports).
A process that dies (killed, out of memory) fails its round, and the next round starts another.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from .._core.threads import background
from ..tracking import LiveTracks, TrackOptions
from ._database import open_store
from ._store import HISTORY_COLUMNS

__all__ = ["NoiseEstimates"]

#: What the estimating process is given by the operating system beside the server (a nice value): the
#: requests first when the cores are busy.
NICENESS = 5
#: How often the estimating process checks that its server is still there (s).
ORPHAN_CHECK_S = 1.0


class NoiseEstimates:
    """Noise estimates of devices from their stored fixes, computed in a process of its own (see the
    module doc).

    Parameters
    ----------
    db : str
        The server's database URL (the process opens it to read).
    options : TrackOptions
        The live filter's options (the model and fix error the estimates are for).
    history_fixes : int
        The most recent fixes of a device an estimate reads.
    """

    def __init__(self, db: str, options: TrackOptions, history_fixes: int):
        self.db, self.options, self.history_fixes = db, options, int(history_fixes)
        self._pool: ProcessPoolExecutor | None = None

    def start(self) -> None:
        """Start the process now (it takes a second or two), without waiting for it."""
        self._process().submit(int)

    def estimate(self, devices: list[int]) -> tuple[dict, np.ndarray]:
        """(noise as :meth:`mptrack.tracking.LiveTracks.estimate_noise` gives it, the fixes each device's
        estimate used) of these devices.  Blocks until the process answers (call it from a thread)."""
        try:
            return self._process().submit(_estimate, devices, self.history_fixes).result()
        except BrokenProcessPool:   # the process died: this round fails, the next starts another
            self._pool.shutdown(wait=False)
            self._pool = None
            raise

    def _process(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=_start, initargs=(self.db, self.options, os.getpid()))
        return self._pool

    def close(self) -> None:
        """Stop the process (the round under way, if any, ends first)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


#: The estimating process's store and live filter (set by _start).
_WORKER: dict = {}


def _start(db: str, options: TrackOptions, server: int) -> None:
    """The estimating process's start: below the server in priority, deaf to the terminal's Ctrl-C (the
    server stops it), gone with its server (a server killed with -9 cannot stop it), its kernels on one
    thread, its store opened to read."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_orphaned, args=(server,), name="mptrack-noise-orphan", daemon=True).start()
    if hasattr(os, "nice"):   # (POSIX)
        os.nice(NICENESS)
    background()
    _WORKER["store"] = open_store(db, reader=True)
    _WORKER["live"] = LiveTracks(options)


def _orphaned(server: int) -> None:
    """Exit once the server process is gone (this process's parent changes)."""
    while os.getppid() == server:
        time.sleep(ORPHAN_CHECK_S)
    os._exit(0)


def _estimate(devices: list[int], n: int) -> tuple[dict, np.ndarray]:
    histories = _WORKER["store"].histories(devices, n)
    noise = _WORKER["live"].estimate_noise([dict(zip(HISTORY_COLUMNS, h.T)) for h in histories])
    return noise, np.array([len(h) for h in histories], dtype=np.int64)
