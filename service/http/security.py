"""Who may ask what: API keys, Host/Origin checks and security headers, in one ASGI middleware.

- With API keys set, every request but the probes (/healthz, /readyz, /metrics) and the page
  itself (GET /, its script, style and icon: no data; it asks for the key) needs
  `Authorization: Bearer KEY` (keys compared in constant time, never logged); `public_read`
  lets GET/HEAD of listings and thumbnails through without one (marked anonymous: the routes
  bound what such a read may render). No cookie is ever accepted, so a browser never sends a
  key on another site's behalf.
- Host must be a name of this service (loopback names, the bound address, `allowed_hosts`) with
  the server's own port: a page that rebinds its own DNS name to 127.0.0.1 cannot read or write
  through it, and `127.0.0.1:8000.evil.com` is no port. A state-changing request carrying an
  Origin must come from this service's own origin (scheme, name, port) or one in
  `allowed_origins`, so no other page, another local port's included, can POST or DELETE
  through the user's browser.
- HEAD is answered wherever GET is: the GET's status and headers, no body.
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
PAGE_PATHS = ("/", "/static/page.js", "/static/page.css", "/favicon.ico")  # no data: the key is asked there
DEFAULT_PORTS = {"http": 80, "https": 443}
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
        # "name" entries go with the server's own port; "name:port" ones name their port
        self.hosts = {h for h in hosts if _split_authority(h)[1] is None} | LOOPBACK_NAMES
        self.host_ports = {h for h in hosts if _split_authority(h)[1] is not None}
        self.origins = {o.strip().lower().rstrip("/") for o in settings.allowed_origins.split(",") if o.strip()}

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope["headers"])
        path, method = scope["path"], scope["method"]
        state = scope.setdefault("state", {})
        state["client"] = "addr:" + (scope.get("client") or ("local", 0))[0]
        state["anonymous"] = False
        port = (scope.get("server") or ("", 0))[1]
        raw_host = headers.get(b"host", b"")
        host = raw_host.decode("latin-1").lower()
        if path not in OPEN_PATHS and not self._host_ok_cached(raw_host, host, port):  # probes: any address
            return await _refuse(send, 421,
                                 f"Host {host[:64]!r} is not a name of this service with its port {port}; "
                                 "add it to allowed_hosts (ASSET_PREVIEW_ALLOWED_HOSTS)")
        origin = headers.get(b"origin")
        if origin is not None and method not in READ_METHODS and not self._origin_ok(origin, scope):
            return await _refuse(send, 403, f"cross-origin request refused: Origin {origin[:80].decode('latin-1')!r} "
                                 "is not this service's own origin nor one in allowed_origins")
        page = path in PAGE_PATHS and method in READ_METHODS
        if self.keys and path not in OPEN_PATHS and not page:
            who = self._known(_bearer(headers.get(b"authorization", b"")))
            if who is not None:
                state["client"] = who
            elif self.public_read and method in READ_METHODS:
                state["anonymous"] = True
            else:
                return await _refuse(send, 401, "missing or wrong API key: send `Authorization: Bearer KEY` "
                                     "(on the page: the key field)", [(b"www-authenticate", b"Bearer")])

        head = method == "HEAD"
        if head:  # answered as the GET it stands for, without the body
            scope = dict(scope, method="GET")

        async def secured(message):
            if message["type"] == "http.response.start":
                hdrs = message.get("headers", [])
                html = any(k.lower() == b"content-type" and v.startswith(b"text/html") for k, v in hdrs)
                message = dict(message, headers=[*hdrs, *(_PAGE_HEADERS if html else _DATA_HEADERS)])
            elif head and message["type"] == "http.response.body":
                if message.get("more_body"):
                    return
                message = {"type": "http.response.body", "body": b""}
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

    def _host_ok_cached(self, raw: bytes, host: str, port: int) -> bool:
        ok = self._hosts_seen.get(raw)
        if ok is None:
            ok = self._host_ok(host, port)
            if len(self._hosts_seen) < 256:  # a client sending random names cannot grow it
                self._hosts_seen[raw] = ok
        return ok

    def _host_ok(self, host: str, port: int) -> bool:
        """`name` or `name:port`, the name one of ours, the port the server's own (absent: the
        scheme's default, which is then the server's), or `name:port` listed as it is."""
        if self.any_host:
            return True
        name, given = _split_authority(host)
        if name is None:
            return False
        ports = (given,) if given is not None else (80, 443)  # no port: the scheme's default
        return any((name in self.hosts and p == port) or f"{name}:{p}" in self.host_ports for p in ports)

    def _origin_ok(self, origin: bytes, scope) -> bool:
        """This service's own origin (the request's scheme, one of its names, the server's
        port) or one listed in allowed_origins; `null` (sandboxed frames, file: pages) never."""
        text = origin.decode("latin-1").lower().rstrip("/")
        if text in self.origins:
            return True
        scheme, sep, authority = text.partition("://")
        if not sep or "/" in authority or scheme not in DEFAULT_PORTS:
            return False
        name, port = _split_authority(authority)
        own_port = (scope.get("server") or ("", 0))[1]
        if port is None:
            port = DEFAULT_PORTS.get(scheme)
        if name is None:
            return False
        own = scheme == scope.get("scheme", "http") and port == own_port and (name in self.hosts or self.any_host)
        return own or f"{name}:{port}" in self.host_ports  # a listed name:port (a proxy in front)


def _split_authority(authority: str) -> tuple[str | None, int | None]:
    """'example.com:8000' -> ('example.com', 8000); '[::1]' -> ('[::1]', None); a port that is
    not all digits (`127.0.0.1:8000.evil.com`) or an empty name -> (None, None)."""
    if authority.startswith("["):
        name, _, rest = authority.partition("]")
        name += "]"
        if not rest:
            return name, None
        if not rest.startswith(":"):
            return None, None
        port_text = rest[1:]
    else:
        if authority.count(":") > 1:  # a bare IPv6 address is no Host
            return None, None
        name, sep, port_text = authority.partition(":")
        if not sep:
            return (name or None), None
    if not name or not port_text.isascii() or not port_text.isdigit() or len(port_text) > 5:
        return None, None
    return name, int(port_text)


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
