"""What a mean NIS far outside its band usually means, in the words of ``mptrack track``'s options: the
advice in the summaries of a tracking run (:func:`mptrack.tracking.track_file`) and of an evaluation
(:func:`mptrack.tracking.evaluate_tracks`)."""

from __future__ import annotations

from ._fixes import TrackOptions

__all__ = ["MIN_ADVISED_FIXES", "nis_advice", "evaluation_nis"]

#: A track's mean NIS is judged (advice in the summary) from this many used fixes on.
MIN_ADVISED_FIXES = 10


def nis_advice(low: int, high: int, options: TrackOptions, *, cellular: bool = False) -> list[str]:
    """What a mean NIS far below (``low`` tracks) or above (``high``) its band usually means, and
    the option to change (``cellular``: the tracks come from ranges to cells, not from fixes)."""
    if cellular:
        return _cellular_nis_advice(low, high, options)
    given = [f for f, v in (("--sigma", options.sigma_m), ("--q", options.q)) if v is not None]
    notes = []
    if low:
        cause = (f"the filter assumes more noise than the fixes show ({' and '.join(given)} too large); leave "
                 f"{' and '.join(given)} out to estimate {'it' if len(given) == 1 else 'them'} from the data"
                 if given else "the fixes' errors are correlated in time (a receiver that smooths its output), "
                 "which the filter cannot tell from motion")
        notes.append(f"{low} track(s) have a mean NIS far below its band: {cause}")
    if high:
        cause = (f"the fixes are noisier or the motion more agile than {' and '.join(given)} say; leave "
                 f"{' and '.join(given)} out to estimate {'it' if len(given) == 1 else 'them'} from the data"
                 if given else "the motion has sharper manoeuvres than the model allows (try --model ca) or "
                 "outliers passed the gate")
        notes.append(f"{high} track(s) have a mean NIS far above its band: {cause}")
    return notes


def _cellular_nis_advice(low: int, high: int, options: TrackOptions) -> list[str]:
    notes = []
    r = f"the range noise (--range-sigma {1e3 * options.r_km2 ** 0.5:.0f} m)"
    if low:
        notes.append(f"{low} track(s) have a mean NIS far below its band: the ranges are more accurate than "
                     f"{r} says; a smaller --range-sigma follows them more closely")
    if high:
        notes.append(f"{high} track(s) have a mean NIS far above its band: the ranges are noisier than {r} "
                     "says, or the path-loss model (--path-loss) does not fit the area")
    return notes


def evaluation_nis(tracks: dict) -> dict:
    """{"far_low", "far_high", "advice"} of an evaluation's per-track statistics ``tracks`` ({id: {"points",
    "outliers", "mean_nis", "mean_nis_dof", ...}}): tracks judged from enough fixes whose mean NIS is below
    half or above twice its degrees of freedom, and what that usually means with the default options."""
    low = high = 0
    for row in tracks.values():
        mean, dof = row.get("mean_nis"), row.get("mean_nis_dof")
        if row.get("points", 0) - row.get("outliers", 0) < MIN_ADVISED_FIXES or not dof or mean != mean:
            continue
        low += mean / dof < 0.5
        high += mean / dof > 2.0
    return {"far_low": int(low), "far_high": int(high), "advice": nis_advice(low, high, TrackOptions())}
