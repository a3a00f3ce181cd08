"""Traccar Client's JSON (the current Android/iOS app, built on Transistorsoft's background
geolocation; Dawarich and PhoneTrack take the same body): ``POST /`` with
``Content-Type: application/json``::

    {"device_id": "12345678",
     "location": {"timestamp": "2026-01-01T12:00:00Z",
                  "coords": {"latitude": 52.5, "longitude": 13.4, "accuracy": 8, "speed": 3.1,
                             "heading": 90, "altitude": 40},
                  "is_moving": true, "odometer": 1234, "battery": {"level": 0.87, "is_charging": false},
                  "activity": {"type": "in_vehicle"}, "extras": {}}}

``location`` may be a list of such objects.  Speed is in m/s; a negative speed, heading or accuracy
means "unknown".  Everything outside ``coords`` and ``timestamp`` is kept as attributes.
"""

from __future__ import annotations

import orjson

from ..errors import RequestError
from ._fix import device_id, fix, optional_number, position, timestamp

__all__ = ["parse_body", "parse_document", "load_json"]


def parse_body(body: bytes, now: float | None = None) -> list[tuple]:
    """The fixes of one JSON body (see the module doc)."""
    return parse_document(load_json(body), now)


def load_json(body: bytes):
    """The JSON document of a body (orjson: NaN and Infinity, which are not JSON though Python writes them,
    and documents nested deeper than 1024 are refused, as any other malformed body)."""
    try:
        return orjson.loads(body)
    except orjson.JSONDecodeError as exc:
        raise RequestError(f"the body is not valid JSON: {exc}", code="malformed_json") from None


def parse_document(doc, now: float | None = None) -> list[tuple]:
    if not isinstance(doc, dict):
        raise RequestError(f"expected a JSON object with device_id and location, got {type(doc).__name__}",
                           code="malformed_json")
    device = device_id(doc.get("device_id"), "device_id")
    locations = doc.get("location")
    if locations is None:
        raise RequestError("the location is missing", code="missing_field", field="location")
    many = isinstance(locations, list)
    if not many:
        locations = [locations]
    if not locations:
        raise RequestError("the list of locations is empty", code="missing_field", field="location")
    return [_location(device, loc, f"location[{i}]" if many else "location", now) for i, loc in enumerate(locations)]


def _location(device: str, loc, where: str, now: float | None) -> tuple:
    if not isinstance(loc, dict):
        raise RequestError(f"expected an object, got {type(loc).__name__}", field=where)
    coords = loc.get("coords")
    if not isinstance(coords, dict):
        raise RequestError("expected an object with latitude and longitude", code="missing_field",
                           field=f"{where}.coords")
    lat, lon = position(coords.get("latitude"), coords.get("longitude"), f"{where}.coords.latitude",
                        f"{where}.coords.longitude")
    t = timestamp(loc.get("timestamp"), f"{where}.timestamp", now)
    attrs = {k: v for k, v in loc.items() if k not in ("coords", "timestamp")}
    extra = {k: v for k, v in coords.items()
             if k not in ("latitude", "longitude", "accuracy", "speed", "heading", "altitude")}
    if extra:
        attrs["coords"] = extra
    c = f"{where}.coords"
    return fix(device, t, lat, lon,
               optional_number(coords.get("accuracy"), f"{c}.accuracy", unknown_below=0.0),
               optional_number(coords.get("speed"), f"{c}.speed", unknown_below=0.0),
               optional_number(coords.get("heading"), f"{c}.heading", unknown_below=0.0),
               optional_number(coords.get("altitude"), f"{c}.altitude"),
               attrs)
