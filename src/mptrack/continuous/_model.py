"""The continuous-discrete nonlinear model (Zhao et al. 2013, eq. 1) and its named examples.

    dx = f(x) dt + dβ,          E[dβ dβ^T] = Q dt     (Q constant, per second)
    z(k) = h(x(t_k)) + e(k),    e(k) ~ N(0, R),       t_k = k·dt

``f`` and ``h`` are vectorised: they map an array of points (..., n) to
(..., n) and (..., m), so the grid filter evaluates them on every node and
quadrature point at once and the particle filter on every particle.
The named models also carry compiled block kernels (:class:`BlockKernels`,
``mptrack.continuous._kernels``) that the particle filter and the UKF use instead.
Measurement components that are angles carry a wrap period (2π for an
``arctan2`` bearing): innovations of those components are wrapped into
[-period/2, period/2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import (
    as_matrix,
    as_vector,
    check_allocation,
    check_covariance,
    check_int,
    check_positive,
    check_rng,
    frozen,
)
from ..errors import ParameterError, ShapeError
from ..models import LinearGaussianModel, van_loan
from .._core.gaussian import gauss_logpdf, wrap_periods
from . import _kernels as kern
from ._kernels import SCHEMES, BlockKernels

__all__ = [
    "ContinuousDiscreteModel",
    "zhao2013_model",
    "linear_sde_model",
    "simulate_sde",
    "ZHAO2013_X0",
    "BlockKernels",
]


#: Zhao et al. 2013, section 6: initial state [-0.6, -1].
ZHAO2013_X0 = (-0.6, -1.0)


def _cap(inc: np.ndarray, cap: float | None) -> np.ndarray:
    """Scale increments (rows of (..., n)) longer than ``cap`` back to length ``cap``; no-op for None."""
    if cap is None:
        return inc
    norm = np.sqrt(np.sum(inc * inc, axis=-1, keepdims=True))
    return inc / (np.maximum(norm, cap) / cap)


def _rk4_step(f, X: np.ndarray, h: float, cap: float | None) -> np.ndarray:
    """One RK4 step of length h of the drift flow dx = f(x) dt, every stage increment and the
    step capped at length ``cap`` (:func:`_cap`)."""
    k1 = f(X)
    k2 = f(X + _cap(0.5 * h * k1, cap))
    k3 = f(X + _cap(0.5 * h * k2, cap))
    k4 = f(X + _cap(h * k3, cap))
    return X + _cap(h / 6 * (k1 + 2.0 * k2 + 2.0 * k3 + k4), cap)


def rk4_flow(model, X: np.ndarray, duration: float, steps: int) -> np.ndarray:
    """The points X (..., n) carried by the noise-free drift flow of ``model`` over ``duration``:
    ``steps`` RK4 steps, increments capped at ``model.max_increment`` (:func:`_rk4_step`)."""
    X = np.array(X, dtype=float)
    h = duration / steps
    for _ in range(steps):
        X = _rk4_step(model.drift, X, h, model.max_increment)
    return X


@dataclass(frozen=True, eq=False)
class ContinuousDiscreteModel:
    """A validated continuous-time SDE with discrete-time measurements (Zhao et al. 2013, eq. 1).

    drift        f: (..., n) -> (..., n), state units per second
    Q            (n, n) diffusion covariance per second (g Q g^T of eq. 3, constant)
    measurement  h: (..., n) -> (..., m)
    R            (m, m) measurement noise covariance, positive definite
    dt           seconds between measurements
    periods      per measurement component: wrap period of an angle (2π for a
                 bearing), or None for an ordinary component
    substeps     sub-steps per dt used when sampling the SDE (simulation, particle filter)
    linear       (A, H) when f(x) = A x and h(x) = H x (enables the exact discretisation)
    kernels      optional :class:`BlockKernels`: numba-compiled drift and measurement on
                 blocks of points (X (n, B) column-wise); the particle filter then runs
                 compiled (same numbers as the NumPy path, which models without kernels use)
    max_increment  opt-in taming of stiff or superlinear drifts: the largest drift increment
                 per sub-step, in state units (Euclidean length); None (default) = no cap.
                 Only for models whose state has a known scale: a cap of 1 on a model in
                 metres would limit the speed to 1 m per sub-step (the bug of issue 15).
                 :func:`zhao2013_model` sets 1 (its state is of order 1, see docs/nonlinear.md).

    References
    ----------
    .. [1] Y.-X. Zhao, L.-J. Chen and Y. Ma, "An FEM-based state estimation approach to nonlinear hybrid
           positioning systems", Mathematical Problems in Engineering, vol. 2013, Article ID 175425, 2013.
           doi:10.1155/2013/175425
    .. [2] M. Hutzenthaler, A. Jentzen and P. E. Kloeden, "Strong convergence of an explicit numerical method
           for SDEs with nonglobally Lipschitz continuous coefficients", The Annals of Applied Probability, vol.
           22, no. 4, pp. 1611–1641, 2012. doi:10.1214/11-AAP803
    """

    drift: Callable[[np.ndarray], np.ndarray]
    Q: np.ndarray
    measurement: Callable[[np.ndarray], np.ndarray]
    R: np.ndarray
    dt: float
    periods: tuple = field(default=None, kw_only=True)
    substeps: int = field(default=20, kw_only=True)
    linear: tuple | None = field(default=None, kw_only=True)
    name: str = field(default="", kw_only=True)
    kernels: BlockKernels | None = field(default=None, kw_only=True)
    max_increment: float | None = field(default=None, kw_only=True)

    def __post_init__(self) -> None:
        if not callable(self.drift):
            raise ParameterError(f"drift: expected a callable f(x), got {type(self.drift).__name__}")
        if not callable(self.measurement):
            raise ParameterError(f"measurement: expected a callable h(x), got {type(self.measurement).__name__}")
        Q = check_covariance("Q", self.Q)
        n = Q.shape[0]
        R = check_covariance("R", self.R, definite=True)
        m = R.shape[0]
        set_ = object.__setattr__
        set_(self, "Q", frozen(Q))
        set_(self, "R", frozen(R))
        set_(self, "dt", check_positive("dt", self.dt))
        set_(self, "substeps", check_int("substeps", self.substeps, minimum=1))
        if self.max_increment is not None:
            set_(self, "max_increment", check_positive("max_increment", self.max_increment))
        probe = np.zeros((3, n)) + np.linspace(-0.5, 0.5, 3)[:, None]
        for name, fn, width in (("drift", self.drift, n), ("measurement", self.measurement, m)):
            out = np.asarray(fn(probe))
            if out.shape != (3, width):
                raise ShapeError(f"{name}: must map points (k, {n}) to (k, {width}), got shape {out.shape} "
                                 f"for k = 3")
        periods = (None,) * m if self.periods is None else tuple(self.periods)
        if len(periods) != m:
            raise ShapeError(f"periods: expected {m} entries (one per measurement component), got {len(periods)}")
        set_(self, "periods", tuple(None if p is None else check_positive("periods", p) for p in periods))
        if self.linear is not None:
            A = as_matrix("linear[0] (A)", self.linear[0], n, n)
            H = as_matrix("linear[1] (H)", self.linear[1], m, n)
            set_(self, "linear", (frozen(A), frozen(H)))
        if self.kernels is not None and not isinstance(self.kernels, BlockKernels):
            raise ParameterError(f"kernels: expected a BlockKernels or None, got {type(self.kernels).__name__}")

    @property
    def n(self) -> int:
        return self.Q.shape[0]

    @property
    def m(self) -> int:
        return self.R.shape[0]

    def innovation(self, z, zhat) -> np.ndarray:
        """z - h, with angle components wrapped into [-period/2, period/2)."""
        return wrap_periods(np.asarray(z, dtype=float) - np.asarray(zhat, dtype=float), self.periods)

    def log_likelihood(self, z: np.ndarray, X: np.ndarray) -> np.ndarray:
        """log p(z | x) at points X (..., n) (Zhao et al. 2013, eq. 25); NaN components of z are skipped."""
        ok = ~np.isnan(z)
        return gauss_logpdf(self.innovation(z, self.measurement(X))[..., ok], self.R[np.ix_(ok, ok)])

    def flow(self, X: np.ndarray, duration: float | None = None, steps: int | None = None) -> np.ndarray:
        """The noise-free flow of dx = f(x) dt over ``duration`` (default dt), Heun sub-steps.

        Drift increments are capped at ``max_increment`` per sub-step as in
        :meth:`sample_transition` (when the model sets it).
        """
        duration = self.dt if duration is None else duration
        steps = self.substeps if steps is None else steps
        h = duration / steps
        X = np.array(X, dtype=float)
        f = self.drift
        cap = self.max_increment
        for _ in range(steps):
            fx = f(X)
            X = X + _cap(0.5 * h * (fx + f(X + _cap(h * fx, cap))), cap)
        return X

    def sample_transition(self, X: np.ndarray, rng: np.random.Generator, steps: int | None = None,
                          scheme: str = "heun") -> np.ndarray:
        """Sample x(t + dt) given x(t) = X (..., n) with ``steps`` sub-steps of length h = dt/steps.

        Both schemes have weak order 2 for additive noise; ΔW ~ N(0, Q h), one draw per sub-step.

        "heun"       stochastic Heun predictor–corrector:
                     x̃ = x + h f(x) + ΔW,  x⁺ = x + h/2 (f(x) + f(x̃)) + ΔW.
        "rk4-split"  Strang splitting of the generator: half a sub-step of the drift flow
                     (one RK4 step), the noise ΔW, the other half (one RK4 step). Deterministic
                     part of order 4, so far fewer sub-steps (the particle filter's default).

        When the model sets ``max_increment`` (opt-in; :func:`zhao2013_model` sets 1 as a
        guard against the superlinear printed eq. 42 drift), each drift increment (and
        each RK4 stage increment) is capped at that length in state units ("taming",
        Hutzenthaler, Jentzen & Kloeden 2012): diverging paths then grow without
        overflowing.  The cap is not scale-free, so models without a known state scale
        (every other constructor) leave it off.
        """
        if scheme not in SCHEMES:
            raise ParameterError(f"scheme: expected one of {SCHEMES}, got {scheme!r}")
        steps = self.substeps if steps is None else steps
        h = self.dt / steps
        L = self.noise_factor()
        X = np.array(X, dtype=float)
        sqh = np.sqrt(h)
        f, cap = self.drift, self.max_increment
        for _ in range(steps):
            dW = sqh * (rng.standard_normal(X.shape) @ L.T)
            if scheme == "heun":
                fx = f(X)
                Xp = X + _cap(h * fx, cap) + dW
                X = X + _cap(0.5 * h * (fx + f(Xp)), cap) + dW
            else:
                X = _rk4_step(f, _rk4_step(f, X, 0.5 * h, cap) + dW, 0.5 * h, cap)
        return X

    def noise_factor(self) -> np.ndarray:
        """L with L L^T = Q (eigen-decomposition, so a singular Q is fine)."""
        w, V = np.linalg.eigh(self.Q)
        return V * np.sqrt(np.clip(w, 0.0, None))

    def to_linear_gaussian(self) -> LinearGaussianModel:
        """The exact discretisation F = e^{AΔt}, Q_d = ∫ e^{As} Q e^{A^T s} ds of a linear model
        (Van Loan, via :func:`mptrack.models.van_loan`)."""
        if self.linear is None:
            raise ParameterError("model: only a linear model (built with linear_sde_model) has an exact "
                                 "discretisation")
        A, H = self.linear
        F, Qd = van_loan(A, np.eye(self.n), self.Q, self.dt)
        return LinearGaussianModel(F, H, Qd, self.R, dt=self.dt, name=f"{self.name} (exact)")


def zhao2013_model(*, variant: str = "printed", diffusion_scale: float = 1.0, bearing: str = "atan2",
                   dt: float = 1.0, substeps: int = 20) -> ContinuousDiscreteModel:
    """The example of Zhao et al. 2013, eq. 42: a Van der Pol-type drift observed by range and bearing.

    R = diag(0.1, 1) (range in state units, bearing in rad), x0 = ZHAO2013_X0.

    Parameters
    ----------
    variant : {"printed", "vdp"}, optional
        ``"printed"``: f(x) = [-x2, 0.2 (x1^2 - 1) x2 + x1] as printed, a time-reversed Van der Pol
        oscillator (stable origin inside an unstable limit cycle; with Q = diag(10, 0.1) almost every path
        diverges); ``"vdp"``: the standard orientation of the cited source (Beard et al. 1999),
        f(x) = [x2, -x1 + 0.2 (1 - x1^2) x2] (stable limit cycle).
    diffusion_scale : float, optional
        Q = diffusion_scale diag(10, 0.1) per second (1 = as printed).
    bearing : {"atan2", "atan"}, optional
        h2 = arctan2(x1, x2) wrapped modulo 2 pi (quadrant-correct; our default), or arctan(x1/x2) as
        printed, ambiguous modulo pi (x and -x give the same measurement: the paper's bimodality).
    dt : float, optional
        Time between measurements (s).
    substeps : int, optional
        Sub-steps per dt of the model's own integrations (simulation, RK4 flows).

    Returns
    -------
    ContinuousDiscreteModel
        With compiled kernels (BlockKernels).

    References
    ----------
    .. [1] Y.-X. Zhao, L.-J. Chen and Y. Ma, "An FEM-based state estimation approach to nonlinear hybrid
           positioning systems", Mathematical Problems in Engineering, vol. 2013, Article ID 175425, 2013.
           doi:10.1155/2013/175425
    .. [2] R. Beard, J. Gunther, J. Lawton and W. Stirling, "Nonlinear projection filter based on Galerkin
           approximation", Journal of Guidance, Control, and Dynamics, vol. 22, no. 2, pp. 258–266, 1999.

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.continuous import ZHAO2013_X0, simulate_sde, zhao2013_model
    >>> model = zhao2013_model(variant="vdp", diffusion_scale=0.01)
    >>> truth, z = simulate_sde(model, 5, np.random.default_rng(0), ZHAO2013_X0)
    >>> truth.shape, z.shape
    ((5, 2), (5, 2))
    """
    if variant == "printed":
        drift_kernel = kern.printed_drift

        def drift(X):
            x1, x2 = X[..., 0], X[..., 1]
            return np.stack([-x2, 0.2 * (x1 * x1 - 1.0) * x2 + x1], axis=-1)
    elif variant == "vdp":
        drift_kernel = kern.vdp_drift

        def drift(X):
            x1, x2 = X[..., 0], X[..., 1]
            return np.stack([x2, -x1 + 0.2 * (1.0 - x1 * x1) * x2], axis=-1)
    else:
        raise ParameterError(f"variant: expected 'printed' or 'vdp', got {variant!r}")
    if bearing == "atan2":
        measurement_kernel = kern.range_atan2

        def measurement(X):
            x1, x2 = X[..., 0], X[..., 1]
            return np.stack([np.hypot(x1, x2), np.arctan2(x1, x2)], axis=-1)
        period = 2.0 * np.pi
    elif bearing == "atan":
        measurement_kernel = kern.range_atan

        def measurement(X):
            x1, x2 = X[..., 0], X[..., 1]
            # arctan(x1/x2) without dividing by zero: arctan2 folded into (-π/2, π/2]
            b = np.arctan2(x1, x2)
            return np.stack([np.hypot(x1, x2), (b + 0.5 * np.pi) % np.pi - 0.5 * np.pi], axis=-1)
        period = np.pi
    else:
        raise ParameterError(f"bearing: expected 'atan2' or 'atan', got {bearing!r}")
    scale = check_positive("diffusion_scale", diffusion_scale)
    return ContinuousDiscreteModel(drift, scale * np.diag([10.0, 0.1]), measurement, np.diag([0.1, 1.0]), dt,
                                   periods=(None, period), substeps=substeps,
                                   name=f"zhao2013 eq. 42 ({variant}, Q x {scale:g}, {bearing})",
                                   kernels=BlockKernels(drift_kernel, measurement_kernel, np.zeros(0), np.zeros(0)),
                                   max_increment=1.0)


def linear_sde_model(A, Q, H, R, dt: float, *, substeps: int = 20, name: str = "") -> ContinuousDiscreteModel:
    """A linear SDE observed linearly: dx = A x dt + dbeta (E dbeta dbeta^T = Q dt), z = H x + e.

    The linear-Gaussian test case of the grid filters: ``to_linear_gaussian()`` gives its exact (Van Loan)
    discretisation, whose Kalman filter is the exact answer.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Drift matrix.
    Q : array_like, shape (n, n)
        Diffusion, symmetric positive semi-definite (per second).
    H : array_like, shape (m, n)
        Measurement matrix.
    R : array_like, shape (m, m)
        Measurement-noise covariance.
    dt : float
        Time between measurements (s).
    substeps : int, optional
        Sub-steps per dt of the model's own integrations.
    name : str, optional

    Returns
    -------
    ContinuousDiscreteModel
        With compiled kernels.
    """
    A = as_matrix("A", A)
    if A.shape[0] != A.shape[1]:
        raise ShapeError(f"A: expected a square matrix, got shape {A.shape}")
    H = as_matrix("H", H, None, A.shape[0])
    At, Ht = A.T.copy(), H.T.copy()
    kernels = BlockKernels(kern.linear_map, kern.linear_map, A, H)  # row-major A, H: out = M x
    return ContinuousDiscreteModel(lambda X: X @ At, Q, lambda X: X @ Ht, R, dt, substeps=substeps,
                                   linear=(A, H), name=name or "linear SDE", kernels=kernels)


@finite_result("the simulated path")
def simulate_sde(model: ContinuousDiscreteModel, steps: int, rng: np.random.Generator, x0,
                 *, substeps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sample the truth x(t_k) and the measurements z(k), k = 1..steps, from x(0) = x0.

    The path is integrated by ``model.sample_transition`` in its default scheme, the stochastic Heun
    predictor-corrector (weak order 2 for additive noise); drift increments are capped only when the
    model sets ``max_increment`` (as :func:`zhao2013_model` does).  Row k-1 is time k, as for the linear
    filters.

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
    steps : int
        Number of measurement times, >= 1.
    rng : numpy.random.Generator
    x0 : array_like, shape (n,)
        The initial state.
    substeps : int, optional
        Sub-steps per dt (default 5 model.substeps).

    Returns
    -------
    truth : ndarray, shape (steps, n)
    z : ndarray, shape (steps, m)
    """
    if not isinstance(model, ContinuousDiscreteModel):
        raise ParameterError(f"model: expected a ContinuousDiscreteModel, got {type(model).__name__}")
    check_rng(rng)
    steps = check_int("steps", steps, minimum=1)
    check_allocation("steps", steps, 16.0 * steps * (model.n + model.m))
    x = as_vector("x0", x0, model.n)
    substeps = 5 * model.substeps if substeps is None else check_int("substeps", substeps, minimum=1)
    truth = np.empty((steps, model.n))
    for k in range(steps):
        x = model.sample_transition(x, rng, substeps)
        truth[k] = x
    Lr = np.linalg.cholesky(model.R)
    z = model.measurement(truth) + rng.standard_normal((steps, model.m)) @ Lr.T
    return truth, wrap_periods(z, model.periods)
