"""The OpenAPI 3.1 document of ``hevr serve`` (``GET /v1/openapi.json``), generated: its schemas
are the JSON Schema of the protocol's models (:mod:`hevr.remote.schema`, the same models that
check every request), its media types and bounds the constants the code uses. Written here are
only the paths, what each answers and the problem documents of its failures (RFC 9457).

>>> from hevr.volume.pyramid import MAX_LEVELS
>>> doc = openapi_document()
>>> doc["components"]["schemas"]["RenderRequest"]["properties"]["level"]["maximum"] == MAX_LEVELS
True
>>> sorted(doc["paths"])[:3]
['/v1', '/v1/health', '/v1/openapi.json']
"""

from __future__ import annotations

from typing import Any

from .. import __version__
from ..remote.protocol import IMAGE_MEDIA, MAX_BODY, PREFIX, PROBLEM_MEDIA, UNITS_MEDIA
from ..remote.schema import STORE_NAME_PATTERN, components

__all__ = ["ERRORS", "openapi_document"]

JSON = "application/json"

#: What each failure status means, by the titles of its problem documents (every one
#: ``application/problem+json``; tests/serve/test_openapi.py keeps the titles the server sends here).
ERRORS = {
    400: "bad request: the parameter named in detail",
    401: "unauthorised: missing or unknown bearer token (a server with a token table)",
    404: "no such store (or not one this token may render)",
    413: f"request too large: body over {MAX_BODY} bytes",
    415: "unsupported media type: Content-Type not application/json",
    422: "render refused by the planner (too many pixels or samples, or a value range it cannot hold); "
    "backend not offered (a backend other than the server's own); or "
    "render over the server's budget (before any work: a step under its minimum, a fraction of the voxel "
    "spacing; more pixels than --max-pixels, a tile too small for the image, more modular products than "
    "--max-products or --max-token-products; detail names step, width, height, tile or products)",
    429: "too many concurrent renders (--max-concurrent, the token's concurrent); or too much work in flight "
    "(the products of this token's running renders over --max-token-products, or of all over "
    "--max-concurrent × --max-products); retry after Retry-After seconds",
    500: "internal error, render failed or store failed a check (the server's log has the details)",
    503: "server out of memory for this render; render cancelled (the server stopped while it ran); "
    "server shutting down (no new render); or store being reopened (it changed on disk); retry after "
    "Retry-After seconds",
}
_HEADERS = {401: {"WWW-Authenticate": "Bearer realm"}, 429: {"Retry-After": "seconds"}, 503: {"Retry-After": "seconds"}}
_FRAMES = (
    "frames of index (u32 LE), length (u32 LE) and that many bytes of ciphertext records, then an end frame "
    'of index 0xFFFFFFFF whose body is the JSON {"ok": true, "stats": ...} or a problem document'
)


def _ref(name: str) -> dict:
    return {"$ref": f"#/components/schemas/{name}"}


def _json(name: str, description: str) -> dict:
    return {"description": description, "content": {JSON: {"schema": _ref(name)}}}


def _errors(*codes: int) -> dict:
    out = {}
    for c in codes:
        answer: dict = {"description": ERRORS[c], "content": {PROBLEM_MEDIA: {"schema": _ref("Problem")}}}
        if c in _HEADERS:
            answer["headers"] = {
                h: {"description": what, "schema": {"type": "string"}} for h, what in _HEADERS[c].items()
            }
        out[str(c)] = answer
    return out


_STORE = {
    "name": "store",
    "in": "path",
    "required": True,
    "description": "the store's id (16 lower-case hex digits) or the name it is served under",
    "schema": {"type": "string", "pattern": f"^{STORE_NAME_PATTERN}$"},
}
_BINARY = {"schema": {"type": "string", "format": "binary"}}
_STATS = {
    "X-Hevr-Stats": {"description": "the render's public statistics, one line of JSON", "schema": {"type": "string"}}
}


