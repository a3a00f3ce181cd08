"""The embedded store: one SQLite file in WAL mode (see :mod:`._store` for what it holds).

A commit is in the database file (its write-ahead log) when it returns, so a fix answered 200
survives a crash or a kill -9 of the server.  SQLite's ``synchronous=NORMAL``, its recommended
setting for WAL, leaves the log's flush to disk to the next checkpoint, so a power loss or an OS
crash may lose the last commits; ``fsync=True`` (``mptrack serve --fsync``) flushes every commit
(``synchronous=FULL``): one fsync per group commit, ~4 ms on this project's machines.

A server's store (``server=True``) holds the database's lock (:func:`mptrack.runs.output_lock`, the file
``.NAME.lock`` beside it) while it is open: a second server of the same file is refused at once, since
each would filter with its own live states and checkpoint over the other's.  Other processes (adding a
device, copying the database) may still open it.

One connection writes (under a lock); each reading thread has its own connection, and WAL lets them
read while the writer writes.  The writer never checkpoints the log into the database file itself
(SQLite's automatic checkpoint would run inside a group commit, every ~1000 pages, copying and syncing
them while the requests of the batch wait): a thread of its own does, with its own connection, every
:data:`CHECKPOINT_S` seconds (a passive checkpoint, which never blocks the writer or the readers), and
once the log has :data:`RESTART_FRAMES` frames it finishes the checkpoint under the writer's lock so that
the log starts again from its beginning (a few milliseconds).
"""

from __future__ import annotations

import contextlib
import sqlite3
import threading
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import OutputError, ParameterError
from ..runs import output_lock
from ._store import (AREA_AGGREGATES, AREA_COLUMNS, CELL_COLUMNS, ESTIMATE_COLUMNS, FIX_COLUMNS, HISTORY_COLUMNS,
                     LATE, StoredRows, split_histories, stored_rows)

__all__ = ["SqliteStore", "SCHEMA_VERSION"]

#: The statements that bring a database of the version before each to it.
_MIGRATIONS = {
    # device states keyed by the device's integer key in a rowid table: a state (~1 kB) overflowed the
    # page of a WITHOUT ROWID table (at most ~1,000 bytes a row there) into a 4 kB page of its own, so
    # 10^6 devices' states took 4.7 GB, all read at every restart; now 1.1 GB
    2: ("CREATE TABLE device_state_v2 (dev INTEGER PRIMARY KEY, state BLOB NOT NULL, upto INTEGER NOT NULL)",
        "INSERT INTO device_state_v2 SELECT k.dev, s.state, s.upto FROM device_state s JOIN device_keys k "
        "USING (device_id) ORDER BY k.dev",
        "DROP TABLE device_state",
        "ALTER TABLE device_state_v2 RENAME TO device_state"),
}
SCHEMA_VERSION = max(_MIGRATIONS)
#: The page cache of the writer's connection (KiB): the (device, time) index pages of the devices reporting.
WRITER_CACHE_KIB = 65536
#: The page cache of each reading thread's connection (KiB): a query's pages (the OS caches the file too);
#: small, as every reading thread has one.
READER_CACHE_KIB = 8192
#: How often the checkpointer moves the write-ahead log into the database file (s).
CHECKPOINT_S = 1.0
#: Frames of the write-ahead log (4 KiB pages) from which the checkpointer makes the log start again
#: (256 MiB).  SQLite starts it again only when a write begins after a complete checkpoint while no reader
#: holds an older snapshot: under sustained ingest a passive checkpoint is never complete when the next
#: batch begins, and the log grew by a page a fix without end (400 MiB in 8 s at 15,000 fixes/s).  Each
#: start costs the batch that begins it an fsync of the log's header (~10 ms here): at 15,000 fixes/s
#: one every ~3 s.
RESTART_FRAMES = 65536
#: The most a restarting checkpoint waits for readers of older snapshots (ms) while the writer waits for it.
RESTART_WAIT_MS = 10
#: The longest a transaction of retention's deletes holds the writer's lock (s).
RETAIN_HOLD_S = 0.005
_ALL = FIX_COLUMNS + ESTIMATE_COLUMNS
#: Retention's delete of one device's old fixes (at most a number), found by the (device, time) index: a
#: probe a device.  (Found by time alone, each round's last batch, which finds nothing, read the whole
#: index under the writer's lock; an index on the time would cost every insert a second B-tree.)
_DELETE_OLD = "DELETE FROM fixes WHERE seq IN (SELECT seq FROM fixes WHERE dev = ? AND t < ? LIMIT ?)"
_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS device_keys (dev INTEGER PRIMARY KEY, device_id TEXT NOT NULL UNIQUE);
CREATE TABLE IF NOT EXISTS fixes (seq INTEGER PRIMARY KEY AUTOINCREMENT,
    dev INTEGER NOT NULL, t REAL NOT NULL, lat REAL NOT NULL, lon REAL NOT NULL, accuracy_m REAL,
    speed_mps REAL, heading_deg REAL, altitude_m REAL, attrs TEXT, received REAL NOT NULL,
    est_lat REAL, est_lon REAL, var_e REAL, cov_en REAL, var_n REAL, vel_e REAL, vel_n REAL, nis REAL,
    flag INTEGER NOT NULL);
