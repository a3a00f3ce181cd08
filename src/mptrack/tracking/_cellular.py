"""Tracking one cellular measurement track with the EKF / FEKF / FCS of :mod:`mptrack.cellular`.

Each row is one cell heard at one time; the rows of one time are one scan, and
the track has one point per scan, at its time.  The default method, ``locate``,
places each scan as a geolocation request (:func:`mptrack.cellular.locate_cells`:
the posterior of the phone's position given its cells' levels and timing
advances, co-sited sector cells one site, the covariance the posterior's).  The
range filters (``ekf``, ``fekf``, ``fcs``) take one range per cell: it is,
in this order of preference: ``range_m``; the timing advance, as the middle of
its ring, (ta + 0.5) x the step of the cell's radio (GSM: c x 48/13 us / 2 =
553.5 m, 3GPP TS 45.010 sec. 5.4; LTE: c x 16 T_s / 2 = 78.07 m, TS 36.213); or the RSS inverted through the path-loss model
(:func:`mptrack.radio.distance_from_rss`) with the cell's transmit power,
antenna height and carrier (from its ARFCN).  Co-sited cells are one station
(their ranges combined); the range filters have a fixed step, so scans go on a
grid fine enough that almost every scan has its own slot (step
``scan_interval_s``, default the shortest interval, at least a tenth of the
median), empty slots only predict, and the points written are the scans'.
Filtering runs in kilometres (the unit the FEKF's fuzzy
sets are defined in, paper Table I), in a local frame at the centroid of the
track's cells.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._core.data_checks import check_frame
from .._core.validation import LATITUDE, LONGITUDE, lookup
from ..errors import DataError, ParameterError
from ..io import LocalFrame, ReadReport, Skipped
from ..models import constant_velocity_continuous
from ..cellular import CELL_FIELDS, RADIO_CODES, RADIOS, locate_cells, motion_position, signal_fit, signal_prior
from ..radio import PATH_LOSS_MODELS, TA_STEP_M, arfcn_to_frequency, band_of_arfcn, distance_from_rss
from ._columns import time_values
from ._fixes import TrackOptions, _time_like
from ._output import point_table
from ._registry import get_cell_method

__all__ = ["track_cells", "check_cell_ids", "resolve_cells", "ranges_km"]

#: a neighbour cell is looked for within this distance of the serving cell's site (m)
NEIGHBOUR_REACH_M = 20_000.0
DEFAULT_FREQUENCY_MHZ = 1800.0


def check_cell_rows(name: str, rows, columns=("t", "row", "cell_id")) -> pd.DataFrame:
    """Cellular measurements as :func:`mptrack.io.iter_tracks` gives them (schema MEASUREMENTS): cell ids as
    text, or empty where the log does not identify the cell."""
    check_frame(name, rows, columns, {
        "t": {}, "rss_dbm": dict(allow_nan=True, low=-160.0, high=0.0), "range_m": dict(allow_nan=True, low=0.0),
        "ta": dict(allow_nan=True, low=0, high=1282), "pci": dict(allow_nan=True, low=0),
        "earfcn": dict(allow_nan=True, low=0)})
    if "cell_id" in rows.columns and pd.api.types.infer_dtype(rows["cell_id"], skipna=True) not in ("string", "empty"):
        bad = next(v for v in rows["cell_id"].dropna() if not isinstance(v, str))
        raise ParameterError(f"{name}.cell_id: expected text ids (mcc-net-area-cell), or empty for a cell the log "
                             f"does not identify, got {bad!r}")
    return rows


def check_cells(name: str, cells, columns=("lat", "lon", "height_m", "power_dbm", "arfcn")) -> pd.DataFrame:
    """A cell table as :func:`mptrack.io.read_cells` gives it (indexed by cell_id, schema CELLS)."""
    return check_frame(name, cells, columns, {
        "lat": LATITUDE, "lon": LONGITUDE, "height_m": dict(low=0.0), "power_dbm": {},
        "arfcn": dict(allow_nan=True, low=0, high=1023), "unit": dict(allow_nan=True, low=0),
        "earfcn": dict(allow_nan=True, low=0)})


def _check_known(rows, cells, columns=("t", "row", "cell_id"), cell_columns=("lat", "lon")) -> None:
    """Measurements (with ``columns``) and a cell table (with ``cell_columns``) listing each of their cells."""
    check_cell_rows("rows", rows, columns)
    check_cells("cells", cells, cell_columns)
    unknown = ~rows["cell_id"].isin(cells.index)
    if unknown.any():
        raise ParameterError(f"rows: cell {rows['cell_id'][unknown].iloc[0]!r} is not in cells (check_cell_ids "
                             "drops such rows)")


def resolve_cells(rows: pd.DataFrame, cells: pd.DataFrame, *, file, report: ReadReport) -> pd.DataFrame:
    """Identify the cells a log names by their physical identity (PCI and channel) against the cell table.

    A drive-test log lists neighbour cells by PCI and channel only (e.g. :mod:`mptrack.io` reading a
    G-NetTrack Pro log).  A row whose ``cell_id`` is not in the table gets the id of the one cell with
    the same ``unit`` (PCI) and ``earfcn`` (a table without the channel matches on the PCI alone): for a
    serving cell in its logged country and area (``mcc``, ``area``), for a neighbour within
    NEIGHBOUR_REACH_M of its scan's serving cell.

    Parameters
    ----------
    rows : pandas.DataFrame
        Cellular measurements with the columns ``t``, ``cell_id`` and ``pci`` (and ``earfcn``, ``role``,
        ``mcc``, ``area``, ``track_id`` where the log has them).
    cells : pandas.DataFrame
        The cell table (:func:`mptrack.io.read_cells`), with ``unit`` and optionally ``earfcn``.
    file : str or path-like
        The measurements' name in the note.
    report : ReadReport
        Receives the count of neighbours left out.

    Returns
    -------
    pandas.DataFrame
        The rows, identified where one cell matches; a neighbour without one is left out and counted (it
        carries no identity of its own: not an error); a serving cell without one keeps its logged
        identity (:func:`check_cell_ids` decides).
    """
    check_cell_rows("rows", rows, ("t", "cell_id", "pci"))
    check_cells("cells", cells, ("lat", "lon"))   # a neighbour is matched near its serving cell
    if not isinstance(report, ReadReport):
        raise ParameterError(f"report: expected a ReadReport, got {type(report).__name__}")
    ids = rows["cell_id"].astype(object).to_numpy().copy()
    pci = rows["pci"].to_numpy(float)
    todo = ~rows["cell_id"].isin(cells.index).to_numpy() & np.isfinite(pci)
    if not todo.any():
        return rows
    tab = cells[cells["unit"].notna()] if "unit" in cells.columns else cells.iloc[:0]

    def col(frame, name):
        return frame[name].to_numpy(float) if name in frame.columns else np.full(len(frame), np.nan)

    unit, channel, t_lat, t_lon = col(tab, "unit"), col(tab, "earfcn"), col(tab, "lat"), col(tab, "lon")
    t_mcc, t_area = col(tab, "mcc"), col(tab, "area")
    earfcn, mcc, area = col(rows, "earfcn"), col(rows, "mcc"), col(rows, "area")
    role = rows["role"].astype(str).to_numpy() if "role" in rows.columns else np.full(len(rows), "neighbour")
    found: dict = {}

    def match(i: int, near) -> object:
        ok = (unit == pci[i]) & (~np.isfinite(channel) | (channel == earfcn[i]))
        if near is None:
            ok &= (t_mcc == mcc[i]) & (t_area == area[i])
        else:
            lat0, lon0 = near
            d = np.hypot((t_lat - lat0) * 111_195.0, (t_lon - lon0) * 111_195.0 * np.cos(np.radians(lat0)))
            ok &= d <= NEIGHBOUR_REACH_M
        hits = np.flatnonzero(ok)
        return tab.index[hits[0]] if len(hits) == 1 else None

    serving = role == "serving"
    for i in np.flatnonzero(todo & serving):
        key = ("s", pci[i], earfcn[i], mcc[i], area[i])
        if key not in found:
            found[key] = match(i, None)
        if found[key] is not None:
            ids[i] = found[key]
    # each scan's serving site (the rows of one scan share track and time)
    scan_key = list(zip(rows["track_id"].astype(str), rows["t"].to_numpy(float))) if "track_id" in rows.columns \
        else list(zip(["" for _ in range(len(rows))], rows["t"].to_numpy(float)))
    site = {}
    for i in np.flatnonzero(serving):
        if ids[i] in cells.index:
            site.setdefault(scan_key[i], ids[i])
    dropped = np.zeros(len(rows), bool)
    for i in np.flatnonzero(todo & ~serving):
        anchor = site.get(scan_key[i])
        if anchor is None:
            dropped[i] = True
            continue
        key = ("n", pci[i], earfcn[i], anchor)
        if key not in found:
            found[key] = match(i, (float(cells.at[anchor, "lat"]), float(cells.at[anchor, "lon"])))
        if found[key] is None:
            dropped[i] = True
        else:
            ids[i] = found[key]
    out = rows.assign(cell_id=ids)
    if dropped.any():
        n = int(dropped.sum())
        report.leave_out([Skipped("neighbour cell not in the cell table", n,
                                  f"{file}: {n} neighbour cells logged by PCI and channel match no single cell of the "
                                  f"table within {NEIGHBOUR_REACH_M / 1e3:g} km of their serving cell")])
        out = out.loc[~dropped]
    return out


def check_cell_ids(rows: pd.DataFrame, cells: pd.DataFrame, *, file, report: ReadReport) -> pd.DataFrame:
    """The rows whose cell_id is in the cell table; the others are left out and counted.

    A real log names cells that no table knows (crowd-sourced tables are incomplete; a drive-test log's
    neighbours may match no cell): their measurements range to no known position, so they are left out
    (not an error: no --max-skip), counted by cell in ``report`` with one note naming the first.

    Parameters
    ----------
    rows : pandas.DataFrame
        Cellular measurements (``cell_id`` empty where the log could not identify the cell).
    cells : pandas.DataFrame
        The cell table.
    file : str or path-like
        The measurements' name in the note.
    report : ReadReport
        Receives the count of rows left out and the note.

    Returns
    -------
    pandas.DataFrame
    """
    check_cell_rows("rows", rows, ("row", "cell_id"))
    check_cells("cells", cells, ())
    if not isinstance(report, ReadReport):
        raise ParameterError(f"report: expected a ReadReport, got {type(report).__name__}")
    known = rows["cell_id"].isin(cells.index).to_numpy()
    if known.all():
        return rows
    ids = rows["cell_id"][~known]
    named = ids.dropna()
    of = [f"{named.nunique()} cell(s) not in the cell table (first: {named.iloc[0]!r})"] if len(named) else []
    if len(named) < len(ids):   # (how many, when the note counts both kinds)
        of.append("cells the log does not identify" + (f" ({len(ids) - len(named)})" if len(named) else ""))
    report.leave_out([Skipped("cell not in the cell table", len(ids),
                              f"{file}: {len(ids)} measurement(s) of {' and of '.join(of)} left out (the first "
                              f"at row {int(rows['row'][~known].iloc[0])}): they range to no known position")])
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
    if "ta" in rows.columns:  # in the steps of the cell's radio (GSM 553.5 m, LTE 78.07 m; a table without radios: GSM)
        ta = rows["ta"].to_numpy(float)
        step = np.full(len(rows), TA_STEP_M)
        if "radio" in cells.columns:
            ids = pd.unique(rows["cell_id"])
            by_cell = dict(zip(ids, (RADIOS[int(c)].ta_step_m for c in _radio_codes(cells.loc[ids]))))
            step = np.array([by_cell[c] for c in rows["cell_id"]], dtype=float)
        r = np.where(np.isnan(r), (ta + 0.5) * step / 1e3, r)
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
    """Track one track of cellular measurements (rows with known cell ids), one point per scan (the rows of
    one time), at the scan's own time: each scan placed as a geolocation request (method "locate"), or the
    EKF, FEKF or FCS of Bouzera et al. 2017 over time.

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
    if filt is locate_cells:
        return _track_located(track_id, rows, cells, options)
    # co-sited cells (sector antennas on one mast) are one station: their ranges combine (geometric mean)
    ids = list(pd.unique(rows["cell_id"]))
    tab = cells.loc[ids]
    site_of, sites = _sites(tab["lat"].to_numpy(float), tab["lon"].to_numpy(float))
    frame = LocalFrame(float(sites[:, 0].mean()), float(sites[:, 1].mean()))
    se, sn = frame.to_enu(sites[:, 0], sites[:, 1])
    stations = np.column_stack([se, sn]) / 1e3
    r = ranges_km(rows, cells, options.path_loss)
    cell_site = dict(zip(ids, site_of))
    scans = pd.DataFrame({"t": rows["t"].to_numpy(float), "site": [cell_site[c] for c in rows["cell_id"]],
                          "logr": np.log(np.where(r > 0, r, np.nan))})
    z_scan = np.exp(scans.pivot_table(index="t", columns="site", values="logr", aggfunc="mean", dropna=False)
                    .reindex(columns=range(len(sites))).to_numpy(float))
    t_scan = np.unique(scans["t"].to_numpy())
    # a grid fine enough that (almost) every scan has its own slot; the points written are the scans'
    gaps = np.diff(t_scan)
    median = float(np.median(gaps)) if len(gaps) else 1.0
    dt = options.scan_interval_s or (min(median, max(float(gaps.min()), median / 10.0)) if len(gaps) else 1.0)
    bins = np.rint((t_scan - t_scan[0]) / dt).astype(np.int64)
    sums = np.zeros((bins[-1] + 1, len(sites)))
    counts = np.zeros_like(sums)
    np.add.at(sums, bins, np.nan_to_num(z_scan))  # scans falling in one slot: mean range per station
    np.add.at(counts, bins, np.isfinite(z_scan))
    z = np.divide(sums, counts, out=np.full_like(sums, np.nan), where=counts > 0)
    seen = np.isfinite(z[0])
    start = stations[seen].mean(axis=0) if seen.any() else stations.mean(axis=0)
    if options.motion == "cv":
        # the project's one constant-velocity state order, [x, vx, y, vy] (km, km/s)
        x0, P0 = np.array([start[0], 0.0, start[1], 0.0]), np.diag([1.0, 1e-4, 1.0, 1e-4])
        Q = constant_velocity_continuous(options.cell_q_km2, axes=2).discretize(dt).Q
    else:  # the random walk's q is per scan: per slot, its share of the median scan interval
        x0, P0, Q = start, np.eye(2), options.cell_q_km2 * min(1.0, dt / median) * np.eye(2)
    # the filters' prior is one step before z[0]
    res = filt(z, stations, x0, P0, Q, options.r_km2, motion=options.motion, dt=dt)
    slot = np.unique(bins)                                     # the slots holding scans, in time order
    first = np.searchsorted(bins, slot)                         # ... and the time of each one's first scan
    nis, dof = res.nis[slot], np.isfinite(res.innovation[slot]).sum(axis=1)
    pos = list(motion_position(options.motion, 2))
    x = res.x[slot]
    vel = x[:, [1, 3]] * 1e3 if options.motion == "cv" else None
    P2 = res.P[slot][:, pos][:, :, pos] * 1e6
    t_out = t_scan[first]
    extra = {"n_cells": np.isfinite(z[slot]).sum(axis=1)}
    return _points(track_id, rows, t_out, x[:, pos[0]] * 1e3, x[:, pos[1]] * 1e3, vel, P2[:, 0, 0], P2[:, 0, 1],
                   P2[:, 1, 1], nis, dof, frame, f"{options.method.upper()}-{options.motion}", max(options.gap_s,
                                                                                                  1.5 * median), extra)


