"""Received signal strength -> path loss -> distance, inverting the path-loss models.

Log-linear models (L = A + B log10 d: free space, WI line of sight, Hata,
COST-231 Hata) are inverted in closed form; COST-231 Walfisch–Ikegami NLOS
(piecewise in d through k_a and the L0 floor, but strictly increasing) by
bisection in log-distance over the model's distance range, all values at once:
about 50 calls of the model on the whole array, whatever its size (a bracketed
scalar root per value, as scipy.optimize.brentq does, called the validated model
~15 times per value: 6 ms per fix, 32 s for a 5,400-row cellular log).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .._core.finiteness import require_finite
from .._core.validation import as_array, broadcast_shape, lookup
from ..errors import ParameterError
from . import _pathloss as pl
from ._validity import check_policy, check_range

__all__ = ["PATH_LOSS_MODELS", "path_loss", "distance_from_path_loss", "distance_from_rss", "path_loss_from_rss"]


@dataclass(frozen=True)
class _Model:
    fn: Callable
    distance_km: tuple[float, float]
    log_linear: bool
    has_policy: bool = True


#: Path-loss models by name, with their valid distance range (km).
PATH_LOSS_MODELS: dict[str, _Model] = {
    "free-space": _Model(pl.free_space_loss, (1e-6, 1e6), True, has_policy=False),
    "cost231-wi-los": _Model(pl.cost231_wi_los, (0.02, 5.0), True),
    "cost231-wi-nlos": _Model(pl.cost231_wi_nlos, (0.02, 5.0), False),
    "cost231-hata": _Model(pl.cost231_hata, (1.0, 20.0), True),
    "okumura-hata": _Model(pl.okumura_hata, (1.0, 20.0), True),
}


def _model(model: str, params: dict) -> _Model:
    """The named model, whose function takes the keyword parameters ``params``."""
    spec = lookup("model", model, PATH_LOSS_MODELS, what="path-loss model", fold=str)
    accepted = inspect.signature(spec.fn).parameters
    for name in params:
        if name not in accepted or name == "distance_km":
            known = [k for k in accepted if k != "distance_km"]
            raise ParameterError(f"{name}: not a parameter of the {model} model (its parameters: {', '.join(known)})")
    return spec


def path_loss(distance_km, model: str = "cost231-wi-nlos", **params):
    """Path loss of a named model (PATH_LOSS_MODELS).

    Parameters
    ----------
    distance_km : float or array_like
        Distance(s) (km), > 0.
    model : str, optional
        A key of PATH_LOSS_MODELS.
    **params
        The model's own parameters (h_base_m, frequency_mhz, ...).

    Returns
    -------
    float or ndarray
        dB.

    Raises
    ------
    UnknownNameError
        An unknown model.
    """
    return _model(model, params).fn(distance_km, **params)


def path_loss_from_rss(rss_dbm, tx_power_dbm, *, tx_gain_dbi=0.0, rx_gain_dbi=0.0, losses_db=0.0):
    """Path loss from a link budget: L = P_tx + G_tx + G_rx - losses - RSS (Bouzera et al. 2017,
    Appendix: Loss = Tx - Rx).

    Parameters
    ----------
    rss_dbm : float or array_like
        Received signal strength (dBm).
    tx_power_dbm : float or array_like
        Transmit power (dBm).
    tx_gain_dbi, rx_gain_dbi : float, optional
        Antenna gains (dBi).
    losses_db : float, optional
        Other losses (dB).

    Returns
    -------
    float or ndarray
        dB.

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    rss = as_array("rss_dbm", rss_dbm)
    terms = [as_array(name, value) for name, value in (("tx_power_dbm", tx_power_dbm), ("tx_gain_dbi", tx_gain_dbi),
                                                        ("rx_gain_dbi", rx_gain_dbi), ("losses_db", losses_db))]
    broadcast_shape(rss_dbm=rss, tx_power_dbm=terms[0], tx_gain_dbi=terms[1], rx_gain_dbi=terms[2],
                    losses_db=terms[3])
    out = np.asarray(terms[0] + terms[1] + terms[2] - terms[3] - rss)
    require_finite("the path loss", out, rss_dbm=rss, tx_power_dbm=terms[0])
    return out[()] if out.ndim == 0 else out


def distance_from_path_loss(loss_db, model: str = "cost231-wi-nlos", *, on_invalid: str = "raise", **params):
    """The distance at which a path-loss model predicts a given loss.

    Every model here is strictly increasing in distance, so the inverse is unique; log-linear models are
    inverted in closed form, WI NLOS by root finding (its parameters other than the loss must then be
    scalars).

    Parameters
    ----------
    loss_db : float or array_like
    model : str, optional
        A key of PATH_LOSS_MODELS.
    on_invalid : {"raise", "warn", "ignore"}, optional
        Outside the model's validity range: raise ParameterError, warn (ValidityWarning) or ignore.
        ``"warn"``/``"ignore"`` extrapolate (log-linear models exactly, WI NLOS within 1 m .. 100 km).
    **params
        The model's parameters.

    Returns
    -------
    float or ndarray
        km.

    Raises
    ------
    ParameterError
        With ``on_invalid="raise"``, a loss that no distance in the valid range explains (the message says
        which losses the model covers).
    """
    return _invert(as_array("loss_db", loss_db), model, on_invalid, "loss_db", params)


