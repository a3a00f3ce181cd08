"""Raw input formats: each reader yields pandas chunks of position fixes (no validation).

Which reader runs is chosen by the file name (:func:`input_format`); a
directory is a Parquet dataset (hive-partitioned or not).  CSV is read
``chunk_rows`` rows at a time and Parquet one record batch at a time; the
other formats are decoded whole and handed out ``chunk_rows`` rows at a time.

CSV and Parquet chunks carry the file's own columns (mapping and unit
detection happen in the schema layer).  The readers of GPS formats (GPX,
NMEA 0183, FIT, TCX, GeoJSON) emit the canonical columns ``track_id``,
``time`` (UTC), ``lat``/``lon`` (degrees) and, when the file has them,
``elevation_m``, ``speed_mps``, ``course_deg``, ``accuracy_m``, plus any other
per-point value of the format (``heart_rate``, ``cadence``, ``hdop``,
``satellites``, ...) under a snake_case name.

Parts of a file that are not position fixes (an empty GPX track, an NMEA epoch
without a fix, FIT records without a position) are not errors: the reader
leaves them out and appends a :class:`Skipped` record to the ``skipped`` list
the caller passes, so they are counted and reported, never dropped silently.
Anything that makes the file unusable is a :class:`~mptrack.errors.DataError`
naming the file, never a library traceback.
"""

from __future__ import annotations

import csv
import importlib
import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import pandas as pd

from .._core.validation import check_path
from ..errors import DataError

__all__ = ["FORMATS", "FORMAT_NAMES", "Skipped", "input_format", "raw_chunks"]

#: file suffix -> input format (".csv.gz" and ".tsv" are CSV, the delimiter sniffed; ".txt" and ".log" are NMEA
#: when they hold NMEA sentences; a text file with G-NetTrack Pro's header is a G-NetTrack log)
FORMATS = {".csv": "csv", ".tsv": "csv", ".txt": "csv", ".log": "csv", ".gz": "csv", ".parquet": "parquet",
           ".pq": "parquet",
           ".gpx": "gpx", ".nmea": "nmea", ".nme": "nmea", ".fit": "fit", ".tcx": "tcx", ".geojson": "geojson",
           ".json": "geojson"}

#: input format -> the name messages use
FORMAT_NAMES = {"csv": "CSV", "parquet": "Parquet", "gpx": "GPX", "nmea": "NMEA 0183", "fit": "FIT", "tcx": "TCX",
                "geojson": "GeoJSON", "gnettrack": "G-NetTrack Pro log"}

#: formats decoded by a module of their own (imported on first use): format -> module
_DECODERS = {"gpx": "._gpx", "nmea": "._nmea_reader", "fit": "._fit_reader", "tcx": "._tcx_reader",
             "geojson": "._geojson"}

_SNIFF_BYTES = 64 * 1024
_DELIMITERS = ",;\t|"


@dataclass(frozen=True)
class Skipped:
    """Records of a file that a reader left out because they are not position fixes.

    reason   what they are, the same text for every file ("NMEA epoch without a fix")
    count    how many records (points, epochs, sentences, features)
    detail   one line for the user: where in the file, and why that is not an error
    """

    reason: str
    count: int
    detail: str


