"""Fuzzing harness of issue 16: call public functions with generated arguments and classify
what happens.

Outcomes (``classify``):
  ok            finite result (or NaN only where the input had NaN = missing)
  clean         an ``mptrack.errors`` exception whose message names an argument the caller passed
  misnamed      an ``mptrack.errors`` exception that names none of the caller's arguments
  unclean       any other exception (numpy/numba/scipy/pandas from deep inside)
  nonfinite     a non-finite result from all-finite input
  inf_accepted  a result returned although an input held +-Inf
  hang          the call took longer than the time bound
  memory        the call allocated more than the allocation bound (or raised MemoryError)

``TARGETS`` maps a name to (callable, strategy of keyword arguments, names the caller passes).
Arguments come from strategies for every argument kind: arrays of any shape, dtype and
magnitude with NaN/Inf sprinkled, ragged lists, wrong types and huge sizes.
"""

from __future__ import annotations

import dataclasses
import re
import signal
import tracemalloc

import numpy as np
from hypothesis import strategies as st

import mptrack.batch as batch
import mptrack.cellular as cellular
import mptrack.continuous as continuous
import mptrack.fuzzy as fuzzy
import mptrack.linear as linear
import mptrack.metrics as metrics
import mptrack.nonlinear as nonlinear
import mptrack.radio as radio
import mptrack.riccati as riccati
from mptrack.errors import MptrackError
from mptrack.models import LinearGaussianModel, assimakis_model_b, constant_velocity_continuous

TIME_BOUND_S = 10.0
ALLOC_BOUND = 512 * 2**20

MAGNITUDES = [0.0, 1.0, -1.0, 0.5, 2.0, 1e-300, 1e-30, 1e30, 1e150, 1e200, 1e300, -1e300, 1e308]
GARBAGE = [None, "abc", 1j, [[1.0], [2.0, 3.0]], [], object(), {"a": 1}, True]


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
    """Arrays of the wrong number of dimensions or sizes (including empty)."""
    return st.sampled_from([(), (0,), (3,), (0, 2), (2, 3, 1), tuple(s + 1 for s in shape) or (2,)]).flatmap(
        lambda s: real_arrays(s, nonfinite=False))


def arg(shape, *, garbage=True):
    """Mostly a correctly-shaped array, sometimes a wrong shape or a wrong type."""
    options = [real_arrays(shape)] * 6 + [wrong_shapes(shape)]
    if garbage:
        options.append(st.sampled_from(GARBAGE))
    return st.one_of(*options)


def covariance(n):
    """A valid PSD covariance (of any scale) or a bad one."""
    @st.composite
    def good(draw):
        seed = draw(st.integers(0, 2**32 - 1))
        rng = np.random.default_rng(seed)
        A = rng.normal(size=(n, n))
        return A @ A.T * draw(st.sampled_from([1.0, 1.0, 1e-30, 1e-8, 1e8, 1e150, 1e300])) + 1e-3 * np.eye(n)
    return st.one_of(good(), good(), good(), arg((n, n)))


def scalar(low=-10.0, high=10.0):
    return st.one_of(st.floats(low, high), st.sampled_from(MAGNITUDES + [np.inf, -np.inf, np.nan]),
                     st.sampled_from(GARBAGE))


def count(low=1, high=50):
    return st.one_of(st.integers(low, high), st.integers(low, high),
                     st.sampled_from([0, -3, 10**3, 10**12, 2**62, 2.5, "3", None]))


@st.composite
def lgm(draw, n=None, m=None):
    """A LinearGaussianModel from generated matrices (constructor errors count as outcomes)."""
    n = n or draw(st.integers(1, 3))
    m = m or draw(st.integers(1, 2))
    F = draw(st.one_of(real_arrays((n, n), nonfinite=False), st.just(np.eye(n) * 0.9)))
    H = draw(st.one_of(real_arrays((m, n), nonfinite=False), st.just(np.eye(m, n))))
    return dict(F=F, H=H, Q=draw(covariance(n)), R=draw(covariance(m)))


def _model(spec):
    return LinearGaussianModel(spec["F"], spec["H"], spec["Q"], spec["R"])


