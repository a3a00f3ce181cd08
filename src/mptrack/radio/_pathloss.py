"""Empirical path-loss models: free space, COST-231 Walfisch–Ikegami, COST-231 Hata, Okumura–Hata.

All functions broadcast over numpy arrays and return the basic transmission
loss in dB.  Units are in the argument names: distances in km, frequencies in
MHz, heights and widths in m, angles in degrees.  Each model checks its
validity range; ``on_invalid`` chooses what happens outside it ("raise" a
:class:`~mptrack.errors.ParameterError`, "warn" with a
:class:`ValidityWarning` and extrapolate, or "ignore").

Sources: COST Action 231 final report (Damosso & Correia, 1999), ch. 4.4
(Walfisch–Ikegami, eqs. 4.4.1–4.4.13) and 4.4.1 (COST-231 Hata); Hata (1980),
IEEE Trans. Veh. Technol. 29(3); 3GPP TR 25.996 §5.3.1 (urban micro NLOS);
Bouzera et al. (2017), Appendix, whose printed constants are
corrected as recorded in docs/errata.md.
"""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import as_array, as_real, broadcast_shape
from ..errors import ParameterError
from ._validity import check_policy, check_range

__all__ = [
    "free_space_loss",
    "wi_free_space_loss",
    "wi_orientation_loss",
    "wi_rooftop_to_street_loss",
    "wi_multiscreen_loss",
    "cost231_wi_los",
    "cost231_wi_nlos",
    "cost231_hata",
    "okumura_hata",
    "hata_mobile_correction",
]

_C_KM_PER_S = 299_792.458
WI_LIMITS = {"frequency_mhz": (800.0, 2000.0), "h_base_m": (4.0, 50.0), "h_mobile_m": (1.0, 3.0),
             "distance_km": (0.02, 5.0)}
HATA_LIMITS = {"h_base_m": (30.0, 200.0), "h_mobile_m": (1.0, 10.0), "distance_km": (1.0, 20.0)}
OKUMURA_HATA_FREQ = (150.0, 1500.0)
COST231_HATA_FREQ = (1500.0, 2000.0)
_UNITS = {"frequency_mhz": "MHz", "h_base_m": "m", "h_mobile_m": "m", "distance_km": "km"}


def _out(value):
    value = np.asarray(value, dtype=float)
    return value[()] if value.ndim == 0 else value


def _positive(name: str, value) -> np.ndarray:
    arr = as_array(name, value)
    if np.any(arr <= 0):
        raise ParameterError(f"{name}: expected finite values > 0, got {arr.ravel()[~(arr.ravel() > 0)][0]!r}")
    return arr


def _same_shape(**values) -> None:
    """The arguments broadcast together (ShapeError naming the first that does not)."""
    broadcast_shape(**{name: as_array(name, value) for name, value in values.items()})


def _check(model: str, limits: dict, on_invalid: str, **values) -> None:
    _same_shape(**values)
    check_policy(on_invalid)
    for name, value in values.items():
        lo, hi = limits[name]
        check_range(model, name, value, lo, hi, _UNITS[name], on_invalid)


@finite_result("the path loss")
def free_space_loss(distance_km, frequency_mhz):
    """Free-space basic transmission loss 20 log10(4 pi d f / c) (Friis): 32.45 + 20 log d + 20 log f.

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.

    Returns
    -------
    float or ndarray
        dB.
    """
    d = _positive("distance_km", distance_km)
    f = _positive("frequency_mhz", frequency_mhz)
    broadcast_shape(distance_km=d, frequency_mhz=f)
    return _out(20.0 * np.log10(4.0 * np.pi * d * f * 1e6 / _C_KM_PER_S))


