"""The shell every report page shares: one self-contained HTML file (styles, scripts and data inlined,
nothing fetched but the optional map tiles), written atomically."""

from __future__ import annotations

import html
import json
import math
from importlib import resources
from pathlib import Path

from .._core.files import atomic_path

__all__ = ["asset", "page", "write_page", "json_script", "esc", "clean"]

#: Records JavaScript errors on the page itself (``data-js-errors`` on <html>), before anything else runs.
_ERRORS = ("<script>window.mptrackErrors=[];window.addEventListener('error',function(e){"
           "window.mptrackErrors.push(String(e.message));document.documentElement.setAttribute("
           "'data-js-errors',window.mptrackErrors.join(' | '));});</script>")


def asset(name: str) -> str:
    """The text of a file shipped in ``mptrack/report/assets`` (Leaflet, the page's script and style)."""
    text = resources.files(__package__).joinpath("assets", name).read_text(encoding="utf-8")
    return "\n".join(line for line in text.splitlines() if not line.startswith("//# sourceMappingURL="))


def esc(value) -> str:
    return html.escape(str(value), quote=True)


def clean(value):
    """JSON-safe: non-finite floats become None, numpy scalars Python numbers."""
    if isinstance(value, dict):
        return {str(k): clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_script(element_id: str, data) -> str:
    """``data`` as an inert JSON script element (``<`` escaped so no text can close the element)."""
    text = json.dumps(clean(data), separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    return f"<script type='application/json' id='{element_id}'>{text}</script>"


def page(title: str, body: str, *, scripts: tuple[str, ...] = (), styles: tuple[str, ...] = ()) -> str:
    """A complete HTML document: ``styles``/``scripts`` are asset names, inlined in order."""
    css = "\n".join(asset(s) for s in styles + ("report.css",))
    js = "".join(f"<script>{asset(s)}</script>" for s in scripts)
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'><title>{esc(title)}</title>"
            f"{_ERRORS}<style>{css}</style></head><body><h1>{esc(title)}</h1>{body}{js}</body></html>\n")


def write_page(path, text: str) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