B = assimakis_model_b()


def _fixed_b(**kw):
    return st.fixed_dictionaries(kw)


def _linear_target(fn):
    def call(model, z, x0, P0):
        return fn(_model(model) if isinstance(model, dict) else model, z, x0, P0)
    strat = st.one_of(
        _fixed_b(model=st.just(B), z=arg((5, 1)), x0=st.one_of(st.none(), arg((2,))),
                 P0=st.one_of(st.none(), covariance(2))),
        lgm(1, 1).flatmap(lambda spec: _fixed_b(model=st.just(spec), z=arg((4, 1)), x0=arg((1,)),
                                                   P0=st.none())))
    return call, strat, ("model", "z", "x0", "P0", "F", "H", "Q", "R")


def _batch_target(fn):
    def call(model, z, x0):
        return fn(_model(model) if isinstance(model, dict) else model, z, x0)
    strat = st.one_of(
        _fixed_b(model=st.just(B), z=arg((2, 4, 1)), x0=st.one_of(st.none(), arg((2,)))),
        lgm(1, 1).flatmap(lambda spec: _fixed_b(model=st.just(spec), z=arg((2, 3, 1)), x0=st.none())))
    return call, strat, ("model", "z", "x0", "F", "H", "Q", "R")


def _riccati_call(model, method):
    return riccati.steady_state(_model(model) if isinstance(model, dict) else model, method)


def _result(x, P):
    return linear.FilterResult(x=x, P=P, method="test")


def _kf(model, z, **kw):
    """linear.kalman_filter with the papers' known prior P(0/0) = 0 unless P0 is given (it is required)."""
    n = np.asarray(model.F).shape[0]
    kw.setdefault("P0", np.zeros((n, n)))
    return linear.kalman_filter(model, z, **kw)


def _predict_ahead(x, N):
    return linear.predict_ahead(B, _kf(B, np.asarray(x, float).reshape(-1, 1)[:, :1]
                                                        if np.ndim(x) == 2 else [[0.0]]), N)


def _irregular(times, z):
    return linear.kalman_filter_irregular(constant_velocity_continuous(0.1), times, z)


STATIONS = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0]])
RANGE_MODEL = batch.RangeModel.constant_velocity(1.0, 1.0, STATIONS, 25.0)


def _range_ekf(z, x0):
    return batch.range_ekf(RANGE_MODEL, z, x0, np.eye(4) * 100.0)


def _range_cv(dt, sigma_a2, sigma_r2):
    return batch.RangeModel.constant_velocity(dt, sigma_a2, STATIONS, sigma_r2)


def _ekf_ranges(z, x0, R):
    return cellular.ekf_ranges(z, STATIONS, x0, np.eye(2) * 100.0, np.eye(2), R)


