"""Fuzzing harness of issue 16: call every public function with generated arguments and classify
what happens.

Outcomes (``classify``):
  ok            finite result (or NaN only where the input had NaN = missing)
  clean         an ``mptrack.errors`` exception whose message STARTS with an argument the caller passed
                (docs/design.md, Contracts; docs/decisions/2026-11-25-finite-answers.md); a DataError (OutputError) names the
                file the caller gave instead
  misnamed      an ``mptrack.errors`` exception whose message does not start with such a name
  unclean       any other exception (numpy/numba/scipy/pandas from deep inside)
  nonfinite     a non-finite result from all-finite input
  inf_accepted  a result returned although an input held +-Inf
  hang          the call took longer than the time bound
  memory        the call allocated more than the allocation bound (or raised MemoryError)

``TARGETS`` maps "package.name" to a :class:`Target` for every callable in the ``__all__`` of every
public package (``PACKAGES``) except the result records listed in ``RECORDS``; the test suite fails
when a public function has no entry.  Arguments come from strategies for every argument kind: arrays
of any shape, dtype and magnitude with NaN/Inf sprinkled, ragged lists, wrong types, huge sizes,
names, random generators, files and tables.
"""

from __future__ import annotations

import atexit
import dataclasses
import importlib
import re
import shutil
import signal
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
from hypothesis import strategies as st
from numba.core import event as numba_event

import mptrack
import mptrack.batch as batch
import mptrack.cellular as cellular
import mptrack.continuous as continuous
import mptrack.fuzzy as fuzzy
import mptrack.io as mio
import mptrack.linear as linear
import mptrack.metrics as metrics
import mptrack.models as models
import mptrack.nonlinear as nonlinear
import mptrack.radio as radio
import mptrack.report as report
import mptrack.result
import mptrack.riccati as riccati
import mptrack.runs as runs
import mptrack.serve as serve
import mptrack.sim as sim
import mptrack.tracking as tracking
from mptrack.errors import DataError, MptrackError, OutputError
from mptrack.models import LinearGaussianModel, assimakis_model_b, constant_velocity_continuous

#: Public modules of mptrack that are not fuzzed, and why.  Every other public module (no leading
#: underscore) is fuzzed: ``PACKAGES`` is found, not listed, so a new package is fuzzed (and fails the
#: suite until its functions have strategies) without anyone remembering to add it.
NOT_FUZZED = {
    "bench": "the benchmark suites: fixed inputs, run by `mptrack bench`",
    "cli": "the command line: its options are fuzzed through the CLI runs of the audit (tests/test_cli*.py)",
    "errors": "the exception classes",
    "experiments": "the paper reproductions: fixed inputs, run by `mptrack reproduce`",
}


def public_modules() -> tuple:
    """The public modules and packages of mptrack (no leading underscore), found on disk."""
    import pkgutil

    import mptrack
    return tuple(sorted(m.name for m in pkgutil.iter_modules(mptrack.__path__) if not m.name.startswith("_")))


#: "mptrack" is the top level (mptrack.track, mptrack.simulate)
PACKAGES = ("mptrack",) + tuple(name for name in public_modules() if name not in NOT_FUZZED)

TIME_BOUND_S = 10.0
ALLOC_BOUND = 512 * 2**20

MAGNITUDES = [0.0, 1.0, -1.0, 0.5, 2.0, 1e-300, 1e-30, 1e30, 1e150, 1e200, 1e300, -1e300, 1e308]
GARBAGE = [None, "abc", 1j, np.complex128(1 + 1j), [[1.0], [2.0, 3.0]], [], object(), {"a": 1}, True]
HUGE = [10**12, 2**62]


# ================================================================ argument strategies

@st.composite
def real_arrays(draw, shape, *, nonfinite=True):
    """A float array of ``shape`` with values of any magnitude, NaN/Inf sprinkled."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    kind = draw(st.sampled_from(["normal", "normal", "normal", "magnitude", "constant"]))
    size = int(np.prod(shape))
    if kind == "normal":
        arr = rng.normal(size=shape) * draw(st.sampled_from([1.0, 1.0, 10.0, 1e3]))
    elif kind == "magnitude":
        arr = rng.choice(MAGNITUDES, size=shape) * rng.choice([1.0, -1.0, 0.3], size=shape)
    else:
        arr = np.full(shape, draw(st.sampled_from(MAGNITUDES)))
    if nonfinite and size and draw(st.integers(0, 9)) == 0:
        idx = np.unravel_index(draw(st.integers(0, size - 1)), shape)
        arr[idx] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    dtype = draw(st.sampled_from([np.float64] * 6 + [np.float32, np.int64, np.complex128]))
    with np.errstate(all="ignore"):
        return arr.astype(dtype) if dtype is not np.complex128 else arr + 1j


def wrong_shapes(shape):
    """Arrays of the wrong number of dimensions or sizes (including empty ones)."""
    return st.sampled_from([(), (0,), (3,), (0, 2), (2, 3, 1), tuple(s + 1 for s in shape) or (2,)]).flatmap(
        lambda s: real_arrays(s, nonfinite=False))


def huge_view(shape):
    """A read-only broadcast view of 10^12 rows: valid values, an impossible size."""
    return st.just(np.broadcast_to(np.ones(shape[1:] if len(shape) > 1 else ()), (10**12,) + tuple(shape[1:])))


def arg(shape, *, garbage=True, valid=None):
    """Mostly a correctly-shaped array, sometimes a wrong shape, a huge view or a wrong type;
    ``valid`` (an array) is drawn as well, so that other arguments' faults are reached."""
    options = [real_arrays(shape)] * 5 + [wrong_shapes(shape), huge_view(shape)]
    if valid is not None:
        options += [st.just(np.array(valid, dtype=float))] * 4
    if garbage:
        options.append(st.sampled_from(GARBAGE))
    return st.one_of(*options)


def covariance(n):
    """A valid PSD covariance (of any scale) or a bad one."""
    @st.composite
    def good(draw):
        rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
        A = rng.normal(size=(n, n))
        return A @ A.T * draw(st.sampled_from([1.0, 1.0, 1e-30, 1e-8, 1e8, 1e150, 1e300])) + 1e-3 * np.eye(n)
    return st.one_of(good(), good(), good(), st.just(np.eye(n)), arg((n, n)))


def scalar(low=-10.0, high=10.0):
    return st.one_of(st.floats(low, high), st.floats(low, high),
                     st.sampled_from(MAGNITUDES + [np.inf, -np.inf, np.nan]),
                     st.sampled_from(GARBAGE + [np.array([1.0, 2.0])]))


def count(low=1, high=50, big=10**3):
    """A valid count, or a bad one: 0, negative, non-integer, text, None, a bool, huge (10^12, 2^62),
    or ``big``: large but feasible (a target whose work grows fast with it takes a smaller one)."""
    return st.one_of(st.integers(low, high), st.integers(low, high), st.integers(low, high),
                     st.sampled_from([0, -3, big, 2.5, np.float64(3.0), "3", None, True] + HUGE))


def names(*valid):
    """One of the valid names, or a wrong one."""
    return st.one_of(st.sampled_from(valid), st.sampled_from(valid),
                     st.sampled_from(["no-such-name", "", None, 3, 1.5]))


def flags():
    return st.one_of(st.booleans(), st.booleans(), st.sampled_from([None, "yes", 2]))


def rngs():
    return st.one_of(st.integers(0, 2**32 - 1).map(np.random.default_rng),
                     st.integers(0, 2**32 - 1).map(np.random.default_rng), st.sampled_from([None, 3, "rng"]))


def maybe(strategy):
    return st.one_of(st.none(), strategy)


def just(value):
    return st.one_of(st.just(value), st.just(value), st.sampled_from([None, "abc", 3]))


# ================================================================ valid fixtures

B = assimakis_model_b()
CV = constant_velocity_continuous(0.1)
CV2 = constant_velocity_continuous(1.0, axes=2, sigma_r2=25.0)
STATIONS = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0]])
STATIONS3 = np.array([[0.0, 0.0, 0.03], [2.0, 0.0, 0.03], [1.0, 1.7, 0.03]])
RANGE_MODEL = batch.RangeModel.constant_velocity(1.0, 1.0, STATIONS, 25.0)
Z_RANGES = np.linalg.norm(np.array([[300.0, 400.0], [310.0, 400.0], [320.0, 405.0]])[:, None] - STATIONS, axis=-1)
Z_KM = np.linalg.norm(np.array([[0.3, 0.4, 0.0015], [0.31, 0.4, 0.0015], [0.32, 0.41, 0.0015]])[:, None] - STATIONS3,
                      axis=-1)
KF = linear.kalman_filter(B, np.ones((4, 1)), P0=np.eye(2))
SS_RESULT = linear.steady_state_filter(B, np.ones((4, 1)))
KFI = linear.kalman_filter_irregular(CV, [1.0, 2.0, 3.0], np.ones((3, 1)))
STEADY = riccati.steady_state(B)
LP = riccati.lainiotis_parameters(B)
NLM = models.nonlinear_model(models.constant_velocity(1.0, 0.1, 2), models.ranges(STATIONS, 25.0))
EKF = nonlinear.ekf_filter(NLM, Z_RANGES, [300.0, 0.0, 400.0, 0.0], np.eye(4) * 100.0)
UKF = nonlinear.ukf_filter(NLM, Z_RANGES, [300.0, 0.0, 400.0, 0.0], np.eye(4) * 100.0, alpha=0.5)
ZHAO = continuous.zhao2013_model(variant="vdp", diffusion_scale=0.01)
ZZ = continuous.simulate_sde(ZHAO, 3, np.random.default_rng(1), continuous.ZHAO2013_X0)[1]
FIS = cellular.bouzera_fekf_fis()
IMM_MODELS, IMM_TRANSITION = nonlinear.cv_ca_models(1.0, 0.1, 0.01, models.position(25.0 * np.eye(2), position=(0, 3)))
GATED = tracking.kalman_filter_gated(CV2, [0.0, 1.0, 2.0], np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]),
                                     np.zeros(4), np.eye(4) * 100.0)
MF = fuzzy.MembershipFunction("triangular", (0.0, 0.5, 1.0))
LOG, _ = tracking.simulate("gps", 1, np.random.default_rng(0), duration_s=12.0)
TRACK_ID, ROWS = next(mio.iter_tracks(LOG))
CELL_LOG, _CELLS = tracking.simulate("urban-3bts", 1, np.random.default_rng(0), duration_s=4.0)
CELLS = mio.read_cells(_CELLS)
CELL_ROWS = next(mio.iter_tracks(CELL_LOG, mio.MEASUREMENTS))[1]
POINTS = tracking.track(LOG)
POINTS_WITH_TRUTH = POINTS.assign(true_lat=POINTS["lat"] + 1e-5, true_lon=POINTS["lon"])

WORKDIR = Path(tempfile.mkdtemp(prefix="mptrack-hardening-"))
atexit.register(shutil.rmtree, WORKDIR, ignore_errors=True)


def _file(name: str, content) -> Path:
    path = WORKDIR / name
    if isinstance(content, pd.DataFrame):
        content.to_csv(path, index=False)
    else:
        path.write_bytes(content)
    return path


LOG_CSV = _file("log.csv", LOG)
CELLS_CSV = _file("cells.csv", _CELLS)
POINTS_CSV = WORKDIR / "points.csv"
POINTS.to_csv(POINTS_CSV, index=False)


def paths(valid: Path):
    """An input path: the valid file, or an empty, garbled, missing or unreadable one, or not a path."""
    bad = [_file("empty.csv", b""), _file("junk.csv", bytes(range(256)) * 4),
           _file("header.csv", b"track_id,time,lat,lon\n"), _file("nan.csv", b"time,lat,lon\n0,nan,inf\n1,1e400,2\n"),
           _file("ragged.csv", b"time,lat,lon\n0,1\n1,2,3,4\n"), WORKDIR / "missing.csv", WORKDIR,
           _file("noext", b"x"), _file("junk.gpx", b"<gpx><trk><trkseg><trkpt lat='x'/></trkseg></trk></gpx>")]
    return st.one_of(st.just(valid), st.just(str(valid)), st.just(valid), st.sampled_from(bad),
                     st.sampled_from([None, 3, b"\x00"]))


def out_paths(suffix=".csv"):
    return st.one_of(st.sampled_from([WORKDIR / f"out{suffix}", WORKDIR / "out.parquet", WORKDIR / "out.geojson"]),
                     st.sampled_from([WORKDIR / "out.xyz", WORKDIR / "no-dir" / "x" / "out.csv", WORKDIR, None, 3]))


@st.composite
def frames(draw, valid: pd.DataFrame, columns=None):
    """``valid`` (a DataFrame), or a copy with a column dropped, a value replaced (NaN, +-Inf, huge,
    text), no rows, or not a DataFrame at all."""
    kind = draw(st.sampled_from(["valid", "valid", "drop", "value", "value", "empty", "garbage"]))
    df = valid.copy()
    cols = list(columns or df.columns)
    if kind == "drop":
        df = df.drop(columns=[draw(st.sampled_from(cols))])
    elif kind == "value":
        col = draw(st.sampled_from(cols))
        value = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, "abc", None]))
        df[col] = df[col].astype(object)
        df.iloc[draw(st.integers(0, len(df) - 1)), df.columns.get_loc(col)] = value
    elif kind == "empty":
        df = df.iloc[:0]
    elif kind == "garbage":
        return draw(st.sampled_from(GARBAGE[:3] + [np.ones((3, 2))]))
    return df


# ================================================================ targets

@dataclasses.dataclass(frozen=True)
class Target:
    """A public callable under test: ``call(**drawn)`` with ``strategy`` drawing the keyword arguments.

    passed      further argument names the wrapper passes (a message may start with them)
    inf_args    arguments for which +-Inf is a valid value (a fuzzy set's open shoulder)
    inf_result  the result may hold +-Inf by design (the shoulders of fuzzy sets)
    nan_result  the result may hold NaN by design (a point table's documented missing values:
                no NIS at a track's first fix, no velocity of a position-only filter)
    """

    call: Callable
    strategy: st.SearchStrategy
    params: tuple
    inf_args: tuple = ()
    inf_result: bool = False
    nan_result: bool = False


