"""ANFIS hybrid learning: premise gradient vs finite differences, exact recovery, monotone training."""

import numpy as np
import pytest

from mptrack.errors import ParameterError, ShapeError
from mptrack.fuzzy import MembershipFunction, TakagiSugeno, anfis_train
from mptrack.fuzzy._anfis import _covers, _forward, _predict, _premise_gradient


def _loss(u, params, kind, c, y):
    w = _forward(u, params, kind)[2]
    return 0.5 * np.mean((_predict(w, c) - y) ** 2)


@pytest.mark.parametrize("kind, params", [
    ("gaussian", [np.array([[0.0, 0.3], [0.4, 0.2], [1.0, 0.25]]), np.array([[0.1, 0.5], [0.9, 0.4]])]),
    ("triangular", [np.array([[-0.5, 0.05, 0.45], [0.1, 0.4, 0.95], [0.35, 1.0, 1.5]]),
                    np.array([[-1.1, 0.1, 1.2], [-0.2, 0.9, 1.9]])]),
])
def test_premise_gradient_matches_finite_differences(kind, params):
    rng = np.random.default_rng(0)
    u = rng.uniform(0, 1, (50, 2))
    y = rng.uniform(0, 1, 50)
    c = rng.uniform(0, 1, (3, 2))
    grads = _premise_gradient(u, params, kind, c, y)
    eps = 1e-7
    for j in range(2):
        for i, k in np.ndindex(params[j].shape):
            up = [p.copy() for p in params]
            dn = [p.copy() for p in params]
            up[j][i, k] += eps
            dn[j][i, k] -= eps
            num = (_loss(u, up, kind, c, y) - _loss(u, dn, kind, c, y)) / (2 * eps)
            assert grads[j][i, k] == pytest.approx(num, rel=1e-5, abs=1e-10), (kind, j, i, k)


def test_triangle_coverage_check():
    assert _covers([-0.5, 0.0, 0.5], [0.5, 1.0, 1.5])          # the initial grid of 3 sets
    assert not _covers([0.1, 0.0, 0.5], [0.5, 1.0, 1.5])       # no set fires at 0
    assert not _covers([-0.5, 0.6], [0.5, 1.5])                # a gap (0.5, 0.6]
    assert not _covers([-0.5, 0.5], [0.5, 1.5])                # 0.5 itself fires nothing
    assert not _covers([-0.5, 0.2], [0.6, 1.0])                # 1 fires nothing


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


def test_triangular_sets_recover_a_generating_system_and_stay_valid():
    # data from a TS system on the initial triangular grid: least squares is exact at epoch 0
    c_true = np.array([[0.9, 0.1], [0.4, 0.6], [0.0, 1.0]])
    sets = (tuple(MembershipFunction("triangular", (m - 0.5, m, m + 0.5)) for m in (0.0, 0.5, 1.0)),
            tuple(MembershipFunction("triangular", (m - 1.0, m, m + 1.0)) for m in (0.0, 1.0)))
    gen = TakagiSugeno(sets, c_true)
    x = np.random.default_rng(1).uniform(0, 1, (400, 2))
    res = anfis_train(x, gen(x[:, 0], x[:, 1]), sets_per_input=(3, 2), universes=((0, 1), (0, 1)), epochs=3,
                      ridge=1e-12, membership="triangular")
    assert res.rmse[0] < 1e-8
    np.testing.assert_allclose(res.fis.consequents, c_true, atol=1e-6)
    # a target the initial grid cannot fit: training moves the breakpoints, lowers the error monotonically
    # and keeps every value of the universes firing some rule
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.uniform(0, 1.5, 800), rng.uniform(0.22, 0.32, 800)])
    y = np.exp(-((x[:, 0] - 0.55) / 0.2) ** 2) * (1.3 - (x[:, 1] - 0.22) / 0.1) / 1.3
    res = anfis_train(x, y, sets_per_input=(5, 2), universes=((0, 1.5), (0.22, 0.32)), epochs=40,
                      membership="triangular", bounds=(0, 1))
    assert np.all(np.diff(res.rmse) <= 1e-15) and res.rmse[-1] < 0.8 * res.rmse[0]
    assert all(mf.kind == "triangular" for s in res.fis.sets for mf in s)
    grid = np.meshgrid(np.linspace(0, 1.5, 301), np.linspace(0.22, 0.32, 51))
    assert np.all(np.isfinite(res.fis(*grid)))


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
    with pytest.raises(ParameterError, match="membership"):
        anfis_train(x, np.zeros(10), sets_per_input=(2, 2), universes=((0, 1), (0, 1)), membership="bell")


def test_bounded_consequents_stay_in_the_box():
    rng = np.random.default_rng(4)
    x = rng.uniform(0, 0.2, (300, 1))  # data in a corner of the universe: unbounded LS extrapolates wildly
    y = np.clip(1.5 - 8 * x[:, 0], 0, 1)
    res = anfis_train(x, y, sets_per_input=(5,), universes=((0, 1.5),), epochs=10, bounds=(0.0, 1.0))
    assert res.fis.consequents.min() >= 0 and res.fis.consequents.max() <= 1
    grid = np.linspace(0, 1.5, 50)
    assert np.all((res.fis(grid) >= 0) & (res.fis(grid) <= 1))
