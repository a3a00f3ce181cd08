"""The compiled particle-filter path against its NumPy oracle, the sub-step schemes, reproducibility."""

import numba
import numpy as np
import pytest
from scipy.linalg import expm

from mptrack.continuous import (
    BlockKernels,
    ContinuousDiscreteModel,
    linear_sde_model,
    pf_substep_study,
    pf_substeps,
    reference_filter,
    simulate_sde,
    zhao2013_model,
)
from mptrack.continuous import _kernels as kern
from mptrack.errors import ParameterError
from mptrack.nonlinear import _pf_kernels as pfk
from mptrack.nonlinear import particle_filter, systematic_resample

X0, P0 = np.array([-0.6, -1.0]), 0.1 * np.eye(2)
A_LIN = [[0.0, 1.0], [-1.0, -0.5]]

MODELS = {
    **{f"{v}-{b}": (lambda v=v, b=b: zhao2013_model(variant=v, bearing=b, diffusion_scale=0.1))
       for v in ("vdp", "printed") for b in ("atan2", "atan")},
    "linear": lambda: linear_sde_model(A_LIN, [[0.1, 0.02], [0.02, 0.2]], [[1.0, 0.5], [0.0, 1.0], [1.0, 1.0]],
                                       np.diag([0.5, 0.4, 0.3]), 0.5),
}


@pytest.fixture(params=sorted(MODELS))
def model(request):
    return MODELS[request.param]()


def _points(n, count=300, scale=2.0, seed=0):
    """A cloud of points, more than one block and not a multiple of the block size."""
    return scale * np.random.default_rng(seed).standard_normal((count, n))


