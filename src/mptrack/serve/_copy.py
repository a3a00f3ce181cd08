"""``mptrack db copy``: a server database copied into another, e.g. a trial installation's SQLite file
into PostgreSQL, losing nothing.

Into an empty target: the device keys, the registered devices and API keys (their digests), every
stored fix as it is (its row number, estimates and flags included), and each device's current live
state -- the source's checkpoint with the fixes stored after it replayed through the filter, as a
restart of the server would, so the target's server resumes exactly where the source's stopped.
Then both are read back: the counts of fixes, devices and keys and a SHA-256 of every fix (all its
columns, with its device id, in row order) must be equal, or the copy fails.
"""

from __future__ import annotations

import hashlib

import numpy as np

from .._core.finiteness import renamed
from ..errors import OutputError, ParameterError
from ..tracking import MODELS, LiveTracks, TrackOptions
from ._database import check_url, open_store
from ._sqlite import sqlite_path
from ._ingest import Ingest
from ._store import ESTIMATE_COLUMNS, FIX_COLUMNS, Store

__all__ = ["copy_database", "fix_digest"]


def copy_database(source: str, target: str, *, model: str | None = None) -> dict:
    """Copy a server database into an empty one, losing nothing (see the module doc).

    Parameters
    ----------
    source, target : str
        Database URLs (``sqlite:///PATH`` or ``postgresql://...``); ``target`` must be empty.
    model : str, optional
        The live filter's motion model (by default the one the stored states were made with, else cv).

    Returns
    -------
    dict
        What was copied: fixes, devices, device_keys, api_keys, states, and the fixes' sha256.

    Raises
    ------
    ParameterError
        ``target`` is ``source``, or a SQLite ``source`` does not exist.
    OutputError
        ``target`` is not empty, the copy stopped, or the copy's counts or checksum differ.
    """
    if source == target:
        raise ParameterError(f"target: the target is the source ({source})")
    with renamed(db="source"):
        if check_url(source) == "sqlite" and not sqlite_path(source).is_file():   # opening it would create it
            raise ParameterError(f"db: {sqlite_path(source)} does not exist (give the database file of the server "
                                 "to copy)")
        src = open_store(source)
    try:
        with renamed(db="target"):
            dst = open_store(target)
        try:
            return _copy(src, dst, model)
        finally:
            dst.close()
    finally:
        src.close()


def _copy(src: Store, dst: Store, model: str | None) -> dict:
    if dst.count() or dst.device_keys() or any(dst.credentials()):
        raise OutputError(f"target: {dst.url} is not empty; mptrack db copy writes only into an empty database")
    keys = src.device_keys()
    devices, api_keys = src.credentials()
    live = LiveTracks(TrackOptions(model=model or _model_of(src)))
    ingest = Ingest(src, live)
    ingest.recover()   # the current states: the checkpoint and the fixes after it, replayed
    try:
        dst.add_device_keys(keys)
        dst.add_credentials(devices, api_keys)
        last = 0
        for rows in src.replay(0):
            dst.load_fixes(rows)
            last = max(last, int(rows["seq"].max()))
        t_last = live.last_fixes(np.arange(live.n))[:, 0]
        started = np.flatnonzero(np.isfinite(t_last))
        started = started[ingest.devices.known(started)]
        states = list(zip(started.tolist(), live.states_bytes(started), t_last[started].tolist()))
        for i in range(0, len(states), 10_000):   # each covers every fix copied
            part = states[i:i + 10_000]
            keys = np.array([k for k, _, _ in part], dtype=np.int64)
            with dst.batch(keys, np.zeros(len(keys), np.int64)) as tx:
                tx.write(states=part, watermark=last)
    except Exception as exc:
        raise OutputError(f"target: the copy into {dst.url} stopped ({exc}); it is incomplete: empty it (or drop "
                          "and create the database) and copy again") from exc
    got = {"fixes": (src.count(), dst.count()), "device_keys": (len(keys), len(dst.device_keys())),
           "devices": (len(devices), len(dst.credentials()[0])), "api_keys": (len(api_keys), len(dst.credentials()[1])),
           "sha256": (fix_digest(src), fix_digest(dst))}
    differ = {k: v for k, v in got.items() if v[0] != v[1]}
    if differ:
        raise OutputError(f"target: the copy in {dst.url} differs from the source: "
                          + ", ".join(f"{k} {a} vs {b}" for k, (a, b) in differ.items()))
    return {k: v[0] for k, v in got.items()} | {"states": len(states)}


def fix_digest(store: Store) -> str:
    """SHA-256 of every stored fix (device id, row number and every column) in row order."""
    ids = dict(store.device_keys())
    h = hashlib.sha256()
    for rows in store.replay(0):
        cols = [rows[n].tolist() for n in ("seq",) + FIX_COLUMNS + ESTIMATE_COLUMNS]
        for r in zip(*cols):
            h.update(repr((ids.get(r[1]),) + tuple(None if v != v else v for v in r)).encode())
    return h.hexdigest()


def _model_of(store: Store) -> str:
    """The motion model of the stored states (cv when there are none)."""
    _, chunks = store.load_checkpoint(batch=1)
    try:
        first = next(chunks, None)
    finally:
        chunks.close()
    if not first:
        return "cv"
    blob = first[0][1]
    for name in MODELS:
        try:
            probe = LiveTracks(TrackOptions(model=name))
            probe.add(1)
            probe.load_states([0], [blob])
            return name
        except ParameterError:
            continue
    raise OutputError(f"source: {store.url} holds live states of no motion model this mptrack knows")
