"""GSM ARFCN <-> frequency at every band edge (3GPP TS 45.005 §2) and the paper's DCS formula."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mptrack.errors import DTypeError, NonFiniteError, ParameterError, UnknownNameError
from mptrack.radio import GSM_BANDS, arfcn_to_frequency, frequency_to_arfcn

EDGES = [  # band, arfcn, uplink MHz, downlink MHz
    ("P-GSM", 1, 890.2, 935.2), ("P-GSM", 124, 914.8, 959.8),
    ("E-GSM", 0, 890.0, 935.0), ("E-GSM", 124, 914.8, 959.8),
    ("E-GSM", 975, 880.2, 925.2), ("E-GSM", 1023, 889.8, 934.8),
    ("R-GSM", 955, 876.2, 921.2), ("R-GSM", 1023, 889.8, 934.8), ("R-GSM", 0, 890.0, 935.0),
    ("DCS1800", 512, 1710.2, 1805.2), ("DCS1800", 885, 1784.8, 1879.8),
    ("PCS1900", 512, 1850.2, 1930.2), ("PCS1900", 810, 1909.8, 1989.8),
    ("GSM850", 128, 824.2, 869.2), ("GSM850", 251, 848.8, 893.8),
]


@pytest.mark.parametrize("band,n,up,down", EDGES)
def test_band_edges(band, n, up, down):
    assert arfcn_to_frequency(n, band, "uplink") == pytest.approx(up, abs=1e-9)
    assert arfcn_to_frequency(n, band) == pytest.approx(down, abs=1e-9)
    assert frequency_to_arfcn(down, band) == n
    assert frequency_to_arfcn(up, band, "uplink") == n


@pytest.mark.parametrize("band,n", [("P-GSM", 0), ("P-GSM", 125), ("E-GSM", 974), ("R-GSM", 954),
                                    ("DCS1800", 511), ("DCS1800", 886), ("PCS1900", 811), ("GSM850", 127),
                                    ("GSM850", 252)])
def test_outside_band_raises(band, n):
    with pytest.raises(ParameterError, match="arfcn"):
        arfcn_to_frequency(n, band)


def test_paper_formula_is_dcs1800_downlink():
    n = np.arange(512, 886)
    np.testing.assert_allclose(arfcn_to_frequency(n, "DCS1800"), 1805 + 0.2 * (n - 511), atol=1e-9)
    assert arfcn_to_frequency(764, "DCS1800") == pytest.approx(1855.6)


def test_overlapping_ranges_need_the_band():
    assert arfcn_to_frequency(600, "DCS1800") != arfcn_to_frequency(600, "PCS1900")


def test_bad_inputs():
    with pytest.raises(UnknownNameError, match="band"):
        arfcn_to_frequency(10, "GSM-R2")
    with pytest.raises(DTypeError, match="arfcn"):
        arfcn_to_frequency(10.5, "P-GSM")
    with pytest.raises(ParameterError, match="link"):
        arfcn_to_frequency(10, "P-GSM", link="sideways")
    with pytest.raises(ParameterError, match="frequency_mhz"):
        frequency_to_arfcn(935.1, "P-GSM")
    with pytest.raises(NonFiniteError, match="frequency_mhz"):
        frequency_to_arfcn(np.nan, "P-GSM")


@given(st.sampled_from(sorted(GSM_BANDS)), st.data())
def test_round_trip(band, data):
    lo, hi = GSM_BANDS[band].segments[-1][:2]
    n = data.draw(st.integers(lo, hi))
    for link in ("uplink", "downlink"):
        assert frequency_to_arfcn(arfcn_to_frequency(n, band, link), band, link) == n
