"""Synthetic logs with truth: GPS fixes or cellular RSS scans, on simulated or real trajectories.

Scenarios (by name, :data:`SCENARIOS`):

* ``gps``        position fixes at irregular times (exponential intervals, mean 2 s, at least 0.2 s),
                 Gaussian noise of ``accuracy_m`` (5 m) per axis, 2 % outliers displaced 50-150 m.
* ``urban-3bts`` three base stations on a 1 km circle around the start (120 deg apart); every second
                 each station's RSS = P_tx - L(d) + N(0, 4 dB) shadowing, L the COST-231 Walfisch-Ikegami
                 NLOS loss (h_base 30 m, DCS 1800 ARFCN 700 = 1842.8 MHz, P_tx 43 dBm); cell table in
                 the OpenCelliD layout.

Truth is a constant-velocity trajectory (white acceleration density 0.5 m^2/s^3, start speed
10 m/s) or, with ``along=``, the tracks of a real position-fix file (time stamps and positions
taken from it).  Every random draw comes from the Generator passed in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from .._validation import check_int
from ..errors import UnknownNameError
from ..io import FIXES, LocalFrame, iter_tracks
from ..radio import arfcn_to_frequency, path_loss

__all__ = ["SCENARIOS", "simulate", "Scenario", "ORIGIN"]

#: Default origin of simulated tracks (Visnjan, Istria: where the bundled real trace is).
ORIGIN = (45.2735, 13.7142)
_EPOCH = pd.Timestamp("2024-01-01T00:00:00Z")


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    run: Callable


def _cv_truth(rng: np.random.Generator, t: np.ndarray, q: float = 0.5, speed: float = 10.0) -> np.ndarray:
    """(T, 2) east/north positions of a CV trajectory sampled at times t (exact discretisation per step)."""
    from ..models import constant_velocity_continuous

    model = constant_velocity_continuous(q, axes=2)
    heading = rng.uniform(0, 2 * np.pi)
    x = np.array([0.0, speed * np.sin(heading), 0.0, speed * np.cos(heading)])
    out = np.empty((len(t), 2))
    prev = t[0]
    for k, tk in enumerate(t):
        if tk > prev:
            d = model.discretize(tk - prev)
            x = d.F @ x + rng.multivariate_normal(np.zeros(4), d.Q, method="cholesky")
        out[k] = x[[0, 2]]
        prev = tk
    return out


def _trajectories(rng, tracks: int, duration_s: float, along, irregular: bool):
    """Yield (track_id, t seconds, frame, east/north truth) — simulated, or the real tracks of ``along``."""
    if along is not None:
        for tid, rows in iter_tracks(along, FIXES):
            frame = LocalFrame.at(rows["lat"], rows["lon"])
            e, n = frame.to_enu(rows["lat"].to_numpy(), rows["lon"].to_numpy())
            yield tid, rows["t"].to_numpy(float), frame, np.column_stack([e, n])
        return
    frame = LocalFrame(*ORIGIN)
    for i in range(tracks):
        if irregular:
            t = np.cumsum(np.maximum(rng.exponential(2.0, size=int(duration_s)), 0.2))
            t = t[t <= duration_s]
        else:
            t = np.arange(1.0, duration_s + 1.0)
        t = t + _EPOCH.timestamp() + 3600.0 * i
        yield f"sim{i + 1:04d}", t, frame, _cv_truth(rng, t)


def _times(t: np.ndarray) -> pd.Series:
    return pd.Series(pd.to_datetime(np.rint(t * 1e3).astype("int64"), unit="ms", utc=True)).dt.strftime(
        "%Y-%m-%dT%H:%M:%S.%fZ")


def _gps(rng, tracks, duration_s, along, accuracy_m: float = 5.0, outlier_rate: float = 0.02):
    frames = []
    for tid, t, frame, xy in _trajectories(rng, tracks, duration_s, along, irregular=True):
        z = xy + rng.normal(0.0, accuracy_m, size=xy.shape)
        out = rng.random(len(t)) < outlier_rate
        ang = rng.uniform(0, 2 * np.pi, size=len(t))
        dist = rng.uniform(50.0, 150.0, size=len(t))
        z[out] += np.column_stack([np.sin(ang[out]), np.cos(ang[out])]) * dist[out, None]
        lat, lon = frame.to_geodetic(z[:, 0], z[:, 1])
        tlat, tlon = frame.to_geodetic(xy[:, 0], xy[:, 1])
        frames.append(pd.DataFrame({"track_id": tid, "time": _times(t), "lat": lat, "lon": lon,
                                    "accuracy_m": accuracy_m, "true_lat": tlat, "true_lon": tlon,
                                    "is_outlier": out}))
    return pd.concat(frames, ignore_index=True), None


def _urban_3bts(rng, tracks, duration_s, along, radius_m: float = 1000.0, shadowing_db: float = 4.0,
                power_dbm: float = 43.0, height_m: float = 30.0, arfcn: int = 700):
    frequency_mhz = float(arfcn_to_frequency(arfcn, "DCS1800"))
    frames, cells = [], []
    for i, (tid, t, frame, xy) in enumerate(_trajectories(rng, tracks, duration_s, along, irregular=False)):
        centre = xy.mean(axis=0)
        ang = rng.uniform(0, 2 * np.pi) + np.array([0.0, 2.0, 4.0]) * np.pi / 3
        st = centre + radius_m * np.column_stack([np.sin(ang), np.cos(ang)])
        slat, slon = frame.to_geodetic(st[:, 0], st[:, 1])
        ids = [(262, 1, 100 + i, 10 * i + j + 1) for j in range(3)]
        for (mcc, net, area, cell), la, lo in zip(ids, slat, slon):
            cells.append({"radio": "GSM", "mcc": mcc, "net": net, "area": area, "cell": cell, "unit": 0,
                          "lon": lo, "lat": la, "range": 3000, "samples": 1, "changeable": 1,
                          "created": 0, "updated": 0, "averageSignal": 0, "height_m": height_m,
                          "power_dbm": power_dbm, "arfcn": arfcn})
        d_km = np.linalg.norm(xy[:, None, :] - st[None], axis=-1) / 1e3
        loss = path_loss(np.clip(d_km, 0.02, 5.0), "cost231-wi-nlos", frequency_mhz=frequency_mhz,
                         h_base_m=height_m, on_invalid="ignore")
        rss = power_dbm - loss + rng.normal(0.0, shadowing_db, size=loss.shape)
        tlat, tlon = frame.to_geodetic(xy[:, 0], xy[:, 1])
        T = len(t)
        frames.append(pd.DataFrame({
            "track_id": tid, "time": np.repeat(_times(t).to_numpy(), 3),
            "cell_id": [f"{m}-{n}-{a}-{c}" for _ in range(T) for (m, n, a, c) in ids],
            "rss_dbm": rss.ravel(), "true_lat": np.repeat(tlat, 3), "true_lon": np.repeat(tlon, 3),
            "true_range_m": d_km.ravel() * 1e3}))
    return pd.concat(frames, ignore_index=True), pd.DataFrame(cells)


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("gps", "GPS fixes at irregular times, 5 m noise, 2 % outliers", _gps),
    Scenario("urban-3bts", "RSS from 3 base stations (COST-231 WI NLOS, 4 dB shadowing), 1 s scans",
             _urban_3bts),
)}


def simulate(scenario: str, tracks: int, rng: np.random.Generator, *, duration_s: float = 300.0,
             along=None) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """(log with truth columns, cell table or None) of ``scenario`` (see the module doc)."""
    if scenario not in SCENARIOS:
        raise UnknownNameError(f"scenario: unknown name {scenario!r}; known: {', '.join(SCENARIOS)}")
    tracks = check_int("tracks", tracks, minimum=1)
    return SCENARIOS[scenario].run(rng, tracks, float(duration_s), along)
