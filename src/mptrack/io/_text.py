"""Columns as text and back, vectorised (Arrow compute): the values of the GeoJSON and GPX writers, and
the columns their readers restore (:func:`restore`).

A column's *kind* (:func:`column_kind`) is what the readers restore it to:
"float", "int", "bool", "string" or "time".  :func:`column_text` turns a whole
column into one text per value (null where the value is missing or not finite),
escaped for JSON or XML; :func:`per_run` joins the texts of runs of rows into
one text per run.  No Python call runs per value (strings are escaped once per
distinct value).
"""

from __future__ import annotations

import json
import re
from xml.sax.saxutils import escape

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import DataError

__all__ = ["KINDS", "column_kind", "column_text", "per_run", "is_degrees", "text", "join", "wrap", "iso_utc",
           "write_texts", "restore", "ISO_Z"]

KINDS = ("float", "int", "bool", "string", "time")
#: The Arrow type each kind but "time" is restored to.
_TYPES = {"float": pa.float64(), "int": pa.int64(), "bool": pa.bool_(), "string": pa.large_string()}
#: An ISO 8601 time in UTC with ``Z``, as :func:`iso_utc` writes it.
ISO_Z = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z"

#: Columns in degrees (positions): written to 1e-7 degrees (about 1 cm) in GeoJSON and GPX.
_DEGREES = re.compile(r"(^|_)(lat|lon)$|_deg$")


def is_degrees(name: str) -> bool:
    """True for lat, lon and the columns named ``*_lat``, ``*_lon`` or ``*_deg``."""
    return bool(_DEGREES.search(name))


def column_kind(type_: pa.DataType) -> str:
    """The kind of an Arrow type: float, int, bool, time (timestamps) or string (text and anything else)."""
    if pa.types.is_dictionary(type_):
        return column_kind(type_.value_type)
    if pa.types.is_floating(type_):
        return "float"
    if pa.types.is_integer(type_):
        return "int"
    if pa.types.is_boolean(type_):
        return "bool"
    if pa.types.is_timestamp(type_):
        return "time"
    return "string"


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


def text(value) -> pa.Scalar:
    """A large_string scalar (the type of every text column here; Arrow's kernels do not mix string types)."""
    return pa.scalar(value, pa.large_string())


def join(*parts, sep: str = "", skip: bool = False) -> pa.Array:
    """Element-wise concatenation of text columns and constants (str), ``sep`` between them; a null part
    makes the result null, or with ``skip`` is left out."""
    parts = [text(p) if isinstance(p, str) else p for p in parts]
    return pc.binary_join_element_wise(*parts, text(sep), null_handling="skip" if skip else "emit_null")


def wrap(before: str, values, after: str) -> pa.Array:
    """``before + value + after`` of every element (null stays null)."""
    return join(before, values, after)


def column_text(col, *, syntax: str, decimals: int | None = None) -> pa.Array:
    """Text of every value of an Arrow column (large_string; null where missing or not finite).

    syntax    "json": strings and times quoted and escaped; "xml": escaped for element text
    decimals  floats rounded to this many decimals (None: the shortest text that reads back the
              same float64)

    Times are ISO 8601 in UTC with ``Z`` at the coarsest of s/ms/us/ns that keeps every value exact
    (naive times are taken as UTC).
    """
    col = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
    if pa.types.is_dictionary(col.type):
        col = col.dictionary_decode()
    kind = column_kind(col.type)
    if kind == "float":
        x = col.to_numpy(zero_copy_only=False).astype(np.float64)
        ok = np.isfinite(x)
        out = pc.cast(pa.array(x if decimals is None else np.round(x, decimals), mask=~ok), pa.large_string())
    elif kind in ("int", "bool"):
        out = pc.cast(col, pa.large_string())
    elif kind == "time":
        iso = iso_utc(col.to_numpy(zero_copy_only=False))
        out = pa.array(iso, type=pa.large_string(), mask=iso == "")
        if syntax == "json":
            out = wrap('"', out, '"')
    else:
        if not (pa.types.is_string(col.type) or pa.types.is_large_string(col.type)):
            col = pc.cast(col, pa.large_string())
        encoded = pc.dictionary_encode(col)
        quote = (lambda v: json.dumps(v, ensure_ascii=False)) if syntax == "json" else escape
        words = pa.array([quote(v) for v in encoded.dictionary.to_pylist()], type=pa.large_string())
        out = pc.take(words, encoded.indices)
    return out.cast(pa.large_string())


def per_run(values, offsets: np.ndarray, sep: str = ",") -> pa.Array:
    """One text per run of rows (run r is rows offsets[r]:offsets[r+1]): the run's texts joined by ``sep``."""
    lists = pa.LargeListArray.from_arrays(pa.array(offsets, pa.int64()), values)
    return pc.binary_join(lists, text(sep))


def write_texts(fh, values) -> None:
    """Write the texts of a large_string array one after the other, as UTF-8, from Arrow's buffer
    (no Python string per value); null elements write nothing."""
    if not len(values):
        return
    offsets = np.frombuffer(values.buffers()[1], np.int64)[values.offset:values.offset + len(values) + 1]
    fh.write(memoryview(values.buffers()[2])[int(offsets[0]):int(offsets[-1])])


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
