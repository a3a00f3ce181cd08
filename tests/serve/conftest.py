"""Fixtures of the server tests: the database backends every server test runs on (SQLite, and a
throwaway PostgreSQL server when its binaries are installed)."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from _postgres import postgres_or_skip

BACKENDS = ["sqlite", "postgresql"]
_names = itertools.count()


@pytest.fixture(scope="session")
def postgres():
    """A PostgreSQL server for this test process (skips when PostgreSQL is not installed)."""
    pg = postgres_or_skip()
    yield pg
    pg.cleanup()


def new_database(backend: str, tmp: Path, request) -> str:
    """The URL of a new empty database of ``backend`` (a file in ``tmp``, or a new PostgreSQL database)."""
    n = next(_names)
    if backend == "sqlite":
        return f"sqlite:///{tmp / f'mptrack-{n}.db'}"
    return request.getfixturevalue("postgres").create_database(f"mptrack_{n}")


@pytest.fixture(params=BACKENDS)
def new_db(request, tmp_path):
    """A function of no arguments that makes a new empty database (once per backend)."""
    return lambda: new_database(request.param, tmp_path, request)
