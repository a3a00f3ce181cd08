"""Gaps: a gap longer than ``max_gap_s`` (default 600 s) starts a new segment, and at any gap length the
first fix after it keeps the variance of its own error -- the update stays accurate when the prediction's
variance is 10^19 times the fix's (the first fix after a 3-day gap had var_east_m2 = 0)."""

import numpy as np
import pandas as pd
import pytest

from mptrack.tracking import track

GAPS = {"1 h": 3600.0, "1 d": 86400.0, "30 d": 30 * 86400.0}


def gap_track(gap_s: float, sigma: float = 1.0) -> pd.DataFrame:
    """120 fixes of a walk at 1.5 m/s, one a second, with a gap of ``gap_s`` after the 60th (the walk goes on
    from where it was, in another direction)."""
    rng = np.random.default_rng(int(gap_s) % 1000)
    t = np.r_[np.arange(60.0), 59.0 + gap_s + np.arange(60.0)]
    x = np.r_[1.5 * np.arange(60.0), 90.0 + np.zeros(60)]
    y = np.r_[np.zeros(60), 1.5 * np.arange(60.0)]
    return pd.DataFrame({"track_id": "walk", "time": t, "x": x + rng.normal(0, sigma, 120),
                         "y": y + rng.normal(0, sigma, 120)})


@pytest.mark.parametrize("bridge", [False, True])
@pytest.mark.parametrize("gap", sorted(GAPS))
def test_the_first_fix_after_a_gap_keeps_its_error(gap, bridge):
    """Default: the fix after the gap starts a new segment (flag init) with the variance of its error, white
    and slow; bridged (max_gap_s=inf), the filter predicts over the gap and the update leaves that same
    variance (the slow error has decorrelated), not 0."""
    points = track(gap_track(GAPS[gap]), **({"max_gap_s": np.inf} if bridge else {}))
    tr = points.attrs["tracks"].iloc[0]
    after = points.iloc[60]
    assert after["flag"] == ("update" if bridge else "init") and points["gap"].iloc[60]
    expected = tr["sigma_m"] ** 2 + tr["sigma_slow_m"] ** 2
    assert after["var_east_m2"] == pytest.approx(expected, rel=1e-3)
    assert after["var_north_m2"] == pytest.approx(expected, rel=1e-3)
    assert after["ell_major_m"] > 0 and np.isfinite(points[["var_east_m2", "east_m", "lat"]].fillna(0)).all().all()
    assert (points["flag"] != "reset").all() and (points["flag"].iloc[61:] == "update").mean() > 0.9


def test_a_gap_shorter_than_max_gap_is_bridged():
    points = track(gap_track(300.0))
    assert points["flag"].iloc[60] != "init" and (points["flag"] == "init").sum() == 1
    points = track(gap_track(300.0), max_gap_s=120.0)
    assert points["flag"].iloc[60] == "init"
