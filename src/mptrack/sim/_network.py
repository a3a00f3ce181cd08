"""A simulated cellular network with a crowd-sourced cell table, and phones' scans of it: the test bed of
cell geolocation where the truth is known.

Sites on a hexagonal grid (``rings`` rings around a centre site, ``isd_m`` apart), each with three sector
cells (azimuths 0/120/240 degrees + a random rotation per site); each cell has its own effective
radiated power (N(eirp_dbm, 3 dB)) and antenna height (20..50 m), which the cell table does not give:
the transmitters' parameters are unknown to the geolocation.  A phone at distance d from a site hears
each of its cells at

    level = EIRP - L_COST231-Hata(d; 1800 MHz, h, 1.5 m, medium city) + offset_db
            + G(theta) + u_site + e_cell

with the 3GPP sector pattern G = -min(12 (dtheta / 65 deg)^2, 20 dB) (TR 36.942), u_site ~ N(0, 7 dB)
shared by the site's cells and e_cell ~ N(0, 4 dB) (8 dB of shadowing in all), ``offset_db`` a network-wide
offset of the whole propagation (the environment the model does not know).  It reports the ``max_cells``
strongest cells above ``sensitivity_dbm`` (the strongest first, as a phone lists its serving cell).

The cell table is what a crowd of ``crowd`` phones at random positions in the network would build, in
the OpenCelliD layout: each cell's exact position (changeable 0), ``samples`` (how many phones heard
it), ``averageSignal`` (their mean level) and ``range`` (the distance holding 95 % of them), and the
sector ``azimuth_deg``.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .._core.validation import as_array, as_real, check_int, check_rng
from ..errors import ParameterError
from ..radio import cost231_hata

__all__ = ["simulate_network", "network_scans"]

EARTH_M = 6_371_008.8
_SITE_DB, _CELL_DB = 7.0, 4.0


def _layout(rings: int, isd: float) -> np.ndarray:
    """Hexagonal site positions (east, north) in metres: the centre and ``rings`` rings around it."""
    pts = []
    for q in range(-rings, rings + 1):
        for r in range(max(-rings, -q - rings), min(rings, -q + rings) + 1):
            pts.append((isd * (q + r / 2.0), isd * r * math.sqrt(3.0) / 2.0))
    return np.array(pts)


def simulate_network(rng, *, rings: int = 2, isd_m: float = 1000.0, eirp_dbm: float = 27.0, offset_db: float = 0.0,
                     crowd: int = 2000, max_cells: int = 7, sensitivity_dbm: float = -120.0,
                     lat0: float = 50.85, lon0: float = 4.35, mcc: int = 999, mnc: int = 1, area: int = 1,
                     sectors: bool = True):
    """A simulated LTE network (see the module doc) and its crowd-sourced cell table.

    Parameters
    ----------
    rng : numpy.random.Generator or int
        The source of randomness.
    rings : int, optional
        Rings of sites around the centre site (2: 19 sites).
    isd_m : float, optional
        Distance between neighbouring sites (m).
    eirp_dbm : float, optional
        Mean radiated power of a cell (each cell's drawn around it, 3 dB).
    offset_db : float, optional
        Offset of the whole propagation (an environment the models do not know).
    crowd : int, optional
        Phones at random positions that build the table.
    max_cells : int, optional
        The strongest cells a phone reports.
    sensitivity_dbm : float, optional
        The weakest level a phone reports.
    lat0, lon0 : float, optional
        The network's centre (degrees).
    mcc, mnc, area : int, optional
        The network's identity (every cell in one area).
    sectors : bool, optional
        False: the three cells of a site are omnidirectional (no pattern, azimuth_deg empty).

    Returns
    -------
    table : pandas.DataFrame
        The OpenCelliD layout (radio, mcc, net, area, cell, unit, lon, lat, range, samples, changeable,
        created, updated, averageSignal) plus ``azimuth_deg``, the cells heard by the crowd.  Cell ids are
        eNB x 256 + sector (eNB = 1000 + site index).
    network : dict
        The cells' true parameters, which :func:`network_scans` reads.
    """
    rng = check_rng(rng)
    rings = check_int("rings", rings, minimum=0, maximum=10)
    isd = as_real("isd_m", isd_m, low=50.0, high=1e5)
    eirp = as_real("eirp_dbm", eirp_dbm, low=-30.0, high=90.0)
    offset = as_real("offset_db", offset_db, low=-40.0, high=40.0)
    crowd = check_int("crowd", crowd, minimum=1, maximum=10**7)
    sites = _layout(rings, isd)
    ns = len(sites)
    if not isinstance(sectors, (bool, np.bool_)):
        raise ParameterError(f"sectors: expected True or False, got {sectors!r}")
    rot = rng.uniform(0.0, 120.0, ns)
    az = (rot[:, None] + np.array([0.0, 120.0, 240.0])) % 360.0 if sectors else np.full((ns, 3), np.nan)
    cells_e = np.repeat(sites[:, 0], 3)
    cells_n = np.repeat(sites[:, 1], 3)
    net = {"east": cells_e, "north": cells_n, "site": np.repeat(np.arange(ns), 3), "azimuth_deg": az.ravel(),
           "eirp_dbm": rng.normal(eirp, 3.0, 3 * ns), "height_m": rng.uniform(20.0, 50.0, 3 * ns),
           "offset_db": offset, "lat0": as_real("lat0", lat0, low=-80.0, high=80.0),
           "lon0": as_real("lon0", lon0, low=-180.0, high=180.0), "max_cells": check_int("max_cells", max_cells,
                                                                                          minimum=1, maximum=64),
           "sensitivity_dbm": as_real("sensitivity_dbm", sensitivity_dbm, low=-200.0, high=0.0),
           "cell": (1000 + np.repeat(np.arange(ns), 3)) * 256 + np.tile(np.arange(3), ns),
           "mcc": check_int("mcc", mcc, minimum=0, maximum=999), "mnc": check_int("mnc", mnc, minimum=0, maximum=999),
           "area": check_int("area", area, minimum=0)}
    # the crowd: random positions over the network (as far out as the outer ring)
    span = max(rings, 0.5) * isd
    pe, pn = rng.uniform(-span, span, crowd), rng.uniform(-span, span, crowd)
    heard, levels = _hear(net, pe, pn, rng)
    d = np.hypot(pe[:, None] - cells_e, pn[:, None] - cells_n)
    samples = heard.sum(axis=0)
    avg = np.where(samples > 0, np.where(heard, levels, 0.0).sum(axis=0) / np.maximum(samples, 1), 0.0)
    rng95 = np.array([np.percentile(d[heard[:, j], j], 95) if samples[j] else np.nan for j in range(3 * ns)])
    lat, lon = _geodetic(net, cells_e, cells_n)
    table = pd.DataFrame({"radio": "LTE", "mcc": net["mcc"], "net": net["mnc"], "area": net["area"],
                          "cell": net["cell"], "unit": np.arange(3 * ns) % 504, "lon": lon, "lat": lat,
                          "range": np.round(rng95), "samples": samples, "changeable": 0,
                          "created": 1_700_000_000, "updated": 1_760_000_000,
                          "averageSignal": np.round(avg), "azimuth_deg": net["azimuth_deg"]})
    return table[samples > 0].reset_index(drop=True), net


def _levels(net: dict, pe: np.ndarray, pn: np.ndarray, rng) -> np.ndarray:
    """(points, cells) levels in dBm of phones at (pe, pn) (metres from the network's centre)."""
    de = pe[:, None] - net["east"]
    dn = pn[:, None] - net["north"]
    d_km = np.maximum(np.hypot(de, dn), 20.0) / 1000.0
    loss = cost231_hata(d_km, 1800.0, h_base_m=np.broadcast_to(net["height_m"], d_km.shape), on_invalid="ignore")
    bearing = np.degrees(np.arctan2(de, dn))
    off = np.abs((bearing - net["azimuth_deg"] + 540.0) % 360.0 - 180.0)
    gain = np.where(np.isnan(off), 0.0, -np.minimum(12.0 * (off / 65.0) ** 2, 20.0))
    ns = int(net["site"].max()) + 1
    site_shadow = rng.normal(0.0, _SITE_DB, (len(pe), ns))[:, net["site"]]
    return net["eirp_dbm"] - loss + net["offset_db"] + gain + site_shadow + rng.normal(0.0, _CELL_DB, d_km.shape)


def _hear(net: dict, pe, pn, rng) -> tuple[np.ndarray, np.ndarray]:
    """(heard mask, levels) of phones at (pe, pn): the max_cells strongest above the sensitivity."""
    levels = _levels(net, pe, pn, rng)
    k = min(net["max_cells"], levels.shape[1])
    kth = -np.partition(-levels, k - 1, axis=1)[:, k - 1:k]
    return (levels >= kth) & (levels >= net["sensitivity_dbm"]), levels


def _geodetic(net: dict, east, north) -> tuple[np.ndarray, np.ndarray]:
    lat = net["lat0"] + np.degrees(np.asarray(north) / EARTH_M)
    lon = net["lon0"] + np.degrees(np.asarray(east) / (EARTH_M * math.cos(math.radians(net["lat0"]))))
    return lat, lon


def network_scans(network: dict, east_m, north_m, rng) -> pd.DataFrame:
    """Scans of phones at given positions in a simulated network.

    Parameters
    ----------
    network : dict
        The network of :func:`simulate_network`.
    east_m, north_m : array_like
        The phones' positions (m from the network's centre).
    rng : numpy.random.Generator or int
        The source of the shadowing.

    Returns
    -------
    pandas.DataFrame
        One row per cell heard: ``scan`` (the index of the position), ``true_lat``/``true_lon``, the cell's
        ``radio``, ``mcc``, ``mnc``, ``area``, ``cell`` and its ``rss_dbm``, the strongest first within a
        scan.  Positions where no cell is heard have no rows.
    """
    if not isinstance(network, dict) or "eirp_dbm" not in network:
        raise ParameterError("network: expected the network of simulate_network")
    rng = check_rng(rng)
    pe = as_array("east_m", east_m, ndim=1, low=-1e7, high=1e7)
    pn = as_array("north_m", north_m, ndim=1, low=-1e7, high=1e7)
    if len(pe) != len(pn):
        raise ParameterError(f"north_m: expected {len(pe)} values (as east_m), got {len(pn)}")
    heard, levels = _hear(network, pe, pn, rng)
    scan, cell = np.nonzero(heard)
    lv = levels[scan, cell]
    order = np.lexsort((-lv, scan))
    scan, cell, lv = scan[order], cell[order], lv[order]
    lat, lon = _geodetic(network, pe, pn)
    return pd.DataFrame({"scan": scan, "true_lat": lat[scan], "true_lon": lon[scan], "radio": "lte",
                         "mcc": network["mcc"], "mnc": network["mnc"], "area": network["area"],
                         "cell": network["cell"][cell], "rss_dbm": np.round(lv)})
