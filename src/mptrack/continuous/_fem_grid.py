"""The grid of the FEM (Fokker-Planck) filter (Zhao et al. 2013, section 3): serendipity elements on a
rectangle, their shape functions and the matrices and moments of an n1 x n2 grid.

Space: 8-node serendipity quadrilaterals (eqs. 7–14) on a rectangle of
n1 × n2 equal elements; Galerkin weak form with a zero-flux (reflecting)
boundary, so the semi-discrete system M dp/dt = A p,

    M_ij = ∫ φ_i φ_j,   A_ij = −½ ∫ ∇φ_i · Q ∇φ_j + ∫ (f · ∇φ_i) φ_j,

conserves ∫p exactly (Σ_i φ_i = 1).  Element matrices come from 3 × 3 Gauss
quadrature; the geometry-free data of an n1 × n2 grid is computed once.

Moments (eq. 27) are exact integrals of the interpolant: precomputed ∫φ_j, ∫φ_j x, ∫φ_j x x^T.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from .._core.finiteness import finite_result, require_finite
from .._core.validation import as_array, broadcast_shape, check_allocation, check_int
from ..errors import ParameterError
from ._fem_kernels import grid_moments, interpolate, stiffness_unit
from ._model import ContinuousDiscreteModel

__all__ = ["FEMGrid", "shape_functions"]

# reference element nodes: corners, then mid-sides (bottom, right, top, left)
_XI = np.array([-1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0, -1.0])
_ETA = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0])
# their offsets on the half-spacing lattice of an element
_DI = np.array([0, 2, 2, 0, 1, 2, 1, 0])
_DJ = np.array([0, 0, 2, 2, 0, 1, 2, 1])
_GAUSS3 = (np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)]), np.array([5.0, 8.0, 5.0]) / 9.0)


@finite_result("the shape functions")
def shape_functions(xi, eta):
    """The 8-node serendipity shape functions and their derivatives (Zhao et al. 2013, eqs. 11-12).

    Corners: N = (1 + xi xi_i)(1 + eta eta_i)(xi xi_i + eta eta_i - 1)/4; mid-sides:
    (1 - xi^2)(1 + eta eta_i)/2 or (1 + xi xi_i)(1 - eta^2)/2.

    Parameters
    ----------
    xi, eta : array_like
        Coordinates on the reference element [-1, 1]^2 (broadcast together).

    Returns
    -------
    N, dN_dxi, dN_deta : ndarray, shape (..., 8)

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


def _stiffness_unit(top: dict, S: np.ndarray) -> np.ndarray:
    """Â(S) = ½ Σ_de S_de G_de: the diffusion's element stiffness on a unit element (8, 8), with
    G_de = ∫ ∂_dφ ∂_eφᵀ in element units and S = H⁻¹QH⁻¹ (``stiffness_unit``)."""
    return stiffness_unit(top["G"], S[0, 0], S[0, 1], S[1, 1])