TARGETS: dict[str, Target] = {}


def target(qualname: str, call=None, /, *, passed=(), inf_args=(), inf_result=False, nan_result=False,
           **strategies) -> None:
    """Register ``qualname`` ("package.function"); ``call`` defaults to the public object itself."""
    if qualname in TARGETS:
        raise ValueError(f"{qualname} registered twice")
    if call is None:
        package, attr = qualname.split(".", 1)
        call = _public(package, attr)
    TARGETS[qualname] = Target(call, st.fixed_dictionaries(strategies), tuple(strategies) + tuple(passed),
                           tuple(inf_args), inf_result, nan_result)


def _module(package: str):
    return importlib.import_module("mptrack" if package == "mptrack" else f"mptrack.{package}")


def _public(package: str, attr: str):
    obj = _module(package)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


#: Result records: built by mptrack and returned, not built from user input; their array fields are
#: checked where a record is passed back in (``check_record``).  Warning and exception classes too.
RECORDS = {
    "linear.FitResult", "linear.FilterSpec", "linear.Implementation", "batch.GainSequence", "runs.Chunk", "runs.Chunks",
    "riccati.SteadyState", "riccati.LainiotisParameters", "continuous.BlockKernels",
    "continuous.GridDensity", "continuous.GridMixture", "continuous.FEMStep", "nonlinear.IMMResult", "radio.GsmBand", "radio.ValidityWarning",
    "fuzzy.AnfisResult", "tracking.GatedResult", "tracking.MotionModel", "io.ReadReport", "io.InputNotSorted",
    "io.Column", "io.Schema", "result.FilterResult", "result.BatchFilterResult", "cellular.Radio", "io.Skipped",
}


def public_callables() -> dict:
    """{"package.name": object} of every callable in the public packages' ``__all__``."""
    out = {}
    for package in PACKAGES:
        module = _module(package)
        for attr in module.__all__:
            if callable(getattr(module, attr)):
                out[f"{package}.{attr}"] = getattr(module, attr)
    return out


def _lgm_spec(n=None, m=None):
    """Matrices of a LinearGaussianModel (constructor errors count as outcomes)."""
    @st.composite
    def spec(draw):
        nn = n or draw(st.integers(1, 3))
        mm = m or draw(st.integers(1, 2))
        F = draw(st.one_of(real_arrays((nn, nn), nonfinite=False), st.just(np.eye(nn) * 0.9)))
        H = draw(st.one_of(real_arrays((mm, nn), nonfinite=False), st.just(np.eye(mm, nn))))
        return dict(F=F, H=H, Q=draw(covariance(nn)), R=draw(covariance(mm)))
    return spec()


def _model(spec):
    return LinearGaussianModel(spec["F"], spec["H"], spec["Q"], spec["R"]) if isinstance(spec, dict) else spec


MODEL = st.one_of(st.just(B), st.just(B), _lgm_spec(), st.sampled_from([None, "model", CV]))
MODEL_PASSED = ("F", "H", "Q", "R")


def _result(x, P):
    return mptrack.result.FilterResult(x=x, P=P, method="test")


# --- linear -----------------------------------------------------------------------------------------------
for _name in ("kalman_filter", "lainiotis_filter", "steady_state_filter", "fir_filter"):
    target(f"linear.{_name}", (lambda fn: lambda model, z, x0, P0: fn(_model(model), z, x0, P0))(
        getattr(linear, _name)), passed=MODEL_PASSED, model=MODEL, z=arg((5, 1), valid=np.ones((5, 1))),
        x0=maybe(arg((2,))), P0=maybe(covariance(2)))
target("linear.kalman_step", x=arg((2,)), P=covariance(2), z=arg((1,)), F=arg((2, 2), valid=B.F),
       H=arg((1, 2), valid=B.H), Q=covariance(2), R=covariance(1), joseph=flags(), Bu=maybe(arg((2,))))
target("linear.lainiotis_step", lambda x, P, z, F: linear.lainiotis_step(LP, F, B.Q, x, P, z, np.eye(2)),
       x=arg((2,)), P=covariance(2), z=arg((1,)), F=arg((2, 2), valid=B.F))
target("linear.fir_order", A=arg((2, 2), valid=0.5 * np.eye(2)), eps=scalar(0, 1), norm=names(2, 1, "fro", np.inf),
       max_order=count(1, 1000), inf_args=("norm",))     # norm=inf: numpy's max-row-sum order, not a number
target("linear.fir_coefficients", A=arg((2, 2), valid=0.5 * np.eye(2)), B=arg((2, 1), valid=np.ones((2, 1))),
       M=count())
target("linear.join_results", a=just(KF), b=st.one_of(st.just(KF), st.just(SS_RESULT), st.builds(
    _result, real_arrays((4, 2)), real_arrays((4, 2, 2)))), method=names("join"))
target("linear.per_axis", lambda run, z, x0: linear.per_axis(run, B, z, x0),
       run=just(linear.steady_state_filter), z=arg((5, 2), valid=np.ones((5, 2))), x0=maybe(arg((4,))),
       passed=("axis_model",))
target("linear.get_filter", name=names(*linear._registry.FILTERS))
target("linear.get_implementation", key=st.one_of(count(1, 12), names("KF-A", "jssklf-b")))
target("linear.steady_state_predictor", lambda model, z, N, method: linear.steady_state_predictor(
    _model(model), z, N, method=method), passed=MODEL_PASSED, model=MODEL, z=arg((4, 1), valid=np.ones((4, 1))),
    N=count(), method=names("recursive", "inverse-free"))
target("linear.prediction_matrices", lambda model, N: linear.prediction_matrices(_model(model), N),
       passed=MODEL_PASSED, model=MODEL, N=count())
target("linear.prediction_covariance", lambda model, P_filt, N: linear.prediction_covariance(_model(model), P_filt, N),
       passed=MODEL_PASSED, model=MODEL, P_filt=covariance(2), N=count())
target("linear.predict_ahead", lambda x, P, N: linear.predict_ahead(B, _result(x, P), N),
       x=real_arrays((3, 2)), P=real_arrays((3, 2, 2)), N=count(), passed=("result",))
target("linear.rts_smoother", lambda x, P: linear.rts_smoother(B, dataclasses.replace(KF, x=x, P=P)),
       x=arg((4, 2), valid=KF.x), P=arg((4, 2, 2), valid=KF.P), passed=("result",))
target("linear.steady_state_smoother", lambda x: linear.steady_state_smoother(B, dataclasses.replace(SS_RESULT, x=x)),
       x=arg((4, 2), valid=SS_RESULT.x), passed=("result",))
target("linear.kalman_filter_irregular", lambda times, z, x0: linear.kalman_filter_irregular(CV, times, z, x0),
       times=arg((3,), valid=[1.0, 2.0, 3.5]), z=arg((3, 1), valid=np.ones((3, 1))), x0=maybe(arg((2,))))
target("linear.rts_smoother_irregular", lambda times, x: linear.rts_smoother_irregular(
    CV, times, dataclasses.replace(KFI, x=x)), times=arg((3,), valid=[1.0, 2.0, 3.0]), x=arg((3, 2), valid=KFI.x),
    passed=("result",))
target("linear.sampling_intervals", times=arg((3,), valid=[1.0, 2.0, 3.0]), t0=scalar())
Z_B = sim.simulate_linear(B, 6, np.random.default_rng(0))[1]
target("linear.fit_em", lambda model, z, x0, P0, estimate, iterations, tol, prior: linear.fit_em(
    _model(model), z, x0=x0, P0=P0, estimate=estimate, iterations=iterations, tol=tol, prior=prior),
    passed=MODEL_PASSED, model=MODEL, z=arg((6, 1), valid=Z_B), x0=maybe(arg((2,))), P0=covariance(2),
    estimate=st.one_of(st.sampled_from([("Q", "R"), ("F", "H", "Q", "R", "x0", "P0"), "R", ("x0", "P0")]),
                       st.sampled_from([("Q", "R", "x0"), ("Q", "K"), (), 3, None])),
    iterations=st.one_of(st.integers(0, 8), count(0, 5, big=50)), tol=st.one_of(st.floats(0.0, 1e-3), scalar(0, 1)),
    prior=names("initial", "first-measurement"))


Z_B40 = sim.simulate_linear(B, 40, np.random.default_rng(0))[1]    # enough to determine q and sigma


def _cv_b(q, sigma):
    """Model B with its process noise scaled by q and measurement sd sigma: fit_ml's model function."""
    return LinearGaussianModel(B.F, B.H, q * B.Q, [[sigma * sigma]])


target("linear.fit_ml", lambda q, sigma, z, x0, P0, positive, iterations: linear.fit_ml(
    _cv_b, z, {"q": q, "sigma": sigma}, x0=x0, P0=P0, positive=positive, iterations=iterations),
    q=st.one_of(st.floats(0.01, 10.0), st.floats(0.01, 10.0), scalar(0, 10)),
    sigma=st.one_of(st.floats(0.1, 10.0), st.floats(0.1, 10.0), scalar(0, 10)), z=arg((40, 1), valid=Z_B40),
    x0=maybe(arg((2,))), P0=covariance(2),
    positive=st.one_of(st.none(), st.none(), st.just(("q",)), st.sampled_from([("x",), 3, ()])),
    iterations=st.one_of(st.integers(1, 20), count(1, 5, big=50)), passed=("params", "model"))

# --- batch ------------------------------------------------------------------------------------------------
for _name in ("steady_state_filter", "kalman_filter"):
    target(f"batch.{_name}", (lambda fn: lambda model, z, x0, lengths: fn(_model(model), z, x0, lengths=lengths))(
        getattr(batch, _name)), passed=MODEL_PASSED, model=MODEL, z=arg((2, 4, 1), valid=np.ones((2, 4, 1))),
        x0=maybe(arg((2,))), lengths=maybe(arg((2,), valid=[4, 2])))
target("batch.fir_filter", lambda model, z, M: batch.fir_filter(_model(model), z, M=M), passed=MODEL_PASSED,
       model=MODEL, z=arg((2, 4, 1), valid=np.ones((2, 4, 1))), M=maybe(count()))
target("batch.predict", lambda model, x, steps: batch.predict(_model(model), x, steps), passed=MODEL_PASSED,
       model=MODEL, x=arg((2, 3, 2), valid=np.ones((2, 3, 2))), steps=count())
target("batch.per_axis", lambda z, x0: batch.per_axis(batch.kalman_filter, B, z, x0),
       z=arg((2, 4, 2), valid=np.ones((2, 4, 2))), x0=maybe(arg((4,))), passed=("axis_model", "run"))
target("batch.gain_sequence", lambda model, steps, P0: batch.gain_sequence(_model(model), steps, P0),
       passed=MODEL_PASSED, model=MODEL, steps=count(1, 20), P0=maybe(covariance(2)))
target("batch.monte_carlo", lambda model, steps, runs, chunk_size: batch.monte_carlo(
    _model(model), steps, runs, seed=1, chunk_size=chunk_size), passed=MODEL_PASSED + ("seed",), model=MODEL,
    steps=count(1, 20), runs=count(1, 20), chunk_size=count(1, 10))
target("batch.MonteCarloTask", lambda model, steps, P0: batch.MonteCarloTask(_model(model), steps, P0=P0)(
    runs.make_chunks(2, 2, seed=1)[0]), passed=MODEL_PASSED, model=MODEL, steps=count(1, 20), P0=maybe(covariance(2)))
target("batch.filter_chunked", lambda z, chunk_size: batch.filter_chunked(batch.steady_state_filter, B, z,
                                                                           chunk_size=chunk_size),
       z=arg((3, 4, 1), valid=np.ones((3, 4, 1))), chunk_size=count(1, 5), passed=("run", "model"))
target("batch.RangeModel", lambda F, Q, stations, R: batch.RangeModel(F, Q, stations, R),
       F=arg((4, 4), valid=RANGE_MODEL.F), Q=covariance(4), stations=arg((3, 2), valid=STATIONS), R=covariance(3))
target("batch.RangeModel.constant_velocity", lambda dt, sigma_a2, sigma_r2, stations:
       batch.RangeModel.constant_velocity(dt, sigma_a2, stations, sigma_r2), dt=scalar(0, 10), sigma_a2=scalar(0, 10),
       sigma_r2=scalar(0, 100), stations=arg((3, 2), valid=STATIONS))
target("batch.ekf_ranges", lambda z, x0, P0: batch.ekf_ranges(RANGE_MODEL, z, x0, P0),
       z=arg((2, 3, 3), valid=np.full((2, 3, 3), 500.0)), x0=arg((4,), valid=[300.0, 0.0, 400.0, 0.0]),
       P0=covariance(4), passed=("model",))

# --- riccati ----------------------------------------------------------------------------------------------
target("riccati.steady_state", lambda model, method, P0: riccati.steady_state(_model(model), method, P0=P0),
       passed=MODEL_PASSED, model=MODEL, method=names(*riccati.METHODS), P0=maybe(covariance(2)))
target("riccati.riccati_step", lambda model, P_pred: riccati.riccati_step(_model(model), P_pred),
       passed=MODEL_PASSED, model=MODEL, P_pred=covariance(2))
target("riccati.riccati_residual", lambda model, P_pred: riccati.riccati_residual(_model(model), P_pred),
       passed=MODEL_PASSED, model=MODEL, P_pred=covariance(2))
target("riccati.lainiotis_parameters", lambda model: riccati.lainiotis_parameters(_model(model)),
       passed=MODEL_PASSED, model=MODEL)
target("riccati.check_detectable", F=arg((2, 2), valid=B.F), H=arg((1, 2), valid=B.H))
target("riccati.check_stabilisable", F=arg((2, 2), valid=B.F), Q_factor=arg((2, 2), valid=np.eye(2)))
target("riccati.power_sum", F=arg((2, 2), valid=B.F), Q=covariance(2), N=count())

