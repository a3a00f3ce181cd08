"""Shared reproduction of Assimakis & Adam's 2-D (seed 000) and 3-D (seed 002) tracking papers.

Both papers have the same structure: models A (joint) and B (per axis), the
12 implementations of Table 1, burden Tables 2-4, and (2-D only) the FIR
steady-state filter, Tables 5-7.  The 3-D paper publishes Table 3 and three
speedups; everything else for 3-D is ours and marked as such.
"""

from __future__ import annotations

import json
import time
from importlib import resources

import numpy as np

from .. import burden
from ..linear import IMPLEMENTATIONS, fir_filter, fir_order, steady_state_filter
from ..models import assimakis_model_a, assimakis_model_b
from ..riccati import steady_state
from ..sim import simulate_linear
from ._plotting import plt, save_figure
from ._registry import RunContext
from ._results import Reproduction, Table

__all__ = ["load_published", "reproduce_assimakis"]

FILTER_NAMES = ("KF", "LF", "JKLF", "SSKF", "SSLF", "JSSKLF")
NAMES = tuple(imp.name for imp in IMPLEMENTATIONS)  # "KF-A", ..., "JSSKLF-B" in Table 1 order
STEPS = 100          # length of the simulated run shown in the figures
TIMING_STEPS = 2000  # steps per timing run of each implementation


def load_published(key: str) -> dict:
    return json.loads(resources.files(__package__).joinpath(f"data/{key}.json").read_text())


def _burdens(axes: int, join: str = "once") -> dict[str, int]:
    return {imp.name: burden.implementation_burden(imp.filter, imp.model, axes, join) for imp in IMPLEMENTATIONS}


def _table2(axes: int) -> Table:
    n, m = 2 * axes, axes
    rows, paper = [], []
    for name in FILTER_NAMES:
        text = burden.FORMULAS[name][0]
        own = burden.FORMULAS[name][1]
        rows.append([name, text, float(own(n, m)), float(own(2, 1))])
        paper.append([name, text, None, None])
    return Table(
        title="Per-iteration calculation burden of filters (formula; evaluated without join for KF/LF parts)",
        columns=["filter", "formula", f"model A (n={n}, m={m})", "model B axis (n=2, m=1)"],
        rows=rows, paper=paper, uncounted=("formula",),
        notes="JKLF/JSSKLF rows are the join procedure only; the implementation burden adds both filters. "
              "The formulas are the paper's, shown, not counted; the evaluated burdens are ours.")


def _table3(axes: int, published: dict | None) -> Table:
    ours = _burdens(axes)
    rows = [[imp.number, imp.model, imp.system, imp.filter, ours[imp.name]] for imp in IMPLEMENTATIONS]
    paper = None
    if published is not None:
        paper = [[imp.number, imp.model, imp.system, imp.filter, published[imp.name]] for imp in IMPLEMENTATIONS]
    return Table(title="Per-iteration calculation burden of implementations",
                 columns=["implementation", "model", "system", "filter", "calculation burden"],
                 rows=rows, paper=paper, uncounted=("model", "system", "filter"),
                 notes=f"model B = {axes} per-axis filters; the JKLF/JSSKLF join counted once, as in the paper. "
                       "Model, system and filter are the paper's labels (shown, not counted).")


def _table3_per_axis(axes: int) -> Table:
    once, per_axis = _burdens(axes), _burdens(axes, "per-axis")
    rows = [[name, once[name], per_axis[name]] for name in NAMES if name.endswith("-B")]
    return Table(title="Model B burden with the join counted once (paper) vs per axis (what runs)",
                 columns=["implementation", "join once (paper)", "join per axis"], rows=rows,
                 notes="The per-axis algorithm averages KF and LF on every axis, so the join costs "
                       "axes x (n^2 + 3n) or axes x 2n; the paper counts it once.")


def _speedup_rows(burdens: dict[str, float]) -> list[list]:
    return [[name] + [round(burdens[name] / burdens[col], 3) for col in NAMES] for name in NAMES]


