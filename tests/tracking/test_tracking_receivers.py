"""Real consumer receivers, tracked with no flags: an uncertainty that describes the error against the truth,
no restarts on clean continuous logs, never a track worse than the raw fixes.

The logs: the Garmin 1 Hz bike ride, the eTrex car drive and the hike of tests/data; a phone's GPX of a bus
journey (~1 s), a GeoLife extract, and three static receivers' NMEA logs (u-blox NEO-M9N, Quectel L76K at
5 Hz, SiRFstar V) from ../shared/data/receivers (README there).  The static receivers did not move: the
spread of their fixes is their own error, and their median position is the best stand-in for the truth.
"""

import warnings

import numpy as np
import pandas as pd
import pytest

from _data import REAL_TRACES, shared_data
from mptrack.tracking import track

MOVING = {"bike": lambda: REAL_TRACES["bike"], "car": lambda: REAL_TRACES["car"], "hike": lambda: REAL_TRACES["hike"],
          "bus": lambda: shared_data("receivers", "bus-304-to-UL.gpx")}
STATIC = {"u-blox": "gpsd-ublox-neo-m9n-nmea.log", "quectel": "gpsd-quectel-l76k-nmea.log",
          "sirf": "gpsd-sirfstarv-nmea.log"}
CLEAN = {**MOVING, **{name: (lambda f=f: shared_data("receivers", f)) for name, f in STATIC.items()}}

_CACHE = {}


def tracked(name: str, smooth: bool = False) -> pd.DataFrame:
    """The point table of a clean log (or GeoLife's, read as lon/lat), tracked with no flags (cached)."""
    if (name, smooth) not in _CACHE:
        if name == "geolife":
            raw = pd.read_csv(shared_data("receivers", "demodata_geolife.csv"), sep=";")
            data = pd.DataFrame({"track_id": raw["trajectory_id"].astype(str), "lat": raw["Y"], "lon": raw["X"],
                                 "time": pd.to_datetime(raw["t"], utc=True)})
        else:
            data = CLEAN[name]()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # the readers' notes on the files
            _CACHE[name, smooth] = track(data, smooth=smooth)
    return _CACHE[name, smooth]


def fastest_steps(points: pd.DataFrame) -> tuple[float, float]:
    """(fastest estimated step, fastest raw step) in m/s between consecutive kept fixes (not outliers) of each
    track."""
    est, raw = 0.0, 0.0
    for _, g in points[points["flag"] != "outlier"].groupby("track_id", sort=False):
        dt = np.diff(g["t"].to_numpy())
        ok = dt > 0
        for cols, acc in ((("east_m", "north_m"), "est"), (("meas_east_m", "meas_north_m"), "raw")):
            step = np.hypot(*(np.diff(g[c].to_numpy()) for c in cols))[ok] / dt[ok]
            if step.size:
                if acc == "est":
                    est = max(est, float(step.max()))
                else:
                    raw = max(raw, float(step.max()))
    return est, raw


def one_sigma(points: pd.DataFrame) -> np.ndarray:
    """The reported 1-sigma per axis of each estimate (m)."""
    return np.sqrt(0.5 * (points["var_east_m2"] + points["var_north_m2"]).to_numpy())


@pytest.mark.parametrize("name", sorted(CLEAN))
def test_the_reported_uncertainty_is_metres(name):
    """Consumer receivers are wrong by metres: the reported 1-sigma is metres (it was 1 mm on the smoothing
    receivers, the white noise between their fixes), from their stated accuracy where they give one."""
    sigma = one_sigma(tracked(name))
    assert 1.0 <= np.median(sigma) <= 20.0, np.median(sigma)
    assert np.isfinite(sigma).all() and sigma.min() > 0.5


@pytest.mark.parametrize("name", sorted(STATIC))
def test_a_static_receivers_ellipses_hold_its_median_position(name):
    """The 95 % ellipse of at least 80 % of the estimates holds the receiver's median position (2-54 % with a
    white fix error alone)."""
    p = tracked(name)
    de = (p["east_m"] - p["meas_east_m"].median()).to_numpy()
    dn = (p["north_m"] - p["meas_north_m"].median()).to_numpy()
    ve, vn, c = p["var_east_m2"].to_numpy(), p["var_north_m2"].to_numpy(), p["cov_en_m2"].to_numpy()
    m2 = (vn * de * de - 2 * c * de * dn + ve * dn * dn) / (ve * vn - c * c)
    assert np.mean(m2 <= -2 * np.log(0.05)) >= 0.8


