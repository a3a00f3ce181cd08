"""The filter contract (issue 19), one parametrised test over every filter of mptrack.

The filters are found, not listed: the entries of the registries (``linear.FILTERS``,
``tracking.FIX_FILTERS``, ``tracking.CELL_METHODS``) and every public function of the filter
packages whose return annotation is a filter result (:data:`PUBLIC`; the batch engine's as
``batch.<name>``, since its filters share their references' names); a filter without a case
below fails :func:`test_every_filter_has_a_contract_case`.

A batch filter (``Case(batch=True)``) runs the problem as a batch of one track; it must return a
:class:`mptrack.result.BatchFilterResult`, and its track 0 (``run(0)``) is held to the same
contract as a single-track filter, and equals its single-track ``twin`` field by field.

Each case runs its filter on one linear-Gaussian problem (a damped oscillator sampled at dt = 1 s
with one missing measurement row, prior x0 = 0 and the steady-state covariance, so the KF is in
steady state and every filter that is exact on a linear model equals it), and the contract is:

- the result is a :class:`mptrack.result.FilterResult` with x (T, n), P (T, n, n), and x_pred,
  P_pred, innovation (T, m), S (T, m, m), nis (T,) where the filter forms them (None only where
  :mod:`mptrack.result` documents that it does not);
- a NaN measurement row only predicts: x == x_pred, P == P_pred there, and its innovation, S
  and NIS are NaN (the FIR filter refuses NaN instead, as documented);
- x, P, x_pred, P_pred equal the KF's within the filter's documented tolerance (the table in
  :mod:`mptrack.result`), and so do innovation, S and NIS;
- bad input (a z with the wrong number of columns, an infinite measurement, an x0 of the wrong
  length, an infinite P0) raises an :class:`mptrack.errors.MptrackError` naming the argument.

The range filters (cellular) observe ranges, not a linear function of the state: their reference is
the EKF on the same ranges (the FEKF and the FCS equal it with one station), the rest is the same.
"""

from __future__ import annotations

import importlib
from typing import Callable

import numpy as np
import pytest

import mptrack.batch as batch
import mptrack.cellular as cellular
import mptrack.linear as linear
import mptrack.tracking as tracking
from mptrack.continuous import linear_sde_model, simulate_sde
from mptrack.errors import MptrackError
from mptrack.models import ContinuousLinearModel, LinearGaussianModel, nonlinear_model, position, ranges
from mptrack.nonlinear import ekf_filter
from mptrack.result import BatchFilterResult, FilterResult
from mptrack.riccati import steady_state

PACKAGES = ("mptrack.linear", "mptrack.nonlinear", "mptrack.continuous", "mptrack.cellular", "mptrack.tracking",
            "mptrack.batch")
#: packages whose filters are named with the package (the batch twins have their references' names)
QUALIFIED = ("mptrack.batch",)
RESULTS = ("FilterResult", "GatedResult", "IMMResult", "BatchFilterResult")

#: public functions that return a result but are not filters, and why
NOT_FILTERS = {
    "join_results": "combines two results (the JKLF/JSSKLF registry entries run it)",
    "per_axis": "runs a filter per axis (model B of the Table 1 implementations)",
    "filter_chunked": "runs a batch filter chunk by chunk (equal to it: tests/batch/test_batch_runner.py)",
    "rts_smoother": "smoother", "steady_state_smoother": "smoother", "rts_smoother_irregular": "smoother",
    "ekf_smoother": "smoother", "ukf_smoother": "smoother", "rts_smoother_gated": "smoother",
    "predict_ahead": "N-step predictor of a filter result", "steady_state_predictor": "N-step predictor",
}


def _public_filters() -> dict[str, Callable]:
    found = {}
    for package in PACKAGES:
        module = importlib.import_module(package)
        prefix = package.rsplit(".", 1)[1] + "." if package in QUALIFIED else ""
        for name in module.__all__:
            fn = getattr(module, name)
            ret = getattr(fn, "__annotations__", {}).get("return", "") if callable(fn) else ""
            if isinstance(ret, str) and any(r in ret for r in RESULTS) and name not in NOT_FILTERS:
                assert prefix + name not in found, f"two public filters named {prefix + name}"
                found[prefix + name] = fn
    return found


PUBLIC = _public_filters()

