"""Dependencies shared by the routers: the service state and the optional API key."""
from __future__ import annotations

import hmac

from fastapi import Depends, HTTPException, Request

from .core import ThumbnailService


# async: FastAPI runs plain-def dependencies in a thread pool, which costs more than the work.
async def get_service(request: Request) -> ThumbnailService:
    return request.app.state.service


async def require_key(request: Request, service: ThumbnailService = Depends(get_service)) -> None:
    """When an API key is configured, writes need `Authorization: Bearer KEY`."""
    key = service.settings.api_key
    if not key:
        return
    scheme, _, given = request.headers.get("authorization", "").partition(" ")
    # compare_digest takes time independent of where the strings differ.
    if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(), key.encode()):
        raise HTTPException(401, "missing or wrong API key: send `Authorization: Bearer KEY`",
                            headers={"WWW-Authenticate": "Bearer"})
