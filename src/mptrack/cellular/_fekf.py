"""Fuzzy extended Kalman filter (FEKF) and fuzzy controller system (FCS) of Bouzera et al. (2017).

Both run one local single-station EKF update per base station from the common
prediction (eq. 14, Tables II and IV), weight the local solutions with a
zero-order Takagi–Sugeno system and fuse them (eqs. 15–16):

    X_i   = X^- + K_i Inn_i,   K_i = P^- H_i^T / S_i,   S_i = H_i P^- H_i^T + R_i      (eqs. 4, 11, 12, 14)
    y_i   = FIS1(|Inn_i|, S_i)   (FEKF, Table I)     or   FIS2(d_i)   (FCS, Table III)
    X_est = sum_i y_i X_i / sum_i y_i                                                   (eq. 15)
    P_est = P^- - sum_i w_i (P^- H_i^T K_i^T + K_i H_i P^-) + sum_i w_i^2 K_i S_i K_i^T  (eq. 16, w = y / sum y)

Eq. 16 drops the cross terms w_i w_j K_i H_i P^- H_j^T K_j^T (i != j) that the
shared prediction error puts into eq. 24; ``covariance="exact"`` keeps them,
P_est = A P^- A^T + sum_i w_i^2 R_i K_i K_i^T with A = I - sum_i w_i K_i H_i,
the true covariance of the fused estimate under the linearisation, which is
positive semi-definite by construction.  Eq. 16 is not: over the paper's own
Q0 sensitivity range (Q0 = 5050, Fig. 13) about half of its covariances are
indefinite (docs/errata.md), so ``"exact"`` is the default and ``"paper"``
reproduces the published algorithm.
When no station gives a positive weight (all ranges missing) the step only predicts.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from .._core.finiteness import derived_from, finite_result, renamed
from .._core.validation import as_array, as_vector
from ..errors import NotPositiveDefiniteError, ParameterError, ShapeError
from ..fuzzy import TakagiSugeno, uniform_partition
from ..result import BatchFilterResult, FilterResult, innovation_arrays, mask_missing
from ._ekf import _prepare, _state_indices, check_stations, ranges_and_jacobian

__all__ = [
    "bouzera_fekf_fis",
    "bouzera_fcs_fis",
    "fekf_ranges",
    "TABLE_I",
    "TABLE_III",
    "fekf_ranges_batch",
    "fcs_ranges",
    "fcs_ranges_batch",
    "fuse_local_solutions",
    "local_solutions",
]

#: The FEKF's rule constants as published (Bouzera et al. 2017, Table I; the default of bouzera_fekf_fis),
#: read with five innovation sets (columns) and two covariance sets (rows), as the text says;
#: rows of this array: innovation Very Small .. Very Large; columns: S Small, S Large.
TABLE_I = ((1.0, 0.75), (0.75, 0.5), (0.5, 0.5), (0.25, 0.5), (0.0, 0.25))
#: The FCS's rule constants as published (Bouzera et al. 2017, Table III; the default of bouzera_fcs_fis):
#: distance Very Small .. Very Large.
TABLE_III = (1.0, 0.75, 0.5, 0.25, 0.0)
_FIVE = ("very small", "small", "neutral", "large", "very large")


def bouzera_fekf_fis(inn_universe_km=(0.0, 1.5), s_universe_km2=(0.22, 0.32), consequents=TABLE_I) -> TakagiSugeno:
    """FIS1 of the FEKF (Bouzera et al. 2017, Table I, Figs. 5-6): inputs |innovation| (km) and its
    variance S (km^2).

    The printed membership figures are not legible, so the sets are uniform triangular partitions (5 for
    |Inn|, 2 for S) over the universes the paper reports (section 3.4).

    Parameters
    ----------
    inn_universe_km : tuple of float, optional
        The universe of |Inn| (km).
    s_universe_km2 : tuple of float, optional
        The universe of S (km^2).
    consequents : sequence, optional
        The rule table (5 x 2): the weight of each (|Inn| set, S set).

    Returns
    -------
    TakagiSugeno

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    inn_universe_km, s_universe_km2 = _universe("inn_universe_km", inn_universe_km), \
        _universe("s_universe_km2", s_universe_km2)
    consequents = as_array("consequents", consequents, shape=(5, 2))
    with renamed(lo="inn_universe_km", hi="inn_universe_km"):
        inn = uniform_partition(*inn_universe_km, 5, labels=_FIVE)
    with renamed(lo="s_universe_km2", hi="s_universe_km2"):
        s = uniform_partition(*s_universe_km2, 2, labels=("small", "large"))
    return TakagiSugeno((inn, s), consequents, universes=(inn_universe_km, s_universe_km2),
                        names=("|innovation|", "S"))


