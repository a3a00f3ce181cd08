"""Benchmark suite of the live server (``mptrack bench --suite serve``).

Every server runs as its own process (uvicorn with uvloop and httptools, no access log) on a free
loopback port, and the load generator (``wrk``, Debian's package) runs on the same machine, as a
small deployment would.  Each figure is set beside an anchor measured in the same run:

* single-fix OsmAnd requests (random devices among 10^4, each request a new fix) against a bare ASGI
  callable that answers 200 on the same server stack: the floor of the HTTP stack;
* p99 latency at about half of the maximum rate (wrk's per-request delay);
* bulk NDJSON (``POST /api/fixes``) against inserting the same rows into SQLite with ``executemany``
  in one process (the storage floor);
* the resident memory of a server holding N devices' live state, and its restart time (process
  start to ``/healthz``), N = 10^6 (10^5 with --quick).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from . import register_suite

__all__ = ["serve_suite"]

_WRK = shutil.which("wrk")
_OSMAND_LUA = """
local n = 0
math.randomseed(%(seed)d)
request = function()
  n = n + 1
  local path = string.format("/?id=dev%%d&timestamp=%%d&lat=%%.6f&lon=%%.6f&accuracy=8", math.random(0, %(devices)d - 1),
                             %(t0)d + n, 52.5 + math.random() * 0.01, 13.4 + math.random() * 0.01)
  return wrk.format("GET", path)