def _points(track_id, rows, t, east, north, vel, var_e, cov_en, var_n, nis, dof, frame, method, gap_s, extra):
    flags = np.zeros(len(t), dtype=np.int8)
    return point_table([track_id], np.array([0, len(t)]), _time_like(t, time_values(rows["time"])), t, east, north,
                       vel, var_e, cov_en, var_n, nis, dof, flags, gap_s, (np.array([frame.lat0]), np.array([frame.lon0])),
                       method, extra).to_pandas()


def _sites(lat: np.ndarray, lon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(site index of each cell, site positions (k, 2) lat/lon): cells within 1 m of each other share a site."""
    east = np.radians(lon - lon[0]) * 6_371_008.8 * np.cos(np.radians(lat[0]))
    north = np.radians(lat - lat[0]) * 6_371_008.8
    site = np.full(len(lat), -1)
    out = []
    for i in range(len(lat)):
        if site[i] < 0:
            same = (np.hypot(east - east[i], north - north[i]) <= 1.0) & (site < 0)
            site[same] = len(out)
            out.append((lat[i], lon[i]))
    return site, np.array(out)


def _track_located(track_id: str, rows: pd.DataFrame, cells: pd.DataFrame, options: TrackOptions) -> pd.DataFrame:
    """Each scan located as POST /v1/geolocate locates a request (:func:`mptrack.cellular.locate_cells`): its
    cells in the order of the log (a phone logs its serving cell first), their levels and timing advances,
    the table's path-loss fit per area; the point's covariance the posterior's."""
    if "range_m" in rows.columns and rows["range_m"].notna().any():
        raise ParameterError("rows.range_m: the locate method reads levels (rss_dbm) and timing advances (ta); "
                             "measured ranges go through the range filters (method ekf, fekf or fcs)")
    table = _cell_models(cells.loc[pd.unique(rows["cell_id"])])
    t = rows["t"].to_numpy(float)
    cols = table.loc[rows["cell_id"]]
    rss = rows["rss_dbm"].to_numpy(float) if "rss_dbm" in rows.columns else np.full(len(rows), np.nan)
    ta = rows["ta"].to_numpy(float) if "ta" in rows.columns else np.full(len(rows), np.nan)
    arr = np.column_stack([cols[c].to_numpy(float) for c in CELL_FIELDS[:11]] + [rss, ta])
    t_scan, first = np.unique(t, return_index=True)
    fix = locate_cells(arr, np.r_[first, len(t)])
    frame = LocalFrame(float(fix[:, 0].mean()), float(fix[:, 1].mean()))
    east, north = frame.to_enu(fix[:, 0], fix[:, 1])
    gaps = np.diff(t_scan)
    gap_s = max(options.gap_s, 1.5 * float(np.median(gaps))) if len(gaps) else options.gap_s
    nan = np.full(len(t_scan), np.nan)
    return _points(track_id, rows, t_scan, east, north, None, fix[:, 3], fix[:, 4], fix[:, 5], nan,
                   np.zeros(len(t_scan)), frame, "LOCATE", gap_s,
                   {"n_cells": np.diff(np.r_[first, len(t)]), "sites": fix[:, 6].astype(np.int64),
                    "accuracy68_m": fix[:, 2]})


def _radio_codes(tab: pd.DataFrame) -> np.ndarray:
    """The radio codes (RADIOS) of the cells of a table; DataError naming an unknown radio."""
    codes = []
    for cell_id, r in tab["radio"].items():
        code = RADIO_CODES.get(str(r).strip(), RADIO_CODES.get(str(r).strip().lower()))
        if code is None:
            raise DataError(f"radio {r!r} of cell {cell_id} is not one of GSM, UMTS, LTE, NR, CDMA", column="radio")
        codes.append(code)
    return np.array(codes, dtype=float)


def _cell_models(tab: pd.DataFrame) -> pd.DataFrame:
    """The columns CELL_FIELDS[:11] of the cells of a table (read_cells): the prior path loss of each
    cell's radio and height, the fit of its area from averageSignal/range."""
    radio = _radio_codes(tab)

    def col(name):
        return tab[name].to_numpy(float) if name in tab.columns else np.full(len(tab), np.nan)

    a0, n0 = signal_prior(radio, col("height_m"))
    fit = signal_fit(a0, n0, col("range"), col("averageSignal"), col("samples"))
    keys = pd.DataFrame({"r": radio, "m": col("mcc"), "n": col("net"), "a": col("area"), "fit": fit})
    grouped = keys.groupby(["r", "m", "n", "a"])["fit"]
    area_n = grouped.transform("count").to_numpy(float)
    area_off = grouped.transform("mean").to_numpy(float)
    out = pd.DataFrame({"lat": col("lat"), "lon": col("lon"), "radio": radio, "intercept_dbm": a0, "slope_db": n0,
                        "fit_offset_db": fit, "area_fits": area_n, "area_offset_db": area_off,
                        "range_m": col("range"), "changeable": col("changeable"), "azimuth_deg": col("azimuth_deg")},
                       index=tab.index)
    return out
