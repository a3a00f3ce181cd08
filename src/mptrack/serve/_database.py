"""Which store a database URL names (the one place that knows every backend)."""

from __future__ import annotations

from ..errors import ParameterError
from ._sqlite import SqliteStore
from ._store import DEFAULT_DB, Store

__all__ = ["open_store", "check_url"]


def open_store(db: str, fsync: bool = False, server: bool = False, reader: bool = False) -> Store:
    """The store of the server database at a URL.

    Parameters
    ----------
    db : str
        The database URL: ``sqlite:///PATH`` (a file, created with its schema) or
        ``postgresql://...`` (a database, its schema created or upgraded).
    fsync : bool, optional
        Every commit is flushed to disk before it returns (also a power loss loses nothing
        acknowledged), not only written to the database's log.
    server : bool, optional
        The store of a running server: a database with one writer (SQLite) is locked against a
        second server while the store is open.
    reader : bool, optional
        A store that only reads (a helper process's): no schema written, one connection, no background
        work.

    Returns
    -------
    Store
        Close it when done.

    Raises
    ------
    ParameterError
        Not a database URL of a known kind.
    OutputError
        The database cannot be opened, its schema is newer than this mptrack's, or (``server``) another
        server has it.
    """
    if check_url(db) == "sqlite":
        return SqliteStore(db, fsync, server, reader)
    from ._postgres import PostgresStore

    return PostgresStore(db, fsync, pool_size=1, upgrade=False) if reader else PostgresStore(db, fsync)


def check_url(db) -> str:
    """The kind of database a URL names, ``sqlite`` or ``postgresql``; a ParameterError for anything else."""
    if not isinstance(db, str):
        raise ParameterError(f"db: expected a database URL such as {DEFAULT_DB}, got {type(db).__name__}")
    if db.startswith("sqlite:///"):
        return "sqlite"
    if db.startswith(("postgresql://", "postgres://")):
        return "postgresql"
    raise ParameterError(f"db: expected sqlite:///PATH or postgresql://..., got {db!r}"[:200])
