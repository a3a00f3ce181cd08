"""Reproduction of Bouzera, Oussalah, Mezhoud & Khireddine (2017), FEKF for mobile localisation.

Section 4.2 simulation (:mod:`._bouzera_scenario`): three base stations, a linear and a two-linear
(manoeuvre) trajectory, ranges d = ||X - B_i|| + N(0, sigma) (eq. 26), 100 Monte-Carlo runs, filters
initialised with R0 = 0.222, P0 = 0.001 I, Q0 = diag(0.02, 0.02, 0.002).  Tables V-VII (for both readings
of sigma, with the paper's rule tables and with systems trained by the paper's ANFIS procedure),
figures 5-7 (trained membership functions) and 9-13, and the Table VIII RSS -> distance examples.

The geometry and motion the paper omits are calibrated so our EKF reproduces the paper's EKF
(:func:`calibrate_scenario`, :data:`CALIBRATED`); the FEKF and FCS are then compared on that scenario.
"""

from __future__ import annotations

from dataclasses import asdict, replace

import numpy as np
from scipy import stats

from ..fuzzy import anfis_train
from ..metrics import position_error
from ..cellular import (
    TABLE_I,
    TABLE_III,
    bouzera_fcs_fis,
    bouzera_fekf_fis,
    ekf_ranges_batch,
    fcs_ranges_batch,
    fekf_ranges_batch,
    local_solutions,
)
from ..radio import arfcn_to_frequency, distance_from_rss
from ._bouzera_scenario import (
    CALIBRATED,
    GEOMETRY,
    KINDS,
    NOISE_READINGS,
    Setup,
    calibrate_scenario,
    calibrated_setup,
    ekf_misfit,
    load_paper,
    ranges,
    scenario,
    scenario_bound,
    simulate,
    trajectory,
)
from ._registry import RunContext, register
from ._results import Reproduction, Table

__all__ = ["Setup", "trajectory", "simulate", "ranges", "scenario_bound", "calibrate_scenario", "CALIBRATED",
           "calibrated_setup", "run_filters", "anfis_training_data", "train_systems", "table_viii", "run"]

KEY = "bouzera2017"
PAPER = ("Bouzera, Oussalah, Mezhoud & Khireddine (2017), Fuzzy extended Kalman filter for dynamic mobile "
         "localization in urban area using wireless network, Applied Soft Computing 57, 452-467")
FILTERS = ("FCS", "EKF", "FEKF")
TRAINED = ("FCS (ANFIS)", "EKF", "FEKF (ANFIS)")  # the EKF has no fuzzy system: the same runs in both
LABELS = {"linear": "one-Linear Traj.", "two-linear": "two-Linear Traj."}
#: The scenario we used before the calibration (sigma as a standard deviation), kept for comparison.
PREVIOUS = {"side_km": 2.0, "start_x": 0.125, "start_y": 0.175, "heading_deg": 20.0, "speed_km_s": 0.0175,
            "turn_deg": 90.0, "turn_at": 0.5}
_SETS5 = ("very small", "small", "neutral", "large", "very large")


def anfis_training_data(setup: Setup, truth, z, x0, result):
    """ANFIS training samples from filter runs with known truth (paper section 3.4).

    For every run, step and station: the inputs |Inn_i|, S_i (FEKF) and d_i (FCS) that the
    filter saw, and the target confidence y_i = min_j e_j / e_i, where e_i is the error of
    local solution i (eq. 14) against the true position: 1 for the best station of the step
    (the paper: "proportional to the confidence attached to the position of the target given the
    full knowledge of the target positioning").
    Returns (inputs_fekf (N, 2), inputs_fcs (N, 1), target (N,)).
    """
    B, T, m = z.shape
    n = x0.shape[1]
    x_prev = np.concatenate([x0[:, None], result.x[:, :-1]], axis=1).reshape(B * T, n)
    P_prev = np.concatenate([np.broadcast_to(np.diag(setup.P0_diag), (B, 1, n, n)), result.P[:, :-1]], axis=1)
    P_pred = P_prev.reshape(B * T, n, n) + np.diag(setup.Q0_diag)
    x_loc, _, _, innov, S = local_solutions(x_prev, P_pred, z.reshape(B * T, m), setup.stations,
                                            np.full(m, setup.R0))
    err = np.linalg.norm(x_loc - np.broadcast_to(truth, (B, T, n)).reshape(B * T, 1, n), axis=-1)
    target = err.min(axis=1, keepdims=True) / np.maximum(err, 1e-12)
    return (np.column_stack([np.abs(innov).ravel(), S.ravel()]), z.reshape(-1, 1), target.ravel())


