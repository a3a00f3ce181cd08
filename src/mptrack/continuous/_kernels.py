"""Compiled (numba) kernels of the continuous-discrete filters (particle filter, UKF) and the model kernels
they call.

A model may carry :class:`BlockKernels`: njit functions that evaluate the drift
and the measurement at a *block* of points stored column-wise,
``drift(X, params, out)`` and ``measurement(X, params, out)`` with X (n, B),
out (n, B) resp. (m, B) written in place and params a float64 vector (e.g. the
matrix of a linear model).  Columns, not rows: the loops over the B points of a
block then run over contiguous memory and LLVM turns them into SIMD
instructions (AVX2/AVX-512): ~10× faster than one point at a time, which is
latency-bound (measured on eq. 42: 0.27 ms against 2.5 ms for 4·10⁴ RK4 steps).

:class:`CompiledModel` runs the same stochastic schemes as
:meth:`ContinuousDiscreteModel.sample_transition` and the same weighting as
:meth:`ContinuousDiscreteModel.log_likelihood`, compiled, with the same
arithmetic in the same order (no fastmath, so no reordering or FMA
contraction): the tests check them against the NumPy methods, which stay the
readable definition and the path for models without kernels.

Randomness: the normal increments of all sub-steps are drawn first from the
caller's ``numpy.random.Generator``; numba's ``standard_normal`` is NumPy's
ziggurat on the same bit generator, so the draws are exactly NumPy's, in
NumPy's order (sub-step, particle, component), and the state of the generator
advances as with NumPy.  The kernels are serial: on the shared 2-core machine a
parallel (``prange``) version was 3–12× *slower* whenever the other core was
busy (OpenMP threads waiting for a descheduled peer), and serial SIMD code
already meets the budget.

The kernels that call a model kernel receive it as two addresses (its C wrapper and
its numba entry point, :func:`kernel_addresses`) and rebuild a first-class
function from them inside (:func:`_as_kernel`).  Their signatures then hold only
arrays and integers, so they are compiled once and cached on disk like the others:
a new process calls the particle filter of any model, named or the user's own,
without compiling (a per-process closure over the kernels used to cost 1-2 s per
model kernel pair at the first call).  Passing the kernel itself as an argument
would also cache, but numba types a function object at every call (~50-150 us,
against 0.5 us for two integers).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.experimental.function_type import _get_jit_address, _get_wrapper_address
from numba.extending import intrinsic, is_jitted

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from ..errors import ParameterError
from .._core.kalman import DIVERGED, NOT_PD, OK, cholesky, finite, store, symmetrise, unscented_update

__all__ = ["BlockKernels", "CompiledModel", "compiled_model", "SCHEMES"]

_LOG2PI = np.log(2.0 * np.pi)
#: sub-step schemes of the SDE sampler: stochastic Heun, and Strang splitting with RK4 drift flows
SCHEMES = ("heun", "rk4-split")
_HEUN = SCHEMES.index("heun")  # the other scheme, "rk4-split", is 1
_BLOCK = 256  # points per block: the (n, B) scratch arrays stay in L1
#: the signature of a block kernel f(X (n, B), params (k,), out (m, B)): C-contiguous float64, params read-only
KERNEL_SIGNATURE = types.void(types.float64[:, ::1], types.Array(types.float64, 1, "C", readonly=True),
                              types.float64[:, ::1])
_KERNEL_TYPE = types.FunctionType(KERNEL_SIGNATURE)


def kernel_addresses(kernel) -> tuple[int, int]:
    """The C-wrapper and numba entry-point addresses of a block kernel compiled for
    :data:`KERNEL_SIGNATURE` (compiling it for that signature if needed)."""
    return _get_wrapper_address(kernel, KERNEL_SIGNATURE), _get_jit_address(kernel, KERNEL_SIGNATURE)


@intrinsic
def _as_kernel(typingctx, c_addr, jit_addr):
    """The block kernel at the addresses of :func:`kernel_addresses`, as a first-class function."""

    def codegen(context, builder, signature, args):
        fn = cgutils.create_struct_proxy(_KERNEL_TYPE)(context, builder)
        voidptr = context.get_value_type(types.voidptr)
        fn.c_addr = builder.inttoptr(args[0], voidptr)
        fn.py_addr = voidptr(None)   # no Python object: every call goes through an address
        if "jit_addr" in context.data_model_manager.lookup(_KERNEL_TYPE)._fields:
            fn.jit_addr = builder.inttoptr(args[1], voidptr)
        return fn._getvalue()

    return _KERNEL_TYPE(types.intp, types.intp), codegen


@dataclass(frozen=True, eq=False)
class BlockKernels:
    """Compiled block versions of a model's drift and measurement (see the module docstring)."""

    drift: object
    measurement: object
    drift_params: np.ndarray
    measurement_params: np.ndarray

    def __post_init__(self) -> None:
        for name in ("drift", "measurement"):
            if not is_jitted(getattr(self, name)):
                raise ParameterError(f"kernels.{name}: expected a numba.njit function f(X, params, out), "
                                     f"got {type(getattr(self, name)).__name__}")
        for name in ("drift_params", "measurement_params"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=float).ravel()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


