"""Benchmark suite of the live server (``mptrack bench --suite serve``).

Every server runs as its own process (uvicorn with uvloop and httptools, no access log) on a free
loopback port, and the load generator (``wrk``, Debian's package) runs on the same machine, as a
small deployment would.  Each figure is set beside an anchor measured in the same run:

* single-fix OsmAnd requests (random devices among 10^4, each request a new fix; every device has
  reported once before, as a fleet's have) against a bare ASGI callable that answers 200 on the same
  server stack: the floor of the HTTP stack;
* p99 latency at about half of the maximum rate (wrk's per-request delay);
* bulk NDJSON (``POST /api/fixes``) against inserting the same rows into SQLite with ``executemany``
  in one process (the storage floor);
* the resident memory of a server holding N devices' live state, and its restart time (process
  start to ``/healthz``), N = 10^6 (10^5 with --quick);
* cell geolocation: ``POST /v1/geolocate`` requests of 3-7 cells each (scans of a simulated 37-site LTE
  network, :func:`mptrack.sim.simulate_network`, with its crowd-sourced table as ``--cells``) against
  the same bare route.

With ``--db postgresql://...`` the suite measures the scale-out instead, on that database (in schemas
of its own, dropped afterwards): OsmAnd GETs with ``--workers 1`` and ``--workers 2`` in the same run,
and to two single-worker servers each sent half the devices (routing by device), with the CPU-seconds
of all the server's processes per acknowledged fix -- two workers both with the one worker's 64
connections in all and with 64 each (on cores of their own each would be as busy as one alone); p99
at about half the rate;
bulk NDJSON (bodies posted in order by two clients, as a gateway replays) against PostgreSQL's binary
COPY of the same rows from one process (the storage floor).
"""

from __future__ import annotations

import contextlib
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
  local path = string.format("/?id=dev%%d&timestamp=%%.0f&lat=%%.6f&lon=%%.6f&accuracy=8",
                             %(first)d + math.random(0, %(devices)d - 1),
                             %(t0)d + n, 52.5 + math.random() * 0.01, 13.4 + math.random() * 0.01)
  return wrk.format("GET", path)
