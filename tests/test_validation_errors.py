"""Bad input is rejected at the public boundary with a specific ``mptrack.errors`` class whose
message names the argument; ``except ValueError`` (``TypeError`` for dtypes, ``KeyError`` for
unknown names) keeps working; the error is raised by mptrack, not by NumPy deep inside."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mptrack.errors import (
    ConvergenceError,
    DTypeError,
    MptrackError,
    NonFiniteError,
    NotDetectableError,
    NotPositiveDefiniteError,
    NotStabilisableError,
    NotSymmetricError,
    ParameterError,
    ShapeError,
    UnknownNameError,
)
from mptrack.linear import (
    FILTERS,
    fir_filter,
    fir_order,
    get_filter,
    get_implementation,
    kalman_filter,
    lainiotis_filter,
    per_axis,
    steady_state_filter,
)
from mptrack.models import LinearGaussianModel, assimakis_model_a, assimakis_model_b, stack_axes
from mptrack.result import FilterResult
from mptrack.riccati import steady_state
from mptrack.sim import simulate_linear


def check_raises(cls, name, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` raises ``cls`` naming ``name``, raised from mptrack's own code."""
    with pytest.raises(cls, match=rf"(?<!\w){re.escape(name)}(?!\w)") as info:
        fn(*args, **kwargs)
    err = info.value
    assert isinstance(err, MptrackError)
    expected_builtin = {DTypeError: TypeError, UnknownNameError: KeyError}.get(cls, ValueError)
    assert isinstance(err, expected_builtin)
    assert "mptrack" in str(info.traceback[-1].path), "raised from outside mptrack"
    return err


# --------------------------------------------------------------------------- LinearGaussianModel

GOOD = dict(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 1.0]], Q=[[0.25, 0.5], [0.5, 1.0]], R=[[0.1]])
GAIN = dict(Q=None, G=[[0.5], [1.0]], Qw=[[0.01]])
NAN2 = [[1.0, np.nan], [0.0, 1.0]]

MODEL_CASES = [
    ("F-not-square", dict(F=np.ones((2, 3))), ShapeError, "F"),
    ("F-1d", dict(F=[1.0, 1.0]), ShapeError, "F"),
    ("F-3d", dict(F=np.ones((2, 2, 2))), ShapeError, "F"),
    ("F-nan", dict(F=NAN2), NonFiniteError, "F"),
    ("F-inf", dict(F=[[1.0, np.inf], [0.0, 1.0]]), NonFiniteError, "F"),
    ("F-complex", dict(F=np.eye(2) * 1j), DTypeError, "F"),
    ("F-strings", dict(F=[["a", "b"], ["c", "d"]]), DTypeError, "F"),
    ("F-ragged", dict(F=[[1.0, 1.0], [0.0]]), DTypeError, "F"),
    ("H-wrong-width", dict(H=[[1.0, 1.0, 0.0]]), ShapeError, "H"),
    ("H-1d", dict(H=[1.0, 1.0]), ShapeError, "H"),
    ("H-nan", dict(H=[[1.0, np.nan]]), NonFiniteError, "H"),
    ("H-inf", dict(H=[[-np.inf, 1.0]]), NonFiniteError, "H"),
    ("Q-wrong-size", dict(Q=np.eye(3)), ShapeError, "Q"),
    ("Q-not-symmetric", dict(Q=[[1.0, 0.5], [0.0, 1.0]]), NotSymmetricError, "Q"),
    ("Q-indefinite", dict(Q=[[1.0, 0.0], [0.0, -0.1]]), NotPositiveDefiniteError, "Q"),
    ("Q-nan", dict(Q=NAN2), NonFiniteError, "Q"),
    ("Q-missing", dict(Q=None), ParameterError, "Q"),
    ("R-wrong-size", dict(R=np.eye(2)), ShapeError, "R"),
    ("R-zero", dict(R=[[0.0]]), NotPositiveDefiniteError, "R"),
    ("R-negative", dict(R=[[-0.1]]), NotPositiveDefiniteError, "R"),
    ("R-inf", dict(R=[[np.inf]]), NonFiniteError, "R"),
    ("R-singular-2x2", dict(H=np.eye(2), R=[[1.0, 1.0], [1.0, 1.0]]), NotPositiveDefiniteError, "R"),
    ("R-not-symmetric", dict(H=np.eye(2), R=[[1.0, 0.2], [0.0, 1.0]]), NotSymmetricError, "R"),
    ("G-without-Qw", dict(G=[[0.5], [1.0]]), ParameterError, "G"),
    ("Qw-without-G", dict(Q=None, Qw=[[1.0]]), ParameterError, "Qw"),
    ("G-wrong-rows", dict(GAIN, G=np.ones((3, 1))), ShapeError, "G"),
    ("G-nan", dict(GAIN, G=[[np.nan], [1.0]]), NonFiniteError, "G"),
    ("Qw-wrong-size", dict(GAIN, Qw=np.eye(2)), ShapeError, "Qw"),
    ("Qw-indefinite", dict(GAIN, Qw=[[-0.01]]), NotPositiveDefiniteError, "Qw"),
    ("Q-disagrees-with-G-Qw", dict(GAIN, Q=np.eye(2)), ParameterError, "Q"),
    ("F-scalar-string", dict(F="abc"), DTypeError, "F"),
    ("F-scalar-complex", dict(F=1j, H=[[1.0]], Q=[[1.0]]), DTypeError, "F"),
    ("H-no-rows", dict(H=np.zeros((0, 2)), R=np.zeros((0, 0))), ShapeError, "H"),
    ("dt-negative", dict(dt=-1.0), ParameterError, "dt"),
    ("dt-string", dict(dt="x"), ParameterError, "dt"),
]