# ---------------------------------------------------------------- block kernels of the named models
@njit(cache=True, nogil=True)
def vdp_drift(X, p, out):  # pragma: no cover - compiled
    """Standard Van der Pol orientation of eq. 42: [x2, -x1 + 0.2(1 - x1²)x2]."""
    for j in range(X.shape[1]):
        out[0, j] = X[1, j]
        out[1, j] = -X[0, j] + 0.2 * (1.0 - X[0, j] * X[0, j]) * X[1, j]


@njit(cache=True, nogil=True)
def printed_drift(X, p, out):  # pragma: no cover - compiled
    """Eq. 42 as printed: [-x2, 0.2(x1² - 1)x2 + x1]."""
    for j in range(X.shape[1]):
        out[0, j] = -X[1, j]
        out[1, j] = 0.2 * (X[0, j] * X[0, j] - 1.0) * X[1, j] + X[0, j]


@njit(cache=True, nogil=True)
def range_atan2(X, p, out):  # pragma: no cover - compiled
    for j in range(X.shape[1]):
        out[0, j] = np.sqrt(X[0, j] * X[0, j] + X[1, j] * X[1, j])  # = np.hypot to rounding
        out[1, j] = np.arctan2(X[0, j], X[1, j])


@njit(cache=True, nogil=True)
def range_atan(X, p, out):  # pragma: no cover - compiled
    for j in range(X.shape[1]):
        out[0, j] = np.sqrt(X[0, j] * X[0, j] + X[1, j] * X[1, j])  # = np.hypot to rounding
        out[1, j] = (np.arctan2(X[0, j], X[1, j]) + 0.5 * np.pi) % np.pi - 0.5 * np.pi


@njit(cache=True, nogil=True)
def linear_map(X, p, out):  # pragma: no cover - compiled
    """out = M X with M = p.reshape(len(out), len(X)) (row-major)."""
    n = X.shape[0]
    for r in range(out.shape[0]):
        for j in range(X.shape[1]):
            out[r, j] = 0.0
        for c in range(n):
            a = p[r * n + c]
            for j in range(X.shape[1]):
                out[r, j] += X[c, j] * a