end
%(delay)s
"""
_GEOLOCATE_LUA = """
local bodies = {%(bodies)s}
local n = 0
wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"
request = function()
  n = n + 1
  return wrk.format(nil, "/v1/geolocate", nil, bodies[(n %% #bodies) + 1])
end
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

    def helpers_mib(self) -> float:
        """The proportional set size of the server's child processes (its noise estimates'), MiB."""
        total = 0
        for child in Path(f"/proc/{self.proc.pid}/task/{self.proc.pid}/children").read_text().split():
            with contextlib.suppress(OSError):
                total += int(re.search(r"Pss:\s+(\d+)", Path(f"/proc/{child}/smaps_rollup").read_text()).group(1))
        return total / 1024.0

    def settled_rss_mib(self, most_s: float = 10.0) -> float:
        """The resident memory once the work in flight is done (two readings 1 s apart within 1 MiB)."""
        last, until = self.rss_mib(), time.monotonic() + most_s
        while time.monotonic() < until:
            time.sleep(1.0)
            now = self.rss_mib()
            if abs(now - last) < 1.0:
                break
            last = now
        return now

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def _wrk(url: str, seconds: int, tmp: Path, *, devices: int = 10_000, delay_ms: float | None = None,
         connections: int = 64, seed: int = 1, script: Path | None = None, first: int = 0) -> dict:
    """requests/s and latency percentiles (ms) of wrk with the OsmAnd script (devices ``first`` ..
    ``first + devices - 1``), ``script``, or a plain GET."""
    cmd = [_WRK, "-t1", f"-c{connections}", f"-d{seconds}s", "--latency"]
    if script is not None:
        cmd += ["-s", str(script)]
    elif devices:
        script = tmp / f"osmand-{seed}-{first}.lua"
        delay = f"delay = function() return {delay_ms:.3f} end" if delay_ms else ""
        # epoch milliseconds, 1 ms a request, each seed 1000 s after the one before: one server's runs (seeds
        # in increasing order) send every device's fixes in time order, ~10 s apart with 10^4 devices
        t0 = int(time.time() * 1000) - 86_000_000 + seed * 1_000_000
        script.write_text(_OSMAND_LUA % {"seed": seed, "devices": devices, "first": first, "t0": t0,
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


def _geolocate_setup(tmp: Path, requests: int = 2000, seed: int = 7) -> tuple[Path, Path]:
    """(cell table CSV, wrk script): a simulated 37-site LTE network's crowd-sourced table and ``requests``
    geolocate bodies of phones at random places in it, each with its 3-7 strongest cells (the strongest first)."""
    from ..sim import network_scans, simulate_network

    rng = np.random.default_rng(seed)
    table, net = simulate_network(rng, rings=3, crowd=4000)
    cells = tmp / "cells.csv"
    table.to_csv(cells, index=False)
    scans = network_scans(net, rng.uniform(-2500, 2500, 3 * requests), rng.uniform(-2500, 2500, 3 * requests), rng)
    scans = scans[scans.cell.isin(set(table.cell))]
    bodies = []
    for _, scan in scans.groupby("scan"):
        scan = scan.head(int(rng.integers(3, 8)))  # the 3-7 strongest (phones report a varying number)
        if len(scan) >= 3:
            bodies.append(json.dumps({"considerIp": False, "cellTowers": [
                {"radioType": "lte", "mobileCountryCode": int(r.mcc), "mobileNetworkCode": int(r.mnc),
                 "locationAreaCode": int(r.area), "cellId": int(r.cell), "signalStrength": int(r.rss_dbm)}
                for r in scan.itertuples()]}))
        if len(bodies) == requests:
            break
    script = tmp / "geolocate.lua"
    script.write_text(_GEOLOCATE_LUA % {"bodies": ",\n".join(f"[[{b}]]" for b in bodies)})
    return cells, script


def _ndjson(devices: int, per_device: int, t0: int, start: int) -> bytes:
    rng = np.random.default_rng(start)
    lines = []
    for k in range(per_device):
        for d in range(devices):
            lines.append(json.dumps({"track_id": f"bulk{d}", "time": t0 + start + k, "lat": 48.1 + 1e-3 * rng.random(),
                                     "lon": 11.6 + 1e-3 * rng.random(), "accuracy_m": 5.0}))
    return ("\n".join(lines) + "\n").encode()


def _known_devices(url: str, devices: int = 10_000) -> None:
    """Every device of the OsmAnd rows reports once before they are timed (one bulk request): the rows
    measure a fleet whose devices the server knows (registering a new device is a transaction of its own)."""
    import httpx

    t = int(time.time()) - 87000
    body = "\n".join(json.dumps({"track_id": f"dev{d}", "time": t, "lat": 52.5, "lon": 13.4}) for d in range(devices))
    httpx.post(url + "/api/fixes", content=body, headers={"Content-Type": "application/x-ndjson"},
               timeout=300.0).raise_for_status()


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
                    body = queue.pop(0)   # in order, as a gateway replays (two clients interleave some)
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


def _cpu_s(pid: int) -> float:
    """CPU-seconds (user + system) of a process and of its children that are alive."""
    return _proc_cpu_s(lambda p, name, parent: p == pid or parent == pid)


def _postgres_cpu_s() -> float:
    """CPU-seconds of every PostgreSQL server process on this machine (a local database's share)."""
    return _proc_cpu_s(lambda p, name, parent: name == "postgres")


def _proc_cpu_s(chosen) -> float:
    """CPU-seconds (user + system) of the live processes for which ``chosen(pid, name, parent pid)``."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            head, tail = (d / "stat").read_text().rsplit(")", 1)
        except OSError:
            continue
        stat = tail.split()
        if chosen(int(d.name), head.split("(", 1)[1], int(stat[1])):
            total += (int(stat[11]) + int(stat[12])) / tick
    return total


def _schemas(url: str, n: int) -> tuple[list[str], callable]:
    """URLs of ``n`` new schemas of the database at ``url`` (the search path set in each), and a function
    that drops them."""
    import psycopg

    names = [f"mptrack_bench_{os.getpid()}_{i}" for i in range(n)]
    with psycopg.connect(url, autocommit=True) as con:
        for name in names:
            con.execute(f"DROP SCHEMA IF EXISTS {name} CASCADE")
            con.execute(f"CREATE SCHEMA {name}")
    sep = "&" if "?" in url else "?"

    def drop():
        with psycopg.connect(url, autocommit=True) as con:
            for name in names:
                con.execute(f"DROP SCHEMA IF EXISTS {name} CASCADE")

    return [f"{url}{sep}options=-csearch_path%3D{name}" for name in names], drop


def _copy_floor(url: str, rows: int) -> float:
    """Rows/s of COPY of fix-sized rows into an indexed PostgreSQL table from one process."""
    import psycopg

    data = [(i % 1000, 1.7e9 + i, 48.1, 11.6, 5.0, None, None, None, None, 1.7e9, 48.1, 11.6, 1.0, 0.0, 1.0, 0.0, 0.0,
             1.0, 0) for i in range(rows)]
    with psycopg.connect(url, autocommit=True) as con:
        con.execute("CREATE TABLE f (dev bigint, t float8, lat float8, lon float8, acc float8, a float8, b float8, "
                    "c float8, d text, r float8, e1 float8, e2 float8, e3 float8, e4 float8, e5 float8, e6 float8, "
                    "e7 float8, e8 float8, e9 smallint, seq bigint GENERATED BY DEFAULT AS IDENTITY)")
        con.execute("CREATE INDEX fi ON f (dev, t)")
        start = time.perf_counter()
        for i in range(0, rows, 5000):
            with con.transaction(), con.cursor() as cur, cur.copy("COPY f (dev, t, lat, lon, acc, a, b, c, d, r, e1, e2, "
                                                                 "e3, e4, e5, e6, e7, e8, e9) FROM STDIN (FORMAT BINARY)") as cp:
                cp.set_types(["bigint"] + ["float8"] * 7 + ["text"] + ["float8"] * 9 + ["smallint"])
                for r in data[i:i + 5000]:
                    cp.write_row(r)
        return rows / (time.perf_counter() - start)


def _postgres_suite(db: str, quick: bool, load: float) -> dict:
    rows, notes = [], []
    seconds = 5 if quick else 10
    urls, drop = _schemas(db, 6)
    try:
        with tempfile.TemporaryDirectory(prefix="mptrack-bench-serve-") as tmp:
            tmp = Path(tmp)
            if _WRK is None:
                notes.append("wrk is not installed (Debian package wrk): the HTTP rows were not measured")
            else:
                # 64 connections in all, then 64 a worker: on this machine's shared cores a group commit is
                # as large as the requests waiting on its worker, so splitting one load over two workers halves
                # their groups; with N cores of their own each worker would be as busy as one alone
                by_load = {}
                for workers, url in ((1, urls[0]), (2, urls[1])):
                    server = _Process(["mptrack", "serve", "-q", "--db", url, "--rate", "0", "--workers",
                                       str(workers)], tmp)
                    try:
                        time.sleep(3.0 * workers)            # every worker ready (each compiles or loads its kernels)
                        _known_devices(server.url)
                        _wrk(server.url, 2, tmp, seed=2)
                        for connections in (64,) if workers == 1 else (64, 128):
                            cpu0, pg0 = _cpu_s(server.proc.pid), _postgres_cpu_s()
                            full = _wrk(server.url, seconds, tmp, seed=3, connections=connections)
                            cpu, pg = _cpu_s(server.proc.pid) - cpu0, _postgres_cpu_s() - pg0
                            by_load[workers, connections] = (full, cpu / (full["rps"] * seconds))
                            notes.append(f"--workers {workers}, {connections} connections: PostgreSQL's processes on "
                                         f"this machine used {1e6 * pg / (full['rps'] * seconds):.0f} CPU-microseconds "
                                         "per acknowledged fix")
                            rows.append([f"OsmAnd GET on PostgreSQL, --workers {workers}, {connections} connections",
                                         full["rps"], full["p50"], full["p99"], 1e6 * cpu / (full["rps"] * seconds)])
                        if workers == 2:
                            rate = by_load[2, 64][0]
                            delay = max(0.0, 1000.0 * 64 / (rate["rps"] / 2.0) - rate["p50"])
                            half = _wrk(server.url, seconds, tmp, seed=4, delay_ms=delay)
                            rows.append(["  --workers 2 at about half its rate (64 connections)", half["rps"],
                                         half["p50"], half["p99"], None])
                    finally:
                        server.stop()
                f1, c1 = by_load[1, 64]
                for connections, what in ((64, "the same 64 connections"), (128, "64 connections a worker")):
                    f2, c2 = by_load[2, connections]
                    notes.append(f"--workers 2 vs 1, {what}: throughput x{f2['rps'] / f1['rps']:.2f}, server "
                                 f"CPU-seconds per acknowledged fix x{c2 / c1:.2f} (goal: >= 0.95 and <= 1.15)")
                for connections, what in ((32, "32 connections each"), (64, "64 connections each")):
                    routed, cr = _routed(urls[4 if connections == 32 else 5], seconds, tmp, connections)
                    rows.append([f"OsmAnd GET on PostgreSQL, 2 servers routed by device, {what}", routed["rps"],
                                 routed["p50"], routed["p99"], 1e6 * cr])
                    notes.append(f"routed by device (two single-worker servers on one database, each sent half the "
                                 f"devices by a wrk of its own, {what}) vs --workers 1: throughput "
                                 f"x{routed['rps'] / f1['rps']:.2f}, server CPU-seconds per acknowledged fix "
                                 f"x{cr / c1:.2f}")
                notes.append("OsmAnd rows: x floor = server CPU-microseconds per acknowledged fix (all its processes)")
            devices, per = (1000, 5) if quick else (2000, 10)
            bodies = [_ndjson(devices, per, int(time.time()) - 80000, 100 * b) for b in range(4 if quick else 20)]
            fixes = devices * per * len(bodies)
            server = _Process(["mptrack", "serve", "-q", "--db", urls[2], "--max-body", str(64 << 20), "--rate", "0"],
                              tmp)
            try:
                _bulk(server.url, [_ndjson(100, 5, int(time.time()) - 90000, 0)], 1)
                bulk_s = _bulk(server.url, bodies, 2)
            finally:
                server.stop()
            floor = _copy_floor(urls[3], min(fixes, 200_000))
            rows.append([f"bulk NDJSON into PostgreSQL, {devices * per:,} fixes a request", fixes / bulk_s, None, None,
                         fixes / bulk_s / floor])
            notes.append(f"bulk x floor: over COPY of the same number of fix-sized rows into an indexed table from one "
                         f"process ({floor:,.0f} rows/s here)")
    finally:
        drop()
    notes.append(_load_note(load, "PostgreSQL, wrk (one thread, 64 or 128 connections) and the server share the machine"))
    notes.append("goals (issue 33): --workers 2 within 1.15x the CPU per fix of --workers 1 and >= 0.95x its throughput; "
                 "bulk >= 100,000 fixes/s; p99 <= 50 ms at half the rate")
    return {"suite": "serve", "title": "mptrack serve on PostgreSQL, loopback (fixes/s; latency ms)",
            "columns": ["case", "fixes/s", "p50 ms", "p99 ms", "x floor"], "rows": rows, "notes": notes}


def _routed(url: str, seconds: int, tmp: Path, connections: int) -> tuple[dict, float]:
    """(wrk's figures summed, server CPU-seconds per acknowledged fix) of two single-worker servers on one
    database, each sent its half of the devices (what nginx's ``hash $arg_id`` gives) over ``connections``."""
    servers = [_Process(["mptrack", "serve", "-q", "--db", url, "--rate", "0"], tmp) for _ in range(2)]
    try:
        _known_devices(servers[0].url)

        def both(secs: int, seed: int) -> list[dict]:
            out: list = [None, None]

            def run(i: int) -> None:
                out[i] = _wrk(servers[i].url, secs, tmp, devices=5000, first=5000 * i, connections=connections,
                              seed=seed)

            threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            return out

        both(2, 2)
        cpu0 = sum(_cpu_s(s.proc.pid) for s in servers)
        runs = both(seconds, 3)
        cpu = sum(_cpu_s(s.proc.pid) for s in servers) - cpu0
    finally:
        for s in servers:
            s.stop()
    rps = sum(r["rps"] for r in runs)
    return ({"rps": rps, "p50": max(r["p50"] for r in runs), "p99": max(r["p99"] for r in runs)},
            cpu / (rps * seconds))


def _load_note(load: float, sharing: str) -> str:
    return (f"load average before the run: {load:.2f} on {os.cpu_count()} cores (timings are meaningless above 0.5); "
            + sharing)


@register_suite("serve")
def serve_suite(quick: bool, db: str | None = None) -> dict:
    load = os.getloadavg()[0]
    if db is not None:
        if not db.startswith(("postgresql://", "postgres://")):
            from ..errors import ParameterError

            raise ParameterError(f"db: the serve suite measures PostgreSQL (postgresql://...), got {db!r}")
        return _postgres_suite(db, quick, load)
    rows, notes = [], []
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
                _known_devices(server.url)
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
                _known_devices(server.url)
                fsync = _wrk(server.url, seconds, tmp, seed=5)
            finally:
                server.stop()
            rows.append(["OsmAnd GET, --fsync (each commit flushed)", fsync["rps"], fsync["p50"], fsync["p99"],
                         fsync["rps"] / floor["rps"]])
            cells, script = _geolocate_setup(tmp)
            server = _Process(["mptrack", "serve", "-q", "--db", f"sqlite:///{tmp / 'cells.db'}", "--cells",
                               str(cells)], tmp)
            try:
                _wrk(server.url, 2, tmp, script=script)
                geo = _wrk(server.url, seconds, tmp, script=script)
            finally:
                server.stop()
            rows.append(["POST /v1/geolocate, 3-7 cells a request", geo["rps"], geo["p50"], geo["p99"],
                         geo["rps"] / floor["rps"]])
            if geo["errors"]:
                notes.append(f"geolocate: {geo['errors']} non-200 answers")
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
            just_after, held = server.rss_mib(), server.settled_rss_mib()
            helpers = server.helpers_mib()
        finally:
            server.stop()
        restart = _Process(["mptrack", "serve", "-q", "--db", f"sqlite:///{db}"], tmp)
        try:
            restart_rss = restart.rss_mib()
        finally:
            restart.stop()
        rows.append([f"{many:,} devices: resident memory, settled (MiB)", held, None, None,
                     (held - base) / many * 2 ** 20])
        rows.append([f"{many:,} devices: the same right after the last upload (MiB)", just_after, None, None,
                     (just_after - base) / many * 2 ** 20])
        rows.append([f"{many:,} devices: the server's noise-estimates process beside it (MiB, proportional set size)",
                     helpers, None, None, None])
        rows.append([f"{many:,} devices: restart to ready (s)", restart.ready_s, None, None, restart_rss])
        notes.append("memory rows: x floor = bytes per device (resident memory growth over the empty server); "
                     "settled: once two readings 1 s apart agree within 1 MiB (at most 10 s: the last upload's "
                     "noise estimates and freed buffers); restart row: x floor = the restarted server's resident "
                     "memory (MiB)")
    notes.append(_load_note(load, "wrk -t1 -c64 on the same machine"))
    notes.append("goals (issue 31): OsmAnd >= 20,000 fixes/s and >= 0.4x the bare route, p99 <= 20 ms at half the "
                 "rate; bulk >= 200,000 fixes/s; 10^6 devices <= 1 GB, restart <= 10 s; (issue 32) geolocate >= 8,000 "
                 "requests/s (its fixes/s column counts requests)")
    return {"suite": "serve", "title": "mptrack serve on loopback (fixes/s; latency ms)",
            "columns": ["case", "fixes/s", "p50 ms", "p99 ms", "x floor"], "rows": rows, "notes": notes}
