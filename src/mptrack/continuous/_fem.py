"""The finite-element (Fokker–Planck) grid filter for a 2-D state (seed 004 section 3).

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
(docs/nonlinear.md).  Separate posterior modes (a range ring seen from an
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
import scipy.ndimage
import scipy.sparse
import scipy.sparse.linalg

from .._validation import as_array, check_int, check_positive
from ..errors import ConvergenceError, ParameterError, ShapeError
from ..linear import FilterResult
from ..nonlinear._common import prepare_nonlinear
from ..nonlinear._ukf import sigma_points
from ._fem_kernels import (
    band_cholesky,
    band_cn,
    band_sdirk2,
    band_solve,
    cholesky_solve,
    deposit,
    flow_points,
    interpolate,
    push_points,
)
from ._kernels import compiled_model
from ._model import ContinuousDiscreteModel, rk4_flow

__all__ = ["FEMGrid", "GridDensity", "GridMixture", "FEMStep", "fem_filter", "fem_steps", "shape_functions"]

# reference element nodes: corners, then mid-sides (bottom, right, top, left)
_XI = np.array([-1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0, -1.0])
_ETA = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0])
# their offsets on the half-spacing lattice of an element
_DI = np.array([0, 2, 2, 0, 1, 2, 1, 0])
_DJ = np.array([0, 0, 2, 2, 0, 1, 2, 1])
_GAUSS3 = (np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)]), np.array([5.0, 8.0, 5.0]) / 9.0)


def shape_functions(xi, eta):
    """Serendipity shape functions N (…, 8) and derivatives dN/dξ, dN/dη (seed 004 eqs. 11–12).

    Corners: N = ¼(1+ξξᵢ)(1+ηηᵢ)(ξξᵢ+ηηᵢ−1); mid-sides: ½(1−ξ²)(1+ηηᵢ) or ½(1+ξξᵢ)(1−η²).
    """
    xi = np.asarray(xi, dtype=float)[..., None]
    eta = np.asarray(eta, dtype=float)[..., None]
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
    sym      (width, slot, entries): the same for the lower band of a symmetric matrix (?pbtrf), slot
             of each (e, a, b) entry on or below the diagonal, and those entries' flat indices
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
    lower = rows >= cols  # lower band: A[i, j], i ≥ j, at [j, i − j] of an (N, width + 1) array
    sym = (width, (cols * (width + 1) + rows - cols)[lower], np.flatnonzero(lower))
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
    out = dict(conn=conn, N=N, node_id=node_id, lattice=lattice, uq=uq, V0=V0, V1=V1, V2=V2,
               phi=phi, dxi=dxi, deta=deta, wq=wq, Me=pw.T @ phi,
               csc=(indices, indptr, slot.ravel()), band=(width, band_slot), sym=sym, triples=triples)
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
    """

    lo: np.ndarray
    hi: np.ndarray
    n1: int
    n2: int
    nodes: np.ndarray = field(init=False, repr=False)
    conn: np.ndarray = field(init=False, repr=False)
    W0: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        lo = as_array("lo", self.lo, shape=(2,))
        hi = as_array("hi", self.hi, shape=(2,))
        if np.any(hi <= lo):
            raise ParameterError(f"hi: must exceed lo in both coordinates, got lo={lo}, hi={hi}")
        n1 = check_int("n1", self.n1, minimum=1)
        n2 = check_int("n2", self.n2, minimum=1)
        top = _topology(n1, n2)
        h = (hi - lo) / np.array([n1, n2])
        nodes = lo + 0.5 * h * top["lattice"]
        W0 = (h[0] * h[1]) * top["V0"]
        set_ = object.__setattr__
        for name, val in (("lo", lo), ("hi", hi), ("nodes", nodes), ("W0", W0)):
            val.setflags(write=False)
            set_(self, name, val)
        for name, val in (("n1", n1), ("n2", n2), ("conn", top["conn"]), ("_top", top), ("_h", h)):
            set_(self, name, val)

    @property
    def size(self) -> int:
        return self.nodes.shape[0]

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
        top, h = self._top, self._h
        m0 = top["V0"] @ p
        mu = (top["V1"].T @ p) / m0
        s = (top["V2"].T @ p) / m0
        cross = s[1] - mu[0] * mu[1]
        cov_u = np.array([[s[0] - mu[0] * mu[0], cross], [cross, s[2] - mu[1] * mu[1]]])
        return (h[0] * h[1]) * m0, self.lo + h * mu, cov_u * np.outer(h, h)

    def evaluate(self, p: np.ndarray, X) -> np.ndarray:
        """The interpolant of nodal values p at points X (..., 2); zero outside the rectangle."""
        X = np.asarray(X, dtype=float)
        flat = np.ascontiguousarray(X.reshape(-1, 2))
        out = interpolate(flat, self.lo, self._h, self.n1, self.n2, self.conn, np.asarray(p, dtype=float),
                          np.empty(flat.shape[0]))
        return out.reshape(X.shape[:-1])

    def element_matrices(self, model: ContinuousDiscreteModel, stabilise: bool = False, advection: bool = True):
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
        Ke = 0.5 * np.einsum("q,qad,de,qbe->ab", wq, grad, model.Q, grad)
        if not advection:  # the diffusion part only (the characteristics scheme moves the density itself)
            return area * top["Me"], np.broadcast_to(-Ke, (self.conn.shape[0], 8, 8))
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
        """The paper's strong form at the nodes (seed 004 eqs. 17–19), as a matrix L with F(p) = L p:

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
    neg = p < 0.0
    clipped = float(-(grid.W0[neg] @ p[neg])) if neg.any() else 0.0
    if neg.any():
        p = np.where(neg, 0.0, p)
    mass = grid.W0 @ p
    if not np.isfinite(mass) or mass <= 0.0:
        raise ConvergenceError(f"{what}: the density on the grid has no positive mass left "
                               "(the grid does not cover it)")
    return p / mass, clipped


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
_PUSH_SUB = 2               # ... on this many sub-cells per axis of every element (_push)
_DIFFUSION_STEP = 0.25      # diffusion sub-steps of the characteristics scheme: duration·ρ ≤ this each (_Diffusion)
_CACHE = 4                  # diffusion factorisations kept (_Diffusion)
_RK4_RADIUS = 2.5           # classical RK4 is stable on the left half-disc of this radius (2.6 is the largest)


def _factorise(grid: FEMGrid, Be: np.ndarray, symmetric: bool = False):
    """Factorise the matrix assembled from element matrices Be (E, 8, 8): (solve, band).

    A band LU (LAPACK ?gbtrf, partial pivoting) in the natural lattice order,
    half-bandwidth ≈ 3·n2, while its factors fit in _BAND_BYTES; ``band`` is then
    (F, piv, kl) for the compiled kernels of _fem_kernels.  ``symmetric`` (a symmetric positive
    definite matrix: the diffusion of the characteristics scheme): a band Cholesky factor
    (?pbtrf) instead, half the work and a third of the storage, ``band`` = (L, empty piv, kd).
    SuperLU with a fill-reducing ordering beyond (band None).  Factors are in _SOLVE_DTYPE
    (single precision); right-hand sides and solutions stay double.  Measured
    (docs/design.md): on 20 × 20 the band LU factorises 2× faster than SuperLU
    and solves faster; on 40 × 40 its factors make every solve slower.
    """
    top = grid._top
    width, slot = top["band"]
    N = grid.size
    dtype = np.dtype(_SOLVE_DTYPE)
    if symmetric and (width + 1) * N * dtype.itemsize <= _BAND_BYTES:
        L, kd = _band_cholesky(top, Be, dtype)
        band = (L, np.empty(0, np.int32), kd)
        return (lambda b: cholesky_solve(L, kd, b.astype(dtype)).astype(float)), band
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
                 stabilise: bool, duration: float | None = None):
        advection = scheme != "characteristics"   # there: the diffusion half-steps only, by SDIRK2
        Me, Ae = grid.element_matrices(model, stabilise and advection, advection)
        tau = (model.dt if duration is None else duration) / substeps
        gamma = 0.5 if scheme == "cn" else _GAMMA
        if advection:
            Ae = np.ascontiguousarray(Ae)
            self.solve, self.band = _factorise(grid, Me - gamma * tau * Ae)
        else:  # M − γτA symmetric positive definite, one element matrix for all: band Cholesky
            Ae = np.ascontiguousarray(Ae[:1])
            Be = np.broadcast_to(Me - gamma * tau * Ae[0], grid.conn.shape + (8,))
            self.solve, self.band = _factorise(grid, Be, symmetric=True)
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
    """The paper's prediction (seed 004 eqs. 19–21): classical RK4 on dp/dt = F(p) = L p at the nodes
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
    """Time steps per dt of the grid filter by default: 0.8·max(n1, n2), at least 8 (a fixed Courant
    number; 16 on 20 × 20)."""
    return max(8, round(0.8 * max(grid)))


