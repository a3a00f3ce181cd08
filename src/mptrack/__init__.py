"""mptrack: position tracking of mobile terminals from cellular and positioning measurements.

For a notebook, two functions need no files::

    import mptrack
    log = mptrack.simulate("gps", tracks=3, seed=1)    # a log with truth columns
    points = mptrack.track(log)                          # the tracks, noise estimated per track
    points.attrs["tracks"]                               # one row per track: sigma, q, NIS, ...

``mptrack.track`` is :func:`mptrack.tracking.track` (keyword options, documented in
``help(mptrack.track)``; ``report=PATH`` writes the HTML report); ``mptrack.simulate`` takes the
options of ``mptrack simulate``.  Everything else is in the subpackages (imported on first use, so
``import mptrack`` is light).
"""

from __future__ import annotations

__version__ = "0.1.0"
__all__ = ["__version__", "track", "simulate"]


def __getattr__(name: str):
    """``mptrack.track`` is :func:`mptrack.tracking.track` itself (its signature and docstring in
    ``help``), imported on first use so that ``import mptrack`` stays light."""
    if name == "track":
        from .tracking import track

        return track
    raise AttributeError(f"module 'mptrack' has no attribute {name!r}")


def simulate(scenario: str = "gps", tracks: int = 10, *, seed: int = 0, **options):
    """A simulated log with truth columns, in memory.

    Parameters
    ----------
    scenario : str, optional
        "gps" (fixes at irregular times) or "urban-3bts" (RSS from three base stations).
    tracks : int, optional
        Number of tracks.
    seed : int, optional
        Seeds the one random generator.
    **options
        As for :func:`mptrack.tracking.simulate` (duration_s, along, interval, q, sigma_m, outlier_rate, ...).

    Returns
    -------
    pandas.DataFrame
        The log; for a cellular scenario the cell table is in ``attrs["cells"]``.

    Examples
    --------
    >>> import mptrack
    >>> log = mptrack.simulate("gps", tracks=2, seed=1, duration_s=60)
    >>> {"true_lat", "true_lon"} <= set(log.columns)
    True
    """
    import numpy as np

    from ._core.validation import check_int
    from .tracking import simulate as _simulate

    log, cells = _simulate(scenario, tracks, np.random.default_rng(check_int("seed", seed, minimum=0)), **options)
    if cells is not None:
        log.attrs["cells"] = cells
    return log
