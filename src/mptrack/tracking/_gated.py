"""Kalman filtering of position fixes at irregular times, with NIS gating, and its RTS smoother.

For every interval dt(k) = t(k) - t(k-1) the continuous motion model is
discretised exactly (F = e^{Phi dt}, Q by Van Loan's method, Assimakis et al.
2016, sec. 2; :func:`mptrack.models.van_loan`), so gaps need no special case: a
long interval simply predicts further and the covariance grows.

Gating uses the normalised innovation squared (NIS)

    eps(k) = nu(k)^T S(k)^{-1} nu(k),   nu = z - H x(k/k-1),   S = H P(k/k-1) H^T + R(k),

which for a consistent filter is chi-square with m = dim z degrees of freedom
(Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4), at two levels of process noise
(the same book, sec. 11.2): a measurement whose NIS exceeds the chi-square
quantile ``gate_probability`` (default 0.999: 13.82 for a 2-D fix) is tested
again against the prediction with ``manoeuvre_factor`` times the process noise
(default 10); if it passes there it updates the filter from that prediction
as a candidate, and the next measurement decides: inside the gate of the
track it leads to, the candidate is a manoeuvre (flag "manoeuvre"); otherwise
it was an outlier and the filter coasts through it.  A measurement outside
both gates is rejected: the step only predicts and the point is flagged
"outlier".  Real motion has heavier tails than the Gaussian
model (turns, braking): without the second level a turn is rejected fix after
fix.  After ``max_rejections`` rejections in a row that agree with each other
(a diffuse start on the first of them under the manoeuvre process noise
predicts every further one inside the gate) the filter restarts from them,
at the last of them (flag "reset"), so a jump or a long gap cannot lose the
track while scattered outliers never restart it.

:func:`track_gated` is the per-track reference of the tracking engine
(:mod:`._engine`): it starts at a track's first fix (flag "init") and runs
:func:`kalman_filter_gated` from there.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, fields

import numpy as np
import scipy.stats

from .._core.validation import (_overflow, as_array, as_real, as_sequence, as_vector, check_covariance, check_int,
                           check_positive, check_record, finite_result, renamed, require_finite)
from ..errors import ParameterError, ShapeError
from .._core.rts import rts_backward_linear
from .._core.van_loan import intervals_unchecked
from ..models import ContinuousLinearModel, require_model
from ..result import FilterResult, innovation_arrays
from ._engine import FLAGS, INIT, MANOEUVRE_FACTOR
from ._kernels import gated_loop

__all__ = ["GatedResult", "kalman_filter_gated", "smooth_gated", "track_gated", "first_fix_prior", "measured_states",
           "nis_threshold", "FLAGS"]


def nis_threshold(probability: float, dof: int) -> float:
    """Chi-square quantile: the NIS gate that a consistent filter passes with ``probability``.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    """
    p = as_real("probability", probability)
    if not 0.0 < p < 1.0:
        raise ParameterError(f"probability: expected a probability in (0, 1), got {probability!r}")
    return float(scipy.stats.chi2.ppf(p, check_int("dof", dof, minimum=1)))


@dataclass(frozen=True, eq=False)
class GatedResult(FilterResult):
    """A gated irregular-time KF run: a :class:`mptrack.result.FilterResult` (method "KF-gated") plus
    per-step data.

    x_pred, P_pred  the nominal prediction (the model's process noise)
    innovation, S   of every measurement, used or rejected (NaN where there was none); at a manoeuvre
                    S is the manoeuvre hypothesis's (``manoeuvre_factor`` times the process noise)
    nis   (T,) the NIS the gate decided on, from innovation and S
    flag  (T,) index into FLAGS: 0 update, 1 outlier (rejected), 2 predicted (no measurement), 3 reset,
          4 init (the first fix of a track, :func:`track_gated`), 5 manoeuvre
    F, Q  (T, n, n) the transition used to reach step k from step k-1 (for smoothing)
    """

    flag: np.ndarray | None = None
    F: np.ndarray | None = None
    Q: np.ndarray | None = None

    @property
    def result(self) -> GatedResult:
        """The run itself (a GatedResult is a FilterResult); deprecated."""
        warnings.warn("GatedResult.result: a GatedResult is a FilterResult now; use it directly (.result will "
                      "be removed in the next release)", DeprecationWarning, stacklevel=2)
        return self


def kalman_filter_gated(model: ContinuousLinearModel, times, z, x0, P0, *, t0: float | None = None, R=None,
                        gate_probability: float | None = 0.999, max_rejections: int | None = None,
                        manoeuvre_factor: float = MANOEUVRE_FACTOR) -> GatedResult:
    """Kalman filter at irregular times with two-level NIS gating (see the module doc).

    model    ContinuousLinearModel (e.g. constant_velocity_continuous(q, axes=2, sigma_r2=...))
    times    (T,) seconds, non-decreasing, >= t0 (fixes at one time are sequential updates)
    z        (T, m) measurements; NaN components skipped, a NaN row only predicts
    x0, P0   prior x(t0), P(t0); t0 defaults to times[0] (first step then has dt = 0)
    R        None (model.R), or (T, m, m) per-measurement noise covariances (e.g. from GPS accuracy)
    gate_probability  chi-square probability of the NIS gate; None disables gating
    max_rejections    rejections in a row that may restart the filter (default and minimum: the
                      fixes a diffuse start needs, n / m, plus one)
    manoeuvre_factor  process noise of the manoeuvre hypothesis, as a multiple of the model's

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    """
    require_model(model, kind=ContinuousLinearModel)
    t = as_array("times", times, ndim=1)
    z = as_sequence("z", z, model.m, allow_nan=True)
    if z.shape[0] != t.shape[0] or t.shape[0] == 0:
        raise ShapeError(f"z: expected {t.shape[0]} rows (one per time stamp, at least one), got shape {z.shape}")
    n, m, T = model.n, model.m, t.shape[0]
    x = as_vector("x0", x0, n)
    P = check_covariance("P0", P0, n)
    start = n // m
    max_rejections = check_int("max_rejections", start + 1 if max_rejections is None else max_rejections,
                               minimum=start + 1)
    manoeuvre_factor = check_positive("manoeuvre_factor", manoeuvre_factor)
    t0 = float(t[0]) if t0 is None else float(t0)
    dts = np.diff(np.r_[t0, t])
    if np.any(dts < 0):
        k = int(np.flatnonzero(dts < 0)[0])
        raise ParameterError(f"times: time stamps must not decrease (from t0); times[{k}] = {t[k]!r}")
    if R is None:
        Rs = np.broadcast_to(model.R, (T, m, m))
    else:
        Rs = as_array("R", R, shape=(T, m, m))
    with renamed(probability="gate_probability"):
        gates = np.array([np.inf] + [nis_threshold(gate_probability, d) if gate_probability is not None else np.inf
                                     for d in range(1, m + 1)])
    H = np.ascontiguousarray(model.H)
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    nu, S, nis = innovation_arrays((T,), m)
    flag = np.zeros(T, dtype=np.int8)
    with renamed(dt="times"):
        Fs, Qs = intervals_unchecked(model, dts)
    require_finite("the discretisation e^(Phi dt), Q of the intervals", (Fs, Qs), times=t, model=model)
    inputs = dict(times=t, z=z, x0=x, P0=P, model=model) | ({} if R is None else {"R": Rs})
    try:
        loglik = gated_loop(t, Fs, Qs, H, np.ascontiguousarray(Rs), z, x.copy(), P.copy(), gates,
                            gate_probability is not None, max_rejections, float(manoeuvre_factor), start,
                            xs, Ps, xp, Pp, nu, S, nis, flag)
    except (np.linalg.LinAlgError, ZeroDivisionError, SystemError) as exc:   # a breakdown inside numba
        raise _overflow("the gated Kalman filter", inputs, exc) from exc
    # every output, not only the estimates: the NIS and log-likelihood of fixes of 1e300 m overflow
    # (NaN marks a component or a fix that was not used, as z's NaN does)
    used = [np.where(np.isnan(a), 0.0, a) for a in (nu, S, nis)]
    require_finite("the gated Kalman filter", (xs, Ps, xp, Pp, loglik, *used), **inputs)
    return GatedResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF-gated", innovation=nu,
                       S=S, nis=nis, flag=flag, F=Fs, Q=Qs)


@finite_result("the RTS smoother")
def smooth_gated(gated: GatedResult) -> FilterResult:
    """RTS smoothing of a gated run: the backward pass of :func:`mptrack.linear.rts_smoother`
    with the per-step (F, Q) the filter used, run separately on each stretch between
    filter resets (a reset breaks the chain of predictions).  Rejected and missing
    measurements are prediction-only steps and need no special case.
    """
    if not isinstance(gated, GatedResult):
        raise ParameterError(f"gated: expected a GatedResult (from kalman_filter_gated), got {type(gated).__name__}")
    check_record("gated", gated, fields=("x", "P"))
    T, n = gated.x.shape
    for name in ("F", "Q"):
        as_array(f"gated.{name}", getattr(gated, name), shape=(T, n, n))
    as_array("gated.flag", gated.flag, shape=(T,))
    r = gated
    xs, Ps = np.empty_like(r.x), np.empty_like(r.P)
    starts = np.flatnonzero(gated.flag == FLAGS.index("reset"))
    bounds = np.unique(np.r_[0, starts, r.T])
    for a, b in zip(bounds[:-1], bounds[1:]):
        part = FilterResult(x=r.x[a:b], P=r.P[a:b])
        sm = rts_backward_linear(part, gated.F[a + 1:b], gated.Q[a + 1:b])
        xs[a:b], Ps[a:b] = sm.x, sm.P
    return FilterResult(x=xs, P=Ps, method="RTS-gated")


def measured_states(H) -> list[int]:
    """The state entry that each row of the measurement matrix H measures (its first non-zero)."""
    return [int(np.flatnonzero(row)[0]) for row in np.asarray(H)]


def first_fix_prior(H, z0, R0, prior_variances) -> tuple[np.ndarray, np.ndarray]:
    """(x0, P0) at a track's first fix: the measured states (:func:`measured_states`) are the fix z0
    with covariance R0, every other state i is 0 with variance ``prior_variances[i]``."""
    picks = measured_states(H)
    x0 = np.zeros(len(prior_variances))
    x0[picks] = z0
    P0 = np.diag(np.asarray(prior_variances, dtype=float))
    P0[np.ix_(picks, picks)] = R0
    return x0, P0


def track_gated(model: ContinuousLinearModel, times, z, R, prior_variances, *,
                gate_probability: float | None = 0.999, max_rejections: int | None = None,
                manoeuvre_factor: float = MANOEUVRE_FACTOR) -> GatedResult:
    """One track from its first fix: the per-track reference of the tracking engine.

    The first fix initialises the state (flag "init", no NIS): the measured
    entries are the fix with covariance R[0], every other state is 0 with the
    variance ``prior_variances[i]`` (state order of ``model``; the entries of
    the measured states are not used).  The other fixes go through
    :func:`kalman_filter_gated` from that prior.  The result covers all T
    fixes; ``F[0]`` = I and ``Q[0]`` = 0.
    """
    require_model(model, kind=ContinuousLinearModel)
    t = as_array("times", times, ndim=1)
    z = as_sequence("z", z, model.m)
    if z.shape[0] != t.shape[0] or t.shape[0] == 0:
        raise ShapeError(f"z: expected {t.shape[0]} rows (one per time stamp, at least one), got shape {z.shape}")
    n, T = model.n, t.shape[0]
    Rs = as_array("R", R, shape=(T, model.m, model.m))
    x0, P0 = first_fix_prior(model.H, z[0], Rs[0], as_vector("prior_variances", prior_variances, n, low=0.0))
    flag0 = np.array([INIT], dtype=np.int8)
    init = GatedResult(x=x0[None], P=P0[None], x_pred=x0[None], P_pred=P0[None], loglik=0.0, method="KF-gated",
                       innovation=np.full((1, model.m), np.nan), S=np.full((1, model.m, model.m), np.nan),
                       nis=np.full(1, np.nan), flag=flag0, F=np.eye(n)[None], Q=np.zeros((1, n, n)))
    if T == 1:
        return init
    g = kalman_filter_gated(model, t[1:], z[1:], x0, P0, t0=float(t[0]), R=Rs[1:],
                            gate_probability=gate_probability, max_rejections=max_rejections,
                            manoeuvre_factor=manoeuvre_factor)
    rows = {f.name: np.concatenate([getattr(init, f.name), getattr(g, f.name)])
            for f in fields(GatedResult) if isinstance(getattr(g, f.name), np.ndarray)}
    return GatedResult(**rows, loglik=g.loglik, method="KF-gated")
