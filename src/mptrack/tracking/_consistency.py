"""How the fixes of a track were used, and whether the filter was consistent with them: the one
definition of the counts and of the mean NIS that the track table, the run summary (``--json``), the
command line, ``mptrack evaluate`` and the HTML report all print (docs/tracking.md, "Consistency").

* Counts are counts of the output's ``flag``: ``updates``, ``manoeuvres``, ``outliers`` and ``resets``
  (fixes flagged ``reset``); a **restart** is one event, a run of consecutive ``reset`` fixes of a
  track (the filter started again from them).
* The NIS of a fix, eps = nu^T S^-1 nu, is chi-square with its degrees of freedom d (2 for a fix, the
  number of ranges for a cellular scan) for a consistent filter (Bar-Shalom, Li & Kirubarajan 2001,
  sec. 5.4).  The **mean NIS** of a track, or of all tracks together, is taken over the fixes the
  filter updated from its own prediction: flags ``update`` and ``manoeuvre``.  Left out are the
  first fix (``init``: no prediction), fixes the gate rejected (``outlier``), fixes that restarted
  the filter (``reset``: their innovation is against the prediction the filter gave up) and slots
  without a fix (``predicted``).
* Its **95 % band**: the mean of n such values with d_1 + ... + d_n degrees of freedom in all lies
  between chi2.ppf(0.025, sum d) / n and chi2.ppf(0.975, sum d) / n; inside it, the track is
  consistent (``nis_consistent``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import scipy.special

from .._core.validation import _to_array, as_array, as_real, check_int
from ..errors import DTypeError, MptrackError, ParameterError, ShapeError
from ._track_filter import FLAGS

__all__ = ["USED_FLAGS", "nis_band", "nis_stats", "pooled_nis", "nis_sentence", "restart_mask", "flag_counts",
           "is_flag"]

#: The flags of the fixes the mean NIS is taken over.
USED_FLAGS = ("update", "manoeuvre")


def nis_band(n, dof=2.0, probability: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided ``probability`` interval of the mean NIS of ``n`` fixes of ``dof`` degrees of freedom
    each on average (chi-square with n * dof degrees of freedom, divided by n); NaN where n is 0."""
    n = np.asarray(n, dtype=float)
    k = n * np.asarray(dof, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):  # chdtri(k, p): the chi-square quantile 1 - p
        lo = scipy.special.chdtri(k, (1 + probability) / 2) / n
        hi = scipy.special.chdtri(k, (1 - probability) / 2) / n
    return np.where(n > 0, lo, np.nan), np.where(n > 0, hi, np.nan)


def nis_stats(nis, dof, flags) -> dict:
    """The one mean NIS of the fixes of one track or of several, with its band.

    The mean is over the used fixes (:data:`USED_FLAGS`, a finite NIS); the band is the 95 % band of the
    mean.

    Parameters
    ----------
    nis : array_like
        The NIS of each row.
    dof : array_like
        Its degrees of freedom.
    flags : array_like of str
        The flag of each row.

    Returns
    -------
    dict
        "mean_nis", "nis_dof" (the mean degrees of freedom), "nis_fixes", "nis_lo", "nis_hi",
        "nis_consistent" (NaN and False without used fixes).
    """
    nis = as_array("nis", nis, ndim=1, finite=False, allow_nan=True)
    dof = as_array("dof", dof, shape=(len(nis),), low=0)
    flags = _flags(flags, len(nis))
    used = is_flag(flags, *USED_FLAGS) & np.isfinite(nis)
    n = int(used.sum())
    if not n:
        return _no_fixes()
    mean, d = float(nis[used].mean()), float(dof[used].mean())
    lo, hi = (float(v) for v in nis_band(n, d))
    return {"mean_nis": mean, "nis_dof": d, "nis_fixes": n, "nis_lo": lo, "nis_hi": hi,
            "nis_consistent": bool(lo <= mean <= hi)}


def _no_fixes() -> dict:
    nan = float("nan")
    return {"mean_nis": nan, "nis_dof": nan, "nis_fixes": 0, "nis_lo": nan, "nis_hi": nan, "nis_consistent": False}


def _flags(flags, n: int) -> np.ndarray:
    """``flags`` as a 1-D array of ``n`` flag names or codes into :data:`FLAGS` (else an error naming it)."""
    arr = _to_array("flags", flags)
    if arr.shape != (n,):
        raise ShapeError(f"flags: expected shape ({n},) (one flag per NIS), got shape {arr.shape}")
    if arr.dtype.kind not in "iuUO":
        raise DTypeError(f"flags: expected flag names or codes into FLAGS, got dtype {arr.dtype}")
    return arr