# --- models -----------------------------------------------------------------------------------------------
target("models.LinearGaussianModel", lambda F, H, Q, R, G: (
    LinearGaussianModel(F, H, Q, R) if G is None else LinearGaussianModel(F, H, None, R, G=G, Qw=[[0.01]])),
    F=arg((2, 2), valid=B.F), H=arg((1, 2), valid=B.H), Q=covariance(2), R=covariance(1),
    G=maybe(arg((2, 1), valid=[[0.5], [1.0]])), passed=("Qw",))
target("models.require_model", model=MODEL, name=names("model", "axis_model"), passed=("axis_model",))
target("models.stack_axes", axis_model=just(B), axes=count(1, 4))
target("models.assimakis_model_a", axes=count(1, 3), dt=scalar(0, 5), sigma_q2=scalar(0, 1), sigma_r2=scalar(0, 1),
       measurement=names("printed", "position"))
target("models.assimakis_model_b", dt=scalar(0, 5), sigma_q2=scalar(0, 1), sigma_r2=scalar(0, 1))
target("models.ContinuousLinearModel", Phi=arg((2, 2), valid=CV.Phi), L=arg((2, 1), valid=CV.L), Qc=covariance(1),
       H=arg((1, 2), valid=CV.H), R=covariance(1))
target("models.van_loan", Phi=arg((2, 2), valid=CV.Phi), L=arg((2, 1), valid=CV.L), Qc=covariance(1), dt=scalar(0, 10))
target("models.discretize", model=just(CV), dt=scalar(0, 10))
target("models.discretize_intervals", model=just(CV), dts=arg((3,), valid=[1.0, 0.5, 2.0]))
for _name in ("constant_velocity_continuous", "constant_acceleration_continuous"):
    target(f"models.{_name}", q=scalar(0, 10), axes=count(1, 3), sigma_r2=scalar(0, 10))
for _name in ("constant_velocity", "constant_acceleration", "cv_discrete_white_noise", "ca_discrete_white_noise"):
    target(f"models.{_name}", dt=scalar(0, 10), q=scalar(0, 10), axes=count(1, 3), sigma_r2=scalar(0, 10))
target("models.NonlinearModel", lambda Q, R, scale: models.NonlinearModel(
    lambda x: x * scale, lambda x: x[..., :1] * scale, Q, R), Q=covariance(2), R=covariance(1), scale=scalar(),
    passed=("f", "h"))
target("models.MeasurementModel", lambda R: models.nonlinear_model(
    models.constant_velocity(1.0, 0.1), models.MeasurementModel(lambda x: x[..., :1], lambda x: np.eye(1, 2), R)),
    R=covariance(1), passed=("measurement",))
target("models.nonlinear_model", motion=st.one_of(st.just(models.constant_velocity(1.0, 0.1, 2)), just(B)),
       measurement=just(models.ranges(STATIONS, 25.0)))
target("models.wrap_angles", nu=arg((3, 2), valid=np.ones((3, 2)) * 7.0),
       periods=st.one_of(st.just((None, 2 * np.pi)), st.sampled_from([(None,), (1.0, -1.0), (np.inf, 0.0), None, "ab",
                                                                      (0.0, np.nan), (1e-300, 1e300)])))
for _name in ("ranges", "bearings", "tdoa"):
    target(f"models.{_name}", stations=arg((3, 2), valid=STATIONS), R=st.one_of(scalar(0, 100), covariance(3)),
           position=st.one_of(st.just((0, 2)), st.sampled_from([(0,), (0, 9), (-1, 2), "xy", None, (0.5, 1)])))
target("models.range_bearing", sensor=arg((2,), valid=[0.0, 0.0]), R=st.one_of(covariance(2),
                                                                              st.just(np.diag([25.0, 1e-4]))))
target("models.range_rate", sensor=arg((2,), valid=[0.0, 0.0]), R=scalar(0, 100),
       velocity=st.one_of(st.just((1, 3)), st.sampled_from([(1,), (9, 3), None])))
target("models.position", R=st.one_of(covariance(2), scalar(0, 100)),
       position=st.one_of(st.just((0, 2)), st.sampled_from([(0,), (0, 9), (-1, 2), "xy", None])))
target("models.stack_measurements", lambda first, second: models.stack_measurements(first, second),
       first=just(models.ranges(STATIONS, 25.0)), second=just(models.bearings(STATIONS, 1e-4)),
       passed=("measurements",))

# --- cellular, continuous, nonlinear --------------------------------------------------------------------------------------------
_RANGE_FILTER = dict(z=arg((3, 3), valid=Z_RANGES), stations=arg((3, 2), valid=STATIONS),
                     x0=arg((2,), valid=[300.0, 400.0]), P0=covariance(2), Q=covariance(2),
                     R=st.one_of(scalar(0, 100), covariance(3)))
_KM_FILTER = dict(z=arg((3, 3), valid=Z_KM), stations=arg((3, 3), valid=STATIONS3),
                  x0=arg((3,), valid=[0.3, 0.4, 0.0015]), P0=covariance(3), Q=covariance(3),
                  R=st.one_of(scalar(0, 1), st.just(0.222)))
target("cellular.check_stations", stations=arg((3, 2), valid=STATIONS), min_count=count(1, 4))
target("cellular.ekf_ranges", **_RANGE_FILTER, motion=names("random-walk"))
target("cellular.ekf_ranges_batch", lambda z, x0, **kw: cellular.ekf_ranges_batch(z, x0=x0, **kw),
       **{**_RANGE_FILTER, "z": arg((1, 3, 3), valid=Z_RANGES[None]), "x0": arg((1, 2), valid=[[300.0, 400.0]])})
for _name in ("fekf_ranges", "fcs_ranges"):
    target(f"cellular.{_name}", **_KM_FILTER)
    target(f"cellular.{_name}_batch", (lambda fn: lambda z, x0, **kw: fn(z, x0=x0, **kw))(
        getattr(cellular, f"{_name}_batch")), **{**_KM_FILTER, "z": arg((1, 3, 3), valid=Z_KM[None]),
                                                 "x0": arg((1, 3), valid=[[0.3, 0.4, 0.0015]])})
target("cellular.motion_matrix", motion=names("cv", "random-walk"), dim=count(1, 3), dt=scalar(0, 10))
target("cellular.motion_position", motion=names("cv", "random-walk"), dim=count(1, 3))
target("cellular.range_measurement", x=arg((2,), valid=[300.0, 400.0]), stations=arg((3, 2), valid=STATIONS))
target("cellular.range_fix", ranges=arg((3,), valid=Z_RANGES[0]), stations=arg((3, 2), valid=STATIONS),
       height=maybe(scalar(0, 100)))
target("cellular.bouzera_fekf_fis", inn_universe_km=st.one_of(st.just((0.0, 1.5)), arg((2,))),
       s_universe_km2=st.one_of(st.just((0.22, 0.32)), arg((2,))))
target("cellular.bouzera_fcs_fis", distance_universe_km=st.one_of(st.just((0.0, 1.5)), arg((2,))),
       consequents=st.one_of(st.just((1.0, 0.75, 0.5, 0.25, 0.0)), arg((5,))))
target("cellular.local_solutions", x_pred=arg((1, 2), valid=[[300.0, 400.0]]), P_pred=arg((1, 2, 2),
       valid=[np.eye(2)]), z=arg((1, 3), valid=Z_RANGES[:1]), stations=arg((3, 2), valid=STATIONS),
       R_diag=arg((3,), valid=[25.0] * 3))
_LS = cellular.local_solutions(np.array([[300.0, 400.0]]), np.eye(2)[None], Z_RANGES[:1], STATIONS, np.full(3, 25.0))
target("cellular.fuse_local_solutions", lambda x_pred, P_pred, innov, y, covariance: cellular.fuse_local_solutions(
    x_pred, P_pred, _LS[1], _LS[2], innov, _LS[4], np.full(3, 25.0), y, covariance=covariance),
    x_pred=arg((1, 2), valid=[[300.0, 400.0]]), P_pred=arg((1, 2, 2), valid=[np.eye(2)]),
    innov=arg((1, 3), valid=_LS[3]), y=arg((1, 3), valid=[[0.2, 0.3, 0.5]]), covariance=names("exact", "paper"),
    passed=("K", "H", "S", "R_diag"))
target("continuous.ContinuousDiscreteModel", lambda Q, R, dt, substeps: continuous.ContinuousDiscreteModel(
    lambda x: -x, Q, lambda x: x[..., :1], R, dt, substeps=substeps), Q=covariance(2), R=covariance(1),
    dt=scalar(0, 10), substeps=count(1, 30))
target("continuous.zhao2013_model", variant=names("printed", "vdp"), diffusion_scale=scalar(0, 2),
       bearing=names("atan2", "atan"), dt=scalar(0, 2), substeps=count(1, 30))
target("continuous.linear_sde_model", A=arg((2, 2), valid=[[0.0, 1.0], [-2.0, -0.3]]), Q=covariance(2),
       H=arg((1, 2), valid=[[1.0, 0.5]]), R=covariance(1), dt=scalar(0, 2), substeps=count(1, 30))
target("continuous.simulate_sde", lambda steps, rng, x0: continuous.simulate_sde(ZHAO, steps, rng, x0),
       steps=count(1, 5, big=100), rng=rngs(), x0=arg((2,), valid=continuous.ZHAO2013_X0), passed=("model",))
target("continuous.FEMGrid", lo=arg((2,), valid=[-1.0, -1.0]), hi=arg((2,), valid=[1.0, 1.0]), n1=count(1, 6),
       n2=count(1, 6))
_FEM_SCHEMES = names(*continuous.FEM_SCHEMES)
target("continuous.fem_filter", lambda z, x0, P0, grid, scheme, width, substeps, splits, box: continuous.fem_filter(
    ZHAO, z, x0, P0, grid=grid, scheme=scheme, width=width, substeps=substeps, splits=splits, box=box),
    z=arg((2, 2), valid=ZZ[:2]), x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2),
    grid=st.one_of(st.just((6, 6)), st.sampled_from([(0, 3), (3,), "a", (10**6, 10**6), (2.5, 3)])),
    scheme=_FEM_SCHEMES, width=st.one_of(st.just(4.0), scalar(0, 8)), substeps=maybe(count(1, 20)),
    splits=st.one_of(st.just(4), count(1, 6)),
    box=st.one_of(st.none(), st.none(), st.just(((-6.0, -6.0), (6.0, 6.0))), st.sampled_from(
        [((0.0, 0.0), (1.0, 1.0)), ((1.0, 1.0), (-1.0, -1.0)), "box", ((np.inf, 0.0), (1.0, 1.0)), (1.0,)])),
    passed=("model",))
target("continuous.fem_steps", lambda z, x0, P0, scheme: list(continuous.fem_steps(ZHAO, z, x0, P0, grid=(6, 6),
                                                                                   scheme=scheme)),
       z=arg((2, 2), valid=ZZ[:2]), x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2),
       scheme=_FEM_SCHEMES, passed=("model",))
target("continuous.fem_substeps", grid=st.one_of(st.just((20, 20)), st.sampled_from([(0, 3), (3,), "a", (2.5, 3),
                                                                                    (10**6, 10**6), None])))
target("continuous.fem_profile", lambda z, x0, P0, repeats: continuous.fem_profile(ZHAO, z, x0, P0, grid=(6, 6),
                                                                                    repeats=repeats),
       z=arg((2, 2), valid=ZZ[:2]), x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2),
       repeats=count(1, 2, big=3), passed=("model", "grid"))
target("continuous.shape_functions", xi=arg((3,), valid=[0.0, 0.5, -1.0]), eta=arg((3,), valid=[0.0, 1.0, 0.2]))
target("nonlinear.ukf_filter", lambda z, x0, P0, alpha, beta, kappa, substeps, compiled: nonlinear.ukf_filter(
    ZHAO, z, x0, P0, alpha=alpha, beta=beta, kappa=kappa, substeps=substeps, compiled=compiled),
    z=arg((3, 2), valid=ZZ), x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2), alpha=scalar(0, 2),
    beta=scalar(0, 3), kappa=scalar(-1, 3), substeps=maybe(count(1, 30)), compiled=maybe(flags()), passed=("model",))
target("nonlinear.ukf_filter[discrete]", lambda z, x0, P0, alpha, prior: nonlinear.ukf_filter(
    NLM, z, x0, P0, alpha=alpha, prior=prior), z=arg((3, 3), valid=Z_RANGES),
    x0=arg((4,), valid=[300.0, 0.0, 400.0, 0.0]), P0=covariance(4), alpha=scalar(0, 2),
    prior=names("initial", "first-measurement"), passed=("model",))
target("nonlinear.ukf_smoother", lambda result, x, alpha: nonlinear.ukf_smoother(
    NLM, dataclasses.replace(result, x=x), alpha=alpha), result=st.sampled_from([EKF, UKF]),
    x=arg((3, 4), valid=EKF.x), alpha=maybe(scalar(0, 2)), passed=("model",))
target("nonlinear.ekf_filter", lambda z, x0, P0: nonlinear.ekf_filter(NLM, z, x0, P0),
       z=arg((3, 3), valid=Z_RANGES), x0=arg((4,), valid=[300.0, 0.0, 400.0, 0.0]), P0=covariance(4),
       passed=("model",))
target("nonlinear.ekf_smoother", lambda x, P: nonlinear.ekf_smoother(NLM, dataclasses.replace(EKF, x=x, P=P)),
       x=arg((3, 4), valid=EKF.x), P=arg((3, 4, 4), valid=EKF.P), passed=("model", "result"))
target("nonlinear.ekf_step", lambda x, P, z, k: nonlinear.ekf_step(NLM, x, P, z, k),
       x=arg((4,), valid=[300.0, 0.0, 400.0, 0.0]), P=covariance(4), z=arg((3,), valid=Z_RANGES[0]), k=count(0, 3),
       passed=("model",))