def input_format(path) -> str:
    """The input format of a file from its name: one of the values of :data:`FORMATS`.

    ".txt" and ".log" files are NMEA 0183 when their first line (after ``#`` comments) is an NMEA
    sentence, CSV otherwise; a text file whose header is G-NetTrack Pro's is a G-NetTrack log.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    str

    Raises
    ------
    ParameterError
        An unknown suffix.
    """
    path = check_path("path", path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise DataError(f"unknown input format {suffix!r}; expected one of {', '.join(sorted(FORMATS))} "
                        "or a directory of Parquet files", file=path)
    if suffix in (".txt", ".log") and _starts_with_nmea(path):
        return "nmea"
    if FORMATS[suffix] == "csv" and suffix != ".gz" and path.is_file() and _is_gnettrack(path):
        return "gnettrack"
    return FORMATS[suffix]


def raw_chunks(source, chunk_rows: int, skipped: list | None = None, *, cells: bool = False,
               timezone: str | None = None) -> Iterator[pd.DataFrame]:
    """Raw chunks of at most ``chunk_rows`` rows of a DataFrame, a file, or a directory of Parquet files.

    ``skipped``: a list to which the readers append a :class:`Skipped` for every kind
    of record they leave out (see the module docstring).  ``cells`` and ``timezone`` are for the
    formats that hold both (:mod:`._gnettrack`): read the cells heard rather than the positions, local
    time stamps in this zone.
    """
    skipped = [] if skipped is None else skipped
    if isinstance(source, pd.DataFrame):
        yield from frame_chunks(source, chunk_rows)
        return
    path = Path(source)
    if path.is_dir():
        yield from _dataset_chunks(path, chunk_rows)
        return
    fmt = input_format(path)
    if not path.exists():
        raise DataError("file not found", file=path)
    try:
        if path.stat().st_size == 0:
            raise DataError(f"cannot be read as {FORMAT_NAMES[fmt]}: the file is empty (0 bytes)", file=path)
        if fmt == "csv":
            yield from _csv_chunks(path, chunk_rows)
        elif fmt == "parquet":
            yield from _parquet_chunks(path, chunk_rows)
        elif fmt == "gnettrack":  # two readings of one log: its positions or its cells
            read_log: Callable = importlib.import_module("._gnettrack", __package__).read
            yield from frame_chunks(read_log(path, skipped, cells=cells, timezone=timezone), chunk_rows)
        else:
            read: Callable = importlib.import_module(_DECODERS[fmt], __package__).read
            yield from frame_chunks(read(path, skipped), chunk_rows)
    except UnicodeDecodeError as exc:
        raise DataError(f"cannot be read as {FORMAT_NAMES[fmt]}: not UTF-8 text ({exc.reason}); save the file "
                        "as UTF-8", file=path) from None
    except OSError as exc:
        raise DataError(f"cannot be read: {exc.strerror or exc}", file=path) from None


def frame_chunks(df: pd.DataFrame, chunk_rows: int) -> Iterator[pd.DataFrame]:
    """``df`` in slices of ``chunk_rows`` rows (one empty slice for an empty frame)."""
    for i in range(0, max(len(df), 1), chunk_rows):
        yield df.iloc[i:i + chunk_rows]


def library_error(fmt: str, path, exc) -> DataError:
    """The DataError for a file that a format library could not decode (``exc``: its exception or a text)."""
    text = str(exc).strip() or type(exc).__name__
    return DataError(f"cannot be read as {FORMAT_NAMES[fmt]}: {text}", file=path)


def snake_case(name: str) -> str:
    """A plain snake_case column name: "HeartRate" -> "heart_rate", "{ns}RunCadence" -> "run_cadence"."""
    name = re.sub(r"^\{[^}]*\}", "", str(name))            # an XML namespace
    name = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)     # camelCase boundaries
    return re.sub(r"[^0-9a-zA-Z]+", "_", name).strip("_").lower()


def unique_name(name: str, taken: set) -> str:
    """``name``, or "name (2)", "name (3)", ... if it is in ``taken`` already (which it joins): two
    tracks with one name would otherwise merge."""
    out, k = name, 1
    while out in taken:
        k += 1
        out = f"{name} ({k})"
    taken.add(out)
    return out


def utc_times(values) -> pd.Series:
    """Datetimes (naive ones are UTC) as a tz-aware UTC Series."""
    return pd.Series(pd.to_datetime(list(values), utc=True), dtype="datetime64[ns, UTC]")


# --- CSV -------------------------------------------------------------------------------------------------------

def _csv_chunks(path: Path, chunk_rows: int) -> Iterator[pd.DataFrame]:
    """A delimited text file ``chunk_rows`` rows at a time: the delimiter (, ; tab |) and a decimal
    comma are sniffed from the first 64 KB and the C parser does the rest; a UTF-8 BOM is dropped."""
    sep, decimal = sniff_csv(_head_text(path))
    try:
        reader = pd.read_csv(path, sep=sep, decimal=decimal, chunksize=chunk_rows,  # the C parser drops a BOM
                             dtype={"track_id": "string", "cell_id": "string", "radio": "string"},
                             skipinitialspace=True)
        with reader:
            yield from reader
    except pd.errors.EmptyDataError:
        raise DataError("no header line: the file holds only blank lines", file=path) from None
    except pd.errors.ParserError as exc:
        raise DataError(f"cannot be read as CSV (delimiter {sep!r}): {exc}", file=path) from None


