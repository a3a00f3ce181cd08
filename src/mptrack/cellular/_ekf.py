"""Extended Kalman filter on ranges to base stations (Bouzera et al. 2017, eqs. 1–10).

    X(k+1) = F X(k) + w(k),   w ~ N(0, Q)         motion: "random-walk" (F = I, the paper's eq. 1, X = p)
                                                  or "cv" (constant velocity, X = [x, vx, y, vy(, z, vz)],
                                                  the state order of every model in mptrack)
    d_i(k) = ||p(k) - B_i|| + v_i(k),  v ~ N(0, R)  p = position part of X, B_i = station i

Units are the caller's (the paper works in km).  :func:`ekf_ranges` is
:func:`mptrack.nonlinear.ekf_filter` on ``nonlinear_model(motion, ranges(...))``, a named
model that runs compiled; the batch function runs B independent tracks at once
(leading axis) in one compiled loop, which is how the Monte-Carlo reproduction
stays fast (the tests check both agree with the generic path to 1e-12).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from .._core.finiteness import finite_result, require_finite
from .._core.validation import as_array, as_real, check_allocation, check_covariance, check_int, check_positive
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..models import LinearGaussianModel, NonlinearModel, nonlinear_model, ranges
from ..nonlinear import ekf_filter, ekf_filter_batch
from ..result import BatchFilterResult, FilterResult

__all__ = [
    "ekf_ranges",
    "ekf_ranges_batch",
    "range_measurement",
    "motion_matrix",
    "check_stations",
    "range_fix",
    "motion_position",
]

MOTIONS = ("random-walk", "cv")
#: the floor of a range divided by at a station (the smallest normal float: it never acts on a range of
#: any scale; 1e-12 m made the Jacobian wrong for positions below ~1e-10 m)
_TINY_RANGE = float(np.finfo(float).tiny)


@finite_result("the ranges")
def range_measurement(x, stations, position=None):
    """Ranges from the position part of states to stations, and their Jacobian (Bouzera et al. 2017,
    eqs. 7-10).

    At a station (range 0) the gradient is undefined; H is 0 there (the range is floored at the
    smallest normal float).

    Parameters
    ----------
    x : array_like, shape (..., n)
        States; the position is x[..., position].
    stations : array_like, shape (m, d)
        Station positions, d = 2 or 3.
    position : tuple of int, optional
        Indices of the position in the state (default the first d entries).

    Returns
    -------
    ranges : ndarray, shape (..., m)
    H : ndarray, shape (..., m, n)
        (p - B_i) / ||p - B_i|| in the position columns, zeros elsewhere.

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    x = as_array("x", x)
    stations = check_stations(stations)
    d = stations.shape[1]
    if x.ndim == 0 or x.shape[-1] < d:
        raise ShapeError(f"x: expected states (..., n) with n >= {d} (the stations' dimension), got shape {x.shape}")
    pos = tuple(range(d)) if position is None else _state_indices("position", position, d, x.shape[-1])
    check_allocation("x", f"{x.size // x.shape[-1]} states", 8.0 * x.size * stations.shape[0] * 3)
    return ranges_and_jacobian(x, stations, pos)


def ranges_and_jacobian(x: np.ndarray, stations: np.ndarray, pos) -> tuple[np.ndarray, np.ndarray]:
    """:func:`range_measurement` of validated arguments (the filters' inner step).  The range is
    computed by hypot (no overflow of the squares for coordinates up to the float64 range)."""
    pos = list(pos)
    diff = x[..., None, pos] - stations  # (..., m, d)
    rng = np.hypot(diff[..., 0], diff[..., 1])
    if diff.shape[-1] == 3:
        rng = np.hypot(rng, diff[..., 2])
    H = np.zeros(x.shape[:-1] + (stations.shape[0], x.shape[-1]))
    H[..., pos] = diff / np.maximum(rng, _TINY_RANGE)[..., None]
    return rng, H


def _state_indices(name: str, idx, count: int, n: int) -> tuple:
    """``count`` distinct state indices in [0, n)."""
    if isinstance(idx, (str, bytes)) or not np.iterable(idx):
        raise ParameterError(f"{name}: expected {count} state indices, got {idx!r}")
    idx = tuple(check_int(name, i, minimum=0, maximum=n - 1) for i in idx)
    if len(idx) != count or len(set(idx)) != count:
        raise ShapeError(f"{name}: expected {count} distinct state indices, got {idx}")
    return idx


def motion_position(motion: str, dim: int) -> tuple:
    """Indices of the position in the state of a cellular motion model.

    Parameters
    ----------
    motion : {"random-walk", "cv"}
    dim : int
        Spatial dimensions, 2 or 3.

    Returns
    -------
    tuple of int
        (0, .., d-1) for the random walk, (0, 2, 4)[:d] for constant velocity.
    """
    if motion not in MOTIONS:
        raise ParameterError(f"motion: expected one of {MOTIONS}, got {motion!r}")
    dim = check_int("dim", dim, minimum=1, maximum=3)
    return tuple(range(dim)) if motion == "random-walk" else tuple(range(0, 2 * dim, 2))


