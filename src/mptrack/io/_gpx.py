"""GPX, both ways: position fixes read from GPX 1.0/1.1 (:func:`read`, with gpxpy) and the GPX 1.1
output (:func:`write_gpx`, read back by :func:`read_gpx`).

Reading position fixes
----------------------
GPX 1.0/1.1 (parsed with gpxpy): tracks, routes and waypoints that carry a time.

Each ``<trk>`` and each ``<rte>`` is a track whose ``track_id`` is its
``<name>`` (else ``trk<i>`` / ``rte<i>``; a name used twice gets " (2)", ...);
the ``<wpt>`` with a ``<time>`` form one more track, "waypoints", in time order.
Columns: ``elevation_m`` (``<ele>``), ``speed_mps`` and ``course_deg`` (GPX 1.0),
``satellites``, ``hdop``/``vdop``/``pdop`` and every number in a point's
``<extensions>`` (Garmin's TrackPointExtension ``hr``, ``cad``, ``atemp`` become
``heart_rate``, ``cadence``, ``temperature``).

What is not a recording is left out and reported as :class:`Skipped`: an empty
track or route, a track or route with no ``<time>`` at all (drawn on a map, or
saved by a GPS unit that strips times), waypoints without a time.  A track or
route with times on some points but not on others is a DataError naming it and
the point ("track 'Morning run', point 17 has no time stamp").


The output
----------
GPX 1.1 output, for GPS tools: one ``<trk>`` per track, the estimates as track points.

Each run of rows of one ``track_id`` is a ``<trk>`` named by it, with one
``<trkseg>`` of ``<trkpt lat lon>`` (degrees with 7 decimals, about 1 cm),
``<ele>`` from an ``elevation_m`` column (where present), ``<time>`` (ISO 8601
in UTC, ``Z``), and every other column in the point's ``<extensions>`` as an
element of the mptrack namespace (:data:`NAMESPACE`): ``<mptrack:east_m>``,
``<mptrack:flag>``, ...  A column whose name is not an XML name is tagged
``column<i>`` (its position).  The file's ``<metadata><extensions>`` list the
columns in order with their kinds, so :func:`read_gpx` returns the table as
written (other floats exactly).  A row without a finite position cannot be a
track point: writing one is an error (write Parquet, CSV or GeoJSON instead).

The text is built column by column with Arrow's string kernels, not through
gpxpy objects: gpxpy builds and serialises a Python object per point and per
extension element (``benchmarks/results/io.json`` holds the measured rates).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Iterable
from xml.sax.saxutils import quoteattr

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from ..errors import DataError, ParameterError
from ._formats import Skipped, library_error, snake_case, unique_name, utc_times
from ._text import column_kind, column_text, join, per_run, restore, text, wrap, write_texts

__all__ = ["NAMESPACE", "read", "write_gpx", "read_gpx", "extension_tag"]

#: names of numbers in GPX <extensions> (Garmin TrackPointExtension v1/v2) -> column
_EXTENSION_COLUMNS = {"hr": "heart_rate", "cad": "cadence", "atemp": "temperature", "wtemp": "water_temperature",
                      "depth": "depth_m", "speed": "speed_mps", "course": "course_deg"}

#: gpxpy point attributes -> column
_POINT_COLUMNS = {"elevation": "elevation_m", "speed": "speed_mps", "course": "course_deg",
                  "satellites": "satellites", "horizontal_dilution": "hdop", "vertical_dilution": "vdop",
                  "position_dilution": "pdop"}


def read(path: Path, skipped: list) -> pd.DataFrame:
    import gpxpy
    import gpxpy.gpx

    try:
        with open(path, encoding="utf-8-sig") as fh:
            gpx = gpxpy.parse(fh)
    except (gpxpy.gpx.GPXException, ValueError) as exc:
        raise library_error("gpx", path, exc) from None
    parts = [("track", trk.name or f"trk{i}", [p for seg in trk.segments for p in seg.points])
             for i, trk in enumerate(gpx.tracks, start=1)]
    parts += [("route", rte.name or f"rte{i}", rte.points) for i, rte in enumerate(gpx.routes, start=1)]
    timed_wpts = sorted((w for w in gpx.waypoints if w.time is not None), key=lambda w: _utc(w.time))
    if timed_wpts:
        parts.append(("waypoints", "waypoints", timed_wpts))
    if len(timed_wpts) < len(gpx.waypoints):
        n = len(gpx.waypoints) - len(timed_wpts)
        skipped.append(Skipped("GPX waypoint without a time", n,
                               f"{path}: {n} <wpt> without <time> (points of interest, not fixes) left out"))
    frames, names, untimed, row = [], set(), [], 1
    for kind, name, points in parts:
        name = unique_name(name, names)
        first_row, row = row, row + len(points)
        if not points:
            skipped.append(Skipped(f"empty GPX {kind}", 1, f"{path}: {kind} {name!r} has no points; left out"))
            continue
        missing = [k for k, p in enumerate(points, start=1) if p.time is None]
        if len(missing) == len(points):
            untimed.append((kind, name, len(points), first_row))
            skipped.append(Skipped(f"GPX {kind} without time stamps", len(points),
                                   f"{path}: {kind} {name!r} has no <time> in any of its {len(points)} points "
                                   "(a planned or saved track, not a recording); left out"))
            continue
        if missing:
            raise DataError(f"{kind} {name!r}, point {missing[0]} has no time stamp "
                            f"({len(missing)} of its {len(points)} points have none)", file=path,
                            row=first_row + missing[0] - 1, column="time")
        frames.append(_frame(name, points))
    if not frames and untimed:
        kind, name, n, first_row = untimed[0]
        raise DataError(f"{kind} {name!r}, point 1 has no time stamp, and no point in the file has one "
                        f"({'; '.join(f'{k} {m!r}: {c} points' for k, m, c, _ in untimed)}); mptrack needs the "
                        "time of every fix", file=path, row=first_row, column="time")
    if not frames:
        raise DataError("no track points: the file has no <trkpt>, <rtept> or <wpt> with a <time>", file=path)
    return pd.concat(frames, ignore_index=True)


def _frame(name: str, points: list) -> pd.DataFrame:
    cols: dict[str, list] = {"lat": [p.latitude for p in points], "lon": [p.longitude for p in points]}
    for attr, col in _POINT_COLUMNS.items():
        values = [getattr(p, attr, None) for p in points]
        if any(v is not None for v in values):
            cols[col] = [float(v) if v is not None else float("nan") for v in values]
    extra: dict[str, list] = {}
    for k, p in enumerate(points):
        for key, value in _extension_numbers(p.extensions):
            col = _EXTENSION_COLUMNS.get(key, key)
            extra.setdefault(col, [float("nan")] * len(points))[k] = value
    for col, values in extra.items():
        if col in cols:  # a standard element wins; the extension fills its gaps
            cols[col] = [a if a == a else b for a, b in zip(cols[col], values)]
        else:
            cols[col] = values
    df = pd.DataFrame(cols)
    df.insert(0, "time", utc_times(_utc(p.time) for p in points))
    df.insert(0, "track_id", pd.array([name] * len(points), dtype="string"))
    return df


def _extension_numbers(elements) -> list[tuple[str, float]]:
    """(snake_case name, value) of every leaf element of ``elements`` whose text is a number."""
    out = []
    for el in elements or ():
        children = list(el)
        if children:
            out += _extension_numbers(children)
            continue
        try:
            out.append((snake_case(el.tag), float((el.text or "").strip())))
        except ValueError:
            pass
    return out


def _utc(t):
    """A gpxpy time (naive = UTC) as an aware datetime."""
    import datetime as dt

    return t.replace(tzinfo=dt.timezone.utc) if t.tzinfo is None else t


GPX_NAMESPACE = "http://www.topografix.com/GPX/1/1"
#: The XML namespace of mptrack's extension elements (a name, not a web address).
NAMESPACE = "urn:mptrack:gpx:1"
ELEVATION = "elevation_m"
_NAME = re.compile(r"^(?![Xx][Mm][Ll])[A-Za-z_][A-Za-z0-9_.-]*$")


def extension_tag(name: str, index: int) -> str:
    """The extension element of a column: its name if that is an XML name, else ``column<index>``."""
    return name if _NAME.match(name) else f"column{index}"


def _layout(schema: pa.Schema) -> dict[str, str]:
    """Column -> where it goes: "name", "lat", "lon", "time", "ele" or "mptrack:<its extension tag>"."""
    own = {"track_id": "name", "lat": "lat", "lon": "lon", ELEVATION: "ele"}
    if "time" in schema.names and column_kind(schema.field("time").type) == "time":
        own["time"] = "time"
    return {name: own.get(name) or "mptrack:" + extension_tag(name, i) for i, name in enumerate(schema.names)}


def write_gpx(tables: Iterable[pa.Table], path) -> None:
    """Write Arrow tables with the same columns (with ``lat``/``lon``; the rows of a track contiguous)
    to ``path`` as one GPX 1.1 file."""
    with open(path, "wb") as fh:
        started = False
        for table in tables:
            if not started:
                fh.write(_header(table.schema).encode())
                started = True
            if table.num_rows:
                write_texts(fh, _tracks(table))
        if not started:
            fh.write(_header(pa.schema([])).encode())
        fh.write(b"</gpx>\n")


def _header(schema: pa.Schema) -> str:
    columns = "".join(f"<mptrack:column name={quoteattr(name)} kind=\"{column_kind(schema.field(name).type)}\"/>"
                      for name in schema.names)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<gpx version="1.1" creator="mptrack" xmlns="{GPX_NAMESPACE}" xmlns:mptrack="{NAMESPACE}">\n'
            f"<metadata><extensions><mptrack:columns>{columns}</mptrack:columns></extensions></metadata>\n")


def _tracks(table: pa.Table) -> pa.Array:
    """The text of each track point, with a track's opening and closing tags around its first and last."""
    n = table.num_rows
    layout = _layout(table.schema)
    if "lat" not in layout or "lon" not in layout:
        raise ParameterError("out: GPX needs the columns lat and lon (positions in degrees); write .parquet, "
                             ".csv or .geojson instead")
    lat = table.column("lat").to_numpy().astype(np.float64)
    lon = table.column("lon").to_numpy().astype(np.float64)
    bad = ~(np.isfinite(lat) & np.isfinite(lon))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        where = f" (track {table.column('track_id')[i].as_py()!r})" if "track_id" in layout else ""
        raise ParameterError(f"out: GPX track points need a latitude and longitude; {int(bad.sum())} rows have "
                             f"none, the first is row {i + 1} of the table{where} (x/y input?); write .parquet, "
                             ".csv or .geojson instead")
    parts = [join('<trkpt lat="', _degrees(lat), '" lon="', _degrees(lon), '">')]
    if ELEVATION in layout:
        parts.append(wrap("<ele>", column_text(table.column(ELEVATION), syntax="xml"), "</ele>"))
    if layout.get("time") == "time":
        parts.append(wrap("<time>", column_text(table.column("time"), syntax="xml"), "</time>"))
    extensions = [wrap(f"<{tag}>", column_text(table.column(name), syntax="xml"), f"</{tag}>")
                  for name, tag in layout.items() if tag.startswith("mptrack:")]
    if extensions:
        parts += ["<extensions>", *extensions, "</extensions>"]
    points = join(*parts, "</trkpt>\n", skip=True)

    if "track_id" in layout:
        ids = pc.fill_null(pc.dictionary_encode(table.column("track_id").combine_chunks()).indices, -1)
        ids = ids.to_numpy(zero_copy_only=False)
        names = column_text(table.column("track_id"), syntax="xml")
    else:
        ids, names = np.zeros(n, np.int64), pa.nulls(n, pa.large_string())
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    offsets = np.r_[starts, n]
    head = pc.fill_null(wrap("<name>", pc.take(names, pa.array(starts)), "</name>"), text(""))
    return join("<trk>", head, "<trkseg>\n", per_run(points, offsets, ""), "</trkseg></trk>\n")


