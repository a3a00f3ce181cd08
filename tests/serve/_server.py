"""``mptrack serve`` as a real process on a free loopback port, for the server tests."""

from __future__ import annotations

import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pandas as pd

from mptrack.serve._store import ESTIMATE_COLUMNS, FIX_COLUMNS

ALL = FIX_COLUMNS + ESTIMATE_COLUMNS

SRC = Path(__file__).resolve().parents[2] / "src"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """A running ``mptrack serve --db URL --port P ARGS`` (started by :meth:`start`); the database
    ``db`` is a URL (default: sqlite:///TMP/mptrack.db)."""

    def __init__(self, tmp: Path, *args: str, db: str | None = None):
        self.tmp = tmp
        self.db = db or f"sqlite:///{tmp / 'mptrack.db'}"
        self.args = args
        self.port = free_port()
        self.proc: subprocess.Popen | None = None
        self.log = tmp / f"serve-{self.port}.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 120.0) -> "Server":
        env = dict(os.environ, PYTHONPATH=str(SRC), PYTHONUNBUFFERED="1")
        cmd = [sys.executable, "-m", "mptrack", "serve", "--port", str(self.port), "--db", self.db, *self.args]
        self._log = open(self.log, "ab")
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env, cwd=self.tmp)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mptrack serve exited with {self.proc.returncode}:\n{self.output()}")
            try:
                if httpx.get(f"{self.url}/healthz", timeout=1.0).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        self.kill()
        raise RuntimeError(f"mptrack serve did not become ready in {timeout} s:\n{self.output()}")

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def get(self, path: str, **kw) -> httpx.Response:
        return httpx.get(self.url + path, timeout=kw.pop("timeout", 60.0), **kw)

    def post(self, path: str, **kw) -> httpx.Response:
        return httpx.post(self.url + path, timeout=kw.pop("timeout", 60.0), **kw)

    def json(self, path: str, **kw):
        r = self.get(path, **kw)
        assert r.status_code == 200, (r.status_code, r.text)
        return r.json()

    def stop(self, timeout: float = 30.0) -> int:
        """SIGTERM and wait: the exit status."""
        if self.proc is None or self.proc.poll() is not None:
            return self.proc.returncode if self.proc else 0
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        finally:
            self._log.close()

    def kill(self) -> None:
        """kill -9."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(30)
            self._log.close()


def query(db: str, sql: str, params: tuple = ()) -> list[tuple]:
    """Rows of ``sql`` (with ? placeholders) on the database at URL ``db`` (SQLite or PostgreSQL)."""
    if db.startswith("sqlite:///"):
        con = sqlite3.connect(db[len("sqlite:///"):])
        try:
            return con.execute(sql, params).fetchall()
        finally:
            con.close()
    import psycopg

    with psycopg.connect(db, autocommit=True) as con:
        cur = con.execute(sql.replace("?", "%s"), params)
        return cur.fetchall() if cur.description else []


def stored(db: str, device: str | None = None) -> pd.DataFrame:
    """The stored fixes (every column) with their device ids, of one device or all."""
    cols = ["device_id", "seq", *ALL]
    sql = f"SELECT k.device_id, f.seq, {', '.join('f.' + c for c in ALL)} FROM fixes f JOIN device_keys k ON k.dev = f.dev"
    rows = query(db, sql + (" WHERE k.device_id = ?" if device else ""), (device,) if device else ())
    return pd.DataFrame(rows, columns=cols).astype({c: float for c in ALL if c not in ("dev", "attrs", "flag")})


def check_acked(db: str, acked: list) -> None:
    """Every acknowledged fix (device, t, lat, lon) is stored, and no fix is stored twice."""
    rows = stored(db)
    count: dict = {}
    for r in zip(rows["device_id"], rows["t"], rows["lat"], rows["lon"]):
        count[r] = count.get(r, 0) + 1
    missing = [x for x in acked if count.get(x, 0) == 0]
    twice = [r for r, n in count.items() if n > 1]
    assert not missing, f"{len(missing)} acknowledged fixes lost, e.g. {missing[:3]}"
    assert not twice, f"stored more than once: {twice[:3]}"


def error_of(r: httpx.Response) -> dict:
    """The JSON error body of a 4xx answer (asserting its shape)."""
    assert 400 <= r.status_code < 500, (r.status_code, r.text)
    body = json.loads(r.text)
    assert set(body) == {"error"} and {"code", "message"} <= set(body["error"]), body
    return body["error"]
