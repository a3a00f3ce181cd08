"""Group commit of accepted fixes through the live filter into the store.

Requests hand their parsed fixes to :meth:`Ingest.submit` and wait.  One task gathers everything
submitted meanwhile into a batch and, on one writer thread: sorts it by (device, time), tells each
fix apart as new (later than every fix of its device: it goes through the live filter), late (stored
with history, not filtered; so is a fix stamped far ahead of its device's clock, :data:`AHEAD_S`) or
an exact duplicate (acknowledged, not stored again); advances the
live filter of every device in the batch in one call of the compiled engine
(:class:`mptrack.tracking.LiveTracks`); writes fixes and estimates in one durable transaction; and
only then wakes the requests, which answer 200.  If the write fails, the filters of the batch's
devices are put back as they were and every request of the batch fails (503): nothing half-done
is acknowledged.  While a batch commits, the next one gathers.  With a store whose commit is quick
(``Store.quick_commit``: SQLite without fsync, PostgreSQL while it answers quickly), a batch of at most
:data:`INLINE_FIXES` fixes is committed on the event loop's own thread instead: two threads taking
turns at the interpreter lock cost more than such a commit.  Before it takes a batch, the writer lets
the event loop turn as long as each turn brings more requests (:data:`GATHER_TURNS`): a busy server's
batches are larger and cost less a fix.

The fixes are the log and the device states checkpoints of it.  With a store of one writer (SQLite)
a device's state is stored :attr:`Ingest.checkpoint_s` seconds after it changed, in the transaction
of the next batch (at most :data:`CHECKPOINT_ROWS` devices a batch, so a large fleet's checkpoints
never stall ingest), with the last fix row it covers; the watermark is
the row up to which every device's stored state covers its fixes.  After a crash, the fixes after the
watermark that a device's state does not cover are replayed through the same filter
(:meth:`Ingest.recover`), which gives the states the filter had, so the live estimates resume exactly.
Noise is re-estimated in a process of its own (:mod:`._estimates`) for devices with enough new fixes
(``calibrate_after``, or :data:`RENEW` times the fixes the device's last estimate used, whichever is
more), in rounds of several devices (:data:`ROUND_MIN`, or fewer once the first has waited
``checkpoint_s``), taking at most :data:`ESTIMATOR_SHARE` of a core while devices keep it busy, and
applied between batches (:data:`APPLY_ROWS` devices a batch), the devices' states stored at once, so
that a replay sees the noise the live filter saw.

With a shared store (PostgreSQL, several processes) a batch locks its devices' states first, loads
those another process changed, and stores the new state of every device it stepped with its fixes:
the stored states are always current and whichever process gets a device's next fix goes on from
there.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from json.encoder import encode_basestring

import numpy as np

from .._core.memory import grown, trim_heap
from ..tracking import ESTIMATE_FIELDS, LiveTracks, ellipse
from ._device_ids import DeviceIds
from ._estimates import NoiseEstimates
from ._fix import iso_time
from ._key_queue import KeyQueue
from ._log_throttle import LogThrottle
from ._metrics import Metrics
from ._store import (ESTIMATE_COLUMNS, FIX_COLUMNS, FLAG_NAMES, LATE, StaleStates, Store,
                     StoredRows)

__all__ = ["Ingest", "ESTIMATES", "StreamQueue"]

log = logging.getLogger("mptrack.serve")
#: The most devices whose noise one round re-estimates.
MAX_ESTIMATED = 2000
#: A round starts once this many devices are due, or once the first of them has waited ``checkpoint_s``: a
#: round has a fixed cost (~20 ms, most of it holding the interpreter lock that ingest needs) beside
#: ~0.3 ms a device, and devices fed at random fall due a few at a time (rounds of a median 3 devices
#: kept the estimator busy 22 % of the time, and 88 % of the requests slower than 8 ms came during one).
ROUND_MIN = 256
#: The most fixes a batch may have to be committed on the event loop's thread when the store's commit
#: is quick (a handoff to the writer thread costs more CPU than such a batch; a larger one, a bulk
#: upload, goes to the writer thread, so the server keeps answering while it commits).
INLINE_FIXES = 512
#: The most turns of the event loop a batch waits while each brings more requests: under load the requests
#: read in one turn join the batch instead of starting the next (64 connections: batches of ~64 fixes
#: instead of ~26, -15 % CPU a fix: a batch has a fixed cost of ~0.35 ms); an idle server's lone request
#: waits one turn.
GATHER_TURNS = 8
#: The most events a stream client's queue holds before a batch's are dropped for it (a queue that is
#: empty takes a batch of any size): a client that does not read loses events, not memory.  Counted in
#: batches (at most 1,000), two stalled clients held 320 MB after 600,000 bulk fixes, and could hold GBs.
STREAM_EVENTS = 10_000
#: A device's noise is estimated again once it has this fraction of the fixes its last estimate used
#: as new fixes (and at least ``calibrate_after``): the estimates follow a device's recent history while
#: a fix costs a few history rows read (re-estimating every 30 fixes from up to 2000 read ~67 a fix).
RENEW = 0.25
#: The share of a core the noise estimates take at most while devices keep them due: after a round the
#: next waits (1 / share - 1) times as long as that round took, so a busy server's estimates (a bulk
#: upload makes every device due every few batches) leave the cores to its commits and its database;
#: they catch up when ingest slows.
ESTIMATOR_SHARE = 0.25
#: The most devices whose new noise estimates one batch applies (a round's up to MAX_ESTIMATED devices are
#: applied over several batches): applying them means storing their states at once, ~5 us a device on
#: the event loop's thread, which 2000 devices at once stalled for ~11 ms.
APPLY_ROWS = 256
#: The most device states one batch checkpoints.
CHECKPOINT_ROWS = 2000
#: A shared store: a batch is written optimistically (one statement; filtered again if it met a state another
#: process changed meanwhile) while fewer than OPTIMISTIC_BELOW of the recent batches met one (a moving
#: average of weight STALE_WEIGHT), else with its rows locked first.  With routing by device a batch never
#: meets one; without, a worker meets the others' states in nearly every batch (each device's last fix went
#: to another worker half the time with two), and filtering twice cost more than the round trip saved.
OPTIMISTIC_BELOW = 0.05
STALE_WEIGHT = 0.1
#: A fix more than this ahead of its device's clock offset -- how far ahead of the server's clock the
#: device's last filtered fix was when it came -- and of the server's clock (s) is stored with the history,
#: not filtered: one fix stamped hours ahead (a receiver's bad time) would otherwise make every later fix
#: of its device late until then.  A device whose clock runs ahead all the time (local time sent as UTC)
#: keeps its offset and is filtered as any other; a device's first fix, or the first after a restart of
#: the server (the offsets are not stored), is trusted.  A device whose last filtered fix is still more
#: than this ahead of the server's clock when a fix that is not comes (its clock was set back, or that
#: trusted fix's time was wrong) has its live filter started again from that fix: else its fixes would
#: all be late until the server's clock passed that time.
AHEAD_S = 600.0
#: The shortest time between two log lines about such fixes (s).
AHEAD_LOG_S = 60.0
#: What :meth:`mptrack.tracking.LiveTracks.advance` returns for each fix, in the order stored (ESTIMATE_COLUMNS).
ESTIMATES = ESTIMATE_FIELDS


class Ingest:
    """The group-commit writer (see the module doc)."""

    def __init__(self, store: Store, live: LiveTracks, *, checkpoint_s: float = 10.0,
                 calibrate_after: int = 30, history_fixes: int = 2000, metrics: Metrics | None = None):
        self.store = store
        self.shared = bool(store.shared)
        self.live = live
        self.checkpoint_s = checkpoint_s
        self.calibrate_after = calibrate_after
        self.metrics = metrics if metrics is not None else Metrics.local()
        self.devices = DeviceIds()               # device id <-> key (the live filter's track index)
        self.lock = threading.Lock()             # the live state and the keys: the writer while it steps, readers
        self._writer = ThreadPoolExecutor(1, thread_name_prefix="mptrack-writer")
        # the noise estimates: a thread that waits for the process computing them (serve/_estimates.py)
        self._estimator = ThreadPoolExecutor(1, thread_name_prefix="mptrack-noise")
        self.estimates = NoiseEstimates(store.url, live.options, history_fixes)
        self._estimating = None                  # the noise estimate under way (a Future)
        self._applying = None                    # (due, noise, fixes used) of an estimate not yet all applied
        self._rest_until = 0.0                   # when the next estimate may start (monotonic)
        self._stopping = threading.Event()       # set at close: an estimate waiting to start goes at once
        self._pending: list = []                 # (fixes, future) waiting for the next batch
        self._wake: asyncio.Event | None = None
        self._task: asyncio.Task | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closing = False
        # devices changed since their last checkpoint, oldest first (an ordered set), with the last fix
        # row before the change and when it changed (monotonic) by key (a store with one writer)
        self._changed = KeyQueue()
        self._changed_row = np.zeros(0, dtype=np.int64)
        self._changed_at = np.zeros(0)
        self._seq = 0                            # the last fix row stored (a store with one writer)
        self._since_calibration = np.zeros(0, dtype=np.int32)
        self._estimated_on = np.zeros(0, dtype=np.int32)   # fixes each device's last noise estimate used
        self._noise_due = KeyQueue()              # devices due for a noise estimate, first due first
        self._due_since = 0.0                     # when the first of them fell due (monotonic)
        self._version = np.zeros(0, dtype=np.int64)   # a shared store: each device's state version held here
        self._clock = np.zeros(0, dtype=np.float32)   # each device's clock offset (AHEAD_S; NaN: unknown)
        self._ahead_log = LogThrottle(AHEAD_LOG_S)    # the lines about fixes ahead (_log_ahead)
        self._stale_rate = 0.0                    # a shared store: how often batches met others' states lately
        self.listeners: set[StreamQueue] = set()

    # ---- start, recovery, stop --------------------------------------------------------------------
    def recover(self) -> None:
        """Load the device keys and the stored states; with a store of one writer, replay the fixes
        stored after the last checkpoint."""
        self._add_keys(self.store.device_keys())
        watermark, chunks = self.store.load_checkpoint()
        covered = np.zeros(self.devices.size, np.int64)   # each device's fixes up to this row are in its state
        for states in chunks:
            keys, blobs, upto, versions = zip(*states)
            idx = np.array(keys, dtype=np.int64)
            # a shared store: a device another process registered after the keys were read is left out
            known = self.devices.known(idx)
            if not known.all():
                blobs = [b for b, k in zip(blobs, known.tolist()) if k]
            if known.any():
                self.live.load_states(idx[known], blobs)
                covered[idx[known]] = np.array(upto, np.int64)[known]
                self._version[idx[known]] = np.array(versions, np.int64)[known]
        if self.shared:
            return   # every stored state is current
        self._seq = self.store.last_row()
        now = time.monotonic()
        for rows in self.store.replay(watermark):
            use = np.flatnonzero((rows["flag"] != LATE) & (rows["seq"] > covered[rows["dev"]]))
            order = use[np.lexsort((rows["seq"][use], rows["dev"][use]))]
            dev, t, lat, lon, acc = (rows[c][order] for c in ("dev", "t", "lat", "lon", "accuracy_m"))
            # each device's filtered fixes in the order stored: forward in time, except where its live filter
            # started again (a clock set back, AHEAD_S), which the replay repeats
            first = np.r_[True, dev[1:] != dev[:-1]]
            back = np.r_[False, t[1:] < t[:-1]] & ~first
            back[first] = t[first] < self.live.last_fixes(dev[first])[:, 0]
            part = np.cumsum(back)
            part -= np.maximum.accumulate(np.where(first, part - back, 0))   # the device's restarts so far
            for k in range(int(part.max(initial=0)) + 1):
                sel = part == k
                if k:
                    self.live.restart(dev[sel & back])
                self.live.advance(dev[sel], t[sel], lat[sel], lon[sel], acc[sel])
            self._mark(np.unique(dev), watermark, now)

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        self._task = self._loop.create_task(self._run())
        self.estimates.start()

    async def close(self) -> None:
        """Commit what is pending, checkpoint, stop the writer."""
        self._closing = True
        self._stopping.set()
        if self._wake is not None:
            self._wake.set()
        if self._task is not None:
            await self._task
        await asyncio.get_running_loop().run_in_executor(self._writer, self._checkpoint)
        self._writer.shutdown(wait=True)
        self._estimator.shutdown(wait=True)
        self.estimates.close()

    # ---- the request side ------------------------------------------------------------------------
    async def submit(self, fixes: list[tuple]) -> None:
        """Wait until ``fixes`` are committed (raises what the commit raised)."""
        if self._closing:
            raise ConnectionAbortedError("the server is stopping")
        fut = asyncio.get_running_loop().create_future()
        self._pending.append((fixes, fut))
        self._wake.set()
        await fut

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            self._wake.clear()
            for _ in range(GATHER_TURNS):    # the requests the loop has read meanwhile join this batch
                waiting = len(self._pending)
                await asyncio.sleep(0)
                if len(self._pending) == waiting:
                    break
            if not self._pending:
                if self._closing:
                    return
                continue
            batch, self._pending = self._pending, []
            fixes = [f for fs, _ in batch for f in fs]
            try:
                if self.store.quick_commit and len(fixes) <= INLINE_FIXES:
                    events = self._commit(fixes)
                else:
                    events = await loop.run_in_executor(self._writer, self._commit, fixes)
            except Exception as exc:  # every request of the batch fails; nothing was acknowledged
                self.metrics.add("commit_failures")
                for _, fut in batch:
                    if not fut.done():
                        fut.set_exception(exc)
                continue
            for fs, fut in batch:
                if not fut.done():
                    fut.set_result(None)
            if len(fixes) > INLINE_FIXES:   # a bulk upload's rows are gone: so is their memory
                loop.run_in_executor(self._writer, trim_heap)
            if events and not self.shared:
                self._publish(events)
            if self._pending:
                self._wake.set()

    # ---- the stream ---------------------------------------------------------------------------------
    def listen(self, queue: StreamQueue) -> None:
        """``queue`` gets the events of every committed batch (a list of (device, JSON) each) from now
        on: this process's own, or with a shared store every process's."""
        self.listeners.add(queue)
        if self.shared:
            self.store.subscribe(self._deliver)

    def _deliver(self, payload: str) -> None:
        """A stream payload of a shared store (on its listener thread): to the event loop."""
        events = [tuple(line.split("\t", 1)) for line in payload.split("\n") if "\t" in line]
        if self._loop is not None and events:
            self._loop.call_soon_threadsafe(self._publish, events)

    def _publish(self, events: list[tuple[str, str]]) -> None:
        for q in list(self.listeners):
            q.offer(events)

    def device_counts(self, window_s: float) -> tuple[int, int]:
        """(devices that have sent a fix, those whose last fix is at most ``window_s`` old), over every
        process of a shared store."""
        since = time.time() - window_s
        if self.shared:
            return len(self.store.device_keys()), self.store.live_devices(since)
        with self.lock:
            t = self.live.last_fixes(np.arange(self.live.n))[:, 0]
        return len(self.devices), int(np.count_nonzero(t >= since))

    # ---- keys and states (a shared store: written by other processes too) ------------------------------
    def _add_keys(self, pairs) -> None:
        if not pairs:
            return
        with self.lock:
            self.devices.add(pairs)
            self._grow(self.devices.size)

    def key(self, device: str) -> int | None:
        """The key of a device that has sent a fix (to any process of a shared store), or None."""
        k = self.devices.get(device)
        if k is None and self.shared:
            self._add_keys(self.store.device_keys([device]))
            k = self.devices.get(device)
        return k

    def refresh(self, devs=None) -> None:
        """A shared store: the live state of ``devs`` (all devices when None) brought up to what any
        process has committed (a reader's view; the writer locks and reads in its transaction)."""
        if not self.shared:
            return
        if devs is None:
            self._add_keys(self.store.device_keys())
        with self.lock:
            versions = self._version.copy()
        rows = self.store.states(None if devs is None else np.asarray(devs, np.int64), versions)
        if rows:
            with self.lock:   # only what is newer than what this process has (its writer may be ahead)
                self._load([r for r in rows if r[1] > self._version[r[0]]])

    def _load(self, stale) -> None:
        """Load (dev, version, blob) states into the live filter (the lock held)."""
        with_state = [(d, b) for d, _, b in stale if b is not None]
        if with_state:
            self.live.load_states([d for d, _ in with_state], [b for _, b in with_state])
        for d, v, _ in stale:
            self._version[d] = v

    # ---- the writer thread ---------------------------------------------------------------------
    def _grow(self, n: int) -> None:
        if n > len(self._since_calibration):
            size = max(n, 2 * len(self._since_calibration), 1024)
            self._since_calibration, self._estimated_on, self._version, self._changed_row, self._changed_at = (
                grown(a, size) for a in (self._since_calibration, self._estimated_on, self._version,
                                         self._changed_row, self._changed_at))
            self._clock = grown(self._clock, size, np.nan)
        if n > self.live.n:
            self.live.add(n - self.live.n)

    def _keys_of(self, fixes: list[tuple]) -> np.ndarray:
        """The keys of the fixes' devices, registering the new devices."""
        devices = [f[0] for f in fixes]
        keys = self.devices.keys_of(devices)
        if (keys < 0).any():
            self._add_keys(self.store.register(sorted({d for d, k in zip(devices, keys.tolist()) if k < 0})))
            keys = self.devices.keys_of(devices)
        return keys

    def _commit(self, fixes: list[tuple]):
        """Filter and commit one batch (a shared store: optimistic first, then, if another process changed
        one of its devices meanwhile, again from the states it wrote, the rows locked first)."""
        if not self.shared or self._stale_rate >= OPTIMISTIC_BELOW:
            return self._commit_batch(fixes, optimistic=False)
        try:
            return self._commit_batch(fixes, optimistic=True)
        except StaleStates as exc:       # nothing was written, the live states are as they were
            self.metrics.add("commit_retries")
            self._met_stale(True)
            with self.lock:
                self._load(exc.stale)
            return self._commit_batch(fixes, optimistic=False)

    def _met_stale(self, met: bool) -> None:
        """One batch into the moving average of those that met another process's states."""
        self._stale_rate += STALE_WEIGHT * (float(met) - self._stale_rate)

    def _commit_batch(self, fixes: list[tuple], optimistic: bool):
        now = time.time()
        dev = self._keys_of(fixes)
        cols = list(zip(*fixes))
        # the fixes' columns as stored (None: NaN, stored as NULL)
        stored = {name: np.array(cols[k], dtype=float) for k, name in enumerate(FIX_COLUMNS[1:8], start=1)}
        stored["dev"] = dev
        t, lat, lon, acc = stored["t"], stored["lat"], stored["lon"], stored["accuracy_m"]
        order = np.lexsort((t, dev))
        d, ts, la, lo = dev[order], t[order], lat[order], lon[order]
        first = np.concatenate(([True], d[1:] != d[:-1]))
        prev_t = np.where(first, np.nan, _previous(ts))
        prev_same = ~first & (ts == prev_t) & (la == _previous(la)) & (lo == _previous(lo))
        devs = d[first]
        with self._undone_on_failure(devs) as versions:
            with self.store.batch(devs, versions, optimistic) as tx:
                with self.lock:
                    self._load(tx.stale)      # what other processes committed for these devices
                    if self.shared:
                        self._met_stale(bool(tx.stale))
                    last = self.live.last_fixes(d)
                    back = last[:, 0] > now + AHEAD_S
                    restarted = ()
                    if back.any():
                        back &= (ts <= now + AHEAD_S) & ~prev_same
                    if back.any():   # clocks set back: these devices' live filters start again
                        restarted = np.unique(d[back])
                        self.live.restart(restarted)
                        self._clock[restarted] = 0.0
                        last = self.live.last_fixes(d)
                    dup_last = (ts == last[:, 0]) & (la == last[:, 1]) & (lo == last[:, 2])
                    duplicate = prev_same | dup_last
                    new = ~duplicate & ~(ts <= last[:, 0]) & ~(ts == prev_t)  # NaN last: a first fix is new
                    ahead = new & (ts - now > AHEAD_S)   # then also ahead of its device's clock offset
                    if ahead.any():
                        ahead &= ts - now > AHEAD_S + np.nan_to_num(np.maximum(self._clock[d], 0.0), nan=np.inf)
                        new &= ~ahead
                    late = ~duplicate & ~new
                    sel = order[new]
                    # checked: the fixes were checked as they came, sorted above, each after its device's last
                    est = self.live.advance(dev[sel], t[sel], lat[sel], lon[sel], acc[sel], checked=True)
                    touched, filtered = np.unique(dev[sel], return_counts=True)
                    if len(sel):  # each device's clock offset: its last filtered fix's
                        dn, tn = d[new], ts[new]
                        ends = np.r_[dn[1:] != dn[:-1], True]
                        self._clock[dn[ends]] = tn[ends] - now
                    if self.shared:   # every state goes in with its fixes
                        states, ready, watermark = self._states_of(touched), [], None
                    else:             # the states that changed checkpoint_s ago go in with this batch
                        ready = self._due_states()
                        watermark = self._oldest_row(set(ready))
                        if not self._changed.has(touched).all():   # newly changed: not covered
                            watermark = self._seq if watermark is None else min(watermark, self._seq)
                        states = self._checkpoints(ready)
                rows = _rows(stored, cols[8], sel, est, now)
                late_rows = _rows(stored, cols[8], order[late], None, now) if late.any() else None
                stream = self.store.streaming() if self.shared else bool(self.listeners)
                events = self._events(sel, fixes, est) if stream and len(sel) else None
                tx.write(rows, late_rows, states, [f"{k}\t{e}" for k, e in events or ()], watermark)
        stored_late = tx.stored_late
        self._since_calibration[touched] += filtered
        used = self._estimated_on[touched]
        due = touched[self._since_calibration[touched] >= np.maximum(self.calibrate_after, RENEW * used)]
        if len(due) and not len(self._noise_due):
            self._due_since = time.monotonic()
        self._noise_due.add(due)
        if not self.shared:
            before, self._seq = self._seq, tx.last_row
            self._changed.discard(ready)
            self._mark(touched, before, time.monotonic())
        m = self.metrics
        m.add("accepted", len(fixes))
        m.add("filtered", len(sel))
        m.add("late", stored_late)
        if len(restarted):
            self._log_back(fixes[order[back][0]], len(restarted))
        if ahead.any():
            m.add("ahead", int(ahead.sum()))
            self._log_ahead(fixes[order[ahead][0]], int(ahead.sum()))
        m.add("duplicates", len(fixes) - len(sel) - stored_late)
        m.add("batches")
        m.observe("batch", len(fixes))
        self._noise()
        return events

    def _log_ahead(self, fix: tuple, n: int) -> None:
        """A log line about fixes kept out of the live filter for their time (AHEAD_S): the first at once,
        then at most one every AHEAD_LOG_S seconds with how many came meanwhile."""
        held = self._ahead_log.due("ahead", n)
        if held is None:
            return
        log.warning("device %s sent a fix stamped %s, %.1f h after the server's clock and after its own clock so "
                    "far: stored with its history, kept out of its live track%s", fix[0], iso_time(fix[1]),
                    (fix[1] - time.time()) / 3600.0, f" ({n + held - 1} more such fixes since the last such line)"
                    if n + held > 1 else "", extra={"event": "ahead", "device": fix[0]})

    def _log_back(self, fix: tuple, n: int) -> None:
        """A log line about live filters started again by a fix before their last (AHEAD_S), throttled as
        _log_ahead's."""
        held = self._ahead_log.due("back", n)
        if held is None:
            return
        log.warning("device %s sent a fix stamped %s, before its last filtered fix, which is still more than "
                    "%.0f min after the server's clock: its clock was set back, or that fix's time was wrong; its "
                    "live track starts again from this fix%s", fix[0], iso_time(fix[1]), AHEAD_S / 60.0,
                    f" ({n + held - 1} more such devices since the last such line)" if n + held > 1 else "",
                    extra={"event": "clock_back", "device": fix[0]})

    def _states_of(self, devs: np.ndarray) -> list[tuple[int, bytes, float]]:
        """A shared store: (key, blob, last fix time) of these devices, their versions raised (lock held)."""
        self._version[devs] += 1
        t_last = self.live.last_fixes(devs)[:, 0].tolist()
        return list(zip(devs.tolist(), self.live.states_bytes(devs), t_last))

    def _checkpoints(self, devices: list[int]) -> list[tuple[int, bytes, float]]:
        """(key, blob, NaN) of these devices' states: checkpoints (a store with one writer; lock held)."""
        if not devices:
            return []
        return [(d, b, np.nan) for d, b in zip(devices, self.live.states_bytes(devices))]

    def _due_states(self) -> list[int]:
        """The devices whose state changed more than ``checkpoint_s`` ago (oldest first, at most
        CHECKPOINT_ROWS): stored with the next batch (a store with one writer)."""
        oldest = self._changed.oldest(CHECKPOINT_ROWS)
        return oldest[:np.count_nonzero(self._changed_at[oldest] <= time.monotonic() - self.checkpoint_s)].tolist()

    def _oldest_row(self, stored: set) -> int | None:
        """The watermark once the states of ``stored`` are stored: the row before the oldest change not
        among them (None: none left).  ``_changed`` keeps its changes oldest first with non-decreasing rows
        (a device enters at its end, with the last row then stored), so this reads only as far as the
        first device not in ``stored`` -- a batch's checkpoints are the oldest changes, so this is
        O(checkpoints), not O(devices changed)."""
        rest = [d for d in self._changed.oldest(len(stored) + 1).tolist() if d not in stored]
        return int(self._changed_row[rest[0]]) if rest else None

    def _mark(self, keys: np.ndarray, row: int, at: float) -> None:
        """Devices ``keys`` (distinct) changed at ``at`` after fix row ``row`` (those not changed already)."""
        new = self._changed.add(keys)
        self._changed_row[new] = row
        self._changed_at[new] = at

    def _noise(self, final: bool = False) -> None:
        """Apply the noise estimates that are ready, APPLY_ROWS devices a call, each one's state stored at
        once (a replay, or another process, must see the noise the filter saw from here on), and once all
        are applied start the next round (devices with enough new fixes, estimated in the estimates'
        process)."""
        fut = self._estimating
        if fut is not None and (fut.done() or final):
            self._estimating = None
            try:
                self._applying = fut.result()
            except Exception as exc:  # an estimate that fails leaves the devices' noise as it was
                log.warning("noise estimation failed: %s", exc)
        if self._applying is not None:   # APPLY_ROWS devices a batch (at closing, all)
            due, noise, used = self._applying
            k = len(due) if final else APPLY_ROWS
            self._applying = (due[k:], {name: v[k:] for name, v in noise.items()}, used[k:]) if k < len(due) else None
            try:
                self._set_noise(due[:k], {name: v[:k] for name, v in noise.items()})
                self._estimated_on[due[:k]] = used[:k]
            except Exception as exc:  # the devices' noise and states as they were (_set_noise put them back)
                log.warning("noise estimates not applied: %s", exc)
        waiting = len(self._noise_due)
        if self._estimating is None and self._applying is None and not final and (
                waiting >= ROUND_MIN or (waiting and time.monotonic() - self._due_since >= self.checkpoint_s)):
            due = self._noise_due.oldest(MAX_ESTIMATED)
            self._noise_due.discard(due)
            self._due_since = time.monotonic()
            self._since_calibration[due] = 0
            self._estimating = self._estimator.submit(self._estimate, due)

    def _checkpoint(self) -> None:
        """At shutdown: the noise estimate under way applied, every changed state stored."""
        self._noise(final=True)
        if not self.shared:
            self._store_states(self._changed.oldest(len(self._changed)).tolist())

    def _set_noise(self, due: np.ndarray, noise: dict) -> None:
        """Apply a noise estimate and store the devices' states at once (so that a replay, or another
        process, sees the noise the live filter saw)."""
        with self._undone_on_failure(due) as versions:
            if not self.shared:
                with self.lock:
                    self.live.set_noise(due, noise)
                self._store_states(due.tolist())
                return
            with self.store.batch(due, versions) as tx:
                with self.lock:
                    self._load(tx.stale)
                    self.live.set_noise(due, noise)
                    states = self._states_of(due)
                tx.write(states=states)

    @contextlib.contextmanager
    def _undone_on_failure(self, devs: np.ndarray):
        """The live states of ``devs`` (sorted keys) and their versions put back as they were if the block
        fails (its transaction rolled back); yields the versions held now."""
        with self.lock:
            saved = self.live.save_states(devs)
            versions = self._version[devs].copy()
        try:
            yield versions
        except BaseException:
            with self.lock:
                self.live.restore_states(saved)
                self._version[devs] = versions
            raise

    def _store_states(self, devices: list[int]) -> None:
        """Store these devices' states (they cover every fix stored so far) and the new watermark (a store
        with one writer)."""
        with self.lock:
            states = self._checkpoints(devices)
        stored = set(devices)
        keys = np.array(sorted(stored), dtype=np.int64)
        with self.store.batch(keys, self._version[keys]) as tx:
            tx.write(states=states, watermark=self._oldest_row(stored))
        self._changed.discard(devices)

    def _estimate(self, due: np.ndarray) -> tuple[np.ndarray, dict, np.ndarray]:
        """(due, noise, fixes used) from the devices' recent stored fixes (on the estimator thread, after the
        rest that ESTIMATOR_SHARE asks of the round before; computed in the estimates' process)."""
        self._stopping.wait(self._rest_until - time.monotonic())
        started = time.monotonic()
        noise, used = self.estimates.estimate(due.tolist())
        now = time.monotonic()
        self._rest_until = now + (1.0 / ESTIMATOR_SHARE - 1.0) * (now - started)
        return due, noise, used

    @staticmethod
    def _events(sel: np.ndarray, fixes: list[tuple], est: dict) -> list[tuple[str, str]]:
        """(device, JSON) of every filtered fix of one batch: the stream's ``data:`` payloads (written from
        a template, each number as json writes it: 22.5 -> 11.5 us a fix with a map open)."""
        major, minor, az = ellipse(est["var_e"], est["cov_en"], est["var_n"])
        columns = [[_FLAG_JSON[x] if k == "flag" else _json_number(x) for x in est[k].tolist()]
                   for k in ESTIMATE_FIELDS]
        shape = [[_json_number(x) for x in c.tolist()] for c in (major, minor, az)]
        out = []
        for j, i in enumerate(sel.tolist()):
            f = fixes[i]
            out.append((f[0], _EVENT % (*[c[j] for c in columns], encode_basestring(f[0]),
                                        encode_basestring(iso_time(f[1])), _json_number(f[2]), _json_number(f[3]),
                                        _json_number(f[4]), *[c[j] for c in shape])))
        return out


def _rows(stored: dict, attrs: tuple, sel: np.ndarray, est: dict | None, now: float) -> StoredRows:
    """The stored rows of fixes ``sel`` (their columns ``stored``, their ``attrs``) with their estimates
    (None: late fixes, without)."""
    n = len(sel)
    out = {name: values[sel] for name, values in stored.items()}
    out["attrs"] = np.full(n, None, dtype=object)
    if any(attrs):
        out["attrs"][:] = [_attrs(attrs[i]) for i in sel.tolist()]
    out["received"] = np.full(n, now)
    for name, field in zip(ESTIMATE_COLUMNS, ESTIMATES):
        out[name] = est[field] if est is not None else np.full(n, LATE if name == "flag" else np.nan)
    return StoredRows(out)


def _previous(values: np.ndarray) -> np.ndarray:
    """Each row's previous value (NaN for the first)."""
    return np.concatenate(([np.nan], values[:-1]))


def _attrs(attrs) -> str | None:
    return None if not attrs else json.dumps(attrs, separators=(",", ":"), allow_nan=False, default=str)


def _json_number(x) -> str:
    """A number as JSON (json's own text for it): null for None, NaN and the infinities."""
    return "null" if x is None or not math.isfinite(x) else repr(x)


#: A stream event's JSON: a fix's estimate (ESTIMATE_FIELDS, its flag by name), then its device, time,
#: the fix as sent and the estimate's 1-sigma ellipse (:meth:`Ingest._events` fills it)
_EVENT = "{" + ",".join(f'"{k}":%s' for k in ESTIMATE_FIELDS + ("device", "time", "raw_lat", "raw_lon", "accuracy_m",
                                                                "ell_major_m", "ell_minor_m", "ell_azimuth_deg")) + "}"
_FLAG_JSON = [encode_basestring(name) for name in FLAG_NAMES]


class StreamQueue(asyncio.Queue):
    """A stream client's committed events, a list of (device, JSON) a batch, bounded by events
    (:data:`STREAM_EVENTS`), not by batches: a bulk upload's batch holds tens of thousands."""

    def __init__(self):
        super().__init__()
        self.events = 0

    def offer(self, events: list[tuple[str, str]]) -> None:
        """Queue a batch's events, unless the client has not read STREAM_EVENTS of them yet."""
        if self.events == 0 or self.events + len(events) <= STREAM_EVENTS:
            self.put_nowait(events)

    # asyncio.Queue's hooks for its storage: the count follows every way in and out
    def _put(self, events) -> None:
        super()._put(events)
        self.events += len(events)

    def _get(self):
        events = super()._get()
        self.events -= len(events)
        return events
