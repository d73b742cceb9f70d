"""The OpenAPI 3.1 document of ``hevr serve`` (``GET /v1/openapi.json``): the protocol of
:mod:`hevr.remote.protocol` as JSON Schema, so that other clients (and schemathesis) can be
written against it. The schemas say what the parsers enforce: unknown fields are refused
(``additionalProperties: false``) and every number is bounded.
"""

from __future__ import annotations

from typing import Any

from .. import __version__
from ..remote.protocol import (
    BACKENDS,
    CHANNELS,
    IMAGE_MEDIA,
    MAX_SIDE,
    MAX_STEP,
    PROBLEM_MEDIA,
    STORE_NAME,
    SAMPLINGS,
    UNITS_MEDIA,
)
from ..store.packing import MAX_WEIGHT_BITS

__all__ = ["openapi_document"]

_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_SIDE = {"type": "integer", "minimum": 1, "maximum": MAX_SIDE}
_CAMERA = {
    "type": "object", "additionalProperties": False, "required": ["position", "focal_point"],
    "properties": {"position": _VEC3, "focal_point": _VEC3, "view_up": _VEC3,
                   "view_angle": {"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 180},
                   "width": _SIDE, "height": _SIDE, "parallel": {"type": "boolean"},
                   "parallel_scale": {"type": ["number", "null"], "exclusiveMinimum": 0}},
}
_PLANE = {
    "type": "object", "required": ["kind"], "description": "hevr.Plane.to_dict(): kind 'plane', origin, axes, size, "
                                                            "slab and slab_step",
    "properties": {"kind": {"const": "plane"}},
}
_RENDER = {
    "type": "object", "additionalProperties": False, "required": ["view", "channel"],
    "properties": {
        "view": {"oneOf": [_CAMERA, _PLANE]},
        "channel": {"enum": list(CHANNELS)},
        "sampling": {"enum": list(SAMPLINGS), "default": "nearest"},
        "step": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_STEP, "default": 1.0},
        "level": {"type": "integer", "minimum": 0, "maximum": 8, "default": 0},
        "digits": {"type": "integer", "minimum": 0, "maximum": 9, "default": 3},
        "pack": {"type": "boolean", "default": True},
        "tile": {"type": "integer", "minimum": 1, "maximum": MAX_SIDE, "default": 32},
        "backend": {"enum": [None, *BACKENDS], "default": None},
        "weight_bits": {"type": ["integer", "null"], "minimum": 0, "maximum": MAX_WEIGHT_BITS, "default": None,
                        "description": "a packed store's in-slice weight bits (null: the store's)"},
    },
}
_VERIFY = {
    "type": "object", "additionalProperties": False, "required": ["render", "seed"],
    "properties": {"render": {"$ref": "#/components/schemas/RenderRequest"},
                   "seed": {"type": "string", "pattern": "^[0-9a-f]{64}$"}},
}
_PROBLEM = {
    "type": "object", "required": ["title", "status", "detail"],
    "properties": {"type": {"type": "string"}, "title": {"type": "string"}, "status": {"type": "integer"},
                   "detail": {"type": "string"}},
}
_NAME = {"type": "string", "pattern": f"^{STORE_NAME.pattern}$", "not": {"pattern": "^[0-9a-fA-F]{16}$"}}
_STORE = {"type": "object", "additionalProperties": False, "required": ["id", "name", "metadata"],
          "properties": {"id": {"type": "string", "pattern": "^[0-9a-f]{16}$"},
                         "name": {"oneOf": [_NAME, {"type": "null"}],
                                  "description": "the name the operator serves the store under (hevr serve "
                                                 "NAME=PATH, or its folder's name without .zarr); null: by id only"},
                         "metadata": {"type": "object", "description": "the store's public 'hevr' attributes "
                                                                       "(docs/store-format.md)"}}}


def _errors(*codes: int) -> dict:
    text = {400: "bad request", 401: "missing or unknown token", 404: "no such store (or not for this token)",
            413: "request too large", 415: "not JSON", 422: "refused by the render planner",
            429: "too many concurrent renders (Retry-After)", 500: "server failure", 503: "out of memory"}
    return {str(c): {"description": text[c], "content": {PROBLEM_MEDIA: {"schema": {"$ref": "#/components/schemas/Problem"}}}}
            for c in codes}


_PATH_STORE = [{"name": "store", "in": "path", "required": True,
                "description": "the store's id (16 hex digits) or the name it is served under",
                "schema": {"type": "string", "maxLength": 64}}]


def _post(summary: str, schema: str, media: str, answer: dict, also: str | None = None) -> dict:
    content = {media: answer, **({also: answer} if also else {})}
    return {"post": {
        "summary": summary, "parameters": _PATH_STORE,
        "requestBody": {"required": True, "content": {"application/json": {
            "schema": {"$ref": f"#/components/schemas/{schema}"}}}},
        "responses": {"200": {"description": "the answer", "content": content},
                      **_errors(400, 401, 404, 413, 415, 422, 429, 500, 503)}}}


def openapi_document() -> dict[str, Any]:
    """The document (a fresh dict each call)."""
    binary = {"schema": {"type": "string", "format": "binary"}}
    return {
        "openapi": "3.1.0",
        "info": {"title": "hevr serve", "version": __version__,
                 "description": "Renders Paillier-encrypted volumes for the key holder, who never sends a key. "
                                "Answers are data only: .hevr images, length-prefixed units, JSON."},
        "components": {
            "schemas": {"RenderRequest": _RENDER, "VerifyRequest": _VERIFY, "Problem": _PROBLEM, "Store": _STORE},
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
        },
        "security": [{"bearer": []}, {}],
        "paths": {
            "/v1": {"get": {"summary": "protocol version", "responses": {"200": {"description": "api and hevr "
                                                                                              "versions"}}}},
            "/v1/openapi.json": {"get": {"summary": "this document", "responses": {"200": {"description": "OpenAPI"}}}},
            "/v1/stores": {"get": {"summary": "the stores this token may render",
                                   "responses": {"200": {"description": "stores", "content": {"application/json": {
                                       "schema": {"type": "object", "properties": {"stores": {
                                           "type": "array", "items": {"$ref": "#/components/schemas/Store"}}}}}}},
                                       **_errors(401)}}},
            "/v1/stores/{store}": {"get": {
                "summary": "one store's id, name and public metadata, by its id or its name",
                "parameters": _PATH_STORE,
                "responses": {"200": {"description": "the store", "content": {"application/json": {
                    "schema": {"$ref": "#/components/schemas/Store"}}}}, **_errors(401, 404)}}},
            "/v1/stores/{store}/render": _post(
                "render a view or slice: a client-finished .hevr image; of a packed store, its tiles' combined values "
                "as frames of index (u32 LE), length (u32 LE) and ciphertext records, in tile order, then an end frame "
                "of index 0xFFFFFFFF holding a JSON status", "RenderRequest", IMAGE_MEDIA, binary, UNITS_MEDIA),
            "/v1/stores/{store}/stream": _post(
                "the same render as finishing units as they complete: frames of index (u32 LE), length (u32 LE) and "
                "ciphertext records; an end frame of index 0xFFFFFFFF holds a JSON status", "RenderRequest",
                UNITS_MEDIA, binary),
            "/v1/stores/{store}/verify": _post(
                "the tag aggregate of a render for the key holder's seed (drawn after it held the image)",
                "VerifyRequest", "application/json",
                {"schema": {"type": "object", "additionalProperties": False, "required": ["aggregate"],
                            "properties": {"aggregate": {"type": "string", "pattern": "^[0-9]+$"}}}}),
        },
    }
