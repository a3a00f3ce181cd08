"""Running ``track`` over an input: chunks of whole tracks through the engine, on any executor,
resumable, written atomically; and the in-memory Python API.

The input (a file, a directory of Parquet files / a hive-partitioned dataset,
or a DataFrame) is read in chunks of whole tracks
(:func:`mptrack.io.iter_track_chunks`); each chunk is one unit of work
(:class:`TrackTask`): position fixes go through the columnar engine
(:func:`._run.track_table`), cellular measurements through the range filters
track by track.  :func:`mptrack.runs.run_stream` runs the chunks serially, in
local processes or on Dask, each writing its point and track tables as parts
in ``.<out>.parts/``; the output is then streamed from the parts.  Every
chunk is computed by the same function from the same rows, so the output does
not depend on the executor.
"""

from __future__ import annotations

import json
import time
from collections import deque
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from .._core.data_checks import check_outputs
from .._core.tracks import track_offsets
from .._core.validation import check_bool, check_int, check_path
from ..errors import ParameterError
from ..io import (FIXES, MEASUREMENTS, InputNotSorted, ReadOptions, ReadReport, input_label, input_name, input_paths,
                  iter_track_chunks, output_format, read_cells, read_chunks, resolve_input)
from ..runs import Chunk, PartStore, output_lock, read_part, resumable_outputs, run_stream
from ._advice import far_from_band, nis_advice
from ._cellular import check_cell_ids, resolve_cells, track_cells
from ._columns import FixTable
from ._fixes import CELL_ONLY, FIX_ONLY, TrackOptions
from ._consistency import flag_counts, nis_sentence, nis_stats, pooled_nis
from ._evaluate import TRUTH_COLUMNS, check_points, evaluate_tracks
from ._output import point_table
from ._noise import SIGMA_FLOOR_M
from ._run import TRACK_COLUMNS, track_table

__all__ = ["track_file", "track", "write_track_report", "TrackTask", "DEFAULT_CHUNK_ROWS"]

#: Rows of whole tracks per unit of work (memory per chunk ~0.5 KB a row in flight).
DEFAULT_CHUNK_ROWS = 200_000
#: Up to this many tracks the run summary lists each track's noise estimates (beyond: the track table).
MAX_LISTED_TRACKS = 1000
_PARTS = ("points", "tracks")


@dataclass(frozen=True, eq=False)
class TrackTask:
    """One chunk of whole tracks -> {"points": point table, "tracks": track table} (picklable).

    cells   the cell table (cellular logs) or None (position fixes)
    fixed   pooled noise estimates to use instead of estimating (``noise="file"``)
    """

    options: TrackOptions
    cells: pd.DataFrame | None = None
    fixed: dict | None = None

    def __call__(self, chunk: Chunk) -> dict:
        rows = chunk.data
        if self.cells is None:
            points, tracks = track_table(FixTable.from_frame(rows), self.options, self.fixed)
            return {"points": _with_input_columns(points, rows), "tracks": tracks}
        return self._cellular(rows)

    def _cellular(self, rows: pd.DataFrame) -> dict:
        """Track by track through the range filters (rows with unknown cells were removed on reading)."""
        ids = rows["track_id"].to_numpy(dtype=object)
        bounds = track_offsets(ids)
        tables = [pa.Table.from_pandas(track_cells(str(ids[a]), rows.iloc[a:b], self.cells, self.options),
                                       preserve_index=False) for a, b in zip(bounds[:-1], bounds[1:])]
        points = pa.concat_tables(tables) if tables else None
        return {"points": points if points is not None else _empty_points(), "tracks": _cell_tracks(points)}


def _with_input_columns(points: pa.Table, rows: pd.DataFrame) -> pa.Table:
    """The point table with the input's own further columns (accuracy_m, hdop, elevation, speed, any
    user column) appended, where it has one row per input row (the gated filter; the grid filters
    resample).  A name the point table already uses gets the prefix ``input_``."""
    extra = [c for c in ("accuracy_m",) if c in rows.columns] + FIXES.extra_columns(rows.columns)
    if not extra or points.num_rows != len(rows):
        return points
    for name in extra:
        values = rows[name]
        try:
            arr = pa.array(values, from_pandas=True)
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # mixed types in one column: keep the text
            arr = pa.array(values.astype("string"), from_pandas=True)
        points = points.append_column(f"input_{name}" if name in points.column_names else name, arr)
    return points


