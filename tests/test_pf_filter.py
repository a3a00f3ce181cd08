"""The bootstrap particle filter and the reference: convergence, resampling, bad input."""

import numpy as np
import pytest

from mptrack.continuous import fem_filter, linear_sde_model, reference_filter, simulate_sde, zhao2013_model
from mptrack.errors import ParameterError
from mptrack.linear import kalman_filter
from mptrack.nonlinear import particle_filter, systematic_resample

X0, P0 = np.array([-0.6, -1.0]), 0.1 * np.eye(2)


def test_systematic_resampling_counts():
    w = np.array([0.5, 0.25, 0.125, 0.125])
    idx = systematic_resample(w, np.random.default_rng(0))
    counts = np.bincount(idx, minlength=4)
    assert counts.sum() == 4
    assert np.all(np.abs(counts - 4 * w) < 1)


@pytest.fixture(scope="module")
def vdp_case():
    model = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    truth, z = simulate_sde(model, 10, np.random.default_rng(5), X0)
    ref = reference_filter(model, z, X0, P0, np.random.default_rng(6), particles=20000)
    return model, z, ref


def test_pf_converges_to_reference(vdp_case):
    model, z, ref = vdp_case
    err = []
    for n in (100, 3000):
        e = [np.sqrt(np.mean((particle_filter(model, z, X0, P0, np.random.default_rng(s), particles=n).x
                              - ref.x) ** 2)) for s in range(3)]
        err.append(np.mean(e))
    assert err[1] < 0.5 * err[0]


def test_fem_agrees_with_reference(vdp_case):
    """Independent algorithms (Galerkin Fokker–Planck vs Monte-Carlo) give the same posterior mean."""
    model, z, ref = vdp_case
    fe = fem_filter(model, z, X0, P0, grid=(30, 30))
    assert np.sqrt(np.mean((fe.x - ref.x) ** 2)) < 0.1


def test_pf_on_linear_model_near_kalman():
    model = linear_sde_model([[0.0, 1.0], [-1.0, -0.5]], np.diag([0.1, 0.2]), np.eye(2), 0.5 * np.eye(2), 1.0)
    _, z = simulate_sde(model, 10, np.random.default_rng(2), [1.0, 0.0])
    kf = kalman_filter(model.to_linear_gaussian(), z, [1.0, 0.0], 0.3 * np.eye(2))
    pf = particle_filter(model, z, [1.0, 0.0], 0.3 * np.eye(2), np.random.default_rng(3), particles=20000,
                         regularise=True)
    np.testing.assert_allclose(pf.x, kf.x, atol=0.05)
    np.testing.assert_allclose(pf.P, kf.P, atol=0.05)
    assert pf.loglik == pytest.approx(kf.loglik, abs=0.5)


def test_pf_is_reproducible_and_skips_nan():
    model = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    z = np.array([[1.0, 0.1], [np.nan, np.nan], [1.1, 0.2]])
    a = particle_filter(model, z, X0, P0, np.random.default_rng(1))
    b = particle_filter(model, z, X0, P0, np.random.default_rng(1))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_allclose(a.x[1], a.x_pred[1])


def test_pf_bad_input():
    model = zhao2013_model()
    z = np.zeros((2, 2))
    with pytest.raises(ParameterError, match="rng"):
        particle_filter(model, z, X0, P0, 42)
    with pytest.raises(ParameterError, match="particles"):
        particle_filter(model, z, X0, P0, np.random.default_rng(0), particles=1)
    with pytest.raises(ParameterError, match="ess_threshold"):
        particle_filter(model, z, X0, P0, np.random.default_rng(0), ess_threshold=2.0)


@pytest.mark.slow
def test_fem_and_pf_converge_to_a_large_reference_over_many_runs():
    """Monte-Carlo version: 5 runs against a 10^5-particle reference; FE error falls with the grid."""
    model = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    fe_err, pf_err = [], []
    for seed in range(5):
        _, z = simulate_sde(model, 15, np.random.default_rng(100 + seed), X0)
        ref = reference_filter(model, z, X0, P0, np.random.default_rng(200 + seed), particles=100_000).x
        fe_err.append([np.sqrt(np.mean((fem_filter(model, z, X0, P0, grid=(g, g), substeps=s).x - ref) ** 2))
                       for g, s in ((20, 16), (40, 32))])
        pf = particle_filter(model, z, X0, P0, np.random.default_rng(300 + seed), particles=10_000).x
        pf_err.append(np.sqrt(np.mean((pf - ref) ** 2)))
    fe_err = np.mean(fe_err, axis=0)
    assert fe_err[1] < 0.6 * fe_err[0]
    assert fe_err[1] < 0.03
    assert np.mean(pf_err) < 0.05  # bootstrap weights degenerate on sharp likelihoods: ESS << N
