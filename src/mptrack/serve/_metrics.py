"""What the server counts, for ``/metrics`` (Prometheus text format) and ``/api/stats``.

Each process counts in its own row of numbers, so that nothing is locked on the hot path; the worker
processes of one ``mptrack serve --workers N`` share one file of rows (a memory map, one row per
worker, claimed by process id; a restarted worker takes over the row of the one that died and goes
on from its counts), and any of them answers ``/metrics`` with the sums: a scrape of the host's
port sees the whole host.  Several hosts are several scrape targets.
"""

from __future__ import annotations

import fcntl
import mmap
import os
from bisect import bisect_left
from pathlib import Path

import numpy as np

__all__ = ["Metrics", "METRICS_ENV", "create_metrics_file"]

#: The environment variable naming the shared file of the worker processes.
METRICS_ENV = "MPTRACK_METRICS_FILE"
_COUNTERS = ("accepted", "filtered", "late", "duplicates", "ahead", "batches", "commit_failures", "commit_retries")
#: Reasons a request is refused (RequestError codes, 503 "not_committed"); others count as "other".
REASONS = ("missing_field", "invalid_field", "malformed_json", "malformed_body", "incomplete_body", "body_too_large",
           "unsupported_media_type", "unauthorized", "forbidden", "rate_limited", "not_found", "encrypted",
           "wrong_endpoint", "not_committed", "other")
#: Upper bounds of the latency histogram's buckets (s) and of the batch-size histogram's (fixes).
LATENCY_S = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0)
BATCH_FIXES = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 50000)


def _layout() -> tuple[dict, int]:
    at, pos = {}, 0
    for name in _COUNTERS:
        at[name] = pos
        pos += 1
    for code in REASONS:
        at["refused:" + code] = pos
        pos += 1
    for name, bounds in (("latency", LATENCY_S), ("batch", BATCH_FIXES)):
        at[name] = pos              # buckets (+Inf last), then sum and count
        pos += len(bounds) + 3
    return at, pos


_AT, WIDTH = _layout()
_HEAD = 8   # bytes per slot of the owners' table (a process id)


def create_metrics_file(path: Path, slots: int) -> None:
    """The shared file of ``slots`` workers' counts, all zero."""
    with open(path, "wb") as f:
        f.write(b"\0" * (slots * (_HEAD + 8 * WIDTH)))


