"""The nonlinear bench suite runs quickly and reports every filter with a positive cost."""

from mptrack.bench import run_suites


def test_nonlinear_suite_quick():
    (report,) = run_suites(["nonlinear"], quick=True)
    assert report["suite"] == "nonlinear"
    names = [row[0] for row in report["rows"]]
    for expected in ("memory copy of z (baseline)", "PF, 10^4 particles (compiled, 2 RK4-split sub-steps)",
                     "FEM 20x20, moving grid (the default: characteristics, 4 Strang steps per second)",
                     "FEM 20x20, fixed box (characteristics)"):
        assert expected in names
    total = {row[0]: row[1] for row in report["rows"]}[
        "FEM 20x20, moving grid (the default: characteristics, 4 Strang steps per second)"]
    parts = [row[1] for row in report["rows"] if row[0].startswith("FEM 20x20 default, per step: ")]
    assert len(parts) == 6 and parts[0] >= 0.0 and all(t > 0 for t in parts[1:-1])  # placement: a difference
    assert abs(sum(parts) - total) <= 1e-9 * total       # the parts of the default's best run add up to its step
    for row in report["rows"]:
        assert len(row) == len(report["columns"]) and row[1] > 0
        assert row[3] is None or 0 < row[3] <= 100


def test_ekf_ukf_suite_quick():
    """The EKF/UKF suite times every filter, compiled and generic, each against FilterPy in the same run,
    and they agree with FilterPy (finite-difference Jacobians to their accuracy)."""
    (report,) = run_suites(["ekf-ukf"], quick=True)
    assert report["suite"] == "ekf-ukf"
    rows = {row[0]: row for row in report["rows"]}
    assert len(rows) == 9
    for row in report["rows"]:
        assert len(row) == len(report["columns"]) and row[1] > 0 and row[4] > 0
        assert row[5] is None or row[5] < (1e-7 if "finite-difference" in row[0] else 1e-10)
    generic = [name for name in rows if name.startswith(("EKF", "UKF"))]
    assert len(generic) == 7 and sum("generic path" in name for name in generic) == 5
    for name in generic:
        assert rows[name][2] > 0 and rows[name][3] == rows[name][2] / rows[name][1]
        assert rows[name][5] is not None
    assert rows["batch EKF, compiled, 200 tracks x 100 steps"][5] < 1e-12
