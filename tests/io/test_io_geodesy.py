"""WGS-84 <-> local ENU: the compiled closed forms against pymap3d (the independent oracle),
against an 80-bit evaluation of the textbook ECEF route, against the WGS-84 radii of
curvature; round trips; per-row origins; broadcasting; validation at the boundary."""

from __future__ import annotations

import ast
import dataclasses
import re
from pathlib import Path

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import DTypeError, MptrackError, NonFiniteError, ParameterError, ShapeError
from mptrack.io import LocalFrame, enu_to_geodetic, geodetic_to_enu

A, F = 6378137.0, 1 / 298.257223563
E2 = F * (2 - F)
RADIUS = 6.4e6                      # m, above every radius of curvature of WGS-84
KM100 = 1e5

# Tolerances (metres of ground; degrees converted with RADIUS).
TOL_REFERENCE = 2e-10               # against the 80-bit textbook route: our round-off
TOL_PYMAP3D = 1e-8                  # against pymap3d, whose ECEF differences carry ~4e-9 m
TOL_PYMAP3D_DEG = 2e-13             # the same in degrees (2e-13 deg = 2.2e-8 m)


# ---- helpers ---------------------------------------------------------------------------------------

def points_around(lat0, lon0, east, north):
    """Latitude, longitude of the points at (east, north) of the origins, by pymap3d (h = 0 at
    the tangent-plane point), so the inputs of the forward tests do not come from the code
    under test."""
    lat, lon, _ = pymap3d.enu2geodetic(east, north, 0.0, lat0, lon0, 0.0)
    return np.asarray(lat, float), np.asarray(lon, float)


def pymap3d_surface_point(east, north, lat0, lon0):
    """The point on the ellipsoid with the given east/north, by pymap3d alone: fixed-point
    iteration on the up coordinate (the contraction factor is (d/R)^2, so six passes reach
    round-off far beyond 100 km)."""
    up = np.zeros_like(np.asarray(east, float))
    for _ in range(6):
        lat, lon, _ = pymap3d.enu2geodetic(east, north, up, lat0, lon0, 0.0)
        _, _, up = pymap3d.geodetic2enu(lat, lon, 0.0, lat0, lon0, 0.0)
    lat, lon, _ = pymap3d.enu2geodetic(east, north, up, lat0, lon0, 0.0)
    return np.asarray(lat, float), np.asarray(lon, float)


def degree_error(lat, lon, lat_ref, lon_ref):
    """Latitude error and longitude error along the parallel (times cos lat), in degrees;
    longitudes compared modulo 360 (at a pole the longitude itself is arbitrary)."""
    dlon = (np.asarray(lon) - lon_ref + 180.0) % 360.0 - 180.0
    return np.abs(np.asarray(lat) - lat_ref), np.abs(dlon) * np.cos(np.radians(lat_ref))


def rounding_metres(lat, lon, lat0, lon0):
    """Ground distance (m) of half a unit in the last place of the degrees returned by the
    inverse (lat0 + dlat, lon0 + dlon): the floor of any ENU -> degrees -> ENU round trip."""
    half_lat = np.spacing(np.maximum(np.abs(lat), np.abs(lat0))) / 2
    half_lon = np.spacing(np.maximum(np.abs(lon), np.abs(lon0))) / 2
    return RADIUS * np.radians(half_lat + half_lon * np.cos(np.radians(lat)))


def enu_long_double(lat, lon, lat0, lon0, h=0.0):
    """The textbook route (ECEF difference rotated into ENU) in 80-bit extended precision."""
    ld = np.longdouble
    rad = ld("3.14159265358979323846264338327950288") / 180

    def ecef(la, lo, hh):
        la, lo = np.asarray(la, ld) * rad, np.asarray(lo, ld) * rad
        n = ld(A) / np.sqrt(1 - ld(E2) * np.sin(la) ** 2)
        r = (n + hh) * np.cos(la)
        return r * np.cos(lo), r * np.sin(lo), (n * (1 - ld(E2)) + hh) * np.sin(la)

    x, y, z = ecef(lat, lon, np.asarray(h, ld))
    x0, y0, z0 = ecef(lat0, lon0, ld(0))
    la0, lo0 = np.asarray(lat0, ld) * rad, np.asarray(lon0, ld) * rad
    dx, dy, dz = x - x0, y - y0, z - z0
    east = -np.sin(lo0) * dx + np.cos(lo0) * dy
    north = -np.sin(la0) * (np.cos(lo0) * dx + np.sin(lo0) * dy) + np.cos(la0) * dz
    return east.astype(float), north.astype(float)