# ---------------------------------------------------------------- schemes on a block (n, B)
@njit(nogil=True)
def _add_capped(x, a, k, out, d, cap):  # pragma: no cover - compiled
    """out = x + inc / (max(|inc|, cap) / cap) per column with inc = a·k (``_model._cap``; cap = inf:
    no cap); d is scratch (B,)."""
    n, B = x.shape
    capped = 0
    if cap < np.inf:
        cap2 = cap * cap
        if n == 2:  # the usual case in one pass (the same sum in the same order)
            for j in range(B):
                d[j] = 0.0 + (a * k[0, j]) * (a * k[0, j]) + (a * k[1, j]) * (a * k[1, j])
                capped += d[j] > cap2
        else:
            for j in range(B):
                d[j] = 0.0
            for r in range(n):
                for j in range(B):
                    d[j] += (a * k[r, j]) * (a * k[r, j])
            for j in range(B):
                capped += d[j] > cap2
    if capped == 0:  # the usual case: dividing by max(|inc|, cap) / cap = 1 would change nothing
        for r in range(n):
            for j in range(B):
                out[r, j] = x[r, j] + a * k[r, j]
        return
    for j in range(B):
        d[j] = max(np.sqrt(d[j]), cap) / cap
    for r in range(n):
        for j in range(B):
            out[r, j] = x[r, j] + a * k[r, j] / d[j]


@njit(nogil=True)
def _rk4(x, h, drift, p, k1, k2, k3, k4, y, inc, d, cap):  # pragma: no cover - compiled
    """x <- one capped RK4 step of the drift flow of length h (``_model._rk4_step``)."""
    n, B = x.shape
    hh = 0.5 * h
    drift(x, p, k1)
    _add_capped(x, hh, k1, y, d, cap)
    drift(y, p, k2)
    _add_capped(x, hh, k2, y, d, cap)
    drift(y, p, k3)
    _add_capped(x, h, k3, y, d, cap)
    drift(y, p, k4)
    h6 = h / 6.0
    for r in range(n):
        for j in range(B):
            inc[r, j] = h6 * (k1[r, j] + 2.0 * k2[r, j] + 2.0 * k3[r, j] + k4[r, j])
    _add_capped(x, 1.0, inc, x, d, cap)


@njit(nogil=True)
def _load(X, start, x):  # pragma: no cover - compiled
    """x (n, B) <- rows start.. of X (N, n) transposed; a short last block repeats its last row."""
    n, B = x.shape
    last = X.shape[0] - 1
    for j in range(B):
        i = min(start + j, last)
        for r in range(n):
            x[r, j] = X[i, r]


@njit(nogil=True)
def _advance(X, Z, scheme, drift, p, L, h, cap):  # pragma: no cover - compiled
    """Advance every particle (rows of X) by len(Z) sub-steps of length h with the normals Z (S, N, n)."""
    N, n = X.shape
    S = Z.shape[0]
    B = _BLOCK
    sqh = np.sqrt(h)
    hh = 0.5 * h
    x, y, dW, inc, zb = np.empty((n, B)), np.empty((n, B)), np.empty((n, B)), np.empty((n, B)), np.empty((n, B))
    k1, k2, k3, k4 = np.empty((n, B)), np.empty((n, B)), np.empty((n, B)), np.empty((n, B))
    d = np.empty(B)
    for start in range(0, N, B):
        _load(X, start, x)
        for s in range(S):
            _load(Z[s], start, zb)
            for r in range(n):  # dW = sqh (L zb), summed as NumPy's sqh * (Z @ L.T)
                for j in range(B):
                    dW[r, j] = 0.0
                for c in range(n):
                    a = L[r, c]
                    for j in range(B):
                        dW[r, j] += zb[c, j] * a
                for j in range(B):
                    dW[r, j] = sqh * dW[r, j]
            if scheme == _HEUN:
                drift(x, p, k1)
                _add_capped(x, h, k1, y, d, cap)
                for r in range(n):
                    for j in range(B):
                        y[r, j] += dW[r, j]
                drift(y, p, k2)
                for r in range(n):
                    for j in range(B):
                        inc[r, j] = hh * (k1[r, j] + k2[r, j])
                _add_capped(x, 1.0, inc, x, d, cap)
                for r in range(n):
                    for j in range(B):
                        x[r, j] += dW[r, j]
            else:
                _rk4(x, hh, drift, p, k1, k2, k3, k4, y, inc, d, cap)
                for r in range(n):
                    for j in range(B):
                        x[r, j] += dW[r, j]
                _rk4(x, hh, drift, p, k1, k2, k3, k4, y, inc, d, cap)
        for j in range(min(B, N - start)):
            for r in range(n):
                X[start + j, r] = x[r, j]


