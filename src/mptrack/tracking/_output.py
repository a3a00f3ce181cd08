"""The output tables of ``mptrack track``, built once from flat columns (no per-track frames).

* the point table: one row per estimate (columns documented in docs/tracking.md);
* the track table: one row per track (noise estimates, counts, NIS consistency).

Every path (the engine, the per-track reference, the grid filters, the
cellular filters) builds its points through :func:`point_table`.
"""

from __future__ import annotations


import numpy as np
import pyarrow as pa

from .._core.validation import as_array, as_vector, check_positive
from ..errors import ParameterError, ShapeError
from ..io import enu_to_geodetic
from ._track_filter import FLAGS

__all__ = ["point_table", "ellipse", "POINT_COLUMNS"]

#: Columns of the point table, in order (extra per-method columns follow).
POINT_COLUMNS = ("track_id", "time", "t", "lat", "lon", "east_m", "north_m", "vel_east_mps", "vel_north_mps",
                 "var_east_m2", "cov_en_m2", "var_north_m2", "ell_major_m", "ell_minor_m", "ell_azimuth_deg",
                 "nis", "nis_dof", "flag", "gap", "origin_lat", "origin_lon", "method")
_FLAG_NAMES = pa.array(FLAGS, type=pa.string())


def ellipse(var_e, cov_en, var_n) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1-sigma error ellipse of east/north covariances.

    Parameters
    ----------
    var_e, cov_en, var_n : array_like
        East variance, east-north covariance and north variance (m^2), of one shape; NaN where
        unknown (the ellipse is NaN there).

    Returns
    -------
    major, minor, azimuth : ndarray
        Semi-axes (m) and the azimuth of the major axis (degrees clockwise from north, in [0, 180);
        a circle has azimuth 0).

    Raises
    ------
    ShapeError, DTypeError, ParameterError
        Arrays of different shapes, not real numbers, or infinite.  (A variance below zero, which
        rounding can make of a zero one, counts as zero.)
    """
    var_e, cov_en, var_n = (as_array(k, v, allow_nan=True) for k, v in (("var_e", var_e), ("cov_en", cov_en),
                                                                       ("var_n", var_n)))
    if not var_e.shape == cov_en.shape == var_n.shape:
        raise ShapeError(f"var_e, cov_en, var_n: expected one shape, got {var_e.shape}, {cov_en.shape}, {var_n.shape}")
    # scaled to the largest entry, so that no sum or square overflows
    scale = np.maximum(np.maximum(np.abs(var_e), np.abs(var_n)), np.abs(cov_en))
    unit = np.where(scale > 0, scale, 1.0)
    e, c, n = var_e / unit, cov_en / unit, var_n / unit
    half_tr = 0.5 * (e + n)
    rad = np.hypot(0.5 * (e - n), c)
    root = np.sqrt(unit)
    major = np.sqrt(np.clip(half_tr + rad, 0.0, None)) * root
    minor = np.sqrt(np.clip(half_tr - rad, 0.0, None)) * root
    lam = half_tr + rad
    # eigenvector of the larger eigenvalue, from the better-conditioned row of (P - lam I)
    east_dominant = e >= n
    ve = np.where(east_dominant, lam - n, c)
    vn = np.where(east_dominant, c, lam - e)
    az = np.degrees(np.arctan2(ve, vn)) % 180.0
    return major, minor, az


def _repeat(values, counts: np.ndarray, dtype=None) -> pa.Array:
    """Per-track values as a per-row Arrow array (dictionary-indexed, then decoded)."""
    idx = pa.array(np.repeat(np.arange(len(counts), dtype=np.int32), counts))
    dictionary = pa.array(values, type=dtype)
    return pa.DictionaryArray.from_arrays(idx, dictionary).dictionary_decode()


def _time_array(time: np.ndarray) -> pa.Array:
    if np.issubdtype(time.dtype, np.datetime64):
        return pa.array(time.astype("datetime64[ns]"), type=pa.timestamp("ns", tz="UTC"))
    return pa.array(np.asarray(time, dtype=float))


def point_table(ids, offsets: np.ndarray, time: np.ndarray, t: np.ndarray, east: np.ndarray, north: np.ndarray,
                vel: np.ndarray | None, var_e: np.ndarray, cov_en: np.ndarray, var_n: np.ndarray, nis: np.ndarray,
                nis_dof: np.ndarray, flag: np.ndarray, gap_s: float, origin: tuple | None, method,
                extra: dict | None = None) -> pa.Table:
    """The point table of B tracks, built once from flat columns (rows offsets[b]:offsets[b+1]).

    Parameters
    ----------
    ids : sequence of str
        The B track ids.
    offsets : ndarray of int, shape (B + 1,)
    time, t : ndarray, shape (N,)
        Time stamps and seconds.
    east, north : ndarray, shape (N,)
        Positions in each track's frame (m).
    vel : ndarray, shape (N, 2) or None
        East/north velocity (m/s) (None: written as NaN).
    var_e, cov_en, var_n : ndarray, shape (N,)
        Position covariance (m^2).
    nis, nis_dof : ndarray, shape (N,)
    flag : ndarray, shape (N,)
        Indices into FLAGS.
    gap_s : float
        An interval longer than this flags the point after it as following a gap.
    origin : tuple of ndarray or None
        (lat0 (B,), lon0 (B,)) of each track's frame, or None for x/y tracks.
    method : str or sequence of str
        One name for all tracks, or one per track.
    extra : dict, optional
        Further columns (name -> (N,) array), appended in order.

    Returns
    -------
    pyarrow.Table
    """
    t = as_array("t", t, ndim=1)
    N = len(t)
    offsets = as_array("offsets", offsets, ndim=1, low=0, high=N)
    if len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != N or np.any(np.diff(offsets) < 0) \
            or np.any(offsets != np.round(offsets)):
        raise ParameterError(f"offsets: expected non-decreasing integer row offsets from 0 to N = {N}")
    offsets = offsets.astype(np.int64)
    B = len(offsets) - 1
    if isinstance(ids, (str, bytes)) or not np.iterable(ids) or len(ids) != B:
        raise ShapeError(f"ids: expected {B} track ids (one per track of offsets), got {ids!r}"[:200])
    east, north, var_e, cov_en, var_n = (as_array(k, v, shape=(N,)) for k, v in (
        ("east", east), ("north", north), ("var_e", var_e), ("cov_en", cov_en), ("var_n", var_n)))
    nis, nis_dof, flag = (as_array(k, v, shape=(N,), allow_nan=k == "nis", low=0) for k, v in (
        ("nis", nis), ("nis_dof", nis_dof), ("flag", flag)))
    if np.any(flag >= len(FLAGS)) or np.any(flag != np.round(flag)):
        raise ParameterError(f"flag: expected indices into FLAGS (0..{len(FLAGS) - 1})")
    flag = flag.astype(np.int8)
    vel = None if vel is None else as_array("vel", vel, shape=(N, 2), allow_nan=True)
    gap_s = check_positive("gap_s", gap_s)
    if origin is not None:
        if not isinstance(origin, (tuple, list)) or len(origin) != 2:
            raise ShapeError(f"origin: expected (lat0 (B,), lon0 (B,)) or None, got {origin!r}"[:200])
        origin = tuple(as_vector(k, v, B) for k, v in (("origin", origin[0]), ("origin", origin[1])))
    if not isinstance(method, str) and (not np.iterable(method) or len(method) != B):
        raise ShapeError(f"method: expected one name or {B} names, got {method!r}"[:200])
    counts = np.diff(offsets)
    if origin is None:
        nan = np.full(N, np.nan)
        lat = lon = lat0 = lon0 = nan
    else:
        lat0, lon0 = np.repeat(origin[0], counts), np.repeat(origin[1], counts)
        lat, lon = enu_to_geodetic(east, north, lat0, lon0)
    major, minor, az = ellipse(var_e, cov_en, var_n)
    gap = np.zeros(N, dtype=bool)
    gap[1:] = np.diff(t) > gap_s
    gap[offsets[:-1][counts > 0]] = False
    methods = [method] * len(counts) if isinstance(method, str) else list(method)
    cols = {
        "track_id": _repeat([str(i) for i in ids], counts, pa.string()),
        "time": _time_array(time), "t": t, "lat": lat, "lon": lon, "east_m": east, "north_m": north,
        "vel_east_mps": np.full(N, np.nan) if vel is None else vel[:, 0],
        "vel_north_mps": np.full(N, np.nan) if vel is None else vel[:, 1],
        "var_east_m2": var_e, "cov_en_m2": cov_en, "var_north_m2": var_n,
        "ell_major_m": major, "ell_minor_m": minor, "ell_azimuth_deg": az,
        "nis": nis, "nis_dof": np.asarray(nis_dof, dtype=np.int64),
        "flag": _FLAG_NAMES.take(pa.array(np.asarray(flag, dtype=np.int32))), "gap": gap,
        "origin_lat": lat0, "origin_lon": lon0,
        "method": _repeat(methods, counts, pa.string()),
    }
    cols.update(extra or {})
    return pa.table({k: v if isinstance(v, pa.Array) else pa.array(np.ascontiguousarray(v)) for k, v in cols.items()})
