"""Speed of N-step prediction (Assimakis et al. 2016), RTS smoothing and irregular-time filtering on the
2-D constant-velocity model, against FilterPy's RTS smoother, in one run."""

from __future__ import annotations

import numpy as np

from ..linear import (
    kalman_filter,
    kalman_filter_irregular,
    predict_ahead,
    rts_smoother,
    steady_state_filter,
    steady_state_predictor,
    steady_state_smoother,
)
from ..models import constant_velocity, constant_velocity_continuous
from ..riccati import steady_state
from ..sim import simulate_linear
from . import register_suite
from ._timing import best_time

__all__ = ["prediction_suite"]


def _filterpy_rts(model, kf):
    from filterpy.kalman import KalmanFilter

    smoother = KalmanFilter(dim_x=model.n, dim_z=model.m)
    smoother.F, smoother.Q = np.array(model.F), np.array(model.Q)
    return smoother.rts_smoother(kf.x, kf.P)[0]


@register_suite("prediction")
def prediction_suite(quick: bool) -> dict:
    steps = 300 if quick else 5000
    repeats = 2 if quick else 5
    model = constant_velocity(1.0, 0.01, 2, sigma_r2=0.1)
    cont = constant_velocity_continuous(0.01, 2, sigma_r2=0.1)
    _, z = simulate_linear(model, steps, np.random.default_rng(2016))
    x0, P0 = np.zeros(model.n), np.eye(model.n)
    ss = steady_state(model)
    times = np.arange(1, steps + 1, dtype=float)
    kf = kalman_filter(model, z, x0, P0)
    filt = steady_state_filter(model, z, x0, steady=ss)
    steady_state_predictor(model, z, 5, x0, steady=ss)  # compile the kernels before timing
    t_ss = best_time(lambda: steady_state_filter(model, z, x0, steady=ss), repeats)
    cases = [
        ("steady-state filter (SSKF, reference)", lambda: steady_state_filter(model, z, x0, steady=ss)),
        ("SS predictor N=5, eq. 19 (A_N, B_N)", lambda: steady_state_predictor(model, z, 5, x0, steady=ss)),
        ("SS predictor N=5, inverse-free F^N x(k/k)",
         lambda: steady_state_predictor(model, z, 5, x0, steady=ss, method="inverse-free")),
        ("KF + predict_ahead N=5", lambda: predict_ahead(model, kalman_filter(model, z, x0, P0), 5)),
        ("kalman_filter (fixed dt)", lambda: kalman_filter(model, z, x0, P0)),
        ("kalman_filter_irregular (equal stamps)", lambda: kalman_filter_irregular(cont, times, z, x0, P0)),
        ("rts_smoother on a KF result", lambda: rts_smoother(model, kf)),
        ("steady_state_smoother on the SSKF result", lambda: steady_state_smoother(model, filt, steady=ss)),
    ]
    rows, notes = [], []
    ours_rts = rts_smoother(model, kf).x
    for name, fn in cases:
        t = best_time(fn, repeats)
        rows.append([name, steps / t, t_ss / t, None])
    t_rts = best_time(lambda: rts_smoother(model, kf), repeats)
    for name, fn in (("FilterPy KalmanFilter.rts_smoother", lambda: _filterpy_rts(model, kf)),):
        try:
            peer = fn()
        except ImportError:
            notes.append(f"{name}: not installed (pip install 'mptrack[bench]')")
            continue
        err = float(np.max(np.abs(peer - ours_rts)))
        if err > 1e-7 * max(1.0, float(np.max(np.abs(ours_rts)))):
            raise AssertionError(f"{name} disagrees with mptrack's RTS smoother by {err:g}; not timing it")
        t = best_time(fn, max(1, repeats // 2))
        rows.append([name, steps / t, t_ss / t, t_rts / t])
    notes.append(f"{steps} steps of the 2-D CV model (n=4, m=2), best of {repeats}; peers checked to agree "
                 "with mptrack's RTS smoother before timing. 'x SSKF' = steps/s of the row / steps/s of the "
                 "steady-state filter; 'x mptrack RTS' = steps/s of the peer / steps/s of mptrack's rts_smoother "
                 "(both in the same run; above 1: faster than the anchor).")
    return {"suite": "prediction", "title": "N-step prediction, smoothing, irregular sampling (one track)",
            "columns": ["operation", "steps/s", "x SSKF", "x mptrack RTS"],
            "rows": rows, "notes": notes}