# ---------------------------------------------------------------------------------------- the problem
A = np.array([[0.0, 1.0], [-1.0, -0.5]])
QC = np.diag([0.1, 0.2])
R = 0.5 * np.eye(2)
T, GAP = 16, 6
CONTINUOUS = ContinuousLinearModel(A, np.eye(2), QC, np.eye(2), R)
MODEL = CONTINUOUS.discretize(1.0)
SDE = linear_sde_model(A, QC, np.eye(2), R, 1.0)
NONLINEAR = nonlinear_model(MODEL, position(R, position=(0, 1)))
X0 = np.zeros(2)
P0 = steady_state(MODEL, "dare").P_filt
Z = simulate_sde(SDE, T, np.random.default_rng(1), [1.0, 0.0])[1]
Z[GAP] = np.nan
TIMES = np.arange(1.0, T + 1.0)

# ranges to base stations, random-walk position (Bouzera et al. 2017's model, km)
STATIONS = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
RANGE_X0, RANGE_P0, RANGE_Q = np.array([0.5, 0.4]), 0.1 * np.eye(2), 0.02 * np.eye(2)
_walk = RANGE_X0 + np.cumsum(np.random.default_rng(2).normal(0.0, 0.05, (T, 2)), axis=0)
Z_RANGES = np.linalg.norm(_walk[:, None, :] - STATIONS, axis=2) + np.random.default_rng(3).normal(0.0, 0.1, (T, 3))
Z_RANGES[GAP] = np.nan


def _kf():
    return linear.kalman_filter(MODEL, Z, X0, P0)


class Case:
    """How one filter runs on the problem: ``run(z, x0, P0)`` (the common prior by default);
    ``reference()`` the result it must equal within ``tol`` (relative to the field's largest
    entry); ``forms`` the fields it forms besides x and P; ``nan`` "predicts" or "raises";
    ``arguments`` those of the prior and measurements it takes (for the bad-input checks); z the
    measurements of the comparison (by default the problem's, with its gap at row GAP), gapped
    those of the NaN check; ``extra_rows`` rows the result has before those of z.  ``batch``: the
    filter runs a batch of one track (``run`` gets z (1, T, m)); ``covariance`` False: it returns
    P None (documented in mptrack.result); ``twin`` the case of its single-track form; ``F`` the
    motion a NaN row predicts with (checked directly where the filter gives no x_pred)."""

    def __init__(self, run: Callable, tol: float, *, reference: Callable = _kf,
                 forms: tuple = ("x_pred", "P_pred", "innovation", "S", "nis", "loglik"), nan: str = "predicts",
                 z=Z, gapped=Z, x0=X0, P0=P0, arguments: tuple = ("z", "x0", "P0"), extra_rows: int = 0,
                 batch: bool = False, covariance: bool = True, twin: str | None = None, F=MODEL.F):
        self.run, self.tol, self.reference, self.forms, self.nan = run, tol, reference, forms, nan
        self.z, self.gapped, self.x0, self.P0 = z, gapped, x0, P0
        self.arguments, self.extra_rows = arguments, extra_rows
        self.batch, self.covariance, self.twin, self.F = batch, covariance, twin, F
        if batch:
            self.run = lambda z, x0, P0: run(np.asarray(z)[None], x0, P0)

    @property
    def fields(self) -> tuple:
        """The fields the filter forms, x first."""
        return ("x", "P", *self.forms) if self.covariance else ("x", *self.forms)


GAUSSIAN = ("x_pred", "P_pred", "innovation", "S", "nis", "loglik")
NO_INNOVATION = ("x_pred", "P_pred", "loglik")
FIR_EPS = 1e-3   # fir_filter's default: ||A^M|| < eps, so |x_FIR - x_SS| < eps |x| from x0 = 0
#: the comparison of the steady-state filters runs on the complete rows after the gap (after a gap the
#: KF's gain grows, theirs does not; the FIR filter needs every measurement)
AFTER_GAP = {"z": Z[GAP + 1:], "reference": lambda: linear.kalman_filter(MODEL, Z[GAP + 1:], X0, P0)}
FIR = {"nan": "raises", **AFTER_GAP}
#: the steady-state filters predict the mean through a gap and keep reporting the steady covariance
STEADY = {"nan": "predicts the mean", **AFTER_GAP}


def _registered(name):
    return lambda z, x0, P0: linear.FILTERS[name].run(MODEL, z, x0, P0)


def _gated(z, x0, P0):
    return tracking.kalman_filter_gated(CONTINUOUS, TIMES, z, x0, P0, t0=0.0)


def _track_gated(z, x0, P0):
    """track_gated from a first fix z = 0 at t = 0 (it takes no prior: it makes one of that fix); its
    fixes are positions, which have no NaN."""
    return tracking.track_gated(CONTINUOUS, np.arange(len(z) + 1.0), np.vstack([np.zeros((1, z.shape[1])), z]),
                                np.broadcast_to(R, (len(z) + 1, 2, 2)), np.diag(P0))