TARGETS: dict = {
    "linear.kalman_filter": _linear_target(linear.kalman_filter),
    "linear.lainiotis_filter": _linear_target(linear.lainiotis_filter),
    "linear.steady_state_filter": _linear_target(linear.steady_state_filter),
    "linear.fir_filter": _linear_target(linear.fir_filter),
    "batch.steady_state_filter": _batch_target(batch.steady_state_filter),
    "batch.kalman_filter": _batch_target(batch.kalman_filter),
    "batch.fir_filter": (lambda z: batch.fir_filter(B, z), _fixed_b(z=arg((2, 4, 1))), ("z",)),
    "batch.per_axis": (lambda z, x0: batch.per_axis(batch.kalman_filter, B, z, x0),
                       _fixed_b(z=arg((2, 4, 2)), x0=st.one_of(st.none(), arg((4,)))), ("z", "x0")),
    "batch.predict": (lambda x, steps: batch.predict(B, x, steps),
                      _fixed_b(x=arg((2, 3, 2)), steps=count()), ("x", "steps")),
    "batch.gain_sequence": (lambda model, steps: batch.gain_sequence(_model(model), steps),
                            _fixed_b(model=lgm(), steps=count(1, 20)), ("model", "steps", "F", "H", "Q", "R")),
    "batch.range_ekf": (_range_ekf, _fixed_b(z=arg((2, 3, 3)), x0=arg((4,))), ("z", "x0")),
    "batch.RangeModel.constant_velocity": (_range_cv, _fixed_b(dt=scalar(0, 10), sigma_a2=scalar(0, 10),
                                                               sigma_r2=scalar(0, 100)),
                                           ("dt", "sigma_a2", "sigma_r2")),
    "batch.make_chunks": (lambda n_items, chunk_size: batch.make_chunks(n_items, chunk_size),
                          _fixed_b(n_items=count(), chunk_size=count()), ("n_items", "chunk_size")),
    "batch.monte_carlo": (lambda steps, runs: batch.monte_carlo(B, steps, runs, seed=1),
                          _fixed_b(steps=count(1, 20), runs=count(1, 20)), ("steps", "runs")),
    "riccati.steady_state": (_riccati_call, _fixed_b(model=lgm(), method=st.sampled_from(riccati.METHODS)),
                             ("model", "method", "F", "H", "Q", "R")),
    "riccati.riccati_step": (lambda P_pred: riccati.riccati_step(B, P_pred), _fixed_b(P_pred=covariance(2)),
                             ("P_pred",)),
    "riccati.riccati_residual": (lambda P_pred: riccati.riccati_residual(B, P_pred),
                                 _fixed_b(P_pred=covariance(2)), ("P_pred",)),
    "riccati.check_detectable": (riccati.check_detectable, _fixed_b(F=arg((2, 2)), H=arg((1, 2))), ("F", "H")),
    "linear.kalman_step": (lambda x, P, z: linear.kalman_step(B.F, B.H, B.Q, B.R, x, P, z),
                           _fixed_b(x=arg((2,)), P=covariance(2), z=arg((1,))), ("x", "P", "z")),
    "linear.prediction_covariance": (lambda P_filt, N: linear.prediction_covariance(B, P_filt, N),
                                     _fixed_b(P_filt=covariance(2), N=count()), ("P_filt", "N")),
    "linear.steady_state_predictor": (lambda z, N: linear.steady_state_predictor(B, z, N),
                                      _fixed_b(z=arg((4, 1)), N=count()), ("z", "N")),
    "linear.predict_ahead": (lambda x, P, N: linear.predict_ahead(B, _result(x, P), N),
                             _fixed_b(x=real_arrays((3, 2)), P=real_arrays((3, 2, 2)), N=count()),
                             ("x", "P", "N", "result")),
    "linear.rts_smoother": (lambda x, P: linear.rts_smoother(B, _result(x, P)),
                            _fixed_b(x=real_arrays((3, 2)), P=real_arrays((3, 2, 2))), ("x", "P", "result")),
    "linear.kalman_filter_irregular": (_irregular, _fixed_b(times=arg((3,)), z=arg((3, 1))), ("times", "z")),
    "cellular.ekf_ranges": (_ekf_ranges, _fixed_b(z=arg((3, 3)), x0=arg((2,)), R=covariance(3)),
                             ("z", "x0", "R")),
    "cellular.range_fix": (lambda ranges, height: cellular.range_fix(ranges, STATIONS, height=height),
                            _fixed_b(ranges=arg((3,)), height=st.one_of(st.none(), scalar())),
                            ("ranges", "height")),
    "cellular.motion_matrix": (cellular.motion_matrix, _fixed_b(
        motion=st.sampled_from(["random-walk", "constant-velocity", "x"]), dim=count(), dt=scalar(0, 5)),
        ("motion", "dim", "dt")),
    "nonlinear.sigma_points": (lambda m, P, alpha, beta: nonlinear.sigma_points(m, P, alpha=alpha, beta=beta),
                               _fixed_b(m=arg((2,)), P=covariance(2), alpha=scalar(0, 2), beta=scalar(0, 3)),
                               ("m", "P", "alpha", "beta")),
    "radio.path_loss": (lambda distance_km, frequency_mhz: radio.path_loss(distance_km, "free-space",
                                                                          frequency_mhz=frequency_mhz),
                        _fixed_b(distance_km=arg((3,)), frequency_mhz=scalar(1, 3000)),
                        ("distance_km", "frequency_mhz")),
    "radio.cost231_wi_nlos": (lambda distance_km, h_roof_m: radio.cost231_wi_nlos(
        distance_km, 900.0, h_base_m=30.0, h_roof_m=h_roof_m, on_invalid="ignore"),
        _fixed_b(distance_km=arg((2,)), h_roof_m=scalar(0, 40)), ("distance_km", "h_roof_m")),
    "radio.cost231_hata": (lambda distance_km, h_base_m: radio.cost231_hata(
        distance_km, 1800.0, h_base_m=h_base_m, on_invalid="ignore"),
        _fixed_b(distance_km=arg((2,)), h_base_m=scalar(1, 200)), ("distance_km", "h_base_m")),
    "radio.distance_from_rss": (lambda rss_dbm: radio.distance_from_rss(rss_dbm, 43.0, "free-space",
                                                                        frequency_mhz=900.0),
                                _fixed_b(rss_dbm=arg((3,))), ("rss_dbm",)),
    "fuzzy.triangular": (fuzzy.triangular, _fixed_b(x=arg((3,)), a=scalar(), b=scalar(), c=scalar()),
                         ("x", "a", "b", "c")),
    "fuzzy.gaussian": (fuzzy.gaussian, _fixed_b(x=arg((3,)), mean=scalar(), sigma=scalar(0, 5)),
                       ("x", "mean", "sigma")),
    "metrics.rmse": (metrics.rmse, _fixed_b(x_est=arg((5, 2)), truth=arg((5, 2))), ("x_est", "truth")),
    "metrics.nees": (metrics.nees, _fixed_b(x_est=arg((4, 2)), P=arg((4, 2, 2)), truth=arg((4, 2))),
                     ("x_est", "P", "truth")),
    "sim.simulate_linear": (lambda steps, x0: __import__("mptrack.sim").sim.simulate_linear(
        B, steps, np.random.default_rng(0), x0), _fixed_b(steps=count(), x0=st.one_of(st.none(), arg((2,)))),
        ("steps", "x0")),
}


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def _has(value, test, depth=0) -> bool:
    """Whether any number inside ``value`` (arrays, lists, dicts, dataclasses) passes ``test``."""
    if depth > 4 or value is None or isinstance(value, (str, bool)):
        return False
    if isinstance(value, (int, float, complex, np.number)):
        try:
            return bool(test(np.asarray(value, dtype=complex)))
        except (TypeError, ValueError, OverflowError):
            return False
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            return bool(test(value).any())
        if value.dtype == object:
            return any(_has(v, test, depth + 1) for v in value.flat)
        return False
    if isinstance(value, dict):
        return any(_has(v, test, depth + 1) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(_has(v, test, depth + 1) for v in value)
    if dataclasses.is_dataclass(value):
        return any(_has(getattr(value, f.name), test, depth + 1) for f in dataclasses.fields(value))
    if hasattr(value, "to_numpy") and hasattr(value, "columns"):  # a DataFrame
        return any(_has(value[c].to_numpy(), test, depth + 1) for c in value.columns
                   if value[c].dtype.kind in "fc")
    if isinstance(value, LinearGaussianModel):
        return any(_has(getattr(value, a), test, depth + 1) for a in ("F", "H", "Q", "R"))
    return False


def _nonfinite(a):
    return ~np.isfinite(a)


def names_argument(message: str, params) -> bool:
    words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", message))
    return any(p in words for p in params)


def classify(fn, kwargs: dict, params, *, time_bound=TIME_BOUND_S, alloc_bound=ALLOC_BOUND) -> tuple[str, str]:
    """(outcome, detail) of ``fn(**kwargs)``; see the module docstring."""
    has_inf = _has(kwargs, np.isinf)
    has_nan = _has(kwargs, np.isnan)
    old = signal.signal(signal.SIGALRM, _alarm)
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
        named = names_argument(str(exc), params) or getattr(exc, "file", None) is not None  # DataError: the file
        return ("clean" if named else "misnamed"), f"{type(exc).__name__}: {exc}"[:300]
    except Exception as exc:  # noqa: BLE001 - classifying is the point
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
    if not has_nan and _has(result, _nonfinite):
        return "nonfinite", ""
    return "ok", ""


GOOD = ("ok", "clean")


def _lgm(F, H, Q, R, **kw):
    return LinearGaussianModel(F, H, Q, R, **kw)


#: One example per failure class of issue 16 (class number, label, call, names the caller passes).
CORPUS = [
    (1, "batch.ssf inf z", lambda: batch.steady_state_filter(B, np.array([[[np.inf], [1.0]]])), ("z",)),
    (1, "batch.kf inf z", lambda: batch.kalman_filter(B, np.array([[[np.inf], [1.0]]])), ("z",)),
    (1, "batch.fir inf z", lambda: batch.fir_filter(B, np.array([[[np.inf], [1.0]]])), ("z",)),
    (1, "batch.per_axis inf z", lambda: batch.per_axis(batch.steady_state_filter, B,
                                                        np.array([[[np.inf, 1.0]]])), ("z",)),
    (1, "batch.predict inf x", lambda: batch.predict(B, np.array([[[np.inf, 1.0]]])), ("x",)),
    (1, "batch.range_ekf inf z", lambda: _range_ekf(np.array([[[np.inf, 1.0, 1.0]]]), [1.0, 0, 1.0, 0]), ("z",)),
    (2, "kf x0 1e308", lambda: _kf(B, np.zeros((3, 1)), x0=[1e308, 1e308]), ("x0",)),
    (2, "gain_sequence 1e200", lambda: batch.gain_sequence(_lgm([[1e200]], [[1.]], [[1.]], [[1.]]), 3, [[1.]]),
     ("model", "F")),
    (2, "LGM G 1e200", lambda: _lgm(np.eye(2), np.eye(2), None, np.eye(2), G=[[1e200, 0], [0, 1]], Qw=np.eye(2)),
     ("G", "Qw")),
    (3, "range_ekf prior on station", lambda: _range_ekf(np.full((1, 3, 3), 500.0), [0.0, 0, 0.0, 0]), ("x0",)),
    (3, "RangeModel sigma_r2 1e-30", lambda: batch.range_ekf(
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
    (5, "LocalFrame None", lambda: __import__("mptrack.io").io.LocalFrame(None, 13.0), ("lat0", "lat0_deg")),
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
    (6, "rts inf", lambda: linear.rts_smoother(B, linear.FilterResult(
        x=np.array([[np.inf, 0.]]), P=np.eye(2)[None], x_pred=np.zeros((1, 2)), P_pred=np.eye(2)[None],
        method="t")), ("result",)),
    (7, "ukf alpha 0", lambda: nonlinear.sigma_points(np.zeros(2), np.eye(2), alpha=0.0), ("alpha",)),
    (7, "sigma beta None", lambda: nonlinear.sigma_points(np.zeros(2), np.eye(2), beta=None), ("beta",)),
    (7, "pf P0 2**62", lambda: _pf(np.eye(ZHAO.n) + 2**62), ("P0",)),
    (8, "predict_ahead N 1e12", lambda: linear.predict_ahead(B, _kf(B, np.ones((3, 1))),
                                                             10**12), ("N",)),
    (8, "prediction_covariance N 1e12", lambda: linear.prediction_covariance(B, np.eye(2), 10**12), ("N",)),
    (8, "steady_state_predictor N 1e12", lambda: linear.steady_state_predictor(B, np.ones((3, 1)), 10**12),
     ("N",)),
    (8, "make_chunks 1e12", lambda: len(batch.make_chunks(10**12, 3)), ("n_items",)),
    (8, "monte_carlo runs 1e12", lambda: batch.monte_carlo(B, 5, 10**12, seed=1), ("runs",)),
    (8, "gain_sequence steps 1e12", lambda: batch.gain_sequence(B, 10**12), ("steps",)),
    (8, "simulate_linear steps 1e12", lambda: __import__("mptrack.sim").sim.simulate_linear(
        B, 10**12, np.random.default_rng(0)), ("steps",)),
    (9, "read_table 0-byte csv", lambda: _empty_csv(), ("path", "source")),
    (10, "RangeModel dt 1e300", lambda: batch.RangeModel.constant_velocity(1e300, 1.0, STATIONS, 1.0),
     ("dt",)),
    (10, "RangeModel sigma_r2 1e-300", lambda: batch.RangeModel.constant_velocity(1.0, 1.0, STATIONS, 1e-300),
     ("sigma_r2",)),
]


ZHAO = continuous.zhao2013_model()


def _pf(P0):
    return nonlinear.particle_filter(ZHAO, np.zeros((2, ZHAO.m)), continuous.ZHAO2013_X0, P0,
                                     np.random.default_rng(0), particles=50)


def _nis(probability, dof):
    from mptrack.tracking import nis_threshold
    return nis_threshold(probability, dof)


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
    import tempfile
    from pathlib import Path

    from mptrack.io import read_table
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "empty.csv"
        path.write_bytes(b"")
        return read_table(path)


def warm_up() -> None:
    """Compile the numba kernels first, so that compilation does not count against the time bound."""
    for dtype in (np.float64, np.float32):   # the batch engine keeps float32: one kernel per dtype
        z = np.ones((2, 3, 1), dtype=dtype)
        for fn in (batch.steady_state_filter, batch.kalman_filter, batch.fir_filter):
            fn(B, z)
            batch.per_axis(fn, B, np.ones((2, 3, 2), dtype=dtype))
        batch.predict(B, np.ones((2, 3, 2), dtype=dtype))
        for tracks in (1, 2):
            _range_ekf(np.full((tracks, 3, 3), 500.0, dtype=dtype), [1.0, 0.0, 1.0, 0.0])
    for fn in (_kf, linear.lainiotis_filter, linear.steady_state_filter, linear.fir_filter):
        fn(B, np.ones((3, 1)))
    linear.rts_smoother(B, _kf(B, np.ones((3, 1))))
    _irregular([1.0, 2.0], np.ones((2, 1)))
    _ekf_ranges(np.full((2, 3), 500.0), [1.0, 1.0], np.eye(3))
    _pf(np.eye(ZHAO.n))
    batch.monte_carlo(B, 3, 2, seed=1)


def run_corpus() -> dict:
    """Failures of the issue's examples, per class: {class: [(label, outcome, detail), ...]}."""
    failures: dict = {c: [] for c in range(1, 11)}
    for cls, label, call, params in CORPUS:
        outcome, detail = classify(lambda: call(), {}, params)
        if outcome not in GOOD:
            failures[cls].append((label, outcome, detail))
    return failures


def run_generated(examples: int, seed: int = 0) -> dict:
    """{target: {outcome: count}} over ``examples`` generated calls per target."""
    from hypothesis import HealthCheck, given, settings

    counts: dict = {}
    samples: dict = {}
    for name, (fn, strat, params) in TARGETS.items():
        tally = counts.setdefault(name, {})

        @settings(max_examples=examples, database=None, deadline=None, derandomize=True,
                  suppress_health_check=list(HealthCheck))
        @given(strat)
        def probe(kwargs):
            outcome, detail = classify(fn, kwargs, params)
            tally[outcome] = tally.get(outcome, 0) + 1
            if outcome not in GOOD:
                samples.setdefault((name, outcome), (kwargs, detail))

        probe()
    return counts, samples


if __name__ == "__main__":  # python tests/_hardening.py [examples per target]
    import sys
    import warnings

    warnings.simplefilter("ignore")
    per_target = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    warm_up()
    fails = run_corpus()
    print("issue examples failing, per class:", {c: len(v) for c, v in fails.items()})
    for c, v in fails.items():
        for label, outcome, detail in v:
            print(f"  class {c}: {label}: {outcome} {detail[:160]}")
    counts, samples = run_generated(per_target)
    total: dict = {}
    for name, tally in counts.items():
        bad = {k: v for k, v in tally.items() if k not in GOOD}
        for k, v in tally.items():
            total[k] = total.get(k, 0) + v
        if bad:
            print(f"{name}: {tally}")
    print("generated outcomes:", total)
    for (name, outcome), (kwargs, detail) in samples.items():
        print(f"  {name} {outcome}: {detail[:200]} | {repr(kwargs)[:200]}")
