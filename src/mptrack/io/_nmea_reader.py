"""NMEA 0183 logs (sentences parsed with pynmea2): one track per file, ``track_id`` = the file's stem.

A receiver sends a burst of sentences per fix; consecutive sentences with the
same UTC time of day form one *epoch*, one row.  Its position comes from GGA
(else GNS, RMC, GLL); GGA adds ``elevation_m`` (above mean sea level),
``satellites``, ``hdop`` and ``fix_quality``; RMC adds ``speed_mps`` (from knots)
and ``course_deg``.  GGA, GNS and GLL carry only the time of day: the date comes
from RMC (or ZDA) sentences, carried forward and back across the file with
midnight roll-overs.

Left out and reported as :class:`Skipped` (a receiver logs them all the time;
none is a position): epochs without a fix (GGA quality 0, RMC/GLL status V, GNS
mode N, or empty position fields), sentences with a bad checksum, lines that
are not sentences (``#`` comment lines are ignored).  A DataError: a file
without any NMEA sentence, without any position sentence, without a date, or
where more than half the sentences fail their checksum (a damaged log).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..errors import DataError
from ._formats import Skipped, utc_times

_KNOT_MPS = 1852.0 / 3600.0
_POSITION_PRIORITY = {"GGA": 0, "GNS": 1, "RMC": 2, "GLL": 3}


@dataclass
class _Epoch:
    tod: dt.time
    line: int
    date: dt.date | None = None
    lat: float | None = None
    lon: float | None = None
    source: int = 99           # _POSITION_PRIORITY of the sentence that gave lat/lon
    no_fix: bool = False
    values: dict = field(default_factory=dict)


def read(path: Path, skipped: list) -> pd.DataFrame:
    import pynmea2

    epochs: list[_Epoch] = []
    sentences = bad_checksum = not_sentence = unparsed = 0
    first_bad = first_junk = None
    kinds: set[str] = set()
    with open(path, encoding="ascii", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            start = min((i for i in (text.find("$"), text.find("!")) if i >= 0), default=-1)
            if start < 0:
                not_sentence += 1
                first_junk = first_junk or (lineno, text)
                continue
            try:
                msg = pynmea2.parse(text[start:])
            except pynmea2.ChecksumError:
                sentences += 1
                bad_checksum += 1
                first_bad = first_bad or lineno
                continue
            except pynmea2.SentenceTypeError:   # a valid sentence of a type pynmea2 does not know
                sentences += 1
                continue
            except (pynmea2.ParseError, ValueError):
                not_sentence += 1
                first_junk = first_junk or (lineno, text)
                continue
            sentences += 1
            kind = getattr(msg, "sentence_type", "")
            kinds.add(kind)
            if kind in _POSITION_PRIORITY or kind == "ZDA":
                try:
                    _add(epochs, msg, kind, lineno)
                except (ValueError, TypeError, AttributeError):
                    unparsed += 1
    if not sentences:
        where = f" (line {first_junk[0]}: {first_junk[1][:40]!r})" if first_junk else ""
        raise DataError(f"cannot be read as NMEA 0183: no NMEA sentence in the file{where}", file=path)
    if bad_checksum * 2 > sentences:
        raise DataError(f"cannot be read as NMEA 0183: {bad_checksum} of {sentences} sentences fail their "
                        f"checksum (first: line {first_bad}); the log is damaged", file=path)
    if not kinds & set(_POSITION_PRIORITY):
        raise DataError("no position sentences (GGA, RMC, GNS or GLL) in the NMEA log; it has "
                        f"{', '.join(sorted(k for k in kinds if k)) or 'none'}", file=path)
    if bad_checksum:
        skipped.append(Skipped("NMEA sentence with a bad checksum", bad_checksum,
                               f"{path}: {bad_checksum} sentences fail their checksum (first: line {first_bad}); "
                               "left out"))
    if not_sentence + unparsed:
        n = not_sentence + unparsed
        where = f" (first: line {first_junk[0]})" if first_junk else ""
        skipped.append(Skipped("line that is not an NMEA sentence", n,
                               f"{path}: {n} lines are not readable NMEA sentences{where}; left out"))
    _date_epochs(epochs, path)
    fixes = [e for e in epochs if not e.no_fix and e.lat is not None and e.lon is not None]
    if len(fixes) < len(epochs):
        n = len(epochs) - len(fixes)
        skipped.append(Skipped("NMEA epoch without a fix", n,
                               f"{path}: {n} of {len(epochs)} epochs have no position fix (GGA quality 0, "
                               "status V or empty position); left out"))
    if not fixes:
        raise DataError(f"no position fix in the NMEA log: all {len(epochs)} epochs have none "
                        "(GGA quality 0, RMC/GLL status V or empty position fields)", file=path)
    columns = sorted({k for e in fixes for k in e.values})
    df = pd.DataFrame({"lat": [e.lat for e in fixes], "lon": [e.lon for e in fixes],
                       **{c: [e.values.get(c, float("nan")) for e in fixes] for c in columns}})
    df.insert(0, "time", utc_times(dt.datetime.combine(e.date, e.tod) for e in fixes))
    df.insert(0, "track_id", pd.array([path.stem] * len(df), dtype="string"))
    return df


def _add(epochs: list, msg, kind: str, lineno: int) -> None:
    """Merge one GGA/GNS/RMC/GLL/ZDA sentence into the epoch of its time of day."""
    tod = getattr(msg, "timestamp", None)
    if not isinstance(tod, dt.time):
        return  # no time field: nothing can be placed (receivers send these before the first fix)
    if tod.tzinfo is None:
        tod = tod.replace(tzinfo=dt.timezone.utc)
    if not epochs or epochs[-1].tod != tod:
        epochs.append(_Epoch(tod, lineno))
    e = epochs[-1]
    if kind == "ZDA":
        e.date = e.date or dt.date(int(msg.year), int(msg.month), int(msg.day))
        return
    if kind == "RMC":
        e.date = msg.datestamp if isinstance(msg.datestamp, dt.date) else e.date
        e.no_fix |= msg.status != "A"
        _put(e.values, "speed_mps", msg.spd_over_grnd, _KNOT_MPS)
        _put(e.values, "course_deg", msg.true_course)
    elif kind == "GLL":
        e.no_fix |= msg.status != "A"
    elif kind == "GGA":
        quality = _number(msg.gps_qual)
        e.no_fix |= not quality
        _put(e.values, "fix_quality", quality)
        _put(e.values, "satellites", msg.num_sats)
        _put(e.values, "hdop", msg.horizontal_dil)
        if (msg.altitude_units or "M") == "M":
            _put(e.values, "elevation_m", msg.altitude)
    elif kind == "GNS":
        e.no_fix |= set(msg.mode_indicator or "N") <= {"N"}
        _put(e.values, "satellites", msg.num_sats)
        _put(e.values, "hdop", msg.hdop)
        _put(e.values, "elevation_m", msg.altitude)
    if msg.lat and msg.lon and _POSITION_PRIORITY[kind] < e.source:
        e.lat, e.lon, e.source = float(msg.latitude), float(msg.longitude), _POSITION_PRIORITY[kind]


def _number(value) -> float | None:
    try:
        return float(value) if value not in (None, "") else None
    except (TypeError, ValueError):
        return None


def _put(values: dict, column: str, raw, scale: float = 1.0) -> None:
    number = _number(raw)
    if number is not None and column not in values:
        values[column] = number * scale


def _date_epochs(epochs: list, path) -> None:
    """Give every epoch a date: its own (RMC/ZDA), else the previous epoch's (+1 day when the time
    of day goes back: midnight), else for the epochs before the first dated one, the next one's."""
    dated = [i for i, e in enumerate(epochs) if e.date is not None]
    if not dated:
        raise DataError("no date in the NMEA log: GGA, GNS and GLL sentences carry only the time of day, "
                        "and there is no RMC or ZDA sentence to give the date", file=path)
    one_day = dt.timedelta(days=1)
    for i in range(dated[0] + 1, len(epochs)):
        if epochs[i].date is None:
            prev = epochs[i - 1]
            epochs[i].date = prev.date + (one_day if epochs[i].tod < prev.tod else dt.timedelta(0))
    for i in range(dated[0] - 1, -1, -1):
        nxt = epochs[i + 1]
        epochs[i].date = nxt.date - (one_day if epochs[i].tod > nxt.tod else dt.timedelta(0))
