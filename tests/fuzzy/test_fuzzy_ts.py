"""Zero-order Takagi–Sugeno inference: hand-computed cases, partition properties, simpful as oracle."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import ParameterError, ShapeError
from mptrack.fuzzy import MembershipFunction, TakagiSugeno, gaussian, trapezoidal, triangular, uniform_partition

INN = uniform_partition(0.0, 1.5, 5)
S = uniform_partition(0.22, 0.32, 2)
C = [[1, 0.75], [0.75, 0.5], [0.5, 0.5], [0.25, 0.5], [0, 0.25]]


def fis():
    return TakagiSugeno((INN, S), C, universes=((0.0, 1.5), (0.22, 0.32)), names=("inn", "S"))


def test_membership_shapes():
    x = np.array([-1.0, 0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    np.testing.assert_allclose(triangular(x, 0, 1, 2), [0, 0, 0.5, 1, 0.5, 0, 0])
    np.testing.assert_allclose(trapezoidal(x, 0, 0.5, 1.5, 2), [0, 0, 1, 1, 1, 0, 0])
    np.testing.assert_allclose(trapezoidal(x, -np.inf, -np.inf, 0, 1), [1, 1, 0.5, 0, 0, 0, 0])
    np.testing.assert_allclose(gaussian(x, 1.0, 0.5), np.exp(-2 * (x - 1) ** 2))
    with pytest.raises(ParameterError, match="params"):
        MembershipFunction("triangular", (1, 0, 2))
    with pytest.raises(ParameterError, match="kind"):
        MembershipFunction("bell", (1, 0, 2))


def test_hand_computed_output():
    # inn = 0.1: VS = 1 - 0.1/0.375, S = 0.1/0.375; S = 0.25: Small = 0.7, Large = 0.3
    vs, sm = 1 - 0.1 / 0.375, 0.1 / 0.375
    expect = vs * (0.7 * 1 + 0.3 * 0.75) + sm * (0.7 * 0.75 + 0.3 * 0.5)
    assert fis()(0.1, 0.25) == pytest.approx(expect)
    # at rule centres the output is the rule's constant
    centres = np.linspace(0, 1.5, 5)
    for i, inn in enumerate(centres):
        for j, s in enumerate((0.22, 0.32)):
            assert fis()(inn, s) == pytest.approx(C[i][j])


def test_clipping_to_the_universe():
    f = fis()
    assert f(5.0, 1.0) == pytest.approx(f(1.5, 0.32))
    assert f(-1.0, 0.0) == pytest.approx(1.0)


def test_vectorised_broadcasting():
    f = fis()
    inn = np.linspace(0, 2, 12).reshape(3, 4)
    out = f(inn, 0.27)
    assert out.shape == (3, 4)
    np.testing.assert_allclose(out, [[f(v, 0.27) for v in row] for row in inn])


@settings(max_examples=50, deadline=None)
@given(st.floats(-5, 5), st.floats(-5, 5), st.integers(2, 7))
def test_partition_sums_to_one_and_output_is_bounded(x, s, count):
    sets = uniform_partition(-1.0, 2.0, count)
    assert sum(mf(x) for mf in sets) == pytest.approx(1.0)
    y = fis()(abs(x), s)
    assert 0.0 <= y <= 1.0


def test_no_firing_rule_raises_and_bad_shapes():
    narrow = (MembershipFunction("triangular", (0, 1, 2)),)
    f = TakagiSugeno((narrow,), [1.0], names=("d",))
    with pytest.raises(ParameterError, match="no rule fires"):
        f(5.0)
    with pytest.raises(ShapeError, match="consequents"):
        TakagiSugeno((INN, S), np.zeros((2, 5)))
    with pytest.raises(ShapeError, match="inputs"):
        fis()(0.1)


def test_agrees_with_simpful():
    simpful = pytest.importorskip("simpful")
    fs = simpful.FuzzySystem(show_banner=False, operators=["AND_PRODUCT"])
    inn_names = ["VS", "S", "N", "L", "VL"]
    c = np.linspace(0, 1.5, 5)
    inn_sets = []
    for i, name in enumerate(inn_names):
        a = c[i - 1] if i else c[0] - 1.0
        b = c[i]
        d = c[i + 1] if i < 4 else c[4] + 1.0
        if i == 0:
            inn_sets.append(simpful.TrapezoidFuzzySet(a, a, b, d, term=name))
        elif i == 4:
            inn_sets.append(simpful.TrapezoidFuzzySet(a, b, d, d, term=name))
        else:
            inn_sets.append(simpful.TriangleFuzzySet(a, b, d, term=name))
    fs.add_linguistic_variable("inn", simpful.LinguisticVariable(inn_sets, universe_of_discourse=[-1, 2.5]))
    s_sets = [simpful.TrapezoidFuzzySet(0.0, 0.0, 0.22, 0.32, term="SM"),
              simpful.TrapezoidFuzzySet(0.22, 0.32, 1.0, 1.0, term="LA")]
    fs.add_linguistic_variable("s", simpful.LinguisticVariable(s_sets, universe_of_discourse=[0, 1]))
    rules = []
    for i, name in enumerate(inn_names):
        for j, sname in enumerate(("SM", "LA")):
            fs.set_crisp_output_value(f"c{i}{j}", C[i][j])
            rules.append(f"IF (inn IS {name}) AND (s IS {sname}) THEN (y IS c{i}{j})")
    fs.add_rules(rules)
    rng = np.random.default_rng(0)
    for inn, s in zip(rng.uniform(0, 1.5, 30), rng.uniform(0.22, 0.32, 30)):
        fs.set_variable("inn", inn)
        fs.set_variable("s", s)
        assert fis()(inn, s) == pytest.approx(fs.Sugeno_inference(["y"])["y"], abs=1e-9)
