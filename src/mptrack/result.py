"""The result record of every filter in mptrack: :class:`FilterResult` (one track) and
:class:`BatchFilterResult` (B tracks, a leading track axis).

Fields, for T measurement times z(1..T) with n states and m measurement components:

    x           (T, n)     filtered means x(k/k)
    P           (T, n, n)  filtered covariances P(k/k)
    x_pred      (T, n)     predicted means x(k/k-1)
    P_pred      (T, n, n)  predicted covariances P(k/k-1)
    innovation  (T, m)     z(k) - zhat(k/k-1), the measurement minus its prediction (angles wrapped);
                           NaN for a component that was missing (all NaN on a row that only predicts)
    S           (T, m, m)  the innovation covariance the update used; rows and columns of missing
                           components NaN (all NaN on a row that only predicts)
    nis         (T,)       normalised innovation squared innovation^T S^-1 innovation over the
                           components used; NaN on a row that only predicts.  Filled from innovation
                           and S (:func:`normalised_innovation`) unless the filter gives it.
    loglik      log-likelihood of the measurements (float)
    method      the filter's name ("KF", "LF", "UKF", ...)
    x0, P0      a filter's prior x(0/0), P(0/0) at time 0, or a smoother's x(0/T), P(0/T)
    inputs      what a smoother must reuse (kalman_filter's per-step F, Q, B u; ukf_filter's
                sigma-point parameters), or None

A field that the algorithm does not form is None.  Which filter forms what:

    KF, irregular-time KF, gated KF, EKF, UKF,          every field
    range EKF (cellular)
    FEKF, FCS (cellular)         every field; innovation = the per-station Inn_i of the common
                                 prediction, S = H P(k/k-1) H^T + R of all stations (its diagonal
                                 is the per-station S_i), loglik None (no joint likelihood)
    LF, SSKF, SSLF, JKLF,        x, P only (the algebra has no prediction or innovation); run from
    JSSKLF, FIR                  the registry, ``mptrack.linear.FILTERS[name].run``, they carry x_pred
                                 .. nis of the one-step prediction of their previous estimate
    IMM                          no innovation, S, nis (each mode forms its own; the combined
                                 estimate forms none); adds mu, x_modes (IMMResult)
    PF, reference, FEM           no innovation, S, nis (the likelihood is evaluated per particle or
                                 grid node; no Gaussian innovation is formed)
    smoothers, predictors        x, P (and x0, P0 for a smoother of a prior at time 0)
    batch SSKF, FIR              x, P, inputs: P a read-only view of the one steady-state Pe
    (mptrack.batch)              (as the single-track forms report it), inputs {"steady": ...}
    batch KF, range EKF          x only: each track's P is formed and discarded by the kernel;
    (mptrack.batch)              the KF's shared gain sequence (the P of complete tracks) in
                                 inputs {"gains": ...}

On a linear-Gaussian model every filter is compared with the KF (tests/test_filter_contract.py, the
largest difference relative to the largest entry of each field, x .. nis and loglik):

    LF, JKLF, EKF, UKF, IMM (one model), irregular-time KF at equal     1e-9 (the same algebra)
    steps, gated KF (no fix outside the gate)
    SSKF, SSLF, JSSKLF                  1e-9 while the KF is in steady state (from P0 = the
                                        steady-state covariance, no missing row since)
    FIR                                 its eps (1e-3): ||A^M|| < eps bounds the truncation
    UKF, continuous-discrete model      1e-4: RK4 sub-steps by the drift's rate
    FEM, 20 x 20 grid                   0.02 (the grid's discretisation error; 5e-3 measured)
    PF, 4000 particles                  0.15 (Monte-Carlo noise and the sub-step bias; <= 0.085
                                        measured over seeds)
    reference, 20000 particles          0.08 (0.023 measured)
    FEKF, FCS with one station          1e-9 to the range EKF (not a linear model: ranges)
    batch filters (mptrack.batch)       those of their single-track forms, which they equal to 1e-10

Subclasses add what one filter alone has: the gated KF's flags and per-step transitions
(:class:`mptrack.tracking.GatedResult`), the IMM's mode probabilities
(:class:`mptrack.nonlinear.IMMResult`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ._core.finiteness import finite_result
from ._core.validation import as_array
from .errors import ParameterError, ShapeError, SingularMatrixError

__all__ = ["FilterResult", "BatchFilterResult", "normalised_innovation"]


@finite_result("the normalised innovation")
def normalised_innovation(innovation, S) -> np.ndarray:
    """The normalised innovation squared, innovation^T S^-1 innovation, over the observed components of
    each row.

    Parameters
    ----------
    innovation : array_like, shape (..., m)
        NaN marks a missing component.
    S : array_like, shape (..., m, m)
        Finite where the innovation is observed.

    Returns
    -------
    ndarray, shape (...)
        NaN for a row without an observed component.
    """
    nu = as_array("innovation", innovation, allow_nan=True)
    if nu.ndim == 0 or nu.shape[-1] == 0:
        raise ShapeError(f"innovation: expected shape (..., m) with m >= 1, got {nu.shape}")
    S = as_array("S", S, shape=nu.shape + (nu.shape[-1],), allow_nan=True)
    ok = ~np.isnan(nu)
    if np.isnan(S[ok[..., :, None] & ok[..., None, :]]).any():
        raise ParameterError("S: NaN in the covariance of an observed innovation component")
    try:
        return _normalised(nu, S)
    except np.linalg.LinAlgError:
        raise SingularMatrixError("S: an innovation covariance is singular") from None


def _normalised(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """:func:`normalised_innovation` of validated arrays."""
    m = nu.shape[-1]
    lead = nu.shape[:-1]
    nu, S = nu.reshape(-1, m), S.reshape(-1, m, m)
    ok = ~np.isnan(nu)
    if ok.all():
        return np.einsum("ti,ti->t", nu, np.linalg.solve(S, nu[..., None])[..., 0]).reshape(lead)
    out = np.full(nu.shape[0], np.nan)
    # rows with the same observed components solve together (a pattern's code: its bits)
    codes = ok @ (1 << np.arange(m))
    for code in np.unique(codes[codes > 0]):
        rows = codes == code
        pattern = ok[np.argmax(rows)]
        v = nu[rows][:, pattern]
        Sp = S[rows][:, pattern][:, :, pattern]
        out[rows] = np.einsum("ti,ti->t", v, np.linalg.solve(Sp, v[..., None])[..., 0])
    return out.reshape(lead)


def innovation_arrays(lead: tuple, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NaN-filled (innovation (*lead, m), S (*lead, m, m), nis (*lead)) for a filter to write the
    components it uses into (lead = (T,) or (B, T)); what it leaves is missing."""
    return np.full((*lead, m), np.nan), np.full((*lead, m, m), np.nan), np.full(lead, np.nan)


