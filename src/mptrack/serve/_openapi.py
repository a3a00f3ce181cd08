"""The OpenAPI description of the ingest routes (plain ASGI, so FastAPI does not see them), merged into
the query API's own at ``/openapi.json`` so that clients and fuzzers see the whole server."""

from __future__ import annotations

from ._bulk import FILE_TYPES

__all__ = ["ingest_paths"]

_ERROR = {"$ref": "#/components/schemas/Error"}
_ERRORS = {str(code): {"description": why, "content": {"application/json": {"schema": _ERROR}}}
           for code, why in ((400, "a field is missing or out of range (the error names it)"),
                             (401, "no or unknown device token (--auth)"), (403, "the token belongs to another device"),
                             (413, "the body is larger than the server takes"),
                             (415, "the content type is not one the route reads"),
                             (422, "a row of a bulk file cannot be accepted"),
                             (429, "the device sends faster than its rate limit"))}
_ERRORS["503"] = {"description": "the fixes could not be committed; nothing of the request is stored",
                  "content": {"application/json": {"schema": _ERROR}}}


def _q(name: str, description: str, kind: str = "string", **extra) -> dict:
    return {"name": name, "in": "query", "required": False, "description": description,
            "schema": {"type": kind, **extra}}


_OSMAND = [
    _q("id", "device id (or deviceid)"), _q("deviceid", "device id"),
    _q("lat", "latitude (degrees)", "number"), _q("lon", "longitude (degrees)", "number"),
    _q("location", "lat,lon (instead of lat and lon)"),
    _q("timestamp", "fix time: epoch seconds, epoch milliseconds or ISO 8601 (the server's clock if absent)"),
    _q("speed", "speed (knots)", "number"), _q("bearing", "course (degrees)", "number"),
    _q("heading", "course (degrees)", "number"), _q("altitude", "altitude (m)", "number"),
    _q("accuracy", "horizontal accuracy (m)", "number"), _q("hdop", "HDOP", "number"),
    _q("batt", "battery level (%)", "number"), _q("cell", "mcc,mnc,lac,cid[,rssi] (repeatable)"),
    _q("wifi", "mac,rssi (repeatable)"), _q("key", "the device's token (--auth)"),
]
_FORM = {"type": "object", "properties": {p["name"]: p["schema"] for p in _OSMAND}}
_COORDS = {"type": "object", "required": ["latitude", "longitude"], "properties": {
    k: {"type": "number"} for k in ("latitude", "longitude", "accuracy", "speed", "heading", "altitude")}}
_LOCATION = {"type": "object", "required": ["timestamp", "coords"],
             "properties": {"timestamp": {"type": "string"}, "coords": _COORDS}}
_TRACCAR = {"type": "object", "required": ["device_id", "location"], "properties": {
    "device_id": {"type": "string"},
    "location": {"oneOf": [_LOCATION, {"type": "array", "items": _LOCATION}]}}}
_OVERLAND_POINT = {"type": "object", "required": ["geometry", "properties"], "properties": {
    "type": {"type": "string", "enum": ["Feature"]},
    "geometry": {"type": "object", "properties": {"type": {"type": "string", "enum": ["Point"]}, "coordinates": {
        "type": "array", "items": {"type": "number"}, "description": "[longitude, latitude]"}}},
    "properties": {"type": "object", "required": ["timestamp"], "properties": {
        "timestamp": {"type": "string"}, "device_id": {"type": "string"},
        **{k: {"type": "number"} for k in ("horizontal_accuracy", "speed", "course", "altitude", "vertical_accuracy")},
        "action": {"type": "string", "description": "an app log entry: not stored"}}}}}
_OVERLAND = {"type": "object", "required": ["locations"], "properties": {
    "locations": {"type": "array", "items": _OVERLAND_POINT}, "current": _OVERLAND_POINT, "trip": {"type": "object"}}}
