"""Many server processes on one PostgreSQL database: each device's fixes applied once, in order,
whichever process receives them (the result of a single process); the stream shows every process's
fixes; kill -9 of a worker and a restart of PostgreSQL under load lose nothing acknowledged; the
schema is versioned; ``mptrack db copy`` moves a SQLite installation to PostgreSQL and back losing
nothing."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from _postgres import postgres_or_skip
from _server import SRC, Server, check_acked, query, stored

from mptrack.errors import OutputError
from mptrack.tracking import LiveTracks, TrackOptions

T0 = int(time.time()) - 20_000


def _walk(devices: int, fixes: int, seed: int) -> dict[str, list[tuple[int, float, float]]]:
    """Each device's fixes (t, lat, lon) in time order: a random walk around its own start."""
    rng = np.random.default_rng(seed)
    out = {}
    for d in range(devices):
        t = T0 + np.cumsum(rng.integers(1, 30, fixes))
        lat = 48.0 + 0.01 * d + np.cumsum(rng.normal(0, 2e-5, fixes))
        lon = 11.0 + np.cumsum(rng.normal(0, 3e-5, fixes))
        out[f"pg-{seed}-{d}"] = list(zip(t.tolist(), lat.tolist(), lon.tolist()))
    return out


def _reference(fixes: dict) -> dict[str, dict]:
    """The single-process run: every device's fixes through one LiveTracks in time order."""
    live = LiveTracks(TrackOptions())
    out = {}
    for k, (dev, rows) in enumerate(fixes.items()):
        live.add(1)
        t, lat, lon = (np.array(c, dtype=float) for c in zip(*rows))
        out[dev] = live.advance(np.full(len(t), k), t, lat, lon, np.full(len(t), 5.0))
    return out


def _spray(urls: list[str], fixes: dict, seed: int, threads: int = 6, repeat: float = 0.1) -> int:
    """Send every device's fixes in time order, each to a server chosen at random (a device's next fix
    after the 200 of the one before); some fixes are sent twice (to any server).  Returns the number
    of requests."""
    devices = list(fixes)
    sent = []
    errors = []

    def work(part: list[str], s: int) -> None:
        rng = np.random.default_rng(s)
        n = 0
        queues = {d: list(fixes[d]) for d in part}
        with httpx.Client(timeout=60.0) as http:
            while queues:
                dev = list(queues)[int(rng.integers(len(queues)))]
                t, lat, lon = queues[dev].pop(0)
                if not queues[dev]:
                    del queues[dev]
                for _ in range(2 if rng.random() < repeat else 1):
                    url = urls[int(rng.integers(len(urls)))]
                    r = http.get(f"{url}/?id={dev}&timestamp={t}&lat={lat!r}&lon={lon!r}&accuracy=5")
                    if r.status_code != 200:
                        errors.append((r.status_code, r.text))
                    n += 1
        sent.append(n)

    pool = [threading.Thread(target=work, args=(devices[i::threads], seed * 100 + i)) for i in range(threads)]
    for th in pool:
        th.start()
    for th in pool:
        th.join(600)
    assert not errors, errors[:3]
    return sum(sent)


def _sse(url: str, seconds: float, out: list, ready: threading.Event) -> None:
    with httpx.Client(timeout=None) as http, http.stream("GET", f"{url}/api/stream") as r:
        ready.set()
        deadline = time.monotonic() + seconds
        try:
            for line in r.iter_lines():
                if line.startswith("data: "):
                    out.append(line[6:])
                if time.monotonic() > deadline:
                    return
        except httpx.HTTPError:
            return   # the server stopped


def _metrics(url: str) -> dict[str, float]:
    text = httpx.get(f"{url}/metrics", timeout=30).text
    return {m.group(1): float(m.group(2)) for m in re.finditer(r"^(mptrack_\S+) (\S+)$", text, re.M)}


