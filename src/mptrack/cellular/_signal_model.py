"""What a cell's received level says about the distance to it: the path-loss model that
:func:`mptrack.cellular.locate_cells` inverts, with COST-231 as the prior and the cell table's
``averageSignal``/``range`` as the fit.

The level a phone reports differs by radio (what Android's ``getDbm()`` and a geolocate request's
``signalStrength`` carry): GSM the RSSI of the BCCH carrier, UMTS the RSCP of the pilot (CPICH), LTE
the RSRP (one resource element of the reference signal), NR the SS-RSRP.  In dBm, at distance d from
the site,

    s = A - n log10(d / 1 km) + G(theta) + site shadowing + e

* A, the cell's *intercept* (the level at 1 km on the antenna's axis): the prior is the radio's typical
  effective radiated power of the measured signal (:data:`RADIOS`) minus the COST-231 Hata loss at
  1 km (Okumura-Hata below 1500 MHz), medium city, the table's antenna height (30 m by default) and a
  1.5 m handset; n = 44.9 - 6.55 log10(h_base) dB per decade (Hata 1980; COST 231 final report,
  sec. 4.4.1).
* The fit from the table (:func:`signal_fit`): a cell whose ``averageSignal`` (mean level of its
  crowd-sourced observations) and ``range`` (the radius they cover) are known gives
  A_fit = averageSignal + n log10(TYPICAL_FRACTION x range / 1 km): the average level is taken as the
  level at 0.4 x the range.  Cells of one location area share their environment, so the mean fitted
  offset A_fit - A_prior of an area's fitted cells moves the intercepts of its other cells
  (:func:`mptrack.cellular.locate_cells` does the pooling, shrinking the area's mean by its number of
  fits).
* G(theta), the sector's pattern, and the shadowing are :func:`mptrack.cellular.locate_cells`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._core.validation import as_array, broadcast_shape
from ..errors import ParameterError
from ..radio import cost231_hata, okumura_hata

__all__ = ["RADIOS", "RADIO_CODES", "Radio", "signal_prior", "signal_fit", "radio_code"]

C_MPS = 299_792_458.0


@dataclass(frozen=True)
class Radio:
    """One radio technology as the geolocation models it.

    eirp_dbm         typical effective radiated power of the signal the phone measures (dBm): GSM a 20 W
                     BCCH carrier, 17 dBi antenna, 3 dB feeder loss (57); UMTS the pilot at 10 % of 20 W
                     (47); LTE one resource element of a 20 W carrier over 10-20 MHz (27); NR SS block (30)
    frequency_mhz    the carrier assumed for the prior (the table does not give it)
    ta_step_m        one timing-advance step as a one-way distance (m), or NaN (no timing advance):
                     GSM one bit period 48/13 us (3GPP TS 45.010 sec. 5.4), LTE 16 T_s = 16 / 30.72 MHz
                     (TS 36.213 sec. 4.2.3), x c / 2
    ta_max           the largest timing advance the radio signals (GSM 63, LTE 1282)
    typical_dbm      the level assumed for a cell heard without a level (with 12 dB more uncertainty)
    min_signal_dbm   Ichnaea's level for a cell without one (its weighted centroid)
    table_name       the radio's name in OpenCelliD / MLS tables
    """

    name: str
    table_name: str
    eirp_dbm: float
    frequency_mhz: float
    ta_step_m: float
    ta_max: int
    typical_dbm: float
    min_signal_dbm: float


#: The radios by code (the code is the index): names as in geolocate requests (``radioType``).
RADIOS: tuple[Radio, ...] = (
    Radio("gsm", "GSM", 57.0, 900.0, C_MPS * 48.0 / 13.0e6 / 2.0, 63, -85.0, -113.0),
    Radio("wcdma", "UMTS", 47.0, 2100.0, math.nan, 0, -95.0, -121.0),
    Radio("lte", "LTE", 27.0, 1800.0, C_MPS * 16.0 / 30.72e6 / 2.0, 1282, -100.0, -140.0),
    Radio("nr", "NR", 30.0, 3500.0, math.nan, 0, -100.0, -140.0),
    Radio("cdma", "CDMA", 47.0, 850.0, math.nan, 0, -90.0, -120.0),
)
#: Radio code by name: request names (gsm, wcdma, lte, nr, cdma; also umts) and table names (GSM, UMTS, ...).
RADIO_CODES: dict[str, int] = {**{r.name: i for i, r in enumerate(RADIOS)},
                               **{r.table_name: i for i, r in enumerate(RADIOS)}, "umts": 1}
#: Mobile antenna height of the prior (m).
HANDSET_M = 1.5
#: The level averaged over a cell's observations is taken as the level at this fraction of its range.
TYPICAL_FRACTION = 0.4
#: averageSignal values outside this range (dBm) are not levels (OpenCelliD writes 0 for "unknown").
_LEVELS = (-150.0, -25.0)


def radio_code(name: str) -> int:
    """The code of a radio named as in a request (``lte``) or a table (``LTE``).

    Parameters
    ----------
    name : str
        ``gsm``, ``wcdma``/``umts``, ``lte``, ``nr``, ``cdma`` (any case), or the tables' ``GSM``, ``UMTS``,
        ``LTE``, ``NR``, ``CDMA``.

    Returns
    -------
    int
        The radio's index in :data:`RADIOS`.

    Raises
    ------
    ParameterError
        An unknown name.
    """
    code = RADIO_CODES.get(name) if isinstance(name, str) else None
    if code is None:
        code = RADIO_CODES.get(name.strip().lower()) if isinstance(name, str) else None
    if code is None:
        raise ParameterError(f"name: expected one of {', '.join(r.name for r in RADIOS)} (or the tables' "
                             f"{', '.join(r.table_name for r in RADIOS)}), got {name!r}")
    return code


def _codes(radio) -> np.ndarray:
    r = as_array("radio", radio, low=0, high=len(RADIOS) - 1)
    if np.any(r != np.round(r)):
        raise ParameterError(f"radio: expected radio codes 0..{len(RADIOS) - 1} (RADIOS), got {r[r != np.round(r)][0]}")
    return r.astype(np.int64)


def signal_prior(radio, height_m=30.0) -> tuple[np.ndarray, np.ndarray]:
    """The prior path-loss model of cells (see the module doc).

    Parameters
    ----------
    radio : int or array_like of int
        Radio codes (indices into :data:`RADIOS`).
    height_m : float or array_like, optional
        Antenna heights above ground (m), taken within Hata's 30..200 m; NaN: unknown (30 m, the
        default, as for a table that gives none).

    Returns
    -------
    intercept_dbm, slope_db : float or ndarray
        The level at 1 km on the antenna's axis (dBm) and the loss per decade of distance (dB),
        broadcast over the arguments.
    """
    code = _codes(radio)
    h = as_array("height_m", height_m, low=0.0, allow_nan=True)
    shape = broadcast_shape(radio=code, height_m=h)
    code, h = np.broadcast_to(code, shape), np.clip(np.nan_to_num(np.broadcast_to(h, shape), nan=30.0), 30.0, 200.0)
    f = np.array([r.frequency_mhz for r in RADIOS])[code]
    eirp = np.array([r.eirp_dbm for r in RADIOS])[code]
    loss = np.where(f < 1500.0,
                    okumura_hata(1.0, np.minimum(f, 1500.0), h_base_m=h, h_mobile_m=HANDSET_M, on_invalid="ignore"),
                    cost231_hata(1.0, np.maximum(f, 1500.0), h_base_m=h, h_mobile_m=HANDSET_M, on_invalid="ignore"))
    slope = 44.9 - 6.55 * np.log10(h)
    return _out(eirp - loss), _out(slope)


def signal_fit(intercept_dbm, slope_db, range_m, average_signal_dbm, samples) -> np.ndarray:
    """The offset of each cell's intercept fitted from the table, A_fit - A_prior (see the module doc).

    Parameters
    ----------
    intercept_dbm, slope_db : array_like
        The prior model of each cell (:func:`signal_prior`).
    range_m : array_like
        The table's ``range`` (m; NaN: unknown).
    average_signal_dbm : array_like
        The table's ``averageSignal`` (dBm; 0 is OpenCelliD's "unknown").
    samples : array_like
        The table's ``samples`` (NaN: unknown).

    Returns
    -------
    float or ndarray
        The offset (dB), NaN where the table does not tell: ``average_signal_dbm`` outside -150..-25 dBm,
        ``range_m`` not above 0, or fewer than 2 ``samples``.
    """
    a = as_array("intercept_dbm", intercept_dbm)
    n = as_array("slope_db", slope_db, low=0.0)
    r = as_array("range_m", range_m, allow_nan=True)
    s = as_array("average_signal_dbm", average_signal_dbm, allow_nan=True)
    k = as_array("samples", samples, allow_nan=True)
    shape = broadcast_shape(intercept_dbm=a, slope_db=n, range_m=r, average_signal_dbm=s, samples=k)
    a, n, r, s, k = (np.broadcast_to(v, shape) for v in (a, n, r, s, k))
    ok = (s >= _LEVELS[0]) & (s <= _LEVELS[1]) & (r > 0.0) & (k >= 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = s + n * np.log10(TYPICAL_FRACTION * np.where(ok, r, 1.0) / 1000.0)
    return _out(np.where(ok, fit - a, np.nan))


def _out(v: np.ndarray):
    v = np.asarray(v, dtype=float)
    return v[()] if v.ndim == 0 else v
