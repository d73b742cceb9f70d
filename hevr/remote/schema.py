"""The protocol's models, written once: the requests the key holder sends to ``hevr serve`` and
the JSON documents it answers, as pydantic models. They are the structural check of every
request (:mod:`hevr.remote.protocol` validates with them before building a
:class:`~hevr.remote.protocol.RenderRequest`) and the source of the OpenAPI document
(:mod:`hevr.serve.openapi` generates its schemas from them); every bound comes from the
constant the code uses (:data:`~hevr.volume.pyramid.MAX_LEVELS`,
:data:`~hevr.rendering.geometry.camera.MAX_COORDINATE`, …).

Why pydantic (a core dependency: the client builds requests with these models too) and not
msgspec: the view is a camera *or* a plane told apart by ``kind`` (absent from a camera), which
pydantic validates with a callable discriminator where msgspec wants a tag in every member;
pydantic's errors are structured (location, input, constraint), so every refusal still reads
``name: expected X, got Y`` naming the field; and its JSON Schema is the 2020-12 dialect
OpenAPI 3.1 uses.

Strict as the hand-written checks were: ``strict`` (no ``"1"`` for a number, no ``true`` for
an integer, no ``1.0`` for an integer), ``extra="forbid"`` (unknown fields refused), no NaN or
infinity (``1e999`` parses as infinity), and every number bounded. Duplicate keys, NaN literals,
huge integers and deep nesting are refused before, by :func:`~hevr.remote.protocol.parse_json`.
The domain checks (a camera's view direction, a plane's orthogonal axes, a plane has no level)
stay with the objects (:class:`~hevr.rendering.geometry.camera.Camera`, ``RenderRequest``).

The models' names are the OpenAPI document's component names; ``RenderRequest`` here is the wire
form of :class:`hevr.remote.protocol.RenderRequest`.

>>> check(RenderRequest, {"view": {"position": [0, 0, 9], "focal_point": [0, 0, 0]},
...                       "channel": "scalar", "level": 99}, "request")
Traceback (most recent call last):
...
hevr.errors.ParameterError: level: expected an integer in [0, 8], got 99
"""

from __future__ import annotations

import json
from dataclasses import MISSING, fields
from functools import cache
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError, create_model
from pydantic.json_schema import GenerateJsonSchema, models_json_schema

from ..backends import AUTO, available_backends
from ..errors import ParameterError
from ..rendering.geometry.camera import Camera as _Camera
from ..rendering.geometry.coordinates import MAX_COORDINATE
from ..rendering.geometry.plane import MAX_SLAB
from ..rendering.geometry.plane import Plane as _Plane
from ..rendering.planning.modes import SAMPLINGS
from ..store.metadata import CHANNELS
from ..store.packing import MAX_WEIGHT_BITS
from ..volume.pyramid import MAX_LEVELS

__all__ = [
    "BACKENDS",
    "CHANNELS",
    "MAX_DIGITS",
    "MAX_PIXELS",
    "MAX_SIDE",
    "MAX_STEP",
    "SAMPLINGS",
    "STORE_ID_PATTERN",
    "STORE_NAME_PATTERN",
    "Aggregate",
    "Camera",
    "Health",
    "Plane",
    "Problem",
    "RenderRequest",
    "Store",
    "Stores",
    "VerifyRequest",
    "Version",
    "check",
    "components",
    "expected",
    "field_table",
    "message",
]

MAX_SIDE = 4096  # pixels per image side over the wire
MAX_PIXELS = MAX_SIDE * MAX_SIDE
MAX_STEP = 1e6  # world units between samples
MAX_DIGITS = 9  # decimal digits of the trilinear weights: the planner's bound (hevr.rendering.planning.request)
BACKENDS = (AUTO, *available_backends())
STORE_ID_PATTERN = "[0-9a-f]{16}"  # a store id as the server and the key holder write it
STORE_NAME_PATTERN = "[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}"  # a served name: safe in a URL path, no '/'
ID_LIKE = "[0-9a-fA-F]{16}"  # what a name may not be (it would read as a store id)


class Wire(BaseModel):
    """A JSON object of the protocol: strict types, unknown fields refused, numbers finite."""

    model_config = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False, frozen=True)


def _default(cls: type, name: str) -> Any:
    """The default of dataclass ``cls``'s field ``name`` as JSON has it (a tuple as a list): the
    wire's defaults are the objects' own, never a second copy of them."""
    f = next(f for f in fields(cls) if f.name == name)
    return list(f.default) if isinstance(f.default, tuple) else None if f.default is MISSING else f.default


Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
Vec3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]
Side = Annotated[int, Field(ge=1, le=MAX_SIDE)]
Positive = Annotated[float, Field(gt=0)]