def _empty_points() -> pa.Table:
    z = np.zeros(0)
    return point_table([], np.zeros(1, np.int64), z, z, z, z, None, z, z, z, z, z.astype(np.int64),
                       z.astype(np.int8), 30.0, (z, z), "", {})


def _cell_tracks(points: pa.Table | None) -> pa.Table:
    """Track table of cellular tracks: counts and NIS consistency (no noise estimation)."""
    if points is None or points.num_rows == 0:
        return pa.table({"track_id": pa.array([], pa.string()), "fixes": pa.array([], pa.int64())})
    df = points.select(["track_id", "flag", "nis", "nis_dof"]).to_pandas()
    ids, flag = df["track_id"].to_numpy(dtype=object), df["flag"].to_numpy(dtype=object)
    nis, dof = df["nis"].to_numpy(float), df["nis_dof"].to_numpy(float)
    bounds = track_offsets(ids)
    stats = pd.DataFrame([nis_stats(nis[a:b], dof[a:b], flag[a:b]) for a, b in zip(bounds[:-1], bounds[1:])])
    out = pd.DataFrame({"track_id": [str(i) for i in ids[bounds[:-1]]], "fixes": np.diff(bounds),
                        "updates": flag_counts(flag, bounds)["updates"]})
    out = pd.concat([out, stats.drop(columns="nis_fixes")], axis=1)
    return pa.Table.from_pandas(out, preserve_index=False)


def _source_chunks(source, schema, on_error: str, chunk_rows: int, report: ReadReport, read: ReadOptions,
                   sort: bool | None, cells=None):
    """Chunks of whole tracks of a path or a DataFrame, numbered; with a cell table, rows of unknown
    cells raise or are dropped and counted (a track left without rows is dropped)."""
    label = input_label(source)
    for i, rows in enumerate(iter_track_chunks(source, schema, on_error=on_error, chunk_rows=chunk_rows,
                                               report=report, read=read, sort=sort)):
        if cells is not None:
            if "pci" in rows.columns:
                rows = resolve_cells(rows, cells, file=label, report=report)
            rows = check_cell_ids(rows, cells, file=label, report=report)
        yield Chunk(i, 0, len(rows), data=rows)


def _manifest(input, options: TrackOptions, cells, chunk_rows: int, read: ReadOptions) -> dict:
    """What a resumed run must share with the interrupted one: the input file(s) as they were, the
    options and the chunking."""
    if isinstance(input, list):
        files = input
    else:
        path = Path(input)
        files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    stamp = [[str(p), p.stat().st_size, p.stat().st_mtime_ns] for p in files]
    return {"input": stamp, "cells": None if cells is None else str(cells), "chunk_rows": chunk_rows,
            "options": {k: v for k, v in asdict(options).items()}, "read": json.loads(json.dumps(asdict(read)))}


def _cell_table(input, cells, on_error: str, chunk_rows: int, read: ReadOptions) -> tuple[pd.DataFrame, ReadReport]:
    cell_report = ReadReport()
    wanted, units = set(), set()
    for chunk in read_chunks(input, MEASUREMENTS, on_error="skip", chunk_rows=chunk_rows, report=ReadReport(),
                             read=read):
        wanted.update(chunk["cell_id"].dropna().unique())
        if "pci" in chunk.columns:  # cells logged by PCI (resolve_cells): the table's cells of those PCIs
            units.update(chunk["pci"].dropna().astype(int).tolist())
    return read_cells(cells, wanted=wanted, units=units, on_error=on_error, report=cell_report), cell_report


def _file_noise(chunks, options: TrackOptions):
    """For ``noise="file"``: the pooled estimate of the first chunk, and the chunks (that one again
    first)."""
    first = next(chunks, None)
    if first is None:
        return None, iter(())
    from ._noise import estimate_noise, fix_weights
    from ._run import noise_spec

    table = FixTable.from_frame(first.data)
    w, has = fix_weights(table, options.sigma_m)
    fixed = estimate_noise(table, w, has, noise_spec(options)).pooled

    def again():
        yield first
        yield from chunks
    return fixed, again()