CREATE INDEX IF NOT EXISTS fixes_device_time ON fixes (dev, t);
CREATE TABLE IF NOT EXISTS device_state (dev INTEGER PRIMARY KEY, state BLOB NOT NULL, upto INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS devices (device_id TEXT PRIMARY KEY, token_sha256 TEXT NOT NULL UNIQUE,
    created REAL NOT NULL) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS api_keys (name TEXT PRIMARY KEY, key_sha256 TEXT NOT NULL UNIQUE,
    created REAL NOT NULL) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS cells (radio INTEGER NOT NULL, mcc INTEGER NOT NULL, net INTEGER NOT NULL,
    area INTEGER NOT NULL, cell INTEGER NOT NULL, lat REAL NOT NULL, lon REAL NOT NULL, range_m REAL, samples REAL,
    changeable REAL, azimuth_deg REAL, intercept_dbm REAL NOT NULL, slope_db REAL NOT NULL, fit_offset_db REAL,
    score REAL NOT NULL, unit INTEGER, earfcn INTEGER, PRIMARY KEY (mcc, net, area, cell, radio)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS cell_areas (radio INTEGER NOT NULL, mcc INTEGER NOT NULL, net INTEGER NOT NULL,
    area INTEGER NOT NULL, lat REAL NOT NULL, lon REAL NOT NULL, radius_m REAL NOT NULL, cells INTEGER NOT NULL,
    fits INTEGER NOT NULL, offset_db REAL, PRIMARY KEY (radio, mcc, net, area)) WITHOUT ROWID;
INSERT OR IGNORE INTO meta VALUES ('schema_version', {SCHEMA_VERSION});
INSERT OR IGNORE INTO meta VALUES ('watermark', 0);
"""
_INSERT = f"INSERT INTO fixes ({', '.join(_ALL)}) VALUES ({', '.join('?' * len(_ALL))})"
# a late fix is stored unless the same fix (device, time, position) is: the (dev, t) index finds it
_INSERT_NEW = (f"INSERT INTO fixes ({', '.join(_ALL)}) SELECT {', '.join('?' * len(_ALL))} WHERE NOT EXISTS "
               "(SELECT 1 FROM fixes WHERE dev = ?1 AND t = ?2 AND lat = ?3 AND lon = ?4)")
_SELECT = f"SELECT seq, {', '.join(_ALL)} FROM fixes"
_HISTORY = (f"SELECT * FROM (SELECT dev, {', '.join(HISTORY_COLUMNS)} FROM fixes WHERE dev = ? AND flag <> ? "
            "ORDER BY t DESC LIMIT ?) ORDER BY t")
_INSERT_CELL = f"INSERT OR IGNORE INTO cells ({', '.join(CELL_COLUMNS)}) VALUES ({', '.join('?' * len(CELL_COLUMNS))})"
_INSERT_AREA = f"INSERT INTO cell_areas ({', '.join(AREA_COLUMNS)}) VALUES ({', '.join('?' * len(AREA_COLUMNS))})"
#: the most keys one look-up statement takes (more are looked up in several statements)
_KEYS_PER_QUERY = 32


class SqliteStore:
    """The SQLite store at ``sqlite:///PATH`` (created with its schema if absent)."""

    shared = False

    def __init__(self, url: str, fsync: bool = False, server: bool = False, reader: bool = False):
        self.url = url
        self.fsync = bool(fsync)
        self.quick_commit = not self.fsync
        self.path = sqlite_path(url)
        if not str(self.path):
            raise ParameterError(f"db: expected sqlite:///PATH, got {url!r}")
        if self.path.is_dir():
            raise ParameterError(f"db: {self.path} is a directory; give a file, e.g. sqlite:///{self.path}/mptrack.db")
        if not self.path.parent.is_dir():
            home = " (~ is not expanded in a URL: give the whole path)" if str(self.path).startswith("~") else ""
            raise OutputError(f"db: the directory {self.path.parent} does not exist{home}; create it first",
                              path=self.path)
        self._held = contextlib.ExitStack()
        self._local = threading.local()
        self._closed = threading.Event()
        if reader:   # a helper process's store: it reads (no schema written, no writer, no checkpoints)
            self._w = self._checkpointer = None
            self.schema_version = _schema_version(self._reader())
            return
        if server:
            try:
                self._held.enter_context(output_lock(self.path, note="mptrack serve",
                                                     advice="stop that server first, or serve another database"))
            except OutputError as exc:
                raise OutputError(f"db: {exc}", path=self.path) from None
        try:
            self._open()
        except BaseException:
            self._held.close()
            raise

    def _open(self) -> None:
        try:
            self._w = self._connect(WRITER_CACHE_KIB)
            self._w.executescript(_SCHEMA)
        except sqlite3.DatabaseError as exc:
            raise OutputError(f"db: cannot open {self.path} as an mptrack database: {exc}", path=self.path) from None
        version = _schema_version(self._w)
        if version > SCHEMA_VERSION:
            raise OutputError(f"db: {self.path} has schema version {version}, newer than this mptrack's "
                              f"{SCHEMA_VERSION}; upgrade mptrack", path=self.path)
        self._lock = threading.Lock()
        if version < SCHEMA_VERSION:
            with self._transaction() as w:   # read again under the write lock: another process may have upgraded it
                version = _schema_version(w)
                for v in range(version + 1, SCHEMA_VERSION + 1):
                    for sql in _MIGRATIONS[v]:
                        w.execute(sql)
                w.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'", (SCHEMA_VERSION,))
        self.schema_version = SCHEMA_VERSION
        self._w.execute("PRAGMA wal_autocheckpoint=0")   # the checkpointer's job, off the commit path
        self._checkpointer = threading.Thread(target=self._checkpoints, name="mptrack-sqlite-checkpoint",
                                              daemon=True)
        self._checkpointer.start()

    def _checkpoints(self) -> None:
        """The checkpointer thread: a passive checkpoint every CHECKPOINT_S seconds until close, the log
        started again once it has RESTART_FRAMES frames."""
        con = self._connect(READER_CACHE_KIB)
        con.execute(f"PRAGMA busy_timeout={RESTART_WAIT_MS}")
        try:
            while not self._closed.wait(CHECKPOINT_S):
                try:
                    _, frames, _ = con.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
                    if frames >= RESTART_FRAMES:
                        # then, under the writer's lock, the last few frames are copied and the log starts
                        # again from its beginning once the readers of older snapshots are done (1-7 ms here,
                        # two fsyncs included; a reader slower than RESTART_WAIT_MS: the next round)
                        con.execute("PRAGMA wal_checkpoint(PASSIVE)")   # what came meanwhile, still unblocked
                        with self._lock:
                            con.execute("PRAGMA wal_checkpoint(RESTART)")
                except sqlite3.OperationalError:   # busy or locked: the next round does it
                    pass
        finally:
            con.close()

    def _connect(self, cache_kib: int) -> sqlite3.Connection:
        con = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
        con.execute("PRAGMA journal_mode=WAL")
        con.execute(f"PRAGMA synchronous={'FULL' if self.fsync else 'NORMAL'}")
        con.execute("PRAGMA busy_timeout=30000")
        # the log file cut back to 512 MiB once started again (a restart at RESTART_FRAMES never needs it)
        con.execute("PRAGMA journal_size_limit=536870912")
        con.execute(f"PRAGMA cache_size=-{int(cache_kib)}")
        return con

    def _reader(self) -> sqlite3.Connection:
        con = getattr(self._local, "con", None)
        if con is None:
            con = self._local.con = self._connect(READER_CACHE_KIB)
        return con

    # ---- writing (one writer) --------------------------------------------------------------------
    @contextlib.contextmanager
    def _transaction(self):
        """The writer connection in one transaction (the writer's lock held)."""
        with self._lock:
            w = self._w
            w.execute("BEGIN IMMEDIATE")
            try:
                yield w
                w.execute("COMMIT")
            except BaseException:
                w.execute("ROLLBACK")
                raise

    def register(self, devices: list[str]) -> list[tuple[int, str]]:
        with self._transaction() as w:
            w.executemany("INSERT INTO device_keys SELECT (SELECT COALESCE(MAX(dev) + 1, 0) FROM device_keys), ? "
                          "WHERE true ON CONFLICT (device_id) DO NOTHING", [(d,) for d in devices])
        return self.device_keys(devices)

    @contextlib.contextmanager
    def batch(self, devs=None, versions=None, optimistic=False):
        with self._transaction() as w:
            yield _Batch(w)

    def add_device(self, device: str, token_sha256: str) -> None:
        self._insert("INSERT INTO devices VALUES (?, ?, ?)", (device, token_sha256, time.time()), "device", device)

    def add_api_key(self, name: str, key_sha256: str) -> None:
        self._insert("INSERT INTO api_keys VALUES (?, ?, ?)", (name, key_sha256, time.time()), "API key", name)

    def _insert(self, sql: str, values: tuple, what: str, name: str) -> None:
        with self._lock:
            try:
                self._w.execute(sql, values)
            except sqlite3.IntegrityError:
                raise ParameterError(f"name: a {what} named {name!r} exists already") from None

    def add_device_keys(self, keys: list[tuple[int, str]]) -> None:
        with self._transaction() as w:
            w.executemany("INSERT INTO device_keys VALUES (?, ?)", keys)

    def load_fixes(self, rows: StoredRows) -> None:
        with self._transaction() as w:
            w.executemany(f"INSERT INTO fixes ({', '.join(_ALL)}, seq) VALUES ({', '.join('?' * (len(_ALL) + 1))})",
                          rows.records(with_seq=True))

    def credentials(self) -> tuple[list[tuple], list[tuple]]:
        con = self._reader()
        return (con.execute("SELECT device_id, token_sha256, created FROM devices").fetchall(),
                con.execute("SELECT name, key_sha256, created FROM api_keys").fetchall())

    def add_credentials(self, devices: list[tuple], api_keys: list[tuple]) -> None:
        with self._transaction() as w:
            w.executemany("INSERT INTO devices VALUES (?, ?, ?)", devices)
            w.executemany("INSERT INTO api_keys VALUES (?, ?, ?)", api_keys)

    def delete_before(self, t: float, batch: int = 1000) -> int:
        """(see :class:`._store.Store`) Device by device, in transactions of at most ``batch`` fixes or
        RETAIN_HOLD_S seconds under the writer's lock, each followed by a pause as long, so that ingest
        has the lock at least half the time."""
        devices = [d for (d,) in self._reader().execute("SELECT dev FROM device_keys")]
        total, k = 0, 0
        while k < len(devices):
            with self._transaction() as w:
                started, deleted = time.perf_counter(), 0
                while True:   # at least one device a transaction, however long the lock took to get
                    room = batch - deleted
                    n = w.execute(_DELETE_OLD, (devices[k], t, room)).rowcount
                    deleted += n
                    k += n < room          # the device has no more (else the transaction is full)
                    if k == len(devices) or deleted == batch or time.perf_counter() - started >= RETAIN_HOLD_S:
                        break
            total += deleted
            if k < len(devices):
                time.sleep(time.perf_counter() - started)
        return total

    # ---- reading ---------------------------------------------------------------------------------
    def load_checkpoint(self, batch: int = 50_000) -> tuple[int, Iterator[list[tuple[int, bytes, int, int]]]]:
        con = self._reader()
        con.execute("BEGIN")   # the watermark and the states: one snapshot
        watermark = int(con.execute("SELECT value FROM meta WHERE key = 'watermark'").fetchone()[0])

        def chunks():
            try:
                cur = con.execute("SELECT dev, state, upto, 0 FROM device_state")
                while rows := cur.fetchmany(batch):
                    yield rows
            finally:
                con.execute("COMMIT")
                con.execute("PRAGMA shrink_memory")   # a restart reads every state once: not worth a cache

        return watermark, chunks()

    def replay(self, after: int, batch: int = 50_000) -> Iterator[StoredRows]:
        con = self._reader()
        while True:
            rows = con.execute(f"{_SELECT} WHERE seq > ? ORDER BY seq LIMIT ?", (after, batch)).fetchall()
            if not rows:
                return
            out = stored_rows(rows)
            after = int(out["seq"][-1])
            yield out

    def last_row(self) -> int:
        return int(self._reader().execute("SELECT COALESCE(MAX(seq), 0) FROM fixes").fetchone()[0])

    def fixes(self, dev: int, t0: float | None = None, t1: float | None = None,
              limit: int | None = None) -> StoredRows:
        lo = -np.inf if t0 is None else t0
        hi = np.inf if t1 is None else t1
        sql = f"{_SELECT} WHERE dev = ? AND t >= ? AND t <= ? ORDER BY t, lat, lon"
        args: tuple = (int(dev), lo, hi)
        if limit is not None:
            sql += " LIMIT ?"
            args += (int(limit),)
        return stored_rows(self._reader().execute(sql, args).fetchall())

    def histories(self, devs: list[int], n: int) -> list[np.ndarray]:
        con = self._reader()
        return split_histories(devs, [r for d in devs for r in con.execute(_HISTORY, (int(d), LATE, int(n)))])

    def device_keys(self, devices: list[str] | None = None) -> list[tuple[int, str]]:
        con = self._reader()
        if devices is None:
            return con.execute("SELECT dev, device_id FROM device_keys ORDER BY dev").fetchall()
        keys = []
        for i in range(0, len(devices), 500):
            part = devices[i:i + 500]
            keys += con.execute(f"SELECT dev, device_id FROM device_keys WHERE device_id IN ({', '.join('?' * len(part))})",
                                part).fetchall()
        return keys

    def devices(self) -> list[tuple[str, str]]:
        return self._reader().execute("SELECT device_id, token_sha256 FROM devices").fetchall()

    def api_keys(self) -> list[str]:
        return [r[0] for r in self._reader().execute("SELECT key_sha256 FROM api_keys")]

    def count(self) -> int:
        return int(self._reader().execute("SELECT COUNT(*) FROM fixes").fetchone()[0])

    # ---- the cell table ---------------------------------------------------------------------------
    def load_cells(self, chunks, areas, source: str) -> int:
        with self._lock:
            w = self._w
            w.execute("BEGIN IMMEDIATE")
            try:
                w.execute("DELETE FROM cells")
                w.execute("DELETE FROM cell_areas")
                before = w.total_changes
                for rows in chunks:
                    w.executemany(_INSERT_CELL, rows)
                stored = w.total_changes - before
                w.executemany(_INSERT_AREA, areas(w.execute(AREA_AGGREGATES).fetchall()))
                w.execute("INSERT OR REPLACE INTO meta VALUES ('cell_source', ?)", (source,))
                w.execute("COMMIT")
            except BaseException:
                w.execute("ROLLBACK")
                raise
        return stored

    def cell_source(self) -> str | None:
        row = self._reader().execute("SELECT value FROM meta WHERE key = 'cell_source'").fetchone()
        return None if row is None else str(row[0])

    def find_cells(self, keys: list[tuple[int, int, int, int]]) -> list[tuple]:
        return self._find("cells", CELL_COLUMNS, ("mcc", "net", "area", "cell"), keys)

    def find_cell_areas(self, keys: list[tuple[int, int, int, int]]) -> list[tuple]:
        return self._find("cell_areas", AREA_COLUMNS, ("radio", "mcc", "net", "area"), keys)

    def _find(self, table: str, columns: tuple, key: tuple, keys: list) -> list[tuple]:
        con = self._reader()
        out: list[tuple] = []
        one = "(" + " AND ".join(f"{k} = ?" for k in key) + ")"
        for i in range(0, len(keys), _KEYS_PER_QUERY):
            part = keys[i:i + _KEYS_PER_QUERY]
            sql = f"SELECT {', '.join(columns)} FROM {table} WHERE " + " OR ".join([one] * len(part))
            out.extend(con.execute(sql, [int(v) for k in part for v in k]).fetchall())
        return out

    def close(self) -> None:
        if self._closed.is_set():
            return
        self._closed.set()
        if self._w is not None:
            self._checkpointer.join()
            with self._lock:
                # the whole log into the database file and the log emptied, so that the next start reads one
                # file (readers of other threads may keep connections open: closing this one would not do it)
                self._w.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                self._w.close()
        con = getattr(self._local, "con", None)
        if con is not None:
            con.close()
            self._local.con = None
        self._held.close()


def sqlite_path(url: str) -> Path:
    """The file a ``sqlite:///PATH`` URL names."""
    return Path(url[len("sqlite:///"):])


def _schema_version(con: sqlite3.Connection) -> int:
    return int(con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0])


class _Batch:
    """One batch's transaction on the writer connection (the store's lock held)."""

    stale: list = []

    def __init__(self, con: sqlite3.Connection):
        self.con = con
        self.stored_late = 0
        self.last_row = 0

    def write(self, rows: StoredRows | None = None, late: StoredRows | None = None, states=(), events=(),
              watermark: int | None = None) -> None:
        """(see :class:`._store.Batch`; the states are checkpoints in the batch's own transaction)"""
        w = self.con
        if rows is not None and len(rows):
            w.executemany(_INSERT, rows.records())
        before = w.total_changes
        if late is not None and len(late):
            w.executemany(_INSERT_NEW, late.records())
        self.stored_late = w.total_changes - before
        last = self.last_row = w.execute("SELECT COALESCE(MAX(seq), 0) FROM fixes").fetchone()[0]
        if states:
            w.executemany("INSERT OR REPLACE INTO device_state VALUES (?, ?, ?)", [(k, b, last) for k, b, _ in states])
        if states or watermark is not None:
            w.execute("UPDATE meta SET value = ? WHERE key = 'watermark'", (last if watermark is None else int(watermark),))