class Camera(Wire):
    """A perspective or parallel camera (hevr.Camera.to_dict(); level 0's frame)."""

    position: Vec3 = Field(description="the eye, world (x, y, z)")
    focal_point: Vec3 = Field(description="the point looked at")
    view_up: Vec3 = Field(_default(_Camera, "view_up"), description="roughly up; not along the view")
    view_angle: Annotated[float, Field(gt=0, lt=180)] = Field(
        _default(_Camera, "view_angle"), description="full vertical angle, degrees"
    )
    width: Side = Field(_default(_Camera, "width"), description="pixels")
    height: Side = Field(_default(_Camera, "height"), description="pixels")
    parallel: bool = Field(_default(_Camera, "parallel"), description="orthographic projection")
    parallel_scale: Annotated[float, Field(gt=0, le=MAX_COORDINATE)] | None = Field(
        None, description="half the view's height, world units (null: what the view angle sees at the focal point)"
    )


class Plane(Wire):
    """A slice plane (hevr.Plane.to_dict()): pixel (r, c) at origin + c·du·u + r·dv·v."""

    kind: Literal["plane"] = Field(description="tells a plane from a camera")
    origin: Vec3 = Field(description="the centre of pixel (0, 0), world (x, y, z)")
    u: Vec3 = Field(description="the direction of increasing column")
    v: Vec3 = Field(description="the direction of increasing row; orthogonal to u")
    width: Side = Field(description="pixels")
    height: Side = Field(description="pixels")
    pixel_spacing: Positive | Annotated[list[Positive], Field(min_length=1, max_length=2)] = Field(
        _default(_Plane, "pixel_spacing"), description="world units per pixel: du, or (du, dv)"
    )
    slab: Annotated[int, Field(ge=1, le=MAX_SLAB)] = Field(
        _default(_Plane, "slab"), description="parallel planes averaged per pixel"
    )
    slab_step: Positive = Field(_default(_Plane, "slab_step"), description="world units between the slab's planes")


def _view_kind(value: Any) -> str:
    """Which model a view is: a plane says ``"kind": "plane"``, a camera says no kind."""
    return "Plane" if isinstance(value, dict) and value.get("kind") == "plane" else "Camera"


View = Annotated[Annotated[Camera, Tag("Camera")] | Annotated[Plane, Tag("Plane")], Discriminator(_view_kind)]


_CAMERA_EXAMPLE = {"position": [3.5, 3.5, 40.0], "focal_point": [3.5, 3.5, 3.5], "width": 8, "height": 8}
_PLANE_EXAMPLE = {
    "kind": "plane",
    "origin": [0.0, 0.0, 3.0],
    "u": [1.0, 0.0, 0.0],
    "v": [0.0, 1.0, 0.0],
    "width": 8,
    "height": 8,
}


class RenderRequest(Wire):
    """What the key holder asks to render: a view and what to sum, nothing of the colouring."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"view": _CAMERA_EXAMPLE, "channel": "scalar"},
                {"view": _PLANE_EXAMPLE, "channel": "scalar", "sampling": "trilinear", "pack": False},
            ]
        }
    )

    view: View = Field(description="a camera (level 0's frame) or a slice plane")
    channel: Literal[CHANNELS] = Field(description="the store's channel to sum")
    sampling: Literal[SAMPLINGS] = Field("nearest", description="how a sample reads the voxels")
    step: Annotated[
        float, Field(gt=0, le=MAX_STEP, description="sample spacing in world units (a plane: its slab step)")
    ] = 1.0
    level: Annotated[int, Field(ge=0, le=MAX_LEVELS, description="pyramid level (0: the volume)")] = 0
    digits: Annotated[int, Field(ge=0, le=MAX_DIGITS, description="decimal digits of trilinear weights")] = 3
    pack: bool = Field(True, description="pack many pixels per ciphertext")
    tile: Annotated[int, Field(ge=1, le=MAX_SIDE)] = Field(32, description="image tile edge (pixels) of the reduce")
    backend: Literal[BACKENDS] | None = Field(None, description="the server's arithmetic backend (null: its default)")
    weight_bits: Annotated[int, Field(ge=0, le=MAX_WEIGHT_BITS)] | None = Field(
        None, description="a packed store's in-slice weight bits (null: the store's)"
    )


#: A render request's fields but its view: what ``RenderRequest.__post_init__`` checks of a request
#: built in Python (its view is a Camera or Plane object, checked by itself).
RenderOptions = create_model(
    "RenderOptions",
    __base__=Wire,
    **{name: (f.annotation, f) for name, f in RenderRequest.model_fields.items() if name != "view"},
)


class VerifyRequest(Wire):
    """The verification round: the render asked before and the seed drawn after holding it."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"render": {"view": _CAMERA_EXAMPLE, "channel": "scalar"}, "seed": "5e" * 32}]}
    )

    render: RenderRequest = Field(description="the render asked before")
    seed: str = Field(pattern="^[0-9a-f]{64}$", description="64 lower-case hex digits (32 bytes)")


