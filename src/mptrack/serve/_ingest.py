"""Group commit of accepted fixes through the live filter into the store.

Requests hand their parsed fixes to :meth:`Ingest.submit` and wait.  One task gathers everything
submitted meanwhile into a batch and, on one writer thread: sorts it by (device, time), tells each
fix apart as new (later than every fix of its device: it goes through the live filter), late (stored
with history, not filtered) or an exact duplicate (acknowledged, not stored again); advances the
live filter of every device in the batch in one call of the compiled engine
(:class:`mptrack.tracking.LiveTracks`); writes fixes and estimates in one durable transaction; and
only then wakes the requests, which answer 200.  If the write fails, the filters of the batch's
devices are put back as they were and every request of the batch fails (503): nothing half-done
is acknowledged.  While a batch commits, the next one gathers.

The fixes are the log and the device states checkpoints of it.  A device's state is stored
:attr:`Ingest.checkpoint_s` seconds after it changed (at most :data:`CHECKPOINT_ROWS` devices a batch,
so a large fleet's checkpoints never stall ingest), with the last fix row it covers; the watermark is
the row up to which every device's stored state covers its fixes.  After a crash, the fixes after the
watermark that a device's state does not cover are replayed through the same filter
(:meth:`Ingest.recover`), which gives the states the filter had, so the live estimates resume exactly.
Noise is re-estimated on another thread for devices with enough new fixes and applied between
batches, the devices' states stored at once, so that a replay sees the noise the live filter saw.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..tracking import ESTIMATE_FIELDS, FLAGS, LiveTracks, ellipse
from ._fix import iso_time
from ._store import Store

__all__ = ["Ingest", "Counters", "FLAG_NAMES", "LATE", "ESTIMATES"]

log = logging.getLogger("mptrack.serve")
#: The most devices whose noise one round re-estimates.
MAX_ESTIMATED = 2000
#: The most device states one batch checkpoints.
CHECKPOINT_ROWS = 2000
#: Names of the stored ``flag`` values: the tracking engine's flags, then "late" (stored, not filtered).
FLAG_NAMES = tuple(FLAGS) + ("late",)
LATE = len(FLAGS)
#: What :meth:`mptrack.tracking.LiveTracks.advance` returns for each fix, in the order stored (ESTIMATE_COLUMNS).
ESTIMATES = ESTIMATE_FIELDS


@dataclass
class Counters:
    """What ingest has done since the server started."""

    accepted: int = 0        # fixes answered 200
    filtered: int = 0        # ... that went through the live filter
    late: int = 0            # ... stored with history only (older than their device's last fix)
    duplicates: int = 0      # ... exact repeats of a stored fix, not stored again
    batches: int = 0         # group commits
    refused: dict = field(default_factory=dict)   # refused requests by reason (code)

    def refuse(self, code: str) -> None:
        self.refused[code] = self.refused.get(code, 0) + 1


class Ingest:
    """The group-commit writer (see the module doc)."""

    def __init__(self, store: Store, live: LiveTracks, *, checkpoint_s: float = 10.0,
                 calibrate_after: int = 30, history_fixes: int = 2000):
        self.store = store
        self.live = live
        self.checkpoint_s = checkpoint_s
        self.calibrate_after = calibrate_after
        self.history_fixes = history_fixes
        self.counters = Counters()
        self.keys: dict[str, int] = {}           # device id -> key (the live filter's track index)
        self.ids: list[str] = []
        self.lock = threading.Lock()             # the live state: the writer while it steps, readers
        self._writer = ThreadPoolExecutor(1, thread_name_prefix="mptrack-writer")
        self._estimator = ThreadPoolExecutor(1, thread_name_prefix="mptrack-noise")
        self._estimating = None                  # the noise estimate under way (a Future)
        self._pending: list = []                 # (fixes, future) waiting for the next batch
        self._wake: asyncio.Event | None = None
        self._task: asyncio.Task | None = None
        self._closing = False
        # devices changed since their last checkpoint, oldest first: key -> (the last fix row before
        # the change, when it changed)
        self._dirty: dict[int, tuple[int, float]] = {}
        self._seq = 0                            # the last fix row stored
        self._since_calibration = np.zeros(0, dtype=np.int64)
        self.listeners: set[asyncio.Queue] = set()

    # ---- start, recovery, stop --------------------------------------------------------------------
    def recover(self) -> None:
        """Load the device keys, the last checkpoint and replay the fixes stored after it."""
        for dev, device in self.store.device_keys():
            if dev != len(self.ids):
                raise RuntimeError(f"device keys are not contiguous at {dev}")  # pragma: no cover
            self.ids.append(device)
            self.keys[device] = dev
        self._grow(len(self.ids))
        watermark, chunks = self.store.load_checkpoint()
        covered = np.zeros(len(self.ids), np.int64)      # each device's fixes up to this row are in its state
        for states in chunks:
            known = [(self.keys[device], blob, upto) for device, blob, upto in states if device in self.keys]
            if known:
                idx = [d for d, _, _ in known]
                self.live.load_states(idx, [b for _, b, _ in known])
                covered[idx] = [u for _, _, u in known]
        self._seq = self.store.last_row()
        now = time.monotonic()
        for rows in self.store.replay(watermark):
            use = (rows["flag"] != LATE) & (rows["seq"] > covered[rows["dev"]])
            dev, t = rows["dev"][use], rows["t"][use]
            order = np.lexsort((t, dev))
            dev, t = dev[order], t[order]
            lat, lon, acc = rows["lat"][use][order], rows["lon"][use][order], rows["accuracy_m"][use][order]
            self.live.advance(dev, t, lat, lon, acc)
            for d in np.unique(dev).tolist():
                self._dirty.setdefault(d, (watermark, now))

    def start(self) -> None:
        self._wake = asyncio.Event()
        self._task = asyncio.get_running_loop().create_task(self._run())

    async def close(self) -> None:
        """Commit what is pending, checkpoint, stop the writer."""
        self._closing = True
        if self._wake is not None:
            self._wake.set()
        if self._task is not None:
            await self._task
        await asyncio.get_running_loop().run_in_executor(self._writer, self._checkpoint)
        self._writer.shutdown(wait=True)
        self._estimator.shutdown(wait=True)

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
            if not self._pending:
                if self._closing:
                    return
                continue
            batch, self._pending = self._pending, []
            fixes = [f for fs, _ in batch for f in fs]
            try:
                published = await loop.run_in_executor(self._writer, self._commit, fixes)
            except Exception as exc:  # every request of the batch fails; nothing was acknowledged
                for _, fut in batch:
                    if not fut.done():
                        fut.set_exception(exc)
                continue
            for fs, fut in batch:
                if not fut.done():
                    fut.set_result(None)
            if published is not None and self.listeners:
                events = self._events(published)   # once per batch, whatever the number of listeners
                for q in list(self.listeners):
                    if q.qsize() < 1000:           # a listener that does not read loses events, not memory
                        q.put_nowait(events)
            if self._pending:
                self._wake.set()

    # ---- the writer thread ---------------------------------------------------------------------
    def _grow(self, n: int) -> None:
        if n > len(self._since_calibration):
            size = max(n, 2 * len(self._since_calibration), 1024)
            self._since_calibration = np.r_[self._since_calibration,
                                            np.zeros(size - len(self._since_calibration), np.int64)]
        if n > self.live.n:
            self.live.add(n - self.live.n)

    def _commit(self, fixes: list[tuple]):
        now = time.time()
        new_devices = []
        keys = self.keys
        dev = np.empty(len(fixes), dtype=np.int64)
        for i, f in enumerate(fixes):
            k = keys.get(f[0])
            if k is None:
                k = keys[f[0]] = len(self.ids)
                self.ids.append(f[0])
                new_devices.append((k, f[0]))
            dev[i] = k
        try:
            self._grow(len(self.ids))
            cols = list(zip(*fixes))
            t = np.array(cols[1], dtype=float)
            lat = np.array(cols[2], dtype=float)
            lon = np.array(cols[3], dtype=float)
            acc = np.array([np.nan if a is None else a for a in cols[4]], dtype=float)
            order = np.lexsort((t, dev))
            d, ts, la, lo = dev[order], t[order], lat[order], lon[order]
            first = np.r_[True, d[1:] != d[:-1]]
            prev_t = np.where(first, np.nan, np.r_[np.nan, ts[:-1]])
            prev_same = ~first & (ts == prev_t) & (la == np.r_[np.nan, la[:-1]]) & (lo == np.r_[np.nan, lo[:-1]])
            last = self.live.last_fixes(d)
            dup_last = (ts == last[:, 0]) & (la == last[:, 1]) & (lo == last[:, 2])
            duplicate = prev_same | dup_last
            new = ~duplicate & ~(ts <= last[:, 0]) & ~(ts == prev_t)  # NaN last: a first fix is new
            late = ~duplicate & ~new
            sel = order[new]
            with self.lock:
                saved = self.live.save_states(np.unique(dev[sel]))
                est = self.live.advance(dev[sel], t[sel], lat[sel], lon[sel], acc[sel])
            rows = _rows(fixes, dev, sel, est, now)
            late_rows = _rows(fixes, dev, order[late], None, now)
            touched = np.unique(dev[sel]).tolist()
            ready = self._due_states()          # their states after this batch go in with its fixes
            watermark = self._oldest_row(set(ready))
            if any(d not in self._dirty for d in touched):   # newly changed: not covered after this batch's rows
                watermark = self._seq if watermark is None else min(watermark, self._seq)
            with self.lock:
                states = [(self.ids[d], self.live.state_bytes(d)) for d in ready]
            try:
                stored_late, last = self.store.write(rows, late_rows, new_devices, states, watermark)
            except BaseException:
                with self.lock:
                    self.live.restore_states(saved)
                raise
        except BaseException:
            for k, device in new_devices:  # not stored: forget the keys given in this batch
                del keys[device]
            del self.ids[len(self.ids) - len(new_devices):]
            raise
        before, self._seq = self._seq, last
        np.add.at(self._since_calibration, dev[sel], 1)
        for d in ready:
            del self._dirty[d]
        changed = time.monotonic()
        for d in touched:
            self._dirty.setdefault(d, (before, changed))
        c = self.counters
        c.accepted += len(fixes)
        c.filtered += len(sel)
        c.late += stored_late
        c.duplicates += len(fixes) - len(sel) - stored_late
        c.batches += 1
        self._noise()
        return (sel, fixes, est, dev) if self.listeners else None

    def _due_states(self) -> list[int]:
        """The devices whose state changed more than ``checkpoint_s`` ago (oldest first, at most
        CHECKPOINT_ROWS): stored with the next batch."""
        old = time.monotonic() - self.checkpoint_s
        ready = []
        for d, (_, changed) in self._dirty.items():   # oldest first
            if changed > old or len(ready) == CHECKPOINT_ROWS:
                break
            ready.append(d)
        return ready

    def _oldest_row(self, stored: set) -> int | None:
        """The watermark once the states of ``stored`` are stored: the row before the oldest change not
        among them (None: none left).  ``_dirty`` keeps its changes oldest first with non-decreasing rows
        (a device enters at its end, with the last row then stored), so this reads only as far as the
        first device not in ``stored`` -- a batch's checkpoints are the oldest changes, so this is
        O(checkpoints), not O(devices changed)."""
        for d, (row, _) in self._dirty.items():
            if d not in stored:
                return row
        return None

    def _noise(self, final: bool = False) -> None:
        """Apply the noise estimates that are ready, the devices' states stored at once (a replay must see
        the noise the filter saw from here on), and start the next round (devices with enough new fixes,
        estimated on another thread)."""
        fut = self._estimating
        if fut is not None and (fut.done() or final):
            self._estimating = None
            try:
                due, noise = fut.result()
            except Exception as exc:  # an estimate that fails leaves the devices' noise as it was
                log.warning("noise estimation failed: %s", exc)
            else:
                with self.lock:
                    self.live.set_noise(due, noise)
                self._store_states(due.tolist())
        if self._estimating is None and not final:
            due = np.flatnonzero(self._since_calibration[:len(self.ids)] >= self.calibrate_after)[:MAX_ESTIMATED]
            if len(due):
                self._since_calibration[due] = 0
                self._estimating = self._estimator.submit(self._estimate, due)

    def _checkpoint(self) -> None:
        """At shutdown: the noise estimate under way applied, every changed state stored."""
        self._noise(final=True)
        self._store_states(list(self._dirty))

    def _store_states(self, devices: list[int]) -> None:
        """Store these devices' states (they cover every fix stored so far) and the new watermark."""
        with self.lock:
            states = [(self.ids[d], self.live.state_bytes(d)) for d in devices]
        self.store.write(states=states, watermark=self._oldest_row(set(devices)))
        for d in devices:
            self._dirty.pop(d, None)

    def _estimate(self, due: np.ndarray) -> tuple[np.ndarray, dict]:
        """(due, noise) from the devices' recent stored fixes (on the estimator thread)."""
        histories = []
        for d in due.tolist():
            rows = self.store.recent(d, self.history_fixes)
            use = rows["flag"] != LATE
            histories.append({k: rows[k][use] for k in ("t", "lat", "lon", "accuracy_m")})
        return due, self.live.estimate_noise(histories)

    # ---- the stream --------------------------------------------------------------------------------
    @staticmethod
    def _events(published) -> list[tuple[str, str]]:
        """(device, JSON) of every fix of one committed batch: the stream's ``data:`` payloads."""
        sel, fixes, est, dev = published
        major, minor, az = ellipse(est["var_e"], est["cov_en"], est["var_n"])
        out = []
        for j, i in enumerate(sel.tolist()):
            f = fixes[i]
            e = {k: _num(v[j]) for k, v in est.items()}
            e.update(device=f[0], time=iso_time(f[1]), raw_lat=f[2], raw_lon=f[3], accuracy_m=f[4],
                     flag=FLAG_NAMES[int(est["flag"][j])], ell_major_m=_num(major[j]), ell_minor_m=_num(minor[j]),
                     ell_azimuth_deg=_num(az[j]))
            out.append((f[0], json.dumps(e, separators=(",", ":"))))
        return out


def _rows(fixes: list[tuple], dev: np.ndarray, sel: np.ndarray, est: dict | None, now: float) -> list[tuple]:
    """The stored rows (FIX_COLUMNS + ESTIMATE_COLUMNS) of ``fixes[sel]`` with their estimates."""
    head = [(k,) + f[1:8] + (_attrs(f[8]), now) for k, f in zip(dev[sel].tolist(), (fixes[i] for i in sel.tolist()))]
    if est is None:
        tail = (None,) * 8 + (LATE,)
        return [h + tail for h in head]
    return [h + e for h, e in zip(head, zip(*(_nullable(est[k]) for k in ESTIMATES)))]


def _nullable(values: np.ndarray) -> np.ndarray:
    """``values`` as Python numbers, NaN as None (stored as NULL)."""
    out = values.astype(object)
    out[values != values] = None
    return out


def _attrs(attrs) -> str | None:
    return None if not attrs else json.dumps(attrs, separators=(",", ":"), allow_nan=False, default=str)


def _num(v):
    v = v.item() if isinstance(v, np.generic) else v
    return None if isinstance(v, float) and v != v else v