def _box(model, m, P, width, floor):
    """Rectangle covering mean ± width·σ now and after one dt.

    The predicted moments come from sigma points pushed through the noise-free
    flow (:func:`_drift_flow`) plus Q·dt: cheap, good enough to place a grid.  P is
    projected onto the PSD cone and its eigenvalues floored at ``floor``² first (a
    posterior narrower than an element has moments that are not trustworthy).
    """
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    P = (V * np.maximum(w, floor * floor)) @ V.T
    s = np.sqrt(np.diag(P))
    X, Wm, Wc = sigma_points(m, P)
    Y = _drift_flow(model, X, model.dt)
    mp = Wm @ Y
    sp = np.sqrt(np.clip(Wc @ (Y - mp) ** 2 + np.diag(model.Q) * model.dt, 0.0, None))
    lo = np.minimum(m - width * s, mp - width * sp)
    hi = np.maximum(m + width * s, mp + width * sp)
    return lo, hi


def _predicted_box(model, m, P, width, floor, duration):
    """Rectangle covering the predicted mean ± width·σ after ``duration`` (sigma points through
    the noise-free flow, plus Q·duration), σ floored at ``floor``."""
    X, Wm, Wc = sigma_points(m, P)
    Y = _drift_flow(model, X, duration)
    mp = Wm @ Y
    sp = np.maximum(np.sqrt(np.clip(Wc @ (Y - mp) ** 2 + np.diag(model.Q) * duration, 0.0, None)), floor)
    return mp - width * sp, mp + width * sp


