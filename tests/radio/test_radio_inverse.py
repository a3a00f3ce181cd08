"""RSS -> distance inverses: closed form and bracketed root agree with the forward models."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import ParameterError, UnknownNameError
from mptrack.radio import (
    ValidityWarning,
    arfcn_to_frequency,
    distance_from_path_loss,
    distance_from_rss,
    path_loss,
)

CASES = [
    ("free-space", dict(frequency_mhz=900.0), (0.01, 50.0)),
    ("cost231-wi-los", dict(frequency_mhz=1800.0), (0.02, 5.0)),
    ("cost231-wi-nlos", dict(frequency_mhz=1800.0, h_base_m=30.0), (0.02, 5.0)),
    ("cost231-wi-nlos", dict(frequency_mhz=900.0, h_base_m=10.0, city="metropolitan"), (0.02, 5.0)),
    ("cost231-hata", dict(frequency_mhz=1800.0, h_base_m=40.0), (1.0, 20.0)),
    ("okumura-hata", dict(frequency_mhz=900.0, h_base_m=40.0, environment="suburban"), (1.0, 20.0)),
]


@pytest.mark.parametrize("model,params,rng", CASES)
def test_inverse_round_trip(model, params, rng):
    d = np.geomspace(rng[0], rng[1], 25)
    loss = path_loss(d, model, **params)
    np.testing.assert_allclose(distance_from_path_loss(loss, model, **params), d, rtol=1e-9)


def test_table_viii_distances():
    rows = [(52, 43, -69, 764, 0.455334), (36, 45, -74, 756, 0.537776), (15, 45, -95, 766, 0.443333)]
    for hb, tx, rx, arfcn, d in rows:
        f = arfcn_to_frequency(arfcn, "DCS1800")
        ours = distance_from_rss(rx, tx, h_base_m=hb, frequency_mhz=f, city="metropolitan",
                                 free_space_constant_db=32.45, on_invalid="ignore")
        assert ours == pytest.approx(d, abs=6e-7)


def test_unexplained_rss_raises_with_the_covered_range():
    with pytest.raises(ParameterError, match="covers"):
        distance_from_rss(-20.0, 43.0, h_base_m=30.0, frequency_mhz=1800.0)
    with pytest.raises(ParameterError, match="covers"):
        distance_from_rss(-200.0, 43.0, "cost231-hata", h_base_m=30.0, frequency_mhz=1800.0)
    with pytest.warns(ValidityWarning):
        d = distance_from_rss(-200.0, 43.0, "cost231-hata", h_base_m=30.0, frequency_mhz=1800.0, on_invalid="warn")
    assert d > 20.0
    with pytest.raises(ParameterError, match="h_base_m"):  # parameters are checked under the same policy
        distance_from_rss(-80.0, 43.0, h_base_m=60.0, frequency_mhz=1800.0)
    with pytest.raises(UnknownNameError):
        distance_from_rss(-80.0, 43.0, "ray-tracing")


@settings(max_examples=40, deadline=None)
@given(st.floats(-110, -60), st.floats(-110, -60))
def test_stronger_signal_means_shorter_distance(a, b):
    kw = dict(h_base_m=30.0, frequency_mhz=1800.0, on_invalid="ignore")
    da, db = distance_from_rss(np.array([a, b]), 43.0, **kw)
    assert (a - b) * (da - db) <= 1e-12


@pytest.mark.parametrize("params", [dict(frequency_mhz=1800.0, h_base_m=30.0),
                                    dict(frequency_mhz=900.0, h_base_m=10.0, city="metropolitan")])
def test_walfisch_ikegami_nlos_inverse_is_vectorised_and_exact(monkeypatch, params):
    """The WI NLOS inverse solves all values together: ~50 calls of the model for 20,000 losses (it
    called it ~15 times per value: 6 ms per fix in cellular tracking), to 1e-13 relative."""
    import functools

    from mptrack.radio import _inverse

    spec = _inverse.PATH_LOSS_MODELS["cost231-wi-nlos"]
    calls = []

    @functools.wraps(spec.fn)
    def counted(*args, **kwargs):
        calls.append(1)
        return spec.fn(*args, **kwargs)

    monkeypatch.setitem(_inverse.PATH_LOSS_MODELS, "cost231-wi-nlos", _inverse._Model(counted, spec.distance_km, False))
    d = np.geomspace(0.02, 5.0, 20_000)
    loss = path_loss(d, "cost231-wi-nlos", **params)
    calls.clear()
    np.testing.assert_allclose(distance_from_path_loss(loss, "cost231-wi-nlos", **params), d, rtol=1e-13, atol=0)
    assert len(calls) < 80