def test_two_servers_apply_each_device_in_order_once(tmp_path, postgres):
    """Two server processes on one database, fixes of the same devices sprayed at both at random: each
    device's stored estimates and final state are those of one process fed its fixes in time order;
    nothing lost or doubled; a stream client of one server sees the other's fixes."""
    db = postgres.create_database("two_servers")
    a = Server(tmp_path, "--rate", "0", db=db).start()
    b = Server(tmp_path, "--rate", "0", db=db).start()
    try:
        fixes = _walk(24, 25, seed=7)           # < 30 fixes a device: no noise re-estimation (its timing varies)
        events: list = []
        ready = threading.Event()
        listener = threading.Thread(target=_sse, args=(a.url, 120.0, events, ready), daemon=True)
        listener.start()
        assert ready.wait(30)
        time.sleep(1.5)                          # the writers look for stream clients once a second
        requests = _spray([a.url, b.url], fixes, seed=7)
        want = _reference(fixes)
        rows = stored(db)
        assert len(rows) == sum(len(v) for v in fixes.values()), "fixes lost or doubled"
        for dev, ref in want.items():
            got = rows[rows["device_id"] == dev].sort_values("t")
            assert list(got["t"]) == [float(t) for t, _, _ in fixes[dev]]
            np.testing.assert_array_equal(got["flag"].to_numpy(), ref["flag"])
            np.testing.assert_allclose(got["est_lat"].to_numpy(), ref["lat"], rtol=0, atol=1e-12)
            np.testing.assert_allclose(got["est_lon"].to_numpy(), ref["lon"], rtol=0, atol=1e-12)
            np.testing.assert_allclose(got["var_e"].to_numpy(), ref["var_e"], rtol=1e-12)
            for srv in (a, b):                  # the final state, as either server knows it now
                pos = srv.json(f"/api/devices/{dev}/position")
                assert abs(pos["lat"] - ref["lat"][-1]) < 1e-12 and abs(pos["lon"] - ref["lon"][-1]) < 1e-12
        stats = [s.json("/api/stats") for s in (a, b)]   # each process counts its own requests
        assert sum(s["accepted"] for s in stats) == requests and sum(s["filtered"] for s in stats) == len(rows)
        assert sum(s["duplicates"] for s in stats) == requests - len(rows)
        metrics = [s.get("/metrics").text for s in (a, b)]
        retries, commits = ([float(re.search(rf"^mptrack_{name}_total (\S+)$", m, re.M).group(1)) for m in metrics]
                            for name in ("commit_retries", "commits"))
        # optimistic batches met the other's states and were filtered again -- and then the batches locked
        # their rows first, as nearly every one met such a state (no routing by device here)
        assert 0 < sum(retries) <= 0.1 * sum(commits), (retries, commits)
        deadline = time.monotonic() + 10
        while len(events) < len(rows) and time.monotonic() < deadline:
            time.sleep(0.2)
        streamed = {(e.split('"device":"')[1].split('"')[0], e.split('"time":"')[1][:19]) for e in events}
        assert len(events) == len(rows) and len(streamed) == len(rows)
    finally:
        assert a.stop() == 0, a.output()
        assert b.stop() == 0, b.output()


