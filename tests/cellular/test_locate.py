"""locate_cells' table checks (the compiled pass of a small float table says the same as the full checks)
and scans located together equal each located alone."""

from __future__ import annotations

import numpy as np
import pytest

from mptrack.cellular import CELL_FIELDS, check_cells, locate_cells
from mptrack.errors import NonFiniteError, ParameterError

CELLS = np.array([[50.8, 4.39, 2, -109.2, 35.2, np.nan, 0, np.nan, np.nan, 0, 120.0, -90.0, 1.0],
                  [50.8, 4.39, 2, -109.2, 35.2, np.nan, 0, np.nan, np.nan, 0, 240.0, -95.0, np.nan],
                  [50.81, 4.40, 0, -69.4, 35.2, 2.0, 3, 1.5, 2000.0, 1, np.nan, np.nan, 2.0],
                  [50.79, 4.41, 2, -105.0, 35.2, np.nan, 0, np.nan, 900.0, 1, 0.0, -101.0, np.nan]])
#: a value out of each column's range (a NaN where the column takes none)
BAD = {"lat": 86.0, "lon": -181.0, "radio": 7.0, "intercept_dbm": np.nan, "slope_db": 0.5,
       "fit_offset_db": 101.0, "area_fits": -1.0, "area_offset_db": -101.0, "range_m": -1.0, "changeable": 2.0,
       "azimuth_deg": 361.0, "rss_dbm": 1.0, "ta": -1.0}


def test_a_valid_float_table_is_taken_as_it_is():
    assert check_cells(CELLS) is CELLS
    mapping = {name: CELLS[:, j] for j, name in enumerate(CELL_FIELDS)}
    np.testing.assert_array_equal(check_cells(mapping), CELLS)
    np.testing.assert_array_equal(check_cells(CELLS.tolist()), CELLS)


@pytest.mark.parametrize("column", CELL_FIELDS)
@pytest.mark.parametrize("as_list", [False, True])
def test_each_column_out_of_its_range_is_named_with_its_row(column, as_list):
    table = CELLS.copy()
    table[2, CELL_FIELDS.index(column)] = BAD[column]
    with pytest.raises(ParameterError, match=rf"cells: column {column} expects .* in row 2$"):
        check_cells(table.tolist() if as_list else table)


def test_infinities_and_fractional_radio_codes_are_refused():
    table = CELLS.copy()
    table[1, CELL_FIELDS.index("range_m")] = np.inf
    with pytest.raises(NonFiniteError, match="infinite"):
        check_cells(table)
    table = CELLS.copy()
    table[3, CELL_FIELDS.index("radio")] = 1.5
    with pytest.raises(ParameterError, match="integer radio codes"):
        check_cells(table)


def test_scans_located_together_equal_each_alone():
    offsets = [0, 2, 3, 4]
    together = locate_cells(CELLS, offsets)
    alone = np.vstack([locate_cells(CELLS[a:b]) for a, b in zip(offsets[:-1], offsets[1:])])
    np.testing.assert_array_equal(together, alone)
    assert np.all(np.isfinite(together))


@pytest.mark.parametrize("sigma", [7.1, 9.0, 13.0, 20.0])
def test_a_levels_likelihood_averages_the_serving_sectors_loss_over_its_bearing(sigma):
    """The tabulated likelihood of a level (the residual s - A + n log10 d, in dB) against scipy's quadrature of
    the Gaussian averaged over the serving sector's bearing theta, uniform over 0..60 degrees, with the loss
    12 (theta / 65)^2 dB of 3GPP TR 36.814's pattern: equal up to one constant (the Gaussian's), within 3e-3."""
    from scipy import integrate, stats

    from mptrack.cellular._locate import _level_loglik, _level_row

    def exact(r):
        return integrate.quad(lambda th: stats.norm.pdf(r + 12.0 * (th / 65.0) ** 2, scale=sigma) / 60.0, 0.0, 60.0,
                              epsabs=0.0, epsrel=1e-12)[0]

    r = np.linspace(-5.0 * sigma - 10.2, 5.0 * sigma, 61)
    kappa = 12.0 * (60.0 / 65.0) ** 2 / sigma
    got = np.array([_level_loglik(v, 1.0 / sigma, kappa, _level_row(kappa)) for v in r])
    want = np.log([exact(v) for v in r]) + np.log(sigma * np.sqrt(2.0 * np.pi))
    np.testing.assert_allclose(got, want, rtol=0, atol=3e-3)
    # the most likely residual is a loss, not 0: a level is most likely ~3-5 dB below the axis's
    assert -6.0 < r[np.argmax(want)] < -2.0
