"""The time-invariant Kalman filter (Assimakis & Adam 2014, eq. 4)."""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import as_array, as_matrix, as_vector
from ..errors import ParameterError, ShapeError
from ..models import LinearGaussianModel
from ..result import FilterResult, innovation_arrays
from ._common import prepare_inputs
from ._kernels import kf_loop

__all__ = ["kalman_filter", "kalman_step"]

_LOG2PI = np.log(2.0 * np.pi)


@finite_result("the Kalman step")
def kalman_step(F, H, Q, R, x, P, z, joseph: bool = False, Bu=None, predict: bool = True, *,
                innovation: bool = False):
    """One Kalman filter iteration in readable NumPy: from x(k/k), P(k/k) and z(k+1) to the next pair.

    :func:`kalman_filter` runs the same equations compiled (tests check that the two agree).  NaN
    components of z are not used; a fully missing z only predicts.

    Parameters
    ----------
    F, H, Q, R : array_like
        The model's matrices, (n, n), (m, n), (n, n), (m, m).
    x : array_like, shape (n,)
        x(k/k).
    P : array_like, shape (n, n)
        P(k/k).
    z : array_like, shape (m,)
        z(k+1).
    joseph : bool, optional
        Joseph form of the covariance update.
    Bu : array_like, shape (n,), optional
        Control term added to the prediction, x(k+1/k) = F x + B u.
    predict : bool, optional
        False: update x, P with z directly (the prior is at this measurement).
    innovation : bool, optional
        Also return the innovation and its covariance.

    Returns
    -------
    x_filt, P_filt, x_pred, P_pred : ndarray
    loglik : float
        The log-likelihood increment.
    nu, S : ndarray, shapes (m,) and (m, m)
        With ``innovation=True`` only: NaN for the components not used.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] R. E. Kalman, "A new approach to linear filtering and prediction problems", Journal of Basic
           Engineering, vol. 82, no. 1, pp. 35–45, 1960. doi:10.1115/1.3662552
    """
    F = as_matrix("F", F)
    n = F.shape[1]
    x, P, Q = as_vector("x", x, n), as_matrix("P", P, n, n), as_matrix("Q", Q, n, n)
    if F.shape != (n, n):
        raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
    H = as_matrix("H", H, None, n)
    R, z = as_matrix("R", R, H.shape[0], H.shape[0]), as_array("z", z, shape=(H.shape[0],), allow_nan=True)
    m = z.shape[0]
    nu_full, S_full = np.full(m, np.nan), np.full((m, m), np.nan)
    if predict:
        x_pred = F @ x if Bu is None else F @ x + Bu
        P_pred = F @ P @ F.T + Q
    else:
        x_pred, P_pred = x, P
    ok = ~np.isnan(z)
    if not ok.any():
        return (x_pred, P_pred, x_pred, P_pred, 0.0) + ((nu_full, S_full) if innovation else ())
    if not ok.all():
        H, R, z = H[ok], R[np.ix_(ok, ok)], z[ok]
    PHt = P_pred @ H.T
    S = H @ PHt + R
    S_inv = np.linalg.inv(S)
    K = PHt @ S_inv
    innov = z - H @ x_pred
    x_filt = x_pred + K @ innov
    if joseph:
        IKH = np.eye(len(x)) - K @ H
        P_filt = IKH @ P_pred @ IKH.T + K @ R @ K.T
    else:
        P_filt = P_pred - K @ PHt.T
    P_filt = 0.5 * (P_filt + P_filt.T)
    _, logdet = np.linalg.slogdet(S)
    ll = -0.5 * (innov @ S_inv @ innov + logdet + len(innov) * _LOG2PI)
    if not innovation:
        return x_filt, P_filt, x_pred, P_pred, ll
    nu_full[ok] = innov
    S_full[np.ix_(ok, ok)] = S
    return x_filt, P_filt, x_pred, P_pred, ll, nu_full, S_full


#: where the prior (x0, P0) sits (as in mptrack.nonlinear): at time 0, or at the first measurement
PRIORS = ("initial", "first-measurement")


def step_matrices(model: LinearGaussianModel, T: int, F=None, H=None, Q=None, R=None, B=None, u=None) -> dict:
    """Per-step matrices of a time-varying and/or controlled model: each of F, H, Q, R is None (the
    model's), one matrix, or a stack with a leading axis of length T (row k is used for measurement row
    k: F[k], Q[k] predict into it, H[k], R[k] update with it); B (n, p) or (T, n, p) with u (T, p) adds
    B u to the prediction.  Returns {"F", "H", "Q", "R": (T, ., .), "Bu": (T, n) or None}."""
    n, m = model.n, model.m
    out = {}
    for name, value, shape in (("F", F, (n, n)), ("H", H, (m, n)), ("Q", Q, (n, n)), ("R", R, (m, m))):
        arr = getattr(model, name) if value is None else as_array(name, value)
        if arr.ndim == 2:
            arr = np.broadcast_to(arr, (T, *arr.shape))
        if arr.shape != (T, *shape):
            raise ShapeError(f"{name}: expected a {shape} matrix or a stack of shape {(T, *shape)}, got {arr.shape}")
        out[name] = arr
    for name in ("Q", "R"):
        sym = np.abs(out[name] - np.swapaxes(out[name], 1, 2)).max()
        if sym > 1e-9 * max(np.abs(out[name]).max(), 1e-300):
            raise ParameterError(f"{name}: every matrix of the stack must be symmetric (max asymmetry {sym:.3g})")
    if (B is None) != (u is None):
        raise ParameterError("B and u: give both (the control term B u) or neither")
    out["Bu"] = None
    if B is not None:
        u = as_array("u", u, ndim=2)
        if u.shape[0] != T:
            raise ShapeError(f"u: expected one control vector per measurement, shape ({T}, p), got {u.shape}")
        B = as_array("B", B)
        if B.ndim == 2:
            B = np.broadcast_to(B, (T, *B.shape))
        if B.shape != (T, n, u.shape[1]):
            raise ShapeError(f"B: expected shape ({n}, {u.shape[1]}) or ({T}, {n}, {u.shape[1]}), got {B.shape}")
        out["Bu"] = np.einsum("tnp,tp->tn", B, u)
    return out