target("nonlinear.ekf_filter_batch", lambda z, x0, P0: nonlinear.ekf_filter_batch(NLM, z, x0, P0),
       z=arg((2, 3, 3), valid=np.stack([Z_RANGES] * 2)), x0=arg((4,), valid=[300.0, 0.0, 400.0, 0.0]),
       P0=covariance(4), passed=("model",))
target("nonlinear.imm_filter", lambda z, x0, P0, transition, mu0, prior: nonlinear.imm_filter(
    IMM_MODELS, z, x0, P0, transition, mu0=mu0, prior=prior), z=arg((3, 2), valid=np.ones((3, 2))),
    x0=arg((6,), valid=np.zeros(6)), P0=covariance(6), transition=arg((2, 2), valid=IMM_TRANSITION),
    mu0=maybe(arg((2,), valid=[0.5, 0.5])), prior=names("initial", "first-measurement"), passed=("models",))
target("nonlinear.cv_ca_models", dt=scalar(0, 5), q_cv=scalar(0, 5), q_ca=scalar(0, 5),
       measurement=just(models.position(25.0 * np.eye(2), position=(0, 3))), p_stay=scalar(0, 1))
target("nonlinear.sigma_points", m=arg((2,), valid=[0.0, 0.0]), P=covariance(2), alpha=scalar(0, 2),
       beta=scalar(0, 3), kappa=scalar(-1, 3))
target("nonlinear.particle_filter", lambda z, x0, P0, rng, particles, ess_threshold: nonlinear.particle_filter(
    ZHAO, z, x0, P0, rng, particles=particles, ess_threshold=ess_threshold), z=arg((2, 2), valid=ZZ[:2]),
    x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2), rng=rngs(), particles=count(1, 60),
    ess_threshold=scalar(0, 1), passed=("model",))
target("continuous.pf_substeps", lambda scheme: continuous.pf_substeps(ZHAO, scheme), scheme=names("rk4-split", "heun"),
       passed=("model",))
target("nonlinear.systematic_resample", weights=arg((3,), valid=[0.2, 0.3, 0.5]), rng=rngs())
target("continuous.reference_filter", lambda z, x0, P0, rng, particles: continuous.reference_filter(
    ZHAO, z, x0, P0, rng, particles=particles), z=arg((2, 2), valid=ZZ[:2]),
    x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2), rng=rngs(), particles=count(1, 60),
    passed=("model",))
target("continuous.pf_substep_study", lambda z, x0, P0, particles, runs, ref_particles: continuous.pf_substep_study(
    ZHAO, z, x0, P0, particles=particles, runs=runs, substeps=(1, 2), schemes=("heun",),
    ref_particles=ref_particles, ref_runs=1, ref_substeps=2), z=arg((2, 2), valid=ZZ[:2]),
    x0=arg((2,), valid=continuous.ZHAO2013_X0), P0=covariance(2), particles=count(1, 30), runs=count(1, 2),
    ref_particles=count(1, 40), passed=("model", "substeps", "schemes", "ref_runs", "ref_substeps"))

_CELLS = np.array([[50.8, 4.39, 2, -109.2, 35.2, np.nan, 0, np.nan, np.nan, 0, 120.0, -90.0, 1.0],
                   [50.8, 4.39, 2, -109.2, 35.2, np.nan, 0, np.nan, np.nan, 0, 240.0, -95.0, np.nan],
                   [50.81, 4.40, 0, -69.4, 35.2, 2.0, 3, 1.5, 2000.0, 1, np.nan, np.nan, 2.0]])
target("cellular.check_cells", cells=arg((3, 13), valid=_CELLS))
target("cellular.locate_cells", cells=arg((3, 13), valid=_CELLS), offsets=maybe(st.one_of(
    st.just([0, 2, 3]), arg((3,), valid=[0, 1, 3]))), level=scalar(0, 1))
_N = dict(lat=arg((3,), valid=[50.8, 50.81, 50.8]), lon=arg((3,), valid=[4.39, 4.4, 4.41]),
          area=arg((3,), valid=[1, 1, 2]), range_m=arg((3,), valid=[1000.0, np.nan, 500.0]),
          score=arg((3,), valid=[1.0, 0.5, 2.0]), rss_dbm=arg((3,), valid=[-90.0, np.nan, -100.0]),
          age_ms=arg((3,), valid=[0.0, 5000.0, np.nan]), min_signal_dbm=arg((3,), valid=[-140.0] * 3))
target("cellular.weighted_centroid", **_N)
target("cellular.station_score", samples=arg((2,), valid=[10.0, np.nan]), created=arg((2,), valid=[1.6e9, np.nan]),
       updated=arg((2,), valid=[1.7e9, 1.7e9]), now=scalar(1e9, 2e9))
target("cellular.signal_prior", radio=st.one_of(arg((3,), valid=[0, 2, 4]), count(0, 4)),
       height_m=st.one_of(scalar(0, 200), arg((3,), valid=[30.0, 10.0, 300.0])))
target("cellular.signal_fit", intercept_dbm=arg((2,), valid=[-109.0, -70.0]), slope_db=arg((2,), valid=[35.0, 35.0]),
       range_m=arg((2,), valid=[1500.0, np.nan]), average_signal_dbm=arg((2,), valid=[-95.0, 0.0]),
       samples=arg((2,), valid=[20.0, 3.0]))
target("cellular.radio_code", name=names("lte", "GSM", "umts", "NR"))

# --- radio ------------------------------------------------------------------------------------------------
_D = dict(distance_km=arg((3,), valid=[0.1, 1.0, 2.0]))
target("radio.arfcn_to_frequency", arfcn=st.one_of(arg((2,), valid=[10, 20]), count(0, 124)),
       band=names("P-GSM", "DCS1800"), link=names("downlink", "uplink"))
target("radio.frequency_to_arfcn", frequency_mhz=st.one_of(arg((1,), valid=[937.0]), scalar(900, 960)),
       band=names("P-GSM"), link=names("downlink", "uplink"))
target("radio.path_loss", lambda distance_km, model, frequency_mhz: radio.path_loss(
    distance_km, model, frequency_mhz=frequency_mhz, h_base_m=30.0, on_invalid="ignore"), **_D,
    model=names("free-space", "cost231-hata", "cost231-wi-nlos"), frequency_mhz=scalar(1, 3000),
    passed=("h_base_m", "on_invalid"))
target("radio.path_loss_from_rss", rss_dbm=arg((2,), valid=[-70.0, -80.0]), tx_power_dbm=scalar(0, 60),
       tx_gain_dbi=scalar(0, 20), losses_db=scalar(0, 20))
target("radio.distance_from_path_loss", lambda loss_db, model, on_invalid: radio.distance_from_path_loss(
    loss_db, model, on_invalid=on_invalid, frequency_mhz=1800.0, h_base_m=30.0),
    loss_db=arg((2,), valid=[140.0, 150.0]), model=names("cost231-hata", "free-space"),
    on_invalid=names("raise", "ignore"), passed=("frequency_mhz", "h_base_m"))
target("radio.distance_from_rss", lambda rss_dbm, tx_power_dbm: radio.distance_from_rss(
    rss_dbm, tx_power_dbm, "free-space", frequency_mhz=900.0), rss_dbm=arg((2,), valid=[-70.0, -80.0]),
    tx_power_dbm=scalar(0, 60), passed=("model", "frequency_mhz"))
target("radio.free_space_loss", **_D, frequency_mhz=scalar(1, 3000))
target("radio.wi_free_space_loss", **_D, frequency_mhz=scalar(1, 3000), constant_db=scalar(0, 40))
target("radio.wi_orientation_loss", street_angle_deg=st.one_of(arg((3,), valid=[0.0, 30.0, 90.0]), scalar(0, 90)))
target("radio.wi_rooftop_to_street_loss", frequency_mhz=scalar(800, 2000), street_width_m=scalar(1, 50),
       h_roof_m=scalar(3, 50), h_mobile_m=scalar(1, 3), street_angle_deg=scalar(0, 90))
target("radio.wi_multiscreen_loss", **_D, frequency_mhz=scalar(800, 2000), h_base_m=scalar(4, 50),
       h_roof_m=scalar(3, 50), building_sep_m=scalar(20, 50), city=names("medium", "metropolitan"))
target("radio.cost231_wi_los", lambda distance_km, frequency_mhz: radio.cost231_wi_los(
    distance_km, frequency_mhz, on_invalid="ignore"), **_D, frequency_mhz=scalar(800, 2000), passed=("on_invalid",))
target("radio.cost231_wi_nlos", lambda distance_km, frequency_mhz, h_base_m, h_roof_m: radio.cost231_wi_nlos(
    distance_km, frequency_mhz, h_base_m=h_base_m, h_roof_m=h_roof_m, on_invalid="ignore"), **_D,
    frequency_mhz=scalar(800, 2000), h_base_m=scalar(4, 50), h_roof_m=scalar(3, 50), passed=("on_invalid",))
target("radio.cost231_hata", lambda distance_km, frequency_mhz, h_base_m, city: radio.cost231_hata(
    distance_km, frequency_mhz, h_base_m=h_base_m, city=city, on_invalid="ignore"), **_D,
    frequency_mhz=scalar(1500, 2000), h_base_m=scalar(30, 200), city=names("medium", "metropolitan"),
    passed=("on_invalid",))
target("radio.okumura_hata", lambda distance_km, frequency_mhz, h_base_m, environment: radio.okumura_hata(
    distance_km, frequency_mhz, h_base_m=h_base_m, environment=environment, on_invalid="ignore"), **_D,
    frequency_mhz=scalar(150, 1500), h_base_m=scalar(30, 200), environment=names("urban", "rural"),
    passed=("on_invalid",))
target("radio.hata_mobile_correction", frequency_mhz=scalar(150, 2000), h_mobile_m=scalar(1, 10),
       large_city=flags())

# --- fuzzy ------------------------------------------------------------------------------------------------
_SHOULDER = st.sampled_from([-np.inf, np.inf])
target("fuzzy.triangular", x=arg((3,), valid=[0.2, 0.5, 0.9]), a=scalar(), b=scalar(), c=scalar())
target("fuzzy.trapezoidal", x=arg((3,), valid=[0.2, 0.5, 0.9]), a=st.one_of(scalar(), _SHOULDER),
       b=st.one_of(scalar(), _SHOULDER), c=st.one_of(scalar(), _SHOULDER), d=st.one_of(scalar(), _SHOULDER),
       inf_args=("a", "b", "c", "d"))
target("fuzzy.gaussian", x=arg((3,), valid=[0.2, 0.5, 0.9]), mean=scalar(), sigma=scalar(0, 5))
target("fuzzy.uniform_partition", lo=scalar(), hi=scalar(), count=count(1, 7), kind=names("triangular", "gaussian"),
       inf_result=True)
target("fuzzy.MembershipFunction", lambda kind, params, x: fuzzy.MembershipFunction(kind, params)(x),
       kind=names("triangular", "trapezoidal", "gaussian"),
       params=st.one_of(st.just((0.0, 0.5, 1.0)), arg((3,)), arg((4,)), arg((2,))),
       x=arg((3,), valid=[0.1, 0.5, 0.7]), inf_result=True)
target("fuzzy.TakagiSugeno", lambda consequents, universes, x: fuzzy.TakagiSugeno(
    ((MF, fuzzy.MembershipFunction("triangular", (0.5, 1.0, 1.5))),), consequents, universes)(x),
    consequents=arg((2,), valid=[0.2, 0.8]), universes=st.one_of(st.just(((0.0, 1.5),)), st.just(None),
                                                                   st.sampled_from([((1.0, 0.0),), (("a", 1),), 3])),
    x=arg((4, 1), valid=[[0.1], [0.5], [0.7], [2.0]]), passed=("sets", "inputs"))
target("fuzzy.anfis_train", lambda inputs, target_, epochs, learning_rate, membership: fuzzy.anfis_train(
    inputs, target_, sets_per_input=(2,), universes=((0.0, 1.0),), epochs=epochs, learning_rate=learning_rate,
    membership=membership), inputs=arg((6, 1), valid=np.linspace(0, 1, 6)[:, None]),
    target_=arg((6,), valid=np.linspace(0, 1, 6) ** 2), epochs=count(1, 5), learning_rate=scalar(0, 1),
    membership=names("gaussian", "triangular"), passed=("target", "sets_per_input", "universes"))
_P3 = np.array([np.eye(2), 2 * np.eye(2)])
target("fuzzy.fused_covariance_prop3", P_pred=covariance(2), P_local=arg((2, 2, 2), valid=_P3),
       H=arg((2, 1, 2), valid=[[[1.0, 0.0]], [[0.0, 1.0]]]), S=arg((2, 1, 1), valid=[[[2.0]], [[3.0]]]),
       y=arg((2,), valid=[0.4, 0.6]))
target("fuzzy.fused_covariance_trace", P_pred=covariance(2), P_local=arg((2, 2, 2), valid=_P3),
       H=arg((2, 1, 2), valid=[[[1.0, 0.0]], [[0.0, 1.0]]]), S=arg((2, 1, 1), valid=[[[2.0]], [[3.0]]]),
       y=arg((2,), valid=[0.4, 0.6]))
target("fuzzy.probabilistic_fusion", X=arg((2, 2), valid=[[1.0, 2.0], [1.5, 2.5]]), P=arg((2, 2, 2), valid=_P3))

# --- metrics ----------------------------------------------------------------------------------------------
target("metrics.position_error", x_est=arg((5, 2)), truth=arg((5, 2), valid=np.zeros((5, 2))), dims=maybe(count(1, 2)))
target("metrics.rmse", x_est=arg((3, 5, 2)), truth=arg((3, 5, 2), valid=np.zeros((3, 5, 2))), dims=maybe(count(1, 2)),
       axis=st.one_of(st.integers(-3, 2), st.sampled_from([None, 1.5, "0"])))
target("metrics.nees", x_est=arg((4, 2)), P=arg((4, 2, 2), valid=np.array([np.eye(2)] * 4)),
       truth=arg((4, 2), valid=np.zeros((4, 2))))