_OWNTRACKS = {"type": "object", "required": ["_type"], "properties": {
    "_type": {"type": "string"}, "lat": {"type": "number"}, "lon": {"type": "number"}, "tst": {"type": "integer"},
    "acc": {"type": "number"}, "alt": {"type": "number"}, "vel": {"type": "number"}, "cog": {"type": "number"},
    "tid": {"type": "string"}}}


_INT = {"type": "integer"}
_TOWER = {"type": "object", "properties": {
    "radioType": {"type": "string", "enum": ["gsm", "wcdma", "lte", "nr", "cdma"]},
    "mobileCountryCode": _INT, "mobileNetworkCode": _INT, "locationAreaCode": _INT, "cellId": _INT,
    "newRadioCellId": _INT, "signalStrength": {"type": "number", "description": "dBm (0: unknown)"},
    "timingAdvance": _INT, "age": {"type": "integer", "description": "milliseconds"}}}
_GEOLOCATE = {"type": "object", "properties": {
    "radioType": {"type": "string", "enum": ["gsm", "wcdma", "lte", "nr", "cdma"]}, "considerIp": {"type": "boolean"},
    "cellTowers": {"type": "array", "items": _TOWER},
    "wifiAccessPoints": {"type": "array", "items": {"type": "object"}, "description": "accepted, not used"},
    "fallbacks": {"type": "object", "properties": {"lacf": {"type": "boolean"}, "ipf": {"type": "boolean"}}}}}
_POSITION = {"type": "object", "required": ["location", "accuracy"], "properties": {
    "location": {"type": "object", "properties": {"lat": {"type": "number"}, "lng": {"type": "number"}}},
    "accuracy": {"type": "number", "description": "radius (m) holding the true position with probability 68 %"},
    "fallback": {"type": "string", "enum": ["lacf"]}}}
_GOOGLE_ERROR = {"type": "object", "properties": {"error": {"type": "object", "properties": {
    "errors": {"type": "array", "items": {"type": "object", "properties": {
        "domain": {"type": "string"}, "reason": {"type": "string"}, "message": {"type": "string"}}}},
    "code": {"type": "integer"}, "message": {"type": "string"}}}}}
_GEO_ERRORS = {str(code): {"description": why, "content": {"application/json": {"schema": _GOOGLE_ERROR}}}
               for code, why in ((400, "parseError: a field is malformed (named); keyInvalid: no or unknown API key "
                                       "(--auth)"),
                                 (404, "notFound: no cell of the request is known"),
                                 (413, "the body is larger than the server takes"))}


