"""The compiled time loops compute exactly the readable single-step equations."""

import numpy as np

from mptrack.linear import kalman_filter, kalman_step, lainiotis_filter, lainiotis_step, steady_state_filter
from mptrack.models import assimakis_model_a
from mptrack.riccati import lainiotis_parameters, steady_state
from mptrack.sim import simulate_linear


def _data(missing=False):
    model = assimakis_model_a(3)
    _, z = simulate_linear(model, 60, np.random.default_rng(7))
    if missing:
        z[10] = np.nan
        z[20, 1] = np.nan
    return model, z


def test_kalman_filter_equals_kalman_step_loop():
    for joseph in (False, True):
        for missing in (False, True):
            model, z = _data(missing)
            x, P = np.ones(model.n), np.eye(model.n)
            res = kalman_filter(model, z, x, P, joseph=joseph)
            ll = 0.0
            for k in range(len(z)):
                x, P, xp, Pp, inc = kalman_step(model.F, model.H, model.Q, model.R, x, P, z[k], joseph)
                ll += inc
                np.testing.assert_allclose(res.x[k], x, rtol=1e-12, atol=1e-12)
                np.testing.assert_allclose(res.P[k], P, rtol=1e-12, atol=1e-14)
                np.testing.assert_allclose(res.x_pred[k], xp, rtol=1e-12, atol=1e-12)
                np.testing.assert_allclose(res.P_pred[k], Pp, rtol=1e-12, atol=1e-14)
            assert res.loglik == np.float64(ll) or abs(res.loglik - ll) < 1e-9 * abs(ll)


def test_lainiotis_filter_equals_lainiotis_step_loop():
    for missing in (False, True):
        model, z = _data(missing)
        lp = lainiotis_parameters(model)
        x, P = np.ones(model.n), 0.5 * np.eye(model.n)
        res = lainiotis_filter(model, z, x, P)
        eye = np.eye(model.n)
        for k in range(len(z)):
            x, P = lainiotis_step(lp, model.F, model.Q, x, P, z[k], eye)
            np.testing.assert_allclose(res.x[k], x, rtol=1e-11, atol=1e-11)
            np.testing.assert_allclose(res.P[k], P, rtol=1e-11, atol=1e-13)


def test_steady_state_loop_equals_matrix_recursion_and_predicts_through_gaps():
    model, z = _data(missing=True)
    ss = steady_state(model)
    res = steady_state_filter(model, z, np.ones(model.n), steady=ss)
    x = np.ones(model.n)
    for k in range(len(z)):
        x = model.F @ x if np.isnan(z[k]).any() else ss.A @ x + ss.B @ z[k]
        np.testing.assert_allclose(res.x[k], x, rtol=1e-12, atol=1e-12)
