"""G-NetTrack Pro drive-test logs (tab-separated text, one header line, one line per scan): one track per
file, ``track_id`` = the file's stem.

Read as position fixes, a log is the phone's own GPS track (``Latitude``, ``Longitude``, ``Accuracy``
as ``accuracy_m``, ``Speed`` km/h as ``speed_mps``, ``Altitude`` as ``elevation_m``): the truth of a
cellular log, for ``mptrack evaluate --truth``.  Scans without a position are left out.

Read as cellular measurements, a scan gives one row per cell heard, the serving cell first:

* the serving cell with its global identity, ``cell_id`` = "mcc-mnc-area-cell" (``Operator`` split as
  MCC, the first three digits, and MNC; ``LAC``, the TAC of LTE; ``RAWCELLID``, the E-UTRAN cell id
  eNB x 256 + local id), its ``Level`` (RSRP for LTE) as ``rss_dbm`` and its timing advance as ``ta``
  (the ``ta=`` of the registered cell in Android's dump that the app appends to the line; the app's own
  ``TA`` column repeats the last value it saw and is not used);
* the neighbours ``NTech<i>``/``NCell<i>`` (the PCI)/``NARFCN<i>``/``NRxLev<i>``: a neighbour carries no
  global identity, so its ``cell_id`` is left for the cell table to resolve by PCI and EARFCN
  (:func:`mptrack.tracking.resolve_cells`), its columns ``pci`` and ``earfcn`` set.

Every row also has ``role`` (serving / neighbour), ``radio``, ``pci``, ``earfcn``, ``mcc`` and ``area``.

The time stamps (``YYYY.MM.DD_HH.MM.SS``) are the phone's local time: they are read in the time zone
given (``timezone``, e.g. "Europe/Brussels"), else as UTC (a note says so).  Left out and counted
(:class:`Skipped`): a scan in the same second as the one before (the log has 1-s stamps; the first
scan of a second is kept, in both readings, so a track and its truth pair up), neighbours without an
identity or with a placeholder level (Android's 2G entries, -205 dBm), scans without a serving cell.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import DataError, ParameterError
from ._formats import Skipped

__all__ = ["read", "check_timezone"]

_NEEDED = ("Timestamp", "Longitude", "Latitude", "Operator", "LAC", "NetworkTech", "Level")
_TECH = {"2G": "GSM", "3G": "UMTS", "4G": "LTE", "5G": "NR"}
_TS = re.compile(r"^\d{4}\.\d{2}\.\d{2}_\d{2}\.\d{2}\.\d{2}$")
_REGISTERED_TA = re.compile(r"mRegistered=YES.*?\bta=(\d+)")
_UNAVAILABLE = 2147483647
_KMH = 1.0 / 3.6


def check_timezone(timezone):
    """The zoneinfo of an IANA zone name ("Europe/Brussels"), None for None."""
    if timezone is None:
        return None
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    if not isinstance(timezone, str) or not timezone.strip():
        raise ParameterError(f"timezone: expected an IANA time zone name such as 'Europe/Brussels', got {timezone!r}")
    try:
        return ZoneInfo(timezone.strip())
    except (ZoneInfoNotFoundError, ValueError):
        raise ParameterError(f"timezone: unknown time zone {timezone!r} (an IANA name such as 'Europe/Brussels' "
                             "or 'UTC')") from None


def _lines(path: Path) -> tuple[list[str], list[list[str]]]:
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as fh:
        header = fh.readline().rstrip("\r\n").split("\t")
        rows = [line.rstrip("\r\n").split("\t") for line in fh if line.strip()]
    missing = [c for c in _NEEDED if c not in header]
    if missing:
        raise DataError(f"cannot be read as a G-NetTrack Pro log: no column {', '.join(missing)}", file=path)
    return header, rows


def _num(values) -> np.ndarray:
    return pd.to_numeric(pd.Series(values, dtype=object).replace({"-": None, "": None}), errors="coerce").to_numpy(
        float)


def _times(stamps: list[str], path: Path, timezone, skipped: list) -> pd.Series:
    """UTC times of the local stamps; a stamp that is not YYYY.MM.DD_HH.MM.SS is an error."""
    for i, s in enumerate(stamps):
        if not _TS.match(s):
            raise DataError(f"Timestamp {s!r} is not YYYY.MM.DD_HH.MM.SS", file=path, row=i + 1, column="Timestamp")
    local = pd.to_datetime(pd.Series(stamps), format="%Y.%m.%d_%H.%M.%S")
    zone = check_timezone(timezone)
    if zone is None:
        skipped.append(Skipped("note", 0, "local time stamps read as UTC (give the phone's time zone, e.g. "
                                          "--timezone Europe/Brussels)"))
        return local.dt.tz_localize("UTC")
    utc = local.dt.tz_localize(zone, ambiguous="NaT", nonexistent="NaT").dt.tz_convert("UTC")
    bad = utc.isna().to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise DataError(f"Timestamp {stamps[i]!r} does not exist or is ambiguous in {timezone} (a clock change)",
                        file=path, row=i + 1, column="Timestamp")
    return utc


def read(path: Path, skipped: list, *, cells: bool = False, timezone=None) -> pd.DataFrame:
    """The log at ``path`` as position fixes (``cells`` False) or as cellular measurements (see the module
    doc); records left out are appended to ``skipped``."""
    header, rows = _lines(path)
    if not rows:
        raise DataError("cannot be read as a G-NetTrack Pro log: no scan below the header", file=path)
    col = {name: i for i, name in enumerate(header)}
    width = len(header)

    def field(name: str) -> list[str]:
        i = col.get(name)
        return [r[i] if i is not None and i < len(r) else "" for r in rows]

    stamps = field("Timestamp")
    time = _times(stamps, path, timezone, skipped)
    repeat = np.r_[False, np.array(stamps[1:]) == np.array(stamps[:-1])]
    if repeat.any():
        skipped.append(Skipped("scan in the same second as the one before", int(repeat.sum()),
                               f"{int(repeat.sum())} scans repeat the second of the scan before them (the log's "
                               "time stamps have 1-s resolution): the first of each second is kept"))
    track = path.stem
    keep = ~repeat
    if not cells:
        lat, lon = _num(field("Latitude")), _num(field("Longitude"))
        fix = keep & np.isfinite(lat) & np.isfinite(lon) & ~((lat == 0) & (lon == 0))
        if (keep & ~fix).any():
            skipped.append(Skipped("scan without a GPS position", int((keep & ~fix).sum()),
                                   "scans without the phone's own position are not fixes"))
        out = pd.DataFrame({"track_id": track, "time": time, "lat": lat, "lon": lon,
                            "accuracy_m": _num(field("Accuracy")), "speed_mps": _num(field("Speed")) * _KMH,
                            "elevation_m": _num(field("Altitude"))})
        return out.loc[fix].reset_index(drop=True)
    return _cells(rows, field, col, width, time, keep, track, skipped)


def _cells(rows, field, col, width, time, keep, track, skipped) -> pd.DataFrame:
    operator = field("Operator")
    mcc = _num([o[:3] for o in operator])
    mnc = _num([o[3:] for o in operator])
    area, level, arfcn, pci = (_num(field(c)) for c in ("LAC", "Level", "ARFCN", "PSC"))
    raw = _num(field("RAWCELLID"))
    cid = np.where(np.isfinite(raw), raw, _num(field("CellID")))
    tech = field("NetworkTech")
    ta = np.full(len(rows), np.nan)
    for i, r in enumerate(rows):
        m = _REGISTERED_TA.search("\t".join(r[width:])) if len(r) > width else None
        if m and int(m.group(1)) != _UNAVAILABLE:
            ta[i] = int(m.group(1))
    ids = np.isfinite(mcc) & np.isfinite(mnc) & np.isfinite(area) & np.isfinite(cid)
    level = np.where((level >= -160) & (level <= 0), level, np.nan)
    serving = keep & ids & (np.isfinite(level) | np.isfinite(ta))
    if (keep & ~serving).any():
        skipped.append(Skipped("scan without a serving cell", int((keep & ~serving).sum()),
                               "scans without the serving cell's identity or level are not measurements"))
    out = [pd.DataFrame({"track_id": track, "time": time, "scan": np.arange(len(rows)), "slot": 0,
                         "role": "serving", "radio": [_TECH.get(t, t) for t in tech], "mcc": mcc, "area": area,
                         "cell_id": [f"{a:.0f}-{b:.0f}-{c:.0f}-{d:.0f}" if ok else "" for a, b, c, d, ok in
                                     zip(mcc, mnc, area, cid, ids)],
                         "pci": pci, "earfcn": arfcn, "rss_dbm": level,
                         "ta": ta})[serving]]
    k = 1
    bad = 0
    while f"NTech{k}" in col:
        ntech = field(f"NTech{k}")
        npci, narfcn, nlev = (_num(field(f"{c}{k}")) for c in ("NCell", "NARFCN", "NRxLev"))
        heard = serving & np.array([t != "" for t in ntech])
        ok = heard & np.isfinite(npci) & np.isfinite(narfcn) & (nlev >= -160) & (nlev <= 0)
        bad += int((heard & ~ok).sum())
        out.append(pd.DataFrame({"track_id": track, "time": time, "scan": np.arange(len(rows)), "slot": k,
                                 "role": "neighbour", "radio": [_TECH.get(t, t) for t in ntech], "mcc": mcc,
                                 "area": np.nan, "cell_id": [f"PCI {p:.0f} EARFCN {e:.0f}" if o else "" for p, e, o in
                                                             zip(npci, narfcn, ok)],
                                 "pci": npci, "earfcn": narfcn, "rss_dbm": nlev, "ta": np.nan})[ok])
        k += 1
    if bad:
        skipped.append(Skipped("neighbour without identity or level", bad,
                               f"{bad} neighbour entries without a PCI/channel or with a placeholder level (Android "
                               "lists 2G neighbours it cannot identify at -113 dBm, some levels at -205 dBm)"))
    df = pd.concat(out, ignore_index=True).sort_values(["scan", "slot"], kind="stable")
    return df.drop(columns=["scan", "slot"]).reset_index(drop=True)