for _name in ("pcrb", "pcrb_tichavsky"):
    target(f"metrics.{_name}", F=arg((2, 2), valid=B.F), Q=covariance(2), P0=covariance(2),
           info=arg((3, 2, 2), valid=np.array([np.eye(2)] * 3)))
target("metrics.range_fisher_information", positions=arg((2, 2), valid=[[300.0, 400.0], [310.0, 400.0]]),
       stations=arg((3, 2), valid=STATIONS), R=st.one_of(scalar(0, 100), arg((3,), valid=[25.0] * 3)),
       n=maybe(count(2, 4)))
target("metrics.pcrb_ranges", truth=arg((2, 2), valid=[[300.0, 400.0], [310.0, 400.0]]),
       stations=arg((3, 2), valid=STATIONS), P0=covariance(2), Q=covariance(2), R=scalar(0, 100),
       F=maybe(arg((2, 2), valid=np.eye(2))))

# --- burden -----------------------------------------------------------------------------------------------
_FILTER_NAMES = tuple(linear._registry.FILTERS)
target("burden.filter_burden", name=names(*_FILTER_NAMES), n=count(1, 10), m=count(1, 10))
target("burden.join_burden", name=names("JKLF", "JSSKLF"), n=count(1, 10))
target("burden.implementation_burden", filter_name=names(*_FILTER_NAMES), model=names("A", "B"), axes=count(1, 3),
       join=names("once", "per-axis"))
target("burden.fir_burden", n=count(1, 10), m=count(1, 10), M=count(1, 100))
target("burden.fir_break_even", fir=scalar(0, 1e4), steady=scalar(0, 1e4))
target("burden.speedup", slow=scalar(0, 10), fast=scalar(0, 10))

# --- sim --------------------------------------------------------------------------------------------------
target("sim.simulate_linear", lambda model, steps, rng, x0: sim.simulate_linear(_model(model), steps, rng, x0),
       passed=MODEL_PASSED, model=MODEL, steps=count(), rng=rngs(), x0=maybe(arg((2,))))

target("sim.simulate_network", rng=rngs(), rings=count(0, 1), isd_m=scalar(50, 5000), eirp_dbm=scalar(-30, 90),
       offset_db=scalar(-40, 40), crowd=count(1, 200), max_cells=count(1, 7), sensitivity_dbm=scalar(-200, 0),
       lat0=scalar(-80, 80), lon0=scalar(-180, 180))
_NET = sim.simulate_network(np.random.default_rng(1), rings=1, crowd=100)[1]
target("sim.network_scans", network=st.one_of(st.just(_NET), st.sampled_from([None, {}, 3])),
       east_m=arg((2,), valid=[0.0, 300.0]), north_m=arg((2,), valid=[0.0, -200.0]), rng=rngs())

# --- tracking ---------------------------------------------------------------------------------------------
_OPTIONS = dict(model=names("cv", "ca"), filter=names("kf", "sskf", "fir"), q=maybe(scalar(0, 10)),
                sigma_m=maybe(scalar(0, 100)), gate_probability=maybe(scalar(0, 1)), gap_s=scalar(0, 100))
target("tracking.TrackOptions", **_OPTIONS)
target("tracking.simulate", scenario=names("gps", "urban-3bts"), tracks=count(1, 2), rng=rngs(),
       duration_s=scalar(0, 30), q=scalar(0, 5), speed_mps=scalar(0, 30), sigma_m=maybe(scalar(0, 20)))
target("tracking.simulate_chunks", lambda scenario, tracks, rng, duration_s: next(tracking.simulate_chunks(
    scenario, tracks, rng, duration_s=duration_s)), scenario=names("gps", "urban-3bts"), tracks=count(1, 2),
    rng=rngs(), duration_s=scalar(0, 30))
target("tracking.Intervals", lambda kind, min_s, mean_s, rng: tracking.simulate(
    "gps", 1, rng, duration_s=10.0, interval=tracking.Intervals(kind, min_s, mean_s)),
    kind=names("exponential", "fixed", "uniform"), min_s=scalar(0, 5), mean_s=maybe(scalar(0, 5)), rng=rngs(),
    passed=("interval", "max_s"))
target("tracking.evaluate_tracks", lambda tracks, truth, tolerance_s, truth_columns: tracking.evaluate_tracks(
    tracks, truth, tolerance_s=tolerance_s, truth_columns=truth_columns),
    # not "time": evaluate reads t and passes the time column through untouched
    tracks=st.one_of(frames(POINTS, ["t", "east_m", "lat", "lon", "var_east_m2"]),
                     frames(POINTS_WITH_TRUTH, ["true_lat", "true_lon", "east_m"])),
    truth=st.one_of(st.just(LOG), st.just(LOG), st.none()), tolerance_s=scalar(0, 5), truth_columns=flags(),
    nan_result=True)
target("tracking.attach_truth", tracks=frames(POINTS, ["time", "lat", "lon"]),
       truth=frames(LOG, ["time", "true_lat", "true_lon"]), tolerance_s=scalar(0, 5), nan_result=True)
target("tracking.track_file", lambda input, out, options: tracking.track_file(input, out, options=options),
       input=paths(LOG_CSV), out=out_paths(), options=st.one_of(st.just(tracking.TrackOptions()),
                                                                st.sampled_from([None, "kf"])), nan_result=True)
for _name in ("mptrack.track", "tracking.track"):
    target(_name, (lambda fn: lambda data, q, sigma_m: fn(data, q=q, sigma_m=sigma_m))(_public(*_name.split("."))),
           data=frames(LOG, ["time", "lat", "lon", "accuracy_m"]), q=maybe(scalar(0, 10)),
           sigma_m=maybe(scalar(0, 100)), nan_result=True)
target("mptrack.simulate", lambda scenario, tracks, seed, duration_s: mptrack.simulate(
    scenario, tracks, seed=seed, duration_s=duration_s), scenario=names("gps", "urban-3bts"), tracks=count(1, 2),
    seed=count(0, 5), duration_s=scalar(0, 30))
target("tracking.track_gated", lambda times, z, R, prior_variances: tracking.track_gated(
    CV2, times, z, R, prior_variances), times=arg((3,), valid=[0.0, 1.0, 2.0]),
    z=arg((3, 2), valid=[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]), R=arg((3, 2, 2), valid=np.array([np.eye(2)] * 3)),
    prior_variances=arg((4,), valid=[1.0, 100.0, 1.0, 100.0]), passed=("model",))
# read_output returns what the file holds: write_table writes +-Inf as is (CSV, Parquet), so may the file
target("tracking.track_fixes", lambda rows, q: tracking.track_fixes(TRACK_ID, rows, q=q),
       rows=frames(ROWS, ["t", "lat", "lon", "accuracy_m"]), q=maybe(scalar(0, 10)), passed=("track_id",),
       nan_result=True)
target("tracking.track_cells", lambda rows, cells: tracking.track_cells("1", rows, cells),
       rows=frames(CELL_ROWS, ["t", "cell_id", "rss_dbm"]), cells=frames(CELLS, ["lat", "lon", "height_m"]),
       passed=("track_id",), nan_result=True)
target("tracking.point_table", lambda east, north, var_e, nis: tracking.point_table(
    ["1"], np.array([0, 3]), np.array(["2024-01-01T00:00:00"] * 3, dtype="datetime64[ms]"), np.arange(3.0),
    east, north, None, var_e, np.zeros(3), np.ones(3), nis, np.full(3, 2), np.zeros(3, dtype=np.int8), 30.0,
    None, "kf"), east=arg((3,), valid=[0.0, 1.0, 2.0]), north=arg((3,), valid=[0.0, 1.0, 2.0]),
    var_e=arg((3,), valid=[1.0, 1.0, 1.0]), nis=arg((3,), valid=[0.5, 1.0, 2.0]),
    passed=("ids", "offsets", "time", "t", "vel", "cov_en", "var_n", "nis_dof", "flag", "gap_s", "origin",
            "method"), nan_result=True)
target("tracking.check_cell_ids", lambda rows, cells: tracking.check_cell_ids(
    rows, cells, file="log", report=mio.ReadReport()),
    rows=frames(CELL_ROWS, ["cell_id"]), cells=frames(CELLS, ["lat"]), passed=("file", "report"))
_PCI_CELLS = mio.read_cells(pd.DataFrame({"radio": "LTE", "mcc": 206, "net": 4, "area": 7, "cell": [1000, 1001, 1002],
                                          "unit": [1, 2, 2], "earfcn": [1300, 1300, np.nan], "lon": [4.39, 4.39, 4.5],
                                          "lat": [50.8, 50.8, 50.9]}))
_PCI_ROWS = pd.DataFrame({"track_id": "1", "t": [0.0, 0.0, 0.0, 5.0], "cell_id": ["206-1-7-1000", "PCI 2 EARFCN 1300",
                                                                                  "PCI 9 EARFCN 1300", "206-4-7-1001"],
                          "role": ["serving", "neighbour", "neighbour", "serving"], "mcc": 206.0,
                          "area": [7.0, np.nan, np.nan, 7.0], "pci": [1.0, 2.0, 9.0, 2.0], "earfcn": 1300.0,
                          "rss_dbm": [-90.0, -95.0, -99.0, -92.0]})
target("tracking.resolve_cells", lambda rows, cells: tracking.resolve_cells(rows, cells, file="log",
                                                                            report=mio.ReadReport()),
       rows=frames(_PCI_ROWS, ["cell_id", "pci", "t"]), cells=frames(_PCI_CELLS, ["lat", "unit"]),
       passed=("file", "report"))
target("tracking.ranges_km", rows=frames(CELL_ROWS, ["cell_id", "rss_dbm"]), cells=frames(CELLS, ["lat", "height_m"]),
       path_loss=names("cost231-wi-nlos", "free-space"), nan_result=True)
target("radio.band_of_arfcn", arfcn=st.one_of(count(0, 1023), scalar()))
target("tracking.kalman_filter_gated", lambda times, z, x0, P0, gate_probability: tracking.kalman_filter_gated(
    CV2, times, z, x0, P0, gate_probability=gate_probability), times=arg((3,), valid=[0.0, 1.0, 2.0]),
    z=arg((3, 2), valid=[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]), x0=arg((4,), valid=np.zeros(4)), P0=covariance(4),
    gate_probability=maybe(scalar(0, 1)), passed=("model",))
target("tracking.rts_smoother_gated", lambda x, P: tracking.rts_smoother_gated(dataclasses.replace(GATED, x=x, P=P)),
       x=arg((3, 4), valid=GATED.x), P=arg((3, 4, 4), valid=GATED.P), passed=("gated",))
target("result.normalised_innovation", innovation=arg((3, 2), valid=[[1.0, 2.0], [np.nan, 1.0], [np.nan, np.nan]]),
       S=arg((3, 2, 2), valid=np.broadcast_to([[2.0, 0.5], [0.5, 1.0]], (3, 2, 2))))
target("tracking.nis_threshold", probability=scalar(0, 1), dof=count(1, 10))
target("tracking.get_model", name=names("cv", "ca"))
target("tracking.get_fix_filter", name=names("kf", "sskf"))
target("tracking.get_cell_method", name=names("ekf", "fekf", "fcs"))

# --- io ---------------------------------------------------------------------------------------------------
target("io.ReadOptions", lambda time_unit, coord_unit, max_skip: mio.read_table(
    LOG_CSV, read=mio.ReadOptions(time_unit=time_unit, coord_unit=coord_unit, max_skip=max_skip)),
    time_unit=names("auto", "s", "ms"), coord_unit=names("auto", "deg"), max_skip=names("1%", "5", "100%"),
    passed=("read", "path"))
target("io.cell_key", mcc=st.one_of(arg((2,), valid=[262, 262]), scalar()), net=st.one_of(arg((2,), valid=[1, 1]),
                                                                                        scalar()),
       area=st.one_of(arg((2,), valid=[100, 100]), scalar()), cell=st.one_of(arg((2,), valid=[1, 2]), scalar()))
target("io.input_format", path=paths(LOG_CSV))
target("io.output_format", path=out_paths())
def _read_all(fn):
    """A reader called with its chunk size, its result read to the end."""
    def call(path, chunk_rows):
        out = fn(path, chunk_rows=chunk_rows)
        return out if isinstance(out, pd.DataFrame) else list(out)
    return call


target("io.read_table", path=paths(LOG_CSV))
target("io.input_columns", path=paths(LOG_CSV))
for _name in ("read_chunks", "iter_tracks", "iter_track_chunks"):
    target(f"io.{_name}", _read_all(getattr(mio, _name)), path=paths(LOG_CSV), chunk_rows=count(1, 1000))
target("io.read_cells", lambda path, chunk_rows: mio.read_cells(path, chunk_rows=chunk_rows),
       path=paths(CELLS_CSV), chunk_rows=count(1, 1000))
target("io.LocalFrame", lambda lat0, lon0, h0, east: mio.LocalFrame(lat0, lon0, h0).to_geodetic(east, east),
       lat0=scalar(-90, 90), lon0=scalar(-180, 180), h0=scalar(0, 1000), east=arg((3,), valid=[0.0, 10.0, -5.0]))
target("io.geodetic_to_enu", lat=arg((3,), valid=[45.0, 45.1, 45.2]), lon=arg((3,), valid=[13.0, 13.1, 13.2]),
       lat0=scalar(-90, 90), lon0=scalar(-180, 180))
target("io.enu_to_geodetic", east=arg((3,), valid=[0.0, 10.0, -5.0]), north=arg((3,), valid=[0.0, 10.0, -5.0]),
       lat0=scalar(-90, 90), lon0=scalar(-180, 180))
# a table may hold +-Inf: GeoJSON writes it as null (tests/io/test_io_outputs.py), CSV/Parquet as is
target("io.write_table", df=frames(POINTS.iloc[:5], ["east_m", "lat"]), path=out_paths(), inf_args=("df",))
target("io.read_output", path=paths(POINTS_CSV), nan_result=True, inf_result=True)