@functools.lru_cache(maxsize=16)
def _unit_mass_factor(n1: int, n2: int):
    """Band Cholesky factor (L, kd) of the mass matrix of an n1 × n2 grid of unit elements (M of any
    grid of that shape is h1·h2 times it; ``_fem_kernels.cholesky_solve``): factorised once per shape."""
    top = _topology(n1, n2)
    return _band_cholesky(top, np.broadcast_to(top["Me"], top["conn"].shape + (8,)), np.float64)


def _band_cholesky(top: dict, Be: np.ndarray, dtype):
    """Band Cholesky factor (C, kd) in ``dtype`` of the symmetric positive definite matrix assembled
    from element matrices Be (E, 8, 8) on the grid of ``top`` (natural lattice order, kd ≈ 3·n2), in
    the layout of ``_fem_kernels.cholesky_solve`` (compiled: ``band_cholesky``, 1.5-2× LAPACK's
    ?pbtrf at this bandwidth)."""
    kd, slot, lower = top["sym"]
    N = top["N"]
    C = np.zeros((N, 2 * (kd + 1)), dtype)
    C[:, :kd + 1] = np.bincount(slot, weights=Be.ravel()[lower], minlength=(kd + 1) * N).reshape(N, kd + 1)
    if not band_cholesky(C, kd):
        raise ConvergenceError("grid filter: the time-step matrix is not positive definite")
    C.setflags(write=False)
    return C, kd


@functools.lru_cache(maxsize=16)
def _push_rule(n1: int, n2: int, order: int, sub: int):
    """Quadrature on every element: order × order Gauss points on each of sub × sub sub-cells.
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
    sub-cells) with the points pushed forward (:func:`_drift_flow`).  Points carrying less than
    10⁻¹² of the largest weight are not moved (their mass is dropped).  Compiled throughout
    (quadrature points, flow, deposit, the mass matrix's band Cholesky solve) when the model has
    kernels.  Returns (nodal values q, fraction of the mass that landed outside new)."""
    loc, phi, wq = _push_rule(old.n1, old.n2, _PUSH_GAUSS, _PUSH_SUB)
    area = float(old._h[0] * old._h[1])
    X, w = push_points(p, old.conn, phi, wq * area, loc, old.lo, old._h, old.n1, old.n2, 1e-12)
    Y = _drift_flow(model, X, duration)
    b = np.zeros(new.size)
    outside = deposit(Y, w, new.lo, new._h, new.n1, new.n2, new.conn, b)
    q = cholesky_solve(*_unit_mass_factor(new.n1, new.n2), b) / float(new._h[0] * new._h[1])
    total = float(w.sum())
    return q, (outside / total if total > 0.0 else 0.0)


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


