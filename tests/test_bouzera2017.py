"""The bouzera2017 reproduction: quick run end to end, Table VIII exact, scenario properties."""

import json

import numpy as np
import pytest

from mptrack.experiments import run_experiment
from mptrack.experiments.bouzera2017 import Setup, ranges, simulate, trajectory


def test_quick_reproduction_writes_all_tables_and_figures(tmp_path):
    rep = run_experiment("bouzera2017", tmp_path, quick=True)
    data = json.loads((tmp_path / "bouzera2017" / "results.json").read_text())
    for label in ("Table V", "Table VI", "Table VII", "Table VIII", "Ordering evidence", "Figure 11 data"):
        assert label in data["tables"], label
    for name in ("Figure 9", "Figure 10", "Figure 11", "Figure 12", "Figure 13"):
        assert (tmp_path / "bouzera2017" / data["figures"][name]).stat().st_size > 1000
    assert data["tables"]["Table VIII"]["mismatches"] == []  # RSS -> distance reproduced to 1e-6 km
    t5 = rep.tables["Table V"].rows
    for row in t5:
        assert all(np.isfinite(v) and v > 0 for v in row[1:])
    # FCS is the worst of the three at sigma = 0.001 km, as in the paper
    for row in (t5[0], t5[2]):
        assert row[1] > max(row[2], row[3])
    assert 0 <= rep.tables["Table VI"].rows[0][1] <= 1
    for row in rep.tables["Table VII"].rows:  # the scenario PCRB bounds every filter
        assert row[4] < min(row[1:4])
    # counts: the FEKF cells lost to the EKF are explained by the averaged-gain erratum, the rest is not
    assert data["comparison"] == {"compared": 49, "matched": 24, "differing_explained": 6,
                                  "differing_unexplained": 19}
    assert data["tables"]["Table VI"]["explained_by"] == [[0, 1, "bouzera2017-fekf-averaged-gain"],
                                                          [1, 1, "bouzera2017-fekf-averaged-gain"]]
    assert set(data["errata"]) == {"bouzera2017-fekf-averaged-gain"}


def test_trajectories_and_common_random_numbers():
    setup = Setup(steps=20)
    lin = trajectory(setup, "linear")
    two = trajectory(setup, "two-linear")
    assert lin.shape == (21, 3)
    step = np.linalg.norm(np.diff(lin, axis=0), axis=1)
    np.testing.assert_allclose(step, setup.speed_km_s * setup.dt_s)
    np.testing.assert_allclose(two[:11], lin[:11])
    d1, d2 = np.diff(two[9:12], axis=0)
    assert abs(d1 @ d2) < 1e-12  # a 90-degree turn at mid-track
    seq = np.random.SeedSequence(3)
    a = simulate(setup, "linear", seq, 4)
    b = simulate(setup, "linear", seq, 4)  # reusing a sequence gives the same runs
    np.testing.assert_array_equal(a[2], b[2])
    c = simulate(setup, "linear", seq, 6)  # more runs extend, not reshuffle
    np.testing.assert_array_equal(a[2], c[2][:4])
    assert np.all(a[2][0] != a[2][1])
    z = ranges(setup, a[0], a[2], 0.001)
    assert z.shape == (4, 20, 3) and np.all(z >= 0)


@pytest.mark.slow
def test_full_reproduction_findings(tmp_path):
    """The default 100-run reproduction: what we claim in docs/errata.md holds."""
    rep = run_experiment("bouzera2017", tmp_path)
    t5 = rep.tables["Table V"].rows
    for row in (t5[0], t5[2]):
        fcs, ekf, fekf = row[1:]
        assert ekf < fekf < fcs
    assert abs(t5[0][2] - 0.0518) < 0.005  # the speed was chosen for this
    t7 = {r[0]: r[1:] for r in rep.tables["Table VII"].rows}
    fcs, ekf, fekf, bound = t7["0.5 (one-Linear Traj.)"]
    assert fekf < ekf  # high noise: the FEKF's smaller gain wins
    assert bound < min(fcs, ekf, fekf)
    assert rep.tables["Table VIII"].mismatches() == []
    assert all(r[1] > r[3] for r in rep.tables["Speed sweep (ours)"].rows)  # FCS worst at every speed
    assert all(r[2] < r[3] for r in rep.tables["Speed sweep (ours)"].rows)  # EKF < FEKF at every speed
