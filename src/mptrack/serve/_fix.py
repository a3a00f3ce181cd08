"""One accepted fix as the protocols hand it on, and the checks of its fields (one way per check).

Every client format (OsmAnd query, Traccar Client JSON, OwnTracks JSON, bulk files) is parsed into
the same record, a tuple in the order of :data:`FIELDS`:

    device       the device id (str, :data:`DEVICE_ID`)
    t            the fix time, seconds since 1970-01-01 UTC (float)
    lat, lon     WGS-84 degrees
    accuracy_m   1-sigma horizontal accuracy the device reports (m), or None
    speed_mps, heading_deg, altitude_m   as reported (converted to these units), or None
    attrs        everything else the client sent (battery, cells, Wi-Fi, ...), a dict or None

A field that cannot be accepted raises :class:`mptrack.errors.RequestError` naming it as the client
sent it, with the HTTP status the server answers.
"""

from __future__ import annotations

import math
import re
import time
from datetime import datetime, timezone

from ..errors import RequestError

__all__ = ["FIELDS", "DEVICE_ID", "EARLIEST", "MAX_FUTURE_S", "device_id", "number", "optional_number", "latitude",
           "longitude", "position", "timestamp", "iso_time", "fix"]

FIELDS = ("device", "t", "lat", "lon", "accuracy_m", "speed_mps", "heading_deg", "altitude_m", "attrs")
#: Device ids: 1 to 64 letters, digits and ``. _ : @ / + -`` (IMEIs, names, OwnTracks' user/device).
DEVICE_ID = re.compile(r"[A-Za-z0-9._:@/+\-]{1,64}")
#: The earliest fix time accepted (2000-01-01 UTC): devices without a clock send 1970 or 1980.
EARLIEST = 946684800.0
#: How far ahead of the server's clock a fix time may be (s).
MAX_FUTURE_S = 86400.0
KNOT_MPS = 1852.0 / 3600.0


def device_id(value, field: str) -> str:
    if value is None or value == "":
        raise RequestError("the device id is missing", code="missing_field", field=field)
    if not isinstance(value, str):
        value = str(value) if isinstance(value, int) and not isinstance(value, bool) else None
    if value is None or not DEVICE_ID.fullmatch(value):
        raise RequestError("a device id is 1 to 64 letters, digits and . _ : @ / + - (got "
                           f"{_shown(value)})", field=field)
    return value


def number(value, field: str) -> float:
    """A finite number (a JSON number or its text)."""
    if isinstance(value, bool) or value is None:
        raise RequestError(f"expected a number, got {_shown(value)}", field=field)
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise RequestError(f"expected a number, got {_shown(value)}", field=field) from None
    if not math.isfinite(x):
        raise RequestError(f"expected a finite number, got {_shown(value)}", field=field)
    return x


def optional_number(value, field: str, *, scale: float = 1.0, unknown_below: float | None = None) -> float | None:
    """A number, or None when absent or empty; values below ``unknown_below`` mean "unknown" (None)."""
    if value is None or value == "":
        return None
    x = number(value, field)
    if unknown_below is not None and x < unknown_below:
        return None
    return x * scale


def latitude(value, field: str) -> float:
    x = number(value, field)
    if not -90.0 <= x <= 90.0:
        raise RequestError(f"a latitude is between -90 and 90 degrees, got {_shown(value)}", field=field)
    return x


def longitude(value, field: str) -> float:
    x = number(value, field)
    if not -180.0 <= x <= 180.0:
        raise RequestError(f"a longitude is between -180 and 180 degrees, got {_shown(value)}", field=field)
    return x


def position(lat, lon, lat_field: str, lon_field: str) -> tuple[float, float]:
    """(lat, lon), both present and in range; (0, 0) is refused (what devices without a fix send)."""
    if lat is None or lat == "":
        raise RequestError("the latitude is missing", code="missing_field", field=lat_field)
    if lon is None or lon == "":
        raise RequestError("the longitude is missing", code="missing_field", field=lon_field)
    la, lo = latitude(lat, lat_field), longitude(lon, lon_field)
    if la == 0.0 and lo == 0.0:
        raise RequestError("(0, 0) is what a device without a position fix sends", field=f"{lat_field}, {lon_field}")
    return la, lo


def timestamp(value, field: str, now: float | None = None, future_s: float = MAX_FUTURE_S) -> float:
    """Seconds since 1970 UTC from epoch seconds, epoch milliseconds (values above 1e11) or ISO 8601
    (``2026-01-01T12:00:00Z``, an offset, or ``2026-01-01 12:00:00``; no zone means UTC; an offset's "+" sent
    unencoded in a URL, read as a space, is taken for what it was); between
    2000-01-01 and ``future_s`` after the server's clock ``now``."""
    now = time.time() if now is None else now
    if value is None or value == "":
        raise RequestError("the time is missing", code="missing_field", field=field)
    t = None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        t = float(value)
    elif isinstance(value, str):
        try:
            t = float(value)
        except ValueError:
            t = _iso(value)
    if t is None or not math.isfinite(t):
        raise RequestError(f"expected epoch seconds, epoch milliseconds or an ISO 8601 time, got {_shown(value)}",
                           field=field)
    if abs(t) > 1e11:
        t /= 1000.0
    if not EARLIEST <= t <= now + future_s:
        when = iso_time(t) if abs(t) < 2.5e11 else _shown(value)
        ahead = "more than a day after the server's clock" if future_s == MAX_FUTURE_S else "too far ahead"
        raise RequestError(f"the time {when} is before 2000 or {ahead} (a device without a clock, or seconds "
                           "and milliseconds mixed up)", field=field)
    return t


def iso_time(t: float) -> str:
    """Seconds since 1970 as ISO 8601 UTC with milliseconds (``2026-01-01T12:00:00.000Z``)."""
    return datetime.fromtimestamp(t, timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


#: an ISO 8601 time whose offset's "+" became a space: an unencoded "+02:00" in a URL's query or a form
_LOST_PLUS = re.compile(r"(.*\d:\d\d(?:\.\d+)?) (\d\d(?::?\d\d)?)")


def _iso(text: str) -> float | None:
    text = text.strip()
    lost = _LOST_PLUS.fullmatch(text)
    try:
        d = datetime.fromisoformat(f"{lost[1]}+{lost[2]}" if lost else text)
    except ValueError:
        return None
    if d.tzinfo is None:
        d = d.replace(tzinfo=timezone.utc)
    return d.timestamp()


def fix(device, t, lat, lon, accuracy_m=None, speed_mps=None, heading_deg=None, altitude_m=None, attrs=None) -> tuple:
    """The record of one fix (see the module doc); accuracy must be positive where given."""
    if accuracy_m is not None and not accuracy_m > 0.0:
        accuracy_m = None  # 0 or negative: the device does not know (Transistorsoft sends -1)
    return (device, t, lat, lon, accuracy_m, speed_mps, heading_deg, altitude_m, attrs or None)


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