def train_systems(setup: Setup, seed_seq: np.random.SeedSequence) -> dict:
    """The paper's ANFIS procedure (section 3.4): FIS1 (|Inn|, S; 5 x 2 triangular sets) and FIS2
    (distance; 5 triangular sets) trained by hybrid learning on a simulated linear trajectory.

    Training data: ``setup.anfis_runs`` runs of their own seed stream at every noise level of Table VII
    (the paper's input ranges, |Inn| up to 1.5 km, need the high levels), the FEKF with the paper's rules
    supplying the inputs, :func:`anfis_training_data` the targets.  Universes: ``setup.universes()`` (the
    paper's for |Inn| and S; the distance's found from the scenario).
    Returns {"FEKF": AnfisResult, "FCS": AnfisResult, "samples": N, "inn_max": km, "s_range": (lo, hi),
    "d_max": km}.
    """
    fis = setup.universes()
    truth, x0, eps = simulate(setup, "linear", seed_seq, setup.anfis_runs)
    parts = []
    for sigma in setup.noise_levels:
        z = ranges(setup, truth, eps, sigma)
        parts.append(anfis_training_data(setup, truth, z, x0, run_filters(setup, z, x0, which=("FEKF",))["FEKF"]))
    in1, in2, target = (np.concatenate(p) for p in zip(*parts))
    common = {"epochs": setup.anfis_epochs, "bounds": (0.0, 1.0), "membership": "triangular"}
    fekf = anfis_train(in1, target, sets_per_input=(5, 2), universes=(fis["inn_universe_km"], fis["s_universe_km2"]),
                       names=("|innovation|", "S"), **common)
    fcs = anfis_train(in2, target, sets_per_input=(5,), universes=(fis["distance_universe_km"],),
                      names=("distance",), **common)
    return {"FEKF": fekf, "FCS": fcs, "samples": len(target), "inn_max": float(in1[:, 0].max()),
            "s_range": (float(in1[:, 1].min()), float(in1[:, 1].max())), "d_max": float(in2.max())}


def run_filters(setup: Setup, z, x0, *, R0=None, P0=None, Q0=None, which=FILTERS, covariance="paper",
                fis_fekf=None, fis_fcs=None):
    """Run the filters on a batch of ranges; returns {name: BatchFilterResult}.  The fuzzy systems default
    to the paper's rule tables (I, III) on uniform triangular sets over ``setup.universes()``."""
    R0 = setup.R0 if R0 is None else R0
    P0 = np.diag(setup.P0_diag) if P0 is None else P0
    Q0 = np.diag(setup.Q0_diag) if Q0 is None else Q0
    fis = setup.universes()
    out = {}
    for name in which:
        if name == "EKF":
            out[name] = ekf_ranges_batch(z, setup.stations, x0, P0, Q0, R0)
        elif name == "FEKF":
            out[name] = fekf_ranges_batch(
                z, setup.stations, x0, P0, Q0, R0, covariance=covariance,
                fis=fis_fekf or bouzera_fekf_fis(fis["inn_universe_km"], fis["s_universe_km2"]))
        else:
            out[name] = fcs_ranges_batch(z, setup.stations, x0, P0, Q0, R0, covariance=covariance,
                                         fis=fis_fcs or bouzera_fcs_fis(fis["distance_universe_km"]))
    return out


def _run_rmse(result, truth) -> np.ndarray:
    """Per-run average of RMSE(k) (eq. 25) over the trajectory: (B,)."""
    return position_error(result.x, truth).mean(axis=1)




def table_viii(paper: dict) -> Table:
    """RSS -> distance for the paper's drive-test rows (COST-231 WI NLOS, DCS 1800 downlink)."""
    params = paper["table8"]["parameters"]
    rows, prows = [], []
    for cell, hb, tx, rx, arfcn, d_paper in paper["table8"]["rows"]:
        f = float(arfcn_to_frequency(arfcn, "DCS1800"))
        d = float(distance_from_rss(rx, tx, "cost231-wi-nlos", frequency_mhz=f, h_base_m=hb, h_mobile_m=1.5,
                                    city="metropolitan", free_space_constant_db=32.45, on_invalid="ignore",
                                    **params))
        rows.append([cell, hb, tx, rx, arfcn, f, round(d, 6)])
        prows.append([cell, hb, tx, rx, arfcn, None, d_paper])
    return Table(
        title="Example of distance calculation using Walfisch-Ikegami model",
        columns=["Cell ID", "Hb (m)", "Tx (dBm)", "Rxlev (dBm)", "ARFCN", "f (MHz)", "Walfish distances (km)"],
        rows=rows, paper=prows, atol=1e-6, uncounted=("Hb (m)", "Tx (dBm)", "Rxlev (dBm)", "ARFCN"),
        notes=("Hb, Tx, Rxlev and ARFCN are the paper's inputs (shown, not counted); the distances are compared. "
               "f = DCS 1800 downlink of the ARFCN (the paper's 1805 + 0.2 (ARFCN - 511)); loss = Tx - Rxlev; "
               "COST-231 WI NLOS, metropolitan k_f, h_m = 1.5 m, b = 50 m, w = 25 m, phi = 30 deg, h_roof = 15 m, "
               "L0 constant 32.45 dB (exact free space; COST 231 prints 32.4, the paper 32.44); "
               "16139E's 52 m mast is outside the model's 4-50 m range (evaluated anyway, as the paper did)."))


def _figure(ctx: RunContext, name: str, draw) -> str:
    from ._plotting import plt, save_figure

    return save_figure(draw(plt), ctx.figure_path(name), dpi=110)


def _sweep(setup, truth, x0, eps, name, values, make):
    """RMSE of EKF and FEKF for each value of one initial parameter (figures 11-13)."""
    z = ranges(setup, truth, eps, setup.sigma)
    res = {"EKF": [], "FEKF": []}
    for v in values:
        out = run_filters(setup, z, x0, which=("EKF", "FEKF"), **{name: make(v)})
        for f in res:
            res[f].append(float(_run_rmse(out[f], truth).mean()))
    return res


