"""Bulk ingest for gateways and replays: ``POST /api/fixes`` with NDJSON (one JSON object per line,
``Content-Type: application/x-ndjson``) or CSV (``text/csv``) in the columns ``mptrack track``
reads: the same names and unit detection (:class:`mptrack.io.ReadOptions`; ``columns``,
``time_unit``, ``time_format`` and ``coord_unit`` may be given as query parameters), any number of
devices (the track id column is the device id).  A recording as a file is read as ``mptrack track``
reads it (:data:`FILE_TYPES`: GPX, TCX, FIT, GeoJSON), with ``?device=ID``: a file is one device's
recording and names no device (its tracks' names are a ride's or a day's, or its file's).
``?device=ID`` also makes every fix of a CSV or NDJSON body that device's.  Times must be absolute
(epoch or ISO 8601) and positions geographic (lat/lon): the server keeps fixes on the globe.
"""

from __future__ import annotations

import contextlib
import io as _stdio
import re
import tempfile
import time
from pathlib import Path
from typing import Iterator

import numpy as np
import pandas as pd
import pyarrow as pa
from pyarrow import json as pa_json

from ..errors import DataError, MptrackError, RequestError
from ..io import FIXES, ReadOptions, ReadReport, read_table
from ._fix import DEVICE_ID, EARLIEST, MAX_FUTURE_S, device_id

__all__ = ["parse_body", "CONTENT_TYPES", "FILE_TYPES", "READ_PARAMETERS"]

#: Content types of recorded tracks as files -> the suffix ``mptrack track`` reads them by.
FILE_TYPES = {"application/gpx+xml": ".gpx", "application/vnd.garmin.tcx+xml": ".tcx", "application/vnd.ant.fit": ".fit",
              "application/geo+json": ".geojson"}
CONTENT_TYPES = {"application/x-ndjson": "ndjson", "application/ndjson": "ndjson", "application/jsonl": "ndjson",
                 "application/json-lines": "ndjson", "text/csv": "csv", **FILE_TYPES}
#: Query parameters of ``POST /api/fixes`` passed to :class:`mptrack.io.ReadOptions`.
READ_PARAMETERS = ("columns", "time_unit", "time_format", "coord_unit")
_PASSED = ("speed_mps", "heading_deg", "altitude_m")


def parse_body(body: bytes, kind: str, params: dict, now: float | None = None,
               notes: list[str] | None = None) -> list[tuple]:
    """The fixes of one bulk body (``kind``: "ndjson", "csv" or a file suffix of :data:`FILE_TYPES`), in
    the order of the body; ``notes``, if given, receives how it was read (the reader's notes: the time unit
    found, columns recognised or swapped), its options named as this route's query parameters."""
    now = time.time() if now is None else now
    device = params.get("device")
    if device is None and kind in FILE_TYPES.values():
        raise RequestError("a recording's file names no device: give it as ?device=ID", code="missing_field",
                           field="device")
    if device is not None:
        device = device_id(device, "device")
    try:
        read = ReadOptions(**{k: params[k] for k in READ_PARAMETERS if k in params})
    except MptrackError as exc:
        raise RequestError(str(exc), field=next((k for k in READ_PARAMETERS if str(exc).startswith(k)), None)) \
            from None
    report = ReadReport()
    try:
        with _readable(body, kind) as source:
            rows = read_table(source, FIXES, read=read, report=report)
    except DataError as exc:
        where = f"row {exc.row}: " if exc.row is not None else ""
        raise RequestError(f"{where}{_parameters(exc.reason)}", status=422, field=exc.column) from None
    except MptrackError as exc:
        raise RequestError(_parameters(str(exc)), status=422) from None
    if device is not None:
        rows["track_id"] = device
    if "lat" not in rows.columns:
        raise RequestError("the server needs geographic positions (lat/lon columns), not local x/y metres",
                           status=422, field="lat")
    if not pd.api.types.is_datetime64_any_dtype(rows["time"]):
        raise RequestError("the server needs absolute times (epoch seconds or milliseconds, or ISO 8601), "
                           "not seconds from an arbitrary start", status=422, field="time")
    t = rows["t"].to_numpy(dtype=float)
    bad = ~((t >= EARLIEST) & (t <= now + MAX_FUTURE_S))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise RequestError(f"row {int(rows['row'].iloc[i])}: the time {rows['time'].iloc[i]} is before 2000 or more "
                           "than a day after the server's clock", status=422, field="time")
    ids = rows["track_id"].to_numpy(dtype=object)
    for dev in pd.unique(ids):
        if not DEVICE_ID.fullmatch(str(dev)):
            i = int(np.flatnonzero(ids == dev)[0])
            raise RequestError(f"row {int(rows['row'].iloc[i])}: a device id is 1 to 64 letters, digits and "
                               f". _ : @ / + - (got {str(dev)[:40]!r}); ?device=ID names the device of every fix",
                               status=422, field="track_id")
    lat, lon = rows["lat"].to_numpy(dtype=float), rows["lon"].to_numpy(dtype=float)
    null = (lat == 0.0) & (lon == 0.0)
    if null.any():
        i = int(np.flatnonzero(null)[0])
        raise RequestError(f"row {int(rows['row'].iloc[i])}: (0, 0) is what a device without a position fix sends",
                           status=422, field="lat, lon")
    if notes is not None:
        notes.extend(_parameters(note) for note in report.notes)
    n = len(rows)
    cols = [[str(d) for d in ids], t.tolist(), lat.tolist(), lon.tolist(), _optional(rows, "accuracy_m", n)]
    cols += [_optional(rows, name, n) for name in _PASSED]
    cols.append(_attrs(rows, n))
    return list(zip(*cols))


