"""Riccati solvers: per-step, doubling and DARE agree with each other and with scipy;
the Lainiotis form (RELF, seed 000 eq. 14) gives the Kalman form's A, B (eq. 15)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from _dare_cases import DAREX, darex_model

from mptrack.linear import kalman_filter
from mptrack.models import LinearGaussianModel, assimakis_model_a, assimakis_model_b
from mptrack.riccati import (
    METHODS,
    lainiotis_parameters,
    riccati_residual,
    riccati_step,
    steady_state,
)

# relative tolerance of each solver against scipy (per-step convergence is linear, so its
# accuracy is limited by the closed-loop spectral radius; darex7/9 have |lambda| ~ 0.99).  "dare" is
# scipy's solver on the problem scaled to R of unit size: on darex13 (R = 1e6 I) its DARE residual is
# 3.7e-9 against scipy's own 1.6e-6, and the two solutions differ by 4e-13 (test below)
RTOL = {"dare": 1e-12, "doubling": 1e-11, "per-step": 1e-10}


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), np.finfo(float).tiny))


@pytest.fixture(scope="module")
def darex_scipy():
    """scipy's solution X of each DAREX case, computed once."""
    return {key: scipy.linalg.solve_discrete_are(*(np.asarray(M, dtype=float) for M in DAREX[key]))
            for key in DAREX}


@pytest.mark.parametrize("key", list(DAREX))
def test_scaled_dare_is_backward_stable(key):
    """What method "dare" promises: its solution satisfies the DARE to a small multiple of the rounding of
    its terms, |A'XA - X + Q - A'XB (R + B'XB)^-1 B'XA| <= 8 n eps max|term| on every DAREX case (measured:
    at most 2.5 n eps, darex6).  A property of our solution alone, not a comparison with scipy's rounding:
    scipy's unscaled solve_discrete_are misses this bound on darex13 (R = 1e6 I; 195 eps against our 0.45
    with scipy 1.17), which is why the problem is scaled to R of unit size first."""
    A, Bc, Q, R = (np.asarray(M, dtype=float) for M in DAREX[key])
    X = steady_state(darex_model(key), "dare").P_pred
    terms = (A.T @ X @ A, X, Q, A.T @ X @ Bc @ np.linalg.solve(R + Bc.T @ X @ Bc, Bc.T @ X @ A))
    residual = np.abs(terms[0] - terms[1] + terms[2] - terms[3]).max()
    scale = max(np.abs(t).max() for t in terms)
    assert residual <= 8 * A.shape[0] * np.finfo(float).eps * scale, f"{key}: {residual / scale:.3g}"


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("key", list(DAREX))
def test_darex_solution_matches_scipy(key, method, darex_scipy):
    model = darex_model(key)
    ss = steady_state(model, method)
    X = darex_scipy[key]
    assert _rel(ss.P_pred, X) <= RTOL[method], f"{key}/{method}: {_rel(ss.P_pred, X):.3g}"
    np.testing.assert_array_equal(ss.P_pred, ss.P_pred.T)
    np.testing.assert_array_equal(ss.P_filt, ss.P_filt.T)
    assert np.linalg.eigvalsh(ss.P_pred)[0] >= -1e-10 * np.linalg.norm(X)
    assert ss.residual <= 1e-11
    assert ss.method == method and ss.form == "kalman"


