"""The SQLite store under a long-running server: its write-ahead log stays bounded under sustained
ingest while queries read, and retention finds old fixes without reading the whole table and leaves
ingest the writer's lock."""

from __future__ import annotations

import re
import sqlite3
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from mptrack.errors import OutputError
from mptrack.serve import _sqlite
from mptrack.serve._database import open_store
from mptrack.serve._store import stored_rows


def _fixes(devs, t: float):
    """One new fix (as the ingest stores it) at time ``t`` of each device of ``devs``."""
    return stored_rows([(0, int(d), t, 50.0, 8.0, 5.0, None, None, None, None, t, 50.0, 8.0, 1.0, 0.0, 1.0, 0.0,
                         0.0, 0.0, 0) for d in devs])


def test_the_log_starts_again_under_sustained_writes_and_reads(tmp_path, monkeypatch):
    """Batches of fixes of random devices committed back to back (a page of the (device, time) index a
    fix) while another thread reads histories: the log starts again, round after round (its header's
    salt changes at each start, SQLite's file format), and stays far smaller than what went through it
    (it grew by every page written, without end, when only passive checkpoints ran: 65 MB of 100)."""
    monkeypatch.setattr(_sqlite, "CHECKPOINT_S", 0.02)
    monkeypatch.setattr(_sqlite, "RESTART_FRAMES", 256)
    path = tmp_path / "log.db"
    store = open_store(f"sqlite:///{path}")
    rng = np.random.default_rng(5)
    keys = [k for k, _ in store.register([f"d{i}" for i in range(3000)])]
    stop, reads = threading.Event(), [0]

    def reader():
        rng_reader = np.random.default_rng(6)
        while not stop.is_set():
            store.histories(list(rng_reader.choice(keys, 20)), 10)
            reads[0] += 1

    thread = threading.Thread(target=reader)
    thread.start()
    wal, largest, written, salts = path.with_name("log.db-wal"), 0, 0, set()
    try:
        for b in range(400):
            devs = np.sort(rng.choice(keys, 64, replace=False))
            with store.batch(devs, np.zeros(len(devs), np.int64)) as tx:
                tx.write(_fixes(devs, 1e9 + b))
            written += 64
            largest = max(largest, wal.stat().st_size)
            with open(wal, "rb") as f:
                salts.add(f.read(32)[16:24])
    finally:
        stop.set()
        thread.join()
        store.close()
    assert reads[0] > 10
    assert len(salts) >= 5, len(salts)
    # ~a page a fix went into the log: 25,600 pages (100 MiB); the log never held a third of them
    assert largest < written * 4096 / 3, (largest, written)


def test_retention_finds_each_devices_old_fixes_by_its_index(tmp_path, monkeypatch):
    """--retain's deletes probe the (device, time) index device by device (found by time alone, each round's
    last batch, which finds nothing, read the whole index under the writer's lock); the old fixes go, every
    device's, the rest stay, also when a device has more old fixes than a transaction takes and when each
    transaction's time is up at once (one device each)."""
    monkeypatch.setattr(_sqlite, "RETAIN_HOLD_S", 0.0)
    path = tmp_path / "retain.db"
    store = open_store(f"sqlite:///{path}")
    keys = [k for k, _ in store.register([f"d{i}" for i in range(7)])]
    store.close()
    with sqlite3.connect(path) as con:
        plan = " | ".join(r[-1] for r in con.execute("EXPLAIN QUERY PLAN " + _sqlite._DELETE_OLD, (0, 0.0, 10)))
        assert "USING COVERING INDEX fixes_device_time (dev=? AND t<?)" in plan and "SCAN" not in plan, plan
        con.executemany("INSERT INTO fixes (dev, t, lat, lon, received, flag) VALUES (?, ?, 50.0, 8.0, 2000.0, 0)",
                        [(keys[i % 7], 1000.0 + (i * 37) % 500) for i in range(500)]
                        + [(keys[3], 900.0 + i * 1e-3) for i in range(95)])
    store = open_store(f"sqlite:///{path}")
    try:
        assert store.delete_before(1100.0, batch=30) == 195
        assert store.delete_before(1100.0, batch=30) == 0
    finally:
        store.close()
    with sqlite3.connect(path) as con:
        assert con.execute("SELECT count(*), min(t), count(DISTINCT dev) FROM fixes").fetchone() == (400, 1100.0, 7)


def test_retention_leaves_ingest_the_writers_lock_between_its_batches(tmp_path):
    """A backlog of old fixes deleted while batches of new ones commit back to back: the batches keep
    committing during the deletion (the deleting thread took the lock again at once after each of its
    batches, and ingest waited for the whole backlog)."""
    path = tmp_path / "backlog.db"
    store = open_store(f"sqlite:///{path}")
    keys = [k for k, _ in store.register([f"d{i}" for i in range(1000)])]
    store.close()
    with sqlite3.connect(path) as con:
        con.executemany("INSERT INTO fixes (dev, t, lat, lon, received, flag) VALUES (?, ?, 50.0, 8.0, 0, 0)",
                        ((i % 1000, 1000.0 + i) for i in range(150_000)))
    store = open_store(f"sqlite:///{path}")
    rng = np.random.default_rng(2)
    stop, commits = threading.Event(), []

    def ingest():
        b = 0
        while not stop.is_set():
            b += 1
            devs = np.sort(rng.choice(keys, 16, replace=False))
            with store.batch(devs, np.zeros(len(devs), np.int64)) as tx:
                tx.write(_fixes(devs, 1e6 + b))
            commits.append(time.perf_counter())

    thread = threading.Thread(target=ingest)
    thread.start()
    try:
        while not commits:
            time.sleep(0.01)
        started = time.perf_counter()
        assert store.delete_before(141_000.0) == 140_000
        ended = time.perf_counter()
    finally:
        stop.set()
        thread.join()
        store.close()
    during = [c for c in commits if started < c < ended]
    assert len(during) >= 50, (len(during), ended - started)
    gaps = np.diff([started] + during + [ended])   # here ~10 ms at most in a deletion of ~0.9 s
    assert gaps.max() < (ended - started) / 3, (gaps.max(), ended - started)


def test_a_database_in_a_missing_directory_is_refused_and_nothing_is_created(tmp_path):
    """A mistyped path (or a ~ that a URL does not expand) is named, not made: no directory appears."""
    with pytest.raises(OutputError, match=re.escape(f"db: the directory {tmp_path / 'missing'} does not exist; "
                                                    "create it first")):
        open_store(f"sqlite:///{tmp_path / 'missing' / 'mptrack.db'}", server=True)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OutputError, match=re.escape("db: the directory ~ does not exist (~ is not expanded in a URL: "
                                                    "give the whole path); create it first")):
        open_store("sqlite:///~/mptrack.db", server=True)
    assert not Path("~").exists()
