"""Schemas of the input tables and the row-level validation that enforces them.

Three kinds of input, each a table with one record per row:

* position fixes (GPS logs):       track_id, time, lat/lon (or x/y), accuracy_m
* cellular measurement logs:       track_id, time, cell_id, rss_dbm / range_m / ta
* cell tables (OpenCelliD layout): radio, mcc, net, area, cell, lon, lat, range, ...

A :class:`Schema` lists the columns with their unit and valid range; its
``markdown()`` renders the table used in docs/tracking.md.  Validation works on
one chunk at a time (so memory stays bounded) and either raises a
:class:`~mptrack.errors.DataError` naming file, row and column, or — with
``on_error="skip"`` — drops the bad rows and counts them in a :class:`ReadReport`.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._core.data_checks import ON_ERROR
from .._core.validation import _to_array
from ..errors import DataError, DTypeError, ParameterError, ShapeError
from ._interpret import MAX_SECONDS

__all__ = ["Column", "Schema", "ReadReport", "FIXES", "MEASUREMENTS", "CELLS", "ON_ERROR", "cell_key"]

#: Columns the readers add to every validated chunk (an input column of that name is not passed through).
RESERVED = ("t", "row")
_MAX_EXAMPLES = 20


@dataclass(frozen=True)
class Column:
    """One column: kind is "id" (text key), "time", "float" or "int"; lo/hi the valid closed range."""

    name: str
    kind: str
    unit: str
    description: str
    required: bool = True
    lo: float | None = None
    hi: float | None = None
    nullable: bool = False  # an optional column whose cells may be empty


@dataclass(frozen=True)
class Schema:
    """Columns of one input kind; ``one_of`` are groups of which at least one must be present."""

    name: str
    columns: tuple[Column, ...]
    one_of: tuple[tuple[str, ...], ...] = ()
    row_needs_one_of: tuple[str, ...] = ()  # per row, at least one of these must be non-empty
    mapped: bool = True  # its columns can be named with --columns (not the cell table's fixed layout)

    def extra_columns(self, columns) -> list[str]:
        """The columns of ``columns`` that are not the schema's (passed through to the output)."""
        names = {c.name for c in self.columns} | set(RESERVED)
        return [str(c) for c in columns if str(c) not in names]

    def column(self, name: str) -> Column:
        return next(c for c in self.columns if c.name == name)

    def markdown(self) -> str:
        """The schema as a Markdown table (for the user guide)."""
        lines = ["| column | required | unit | valid range | meaning |", "|---|---|---|---|---|"]
        for c in self.columns:
            rng = "" if c.lo is None and c.hi is None else f"{'' if c.lo is None else c.lo} .. " \
                                                           f"{'' if c.hi is None else c.hi}"
            lines.append(f"| `{c.name}` | {'yes' if c.required else 'no'} | {c.unit} | {rng} | {c.description} |")
        if self.one_of:
            lines.append(f"\nAt least one of {' / '.join('+'.join(g) for g in self.one_of)} must be present"
                         + (", and filled in each row." if self.row_needs_one_of else "."))
        return "\n".join(lines)


def cell_key(mcc, net, area, cell) -> pd.Series:
    """The cell identifier that joins measurement logs and cell tables: "mcc-net-area-cell".

    Parameters
    ----------
    mcc, net, area, cell : int or array_like of int
        Non-negative integers, or 1-D sequences of them of one length.

    Returns
    -------
    pandas.Series of str
    """
    parts = [_id_part(name, v) for name, v in (("mcc", mcc), ("net", net), ("area", area), ("cell", cell))]
    sizes = {len(p) for p in parts} - {1}
    if len(sizes) > 1:
        raise ShapeError(f"cell: expected mcc, net, area and cell of one length, got lengths "
                         f"{[len(p) for p in parts]}")
    size = sizes.pop() if sizes else 1   # a single value goes with every row of the others (none: no rows)
    parts = [p if len(p) == size else pd.Series([p.iloc[0]] * size, dtype=object) for p in parts]
    return parts[0] + "-" + parts[1] + "-" + parts[2] + "-" + parts[3]


