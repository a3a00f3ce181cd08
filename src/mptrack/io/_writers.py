"""Writers for Parquet, CSV and GeoJSON, atomic (temporary file, then rename).

Every output is written beside its destination and renamed over it only when
complete (:func:`mptrack._io.atomic_path`), so an interrupted or failed run
never leaves a half-written result.

CSV goes through pyarrow's CSV writer (fields quoted only where needed,
booleans as true/false, floats in shortest round-trip form), with datetime
columns as ISO 8601 text ending in ``Z`` (:func:`iso_utc`), which the readers
parse back to the same instants.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np
import pandas as pd

from .._io import atomic_path
from ..errors import ParameterError

__all__ = ["OUTPUT_FORMATS", "output_format", "write_table", "geojson_features", "iso_utc"]

OUTPUT_FORMATS = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv", ".geojson": "geojson",
                  ".json": "geojson"}


def output_format(path) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in OUTPUT_FORMATS:
        raise ParameterError(f"out: unknown output format {suffix!r}; expected one of "
                             f"{', '.join(sorted(OUTPUT_FORMATS))}")
    return OUTPUT_FORMATS[suffix]


def _plain(value):
    """A JSON-safe scalar: NaN -> null, numpy -> Python, timestamps -> ISO 8601."""
    if value is None or value is pd.NaT:
        return None
    if isinstance(value, pd.Timestamp):
        return value.isoformat().replace("+00:00", "Z")
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(value) else float(value)
    return value if isinstance(value, (int, str)) else str(value)


def iso_utc(values) -> np.ndarray:
    """ISO 8601 text with a ``Z`` suffix of a datetime column (naive times are UTC), vectorised, at the
    coarsest of s / ms / us / ns that keeps every value exact ("2024-01-01T00:00:01.250Z"); NaT -> ""."""
    times = pd.Series(values)
    if times.dt.tz is not None:
        times = times.dt.tz_convert("UTC").dt.tz_localize(None)
    arr = times.to_numpy()
    nat = np.isnat(arr)
    unit = next((u for u in ("s", "ms", "us") if (arr[~nat].astype(f"datetime64[{u}]") == arr[~nat]).all()), "ns")
    text = np.datetime_as_string(arr, unit=unit, timezone="UTC")  # "...Z"
    text[nat] = ""
    return text


def _csv_ready(table):
    """Timestamp columns of an Arrow table as ISO 8601 text with Z (what the readers parse back to
    the same instant)."""
    import pyarrow as pa

    for i, field in enumerate(table.schema):
        if pa.types.is_timestamp(field.type):
            values = table.column(i).to_numpy()
            table = table.set_column(i, field.name, pa.array(iso_utc(values), type=pa.string()))
    return table


def geojson_features(df: pd.DataFrame, *, lat: str = "lat", lon: str = "lon") -> Iterator[dict]:
    """GeoJSON features of one track table: a LineString per track, then a Point per row.

    Coordinates are [longitude, latitude] (RFC 7946, WGS-84); every other column
    becomes a property of the point.
    """
    props = [c for c in df.columns if c not in (lat, lon)]
    for tid, grp in df.groupby("track_id", sort=False):
        coords = np.column_stack([grp[lon].to_numpy(float), grp[lat].to_numpy(float)])
        coords = coords[np.isfinite(coords).all(axis=1)]
        if len(coords) >= 2:
            yield {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords.tolist()},
                   "properties": {"track_id": str(tid), "kind": "track", "points": int(len(grp))}}
        records = grp[props].to_dict("records")
        for (x, y), rec in zip(zip(grp[lon].to_numpy(float), grp[lat].to_numpy(float)), records):
            geometry = {"type": "Point", "coordinates": [x, y]} if np.isfinite(x) and np.isfinite(y) else None
            yield {"type": "Feature", "geometry": geometry,
                   "properties": {"kind": "point", **{k: _plain(v) for k, v in rec.items()}}}


def _write_arrow(frames: Iterable, open_writer, prepare=None) -> bool:
    """Stream tables (pandas or pyarrow) into a pyarrow writer opened on the first one's schema;
    False if there was none."""
    import pyarrow as pa

    writer = schema = None
    try:
        for df in frames:
            table = df if isinstance(df, pa.Table) else pa.Table.from_pandas(df, preserve_index=False)
            table = prepare(table) if prepare else table
            if writer is None:
                schema, writer = table.schema, open_writer(table.schema)
            writer.write_table(table.cast(schema))
    finally:
        if writer is not None:
            writer.close()
    return writer is not None


def _text_columns(schema) -> list[str]:
    """The names of the string columns of an Arrow schema."""
    import pyarrow as pa

    return [f.name for f in schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)]


class _CsvWriter:
    """pyarrow's CSV writer with pandas' conventions: a plain header, and text quoted only in the chunks
    where some value holds a delimiter, quote or line break (arrow's "needed" quotes every string)."""

    def __init__(self, fh, schema) -> None:
        self.fh = fh
        line = io.StringIO()
        csv.writer(line, lineterminator="\n").writerow(schema.names)
        fh.write(line.getvalue().encode())
        self.text = _text_columns(schema)

    def write_table(self, table) -> None:
        import pyarrow.compute as pc
        import pyarrow.csv as pacsv

        quote = any(pc.any(pc.match_substring_regex(table[c], '[,"\r\n]')).as_py() for c in self.text)
        pacsv.write_csv(table, self.fh, pacsv.WriteOptions(include_header=False,
                                                           quoting_style="needed" if quote else "none"))

    def close(self) -> None:
        pass


def _write_parts(frames: Iterable[pd.DataFrame], tmp: Path, fmt: str) -> None:
    if fmt == "parquet":
        import pyarrow.parquet as pq

        def parquet_writer(schema):  # dictionary pages for text only: floats do not repeat (2x faster)
            return pq.ParquetWriter(tmp, schema, use_dictionary=_text_columns(schema))

        if not _write_arrow(frames, parquet_writer):
            pd.DataFrame().to_parquet(tmp, index=False)
    elif fmt == "csv":
        with open(tmp, "wb") as fh:
            _write_arrow(frames, lambda schema: _CsvWriter(fh, schema), _csv_ready)
    else:
        with open(tmp, "w") as fh:
            fh.write('{"type": "FeatureCollection", "features": [\n')
            first = True
            for df in frames:
                df = df if isinstance(df, pd.DataFrame) else df.to_pandas()
                for feat in geojson_features(df):
                    fh.write(("" if first else ",\n") + json.dumps(feat, allow_nan=False))
                    first = False
            fh.write("\n]}\n")


def write_table(df, path) -> Path:
    """Write a table (pandas DataFrame or pyarrow Table), or an iterable of tables with the same
    columns, atomically as Parquet, CSV or GeoJSON, chosen by the file suffix."""
    path = Path(path)
    fmt = output_format(path)
    frames = [df] if isinstance(df, pd.DataFrame) or hasattr(df, "schema") else df
    with atomic_path(path) as tmp:
        _write_parts(frames, tmp, fmt)
    return path