def _degrees(x: np.ndarray) -> pa.Array:
    return column_text(pa.array(x), syntax="xml", decimals=7)


def read_gpx(path) -> pd.DataFrame:
    """The table of a GPX file written by :func:`write_gpx` (columns, kinds and row order as written;
    lat/lon to 1e-7 degrees, every other value as written)."""
    path = Path(path)
    g, m = f"{{{GPX_NAMESPACE}}}", f"{{{NAMESPACE}}}"
    kinds: dict | None = None
    data: dict[str, list] = {}
    name = None
    try:
        for event, elem in ET.iterparse(path, events=("start", "end")):
            tag = elem.tag
            if event == "start":
                if tag == g + "trk":
                    name = None
                continue
            if tag == m + "columns":
                kinds = {c.get("name"): c.get("kind") for c in elem.iter(m + "column")}
                layout = _layout(pa.schema([(c, pa.timestamp("ns") if k == "time" else pa.string())
                                            for c, k in kinds.items()]))
                data = {c: [] for c in kinds}
                where = {v: k for k, v in layout.items()}
            elif tag == g + "name" and kinds is not None and name is None:
                name = elem.text or ""
            elif tag == g + "trkpt":
                if kinds is None:
                    raise DataError("has no mptrack column list (<metadata><extensions><mptrack:columns>): not "
                                    "written by mptrack; read it as an input instead", file=path)
                values = {"name": name, "lat": elem.get("lat"), "lon": elem.get("lon")}
                for child in elem:
                    if child.tag == g + "extensions":
                        values.update(("mptrack:" + ext.tag[len(m):], ext.text) for ext in child
                                      if ext.tag.startswith(m))
                    else:
                        values[child.tag[len(g):]] = child.text
                for place, column in where.items():
                    data[column].append(values.get(place))
                elem.clear()
            elif tag == g + "trk":
                elem.clear()
    except ET.ParseError as exc:
        raise DataError(f"not a valid GPX file: {exc}", file=path) from None
    if kinds is None:
        raise DataError("has no mptrack column list (<metadata><extensions><mptrack:columns>): not written by "
                        "mptrack; read it as an input instead", file=path)
    return restore(data, kinds, file=path)
