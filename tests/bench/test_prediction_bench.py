"""The prediction/smoothing bench suite runs and checks its peer before timing it."""

from mptrack.bench import run_suites


def test_prediction_suite_quick():
    (report,) = run_suites(["prediction"], quick=True)
    assert report["suite"] == "prediction"
    names = [row[0] for row in report["rows"]]
    assert "SS predictor N=5, eq. 19 (A_N, B_N)" in names and "rts_smoother on a KF result" in names
    for row in report["rows"]:
        assert len(row) == len(report["columns"]) and row[1] > 0
