"""The service's own endpoints: ``GET /v1`` (the API and hevr versions), ``GET /v1/openapi.json``
(the protocol's document) and ``GET /v1/health`` (liveness for a load balancer or an
orchestrator: no token, ``{"status": "ok"}``, nothing about the stores; ``HEAD`` too)."""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from ... import __version__
from ...remote.protocol import API_VERSION
from ..openapi import openapi_document
from .base import Caller, endpoint

__all__ = ["HEALTH", "ROUTES"]

HEALTH = {"status": "ok"}  # all /v1/health ever says: no store, token, version or load


async def version(request: Request, caller: Caller) -> Response:
    return JSONResponse({"api": API_VERSION, "hevr": __version__})


async def openapi(request: Request, caller: Caller) -> Response:
    return JSONResponse(openapi_document())


async def health(request: Request, caller: Caller) -> Response:
    """200 ``{"status": "ok"}`` while the process answers HTTP: public (no token), and about
    nothing else, so that a probe that may not hold a token learns nothing of the stores."""
    return JSONResponse(HEALTH, headers={"Cache-Control": "no-store"})


ROUTES = [
    Route("/v1", endpoint(version), methods=["GET"]),
    Route("/v1/openapi.json", endpoint(openapi), methods=["GET"]),
    Route("/v1/health", endpoint(health, public=True), methods=["GET", "HEAD"]),
]
