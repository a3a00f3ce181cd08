"""Garmin FIT activity files (decoded with fitdecode): one track per file, ``track_id`` = the file's stem.

Every ``record`` message is a point: ``timestamp`` -> ``time`` (UTC),
``position_lat``/``position_long`` (semicircles) -> ``lat``/``lon`` (degrees,
x 180 / 2^31), ``enhanced_altitude`` (else ``altitude``) -> ``elevation_m``,
``enhanced_speed`` (else ``speed``) -> ``speed_mps``, ``distance`` ->
``distance_m``, ``gps_accuracy`` -> ``accuracy_m``; every other number the
record carries (``heart_rate``, ``cadence``, ``power``, ``temperature``,
developer fields, ...) keeps its FIT name.  Fields the FIT profile does not
name (``unknown_88``) and text fields are left out.

Records without a position (indoor activities, the seconds before the GPS fix)
are left out and reported as :class:`Skipped`, and so are the records after the
point where a truncated file ends (a watch that died mid-activity), a file CRC
that does not match and values fitdecode cannot decode.  A file that is not FIT, or has no record with a
position, is a DataError.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pandas as pd

from ..errors import DataError
from ._formats import Skipped, library_error, snake_case, utc_times

_SEMICIRCLE_DEG = 180.0 / 2 ** 31
_RENAMED = {"enhanced_altitude": "elevation_m", "enhanced_speed": "speed_mps", "distance": "distance_m",
            "gps_accuracy": "accuracy_m"}
_FALLBACK = {"altitude": "elevation_m", "speed": "speed_mps"}   # used when the enhanced field is absent
_NOT_COLUMNS = {"timestamp", "position_lat", "position_long"}


def read(path: Path, skipped: list) -> pd.DataFrame:
    import fitdecode

    rows: list[dict] = []
    n_records = 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with fitdecode.FitReader(str(path), check_crc=fitdecode.CrcCheck.WARN,
                                     error_handling=fitdecode.ErrorHandling.WARN) as fit:
                for frame in fit:
                    if isinstance(frame, fitdecode.FitDataMessage) and frame.name == "record":
                        n_records += 1
                        rows.append(_record(frame))
        except fitdecode.FitEOFError as exc:
            if not n_records:
                raise library_error("fit", path, exc) from None
            skipped.append(Skipped("FIT file truncated", 1,
                                   f"{path}: the file ends early ({exc}); read the {n_records} records before "
                                   "that"))
        except (fitdecode.FitError, ValueError, KeyError, IndexError, TypeError) as exc:
            raise library_error("fit", path, exc) from None
    crc = [w for w in caught if "crc" in str(w.message).lower()]
    if crc:
        skipped.append(Skipped("FIT file CRC mismatch", 1,
                               f"{path}: the file's CRC does not match ({crc[0].message}); it may be damaged"))
    other = [w for w in caught if w not in crc]
    if other:
        skipped.append(Skipped("FIT value not decoded", len(other),
                               f"{path}: {len(other)} values could not be decoded (first: {other[0].message})"))
    if not n_records:
        raise DataError("no record messages in the FIT file (is it an activity? settings, workout and "
                        "monitoring files hold no track)", file=path)
    placed = [r for r in rows if r.get("lat") is not None and r.get("lon") is not None]
    timed = [r for r in placed if r.get("time") is not None]
    if len(placed) < len(rows):
        n = len(rows) - len(placed)
        skipped.append(Skipped("FIT record without a position", n,
                               f"{path}: {n} of {len(rows)} records have no position (indoor, or before the "
                               "GPS fix); left out"))
    if len(timed) < len(placed):
        n = len(placed) - len(timed)
        skipped.append(Skipped("FIT record without a time stamp", n,
                               f"{path}: {n} records have no timestamp; left out"))
    if not timed:
        raise DataError(f"no positions in the FIT file: none of its {len(rows)} records has a timestamp and a "
                        "position (an indoor activity?)", file=path)
    df = pd.DataFrame.from_records([{k: v for k, v in r.items() if k != "time"} for r in timed])
    df = df.reindex(columns=["lat", "lon"] + [c for c in df.columns if c not in ("lat", "lon")])
    df.insert(0, "time", utc_times(r["time"] for r in timed))
    df.insert(0, "track_id", pd.array([path.stem] * len(df), dtype="string"))
    return df


def _record(frame) -> dict:
    """One record message as {column: value}: time, lat/lon in degrees, and the numeric fields."""
    values = {}
    for f in frame.fields:
        if f.value is not None and f.name not in values:
            values[f.name] = f.value
    out = {"time": values.get("timestamp")}
    lat, lon = values.get("position_lat"), values.get("position_long")
    if isinstance(lat, (int, float)) and isinstance(lon, (int, float)):
        out["lat"], out["lon"] = lat * _SEMICIRCLE_DEG, lon * _SEMICIRCLE_DEG
    for name, value in values.items():
        if name in _NOT_COLUMNS or name.startswith("unknown_") or isinstance(value, bool) \
                or not isinstance(value, (int, float)):
            continue
        if name in _FALLBACK:
            if _FALLBACK[name] in out or _enhanced(name) in values:
                continue
            col = _FALLBACK[name]
        else:
            col = _RENAMED.get(name, snake_case(name))
        out[col] = float(value)
    return out


def _enhanced(name: str) -> str:
    return f"enhanced_{name}"