def _other(reading: str) -> str:
    return next(r for r in NOISE_READINGS if r != reading)


@register(KEY, paper=PAPER, seed=2017,
          description="FEKF vs EKF vs FCS on ranges to 3 base stations: calibrated scenario, both readings of "
                      "sigma, ANFIS-trained systems, Tables V-VIII, figures 5-7, 9-13")
def run(ctx: RunContext, setup: Setup | None = None) -> Reproduction:
    setup = setup or Setup()
    if ctx.quick:
        setup = replace(setup, runs=12, steps=60, noise_levels=(0.001, 0.1, 0.6), R0_sweep=(1e-3, 0.222, 10.0),
                        P0_sweep=(1e-3, 0.1), Q0_sweep=(0.02, 5050.0), nlos_bias_km=(0.0, 0.3),
                        speed_factors=(0.5, 1.0), anfis_runs=4, anfis_epochs=5)
    paper = load_paper()
    root = np.random.SeedSequence(ctx.seed)
    seeds = dict(zip(KINDS + ("anfis",), root.spawn(len(KINDS) + 1)))
    main = setup.noise_reading
    setups = {main: setup, _other(main): calibrated_setup(_other(main), setup)}
    mc = {}
    for reading, s in setups.items():  # the same seeds (common random numbers) for both readings
        mc[reading] = ctx.cached(f"monte-carlo-{reading.replace(' ', '-')}",
                                 lambda s=s: _monte_carlo(ctx, s, seeds), setup=asdict(s))
    sims, per_run, base = mc[main]["sims"], mc[main]["per_run"], mc[main]["base"]

    tables = _published_tables(setup, paper, sims, per_run, FILTERS)
    _explain_fekf(tables)
    tables.update({f"{k} (ANFIS-trained)": t for k, t in
                   _published_tables(setup, paper, sims, per_run, TRAINED, counted=False).items()})
    other = _other(main)
    tables[f"Table VII (sigma as {other})"] = _published_tables(
        setups[other], paper, mc[other]["sims"], mc[other]["per_run"], FILTERS, counted=False)["Table VII"]
    tables["Fit to the paper"] = _fit_table(paper, setups, mc)
    tables["Scenario calibration"] = _calibration_table(paper, setups, mc, seeds)
    tables.update(_anfis_tables(setup, mc[main]["systems"]))
    tables.update(_ordering_tables(ctx, setup, sims, seeds, per_run))
    sweeps = ctx.cached("sensitivity", lambda: _sensitivity(ctx, setup, sims), setup=asdict(setup))
    for label, (name, (values, res)) in zip(("Figure 11", "Figure 12", "Figure 13"), sweeps.items()):
        tables[f"{label} data"] = Table(f"Average RMSE (km) vs {name} (diagonal elements equal for P0, Q0)",
                                        [name, "EKF", "FEKF"],
                                        [[v, e, f] for v, e, f in zip(values, res["EKF"], res["FEKF"])])
    tables["Table VIII"] = table_viii(paper)

    figures = _figures(ctx, setup, sims, base, sweeps, mc[main]["systems"])
    parameters = {k: v for k, v in asdict(setup).items()}
    parameters["fis"] = {k: list(v) for k, v in setup.universes().items()}
    parameters["calibrated"] = {r: dict(CALIBRATED[r]) for r in NOISE_READINGS}
    notes = _notes(setup, tables)
    return Reproduction(key=KEY, paper=PAPER, seed=ctx.seed, parameters=parameters, tables=tables,
                        figures=figures, notes=notes, errata=dict(ERRATA))


def _monte_carlo(ctx, setup, seeds) -> dict:
    """Tables V-VII under one reading of sigma: the ANFIS training, then every noise level, both trajectories,
    the paper's systems and the trained ones.

    Returns {"sims", "systems" (train_systems), "per_run": {(sigma, kind): {filter: (B,) per-run average
    RMSE}}, "base": {kind: {filter: BatchFilterResult}} at setup.sigma}.
    """
    with ctx.progress.task(f"ANFIS training (sigma as {setup.noise_reading})", total=1) as advance:
        systems = train_systems(setup, seeds["anfis"])
        advance()
    sims = {kind: simulate(setup, kind, seeds[kind], setup.runs) for kind in KINDS}
    levels = tuple(setup.noise_levels) + (() if setup.sigma in setup.noise_levels else (setup.sigma,))
    per_run: dict[tuple, dict[str, np.ndarray]] = {}
    base: dict[str, dict] = {}
    with ctx.progress.task(f"Monte-Carlo, sigma as {setup.noise_reading} (Tables V-VII)",
                           total=len(levels) * len(KINDS)) as advance:
        for sigma in levels:
            for kind in KINDS:
                truth, x0, eps = sims[kind]
                z = ranges(setup, truth, eps, sigma)
                out = run_filters(setup, z, x0)
                trained = run_filters(setup, z, x0, which=("FEKF", "FCS"), fis_fekf=systems["FEKF"].fis,
                                      fis_fcs=systems["FCS"].fis)
                out.update({f"{k} (ANFIS)": v for k, v in trained.items()})
                per_run[sigma, kind] = {f: _run_rmse(r, truth) for f, r in out.items()}
                if sigma == setup.sigma:
                    base[kind] = out
                advance()
    return {"sims": sims, "systems": systems, "per_run": per_run, "base": base}


