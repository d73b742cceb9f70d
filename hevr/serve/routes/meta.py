"""The service's own endpoints: ``GET /v1`` (the API and hevr versions) and
``GET /v1/openapi.json`` (the protocol's document)."""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from ... import __version__
from ...remote.protocol import API_VERSION
from ..openapi import openapi_document
from .base import Caller, endpoint

__all__ = ["ROUTES"]


async def version(request: Request, caller: Caller) -> Response:
    return JSONResponse({"api": API_VERSION, "hevr": __version__})


async def openapi(request: Request, caller: Caller) -> Response:
    return JSONResponse(openapi_document())


ROUTES = [
    Route("/v1", endpoint(version), methods=["GET"]),
    Route("/v1/openapi.json", endpoint(openapi), methods=["GET"]),
]