def pooled_nis(mean, dof, n) -> dict:
    """:func:`nis_stats` of several tracks together from their own (mean NIS, mean degrees of
    freedom, number of used fixes): the mean over all their used fixes."""
    mean, dof, n = (np.asarray(v, dtype=float) for v in (mean, dof, n))
    ok = (n > 0) & np.isfinite(mean)
    total = float(n[ok].sum())
    if not total:
        return _no_fixes()
    m, d = float((mean[ok] * n[ok]).sum() / total), float((dof[ok] * n[ok]).sum() / total)
    lo, hi = (float(v) for v in nis_band(total, d))
    return {"mean_nis": m, "nis_dof": d, "nis_fixes": int(total), "nis_lo": lo, "nis_hi": hi,
            "nis_consistent": bool(lo <= m <= hi)}


def nis_sentence(stats: dict) -> str:
    """The mean NIS in words, the same everywhere it is printed (4 significant digits).

    For example "mean NIS 1.849 over 2123 fixes (expected 2, 95 % band 1.916-2.086): below its band".

    Parameters
    ----------
    stats : dict
        :func:`nis_stats`, or a track table's row.

    Returns
    -------
    str
    """
    if not isinstance(stats, Mapping):
        raise ParameterError(f"stats: expected the dict of nis_stats, got {type(stats).__name__}")
    n, mean = stats.get("nis_fixes"), stats.get("mean_nis")
    try:   # a count and a number, or nothing (a track without updated fixes: nis_stats gives 0 and NaN)
        n = 0 if n is None else check_int("nis_fixes", n, minimum=0)
        nan = isinstance(mean, (float, np.floating)) and mean != mean
        mean = None if mean is None or nan else as_real("mean_nis", mean, infinite=True)
    except MptrackError as exc:
        raise type(exc)(f"stats: {exc}") from None
    if not n or mean is None:
        return "mean NIS: no fix was updated from a prediction"
    try:
        mean, lo, hi, d = (as_real(k, stats[k], infinite=k == "mean_nis")
                           for k in ("mean_nis", "nis_lo", "nis_hi", "nis_dof"))
    except KeyError as exc:
        raise ParameterError(f"stats: expected the dict of nis_stats, without {exc}") from None
    except MptrackError as exc:  # a value of the dict: named as the argument's entry
        raise type(exc)(f"stats: {exc}") from None
    where = "inside its band" if lo <= mean <= hi else "below its band" if mean < lo else "above its band"
    return (f"mean NIS {mean:.4g} over {n} fix{'es' if n != 1 else ''} (expected {d:.4g}, 95 % band "
            f"{lo:.4g}-{hi:.4g}): {where}")


def restart_mask(reset, new_track) -> np.ndarray:
    """The rows that begin a restart: a ``reset`` fix whose previous row is not a reset of the same
    track (``new_track``: True at the first row of each track; rows grouped by track, in time order)."""
    reset = np.asarray(reset, dtype=bool)
    new_track = np.asarray(new_track, dtype=bool)
    prev = np.r_[False, reset[:-1]] & ~new_track
    return reset & ~prev


def is_flag(flags: np.ndarray, *names: str) -> np.ndarray:
    """Where ``flags`` (names, or codes into :data:`FLAGS`) is one of ``names``."""
    if flags.dtype.kind in "iu":
        return np.isin(flags, [FLAGS.index(n) for n in names])
    return np.isin(flags, list(names))


def flag_counts(flags, starts) -> dict:
    """Per track (rows ``starts[b]:starts[b+1]``, ``starts`` ending with the row count; ``flags`` names
    or codes into :data:`FLAGS`): updates, manoeuvres, outliers, resets (fixes flagged reset) and
    restarts (runs of them)."""
    flags = np.asarray(flags)
    starts = np.asarray(starts, dtype=np.int64)
    first = np.zeros(len(flags), dtype=bool)
    first[starts[:-1][starts[:-1] < len(flags)]] = True
    by = np.repeat(np.arange(len(starts) - 1), np.diff(starts))

    def count(mask):
        return np.bincount(by, weights=mask, minlength=len(starts) - 1).astype(np.int64)

    reset = is_flag(flags, "reset")
    return {"updates": count(is_flag(flags, "update")), "manoeuvres": count(is_flag(flags, "manoeuvre")),
            "outliers": count(is_flag(flags, "outlier")), "resets": count(reset),
            "restarts": count(restart_mask(reset, first))}
