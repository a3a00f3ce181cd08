"""Reading back the outputs of :func:`mptrack.io.write_table`, one reader per format.

Each returns the table as the Parquet output holds it (the same columns in the
same order, the same kinds): GeoJSON and GPX positions to 1e-7 degrees and
GeoJSON's other floats to its rounding, times to the precision written.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pyarrow as pa

from .._validation import check_path
from ..errors import DataError, MptrackError

__all__ = ["read_output", "restore"]

_TYPES = {"float": pa.float64(), "int": pa.int64(), "bool": pa.bool_(), "string": pa.large_string()}
_ISO_Z = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z"


def restore(data: dict[str, list], kinds: dict[str, str | None], file=None) -> pd.DataFrame:
    """A DataFrame of column value lists (JSON values or XML text; None for missing), each column
    converted to its kind (float/int/bool/string/time; None: as pandas infers)."""
    columns = {}
    for name, values in data.items():
        kind = kinds.get(name)
        try:
            if kind == "time":
                columns[name] = pd.to_datetime(pd.Series(values, dtype=object), format="ISO8601",
                                               utc=True).dt.as_unit("ns")
            elif kind in _TYPES:
                columns[name] = pa.array(values).cast(_TYPES[kind]).to_pandas()
            else:
                columns[name] = pd.Series(values)
        except (ValueError, TypeError, pa.ArrowException) as exc:
            raise DataError(f"values are not of the kind {kind!r} the file declares: {exc}", file=file,
                            column=name) from None
    return pd.DataFrame(columns)


def _read_csv(path) -> pd.DataFrame:
    """CSV with the text columns whose every value is ISO 8601 with ``Z`` (how the writer puts times)
    as UTC times."""
    df = pd.read_csv(path, dtype={"track_id": str})
    for name in df.columns:
        col = df[name]
        if (pd.api.types.is_string_dtype(col) and col.notna().any()
                and col.dropna().str.fullmatch(_ISO_Z).all()):
            df[name] = pd.to_datetime(col, format="ISO8601", utc=True).dt.as_unit("ns")
    return df


def _read_geoparquet(path) -> pd.DataFrame:
    from ._geoparquet import GEOMETRY

    df = pd.read_parquet(path)
    return df.drop(columns=[GEOMETRY]) if GEOMETRY in df.columns else df


def read_output(path) -> pd.DataFrame:
    """The table in an output file (by its suffix, as :func:`mptrack.io.output_format`): Parquet, CSV,
    GeoJSON, GPX or GeoParquet (without its derived ``geometry`` column)."""
    from ._geojson import read_geojson
    from ._gpx_out import read_gpx
    from ._writers import output_format

    fmt = output_format(check_path("path", path))
    if not Path(path).is_file():
        raise DataError("file not found", file=path)
    readers = {"parquet": pd.read_parquet, "csv": _read_csv, "geojson": read_geojson, "gpx": read_gpx,
               "geoparquet": _read_geoparquet}
    if Path(path).stat().st_size == 0:
        raise DataError(f"cannot be read as {fmt}: the file is empty (0 bytes)", file=path)
    try:
        return readers[fmt](path)
    except MptrackError:
        raise
    except Exception as exc:  # pandas, pyarrow, json and XML parsers each raise their own types
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"cannot be read as {fmt}: {text}", file=path) from None