def _invert(loss: np.ndarray, model: str, on_invalid: str, label: str, params: dict):
    """distance_from_path_loss; ``label`` names the user's argument the loss came from."""
    spec = _model(model, params)
    check_policy(on_invalid)
    lo, hi = spec.distance_km
    kwargs = dict(params)
    if spec.has_policy:
        spec.fn(np.sqrt(lo * hi) if hi < 1e3 else 1.0, on_invalid=on_invalid, **kwargs)  # checks f, heights
        kwargs["on_invalid"] = "ignore"
    fn = lambda d: spec.fn(d, **kwargs)
    if spec.log_linear:
        a = np.asarray(fn(1.0))
        b = np.asarray(fn(10.0)) - a
        d = 10.0 ** ((loss - a) / b)
    else:
        for name, value in params.items():
            if np.ndim(value) != 0:
                raise ParameterError(f"{name}: must be a scalar for the {model} inverse, got shape {np.shape(value)}")
        blo, bhi = (lo, hi) if on_invalid == "raise" else (1e-3, 100.0)
        llo, lhi = float(fn(blo)), float(fn(bhi))
        flat = loss.ravel()
        outside = (flat < llo) | (flat > lhi)
        if outside.any():
            raise ParameterError(
                f"{label}: the loss {flat[outside][0]:.2f} dB is not explained by {model} for {blo:g}..{bhi:g} km "
                f"(it covers {llo:.2f}..{lhi:.2f} dB)")
        d = _bisect_log10(fn, flat, blo, bhi).reshape(loss.shape)
    lo_tol, hi_tol = lo * (1 - 1e-9), hi * (1 + 1e-9)  # round-off at the range edges
    if on_invalid == "raise" and np.any((d < lo_tol) | (d > hi_tol)):
        bad = np.asarray(d)[(d < lo_tol) | (d > hi_tol)].flat[0]
        llo, lhi = float(fn(lo)), float(fn(hi))
        raise ParameterError(
            f"{label}: no distance in {lo:g}..{hi:g} km explains it under {model} (needs {bad:.4g} km; "
            f"the model covers {llo:.2f}..{lhi:.2f} dB)")
    check_range(model, "distance_km", d, lo_tol, hi_tol, "km", on_invalid)
    d = np.asarray(d, dtype=float)
    return d[()] if d.ndim == 0 else d


#: Bisection stops when the bracket of log10(d) is this narrow: a relative error of d below 2.3e-14.
_LOG10_TOL = 1e-14


def _bisect_log10(fn: Callable, loss: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The d in [lo, hi] with fn(d) = loss for each value of ``loss`` (fn strictly increasing and
    vectorised, fn(lo) <= loss <= fn(hi)): bisection on log10(d) for all values together."""
    a = np.full(loss.shape, np.log10(lo))
    b = np.full(loss.shape, np.log10(hi))
    while loss.size and float(np.max(b - a)) > _LOG10_TOL:
        mid = 0.5 * (a + b)
        above = np.asarray(fn(10.0 ** mid)) > loss
        b = np.where(above, mid, b)
        a = np.where(above, a, mid)
    return 10.0 ** (0.5 * (a + b))


def distance_from_rss(rss_dbm, tx_power_dbm, model: str = "cost231-wi-nlos", *, tx_gain_dbi=0.0,
                      rx_gain_dbi=0.0, losses_db=0.0, on_invalid: str = "raise", **params):
    """Distance from a received signal strength and the transmit power.

    The path loss of the link budget (:func:`path_loss_from_rss`) inverted by
    :func:`distance_from_path_loss`.

    Parameters
    ----------
    rss_dbm : float or array_like
        Received signal strength (dBm).
    tx_power_dbm : float or array_like
        Transmit power (dBm).
    model : str, optional
        A key of PATH_LOSS_MODELS.
    tx_gain_dbi, rx_gain_dbi, losses_db : float, optional
        The link budget's gains and losses.
    on_invalid : {"raise", "warn", "ignore"}, optional
        Outside the model's validity range: raise ParameterError, warn (ValidityWarning) or ignore.
    **params
        The model's parameters.

    Returns
    -------
    float or ndarray
        km.

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007

    Examples
    --------
    The link of Table VIII of Bouzera et al. 2017 (DCS 1800 channel 764):

    >>> from mptrack.radio import arfcn_to_frequency, distance_from_rss
    >>> d = distance_from_rss(-69, 43, h_base_m=52, frequency_mhz=arfcn_to_frequency(764, "DCS1800"),
    ...                       on_invalid="ignore")
    >>> 0.1 < float(d) < 5.0
    True
    """
    loss = path_loss_from_rss(rss_dbm, tx_power_dbm, tx_gain_dbi=tx_gain_dbi, rx_gain_dbi=rx_gain_dbi,
                              losses_db=losses_db)
    return _invert(np.asarray(loss, dtype=float), model, on_invalid,
                   "rss_dbm (with tx_power_dbm, the gains and losses_db)", params)