def _published_tables(setup, paper, sims, per_run, names, counted: bool = True) -> dict[str, Table]:
    """Tables V, VI (with its detail) and VII beside the published numbers, for the filters ``names``
    (FCS, EKF, FEKF in the paper's column order).  ``counted=False``: a second version of cells counted
    elsewhere (another reading of sigma, the trained systems), shown beside the paper but not counted."""
    tables: dict[str, Table] = {}
    t5 = paper["table5"]
    labels = LABELS
    fcs, ekf, fekf = names
    off = () if counted else tuple(FILTERS)
    reading = f"sigma = {setup.sigma} read as a {setup.noise_reading}"
    rows5, paper5 = [], []
    for kind in KINDS:
        r = per_run[setup.sigma, kind]
        rows5.append([f"Average RMSE (km) ({labels[kind]})"] + [float(r[f].mean()) for f in names])
        rows5.append([f"Standard deviation σ ({labels[kind]})"] + [float(r[f].std(ddof=1)) for f in names])
        paper5 += [[rows5[-2][0]] + t5[kind]["mean"], [rows5[-1][0]] + t5[kind]["std"]]
    tables["Table V"] = Table(
        "Average RMSE along the whole trajectory", ["", *FILTERS], rows5, paper5, rtol=0.25, uncounted=off,
        notes=(f"{setup.runs} Monte-Carlo runs, {reading}; fuzzy systems: {fekf}, {fcs}; RMSE(k) = position "
               "error (eq. 25), averaged over k per run; mean and sample std over runs. 'Matches' means within "
               "25 %."))

    # Table VI: one-sided t-tests of mean RMSE(FEKF) < mean RMSE(other)
    rows6, paper6, rows6b = [], [], []
    for kind in KINDS:
        r = per_run[setup.sigma, kind]
        cells, detail = [], [kind]
        for other in (ekf, fcs):
            welch = stats.ttest_ind(r[fekf], r[other], equal_var=False, alternative="less")
            paired = stats.ttest_rel(r[fekf], r[other], alternative="less")
            two = stats.ttest_ind(r[fekf], r[other], equal_var=False)
            cells.append(float(welch.pvalue))
            detail += [float(welch.statistic), float(two.pvalue), float(paired.pvalue)]
        rows6.append([f"t-test p-value ({labels[kind]})", *cells])
        p6 = paper["table6"][kind]
        paper6.append([rows6[-1][0], p6["FEKF vs EKF"], p6["FEKF vs FCS"]])
        rows6b.append(detail)
    tables["Table VI"] = Table(
        "t-test p-values for RMSE-mean(FEKF) < RMSE-mean(other)", ["", "FEKF Vs EKF", "FEKF Vs FCS"], rows6, paper6,
        rtol=0.0, atol=0.05, uncounted=() if counted else ("FEKF Vs EKF", "FEKF Vs FCS"),
        notes=("Welch one-sided t-test (scipy.stats.ttest_ind, equal_var=False, alternative='less') over the runs; "
               "the paper's '<0.00001' is stored as its bound 1e-5; 'matches' = same side of 0.05 within 0.05."))
    tables["t-tests (detail)"] = Table(
        "Welch t statistic, two-sided Welch p and paired one-sided p (same noise in every filter)",
        ["trajectory", "t FEKF-EKF", "p two-sided", "p paired", "t FEKF-FCS", "p two-sided", "p paired"], rows6b)

    t7 = paper["table7"]["rows"]
    rows7, paper7 = [], []
    lookup = {(s, k): vals for s, k, *vals in t7}
    for sigma in setup.noise_levels:
        for kind in KINDS:
            r = per_run[sigma, kind]
            label = f"{sigma:g} ({labels[kind]})"
            bound = scenario_bound(setup, sims[kind][0], sigma)
            rows7.append([label] + [float(r[f].mean()) for f in names] + [float(bound.mean())])
            paper7.append([label] + (list(lookup[sigma, kind]) if (sigma, kind) in lookup else [None] * 3) + [None])
    tables["Table VII"] = Table(f"Average RMSE (km) for various noise intensities sigma ({setup.noise_reading})",
                                ["Noise intensity σ", *FILTERS, "PCRB (ours)"], rows7, paper7, rtol=0.25,
                                uncounted=off,
                                notes=(f"Sigma read as a {setup.noise_reading}; fuzzy systems: {fekf}, {fcs}. Same "
                                       "runs and noise draws at every sigma (common random numbers). PCRB: "
                                       "Tichavsky bound for the scenario (known path shape, unknown start ~ P0, "
                                       "the range variance of sigma), averaged over the trajectory."))
    return tables


# erratum keys cited by the tables (results.json "errata"): each is an anchor in docs/errata.md
ERRATA = {
    "bouzera2017-fekf-averaged-gain": "The ordering FEKF < EKF < FCS is not reproduced at "
                                      "sigma = 0.001: the FEKF's normalised weights average single-station "
                                      "corrections (about 1/m of the EKF's gain), so under the paper's R0 it "
                                      "lags more than the EKF",
}


