"""Reproduction of seed 001 (Assimakis et al. 2016)."""

import json

import numpy as np
import pytest

from mptrack.experiments import run_experiment
from mptrack.experiments.assimakis2016 import (
    READINGS,
    _batch_steady_filter,
    as_one_run,
    axis_model,
    load_published,
    monte_carlo_errors,
    motion_truth,
    percent_absolute_average_error,
)
from mptrack.linear import per_axis, steady_state_filter, steady_state_predictor
from mptrack.riccati import steady_state


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    rep = run_experiment("assimakis2016", out, quick=True)
    return rep, out / "assimakis2016"


def test_quick_run_writes_results_and_figures(quick_run):
    rep, folder = quick_run
    data = json.loads((folder / "results.json").read_text())
    assert data["key"] == "assimakis2016" and data["seed"] == 12345
    for label in ("Table 1", "Table 1 (run-to-run spread)", "Table 1 readings", "Table 1 vs horizon T",
                  "Table 2", "Sweep dt",
                  "Sweep sigma_r2", "Sweep motion", "Sweep N"):
        assert label in data["tables"], label
    for label in ("Figure 1", "Figure 2", "Figure 3", "Figure 4", "Sweep dt", "Sweep sigma_r2",
                  "Sweep motion", "Sweep N"):
        assert (folder / data["figures"][label]).stat().st_size > 10_000
    assert data["tables"]["Table 2"]["mismatches"] == []
    assert len(data["notes"]) == 5


def test_table_2_burden_is_published(quick_run):
    rep, _ = quick_run
    table = rep.tables["Table 2"]
    assert table.rows[0] == ["estimation", 10, 21] and table.rows[1] == ["prediction", 10, 21]
    assert table.mismatches() == []


def test_table_1_is_pinned_and_close_to_the_paper(quick_run):
    """Seed 12345, 40 runs of T = 10^4 steps, percent: our numbers (pinned) and their distance to the paper."""
    rep, _ = quick_run
    table = rep.tables["Table 1"]
    ours = np.array([r[1:] for r in table.rows], dtype=float)
    paper = np.array([r[1:] for r in table.paper], dtype=float)
    np.testing.assert_allclose(ours, [[0.0111, 0.0061], [0.0141, 0.0138], [0.0155, 0.0168],
                                      [0.0164, 0.0186], [0.0170, 0.0198], [0.0176, 0.0207]], atol=1e-12)
    assert np.all(np.abs(ours[:, 0] / paper[:, 0] - 1) < 0.012)     # every CV cell within 1 % (+ rounding)
    assert np.all(np.abs(ours[2:, 1] / paper[2:, 1] - 1) < 0.05)
    # the paper's shape: errors grow with N, CV estimation above CA estimation
    assert np.all(np.diff(ours[:, 0]) > 0) and np.all(np.diff(ours[:, 1]) > 0)
    assert ours[0, 0] > ours[0, 1]
    readings = rep.tables["Table 1 readings"].rows
    assert [r[0] for r in readings] == list(READINGS)
    assert readings[0][1] < 0.011 < 0.05 < readings[1][1]          # worst CV cell: percent fits, fraction not
    # the paper's row passes for one run of our set-up only (40 runs: a rough covariance, a clear verdict)
    p = [r[5] for r in readings]
    assert p[0] > 0.05 and max(p[1:]) < 1e-3, p


def test_as_one_run_measures_the_distance_of_a_table_from_single_runs():
    """A draw of the runs' own law passes; moving one cell of their mean by 3 of its sd costs at least 9
    in d^2 (more when the other cells, correlated with it, stay); a table 1.5 times the mean fails."""
    rng = np.random.default_rng(3)
    L = np.tril(rng.normal(size=(12, 12))) * 0.01 + np.eye(12) * 0.05
    runs = (1.0 + rng.normal(size=(4000, 12)) @ L.T).reshape(-1, 6, 2)
    one = (1.0 + rng.normal(size=12) @ L.T).reshape(6, 2)
    fit = as_one_run(runs, one)
    assert fit["p"] > 0.01 and fit["quantile"].shape == (6, 2)
    off = runs.mean(axis=0) + 0.0
    off[0, 0] += 3.0 * np.sqrt(np.cov(runs.reshape(-1, 12), rowvar=False)[0, 0])
    assert as_one_run(runs, off)["d2"] > 9.0 * 0.9
    assert as_one_run(runs, runs.mean(axis=0) * 1.5)["p"] < 1e-9


