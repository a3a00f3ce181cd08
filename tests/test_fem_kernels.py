"""The grid filter's compiled kernels against their NumPy definitions (to 1e-12)."""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse.linalg

from mptrack.continuous import FEMGrid, linear_sde_model, zhao2013_model
from mptrack.continuous import _fem
from mptrack.continuous._fem_kernels import cholesky_solve, flow_points, push_points
from mptrack.continuous._model import rk4_flow


def _density(g, m, P):
    p = _fem._gaussian_on(g, m, P)
    return p / (g.W0 @ p)


@pytest.mark.parametrize("shape", [(3, 5), (20, 20)])
def test_push_points_equal_the_numpy_quadrature(shape):
    g = FEMGrid([-1.0, 0.5], [2.0, 1.7], *shape)
    p = _density(g, np.array([0.4, 1.1]), np.diag([0.05, 0.02]))
    loc, phi, wq = _fem._push_rule(*shape, _fem._PUSH_GAUSS, _fem._PUSH_SUB)
    area = float(g._h[0] * g._h[1])
    X, w = push_points(p, g.conn, phi, wq * area, loc, g.lo, g._h, *shape, 1e-12)
    # NumPy: every element's points, weights from the nodal values, the negligible ones dropped
    e1, e2 = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    corner = np.stack([e1.ravel(), e2.ravel()], axis=-1).astype(float)
    uq = (corner[:, None, :] + loc[None]).reshape(-1, 2)
    ref_w = ((p[g.conn] @ phi.T) * (wq * area)).ravel()
    keep = np.abs(ref_w) > 1e-12 * np.max(np.abs(ref_w))
    assert 0 < keep.sum() < keep.size or shape == (3, 5)
    np.testing.assert_allclose(w, ref_w[keep], rtol=1e-12, atol=1e-12 * np.abs(ref_w).max())
    np.testing.assert_array_equal(X, g.lo + g._h * uq[keep])


@pytest.mark.parametrize("variant, scale, spread", [("vdp", 0.01, 3.0), ("vdp", 1.0, 14.0), ("printed", 0.001, 2.0)])
def test_compiled_flow_takes_the_numpy_step_count_and_path(variant, scale, spread):
    model = zhao2013_model(variant=variant, diffusion_scale=scale)
    X = np.random.default_rng(7).uniform(-spread, spread, (1000, 2))  # 4 blocks, a short last one
    for duration in (0.25, 1.0):
        steps = _fem._flow_steps(model, X, duration)
        Y = X.copy()
        cm = _fem._compiled(model)
        got = flow_points(Y, *cm.drift_at, model.kernels.drift_params, duration, model.dt, model.max_increment)
        assert got == steps
        np.testing.assert_allclose(Y, rk4_flow(model, X, duration, steps), rtol=1e-12, atol=1e-12)


def test_compiled_flow_of_a_linear_model():
    model = linear_sde_model([[0.0, 1.0], [20.0, -20.0]], np.eye(2), np.eye(2), np.eye(2), 1.0)
    X = np.random.default_rng(8).normal(size=(300, 2))
    steps = _fem._flow_steps(model, X, 0.25)
    assert steps > 1
    np.testing.assert_allclose(_fem._drift_flow(model, X, 0.25), rk4_flow(model, X, 0.25, steps), rtol=1e-12,
                               atol=1e-12)


@pytest.mark.parametrize("shape", [(4, 6), (20, 20)])
def test_band_cholesky_of_the_mass_matrix_solves_the_assembled_system(shape):
    g = FEMGrid([0.0, 0.0], [float(shape[0]), float(shape[1])], *shape)
    M = g.assemble(g._top["Me"])
    b = np.random.default_rng(9).standard_normal(g.size)
    C, kd = _fem._unit_mass_factor(*shape)
    got = cholesky_solve(C, kd, b.copy())
    np.testing.assert_allclose(got, scipy.sparse.linalg.spsolve(M.tocsc(), b), rtol=1e-12, atol=1e-12)
    dense = M.toarray()
    assert C.shape == (g.size, 2 * (kd + 1))
    assert np.all(np.abs(np.triu(dense, kd + 1)) == 0.0)
    # both halves hold LAPACK's factor: columns of L in the first, rows in the second
    L = scipy.linalg.cholesky(dense, lower=True)
    for j in range(g.size):
        m = min(kd, g.size - 1 - j)
        np.testing.assert_allclose(C[j, : m + 1], L[j: j + m + 1, j], atol=1e-12)
        lo = max(0, j - kd)
        np.testing.assert_allclose(C[j, kd + 1 + lo - (j - kd):], L[j, lo: j + 1], atol=1e-12)
