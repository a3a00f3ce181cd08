"""Headless Chromium driven over the DevTools protocol: open a page, wait until a JavaScript condition
holds (a live page never "finishes loading", so --dump-dom cannot tell), read values, take a screenshot."""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from _server import free_port

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
needs_chromium = pytest.mark.skipif(not Path(CHROMIUM).exists(),
                                    reason="headless browser tests need Debian's chromium (apt-get install -y chromium)")


class Browser:
    """One headless Chromium showing ``url`` (offline but for loopback: other hosts go to a closed port)."""

    def __init__(self, url: str, profile: Path, size: str = "1300,900"):
        from websockets.sync.client import connect

        self.port = free_port()
        self.proc = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
             "--no-first-run", "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
             "--proxy-server=127.0.0.1:9", f"--remote-debugging-port={self.port}", f"--window-size={size}",
             "--hide-scrollbars", url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        target = None
        while target is None and time.monotonic() < deadline:
            try:
                pages = httpx.get(f"http://127.0.0.1:{self.port}/json/list", timeout=2).json()
                target = next((p for p in pages if p.get("type") == "page"), None)
            except (httpx.HTTPError, ValueError):
                time.sleep(0.2)
        if target is None:
            self.close()
            raise RuntimeError("chromium did not open its DevTools port")
        # websockets wants its connection entered as a context manager (a plain call is deprecated)
        self._ws = contextlib.ExitStack()
        self.ws = self._ws.enter_context(connect(target["webSocketDebuggerUrl"], max_size=None))
        self._id = 0

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=60))
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise RuntimeError(msg["error"])
                return msg["result"]

    def eval(self, expression: str):
        res = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return res["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 60.0):
        """Poll until ``expression`` is truthy; returns its value (fails the test on timeout)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.eval(expression)
            if value:
                return value
            time.sleep(0.2)
        raise AssertionError(f"not true within {timeout} s: {expression}")

    def screenshot(self, path: Path) -> Path:
        path.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"]))
        return path

    def close(self) -> None:
        if getattr(self, "_ws", None) is not None:
            self._ws.close()
        self.proc.kill()
        self.proc.wait(30)
