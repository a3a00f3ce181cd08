"""Who may write and read: device tokens (ingest), API keys (the query API and the map), and the
per-device rate limit.

Tokens and keys are random (``secrets.token_urlsafe``) and only their SHA-256 is stored.  A request
carries one as the ``key`` query parameter (the server URL given to an app), as
``Authorization: Bearer TOKEN``, or as the password of HTTP Basic (OwnTracks).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import secrets
import threading
import time
from array import array

from ..errors import RequestError
from ._fix import device_id
from ._store import Store

__all__ = ["new_secret", "digest", "Registry", "RateLimit", "credentials"]


def new_secret() -> str:
    """A new random token or key (32 bytes, URL-safe text)."""
    return secrets.token_urlsafe(32)


def digest(secret: str) -> str:
    return hashlib.sha256(secret.encode("utf-8")).hexdigest()


def credentials(headers: dict, query_key: str | None) -> tuple[str | None, str | None]:
    """(secret, basic user) of a request: the ``key`` parameter, a Bearer token or HTTP Basic."""
    auth = headers.get(b"authorization", b"").decode("latin-1").strip()
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value:
        return value.strip(), None
    if scheme.lower() == "basic" and value:
        try:
            user, _, password = base64.b64decode(value.strip(), validate=True).decode("utf-8").partition(":")
        except (binascii.Error, UnicodeDecodeError):
            raise RequestError("the Authorization header is not valid HTTP Basic", status=401,
                               code="unauthorized") from None
        return password, user
    return query_key, None


class Registry:
    """The devices' token digests and the API keys' digests, read from the store (again when an
    unknown token arrives, at most once a second, so ``mptrack devices add`` needs no restart)."""

    def __init__(self, store: Store):
        self.store = store
        self._lock = threading.Lock()
        self._loaded = 0.0
        self._devices: dict[str, str] = {}
        self._keys: set[str] = set()
        self._load()

    def _load(self) -> None:
        with self._lock:
            self._devices = {token: dev for dev, token in self.store.devices()}
            self._keys = set(self.store.api_keys())
            self._loaded = time.monotonic()

    def _fresh(self) -> bool:
        if time.monotonic() - self._loaded >= 1.0:
            self._load()
            return True
        return False

    def device(self, secret: str | None) -> str:
        """The device a token belongs to; 401 for none or an unknown one."""
        if not secret:
            raise RequestError("this server needs the device's token (the key parameter of the server URL, "
                               "a Bearer token, or the HTTP Basic password)", status=401, code="unauthorized")
        h = digest(secret)
        dev = self._devices.get(h)
        if dev is None and self._fresh():
            dev = self._devices.get(h)
        if dev is None:
            raise RequestError("unknown device token", status=401, code="unauthorized")
        return dev

    def check_key(self, secret: str | None) -> None:
        """401 unless ``secret`` is an API key."""
        if not secret:
            raise RequestError("this server needs an API key (?key=, or Authorization: Bearer)", status=401,
                               code="unauthorized")
        h = digest(secret)
        if h not in self._keys and not (self._fresh() and h in self._keys):
            raise RequestError("unknown API key", status=401, code="unauthorized")


class RateLimit:
    """A token bucket per device: ``rate`` fixes a second on average, bursts of ``burst``.  A request of
    more fixes than ``burst`` (an app's queue sent after hours offline, in batches as large as its user
    set) passes when the bucket is full and empties it: refused, it would be refused at every retry.

    The buckets are two arrays indexed by the device's key (16 bytes a device; a fleet of 10^6 in a
    dict of per-device lists took ~200 MB); a device without a key yet -- its first fix is being
    committed -- is not limited."""

    def __init__(self, rate: float, burst: float):
        self.rate, self.burst = float(rate), float(burst)
        self._level = array("d")     # tokens left at _last (s, monotonic); a new bucket is full
        self._last = array("d")

    def take(self, device: str, key: int | None, n: int = 1, now: float | None = None) -> None:
        if self.rate <= 0 or key is None:
            return
        now = time.monotonic() if now is None else now
        if key >= len(self._level):
            grow = max(key + 1, 2 * len(self._level)) - len(self._level)
            self._level.extend([self.burst] * grow)
            self._last.extend([0.0] * grow)
        n = min(n, self.burst)
        level = min(self.burst, self._level[key] + (now - self._last[key]) * self.rate)
        if level < n:
            self._level[key], self._last[key] = level, now
            raise RequestError(f"device {device} sends faster than {self.rate:g} fixes/s (bursts of "
                               f"{self.burst:g}); slow down", status=429, code="rate_limited")
        self._level[key], self._last[key] = level - n, now


def check_device(claimed: str, owner: str) -> str:
    """The device id of a request whose token belongs to ``owner``: the id it claims must be that."""
    if claimed != owner:
        raise RequestError(f"the token belongs to device {owner}, not {device_id(claimed, 'id')}", status=403,
                           code="forbidden")
    return claimed