def motion_matrix(motion: str, dim: int, dt: float = 1.0) -> np.ndarray:
    """The transition matrix of a cellular motion model, axis by axis.

    Parameters
    ----------
    motion : {"random-walk", "cv"}
        Identity (the paper's eq. 2) or constant velocity (block-diag [[1, dt], [0, 1]] per axis).
    dim : int
        Spatial dimensions, 2 or 3.
    dt : float, optional
        Step (s).

    Returns
    -------
    ndarray, shape (n, n)

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    if motion not in MOTIONS:
        raise ParameterError(f"motion: expected one of {MOTIONS}, got {motion!r}")
    dim = check_int("dim", dim, minimum=1, maximum=3)
    dt = check_positive("dt", dt)   # checked even where unused (random walk): an Inf is never accepted
    if motion == "random-walk":
        return np.eye(dim)
    return np.kron(np.eye(dim), np.array([[1.0, dt], [0.0, 1.0]]))


def check_stations(stations, *, min_count: int = 1) -> np.ndarray:
    """Validate station positions.

    Parameters
    ----------
    stations : array_like, shape (m, d)
        d in {2, 3}, finite, no duplicates.
    min_count : int, optional
        Least number of stations.

    Returns
    -------
    ndarray, shape (m, d)

    Raises
    ------
    ParameterError, ShapeError
        The message starts with ``stations``.
    """
    min_count = check_int("min_count", min_count, minimum=1)
    s = as_array("stations", stations, ndim=2)
    if s.shape[1] not in (2, 3):
        raise ShapeError(f"stations: expected shape (m, 2) or (m, 3), got {s.shape}")
    if s.shape[0] < min_count:
        raise ParameterError(f"stations: need at least {min_count} base stations, got {s.shape[0]}")
    # duplicates by sorting (m log m; the pairwise distances took m^2 memory); + 0.0 makes -0.0 equal 0.0
    unique, counts = np.unique(s + 0.0, axis=0, return_counts=True)
    if np.any(counts > 1):
        i, j = np.flatnonzero(((s + 0.0) == unique[np.argmax(counts > 1)]).all(axis=1))[:2]
        raise ParameterError(f"stations: stations {i} and {j} are at the same position {s[i].tolist()}")
    return s


def _prepare(z, stations, x0, P0, Q, R, motion, dt, *, batch: bool):
    stations = check_stations(stations)
    m, d = stations.shape
    F = motion_matrix(motion, d, dt)
    n = F.shape[0]
    z = as_array("z", z, ndim=3 if batch else 2, allow_nan=True)
    if z.shape[-1] != m:
        raise ShapeError(f"z: expected {m} ranges per time step (one per station), got shape {z.shape}")
    if z.shape[-2] == 0:
        raise ShapeError(f"z: expected at least one time step, got shape {z.shape}")
    if np.any(z < 0):
        raise ParameterError("z: ranges must be >= 0 (NaN marks a missing range)")
    if not batch:
        z = z[None]
    B = z.shape[0]
    x0 = as_array("x0", x0, shape=(B, n) if batch else (n,))
    x0 = np.broadcast_to(x0, (B, n)).copy()
    P0 = check_covariance("P0", P0, n)
    Q = check_covariance("Q", Q, n)
    R = as_array("R", R)
    R = check_covariance("R", R * np.eye(m) if R.ndim == 0 else R, m, definite=True)
    return z, stations, x0, P0, F, Q, R, motion_position(motion, d)


@finite_result("the range EKF")
def ekf_ranges(z, stations, x0, P0, Q, R, *, motion: str = "random-walk", dt: float = 1.0) -> FilterResult:
    """EKF from ranges to base stations (Bouzera et al. 2017, eqs. 2-10), all ranges updated jointly.

    Any number of stations is accepted: with fewer than d + 1 the position is not observable from one scan
    and the prior and motion carry the unobserved directions (the covariance shows it).

    Parameters
    ----------
    z : array_like, shape (T, m)
        Measured ranges; NaN = missing (skipped; an all-NaN row predicts).
    stations : array_like, shape (m, d)
        Base-station positions, d = 2 or 3, distinct.
    x0 : array_like, shape (n,)
        The prior X(0/0); n = d (random walk) or 2d (constant velocity, [x, vx, y, vy(, z, vz)]).
    P0 : array_like, shape (n, n)
        The prior covariance.
    Q : array_like, shape (n, n)
        Process-noise covariance (the paper's Q0 = diag(0.02, 0.02, 0.002) km^2).
    R : float or array_like
        Range-noise variance (the paper's R0 = 0.222 km^2) or an (m, m) covariance.
    motion : {"random-walk", "cv"}, optional
        The paper's X(k+1) = X(k) + w, or constant velocity with step dt.
    dt : float, optional
        The step of the constant-velocity motion (s).

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.cellular import ekf_ranges
    >>> stations = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])          # km
    >>> z = np.array([[1.41, 1.42, 1.40], [1.45, 1.38, 1.44]])
    >>> res = ekf_ranges(z, stations, [0.9, 0.9], np.eye(2), np.diag([0.02, 0.02]), 0.222)
    >>> res.x.shape
    (2, 2)
    """
    z, stations, x0, P0, F, Q, R, pos = _prepare(z, stations, x0, P0, Q, R, motion, dt, batch=False)
    return ekf_filter(_ranges_model(stations, F, Q, R, pos, motion), z[0], x0[0], P0)


def _ranges_model(stations, F, Q, R, pos, motion) -> NonlinearModel:
    """The motion (F, Q) observed by :func:`mptrack.models.ranges`: a named model, which the EKF runs
    compiled (the motion's own H, R are not used: the position with unit noise)."""
    motion_model = LinearGaussianModel(F, np.eye(F.shape[0])[list(pos)], Q, np.eye(len(pos)))
    return nonlinear_model(motion_model, ranges(stations, R, position=pos), name=f"ranges EKF ({motion})")


@finite_result("the range EKF")
def ekf_ranges_batch(z, stations, x0, P0, Q, R, *, motion: str = "random-walk",
                     dt: float = 1.0) -> BatchFilterResult:
    """:func:`ekf_ranges` on B independent tracks at once.

    Parameters
    ----------
    z : array_like, shape (B, T, m)
        Measured ranges of B tracks.
    stations : array_like, shape (m, d)
        Base-station positions, d = 2 or 3, distinct.
    x0 : array_like, shape (n,) or (B, n)
        The prior mean(s).
    P0, Q, R, motion, dt
        As for :func:`ekf_ranges`.

    Returns
    -------
    BatchFilterResult

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    return _ekf(z, stations, x0, P0, Q, R, motion, dt, batch=True)


def _ekf(z, stations, x0, P0, Q, R, motion, dt, *, batch: bool) -> BatchFilterResult:
    z, stations, x0, P0, F, Q, R, pos = _prepare(z, stations, x0, P0, Q, R, motion, dt, batch=batch)
    return ekf_filter_batch(_ranges_model(stations, F, Q, R, pos, motion), z, x0, P0)


@finite_result("the range fix")
def range_fix(ranges, stations, *, height=None) -> np.ndarray:
    """Snapshot position from one scan of ranges (nonlinear least squares).

    The linearised solution (differences of squared ranges) starts the Gauss-Newton iterations
    (scipy.optimize.least_squares).  Useful to initialise :func:`ekf_ranges`.

    Parameters
    ----------
    ranges : array_like, shape (m,)
        Measured ranges.
    stations : array_like, shape (m, d)
        Station positions, d = 2 or 3.
    height : float, optional
        With 3-D stations, the handset's known height: the fix is then 2-D (x, y) with z = height (a
        ground handset fixed from masts of similar height).

    Returns
    -------
    ndarray, shape (d,) or (2,)

    Raises
    ------
    ParameterError, SingularMatrixError
        Fewer than (unknowns + 1) stations (3 for a 2-D fix, 4 for 3-D), or all on one line (plane).
    """
    st = check_stations(stations)
    # the linearised start squares the ranges: bound them well inside the float64 range
    r = as_array("ranges", ranges, shape=(st.shape[0],), low=0.0, high=1e150)
    d = st.shape[1]
    fixed = None
    if height is not None:
        if d != 3:
            raise ParameterError("height: only meaningful with 3-D stations")
        fixed = as_real("height", height)
        dz2 = (fixed - st[:, 2]) ** 2
        r = np.sqrt(np.maximum(r ** 2 - dz2, 0.0))
        st = st[:, :2]
    k = st.shape[1]
    if st.shape[0] < k + 1:
        raise ParameterError(f"stations: a {k}-D fix needs at least {k + 1} stations, got {st.shape[0]}")
    # solved in units of the problem's own size, from the middle of the stations: station coordinates
    # of 1e-200 or 1e300 metres (or 1e6 m from the origin with 1 m between them) are then numbers near 1,
    # whose squares neither underflow, overflow nor cancel
    centre = 0.5 * st.min(axis=0) + 0.5 * st.max(axis=0)
    rel = st - centre
    size = max(float(np.abs(rel).max()), float(r.max()))
    rel, r = rel / size, r / size
    A = 2.0 * (rel[1:] - rel[0])
    # rank against the problem's size: stations 1e-200 m apart are one point for ranges of metres
    if np.linalg.matrix_rank(A, tol=max(A.shape) * np.finfo(float).eps * 4.0) < k:
        raise SingularMatrixError(f"stations: the stations are collinear/coplanar (or their spread, "
                                  f"{float(np.ptp(st, axis=0).max()):.3g}, is negligible against ranges up to "
                                  f"{size:.3g}); a {k}-D fix is not determined")
    b = r[0] ** 2 - r[1:] ** 2 + np.sum(rel[1:] ** 2, axis=1) - np.sum(rel[0] ** 2)
    guess = np.linalg.lstsq(A, b, rcond=None)[0]
    sol = centre + size * least_squares(lambda p: np.linalg.norm(p - rel, axis=1) - r, guess, method="lm").x
    require_finite("the fix", sol, ranges=ranges, stations=stations)
    return sol if fixed is None else np.append(sol, fixed)
