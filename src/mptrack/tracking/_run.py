"""One chunk of position fixes through the engine: noise calibration, filter, output tables.

:func:`track_table` is the unit of work of ``mptrack track`` on position
fixes: whole tracks in, the point table and the track table out, with no
Python per track on the default path (the gated Kalman filter, ``--filter
kf``).  The fixed-step linear filters (``--filter lf|sskf|...``) run per track
through the reference :func:`._fixes.track_fixes`, with the same noise
estimates.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pyarrow as pa

from .._core.finiteness import derived_from, require_finite
from .._core.tracks import track_offsets
from ._columns import FixTable
from ._engine import filter_tracks
from ._fix_error import SLOW_TAU_S, slow_error_variance
from ._fixes import TrackOptions, track_fixes
from ._noise import SOURCES, NoiseEstimate, NoiseSpec, estimate_noise, fix_weights
from ._consistency import USED_FLAGS, flag_counts, is_flag, nis_band
from ._output import point_table
from ._registry import get_model

__all__ = ["noise_spec", "track_table", "TRACK_COLUMNS"]

#: Columns of the track table, in order.
TRACK_COLUMNS = ("track_id", "fixes", "duration_s", "updates", "manoeuvres", "outliers", "resets", "restarts",
                 "sigma_m",
                 "sigma_se_m", "sigma_slow_m",
                 "accuracy_scale", "accuracy_scale_se", "q", "q_se", "sigma_source", "q_source", "mean_nis",
                 "nis_dof", "nis_lo", "nis_hi", "nis_consistent", "loglik")


def noise_spec(options: TrackOptions) -> NoiseSpec:
    """What :func:`estimate_noise` does for ``options``."""
    spec = get_model(options.model)
    return NoiseSpec(order=spec.order, prior=spec.prior_variances, sigma_m=options.sigma_m, q=options.q,
                     scope=options.noise, gate=options.gate, max_rej=spec.order + 1, default_q=spec.default_q,
                     max_gap_s=math.inf if options.max_gap_s is None else options.max_gap_s)


def track_table(table: FixTable, options: TrackOptions, fixed: dict | None = None) -> tuple[pa.Table, pa.Table]:
    """(point table, track table) of the whole tracks in ``table``.

    ``fixed`` (from an earlier chunk, for ``noise="file"``): noise parameters to use instead of
    estimating them, see :func:`mptrack.tracking._noise.estimate_noise`.
    """
    # the options are what the caller (the CLI user) gave: a failure of the filters on the model derived
    # from them names the noise option of larger magnitude, not an internal matrix
    with derived_from(sigma_m=options.sigma_m, q=options.q):
        return _track_table(table, options, fixed)


def _track_table(table: FixTable, options: TrackOptions, fixed: dict | None) -> tuple[pa.Table, pa.Table]:
    spec = noise_spec(options)
    w, has_acc = fix_weights(table, options.sigma_m)
    noise = estimate_noise(table, w, has_acc, spec, fixed=fixed)
    r = table.per_row(noise.c) * w
    extra = {"meas_east_m": table.east, "meas_north_m": table.north, "fix_sigma_m": np.sqrt(r)}
    if table.geographic:
        extra["meas_lat"], extra["meas_lon"] = table.lat, table.lon
    origin = table.origin if table.geographic else None
    stats = np.full((table.B, 6), np.nan)
    sb2 = slow_error_variance(noise.c, table.per_track_median(w), has_acc)
    if options.filter == "kf":
        N, order = table.N, spec.order
        X = np.empty((N, 2, order + 1))
        P = np.empty((N, order + 1, order + 1))
        nis = np.empty(N)
        flag = np.empty(N, dtype=np.int8)
        filter_tracks(table.offsets, table.t, table.east, table.north, w, noise.c, noise.q, sb2,
                      np.full(table.B, SLOW_TAU_S), order, spec.prior, spec.gate, spec.max_rej, spec.max_gap_s, True,
                      options.smooth, X, P, nis, flag, stats)
        require_finite("the gated Kalman filter", (X, P), sigma_m=options.sigma_m, q=options.q,
                       east=table.east, north=table.north)
        method = "KF-gated" + ("+RTS" if options.smooth else "")
        var = P[:, 0, 0]
        points = point_table(table.ids, table.offsets, table.time, table.t, X[:, 0, 0], X[:, 1, 0], X[:, :, 1],
                             var, np.zeros(N), var, nis, np.where(np.isnan(nis), 0, 2), flag, options.gap_s,
                             origin, method, extra)
    else:
        points = _per_track(table, options, noise, r)
        flag = None
        sb2 = np.full(table.B, np.nan)   # the grid filters model a white fix error only
    return points, _tracks(table, noise, w, has_acc, sb2, stats, points, flag)


def _per_track(table: FixTable, options: TrackOptions, noise: NoiseEstimate, r: np.ndarray) -> pa.Table:
    """The fixed-step linear filters: the reference path, one track at a time."""
    frames = []
    for b in range(table.B):
        a0, b0 = table.offsets[b], table.offsets[b + 1]
        cols = {"track_id": table.ids[b], "time": table.time[a0:b0], "t": table.t[a0:b0],
                "row": table.row[a0:b0]}
        if table.geographic:
            cols.update(lat=table.lat[a0:b0], lon=table.lon[a0:b0])
        else:
            cols.update(x=table.east[a0:b0], y=table.north[a0:b0])
        frames.append(track_fixes(table.ids[b], pd.DataFrame(cols), options, fix_var=r[a0:b0], q=noise.q[b]))
    return pa.Table.from_pandas(pd.concat(frames, ignore_index=True), preserve_index=False)


def _tracks(table: FixTable, noise: NoiseEstimate, w: np.ndarray, has_acc: np.ndarray, sb2: np.ndarray,
            stats: np.ndarray, points: pa.Table, flag: np.ndarray | None) -> pa.Table:
    """The track table (one row per track): counts and the mean NIS from the flags
    (:mod:`._consistency`, the one definition every summary prints); ``sb2`` the variance of the fix
    error's slow part."""
    B = table.B
    nis = points.column("nis").to_numpy()
    if flag is None:  # per-track path: its rows are grid slots
        flag = points.column("flag").to_numpy(zero_copy_only=False)
        bounds = track_offsets(points.column("track_id").to_numpy(zero_copy_only=False))
        loglik = np.full(B, np.nan)
    else:
        bounds, loglik = table.offsets, stats[:, 0]
    counts = flag_counts(flag, bounds)
    used_rows = is_flag(flag, *USED_FLAGS) & np.isfinite(nis)
    by = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))
    nis_sum = np.bincount(by, weights=np.where(used_rows, nis, 0.0), minlength=B)
    used = np.bincount(by, weights=used_rows, minlength=B).astype(np.int64)
    starts, ends = table.offsets[:-1], table.offsets[1:] - 1
    sigma = np.sqrt(noise.c * table.per_track_median(w))
    scale = np.where(has_acc, np.sqrt(noise.c), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_nis = nis_sum / used
    lo, hi = nis_band(used)
    src = np.array(SOURCES, dtype=object)
    cols = {
        "track_id": pa.array([str(i) for i in table.ids], type=pa.string()),
        "fixes": table.counts, "duration_s": table.t[ends] - table.t[starts] if B else np.zeros(0),
        **counts,
        "sigma_m": sigma, "sigma_se_m": sigma * noise.se_log_c / 2.0, "sigma_slow_m": np.sqrt(sb2),
        "accuracy_scale": scale, "accuracy_scale_se": scale * noise.se_log_c / 2.0,
        "q": noise.q, "q_se": noise.q * noise.se_log_q,
        "sigma_source": pa.array(src[noise.source_c].tolist(), type=pa.string()),
        "q_source": pa.array(src[noise.source_q].tolist(), type=pa.string()),
        "mean_nis": mean_nis, "nis_dof": np.full(B, 2.0), "nis_lo": lo, "nis_hi": hi,
        "nis_consistent": (mean_nis >= lo) & (mean_nis <= hi),
        "loglik": loglik,
    }
    return pa.table({k: v if isinstance(v, pa.Array) else pa.array(np.asarray(v)) for k, v in cols.items()})