def _universe(name: str, value) -> tuple[float, float]:
    """A universe of discourse (lo, hi), lo < hi."""
    lo, hi = as_vector(name, value, 2)
    if not hi > lo:
        raise ParameterError(f"{name}: expected (lo, hi) with lo < hi, got {tuple(value)!r}")
    return float(lo), float(hi)


def bouzera_fcs_fis(distance_universe_km=(0.0, 1.5), consequents=TABLE_III) -> TakagiSugeno:
    """FIS2 of the FCS (Bouzera et al. 2017, Table III, Fig. 7): input the measured range (km), five
    uniform triangular sets.

    Parameters
    ----------
    distance_universe_km : tuple of float, optional
        The universe of the range (km).
    consequents : sequence of float, optional
        The weight of each set.

    Returns
    -------
    TakagiSugeno

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    distance_universe_km = _universe("distance_universe_km", distance_universe_km)
    consequents = as_vector("consequents", consequents, 5)
    with renamed(lo="distance_universe_km", hi="distance_universe_km"):
        d = uniform_partition(*distance_universe_km, 5, labels=_FIVE)
    return TakagiSugeno((d,), consequents, universes=(distance_universe_km,), names=("distance",))


def local_solutions(x_pred, P_pred, z, stations, R_diag, position=None):
    """One-station EKF updates from a common prediction (Bouzera et al. 2017, eqs. 4, 11, 12, 14),
    batched over a leading axis.

    Parameters
    ----------
    x_pred : array_like, shape (B, n)
    P_pred : array_like, shape (B, n, n)
    z : array_like, shape (B, m)
        Ranges (NaN = missing).
    stations : array_like, shape (m, d)
    R_diag : array_like, shape (m,)
        Range variances.
    position : tuple of int, optional
        Indices of the position in the state (default the first d entries).

    Returns
    -------
    x_local, K, H : ndarray, shape (B, m, n)
        Each station's updated state, gain and Jacobian row.
    innov, S : ndarray, shape (B, m)
        Innovations (0 where missing) and their variances.

    Raises
    ------
    NotPositiveDefiniteError
        An innovation variance H P H^T + R <= 0 (an indefinite prediction).

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    stations = check_stations(stations)
    m, d = stations.shape
    x_pred = as_array("x_pred", x_pred, ndim=2)
    B, n = x_pred.shape
    if n < d:
        raise ShapeError(f"x_pred: expected states (B, n) with n >= {d} (the stations' dimension), got {x_pred.shape}")
    P_pred = as_array("P_pred", P_pred, shape=(B, n, n))
    z = as_array("z", z, shape=(B, m), allow_nan=True)
    R_diag = as_vector("R_diag", R_diag, m, low=0.0)
    pos = tuple(range(d)) if position is None else _state_indices("position", position, d, n)
    return _local_solutions(x_pred, P_pred, z, stations, R_diag, pos)


def _local_solutions(x_pred, P_pred, z, stations, R_diag, pos):
    """:func:`local_solutions` of validated arguments (the filters' inner step)."""
    h, H = ranges_and_jacobian(x_pred, stations, pos)               # eqs. 7-10
    PHt = np.einsum("bnk,bmk->bmn", P_pred, H)                       # rows P^- H_i^T
    S = np.einsum("bmn,bmn->bm", H, PHt) + R_diag                    # eq. 12, per station
    if np.any(S <= 0):
        raise NotPositiveDefiniteError(
            "P_pred: an innovation variance H P H^T + R is <= 0; the predicted covariance is indefinite "
            "(eq. 16 of the paper can make it so: use covariance='exact')")
    K = PHt / S[..., None]                                           # eq. 4, per station
    innov = np.where(np.isnan(z), 0.0, z - h)                        # eq. 11
    return x_pred[:, None, :] + K * innov[..., None], K, H, innov, S  # eq. 14