# --- runs -------------------------------------------------------------------------------------------------
target("runs.run_chunks", lambda n_items, chunk_size: runs.run_chunks(_chunk_table, n_items, chunk_size=chunk_size),
       n_items=count(0, 20), chunk_size=count(1, 10), passed=("task",))
target("runs.run_stream", lambda chunks, part_format: runs.run_stream(_chunk_table, chunks, part_format=part_format),
       chunks=st.one_of(count(1, 5).map(lambda n: runs.make_chunks(n, 2) if type(n) is int and 1 <= n < 10
                                        else n)), part_format=names("parquet", "arrow"), passed=("task",))
target("runs.part_path", out_dir=just(WORKDIR), name=names("chunk", "x"), index=count(0, 5), fmt=names("parquet"))
target("runs.read_part", path=paths(WORKDIR / "missing.parquet"))
target("runs.make_chunks", n_items=count(0, 50), chunk_size=count(), seed=maybe(count(0, 10)))
target("runs.PartStore", lambda out: runs.PartStore(out), out=out_paths())


def _locked(lock, paths):
    with lock(*paths):
        pass


target("runs.output_lock", lambda paths: _locked(runs.output_lock, [paths]), paths=out_paths())
target("runs.lock_path", path=out_paths())
target("runs.resumable_outputs", lambda out: _locked(lambda *p: runs.resumable_outputs(*p, last_part="tracks"), [out]),
       out=out_paths(), passed=("last_part",))


target("io.resolve_input", source=st.one_of(paths(LOG_CSV), st.just([LOG_CSV, POINTS_CSV]),
                                            st.just(str(WORKDIR / "*.csv")), st.sampled_from([[], [None], (3,)])))
for _name in ("input_label", "input_name", "input_paths"):
    target(f"io.{_name}", (lambda fn: lambda source: fn(mio.resolve_input(source)))(getattr(mio, _name)),
           source=st.one_of(paths(LOG_CSV), st.just([LOG_CSV, POINTS_CSV]), st.just(LOG)))
target("tracking.nis_stats", nis=arg((3,), valid=[1.0, 2.0, 3.0]), dof=arg((3,), valid=[2.0, 2.0, 2.0]),
       flags=st.one_of(st.just(np.array(["init", "update", "manoeuvre"])), st.just(np.array([4, 0, 5])),
                       st.sampled_from([None, "update", np.array(["update"]), np.ones(3), [[1, 2, 3]]])),
       nan_result=True)
target("tracking.nis_sentence", stats=st.one_of(
    st.just(tracking.nis_stats([np.nan, 1.0, 3.0], [0, 2, 2], ["init", "update", "update"])),
    st.fixed_dictionaries({"mean_nis": scalar(0, 10), "nis_fixes": count(1, 100), "nis_lo": scalar(0, 10),
                           "nis_hi": scalar(0, 10), "nis_dof": scalar(0, 10)}),
    st.sampled_from([None, {}, {"nis_fixes": 3, "mean_nis": 1.0}, [1.0], "mean"])))
target("tracking.far_from_band", mean=arg((3,), valid=[0.5, 2.0, 9.0]), dof=arg((3,), valid=[2.0, 2.0, 2.0]),
       used=arg((3,), valid=[5.0, 50.0, 500.0]))
target("tracking.write_track_report", lambda points, path, budget: tracking.write_track_report(
    points, path, budget=budget), points=frames(POINTS, ["t", "lat", "east_m", "flag", "nis", "var_east_m2"]),
    path=out_paths(".html"), budget=st.one_of(st.just(5000), count(1, 10**4)), nan_result=True)


target("tracking.ellipse", var_e=arg((3,), valid=[4.0, 1.0, 9.0]), cov_en=arg((3,), valid=[0.0, 0.5, -1.0]),
       var_n=arg((3,), valid=[4.0, 2.0, 1.0]))
target("tracking.LiveTracks", options=st.one_of(st.just(tracking.TrackOptions()),
                                                st.sampled_from([None, "cv", 3, tracking.TrackOptions(model="ca")])))

# --- serve ------------------------------------------------------------------------------------------------
_DB = f"sqlite:///{WORKDIR / 'serve.db'}"
_DBS = st.one_of(st.just(_DB), st.sampled_from([None, 3, "mptrack.db", "postgresql://nobody@127.0.0.1:9/x",
                                               f"sqlite:///{WORKDIR}", "sqlite:///"]))
_NAMES = st.one_of(st.sampled_from(["car-7", "jane/phone"]), st.text(max_size=70), st.sampled_from([None, 3, b"x"]))
target("serve.ServeConfig", db=_DBS, auth=flags(), max_body=count(1, 1 << 20), rate=scalar(0, 100),
       burst=scalar(0, 1000), retain_s=maybe(scalar(0, 1e6)), checkpoint_s=scalar(0, 60), fsync=flags(),
       model=names("cv", "ca"), cells=maybe(st.sampled_from([str(LOG_CSV), "", 3])))
target("serve.create_app", config=st.one_of(st.just(__import__("mptrack.serve").serve.ServeConfig(db=_DB)),
                                            st.sampled_from([None, "sqlite:///x.db", {}])))
target("serve.add_device", db=_DBS, name=_NAMES)
target("serve.add_api_key", db=_DBS, name=_NAMES)
_serve = __import__("mptrack.serve").serve
target("serve.open_store", lambda db, fsync: _serve.open_store(db, fsync).close(), db=_DBS, fsync=flags())
target("serve.copy_database", source=_DBS, target=_DBS, model=maybe(names("cv", "ca")))
target("serve.shown_url", url=st.one_of(st.sampled_from(["postgresql://u:secret@h/db", "sqlite:///x.db"]),
                                        st.text(max_size=40), st.sampled_from([None, 3, b"x"])))
target("serve.worker_environment", config=st.one_of(st.just(_serve.ServeConfig(db=_DB)), st.sampled_from([None, {}])),
       directory=st.one_of(st.just(str(WORKDIR)), st.sampled_from([None, 3, str(WORKDIR / "no" / "such")])),
       workers=count(1, 8))
_CELL_TABLE = _file("geo_cells.csv", pd.DataFrame({"radio": ["LTE", "GSM"], "mcc": [206, 206], "net": [4, 4],
                                               "area": [7, 7], "cell": [1000, 12], "lon": [4.39, 4.4],
                                               "lat": [50.8, 50.81]}))
_REQUESTS = WORKDIR / "requests.ndjson"
_REQUESTS.write_text('{"cellTowers": [{"radioType": "lte", "mobileCountryCode": 206, "mobileNetworkCode": 4, '
                     '"locationAreaCode": 7, "cellId": 1000, "signalStrength": -90}]}\n{"cellTowers": 3}\n')
target("serve.geolocate_requests", lambda requests, cells, db: list(serve.geolocate_requests(requests, cells=cells,
                                                                                               db=db)),
       requests=st.one_of(st.just(str(_REQUESTS)), st.sampled_from([None, 3, str(WORKDIR), str(LOG_CSV)])),
       cells=st.one_of(st.just(str(_CELL_TABLE)), st.sampled_from([None, 3, str(WORKDIR), str(_REQUESTS)])),
       db=maybe(_DBS))

# --- report -----------------------------------------------------------------------------------------------
SUMMARY, EVALUATED = tracking.evaluate_tracks(POINTS, LOG)
ARROW = WORKDIR / "points.arrow"
ARROW_TABLE = __import__("pyarrow").Table.from_pandas(pd.DataFrame(dict(POINTS)))   # without the attrs tables
__import__("pyarrow.feather").feather.write_feather(ARROW_TABLE, ARROW)
_TABLE = {"title": "t", "columns": ["q", "ours"], "rows": [[1.0, 2.0]], "paper": [[1.0, 2.1]], "explained_by": [[0, 1, "e1"]],
          "uncounted": ["q"], "mismatches": [[0, 1]]}
_BAD_TABLES = [None, {}, {"columns": "ab"}, {"columns": ["a"], "explained_by": [[1]]},
               {"columns": ["a"], "explained_by": [["x", 0, "k"]]}, {"columns": ["a"], "uncounted": 3}, [1, 2]]
target("report.write_report", lambda tracks, path, summary, budget: report.write_report(
    tracks, path, summary=summary, budget=budget),
    tracks=frames(EVALUATED, ["t", "lat", "east_m", "flag", "var_east_m2", "error_m"]), path=out_paths(".html"),
    summary=st.one_of(st.just(SUMMARY), st.just(SUMMARY), st.sampled_from([None, {}, {"overall": 3}])),
    budget=st.one_of(st.just(5000), count(1, 10**4)), nan_result=True)
target("report.report_points", sources=st.one_of(
    st.just([ARROW]), st.just([str(ARROW), ARROW]), st.just([ARROW_TABLE]),
    st.sampled_from([None, "points.arrow", 3, [3], [None], [WORKDIR / "missing.arrow"], [LOG_CSV], [],
                     [ARROW, __import__("pyarrow").table({"track_id": ["1"]})]])), nan_result=True)
for _name in ("explained_cells", "uncounted_columns"):
    target(f"report.{_name}", table=st.one_of(st.just(_TABLE), st.just(_TABLE), st.sampled_from(_BAD_TABLES)))
target("report.live_map_page", key=maybe(st.one_of(st.text(max_size=50), st.sampled_from([3, b"k"]))),
       title=st.one_of(st.text(max_size=50), st.sampled_from([None, 3])))
target("report.write_reproduction_report", lambda results, path, counts, title: report.write_reproduction_report(
    results, path, counts=counts, title=title),
    results=st.one_of(st.just({"key": "k", "tables": {"Table 1": _TABLE}}), st.sampled_from(
        [None, {}, {"tables": 3}, {"tables": {"t": None}}, {"tables": {"t": _BAD_TABLES[4]}}])),
    path=out_paths(".html"), counts=maybe(st.one_of(st.just(dict(published=2, matched=1, explained=1, unexplained=0)),
                                                    st.sampled_from([{}, 3, "all"]))),
    title=maybe(st.sampled_from(["title", 3, b"x"])))


def _chunk_table(chunk) -> pd.DataFrame:
    return pd.DataFrame({"start": [chunk.start], "stop": [chunk.stop]})


# ================================================================ classification

class _Timeout(Exception):
    pass


class _CompileClock(numba_event.Listener):
    """Time spent holding numba's compiler lock (compiling a kernel signature, or loading it from the
    cache): not the call's own work.  The time bound counts only the rest, so a signature that no
    warm-up compiled (a cold cache, a model size or dtype not warmed) cannot look like a hang."""

    def __init__(self):
        self.depth, self.started, self.spent, self.base, self.credited = 0, 0.0, 0.0, 0.0, 0.0

    def on_start(self, event):
        if self.depth == 0:
            self.started = time.perf_counter()
        self.depth += 1

    def on_end(self, event):
        self.depth -= 1
        if self.depth == 0:
            self.spent += time.perf_counter() - self.started

    def total(self) -> float:
        return self.spent + (time.perf_counter() - self.started if self.depth else 0.0)

    def start_call(self) -> None:
        """A timed call starts: compilation before it is not its own."""
        self.base, self.credited = self.total(), 0.0

    def owed(self) -> float:
        """This call's compilation time not yet added to its deadline."""
        return self.total() - self.base - self.credited


_COMPILING = _CompileClock()
numba_event.register("numba:compiler_lock", _COMPILING)
#: a call whose compilation alone takes longer than this is a hang after all
_MAX_COMPILE_S = 600.0


def _alarm(signum, frame):
    """At the time bound: a call that spent time compiling gets that time on top (the alarm is re-armed,
    never raised inside numba's compiler); otherwise it is a hang."""
    owed = _COMPILING.owed()
    if (owed > 0.01 or _COMPILING.depth) and _COMPILING.credited < _MAX_COMPILE_S:
        _COMPILING.credited += owed
        signal.setitimer(signal.ITIMER_REAL, max(owed, 0.05))
        return
    raise _Timeout()


def _has(value, test, depth=0, skip=()) -> bool:
    """Whether any number inside ``value`` (arrays, lists, dicts, dataclasses) passes ``test``."""
    if depth > 4 or value is None or isinstance(value, (str, bool, bytes)):
        return False
    if isinstance(value, (int, float, complex, np.number)):
        try:
            return bool(test(np.asarray(value, dtype=complex)))
        except (TypeError, ValueError, OverflowError):
            return False
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            if value.size and 0 in value.strides:  # a broadcast view: one copy of its data
                value = value[tuple(0 if s == 0 else slice(None) for s in value.strides)]
            return bool(test(value).any())
        if value.dtype == object:
            return any(_has(v, test, depth + 1) for v in value.flat)
        return False
    if isinstance(value, dict):
        return any(_has(v, test, depth + 1) for k, v in value.items() if k not in skip)
    if isinstance(value, (list, tuple)):
        return any(_has(v, test, depth + 1) for v in value)
    if isinstance(value, fuzzy.MembershipFunction):
        return False    # its open shoulders are +-inf by design
    if dataclasses.is_dataclass(value):
        return any(_has(getattr(value, f.name), test, depth + 1) for f in dataclasses.fields(value))
    if isinstance(value, pd.DataFrame):
        return any(_has(value[c].to_numpy(), test, depth + 1) for c in value.columns
                   if value[c].dtype.kind in "fcO")
    if isinstance(value, LinearGaussianModel):
        return any(_has(getattr(value, a), test, depth + 1) for a in ("F", "H", "Q", "R"))
    if hasattr(value, "to_pandas") and hasattr(value, "column_names"):  # a pyarrow Table
        return _has(value.to_pandas(), test, depth)
    return False


def _nonfinite(a):
    return ~np.isfinite(a)


_FIRST_WORD = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")


def starts_with_argument(message: str, params) -> bool:
    """Whether ``message`` starts with one of the argument names ``params`` (docs/decisions/2026-11-25-finite-answers.md:
    "a message that starts with the name of an argument the caller passed")."""
    first = _FIRST_WORD.match(message)
    return bool(first) and first.group(1) in params


