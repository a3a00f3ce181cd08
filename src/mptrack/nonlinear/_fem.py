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
operator), the density carried along the back-traced characteristics of the
drift (Liouville: p(t+τ, x) = p(t, Φ₋τ(x))·|det DΦ₋τ(x)|) onto a grid placed
around the density predicted for t + τ, diffusion over τ/2 there.  The grid
only has to cover the density, not the path it travels, and nothing
oscillates when the drift dominates: with little diffusion the Galerkin
schemes below need a box spanning the whole move, elements wider than the
density, and lose the state (docs/nonlinear.md).

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

from .._validation import (
    as_array,
    broadcast_shape,
    check_allocation,
    check_int,
    check_positive,
    finite_result,
    require_finite,
)
from ..errors import ConvergenceError, ParameterError, ShapeError
from ..linear import FilterResult
from ._common import prepare_nonlinear
from ._fem_kernels import band_cn, band_sdirk2, band_solve
from ._model import ContinuousDiscreteModel
from ._ukf import sigma_points

__all__ = ["FEMGrid", "GridDensity", "FEMStep", "fem_filter", "fem_steps", "shape_functions"]

# reference element nodes: corners, then mid-sides (bottom, right, top, left)
_XI = np.array([-1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0, -1.0])
_ETA = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0])
# their offsets on the half-spacing lattice of an element
_DI = np.array([0, 2, 2, 0, 1, 2, 1, 0])
_DJ = np.array([0, 0, 2, 2, 0, 1, 2, 1])
_GAUSS3 = (np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)]), np.array([5.0, 8.0, 5.0]) / 9.0)


