"""Evaluation of a track table against truth: horizontal error, NEES, NIS, error CDF.

For each estimate the truth at the same time (nearest time stamp within
``tolerance_s``, per track) is expressed in the estimate's local frame and

    error  = ||p_hat - p|| (m),                      RMSE = sqrt(mean error^2)
    NEES   = (p_hat - p)^T P^{-1} (p_hat - p)         chi-square, 2 dof, for a consistent filter
    NIS    as written by the filter, of the fixes it updated from its prediction (flags update and
           manoeuvre: the one definition of :mod:`._consistency`, as the track table has it)

(Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4).  Reported are the counts of the
flags, the mean NEES and NIS, the fraction inside their two-sided 95 %
chi-square interval, the mean NIS's own 95 % band, and the 50/67/95 % points of
the error CDF.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import scipy.special

from .._core.data_checks import check_frame, point_numbers
from .._core.validation import check_bool, check_path, check_positive
from ..errors import DataError, ParameterError
from ..io import FIXES, LocalFrame, ReadOptions, ReadReport, input_columns, read_table
from .._core.tracks import track_offsets
from ._advice import evaluation_nis
from ._consistency import USED_FLAGS, flag_counts, is_flag, nis_stats
from ._registry import CELL_METHODS
from ._output import POINT_COLUMNS

__all__ = ["attach_truth", "evaluate_tracks"]


def _truth_table(truth, file, read: ReadOptions = ReadOptions(),
                 report: ReadReport | None = None) -> tuple[pd.DataFrame, bool]:
    """(truth as track_id, t, true_a, true_b sorted by t; True if a, b are lat/lon, False if x/y in m).

    ``truth`` is a file in any input format or a DataFrame, read like a track's input (column names
    and units recognised, :func:`mptrack.io.read_table`, with what ``read`` says; its notes go to
    ``report``); ``true_lat``/``true_lon`` (or ``true_x``/``true_y``), as in simulated logs, are
    preferred over ``lat``/``lon`` unless ``read`` names the position columns."""
    given = read.column_map
    columns = input_columns(truth)
    prefer = next(({"lat": a, "lon": b} if geo else {"x": a, "y": b}
                   for a, b, geo in (("true_lat", "true_lon", True), ("true_x", "true_y", False))
                   if a in columns and b in columns), {})
    if {"lat", "lon", "x", "y"} & set(given):
        prefer = {}
    rows = read_table(truth, FIXES, read=replace(read, columns={**prefer, **given}), report=report)
    geographic = "lat" in rows.columns and "lon" in rows.columns
    a, b = ("lat", "lon") if geographic else ("x", "y")
    out = pd.DataFrame({"track_id": rows["track_id"].astype("string"), "t": rows["t"].to_numpy(float),
                        "true_a": rows[a].to_numpy(float), "true_b": rows[b].to_numpy(float)})
    return out.dropna().drop_duplicates(["track_id", "t"]).sort_values("t", kind="stable"), geographic


def _one_track_ids(truth: pd.DataFrame, tracks: pd.DataFrame, file) -> pd.DataFrame:
    """Truth of one track (a GPX trace, a log without track_id) matches an output of one track
    whatever the two are called; otherwise the track ids must match."""
    truth_ids, ids = truth["track_id"].unique(), tracks["track_id"].unique()
    if len(truth_ids) == 1 and len(ids) == 1:
        return truth.assign(track_id=pd.array([ids[0]] * len(truth), dtype="string"))
    if not set(ids) & set(truth_ids):
        raise DataError(f"no track id of the truth ({', '.join(map(str, truth_ids[:5]))}) is one of the "
                        f"tracks ({', '.join(map(str, ids[:5]))})", file=file, column="track_id")
    return truth


def check_points(name: str, tracks, columns=()) -> None:
    """A point table with ``columns``, its numbers checked (:func:`mptrack._core.data_checks.point_numbers`)."""
    check_frame(name, tracks, columns, point_numbers(tracks, POINT_COLUMNS + _ADDED))


#: The columns :func:`attach_truth` adds.
_ADDED = ("true_lat", "true_lon", "true_x", "true_y", "true_east_m", "true_north_m", "error_m", "nees")


def attach_truth(tracks: pd.DataFrame, truth, *, tolerance_s: float = 0.5, file="truth",
                 read: ReadOptions = ReadOptions(), report: ReadReport | None = None) -> pd.DataFrame:
    """A track table with error_m, nees and true east/north columns from the nearest truth sample.

    Truth in lat/lon is projected into each track's local frame; truth in x/y (metres) is compared with
    tracks computed in x/y.  Only the keys (track, time) are matched, so the table is not copied.

    Parameters
    ----------
    tracks : pandas.DataFrame
        A point table of ``mptrack track`` (:func:`mptrack.io.read_output`).
    truth : str, path-like or pandas.DataFrame
    tolerance_s : float, optional
        Largest time difference of a match (s).
    file : str, optional
        The truth's name in messages.
    read : ReadOptions, optional
    report : ReadReport, optional

    Returns
    -------
    pandas.DataFrame
    """
    check_points("tracks", tracks, ("track_id", "t", "origin_lat"))
    tolerance_s = check_positive("tolerance_s", tolerance_s, allow_zero=True)
    if not isinstance(truth, pd.DataFrame):
        check_path("truth", truth)
    tt, geographic = _truth_table(truth, file, read, report)
    keys = pd.DataFrame({"track_id": tracks["track_id"].astype("string").array,
                         "t": tracks["t"].to_numpy(float), "_order": np.arange(len(tracks))})
    tt = _one_track_ids(tt, keys, file)
    merged = pd.merge_asof(keys.sort_values("t", kind="stable"), tt, on="t", by="track_id",
                           direction="nearest", tolerance=tolerance_s)
    a, b = np.full(len(tracks), np.nan), np.full(len(tracks), np.nan)
    at = merged["_order"].to_numpy()
    a[at], b[at] = merged["true_a"].to_numpy(float), merged["true_b"].to_numpy(float)
    if len(tracks) and not np.isfinite(a).any():
        shift = _clock_shift(keys["t"].to_numpy(float), tt["t"].to_numpy(float), tolerance_s)
        hint = "; is it the truth of this run? (--tolerance widens the match)" if shift is None else (
            f", but the truth's times are {abs(shift) / 3600:g} h {'after' if shift > 0 else 'before'} the "
            "estimates': local time stamps read in different time zones? (give both commands the same --timezone)")
        raise DataError(f"no estimate has a truth sample within {tolerance_s:g} s of its time (of the same "
                        f"track){hint}", file=file)
    return _with_errors(tracks.assign(track_id=keys["track_id"].array), a, b, geographic, file)


#: The time-zone offsets :func:`_clock_shift` tries (s): every quarter hour within +-14 h.
_ZONE_SHIFTS = 900.0 * np.arange(-56, 57)


def _clock_shift(t: np.ndarray, truth_t: np.ndarray, tolerance_s: float) -> float | None:
    """The time-zone offset (a whole number of quarter hours) by which the truth's times follow the
    estimates' when shifting them by it matches most estimates (more than half), or None."""
    truth_t = np.sort(truth_t[np.isfinite(truth_t)])
    t = t[np.isfinite(t)]
    if not len(truth_t) or not len(t):
        return None
    best, found = len(t) // 2, None
    for shift in _ZONE_SHIFTS[_ZONE_SHIFTS != 0.0]:
        want = t + shift
        i = np.searchsorted(truth_t, want)
        near = np.minimum(np.abs(truth_t[np.maximum(i - 1, 0)] - want),
                          np.abs(truth_t[np.minimum(i, len(truth_t) - 1)] - want))
        n = int(np.count_nonzero(near <= tolerance_s))
        if n > best:
            best, found = n, float(shift)
    return found


