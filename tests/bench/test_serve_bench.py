"""The geolocate case of ``mptrack bench --suite serve``: its requests are what the issue asks for (3-7 cells
each) and every one is answered with a position from its cell table (no 404 measured as throughput)."""

from __future__ import annotations

import json
import re

from mptrack.bench.serve import _geolocate_setup
from mptrack.serve import geolocate_requests


def test_geolocate_requests_have_3_to_7_known_cells(tmp_path):
    cells, script = _geolocate_setup(tmp_path, requests=60)
    bodies = re.findall(r"\[\[(.*?)\]\]", script.read_text())
    assert len(bodies) == 60
    sizes = [len(json.loads(b)["cellTowers"]) for b in bodies]
    assert min(sizes) >= 3 and max(sizes) <= 7 and len(set(sizes)) >= 3, sizes
    path = tmp_path / "requests.ndjson"
    path.write_text("\n".join(bodies) + "\n")
    answers = list(geolocate_requests(path, cells=cells))
    assert [status for _, status, _ in answers] == [200] * 60
    assert all("fallback" not in a for _, _, a in answers)