def ingest_paths() -> dict:
    """The OpenAPI ``paths`` of the ingest routes."""
    ok = {"description": "committed: every fix of the request is stored with its estimate"}
    return {
        "/": {
            "get": {"summary": "OsmAnd / Traccar Client fix (with a device id or a position), or the live map "
                               "(without)", "operationId": "osmand_get", "tags": ["ingest"], "parameters": _OSMAND,
                    "responses": {"200": {"description": "committed (empty body), or the map page (HTML)"},
                                  **_ERRORS}},
            "post": {"summary": "OsmAnd fix as a form body, Traccar Client JSON, or an Overland batch",
                     "operationId": "osmand_post", "tags": ["ingest"],
                     "parameters": [_q("key", "the device's token (--auth)"),
                                    _q("device", "Overland: the device of the points without a device_id")],
                     "requestBody": {"required": True, "content": {
                         "application/x-www-form-urlencoded": {"schema": _FORM},
                         "application/json": {"schema": {"oneOf": [_TRACCAR, _OVERLAND]}}}},
                     "responses": {"200": {
                         "description": ok["description"] + "; an Overland batch is answered {\"result\": \"ok\"}, "
                                                            "the others with an empty body",
                         "content": {"application/json": {"schema": {
                             "type": "object", "properties": {"result": {"type": "string", "enum": ["ok"]}}}}}},
                         **_ERRORS}},
        },
        "/pub": {"post": {
            "summary": "OwnTracks HTTP mode (user and device from ?u=&d= or X-Limit-U / X-Limit-D)",
            "operationId": "owntracks", "tags": ["ingest"],
            "parameters": [_q("u", "OwnTracks user"), _q("d", "OwnTracks device")],
            "requestBody": {"required": True, "content": {"application/json": {"schema": _OWNTRACKS}}},
            "responses": {"200": {"description": "accepted; the body is [] (OwnTracks' answer)",
                                  "content": {"application/json": {"schema": {"type": "array"}}}}, **_ERRORS}}},
        "/api/fixes": {"post": {
            "summary": "Bulk fixes of any number of devices: NDJSON or CSV in the columns mptrack track reads, or "
                       "one device's recording as a GPX, TCX, FIT or GeoJSON file",
            "operationId": "bulk", "tags": ["ingest"],
            "parameters": [_q("device", "the device of every fix (needed for a recording's file)"),
                           _q("columns", "which column is which, e.g. time=ts,lat=Latitude"),
                           _q("time_unit", "auto, s, ms, us or ns"), _q("time_format", "strftime layout of text times"),
                           _q("coord_unit", "auto, deg, deg-e7, deg-e6 or rad"), _q("key", "API key (--auth)")],
            "requestBody": {"required": True, "content": {
                **{t: {"schema": {"type": "string"}} for t in ("application/x-ndjson", "text/csv")},
                **{t: {"schema": {"type": "string", "format": "binary"}} for t in FILE_TYPES}}},
            "responses": {"200": {"description": "committed", "content": {"application/json": {"schema": {
                "type": "object", "properties": {"accepted": {"type": "integer"}, "notes": {
                    "type": "array", "items": {"type": "string"}, "description": "how the body was read: the "
                    "time unit found, the columns recognised or swapped (the query parameters that override)"}}}}}},
                **_ERRORS}}},
        "/v1/geolocate": {"post": {
            "summary": "Cell geolocation: Google's Geolocation API / Mozilla Ichnaea request and answer (needs "
                       "--cells)", "operationId": "geolocate", "tags": ["geolocation"],
            "parameters": [_q("key", "API key (--auth)")],
            "requestBody": {"required": False, "content": {"application/json": {"schema": _GEOLOCATE}}},
            "responses": {"200": {"description": "the position", "content": {"application/json": {
                "schema": _POSITION}}}, **_GEO_ERRORS}}},
        "/api/devices/{device_id}/cells": {"post": {
            "summary": "A device's cells (a geolocate body, optionally with a timestamp): placed from the cell "
                       "table, the position feeds the device's track", "operationId": "device_cells",
            "tags": ["ingest"],
            "parameters": [{"name": "device_id", "in": "path", "required": True, "schema": {"type": "string"}},
                           _q("key", "the device's token (--auth)")],
            "requestBody": {"required": True, "content": {"application/json": {"schema": {
                **_GEOLOCATE, "properties": {**_GEOLOCATE["properties"], "timestamp": {
                    "description": "time of the scan: epoch s or ms, or ISO 8601 (the server's clock if absent)"}}}}}},
            "responses": {"200": {"description": "committed; the position", "content": {"application/json": {
                "schema": _POSITION}}}, **_ERRORS, "404": {
                "description": "no cell of the request is known", "content": {"application/json": {
                    "schema": _ERROR}}}}}},
        "/healthz": {"get": {"summary": "200 when the server is ready", "operationId": "healthz", "tags": ["operations"],
                             "responses": {"200": {"description": "ready"}}}},
        "/metrics": {"get": {"summary": "Counters, latency and batch-size histograms, devices (Prometheus text format; "
                                        "the sums over the host's worker processes)", "operationId": "metrics",
                             "tags": ["operations"], "parameters": [{"name": "key", "in": "query", "required": False,
                                                                     "schema": {"type": "string"},
                                                                     "description": "API key (with --auth)"}],
                             "responses": {"200": {"description": "Prometheus text exposition format 0.0.4",
                                                   "content": {"text/plain": {"schema": {"type": "string"}}}},
                                           **{k: v for k, v in _ERRORS.items() if k == "401"}}}},
    }