def fuse_local_solutions(x_pred, P_pred, K, H, innov, S, R_diag, y, *, covariance: str = "exact"):
    """Fuse one-station solutions with weights (Bouzera et al. 2017, eqs. 15-16), batched.

    Rows whose weights sum to 0 return the prediction.

    Parameters
    ----------
    x_pred : array_like, shape (B, n)
    P_pred : array_like, shape (B, n, n)
    K, H : array_like, shape (B, m, n)
        Local gains and Jacobian rows (:func:`local_solutions`).
    innov, S : array_like, shape (B, m)
    R_diag : array_like, shape (m,)
    y : array_like, shape (B, m)
        Weights, >= 0.
    covariance : {"exact", "paper"}, optional
        Eq. 16 with the cross-station terms (positive semi-definite), or as printed.

    Returns
    -------
    x_est : ndarray, shape (B, n)
    P_est : ndarray, shape (B, n, n)

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    x_pred = as_array("x_pred", x_pred, ndim=2)
    B, n = x_pred.shape
    P_pred = as_array("P_pred", P_pred, shape=(B, n, n))
    K = as_array("K", K, ndim=3)
    m = K.shape[1]
    K = as_array("K", K, shape=(B, m, n))
    H = as_array("H", H, shape=(B, m, n))
    innov, S = as_array("innov", innov, shape=(B, m)), as_array("S", S, shape=(B, m), low=0.0)
    R_diag = as_vector("R_diag", R_diag, m, low=0.0)
    y = as_array("y", y, shape=(B, m), low=0.0)
    return _fuse(x_pred, P_pred, K, H, innov, S, R_diag, y, covariance)


def _fuse(x_pred, P_pred, K, H, innov, S, R_diag, y, covariance: str):
    """:func:`fuse_local_solutions` of validated arguments (the filters' inner step)."""
    total = y.sum(axis=1)
    live = total > 0
    w = np.where(live[:, None], y / np.where(live, total, 1.0)[:, None], 0.0)
    x = x_pred + np.einsum("bm,bmn,bm->bn", w, K, innov)                           # eq. 15 (via eq. 19)
    KH = np.einsum("bm,bmn,bmk->bnk", w, K, H)                                      # sum_i w_i K_i H_i
    if covariance == "paper":
        KHP = KH @ P_pred
        P = P_pred - KHP - KHP.transpose(0, 2, 1) + np.einsum("bm,bmn,bmk->bnk", w ** 2 * S, K, K)  # eq. 16
    elif covariance == "exact":
        A = np.eye(x.shape[1]) - KH
        P = A @ P_pred @ A.transpose(0, 2, 1) + np.einsum("bm,bmn,bmk->bnk", w ** 2 * R_diag, K, K)
    else:
        raise ParameterError(f"covariance: expected 'paper' or 'exact', got {covariance!r}")
    P = 0.5 * (P + P.transpose(0, 2, 1))
    return np.where(live[:, None], x, x_pred), np.where(live[:, None, None], P, P_pred)


def _fused_core(z, stations, x0, P0, F, Q, R, pos, weights: Callable, covariance: str):
    if np.any(R - np.diag(np.diag(R))):
        raise ParameterError("R: the FEKF/FCS local filters use one range each, so R must be diagonal")
    R_diag = np.diag(R)
    B, T, m = z.shape
    n = F.shape[0]
    xs, xp = np.empty((B, T, n)), np.empty((B, T, n))
    Ps, Pp = np.empty((B, T, n, n)), np.empty((B, T, n, n))
    nus, Ss, _ = innovation_arrays((B, T), m)
    diag = np.arange(m)
    x = x0.copy()
    P = np.broadcast_to(P0, (B, n, n)).copy()
    for k in range(T):
        x = x @ F.T                                                  # eq. 2
        P = F @ P @ F.T + Q                                          # eq. 3
        xp[:, k], Pp[:, k] = x, P
        dk = z[:, k]
        ok = ~np.isnan(dk)
        _, K, H, innov, S = _local_solutions(x, P, dk, stations, R_diag, pos)
        # the joint innovation covariance H P H^T + R of the stations, its diagonal the local S_i
        S_all = H @ P @ H.transpose(0, 2, 1) + R
        S_all[:, diag, diag] = S
        nus[:, k] = np.where(ok, innov, np.nan)
        Ss[:, k] = mask_missing(nus[:, k], S_all)
        y = np.where(ok, weights(np.abs(innov), S, np.where(ok, dk, 0.0)), 0.0)
        x, P = _fuse(x, P, K, H, innov, S, R_diag, y, covariance)
        xs[:, k] = x
        Ps[:, k] = P
    return BatchFilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, innovation=nus, S=Ss)


def _fis_weights(fis, kind: str):
    if fis is None:
        fis = bouzera_fekf_fis() if kind == "FEKF" else bouzera_fcs_fis()
    if not isinstance(fis, TakagiSugeno) or fis.n_inputs != (2 if kind == "FEKF" else 1):
        raise ParameterError(f"fis: expected a TakagiSugeno system with {2 if kind == 'FEKF' else 1} input(s)")
    if kind == "FEKF":
        return lambda inn, S, d: fis(inn, S)
    return lambda inn, S, d: fis(d)


