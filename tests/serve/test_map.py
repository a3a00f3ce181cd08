"""The live map of mptrack serve in headless Chromium: one marker per device, devices that move and
appear as fixes arrive (Server-Sent Events), a device's last hour on click, no script errors, offline."""

from __future__ import annotations

import time

import pytest
from _browser import Browser, needs_chromium
from _server import Server


@pytest.fixture
def served(tmp_path):
    srv = Server(tmp_path).start()
    yield srv
    assert srv.stop() == 0, srv.output()


def _send(srv, device: str, k: int, t0: int, lat0: float) -> None:
    r = srv.get(f"/?id={device}&lat={lat0 + 2e-4 * k!r}&lon=13.4&timestamp={t0 + 5 * k}&accuracy=6")
    assert r.status_code == 200, r.text


#: The names written on the map beside the markers, in order.
_NAMES = "Array.from(document.querySelectorAll('.device-name')).map(function (e) { return e.textContent; }).sort().join()"


@needs_chromium
def test_live_map_shows_every_device_and_follows_new_fixes(served, tmp_path, tmp_path_factory):
    t0 = int(time.time()) - 600
    for i, dev in enumerate(("bus-1", "bus-2", "bus-3")):
        for k in range(5):
            _send(served, dev, k, t0, 52.50 + 0.01 * i)
    browser = Browser(served.url + "/", tmp_path / "profile")
    try:
        browser.wait_for("document.body.dataset.ready === '1'")
        assert browser.eval("document.body.dataset.devices") == "3"
        assert browser.eval("document.documentElement.dataset.jsErrors || ''") == ""
        assert browser.eval("document.querySelectorAll('#device-list li').length") == 3
        # each device's id on its line, its last fix's time, flag and uncertainty below, within the list's width
        assert browser.eval("document.querySelector('#device-list li b').textContent") == "bus-1"
        assert browser.eval(_NAMES) == "bus-1,bus-2,bus-3"   # a small fleet is named on the map
        assert "±" in browser.eval("document.querySelector('#device-list li small').textContent")
        assert browser.eval("(function (l) { return l.scrollWidth <= l.clientWidth; })"
                            "(document.getElementById('device-list'))") is True
        browser.wait_for("document.getElementById('status').textContent === 'live'")
        # a new device and a moving one: the page follows the stream
        for k in range(3):
            _send(served, "bus-4", k, t0 + 100, 52.53)
        _send(served, "bus-1", 5, t0, 52.50)
        browser.wait_for("document.body.dataset.devices === '4'")
        assert int(browser.wait_for("Number(document.body.dataset.events) >= 4 && document.body.dataset.events"))
        # a click on a device draws its track (its stored fixes of the last hour)
        browser.eval("document.querySelector('#device-list li').click()")
        assert browser.wait_for("document.body.dataset.trackPoints") == "6"
        assert browser.eval(_NAMES) == "bus-1,bus-2,bus-3,bus-4"
        shot = browser.screenshot(tmp_path_factory.getbasetemp() / "live-map.png")
        print(f"screenshot: {shot}")
        # past 30 devices the names would cover the map: they show on hover only, every marker's
        for i in range(5, 32):
            _send(served, f"bus-{i}", 0, t0 + 200, 52.50 + 0.001 * i)
        browser.wait_for("document.body.dataset.devices === '31'")
        assert browser.wait_for(f"({_NAMES}) === ''")   # (a name fades out in 0.2 s)
        assert browser.eval("document.documentElement.dataset.jsErrors || ''") == ""
    finally:
        browser.close()


#: The names shown on the map (not hidden for covering another), sorted.
_SHOWN = ("Array.from(document.querySelectorAll('.device-name')).filter(function (e) { "
          "return e.style.visibility !== 'hidden'; }).map(function (e) { return e.textContent; }).sort().join()")


@needs_chromium
def test_names_that_would_cover_each_other_are_not_both_shown(served, tmp_path):
    """Two vans parked 11 m apart: one name is shown, marked +1, not two written over each other; a device a
    kilometre away keeps its own; zoomed in far enough, both vans are named."""
    t0 = int(time.time()) - 600
    for dev, lat in (("van-a", 52.5), ("van-b", 52.5001), ("far-1", 52.51)):
        for k in range(3):
            assert served.get(f"/?id={dev}&lat={lat!r}&lon=13.4&timestamp={t0 + 5 * k}&accuracy=6").status_code == 200
    browser = Browser(served.url + "/", tmp_path / "profile")
    try:
        browser.wait_for("document.body.dataset.ready === '1' && document.body.dataset.namesShown !== undefined")
        assert browser.eval(_NAMES) == "far-1,van-a,van-b"
        shown = browser.wait_for(f"({_SHOWN}).split(',').length === 2 && ({_SHOWN})")
        assert "far-1" in shown and ("van-a" in shown) != ("van-b" in shown), shown
        assert browser.eval("document.body.dataset.namesShown") == "2"
        # the name shown says how many it hides ("van-a +1")
        assert browser.eval("Array.from(document.querySelectorAll('.device-name[data-more]'))"
                            ".map(function (e) { return e.dataset.more; }).join()") == "+1"
        for _ in range(6):   # the zoom control, as a user zooms in
            browser.eval("document.querySelector('.leaflet-control-zoom-in').click()")
            time.sleep(0.4)
        assert browser.wait_for(f"({_SHOWN}).indexOf('van-a') >= 0 && ({_SHOWN}).indexOf('van-b') >= 0")
        assert browser.eval("document.documentElement.dataset.jsErrors || ''") == ""
    finally:
        browser.close()
