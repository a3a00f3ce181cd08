"""The server: one ASGI application.

The ingest routes (``/`` with OsmAnd parameters, Traccar Client JSON or Overland batches, ``/pub``
for OwnTracks, ``/api/fixes`` for bulk files, ``/api/devices/{id}/cells`` for devices that report
cells) and cell geolocation (``/v1/geolocate``, :mod:`._geolocate`) are plain ASGI: they read the
request, parse it with their protocol module into fix records, wait for the group commit
(:class:`._ingest.Ingest`) and answer in the client's format.  Everything else -- the query API, its OpenAPI description, the stream and the
map -- is a FastAPI application (:mod:`._query`).

Errors are JSON, ``{"error": {"code": ..., "message": ..., "field": ...}}``, with a 4xx status; a
request that cannot be committed gets 503 and nothing of it is stored.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import logging
import os
import time
from dataclasses import asdict, dataclass
from urllib.parse import parse_qsl

from .._core.memory import arrow_gives_memory_back, trim_heap
from .._core.validation import as_real, check_bool, check_int, check_path, check_positive, lookup
from ..errors import MptrackError, ParameterError, RequestError
from ..tracking import MODELS, LiveTracks, TrackOptions
from . import _bulk, _osmand, _overland, _owntracks, _traccar_json
from ._auth import RateLimit, Registry, check_device, credentials
from ._celltable import load_cell_table
from ._fix import device_id, iso_time, timestamp
from ._geolocate import GeolocateError, Geolocator, answer_body, error_body, osmand_query, parse_request
from ._ingest import Ingest
from ._log_throttle import LogThrottle
from ._metrics import Metrics
from ._database import check_url, open_store
from ._postgres import shown_url
from ._store import DEFAULT_DB, first_line

__all__ = ["ServeConfig", "create_app", "app_from_environment", "config_environment", "CONFIG_ENV"]

log = logging.getLogger("mptrack.serve")
#: The environment variable holding a worker's ServeConfig (JSON), for ``mptrack serve --workers N``.
CONFIG_ENV = "MPTRACK_SERVE_CONFIG"

MIB = 1 << 20
#: The shortest time between two log lines of refused ingest requests of one reason (s): a client that
#: keeps sending what is refused shows in the log without flooding it.
REFUSAL_LOG_S = 60.0


@dataclass(frozen=True)
class ServeConfig:
    """What ``mptrack serve`` runs with (its options).

    db            database URL (``sqlite:///PATH``)
    auth          ingest needs a device token, queries and the map an API key
    max_body      largest request body accepted (bytes; 413 beyond)
    rate, burst   per-device rate limit: fixes per second on average, and bursts (0: none)
    retain_s      fixes older than this are deleted (seconds; None keeps everything)
    checkpoint_s  how often live states are checkpointed (and noise re-estimated)
    fsync         flush every group commit to disk (a power loss loses nothing acknowledged), not
                  only to the database file (a crash or kill -9 of the server loses nothing)
    model         the motion model of the live filter (as ``mptrack track --model``)
    cells         an OpenCelliD cell table (for cell geolocation), or None
    """

    db: str = DEFAULT_DB
    auth: bool = False
    max_body: int = MIB
    rate: float = 20.0
    burst: float = 200.0
    retain_s: float | None = None
    checkpoint_s: float = 10.0
    fsync: bool = False
    model: str = "cv"
    cells: str | None = None

    def __post_init__(self) -> None:
        check_url(self.db)
        for name in ("auth", "fsync"):
            check_bool(name, getattr(self, name))
        check_int("max_body", self.max_body, minimum=1)
        as_real("rate", self.rate, low=0.0)
        as_real("burst", self.burst, low=1.0)
        check_positive("checkpoint_s", self.checkpoint_s)
        if self.retain_s is not None:
            check_positive("retain_s", self.retain_s)
        lookup("model", self.model, MODELS, what="motion model")
        if self.cells is not None:
            check_path("cells", self.cells)


def _error_body(exc: RequestError) -> bytes:
    err = {"code": exc.code, "message": str(exc)}
    if exc.field is not None:
        err["field"] = exc.field
    return json.dumps({"error": err}).encode()


class RefusalLog:
    """Log lines of refused ingest requests: the first of each reason at once, then at most one every
    :data:`REFUSAL_LOG_S` seconds, with how many more were refused meanwhile.  Some apps never show the
    answer (OwnTracks takes every status as delivered): the log is where their user sees why."""

    def __init__(self):
        self._throttle = LogThrottle(REFUSAL_LOG_S)

    def note(self, exc: RequestError, path: str) -> None:
        more = self._throttle.due(exc.code)
        if more is None:
            return
        log.warning("refused %s (%d %s): %s%s", path, exc.status, exc.code, exc,
                    f" (and {more} more since the last such line)" if more else "",
                    extra={"event": "refused", "reason": exc.code, "status": exc.status})


class Server:
    """The ASGI application (see the module doc); ``create_app`` builds it."""

    def __init__(self, config: ServeConfig):
        from ._query import query_app

        self.config = config
        self.store = None
        self.ingest: Ingest | None = None
        self.registry: Registry | None = None
        self.geolocator: Geolocator | None = None
        self.limits = RateLimit(config.rate, config.burst)
        self.refusals = RefusalLog()
        self.metrics = Metrics.from_environment()
        self.started = time.time()
        self.startup_error: Exception | None = None   # why startup failed (the command line says it)
        self.query = query_app(self)
        self._tasks: list[asyncio.Task] = []

    # ---- life ------------------------------------------------------------------------------------
    async def startup(self) -> None:
        arrow_gives_memory_back()
        loop = asyncio.get_running_loop()
        collecting = gc.isenabled()
        gc.disable()   # a restart makes millions of objects that live on: no collection while it does
        try:
            await self._start(loop)
        finally:
            # what is loaded now (modules, the device ids, ...) lives as long as the server: out of the
            # cyclic garbage collector's reach, whose full collections otherwise scan it all (~100 ms
            # pauses of every request, several a minute under load)
            gc.freeze()
            if collecting:
                gc.enable()
        trim_heap()
        log.info("mptrack serve ready: %d devices, %s", len(self.ingest.devices), shown_url(self.config.db),
                 extra={"event": "ready", "devices": len(self.ingest.devices)})

    async def _start(self, loop) -> None:
        self.store = await loop.run_in_executor(None, open_store, self.config.db, self.config.fsync, True)
        live = LiveTracks(TrackOptions(model=self.config.model))
        await loop.run_in_executor(None, live.warm_up)
        self.ingest = Ingest(self.store, live, checkpoint_s=self.config.checkpoint_s, metrics=self.metrics)
        await loop.run_in_executor(None, self.ingest.recover)
        self.registry = Registry(self.store)
        if self.config.cells is not None:
            report = await loop.run_in_executor(None, load_cell_table, self.store, self.config.cells)
            log.info("cell table %s: %s", self.config.cells, "unchanged, not reloaded" if not report.loaded else
                     f"{report.cells} cells, {report.areas} areas in {report.seconds:.1f} s; "
                     f"{report.duplicates} duplicates and {sum(report.skipped.values())} bad rows left out "
                     f"{report.examples[:3] if report.examples else ''}")
        if self.store.cell_source() is not None:
            self.geolocator = Geolocator(self.store)
        self.ingest.start()
        if self.config.retain_s is not None:
            self._tasks.append(loop.create_task(self._retention()))

    async def shutdown(self) -> None:
        for task in self._tasks:
            task.cancel()
        if self.ingest is not None:
            await self.ingest.close()
        if self.geolocator is not None:
            self.geolocator.close()
        if self.store is not None:
            self.store.close()

    def _abandon(self) -> None:
        """After a failed start: close what was opened (the database's lock released), storing nothing --
        the live states may be half loaded."""
        for part in (self.geolocator, self.store):
            if part is not None:
                with contextlib.suppress(Exception):
                    part.close()

    async def _retention(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            cutoff = time.time() - self.config.retain_s
            try:
                n = await loop.run_in_executor(None, self.store.delete_before, cutoff)
            except Exception as exc:  # the database is down: try again next time
                if not _is_database_error(exc):
                    raise
                log.warning("retention: %s; trying again later", first_line(exc), extra={"event": "retention_failed"})
            else:
                if n:
                    log.info("retention: deleted %d fixes older than %s", n, iso_time(cutoff),
                             extra={"event": "retention", "deleted": n, "before": iso_time(cutoff)})
            await asyncio.sleep(min(3600.0, max(1.0, self.config.retain_s / 100.0)))

    # ---- ASGI --------------------------------------------------------------------------------------
    async def __call__(self, scope, receive, send):
        kind = scope["type"]
        if kind == "http":
            path, method = scope["path"], scope["method"]
            if path == "/":
                if method == "POST" or (method == "GET" and _is_osmand(scope["query_string"])):
                    return await self._guard(self._root, scope, receive, send)
            elif path == "/pub" and method == "POST":
                return await self._guard(self._owntracks, scope, receive, send)
            elif path == "/api/fixes" and method == "POST":
                return await self._guard(self._bulk, scope, receive, send)
            elif path == "/v1/geolocate" and method == "POST":
                return await self._geolocate(scope, receive, send)
            elif path.startswith("/api/devices/") and path.endswith("/cells") and method == "POST":
                return await self._guard(self._cells, scope, receive, send)
            elif path == "/healthz" and method in ("GET", "HEAD"):
                return await _respond(send, 200, b'{"status":"ok"}')
            elif path == "/metrics" and method == "GET":
                return await self._metrics(scope, send)
        elif kind == "lifespan":
            return await self._lifespan(receive, send)
        await self.query(scope, receive, send)

    async def _lifespan(self, receive, send):
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                try:
                    await self.startup()
                except Exception as exc:  # the server cannot start: say why in one line
                    self.startup_error = exc
                    self._abandon()
                    await send({"type": "lifespan.startup.failed", "message": str(exc)})
                    return
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                await self.shutdown()
                await send({"type": "lifespan.shutdown.complete"})
                return

    async def _guard(self, handler, scope, receive, send):
        """Run an ingest handler: RequestError -> its 4xx JSON; a failed commit -> 503."""
        started = time.perf_counter()
        try:
            status, body, ctype = await handler(scope, receive)
        except RequestError as exc:
            self.metrics.refuse(exc.code)
            self.refusals.note(exc, scope["path"])
            status, body, ctype = exc.status, _error_body(exc), b"application/json"
        except Exception as exc:  # the database (or the server) could not commit: nothing stored
            if not isinstance(exc, (ConnectionAbortedError, MptrackError, OSError, RuntimeError)) and \
                    not _is_database_error(exc):
                raise
            self.metrics.refuse("not_committed")
            log.warning("not committed: %s", first_line(exc), extra={"event": "not_committed"})
            status, ctype = 503, b"application/json"
            body = json.dumps({"error": {"code": "not_committed", "message": f"not stored: {first_line(exc)}"}}).encode()
        await _respond(send, status, body, ctype)
        self.metrics.observe("latency", time.perf_counter() - started)

    async def _metrics(self, scope, send):
        if self.config.auth:
            params = dict(parse_qsl(scope["query_string"].decode("latin-1")))
            try:
                self.registry.check_key(credentials(dict(scope["headers"]), params.get(_osmand.TOKEN_PARAMETER))[0])
            except RequestError as exc:
                return await _respond(send, exc.status, _error_body(exc))
        loop = asyncio.get_running_loop()
        try:
            known, live = await loop.run_in_executor(None, self.ingest.device_counts, 300.0)
        except Exception as exc:  # the database is down: the counters still answer
            if not _is_database_error(exc):
                raise
            known = live = float("nan")
        text = self.metrics.prometheus({
            "devices": ("Devices that have sent a fix.", known),
            "devices_live": ("Devices whose last fix is at most 5 minutes old.", live),
            "uptime_seconds": ("Seconds since this process started.", time.time() - self.started)})
        await _respond(send, 200, text.encode(), b"text/plain; version=0.0.4; charset=utf-8")

    async def _root(self, scope, receive):
        headers = dict(scope["headers"])
        answer = b""
        if scope["method"] == "GET":
            fixes, key = _one(_osmand.parse_query(scope["query_string"]))
        else:
            ctype = _content_type(headers)
            body = await _body(receive, headers, self.config.max_body)
            if ctype == "application/json":
                doc = _traccar_json.load_json(body)
                key = _query_key(scope)
                if _overland.is_batch(doc):
                    fixes = _overland.parse_document(doc, self._endpoint_device(scope, headers, key))
                    answer = _overland.REPLY
                elif _owntracks.is_message(doc):
                    raise RequestError("an OwnTracks message: OwnTracks posts to /pub (set its URL to this "
                                       "server's address followed by /pub)", code="wrong_endpoint", field="_type")
                else:
                    fixes = _traccar_json.parse_document(doc)
            elif ctype == "application/x-www-form-urlencoded" or (not ctype and not body):
                fixes, key = _one(_osmand.parse_query(body or scope["query_string"]))
            else:
                raise RequestError(f"expected application/x-www-form-urlencoded (OsmAnd) or application/json "
                                   f"(Traccar Client, Overland), got {ctype or 'no content type'}", status=415,
                                   code="unsupported_media_type", field="Content-Type")
        await self._accept(self._place(fixes), headers, key)
        return 200, answer, b"application/json" if answer else b"text/plain"

    def _endpoint_device(self, scope, headers: dict, key: str | None) -> str | None:
        """The device of a batch's points that name none: the endpoint's ``?device=ID``, else (``--auth``)
        the token's owner."""
        named = dict(parse_qsl(scope["query_string"].decode("latin-1"))).get("device")
        if named:
            return device_id(named, "device")
        return self.registry.device(credentials(headers, key)[0]) if self.config.auth else None

    async def _owntracks(self, scope, receive):
        headers = dict(scope["headers"])
        params = dict(parse_qsl(scope["query_string"].decode("latin-1")))
        secret, user = credentials(headers, params.get(_osmand.TOKEN_PARAMETER))
        owner = self.registry.device(secret) if self.config.auth else None
        u = params.get("u") or _header(headers, b"x-limit-u")
        d = params.get("d") or _header(headers, b"x-limit-d")
        if not u and user:  # HTTP Basic's user is USER/DEVICE (or USER)
            u, _, d = user.partition("/")
        device = _owntracks.device_of(u, d) if u or owner is None else owner
        body = await _body(receive, headers, self.config.max_body)
        fixes = _owntracks.parse_body(body, device)
        if owner is not None:
            check_device(device, owner)
        await self._accept(fixes, headers, None, device=device, checked=True)
        return 200, b"[]", b"application/json"

    async def _bulk(self, scope, receive):
        headers = dict(scope["headers"])
        params = dict(parse_qsl(scope["query_string"].decode("latin-1")))
        if self.config.auth:
            self.registry.check_key(credentials(headers, params.get(_osmand.TOKEN_PARAMETER))[0])
        ctype = _content_type(headers)
        kind = _bulk.CONTENT_TYPES.get(ctype)
        if kind is None:
            raise RequestError(f"expected one of {', '.join(_bulk.CONTENT_TYPES)}, got {ctype or 'no content type'}",
                               status=415, code="unsupported_media_type", field="Content-Type")
        body = await _body(receive, headers, self.config.max_body)
        loop = asyncio.get_running_loop()
        notes: list[str] = []
        fixes = await loop.run_in_executor(None, _bulk.parse_body, body, kind, params, None, notes)
        await self.ingest.submit(fixes)
        return 200, json.dumps({"accepted": len(fixes), "notes": notes}).encode(), b"application/json"

    async def _geolocate(self, scope, receive, send):
        """POST /v1/geolocate: the position of the cells of a Google/Ichnaea request, errors in their format."""
        try:
            headers = dict(scope["headers"])
            if self.config.auth:
                try:
                    self.registry.check_key(credentials(headers, _query_key(scope))[0])
                except RequestError as exc:  # Google answers a bad key with 400 keyInvalid
                    raise GeolocateError(exc.reason, reason="keyInvalid", field="key") from None
            answer = await self._answer(parse_request(await _body(receive, headers, self.config.max_body)))
        except RequestError as exc:
            return await _respond(send, exc.status, error_body(exc))
        await _respond(send, 200, answer_body(answer))

    def _geolocator(self) -> Geolocator:
        if self.geolocator is None:
            raise GeolocateError("Not found: this server has no cell table (start it with --cells FILE)",
                                 reason="notFound", status=404)
        return self.geolocator

    async def _answer(self, query):
        return await self._geolocator().answer(query)

    async def _cells(self, scope, receive):
        """POST /api/devices/{id}/cells: a geolocate body of a device; its position feeds the device's track."""
        headers = dict(scope["headers"])
        device = device_id(scope["path"][len("/api/devices/"):-len("/cells")], "device_id")
        body = await _body(receive, headers, self.config.max_body)
        query = parse_request(body)
        answer = await self._answer(query)
        t = timestamp(query.timestamp, "timestamp") if query.timestamp is not None else time.time()
        await self._accept([_cell_fix(device, t, answer)], headers, _query_key(scope))
        return 200, answer_body(answer), b"application/json"

    def _place(self, fixes: list[tuple]) -> list[tuple]:
        """Fixes without a position (an OsmAnd report of cells only) placed from their cells."""
        out = []
        for f in fixes:
            if f[2] is None:
                out.append(_cell_fix(f[0], f[1], self._geolocator().locate(osmand_query(f[8]["cells"])), f[8]))
            else:
                out.append(f)
        return out

    async def _accept(self, fixes: list[tuple], headers: dict, key: str | None, *, device: str | None = None,
                      checked: bool = False) -> None:
        """Check the device's token (unless ``checked``) and its rate, then wait for the commit."""
        if self.config.auth and not checked:
            owner = self.registry.device(credentials(headers, key)[0])
            for claimed in {device} if device else {f[0] for f in fixes}:
                check_device(claimed, owner)
        if not fixes:
            return
        self.limits.take(fixes[0][0], self.ingest.devices.get(fixes[0][0]), len(fixes))
        await self.ingest.submit(fixes)


def create_app(config: ServeConfig = ServeConfig()) -> Server:
    """The ASGI application of ``mptrack serve`` (run it with uvicorn).

    Parameters
    ----------
    config : ServeConfig, optional
        The database, authentication, limits, retention, checkpoints and motion model.

    Returns
    -------
    Server
        The ASGI application.
    """
    if not isinstance(config, ServeConfig):
        raise ParameterError(f"config: expected a ServeConfig, got {type(config).__name__}")
    return Server(config)


def config_environment(config: ServeConfig) -> dict[str, str]:
    """The environment that hands ``config`` to worker processes (:func:`app_from_environment`)."""
    return {CONFIG_ENV: json.dumps(asdict(config))}


def app_from_environment() -> Server:
    """The application of one worker of ``mptrack serve --workers N``: the ServeConfig in
    $MPTRACK_SERVE_CONFIG (uvicorn calls this factory in each worker process)."""
    return create_app(ServeConfig(**json.loads(os.environ[CONFIG_ENV])))


def _is_database_error(exc: BaseException) -> bool:
    """A database driver's error (the database is down, a connection broke, a pool timed out)."""
    mod = type(exc).__module__
    return mod.startswith(("psycopg", "sqlite3"))


# ---- small ASGI helpers --------------------------------------------------------------------------------
_OSMAND = (b"id=", b"deviceid=", b"lat=", b"lon=", b"location=")


def _is_osmand(query: bytes) -> bool:
    """A GET / with a device id or a position is an OsmAnd fix (without any it is the map page)."""
    return query.startswith(_OSMAND) or any(b"&" + p in query for p in _OSMAND)


def _cell_fix(device: str, t: float, answer, attrs: dict | None = None) -> tuple:
    """The fix of a device placed from its cells (its accuracy the 68 % radius, as a phone's own)."""
    extra = {"source": "lacf" if answer.fallback else "cells", "cells_known": answer.known}
    return (device, t, answer.lat, answer.lon, answer.accuracy, None, None, None, {**(attrs or {}), **extra})


def _one(parsed) -> tuple[list[tuple], str | None]:
    fix, key = parsed
    return [fix], key


def _query_key(scope) -> str | None:
    q = scope["query_string"]
    if not q:
        return None
    return dict(parse_qsl(q.decode("latin-1"))).get(_osmand.TOKEN_PARAMETER)


def _header(headers: dict, name: bytes) -> str | None:
    v = headers.get(name)
    return v.decode("latin-1").strip() if v else None


def _content_type(headers: dict) -> str:
    return headers.get(b"content-type", b"").decode("latin-1").split(";")[0].strip().lower()


async def _body(receive, headers: dict, limit: int) -> bytes:
    """The request body, refused with 413 as soon as it exceeds ``limit`` bytes."""
    declared = headers.get(b"content-length")
    if declared is not None:
        try:
            n = int(declared)
        except ValueError:
            raise RequestError("Content-Length is not a number", field="Content-Length") from None
        if n > limit:
            raise RequestError(f"the body has {n} bytes; this server takes at most {limit}", status=413,
                               code="body_too_large")
    chunks, size = [], 0
    while True:
        message = await receive()
        if message["type"] == "http.disconnect":
            raise RequestError("the client went away before sending the whole body", code="incomplete_body")
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > limit:
            raise RequestError(f"the body has more than {limit} bytes, the most this server takes", status=413,
                               code="body_too_large")
        chunks.append(chunk)
        if not message.get("more_body", False):
            return b"".join(chunks)


async def _respond(send, status: int, body: bytes, ctype: bytes = b"application/json") -> None:
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", ctype), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})