class Version(Wire):
    """``GET /v1``: the protocol's version and the server's hevr."""

    api: int
    hevr: str


class Health(Wire):
    """``GET /v1/health``: the server is up (asks for no token)."""

    status: Literal["ok"]


class Store(Wire):
    """A served store: its id, the name it is served under, its public metadata."""

    id: str = Field(pattern=f"^{STORE_ID_PATTERN}$", description="16 lower-case hex digits")
    name: str | None = Field(
        pattern=f"^{STORE_NAME_PATTERN}$",
        json_schema_extra={"not": {"type": "string", "pattern": f"^{ID_LIKE}$"}},
        description="the name the operator serves the store under (hevr serve NAME=PATH, or "
        "its folder's name without .zarr); null: by id only",
    )
    metadata: dict[str, Any] = Field(description="the store's public 'hevr' attributes (docs/format.md)")


class Stores(Wire):
    """``GET /v1/stores``: the stores this token may render."""

    stores: list[Store]


class Aggregate(Wire):
    """``POST /v1/stores/{store}/verify``: the tag aggregate, a decimal integer."""

    aggregate: str = Field(pattern="^[0-9]+$")


class Problem(BaseModel):
    """An RFC 9457 problem document: ``detail`` names the parameter at fault."""

    model_config = ConfigDict(extra="allow")
    type: str = "about:blank"
    title: str
    status: Annotated[int, Field(ge=400, le=599)]
    detail: str


MODELS = (RenderRequest, VerifyRequest, Version, Health, Store, Stores, Aggregate, Problem)


class _NoTitles(GenerateJsonSchema):
    """JSON Schema without pydantic's generated field titles ("Focal Point")."""

    def field_title_should_be_set(self, schema: Any) -> bool:
        return False


def components(ref: str = "#/components/schemas/{model}") -> dict[str, dict]:
    """The JSON Schema of every model, by name, its references ``ref`` (OpenAPI's components).

    >>> sorted(components())[:4]
    ['Aggregate', 'Camera', 'Health', 'Plane']
    """
    _, doc = models_json_schema([(m, "validation") for m in MODELS], ref_template=ref, schema_generator=_NoTitles)
    return doc["$defs"]


@cache
def _defs(model: type[BaseModel]) -> dict[str, dict]:
    """The JSON Schema of ``model`` and of every model it refers to, by name (references
    ``#/$defs/NAME``): what :func:`message` walks, derived from the model itself, so that any model
    :func:`check` is given (``RenderOptions`` included) has its schema.

    >>> sorted(_defs(RenderOptions))
    ['RenderOptions']
    """
    _, doc = models_json_schema([(model, "validation")], ref_template="#/$defs/{model}", schema_generator=_NoTitles)
    return doc["$defs"]


_SCHEMAS = components("#/$defs/{model}")  # the protocol's models (field tables, expected())