def _first_fix_kf():
    """The KF from the prior that track_gated makes of its first fix z = 0 (both states measured: the
    fix with covariance R)."""
    return linear.kalman_filter(MODEL, Z[GAP + 1:], np.zeros(2), R)


def _cell(fn):
    return lambda z, x0, P0: fn(z, STATIONS[:1], x0, P0, RANGE_Q, 0.222)


def _one_station_ekf():
    """The EKF on the ranges to the first station (random-walk motion)."""
    motion = LinearGaussianModel(np.eye(2), np.eye(2), RANGE_Q, np.eye(2))
    model = nonlinear_model(motion, ranges(STATIONS[:1], 0.222, position=(0, 1)))
    return ekf_filter(model, Z_RANGES[:, :1], RANGE_X0, RANGE_P0)


_CELL = {"z": Z_RANGES[:, :1], "gapped": Z_RANGES[:, :1], "x0": RANGE_X0, "P0": RANGE_P0, "reference": _one_station_ekf,
         "F": np.eye(2)}

#: registry entries and public filter functions -> their case.  Tolerances: exact algebra 1e-9; the
#: FIR its eps; the continuous-discrete UKF its RK4 error (docs/decisions/2026-12-01-warm-compiled-code.md);
#: Monte-Carlo and grid filters their sampling and discretisation errors at the settings used here.
CASES: dict[str, Case] = {
    **{f"linear.FILTERS[{name}]": Case(_registered(name), 1e-9, forms=GAUSSIAN if name == "KF" else
                                       ("x_pred", "P_pred", "innovation", "S", "nis"),
                                       **(STEADY if linear.FILTERS[name].system == "steady state" else {}))
       for name in linear.FILTERS if name != "FIR"},
    "linear.FILTERS[FIR]": Case(_registered("FIR"), FIR_EPS, forms=("x_pred", "P_pred", "innovation", "S", "nis"),
                                **FIR),
    "kalman_filter": Case(lambda z, x0, P0: linear.kalman_filter(MODEL, z, x0, P0), 0.0),
    "kalman_filter[per-step form]": Case(lambda z, x0, P0: linear.kalman_filter(
        MODEL, z, x0, P0, F=np.broadcast_to(MODEL.F, (len(z), 2, 2))), 1e-12),
    "lainiotis_filter": Case(lambda z, x0, P0: linear.lainiotis_filter(MODEL, z, x0, P0), 1e-9, forms=()),
    "steady_state_filter": Case(lambda z, x0, P0: linear.steady_state_filter(MODEL, z, x0, P0), 1e-9, forms=(),
                                **STEADY),
    "fir_filter": Case(lambda z, x0, P0: linear.fir_filter(MODEL, z, x0, P0), FIR_EPS, forms=(), **FIR),
    "kalman_filter_irregular": Case(lambda z, x0, P0: linear.kalman_filter_irregular(CONTINUOUS, TIMES, z, x0, P0),
                                    1e-9),
    "ekf_filter": Case(lambda z, x0, P0: ekf_filter(NONLINEAR, z, x0, P0), 1e-9),
    "ukf_filter": Case(lambda z, x0, P0: PUBLIC["ukf_filter"](NONLINEAR, z, x0, P0), 1e-9),
    "ukf_filter[continuous-discrete]": Case(lambda z, x0, P0: PUBLIC["ukf_filter"](SDE, z, x0, P0), 1e-4),
    "imm_filter": Case(lambda z, x0, P0: PUBLIC["imm_filter"](MODEL, z, x0, P0, np.ones((1, 1))), 1e-9,
                       forms=NO_INNOVATION),
    "particle_filter": Case(lambda z, x0, P0: PUBLIC["particle_filter"](
        SDE, z, x0, P0, np.random.default_rng(5), particles=4000), 0.15, forms=NO_INNOVATION),
    "reference_filter": Case(lambda z, x0, P0: PUBLIC["reference_filter"](
        SDE, z, x0, P0, np.random.default_rng(6), particles=20000), 0.08, forms=NO_INNOVATION),
    "fem_filter": Case(lambda z, x0, P0: PUBLIC["fem_filter"](SDE, z, x0, P0), 0.02, forms=NO_INNOVATION),
    "kalman_filter_gated": Case(_gated, 1e-9),
    "track_gated": Case(_track_gated, 1e-9, reference=_first_fix_kf, arguments=("z",), nan="raises",
                        z=Z[GAP + 1:], extra_rows=1),
    "ekf_ranges": Case(_cell(cellular.ekf_ranges), 0.0, **_CELL),
    "fekf_ranges": Case(_cell(cellular.fekf_ranges), 1e-9, forms=GAUSSIAN[:-1], **_CELL),
    "fcs_ranges": Case(_cell(cellular.fcs_ranges), 1e-9, forms=GAUSSIAN[:-1], **_CELL),
    # the batch engine: states only, plus the shared steady covariance of the steady-state filters
    "batch.steady_state_filter": Case(lambda z, x0, P0: batch.steady_state_filter(MODEL, z, x0), 1e-9, forms=(),
                                      batch=True, twin="steady_state_filter", arguments=("z", "x0"), **STEADY),
    "batch.fir_filter": Case(lambda z, x0, P0: batch.fir_filter(MODEL, z), FIR_EPS, forms=(), batch=True,
                             twin="fir_filter", arguments=("z",), **FIR),
    "batch.kalman_filter": Case(lambda z, x0, P0: batch.kalman_filter(MODEL, z, x0, P0), 1e-9, forms=(),
                                batch=True, covariance=False, twin="kalman_filter"),
    "batch.ekf_ranges": Case(lambda z, x0, P0: batch.ekf_ranges(batch.RangeModel(
        np.eye(2), RANGE_Q, STATIONS[:1], [[0.222]], position=(0, 1)), z, x0, P0), 1e-9, forms=(), batch=True,
        covariance=False, twin="ekf_ranges", **_CELL),
}
#: tracking's registries name the same filters: fix filters run linear.FILTERS (or the gated KF),
#: cell methods the range filters
CASES.update({f"tracking.FIX_FILTERS[{key}]": CASES["kalman_filter_gated" if key == "kf" else
                                                    f"linear.FILTERS[{key.upper()}]"]
              for key in tracking.FIX_FILTERS})