def test_block_kernels_equal_the_numpy_model(model):
    X = _points(model.n)
    kn = model.kernels
    f, h = np.empty((model.n, len(X))), np.empty((model.m, len(X)))
    kn.drift(np.ascontiguousarray(X.T), kn.drift_params, f)
    kn.measurement(np.ascontiguousarray(X.T), kn.measurement_params, h)
    np.testing.assert_allclose(f.T, model.drift(X), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(h.T, model.measurement(X), rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("scheme", ["heun", "rk4-split"])
@pytest.mark.parametrize("scale", [1.0, 6.0])  # 6: many increments capped (taming active)
def test_compiled_propagation_equals_numpy(model, scheme, scale):
    X = _points(model.n, scale=scale)
    a_rng, b_rng = np.random.default_rng(3), np.random.default_rng(3)
    a = model.sample_transition(X, a_rng, 3, scheme)
    b = kern.CompiledModel(model).propagate(X.copy(), b_rng, 3, scheme)
    np.testing.assert_allclose(b, a, rtol=1e-13, atol=1e-13)
    assert a_rng.random() == b_rng.random()  # the same draws were consumed
    if scale > 1 and model.linear is None:  # the cap was active: uncapped steps would differ
        assert np.abs(b - X).max() > 1


def test_propagation_uses_numpys_normals():
    """numba's Generator.standard_normal is NumPy's ziggurat: one sub-step equals the formula with
    NumPy's own draws (sub-step, particle, component order)."""
    model = linear_sde_model(np.zeros((2, 2)), np.diag([4.0, 1.0]), np.eye(2), np.eye(2), 1.0)
    X = _points(2, count=5)
    out = kern.CompiledModel(model).propagate(X.copy(), np.random.default_rng(9), 1, "rk4-split")
    Z = np.random.default_rng(9).standard_normal((5, 2))
    L = model.noise_factor()  # eigen-factor of diag(4, 1): a scaled permutation, so Z @ L.T is exact
    np.testing.assert_array_equal(out, X + Z @ L.T)


def test_compiled_log_likelihood_equals_numpy(model):
    X = _points(model.n)
    cm = kern.CompiledModel(model)
    z = model.measurement(X[:1])[0] + 0.3
    z[-1] += 7.0  # an angle innovation that must be wrapped (or a plain one)
    np.testing.assert_allclose(cm.log_likelihood(z, X), model.log_likelihood(z, X), rtol=1e-12)
    z[0] = np.nan
    np.testing.assert_allclose(cm.log_likelihood(z, X), model.log_likelihood(z, X), rtol=1e-12)


def test_weighting_moments_and_resampling_equal_numpy_oracles():
    rng = np.random.default_rng(4)
    X = rng.standard_normal((1001, 3))
    logw = np.log(rng.random(1001))
    logw -= np.log(np.exp(logw).sum())
    ll = -rng.random(1001) * 50
    lw, w = logw.copy(), np.exp(logw)
    inc = pfk.reweight(lw, w, ll)
    a = logw + ll
    total = a.max() + np.log(np.exp(a - a.max()).sum())
    assert inc == pytest.approx(total, abs=1e-12)
    np.testing.assert_allclose(lw, a - total, atol=1e-12)
    np.testing.assert_allclose(w, np.exp(a - total), rtol=1e-12)
    m, P, ess = pfk.weighted_moments(X, w)
    np.testing.assert_allclose(m, w @ X, atol=1e-14)
    np.testing.assert_allclose(P, ((X - m).T * w) @ (X - m), atol=1e-14)
    assert ess == pytest.approx(1 / np.sum(w * w), rel=1e-12)
    assert pfk.reweight(lw.copy(), w.copy(), np.full(1001, -np.inf)) == -np.inf
    for u in (0.0, 0.37, 1 - 1e-12):
        w0 = w.copy()
        w0[::7] = 0.0
        w0 /= w0.sum()
        want = _systematic_oracle(w0, u)
        np.testing.assert_array_equal(pfk.systematic_indices(w0, u), want)
        assert not np.isin(np.flatnonzero(w0 == 0), want[want < len(w0) - 1]).any()
    np.testing.assert_array_equal(pfk.resample(X, w, 0.37), X[pfk.systematic_indices(w, 0.37)])
    np.testing.assert_array_equal(systematic_resample(w, np.random.default_rng(1)),
                                  pfk.systematic_indices(w, np.random.default_rng(1).random()))


def _systematic_oracle(w, u):
    """np.searchsorted on the running sum (capped at 1, last = 1), index capped at N - 1."""
    cdf = np.minimum(np.cumsum(w), 1.0)
    cdf[-1] = 1.0
    return np.minimum(np.searchsorted(cdf, (u + np.arange(len(w))) / len(w), side="right"), len(w) - 1)


def test_systematic_indices_match_searchsorted_on_random_and_tied_weights():
    rng = np.random.default_rng(11)
    for trial in range(300):
        N = int(rng.integers(1, 3000))
        w = rng.random(N) ** 8
        if trial % 3 == 0:
            w[rng.random(N) < 0.5] = 0.0
        w[0] += 1e-300
        w /= w.sum()
        u = (0.0, rng.random(), 1 - 1e-16)[trial % 3]
        np.testing.assert_array_equal(pfk.systematic_indices(w, u), _systematic_oracle(w, u))
    for N in (3, 10, 1000, 4096):  # equal weights: with u = 0 every t_i lies on a cdf step (ties)
        w = np.full(N, 1.0 / N)
        np.testing.assert_array_equal(pfk.systematic_indices(w, 0.0), _systematic_oracle(w, 0.0))
        np.testing.assert_array_equal(pfk.systematic_indices(w, 0.5), np.arange(N))  # one copy of each


@pytest.mark.parametrize("scheme", ["heun", "rk4-split"])
@pytest.mark.parametrize("regularise", [False, True])
def test_compiled_pf_equals_numpy_pf(model, scheme, regularise):
    _, z = simulate_sde(model, 8, np.random.default_rng(5), np.zeros(model.n) + 0.5)
    z[3, 0] = np.nan
    x0, P0_ = np.zeros(model.n) + 0.5, 0.1 * np.eye(model.n)
    kw = dict(particles=300, scheme=scheme, regularise=regularise, substeps=2)
    a = particle_filter(model, z, x0, P0_, np.random.default_rng(6), compiled=True, **kw)
    b = particle_filter(model, z, x0, P0_, np.random.default_rng(6), compiled=False, **kw)
    for name in ("x", "P", "x_pred", "P_pred"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-9)
    assert a.loglik == pytest.approx(b.loglik, abs=1e-9)


def test_user_model_without_kernels_gives_the_same_filter():
    """Plain NumPy callables (no kernels) run the NumPy path; same numbers as the compiled model."""
    named = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    plain = ContinuousDiscreteModel(named.drift, named.Q, named.measurement, named.R, named.dt,
                                    periods=named.periods)
    assert plain.kernels is None
    _, z = simulate_sde(named, 6, np.random.default_rng(7), X0)
    a = particle_filter(named, z, X0, P0, np.random.default_rng(8), particles=500)
    b = particle_filter(plain, z, X0, P0, np.random.default_rng(8), particles=500)
    np.testing.assert_allclose(a.x, b.x, atol=1e-9)
    with pytest.raises(ParameterError, match="compiled"):
        particle_filter(plain, z, X0, P0, np.random.default_rng(8), compiled=True)
    with pytest.raises(ParameterError, match="kernels"):
        kern.CompiledModel(plain)


def test_seeded_reproducibility_and_thread_independence():
    model = zhao2013_model(variant="vdp", diffusion_scale=0.01)
    _, z = simulate_sde(model, 10, np.random.default_rng(2), X0)
    a = particle_filter(model, z, X0, P0, np.random.default_rng(1), particles=2000)
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        b = particle_filter(model, z, X0, P0, np.random.default_rng(1), particles=2000)
    finally:
        numba.set_num_threads(previous)
    c = particle_filter(model, z, X0, P0, np.random.default_rng(2), particles=2000)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    assert a.loglik == b.loglik
    assert np.abs(a.x - c.x).max() > 1e-6


@pytest.mark.parametrize("scheme, order", [("heun", 2), ("rk4-split", 4)])
def test_deterministic_order_of_the_schemes(scheme, order):
    """Q = 0: the schemes integrate ẋ = A x; halving the step divides the error by 2^order."""
    model = linear_sde_model(A_LIN, np.zeros((2, 2)), np.eye(2), np.eye(2), 1.0)
    x = np.array([[1.0, 0.0]])
    exact = x @ expm(np.array(A_LIN)).T
    err = [np.abs(model.sample_transition(x, np.random.default_rng(0), s, scheme) - exact).max()
           for s in (2, 4)]
    assert err[0] / err[1] == pytest.approx(2.0 ** order, rel=0.25)


def test_split_scheme_covariance_is_second_order():
    """Linear SDE: one split sub-step is x -> M (M x + ΔW), M the RK4 map of h/2 (the Taylor polynomial
    of e^{Ah/2} to 4th order), so its covariance after dt follows exactly; it approaches the exact
    Van Loan covariance with error O(h²) (the midpoint rule for the noise integral)."""
    A = np.array(A_LIN)
    Q = np.array([[0.1, 0.02], [0.02, 0.2]])
    Qd = linear_sde_model(A, Q, np.eye(2), np.eye(2), 1.0).to_linear_gaussian().Q
    x = np.array([[0.01, 0.02]])
    errs = []
    for s in (2, 4, 8):
        h = 1.0 / s
        Mh = sum(np.linalg.matrix_power(0.5 * h * A, j) / np.prod(np.arange(1, j + 1)) for j in range(5))
        deterministic = linear_sde_model(A, np.zeros((2, 2)), np.eye(2), np.eye(2), h)  # the code's sub-step
        np.testing.assert_allclose(deterministic.sample_transition(x, np.random.default_rng(0), 1, "rk4-split"),
                                   x @ (Mh @ Mh).T, rtol=1e-13)
        P = np.zeros((2, 2))
        for _ in range(s):
            P = Mh @ (Mh @ P @ Mh.T + Q * h) @ Mh.T
        errs.append(np.abs(P - Qd).max())
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.3)
    assert errs[1] / errs[2] == pytest.approx(4.0, rel=0.3)


def test_default_substeps_and_bad_input():
    small = zhao2013_model(variant="vdp", diffusion_scale=0.01)
    assert pf_substeps(small) == 2 and pf_substeps(small, "heun") == 20
    assert pf_substeps(zhao2013_model(variant="vdp", diffusion_scale=0.01, substeps=25)) == 3
    assert pf_substeps(zhao2013_model(variant="vdp", diffusion_scale=0.1)) == 5     # tr Q = 1.01
    model = zhao2013_model()
    assert pf_substeps(model) == 41                                                  # tr Q = 10.1
    z = np.zeros((2, 2))
    with pytest.raises(ParameterError, match="scheme"):
        particle_filter(model, z, X0, P0, np.random.default_rng(0), scheme="euler")
    with pytest.raises(ParameterError, match="scheme"):
        model.sample_transition(np.zeros((2, 2)), np.random.default_rng(0), scheme="euler")
    with pytest.raises(ParameterError, match="substeps"):
        particle_filter(model, z, X0, P0, np.random.default_rng(0), substeps=0)
    with pytest.raises(ParameterError, match="kernels.drift"):
        BlockKernels(lambda X, p, out: None, model.kernels.measurement, (), ())
    with pytest.raises(ParameterError, match="kernels"):
        ContinuousDiscreteModel(model.drift, model.Q, model.measurement, model.R, 1.0, kernels="fast")


def test_kernels_that_disagree_with_the_numpy_model_are_rejected():
    named = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    wrong = BlockKernels(kern.printed_drift, named.kernels.measurement, (), ())
    model = ContinuousDiscreteModel(named.drift, named.Q, named.measurement, named.R, 1.0, periods=named.periods,
                                    kernels=wrong)
    with pytest.raises(ParameterError, match="kernels.drift: the compiled kernel disagrees"):
        particle_filter(model, np.zeros((2, 2)), X0, P0, np.random.default_rng(0))
    wrong = BlockKernels(named.kernels.drift, kern.range_atan, (), ())   # bearing folded modulo π
    model = ContinuousDiscreteModel(named.drift, named.Q, named.measurement, named.R, 1.0, periods=named.periods,
                                    kernels=wrong)
    with pytest.raises(ParameterError, match="kernels.measurement"):
        particle_filter(model, np.zeros((2, 2)), X0, P0, np.random.default_rng(0))
    assert particle_filter(model, np.zeros((2, 2)), X0, P0, np.random.default_rng(0), compiled=False).x.shape == (2, 2)


@pytest.mark.filterwarnings("ignore:overflow encountered")
@pytest.mark.parametrize("compiled", [True, False])
def test_zero_likelihood_is_an_error_in_both_paths(compiled):
    model = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    z = np.array([[1.0, 0.0], [1e200, 0.0]])
    with pytest.raises(ParameterError, match="measurement 1 has zero likelihood"):
        particle_filter(model, z, X0, P0, np.random.default_rng(0), compiled=compiled)


def test_reference_default_is_finer_than_the_pf():
    model = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    z = np.array([[1.1, -0.5]])
    a = reference_filter(model, z, X0, P0, np.random.default_rng(0), particles=500)
    b = particle_filter(model, z, X0, P0, np.random.default_rng(0), particles=500, substeps=4 * pf_substeps(model),
                        ess_threshold=0.5)
    np.testing.assert_array_equal(a.x, b.x)


@pytest.mark.slow
def test_substep_study_split_scheme_bias_below_monte_carlo_noise():
    """docs/nonlinear.md: on eq. 42 (vdp, Q x 0.01) the default 2 RK4-split sub-steps have a bias
    well below the Monte-Carlo noise of 10^4 particles; 2 Heun sub-steps do not."""
    model = zhao2013_model(variant="vdp", diffusion_scale=0.01)
    _, z = simulate_sde(model, 30, np.random.default_rng(2013), X0)
    out = pf_substep_study(model, z, X0, P0, seed=4, runs=6, substeps=(2,), ref_particles=100_000)
    rows = {(r[0], r[1]): r for r in out["rows"]}
    split, heun = rows[("rk4-split", 2)], rows[("heun", 2)]
    assert split[3] < 0.5 * split[2]       # bias < half the error of one 10^4-particle filter
    assert heun[3] > 3 * split[2]          # Heun at 2 sub-steps: bias dominates


def test_a_nonlinear_model_takes_only_the_default_scheme():
    """The SDE sub-step scheme means nothing for a discrete-time model: another value is an error naming
    it (it used to be ignored), and so is compiled=True."""
    from mptrack.models import constant_velocity, nonlinear_model, position

    model = nonlinear_model(constant_velocity(1.0, 0.5, axes=1), position(np.eye(1), position=(0,)))
    z, x0, P0 = np.zeros((3, 1)), np.zeros(2), np.eye(2)
    assert particle_filter(model, z, x0, P0, np.random.default_rng(0), particles=50).x.shape == (3, 2)
    with pytest.raises(ParameterError, match="^scheme: only for a continuous-discrete model"):
        particle_filter(model, z, x0, P0, np.random.default_rng(0), particles=50, scheme="heun")
    with pytest.raises(ParameterError, match="^compiled"):
        particle_filter(model, z, x0, P0, np.random.default_rng(0), particles=50, compiled=True)