@finite_result("the path loss")
def wi_free_space_loss(distance_km, frequency_mhz, *, constant_db: float = 32.4):
    """The COST-231 Walfisch-Ikegami free-space term L0 = 32.4 + 20 log d + 20 log f (COST 231 eq. 4.4.2).

    COST 231 (and 3GPP TR 25.996) use 32.4; the exact Friis constant 32.45 reproduces the paper's Table VIII
    (its appendix prints 32.44).

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    constant_db : float, optional

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    .. [2] 3GPP, Spatial channel model for Multiple Input Multiple Output (MIMO) simulations, Technical Report
           25.996, §5.3.1 (urban micro NLOS: COST-231 Walfisch–Ikegami).
    .. [3] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    d = _positive("distance_km", distance_km)
    f = _positive("frequency_mhz", frequency_mhz)
    broadcast_shape(distance_km=d, frequency_mhz=f)
    return _out(as_real("constant_db", constant_db) + 20.0 * np.log10(d) + 20.0 * np.log10(f))


def wi_orientation_loss(street_angle_deg):
    """Street-orientation correction L_ori(phi) (COST 231 eq. 4.4.5).

    -10 + 0.354 phi (phi < 35), 2.5 + 0.075 (phi - 35) (35 <= phi < 55), 4.0 - 0.114 (phi - 55)
    (55 <= phi <= 90); as in COST 231 the first piece ends 0.11 dB below the second.  The paper prints
    0.3574 and 0.1004; its own Table VIII is reproduced with 0.354 (docs/errata.md).

    Parameters
    ----------
    street_angle_deg : float or array_like
        The angle between the street and the incident wave, 0 to 90 degrees.

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    .. [2] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    phi = as_array("street_angle_deg", street_angle_deg)
    if not np.all(np.isfinite(phi)) or np.any((phi < 0) | (phi > 90)):
        raise ParameterError(f"street_angle_deg: expected angles in [0, 90] degrees, got {phi}")
    return _out(np.where(phi < 35, -10.0 + 0.354 * phi,
                         np.where(phi < 55, 2.5 + 0.075 * (phi - 35), 4.0 - 0.114 * (phi - 55))))


@finite_result("the path loss")
def wi_rooftop_to_street_loss(frequency_mhz, *, street_width_m, h_roof_m, h_mobile_m, street_angle_deg):
    """Roof-top-to-street diffraction and scatter loss L_rts = -16.9 - 10 log w + 10 log f
    + 20 log(h_roof - h_mobile) + L_ori(phi) (COST 231 eq. 4.4.4).

    Parameters
    ----------
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    street_width_m : float
    h_roof_m, h_mobile_m : float
        Heights (m), h_roof > h_mobile.
    street_angle_deg : float

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    """
    _same_shape(frequency_mhz=frequency_mhz, street_width_m=street_width_m, h_roof_m=h_roof_m,
                h_mobile_m=h_mobile_m, street_angle_deg=street_angle_deg)
    f = _positive("frequency_mhz", frequency_mhz)
    w = _positive("street_width_m", street_width_m)
    dhm = as_array("h_roof_m", h_roof_m) - as_array("h_mobile_m", h_mobile_m)
    if np.any(dhm <= 0):
        raise ParameterError(f"h_roof_m: must exceed h_mobile_m (mobile below roof level), got "
                             f"h_roof_m - h_mobile_m = {dhm}")
    return _out(-16.9 - 10.0 * np.log10(w) + 10.0 * np.log10(f) + 20.0 * np.log10(dhm)
                + wi_orientation_loss(street_angle_deg))


