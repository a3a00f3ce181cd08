"""Registries: the linear filters by name, and the 12 implementations of Assimakis & Adam 2014, Table 1."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .._core.validation import lookup
from ..errors import UnknownNameError
from ..models import LinearGaussianModel, assimakis_model_a, assimakis_model_b
from ..result import FilterResult, mask_missing
from ..riccati import lainiotis_parameters, steady_state
from ._joint import join_results, per_axis
from ._kalman import kalman_filter
from ._lainiotis import lainiotis_filter
from ._steady import fir_filter, steady_state_filter

__all__ = ["FilterSpec", "FILTERS", "get_filter", "Implementation", "IMPLEMENTATIONS", "get_implementation"]

Runner = Callable[..., FilterResult]  # runner(z, x0=None, P0=None) -> FilterResult


@dataclass(frozen=True)
class FilterSpec:
    """A registered filter.  ``prepare(model)`` does the off-line work (Lainiotis
    parameters, Riccati solution) and returns ``runner(z, x0, P0)``, which does
    only the per-iteration work."""

    name: str
    system: str  # "time invariant" or "steady state"
    description: str
    prepare: Callable[[LinearGaussianModel], Runner]

    def run(self, model: LinearGaussianModel, z, x0=None, P0=None) -> FilterResult:
        """The filter on ``model`` and z from the prior x0, P0 (default zeros), with the one-step
        prediction x_pred, P_pred and the innovation, S and NIS of every step: the filter's own where
        it forms them (KF), else from the prediction of its previous estimate (:func:`one_step`)."""
        result = self.prepare(model)(z, x0, P0)
        n = model.n
        return one_step(result, model, z, np.zeros(n) if x0 is None else x0,
                        np.zeros((n, n)) if P0 is None else P0)


def one_step(result: FilterResult, model: LinearGaussianModel, z, x0, P0) -> FilterResult:
    """``result`` with x_pred, P_pred, innovation, S (and so nis) from the one-step prediction of the
    filter's own previous estimate: x(k/k-1) = F x(k-1/k-1), P(k/k-1) = F P(k-1/k-1) F^T + Q (x0, P0
    before the first), the innovation z(k) - H x(k/k-1), S = H P(k/k-1) H^T + R (NaN on the rows with
    a NaN, which these filters do not use).
    For the filters whose algebra forms none of them (LF, steady-state, FIR, joins); a result with an
    innovation already is returned as it is."""
    if result.innovation is not None:
        return result
    F, H, Q, R = model.F, model.H, model.Q, model.R
    x_prev = np.vstack([np.asarray(x0, dtype=float)[None], result.x[:-1]])
    P_prev = np.concatenate([np.asarray(P0, dtype=float)[None], result.P[:-1]])
    x_pred = x_prev @ F.T
    P_pred = F @ P_prev @ F.T + Q
    S = H @ P_pred @ H.T + R
    nu = np.asarray(z, dtype=float) - x_pred @ H.T
    nu[np.isnan(nu).any(axis=1)] = np.nan       # these filters only predict at a row with a NaN
    mask_missing(nu, S)
    return replace(result, x_pred=x_pred, P_pred=P_pred, innovation=nu, S=S)


def _prep_kf(model):
    # the registry keeps the papers' example default P(0/0) = 0 (kalman_filter itself requires P0)
    def run(z, x0=None, P0=None):
        if P0 is None and isinstance(model, LinearGaussianModel):
            P0 = np.zeros((model.n, model.n))
        return kalman_filter(model, z, x0, P0)
    return run


def _prep_lf(model):
    lp = lainiotis_parameters(model)
    return lambda z, x0=None, P0=None: lainiotis_filter(model, z, x0, P0, params=lp)


def _prep_ss(form):
    def prepare(model):
        ss = steady_state(model, "dare") if form == "kalman" else \
            steady_state(model, "per-step", form="lainiotis")
        return lambda z, x0=None, P0=None: steady_state_filter(model, z, x0, P0, steady=ss)
    return prepare


def _prep_join(name, first, second):
    def prepare(model):
        a, b = first(model), second(model)
        return lambda z, x0=None, P0=None: join_results(a(z, x0, P0), b(z, x0, P0), name)
    return prepare


def _prep_fir(model):
    ss = steady_state(model, "dare")
    return lambda z, x0=None, P0=None: fir_filter(model, z, x0, P0, steady=ss)


FILTERS: dict[str, FilterSpec] = {spec.name: spec for spec in (
    FilterSpec("KF", "time invariant", "Kalman filter, per-step Riccati (Assimakis & Adam 2014, eq. 4)", _prep_kf),
    FilterSpec("LF", "time invariant", "Lainiotis filter (Assimakis & Adam 2014, eqs. 5-7)", _prep_lf),
    FilterSpec("JKLF", "time invariant", "Join Kalman-Lainiotis filter, 50/50 average (eq. 8)",
               _prep_join("JKLF", _prep_kf, _prep_lf)),
    FilterSpec("SSKF", "steady state", "Steady-state Kalman filter (eqs. 9-11)", _prep_ss("kalman")),
    FilterSpec("SSLF", "steady state", "Steady-state Lainiotis filter (eqs. 12-14)", _prep_ss("lainiotis")),
    FilterSpec("JSSKLF", "steady state", "Join steady-state Kalman-Lainiotis filter (eq. 16)",
               _prep_join("JSSKLF", _prep_ss("kalman"), _prep_ss("lainiotis"))),
    FilterSpec("FIR", "steady state", "FIR steady-state filter, order M from ||A^M|| < eps (eq. 22)",
               _prep_fir),
)}


def get_filter(name: str) -> FilterSpec:
    """A registered filter by name (case-insensitive): KF, LF, SSKF, SSLF, FIR, ... (:data:`FILTERS`).

    Parameters
    ----------
    name : str

    Returns
    -------
    FilterSpec

    Raises
    ------
    UnknownNameError
        The name is not registered; the message lists the known names.
    """
    return lookup("name", name, FILTERS, what="filter", fold=str.upper)


@dataclass(frozen=True)
class Implementation:
    """One row of Table 1 of Assimakis & Adam 2014: a filter applied with model A (joint) or B (per axis).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).
    """

    number: int
    model: str  # "A" or "B"
    filter: str

    @property
    def name(self) -> str:
        return f"{self.filter}-{self.model}"

    @property
    def system(self) -> str:
        return FILTERS[self.filter].system

    def prepare(self, axes: int = 2, dt: float = 1.0, sigma_q2: float = 0.01, sigma_r2: float = 0.1,
                measurement: str = "printed") -> Runner:
        """Off-line preparation for the given set-up; returns runner(z (T, axes), x0, P0)."""
        spec = FILTERS[self.filter]
        if self.model == "A":
            return spec.prepare(assimakis_model_a(axes, dt, sigma_q2, sigma_r2, measurement))
        axis_model = assimakis_model_b(dt, sigma_q2, sigma_r2, measurement)
        runner = spec.prepare(axis_model)
        return lambda z, x0=None, P0=None: per_axis(lambda _m, zz, a, b: runner(zz, a, b),
                                                    axis_model, z, x0, P0)


IMPLEMENTATIONS: tuple[Implementation, ...] = tuple(
    Implementation(number=6 * i + j + 1, model=model, filter=name)
    for i, model in enumerate("AB")
    for j, name in enumerate(("KF", "LF", "JKLF", "SSKF", "SSLF", "JSSKLF")))


def get_implementation(key: int | str) -> Implementation:
    """One of the 12 implementations of Table 1 of Assimakis & Adam 2014.

    Parameters
    ----------
    key : int or str
        Its number (1-12) or name ("KF-A", "jssklf-b", ...; case-insensitive).

    Returns
    -------
    Implementation

    Raises
    ------
    UnknownNameError
        No such implementation.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).
    """
    for imp in IMPLEMENTATIONS:
        if key == imp.number or (isinstance(key, str) and key.upper() == imp.name.upper()):
            return imp
    names = ", ".join(f"{i.number}={i.name}" for i in IMPLEMENTATIONS)
    raise UnknownNameError(f"key: unknown implementation {key!r}; known: {names}")