needs_long_double = pytest.mark.skipif(np.finfo(np.longdouble).eps > 1e-18,
                                       reason="long double is not extended precision here")


def worldwide(n, seed):
    """Origins anywhere (a quarter near the poles, a quarter at the antimeridian) and offsets
    up to 100 km in each axis."""
    rng = np.random.default_rng(seed)
    lat0 = rng.uniform(-90.0, 90.0, n)
    lon0 = rng.uniform(-180.0, 180.0, n)
    q = n // 4
    lat0[:q] = rng.choice([-1.0, 1.0], q) * (90.0 - rng.uniform(0.0, 1.0, q) ** 3)
    lon0[q:2 * q] = rng.choice([-1.0, 1.0], q) * (180.0 - rng.uniform(0.0, 0.5, q) ** 3)
    lat0[:3], lon0[3:6] = [90.0, -90.0, 90.0], [180.0, -180.0, 180.0]
    east, north = rng.uniform(-KM100, KM100, (2, n))
    return lat0, lon0, east, north


origins = dict(lat0=st.floats(-90.0, 90.0), lon0=st.floats(-180.0, 180.0))
offsets = dict(east=st.floats(-KM100, KM100), north=st.floats(-KM100, KM100))


# ---- geodetic -> ENU -------------------------------------------------------------------------------

@needs_long_double
def test_forward_is_exact_to_round_off():
    """Against the textbook route in 80-bit arithmetic: ~1e-10 m, where float64 ECEF
    differences (pymap3d) carry ~4e-9 m."""
    lat0, lon0, east, north = worldwide(40_000, seed=1)
    lat, lon = points_around(lat0, lon0, east, north)
    h = np.random.default_rng(2).uniform(-500.0, 9000.0, lat.size)
    e, n = geodetic_to_enu(lat, lon, lat0, lon0, h=h)
    e_ref, n_ref = enu_long_double(lat, lon, lat0, lon0, h)
    assert np.max(np.abs(e - e_ref)) <= TOL_REFERENCE
    assert np.max(np.abs(n - n_ref)) <= TOL_REFERENCE


def test_forward_matches_pymap3d_worldwide():
    lat0, lon0, east, north = worldwide(40_000, seed=3)
    lat, lon = points_around(lat0, lon0, east, north)
    h = np.random.default_rng(4).uniform(-500.0, 9000.0, lat.size)
    h0 = np.random.default_rng(5).uniform(-500.0, 9000.0, lat.size)
    e, n = geodetic_to_enu(lat, lon, lat0, lon0, h=h, h0=h0)
    e_ref, n_ref, _ = pymap3d.geodetic2enu(lat, lon, h, lat0, lon0, h0)
    assert np.max(np.abs(e - e_ref)) <= TOL_PYMAP3D
    assert np.max(np.abs(n - n_ref)) <= TOL_PYMAP3D


@settings(max_examples=200, deadline=None)
@given(**origins, **offsets, h=st.floats(-500.0, 9000.0), h0=st.floats(-500.0, 9000.0))
def test_forward_matches_pymap3d(lat0, lon0, east, north, h, h0):
    lat, lon = points_around(lat0, lon0, east, north)
    e, n = geodetic_to_enu(lat, lon, lat0, lon0, h=h, h0=h0)
    e_ref, n_ref, _ = pymap3d.geodetic2enu(lat, lon, h, lat0, lon0, h0)
    assert abs(e - e_ref) <= TOL_PYMAP3D and abs(n - n_ref) <= TOL_PYMAP3D


