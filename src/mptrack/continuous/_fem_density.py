"""Densities on FEM grids: one grid's nodal values (:class:`GridDensity`), a mixture of grids, one per
posterior mode (:class:`GridMixture`), and what a filter step yields (:class:`FEMStep`).

Negative overshoot: the Galerkin solution has negative nodal values where
the drift dominates the diffusion on the element scale (wiggles); after each prediction and re-interpolation they
are set to zero and the density renormalised (the removed mass is reported
as ``clipped``).  All nodal values are therefore ≥ 0 and ∫p = 1; the
serendipity interpolant between nodes can still dip slightly below zero
(its corner shape functions are negative inside the element).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConvergenceError, NotPositiveDefiniteError
from ._fem_grid import FEMGrid
from ._fem_kernels import clip_normalise

__all__ = ["GridDensity", "GridMixture", "FEMStep"]


@dataclass(frozen=True, eq=False)
class GridDensity:
    """A density on a grid: nodal values ``p`` of a FEMGrid (∫ interpolant = 1)."""

    grid: FEMGrid
    p: np.ndarray

    def __call__(self, X) -> np.ndarray:
        return self.grid.evaluate(self.p, X)


@dataclass(frozen=True, eq=False)
class GridMixture:
    """What the grid filter holds: Σᵢ wᵢ pᵢ, densities on one or more grids.

    parts  ((weight, GridDensity), ...), heaviest first, weights summing to 1.  One part
           unless the posterior split into separate modes (a range ring seen from an
           ambiguous bearing: each arc gets its own grid, see docs/nonlinear.md).
    """

    parts: tuple

    def __call__(self, X) -> np.ndarray:
        return sum(w * d(X) for w, d in self.parts)

    @property
    def lo(self) -> np.ndarray:
        """Lower corner of the rectangle covering every part's grid."""
        return np.min([d.grid.lo for _, d in self.parts], axis=0)

    @property
    def hi(self) -> np.ndarray:
        return np.max([d.grid.hi for _, d in self.parts], axis=0)

    def moments(self):
        """(mean (2,), covariance (2, 2)) of the mixture, exact integrals of the interpolants."""
        mom = [(w, *d.grid.moments(d.p)[1:]) for w, d in self.parts]
        mean = sum(w * m for w, m, _ in mom)
        return mean, sum(w * (C + np.outer(m - mean, m - mean)) for w, m, C in mom)


def _single(g: FEMGrid, p: np.ndarray) -> GridMixture:
    return GridMixture(((1.0, GridDensity(g, p)),))


@dataclass(frozen=True, eq=False)
class FEMStep:
    """One measurement step of the grid filter (what ``fem_steps`` yields)."""

    k: int                    # measurement index (time t = (k+1)·dt)
    prior: GridMixture
    posterior: GridMixture
    x_pred: np.ndarray
    P_pred: np.ndarray
    x: np.ndarray
    P: np.ndarray
    loglik: float
    clipped: float            # negative mass removed after the prediction
    lost: float               # mass outside the new box when the grid moved ("paper": + boundary outflow)
    regridded: bool           # the grid moved before this prediction
    factorised: bool          # ... and its operator was assembled and factorised (not re-used)


def _clip_normalise(grid: FEMGrid, p: np.ndarray, what: str):
    """(nodal values ≥ 0 integrating to 1, the negative mass removed): ``clip_normalise`` on a copy."""
    p = np.array(p, dtype=float)
    clipped, mass = clip_normalise(p, grid._top["V0"], float(grid._h[0] * grid._h[1]))
    _check_mass(mass, what)
    return p, clipped


def _check_mass(mass: float, what: str) -> None:
    if not (np.isfinite(mass) and mass > 0.0):
        raise ConvergenceError(f"{what}: the density on the grid has no positive mass left "
                               "(the grid does not cover it)")


def _raise(status: int, what: str) -> None:
    """The error of a compiled step's status (0: none)."""
    if status == 1:
        raise NotPositiveDefiniteError("P: the density's covariance lost positive semi-definiteness")
    if status == 2:
        _check_mass(0.0, what)
    if status == 3:
        raise ConvergenceError("grid filter: the diffusion's time-step matrix is not positive definite")
