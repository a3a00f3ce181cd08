"""Validated, chunked reading of every input format (:mod:`._formats`), and a track-by-track iterator.

Memory stays bounded: the raw readers yield chunks, and :func:`iter_tracks`
holds one track (plus one chunk) at once, which is why the rows of a track
must be contiguous.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
import pandas as pd

from .._core.data_checks import check_on_error, source_label
from .._core.tracks import track_offsets
from .._core.validation import check_int
from ._inputs import InputFiles, file_labels, input_label, resolve_input
from ..errors import DataError, ParameterError
from ._formats import Skipped, input_format, raw_chunks
from ._interpret import ReadOptions, interpret
from ._schema import CELLS, FIXES, MEASUREMENTS, ReadReport, Schema, cell_key, validate_chunk

__all__ = ["read_chunks", "iter_track_chunks", "iter_tracks", "read_table", "read_cells",
           "input_columns"]

DEFAULT_CHUNK_ROWS = 50_000

def input_columns(path) -> list[str]:
    """The column names of an input as the file has them, before names and units are recognised.

    Reads only the first record: e.g. to see whether a log has ``true_lat``/``true_lon`` beside
    ``lat``/``lon``.

    Parameters
    ----------
    path : str, path-like, list or pandas.DataFrame
        A file in any of :data:`FORMATS`, a directory of Parquet files, a DataFrame read like a file, or
        several files (a list, a glob or a directory of other files: :func:`resolve_input`), each read on its
        own with its track ids prefixed by its name.

    Returns
    -------
    list of str

    Raises
    ------
    DataError
        The file cannot be read.
    """
    source = resolve_input(path, "path")
    first = next(raw_chunks(source[0] if isinstance(source, list) else source, 1), None)
    return [] if first is None else [str(c) for c in first.columns]


def read_chunks(path, schema: Schema = FIXES, *, on_error: str = "raise", chunk_rows: int = DEFAULT_CHUNK_ROWS,
                report: ReadReport | None = None, read: ReadOptions = ReadOptions()) -> Iterator[pd.DataFrame]:
    """Validated chunks of an input against a schema.

    Column names and units are decided from the first chunk (each decision a note in ``report``).  Each
    chunk has the schema's columns, ``t`` (seconds, float), ``row`` (the 1-based record number in the
    file) and the file's other columns.

    Parameters
    ----------
    path : str, path-like, list or pandas.DataFrame
        A file in any of :data:`FORMATS`, a directory of Parquet files, a DataFrame read like a file, or
        several files (a list, a glob or a directory of other files: :func:`resolve_input`), each read on its
        own with its track ids prefixed by its name.
    schema : Schema, optional
        :data:`FIXES` (position fixes, the default), :data:`MEASUREMENTS` or :data:`CELLS`.
    on_error : {"raise", "skip"}, optional
        Raise a DataError naming file, row and column at the first bad row, or drop bad rows and count
        them by reason in ``report``.
    chunk_rows : int, optional
        Rows per chunk (memory).
    report : ReadReport, optional
        Receives the counts of dropped rows and the notes of how the input was read.
    read : ReadOptions, optional
        The input's column names and units where they are not recognised.

    Yields
    ------
    pandas.DataFrame

    Raises
    ------
    DataError
        A bad row (``on_error="raise"``), an unreadable file, or more dropped rows than ``read.max_skip``.
    """
    check_on_error(on_error)
    path = resolve_input(path, "path")
    label = input_label(path)
    chunk_rows = check_int("chunk_rows", chunk_rows, minimum=1)
    if not isinstance(schema, Schema):
        raise ParameterError(f"schema: expected a Schema (FIXES, MEASUREMENTS, CELLS), got {type(schema).__name__}")
    if not isinstance(read, ReadOptions):
        raise ParameterError(f"read: expected ReadOptions, got {type(read).__name__}")
    report = report if report is not None else ReadReport()
    report.file = str(label)
    if isinstance(path, InputFiles):
        report.leave_out(list(path.left_out))
        yield from _read_files(path, schema, on_error, chunk_rows, report, read)
        return
    first = 1
    plan = None
    skipped: list = []
    for raw in raw_chunks(path, chunk_rows, skipped, cells=schema is MEASUREMENTS, timezone=read.timezone):
        report.leave_out(skipped)
        if plan is None:
            plan = interpret(raw, schema, read, file=label)
            for note in plan.notes:
                report.note(note)
        n = len(raw)
        yield validate_chunk(plan.apply(raw), schema, file=label, first_row=first, on_error=on_error,
                             report=report, time_scale=plan.time_scale, time_format=plan.time_format,
                             time_epoch=plan.time_epoch, file_columns=list(raw.columns))
        first += n
    report.leave_out(skipped)


#: Columns that make a file an output of ``mptrack track`` (the point table's).
_OUTPUT_COLUMNS = ("east_m", "north_m", "var_east_m2", "nis", "flag", "method")


def _read_files(files: list, schema: Schema, on_error: str, chunk_rows: int, report: ReadReport,
                read: ReadOptions) -> Iterator[pd.DataFrame]:
    """The validated chunks of several files, one after the other, each read on its own (its own column
    names and units, its own row numbers) and its track ids prefixed with its name (the tracks of two
    files never merge); what each file's reading noted is counted in ``report``, its notes prefixed
    with the file's name.  A Parquet or CSV file that is an output of ``mptrack track`` (it has the point
    table's columns) is left out and counted: a folder of logs often holds an earlier run's output too."""
    for path, name in zip(files, file_labels(files)):
        if input_format(path) in ("parquet", "csv") and set(_OUTPUT_COLUMNS) <= set(input_columns(path)):
            report.leave_out([Skipped("output of mptrack track", 1, f"{path}: an output of mptrack track (it has "
                                      f"the columns {', '.join(_OUTPUT_COLUMNS)}), not fixes; left out")])
            continue
        own = ReadReport()
        for chunk in read_chunks(path, schema, on_error=on_error, chunk_rows=chunk_rows, report=own, read=read):
            if "track_id" in chunk.columns:
                ids = chunk["track_id"]
                chunk = chunk.assign(track_id=(name + "/" + ids.astype(str)).astype(ids.dtype))
            yield chunk
        report.merge(own, prefix=name)


def read_table(path, schema: Schema = FIXES, *, on_error: str = "raise", report: ReadReport | None = None,
               chunk_rows: int = DEFAULT_CHUNK_ROWS, read: ReadOptions = ReadOptions()) -> pd.DataFrame:
    """The whole validated input as one DataFrame (:func:`read_chunks`); for small inputs.

    Parameters
    ----------
    path : str, path-like, list or pandas.DataFrame
        A file in any of :data:`FORMATS`, a directory of Parquet files, a DataFrame read like a file, or
        several files (a list, a glob or a directory of other files: :func:`resolve_input`), each read on its
        own with its track ids prefixed by its name.
    schema : Schema, optional
        :data:`FIXES` (position fixes, the default), :data:`MEASUREMENTS` or :data:`CELLS`.
    on_error : {"raise", "skip"}, optional
        Raise a DataError naming file, row and column at the first bad row, or drop bad rows and count
        them by reason in ``report``.
    report : ReadReport, optional
        Receives the counts of dropped rows and the notes of how the input was read.
    chunk_rows : int, optional
        Rows per chunk (memory).
    read : ReadOptions, optional
        The input's column names and units where they are not recognised.

    Returns
    -------
    pandas.DataFrame

    Examples
    --------
    >>> import pandas as pd
    >>> from mptrack.io import read_table
    >>> log = pd.DataFrame({"time": [0, 1, 2], "lat": [45.0, 45.0001, 45.0002], "lon": [13.0, 13.0, 13.0001]})
    >>> read_table(log)[["t", "lat", "lon"]].shape
    (3, 3)
    """
    parts = list(read_chunks(path, schema, on_error=on_error, report=report, chunk_rows=chunk_rows, read=read))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


class InputNotSorted(Exception):
    """Raised by :func:`iter_track_chunks` with ``sort=None`` at the first row out of (track, time)
    order: the caller starts again with ``sort=True`` (chunks already yielded are not in sorted order)."""


def iter_track_chunks(path, schema: Schema = FIXES, *, on_error: str = "raise",
                      chunk_rows: int = DEFAULT_CHUNK_ROWS, report: ReadReport | None = None,
                      strict: bool | None = None, read: ReadOptions = ReadOptions(),
                      sort: bool | None = False) -> Iterator[pd.DataFrame]:
    """Validated rows of an input in chunks of whole tracks in time order.

    Each chunk holds at least ``chunk_rows`` rows (the last may hold fewer) and never cuts a track, so
    memory is bounded by ``chunk_rows`` plus the largest track.  A row that repeats the previous row of
    its track exactly is dropped and counted (``report.duplicates_dropped``); a repeated time with other
    values is an error (or skipped).

    Parameters
    ----------
    path : str, path-like, list or pandas.DataFrame
        A file in any of :data:`FORMATS`, a directory of Parquet files, a DataFrame read like a file, or
        several files (a list, a glob or a directory of other files: :func:`resolve_input`), each read on its
        own with its track ids prefixed by its name.
    schema : Schema, optional
        :data:`FIXES` (position fixes, the default), :data:`MEASUREMENTS` or :data:`CELLS`.
    on_error : {"raise", "skip"}, optional
        Raise a DataError naming file, row and column at the first bad row, or drop bad rows and count
        them by reason in ``report``.
    chunk_rows : int, optional
        Rows per chunk (memory).
    report : ReadReport, optional
        Receives the counts of dropped rows and the notes of how the input was read.
    strict : bool, optional
        Times must increase strictly within a track (default: for position fixes; measurement logs have
        one row per cell of a scan and may repeat a time).
    read : ReadOptions, optional
        The input's column names and units where they are not recognised.
    sort : bool, optional
        False: the rows of a track must be contiguous and in time order (else DataError, or skipped);
        None: stream while the rows are in order and raise :class:`InputNotSorted` at the first that is
        not; True: read the whole input and sort it by (track in order of first appearance, time), counting
        the rows that moved in ``report.rows_reordered``.

    Yields
    ------
    pandas.DataFrame

    Raises
    ------
    DataError
        An input without rows, a bad row, or more dropped rows than ``read.max_skip``.
    InputNotSorted
        With ``sort=None``, at the first row out of order.
    """
    strict = (schema is FIXES) if strict is None else strict
    report = report if report is not None else ReadReport()
    label = input_label(path)
    chunks = read_chunks(path, schema, on_error=on_error, chunk_rows=chunk_rows, report=report, read=read)
    if sort:
        chunks = _sorted(chunks, chunk_rows, report)
    finished: set[str] = set()
    ready: list[pd.DataFrame] = []          # complete tracks not yet yielded
    ready_rows = 0
    carry: list[pd.DataFrame] = []          # the rows so far of the track still open
    carry_id, carry_t, carry_last = None, -np.inf, None
    for chunk in chunks:
        if chunk.empty:
            continue
        if sort is None:
            _check_sorted(chunk, carry_id, carry_t, finished)
        chunk = _contiguous(chunk, carry_id, finished, label, on_error, report)
        chunk = _ordered(chunk, carry_id, carry_t, carry_last, strict, label, on_error, report)
        if chunk.empty:
            continue
        ids = chunk["track_id"].to_numpy(dtype=object)
        starts = track_offsets(ids)[:-1]
        continues = ids[0] == carry_id
        if len(starts) > 1 or not continues:
            # the open track ends in this chunk: it and every run but the last are complete
            last = int(starts[-1])
            complete = carry + ([chunk.iloc[:last]] if last else [])
            ready.extend(complete)
            ready_rows += sum(len(c) for c in complete)
            if carry_id is not None:
                finished.add(carry_id)
            finished.update(str(i) for i in ids[starts[:-1]])
            carry, carry_t = [], -np.inf
            chunk = chunk.iloc[last:]
        carry.append(chunk)
        carry_id = str(ids[-1])
        carry_t = max(carry_t, float(chunk["t"].max()))
        carry_last = chunk.iloc[[-1]]
        while ready_rows >= chunk_rows:
            head, ready = _cut(pd.concat(ready, ignore_index=True), chunk_rows)
            ready_rows = sum(len(r) for r in ready)
            yield head
    _check_totals(report, read, on_error, label)
    ready.extend(carry)
    rest = pd.concat(ready, ignore_index=True) if ready else None
    while rest is not None and len(rest):
        head, tail = _cut(rest, chunk_rows)
        yield head
        rest = tail[0] if tail else None


def _check_totals(report: ReadReport, read: ReadOptions, on_error: str, label) -> None:
    """After the last row: an input without rows, or more rows dropped than allowed, is an error."""
    if report.rows_read == 0:
        raise DataError("no rows to track: the input is empty or has a header only", file=label)
    if on_error == "skip":
        report.check_skips(read.skip_limit(report.rows_read), f"--max-skip {read.max_skip}")
    if report.rows_skipped == report.rows_read:
        raise DataError("every row is bad; nothing to track", file=label)


def _sorted(chunks, chunk_rows: int, report: ReadReport) -> Iterator[pd.DataFrame]:
    """All chunks as one table, stably sorted by (track in order of first appearance, time), in
    chunks of ``chunk_rows`` rows."""
    parts = [c for c in chunks if len(c)]
    if not parts:
        return
    rows = pd.concat(parts, ignore_index=True)
    track_no = pd.factorize(rows["track_id"].to_numpy(dtype=object))[0]
    order = np.lexsort((rows["t"].to_numpy(dtype=float), track_no))
    moved = int((order != np.arange(len(order))).sum())
    if moved:
        report.rows_reordered += moved
        report.note(f"{moved} rows were not in (track, time) order and were sorted")
        rows = rows.take(order).reset_index(drop=True)
    for i in range(0, len(rows), chunk_rows):
        yield rows.iloc[i:i + chunk_rows]


def _check_sorted(chunk: pd.DataFrame, open_id, open_t: float, finished: set) -> None:
    """Raise InputNotSorted if a track reappears or its time goes back (equal times are judged later)."""
    ids = chunk["track_id"].to_numpy(dtype=object)
    t = chunk["t"].to_numpy(dtype=float)
    starts = track_offsets(ids)[:-1]
    run_ids = [str(ids[a]) for a in starts]
    seen = set(finished)
    if open_id is not None and run_ids[0] != open_id:
        seen.add(open_id)
    for j, tid in enumerate(run_ids):
        if tid in seen or (tid == open_id and j > 0):
            raise InputNotSorted(tid)
        seen.add(tid)
    new_run = np.r_[True, ids[1:] != ids[:-1]]
    back = np.r_[False, t[1:] < t[:-1]] & ~new_run
    if back.any() or (ids[0] == open_id and t[0] < open_t):
        raise InputNotSorted(str(ids[0]))


def _cut(rows: pd.DataFrame, chunk_rows: int) -> tuple[pd.DataFrame, list]:
    """(the first whole tracks of ``rows`` that reach ``chunk_rows`` rows, [the rest] or []): chunks
    depend on the tracks alone, not on how the file was split into batches or files."""
    ids = rows["track_id"].to_numpy(dtype=object)
    ends = track_offsets(ids)[1:]
    cut = int(ends[np.searchsorted(ends, chunk_rows)]) if ends[-1] >= chunk_rows else len(ids)
    head = rows.iloc[:cut].reset_index(drop=True)
    return head, ([rows.iloc[cut:].reset_index(drop=True)] if cut < len(ids) else [])


def iter_tracks(path, schema: Schema = FIXES, *, on_error: str = "raise", chunk_rows: int = DEFAULT_CHUNK_ROWS,
                report: ReadReport | None = None, strict: bool | None = None, read: ReadOptions = ReadOptions(),
                sort: bool | None = False) -> Iterator[tuple[str, pd.DataFrame]]:
    """Validated tracks of an input, one at a time (the checks of :func:`iter_track_chunks`).

    Parameters
    ----------
    path : str, path-like, list or pandas.DataFrame
        A file in any of :data:`FORMATS`, a directory of Parquet files, a DataFrame read like a file, or
        several files (a list, a glob or a directory of other files: :func:`resolve_input`), each read on its
        own with its track ids prefixed by its name.
    schema : Schema, optional
        :data:`FIXES` (position fixes, the default), :data:`MEASUREMENTS` or :data:`CELLS`.
    on_error : {"raise", "skip"}, optional
        Raise a DataError naming file, row and column at the first bad row, or drop bad rows and count
        them by reason in ``report``.
    chunk_rows : int, optional
        Rows per chunk (memory).
    report : ReadReport, optional
        Receives the counts of dropped rows and the notes of how the input was read.
    strict : bool, optional
    read : ReadOptions, optional
        The input's column names and units where they are not recognised.
    sort : bool, optional
        As for :func:`iter_track_chunks`.

    Yields
    ------
    track_id : str
    rows : pandas.DataFrame
    """
    for chunk in iter_track_chunks(path, schema, on_error=on_error, chunk_rows=chunk_rows, report=report,
                                   strict=strict, read=read, sort=sort):
        ids = chunk["track_id"].to_numpy(dtype=object)
        bounds = track_offsets(ids)
        for a, b in zip(bounds[:-1], bounds[1:]):
            yield str(ids[a]), chunk.iloc[a:b].reset_index(drop=True)


def _contiguous(chunk: pd.DataFrame, open_id, finished: set, path, on_error: str, report: ReadReport):
    """Drop (or raise on) runs of rows whose track already ended earlier in the file."""
    ids = chunk["track_id"].to_numpy(dtype=object)
    starts = track_offsets(ids)[:-1]
    seen = set(finished)
    bad_runs = []
    for j, a in enumerate(starts):
        tid = str(ids[a])
        if tid in seen or (tid == open_id and j > 0):
            bad_runs.append(j)
        seen.add(tid)
        if j == 0 and tid != open_id and open_id is not None:
            seen.add(open_id)
    if not bad_runs:
        return chunk
    ends = np.r_[starts[1:], len(ids)]
    keep = np.ones(len(ids), dtype=bool)
    for j in bad_runs:
        a, b = starts[j], ends[j]
        err = DataError(f"track {str(ids[a])!r} appears again after other tracks; the rows of a track "
                        "must be contiguous (sort the file by track_id, time)", file=path,
                        row=int(chunk["row"].iloc[a]), column="track_id")
        if on_error == "raise":
            raise err
        err.kind = "track rows not contiguous"
        report.skip(err, count=int(b - a))
        keep[a:b] = False
    return chunk.loc[keep].reset_index(drop=True)


def _ordered(chunk: pd.DataFrame, open_id, open_t: float, open_last, strict: bool, path, on_error: str,
             report: ReadReport) -> pd.DataFrame:
    """Drop exact repeats of a track's previous row (counted), then keep rows whose time is after
    every earlier row's of the same track (>= if not strict); ``open_last`` is the last row (a 1-row
    frame) of the open track ``open_id``."""
    chunk = _without_repeats(chunk, open_id, open_last, report)
    ids = chunk["track_id"].to_numpy(dtype=object)
    t = chunk["t"].to_numpy(dtype=float)
    new_run = np.r_[True, ids[1:] != ids[:-1]]
    run_no = np.cumsum(new_run) - 1
    running = pd.Series(t).groupby(run_no).cummax().to_numpy()
    before = np.r_[-np.inf, running[:-1]]
    before[new_run] = -np.inf
    if len(ids) and ids[0] == open_id:
        first_run = run_no == 0
        before[first_run] = np.maximum(before[first_run], open_t)
    ok = t > before if strict else t >= before
    if ok.all():
        return chunk
    i = int(np.flatnonzero(~ok)[0])
    same = t[i] == before[i]
    what = (f"time {chunk['time'].iloc[i]!s} repeats the track's previous time stamp with other values"
            if same else f"time {chunk['time'].iloc[i]!s} is before the track's previous time stamp")
    err = DataError(f"{what}; a track can have one fix per time stamp (--on-error skip drops such rows)",
                    file=path, row=int(chunk["row"].iloc[i]), column="time")
    if on_error == "raise":
        raise err
    err.kind = "same time, other values" if same else "time not increasing"
    report.skip(err, count=int((~ok).sum()))
    return chunk.loc[ok].reset_index(drop=True)


def _without_repeats(chunk: pd.DataFrame, open_id, open_last, report: ReadReport) -> pd.DataFrame:
    """The chunk without rows equal in every column (but ``row``) to the row before them in the same
    track (only rows that repeat the time are compared)."""
    ids = chunk["track_id"].to_numpy(dtype=object)
    t = chunk["t"].to_numpy(dtype=float)
    cont = open_last is not None and ids[0] == open_id
    prev_t = np.r_[open_last["t"].iloc[0] if cont else np.nan, t[:-1]]
    same = np.r_[cont, ids[1:] == ids[:-1]] & (t == prev_t)
    if not same.any():
        return chunk
    cols = [c for c in chunk.columns if c != "row"]
    both = pd.concat([open_last[cols], chunk[cols]], ignore_index=True) if cont else \
        pd.concat([chunk[cols].iloc[:1], chunk[cols]], ignore_index=True)
    idx = np.flatnonzero(same)
    cur, prev = both.iloc[idx + 1].reset_index(drop=True), both.iloc[idx].reset_index(drop=True)
    equal = (cur.eq(prev) | (cur.isna() & prev.isna())).all(axis=1).to_numpy()
    if not equal.any():
        return chunk
    repeat = np.zeros(len(chunk), bool)
    repeat[idx[equal]] = True
    report.duplicates_dropped += int(repeat.sum())
    report.notes[:] = [x for x in report.notes if not x.startswith("duplicate rows:")]
    report.note(f"duplicate rows: {report.duplicates_dropped} exact repeats of the row before them were dropped")
    return chunk.loc[~repeat].reset_index(drop=True)


def read_cells(path, *, wanted=None, units=None, on_error: str = "raise", report: ReadReport | None = None,
               chunk_rows: int = DEFAULT_CHUNK_ROWS) -> pd.DataFrame:
    """A cell table in the OpenCelliD CSV layout, indexed by ``cell_id`` = "mcc-net-area-cell".

    Missing optional columns get their documented defaults: height_m 30 m, power_dbm 43 dBm, arfcn empty
    (1800 MHz carrier).

    Parameters
    ----------
    path : str, path-like or pandas.DataFrame
        The table (CSV or Parquet).
    wanted : iterable of str, optional
        Keep only these cell ids (a country-sized table is then streamed, not held).
    units : iterable of int, optional
        With ``wanted``: keep the cells whose ``unit`` (PCI/PSC) is one of these too (cells a log names
        by PCI, :func:`mptrack.tracking.resolve_cells`).
    on_error : {"raise", "skip"}, optional
        Raise a DataError naming file, row and column at the first bad row, or drop bad rows and count
        them by reason in ``report``.
    report : ReadReport, optional
        Receives the counts of dropped rows and the notes of how the input was read.
    chunk_rows : int, optional
        Rows per chunk (memory).

    Returns
    -------
    pandas.DataFrame

    Raises
    ------
    DataError
        A cell id listed twice (naming the second row), or a table without rows.
    """
    wanted = None if wanted is None else set(wanted)
    units = set() if units is None else {int(u) for u in units}
    report = report if report is not None else ReadReport()
    keep = []
    for chunk in read_chunks(path, CELLS, on_error=on_error, report=report, chunk_rows=chunk_rows):
        chunk["cell_id"] = cell_key(chunk["mcc"], chunk["net"], chunk["area"], chunk["cell"]).to_numpy()
        if wanted is not None:
            keep_rows = chunk["cell_id"].isin(wanted)
            if units and "unit" in chunk.columns:
                keep_rows |= chunk["unit"].isin(units)
            chunk = chunk.loc[keep_rows]
        keep.append(chunk)
    if report.rows_read == 0:
        raise DataError("the cell table is empty: it has a header only, no cells", file=source_label(path))
    cells = pd.concat(keep, ignore_index=True) if keep else pd.DataFrame(columns=["cell_id", "row"])
    dup = cells["cell_id"].duplicated()
    if dup.any():
        i = int(np.flatnonzero(dup.to_numpy())[0])
        raise DataError(f"cell {cells['cell_id'].iloc[i]!r} is listed twice",
                        file=source_label(path),
                        row=int(cells["row"].iloc[i]), column="cell")
    for name, default in (("height_m", 30.0), ("power_dbm", 43.0), ("arfcn", np.nan)):
        if name not in cells.columns:
            cells[name] = default
        elif name != "arfcn":
            cells[name] = cells[name].fillna(default)
    return cells.set_index("cell_id")
