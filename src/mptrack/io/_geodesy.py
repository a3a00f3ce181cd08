"""WGS-84 <-> local East-North-Up coordinates, compiled and vectorised over rows.

Each track is filtered in its own tangent plane: the origin is the track's
first fix (or the centroid of its cells for cellular logs), on the WGS-84
ellipsoid.  East/north are in metres; within a few tens of kilometres of the
origin the plane's distortion is far below GPS noise.

A columnar log holds many tracks as flat columns, so both directions take one
origin *per row* (or one for all rows) and run as one numba kernel over all
rows (``prange`` over blocks of rows; the sine, cosine and radius of curvature
of an origin are computed once per run of equal origins, i.e. once per track).

Method (the formulas are derived in the docstrings of :func:`geodetic_to_enu`
and :func:`enu_to_geodetic`): closed forms written in differences of the
coordinates (lat - lat0, lon - lon0, sin lat - sin lat0, N - N0), so no two
Earth-sized numbers (ECEF coordinates, ~6.4e6 m) are ever subtracted.  The
results are exact to round-off: east/north to ~1e-10 m within 100 km of the
origin, where the textbook ECEF difference (pymap3d) carries ~4e-9 m; the
inverse to the rounding of the degrees it returns (half a unit in the last
place of a longitude near 180 degrees is 1.6e-9 m at the equator: the floor of
any ENU -> degrees -> ENU round trip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.validation import LATITUDE, LONGITUDE, as_array, broadcast_shape
from ..errors import ParameterError

__all__ = ["LocalFrame", "geodetic_to_enu", "enu_to_geodetic"]

# WGS-84 defining parameters (NIMA TR8350.2, 3rd ed., 2000, Table 3.1): semi-major axis a (m)
# and flattening f; e2 is the first eccentricity squared, ep2 the second.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)
_EP2 = _E2 / (1.0 - _E2)
_RAD = math.pi / 180.0           # radians per degree
_DEG = 180.0 / math.pi           # degrees per radian

# Valid ranges, as keyword arguments of mptrack._core.validation.as_array (and LATITUDE, LONGITUDE from there).
_METRES = dict(unit="m")
#: east/north of enu_to_geodetic: their squares must stay finite (points that far miss the ellipsoid anyway)
_PLANE = dict(low=-1e150, high=1e150, unit="m")

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
def _origin_terms(lat0):
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
def _enu_row(lat, lon, lat0, lon0, h, s0, c0, w0):
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
def _geodetic_row(east, north, lat0, lon0, s0, c0, w0):
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
            s0, c0, w0 = _origin_terms(phi0)
            last = phi0
        east[i], north[i] = _enu_row(lat[i * k_lat], lon[i * k_lon], phi0, lon0[i * k_lon0],
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
            s0, c0, w0 = _origin_terms(phi0)
            last = phi0
        lat[i], lon[i] = _geodetic_row(east[i * k_e], north[i * k_n], phi0, lon0[i * k_lon0], s0, c0, w0)
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


# ---- the public boundary --------------------------------------------------------------------------

def _columns(**named) -> tuple[tuple, list[np.ndarray]]:
    """Validate the named ``(value, bounds)`` arguments; return their broadcast shape and one flat
    float64 column per argument, of one value per row or a single value for all rows."""
    arrays = {name: as_array(name, value, **bounds) for name, (value, bounds) in named.items()}
    shape = broadcast_shape(**arrays)
    return shape, [_column(arr, shape) for arr in arrays.values()]


def _column(arr: np.ndarray, shape: tuple) -> np.ndarray:
    if arr.size == 1:
        return arr.reshape(1)
    if arr.shape != shape:
        arr = np.broadcast_to(arr, shape)
    return arr.ravel()


def _run(rows_kernel, parallel_kernel, columns: list[np.ndarray], outputs: list[np.ndarray]) -> int:
    n = outputs[0].size
    if n < _SERIAL_ROWS:
        return int(rows_kernel(*columns, *outputs, 0, n))
    return int(parallel_kernel(*columns, *outputs))


def _shaped(column: np.ndarray, shape: tuple):
    """The output column in the broadcast shape; a NumPy scalar for scalar inputs (as a ufunc)."""
    return column.reshape(shape) if shape else column[0]


def geodetic_to_enu(lat, lon, lat0, lon0, h=0.0, h0=0.0):
    """East and north (m) of WGS-84 points in the local frames at (lat0, lon0).

    Parameters
    ----------
    lat, lon : latitude in [-90, 90] and longitude in [-180, 180] of the points, degrees.
    lat0, lon0 : the frame origins, degrees; one per point or one for all.
    h : height of the points above the ellipsoid, metres.
    h0 : height of the origins, metres.  East and north do not depend on it (the
        origin moves along its own up axis, which is orthogonal to both); it is
        validated and accepted for the argument order of ``pymap3d.geodetic2enu``.

    All arguments broadcast (NumPy rules); the result has the broadcast shape
    (NumPy scalars for scalar inputs).  Raises the :mod:`mptrack.errors` error that
    names the argument for a non-finite value, a value out of range or shapes that
    do not broadcast.

    Method.  The geodetic -> ECEF map of any geodesy text (e.g. Hofmann-Wellenhof,
    Lichtenegger and Wasle, *GNSS*, Springer 2008) is
    ``P = ((N + h) cos(lat) cos(lon), (N + h) cos(lat) sin(lon), (N (1 - e2) + h) sin(lat))``
    with ``N = a / sqrt(1 - e2 sin^2(lat))``, and east, north are the projections of
    ``P - P0`` on the origin's unit vectors ``(-sin lon0, cos lon0, 0)`` and
    ``(-sin lat0 cos lon0, -sin lat0 sin lon0, cos lat0)``.  Expanding the
    projections and using that both vectors are orthogonal to the origin's normal
    gives, with ``dlon = lon - lon0``,

    * ``east = (N + h) cos(lat) sin(dlon)``
    * ``north = (N + h) [sin(lat - lat0) + 2 sin(lat0) cos(lat) sin^2(dlon/2)]
      - e2 cos(lat0) [(N - N0) sin(lat) + N0 (sin(lat) - sin(lat0))]``

    where ``sin(lat) - sin(lat0)`` and ``N - N0`` are evaluated from
    ``sin(lat - lat0)`` and ``sin((lat - lat0)/2)`` without cancellation.  The
    textbook route subtracts ECEF coordinates of ~6.4e6 m and so carries ~1e-9 m
    of round-off; this one is ~1e-10 m at 100 km (tested against an 80-bit
    evaluation of the textbook route and against pymap3d).
    """
    shape, columns = _columns(lat=(lat, LATITUDE), lon=(lon, LONGITUDE), lat0=(lat0, LATITUDE),
                              lon0=(lon0, LONGITUDE), h=(h, _METRES), h0=(h0, _METRES))
    size = math.prod(shape)
    east, north = np.empty(size), np.empty(size)
    _run(_enu_rows, _enu_parallel, columns[:5], [east, north])
    return _shaped(east, shape), _shaped(north, shape)


def enu_to_geodetic(east, north, lat0, lon0, h0=0.0):
    """Latitude and longitude of the points on the WGS-84 ellipsoid (h = 0) whose local east/north
    coordinates are given.

    The exact inverse of :func:`geodetic_to_enu` with ``h = 0``: a point of the tangent plane lies above
    the ellipsoid (about 31 m at 20 km), and the point returned is the one below it along the origin's
    up axis.  Closed form, no iteration: the line-ellipsoid intersection in the origin's meridian plane,
    then the exact latitude on the ellipsoid, with the Earth-sized terms cancelled analytically.

    Parameters
    ----------
    east, north : array_like
        Local coordinates (m).
    lat0, lon0 : float or array_like
        The frames' origins (degrees), one per point or one for all (broadcast).
    h0 : float or array_like, optional
        The origins' heights (m); they do not change the result and are accepted for the argument order
        of ``pymap3d.enu2geodetic``.

    Returns
    -------
    lat, lon : ndarray
        Degrees.

    Raises
    ------
    ParameterError
        A point so far away (thousands of km) that the vertical misses the ellipsoid, or coordinates out
        of range.
    """
    shape, columns = _columns(east=(east, _PLANE), north=(north, _PLANE), lat0=(lat0, LATITUDE),
                              lon0=(lon0, LONGITUDE), h0=(h0, _METRES))
    size = math.prod(shape)
    lat, lon = np.empty(size), np.empty(size)
    if _run(_geodetic_rows, _geodetic_parallel, columns[:4], [lat, lon]):
        index = np.unravel_index(int(np.flatnonzero(np.isnan(lat))[0]), shape) if shape else ()
        raise ParameterError(f"east, north: the point at index {tuple(int(i) for i in index)} is too far "
                             f"from its origin: the vertical through it misses the ellipsoid")
    return _shaped(lat, shape), _shaped(lon, shape)


def enu_columns(lat: np.ndarray, lon: np.ndarray, lat0: np.ndarray, lon0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`geodetic_to_enu` (h = 0) of float64 columns of one length that the caller has checked
    (finite, in range): east, north.  For hot paths of a few rows, where the checks and the
    broadcasting cost more than the conversion."""
    east, north = np.empty(lat.size), np.empty(lat.size)
    _run(_enu_rows, _enu_parallel, [lat, lon, lat0, lon0, _NO_HEIGHT], [east, north])
    return east, north


