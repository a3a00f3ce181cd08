"""Reproduction of Assimakis, Tziallas, Adam, Polyzos & Papanastasiou (2016):
steady-state estimation and N-step prediction of 2-D constant-velocity (CV) and
constant-acceleration (CA) motion.

Set-up (paper sec. 5): per axis, the exactly discretised CV / CA model with
dt = 1 s, sigma_q^2 = 0.01, sigma_r^2 = 0.1, x(0/0) = 0; two per-axis
steady-state filters / predictors.  The true motion is deterministic (the
paper gives only velocities 20, 30 m/s and accelerations 2, 3 m/s^2): CV
starts at the origin, CA at rest at the origin, and z(k) = s(k dt) + v(k).
The paper does not say how many steps it ran nor define its "percent absolute
average error".  The reading that fits is the literal one: 100 x the mean
relative position error (:func:`percent_absolute_average_error`) over a long
run, T = 10^4 steps; the sum of relative errors is set by the first steps, so
the value scales like 1/T and the fraction at T = 100 looks alike.  The paper's
table is one run: :func:`as_one_run` measures how well its twelve numbers pass for
one of our runs under each reading (READINGS), and only this set-up passes.  The
reproduction shows the readings, the run-to-run spread of every cell, and the
dependence on T (docs/errata.md).
"""

from __future__ import annotations

import json
from importlib import resources

import numpy as np

from ..burden import filter_burden
from ..linear import per_axis, steady_state_filter, steady_state_predictor
from ..models import LinearGaussianModel, constant_acceleration, constant_velocity
from ..riccati import steady_state
from ._registry import RunContext, register
from ._results import Reproduction, Table

__all__ = ["percent_absolute_average_error", "motion_truth", "noisy_truth", "axis_model", "monte_carlo_errors",
           "as_one_run", "load_published", "run"]

KEY = "assimakis2016"
PAPER = ("Assimakis, Tziallas, Adam, Polyzos & Papanastasiou (2016), Mobile position estimation and "
         "prediction using steady state Kalman filter, IJCSITR 4(3):261-272")
KINDS = ("CV", "CA")
LABEL = {"CV": "constant velocity", "CA": "constant acceleration"}
N_MAX = 5          # prediction steps of Table 1
STEPS = 100        # time steps of the figures' runs and the sweeps
TABLE1_STEPS = 10_000   # run length of Table 1 (not given in the paper; the reading that fits)
TABLE1_RTOL = 0.05      # a Table 1 cell is reproduced within 5 % of the paper
CHUNK_RUNS = 50         # Monte-Carlo runs per batch (bounds memory at T = 10^4)
SETTLE_S = 40.0    # seconds left out of the steady-state RMSE (the transient from x(0/0) = 0
                   # decays by 1e-4 within 13-36 s for dt = 0.1..5 s)
DEFAULTS = dict(dt=1.0, sigma_q2=0.01, sigma_r2=0.1)


def load_published() -> dict:
    """The published numbers and set-up (package data ``data/assimakis2016.json``)."""
    text = resources.files(__package__).joinpath("data", f"{KEY}.json").read_text()
    return json.loads(text)


def percent_absolute_average_error(truth, estimate) -> float:
    """The paper's "percent absolute average error" as we read it (docs/errata.md):

        PAAE = 100/(T * axes) sum_k sum_axis |s_hat(k) - s(k)| / |s(k)|,

    the mean relative absolute position error over time steps and axes, in
    percent.  ``truth`` and ``estimate`` have the same shape, e.g. (T, axes);
    truth must be non-zero.
    """
    s = np.asarray(truth, dtype=float)
    e = np.asarray(estimate, dtype=float)
    if s.shape != e.shape:
        raise ValueError(f"estimate: expected the shape of truth {s.shape}, got {e.shape}")
    if np.any(s == 0):
        raise ValueError("truth: the relative error needs non-zero true positions")
    return float(100.0 * np.mean(np.abs(e - s) / np.abs(s)))


def motion_truth(kind: str, motion, dt: float, steps: int, velocity=None) -> np.ndarray:
    """True positions s(k dt), k = 1..steps, shape (steps, axes), metres.

    CV: s = v t from the origin (motion = velocities, m/s);
    CA: s = v0 t + a t^2 / 2 from the origin (motion = accelerations, m/s^2), from rest unless the
    initial ``velocity`` v0 (m/s) is given.
    """
    t = dt * np.arange(1, steps + 1)[:, None]
    motion = np.asarray(motion, dtype=float)[None, :]
    if kind == "CV":
        return motion * t
    v0 = 0.0 if velocity is None else np.asarray(velocity, dtype=float)[None, :]
    return v0 * t + 0.5 * motion * t * t


