"""The FastAPI application: `uvicorn service.http.app:app` or `asset-preview serve`.

Routers by resource live in service/http/routes/; the state they share is one ThumbnailService
(service/thumbnails.py), created here and started with the app's lifespan (worker processes, seed).
"""
from __future__ import annotations

import logging
import math
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi_offline import FastAPIOffline

from core.errors import AssetError, UnsupportedFormat
from service.archive import AmbiguousEntry
from service.assets import BadParameter, Conflict, NotFound, QuotaExceeded, StillBaking, UploadTooLarge, public_message
from service.http.metrics import MetricsMiddleware
from service.http.routes import assets, environments, health, pages
from service.http.security import AccessMiddleware
from service.settings import Settings
from service.thumbnails import NeedsKey, RateLimited, ThumbnailService
from service.workers.protocol import QueueFull, WorkerFailure

log = logging.getLogger(__name__)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings.from_env()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        service = ThumbnailService(settings)
        app.state.service = service
        await service.start()
        log.info("serving with %d render workers, cache %s", service.pool.size, settings.cache)
        try:
            yield
        finally:
            await service.stop()

    # FastAPIOffline serves the /docs and /redoc assets from the package, not from a CDN, so
    # the API pages work on machines without internet access.
    app = FastAPIOffline(title="asset-preview", version="0.1.0", lifespan=lifespan,
                  description="Upload glTF/USD assets; get physically based thumbnails.")
    for router in (assets.router, environments.router, health.router, pages.router):
        app.include_router(router)
    _install_error_handlers(app)
    app.add_middleware(BodyLimit, limit=settings.max_upload_bytes)
    # Outside BodyLimit: a request without its key is refused before its body is read.
    app.add_middleware(AccessMiddleware, settings=settings)
    # Added last = outermost, so it also times requests refused by the others.
    app.add_middleware(MetricsMiddleware)
    return app


def _install_error_handlers(app: FastAPI) -> None:
    def detail(status: int, message: str, headers: dict | None = None) -> JSONResponse:
        return JSONResponse({"detail": message}, status_code=status, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError):
        # One line, like every other error (ErrorDetail), naming each bad field and why.
        parts = [".".join(str(p) for p in e["loc"]) + ": " + e["msg"] for e in exc.errors()]
        return detail(422, "; ".join(parts)[:2000] or "invalid request")

    @app.exception_handler(AssetError)
    async def asset_error(request: Request, exc: AssetError):
        message = public_message(str(exc))  # never a server folder, whichever path raised it
        if isinstance(exc, UploadTooLarge):
            return detail(413, message)
        if isinstance(exc, AmbiguousEntry):  # the page (or a client) offers these as `main`
            return JSONResponse({"detail": message, "candidates": list(exc.candidates)}, status_code=422)
        return detail(415 if isinstance(exc, UnsupportedFormat) else 422, message)

    @app.exception_handler(NeedsKey)
    async def needs_key(request: Request, exc: NeedsKey):
        return detail(401, str(exc), {"WWW-Authenticate": "Bearer"})

    @app.exception_handler(RateLimited)
    async def rate_limited(request: Request, exc: RateLimited):
        return detail(429, str(exc), {"Retry-After": str(max(1, math.ceil(exc.retry_after)))})

    @app.exception_handler(QuotaExceeded)
    async def quota(request: Request, exc: QuotaExceeded):
        return detail(413, str(exc))

    @app.exception_handler(NotFound)
    async def not_found(request: Request, exc: NotFound):
        what = str(exc)
        return detail(404, what if " " in what else f"no asset with id {what!r}")

    @app.exception_handler(StillBaking)
    async def still_baking(request: Request, exc: StillBaking):
        retry = request.app.state.service.settings.retry_after_seconds
        return detail(202, f"asset {exc} is still baking; retry in {retry} s", {"Retry-After": str(retry)})

    @app.exception_handler(WorkerFailure)
    async def worker_failure(request: Request, exc: WorkerFailure):
        service = request.app.state.service
        headers = None
        if isinstance(exc, QueueFull):
            service.metrics.rejected.labels("queue_full").inc()
            headers = {"Retry-After": str(service.settings.retry_after_seconds)}
        return detail(exc.status, public_message(str(exc)), headers)

    @app.exception_handler(BadParameter)
    async def bad_parameter(request: Request, exc: BadParameter):
        return detail(422, str(exc))

    @app.exception_handler(Conflict)
    async def conflict(request: Request, exc: Conflict):
        return detail(409, str(exc))

    @app.exception_handler(Exception)
    async def unexpected(request: Request, exc: Exception):
        # A bug, not the client's input: logged once with its traceback, answered without it.
        log.error("%s %s failed: %s", request.method, request.url.path, exc, exc_info=exc)
        return detail(500, f"internal error ({type(exc).__name__}); it has been logged")


class BodyLimit:
    """413 for request bodies beyond the upload limit, decided from Content-Length before
    reading, and by counting for chunked bodies (the multipart parser would spool them whole).
    Past the limit, reading raises and whatever answer the app makes of that becomes the 413."""

    def __init__(self, app, limit: int):
        self.app = app
        self.limit = limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] not in ("POST", "PUT"):
            return await self.app(scope, receive, send)
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.limit:
            return await self._refuse(scope, send)
        seen, refused = 0, False

        async def counting_receive():
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.limit:
                raise _TooLarge()
            return message

        async def guarded_send(message):
            nonlocal refused
            if seen <= self.limit:
                return await send(message)
            if not refused:
                refused = True
                await self._refuse(scope, send)

        try:
            await self.app(scope, counting_receive, guarded_send)
        except _TooLarge:
            if not refused:
                await self._refuse(scope, send)

    async def _refuse(self, scope, send):
        scope["app"].state.service.metrics.rejected.labels("too_large").inc()
        body = b'{"detail":"request body is larger than the upload limit of %d bytes"}' % self.limit
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"connection", b"close"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


class _TooLarge(Exception):
    pass


def __getattr__(name: str):
    """`uvicorn service.http.app:app` builds the app (and reads the settings) when it asks for it,
    not when this module is imported."""
    if name == "app":
        globals()["app"] = application = create_app()
        return application
    raise AttributeError(name)
