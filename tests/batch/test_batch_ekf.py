"""The batched range EKF ≡ a plain numpy EKF per track."""

import numpy as np
import pytest

from mptrack import batch
from mptrack.errors import ParameterError, ShapeError

STATIONS = [[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0]]
MODEL = batch.RangeModel.constant_velocity(1.0, 0.5, STATIONS, 25.0)


def ekf_reference(model, z, x0, P0):
    """Textbook EKF, one track, numpy (gain through the inverse of S)."""
    x, P = np.array(x0, float), np.array(P0, float)
    pos = list(model.position)
    out = np.empty((len(z), model.n))
    for k, zk in enumerate(z):
        x = model.F @ x
        P = model.F @ P @ model.F.T + model.Q
        ok = ~np.isnan(zk)
        if ok.any():
            diff = x[pos][None, :] - model.stations[ok]
            r = np.linalg.norm(diff, axis=1)
            H = np.zeros((ok.sum(), model.n))
            H[:, pos] = diff / r[:, None]
            S = H @ P @ H.T + model.R[np.ix_(ok, ok)]
            K = P @ H.T @ np.linalg.inv(S)
            x = x + K @ (zk[ok] - r)
            P = P - K @ H @ P
            P = 0.5 * (P + P.T)
        out[k] = x
    return out


def simulate(model, runs, steps, rng, x0):
    L = np.linalg.cholesky(model.Q + 1e-12 * np.eye(model.n))
    x = np.tile(x0, (runs, 1))
    truth = np.empty((runs, steps, model.n))
    for k in range(steps):
        x = x @ model.F.T + rng.standard_normal((runs, model.n)) @ L.T
        truth[:, k] = x
    p = truth[..., list(model.position)]
    ranges = np.linalg.norm(p[:, :, None, :] - model.stations[None, None], axis=-1)
    return truth, ranges + 5.0 * rng.standard_normal(ranges.shape)


def test_batched_range_ekf_matches_numpy_reference_with_gaps_and_ragged_lengths():
    rng = np.random.default_rng(0)
    x0 = np.array([400.0, 5.0, 300.0, -3.0])
    truth, z = simulate(MODEL, 9, 60, rng, x0)
    z[1, 10:15] = np.nan
    z[2, 20, 1] = np.nan
    lengths = np.array([60, 60, 60, 5, 0, 60, 33, 60, 60])
    P0 = np.diag([100.0, 4.0, 100.0, 4.0])
    res = batch.ekf_ranges(MODEL, z, x0, P0, lengths=lengths)
    assert res.method == "EKF" and res.P is None and res.loglik is None    # states only
    got = res.x
    for b, L in enumerate(lengths):
        assert np.isnan(got[b, L:]).all()
        if L:
            np.testing.assert_allclose(got[b, :L], ekf_reference(MODEL, z[b, :L], x0, P0),
                                       rtol=1e-10, atol=1e-9)
    full = lengths == 60
    err = np.sqrt(np.mean((got[full][:, 20:, [0, 2]] - truth[full][:, 20:, [0, 2]]) ** 2))
    assert err < 5.0    # better than one range's noise (5 m) once converged


def test_range_model_validation():
    with pytest.raises(ShapeError, match="position: expected 2 distinct state indices"):
        batch.RangeModel(np.eye(4), np.eye(4), STATIONS, np.eye(3), position=(0, 0))
    with pytest.raises(ParameterError, match="x0: the EKF needs a prior"):
        batch.ekf_ranges(MODEL, np.zeros((1, 3, 3)), None, np.eye(4))
    with pytest.raises(ParameterError, match="model: expected a RangeModel"):
        batch.ekf_ranges("model", np.zeros((1, 3, 3)), np.ones(4), np.eye(4))
    with pytest.raises(ShapeError, match=r"z: expected shape \(B, T, 3\)"):
        batch.ekf_ranges(MODEL, np.zeros((1, 3, 2)), np.ones(4), np.eye(4))


def test_range_ekf_agrees_with_the_numpy_batch_ekf_of_mptrack_nonlinear():
    """Independent implementation: mptrack.nonlinear.ekf_ranges_batch (state [p, v], cv motion)."""
    from mptrack.cellular import ekf_ranges_batch, motion_matrix

    F = motion_matrix("cv", 2, 1.0)                     # state [x, vx, y, vy]
    Q = np.diag([1.0, 0.25, 1.0, 0.25])
    R = 16.0 * np.eye(3)
    model = batch.RangeModel(F, Q, STATIONS, R, position=(0, 2))
    rng = np.random.default_rng(1)
    x0 = np.array([300.0, 4.0, 450.0, -2.0]) + rng.normal(0, 10, (6, 4))
    _, z = simulate(model, 6, 40, rng, x0[0])
    P0 = np.diag([100.0, 4.0, 100.0, 4.0])
    ours = batch.ekf_ranges(model, z, x0, P0).x
    theirs = ekf_ranges_batch(z, STATIONS, x0, P0, Q, R, motion="cv", dt=1.0).x
    np.testing.assert_allclose(ours, theirs, rtol=1e-10, atol=1e-8)