@finite_result("the path loss")
def wi_multiscreen_loss(distance_km, frequency_mhz, *, h_base_m, h_roof_m, building_sep_m,
                        city: str = "medium"):
    """Multi-screen diffraction loss L_msd = L_bsh + k_a + k_d log d + k_f log f - 9 log b (COST 231
    eqs. 4.4.6-4.4.10).

    With dh_b = h_base - h_roof: L_bsh = -18 log(1 + dh_b) if dh_b > 0 else 0; k_a = 54 (dh_b > 0),
    54 - 0.8 dh_b (d >= 0.5 km) or 54 - 0.8 dh_b d / 0.5 (d < 0.5 km); k_d = 18 (dh_b > 0) or
    18 - 15 dh_b / h_roof; k_f = -4 + 0.7 (f/925 - 1) (medium-sized city, suburban).

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    h_base_m, h_roof_m : float
        Heights (m).
    building_sep_m : float
        Building separation b (m).
    city : {"medium"}, optional

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    """
    d = _positive("distance_km", distance_km)
    f = _positive("frequency_mhz", frequency_mhz)
    b = _positive("building_sep_m", building_sep_m)
    h_roof = _positive("h_roof_m", h_roof_m)
    h_base = as_array("h_base_m", h_base_m)
    broadcast_shape(distance_km=d, frequency_mhz=f, building_sep_m=b, h_roof_m=h_roof, h_base_m=h_base)
    dhb = h_base - h_roof
    if city not in ("medium", "metropolitan"):
        raise ParameterError(f"city: expected 'medium' or 'metropolitan', got {city!r}")
    above = dhb > 0
    l_bsh = np.where(above, -18.0 * np.log10(1.0 + np.where(above, dhb, 0.0)), 0.0)
    k_a = np.where(above, 54.0, np.where(d >= 0.5, 54.0 - 0.8 * dhb, 54.0 - 0.8 * dhb * d / 0.5))
    k_d = np.where(above, 18.0, 18.0 - 15.0 * dhb / h_roof)
    k_f = -4.0 + (0.7 if city == "medium" else 1.5) * (f / 925.0 - 1.0)
    return _out(l_bsh + k_a + k_d * np.log10(d) + k_f * np.log10(f) - 9.0 * np.log10(b))


@finite_result("the path loss")
def cost231_wi_nlos(distance_km, frequency_mhz, *, h_base_m, h_mobile_m=1.5, h_roof_m=15.0,
                    street_width_m=25.0, building_sep_m=50.0, street_angle_deg=30.0,
                    city: str = "medium", free_space_constant_db: float = 32.4, on_invalid: str = "warn"):
    """COST-231 Walfisch-Ikegami non-line-of-sight loss (COST 231 eq. 4.4.1; Bouzera et al. 2017,
    Appendix).

    L = L0 + L_rts + L_msd if L_rts + L_msd > 0, else L0.  Valid for 800 <= f <= 2000 MHz,
    4 <= h_base <= 50 m, 1 <= h_mobile <= 3 m, 0.02 <= d <= 5 km.  The defaults are the paper's drive
    test (b = 50 m, w = b/2, phi = 30 degrees, h_roof = 15 m).

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    h_base_m : float
    h_mobile_m, h_roof_m : float, optional
    street_width_m, building_sep_m : float, optional
    street_angle_deg : float, optional
    city : {"medium"}, optional
    free_space_constant_db : float, optional
        The constant of L0 (32.4 in COST 231; 32.45 reproduces the paper's Table VIII).
    on_invalid : {"raise", "warn", "ignore"}, optional
        Outside the model's validity range: raise ParameterError, warn (ValidityWarning) or ignore.

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    .. [2] 3GPP, Spatial channel model for Multiple Input Multiple Output (MIMO) simulations, Technical Report
           25.996, §5.3.1 (urban micro NLOS: COST-231 Walfisch–Ikegami).
    .. [3] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    _check("COST-231 Walfisch-Ikegami", WI_LIMITS, on_invalid, distance_km=distance_km,
           frequency_mhz=frequency_mhz, h_base_m=h_base_m, h_mobile_m=h_mobile_m)
    _same_shape(h_roof_m=h_roof_m, street_width_m=street_width_m, building_sep_m=building_sep_m,
                street_angle_deg=street_angle_deg, distance_km=distance_km, frequency_mhz=frequency_mhz,
                h_base_m=h_base_m, h_mobile_m=h_mobile_m)
    _positive("h_base_m", h_base_m)
    _positive("h_mobile_m", h_mobile_m)
    l0 = wi_free_space_loss(distance_km, frequency_mhz, constant_db=free_space_constant_db)
    extra = (wi_rooftop_to_street_loss(frequency_mhz, street_width_m=street_width_m, h_roof_m=h_roof_m,
                                       h_mobile_m=h_mobile_m, street_angle_deg=street_angle_deg)
             + wi_multiscreen_loss(distance_km, frequency_mhz, h_base_m=h_base_m, h_roof_m=h_roof_m,
                                   building_sep_m=building_sep_m, city=city))
    return _out(np.where(extra > 0, l0 + extra, l0))


@finite_result("the path loss")
def cost231_wi_los(distance_km, frequency_mhz, *, on_invalid: str = "warn"):
    """COST-231 Walfisch-Ikegami line-of-sight (street canyon) loss 42.6 + 26 log d + 20 log f
    (COST 231 eq. 4.4.13; the paper prints 42.64).

    Valid for d >= 0.02 km, 800-2000 MHz.

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    on_invalid : {"raise", "warn", "ignore"}, optional
        Outside the model's validity range: raise ParameterError, warn (ValidityWarning) or ignore.

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    .. [2] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    check_policy(on_invalid)
    _same_shape(distance_km=distance_km, frequency_mhz=frequency_mhz)
    check_range("COST-231 WI LOS", "distance_km", distance_km, 0.02, 5.0, "km", on_invalid)
    check_range("COST-231 WI LOS", "frequency_mhz", frequency_mhz, 800.0, 2000.0, "MHz", on_invalid)
    d = _positive("distance_km", distance_km)
    f = _positive("frequency_mhz", frequency_mhz)
    return _out(42.6 + 26.0 * np.log10(d) + 20.0 * np.log10(f))