@pytest.mark.parametrize("key", list(DAREX))
def test_darex_steady_state_quantities_follow_eq_10(key, darex_scipy):
    """K = Pp H^T (H Pp H^T + R)^{-1}, Pe = (I - K H) Pp, A = (I - K H) F, B = K, and
    the Kalman closed loop A (hence F - F K H) is stable (the solution is the stabilising one)."""
    model = darex_model(key)
    ss = steady_state(model, "doubling")
    F, H, R = model.F, model.H, model.R
    Pp = darex_scipy[key]
    K = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + R)
    eye = np.eye(model.n)
    scale = max(1.0, np.linalg.norm(K))
    assert np.linalg.norm(ss.K - K) <= 1e-9 * scale
    np.testing.assert_array_equal(ss.B, ss.K)
    assert np.linalg.norm(ss.A - (eye - ss.K @ H) @ F) <= 1e-13 * max(1.0, np.linalg.norm(F))
    # Pe = (I - K H) Pp with the solver's own Pp and K (the identity, to rounding; (I - K H) Pp cancels
    # digits when Pp is large, darex12: 1e12, so compare on the scale of Pp).  Not with scipy's X:
    # on darex8 (an eigenvalue of F at -0.999982) scipy's solve_discrete_are is off by 2.3e-12 relative
    # on some machines, while the doubling solution agrees with a 40-digit Riccati iteration to 4e-16;
    # the distance to scipy's X is checked, with its tolerance, in test_darex_solution_matches_scipy.
    assert np.linalg.norm(ss.P_filt - (eye - ss.K @ H) @ ss.P_pred) <= 1e-12 * np.linalg.norm(Pp)
    # prediction from the filtered steady state closes the loop: Pp = F Pe F^T + Q
    assert _rel(F @ ss.P_filt @ F.T + model.Q, ss.P_pred) <= 1e-10
    assert max(abs(np.linalg.eigvals(ss.A))) < 1.0


@pytest.mark.parametrize("key", list(DAREX))
def test_darex_lainiotis_form_gives_the_kalman_a_b(key):
    """RELF (eq. 14) + eq. 13 reproduce A_KF, B_KF (eq. 15) and the same Pe."""
    model = darex_model(key)
    kal = steady_state(model, "dare")
    lai = steady_state(model, "per-step", form="lainiotis")
    assert lai.form == "lainiotis"
    for name in ("A", "B", "K"):
        got, want = getattr(lai, name), getattr(kal, name)
        err = np.linalg.norm(got - want) / max(1.0, np.linalg.norm(want))
        assert err <= 1e-9, f"{key}: {name} differs by {err:.3g}"
    assert _rel(lai.P_filt, kal.P_filt) <= 1e-9 or np.linalg.norm(kal.P_filt) < 1e-12
    assert _rel(lai.P_pred, kal.P_pred) <= 1e-9


def test_doubling_needs_logarithmically_few_steps():
    """Doubling step k covers 2^k per-step iterations: far fewer steps on a slow case."""
    model = darex_model("darex7")
    per_step = steady_state(model, "per-step")
    doubling = steady_state(model, "doubling")
    assert steady_state(model, "dare").iterations == 0
    assert per_step.iterations > 500
    assert doubling.iterations <= np.log2(per_step.iterations) + 3


# --------------------------------------------------------------------------- the papers' models

PAPER = {
    "B-printed": lambda: assimakis_model_b(),
    "B-position": lambda: assimakis_model_b(measurement="position"),
    "A2-printed": lambda: assimakis_model_a(2),
    "A3-position": lambda: assimakis_model_a(3, measurement="position"),
    "B-dt0.1": lambda: assimakis_model_b(dt=0.1, sigma_q2=1.0, sigma_r2=0.01),
}


@pytest.mark.parametrize("key", list(PAPER))
def test_paper_models_all_solvers_agree(key):
    model = PAPER[key]()
    X = scipy.linalg.solve_discrete_are(model.F.T, model.H.T, model.Q, model.R)
    sols = {method: steady_state(model, method) for method in METHODS}
    sols["relf"] = steady_state(model, "per-step", form="lainiotis")
    for method, ss in sols.items():
        assert _rel(ss.P_pred, X) <= 1e-10, method
        assert _rel(ss.P_filt, sols["dare"].P_filt) <= 1e-10, method
        assert _rel(ss.A, sols["dare"].A) <= 1e-10, method
        assert _rel(ss.B, sols["dare"].B) <= 1e-10, method


def test_model_b_steady_state_pinned():
    """Steady state of the papers' example (dt = 1, sigma_q^2 = 0.01, sigma_r^2 = 0.1, H = [1 1]).

    Reference values from scipy.linalg.solve_discrete_are (independent of mptrack) to 8 digits;
    they pin the model as printed (a different H or Q changes the leading digits).
    """
    ss = steady_state(assimakis_model_b(), "doubling")
    np.testing.assert_allclose(ss.P_pred, [[0.05971936, 0.02568348], [0.02568348, 0.02266428]], rtol=2e-7)
    np.testing.assert_allclose(ss.K[:, 0], [0.36535881, 0.20683481], rtol=2e-7)