class Metrics:
    """This process's counts (a row) and the sums over every process sharing them."""

    def __init__(self, rows: np.ndarray, slot: int = 0):
        self.rows = rows
        self.row = rows[slot]

    @classmethod
    def local(cls) -> "Metrics":
        return cls(np.zeros((1, WIDTH)))

    @classmethod
    def from_environment(cls) -> "Metrics":
        """The worker's row of the file in $MPTRACK_METRICS_FILE, or a row of its own without one."""
        path = os.environ.get(METRICS_ENV)
        return cls.local() if not path else cls.attach(Path(path))

    @classmethod
    def attach(cls, path: Path) -> "Metrics":
        """Claim a row of the shared file: a free one, or one whose process is gone."""
        with open(path, "r+b") as f:
            size = os.fstat(f.fileno()).st_size
            slots = size // (_HEAD + 8 * WIDTH)
            buf = mmap.mmap(f.fileno(), size)
            fcntl.flock(f, fcntl.LOCK_EX)
            try:
                owners = np.frombuffer(buf, dtype=np.int64, count=slots)
                slot = next((i for i in range(slots) if not _alive(int(owners[i]))), None)
                if slot is None:
                    raise RuntimeError(f"{path}: no free row for another worker")  # pragma: no cover
                owners[slot] = os.getpid()
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)
        rows = np.frombuffer(buf, dtype=np.float64, offset=slots * _HEAD).reshape(slots, WIDTH)
        return cls(rows, slot)

    # ---- counting (this process's row) ----------------------------------------------------------
    def add(self, name: str, n: float = 1) -> None:
        self.row[_AT[name]] += n

    def refuse(self, code: str) -> None:
        self.row[_AT.get("refused:" + code, _AT["refused:other"])] += 1

    def observe(self, name: str, value: float) -> None:
        """One value into histogram ``name`` ("latency" in s, "batch" in fixes)."""
        bounds = LATENCY_S if name == "latency" else BATCH_FIXES
        at = _AT[name]
        row = self.row
        row[at + bisect_left(bounds, value)] += 1
        row[at + len(bounds) + 1] += value
        row[at + len(bounds) + 2] += 1

    # ---- reading (the sums over every process) ---------------------------------------------------------
    def totals(self) -> dict:
        """The counters summed over the processes: accepted, filtered, late, duplicates, ahead, batches,
        commit_failures, commit_retries, and refused (reason -> count, the reasons seen)."""
        s = self.rows.sum(axis=0)
        out = {name: int(s[_AT[name]]) for name in _COUNTERS}
        out["refused"] = {code: int(s[_AT["refused:" + code]]) for code in REASONS if s[_AT["refused:" + code]]}
        return out

    def prometheus(self, gauges: dict[str, tuple[str, float]]) -> str:
        """The Prometheus text exposition (format 0.0.4) of the sums, with ``gauges`` (name -> (help, value))."""
        s = self.rows.sum(axis=0)
        out = []

        def metric(name, kind, text):
            out.append(f"# HELP mptrack_{name} {text}\n# TYPE mptrack_{name} {kind}")

        metric("fixes_accepted_total", "counter", "Fixes answered 200 (committed).")
        out.append(f"mptrack_fixes_accepted_total {_n(s[_AT['accepted']])}")
        metric("fixes_total", "counter", "Accepted fixes by how they were stored: filtered (through the live filter), "
                                         "late (stored with history only), duplicate (not stored again).")
        for kind, name in (("filtered", "filtered"), ("late", "late"), ("duplicate", "duplicates")):
            out.append(f'mptrack_fixes_total{{kind="{kind}"}} {_n(s[_AT[name]])}')
        metric("fixes_ahead_total", "counter", "Late fixes that were so for their time: ahead of the server's clock "
                                              "and of their device's clock so far (kept out of the live filter).")
        out.append(f"mptrack_fixes_ahead_total {_n(s[_AT['ahead']])}")
        metric("requests_refused_total", "counter", "Ingest requests refused, by reason (not_committed: 503, the "
                                                    "database could not commit).")
        for code in REASONS:
            out.append(f'mptrack_requests_refused_total{{reason="{code}"}} {_n(s[_AT["refused:" + code]])}')
        metric("commits_total", "counter", "Group commits (batches) written.")
        out.append(f"mptrack_commits_total {_n(s[_AT['batches']])}")
        metric("commit_failures_total", "counter", "Group commits that failed (every request of the batch got 503).")
        out.append(f"mptrack_commit_failures_total {_n(s[_AT['commit_failures']])}")
        metric("commit_retries_total", "counter", "Group commits filtered again because another worker had changed "
                                                  "one of their devices meanwhile (PostgreSQL; none with routing by "
                                                  "device).")
        out.append(f"mptrack_commit_retries_total {_n(s[_AT['commit_retries']])}")
        for name, bounds, key, text in (
                ("ingest_request_seconds", LATENCY_S, "latency", "Ingest request latency, from the request to the "
                                                                 "answer (s)."),
                ("commit_batch_fixes", BATCH_FIXES, "batch", "Fixes per group commit.")):
            metric(name, "histogram", text)
            at, cum = _AT[key], 0.0
            for i, b in enumerate(list(bounds) + ["+Inf"]):
                cum += s[at + i]
                out.append(f'mptrack_{name}_bucket{{le="{b}"}} {_n(cum)}')
            out.append(f"mptrack_{name}_sum {_n(s[at + len(bounds) + 1])}")
            out.append(f"mptrack_{name}_count {_n(s[at + len(bounds) + 2])}")
        for name, (text, value) in gauges.items():
            metric(name, "gauge", text)
            out.append(f"mptrack_{name} {_n(value)}")
        return "\n".join(out) + "\n"


def _n(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover
        return True
    return True
