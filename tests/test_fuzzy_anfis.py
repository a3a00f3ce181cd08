"""ANFIS hybrid learning: premise gradient vs finite differences, exact recovery, monotone training."""

import numpy as np
import pytest

from mptrack.errors import ParameterError, ShapeError
from mptrack.fuzzy import MembershipFunction, TakagiSugeno, anfis_train
from mptrack.fuzzy._anfis import _forward, _predict, _premise_gradient


def _loss(u, means, sigmas, c, y):
    _, w = _forward(u, means, sigmas)
    return 0.5 * np.mean((_predict(w, c) - y) ** 2)


def test_premise_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    u = rng.uniform(0, 1, (50, 2))
    y = rng.uniform(0, 1, 50)
    means = [np.array([0.0, 0.4, 1.0]), np.array([0.1, 0.9])]
    sigmas = [np.array([0.3, 0.2, 0.25]), np.array([0.5, 0.4])]
    c = rng.uniform(0, 1, (3, 2))
    gm, gs = _premise_gradient(u, means, sigmas, c, y)
    eps = 1e-6
    for j in range(2):
        for a in range(len(means[j])):
            for params, grad in ((means, gm), (sigmas, gs)):
                up = [p.copy() for p in params]
                dn = [p.copy() for p in params]
                up[j][a] += eps
                dn[j][a] -= eps
                if params is means:
                    num = (_loss(u, up, sigmas, c, y) - _loss(u, dn, sigmas, c, y)) / (2 * eps)
                else:
                    num = (_loss(u, means, up, c, y) - _loss(u, means, dn, c, y)) / (2 * eps)
                assert grad[j][a] == pytest.approx(num, rel=1e-5, abs=1e-10)


def test_recovers_consequents_of_a_generating_system():
    # data from a TS system whose sets equal ANFIS's initial partition: least squares is exact at epoch 0
    c_true = np.array([[0.9, 0.1], [0.4, 0.6], [0.0, 1.0]])
    sets = (tuple(MembershipFunction("gaussian", (m, 0.25)) for m in (0.0, 0.5, 1.0)),
            tuple(MembershipFunction("gaussian", (m, 0.5)) for m in (0.0, 1.0)))
    gen = TakagiSugeno(sets, c_true)
    x = np.random.default_rng(1).uniform(0, 1, (400, 2))
    res = anfis_train(x, gen(x[:, 0], x[:, 1]), sets_per_input=(3, 2), universes=((0, 1), (0, 1)), epochs=3,
                      ridge=1e-12)
    assert res.rmse[0] < 1e-8
    np.testing.assert_allclose(res.fis.consequents, c_true, atol=1e-6)


def test_training_reduces_error_monotonically_and_is_deterministic():
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.uniform(0, 1.5, 800), rng.uniform(0.22, 0.32, 800)])
    y = np.exp(-((x[:, 0] - 0.55) / 0.2) ** 2) * (1.3 - (x[:, 1] - 0.22) / 0.1) / 1.3
    kw = dict(sets_per_input=(5, 2), universes=((0, 1.5), (0.22, 0.32)), epochs=40)
    a = anfis_train(x, y, **kw)
    b = anfis_train(x, y, **kw)
    assert np.all(np.diff(a.rmse) <= 1e-15)
    assert a.rmse[-1] < 0.7 * a.rmse[0]
    np.testing.assert_array_equal(a.rmse, b.rmse)
    np.testing.assert_allclose(a.fis(x[:, 0], x[:, 1]), y, atol=0.1)


def test_bad_input():
    x = np.zeros((10, 2))
    with pytest.raises(ShapeError, match="inputs, target"):
        anfis_train(x, np.zeros(9), sets_per_input=(2, 2), universes=((0, 1), (0, 1)))
    with pytest.raises(ShapeError, match="sets_per_input"):
        anfis_train(x, np.zeros(10), sets_per_input=(2,), universes=((0, 1), (0, 1)))
    with pytest.raises(ParameterError, match="universes"):
        anfis_train(x, np.zeros(10), sets_per_input=(2, 2), universes=((0, 1), (1, 1)))
    with pytest.raises(ParameterError, match="sets_per_input"):
        anfis_train(x, np.zeros(10), sets_per_input=(1, 2), universes=((0, 1), (0, 1)))


def test_bounded_consequents_stay_in_the_box():
    rng = np.random.default_rng(4)
    x = rng.uniform(0, 0.2, (300, 1))  # data in a corner of the universe: unbounded LS extrapolates wildly
    y = np.clip(1.5 - 8 * x[:, 0], 0, 1)
    res = anfis_train(x, y, sets_per_input=(5,), universes=((0, 1.5),), epochs=10, bounds=(0.0, 1.0))
    assert res.fis.consequents.min() >= 0 and res.fis.consequents.max() <= 1
    grid = np.linspace(0, 1.5, 50)
    assert np.all((res.fis(grid) >= 0) & (res.fis(grid) <= 1))