@pytest.mark.parametrize("case, kwargs, cls, name", MODEL_CASES, ids=[c[0] for c in MODEL_CASES])
def test_bad_model_arguments(case, kwargs, cls, name):
    args = {**GOOD, **kwargs}
    F, H, Q, R = args.pop("F"), args.pop("H"), args.pop("Q"), args.pop("R")
    check_raises(cls, name, LinearGaussianModel, F, H, Q, R, **args)


def test_good_model_arguments_are_accepted():
    """The base of the bad cases above is itself valid (so each case tests one defect)."""
    LinearGaussianModel(GOOD["F"], GOOD["H"], GOOD["Q"], GOOD["R"])
    LinearGaussianModel(GOOD["F"], GOOD["H"], None, GOOD["R"], G=GAIN["G"], Qw=GAIN["Qw"])
    LinearGaussianModel(GOOD["F"], np.eye(2), GOOD["Q"], np.eye(2))


# --------------------------------------------------------------------------- paper model constructors

@pytest.mark.parametrize("kwargs, name", [
    (dict(dt=0.0), "dt"), (dict(dt=-1.0), "dt"), (dict(dt=np.nan), "dt"), (dict(dt=np.inf), "dt"),
    (dict(dt="1"), "dt"), (dict(dt=True), "dt"),
    (dict(sigma_q2=-0.01), "sigma_q2"), (dict(sigma_r2=0.0), "sigma_r2"), (dict(sigma_r2=-1.0), "sigma_r2"),
    (dict(measurement="velocity"), "measurement"),
])
@pytest.mark.parametrize("factory", [assimakis_model_b, assimakis_model_a], ids=["B", "A"])
def test_bad_paper_model_parameters(factory, kwargs, name):
    check_raises(ParameterError, name, factory, **kwargs)


@pytest.mark.parametrize("axes", [0, 1, 4, 2.0, "2"])
def test_model_a_axes_must_be_2_or_3(axes):
    check_raises(ParameterError, "axes", assimakis_model_a, axes)


def test_zero_process_noise_is_a_valid_paper_model():
    assert np.all(assimakis_model_b(sigma_q2=0.0).Q == 0.0)


@pytest.mark.parametrize("axes", [0, 2.5])
def test_stack_axes_rejects_bad_axes(axes):
    check_raises(ParameterError, "axes", stack_axes, assimakis_model_b(), axes)


# --------------------------------------------------------------------------- filter inputs

MODEL = assimakis_model_a(2)  # n = 4, m = 2
Z = np.zeros((5, 2))

RUNNERS = {
    "KF": kalman_filter,
    "KF-joseph": lambda *a: kalman_filter(*a, joseph=True),
    "LF": lainiotis_filter,
    "SSKF": steady_state_filter,
    "SSLF": lambda *a: steady_state_filter(*a, form="lainiotis"),
    "SSKF-exact": lambda *a: steady_state_filter(*a, covariance="exact"),
    "FIR": fir_filter,
    **{f"registry-{name}": spec.run for name, spec in FILTERS.items()},
}