def _explain_fekf(tables: dict[str, Table]) -> None:
    """Mark the FEKF cells that differ because our FEKF loses to our EKF (the structural erratum)."""
    fe, ekf = 1 + FILTERS.index("FEKF"), 1 + FILTERS.index("EKF")
    for label in ("Table V", "Table VII"):
        t = tables[label]
        t.explain([(i, j) for i, j in t.mismatches() if j == fe and not t.rows[i][0].startswith("Standard")
                   and t.rows[i][fe] > t.rows[i][ekf]], "bouzera2017-fekf-averaged-gain")
    t6 = tables["Table VI"]
    t6.explain([(i, 1) for i, j in t6.mismatches() if j == 1 and t6.rows[i][1] > 0.05],
               "bouzera2017-fekf-averaged-gain")


def _ordering_tables(ctx, setup, sims, seeds, per_run) -> dict[str, Table]:
    """Our evidence on the EKF/FEKF ordering: filter variants with the PCRB, a speed sweep, an NLOS bias."""
    tables: dict[str, Table] = {}
    # Evidence for the ordering: the FEKF's fused update is a convex combination of one-station updates
    rows_g = []
    for kind in KINDS:
        truth, x0, eps = sims[kind]
        z = ranges(setup, truth, eps, setup.sigma)
        m = len(setup.stations_km)
        extra = {
            "EKF, R = m R0": run_filters(setup, z, x0, R0=m * setup.R0, which=("EKF",))["EKF"],
            "EKF, R = sigma^2 (matched)": run_filters(setup, z, x0, R0=setup.noise_variance(setup.sigma),
                                                      which=("EKF",))["EKF"],
            "FEKF, exact fused covariance": run_filters(setup, z, x0, which=("FEKF",), covariance="exact")["FEKF"],
        }
        bound = scenario_bound(setup, truth, setup.sigma)
        row = [kind, float(bound.mean())] + [float(per_run[setup.sigma, kind][f].mean()) for f in ("EKF", "FEKF")]
        row += [float(_run_rmse(v, truth).mean()) for v in extra.values()]
        rows_g.append(row)
    tables["Ordering evidence"] = Table(
        "Average RMSE (km): PCRB and filter variants explaining EKF vs FEKF",
        ["trajectory", "PCRB", "EKF", "FEKF", "EKF, R = m R0", "EKF, R = true range variance",
         "FEKF exact cov."], rows_g,
        notes=("With weights summing to 1 the FEKF correction sum_i w_i K_i Inn_i is an average of single-station "
               "corrections, about 1/m of the joint EKF correction: the FEKF behaves like an EKF with a larger R. "
               f"With R0 = {setup.R0} km^2 against a true range variance of "
               f"{setup.noise_variance(setup.sigma):g} km^2 the EKF already lags the moving handset, so the FEKF "
               "lags more. PCRB (scenario_bound): what the ranges support; every filter here is limited by its "
               "tuning (R0, Q0), not by the data."))

    # Eq. 16 as printed is not a covariance: how often it goes indefinite, and what the exact form changes
    rows_c = []
    for kind in KINDS:
        truth, x0, eps = sims[kind]
        for sigma, q in ((setup.sigma, None), (max(setup.noise_levels), None), (setup.sigma, 5050.0)):
            Q0 = None if q is None else q * np.eye(3)
            z = ranges(setup, truth, eps, sigma)
            printed = run_filters(setup, z, x0, Q0=Q0, which=("FEKF", "FCS"), covariance="paper")
            exact = run_filters(setup, z, x0, Q0=Q0, which=("FEKF", "FCS"), covariance="exact")
            share = {f: float(np.mean(np.linalg.eigvalsh(printed[f].P)[..., 0] < 0)) for f in ("FEKF", "FCS")}
            rows_c.append([kind, sigma, q if q is not None else setup.Q0_diag[0], 100 * share["FEKF"],
                           100 * share["FCS"], float(_run_rmse(printed["FEKF"], truth).mean()),
                           float(_run_rmse(exact["FEKF"], truth).mean()),
                           float(_run_rmse(printed["FCS"], truth).mean()),
                           float(_run_rmse(exact["FCS"], truth).mean())])
    tables["Eq. 16 check (ours)"] = Table(
        "Share (%) of filtered covariances with a negative eigenvalue under eq. 16, and RMSE (km) eq. 16 vs exact",
        ["trajectory", "σ (km)", "Q0 (first diagonal value)", "FEKF indefinite %", "FCS indefinite %",
         "FEKF eq. 16", "FEKF exact", "FCS eq. 16", "FCS exact"], rows_c,
        notes=("Eq. 16 omits the cross-station terms of eq. 24; the exact form A P A^T + sum w_i^2 R_i K_i K_i^T "
               "is PSD by construction. 'Q0 = 0.02' rows use the paper's diag(0.02, 0.02, 0.002)."))

    # Our check that the ordering is not an artefact of the (unpublished) speed
    rows_v = []
    with ctx.progress.task("Speed sweep", total=len(setup.speed_factors)) as advance:
        for factor in setup.speed_factors:
            sv = replace(setup, speed_km_s=factor * setup.speed_km_s)
            row = [sv.speed_km_s * 3600.0]
            for kind in KINDS:  # the main runs' noise and x0 at every speed
                truth, x0, eps = simulate(sv, kind, seeds[kind], setup.runs)
                out = run_filters(sv, ranges(sv, truth, eps, sv.sigma), x0)
                row += [float(_run_rmse(out[f], truth).mean()) for f in FILTERS]
            rows_v.append(row)
            advance()
    tables["Speed sweep (ours)"] = Table(
        f"Average RMSE (km) vs handset speed (the calibrated speed times {setup.speed_factors}), "
        f"sigma = {setup.sigma}",
        ["speed (km/h)"] + [f"{f} {kind}" for kind in KINDS for f in FILTERS], rows_v)

    # Our robustness check: an NLOS bias on one station, where down-weighting by innovation can help
    rows_n = []
    with ctx.progress.task("NLOS bias check", total=len(setup.nlos_bias_km)) as advance:
        truth, x0, eps = sims["linear"]
        for bias in setup.nlos_bias_km:
            b = np.zeros((setup.steps, len(setup.stations_km)))
            b[int(0.3 * setup.steps):int(0.7 * setup.steps), 1] = bias
            out = run_filters(setup, ranges(setup, truth, eps, setup.sigma, bias=b), x0)
            rows_n.append([bias] + [float(_run_rmse(out[f], truth).mean()) for f in FILTERS])
            advance()
    tables["NLOS bias (ours)"] = Table(
        "Average RMSE (km), linear trajectory, range bias on station 2 for the middle 40 % of the track",
        ["bias (km)", *FILTERS], rows_n)
    return tables


