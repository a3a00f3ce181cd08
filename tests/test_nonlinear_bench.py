"""The nonlinear bench suite runs quickly and reports every filter with a positive cost."""

from mptrack.bench import run_suites


def test_nonlinear_suite_quick():
    (report,) = run_suites(["nonlinear"], quick=True)
    assert report["suite"] == "nonlinear"
    names = [row[0] for row in report["rows"]]
    for expected in ("memory copy of z (baseline)", "PF, 10^4 particles (compiled, 2 RK4-split sub-steps)",
                     "FEM 20x20, moving grid (seed 004 section 3.1), 16 SDIRK2 sub-steps",
                     "FEM 20x20, fixed box (one factorisation), 8 SDIRK2 sub-steps"):
        assert expected in names
    for row in report["rows"]:
        assert len(row) == len(report["columns"]) and row[1] > 0
        assert row[3] is None or 0 < row[3] <= 100
