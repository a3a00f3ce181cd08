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


def simulated_requests(seed: int, n: int = 1500, azimuth: bool = True, mcc: int = 999) -> tuple[
        list[dict], pd.DataFrame, pd.DataFrame]:
    """(bodies, truth, cell table) of ``n`` phones at random positions inside a simulated 19-site network
    (mptrack.sim.simulate_network: three sectors a site, unknown transmit powers and heights, 8 dB of
    shadowing; the table crowd-sourced, with the sectors' azimuths unless ``azimuth`` is False)."""
    from mptrack.sim import network_scans, simulate_network

    rng = np.random.default_rng(seed)
    table, net = simulate_network(rng, mcc=mcc)
    if not azimuth:
        table = table.drop(columns="azimuth_deg")
    east, north = rng.uniform(-1500, 1500, n), rng.uniform(-1500, 1500, n)
    scans = network_scans(net, east, north, rng)
    known = table.set_index("cell")
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
        bodies.append({"cellTowers": towers})
        truth.append((scan.true_lat.iloc[0], scan.true_lon.iloc[0], *ref))
    return bodies, pd.DataFrame(truth, columns=["lat", "lon", "ref_lat", "ref_lon"]), table


def write_ndjson(path: Path, bodies: list[dict]) -> Path:
    path.write_text("".join(json.dumps(b) + "\n" for b in bodies))
    return path
