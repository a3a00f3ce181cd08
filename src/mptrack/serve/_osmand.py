"""The OsmAnd protocol (Traccar's port 5055): what Traccar Client (Android, iOS), OsmAnd's online
tracking, GPSLogger's custom URL and many trackers send.

A GET with a query string, or a POST whose form body (``application/x-www-form-urlencoded``) holds
the same parameters::

    /?id=123456&timestamp=1767268800&lat=52.5&lon=13.4&speed=3.1&bearing=90&altitude=40&accuracy=8&batt=87

``id`` or ``deviceid``; ``lat``, ``lon`` or ``location=lat,lon``; ``timestamp`` in epoch seconds,
epoch milliseconds or ISO 8601 (the server's clock when absent); ``speed`` in knots; ``bearing`` or
``heading`` (degrees); ``altitude`` (m); ``accuracy`` (m); ``hdop``; ``batt``;
``cell=mcc,mnc,lac,cid[,rssi]`` and ``wifi=mac,rssi`` (both repeatable; a report with cells and no
position is placed from the server's cell table); any other parameter is kept as an attribute (a
number, true/false, or text).  ``key`` is the device's token (``--auth``), not
an attribute.  The answer is 200 with an empty body.
"""

from __future__ import annotations

import time
from urllib.parse import unquote_plus

from ..errors import RequestError
from ._fix import KNOT_MPS, device_id, fix, optional_number, position, timestamp

__all__ = ["parse_pairs", "parse_query", "TOKEN_PARAMETER"]

TOKEN_PARAMETER = "key"
_KNOWN = {"id", "deviceid", "timestamp", "lat", "lon", "location", "speed", "bearing", "heading", "altitude",
          "accuracy", "cell", "wifi", TOKEN_PARAMETER}
_SCALARS = _KNOWN - {"cell", "wifi"}   # the parameters a fix has at most once


MAX_FIELDS = 200


def parse_query(query: bytes | str, now: float | None = None) -> tuple[tuple, str | None]:
    """(fix, token) of one OsmAnd query string or form body (see the module doc)."""
    if isinstance(query, bytes):
        try:
            query = query.decode("utf-8")
        except UnicodeDecodeError:
            raise RequestError("the parameters are not UTF-8 text", code="malformed_body") from None
    parts = query.split("&")
    if len(parts) > MAX_FIELDS:
        raise RequestError(f"more than {MAX_FIELDS} parameters", code="malformed_body")
    if "%" in query or "+" in query:   # the rare encoded query; plain ones skip unquoting
        try:
            pairs = [(unquote_plus(name, errors="strict"), unquote_plus(value, errors="strict"))
                     for name, _, value in (part.partition("=") for part in parts if part)]
        except UnicodeDecodeError:
            raise RequestError("the parameters are not UTF-8 text", code="malformed_body") from None
    else:
        pairs = [part.partition("=")[::2] for part in parts if part]
    return parse_pairs(pairs, now)


def parse_pairs(pairs, now: float | None = None) -> tuple[tuple, str | None]:
    """(fix, token) of the (name, value) pairs of one OsmAnd request."""
    p = dict(pairs)
    cells, wifi, attrs = [], [], {}
    if not p.keys() <= _SCALARS:   # cells, Wi-Fi (repeatable) or attributes: sort them out
        p = {}
        for name, value in pairs:
            if name == "cell":
                cells.append(_cell(value))
            elif name == "wifi":
                wifi.append(_wifi(value))
            elif name in _KNOWN:
                p[name] = value
            else:
                attrs[name] = _attribute(value)
    dev_field = "id" if "id" in p else "deviceid"
    device = device_id(p.get(dev_field), "id")
    if "location" in p and "lat" not in p:
        parts = p["location"].split(",")
        if len(parts) != 2:
            raise RequestError(f"expected location=lat,lon, got {p['location']!r}", field="location")
        lat, lon = position(parts[0], parts[1], "location", "location")
    elif cells and not p.get("lat") and not p.get("lon"):
        lat = lon = None  # cells only: the server places the fix from its cell table
    else:
        lat, lon = position(p.get("lat"), p.get("lon"), "lat", "lon")
    now = time.time() if now is None else now
    t = timestamp(p["timestamp"], "timestamp", now) if p.get("timestamp") else now
    heading_field = "bearing" if "bearing" in p else "heading"
    if cells:
        attrs["cells"] = cells
    if wifi:
        attrs["wifi"] = wifi
    return fix(device, t, lat, lon,
               optional_number(p.get("accuracy"), "accuracy"),
               optional_number(p.get("speed"), "speed", scale=KNOT_MPS),
               optional_number(p.get(heading_field), heading_field),
               optional_number(p.get("altitude"), "altitude"),
               attrs), p.get(TOKEN_PARAMETER)


def _cell(value: str) -> list:
    parts = value.split(",")
    if not 4 <= len(parts) <= 5:
        raise RequestError(f"expected cell=mcc,mnc,lac,cid[,rssi], got {value!r}", field="cell")
    try:
        numbers = [int(x) for x in parts[:4]]
        rssi = [float(parts[4])] if len(parts) == 5 else []
    except ValueError:
        raise RequestError(f"expected cell=mcc,mnc,lac,cid[,rssi] as integers, got {value!r}", field="cell") from None
    return numbers + rssi


def _wifi(value: str) -> list:
    mac, sep, rssi = value.rpartition(",")
    if not sep:
        raise RequestError(f"expected wifi=mac,rssi, got {value!r}", field="wifi")
    try:
        level = float(rssi)
    except ValueError:
        raise RequestError(f"expected wifi=mac,rssi with rssi a number, got {value!r}", field="wifi") from None
    return [mac.replace("-", ":").lower(), level]


def _attribute(value: str):
    if value in ("true", "false"):
        return value == "true"
    try:
        x = float(value)
    except ValueError:
        return value
    if x != x or x in (float("inf"), float("-inf")):
        return value
    return int(x) if x.is_integer() and "." not in value and "e" not in value.lower() else x