#: (the method "locate" is not a filter over time: each scan is one geolocation request, its contract is
#: tests/serve/test_geolocate.py's)
RANGE_METHODS = [key for key in tracking.CELL_METHODS if key != "locate"]
CASES.update({f"tracking.CELL_METHODS[{key}]": CASES[tracking.CELL_METHODS[key].__name__] for key in RANGE_METHODS})

#: the batch forms of filters, checked against their single-track form
BATCH = {"ekf_filter_batch": "ekf_filter", "ekf_ranges_batch": "ekf_ranges", "fekf_ranges_batch": "fekf_ranges",
         "fcs_ranges_batch": "fcs_ranges"}

FILTERS = [f"linear.FILTERS[{n}]" for n in linear.FILTERS] + \
    [f"tracking.FIX_FILTERS[{k}]" for k in tracking.FIX_FILTERS] + \
    [f"tracking.CELL_METHODS[{k}]" for k in RANGE_METHODS] + \
    [name for name in CASES if name.split("[")[0] in PUBLIC]
_results: dict = {}


def _run(name: str) -> FilterResult | BatchFilterResult:
    if name not in _results:
        case = CASES[name]
        _results[name] = case.run(case.z, case.x0, case.P0)
    return _results[name]


def _track(case: Case, res) -> FilterResult:
    """The one track a case's result holds (track 0 of a batch)."""
    if case.batch:
        assert isinstance(res, BatchFilterResult) and res.B == 1 and res.method
        return res.run(0)
    return res


def test_every_filter_has_a_contract_case():
    missing = [f for f in PUBLIC if f not in BATCH and f not in CASES]
    assert not missing, f"filters without a contract case: {missing}"
    assert set(BATCH) <= set(PUBLIC), "a batch form listed here is no longer public"
    unregistered = [k for k in FILTERS if k not in CASES]
    assert not unregistered


@pytest.mark.parametrize("name", FILTERS)
def test_result_type_and_shapes(name):
    case = CASES[name]
    res = _track(case, _run(name))
    T_, m = case.z.shape
    T_ += case.extra_rows
    n = case.x0.shape[0]
    assert isinstance(res, FilterResult) and res.method
    assert res.x.shape == (T_, n)
    if case.covariance:
        assert res.P.shape == (T_, n, n)
    else:
        assert res.P is None, "P: the filter does not form it (mptrack.result documents None)"
    shapes = {"x_pred": (T_, n), "P_pred": (T_, n, n), "innovation": (T_, m), "S": (T_, m, m), "nis": (T_,)}
    for field, shape in shapes.items():
        value = getattr(res, field)
        if field in case.forms:
            assert value is not None and value.shape == shape, field
        else:
            assert value is None, f"{field}: the filter does not form it (mptrack.result documents None)"
    assert (res.loglik is not None) == ("loglik" in case.forms)
    if res.loglik is not None:
        assert isinstance(res.loglik, float) and np.isfinite(res.loglik)


