"""Benchmark suite of mptrack's readers and writers (``mptrack bench --suite io``).

Reading: a log of position fixes as CSV and as Parquet through
:func:`mptrack.io.read_chunks` (validated, consumed fully), each next to
``pandas.read_csv`` / ``pandas.read_parquet`` of the same file.  Writing: the
point table that ``mptrack track`` makes of that log, in every output format
through :func:`mptrack.io.write_table`, next to ``DataFrame.to_parquet`` of it;
and GPX built through gpxpy's objects on a sample, the alternative the GPX
writer was measured against.  Every anchor is timed in the same run; ratios
are time over the anchor's time.
"""

from __future__ import annotations

import tempfile
from collections import deque
from pathlib import Path

import numpy as np
import pandas as pd

from . import register_suite
from ._timing import best_time

__all__ = ["io_suite", "gpxpy_write"]

#: Output formats, in the order of the report.
OUTPUTS = ("parquet", "csv", "geojson", "gpx", "geoparquet")
#: Rows written through gpxpy's objects (its rate does not depend on the size, and it is slow).
GPXPY_ROWS = 20_000


def _fixes(rows: int, seed: int = 1) -> pd.DataFrame:
    """A simulated log of ``rows`` position fixes (tracks of ~200 fixes 1-3 s apart)."""
    from ..tracking import Intervals, simulate

    log, _ = simulate("gps", max(1, rows // 200 + 1), np.random.default_rng(seed), duration_s=400.0,
                      interval=Intervals.uniform(1.0, 3.0), accuracy_column=False)
    return log[["track_id", "time", "lat", "lon"]].iloc[:rows].reset_index(drop=True)


def gpxpy_write(points: pd.DataFrame, path) -> None:
    """The point table as GPX built through gpxpy (a GPXTrackPoint per row, an ElementTree element per
    extension value): the alternative to mptrack's vectorised GPX writer, for comparison."""
    import xml.etree.ElementTree as ET

    import gpxpy.gpx as gpx

    from ..io import GPX_EXTENSION_NAMESPACE as NAMESPACE

    doc = gpx.GPX()
    doc.nsmap["mptrack"] = NAMESPACE
    extra = [c for c in points.columns if c not in ("track_id", "time", "lat", "lon")]
    values = np.asarray(points[extra].to_numpy(dtype=object)).astype(str)
    ids = points["track_id"].to_numpy(dtype=object)
    times = points["time"].dt.to_pydatetime()
    lat, lon = points["lat"].to_numpy(), points["lon"].to_numpy()
    seg = None
    for i in range(len(points)):
        if seg is None or ids[i] != ids[i - 1]:
            trk = gpx.GPXTrack(name=str(ids[i]))
            seg = gpx.GPXTrackSegment()
            trk.segments.append(seg)
            doc.tracks.append(trk)
        point = gpx.GPXTrackPoint(latitude=round(float(lat[i]), 7), longitude=round(float(lon[i]), 7), time=times[i])
        for name, value in zip(extra, values[i]):
            element = ET.Element(f"{{{NAMESPACE}}}{name}")
            element.text = value
            point.extensions.append(element)
        seg.points.append(point)
    Path(path).write_text(doc.to_xml(), encoding="utf-8")


@register_suite("io")
def io_suite(quick: bool, rows: int | None = None) -> dict:
    from ..io import FIXES, read_chunks, write_table
    from ..tracking import track

    rows = rows or (10_000 if quick else 1_000_000)
    repeats = 3 if quick else 2
    table = []
    sizes = {}   # bytes per fix of each file written (lower is better: kept out of the table of rates)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fixes = _fixes(rows)
        n = len(fixes)
        files = {"csv": write_table(fixes, tmp / "fixes.csv"), "parquet": write_table(fixes, tmp / "fixes.parquet")}
        pandas_read = {"csv": pd.read_csv, "parquet": pd.read_parquet}
        for fmt, path in files.items():
            ours = best_time(lambda: deque(read_chunks(path, FIXES), maxlen=0), repeats)
            anchor = best_time(lambda: pandas_read[fmt](path), repeats)
            size = path.stat().st_size / n
            table.append([f"read {fmt} (mptrack.io.read_chunks)", n, n / ours, anchor / ours])
            sizes[fmt] = size
            table.append([f"read {fmt} (pandas.read_{fmt})", n, n / anchor, 1.0])
        points = track(fixes, sigma_m=5.0, q=0.5)
        points.attrs = {}
        n = len(points)
        anchor = best_time(lambda: points.to_parquet(tmp / "anchor.parquet", index=False), repeats)
        table.append(["write parquet (DataFrame.to_parquet)", n, n / anchor, 1.0])
        for fmt in OUTPUTS:
            out = tmp / f"points.{fmt}"
            seconds = best_time(lambda: write_table(points, out), repeats)
            table.append([f"write {fmt} (mptrack.io.write_table)", n, n / seconds, anchor / seconds])
            sizes[fmt] = out.stat().st_size / n
            out.unlink()
        sample = points.iloc[:min(n, GPXPY_ROWS)]
        seconds = best_time(lambda: gpxpy_write(sample, tmp / "gpxpy.gpx"), 1)
        table.append(["write gpx (gpxpy objects)", len(sample), len(sample) / seconds,
                      anchor / seconds * len(sample) / n])
        sizes["gpx (gpxpy)"] = (tmp / "gpxpy.gpx").stat().st_size / len(sample)
    rates = {row[0]: row for row in table}
    geojson = rates["write geojson (mptrack.io.write_table)"]
    notes = [f"{rows:,} fixes of {max(1, rows // 200 + 1):,} simulated tracks; the point table has "
             f"{points.shape[1]} columns; best of {repeats} runs, anchors timed in the same run",
             "x pandas = fixes/s over that of the pandas anchor for the same rows (above 1: faster; reading: "
             "pandas.read_csv / read_parquet of the same file with their defaults, which neither parse nor "
             "check the times; mptrack's reader also validates every column and converts the times; writing: "
             "DataFrame.to_parquet of the same table); the gpxpy row is scaled to the table's rows",
             "bytes per fix of the files: " + ", ".join(f"{k} {v:.0f}" for k, v in sizes.items()),
             f"GeoJSON: {sizes['geojson']:.0f} bytes and {geojson[2]:,.0f} points per second (goals <= 300 and "
             ">= 100 k)"]
    return {"suite": "io", "title": "Reading fixes and writing point tables, next to pandas (fixes/s)",
            "columns": ["case", "fixes", "fixes/s", "x pandas"], "rows": table,
            "bytes_per_fix": sizes, "notes": notes}