@njit(nogil=True)
def _flow(X, drift, p, h, steps, cap):  # pragma: no cover - compiled
    """Advance the rows of X (N, n) in place by ``steps`` capped RK4 steps of length h of the
    noise-free drift flow (``_model._rk4_step``, the same arithmetic)."""
    N, n = X.shape
    B = _BLOCK
    x, y, inc = np.empty((n, B)), np.empty((n, B)), np.empty((n, B))
    k1, k2, k3, k4 = np.empty((n, B)), np.empty((n, B)), np.empty((n, B)), np.empty((n, B))
    d = np.empty(B)
    for start in range(0, N, B):
        _load(X, start, x)
        for _ in range(steps):
            _rk4(x, h, drift, p, k1, k2, k3, k4, y, inc, d, cap)
        for j in range(min(B, N - start)):
            for r in range(n):
                X[start + j, r] = x[r, j]


# ---------------------------------------------------------------- weighting
@njit(nogil=True)
def _loglik(X, z, ok, periods, Linv, logdet, klog2pi, measurement, p, m):  # pragma: no cover - compiled
    N, n = X.shape
    k = ok.shape[0]
    B = _BLOCK
    x, hx, nu = np.empty((n, B)), np.empty((m, B)), np.empty((k, B))
    q, w = np.empty(B), np.empty(B)
    out = np.empty(N)
    for start in range(0, N, B):
        _load(X, start, x)
        measurement(x, p, hx)
        for a in range(k):
            c = ok[a]
            per = periods[c]
            for j in range(B):
                v = z[c] - hx[c, j]
                # wrap into [-per/2, per/2): v itself inside, else NumPy's (v + per/2) % per - per/2 to rounding
                nu[a, j] = v - per * np.floor((v + 0.5 * per) / per) if per > 0.0 else v
        for j in range(B):
            q[j] = 0.0
        for r in range(k):  # q = |Linv nu|², summed in the order of NumPy's (nu @ Linv.T)² row sums
            for j in range(B):
                w[j] = 0.0
            for c in range(k):
                a = Linv[r, c]
                for j in range(B):
                    w[j] += nu[c, j] * a
            for j in range(B):
                q[j] += w[j] * w[j]
        for j in range(min(B, N - start)):
            out[start + j] = -0.5 * (q[j] + logdet + klog2pi)
    return out


@njit(cache=True, nogil=True)
def _advance_at(X, rng, steps, scheme, drift_c, drift_jit, p, L, h, cap):  # pragma: no cover - compiled
    """:func:`_advance` with the normals drawn here and the drift given by its addresses."""
    _advance(X, rng.standard_normal((steps, X.shape[0], X.shape[1])), scheme, _as_kernel(drift_c, drift_jit), p,
             L, h, cap)


@njit(cache=True, nogil=True)
def _loglik_at(X, z, ok, periods, Linv, logdet, klog2pi, meas_c, meas_jit, p, m):  # pragma: no cover - compiled
    """:func:`_loglik` with the measurement given by its addresses."""
    return _loglik(X, z, ok, periods, Linv, logdet, klog2pi, _as_kernel(meas_c, meas_jit), p, m)


@njit(cache=True, nogil=True)
def _flow_at(X, drift_c, drift_jit, p, h, steps, cap):  # pragma: no cover - compiled
    """:func:`_flow` with the drift given by its addresses."""
    _flow(X, _as_kernel(drift_c, drift_jit), p, h, steps, cap)


