"""Tracking one cellular measurement track with the EKF / FEKF / FCS of :mod:`mptrack.cellular`.

Each row is one cell heard at one time.  Its range to the cell's antenna is,
in this order of preference: ``range_m``; the timing advance, as the middle of
its ring, (ta + 0.5) x 553.5 m (one GSM TA step is c x 48/13 us / 2 = 553.5 m,
3GPP TS 45.010 sec. 5.4); or the RSS inverted through the path-loss model
(:func:`mptrack.radio.distance_from_rss`) with the cell's transmit power,
antenna height and carrier (from its ARFCN).  Rows at the same time form one
scan; scans are placed on a regular grid (step ``scan_interval_s``, default the
median interval) because the range filters have a fixed step; an empty grid
slot only predicts.  Filtering runs in kilometres (the unit the FEKF's fuzzy
sets are defined in, paper Table I), in a local frame at the centroid of the
track's cells.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._core.data_checks import check_frame, check_on_error
from .._core.validation import LATITUDE, LONGITUDE, lookup
from ..errors import DataError, ParameterError
from ..io import LocalFrame, ReadReport
from ..models import constant_velocity_continuous
from ..cellular import motion_position
from ..radio import PATH_LOSS_MODELS, TA_STEP_M, arfcn_to_frequency, band_of_arfcn, distance_from_rss
from ._columns import time_values
from ._fixes import TrackOptions, _time_like
from ._output import point_table
from ._registry import get_cell_method

__all__ = ["track_cells", "check_cell_ids", "ranges_km"]

DEFAULT_FREQUENCY_MHZ = 1800.0


def check_cell_rows(name: str, rows, columns=("t", "row", "cell_id")) -> pd.DataFrame:
    """Cellular measurements as :func:`mptrack.io.iter_tracks` gives them (schema MEASUREMENTS)."""
    return check_frame(name, rows, columns, {
        "t": {}, "rss_dbm": dict(allow_nan=True, low=-160.0, high=0.0), "range_m": dict(allow_nan=True, low=0.0),
        "ta": dict(allow_nan=True, low=0, high=63)})


def check_cells(name: str, cells, columns=("lat", "lon", "height_m", "power_dbm", "arfcn")) -> pd.DataFrame:
    """A cell table as :func:`mptrack.io.read_cells` gives it (indexed by cell_id, schema CELLS)."""
    return check_frame(name, cells, columns, {
        "lat": LATITUDE, "lon": LONGITUDE, "height_m": dict(low=0.0), "power_dbm": {},
        "arfcn": dict(allow_nan=True, low=0, high=1023)})


def _check_known(rows, cells, columns=("t", "row", "cell_id"), cell_columns=("lat", "lon")) -> None:
    """Measurements (with ``columns``) and a cell table (with ``cell_columns``) listing each of their cells."""
    check_cell_rows("rows", rows, columns)
    check_cells("cells", cells, cell_columns)
    unknown = ~rows["cell_id"].isin(cells.index)
    if unknown.any():
        raise ParameterError(f"rows: cell {rows['cell_id'][unknown].iloc[0]!r} is not in cells (check_cell_ids "
                             "drops such rows)")


def check_cell_ids(rows: pd.DataFrame, cells: pd.DataFrame, *, file, on_error: str,
                   report: ReadReport) -> pd.DataFrame:
    """The rows whose cell_id is in the cell table.

    Parameters
    ----------
    rows : pandas.DataFrame
        Cellular measurements.
    cells : pandas.DataFrame
        The cell table.
    file : str or path-like
        The measurements' name in messages.
    on_error : {"raise", "skip"}
    report : ReadReport
        Receives the count of skipped rows.

    Returns
    -------
    pandas.DataFrame

    Raises
    ------
    DataError
        An unknown cell id (naming file, row and "cell_id"), with ``on_error="raise"``.
    """
    check_cell_rows("rows", rows, ("row", "cell_id"))
    check_cells("cells", cells, ())
    check_on_error(on_error)
    if not isinstance(report, ReadReport):
        raise ParameterError(f"report: expected a ReadReport, got {type(report).__name__}")
    known = rows["cell_id"].isin(cells.index).to_numpy()
    if known.all():
        return rows
    for i in np.flatnonzero(~known):
        err = DataError(f"unknown cell {rows['cell_id'].iloc[i]!r} (not in the cell table)", file=file,
                        row=int(rows["row"].iloc[i]), column="cell_id")
        if on_error == "raise":
            raise err
        err.kind = "unknown cell id"
        report.skip(err)
    return rows.loc[known]


def ranges_km(rows: pd.DataFrame, cells: pd.DataFrame, path_loss: str = "cost231-wi-nlos") -> np.ndarray:
    """The range (km) of every measurement row: range_m, else the timing advance, else the RSS through a
    path-loss model; NaN where a row has none of them.

    Parameters
    ----------
    rows : pandas.DataFrame
        Cellular measurements.
    cells : pandas.DataFrame
        The cell table (power, height, ARFCN of each cell).
    path_loss : str, optional
        A key of :data:`mptrack.radio.PATH_LOSS_MODELS`.

    Returns
    -------
    ndarray, shape (N,)
    """
    _check_known(rows, cells, ("cell_id",), ("height_m", "power_dbm", "arfcn"))
    lookup("path_loss", path_loss, PATH_LOSS_MODELS, what="path-loss model", fold=str)
    r = np.full(len(rows), np.nan)
    if "range_m" in rows.columns:
        r = rows["range_m"].to_numpy(float) / 1e3
    if "ta" in rows.columns:
        ta = rows["ta"].to_numpy(float)
        r = np.where(np.isnan(r), (ta + 0.5) * TA_STEP_M / 1e3, r)
    if "rss_dbm" in rows.columns:
        need = np.isnan(r) & np.isfinite(rows["rss_dbm"].to_numpy(float))
        for cid in pd.unique(rows["cell_id"][need]):
            sel = need & (rows["cell_id"] == cid).to_numpy()
            cell = cells.loc[cid]
            arfcn = cell["arfcn"]
            f = DEFAULT_FREQUENCY_MHZ if pd.isna(arfcn) else float(arfcn_to_frequency(int(arfcn),
                                                                                       band_of_arfcn(arfcn)))
            params = {"frequency_mhz": f}
            if path_loss != "free-space":
                params["h_base_m"] = float(cell["height_m"])
            r[sel] = distance_from_rss(rows["rss_dbm"].to_numpy(float)[sel], float(cell["power_dbm"]),
                                       path_loss, on_invalid="ignore", **params)
    return r


def track_cells(track_id: str, rows: pd.DataFrame, cells: pd.DataFrame,
                options: TrackOptions = TrackOptions()) -> pd.DataFrame:
    """Filter one track of cellular measurements (rows with known cell ids) with the method of the
    options (EKF, FEKF or FCS of Bouzera et al. 2017).

    Parameters
    ----------
    track_id : str
    rows : pandas.DataFrame
        The track's measurements (schema MEASUREMENTS).
    cells : pandas.DataFrame
        The cell table (:func:`mptrack.io.read_cells`).
    options : TrackOptions, optional
        The settings of ``mptrack track``.

    Returns
    -------
    pandas.DataFrame
        The track's point table.

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    if not isinstance(options, TrackOptions):
        raise ParameterError(f"options: expected TrackOptions, got {type(options).__name__}")
    _check_known(rows, cells)
    if np.any(np.diff(rows["t"].to_numpy(dtype=float)) < 0):
        raise ParameterError("rows.t: expected non-decreasing times (one track in time order)")
    filt = get_cell_method(options.method)
    ids = list(pd.unique(rows["cell_id"]))
    tab = cells.loc[ids]
    frame = LocalFrame(float(tab["lat"].mean()), float(tab["lon"].mean()))
    se, sn = frame.to_enu(tab["lat"].to_numpy(float), tab["lon"].to_numpy(float))
    stations = np.column_stack([se, sn]) / 1e3
    r = ranges_km(rows, cells, options.path_loss)
    scans = pd.DataFrame({"t": rows["t"].to_numpy(float), "cell": pd.Categorical(rows["cell_id"], ids), "r": r})
    z_scan = scans.pivot_table(index="t", columns="cell", values="r", aggfunc="mean", observed=False,
                               dropna=False).reindex(columns=ids)
    t_scan = z_scan.index.to_numpy(float)
    dt = options.scan_interval_s or (float(np.median(np.diff(t_scan))) if len(t_scan) > 1 else 1.0)
    bins = np.rint((t_scan - t_scan[0]) / dt).astype(np.int64)
    zs = z_scan.to_numpy(float)
    sums = np.zeros((bins[-1] + 1, len(ids)))
    counts = np.zeros_like(sums)
    np.add.at(sums, bins, np.nan_to_num(zs))  # scans falling in one slot: mean range per cell
    np.add.at(counts, bins, np.isfinite(zs))
    z = np.divide(sums, counts, out=np.full_like(sums, np.nan), where=counts > 0)
    t = t_scan[0] + dt * np.arange(len(z))
    seen = np.isfinite(z[0])
    start = stations[seen].mean(axis=0)
    if options.motion == "cv":
        # the project's one constant-velocity state order, [x, vx, y, vy] (km, km/s)
        x0, P0 = np.array([start[0], 0.0, start[1], 0.0]), np.diag([1.0, 1e-4, 1.0, 1e-4])
        Q = constant_velocity_continuous(options.cell_q_km2, axes=2).discretize(dt).Q
    else:
        x0, P0, Q = start, np.eye(2), options.cell_q_km2 * np.eye(2)
    # the filters' prior is one step before z[0]
    res = filt(z, stations, x0, P0, Q, options.r_km2, motion=options.motion, dt=dt)
    nis, dof = res.nis, np.isfinite(res.innovation).sum(axis=1)
    flags = np.where(np.isfinite(z).any(axis=1), 0, 2).astype(np.int8)
    pos = list(motion_position(options.motion, 2))
    vel = res.x[:, [1, 3]] * 1e3 if options.motion == "cv" else None
    P2 = res.P[:, pos][:, :, pos] * 1e6
    extra = {"n_cells": np.isfinite(z).sum(axis=1)}
    return point_table([track_id], np.array([0, len(t)]), _time_like(t, time_values(rows["time"])), t, res.x[:, pos[0]] * 1e3,
                       res.x[:, pos[1]] * 1e3, vel, P2[:, 0, 0], P2[:, 0, 1], P2[:, 1, 1], nis, dof, flags,
                       max(options.gap_s, 1.5 * dt), (np.array([frame.lat0]), np.array([frame.lon0])),
                       f"{options.method.upper()}-{options.motion}", extra).to_pandas()