def _run(source, options: TrackOptions, *, cells_table, on_error, chunk_rows, executor, max_workers, client,
         store: PartStore | None, manifest: dict | None, progress, report: ReadReport, read: ReadOptions):
    """Run every chunk; returns the per-chunk results (paths with a store, else tables).

    The input is streamed while its rows are in (track, time) order; at the first row that is
    not, the work so far is dropped and the input is read whole and sorted (a note says how many
    rows moved)."""
    schema = MEASUREMENTS if cells_table is not None else FIXES
    for sort in (None, True):
        chunks = _source_chunks(source, schema, on_error, chunk_rows, report, read, sort, cells_table)
        fixed = None
        try:
            if cells_table is None and options.noise == "file" and (options.sigma_m is None or options.q is None):
                fixed, chunks = _file_noise(chunks, options)
            chunks, advance = _counting_tracks(chunks, progress)
            return run_stream(TrackTask(options, cells_table, fixed), chunks, parts=_PARTS,
                              out_dir=None if store is None else store.dir, part_format="arrow", executor=executor,
                              max_workers=max_workers, client=client, manifest=manifest, progress=advance)
        except InputNotSorted:
            if store is not None:
                store.discard()
            report.reset()


def _counting_tracks(chunks, progress):
    """(the chunks as they are read, a progress callback for run_stream): each finished chunk advances
    ``progress`` by its number of tracks (taken in the order the chunks were read: exact with the
    serial executor, close with the others), so progress counts tracks, not chunks."""
    if progress is None:
        return chunks, None
    sizes: deque[int] = deque()

    def read():
        for chunk in chunks:
            sizes.append(int(chunk.data["track_id"].nunique()))
            yield chunk

    def advance(k: int = 1) -> None:
        progress(sum(sizes.popleft() for _ in range(min(k, len(sizes)))))
    return read(), advance


