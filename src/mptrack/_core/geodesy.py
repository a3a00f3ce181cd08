"""The compiled WGS-84 <-> local East-North kernels, one origin per row (the method and its accuracy:
:func:`mptrack.io.geodetic_to_enu` and :func:`mptrack.io.enu_to_geodetic`, their checked public
forms), and the inline one-point functions (:func:`origin_terms`, :func:`enu_row`, :func:`geodetic_row`) for other
compiled kernels (the live filter of ``mptrack serve``, which converts a batch of a few dozen fixes
inside its own kernel)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["origin_terms", "enu_row", "geodetic_row"]

# WGS-84 defining parameters (NIMA TR8350.2, 3rd ed., 2000, Table 3.1): semi-major axis a (m)
# and flattening f; e2 is the first eccentricity squared, ep2 the second.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)
_EP2 = _E2 / (1.0 - _E2)
_RAD = math.pi / 180.0           # radians per degree
_DEG = 180.0 / math.pi           # degrees per radian

_BLOCK = 4096                    # rows per prange task
_SERIAL_ROWS = 1 << 14           # fewer rows: run on the calling thread (waking the others costs more)
_JIT = dict(cache=True, nogil=True, error_model="numpy")


# ---- compiled kernels -----------------------------------------------------------------------------

@nb.njit(inline="always")
def _sincosd(deg):
    """(sin, cos) of an angle in degrees in [-90, 90], each to full relative precision.

    ``cos`` is taken as the sine of the colatitude 90 - |deg| (exact in degrees for
    |deg| >= 45), so it keeps its relative precision near the poles, where
    cos(deg * pi/180) would carry the absolute error of the radian conversion
    (1e-16 rad, i.e. ~1e-9 m of east at the pole).
    """
    return math.sin(deg * _RAD), math.sin((90.0 - abs(deg)) * _RAD)


@nb.njit(inline="always")
def origin_terms(lat0):
    """(sin lat0, cos lat0, sqrt(1 - e2 sin^2 lat0)) of an origin latitude (degrees)."""
    s0, c0 = _sincosd(lat0)
    return s0, c0, math.sqrt(1.0 - _E2 * s0 * s0)


@nb.njit(inline="always")
def _dlon_rad(lon, lon0):
    """lon - lon0 in radians, wrapped into [-pi, pi]; across the antimeridian the difference is
    formed as (lon -+ 180) - (lon0 +- 180), whose terms are exact, not as (lon - lon0) -+ 360."""
    d = lon - lon0
    if d > 180.0:
        d = (lon - 180.0) - (lon0 + 180.0)
    elif d < -180.0:
        d = (lon + 180.0) - (lon0 - 180.0)
    return d * _RAD


@nb.njit(inline="always")
def enu_row(lat, lon, lat0, lon0, h, s0, c0, w0):
    """East, north (m) of one point; s0, c0 = sin, cos lat0, w0 = sqrt(1 - e2 s0^2)."""
    dphi = (lat - lat0) * _RAD
    sd = math.sin(dphi)
    sh = math.sin(0.5 * dphi)
    vd = 2.0 * sh * sh                          # 1 - cos(dphi)
    ds = c0 * sd - s0 * vd                      # sin(lat) - sin(lat0)
    s = s0 + ds
    c = c0 - (c0 * vd + s0 * sd)                # cos(lat)
    w = math.sqrt(1.0 - _E2 * s * s)
    n0 = WGS84_A / w0
    dn = WGS84_A * _E2 * ds * (s + s0) / (w * w0 * (w + w0))   # N - N0
    r = WGS84_A / w + h                         # N + h
    dlam = _dlon_rad(lon, lon0)
    sl = math.sin(0.5 * dlam)
    east = r * c * math.sin(dlam)
    north = r * (sd + 2.0 * s0 * c * sl * sl) - _E2 * c0 * (dn * s + n0 * ds)
    return east, north


@nb.njit(inline="always")
def geodetic_row(east, north, lat0, lon0, s0, c0, w0):
    """Latitude, longitude (degrees) of the ellipsoid point at east, north (m); NaN if the
    origin's vertical through (east, north) misses the ellipsoid (thousands of km away)."""
    n0 = WGS84_A / w0
    w = 1.0 + _EP2 * s0 * s0
    beta = n0 + _EP2 * s0 * c0 * north
    cc = east * east + north * north * (1.0 + _EP2 * c0 * c0)
    disc = beta * beta - w * cc
    if disc < 0.0:
        return np.nan, np.nan
    u = -cc / (beta + math.sqrt(disc))                           # the up coordinate of the point
    x = (n0 + u) * c0 - north * s0                               # in the origin's meridian plane
    z = (n0 * (1.0 - _E2) + u) * s0 + north * c0
    p = math.sqrt(x * x + east * east)                           # distance from the polar axis
    p_minus_x = east * east / (p + x) if x > 0.0 else p - x
    num = north * w0 * w0 + _E2 * s0 * c0 * u - (1.0 - _E2) * s0 * p_minus_x
    den = (1.0 - _E2) * c0 * p + s0 * z
    lat = min(90.0, max(-90.0, lat0 + math.atan2(num, den) * _DEG))
    lon = lon0 + math.atan2(east, x) * _DEG
    if lon > 180.0:
        lon -= 360.0
    elif lon < -180.0:
        lon += 360.0
    return lat, lon


