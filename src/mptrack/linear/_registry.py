"""Registries: the linear filters by name, and the 12 implementations of seed 000 Table 1."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .._validation import lookup
from ..errors import UnknownNameError
from ..models import LinearGaussianModel, assimakis_model_a, assimakis_model_b
from ..riccati import lainiotis_parameters, steady_state
from ._joint import join_results, per_axis
from ._kalman import kalman_filter
from ._lainiotis import lainiotis_filter
from ._result import FilterResult
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
        return self.prepare(model)(z, x0, P0)


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
    FilterSpec("KF", "time invariant", "Kalman filter, per-step Riccati (seed 000 eq. 4)", _prep_kf),
    FilterSpec("LF", "time invariant", "Lainiotis filter (seed 000 eqs. 5-7)", _prep_lf),
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
    return lookup("name", name, FILTERS, what="filter", fold=str.upper)


@dataclass(frozen=True)
class Implementation:
    """One row of seed 000 Table 1: a filter applied with model A (joint) or B (per axis)."""

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
    """An implementation by its Table 1 number (1-12) or name ("KF-A", "jssklf-b", ...)."""
    for imp in IMPLEMENTATIONS:
        if key == imp.number or (isinstance(key, str) and key.upper() == imp.name.upper()):
            return imp
    names = ", ".join(f"{i.number}={i.name}" for i in IMPLEMENTATIONS)
    raise UnknownNameError(f"key: unknown implementation {key!r}; known: {names}")