class CompiledModel:
    """A model's compiled kernels with the constants of a filter run computed once: the compiled
    twins of ``sample_transition`` (:meth:`propagate`) and ``log_likelihood`` (:meth:`log_likelihood`)."""

    def __init__(self, model) -> None:
        if model.kernels is None:
            raise ParameterError("model: has no compiled kernels (build it with zhao2013_model or "
                                 "linear_sde_model, or pass kernels=BlockKernels(...))")
        self.model = model
        self.kernels = model.kernels
        self.L = np.ascontiguousarray(model.noise_factor())
        self.periods = np.array([0.0 if p is None else p for p in model.periods])
        self.drift_at = kernel_addresses(self.kernels.drift)
        self.measurement_at = kernel_addresses(self.kernels.measurement)
        self._check_against_numpy()
        self._weighting = {}  # pattern of observed components -> (indices, Linv, log det, k log 2π)

    def _check_against_numpy(self) -> None:
        """The kernels must compute what the model's NumPy callables compute: compare on a few points."""
        model, kn = self.model, self.kernels
        probe = np.linspace(-1.3, 1.7, 5)[:, None] * np.linspace(1.0, -0.6, model.n)[None, :] + 0.1
        f, h = np.empty((model.n, 5)), np.empty((model.m, 5))
        kn.drift(np.ascontiguousarray(probe.T), kn.drift_params, f)
        kn.measurement(np.ascontiguousarray(probe.T), kn.measurement_params, h)
        for name, got, want in (("drift", f.T, model.drift(probe)),
                                ("measurement", model.innovation(h.T, model.measurement(probe)), 0.0)):
            if not np.allclose(got, want, rtol=1e-9, atol=1e-9):
                raise ParameterError(f"kernels.{name}: the compiled kernel disagrees with model.{name} "
                                     f"(largest difference {np.max(np.abs(got - want)):.3g} on probe points)")

    def propagate(self, X: np.ndarray, rng: np.random.Generator, steps: int, scheme: str) -> np.ndarray:
        """Advance the particles X (N, n) (C-contiguous float64) in place by ``steps`` sub-steps."""
        if scheme not in SCHEMES:
            raise ParameterError(f"scheme: expected one of {SCHEMES}, got {scheme!r}")
        cap = np.inf if self.model.max_increment is None else self.model.max_increment
        _advance_at(X, rng, steps, SCHEMES.index(scheme), *self.drift_at, self.kernels.drift_params, self.L,
                    self.model.dt / steps, cap)
        return X

    def flow(self, X: np.ndarray, duration: float, steps: int) -> np.ndarray:
        """The points X (N, n) carried by the noise-free drift flow over ``duration``: ``steps``
        capped RK4 steps (the compiled twin of :func:`_model.rk4_flow`); returns a new array."""
        X = np.array(X, dtype=float, order="C")
        cap = np.inf if self.model.max_increment is None else self.model.max_increment
        _flow_at(X, *self.drift_at, self.kernels.drift_params, duration / steps, steps, cap)
        return X

    def log_likelihood(self, z: np.ndarray, X: np.ndarray) -> np.ndarray:
        """log p(z | x) at the particles X (N, n); NaN components of z are skipped."""
        ok = ~np.isnan(z)
        key = ok.tobytes()
        if key not in self._weighting:
            L = np.linalg.cholesky(self.model.R[np.ix_(ok, ok)])
            self._weighting[key] = (np.flatnonzero(ok), np.linalg.inv(L), 2.0 * np.log(np.diag(L)).sum(),
                                    ok.sum() * _LOG2PI)
        idx, Linv, logdet, klog2pi = self._weighting[key]
        return _loglik_at(X, z, idx, self.periods, Linv, logdet, klog2pi, *self.measurement_at,
                          self.kernels.measurement_params, self.model.m)


