"""The immutable linear-Gaussian state-space model.

    x(k+1) = F x(k) + w(k),   w ~ N(0, Q)      (Q = G Qw G^T when given as G, Qw)
    z(k)   = H x(k) + v(k),   v ~ N(0, R)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .._core.finiteness import require_finite
from .._core.validation import as_matrix, check_allocation, check_covariance, check_int, check_positive, frozen
from ..errors import ParameterError, ShapeError

__all__ = ["LinearGaussianModel", "stack_axes", "require_model"]


@dataclass(frozen=True, eq=False)
class LinearGaussianModel:
    """A validated, immutable linear-Gaussian model (F, H, Q, R).

    Give the process noise either as ``Q`` (n x n) or as a noise gain ``G``
    (n x p) with the noise covariance ``Qw`` (p x p), in which case
    ``Q = G Qw G^T`` is formed and ``G``/``Qw`` are kept for noise sampling
    and for the papers' formulas written with ``G Q G^T``.

    Arrays are copied and made read-only.  ``dt`` (seconds) and ``name`` are
    descriptive metadata.
    """

    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray | None
    R: np.ndarray
    G: np.ndarray | None = field(default=None, kw_only=True)
    Qw: np.ndarray | None = field(default=None, kw_only=True)
    dt: float | None = field(default=None, kw_only=True)
    name: str = field(default="", kw_only=True)

    def __post_init__(self) -> None:
        F = as_matrix("F", self.F)
        n = F.shape[0]
        if F.shape != (n, n):
            raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
        H = as_matrix("H", self.H, None, n)
        m = H.shape[0]
        R = check_covariance("R", self.R, m, definite=True)
        if (self.G is None) != (self.Qw is None):
            raise ParameterError("G and Qw: give both (Q = G Qw G^T) or neither")
        G = Qw = None
        if self.G is not None:
            G = as_matrix("G", self.G, n, None)
            Qw = check_covariance("Qw", self.Qw, G.shape[1])
            with np.errstate(all="ignore"):
                Q_from_g = G @ Qw @ G.T
                Q_from_g = 0.5 * (Q_from_g + Q_from_g.T)
            require_finite("Q = G Qw G^T", Q_from_g, G=G, Qw=Qw)
            if self.Q is not None:
                Q = check_covariance("Q", self.Q, n)
                if not np.allclose(Q, Q_from_g, rtol=1e-10, atol=1e-14):
                    raise ParameterError("Q: disagrees with G Qw G^T; give Q or (G, Qw), not both")
            Q = Q_from_g
        elif self.Q is None:
            raise ParameterError("Q: the process noise is missing; give Q or (G, Qw)")
        else:
            Q = check_covariance("Q", self.Q, n)
        for attr, value in (("F", F), ("H", H), ("Q", Q), ("R", R), ("G", G), ("Qw", Qw)):
            object.__setattr__(self, attr, None if value is None else frozen(value))
        if self.dt is not None:
            object.__setattr__(self, "dt", check_positive("dt", self.dt))

    @classmethod
    def from_noise_gain(cls, F, H, G, Qw, R, **meta) -> "LinearGaussianModel":
        """Build the model with ``Q = G Qw G^T`` (the papers' ``G Q G^T``)."""
        return cls(F, H, None, R, G=G, Qw=Qw, **meta)

    @property
    def n(self) -> int:
        """State dimension."""
        return self.F.shape[0]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.H.shape[0]

    def noise_factor(self) -> np.ndarray:
        """A matrix L with L L^T = Q (the noise gain times chol(Qw) when available)."""
        if self.G is not None:
            w, V = np.linalg.eigh(self.Qw)
            return self.G @ (V * np.sqrt(np.clip(w, 0.0, None)))
        w, V = np.linalg.eigh(self.Q)
        return V * np.sqrt(np.clip(w, 0.0, None))

    def __repr__(self) -> str:
        label = f" {self.name!r}" if self.name else ""
        return f"<LinearGaussianModel{label} n={self.n} m={self.m} dt={self.dt}>"


def stack_axes(axis_model: LinearGaussianModel, axes: int, *, name: str = "") -> LinearGaussianModel:
    """The joint model of independent copies of one axis model (block-diagonal).

    The state is ordered axis by axis, ``[x_axis0, x_axis1, ...]``: this is how the papers' model A arises
    from model B (Assimakis & Adam 2014, eqs. 17-18).

    Parameters
    ----------
    axis_model : LinearGaussianModel
        The model of one axis.
    axes : int
        Number of copies, >= 1.
    name : str, optional
        Name of the joint model (default: derived from ``axis_model``'s).

    Returns
    -------
    LinearGaussianModel
        F, H, Q, R block-diagonal with one block per axis.

    Raises
    ------
    ParameterError
        ``axis_model`` is not a LinearGaussianModel.
    ResourceError
        The joint matrices would exceed the memory limit.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512

    Examples
    --------
    >>> from mptrack.models import assimakis_model_b, stack_axes
    >>> stack_axes(assimakis_model_b(), 2).F.shape
    (4, 4)
    """
    axis_model = require_model(axis_model, "axis_model")
    axes = check_int("axes", axes, minimum=1)
    n, m = axis_model.n, axis_model.m
    check_allocation("axes", axes, 16.0 * axes * axes * (2 * n * n + 2 * m * n + m * m))   # F, Q, G, H, R (x2)
    blocks = lambda M: scipy.linalg.block_diag(*([M] * axes))  # noqa: E731
    kwargs = dict(dt=axis_model.dt, name=name or f"{axes} x {axis_model.name or 'axis model'}")
    if axis_model.G is not None:
        return LinearGaussianModel.from_noise_gain(
            blocks(axis_model.F), blocks(axis_model.H), blocks(axis_model.G),
            blocks(axis_model.Qw), blocks(axis_model.R), **kwargs)
    return LinearGaussianModel(blocks(axis_model.F), blocks(axis_model.H),
                               blocks(axis_model.Q), blocks(axis_model.R), **kwargs)


def require_model(model, name: str = "model", kind: type = LinearGaussianModel):
    """Check that an argument is a model of the expected type.

    Parameters
    ----------
    model : object
        The argument to check.
    name : str, optional
        The argument's name, used in the error message.
    kind : type, optional
        The expected model class (default :class:`LinearGaussianModel`).

    Returns
    -------
    object
        ``model`` itself.

    Raises
    ------
    ParameterError
        ``model`` is not a ``kind``; the message starts with ``name``.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ParameterError(f"name: expected the argument's name (an identifier), got {name!r}")
    if not isinstance(kind, type):
        raise ParameterError(f"kind: expected a class, got {kind!r}")
    if not isinstance(model, kind):
        raise ParameterError(f"{name}: expected a {kind.__name__}, got {type(model).__name__}")
    return model
