"""Overland (Aaron Parecki's GPS tracker for iOS, as its README and ``GLManager.m`` describe it):
``POST`` of a batch of GeoJSON points to the *Receiver Endpoint* the user sets,
``Content-Type: application/json``::

    {"locations": [{"type": "Feature",
                    "geometry": {"type": "Point", "coordinates": [-122.030581, 37.3318]},
                    "properties": {"timestamp": "2015-10-01T08:00:00-0700", "altitude": 0, "speed": 4,
                                   "course": 90, "horizontal_accuracy": 30, "vertical_accuracy": -1,
                                   "motion": ["driving"], "battery_level": 0.89, "device_id": "phone"}}],
     "current": {...}, "trip": {...}}

``speed`` m/s, ``course`` degrees, ``horizontal_accuracy`` m (iOS's radius of uncertainty), a negative
value meaning "unknown"; a negative ``vertical_accuracy`` means the altitude is not valid.  The
device is the point's ``device_id`` (the app's *Device ID*; absent when the setting is empty), else
the endpoint's ``?device=ID``, else the owner of the ``Authorization: Bearer`` token.  The app queues
its log entries (``properties.action``) and finished trips (``properties.type == "trip"``) with the
points: they are not positions and are not stored; ``current`` and ``trip`` repeat a point the
queue sends later.  The answer is ``{"result": "ok"}``: the app deletes the batch from its queue only
on that answer, and sends it again later on any other.
"""

from __future__ import annotations

from ..errors import RequestError
from ._fix import device_id, fix, optional_number, position, timestamp

__all__ = ["is_batch", "parse_document", "REPLY"]

#: The answer to a committed batch (the app keeps and resends a batch on any other).
REPLY = b'{"result":"ok"}'
_FIELDS = ("timestamp", "speed", "course", "horizontal_accuracy", "altitude", "device_id")


def is_batch(doc) -> bool:
    """Whether a JSON document posted to ``/`` is an Overland batch (Traccar Client's has ``location``)."""
    return isinstance(doc, dict) and "locations" in doc


def parse_document(doc: dict, device: str | None, now: float | None = None) -> list[tuple]:
    """The fixes of one batch (see the module doc); ``device``: the endpoint's or the token's device, for
    points without a ``device_id``."""
    locations = doc["locations"]
    if not isinstance(locations, list):
        raise RequestError(f"expected a list of GeoJSON points, got {type(locations).__name__}", field="locations")
    fixes = []
    for i, feature in enumerate(locations):
        where = f"locations[{i}]"
        props = feature.get("properties") if isinstance(feature, dict) else None
        if not isinstance(props, dict):
            raise RequestError("expected a GeoJSON Feature with properties", code="missing_field",
                               field=f"{where}.properties")
        if "action" in props or props.get("type") == "trip":
            continue  # the app's log entries and trip records: not positions
        fixes.append(_point(feature, props, where, device, now))
    return fixes


def _point(feature: dict, props: dict, where: str, device: str | None, now: float | None) -> tuple:
    geometry = feature.get("geometry")
    coords = geometry.get("coordinates") if isinstance(geometry, dict) else None
    if not isinstance(coords, list) or len(coords) < 2 or geometry.get("type") != "Point":
        raise RequestError("expected a GeoJSON Point with coordinates [longitude, latitude]", code="missing_field",
                           field=f"{where}.geometry")
    lat, lon = position(coords[1], coords[0], f"{where}.geometry.coordinates[1]", f"{where}.geometry.coordinates[0]")
    p = f"{where}.properties"
    named = props.get("device_id")
    if not named and device is None:
        raise RequestError("the device id is missing: set the Device ID in Overland's settings, or add ?device=ID "
                           "to the receiver endpoint", code="missing_field", field=f"{p}.device_id")
    dev = device_id(named, f"{p}.device_id") if named else device
    altitude = optional_number(props.get("altitude"), f"{p}.altitude")
    vertical = optional_number(props.get("vertical_accuracy"), f"{p}.vertical_accuracy")
    if vertical is not None and vertical < 0.0:
        altitude = None  # iOS: a negative vertical accuracy means the altitude is not valid
    attrs = {k: v for k, v in props.items() if k not in _FIELDS}
    return fix(dev, timestamp(props.get("timestamp"), f"{p}.timestamp", now), lat, lon,
               optional_number(props.get("horizontal_accuracy"), f"{p}.horizontal_accuracy", unknown_below=0.0),
               optional_number(props.get("speed"), f"{p}.speed", unknown_below=0.0),
               optional_number(props.get("course"), f"{p}.course", unknown_below=0.0),
               altitude, attrs)
