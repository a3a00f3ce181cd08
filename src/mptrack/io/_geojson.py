"""GeoJSON, both ways: timed Point and LineString features read as position fixes (:func:`read`) and
the output of one Feature per track (:func:`write_geojson`, read back by :func:`read_geojson`).

Reading position fixes
----------------------
GeoJSON (RFC 7946, read with the standard json module): timed Point and LineString features.

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


The output
----------
GeoJSON output (RFC 7946): one Feature per track, its estimates as per-vertex arrays.

A FeatureCollection with one Feature per track (per run of rows with a finite
position, see below): a ``LineString`` whose coordinates are the track's
[longitude, latitude] rounded to 1e-7 degrees (a track of one point is a
``Point``), and every other column in ``properties``: a single value when it
is the same at every vertex of the feature (``track_id``, ``method``,
``origin_lat``, ...), else an array with one value per vertex.  Times are
ISO 8601 text in UTC (``Z``), degrees (columns named lat, lon, ``*_lat``,
``*_lon``, ``*_deg``) have 7 decimals, other floats :data:`DECIMALS`, and
missing or non-finite values are ``null``.

Rows whose position is not finite (local x/y input, or a missing estimate)
cannot be vertices: a track is split there into features of consecutive rows,
and a run of rows without a position is a feature with ``"geometry": null``
whose ``lat`` and ``lon`` are in its properties.  The features of a track are
consecutive, in row order.

The collection's foreign member ``"columns"`` maps every column, in order, to
its kind (float, int, bool, string, time), so :func:`read_geojson` returns the
table as written.  The text is built column by column with Arrow's string
kernels (no Python object per point).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import DataError
from ._formats import Skipped, library_error, snake_case, unique_name
from ._text import column_kind, column_text, is_degrees, join, per_run, restore, text, wrap, write_texts

__all__ = ["read", "write_geojson", "read_geojson", "DECIMALS"]

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


#: Decimals of the floats that are not degrees (metres, seconds, m/s, m^2, ...): 1 micro-unit.
DECIMALS = 6
#: Decimals of degrees: 1e-7 degrees is about 1 cm.
DEGREE_DECIMALS = 7


def write_geojson(tables: Iterable[pa.Table], fh) -> None:
    """Write Arrow tables with the same columns (the rows of a track contiguous, not split between
    tables) to the binary file ``fh`` as one FeatureCollection."""
    started = False
    for table in tables:
        if not started:
            kinds = {name: column_kind(table.schema.field(name).type) for name in table.column_names}
            fh.write(('{"type":"FeatureCollection","columns":' + json.dumps(kinds, ensure_ascii=False)
                      + ',"features":[\n').encode())
        if table.num_rows:
            write_texts(fh, _features(table, first=not started))
        started = True
    fh.write(b'{"type":"FeatureCollection","features":[\n' if not started else b"")
    fh.write(b"\n]}\n")


def _features(table: pa.Table, first: bool) -> pa.Array:
    """The text of each feature of ``table``, preceded by ",\\n" (but the very first of the file)."""
    n = table.num_rows
    names = table.column_names
    lat = _floats(table, "lat")
    lon = _floats(table, "lon")
    located = np.isfinite(lat) & np.isfinite(lon)
    if "track_id" in names:
        ids = pc.dictionary_encode(table.column("track_id").combine_chunks()).indices
        ids = pc.fill_null(ids, -1).to_numpy(zero_copy_only=False)
    else:
        ids = np.zeros(n, np.int64)
    starts = np.flatnonzero(np.r_[True, (ids[1:] != ids[:-1]) | (located[1:] != located[:-1])])
    offsets = np.r_[starts, n].astype(np.int64)
    counts = np.diff(offsets)
    run_located = located[starts]

    coords = join("[", _degrees(lon), ",", _degrees(lat), "]")
    line = wrap('{"type":"LineString","coordinates":[', per_run(coords, offsets), "]}")
    point = wrap('{"type":"Point","coordinates":', pc.take(coords, pa.array(starts)), "}")
    geometry = pc.if_else(pa.array(~run_located), text("null"), pc.if_else(pa.array(counts == 1), point, line))

    props = []
    for name in names:
        key = json.dumps(name, ensure_ascii=False) + ":"
        if name in ("lat", "lon"):
            # only in features without a geometry, and there always per vertex (the vertex count)
            values = pc.fill_null(_degrees(lat if name == "lat" else lon), text("null"))
            value = _values(values, starts, offsets, const=counts == 1)
            props.append(pc.if_else(pa.array(run_located), text(None), wrap(key, value, "")))
            continue
        values = column_text(table.column(name), syntax="json",
                             decimals=DEGREE_DECIMALS if is_degrees(name) else DECIMALS)
        props.append(wrap(key, _values(pc.fill_null(values, text("null")), starts, offsets), ""))
    properties = join(*props, sep=",", skip=True) if props else pa.array([""] * len(starts), pa.large_string())
    head = np.full(len(starts), ',\n{"type":"Feature","geometry":', dtype=object)
    head[0] = head[0][2:] if first else head[0]
    return join(pa.array(head, pa.large_string()), geometry, ',"properties":{', properties, "}}")


def _floats(table: pa.Table, name: str) -> np.ndarray:
    if name not in table.column_names:
        return np.full(table.num_rows, np.nan)
    return table.column(name).to_numpy().astype(np.float64)


def _degrees(x: np.ndarray) -> pa.Array:
    return column_text(pa.array(x), syntax="json", decimals=DEGREE_DECIMALS)


def _values(values, starts: np.ndarray, offsets: np.ndarray, const: np.ndarray | None = None) -> pa.Array:
    """Per run: its single value where every row has the same text (or where ``const``), else a JSON
    array of its values."""
    if const is None:
        eq = pc.equal(values[1:], values[:-1]).to_numpy(zero_copy_only=False)
        changed = np.r_[False, ~eq.astype(bool)]
        changed[starts] = False
        const = np.add.reduceat(changed, starts) == 0
    array = wrap("[", per_run(values, offsets), "]")
    return pc.if_else(pa.array(const), pc.take(values, pa.array(starts)), array)


def read_geojson(path) -> pd.DataFrame:
    """The table of a GeoJSON file written by :func:`write_geojson` (columns, kinds and row order as
    written; positions to 1e-7 degrees, other floats to :data:`DECIMALS` decimals)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        features = doc["features"]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise DataError(f"cannot be read as a GeoJSON FeatureCollection: {exc}", file=path) from None
    kinds = doc.get("columns")
    if not isinstance(kinds, dict):  # not written by mptrack: the properties of the first feature
        first = features[0].get("properties") or {} if features else {}
        kinds = dict.fromkeys([*first, "lat", "lon"])
    data = {name: [] for name in kinds}
    for i, feature in enumerate(features):
        geometry = feature.get("geometry")
        props = feature.get("properties") or {}
        if geometry:
            coords = [geometry["coordinates"]] if geometry["type"] == "Point" else geometry["coordinates"]
            xy = np.asarray(coords, dtype=float).reshape(-1, 2)
            props = dict(props, lon=xy[:, 0].tolist(), lat=xy[:, 1].tolist())
            count = len(xy)
        else:
            count = max((len(v) for v in props.values() if isinstance(v, list)), default=1)
        for name, values in data.items():
            value = props.get(name)
            if isinstance(value, list) and len(value) != count:
                raise DataError(f"feature {i + 1}: property {name!r} has {len(value)} values for {count} vertices",
                                file=path)
            values.extend(value if isinstance(value, list) else [value] * count)
    return restore(data, kinds, file=path)