#: The truth columns a point table can carry (a simulated log's truth passed through ``mptrack track``):
#: (first, second, geographic).
TRUTH_COLUMNS = (("true_lat", "true_lon", True), ("true_x", "true_y", False))


def _own_truth(tracks: pd.DataFrame) -> pd.DataFrame:
    """``tracks`` with the columns of :func:`attach_truth` from the truth columns of its own rows."""
    found = next(((a, b, geo) for a, b, geo in TRUTH_COLUMNS if a in tracks.columns and b in tracks.columns), None)
    if found is None:
        raise DataError("has no truth columns (true_lat/true_lon or true_x/true_y)", file=tracks.attrs.get("file",
                                                                                                           "tracks"))
    a, b, geographic = found
    return _with_errors(tracks, tracks[a].to_numpy(float), tracks[b].to_numpy(float), geographic,
                        f"the columns {a}/{b}")


def _with_errors(tracks: pd.DataFrame, a: np.ndarray, b: np.ndarray, geographic: bool, file) -> pd.DataFrame:
    """``tracks`` with error_m, nees, true_east_m/true_north_m (and true_lat/true_lon from a geographic
    truth) for the truth ``a``, ``b`` (lat/lon or x/y in m) of each row (NaN where none)."""
    origin = tracks[["origin_lat", "origin_lon"]].astype(float)
    has_origin = np.isfinite(origin["origin_lat"].to_numpy())
    if geographic and not has_origin.all():
        raise DataError("the truth is in lat/lon but some tracks were computed in x/y (no geographic "
                        "origin); give the truth as x/y in metres", file=file, column="lat")
    if not geographic and has_origin.any():
        raise DataError("the truth is in x/y but the tracks are in lat/lon; give the truth as lat/lon",
                        file=file, column="x")
    e = np.full(len(tracks), np.nan)
    n = np.full(len(tracks), np.nan)
    if geographic:
        for (la, lo), idx in origin.groupby(["origin_lat", "origin_lon"]).indices.items():
            ok = idx[np.isfinite(a[idx])]
            if ok.size:
                e[ok], n[ok] = LocalFrame(la, lo).to_enu(a[ok], b[ok])
    else:
        e, n = a, b
    de, dn = tracks["east_m"].to_numpy(float) - e, tracks["north_m"].to_numpy(float) - n
    va, cov, vb = (tracks[k].to_numpy(float) for k in ("var_east_m2", "cov_en_m2", "var_north_m2"))
    det = va * vb - cov * cov
    with np.errstate(invalid="ignore", divide="ignore"):
        nees = (vb * de * de - 2 * cov * de * dn + va * dn * dn) / det
    # columns this adds replace any of the same name (a simulated log's truth passed through the track)
    est = tracks.drop(columns=[c for c in _ADDED if c in tracks.columns])
    true = {"true_lat": a, "true_lon": b} if geographic else {}
    return est.assign(**true, true_east_m=e, true_north_m=n, error_m=np.hypot(de, dn), nees=nees
                      ).reset_index(drop=True)