def track_file(input, out, *, cells=None, options: TrackOptions = TrackOptions(), on_error: str = "raise",
               read: ReadOptions = ReadOptions(), resume: bool = False, chunk_rows: int = DEFAULT_CHUNK_ROWS, executor: str = "serial",
               max_workers: int | None = None, client=None, track_summary=None, progress=None,
               on_points=None, note: str = "") -> dict:
    """Track every track of an input file and write the point table, with bounded memory, on any
    executor, resumable.

    Memory is bounded by ``chunk_rows`` and the largest track, not by the input.  An output that is an
    input (or inside an input directory) is refused; ``out`` and ``track_summary`` are locked for the whole
    run (:func:`mptrack.runs.resumable_outputs`), their stale temporary files removed.  A run stopped by bad
    input or options leaves nothing (a resumed run keeps the parts it came to resume); one stopped by
    Ctrl-C, an OS failure or a crash keeps its finished chunks in ``.<out>.parts/`` for ``resume=True``.

    Parameters
    ----------
    input : str, path-like or list
        Position fixes (CSV, Parquet, GPX, TCX, FIT, NMEA, GeoJSON; a directory, a list or a glob of files)
        or, with ``cells``, a cellular measurement log (CSV/Parquet).
    out : str or path-like
        The point table: .parquet, .csv, .geojson, .gpx or .geoparquet (written atomically).
    cells : str or path-like, optional
        A cell table in the OpenCelliD layout: cellular tracking (``options.method``).
    options : TrackOptions, optional
    on_error : {"raise", "skip"}, optional
        The first bad row stops the run (DataError naming file, row and column; nothing written), or bad
        rows are dropped, counted and reported, and more than ``read.max_skip`` stop the run.
    read : ReadOptions, optional
        The input's column names and units where they are not recognised.
    resume : bool, optional
        Keep the chunks finished by an interrupted run of the same input and options.
    chunk_rows : int, optional
        Rows of whole tracks per chunk (memory).
    executor : {"serial", "processes", "dask"}, optional
        Who runs the chunks (:func:`mptrack.runs.run_stream`); the output is the same.
    max_workers : int, optional
    client : dask.distributed.Client, optional
    track_summary : str or path-like, optional
        Also write the track table (one row per track: noise estimates, counts, NIS).
    progress : optional
        A progress reporter (the CLI's).
    on_points : callable, optional
        Called once, after ``out`` is written, with the paths of the chunks' point tables (Arrow IPC
        files, in output row order), to read the run's points again without reading ``out`` back; the
        files are removed after the call.
    note : str, optional
        Shown to another run refused these outputs (the CLI passes its command line).

    Returns
    -------
    dict
        The run summary (JSON-safe): counts, the noise estimates' distribution, the mean NIS and advice.

    Raises
    ------
    DataError
        Bad input (naming file, row and column).
    OutputError
        An output that cannot be written or that another run holds.
    """
    start = time.perf_counter()
    input, out = resolve_input(input, "input"), check_path("out", out)
    if not isinstance(options, TrackOptions):
        raise ParameterError(f"options: expected TrackOptions, got {type(options).__name__}")
    check_outputs(*input_paths(input), cells, out=out, track_summary=track_summary)
    chunk_rows = check_int("chunk_rows", chunk_rows, minimum=1)
    if track_summary is not None:
        output_format(track_summary)
    with resumable_outputs(out, track_summary, resume=resume, note=note, last_part=_PARTS[-1]) as store:
        report = ReadReport()
        cell_table, cell_report = (None, None) if cells is None else _cell_table(input, cells, on_error,
                                                                                 chunk_rows, read)
        progress = progress or _NullProgress()
        with progress.task(f"tracking the tracks of {input_name(input)}", total=None) as advance:
            results = _run(input, options, cells_table=cell_table, on_error=on_error, chunk_rows=chunk_rows,
                           executor=executor, max_workers=max_workers, client=client, store=store,
                           manifest=_manifest(input, options, cells, chunk_rows, read), progress=advance,
                           report=report, read=read)
        resumed = [p for p in store.resumed if p.exists()]  # an unsorted input starts again from scratch
        files = store.check(results)  # every chunk's parts, or an OutputError if some vanished
        points = sum(_rows(p) for p in files.get("points", ()))
        tracks_resumed = sum(_rows(p) for p in resumed)
        store.finish(files.get("points", []), empty=_empty_points())
        if on_points is not None:
            on_points(files.get("points", []))
        tracks = _tracks_frame([read_part(p) for p in files.get("tracks", ())])
        if track_summary is not None:
            store.finish(files.get("tracks", []), to=track_summary,
                         empty=pa.Table.from_pandas(tracks, preserve_index=False))
        store.discard()
    summary = _summary(tracks, report, options, len(results), cellular=cells is not None)
    summary.update(input=str(input_label(input)), output=str(out), points_written=points, chunks_resumed=len(resumed),
                   tracks_resumed=tracks_resumed, elapsed_s=time.perf_counter() - start)
    if track_summary is not None:
        summary["track_summary"] = str(track_summary)
    if cell_table is not None:
        summary["cells"] = {"file": str(cells), "cells_used": int(len(cell_table)), "read": cell_report.to_dict()}
    return summary


def _rows(path) -> int:
    return read_part(path).num_rows


def _tracks_frame(tables: list) -> pd.DataFrame:
    """The track table of all chunks (their track tables in order)."""
    return pa.concat_tables(tables).to_pandas() if tables else pd.DataFrame(columns=list(TRACK_COLUMNS))


class _NullProgress:
    def task(self, description, total=None):
        return nullcontext(lambda n=1: None)