# erratum keys cited by the tables (results.json "errata"): each is an anchor in docs/errata.md
ERRATA = {
    "assimakis2014-table4-burdens": "Table 4 uses different burdens from Table 3: "
                                    "printed speedups are ratios of burdens 1191, 118, 640, 98 for JKLF-A, "
                                    "JSSKLF-A, JKLF-B, JSSKLF-B, not Table 3's 1207, 96, 326, 44",
    "assimakis2014-table4-garbled": "Table 4 as printed is garbled: "
                                    "a printed value that belongs to another cell (text extraction garbled)",
}


def _table4(axes: int, printed: dict | None, implied: dict | None) -> Table:
    """Our speedups beside Table 4 exactly as printed (null where nothing is printed)."""
    rows = _speedup_rows(_burdens(axes))
    notes = "speedup(row to column) = burden(row) / burden(column), from our Table 3."
    if printed is None:
        return Table(title="Speedup between implementations", columns=["implementation", *NAMES], rows=rows,
                     notes=notes, atol=0.0005 + 1e-12)
    index = {name: i for i, name in enumerate(NAMES)}
    paper = [[name] + [None] * len(NAMES) for name in NAMES]
    for row, col, value in printed["cells"]:
        paper[index[row]][1 + index[col]] = value
    garbled = {}
    for row, col, value, where in printed["garbled"]:
        paper[index[row]][1 + index[col]] = value
        garbled[index[row], 1 + index[col]] = where
    notes += (" The paper's cells are stored exactly as printed (null where nothing is printed: the diagonal "
              "of rows 1-6, LF-A in rows 7-8, SSLF-A in rows 9-12). Every readable printed cell equals "
              "b_i/b_j with the burdens b = " + json.dumps(implied) + ", which differ from Table 3 for JKLF-A, "
              "JSSKLF-A, JKLF-B and JSSKLF-B, so cells in those rows and columns differ (erratum "
              "assimakis2014-table4-burdens). Five printed values sit in a cell they do not belong to "
              "(erratum assimakis2014-table4-garbled): " + "; ".join(garbled.values()) + ".")
    table = Table(title="Speedup between implementations", columns=["implementation", *NAMES], rows=rows,
                  paper=paper, notes=notes, atol=0.0005 + 1e-12)
    joined = {name for name in NAMES if implied[name] != _burdens(axes)[name]}
    for i, j in table.mismatches():
        if (i, j) in garbled:
            table.explain([(i, j)], "assimakis2014-table4-garbled")
        elif NAMES[i] in joined or NAMES[j - 1] in joined:
            table.explain([(i, j)], "assimakis2014-table4-burdens")
    return table


def _text_speedups(axes: int, quoted: list) -> Table:
    b = _burdens(axes)
    rows = [[f"{slow} to {fast}", round(b[slow] / b[fast], 3)] for slow, fast, _ in quoted]
    paper = [[f"{slow} to {fast}", value] for slow, fast, value in quoted]
    return Table(title="Speedups quoted in the text", columns=["speedup", "value"], rows=rows, paper=paper,
                 atol=0.0005 + 1e-12)