@pytest.mark.parametrize("name", sorted(CLEAN))
def test_no_restarts_on_a_clean_continuous_log(name):
    """At most one restart per 2000 fixes (the bike ride restarted 3 times at its sharp turns, the SiRF
    receiver 5 times in 59 fixes on its quantised positions)."""
    p = tracked(name)
    tracks = p.attrs["tracks"]
    assert tracks["restarts"].sum() <= len(p) / 2000, tracks[["track_id", "fixes", "restarts"]]


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("name", sorted(CLEAN))
def test_no_estimated_step_is_faster_than_the_fastest_raw_step(name, smooth):
    est, raw = fastest_steps(tracked(name, smooth))
    assert est <= raw, (est, raw)


@pytest.mark.parametrize("name", sorted(CLEAN))
def test_the_smoothed_track_stays_within_the_fixes_error(name):
    """Every smoothed estimate lies inside the 99 % circle of the error the model gives its fix (white and
    slow parts: the track table's sigma_m and sigma_slow_m) around that fix."""
    p = tracked(name, smooth=True)
    tr = p.attrs["tracks"].set_index("track_id")
    kept = p[p["flag"] != "outlier"]
    sigma = np.hypot(kept["fix_sigma_m"], kept["track_id"].map(tr["sigma_slow_m"]))
    dist = np.hypot(kept["east_m"] - kept["meas_east_m"], kept["north_m"] - kept["meas_north_m"])
    assert (dist <= np.sqrt(-2 * np.log(0.01)) * sigma).all(), (dist / sigma).max()


def test_geolife_restarts_only_at_its_jumps():
    """GeoLife's trajectories are not clean (fixes that jump 40-90 m/s and back, cold starts, gaps of hours):
    each of its restarts follows fixes whose raw velocity changed by more than 5 m/s^2 (a car's hard braking
    is 8-9 m/s^2; these logs are walks, bikes, buses), and its hours-long gaps start new segments."""
    p = tracked("geolife")
    for _, g in p.groupby("track_id", sort=False):
        g = g.reset_index(drop=True)
        t, e, n = g["t"].to_numpy(), g["meas_east_m"].to_numpy(), g["meas_north_m"].to_numpy()
        v = np.column_stack([np.diff(e), np.diff(n)]) / np.diff(t)[:, None]      # v[i]: fix i -> i + 1
        accel = np.r_[np.nan, np.nan, np.hypot(*np.diff(v, axis=0).T) / np.diff(t)[1:]]   # at fix i + 1
        flags = g["flag"].to_numpy()
        starts = np.flatnonzero((flags == "reset") & np.r_[True, flags[:-1] != "reset"])
        for j in starts:
            first = j
            while first > 0 and flags[first - 1] == "outlier":
                first -= 1
            end = int(np.flatnonzero(flags[j:] != "reset")[0]) + j if (flags[j:] != "reset").any() else len(g)
            assert np.nanmax(accel[first:end]) > 5.0, g.iloc[max(first - 2, 0):end + 1]
        assert (g["flag"][g["t"].diff() > 600] == "init").all()


@pytest.mark.parametrize("smooth", [False, True])
def test_geolife_steps_no_faster_than_its_fixes(smooth):
    """Where GeoLife's fixes jump, a restart takes the new stretch back over the run of rejected fixes (each
    from the filter started at the run's first fix, or taken back to it and updated with its fix): no
    estimated step of a trajectory is more than 0.5 % faster than its fastest raw step (the back-predicted
    run of a restart stepped 18 % faster, 35.0 against 29.8 m/s in trajectory 3), and no kept fix is more
    than 10 m from its estimate (37 m)."""
    p = tracked("geolife", smooth)
    for _, g in p.groupby("track_id", sort=False):
        est, raw = fastest_steps(g)
        assert est <= 1.005 * raw, (g["track_id"].iloc[0], est, raw)
    kept = p[p["flag"] != "outlier"]
    assert np.hypot(kept["east_m"] - kept["meas_east_m"], kept["north_m"] - kept["meas_north_m"]).max() < 10.0
