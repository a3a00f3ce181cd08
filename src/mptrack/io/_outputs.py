"""The output formats, both ways: every table written atomically (temporary file, then rename) and
read back (:func:`read_output`).

Every output is written beside its destination and renamed over it only when
complete (:func:`mptrack._core.files.atomic_path`), so an interrupted or failed run
never leaves a half-written result.  The format follows the suffix
(:data:`OUTPUT_FORMATS`):

* Parquet (``.parquet``, ``.pq``): the table as is.
* CSV: pyarrow's CSV writer (fields quoted only where needed, booleans as
  true/false, floats in shortest round-trip form), with datetime columns as
  ISO 8601 text ending in ``Z`` (:func:`iso_utc`), which the readers parse back
  to the same instants.
* GeoJSON (``.geojson``, ``.json``): one Feature per track with per-vertex
  arrays (:mod:`._geojson`).
* GPX (``.gpx``): one ``<trk>`` per track, the other columns in mptrack
  ``<extensions>`` (:mod:`._gpx`).
* GeoParquet (``.geoparquet``): Parquet plus a WKB point ``geometry`` column and
  the ``geo`` metadata (:mod:`._geoparquet`).

Each is read back (:func:`read_output`) as the Parquet output holds it (the same columns in the
same order, the same kinds): GeoJSON and GPX positions to 1e-7 degrees and GeoJSON's other floats
to its rounding, times to the precision written.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Iterable, Iterator

import pandas as pd

from .._core.files import atomic_path
from .._core.validation import check_path
from ..errors import DataError, MptrackError, ParameterError
from ._geojson import read_geojson, write_geojson
from ._geoparquet import GEOMETRY, write_geoparquet
from ._gpx import read_gpx, write_gpx
from ._text import ISO_Z, iso_utc

__all__ = ["OUTPUT_FORMATS", "output_format", "write_table", "read_output", "iso_utc"]

OUTPUT_FORMATS = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv", ".geojson": "geojson",
                  ".json": "geojson", ".gpx": "gpx", ".geoparquet": "geoparquet"}


def output_format(path) -> str:
    """The output format of a file from its suffix (:data:`OUTPUT_FORMATS`).

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    str
        "parquet", "csv", "geojson", "gpx" or "geoparquet".

    Raises
    ------
    ParameterError
        An unknown suffix; the message lists the known ones.
    """
    suffix = check_path("path", path).suffix.lower()
    if suffix not in OUTPUT_FORMATS:
        raise ParameterError(f"path: unknown output format {suffix!r}; expected one of "
                             f"{', '.join(sorted(OUTPUT_FORMATS))}")
    return OUTPUT_FORMATS[suffix]


def _csv_ready(table):
    """Timestamp columns of an Arrow table as ISO 8601 text with Z (what the readers parse back to
    the same instant)."""
    import pyarrow as pa

    for i, field in enumerate(table.schema):
        if pa.types.is_timestamp(field.type):
            values = table.column(i).to_numpy()
            table = table.set_column(i, field.name, pa.array(iso_utc(values), type=pa.string()))
    return table


def _tables(frames: Iterable) -> Iterator:
    """Arrow tables of the frames (pandas or pyarrow), each cast to the first one's schema."""
    import pyarrow as pa
    schema = None
    for df in frames:
        if not isinstance(df, (pa.Table, pd.DataFrame)):
            raise ParameterError(f"df: expected pandas DataFrames or pyarrow Tables, got {type(df).__name__}")
        if isinstance(df, pd.DataFrame) and df.attrs:   # a run's summaries (tables) are not file metadata:
            df = df.copy(deep=False)                     # pyarrow warns that it cannot store them
            df.attrs = {}
        table = df if isinstance(df, pa.Table) else pa.Table.from_pandas(df, preserve_index=False)
        schema = table.schema if schema is None else schema
        yield table.cast(schema)