def _sensitivity(ctx, setup, sims) -> dict:
    """Figures 11-13: average RMSE of EKF and FEKF vs R0, P0, Q0 (linear trajectory)."""
    truth, x0, eps = sims["linear"]
    sweeps = {}
    with ctx.progress.task("Sensitivity (figures 11-13)", total=3) as advance:
        sweeps["R0"] = (setup.R0_sweep, _sweep(setup, truth, x0, eps, "R0", setup.R0_sweep, lambda v: v))
        advance()
        sweeps["P0"] = (setup.P0_sweep, _sweep(setup, truth, x0, eps, "P0", setup.P0_sweep, lambda v: v * np.eye(3)))
        advance()
        sweeps["Q0"] = (setup.Q0_sweep, _sweep(setup, truth, x0, eps, "Q0", setup.Q0_sweep, lambda v: v * np.eye(3)))
        advance()
    return sweeps


def _fit_table(paper, setups, mc) -> Table:
    """How well each reading of sigma, with the paper's rules or the trained systems, fits Tables V and VII."""
    t7 = {(s, k): vals for s, k, *vals in paper["table7"]["rows"]}
    t5 = paper["table5"]

    def fit(setup, per_run, names):
        r5 = [(per_run[setup.sigma, k][f].mean(), t5[k]["mean"][i]) for k in KINDS for i, f in enumerate(names)]
        r5 += [(per_run[setup.sigma, k][f].std(ddof=1), t5[k]["std"][i]) for k in KINDS for i, f in enumerate(names)]
        cells = rank = fekf_wins = fcs_worst = n_rows = n_high = n_low = 0
        for (s, k), pv in t7.items():
            if (s, k) not in per_run:
                continue
            ours = [per_run[s, k][f].mean() for f in names]
            n_rows += 1
            cells += sum(abs(o - p) <= 0.25 * p for o, p in zip(ours, pv))
            rank += list(np.argsort(ours)) == list(np.argsort(pv))
            if s >= 0.1:
                n_high += 1
                fekf_wins += ours[2] < ours[1]
            else:
                n_low += 1
                fcs_worst += ours[0] > max(ours[1:])
        within5 = sum(abs(o - p) <= 0.25 * p for o, p in r5)
        return [within5, cells, 3 * n_rows, rank, n_rows, fekf_wins, n_high, fcs_worst, n_low]

    rows = []
    for reading, setup in setups.items():
        for label, names in (("paper's Tables I, III", FILTERS), ("ANFIS-trained", TRAINED)):
            rows.append([f"sigma as {reading}, {label}"] + fit(setup, mc[reading]["per_run"], names))
    levels = setups[next(iter(setups))].noise_levels
    p_rows = [v for (s, _), v in t7.items() if s in levels]
    p_high = [v for (s, _), v in t7.items() if s in levels and s >= 0.1]
    p_low = [v for (s, _), v in t7.items() if s in levels and s < 0.1]
    rows.append(["paper", 12, 3 * len(p_rows), 3 * len(p_rows), len(p_rows), len(p_rows),
                 sum(v[2] < v[1] for v in p_high), len(p_high), sum(v[0] > max(v[1:]) for v in p_low), len(p_low)])
    return Table(
        "Fit to the paper's Tables V and VII: each reading of sigma, with the paper's rules and the trained systems",
        ["variant", "Table V cells within 25 % (of 12)", "Table VII cells within 25 %", "Table VII cells",
         "Table VII rows ranked as the paper", "Table VII rows", "FEKF < EKF, sigma >= 0.1", "rows sigma >= 0.1",
         "FCS worst, sigma < 0.1", "rows sigma < 0.1"], rows,
        notes=("Each reading runs on its own calibrated scenario (Scenario calibration) with the same noise draws. "
               "'Ranked as the paper': the order of FCS, EKF, FEKF in that row is the paper's. The 'paper' row "
               "gives the paper's own counts for the last two pairs of columns."))


