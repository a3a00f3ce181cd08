"""The live map of ``mptrack serve``: one page (Leaflet and its script inlined, so it works offline on
a plain background), fed by the server's query API and its event stream."""

from __future__ import annotations

from ..errors import ParameterError
from ._page import json_script, page

__all__ = ["live_map_page"]


def live_map_page(*, key: str | None = None, title: str = "mptrack live map") -> str:
    """The HTML of the live map of ``mptrack serve``.

    Every device's estimate (with its 1-sigma ellipse) beside its last raw fix, moving as fixes arrive
    (Server-Sent Events from ``/api/stream``); a click on a device draws its last hour's track.

    Parameters
    ----------
    key : str, optional
        The API key the page passes on to the API (``mptrack serve --auth``).
    title : str, optional

    Returns
    -------
    str
    """
    if key is not None and not isinstance(key, str):
        raise ParameterError(f"key: expected the API key as text or None, got {type(key).__name__}")
    if not isinstance(title, str):
        raise ParameterError(f"title: expected text, got {type(title).__name__}")
    body = ("<p class='note'><span id='status'>connecting…</span> · <span id='device-count'>0</span> devices · "
            "<span class='swatch estimate'></span>estimate with its 1-σ ellipse "
            "<span class='swatch raw'></span>last fix as sent · click a device for its last hour</p>"
            "<div class='layout'><aside><input id='device-filter' type='search' placeholder='filter devices'>"
            "<ul id='device-list'></ul></aside><div id='map'></div></div>"
            + json_script("mptrack-live", {"key": key}))
    return page(title, body, scripts=("leaflet.js", "live.js"), styles=("leaflet.css",))
