"""``mptrack serve`` (the live tracking server, docs/serve.md), the commands that manage who may use
it: ``mptrack devices add NAME`` (a device token for ingest) and ``mptrack keys add NAME`` (an API key
for the query API and the map), its database: ``mptrack db upgrade`` and ``mptrack db copy``, and
``mptrack geolocate`` (the server's cell geolocation on a file of requests)."""

from __future__ import annotations

import contextlib
import ipaddress
import json
import logging
import os
import tempfile
from pathlib import Path
from typing import Optional

import typer

from ..errors import MptrackError
from ._common import QUIET, check_outputs, echo, err, fail, note
from ._logs import log_config_of

__all__ = ["serve", "devices", "keys", "db", "geolocate"]

_DB_HELP = ("Database: sqlite:///PATH (default sqlite:///mptrack.db in the working directory) or "
            "postgresql://USER@HOST/DB (many workers and hosts on one database).")


def _duration(text: str | None, option: str) -> float | None:
    """Seconds of a duration such as 30d, 12h, 90m, 3600s or 3600."""
    if text is None:
        return None
    units = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0, "w": 604800.0}
    body, unit = (text[:-1], text[-1]) if text and text[-1] in units else (text, "s")
    try:
        value = float(body) * units[unit]
    except ValueError:
        fail(f"{option}: expected a duration such as 30d, 12h or 3600s, got {text!r}")
    if not value > 0 or value != value or value == float("inf"):
        fail(f"{option}: expected a positive duration, got {text!r}")
    return value


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def serve(
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (loopback by default; any other "
                                                         "address needs --auth)."),
    port: int = typer.Option(5055, "--port", help="TCP port (5055: Traccar's OsmAnd port, so apps' defaults work)."),
    db: str = typer.Option("sqlite:///mptrack.db", "--db", help=_DB_HELP),
    auth: bool = typer.Option(False, "--auth", help="Devices need their token (mptrack devices add) and the query "
                                                    "API and map an API key (mptrack keys add)."),
    fsync: bool = typer.Option(False, "--fsync", help="Flush every commit to disk before answering, so that a power "
                                                      "loss too loses nothing acknowledged (a crash or kill -9 of the "
                                                      "server never does); costs one disk flush per group commit."),
    retain: Optional[str] = typer.Option(None, "--retain", help="Delete fixes older than this (e.g. 30d, 12h); "
                                                                "default: keep everything."),
    cells: Optional[Path] = typer.Option(None, "--cells", help="Cell table (OpenCelliD/MLS CSV, gzip or plain) "
                                                               "for cell geolocation: POST /v1/geolocate, and "
                                                               "devices that report cells; loaded into the "
                                                               "database once (again when the file changes)."),
    model: str = typer.Option("cv", "--model", help="Motion model of the live filter: cv or ca."),
    workers: int = typer.Option(1, "--workers", help="Server processes on this machine (PostgreSQL only: any number "
                                                     "of processes and hosts may serve one database)."),
    log_format: str = typer.Option("text", "--log-format", help="Log lines as text, or as json (one object per "
                                                                "line: time, level, logger, message, pid, fields)."),
    max_body: int = typer.Option(1 << 20, "--max-body", help="Largest request body accepted (bytes)."),
    rate: float = typer.Option(20.0, "--rate", help="Per-device rate limit: fixes per second on average "
                                                    "(0: none)."),
    burst: float = typer.Option(200.0, "--burst", help="Per-device rate limit: fixes in a burst."),
    quiet: bool = QUIET,
) -> None:
    """Run the live tracking server: phones and trackers report fixes (OsmAnd/Traccar Client, OwnTracks,
    Overland, bulk files), every device gets a filtered track, a prediction and a live map at http://HOST:PORT/.

    Stops on Ctrl-C or SIGTERM after committing every acknowledged fix (exit 0)."""
    if not _loopback(host) and not auth:
        fail(f"--host {host} is not a loopback address: the server would be open to anyone who can reach it; "
             "add --auth (and give each device a token with mptrack devices add NAME)")
    if cells is not None and not cells.is_file():
        fail(f"--cells: {cells} is not a file")
    for name, value in (("--port", port), ("--max-body", max_body)):
        if value < 1 or (name == "--port" and value > 65535):
            fail(f"{name}: expected a positive number{' up to 65535' if name == '--port' else ''}, got {value}")
    if rate < 0 or burst < 1:
        fail("--rate must be >= 0 and --burst >= 1")
    if log_format not in ("text", "json"):
        fail(f"--log-format: expected text or json, got {log_format!r}")
    if workers < 1:
        fail(f"--workers: expected a positive number, got {workers}")
    if workers > 1 and not _db_url(db).startswith(("postgresql://", "postgres://")):
        fail(f"--workers {workers} needs a PostgreSQL database (--db postgresql://...): a SQLite file has one writer")
    import uvicorn

    _Server = _server_class()

    from ..serve import ServeConfig, create_app
    from ..tracking import get_model

    try:
        get_model(model)
        config = ServeConfig(db=_db_url(db), auth=auth, max_body=max_body, rate=rate, burst=burst,
                             retain_s=_duration(retain, "--retain"), model=model, fsync=fsync,
                             cells=None if cells is None else str(cells))
        app = create_app(config)
    except MptrackError as exc:
        fail(exc)
    sock = _listen(host, port)
    port = sock.getsockname()[1]
    level = "WARNING" if quiet else "INFO"
    log_config = log_config_of(log_format, level)
    if not quiet:
        where = "localhost" if _loopback(host) else host
        note(f"listening on http://{where}:{port}/ (live map there; OsmAnd/Traccar Client: server URL "
             f"http://{where}:{port}; OwnTracks: http://{where}:{port}/pub; Overland: receiver endpoint "
             f"http://{where}:{port}/), database {_shown(config.db)}"
             + (f", {workers} workers" if workers > 1 else ""), "serve")
    # the server reads no client address or scheme: uvicorn's rewriting of them from a proxy's
    # X-Forwarded-* headers would only cost every request (~7 microseconds, 7 % of an OsmAnd fix)
    options = dict(host=host, port=port, log_level=level.lower(), access_log=False, lifespan="on",
                   timeout_graceful_shutdown=10, log_config=log_config, proxy_headers=False)
    if workers > 1:
        _run_workers(config, workers, options, sock)
        return
    server_config = uvicorn.Config(app, **options)   # (configures logging)
    quiet_failure = _StartupFailed(app)
    logging.getLogger("uvicorn.error").addFilter(quiet_failure)
    try:
        _Server(server_config).run(sockets=[sock])
    except SystemExit:
        if app.startup_error is not None:   # uvicorn exits 3 when the app cannot start: say why, exit 2
            fail(app.startup_error)
        raise
    finally:   # (a command run again in one process, as the tests do, adds its own)
        logging.getLogger("uvicorn.error").removeFilter(quiet_failure)