def _id_part(name: str, value) -> pd.Series:
    """One part of a cell id as text: integers >= 0 (a DTypeError/ParameterError naming ``name``)."""
    _to_array(name, value)                       # ragged lists, sizes beyond memory
    try:
        part = pd.Series(value).astype("Int64")
    except (TypeError, ValueError, OverflowError) as exc:
        raise DTypeError(f"{name}: expected integer identifiers ({exc})") from None
    if part.isna().any() or (part < 0).any():
        bad = part[part.isna() | (part < 0)].iloc[0]
        raise ParameterError(f"{name}: expected integer identifiers >= 0, got {bad!r}")
    return part.reset_index(drop=True).astype(str)


_TRACK = Column("track_id", "id", "", "track (terminal) identifier, default \"1\"; the rows need not be "
                "sorted (unsorted input is sorted by track and time, and the run says so)", required=False)
_TIME = Column("time", "time", "ISO 8601 or s/ms/us/ns", "time stamp: ISO 8601 text (no zone = UTC), or "
               "numbers: seconds from any start, or epoch s/ms/us/ns (unit by magnitude, --time-unit)")

FIXES = Schema("position fixes", (
    _TRACK, _TIME,
    Column("lat", "float", "degrees", "WGS-84 latitude", required=False, lo=-90.0, hi=90.0),
    Column("lon", "float", "degrees", "WGS-84 longitude", required=False, lo=-180.0, hi=180.0),
    Column("x", "float", "m", "local east coordinate (instead of lat/lon)", required=False),
    Column("y", "float", "m", "local north coordinate (instead of lat/lon)", required=False),
    Column("accuracy_m", "float", "m", "1-sigma horizontal accuracy of the fix; empty = filter default",
           required=False, lo=0.0, nullable=True),
), one_of=(("lat", "lon"), ("x", "y")))

MEASUREMENTS = Schema("cellular measurements", (
    _TRACK, _TIME,
    Column("cell_id", "id", "", "serving/neighbour cell, \"mcc-net-area-cell\" as in the cell table; empty: a "
           "cell the log could not identify (left out, as a cell that is not in the table)", nullable=True),
    Column("rss_dbm", "float", "dBm", "received signal strength", required=False, lo=-160.0, hi=0.0,
           nullable=True),
    Column("range_m", "float", "m", "measured range to the cell's antenna", required=False, lo=0.0,
           nullable=True),
    Column("ta", "int", "TA steps", "timing advance in the steps of the cell's radio: range = (ta + 0.5) x "
           "553.5 m for GSM (0..63, 3GPP TS 45.010), x 78.07 m for LTE (0..1282, TS 36.213)", required=False, lo=0,
           hi=1282, nullable=True),
), one_of=(("rss_dbm",), ("range_m",), ("ta",)), row_needs_one_of=("rss_dbm", "range_m", "ta"))

CELLS = Schema("cell table (OpenCelliD layout)", (
    Column("radio", "id", "", "GSM, UMTS, LTE, NR, CDMA"),
    Column("mcc", "int", "", "mobile country code", lo=0, hi=999),
    Column("net", "int", "", "mobile network code (MNC)", lo=0, hi=999),
    Column("area", "int", "", "LAC / TAC", lo=0),
    Column("cell", "int", "", "cell identity (CID / ECI)", lo=0),
    Column("lon", "float", "degrees", "antenna longitude (WGS-84)", lo=-180.0, hi=180.0),
    Column("lat", "float", "degrees", "antenna latitude (WGS-84)", lo=-90.0, hi=90.0),
    Column("range", "float", "m", "coverage radius estimate (geolocation: single-cell accuracy and the path-loss "
           "fit)", required=False, lo=0.0, nullable=True),
    Column("height_m", "float", "m", "antenna height above ground (default 30)", required=False, lo=0.0,
           nullable=True),
    Column("power_dbm", "float", "dBm", "transmit power incl. antenna gain (default 43)", required=False,
           nullable=True),
    Column("arfcn", "int", "", "GSM channel number; sets the carrier frequency (default 1800 MHz)",
           required=False, lo=0, hi=1023, nullable=True),
    Column("unit", "int", "", "PSC (UMTS) or PCI (LTE, NR)", required=False, lo=0, nullable=True),
    Column("samples", "int", "", "observations behind the row (geolocation: weight and fit)", required=False,
           lo=0, nullable=True),
    Column("changeable", "int", "", "1: position averaged from observations, 0: exact", required=False, lo=0,
           hi=1, nullable=True),
    Column("created", "int", "s since 1970", "first seen", required=False, lo=0, nullable=True),
    Column("updated", "int", "s since 1970", "last seen", required=False, lo=0, nullable=True),
    Column("averageSignal", "float", "dBm", "mean signal of the observations (0 = unknown; geolocation fits the "
           "path loss from it and range)", required=False, nullable=True),
    Column("azimuth_deg", "float", "degrees", "sector antenna azimuth, clockwise from north (empty: "
           "omnidirectional or unknown)", required=False, lo=0.0, hi=360.0, nullable=True),
    Column("earfcn", "int", "", "LTE/NR channel number (resolves neighbour cells logged by PCI)",
           required=False, lo=0, nullable=True),
), mapped=False)