def test_model_a_steady_state_is_block_diagonal_copy_of_model_b():
    b = steady_state(assimakis_model_b(), "dare")
    a = steady_state(assimakis_model_a(3), "doubling")
    for name in ("P_pred", "P_filt", "A", "B", "K"):
        want = scipy.linalg.block_diag(*[getattr(b, name)] * 3)
        np.testing.assert_allclose(getattr(a, name), want, rtol=1e-11, atol=1e-14, err_msg=name)


def test_per_step_steady_state_is_the_kalman_filter_covariance_limit():
    """The per-step solution from P(0/0) = P0 after k iterations is the KF's P(k+1/k);
    ``steady_state_time`` is the step from which the KF's covariance has settled."""
    model = assimakis_model_b()
    ss = steady_state(model, "per-step")
    k = ss.steady_state_time
    # the iteration goes on to the rounding level (issue 16); the steady-state time is the first
    # step within 1e-13
    assert k <= ss.iterations and 10 < k < 200
    kf = kalman_filter(model, np.zeros((k + 5, 1)), P0=np.zeros((2, 2)))
    # row k of P_pred is P(k+1/k), the k-th per-step iterate
    assert _rel(kf.P_pred[k], ss.P_pred) <= 1e-12
    assert _rel(kf.P[k], ss.P_filt) <= 1e-12
    # and it had not settled to that accuracy well before
    assert _rel(kf.P_pred[k // 2], ss.P_pred) > 1e-12


def test_per_step_solution_does_not_depend_on_p0():
    model = assimakis_model_a(2)
    ref = steady_state(model, "dare")
    for P0 in (np.zeros((4, 4)), 100.0 * np.eye(4), np.diag([1.0, 0.0, 3.0, 0.0])):
        for form in ("kalman", "lainiotis"):
            ss = steady_state(model, "per-step", form=form, P0=P0)
            assert _rel(ss.P_pred, ref.P_pred) <= 1e-10, (P0, form)


def test_unobserved_stable_model_solves_the_lyapunov_equation():
    """H = 0 with stable F is detectable: Pp is the stationary covariance F Pp F^T + Q = Pp."""
    F = np.array([[0.5, 0.3], [-0.2, 0.7]])
    Q = np.array([[1.0, 0.2], [0.2, 0.5]])
    model = LinearGaussianModel(F, np.zeros((1, 2)), Q, [[1.0]])
    lyap = scipy.linalg.solve_discrete_lyapunov(F, Q)
    for method in METHODS:
        ss = steady_state(model, method)
        assert _rel(ss.P_pred, lyap) <= 1e-10, method
        np.testing.assert_allclose(ss.K, 0.0, atol=1e-15)


# --------------------------------------------------------------------------- step and residual

def test_riccati_step_is_eq_11():
    model = darex_model("darex2")
    P = np.array([[2.0, 0.3], [0.3, 1.0]])
    F, H, Q, R = model.F, model.H, model.Q, model.R
    want = Q + F @ P @ F.T - F @ P @ H.T @ np.linalg.inv(H @ P @ H.T + R) @ H @ P @ F.T
    np.testing.assert_allclose(riccati_step(model, P), want, rtol=1e-13)


def test_residual_is_zero_at_the_solution_and_not_elsewhere():
    model = assimakis_model_a(2)
    ss = steady_state(model, "dare")
    assert riccati_residual(model, ss.P_pred) <= 1e-14
    assert riccati_residual(model, 1.01 * ss.P_pred) > 1e-5


def test_lainiotis_parameters_are_eq_7():
    model = assimakis_model_a(2, dt=0.8, sigma_q2=0.05, sigma_r2=0.2)
    F, H, Q, R = model.F, model.H, model.Q, model.R
    lp = lainiotis_parameters(model)
    A = np.linalg.inv(H @ Q @ H.T + R)
    Kn = Q @ H.T @ A
    want = dict(A=A, Kn=Kn, Km=F.T @ H.T @ A, Pn=Q - Kn @ H @ Q, Fn=F - Kn @ H @ F,
                On=F.T @ H.T @ A @ H @ F)
    for name, value in want.items():
        np.testing.assert_allclose(getattr(lp, name), value, rtol=1e-13, atol=1e-16, err_msg=name)
