"""The time schemes of the FEM filter: how the density on a grid is carried over one dt.

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
sharp update (docs/decisions/2026-12-01-continuous-discrete.md).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.linalg.lapack
import scipy.sparse
import scipy.sparse.linalg

from .._core.unscented import sigma_points
from .._core.unscented import weights as _sigma_weights
from .._core.validation import check_int
from ..errors import ConvergenceError, NotPositiveDefiniteError, ShapeError
from ._fem_density import _clip_normalise, _raise
from ._fem_grid import FEMGrid, _nodal_derivatives, shape_functions, _topology
from ._fem_kernels import (
    band_cn,
    band_sdirk2,
    band_solve,
    deposit,
    diffuse_kept,
    element_band_cholesky,
    flow_points,
    flow_sites,
    mass_solve,
    next_grid,
    predict_dt,
    predicted_box,
    sigma_points_2d,
    transport_deposit,
    transport_split,
)
from ._kernels import compiled_model
from ._model import ContinuousDiscreteModel, rk4_flow

__all__ = ["SCHEMES", "fem_substeps", "default_substeps"]

SCHEMES = ("characteristics", "sdirk2", "cn", "paper")
_GAMMA = 1.0 - np.sqrt(0.5)
_MARGIN = 0.15   # a new box is the required one widened by this fraction on each side ...
_SHRINK = 0.4    # ... and it is redrawn when the required box falls below this fraction of it
_BAND_BYTES = 4 * 2**20   # largest band-LU factors; SuperLU beyond (see _factorise)
_SOLVE_DTYPE = np.float32  # precision of the factorisation and solves (see _factorise)


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
    (docs/decisions/2026-12-01-continuous-discrete.md): on 20 × 20 the band LU factorises 2× faster than SuperLU
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
    """Time steps per dt that :func:`fem_filter` takes on a grid when ``substeps`` is None.

    0.8 max(n1, n2), at least 8: a fixed Courant number (16 on 20 x 20).

    Parameters
    ----------
    grid : tuple of int
        (n1, n2) elements per axis.

    Returns
    -------
    int
    """
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
