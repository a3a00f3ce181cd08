"""Shared pieces of the cell-geolocation tests: the requests of the real LTE walks and of a simulated
network, and Mozilla's weighted centroid written here from its published description (the baseline the
issue measures against, independent of mptrack.cellular.weighted_centroid).

Ichnaea (mozilla/ichnaea, ``ichnaea/api/locate/cell.py``, ``score.py``; docs/algo): the known cells are
grouped by location area; in a group the position is the centroid of the cells weighted by
score x min(sqrt(2000 / age), 1) / signal^2 (age floored at 1000 ms, a missing signal the radio's minimum,
LTE -140 dBm); one cell alone gives its own position.  The score of a row is
age weight x collection weight x samples weight, here 1 x 1 x clamp(log2(samples), 0.5, 10) (the tables
used here are current).  The group with the largest total score answers.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from _data import shared_data

EARTH_M = 6_371_008.8
LTE_MIN_SIGNAL = -140.0


def distance_m(lat, lon, lat0, lon0) -> np.ndarray:
    """Haversine distance (m)."""
    p, p0 = np.radians(lat), np.radians(lat0)
    a = np.sin((p - p0) / 2) ** 2 + np.cos(p) * np.cos(p0) * np.sin(np.radians(np.asarray(lon) - lon0) / 2) ** 2
    return 2 * EARTH_M * np.arcsin(np.sqrt(a))


def reference_centroid(cells: list[dict]) -> tuple[float, float]:
    """Ichnaea's position of one request: ``cells`` are the known cells, each a dict with lat, lon, area,
    samples (NaN: one), signal (dBm or None), age (ms or None)."""
    groups: dict = {}
    for c in cells:
        groups.setdefault(c["area"], []).append(c)

    def score(c):
        s = 1.0 if c["samples"] != c["samples"] else c["samples"]
        return min(max(math.log2(max(s, 1.0)), 0.5), 10.0)

    best = max(groups.values(), key=lambda g: sum(score(c) for c in g))
    if len(best) == 1:
        return best[0]["lat"], best[0]["lon"]
    w = [score(c) * min(math.sqrt(2000.0 / max(abs(c["age"] or 0), 1000)), 1.0) / (c["signal"] or LTE_MIN_SIGNAL) ** 2
         for c in best]
    total = sum(w)
    return (sum(wi * c["lat"] for wi, c in zip(w, best)) / total,
            sum(wi * c["lon"] for wi, c in zip(w, best)) / total)


def real_requests(ta: bool = True) -> tuple[list[dict], pd.DataFrame, Path]:
    """(geolocate bodies, truth, cell table) of the 953 scans of the real LTE walks: each scan's cells with a
    position in the extract's table, the RSRP as signalStrength (Android's getDbm of an LTE cell) and, with
    ``ta``, Android's fresh timing advance of the serving cell.  truth: track_id, place, lat, lon and the
    reference centroid (ref_lat, ref_lon)."""
    cells_csv = shared_data("cellular", "cells.csv")
    m = pd.read_csv(shared_data("cellular", "measurements.csv"), dtype={"mnc": str})
    cells = pd.read_csv(cells_csv)
    cells.index = (cells.mcc.astype(str) + "-" + cells.net.astype(str) + "-" + cells.area.astype(str) + "-"
                   + cells.cell.astype(str))
    bodies, truth = [], []
    for (track, _), scan in m.groupby(["track_id", "record"], sort=False):
        towers, known = [], []
        for r in scan.itertuples():
            if not isinstance(r.cell_id, str):
                continue
            c = cells.loc[r.cell_id]
            t = {"radioType": "lte", "mobileCountryCode": int(c.mcc), "mobileNetworkCode": int(c.net),
                 "locationAreaCode": int(c.area), "cellId": int(c.cell)}
            signal = None
            if -160 <= r.rsrp_dbm <= -20:
                signal = t["signalStrength"] = int(r.rsrp_dbm)
            if ta and r.role == "serving" and r.ta_android == r.ta_android and r.ta_android < 2**31 - 1:
                t["timingAdvance"] = int(r.ta_android)
            towers.append(t)
            known.append({"lat": c.lat, "lon": c.lon, "area": int(c.area), "samples": c.samples, "signal": signal,
                          "age": None})
        bodies.append({"considerIp": False, "cellTowers": towers})
        ref = reference_centroid(known)
        truth.append((track, track.split("_")[0], scan.lat.iloc[0], scan.lon.iloc[0], *ref))
    return bodies, pd.DataFrame(truth, columns=["track_id", "place", "lat", "lon", "ref_lat", "ref_lon"]), cells_csv


_GRID = np.linspace(-2500.0, 2500.0, 201)


def oracle_levels(network: dict) -> np.ndarray:
    """(grid points, cells): the mean level of every cell of the network at every point of a 201 x 201 grid
    over it (5 km wide), as the simulator draws it before shadowing (mptrack.sim._network: power, COST-231
    Hata with the cell's height, the 3GPP sector pattern)."""
    from mptrack.radio import cost231_hata

    ge, gn = (a.ravel() for a in np.meshgrid(_GRID, _GRID))
    de = ge[:, None] - network["east"]
    dn = gn[:, None] - network["north"]
    d_km = np.maximum(np.hypot(de, dn), 20.0) / 1000.0
    mean = network["eirp_dbm"] + network["offset_db"] - cost231_hata(
        d_km, 1800.0, h_base_m=np.broadcast_to(network["height_m"], d_km.shape), on_invalid="ignore")
    off = np.abs((np.degrees(np.arctan2(de, dn)) - network["azimuth_deg"] + 540.0) % 360.0 - 180.0)
    return mean + np.where(np.isnan(off), 0.0, -np.minimum(12.0 * (off / 65.0) ** 2, 20.0))


def oracle_fix(network: dict, mean: np.ndarray, cells: np.ndarray, levels: np.ndarray) -> tuple[float, float]:
    """(east, north) in metres: the posterior mean of a scan that knows the network exactly -- every cell's
    power, height, pattern and azimuth (``mean``: :func:`oracle_levels`), the path-loss model and the
    shadowing's law (7 dB shared by a site's cells, 4 dB each cell's) -- with a flat prior over the grid.
    The best any method can do with the scan; written here from the simulator's description."""
    ge, gn = (a.ravel() for a in np.meshgrid(_GRID, _GRID))
    site = network["site"][cells]
    cov = 16.0 * np.eye(len(cells)) + 49.0 * (site[:, None] == site[None, :])
    r = levels[None, :] - mean[:, cells]
    ll = -0.5 * np.einsum("gi,ij,gj->g", r, np.linalg.inv(cov), r)
    w = np.exp(ll - ll.max())
    return float(w @ ge / w.sum()), float(w @ gn / w.sum())


def simulated_requests(seed: int, n: int = 1500, azimuth: bool = True, mcc: int = 999, sectors: bool = True,
                       oracle: bool = False) -> tuple[list[dict], pd.DataFrame, pd.DataFrame]:
    """(bodies, truth, cell table) of ``n`` phones at random positions inside a simulated 19-site network
    (mptrack.sim.simulate_network: three cells a site, sectors unless ``sectors`` is False, unknown transmit
    powers and heights, 8 dB of shadowing; the table crowd-sourced, with the sectors' azimuths unless
    ``azimuth`` is False).  truth: lat, lon, the reference centroid (ref_lat, ref_lon) and, with ``oracle``,
    the posterior mean that knows the network (oracle_lat, oracle_lon; :func:`oracle_fix`)."""
    from mptrack.sim import network_scans, simulate_network

    rng = np.random.default_rng(seed)
    table, net = simulate_network(rng, mcc=mcc, sectors=sectors)
    if not azimuth:
        table = table.drop(columns="azimuth_deg")
    east, north = rng.uniform(-1500, 1500, n), rng.uniform(-1500, 1500, n)
    scans = network_scans(net, east, north, rng)
    known = table.set_index("cell")
    index = {c: i for i, c in enumerate(net["cell"])}
    mean = oracle_levels(net) if oracle else None
    k_lat = math.degrees(1.0 / EARTH_M)
    k_lon = k_lat / math.cos(math.radians(net["lat0"]))
    bodies, truth = [], []
    for _, scan in scans.groupby("scan"):
        scan = scan[scan.cell.isin(known.index)]
        if scan.empty:
            continue
        towers = [{"radioType": "lte", "mobileCountryCode": int(r.mcc), "mobileNetworkCode": int(r.mnc),
                   "locationAreaCode": int(r.area), "cellId": int(r.cell), "signalStrength": int(r.rss_dbm)}
                  for r in scan.itertuples()]
        ref = reference_centroid([{"lat": known.lat[r.cell], "lon": known.lon[r.cell], "area": int(r.area),
                                   "samples": float(known.samples[r.cell]), "signal": r.rss_dbm, "age": None}
                                  for r in scan.itertuples()])
        best = (math.nan, math.nan)
        if oracle:
            e, nn = oracle_fix(net, mean, np.array([index[c] for c in scan.cell]), scan.rss_dbm.to_numpy(float))
            best = (net["lat0"] + nn * k_lat, net["lon0"] + e * k_lon)
        bodies.append({"cellTowers": towers})
        truth.append((scan.true_lat.iloc[0], scan.true_lon.iloc[0], *ref, *best))
    return bodies, pd.DataFrame(truth, columns=["lat", "lon", "ref_lat", "ref_lon", "oracle_lat", "oracle_lon"]), table


def write_ndjson(path: Path, bodies: list[dict]) -> Path:
    path.write_text("".join(json.dumps(b) + "\n" for b in bodies))
    return path
