"""WGS-84 <-> local East-North-Up coordinates, per track, through pymap3d.

Each track is filtered in its own tangent plane: the origin is the track's
first fix (or the centroid of its cells for cellular logs), at height 0 on the
WGS-84 ellipsoid.  East/north are in metres; within a few tens of kilometres of
the origin the plane's distortion is far below GPS noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_array
from ..errors import ParameterError

__all__ = ["LocalFrame"]


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
        east/north coordinates are ``east``, ``north`` (m): the exact inverse of :meth:`to_enu`.

        A point of the tangent plane lies above the ellipsoid (~31 m at 20 km); its
        surface point is found by iterating on the up coordinate (three passes
        reach round-off within 100 km).
        """
        import pymap3d

        east = as_array("east", east)
        north = as_array("north", north)
        up = np.zeros_like(east)
        for _ in range(3):
            lat, lon, _h = pymap3d.enu2geodetic(east, north, up, self.lat0, self.lon0, self.h0)
            _e, _n, up = pymap3d.geodetic2enu(lat, lon, np.zeros_like(east), self.lat0, self.lon0, self.h0)
        lat, lon, _h = pymap3d.enu2geodetic(east, north, up, self.lat0, self.lon0, self.h0)
        return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)


def geodetic_to_enu(lat, lon, lat0, lon0, h=0.0, h0=0.0):  # TEMPORARY: replaced by the compiled version
    import pymap3d

    e, n, _ = pymap3d.geodetic2enu(np.asarray(lat, float), np.asarray(lon, float), h, np.asarray(lat0, float),
                                   np.asarray(lon0, float), h0)
    return np.asarray(e, dtype=float), np.asarray(n, dtype=float)


def enu_to_geodetic(east, north, lat0, lon0, h0=0.0):  # TEMPORARY
    import pymap3d

    east, north = np.asarray(east, float), np.asarray(north, float)
    lat0, lon0 = np.asarray(lat0, float), np.asarray(lon0, float)
    up = np.zeros_like(east)
    for _ in range(3):
        lat, lon, _h = pymap3d.enu2geodetic(east, north, up, lat0, lon0, h0)
        _e, _n, up = pymap3d.geodetic2enu(lat, lon, np.zeros_like(east), lat0, lon0, h0)
    lat, lon, _h = pymap3d.enu2geodetic(east, north, up, lat0, lon0, h0)
    return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
