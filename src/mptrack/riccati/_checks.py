"""Existence conditions of the steady state: detectability and stabilisability (PBH test)."""

from __future__ import annotations

import numpy as np

from .._core.validation import as_matrix
from ..errors import ConvergenceError, NotDetectableError, NotStabilisableError, ShapeError

__all__ = ["unstable_modes_unobservable", "undriven_modes", "check_detectable", "check_stabilisable"]


def _pair(first: str, F, second: str, M, rows: bool) -> tuple[np.ndarray, np.ndarray]:
    """Validate a pair (F square, M with n columns (rows=True) or n rows)."""
    F = as_matrix(first, F)
    if F.shape[0] != F.shape[1]:
        raise ShapeError(f"{first}: expected a square matrix, got shape {F.shape}")
    n = F.shape[0]
    M = as_matrix(second, M, None, n) if rows else as_matrix(second, M, n, None)
    return F, M


def _analysed(analysis, F, M, names):
    """``analysis(F, M)``; LAPACK failing to converge (entries near the float range) is a
    ConvergenceError naming the larger of the two matrices."""
    try:
        return analysis(F, M)
    except np.linalg.LinAlgError as exc:
        name = names[0] if np.abs(F).max(initial=0.0) >= np.abs(M).max(initial=0.0) else names[1]
        raise ConvergenceError(f"{name}: the eigen/singular-value analysis of the model did not converge "
                               f"({exc}); entries up to {max(np.abs(F).max(initial=0), np.abs(M).max(initial=0)):.3g} "
                               "are too large, rescale the units") from None


def _rank(mat: np.ndarray) -> int:
    s = np.linalg.svd(mat, compute_uv=False)
    tol = max(mat.shape) * np.finfo(float).eps * max(1.0, s[0] if s.size else 0.0) * 1e3
    return int(np.sum(s > tol))


def _unstable_eigenvalues(F: np.ndarray) -> np.ndarray:
    eig = np.linalg.eigvals(F)
    return eig[np.abs(eig) >= 1.0 - 1e-10]


def _unit(block: np.ndarray) -> np.ndarray:
    """``block`` divided by its largest |entry| (a zero block as it is): scaling a block's rows does not
    change the rank of the stacked matrix, and with both blocks near 1 the rank tolerance means the
    same for each (H or Q^{1/2} of 1e25 or 1e-50 against F of 1 was read as rank-deficient)."""
    big = np.abs(block).max(initial=0.0)
    return block / big if big > 0 else block


def unstable_modes_unobservable(F: np.ndarray, H: np.ndarray) -> list[complex]:
    """Eigenvalues |lambda| >= 1 of F that fail the PBH rank test with H."""
    n = F.shape[0]
    Hu = _unit(H.astype(complex))
    return [lam for lam in _unstable_eigenvalues(F) if _rank(np.vstack([_unit(lam * np.eye(n) - F), Hu])) < n]


def undriven_modes(F: np.ndarray, Q_factor: np.ndarray) -> tuple[list[complex], list[complex]]:
    """(on the unit circle, outside it): the modes |lambda| >= 1 of F that the process noise
    (Q = L L^T, ``Q_factor`` = L) does not drive."""
    bad = unstable_modes_unobservable(F.T, Q_factor.T)
    on = [v for v in bad if abs(abs(v) - 1.0) <= 1e-10]
    return on, [v for v in bad if abs(abs(v) - 1.0) > 1e-10]


def check_detectable(F: np.ndarray, H: np.ndarray) -> None:
    """Check that (F, H) is detectable (the PBH rank test).

    Parameters
    ----------
    F : array_like, shape (n, n)
        Transition matrix.
    H : array_like, shape (m, n)
        Measurement matrix.

    Raises
    ------
    NotDetectableError
        An unstable mode of F is invisible in H; the message names its eigenvalue.
    """
    F, H = _pair("F", F, "H", H, rows=True)
    bad = _analysed(unstable_modes_unobservable, F, H, names=("F", "H"))
    if bad:
        raise NotDetectableError(
            "F: the pair (F, H) is not detectable; the unstable mode(s) "
            f"{', '.join(f'{complex(v):.4g}' for v in bad)} of F are not observed by H, "
            "so no steady-state filter exists")


def check_stabilisable(F: np.ndarray, Q_factor: np.ndarray) -> None:
    """Check that no mode of F on the unit circle is left without process noise (the PBH rank test).

    Only those modes prevent a stabilising solution of the filter DARE (with (F, H) detectable): an
    undriven mode outside the unit circle (F = 2, Q = 0) is estimated from the measurements (P = 3 for
    F = 2, H = 1, Q = 0, R = 1, as scipy finds).

    Parameters
    ----------
    F : array_like, shape (n, n)
        Transition matrix.
    Q_factor : array_like, shape (n, p)
        A factor G of the process noise, Q = G G^T.

    Raises
    ------
    NotStabilisableError
        A mode on the unit circle receives no process noise; the message names its eigenvalue.
    """
    F, Q_factor = _pair("F", F, "Q_factor", Q_factor, rows=False)
    bad, _ = _analysed(undriven_modes, F, Q_factor, names=("F", "Q_factor"))
    if bad:
        raise NotStabilisableError(
            "F: the pair (F, Q^{1/2}) is not stabilisable: mode(s) on the unit circle "
            f"{', '.join(f'{complex(v):.4g}' for v in bad)} of F that the process noise does not drive, "
            "so no stabilising steady-state Riccati solution exists")