def _listen(host: str, port: int):
    """A TCP socket bound to ``host``:``port`` (as uvicorn binds one), or one line naming the option
    and exit status 2 (a port in use: before the database is opened)."""
    import errno
    import socket

    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            fail(f"--port: {host}:{port} is in use (another server is listening there); give another --port")
        fail(f"--host/--port: cannot listen on {host}:{port}: {exc.strerror or exc}")
    sock.set_inheritable(True)
    return sock


def _run_workers(config, workers: int, options: dict, sock) -> None:
    """N worker processes on one listening socket (uvicorn's supervisor restarts one that dies), the
    configuration handed on in the environment, their counters in one shared file."""
    import uvicorn
    from uvicorn.supervisors import Multiprocess

    from ..serve import WORKER_APP, worker_environment

    with tempfile.TemporaryDirectory(prefix="mptrack-serve-") as tmp:
        os.environ.update(worker_environment(config, tmp, workers))
        ucfg = uvicorn.Config(WORKER_APP, factory=True, workers=workers, **options)
        Multiprocess(ucfg, sockets=[sock]).run()


def _shown(url: str) -> str:
    """A database URL without its password."""
    from ..serve import shown_url

    return shown_url(url)


class _StartupFailed(logging.Filter):
    """Drops uvicorn's lines about an application that could not start (its reason, then "Application
    startup failed"): the one line the command prints says why."""

    def __init__(self, app):
        super().__init__()
        self.app = app

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        error = self.app.startup_error
        return not (message.startswith("Application startup failed") or
                    (error is not None and message == str(error)))


def _server_class():
    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, except that stopping by SIGTERM/SIGINT (after the graceful shutdown that
        commits every acknowledged fix) exits 0 instead of re-raising the signal."""

        @contextlib.contextmanager
        def capture_signals(self):
            with super().capture_signals():
                yield
                self._captured_signals.clear()

    return Server


def _db_url(db: str) -> str:
    """sqlite:///PATH as given, or a bare path as sqlite:///PATH."""
    return db if "://" in db else f"sqlite:///{db}"


devices = typer.Typer(help="Devices allowed to report to mptrack serve --auth.", no_args_is_help=True)
keys = typer.Typer(help="API keys of the query API and the map of mptrack serve --auth.", no_args_is_help=True)