def _summary(tracks: pd.DataFrame, report: ReadReport, options: TrackOptions, chunks: int, *,
             cellular: bool = False) -> dict:
    """The run summary (JSON-safe): counts, the noise estimates' distribution, NIS consistency and
    what to do about tracks far outside their band."""
    n = len(tracks)
    total = (lambda col: int(tracks[col].sum()) if col in tracks and n else 0)  # noqa: E731
    out = {"tracks": n, "chunks": chunks, "fixes": total("fixes"), "outliers_rejected": total("outliers"),
           "manoeuvres": total("manoeuvres"), "resets": total("resets"), "restarts": total("restarts"),
           "read": report.to_dict(),
           "options": asdict(options)}
    if n and "sigma_m" in tracks:
        if n <= MAX_LISTED_TRACKS:
            cols = ["track_id", "fixes", "sigma_m", "sigma_se_m", "sigma_slow_m", "accuracy_scale", "q", "q_se",
                    "sigma_source", "q_source", "mean_nis", "nis_consistent"]
            out["track_noise"] = [{k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                                   for k, v in row.items()} for row in tracks[cols].to_dict("records")]
        noise = {name: _distribution(tracks[name].to_numpy(float)) for name in ("sigma_m", "sigma_slow_m", "q")
                 if name in tracks}
        for name in ("sigma_source", "q_source"):
            noise[name] = {str(k): int(v) for k, v in tracks[name].value_counts().items()}
        noise["sigma_at_floor"] = int(((tracks["sigma_source"] != "given")
                                       & (tracks["sigma_m"] <= SIGMA_FLOOR_M * 1.0001)).sum())
        out["noise"] = noise
    if n and "nis_consistent" in tracks:
        used = tracks["updates"] + tracks.get("manoeuvres", 0)
        outside = ~tracks["nis_consistent"].astype(bool) & (used > 0)
        low, high = far_from_band(tracks["mean_nis"], tracks["nis_dof"], used)
        pooled = pooled_nis(tracks["mean_nis"], tracks["nis_dof"], used)
        out["nis"] = {**pooled, "sentence": nis_sentence(pooled),
                      "tracks_outside_band": int(outside.sum()), "tracks_judged": int((used > 0).sum()),
                      "far_low": int(low.sum()),
                      "far_high": int(high.sum()),
                      "advice": nis_advice(int(low.sum()), int(high.sum()), options, cellular=cellular)}
    return out


def _distribution(x: np.ndarray) -> dict:
    x = x[np.isfinite(x)]
    if not len(x):
        return {}
    return {"median": float(np.median(x)), "p5": float(np.percentile(x, 5)), "p95": float(np.percentile(x, 95))}


