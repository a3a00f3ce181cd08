"""A chunk of position fixes as flat columns: the input of the tracking engine.

The rows of B whole tracks, in file order (each track contiguous and in time
order, as :func:`mptrack.io.iter_track_chunks` delivers them), held as NumPy
columns plus ``offsets`` (track b is rows ``offsets[b]:offsets[b+1]``).  Each
track has its own local ENU frame with its origin at its first fix; the
conversion runs once over all rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._core.tracks import track_offsets
from ..io import geodetic_to_enu

__all__ = ["FixTable", "median_by", "time_values"]


@dataclass(frozen=True, eq=False)
class FixTable:
    """Position fixes of whole tracks (see the module doc).

    ids        (B,) track ids (str)
    offsets    (B+1,) int64 row offsets of the tracks
    t          (N,) seconds
    time       (N,) the time stamps as read: datetime64[ns] (UTC) or float seconds
    east, north  (N,) metres in the track's frame (x/y input: the input's own metres)
    lat, lon   (N,) input degrees, or None for x/y input
    accuracy   (N,) 1-sigma accuracy of each fix (m, NaN where empty), or None without the column
    row        (N,) record number of each row in the input (1-based)
    """

    ids: np.ndarray
    offsets: np.ndarray
    t: np.ndarray
    time: np.ndarray
    east: np.ndarray
    north: np.ndarray
    lat: np.ndarray | None
    lon: np.ndarray | None
    accuracy: np.ndarray | None
    row: np.ndarray

    @property
    def B(self) -> int:
        return len(self.ids)

    @property
    def N(self) -> int:
        return len(self.t)

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)

    @property
    def geographic(self) -> bool:
        return self.lat is not None

    @property
    def origin(self) -> tuple[np.ndarray, np.ndarray]:
        """(lat0, lon0) of each track's frame (its first fix); NaN for x/y input."""
        if not self.geographic:
            nan = np.full(self.B, np.nan)
            return nan, nan
        first = self.offsets[:-1]
        return self.lat[first], self.lon[first]

    def per_row(self, values: np.ndarray) -> np.ndarray:
        """Per-track values repeated for each of the track's rows."""
        return np.repeat(values, self.counts)

    def per_track_median(self, values: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
        """(B,) median of each track's ``values`` (over the rows ``where`` is true; NaN where none is)."""
        return median_by(self.per_row(np.arange(self.B)), values, np.arange(self.B), where)

    @classmethod
    def from_frame(cls, rows: pd.DataFrame) -> "FixTable":
        """The table of validated rows of whole tracks (columns track_id, time, t, row, lat/lon or x/y,
        optional accuracy_m)."""
        ids = rows["track_id"].to_numpy(dtype=object)
        offsets = track_offsets(ids)
        starts = offsets[:-1]
        time = time_values(rows["time"])
        t = rows["t"].to_numpy(dtype=float)
        if "lat" in rows.columns and "lon" in rows.columns:
            lat = rows["lat"].to_numpy(dtype=float)
            lon = rows["lon"].to_numpy(dtype=float)
            counts = np.diff(offsets)
            east, north = geodetic_to_enu(lat, lon, np.repeat(lat[starts], counts), np.repeat(lon[starts], counts))
        else:
            lat = lon = None
            east, north = rows["x"].to_numpy(dtype=float), rows["y"].to_numpy(dtype=float)
        accuracy = rows["accuracy_m"].to_numpy(dtype=float) if "accuracy_m" in rows.columns else None
        return cls(ids=np.array([str(i) for i in ids[starts]], dtype=object), offsets=offsets, t=t, time=time,
                   east=np.ascontiguousarray(east), north=np.ascontiguousarray(north), lat=lat, lon=lon,
                   accuracy=accuracy, row=rows["row"].to_numpy(dtype=np.int64))


def median_by(keys: np.ndarray, values: np.ndarray, wanted: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """The median of ``values`` over the rows of each key in ``wanted`` (rows ``where`` is true; NaN
    for a key without rows), one vectorised group-by."""
    sel = np.ones(len(keys), bool) if where is None else np.asarray(where, bool)
    med = pd.Series(values[sel]).groupby(keys[sel]).median()
    return med.reindex(wanted).to_numpy(dtype=float, copy=True)


def time_values(times: pd.Series) -> np.ndarray:
    """A validated time column as written back out: datetime64[ns] (UTC) or float seconds."""
    if pd.api.types.is_datetime64_any_dtype(times):
        return times.to_numpy(dtype="datetime64[ns]")
    return times.to_numpy(dtype=float)