def _head_text(path: Path) -> str:
    """The first 64 KB of a (possibly compressed) text file, cut at the last full line."""
    with open(path, "rb") as fh:
        magic = fh.read(2)
    if magic == b"\x1f\x8b":
        import gzip

        opener = gzip.open
    else:
        opener = open
    try:
        with opener(path, "rb") as fh:
            raw = fh.read(_SNIFF_BYTES)
    except (OSError, EOFError) as exc:
        raise DataError(f"cannot be read as CSV: {exc}", file=path) from None
    if len(raw) == _SNIFF_BYTES and b"\n" in raw:
        raw = raw[:raw.rindex(b"\n")]
    return raw.decode("utf-8-sig", errors="replace")


def sniff_csv(text: str) -> tuple[str, str]:
    """(delimiter, decimal mark) of a CSV sample: the delimiter is what ``csv.Sniffer`` finds among
    , ; tab | if the header line contains it, else the one of them most frequent in the header
    (","  when there is none: one column).  A decimal comma is assumed with a delimiter other than
    "," when the sample's values look like ``45,123``."""
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines:
        return ",", "."
    header = lines[0]
    try:
        sep = csv.Sniffer().sniff("\n".join(lines[:50]), delimiters=_DELIMITERS).delimiter
    except csv.Error:
        sep = ""
    if not sep or sep not in header:
        counts = {d: header.count(d) for d in _DELIMITERS}
        sep = max(counts, key=counts.get) if max(counts.values()) else ","
    decimal = "."
    if sep != ",":
        values = [v.strip().strip('"') for ln in lines[1:50] for v in ln.split(sep)]
        if any(re.fullmatch(r"-?\d+,\d+", v) for v in values):
            decimal = ","
    return sep, decimal


#: the first fields of a G-NetTrack Pro log's header line
GNETTRACK_HEADER = ("Timestamp", "Longitude", "Latitude", "Speed")


def _is_gnettrack(path: Path) -> bool:
    """Whether the first line of ``path`` is a G-NetTrack Pro header (:mod:`._gnettrack` reads the log)."""
    try:
        with open(path, "rb") as fh:
            first = fh.readline(4096).decode("utf-8", errors="replace")
    except OSError:
        return False
    return tuple(first.rstrip("\r\n").lstrip("\ufeff").split("\t")[:4]) == GNETTRACK_HEADER


def _starts_with_nmea(path: Path) -> bool:
    """Whether the first line of ``path`` that is not blank or a ``#`` comment is an NMEA sentence."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    for line in io.StringIO(head.decode("ascii", errors="replace")):
        line = line.strip()
        if line and not line.startswith("#"):
            return line[0] in "$!"
    return False


# --- Parquet ---------------------------------------------------------------------------------------------------

def _parquet_chunks(path: Path, chunk_rows: int) -> Iterator[pd.DataFrame]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        with pq.ParquetFile(path) as pf:
            for batch in pf.iter_batches(batch_size=chunk_rows):
                yield batch.to_pandas()
    except (pa.ArrowException, OSError) as exc:
        raise library_error("parquet", path, exc) from None


def _dataset_chunks(path: Path, chunk_rows: int) -> Iterator[pd.DataFrame]:
    """A directory of Parquet files (hive-partitioned or not: ``key=value`` directories become
    columns), in file-path order, ``chunk_rows`` rows at a time."""
    import pyarrow as pa
    import pyarrow.dataset as ds

    try:
        dataset = ds.dataset(path, format="parquet", partitioning="hive", exclude_invalid_files=False)
        files = sorted(dataset.files)
        if not files:
            raise DataError("no Parquet files in the directory", file=path)
        dataset = ds.dataset(files, format="parquet", partitioning=ds.HivePartitioning.discover(),
                             partition_base_dir=str(path))
        for batch in dataset.to_batches(batch_size=chunk_rows, use_threads=False):
            if batch.num_rows:
                yield batch.to_pandas()
    except (pa.ArrowException, OSError) as exc:
        raise DataError(f"cannot be read as a Parquet dataset: {exc}", file=path) from None