@pytest.mark.parametrize("lat0", [0.0, 45.0, -60.0, 89.0])
def test_forward_against_the_radii_of_curvature(lat0):
    """Along the meridian, north is the meridian radius at the mid-latitude times the angle
    (relative error ~dlat^2/6, 5e-13 for 1e-4 deg); along the parallel, east is
    N cos(lat) sin(dlon) exactly."""
    lat = lat0 + 1e-4
    phi, dphi = np.radians(lat0), np.radians(lat - lat0)     # the difference actually represented
    meridian_radius = A * (1 - E2) / (1 - E2 * np.sin(phi + dphi / 2) ** 2) ** 1.5
    e, n = geodetic_to_enu(lat, 13.0, lat0, 13.0)
    assert abs(e) <= 1e-12
    assert n == pytest.approx(meridian_radius * dphi, rel=2e-11)
    lon = 13.0 + 1e-3
    normal_radius = A / np.sqrt(1 - E2 * np.sin(phi) ** 2)
    e, _ = geodetic_to_enu(lat0, lon, lat0, 13.0)
    assert e == pytest.approx(normal_radius * np.cos(phi) * np.sin(np.radians(lon - 13.0)), rel=1e-13)


def test_forward_across_the_antimeridian_and_the_pole():
    """A point 0.0002 deg east across the antimeridian is ~22 m east, not 40,000 km west; a point
    just across the pole is north of the origin."""
    e, n = geodetic_to_enu(0.0, -179.9999, 0.0, 179.9999)
    e_ref, _ = geodetic_to_enu(0.0, 0.0001, 0.0, -0.0001)
    assert e == pytest.approx(e_ref, abs=5e-9) and abs(n) <= 1e-9    # 5e-9: the ulps of 179.9999
    e, n = geodetic_to_enu(89.9, 180.0, 89.9, 0.0)
    assert abs(e) <= 1e-9 and n == pytest.approx(22_338.0, abs=10.0)   # 2 x 0.1 deg of meridian


# ---- ENU -> geodetic -------------------------------------------------------------------------------

def test_inverse_matches_pymap3d_worldwide():
    lat0, lon0, east, north = worldwide(20_000, seed=6)
    lat, lon = enu_to_geodetic(east, north, lat0, lon0)
    lat_ref, lon_ref = pymap3d_surface_point(east, north, lat0, lon0)
    dlat, dlon = degree_error(lat, lon, lat_ref, lon_ref)
    assert dlat.max() <= TOL_PYMAP3D_DEG and dlon.max() <= TOL_PYMAP3D_DEG


@settings(max_examples=100, deadline=None)
@given(**origins, **offsets)
def test_inverse_matches_pymap3d(lat0, lon0, east, north):
    lat, lon = enu_to_geodetic(east, north, lat0, lon0)
    lat_ref, lon_ref = pymap3d_surface_point(east, north, lat0, lon0)
    dlat, dlon = degree_error(lat, lon, lat_ref, lon_ref)
    assert dlat <= TOL_PYMAP3D_DEG and dlon <= TOL_PYMAP3D_DEG


def test_inverse_returns_the_point_on_the_ellipsoid_below_the_plane():
    """20 km east of the origin the tangent plane is ~31 m above the ellipsoid: pymap3d puts
    the returned point at the same east/north, 31 m below the plane."""
    lat, lon = enu_to_geodetic(20e3, 0.0, 45.0, 13.0)
    e, n, u = pymap3d.geodetic2enu(lat, lon, 0.0, 45.0, 13.0, 0.0)
    assert e == pytest.approx(20e3, abs=TOL_PYMAP3D) and abs(n) <= TOL_PYMAP3D
    normal_radius = A / np.sqrt(1 - E2 * np.sin(np.radians(45.0)) ** 2)
    assert u == pytest.approx(-20e3 ** 2 / (2 * normal_radius), rel=1e-3)


