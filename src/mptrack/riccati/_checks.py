"""Existence conditions of the steady state: detectability and stabilisability (PBH test)."""

from __future__ import annotations

import numpy as np

from ..errors import NotDetectableError, NotStabilisableError

__all__ = ["unstable_modes_unobservable", "check_detectable", "check_stabilisable"]


def _rank(mat: np.ndarray) -> int:
    s = np.linalg.svd(mat, compute_uv=False)
    tol = max(mat.shape) * np.finfo(float).eps * max(1.0, s[0] if s.size else 0.0) * 1e3
    return int(np.sum(s > tol))


def _unstable_eigenvalues(F: np.ndarray) -> np.ndarray:
    eig = np.linalg.eigvals(F)
    return eig[np.abs(eig) >= 1.0 - 1e-10]


def unstable_modes_unobservable(F: np.ndarray, H: np.ndarray) -> list[complex]:
    """Eigenvalues |lambda| >= 1 of F that fail the PBH rank test with H."""
    n = F.shape[0]
    return [lam for lam in _unstable_eigenvalues(F)
            if _rank(np.vstack([lam * np.eye(n) - F, H.astype(complex)])) < n]


def check_detectable(F: np.ndarray, H: np.ndarray) -> None:
    """Raise NotDetectableError when an unstable mode of F is invisible in H."""
    bad = unstable_modes_unobservable(F, H)
    if bad:
        raise NotDetectableError(
            "model: the pair (F, H) is not detectable; the unstable mode(s) "
            f"{', '.join(f'{complex(v):.4g}' for v in bad)} of F are not observed by H, "
            "so no steady-state filter exists")


def check_stabilisable(F: np.ndarray, Q_factor: np.ndarray) -> None:
    """Raise NotStabilisableError when an unstable mode of F receives no process noise."""
    bad = unstable_modes_unobservable(F.T, Q_factor.T)
    if bad:
        raise NotStabilisableError(
            "model: the pair (F, Q^{1/2}) is not stabilisable; the unit-circle or unstable "
            f"mode(s) {', '.join(f'{complex(v):.4g}' for v in bad)} of F are not driven by the "
            "process noise, so the steady-state Riccati solution is not stabilising")
