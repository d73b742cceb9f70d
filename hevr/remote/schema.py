"""The protocol's models, written once: the requests the key holder sends to ``hevr serve`` and
the JSON documents it answers, as pydantic models. They are the structural check of every
request (:mod:`hevr.remote.protocol` validates with them before building a
:class:`~hevr.remote.protocol.RenderRequest`) and the source of the OpenAPI document
(:mod:`hevr.serve.openapi` generates its schemas from them); every bound comes from the
constant the code uses (:data:`~hevr.volume.pyramid.MAX_LEVELS`,
:data:`~hevr.rendering.geometry.coordinates.MAX_COORDINATE`, …).

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
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeAlias

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, create_model
from pydantic.json_schema import JsonDict, models_json_schema

from ..backends import AUTO, available_backends
from ..rendering.geometry.camera import Camera as _Camera
from ..rendering.geometry.coordinates import MAX_COORDINATE
from ..rendering.geometry.plane import MAX_SLAB
from ..rendering.geometry.plane import Plane as _Plane
from ..rendering.planning.modes import SAMPLINGS
from ..store.metadata import CHANNELS
from ..store.packing import MAX_WEIGHT_BITS
from ..volume.pyramid import MAX_LEVELS
from .schema_words import _NoTitles, check, expected, message

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


# The names the wire accepts, from the constants the code uses: a Literal of them for pydantic (its
# enum in the OpenAPI document); a str for static checkers, which cannot read a Literal of a tuple.
if TYPE_CHECKING:
    ChannelName: TypeAlias = str
    SamplingName: TypeAlias = str
    BackendName: TypeAlias = str
else:
    ChannelName, SamplingName, BackendName = Literal[CHANNELS], Literal[SAMPLINGS], Literal[BACKENDS]

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


_CAMERA_EXAMPLE: JsonDict = {"position": [3.5, 3.5, 40.0], "focal_point": [3.5, 3.5, 3.5], "width": 8, "height": 8}
_PLANE_EXAMPLE: JsonDict = {
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
    channel: ChannelName = Field(description="the store's channel to sum")
    sampling: SamplingName = Field("nearest", description="how a sample reads the voxels")
    step: Annotated[
        float, Field(gt=0, le=MAX_STEP, description="sample spacing in world units (a plane: its slab step)")
    ] = 1.0
    level: Annotated[int, Field(ge=0, le=MAX_LEVELS, description="pyramid level (0: the volume)")] = 0
    digits: Annotated[int, Field(ge=0, le=MAX_DIGITS, description="decimal digits of trilinear weights")] = 3
    pack: bool = Field(True, description="pack many pixels per ciphertext")
    tile: Annotated[int, Field(ge=1, le=MAX_SIDE)] = Field(32, description="image tile edge (pixels) of the reduce")
    backend: BackendName | None = Field(None, description="the server's arithmetic backend (null: its default)")
    weight_bits: Annotated[int, Field(ge=0, le=MAX_WEIGHT_BITS)] | None = Field(
        None, description="a packed store's in-slice weight bits (null: the store's)"
    )


#: A render request's fields but its view: what ``RenderRequest.__post_init__`` checks of a request
#: built in Python (its view is a Camera or Plane object, checked by itself).
_OPTIONS: dict[str, Any] = {name: (f.annotation, f) for name, f in RenderRequest.model_fields.items() if name != "view"}
RenderOptions = create_model("RenderOptions", __base__=Wire, **_OPTIONS)


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


def components(ref: str = "#/components/schemas/{model}") -> dict[str, dict]:
    """The JSON Schema of every model, by name, its references ``ref`` (OpenAPI's components).

    >>> sorted(components())[:4]
    ['Aggregate', 'Camera', 'Health', 'Plane']
    """
    _, doc = models_json_schema([(m, "validation") for m in MODELS], ref_template=ref, schema_generator=_NoTitles)
    return doc["$defs"]


_SCHEMAS = components("#/$defs/{model}")  # the protocol's models (field tables, expected())


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
        rows.append(f"| `{name}` | {default} | {expected(prop, _SCHEMAS)} | {meaning} |")
    return "\n".join(rows)