def test_round_trip_enu_geodetic_enu():
    """ENU -> degrees -> ENU returns the input to round-off: 2e-10 m plus the rounding of the
    degrees themselves (up to 1.6e-9 m for a longitude near 180 at the equator)."""
    lat0, lon0, east, north = worldwide(100_000, seed=7)
    lat, lon = enu_to_geodetic(east, north, lat0, lon0)
    e, n = geodetic_to_enu(lat, lon, lat0, lon0)
    bound = TOL_REFERENCE + rounding_metres(lat, lon, lat0, lon0)
    assert np.all(np.abs(e - east) <= bound) and np.all(np.abs(n - north) <= bound)
    inside = (np.abs(lat0) < 60) & (np.abs(lon0) < 62)   # |lat|, |lon| < 64: half an ulp is 0.4e-9 m
    assert np.max(np.abs(e - east)[inside]) <= 1e-9 and np.max(np.abs(n - north)[inside]) <= 1e-9


@settings(max_examples=200, deadline=None)
@given(**origins, **offsets)
def test_round_trip_property(lat0, lon0, east, north):
    lat, lon = enu_to_geodetic(east, north, lat0, lon0)
    e, n = geodetic_to_enu(lat, lon, lat0, lon0)
    bound = TOL_REFERENCE + rounding_metres(lat, lon, lat0, lon0)
    assert abs(e - east) <= bound and abs(n - north) <= bound


def test_round_trip_geodetic_enu_geodetic():
    lat0, lon0, east, north = worldwide(40_000, seed=8)
    lat, lon = points_around(lat0, lon0, east, north)
    back_lat, back_lon = enu_to_geodetic(*geodetic_to_enu(lat, lon, lat0, lon0), lat0, lon0)
    dlat, dlon = degree_error(back_lat, back_lon, lat, lon)
    bound = np.degrees((TOL_REFERENCE + rounding_metres(lat, lon, lat0, lon0)) / RADIUS) * 2
    assert np.all(dlat <= bound) and np.all(dlon <= bound)


# ---- per-row origins, shapes, paths ----------------------------------------------------------------

def test_per_row_origins_equal_per_origin_calls():
    """25 tracks x 1000 rows in one call (the parallel path) give bit for bit what one call
    per track gives (the serial path), and what one scalar call per row gives."""
    rng = np.random.default_rng(9)
    tracks, length = 25, 1000
    lat0 = np.repeat(rng.uniform(-89.0, 89.0, tracks), length)
    lon0 = np.repeat(rng.uniform(-180.0, 180.0, tracks), length)
    east, north = rng.uniform(-KM100, KM100, (2, tracks * length))
    lat, lon = enu_to_geodetic(east, north, lat0, lon0)
    e, n = geodetic_to_enu(lat, lon, lat0, lon0)
    for b in range(tracks):
        rows = slice(b * length, (b + 1) * length)
        one_lat, one_lon = enu_to_geodetic(east[rows], north[rows], lat0[rows][0], lon0[rows][0])
        np.testing.assert_array_equal(one_lat, lat[rows])
        np.testing.assert_array_equal(one_lon, lon[rows])
        one_e, one_n = geodetic_to_enu(lat[rows], lon[rows], lat0[rows][0], lon0[rows][0])
        np.testing.assert_array_equal(one_e, e[rows])
        np.testing.assert_array_equal(one_n, n[rows])
    for i in rng.choice(lat.size, 50, replace=False):
        assert enu_to_geodetic(east[i], north[i], lat0[i], lon0[i]) == (lat[i], lon[i])
        assert geodetic_to_enu(lat[i], lon[i], lat0[i], lon0[i]) == (e[i], n[i])


