"""OwnTracks (Android, iOS) in HTTP mode: ``POST /pub`` with the app's JSON, as the OwnTracks
Recorder takes it.

The user and device come from ``?u=USER&d=DEVICE`` or the ``X-Limit-U`` / ``X-Limit-D`` headers the
app sends (the device id is ``USER/DEVICE``; with ``--auth``, HTTP Basic with the user
``USER/DEVICE`` and the device's token as password).  A ``_type=location`` message::

    {"_type": "location", "tst": 1440405601, "lat": 51.0626, "lon": 13.6028, "acc": 10, "alt": 262,
     "vel": 18, "cog": 82, "tid": "NE", "batt": 99}

``tst`` epoch seconds; ``acc``, ``alt`` metres; ``vel`` km/h; ``cog`` degrees; the rest is kept as
attributes.  Messages of other types (waypoints, transitions, cards, ...) are acknowledged and not
stored; an encrypted message (the app's payload encryption) is refused, as the server has no key, and
so is an object without ``_type`` (another app's body on this route is named with its own route).
The answer is ``[]`` (the app treats any status as delivered, so a refused message is also logged by
the server).
"""

from __future__ import annotations

from ..errors import RequestError
from ._fix import device_id, fix, optional_number, position, timestamp
from ._overland import is_batch
from ._traccar_json import load_json

__all__ = ["parse_body", "device_of", "is_message"]

_FIELDS = ("_type", "lat", "lon", "tst", "acc", "vel", "cog", "alt")


def device_of(user: str | None, device: str | None) -> str:
    """The device id ``USER/DEVICE`` (or ``USER`` alone)."""
    if not user:
        raise RequestError("the OwnTracks user is missing (?u= or the X-Limit-U header)", code="missing_field",
                           field="u")
    return device_id(f"{user}/{device}" if device else user, "u" if not device else "d")


def is_message(doc) -> bool:
    """Whether a JSON document is OwnTracks' (an object with ``_type``, or a list of them)."""
    first = doc[0] if isinstance(doc, list) and doc else doc
    return isinstance(first, dict) and "_type" in first


def parse_body(body: bytes, device: str, now: float | None = None) -> list[tuple]:
    """The location fixes of one OwnTracks body (an object, or a list of them) for ``device``."""
    doc = load_json(body)
    many = isinstance(doc, list)
    items = doc if many else [doc]
    fixes = []
    for i, msg in enumerate(items):
        where = f"[{i}]." if many else ""
        if not isinstance(msg, dict):
            raise RequestError(f"expected a JSON object with _type, got {type(msg).__name__}", code="malformed_json")
        if "_type" not in msg:
            raise _not_owntracks(msg, where)
        if msg.get("_type") == "encrypted":
            raise RequestError("an encrypted OwnTracks message: this server does not decrypt payloads; leave the "
                               "app's encryption key empty (HTTPS protects the connection)", code="encrypted",
                               field=f"{where}_type")
        if msg.get("_type") != "location":
            continue
        lat, lon = position(msg.get("lat"), msg.get("lon"), f"{where}lat", f"{where}lon")
        attrs = {k: v for k, v in msg.items() if k not in _FIELDS}
        fixes.append(fix(device, timestamp(msg.get("tst"), f"{where}tst", now), lat, lon,
                         optional_number(msg.get("acc"), f"{where}acc"),
                         optional_number(msg.get("vel"), f"{where}vel", scale=1.0 / 3.6, unknown_below=0.0),
                         optional_number(msg.get("cog"), f"{where}cog", unknown_below=0.0),
                         optional_number(msg.get("alt"), f"{where}alt"),
                         attrs))
    return fixes


def _not_owntracks(msg: dict, where: str) -> RequestError:
    """The refusal of an object without ``_type`` (acknowledged, it would be stored nowhere): another app's
    body on this route is named with the route it posts to."""
    if is_batch(msg):
        return RequestError("an Overland batch: Overland posts to / (set its receiver endpoint to this server's "
                            "address without /pub)", code="wrong_endpoint", field=f"{where}locations")
    if "device_id" in msg and "location" in msg:
        return RequestError("Traccar Client's JSON: Traccar Client posts to / (set its server URL to this server's "
                            "address without /pub)", code="wrong_endpoint", field=f"{where}location")
    return RequestError("not an OwnTracks message: every one has a _type (location, waypoint, ...)",
                        code="missing_field", field=f"{where}_type")
