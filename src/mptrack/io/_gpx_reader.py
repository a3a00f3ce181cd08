"""GPX 1.0/1.1 (parsed with gpxpy): tracks, routes and waypoints that carry a time.

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
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..errors import DataError
from ._formats import Skipped, library_error, snake_case, unique_name, utc_times

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