def _inside(values: np.ndarray, dof: np.ndarray) -> float:
    ok = np.isfinite(values) & (dof > 0)
    if not ok.any():
        return float("nan")
    lo = scipy.special.chdtri(dof[ok], 0.975)  # the chi-square quantiles 0.025 and 0.975
    hi = scipy.special.chdtri(dof[ok], 0.025)
    return float(np.mean((values[ok] >= lo) & (values[ok] <= hi)))


def _stats(g: pd.DataFrame) -> dict:
    """The statistics of one track's rows, or of every row of the table (the overall row): counts of
    the flags, error against the truth, and the mean NIS of :mod:`._consistency` (the one definition)
    with the fraction of those fixes inside their own 95 % interval."""
    err = g["error_m"].to_numpy(float) if "error_m" in g else np.array([])
    err = err[np.isfinite(err)]
    flag = g["flag"].to_numpy(dtype=object)
    ids = g["track_id"].to_numpy(dtype=object)
    counts = flag_counts(flag, track_offsets(ids))
    row = {"points": int(len(g)), **{k: int(v.sum()) for k, v in counts.items()}}
    if err.size:
        nees = g["nees"].to_numpy(float)
        row.update(rmse_m=float(np.sqrt(np.mean(err ** 2))), mean_error_m=float(err.mean()),
                   cdf50_m=float(np.percentile(err, 50)), cdf67_m=float(np.percentile(err, 67)),
                   cdf95_m=float(np.percentile(err, 95)), mean_nees=float(np.nanmean(nees)),
                   nees_in_95=_inside(nees, np.full(len(nees), 2)))
    nis, dof = g["nis"].to_numpy(float), g["nis_dof"].to_numpy()
    row.update(nis_stats(nis, dof, flag))
    used = is_flag(flag, *USED_FLAGS)
    row["nis_in_95"] = _inside(nis[used], dof[used])
    return row


