"""Monte-Carlo throughput of the range filters (EKF, FEKF, FCS): batched across runs vs one run at a
time, and the batched EKF against FilterPy's ExtendedKalmanFilter on the same tracks, in one run."""

from __future__ import annotations


import numpy as np

from ..experiments.bouzera2017 import Setup, ranges, simulate
from ..cellular import (
    ekf_ranges,
    ekf_ranges_batch,
    fcs_ranges,
    fcs_ranges_batch,
    fekf_ranges,
    fekf_ranges_batch,
    range_measurement,
)
from . import register_suite
from ._timing import best_time

__all__ = ["cellular_suite"]




def _filterpy_runs(z, st, x0, P0, Q0, R0):
    from filterpy.kalman import ExtendedKalmanFilter

    for b in range(z.shape[0]):
        ekf = ExtendedKalmanFilter(dim_x=3, dim_z=st.shape[0])
        ekf.x, ekf.P, ekf.Q, ekf.R = x0[b].copy(), P0.copy(), Q0.copy(), R0 * np.eye(st.shape[0])
        for zk in z[b]:
            ekf.predict()
            ekf.update(zk, lambda x: range_measurement(x, st)[1], lambda x: range_measurement(x, st)[0])


@register_suite("cellular")
def cellular_suite(quick: bool) -> dict:
    setup = Setup()
    runs = 20 if quick else 100
    truth, x0, eps = simulate(setup, "linear", np.random.SeedSequence(0), runs)
    z = ranges(setup, truth, eps, setup.sigma)
    st, P0, Q0, R0 = setup.stations, np.diag(setup.P0_diag), np.diag(setup.Q0_diag), setup.R0
    repeats = 1 if quick else 3
    single_runs = min(runs, 10)
    rows = []
    for name, batch, single in (("EKF", ekf_ranges_batch, ekf_ranges), ("FEKF", fekf_ranges_batch, fekf_ranges),
                                ("FCS", fcs_ranges_batch, fcs_ranges)):
        tb = best_time(lambda: batch(z, st, x0, P0, Q0, R0), repeats)
        ts = best_time(lambda: [single(z[b], st, x0[b], P0, Q0, R0) for b in range(single_runs)], repeats) / single_runs
        rows.append([name, setup.steps, runs / tb, 1.0 / ts, (runs / tb) * ts])
    notes = [f"{runs} runs of {setup.steps} steps, 3 stations (bouzera2017 linear scenario); best of {repeats}.",
             "runs/s batched: all runs advanced together in numpy; one at a time: the same code with B = 1."]
    try:
        fp_runs = min(runs, 10)
        t_fp = best_time(lambda: _filterpy_runs(z[:fp_runs], st, x0[:fp_runs], P0, Q0, R0), repeats) / fp_runs
        rows.append(["EKF (FilterPy, per run)", setup.steps, 1.0 / t_fp, 1.0 / t_fp, 1.0])
        notes.append(f"batched EKF vs FilterPy ExtendedKalmanFilter: {rows[0][2] * t_fp:.1f}x the runs/s.")
    except ImportError:  # pragma: no cover - filterpy is in the bench extra
        notes.append("FilterPy not installed: peer comparison skipped.")
    return {"suite": "cellular", "title": "Range-filter Monte-Carlo throughput",
            "columns": ["filter", "steps", "runs/s batched", "runs/s one at a time", "speed-up"],
            "rows": rows, "notes": notes}
