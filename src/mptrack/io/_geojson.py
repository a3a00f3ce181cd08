"""GeoJSON output (RFC 7946): one Feature per track, its estimates as per-vertex arrays.

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
from ._text import column_kind, column_text, is_degrees, join, per_run, text, wrap, write_texts

__all__ = ["write_geojson", "read_geojson", "DECIMALS"]

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
    from ._outputs import restore

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
