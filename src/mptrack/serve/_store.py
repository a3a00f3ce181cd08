"""The server's storage, behind one small interface: SQLite embedded by default (one server process;
:mod:`._sqlite`), PostgreSQL for many processes and hosts on one database (:mod:`._postgres`).

What is stored, every table keyed by device first:

    fixes         every accepted fix as the device sent it, with the live estimate made when it
                  arrived (NULL for a late fix), by device key and time; an exact duplicate
                  (device, time, lat, lon) is stored once
    device_keys   the device ids and their integer keys (the fixes' ``dev``)
    device_state  each device's live filter state (an opaque blob of the online filter): in SQLite
                  as of its last checkpoint with the last fix row it covers; in PostgreSQL the
                  current state with a version, written with every batch
    devices       registered devices and the SHA-256 of their tokens (``mptrack devices add``)
    api_keys      keys of the query API and the map (``mptrack keys add``)
    meta          the schema version (SQLite: and the checkpoint watermark: every device's fixes up
                  to that row are in its stored state)
    cells         the cell table of cell geolocation (CELL_COLUMNS), keyed by (mcc, net, area, cell, radio)
    cell_areas    its location areas (AREA_COLUMNS), keyed by (radio, mcc, net, area)

A batch of fixes is committed in one transaction (:meth:`Store.batch`, :meth:`Batch.write`), with
the device states it stores: so a 200 means the fixes and those states are committed together.  A
store that is not ``shared`` has one writer, which stores a device's state some seconds after it
changed (incremental checkpoints, a few with each batch) and the watermark; replaying the fixes
after the watermark that each device's state does not cover restores the live state exactly after a
crash (:meth:`Store.replay`).  A ``shared`` store has writers in many processes: a batch locks its
devices' state rows (in sorted order), gets the states another process wrote since, and writes the
new states of every device it stepped with the fixes; its states are always current, there is
nothing to replay.  Ingest's batches are optimistic there: the fixes are filtered with the states
this process holds, and one statement locks the rows, writes only if no state changed meanwhile and
reports those that did (:class:`StaleStates`); the batch is then filtered again from them and
written the locking way.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Callable, Iterator, Protocol

import numpy as np

from ..tracking import FLAGS

__all__ = ["Store", "Batch", "StaleStates", "StoredRows", "stored_rows", "FIX_COLUMNS", "ESTIMATE_COLUMNS",
           "CELL_COLUMNS", "AREA_COLUMNS", "AREA_AGGREGATES", "DEFAULT_DB", "first_line", "split_histories",
           "FLAG_NAMES", "LATE", "HISTORY_COLUMNS"]

DEFAULT_DB = "sqlite:///mptrack.db"
#: Names of the stored ``flag`` values: the tracking engine's flags, then "late" (stored, not filtered).
FLAG_NAMES = tuple(FLAGS) + ("late",)
LATE = len(FLAGS)
#: The columns of a device's filtered history (:meth:`Store.histories`), what its noise is estimated from.
HISTORY_COLUMNS = ("t", "lat", "lon", "accuracy_m")
#: History rows converted to an array in one call: the noise estimates read histories on their own thread,
#: and one call holds the interpreter lock (~0.2 us a row) while ingest on the event loop waits for it.
HISTORY_PIECE = 4096
#: Columns of a stored fix as the device sent it (the :data:`._fix.FIELDS` minus attrs, plus received).
FIX_COLUMNS = ("dev", "t", "lat", "lon", "accuracy_m", "speed_mps", "heading_deg", "altitude_m", "attrs",
               "received")
#: Columns of the live estimate stored with each fix (flag: an index into :data:`._online.FLAG_NAMES`).
ESTIMATE_COLUMNS = ("est_lat", "est_lon", "var_e", "cov_en", "var_n", "vel_e", "vel_n", "nis", "flag")
#: Columns of a stored cell (serve/_celltable.py): its key, position, what the table says of it, and its
#: path-loss model (radio: a code of mptrack.cellular.RADIOS; NULL where unknown).
CELL_COLUMNS = ("radio", "mcc", "net", "area", "cell", "lat", "lon", "range_m", "samples", "changeable",
                "azimuth_deg", "intercept_dbm", "slope_db", "fit_offset_db", "score", "unit", "earfcn")
#: Columns of a stored location area: its centre and radius (m), its cells, and their fits' count and mean.
AREA_COLUMNS = ("radio", "mcc", "net", "area", "lat", "lon", "radius_m", "cells", "fits", "offset_db")
#: What each location area's row is made of, computed over the stored cells (plain SQL, every store's):
#: its key, cell count, mean position, bounding box, and how many cells have a fit and their mean offset.
AREA_AGGREGATES = ("SELECT radio, mcc, net, area, COUNT(*), AVG(lat), AVG(lon), MIN(lat), MAX(lat), MIN(lon), "
                   "MAX(lon), COUNT(fit_offset_db), AVG(fit_offset_db) FROM cells GROUP BY radio, mcc, net, area")


@dataclass
class StoredRows:
    """Stored fixes as columns (one NumPy array per column of FIX_COLUMNS + ESTIMATE_COLUMNS, attrs as
    JSON text), plus ``seq`` (the insertion order, never reused)."""

    columns: dict

    def __len__(self) -> int:
        return len(self.columns["t"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def records(self, with_seq: bool = False) -> list[tuple]:
        """The rows as tuples of FIX_COLUMNS + ESTIMATE_COLUMNS (+ seq) values, None for NULL."""
        return list(zip(*self.lists(_ALL + (("seq",) if with_seq else ()))))

    def lists(self, names) -> list[list]:
        """The columns ``names`` as lists of Python values, None for NULL (NaN)."""
        return [_nullable(self.columns[n]) for n in names]


def _nullable(values: np.ndarray) -> list:
    """``values`` as a list, NaN as None if they are floats (a server's batch has whole columns of
    either: the fields a client does not send, the estimates)."""
    if values.dtype.kind != "f":
        return values.tolist()
    nan = values != values
    if not nan.any():
        return values.tolist()
    if nan.all():
        return [None] * len(values)
    return [None if m else x for x, m in zip(values.tolist(), nan.tolist())]


_ALL = FIX_COLUMNS + ESTIMATE_COLUMNS
_TEXT = {"attrs"}
_INT = {"seq", "flag", "dev"}


def stored_rows(rows: list[tuple]) -> StoredRows:
    """StoredRows from rows of (seq,) + FIX_COLUMNS + ESTIMATE_COLUMNS values."""
    names = ("seq",) + _ALL
    if not rows:
        return StoredRows({n: np.empty(0, dtype=object if n in _TEXT else np.int64 if n in _INT else float)
                           for n in names})
    out = {}
    for n, values in zip(names, zip(*rows)):
        if n in _TEXT:
            out[n] = np.array(values, dtype=object)
        elif n in _INT:
            out[n] = np.array(values, dtype=np.int64)
        else:
            out[n] = np.array([np.nan if v is None else v for v in values], dtype=float)
    return StoredRows(out)


def split_histories(devs: list[int], rows: list[tuple]) -> list[np.ndarray]:
    """The devices' histories (:meth:`Store.histories`) from rows (dev,) + HISTORY_COLUMNS, each device's
    together and in time order."""
    k = len(HISTORY_COLUMNS)
    values = np.empty((len(rows), 1 + k))
    for i in range(0, len(rows), HISTORY_PIECE):   # pieces: the interpreter lock is let go between them
        values[i:i + HISTORY_PIECE] = np.array(rows[i:i + HISTORY_PIECE], dtype=float).reshape(-1, 1 + k)
    dev = values[:, 0].astype(np.int64)
    cuts = np.flatnonzero(dev[1:] != dev[:-1]) + 1
    found = {int(part[0, 0]): part[:, 1:] for part in np.split(values, cuts) if len(part)}
    return [found.get(int(d), np.empty((0, k))) for d in devs]


def first_line(exc: BaseException) -> str:
    """The first line of what an error (a database driver's, most often) says, for a log line or a
    one-line message; its type's name when it says nothing."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


class StaleStates(Exception):
    """An optimistic batch (:meth:`Store.batch`) wrote nothing: other processes changed these states
    (``stale``: (dev, version, state blob or None)) since the versions it was given."""

    def __init__(self, stale: list[tuple[int, int, bytes | None]]):
        super().__init__(f"{len(stale)} device states changed by another process")
        self.stale = stale


class Batch(Protocol):
    """One batch's transaction (:meth:`Store.batch`)."""

    #: (dev, version, state blob or None) of the batch's devices whose stored state is not the version
    #: this process has (a shared store; empty otherwise)
    stale: list[tuple[int, int, bytes | None]]

    #: how many of the ``late`` rows were stored (not duplicates), once the transaction committed
    stored_late: int
    #: a store with one writer: the last fix row, this transaction's included
    last_row: int

    def write(self, rows: StoredRows | None = None, late: StoredRows | None = None,
              states: list[tuple[int, bytes, float]] = (), events: list[str] = (),
              watermark: int | None = None) -> None:
        """(Once per batch.) Insert the fix rows (columns FIX_COLUMNS + ESTIMATE_COLUMNS) ``rows`` -- fixes later than every
        stored fix of their device, which cannot be duplicates -- and the rows ``late`` that are not exact
        duplicates of a stored fix (device, t, lat, lon); store device ``states`` (key, blob, time of
        the last fix) that cover every fix of their device stored so far, this transaction's included
        (a shared store: as the devices' current states).  A store with one writer also sets the
        watermark (None: the last row) when states or a watermark are given; a shared store sends
        ``events`` to the stream when the transaction commits."""


class Store(Protocol):
    """The storage interface of ``mptrack serve`` (see the module doc)."""

    url: str
    #: several processes write (PostgreSQL): states travel with every batch, see the module doc
    shared: bool
    #: a batch's commit is quick now (SQLite without fsync: its log is written to the OS, a few hundred
    #: microseconds of CPU; PostgreSQL while its last batch committed within 20 ms): the group
    #: commit runs it on the event loop's own thread rather than handing it to a writer thread
    #: (docs/design.md, "group commit")
    quick_commit: bool
    #: the version of the database's schema
    schema_version: int

    def register(self, devices: list[str]) -> list[tuple[int, str]]:
        """(key, id) of these device ids, registering (and committing) the new ones."""

    def batch(self, devs: np.ndarray, versions: np.ndarray,
              optimistic: bool = False) -> contextlib.AbstractContextManager[Batch]:
        """A durable transaction for a batch of the devices ``devs`` (sorted keys), committed when the
        context exits without an exception, rolled back otherwise.  A shared store locks the devices'
        rows first (in sorted order) and reports the states whose version is not in ``versions``;
        ``optimistic``: it reports none, and the commit (or a write that needs the rows locked first)
        raises :class:`StaleStates`, having written nothing, if some version is not in ``versions``."""

    def load_checkpoint(self, batch: int = 50_000) -> tuple[int, Iterator[list[tuple[int, bytes, int, int]]]]:
        """(watermark, the device states (key, blob, upto, version) in chunks of ``batch``), read from
        one snapshot (consume the chunks before writing)."""

    def states(self, devs: np.ndarray | None, versions: np.ndarray) -> list[tuple[int, int, bytes]]:
        """A shared store: (dev, version, blob) of the devices (all when None) whose stored state is
        newer than ``versions[dev]``."""

    def streaming(self) -> bool:
        """A shared store: whether some process has stream clients (batches then send events)."""

    def subscribe(self, deliver: Callable[[str], None]) -> None:
        """A shared store: ``deliver(payload)`` every committed batch's events, from any process."""

    def replay(self, after: int, batch: int = 50_000) -> Iterator[StoredRows]:
        """The stored fixes after row ``after`` in insertion order, in batches."""

    def last_row(self) -> int:
        """The position of the last stored fix row (0 when none)."""

    def fixes(self, dev: int, t0: float | None = None, t1: float | None = None,
              limit: int | None = None) -> StoredRows:
        """A device's stored fixes with t0 <= t <= t1, in time order."""

    def histories(self, devs: list[int], n: int) -> list[np.ndarray]:
        """Each device's last ``n`` fixes that went through the live filter (not late), in time order: a
        float array (rows, HISTORY_COLUMNS) a device, NaN where a value is missing."""

    def device_keys(self, devices: list[str] | None = None) -> list[tuple[int, str]]:
        """(key, device id) of every device that has sent a fix (of these ``devices`` only, if given)."""

    def devices(self) -> list[tuple[str, str]]:
        """(device id, token SHA-256) of the registered devices."""

    def add_device(self, device: str, token_sha256: str) -> None: ...

    def api_keys(self) -> list[str]:
        """The SHA-256 of every API key."""

    def add_api_key(self, name: str, key_sha256: str) -> None: ...

    def credentials(self) -> tuple[list[tuple], list[tuple]]:
        """(devices (id, token SHA-256, created), API keys (name, key SHA-256, created)), to copy them."""

    def add_credentials(self, devices: list[tuple], api_keys: list[tuple]) -> None: ...

    def add_device_keys(self, keys: list[tuple[int, str]]) -> None:
        """Register devices with given keys (copying a database)."""

    def load_fixes(self, rows: StoredRows) -> None:
        """Insert stored rows as they are, their ``seq`` included (copying a database)."""

    def delete_before(self, t: float, batch: int = ...) -> int:
        """Delete fixes older than ``t`` (seconds since 1970), in transactions of at most ``batch`` fixes
        (each store has its own default: they must not stall its ingest); returns how many."""

    def count(self) -> int: ...

    def live_devices(self, since: float) -> int:
        """A shared store: how many devices have a fix at or after ``since`` (s since 1970)."""

    def load_cells(self, chunks: Iterator[list[tuple]], areas: Callable[[list[tuple]], list[tuple]],
                   source: str) -> int:
        """In one transaction: replace the cell table by the rows (CELL_COLUMNS) of ``chunks`` (a cell listed
        twice is stored once, the first), the areas by the rows (AREA_COLUMNS) that ``areas`` makes of the
        stored cells' AREA_AGGREGATES, and record ``source`` (what was loaded).  Returns how many cells were
        stored."""

    def cell_source(self) -> str | None:
        """The ``source`` of the loaded cell table (None: none loaded)."""

    def find_cells(self, keys: list[tuple[int, int, int, int]]) -> list[tuple]:
        """The stored cells (CELL_COLUMNS) whose (mcc, net, area, cell) is one of ``keys`` (any radio)."""

    def find_cell_areas(self, keys: list[tuple[int, int, int, int]]) -> list[tuple]:
        """The stored areas (AREA_COLUMNS) whose (radio, mcc, net, area) is one of ``keys``."""

    def close(self) -> None: ...