@finite_result("the shape functions")
def shape_functions(xi, eta):
    """Serendipity shape functions N (…, 8) and derivatives dN/dξ, dN/dη (seed 004 eqs. 11–12).

    Corners: N = ¼(1+ξξᵢ)(1+ηηᵢ)(ξξᵢ+ηηᵢ−1); mid-sides: ½(1−ξ²)(1+ηηᵢ) or ½(1+ξξᵢ)(1−η²).
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
               csc=(indices, indptr, slot.ravel()), band=(width, band_slot))
    for val in out.values():
        for arr in (val if isinstance(val, tuple) else (val,)):
            if isinstance(arr, np.ndarray):
                arr.setflags(write=False)
    return out


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
        if not np.all(np.isfinite(hi - lo)):
            raise ParameterError(f"hi: the box [lo, hi] is wider than the float64 range, lo={lo}, hi={hi}")
        n1 = check_int("n1", self.n1, minimum=1)
        n2 = check_int("n2", self.n2, minimum=1)
        check_allocation("n1", n1 * n2, 8.0 * 64 * (2 * n1 + 1) * (2 * n2 + 1))   # nodes and their matrices
        top = _topology(n1, n2)
        h = (hi - lo) / np.array([n1, n2])
        nodes = lo + 0.5 * h * top["lattice"]
        W0 = (h[0] * h[1]) * top["V0"]
        require_finite("the element areas", W0, lo=lo, hi=hi)
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
        u = (X - self.lo) / self._h
        inside = np.all((u >= 0.0) & (u <= np.array([self.n1, self.n2])), axis=-1)
        e = np.clip(np.floor(u).astype(np.int64), 0, np.array([self.n1, self.n2]) - 1)
        loc = 2.0 * (u - e) - 1.0
        N, _, _ = shape_functions(loc[..., 0], loc[..., 1])
        vals = np.einsum("...a,...a->...", N, p[self.conn[e[..., 0] * self.n2 + e[..., 1]]])
        return np.where(inside, vals, 0.0)

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


@dataclass(frozen=True, eq=False)
class GridDensity:
    """A density on a grid: nodal values ``p`` of a FEMGrid (∫ interpolant = 1)."""

    grid: FEMGrid
    p: np.ndarray

    def __call__(self, X) -> np.ndarray:
        return self.grid.evaluate(self.p, X)


@dataclass(frozen=True, eq=False)
class FEMStep:
    """One measurement step of the grid filter (what ``fem_steps`` yields)."""

    k: int                    # measurement index (time t = (k+1)·dt)
    prior: GridDensity
    posterior: GridDensity
    x_pred: np.ndarray
    P_pred: np.ndarray
    x: np.ndarray
    P: np.ndarray
    loglik: float
    clipped: float            # negative mass removed after the prediction
    lost: float               # mass outside the new box when the grid moved
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


SCHEMES = ("characteristics", "sdirk2", "cn")
_GAMMA = 1.0 - np.sqrt(0.5)
_MARGIN = 0.15   # a new box is the required one widened by this fraction on each side ...
_SHRINK = 0.4    # ... and it is redrawn when the required box falls below this fraction of it
_BAND_BYTES = 4 * 2**20   # largest band-LU factors; SuperLU beyond (see _factorise)
_SOLVE_DTYPE = np.float32  # precision of the factorisation and solves (see _factorise)
_PLACEMENT_STEPS = 4        # Heun steps of the noise-free flow used to place the grid
_FOCUS = 4                  # refinement of the lattice that locates a narrow posterior (_focus)


def _factorise(grid: FEMGrid, Be: np.ndarray):
    """Factorise the matrix assembled from element matrices Be (E, 8, 8): (solve, band).

    A band LU (LAPACK ?gbtrf, partial pivoting) in the natural lattice order,
    half-bandwidth ≈ 3·n2, while its factors fit in _BAND_BYTES; ``band`` is then
    (F, piv, kl) for the compiled kernels of _fem_kernels.  SuperLU with a
    fill-reducing ordering beyond (band None).  Factors are in _SOLVE_DTYPE
    (single precision); right-hand sides and solutions stay double.  Measured
    (docs/design.md): on 20 × 20 the band LU factorises 2× faster than SuperLU
    and solves faster; on 40 × 40 its factors make every solve slower.
    """
    width, slot = grid._top["band"]
    ld, N = 3 * width + 1, grid.size
    dtype = np.dtype(_SOLVE_DTYPE)
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
        Ae = np.ascontiguousarray(Ae)
        tau = (model.dt if duration is None else duration) / substeps
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


def default_substeps(grid: tuple[int, int]) -> int:
    """Time steps per dt of the grid filter by default: 0.8·max(n1, n2), at least 8 (a fixed Courant
    number; 16 on 20 × 20)."""
    return max(8, round(0.8 * max(grid)))


def _box(model, m, P, width, floor):
    """Rectangle covering mean ± width·σ now and after one dt.

    The predicted moments come from sigma points pushed through the noise-free
    flow (a few Heun steps) plus Q·dt: cheap, good enough to place a grid.  P is
    projected onto the PSD cone and its eigenvalues floored at ``floor``² first (a
    posterior narrower than an element has moments that are not trustworthy).
    """
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    P = (V * np.maximum(w, floor * floor)) @ V.T
    s = np.sqrt(np.diag(P))
    X, Wm, Wc = sigma_points(m, P)
    Y = model.flow(X, steps=_PLACEMENT_STEPS)
    mp = Wm @ Y
    sp = np.sqrt(np.clip(Wc @ (Y - mp) ** 2 + np.diag(model.Q) * model.dt, 0.0, None))
    lo = np.minimum(m - width * s, mp - width * sp)
    hi = np.maximum(m + width * s, mp + width * sp)
    return lo, hi


def _predicted_box(model, m, P, width, floor, duration):
    """Rectangle covering the predicted mean ± width·σ after ``duration`` (sigma points through
    the noise-free flow, plus Q·duration), σ floored at ``floor``."""
    X, Wm, Wc = sigma_points(m, P)
    Y = model.flow(X, duration, steps=_PLACEMENT_STEPS)
    mp = Wm @ Y
    sp = np.maximum(np.sqrt(np.clip(Wc @ (Y - mp) ** 2 + np.diag(model.Q) * duration, 0.0, None)), floor)
    return mp - width * sp, mp + width * sp


def _transport(old: FEMGrid, p: np.ndarray, new: FEMGrid, model, duration: float) -> np.ndarray:
    """Nodal values on ``new`` of the density p on ``old`` carried by the noise-free flow over τ =
    ``duration``: p(t + τ, x) = p(t, Φ₋τ(x))·|det DΦ₋τ(x)| (Liouville), the back-traced foot Φ₋τ(x)
    by Heun steps and its Jacobian by central differences."""
    X = new.nodes
    d = 1e-5 * max(1.0, float(np.max(np.abs(X))))
    e = d * np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    steps = max(_PLACEMENT_STEPS, int(np.ceil(model.substeps * duration / model.dt)))  # the model's Heun step
    Y = model.flow(np.concatenate([X[None], X[None] + e[:, None]]), -duration, steps)  # (5, N, 2), one call
    back = Y[0]
    J = np.stack([Y[1] - Y[2], Y[3] - Y[4]], axis=-1) / (2.0 * d)               # (N, 2, 2): ∂Φ/∂x_i columns
    return old.evaluate(p, back) * np.abs(np.linalg.det(J))


def _focus(g: FEMGrid, p: np.ndarray, model, zk, width: float):
    """The prior moved onto a grid around the posterior when the likelihood is much narrower
    than the prior (a range ring across a wide prior): the posterior's moments come from
    prior × likelihood on a lattice _FOCUS times finer than g; if mean ± width·σ of it is
    less than _SHRINK of g (per axis), the prior is re-interpolated onto a grid over that box
    (intersected with g), so that the update resolves the likelihood.  Returns (grid, p, log of
    the prior mass kept on it) — the last term belongs to the log evidence."""
    fine = FEMGrid(g.lo, g.hi, _FOCUS * g.n1, _FOCUS * g.n2)
    logl = model.log_likelihood(zk, fine.nodes)
    w = fine.W0 * np.clip(g.evaluate(p, fine.nodes), 0.0, None) * np.exp(logl - logl.max())
    total = w.sum()
    if not np.isfinite(total) or total <= 0.0:
        return g, p, 0.0
    mean = w @ fine.nodes / total
    sd = np.sqrt(np.clip(w @ (fine.nodes - mean) ** 2 / total, 0.0, None))
    sd = np.maximum(sd, 0.5 * fine._h)
    lo = np.maximum(mean - width * sd, g.lo)
    hi = np.minimum(mean + width * sd, g.hi)
    if np.any(hi - lo >= _SHRINK * (g.hi - g.lo)):
        return g, p, 0.0
    margin = _MARGIN * (hi - lo)
    new = FEMGrid(np.maximum(lo - margin, g.lo), np.minimum(hi + margin, g.hi), g.n1, g.n2)
    q = np.clip(g.evaluate(p, new.nodes), 0.0, None)
    kept = float(new.W0 @ q)
    if not np.isfinite(kept) or kept <= 0.0:
        return g, p, 0.0
    return new, q / kept, float(np.log(kept))


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

    grid      (n1, n2) elements per axis (seed 004: 20 × 20)
    width     half-width of the box in posterior standard deviations (section 3.1)
    substeps  time steps per dt; default 0.8·max(n1, n2), at least 8: a fixed Courant
              number, 16 on the paper's 20 × 20 grid, where 32 are no more accurate on
              eq. 42 and 8 are measurably less (docs/design.md)
    scheme    "characteristics" (default): Strang splitting — half a dt of diffusion by SDIRK2,
              the density carried along the back-traced characteristics of the drift onto a
              grid placed around the predicted density, half a dt of diffusion there;
              "sdirk2" (L-stable) or "cn" (Crank–Nicolson): the Galerkin drift–diffusion
              operator, accurate while the density moves less than its own width per element
              (docs/nonlinear.md: at low diffusion it loses the state)
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
        yield from _characteristic_steps(model, z, m, P, g, width, substeps, box is not None,
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
            prop = _Propagator(g, model, substeps, scheme, stabilise)
        p, clipped = _clip_normalise(g, prop(p), "prediction")
        prior = GridDensity(g, p)
        _, x_pred, P_pred = g.moments(p)
        ll = 0.0
        if not np.isnan(z[k]).all():
            p, ll = _bayes_update(g, p, model.log_likelihood(z[k], g.nodes), k)
        _, m, P = g.moments(p)
        yield FEMStep(k=k, prior=prior, posterior=GridDensity(g, p), x_pred=x_pred, P_pred=P_pred, x=m, P=P,
                      loglik=ll, clipped=clipped, lost=lost, regridded=regridded, factorised=factorised)


def _transport_steps(model, g, p, prop, width, splits, half, tau, fixed):
    """One dt of the characteristics scheme: ``splits`` Strang steps (see _characteristic_steps)."""
    shape = (g.n1, g.n2)
    factorised, regridded, lost, clipped = prop is None, False, 0.0, 0.0
    for _ in range(splits):
        if prop is None:
            prop = _Propagator(g, model, half, "characteristics", False, 0.5 * tau)
        p, c = _clip_normalise(g, prop(p), "prediction")
        new = g
        if not fixed:
            _, m, P = g.moments(p)
            lo, hi = _predicted_box(model, m, P, width, 0.5 * float(np.min(g._h)), tau)
            size, old = (1.0 + 2.0 * _MARGIN) * (hi - lo), g.hi - g.lo
            if np.all(size <= old) and np.all(size >= _SHRINK * old):
                size = old  # a translated grid: same elements, the diffusion LU is re-used
            centre = 0.5 * (lo + hi)
            new = FEMGrid(centre - 0.5 * size, centre + 0.5 * size, *shape)
        q = _transport(g, p, new, model, tau)
        if new is not g:
            lost += max(0.0, 1.0 - float(new.W0 @ np.clip(q, 0.0, None)))
            regridded = True
            if not np.array_equal(new.hi - new.lo, g.hi - g.lo):
                prop, factorised = _Propagator(new, model, half, "characteristics", False, 0.5 * tau), True
            g = new
        p, c1 = _clip_normalise(g, q, "prediction")
        p, c2 = _clip_normalise(g, prop(p), "prediction")
        clipped += c + c1 + c2
    return g, p, prop, factorised, regridded, lost, clipped


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


def _characteristic_steps(model, z, m, P, g: FEMGrid, width, substeps, fixed: bool, splits: int
                          ) -> Iterator[FEMStep]:
    """fem_steps with scheme="characteristics" from the initial grid g (arguments validated).

    Each dt is cut into ``splits`` intervals τ, each a Strang step: diffusion over τ/2 (SDIRK2 on
    the current grid), transport along the characteristics onto a grid placed around the density
    predicted for t + τ, diffusion over τ/2 there.
    """
    tau = model.dt / splits
    half = max(1, -(-substeps // (2 * splits)))
    p, _ = _clip_normalise(g, _gaussian_on(g, m, P), "P0")
    prop = None
    for k in range(z.shape[0]):
        g0, p0, m0, P0 = g, p, m, P
        try:
            g, p, prop, factorised, regridded, lost, clipped = _transport_steps(
                model, g, p, prop, width, splits, half, tau, fixed)
        except ConvergenceError:  # the characteristics left the grid (a stiff drift far out): Galerkin step
            g, p, factorised, regridded, lost, clipped = _galerkin_step(model, g0, p0, m0, P0, width, substeps,
                                                                        fixed)
            prop = None
        prior = GridDensity(g, p)
        _, x_pred, P_pred = g.moments(p)
        ll = 0.0
        if not np.isnan(z[k]).all():
            focused, p, log_kept = (g, p, 0.0) if fixed else _focus(g, p, model, z[k], width)
            if focused is not g:
                g, prop, regridded = focused, None, True
            p, ll = _bayes_update(g, p, model.log_likelihood(z[k], g.nodes), k)
            ll += log_kept
        _, m, P = g.moments(p)
        yield FEMStep(k=k, prior=prior, posterior=GridDensity(g, p), x_pred=x_pred, P_pred=P_pred, x=m, P=P,
                      loglik=ll, clipped=clipped, lost=lost, regridded=regridded, factorised=factorised)


@finite_result("the FEM filter")
def fem_filter(model: ContinuousDiscreteModel, z, x0, P0, **options) -> FilterResult:
    """The FEM grid filter (seed 004) as a FilterResult; options as for :func:`fem_steps`."""
    rows, loglik = [], 0.0
    for step in fem_steps(model, z, x0, P0, **options):  # the densities are not kept
        rows.append((step.x, step.P, step.x_pred, step.P_pred))
        loglik += step.loglik
    x, P, x_pred, P_pred = (np.array(col) for col in zip(*rows))
    return FilterResult(x=x, P=P, x_pred=x_pred, P_pred=P_pred, loglik=float(loglik), method="FEM")
