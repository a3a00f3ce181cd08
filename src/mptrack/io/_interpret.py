"""How a file's columns are read: which column is which, and in which unit.

Real exports name their columns in many ways (``Latitude``, ``lng``,
``timestamp``, ``device``) and store values in several units (epoch
milliseconds, degrees x 10^7, radians).  :class:`ReadOptions` holds what the
user said (``--columns``, ``--time-unit``, ``--coord-unit``, ``--time-format``,
``--max-skip``); :func:`interpret` decides the rest from the first chunk of
the file, once, so every chunk of the file is read the same way, and records
each decision as a one-line note (shown to the user, kept in the run summary).

Rules (docs/tracking.md, "Column names and units"):

* column names: an explicit ``--columns canonical=name`` first, then the exact
  canonical name, then case-insensitive synonyms (punctuation ignored); two
  columns that both fit one name is an error naming both.
* ``hdop`` without an accuracy column: ``accuracy_m = HDOP_UERE_M x hdop``.
* numeric times, by the median magnitude: below 1e10 seconds, 1e11..1e13
  milliseconds, 1e14..1e16 microseconds, 1e17..1e19 nanoseconds since 1970;
  the decades between are ambiguous and an error that names ``--time-unit``.
  Seconds from 1e8 on (1973-03-03) are epoch seconds; below, seconds from any
  start (they stay numbers).  Epoch times of every unit become UTC times, with
  a note naming the unit and the first time.
* text times (ISO 8601, or ``--time-format``) and datetimes without a zone are
  read as UTC, with a note saying so.
* coordinates, by the median magnitude: degrees when they fit; integers that
  fit as degrees x 10^7 or x 10^6 (exactly one of the two) are converted;
  latitude beyond 90 with longitude within 90 is a swap and is swapped back;
  all positions within +-pi/2, +-pi (radians, or degrees in the Gulf of Guinea)
  are an error naming ``--coord-unit``.  Each conversion is a note.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import pandas as pd

from ..errors import DataError, ParameterError

__all__ = ["ReadOptions", "Interpretation", "interpret", "TIME_UNITS", "COORD_UNITS", "HDOP_UERE_M"]

TIME_UNITS = {"auto": None, "s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9}
COORD_UNITS = {"auto": None, "deg": 1.0, "deg-e6": 1e-6, "deg-e7": 1e-7, "rad": 180.0 / math.pi}
#: accuracy_m = HDOP_UERE_M x HDOP where a file gives HDOP only (a typical user-equivalent range error
#: of standalone GPS; the filter estimates a scale on it from the data unless --sigma is given).
HDOP_UERE_M = 5.0
#: Seconds of a valid time stamp lie within +-MAX_SECONDS (1e10 s: the year 2286).
MAX_SECONDS = 1e10
#: Median speeds above this (m/s, faster than sound) are reported as implausible.
MAX_PLAUSIBLE_SPEED = 340.0

#: Synonyms of each canonical column (compared lower-case with punctuation removed).  A tuple of tuples
#: ranks them: a column of an earlier group wins over one of a later group (a trajectory over the user who
#: made it, any named id over a bare "id"); two columns of one group are an error naming both.
SYNONYMS = {
    "track_id": (("track", "trackid", "trajectory", "trajectoryid", "traj", "trajid", "trip", "tripid"),
                 ("device", "deviceid", "vehicle", "vehicleid", "terminal", "terminalid", "imei", "mmsi"),
                 ("user", "userid"),
                 ("id",)),
    "time": (("time", "timestamp", "datetime", "datetimeutc", "timeutc", "utc", "ts", "gpstime", "timestamputc"),
             ("t",)),
    "lat": ("lat", "latitude", "latdeg", "latitudedeg", "latitudedegrees"),
    "lon": ("lon", "lng", "long", "longitude", "londeg", "longitudedeg", "longitudedegrees"),
    "x": ("x", "xm", "east", "eastm", "easting"),
    "y": ("y", "ym", "north", "northm", "northing"),
    "accuracy_m": ("accuracy", "accuracym", "horizontalaccuracy", "horizontalaccuracym", "hacc", "haccuracy",
                   "hacc_m", "acc", "accm"),
    "cell_id": ("cellid", "cell", "cellidentity"),
    # LTE's RSRP (the level of one reference-signal element, which the path-loss prior models) over the
    # RSSI (the whole band's power, ~10 log10(12 x resource blocks) dB more), both logged by drive-test apps
    "rss_dbm": (("rssdbm", "rss"), ("rsrpdbm", "rsrp"), ("rssidbm", "rssi"), ("signaldbm", "dbm")),
    "range_m": ("rangem", "range", "distance", "distancem"),
    "ta": ("ta", "timingadvance"),
}
_HDOP = "hdop"


def _norm(name) -> str:
    return re.sub(r"[^0-9a-z]", "", str(name).lower())


@dataclass(frozen=True)
class ReadOptions:
    """What the user said about the input's columns and units ("auto": decide from the data).

    columns      {canonical name: the file's column}, or "time=ts,lat=Latitude" text
    time_unit    unit of numeric time stamps: auto, s, ms, us, ns (since 1970, or any origin for s)
    time_format  strftime layout of text time stamps (default: ISO 8601), e.g. "%d/%m/%Y %H:%M:%S"
    coord_unit   unit of lat/lon: auto, deg, deg-e6, deg-e7 (integer degrees x 10^6 / 10^7), rad
    max_skip     with on_error="skip": the most rows that may be dropped, "1%" of the rows read or a
                 count ("50"); beyond it the run fails with the reasons
    timezone     the time zone (IANA name, "Europe/Brussels") of logs that write the phone's local time
                 (G-NetTrack Pro); None: read as UTC, with a note
    """

    columns: tuple = ()
    time_unit: str = "auto"
    time_format: str | None = None
    coord_unit: str = "auto"
    max_skip: str = "1%"
    timezone: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "columns", parse_columns(self.columns))
        for name, allowed in (("time_unit", TIME_UNITS), ("coord_unit", COORD_UNITS)):
            if getattr(self, name) not in allowed:
                raise ParameterError(f"{name}: expected one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        object.__setattr__(self, "max_skip", str(self.max_skip).strip())
        self.skip_limit(0)  # validates
        if self.timezone is not None:
            from ._gnettrack import check_timezone

            check_timezone(self.timezone)
            object.__setattr__(self, "timezone", self.timezone.strip())

    @property
    def column_map(self) -> dict:
        return dict(self.columns)

    def skip_limit(self, rows_read: int) -> int:
        """The most rows that may be dropped out of ``rows_read``."""
        text = self.max_skip
        try:
            if text.endswith("%"):
                pct = float(text[:-1])
                if not 0 <= pct <= 100:
                    raise ValueError
                return int(math.floor(rows_read * pct / 100 + 1e-9))
            count = int(text)
            if count < 0:
                raise ValueError
            return count
        except ValueError:
            raise ParameterError(f"max_skip: expected a percentage of the rows read (\"1%\") or a row count "
                                 f"(\"50\"), got {text!r}") from None


def parse_columns(spec) -> tuple:
    """{canonical: file column} or "a=b,c=d" text -> sorted ((canonical, file column), ...)."""
    if not spec:
        return ()
    if isinstance(spec, str):
        pairs = []
        for item in spec.split(","):
            key, eq, value = item.partition("=")
            if not eq or not key.strip() or not value.strip():
                raise ParameterError(f"columns: expected NAME=COLUMN pairs separated by commas "
                                     f"(time=ts,lat=Latitude), got {spec!r}")
            pairs.append((key.strip(), value.strip()))
    elif isinstance(spec, Mapping):
        pairs = [(str(k), str(v)) for k, v in spec.items()]
    else:
        pairs = [(str(k), str(v)) for k, v in spec]
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        raise ParameterError(f"columns: {next(k for k in keys if keys.count(k) > 1)!r} is given twice")
    return tuple(sorted(pairs))


@dataclass
class Interpretation:
    """How every chunk of one file is read (decided from its first chunk)."""

    rename: dict = field(default_factory=dict)     # file column -> canonical
    hdop: str | None = None                        # the HDOP column turned into accuracy_m
    time_scale: float = 1.0                        # numeric time / time_scale = seconds
    time_epoch: bool = False                       # numeric times count from 1970 (-> UTC times)
    time_format: str | None = None
    coord_scale: float = 1.0                       # degrees = value x coord_scale
    swap: bool = False                             # the file's lat column holds longitudes
    notes: list = field(default_factory=list)

    def apply(self, raw: pd.DataFrame) -> pd.DataFrame:
        """The chunk with canonical column names and lat/lon in degrees (times are converted in
        validation, which needs the raw text for its messages)."""
        df = raw.rename(columns=self.rename)
        if self.swap:
            df = df.rename(columns={"lat": "lon", "lon": "lat"})
        if self.coord_scale != 1.0:
            for c in ("lat", "lon"):
                if c in df.columns:
                    df[c] = pd.to_numeric(df[c], errors="coerce") * self.coord_scale
        if self.hdop is not None:  # the hdop column stays (it passes through to the output)
            df["accuracy_m"] = pd.to_numeric(df[self.hdop], errors="coerce") * HDOP_UERE_M
        return df


def interpret(raw: pd.DataFrame, schema, options: ReadOptions, *, file) -> Interpretation:
    """Decide the column mapping and units of a file from its first raw chunk."""
    plan = Interpretation(time_format=options.time_format)
    plan.rename = _mapping(list(raw.columns), schema, options.column_map, file, plan.notes)
    _row_ids(raw, plan, options)
    names = {c.name for c in schema.columns}
    if "accuracy_m" in names and "accuracy_m" not in plan.rename.values():
        hdop = [c for c in raw.columns if _norm(c) == _HDOP and c not in plan.rename]
        if hdop:
            plan.hdop = hdop[0]
            plan.notes.append(f"accuracy: {HDOP_UERE_M:g} m x {hdop[0]} (no accuracy column; the filter "
                              "estimates a scale on it)")
    df = raw.rename(columns=plan.rename)
    if "time" in df.columns and "time" in names:
        _time_unit(df["time"], options.time_unit, plan, file)
    fixes = schema.name == "position fixes"
    if fixes and {"x", "y"} <= set(df.columns) and not {"lat", "lon"} & set(df.columns) \
            and not {"x", "y"} & set(options.column_map) and _xy_in_degrees(df, plan, file):
        df = raw.rename(columns=plan.rename)
    if "lat" in df.columns and "lon" in df.columns and fixes:
        _coordinates(df, options.coord_unit, plan, file, explicit={"lat", "lon"} & set(options.column_map))
        read = plan.apply(raw)
        _speed_check(read, plan)
        _zone_check(read, plan)
    return plan


def _mapping(columns: list, schema, explicit: dict, file, notes: list) -> dict:
    """{file column: canonical name} for the schema's columns found in ``columns`` (a choice between
    synonyms of different ranks is a note in ``notes``)."""
    names = [c.name for c in schema.columns]
    present = {str(c): c for c in columns}
    rename = {}
    sources = list(explicit.values())
    for canonical, source in explicit.items():
        if canonical not in names:
            raise ParameterError(f"--columns: {canonical!r} is not a column mptrack reads here; the names are "
                                 f"{', '.join(names)}")
        if source not in present:
            raise ParameterError(f"--columns: {canonical}={source}: {file} has no column {source!r} (it has: "
                                 f"{', '.join(map(str, columns))})")
        if sources.count(source) > 1:
            raise ParameterError(f"--columns: the column {source!r} is given for "
                                 f"{' and '.join(k for k, v in explicit.items() if v == source)}; one each")
        rename[present[source]] = canonical
        if canonical in present and canonical not in sources:  # the file's own column of that name steps aside
            rename[present[canonical]] = f"input_{canonical}"
    taken = set(rename.values())
    for canonical in names:
        if canonical in taken:
            continue
        if canonical in present and present[canonical] not in rename:
            continue  # already its own name
        groups = SYNONYMS.get(canonical, ())
        groups = groups if groups and isinstance(groups[0], tuple) else (groups,)
        free = [c for c in columns if c not in rename and str(c) not in names]
        for rank, group in enumerate(groups):
            wanted = set(group) | ({_norm(canonical)} if rank == 0 else set())
            hits = [c for c in free if _norm(c) in wanted]
            if len(hits) > 1:
                raise DataError(f"columns {', '.join(repr(str(h)) for h in hits)} all look like {canonical}; say "
                                f"which with --columns {canonical}=NAME", file=file, column=canonical)
            if hits:
                rename[hits[0]] = canonical
                # another kind of id passed over (a trajectory's user; not a bare "id", often a row number)
                passed = [c for later in groups[rank + 1:-1] for c in free if _norm(c) in later]
                if passed and canonical == "track_id":
                    others = ", ".join(repr(str(c)) for c in passed)
                    notes.append(f"track id: column {str(hits[0])!r} (also found {others}; --columns track_id=NAME to "
                                 "take another)")
                break
    return {k: v for k, v in rename.items() if str(k) != v}


def _row_ids(raw: pd.DataFrame, plan: Interpretation, options: ReadOptions) -> None:
    """Undo a track-id guess that is a row number (a different value in every row)."""
    source = next((k for k, v in plan.rename.items() if v == "track_id"), None)
    if source is None or "track_id" in options.column_map or len(raw) < 10:
        return
    if raw[source].nunique() == len(raw):
        del plan.rename[source]
        plan.notes.append(f"column {source!r} has a different value in every row, so it is not read as the "
                          f"track id (one track; --columns track_id={source} to override)")


def _time_unit(values: pd.Series, unit: str, plan: Interpretation, file) -> None:
    """Decide how the time column is read: ``plan.time_scale`` (units per second of numeric time
    stamps) and ``plan.time_epoch`` (numbers counted from 1970-01-01 UTC: they become UTC times),
    with a note saying which unit was taken; text or datetimes without a zone get a note that they
    are read as UTC."""
    if pd.api.types.is_datetime64_any_dtype(values):
        if getattr(values.dt, "tz", None) is None:
            plan.notes.append(f"time: time stamps without a zone (e.g. {_first(values)}) were read as UTC")
        return
    num = pd.to_numeric(values, errors="coerce")
    if num.notna().sum() * 2 <= values.notna().sum():
        _zone_note(values, plan)  # text time stamps
        return
    numbers = num.to_numpy(dtype=float)
    numbers = numbers[np.isfinite(numbers)]
    finite = np.abs(numbers)
    m = float(np.median(finite)) if len(finite) else 0.0
    if unit != "auto":
        name = unit
    else:
        name = next((name for name, lo, hi in _UNIT_RANGES if lo <= m < hi), None)
        if name is None:
            raise DataError(f"numeric time stamps around {m:.3g} fit no unit unambiguously (seconds, milliseconds, "
                            "microseconds or nanoseconds since 1970); set --time-unit s, ms, us or ns",
                            file=file, column="time")
    plan.time_scale = TIME_UNITS[name]
    plan.time_epoch = name != "s" or m >= MIN_EPOCH_SECONDS
    if plan.time_epoch:
        valid = numbers[np.abs(numbers) / plan.time_scale <= MAX_SECONDS] / plan.time_scale
        start = f", from {pd.Timestamp(float(valid.min()), unit='s', tz='UTC'):%Y-%m-%d %H:%M:%S} UTC" \
            if len(valid) else ""
        plan.notes.append(f"time: epoch {_UNIT_WORDS[name]} (numbers around {m:.3g}{start})"
                          + ("; set --time-unit if that is wrong" if unit == "auto" else ""))
    elif unit == "auto" and m < 1e8 and _integral(finite) and len(finite) > 1 \
            and np.median(np.diff(np.sort(finite))) >= 500:
        plan.notes.append("time: numbers read as seconds from an arbitrary start, fixes about "
                          f"{float(np.median(np.diff(np.sort(finite)))):g} s apart; if they are "
                          "milliseconds set --time-unit ms")


#: A time of day followed by its zone (ISO 8601): Z, or a UTC offset's sign, hours and minutes
#: (+01, +0100, +01:00).
_ZONE = re.compile(r"\d\d:\d\d(?::\d\d(?:[.,]\d+)?)?\s*(?:Z|([+-])(\d\d):?(\d\d)?)\s*\Z", re.IGNORECASE)
#: Text time stamps whose zone is looked at (the first of the file).
_ZONE_SAMPLE = 1000


def _zone_note(values: pd.Series, plan: Interpretation) -> None:
    """A note when text time stamps (the first of the file) carry no zone: they are read as UTC."""
    if plan.time_format is not None:
        if not re.search("%[zZ]", plan.time_format):
            plan.notes.append(f"time: the layout {plan.time_format!r} has no zone; the time stamps were read as UTC")
        return
    text = values.dropna().iloc[:_ZONE_SAMPLE].astype(str).str.strip()
    naive = [x for x in text if not _ZONE.search(x)]
    if naive:
        plan.notes.append(f"time: ISO 8601 time stamps without a zone (e.g. {naive[0]!r}) were read as UTC; "
                          "if they are local time, add the offset (e.g. +01:00) to them")


def _first(values: pd.Series) -> str:
    first = values.dropna()
    return repr(str(first.iloc[0])) if len(first) else "none"


#: Numeric time stamps by their median magnitude: (unit, lowest, highest); the decades between are ambiguous.
_UNIT_RANGES = (("s", 0.0, 1e10), ("ms", 1e11, 1e13), ("us", 1e14, 1e16), ("ns", 1e17, 1e19))
#: Seconds from this on (1973-03-03) are epoch seconds (UTC times); below, seconds from any start.
MIN_EPOCH_SECONDS = 1e8
_UNIT_WORDS = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}


def _integral(x: np.ndarray) -> bool:
    return bool(np.all(x == np.round(x)))


def _coordinates(df: pd.DataFrame, unit: str, plan: Interpretation, file, explicit=()) -> None:
    """Decide the unit of lat/lon (and a swap) from the bulk of the first chunk; single bad rows
    are left to the row checks.  Columns the user named (``explicit``: "lat", "lon" given with
    --columns) are never swapped: a latitude column beyond 90 is then an error naming the option."""
    lat = pd.to_numeric(df["lat"], errors="coerce").to_numpy(dtype=float)
    lon = pd.to_numeric(df["lon"], errors="coerce").to_numpy(dtype=float)
    ok = np.isfinite(lat) & np.isfinite(lon)
    lat, lon = lat[ok], lon[ok]
    if unit != "auto":
        plan.coord_scale = COORD_UNITS[unit]
        return
    if not len(lat):
        return
    mlat, mlon = float(np.median(np.abs(lat))), float(np.median(np.abs(lon)))
    if mlat <= 90 and mlon <= 180:
        if np.all(np.abs(lat) <= math.pi / 2) and np.all(np.abs(lon) <= math.pi):
            raise DataError("every position lies within +-1.571 deg latitude and +-3.142 deg longitude, as "
                            "radians would; set --coord-unit rad (radians) or deg (degrees, near 0 N 0 E)",
                            file=file, column="lat")
        return
    readings = []
    swapped = mlat <= 180 and mlon <= 90 and np.all(np.abs(lat) <= 180) and np.all(np.abs(lon) <= 90)
    if swapped and explicit:
        names = {v: str(k) for k, v in plan.rename.items()}
        raise DataError(f"--columns lat={names.get('lat', 'lat')}: that column holds values around {mlat:.4g}, beyond "
                        f"90: not latitudes; the longitude column {names.get('lon', 'lon')!r} ({mlon:.4g}) would "
                        f"fit: --columns lat={names.get('lon', 'lon')},lon={names.get('lat', 'lat')}",
                        file=file, column="lat")
    if swapped:
        readings.append("swap")
    if _integral(lat) and _integral(lon):
        for name, scale in (("deg-e7", 1e-7), ("deg-e6", 1e-6)):
            if np.all(np.abs(lat) * scale <= 90) and np.all(np.abs(lon) * scale <= 180):
                readings.append(name)
    if len(readings) != 1:
        maybe = " or ".join(readings) if readings else "none of deg-e7, deg-e6 or a lat/lon swap"
        raise DataError(f"lat/lon around {mlat:.4g}/{mlon:.4g} are not degrees; they fit {maybe}: set "
                        "--coord-unit (deg-e7, deg-e6, rad) or name the columns with --columns lat=...,lon=...",
                        file=file, column="lat")
    if readings[0] == "swap":
        plan.swap = True
        plan.notes.append(f"lat/lon: the column read as latitude holds values up to {np.abs(lat).max():.4g} deg, "
                          "beyond 90: the two columns are swapped back (--columns lat=...,lon=... to override)")
    else:
        plan.coord_scale = COORD_UNITS[readings[0]]
        plan.notes.append(f"lat/lon: integers around {mlat:.4g}/{mlon:.4g} read as degrees x "
                          f"{'10^7' if readings[0] == 'deg-e7' else '10^6'} (--coord-unit to override)")


def _speed_check(df: pd.DataFrame, plan: Interpretation) -> None:
    """A note when the median speed between fixes is beyond any vehicle (wrong time or coordinate
    unit, or swapped columns)."""
    if "time" not in df.columns:
        return
    secs, same = _seconds(df, plan)
    lat = pd.to_numeric(df["lat"], errors="coerce").to_numpy(dtype=float)
    lon = pd.to_numeric(df["lon"], errors="coerce").to_numpy(dtype=float)
    speed = _speeds(lat, lon, secs, same)
    if speed is None or speed <= MAX_PLAUSIBLE_SPEED:
        return
    swapped = _speeds(lon, lat, secs, same) if np.all(np.abs(lon) <= 90) else None
    hint = (f"; read with lat and lon swapped it would be {swapped:.3g} m/s (--columns lat=...,lon=...)"
            if swapped is not None and swapped <= MAX_PLAUSIBLE_SPEED else "")
    plan.notes.append(f"warning: the median speed between fixes is {speed:.3g} m/s, faster than any vehicle: "
                      f"check the time unit (--time-unit) and the coordinate unit (--coord-unit){hint}")


def _seconds(df: pd.DataFrame, plan: Interpretation) -> tuple[np.ndarray, np.ndarray]:
    """(the first chunk's times in seconds, NaN where unreadable; whether each row continues the track
    of the row before it)."""
    t = pd.to_numeric(df["time"], errors="coerce") if plan.time_scale != 1.0 or \
        pd.api.types.is_numeric_dtype(df["time"]) else None
    if t is not None:
        secs = t.to_numpy(dtype=float) / plan.time_scale
    else:
        ts = pd.to_datetime(df["time"], errors="coerce", utc=True, format=plan.time_format or "ISO8601")
        secs = ts.to_numpy(dtype="datetime64[ns]").astype("int64") / 1e9
        secs[ts.isna().to_numpy()] = np.nan
    ids = df["track_id"].astype(str).to_numpy() if "track_id" in df.columns else np.zeros(len(df))
    return secs, ids[1:] == ids[:-1]


def _speeds(lat, lon, secs, same, degrees: bool = True, moving: bool = False) -> float | None:
    """The median speed (m/s) between consecutive fixes of a track (equirectangular distances; with
    ``degrees`` False, lat/lon are north/east metres); ``moving``: over the steps that move only."""
    dt = np.diff(secs)
    with np.errstate(invalid="ignore"):
        if degrees:
            dy = np.radians(np.diff(lat)) * 6371e3
            dx = np.radians(np.diff(lon)) * 6371e3 * np.cos(np.radians(lat[1:]))
        else:
            dy, dx = np.diff(lat), np.diff(lon)
        ok = same & (dt > 0) & np.isfinite(dx) & np.isfinite(dy)
        if moving:
            ok &= (dx != 0) | (dy != 0)
    if ok.sum() < 3:
        return None
    return float(np.median(np.hypot(dx[ok], dy[ok]) / dt[ok]))


def _xy_in_degrees(df: pd.DataFrame, plan: Interpretation, file) -> bool:
    """Whether columns found as x/y (local metres: ``X``/``Y``, ``easting``/``northing``) hold longitude/
    latitude in degrees: every value within +-180/+-90 and the fixes moving at a speed no vehicle
    exceeds as degrees (:data:`MAX_PLAUSIBLE_SPEED`), which as metres is below 3 mm/s.  Then they are
    read as lon/lat, with a note; values that could be either but do not move enough to tell (and
    lie more than a degree from 0, 0) are an error naming the two ways to say which; else metres."""
    x = pd.to_numeric(df["x"], errors="coerce").to_numpy(dtype=float)
    y = pd.to_numeric(df["y"], errors="coerce").to_numpy(dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any() or np.any(np.abs(x[ok]) > 180) or np.any(np.abs(y[ok]) > 90):
        return False
    names = {v: str(k) for k, v in plan.rename.items()}
    xc, yc = names.get("x", "x"), names.get("y", "y")
    mx, my = float(np.median(x[ok])), float(np.median(y[ok]))
    secs, same = _seconds(df, plan) if "time" in df.columns else (np.full(len(df), np.nan), np.zeros(0, bool))
    as_degrees = _speeds(y, x, secs, same, moving=True)
    if as_degrees is None:
        if (abs(mx) >= 1 or abs(my) >= 1) and not (_integral(x[ok]) and _integral(y[ok])):
            raise DataError(f"columns {xc!r}/{yc!r} hold values around {mx:.6g}/{my:.6g}: longitude/latitude in "
                            "degrees or local metres? Too few fixes move to tell; say which: --columns "
                            f"lon={xc},lat={yc} (degrees) or --columns x={xc},y={yc} (metres)", file=file, column="x")
        return False
    if as_degrees > MAX_PLAUSIBLE_SPEED:
        return False
    as_metres = _speeds(y, x, secs, same, degrees=False, moving=True)
    for axis, canonical in (("x", "lon"), ("y", "lat")):
        plan.rename[next((k for k, v in plan.rename.items() if v == axis), axis)] = canonical
    plan.notes.append(f"x/y: columns {xc!r}/{yc!r} (values around {mx:.6g}/{my:.6g}) move at {as_degrees:.3g} m/s "
                      f"read as longitude/latitude in degrees, {as_metres:.2g} m/s as metres: read as lon/lat "
                      f"(--columns x={xc},y={yc} to read them as metres)")
    return True


#: Degrees of longitude that a legal time may lie from 15 deg x its UTC offset, besides an hour of
#: summer time: legal time runs up to ~3 h ahead of solar time (western China, 44 deg), never 2 h behind.
ZONE_MARGIN_DEG = 30.0


def _zone_check(df: pd.DataFrame, plan: Interpretation) -> None:
    """A warning note when the time stamps' UTC offset rules out the longitude column but fits the
    latitude column: probably swapped columns (both within range, so nothing else shows it).

    An offset of h hours puts the fixes within [15 (h - 1) - 30, 15 h + 30] degrees east (standard
    or summer time, with :data:`ZONE_MARGIN_DEG`); only offsets other than 0 count (+00:00 and Z are
    how most programs write UTC, wherever the fixes are)."""
    if plan.swap or "time" not in df.columns or not (pd.api.types.is_string_dtype(df["time"])
                                                     or df["time"].dtype == object):
        return
    found = df["time"].dropna().iloc[:_ZONE_SAMPLE].astype(str).str.extract(_ZONE)
    found = found.dropna(subset=[0])
    if found.empty:
        return
    hours = (found[1].astype(float) + found[2].fillna("0").astype(float) / 60) * found[0].map({"+": 1, "-": -1})
    hours = hours[hours != 0]
    if hours.empty:
        return
    offset = float(hours.mode().iloc[0])
    lat = float(np.nanmedian(pd.to_numeric(df["lat"], errors="coerce")))
    lon = float(np.nanmedian(pd.to_numeric(df["lon"], errors="coerce")))
    lo, hi = 15 * (offset - 1) - ZONE_MARGIN_DEG, 15 * offset + ZONE_MARGIN_DEG
    if not (_beyond(lon, lo, hi) > 0 and _beyond(lat, lo, hi) <= 0):
        return
    names = {v: str(k) for k, v in plan.rename.items()}
    lat_col, lon_col = names.get("lat", "lat"), names.get("lon", "lon")
    sign = "+" if offset >= 0 else "-"
    shown = f"{sign}{int(abs(offset)):02d}:{round(abs(offset) % 1 * 60):02d}"
    plan.notes.append(f"warning: the time stamps' UTC offset {shown} puts the fixes between {_east(lo)} and "
                      f"{_east(hi)}, but the longitude column {lon_col!r} reads {lon:.4g} deg; the latitude column "
                      f"{lat_col!r} ({lat:.4g} deg) would fit as longitude: if the two columns are swapped, read "
                      f"them with --columns lat={lon_col},lon={lat_col}")


def _beyond(x: float, lo: float, hi: float) -> float:
    """Degrees by which longitude ``x`` lies outside [lo, hi] (around the globe; <= 0 inside)."""
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    return abs((x - centre + 180) % 360 - 180) - half


def _east(deg: float) -> str:
    deg = (deg + 180) % 360 - 180
    return f"{abs(deg):g} deg {'E' if deg >= 0 else 'W'}"