@finite_result("the path loss")
def hata_mobile_correction(frequency_mhz, h_mobile_m, *, large_city: bool = False):
    """Hata's mobile-antenna correction a(h_m) (Hata 1980, eqs. 4a-4b).

    Small/medium city: (1.1 log f - 0.7) h_m - (1.56 log f - 0.8); large city: 8.29 (log 1.54 h_m)^2 - 1.1
    for f <= 300 MHz, 3.2 (log 11.75 h_m)^2 - 4.97 above.

    Parameters
    ----------
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    h_mobile_m : float or array_like
    large_city : bool, optional

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] M. Hata, "Empirical formula for propagation loss in land mobile radio services", IEEE Transactions on
           Vehicular Technology, vol. 29, no. 3, pp. 317–325, 1980. doi:10.1109/T-VT.1980.23859
    """
    f = _positive("frequency_mhz", frequency_mhz)
    hm = _positive("h_mobile_m", h_mobile_m)
    if large_city:
        return _out(np.where(f <= 300.0, 8.29 * np.log10(1.54 * hm) ** 2 - 1.1,
                             3.2 * np.log10(11.75 * hm) ** 2 - 4.97))
    lf = np.log10(f)
    return _out((1.1 * lf - 0.7) * hm - (1.56 * lf - 0.8))


def _hata_loss(model, freq_limits, on_invalid, distance_km, frequency_mhz, h_base_m, h_mobile_m, a, b,
               large_city=False):
    """A + B log f - 13.82 log h_b - a(h_m) + (44.9 - 6.55 log h_b) log d after the validity checks."""
    _check(model, {**HATA_LIMITS, "frequency_mhz": freq_limits}, on_invalid,
           distance_km=distance_km, frequency_mhz=frequency_mhz, h_base_m=h_base_m, h_mobile_m=h_mobile_m)
    d = _positive("distance_km", distance_km)
    f = _positive("frequency_mhz", frequency_mhz)
    hb = _positive("h_base_m", h_base_m)
    a_hm = hata_mobile_correction(f, h_mobile_m, large_city=large_city)
    return a + b * np.log10(f) - 13.82 * np.log10(hb) - a_hm + (44.9 - 6.55 * np.log10(hb)) * np.log10(d), f


