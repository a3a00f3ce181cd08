"""Batched extended Kalman filter for range measurements (many Monte-Carlo runs at once).

The measurement model is our own, kept deliberately simple: a linear-Gaussian
motion model and the ranges (metres) from the position to fixed stations,

    x(k+1) = F x(k) + w(k),          w ~ N(0, Q)
    z_s(k) = || p(k) - b_s || + v_s,  v ~ N(0, R),  p = x[position]

The EKF (e.g. Bar-Shalom, Li & Kirubarajan 2001, sec. 10.3) linearises h at
x(k/k-1): H_s = (p - b_s)^T / ||p - b_s|| in the position columns.  Every track
has its own covariance (the Jacobian depends on the state), so the kernel runs
the full recursion per track; the batch axis is the Monte-Carlo run.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from .._core.finiteness import _overflow, require_finite
from .._core.kalman import OK, predict, update, workspace
from .._core.validation import as_matrix, check_covariance, check_int, check_positive, frozen
from ..errors import ParameterError, ShapeError
from ..result import BatchFilterResult
from ._inputs import check_finite_out, launch, prepare_batch
from ._kernels import _OPTS

__all__ = ["RangeModel", "ekf_ranges"]


@dataclass(frozen=True, eq=False)
class RangeModel:
    """Motion (F, Q) observed through ranges to ``stations`` (S, d) with noise R (S, S).

    position  the d state indices holding the position (metres), e.g. (0, 2)
              for the state [p_x, v_x, p_y, v_y]
    """

    F: np.ndarray
    Q: np.ndarray
    stations: np.ndarray
    R: np.ndarray
    position: tuple = field(default=(0, 2))

    def __post_init__(self) -> None:
        F = as_matrix("F", self.F)
        n = F.shape[0]
        if F.shape != (n, n):
            raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
        Q = check_covariance("Q", self.Q, n)
        st = as_matrix("stations", self.stations)
        S, d = st.shape
        if d not in (2, 3):
            raise ShapeError(f"stations: expected shape (m, 2) or (m, 3), got {st.shape}")
        if isinstance(self.position, (str, bytes)) or not np.iterable(self.position):
            raise ParameterError(f"position: expected {d} state indices, got {self.position!r}")
        pos = tuple(check_int("position", i, minimum=0, maximum=n - 1) for i in self.position)
        if len(pos) != d:
            raise ShapeError(f"stations: {d}-D stations need {d} state indices in position, got {pos}")
        if len(set(pos)) != d:
            raise ShapeError(f"position: expected {d} distinct state indices in [0, {n}), "
                             f"got {self.position}")
        R = check_covariance("R", self.R, S, definite=True)
        for name, value in (("F", F), ("Q", Q), ("stations", st), ("R", R)):
            object.__setattr__(self, name, frozen(value))
        object.__setattr__(self, "position", pos)

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @property
    def m(self) -> int:
        return self.stations.shape[0]

    @classmethod
    def constant_velocity(cls, dt: float, sigma_a2: float, stations, sigma_r2: float) -> "RangeModel":
        """2-D constant velocity, state [p_x, v_x, p_y, v_y] (m, m/s), white acceleration of
        variance sigma_a2 (m^2/s^4) with the noise gain [dt^2/2, dt]; range noise sigma_r2 (m^2)."""
        dt = check_positive("dt", dt)
        sigma_a2 = check_positive("sigma_a2", sigma_a2, allow_zero=True)
        if sigma_a2 > _MAX_VAR:
            raise ParameterError(f"sigma_a2: expected a variance of at most {_MAX_VAR:.3g} m^2/s^4, got {sigma_a2!r}")
        sigma_r2 = check_positive("sigma_r2", sigma_r2)
        if not _MIN_VAR <= sigma_r2 <= _MAX_VAR:  # beyond, R = sigma_r2 I defeats the eigen-analysis
            raise ParameterError(f"sigma_r2: expected a variance within {_MIN_VAR:.3g} .. {_MAX_VAR:.3g} m^2, "
                                 f"got {sigma_r2!r}")
        Fa = np.array([[1.0, dt], [0.0, 1.0]])
        g = np.array([0.5 * dt * dt, dt])
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported below
            Qa = sigma_a2 * np.outer(g, g)
        z2 = np.zeros((2, 2))
        F = np.block([[Fa, z2], [z2, Fa]])
        Q = np.block([[Qa, z2], [z2, Qa]])
        st = as_matrix("stations", stations)
        require_finite("Q = sigma_a2 G G^T", Q, dt=dt, sigma_a2=sigma_a2)
        return cls(F, Q, st, sigma_r2 * np.eye(st.shape[0]), (0, 2))


#: The range of a range variance that the covariance checks can analyse (normal floats, with room).
_MIN_VAR, _MAX_VAR = float(np.finfo(float).tiny), 1e300

_TINY_RANGE = float(np.finfo(float).tiny)   # the floor of the single-track ekf_ranges


@nb.njit(**_OPTS)
def ekf_kernel(z, out, F, Q, R, stations, pos, x0, P0, lengths):
    """The range EKF of every track: the predict and update of :mod:`mptrack._core.kalman` with the
    ranges h(x(k/k-1)) and their Jacobian H (standard form); NaN ranges are skipped."""
    nb_, T = z.shape[0], z.shape[1]
    n = F.shape[0]
    S, d = stations.shape
    for b in nb.prange(nb_):
        x = x0[b].copy()
        P = P0.copy()
        ws = workspace(n, S)
        Hf = np.zeros((S, n))
        hx = np.empty(S)
        periods = np.zeros(S)
        zb = z[b]
        for t in range(lengths[b]):
            predict(F, Q, x, P, ws)
            for i in range(S):
                r2 = 0.0
                for j in range(d):
                    diff = x[pos[j]] - stations[i, j]
                    r2 += diff * diff
                r = np.sqrt(r2)
                r_floor = max(r, _TINY_RANGE)  # on a station: H stays finite (as ekf_ranges)
                for j in range(d):
                    Hf[i, pos[j]] = (x[pos[j]] - stations[i, j]) / r_floor
                hx[i] = r
            status, _ = update(x, P, Hf, hx, R, zb, t, periods, False, ws)
            if status != OK:
                x[:] = np.nan
                P[:, :] = np.nan
            for r in range(n):
                out[b, t, r] = x[r]
        for t in range(lengths[b], T):
            for r in range(n):
                out[b, t, r] = np.nan


def ekf_ranges(model: RangeModel, z, x0, P0, out=None, *, lengths=None) -> BatchFilterResult:
    """Extended Kalman filter of a batch of range tracks, compiled, one covariance per track.

    The states-only twin of :func:`mptrack.cellular.ekf_ranges_batch` for Monte-Carlo studies.

    Parameters
    ----------
    model : RangeModel
        F, Q, the S stations, R and the position's indices.
    z : array_like, shape (B, T, S)
        Ranges (m); NaN = that range missing.
    x0 : array_like, shape (n,) or (B, n)
        The prior x(0/0); it must not sit on a station.
    P0 : array_like, shape (n, n)
        The shared prior covariance.
    out : ndarray, optional
        As in :func:`steady_state_filter`.
    lengths : array_like of int, optional
        As in :func:`steady_state_filter`.

    Returns
    -------
    BatchFilterResult
        x the (B, T, n) filtered states, method "EKF"; the other fields None (formed and discarded per
        track: :func:`mptrack.cellular.ekf_ranges_batch` returns them all).

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    if x0 is None:
        raise ParameterError("x0: the EKF needs a prior state (the Jacobian at 0 may be undefined)")
    bi = prepare_batch(model, z, x0, out, lengths, model_type=RangeModel)
    P0 = check_covariance("P0", P0, model.n)
    try:
        launch(ekf_kernel, bi.out.size * model.m * model.n, bi.z, bi.out, model.F, model.Q, model.R,
               model.stations, np.asarray(model.position, dtype=np.int64), bi.x0, P0, bi.lengths)
    except (np.linalg.LinAlgError, ZeroDivisionError, SystemError) as exc:  # a breakdown inside numba
        raise _overflow("the range EKF", dict(model=model, z=bi.z, x0=bi.x0, P0=P0), exc) from exc
    x = check_finite_out(bi, "the range EKF", model=model, z=bi.z, x0=bi.x0, P0=P0)
    return BatchFilterResult(x=x, P=None, method="EKF")