def classify(fn, kwargs: dict, params, *, time_bound=TIME_BOUND_S, alloc_bound=ALLOC_BOUND, inf_args=(),
             inf_result=False, nan_result=False) -> tuple[str, str]:
    """(outcome, detail) of ``fn(**kwargs)``; see the module docstring."""
    has_inf = _has(kwargs, np.isinf, skip=inf_args)
    has_nan = _has(kwargs, np.isnan)
    old = signal.signal(signal.SIGALRM, _alarm)
    _COMPILING.start_call()
    signal.setitimer(signal.ITIMER_REAL, time_bound)
    tracemalloc.start()
    try:
        with np.errstate(all="ignore"):
            result = fn(**kwargs)
    except _Timeout:
        return "hang", ""
    except MemoryError as exc:
        return "memory", repr(exc)[:200]
    except MptrackError as exc:
        _, peak = tracemalloc.get_traced_memory()
        if peak > alloc_bound:
            return "memory", f"peak {peak} B then {exc!r}"[:200]
        named = starts_with_argument(str(exc), params) or (isinstance(exc, DataError) and exc.file is not None) \
            or (isinstance(exc, OutputError) and exc.path is not None)     # they name the file given
        return ("clean" if named else "misnamed"), f"{type(exc).__name__}: {exc}"[:300]
    except Exception as exc:
        cause = exc.__cause__ or exc.__context__
        return "unclean", f"{type(exc).__name__}: {exc}"[:200] + (f" <- {type(cause).__name__}" if cause else "")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    if peak > alloc_bound:
        return "memory", f"peak {peak} B"
    if has_inf:
        return "inf_accepted", ""
    if not has_nan and not (inf_result and nan_result) and \
            _has(result, np.isnan if inf_result else np.isinf if nan_result else _nonfinite):
        return "nonfinite", ""
    return "ok", ""


def run_target(name: str, kwargs: dict) -> tuple[str, str]:
    t = TARGETS[name]
    return classify(t.call, kwargs, t.params, inf_args=t.inf_args, inf_result=t.inf_result,
                    nan_result=t.nan_result)


GOOD = ("ok", "clean")


# ================================================================ the and the audit's examples

def _lgm(F, H, Q, R, **kw):
    return LinearGaussianModel(F, H, Q, R, **kw)


def _kf(model, z, **kw):
    """linear.kalman_filter with the papers' known prior P(0/0) = 0 unless P0 is given (it is required)."""
    n = np.asarray(model.F).shape[0]
    kw.setdefault("P0", np.zeros((n, n)))
    return linear.kalman_filter(model, z, **kw)


def _range_ekf(z, x0):
    return batch.ekf_ranges(RANGE_MODEL, z, x0, np.eye(4) * 100.0)


def _ekf_ranges(z, x0, R):
    return cellular.ekf_ranges(z, STATIONS, x0, np.eye(2) * 100.0, np.eye(2), R)


ZHAO_PRINTED = continuous.zhao2013_model()


def _pf(P0):
    return nonlinear.particle_filter(ZHAO_PRINTED, np.zeros((2, ZHAO_PRINTED.m)), continuous.ZHAO2013_X0, P0,
                                     np.random.default_rng(0), particles=50)


def _nis(probability, dof):
    return tracking.nis_threshold(probability, dof)


def _expect_type(call, name):
    try:
        call()
    except Exception as exc:
        if type(exc).__name__ == name:
            raise AssertionError(f"wrong diagnosis {name}: {exc}") from None
        raise
    return 0.0


def _expect_p(ss):
    if abs(ss.P_pred[0, 0] - 3.0) > 1e-9:
        raise AssertionError(f"P = {ss.P_pred[0, 0]}, expected 3")
    return ss.P_pred


def _empty_csv():
    path = _file("empty.csv", b"")
    return mio.read_table(path)


def _cli_track(*options):
    """`mptrack track` on a bundled GPX file: (exit code, output)."""
    from typer.testing import CliRunner

    from mptrack.cli import app
    gpx = Path(__file__).parent / "data" / "berkelland-bike-ride.gpx"
    result = CliRunner().invoke(app, ["track", str(gpx), "--out", str(WORKDIR / "cli.csv"), "--quiet", *options])
    if result.exit_code == 0:
        return 0
    if isinstance(result.exception, SystemExit) or result.exception is None:
        raise _CliError(result.output.strip().splitlines()[-1] if result.output.strip() else "")
    raise result.exception


class _CliError(MptrackError):
    """The CLI's one-line error, classified like a library error (it must start with the option)."""

    def __init__(self, line: str):
        super().__init__(re.sub(r"^(error|Error):\s*", "", line).lstrip("-"))


ZHAO_VDP = ZHAO
ST3 = STATIONS3

#: One example per failure class (class, label, call, names the caller passes): the issue's classes
#: 1-10 and the audit's ("a0".."a5": its numbered list of what the first fix missed).
CORPUS = [
    (1, "batch.ssf inf z", lambda: batch.steady_state_filter(B, np.array([[[np.inf], [1.0]]])), ("z",)),
    (1, "batch.kf inf z", lambda: batch.kalman_filter(B, np.array([[[np.inf], [1.0]]])), ("z",)),
    (1, "batch.fir inf z", lambda: batch.fir_filter(B, np.array([[[np.inf], [1.0]]])), ("z",)),
    (1, "batch.per_axis inf z", lambda: batch.per_axis(batch.steady_state_filter, B,
                                                        np.array([[[np.inf, 1.0]]])), ("z",)),
    (1, "batch.predict inf x", lambda: batch.predict(B, np.array([[[np.inf, 1.0]]])), ("x",)),
    (1, "batch.ekf_ranges inf z", lambda: _range_ekf(np.array([[[np.inf, 1.0, 1.0]]]), [1.0, 0, 1.0, 0]), ("z",)),
    (2, "kf x0 1e308", lambda: _kf(B, np.zeros((3, 1)), x0=[1e308, 1e308]), ("x0",)),
    (2, "gain_sequence 1e200", lambda: batch.gain_sequence(_lgm([[1e200]], [[1.]], [[1.]], [[1.]]), 3, [[1.]]),
     ("model", "F")),
    (2, "LGM G 1e200", lambda: _lgm(np.eye(2), np.eye(2), None, np.eye(2), G=[[1e200, 0], [0, 1]], Qw=np.eye(2)),
     ("G", "Qw")),
    (3, "range_ekf prior on station", lambda: _range_ekf(np.full((1, 3, 3), 500.0), [0.0, 0, 0.0, 0]), ("x0",)),
    (3, "RangeModel sigma_r2 1e-30", lambda: batch.ekf_ranges(
        batch.RangeModel.constant_velocity(1.0, 1.0, STATIONS, 1e-30), np.full((1, 3, 3), 500.0),
        [1.0, 0, 1.0, 0], np.eye(4)), ("sigma_r2", "model", "z", "x0", "P0")),
    (3, "kf F 1e200", lambda: _kf(_lgm([[1e200]], [[1.]], [[1.]], [[1.]]), np.ones((3, 1))),
     ("model", "F", "z")),
    (3, "lf z 1e308", lambda: linear.lainiotis_filter(B, np.full((5, 1), 1e308)), ("z",)),
    (3, "kf irregular 1e300", lambda: linear.kalman_filter_irregular(constant_velocity_continuous(0.1), [1e300],
                                                                      [[1.0]]), ("times",)),
    (4, "per-step 1e160", lambda: riccati.steady_state(_lgm([[1e160]], [[1.]], [[1.]], [[1.]]), "per-step"),
     ("model", "F")),
    (4, "doubling 1e160", lambda: riccati.steady_state(_lgm([[1e160]], [[1.]], [[1.]], [[1.]]), "doubling"),
     ("model", "F")),
    (4, "dare 1e160 diagnosis", lambda: _expect_type(
        lambda: riccati.steady_state(_lgm([[1e160]], [[1.]], [[1.]], [[1.]]), "dare"), "NotDetectableError"),
     ("model", "F")),
    (4, "F=2 Q=0 dare", lambda: _expect_p(riccati.steady_state(_lgm([[2.]], [[1.]], [[0.]], [[1.]]), "dare")),
     ("model",)),
    (4, "F=2 Q=0 per-step", lambda: _expect_p(riccati.steady_state(_lgm([[2.]], [[1.]], [[0.]], [[1.]]),
                                                                   "per-step", P0=[[1.0]])), ("model",)),
    (4, "F=2 Q=0 doubling", lambda: _expect_p(riccati.steady_state(_lgm([[2.]], [[1.]], [[0.]], [[1.]]),
                                                                   "doubling")), ("model",)),
    (5, "kf ragged z", lambda: _kf(B, [[1.0], [2.0, 3.0]]), ("z",)),
    (5, "kf ragged x0", lambda: _kf(B, [[1.0]], x0=[[1.0], [2.0, 3.0]]), ("x0",)),
    (5, "batch ragged z", lambda: batch.kalman_filter(B, [[[1.0]], [[2.0], [3.0]]]), ("z",)),
    (5, "ekf R abc", lambda: _ekf_ranges(np.ones((2, 3)), [1.0, 1.0], "abc"), ("R",)),
    (5, "range_fix height abc", lambda: cellular.range_fix([1.0, 1.0, 1.0], STATIONS, height="abc"),
     ("height",)),
    (5, "wi_nlos h_roof abc", lambda: radio.cost231_wi_nlos(1.0, 900.0, h_base_m=30.0, h_roof_m="abc"),
     ("h_roof_m",)),
    (5, "path_loss 1j", lambda: radio.path_loss(1.0, "free-space", frequency_mhz=1j), ("frequency_mhz",)),
    (5, "triangular b", lambda: fuzzy.triangular(np.ones(3), 0, "b", 1), ("b",)),
    (5, "nis_threshold str", lambda: _nis("0.99", 2), ("probability", "gate_probability")),
    (5, "motion_matrix 2.5", lambda: cellular.motion_matrix("cv", 2.5), ("dim",)),
    (5, "LocalFrame None", lambda: mio.LocalFrame(None, 13.0), ("lat0", "lat0_deg")),
    (5, "per_axis None", lambda: linear.per_axis(linear.kalman_filter, None, np.ones((3, 2))), ("axis_model",)),
    (6, "riccati_step 3x3", lambda: riccati.riccati_step(B, np.eye(3)), ("P_pred",)),
    (6, "riccati_residual str", lambda: riccati.riccati_residual("model", np.eye(2)), ("model",)),
    (6, "prediction_covariance N 2.0", lambda: linear.prediction_covariance(B, np.eye(2), 2.0), ("N",)),
    (6, "check_detectable nan", lambda: riccati.check_detectable(np.full((2, 2), np.nan), np.eye(2)), ("F",)),
    (6, "kalman_step inf", lambda: linear.kalman_step(B.F, B.H, B.Q, B.R, np.array([np.inf, 0.]), np.eye(2),
                                                      np.ones(1)), ("x",)),
    (6, "rmse shapes", lambda: metrics.rmse(np.zeros((5, 2)), np.zeros((4, 2))), ("truth", "x_est")),
    (6, "nis_threshold -3", lambda: _nis(0.999, -3), ("dof",)),
    (6, "nis_threshold inf", lambda: _nis(0.999, np.inf), ("dof",)),
    (6, "predict_ahead inf", lambda: linear.predict_ahead(B, _result([[np.inf, 0.]], [np.eye(2)]), 1),
     ("result",)),
    (6, "rts inf", lambda: linear.rts_smoother(B, mptrack.result.FilterResult(
        x=np.array([[np.inf, 0.]]), P=np.eye(2)[None], x_pred=np.zeros((1, 2)), P_pred=np.eye(2)[None],
        method="t")), ("result",)),
    (7, "ukf alpha 0", lambda: nonlinear.sigma_points(np.zeros(2), np.eye(2), alpha=0.0), ("alpha",)),
    (7, "sigma beta None", lambda: nonlinear.sigma_points(np.zeros(2), np.eye(2), beta=None), ("beta",)),
    (7, "pf P0 2**62", lambda: _pf(np.eye(ZHAO_PRINTED.n) + 2**62), ("P0",)),
    (8, "predict_ahead N 1e12", lambda: linear.predict_ahead(B, _kf(B, np.ones((3, 1))),
                                                             10**12), ("N",)),
    (8, "prediction_covariance N 1e12", lambda: linear.prediction_covariance(B, np.eye(2), 10**12), ("N",)),
    (8, "steady_state_predictor N 1e12", lambda: linear.steady_state_predictor(B, np.ones((3, 1)), 10**12),
     ("N", "model")),
    (8, "make_chunks 1e12", lambda: len(runs.make_chunks(10**12, 3)), ("n_items",)),
    (8, "monte_carlo runs 1e12", lambda: batch.monte_carlo(B, 5, 10**12, seed=1), ("runs",)),
    (8, "gain_sequence steps 1e12", lambda: batch.gain_sequence(B, 10**12), ("steps",)),
    (8, "simulate_linear steps 1e12", lambda: sim.simulate_linear(B, 10**12, np.random.default_rng(0)), ("steps",)),
    (9, "read_table 0-byte csv", lambda: _empty_csv(), ("path", "source")),
    (10, "RangeModel dt 1e300", lambda: batch.RangeModel.constant_velocity(1e300, 1.0, STATIONS, 1.0),
     ("dt",)),
    (10, "RangeModel sigma_r2 1e-300", lambda: batch.RangeModel.constant_velocity(1.0, 1.0, STATIONS, 1e-300),
     ("sigma_r2",)),
    # the audit of the first fix: its items 1-5
    ("a1", "discretize_intervals 1e300", lambda: models.discretize_intervals(constant_velocity_continuous(1.0),
                                                                            [1e300]), ("dts",)),
    ("a1", "power_sum 1e300", lambda: riccati.power_sum(np.array([[1e300]]), np.array([[1.0]]), 5), ("F",)),
    ("a1", "range_measurement 1e300", lambda: cellular.range_measurement(np.array([1e300, 0.0]), STATIONS), ("x",)),
    ("a1", "simulate_sde x0 1e300", lambda: continuous.simulate_sde(ZHAO_VDP, 3, np.random.default_rng(0),
                                                                   [1e300, 1e300]), ("x0",)),
    ("a1", "probabilistic_fusion inf", lambda: fuzzy.probabilistic_fusion(
        np.array([[np.inf, 2.0], [1.5, 2.5]]), np.array([np.eye(2), 2 * np.eye(2)])), ("X",)),
    ("a1", "systematic_resample inf", lambda: nonlinear.systematic_resample(np.array([np.inf, 1.0, 1.0]),
                                                                            np.random.default_rng(0)), ("weights",)),
    ("a1", "wrap_angles inf", lambda: models.wrap_angles(np.array([0.1, np.inf]), (None, 2 * np.pi)), ("nu",)),
    ("a1", "fir_coefficients inf", lambda: linear.fir_coefficients(np.array([[np.inf]]), np.array([[1.0]]), 3),
     ("A",)),
    ("a2", "track --sigma 1e140", lambda: _cli_track("--sigma", "1e140"), ("sigma", "sigma_m")),
    ("a3", "power_sum F str", lambda: riccati.power_sum("abc", np.eye(2), 5), ("F",)),
    ("a3", "power_sum N -3", lambda: riccati.power_sum(np.eye(2), np.eye(2), -3), ("N",)),
    ("a3", "range_fisher_information R<0", lambda: metrics.range_fisher_information(
        np.array([[300.0, 400.0]]), STATIONS, -26.0), ("R",)),
    ("a3", "pcrb Q 1e300", lambda: metrics.pcrb(B.F, np.full((2, 2), 1e300), np.eye(2), np.array([np.eye(2)] * 3)),
     ("F", "Q", "P0", "info")),
    ("a3", "sigma_points kappa str", lambda: nonlinear.sigma_points(np.zeros(2), np.eye(2), kappa="abc"), ("kappa",)),
    ("a3", "tdoa R str", lambda: models.tdoa(STATIONS, "abc"), ("R",)),
    ("a3", "ranges R str", lambda: models.ranges(STATIONS, "abc"), ("R",)),
    ("a3", "uniform_partition lo str", lambda: fuzzy.uniform_partition("a", 1.0, 3), ("lo",)),
    ("a3", "ranges R complex scalar", lambda: models.ranges(STATIONS, np.complex128(25 + 1j)), ("R",)),
    ("a3", "fusion X complex", lambda: fuzzy.probabilistic_fusion(np.array([[1.0, 2.0], [1.5, 2.5]]) + 1j,
                                                                   np.array([np.eye(2)] * 2)), ("X",)),
    ("a3", "discretize_intervals complex", lambda: models.discretize_intervals(CV, [np.complex128(1 + 1j)]),
     ("dts",)),
    ("a4", "fir_filter M 1e12", lambda: linear.fir_filter(B, np.ones((3, 1)), M=10**12), ("M",)),
    ("a4", "batch.fir_filter M 1e12", lambda: batch.fir_filter(B, np.ones((2, 3, 1)), M=10**12), ("M",)),
    ("a4", "fir_coefficients M 1e12", lambda: linear.fir_coefficients(0.5 * np.eye(2), np.ones((2, 1)), 10**12),
     ("M",)),
    ("a4", "stack_axes 1e12", lambda: models.stack_axes(B, 10**12), ("axes",)),
    ("a4", "simulate_sde steps 1e12", lambda: continuous.simulate_sde(ZHAO_PRINTED, 10**12, np.random.default_rng(0),
                                                                     [0.0, 0.0]), ("steps",)),
    ("a4", "uniform_partition 1e12", lambda: fuzzy.uniform_partition(0.0, 1.0, 10**12), ("count",)),
    ("a4", "simulate duration 1e12", lambda: tracking.simulate("gps", 1, np.random.default_rng(0),
                                                               duration_s=1e12), ("duration_s",)),
    ("a4", "simulate tracks 1e12", lambda: tracking.simulate("gps", 10**12, np.random.default_rng(0)), ("tracks",)),
    ("a4", "kalman_step F huge view", lambda: linear.kalman_step(np.broadcast_to(1.0, (10**12, 2)), B.H, B.Q, B.R,
                                                                 np.zeros(2), np.eye(2), np.ones(1)), ("F",)),
    ("a5", "cv_discrete_white_noise dt 1e300", lambda: models.cv_discrete_white_noise(1e300, 1.0), ("dt",)),
    ("a5", "range_bearing sensor inf", lambda: models.range_bearing(np.array([np.inf, 0.0]), np.diag([25.0, 1e-4])),
     ("sensor",)),
    ("a5", "fekf_ranges z 1e300", lambda: cellular.fekf_ranges(
        np.full((3, 3), 1e300), ST3, [0.3, 0.4, 0.0015], 1e-3 * np.eye(3), np.diag([0.02, 0.02, 0.002]), 0.222),
     ("z",)),
    ("a5", "pcrb_ranges truth inf", lambda: metrics.pcrb_ranges(np.array([[np.inf, 400.0], [310.0, 400.0]]),
                                                                STATIONS, np.eye(2), np.eye(2), 25.0), ("truth",)),
    ("a5", "check_detectable 1e300", lambda: riccati.check_detectable(np.array([[1e300, 0], [0, 1.0]]),
                                                                      np.array([[0.0, 1.0]])), ("F", "H")),
    ("a5", "triangular c inf", lambda: fuzzy.triangular(np.ones(2), 0, 0.5, np.inf), ("c",)),
    ("a5", "ukf printed model diverges", lambda: nonlinear.ukf_filter(ZHAO_PRINTED, np.ones((3, 2)),
                                                                       continuous.ZHAO2013_X0, np.eye(2)),
     ("model", "z", "x0", "P0")),
    ("a5", "ukf kappa str", lambda: nonlinear.ukf_filter(ZHAO_VDP, ZZ, continuous.ZHAO2013_X0, np.eye(2),
                                                          kappa="abc"), ("kappa",)),
    ("a5", "range_ekf exact data sigma_r2 1e-30", lambda: batch.ekf_ranges(
        batch.RangeModel.constant_velocity(1.0, 1.0, STATIONS, 1e-30),
        np.linalg.norm(np.array([[300.0, 400.0]] * 3)[:, None] - STATIONS, axis=-1)[None], [300.0, 0, 400.0, 0],
        np.eye(4)), ("model", "sigma_r2", "P0")),
    ("a5", "ekf_ranges_batch R 1e-30", lambda: cellular.ekf_ranges_batch(
        np.full((1, 3, 3), 500.0), STATIONS, [[1.0, 1.0]], np.eye(2), np.eye(2), 1e-30), ("R", "P0")),
    # issue 35: the last fuzz findings (each was unclean, non-finite or accepted before)
    ("i35", "range_fix stations 1e-200", lambda: cellular.range_fix([1.0, 2.0, 3.0], STATIONS * 1e-200),
     ("stations", "ranges")),
    ("i35", "gated z 1e300", lambda: tracking.kalman_filter_gated(
        CV2, [0.0, 1.0, 2.0], np.array([[0.0, 0.0], [1e300, 1.0], [2.0, -1e300]]), np.zeros(4), np.eye(4) * 100.0),
     ("z",)),
    ("i35", "gated z 1e300 ungated", lambda: tracking.kalman_filter_gated(
        CV2, [0.0, 1.0, 2.0], np.array([[0.0, 0.0], [1e300, 1.0], [2.0, 1.0]]), np.zeros(4), np.eye(4) * 100.0,
        gate_probability=None), ("z",)),
    ("i35", "riccati_residual entries beyond 1e154", lambda: riccati.riccati_residual(
        _lgm(np.diag([1.0, 1e100]), [[1.0, 0.0]], np.eye(2), [[1.0]]), np.eye(2) * 1e100), ("model", "P_pred")),
    ("i35", "fir_filter eps inf with M", lambda: linear.fir_filter(B, np.ones((3, 1)), eps=np.inf, M=3), ("eps",)),
    ("i35", "batch.fir_filter eps inf with M", lambda: batch.fir_filter(B, np.ones((2, 3, 1)), eps=np.inf, M=3),
     ("eps",)),
    ("i35", "fir_filter norm 7 with M", lambda: linear.fir_filter(B, np.ones((3, 1)), norm=7, M=3), ("norm",)),
    ("i35", "fir_order eps inf", lambda: linear.fir_order(0.5 * np.eye(2), np.inf), ("eps",)),
]