def _fir_tables(axes: int, published: dict | None) -> dict[str, Table]:
    tables = {}
    orders = []
    for measurement in ("printed", "position"):
        A = steady_state(assimakis_model_b(measurement=measurement)).A
        for norm in (2, "fro", 1, np.inf):
            M = fir_order(A, 1e-3, norm)
            label = f"H = {'[1 dt]' if measurement == 'printed' else '[1 0]'}, norm {norm}"
            pub = published["fir_order"]["M"] if (published and measurement == "printed" and norm == 2) else None
            orders.append(([label, M], [label, pub]))
    M = orders[0][0][1]
    tables["FIR order M"] = Table(
        title="FIR filter order M from ||A^M|| < eps = 1e-3 (model B; model A is block-diagonal, same M)",
        columns=["set-up", "M"], rows=[o[0] for o in orders],
        paper=[o[1] for o in orders] if published else None,
        notes="The published M = 17 needs the measurement matrix as printed, H = [1 dt]; "
              "the textbook H = [1 0] gives M = 20.")
    nA, mA = 2 * axes, axes
    ss = {"A": burden.filter_burden("SSKF", nA, mA), "B": axes * burden.filter_burden("SSKF", 2, 1)}
    fir = {"A": burden.fir_burden(nA, mA, M), "B": axes * burden.fir_burden(2, 1, M)}
    formula_a = f"{ss['A'] - nA} + {nA}M"
    formula_b = f"{ss['B'] - 2 * axes} + {2 * axes}M"
    tables["Table 5"] = Table(
        title="Calculation burden of classical and FIR steady-state filters",
        columns=["filter", "calculation burden", "when"],
        rows=[["SSKF/SSLF", "2n^2 + 2nm - n", "per-iteration"],
              ["FIR SSKF/SSLF", "2n^2 + 2nm - n + (M - 1)n", "when required"]],
        paper=[["SSKF/SSLF", "2n^2 + 2nm - n", "per-iteration"],
               ["FIR SSKF/SSLF", "2n^2 + 2nm - n + (M - 1)n", "when required"]] if published else None,
        uncounted=("calculation burden", "when"),
        notes="The paper's formulas, shown, not counted: Tables 6 and 7 evaluate them.")
    t6 = published.get("table6") if published else None
    tables["Table 6"] = Table(
        title="Calculation burden of classical and FIR steady-state implementations",
        columns=["filter", "model A", "model B"],
        rows=[["SSKF/SSLF", ss["A"], ss["B"]], ["FIR SSKF/SSLF", formula_a, formula_b]],
        paper=[["SSKF/SSLF", t6["SSKF/SSLF"]["A"], t6["SSKF/SSLF"]["B"]],
               ["FIR SSKF/SSLF", t6["FIR SSKF/SSLF"]["A"], t6["FIR SSKF/SSLF"]["B"]]] if t6 else None,
        notes=None if t6 else "Not published for 3-D: our evaluation of the paper's formulas.")
    t7 = published.get("table7") if published else None
    mu = {k: burden.fir_break_even(fir[k], ss[k]) for k in "AB"}
    tables["Table 7"] = Table(
        title=f"FIR results for the example (M = {M})",
        columns=["filter", "model A", "model B"],
        rows=[["SSKF/SSLF", ss["A"], ss["B"]], ["FIR SSKF/SSLF", fir["A"], fir["B"]], ["mu", mu["A"], mu["B"]]],
        paper=[["SSKF/SSLF", t7["SSKF/SSLF"]["A"], t7["SSKF/SSLF"]["B"]],
               ["FIR SSKF/SSLF", t7["FIR SSKF/SSLF"]["A"], t7["FIR SSKF/SSLF"]["B"]],
               ["mu", t7["mu"]["A"], t7["mu"]["B"]]] if t7 else None,
        notes="mu = ceil(FIR burden / SS burden): the FIR filter is cheaper when outputs are needed every "
              "mu or more steps." + ("" if t7 else " Not published for 3-D."))
    return tables


def _simulate(ctx: RunContext, axes: int):
    model = assimakis_model_a(axes)
    rng = np.random.default_rng(ctx.seed)
    truth, z = simulate_linear(model, STEPS, rng)
    return model, truth, z


def _equivalence(results: dict, model, z) -> tuple[Table, dict]:
    ref = results["KF-A"]
    ss_time = steady_state(model, "per-step").steady_state_time
    rows = []
    for name in NAMES:
        r = results[name]
        dx = float(np.max(np.abs(r.x - ref.x)) / np.max(np.abs(ref.x)))
        dP = float(np.max(np.abs(r.P - ref.P)) / np.max(np.abs(ref.P)))
        tail = slice(min(ss_time, len(z) - 1), None)
        dx_tail = float(np.max(np.abs(r.x[tail] - ref.x[tail])) / np.max(np.abs(ref.x)))
        rows.append([name, dx, dP, dx_tail])
    table = Table(
        title="Behaviour: every implementation against KF model A (relative max differences)",
        columns=["implementation", "max |x - x_KF-A| / max |x_KF-A|", "max |P - P_KF-A| / max |P_KF-A|",
                 f"same, after the steady-state time k >= {ss_time}"],
        rows=rows,
        notes="Claims (i), (ii), (iv) of section 6: time-invariant filters agree to rounding, steady-state "
              "filters agree to rounding, model A = model B. Claim (iii): steady-state and time-invariant "
              "filters differ during the transient from P0 = 0 only.")
    return table, {"ss_time": ss_time}