@devices.command("add")
def add_device(name: str = typer.Argument(..., help="The device id the device reports with (OsmAnd id, "
                                                    "Traccar Client device identifier, OwnTracks USER/DEVICE)."),
               db: str = typer.Option("sqlite:///mptrack.db", "--db", help=_DB_HELP)) -> None:
    """Register a device and print its token (shown once: only its digest is stored)."""
    from ..serve import add_device as _add

    try:
        token = _add(_db_url(db), name)
    except MptrackError as exc:
        fail(exc)
    echo(token)
    err.print(f"device {name}: give the app the server URL with ?key={token[:6]}… (OsmAnd/Traccar Client), "
              "or the token as password (OwnTracks, HTTP Basic) or Bearer token", soft_wrap=True, highlight=False)


@keys.command("add")
def add_key(name: str = typer.Argument(..., help="A name for the key (who uses it)."),
            db: str = typer.Option("sqlite:///mptrack.db", "--db", help=_DB_HELP)) -> None:
    """Create an API key for the query API and the map, and print it (shown once)."""
    from ..serve import add_api_key

    try:
        key = add_api_key(_db_url(db), name)
    except MptrackError as exc:
        fail(exc)
    echo(key)


db = typer.Typer(help="The database of mptrack serve: create or upgrade its schema, copy it into another.",
                 no_args_is_help=True)


@db.command("upgrade")
def upgrade(db_url: str = typer.Option("sqlite:///mptrack.db", "--db", help=_DB_HELP)) -> None:
    """Create the server's tables in a database, or upgrade them to this mptrack's schema (mptrack serve
    does it too when it starts); prints the schema version."""
    from ..serve import open_store

    try:
        store = open_store(_db_url(db_url))
    except MptrackError as exc:
        fail(exc)
    try:
        echo(f"{_shown(store.url)}: schema version {store.schema_version}")
    finally:
        store.close()


@db.command("copy")
def copy(source: str = typer.Argument(..., help="The database to copy (sqlite:///PATH or postgresql://...)."),
         target: str = typer.Argument(..., help="An empty database to copy it into (created with its schema)."),
         model: Optional[str] = typer.Option(None, "--model", help="Motion model of the live states (default: the "
                                                                   "one they were made with).")) -> None:
    """Copy a server database into another, e.g. a trial's SQLite file into PostgreSQL, losing nothing:
    devices, keys, every fix with its estimate, and each device's live state; the counts and a SHA-256
    of the fixes are compared at the end."""
    from ..serve import copy_database

    try:
        got = copy_database(_db_url(source), _db_url(target), model=model)
    except MptrackError as exc:
        fail(exc)
    echo(json.dumps(got))
    err.print(f"copied {got['fixes']:,} fixes of {got['device_keys']:,} devices, {got['devices']} registered "
              f"devices and {got['api_keys']} API keys; fixes' SHA-256 equal in both: {got['sha256'][:16]}…",
              soft_wrap=True, highlight=False)


def geolocate(
    requests: Path = typer.Argument(..., help="NDJSON file: one geolocate request (Google's / Ichnaea's JSON) per "
                                              "line."),
    cells: Optional[Path] = typer.Option(None, "--cells", help="Cell table (OpenCelliD/MLS CSV, gzip or plain)."),
    db: Optional[str] = typer.Option(None, "--db", help="Database holding the cell table (e.g. the server's, "
                                                        "sqlite:///mptrack.db); default: a temporary one."),
    out: Optional[Path] = typer.Option(None, "--out", help="Write the answers here (NDJSON) instead of stdout."),
    quiet: bool = QUIET,
) -> None:
    """Answer a file of cell geolocation requests as the server's POST /v1/geolocate does: one JSON line per
    request, the position ({"location": {"lat", "lng"}, "accuracy"}: the 68 % radius in metres) or the error
    in Google's format, with the request's line number and the HTTP status the server would give."""
    import json

    from .._core.files import atomic_path
    from ..serve import geolocate_requests

    if cells is None and db is None:
        fail("--cells: give the cell table (or --db, a database that holds one)")
    check_outputs(requests, cells, out=out)
    counts: dict[int, int] = {}
    try:
        lines = geolocate_requests(requests, cells=cells, db=None if db is None else _db_url(db))
        if out is None:
            for number, status, answer in lines:
                counts[status] = counts.get(status, 0) + 1
                echo(json.dumps({"line": number, "status": status, **answer}, separators=(",", ":")))
        else:
            with atomic_path(out) as tmp, open(tmp, "w") as f:
                for number, status, answer in lines:
                    counts[status] = counts.get(status, 0) + 1
                    f.write(json.dumps({"line": number, "status": status, **answer}, separators=(",", ":")) + "\n")
    except MptrackError as exc:
        fail(exc)
    except KeyboardInterrupt:
        from ._common import interrupted

        interrupted("nothing was written" if out is not None else "the answers printed so far")
    if not quiet:
        total = sum(counts.values())
        note(f"{total} requests: {counts.get(200, 0)} located, {counts.get(404, 0)} not found, "
             f"{counts.get(400, 0)} refused" + (f"; answers in {out}" if out is not None else ""), "geolocate")