def test_scalars_give_numpy_scalars_and_arrays_keep_their_shape():
    e, n = geodetic_to_enu(45.001, 13.001, 45.0, 13.0)
    assert isinstance(e, np.float64) and isinstance(n, np.float64)
    lat, lon = enu_to_geodetic(100.0, 200.0, 45.0, 13.0)
    assert isinstance(lat, np.float64) and isinstance(lon, np.float64)
    grid_lat = 45.0 + np.linspace(0, 0.1, 12).reshape(3, 4)
    e2d, n2d = geodetic_to_enu(grid_lat, 13.0, 45.0, 13.0)
    assert e2d.shape == n2d.shape == (3, 4)
    np.testing.assert_array_equal(n2d.ravel(), geodetic_to_enu(grid_lat.ravel(), 13.0, 45.0, 13.0)[1])
    assert geodetic_to_enu([], [], 45.0, 13.0)[0].shape == (0,)


def test_general_broadcasting_equals_elementwise_calls():
    lat = 45.0 + np.array([0.0, 0.01, 0.02])[:, None]        # (3, 1)
    lon0 = 13.0 + np.array([0.0, 0.1, -0.1, 0.2])[None, :]   # (1, 4)
    e, n = geodetic_to_enu(lat, 13.05, 45.0, lon0)
    assert e.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            assert (e[i, j], n[i, j]) == geodetic_to_enu(lat[i, 0], 13.05, 45.0, lon0[0, j])


# ---- LocalFrame ------------------------------------------------------------------------------------

def test_local_frame_delegates_and_keeps_its_behaviour():
    frame = LocalFrame(45.0, 13.0)
    e, n = frame.to_enu([45.0005], [13.0])
    assert isinstance(e, np.ndarray) and e.shape == (1,)
    assert (e[0], n[0]) == geodetic_to_enu(45.0005, 13.0, 45.0, 13.0)
    lat, lon = frame.to_geodetic(np.array([100.0, -50.0]), np.array([20.0, 0.0]))
    np.testing.assert_array_equal(lat, enu_to_geodetic(np.array([100.0, -50.0]), np.array([20.0, 0.0]),
                                                       45.0, 13.0)[0])
    assert np.asarray(frame.to_enu(45.0, 13.0)[0]).shape == ()
    with pytest.raises(dataclasses.FrozenInstanceError):
        frame.lat0 = 46.0


def test_the_origin_height_does_not_move_east_north():
    """The origin's height moves it along its own up axis, orthogonal to east and north."""
    low, high = LocalFrame(45.0, 13.0), LocalFrame(45.0, 13.0, h0=2500.0)
    e, n = high.to_enu(45.2, 13.1)
    assert (e, n) == low.to_enu(45.2, 13.1)
    e_ref, n_ref, _ = pymap3d.geodetic2enu(45.2, 13.1, 0.0, 45.0, 13.0, 2500.0)
    assert abs(e - e_ref) <= TOL_PYMAP3D and abs(n - n_ref) <= TOL_PYMAP3D
    assert high.to_geodetic(1e3, 2e3) == low.to_geodetic(1e3, 2e3)


@settings(max_examples=40, deadline=None)
@given(**origins, **offsets)
def test_local_frame_round_trip(lat0, lon0, east, north):
    frame = LocalFrame(lat0, lon0)
    lat, lon = frame.to_geodetic([east], [north])
    e, n = frame.to_enu(lat, lon)
    bound = TOL_REFERENCE + rounding_metres(lat, lon, lat0, lon0)
    assert abs(e[0] - east) <= bound[0] and abs(n[0] - north) <= bound[0]


# ---- validation at the boundary --------------------------------------------------------------------

def check_raises(cls, name, fn, *args, **kwargs):
    """``fn`` raises ``cls`` (an mptrack error) naming ``name``, from mptrack's own code."""
    with pytest.raises(cls, match=rf"(?<!\w){re.escape(name)}(?!\w)") as info:
        fn(*args, **kwargs)
    assert isinstance(info.value, MptrackError)
    assert "mptrack" in str(info.traceback[-1].path), "raised from outside mptrack"
    return info.value


FORWARD = dict(lat=np.array([45.0, 45.1, 45.2]), lon=np.array([13.0, 13.1, 13.2]), lat0=45.0, lon0=13.0,
               h=0.0, h0=0.0)
