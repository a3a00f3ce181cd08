"""Rows per second of the compiled WGS-84 <-> ENU layer against pymap3d on the same arrays.

    python benchmarks/bench_geodesy.py [--rows 1000000] [--track-length 500] [--repeat 9]

10^6 points within 100 km of per-row origins, in two layouts: tracks of
``--track-length`` rows sharing an origin (a columnar log), and the worst case
of a new origin on every row.  Two figures per function, in million rows/s:

* ``cpu``: one thread, rows per CPU-second of the process (best of ``--repeat``);
  insensitive to other jobs on a shared machine.
* ``wall``: numba's default thread count, rows per wall-clock second (best of
  ``--repeat``); on a busy machine this is what the other jobs leave.

pymap3d (a test dependency) is single-threaded NumPy; it is timed on
``geodetic2enu`` and, for the inverse, on one ``enu2geodetic`` call with up = 0
(a lower bound: it does not land on the ellipsoid) and on the previous
LocalFrame method (3 fixed-point passes, 7 calls).
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
import pymap3d

from mptrack.io import enu_to_geodetic, geodetic_to_enu


def best_rate(fn, rows: int, repeat: int, clock) -> float:
    """Million rows per second of ``clock`` time, best of ``repeat`` runs."""
    best = np.inf
    for _ in range(repeat):
        start = clock()
        fn()
        best = min(best, clock() - start)
    return rows / best / 1e6


def pymap3d_surface_point(east, north, lat0, lon0):
    """The previous LocalFrame.to_geodetic: fixed point on up, 3 passes (7 pymap3d calls)."""
    up = np.zeros_like(east)
    for _ in range(3):
        lat, lon, _ = pymap3d.enu2geodetic(east, north, up, lat0, lon0, 0.0)
        _, _, up = pymap3d.geodetic2enu(lat, lon, 0.0, lat0, lon0, 0.0)
    return pymap3d.enu2geodetic(east, north, up, lat0, lon0, 0.0)[:2]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=10**6)
    parser.add_argument("--track-length", type=int, default=500)
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(2024)
    n, threads = args.rows, numba.get_num_threads()
    east, north = rng.uniform(-1e5, 1e5, n), rng.uniform(-1e5, 1e5, n)
    print(f"{n} rows; million rows/s: cpu = 1 thread per CPU-second, wall = {threads} threads")
    for layout, length in (("tracks", args.track_length), ("row origins", 1)):
        tracks = -(-n // length)
        lat0 = np.repeat(rng.uniform(-89.0, 89.0, tracks), length)[:n]
        lon0 = np.repeat(rng.uniform(-180.0, 180.0, tracks), length)[:n]
        lat, lon = enu_to_geodetic(east, north, lat0, lon0)   # also compiles / loads the cache
        geodetic_to_enu(lat, lon, lat0, lon0)
        ours = {"geodetic_to_enu": lambda: geodetic_to_enu(lat, lon, lat0, lon0),
                "enu_to_geodetic": lambda: enu_to_geodetic(east, north, lat0, lon0)}
        peers = {"pymap3d.geodetic2enu": lambda: pymap3d.geodetic2enu(lat, lon, 0.0, lat0, lon0, 0.0),
                 "pymap3d.enu2geodetic": lambda: pymap3d.enu2geodetic(east, north, 0.0, lat0, lon0, 0.0),
                 "pymap3d 3-pass surface point": lambda: pymap3d_surface_point(east, north, lat0, lon0)}
        print(f"{layout} (length {length}):")
        numba.set_num_threads(1)
        cpu = {name: best_rate(fn, n, args.repeat, time.process_time) for name, fn in ours.items()}
        numba.set_num_threads(threads)
        for name, fn in ours.items():
            wall = best_rate(fn, n, args.repeat, time.perf_counter)
            print(f"  {name:30s} cpu {cpu[name]:6.2f}  wall {wall:6.2f}")
        for name, fn in peers.items():
            print(f"  {name:30s} cpu {best_rate(fn, n, 2, time.process_time):6.2f}")


if __name__ == "__main__":
    main()
