"""Integrator-chain algebra of the tracking engine: closed-form transitions, the shared-covariance
predict and update of two axes, small inverses, and the diffuse (information-form) start.

The motion models of ``mptrack track`` are integrator chains per axis (cv:
position, velocity; ca: + acceleration) driven by white noise of density q on
the highest derivative, with the same model on the east and north axes and an
isotropic fix noise R = r I.  Then the 2-D Kalman filter splits exactly into
two per-axis filters that share one covariance (it depends on the times and
r only), so the engine carries one covariance and two means.
Each interval is discretised in closed form, F_ij = dt^(j-i)/(j-i)! and
Q_ij = q dt^p / (p (r-1-i)! (r-1-j)!), p = 2r-1-i-j (the exact Van Loan
result for an integrator chain of order r; Assimakis et al. 2016, sec. 2, for
r = 2, 3).

The fix error may have a slow part: per axis z = p + b + v, with v white and b
a first-order Gauss-Markov process (stationary variance sb2, time constant
tau) carried as one more state per axis (n = order + 1; Gelb 1974;
the error model of :mod:`._fix_error`).  The functions take ``n``, the state
per axis, and treat state n - 1 as b when n > order.

Everything here is compiled (numba) and called from the per-track loops of
:mod:`._track_filter` (the gated filter) and :mod:`._likelihood` (the likelihood
that noise estimation maximises); they allocate one workspace (:func:`work`)
per block of tracks and nothing per track or per fix.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

MAX_ORDER = 3
LOG2PI = math.log(2.0 * math.pi)

# error_model="numpy": a division by zero gives inf/NaN as in NumPy (checked by the callers), not an exception
PAR = dict(parallel=True, cache=True, nogil=True, boundscheck=False, error_model="numpy")
SEQ = dict(cache=True, nogil=True, boundscheck=False, error_model="numpy")
# Inlined: the per-fix steps and the diffuse start (once per track, several calls): a call passes
# every array as ~7 scalars (the workspace tuple as ~240), which made short tracks 5x slower; the
# rest stays a call, as inlining everything took minutes to compile.
INLINE = dict(SEQ, inline="always")
#: Tracks are split into at most this many blocks in the parallel kernels; each allocates one workspace.
BLOCKS = 256


@nb.njit(**INLINE)
def chain_transition(order, dt, F, Qu):
    """F and the unit-density Q (q = 1) of an integrator chain of ``order`` (2 or 3) over ``dt`` seconds
    into their top-left ``order`` x ``order`` blocks: F_ij = dt^(j-i)/(j-i)!,
    Qu_ij = dt^p / (p (r-1-i)! (r-1-j)!), p = 2r-1-i-j (written out)."""
    d2 = dt * dt
    d3 = d2 * dt
    if order == 2:
        F[0, 0] = 1.0
        F[0, 1] = dt
        F[1, 0] = 0.0
        F[1, 1] = 1.0
        Qu[0, 0] = d3 / 3.0
        Qu[0, 1] = d2 / 2.0
        Qu[1, 0] = d2 / 2.0
        Qu[1, 1] = dt
        return
    d4 = d3 * dt
    d5 = d4 * dt
    for i in range(3):
        for j in range(3):
            F[i, j] = 0.0
    F[0, 0] = F[1, 1] = F[2, 2] = 1.0
    F[0, 1] = F[1, 2] = dt
    F[0, 2] = d2 / 2.0
    Qu[0, 0] = d5 / 20.0
    Qu[0, 1] = Qu[1, 0] = d4 / 8.0
    Qu[0, 2] = Qu[2, 0] = d3 / 6.0
    Qu[1, 1] = d3 / 3.0
    Qu[1, 2] = Qu[2, 1] = d2 / 2.0
    Qu[2, 2] = dt


@nb.njit(**INLINE)
def transition(order, n, dt, tau, F, Qu):
    """F and the unit-density motion noise Qu of the state over ``dt`` seconds: the chain
    (:func:`chain_transition`) and, for n = order + 1, the fix error's slow part b (a first-order
    Gauss-Markov process of time constant ``tau``): F_bb = e^(-dt/tau), no motion noise on b.
    Returns b's variance increment per unit of its stationary variance, 1 - e^(-2 dt/tau) (0 without b;
    meaningless for dt < 0, where F is the inverse of F(-dt))."""
    chain_transition(order, dt, F, Qu)
    if n == order:
        return 0.0
    for i in range(order):
        F[i, order] = 0.0
        F[order, i] = 0.0
        Qu[i, order] = 0.0
        Qu[order, i] = 0.0
    Qu[order, order] = 0.0
    F[order, order] = math.exp(-dt / tau)
    return -math.expm1(-2.0 * dt / tau)


@nb.njit(**INLINE)
def product(n, A, B, out, ta, tb):
    """out = op(A) op(B) for n x n matrices, op(X) = X^T where ta / tb."""
    for i in range(n):
        for j in range(n):
            s = 0.0
            for m in range(n):
                s += (A[m, i] if ta else A[i, m]) * (B[j, m] if tb else B[m, j])
            out[i, j] = s


@nb.njit(**INLINE)
def congruence(n, A, B, T, base, scale, out):
    """out = A B A^T + scale * base, symmetric (T is scratch: it holds A B afterwards)."""
    product(n, A, B, T, False, False)
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for m in range(n):
                s += T[i, m] * A[j, m]
            s += scale * base[i, j]
            out[i, j] = s
            out[j, i] = s


@nb.njit(**INLINE)
def predict(n, F, Qu, q, qb, x, P, xp, Pp, T):
    """xp = F x (both axes), Pp = F P F^T + q Qu + qb e e^T with e the last state (the slow error's
    variance increment qb; 0 without it), T scratch (F P afterwards)."""
    for a in range(2):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += F[i, j] * x[a, j]
            xp[a, i] = s
    congruence(n, F, P, T, Qu, q, Pp)
    Pp[n - 1, n - 1] += qb


@nb.njit(**INLINE)
def innovation(n, hb, xp, Pp, r, ze, zn):
    """(NIS, S) of the fix (ze, zn) of variance r against the prediction xp, Pp, measuring x_0
    (+ x_hb if hb >= 0), with the arithmetic of :func:`update`."""
    if hb < 0:
        S = Pp[0, 0] + r
        ne = ze - xp[0, 0]
        nn = zn - xp[1, 0]
    else:
        S = (Pp[0, 0] + Pp[0, hb]) + (Pp[hb, 0] + Pp[hb, hb]) + r
        ne = ze - xp[0, 0] - xp[0, hb]
        nn = zn - xp[1, 0] - xp[1, hb]
    return (ne * ne + nn * nn) / S, S


@nb.njit(**INLINE)
def update(n, hb, xp, Pp, r, ze, zn, x, P, A, T, k):
    """Kalman update of both axes with the fix (ze, zn) of variance r, measuring h^T x with
    h = e_0 (+ e_hb if hb >= 0: the position plus the fix error's slow part); returns (NIS, S).

    The rank-one form of :func:`mptrack._core.kalman.update` in Joseph form for one covariance shared
    by the two axes: S = h^T P h + r, k = P h / S, P <- (I - k h^T) P (I - k h^T)^T + r k k^T, which
    stays positive and accurate when a long gap makes P huge next to r (the standard form
    P - k h^T P cancels to 0 there).  Written out because it is inlined in the per-fix loops: a
    documented exception to the one compiled update, tested against it (tests/test_kalman_core.py).
    A, T (n, n) and k (n,) are scratch."""
    if hb < 0:
        for i in range(n):
            k[i] = Pp[i, 0]
        S = k[0] + r
        ne = ze - xp[0, 0]
        nn = zn - xp[1, 0]
    else:
        for i in range(n):
            k[i] = Pp[i, 0] + Pp[i, hb]
        S = k[0] + k[hb] + r
        ne = ze - xp[0, 0] - xp[0, hb]
        nn = zn - xp[1, 0] - xp[1, hb]
    for i in range(n):
        k[i] /= S
        x[0, i] = xp[0, i] + k[i] * ne
        x[1, i] = xp[1, i] + k[i] * nn
    for i in range(n):
        for j in range(n):
            A[i, j] = (1.0 if i == j else 0.0) - (k[i] if j == 0 or j == hb else 0.0)
    product(n, A, Pp, T, False, False)
    for i in range(n):
        for j in range(i, n):
            s = r * k[i] * k[j]
            for m in range(n):
                s += T[i, m] * A[j, m]
            P[i, j] = s
            P[j, i] = s
    return (ne * ne + nn * nn) / S, S


@nb.njit(**INLINE)
def copy_state(n, xs, Ps, xd, Pd):
    for i in range(n):
        xd[0, i] = xs[0, i]
        xd[1, i] = xs[1, i]
        for j in range(n):
            Pd[i, j] = Ps[i, j]


# ---- the workspace: every small array the per-track functions use, allocated once per block ----------
# Five arrays (so a call passes ~35 scalars, not ~240 as a tuple of 34 named arrays did): slots of
# (n, n) matrices, (2, n) states, (n,) vectors, the Gauss-Jordan work, and ints.
# Nested functions use disjoint slots (R*: the restart test and the back prediction of the gated filter,
# I*: info_start / info_predict, U*: update's scratch); ints hold row indices (a restart's window, a
# diffuse start's rows).
(M_F, M_QU, M_T, M_P, M_PP, M_PC, M_PI, M_C, M_D, M_RF, M_RQU, M_RT, M_RPP, M_RP, M_IF, M_IQU, M_IA, M_IM, M_IMI, M_IT,
 M_IY, M_UA, M_UT, M_RUN) = range(24)
(S_X, S_XP, S_XC, S_DX, S_RX, S_RXP, S_RUN) = range(7)
# M_RUN, S_RUN: the first of n_run slots (a restart test's state at each fix of its run)
(V_IYE, V_IYN, V_IV, V_UK) = range(4)
#: The largest state per axis: a chain of order 3 and the fix error's slow part.
MAX_N = MAX_ORDER + 1


@nb.njit(**SEQ)
def work(n, n_ints, n_run=0):
    """The workspace of one block for states of n per axis: (mats, states, vectors, W, ints (n_ints,)), with
    ``n_run`` more slots of mats and states from M_RUN, S_RUN on."""
    return (np.zeros((M_RUN + n_run, n, n)), np.zeros((S_RUN + n_run, 2, n)), np.zeros((4, n)),
            np.zeros((MAX_N, 2 * MAX_N)), np.zeros(max(n_ints, 1), dtype=np.int64))


@nb.njit(**SEQ)
def inverse(n, A, out, W):
    """out = A^-1 for n <= MAX_N (Gauss-Jordan, partial pivoting, W work); False if A is numerically singular."""
    scale = 0.0
    for i in range(n):
        for j in range(n):
            W[i, j] = A[i, j]
            W[i, n + j] = 1.0 if i == j else 0.0
            scale = max(scale, abs(A[i, j]))
    if not scale > 0.0:
        return False
    for col in range(n):
        piv = col
        for i in range(col + 1, n):
            if abs(W[i, col]) > abs(W[piv, col]):
                piv = i
        if not abs(W[piv, col]) > 1e-13 * scale:
            return False
        if piv != col:
            for j in range(2 * n):
                tmp = W[col, j]
                W[col, j] = W[piv, j]
                W[piv, j] = tmp
        d = W[col, col]
        for j in range(2 * n):
            W[col, j] /= d
        for i in range(n):
            if i != col:
                f = W[i, col]
                if f != 0.0:
                    for j in range(2 * n):
                        W[i, j] -= f * W[col, j]
    for i in range(n):
        for j in range(n):
            out[i, j] = W[i, n + j]
    return True


# ---- the diffuse start: information form from zero information ------------------------------------

@nb.njit(**INLINE)
def info_predict(order, n, dt, tau, q, sb2, Y, ye, yn, wk):
    """Information-form prediction over dt of a possibly singular information matrix Y:
    Y <- A (I + Q A)^-1, y <- (I + A Q)^-1 F^-T y with A = F^-T Y F^-1 (exact also for singular
    Y or Q, since I + Q A is invertible for PSD Q, A); Q = q Qu + sb2 (1 - e^(-2 dt/tau)) on the slow
    error state (n = order + 1)."""
    if dt == 0.0:
        return True
    mats, _, vec, W, _ = wk
    F, Qu, A, M, Mi, tmp, v = mats[M_IF], mats[M_IQU], mats[M_IA], mats[M_IM], mats[M_IMI], mats[M_IT], vec[V_IV]
    transition(order, n, -dt, tau, F, Qu)      # F(-dt) = F(dt)^-1; Qu of -dt is not used
    qb = sb2 * transition(order, n, dt, tau, M, Qu)   # only Qu(dt), qb are kept (M is overwritten below)
    product(n, Y, F, tmp, False, False)   # A = Fi^T Y Fi
    product(n, F, tmp, A, True, False)
    for i in range(n):                    # M = I + Q A
        for j in range(n):
            s = 1.0 if i == j else 0.0
            for m in range(n):
                s += q * Qu[i, m] * A[m, j]
            if i == n - 1:
                s += qb * A[i, j]
            M[i, j] = s
    if not inverse(n, M, Mi, W):
        return False
    product(n, A, Mi, tmp, False, False)  # Y = A M^-1 (symmetric)
    for i in range(n):
        for j in range(n):
            Y[i, j] = 0.5 * (tmp[i, j] + tmp[j, i])
    for ax in range(2):                   # y = M^-T Fi^T y
        y = ye if ax == 0 else yn
        for i in range(n):
            s = 0.0
            for m in range(n):
                s += F[m, i] * y[m]
            v[i] = s
        for i in range(n):
            s = 0.0
            for m in range(n):
                s += Mi[m, i] * v[m]
            y[i] = s
    return True


@nb.njit(**INLINE)
def info_start(t, ze, zn, w, c, rows, n_rows, q, order, n, tau, sb2, x, P, wk):
    """The exact state after the fixes ``rows[:n_rows]`` (variances c w) from zero information on the
    chain (a diffuse start) and, for n = order + 1, the slow fix error's own prior N(0, sb2):
    information-form predictions between them (motion density q), x, P <- the state at the last one.
    False if their information is singular (fewer than ``order`` distinct times) or numerically lost."""
    distinct = 1
    for j in range(1, n_rows):
        if t[rows[j]] != t[rows[j - 1]]:
            distinct += 1
    if distinct < order:  # a chain of order r needs fixes at r distinct times
        return False
    mats, _, vec, W, _ = wk
    Y, ye, yn = mats[M_IY], vec[V_IYE], vec[V_IYN]
    for i in range(n):
        ye[i] = 0.0
        yn[i] = 0.0
        for j in range(n):
            Y[i, j] = 0.0
    hb = n - 1 if n > order else 0     # the fix measures x_0 + x_hb (x_0 alone without a slow error)
    if n > order:
        Y[hb, hb] = 1.0 / sb2
    for j in range(n_rows):
        k = rows[j]
        if j > 0 and not info_predict(order, n, t[k] - t[rows[j - 1]], tau, q, sb2, Y, ye, yn, wk):
            return False
        rk = c * w[k]
        Y[0, 0] += 1.0 / rk
        ye[0] += ze[k] / rk
        yn[0] += zn[k] / rk
        if hb > 0:
            Y[0, hb] += 1.0 / rk
            Y[hb, 0] += 1.0 / rk
            Y[hb, hb] += 1.0 / rk
            ye[hb] += ze[k] / rk
            yn[hb] += zn[k] / rk
    if not inverse(n, Y, P, W):
        return False
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v
    for i in range(n):
        se = 0.0
        sn = 0.0
        for j in range(n):
            se += P[i, j] * ye[j]
            sn += P[i, j] * yn[j]
        x[0, i] = se
        x[1, i] = sn
    return True
