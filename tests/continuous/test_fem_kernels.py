"""The grid filter's compiled kernels against their NumPy definitions (to 1e-12)."""

import itertools

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse.linalg

from mptrack.continuous import (
    FEMGrid,
    _fem,
    _fem_grid,
    _fem_kernels,
    _fem_schemes,
    linear_sde_model,
    zhao2013_model,
)
from mptrack.continuous._fem_kernels import (
    cholesky_solve,
    deposit,
    flow_points,
    flow_sites,
    transport_deposit,
)
from mptrack.continuous._model import rk4_flow


def _density(g, m, P):
    p = _fem._gaussian_on(g, m, P)
    return p / (g.W0 @ p)


@pytest.mark.parametrize("shape", [(3, 5), (20, 20)])
def test_transport_deposit_equals_the_numpy_quadrature(shape):
    """Every element's quadrature (the fine rule, or the coarse one where all its nodal values are below
    the tail level), the points' images under the serendipity interpolant of the flowed nodes deposited
    on the new grid, and the points of the elements whose flowed centre that interpolant misses
    returned for an exact flow instead."""
    g = FEMGrid([-1.0, 0.5], [2.0, 1.7], *shape)
    p = _density(g, np.array([0.4, 1.1]), np.diag([0.05, 0.02]))
    loc, phi, wq, bounds, _ = rules = _fem_schemes._push_rules(((3, 1, 0.03), (2, 1, 1e-3)))   # three rules
    fine, mid, coarse = ((loc[a:b], phi[a:b], wq[a:b]) for a, b in itertools.pairwise(bounds))
    sites = flow_sites(g.lo, g._h, g._top["lattice"], *shape)
    N = g.size
    np.testing.assert_array_equal(sites[:N], g.nodes)
    Z = sites @ np.array([[1.1, 0.2], [-0.3, 0.9]]).T + 0.5 + 0.05 * np.exp(np.prod(sites, axis=1, keepdims=True))
    # (a smooth map outside the serendipity space: its interpolant misses the centres by different amounts)
    new = FEMGrid([-0.2, 0.8], [2.6, 2.3], shape[0] + 1, shape[1] + 2)  # some images fall outside it
    # NumPy: element by element, the interpolant's miss at the centres first
    miss = [np.max(np.abs(Z[N + e] - _fem_grid.shape_functions(0.0, 0.0)[0] @ Z[nodes]) / new._h)
            for e, nodes in enumerate(g.conn)]
    tol = float(np.median(miss))
    b = np.zeros(new.size)
    outside, total, X, w = transport_deposit(p, g.conn, g.lo, g._h, shape[1], *rules, Z, tol, 1e-12, new.lo,
                                             new._h, new.n1, new.n2, new.conn, b)
    rows = []
    for e, nodes in enumerate(g.conn):
        corner = np.array([e // shape[1], e % shape[1]], dtype=float)
        top = np.abs(p[nodes]).max() / np.abs(p).max()
        loc, phi, wq = coarse if top < 1e-3 else mid if top < 0.03 else fine
        for k in range(len(wq)):
            rows.append((g.lo + g._h * (corner + loc[k]), phi[k] @ Z[nodes], (p[nodes] @ phi[k]) * wq[k] * np.prod(g._h),
                         miss[e] > tol))
    ref_X, ref_Y, ref_w, ref_exact = (np.array(c) for c in zip(*rows))
    keep = np.abs(ref_w) > 1e-12 * np.max(np.abs(ref_w))
    assert [len(r[2]) for r in (fine, mid, coarse)] == [36, 9, 4]
    assert keep.sum() < 36 * len(g.conn) or shape == (3, 5)
    exact, moved = keep & ref_exact, keep & ~ref_exact
    assert exact.any() and moved.any()
    np.testing.assert_allclose(X, ref_X[exact], rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(w, ref_w[exact], rtol=1e-12, atol=1e-12 * np.abs(ref_w).max())
    ref_b = np.zeros(new.size)
    ref_outside = deposit(ref_Y[moved], ref_w[moved], new.lo, new._h, new.n1, new.n2, new.conn, ref_b)
    assert ref_outside != 0.0                                           # (weights can be negative)
    np.testing.assert_allclose(b, ref_b, rtol=1e-10, atol=1e-12 * np.abs(ref_b).max())
    assert outside == pytest.approx(ref_outside, rel=1e-10) and total == pytest.approx(ref_w[keep].sum(), rel=1e-12)


@pytest.mark.parametrize("variant, scale, spread", [("vdp", 0.01, 3.0), ("vdp", 1.0, 14.0), ("printed", 0.001, 2.0)])
def test_compiled_flow_takes_the_numpy_step_count_and_path(variant, scale, spread):
    model = zhao2013_model(variant=variant, diffusion_scale=scale)
    X = np.random.default_rng(7).uniform(-spread, spread, (1000, 2))  # 4 blocks, a short last one
    for duration in (0.25, 1.0):
        steps = _fem_schemes._flow_steps(model, X, duration)
        Y = X.copy()
        cm = _fem_schemes._compiled(model)
        got = flow_points(Y, *cm.drift_at, model.kernels.drift_params, duration, model.dt, model.max_increment)
        assert got == steps
        np.testing.assert_allclose(Y, rk4_flow(model, X, duration, steps), rtol=1e-12, atol=1e-12)


def test_compiled_flow_of_a_linear_model():
    model = linear_sde_model([[0.0, 1.0], [20.0, -20.0]], np.eye(2), np.eye(2), np.eye(2), 1.0)
    X = np.random.default_rng(8).normal(size=(300, 2))
    steps = _fem_schemes._flow_steps(model, X, 0.25)
    assert steps > 1
    np.testing.assert_allclose(_fem_schemes._drift_flow(model, X, 0.25), rk4_flow(model, X, 0.25, steps), rtol=1e-12,
                               atol=1e-12)


@pytest.mark.parametrize("shape", [(4, 6), (20, 20)])
def test_band_cholesky_of_the_mass_matrix_solves_the_assembled_system(shape):
    g = FEMGrid([0.0, 0.0], [float(shape[0]), float(shape[1])], *shape)
    M = g.assemble(g._top["Me"])
    b = np.random.default_rng(9).standard_normal(g.size)
    C, kd = _fem_schemes._unit_mass_factor(*shape)
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


@pytest.mark.parametrize("scale, moving", [(0.01, True), (1.0, True), (0.01, False)])
def test_compiled_transport_equals_the_numpy_flow_path(scale, moving):
    """transport_split (compiled end to end) against the same steps with the NumPy flow in between (the
    path of a model without kernels): the next grid, the transported density, lost and clipped mass."""
    import dataclasses

    model = zhao2013_model(variant="vdp", diffusion_scale=scale)   # max_increment set at Q x 1: capped flows
    plain = dataclasses.replace(model, kernels=None)
    g = FEMGrid([-1.5, 0.5], [2.5, 3.5], 20, 20)
    p = _density(g, np.array([0.4, 2.0]), np.array([[0.3, 0.1], [0.1, 0.2]]))
    got = _fem_schemes._Characteristics(model, None, 4.0, 4, False, (20, 20)).transport(g, p, moving, 0.25)
    want = _fem_schemes._Characteristics(plain, None, 4.0, 4, False, (20, 20)).transport(g, p, moving, 0.25)
    assert (got[0] is g) == (not moving) and (want[0] is g) == (not moving)
    np.testing.assert_allclose(got[0].lo, want[0].lo, rtol=1e-12)
    np.testing.assert_allclose(got[0].hi, want[0].hi, rtol=1e-12)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-10, atol=1e-12 * np.abs(want[1]).max())
    np.testing.assert_allclose(got[2:], want[2:], rtol=1e-9, atol=1e-15)
    assert got[0].W0 @ got[1] == pytest.approx(1.0)


def test_diffusion_reuses_a_nearby_factorisation_and_keeps_mean_and_covariance_growth():
    """A grid whose elements are 10 % larger re-uses the kept factorisation (a W-method: its C = τQ/h² is
    within _REUSE of the kept one's); one 1.5 x larger (C/2.25) does not.  Either way the diffusion adds Q·duration to the covariance and keeps the mean (the
    Galerkin moments of the stages do not depend on the stage matrix), and the re-used factorisation's
    density differs from an exact one's by far less than the diffusion changes it."""
    model = linear_sde_model(np.zeros((2, 2)), np.array([[0.02, 0.005], [0.005, 0.01]]), np.eye(2), np.eye(2), 1.0)
    m, P = np.array([0.3, -0.2]), np.array([[0.04, 0.01], [0.01, 0.03]])
    scheme = _fem_schemes._Characteristics(model, None, 4.0, 4, False, (20, 20))
    g0 = FEMGrid(m - 1.0, m + 1.0, 20, 20)
    scheme.diffuse(g0, _density(g0, m, P), 0.125)
    assert scheme.factorisations == 1
    for grow, factorisations in ((1.1, 1), (1.5, 2)):
        g = FEMGrid(m - grow, m + grow, 20, 20)
        p = _density(g, m, P)
        q, clipped = scheme.diffuse(g, p, 0.125)
        assert scheme.factorisations == factorisations
        mass, mean, cov = g.moments(q)
        assert clipped < 1e-6 and mass == pytest.approx(1.0)
        np.testing.assert_allclose(mean, g.moments(p)[1], atol=1e-6)      # single-precision solves
        np.testing.assert_allclose(cov, g.moments(p)[2] + 0.125 * model.Q, atol=1e-6)
        exact = _fem_schemes._Characteristics(model, None, 4.0, 4, False, (20, 20)).diffuse(g, p, 0.125)[0]
        change = np.abs(exact - p).max()
        assert np.abs(q - exact).max() < (0.02 if factorisations == 1 else 1e-6) * change


def test_lattice_modes_equal_scipy_labels():
    """The compiled mode finder against scipy.ndimage.label (8-connected) on the lattice image of random
    blobs, with the same raster-order labels and per-region weighted sums."""
    import scipy.ndimage

    g = FEMGrid([0.0, 0.0], [1.0, 1.0], 12, 9)
    lattice = g._top["lattice"]
    rng = np.random.default_rng(11)
    for _ in range(5):
        d = np.zeros(g.size)
        for c in rng.uniform(0.0, 1.0, (4, 2)):
            d += rng.uniform(0.5, 2.0) * np.exp(-0.5 * np.sum((g.nodes - c) ** 2, axis=1) / 0.004)
        count, stats = _fem_kernels.lattice_modes(d, lattice, 25, 19, 0.05)
        img = np.zeros((25, 19))
        img[lattice[:, 0], lattice[:, 1]] = d
        img[1::2, 1::2] = 0.25 * (img[:-1:2, 1::2] + img[2::2, 1::2] + img[1::2, :-1:2] + img[1::2, 2::2])
        labels, n = scipy.ndimage.label(img > 0.05 * img.max(), structure=np.ones((3, 3)))
        assert count == n and n >= 2
        ii, jj = np.nonzero(labels)
        lab, w = labels[ii, jj] - 1, img[ii, jj]
        want = np.stack([np.bincount(lab, weights=w * f, minlength=n) for f in (1, ii, jj, ii * ii, jj * jj)], axis=1)
        np.testing.assert_allclose(stats, want, rtol=1e-12)


@pytest.mark.parametrize("scale, fixed", [(0.01, False), (1.0, False), (0.01, True)])
def test_compiled_dt_equals_its_steps(scale, fixed):
    """predict_dt (one compiled call per dt) against the same steps called one by one from Python, on
    the same factorisation cache: grid, density, lost and clipped mass, factorisations."""
    model = zhao2013_model(variant="vdp", diffusion_scale=scale)
    g = FEMGrid([-1.5, 0.5], [2.5, 3.5], 20, 20)
    p = _density(g, np.array([0.4, 2.0]), np.array([[0.3, 0.1], [0.1, 0.2]]))
    whole, steps = (_fem_schemes._Characteristics(model, None, 4.0, 4, fixed, (20, 20)) for _ in range(2))
    for _ in range(3):                                    # the kept factorisations carry over between dts
        got, want = whole.predict(g, p), steps.predict_steps(g, p)
        assert (got[0] is g) == fixed and got[2:4] == want[2:4]
        np.testing.assert_allclose(got[0].lo, want[0].lo, rtol=1e-14)
        np.testing.assert_allclose(got[0].hi, want[0].hi, rtol=1e-14)
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12, atol=1e-14 * np.abs(want[1]).max())
        np.testing.assert_allclose(got[4:], want[4:], rtol=1e-12, atol=1e-16)
        g, p = got[:2]
    assert whole.factorisations == steps.factorisations >= 1
