"""The FEM grid filter: shape functions, conservation, agreement with the Kalman filter, bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.continuous import FEMGrid, fem_filter, fem_steps, linear_sde_model, shape_functions, simulate_sde
from mptrack.continuous._fem_grid import _nodal_derivatives
from mptrack.errors import NotPositiveDefiniteError, ParameterError, ShapeError
from mptrack.linear import kalman_filter

A = np.array([[0.0, 1.0], [-1.0, -0.5]])
Q = np.diag([0.1, 0.2])
X0, P0 = np.array([1.0, 0.0]), 0.3 * np.eye(2)


@pytest.fixture(scope="module")
def linear_case():
    model = linear_sde_model(A, Q, np.eye(2), 0.5 * np.eye(2), 1.0)
    _, z = simulate_sde(model, 12, np.random.default_rng(1), X0)
    return model, z, kalman_filter(model.to_linear_gaussian(), z, X0, P0)


def test_shape_functions_are_nodal_and_partition_unity():
    xi = np.array([-1, 1, 1, -1, 0, 1, 0, -1.0])
    eta = np.array([-1, -1, 1, 1, -1, 0, 1, 0.0])
    N, dx, dy = shape_functions(xi, eta)
    np.testing.assert_allclose(N, np.eye(8), atol=1e-15)
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 2))
    N, dx, dy = shape_functions(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(N.sum(1), 1.0)
    np.testing.assert_allclose(dx.sum(1), 0.0, atol=1e-13)
    e = 1e-6
    num = (shape_functions(pts[:, 0] + e, pts[:, 1])[0] - shape_functions(pts[:, 0] - e, pts[:, 1])[0]) / (2 * e)
    np.testing.assert_allclose(num, dx, atol=1e-8)
    num = (shape_functions(pts[:, 0], pts[:, 1] + e)[0] - shape_functions(pts[:, 0], pts[:, 1] - e)[0]) / (2 * e)
    np.testing.assert_allclose(num, dy, atol=1e-8)


def test_grid_integrates_quadratics_exactly():
    g = FEMGrid([-1.0, -2.0], [3.0, 1.0], 5, 4)
    x, y = g.nodes[:, 0], g.nodes[:, 1]
    assert g.size == 11 * 9 - 20
    # ∫ 1, ∫ x, ∫ x y over [-1,3]x[-2,1]: 12, 12, 12*... exact for the serendipity space
    assert g.W0 @ np.ones(g.size) == pytest.approx(12.0)
    assert g.W0 @ x == pytest.approx(3 * (9 - 1) / 2 * 1)
    assert g.W0 @ (x * y) == pytest.approx((9 - 1) / 2 * (1 - 4) / 2)
    assert g.W0 @ (x * x * y) == pytest.approx((27 + 1) / 3 * (1 - 4) / 2)
    # interpolant reproduces a quadratic anywhere inside, zero outside
    pts = np.array([[0.3, -0.7], [2.9, 0.9], [5.0, 0.0]])
    q = lambda P: 1 + P[..., 0] - 2 * P[..., 1] + P[..., 0] * P[..., 1] + P[..., 0] ** 2  # noqa: E731
    np.testing.assert_allclose(g.evaluate(q(g.nodes), pts), [q(pts[0]), q(pts[1]), 0.0])


def test_operator_conserves_mass():
    model = linear_sde_model(A, Q, np.eye(2), np.eye(2), 1.0)
    g = FEMGrid([-4.0, -4.0], [4.0, 4.0], 6, 6)
    M, Aop = g.operators(model)
    ones = np.ones(g.size)
    np.testing.assert_allclose(ones @ Aop.toarray(), 0.0, atol=1e-12)
    np.testing.assert_allclose(ones @ M.toarray(), g.W0, atol=1e-12)


def test_mass_and_nonnegativity_after_prediction_and_update(linear_case):
    model, z, _ = linear_case
    for step in fem_steps(model, z, X0, P0, grid=(12, 12)):
        for mix in (step.prior, step.posterior):
            assert sum(w for w, _ in mix.parts) == pytest.approx(1.0, rel=1e-12)
            for _, dens in mix.parts:
                assert np.all(dens.p >= 0)
                assert dens.grid.W0 @ dens.p == pytest.approx(1.0, rel=1e-12)
        assert 0 <= step.clipped < 0.05


@pytest.mark.parametrize("scheme", ["sdirk2", "cn", "characteristics"])
def test_fem_matches_kalman_on_linear_model(linear_case, scheme):
    model, z, kf = linear_case
    fe = fem_filter(model, z, X0, P0, grid=(24, 24), substeps=16, scheme=scheme, splits=8)
    assert fe.method == "FEM"
    np.testing.assert_allclose(fe.x, kf.x, atol=2e-3)
    np.testing.assert_allclose(fe.P, kf.P, atol=2e-3)
    np.testing.assert_allclose(fe.x_pred, kf.x_pred, atol=2e-3)
    assert fe.loglik == pytest.approx(kf.loglik, abs=0.05)


@pytest.mark.parametrize("scheme", ["sdirk2", "characteristics"])
def test_fem_error_falls_with_grid_refinement(linear_case, scheme):
    """Observed spatial order (fine time steps, 8 Strang splits per dt) is reported and is at least 2."""
    model, z, kf = linear_case
    sizes = (8, 16, 32)
    err = [np.abs(fem_filter(model, z, X0, P0, grid=(n, n), substeps=32, scheme=scheme, splits=8).x - kf.x).max()
           for n in sizes]
    order = -np.polyfit(np.log(sizes), np.log(err), 1)[0]
    print(f"FEM ({scheme}) vs KF max mean error {err}, observed order {order:.2f}")
    assert err[0] > err[1] > err[2]
    assert order > 2.0


def test_characteristics_splitting_error_is_second_order(linear_case):
    """Strang splitting: the error against the KF falls like tau^2 with the splits per dt (32 x 32 grid)."""
    model, z, kf = linear_case
    splits = (1, 2, 4, 8)
    err = [np.abs(fem_filter(model, z, X0, P0, grid=(32, 32), substeps=32, splits=n).x - kf.x).max()
           for n in splits]
    order = -np.polyfit(np.log(splits), np.log(err), 1)[0]
    print(f"characteristics vs KF max mean error {err}, observed order in splits {order:.2f}")
    assert np.all(np.diff(err) < 0) and 1.7 < order < 2.6


def test_paper_scheme_converges_to_the_kalman_filter_with_order_two(linear_case):
    """The paper's nodal strong form + corrected RK4 (scheme="paper"): error against the exact KF
    falls with the grid at an observed order of about 2 (measured 2.2 on 12..32; Galerkin: 3.4)."""
    model, z, kf = linear_case
    sizes = (12, 16, 24, 32)
    err = [np.abs(fem_filter(model, z, X0, P0, grid=(n, n), scheme="paper").x - kf.x).max() for n in sizes]
    order = -np.polyfit(np.log(sizes), np.log(err), 1)[0]
    print(f"paper scheme vs KF max mean error {err}, observed order {order:.2f}")
    assert np.all(np.diff(err) < 0) and err[-1] < 6e-3
    assert 1.8 < order < 2.7


def test_nodal_differences_are_exact_on_quadratics_and_the_laplacian_is_dissipative():
    g = FEMGrid([-1.0, -2.0], [3.0, 1.0], 6, 5)
    x, y = g.nodes.T
    Du, Dv, Duu, Duv, Dvv, inner = _nodal_derivatives(6, 5)
    (h1, h2), q = g._h, 1 + x - 2 * y + 3 * x * y + x**2 - 0.5 * y**2
    for D, scale, exact in ((Du, h1, 1 + 3 * y + 2 * x), (Dv, h2, -2 + 3 * x - y), (Duu, h1 * h1, 2.0),
                            (Duv, h1 * h2, 3.0), (Dvv, h2 * h2, -1.0)):
        np.testing.assert_allclose((D @ q)[inner] / scale, np.broadcast_to(exact, q.shape)[inner], atol=1e-11)
        assert not np.any((D @ q)[~inner])  # p = 0 on the boundary: no rows there
    for D in (Duu, Dvv):  # symmetric three-point second differences: no growing (anti-diffusive) mode
        block = D.toarray()[np.ix_(inner, inner)]
        np.testing.assert_allclose(block, block.T)
        assert np.linalg.eigvalsh(block).max() < 1e-12


def test_paper_scheme_takes_enough_rk4_steps_to_be_stable(linear_case):
    """Explicit RK4: dt·rho(L)/substeps stays inside the stability half-disc (radius 2.5 < 2.6)."""
    from mptrack.continuous._fem_schemes import _NodalRK4

    model, _, _ = linear_case
    g = FEMGrid([-4.0, -4.0], [4.0, 4.0], 32, 32)
    prop = _NodalRK4(g, model, 1)
    L = g.nodal_operator(model).toarray()
    assert np.abs(np.linalg.eigvals(L)).max() * prop.tau <= 2.5
    assert prop.substeps > 16  # one RK4 step per dt (eq. 20 as printed) would be unstable here


def test_fixed_box_must_cover_the_prior(linear_case):
    model, z, _ = linear_case
    with pytest.raises(ParameterError, match="box"):
        fem_filter(model, z, X0, P0, box=((0.5, -1.0), (3.0, 1.0)))
    res = fem_filter(model, z[:3], X0, P0, grid=(10, 10), box=((-5.0, -5.0), (5.0, 5.0)))
    assert res.x.shape == (3, 2)


def test_nan_measurement_only_predicts(linear_case):
    model, z, _ = linear_case
    z = z.copy()
    z[2] = np.nan
    steps = list(fem_steps(model, z[:4], X0, P0, grid=(12, 12)))
    np.testing.assert_allclose(steps[2].x, steps[2].x_pred)
    assert steps[2].loglik == 0.0


def test_bad_input(linear_case):
    model, z, _ = linear_case
    with pytest.raises(NotPositiveDefiniteError, match="P0"):
        fem_filter(model, z, X0, np.diag([1.0, -1.0]))
    with pytest.raises(ShapeError, match="z"):
        fem_filter(model, z[:, :1], X0, P0)
    with pytest.raises(ParameterError, match="scheme"):
        fem_filter(model, z, X0, P0, scheme="rk4")
    with pytest.raises(ParameterError, match="hi"):
        FEMGrid([0.0, 0.0], [0.0, 1.0], 2, 2)
    three = linear_sde_model(np.eye(3), np.eye(3), np.eye(3), np.eye(3), 1.0)
    with pytest.raises(ShapeError, match="2-D"):
        fem_filter(three, np.zeros((2, 3)), np.zeros(3), np.eye(3))


@settings(max_examples=15, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(0.2, 2.0))
def test_interpolated_gaussian_moments(mx, my, s):
    g = FEMGrid([mx - 6 * s, my - 6 * s], [mx + 6 * s, my + 6 * s], 24, 24)
    p = np.exp(-0.5 * np.sum((g.nodes - [mx, my]) ** 2, axis=1) / s**2)
    mass, mean, cov = g.moments(p)
    np.testing.assert_allclose(mean, [mx, my], atol=1e-3 * s)
    np.testing.assert_allclose(cov, s * s * np.eye(2), atol=1e-3 * s * s)


@pytest.mark.parametrize("n", [6, 30])
def test_band_and_sparse_factorisations_solve_the_assembled_system(n, monkeypatch):
    """The band LU (small grids) and SuperLU (large grids) both solve (M − γτA) x = b."""
    import scipy.sparse.linalg

    from mptrack.continuous import _fem_schemes

    model = linear_sde_model(A, Q, np.eye(2), np.eye(2), 1.0)
    g = FEMGrid([-4.0, -3.0], [4.0, 5.0], n, n)
    Me, Ae = g.element_matrices(model)
    Be = Me - 0.3 * Ae
    b = np.random.default_rng(n).standard_normal(g.size)
    expected = scipy.sparse.linalg.spsolve(g.assemble(Be), b)
    for dtype, tol in ((np.float64, 1e-10), (np.float32, 1e-5)):
        monkeypatch.setattr(_fem_schemes, "_SOLVE_DTYPE", dtype)
        for limit in (0, 2**40):  # force SuperLU, then the band LU
            monkeypatch.setattr(_fem_schemes, "_BAND_BYTES", limit)
            x = _fem_schemes._factorise(g, Be)[0](b.copy())
            assert x.dtype == np.float64
            np.testing.assert_allclose(x, expected, rtol=0, atol=tol * np.abs(expected).max())


@pytest.mark.parametrize("scheme", ["sdirk2", "cn"])
def test_compiled_band_steps_equal_the_sparse_loop(scheme, monkeypatch):
    """The compiled sub-steps on the band LU and the Python loop on SuperLU give the same prediction."""
    from mptrack.continuous import _fem_schemes

    monkeypatch.setattr(_fem_schemes, "_SOLVE_DTYPE", np.float64)
    model = linear_sde_model(A, Q, np.eye(2), np.eye(2), 1.0)
    g = FEMGrid([-4.0, -3.0], [4.0, 5.0], 10, 12)
    p = np.exp(-0.5 * np.sum((g.nodes - [0.5, 1.0]) ** 2, axis=1))
    band = _fem_schemes._Propagator(g, model, 6, scheme, False)
    assert band.band is not None
    monkeypatch.setattr(_fem_schemes, "_BAND_BYTES", 0)
    sparse = _fem_schemes._Propagator(g, model, 6, scheme, False)
    assert sparse.band is None
    np.testing.assert_allclose(band(p), sparse(p), rtol=0, atol=1e-12 * p.max())
    assert g.W0 @ band(p) == pytest.approx(g.W0 @ p, rel=1e-12)


def test_single_precision_solves_change_the_filter_by_far_less_than_its_discretisation_error(linear_case,
                                                                                             monkeypatch):
    from mptrack.continuous import _fem_schemes

    model, z, kf = linear_case
    single = fem_filter(model, z, X0, P0, grid=(24, 24))
    monkeypatch.setattr(_fem_schemes, "_SOLVE_DTYPE", np.float64)
    double = fem_filter(model, z, X0, P0, grid=(24, 24))
    rounding = np.abs(single.x - double.x).max()
    discretisation = np.abs(double.x - kf.x).max()
    print(f"single vs double {rounding:.1e}, double vs KF {discretisation:.1e}")
    assert rounding < 0.01 * discretisation


def test_moment_weights_are_exact_integrals():
    """W1, W2 (mapped from element units) equal direct quadrature of x φ_j and x xᵀ φ_j."""
    g = FEMGrid([-1.5, 2.0], [2.5, 3.5], 4, 3)
    rng = np.random.default_rng(3)
    p = rng.random(g.size)
    # the interpolant of p·(1, x, x², x y, y²) is not p times those, so compare against a fine Riemann sum
    u = np.linspace(0, 1, 801)[1:] - 1 / 1600
    X, Y = np.meshgrid(-1.5 + 4 * u, 2.0 + 1.5 * u, indexing="ij")
    pts = np.stack([X, Y], axis=-1)
    dens = g.evaluate(p, pts)
    area = 4 * 1.5 / dens.size
    for weights, fn in ((g.W0, 1.0), (g.W1[:, 0], X), (g.W1[:, 1], Y), (g.W2[:, 0], X * X), (g.W2[:, 1], X * Y),
                        (g.W2[:, 2], Y * Y)):
        assert weights @ p == pytest.approx(np.sum(dens * fn) * area, rel=1e-5)
    mass, mean, cov = g.moments(p)
    assert mass == pytest.approx(g.W0 @ p)
    np.testing.assert_allclose(mean, g.W1.T @ p / mass, rtol=1e-12)
    s = g.W2.T @ p / mass
    np.testing.assert_allclose(cov, [[s[0] - mean[0] ** 2, s[1] - mean[0] * mean[1]],
                                     [s[1] - mean[0] * mean[1], s[2] - mean[1] ** 2]], atol=1e-12)


@pytest.mark.parametrize("scheme", ["sdirk2", "characteristics"])
def test_a_moving_grid_refactorises_only_when_it_moves(linear_case, scheme):
    model, z, _ = linear_case
    steps = list(fem_steps(model, z, X0, P0, grid=(12, 12), scheme=scheme))
    assert steps[0].factorised
    if scheme == "sdirk2":
        assert [s.factorised for s in steps[1:]] == [s.regridded for s in steps[1:]]
    else:  # the grid follows the density every split; the diffusion LU is kept while the elements keep their size
        assert all(s.regridded for s in steps) and not all(s.factorised for s in steps[1:])
    fixed = list(fem_steps(model, z, X0, P0, grid=(12, 12), scheme=scheme, box=((-5.0, -5.0), (5.0, 5.0))))
    assert [s.factorised for s in fixed] == [True] + [False] * (len(z) - 1)


def test_default_substeps_follow_the_grid():
    from mptrack.continuous._fem_schemes import default_substeps

    assert default_substeps((20, 20)) == 16
    assert default_substeps((40, 10)) == 32
    assert default_substeps((2, 2)) == 8


def test_grid_must_be_two_counts(linear_case):
    model, z, _ = linear_case
    with pytest.raises(ShapeError, match="grid"):
        fem_filter(model, z, X0, P0, grid=(10, 10, 10))


def test_deposit_is_the_transpose_of_interpolation():
    """deposit (Σ w φ_j(Y)) and evaluate (Σ p_j φ_j(Y)) use the same shape functions: bᵀp = Σ w p(Y)."""
    from mptrack.continuous._fem_kernels import deposit

    g = FEMGrid([-1.0, -2.0], [3.0, 1.0], 5, 4)
    rng = np.random.default_rng(4)
    Y = rng.uniform([-1.5, -2.5], [3.5, 1.5], (500, 2))
    Y[0] = np.nan
    w, p = rng.random(500), rng.standard_normal(g.size)
    b = np.zeros(g.size)
    outside = deposit(Y, w, g.lo, g._h, g.n1, g.n2, g.conn, b)
    inside = np.all((Y >= g.lo) & (Y <= g.hi), axis=1)
    assert outside == pytest.approx(w[~inside].sum())
    assert b @ p == pytest.approx(w @ g.evaluate(p, np.nan_to_num(Y, nan=1e9)))
    assert b.sum() == pytest.approx(w[inside].sum())  # Σφ = 1


def test_compiled_flow_equals_the_numpy_rk4_flow():
    from mptrack.continuous import zhao2013_model
    from mptrack.continuous._fem_schemes import _compiled
    from mptrack.continuous._model import rk4_flow

    model = zhao2013_model(variant="vdp", diffusion_scale=1.0)  # max_increment = 1: some steps are capped
    X = np.random.default_rng(5).uniform(-12, 12, (700, 2))
    np.testing.assert_allclose(_compiled(model).flow(X, 0.25, 3), rk4_flow(model, X, 0.25, 3), rtol=1e-12,
                               atol=1e-12)


def test_transport_keeps_mass_mean_and_covariance_of_a_density_contracted_below_the_element_size():
    """The transport is the Galerkin projection of the pushed-forward density, and the serendipity
    space holds 1, x and x xᵀ: mass, mean and covariance of the transported density are exact
    (to quadrature) even when a stiff drift squeezes it into a ridge 0.02 wide across elements
    0.25 high, which sampling the density at the nodes misses (the FE failures at Q x 1)."""
    import scipy.linalg

    from mptrack.continuous._fem_schemes import _push

    A_stiff = np.array([[0.0, 1.0], [20.0, -20.0]])       # x2 relaxes onto the line x2 = x1 at rate 20
    model = linear_sde_model(A_stiff, np.diag([0.5, 0.2]), np.eye(2), np.eye(2), 1.0)
    m, P = np.array([0.5, -1.0]), np.diag([1.0, 1.0])
    old = FEMGrid(m - 5.0, m + 5.0, 20, 20)
    p = np.exp(-0.5 * np.sum((old.nodes - m) ** 2, axis=1))
    p /= old.W0 @ p
    F = scipy.linalg.expm(0.25 * A_stiff)
    new = FEMGrid([-7.0, -7.0], [7.0, 7.0], 20, 40)
    q, outside = _push(old, p, new, model, 0.25)
    mass, mean, cov = new.moments(q)
    assert outside < 1e-6 and mass == pytest.approx(1.0 - outside, abs=1e-9)
    np.testing.assert_allclose(mean, F @ m, atol=5e-4)  # the RK4 flow (hλ ≤ 1) is off by 1e-4
    np.testing.assert_allclose(cov, F @ P @ F.T, atol=2e-3)
    ridge = np.sqrt(np.linalg.eigvalsh(F @ P @ F.T).min())
    assert ridge < 0.1 * new._h[1]


def _abs_x1_model(Qs):
    """Zero drift, measurement |x1| (σ = 0.05): a wide prior across x1 = 0 gives two separate modes."""
    from mptrack.continuous import ContinuousDiscreteModel

    return ContinuousDiscreteModel(lambda X: np.zeros_like(X), np.diag(Qs), lambda X: np.abs(X[..., :1]),
                                   [[0.0025]], 1.0)


def test_separate_modes_get_their_own_grids_and_match_brute_force_bayes():
    """One measurement of |x1| = 3 on the prior N(0, diag(9, 0.1)) + Q·dt: the posterior has two modes
    0.05 wide, 6 apart.  Each gets its own grid; the mixture's moments match prior × likelihood
    integrated on a fine lattice (with one 20 × 20 grid over both the nodes are 0.7 apart)."""
    model = _abs_x1_model([1.0, 0.1])
    x0, P0s = np.zeros(2), np.diag([9.0, 0.1])
    z = np.array([[3.0]])
    step = next(fem_steps(model, z, x0, P0s, grid=(20, 20)))
    assert len(step.posterior.parts) == 2
    assert [w for w, _ in step.posterior.parts] == pytest.approx([0.5, 0.5], abs=0.02)
    Pp = P0s + model.Q                                   # the exact prior (zero drift)
    u = np.linspace(-16, 16, 6401)
    v = np.linspace(-3, 3, 601)
    X1, X2 = np.meshgrid(u, v, indexing="ij")
    w = np.exp(-0.5 * (X1**2 / Pp[0, 0] + X2**2 / Pp[1, 1]) - 0.5 * (np.abs(X1) - 3.0) ** 2 / 0.0025)
    w /= w.sum()
    mean = [np.sum(w * X1), np.sum(w * X2)]
    var = [np.sum(w * (X1 - mean[0]) ** 2), np.sum(w * (X2 - mean[1]) ** 2)]
    np.testing.assert_allclose(step.x, mean, atol=0.02)
    np.testing.assert_allclose(np.diag(step.P), var, rtol=0.01)


def test_modes_that_meet_again_share_one_grid():
    """After the split above, no further measurement: diffusion (Q11 = 4) merges the two parts' grids."""
    model = _abs_x1_model([4.0, 0.1])
    z = np.array([[3.0], [np.nan], [np.nan], [np.nan]])
    parts = [len(s.posterior.parts) for s in fem_steps(model, z, np.zeros(2), np.diag([9.0, 0.1]), grid=(20, 20))]
    assert parts[0] == 2 and parts[-1] == 1


def test_a_coarse_grid_with_moments_off_the_psd_cone_still_places_its_next_grid():
    """On a 6 x 6 grid the posterior's moments (a density with clipped negative lobes) need not be PSD;
    placing the next grid drew sigma points of them and failed ("P: must be positive semi-definite,
    smallest eigenvalue -61.5", found by the hardening harness); they are projected as the box of the
    prior's grid already was."""
    from mptrack.continuous import ZHAO2013_X0, zhao2013_model
    model = zhao2013_model(variant="vdp", diffusion_scale=0.01)
    _, z = simulate_sde(model, 3, np.random.default_rng(1), ZHAO2013_X0)
    result = fem_filter(model, z[:2], ZHAO2013_X0, np.eye(2), grid=(6, 6))
    assert np.isfinite(result.x).all() and np.isfinite(result.P).all()