@nb.njit(**_JIT)
def _enu_rows(lat, lon, lat0, lon0, h, east, north, start, stop):
    """Rows start..stop-1 of :func:`geodetic_to_enu` into ``east``, ``north``.

    Each input holds one value per row or a single value for all rows.
    """
    k_lat, k_lon, k_h = int(lat.size > 1), int(lon.size > 1), int(h.size > 1)
    k_lat0, k_lon0 = int(lat0.size > 1), int(lon0.size > 1)
    last = np.nan
    s0 = c0 = w0 = 0.0
    for i in range(start, stop):
        phi0 = lat0[i * k_lat0]
        if phi0 != last:                        # once per run of equal origins (per track)
            s0, c0, w0 = origin_terms(phi0)
            last = phi0
        east[i], north[i] = enu_row(lat[i * k_lat], lon[i * k_lon], phi0, lon0[i * k_lon0],
                                    h[i * k_h], s0, c0, w0)
    return 0


@nb.njit(**_JIT)
def _geodetic_rows(east, north, lat0, lon0, lat, lon, start, stop):
    """Rows start..stop-1 of :func:`enu_to_geodetic` into ``lat``, ``lon``; returns the number of
    rows whose point is off the ellipsoid (NaN)."""
    k_e, k_n = int(east.size > 1), int(north.size > 1)
    k_lat0, k_lon0 = int(lat0.size > 1), int(lon0.size > 1)
    last = np.nan
    s0 = c0 = w0 = 0.0
    missed = 0
    for i in range(start, stop):
        phi0 = lat0[i * k_lat0]
        if phi0 != last:
            s0, c0, w0 = origin_terms(phi0)
            last = phi0
        lat[i], lon[i] = geodetic_row(east[i * k_e], north[i * k_n], phi0, lon0[i * k_lon0], s0, c0, w0)
        missed += np.isnan(lat[i])
    return missed


@nb.njit(parallel=True, **_JIT)
def _enu_parallel(lat, lon, lat0, lon0, h, east, north):
    """:func:`_enu_rows` over all rows, one block of rows per task."""
    n = east.size
    for b in nb.prange((n + _BLOCK - 1) // _BLOCK):
        _enu_rows(lat, lon, lat0, lon0, h, east, north, b * _BLOCK, min(n, (b + 1) * _BLOCK))
    return 0


@nb.njit(parallel=True, **_JIT)
def _geodetic_parallel(east, north, lat0, lon0, lat, lon):
    """:func:`_geodetic_rows` over all rows, one block of rows per task."""
    n = lat.size
    missed = 0
    for b in nb.prange((n + _BLOCK - 1) // _BLOCK):
        missed += _geodetic_rows(east, north, lat0, lon0, lat, lon, b * _BLOCK, min(n, (b + 1) * _BLOCK))
    return missed


def _run(rows_kernel, parallel_kernel, columns: list[np.ndarray], outputs: list[np.ndarray]) -> int:
    n = outputs[0].size
    if n < _SERIAL_ROWS:
        return int(rows_kernel(*columns, *outputs, 0, n))
    return int(parallel_kernel(*columns, *outputs))