def fem_steps(model: ContinuousDiscreteModel, z, x0, P0, *, grid: tuple[int, int] = (20, 20),
              width: float = 4.0, substeps: int | None = None, scheme: str = "characteristics",
              stabilise: bool = False, box: tuple | None = None, splits: int = 4) -> Iterator[FEMStep]:
    """Run the grid filter step by step, yielding a FEMStep (densities included) per measurement.

    grid      (n1, n2) elements per axis (seed 004: 20 × 20)
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
    """
    shape = tuple(check_int("grid", g, minimum=1) for g in np.atleast_1d(grid))
    if len(shape) != 2:
        raise ShapeError(f"grid: expected (n1, n2) elements per axis, got {grid!r}")
    adaptive = substeps is None  # the characteristics scheme then sizes its diffusion sub-steps itself
    if substeps is None:
        substeps = default_substeps(shape)
    z, m, P, substeps = prepare_nonlinear(model, z, x0, P0, substeps, definite=True)
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


class _Diffusion:
    """The diffusion half-steps of the characteristics scheme: SDIRK2 over ``duration`` (τ/2) on a
    grid, in ``substeps`` steps, or (None) in as many as the diffusion's rate on the element scale
    needs: n = ⌈duration·ρ/_DIFFUSION_STEP⌉ with ρ the largest eigenvalue of H⁻¹QH⁻¹, H = diag(h)
    (SDIRK2 is L-stable; this bounds its error on the modes the elements resolve).  One
    factorisation per element size: the operator depends on the elements' size only (the
    diffusion's mass and stiffness matrices are translation-invariant), so translated grids,
    grids that return to an earlier size and the parts of a mixture share it; the _CACHE most
    recently used are kept."""

    def __init__(self, model, substeps: int | None, duration: float):
        self.model, self.substeps, self.duration = model, substeps, duration
        self.cache: dict = {}
        self.factorisations = 0

    def __call__(self, g: FEMGrid, p: np.ndarray) -> np.ndarray:
        key = f"{g._h[0]:.12e} {g._h[1]:.12e}"  # a translated grid's h differs in the last bits
        prop = self.cache.pop(key, None)
        if prop is None:
            n = self.substeps
            if n is None:
                S = self.model.Q / np.outer(g._h, g._h)
                rho = 0.5 * (S[0, 0] + S[1, 1]) + np.hypot(0.5 * (S[0, 0] - S[1, 1]), S[0, 1])
                n = max(1, int(np.ceil(self.duration * rho / _DIFFUSION_STEP)))
            prop = _Propagator(g, self.model, n, "characteristics", False, self.duration)
            self.factorisations += 1
            if len(self.cache) >= _CACHE:
                del self.cache[next(iter(self.cache))]
        self.cache[key] = prop  # the most recent last
        return prop(p)


