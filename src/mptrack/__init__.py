"""mptrack: position tracking of mobile terminals from cellular and positioning measurements.

For a notebook, two functions need no files::

    import mptrack
    log = mptrack.simulate("gps", tracks=3, seed=1)    # a log with truth columns
    points = mptrack.track(log)                          # the tracks, noise estimated per track
    points.attrs["tracks"]                               # one row per track: sigma, q, NIS, ...

Both take the options of ``mptrack track`` / ``mptrack simulate``; everything
else is in the subpackages (imported on first use, so ``import mptrack`` is light).
"""

from __future__ import annotations

__version__ = "0.1.0"
__all__ = ["__version__", "track", "simulate"]


def track(data, **options):
    """Track a log (DataFrame or path): the point table as a DataFrame; ``attrs["tracks"]`` holds the
    per-track table (noise estimates with standard errors, counts, NIS) and ``attrs["summary"]`` the
    run summary.  Options as :func:`mptrack.tracking.track` (model, smooth, sigma_m, q, noise, cells,
    on_error, executor, ...)."""
    from .tracking import track as _track

    return _track(data, **options)


def simulate(scenario: str = "gps", tracks: int = 10, *, seed: int = 0, **options):
    """A simulated log with truth columns (DataFrame); for a cellular scenario the cell table is in
    ``attrs["cells"]``.  ``seed`` seeds the one random generator; other options as
    :func:`mptrack.tracking.simulate` (duration_s, along, interval, q, sigma_m, outlier_rate, ...)."""
    import numpy as np

    from ._core.validation import check_int
    from .tracking import simulate as _simulate

    log, cells = _simulate(scenario, tracks, np.random.default_rng(check_int("seed", seed, minimum=0)), **options)
    if cells is not None:
        log.attrs["cells"] = cells
    return log