INPUT_CASES = [
    ("z-wrong-width", dict(z=np.zeros((5, 3))), ShapeError, "z"),
    ("z-1d", dict(z=np.zeros(5)), ShapeError, "z"),
    ("z-3d", dict(z=np.zeros((5, 2, 1))), ShapeError, "z"),
    ("z-scalar", dict(z=1.0), ShapeError, "z"),
    ("z-empty", dict(z=np.zeros((0, 2))), ShapeError, "z"),
    ("z-inf", dict(z=[[0.0, 0.0], [np.inf, 0.0]]), NonFiniteError, "z"),
    ("z-complex", dict(z=Z + 0j), DTypeError, "z"),
    ("z-strings", dict(z=[["a", "b"]]), DTypeError, "z"),
    ("x0-wrong-length", dict(x0=np.zeros(3)), ShapeError, "x0"),
    ("x0-column", dict(x0=np.zeros((4, 1))), ShapeError, "x0"),
    ("x0-nan", dict(x0=[0.0, np.nan, 0.0, 0.0]), NonFiniteError, "x0"),
    ("x0-inf", dict(x0=[0.0, 0.0, np.inf, 0.0]), NonFiniteError, "x0"),
    ("P0-wrong-shape", dict(P0=np.eye(3)), ShapeError, "P0"),
    ("P0-1d", dict(P0=np.ones(4)), ShapeError, "P0"),
    ("P0-not-symmetric", dict(P0=np.eye(4) + np.triu(np.ones((4, 4)), 1)), NotSymmetricError, "P0"),
    ("P0-indefinite", dict(P0=np.diag([1.0, 1.0, -1.0, 1.0])), NotPositiveDefiniteError, "P0"),
    ("P0-nan", dict(P0=np.full((4, 4), np.nan)), NonFiniteError, "P0"),
    ("model-not-a-model", dict(model="model A"), ParameterError, "model"),
]


@pytest.mark.parametrize("case, bad, cls, name", INPUT_CASES, ids=[c[0] for c in INPUT_CASES])
@pytest.mark.parametrize("runner", list(RUNNERS))
def test_bad_filter_inputs(runner, case, bad, cls, name):
    args = {"model": MODEL, "z": Z, "x0": None, "P0": None, **bad}
    check_raises(cls, name, RUNNERS[runner], args["model"], args["z"], args["x0"], args["P0"])


@pytest.mark.parametrize("runner", [r for r in RUNNERS if "FIR" not in r])
def test_nan_is_allowed_in_z_only(runner):
    z = np.array([[0.1, np.nan], [np.nan, np.nan], [0.3, 0.2]])
    res = RUNNERS[runner](MODEL, z, None, np.zeros((MODEL.n, MODEL.n)))
    assert isinstance(res, FilterResult)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P))


@pytest.mark.parametrize("runner", ["FIR", "registry-FIR"])
def test_fir_needs_complete_measurements(runner):
    check_raises(NonFiniteError, "z", RUNNERS[runner], MODEL, [[0.1, np.nan], [0.2, 0.3]], None, None)


def test_one_dimensional_z_is_accepted_for_scalar_measurements():
    res = kalman_filter(assimakis_model_b(), [0.1, 0.2, 0.3], P0=np.eye(2))
    assert res.x.shape == (3, 2)


@pytest.mark.parametrize("kwargs, cls, name", [
    (dict(covariance="optimal"), ParameterError, "covariance"),
    (dict(steady="dare"), ParameterError, "steady"),
    (dict(steady=steady_state(assimakis_model_b())), ParameterError, "steady"),
    (dict(form="kalmann"), ParameterError, "form"),
])
def test_bad_steady_state_filter_options(kwargs, cls, name):
    check_raises(cls, name, steady_state_filter, MODEL, Z, **kwargs)


@pytest.mark.parametrize("kwargs, cls, name", [
    (dict(warmup="zeros"), ParameterError, "warmup"),
    (dict(M=0), ParameterError, "M"),
    (dict(M=2.0), ParameterError, "M"),
    (dict(eps=0.0), ParameterError, "eps"),
    (dict(eps=-1e-3), ParameterError, "eps"),
    (dict(steady=np.eye(4)), ParameterError, "steady"),
])
def test_bad_fir_filter_options(kwargs, cls, name):
    check_raises(cls, name, fir_filter, MODEL, Z, **kwargs)