_COMPILED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def compiled_model(model) -> CompiledModel:
    """The :class:`CompiledModel` of ``model``, built (and checked against the NumPy callables) once per
    model object: the filters of a study call it for every run."""
    found = _COMPILED.get(model)
    if found is None:
        found = _COMPILED[model] = CompiledModel(model)
    return found


# ---------------------------------------------------------------- continuous-discrete UKF
#: the sub-step h of the UKF's moment equations keeps h * rho <= RATE_STEP, rho the drift's rate
#: (the largest row sum of |df/dx| at the sigma points): see mptrack.continuous._ukf
RATE_STEP = 0.25
MAX_SUBSTEPS = 10_000


@njit(cache=True, nogil=True)
def _sigma_columns(m, P, c, X, S, L):  # pragma: no cover - compiled
    """The 2n+1 sigma points of N(m, P) as the columns of X (n, 2n+1); False when c P has no Cholesky
    factor (S, L: (n, n) scratch)."""
    n = m.shape[0]
    for a in range(n):
        for b in range(n):
            S[a, b] = c * P[a, b]
    if not cholesky(S, L, n):
        return False
    for a in range(n):
        X[a, 0] = m[a]
        for i in range(n):
            X[a, 1 + i] = m[a] + L[a, i]
            X[a, 1 + n + i] = m[a] - L[a, i]
    return True


@njit(cache=True, nogil=True)
def drift_rate(drift, p, X, Xd, Fd):  # pragma: no cover - compiled
    """rho = max over the points X (n, N) of the largest row sum of |df/dx| (forward differences with
    steps 1e-6 (1 + |x|)); Xd, Fd: (n, N (n + 1)) scratch."""
    n, N = X.shape
    for j in range(N):
        for i in range(n + 1):
            for a in range(n):
                Xd[a, j * (n + 1) + i] = X[a, j]
            if i > 0:
                Xd[i - 1, j * (n + 1) + i] += 1e-6 * (1.0 + abs(X[i - 1, j]))
    drift(Xd, p, Fd)
    rho = 0.0
    for j in range(N):
        base = j * (n + 1)
        for a in range(n):
            row = 0.0
            for i in range(n):
                row += abs(Fd[a, base + 1 + i] - Fd[a, base]) / (Xd[i, base + 1 + i] - X[i, j])
            rho = max(rho, row)
    return rho


@njit(cache=True, nogil=True)
def substeps_for(rho, dt):  # pragma: no cover - compiled
    """Sub-steps of length h <= RATE_STEP / rho over dt (at least 1, at most MAX_SUBSTEPS)."""
    if not rho < np.inf:
        return MAX_SUBSTEPS
    return min(max(int(np.ceil(dt * rho / RATE_STEP)), 1), MAX_SUBSTEPS)


@njit(cache=True, nogil=True)
def _moment_rate(m, P, c, Wm, Wc, Q, drift, p, X, F, S, L, dm, dP):  # pragma: no cover - compiled
    """dm = E f(x), dP = E[f (x - m)^T] + E[(x - m) f^T] + Q by the unscented transform; False when P
    has no square root."""
    n, N = X.shape
    if not _sigma_columns(m, P, c, X, S, L):
        return False
    drift(X, p, F)
    for a in range(n):
        acc = 0.0
        for j in range(N):
            acc += Wm[j] * F[a, j]
        dm[a] = acc
    for a in range(n):
        for b in range(n):
            acc = 0.0
            for j in range(N):
                acc += Wc[j] * F[a, j] * (X[b, j] - m[b])
            S[a, b] = acc
    for a in range(n):
        for b in range(n):
            dP[a, b] = S[a, b] + S[b, a] + Q[a, b]
    return True


