"""Tracking one position-fix track: local ENU frame, filter by name, optional smoothing, output table."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._validation import check_positive
from ..io import LocalFrame
from ..linear import FilterResult, get_filter
from ._gated import FLAGS, kalman_filter_gated, smooth_gated
from ._registry import get_fix_filter, get_model

__all__ = ["TrackOptions", "track_fixes", "point_table"]


@dataclass(frozen=True)
class TrackOptions:
    """Settings of ``mptrack track`` (units in the names).

    model             motion model name (MODELS): "cv" or "ca"
    filter            position-fix filter (FIX_FILTERS): "kf" (gated, irregular times) or a linear filter name
    q                 process-noise spectral density (m^2/s^3 for cv, m^2/s^5 for ca)
    sigma_m           1-sigma fix accuracy used where a fix has no accuracy_m (m)
    gate_probability  chi-square probability of the NIS gate (None: no gating); 0.999 -> 13.82 for 2-D fixes
    smooth            add an RTS smoothing pass (fixed interval, whole track)
    gap_s             an interval longer than this flags the point after it as following a gap (s)
    method            cellular filter (CELL_METHODS): "ekf", "fekf" or "fcs"
    motion            cellular motion model: "random-walk" (the paper's) or "cv"
    path_loss         path-loss model for RSS -> range (mptrack.radio.PATH_LOSS_MODELS)
    q_km2             cellular process noise: random walk, km^2 per scan; cv, km^2/s^3
    r_km2             cellular range-noise variance (km^2; the paper's R0 = 0.222)
    scan_interval_s   cellular scan grid step (None: median interval between scans)
    """

    model: str = "cv"
    filter: str = "kf"
    q: float = 2.0
    sigma_m: float = 5.0
    gate_probability: float | None = 0.999
    smooth: bool = False
    gap_s: float = 30.0
    method: str = "ekf"
    motion: str = "random-walk"
    path_loss: str = "cost231-wi-nlos"
    q_km2: float = 0.02
    r_km2: float = 0.222
    scan_interval_s: float | None = None

    def __post_init__(self) -> None:
        get_model(self.model)
        object.__setattr__(self, "filter", get_fix_filter(self.filter))
        for name, allow_zero in (("q", True), ("sigma_m", False), ("gap_s", False), ("q_km2", True),
                                 ("r_km2", False)):
            check_positive(name, getattr(self, name), allow_zero=allow_zero)
        if self.scan_interval_s is not None:
            check_positive("scan_interval_s", self.scan_interval_s)


_FLAG_NAMES = np.array(FLAGS, dtype=object)


@functools.lru_cache(maxsize=32)
def _model(name: str, q: float, sigma_r2: float):
    return get_model(name).build(q, sigma_r2)


def _ellipse(P2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1-sigma ellipse of (T, 2, 2) east/north covariances: semi-axes (m) and azimuth of the major axis
    (degrees clockwise from north, in [0, 180))."""
    w, v = np.linalg.eigh(P2)
    major = np.sqrt(np.clip(w[:, 1], 0.0, None))
    minor = np.sqrt(np.clip(w[:, 0], 0.0, None))
    az = np.degrees(np.arctan2(v[:, 0, 1], v[:, 1, 1])) % 180.0
    return major, minor, az


def point_table(track_id: str, frame: LocalFrame | None, times, t, xy: np.ndarray, vel: np.ndarray | None,
                P2: np.ndarray, nis: np.ndarray, nis_dof: np.ndarray, flags: np.ndarray, gap_s: float,
                method: str, extra: dict | None = None) -> pd.DataFrame:
    """The output table of one track (one row per estimate; columns documented in docs/tracking.md).
    ``frame`` None (x/y input): lat, lon and the origin are NaN."""
    if frame is None:  # x/y input: positions are local only
        lat = lon = origin_lat = origin_lon = np.full(len(t), np.nan)
    else:
        lat, lon = frame.to_geodetic(xy[:, 0], xy[:, 1])
        origin_lat, origin_lon = np.full(len(t), frame.lat0), np.full(len(t), frame.lon0)
    major, minor, az = _ellipse(P2)
    T = len(t)
    gap = np.r_[False, np.diff(t) > gap_s]
    cols = {
        "track_id": np.full(T, track_id, dtype=object), "time": times, "t": t, "lat": lat, "lon": lon,
        "east_m": xy[:, 0], "north_m": xy[:, 1],
        "vel_east_mps": np.full(T, np.nan) if vel is None else vel[:, 0],
        "vel_north_mps": np.full(T, np.nan) if vel is None else vel[:, 1],
        "var_east_m2": P2[:, 0, 0], "cov_en_m2": P2[:, 0, 1], "var_north_m2": P2[:, 1, 1],
        "ell_major_m": major, "ell_minor_m": minor, "ell_azimuth_deg": az,
        "nis": nis, "nis_dof": nis_dof.astype(np.int64),
        "flag": _FLAG_NAMES[flags], "gap": gap,
        "origin_lat": origin_lat, "origin_lon": origin_lon,
        "method": np.full(T, method, dtype=object),
    }
    cols.update(extra or {})
    return pd.DataFrame(cols)


def _grid(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Regular grid at the median interval: (grid times, bin of each sample, dt); a bin keeps its first sample."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    bins = np.rint((t - t[0]) / dt).astype(np.int64)
    return t[0] + dt * np.arange(bins[-1] + 1), bins, dt


def _time_like(t_grid: np.ndarray, times: pd.Series):
    if pd.api.types.is_datetime64_any_dtype(times):
        return pd.to_datetime(np.rint(t_grid * 1e9).astype("int64"), utc=True)
    return t_grid


def track_fixes(track_id: str, rows: pd.DataFrame, options: TrackOptions = TrackOptions()) -> pd.DataFrame:
    """Filter (and optionally smooth) one track of validated position fixes; returns its point table.

    rows: a track from :func:`mptrack.io.iter_tracks` (columns t, time, lat/lon or x/y, accuracy_m?).
    Positions are east/north metres in the track's local frame (origin at the first fix).
    """
    spec = get_model(options.model)
    if "lat" in rows.columns and "lon" in rows.columns:
        frame = LocalFrame.at(rows["lat"], rows["lon"])
        e, n = frame.to_enu(rows["lat"].to_numpy(), rows["lon"].to_numpy())
    else:
        frame = None
        e, n = rows["x"].to_numpy(float), rows["y"].to_numpy(float)
    z = np.column_stack([e, n])
    t = rows["t"].to_numpy(float)
    T = len(t)
    sig = np.full(T, options.sigma_m)
    if "accuracy_m" in rows.columns:
        acc = rows["accuracy_m"].to_numpy(float)
        sig = np.where(np.isfinite(acc) & (acc > 0), acc, sig)
    model = _model(options.model, options.q, options.sigma_m ** 2)
    n_state = model.n
    pos = [int(np.flatnonzero(model.H[i])[0]) for i in range(2)]
    x0 = np.zeros(n_state)
    x0[pos] = z[0]
    p_axis = np.array([options.sigma_m ** 2] + [s ** 2 for s in spec.prior_sigmas])
    P0 = np.diag(np.tile(p_axis, 2))
    P0[np.ix_(pos, pos)] = np.diag([sig[0] ** 2] * 2)
    extra = {"meas_east_m": e, "meas_north_m": n}
    if options.filter == "kf":
        R = sig[:, None, None] ** 2 * np.eye(2)
        gated = kalman_filter_gated(model, t, z, x0, P0, R=R, gate_probability=options.gate_probability,
                                    reset_P0=P0)
        res = smooth_gated(gated) if options.smooth else gated.result
        flags, nis = gated.flag, gated.nis
        times = rows["time"].to_numpy() if not pd.api.types.is_datetime64_any_dtype(rows["time"]) \
            else rows["time"].reset_index(drop=True)
        method = "KF-gated" + ("+RTS" if options.smooth else "")
    else:
        res, flags, nis, t_out, extra = _grid_filter(model, options, t, z, x0, P0, extra)
        times = _time_like(t_out, rows["time"])
        t = t_out
        method = options.filter.upper() + ("+RTS" if options.smooth else "")
    vel = res.x[:, [p + 1 for p in pos]]
    P2 = res.P[:, pos][:, :, pos]
    dof = np.where(np.isnan(nis), 0, 2)
    if "lat" in rows.columns and options.filter == "kf":
        extra["meas_lat"], extra["meas_lon"] = rows["lat"].to_numpy(float), rows["lon"].to_numpy(float)
    return point_table(track_id, frame, times, t, res.x[:, pos], vel, P2, nis, dof, flags, options.gap_s,
                       method, extra)


def _grid_filter(model, options, t, z, x0, P0, extra):
    """A registered linear filter on the track resampled to a regular grid (NaN rows predict only)."""
    from ..linear import rts_smoother

    t_grid, bins, dt = _grid(t)
    zg = np.full((len(t_grid), 2), np.nan)
    first = np.r_[True, bins[1:] != bins[:-1]]
    zg[bins[first]] = z[first]
    disc = model.discretize(dt)
    # the prior is at the first fix: start one step before it
    res: FilterResult = get_filter(options.filter).run(disc, zg, np.linalg.solve(disc.F, x0), P0)
    # NIS of each grid measurement against the one-step prediction of the estimate before it
    x_prev = np.vstack([np.linalg.solve(disc.F, x0), res.x[:-1]])
    P_prev = np.concatenate([P0[None], res.P[:-1]])
    x_pred = x_prev @ disc.F.T
    P_pred = disc.F @ P_prev @ disc.F.T + disc.Q
    H, R = disc.H, disc.R
    S = H @ P_pred @ H.T + R
    nu = zg - x_pred @ H.T
    ok = np.isfinite(nu).all(axis=1)
    nis = np.full(len(t_grid), np.nan)
    nis[ok] = np.einsum("ti,ti->t", nu[ok], np.linalg.solve(S[ok], nu[ok][..., None])[..., 0])
    flags = np.where(ok, 0, 2).astype(np.int8)
    extra = {"meas_east_m": zg[:, 0], "meas_north_m": zg[:, 1]}
    if options.smooth:
        res = rts_smoother(disc, res)
    return res, flags, nis, t_grid, extra