def _calibration_table(paper, setups, mc, seeds) -> Table:
    """The calibrated geometry for each reading, and how close our EKF then is to the paper's."""
    rows = []
    candidates = [(f"sigma as {r}, calibrated", s, mc[r]["per_run"]) for r, s in setups.items()]
    previous = scenario(replace(setups[next(iter(setups))], noise_reading="standard deviation"), **PREVIOUS)
    prev_runs = {}
    for kind in KINDS:
        truth, x0, eps = simulate(previous, kind, seeds[kind], previous.runs)
        for s in previous.noise_levels:
            ekf = run_filters(previous, ranges(previous, truth, eps, s), x0, which=("EKF",))["EKF"]
            prev_runs[s, kind] = {"EKF": _run_rmse(ekf, truth)}
    candidates.append(("before calibration (sigma as standard deviation)", previous, prev_runs))
    for label, s, per_run in candidates:
        curves = {k: np.array([per_run[v, k]["EKF"].mean() for v in s.noise_levels]) for k in KINDS}
        misfit = ekf_misfit(curves, paper, s.noise_levels)
        side = float(np.linalg.norm(s.stations[1] - s.stations[0]))
        rows.append([label, side, s.start_km[0], s.start_km[1], s.heading_deg, s.speed_km_s * 3600.0, s.turn_deg,
                     round(s.turn_at * s.steps), float(per_run[s.sigma, "linear"]["EKF"].mean()),
                     float(per_run[s.sigma, "two-linear"]["EKF"].mean()), misfit["table_v"], misfit["table_vii"]])
    names = ", ".join(f"{n} in [{lo:g}, {hi:g}]" for n, lo, hi in GEOMETRY)
    return Table(
        "The omitted scenario, calibrated so our EKF reproduces the paper's EKF (Tables V and VII)",
        ["scenario", "triangle side (km)", "start x (km)", "start y (km)", "heading (deg)", "speed (km/h)",
         "turn (deg)", "turn at step", "EKF linear, sigma = 0.001 (paper 0.0518)",
         "EKF two-linear, sigma = 0.001 (paper 0.0937)", "EKF misfit, Table V", "EKF misfit, Table VII"], rows,
        notes=(f"calibrate_scenario: differential evolution over {names} (start in units of the side, from "
               "station 1; stations on an equilateral triangle), every station-handset distance in 0.02-5 km, "
               "minimising mean_VII log^2(ours/paper) + 10 mean_V log^2(ours/paper) over the EKF column, on "
               "20 runs of its own seed. Misfit = RMS of log(ours/paper) over the 2 cells of Table V or the "
               "22 of Table VII, here on this reproduction's runs (out of the calibration's sample)."))


def _anfis_tables(setup, systems) -> dict[str, Table]:
    """The trained systems beside the paper's Tables I and III, and the tuned membership functions (Figs. 5-7)."""
    fis = setup.universes()
    c1, c3 = systems["FEKF"].fis.consequents, systems["FCS"].fis.consequents
    rows1 = [[lab, float(c1[i, 0]), float(c1[i, 1])] for i, lab in enumerate(_SETS5)]
    rows3 = [[lab, float(c3[i])] for i, lab in enumerate(_SETS5)]
    training = (f"ANFIS hybrid learning with triangular sets on {setup.anfis_runs} runs of the linear trajectory at "
                f"every Table VII sigma ({systems['samples']} samples, own seed stream); target y_i = min_j e_j / "
                f"e_i from the local solutions' errors. Training RMSE {systems['FEKF'].rmse[0]:.4f} -> "
                f"{systems['FEKF'].rmse[-1]:.4f} (FIS1), {systems['FCS'].rmse[0]:.4f} -> "
                f"{systems['FCS'].rmse[-1]:.4f} (FIS2). Inputs seen: |Inn| up to {systems['inn_max']:.3f} km "
                f"(paper: [0, 1.5]), S in [{systems['s_range'][0]:.3f}, {systems['s_range'][1]:.3f}] (paper: "
                f"[0.22, 0.32]), distance up to {systems['d_max']:.3f} km. 'Matches': within 0.125 (half the "
                "paper's 0.25 grid of constants).")
    mf_rows = []
    for name, res, initial in (("|innovation| (km), Fig. 5", systems["FEKF"], (fis["inn_universe_km"], 5)),
                               ("S (km^2), Fig. 6", systems["FEKF"], (fis["s_universe_km2"], 2)),
                               ("distance (km), Fig. 7", systems["FCS"], (fis["distance_universe_km"], 5))):
        j = 1 if name.startswith("S ") else 0
        (lo, hi), n = initial
        step = (hi - lo) / (n - 1)
        labels = _SETS5 if n == 5 else ("small", "large")
        for i, mf in enumerate(res.fis.sets[j]):
            peak = lo + i * step
            mf_rows.append([name, labels[i], *mf.params, peak - step, peak, peak + step])
    return {
        "Table I (ANFIS-trained)": Table(
            "FEKF rule constants: ANFIS-trained beside the paper's Table I (rows: |innovation| set)",
            ["|Inn|", "S small", "S large"], rows1, [[lab, *TABLE_I[i]] for i, lab in enumerate(_SETS5)],
            atol=0.125, notes=training),
        "Table III (ANFIS-trained)": Table(
            "FCS rule constants: ANFIS-trained beside the paper's Table III", ["distance", "weight c"], rows3,
            [[lab, TABLE_III[i]] for i, lab in enumerate(_SETS5)], atol=0.125),
        "Figures 5-7 data": Table(
            "Tuned triangular membership functions (feet a, c, peak b) beside the initial even grid",
            ["input", "set", "a", "b", "c", "a initial", "b initial", "c initial"], mf_rows,
            notes=("Figures 5-7 of the paper are images the available text does not reproduce; it states "
                   "triangular sets, 5 for |Inn| and the distance, 2 for S (Table I, read as in docs/errata.md), "
                   "and the universes above. Inputs are clipped to the universes, so a foot beyond one acts as a "
                   "shoulder.")),
    }


