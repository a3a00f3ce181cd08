"""The zhao2013 reproduction (quick run) and the published numbers it is compared with."""

import json

import numpy as np
import pytest

from mptrack.continuous import ZHAO2013_X0, zhao2013_model
from mptrack.experiments import run_experiment
from mptrack.experiments.zhao2013 import _paper, _table1_rows


def test_published_table1_is_pinned():
    t = _paper()["table1"]
    assert t["rows"][0] == ["FE", 0.1817, 0.2250, 0.0956, 0.1194]
    assert t["rows"][2] == ["UKF", 0.5366, 0.4965, 0.2857, 0.3223]


def test_metrics_eq43_44():
    truth = np.zeros((4, 2))
    x = np.array([[1.0, 0.0]] * 4)
    P = np.tile(np.diag([4.0, 1.0]), (4, 1, 1))
    run = {"truth": truth, "FE": (x, P, 0.0), "PF": (2 * x, P, 0.0), "UKF": None}
    rows, failed = _table1_rows([run, run])
    assert rows[0] == ["FE", 1.0, 0.0, 2.0, 1.0]
    assert rows[1][1] == 2.0
    assert failed["UKF"] == 2


def test_printed_model_diverges():
    model = zhao2013_model()
    X = np.tile(ZHAO2013_X0, (200, 1))
    rng = np.random.default_rng(0)
    for _ in range(30):
        X = model.sample_transition(X, rng, 100)
    assert np.all(np.isfinite(X))
    assert np.mean(np.abs(X).max(axis=1) > 1e3) > 0.9


def test_quick_reproduction(tmp_path):
    rep = run_experiment("zhao2013", tmp_path, quick=True)
    data = json.loads((tmp_path / "zhao2013" / "results.json").read_text())
    table = data["tables"]["Table 1"]
    assert [r[0] for r in table["rows"]] == ["FE", "PF", "UKF"]
    assert table["paper"][0][1] == pytest.approx(0.1817)
    assert all(v is None or v > 0 for r in table["rows"] for v in r[1:])
    div = data["tables"]["Divergence of eq. 42"]["rows"]
    assert div[0][1] > 0.9 and div[-1][1] == 0.0
    assert table["comparison"] == {"compared": 12, "matched": 0, "differing_explained": 12,
                                   "differing_unexplained": 0}
    assert {k for _, _, k in table["explained_by"]} == {"zhao2013-eq42-ill-posed"}
    sweep = data["tables"]["Diffusion sweep"]
    assert [r[0] for r in sweep["rows"]] == ["standard Van der Pol, Q = 0.01·diag(10, 0.1)",
                                             "standard Van der Pol, Q = 1·diag(10, 0.1)"]
    assert all(r[7] < r[8] for r in sweep["rows"])  # FE nearer the reference posterior mean than PF-200
    assert all(r[-2].startswith("0/") for r in sweep["rows"])  # no FE run fails, Q x 1 included
    linear = {r[0]: r for r in data["tables"]["Time schemes (linear-Gaussian)"]["rows"]}
    assert set(linear) == {"paper", "characteristics", "sdirk2", "cn"}
    assert 1.8 < linear["paper"][-2] < 3.5 and linear["paper"][2] < 0.03
    eq42 = data["tables"]["Time schemes (eq. 42)"]["rows"]
    assert {r[1] for r in eq42} == {"paper", "characteristics", "sdirk2", "cn"}
    assert "Diffusion sweep" in rep.figures
    for name in rep.figures.values():
        assert (tmp_path / "zhao2013" / name).stat().st_size > 1000


def _sweep(variant: str, scale: float, runs: int = 20, ref_particles: int = 10_000):
    """Per filter (FE default scheme, PF-200, UKF): mean per-run RMSE (x1, x2) to the truth, mean RMS
    distance to the reference posterior mean, failed runs (left out of the means)."""
    from mptrack.errors import MptrackError
    from mptrack.continuous import fem_filter, reference_filter, simulate_sde
    from mptrack.nonlinear import particle_filter, ukf_filter

    model = zhao2013_model(variant=variant, diffusion_scale=scale)
    x0, P0 = np.array(ZHAO2013_X0), 0.1 * np.eye(2)
    out = {"FE": [], "PF": [], "UKF": []}
    for seq in np.random.SeedSequence([2013, 0]).spawn(runs):
        sim, filt, ref_rng = (np.random.default_rng(s) for s in seq.spawn(3))
        truth, z = simulate_sde(model, 30, sim, ZHAO2013_X0)
        ref = reference_filter(model, z, x0, P0, ref_rng, particles=ref_particles).x
        calls = {"FE": lambda: fem_filter(model, z, x0, P0),
                 "PF": lambda: particle_filter(model, z, x0, P0, filt, particles=200),
                 "UKF": lambda: ukf_filter(model, z, x0, P0)}
        for name, call in calls.items():
            try:
                x = call().x
                out[name].append([*np.sqrt(np.mean((x - truth) ** 2, axis=0)),
                                  np.sqrt(np.mean(np.sum((x - ref) ** 2, axis=1)))])
            except MptrackError:
                out[name].append([np.nan] * 3)
    return {k: (np.nanmean(v, axis=0), int(np.isnan(np.array(v)[:, 0]).sum())) for k, v in out.items()}


@pytest.mark.slow
@pytest.mark.parametrize("variant, scale", [("vdp", 0.001), ("vdp", 0.003), ("vdp", 0.01), ("vdp", 0.03),
                                            ("vdp", 0.1), ("vdp", 0.3), ("vdp", 1.0),
                                            ("printed", 0.001), ("printed", 0.003)])
def test_fe_never_loses_to_pf_and_ukf_across_diffusion_scales(variant, scale):
    """20 runs x 30 s: FE <= 1.05 x the better of PF (200 particles) and UKF, per coordinate, no FE run
    fails, and FE is nearer the reference posterior mean than PF-200, from Q x 0.001 to Q x 1 (at Q x 1 FE failed in 7-11 of 20 runs before the mass-conserving
    transport and the per-mode grids; docs/nonlinear.md)."""
    res = _sweep(variant, scale)
    fe, fe_failed = res["FE"]
    best = np.minimum(res["PF"][0][:2], res["UKF"][0][:2])
    print(variant, scale, {k: (np.round(v[0], 4).tolist(), v[1]) for k, v in res.items()})
    assert fe_failed == 0
    assert np.all(fe[:2] <= 1.05 * best)
    assert fe[2] < res["PF"][0][2]  # and nearer the reference posterior mean than PF-200 (2.5-8 x)