def run_corpus() -> dict:
    """Failures of the examples, per class: {class: [(label, outcome, detail), ...]}."""
    failures: dict = {}
    for cls, label, call, params in CORPUS:
        outcome, detail = classify(lambda: call(), {}, params)
        failures.setdefault(cls, [])
        if outcome not in GOOD:
            failures[cls].append((label, outcome, detail))
    return failures


# ================================================================ compiled kernels first

def warm_up() -> None:
    """Compile every numba kernel signature the targets can reach, so that compilation does not count
    against the time bound: the batch engine per storage dtype (float64, float32) for its special 2x1
    kernels and the general ones (another model size), with and without x0; the compiled single-track
    filters; the nonlinear kernels."""
    general = _lgm(0.5 * np.eye(3), np.ones((2, 3)), np.eye(3), np.eye(2))
    for dtype in (np.float64, np.float32):
        for model in (B, general, _lgm([[0.5]], [[1.0]], [[1.0]], [[1.0]])):
            z = np.ones((2, 3, model.m), dtype=dtype)
            for fn in (batch.steady_state_filter, batch.kalman_filter):
                fn(model, z)
                fn(model, z, np.zeros(model.n), lengths=[3, 2])
            batch.fir_filter(model, z)
            batch.predict(model, np.ones((2, 3, model.n), dtype=dtype))
        batch.per_axis(batch.kalman_filter, B, np.ones((2, 3, 2), dtype=dtype))
        for tracks in (1, 2):
            _range_ekf(np.full((tracks, 3, 3), 500.0, dtype=dtype), [1.0, 0.0, 1.0, 0.0])
    for model in (B, general):
        for fn in (_kf, linear.lainiotis_filter, linear.steady_state_filter, linear.fir_filter):
            fn(model, np.ones((3, model.m)))
        linear.rts_smoother(model, _kf(model, np.ones((3, model.m))))
        linear.steady_state_smoother(model, linear.steady_state_filter(model, np.ones((3, model.m))))
    linear.kalman_filter_irregular(CV, [1.0, 2.0], np.ones((2, 1)))
    linear.rts_smoother_irregular(CV, [1.0, 2.0, 3.0], KFI)
    _ekf_ranges(np.full((2, 3), 500.0), [1.0, 1.0], np.eye(3))
    for fn in (cellular.fekf_ranges, cellular.fcs_ranges):
        fn(Z_KM, STATIONS3, [0.3, 0.4, 0.0015], 1e-3 * np.eye(3), np.diag([0.02, 0.02, 0.002]), 0.222)
    cellular.locate_cells(_CELLS)
    nonlinear.ekf_filter_batch(NLM, np.stack([Z_RANGES] * 2), [300.0, 0.0, 400.0, 0.0], np.eye(4))
    nonlinear.ukf_filter(ZHAO, ZZ, continuous.ZHAO2013_X0, np.eye(2))
    _pf(np.eye(ZHAO_PRINTED.n))
    nonlinear.particle_filter(ZHAO, ZZ, continuous.ZHAO2013_X0, np.eye(2), np.random.default_rng(0), particles=20)
    try:
        continuous.fem_filter(ZHAO, ZZ[:2], continuous.ZHAO2013_X0, np.eye(2), grid=(6, 6))
    except MptrackError:      # compiled either way
        pass
    nonlinear.systematic_resample(np.array([0.2, 0.3, 0.5]), np.random.default_rng(0))
    batch.monte_carlo(B, 3, 2, seed=1)
    tracking.track_cells("1", CELL_ROWS, CELLS)
    tracking.track_fixes(TRACK_ID, ROWS)
    tracking.track(LOG, smooth=True)
    tracking.rts_smoother_gated(GATED)


# ================================================================ a run outside pytest

def run_generated(examples: int, names=None) -> tuple[dict, dict]:
    """({target: {outcome: count}}, {(target, outcome): (kwargs, detail)}) over ``examples`` generated
    calls per target."""
    from hypothesis import HealthCheck, given, settings

    counts: dict = {}
    samples: dict = {}

    def probe_of(name: str, tally: dict):
        @settings(max_examples=examples, database=None, deadline=None, derandomize=True,
                  suppress_health_check=list(HealthCheck))
        @given(TARGETS[name].strategy)
        def probe(kwargs):
            outcome, detail = run_target(name, kwargs)
            tally[outcome] = tally.get(outcome, 0) + 1
            if outcome not in GOOD:
                samples.setdefault((name, outcome), (kwargs, detail))
        return probe

    for name in names or TARGETS:
        try:
            probe_of(name, counts.setdefault(name, {}))()
        except Exception as exc:
            counts[name]["harness-error"] = 1
            samples[(name, "harness-error")] = ({}, repr(exc)[:300])
    return counts, samples


if __name__ == "__main__":  # python tests/_hardening.py [examples per target] [target prefix ...]
    import sys
    import warnings

    warnings.simplefilter("ignore")
    per_target = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    prefixes = sys.argv[2:]
    warm_up()
    fails = run_corpus()
    print("examples failing, per class:", {c: len(v) for c, v in fails.items() if v})
    for c, v in fails.items():
        for label, outcome, detail in v:
            print(f"  class {c}: {label}: {outcome} {detail[:200]}")
    chosen = [n for n in TARGETS if not prefixes or n.startswith(tuple(prefixes))]
    counts, samples = run_generated(per_target, chosen)
    total: dict = {}
    for name, tally in counts.items():
        for k, v in tally.items():
            total[k] = total.get(k, 0) + v
        if any(k not in GOOD for k in tally):
            print(f"{name}: {tally}")
    print("generated outcomes:", total)
    for (name, outcome), (kwargs, detail) in samples.items():
        print(f"  {name} {outcome}: {detail[:220]} | {repr(kwargs)[:220]}")