def test_published_numbers_file():
    pub = load_published()
    assert pub["table1"]["rows"][0] == ["estimation", 0.0111, 0.0077]
    assert pub["table1"]["rows"][-1] == ["prediction N=5", 0.0177, 0.0209]
    assert pub["table2"]["rows"][0] == ["estimation", 10, 21]


def test_paae_definition():
    truth = np.array([[10.0, 20.0], [20.0, 40.0]])
    est = np.array([[11.0, 18.0], [20.0, 44.0]])
    assert percent_absolute_average_error(truth, est) == pytest.approx(100 * (0.1 + 0.1 + 0.0 + 0.1) / 4)
    with pytest.raises(ValueError, match="estimate"):
        percent_absolute_average_error(truth, est[:1])
    with pytest.raises(ValueError, match="truth"):
        percent_absolute_average_error(np.zeros((2, 2)), est)


def test_motion_truth():
    np.testing.assert_allclose(motion_truth("CV", [20, 30], 1.0, 3), [[20, 30], [40, 60], [60, 90]])
    np.testing.assert_allclose(motion_truth("CA", [2, 3], 0.5, 2), [[0.25, 0.375], [1.0, 1.5]])


def test_batched_monte_carlo_equals_the_library_filters():
    """The experiment's batched loop is the library's steady-state filter / eq.-19 predictor."""
    model = axis_model("CA", 1.0, 0.01, 0.1)
    ss = steady_state(model)
    z = np.random.default_rng(0).normal(size=(3, 50)) + motion_truth("CA", [2.0], 1.0, 50)[:, 0]
    batch = _batch_steady_filter(ss.A, ss.B, z)
    for r in range(3):
        ref = steady_state_filter(model, z[r][:, None], steady=ss).x
        np.testing.assert_allclose(batch[r], ref, rtol=1e-12, atol=1e-12)
        pred = steady_state_predictor(model, z[r][:, None], 3, steady=ss).x
        np.testing.assert_allclose(batch[r] @ np.linalg.matrix_power(model.F, 3).T, pred, rtol=1e-9)


def test_monte_carlo_errors_shape_and_growth():
    res = monte_carlo_errors("CV", [20.0, 30.0], dt=1.0, sigma_q2=0.01, sigma_r2=0.1, steps=100, runs=50,
                             rng=np.random.default_rng(1))
    assert res["paae"].shape == (50, 6) and res["rmse"].shape == (6,)
    assert np.all(np.diff(res["rmse"]) > 0) and np.all(np.diff(res["paae"].mean(axis=0)) > 0)


def test_single_run_uses_the_per_axis_split():
    """Two per-axis filters (the paper's choice) equal the joint block-diagonal filter."""
    from mptrack.models import constant_velocity

    joint = constant_velocity(1.0, 0.01, 2, sigma_r2=0.1)
    z = np.random.default_rng(2).normal(size=(30, 2)) + motion_truth("CV", [20, 30], 1.0, 30)
    a = per_axis(steady_state_filter, axis_model("CV", 1.0, 0.01, 0.1), z).x
    b = steady_state_filter(joint, z).x
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.slow
def test_full_run_monte_carlo_table_1(tmp_path):
    """Default sizes (400 runs of 10^4 steps): 11 of 12 cells within 5 % of the paper; CA estimation
    (0.0065 vs 0.0077) inside the central 95 % of single runs, explained (docs/errata.md): the paper's
    twelve numbers pass for one run of this set-up (p = 0.54) and of no other reading (p < 1e-8); every
    sweep conclusion is as documented."""
    rep = run_experiment("assimakis2016", tmp_path)
    t1 = rep.tables["Table 1"]
    assert t1.mismatches() == [(0, 2)]
    assert t1.explained_by() == [(0, 2, "assimakis2016-table1-single-run")]
    assert [r[1:] for r in t1.rows] == [[0.0111, 0.0065], [0.0141, 0.0141], [0.0155, 0.017], [0.0164, 0.0187],
                                        [0.017, 0.0199], [0.0176, 0.0208]]
    readings = rep.tables["Table 1 readings"].rows
    assert readings[0][1:4] == [0.0099, 0.1576, 11] and readings[1][1:4] == [0.0543, 0.1634, 9]
    assert readings[0][4:] == [10.89, 0.5383, 0.1425]                 # d^2, p, runs within 5 % in all 12 cells
    assert max(r[5] for r in readings[1:]) < 1e-8
    notes = " ".join(rep.notes)
    assert "does not affect the filter': refuted" in notes
    assert "measurement noise covariance increases': supported" in notes
    assert "for the steady-state error" in notes and "grows monotonically with N: True" in notes