def _get(summary: str, answer: dict, *codes: int, **more: Any) -> dict:
    """A GET operation and its HEAD (Starlette answers HEAD on every GET route: the same status and
    headers, no body)."""
    head = {
        "description": f"as GET, without the body: {answer['description']}",
        **({"headers": answer["headers"]} if "headers" in answer else {}),
    }
    errors = _errors(*codes, 500)
    return {
        "get": {"summary": summary, "responses": {"200": answer, **errors}, **more},
        "head": {
            "summary": f"{summary} (the answer's head only)",
            "responses": {
                "200": head,
                **{c: {k: v for k, v in e.items() if k != "content"} for c, e in errors.items()},
            },
            **more,
        },
    }


def _post(summary: str, body: str, answer: dict) -> dict:
    return {
        "post": {
            "summary": summary,
            "parameters": [_STORE],
            "requestBody": {"required": True, "content": {JSON: {"schema": _ref(body)}}},
            "responses": {"200": answer, **_errors(400, 401, 404, 413, 415, 422, 429, 500, 503)},
        }
    }


def openapi_document() -> dict[str, Any]:
    """The document (a fresh dict each call)."""
    return {
        "openapi": "3.1.0",
        "info": {
            "title": "hevr serve",
            "version": __version__,
            "description": "Renders Paillier-encrypted volumes for the key holder, who never sends a key. "
            "Requests are strict JSON (unknown fields, duplicate keys, NaN and out-of-range "
            "numbers refused; an integer is written as one: 1, not 1.0); answers are data only: "
            ".hevr images, length-prefixed frames of ciphertext records, JSON. In words: "
            "docs/protocol.md in hevr's repository. Every operation but /v1/health asks for a "
            "bearer token when the server runs with a token table (hevr serve --tokens); "
            "without one it asks for none.",
        },
        "components": {
            "schemas": components(),
            "securitySchemes": {
                "bearer": {
                    "type": "http",
                    "scheme": "bearer",
                    "description": "a token of the server's token table; "
                    "a server started without a token table "
                    "asks for none (and ignores one sent)",
                }
            },
        },
        "security": [{"bearer": []}],
        "paths": {
            PREFIX: _get("the protocol's version and the server's hevr", _json("Version", "versions"), 401),
            f"{PREFIX}/health": _get("the server is up", _json("Health", "up"), security=[]),
            f"{PREFIX}/openapi.json": _get(
                "this document",
                {"description": "the OpenAPI document", "content": {JSON: {"schema": {"type": "object"}}}},
                401,
            ),
            f"{PREFIX}/stores": _get(
                "the stores this token may render", _json("Stores", "their ids, names and public metadata"), 401
            ),
            f"{PREFIX}/stores/{{store}}": _get(
                "one store's id, name and public metadata, by its id or its name",
                _json("Store", "the store"),
                401,
                404,
                503,
                parameters=[_STORE],
            ),
            f"{PREFIX}/stores/{{store}}/render": _post(
                "render a view or slice",
                "RenderRequest",
                {
                    "description": f"a per-voxel store's client-finished .hevr image ({IMAGE_MEDIA}); a packed "
                    f"store's frame as its reduce tiles' combined values, in tile order, as {_FRAMES} "
                    f"({UNITS_MEDIA})",
                    "headers": _STATS,
                    "content": {IMAGE_MEDIA: _BINARY, UNITS_MEDIA: _BINARY},
                },
            ),
            f"{PREFIX}/stores/{{store}}/stream": _post(
                "a per-voxel store's render as its finishing units, as they complete",
                "RenderRequest",
                {"description": f"one frame per finishing unit: {_FRAMES}", "content": {UNITS_MEDIA: _BINARY}},
            ),
            f"{PREFIX}/stores/{{store}}/verify": _post(
                "the tag aggregate of a render for the key holder's seed (drawn after it held the image)",
                "VerifyRequest",
                _json("Aggregate", "the aggregate"),
            ),
        },
    }