def track(data, *, cells=None, model: str | None = None, filter: str | None = None, smooth: bool = False,
          sigma_m: float | None = None, q: float | None = None, noise: str | None = None,
          gate_probability: float | None = None, max_gap_s: float | None = None, method: str | None = None,
          motion: str | None = None, path_loss: str | None = None, q_km2: float | None = None, r_km2: float | None = None,
          scan_interval_s: float | None = None, gap_s: float | None = None, columns=None, time_unit: str = "auto",
          time_format: str | None = None, coord_unit: str = "auto", on_error: str = "raise",
          max_skip: str | None = None, chunk_rows: int = DEFAULT_CHUNK_ROWS, executor: str = "serial",
          max_workers: int | None = None, client=None, report=None, **unknown) -> pd.DataFrame:
    """Track a log in memory, as ``mptrack track`` does: the point table as a pandas DataFrame.

    Every option is ``mptrack track``'s under its library name (``sigma_m`` is ``--sigma``,
    ``gate_probability`` ``--gate``, ``r_km2`` the square of ``--range-sigma`` in km); an option left
    at None takes its default.  Options for position fixes and options for cellular measurements
    (``cells`` given) exclude each other, as on the command line.

    Parameters
    ----------
    data : DataFrame, path, list of paths or glob
        Position fixes (columns as in a file: ``track_id``, ``time``, ``lat``/``lon`` or ``x``/``y``,
        ``accuracy_m``; other names and units are recognised as ``mptrack track`` does) or, with
        ``cells``, cellular measurements; or a file in any input format, a directory, several files
        or a glob (each file's tracks kept apart).
    cells : DataFrame or path, optional
        The cell table (OpenCelliD layout): track cellular measurements instead of position fixes.
    model : {"cv", "ca"}, optional
        Position fixes: the motion model (default "cv").
    filter : str, optional
        Position fixes: "kf" (default: gated, at the fixes' own times) or a linear filter on a
        regular grid ("lf", "sskf", ...; :data:`mptrack.tracking.FIX_FILTERS`).
    smooth : bool
        Position fixes: add a Rauch-Tung-Striebel smoothing pass.
    sigma_m, q : float, optional
        Position fixes: the fix noise (1-sigma per axis, m; where a fix has no ``accuracy_m``) and the
        process-noise density (m^2/s^3 for cv, m^2/s^5 for ca).  Default: estimated from each track.
    noise : {"track", "file"}, optional
        Position fixes: one noise estimate per track (default) or one for the whole input.
    gate_probability : float, optional
        Position fixes: the NIS gate's chi-square probability (default 0.999); 1 disables gating.
    max_gap_s : float, optional
        Position fixes: a gap longer than this (s, default 600) starts a new segment of the track (its
        next fix starts the filter again); ``math.inf`` bridges every gap.
    method : {"ekf", "fekf", "fcs"}, optional
        Cellular: the range filter (default "ekf"; Bouzera et al. 2017).
    motion : {"random-walk", "cv"}, optional
        Cellular: the motion model (default "random-walk").
    path_loss : str, optional
        Cellular: the path-loss model that turns RSS into ranges (default "cost231-wi-nlos";
        :data:`mptrack.radio.PATH_LOSS_MODELS`).
    q_km2, r_km2, scan_interval_s : float, optional
        Cellular: process noise, range-noise variance (km^2; default 0.222) and scan grid step (s).
    gap_s : float, optional
        An interval longer than this (s, default 30) flags the point after it as following a gap.
    columns, time_unit, time_format, coord_unit : optional
        How the input is read where its names or units are not recognised
        (:class:`mptrack.io.ReadOptions`), e.g. ``columns="time=ts,lat=Latitude"``.
    on_error : {"raise", "skip"}
        "raise": the first bad row is an error; "skip": bad rows are dropped and counted.
    max_skip : str, optional
        With ``on_error="skip"``: the most rows that may be dropped ("1%" of the rows read by
        default, or a count such as "50").
    chunk_rows, executor, max_workers, client
        Rows of whole tracks per chunk, and who runs the chunks ("serial", "processes" or "dask";
        ``max_workers`` with processes or Dask, ``client`` a Dask client).  The result is the same.
    report : path, optional
        Also write the HTML report of the run there (the page ``mptrack track --report`` writes).

    Returns
    -------
    DataFrame
        One row per estimate (columns in docs/tracking.md).  ``attrs["tracks"]`` holds the track
        table (one row per track: the noise estimates with their standard errors, counts, the mean
        NIS and its band) and ``attrs["summary"]`` the run summary (as :func:`track_file` returns).

    Raises
    ------
    mptrack.errors.ParameterError
        An unknown option, an option that does not apply (``method`` without ``cells``, ``model``
        with them, ``max_workers`` with the serial executor, ``max_skip`` without
        ``on_error="skip"``) or a bad value; :class:`~mptrack.errors.UnknownNameError` for an unknown
        model, filter or method.
    mptrack.errors.DataError
        Bad input, naming file, row and column.
    mptrack.errors.OutputError
        The report cannot be written (another run holds it, the disk is full, ...).

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007

    Examples
    --------
    >>> import mptrack
    >>> log = mptrack.simulate("gps", tracks=2, seed=0, duration_s=60.0)
    >>> points = mptrack.track(log, smooth=True)
    >>> sorted(points["track_id"].unique())
    ['sim0001', 'sim0002']
    >>> mptrack.track(log, method="ukf")
    Traceback (most recent call last):
    ...
    mptrack.errors.ParameterError: method: applies to cellular measurements only: give the cell table with cells=...
    """
    if unknown:
        raise ParameterError(_unknown_option(sorted(unknown)[0]))
    given = {"model": model, "filter": filter, "smooth": check_bool("smooth", smooth) or None, "q": q,
             "sigma_m": sigma_m, "noise": noise, "gate_probability": gate_probability, "max_gap_s": max_gap_s, "method": method,
             "motion": motion, "path_loss": path_loss, "q_km2": q_km2, "r_km2": r_km2,
             "scan_interval_s": scan_interval_s, "gap_s": gap_s}
    given = {k: v for k, v in given.items() if v is not None}
    wrong = [k for k in (FIX_ONLY if cells is not None else CELL_ONLY) if k in given]
    if wrong:
        raise ParameterError(f"{wrong[0]}: applies to position fixes, not to cellular measurements (cells=...)"
                             if cells is not None else
                             f"{wrong[0]}: applies to cellular measurements only: give the cell table with cells=...")
    for name, value, why in (("max_workers", max_workers if executor == "serial" else None,
                              "applies to executor='processes' or 'dask'"),
                             ("client", client if executor != "dask" else None, "applies to executor='dask'"),
                             ("max_skip", max_skip if on_error != "skip" else None, "applies to on_error='skip'")):
        if value is not None:
            raise ParameterError(f"{name}: {why}")
    if given.get("gate_probability") == 1:
        given["gate_probability"] = None  # 1 disables gating, as --gate 1
    data = resolve_input(data, "data")
    opts = TrackOptions(**given)
    read = ReadOptions(columns=columns or (), time_unit=time_unit, time_format=time_format, coord_unit=coord_unit,
                       **({} if max_skip is None else {"max_skip": max_skip}))
    chunk_rows = check_int("chunk_rows", chunk_rows, minimum=1)
    if report is not None:
        check_outputs(*input_paths(data),
                      *([] if cells is None or isinstance(cells, pd.DataFrame) else [cells]), report=report)
    with nullcontext() if report is None else output_lock(report):
        report_of_reading = ReadReport()
        cell_table = None if cells is None else _cell_table(data, cells, on_error, chunk_rows, read)[0]
        results = _run(data, opts, cells_table=cell_table, on_error=on_error, chunk_rows=chunk_rows,
                       executor=executor, max_workers=max_workers, client=client, store=None, manifest=None,
                       progress=None, report=report_of_reading, read=read)
        points = pa.concat_tables([r["points"] for r in results]) if results else _empty_points()
        tracks = _tracks_frame([r["tracks"] for r in results])
        df = points.to_pandas()
        df.attrs["tracks"] = tracks
        df.attrs["summary"] = _summary(tracks, report_of_reading, opts, len(results), cellular=cells is not None)
        if report is not None:
            write_track_report(df, report, run=df.attrs["summary"], title="mptrack.track")
            df.attrs["summary"]["report"] = str(report)
    return df


