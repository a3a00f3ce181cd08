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
(default 10), and failing that with its square (100: a sharp turn); if it
passes there it updates the filter from that prediction
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

from .._core.finiteness import finite_result, _overflow, renamed, require_finite
from .._core.validation import (
    as_array,
    as_real,
    as_sequence,
    as_vector,
    check_covariance,
    check_int,
    check_positive,
    check_record,
)
from ..errors import ParameterError, ShapeError
from .._core.rts import rts_backward_linear
from .._core.van_loan import intervals_unchecked
from ..models import ContinuousLinearModel, require_model
from ..result import FilterResult, innovation_arrays
from ._kernels import gated_loop
from ._track_filter import FLAGS, INIT, MANOEUVRE_FACTOR

__all__ = ["GatedResult", "kalman_filter_gated", "rts_smoother_gated", "track_gated", "first_fix_prior",
           "measured_states", "nis_threshold"]


def nis_threshold(probability: float, dof: int) -> float:
    """Chi-square quantile: the NIS gate that a consistent filter passes with ``probability``.

    Parameters
    ----------
    probability : float
        Probability in (0, 1) that a consistent filter's NIS lies inside the gate (0.999: 13.82 for
        ``dof`` = 2).
    dof : int
        Degrees of freedom: the dimension of the measurement.

    Returns
    -------
    float
        The NIS threshold.

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
    F, Q  (T, n, n) the transition used to reach step k from step k-1 (for smoothing): Q is the manoeuvre's
          process noise at a manoeuvre
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
                        manoeuvre_factor: float = MANOEUVRE_FACTOR, manoeuvre_noise=None,
                        prior_information=None) -> GatedResult:
    """Kalman filter at irregular times with two-level NIS gating (see the module doc).

    Parameters
    ----------
    model : ContinuousLinearModel
        E.g. ``constant_velocity_continuous(q, axes=2, sigma_r2=...)``.
    times : array_like, shape (T,)
        Time stamps (s), non-decreasing, >= t0 (fixes at one time are sequential updates).
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped, a NaN row only predicts.
    x0 : array_like, shape (n,)
        Prior mean x(t0).
    P0 : array_like, shape (n, n)
        Prior covariance P(t0).
    t0 : float, optional
        The prior's time (s); default ``times[0]`` (the first step then has dt = 0).
    R : array_like, shape (T, m, m), optional
        Per-measurement noise covariances (e.g. from GPS accuracy); default ``model.R``.
    gate_probability : float or None, optional
        Chi-square probability of the NIS gate; None disables gating.
    max_rejections : int, optional
        Rejections in a row that may restart the filter (default and minimum: the fixes a diffuse
        start needs, (n - states with a prior information) / m, plus one).
    manoeuvre_factor : float, optional
        Process noise of the manoeuvre hypothesis, as a multiple of the model's (the sharp
        manoeuvre: its square).
    manoeuvre_noise : pair of array_like, optional
        The spectral densities (Qc of the model) of the two manoeuvre hypotheses, e.g. to scale only
        the motion's noise and not that of an error state; default from ``manoeuvre_factor``.
    prior_information : array_like, shape (n, n), optional
        The information (inverse covariance) a restart starts from: the states it covers have a
        prior of their own (e.g. a fix error's slow part), the others start diffuse; default none.

    Returns
    -------
    GatedResult
        The filtered states, the nominal predictions, every measurement's innovation, S and NIS, the
        flag of each step and the (F, Q) each step used.

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
    Y0 = np.zeros((n, n)) if prior_information is None else check_covariance("prior_information",
                                                                             prior_information, n)
    start = (n - int(np.count_nonzero(np.diag(Y0)))) // m
    max_rejections = check_int("max_rejections", start + 1 if max_rejections is None else max_rejections,
                               minimum=start + 1)
    manoeuvre_factor = check_positive("manoeuvre_factor", manoeuvre_factor)
    if manoeuvre_noise is not None and len(manoeuvre_noise) != 2:
        raise ParameterError("manoeuvre_noise: expected the spectral densities of the two manoeuvre hypotheses")
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
    level = np.zeros(T, dtype=np.int8)
    with renamed(dt="times"):
        Fs, Qs = intervals_unchecked(model, dts)
    require_finite("the discretisation e^(Phi dt), Q of the intervals", (Fs, Qs), times=t, model=model)
    if manoeuvre_noise is None:
        with np.errstate(over="ignore"):   # beyond the float range: the check below names it
            manoeuvre_noise = (manoeuvre_factor * model.Qc, manoeuvre_factor ** 2 * model.Qc)
    levels = [ContinuousLinearModel(model.Phi, model.L, check_covariance("manoeuvre_noise", Qc, model.Qc.shape[0]),
                                    model.H, model.R) for Qc in manoeuvre_noise]
    with renamed(dt="times"):
        Qm, Qsharp = (intervals_unchecked(level, dts)[1] for level in levels)
    require_finite("the discretisation of the manoeuvre hypotheses", (Qm, Qsharp), times=t, model=model)
    inputs = dict(times=t, z=z, x0=x, P0=P, model=model) | ({} if R is None else {"R": Rs})
    try:
        loglik = gated_loop(t, Fs, Qs, Qm, Qsharp, H, np.ascontiguousarray(Rs), z, x.copy(), P.copy(),
                            np.ascontiguousarray(Y0), gates, gate_probability is not None, max_rejections, start,
                            xs, Ps, xp, Pp, nu, S, nis, flag, level)
    except (np.linalg.LinAlgError, ZeroDivisionError, SystemError) as exc:   # a breakdown inside numba
        raise _overflow("the gated Kalman filter", inputs, exc) from exc
    # every output, not only the estimates: the NIS and log-likelihood of fixes of 1e300 m overflow
    # (NaN marks a component or a fix that was not used, as z's NaN does)
    used = [np.where(np.isnan(a), 0.0, a) for a in (nu, S, nis)]
    require_finite("the gated Kalman filter", (xs, Ps, xp, Pp, loglik, *used), **inputs)
    # the process noise each step used: a manoeuvre's where the filter took one (for the smoother)
    Q_used = np.where((level == 1)[:, None, None], Qm, np.where((level == 2)[:, None, None], Qsharp, Qs))
    return GatedResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF-gated", innovation=nu,
                       S=S, nis=nis, flag=flag, F=Fs, Q=Q_used)


