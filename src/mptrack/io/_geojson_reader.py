"""GeoJSON (RFC 7946, read with the standard json module): timed Point and LineString features.

* A ``Point`` feature is one fix; its time is the property ``time``,
  ``timestamp``, ``datetime`` or ``date_time`` (any case), its track the property
  ``track_id``, ``track``, ``device`` or ``device_id`` (else the file's stem).
  Its other scalar properties become columns (snake_case names).
* A ``LineString`` (or ``MultiLineString``) feature is a track with one time per
  vertex: the property array ``times``/``time``/``timestamps``, ``coordTimes``
  (as toGeoJSON writes from GPX) or ``coordinateProperties.times``.  Every other
  property array with one value per vertex (``heart``, ``speed_mps``, ...)
  becomes a column.  Its track is ``track_id``, else ``name``, else
  ``line<feature number>``.

A third coordinate is ``elevation_m``.  Times are ISO 8601 text (read as UTC
when without zone) or numbers, which are passed on for the schema's unit
detection (epoch seconds or milliseconds).  Point features are grouped by track
in the order tracks first appear.

A Point without a time is a DataError naming the feature; LineStrings without
per-vertex times (a drawn route, or the track lines of mptrack's own output) and
other geometries are left out and reported as :class:`Skipped`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import DataError
from ._formats import Skipped, library_error, snake_case, unique_name

_TIME_KEYS = ("time", "timestamp", "datetime", "date_time")
_TIMES_KEYS = ("times", "time", "timestamps", "coordtimes")
_TRACK_KEYS = ("track_id", "track", "device", "device_id")


def read(path: Path, skipped: list) -> pd.DataFrame:
    try:
        with open(path, encoding="utf-8-sig") as fh:
            data = json.load(fh)
    except json.JSONDecodeError as exc:
        raise library_error("geojson", path, f"not valid JSON ({exc})") from None
    kind = data.get("type") if isinstance(data, dict) else type(data).__name__
    if kind == "FeatureCollection" and isinstance(data.get("features"), list):
        features = data["features"]
    elif kind == "Feature":
        features = [data]
    else:
        raise DataError(f"cannot be read as GeoJSON: expected a FeatureCollection or a Feature, got {kind!r}",
                        file=path)
    stem = path.stem
    points, lines, names, ignored, untimed = [], [], set(), {}, []
    for k, feature in enumerate(features, start=1):
        geometry = (feature or {}).get("geometry") or {}
        gtype = geometry.get("type")
        props = feature.get("properties") or {}
        if gtype == "Point":
            points.append(_point(k, geometry, props, stem, path))
        elif gtype in ("LineString", "MultiLineString"):
            frame = _line(k, geometry, props, path)
            if frame is None:
                untimed.append(k)
            else:
                frame.insert(0, "track_id", unique_name(str(_first(props, ("track_id",)) or props.get("name")
                                                            or f"line{k}"), names))
                lines.append(frame)
        else:
            ignored[gtype or "no geometry"] = ignored.get(gtype or "no geometry", 0) + 1
    if untimed:
        skipped.append(Skipped("GeoJSON line without per-vertex times", len(untimed),
                               f"{path}: {len(untimed)} LineString features without per-vertex times "
                               f"(first: feature {untimed[0]}); left out"))
    for gtype, n in ignored.items():
        skipped.append(Skipped(f"GeoJSON {gtype} feature", n, f"{path}: {n} {gtype} features left out "
                                                              "(only Point and LineString are fixes)"))
    frames = lines
    if points:
        pts = pd.DataFrame.from_records(points)
        order = pd.Index(pd.unique(pts["track_id"]))
        pts = pts.iloc[np.argsort(order.get_indexer(pts["track_id"]), kind="stable")]
        frames = [pts] + lines
    if not frames:
        raise DataError("no timed features: Point features need a time property (time, timestamp or "
                        "datetime), LineStrings a per-vertex time array (times or coordTimes)", file=path)
    df = pd.concat(frames, ignore_index=True)
    df["track_id"] = df["track_id"].astype("string")
    df["time"] = _times(df["time"], df.get("feature"), path)
    return df.drop(columns="feature")


def _point(k: int, geometry: dict, props: dict, stem: str, path) -> dict:
    time = _first(props, _TIME_KEYS)
    if time is None or time == "":
        raise DataError(f"feature {k} (a Point) has no time property ({', '.join(_TIME_KEYS)})", file=path,
                        column="time")
    coords = _coordinates(k, geometry, path)[0]
    row = {"track_id": str(_first(props, _TRACK_KEYS) or stem), "time": time, "lat": coords[1], "lon": coords[0]}
    if len(coords) > 2:
        row["elevation_m"] = coords[2]
    used = {key.lower() for key in _TIME_KEYS + _TRACK_KEYS}
    for key, value in props.items():
        if key.lower() not in used and (value is None or isinstance(value, (int, float, str))):
            row.setdefault(snake_case(key), value)
    row["feature"] = k
    return row


def _line(k: int, geometry: dict, props: dict, path) -> pd.DataFrame | None:
    coords = _coordinates(k, geometry, path)
    n = len(coords)
    arrays = {key: value for key, value in props.items() if isinstance(value, list)}
    nested = props.get("coordinateProperties")
    if isinstance(nested, dict):
        arrays.update({key: value for key, value in nested.items() if isinstance(value, list)})
    if geometry["type"] == "MultiLineString":  # toGeoJSON: one array per part
        arrays = {key: _flat(value) for key, value in arrays.items()}
    times_key = next((key for key in arrays if key.lower() in _TIMES_KEYS), None)
    if times_key is None:
        return None
    if len(arrays[times_key]) != n:
        raise DataError(f"feature {k} (a {geometry['type']}) has {n} vertices but {len(arrays[times_key])} "
                        f"times in {times_key!r}", file=path, column="time")
    cols = {"time": arrays[times_key], "lat": [c[1] for c in coords], "lon": [c[0] for c in coords]}
    if all(len(c) > 2 for c in coords):
        cols["elevation_m"] = [c[2] for c in coords]
    for key, value in arrays.items():
        if key != times_key and len(value) == n and all(v is None or isinstance(v, (int, float, str)) for v in value):
            cols.setdefault(snake_case(key), value)
    cols["feature"] = [k] * n
    return pd.DataFrame(cols)


def _coordinates(k: int, geometry: dict, path) -> list:
    """The positions of a Point / LineString / MultiLineString as a list of [lon, lat(, z)]."""
    coords = geometry.get("coordinates")
    if geometry["type"] == "Point":
        coords = [coords]
    elif geometry["type"] == "MultiLineString" and isinstance(coords, list):
        coords = _flat(coords)
    ok = isinstance(coords, list) and coords and all(
        isinstance(c, list) and len(c) >= 2 and all(isinstance(v, (int, float)) for v in c[:3]) for c in coords)
    if not ok:
        raise DataError(f"feature {k} (a {geometry['type']}) has no valid coordinates: expected "
                        "[longitude, latitude] numbers", file=path)
    return coords


def _flat(parts) -> list:
    return [v for part in parts for v in (part if isinstance(part, list) else [part])]


def _first(props: dict, keys: tuple):
    """The value of the first of ``keys`` (any case) among ``props``."""
    lower = {key.lower(): value for key, value in props.items()}
    return next((lower[key] for key in keys if lower.get(key) is not None), None)


def _times(values: pd.Series, feature, path) -> pd.Series:
    """ISO 8601 texts -> UTC datetimes (a bad one is a DataError naming its feature); numbers stay."""
    if pd.api.types.is_numeric_dtype(values):
        return values
    text = values.astype("string")
    parsed = pd.to_datetime(text, errors="coerce", utc=True, format="ISO8601")
    bad = parsed.isna().to_numpy() & text.notna().to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        if pd.to_numeric(values, errors="coerce").notna().all():
            return pd.to_numeric(values)
        raise DataError(f"feature {int(feature.iloc[i])}: time {values.iloc[i]!r} is not an ISO 8601 time stamp",
                        file=path, column="time")
    return parsed.astype("datetime64[ns, UTC]")