def _notes(setup, tables) -> list[str]:
    t5 = tables["Table V"].rows
    return [
        ("Scenario: calibrated so our EKF reproduces the paper's EKF (Scenario calibration); sigma read as a "
         f"{setup.noise_reading} (Fit to the paper; docs/errata.md)."),
        (f"Table V (paper's rules): FCS {t5[0][1]:.4f} / EKF {t5[0][2]:.4f} / FEKF {t5[0][3]:.4f} km (linear), "
         f"{t5[2][1]:.4f} / {t5[2][2]:.4f} / {t5[2][3]:.4f} km (two-linear); paper 0.1642 / 0.0518 / 0.0360 and "
         "0.2181 / 0.0937 / 0.0605."),
        ("FEKF/FCS fuzzy sets: the paper's rules (Tables I, III) on uniform triangular sets over the universes "
         "the paper reports, and systems trained by the paper's ANFIS procedure (tables marked ANFIS-trained)."),
    ]


def _figures(ctx, setup, sims, base, sweeps, systems) -> dict[str, str]:
    figs = {}
    colours = {"FCS": "tab:orange", "EKF": "tab:blue", "FEKF": "tab:green"}

    def fig9(plt):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
        for ax, kind in zip(axes, KINDS):
            truth = sims[kind][0]
            st = setup.stations
            ax.plot(st[:, 0], st[:, 1], "k^", ms=9, label="BTS")
            ax.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="real path")
            for f in FILTERS:
                x = base[kind][f].x[0]
                ax.plot(x[:, 0], x[:, 1], "-", color=colours[f], lw=1, label=f)
            ax.set(title=f"{kind} trajectory (run 1)", xlabel="x (km)", ylabel="y (km)", aspect="equal")
            ax.legend(fontsize=8)
        return fig

    def fig10(plt):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for ax, kind in zip(axes, KINDS):
            truth = sims[kind][0]
            t = np.arange(1, setup.steps + 1) * setup.dt_s
            for f in FILTERS:
                ax.plot(t, position_error(base[kind][f].x, truth).mean(axis=0), color=colours[f], label=f)
            bound = scenario_bound(setup, truth, setup.sigma)
            ax.plot(t, bound, "k--", lw=1, label="PCRB")
            ax.set(title=f"RMSE(k), {kind} ({setup.runs} runs)", xlabel="time (s)", ylabel="RMSE (km)", yscale="log")
            ax.legend(fontsize=8)
        return fig

    def sweep_fig(name):
        def draw(plt):
            values, res = sweeps[name]
            fig, ax = plt.subplots(figsize=(5.5, 4))
            for f in ("EKF", "FEKF"):
                ax.plot(values, res[f], "o-", color=colours[f], label=f)
            ax.set(xscale="log", xlabel=f"{name} (diagonal value)", ylabel="average RMSE (km)",
                   title=f"Influence of {name}, linear trajectory")
            ax.legend()
            return fig
        return draw

    def fig5_7(plt):
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        fis = setup.universes()
        panels = (("Fig. 5: |innovation| (km)", systems["FEKF"].fis, 0, fis["inn_universe_km"], 5),
                  ("Fig. 6: S (km²)", systems["FEKF"].fis, 1, fis["s_universe_km2"], 2),
                  ("Fig. 7: distance (km)", systems["FCS"].fis, 0, fis["distance_universe_km"], 5))
        for ax, (title, trained, j, (lo, hi), n) in zip(axes, panels):
            x = np.linspace(lo, hi, 400)
            step = (hi - lo) / (n - 1)
            for i, mf in enumerate(trained.sets[j]):
                peak = lo + i * step
                ax.plot(x, np.interp(x, [peak - step, peak, peak + step], [0, 1, 0]), ":", color="0.6", lw=1)
                ax.plot(x, mf(x), "-", lw=1.5, color=f"C{i}")
            ax.set(title=f"{title}: trained (solid), initial (dotted)", xlabel=title.split(": ")[1],
                   ylabel="membership", xlim=(lo, hi), ylim=(0, 1.05))
            ax.title.set_fontsize(9)
        return fig

    figs["Figures 5-7"] = _figure(ctx, "figures5-7.png", fig5_7)
    figs["Figure 9"] = _figure(ctx, "figure9.png", fig9)
    figs["Figure 10"] = _figure(ctx, "figure10.png", fig10)
    for label, name in (("Figure 11", "R0"), ("Figure 12", "P0"), ("Figure 13", "Q0")):
        figs[label] = _figure(ctx, f"figure{label.split()[1]}.png", sweep_fig(name))
    return figs
