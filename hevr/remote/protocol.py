"""The wire protocol between ``hevr serve`` and :func:`hevr.connect`: requests as strict JSON,
answers as data only.

Nothing that crosses the wire can carry code: requests are JSON objects checked field by field
(unknown fields refused, every number bounded) by the protocol's models, written once in
:mod:`hevr.remote.schema` (the OpenAPI document is generated from them; docs/protocol.md says it
in words), answers are a ``.hevr`` image (its own strict
parser, :mod:`hevr.image.header`), length-prefixed finishing units, JSON documents and RFC 9457
problem documents. Neither side ever unpickles what the other sends.

Endpoints (``/v1``; the OpenAPI document at ``/v1/openapi.json``, :mod:`hevr.serve.openapi`)::

    GET  /v1                          the server's protocol version
    GET  /v1/health                   {"status": "ok"}, no token asked
    GET  /v1/stores                   the stores this token may render: id, name and public metadata
    GET  /v1/stores/{id or name}      one store's description: its id, its served name and its
                                      public metadata (its ``hevr`` attributes)
    POST /v1/stores/{id}/render       RenderRequest          -> application/vnd.hevr.image
                                                                (a packed store: application/vnd.hevr.units)
    POST /v1/stores/{id}/stream       RenderRequest          -> application/vnd.hevr.units
    POST /v1/stores/{id}/verify       VerifyRequest          -> {"aggregate": "<decimal>"}

A store is served under its id (16 hex digits, :attr:`~hevr.store.metadata.VolumeMetadata.store_id`)
and under a *name* the operator controls (:data:`STORE_NAME`: ``hevr serve NAME=PATH``, or the
store's folder name without ``.zarr``). A name never looks like an id (:func:`check_store_name`),
so ``/v1/stores/{x}`` is never ambiguous. The key holder opens a store by either and then sends
every render to its id, so a server that swaps the store under a name mid-session is caught
(404), and a new version under a known name is caught by the key holder's known stores
(:mod:`hevr.store.known`: a store opened by name is recorded under ``<server>/v1/stores/<name>``).

A render request names a *channel*, never a mode, a density or a transfer function: frames are
finished on the client (:mod:`hevr.colour`), so the colouring never leaves the key holder.

The units stream: one frame per finishing unit as it completes, ``index`` (u32, little-endian),
``length`` (u32) and ``length`` bytes of ciphertext records; then an end frame, index
``0xFFFFFFFF``, whose body is a JSON object: ``{"ok": true}`` or a problem document. A packed
store's frame (:mod:`hevr.rendering.packed`) comes back in the same framing from ``render``: one
frame per reduce tile of its plan, in tile order, each the tile's combined values as ciphertext
records; the key holder, who plans the frame itself, knows how many records every tile must hold.

>>> r = RenderRequest.from_dict({"view": {"position": [0, 0, 40], "focal_point": [0, 0, 0], "width": 8,
...                                       "height": 8}, "channel": "scalar"})
>>> RenderRequest.from_dict(r.to_dict()) == r, r.sampling, r.level
(True, 'nearest', 0)
>>> RenderRequest.from_dict(dict(r.to_dict(), colour="red"))  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
hevr.errors.ParameterError: request: expected only the fields ['backend', 'channel', ...], got extra fields ['colour']
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from typing import Any

from ..crypto.mac import digest
from ..errors import HevrError, ParameterError
from ..image.header import _no_duplicates, _small_int
from ..rendering.geometry.camera import Camera
from ..rendering.geometry.plane import Plane, view_from_dict
from . import schema
from .schema import BACKENDS, CHANNELS, MAX_PIXELS, MAX_SIDE, MAX_STEP, SAMPLINGS, check

__all__ = [
    "API_VERSION",
    "BACKENDS",
    "CHANNELS",
    "END",
    "IMAGE_MEDIA",
    "MAX_BODY",
    "MAX_PIXELS",
    "MAX_SIDE",
    "MAX_STEP",
    "PROBLEM_MEDIA",
    "SAMPLINGS",
    "STORE_ID",
    "STORE_NAME",
    "UNITS_MEDIA",
    "RenderRequest",
    "VerifyRequest",
    "check_store_name",
    "image_limit",
    "is_store_id",
    "pack_frame",
    "packed_limit",
    "parse_json",
    "unpack_head",
]

API_VERSION = 1
PREFIX = "/v1"
IMAGE_MEDIA = "application/vnd.hevr.image"
UNITS_MEDIA = "application/vnd.hevr.units"
PROBLEM_MEDIA = "application/problem+json"
MAX_BODY = 64 * 1024  # a request body: a camera and a few numbers are a few hundred bytes
END = 0xFFFFFFFF  # the index of a units stream's end frame
FRAME = struct.Struct("<II")
MAX_JSON_DEPTH = 32
STORE_ID = re.compile(schema.STORE_ID_PATTERN)  # a store id as the server and the key holder write it
STORE_NAME = re.compile(schema.STORE_NAME_PATTERN)  # a served name: safe in a URL path, no '/'
_ID_LIKE = re.compile(schema.ID_LIKE)


def is_store_id(text: Any) -> bool:
    """Whether ``text`` is a store id (16 lower-case hex digits)."""
    return isinstance(text, str) and STORE_ID.fullmatch(text) is not None


def check_store_name(name: Any, where: str = "name") -> str:
    """``name`` if it can name a served store (:data:`STORE_NAME`, and not 16 hex digits, which
    would read as a store id); a :class:`hevr.ParameterError` naming ``where`` otherwise.

    >>> check_store_name("ct-2024.v2")
    'ct-2024.v2'
    >>> check_store_name("0123456789abcdef")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: name: expected a store name that is not 16 hex digits (...), got '0123456789abcdef'
    """
    if not isinstance(name, str) or not STORE_NAME.fullmatch(name):
        raise ParameterError(
            f"{where}: expected a store name of 1-64 letters, digits or _.@- (starting with a "
            f"letter or digit), got {str(name)[:70]!r}"
        )
    if _ID_LIKE.fullmatch(name):
        raise ParameterError(
            f"{where}: expected a store name that is not 16 hex digits (those read as a store id), got {name!r}"
        )
    return name


def parse_json(raw: bytes, name: str, limit: int = MAX_BODY) -> Any:
    """Strict JSON of at most ``limit`` bytes (default :data:`MAX_BODY`): UTF-8, no duplicate keys, no NaN or
    Infinity, integers of at most 40 digits, bounded nesting; a :class:`hevr.ParameterError`
    naming ``name`` otherwise.

    >>> parse_json(b'{"a": 1}', "body")
    {'a': 1}
    >>> parse_json(b'{"a": 1, "a": 2}', "body")
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: body: expected a JSON document, got duplicate key 'a'
    """
    if len(raw) > limit:
        raise ParameterError(f"{name}: expected at most {limit} bytes of JSON, got {len(raw)}")
    if raw.count(b"[") + raw.count(b"{") > 4 * MAX_JSON_DEPTH * 16 * max(1, limit // MAX_BODY):
        raise ParameterError(f"{name}: expected a small JSON document, got too many '[' and '{{'")

    def no_constant(text: str) -> Any:
        raise ValueError(f"{text} (not JSON)")

    try:
        doc = json.loads(
            raw.decode("utf-8"), object_pairs_hook=_no_duplicates, parse_int=_small_int, parse_constant=no_constant
        )
    except RecursionError:
        raise ParameterError(f"{name}: expected a JSON document, got one nested too deeply") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, the hooks'
        raise ParameterError(f"{name}: expected a JSON document, got {str(exc)[:160]}") from None
    if _depth(doc) > MAX_JSON_DEPTH:
        raise ParameterError(f"{name}: expected a JSON document nested at most {MAX_JSON_DEPTH} deep")
    return doc


def _depth(doc: Any, level: int = 0) -> int:
    if level > MAX_JSON_DEPTH:
        return level
    if isinstance(doc, dict):
        return max([_depth(v, level + 1) for v in doc.values()] or [level + 1])
    if isinstance(doc, list):
        return max([_depth(v, level + 1) for v in doc] or [level + 1])
    return level


def _view(data: dict) -> Camera | Plane:
    """A camera or plane from its checked JSON (:class:`schema.Camera` or :class:`schema.Plane`),
    by its own domain checks (a view direction, orthogonal axes), at most :data:`MAX_PIXELS`."""
    try:
        view = view_from_dict(data)
    except HevrError as exc:
        raise ParameterError(f"view: expected a camera or plane ({exc})") from None
    except (TypeError, ValueError, OverflowError) as exc:  # a constructor's own checks on odd JSON
        raise ParameterError(f"view: expected a camera or plane, got {type(exc).__name__}: {str(exc)[:120]}") from None
    if view.width * view.height > MAX_PIXELS:
        raise ParameterError(f"view: expected at most {MAX_PIXELS} pixels, got {view.width}x{view.height}")
    return view


def _plain(value: Any) -> Any:
    """A NumPy integer or float of a request built in Python as the Python number (strict models
    take only those); anything else as it is (a bool stays a bool, and is refused as a number)."""
    if type(value).__module__ == "numpy" and hasattr(value, "item"):
        return value.item()
    return value


_OPTIONS = tuple(name for name in schema.RenderRequest.model_fields if name != "view")
_DEFAULT = {name: f.default for name, f in schema.RenderRequest.model_fields.items()}


@dataclass(frozen=True)
class RenderRequest:
    """What the key holder asks ``hevr serve`` to render: a view and what to sum, nothing of the
    colouring (module docstring). Its fields, their bounds and defaults are those of the wire
    model :class:`hevr.remote.schema.RenderRequest`, which checks them in ``__post_init__`` (and
    the whole JSON in :meth:`from_dict`); ``to_dict``/``from_dict`` are the wire form, :meth:`key`
    a stable identity.

    Parameters
    ----------
    view : Camera or Plane
        The camera (level 0's frame, as :func:`hevr.render` takes it) or the slice plane.
    channel : {"scalar", "vector", "gradient"}
    sampling : {"nearest", "trilinear"}
    step : float
        Sample spacing in world units (a plane: its slab step).
    level : int
        Pyramid level (0: the volume).
    digits : int
        Decimal digits of the trilinear weights.
    pack : bool
    tile : int
    backend : str, optional
        The server's arithmetic backend (None: the server's default).
    weight_bits : int, optional
        A packed store's in-slice weight bits (None: the store's; per-voxel stores take None).

    Examples
    --------
    A request built in Python is checked as one from the wire, by the same model, and refused
    with a :class:`hevr.ParameterError` naming the field:

    >>> cam = Camera((0, 0, 9), (0, 0, 0), width=4, height=4)
    >>> RenderRequest(view=cam, channel="scalar", step=-1.0)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: step: expected a number in (0, 1e+06], got -1.0
    >>> RenderRequest(view=cam, channel="scalar", tile=0)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: tile: expected an integer in [1, 4096], got 0
    """

    view: Camera | Plane
    channel: str
    sampling: str = _DEFAULT["sampling"]
    step: float = _DEFAULT["step"]
    level: int = _DEFAULT["level"]
    digits: int = _DEFAULT["digits"]
    pack: bool = _DEFAULT["pack"]
    tile: int = _DEFAULT["tile"]
    backend: str | None = _DEFAULT["backend"]
    weight_bits: int | None = _DEFAULT["weight_bits"]

    FIELDS = tuple(schema.RenderRequest.model_fields)

    def __post_init__(self) -> None:
        if not isinstance(self.view, (Camera, Plane)):
            raise ParameterError(f"view: expected a hevr.Camera or hevr.Plane, got {type(self.view).__name__}")
        options = check(schema.RenderOptions, {name: _plain(getattr(self, name)) for name in _OPTIONS})
        for name in _OPTIONS:
            object.__setattr__(self, name, getattr(options, name))
        if isinstance(self.view, Plane) and self.level:
            raise ParameterError(f"level: expected 0 for a plane (slices have no level), got {self.level}")

    def to_dict(self) -> dict[str, Any]:
        return {"view": self.view.to_dict(), **{name: getattr(self, name) for name in _OPTIONS}}

    @classmethod
    def from_dict(cls, d: Any, name: str = "request") -> RenderRequest:
        wire = check(schema.RenderRequest, d, name)
        return cls(view=_view(d["view"]), **{k: getattr(wire, k) for k in _OPTIONS})

    def key(self) -> str:
        """SHA-256 of the canonical JSON: equal across processes."""
        return digest(self.to_dict()).hex()

    @property
    def pixels(self) -> int:
        return self.view.width * self.view.height


@dataclass(frozen=True)
class VerifyRequest:
    """The verification round: the render asked before and the seed the key holder drew *after* it
    held the image (:mod:`hevr.rendering.verify`); the server answers the tag aggregate. The wire
    model: :class:`hevr.remote.schema.VerifyRequest`.

    >>> cam = {"position": [0, 0, 40], "focal_point": [0, 0, 0], "width": 4, "height": 4}
    >>> v = VerifyRequest.from_dict({"render": {"view": cam, "channel": "scalar"}, "seed": "ab" * 32})
    >>> len(v.seed), VerifyRequest.from_dict(v.to_dict()) == v
    (32, True)
    """

    render: RenderRequest
    seed: bytes

    def __post_init__(self) -> None:
        if not isinstance(self.render, RenderRequest):
            raise ParameterError(f"render: expected a RenderRequest, got {type(self.render).__name__}")
        if not isinstance(self.seed, bytes) or len(self.seed) != 32:
            raise ParameterError("seed: expected 32 bytes")

    def to_dict(self) -> dict[str, Any]:
        return {"render": self.render.to_dict(), "seed": self.seed.hex()}

    @classmethod
    def from_dict(cls, d: Any, name: str = "request") -> VerifyRequest:
        wire = check(schema.VerifyRequest, d, name)
        return cls(render=RenderRequest.from_dict(d["render"], "render"), seed=bytes.fromhex(wire.seed))


HEADER_ROOM = 1 << 20  # a .hevr header beyond its hit mask: the info, the plan, the numbers


def image_limit(height: int, width: int, components: int, record_width: int) -> int:
    """The most bytes a client-finished image of this size can take: every pixel a ciphertext per
    component (no packing), the sample counts, the hit mask and the header. The key holder reads no
    more of an answer than this (:mod:`hevr.remote.client`).

    >>> image_limit(2, 2, 1, 512) > 4 * 512
    True
    """
    pixels = int(height) * int(width)
    return pixels * int(components) * int(record_width) + pixels * 4 + pixels // 4 + HEADER_ROOM


def packed_limit(counts: list[int], record_width: int) -> int:
    """The bytes of a packed frame's answer: every tile's ``counts`` records as one frame, then the
    end frame (its JSON status and statistics, at most :data:`MAX_BODY`).

    >>> packed_limit([2, 3], 10) == 2 * 8 + 50 + 8 + MAX_BODY
    True
    """
    return sum(FRAME.size + int(c) * int(record_width) for c in counts) + FRAME.size + MAX_BODY


def pack_frame(index: int, body: bytes) -> bytes:
    """One frame of the units stream: index and length (u32 LE each), then the bytes.

    >>> unpack_head(pack_frame(3, b"abc")[:8])
    (3, 3)
    """
    return FRAME.pack(index, len(body)) + body


def unpack_head(head: bytes) -> tuple[int, int]:
    """The (index, length) of a frame's 8-byte head."""
    return FRAME.unpack(head)