def _unknown_option(name: str) -> str:
    """The message for an option :func:`track` does not have, with the nearest one it has."""
    import difflib
    import inspect

    known = [p for p in inspect.signature(track).parameters if p not in ("data", "unknown")]
    near = difflib.get_close_matches(name, known, n=1) + difflib.get_close_matches(
        {"sigma": "sigma_m", "gate": "gate_probability", "range_sigma": "r_km2"}.get(name, ""), known, n=1)
    return (f"{name}: not an option of mptrack.track" + (f"; did you mean {near[0]}?" if near else "")
            + f" (the options are: {', '.join(known)})")


def write_track_report(points: pd.DataFrame, path, *, run: dict | None = None, title: str = "mptrack track",
                       budget: int | None = None):
    """Write the HTML report of a tracking run, as ``mptrack track --report`` and ``track(report=...)`` do.

    The points are evaluated against the truth columns a simulated log passes through (true_lat/true_lon
    or true_x/true_y) when they have them, then drawn by :func:`mptrack.report.write_report`.

    Parameters
    ----------
    points : pandas.DataFrame
        The run's point table, or the columns of it :func:`mptrack.report.report_points` keeps.
    path : str or path-like
        The HTML file.
    run : dict, optional
        The run's summary (rows skipped, NIS advice).
    title : str, optional
    budget : int, optional
        Points drawn at most (decimation keeps every event).

    Returns
    -------
    pathlib.Path
    """
    from ..report import write_report

    check_points("points", points)   # (evaluate_tracks checks it again, naming its own argument)
    own = any(a in points.columns and b in points.columns for a, b, _ in TRUTH_COLUMNS)
    summary, table = evaluate_tracks(points, truth_columns=own)
    return write_report(table, path, summary=summary, run=run, title=title,
                        **({} if budget is None else {"budget": budget}))