def _cellular(tracks: pd.DataFrame) -> bool:
    """Whether a point table holds cellular tracks (its ``method``: EKF-..., FEKF-..., FCS-...)."""
    if "method" not in tracks.columns or not len(tracks):
        return False
    return str(tracks["method"].iloc[0]).split("-")[0].lower() in CELL_METHODS


def evaluate_tracks(tracks: pd.DataFrame, truth=None, *, tolerance_s: float = 0.5, truth_file="truth",
                    truth_columns: bool = False, read: ReadOptions = ReadOptions(),
                    report: ReadReport | None = None) -> tuple[dict, pd.DataFrame]:
    """Evaluate a track table against truth: RMSE, NEES/NIS consistency and the error distribution.

    Parameters
    ----------
    tracks : pandas.DataFrame
        A point table of ``mptrack track`` (:func:`mptrack.io.read_output`).
    truth : str, path-like or pandas.DataFrame, optional
        Truth in any input format, matched by track and nearest time (:func:`attach_truth`).
    tolerance_s : float, optional
        Largest time difference of a match (s).
    truth_file : str, optional
        The truth's name in messages.
    truth_columns : bool, optional
        Instead of ``truth``: the table's own truth columns (true_lat/true_lon or true_x/true_y, a
        simulated log's passed through ``mptrack track``).
    read : ReadOptions, optional
        How the truth file is read.
    report : ReadReport, optional
        Receives how the truth was read.

    Returns
    -------
    summary : dict
        {"overall": {...}, "tracks": {id: {...}}, "nis": {"far_low", "far_high", "advice"}}; "nis"
        counts the tracks whose mean NIS is far outside its band and says what that usually means.
    tracks : pandas.DataFrame
        With error columns when truth is given.
    """
    check_points("tracks", tracks)
    truth_columns = check_bool("truth_columns", truth_columns)
    tolerance_s = check_positive("tolerance_s", tolerance_s, allow_zero=True)
    if truth is not None and truth_columns:
        raise ParameterError("truth_columns: give a truth or truth_columns=True, not both")
    evaluated = truth is not None or truth_columns
    needed = ["track_id", "t", "flag", "nis", "nis_dof"] + (
        ["east_m", "north_m", "var_east_m2", "cov_en_m2", "var_north_m2", "origin_lat", "origin_lon"]
        if evaluated else [])
    missing = [c for c in needed if c not in tracks.columns]
    if missing:
        raise DataError(f"not a table written by mptrack track (no column {', '.join(missing)}); track the log "
                        "first: mptrack track LOG --out TRACKS", file=tracks.attrs.get("file", "tracks"))
    if truth is not None:
        tracks = attach_truth(tracks, truth, tolerance_s=tolerance_s, file=truth_file, read=read, report=report)
    elif truth_columns:
        tracks = _own_truth(tracks)
    per = {str(tid): _stats(g) for tid, g in tracks.groupby("track_id", sort=False)}
    summary = {"overall": _stats(tracks), "tracks": per}
    summary["nis"] = evaluation_nis(per, summary["overall"], cellular=_cellular(tracks))
    if evaluated:
        summary["overall"]["matched_points"] = int(np.isfinite(tracks["error_m"]).sum())
    return summary, tracks