def noisy_truth(kind: str, motion, dt: float, sigma_q2: float, steps: int, runs: int,
                rng: np.random.Generator) -> np.ndarray:
    """True positions (runs, axes, steps) of the model's own random motion: x(k+1) = F x(k) + w(k),
    w ~ N(0, Q), from the origin at the velocity (CV) or at rest with the acceleration (CA) ``motion``
    (a reading of Table 1 that the paper's set-up does not fit; docs/errata.md)."""
    model = axis_model(kind, dt, sigma_q2, 1.0)
    motion = np.asarray(motion, dtype=float)
    x = np.zeros((runs, motion.size, model.n))
    x[..., model.n - 1] = motion                          # the velocity (CV) or acceleration (CA) state
    L = model.noise_factor()
    out = np.empty((runs, motion.size, steps))
    for k in range(steps):
        x = x @ model.F.T + rng.standard_normal(x.shape[:-1] + (L.shape[1],)) @ L.T
        out[..., k] = x[..., 0]
    return out


def axis_model(kind: str, dt: float, sigma_q2: float, sigma_r2: float) -> LinearGaussianModel:
    """The one-axis model of the paper's eq. 5 (CV) or eq. 6 (CA), exactly discretised."""
    make = constant_velocity if kind == "CV" else constant_acceleration
    return make(dt, sigma_q2, 1, sigma_r2=sigma_r2)