def geodetic_columns(east: np.ndarray, north: np.ndarray, lat0: np.ndarray,
                     lon0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`enu_to_geodetic` of float64 columns of one length that the caller has checked: lat, lon,
    NaN where a point is so far from its origin that the vertical misses the ellipsoid."""
    lat, lon = np.empty(east.size), np.empty(east.size)
    _run(_geodetic_rows, _geodetic_parallel, [east, north, lat0, lon0], [lat, lon])
    return lat, lon


_NO_HEIGHT = np.zeros(1)


@dataclass(frozen=True)
class LocalFrame:
    """A local ENU frame at geodetic origin (lat0, lon0 in degrees, h0 in metres).

    A convenience for one origin; :func:`geodetic_to_enu` and :func:`enu_to_geodetic`
    take one origin per row.
    """

    lat0: float
    lon0: float
    h0: float = 0.0

    def __post_init__(self) -> None:
        as_array("lat0", self.lat0, ndim=0, **LATITUDE)
        as_array("lon0", self.lon0, ndim=0, **LONGITUDE)
        as_array("h0", self.h0, ndim=0, **_METRES)

    @classmethod
    def at(cls, lat, lon) -> "LocalFrame":
        """The frame at the first of the given points."""
        return cls(float(np.asarray(lat).flat[0]), float(np.asarray(lon).flat[0]))

    def to_enu(self, lat, lon, h=0.0) -> tuple[np.ndarray, np.ndarray]:
        """East, north (m) of WGS-84 points (degrees; h metres above the ellipsoid)."""
        east, north = geodetic_to_enu(lat, lon, self.lat0, self.lon0, h=h, h0=self.h0)
        return np.asarray(east, dtype=float), np.asarray(north, dtype=float)

    def to_geodetic(self, east, north) -> tuple[np.ndarray, np.ndarray]:
        """WGS-84 latitude, longitude (degrees) of the points on the ellipsoid (h = 0) whose local
        east/north coordinates are ``east``, ``north`` (m): the exact inverse of :meth:`to_enu`
        (see :func:`enu_to_geodetic`)."""
        lat, lon = enu_to_geodetic(east, north, self.lat0, self.lon0, h0=self.h0)
        return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
