"""What a mean NIS far outside its band usually means, in the words of ``mptrack track``'s options: the
advice in the summaries of a tracking run (:func:`mptrack.tracking.track_file`) and of an evaluation
(:func:`mptrack.tracking.evaluate_tracks`).

Every option an advice names is one ``mptrack track`` takes for that kind of input (position fixes,
or cellular measurements with ``--cells``), with a value it accepts, so the command it suggests runs
(tests/tracking/test_advice.py runs each one)."""

from __future__ import annotations

import numpy as np

from .._core.validation import as_array
from ._consistency import nis_sentence
from ._fixes import TrackOptions

__all__ = ["MIN_ADVISED_FIXES", "far_from_band", "nis_advice", "evaluation_nis"]

#: A track's mean NIS is judged (advice in the summary) from this many used fixes on.
MIN_ADVISED_FIXES = 10
#: Far outside its band: a mean NIS below FAR_LOW or above FAR_HIGH times its degrees of freedom.
FAR_LOW, FAR_HIGH = 0.5, 2.0
#: The path-loss model the cellular advice suggests trying instead of the one in use.
_OTHER_PATH_LOSS = {"cost231-wi-nlos": "cost231-hata"}


def far_from_band(mean, dof, used) -> tuple[np.ndarray, np.ndarray]:
    """Which tracks' mean NIS is far from its band: below half or above twice its degrees of freedom over
    at least :data:`MIN_ADVISED_FIXES` used fixes (a handful of fixes is far out by chance).

    From 10 fixes on, either lies outside the track's 95 % band too.

    Parameters
    ----------
    mean : array_like
        Mean NIS per track.
    dof : array_like
        Its degrees of freedom per track.
    used : array_like of int
        Fixes the mean is over, per track.

    Returns
    -------
    below, above : ndarray of bool
    """
    mean = as_array("mean", mean, ndim=1, finite=False, allow_nan=True)
    dof, used = (as_array(k, v, shape=mean.shape, finite=False, allow_nan=True) for k, v in (("dof", dof),
                                                                                           ("used", used)))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = mean / dof
    judged = (used >= MIN_ADVISED_FIXES) & np.isfinite(ratio)
    return judged & (ratio < FAR_LOW), judged & (ratio > FAR_HIGH)


def nis_advice(low: int, high: int, options: TrackOptions | None, *, cellular: bool = False) -> list[str]:
    """What a mean NIS far below (``low`` tracks) or above (``high``) its band usually means, and
    the option to change (``cellular``: the tracks come from ranges to cells, not from fixes);
    ``options`` None: the run's options are not known (an evaluation of a track table)."""
    if cellular:
        return _cellular_nis_advice(low, high, options)
    options = options or TrackOptions()
    given = [f for f, v in (("--sigma", options.sigma_m), ("--q", options.q)) if v is not None]
    notes = []
    if low:
        cause = (f"the filter assumes more noise than the fixes show ({' and '.join(given)} too large); leave "
                 f"{' and '.join(given)} out to estimate {'it' if len(given) == 1 else 'them'} from the data"
                 if given else "the fixes vary less from one to the next than the model allows (a receiver that "
                 "smooths its output, often a static one); their error against the truth is in the covariance")
        notes.append(f"{low} track(s) have a mean NIS far below its band: {cause}")
    if high:
        cause = (f"the fixes are noisier or the motion more agile than {' and '.join(given)} say; leave "
                 f"{' and '.join(given)} out to estimate {'it' if len(given) == 1 else 'them'} from the data"
                 if given else "the motion has sharper manoeuvres than the model allows"
                 + (" (try --model ca)" if options.model == "cv" else "") + " or outliers passed the gate")
        notes.append(f"{high} track(s) have a mean NIS far above its band: {cause}")
    return notes


def _cellular_nis_advice(low: int, high: int, options: TrackOptions | None) -> list[str]:
    """The cellular advice; with ``options`` None (not known) it names the options without values."""
    notes = []
    sigma = None if options is None else 1e3 * options.r_km2 ** 0.5
    r = "the range noise the run assumed" if sigma is None else f"the range noise ({sigma:.0f} m, 1-sigma)"
    if low:
        notes.append(f"{low} track(s) have a mean NIS far below its band: the ranges are more accurate than "
                     f"{r}; a smaller one follows them more closely ("
                     + ("a smaller --range-sigma" if sigma is None else f"try --range-sigma {sigma / 2:.0f}") + ")")
    if high:
        model = "the path-loss model" if options is None else f"the path-loss model ({options.path_loss})"
        other = "another --path-loss" if options is None else \
            f"try --path-loss {_OTHER_PATH_LOSS.get(options.path_loss, 'cost231-wi-nlos')}"
        notes.append(f"{high} track(s) have a mean NIS far above its band: the ranges are noisier than {r} ("
                     + ("a larger --range-sigma" if sigma is None else f"try --range-sigma {2 * sigma:.0f}")
                     + f"), or, where they come from the signal strength, {model} does not fit the area ({other})")
    return notes


def evaluation_nis(tracks: dict, overall: dict, *, cellular: bool = False) -> dict:
    """The "nis" part of an evaluation's summary, shaped as a tracking run's: the mean NIS of all tracks
    (``overall``, :func:`._consistency.nis_stats`) and its sentence (:func:`._consistency.nis_sentence`;
    "far": "below" or "above" when it is far from its band, else ""), how many tracks lie outside their own band, the
    tracks far from it (:func:`far_from_band`) and what that usually means (the run's options are not
    known; ``cellular``: tracks of a cellular run).  ``tracks``: {id: per-track statistics}."""
    rows = [r for r in tracks.values() if r.get("nis_fixes")]
    low, high = far_from_band([r["mean_nis"] for r in rows], [r["nis_dof"] for r in rows],
                              [r["nis_fixes"] for r in rows])
    low, high = int(low.sum()), int(high.sum())
    keys = ("mean_nis", "nis_dof", "nis_fixes", "nis_lo", "nis_hi", "nis_consistent")
    below, above = far_from_band([overall.get("mean_nis", np.nan)], [overall.get("nis_dof", np.nan)],
                                 [overall.get("nis_fixes", 0)])
    return {**{k: overall.get(k) for k in keys}, "sentence": nis_sentence(overall),
            "far": "below" if below[0] else "above" if above[0] else "",
            "tracks_outside_band": sum(not r["nis_consistent"] for r in rows),
            "tracks_judged": len(rows), "far_low": low, "far_high": high,
            "advice": nis_advice(low, high, None, cellular=cellular)}
