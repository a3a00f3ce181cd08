"""The discrete-time nonlinear model and the standard measurement models.

    x(k) = f(x(k-1)) + w(k),   w(k) ~ N(0, Q(x(k-1), k))
    z(k) = h(x(k)) + v(k),     v(k) ~ N(0, R(x(k), k))

``f`` and ``h`` are vectorised over leading axes: (..., n) -> (..., n) and (..., m),
as for :class:`mptrack.continuous.ContinuousDiscreteModel` (the SDE model, which
stays the model for continuous-time dynamics).  Q and R are constant matrices or
callables ``Q(x, k)`` / ``R(x, k)`` of one state x (n,) and the row k = 0..T-1 of
the measurement sequence, returning (n, n) / (m, m).

Jacobians: give ``jac_f(x)`` / ``jac_h(x)`` (one state (n,) -> (n, n) / (m, n)), or
leave them None for central finite differences, step 6e-6·max(|x_i|, 1) (relative
error ~1e-10 for smooth f, h).  Complex-step differentiation would be exact but
fails on ``np.hypot``/``np.arctan2``/``np.abs``, which nearly every measurement
model uses, so it is not the default.  The named measurement models below carry
their analytic Jacobians.

State order: every model in mptrack orders a 2-D kinematic state axis by axis,
``[x, vx, y, vy]`` (as :func:`constant_velocity` with ``axes=2``, FilterPy and
Stone Soup); the measurement constructors take the indices of the position
(default (0, 2)) and velocity (default (1, 3)) components.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._core.finiteness import renamed
from .._core.gaussian import gauss_logpdf, wrap_periods
from .._core.validation import as_array, as_matrix, as_vector, check_covariance, check_int, check_positive, frozen
from ..errors import NonFiniteError, ParameterError, ShapeError
from ._linear import LinearGaussianModel

__all__ = [
    "NonlinearModel",
    "MeasurementModel",
    "nonlinear_model",
    "wrap_angles",
    "ranges",
    "bearings",
    "range_bearing",
    "range_rate",
    "tdoa",
    "position",
    "stack_measurements",
]

#: the floor of a range (or squared range) divided by at a station, where the gradient is undefined: the
#: smallest normal float, so that it never acts on a range of any scale (1e-12 m made the Jacobian wrong
#: for coordinates below ~1e-10)
_TINY = float(np.finfo(float).tiny)


def wrap_angles(nu: np.ndarray, periods: tuple) -> np.ndarray:
    """Angle components of innovations wrapped into [-period/2, period/2).

    Parameters
    ----------
    nu : array_like, shape (..., m)
        Innovations (NaN = missing, kept).
    periods : tuple of m (float or None)
        The period of each component (e.g. 2 pi for an angle in radians), or None for a component that is
        not an angle.

    Returns
    -------
    ndarray, shape (..., m)
        A wrapped copy of ``nu``.

    Raises
    ------
    ParameterError
        ``periods`` has the wrong length or a period <= 0.
    """
    nu = as_array("nu", nu, allow_nan=True)
    if nu.ndim == 0 or nu.shape[-1] == 0:
        raise ShapeError(f"nu: expected components on the last axis (..., m), got shape {nu.shape}")
    if not isinstance(periods, (tuple, list)) or len(periods) != nu.shape[-1]:
        raise ParameterError(f"periods: expected a tuple of {nu.shape[-1]} periods (None or > 0, one per "
                             f"component of nu), got {periods!r}")
    periods = tuple(None if p is None else check_positive(f"periods[{i}]", p) for i, p in enumerate(periods))
    return wrap_periods(nu, periods)


def _numeric_jacobian(fn, x: np.ndarray, periods: tuple | None = None) -> np.ndarray:
    """Central differences of fn (vectorised) at x (n,): (out, n)."""
    n = x.shape[0]
    step = 6e-6 * np.maximum(np.abs(x), 1.0)
    X = np.concatenate([x + np.diag(step), x - np.diag(step)])
    Y = np.asarray(fn(X), dtype=float)
    diff = Y[:n] - Y[n:]
    if periods is not None:
        diff = wrap_periods(diff, periods)
    return (diff / (2.0 * step)[:, None]).T


def _noise(name: str, value, size: int | None):
    """A constant covariance (validated, frozen) or a callable (x, k) -> covariance."""
    if callable(value):
        return value
    return frozen(check_covariance(name, value, size, definite=name == "R"))


@dataclass(frozen=True, eq=False)
class NonlinearModel:
    """A validated discrete-time nonlinear model (module docstring).

    f, h              vectorised transition and measurement functions
    Q, R              (n, n), (m, m) covariances, or callables Q(x, k), R(x, k)
    jac_f, jac_h      Jacobians of one state (x (n,) -> (n, n), (m, n)); None: finite differences
    angle_components  indices of the measurement components that are angles in radians
                      (innovations wrapped into [-π, π), unscented means taken on the circle)
    n                 state dimension; needed only when Q is a callable
    dt, name          descriptive metadata (seconds between measurements)
    """

    f: Callable[[np.ndarray], np.ndarray]
    h: Callable[[np.ndarray], np.ndarray]
    Q: np.ndarray | Callable
    R: np.ndarray | Callable
    jac_f: Callable | None = field(default=None, kw_only=True)
    jac_h: Callable | None = field(default=None, kw_only=True)
    angle_components: tuple = field(default=(), kw_only=True)
    n: int | None = field(default=None, kw_only=True)
    dt: float | None = field(default=None, kw_only=True)
    name: str = field(default="", kw_only=True)
    periods: tuple = field(init=False, repr=False)
    #: (m,) float, each component's period (2 pi for an angle, 0 for none; read by the compiled filter steps)
    period_array: np.ndarray = field(init=False, repr=False)
    m: int = field(init=False)
    #: set by :func:`nonlinear_model` for a linear motion observed by named measurement models:
    #: (F, codes, pos, stations) read by the compiled filters (mptrack.nonlinear._named_kernels)
    named: tuple | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for attr in ("f", "h"):
            if not callable(getattr(self, attr)):
                raise ParameterError(f"{attr}: expected a callable {attr}(x), got {type(getattr(self, attr)).__name__}")
        for attr in ("jac_f", "jac_h"):
            if getattr(self, attr) is not None and not callable(getattr(self, attr)):
                raise ParameterError(f"{attr}: expected a callable of one state x (n,) or None, "
                                     f"got {type(getattr(self, attr)).__name__}")
        if callable(self.Q):
            if self.n is None:
                raise ParameterError("n: give the state dimension when Q is a callable Q(x, k)")
            n = check_int("n", self.n, minimum=1)
        else:
            Q = _noise("Q", self.Q, self.n)
            n = Q.shape[0]
            set_(self, "Q", Q)
        set_(self, "n", n)
        probe = np.zeros((3, n)) + np.linspace(-0.5, 0.5, 3)[:, None] + 1.0
        fx, hx = (_probe(attr, getattr(self, attr), probe) for attr in ("f", "h"))
        if fx.shape != (3, n):
            raise ShapeError(f"f: must map states (k, {n}) to (k, {n}), got shape {fx.shape} for k = 3")
        if hx.ndim != 2 or hx.shape[0] != 3:
            raise ShapeError(f"h: must map states (k, {n}) to (k, m), got shape {hx.shape} for k = 3")
        m = hx.shape[1]
        set_(self, "m", m)
        set_(self, "R", _noise("R", self.R, m))
        angles = tuple(check_int("angle_components", i, minimum=0) for i in self.angle_components)
        if any(i >= m for i in angles):
            raise ShapeError(f"angle_components: indices must be < m = {m}, got {angles}")
        set_(self, "angle_components", angles)
        set_(self, "periods", tuple(2.0 * np.pi if i in angles else None for i in range(m)))
        period_array = np.array([0.0 if p is None else p for p in self.periods])
        period_array.setflags(write=False)
        set_(self, "period_array", period_array)
        if self.dt is not None:
            set_(self, "dt", check_positive("dt", self.dt))
        for attr, rows in (("jac_f", n), ("jac_h", m)):
            if getattr(self, attr) is not None:
                J = np.asarray(getattr(self, attr)(probe[0]))
                if J.shape != (rows, n):
                    raise ShapeError(f"{attr}: must return a ({rows}, {n}) matrix for a state (n,), got {J.shape}")

    # ------------------------------------------------------------ evaluations used by the filters
    def Q_at(self, x: np.ndarray, k: int) -> np.ndarray:
        """The process-noise covariance of the step into row k from state x."""
        return self.Q if not callable(self.Q) else self._checked("Q", self.Q(x, k), self.n)

    def R_at(self, x: np.ndarray, k: int) -> np.ndarray:
        """The measurement-noise covariance of row k at state x."""
        return self.R if not callable(self.R) else self._checked("R", self.R(x, k), self.m)

    @staticmethod
    def _checked(name, value, size):
        arr = np.asarray(value, dtype=float)
        if arr.shape != (size, size) or not np.all(np.isfinite(arr)):
            raise ShapeError(f"{name}: the callable {name}(x, k) must return a finite ({size}, {size}) matrix, "
                             f"got shape {arr.shape}")
        arr = 0.5 * (arr + arr.T)
        arr.setflags(write=False)   # read-only like a constant Q, R: one compiled variant of the filter steps
        return arr

    def F_at(self, x: np.ndarray) -> np.ndarray:
        """Jacobian of f at x (n,)."""
        return np.asarray(self.jac_f(x), dtype=float) if self.jac_f is not None else _numeric_jacobian(self.f, x)

    def H_at(self, x: np.ndarray) -> np.ndarray:
        """Jacobian of h at x (n,)."""
        if self.jac_h is not None:
            return np.asarray(self.jac_h(x), dtype=float)
        return _numeric_jacobian(self.h, x, self.periods)

    def innovation(self, z, zhat) -> np.ndarray:
        """z - h, angle components wrapped into [-π, π)."""
        return wrap_periods(np.asarray(z, dtype=float) - np.asarray(zhat, dtype=float), self.periods)

    def log_likelihood(self, z: np.ndarray, X: np.ndarray, k: int = 0) -> np.ndarray:
        """log p(z | x) at states X (N, n); NaN components of z are skipped."""
        ok = ~np.isnan(z)
        nu = self.innovation(z, self.h(X))[..., ok]
        if callable(self.R):
            return np.array([gauss_logpdf(v, self.R_at(x, k)[np.ix_(ok, ok)]) for v, x in zip(nu, X)])
        return gauss_logpdf(nu, self.R[np.ix_(ok, ok)])

    def sample_transition(self, X: np.ndarray, rng: np.random.Generator, k: int = 0) -> np.ndarray:
        """Draw x(k) given x(k-1) = X (N, n)."""
        FX = np.asarray(self.f(X), dtype=float)
        if callable(self.Q):
            return FX + np.stack([_factor(self.Q_at(x, k)) @ rng.standard_normal(self.n) for x in X])
        return FX + rng.standard_normal(X.shape) @ _factor(self.Q).T

    def __repr__(self) -> str:
        label = f" {self.name!r}" if self.name else ""
        return f"<NonlinearModel{label} n={self.n} m={self.m}>"


def _probe(name: str, fn, states: np.ndarray) -> np.ndarray:
    """``fn(states)`` as an array; a function that cannot take states of this size is a ShapeError."""
    try:
        with np.errstate(all="ignore"):
            out = np.asarray(fn(states))
    except (IndexError, ValueError, TypeError) as exc:
        raise ShapeError(f"{name}: cannot be evaluated on states (k, {states.shape[1]}) ({type(exc).__name__}: "
                         f"{exc})") from None
    if out.dtype.kind in "fc" and not np.isfinite(out).all():
        raise NonFiniteError(f"{name}: gives non-finite values at the probe states (k, {states.shape[1]}) near 1")
    return out


def _factor(Q: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(Q)
    return V * np.sqrt(np.clip(w, 0.0, None))


# ---------------------------------------------------------------- measurement models
@dataclass(frozen=True, eq=False)
class MeasurementModel:
    """A measurement function with its Jacobian, noise and angle components (built by the constructors
    below; combine with a motion model by :func:`nonlinear_model`)."""

    h: Callable
    jac_h: Callable
    R: np.ndarray | Callable
    angle_components: tuple = ()
    name: str = ""
    #: set by the constructors (leave None for your own h): the components as the compiled filters read
    #: them, or None (e.g. TDOA, range rate): codes (m,)
    #: (0 range, 1 bearing, 2 state component), pos (m, 3) state indices of the position (-1 padded;
    #: code 2: the observed component) and stations (m, 3)
    kernel: tuple | None = field(default=None, repr=False)
    #: set by the constructors: the state components it reads are below this (the largest index + 1;
    #: :func:`nonlinear_model` checks it against the motion's n); 0 for your own h (not known)
    states: int = 0


_RANGE, _BEARING, _COMPONENT = 0, 1, 2


def _kernel_spec(code: int, pos: tuple, stations: np.ndarray) -> tuple:
    """The kernel description of len(stations) components of one kind seen from the position x[pos]."""
    k = len(stations)
    codes = np.full(k, code, dtype=np.int64)
    idx = np.full((k, 3), -1, dtype=np.int64)
    idx[:, :len(pos)] = pos
    st = np.zeros((k, 3))
    st[:, :stations.shape[1]] = stations
    return codes, idx, st


def _join_specs(specs) -> tuple | None:
    if any(spec is None for spec in specs):
        return None
    joined = tuple(np.ascontiguousarray(np.concatenate(parts)) for parts in zip(*specs))
    for arr in joined:
        arr.setflags(write=False)
    return joined


@renamed(h="measurement", jac_h="measurement", R="measurement", angle_components="measurement", f="motion",
         jac_f="motion", Q="motion", dt="motion")      # the model's parts are the caller's motion and measurement
def nonlinear_model(motion: LinearGaussianModel, measurement: MeasurementModel, *, name: str = "") -> NonlinearModel:
    """A linear-Gaussian motion model observed by a nonlinear measurement.

    Parameters
    ----------
    motion : LinearGaussianModel
        The motion (its F and Q; e.g. :func:`constant_velocity`).
    measurement : MeasurementModel
        The measurement (:func:`ranges`, :func:`bearings`, :func:`range_bearing`, ...).
    name : str, optional
        The model's name (default: derived from both).

    Returns
    -------
    NonlinearModel
        With the exact Jacobians F and ``measurement.jac_h``; a named measurement runs the compiled
        filters.

    Raises
    ------
    ParameterError
        ``motion`` or ``measurement`` is of the wrong type, or their state sizes disagree.

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.models import constant_velocity, nonlinear_model, ranges
    >>> stations = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0]])
    >>> model = nonlinear_model(constant_velocity(1.0, 0.5, axes=2), ranges(stations, 25.0))
    >>> model.n, model.m
    (4, 3)
    """
    if not isinstance(motion, LinearGaussianModel):
        raise ParameterError(f"motion: expected a LinearGaussianModel, got {type(motion).__name__}")
    if not isinstance(measurement, MeasurementModel):
        raise ParameterError(f"measurement: expected a MeasurementModel, got {type(measurement).__name__}")
    if measurement.states > motion.n:     # indices beyond the state would be cut off silently (slices)
        raise ShapeError(f"measurement: reads state component {measurement.states - 1} ({measurement.name}), but "
                         f"motion has n = {motion.n} states; give the measurement's position= (velocity=) "
                         "indices of this state")
    F = motion.F
    Ft = np.ascontiguousarray(F.T)
    model = NonlinearModel(lambda X: X @ Ft, measurement.h, motion.Q, measurement.R,
                           jac_f=lambda x: np.broadcast_to(F, np.shape(x)[:-1] + F.shape),
                           jac_h=measurement.jac_h, angle_components=measurement.angle_components, dt=motion.dt,
                           name=name or f"{motion.name or 'linear motion'} + {measurement.name}")
    spec = measurement.kernel
    if spec is not None and not callable(model.R) and int(spec[1].max()) < model.n:
        object.__setattr__(model, "named", (frozen(np.ascontiguousarray(F, dtype=float)),) + tuple(spec))
    return model


def _selector(idx: tuple):
    """Indices as a slice when they step evenly (basic indexing: a view, several times faster than the
    fancy indexing of a list on the single states of the filters' inner loops), else as a list."""
    step = idx[1] - idx[0] if len(idx) > 1 else 1
    if step > 0 and all(b - a == step for a, b in zip(idx, idx[1:])):
        return slice(idx[0], idx[-1] + 1, step)
    return list(idx)


def _indices(name: str, idx, count: int | None = None, points: str = "") -> tuple:
    """State indices; ``count`` of them when given, the dimension of the argument ``points``
    (a 3-D sensor with the default 2-D position: the message names the points the caller passed)."""
    idx = tuple(check_int(name, i, minimum=0) for i in np.atleast_1d(idx).tolist())
    if count is not None and len(idx) != count:
        first = f"{points}: {count}-D {points} need" if points else f"{name}: expected"
        raise ShapeError(f"{first} {count} state indices in {name}, got {idx}")
    if len(set(idx)) != len(idx):
        raise ParameterError(f"{name}: indices must be distinct, got {idx}")
    return idx


def _points(name: str, value) -> np.ndarray:
    pts = as_array(name, value)
    pts = pts[None] if pts.ndim == 1 else pts
    pts = as_matrix(name, pts)
    if pts.shape[1] not in (2, 3):
        raise ShapeError(f"{name}: expected positions of shape (d,) or (k, d) with d = 2 or 3, got {pts.shape}")
    return frozen(pts)


def _covariance(R, m: int):
    """R as a scalar variance (same for every component), a vector of variances, a matrix, or a callable."""
    if callable(R):
        return R
    arr = as_array("R", R)
    if arr.ndim == 0:
        arr = check_positive("R", float(arr)) * np.eye(m)
    elif arr.ndim == 1:
        arr = np.diag(as_vector("R", arr, m))
    return frozen(check_covariance("R", arr, m, definite=True))


def _jac_from(pos: tuple, rows_fn):
    """A Jacobian function placing rows_fn(x) (..., m, len(pos)) into the position columns of an (..., m, n)
    array (states x (..., n): the named models' Jacobians are vectorised like h)."""
    sel = _selector(pos)

    def jac(x):
        x = np.asarray(x, dtype=float)
        G = rows_fn(x)
        J = np.zeros(G.shape[:-1] + (x.shape[-1],))
        J[..., sel] = G
        return J
    return jac


def ranges(stations, R, *, position=(0, 2)) -> MeasurementModel:
    """Ranges (m) from the position to each station (TOA times c).

    h_i(x) = ||p - s_i|| with p = x[position]; the Jacobian rows are (p - s_i) / ||p - s_i|| (0 at a
    station).

    Parameters
    ----------
    stations : array_like, shape (d,) or (k, d)
        One sensor or k stations, d = len(position) = 2 or 3 (m).
    R : float, array_like or callable
        Variance (m^2) common to all ranges, a vector of k variances, a (k, k) matrix, or R(x, k).
    position : tuple of int, optional
        Indices of the position in the state (default (0, 2): x and y of ``[x, vx, y, vy]``).

    Returns
    -------
    MeasurementModel
    """
    s = _points("stations", stations)
    pos = _indices("position", position, s.shape[1], "stations")
    sel = _selector(pos)

    def h(X):
        diff = np.asarray(X)[..., None, sel] - s
        return np.sqrt(np.sum(diff * diff, axis=-1))

    def rows(x):
        diff = x[..., None, sel] - s
        return diff / np.maximum(np.sqrt(np.sum(diff * diff, axis=-1)), _TINY)[..., None]
    return MeasurementModel(h, _jac_from(pos, rows), _covariance(R, s.shape[0]), (), f"ranges to {len(s)}",
                            _join_specs([_kernel_spec(_RANGE, pos, s)]), states=max(pos) + 1)


def bearings(stations, R, *, position=(0, 2)) -> MeasurementModel:
    """Bearings (AOA, rad) from each station to the 2-D position.

    h_i(x) = atan2(y - s_y, x - s_x), counter-clockwise from the x axis (as Stone Soup's
    CartesianToBearingRange); the components are angles (period 2 pi).

    Parameters
    ----------
    stations : array_like, shape (2,) or (k, 2)
        One sensor or k stations (m).
    R : float, array_like or callable
        Variance (rad^2), a vector of k variances, a (k, k) matrix, or R(x, k).
    position : tuple of int, optional
        Indices of the position in the state (default (0, 2): x and y of ``[x, vx, y, vy]``).

    Returns
    -------
    MeasurementModel
    """
    s = _points("stations", stations)
    if s.shape[1] != 2:
        raise ShapeError(f"stations: bearings need 2-D stations (k, 2), got {s.shape}")
    pos = _indices("position", position, 2)
    sel = _selector(pos)

    def h(X):
        diff = np.asarray(X)[..., None, sel] - s
        return np.arctan2(diff[..., 1], diff[..., 0])

    def rows(x):
        diff = x[..., None, sel] - s
        r2 = np.maximum(np.sum(diff * diff, axis=-1), _TINY)
        G = np.empty(diff.shape)
        G[..., 0] = -diff[..., 1] / r2
        G[..., 1] = diff[..., 0] / r2
        return G
    k = s.shape[0]
    return MeasurementModel(h, _jac_from(pos, rows), _covariance(R, k), tuple(range(k)), f"bearings from {k}",
                            _join_specs([_kernel_spec(_BEARING, pos, s)]), states=max(pos) + 1)


def range_bearing(sensor, R, *, position=(0, 2)) -> MeasurementModel:
    """[bearing (rad), range (m)] of the 2-D position from one sensor (Stone Soup's order).

    Parameters
    ----------
    sensor : array_like, shape (2,)
        The sensor's position (m).
    R : array_like or callable
        A (2, 2) covariance, a vector of the 2 variances, or R(x, k).
    position : tuple of int, optional
        Indices of the position in the state (default (0, 2): x and y of ``[x, vx, y, vy]``).

    Returns
    -------
    MeasurementModel
    """
    with renamed(stations="sensor"):
        b, r = bearings(sensor, 1.0, position=position), ranges(sensor, 1.0, position=position)
    return MeasurementModel(lambda X: np.concatenate([b.h(X), r.h(X)], axis=-1),
                            lambda x: np.concatenate([b.jac_h(x), r.jac_h(x)], axis=-2), _covariance(R, 2), (0,),
                            "range-bearing", _join_specs([b.kernel, r.kernel]), states=max(b.states, r.states))


def range_rate(sensor, R, *, position=(0, 2), velocity=(1, 3)) -> MeasurementModel:
    """Range rate (m/s) of a target seen from a static sensor (Doppler).

    h(x) = (p - s) . v / ||p - s|| with p = x[position], v = x[velocity].

    Parameters
    ----------
    sensor : array_like, shape (d,)
        The sensor's position (m).
    R : float or callable
        Variance ((m/s)^2), or R(x, k).
    position : tuple of int, optional
        Indices of the position in the state (default (0, 2): x and y of ``[x, vx, y, vy]``).
    velocity : tuple of int, optional
        Indices of the velocity in the state (default (1, 3)).

    Returns
    -------
    MeasurementModel
    """
    s = _points("sensor", sensor)
    if s.shape[0] != 1:
        raise ShapeError(f"sensor: expected one position (d,), got {s.shape}")
    s = s[0]
    d = s.shape[0]
    pos, vel = _indices("position", position, d, "sensor"), _indices("velocity", velocity, d, "sensor")
    psel, vsel = _selector(pos), _selector(vel)

    def h(X):
        X = np.asarray(X)
        p, v = X[..., psel] - s, X[..., vsel]
        r = np.maximum(np.sqrt(np.sum(p * p, axis=-1)), _TINY)
        return (np.sum(p * v, axis=-1) / r)[..., None]

    def jac(x):
        x = np.asarray(x, dtype=float)
        p, v = x[..., psel] - s, x[..., vsel]
        r = np.maximum(np.sqrt(np.sum(p * p, axis=-1)), _TINY)[..., None]
        rr = np.sum(p * v, axis=-1)[..., None] / r
        J = np.zeros(x.shape[:-1] + (1, x.shape[-1]))
        J[..., 0, psel] = (v - rr * p / r) / r
        J[..., 0, vsel] = p / r
        return J
    return MeasurementModel(h, jac, _covariance(R, 1), (), "range rate", states=max(pos + vel) + 1)


def tdoa(stations, R, *, position=(0, 2), reference: int = 0) -> MeasurementModel:
    """Range differences (TDOA times c, m) ||p - s_i|| - ||p - s_ref|| for every station i other than
    the reference.

    Parameters
    ----------
    stations : array_like, shape (k, d)
        The stations (m), k >= 2.
    R : float, array_like or callable
        The variance sigma^2 of one station's range (TOA) error, so that the differences have the correlated
        covariance sigma^2 (I + 1 1^T); or a full (k - 1, k - 1) matrix, or R(x, k).
    position : tuple of int, optional
        Indices of the position in the state (default (0, 2): x and y of ``[x, vx, y, vy]``).
    reference : int, optional
        Index of the reference station.

    Returns
    -------
    MeasurementModel
    """
    toa = ranges(stations, 1.0, position=position)
    k = toa.R.shape[0]
    if k < 2:
        raise ParameterError(f"stations: TDOA needs at least 2 stations, got {k}")
    ref = check_int("reference", reference, minimum=0)
    if ref >= k:
        raise ParameterError(f"reference: expected a station index < {k}, got {ref}")
    others = [i for i in range(k) if i != ref]
    if not callable(R):
        R = as_array("R", R)
    if not callable(R) and R.ndim == 0:
        var = check_positive("R", float(R))
        R = var * (np.eye(k - 1) + np.ones((k - 1, k - 1)))

    def h(X):
        r = toa.h(X)
        return r[..., others] - r[..., ref:ref + 1]

    def jac(x):
        J = toa.jac_h(x)
        return J[..., others, :] - J[..., ref:ref + 1, :]
    return MeasurementModel(h, jac, _covariance(R, k - 1), (), f"TDOA to {k} stations", states=toa.states)


def position(R, *, position=(0, 2)) -> MeasurementModel:
    """The position itself (a GPS fix; linear, so that a hybrid model can stack it).

    Parameters
    ----------
    R : float, array_like or callable
        Variance (m^2), a vector of variances, a (d, d) matrix, or R(x, k).
    position : tuple of int, optional
        Indices of the position in the state (default (0, 2): x and y of ``[x, vx, y, vy]``).

    Returns
    -------
    MeasurementModel
    """
    pos = _indices("position", position)
    sel = _selector(pos)

    def h(X):
        return np.asarray(X)[..., sel].copy()
    eye = np.eye(len(pos))
    return MeasurementModel(h, _jac_from(pos, lambda x: np.broadcast_to(eye, x.shape[:-1] + eye.shape)),
                            _covariance(R, len(pos)), (), "position",
                            _join_specs([_kernel_spec(_COMPONENT, (i,), np.zeros((1, 1))) for i in pos]),
                            states=max(pos) + 1)


def stack_measurements(*measurements: MeasurementModel) -> MeasurementModel:
    """Several measurement models of one state observed together (hybrid positioning, e.g. TOA + AOA).

    Parameters
    ----------
    *measurements : MeasurementModel
        The models, at least one; their components are concatenated in this order, with independent errors
        (R block-diagonal; constant R only).

    Returns
    -------
    MeasurementModel

    Raises
    ------
    ParameterError
        No model, a model that is not a MeasurementModel, or a callable R.
    """
    if not measurements or not all(isinstance(mm, MeasurementModel) for mm in measurements):
        raise ParameterError("measurements: expected one or more MeasurementModel")
    if any(callable(mm.R) for mm in measurements):
        raise ParameterError("measurements: stacking needs constant R matrices (build a NonlinearModel with "
                             "R(x, k) yourself for state-dependent noise)")
    import scipy.linalg
    sizes = [mm.R.shape[0] for mm in measurements]
    offsets = np.cumsum([0] + sizes)
    angles = tuple(int(o + i) for mm, o in zip(measurements, offsets) for i in mm.angle_components)
    return MeasurementModel(lambda X: np.concatenate([mm.h(X) for mm in measurements], axis=-1),
                            lambda x: np.concatenate([mm.jac_h(x) for mm in measurements], axis=-2),
                            frozen(scipy.linalg.block_diag(*[mm.R for mm in measurements])), angles,
                            " + ".join(mm.name for mm in measurements),
                            _join_specs([mm.kernel for mm in measurements]),
                            states=max(mm.states for mm in measurements))