def _grid_size(need: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Side lengths of the next grid: the current ones while the needed size lies within
    [_SHRINK, 1] of them on both axes (a translated grid: its diffusion factorisation is kept), else
    the needed ones on both.  Refitting both axes keeps the elements small: rounding the sizes up to
    a ladder of rungs (2^¼ apart, so that factorisations could be re-used) or refitting only the
    axis that outgrew its side made the filter measurably less accurate (docs/nonlinear.md)."""
    keep = (need <= old) & (need >= _SHRINK * old)
    return old if keep.all() else need


def _transport_steps(model, g, p, diffusion: _Diffusion, width, splits, tau, fixed):
    """One dt of the characteristics scheme: ``splits`` Strang steps (see _characteristic_steps)."""
    shape = (g.n1, g.n2)
    before, regridded, lost, clipped = diffusion.factorisations, False, 0.0, 0.0
    for _ in range(splits):
        p, c = _clip_normalise(g, diffusion(g, p), "prediction")
        new = g
        if not fixed:
            _, m, P = g.moments(p)
            lo, hi = _predicted_box(model, m, P, width, 0.5 * float(np.min(g._h)), tau)
            size = _grid_size((1.0 + 2.0 * _MARGIN) * (hi - lo), g.hi - g.lo)
            centre = 0.5 * (lo + hi)
            new = FEMGrid(centre - 0.5 * size, centre + 0.5 * size, *shape)
        q, out = _push(g, p, new, model, tau)
        lost += out
        regridded = regridded or new is not g
        g = new
        p, c1 = _clip_normalise(g, q, "prediction")
        p, c2 = _clip_normalise(g, diffusion(g, p), "prediction")
        clipped += c + c1 + c2
    return g, p, diffusion.factorisations > before, regridded, lost, clipped


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
        fine = FEMGrid(g.lo, g.hi, _FOCUS * g.n1, _FOCUS * g.n2)
        logl = _log_likelihood(model, zk, fine.nodes)
        d = np.clip(g.evaluate(p, fine.nodes), 0.0, None) * np.exp(logl - logl.max())
        if not np.all(np.isfinite(d)) or d.max() <= 0.0:
            return [(g, p, 0.0)]
    lattice = fine._top["lattice"]
    img = np.zeros(fine._top["node_id"].shape)  # the half-spacing lattice; element centres have no node:
    img[lattice[:, 0], lattice[:, 1]] = d       # they get the mean of their four mid-side neighbours
    img[1::2, 1::2] = 0.25 * (img[:-1:2, 1::2] + img[2::2, 1::2] + img[1::2, :-1:2] + img[1::2, 2::2])
    labels, count = scipy.ndimage.label(img > _LEVEL * img.max(), structure=np.ones((3, 3)))
    ii, jj = np.nonzero(labels)
    lab, w = labels[ii, jj] - 1, img[ii, jj]
    X = fine.lo + 0.5 * fine._h * np.stack([ii, jj], axis=-1)
    mass = np.bincount(lab, weights=w, minlength=count)
    boxes = []
    for c in np.flatnonzero(mass > _MIN_MODE * mass.sum()):
        sel = lab == c
        mu = w[sel] @ X[sel] / mass[c]
        sd = np.maximum(np.sqrt(w[sel] @ (X[sel] - mu) ** 2 / mass[c]), 0.5 * fine._h)
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
        new = FEMGrid(np.maximum(lo - margin, g.lo), np.minimum(hi + margin, g.hi), g.n1, g.n2)
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
    a, b, c = g._top["triples"]
    on = d[b] > _LEVEL * d.max()
    return bool(np.max(np.abs(logl[a] - 2.0 * logl[b] + logl[c])[on], initial=0.0) <= _RESOLVED)


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
                g = FEMGrid(np.minimum(part.g.lo, o.g.lo), np.maximum(part.g.hi, o.g.hi), o.g.n1, o.g.n2)
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
    tau = model.dt / splits
    diffusion = _Diffusion(model, None if substeps is None else max(1, -(-substeps // (2 * splits))), 0.5 * tau)
    parts = [_Part(1.0, g, _clip_normalise(g, _gaussian_on(g, m, P), "P0")[0])]
    for k in range(z.shape[0]):
        factorised = regridded = False
        lost = clipped = 0.0
        for part in parts:
            try:
                part.g, part.p, f_, r_, l_, c_ = _transport_steps(model, part.g, part.p, diffusion, width,
                                                                  splits, tau, fixed)
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


def fem_filter(model: ContinuousDiscreteModel, z, x0, P0, **options) -> FilterResult:
    """The FEM grid filter (seed 004) as a FilterResult; options as for :func:`fem_steps`."""
    rows, loglik = [], 0.0
    for step in fem_steps(model, z, x0, P0, **options):  # the densities are not kept
        rows.append((step.x, step.P, step.x_pred, step.P_pred))
        loglik += step.loglik
    x, P, x_pred, P_pred = (np.array(col) for col in zip(*rows))
    return FilterResult(x=x, P=P, x_pred=x_pred, P_pred=P_pred, loglik=float(loglik), method="FEM")