@finite_result("the path loss")
def okumura_hata(distance_km, frequency_mhz, *, h_base_m, h_mobile_m=1.5, environment: str = "urban",
                 on_invalid: str = "warn"):
    """Okumura-Hata loss (Hata 1980, eqs. 3-6).

    L_u = 69.55 + 26.16 log f - 13.82 log h_b - a(h_m) + (44.9 - 6.55 log h_b) log d.  Valid for
    150 <= f <= 1500 MHz, 30 <= h_b <= 200 m, 1 <= h_m <= 10 m, 1 <= d <= 20 km.

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    h_base_m : float
    h_mobile_m : float, optional
    environment : {"urban", "urban-large", "suburban", "rural"}, optional
        Small/medium city a(h_m), large-city a(h_m), L_u - 2 (log(f/28))^2 - 5.4, or open area
        L_u - 4.78 (log f)^2 + 18.33 log f - 40.94.
    on_invalid : {"raise", "warn", "ignore"}, optional
        Outside the model's validity range: raise ParameterError, warn (ValidityWarning) or ignore.

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] M. Hata, "Empirical formula for propagation loss in land mobile radio services", IEEE Transactions on
           Vehicular Technology, vol. 29, no. 3, pp. 317–325, 1980. doi:10.1109/T-VT.1980.23859
    """
    envs = ("urban", "urban-large", "suburban", "rural")
    if environment not in envs:
        raise ParameterError(f"environment: expected one of {envs}, got {environment!r}")
    # suburban and open-area corrections are applied to the small/medium-city urban loss (Hata eqs. 5, 6)
    loss, f = _hata_loss("Okumura-Hata", OKUMURA_HATA_FREQ, on_invalid, distance_km, frequency_mhz, h_base_m,
                         h_mobile_m, 69.55, 26.16, large_city=environment == "urban-large")
    if environment == "suburban":
        loss = loss - 2.0 * np.log10(f / 28.0) ** 2 - 5.4
    elif environment == "rural":
        loss = loss - 4.78 * np.log10(f) ** 2 + 18.33 * np.log10(f) - 40.94
    return _out(loss)


@finite_result("the path loss")
def cost231_hata(distance_km, frequency_mhz, *, h_base_m, h_mobile_m=1.5, city: str = "medium",
                 on_invalid: str = "warn"):
    """COST-231 Hata loss L = 46.3 + 33.9 log f - 13.82 log h_b - a(h_m) + (44.9 - 6.55 log h_b) log d + C_m.

    Valid for 1500 <= f <= 2000 MHz, 30 <= h_b <= 200 m, 1 <= h_m <= 10 m, 1 <= d <= 20 km.

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    frequency_mhz : float or array_like
        Carrier frequency (MHz), > 0.
    h_base_m : float
    h_mobile_m : float, optional
    city : {"medium", "metropolitan"}, optional
        C_m = 0 dB (medium city, suburban) or 3 dB.
    on_invalid : {"raise", "warn", "ignore"}, optional
        Outside the model's validity range: raise ParameterError, warn (ValidityWarning) or ignore.

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] E. Damosso and L. M. Correia (eds.), Digital Mobile Radio Towards Future Generation Systems: COST 231
           Final Report, European Commission, EUR 18957, 1999, ch. 4 (the COST-231 Hata and Walfisch–Ikegami
           models).
    """
    if city not in ("medium", "metropolitan"):
        raise ParameterError(f"city: expected 'medium' or 'metropolitan', got {city!r}")
    loss, _ = _hata_loss("COST-231 Hata", COST231_HATA_FREQ, on_invalid, distance_km, frequency_mhz, h_base_m,
                         h_mobile_m, 46.3, 33.9)
    return _out(loss + (0.0 if city == "medium" else 3.0))
