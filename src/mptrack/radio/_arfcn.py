"""GSM channel plans: ARFCN <-> carrier frequency (3GPP TS 45.005 §2).

Each band maps an absolute radio-frequency channel number n to the uplink
(mobile transmit) carrier F_l(n) and the downlink (base transmit) carrier
F_u(n) = F_l(n) + duplex spacing, on a 200 kHz raster.  ARFCN ranges overlap
between bands (512–810 is both DCS 1800 and PCS 1900; 0–124 is P/E/R-GSM), so
the band is always an argument.  Bouzera et al. (2017) use
f = 1805 + 0.2 (ARFCN - 511), which is the DCS 1800 downlink.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core.validation import as_array, as_real
from ..errors import DTypeError, ParameterError, UnknownNameError

__all__ = ["GsmBand", "GSM_BANDS", "arfcn_to_frequency", "frequency_to_arfcn", "band_of_arfcn", "TA_STEP_M"]


@dataclass(frozen=True)
class GsmBand:
    """One contiguous ARFCN segment: F_l(n) = f0_mhz + 0.2 (n - n0) for n_min <= n <= n_max."""

    name: str
    segments: tuple[tuple[int, int, int, float], ...]  # (n_min, n_max, n0, f0_mhz)
    duplex_mhz: float

    def contains(self, arfcn) -> np.ndarray:
        n = np.asarray(arfcn)
        return np.logical_or.reduce([(n >= lo) & (n <= hi) for lo, hi, _, _ in self.segments])


#: The bands of 3GPP TS 45.005 §2 used in Europe and the Americas.
GSM_BANDS: dict[str, GsmBand] = {
    "P-GSM": GsmBand("P-GSM 900", ((1, 124, 0, 890.0),), 45.0),
    "E-GSM": GsmBand("E-GSM 900", ((0, 124, 0, 890.0), (975, 1023, 1024, 890.0)), 45.0),
    "R-GSM": GsmBand("R-GSM 900", ((0, 124, 0, 890.0), (955, 1023, 1024, 890.0)), 45.0),
    "DCS1800": GsmBand("DCS 1800", ((512, 885, 512, 1710.2),), 95.0),
    "PCS1900": GsmBand("PCS 1900", ((512, 810, 512, 1850.2),), 80.0),
    "GSM850": GsmBand("GSM 850", ((128, 251, 128, 824.2),), 45.0),
}

#: The distance of one step of the GSM timing advance (m): one bit period, 48/13 µs, of the round trip
#: (3GPP TS 45.010), so c * 48/13 µs / 2.
TA_STEP_M = 553.5

_LINKS = ("downlink", "uplink")


def _band(band: str) -> GsmBand:
    if band not in GSM_BANDS:
        raise UnknownNameError(f"band: unknown GSM band {band!r}; known: {', '.join(GSM_BANDS)}")
    return GSM_BANDS[band]


def _link(link: str) -> str:
    if link not in _LINKS:
        raise ParameterError(f"link: expected 'downlink' or 'uplink', got {link!r}")
    return link


def arfcn_to_frequency(arfcn, band: str, link: str = "downlink"):
    """Carrier frequency of a GSM channel (3GPP TS 45.005, sec. 2).

    Parameters
    ----------
    arfcn : int or array_like of int
        Absolute radio-frequency channel number(s).
    band : str
        One of GSM_BANDS: "P-GSM", "E-GSM", "R-GSM", "DCS1800", "PCS1900", "GSM850" (ranges overlap, so the
        band is always given).
    link : {"downlink", "uplink"}, optional
        Base-station transmit (what a handset measures) or mobile transmit.

    Returns
    -------
    float or ndarray
        MHz.

    Raises
    ------
    UnknownNameError
        An unknown band.
    ParameterError
        A channel outside the band.

    References
    ----------
    .. [1] 3GPP, GSM/EDGE Radio transmission and reception, Technical Specification 45.005, §2 (frequency bands
           and channel arrangement).
    .. [2] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007

    Examples
    --------
    >>> from mptrack.radio import arfcn_to_frequency
    >>> round(float(arfcn_to_frequency(764, "DCS1800")), 1)
    1855.6
    """
    spec, link = _band(band), _link(link)
    n = as_array("arfcn", arfcn)
    if not np.all(n == np.round(n)):
        raise DTypeError(f"arfcn: expected integer channel numbers, got {arfcn!r}")
    n = n.astype(np.int64)
    ok = spec.contains(n)
    if not np.all(ok):
        bad = n[~ok].flat[0] if n.ndim else int(n)
        ranges = ", ".join(f"{lo}-{hi}" for lo, hi, _, _ in spec.segments)
        raise ParameterError(f"arfcn: {bad} is not a {spec.name} channel (valid: {ranges})")
    f_up = np.zeros(n.shape)
    for lo, hi, n0, f0 in spec.segments:
        seg = (n >= lo) & (n <= hi)
        f_up = np.where(seg, f0 + 0.2 * (n - n0), f_up)
    f = f_up + (spec.duplex_mhz if link == "downlink" else 0.0)
    f = np.round(f, 1)  # the raster is exactly 0.1 MHz-representable; remove binary noise
    return f[()] if f.ndim == 0 else f


def frequency_to_arfcn(frequency_mhz, band: str, link: str = "downlink"):
    """The GSM channel of a carrier frequency (inverse of :func:`arfcn_to_frequency`).

    Parameters
    ----------
    frequency_mhz : float or array_like
    band : str
        One of GSM_BANDS.
    link : {"downlink", "uplink"}, optional

    Returns
    -------
    int or ndarray of int

    Raises
    ------
    ParameterError
        The frequency is not on the band's 200 kHz raster.
    """
    spec, link = _band(band), _link(link)
    f = as_array("frequency_mhz", frequency_mhz)
    f_up = f - (spec.duplex_mhz if link == "downlink" else 0.0)
    out = np.full(f.shape, -1, dtype=np.int64)
    for lo, hi, n0, f0 in spec.segments:
        n = np.rint((f_up - f0) / 0.2).astype(np.int64) + n0
        hit = (n >= lo) & (n <= hi) & (np.abs(f0 + 0.2 * (n - n0) - f_up) < 1e-6)
        out = np.where(hit & (out < 0), n, out)
    if np.any(out < 0):
        bad = f[out < 0].flat[0]
        raise ParameterError(f"frequency_mhz: {bad} MHz is not a {spec.name} {link} carrier")
    return out[()] if out.ndim == 0 else out


def band_of_arfcn(arfcn: int) -> str:
    """The GSM band of a channel number: 0-124 and 975-1023 E-GSM, 128-251 GSM850, 512-885 DCS1800.

    PCS1900 reuses 512-810: give ranges, or a frequency-consistent cell table, for PCS networks.

    Parameters
    ----------
    arfcn : int
        0 to 1023.

    Returns
    -------
    str
        A key of GSM_BANDS.
    """
    a = as_real("arfcn", arfcn, low=0, high=1023)
    if a != int(a):
        raise ParameterError(f"arfcn: expected an integer channel number, got {arfcn!r}")
    if a <= 124 or 975 <= a <= 1023:
        return "E-GSM"
    if 128 <= a <= 251:
        return "GSM850"
    return "DCS1800"