@pytest.mark.parametrize("A, kwargs, cls, name", [
    (np.array([[1.0, 1.0], [0.0, 1.0]]), {}, ConvergenceError, "A"),
    (np.diag([0.5, -1.2]), {}, ConvergenceError, "A"),
    (0.9 * np.eye(2), dict(max_order=5), ConvergenceError, "max_order"),
    (0.5 * np.eye(2), dict(eps=0.0), ParameterError, "eps"),
    (0.5 * np.eye(2), dict(max_order=0), ParameterError, "max_order"),
    (np.ones(3), {}, ShapeError, "A"),
    (np.ones((2, 3)), {}, ShapeError, "A"),
    (np.full((2, 2), np.nan), {}, NonFiniteError, "A"),
    (0.5 * np.eye(2), dict(norm="bogus"), ParameterError, "norm"),
], ids=["cv-unit-circle", "unstable", "max_order", "eps", "max_order-0",
        "A-1d", "A-not-square", "A-nan", "norm"])
def test_bad_fir_order_arguments(A, kwargs, cls, name):
    check_raises(cls, name, fir_order, A, **kwargs)


@pytest.mark.parametrize("kwargs, cls, name", [
    (dict(z=np.zeros(5)), ShapeError, "z"),
    (dict(z=np.zeros((5, 2, 1))), ShapeError, "z"),
    (dict(x0=np.zeros(3)), ShapeError, "x0"),
    (dict(P0=np.ones((4, 4)) + np.eye(4)), ParameterError, "P0"),  # not block-diagonal
    (dict(P0=-np.eye(4)), NotPositiveDefiniteError, "P0"),
    (dict(z=[[np.inf, 0.0]]), NonFiniteError, "z"),
])
def test_bad_per_axis_inputs(kwargs, cls, name):
    args = {"z": Z, "x0": None, "P0": None, **kwargs}
    check_raises(cls, name, per_axis, kalman_filter, assimakis_model_b(), args["z"], args["x0"], args["P0"])


# --------------------------------------------------------------------------- steady-state existence

UNDETECTABLE = {
    # constant velocity, nothing measured: H = 0 with F unstable (double unit eigenvalue)
    "cv-H0": LinearGaussianModel([[1.0, 1.0], [0.0, 1.0]], [[0.0, 0.0]], np.eye(2), [[1.0]]),
    # unstable mode 1.2 not seen by H
    "hidden-unstable": LinearGaussianModel(np.diag([1.2, 0.5]), [[0.0, 1.0]], np.eye(2), [[1.0]]),
    # the papers' model B but measuring velocity only: position is not observable
    "velocity-only": LinearGaussianModel([[1.0, 1.0], [0.0, 1.0]], [[0.0, 1.0]], np.eye(2), [[0.1]]),
}
NOT_STABILISABLE = {
    # constant velocity with Q = 0: unit-circle modes not driven by noise
    "cv-Q0": LinearGaussianModel([[1.0, 1.0], [0.0, 1.0]], [[1.0, 0.0]], np.zeros((2, 2)), [[0.1]]),
}
# Undriven modes *outside* the unit circle do not prevent a stabilising solution (issue 16):
# the measurements estimate them; every solver must find scipy's solution.
UNDRIVEN_UNSTABLE = {
    "noise-free-unstable": LinearGaussianModel(np.diag([1.2, 0.5]), np.eye(2), np.diag([0.0, 1.0]), np.eye(2)),
    "gain-on-stable-mode": LinearGaussianModel.from_noise_gain(np.diag([1.1, 0.3]), np.eye(2),
                                                               [[0.0], [1.0]], [[1.0]], np.eye(2)),
    "F2-Q0": LinearGaussianModel([[2.0]], [[1.0]], [[0.0]], [[1.0]]),
}
SOLVES = {
    "dare": lambda m: steady_state(m, "dare"),
    "doubling": lambda m: steady_state(m, "doubling"),
    "per-step": lambda m: steady_state(m, "per-step"),
    "relf": lambda m: steady_state(m, "per-step", form="lainiotis"),
    "SSKF": lambda m: steady_state_filter(m, np.zeros((3, m.m))),
    "SSLF": lambda m: steady_state_filter(m, np.zeros((3, m.m)), form="lainiotis"),
    "FIR": lambda m: fir_filter(m, np.zeros((3, m.m))),
    "registry-JSSKLF": lambda m: FILTERS["JSSKLF"].run(m, np.zeros((3, m.m))),
}