@dataclass
class ReadReport:
    """Counts of what a reader did; skipped rows are counted by reason and never dropped silently."""

    file: str = ""
    rows_read: int = 0
    rows_skipped: int = 0
    reasons: Counter = field(default_factory=Counter)
    examples: list[str] = field(default_factory=list)
    first_example: dict = field(default_factory=dict)  # reason -> the first row dropped for it
    notes: list[str] = field(default_factory=list)   # how the file was read (units, column names, sorting)
    duplicates_dropped: int = 0                      # exact repeats of the previous row of a track
    left_out: Counter = field(default_factory=Counter)  # records that are not fixes (GPX routes without
                                                        # times, NMEA epochs without a fix), by reason
    rows_reordered: int = 0                          # rows not in (track, time) order, sorted

    def skip(self, error: DataError, count: int = 1) -> None:
        """Count ``count`` rows dropped for ``error`` (its message kept as an example)."""
        self.rows_skipped += count
        reason = getattr(error, "kind", error.reason).rstrip(":")
        key = f"{error.column}: {reason}" if error.column else reason
        self.reasons[key] += count
        self.first_example.setdefault(key, str(error))
        if len(self.examples) < _MAX_EXAMPLES:
            self.examples.append(str(error))

    def to_dict(self) -> dict:
        return {"file": self.file, "rows_read": self.rows_read, "rows_skipped": self.rows_skipped,
                "skipped_by_reason": dict(self.reasons), "examples": list(self.examples), "notes": list(self.notes),
                "duplicates_dropped": self.duplicates_dropped, "rows_reordered": self.rows_reordered,
                "left_out": dict(self.left_out)}

    def leave_out(self, skipped: list) -> None:
        """Take the records a reader left out (:class:`mptrack.io._formats.Skipped`, consumed from the
        list): counted by reason, one note each.  They are not bad rows (no --max-skip)."""
        while skipped:
            s = skipped.pop(0)
            if s.count:  # a count of 0: a note on how the file was read
                self.left_out[s.reason] += s.count
            self.note(s.detail)

    def reset(self) -> None:
        """Forget every count (the input is read again from the start)."""
        fresh = ReadReport(file=self.file)
        self.__dict__.update(fresh.__dict__)

    def merge(self, other: "ReadReport", prefix: str) -> None:
        """Add the counts of ``other`` (the report of one file of several), its notes prefixed with
        ``prefix`` (the file's name) unless they name the file already."""
        self.rows_read += other.rows_read
        self.rows_skipped += other.rows_skipped
        self.reasons.update(other.reasons)
        for reason, example in other.first_example.items():
            self.first_example.setdefault(reason, example)
        self.examples.extend(other.examples[:max(0, _MAX_EXAMPLES - len(self.examples))])
        for text in other.notes:
            self.note(text if other.file and other.file in text else f"{prefix}: {text}")
        self.duplicates_dropped += other.duplicates_dropped
        self.left_out.update(other.left_out)
        self.rows_reordered += other.rows_reordered

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    def check_skips(self, limit: int, option: str) -> None:
        """Raise DataError when more than ``limit`` rows were dropped: the top reasons with an
        example each (``option`` is how the user sets the limit)."""
        if self.rows_skipped <= limit:
            return
        lines = [f"{count} x {reason} (first: {self.first_example[reason].removeprefix(self.file + ', ')})"
                 for reason, count in self.reasons.most_common(3)]
        raise DataError(f"{self.rows_skipped} of {self.rows_read} rows would be dropped, more than the {limit} "
                        f"allowed by {option}; " + "; ".join(lines), file=self.file)


