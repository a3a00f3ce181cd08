"""The data a tracking report's page draws, as compact JSON: per track, the decimated points with
coordinates as integer deltas, flags as one character per point, and the series of its time plots.

Coordinates are integers in units of 1e-6 degree (about 0.1 m) for lat/lon tracks, or centimetres
for tracks in local x/y metres; each track's first point is absolute, the rest are differences to the
previous point.  Raw fixes and truth are differences to the estimate of the same row (null where
absent).  Times are milliseconds since the track's start, delta-coded (a 50 Hz trace's 20 ms steps
are exact; deciseconds made its speed plot zig-zag).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ._decimate import BREAK, DEFAULT_BUDGET, ORDINARY, REJECTED, keep_mask, point_budget

__all__ = ["track_payload", "FLAG_CODES"]

#: One character per point in the page: the output's ``flag`` values.
FLAG_CODES = {"update": "u", "outlier": "o", "predicted": "p", "reset": "r", "init": "i", "manoeuvre": "m"}


def _order(ids: pd.Series) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """(row order that groups the tracks or None if they are already contiguous, offsets, track ids)."""
    codes, uniques = pd.factorize(ids, sort=False)
    order, step = None, np.diff(codes)
    if np.any((step != 0) & (step != 1)):  # a track's rows are not contiguous
        order = np.argsort(codes, kind="stable")
        codes = codes[order]
    counts = np.bincount(codes, minlength=len(uniques)) if len(codes) else np.zeros(0, np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return order, offsets, np.asarray(uniques).astype(str)


def _col(df: pd.DataFrame, name: str, order, keep) -> np.ndarray | None:
    if name not in df.columns:
        return None
    v = df[name].to_numpy()
    if order is not None:
        v = v[order]
    return v[keep]


def _f(df, name, order, keep) -> np.ndarray | None:
    v = _col(df, name, order, keep)
    return None if v is None else v.astype(float)


def _ints(x: np.ndarray) -> list:
    """Integers, None where not finite."""
    out = np.where(np.isfinite(x), np.round(x), 0).astype(np.int64).tolist()
    if not np.isfinite(x).all():
        bad = np.flatnonzero(~np.isfinite(x))
        for i in bad:
            out[i] = None
    return out


def _sig(x: np.ndarray, digits: int = 3) -> list:
    """Values rounded to ``digits`` significant digits, None where not finite."""
    x = np.asarray(x, float)
    fin = np.isfinite(x)
    mag = np.where(fin & (x != 0), np.floor(np.log10(np.abs(np.where(fin & (x != 0), x, 1.0)))), 0)
    scale = 10.0 ** (digits - 1 - mag)
    r = np.where(fin, np.round(np.where(fin, x, 0) * scale) / scale, 0.0)
    out = [float(f"{v:.{digits}g}") for v in r.tolist()]
    if not fin.all():
        for i in np.flatnonzero(~fin):
            out[i] = None
    return out


def _delta(x: np.ndarray) -> list:
    """Integer deltas of a finite integer-valued series (the first value absolute)."""
    x = np.asarray(x, np.int64)
    return np.diff(x, prepend=0).tolist() if len(x) else []


def track_payload(tracks: pd.DataFrame, *, budget: int = DEFAULT_BUDGET) -> dict:
    """The JSON-ready description of every track of ``tracks`` (a point table of ``mptrack track``,
    with ``error_m`` and truth columns when evaluated), decimated to about ``budget`` points."""
    order, offsets, ids = _order(tracks["track_id"])
    counts = np.diff(offsets)
    flags = tracks["flag"].to_numpy().astype(str)
    gap = tracks["gap"].to_numpy(bool) if "gap" in tracks.columns else np.zeros(len(tracks), bool)
    if order is not None:
        flags, gap = flags[order], gap[order]
    rejected, reset = flags == "outlier", flags == "reset"
    kinds = np.where(reset | gap, BREAK, np.where(rejected, REJECTED, ORDINARY))
    keep = keep_mask(offsets, point_budget(counts, budget), kinds)
    kept = np.add.reduceat(keep, offsets[:-1]) if len(counts) else np.zeros(0, np.int64)
    kept = np.where(counts > 0, kept, 0)
    k_off = np.concatenate([[0], np.cumsum(kept)]).astype(np.int64)

    lat = _f(tracks, "lat", order, keep)
    geo = lat is not None and bool(np.isfinite(lat).any())
    if geo:
        scale, ny, nx = 1e6, lat, _f(tracks, "lon", order, keep)
        my, mx = _f(tracks, "meas_lat", order, keep), _f(tracks, "meas_lon", order, keep)
        ty, tx = _f(tracks, "true_lat", order, keep), _f(tracks, "true_lon", order, keep)
    else:
        scale, ny, nx = 100.0, _f(tracks, "north_m", order, keep), _f(tracks, "east_m", order, keep)
        my, mx = _f(tracks, "meas_north_m", order, keep), _f(tracks, "meas_east_m", order, keep)
        ty, tx = _f(tracks, "true_north_m", order, keep), _f(tracks, "true_east_m", order, keep)
    totals = _totals(tracks, "meas_lat" if geo else "meas_north_m", order, rejected, reset, gap)
    iy, ix = np.round(ny * scale), np.round(nx * scale)
    drawable = np.isfinite(iy) & np.isfinite(ix)
    t = _f(tracks, "t", order, keep)
    sd = np.sqrt(_f(tracks, "var_east_m2", order, keep) + _f(tracks, "var_north_m2", order, keep))
    ve, vn = _f(tracks, "vel_east_mps", order, keep), _f(tracks, "vel_north_mps", order, keep)
    speed = np.hypot(ve, vn) if ve is not None and vn is not None else None
    nis, dof = _f(tracks, "nis", order, keep), _f(tracks, "nis_dof", order, keep)
    err = _f(tracks, "error_m", order, keep)
    ell = [_f(tracks, c, order, keep) for c in ("ell_major_m", "ell_minor_m", "ell_azimuth_deg")]
    kflags = flags[keep]
    kgap = gap[keep]
    codes = np.array([FLAG_CODES.get(f, "?") for f in FLAG_CODES] + ["?"])
    flag_index = {f: i for i, f in enumerate(FLAG_CODES)}
    kcode = codes[np.array([flag_index.get(f, len(FLAG_CODES)) for f in kflags], dtype=np.int64)] \
        if len(kflags) else np.array([], str)
    has_meas = my is not None and bool(np.isfinite(my).any())
    has_truth = ty is not None and bool(np.isfinite(ty).any())
    out_tracks = []
    for b, tid in enumerate(ids):
        s = slice(k_off[b], k_off[b + 1])
        ok = drawable[s]
        rec: dict = {"id": str(tid), "n": int(counts[b]), "drawn": int(ok.sum())}
        if not ok.any():
            out_tracks.append(rec)
            continue
        yy, xx = iy[s][ok], ix[s][ok]
        rec["y"], rec["x"] = _delta(yy), _delta(xx)
        rec["f"] = "".join(kcode[s][ok].tolist())
        if kgap[s][ok].any():
            rec["gap"] = np.flatnonzero(kgap[s][ok]).tolist()
        if has_meas:
            rec["my"], rec["mx"] = _ints(np.round(my[s][ok] * scale) - yy), _ints(np.round(mx[s][ok] * scale) - xx)
        if has_truth:
            rec["ty"], rec["tx"] = _ints(np.round(ty[s][ok] * scale) - yy), _ints(np.round(tx[s][ok] * scale) - xx)
        tt = t[s][ok]
        rec["t"] = _delta(np.round((tt - tt[0]) * 1000)) if np.isfinite(tt).all() \
            else _delta(1000 * np.arange(ok.sum()))
        rec["sd"] = _sig(sd[s][ok])
        if speed is not None:
            rec["sp"] = _sig(speed[s][ok])
        if nis is not None:
            nn, d = nis[s][ok], dof[s][ok]
            rec["nis"] = _sig(nn)
            used = np.isfinite(nn) & (d > 0) & (kcode[s][ok] != "o")
            if used.any():
                rec["dof"] = int(np.bincount(d[used].astype(np.int64)).argmax())
        if err is not None and np.isfinite(err[s][ok]).any():
            rec["err"] = _sig(err[s][ok])
        if ell[0] is not None:
            rec["ell"] = [_sig(e[s][ok], 2 if i < 2 else 3) for i, e in enumerate(ell)]
        out_tracks.append(rec)
    dofs = sorted({r["dof"] for r in out_tracks if "dof" in r})
    import scipy.stats

    bands = {str(d): [float(f"{v:.4g}") for v in scipy.stats.chi2.ppf([0.025, 0.975], d)] for d in dofs}
    return {"geo": geo, "scale": scale, "tracks": out_tracks, "bands": bands,
            "points": int(len(tracks)), "drawn": int(sum(r["drawn"] for r in out_tracks)),
            "decimated": bool(int(keep.sum()) < len(tracks)), "has_meas": has_meas, "has_truth": has_truth,
            "has_error": err is not None and bool(np.isfinite(err).any()), "totals": totals}


def _totals(tracks: pd.DataFrame, name: str, order, rejected: np.ndarray, reset: np.ndarray,
            gap: np.ndarray) -> dict:
    """How many points of each layer the whole table has (drawn or not): raw fixes accepted and
    rejected (rows with a measured position in column ``name``), resets and gaps."""
    measured = np.isfinite(tracks[name].to_numpy(float)) if name in tracks.columns else np.zeros(len(tracks), bool)
    if order is not None:
        measured = measured[order]
    return {"raw": int((measured & ~rejected).sum()), "rejected": int((measured & rejected).sum()),
            "resets": int(reset.sum()), "gaps": int(gap.sum())}