@finite_result("the RTS smoother")
def rts_smoother_gated(gated: GatedResult) -> FilterResult:
    """RTS smoothing of a gated run: the backward pass of :func:`mptrack.linear.rts_smoother`
    with the per-step (F, Q) the filter used, run separately on each stretch between
    filter resets and segment starts (flag init after a gap: either breaks the chain of
    predictions).  Rejected and missing measurements are prediction-only steps and need no
    special case.

    Parameters
    ----------
    gated : GatedResult
        A run of :func:`kalman_filter_gated` or :func:`track_gated`.

    Returns
    -------
    FilterResult
        The smoothed states x and covariances P (method "RTS-gated").

    References
    ----------
    .. [1] H. E. Rauch, F. Tung and C. T. Striebel, "Maximum likelihood estimates of linear dynamic systems",
           AIAA Journal, vol. 3, no. 8, pp. 1445–1450, 1965. doi:10.2514/3.3166
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
    starts = np.flatnonzero((gated.flag == FLAGS.index("reset")) | (gated.flag == INIT))
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
    """(x0, P0) at a track's first fix: the measured states (:func:`measured_states`) have a flat prior
    and every other state i is 0 with variance ``prior_variances[i]``; the fix z0 = H x + v (v of
    covariance R0) then gives the measured states z0 - H_o x_o (H_o: H without the measured columns),
    of covariance H_o D H_o^T + R0 and covariance -H_o D with the others (D = diag(prior_variances)):
    the fix with its variance when it measures its states alone."""
    picks = measured_states(H)
    D = np.diag(np.asarray(prior_variances, dtype=float))
    Ho = np.array(H, dtype=float)
    Ho[:, picks] = 0.0
    x0 = np.zeros(len(prior_variances))
    x0[picks] = z0
    P0 = D.copy()
    P0[np.ix_(picks, picks)] = Ho @ D @ Ho.T + R0
    cross = -Ho @ D
    others = [i for i in range(len(x0)) if i not in picks]
    P0[np.ix_(picks, others)] = cross[:, others]
    P0[np.ix_(others, picks)] = cross[:, others].T
    return x0, P0


def track_gated(model: ContinuousLinearModel, times, z, R, prior_variances, *,
                gate_probability: float | None = 0.999, max_rejections: int | None = None,
                manoeuvre_factor: float = MANOEUVRE_FACTOR, manoeuvre_noise=None, prior_information=None,
                max_gap_s: float | None = None) -> GatedResult:
    """One track from its first fix: the per-track reference of the tracking engine.

    The first fix initialises the state (flag "init", no NIS): the measured
    entries are the fix with covariance R[0] (:func:`first_fix_prior`), every
    other state is 0 with the variance ``prior_variances[i]`` (state order of
    ``model``; the entries of the measured states are not used).  The other
    fixes go through :func:`kalman_filter_gated` from that prior (its
    ``manoeuvre_factor``, ``manoeuvre_noise``, ``prior_information``).  A fix
    more than ``max_gap_s`` seconds after the one before starts a new segment:
    the track is run again from it as from a first fix (None: never).

    Parameters
    ----------
    model : ContinuousLinearModel
        The motion and measurement model.
    times : array_like, shape (T,)
        Time stamps of the fixes (s), non-decreasing.
    z : array_like, shape (T, m)
        The fixes.
    R : array_like, shape (T, m, m)
        Their noise covariances.
    prior_variances : array_like, shape (n,)
        Variances of the states a fix does not measure at a track's (or segment's) first fix.
    gate_probability, max_rejections, manoeuvre_factor, manoeuvre_noise, prior_information
        As in :func:`kalman_filter_gated`.
    max_gap_s : float, optional
        A fix more than this many seconds after the one before starts a new segment (None: never).

    Returns
    -------
    GatedResult
        All T fixes; ``F``, ``Q`` at a segment's first fix are I and 0.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    """
    require_model(model, kind=ContinuousLinearModel)
    t = as_array("times", times, ndim=1)
    z = as_sequence("z", z, model.m)
    if z.shape[0] != t.shape[0] or t.shape[0] == 0:
        raise ShapeError(f"z: expected {t.shape[0]} rows (one per time stamp, at least one), got shape {z.shape}")
    n, T = model.n, t.shape[0]
    Rs = as_array("R", R, shape=(T, model.m, model.m))
    prior = as_vector("prior_variances", prior_variances, n, low=0.0)
    gap = np.inf if max_gap_s is None else check_positive("max_gap_s", max_gap_s)
    bounds = np.r_[0, np.flatnonzero(np.diff(t) > gap) + 1, T]
    parts = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        x0, P0 = first_fix_prior(model.H, z[a], Rs[a], prior)
        init = GatedResult(x=x0[None], P=P0[None], x_pred=x0[None], P_pred=P0[None], loglik=0.0, method="KF-gated",
                           innovation=np.full((1, model.m), np.nan), S=np.full((1, model.m, model.m), np.nan),
                           nis=np.full(1, np.nan), flag=np.array([INIT], dtype=np.int8), F=np.eye(n)[None],
                           Q=np.zeros((1, n, n)))
        parts.append(init)
        if b - a > 1:
            parts.append(kalman_filter_gated(model, t[a + 1:b], z[a + 1:b], x0, P0, t0=float(t[a]), R=Rs[a + 1:b],
                                             gate_probability=gate_probability, max_rejections=max_rejections,
                                             manoeuvre_factor=manoeuvre_factor, manoeuvre_noise=manoeuvre_noise,
                                             prior_information=prior_information))
    if len(parts) == 1:
        return parts[0]
    rows = {f.name: np.concatenate([getattr(g, f.name) for g in parts])
            for f in fields(GatedResult) if isinstance(getattr(parts[-1], f.name), np.ndarray)}
    return GatedResult(**rows, loglik=float(sum(g.loglik for g in parts)), method="KF-gated")