@pytest.mark.parametrize("solve", list(SOLVES))
@pytest.mark.parametrize("key", list(UNDETECTABLE))
def test_undetectable_model_has_no_steady_state(key, solve):
    err = check_raises(NotDetectableError, "model", SOLVES[solve], UNDETECTABLE[key])
    assert "detectable" in str(err)


@pytest.mark.parametrize("solve", list(SOLVES))
@pytest.mark.parametrize("key", list(NOT_STABILISABLE))
def test_non_stabilisable_model_has_no_stabilising_steady_state(key, solve):
    err = check_raises(NotStabilisableError, "model", SOLVES[solve], NOT_STABILISABLE[key])
    assert "stabilisable" in str(err)


@pytest.mark.parametrize("method", ["dare", "doubling", "per-step"])
@pytest.mark.parametrize("key", list(UNDRIVEN_UNSTABLE))
def test_undriven_unstable_modes_are_solved_like_scipy(key, method):
    import scipy.linalg
    model = UNDRIVEN_UNSTABLE[key]
    want = scipy.linalg.solve_discrete_are(model.F.T, model.H.T, model.Q, model.R)
    ss = steady_state(model, method)
    np.testing.assert_allclose(ss.P_pred, want, rtol=1e-10, atol=1e-12)
    assert max(abs(np.linalg.eigvals(ss.A))) < 1.0     # the stabilising solution
    if key == "F2-Q0":
        assert ss.P_pred[0, 0] == pytest.approx(3.0, rel=1e-12)   # P = 3, as the KF converges to


@pytest.mark.parametrize("model", list(UNDETECTABLE.values()) + list(NOT_STABILISABLE.values()))
def test_time_invariant_filters_still_run_without_a_steady_state(model):
    """KF and LF need no steady state: they must not raise on these models."""
    z = np.ones((4, model.m))
    kf = kalman_filter(model, z, P0=np.zeros((model.n, model.n)))
    lf = lainiotis_filter(model, z)
    np.testing.assert_allclose(lf.x, kf.x, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("kwargs, cls, name", [
    (dict(method="schur"), ParameterError, "method"),
    (dict(method="dare", form="lainiotis"), ParameterError, "method"),
    (dict(method="doubling", form="lainiotis"), ParameterError, "method"),
    (dict(form="joseph"), ParameterError, "form"),
    (dict(tol=0.0), ParameterError, "tol"),
    (dict(tol=np.nan), ParameterError, "tol"),
    (dict(max_iter=0), ParameterError, "max_iter"),
    (dict(max_iter=10.0), ParameterError, "max_iter"),
    (dict(P0=-np.eye(4)), NotPositiveDefiniteError, "P0"),
    (dict(P0=np.eye(2)), ShapeError, "P0"),
    (dict(method="per-step", max_iter=3), ConvergenceError, "max_iter"),
    (dict(method="doubling", max_iter=1), ConvergenceError, "max_iter"),
    (dict(method="per-step", form="lainiotis", max_iter=3), ConvergenceError, "max_iter"),
])
def test_bad_steady_state_options(kwargs, cls, name):
    check_raises(cls, name, steady_state, MODEL, **kwargs)


def test_steady_state_rejects_a_non_model():
    check_raises(ParameterError, "model", steady_state, {"F": np.eye(2)})


# --------------------------------------------------------------------------- simulator

@pytest.mark.parametrize("kwargs, cls, name", [
    (dict(rng=42), ParameterError, "rng"),
    (dict(rng=np.random.RandomState(1)), ParameterError, "rng"),
    (dict(steps=0), ParameterError, "steps"),
    (dict(steps=2.5), ParameterError, "steps"),
    (dict(x0=np.zeros(3)), ShapeError, "x0"),
    (dict(x0=[np.nan, 0.0, 0.0, 0.0]), NonFiniteError, "x0"),
    (dict(model=None), ParameterError, "model"),
])
def test_bad_simulator_arguments(kwargs, cls, name):
    args = {"model": MODEL, "steps": 5, "rng": np.random.default_rng(0), "x0": None, **kwargs}
    check_raises(cls, name, simulate_linear, args["model"], args["steps"], args["rng"], args["x0"])


# --------------------------------------------------------------------------- registries

@pytest.mark.parametrize("name", ["EKF", "", "KF-A", "kalman"])
def test_unknown_filter_name(name):
    err = check_raises(UnknownNameError, "filter", get_filter, name)
    assert "KF" in str(err) and "JSSKLF" in str(err)  # lists what is known
    with pytest.raises(LookupError):
        get_filter(name)


def test_unknown_filter_name_of_wrong_type():
    check_raises(UnknownNameError, "filter", get_filter, 3)


@pytest.mark.parametrize("key", [0, 13, -1, "KF-C", "KF", "", None, "7"])
def test_unknown_implementation(key):
    err = check_raises(UnknownNameError, "implementation", get_implementation, key)
    assert "JSSKLF-B" in str(err)


# --------------------------------------------------------------------------- fuzz

@settings(max_examples=60, deadline=None)
@given(
    z=hnp.arrays(st.sampled_from([np.float64, np.int64, np.complex128, np.bool_]),
                 hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4),
                 elements=st.just(0) | st.just(1)),
    x0=st.none() | hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=2, max_side=5),
                              elements=st.sampled_from([0.0, 1.0, np.nan, np.inf])),
    P0=st.none() | hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=3, max_side=5),
                              elements=st.sampled_from([0.0, 1.0, -1.0, np.nan])),
    runner=st.sampled_from(["KF", "LF", "SSKF", "FIR"]),
)
def test_fuzzed_inputs_give_a_result_or_an_mptrack_error(z, x0, P0, runner):
    """Whatever the shapes, dtypes and values: a FilterResult or a named MptrackError."""
    try:
        res = RUNNERS[runner](MODEL, z, x0, P0)
    except MptrackError as err:
        assert re.match(r"^(z|x0|P0)\b", str(err)), str(err)
    else:
        assert isinstance(res, FilterResult) and res.x.shape[1] == 4


