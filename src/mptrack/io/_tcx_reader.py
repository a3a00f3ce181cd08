"""Garmin Training Center XML (TCX): one track per ``<Activity>`` (its laps concatenated), ``track_id``
= the activity's ``<Id>``; a ``<Course>`` is a track named by its ``<Name>``.

Each ``<Trackpoint>`` is decoded by tcxreader (maintained, release 0.4.11 of
2025; it knows the time formats, heart rate, cadence and the ActivityExtension
TPX values).  tcxreader's whole-file reader merges all activities into one list
and drops the points without a position, so the walk over activities, laps and
tracks below is ours and calls tcxreader's per-point parser.  python-tcxparser
was not chosen: it returns one list per quantity, which lose their alignment
when a point lacks one of them.

Columns: ``elevation_m``, ``distance_m``, ``heart_rate``, ``cadence`` and each
TPX value (``Speed`` -> ``speed_mps``, ``Watts`` -> ``power``, ``RunCadence`` ->
``run_cadence``).  Trackpoints without a ``<Position>`` (heart rate only: pauses,
indoor, before the GPS fix) are left out and reported as :class:`Skipped`; a
trackpoint without a ``<Time>`` is a DataError naming the activity and the point.
"""

from __future__ import annotations

import datetime as dt
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd

from ..errors import DataError
from ._formats import Skipped, library_error, snake_case, unique_name, utc_times

_NS = "{http://www.garmin.com/xmlschemas/TrainingCenterDatabase/v2}"
_POINT_COLUMNS = {"elevation": "elevation_m", "distance": "distance_m", "hr_value": "heart_rate",
                  "cadence": "cadence"}
_TPX_COLUMNS = {"speed": "speed_mps", "watts": "power"}


def read(path: Path, skipped: list) -> pd.DataFrame:
    from tcxreader.tcx_track_point import TCXTrackPoint
    from tcxreader.tcxreader import TCXReader

    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise library_error("tcx", path, exc) from None
    parser = TCXReader()
    frames, no_position, seen = [], 0, set()
    groups = [(a, _text(a, "Id") or f"activity{i}", "activity")
              for i, a in enumerate(root.iter(_NS + "Activity"), start=1)]
    groups += [(c, _text(c, "Name") or f"course{i}", "course") for i, c in enumerate(root.iter(_NS + "Course"), 1)]
    for element, name, kind in groups:
        name = unique_name(name, seen)
        rows = []
        for k, tp in enumerate(element.iter(_NS + "Trackpoint"), start=1):
            point = TCXTrackPoint(tpx_ext={})
            try:
                parser.trackpoint_parser(point, tp)
            except (ValueError, TypeError, AttributeError) as exc:
                raise DataError(f"{kind} {name!r}, point {k}: {exc}", file=path) from None
            if point.time is None:
                raise DataError(f"{kind} {name!r}, point {k} has no time stamp", file=path, column="time")
            if point.latitude is None or point.longitude is None:
                no_position += 1
                continue
            rows.append(_row(point))
        if rows:
            df = pd.DataFrame.from_records([{k: v for k, v in r.items() if k != "time"} for r in rows])
            df.insert(0, "time", utc_times(r["time"] for r in rows))
            df.insert(0, "track_id", pd.array([name] * len(df), dtype="string"))
            frames.append(df)
        else:
            skipped.append(Skipped(f"TCX {kind} without positions", 1,
                                   f"{path}: {kind} {name!r} has no trackpoint with a position; left out"))
    if no_position:
        skipped.append(Skipped("TCX trackpoint without a position", no_position,
                               f"{path}: {no_position} trackpoints have no <Position> (pauses, indoor, or "
                               "before the GPS fix); left out"))
    if not frames:
        what = "no <Activity> or <Course>" if not groups else "no <Trackpoint> with a <Position>"
        raise DataError(f"no track points in the TCX file: {what}", file=path)
    return pd.concat(frames, ignore_index=True)


def _row(point) -> dict:
    t = point.time if point.time.tzinfo is not None else point.time.replace(tzinfo=dt.timezone.utc)
    row = {"time": t, "lat": float(point.latitude), "lon": float(point.longitude)}
    for attr, col in _POINT_COLUMNS.items():
        value = getattr(point, attr, None)
        if value is not None:
            row[col] = float(value)
    for key, value in (point.tpx_ext or {}).items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            name = snake_case(key)
            row[_TPX_COLUMNS.get(name, name)] = float(value)
    return row


def _text(element, tag: str) -> str | None:
    child = element.find(_NS + tag)
    return child.text.strip() if child is not None and child.text and child.text.strip() else None
