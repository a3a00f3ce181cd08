"""The SQLite database's schema is versioned: an older one is upgraded, with what it holds, when a
server opens it, and a newer one is refused by name."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from mptrack.errors import OutputError
from mptrack.serve._database import open_store
from mptrack.serve._sqlite import SCHEMA_VERSION


def _version(path) -> int:
    with sqlite3.connect(path) as con:
        return int(con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0])


def test_a_version_1_database_is_upgraded_with_its_device_states(tmp_path):
    path = tmp_path / "old.db"
    store = open_store(f"sqlite:///{path}")
    keys = store.register(["a", "b"])
    states = {device: bytes([k + 1]) * 1100 for k, device in keys}   # as large as a live state
    with store.batch(np.array([0, 1]), np.zeros(2, np.int64)) as tx:
        tx.write(states=[(k, states[device], np.nan) for k, device in keys])
    store.close()
    # version 1 kept the states by device id in a WITHOUT ROWID table
    con = sqlite3.connect(path)
    con.executescript("""
        CREATE TABLE v1 (device_id TEXT PRIMARY KEY, state BLOB NOT NULL, upto INTEGER NOT NULL) WITHOUT ROWID;
        INSERT INTO v1 SELECT k.device_id, s.state, s.upto FROM device_state s JOIN device_keys k USING (dev);
        DROP TABLE device_state;
        ALTER TABLE v1 RENAME TO device_state;
        UPDATE meta SET value = 1 WHERE key = 'schema_version';""")
    con.close()
    store = open_store(f"sqlite:///{path}")
    try:
        assert store.schema_version == SCHEMA_VERSION == _version(path) == 2
        _, chunks = store.load_checkpoint()
        device = dict(keys)
        assert {device[k]: blob for chunk in chunks for k, blob, _, _ in chunk} == states
    finally:
        store.close()


def test_a_newer_database_is_refused_by_name(tmp_path):
    path = tmp_path / "new.db"
    open_store(f"sqlite:///{path}").close()
    with sqlite3.connect(path) as con:
        con.execute("UPDATE meta SET value = 99 WHERE key = 'schema_version'")
    with pytest.raises(OutputError, match="schema version 99, newer"):
        open_store(f"sqlite:///{path}")