def _children(pid: int) -> list[int]:
    """The worker processes of a ``mptrack serve --workers N`` (its children running multiprocessing)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid and b"spawn_main" in cmd:
            out.append(int(d.name))
    return out


def _load(url: str, devices: list[str], acked: list, stop: threading.Event, codes: list) -> None:
    k = 0
    with httpx.Client(timeout=10.0) as http:
        while not stop.is_set():
            dev = devices[k % len(devices)]
            step = k // len(devices)
            t, lat, lon = T0 + step, 52.5 + 1e-4 * step, 13.4 + 1e-3 * devices.index(dev)
            try:
                r = http.get(f"{url}/?id={dev}&timestamp={t}&lat={lat!r}&lon={lon!r}&accuracy=5")
            except httpx.HTTPError:
                codes.append(0)
                time.sleep(0.05)
                continue                          # not acknowledged: sent again
            codes.append(r.status_code)
            if r.status_code == 200:
                acked.append((dev, float(t), lat, lon))
                k += 1
            else:
                time.sleep(0.05)


def test_kill_9_of_a_worker_under_load(tmp_path, postgres):
    """--workers 2: one worker killed -9 under load loses nothing acknowledged; the server keeps serving."""
    db = postgres.create_database("kill_worker")
    srv = Server(tmp_path, "--workers", "2", "--rate", "0", db=db).start()
    try:
        deadline = time.monotonic() + 120
        while len(_children(srv.proc.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        workers = _children(srv.proc.pid)
        assert len(workers) == 2, workers
        acked: list = []
        codes: list = []
        stop = threading.Event()
        threads = [threading.Thread(target=_load, args=(srv.url, [f"k{c}-{i}" for i in range(4)], acked, stop, codes))
                   for c in range(6)]
        for th in threads:
            th.start()
        time.sleep(3.0)
        before = len(acked)
        os.kill(workers[0], signal.SIGKILL)
        time.sleep(4.0)
        after_kill = len(acked)
        time.sleep(2.0)
        stop.set()
        for th in threads:
            th.join(60)
        assert before > 50 and len(acked) > after_kill > before, (before, after_kill, len(acked))
        check_acked(db, acked)
        assert srv.get("/healthz").status_code == 200
    finally:
        assert srv.stop() == 0, srv.output()


def test_postgres_restart_under_load(tmp_path):
    """PostgreSQL stopped (as by a crash) and started again under load: 503 while it is down, 200 again
    without restarting the server, nothing acknowledged lost."""
    pg = postgres_or_skip()
    try:
        db = pg.create_database("restart")
        srv = Server(tmp_path, "--rate", "0", db=db).start()
        try:
            acked: list = []
            codes: list = []
            stop = threading.Event()
            threads = [threading.Thread(target=_load, args=(srv.url, [f"r{c}-{i}" for i in range(3)], acked, stop,
                                                           codes)) for c in range(4)]
            for th in threads:
                th.start()
            time.sleep(2.0)
            stopped = len(codes)
            pg.stop("immediate", check=True)
            # a batch on a connection that broke fails at once; one that waits for a new connection fails
            # when the pool gives up (5 s): 503 either way while the database is down
            deadline = time.monotonic() + 15
            while 503 not in codes[stopped:] and time.monotonic() < deadline:
                time.sleep(0.2)
            down = codes[stopped:]
            pg.start()
            n = len(acked)
            deadline = time.monotonic() + 60
            while len(acked) < n + 50 and time.monotonic() < deadline:
                time.sleep(0.2)
            stop.set()
            for th in threads:
                th.join(60)
            assert 503 in down, sorted(set(down))
            assert len(acked) >= n + 50, "the server did not recover after PostgreSQL came back"
            check_acked(db, acked)
            m = _metrics(srv.url)
            assert m['mptrack_requests_refused_total{reason="not_committed"}'] >= 1
            assert srv.get("/healthz").status_code == 200
        finally:
            assert srv.stop() == 0, srv.output()
    finally:
        pg.cleanup()


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mptrack", *args], capture_output=True, text=True, timeout=600,
                          env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})


def test_db_copy_round_trip(tmp_path, postgres):
    """A SQLite installation copied to PostgreSQL and back: every fix, key and state; the server on the
    copy resumes where the original stopped."""
    lite = f"sqlite:///{tmp_path / 'trial.db'}"
    assert _cli("devices", "add", "car-1", "--db", lite).returncode == 0
    assert _cli("keys", "add", "map", "--db", lite).returncode == 0
    srv = Server(tmp_path, "--rate", "0", db=lite).start()
    fixes = _walk(5, 40, seed=3)   # > 30 a device: noise re-estimated, states checkpointed
    try:
        _spray([srv.url], fixes, seed=3, threads=2, repeat=0.2)
        t, lat, lon = fixes["pg-3-0"][10]
        assert srv.get(f"/?id=pg-3-0&timestamp={t + 0.5}&lat={lat!r}&lon={lon!r}").status_code == 200   # late
        before = {d: srv.json(f"/api/devices/{d}/position") for d in fixes}
    finally:
        os.kill(srv.proc.pid, signal.SIGKILL)   # no final checkpoint: the copy must replay
        srv.proc.wait(30)
    pg = postgres.create_database("copied")
    proc = _cli("db", "copy", lite, pg)
    assert proc.returncode == 0, proc.stderr
    assert '"fixes": 201' in proc.stdout and '"devices": 1' in proc.stdout and '"api_keys": 1' in proc.stdout
    again = _cli("db", "copy", lite, pg)
    assert again.returncode == 2 and "not empty" in again.stderr
    # a source file that is not there (a typo) is named, not created and copied as an empty database
    typo = f"sqlite:///{tmp_path / 'mptrak.db'}"
    wrong = _cli("db", "copy", typo, postgres.create_database("typo"))
    assert wrong.returncode == 2 and f"source: {tmp_path / 'mptrak.db'} does not exist" in wrong.stderr, wrong.stderr
    assert not (tmp_path / "mptrak.db").exists()
    srv = Server(tmp_path, "--rate", "0", db=pg).start()
    try:
        for d, pos in before.items():
            got = srv.json(f"/api/devices/{d}/position")
            assert (got["lat"], got["lon"], got["ell_major_m"]) == (pos["lat"], pos["lon"], pos["ell_major_m"])
    finally:
        assert srv.stop() == 0
    back = f"sqlite:///{tmp_path / 'back.db'}"
    proc = _cli("db", "copy", pg, back)
    assert proc.returncode == 0, proc.stderr
    from mptrack.serve._copy import fix_digest
    from mptrack.serve._database import open_store

    digests = []
    for url in (lite, pg, back):
        store = open_store(url)
        try:
            digests.append(fix_digest(store))
        finally:
            store.close()
    assert digests[0] == digests[1] == digests[2]
    assert query(back, "SELECT count(*) FROM devices")[0][0] == 1


def test_schema_is_versioned(postgres):
    from mptrack.serve import _postgres
    from mptrack.serve._database import open_store

    db = postgres.create_database("versioned")
    store = open_store(db)
    store.close()
    assert query(db, "SELECT value FROM meta WHERE key = 'schema_version'") == [(_postgres.SCHEMA_VERSION,)]
    # a database of version 1 (before the cell table) is upgraded when a server opens it
    query(db, "DROP TABLE cells, cell_areas, cell_source")
    query(db, "UPDATE meta SET value = 1 WHERE key = 'schema_version'")
    open_store(db).close()
    assert query(db, "SELECT value FROM meta WHERE key = 'schema_version'") == [(2,)]
    assert query(db, "SELECT count(*) FROM cells") == [(0,)]
    query(db, "UPDATE meta SET value = 99 WHERE key = 'schema_version'")
    with pytest.raises(OutputError, match="schema version 99, newer"):
        open_store(db)
    proc = _cli("db", "upgrade", "--db", db)
    assert proc.returncode == 2 and "newer than this mptrack" in proc.stderr


def test_retention_does_not_block_ingest_and_runs_in_one_process(postgres):
    """A batch of --retain's deletes held open (uncommitted) on a device's old fixes: a batch of new
    fixes of that device still commits at once; a second process's retention meanwhile deletes
    nothing and returns (one process deletes at a time); then everything old goes, the new stays."""
    from mptrack.serve import _postgres
    from mptrack.serve._database import open_store
    from mptrack.serve._store import stored_rows

    db = postgres.create_database("retention")
    a, b = open_store(db), open_store(db)
    try:
        (dev, _), = a.register(["old-and-new"])

        def rows(times):   # (seq: not written) + the stored columns
            return stored_rows([(0, dev, t, 52.5, 13.4, 5.0, None, None, None, None, t, 52.5, 13.4, 1.0, 0.0, 1.0, 0.0,
                                 0.0, 0.0, 0) for t in times])

        with a.batch(np.array([dev]), np.array([0])) as tx:
            tx.write(rows([float(t) for t in range(1000, 1600)]))
        held = a.pool.getconn()
        try:
            held.execute("SELECT pg_advisory_lock(%s, %s)", _postgres._RETENTION_LOCK)
            with held.transaction():
                assert held.execute(_postgres._DELETE_OLD, (1300.0, 10_000)).rowcount == 300   # not committed yet
                done = threading.Event()

                def ingest():
                    with b.batch(np.array([dev]), np.array([0])) as tx:
                        tx.write(rows([2000.0 + k for k in range(10)]))
                    done.set()

                th = threading.Thread(target=ingest, daemon=True)
                th.start()
                assert done.wait(10), "ingest waited for the retention's open delete"
                got: list = []                          # the other process is deleting: this one does not
                other = threading.Thread(target=lambda: got.append(b.delete_before(1500.0)), daemon=True)
                other.start()
                other.join(10)
                assert got == [0], "a second process's retention deleted (or waited) while another was deleting"
            held.execute("SELECT pg_advisory_unlock(%s, %s)", _postgres._RETENTION_LOCK)
        finally:
            a.pool.putconn(held)
        assert b.delete_before(1500.0) == 200
        assert query(db, "SELECT min(t), count(*) FROM fixes") == [(1500.0, 110)]
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("optimistic", [False, True])
def test_small_batches_store_every_value_as_sent(postgres, optimistic):
    """A small batch's fixes go in as numpy arrays in binary (a matrix of the float columns, NaN for NULL):
    each value comes back exactly, a missing one as NULL (NaN), text and flags as they were; a late
    fix is stored once, its exact twin not again -- with the rows locked first or optimistically (one
    statement)."""
    from mptrack.serve._database import open_store
    from mptrack.serve._store import ESTIMATE_COLUMNS, FIX_COLUMNS, StoredRows

    db = postgres.create_database(f"arrays_{int(optimistic)}")
    store = open_store(db)
    try:
        (k0, _), (k1, _) = store.register(["arr-a", "arr-b"])
        rng = np.random.default_rng(7)
        n = 5
        cols = {c: rng.normal(50.0, 20.0, n) for c in FIX_COLUMNS + ESTIMATE_COLUMNS}
        cols["dev"] = np.array([k0, k0, k0, k1, k1], np.int64)
        cols["t"] = T0 + np.arange(n) * 1.5
        cols["speed_mps"][[1, 3]] = np.nan
        cols["attrs"] = np.array(['{"batt":"81"}', None, '{"a":1}', None, None], dtype=object)
        cols["flag"] = np.array([0, 1, 2, 0, 3], np.int64)
        rows = StoredRows(cols)
        late = StoredRows({**cols, "t": cols["t"] - 100.0, "flag": np.full(n, 4, np.int64)})
        devs = np.array([k0, k1], np.int64)
        for again in (False, True):
            with store.batch(devs, np.zeros(2, np.int64), optimistic) as tx:
                tx.write(None if again else rows, late)
            assert tx.stored_late == (0 if again else n)
        for k, dev in ((k0, slice(0, 3)), (k1, slice(3, 5))):
            got = store.fixes(k)
            assert len(got) == 2 * (dev.stop - dev.start)
            new = got["flag"] != 4
            for c in FIX_COLUMNS + ESTIMATE_COLUMNS:
                want, have = cols[c][dev], got[c][new]
                if c == "attrs":
                    assert have.tolist() == want.tolist()
                else:
                    np.testing.assert_array_equal(have, want, err_msg=c)   # exactly: binary, not text
        assert query(db, "SELECT count(*) FROM fixes WHERE speed_mps IS NULL") == [(4,)]   # NULL, not NaN
    finally:
        store.close()


def test_an_optimistic_batch_writes_nothing_when_another_process_changed_a_device(postgres):
    """An optimistic batch (one statement, no lock taken before) whose versions are behind what another
    process stored writes nothing -- no fix, no late fix, no state, no event -- and reports the changed
    states; with the versions stored, it writes everything and its event goes out.  A batch that needs
    COPY locks its rows first and is refused before it writes."""
    import psycopg

    from mptrack.serve._database import open_store
    from mptrack.serve._postgres import CHANNEL
    from mptrack.serve._store import ESTIMATE_COLUMNS, FIX_COLUMNS, StaleStates, StoredRows

    db = postgres.create_database("optimistic")
    store, other = open_store(db), open_store(db)          # two processes
    listener = psycopg.connect(db, autocommit=True)
    listener.execute(f"LISTEN {CHANNEL}")
    try:
        (k0, _), (k1, _) = store.register(["opt-a", "opt-b"])
        devs, held = np.array([k0, k1], np.int64), np.zeros(2, np.int64)
        with other.batch(devs, held) as tx:                 # the other process steps opt-b
            tx.write(states=[(k1, b"theirs", T0)])

        def rows(n, t0):
            cols = {c: np.full(n, 1.0) for c in FIX_COLUMNS + ESTIMATE_COLUMNS}
            cols.update(dev=np.repeat(devs, n // 2), t=t0 + np.arange(n) % (n // 2), attrs=np.full(n, None),
                        flag=np.zeros(n, np.int64))
            return StoredRows(cols)

        mine = [(k0, b"mine-a", T0), (k1, b"mine-b", T0)]
        with pytest.raises(StaleStates) as stale:
            with store.batch(devs, held, optimistic=True) as tx:
                assert tx.stale == []
                tx.write(rows(4, T0), rows(2, T0 - 50), mine, ["opt-a\t{}"])
        assert stale.value.stale == [(k1, 1, b"theirs")]
        assert query(db, "SELECT count(*) FROM fixes") == [(0,)]
        assert query(db, "SELECT dev, version, state FROM device_state ORDER BY dev") == [(k0, 0, None),
                                                                                       (k1, 1, b"theirs")]
        assert list(listener.notifies(timeout=0.5)) == []
        with store.batch(devs, np.array([0, 1], np.int64), optimistic=True) as tx:
            tx.write(rows(4, T0), rows(2, T0 - 50), mine, ["opt-a\t{}"])
        assert tx.stored_late == 2
        assert query(db, "SELECT count(*) FROM fixes") == [(6,)]
        assert query(db, "SELECT dev, version, state FROM device_state ORDER BY dev") == [(k0, 1, b"mine-a"),
                                                                                       (k1, 2, b"mine-b")]
        assert [n.payload for n in listener.notifies(timeout=5, stop_after=1)] == ["opt-a\t{}"]
        with pytest.raises(StaleStates):                    # COPY-sized: locked first, refused before writing
            with store.batch(devs, held, optimistic=True) as tx:
                tx.write(rows(1000, T0 + 10))
        assert query(db, "SELECT count(*) FROM fixes") == [(6,)]
    finally:
        listener.close()
        store.close()
        other.close()


def test_batches_commit_on_the_event_loop_only_while_postgres_is_quick(postgres, monkeypatch):
    """A batch goes on the event loop's thread while the one before committed quickly; after a failed or
    slow one, on the writer thread (the server keeps answering while PostgreSQL is slow or down)."""
    from mptrack.serve import _postgres
    from mptrack.serve._database import open_store

    store = open_store(postgres.create_database("quick"))
    try:
        (k, _), = store.register(["quick-a"])
        devs, versions = np.array([k], np.int64), np.zeros(1, np.int64)
        assert store.quick_commit
        with pytest.raises(ZeroDivisionError):
            with store.batch(devs, versions):
                1 / 0
        assert not store.quick_commit
        with store.batch(devs, versions) as tx:
            tx.write()
        assert store.quick_commit
        monkeypatch.setattr(_postgres, "QUICK_COMMIT_S", 0.0)
        with store.batch(devs, versions) as tx:
            tx.write()
        assert not store.quick_commit
    finally:
        store.close()
