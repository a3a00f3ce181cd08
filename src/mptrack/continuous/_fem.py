"""The finite-element (Fokker–Planck) grid filter for a 2-D state (Zhao et al. 2013, section 3).

Between measurements the density p(x, t) obeys the Kolmogorov forward
(Fokker–Planck) equation, eq. 3 with constant diffusion Q:

    ∂p/∂t = ∇·(½ Q ∇p − f p).

Space: 8-node serendipity quadrilaterals (eqs. 7–14) on a rectangle of
n1 × n2 equal elements; Galerkin weak form with a zero-flux (reflecting)
boundary, so the semi-discrete system M dp/dt = A p,

    M_ij = ∫ φ_i φ_j,   A_ij = −½ ∫ ∇φ_i · Q ∇φ_j + ∫ (f · ∇φ_i) φ_j,

conserves ∫p exactly (Σ_i φ_i = 1).  Element matrices come from 3 × 3 Gauss
quadrature; the geometry-free data of an n1 × n2 grid is computed once.

Default time scheme ("characteristics"): each dt is cut into ``splits``
Strang steps — diffusion over τ/2 by SDIRK2 (the diffusion-only Galerkin
operator), the density carried by the drift's flow Φ_τ onto a grid placed
around the density predicted for t + τ (the Galerkin projection of the
pushed-forward density, ∫φ_j p(t+τ) = ∫φ_j(Φ_τ(y)) p(t, y) dy: mass, mean and
covariance conserved; _push), diffusion over τ/2 there.  The grid only has to
cover the density, not the path it travels, and nothing oscillates when the
drift dominates: with little diffusion the Galerkin schemes below need a box
spanning the whole move, elements wider than the density, and lose the state
(docs/nonlinear.md).  With a model's compiled kernels each transport (grid
placement, node flow, quadrature, deposit, mass solve) is one compiled call
(_Characteristics.transport); the diffusion's factorisations are kept and
re-used across grids of nearby element sizes (_Characteristics).  Separate posterior modes (a range ring seen from an
ambiguous bearing) get a grid each: the filter carries a mixture of parts
(GridMixture), predicted independently since the equation is linear (_split,
_update, _merge).

The paper's own scheme ("paper", _NodalRK4): the strong form F(p) = Δ₁p + Δ₂·∇p + ½Δ₃:∇²p
(eqs. 17–19, the ½ of eq. 17 restored) at the nodes, by central differences on the node
lattice, stepped by classical RK4 (eqs. 20–21 with the stages corrected to F(p + τ/2·K₁) etc.)
with as many steps per dt as its stability needs; p = 0 on the boundary.  It converges with
order 2 on a linear-Gaussian model but, being a central scheme, wiggles and loses accuracy
when the drift dominates the diffusion on the element scale (docs/nonlinear.md).

Galerkin time schemes ("sdirk2", "cn"): the paper's RK4 stages (eq. 21) are wrong (K2 = F(p) + Δt/2·K1), and
explicit RK4 would need τ ≲ h²/‖Q‖ anyway.  We use ``substeps`` steps per dt
of the L-stable, second-order SDIRK2 (Alexander; γ = 1 − 1/√2), whose two
stages both solve with M − γτA: one LU (a single-precision LAPACK band LU
with compiled sub-steps on small grids, SuperLU on large ones: _factorise)
is reused across sub-steps and across measurement steps while the grid does
not move.  Crank–Nicolson is available (``scheme="cn"``): as accurate on
eq. 42 and cheaper, but not L-stable, so more negative mass to clip after a
sharp update (docs/design.md).

Update: Bayes' rule at the nodes (eqs. 24–26: nodal prior × likelihood),
normalised so the interpolant integrates to 1.  Moments (eq. 27) are exact
integrals of the interpolant: precomputed ∫φ_j, ∫φ_j x, ∫φ_j x x^T.

Negative overshoot: the Galerkin solution has negative nodal values where
the drift dominates the diffusion on the element scale (wiggles); after each prediction and re-interpolation they
are set to zero and the density renormalised (the removed mass is reported
as ``clipped``).  All nodal values are therefore ≥ 0 and ∫p = 1; the
serendipity interpolant between nodes can still dip slightly below zero
(its corner shape functions are negative inside the element).

Grid placement (section 3.1): the box is the union of posterior mean ± c·σ
and predicted mean ± c·σ (sigma points through the noise-free flow, plus
Q·dt); the grid moves only when the required box leaves the current one or
becomes less than 40 % of its size, and the density is then re-interpolated
onto the new nodes (mass outside the new box is dropped and reported).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
import scipy.linalg.lapack
import scipy.sparse
import scipy.sparse.linalg

from .._core.validation import (
    as_array,
    broadcast_shape,
    check_allocation,
    check_int,
    check_positive,
    finite_result,
    require_finite,
)
from ..errors import ConvergenceError, NotPositiveDefiniteError, ParameterError, ShapeError
from ..result import FilterResult
from .._core.filter_inputs import prepare_nonlinear
from .._core.unscented import sigma_points
from .._core.unscented import weights as _sigma_weights
from ._fem_kernels import (
    band_cn,
    band_sdirk2,
    band_solve,
    clip_normalise,
    deposit,
    diffuse_kept,
    element_band_cholesky,
    flow_points,
    flow_sites,
    grid_moments,
    interpolate,
    lattice_modes,
    mass_solve,
    next_grid,
    predict_dt,
    predicted_box,
    second_difference_max,
    sigma_points_2d,
    stiffness_unit,
    transport_deposit,
    transport_split,
)
from ._kernels import compiled_model
from ._model import ContinuousDiscreteModel, rk4_flow

__all__ = ["FEMGrid", "GridDensity", "GridMixture", "FEMStep", "fem_filter", "fem_steps", "fem_substeps",
           "shape_functions", "SCHEMES"]

# reference element nodes: corners, then mid-sides (bottom, right, top, left)
_XI = np.array([-1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0, -1.0])
_ETA = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0])
# their offsets on the half-spacing lattice of an element
_DI = np.array([0, 2, 2, 0, 1, 2, 1, 0])
_DJ = np.array([0, 0, 2, 2, 0, 1, 2, 1])
_GAUSS3 = (np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)]), np.array([5.0, 8.0, 5.0]) / 9.0)


@finite_result("the shape functions")
def shape_functions(xi, eta):
    """Serendipity shape functions N (…, 8) and derivatives dN/dξ, dN/dη (Zhao et al. 2013, eqs. 11–12).

    Corners: N = ¼(1+ξξᵢ)(1+ηηᵢ)(ξξᵢ+ηηᵢ−1); mid-sides: ½(1−ξ²)(1+ηηᵢ) or ½(1+ξξᵢ)(1−η²).

    References
    ----------
    .. [1] Y.-X. Zhao, L.-J. Chen and Y. Ma, "An FEM-based state estimation approach to nonlinear hybrid
           positioning systems", Mathematical Problems in Engineering, vol. 2013, Article ID 175425, 2013.
           doi:10.1155/2013/175425
    """
    xi = as_array("xi", xi)[..., None]
    eta = as_array("eta", eta)[..., None]
    broadcast_shape(xi=xi, eta=eta)
    a, b = 1.0 + xi * _XI, 1.0 + eta * _ETA
    N = np.empty(np.broadcast_shapes(xi.shape, eta.shape)[:-1] + (8,))
    dx, dy = np.empty_like(N), np.empty_like(N)
    c = slice(0, 4)
    N[..., c] = 0.25 * a[..., c] * b[..., c] * (xi * _XI[c] + eta * _ETA[c] - 1.0)
    dx[..., c] = 0.25 * _XI[c] * b[..., c] * (2.0 * xi * _XI[c] + eta * _ETA[c])
    dy[..., c] = 0.25 * _ETA[c] * a[..., c] * (xi * _XI[c] + 2.0 * eta * _ETA[c])
    s = [4, 6]  # ξᵢ = 0
    N[..., s] = 0.5 * (1.0 - xi * xi) * b[..., s]
    dx[..., s] = -xi * b[..., s]
    dy[..., s] = 0.5 * (1.0 - xi * xi) * _ETA[s]
    s = [5, 7]  # ηᵢ = 0
    N[..., s] = 0.5 * a[..., s] * (1.0 - eta * eta)
    dx[..., s] = 0.5 * _XI[s] * (1.0 - eta * eta)
    dy[..., s] = -eta * a[..., s]
    return N, dx, dy


@functools.lru_cache(maxsize=16)
def _topology(n1: int, n2: int):
    """Geometry-free data of an n1 × n2 grid, in lattice units (an element is 1 × 1).

    conn     (E, 8) node indices of each element (corners, then mid-sides)
    node_id  (2n1+1, 2n2+1) node index at each half-spacing lattice point (−1 at element centres)
    lattice  (N, 2) half-spacing lattice coordinates of the nodes
    uq       (E, 9, 2) the 3 × 3 Gauss points of every element in lattice units
    V0, V1, V2  ∫φ_j du, ∫φ_j u du, ∫φ_j u uᵀ du (as (N,), (N, 2), (N, 3): uu, uv, vv)
    csc      (indices, indptr, slot): the CSC pattern and where each (e, a, b) entry goes
    band     (width, slot): LAPACK band storage (natural node order) and where each entry goes
    triples  (a, b, c): consecutive nodes along the even lattice rows and columns (b in the middle)
    G        (3, 8, 8) ∫ ∂_dφ ∂_eφᵀ for (d, e) = (0, 0), (0, 1), (1, 1): the diffusion's element stiffness
    """
    L1, L2 = 2 * n1 + 1, 2 * n2 + 1
    ii, jj = np.meshgrid(np.arange(L1), np.arange(L2), indexing="ij")
    is_node = ~((ii % 2 == 1) & (jj % 2 == 1))
    node_id = np.full((L1, L2), -1)
    node_id[is_node] = np.arange(is_node.sum())
    e1, e2 = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
    conn = node_id[2 * e1.reshape(-1, 1) + _DI, 2 * e2.reshape(-1, 1) + _DJ]  # (E, 8)
    N = int(is_node.sum())
    rows = np.broadcast_to(conn[:, :, None], conn.shape + (8,)).ravel()
    cols = np.broadcast_to(conn[:, None, :], conn.shape + (8,)).ravel()
    keys, slot = np.unique(cols * N + rows, return_inverse=True)  # CSC order: column-major
    indices = (keys % N).astype(np.int32)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(keys // N, minlength=N))]).astype(np.int32)
    width = int(np.max(np.abs(rows - cols)))
    # dgbtrf layout: A[i, j] at ab[2w + i − j, j] of a (3w+1, N) Fortran array, i.e. flat j·(3w+1) + 2w + i − j
    band_slot = cols * (3 * width + 1) + 2 * width + rows - cols
    # three consecutive nodes along the full lattice lines (the even rows and columns: half an element apart)
    full = (ii % 2 == 0) & (jj > 0) & (jj < L2 - 1), (jj % 2 == 0) & (ii > 0) & (ii < L1 - 1)
    triples = tuple(np.concatenate(t) for t in zip(
        (node_id[ii[full[0]], jj[full[0]] - 1], node_id[full[0]], node_id[ii[full[0]], jj[full[0]] + 1]),
        (node_id[ii[full[1]] - 1, jj[full[1]]], node_id[full[1]], node_id[ii[full[1]] + 1, jj[full[1]]])))
    lattice = np.stack([ii[is_node], jj[is_node]], axis=-1)
    g, w = _GAUSS3
    gx, gy = np.meshgrid(g, g, indexing="ij")
    phi, dxi, deta = shape_functions(gx.ravel(), gy.ravel())  # (9, 8)
    wq = np.outer(w, w).ravel() / 4.0  # weights on a unit element
    corner = np.stack([e1.ravel(), e2.ravel()], axis=-1).astype(float)
    uq = corner[:, None, :] + 0.5 * (1.0 + np.stack([gx.ravel(), gy.ravel()], axis=-1))  # (E, 9, 2)
    pw = phi * wq[:, None]  # (9, 8)
    flat = conn.ravel()
    uu = np.stack([uq[..., 0], uq[..., 1], uq[..., 0] ** 2, uq[..., 0] * uq[..., 1], uq[..., 1] ** 2])
    V = [np.bincount(flat, weights=np.broadcast_to(pw.sum(0), conn.shape).ravel(), minlength=N)]
    V += [np.bincount(flat, weights=(v @ pw).ravel(), minlength=N) for v in uu]
    V0, V1, V2 = V[0], np.stack(V[1:3], axis=-1), np.stack(V[3:], axis=-1)
    d = np.stack([2.0 * dxi, 2.0 * deta])  # (2, 9, 8): derivatives in element units
    G = np.stack([(d[0] * wq[:, None]).T @ d[0], (d[0] * wq[:, None]).T @ d[1], (d[1] * wq[:, None]).T @ d[1]])
    out = dict(conn=conn, N=N, node_id=node_id, lattice=lattice, uq=uq, V0=V0, V1=V1, V2=V2, G=G,
               phi=phi, dxi=dxi, deta=deta, wq=wq, Me=pw.T @ phi,
               csc=(indices, indptr, slot.ravel()), band=(width, band_slot), triples=triples)
    for val in out.values():
        for arr in (val if isinstance(val, tuple) else (val,)):
            if isinstance(arr, np.ndarray):
                arr.setflags(write=False)
    return out


@functools.lru_cache(maxsize=16)
def _nodal_derivatives(n1: int, n2: int):
    """Central differences at the nodes of an n1 × n2 grid, in element units (an element is 1 × 1).

    Returns (Du, Dv, Duu, Duv, Dvv, interior): CSR matrices mapping nodal values to first and
    second derivatives at every interior node (boundary rows are empty), and the interior mask.
    Each derivative is the central difference along a line of the node lattice with the
    nearest nodes on it: half an element apart where they exist, a whole element where the
    half-way point is an element centre (which has no node); the mixed derivative from the
    four diagonal neighbours (half an element away from mid-side nodes, a whole element from
    corners).  All are O(h²) and symmetric, so the second differences are negative
    semi-definite (three-point Laplacians).

    The derivatives of the serendipity interpolant itself, averaged over the elements sharing
    a node, are not usable: at a corner the averaged ∂²/∂u² is ½(δ²p(u−½) + δ²p(u+½)), whose
    symbol cos 2θ − 2 cos θ + 1 is +4 on the node-to-node sawtooth (anti-diffusion), and the
    filter built on them does not converge to the Kalman filter (docs/nonlinear.md).
    """
    top = _topology(n1, n2)
    node_id, N = top["node_id"], top["N"]
    i, j = top["lattice"][:, 0], top["lattice"][:, 1]
    interior = (i > 0) & (i < 2 * n1) & (j > 0) & (j < 2 * n2)
    k, i, j = np.flatnonzero(interior), i[interior], j[interior]
    su = np.where(j % 2 == 0, 1, 2)   # lattice step to the nearest node along u (half-element units)
    sv = np.where(i % 2 == 0, 1, 2)
    sd = np.where((i % 2 == 0) & (j % 2 == 0), 2, 1)  # diagonal step: corners skip the element centres

    def stencil(terms):
        rows = np.concatenate([k] * len(terms))
        cols = np.concatenate([node_id[i + di, j + dj] for di, dj, _ in terms])
        vals = np.concatenate([np.broadcast_to(w, k.shape) for _, _, w in terms])
        return scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(N, N))

    # a lattice step s is s/2 element units: d/du = (p₊ − p₋)/s, d²/du² = 4(p₊ − 2p + p₋)/s²
    Du = stencil([(su, 0, 1.0 / su), (-su, 0, -1.0 / su)])
    Dv = stencil([(0, sv, 1.0 / sv), (0, -sv, -1.0 / sv)])
    Duu = stencil([(su, 0, 4.0 / su**2), (0, 0, -8.0 / su**2), (-su, 0, 4.0 / su**2)])
    Dvv = stencil([(0, sv, 4.0 / sv**2), (0, 0, -8.0 / sv**2), (0, -sv, 4.0 / sv**2)])
    Duv = stencil([(sd, sd, 1.0 / sd**2), (sd, -sd, -1.0 / sd**2), (-sd, sd, -1.0 / sd**2),
                   (-sd, -sd, 1.0 / sd**2)])
    interior.setflags(write=False)
    return Du, Dv, Duu, Duv, Dvv, interior


@dataclass(frozen=True, eq=False)
class FEMGrid:
    """A rectangle [lo, hi] cut into n1 × n2 serendipity elements, with its quadrature data.

    nodes      (N, 2) node coordinates, N = (2n1+1)(2n2+1) − n1·n2
    conn       (E, 8) node indices of each element (corners, then mid-sides)
    W0, W1, W2 ∫φ_j, ∫φ_j x, ∫φ_j x x^T: moments of the interpolant are dot products

    Everything geometry-free (connectivity, quadrature, the moment weights in
    element units) is computed once per (n1, n2) and shared, so placing a new
    grid costs a few small array operations.

    References
    ----------
    .. [1] Y.-X. Zhao, L.-J. Chen and Y. Ma, "An FEM-based state estimation approach to nonlinear hybrid
           positioning systems", Mathematical Problems in Engineering, vol. 2013, Article ID 175425, 2013.
           doi:10.1155/2013/175425
    """

    lo: np.ndarray
    hi: np.ndarray
    n1: int
    n2: int
    conn: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        lo = as_array("lo", self.lo, shape=(2,))
        hi = as_array("hi", self.hi, shape=(2,))
        if np.any(hi <= lo):
            raise ParameterError(f"hi: must exceed lo in both coordinates, got lo={lo}, hi={hi}")
        if not np.all(np.isfinite(hi - lo)):
            raise ParameterError(f"hi: the box [lo, hi] is wider than the float64 range, lo={lo}, hi={hi}")
        n1 = check_int("n1", self.n1, minimum=1)
        n2 = check_int("n2", self.n2, minimum=1)
        check_allocation("n1", n1 * n2, 8.0 * 64 * (2 * n1 + 1) * (2 * n2 + 1))   # nodes and their matrices
        h = (hi - lo) / np.array([n1, n2])
        require_finite("the element areas", np.array([h[0] * h[1]]), lo=lo, hi=hi)
        self._fill(lo, hi, n1, n2)

    def _fill(self, lo: np.ndarray, hi: np.ndarray, n1: int, n2: int) -> None:
        top = _topology(n1, n2)
        h = (hi - lo) / np.array([n1, n2])
        set_ = object.__setattr__
        for name, val in (("lo", lo), ("hi", hi)):
            val.setflags(write=False)
            set_(self, name, val)
        for name, val in (("n1", n1), ("n2", n2), ("conn", top["conn"]), ("_top", top), ("_h", h)):
            set_(self, name, val)

    @functools.cached_property
    def nodes(self) -> np.ndarray:
        """(N, 2) node coordinates (computed on first use: the filter's intermediate grids need none)."""
        nodes = self.lo + 0.5 * self._h * self._top["lattice"]
        nodes.setflags(write=False)
        return nodes

    @functools.cached_property
    def W0(self) -> np.ndarray:
        """∫φ_j, (N,)."""
        W0 = (self._h[0] * self._h[1]) * self._top["V0"]
        W0.setflags(write=False)
        return W0

    @classmethod
    def _at(cls, lo: np.ndarray, hi: np.ndarray, n1: int, n2: int) -> FEMGrid:
        """A grid the filter placed itself (float64 corners, hi > lo): no argument checks."""
        grid = object.__new__(cls)
        grid._fill(lo, hi, n1, n2)
        return grid

    @property
    def size(self) -> int:
        return self._top["N"]

    @property
    def W1(self) -> np.ndarray:
        """∫φ_j x, (N, 2)."""
        return self.W0[:, None] * self.lo + (self._h[0] * self._h[1]) * self._top["V1"] * self._h

    @property
    def W2(self) -> np.ndarray:
        """∫φ_j x xᵀ as (N, 3) columns xx, xy, yy."""
        (a, b), (c, d), V0, V1, V2 = self.lo, self._h, self._top["V0"], self._top["V1"], self._top["V2"]
        u, v = V1[:, 0], V1[:, 1]
        xx = a * a * V0 + 2 * a * c * u + c * c * V2[:, 0]
        xy = a * b * V0 + a * d * v + b * c * u + c * d * V2[:, 1]
        yy = b * b * V0 + 2 * b * d * v + d * d * V2[:, 2]
        return (c * d) * np.stack([xx, xy, yy], axis=-1)

    def contains(self, lo, hi) -> bool:
        return bool(np.all(lo >= self.lo) and np.all(hi <= self.hi))

    def moments(self, p: np.ndarray):
        """(mass, mean (2,), covariance (2, 2)) of the interpolant of nodal values p.

        Computed in element units u = (x − lo)/h and mapped back (x = lo + h∘u),
        which is exact and avoids cancellation far from the origin.
        """
        top = self._top
        mass, mean, cov = grid_moments(np.asarray(p, dtype=float), top["V0"], top["V1"], top["V2"], self.lo,
                                       self._h)
        return float(mass), mean, cov

    def evaluate(self, p: np.ndarray, X) -> np.ndarray:
        """The interpolant of nodal values p at points X (..., 2); zero outside the rectangle."""
        X = np.asarray(X, dtype=float)
        flat = np.ascontiguousarray(X.reshape(-1, 2))
        out = interpolate(flat, self.lo, self._h, self.n1, self.n2, self.conn, np.asarray(p, dtype=float),
                          np.empty(flat.shape[0]))
        return out.reshape(X.shape[:-1])

    def element_matrices(self, model: ContinuousDiscreteModel, stabilise: bool = False):
        """Element mass matrix Me (8, 8) (the same for every element) and Fokker–Planck
        element matrices Ae (E, 8, 8), with M dp/dt = A p after assembly.

        ``stabilise`` adds streamline diffusion δ f f^T (Brooks & Hughes 1982) with
        δ = h_f/(2|f|)·(coth Pe − 1/Pe), h_f the half element length along f and Pe
        the streamline Péclet number: it damps the Galerkin wiggles of an
        advection-dominated drift at an O(h) consistency cost (mass stays conserved).
        """
        top, h = self._top, self._h
        area = h[0] * h[1]
        phi, wq = top["phi"], top["wq"] * area
        grad = np.stack([top["dxi"] * (2.0 / h[0]), top["deta"] * (2.0 / h[1])], axis=-1)  # (9, 8, 2)
        Ke = area * _stiffness_unit(top, model.Q / np.outer(h, h))
        f = model.drift(self.lo + h * top["uq"])  # (E, 9, 2) at the quadrature points
        fgrad = f[..., 0, None] * grad[:, :, 0] + f[..., 1, None] * grad[:, :, 1]  # (E, 9, 8): f·∇φ_a
        Ce = np.swapaxes(fgrad * wq[:, None], 1, 2) @ phi  # (E, 8, 8)
        if stabilise:
            speed = np.sqrt(np.sum(f * f, axis=-1))
            safe = np.where(speed > 0.0, speed, 1.0)
            hf = 0.5 * safe / np.sqrt((f[..., 0] / h[0]) ** 2 + (f[..., 1] / h[1]) ** 2 + 1e-300)
            kappa = 0.5 * np.einsum("kqd,de,kqe->kq", f, model.Q, f) / safe ** 2
            pe = speed * hf / (2.0 * kappa + 1e-300)
            xi = np.where(pe > 1e-3, 1.0 / np.tanh(np.clip(pe, 1e-3, None)) - 1.0 / np.clip(pe, 1e-3, None),
                          pe / 3.0)
            delta = np.where(speed > 0.0, hf / (2.0 * safe) * xi, 0.0) * wq
            Ce = Ce - np.swapaxes(fgrad * delta[..., None], 1, 2) @ fgrad
        return area * top["Me"], Ce - Ke

    def assemble(self, element: np.ndarray) -> scipy.sparse.csc_matrix:
        """Sparse (CSC) matrix assembled from element matrices (E, 8, 8) (or one (8, 8) for all)."""
        indices, indptr, slot = self._top["csc"]
        vals = np.broadcast_to(element, self.conn.shape + (8,)).ravel()
        data = np.bincount(slot, weights=vals, minlength=indices.shape[0])
        return scipy.sparse.csc_matrix((data, indices, indptr), shape=(self.size, self.size))

    def operators(self, model: ContinuousDiscreteModel, stabilise: bool = False):
        """Sparse (CSC) mass matrix M and Fokker–Planck operator A with M dp/dt = A p
        (see :meth:`element_matrices`)."""
        Me, Ae = self.element_matrices(model, stabilise)
        return self.assemble(Me), self.assemble(Ae)

    def nodal_operator(self, model: ContinuousDiscreteModel) -> scipy.sparse.csr_matrix:
        """The paper's strong form at the nodes (Zhao et al. 2013, eqs. 17–19), as a matrix L with F(p) = L p:

            F(p) = Δ₁ p + Δ₂ · ∇p + ½ Σᵢⱼ (Δ₃)ᵢⱼ ∂²p/∂xᵢ∂xⱼ,   Δ₁ = −∇·f,  Δ₂ = −f,  Δ₃ = Q

        (constant Q, so the derivatives of gQgᵀ in eq. 18 vanish; eq. 19 drops the ½ of eq. 17,
        restored here).  ∇p and ∇²p are central differences on the node lattice (the paper
        does not say how; :func:`_nodal_derivatives`), ∇·f central differences of the drift.  Boundary rows are zero: p = 0 on the boundary
        (homogeneous Dirichlet; the paper states no boundary condition)."""
        Du, Dv, Duu, Duv, Dvv, interior = _nodal_derivatives(self.n1, self.n2)
        (h1, h2), Q, X = self._h, model.Q, self.nodes
        d = 1e-4 * float(np.min(self._h))
        e = d * np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
        f = model.drift(np.concatenate([X[None], X[None] + e[:, None]]))  # (5, N, 2)
        div = ((f[1, :, 0] - f[2, :, 0]) + (f[3, :, 1] - f[4, :, 1])) / (2.0 * d)
        diag = scipy.sparse.diags
        L = (diag(-div) - diag(f[0, :, 0] / h1) @ Du - diag(f[0, :, 1] / h2) @ Dv
             + (0.5 * Q[0, 0] / (h1 * h1)) * Duu + ((Q[0, 1] + Q[1, 0]) * 0.5 / (h1 * h2)) * Duv
             + (0.5 * Q[1, 1] / (h2 * h2)) * Dvv)
        return (diag(interior.astype(float)) @ L).tocsr()


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


SCHEMES = ("characteristics", "sdirk2", "cn", "paper")
_GAMMA = 1.0 - np.sqrt(0.5)
_MARGIN = 0.15   # a new box is the required one widened by this fraction on each side ...
_SHRINK = 0.4    # ... and it is redrawn when the required box falls below this fraction of it
_BAND_BYTES = 4 * 2**20   # largest band-LU factors; SuperLU beyond (see _factorise)
_SOLVE_DTYPE = np.float32  # precision of the factorisation and solves (see _factorise)
_FOCUS = 4                  # refinement of the lattice that locates the posterior's modes (_split) ...
_LEVEL = 1e-3               # ... the modes: connected regions above this fraction of the maximum ...
_MIN_MODE = 1e-3            # ... holding more than this fraction of the mass; the lattice is g's own
_RESOLVED = 1.0            # ... where log p(z|x) has second differences below this between its nodes (_resolved)
_MAX_PARTS = 4              # parts of the mixture kept (the heaviest) ...
_MIN_PART = 1e-4            # ... with at least this fraction of the heaviest one's weight
_PUSH_GAUSS = 3             # the transport's quadrature: Gauss points per axis ...
_PUSH_SUB = 2               # ... on this many sub-cells per axis of every element (_push) ...
_PUSH_TIERS = ((2, 1, 1e-3),)  # ... and 2 × 2 Gauss points on the elements whose nodal values are all below
                            # 1e-3 of the largest (the tails: 60 % of the elements); a 3 × 3 tier below 0.03
                            # saved 25 % of the deposit but cost +0.0003 at Q x 0.001 (docs/nonlinear.md)
_MAP_TOL = 0.01             # the flow interpolated from the nodes unless it misses an element's centre by
                            # more than this fraction of an element (transport_points)
_DIFFUSION_STEP = 0.5       # diffusion sub-steps of the characteristics scheme: duration·ρ ≤ this each (_Characteristics)
_CACHE = 16                 # diffusion factorisations kept (_Characteristics) ...
_CACHE_BYTES = 48 * 2**20   # ... at most this many bytes of them ...
_REUSE = (0.8, 2.0)         # ... re-used for operators within these factors of theirs (_Characteristics)
_RK4_RADIUS = 2.5           # classical RK4 is stable on the left half-disc of this radius (2.6 is the largest)


def _factorise(grid: FEMGrid, Be: np.ndarray):
    """Factorise the matrix assembled from element matrices Be (E, 8, 8): (solve, band).

    A band LU (LAPACK ?gbtrf, partial pivoting) in the natural lattice order,
    half-bandwidth ≈ 3·n2, while its factors fit in _BAND_BYTES; ``band`` is then
    (F, piv, kl) for the compiled kernels of _fem_kernels.  SuperLU with a fill-reducing ordering
    beyond (band None).  Factors are in _SOLVE_DTYPE (single precision); right-hand sides and
    solutions stay double.  Measured
    (docs/design.md): on 20 × 20 the band LU factorises 2× faster than SuperLU
    and solves faster; on 40 × 40 its factors make every solve slower.
    """
    top = grid._top
    width, slot = top["band"]
    N = grid.size
    dtype = np.dtype(_SOLVE_DTYPE)
    ld = 3 * width + 1
    if ld * N * dtype.itemsize <= _BAND_BYTES:
        gbtrf = scipy.linalg.lapack.get_lapack_funcs("gbtrf", dtype=dtype)
        ab = np.bincount(slot, weights=Be.ravel(), minlength=ld * N).reshape(N, ld).T.astype(dtype, order="F")
        lu, piv, info = gbtrf(ab, width, width, overwrite_ab=True)
        if info != 0:
            raise ConvergenceError(f"grid filter: the time-step matrix is singular (pivot {info}); "
                                   "use more substeps")
        band = (lu.T, piv, width)  # C-contiguous view: row j is column j of the band
        return (lambda b: band_solve(*band, b.astype(dtype)).astype(float)), band
    try:
        solve = scipy.sparse.linalg.splu(grid.assemble(Be).astype(dtype), permc_spec="MMD_AT_PLUS_A").solve
    except RuntimeError as exc:  # "Factor is exactly singular"
        raise ConvergenceError(f"grid filter: the time-step matrix is singular ({exc}); use more substeps") \
            from None
    return (lambda b: solve(b.astype(dtype)).astype(float)), None


class _Propagator:
    """The prediction p ↦ p(t + dt) of M dp/dt = A p on one grid, with one LU factorisation kept.

    "sdirk2": ``substeps`` steps of Alexander's 2-stage SDIRK (γ = 1 − 1/√2): second
              order, L-stable, both stages solve with the same matrix M − γτA.
    "cn":     ``substeps`` Crank–Nicolson steps (θ = ½): second order, A-stable, not L-stable.
    Both conserve 1ᵀM p (Σφ = 1 makes 1ᵀA = 0), i.e. the probability mass.
    On a band LU the sub-steps run compiled (_fem_kernels); with SuperLU in the loop below.
    """

    def __init__(self, grid: FEMGrid, model: ContinuousDiscreteModel, substeps: int, scheme: str,
                 stabilise: bool):
        Me, Ae = grid.element_matrices(model, stabilise)
        Ae = np.ascontiguousarray(Ae)
        tau = model.dt / substeps
        gamma = 0.5 if scheme == "cn" else _GAMMA
        self.solve, self.band = _factorise(grid, Me - gamma * tau * Ae)
        self.conn, self.Ae = grid.conn, Ae
        self.Re = Me + 0.5 * tau * Ae if scheme == "cn" else None
        if self.band is None:  # the loop below multiplies with assembled matrices
            self.A = grid.assemble(Ae).tocsr()
            self.rhs = None if self.Re is None else grid.assemble(self.Re).tocsr()
        self.tau, self.substeps = tau, substeps

    def __call__(self, p):
        tau, solve = self.tau, self.solve
        if self.band is not None:
            if self.Re is not None:
                return band_cn(*self.band, self.conn, self.Re, p, self.substeps)
            return band_sdirk2(*self.band, self.conn, self.Ae, p, tau, _GAMMA, self.substeps)
        A, R = self.A, self.rhs
        for _ in range(self.substeps):
            if R is not None:
                p = solve(R @ p)
            else:
                k1 = solve(A @ p)
                k2 = solve(A @ (p + (1.0 - _GAMMA) * tau * k1))
                p = p + tau * ((1.0 - _GAMMA) * k1 + _GAMMA * k2)
        return p


class _NodalRK4:
    """The paper's prediction (Zhao et al. 2013, eqs. 19–21): classical RK4 on dp/dt = F(p) = L p at the nodes
    (:meth:`FEMGrid.nodal_operator`), with the stages of eq. 21 corrected to
    K₂ = F(p + τ/2·K₁), K₃ = F(p + τ/2·K₂), K₄ = F(p + τ·K₃).

    Explicit: τ·ρ(L) must stay inside RK4's stability region, so the number of steps per dt
    is the larger of ``substeps`` and dt·ρ/_RK4_RADIUS, with ρ ≥ |λ| from Gershgorin's
    bound (the largest absolute row sum of L).  One RK4 step over the whole dt (eq. 20 as
    printed) is unstable on every grid of the eq. 42 example.  Not conservative: the mass
    leaving through the Dirichlet boundary (and the strong form's own imbalance) is
    renormalised away by the caller.
    """

    def __init__(self, grid: FEMGrid, model: ContinuousDiscreteModel, substeps: int):
        self.L = grid.nodal_operator(model)
        self.rho = float(np.max(np.abs(self.L).sum(axis=1)))
        self.substeps = max(substeps, int(np.ceil(model.dt * self.rho / _RK4_RADIUS)))
        self.tau = model.dt / self.substeps
        self.interior = _nodal_derivatives(grid.n1, grid.n2)[-1]

    def __call__(self, p):
        L, tau = self.L, self.tau
        p = np.where(self.interior, p, 0.0)
        for _ in range(self.substeps):
            k1 = L @ p
            k2 = L @ (p + 0.5 * tau * k1)
            k3 = L @ (p + 0.5 * tau * k2)
            k4 = L @ (p + tau * k3)
            p = p + (tau / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return p


def default_substeps(grid: tuple[int, int]) -> int:
    """:func:`fem_substeps` of a checked grid shape."""
    return max(8, round(0.8 * max(grid)))


def _grid_shape(grid) -> tuple[int, int]:
    shape = tuple(check_int("grid", g, minimum=1) for g in np.atleast_1d(grid))
    if len(shape) != 2:
        raise ShapeError(f"grid: expected (n1, n2) elements per axis, got {grid!r}")
    return shape


def fem_substeps(grid: tuple[int, int]) -> int:
    """Time steps per dt that :func:`fem_filter` takes on a ``grid`` of (n1, n2) elements when its
    ``substeps`` is None: 0.8·max(n1, n2), at least 8 (a fixed Courant number; 16 on
    20 × 20)."""
    return default_substeps(_grid_shape(grid))


def _box(model, m, P, width, floor):
    """Rectangle covering mean ± width·σ now and after one dt.

    The predicted moments come from sigma points pushed through the noise-free
    flow (:func:`_drift_flow`) plus Q·dt: cheap, good enough to place a grid.  P is
    projected onto the PSD cone and its eigenvalues floored at ``floor``² first (a
    posterior narrower than an element has moments that are not trustworthy).
    """
    P = _psd_floor(P, floor)
    s = np.sqrt(np.diag(P))
    X, Wm, Wc = sigma_points(m, P)
    Y = _drift_flow(model, X, model.dt)
    mp = Wm @ Y
    sp = np.sqrt(np.clip(Wc @ (Y - mp) ** 2 + np.diag(model.Q) * model.dt, 0.0, None))
    lo = np.minimum(m - width * s, mp - width * sp)
    hi = np.maximum(m + width * s, mp + width * sp)
    return lo, hi


def _psd_floor(P, floor: float) -> np.ndarray:
    """P projected onto the PSD cone, its eigenvalues floored at ``floor``²."""
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    return (V * np.maximum(w, floor * floor)) @ V.T


def _predicted_box(model, m, P, width, floor, duration):
    """Rectangle covering the predicted mean ± width·σ after ``duration`` (sigma points through
    the noise-free flow, plus Q·duration), σ floored at ``floor`` (``predicted_box``).  A P that is not PSD
    (on a coarse grid the moments of a density with clipped negative lobes need not be) is projected onto
    the PSD cone."""
    if np.linalg.eigvalsh(0.5 * (P + P.T))[0] < 0.0:
        P = _psd_floor(P, 0.0)
    X = np.empty((5, 2))
    if not sigma_points_2d(m, P, _SIGMA[0], X):
        raise NotPositiveDefiniteError(f"P: the density's covariance lost positive semi-definiteness ({P.tolist()})")
    Y = _drift_flow(model, X, duration)
    lo, hi = np.empty(2), np.empty(2)
    predicted_box(Y, _SIGMA[1], _SIGMA[2], np.diag(model.Q).copy(), duration, width, floor, lo, hi)
    return lo, hi


_SIGMA = _sigma_weights(2, 1.0, 2.0, 0.0)   # the sigma points of _predicted_box: scale, Wm, Wc


@functools.lru_cache(maxsize=16)
def _unit_mass_factor(n1: int, n2: int):
    """Band Cholesky factor (L, kd) of the mass matrix of an n1 × n2 grid of unit elements (M of any
    grid of that shape is h1·h2 times it; ``_fem_kernels.cholesky_solve``): factorised once per shape."""
    top = _topology(n1, n2)
    return _band_cholesky(top, top["Me"], np.float64)


def _band_cholesky(top: dict, Be: np.ndarray, dtype):
    """Band Cholesky factor (C, kd) in ``dtype`` of the symmetric positive definite matrix assembled
    from the element matrix Be (8, 8) on every element of the grid of ``top`` (natural lattice order,
    kd ≈ 3·n2), in the layout of ``_fem_kernels.cholesky_solve`` (compiled: ``element_band_cholesky``,
    1.5-2× LAPACK's ?pbtrf at this bandwidth)."""
    kd = top["band"][0]   # the half-bandwidth
    C = np.zeros((top["N"], 2 * (kd + 1)), dtype)
    if not element_band_cholesky(np.asarray(Be, dtype=float), top["conn"], kd, C):
        raise ConvergenceError("grid filter: the time-step matrix is not positive definite")
    C.setflags(write=False)
    return C, kd


@functools.lru_cache(maxsize=16)
def _push_rule(order: int, sub: int):
    """Quadrature on an element: order × order Gauss points on each of sub × sub sub-cells.
    Returns (points (P, 2) in [0, 1]² of an element, shape functions (P, 8) at them, weights (P,)
    on a unit element)."""
    g, w = np.polynomial.legendre.leggauss(order)
    c = (np.arange(sub)[:, None] + 0.5 * (1.0 + g[None, :])).ravel() / sub   # (sub·order,) in [0, 1]
    wc = np.tile(0.5 * w, sub) / sub
    cx, cy = np.meshgrid(c, c, indexing="ij")
    loc = np.stack([cx.ravel(), cy.ravel()], axis=-1)                        # (P, 2) in [0, 1]²
    wq = np.outer(wc, wc).ravel()
    phi, _, _ = shape_functions(2.0 * loc[:, 0] - 1.0, 2.0 * loc[:, 1] - 1.0)
    return loc, phi, wq


def _compiled(model: ContinuousDiscreteModel):
    """The model's compiled kernels (None for a model without)."""
    return None if model.kernels is None else compiled_model(model)


def _flow_steps(model: ContinuousDiscreteModel, X: np.ndarray, duration: float) -> int:
    """RK4 steps for carrying the points X (P, 2) over ``duration``: at least 2 per dt and as many
    as the drift's stiffness at the points needs (τ·‖∂f/∂x‖ ≤ 1 per step, the Frobenius norm by
    central differences; RK4 is then accurate to a few per cent on the fastest mode).  The NumPy
    definition; ``_fem_kernels.flow_points`` computes the same compiled."""
    d = 1e-5 * max(1.0, float(np.max(np.abs(X))))
    e = d * np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    f = model.drift(X[None] + e[:, None])                                            # (4, P, 2)
    stiff = float(np.max(np.sqrt(np.sum((f[0] - f[1]) ** 2 + (f[2] - f[3]) ** 2, axis=-1)))) / (2.0 * d)
    return max(int(np.ceil(2.0 * duration / model.dt)), int(np.ceil(duration * stiff)), 1)


def _drift_flow(model: ContinuousDiscreteModel, X: np.ndarray, duration: float) -> np.ndarray:
    """The points X (P, 2) carried by the noise-free drift flow over ``duration`` (RK4 steps by
    :func:`_flow_steps`); compiled, step count included, when the model has kernels."""
    compiled = _compiled(model)
    if compiled is None:
        return rk4_flow(model, X, duration, _flow_steps(model, X, duration))
    Y = np.array(X, dtype=float, order="C")
    cap = np.inf if model.max_increment is None else model.max_increment
    flow_points(Y, *compiled.drift_at, model.kernels.drift_params, duration, model.dt, cap)
    return Y


def _push(old: FEMGrid, p: np.ndarray, new: FEMGrid, model, duration: float):
    """The density p on ``old`` carried by the noise-free flow over τ = ``duration`` onto ``new``,
    conserving mass: the L2 projection of the transported density onto new's elements,
    M q = b with b_j = ∫ φ_j p(t+τ) dx = ∫ φ_j(Φ_τ(y)) p(y) dy (a change of variables, so no
    Jacobian), by Gauss quadrature on old's elements (_PUSH_GAUSS² points on each of _PUSH_SUB²
    sub-cells; coarser rules on the tail elements, _PUSH_TIERS) with the points carried by the flow's
    serendipity interpolant from old's nodes (the nodes flowed by :func:`_drift_flow`; points of
    elements whose flowed centre the interpolant misses by more than _MAP_TOL of a new element are
    flowed themselves).  Points carrying less than 10⁻¹² of the largest weight are not moved (their
    mass is dropped).  ``transport_split`` runs the same steps compiled, flows included, when the
    model has kernels.  Returns (nodal values q, fraction of the mass that landed outside new)."""
    Z = _drift_flow(model, flow_sites(old.lo, old._h, old._top["lattice"], old.n1, old.n2), duration)
    b = np.zeros(new.size)
    outside, total, X, w = transport_deposit(p, old.conn, old.lo, old._h, old.n2, *_push_rules(), Z,
                                             _MAP_TOL, 1e-12, new.lo, new._h, new.n1, new.n2, new.conn, b)
    if len(w):
        outside += deposit(_drift_flow(model, X, duration), w, new.lo, new._h, new.n1, new.n2, new.conn, b)
    q = mass_solve(b, *_unit_mass_factor(new.n1, new.n2), new._h)
    return q, (outside / total if total > 0.0 else 0.0)


@functools.lru_cache(maxsize=4)
def _push_rules(tiers=None):
    """The transport's quadrature rules on a unit element, stacked from the finest: (loc, phi, wq) of
    all, each rule's first row (and the total), and the levels below which an element takes the next
    coarser rule (_PUSH_TIERS: (Gauss points per axis, sub-cells per axis, level) after the fine rule)."""
    tiers = _PUSH_TIERS if tiers is None else tiers
    rules = [_push_rule(_PUSH_GAUSS, _PUSH_SUB)] + [_push_rule(order, sub) for order, sub, _ in tiers]
    bounds = np.cumsum([0] + [len(r[2]) for r in rules])
    levels = np.array([level for _, _, level in tiers], dtype=float)
    return (*(np.ascontiguousarray(np.concatenate(r)) for r in zip(*rules)), bounds, levels)


class _Characteristics:
    """The prediction of the characteristics scheme over one filter run on n1 × n2 grids (see
    _characteristic_steps): the constants of the compiled kernels, and the diffusion's factorisations.

    Diffusion: SDIRK2 over a duration, in ⌈``substeps``·duration/dt⌉ steps, or (None) in as many as
    the diffusion's rate on the element scale needs: n = ⌈duration·ρ/_DIFFUSION_STEP⌉ with ρ the
    largest eigenvalue of S = H⁻¹QH⁻¹, H = diag(h) (SDIRK2 is L-stable; this bounds its error on the
    modes the elements resolve).  In element units the operator is M̂ dp/dt = −Â(S) p, with M̂ and
    Â(S) = ½ Σ S_de G_de the same for every grid of a shape, so a stage matrix M̂ + γτ_s Â(S) depends on
    C = τ_s·S alone.  A kept band Cholesky factorisation whose C' lies within _REUSE of C
    (_REUSE[0]·C ⪯ C' ⪯ _REUSE[1]·C) is re-used with the grid's own, exact, right-hand side Â(S) p: a
    W-method (the stage matrix of a nearby operator).  Its error on the modes the elements resolve is
    a fraction |1 − C'/C| of SDIRK2's own second-order term, and it stays stable for stiff modes while
    C' ⪰ 0.75·C (the amplification at −∞ is 1 − 1/(γr) + (1 − γ)/(γr²), r = C'/C; 0 at r = 1, |·| < 1
    for r > 0.75); the mean and covariance the diffusion adds do not depend on the stage matrix
    (tested).  A factorisation costs 9 solves at 20 × 20; re-use takes them from 2.9 to 0.37 per
    measurement step on eq. 42 at no measurable cost in accuracy (docs/nonlinear.md).  _CACHE kept (at
    most _CACHE_BYTES), the least recently used replaced (``diffuse_kept``).

    With the model's compiled kernels a whole dt runs in one call (``predict_dt``); without, the
    same steps run from Python (:meth:`predict_steps`), the transport with the NumPy flow."""

    def __init__(self, model, substeps: int | None, width: float, splits: int, fixed: bool, shape):
        self.model, self.width, self.splits, self.fixed = model, width, splits, fixed
        self.tau = model.dt / splits
        n1, n2 = shape
        top = _topology(n1, n2)
        kd = top["band"][0]
        self.grid = (n1, n2, top["conn"], top["lattice"], top["V0"], top["V1"], top["V2"],
                     *_unit_mass_factor(n1, n2), top["Me"], top["G"])
        self.place = (width, *_SIGMA, np.diag(model.Q).copy(), _MARGIN, _SHRINK)
        self.rules = (*_push_rules(), _MAP_TOL)
        self.diff = (np.ascontiguousarray(model.Q, dtype=float), 0 if substeps is None else substeps,
                     _DIFFUSION_STEP, model.dt, _GAMMA, *_REUSE)
        width_bytes = top["N"] * 2 * (kd + 1) * np.dtype(_SOLVE_DTYPE).itemsize
        K = max(1, min(_CACHE, _CACHE_BYTES // width_bytes))
        self.kept = (np.zeros((K, 3)), np.zeros((K, top["N"], 2 * (kd + 1)), _SOLVE_DTYPE), np.zeros(K, np.int64),
                     np.zeros(2, np.int64))
        compiled = _compiled(model)
        cap = np.inf if model.max_increment is None else model.max_increment
        self.flow = None if compiled is None else (*compiled.drift_at, model.kernels.drift_params, model.dt, cap)

    @property
    def factorisations(self) -> int:
        """Diffusion factorisations made so far."""
        return int(self.kept[3][1])

    def predict(self, g: FEMGrid, p: np.ndarray):
        """One dt: ``splits`` Strang steps; the diffusions over τ/2 that end one step and start the next
        run on the same grid, as one over τ.  Returns (grid, p, factorised, regridded, lost, clipped)."""
        if self.flow is None:
            return self.predict_steps(g, p)
        before = self.factorisations
        status, lo, hi, q, lost, clipped = predict_dt(p, g.lo, g.hi, not self.fixed, self.splits, self.kept,
                                                      self.grid, self.place, self.flow, self.rules, self.diff)
        _raise(status, "prediction")
        g = g if self.fixed else FEMGrid._at(lo, hi, g.n1, g.n2)
        return g, q, self.factorisations > before, not self.fixed, lost, clipped

    def predict_steps(self, g: FEMGrid, p: np.ndarray):
        """:meth:`predict` step by step from Python (``predict_dt``'s steps)."""
        tau, before, lost = self.tau, self.factorisations, 0.0
        p, clipped = self.diffuse(g, p, 0.5 * tau)
        for i in range(self.splits):
            g, p, out, c1 = self.transport(g, p, not self.fixed, tau)
            p, c2 = self.diffuse(g, p, tau if i < self.splits - 1 else 0.5 * tau)
            lost += out
            clipped += c1 + c2
        return g, p, self.factorisations > before, not self.fixed, lost, clipped

    def diffuse(self, g: FEMGrid, p: np.ndarray, duration: float):
        """(p diffused over ``duration`` on g, clipped and normalised; the negative mass removed)."""
        q, clipped, mass, status = diffuse_kept(self.kept, p, g._h, duration, self.grid, self.diff)
        _raise(status or (2 if not (np.isfinite(mass) and mass > 0.0) else 0), "prediction")
        return q, clipped

    def transport(self, g: FEMGrid, p: np.ndarray, moving: bool, duration: float):
        """The transport step: the next grid (g itself when not ``moving``, else placed around the
        density predicted for t + duration: _predicted_box, ``next_grid``) and the density carried onto
        it (_push), clipped and normalised.  Compiled end to end (``transport_split``) when the model
        has kernels.  Returns (grid, p, lost, clipped)."""
        if self.flow is None:
            lo, hi = g.lo, g.hi
            if moving:
                _, m, P = g.moments(p)
                blo, bhi = _predicted_box(self.model, m, P, self.width, 0.5 * float(np.min(g._h)), duration)
                lo, hi = np.empty(2), np.empty(2)
                next_grid(blo, bhi, g.lo, g.hi, _MARGIN, _SHRINK, lo, hi)
            new = FEMGrid._at(lo, hi, g.n1, g.n2) if moving else g
            q, lost = _push(g, p, new, self.model, duration)
            p, clipped = _clip_normalise(new, q, "prediction")
            return new, p, lost, clipped
        status, lo, hi, q, lost, clipped, mass = transport_split(p, g.lo, g.hi, moving, duration, self.grid,
                                                                 self.place, self.flow, self.rules)
        _raise(status or (2 if not (np.isfinite(mass) and mass > 0.0) else 0), "prediction")
        return (FEMGrid._at(lo, hi, g.n1, g.n2) if moving else g), q, lost, clipped


def _raise(status: int, what: str) -> None:
    """The error of a compiled step's status (0: none)."""
    if status == 1:
        raise NotPositiveDefiniteError("P: the density's covariance lost positive semi-definiteness")
    if status == 2:
        _check_mass(0.0, what)
    if status == 3:
        raise ConvergenceError("grid filter: the diffusion's time-step matrix is not positive definite")


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
    """Run the grid filter step by step, yielding a FEMStep (densities included) per measurement.

    grid      (n1, n2) elements per axis (Zhao et al. 2013: 20 × 20)
    width     half-width of the box in posterior standard deviations (section 3.1)
    substeps  time steps per dt; default 0.8·max(n1, n2), at least 8: a fixed Courant
              number, 16 on the paper's 20 × 20 grid, where 32 are no more accurate on
              eq. 42 and 8 are measurably less (docs/design.md)
    scheme    "characteristics" (default): Strang splitting — half a dt of diffusion by SDIRK2,
              the density carried by the drift's flow (mass-conserving projection) onto a
              grid placed around the predicted density, half a dt of diffusion there;
              separate posterior modes get their own grids (``step.posterior.parts``);
              "sdirk2" (L-stable) or "cn" (Crank–Nicolson): the Galerkin drift–diffusion
              operator, accurate while the density moves less than its own width per element
              (docs/nonlinear.md: at low diffusion it loses the state);
              "paper": the paper's own scheme (eqs. 17–21) — the strong form
              F(p) = Δ₁p + Δ₂·∇p + ½Δ₃:∇²p at the nodes (central differences), stepped by
              classical RK4 with eq. 21's stages corrected; explicit, so ``substeps`` is raised
              to its stability limit; p = 0 on the boundary (the mass that leaves is counted in
              ``lost``).  Needs elements narrower than the density relative to the drift
              (docs/nonlinear.md, "The paper's scheme")
    splits    Strang steps per dt of the "characteristics" scheme (its splitting error falls
              like (dt/splits)²); each places its own grid around the density it predicts
    stabilise add streamline diffusion (see FEMGrid.element_matrices); off by default: on the
              eq. 42 example its O(h) smearing costs more accuracy than the clipped
              Galerkin wiggles do (docs/nonlinear.md)
    box       ((lo1, lo2), (hi1, hi2)): a fixed rectangle instead of the moving grid;
              it must cover the prior mean ± 3σ, and as its boundary is zero-flux no
              mass can leave it: choose it to contain the whole track

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


def _stiffness_unit(top: dict, S: np.ndarray) -> np.ndarray:
    """Â(S) = ½ Σ_de S_de G_de: the diffusion's element stiffness on a unit element (8, 8), with
    G_de = ∫ ∂_dφ ∂_eφᵀ in element units and S = H⁻¹QH⁻¹ (``stiffness_unit``)."""
    return stiffness_unit(top["G"], S[0, 0], S[0, 1], S[1, 1])


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
    """The FEM grid filter (Zhao et al. 2013) as a FilterResult; options as for :func:`fem_steps`.

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
