"""The server's storage, behind one small interface (SQLite embedded by default; PostgreSQL for many
workers and hosts is the same interface).

What is stored, every table keyed by device first:

    fixes         every accepted fix as the device sent it, with the live estimate made when it
                  arrived (NULL for a late fix), by device key and time; an exact duplicate
                  (device, time, lat, lon) is stored once
    device_keys   the device ids and their integer keys (the fixes' ``dev``)
    device_state  each device's live filter state as of its last checkpoint (an opaque blob of
                  the online filter) and the last fix row it covers
    devices       registered devices and the SHA-256 of their tokens (``mptrack devices add``)
    api_keys      keys of the query API and the map (``mptrack keys add``)
    meta          the schema version and the checkpoint watermark: every device's fixes up to that
                  row are in its stored state

One writer commits a batch of fixes in one transaction (:meth:`Store.write`); readers run
concurrently.  Replaying the fixes after the watermark that each device's state does not cover yet
through the same filter restores the
live state exactly after a crash (:meth:`Store.replay`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Protocol

import numpy as np


__all__ = ["Store", "StoredRows", "FIX_COLUMNS", "ESTIMATE_COLUMNS", "DEFAULT_DB"]

DEFAULT_DB = "sqlite:///mptrack.db"
#: Columns of a stored fix as the device sent it (the :data:`._fix.FIELDS` minus attrs, plus received).
FIX_COLUMNS = ("dev", "t", "lat", "lon", "accuracy_m", "speed_mps", "heading_deg", "altitude_m", "attrs",
               "received")
#: Columns of the live estimate stored with each fix (flag: an index into :data:`._online.FLAG_NAMES`).
ESTIMATE_COLUMNS = ("est_lat", "est_lon", "var_e", "cov_en", "var_n", "vel_e", "vel_n", "nis", "flag")


@dataclass
class StoredRows:
    """Stored fixes as columns (one NumPy array per column of FIX_COLUMNS + ESTIMATE_COLUMNS, attrs as
    JSON text), plus ``seq`` (the insertion order, never reused)."""

    columns: dict

    def __len__(self) -> int:
        return len(self.columns["t"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]


class Store(Protocol):
    """The storage interface of ``mptrack serve`` (see the module doc)."""

    url: str

    def write(self, rows: list[tuple] = (), late: list[tuple] = (), new_devices: list[tuple[int, str]] = (),
              states: list[tuple[str, bytes]] = (), watermark: int | None = None) -> tuple[int, int]:
        """In one durable transaction: register ``new_devices`` (key, id); insert the fix rows
        (FIX_COLUMNS + ESTIMATE_COLUMNS values) ``rows`` -- fixes later than every stored fix of their
        device, which cannot be duplicates -- and the rows ``late`` that are not exact duplicates of a
        stored fix (device, t, lat, lon); store device ``states`` (id, blob) that cover every fix of
        their device stored so far, this transaction's included; set the watermark (None: the last
        row) when states or a watermark are given.  Returns (how many of ``late`` were stored, the
        last fix row)."""

    def load_checkpoint(self, batch: int = 50_000) -> tuple[int, Iterator[list[tuple[str, bytes, int]]]]:
        """(watermark, the device states (id, blob, upto) in chunks of ``batch``), read from one
        snapshot (consume the chunks before writing)."""

    def replay(self, after: int, batch: int = 50_000) -> Iterator[StoredRows]:
        """The stored fixes after row ``after`` in insertion order, in batches."""

    def last_row(self) -> int:
        """The position of the last stored fix row (0 when none)."""

    def fixes(self, dev: int, t0: float | None = None, t1: float | None = None,
              limit: int | None = None) -> StoredRows:
        """A device's stored fixes with t0 <= t <= t1, in time order."""

    def recent(self, dev: int, n: int) -> StoredRows:
        """A device's last ``n`` stored fixes (by time), in time order."""

    def device_keys(self) -> list[tuple[int, str]]:
        """(key, device id) of every device that has sent a fix."""

    def devices(self) -> list[tuple[str, str]]:
        """(device id, token SHA-256) of the registered devices."""

    def add_device(self, device: str, token_sha256: str) -> None: ...

    def api_keys(self) -> list[str]:
        """The SHA-256 of every API key."""

    def add_api_key(self, name: str, key_sha256: str) -> None: ...

    def delete_before(self, t: float, batch: int = 10_000) -> int:
        """Delete fixes older than ``t`` (seconds since 1970), in batches; returns how many."""

    def count(self) -> int: ...

    def close(self) -> None: ...
