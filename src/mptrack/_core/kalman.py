"""The compiled (numba) Kalman predict and update: the one copy every compiled Gaussian filter calls.

    predict   x(k/k-1) = F x,  P(k/k-1) = F P F^T + Q
    update    ν = z - h(x(k/k-1)) (angles wrapped),  S = H P H^T + R = L L^T (Cholesky),  C = P H^T,
              K = C S^-1,  x(k/k) = x(k/k-1) + K ν,
              P(k/k) = P - K C^T                       (standard form), or
              P(k/k) = (I - K H) P (I - K H)^T + K R K^T   (Joseph form)
    NIS ν^T S^-1 = |L^-1 ν|^2,  log N(ν; 0, S) = -(|L^-1 ν|^2 + 2 Σ log L_ii + q log 2π) / 2

The update is three steps that a caller may also run apart: :func:`innovation` (ν, S, C of the
observed components), :func:`whiten` (Cholesky factor, NIS, log-likelihood: a gate decides here) and
:func:`apply_gain` (the gain and the new x, P).  The gain step takes any cross-covariance C: the
UKF's C = P_xz of the sigma points (:func:`unscented_update`) goes through the same step as the
KF's and EKF's C = P H^T (for the UKF P - K C^T = P - K S K^T).

Who calls it: the linear KF loop (:func:`mptrack.linear.kalman_filter`, ``kalman_filter_irregular``),
the gated tracking loop (:mod:`mptrack.tracking._kernels`), the batch KF's own-covariance fallback and
the batch range EKF (:mod:`mptrack.batch._kernels`, :mod:`mptrack.batch._ekf`), the EKF and UKF step
kernels, the named-model loops and the batched EKF of any model (:mod:`mptrack.nonlinear`), the
continuous-discrete UKF, compiled and NumPy (:mod:`mptrack.continuous`).

Every other place that writes Kalman algebra is one of these exceptions (this is the one list; each is
tested as stated):

* the readable NumPy reference :func:`mptrack.linear.kalman_step`, which tests/test_kalman_core.py
  checks this module against (random models, NaN-gapped measurements, both forms, the UKF gain step);
* the batch engine's shared-gain paths in :mod:`mptrack.batch._kernels`, above all the n = 2, m = 1
  time blocks (``kf_kernel_blocks``, ``ss_kernel_blocks``; also the complete-track branch of
  ``kf_kernel``): a shared, precomputed gain sequence and no covariance -- x = A(k) x + K(k) z with
  A(k) = (I - K(k) H) F, which is x = F x + K (z - H F x), eight steps at a time (four tracks at a time
  in ``kf_kernel``); they fall back to this core at a track's first gap (tested track by track against
  :func:`mptrack.linear.kalman_filter`);
* the tracking engine (:mod:`mptrack.tracking._chain` and ``_track_filter``; ``_likelihood`` runs the same steps):
  integrator chains with a position fix of variance r on two axes sharing one covariance, so one
  covariance and two means, per axis the chain and the fix error's slow part -- its predict
  (closed-form F, Q), its update (rank one, h = e_0 or e_0 + e_b, in Joseph form as ``update(...,
  joseph=True)``; tests/test_kalman_core.py), its RTS backward pass (one
  smoother gain for both axes; against :func:`mptrack.tracking.rts_smoother_gated`, which runs
  :mod:`mptrack._core.rts`) and its back prediction at a restart, all inlined in the per-fix loops for speed;
  the engine as a whole is tested against the per-track reference :func:`mptrack.tracking.track_gated`,
  which runs this core;
* the diffuse (information-form) start of a restart test (``tracking._kernels``, ``tracking._chain``) and
  of the tracking likelihood: information-filter algebra from zero information, which the covariance
  form cannot start from; tested against dense Gaussian algebra (tests/tracking/test_tracking_engine.py);
* covariance-only recursions that are the papers' equations, not a filter's update: the Riccati map of
  :mod:`mptrack.riccati` (``riccati_step`` and the steady gain; tested per-step = doubling = DARE), the
  error covariance of a fixed-gain filter (``steady_state_filter(covariance="exact")``, the Joseph form
  with the steady gain; tested never below the KF's and constant from the steady state), the N-step
  predictor's coefficients (:mod:`mptrack.linear._prediction`; tested eq. 19 = F^N x(k/k)) and the PCRB's
  information form (:func:`mptrack.metrics.pcrb`; tested equal to the KF covariance on a linear model);
* the fuzzy fusion filters of Bouzera et al. 2017 (:mod:`mptrack.cellular._fekf`): one-station scalar
  updates and their weighted fusion (eqs. 4, 11-16), batched over Monte-Carlo runs in NumPy as the
  paper writes them (tested: one station equals the EKF).

All work arrays are carved once from one buffer (:func:`workspace`), so a whole-run loop allocates
nothing per step; NaN components of z are skipped.  A function reports a problem by a status code,
never by raising: NOT_PD (S without a Cholesky factor), DIVERGED (a non-finite input or result).
The small helpers are inlined in numba's IR (``inline="always"``): as calls they cost the named EKF's
loop about a third of its time.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = [
    "DIVERGED",
    "LOG2PI",
    "NOT_PD",
    "OK",
    "apply_gain",
    "cholesky",
    "cov_predict",
    "finite",
    "innovation",
    "linear_update",
    "observed",
    "predict",
    "record_update",
    "store",
    "symmetrise",
    "unscented_update",
    "update",
    "whiten",
    "workspace",
    "wrap",
]

LOG2PI = float(np.log(2.0 * np.pi))
_TWO_PI = 2.0 * np.pi

OK, NOT_PD, DIVERGED = 0, 1, 2


@njit(cache=True, nogil=True, inline="always")
def wrap(v, period):
    """v wrapped into [-period/2, period/2) (``wrap_angles``); period 0: v itself."""
    return (v + 0.5 * period) % period - 0.5 * period if period > 0.0 else v


@njit(cache=True, nogil=True, inline="always")
def cholesky(S, L, q):
    """Lower Cholesky factor of S[:q, :q] into L[:q, :q]; False when S is not positive definite."""
    for i in range(q):
        for j in range(q):
            L[i, j] = 0.0
    for j in range(q):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, q):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@njit(cache=True, nogil=True, inline="always")
def _chol_solve(L, b, out, q):
    """out[:q] = S^-1 b[:q] with S = L L^T (L[:q, :q])."""
    for i in range(q):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * out[k]
        out[i] = s / L[i, i]
    for i in range(q - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, q):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@njit(cache=True, nogil=True, inline="always")
def finite(x, P):
    """All of x and P finite."""
    acc = 0.0
    for a in range(x.shape[0]):
        acc += x[a]
        for b in range(x.shape[0]):
            acc += P[a, b]
    return np.isfinite(acc)


@njit(cache=True, nogil=True)
def symmetrise(P):
    """P <- (P + P^T) / 2 in place."""
    n = P.shape[0]
    for a in range(n):
        for b in range(a + 1, n):
            v = 0.5 * (P[a, b] + P[b, a])
            P[a, b] = v
            P[b, a] = v


@njit(cache=True, nogil=True, inline="always")
def _mul(A, B, out, ni, nk, nj):
    """out[:ni, :nj] = A[:ni, :nk] B[:nk, :nj] (explicit loops: no temporaries, views or BLAS calls for
    these small matrices)."""
    for i in range(ni):
        for j in range(nj):
            acc = 0.0
            for k in range(nk):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@njit(cache=True, nogil=True, inline="always")
def _sym_bt(A, B, out, n, nk):
    """out[:n, :n] = A[:n, :nk] B[:n, :nk]^T for a product known to be symmetric: the upper triangle,
    mirrored (0.5 (P + P^T) up to rounding)."""
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for k in range(nk):
                acc += A[i, k] * B[j, k]
            out[i, j] = acc
            out[j, i] = acc


@njit(cache=True, nogil=True, inline="always")
def observed(z, k, idx):
    """The indices of the non-NaN components of row k of z into idx; returns their count.  (The
    functions take z and k, not the row z[k]: a view made per step costs a reference count pair, a
    fifth of the named EKF's step.)"""
    q = 0
    for i in range(z.shape[1]):
        if not np.isnan(z[k, i]):
            idx[q] = i
            q += 1
    return q


@njit(cache=True, nogil=True, inline="always")
def store(x, P, xs, Ps, k):
    """xs[k], Ps[k] = x, P."""
    n = x.shape[0]
    for a in range(n):
        xs[k, a] = x[a]
        for b in range(n):
            Ps[k, a, b] = P[a, b]


@njit(cache=True, nogil=True, inline="always")
def _record(idx, q, nu, S, w, nus, Ss, nis, row):
    """nus[row], Ss[row] at the q components idx <- the innovation nu[:q] and its covariance S[:q, :q],
    nis[row] <- the NIS w[:q]^T w[:q] of the whitened innovation w = L^-1 nu (rows of the filter's
    result; row < 0 or no component: not recorded)."""
    if row < 0 or q == 0:
        return
    e = 0.0
    for a in range(q):
        e += w[a] * w[a]
    nis[row] = e
    for a in range(q):
        nus[row, idx[a]] = nu[a]
        for b in range(q):
            Ss[row, idx[a], idx[b]] = S[a, b]


# ---------------------------------------------------------------- the workspace
@njit(cache=True, nogil=True)
def workspace(n, m):
    """The work arrays of an update: component indices (m,) and the step's matrices H, HP (m, n),
    C = P H^T, K, KR (n, m), Rq, S, L (m, m), IKH, A (n, n), nu, w (m,): views of one buffer."""
    return np.empty(m, np.int64), _carve(np.empty(5 * m * n + 3 * m * m + 2 * m + 2 * n * n), n, m)


@njit(cache=True, nogil=True)
def _carve(buf, n, m):
    a, b, c = m * n, m * m, n * n
    return (buf[0:a].reshape((m, n)), buf[a:2 * a].reshape((m, n)), buf[2 * a:3 * a].reshape((n, m)),
            buf[3 * a:4 * a].reshape((n, m)), buf[4 * a:5 * a].reshape((n, m)),
            buf[5 * a:5 * a + b].reshape((m, m)), buf[5 * a + b:5 * a + 2 * b].reshape((m, m)),
            buf[5 * a + 2 * b:5 * a + 3 * b].reshape((m, m)),
            buf[5 * a + 3 * b:5 * a + 3 * b + c].reshape((n, n)),
            buf[5 * a + 3 * b + c:5 * a + 3 * b + 2 * c].reshape((n, n)),
            buf[5 * a + 3 * b + 2 * c:5 * a + 3 * b + 2 * c + m], buf[5 * a + 3 * b + 2 * c + m:])


# ---------------------------------------------------------------- predict
@njit(cache=True, nogil=True)
def cov_predict(F, Q, P, A):
    """P <- F P F^T + Q in place (A: (n, n) work)."""
    n = P.shape[0]
    _mul(F, P, A, n, n, n)
    _sym_bt(A, F, P, n, n)
    for a in range(n):
        for b in range(n):
            P[a, b] += Q[a, b]


@njit(cache=True, nogil=True)
def predict(F, Q, x, P, ws):
    """x <- F x, P <- F P F^T + Q in place (ws from :func:`workspace`)."""
    _idx, (_H, _HP, _PHt, _K, _KR, _Rq, _S, _L, IKH, A, _nu, _w) = ws
    n = x.shape[0]
    for a in range(n):
        acc = 0.0
        for b in range(n):
            acc += F[a, b] * x[b]
        IKH[0, a] = acc
    for a in range(n):
        x[a] = IKH[0, a]
    cov_predict(F, Q, P, A)


# ---------------------------------------------------------------- update
@njit(cache=True, nogil=True)
def innovation(P, Hf, hx, R, z, k, periods, ws):
    """The innovation of row k of z (NaN components skipped) against the prediction with covariance P,
    measurement Jacobian Hf (m, n), predicted measurement hx (m,), noise R (m, m) and periods (m,) (0:
    not an angle) of all components: ν, S = H P H^T + R, C = P H^T, H and R of the q observed
    components into ws.  Returns q."""
    n = P.shape[0]
    idx, (H, HP, PHt, _K, _KR, Rq, S, _L, _IKH, _A, nu, _w) = ws
    q = observed(z, k, idx)
    if q == 0:
        return 0
    for a in range(q):
        i = idx[a]
        for b in range(n):
            H[a, b] = Hf[i, b]
        nu[a] = wrap(z[k, i] - hx[i], periods[i])
        for b in range(q):
            Rq[a, b] = R[i, idx[b]]
    _mul(H, P, HP, q, n, n)
    _sym_bt(HP, H, S, q, n)
    for a in range(q):
        for b in range(q):
            S[a, b] += Rq[a, b]
    for a in range(n):
        for b in range(q):
            PHt[a, b] = HP[b, a]
    return q


@njit(cache=True, nogil=True, inline="always")
def whiten(ws, q):
    """The Cholesky factor L of S and w = L^-1 ν into ws: (positive definite, NIS |w|^2, log N(ν; 0, S))
    ((False, 0, 0) when S has no Cholesky factor)."""
    _idx, (_H, _HP, _PHt, _K, _KR, _Rq, S, L, _IKH, _A, nu, w) = ws
    if not cholesky(S, L, q):
        return False, 0.0, 0.0
    quad = 0.0
    logdet = 0.0
    for i in range(q):
        s = nu[i]
        for k in range(i):
            s -= L[i, k] * w[k]
        w[i] = s / L[i, i]
        quad += w[i] * w[i]
        logdet += np.log(L[i, i])
    return True, quad, -0.5 * (quad + 2.0 * logdet + q * LOG2PI)


@njit(cache=True, nogil=True)
def apply_gain(x, P, ws, q, joseph):
    """After :func:`whiten`: K = C S^-1, x <- x + K ν and P <- P - K C^T (symmetrised), or the Joseph
    form (I - K H) P (I - K H)^T + K R K^T with the H, R of :func:`innovation`, in place."""
    n = x.shape[0]
    _idx, (H, _HP, PHt, K, KR, Rq, _S, L, IKH, A, nu, _w) = ws
    for a in range(n):
        _chol_solve(L, PHt[a], K[a], q)
    for a in range(n):
        acc = 0.0
        for b in range(q):
            acc += K[a, b] * nu[b]
        x[a] += acc
    if not joseph:
        for a in range(n):
            for b in range(a, n):
                acc = 0.0
                for c in range(q):
                    acc += K[a, c] * PHt[b, c]
                acc2 = 0.0
                for c in range(q):
                    acc2 += K[b, c] * PHt[a, c]
                v = 0.5 * ((P[a, b] - acc) + (P[b, a] - acc2))
                P[a, b] = v
                P[b, a] = v
        return
    _mul(K, H, IKH, n, q, n)
    for a in range(n):
        for b in range(n):
            IKH[a, b] = (1.0 if a == b else 0.0) - IKH[a, b]
    _mul(IKH, P, A, n, n, n)
    _sym_bt(A, IKH, P, n, n)
    _mul(K, Rq, KR, n, q, q)
    for a in range(n):
        for b in range(a, n):
            acc = 0.0
            for c in range(q):
                acc += KR[a, c] * K[b, c]
            P[a, b] += acc
            if b != a:
                P[b, a] = P[a, b]


@njit(cache=True, nogil=True)
def update(x, P, Hf, hx, R, z, k, periods, joseph, ws):
    """The Kalman / EKF update of x, P in place with row k of z (arguments of :func:`innovation`,
    Joseph form when ``joseph``).  Returns (status, loglik); OK and 0 when no component is observed."""
    q = innovation(P, Hf, hx, R, z, k, periods, ws)
    if q == 0:
        return OK, 0.0
    ok, _e, ll = whiten(ws, q)
    if not ok:
        return NOT_PD, 0.0
    apply_gain(x, P, ws, q, joseph)
    return OK, ll


@njit(cache=True, nogil=True)
def linear_update(x, P, H, R, z, k, periods, joseph, ws, hx):
    """:func:`update` for a linear measurement h(x) = H x (hx: (m,) work, periods: (m,) zeros).
    Returns (status, loglik)."""
    n = x.shape[0]
    for i in range(H.shape[0]):
        acc = 0.0
        for j in range(n):
            acc += H[i, j] * x[j]
        hx[i] = acc
    return update(x, P, H, hx, R, z, k, periods, joseph, ws)


@njit(cache=True, nogil=True, inline="always")
def record_update(ws, z, k, nus, Ss, nis, row):
    """After an update with row k of z and the workspace ws: its innovation, S and NIS into row ``row``
    of nus, Ss, nis (the workspace still holds them)."""
    idx, (_H, _HP, _PHt, _K, _KR, _Rq, S, _L, _IKH, _A, nu, w) = ws
    _record(idx, observed(z, k, idx), nu, S, w, nus, Ss, nis, row)


@njit(cache=True, nogil=True)
def unscented_update(x, P, X, Zf, Wm, Wc, R, z, k, periods, nus, Ss, nis, row):
    """The unscented update of N(x, P) (sigma points X, their measurements Zf (N, m)) with row k of z
    (NaN components skipped); components of period > 0 are averaged on the circle and wrapped.
    S = Σ Wc dZ dZ^T + R and C = Σ Wc (X - x) dZ^T go through :func:`whiten` and :func:`apply_gain`.
    The innovation, its covariance S and the NIS go into row ``row`` of nus, Ss, nis (row < 0: not
    recorded).  Returns (status, x, P, loglik) with new x, P."""
    N, m = Zf.shape
    n = x.shape[0]
    ws = workspace(n, m)
    idx, (_H, _HP, C, _K, _KR, Rq, S, _L, _IKH, _A, nu, w) = ws
    q = observed(z, k, idx)
    if q == 0:
        return OK, x, P, 0.0
    zbar = np.empty(m)
    for i in range(m):
        per = periods[i]
        if per > 0.0:
            sn = 0.0
            cs = 0.0
            for j in range(N):
                sn += Wm[j] * np.sin(Zf[j, i] * (_TWO_PI / per))
                cs += Wm[j] * np.cos(Zf[j, i] * (_TWO_PI / per))
            zbar[i] = np.arctan2(sn, cs) * (per / _TWO_PI)
        else:
            acc = 0.0
            for j in range(N):
                acc += Wm[j] * Zf[j, i]
            zbar[i] = acc
    dZ = np.empty((N, q))
    for a in range(q):
        i = idx[a]
        for j in range(N):
            dZ[j, a] = wrap(Zf[j, i] - zbar[i], periods[i])
        nu[a] = wrap(z[k, i] - zbar[i], periods[i])
        for b in range(q):
            Rq[a, b] = R[i, idx[b]]
    for a in range(q):
        for b in range(q):
            acc = 0.0
            for j in range(N):
                acc += Wc[j] * dZ[j, a] * dZ[j, b]
            S[a, b] = acc + Rq[a, b]
    for a in range(n):
        for b in range(q):
            acc = 0.0
            for j in range(N):
                acc += Wc[j] * (X[j, a] - x[a]) * dZ[j, b]
            C[a, b] = acc
    ok, _e, ll = whiten(ws, q)
    if not ok:
        return NOT_PD, x, P, 0.0
    _record(idx, q, nu, S, w, nus, Ss, nis, row)
    x = x.copy()
    P = P.copy()
    apply_gain(x, P, ws, q, False)
    return OK, x, P, ll
