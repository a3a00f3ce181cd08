"""WGS-84 <-> local East-North-Up coordinates, per track, through pymap3d.

Each track is filtered in its own tangent plane: the origin is the track's
first fix (or the centroid of its cells for cellular logs), at height 0 on the
WGS-84 ellipsoid.  East/north are in metres; within a few tens of kilometres of
the origin the plane's distortion is far below GPS noise.

The inverse (local east/north -> the point on the ellipsoid below it) is in
closed form, :func:`enu_to_surface`, and broadcasts over per-point origins, so
many tracks, each in its own frame, convert in one call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_array
from ..errors import ParameterError

__all__ = ["LocalFrame", "enu_to_surface"]

_A = 6378137.0                       # WGS-84 semi-major axis (m), as pymap3d
_F = 1.0 / 298.257223563             # WGS-84 flattening
_E2 = _F * (2.0 - _F)                # first eccentricity squared
_D = (1.0 / _A ** 2, 1.0 / _A ** 2, 1.0 / (_A * (1.0 - _F)) ** 2)  # x'Dx = 1 on the ellipsoid


def enu_to_surface(east, north, lat0, lon0, h0=0.0) -> tuple[np.ndarray, np.ndarray]:
    """WGS-84 latitude, longitude (degrees) of the points on the ellipsoid whose east/north coordinates
    (m) in the ENU frame at (lat0, lon0, h0) are ``east``, ``north``.

    The point is where the frame's vertical through (east, north, 0) meets the
    ellipsoid: with C = P0 + east E + north N (ECEF) and U the frame's up vector,
    the root u near 0 of (C + u U)' D (C + u U) = 1 (D = diag(1/a^2, 1/a^2, 1/b^2)),
    then latitude = atan2(z, (1 - e^2) p) (exact on the ellipsoid), longitude =
    atan2(y, x).  Closed form, so it is the exact inverse of :meth:`LocalFrame.to_enu`
    (h = 0) to round-off; all arguments broadcast (one origin per point is fine).
    """
    e, n, h0 = np.broadcast_arrays(np.asarray(east, float), np.asarray(north, float), np.asarray(h0, float))
    phi, lam = np.radians(lat0), np.radians(lon0)
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    nu = _A / np.sqrt(1.0 - _E2 * sp ** 2)
    p0 = ((nu + h0) * cp * cl, (nu + h0) * cp * sl, (nu * (1.0 - _E2) + h0) * sp)  # origin (ECEF)
    up = (cp * cl, cp * sl, sp)
    d = (-sl * e - sp * cl * n, cl * e - sp * sl * n, cp * n)                      # east E + north N

    def dot(x, y):
        return x[0] * y[0] * _D[0] + x[1] * y[1] * _D[1] + x[2] * y[2] * _D[2]

    # (p0 + d + u up)' D (...) - 1 = a u^2 + b u + c; c from the small offsets, not from |C|^2 - 1
    a = dot(up, up)
    b = 2.0 * (dot(p0, up) + dot(d, up))
    c = (dot(p0, p0) - 1.0) + 2.0 * dot(p0, d) + dot(d, d)
    u = -2.0 * c / (b + np.sqrt(b * b - 4.0 * a * c))  # the root near 0, without cancellation
    x, y, z = (p0[i] + d[i] + u * up[i] for i in range(3))
    lat = np.degrees(np.arctan2(z, (1.0 - _E2) * np.hypot(x, y)))
    return lat, np.degrees(np.arctan2(y, x))


@dataclass(frozen=True)
class LocalFrame:
    """A local ENU frame at geodetic origin (lat0, lon0 in degrees, h0 in metres)."""

    lat0: float
    lon0: float
    h0: float = 0.0

    def __post_init__(self) -> None:
        if not (-90.0 <= self.lat0 <= 90.0) or not (-180.0 <= self.lon0 <= 180.0):
            raise ParameterError(f"origin: expected lat in [-90, 90] and lon in [-180, 180] degrees, "
                                 f"got ({self.lat0}, {self.lon0})")

    @classmethod
    def at(cls, lat, lon) -> "LocalFrame":
        """The frame at the first of the given points."""
        return cls(float(np.asarray(lat).flat[0]), float(np.asarray(lon).flat[0]))

    def to_enu(self, lat, lon, h=0.0) -> tuple[np.ndarray, np.ndarray]:
        """East, north (m) of WGS-84 points (degrees; h metres above the ellipsoid)."""
        import pymap3d

        lat = as_array("lat", lat)
        lon = as_array("lon", lon)
        e, n, _ = pymap3d.geodetic2enu(lat, lon, np.broadcast_to(h, lat.shape), self.lat0, self.lon0, self.h0)
        return np.asarray(e, dtype=float), np.asarray(n, dtype=float)

    def to_geodetic(self, east, north) -> tuple[np.ndarray, np.ndarray]:
        """WGS-84 latitude, longitude (degrees) of the points on the ellipsoid (h = 0) whose local
        east/north coordinates are ``east``, ``north`` (m): the exact inverse of :meth:`to_enu`
        (closed form, :func:`enu_to_surface`)."""
        east = as_array("east", east)
        north = as_array("north", north)
        return enu_to_surface(east, north, self.lat0, self.lon0, self.h0)