def _run(kind, z, stations, x0, P0, Q, R, fis, motion, dt, covariance, batch):
    args = _prepare(z, stations, x0, P0, Q, R, motion, dt, batch=batch)
    if covariance not in ("paper", "exact"):
        raise ParameterError(f"covariance: expected 'paper' or 'exact', got {covariance!r}")
    weights = _fis_weights(fis, kind)
    with derived_from(z=args[0], stations=args[1], x0=args[2], P0=args[3], Q=args[5], R=args[6]):
        out = replace(_fused_core(*args, weights=weights, covariance=covariance), method=kind)
    return out if batch else out.run(0)


@finite_result("the FEKF")
def fekf_ranges(z, stations, x0, P0, Q, R, *, fis: TakagiSugeno | None = None, motion: str = "random-walk",
                dt: float = 1.0, covariance: str = "exact") -> FilterResult:
    """Fuzzy EKF (Bouzera et al. 2017, Table II): one-station EKF updates fused with the weights
    FIS1(|Inn_i|, S_i).

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
        Scalar or diagonal here (one range per local filter).
    fis : TakagiSugeno, optional
        The fuzzy weight system (default :func:`bouzera_fekf_fis`, Table I).
    motion : {"random-walk", "cv"}, optional
        The paper's X(k+1) = X(k) + w, or constant velocity with step dt.
    dt : float, optional
        The step of the constant-velocity motion (s).
    covariance : {"exact", "paper"}, optional
        The fused covariance: eq. 16 with the cross-station terms (always positive semi-definite), or
        eq. 16 as printed (which can go indefinite).

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    return _run("FEKF", z, stations, x0, P0, Q, R, fis, motion, dt, covariance, False)


@finite_result("the FEKF")
def fekf_ranges_batch(z, stations, x0, P0, Q, R, *, fis=None, motion="random-walk", dt=1.0,
                      covariance="exact") -> BatchFilterResult:
    """:func:`fekf_ranges` on B independent tracks at once.

    Parameters
    ----------
    z : array_like, shape (B, T, m)
        Measured ranges of B tracks.
    stations : array_like, shape (m, d)
        Base-station positions, d = 2 or 3, distinct.
    x0 : array_like, shape (n,) or (B, n)
        The prior mean(s).
    P0, Q, R, fis, motion, dt, covariance
        As for :func:`fekf_ranges`.

    Returns
    -------
    BatchFilterResult

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    return _run("FEKF", z, stations, x0, P0, Q, R, fis, motion, dt, covariance, True)


@finite_result("the FCS filter")
def fcs_ranges(z, stations, x0, P0, Q, R, *, fis: TakagiSugeno | None = None, motion: str = "random-walk",
               dt: float = 1.0, covariance: str = "exact") -> FilterResult:
    """Fuzzy controller system (Bouzera et al. 2017, Table IV): as the FEKF, with the weights FIS2(d_i)
    of the measured ranges.

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
        Scalar or diagonal here (one range per local filter).
    fis : TakagiSugeno, optional
        The fuzzy weight system (default :func:`bouzera_fcs_fis`, Table III).
    motion : {"random-walk", "cv"}, optional
        The paper's X(k+1) = X(k) + w, or constant velocity with step dt.
    dt : float, optional
        The step of the constant-velocity motion (s).
    covariance : {"exact", "paper"}, optional
        The fused covariance: eq. 16 with the cross-station terms (always positive semi-definite), or
        eq. 16 as printed (which can go indefinite).

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    return _run("FCS", z, stations, x0, P0, Q, R, fis, motion, dt, covariance, False)


@finite_result("the FCS filter")
def fcs_ranges_batch(z, stations, x0, P0, Q, R, *, fis=None, motion="random-walk", dt=1.0,
                     covariance="exact") -> BatchFilterResult:
    """:func:`fcs_ranges` on B independent tracks at once.

    Parameters
    ----------
    z : array_like, shape (B, T, m)
        Measured ranges of B tracks.
    stations : array_like, shape (m, d)
        Base-station positions, d = 2 or 3, distinct.
    x0 : array_like, shape (n,) or (B, n)
        The prior mean(s).
    P0, Q, R, fis, motion, dt, covariance
        As for :func:`fcs_ranges`.

    Returns
    -------
    BatchFilterResult

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    return _run("FCS", z, stations, x0, P0, Q, R, fis, motion, dt, covariance, True)