def _write_arrow(tables: Iterable, open_writer, prepare=None) -> bool:
    """Stream Arrow tables into a pyarrow writer opened on the first one's schema; False if there
    was none."""
    writer = None
    try:
        for table in tables:
            table = prepare(table) if prepare else table
            if writer is None:
                writer = open_writer(table.schema)
            writer.write_table(table)
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


def _parquet_writer(path, schema):
    """pyarrow's Parquet writer with dictionary pages for text only (floats do not repeat: 2x faster)."""
    import pyarrow.parquet as pq

    return pq.ParquetWriter(path, schema, use_dictionary=_text_columns(schema))


def _write_parquet(tables: Iterable, path: Path) -> None:
    if not _write_arrow(tables, lambda schema: _parquet_writer(path, schema)):
        pd.DataFrame().to_parquet(path, index=False)


def _write_csv(tables: Iterable, path: Path) -> None:
    with open(path, "wb") as fh:
        _write_arrow(tables, lambda schema: _CsvWriter(fh, schema), _csv_ready)


def _write_geojson(tables: Iterable, path: Path) -> None:
    with open(path, "wb") as fh:
        write_geojson(tables, fh)


_WRITERS = {"parquet": _write_parquet, "csv": _write_csv, "geojson": _write_geojson, "gpx": write_gpx,
            "geoparquet": lambda tables, path: write_geoparquet(tables, path, _parquet_writer)}


def write_table(df, path) -> Path:
    """Write a table atomically as Parquet, CSV, GeoJSON, GPX or GeoParquet, chosen by the suffix.

    The file is complete on disk or absent: written to a temporary file beside it and renamed.

    Parameters
    ----------
    df : pandas.DataFrame, pyarrow.Table or iterable of them
        One table, or tables with the same columns (the rows of a track in one of them), streamed.
    path : str or path-like

    Returns
    -------
    pathlib.Path

    Raises
    ------
    OutputError
        The file cannot be written (the message names it and the cause).

    Examples
    --------
    >>> import pandas as pd
    >>> from mptrack.io import read_output, write_table
    >>> table = pd.DataFrame({"track_id": ["a", "a"], "lat": [45.0, 45.001], "lon": [13.0, 13.001]})
    >>> path = write_table(table, "points.geojson")
    >>> read_output(path)["lat"].tolist()
    [45.0, 45.001]
    """
    path = check_path("path", path)
    if not (isinstance(df, pd.DataFrame) or hasattr(df, "schema")) and (
            isinstance(df, (str, bytes)) or not hasattr(df, "__iter__")):
        raise ParameterError(f"df: expected a pandas DataFrame, a pyarrow Table or an iterable of them, "
                             f"got {type(df).__name__}")
    fmt = output_format(path)
    frames = [df] if isinstance(df, pd.DataFrame) or hasattr(df, "schema") else df
    with atomic_path(path) as tmp:
        _WRITERS[fmt](_tables(frames), tmp)
    return path


def _read_csv(path) -> pd.DataFrame:
    """CSV with the text columns whose every value is ISO 8601 with ``Z`` (how the writer puts times)
    as UTC times."""
    df = pd.read_csv(path, dtype={"track_id": str})
    for name in df.columns:
        col = df[name]
        if (pd.api.types.is_string_dtype(col) and col.notna().any()
                and col.dropna().str.fullmatch(ISO_Z).all()):
            df[name] = pd.to_datetime(col, format="ISO8601", utc=True).dt.as_unit("ns")
    return df


def _read_geoparquet(path) -> pd.DataFrame:
    df = pd.read_parquet(path)
    return df.drop(columns=[GEOMETRY]) if GEOMETRY in df.columns else df


def read_output(path) -> pd.DataFrame:
    """The table in an output file (by its suffix, as :func:`output_format`).

    Each format returns the table as the Parquet output holds it (the same columns in the same order, the
    same kinds): GeoJSON and GPX positions to 1e-7 degrees, GeoJSON's other floats to its rounding, times
    to the precision written; GeoParquet without its derived ``geometry`` column.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    pandas.DataFrame

    Raises
    ------
    DataError
        A missing, empty or unreadable file.
    """
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
