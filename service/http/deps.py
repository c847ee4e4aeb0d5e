"""Dependencies shared by the routers: the service state and who is asking.

Access itself (API keys, Host/Origin) is checked for every request by
service.http.security.AccessMiddleware, before any router runs.
"""
from __future__ import annotations

from fastapi import Request

from service.thumbnails import ThumbnailService


# async: FastAPI runs plain-def dependencies in a thread pool, which costs more than the work.
async def get_service(request: Request) -> ThumbnailService:
    return request.app.state.service


def client_of(request: Request) -> str:
    """"key:<fingerprint>" for a request with a valid key, else "addr:<peer address>"."""
    return request.scope.get("state", {}).get("client") or "addr:?"
