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

import numpy as np

from .._core.geodesy import _enu_parallel, _enu_rows, _geodetic_parallel, _geodetic_rows, _run
from .._core.validation import LATITUDE, LONGITUDE, as_array, broadcast_shape
from ..errors import ParameterError

__all__ = ["LocalFrame", "geodetic_to_enu", "enu_to_geodetic"]

# Valid ranges, as keyword arguments of mptrack._core.validation.as_array (and LATITUDE, LONGITUDE from there).
_METRES = dict(unit="m")
#: east/north of enu_to_geodetic: their squares must stay finite (points that far miss the ellipsoid anyway)
_PLANE = dict(low=-1e150, high=1e150, unit="m")


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
