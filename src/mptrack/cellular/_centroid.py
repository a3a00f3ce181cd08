"""The weighted centroid of Mozilla's location service (Ichnaea), the baseline and the fallback of
:func:`mptrack.cellular.locate_cells`.

Ichnaea (``ichnaea/api/locate/cell.py``, ``score.py``) groups the known cells of a request by location
area and, in each group, places the phone at the centroid of the cells' positions weighted by

    w = score x min(sqrt(2000 / age_ms), 1) / signalStrength^2

(age floored at 1000 ms; a cell without a level takes the radio's minimum: GSM -113, WCDMA -121, LTE
-140 dBm), with the accuracy the 95th percentile of the distances from the centroid to the cells,
clamped to 1000..50000 m.  One cell gives its own position with its range as accuracy (same clamp).
The station score rates the table row: age weight 1/sqrt(months since update + 1) x collection weight
min(days between first and last seen / 10, 1) x samples weight clamp(log2(samples), 0.5, 10).
The group with the highest total score is the answer.
"""

from __future__ import annotations

import math

import numpy as np

from .._core.validation import as_array, broadcast_shape
from ..errors import ParameterError

__all__ = ["weighted_centroid", "station_score", "CENTROID_ACCURACY_M"]

#: Ichnaea's clamp of a cell answer's accuracy (m); it states the accuracy as a 95 % radius.
CENTROID_ACCURACY_M = (1000.0, 50000.0)
_DAY = 86400.0
EARTH_M = 6_371_008.8


def station_score(samples, created, updated, now: float) -> np.ndarray:
    """Ichnaea's score of table rows (``score.py``, station_score): the age, collection and samples weights
    of the module doc.

    Parameters
    ----------
    samples : array_like
        Observations behind each row (NaN: one).
    created, updated : array_like
        First and last seen, seconds since 1970 (NaN: unknown, weight 1).
    now : float
        The present, seconds since 1970.

    Returns
    -------
    float or ndarray
        The scores, broadcast over the arguments.
    """
    k = as_array("samples", samples, allow_nan=True, low=0.0)
    c = as_array("created", created, allow_nan=True)
    u = as_array("updated", updated, allow_nan=True)
    shape = broadcast_shape(samples=k, created=c, updated=u)
    k, c, u = (np.broadcast_to(v, shape) for v in (k, c, u))
    months = np.floor(np.maximum((now - u) / _DAY, 0.0) // 30.0)
    age = np.where(np.isnan(u), 1.0, 1.0 / np.sqrt(np.where(np.isnan(months), 0.0, months) + 1.0))
    days = np.maximum(np.floor((u - c) / _DAY), 1.0)
    collection = np.where(np.isnan(days), 1.0, np.minimum(np.where(np.isnan(days), 1.0, days) / 10.0, 1.0))
    with np.errstate(divide="ignore"):
        weight = np.clip(np.log2(np.maximum(np.where(np.isnan(k), 1.0, k), 1.0)), 0.5, 10.0)
    out = age * collection * weight
    return out[()] if out.ndim == 0 else out


def weighted_centroid(lat, lon, area, range_m, score, rss_dbm, age_ms, min_signal_dbm) -> tuple[float, float, float]:
    """The position of one request by Ichnaea's weighted centroid (the module doc).

    Parameters
    ----------
    lat, lon : array_like
        The known cells' positions (degrees), one per cell heard.
    area : array_like
        Their location-area keys (any integers: cells are grouped by equal keys).
    range_m : array_like
        Their table range (NaN: unknown, the clamp's minimum).
    score : array_like
        Their station score (:func:`station_score`).
    rss_dbm : array_like
        The levels reported (NaN or 0: none).
    age_ms : array_like
        The ages (ms; NaN: none).
    min_signal_dbm : array_like
        Each cell's radio minimum, used where a level is missing.

    Returns
    -------
    lat, lon, accuracy_m : float
        The centroid of the best-scored area and its accuracy (the 95th percentile of its cells'
        distances, clamped to 1-50 km; one cell: its range).
    """
    lat = as_array("lat", lat, ndim=1, low=-90.0, high=90.0)
    arrays = {"lon": lon, "area": area, "range_m": range_m, "score": score, "rss_dbm": rss_dbm, "age_ms": age_ms,
              "min_signal_dbm": min_signal_dbm}
    nan_ok = {"range_m", "rss_dbm", "age_ms"}
    v = {k: as_array(k, a, ndim=1, allow_nan=k in nan_ok) for k, a in arrays.items()}
    if len(lat) == 0:
        raise ParameterError("lat: expected at least one cell")
    for k, a in v.items():
        if len(a) != len(lat):
            raise ParameterError(f"{k}: expected {len(lat)} values (one per cell), got {len(a)}")
    if np.any(np.abs(v["lon"]) > 180.0):
        raise ParameterError("lon: expected longitudes within -180..180 degrees")
    if np.any(v["score"] < 0.0):
        raise ParameterError("score: expected scores >= 0")
    lo, hi = CENTROID_ACCURACY_M
    best = None
    for key in np.unique(v["area"]):
        g = v["area"] == key
        total = float(v["score"][g].sum())
        if best is not None and total <= best[0]:
            continue
        la, lo_, rng = lat[g], v["lon"][g], v["range_m"][g]
        if len(la) == 1:
            r = rng[0] if np.isfinite(rng[0]) else lo
            best = (total, float(la[0]), float(lo_[0]), float(min(max(r, lo), hi)))
            continue
        s = v["rss_dbm"][g]
        s = np.where(np.isnan(s) | (s == 0.0), v["min_signal_dbm"][g], s)
        age = np.maximum(np.abs(np.where(np.isnan(v["age_ms"][g]), 0.0, v["age_ms"][g])), 1000.0)
        w = v["score"][g] * np.minimum(np.sqrt(2000.0 / age), 1.0) / s ** 2
        if not w.sum() > 0.0:
            w = np.ones_like(w)
        clat, clon = float(np.average(la, weights=w)), float(np.average(lo_, weights=w))
        dist = _haversine(clat, clon, la, lo_)
        best = (total, clat, clon, float(min(max(np.percentile(dist, 95), lo), hi)))
    return best[1], best[2], best[3]


def _haversine(lat0, lon0, lat, lon) -> np.ndarray:
    p0, p = math.radians(lat0), np.radians(lat)
    a = np.sin((p - p0) / 2) ** 2 + math.cos(p0) * np.cos(p) * np.sin(np.radians(lon - lon0) / 2) ** 2
    return 2.0 * EARTH_M * np.arcsin(np.sqrt(np.minimum(a, 1.0)))
