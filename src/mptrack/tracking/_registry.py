"""Registries of what ``mptrack track`` can run, by name: motion models, position-fix filters
and cellular (range) filters."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .._core.validation import lookup
from ..linear import FILTERS as LINEAR_FILTERS
from ..models import ContinuousLinearModel, constant_acceleration_continuous, constant_velocity_continuous
from ..cellular import ekf_ranges, fcs_ranges, fekf_ranges, locate_cells

__all__ = ["MotionModel", "MODELS", "get_model", "FIX_FILTERS", "get_fix_filter", "CELL_METHODS",
           "get_cell_method", "DEFAULT_SIGMA_M"]

#: Fix noise (1-sigma per axis, m) used where it can be neither estimated nor was given.
DEFAULT_SIGMA_M = 5.0


@dataclass(frozen=True)
class MotionModel:
    """A 2-D continuous motion model: ``build(q, sigma_r2)``; ``order`` states per axis
    (2 = position, velocity; 3 = + acceleration); ``prior_sigmas`` the 1-sigma spread of the
    unmeasured states at start (m/s, m/s^2); ``q_unit`` the unit of the noise density q;
    ``default_q`` the density used where it can be neither estimated nor was given."""

    name: str
    description: str
    build: Callable[[float, float], ContinuousLinearModel]
    order: int
    prior_sigmas: tuple[float, ...]
    q_unit: str
    default_q: float

    @property
    def prior_variances(self):
        """(order,) prior variances per axis: position (set from the first fix), then prior_sigmas^2."""
        import numpy as np

        return np.r_[0.0, np.square(self.prior_sigmas)]


MODELS: dict[str, MotionModel] = {m.name: m for m in (
    MotionModel("cv", "constant velocity, white-noise acceleration (Assimakis et al. 2016, sec. 2.1)",
                lambda q, r: constant_velocity_continuous(q, axes=2, sigma_r2=r), 2, (30.0,), "m^2/s^3", 2.0),
    MotionModel("ca", "constant acceleration, white-noise jerk (Assimakis et al. 2016, sec. 2.2)",
                lambda q, r: constant_acceleration_continuous(q, axes=2, sigma_r2=r), 3, (30.0, 5.0),
                "m^2/s^5", 0.1),
)}

#: Position-fix filters: "kf" is the gated irregular-time KF; the others are the registered linear
#: filters of :data:`mptrack.linear.FILTERS`, run on the track resampled to a regular grid.
FIX_FILTERS: dict[str, str] = {
    "kf": "Kalman filter at the fixes' own (irregular) times, exact discretisation per interval, NIS gating",
    **{name.lower(): f"{spec.description}; on a regular grid at the median interval, no gating"
       for name, spec in LINEAR_FILTERS.items() if name != "KF"},
}

#: Cellular methods: "locate" places each scan as a geolocation request (mptrack.cellular.locate_cells); the
#: range filters of Bouzera et al. (2017) filter one range per site over time.
CELL_METHODS: dict[str, Callable] = {"locate": locate_cells, "ekf": ekf_ranges, "fekf": fekf_ranges,
                                     "fcs": fcs_ranges}


def get_model(name: str) -> MotionModel:
    """A motion model of ``mptrack track`` by name (:data:`MODELS`: cv, ca).

    Parameters
    ----------
    name : str

    Returns
    -------
    MotionModel

    Raises
    ------
    UnknownNameError
        The name is not registered; the message lists the known names.
    """
    return lookup("name", name, MODELS, what="motion model")


def get_fix_filter(name: str) -> str:
    """The canonical name of a position-fix filter (:data:`FIX_FILTERS`: kf, or a linear filter).

    Parameters
    ----------
    name : str

    Returns
    -------
    str

    Raises
    ------
    UnknownNameError
        The name is not registered; the message lists the known names.
    """
    lookup("name", name, FIX_FILTERS, what="position-fix filter")
    return name.lower()


def get_cell_method(name: str) -> Callable:
    """A cellular tracking method by name (:data:`CELL_METHODS`: ekf, fekf, fcs).

    Parameters
    ----------
    name : str

    Returns
    -------
    callable

    Raises
    ------
    UnknownNameError
        The name is not registered; the message lists the known names.
    """
    return lookup("name", name, CELL_METHODS, what="cellular method")
