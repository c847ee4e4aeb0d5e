"""Who may ask what: API keys, Host/Origin checks and security headers, in one ASGI middleware.

- With API keys set, every request but /healthz, /readyz and /metrics needs
  `Authorization: Bearer KEY` (keys compared in constant time, never logged); `public_read`
  lets GET/HEAD of the page, listings and thumbnails through without one.
- Host must name this service (loopback names, the bound address, `allowed_hosts`): a page
  that rebinds its own DNS name to 127.0.0.1 cannot read or write through it. A state-changing
  request carrying an Origin must come from an allowed origin too, so another site's page
  cannot POST or DELETE through the user's browser.
- Every answer carries nosniff and frame-ancestors/X-Frame-Options; HTML gets a CSP that
  allows only this origin's scripts, styles and images.

The caller's identity (`scope["state"]["client"]`: the key's fingerprint, else the peer
address) is what scheduling shares and quotas count by.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import logging

from service.settings import Settings

log = logging.getLogger(__name__)

OPEN_PATHS = ("/healthz", "/readyz", "/metrics")
READ_METHODS = ("GET", "HEAD", "OPTIONS")
LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1", "[::1]"}
WILDCARDS = {"0.0.0.0", "::", ""}
PAGE_CSP = ("default-src 'self'; img-src 'self' data: blob:; script-src 'self' 'unsafe-inline'; "
            "style-src 'self' 'unsafe-inline'; worker-src 'self' blob:; frame-ancestors 'none'; "
            "base-uri 'none'; form-action 'self'")
DATA_CSP = "default-src 'none'; frame-ancestors 'none'; sandbox"
_COMMON = [(b"x-content-type-options", b"nosniff"), (b"x-frame-options", b"DENY"),
           (b"referrer-policy", b"no-referrer")]
_PAGE_HEADERS = _COMMON + [(b"content-security-policy", PAGE_CSP.encode())]
_DATA_HEADERS = _COMMON + [(b"content-security-policy", DATA_CSP.encode())]


def fingerprint(key: str) -> str:
    """Names a key in logs, quotas and metrics without revealing it."""
    return hashlib.sha256(key.encode()).hexdigest()[:12]


class AccessMiddleware:
    def __init__(self, app, settings: Settings):
        self.app = app
        self.keys = [k.encode() for k in settings.api_keys]
        self._fingerprints = {k: "key:" + fingerprint(k.decode()) for k in self.keys}
        self._hosts_seen: dict[bytes, bool] = {}  # Host header -> allowed (bounded)
        self.public_read = settings.public_read
        hosts = {h.strip().lower() for h in settings.allowed_hosts.split(",") if h.strip()}
        self.any_host = "*" in hosts or (settings.host in WILDCARDS and not hosts)
        if settings.host not in WILDCARDS:
            hosts.add(settings.host.lower())
        self.hosts = hosts | LOOPBACK_NAMES

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope["headers"])
        path, method = scope["path"], scope["method"]
        state = scope.setdefault("state", {})
        state["client"] = "addr:" + (scope.get("client") or ("local", 0))[0]
        raw_host = headers.get(b"host", b"")
        host = raw_host.decode("latin-1").lower()
        if path not in OPEN_PATHS and not self._host_ok_cached(raw_host, host):  # probes: any address
            return await _refuse(send, 421,
                                 f"Host {host[:64]!r} is not a name of this service; add it to "
                                 "allowed_hosts (ASSET_PREVIEW_ALLOWED_HOSTS)")
        origin = headers.get(b"origin")
        if origin is not None and method not in READ_METHODS and not self._origin_ok(origin, host):
            return await _refuse(send, 403, "cross-origin request refused: Origin is not this service")
        if self.keys and path not in OPEN_PATHS and not (self.public_read and method in READ_METHODS):
            who = self._known(_bearer(headers.get(b"authorization", b"")))
            if who is None:
                return await _refuse(send, 401, "missing or wrong API key: send `Authorization: Bearer KEY`",
                                     [(b"www-authenticate", b"Bearer")])
            state["client"] = who
        elif self.keys:
            who = self._known(_bearer(headers.get(b"authorization", b"")))
            if who is not None:
                state["client"] = who

        async def secured(message):
            if message["type"] == "http.response.start":
                hdrs = message.get("headers", [])
                html = any(k.lower() == b"content-type" and v.startswith(b"text/html") for k, v in hdrs)
                message = dict(message, headers=[*hdrs, *(_PAGE_HEADERS if html else _DATA_HEADERS)])
            await send(message)

        await self.app(scope, receive, secured)

    def _known(self, key: bytes | None) -> str | None:
        """The caller's identity for a valid key, else None. Every key is compared
        (compare_digest: time independent of where they differ)."""
        if key is None:
            return None
        found = None
        for k in self.keys:
            if hmac.compare_digest(key, k):
                found = self._fingerprints[k]
        return found

    def _host_ok_cached(self, raw: bytes, host: str) -> bool:
        ok = self._hosts_seen.get(raw)
        if ok is None:
            ok = self._host_ok(host)
            if len(self._hosts_seen) < 256:  # a client sending random names cannot grow it
                self._hosts_seen[raw] = ok
        return ok

    def _host_ok(self, host: str) -> bool:
        if self.any_host:
            return True
        return _hostname(host) in self.hosts

    def _origin_ok(self, origin: bytes, host: str) -> bool:
        text = origin.decode("latin-1").lower()
        if text == "null":  # sandboxed frames, file: pages
            return False
        authority = text.split("://", 1)[-1].split("/", 1)[0]
        return authority == host or _hostname(authority) in self.hosts


def _hostname(authority: str) -> str:
    """'example.com:8000' -> 'example.com'; '[::1]:8000' -> '[::1]'."""
    if authority.startswith("["):
        return authority.split("]", 1)[0] + "]"
    return authority.rsplit(":", 1)[0] if authority.count(":") == 1 else authority


def _bearer(header: bytes) -> bytes | None:
    scheme, _, given = header.partition(b" ")
    if scheme.lower() != b"bearer" or not given.strip():
        return None
    return given.strip()


async def _refuse(send, status: int, detail: str, extra: list | None = None) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            *_COMMON, (b"content-security-policy", DATA_CSP.encode()), *(extra or [])]})
    await send({"type": "http.response.body", "body": body})