#: Values of a text column tried as numbers before the whole column is (see :func:`_numeric_time`).
_TIME_SAMPLE = 64


def _numeric_time(values: pd.Series) -> pd.Series | None:
    """The numbers of a numeric time column (mostly numbers: the rest is bad), else None."""
    if pd.api.types.is_numeric_dtype(values):
        return pd.to_numeric(values, errors="coerce").astype(float)
    if pd.api.types.is_datetime64_any_dtype(values):
        return None
    sample = values.dropna().iloc[:_TIME_SAMPLE]  # text times fail fast: converting all is slow
    if pd.to_numeric(sample, errors="coerce").notna().sum() * 2 <= len(sample):
        return None
    num = pd.to_numeric(values, errors="coerce")
    return num.astype(float) if num.notna().sum() * 2 > values.notna().sum() else None


def _parse_time(values: pd.Series, scale: float = 1.0, fmt: str | None = None,
                num: pd.Series | None = None, epoch: bool = False) -> tuple[pd.Series, np.ndarray]:
    """(parsed column, seconds as float64 with NaN where unparseable or beyond +-MAX_SECONDS).

    Numbers are ``scale`` units per second: counted from 1970 (``epoch``) they become UTC
    datetimes, else (seconds from any start) they stay numbers.  Text is ISO 8601 (no zone = UTC)
    or the strftime layout ``fmt``.  ``num``: the column's :func:`_numeric_time`, if already known."""
    num = _numeric_time(values) if num is None else num
    if num is not None:
        secs = num.to_numpy(dtype=float) / scale
        with np.errstate(invalid="ignore"):
            secs[~(np.abs(secs) <= MAX_SECONDS)] = np.nan
        if not epoch:
            return num, secs
        ns = np.where(np.isnan(secs), 0, np.round(num.to_numpy(dtype=float) * (1e9 / scale))).astype("int64")
        ts = pd.Series(pd.to_datetime(ns, utc=True)).where(~np.isnan(secs))
        return ts, secs
    if pd.api.types.is_datetime64_any_dtype(values):
        ts = values.dt.tz_localize("UTC") if values.dt.tz is None else values.dt.tz_convert("UTC")
    else:
        ts = pd.to_datetime(values.astype("string"), errors="coerce", utc=True, format=fmt or "ISO8601")
    ns = ts.to_numpy(dtype="datetime64[ns]").astype("int64").astype(float)
    secs = np.where(ts.isna().to_numpy(), np.nan, ns / 1e9)
    return ts, secs


def _shown(value) -> str:
    """A cell as the user wrote it (numpy scalars as plain numbers)."""
    return repr(value.item() if isinstance(value, np.generic) else value)