def _rng(seed: int, *key: int) -> np.random.Generator:
    """An independent stream per named task (SeedSequence spawn keys)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def _batch_steady_filter(A: np.ndarray, B: np.ndarray, z: np.ndarray) -> np.ndarray:
    """x(k/k) = A x(k-1/k-1) + B z(k) from x(0/0) = 0 for a batch z (R, T) of scalar
    measurements; returns (R, T, n).  Same recursion as steady_state_filter, batched."""
    R, T = z.shape
    xs = np.empty((R, T, A.shape[0]))
    x = np.zeros((R, A.shape[0]))
    b = B[:, 0]
    for k in range(T):
        x = x @ A.T + z[:, k, None] * b
        xs[:, k] = x
    return xs


def monte_carlo_errors(kind: str, motion, *, dt: float, sigma_q2: float, sigma_r2: float, steps: int,
                       runs: int, rng: np.random.Generator, n_max: int = N_MAX,
                       settle: int | None = None, truth: str = "motion", velocity=None) -> dict:
    """Monte-Carlo position errors of estimation (N = 0) and N-step prediction (N = 1..n_max).

    truth     "motion": the noise-free motion of :func:`motion_truth` (with the CA initial
              ``velocity``), the same in every run; "process-noise": each run's own
              :func:`noisy_truth`.
    Returns {"paae": (runs, n_max+1) per-run PAAE (percent), "rmse": (n_max+1,) steady-state
    RMS position error (metres, steps after ``settle``, default SETTLE_S seconds,
    all runs and axes)}.  Predictions use x(k+N/k) = F^N x(k/k), proven equal to
    eq. 19 in the tests.
    """
    settle = int(np.ceil(SETTLE_S / dt)) if settle is None else settle
    model = axis_model(kind, dt, sigma_q2, sigma_r2)
    ss = steady_state(model)
    if truth == "motion":
        s_true = motion_truth(kind, motion, dt, steps + n_max, velocity).T[None]   # (1, axes, steps+n_max)
    else:
        s_true = noisy_truth(kind, motion, dt, sigma_q2, steps + n_max, runs, rng)
    axes = s_true.shape[1]
    noise = rng.standard_normal((runs, axes, steps)) * np.sqrt(sigma_r2)
    z = s_true[..., :steps] + noise                                   # (runs, axes, steps)
    x = _batch_steady_filter(ss.A, ss.B, z.reshape(runs * axes, steps)).reshape(runs, axes, steps, -1)
    paae = np.empty((runs, n_max + 1))
    rmse = np.empty(n_max + 1)
    row = np.zeros(model.n)
    row[0] = 1.0                                                     # position of F^N x
    for N in range(n_max + 1):
        pos = x @ (row @ np.linalg.matrix_power(model.F, N))         # (runs, axes, steps)
        s = s_true[..., N:N + steps]
        rel = np.abs(pos - s) / np.abs(s)
        paae[:, N] = 100.0 * rel.mean(axis=(1, 2))
        rmse[N] = np.sqrt(np.mean((pos - s)[..., settle:] ** 2))
    return {"paae": paae, "rmse": rmse}


def paae_runs(kind: str, motion, *, steps: int, runs: int, rng: np.random.Generator,
              chunk: int = CHUNK_RUNS, **truth) -> np.ndarray:
    """Per-run PAAE (runs, N_MAX+1), percent, at the paper's defaults; ``chunk`` runs at a time
    so that memory stays bounded at T = 10^4; ``truth``: the truth arguments of monte_carlo_errors."""
    parts = [monte_carlo_errors(kind, motion, **DEFAULTS, steps=steps, runs=min(chunk, runs - start), rng=rng,
                                settle=0, **truth)["paae"] for start in range(0, runs, chunk)]
    return np.concatenate(parts)


# ---------------------------------------------------------------- single run: figures 1-4

def _single_run(kind: str, motion, seed: int, index: int) -> dict:
    p = DEFAULTS
    model = axis_model(kind, p["dt"], p["sigma_q2"], p["sigma_r2"])
    ss = steady_state(model)
    truth = motion_truth(kind, motion, p["dt"], STEPS + N_MAX)
    z = truth[:STEPS] + np.sqrt(p["sigma_r2"]) * _rng(seed, 0, index).standard_normal((STEPS, len(motion)))
    est = per_axis(steady_state_filter, model, z, steady=ss)
    pos = [0, model.n]  # position components of the per-axis stacked state
    out = {"truth": truth, "z": z, "estimate": est.x[:, pos], "paae": [
        percent_absolute_average_error(truth[:STEPS], est.x[:, pos])]}
    preds = {}
    for N in range(1, N_MAX + 1):
        pred = per_axis(lambda m, zz, a, b: steady_state_predictor(m, zz, N, a, steady=ss), model, z)
        preds[N] = pred.x[:, pos]
        out["paae"].append(percent_absolute_average_error(truth[N:N + STEPS], preds[N]))
    out["predictions"] = preds
    return out


def _plot_run(path, run: dict, N: int, title: str) -> None:
    from ._plotting import plt, save_figure

    truth = run["truth"]
    est = run["estimate"] if N == 0 else run["predictions"][N]
    k = np.arange(1, STEPS + 1) + N
    s = truth[N:N + STEPS]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True,
                                      gridspec_kw={"height_ratios": [2, 1]})
    what = "estimate x(k/k)" if N == 0 else f"{N}-step prediction x(k/k-{N})"
    for j, axis in enumerate("xy"):
        top.plot(k, s[:, j], "-", color=f"C{j}", lw=1.5, label=f"real position {axis}")
        top.plot(k, est[:, j], ".", color=f"C{j}", ms=4, alpha=0.8, label=f"{what}, {axis}")
        bottom.plot(k, est[:, j] - s[:, j], "-", color=f"C{j}", lw=0.9, label=f"{axis} error")
    bottom.axhline(0.0, color="k", lw=0.5)
    top.set_ylabel("position (m)")
    bottom.set_ylabel("error (m)")
    bottom.set_xlabel("time step k (dt = 1 s)")
    top.legend(fontsize=8, ncol=2)
    bottom.legend(fontsize=8, ncol=2)
    lim = 1.5 * np.percentile(np.abs(est - s), 99)  # the first steps' transient may leave the frame
    bottom.set_ylim(-lim, lim)
    top.set_title(title)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


# ---------------------------------------------------------------- sweeps

SWEEPS = {
    "dt": dict(values=[0.1, 0.2, 0.5, 1.0, 2.0, 5.0],
               xlabel=f"discretisation time dt (s); {STEPS} s of motion", log=True),
    "sigma_r2": dict(values=[0.001, 0.01, 0.1, 1.0, 10.0], xlabel="measurement noise variance sigma_r^2 (m^2)",
                     log=True),
    "motion": dict(values=[0.05, 0.25, 0.5, 1.0, 2.0, 5.0],
                   xlabel="velocity (CV) / acceleration (CA) scale, x paper's (20, 30) / (2, 3)", log=True),
}
N_SWEEP = 10


def _sweep(ctx: RunContext, name: str, runs: int, motions: dict) -> dict:
    """PAAE (mean over runs) and steady RMSE for each kind and sweep value."""
    spec = SWEEPS[name]
    out = {}
    with ctx.progress.task(f"sweep over {name}", total=len(KINDS) * len(spec["values"])) as advance:
        for i, kind in enumerate(KINDS):
            paae, rmse = [], []
            for j, value in enumerate(spec["values"]):
                p = dict(DEFAULTS, steps=STEPS, runs=runs)
                motion = np.asarray(motions[kind], dtype=float)
                if name == "motion":
                    motion = motion * value
                else:
                    p[name] = value
                if name == "dt":  # the same 100 s of motion at every sampling interval
                    p["steps"] = int(round(STEPS * DEFAULTS["dt"] / value))
                # common random numbers: the same noise stream at every sweep value
                rng = _rng(ctx.seed, 2, list(SWEEPS).index(name), i)
                res = monte_carlo_errors(kind, motion, rng=rng, **p)
                paae.append(res["paae"].mean(axis=0))
                rmse.append(res["rmse"])
                advance()
            out[kind] = {"paae": np.array(paae), "rmse": np.array(rmse)}
    return out


def _plot_sweep(path, name: str, data: dict) -> None:
    from ._plotting import plt, save_figure

    spec = SWEEPS[name]
    x = spec["values"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for kind, color in zip(KINDS, ("C0", "C3")):
        for N, style in ((0, "-o"), (1, "--s"), (N_MAX, ":^")):
            label = f"{kind} " + ("estimation" if N == 0 else f"prediction N={N}")
            left.plot(x, data[kind]["paae"][:, N], style, color=color, ms=4, label=label)
            right.plot(x, data[kind]["rmse"][:, N], style, color=color, ms=4, label=label)
    for ax in (left, right):
        ax.set_xscale("log" if spec["log"] else "linear")
        ax.set_yscale("log")
        ax.set_xlabel(spec["xlabel"])
        ax.grid(True, which="both", alpha=0.3)
    left.set_ylabel("PAAE (mean relative |error|, percent)")
    right.set_ylabel(f"steady-state RMS position error (m), t > {SETTLE_S:g} s")
    left.legend(fontsize=7)
    fig.suptitle(f"Assimakis et al. 2016: sweep over {name} ({STEPS} steps, Monte-Carlo mean)")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _plot_n_sweep(path, data: dict) -> None:
    from ._plotting import plt, save_figure

    N = np.arange(0, N_SWEEP + 1)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for kind, color in zip(KINDS, ("C0", "C3")):
        left.plot(N, data[kind]["paae"], "-o", color=color, ms=4, label=LABEL[kind])
        right.plot(N, data[kind]["rmse"], "-o", color=color, ms=4, label=LABEL[kind])
        right.plot(N, data[kind]["sigma"], ":", color=color, label=f"{LABEL[kind]}: predicted sqrt(P(k+N/k)[0,0])")
    left.set_ylabel("PAAE (percent)")
    right.set_ylabel(f"steady-state RMS position error (m), t > {SETTLE_S:g} s")
    right.set_yscale("log")
    for ax in (left, right):
        ax.set_xlabel("prediction steps N (0 = estimation)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"Assimakis et al. 2016: sweep over the prediction horizon N ({STEPS} steps, Monte-Carlo mean)")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


# ---------------------------------------------------------------- conclusions of the sweeps

def _spread(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(values.max() / values.min())


def _verdict(ratio: float) -> str:
    if ratio < 1.05:
        return "supported"
    if ratio < 2.0:
        return f"only roughly true (the error changes by a factor {ratio:.2f})"
    return f"refuted (the error changes by a factor {ratio:.1f})"


def _conclude_dt(data: dict) -> str:
    parts = []
    for kind in KINDS:
        est, pred = data[kind]["rmse"][:, 0], data[kind]["rmse"][:, N_MAX]
        parts.append(f"{kind}: estimation RMS error {est.min():.3f}-{est.max():.3f} m, "
                     f"{N_MAX}-step prediction {pred.min():.3f}-{pred.max():.3f} m")
    est_ratio = max(_spread(data[k]["rmse"][:, 0]) for k in KINDS)
    pred_ratio = max(_spread(data[k]["rmse"][:, N_MAX]) for k in KINDS)
    return ("Sweep over dt (same continuous sigma_q^2 = 0.01 density, same per-sample sigma_r^2, "
            f"{STEPS} s of motion): " + "; ".join(parts) + ". 'The discretization time does not affect "
            f"the filter': {_verdict(est_ratio)}. 'Does not affect the prediction algorithms': "
            f"{_verdict(pred_ratio)}; N steps ahead is N dt seconds ahead, so a fixed N predicts "
            "further at larger dt. (With the continuous noise density fixed, a shorter dt also means "
            "more measurements per second, hence the smaller estimation error; the PAAE moves with dt "
            "mostly because the positions it divides by change.)")


def _conclude_r(data: dict) -> str:
    grows = all(np.all(np.diff(data[k]["rmse"][:, N]) > 0) for k in KINDS for N in (0, 1, N_MAX))
    parts = [f"{k}: estimation {data[k]['rmse'][0, 0]:.3f} -> {data[k]['rmse'][-1, 0]:.3f} m"
             for k in KINDS]
    verdict = "supported" if grows else "not supported"
    return (f"Sweep over sigma_r^2 = {SWEEPS['sigma_r2']['values'][0]:g}..{SWEEPS['sigma_r2']['values'][-1]:g}: "
            + "; ".join(parts) + f". 'The filters produce worse estimates (and predictions) as the "
            f"measurement noise covariance increases': {verdict} (every error grows monotonically: {grows}).")


def _conclude_motion(data: dict) -> str:
    rmse_ratio = max(_spread(data[k]["rmse"][:, N]) for k in KINDS for N in (0, 1, N_MAX))
    paae = {k: data[k]["paae"][:, 0] for k in KINDS}
    return ("Sweep over the velocity (CV) / acceleration (CA), x0.05..x5 of the paper's, same noise "
            f"stream at every value: the steady-state RMS errors agree to a factor {rmse_ratio:.6f} (the "
            "filter is linear and the model has no bias for this motion, so after the transient its error "
            "does not depend on it). 'The movement's velocity does not affect the filter / prediction': "
            f"{_verdict(rmse_ratio)} for the steady-state error. The transient "
            "from x(0/0) = 0 scales with the velocity, and the relative PAAE does change: "
            + ", ".join(f"{k} {paae[k][0]:.4f} -> {paae[k][-1]:.4f}" for k in KINDS) + ".")


def _conclude_n(data: dict) -> str:
    parts = []
    grows = True
    for k in KINDS:
        r = data[k]["rmse"]
        grows &= bool(np.all(np.diff(r) > 0))
        parts.append(f"{k}: RMS error {r[0]:.3f} m (estimation), {r[1]:.3f} (N=1), {r[N_MAX]:.3f} "
                     f"(N={N_MAX}), {r[-1]:.3f} m (N={N_SWEEP})")
    return ("Sweep over N = 0..%d: " % N_SWEEP + "; ".join(parts)
            + f". The error grows monotonically with N: {grows}. 'Predictions for small time units ahead "
            "are satisfying compared to one step prediction': supported for N of a few steps (CV "
            "grows roughly linearly, CA roughly quadratically in N, as F^N amplifies the velocity / "
            "acceleration error). The model's own prediction covariance is larger than the "
            "Monte-Carlo error because the simulated motion has no process noise.")


# ---------------------------------------------------------------- Table 1: the readings

ERRATA = {
    "assimakis2016-table1-single-run": "'Percent absolute average error' (Table 1): the paper shows one run; "
                                       "its twelve numbers are a typical single run of this set-up, and the cell "
                                       "lies inside the central 95 % of single runs",
}
HORIZONS = (100, 1000, 3000, TABLE1_STEPS)
#: the central range of single runs inside which a paper's cell counts as one run of our set-up
ONE_RUN_RANGE = (0.025, 0.975)
#: the readings of Table 1 tried against all twelve cells (docs/errata.md); the first is the reproduction
READINGS = {
    "one run of the noise-free motion, T = 10^4 (ours)": {},
    "fraction (no x100), T = 100 (our former reading)": {},
    "CA starting at the CV example's velocity (20, 30) m/s": {"CA": dict(velocity=True)},
    "truth with the model's own process noise": {"CV": dict(truth="process-noise"), "CA": dict(truth="process-noise")},
}


def _worst(mean: np.ndarray, paper: np.ndarray) -> np.ndarray:
    """Worst relative cell error |ours/paper - 1| per column."""
    return np.max(np.abs(mean / paper - 1.0), axis=0)


def as_one_run(single: np.ndarray, paper: np.ndarray) -> dict:
    """How well the paper's table (6, 2) passes for one run among ``single`` (runs, 6, 2):
    {"d2": its squared Mahalanobis distance from the runs (their mean and covariance, plus the variance
    of the paper's rounding to 4 decimals), "p": the chi-square (12 dof) probability of a larger one,
    "within": the fraction of runs within TABLE1_RTOL of the paper in all twelve cells, "quantile": (6, 2)
    the fraction of runs below each paper cell}."""
    from scipy.stats import chi2

    flat, target = single.reshape(len(single), -1), paper.reshape(-1)
    cov = np.cov(flat, rowvar=False) + np.diag(np.full(target.size, 0.00005 ** 2 / 3.0))
    dev = target - flat.mean(axis=0)
    d2 = float(dev @ np.linalg.solve(cov, dev))
    return {"d2": d2, "p": float(chi2.sf(d2, target.size)),
            "within": float(np.mean(np.abs(single / paper - 1.0).max(axis=(1, 2)) <= TABLE1_RTOL)),
            "quantile": (flat < target).mean(axis=0).reshape(paper.shape)}


def _reading_runs(ctx: RunContext, motions: dict, runs: int, runs_by_T: dict) -> dict:
    """{reading: (runs, 6, 2) single-run PAAE} of each of READINGS."""
    out = {}
    with ctx.progress.task("Table 1: readings", total=2 * len(READINGS) - 2) as advance:
        for r, (name, spec) in enumerate(READINGS.items()):
            if r < 2:          # the runs over horizons already hold these two
                T, scale = (TABLE1_STEPS, 1.0) if r == 0 else (STEPS, 0.01)
                out[name] = np.stack([runs_by_T[T, k] for k in KINDS], axis=2) * scale
                continue
            per_kind = []
            for i, kind in enumerate(KINDS):
                truth = dict(spec.get(kind, {}))
                if not truth:
                    per_kind.append(runs_by_T[TABLE1_STEPS, kind])
                    continue
                if truth.get("velocity"):
                    truth["velocity"] = motions["CV"]
                per_kind.append(ctx.cached(f"paae-{kind}-reading{r}", lambda: paae_runs(
                    kind, motions[kind], steps=TABLE1_STEPS, runs=runs, rng=_rng(ctx.seed, 5, r, i), **truth),
                    runs=runs))
                advance()
            out[name] = np.stack(per_kind, axis=2)
    return out


def _table1_tables(ctx: RunContext, motions: dict, published: dict, runs: int, labels: list) -> dict:
    paper = np.array([r[1:] for r in published["rows"]], dtype=float)       # (6, 2): CV, CA
    runs_by_T = {}
    with ctx.progress.task("Table 1: Monte-Carlo over run lengths", total=len(HORIZONS) * len(KINDS)) as advance:
        for j, T in enumerate(HORIZONS):
            for i, kind in enumerate(KINDS):
                runs_by_T[T, kind] = ctx.cached(f"paae-{kind}-{T}", lambda: paae_runs(
                    kind, motions[kind], steps=T, runs=runs, rng=_rng(ctx.seed, 1, i, j)), runs=runs)
                advance()
    mean = {T: np.stack([runs_by_T[T, k].mean(axis=0) for k in KINDS], axis=1) for T in HORIZONS}
    sd = {T: np.stack([runs_by_T[T, k].std(axis=0, ddof=1) for k in KINDS], axis=1) for T in HORIZONS}
    m, s = mean[TABLE1_STEPS], sd[TABLE1_STEPS]
    readings = _reading_runs(ctx, motions, runs, runs_by_T)
    fits = {name: as_one_run(single, paper) for name, single in readings.items()}
    ours = fits[next(iter(READINGS))]
    lo, hi = ONE_RUN_RANGE
    note = (f"PAAE = 100 x mean over k = 1..T and both axes of |s_hat(k) - s(k)| / |s(k)| (percent, the "
            f"paper's literal unit), T = {TABLE1_STEPS} steps (not given in the paper), mean of {runs} "
            "Monte-Carlo runs; predictions x(k+N/k) compared with s(k+N). The paper shows one run: its twelve "
            f"numbers are a typical single run of this set-up (squared Mahalanobis distance {ours['d2']:.1f} from "
            f"our runs, chi-square p = {ours['p']:.2f} with 12 dof; {100 * ours['within']:.0f} % of single runs are "
            f"within {100 * TABLE1_RTOL:g} % of all twelve cells), and no other reading is (table 'Table 1 "
            f"readings'). A cell counts as reproduced within {100 * TABLE1_RTOL:g} % of our mean, or as one run when "
            f"the paper's number lies inside the central {100 * (hi - lo):g} % of single runs (the CA estimation "
            f"cell, sd {100 * s[0, 1] / m[0, 1]:.0f} % of its mean: table 'Table 1 (run-to-run spread)').")
    t1 = Table(title=f"Percent absolute average error of position estimation and prediction "
                     f"(mean of {runs} runs, T = {TABLE1_STEPS})",
               columns=published["columns"], rows=[[lab, _fmt(m[j, 0]), _fmt(m[j, 1])] for j, lab in enumerate(labels)],
               paper=[list(r) for r in published["rows"]], rtol=TABLE1_RTOL, notes=note)
    q = ours["quantile"]
    t1.explain([(i, j) for i, j in t1.mismatches() if lo <= q[i, j - 1] <= hi], "assimakis2016-table1-single-run")
    spread = Table(
        title=f"Table 1 run-to-run spread (T = {TABLE1_STEPS}, {runs} runs; sd of one run)",
        columns=["", "CV mean (%)", "CV sd", "CV ours/paper - 1", "CV runs below paper", "CA mean (%)", "CA sd",
                 "CA ours/paper - 1", "CA runs below paper"],
        rows=[[lab] + [v for k in range(2) for v in (_sig(m[j, k]), _sig(s[j, k]), _sig(m[j, k] / paper[j, k] - 1),
                                                       _sig(q[j, k]))]
              for j, lab in enumerate(labels)],
        notes=f"The standard error of each mean is sd / sqrt({runs}); it is the yardstick of our mean, not of the "
              "paper's single run, whose spread is sd. 'Runs below paper': the fraction of our single runs below "
              f"the paper's number (inside [{lo:g}, {hi:g}]: the paper's cell is an ordinary single run).")
    rows = []
    for name, single in readings.items():
        w = _worst(single.mean(axis=0), paper)
        within = int(np.sum(np.abs(single.mean(axis=0) / paper - 1.0) <= TABLE1_RTOL))
        fit = fits[name]
        rows.append([name, _fmt(w[0]), _fmt(w[1]), within, _sig(fit["d2"]), _sig(fit["p"]), _sig(fit["within"])])
    read = Table(title="Table 1: the readings of the paper's set-up, against all twelve cells",
                 columns=["reading", "worst CV cell |mean/paper - 1|", "worst CA cell |mean/paper - 1|",
                          f"cells of the mean within {100 * TABLE1_RTOL:g} % (of 12)",
                          "paper as one run: Mahalanobis d^2", "p (chi-square, 12 dof)",
                          f"single runs within {100 * TABLE1_RTOL:g} % in all 12 cells"], rows=rows,
                 notes="The paper's table is one run: each reading is judged by how well the paper's twelve numbers "
                       "pass for one of its runs (d^2 from the runs' mean and covariance; p, the chance of a larger "
                       "d^2). Only the first reading passes. Other readings, far off: Sum|e| / Sum|s| is ~20 "
                       "times too small; the Euclidean-distance ratio is within 1 % of the per-axis mean.")
    hor = Table(
        title="Monte-Carlo mean PAAE (percent) for run lengths T (the paper does not give T)",
        columns=["steps T", "CV estimation", "CV N=1", f"CV N={N_MAX}", "CA estimation", "CA N=1",
                 f"CA N={N_MAX}", "worst CV cell |ours/paper - 1|", "worst CA cell |ours/paper - 1|"],
        rows=[[T] + [_fmt(mean[T][N, k]) for k in range(2) for N in (0, 1, N_MAX)]
              + [_fmt(w) for w in _worst(mean[T], paper)] for T in HORIZONS],
        notes="PAAE x T is nearly constant: the relative error of the first steps dominates the sum.")
    return {"Table 1": t1, "Table 1 (run-to-run spread)": spread, "Table 1 readings": read,
            "Table 1 vs horizon T": hor}


# ---------------------------------------------------------------- the reproduction

def _fmt(x: float) -> float:
    return float(f"{x:.4f}")


def _sig(x: float) -> float:
    return float(f"{x:.4g}")


@register(KEY, paper=PAPER, seed=12345,
          description="Steady-state estimation and N-step prediction of 2-D CV/CA motion: Table 1 "
                      "(PAAE), Table 2 (burden), figures 1-4 and the sweeps over dt, sigma_r^2, velocity, N")
def run(ctx: RunContext) -> Reproduction:
    pub = load_published()
    motions = {"CV": pub["setup"]["velocity"], "CA": pub["setup"]["acceleration"]}
    runs_t1 = 40 if ctx.quick else 400
    runs_sweep = 20 if ctx.quick else 400
    labels = ["estimation"] + [f"prediction N={N}" for N in range(1, N_MAX + 1)]
    rep = Reproduction(key=KEY, paper=PAPER, seed=ctx.seed, parameters={
        **DEFAULTS, "x0": 0.0, "velocity": motions["CV"], "acceleration": motions["CA"], "steps": STEPS,
        "table1_steps": TABLE1_STEPS,
        "prediction_steps": N_MAX, "table1_runs": runs_t1, "sweep_runs": runs_sweep,
        "settle_s": SETTLE_S, "quick": ctx.quick})

    # Figures 1-4: one run of STEPS steps
    single = {}
    with ctx.progress.task("single runs, figures 1-4", total=len(KINDS)) as advance:
        for i, kind in enumerate(KINDS):
            single[kind] = ctx.cached(f"single-{kind}", lambda: _single_run(kind, motions[kind], ctx.seed, i),
                                      motion=motions[kind], steps=STEPS)
            advance()
    rep.errata.update(ERRATA)
    rep.tables.update(_table1_tables(ctx, motions, pub["table1"], runs_t1, labels))

    # Table 2
    # the paper's Table 2: the N-step predictor has the steady-state filter's burden 2n^2 + 2nm - n
    cb = {k: filter_burden("SSKF", n, 1) for k, n in (("CV", 2), ("CA", 3))}
    rep.tables["Table 2"] = Table(
        title="Per-iteration calculation burden of estimation and N-step prediction (2n^2 + 2nm - n)",
        columns=pub["table2"]["columns"],
        rows=[["estimation", cb["CV"], cb["CA"]], ["prediction", cb["CV"], cb["CA"]],
              ["both axes (two filters)", 2 * cb["CV"], 2 * cb["CA"]]],
        paper=[list(r) for r in pub["table2"]["rows"]] + [["both axes (two filters)", None, None]],
        notes="Per axis, independent of N (A_N, B_N are computed off-line); the paper quotes the "
              "per-axis value CB_v = 10, CB_a = 21.")

    titles = {
        "Figure 1": ("CV", 0, "Fig. 1: position estimation, constant velocity (v = 20, 30 m/s)"),
        "Figure 2": ("CV", 1, "Fig. 2: one-step position prediction, constant velocity"),
        "Figure 3": ("CA", 0, "Fig. 3: position estimation, constant acceleration (a = 2, 3 m/s^2)"),
        "Figure 4": ("CA", 1, "Fig. 4: one-step position prediction, constant acceleration"),
    }
    for label, (kind, N, title) in titles.items():
        name = label.lower().replace(" ", "") + ".png"
        _plot_run(ctx.figure_path(name), single[kind], N, title)
        rep.figures[label] = name

    # Sweeps the paper describes in words
    conclusions = {"dt": _conclude_dt, "sigma_r2": _conclude_r, "motion": _conclude_motion}
    for name in SWEEPS:
        data = ctx.cached(f"sweep-{name}", lambda: _sweep(ctx, name, runs_sweep, motions), runs=runs_sweep)
        fig = f"sweep_{name}.png"
        _plot_sweep(ctx.figure_path(fig), name, data)
        rep.figures[f"Sweep {name}"] = fig
        rep.tables[f"Sweep {name}"] = Table(
            title=f"Monte-Carlo errors vs {name} ({runs_sweep} runs)",
            columns=[name, "CV est RMSE (m)", "CV N=1 RMSE", f"CV N={N_MAX} RMSE", "CA est RMSE (m)",
                     "CA N=1 RMSE", f"CA N={N_MAX} RMSE", "CV est PAAE", "CA est PAAE"],
            rows=[[v] + [_fmt(data[k]["rmse"][j, N]) for k in KINDS for N in (0, 1, N_MAX)]
                  + [_fmt(data[k]["paae"][j, 0]) for k in KINDS] for j, v in enumerate(SWEEPS[name]["values"])],
            notes=conclusions[name](data))
        rep.notes.append(conclusions[name](data))

    n_data = ctx.cached("sweep-N", lambda: _n_sweep(ctx, runs_sweep, motions), runs=runs_sweep)
    _plot_n_sweep(ctx.figure_path("sweep_N.png"), n_data)
    rep.figures["Sweep N"] = "sweep_N.png"
    rep.tables["Sweep N"] = Table(
        title=f"Monte-Carlo errors vs prediction steps N ({runs_sweep} runs; N = 0 is estimation)",
        columns=["N", "CV PAAE", "CV RMSE (m)", "CV model sigma (m)", "CA PAAE", "CA RMSE (m)",
                 "CA model sigma (m)"],
        rows=[[N] + [_fmt(n_data[k][q][N]) for k in KINDS for q in ("paae", "rmse", "sigma")]
              for N in range(N_SWEEP + 1)],
        notes=_conclude_n(n_data))
    rep.notes.append(_conclude_n(n_data))
    rep.notes.insert(0, rep.tables["Table 1"].notes)
    return rep


def _n_sweep(ctx: RunContext, runs: int, motions: dict) -> dict:
    from ..linear import prediction_covariance

    out = {}
    with ctx.progress.task("sweep over N", total=len(KINDS)) as advance:
        for i, kind in enumerate(KINDS):
            res = monte_carlo_errors(kind, motions[kind], **DEFAULTS, steps=STEPS, runs=runs,
                                     rng=_rng(ctx.seed, 4, i), n_max=N_SWEEP)
            model = axis_model(kind, **DEFAULTS)
            Pe = steady_state(model).P_filt
            sigma = [np.sqrt(Pe[0, 0])] + [np.sqrt(prediction_covariance(model, Pe, N)[0, 0])
                                           for N in range(1, N_SWEEP + 1)]
            out[kind] = {"paae": res["paae"].mean(axis=0), "rmse": res["rmse"], "sigma": np.array(sigma)}
            advance()
    return out
