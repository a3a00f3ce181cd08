"""The SQLite store's write-ahead log stays bounded under sustained ingest while queries read."""

from __future__ import annotations

import threading

import numpy as np

from mptrack.serve import _sqlite
from mptrack.serve._database import open_store
from mptrack.serve._store import stored_rows


def test_the_log_starts_again_under_sustained_writes_and_reads(tmp_path, monkeypatch):
    """Batches of fixes of random devices committed back to back (a page of the (device, time) index a
    fix) while another thread reads histories: the log stays within a few checkpoint rounds' writes
    (it grew by every page written, without end, when only passive checkpoints ran)."""
    monkeypatch.setattr(_sqlite, "CHECKPOINT_S", 0.02)
    monkeypatch.setattr(_sqlite, "RESTART_FRAMES", 256)
    path = tmp_path / "log.db"
    store = open_store(f"sqlite:///{path}")
    rng = np.random.default_rng(5)
    keys = [k for k, _ in store.register([f"d{i}" for i in range(3000)])]
    stop, reads = threading.Event(), [0]

    def reader():
        while not stop.is_set():
            store.histories(list(rng.choice(keys, 20)), 10)
            reads[0] += 1

    thread = threading.Thread(target=reader)
    thread.start()
    wal, largest, written = path.with_name("log.db-wal"), 0, 0
    try:
        for b in range(400):
            devs = np.sort(rng.choice(keys, 64, replace=False))
            rows = stored_rows([(0, int(d), 1e9 + b, 50.0, 8.0, 5.0, None, None, None, None, 1e9 + b, 50.0, 8.0,
                                 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0) for d in devs])
            with store.batch(devs, np.zeros(len(devs), np.int64)) as tx:
                tx.write(rows)
            written += 64
            largest = max(largest, wal.stat().st_size)
    finally:
        stop.set()
        thread.join()
        store.close()
    assert reads[0] > 10
    # ~a page a fix went into the log: 25,600 pages (100 MiB); the log never held more than a tenth of them
    assert largest < written * 4096 / 10, (largest, written)