INVERSE = dict(east=np.array([0.0, 10.0, 20.0]), north=np.array([0.0, 5.0, 9.0]), lat0=45.0, lon0=13.0,
               h0=0.0)
ARGUMENTS = [(geodetic_to_enu, FORWARD, name) for name in FORWARD] + \
            [(enu_to_geodetic, INVERSE, name) for name in INVERSE]
IDS = [f"{fn.__name__}-{name}" for fn, _, name in ARGUMENTS]
RANGES = {"lat": 90.0, "lat0": 90.0, "lon": 180.0, "lon0": 180.0}


def _with(kwargs, name, bad_value, at=1):
    """The arguments with one value of ``name`` replaced (an array keeps its other values)."""
    value = np.array(kwargs[name], dtype=float)
    if value.ndim:
        value[at] = bad_value
    else:
        value = np.float64(bad_value)
    return {**kwargs, name: value}


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize(("fn", "kwargs", "name"), ARGUMENTS, ids=IDS)
def test_non_finite_values_are_refused(fn, kwargs, name, bad):
    err = check_raises(NonFiniteError, name, fn, **_with(kwargs, name, bad))
    assert isinstance(err, ValueError)
    if np.ndim(kwargs[name]):
        assert "at index (1,)" in str(err)


@pytest.mark.parametrize(("fn", "kwargs", "name"), [a for a in ARGUMENTS if a[2] in RANGES],
                         ids=[i for i, a in zip(IDS, ARGUMENTS) if a[2] in RANGES])
def test_out_of_range_coordinates_are_refused(fn, kwargs, name):
    limit = RANGES[name]
    for bad in (np.nextafter(limit, np.inf), -limit - 1.0):
        err = check_raises(ParameterError, name, fn, **_with(kwargs, name, bad))
        assert f"[{-limit:g}, {limit:g}] degrees" in str(err)
    fn(**_with(kwargs, name, limit))       # the limits themselves are valid
    fn(**_with(kwargs, name, -limit))


@pytest.mark.parametrize(("fn", "kwargs", "name"), [a for a in ARGUMENTS if np.ndim(a[1][a[2]]) == 0],
                         ids=[i for i, a in zip(IDS, ARGUMENTS) if np.ndim(a[1][a[2]]) == 0])
def test_shapes_that_do_not_broadcast_are_refused(fn, kwargs, name):
    err = check_raises(ShapeError, name, fn, **{**kwargs, name: np.zeros(2)})
    assert "(2,)" in str(err) and "(3,)" in str(err)


@pytest.mark.parametrize(("fn", "kwargs", "name"), ARGUMENTS, ids=IDS)
def test_non_numbers_are_refused(fn, kwargs, name):
    check_raises(DTypeError, name, fn, **{**kwargs, name: "north"})


def test_a_point_off_the_ellipsoid_is_refused():
    """At 10,000 km the origin's vertical misses the ellipsoid: an error, never a silent NaN."""
    err = check_raises(ParameterError, "east, north", enu_to_geodetic, np.array([0.0, 1e7]), 0.0, 45.0, 13.0)
    assert "index (1,)" in str(err)
    check_raises(ParameterError, "east, north", enu_to_geodetic, 1e7, 0.0, 45.0, 13.0)


@pytest.mark.parametrize(("field", "value", "cls"), [
    ("lat0", 95.0, ParameterError), ("lon0", -180.5, ParameterError), ("lat0", np.nan, NonFiniteError),
    ("h0", np.inf, NonFiniteError), ("lon0", [13.0, 14.0], ShapeError)])
def test_local_frame_origin_validated(field, value, cls):
    check_raises(cls, field, LocalFrame, **{"lat0": 45.0, "lon0": 13.0, field: value})


def test_pymap3d_is_not_a_run_time_dependency():
    """pymap3d is the tests' oracle only: nothing under src/ imports it."""
    importers = []
    for path in (Path(__file__).parents[2] / "src").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(name.split(".")[0] == "pymap3d" for name in names):
                importers.append(str(path))
    assert importers == []