def mask_missing(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """S (..., m, m) with NaN in the rows and columns of the components whose innovation is NaN
    (in place; returns S)."""
    missing = np.isnan(innovation)
    S[missing[..., :, None] | missing[..., None, :]] = np.nan
    return S


@dataclass(frozen=True, eq=False)
class _Fields:
    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray | None = None
    P_pred: np.ndarray | None = None
    loglik: float | np.ndarray | None = None
    method: str = ""
    x0: np.ndarray | None = None
    P0: np.ndarray | None = None
    inputs: dict | None = None
    innovation: np.ndarray | None = None
    S: np.ndarray | None = None
    nis: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.nis is None and self.innovation is not None and self.S is not None:
            object.__setattr__(self, "nis", _normalised(np.asarray(self.innovation, float), np.asarray(self.S, float)))


@dataclass(frozen=True, eq=False)
class FilterResult(_Fields):
    """Output of a filter run over T measurement times (module docstring: the fields, and which
    filter forms which)."""

    @property
    def T(self) -> int:
        return self.x.shape[0]

    @property
    def n(self) -> int:
        return self.x.shape[1]


@dataclass(frozen=True, eq=False)
class BatchFilterResult(_Fields):
    """B filter runs: the fields of :class:`FilterResult` with a leading track axis (x (B, T, n),
    P (B, T, n, n), innovation (B, T, m), nis (B, T), loglik (B,), x0 (B, n), ...); ``inputs`` and
    ``method`` are shared.  ``run(b)`` is track b as a FilterResult."""

    @property
    def B(self) -> int:
        return self.x.shape[0]

    def run(self, b: int) -> FilterResult:
        """Track ``b`` as a FilterResult."""
        row = {}
        for f in fields(_Fields):
            value = getattr(self, f.name)
            if f.name in ("method", "inputs") or value is None:
                row[f.name] = value
            elif f.name == "loglik":
                row[f.name] = float(value[b])
            else:
                row[f.name] = value[b]
        return FilterResult(**row)