def _riccati_table(model) -> Table:
    ref = steady_state(model, "dare")
    rows = []
    for method, form in (("dare", "kalman"), ("doubling", "kalman"), ("per-step", "kalman"),
                         ("per-step", "lainiotis")):
        s = steady_state(model, method, form=form)
        rows.append([f"{method} ({form})", s.iterations, s.steady_state_time, s.residual,
                     float(np.max(np.abs(s.P_filt - ref.P_filt))), float(np.max(np.abs(s.A - ref.A)))])
    return Table(title="Steady state of model A from three Riccati solvers (REKF) and the RELF",
                 columns=["solver", "iterations", "steady-state time", "REKF residual",
                          "max |Pe - Pe_DARE|", "max |A - A_DARE|"], rows=rows,
                 notes="doubling iterations are doublings (2^k per-step iterations each); "
                       "the steady-state time is the step from which P(k/k-1) stays within 1e-13 (relative).")


def _timings(ctx: RunContext, axes: int, advance) -> Table:
    steps = 200 if ctx.quick else TIMING_STEPS
    repeats = 1 if ctx.quick else 3
    rng = np.random.default_rng(ctx.seed + 1)
    _, z = simulate_linear(assimakis_model_a(axes), steps, rng)
    per_iter = {}
    for imp in IMPLEMENTATIONS:
        runner = imp.prepare(axes)
        best = np.inf
        for _ in range(repeats):
            start = time.perf_counter()
            runner(z)
            best = min(best, time.perf_counter() - start)
        per_iter[imp.name] = best / steps
        advance()
    flops = _burdens(axes)
    base_t, base_f = per_iter["KF-A"], flops["KF-A"]
    rows = [[name, flops[name], per_iter[name] * 1e6, round(base_f / flops[name], 3),
             round(base_t / per_iter[name], 3)] for name in NAMES]
    return Table(
        title="Measured per-iteration time on this machine vs flop count",
        columns=["implementation", "flops (Table 3)", "measured us/iteration", "flop speedup of KF-A over it",
                 "measured speedup of KF-A over it"], rows=rows,
        notes=f"best of {repeats} runs of {steps} steps of the compiled per-step loops (numba). For n <= 6 "
              "every matrix product or inverse has a fixed cost (a BLAS/LAPACK call, ~0.1 us) larger than its "
              "flops, so measured time follows the number of matrix operations rather than the flop count: "
              "LF (one solve) beats KF (inverse + determinant) although it has more flops, and model B, "
              "which runs one loop per axis, is slower than model A although it has fewer flops.")


