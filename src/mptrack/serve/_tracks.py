"""A device's stored track as the query API returns it, in the formats ``mptrack track`` writes.

Without smoothing: every stored fix as sent (``meas_lat``, ``meas_lon``, ``accuracy_m``, ...) with
the live estimate made when it arrived (``lat``, ``lon``, velocity, covariance, 1-sigma ellipse,
NIS, flag; a late fix has no estimate and the flag "late").  With ``smooth=true``: the stored fixes
through :func:`mptrack.track` with ``smooth=True`` -- the engine and the noise estimation of
``mptrack track --smooth``, so the two agree on the same fixes.  Where two stored fixes of a device
have the same time (a late fix that repeats a time with another position), the one stored first is
used for smoothing.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from ..io import write_table
from ..tracking import ellipse
from ._store import FLAG_NAMES, StoredRows

__all__ = ["FORMATS", "track_body", "live_frame", "fix_frame"]

#: format -> (media type, file suffix of :func:`mptrack.io.write_table`)
FORMATS = {"json": ("application/json", None), "geojson": ("application/geo+json", ".geojson"),
           "gpx": ("application/gpx+xml", ".gpx"), "csv": ("text/csv", ".csv"),
           "parquet": ("application/vnd.apache.parquet", ".parquet")}


def _times(t: np.ndarray) -> pd.Series:
    return pd.Series(pd.to_datetime(np.round(t * 1e6).astype("int64"), unit="us", utc=True))


def fix_frame(device: str, rows: StoredRows) -> pd.DataFrame:
    """The stored fixes as ``mptrack track`` reads them (one per time: the first stored)."""
    order = np.lexsort((rows["seq"], rows["t"]))
    t = rows["t"][order]
    keep = order[np.r_[True, t[1:] != t[:-1]]] if len(t) else order
    return pd.DataFrame({"track_id": device, "time": _times(rows["t"][keep]), "lat": rows["lat"][keep],
                         "lon": rows["lon"][keep], "accuracy_m": rows["accuracy_m"][keep]})


def live_frame(device: str, rows: StoredRows) -> pd.DataFrame:
    """The stored fixes with their live estimates (see the module doc), in time order."""
    major, minor, az = ellipse(rows["var_e"], rows["cov_en"], rows["var_n"])
    return pd.DataFrame({
        "track_id": device, "time": _times(rows["t"]), "lat": rows["est_lat"], "lon": rows["est_lon"],
        "vel_east_mps": rows["vel_e"], "vel_north_mps": rows["vel_n"], "var_east_m2": rows["var_e"],
        "cov_en_m2": rows["cov_en"], "var_north_m2": rows["var_n"], "ell_major_m": major, "ell_minor_m": minor,
        "ell_azimuth_deg": az, "nis": rows["nis"], "flag": np.array(FLAG_NAMES, dtype=object)[rows["flag"]],
        "meas_lat": rows["lat"], "meas_lon": rows["lon"], "accuracy_m": rows["accuracy_m"],
        "speed_mps": rows["speed_mps"], "heading_deg": rows["heading_deg"], "altitude_m": rows["altitude_m"],
        "received": _times(rows["received"]),
    })


def track_body(device: str, rows: StoredRows, smooth: bool, fmt: str) -> tuple[bytes, str]:
    """(body, media type) of a device's track (see the module doc)."""
    if smooth and len(rows):
        from .. import track

        frame = track(fix_frame(device, rows), smooth=True)
        frame.attrs = {}
    else:
        frame = live_frame(device, rows)
    media, suffix = FORMATS[fmt]
    if suffix is None:
        return frame.to_json(orient="records", date_format="iso", date_unit="ms", double_precision=15).encode(), media
    with tempfile.TemporaryDirectory(prefix="mptrack-track-") as tmp:
        path = Path(tmp) / f"track{suffix}"
        write_table(frame, path)
        return path.read_bytes(), media