def validate_chunk(df: pd.DataFrame, schema: Schema, *, file, first_row: int, on_error: str,
                   report: ReadReport, time_scale: float = 1.0, time_format: str | None = None,
                   time_epoch: bool = False, file_columns=None) -> pd.DataFrame:
    """Check one chunk (canonical column names, see :mod:`._interpret`) against ``schema``; return
    the good rows with a float column ``t`` (seconds), ``row``, and the file's other columns
    unchanged after the schema's (they pass through to the output).

    ``first_row`` is the 1-based record number of the chunk's first row; numeric times are
    ``time_scale`` units per second (since 1970 with ``time_epoch``: they become UTC times) and
    text times ISO 8601 or ``time_format``.  ``file_columns``: the file's own column names (before
    they were mapped), which the error for a missing column lists.  Raises
    DataError for the first bad cell (on_error="raise") or drops and counts bad rows.
    """
    present = set(df.columns)
    has = f"the file has: {', '.join(map(str, df.columns if file_columns is None else file_columns))}"
    for col in schema.columns:
        if col.required and col.name not in present:
            hint = f"; name it with --columns {col.name}=COLUMN" if schema.mapped else ""
            raise DataError(f"missing column ({has}){hint}", file=file, column=col.name)
    if schema.one_of and not any(all(c in present for c in g) for g in schema.one_of):
        want = " or ".join("+".join(g) for g in schema.one_of)
        first = schema.one_of[0]
        hint = (f"; name {'them' if len(first) > 1 else 'it'} with --columns "
                f"{','.join(f'{c}=COLUMN' for c in first)}") if schema.mapped else ""
        raise DataError(f"missing columns: need {want} ({has}){hint}", file=file, column="+".join(first))
    df = df.reset_index(drop=True)
    rows = np.arange(first_row, first_row + len(df))
    report.rows_read += len(df)
    bad = np.zeros(len(df), dtype=bool)
    errors: list[DataError] = []

    def flag(mask: np.ndarray, column: str, reason: str, values: pd.Series | None = None, kind=None) -> None:
        new = mask & ~bad
        for i in np.flatnonzero(new):
            text = reason if values is None else f"{reason} {_shown(values.iloc[i])}"
            err = DataError(text, file=file, row=int(rows[i]), column=column)
            err.kind = kind or reason
            errors.append(err)
        bad[new] = True

    out = {}
    for col in schema.columns:
        if col.name not in present:
            continue
        values = df[col.name]
        if col.kind == "id":
            if not col.nullable:
                flag(values.isna().to_numpy(), col.name, "empty identifier")
            out[col.name] = values.astype("string").str.strip().astype(object)  # object: cheap to compare
        elif col.kind == "time":
            num = _numeric_time(values)
            parsed, secs = _parse_time(values, time_scale, time_format, num, time_epoch)
            text = num is None and not pd.api.types.is_datetime64_any_dtype(values)
            how = (f"not in the layout {time_format!r}" if time_format else
                   "not ISO 8601 (set --time-format for other layouts, e.g. '%d/%m/%Y %H:%M:%S')") if text \
                else "missing" if pd.api.types.is_datetime64_any_dtype(values) \
                else f"not a time within +-{MAX_SECONDS:.0e} s"
            flag(~np.isfinite(secs), col.name, f"bad time stamp ({how}):", values,
                 kind="bad time stamp")
            out[col.name] = parsed
            out["t"] = secs
        else:
            num = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
            empty = values.isna().to_numpy()
            notnum = np.isnan(num) & ~empty
            flag(notnum, col.name, "not a number:", values)
            if not col.nullable:
                flag(empty, col.name, "empty value (NaN)")
            with np.errstate(invalid="ignore"):
                lo = (num < col.lo) if col.lo is not None else np.zeros(len(num), bool)
                hi = (num > col.hi) if col.hi is not None else np.zeros(len(num), bool)
                flag(np.isinf(num), col.name, "infinite value")
            outside = (lo | hi) & np.isfinite(num)
            flag(outside, col.name, f"outside {col.lo} .. {col.hi} {col.unit}:", values)
            if col.kind == "int":
                frac = np.isfinite(num) & (num != np.round(num))
                flag(frac, col.name, "not an integer:", values)
            out[col.name] = num
    if schema.row_needs_one_of:
        have = [c for c in schema.row_needs_one_of if c in out]
        none = np.all([np.isnan(out[c]) for c in have], axis=0) if have else np.ones(len(df), bool)
        flag(none, "/".join(have), "no measurement: all of these are empty")
    clean = pd.DataFrame(out)
    if "track_id" not in clean.columns and any(c.name == "track_id" for c in schema.columns):
        clean.insert(0, "track_id", np.full(len(clean), "1", dtype=object))
    clean["row"] = rows
    for name in schema.extra_columns(df.columns):
        clean[name] = df[name].to_numpy()
    return _apply(clean, bad, errors, on_error, report)


def _apply(clean: pd.DataFrame, bad: np.ndarray, errors: list, on_error: str, report: ReadReport):
    if errors:
        errors.sort(key=lambda e: e.row)
        if on_error == "raise":
            raise errors[0]
        for e in errors:
            report.skip(e)
        clean = clean.loc[~bad].reset_index(drop=True)
    return clean

