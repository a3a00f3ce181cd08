"""GeoParquet output: the Parquet table plus a WKB point ``geometry`` column and the ``geo`` metadata.

Follows GeoParquet 1.1.0 (https://geoparquet.org/releases/v1.1.0/): the
``geometry`` column holds each row's position as a WKB Point (21 bytes: byte
order 1 = little-endian, geometry type 1, x = longitude, y = latitude as
float64), built with numpy; a row without a finite position has a null
geometry.  The file's ``geo`` metadata names ``geometry`` the primary column,
encoding WKB, geometry type Point and the bounding box of the positions; it
gives no ``crs``, which the specification defines as OGC:CRS84 (WGS 84
longitude/latitude, i.e. EPSG:4326 in x/y order).  Every other column is kept
as in the plain Parquet output, so ``geopandas.read_parquet`` returns a
GeoDataFrame and ``pandas.read_parquet`` the table plus ``geometry`` (bytes).
"""

from __future__ import annotations

import json
from typing import Iterable

import numpy as np
import pyarrow as pa

from ..errors import ParameterError

__all__ = ["GEOMETRY", "GEOPARQUET_VERSION", "wkb_points", "geo_metadata", "write_geoparquet"]

GEOMETRY = "geometry"
GEOPARQUET_VERSION = "1.1.0"

_WKB_POINT = np.dtype([("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8")])  # packed: 21 bytes


def wkb_points(lon, lat) -> pa.Array:
    """WKB Points (binary) of the positions; null where longitude or latitude is not finite."""
    lon = np.asarray(lon, np.float64)
    lat = np.asarray(lat, np.float64)
    ok = np.isfinite(lon) & np.isfinite(lat)
    points = np.zeros(len(lon), _WKB_POINT)
    points["order"], points["type"], points["x"], points["y"] = 1, 1, lon, lat
    points = points[ok]
    offsets = np.zeros(len(lon) + 1, np.int32)
    offsets[1:] = np.cumsum(np.where(ok, _WKB_POINT.itemsize, 0))
    validity = pa.array(ok).buffers()[1] if not ok.all() else None
    buffers = [validity, pa.py_buffer(offsets), pa.py_buffer(points.tobytes())]
    return pa.Array.from_buffers(pa.binary(), len(lon), buffers, null_count=int((~ok).sum()))


def geo_metadata(bbox: list[float] | None) -> bytes:
    """The ``geo`` file metadata (JSON) of a table whose primary column holds WKB points."""
    column = {"encoding": "WKB", "geometry_types": ["Point"]}
    if bbox is not None:
        column["bbox"] = bbox
    return json.dumps({"version": GEOPARQUET_VERSION, "primary_column": GEOMETRY,
                       "columns": {GEOMETRY: column}}).encode()


def write_geoparquet(tables: Iterable[pa.Table], path, open_parquet) -> None:
    """Write the tables (with ``lat``/``lon`` columns) with their geometry column through the Parquet
    writer ``open_parquet(path, schema)`` (no table: an empty geometry column)."""
    writer = None
    lo = np.full(2, np.inf)
    hi = np.full(2, -np.inf)
    try:
        for table in tables:
            missing = [c for c in ("lat", "lon") if c not in table.column_names]
            if missing:
                raise ParameterError(f"out: GeoParquet needs the columns lat and lon; the table has no "
                                     f"{' or '.join(missing)}")
            if GEOMETRY in table.column_names:
                raise ParameterError(f"out: GeoParquet adds the column {GEOMETRY!r}, which the table already has")
            lon = table.column("lon").to_numpy().astype(np.float64)
            lat = table.column("lat").to_numpy().astype(np.float64)
            table = table.append_column(pa.field(GEOMETRY, pa.binary()), wkb_points(lon, lat))
            ok = np.isfinite(lon) & np.isfinite(lat)
            if ok.any():
                lo = np.minimum(lo, [lon[ok].min(), lat[ok].min()])
                hi = np.maximum(hi, [lon[ok].max(), lat[ok].max()])
            if writer is None:
                writer = open_parquet(path, table.schema)
            writer.write_table(table)
        if writer is None:  # no rows: the geometry column alone
            writer = open_parquet(path, pa.schema([pa.field(GEOMETRY, pa.binary())]))
        bbox = [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])] if np.isfinite(lo).all() else None
        writer.add_key_value_metadata({"geo": geo_metadata(bbox)})
    finally:
        if writer is not None:
            writer.close()
