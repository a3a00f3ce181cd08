"""``track``: stream an input file track by track, filter each, write the result atomically (resumable)."""

from __future__ import annotations

import time
from contextlib import nullcontext
from pathlib import Path

import pandas as pd

from ..errors import MptrackError
from ..io import FIXES, MEASUREMENTS, PartStore, ReadReport, iter_tracks, read_cells, read_chunks
from ._cellular import check_cell_ids, track_cells
from ._fixes import TrackOptions, track_fixes

__all__ = ["track_file"]


class _NullProgress:
    def task(self, description, total=None):
        return nullcontext(lambda n=1: None)


def track_file(input, out, *, cells=None, options: TrackOptions = TrackOptions(), on_error: str = "raise",
               resume: bool = False, chunk_rows: int = 50_000, flush_rows: int = 50_000,
               progress=None) -> dict:
    """Track every track of ``input`` and write the point table to ``out`` (.parquet, .csv or .geojson).

    input    position fixes (CSV/Parquet/GPX) or, with ``cells``, a cellular measurement log (CSV/Parquet)
    cells    cell table in the OpenCelliD layout (CSV/Parquet) -> cellular tracking (options.method)
    resume   keep the tracks finished by an interrupted run (kept in ``.<out>.parts/``, written every
             ``flush_rows`` rows and on interruption) and skip them
    on_error "raise": the first bad row stops the run (DataError naming file/row/column, nothing written);
             "skip": bad rows are dropped, counted and reported in the returned summary

    The input is read in chunks and one track is held at a time, so memory is
    bounded by the largest track.  Returns a summary dict (JSON-safe).
    """
    start = time.perf_counter()
    input, out = Path(input), Path(out)
    store = PartStore(out, flush_rows=flush_rows)
    if not resume:
        store.discard()
    report = ReadReport()
    progress = progress or _NullProgress()
    cell_table = None
    if cells is not None:
        cell_report = ReadReport()
        wanted = set()
        for chunk in read_chunks(input, MEASUREMENTS, on_error="skip", chunk_rows=chunk_rows,
                                 report=ReadReport()):
            wanted.update(chunk["cell_id"].dropna().unique())
        cell_table = read_cells(cells, wanted=wanted, on_error=on_error, report=cell_report)
    finished = store.finished() if resume else set()
    done, resumed, points, outliers = 0, 0, 0, 0
    try:
        with progress.task(f"tracking {input.name}", total=None) as advance:
            schema = MEASUREMENTS if cell_table is not None else FIXES
            for tid, rows in iter_tracks(input, schema, on_error=on_error, chunk_rows=chunk_rows, report=report):
                if tid in finished:
                    resumed += 1
                    done += 1
                    advance()
                    continue
                if cell_table is not None:
                    rows = check_cell_ids(rows, cell_table, file=input, on_error=on_error, report=report)
                    if rows.empty:
                        continue
                    table = track_cells(tid, rows, cell_table, options)
                else:
                    table = track_fixes(tid, rows, options)
                store.add(table)
                done += 1
                points += len(table)
                outliers += int((table["flag"] == "outlier").sum())
                advance()
        store.finish()
    except MptrackError:
        store.discard()  # bad input: nothing to resume from, nothing left behind
        raise
    except BaseException:
        store.flush()  # interrupted: keep the finished tracks for --resume
        raise
    summary = {"input": str(input), "output": str(out), "tracks": done, "tracks_resumed": resumed,
               "points_written": points, "outliers_rejected": outliers, "read": report.to_dict(),
               "options": {k: v for k, v in vars(options).items()}, "elapsed_s": time.perf_counter() - start}
    if cell_table is not None:
        summary["cells"] = {"file": str(cells), "cells_used": int(len(cell_table)), "read": cell_report.to_dict()}
    return summary


def read_output(path) -> pd.DataFrame:
    """A track table written by :func:`track_file` (Parquet or CSV; GeoJSON points)."""
    from ..io._writers import output_format

    fmt = output_format(path)
    if fmt == "parquet":
        return pd.read_parquet(path)
    if fmt == "csv":
        return pd.read_csv(path, dtype={"track_id": "string"})
    import json

    feats = json.loads(Path(path).read_text())["features"]
    recs = [dict(f["properties"], lon=f["geometry"]["coordinates"][0], lat=f["geometry"]["coordinates"][1])
            for f in feats if f["properties"].get("kind") == "point" and f["geometry"]]
    return pd.DataFrame(recs)
