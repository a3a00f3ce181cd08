"""The finite-element (Fokker–Planck) grid filter for a 2-D state (Zhao et al. 2013, section 3).

Between measurements the density p(x, t) obeys the Kolmogorov forward
(Fokker–Planck) equation, eq. 3 with constant diffusion Q:

    ∂p/∂t = ∇·(½ Q ∇p − f p).

Update: Bayes' rule at the nodes (eqs. 24–26: nodal prior × likelihood),
normalised so the interpolant integrates to 1.  Moments (eq. 27) are exact
integrals of the interpolant: precomputed ∫φ_j, ∫φ_j x, ∫φ_j x x^T.

Grid placement (section 3.1): the box is the union of posterior mean ± c·σ
and predicted mean ± c·σ (sigma points through the noise-free flow, plus
Q·dt); the grid moves only when the required box leaves the current one or
becomes less than 40 % of its size, and the density is then re-interpolated
onto the new nodes (mass outside the new box is dropped and reported).

The grid and its elements are in :mod:`._fem_grid`, the densities in :mod:`._fem_density`, the time
schemes in :mod:`._fem_schemes`; this module runs the filter: a scheme's prediction, the update and the
mixture of grids.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .._core.filter_inputs import prepare_nonlinear
from .._core.finiteness import finite_result
from .._core.validation import as_array, check_int, check_positive
from ..errors import ConvergenceError, ParameterError, ShapeError
from ..result import FilterResult
from ._fem_density import FEMStep, GridDensity, GridMixture, _clip_normalise, _single
from ._fem_grid import FEMGrid
from ._fem_kernels import lattice_modes, second_difference_max
from ._fem_schemes import (
    _MARGIN,
    SCHEMES,
    _SHRINK,
    _Characteristics,
    _NodalRK4,
    _Propagator,
    _box,
    _compiled,
    default_substeps,
    _grid_shape,
)
from ._model import ContinuousDiscreteModel

__all__ = ["fem_filter", "fem_steps"]

_FOCUS = 4                  # refinement of the lattice that locates the posterior's modes (_split) ...
_LEVEL = 1e-3               # ... the modes: connected regions above this fraction of the maximum ...
_MIN_MODE = 1e-3            # ... holding more than this fraction of the mass; the lattice is g's own
_RESOLVED = 1.0            # ... where log p(z|x) has second differences below this between its nodes (_resolved)
_MAX_PARTS = 4              # parts of the mixture kept (the heaviest) ...
_MIN_PART = 1e-4            # ... with at least this fraction of the heaviest one's weight


def _bayes_update(grid: FEMGrid, p: np.ndarray, logl: np.ndarray, k: int):
    """Posterior nodal values (prior p × likelihood exp(logl), normalised) and the log evidence."""
    top = logl.max()
    post = p * np.exp(logl - top)
    evidence = grid.W0 @ post
    if not np.isfinite(evidence) or evidence <= 0.0:
        raise ConvergenceError(f"z: measurement {k} has no likelihood mass on the grid")
    post, _ = _clip_normalise(grid, post, "update")
    return post, float(top + np.log(evidence))


def _gaussian_on(grid: FEMGrid, m, P):
    D = grid.nodes - m
    w = np.linalg.solve(P, D.T).T
    return np.exp(-0.5 * np.sum(D * w, axis=1))


@finite_result("the FEM filter")
def fem_steps(model: ContinuousDiscreteModel, z, x0, P0, *, grid: tuple[int, int] = (20, 20),
              width: float = 4.0, substeps: int | None = None, scheme: str = "characteristics",
              stabilise: bool = False, box: tuple | None = None, splits: int = 4) -> Iterator[FEMStep]:
    """Run the FEM grid filter (Zhao et al. 2013) step by step.

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
        (2-D state.)
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped.
    x0 : array_like, shape (n,)
        The prior mean at time 0.
    P0 : array_like, shape (n, n)
        The prior covariance at time 0.
    grid : tuple of int, optional
        (n1, n2) elements per axis (Zhao et al. 2013: 20 x 20).
    width : float, optional
        Half-width of the box in posterior standard deviations (section 3.1).
    substeps : int, optional
        Time steps per dt (default :func:`fem_substeps`: 0.8 max(n1, n2), at least 8).
    scheme : {"characteristics", "sdirk2", "cn", "paper"}, optional
        ``"characteristics"``: Strang splitting of diffusion (SDIRK2) and transport along the drift's flow
        onto a grid placed around the predicted density, one grid per posterior mode; ``"sdirk2"``,
        ``"cn"``: the Galerkin drift-diffusion operator (it loses the state at low diffusion);
        ``"paper"``: the paper's scheme (eqs. 17-21, RK4 stages corrected; explicit, p = 0 on the
        boundary).  See docs/nonlinear.md.
    stabilise : bool, optional
        Add streamline diffusion (its O(h) smearing costs more accuracy on eq. 42 than it saves).
    box : tuple, optional
        ((lo1, lo2), (hi1, hi2)): a fixed rectangle instead of the moving grid; it must cover the prior
        mean +- 3 sigma, and its zero-flux boundary keeps all mass in: choose it to contain the track.
    splits : int, optional
        Strang steps per dt of the characteristics scheme.

    Yields
    ------
    FEMStep
        One per measurement: estimates, the prior and posterior densities (GridMixture), clipped and lost
        mass, regridding.

    Raises
    ------
    ConvergenceError
        A measurement's likelihood falls between the nodes, or the grid lost the density.

    References
    ----------
    .. [1] Y.-X. Zhao, L.-J. Chen and Y. Ma, "An FEM-based state estimation approach to nonlinear hybrid
           positioning systems", Mathematical Problems in Engineering, vol. 2013, Article ID 175425, 2013.
           doi:10.1155/2013/175425
    .. [2] A. N. Brooks and T. J. R. Hughes, "Streamline upwind/Petrov–Galerkin formulations for convection
           dominated flows with particular emphasis on the incompressible Navier–Stokes equations", Computer
           Methods in Applied Mechanics and Engineering, vol. 32, no. 1–3, pp. 199–259, 1982.
           doi:10.1016/0045-7825(82)90071-8
    """
    shape = _grid_shape(grid)
    adaptive = substeps is None  # the characteristics scheme then sizes its diffusion sub-steps itself
    if substeps is None:
        substeps = default_substeps(shape)
    z, m, P, substeps = prepare_nonlinear(model, z, x0, P0, substeps, definite=True,
                                          kinds=(ContinuousDiscreteModel,))
    if model.n != 2:
        raise ShapeError(f"model: the FEM grid filter is for a 2-D state, got n = {model.n}")
    width = check_positive("width", width)
    if scheme not in SCHEMES:
        raise ParameterError(f"scheme: expected one of {', '.join(map(repr, SCHEMES))}, got {scheme!r}")
    s0 = np.sqrt(np.diag(P))
    if box is not None:
        lo = as_array("box[0]", box[0], shape=(2,))
        hi = as_array("box[1]", box[1], shape=(2,))
        if np.any(m - 3 * s0 < lo) or np.any(m + 3 * s0 > hi):
            raise ParameterError(f"box: [{lo}, {hi}] does not cover the prior mean ± 3σ "
                                 f"[{m - 3 * s0}, {m + 3 * s0}]")
        g = FEMGrid(lo, hi, *shape)
    else:
        g = FEMGrid(*_box(model, m, P, width, 0.0), *shape)
    if scheme == "characteristics":
        yield from _characteristic_steps(model, z, m, P, g, width, None if adaptive else substeps, box is not None,
                                         check_int("splits", splits, minimum=1))
        return
    p, _ = _clip_normalise(g, _gaussian_on(g, m, P), "P0")
    prop = None
    for k in range(z.shape[0]):
        regridded, lost = False, 0.0
        if box is None:
            lo, hi = _box(model, m, P, width, 0.5 * float(np.min(g._h)))
            if not g.contains(lo, hi) or np.any(hi - lo < _SHRINK * (g.hi - g.lo)):
                margin = _MARGIN * (hi - lo)
                new = FEMGrid(lo - margin, hi + margin, *shape)
                q = g.evaluate(p, new.nodes)
                lost = max(0.0, 1.0 - float(new.W0 @ q)) if np.all(q >= 0) else 0.0
                g, prop, regridded = new, None, True
                p, _ = _clip_normalise(g, q, "re-interpolation")
        factorised = prop is None
        if factorised:
            prop = (_NodalRK4(g, model, substeps) if scheme == "paper"
                    else _Propagator(g, model, substeps, scheme, stabilise))
        q = prop(p)
        if scheme == "paper":  # not conservative: count what left through the boundary
            lost += max(0.0, 1.0 - float(g.W0 @ np.clip(q, 0.0, None)))
        p, clipped = _clip_normalise(g, q, "prediction")
        prior = _single(g, p)
        _, x_pred, P_pred = g.moments(p)
        ll = 0.0
        if not np.isnan(z[k]).all():
            p, ll = _bayes_update(g, p, model.log_likelihood(z[k], g.nodes), k)
        _, m, P = g.moments(p)
        yield FEMStep(k=k, prior=prior, posterior=_single(g, p), x_pred=x_pred, P_pred=P_pred, x=m, P=P,
                      loglik=ll, clipped=clipped, lost=lost, regridded=regridded, factorised=factorised)


def _galerkin_step(model, g, p, m, P, width, substeps, fixed):
    """One dt of the Galerkin SDIRK2 scheme on a box spanning the move (the fallback of the
    characteristics scheme)."""
    lost, regridded = 0.0, False
    if not fixed:
        lo, hi = _box(model, m, P, width, 0.5 * float(np.min(g._h)))
        margin = _MARGIN * (hi - lo)
        new = FEMGrid(lo - margin, hi + margin, g.n1, g.n2)
        q = g.evaluate(p, new.nodes)
        lost = max(0.0, 1.0 - float(new.W0 @ np.clip(q, 0.0, None)))
        g, regridded = new, True
        p, _ = _clip_normalise(g, q, "re-interpolation")
    p, clipped = _clip_normalise(g, _Propagator(g, model, substeps, "sdirk2", False)(p), "prediction")
    return g, p, True, regridded, lost, clipped


def _split(g: FEMGrid, p: np.ndarray, model, zk, width: float, logl: np.ndarray):
    """The prior cut into pieces around the modes of the posterior, each on its own grid, when the
    likelihood is much narrower than the prior (a range ring across a wide prior, or two arcs of
    it): prior × likelihood on g's node lattice if the likelihood is resolved there (_resolved;
    ``logl`` at g's nodes), else on a lattice _FOCUS times finer than g; its 8-connected regions
    above _LEVEL × its maximum holding more than _MIN_MODE of the mass are the modes; each mode's
    box is mean ± width·σ (intersected with g), overlapping boxes are merged.  One box not
    smaller than _SHRINK of g on some axis: g itself.  Otherwise the prior is re-interpolated
    onto a grid per box (g's element counts), so that the update resolves the likelihood.
    Returns [(grid, prior nodal values normalised on it, log of the prior mass kept)]; the last
    term belongs to the log evidence."""
    fine, d = g, np.clip(p, 0.0, None) * np.exp(logl - logl.max())
    if not np.all(np.isfinite(d)) or d.max() <= 0.0:
        return [(g, p, 0.0)]
    if not _resolved(g, d, logl):
        fine = FEMGrid._at(g.lo, g.hi, _FOCUS * g.n1, _FOCUS * g.n2)
        logl = _log_likelihood(model, zk, fine.nodes)
        d = np.clip(g.evaluate(p, fine.nodes), 0.0, None) * np.exp(logl - logl.max())
        if not np.all(np.isfinite(d)) or d.max() <= 0.0:
            return [(g, p, 0.0)]
    _, stats = lattice_modes(d, fine._top["lattice"], 2 * fine.n1 + 1, 2 * fine.n2 + 1, _LEVEL)
    mass = stats[:, 0]
    boxes = []
    for c in np.flatnonzero(mass > _MIN_MODE * mass.sum()):
        mu = stats[c, 1:3] / mass[c]                                   # in half-spacing lattice units
        sd = np.sqrt(np.maximum(stats[c, 3:5] / mass[c] - mu * mu, 0.0))
        mu, sd = fine.lo + 0.5 * fine._h * mu, 0.5 * fine._h * np.maximum(sd, 1.0)
        box = (np.maximum(mu - width * sd, g.lo), np.minimum(mu + width * sd, g.hi))
        for i in [i for i, b in enumerate(boxes) if np.all(b[0] <= box[1]) and np.all(box[0] <= b[1])][::-1]:
            other = boxes.pop(i)
            box = (np.minimum(box[0], other[0]), np.maximum(box[1], other[1]))
        boxes.append(box)
    if len(boxes) == 1 and np.any(boxes[0][1] - boxes[0][0] >= _SHRINK * (g.hi - g.lo)):
        return [(g, p, 0.0)]
    out = []
    for lo, hi in boxes:
        margin = _MARGIN * (hi - lo)
        new = FEMGrid._at(np.maximum(lo - margin, g.lo), np.minimum(hi + margin, g.hi), g.n1, g.n2)
        q = np.clip(g.evaluate(p, new.nodes), 0.0, None)
        kept = float(new.W0 @ q)
        if np.isfinite(kept) and kept > 0.0:
            out.append((new, q / kept, float(np.log(kept))))
    return out or [(g, p, 0.0)]


def _resolved(g: FEMGrid, d: np.ndarray, logl: np.ndarray) -> bool:
    """Whether g's nodes resolve the likelihood where the posterior lives: along the lattice lines
    (nodes half an element apart), at the nodes where prior × likelihood d exceeds _LEVEL of its
    maximum, the second difference of log p(z | x) is at most _RESOLVED in size (a Gaussian
    likelihood σ wide along the line has s²/σ² there, s the node spacing: σ ≥ 2s), so a finer
    lattice would find the same modes."""
    return second_difference_max(d, logl, *g._top["triples"], _LEVEL) <= _RESOLVED


def _log_likelihood(model, zk, X: np.ndarray) -> np.ndarray:
    """log p(z | x) at the points X (P, 2) (model.log_likelihood), compiled when the model has kernels."""
    compiled = _compiled(model)
    return model.log_likelihood(zk, X) if compiled is None else compiled.log_likelihood(zk, X)


@dataclass(eq=False)
class _Part:
    """One part of the filter's mixture (see GridMixture) while it runs."""

    w: float
    g: FEMGrid
    p: np.ndarray


def _merge(parts: list) -> list:
    """Parts whose grids overlap, merged onto one grid over the union of theirs (the nodal values
    of Σ wᵢ pᵢ there): the modes have met again, one grid is cheaper and resolves them."""
    parts = sorted(parts, key=lambda q: -q.w)
    out: list = []
    for part in parts:
        for i, o in enumerate(out):
            if np.all(part.g.lo <= o.g.hi) and np.all(o.g.lo <= part.g.hi):
                g = FEMGrid._at(np.minimum(part.g.lo, o.g.lo), np.maximum(part.g.hi, o.g.hi), o.g.n1, o.g.n2)
                w = o.w + part.w
                q = (o.w * o.g.evaluate(o.p, g.nodes) + part.w * part.g.evaluate(part.p, g.nodes)) / w
                out[i] = _Part(w, g, _clip_normalise(g, q, "merging")[0])
                break
        else:
            out.append(part)
    return out


def _mixture(parts) -> GridMixture:
    return GridMixture(tuple((q.w, GridDensity(q.g, q.p)) for q in parts))


def _characteristic_steps(model, z, m, P, g: FEMGrid, width, substeps, fixed: bool, splits: int
                          ) -> Iterator[FEMStep]:
    """fem_steps with scheme="characteristics" from the initial grid g (arguments validated).

    Each dt is cut into ``splits`` intervals τ, each a Strang step: diffusion over τ/2 (SDIRK2 on
    the current grid), transport along the characteristics onto a grid placed around the density
    predicted for t + τ, diffusion over τ/2 there.  The density is a mixture of parts on their
    own grids (one unless the posterior has separate modes, see _split); the Fokker–Planck
    equation is linear, so each part is predicted on its own, and parts whose grids come to
    overlap are merged.
    """
    scheme = _Characteristics(model, substeps, width, splits, fixed, (g.n1, g.n2))
    parts = [_Part(1.0, g, _clip_normalise(g, _gaussian_on(g, m, P), "P0")[0])]
    for k in range(z.shape[0]):
        factorised = regridded = False
        lost = clipped = 0.0
        for part in parts:
            try:
                part.g, part.p, f_, r_, l_, c_ = scheme.predict(part.g, part.p)
            except ConvergenceError:  # the characteristics left the grid (a stiff drift far out): Galerkin step
                _, m, P = part.g.moments(part.p)
                part.g, part.p, f_, r_, l_, c_ = _galerkin_step(model, part.g, part.p, m, P, width, substeps, fixed)
            factorised, regridded = factorised or f_, regridded or r_
            lost += part.w * l_
            clipped += part.w * c_
        if len(parts) > 1:
            parts = _merge(parts)
        prior = _mixture(parts)
        x_pred, P_pred = prior.moments()
        ll = 0.0
        if not np.isnan(z[k]).all():
            parts, ll, split = _update(parts, model, z[k], k, width, fixed)
            regridded = regridded or split
        m, P = (posterior := _mixture(parts)).moments()
        yield FEMStep(k=k, prior=prior, posterior=posterior, x_pred=x_pred, P_pred=P_pred, x=m, P=P, loglik=ll,
                      clipped=clipped, lost=lost, regridded=regridded, factorised=factorised)


def _update(parts: list, model, zk, k: int, width: float, fixed: bool):
    """Bayes' rule on every part, each first cut around its posterior modes (_split); parts with
    less than _MIN_PART of the heaviest one's weight are dropped, at most _MAX_PARTS kept.
    Returns (parts, log evidence, whether a part moved to a new grid)."""
    new, logs, moved = [], [], False
    for part in parts:
        logl = _log_likelihood(model, zk, part.g.nodes)
        pieces = [(part.g, part.p, 0.0)] if fixed else _split(part.g, part.p, model, zk, width, logl)
        for g, q, log_kept in pieces:
            try:
                q, lp = _bayes_update(g, q, logl if g is part.g else _log_likelihood(model, zk, g.nodes), k)
            except ConvergenceError:
                if len(parts) + len(pieces) > 2:  # another part holds the likelihood
                    continue
                raise
            moved = moved or g is not part.g
            new.append(_Part(part.w, g, q))
            logs.append(np.log(part.w) + log_kept + lp)
    if not new:
        raise ConvergenceError(f"z: measurement {k} has no likelihood mass on the grid")
    logs = np.array(logs)
    ll = float(logs.max() + np.log(np.sum(np.exp(logs - logs.max()))))
    w = np.exp(logs - ll)
    keep = [i for i in np.argsort(-w)[:_MAX_PARTS] if w[i] >= _MIN_PART * w.max()]
    for i in keep:
        new[i].w = w[i] / w[keep].sum()
    return [new[i] for i in keep], ll, moved


@finite_result("the FEM filter")
def fem_filter(model: ContinuousDiscreteModel, z, x0, P0, **options) -> FilterResult:
    """The FEM (Fokker-Planck) grid filter of Zhao et al. 2013 as a FilterResult.

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
        (2-D state.)
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped.
    x0 : array_like, shape (n,)
        The prior mean at time 0.
    P0 : array_like, shape (n, n)
        The prior covariance at time 0.
    **options
        As for :func:`fem_steps` (grid, width, substeps, scheme, stabilise, box, splits).

    Returns
    -------
    FilterResult
        Means, covariances, predictions and the log-likelihood (method "FEM").

    Raises
    ------
    ConvergenceError
        As :func:`fem_steps`.

    References
    ----------
    .. [1] Y.-X. Zhao, L.-J. Chen and Y. Ma, "An FEM-based state estimation approach to nonlinear hybrid
           positioning systems", Mathematical Problems in Engineering, vol. 2013, Article ID 175425, 2013.
           doi:10.1155/2013/175425
    """
    rows, loglik = [], 0.0
    for step in fem_steps(model, z, x0, P0, **options):  # the densities are not kept
        rows.append((step.x, step.P, step.x_pred, step.P_pred))
        loglik += step.loglik
    x, P, x_pred, P_pred = (np.array(col) for col in zip(*rows))
    return FilterResult(x=x, P=P, x_pred=x_pred, P_pred=P_pred, loglik=float(loglik), method="FEM")
