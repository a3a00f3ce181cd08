"""The query side of the server: a FastAPI application (typed parameters, the OpenAPI description at
``/openapi.json``), the live stream and the map page.

    GET /api/devices                          every device: last fix time, last raw and estimated position
    GET /api/devices/{id}/position[?at=TIME]  the current estimate, or the prediction at TIME
    GET /api/devices/{id}/track               stored fixes with their live estimates, or smoothed
    GET /api/stream                           Server-Sent Events: every accepted fix's estimate
    GET /api/stats                            what ingest has accepted and refused
    GET /                                     the live map
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Literal, Optional

from fastapi import Depends, FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse, Response, StreamingResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

from .. import __version__
from ..errors import RequestError
from ._auth import credentials
from ._fix import MAX_FUTURE_S, iso_time, timestamp
from ._ingest import StreamQueue
from ._store import FLAG_NAMES
from ._openapi import ingest_paths
from ._tracks import FORMATS, track_body

__all__ = ["query_app"]


class DeviceSummary(BaseModel):
    id: str = Field(description="the device id")
    last_fix_time: Optional[str] = Field(description="time of the device's last fix (ISO 8601 UTC)")
    raw_lat: Optional[float] = Field(description="the last fix as sent (degrees)")
    raw_lon: Optional[float]
    lat: Optional[float] = Field(description="the filter's estimate at the last fix (degrees)")
    lon: Optional[float]
    ell_major_m: Optional[float] = Field(description="1-sigma error ellipse of the estimate: semi-major axis (m)")
    ell_minor_m: Optional[float]
    ell_azimuth_deg: Optional[float]
    flag: Optional[str] = Field(description="how the last fix was used (update, manoeuvre, outlier, reset, init)")


class Position(BaseModel):
    id: str
    time: str = Field(description="the time of the estimate (ISO 8601 UTC): the last fix, or ?at=")
    lat: float
    lon: float
    speed_mps: Optional[float]
    heading_deg: Optional[float] = Field(description="direction of motion, degrees clockwise from north")
    ell_major_m: float = Field(description="1-sigma error ellipse: semi-major axis (m)")
    ell_minor_m: float
    ell_azimuth_deg: float = Field(description="azimuth of the major axis, degrees clockwise from north")
    age_s: float = Field(description="seconds from the last fix to now (or to ?at=)")
    flag: str = Field(description="how the last fix was used: update, manoeuvre, outlier, reset, init, or "
                                  "predicted (with ?at=)")
    last_fix_time: str


class Stats(BaseModel):
    devices: int = Field(description="devices that have sent a fix")
    accepted: int
    filtered: int
    late: int
    duplicates: int
    ahead: int = Field(description="late fixes that were so for their time: stamped ahead of the server's clock "
                                   "and of their device's clock so far, kept out of the live filter")
    batches: int
    refused: dict[str, int]
    uptime_s: float
    geolocate: Optional[dict[str, int]] = Field(None, description="cell geolocation (with a cell table): "
                                                "requests, found, lacf, not_found, cells_known, cells_unknown, "
                                                "cells_incomplete, wifi_ignored")


class ErrorBody(BaseModel):
    code: str
    message: str
    field: Optional[str] = None


class Error(BaseModel):
    error: ErrorBody


_ERRORS = {401: {"model": Error, "description": "no or unknown API key"},
           404: {"model": Error, "description": "unknown device"},
           422: {"model": Error, "description": "a parameter is out of range"}}


def _error(status: int, code: str, message: str, field: str | None = None) -> JSONResponse:
    body = {"code": code, "message": message}
    if field:
        body["field"] = field
    return JSONResponse({"error": body}, status_code=status)


def query_app(server) -> FastAPI:
    """The FastAPI application of ``server`` (a :class:`._app.Server`)."""
    app = FastAPI(title="mptrack live tracking server", version=__version__, docs_url="/docs", redoc_url=None,
                  description="Filtered live tracks of phones and trackers: the query API. Devices report "
                              "with the OsmAnd protocol (GET/POST /), Traccar Client JSON or Overland (POST /), "
                              "OwnTracks (POST /pub) or bulk files (POST /api/fixes): see docs/serve.md.")

    @app.exception_handler(RequestError)
    async def _request_error(request, exc: RequestError):
        return _error(exc.status, exc.code, str(exc), exc.field)

    @app.exception_handler(RequestValidationError)
    async def _validation(request, exc: RequestValidationError):
        first = exc.errors()[0] if exc.errors() else {}
        field = ".".join(str(p) for p in first.get("loc", ())[1:]) or None
        return _error(422, "invalid_field", f"{field}: {first.get('msg', 'invalid')}" if field else
                      first.get("msg", "invalid request"), field)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request, exc: StarletteHTTPException):
        codes = {404: "not_found", 405: "method_not_allowed"}
        return _error(exc.status_code, codes.get(exc.status_code, "http_error"), str(exc.detail))

    def api_key(request: Request, key: Optional[str] = Query(None, description="API key (with --auth)")) -> None:
        if server.config.auth:
            server.registry.check_key(credentials(dict(request.scope["headers"]), key)[0])

    def device(device_id: str) -> int:
        dev = server.ingest.key(device_id)
        if dev is None:
            raise RequestError(f"no device {device_id!r} has sent a fix", status=404, code="not_found",
                               field="device_id")
        return dev

    @app.get("/api/devices", response_model=list[DeviceSummary], responses=_ERRORS, dependencies=[Depends(api_key)],
             summary="Every device with its last fix and estimate")
    def devices():
        ing = server.ingest
        ing.refresh()
        with ing.lock:
            last = ing.live.summaries()
            ids = ing.devices.ids_of(range(ing.devices.size))
        return [{"id": ids[i], "last_fix_time": iso_time(s["time"]) if s["time"] == s["time"] else None,
                 "raw_lat": _f(s["raw_lat"]), "raw_lon": _f(s["raw_lon"]), "lat": _f(s["lat"]), "lon": _f(s["lon"]),
                 "ell_major_m": _f(s["ell_major_m"]), "ell_minor_m": _f(s["ell_minor_m"]),
                 "ell_azimuth_deg": _f(s["ell_azimuth_deg"]),
                 "flag": FLAG_NAMES[int(s["flag"])] if s["flag"] == s["flag"] else None}
                for i, s in enumerate(last[:len(ids)]) if ids[i] is not None]

    @app.get("/api/devices/{device_id:path}/position", response_model=Position, responses=_ERRORS,
             dependencies=[Depends(api_key)], summary="The current estimate, or the prediction at a time")
    def position(device_id: str, at: Optional[str] = Query(None, description="predict to this time (ISO 8601 or "
                                                                                 "epoch seconds), at or after the last fix")):
        dev = device(device_id)
        now = time.time()
        ing = server.ingest
        ing.refresh([dev])
        with ing.lock:
            last_t = ing.live.last_fix(dev)[0]
            if not last_t == last_t:
                raise RequestError(f"device {device_id!r} has no filtered fix yet", status=404, code="not_found",
                                   field="device_id")
            when = last_t if at is None else _time_param(at, "at", now, future_s=MAX_FUTURE_S)
            if when < last_t:
                raise RequestError(f"{iso_time(when)} is before the device's last fix ({iso_time(last_t)}); "
                                   "the track of the past is at /track", status=422, field="at")
            est = ing.live.position(dev, when)
        speed = math.hypot(est["vel_e"], est["vel_n"])
        return {"id": device_id, "time": iso_time(when), "lat": est["lat"], "lon": est["lon"],
                "speed_mps": _f(speed), "heading_deg": _f(math.degrees(math.atan2(est["vel_e"], est["vel_n"])) % 360.0)
                if speed > 0 else None,
                "ell_major_m": est["ell_major_m"], "ell_minor_m": est["ell_minor_m"],
                "ell_azimuth_deg": est["ell_azimuth_deg"], "age_s": (now if at is None else when) - last_t,
                "flag": "predicted" if at is not None and when > last_t else FLAG_NAMES[est["flag"]],
                "last_fix_time": iso_time(last_t)}

    @app.get("/api/devices/{device_id:path}/track", responses={**_ERRORS, 200: {
                 "description": "the track in the chosen format",
                 "content": {m: {} for m in sorted({mt for mt, _ in FORMATS.values()})}}},
             dependencies=[Depends(api_key)], summary="Stored fixes with their estimates, or the smoothed track")
    async def track(device_id: str,
                    from_: Optional[str] = Query(None, alias="from", description="first time (ISO 8601 or epoch s)"),
                    to: Optional[str] = Query(None, description="last time (ISO 8601 or epoch s)"),
                    smooth: bool = Query(False, description="the fixed-interval (RTS) smoother over the stored "
                                                            "fixes, as mptrack track --smooth"),
                    format: Literal["json", "geojson", "gpx", "csv", "parquet"] = Query("json")):
        dev = device(device_id)
        t0 = None if from_ is None else _time_param(from_, "from")
        t1 = None if to is None else _time_param(to, "to")
        if t0 is not None and t1 is not None and t1 < t0:
            raise RequestError("to is before from", status=422, field="to")
        loop = asyncio.get_running_loop()
        rows = await loop.run_in_executor(None, server.store.fixes, dev, t0, t1)
        body, media = await loop.run_in_executor(None, track_body, device_id, rows, smooth, format)
        return Response(body, media_type=media)

    @app.get("/api/stream", dependencies=[Depends(api_key)], responses={200: {
                 "description": "Server-Sent Events, one `fix` event per accepted fix (JSON)",
                 "content": {"text/event-stream": {}}}},
             summary="Every accepted fix's estimate as it happens (Server-Sent Events)")
    async def stream(request: Request, device_id: Optional[str] = Query(None, alias="device",
                                                                        description="only this device")):
        queue = StreamQueue()
        ing = server.ingest

        async def events():
            ing.listen(queue)
            try:
                yield ": connected\n\n"
                while True:
                    try:
                        events = await asyncio.wait_for(queue.get(), 15.0)
                    except asyncio.TimeoutError:
                        yield ": keep-alive\n\n"
                        continue
                    text = "".join(f"event: fix\ndata: {line}\n\n" for dev, line in events
                                   if device_id is None or dev == device_id)
                    if text:
                        yield text
            finally:
                ing.listeners.discard(queue)

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    @app.get("/api/stats", response_model=Stats, dependencies=[Depends(api_key)], responses=_ERRORS,
             summary="What ingest accepted and refused since the server started (all its worker processes)")
    def stats():
        c = server.metrics.totals()
        return {"devices": server.ingest.device_counts(300.0)[0], "accepted": c["accepted"], "filtered": c["filtered"],
                "late": c["late"], "duplicates": c["duplicates"], "ahead": c["ahead"], "batches": c["batches"],
                "refused": c["refused"],
                "uptime_s": time.time() - server.started,
                "geolocate": None if server.geolocator is None else dict(server.geolocator.counters)}

    @app.get("/", response_class=HTMLResponse, dependencies=[Depends(api_key)], responses=_ERRORS,
             summary="The live map")
    def live_map(key: Optional[str] = Query(None)):
        from ..report import live_map_page

        return HTMLResponse(live_map_page(key=key))

    def openapi() -> dict:
        """The query API's description with the ingest routes merged in (GET / is both)."""
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, description=app.description,
                                 routes=app.routes)
            schema["paths"].update(ingest_paths())
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi
    return app


def _f(v) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _time_param(value: str, name: str, now: float | None = None, future_s: float = math.inf) -> float:
    """A time parameter of a query (by default any later time may bound one); 422 if it is not one."""
    try:
        return timestamp(value, name, now, future_s=future_s)
    except RequestError as exc:
        raise RequestError(exc.reason, status=422, field=name) from None
