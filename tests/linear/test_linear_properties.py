"""Property-based tests (hypothesis) of the linear filters and Riccati solvers on random models.

Strategies build valid models: F with a chosen spectral radius, H of any width, Q = L L^T
(possibly singular) given directly or through a noise gain (G, Qw), R = L L^T + delta I (PD).
Example counts are kept modest so the file runs in seconds.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mptrack.linear import (
    fir_order,
    kalman_filter,
    lainiotis_filter,
    steady_state_filter,
)
from mptrack.models import LinearGaussianModel
from mptrack.riccati import METHODS, steady_state
from mptrack.sim import simulate_linear

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
RTOL = 1e-10


def _entries(shape):
    """Entries in [-1, 1] on a 1e-3 grid: zeros and exact small values are drawn often, and the
    matrices stay well scaled (a 1e-269 entry is a different, numerical-range test)."""
    return hnp.arrays(np.float64, shape, elements=st.integers(-1000, 1000).map(lambda i: i / 1000))


def _grid(lo, hi):
    """Scalars in [lo, hi] on a 0.01 grid (no 1e-247 spectral radii: see _entries)."""
    return st.integers(round(100 * lo), round(100 * hi)).map(lambda i: i / 100)


def _with_radius(M: np.ndarray, rho: float) -> np.ndarray:
    r = max(abs(np.linalg.eigvals(M)))
    return M * (rho / r) if r > 1e-3 else M  # tiny r: M is already stable; no 1e8 rescaling


@st.composite
def models(draw, *, max_n=4, stable=True):
    """Random valid models.  ``stable``: spectral radius of F in [0, 0.95], H any (m x n);
    otherwise F up to radius 1.5 with a square invertible H and PD Q, so the pair is
    detectable and stabilisable and the steady state exists."""
    n = draw(st.integers(1, max_n))
    if stable:
        m = draw(st.integers(1, 3))
        F = _with_radius(draw(_entries((n, n))), draw(_grid(0.0, 0.95)))
        H = 2.0 * draw(_entries((m, n)))
    else:
        m = n
        F = _with_radius(draw(_entries((n, n))), draw(_grid(0.0, 1.5)))
        H = np.eye(n) + (0.2 / n) * draw(_entries((n, n)))
    Lr = draw(_entries((m, m)))
    R = Lr @ Lr.T + draw(_grid(0.05, 1.0)) * np.eye(m)
    if stable and draw(st.booleans()):
        p = draw(st.integers(1, n))
        G = draw(_entries((n, p)))
        Lw = draw(_entries((p, p)))
        return LinearGaussianModel.from_noise_gain(F, H, G, Lw @ Lw.T, R)
    L = draw(_entries((n, n)))
    Q = L @ L.T + (0.0 if stable else 0.1) * np.eye(n)
    return LinearGaussianModel(F, H, Q, R)


@st.composite
def problems(draw, **kw):
    """(model, z (T, m), x0, P0) with z simulated from the model, T in [1, 40]."""
    model = draw(models(**kw))
    seed = draw(st.integers(0, 2**32 - 1))
    T = draw(st.integers(1, 40))
    rng = np.random.default_rng(seed)
    _, z = simulate_linear(model, T, rng, x0=rng.standard_normal(model.n))
    L = rng.standard_normal((model.n, model.n))
    P0 = L @ L.T if draw(st.booleans()) else np.zeros((model.n, model.n))
    return model, z, rng.standard_normal(model.n), P0


def _rel(got, want) -> float:
    """Max error relative to the largest entry of the reference sequence."""
    return float(np.max(np.abs(got - want)) / max(np.max(np.abs(want)), 1e-300))


def _assert_covariances(P, what, scale=None):
    """Each P[k] symmetric (to rounding) and positive semi-definite; tolerances relative to
    ``scale`` (default: the largest entry; give the operands' size when P is a difference)."""
    P = np.asarray(P)
    scale = max(float(np.max(np.abs(P))) if scale is None else scale, 1e-300)
    assert np.max(np.abs(P - np.swapaxes(P, -1, -2))) <= 1e-12 * scale, f"{what}: not symmetric"
    Ps = 0.5 * (P + np.swapaxes(P, -1, -2))
    low = np.linalg.eigvalsh(Ps)[..., 0]
    assert np.all(low >= -1e-10 * scale), f"{what}: smallest eigenvalue {low.min():.3g}"


# --------------------------------------------------------------------------- KF == LF

@SETTINGS
@given(problems())
def test_kf_and_lf_agree_on_random_stable_models(problem):
    model, z, x0, P0 = problem
    kf = kalman_filter(model, z, x0, P0)
    lf = lainiotis_filter(model, z, x0, P0)
    assert _rel(lf.x, kf.x) <= RTOL
    assert _rel(lf.P, kf.P) <= RTOL


@SETTINGS
@given(problems())
def test_joseph_form_agrees_on_random_models(problem):
    model, z, x0, P0 = problem
    std = kalman_filter(model, z, x0, P0)
    jos = kalman_filter(model, z, x0, P0, joseph=True)
    assert _rel(jos.x, std.x) <= RTOL
    assert _rel(jos.P, std.P) <= RTOL


# --------------------------------------------------------------------------- covariances

@SETTINGS
@given(problems())
def test_filter_covariances_are_symmetric_psd(problem):
    model, z, x0, P0 = problem
    kf = kalman_filter(model, z, x0, P0)
    _assert_covariances(kf.P, "KF P(k/k)")
    _assert_covariances(kf.P_pred, "KF P(k/k-1)")
    _assert_covariances(lainiotis_filter(model, z, x0, P0).P, "LF P(k/k)")
    _assert_covariances(kalman_filter(model, z, x0, P0, joseph=True).P, "Joseph P(k/k)")
    # a measurement update never adds uncertainty: P(k/k-1) - P(k/k) is PSD
    _assert_covariances(kf.P_pred - kf.P, "P(k/k-1) - P(k/k)", np.max(np.abs(kf.P_pred)))


@SETTINGS
@given(problems())
def test_exact_steady_state_covariance_is_psd_and_above_the_kf(problem):
    model, z, x0, P0 = problem
    ex = steady_state_filter(model, z, x0, P0, covariance="exact")
    _assert_covariances(ex.P, "SS exact P")
    kf = kalman_filter(model, z, x0, P0)
    _assert_covariances(ex.P - kf.P, "SS exact P - KF P", np.max(np.abs(ex.P)))  # the KF is the optimal linear filter


# --------------------------------------------------------------------------- Riccati solutions

def _check_solution(model, ss, ref):
    _assert_covariances(ss.P_pred, f"{ss.method} Pp")
    _assert_covariances(ss.P_filt, f"{ss.method} Pe")
    _assert_covariances(ss.P_pred - ss.P_filt, f"{ss.method} Pp - Pe", np.max(np.abs(ss.P_pred)))
    np.testing.assert_array_equal(ss.P_pred, ss.P_pred.T)
    assert ss.residual <= 1e-10, (ss.method, ss.residual)
    scale = max(1.0, np.linalg.norm(ref.P_pred))
    assert np.linalg.norm(ss.P_pred - ref.P_pred) <= 1e-9 * scale, ss.method
    assert max(abs(np.linalg.eigvals(ss.A))) < 1.0  # stabilising solution


@settings(SETTINGS, max_examples=30)
@given(st.one_of(models(stable=True), models(stable=False)))
def test_riccati_solutions_are_symmetric_psd_and_agree(model):
    ref = steady_state(model, "dare")
    X = scipy.linalg.solve_discrete_are(model.F.T, model.H.T, model.Q, model.R)
    assert np.linalg.norm(ref.P_pred - X) <= 1e-9 * max(1.0, np.linalg.norm(X))
    for method in METHODS:
        _check_solution(model, steady_state(model, method), ref)
    lai = steady_state(model, "per-step", form="lainiotis")
    _check_solution(model, lai, ref)
    scale = max(1.0, np.linalg.norm(ref.A))
    assert np.linalg.norm(lai.A - ref.A) <= 1e-8 * scale
    assert np.linalg.norm(lai.B - ref.B) <= 1e-8 * max(1.0, np.linalg.norm(ref.B))


@SETTINGS
@given(models(stable=True), st.sampled_from([2, "fro", 1, np.inf]), st.floats(1e-8, 0.5))
def test_fir_order_definition_on_random_models(model, norm, eps):
    A = steady_state(model, "dare").A
    M = fir_order(A, eps=eps, norm=norm)
    assert M >= 1
    assert np.linalg.norm(np.linalg.matrix_power(A, M), norm) < eps
    assert np.linalg.norm(np.linalg.matrix_power(A, M - 1), norm) >= eps


@pytest.mark.parametrize("stable", [True, False])
def test_strategies_produce_valid_models(stable):
    """Guard for the strategies themselves: they draw both noise forms and several sizes."""
    seen = set()

    @settings(max_examples=30, deadline=None)
    @given(models(stable=stable))
    def collect(model):
        seen.add((model.n, model.G is not None))
        assert isinstance(model, LinearGaussianModel)

    collect()
    assert len(seen) >= 3
