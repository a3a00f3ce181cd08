"""Raw input formats: each reader yields pandas chunks of the file's own columns (no validation).

Which reader runs is chosen by the file name (:func:`input_format`); a
directory is a Parquet dataset (hive-partitioned or not).  CSV is read
``chunk_rows`` rows at a time and Parquet one record batch at a time; XML
formats (GPX) are parsed whole.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import pandas as pd

from ..errors import DataError

__all__ = ["FORMATS", "input_format", "raw_chunks"]

FORMATS = {".csv": "csv", ".txt": "csv", ".gz": "csv", ".parquet": "parquet", ".pq": "parquet", ".gpx": "gpx"}


def input_format(path) -> str:
    """"csv", "parquet" or "gpx" from the file name (".csv.gz" is CSV)."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise DataError(f"unknown input format {suffix!r}; expected one of {', '.join(sorted(FORMATS))}",
                        file=path)
    return FORMATS[suffix]


def raw_chunks(source, chunk_rows: int) -> Iterator[pd.DataFrame]:
    """Raw chunks of ``chunk_rows`` rows of a DataFrame, a file, or a directory of Parquet files."""
    if isinstance(source, pd.DataFrame):
        for i in range(0, max(len(source), 1), chunk_rows):
            yield source.iloc[i:i + chunk_rows]
        return
    path = Path(source)
    if path.is_dir():
        yield from _dataset_chunks(path, chunk_rows)
        return
    fmt = input_format(path)
    if not path.exists():
        raise DataError("file not found", file=path)
    try:
        if fmt == "csv":
            reader = pd.read_csv(path, chunksize=chunk_rows, dtype={"track_id": "string", "cell_id": "string",
                                                                     "radio": "string"},
                                 skipinitialspace=True)
            with reader:
                yield from reader
        elif fmt == "parquet":
            import pyarrow.parquet as pq

            with pq.ParquetFile(path) as pf:
                for batch in pf.iter_batches(batch_size=chunk_rows):
                    yield batch.to_pandas()
        else:
            yield _gpx_frame(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, OSError) as exc:
        raise DataError(f"cannot be read as {fmt}: {exc}", file=path) from None
    except Exception as exc:  # pyarrow / gpxpy raise their own types for corrupt files
        if type(exc).__module__.split(".")[0] in ("pyarrow", "gpxpy"):
            raise DataError(f"cannot be read as {fmt}: {exc}", file=path) from None
        raise


def _dataset_chunks(path: Path, chunk_rows: int) -> Iterator[pd.DataFrame]:
    """A directory of Parquet files (hive-partitioned or not: ``key=value`` directories become
    columns), in file-path order, ``chunk_rows`` rows at a time."""
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
    except DataError:
        raise
    except Exception as exc:
        if type(exc).__module__.split(".")[0] == "pyarrow" or isinstance(exc, OSError):
            raise DataError(f"cannot be read as a Parquet dataset: {exc}", file=path) from None
        raise


def _gpx_frame(path: Path) -> pd.DataFrame:
    """All track points of a GPX file: one track_id per <trk> (its name, else "trk<i>")."""
    import gpxpy
    import gpxpy.gpx

    try:
        with open(path, encoding="utf-8-sig") as fh:
            gpx = gpxpy.parse(fh)
    except gpxpy.gpx.GPXException as exc:
        raise DataError(f"not a valid GPX file: {exc}", file=path) from None
    rows = []
    for i, trk in enumerate(gpx.tracks, start=1):
        name = trk.name or f"trk{i}"
        for seg in trk.segments:
            for p in seg.points:
                rows.append((name, pd.Timestamp(p.time) if p.time is not None else pd.NaT,
                             p.latitude, p.longitude, p.elevation))
    df = pd.DataFrame(rows, columns=["track_id", "time", "lat", "lon", "elevation_m"])
    if df.empty:
        raise DataError("no track points (<trkpt>) in the file", file=path)
    df["time"] = pd.to_datetime(df["time"], utc=True)
    return df