@njit(cache=True, nogil=True)
def _cd_predict(m, P, h, steps, c, Wm, Wc, Q, drift, p, X, F, S, L, k):  # pragma: no cover - compiled
    """RK4 over ``steps`` sub-steps of length h of the unscented moment equations, in place; k: (4, 2, n, n)
    scratch (stage rates: k[s, 0, :, 0] the mean's, k[s, 1] the covariance's)."""
    n = m.shape[0]
    mt, Pt = np.empty(n), np.empty((n, n))
    for _ in range(steps):
        for s in range(4):
            if s == 0:
                mt[:] = m
                Pt[:, :] = P
            else:
                a = h if s == 3 else 0.5 * h
                for r in range(n):
                    mt[r] = m[r] + a * k[s - 1, 0, r, 0]
                    for q in range(n):
                        Pt[r, q] = P[r, q] + a * k[s - 1, 1, r, q]
            if not _moment_rate(mt, Pt, c, Wm, Wc, Q, drift, p, X, F, S, L, k[s, 0, :, 0], k[s, 1]):
                return False
        h6 = h / 6.0
        for r in range(n):
            m[r] += h6 * (k[0, 0, r, 0] + 2.0 * k[1, 0, r, 0] + 2.0 * k[2, 0, r, 0] + k[3, 0, r, 0])
            for q in range(n):
                P[r, q] += h6 * (k[0, 1, r, q] + 2.0 * k[1, 1, r, q] + 2.0 * k[2, 1, r, q] + k[3, 1, r, q])
        symmetrise(P)
    return True


@njit(cache=True, nogil=True)
def cd_ukf_run(z, x0, P0, dt, fixed_steps, drift_c, drift_jit, dp, meas_c, meas_jit, mp, periods, Q, R, c, Wm, Wc,
               xs, Ps, xp, Pp, nus, Ss, nis, steps_used):  # pragma: no cover - compiled
    """The continuous-discrete UKF over z (T, m) (:func:`mptrack.nonlinear.ukf_filter`'s NumPy path,
    compiled): returns (status, step, loglik) with status OK, NOT_PD or DIVERGED of the named kernels;
    the innovations, their covariances and NIS go into nus, Ss, nis (NaN-filled by the caller).
    fixed_steps > 0: that many RK4 sub-steps per dt, else :func:`substeps_for` the drift's rate at the
    sigma points of each step's prior (recorded in steps_used)."""
    drift = _as_kernel(drift_c, drift_jit)
    meas = _as_kernel(meas_c, meas_jit)
    T, mdim = z.shape
    n = x0.shape[0]
    N = 2 * n + 1
    x, P = x0.copy(), P0.copy()
    X, F, S, L = np.empty((n, N)), np.empty((n, N)), np.empty((n, n)), np.empty((n, n))
    Xd, Fd = np.empty((n, N * (n + 1))), np.empty((n, N * (n + 1)))
    kst = np.empty((4, 2, n, n))
    Zc = np.empty((mdim, N))
    loglik = 0.0
    for k in range(T):
        steps = fixed_steps
        if steps <= 0:
            if not _sigma_columns(x, P, c, X, S, L):
                return NOT_PD, k, loglik
            steps = substeps_for(drift_rate(drift, dp, X, Xd, Fd), dt)
        steps_used[k] = steps
        if not _cd_predict(x, P, dt / steps, steps, c, Wm, Wc, Q, drift, dp, X, F, S, L, kst):
            return NOT_PD, k, loglik
        if not finite(x, P):
            return DIVERGED, k, loglik
        store(x, P, xp, Pp, k)
        if not np.isnan(z[k]).all():   # a row without measurements only predicts
            if not _sigma_columns(x, P, c, X, S, L):
                return NOT_PD, k, loglik
            meas(X, mp, Zc)
            status, x, P, ll = unscented_update(x, P, X.T, Zc.T, Wm, Wc, R, z, k, periods, nus, Ss, nis, k)
            if status != OK:
                return status, k, loglik
            loglik += ll
        if not finite(x, P):
            return DIVERGED, k, loglik
        store(x, P, xs, Ps, k)
    return OK, T, loglik