def _figures(ctx: RunContext, model, truth, z, results, axes) -> dict[str, str]:
    t = np.arange(1, len(z) + 1)
    figures = {}
    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for ax, idx, label in ((axs[0], 0, "position s_x"), (axs[1], 1, "velocity v_x")):
        ax.plot(t, truth[:, idx], color="0.6", lw=3, label="truth")
        if idx == 0:
            ax.plot(t, z[:, 0], ".", color="0.3", ms=3, label="measurement z_x (= s_x + dt v_x + v)")
        for name, style in (("KF-A", "-"), ("LF-A", "-"), ("JKLF-A", "-")):
            ax.plot(t, results[name].x[:, idx], style, lw=1, label=name)
        for name in ("SSKF-A", "SSLF-A", "JSSKLF-A"):
            ax.plot(t, results[name].x[:, idx], "--", lw=1, label=name)
        ax.set_ylabel(label)
    axs[0].legend(ncol=4, fontsize=6, loc="best", framealpha=0.6)
    axs[1].set_xlabel("time step k")
    fig.suptitle("Figure 1: estimation, solid KF/LF/JKLF, dashed SSKF/SSLF/JSSKLF (model A)")
    figures["Figure 1"] = save_figure(fig, ctx.figure_path("figure1.png"))

    ss = steady_state(model)
    fir = fir_filter(model, z, steady=ss)
    sskf = steady_state_filter(model, z, steady=ss)
    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for ax, idx, label in ((axs[0], 0, "position s_x"), (axs[1], 1, "velocity v_x")):
        ax.plot(t, truth[:, idx], color="0.6", lw=3, label="truth")
        ax.plot(t, sskf.x[:, idx], "-", lw=1, label="SSKF/SSLF")
        ax.plot(t, fir.x[:, idx], "--", lw=1, label="FIR SSKF/SSLF")
        ax.set_ylabel(label)
    axs[0].legend(fontsize=7)
    axs[1].set_xlabel("time step k")
    fig.suptitle("Figure 2: solid SSKF/SSLF, dashed FIR SSKF/SSLF (model A)")
    figures["Figure 2"] = save_figure(fig, ctx.figure_path("figure2.png"))

    fig, ax = plt.subplots(figsize=(8, 4))
    tiny = np.finfo(float).tiny
    for name in ("LF-A", "KF-B", "LF-B"):
        diff = np.max(np.abs(results[name].x - results["KF-A"].x), axis=1)
        ax.semilogy(t, np.maximum(diff, tiny), lw=1, label=f"|x_{name} - x_KF-A|")
    diff = np.max(np.abs(sskf.x - results["KF-A"].x), axis=1)
    ax.semilogy(t, np.maximum(diff, tiny), lw=1, label="|x_SSKF-A - x_KF-A| (transient)")
    ax.set_xlabel("time step k")
    ax.set_ylabel("max abs difference")
    ax.legend(fontsize=7)
    ax.set_title("KF and LF agree to rounding; SS filters converge to them")
    figures["KF-LF agreement"] = save_figure(fig, ctx.figure_path("kf_lf_agreement.png"))
    return figures


def reproduce_assimakis(ctx: RunContext, *, key: str, axes: int) -> Reproduction:
    pub = load_published(key)
    model, truth, z = _simulate(ctx, axes)
    ex = pub["example"]
    rep = Reproduction(key=key, paper=pub["paper"], seed=ctx.seed,
                       parameters={"axes": axes, "dt": ex["dt"], "sigma_q2": ex["sigma_q2"],
                                   "sigma_r2": ex["sigma_r2"], "x0": 0.0, "P0": 0.0, "steps": STEPS,
                                   "measurement_matrix": "H = [1 dt] per axis (as printed)"})
    with ctx.progress.task(f"{key}: 12 implementations", total=2 * len(IMPLEMENTATIONS)) as advance:
        results = {}
        for imp in IMPLEMENTATIONS:
            results[imp.name] = imp.prepare(axes)(z)
            advance()
        timing = _timings(ctx, axes, advance)
    rep.tables["Table 2"] = _table2(axes)
    rep.tables["Table 3"] = _table3(axes, pub["table3"])
    rep.tables["Table 3 (join per axis)"] = _table3_per_axis(axes)
    implied = pub.get("table4_implied_burdens")
    if implied:
        implied = {k: v for k, v in implied.items() if not k.startswith("_")}
        rep.errata.update(ERRATA)
    rep.tables["Table 4"] = _table4(axes, pub.get("table4_printed_cells"), implied)
    rep.tables["Speedups in the text"] = _text_speedups(axes, pub["text_speedups"])
    rep.tables.update(_fir_tables(axes, pub if "fir_order" in pub else None))
    eq_table, _ = _equivalence(results, model, z)
    rep.tables["Behaviour"] = eq_table
    rep.tables["Riccati solvers"] = _riccati_table(model)
    rep.tables["Measured speed"] = timing
    rep.figures = _figures(ctx, model, truth, z, results, axes)
    rep.notes.append("KF/LF/JKLF and SSKF/SSLF/JSSKLF outputs agree to rounding with model A and model B "
                     "(Behaviour table), as claimed in section 6.")
    return rep