end
%(delay)s
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Process:
    """A server process on a free port, ready when ``path`` answers 200."""

    def __init__(self, args: list[str], cwd: Path, ready: str = "/healthz", timeout: float = 300.0):
        import httpx

        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        started = time.perf_counter()
        self.proc = subprocess.Popen([sys.executable, "-m", *args, "--port", str(self.port)], cwd=cwd,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while True:
            try:
                if httpx.get(self.url + ready, timeout=1.0).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if self.proc.poll() is not None or time.perf_counter() - started > timeout:
                self.stop()
                raise RuntimeError(f"{' '.join(args)} did not start")
            time.sleep(0.05)
        self.ready_s = time.perf_counter() - started

    def rss_mib(self) -> float:
        status = Path(f"/proc/{self.proc.pid}/status").read_text()
        return int(re.search(r"VmRSS:\s+(\d+)", status).group(1)) / 1024.0

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def _wrk(url: str, seconds: int, tmp: Path, *, devices: int = 10_000, delay_ms: float | None = None,
         connections: int = 64, seed: int = 1) -> dict:
    """requests/s and latency percentiles (ms) of wrk with the OsmAnd script (or a plain GET)."""
    cmd = [_WRK, "-t1", f"-c{connections}", f"-d{seconds}s", "--latency"]
    if devices:
        script = tmp / f"osmand-{seed}.lua"
        delay = f"delay = function() return {delay_ms:.3f} end" if delay_ms else ""
        script.write_text(_OSMAND_LUA % {"seed": seed, "devices": devices, "t0": int(time.time()) - 86000,
                                          "delay": delay})
        cmd += ["-s", str(script)]
    out = subprocess.run(cmd + [url + "/"], capture_output=True, text=True, check=True).stdout
    res = {"rps": float(re.search(r"Requests/sec:\s+([\d.]+)", out).group(1))}
    for p in ("50", "99"):
        m = re.search(rf"\s{p}%\s+([\d.]+)(us|ms|s)\b", out)
        res[f"p{p}"] = float(m.group(1)) * {"us": 1e-3, "ms": 1.0, "s": 1e3}[m.group(2)]
    errors = re.search(r"Non-2xx or 3xx responses:\s+(\d+)", out)
    res["errors"] = int(errors.group(1)) if errors else 0
    return res


def _ndjson(devices: int, per_device: int, t0: int, start: int) -> bytes:
    rng = np.random.default_rng(start)
    lines = []
    for k in range(per_device):
        for d in range(devices):
            lines.append(json.dumps({"track_id": f"bulk{d}", "time": t0 + start + k, "lat": 48.1 + 1e-3 * rng.random(),
                                     "lon": 11.6 + 1e-3 * rng.random(), "accuracy_m": 5.0}))
    return ("\n".join(lines) + "\n").encode()


def _bulk(url: str, bodies: list[bytes], clients: int) -> float:
    """Seconds to post ``bodies`` from ``clients`` threads (each body NDJSON)."""
    import httpx

    queue = list(bodies)
    lock = threading.Lock()

    def work():
        with httpx.Client(timeout=300.0) as http:
            while True:
                with lock:
                    if not queue:
                        return
                    body = queue.pop()
                r = http.post(url + "/api/fixes", content=body, headers={"Content-Type": "application/x-ndjson"})
                r.raise_for_status()

    threads = [threading.Thread(target=work) for _ in range(clients)]
    start = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return time.perf_counter() - start


def _sqlite_floor(rows: int, tmp: Path) -> float:
    """Rows/s of inserting fix-sized rows with executemany into an indexed SQLite table (WAL)."""
    con = sqlite3.connect(tmp / "floor.db", isolation_level=None)
    con.execute("PRAGMA journal_mode=WAL")
    con.execute("PRAGMA synchronous=NORMAL")
    con.execute("CREATE TABLE f (dev INTEGER, t REAL, lat REAL, lon REAL, acc REAL, a REAL, b REAL, c REAL, d TEXT, "
                "r REAL, e1 REAL, e2 REAL, e3 REAL, e4 REAL, e5 REAL, e6 REAL, e7 REAL, e8 REAL, e9 INTEGER)")
    con.execute("CREATE INDEX fi ON f (dev, t)")
    data = [(i % 1000, 1.7e9 + i, 48.1, 11.6, 5.0, None, None, None, None, 1.7e9, 48.1, 11.6, 1.0, 0.0, 1.0, 0.0, 0.0,
             1.0, 0) for i in range(rows)]
    start = time.perf_counter()
    for i in range(0, rows, 5000):
        con.execute("BEGIN")
        con.executemany("INSERT INTO f VALUES (" + ",".join("?" * 19) + ")", data[i:i + 5000])
        con.execute("COMMIT")
    seconds = time.perf_counter() - start
    con.close()
    return rows / seconds


@register_suite("serve")
def serve_suite(quick: bool) -> dict:
    rows, notes = [], []
    load = os.getloadavg()[0]
    seconds = 5 if quick else 10
    many = 100_000 if quick else 1_000_000
    with tempfile.TemporaryDirectory(prefix="mptrack-bench-serve-") as tmp:
        tmp = Path(tmp)
        if _WRK is None:
            notes.append("wrk is not installed (Debian package wrk): the HTTP rows were not measured")
        else:
            bare = _Process(["uvicorn", "mptrack.bench._asgi_floor:app", "--loop", "uvloop", "--http", "httptools",
                             "--no-access-log", "--log-level", "warning"], tmp, ready="/")
            try:
                _wrk(bare.url, 2, tmp, devices=0)
                floor = _wrk(bare.url, seconds, tmp, devices=0)
            finally:
                bare.stop()
            server = _Process(["mptrack", "serve", "-q", "--db", f"sqlite:///{tmp / 'osmand.db'}", "--rate", "0"], tmp)
            try:
                _wrk(server.url, 2, tmp, seed=2)
                full = _wrk(server.url, seconds, tmp, seed=3)
                delay = max(0.0, 1000.0 * 64 / (full["rps"] / 2.0) - full["p50"])
                half = _wrk(server.url, seconds, tmp, seed=4, delay_ms=delay)
            finally:
                server.stop()
            rows.append(["bare ASGI route (floor)", floor["rps"], floor["p50"], floor["p99"], 1.0])
            rows.append(["OsmAnd GET, 10^4 devices, committed", full["rps"], full["p50"], full["p99"],
                         full["rps"] / floor["rps"]])
            rows.append(["  the same at about half that rate", half["rps"], half["p50"], half["p99"],
                         half["rps"] / floor["rps"]])
            if full["errors"] or half["errors"]:
                notes.append(f"non-200 answers: {full['errors']} at full rate, {half['errors']} at half")
            server = _Process(["mptrack", "serve", "-q", "--fsync", "--db", f"sqlite:///{tmp / 'fsync.db'}", "--rate",
                               "0"], tmp)
            try:
                fsync = _wrk(server.url, seconds, tmp, seed=5)
            finally:
                server.stop()
            rows.append(["OsmAnd GET, --fsync (each commit flushed)", fsync["rps"], fsync["p50"], fsync["p99"],
                         fsync["rps"] / floor["rps"]])
        # bulk NDJSON
        devices, per = (1000, 5) if quick else (2000, 10)
        bodies = [_ndjson(devices, per, int(time.time()) - 80000, 100 * b) for b in range(4 if quick else 20)]
        fixes = devices * per * len(bodies)
        server = _Process(["mptrack", "serve", "-q", "--db", f"sqlite:///{tmp / 'bulk.db'}", "--max-body",
                           str(64 << 20)], tmp)
        try:
            _bulk(server.url, [_ndjson(100, 5, int(time.time()) - 90000, 0)], 1)
            bulk_s = _bulk(server.url, bodies, 2)
        finally:
            server.stop()
        floor_rows = _sqlite_floor(min(fixes, 200_000), tmp)
        rows.append([f"bulk NDJSON, {devices * per:,} fixes a request", fixes / bulk_s, None, None,
                     fixes / bulk_s / floor_rows])
        notes.append(f"bulk x floor: over SQLite executemany of the same number of fix-sized rows into an indexed WAL "
                     f"table in one process ({floor_rows:,.0f} rows/s here)")
        # memory and restart with many devices
        db = tmp / "many.db"
        server = _Process(["mptrack", "serve", "-q", "--db", f"sqlite:///{db}", "--max-body", str(256 << 20),
                           "--rate", "0"], tmp)
        try:
            base = server.rss_mib()
            chunk = 50_000
            for start in range(0, many, chunk):
                body = "\n".join(json.dumps({"track_id": f"m{d}", "time": 1765000000 + d % 7, "lat": 45.0 + d * 1e-6,
                                             "lon": 9.0}) for d in range(start, min(many, start + chunk))).encode()
                _bulk(server.url, [body], 1)
            held = server.rss_mib()
        finally:
            server.stop()
        restart = _Process(["mptrack", "serve", "-q", "--db", f"sqlite:///{db}"], tmp)
        try:
            restart_rss = restart.rss_mib()
        finally:
            restart.stop()
        rows.append([f"{many:,} devices: resident memory (MiB)", held, None, None, (held - base) / many * 2 ** 20])
        rows.append([f"{many:,} devices: restart to ready (s)", restart.ready_s, None, None, restart_rss])
        notes.append("memory row: x floor = bytes per device (resident memory growth over the empty server); restart "
                     "row: x floor = the restarted server's resident memory (MiB)")
    notes.append(f"load average before the run: {load:.2f} on {os.cpu_count()} cores (timings are meaningless above "
                 f"0.5); wrk -t1 -c64 on the same machine")
    notes.append("goals (issue 31): OsmAnd >= 20,000 fixes/s and >= 0.4x the bare route, p99 <= 20 ms at half the "
                 "rate; bulk >= 200,000 fixes/s; 10^6 devices <= 1 GB, restart <= 10 s")
    return {"suite": "serve", "title": "mptrack serve on loopback (fixes/s; latency ms)",
            "columns": ["case", "fixes/s", "p50 ms", "p99 ms", "x floor"], "rows": rows, "notes": notes}
