"""The stores a token may render: ``GET /v1/stores`` and ``GET /v1/stores/{store}`` (id, name and
public metadata; a store the token may not render is as unknown, 404)."""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from .base import Caller, endpoint, service

__all__ = ["ROUTES"]


async def list_stores(request: Request, caller: Caller) -> Response:
    svc = service(request)
    return JSONResponse({"stores": [svc.description(sid) for sid in svc.visible(caller.token)]})


async def one_store(request: Request, caller: Caller) -> Response:
    svc = service(request)
    sid, _ = svc.resolve(request, caller.token)
    return JSONResponse(svc.description(sid))


ROUTES = [
    Route("/v1/stores", endpoint(list_stores), methods=["GET"]),
    Route("/v1/stores/{store}", endpoint(one_store), methods=["GET"]),
]