@pytest.mark.parametrize("name", FILTERS)
def test_a_nan_row_only_predicts(name):
    case = CASES[name]
    if case.nan == "raises":
        with pytest.raises(MptrackError, match=r"^z: "):
            case.run(case.gapped, case.x0, case.P0)
        return
    res = _track(case, _run(name) if case.z is case.gapped else case.run(case.gapped, case.x0, case.P0))
    row = GAP
    if res.x_pred is not None:   # to rounding: LF/SS/FIR predictions are formed outside their loops
        _close(res.x[row], res.x_pred[row], 1e-12, "x")
        if case.nan == "predicts":
            _close(res.P[row], res.P_pred[row], 1e-12, "P")
    else:
        _close(res.x[row], case.F @ res.x[row - 1], 1e-12, "x")
    if res.innovation is not None:
        assert np.isnan(res.innovation[row]).all() and np.isnan(res.S[row]).all() and np.isnan(res.nis[row])
        assert np.isfinite(np.delete(res.nis, row)).all()
    assert np.isfinite(res.x).all() and (res.P is None or np.isfinite(res.P).all())


def _close(got, want, tol, what):
    scale = max(float(np.nanmax(np.abs(want))), 1e-300)
    assert np.array_equal(np.isnan(got), np.isnan(want)), f"{what}: NaN in other places"
    err = float(np.nanmax(np.abs(np.asarray(got) - want))) if np.size(want) else 0.0
    assert err <= tol * scale, f"{what}: max |difference| {err:.3g} > {tol:g} x {scale:.3g}"


@pytest.mark.parametrize("name", FILTERS)
def test_equals_the_reference_within_its_tolerance(name):
    """x, P, x_pred, P_pred, innovation, S, NIS of the filter equal the reference's (the KF on the linear
    model) within the filter's tolerance; loglik too."""
    case = CASES[name]
    res, kf = _track(case, _run(name)), case.reference()
    rows = slice(case.extra_rows, None)
    for field in case.fields:
        if field == "loglik":
            assert abs(res.loglik - kf.loglik) <= max(case.tol, 1e-12) * abs(kf.loglik), "loglik"
            continue
        _close(getattr(res, field)[rows], getattr(kf, field), max(case.tol, 1e-14), field)


@pytest.mark.parametrize("name", [n for n in FILTERS if n.split("[")[0] in PUBLIC or n.startswith("linear.")])
@pytest.mark.parametrize("bad", ["z columns", "z inf", "x0 length", "P0 inf"])
def test_bad_input_names_the_argument(name, bad):
    case = CASES[name]
    z, x0, P0 = case.z.copy(), case.x0.copy(), case.P0.copy()
    if bad == "z columns":
        z = np.hstack([z, z[:, :1]])
    elif bad == "z inf":
        z[1, 0] = np.inf
    elif bad == "x0 length":
        x0 = np.r_[x0, 0.0]
    else:
        P0[0, 0] = np.inf
    arg = bad.split()[0]
    if arg not in case.arguments:
        pytest.skip(f"{name} takes no {arg}")
    with pytest.raises(MptrackError, match=rf"^{arg}\b"):
        case.run(z, x0, P0)


@pytest.mark.parametrize("batch", list(BATCH))
def test_batch_form_is_the_single_track_form(batch):
    """A batch of one track is the single-track result, field by field."""
    single = BATCH[batch]
    case = CASES[single]
    if single == "ekf_filter":
        out = PUBLIC[batch](NONLINEAR, case.z[None], case.x0, case.P0)
    else:
        out = PUBLIC[batch](case.z[None], STATIONS[:1], case.x0[None], case.P0, RANGE_Q, 0.222)
    assert isinstance(out, BatchFilterResult) and out.B == 1
    one, ref = out.run(0), _run(single)
    for field in ("x", "P", *case.forms):
        got, want = getattr(one, field), getattr(ref, field)
        if field == "loglik":
            assert got == pytest.approx(want, rel=1e-10)
        else:
            _close(got, want, 1e-10, field)


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n].twin])
def test_batch_filter_is_its_single_track_twin(name):
    """Track 0 of a batch filter equals its single-track form in every field it forms (the batch
    engine's 1e-12 to the reference, with room for the FIR's summation order)."""
    case = CASES[name]
    one, ref = _track(case, _run(name)), _run(case.twin)
    assert one.method == ref.method
    for field in case.fields:
        _close(getattr(one, field), getattr(ref, field), 1e-10, field)