# ----------------------------------------------------------------------------------- errors
def check(model: type[BaseModel], data: Any, name: str = "request") -> Any:
    """``data`` validated by ``model``; a :class:`hevr.ParameterError` naming the field otherwise
    (``name``: what the whole object is called)."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ParameterError(message(exc, model, name)) from None


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _deref(s: dict, defs: dict | None = None) -> dict:
    while "$ref" in s:
        s = (defs or _SCHEMAS)[s["$ref"].rsplit("/", 1)[1]]
    return s


def _walk(model: type[BaseModel], loc: tuple) -> tuple[str, dict, dict, bool]:
    """(the field's path, the schema of the field, the schema of the node the error is at,
    whether the walk stopped at a union's member) of a pydantic error location in ``model``."""
    defs = _defs(model)
    node = field = defs[model.__name__]
    path = ""
    for part in loc:
        node = _deref(node, defs)
        options = node.get("oneOf") or node.get("anyOf")
        if options and isinstance(part, str) and {"$ref": f"#/$defs/{part}"} in options:
            node = defs[part]  # a tagged member: the same field
        elif isinstance(part, int) and "items" in node:
            node = field = node["items"]
            path += f"[{part}]"
        elif isinstance(part, str) and part in node.get("properties", {}):
            node = field = node["properties"][part]
            path += f".{part}" if path else part
        else:  # inside an untagged union (its members' names): the field as a whole
            return path, field, field, True
    return path, field, _deref(node, defs), False


def _number(x: Any) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def expected(s: dict, defs: dict | None = None) -> str:
    """What a JSON Schema accepts, in words (``defs``: the schemas its references name; None: the
    protocol's models).

    >>> expected({"type": "integer", "minimum": 0, "maximum": 8})
    'an integer in [0, 8]'
    >>> expected({"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "null"}]})
    'a number > 0 or null'
    """
    s = _deref(s, defs)
    if "const" in s:
        return json.dumps(s["const"])
    if "enum" in s:
        return "one of " + ", ".join(map(str, s["enum"]))
    options = s.get("oneOf") or s.get("anyOf")
    if options:
        return " or ".join(expected(o, defs) for o in options)
    kind = s.get("type")
    if kind in ("integer", "number"):
        lo = (
            f"[{_number(s['minimum'])}"
            if "minimum" in s
            else f"({_number(s['exclusiveMinimum'])}"
            if "exclusiveMinimum" in s
            else None
        )
        hi = (
            f"{_number(s['maximum'])}]"
            if "maximum" in s
            else f"{_number(s['exclusiveMaximum'])})"
            if "exclusiveMaximum" in s
            else None
        )
        what = "an integer" if kind == "integer" else "a number"
        if lo and hi:
            return f"{what} in {lo}, {hi}"
        if lo:
            return f"{what} {'>=' if lo[0] == '[' else '>'} {lo[1:]}"
        return f"{what} {'<=' if hi[-1] == ']' else '<'} {hi[:-1]}" if hi else what
    if kind == "array":
        lo, hi = s.get("minItems", 0), s.get("maxItems")
        count = f"{lo}" if lo == hi else f"{lo} to {hi}" if hi is not None else f"at least {lo}"
        return f"an array of {count} items, each {expected(s.get('items', {}), defs)}"
    if kind == "string":
        return s.get("description") or (f"a string matching {s['pattern']}" if "pattern" in s else "a string")
    if kind == "object":
        return f"a {s['title']} object" if "title" in s else "a JSON object"
    return {"boolean": "true or false", "null": "null"}.get(kind, "a JSON value")


def field_table(model: type[BaseModel]) -> str:
    """A Markdown table of ``model``'s fields: its default (or that it is required), what it
    accepts and what it means (docs/protocol.md holds these tables; a test keeps them current).

    >>> print(field_table(Health))
    | field | default | accepts | meaning |
    |---|---|---|---|
    | `status` | required | "ok" |  |
    """
    s = _SCHEMAS[model.__name__]
    rows = ["| field | default | accepts | meaning |", "|---|---|---|---|"]
    for name, prop in s["properties"].items():
        default = "required" if name in s.get("required", ()) else f"`{json.dumps(prop.get('default'))}`"
        said = prop.get("type") == "string" and not {"enum", "const"} & set(prop)  # the description is `accepts`
        meaning = "" if said else prop.get("description", "")
        rows.append(f"| `{name}` | {default} | {expected(prop)} | {meaning} |")
    return "\n".join(rows)


def message(exc: ValidationError, model: type[BaseModel], name: str) -> str:
    """The one-line message of a pydantic error of ``model`` (any model: its schema is derived
    from it): unknown fields first, then missing ones, then the first field refused, each as
    ``field: expected X, got Y``.

    >>> try:
    ...     RenderOptions.model_validate({"channel": "scalar", "step": -1.0})
    ... except ValidationError as exc:
    ...     message(exc, RenderOptions, "request")
    'step: expected a number in (0, 1e+06], got -1.0'
    """
    errors = exc.errors(include_url=False)
    for kind in ("extra_forbidden", "missing"):
        found = [e for e in errors if e["type"] == kind]
        if found:
            where = min((_walk(model, e["loc"][:-1]) for e in found), key=lambda w: w[0].count("."))
            names = sorted(str(e["loc"][-1]) for e in found if _walk(model, e["loc"][:-1])[0] == where[0])
            node = where[2]
            if kind == "extra_forbidden":
                return (
                    f"{where[0] or name}: expected only the fields {sorted(node.get('properties', {}))}, "
                    f"got extra fields {names}"
                )
            return f"{where[0] or name}: expected the fields {sorted(node.get('required', []))}, missing {names}"
    e = errors[0]
    path, field, node, _ = _walk(model, e["loc"])
    return f"{path or name}: expected {expected(field if path else node, _defs(model))}, got {_show(e['input'])}"
