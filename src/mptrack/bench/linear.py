"""Per-iteration speed of the 12 implementations of Assimakis & Adam 2014, Table 1, and of the per-step
KF against FilterPy's and pykalman's on the same 4-state model, in one run."""

from __future__ import annotations


import numpy as np

from ..linear import IMPLEMENTATIONS, kalman_filter
from ..models import assimakis_model_a
from ..sim import simulate_linear
from . import register_suite
from ._timing import best_time

__all__ = ["linear_suite"]




def _filterpy(model, z, x0, P0):
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=model.n, dim_z=model.m)
    kf.F, kf.H, kf.Q, kf.R = (np.array(a) for a in (model.F, model.H, model.Q, model.R))
    kf.x, kf.P = x0.copy(), P0.copy()
    out = np.empty((len(z), model.n))
    for k, zk in enumerate(z):
        kf.predict()
        kf.update(zk)
        out[k] = kf.x
    return out


def _pykalman(model, z, x0, P0):
    from pykalman import KalmanFilter

    # pykalman's prior is x(1/0): predict our x(0/0) once.
    kf = KalmanFilter(transition_matrices=model.F, observation_matrices=model.H,
                      transition_covariance=model.Q, observation_covariance=model.R,
                      initial_state_mean=model.F @ x0,
                      initial_state_covariance=model.F @ P0 @ model.F.T + model.Q)
    return kf.filter(z)[0]


@register_suite("linear")
def linear_suite(quick: bool) -> dict:
    steps = 300 if quick else 5000
    repeats = 2 if quick else 5
    model = assimakis_model_a(2)
    _, z = simulate_linear(model, steps, np.random.default_rng(2014))
    x0, P0 = np.zeros(model.n), np.eye(model.n)
    notes = []
    ours = kalman_filter(model, z, x0, P0)  # also compiles/loads the kernel before timing
    t_kf = best_time(lambda: kalman_filter(model, z, x0, P0), repeats)
    copy_t = best_time(lambda: (z.copy(), ours.x.copy(), ours.P.copy()), repeats)
    rows = [["memory copy of z, x, P (baseline)", steps / copy_t, t_kf / copy_t]]
    rows.append(["mptrack kalman_filter (KF-A)", steps / t_kf, 1.0])
    for name, fn in (("FilterPy KalmanFilter", _filterpy), ("pykalman KalmanFilter.filter", _pykalman)):
        try:
            peer = fn(model, z, x0, P0)
        except ImportError:
            notes.append(f"{name}: not installed (pip install 'mptrack[bench]')")
            continue
        err = float(np.max(np.abs(peer - ours.x)))
        if err > 1e-8 * max(1.0, float(np.max(np.abs(ours.x)))):
            raise AssertionError(f"{name} disagrees with mptrack by {err:g}; not timing it")
        t = best_time(lambda fn=fn: fn(model, z, x0, P0), max(1, repeats // 2))
        rows.append([name, steps / t, t_kf / t])
    for imp in IMPLEMENTATIONS:
        runner = imp.prepare(2)
        runner(z, x0, np.zeros((4, 4)))
        t = best_time(lambda runner=runner: runner(z, x0, np.zeros((4, 4))), repeats)
        rows.append([f"implementation {imp.number}: {imp.name}", steps / t, t_kf / t])
    notes.append(f"{steps} steps of the 2-D model A (n=4, m=2); best of {repeats}; peers checked to agree "
                 "with mptrack to 1e-8 before timing. 'x KF-A' = steps/s of the row / steps/s of mptrack's "
                 "kalman_filter in the same run (above 1: faster than it; a peer's 1 / 'x KF-A' is mptrack's "
                 "speed-up over it).")
    return {"suite": "linear", "title": "per-step filters, one track",
            "columns": ["implementation", "steps/s", "x KF-A"],
            "rows": rows, "notes": notes}