#: a reading option in a reader's message, and the space before its value if a value follows (not a word of
#: the sentence: "set --time-unit ms" -> "?time_unit=ms", "set --time-unit if that is wrong" -> "?time_unit if")
_OPTION = re.compile(r"--(" + "|".join(n.replace("_", "-") for n in READ_PARAMETERS) +
                     r")( (?!(?:if|to|for|or|and)\b)(?=[\w%'.])|)")


def _parameters(message: str) -> str:
    """A reader's message with its command-line options named as this route's query parameters."""
    return _OPTION.sub(lambda m: f"?{m[1].replace('-', '_')}{'=' if m[2] else ''}", message)


@contextlib.contextmanager
def _readable(body: bytes, kind: str) -> Iterator[pd.DataFrame | Path]:
    """What :func:`mptrack.io.read_table` reads the body from: its table (NDJSON), or the body as a file of
    its format (CSV: read as ``mptrack track`` reads a CSV file, its delimiter and decimal mark sniffed) in
    a directory of its own, removed afterwards."""
    if not body.strip():
        raise RequestError("the body is empty", code="missing_field")
    if kind == "ndjson":
        yield _frame(body)
        return
    with tempfile.TemporaryDirectory(prefix="mptrack-upload-") as tmp:
        path = Path(tmp) / f"upload{'.csv' if kind == 'csv' else kind}"
        path.write_bytes(body)
        yield path


def _frame(body: bytes) -> pd.DataFrame:
    try:
        flat = _flat_ndjson(body)
        return flat if flat is not None else pd.read_json(_stdio.BytesIO(body), lines=True, dtype=False)
    except (ValueError, UnicodeDecodeError) as exc:
        raise RequestError(f"the body is not valid NDJSON (one JSON object per line): "
                           f"{str(exc).splitlines()[0][:200]}", code="malformed_body") from None


def _flat_ndjson(body: bytes) -> pd.DataFrame | None:
    """NDJSON of flat objects (numbers, text, true/false, null) read by Arrow's reader, ~2x faster than
    pandas'; None for anything else -- nested values, a column of mixed types, invalid JSON, and text
    that Arrow takes for times (it reads some ISO 8601 forms as instants) -- which pandas reads (the
    times as text, as everywhere else) or refuses, as before."""
    try:
        body.decode("utf-8")     # Arrow's reader lets text that is not UTF-8 through to its strings
        table = pa_json.read_json(_stdio.BytesIO(body))
        if table.num_rows != sum(1 for line in body.split(b"\n") if line.strip()):
            return None          # objects not one a line (Arrow reads two on a line, pandas refuses them)
        if not all(pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_string(t)
                   or pa.types.is_boolean(t) or pa.types.is_null(t) for t in table.schema.types):
            return None
        return table.to_pandas()
    except (UnicodeDecodeError, pa.ArrowException):
        return None


def _optional(rows: pd.DataFrame, name: str, n: int) -> list:
    if name not in rows.columns:
        return [None] * n
    values = pd.to_numeric(rows[name], errors="coerce").to_numpy(dtype=float)
    if name == "accuracy_m":
        values = np.where(values > 0.0, values, np.nan)
    return [None if v != v else v for v in values.tolist()]


def _attrs(rows: pd.DataFrame, n: int) -> list:
    extra = [c for c in rows.columns if c not in ("track_id", "time", "t", "row", "lat", "lon", "accuracy_m")
             and c not in _PASSED]
    if not extra:
        return [None] * n
    records = rows[extra].to_dict("records")
    return [{k: _plain(v) for k, v in r.items() if not (isinstance(v, float) and v != v) and v is not None} or None
            for r in records]


def _plain(v):
    return v.item() if isinstance(v, np.generic) else v if isinstance(v, (int, float, str, bool)) else str(v)
