"""Paths of the real GPS traces shipped in tests/data (sources and licences: docs/data.md).

``REAL_TRACES[kind]`` is the GPX file of one real recording of each kind.
``REAL_TRACK_IDS[kind]`` names the <trk> elements that hold the timed recording
(the ``track_id`` values that ``mptrack.io`` gives them).
:func:`shared_data` is a file of the real data kept beside the repository, in ``../shared/data``
(receiver logs, LTE walks; sources and licences in each folder's README), never copied here.
"""

from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
#: The shared real data beside the repository (``../shared/data`` from its root).
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def shared_data(*parts: str) -> Path:
    """The path of ``../shared/data/<parts>``; skips the calling test with a message when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data {path} is absent (it lives beside the repository in ../shared/data)")
    return path

REAL_TRACES = {
    # One <trk>, 104 points, Garmin eTrex 20x, irregular 1-49 s intervals.
    "car": DATA / "around-visnjan-with-car.gpx",
    # The recording is the two <trk> "ACTIVE LOG" (176 points) and "ACTIVE LOG #2"
    # (337 points), 4 min 48 s apart. The file also holds "03-OCT-10" (empty) and
    # "03-OCT-10 #2" (358 points, no <time>, another walk 13 km away), which the
    # reader leaves out with a note (a track without any time is not a recording).
    "hike": DATA / "korita-zbevnica-hike.gpx",
    # One <trk> "Berkelland Fietsen", 5159 points at 1 s (Garmin Forerunner 935).
    "bike": DATA / "berkelland-bike-ride.gpx",
}

REAL_TRACK_IDS = {
    "car": ("2020-12-18 07:24:29",),
    "hike": ("ACTIVE LOG", "ACTIVE LOG #2"),
    "bike": ("Berkelland Fietsen",),
}