def test_unknown_name_is_also_a_value_error():
    """A bad name is a bad argument value: ``except ValueError`` catches it like every other mptrack error."""
    with pytest.raises(ValueError, match="filter"):
        get_filter("nope")
    with pytest.raises(ValueError, match="implementation"):
        get_implementation(99)


# --------------------------------------------------------------------------- shared helpers

from mptrack._core.validation import as_array, broadcast_shape  # noqa: E402


@settings(max_examples=300, deadline=None)
@given(values=hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=2, max_side=4),
                         elements=st.sampled_from([0.0, -1.0, 1.0, 2.5, -3.0, np.nan, np.inf, -np.inf])),
       allow_nan=st.booleans(), bounded=st.booleans())
def test_as_array_verdict_equals_plain_numpy(values, allow_nan, bounded):
    """The min/max fast path refuses exactly what the element-wise definition refuses:
    infinities always, NaN unless allowed, values outside [low, high] (NaN not compared)."""
    low, high = (-1.0, 2.5) if bounded else (-np.inf, np.inf)
    non_finite = np.isinf(values) if allow_nan else ~np.isfinite(values)
    outside = (values < low) | (values > high)
    if non_finite.any():
        check_raises(NonFiniteError, "v", as_array, "v", values, allow_nan=allow_nan, low=low, high=high)
    elif outside.any():
        err = check_raises(ParameterError, "v", as_array, "v", values, allow_nan=allow_nan, low=low, high=high)
        assert "[-1, 2.5]" in str(err)
    else:
        np.testing.assert_array_equal(as_array("v", values, allow_nan=allow_nan, low=low, high=high), values)


def test_as_array_range_message_names_value_index_and_unit():
    err = check_raises(ParameterError, "lat", as_array, "lat", [10.0, 95.0], low=-90, high=90, unit="degrees")
    assert str(err) == "lat: expected values in [-90, 90] degrees, got 95.0 at index (1,)"
    assert str(check_raises(ParameterError, "lat0", as_array, "lat0", 91.0, low=-90, high=90)) == \
        "lat0: expected values in [-90, 90], got 91.0"


def test_broadcast_shape_names_the_argument_that_does_not_fit():
    a, b, s = np.zeros(3), np.zeros((2, 1)), np.float64(1.0)
    assert broadcast_shape(a=a, s=s) == (3,)
    assert broadcast_shape(a=a, b=b, s=s) == (2, 3)
    assert broadcast_shape(s=s, t=s) == ()
    err = check_raises(ShapeError, "c", broadcast_shape, a=a, s=s, c=np.zeros(4))
    assert "(3,)" in str(err) and "(4,)" in str(err) and "a, s" in str(err)