@finite_result("the Kalman filter")
def kalman_filter(model: LinearGaussianModel, z, x0=None, P0=None, *, joseph: bool = False, F=None, H=None,
                  Q=None, R=None, B=None, u=None, prior: str = "initial") -> FilterResult:
    """Kalman filter with the per-step Riccati recursion (Assimakis & Adam 2014, eq. 4).

    The time-invariant loop is compiled (the one Kalman core); the time-varying, controlled and
    first-measurement forms run :func:`kalman_step` per step.

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    z : array_like, shape (T, m)
        Measurements z(1..T); NaN components are missing (a NaN row only predicts).
    x0 : array_like, shape (n,), optional
        The prior x(0/0) (default zeros).
    P0 : array_like, shape (n, n)
        The prior covariance P(0/0), required (zeros for a known initial state, as in the papers).
    joseph : bool, optional
        Use the Joseph form (I - K H) P (I - K H)^T + K R K^T for P(k/k).
    F, H, Q, R : array_like, shape (T, ., .), optional
        A time-varying model: stacks replacing the model's matrices, row k used for measurement k
        (FilterPy's ``batch_filter`` convention).
    B, u : array_like, optional
        A control input, x(k/k-1) = F x(k-1/k-1) + B u(k): u (T, p), B (n, p) or (T, n, p).
    prior : {"initial", "first-measurement"}, optional
        ``"initial"``: x0, P0 at time 0 (every step predicts first); ``"first-measurement"``: x0, P0 are
        the prior at the first measurement (as pykalman and simdkalman).

    Returns
    -------
    FilterResult
        Filtered and predicted means and covariances, innovations, S, NIS, log-likelihood, the prior as
        x0, P0 and, for a time-varying or controlled run, the per-step F, Q and B u as ``inputs`` (for
        :func:`rts_smoother`).

    Raises
    ------
    ParameterError
        P0 missing, or arguments of the wrong shape or type (the message names the argument).
    NonFiniteError
        The filter overflowed float64 (the message names the input of largest magnitude).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] R. E. Kalman, "A new approach to linear filtering and prediction problems", Journal of Basic
           Engineering, vol. 82, no. 1, pp. 35–45, 1960. doi:10.1115/1.3662552

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.linear import kalman_filter
    >>> from mptrack.models import assimakis_model_b
    >>> from mptrack.sim import simulate_linear
    >>> model = assimakis_model_b()
    >>> truth, z = simulate_linear(model, 100, np.random.default_rng(1))
    >>> result = kalman_filter(model, z, P0=np.zeros((2, 2)))
    >>> result.x.shape, result.method
    ((100, 2), 'KF')
    """
    z, x, P, _ = prepare_inputs(model, z, x0, P0)
    if P0 is None:
        raise ParameterError("P0: the prior covariance is required (np.zeros((n, n)) for a known x0)")
    if prior not in PRIORS:
        raise ParameterError(f"prior: expected one of {PRIORS}, got {prior!r}")
    T, n = z.shape[0], model.n
    xs = np.empty((T, n))
    Ps = np.empty((T, n, n))
    xp = np.empty((T, n))
    Pp = np.empty((T, n, n))
    nu, S, nis = innovation_arrays((T,), model.m)
    prior0 = {"x0": x.copy(), "P0": P.copy()} if prior == "initial" else {}
    if all(v is None for v in (F, H, Q, R, B, u)) and prior == "initial":
        loglik = kf_loop(model.F, model.H, model.Q, model.R, z, x, P, bool(joseph), xs, Ps, xp, Pp, nu, S, nis)
        return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF", innovation=nu,
                            S=S, nis=nis, **prior0)
    mats = step_matrices(model, T, F, H, Q, R, B, u)
    varying = any(v is not None for v in (F, H, Q, R, B, u))
    loglik = 0.0
    for k in range(T):
        Bu = None if mats["Bu"] is None else mats["Bu"][k]
        x, P, xp[k], Pp[k], ll, nu[k], S[k] = kalman_step(
            mats["F"][k], mats["H"][k], mats["Q"][k], mats["R"][k], x, P, z[k], joseph, Bu=Bu,
            predict=not (k == 0 and prior != "initial"), innovation=True)
        xs[k], Ps[k] = x, P
        loglik += ll
    # what the smoother must reuse (rts_smoother reads it: the model's constant F, Q would be wrong)
    inputs = {"F": mats["F"], "Q": mats["Q"], "Bu": mats["Bu"]} if varying else None
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF", inputs=inputs,
                        innovation=nu, S=S, **prior0)
